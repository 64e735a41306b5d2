#!/usr/bin/env bash
# System packages, installed where we can (root with apt-get), else a note and carry on:
# * libusb-1.0-0: Open3D's Linux wheel links against it. Without it masknet still works;
#   only Open3D features fail, with a clear message.
# * chromium (with --test): the HTML viewer's browser test. Without it that test is skipped.
want=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || want+=(libusb-1.0-0)
if [ "$1" = "--test" ] && ! command -v chromium >/dev/null 2>&1; then
    want+=(chromium)
fi
[ ${#want[@]} -eq 0 ] && exit 0
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing ${want[*]} (apt-get)"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${want[@]}" >/dev/null 2>&1 \
        || { apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${want[@]}" >/dev/null 2>&1; } \
        || echo "note: could not install ${want[*]}; Open3D features / the browser test will be unavailable"
else
    echo "note: ${want[*]} missing and cannot be installed here (needs root and apt-get)."
    echo "      Open3D features (libusb-1.0-0) or the viewer's browser test (chromium) will be"
    echo "      unavailable. Install with: sudo apt-get install ${want[*]}"
fi
exit 0

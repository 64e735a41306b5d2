#!/usr/bin/env bash
# Open3D's Linux wheel links against libusb-1.0. Install it where we can (root on Debian/Ubuntu);
# elsewhere say so and carry on: masknet works without Open3D, only Open3D features will fail
# with a clear message.
if ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    exit 0
fi
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing libusb-1.0-0 (needed by Open3D)"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 \
        || { apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1; } \
        || echo "note: could not install libusb-1.0-0; Open3D features will be unavailable"
else
    echo "note: libusb-1.0 is missing and cannot be installed here (needs root and apt-get);"
    echo "      Open3D features will be unavailable. Install it with: sudo apt-get install libusb-1.0-0"
fi
exit 0

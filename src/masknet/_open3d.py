"""Open3D, optional and slow to import: loading it once, and hearing what it reports.

:func:`require_open3d` imports it on first use (quietened to errors, a Ctrl-C during the
import held until it ends) or raises a :class:`~masknet.errors.MaskNetError` saying how to
install it; :func:`has_open3d` asks once per process. Open3D does not raise on bad files:
it prints. :func:`captured_output` captures what it and the C library RPly print (Python
and file-descriptor level), and :func:`open3d_failure` finds a reported failure in it.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import io
import os
import re
import signal
import tempfile
import threading
from collections.abc import Iterator
from types import ModuleType

from masknet.errors import MaskNetError, first_line

__all__ = ["captured_output", "has_open3d", "open3d_failure", "open3d_threads", "require_open3d"]

_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_FAILURE = re.compile(r"fail|error", re.IGNORECASE)


@functools.lru_cache(maxsize=1)
def _load_open3d() -> ModuleType:
    """Import Open3D once (slow), and quieten its logger to errors only.

    Ctrl-C during the import would break Open3D's C initialisation, which then reports
    itself as not importable; the interrupt is held until the import ends and raised then,
    so that it is reported as what it is."""
    interrupted: list[int] = []
    previous = signal.getsignal(signal.SIGINT)
    # Only where Python may set handlers, and over a handler Python knows (not C's).
    held = threading.current_thread() is threading.main_thread() and previous is not None
    if held:
        signal.signal(signal.SIGINT, lambda signum, frame: interrupted.append(signum))
    try:
        import open3d
    finally:
        if held:
            signal.signal(signal.SIGINT, previous)
    if interrupted:  # the user's handler decides now (KeyboardInterrupt by default)
        signal.raise_signal(signal.SIGINT)
    open3d.utility.set_verbosity_level(open3d.utility.VerbosityLevel.Error)
    return open3d


def require_open3d(feature: str) -> ModuleType:
    """Return the ``open3d`` module, or raise a MaskNetError saying how to install it.

    ``feature`` names what needs it, e.g. ``"reading .pcd files"``; it starts the
    message. Import failures of any kind count (a missing package, or a shared
    library such as libusb that the wheel needs).
    """
    try:
        return _load_open3d()
    except Exception as exc:  # ImportError, OSError from a missing shared library, ...
        reason = first_line(str(exc)) or type(exc).__name__
        raise MaskNetError(
            f"{feature} needs Open3D, which did not import ({reason}). "
            "Install it with `pip install open3d`; on Debian/Ubuntu it also needs "
            "`apt-get install libusb-1.0-0`."
        ) from exc


@functools.cache
def has_open3d() -> bool:
    """Whether Open3D imports (it may be installed and still fail, e.g. without libusb);
    asked once per process."""
    try:
        require_open3d("Open3D")
    except MaskNetError:
        return False
    return True


@contextlib.contextmanager
def captured_output() -> Iterator[io.StringIO]:
    """Capture what is printed to stdout/stderr, at Python and file-descriptor level.

    Open3D logs through Python's ``sys.stdout``; the RPly library it uses for PLY
    writes to the C stderr. The captured text is in the yielded buffer on exit.
    """
    buf = io.StringIO()
    saved: list[tuple[int, int]] = []
    sink = None
    try:
        sink = tempfile.TemporaryFile()
        for fd in (1, 2):
            try:
                saved.append((fd, os.dup(fd)))
                os.dup2(sink.fileno(), fd)
            except OSError:
                pass
    except OSError:  # no temporary file: capture at Python level only
        sink = None
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            yield buf
    finally:
        _flush_c_stdio()
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        if sink is not None:
            sink.seek(0)
            buf.write(sink.read().decode("utf-8", "replace"))
            sink.close()


def _flush_c_stdio() -> None:
    with contextlib.suppress(Exception):  # not on every platform
        ctypes.CDLL(None).fflush(None)


def open3d_failure(captured: str) -> str | None:
    """The first failure Open3D (or RPly) reported in ``captured``, cleaned up; else None."""
    for line in _ANSI.sub("", captured).splitlines():
        if _FAILURE.search(line):
            line = re.sub(r"^\[Open3D [A-Z]+\]\s*", "", line.strip())
            return line.rstrip(".")
    return None


@contextlib.contextmanager
def open3d_threads(threads: int | None) -> Iterator[None]:
    """Open3D on ``threads`` threads within the block (None: as it is), its former count
    restored after. One thread makes Open3D's RANSAC and its parallel sums repeat."""
    o3d = require_open3d("Open3D's thread count")
    before = o3d.utility.get_max_threads()
    if threads is not None:
        o3d.utility.set_max_threads(threads)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(before)

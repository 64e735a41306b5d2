"""Atomic writes: data goes to a temporary file beside the target, then
:func:`os.replace` moves it into place, so a failure never leaves a partial file."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from masknet.errors import MaskNetError

__all__ = ["atomic_target", "write_text_atomic"]


@contextlib.contextmanager
def atomic_target(path: str | os.PathLike, suffix: str = "") -> Iterator[str]:
    """Yield a temporary path beside ``path``; on success move it over ``path``.

    The temporary name is ``.<name>.tmpXXXX<suffix>`` (give the target's extension as
    ``suffix`` to writers that choose a format by it, or append one). Parent directories
    are created. On any exception the temporary file is removed and ``path`` is
    untouched; an :class:`OSError` becomes a :class:`MaskNetError` naming the file.
    """
    name = os.fspath(path)
    target = Path(name)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.tmp", suffix=suffix, dir=target.parent)
        os.close(fd)
    except OSError as exc:
        raise MaskNetError(f"{name}: cannot write ({exc.strerror or exc})") from exc
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it 0600
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise MaskNetError(f"{name}: cannot write ({exc.strerror or exc})") from exc
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically, creating parent directories."""
    with atomic_target(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(text)

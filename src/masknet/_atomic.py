"""Atomic writes, of one file or of several all-or-nothing: data goes to temporary files
beside the targets, then :func:`os.replace` moves them into place, so a failure never
leaves a partial file and never loses a file that was there before.

:func:`atomic_target` and :func:`write_all` share one implementation (:class:`_Staging`).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from masknet.errors import MaskNetError, warn

__all__ = ["atomic_target", "write_all", "write_text_atomic"]


class _Staging:
    """Temporary files beside their targets, moved over them all together or not at all."""

    def __init__(self) -> None:
        self.files: list[tuple[str, Path]] = []  # (temporary file, its target)
        self.current = "output"  # the target an error is about
        self.made: list[Path] = []  # folders this staging created, outermost first

    def add(self, path: str | os.PathLike, suffix: str) -> str:
        """A new temporary file ``.<name>.tmpXXXX<suffix>`` beside ``path`` (parent
        directories are created)."""
        self.current = os.fspath(path)
        target = Path(path)
        if target.is_dir():
            raise MaskNetError(f"{self.current}: is a directory, not a file")
        missing = [p for p in [target.parent, *target.parent.parents] if not p.exists()]
        target.parent.mkdir(parents=True, exist_ok=True)
        self.made += reversed(missing)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.tmp", suffix=suffix, dir=target.parent)
        os.close(fd)
        self.files.append((tmp, target))
        return tmp

    def commit(self, stale: Iterable[Path] = ()) -> list[Path]:
        """Move every temporary file over its target, and move aside the ``stale`` files
        that exist and were not written; on a failure put everything back as it was.
        An earlier target is kept aside until all moves have succeeded, except the last
        one's when nothing follows it: that move is the one atomic step. Returns the stale
        files removed."""
        written = {path.resolve() for _, path in self.files}
        stale = [p for p in stale if p.exists() and p.resolve() not in written]
        kept: list[tuple[str, Path]] = []  # (earlier file moved aside, its path)
        placed: list[Path] = []
        try:
            for i, (tmp, path) in enumerate(self.files):
                self.current = str(path)
                os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it 0600
                if path.exists() and (stale or i < len(self.files) - 1):
                    aside = f"{tmp}.earlier"
                    os.replace(path, aside)
                    kept.append((aside, path))
                os.replace(tmp, path)
                placed.append(path)
            for path in stale:
                self.current = str(path)
                aside = f"{path.parent / ('.' + path.name)}.stale"
                os.replace(path, aside)
                kept.append((aside, path))
        except BaseException:
            for path in placed:
                with contextlib.suppress(OSError):
                    path.unlink()
            for aside, path in kept:
                with contextlib.suppress(OSError):
                    os.replace(aside, path)
            raise
        for aside, _ in kept:
            with contextlib.suppress(OSError):
                os.unlink(aside)
        return stale

    def drop_last(self) -> None:
        """Forget the last temporary file (an output that will not be written)."""
        tmp, _ = self.files.pop()
        with contextlib.suppress(OSError):
            os.unlink(tmp)

    def discard(self) -> None:
        for tmp, _ in self.files:
            with contextlib.suppress(OSError):
                os.unlink(tmp)

    def unmake(self) -> None:
        """Remove the folders this staging created and that are still empty, innermost
        first: a failed or interrupted run leaves no empty folder behind, and a folder that
        was there before, or that holds anything, stays."""
        for folder in reversed(self.made):
            with contextlib.suppress(OSError):
                folder.rmdir()  # refuses a folder that is not empty

    def named(self, message: str) -> str:
        """``message`` with every temporary file's name replaced by its target's."""
        for tmp, path in self.files:
            message = message.replace(tmp, str(path))
        return message


@contextlib.contextmanager
def _staging() -> Iterator[_Staging]:
    """A :class:`_Staging` whose temporary files are gone on exit, and on a failure or an
    interrupt the folders it created too, where they are empty. An :class:`OSError`
    becomes a :class:`MaskNetError` naming the target, and a MaskNetError naming a
    temporary file names its target instead."""
    staging = _Staging()
    failed = True
    try:
        yield staging
        failed = False
    except OSError as exc:
        raise MaskNetError(f"{staging.current}: cannot write ({exc.strerror or exc})") from exc
    except MaskNetError as exc:
        message = staging.named(str(exc))
        if message == str(exc):
            raise
        raise MaskNetError(message) from exc
    finally:
        staging.discard()
        if failed:  # after discard: a folder holding a temporary file is not empty
            staging.unmake()


@contextlib.contextmanager
def atomic_target(path: str | os.PathLike, suffix: str = "") -> Iterator[str]:
    """Yield a temporary path beside ``path``; on success move it over ``path``.

    The temporary name is ``.<name>.tmpXXXX<suffix>`` (give the target's extension as
    ``suffix`` to writers that choose a format by it, or append one). Parent directories
    are created. On any exception the temporary file is removed and ``path`` is
    untouched; an :class:`OSError` becomes a :class:`MaskNetError` naming the file.
    """
    with _staging() as staging:
        yield staging.add(path, suffix)
        staging.commit()


def write_all(
    writers: list[tuple[Path, Callable[[Path], None]]],
    stale: Iterable[Path] = (),
    optional: Iterable[Path] = (),
) -> list[Path]:
    """Write every output or none, and never lose a file that was there before.

    Each writer is called, in order, with a temporary file beside its target (with the
    target's extension); only when all have been written are they moved into place, each
    earlier file kept aside until every move has succeeded, and put back if one fails.
    ``stale``: side files the caller owns but did not write this time (an earlier
    run's); those that exist are removed in the same transaction, so no earlier output
    looks like part of this one. Returns them. ``optional``: side outputs whose writer
    may refuse its content (a :class:`MaskNetError`, e.g. an empty cloud as ``.ply``):
    such an output is skipped with a one-line :class:`~masknet.errors.MaskNetWarning`
    and counts as stale, and the others are written; the answer is never lost to a side
    file's format. Errors name the targets, never the temporary files.
    """
    optional = {Path(p) for p in optional}
    skipped: list[Path] = []
    with _staging() as staging:
        for path, write in writers:
            tmp = Path(staging.add(path, Path(path).suffix))
            try:
                write(tmp)
            except MaskNetError as exc:
                if Path(path) not in optional:
                    raise
                warn(f"{staging.named(str(exc))}; skipped, the other outputs are written")
                staging.drop_last()
                skipped.append(Path(path))
        return staging.commit([*stale, *skipped])


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically, creating parent directories."""
    with atomic_target(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(text)

"""The one output rule of every command: no output is an input (by path, symbolic link or
hard link, through folders not made yet too), and every output can be written, checked
before any work."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

from masknet.errors import MaskNetError

__all__ = ["check_outputs", "output_file", "refuse_inputs"]


def check_outputs(
    paths: list[Path],
    text: tuple[str, ...] = (".txt", ".html", ".png"),
    inputs: Iterable[str | Path] = (),
    hint: str = "give it another name",
) -> None:
    """Refuse, before any computing, outputs that cannot be written: one of the ``inputs``
    (:func:`refuse_inputs`), an unsupported extension (point files; ``text`` suffixes are
    always fine), a path that is a directory, or a parent that is not a writable directory
    (missing ones are made)."""
    from masknet.io import SUPPORTED_WRITE

    refuse_inputs(paths, inputs, hint)
    seen: dict[Path, Path] = {}
    writable: dict[Path, bool] = {}  # a batch writes many files into one folder: tried once
    for path in paths:
        key = path.resolve()
        if key in seen:
            raise MaskNetError(f"{path}: named for two outputs; give each output its own name")
        seen[key] = path
        if path.is_dir():  # before the extension: a folder has none
            raise MaskNetError(f"{path}: is a directory, not a file")
        ext = path.suffix.lower()
        if ext not in SUPPORTED_WRITE and ext not in text:
            raise MaskNetError(
                f"{path}: cannot write extension {ext or '(none)'!r} "
                f"(supported: {', '.join(SUPPORTED_WRITE)})"
            )
        parent = next((p for p in [path.parent, *path.parent.parents] if p.exists()), Path("."))
        if parent not in writable:
            writable[parent] = parent.is_dir() and _can_create_in(parent)
        if not writable[parent]:
            raise MaskNetError(f"{path}: cannot write into {parent} (not a writable directory)")


def refuse_inputs(
    outputs: Iterable[str | Path], inputs: Iterable[str | Path], hint: str = "give it another name"
) -> None:
    """The one output rule of every command: no output is one of the ``inputs`` (the same
    path, a symbolic link to it, or a hard link to it), so a run never overwrites what it
    reads. Raises a :class:`MaskNetError` naming the first clash, followed by ``hint``
    (what to do). One pass over each list: a batch of thousands of pairs checks fast."""
    given = {_identity(Path(p)): p for p in inputs}
    for path in outputs:
        clash = given.get(_identity(Path(path)))
        if clash is not None:
            raise MaskNetError(
                f"{path}: is the input {clash}; an output never overwrites an input, {hint}"
            )


def _identity(path: Path) -> tuple[int, int] | str:
    """What names one file whatever the path: (device, inode) where it exists (symbolic
    and hard links), else the path with its links resolved (a file not made yet).

    A path through a folder not made yet (``new/../scan.ply``) cannot be stat'ed as given,
    but the writer makes that folder and lands on ``scan.ply``: such a path is resolved
    first (``..`` after a missing folder taken lexically, as the folder made will be a
    real one) and stat'ed again."""
    resolved = os.path.realpath(path)
    for candidate in (path, Path(resolved)):
        try:
            info = candidate.stat()  # follows a symbolic link: its target is what gets written
        except OSError:
            continue
        return (info.st_dev, info.st_ino)
    return resolved


def output_file(text: str) -> Path:
    """``-o/--output`` of a command that writes one file and its side files: refused in one
    line where it names no file (``.``, ``..``, a path ending in ``/``, an empty string)."""
    path = Path(text)
    if not text or text.endswith(("/", os.sep)) or path.name in ("", ".", ".."):
        raise MaskNetError(
            f"-o {text!r}: names a folder, not a file; give a file name such as out.ply"
        )
    return path


def _can_create_in(folder: Path) -> bool:
    """Whether a file can be created in ``folder``: tried, since permission bits do not
    tell (root, read-only mounts, /proc)."""
    probe = None
    try:  # the probe goes even when Ctrl-C lands between its creation and removal
        fd, probe = tempfile.mkstemp(prefix=".masknet-probe", dir=folder)
        os.close(fd)
    except OSError:
        return False
    finally:
        if probe is not None:
            with contextlib.suppress(OSError):
                os.unlink(probe)
    return True

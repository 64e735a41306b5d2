"""The one atomic writer (masknet._atomic): one file or several, all or nothing, never
losing what was there, errors naming the user's files."""

from __future__ import annotations

import os
import stat

import pytest

from masknet._atomic import atomic_target, write_all
from masknet.errors import MaskNetError


def _names(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_a_failed_write_leaves_the_earlier_file_and_no_temporary(tmp_path):
    path = tmp_path / "a.txt"
    path.write_text("OLD")
    with pytest.raises(RuntimeError), atomic_target(path) as tmp:
        with open(tmp, "w") as f:
            f.write("half")
        raise RuntimeError("killed")
    assert path.read_text() == "OLD" and _names(tmp_path) == ["a.txt"]


def test_one_file_is_replaced_in_one_step(tmp_path, monkeypatch):
    """No moment without the file (a checkpoint killed mid-write): one os.replace."""
    path = tmp_path / "checkpoint.safetensors"
    path.write_text("OLD")
    moves = []
    real_replace = os.replace
    monkeypatch.setattr(os, "replace", lambda a, b: (moves.append(b), real_replace(a, b)))
    with atomic_target(path) as tmp, open(tmp, "w") as f:
        f.write("NEW")
    assert path.read_text() == "NEW" and moves == [path]


def test_errors_name_the_target_not_the_temporary_file(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.ply"
    a.write_text("OLD")

    def os_error(path):
        raise OSError(28, "No space left on device", str(path))

    def masknet_error(path):
        raise MaskNetError(f"{path}: cannot write an empty cloud")

    with pytest.raises(MaskNetError) as info:
        write_all([(a, lambda p: p.write_text("NEW")), (b, os_error)])
    assert str(info.value) == f"{b}: cannot write (No space left on device)"
    with pytest.raises(MaskNetError) as info:
        write_all([(b, masknet_error)])
    assert str(info.value) == f"{b}: cannot write an empty cloud"
    with pytest.raises(MaskNetError) as info, atomic_target(b, suffix=".ply") as tmp:
        masknet_error(tmp)
    assert str(info.value) == f"{b}: cannot write an empty cloud"
    assert a.read_text() == "OLD" and _names(tmp_path) == ["a.txt"]


def test_a_directory_is_refused(tmp_path):
    (tmp_path / "d.txt").mkdir()
    with pytest.raises(MaskNetError, match="d.txt: is a directory, not a file"):
        write_all([(tmp_path / "d.txt", lambda p: p.write_text("x"))])
    with pytest.raises(MaskNetError, match="d.txt: is a directory, not a file"):
        with atomic_target(tmp_path / "d.txt"):
            pass


def test_written_files_follow_the_umask(tmp_path):
    mask = os.umask(0o022)
    try:
        write_all([(tmp_path / "a.txt", lambda p: p.write_text("x"))])
        with atomic_target(tmp_path / "b.txt") as tmp, open(tmp, "w") as f:
            f.write("x")
    finally:
        os.umask(mask)
    for name in ("a.txt", "b.txt"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644


def test_an_optional_output_that_refuses_is_skipped_and_the_others_written(tmp_path):
    from masknet.errors import MaskNetWarning

    answer, side = tmp_path / "answer.txt", tmp_path / "side.ply"
    side.write_text("AN EARLIER RUN'S")

    def refuses(path):
        raise MaskNetError(f"{path}: cannot write an empty cloud as .ply")

    with pytest.warns(
        MaskNetWarning,
        match=r"/side.ply: cannot write an empty cloud as .ply; skipped, the other outputs are written",
    ):
        removed = write_all(
            [(answer, lambda p: p.write_text("NEW")), (side, refuses)],
            optional=[side],
        )
    # the answer is there; the earlier side file is gone with it (it is not this run's)
    assert answer.read_text() == "NEW" and removed == [side]
    assert _names(tmp_path) == ["answer.txt"]
    with pytest.raises(MaskNetError, match="empty cloud"):  # not optional: all or nothing
        write_all([(answer, lambda p: p.write_text("NEWER")), (side, refuses)])
    assert answer.read_text() == "NEW"


@pytest.mark.parametrize("failure", [KeyboardInterrupt, MaskNetError])
def test_a_failed_write_removes_only_the_empty_folders_it_made(tmp_path, failure):
    (tmp_path / "there").mkdir()  # empty, but there before: it stays

    def fails(path):
        raise failure("stopped")

    for target in (tmp_path / "new" / "deeper" / "a.txt", tmp_path / "there" / "a.txt"):
        with pytest.raises(failure):
            write_all([(target, fails)])
    assert _names(tmp_path) == ["there"] and _names(tmp_path / "there") == []
    # a folder it made that holds something by then is kept, and so is what it holds
    kept = tmp_path / "made" / "kept.txt"
    write_all([(kept, lambda p: p.write_text("KEPT"))])
    with pytest.raises(failure):
        write_all([(tmp_path / "made" / "sub" / "b.txt", fails)])
    assert _names(tmp_path / "made") == ["kept.txt"]

"""masknet.cli._common: progress lines, output checks, all-or-nothing writes."""

from __future__ import annotations

import pytest

from masknet.cli import main


def test_a_failed_write_keeps_the_files_that_were_there(tmp_path, pair_files):
    template, source, _ = pair_files
    folder = tmp_path / "d"
    (folder / "o_inliers.ply").mkdir(parents=True)  # this output cannot be written
    (folder / "o.ply").write_text("OLD")
    (folder / "o_transform.txt").write_text("OLD")
    assert main(["register", str(template), str(source), "-o", str(folder / "o.ply")]) == 2
    assert (folder / "o.ply").read_text() == "OLD"
    assert (folder / "o_transform.txt").read_text() == "OLD"
    assert sorted(p.name for p in folder.iterdir()) == ["o.ply", "o_inliers.ply", "o_transform.txt"]


def test_output_paths_are_checked_before_computing(tmp_path, pair_files, capsys):
    template, source, _ = pair_files
    assert main(["register", str(template), str(source), "-o", str(tmp_path / "noext")]) == 2
    assert "cannot write extension '(none)'" in capsys.readouterr().err


def test_write_all_is_all_or_nothing_and_keeps_earlier_files(tmp_path):
    from masknet._atomic import write_all
    from masknet.errors import MaskNetError

    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("OLD")

    def fail(path):
        raise MaskNetError(f"{path}: cannot write (disk full)")

    with pytest.raises(MaskNetError, match="disk full"):
        write_all([(a, lambda p: p.write_text("NEW")), (b, fail)])
    assert a.read_text() == "OLD" and not b.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]  # no temporary files left
    write_all([(a, lambda p: p.write_text("NEW")), (b, lambda p: p.write_text("B"))])
    assert a.read_text() == "NEW" and b.read_text() == "B"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt"]
    # A side file this run owns but does not write goes with a successful run only.
    with pytest.raises(MaskNetError, match="disk full"):
        write_all([(a, fail)], stale=[b])
    assert b.read_text() == "B"
    assert write_all([(a, lambda p: p.write_text("NEWER"))], stale=[a, b]) == [b]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"] and a.read_text() == "NEWER"


def test_progress_speaks_only_for_slow_steps(capsys):
    import time

    from masknet.cli._common import progress

    with progress("quick step", after=0.5):
        pass
    with progress("slow step", after=0.05):
        time.sleep(0.3)
    err = capsys.readouterr().err
    assert "quick step" not in err
    assert "masknet: slow step ..." in err and "masknet: slow step: done in" in err


def test_a_writer_error_names_the_users_file_not_the_temporary_one(tmp_path, pair_files, capsys):
    template, source, _ = pair_files
    out = tmp_path / "inliers.ply"
    # A threshold no score reaches keeps no point: an empty .ply cannot be written, and the
    # mask, the answer, is written all the same.
    assert main(["mask", str(template), str(source), "-o", str(out), "--threshold", "1"]) == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"masknet: warning: {out}: cannot write an empty cloud")
    assert ".tmp" not in err and ".part" not in err
    assert not out.exists() and (tmp_path / "inliers_mask.txt").exists()


# Each old spelling, kept for one version: (command line with it, the attribute it sets,
# the value, what the warning says to use).
_OLD_SPELLINGS = [
    ("demo --out d", "output", "d", "-o/--output"),
    ("benchmark registration --out b", "output", "b", "-o/--output"),
    ("train --out r", "output", "r", "-o/--output"),
    ("evaluate --json e.json", "output", "e.json", "-o/--output"),
    ("register-many --list l.txt --out o", "output", "o", "-o/--output"),
    ("mask t.xyz s.xyz -o m.xyz --pretrained scans", "weights", "scans", "--weights NAME"),
    ("mask t.xyz s.xyz -o m.xyz --inference-precision fp32", "precision", "fp32", "--precision"),
    ("register t.xyz s.xyz -o m.xyz --pretrained scans", "weights", ["scans"], "--weights NAME"),
    ("register t.xyz s.xyz -o m.xyz --network-weights n", "weights", ["n"], "--weights FILE"),
    ("denoise t.xyz s.xyz -o k.xyz --inference-precision bf16", "precision", "bf16", "--precision"),
]


@pytest.mark.parametrize(("line", "dest", "value", "new"), _OLD_SPELLINGS)
def test_old_spellings_work_for_one_version_with_a_warning(line, dest, value, new, capsys):
    from masknet.cli import build_parser

    args = build_parser().parse_args(line.split())
    assert getattr(args, dest) == value
    spellings = {"--out", "--json", "--pretrained", "--inference-precision", "--network-weights"}
    old = next(word for word in line.split() if word in spellings)
    assert capsys.readouterr().err == (
        f"masknet: warning: {old} is deprecated and goes in the next version; use {new}\n"
    )


def test_one_spelling_per_idea_across_commands():
    """Every command that writes takes -o/--output; weights are --weights, precision
    --precision; the old spellings are hidden from --help."""
    import argparse

    from masknet.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in commands.choices.items():
        shown = {s for a in sub._actions if a.help != argparse.SUPPRESS for s in a.option_strings}
        assert not shown & {"--out", "--json", "--pretrained", "--network-weights"}, name
        assert "--inference-precision" not in shown, name
        assert {"-o", "--output"} <= shown, name  # every command writes something


def test_shipped_crossmasknet_weights_load_by_name():
    import argparse

    from masknet.cli._common import load_model
    from masknet.models import CrossMaskNet, MaskNet

    args = argparse.Namespace(weights="crossmasknet_modelnet40", precision="fp32")
    assert isinstance(load_model(args), CrossMaskNet)
    args = argparse.Namespace(weights="modelnet40", precision="fp32")
    assert type(load_model(args)) is MaskNet

"""`masknet benchmark all --quick`: every experiment runs and writes readable output."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from masknet.cli import main
from masknet.experiments import EXPERIMENTS


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    mp = pytest.MonkeyPatch()
    mp.delenv("MASKNET_DATA", raising=False)  # the bundled sample, as in CI without data
    try:
        # A smoke run: every experiment's code path, on a few pairs.
        argv = [
            "benchmark",
            "all",
            "--quick",
            "--pairs",
            "4",
            "--output",
            str(out),
            "--threads",
            "1",
        ]
        code = main(argv)
    finally:
        mp.undo()
    assert code == 0
    return out


NAN_COLUMNS = {
    "masks-per-round": {"precision", "recall", "source_precision", "source_recall"},
    "networks": {"ms_mask", "ms_per_pair", "ms_register"},
    "refine-masks": {"learned_outliers_removed", "rule_outliers_removed"},
    "timing": {"paper_gtx1070_ms"},
}


@pytest.mark.parametrize("name", [n for n in EXPERIMENTS if n != "scans"])
def test_every_experiment_writes_a_table(quick_run, name):
    payload = json.loads((quick_run / f"{name}.json").read_text())
    assert payload["experiment"] == name and payload["quick"] is True
    assert payload["rows"] and payload["wall_time_s"] > 0
    numbers = [
        (key, v) for row in payload["rows"] for key, v in row.items() if isinstance(v, float)
    ]
    assert numbers
    # NaN only where a row has nothing to measure: no mask (plain ICP), no outliers, no
    # network (the identity), no figure in the paper. Everything else is finite.
    allowed = NAN_COLUMNS.get(name, set())
    bad = [(key, v) for key, v in numbers if not math.isfinite(v) and key not in allowed]
    assert not bad, bad
    assert (quick_run / f"{name}.csv").read_text().count("\n") == len(payload["rows"]) + 1


def test_plots_and_contents(quick_run):
    for name in ("registration", "iterations", "precision-vs-missing", "rotation-sweep", "noise"):
        assert (quick_run / f"{name}.png").stat().st_size > 10_000
    registration = json.loads((quick_run / "registration.json").read_text())["rows"]
    assert {"ICP", "Mask-ICP", "PointNetLK", "Mask-PointNetLK"} <= {
        r["pipeline"] for r in registration
    }
    missing = json.loads((quick_run / "precision-vs-missing.json").read_text())["rows"]
    assert [r["chance"] for r in missing] == pytest.approx([0.9, 0.7, 0.5])
    assert all(r["precision"] > r["chance"] for r in missing)  # the shipped model beats chance
    rounds = json.loads((quick_run / "iterations.json").read_text())["rows"]
    loops = [(r["pipeline"], r["loop"], r["round"]) for r in rounds]
    assert loops == [
        (p, loop, n)
        for p in ("Mask-ICP", "Mask-PointNetLK")
        for n in (1, 2, 3)
        for loop in ("paper's loop", "refined loop")
    ]
    refined = [r for r in rounds if r["loop"] == "refined loop"]
    assert all(math.isfinite(r["paired_diff"]) and r["paired_se"] >= 0 for r in refined)
    networks = {
        r["pipeline"]: r for r in json.loads((quick_run / "networks.json").read_text())["rows"]
    }
    learned = [f"{p}{n}" for n in ("DCP", "PRNet", "PCRNet", "RPM-Net") for p in ("", "Mask-")]
    assert set(networks) == {"Identity (no motion)", *learned}  # every shipped network runs
    assert all(networks[n]["ms_per_pair"] > 0 for n in learned)
    assert all(networks[n]["ms_mask"] > 0 for n in learned if n.startswith("Mask-"))
    outliers = {
        r["pipeline"] for r in json.loads((quick_run / "outliers.json").read_text())["rows"]
    }
    assert "Mask-ICP (MaskNet trained with 10% outliers)" in outliers
    sweep = {
        r["pipeline"] for r in json.loads((quick_run / "rotation-sweep.json").read_text())["rows"]
    }
    assert set(learned) <= sweep
    # Real data with ground truth: the 3DMatch pair, in metres and in millimetres.
    real = json.loads((quick_run / "real-pairs.json").read_text())["rows"]
    ours = [r for r in real if r["pipeline"] in ("default (auto)", "robust")]
    assert {(r["unit"], r["pipeline"]) for r in ours} == {
        (u, p) for u in ("m", "mm") for p in ("default (auto)", "robust")
    }
    for r in ours:  # the usual 3DMatch bar is 15 degrees and 30 cm; measured 0.9 and 0.085
        assert r["rot_error_deg"] < 2 and r["trans_error_m"] < 0.1, r


def test_benchmark_help_names_every_experiment(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "300")  # no line breaks inside hyphenated names
    with pytest.raises(SystemExit):
        main(["benchmark", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert all(name in text for name in EXPERIMENTS)


def test_benchmark_resume_from_the_command_line(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("MASKNET_DATA", raising=False)
    argv = ["benchmark", "iterations", "--quick", "--pairs", "4", "--output", str(tmp_path)]
    argv += ["--threads", "1"]
    assert main(argv) == 0
    first = json.loads((tmp_path / "iterations.json").read_text())
    # stderr is not a terminal here: one line per row stands in for the progress bars
    log = capsys.readouterr().err.splitlines()
    assert sum(line.startswith("iterations: pipeline Mask-") for line in log) == 2, log
    assert main([*argv, "--resume"]) == 0
    assert (
        "iterations: pipeline Mask-ICP: kept from an earlier invocation" in capsys.readouterr().err
    )
    again = json.loads((tmp_path / "iterations.json").read_text())
    assert first["resumed_rows"] == 0 and again["resumed_rows"] == 2  # Mask-ICP, Mask-PointNetLK
    assert again["rows"] == first["rows"]


def test_benchmark_rewrites_a_results_page_only_when_one_is_named(tmp_path, monkeypatch):
    # A trial run from the repository root must leave docs/RESULTS.md as it is.
    import masknet.experiments

    monkeypatch.delenv("MASKNET_DATA", raising=False)
    handed = []
    monkeypatch.setattr(
        masknet.experiments,
        "run_experiments",
        lambda names, ctx, results, echo: handed.append(results),
    )
    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "RESULTS.md").write_text("# results\n")
    argv = ["benchmark", "registration", "--output", "bench", "--pairs", "5"]
    assert main(argv) == 0
    assert main([*argv, "--results", "docs/RESULTS.md"]) == 0
    assert main([*argv, "--quick", "--results", "docs/RESULTS.md"]) == 0
    assert handed == [None, Path("docs/RESULTS.md"), None]

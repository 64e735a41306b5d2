"""`masknet benchmark all --quick`: every experiment runs and writes readable output."""

from __future__ import annotations

import json
import math

import pytest

from masknet.cli import main
from masknet.evaluation.benchmark import EXPERIMENTS, markdown_table, update_results


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    mp = pytest.MonkeyPatch()
    mp.delenv("MASKNET_DATA", raising=False)  # the bundled sample, as in CI without data
    try:
        code = main(["benchmark", "all", "--quick", "--out", str(out), "--threads", "1"])
    finally:
        mp.undo()
    assert code == 0
    return out


@pytest.mark.parametrize("name", [n for n in EXPERIMENTS if n != "scans"])
def test_every_experiment_writes_a_table(quick_run, name):
    payload = json.loads((quick_run / f"{name}.json").read_text())
    assert payload["experiment"] == name and payload["quick"] is True
    assert payload["rows"] and payload["wall_time_s"] > 0
    numbers = [v for row in payload["rows"] for v in row.values() if isinstance(v, float)]
    assert numbers and all(math.isfinite(v) or math.isnan(v) for v in numbers)
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
    assert [r["round"] for r in rounds] == [1, 2, 3, 1, 2, 3]
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


def test_results_block_is_replaced_in_place(tmp_path):
    doc = tmp_path / "RESULTS.md"
    doc.write_text("# Results\n\nintro\n")
    update_results(doc, "demo", markdown_table([{"a": 1.0, "b": "x"}]))
    update_results(doc, "demo", markdown_table([{"a": 2.0, "b": "y"}]))
    text = doc.read_text()
    assert (
        text.count("<!-- benchmark:demo -->") == 1 and "| 2 | y |" in text and "| 1 |" not in text
    )
    assert text.startswith("# Results\n\nintro")


def test_run_experiments_skips_a_failing_one_and_records_wall_times(tmp_path, monkeypatch):
    from masknet.errors import MaskNetError
    from masknet.evaluation import benchmark

    def works(ctx):
        return benchmark.ExperimentResult([{"value": 1.5}], "a working experiment")

    def fails(ctx):
        raise MaskNetError("no such folder")

    monkeypatch.setattr(benchmark, "EXPERIMENTS", {"works": works, "fails": fails})
    doc = tmp_path / "RESULTS.md"
    doc.write_text("# Results\n")
    ctx = benchmark.BenchmarkContext(out=tmp_path / "out", command="masknet benchmark all")
    lines: list[str] = []
    log = benchmark.run_experiments(["fails", "works"], ctx, doc, echo=lines.append)
    assert [r["status"] for r in log] == ["skipped: no such folder", "done"]
    assert json.loads((tmp_path / "out" / "works.json").read_text())["rows"] == [{"value": 1.5}]
    text = doc.read_text()
    assert "<!-- benchmark:all -->" in text and "| works |" in text and "min in all" in text
    assert any("skipped" in line for line in lines)
    with pytest.raises(MaskNetError):  # a single experiment reports its own failure
        benchmark.run_experiments(["fails"], ctx, doc)


def test_benchmark_help_names_every_experiment(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "300")  # no line breaks inside hyphenated names
    with pytest.raises(SystemExit):
        main(["benchmark", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert all(name in text for name in EXPERIMENTS)

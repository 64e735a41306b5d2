"""`masknet benchmark all --quick`: every experiment runs and writes readable output."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from masknet.cli import main
from masknet.evaluation.benchmark import EXPERIMENTS, _csv_text, markdown_table, update_results


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


def test_resume_keeps_the_rows_an_interrupted_run_wrote(tmp_path, monkeypatch):
    from masknet.data import bundled_sample_path
    from masknet.evaluation import benchmark

    calls: list[int] = []

    def square(value: int, kill_at: int | None) -> dict:
        if value == kill_at:
            raise KeyboardInterrupt  # the run is killed while computing this row
        calls.append(value)
        return {"square": float(value**2)}

    def experiment(ctx, kill_at=None):
        rows = [ctx.row({"value": v}, square, v, kill_at) for v in range(4)]
        return benchmark.ExperimentResult(rows, "squares")

    monkeypatch.setattr(benchmark, "EXPERIMENTS", {"squares": experiment})
    doc = tmp_path / "RESULTS.md"
    doc.write_text("# Results\n")

    def context(resume, data=None):
        data = data or bundled_sample_path()
        return benchmark.BenchmarkContext(data=data, pairs=5, out=tmp_path, resume=resume)

    monkeypatch.setitem(benchmark.EXPERIMENTS, "squares", lambda ctx: experiment(ctx, kill_at=2))
    with pytest.raises(KeyboardInterrupt):
        benchmark.run_benchmark("squares", context(resume=False), doc)
    assert calls == [0, 1] and not (tmp_path / "squares.json").exists()
    with open(tmp_path / ".rows" / "squares.jsonl", "a") as f:
        f.write('{"id": "torn by the kill')  # a half-written line is ignored

    monkeypatch.setitem(benchmark.EXPERIMENTS, "squares", experiment)
    calls.clear()
    benchmark.run_benchmark("squares", context(resume=True), doc)
    payload = json.loads((tmp_path / "squares.json").read_text())
    assert calls == [2, 3]  # only the rows the kill lost
    lines = (tmp_path / ".rows" / "squares.jsonl").read_text().splitlines()
    assert [json.loads(line)["row"]["value"] for line in lines] == [0, 1, 2, 3]  # torn tail cut
    assert [r["square"] for r in payload["rows"]] == [0.0, 1.0, 4.0, 9.0]
    assert payload["resumed_rows"] == 2 and "2 rows kept from an interrupted" in doc.read_text()

    calls.clear()  # a fresh run (no --resume) recomputes everything
    benchmark.run_benchmark("squares", context(resume=False), doc)
    assert calls == [0, 1, 2, 3]
    assert json.loads((tmp_path / "squares.json").read_text())["resumed_rows"] == 0

    calls.clear()  # other test shapes: the kept rows do not apply
    other = tmp_path / "other.npz"
    with np.load(bundled_sample_path()) as sample:
        arrays = dict(sample)
    arrays["test_points"] = arrays["test_points"][::-1].copy()
    np.savez(other, **arrays)
    benchmark.run_benchmark("squares", context(resume=True, data=other), doc)
    assert calls == [0, 1, 2, 3]


def test_benchmark_resume_from_the_command_line(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("MASKNET_DATA", raising=False)
    argv = ["benchmark", "iterations", "--quick", "--out", str(tmp_path), "--threads", "1"]
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


def test_tables_leave_a_column_blank_where_a_row_lacks_it():
    rows = [{"a": 1.0}, {"a": 2.0, "b": 3}]
    assert markdown_table(rows).splitlines()[0] == "| a | b |"
    assert markdown_table(rows).splitlines()[2] == "| 1 |  |"
    assert _csv_text(rows).splitlines() == ["a,b", "1.0,", "2.0,3"]


def test_denoise_round_keeps_the_first_estimate_when_nothing_survives(monkeypatch):
    """A first registration far off leaves no source point near the template: the second
    round is skipped (and counted) instead of failing on an empty cloud."""
    import torch

    from masknet.data.pairs import Pairs
    from masknet.evaluation import benchmark

    rng = np.random.default_rng(0)
    template = rng.uniform(-1, 1, (2, 64, 3)).astype(np.float32)
    source = template[:, :40].copy()
    source[1] += 100.0  # the second pair's source is far from its template
    truth = np.tile(np.eye(4), (2, 1, 1))
    truth[1, :3, 3] = -100.0
    pairs = Pairs(
        torch.from_numpy(template),
        torch.from_numpy(source),
        torch.ones(2, 64, dtype=torch.bool),
        torch.from_numpy(truth).float(),
        torch.ones(2, 40, dtype=torch.bool),
    )
    calls = []

    class Identity:
        transform = np.eye(4)

    def fake_register(template, source, **kwargs):
        calls.append(len(source))
        return Identity()

    monkeypatch.setattr(benchmark, "register", fake_register)
    row = benchmark._register_denoise_register(pairs, {"method": "distance"}, {})
    assert row["second_pass_skipped"] == 1
    assert calls == [40, 40, 40]  # both first rounds, then only the first pair's second
    assert row["trans_mean"] == pytest.approx(50.0 * np.sqrt(3), rel=1e-4)

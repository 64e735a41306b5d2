"""Running experiments: skipping a failing one, and resuming from the row cache."""

from __future__ import annotations

import json

import numpy as np
import pytest

from masknet.experiments import BenchmarkContext, ExperimentResult


def test_run_experiments_skips_a_failing_one_and_records_wall_times(tmp_path, monkeypatch):
    from masknet.errors import MaskNetError
    from masknet.experiments import registry

    def works(ctx):
        return ExperimentResult([{"value": 1.5}], "a working experiment")

    def fails(ctx):
        raise MaskNetError("no such folder")

    monkeypatch.setattr(registry, "EXPERIMENTS", {"works": works, "fails": fails})
    doc = tmp_path / "RESULTS.md"
    doc.write_text("# Results\n")
    ctx = BenchmarkContext(out=tmp_path / "out", command="masknet benchmark all")
    lines: list[str] = []
    log = registry.run_experiments(["fails", "works"], ctx, doc, echo=lines.append)
    assert [r["status"] for r in log] == ["skipped: no such folder", "done"]
    assert json.loads((tmp_path / "out" / "works.json").read_text())["rows"] == [{"value": 1.5}]
    text = doc.read_text()
    assert "<!-- benchmark:all -->" in text and "| works |" in text and "min in all" in text
    assert any("skipped" in line for line in lines)
    with pytest.raises(MaskNetError):  # a single experiment reports its own failure
        registry.run_experiments(["fails"], ctx, doc)


def test_resume_keeps_the_rows_an_interrupted_run_wrote(tmp_path, monkeypatch):
    from masknet.data import bundled_sample_path
    from masknet.experiments import registry

    calls: list[int] = []

    def square(value: int, kill_at: int | None) -> dict:
        if value == kill_at:
            raise KeyboardInterrupt  # the run is killed while computing this row
        calls.append(value)
        return {"square": float(value**2)}

    def experiment(ctx, kill_at=None):
        rows = [ctx.row({"value": v}, square, v, kill_at) for v in range(4)]
        return ExperimentResult(rows, "squares")

    monkeypatch.setattr(registry, "EXPERIMENTS", {"squares": experiment})
    doc = tmp_path / "RESULTS.md"
    doc.write_text("# Results\n")

    def context(resume, data=None):
        data = data or bundled_sample_path()
        return BenchmarkContext(data=data, pairs=5, out=tmp_path, resume=resume)

    monkeypatch.setitem(registry.EXPERIMENTS, "squares", lambda ctx: experiment(ctx, kill_at=2))
    with pytest.raises(KeyboardInterrupt):
        registry.run_benchmark("squares", context(resume=False), doc)
    assert calls == [0, 1] and not (tmp_path / "squares.json").exists()
    with open(tmp_path / ".rows" / "squares.jsonl", "a") as f:
        f.write('{"id": "torn by the kill')  # a half-written line is ignored

    monkeypatch.setitem(registry.EXPERIMENTS, "squares", experiment)
    calls.clear()
    registry.run_benchmark("squares", context(resume=True), doc)
    payload = json.loads((tmp_path / "squares.json").read_text())
    assert calls == [2, 3]  # only the rows the kill lost
    lines = (tmp_path / ".rows" / "squares.jsonl").read_text().splitlines()
    assert [json.loads(line)["row"]["value"] for line in lines] == [0, 1, 2, 3]  # torn tail cut
    assert [r["square"] for r in payload["rows"]] == [0.0, 1.0, 4.0, 9.0]
    assert payload["resumed_rows"] == 2 and "2 rows kept from an interrupted" in doc.read_text()

    calls.clear()  # a fresh run (no --resume) recomputes everything
    registry.run_benchmark("squares", context(resume=False), doc)
    assert calls == [0, 1, 2, 3]
    assert json.loads((tmp_path / "squares.json").read_text())["resumed_rows"] == 0

    calls.clear()  # other test shapes: the kept rows do not apply
    other = tmp_path / "other.npz"
    with np.load(bundled_sample_path()) as sample:
        arrays = dict(sample)
    arrays["test_points"] = arrays["test_points"][::-1].copy()
    np.savez(other, **arrays)
    registry.run_benchmark("squares", context(resume=True, data=other), doc)
    assert calls == [0, 1, 2, 3]

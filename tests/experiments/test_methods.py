"""The method table is the one list of methods: the command line, the benchmark
(``masknet benchmark methods``) and docs/ARCHITECTURE.md list exactly its methods."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from masknet.registration.terms.methods import METHOD_TABLE

ROOT = Path(__file__).resolve().parents[2]


def _choices(parser, command: str, option: str) -> list[str]:
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    return list(next(a for a in sub._actions if option in a.option_strings).choices)


def test_the_command_line_offers_exactly_the_tables_methods():
    from masknet.cli import build_parser

    assert _choices(build_parser(), "register", "--method") == list(METHOD_TABLE)


def test_the_architecture_doc_lists_exactly_the_table():
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    rows = re.findall(
        r"^\| `([a-z0-9-]+)` \| (.+?) \| `(\w+)` \| `([\w/.]+):(\w+)` \| (\w+) \|$", text, re.M
    )
    assert [r[0] for r in rows] == list(METHOD_TABLE)
    for name, title, options, module, function, kind in rows:
        entry = METHOD_TABLE[name]
        assert (title, options, kind) == (entry.title, entry.options.__name__, entry.kind)
        assert entry.adapter.endswith(f"{module.removesuffix('.py').replace('/', '.')}:{function}")


def test_the_benchmark_runs_exactly_the_tables_methods(monkeypatch, scans_dir):
    """``masknet benchmark methods`` has one row per method and mask; register is replaced
    by a recorder here (the real run is in docs/RESULTS.md)."""
    from masknet.experiments import methods
    from masknet.experiments.context import BenchmarkContext
    from masknet.registration import api

    called = []

    class _Result:
        transform = np.eye(4)

    def recorder(template, source, *, method=None, use_mask=True, **_):
        called.append((method, use_mask))
        return _Result()

    monkeypatch.setattr(api, "register", recorder)
    monkeypatch.setenv("MASKNET_SCANS", str(scans_dir))
    result = methods.run(BenchmarkContext.__new__(BenchmarkContext))
    expected = [(m, mask) for m in METHOD_TABLE for mask in (False, True)]
    assert called[1:] == expected  # after one warm-up call
    assert [(r["method"], r["pipeline"].startswith("Mask-")) for r in result.rows] == expected
    # the identity is the 3DMatch pair's doing-nothing error, 17.8 degrees
    assert all(r["rot_error_deg"] == pytest.approx(17.8, abs=0.05) for r in result.rows)

"""masknet benchmark: its experiments are the registry's, and a wrong name is one line."""

from __future__ import annotations

import pytest

from masknet.cli import build_parser, main
from masknet.experiments.registry import EXPERIMENTS


def test_the_command_offers_exactly_the_registrys_experiments(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["benchmark", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    for name in EXPERIMENTS:
        assert name in shown


def test_an_unknown_experiment_is_refused_in_one_line(tmp_path, capsys):
    assert main(["benchmark", "no-such-thing", "--output", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no-such-thing" in err[0] and "registration" in err[0]

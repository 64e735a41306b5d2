"""Under CI a missing prerequisite (Open3D, Chromium, ../shared/data) fails the test that
needs it; elsewhere it skips. ``.ci/run`` sets ``CI=true``."""

from pathlib import Path

import pytest


def test_a_missing_prerequisite_skips_locally_and_fails_under_ci(skip_unless_ci, monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="no chromium"):
        skip_unless_ci("no chromium")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="no chromium; CI must run this test"):
        skip_unless_ci("no chromium")


def test_ci_script_sets_ci():
    script = (Path(__file__).parents[1] / ".ci" / "run").read_text()
    assert "export CI=true" in script

"""masknet.registration.many: many pairs in parallel give what one call at a time gives, in
order, a refused pair in its place; and the same on a local Dask cluster. The sources of
one template travel together, its views prepared once, and give the cold calls' poses. The README's call
works as written in a script, and a worker that dies stops the call."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from masknet import MaskNetError, register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.geometry.prepared_template import PreparedTemplate
from masknet.registration.many import register_many, source_jobs


@pytest.fixture(scope="module")
def pairs() -> list[tuple[np.ndarray, np.ndarray]]:
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:4]
    made = make_test_pairs(shapes, 4, PairConfig(), seed=8)
    return [(made.template[i].double().numpy(), made.source[i].double().numpy()) for i in range(4)]


def test_results_come_in_order_and_equal_single_calls(pairs, one_thread):
    bad = (pairs[0][0], np.full((10, 3), np.nan))
    results = register_many([*pairs, bad], workers=2, method="icp")
    assert len(results) == 5 and isinstance(results[4], MaskNetError)
    assert "NaN" in str(results[4])
    for (template, source), result in zip(pairs, results, strict=False):
        single = register(template, source, method="icp")
        np.testing.assert_allclose(result.transform, single.transform, atol=1e-9)


def test_a_local_dask_cluster_gives_the_same_results(pairs, one_thread):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        results = register_many(pairs, scheduler=cluster.scheduler_address, method="icp")
    for (template, source), result in zip(pairs, results, strict=True):
        single = register(template, source, method="icp")
        np.testing.assert_allclose(result.transform, single.transform, atol=1e-9)


ROOT = Path(__file__).resolve().parents[2]


def _readme_batch_block() -> str:
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)
    (block,) = [textwrap.dedent(b) for b in blocks if "register_many(" in b]
    return block


def test_the_readme_batch_runs_as_a_script(tmp_path):
    # As a user saves it: a pair, the README's lines as they are (no __main__ guard), a print.
    setup = """\
        from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs

        shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
        pair = make_test_pairs(shapes, 1, PairConfig(), seed=3)
        template, source = pair.template[0].double().numpy(), pair.source[0].double().numpy()
        """
    script = tmp_path / "script.py"
    script.write_text(
        textwrap.dedent(setup) + _readme_batch_block() + "print(len(results), len(poses))\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), OMP_NUM_THREADS="1")
    done = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split()[-2:] == ["2", "2"], (done.stdout, done.stderr[-2000:])
    assert "Traceback" not in done.stderr


class _KillsItsWorker:
    """A mask network that kills the process it runs in, as the out-of-memory killer would."""

    def predict_masks(self, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGKILL)


def test_a_killed_worker_stops_the_call(pairs, one_thread):
    with pytest.raises(MaskNetError, match="worker process of the batch stopped") as caught:
        register_many(pairs[:2], workers=1, method="icp", model=_KillsItsWorker())
    assert "\n" not in str(caught.value)


def test_spawned_workers_of_a_script_without_the_guard_say_what_to_add(tmp_path):
    # Where workers are spawned (macOS, Windows), they run the script again: the call
    # fails at once, in one line naming the guard, not pair by pair.
    script = tmp_path / "script.py"
    script.write_text(
        textwrap.dedent(
            """\
            import numpy as np
            import masknet.registration.many as many
            from masknet import MaskNetError, register_many

            many.start_method = lambda: "spawn"
            cloud = np.random.default_rng(0).normal(size=(64, 3))
            try:
                register_many([(cloud, cloud)], workers=1, method="icp")
            except MaskNetError as exc:
                print("refused:", exc)
            """
        )
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), OMP_NUM_THREADS="1")
    done = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    refused = [line for line in done.stdout.splitlines() if line.startswith("refused:")]
    assert len(refused) == 1, (done.stdout, done.stderr[-2000:])
    assert 'if __name__ == "__main__":' in refused[0]


@pytest.fixture(scope="module")
def one_template() -> tuple[np.ndarray, list[np.ndarray]]:
    """One bundled ModelNet40 shape and five partial, moved views of it."""
    shape = load_modelnet40(bundled_sample_path(), "test").points[1:2]
    made = make_test_pairs(np.repeat(shape, 5, 0), 5, PairConfig(), seed=5)
    return made.template[0].double().numpy(), list(made.source.double().numpy())


def test_one_template_for_many_sources_gives_the_cold_calls(one_template, one_thread):
    template, sources = one_template
    pooled = register_many([(template, s) for s in sources], workers=2)
    here = register_many([(template, s) for s in sources], workers=0)
    for source, a, b in zip(sources, pooled, here, strict=True):
        cold = register(template, source)
        for result in (a, b):
            np.testing.assert_array_equal(result.transform, cold.transform)
            np.testing.assert_array_equal(result.mask, cold.mask)
            assert result.info["path"] == cold.info["path"]


def test_the_sources_of_one_template_travel_together(one_template):
    template, sources = one_template
    other = template[::2].copy()
    pairs = [(template, s) for s in sources * 8] + [(other, sources[0])]
    jobs = source_jobs(pairs, {}, workers=2)
    shared = [job for job in jobs if isinstance(job.template, PreparedTemplate)]
    # 40 sources, 2 workers: jobs of 5 (4 jobs per worker), one template prepared once.
    assert [len(job.sources) for job in shared] == [5] * 8
    assert len({id(job.template) for job in shared}) == 1
    assert [n for job in jobs for n in job.names] == [str(i) for i in range(41)]
    assert jobs[-1].template is other and jobs[-1].names == ("40",)


def test_a_refused_shared_template_is_each_pairs_error(one_template):
    _, sources = one_template
    bad = np.full((10, 3), np.nan)
    results = register_many([(bad, s) for s in sources[:3]], workers=0)
    assert all(isinstance(r, MaskNetError) and "NaN" in str(r) for r in results)

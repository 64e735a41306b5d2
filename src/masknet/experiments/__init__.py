"""``masknet benchmark EXPERIMENT``: the paper's experiments, seeded, one module each.

Every experiment builds its pairs from the ModelNet40 test split with a seed,
runs the methods on the same pairs, and writes ``<out>/<experiment>.json``,
``.csv`` and ``.png``. With ``results=`` it also rewrites the experiment's block
in docs/RESULTS.md (between ``<!-- benchmark:NAME -->`` markers), so the
document always shows what the last run measured and the command that did it.

Every table row is also appended to ``<out>/.rows/<experiment>.jsonl`` as soon as it
is computed. ``--resume`` (``BenchmarkContext(resume=True)``) reads those rows back
instead of recomputing them, when their settings, the package version, the shipped
weights and the test shapes all match, so a full-size run killed after hours loses
at most the row in progress.

Registration methods run with the paper's budget (10 iterations) and the shipped
weights. Errors: rotation in degrees (angle of R_est^T R_true), translation as
||t_est - t_true|| in units of the unit-radius shapes.

Layout: :mod:`~masknet.experiments.context` (what an experiment gets and returns),
:mod:`~masknet.experiments.rows` (the resumable row cache),
:mod:`~masknet.experiments.pipelines` (the pipelines compared),
:mod:`~masknet.experiments.plots`, :mod:`~masknet.experiments.report` (tables and the
docs' blocks), :mod:`~masknet.experiments.registry` (the table of experiments and the
runner), and one module per experiment with ``run(ctx) -> ExperimentResult``. To add an
experiment: write its module and add it to ``EXPERIMENTS`` (and to the ``masknet
benchmark`` help).
"""

from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.registry import EXPERIMENTS, run_benchmark, run_experiments
from masknet.experiments.report import markdown_table, update_results

__all__ = [
    "EXPERIMENTS",
    "BenchmarkContext",
    "ExperimentResult",
    "markdown_table",
    "run_benchmark",
    "run_experiments",
    "update_results",
]

"""Many pairs at once: :func:`register_many`, in parallel on this machine's cores or on a
Dask cluster, results in order.

Each worker is a process with one thread (torch's, BLAS's and Open3D's), so ``workers``
processes use as many cores; the shipped networks load once per process and stay for every
pair it registers. A pair that fails (a bad file, a refusal) is recorded as its error, in
its place, and the others go on. With ``scheduler`` (``"tcp://host:8786"``, the ``cluster``
extra: ``pip install 'masknet[cluster]'``) the same jobs run on a Dask cluster's workers.

Example (as written in a script too, on Linux: see :func:`start_method`)::

    results = register_many([(model, scan) for scan in scans])
    poses = [r.transform for r in results if not isinstance(r, MaskNetError)]

One template for every source: give it prepared (:func:`masknet.prepare_template`), and
each worker computes its template-only views once, for every pair it registers (the
prepared template travels as its points and a token, once per job of up to
``CHUNK_SOURCES`` of its sources; a worker keeps the one it rebuilt). One (N, 3) array
given in every pair is prepared so too::

    prepared = masknet.prepare_template(model)
    results = register_many([(prepared, scan) for scan in scans])

A worker process that dies (killed, out of memory) stops the call with a
:class:`MaskNetError`: the pairs it held have no result to put in their place.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any, NamedTuple

import numpy as np

from masknet.errors import MaskNetError

__all__ = [
    "PairJob",
    "PairOutcome",
    "SourcesJob",
    "executor",
    "register_many",
    "run_jobs",
    "run_sources",
    "start_method",
]

# register_many sends the sources of one template to a worker this many at a time, at most:
# the template (and, in the worker, its prepared views and one BLAS limit) once per job
# rather than once per pair; fewer when the workers would otherwise get under 4 jobs each
# (the last job of a worker whose pairs escalate decides when the call ends).
CHUNK_SOURCES = 16


class PairJob(NamedTuple):
    """One pair: template and source as (N, 3) arrays or file paths, and its name."""

    name: str
    template: Any
    source: Any


class SourcesJob(NamedTuple):
    """Sources registered against one template: their names, the template (an (N, 3)
    array, a file path, or a prepared template) and the sources, in order."""

    names: tuple[str, ...]
    template: Any
    sources: tuple[Any, ...]


class PairOutcome(NamedTuple):
    """What became of a :class:`PairJob`: its result (None where it failed), the verdict
    of :func:`~masknet.registration.judge.assessment.assess_registration` and its reason, the
    error line of a failure (else ""), the seconds it took in its worker, and the warnings
    the pair raised (one line each)."""

    name: str
    result: Any
    verdict: str
    reason: str
    error: str
    seconds: float
    warnings: tuple[str, ...] = ()


def _one_thread() -> None:
    """A worker's initializer: one thread for every library in this process, Ctrl-C left to
    the parent (which stops the batch), so a worker prints no traceback, and an exit when
    the parent is gone."""
    import signal
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A worker whose parent was killed outright (SIGKILL, out of memory) would wait for work
    # forever, holding the terminal's pipes: it leaves once the parent is gone.
    parent = os.getppid()

    def leave_with_the_parent() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=leave_with_the_parent, daemon=True).start()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)


def run_job(job: PairJob, options: dict[str, Any]) -> PairOutcome:
    """Register one pair (reading its files first where it names them) and judge the
    result (one pair: its verdict; a batch in one job is not judged). A refusal, an
    unreadable file, or any other error is returned as the outcome's error, so that the
    other pairs go on; the pair's warnings come with it."""
    return _outcome(job.name, lambda: _register_and_judge(job, options))


def run_sources(job: SourcesJob, options: dict[str, Any]) -> list[PairOutcome]:
    """Register each source of ``job`` against its one template, in order, unjudged (the
    verdict is the command line's; :func:`register_many` returns the results alone): one
    outcome per source, as :func:`run_job` gives it, BLAS on one thread for the whole job."""
    from threadpoolctl import threadpool_limits

    from masknet.registration.api import register

    drop = bool(options.get("drop_nonfinite", False))

    def one(source: Any) -> tuple[Any, str, str]:
        return register(_cloud(job.template, drop), _cloud(source, drop), **options), "", ""

    with threadpool_limits(1):
        return [
            _outcome(name, lambda s=source: one(s))
            for name, source in zip(job.names, job.sources, strict=True)
        ]


def _outcome(name: str, work: Callable[[], tuple[Any, str, str]]) -> PairOutcome:
    """The outcome of one pair's ``work`` (its result, verdict and reason): an error is
    recorded in one line, and the pair's own warnings are kept."""
    import warnings

    from masknet.errors import MaskNetWarning

    tic = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MaskNetWarning)
        try:
            result, verdict, reason = work()
            error = ""
        except MaskNetError as exc:
            result, verdict, reason, error = None, "", "", str(exc)
        except Exception as exc:  # a bug or a resource, in one pair: recorded, not fatal
            result, verdict, reason, error = None, "", "", f"{type(exc).__name__}: {exc}"
    said = tuple(
        dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, MaskNetWarning))
    )
    return PairOutcome(name, result, verdict, reason, error, time.perf_counter() - tic, said)


def _cloud(cloud: Any, drop: bool) -> Any:
    """A pair's cloud as :func:`masknet.register` takes it: a prepared template as it is,
    a file read, anything else as a float64 array."""
    from masknet.geometry.clouds import points_of
    from masknet.geometry.prepared_template import PreparedTemplate
    from masknet.io import read_points

    if isinstance(cloud, PreparedTemplate):
        return cloud
    if isinstance(cloud, str | os.PathLike):
        return read_points(cloud, drop_nonfinite=drop)
    return np.asarray(points_of(cloud), dtype=np.float64)


def _register_and_judge(job: PairJob, options: dict[str, Any]) -> tuple[Any, str, str]:
    from threadpoolctl import threadpool_limits

    from masknet.geometry.prepared_template import PreparedTemplate
    from masknet.registration.api import register
    from masknet.registration.judge.assessment import assess_registration

    drop = bool(options.get("drop_nonfinite", False))
    with threadpool_limits(1):
        clouds = [_cloud(c, drop) for c in (job.template, job.source)]
        result = register(*clouds, **options)
        if result.transform.ndim != 2:
            return result, "", ""
        if isinstance(clouds[0], PreparedTemplate):  # checked: every row finite
            clouds[0] = clouds[0].points
        template, source = (c[np.isfinite(c).all(-1)] for c in clouds)
        if result.source_mask is not None:  # over every input row
            source = clouds[1][result.source_mask]
        check = assess_registration(template, source, result.transform)
    return result, check.verdict, check.reason


@contextmanager
def executor(workers: int | None = None, scheduler: str | None = None) -> Iterator[Executor]:
    """The executor of the jobs: ``workers`` processes of one thread each on this machine
    (default: one per core), or the workers of the Dask scheduler at ``scheduler``."""
    if scheduler is not None:
        from masknet._extras import need

        distributed = need("distributed", "cluster", "register-many --scheduler")
        with distributed.Client(scheduler) as client:
            yield client.get_executor()
        return
    import multiprocessing

    workers = workers or os.cpu_count() or 1
    context = multiprocessing.get_context(start_method())
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_one_thread) as pool:
        yield pool


def _main_is_reimported() -> bool:
    """Whether a spawned worker would run the caller's ``__main__`` again: a script file or
    a ``python -m`` module (an interactive interpreter or a notebook has neither)."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    return getattr(main, "__file__", None) is not None or getattr(spec, "name", None) is not None


def start_method() -> str:
    """How :func:`executor` starts its worker processes: ``"fork"`` or ``"spawn"``.

    "spawn" and "forkserver" start each worker by running the caller's ``__main__`` again,
    so a script that calls :func:`register_many` without an ``if __name__ == "__main__":``
    guard would start a pool in every worker (Python refuses it). "fork" copies the caller
    instead and runs nothing again, so the call works in a script as written. Forking is
    unsafe where another thread holds a lock at that moment: the pool forks every worker
    before its own threads start, and the idle pools of torch (OpenMP) and Open3D do not
    hold one (a caller that had run torch on 2 OpenMP threads, Open3D's ICP, RANSAC and FGR
    and the robust pipeline, 6 threads in all, then forked the pool: every pair registered
    in 6 of 6 runs, the shipped networks already loaded). So: "fork" where the caller's
    ``__main__`` would run again, on Linux, and CUDA has not started (a forked child
    cannot use it); "spawn" elsewhere: in an interactive interpreter (nothing runs again),
    on macOS and Windows (fork is unsafe or absent; a script there needs the guard, and a
    pool that breaks says so)."""
    import multiprocessing

    if (
        not sys.platform.startswith("linux")
        or "fork" not in multiprocessing.get_all_start_methods()
    ):
        return "spawn"
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_initialized():
        return "spawn"
    return "fork" if _main_is_reimported() else "spawn"


def _broken(exc: BaseException) -> MaskNetError:
    """The error of a call whose pool failed: one line, with the guard a spawned worker
    needs where a dead worker is likely to have died of it."""
    from concurrent.futures import BrokenExecutor

    from masknet.errors import first_line

    if not isinstance(exc, BrokenExecutor):  # e.g. an option that cannot be sent (pickled)
        return MaskNetError(f"the batch stopped: {type(exc).__name__}: {first_line(str(exc))}")
    line = f"a worker process of the batch stopped before it finished ({type(exc).__name__})"
    if start_method() == "spawn" and _main_is_reimported():
        line += (
            "; the workers run this script again: call register_many under "
            '`if __name__ == "__main__":`'
        )
    return MaskNetError(line + "; no result is returned for the batch")


def run_jobs(
    jobs: Iterable[PairJob],
    options: dict[str, Any],
    pool: Executor,
    done: Callable[[PairOutcome], None] | None = None,
) -> list[PairOutcome]:
    """Run ``jobs`` on ``pool``; ``done`` sees each outcome as it finishes (in finishing
    order); returns the outcomes in the jobs' order. On Ctrl-C the jobs not started are
    cancelled and KeyboardInterrupt propagates. A pair's own failure is its outcome's
    error; a worker that dies (a broken pool) raises :class:`MaskNetError` for the call."""
    return _gather(pool, run_job, list(jobs), options, done)


def _gather(
    pool: Executor,
    runner: Callable[[Any, dict[str, Any]], Any],
    jobs: list,
    options: dict[str, Any],
    done: Callable[[Any], None] | None = None,
) -> list:
    """``runner(job, options)`` for each of ``jobs`` on ``pool``; ``done`` sees each answer
    as it comes; the answers in the jobs' order. Ctrl-C cancels the jobs not started; a
    worker that dies raises :class:`MaskNetError` for the call."""
    futures: dict[Future, int] = {}
    try:
        for index, job in enumerate(jobs):
            futures[pool.submit(runner, job, options)] = index
        answers: list[Any] = [None] * len(jobs)
        for future in as_completed(futures):
            try:
                answer = future.result()
            except Exception as exc:  # the worker itself died: no pair failed, the call did
                raise _broken(exc) from exc
            answers[futures[future]] = answer
            if done is not None:
                done(answer)
    except BaseException:
        for future in futures:
            future.cancel()
        raise
    return answers


def _shares(template: Any) -> bool:
    """Whether pairs holding this very template object are sent as one template's sources:
    a prepared template, or one (N, 3) array."""
    from masknet.geometry.prepared_template import PreparedTemplate

    return isinstance(template, PreparedTemplate) or (
        isinstance(template, np.ndarray) and template.ndim == 2
    )


def _prepared(template: Any, options: dict[str, Any]) -> Any:
    """A template that several pairs share, prepared once (its views computed once per
    worker, the results those of cold calls) and kept for the workers forked after (those
    built here so far travel with them); as it is where ``drop_nonfinite`` may drop its
    rows, or where it is refused (each pair then says so)."""
    from masknet.geometry.prepared_template import prepare_template, share_with_workers

    if options.get("drop_nonfinite", False):
        return template
    try:
        return share_with_workers(prepare_template(template))
    except MaskNetError:
        return template


def source_jobs(
    pairs: list[tuple[Any, Any]], options: dict[str, Any], workers: int | None
) -> list[SourcesJob]:
    """The pairs as jobs, each pair named by its place: pairs that hold the same template
    object (:func:`_shares`) go together, the template prepared once, in jobs of at most
    ``CHUNK_SOURCES`` sources (fewer where ``workers`` would get under 4 jobs each); every
    other pair is a job of its own."""
    groups: dict[Any, list[int]] = {}
    for index, (template, _) in enumerate(pairs):
        key = id(template) if _shares(template) else ("pair", index)
        groups.setdefault(key, []).append(index)
    per_worker = 4 * (workers or os.cpu_count() or 1)
    jobs = []
    for rows in groups.values():
        template = pairs[rows[0]][0]
        if len(rows) > 1:
            template = _prepared(template, options)
        size = max(1, min(CHUNK_SOURCES, -(-len(rows) // per_worker)))
        for start in range(0, len(rows), size):
            part = rows[start : start + size]
            names = tuple(str(i) for i in part)
            jobs.append(SourcesJob(names, template, tuple(pairs[i][1] for i in part)))
    return jobs


def register_many(
    pairs: Iterable[tuple[Any, Any]],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    **options: Any,
) -> list[Any]:
    """Register every (template, source) pair, in parallel; the results in order.

    Args:
        pairs: (template, source) clouds, (N, 3) and (M, 3) arrays or file paths (read
            with :func:`masknet.io.read_points` in the worker); a template may be a
            :class:`~masknet.geometry.prepared_template.PreparedTemplate`, prepared once
            per worker for all its pairs. Pairs that hold the same template object (one
            prepared template, or one (N, 3) array, which is then prepared here once) go
            to the workers together, ``CHUNK_SOURCES`` sources at a time at most.
        workers: processes on this machine, one thread each (default: one per core); 0
            registers the pairs here, one after another (BLAS on one thread, as a worker).
        scheduler: a Dask scheduler's address to run on instead (``masknet[cluster]``).
        **options: :func:`masknet.register`'s keywords, the same for every pair.

    Returns:
        One entry per pair, in order: its :class:`RegistrationResult`, or the
        :class:`MaskNetError` that refused it (the other pairs go on). The results are
        not judged here (``masknet register-many`` gives each pair's verdict).

    Raises:
        MaskNetError: a worker process died (killed, out of memory, or, where workers are
            spawned, a script without an ``if __name__ == "__main__":`` guard).
    """
    pairs = list(pairs)
    jobs = source_jobs(pairs, options, workers)
    if workers == 0 and scheduler is None:
        answers = [run_sources(job, options) for job in jobs]
    else:
        with executor(workers, scheduler) as pool:
            answers = _gather(pool, run_sources, jobs, options)
    outcomes: list[Any] = [None] * len(pairs)
    for outcome in (o for answer in answers for o in answer):
        outcomes[int(outcome.name)] = outcome
    return [o.result if not o.error else MaskNetError(o.error) for o in outcomes]


def transform_text(transform: np.ndarray) -> str:
    """A 4x4 transform as ``masknet register`` writes it (``np.loadtxt`` reads it)."""
    header = "# source -> template: template ~= R @ source + t, [[R, t], [0, 0, 0, 1]]"
    return header + "\n" + "\n".join(" ".join(f"{v:.10g}" for v in row) for row in transform) + "\n"

"""What every experiment gets (:class:`BenchmarkContext`) and returns (:class:`ExperimentResult`)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from masknet.data.modelnet import PointCloudSet, load_modelnet40
from masknet.data.pairs import PairConfig, Pairs, make_test_pairs
from masknet.experiments import rows as row_cache

__all__ = ["BenchmarkContext", "ExperimentResult"]


@dataclass
class BenchmarkContext:
    """What every experiment gets: test shapes (loaded on first use), seed, size, output."""

    data: str | os.PathLike | None = None  # ModelNet40 path; None: $MASKNET_DATA
    pairs: int = 1000
    seed: int = 0
    quick: bool = False
    out: Path = Path("masknet_benchmark")
    progress: bool = True
    command: str = ""
    resume: bool = False  # keep the rows an interrupted invocation already computed
    experiment: str = ""  # set by run_benchmark: the experiment whose rows row() records
    reused: dict[str, float] = field(default_factory=lambda: {"rows": 0, "seconds": 0.0})
    # called with one line per table row computed or kept: a log's only sign of life in a
    # long experiment when stderr is not a terminal (no progress bars)
    log: Callable[[str], None] | None = None
    _test: PointCloudSet | None = None
    _fingerprint: str | None = None
    _kept: dict[str, dict] | None = None

    @property
    def test_set(self) -> PointCloudSet:
        if self._test is None:
            self._test = load_modelnet40(self.data, "test")
        return self._test

    @property
    def points(self) -> np.ndarray:
        """(S, N, 3) ModelNet40 test shapes."""
        return self.test_set.points

    @property
    def categories(self) -> np.ndarray:
        """(S,) category index of each test shape."""
        return self.test_set.labels

    def test_pairs(self, config: PairConfig | None = None, count: int | None = None) -> Pairs:
        """Seeded test pairs: ``count`` (default :attr:`pairs`) of ``config`` (default
        :class:`PairConfig`)."""
        return make_test_pairs(self.points, count or self.pairs, config or PairConfig(), self.seed)

    @property
    def fingerprint(self) -> str:
        """A digest of what a row depends on beyond its key: the package version, every
        shipped weight file and the test shapes."""
        if self._fingerprint is None:
            self._fingerprint = row_cache.fingerprint(self.points)
        return self._fingerprint

    @property
    def rows_file(self) -> Path:
        """``<out>/.rows/<experiment>.jsonl``: every row computed, one JSON line each."""
        return self.out / ".rows" / f"{self.experiment}.jsonl"

    def start_experiment(self, name: str) -> None:
        """Point :meth:`row` at ``name``; without ``resume``, forget its earlier rows."""
        self.experiment, self._kept = name, None
        self.reused = {"rows": 0, "seconds": 0.0}
        if not self.resume:
            self.rows_file.unlink(missing_ok=True)

    def row(self, key: dict, compute: Callable[..., dict], *args: object, **kwargs: object) -> dict:
        """One table row, ``{**key, **compute(*args, **kwargs)}``.

        The row is appended to :attr:`rows_file` as soon as it is computed. With
        ``resume``, a row recorded there for the same key, pairs, seed, quick flag and
        :attr:`fingerprint` is read back instead of computed, so a killed run, restarted
        with ``--resume``, loses at most the row it was computing.
        """
        ident = row_cache.row_id(key, self.pairs, self.seed, self.quick, self.fingerprint)
        if self.resume:
            if self._kept is None:
                self._kept = row_cache.read_rows(self.rows_file)
            kept = self._kept.get(ident)
            if kept is not None:
                self.reused["rows"] += 1
                self.reused["seconds"] += kept["seconds"]
                self._log_row(key, "kept from an earlier invocation")
                return kept["row"]
        tic = time.perf_counter()
        row = {**key, **compute(*args, **kwargs)}
        entry = {"id": ident, "seconds": time.perf_counter() - tic, "row": row}
        row_cache.append_row(self.rows_file, entry)
        self._log_row(key, f"{entry['seconds']:.0f} s")
        return row

    def _log_row(self, key: dict, how: str) -> None:
        if self.log is not None:
            what = ", ".join(f"{k} {v}" for k, v in key.items())
            self.log(f"{self.experiment}: {what}: {how}")


@dataclass
class ExperimentResult:
    """A table (list of rows with the same keys), a plot, and a few lines of context."""

    rows: list[dict]
    summary: str
    plot: Callable[[Path], None] | None = None


def median_time(
    call: Callable[[], Any], repeats: int, repeat_below_s: float = float("inf")
) -> tuple[Any, float]:
    """``call()``'s first result and the median seconds of up to ``repeats`` calls: the
    first call alone where it takes ``repeat_below_s`` or longer (a long call is timed
    once; a single call of a fraction of a second moves by a fifth between calls)."""
    tic = time.perf_counter()
    result = call()
    seconds = [time.perf_counter() - tic]
    while seconds[0] < repeat_below_s and len(seconds) < repeats:
        tic = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - tic)
    return result, float(np.median(seconds))

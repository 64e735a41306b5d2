"""A template prepared once for many sources: :func:`prepare_template` and
:class:`PreparedTemplate`.

Registering many sources against one template repeats everything that depends on the
template alone: its place in the call's frame, its farthest-point sample for the
networks, the fit's even subset with its KD-tree and spacing, the verdict's subset and
tree, the measure of its shape, the consensus front end's grids, normals and FPFH
features, and the mask network's per-point template encoding. A
:class:`PreparedTemplate` computes each of these on first use and keeps it, keyed by
every parameter that determines it (a voxel edge, a point budget, a seed, the frame's
rounding, the network's weights and precision): a view built under one key is never
served under another, so a call with the prepared template returns what a cold call
returns, array for array.

Example::

    prepared = masknet.prepare_template(template)        # (N, 3), checked once
    results = [masknet.register(prepared, s) for s in sources]
    results = masknet.register_many([(prepared, s) for s in sources])

How the views reach the stages: :func:`masknet.register` makes the prepared template
*active* for the call (:func:`active`), and a stage that holds a template array asks
:func:`template_view` for a view of it. The view is served from the cache only where the
array is one the prepared template handed out itself (the same memory, shape and
strides: its arrays are read-only, so the same memory holds the same points); any other
array, or no active template, builds the view as a cold call does.
"""

from __future__ import annotations

import contextlib
import threading
import uuid
from collections.abc import Callable, Hashable, Iterator
from contextvars import ContextVar
from typing import Any, TypeVar

import numpy as np

__all__ = [
    "PreparedTemplate",
    "active",
    "prepare_template",
    "share_with_workers",
    "template_view",
    "using",
]

View = TypeVar("View")
_NOT_BUILT = object()
# Prepared templates rebuilt in this process from a pickle (a register_many worker), by
# token: a worker keeps one per template for every job that brings it, not one per job.
# register_many keeps its templates here before its workers fork, views and all.
KEPT_IN_WORKER = 4
# Views kept per prepared template, at most: those keyed by the template's own parameters
# are a handful; those keyed by a source's (the consensus front end's voxel edge, set by
# both clouds' spacings) would otherwise grow with every source.
MAX_VIEWS = 64
_ACTIVE: ContextVar[PreparedTemplate | None] = ContextVar("masknet_prepared", default=None)


def _frozen(points: np.ndarray) -> np.ndarray:
    out = np.array(points, dtype=np.float64, copy=True)
    out.flags.writeable = False
    return out


def _frozen_view(view: View) -> View:
    """``view`` with its arrays (itself, or the fields of a tuple) made read-only: a stage
    that wrote into a shared view would change the next call's answer, and now raises."""
    for part in view if isinstance(view, tuple) else (view,):
        if isinstance(part, np.ndarray) and part.flags.writeable:
            part.flags.writeable = False
    return view


def _memory(array: np.ndarray) -> tuple:
    """Where ``array``'s values lie: its first byte, shape and strides."""
    return array.__array_interface__["data"][0], array.shape, array.strides


class PreparedTemplate:
    """A template (N, 3), float64, checked once, with its template-only views cached.

    Build it with :func:`prepare_template`. ``points`` is the checked cloud (read-only);
    ``views`` the number of views built so far; ``hits`` the number of times a view was
    served from the cache. Thread-safe: one lock guards the cache (a view is built at most
    once per key)."""

    def __init__(self, points: np.ndarray, token: str | None = None) -> None:
        self.points = _frozen(points)
        self.token = token or uuid.uuid4().hex
        self._views: dict[Hashable, Any] = {}
        self._known: dict[tuple, Hashable] = {}
        self._lock = threading.RLock()
        self.hits = 0
        self.remember(self.points, "points")

    def __repr__(self) -> str:
        return f"PreparedTemplate({len(self.points)} points, {len(self._views)} views cached)"

    def __len__(self) -> int:
        return len(self.points)

    def __reduce__(self) -> tuple:
        # Only the points and the token travel: the views are rebuilt where they are used.
        return _restored, (self.token, np.asarray(self.points))

    @property
    def views(self) -> int:
        return len(self._views)

    def remember(self, array: np.ndarray, name: Hashable) -> np.ndarray:
        """Mark ``array`` (one this template handed out, read-only) as ``name``: views of
        it are then served from the cache. Returns the array."""
        if array.flags.writeable:
            array.flags.writeable = False
        with self._lock:
            self._known[_memory(array)] = name
        return array

    def name_of(self, array: np.ndarray) -> Hashable | None:
        """The name under which ``array`` was handed out, or None (another array)."""
        if not isinstance(array, np.ndarray):
            return None
        return self._known.get(_memory(array))

    def view(
        self, key: Hashable, build: Callable[[], View], hands_out: Hashable | None = None
    ) -> View:
        """The view ``key``: ``build()`` on first use, then the same object. Once
        ``MAX_VIEWS`` are kept (views keyed by a source's parameters, as a voxel edge,
        accumulate), a new one is built as a cold call builds it and not kept.
        ``hands_out``: the view is a template array, remembered under this name."""
        with self._lock:
            found = self._views.get(key, _NOT_BUILT)
            if found is not _NOT_BUILT:
                self.hits += 1
                return found
            found = build()
            if len(self._views) >= MAX_VIEWS:
                return found
            self._views[key] = _frozen_view(found)
            if hands_out is not None:
                _remember_batch(self, found, hands_out)
            return found

    def frame_points(self, key: Hashable, build: Callable[[], np.ndarray]) -> np.ndarray:
        """The template in a call's frame (``key``: the frame's parameters), (N, 3) or
        (1, N, 3), built once and remembered, so the stages' views of it are cached."""
        return self.view(("frame", key), build, hands_out=("frame", key))


_WORKER: dict[str, PreparedTemplate] = {}
_WORKER_LOCK = threading.Lock()


def share_with_workers(prepared: PreparedTemplate) -> PreparedTemplate:
    """Keep ``prepared`` in this process's registry of rebuilt templates (the last
    ``KEPT_IN_WORKER``), so that a worker forked from this process after it finds it there,
    with every view built here so far, instead of building them again."""
    with _WORKER_LOCK:
        _WORKER[prepared.token] = prepared
        while len(_WORKER) > KEPT_IN_WORKER:
            _WORKER.pop(next(iter(_WORKER)))
    return prepared


def _restored(token: str, points: np.ndarray) -> PreparedTemplate:
    """A pickled prepared template in this process: the one already rebuilt for this
    token (its views kept), else a new one (the last ``KEPT_IN_WORKER`` are kept)."""
    with _WORKER_LOCK:
        found = _WORKER.get(token)
        if found is None or found.points.shape != points.shape:
            found = _WORKER[token] = PreparedTemplate(points, token)
            while len(_WORKER) > KEPT_IN_WORKER:
                _WORKER.pop(next(iter(_WORKER)))
        return found


def prepare_template(template: Any) -> PreparedTemplate:
    """The template (N, 3) (an array, or an Open3D point cloud), checked once and prepared
    for many :func:`masknet.register` calls (and :func:`masknet.register_many`,
    :class:`masknet.Tracker`): each view that depends on the template alone is computed
    on first use and reused; the results are those of the cold calls.

    Raises:
        MaskNetError: a cloud :func:`masknet.io_checks.check_cloud` refuses (one line).
    """
    from masknet.errors import MaskNetError
    from masknet.io_checks import check_cloud

    if isinstance(template, PreparedTemplate):
        return template
    if np.ndim(template) == 3:
        raise MaskNetError(
            f"prepare_template takes one template, (N, 3); got a batch of shape "
            f"{np.shape(template)}"
        )
    points, _ = check_cloud(template, "template")
    return PreparedTemplate(points)


def active() -> PreparedTemplate | None:
    """The prepared template of the call running in this context, or None."""
    return _ACTIVE.get()


@contextlib.contextmanager
def using(prepared: PreparedTemplate | None) -> Iterator[None]:
    """Make ``prepared`` the active template (None: none) for the ``with`` block."""
    reset = _ACTIVE.set(prepared)
    try:
        yield
    finally:
        _ACTIVE.reset(reset)


def template_view(
    template: np.ndarray, key: Hashable, build: Callable[[], View], hands_out: bool = False
) -> View:
    """The view ``key`` of ``template``: from the active prepared template's cache where
    it handed this array out, else ``build()`` (a cold call's view). ``hands_out``: the
    view is itself a template array (B, N, 3) or (N, 3) that later stages take views of
    (a sample of it): it is remembered, with its first pair where it is a batch."""
    prepared = _ACTIVE.get()
    name = None if prepared is None else prepared.name_of(template)
    if name is None:
        return build()
    return prepared.view((name, key), build, (name, key) if hands_out else None)


def _remember_batch(prepared: PreparedTemplate, array: np.ndarray, name: Hashable) -> np.ndarray:
    """Remember ``array`` as ``name`` and, where it is a batch of one (1, N, 3), its pair
    (N, 3) as well (``array[0]``: the same memory, another shape)."""
    prepared.remember(array, name)
    if array.ndim == 3 and array.shape[0] == 1:
        prepared.remember(array[0], (name, 0))
    return array

"""Stage 1 of the default (:mod:`masknet.registration.stages.auto`): the pair's route,
sparse by size, or a scan or an object as
:func:`~masknet.registration.judge.shape.classify_template` measures the template
(docs/ARCHITECTURE.md, "The routing table"), and the principal axes' gate that sends a
turned object to the search first."""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from masknet.geometry.clouds import principal_turn_deg
from masknet.geometry.prepared_template import template_view
from masknet.registration.judge.shape import PairShape, classify_template
from masknet.registration.terms.options import RobustOptions

__all__ = ["Route", "turned_first"]


class Route(NamedTuple):
    """Stage 1 of the default: the pair's class. ``sparse``: a template under
    ``consensus_below`` points; ``shape``: the template's measured class
    (:func:`~masknet.registration.judge.shape.classify_template`), None until measured
    (templates between the sizes are measured once the fast path failed); ``on``: the
    consensus front end is (``consensus_points`` > 0)."""

    sparse: bool
    shape: PairShape | None
    on: bool

    @classmethod
    def first(cls, template: np.ndarray, options: RobustOptions, times: dict) -> Route:
        """The route before any stage: sparse by size; templates of ``consensus_from``
        points or more measured now (a scan's front end comes before the fast path)."""
        route = cls(options.is_sparse(len(template)), None, options.consensus_points > 0)
        if options.is_scan(len(template)):
            return route.measured(template, options, times)
        return route

    def measured(self, template: np.ndarray, options: RobustOptions, times: dict) -> Route:
        """This route with the template's shape measured (``times["route"]``)."""
        if self.sparse:
            return self
        tic = time.perf_counter()
        large = options.is_scan(len(template))
        shape = template_view(
            template, ("shape", large), lambda: classify_template(template, large=large)
        )
        times["route"] = times.get("route", 0.0) + time.perf_counter() - tic
        return self._replace(shape=shape)

    @property
    def scan(self) -> bool:
        """A scan's route: measured as one (sparse templates are not measured)."""
        return self.shape is not None and self.shape.kind == "scan"

    @property
    def dense_object(self) -> bool:
        """An object's route: not sparse, not measured as a scan (the fast path's object
        accept level and the principal axes' gate)."""
        return not self.sparse and not self.scan


def turned_first(
    template: np.ndarray, source: np.ndarray, options: RobustOptions, route: Route
) -> bool:
    """Whether an object's pair goes to the search first: its principal axes turned
    ``search_first_turn_deg`` or more. On 100 ModelNet40 pairs turned up to 180 degrees the
    fast path held on 23 and was paid for before the search on the rest; the axes flagged
    50, of which the fast path would have held 2."""
    turn = options.search_first_turn_deg
    if turn is None or not route.dense_object:
        return False
    return principal_turn_deg(template, source) >= turn

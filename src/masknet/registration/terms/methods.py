"""The method table: every method :func:`masknet.register` runs, in one place.

Each entry gives a method's name, its title (X of "Mask-X"), its adapter (imported when
first used, so that this module, and the command line's choices, need no torch), its
typed options, its default ``max_iterations`` and whether ``init`` applies. The facade,
the command line, the benchmark and the docs all read it; a test checks that they list
exactly its methods.

To add a method: write an adapter module under :mod:`masknet.registration.solvers.backends`
(``(template, source, template_mask, source_mask, options) -> BackendRun``, see
:mod:`~masknet.registration.solvers.backends.base`), give it an options class in
:mod:`~masknet.registration.terms.options`, and add one :class:`Method` below.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from typing import Any, NamedTuple

from masknet.registration.terms.options import (
    FGROptions,
    ICPCriteria,
    NetworkOptions,
    Open3DICPOptions,
    PointNetLKOptions,
    RANSACOptions,
    RobustOptions,
)

__all__ = [
    "GLOBAL_METHODS",
    "INITS",
    "METHODS",
    "METHOD_TABLE",
    "METHOD_TITLES",
    "NETWORK_METHODS",
    "PIPELINES",
    "Method",
    "adapter",
    "check_pipeline_keywords",
    "default_method",
    "method_options",
]


class Method(NamedTuple):
    """One entry of :data:`METHOD_TABLE`.

    name: what ``register(method=...)`` and ``masknet register --method`` take.
    title: the display name, X of "Mask-X".
    adapter: ``"module:function"``, imported on first use. A back-end's adapter runs one
        round on a batch (:data:`~masknet.registration.solvers.backends.base.Backend`); a
        pipeline's runs a whole call at full resolution
        (:data:`~masknet.registration.solvers.backends.base.Pipeline`).
    options: its typed options class (:mod:`masknet.registration.terms.options`).
    default_iterations: ``max_iterations`` when none is given (None: the options' own).
    uses_init: whether ``init`` (the centroid start) matters; False for global registration,
        which searches every pose and has no iteration budget (:data:`GLOBAL_METHODS`,
        which the command line reads).
    kind: ``"backend"`` (runs inside the rounds), ``"network"`` (a learned back-end, the
        shipped weights by default) or ``"pipeline"`` (a whole coarse-to-fine call).
    """

    name: str
    title: str
    adapter: str
    options: type
    default_iterations: int | None
    uses_init: bool
    kind: str


_BACKENDS = "masknet.registration.solvers.backends"
METHOD_TABLE: dict[str, Method] = {
    m.name: m
    for m in (
        Method("auto", "ICP (auto)", "masknet.registration.stages.auto:auto_register", RobustOptions, None, False, "pipeline"),
        Method("icp", "ICP", f"{_BACKENDS}.icp:run_icp", ICPCriteria, 10, True, "backend"),
        Method("robust", "ICP (robust)", "masknet.registration.stages.robust:robust_register", RobustOptions, None, False, "pipeline"),
        Method("open3d-icp", "Open3D-ICP", f"{_BACKENDS}.icp:run_open3d_icp", Open3DICPOptions, 10, True, "backend"),
        Method("pointnetlk", "PointNetLK", f"{_BACKENDS}.network:run_network", PointNetLKOptions, 10, True, "network"),
        Method("dcp", "DCP", f"{_BACKENDS}.network:run_network", NetworkOptions, 1, True, "network"),
        Method("prnet", "PRNet", f"{_BACKENDS}.network:run_network", NetworkOptions, 3, True, "network"),
        Method("pcrnet", "PCRNet", f"{_BACKENDS}.network:run_network", NetworkOptions, 8, True, "network"),
        Method("rpmnet", "RPM-Net", f"{_BACKENDS}.network:run_network", NetworkOptions, 5, True, "network"),
        Method("open3d-ransac", "Open3D-RANSAC", f"{_BACKENDS}.open3d_global:run_ransac", RANSACOptions, None, False, "backend"),
        Method("open3d-fgr", "Open3D-FGR", f"{_BACKENDS}.open3d_global:run_fgr", FGROptions, None, False, "backend"),
    )
}  # fmt: skip

# Views of the table, for the places that need one list.
METHODS = tuple(METHOD_TABLE)
METHOD_TITLES = {name: m.title for name, m in METHOD_TABLE.items()}
NETWORK_METHODS = tuple(name for name, m in METHOD_TABLE.items() if m.kind == "network")
PIPELINES = tuple(name for name, m in METHOD_TABLE.items() if m.kind == "pipeline")
# Global registration: no iteration budget, no init.
GLOBAL_METHODS = tuple(
    name for name, m in METHOD_TABLE.items() if m.kind == "backend" and not m.uses_init
)
INITS = ("centroid", "identity")


def adapter(name: str) -> Callable[..., Any]:
    """The adapter of method ``name``, imported on first use."""
    module, function = METHOD_TABLE[name].adapter.split(":")
    return getattr(importlib.import_module(module), function)


# Open3D's names for the same options (ICPConvergenceCriteria's ``max_iteration``), taken
# as the masknet name: ``max_iterations`` stays masknet's, as in PyTorch3D's
# ``iterative_closest_point(max_iterations=...)``.
OPEN3D_NAMES = {"max_iteration": "max_iterations"}


def open3d_spelling(keywords: dict[str, Any]) -> dict[str, Any]:
    """``keywords`` with Open3D's names (:data:`OPEN3D_NAMES`) as masknet's; MaskNetError
    when both spellings of one option are given."""
    from masknet.errors import MaskNetError

    out = dict(keywords)
    for theirs, ours in OPEN3D_NAMES.items():
        if theirs in out:
            if ours in out:
                raise MaskNetError(f"give {ours} or {theirs} (Open3D's name), not both")
            out[ours] = out.pop(theirs)
    return out


def method_options(name: str, given: Any | None, keywords: dict[str, Any]) -> Any:
    """Method ``name``'s typed options: ``given`` (an instance of its options class, or
    None) with ``keywords`` (its fields, spelled inline) set, checked on construction.
    MaskNetError for an unknown field, a wrong options class, or a field given twice."""
    from masknet.errors import MaskNetError
    from masknet.registration.terms.options import as_dict

    kind = METHOD_TABLE[name].options
    keywords = open3d_spelling(keywords)
    if given is not None and type(given) is not kind:
        raise MaskNetError(
            f"method {name!r} takes options={kind.__name__}(...), got {type(given).__name__}"
        )
    fields = as_dict(kind()) if given is None else as_dict(given)
    unknown = sorted(set(keywords) - set(fields))
    if unknown:
        raise MaskNetError(
            f"unknown option(s) for method {name!r}: {', '.join(unknown)}{_takers(unknown)} "
            f"(accepted: {', '.join(fields)})"
        )
    if given is not None and keywords:
        raise MaskNetError(
            f"give options={kind.__name__}(...) or its fields as keywords "
            f"({', '.join(sorted(keywords))}), not both"
        )
    options = kind(**keywords) if given is None else given
    default = METHOD_TABLE[name].default_iterations
    if "max_iterations" in fields and options.max_iterations is None and default is not None:
        options = dataclasses.replace(options, max_iterations=default)  # the table's
    return options


def _takers(names: list[str]) -> str:
    """Where the methods that take option ``names`` are, for a refusal: ``"; it applies to
    method="icp", ...: name the method to use it"``, or "" where none does."""
    takers = [m for m, entry in METHOD_TABLE.items() if set(names) <= _fields(entry.options)]
    if not takers:
        return ""
    listed = ", ".join(f'"{m}"' for m in takers)
    return f"; {'it applies' if len(names) == 1 else 'they apply'} to method={listed}: name it"


def _fields(kind: type) -> set[str]:
    return {f.name for f in dataclasses.fields(kind)}


def default_method(method: str | None, options: Any | None) -> str:
    """``method``, or for None the default: the method whose options class ``options`` is
    (``ICPCriteria`` -> ``"icp"``), else ``"auto"``. The other arguments never choose the
    method: one that the default does not take is refused
    (:func:`check_pipeline_keywords`), not run by another method."""
    if method is not None:
        return method
    if options is not None:
        from masknet.errors import MaskNetError

        names = [n for n, entry in METHOD_TABLE.items() if type(options) is entry.options]
        if not names:
            raise MaskNetError(f"options= takes a method's options, got {type(options).__name__}")
        if len(names) > 1 and names[0] != "auto":  # NetworkOptions: DCP, PRNet, ...
            raise MaskNetError(
                f"{type(options).__name__} serves {', '.join(names)}: name the method"
            )
        return names[0]  # RobustOptions: "auto", the default that escalates to "robust"
    return "auto"


# The keywords the pipelines ("auto", "robust") do not take as the rounds' methods do, and
# what each sets there. Open3D's ``max_iteration`` is ICP's iteration cap; the pipelines' own
# ``max_iterations`` (RobustOptions) is the hypotheses' short ICP, another thing, so Open3D's
# spelling is refused there, and masknet's is taken as RobustOptions' only where the
# pipeline is named (with no method named it most likely means ICP's cap).
ROUNDS_ONLY = {
    "k": "the size of round 1's MaskNet mask",
    "mask_threshold": "round 1's MaskNet score cut-off",
    "threshold": "mask_threshold's deprecated name, round 1's MaskNet score cut-off; Open3D's "
    "threshold is max_correspondence_distance",
    "max_iteration": "ICP's iteration cap, Open3D's ICPConvergenceCriteria",
    "max_iterations": "ICP's updates per round",
}


def check_pipeline_keywords(method: str, named: bool, given: list[str]) -> None:
    """Refuse, in one line naming the method that takes it, a keyword of ``given`` (those the
    caller set) that the pipeline ``method`` would not honour as Mask-ICP and Open3D mean it
    (:data:`ROUNDS_ONLY`); ``named``: the caller named the method. Nothing for the rounds'
    methods, which take them all: no keyword changes the method that runs."""
    from masknet.errors import MaskNetError

    if METHOD_TABLE[method].kind != "pipeline":
        return
    for name in given:
        if name not in ROUNDS_ONLY or (name == "max_iterations" and named):
            continue
        also = ""
        if name == "max_iterations":
            also = f" (method=\"{method}\" with max_iterations sets RobustOptions' hypotheses' ICP)"
        raise MaskNetError(
            f'{name} ({ROUNDS_ONLY[name]}) applies to method="icp" (--method icp), not to the '
            f'"{method}" pipeline: pass method="icp" to use it{also}'
        )

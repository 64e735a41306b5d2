"""The methods :func:`masknet.register` runs: names, display titles, options and defaults."""

from __future__ import annotations

from masknet.models import REGISTRATION_NETWORKS
from masknet.names import GLOBAL_METHODS, METHOD_TITLES, METHODS, NETWORK_METHODS
from masknet.registration.options import RobustOptions

__all__ = [
    "DEFAULT_ITERATIONS",
    "GLOBAL_METHODS",
    "INITS",
    "METHODS",
    "METHOD_TITLES",
    "NETWORK_METHODS",
    "OPTIONS",
    "PIPELINES",
    "default_method",
    "resolve_method",
]

# The options (``**options`` of register) each method accepts.
OPTIONS = {
    "icp": ("max_iterations", "tolerance", "max_correspondence_distance"),
    "auto": RobustOptions._fields,
    "robust": RobustOptions._fields,
    "open3d-icp": (
        "max_iterations",
        "max_correspondence_distance",
        "relative_fitness",
        "relative_rmse",
    ),
    "pointnetlk": ("max_iterations", "tolerance", "network"),
    **{name: ("max_iterations", "network") for name in NETWORK_METHODS if name != "pointnetlk"},
    "open3d-ransac": ("max_iterations", "voxel_size", "confidence", "seed", "repeatable"),
    "open3d-fgr": ("max_iterations", "voxel_size"),
}
DEFAULT_MAX_ITERATIONS = 10  # the paper's budget for ICP and PointNetLK
# Each method's default max_iterations; each learned network its paper's: DCP 1, PRNet 3, ...
DEFAULT_ITERATIONS = {
    **{m: DEFAULT_MAX_ITERATIONS for m in METHODS},
    **{name: cls.default_iterations for name, cls in REGISTRATION_NETWORKS.items()},
}
INITS = ("centroid", "identity")
# Methods that run the coarse-to-fine pipeline and ignore the round options.
PIPELINES = ("auto", "robust")


def default_method(
    method: str | None,
    iterations: int = 1,
    k: int | None = None,
    threshold: float | None = None,
    refine_iterations: int = 0,
    init: str = "centroid",
    options: dict | None = None,
    typed: bool = False,
) -> str:
    """:func:`resolve_method` from register's own arguments (``typed``: an ICPCriteria,
    Selection or Rounds was given); the command line calls it too."""
    return resolve_method(
        method,
        {
            "iterations": iterations != 1,
            "k": k is not None,
            "threshold": threshold is not None,
            "refine_iterations": refine_iterations != 0,
            "init": init != "centroid",
            "icp options": any(key in OPTIONS["icp"] for key in options or {}),
            "typed": typed,
        },
    )


def resolve_method(method: str | None, round_options: dict) -> str:
    """``method``, or for None the default: ``"auto"``, unless ``round_options`` (the
    arguments only Mask-ICP's rounds take: ``iterations`` other than 1, ``k``,
    ``threshold``, ``refine_iterations``, ``init="identity"``, ICP's options) ask for
    Mask-ICP itself, which is then what runs."""
    if method is not None:
        return method
    return "icp" if any(round_options.values()) else "auto"

"""Registration: ``register`` (Mask-X for every method) and the algorithms behind it.

* :mod:`.api`: the facade, :func:`register`; :mod:`.result`: :class:`RegistrationResult`;
* :mod:`.evaluation`: :func:`evaluate_registration`, inlier fraction and RMSE of any result;
* :mod:`.assessment`: :func:`assess_registration`, did it work: a verdict and its reason;
* :mod:`.methods`: the method table (names, titles, adapters, options, defaults);
  :mod:`.options`: one typed options class per method (``ICPCriteria``,
  ``RobustOptions``, ...);
* :mod:`.validation` and :mod:`.sampling`: argument checks, large clouds to network size;
* :mod:`.rounds`: the rounds of Mask-X; :mod:`.backends`: one adapter per method;
* :mod:`.icp`, :mod:`.open3d_icp`, :mod:`.open3d_global`: the algorithms (ICP, Open3D's
  ICP, Open3D's RANSAC / FGR on FPFH); :mod:`.scene`: finding an object in a scan.

Names load on first use, so that the method table (and ``masknet --help``) needs no torch.
"""

from typing import TYPE_CHECKING

__all__ = [
    "Assessment",
    "FGROptions",
    "ICPCriteria",
    "ICPSolution",
    "METHODS",
    "METHOD_TABLE",
    "METHOD_TITLES",
    "NetworkOptions",
    "Open3DICPOptions",
    "PointNetLKOptions",
    "RANSACOptions",
    "RegistrationQuality",
    "RegistrationResult",
    "RobustOptions",
    "SceneMatch",
    "SceneSearch",
    "assess_registration",
    "evaluate_registration",
    "icp",
    "open3d_icp",
    "register",
]

_LAZY = {
    "register": "api",
    "RegistrationResult": "result",
    "Assessment": "assessment",
    "assess_registration": "assessment",
    "RegistrationQuality": "evaluation",
    "evaluate_registration": "evaluation",
    "ICPSolution": "icp",
    "icp": "icp",
    "METHODS": "methods",
    "METHOD_TABLE": "methods",
    "METHOD_TITLES": "methods",
    "open3d_icp": "open3d_icp",
    "SceneMatch": "scene",
    "SceneSearch": "scene",
    **{
        name: "options"
        for name in (
            "FGROptions",
            "ICPCriteria",
            "NetworkOptions",
            "Open3DICPOptions",
            "PointNetLKOptions",
            "RANSACOptions",
            "RobustOptions",
        )
    },
}

if TYPE_CHECKING:
    from masknet.registration.api import register
    from masknet.registration.assessment import Assessment, assess_registration
    from masknet.registration.evaluation import RegistrationQuality, evaluate_registration
    from masknet.registration.icp import ICPSolution, icp
    from masknet.registration.methods import METHOD_TABLE, METHOD_TITLES, METHODS
    from masknet.registration.open3d_icp import open3d_icp
    from masknet.registration.options import (
        FGROptions,
        ICPCriteria,
        NetworkOptions,
        Open3DICPOptions,
        PointNetLKOptions,
        RANSACOptions,
        RobustOptions,
    )
    from masknet.registration.result import RegistrationResult
    from masknet.registration.scene import SceneMatch, SceneSearch


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f"masknet.registration.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'masknet.registration' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

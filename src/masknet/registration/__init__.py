"""Registration: ``register`` (Mask-X for every method) and the algorithms behind it.

* :mod:`.api`: the facade, :func:`register`; :mod:`.result`: :class:`RegistrationResult`;
* :mod:`.fit`: :func:`evaluate_registration`, inlier fraction and RMSE of any result, and
  every other fit;
* :mod:`.assessment`: :func:`assess_registration`, did it work: a verdict and its reason;
* :mod:`.methods`: the method table (names, titles, adapters, options, defaults);
  :mod:`.options`: one typed options class per method (``ICPCriteria``,
  ``RobustOptions``, ...);
* :mod:`.validation`: argument checks;
* :mod:`.rounds`: the rounds of Mask-X; :mod:`.backends`: one adapter per method;
* :mod:`.icp`, :mod:`.open3d_icp`, :mod:`.open3d_global`: the algorithms (ICP, Open3D's
  ICP, Open3D's RANSAC / FGR on FPFH); :mod:`.scene`: finding an object in a scan;
  :mod:`.auto`, :mod:`.robust` (with :mod:`.robust.search`): the default and the
  coarse-to-fine search.

Names load on first use, so that the method table (and ``masknet --help``) needs no torch.
"""

from typing import TYPE_CHECKING

# The method table and the options are torch-free: loaded with the package.
from masknet.registration import options as _options
from masknet.registration.methods import METHOD_TABLE, METHOD_TITLES, METHODS  # noqa: F401
from masknet.registration.options import *  # noqa: F403 (one options class per method)

_LAZY = {
    "register": "api",
    "RegistrationResult": "result",
    "Assessment": "assessment",
    "assess_registration": "assessment",
    "RegistrationQuality": "fit",
    "evaluate_registration": "fit",
    "ICPSolution": "icp",
    "SceneMatch": "scene",
    "SceneSearch": "scene",
}
__all__ = sorted(["METHODS", "METHOD_TABLE", "METHOD_TITLES", *_options.__all__, *_LAZY])

if TYPE_CHECKING:  # noqa: F401 below: names of __all__, loaded on first use
    from masknet.registration.api import register  # noqa: F401
    from masknet.registration.assessment import Assessment, assess_registration  # noqa: F401
    from masknet.registration.fit import RegistrationQuality, evaluate_registration  # noqa: F401
    from masknet.registration.icp import ICPSolution  # noqa: F401
    from masknet.registration.result import RegistrationResult  # noqa: F401
    from masknet.registration.scene import SceneMatch, SceneSearch  # noqa: F401


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f"masknet.registration.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'masknet.registration' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

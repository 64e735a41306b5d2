"""Registration: ``register`` (Mask-X for every method) and the algorithms behind it.

The call itself sits at the top: :mod:`.api` (the facade, :func:`register`), :mod:`.plan`
(what the arguments resolve to), :mod:`.pipeline` (the stages of one call) and
:mod:`.many` (many pairs at once). Below it, four folders by role, each using only the
ones after it (the judge and the solvers side by side):

* :mod:`.stages`: what runs. ``auto`` (the default, its stages in run order), the
  consensus front end for scans (``consensus``), the coarse-to-fine search (``search``,
  ``robust``), finding an object in a scene (``scene``, ``scene_centres``), and the rounds
  of Mask-X with the masks of later rounds (``rounds``, ``refinement``).
* :mod:`.judge`: did it work, and which pose wins. The prepared pair (``prepared``), every
  fit of a pose (``fit``: :func:`evaluate_registration`), the verdict (``assessment``:
  :func:`assess_registration`) with its constraint analysis (``constraints``), and the
  arbiter (``arbiter``), where every choice between poses is made.
* :mod:`.solvers`: the algorithms. ICP (``icp``), Open3D's ICP and global registration
  (``open3d_icp``, ``open3d_global``), FPFH correspondences and RANSAC
  (``correspondences``), and one adapter per method (``backends``).
* :mod:`.terms`: the terms every part uses. One typed options class per method
  (``options``), the method table (``methods``), argument checks (``validation``), the
  mixed-units diagnosis (``units``) and :class:`RegistrationResult` (``result``).

The modules' old flat places (``masknet.registration.auto`` and the like) still import,
with a ``DeprecationWarning``, for one more release.

Names load on first use, so that the method table (and ``masknet --help``) needs no torch.
"""

from typing import TYPE_CHECKING

# The method table and the options are torch-free: loaded with the package.
from masknet.registration.terms import options as _options
from masknet.registration.terms.methods import METHOD_TABLE, METHOD_TITLES, METHODS  # noqa: F401
from masknet.registration.terms.options import *  # noqa: F403 (one options class per method)

_LAZY = {
    "register": "api",
    "RegistrationResult": "terms.result",
    "Assessment": "judge.assessment",
    "assess_registration": "judge.assessment",
    "RegistrationQuality": "judge.fit",
    "evaluate_registration": "judge.fit",
    "ICPSolution": "solvers.icp",
    "SceneMatch": "stages.scene",
    "SceneSearch": "stages.scene",
}
__all__ = sorted(["METHODS", "METHOD_TABLE", "METHOD_TITLES", *_options.__all__, *_LAZY])

if TYPE_CHECKING:  # noqa: F401 below: names of __all__, loaded on first use
    from masknet.registration.api import register  # noqa: F401
    from masknet.registration.judge.assessment import Assessment, assess_registration  # noqa: F401
    from masknet.registration.judge.fit import RegistrationQuality, evaluate_registration  # noqa: F401
    from masknet.registration.solvers.icp import ICPSolution  # noqa: F401
    from masknet.registration.stages.scene import SceneMatch, SceneSearch  # noqa: F401
    from masknet.registration.terms.result import RegistrationResult  # noqa: F401


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f"masknet.registration.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'masknet.registration' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

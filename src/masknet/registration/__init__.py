"""Registration: ``register`` (Mask-X for every method) and the algorithms behind it.

* :mod:`.api`: the facade, :func:`register`; :mod:`.result`: :class:`RegistrationResult`;
* :mod:`.evaluation`: :func:`evaluate_registration`, inlier fraction and RMSE of any result;
* :mod:`.assessment`: :func:`assess_registration`, did it work: a verdict and its reason;
* :mod:`.methods`: method names, titles, options and defaults; :mod:`.options`: the
  typed options (``ICPCriteria``, ``Selection``, ``Rounds``, ``RobustOptions``);
* :mod:`.validation` and :mod:`.sampling`: argument checks, large clouds to network size;
* :mod:`.backends`: one adapter per method, ``(template, source, mask, options) -> run``;
* :mod:`.icp`, :mod:`.open3d_icp`, :mod:`.open3d_global`: the algorithms (batched torch
  ICP, Open3D's ICP, Open3D's RANSAC / FGR on FPFH).
"""

from masknet.registration.api import RegistrationResult, register
from masknet.registration.assessment import Assessment, assess_registration
from masknet.registration.evaluation import RegistrationQuality, evaluate_registration
from masknet.registration.icp import ICPSolution, icp
from masknet.registration.methods import METHOD_TITLES, METHODS
from masknet.registration.open3d_icp import open3d_icp
from masknet.registration.options import ICPCriteria, RobustOptions, Rounds, Selection

__all__ = [
    "Assessment",
    "ICPCriteria",
    "METHODS",
    "METHOD_TITLES",
    "ICPSolution",
    "RegistrationQuality",
    "RegistrationResult",
    "RobustOptions",
    "Rounds",
    "Selection",
    "assess_registration",
    "evaluate_registration",
    "icp",
    "open3d_icp",
    "register",
]

"""Registration: batched torch ICP, an Open3D ICP backend and ``register`` (Mask-ICP)."""

from masknet.registration.api import METHOD_TITLES, METHODS, RegistrationResult, register
from masknet.registration.icp import ICPSolution, icp
from masknet.registration.open3d_icp import open3d_icp

__all__ = [
    "METHODS",
    "METHOD_TITLES",
    "ICPSolution",
    "RegistrationResult",
    "icp",
    "open3d_icp",
    "register",
]

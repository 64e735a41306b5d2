"""Method and network names, importable without torch (the command line's choices).

:mod:`masknet.registration.methods` and :data:`masknet.models.REGISTRATION_NETWORKS`
use these names; a test checks that they agree.
"""

from __future__ import annotations

__all__ = ["GLOBAL_METHODS", "METHODS", "METHOD_TITLES", "NETWORK_METHODS"]

# The learned registration networks, by method name.
NETWORK_METHODS = ("pointnetlk", "dcp", "prnet", "pcrnet", "rpmnet")
# Open3D's global registration on FPFH features: no iteration budget, no init.
GLOBAL_METHODS = ("open3d-ransac", "open3d-fgr")
METHODS = ("auto", "icp", "robust", "open3d-icp", *NETWORK_METHODS, *GLOBAL_METHODS)
# Each method's display name (X of "Mask-X").
METHOD_TITLES = {
    "auto": "ICP (auto)",
    "icp": "ICP",
    "robust": "ICP (robust)",
    "open3d-icp": "Open3D-ICP",
    "pointnetlk": "PointNetLK",
    "dcp": "DCP",
    "prnet": "PRNet",
    "pcrnet": "PCRNet",
    "rpmnet": "RPM-Net",
    "open3d-ransac": "Open3D-RANSAC",
    "open3d-fgr": "Open3D-FGR",
}

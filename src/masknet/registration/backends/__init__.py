"""Back-end adapters of :func:`masknet.register`: each runs one method on a batch of pairs,
``(template, source, mask, options) -> BackendRun`` (see :mod:`.base`).

To add a method: write its adapter here, add it to :data:`BACKENDS`, and give it a name,
title and options in :mod:`masknet.registration.methods`.
"""

from masknet.registration.backends.base import Backend, BackendRun
from masknet.registration.backends.icp import run_icp, run_open3d_icp
from masknet.registration.backends.network import run_network
from masknet.registration.backends.open3d_global import open3d_global_backend
from masknet.registration.methods import NETWORK_METHODS

__all__ = ["BACKENDS", "Backend", "BackendRun", "run_icp"]

# Method name -> its adapter.
BACKENDS: dict[str, Backend] = {
    "icp": run_icp,
    "open3d-icp": run_open3d_icp,
    **{name: run_network for name in NETWORK_METHODS},
    "open3d-ransac": open3d_global_backend("open3d-ransac"),
    "open3d-fgr": open3d_global_backend("open3d-fgr"),
}

"""Adapters of the method table (:mod:`masknet.registration.terms.methods`), one module per
family: :mod:`.icp` (ICP, Open3D's ICP), :mod:`.network` (the learned networks),
:mod:`.open3d_global` (Open3D's RANSAC and FGR). :mod:`.base` says what each takes and
returns, and what the whole-call pipelines take (``auto`` and ``robust``, whose adapters
are :func:`~masknet.registration.stages.auto.auto_register` and
:func:`~masknet.registration.stages.robust.robust_register`). The table imports each on first
use.
"""

from masknet.registration.solvers.backends.base import Backend, BackendRun, Pipeline

__all__ = ["Backend", "BackendRun", "Pipeline"]

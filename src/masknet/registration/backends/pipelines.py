"""Adapters of the whole-call pipelines, ``auto`` (the default) and ``robust``."""

from __future__ import annotations

import numpy as np

from masknet.registration.backends.base import MaskModels, PipelineRun
from masknet.registration.options import RobustOptions

__all__ = ["run_auto", "run_robust"]


def run_auto(
    template: np.ndarray,
    source: np.ndarray,
    template_net: np.ndarray,
    source_net: np.ndarray,
    models: MaskModels,
    options: RobustOptions,
    times: dict[str, float],
    precision: str,
) -> PipelineRun:
    """``method="auto"``: :func:`masknet.registration.auto.auto_register`."""
    from masknet.registration.auto import auto_register

    return auto_register(
        template,
        source,
        template_net,
        source_net,
        models.first,
        models.search,
        options,
        times,
        precision,
    )


def run_robust(
    template: np.ndarray,
    source: np.ndarray,
    template_net: np.ndarray,
    source_net: np.ndarray,
    models: MaskModels,
    options: RobustOptions,
    times: dict[str, float],
    precision: str,
) -> PipelineRun:
    """``method="robust"``: :func:`masknet.registration.robust.robust_register`."""
    from masknet.registration.robust import robust_register

    return robust_register(
        template, source, template_net, source_net, models.first, options, times, precision
    )

"""masknet: predict which template points a partial source cloud also sees.

    >>> from masknet import MaskNet
    >>> model = MaskNet.pretrained()
    >>> mask = model.predict_mask(template, source)   # (N,) bool, top-k with k = len(source)
    >>> from masknet import register
    >>> result = register(template, source)           # the default, "auto"; result.transform (4, 4)
    >>> from masknet import evaluate_registration
    >>> quality = evaluate_registration(template=template, source=source, transform=result.transform)
    >>> quality.fitness                               # inlier fraction (names only: not Open3D's order)
    >>> from masknet import assess_registration
    >>> assess_registration(template, source, result.transform).verdict  # did it work?
    >>> from masknet import denoise
    >>> kept = denoise(template, noisy)               # aligned clouds: kept.points, kept.mask

The transform convention for every registration result is documented in
:mod:`masknet.geometry.se3`: ``template ~= R @ source + t``.
"""

import os
from typing import TYPE_CHECKING

from masknet.errors import MaskNetError, MaskNetWarning

# GNU OpenMP's idle threads spin for about 300,000 iterations before they sleep. Torch and
# pykdtree each bring their own pool, and Open3D its own threads: one's spinning took the
# cores another needed (FPFH features right after a network pass took 5.7 ms instead of
# 3.3 on 2 cores, and ``method="robust"`` about a fifth longer per pair). Shorter spins
# keep back-to-back small regions fast. Read once, when each OpenMP runtime loads: a
# value the user set wins, and a torch imported before masknet keeps its own.
os.environ.setdefault("GOMP_SPINCOUNT", "10000")

__version__ = "0.1.0"
from masknet.registration.terms import options as _options  # noqa: E402 (after the environment)

# Every options class (SceneSearch included), as masknet.registration.terms.options lists them:
# that module is plain dataclasses, no torch.
_OPTIONS = tuple(name for name in _options.__all__ if name[0].isupper())

__all__ = [
    "DenoiseResult",
    "MaskNet",
    "MaskNetError",
    "MaskNetWarning",
    "assess_registration",
    "denoise",
    "evaluate_registration",
    "RegistrationResult",
    *_OPTIONS,
    "PreparedTemplate",
    "prepare_template",
    "register",
    "register_many",
    "select_mask",
    "track",
    "Tracker",
    "__version__",
]

# Names loaded on first use (PEP 562), so that ``import masknet.cli`` and ``masknet
# --help`` do not import torch.
_LAZY = {
    "DenoiseResult": "masknet.denoising",
    "denoise": "masknet.denoising",
    "MaskNet": "masknet.models",
    "select_mask": "masknet.models",
    "RegistrationResult": "masknet.registration",
    "assess_registration": "masknet.registration",
    "evaluate_registration": "masknet.registration",
    "register": "masknet.registration",
    "PreparedTemplate": "masknet.geometry.prepared_template",
    "prepare_template": "masknet.geometry.prepared_template",
    "register_many": "masknet.registration.many",
    "track": "masknet.tracking",
    "Tracker": "masknet.tracking",
    **dict.fromkeys(_OPTIONS, "masknet.registration.terms.options"),
}

if TYPE_CHECKING:
    from masknet.denoising import DenoiseResult, denoise
    from masknet.geometry.prepared_template import PreparedTemplate, prepare_template
    from masknet.models import MaskNet, select_mask
    from masknet.registration import (
        RegistrationResult,
        assess_registration,
        evaluate_registration,
        register,
    )
    from masknet.tracking import Tracker, track


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'masknet' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

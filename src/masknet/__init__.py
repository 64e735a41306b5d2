"""masknet: predict which template points a partial source cloud also sees.

    >>> from masknet import MaskNet
    >>> model = MaskNet.pretrained()
    >>> mask = model.predict_mask(template, source)   # (N,) bool, top-k with k = len(source)
    >>> from masknet import register
    >>> result = register(template, source)           # Mask-ICP; result.transform (4, 4)
    >>> from masknet import denoise
    >>> kept = denoise(noisy, template)               # aligned clouds: kept.points, kept.mask

The transform convention for every registration result is documented in
:mod:`masknet.geometry.se3`: ``template ~= R @ source + t``.
"""

from masknet.denoising import DenoiseResult, denoise
from masknet.errors import MaskNetError
from masknet.models import MaskNet, select_mask
from masknet.registration import RegistrationResult, register

__version__ = "0.1.0"
__all__ = [
    "DenoiseResult",
    "MaskNet",
    "MaskNetError",
    "denoise",
    "RegistrationResult",
    "register",
    "select_mask",
    "__version__",
]

"""Device and precision helpers."""

import pytest

from masknet.errors import MaskNetError
from masknet.runtime import default_precision, resolve_device


def test_default_precision_is_a_known_mode():
    assert default_precision("cpu") in ("fp32", "bf16")
    assert default_precision("meta") == "fp32"


def test_unknown_device_is_one_clear_error():
    assert resolve_device("cpu").type == "cpu"
    with pytest.raises(MaskNetError, match="unknown device"):
        resolve_device("tpu:7")

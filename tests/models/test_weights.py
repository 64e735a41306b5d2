"""safetensors weights: fp16 storage round trip, range check, shipped files' metadata."""

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from masknet.errors import MaskNetError
from masknet.models import MaskNet, TwoSidedMaskNet
from masknet.models.weights import read_metadata, shipped_weights_path


def test_fp16_storage_halves_the_file_and_loads_as_fp32(small_masknet, tmp_path):
    full, half = tmp_path / "full.safetensors", tmp_path / "half.safetensors"
    small_masknet.save(full)
    small_masknet.save(half, {"note": "x"}, storage="fp16")
    assert half.stat().st_size < 0.6 * full.stat().st_size
    assert read_metadata(half)["storage"] == "fp16"
    assert read_metadata(half)["note"] == "x"
    stored = load_file(str(half))
    assert stored["encoder.linears.0.weight"].dtype == torch.float16
    assert stored["encoder.norms.0.num_batches_tracked"].dtype == torch.int64
    loaded = MaskNet.from_file(half)
    assert next(loaded.parameters()).dtype == torch.float32
    for name, value in small_masknet.state_dict().items():
        if value.is_floating_point():  # rounded to fp16, and nothing more
            torch.testing.assert_close(loaded.state_dict()[name], value.half().float())


def test_fp16_storage_refuses_values_out_of_range(small_masknet, tmp_path):
    model = MaskNet(encoder_channels=(16, 32), head_channels=(32, 16))
    model.load_state_dict(small_masknet.state_dict())
    with torch.no_grad():
        next(model.parameters())[0] = 1e6  # beyond fp16's 65504
    path = tmp_path / "w.safetensors"
    with pytest.raises(MaskNetError, match="does not fit in fp16"):
        model.save(path, storage="fp16")
    assert not path.exists()
    with pytest.raises(MaskNetError, match="storage must be one of"):
        model.save(path, storage="int8")


@pytest.mark.parametrize(
    "cls, name",
    [(MaskNet, "modelnet40"), (MaskNet, "scans"), (TwoSidedMaskNet, "scans")],
)
def test_shipped_masknet_weights_are_stored_in_fp16(cls, name):
    path = shipped_weights_path(f"{cls.weights_prefix}{name}.safetensors")
    assert read_metadata(path)["storage"] == "fp16"
    model = cls.pretrained(name)
    assert all(p.dtype == torch.float32 for p in model.parameters())
    assert all(np.isfinite(p.detach().numpy()).all() for p in model.parameters())

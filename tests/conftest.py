"""Shared fixtures."""

from pathlib import Path

import pytest
import torch

from masknet.models import MaskNet


@pytest.fixture(scope="module")
def one_thread():
    """Small problems: one thread is faster and avoids contention on busy machines."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def small_masknet() -> MaskNet:
    """A small random MaskNet (seed 0, eval mode), so that the tests do not depend on the
    shipped weights. One per test module."""
    torch.manual_seed(0)
    return MaskNet(encoder_channels=(16, 32), head_channels=(32, 16)).eval()


@pytest.fixture(scope="module")
def small_masknet_weights(small_masknet: MaskNet, tmp_path_factory) -> Path:
    """:func:`small_masknet` saved as ``tiny.safetensors``, for commands that read files."""
    path = tmp_path_factory.mktemp("w") / "tiny.safetensors"
    small_masknet.save(path)
    return path

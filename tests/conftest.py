"""Shared fixtures."""

import os
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


def _skip_unless_ci(reason: str) -> None:
    if os.environ.get("CI", "").lower() not in ("", "0", "false"):
        pytest.fail(f"{reason}; CI must run this test")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def skip_unless_ci():
    """``skip_unless_ci(reason)``: skip a test whose prerequisite is missing (Open3D,
    Chromium, ../shared/data), but fail under CI (``CI`` set), where every prerequisite
    must be present, so that a missing one cannot let CI go green silently."""
    return _skip_unless_ci


@pytest.fixture(scope="session")
def o3d():
    """Open3D's module; where it does not import, :func:`skip_unless_ci`."""
    from masknet.errors import MaskNetError
    from masknet.io import require_open3d

    try:
        return require_open3d("this test")
    except MaskNetError as exc:
        _skip_unless_ci(str(exc))


@pytest.fixture(scope="session")
def scans_dir() -> Path:
    """The evaluation scans (``$MASKNET_SCANS``, default ../shared/data/scans); where they
    are missing, :func:`skip_unless_ci`."""
    from masknet.experiments.scans import scans_folder

    folder = scans_folder()
    if not folder.is_dir():
        _skip_unless_ci(f"{folder}: the evaluation scans are missing")
    return folder

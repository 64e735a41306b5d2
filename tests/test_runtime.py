"""Device and precision helpers."""

import numpy as np
import pytest
import torch

import masknet.runtime as runtime
from masknet.errors import MaskNetError
from masknet.runtime import default_precision, resolve_device


@pytest.fixture
def cpuinfo(monkeypatch):
    """``cpuinfo(text)``: default_precision reads ``text`` as /proc/cpuinfo (None: unreadable)."""
    runtime._default_precision.cache_clear()

    def set_text(text):
        class FakePath:
            def __init__(self, path):
                assert str(path) == "/proc/cpuinfo"

            def read_text(self):
                if text is None:
                    raise OSError("no /proc")
                return text

        monkeypatch.setattr(runtime, "Path", FakePath)
        runtime._default_precision.cache_clear()

    yield set_text
    runtime._default_precision.cache_clear()


@pytest.mark.parametrize(
    "flags, expected",
    [
        ("fpu sse avx2 avx512f", "fp32"),
        ("fpu avx512f avx512_bf16", "bf16"),
        ("fpu amx_tile amx_bf16", "bf16"),
        (None, "fp32"),  # no /proc/cpuinfo: the safe choice
    ],
)
def test_cpu_precision_follows_the_bf16_flags(cpuinfo, flags, expected):
    cpuinfo(None if flags is None else f"processor\t: 0\nflags\t\t: {flags}\n")
    assert default_precision("cpu") == expected
    assert default_precision("meta") == "fp32"


@pytest.mark.parametrize("supported, expected", [(True, "bf16"), (False, "fp32")])
def test_cuda_precision_follows_bf16_support(monkeypatch, supported, expected):
    runtime._default_precision.cache_clear()
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: supported)
    try:
        assert default_precision("cuda") == expected
    finally:
        runtime._default_precision.cache_clear()


def test_unknown_device_is_one_clear_error():
    assert resolve_device("cpu").type == "cpu"
    with pytest.raises(MaskNetError, match="unknown device"):
        resolve_device("tpu:7")


def test_small_blas_runs_numpy_blas_single_threaded_and_restores_it():
    from threadpoolctl import threadpool_info

    from masknet.registration import register
    from masknet.runtime import _numpy_blas, small_blas

    assert _numpy_blas() is not None, "numpy's BLAS is not found"

    def numpy_blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    before = numpy_blas_threads()

    @small_blas
    def inside() -> list[int]:
        return [i["num_threads"] for i in _numpy_blas().info()]

    assert inside() and inside() == [1] * len(inside())
    assert numpy_blas_threads() == before

    # register's stages run within it: a mask model sees the limit
    seen = []

    class Recorder:
        def predict_masks(self, template, source, **_):
            seen.extend(i["num_threads"] for i in _numpy_blas().info())
            return np.ones(template.shape[:2], bool), None

    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(64, 3))
    register(cloud, cloud[:40], method="icp", model=Recorder())
    assert seen and set(seen) == {1}
    assert numpy_blas_threads() == before


@pytest.mark.parametrize(("preset", "expected"), [(None, "10000"), ("123", "123")])
def test_importing_masknet_shortens_openmp_spinning_unless_the_user_chose(preset, expected):
    """The spin count is set before any OpenMP runtime loads, and a user's own value stays."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "GOMP_SPINCOUNT"}
    if preset is not None:
        env["GOMP_SPINCOUNT"] = preset
    code = (
        "import os, sys, masknet\n"
        "assert 'torch' not in sys.modules\n"
        "print(os.environ['GOMP_SPINCOUNT'])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == expected


def test_cpu_name_names_the_machine():
    from masknet.runtime import cpu_name

    name = cpu_name()
    assert isinstance(name, str) and name.strip() and "\n" not in name

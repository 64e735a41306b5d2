"""Device, precision and thread helpers."""

import torch

from masknet.runtime import SMALL_WORK, default_precision, threads_for


def test_small_work_runs_on_one_thread_and_restores_the_setting():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with threads_for(1000):
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        with threads_for(SMALL_WORK):
            assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_default_precision_is_a_known_mode():
    assert default_precision("cpu") in ("fp32", "bf16")
    assert default_precision("meta") == "fp32"

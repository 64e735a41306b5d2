"""Run by tests/training/test_distributed.py, alone or under torchrun: a few PointNetLK
training steps on the bundled sample, written to the folder given as argv[1]."""

import sys

import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.training import RegistrationTask, TrainConfig, fit

torch.set_num_threads(1)
shapes = load_modelnet40(bundled_sample_path()).points[:40]


class Float64Task(RegistrationTask):
    """float64, so that rounding cannot hide or fake a difference from the parallelism."""

    def build_model(self):
        return super().build_model().double()


task = Float64Task(num_points=64, iterations=3, model_config={"encoder_channels": [16, 32]})
config = TrainConfig(
    out_dir=sys.argv[1],
    epochs=2,
    batch_size=8,
    lr=1e-3,
    precision="fp32",
    val_pairs=8,
    device="cpu",
)
fit(task, shapes, config)

"""Training: one loop (:func:`fit`) for every model, plus each model's task."""

from masknet.training.loop import Task, TrainConfig, fit, split_train_val
from masknet.training.masknet_task import MaskNetTask
from masknet.training.pair_task import PairTask
from masknet.training.registration_task import TRAINING_DEFAULTS, RegistrationTask

__all__ = [
    "Task",
    "TrainConfig",
    "fit",
    "split_train_val",
    "MaskNetTask",
    "PairTask",
    "RegistrationTask",
    "TRAINING_DEFAULTS",
]

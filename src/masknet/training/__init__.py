"""Training: one loop (:func:`fit`) for every model, plus each model's task."""

from masknet.training.loop import Task, TrainConfig, fit, split_train_val
from masknet.training.masknet_task import MaskNetTask

__all__ = ["Task", "TrainConfig", "fit", "split_train_val", "MaskNetTask"]

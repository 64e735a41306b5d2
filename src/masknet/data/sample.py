"""Build the small ModelNet40 sample that ships inside the package.

The sample holds the first ``per_class`` test shapes of every category (by
name), stored like the full ``.npz``: int16 coordinates times ``scale``. It is
made from the test split only, so models trained on the train split never saw it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from masknet._atomic import atomic_target
from masknet.data.modelnet import load_modelnet40

__all__ = ["build_sample"]


def build_sample(
    data: str | os.PathLike | None, out: str | os.PathLike, per_class: int = 3
) -> Path:
    """Write the sample ``.npz`` (atomically) and return its path."""
    test = load_modelnet40(data, "test")
    picks = []
    for label in range(len(test.shape_names)):
        members = np.flatnonzero(test.labels == label)
        picks.extend(members[np.argsort(test.names[members], kind="stable")][:per_class])
    picks = np.array(picks)
    scale = np.float32(1 / 32767)
    quantised = np.round(test.points[picks] / scale).clip(-32767, 32767).astype(np.int16)
    out = Path(out)
    with atomic_target(out, suffix=".npz") as tmp:  # np.savez appends .npz to other names
        np.savez_compressed(
            tmp,
            test_points=quantised,
            test_labels=test.labels[picks],
            test_names=test.names[picks].astype(str),
            shape_names=np.array(test.shape_names),
            scale=scale,
        )
    return out

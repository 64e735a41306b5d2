"""Shared files of the command-line tests: a pair of the bundled sample, written out."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs


def _pair_files(folder, seed: int):
    """A pair of the first sample shape as template.xyz and source.npy, and the pair."""
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pair = make_test_pairs(shapes, 1, PairConfig(), seed=seed)
    np.savetxt(folder / "template.xyz", pair.template[0].numpy())
    np.save(folder / "source.npy", pair.source[0].numpy())
    return folder / "template.xyz", folder / "source.npy", pair


@pytest.fixture(scope="module")
def pair_files(tmp_path_factory):
    return _pair_files(tmp_path_factory.mktemp("pair"), seed=1)


@pytest.fixture(scope="module")
def turned_pair_files(tmp_path_factory):
    """pair_files' shape turned 27.4 deg and moved 0.82 (pair_files' is turned only 5.6)."""
    return _pair_files(tmp_path_factory.mktemp("turned"), seed=3)


def _sha256_of(folder) -> dict[str, str]:
    """Every entry below ``folder``: a file's sha256, a link's target with its content's,
    a folder as "folder"; a changed byte, a new file or a new folder changes the dict."""
    import hashlib
    import os

    found = {}
    for path in sorted(folder.rglob("*")):
        name = str(path.relative_to(folder))
        if path.is_dir() and not path.is_symlink():
            found[name] = "folder"
            continue
        digest = hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else "dangling"
        found[name] = f"-> {os.readlink(path)} {digest}" if path.is_symlink() else digest
    return found


@pytest.fixture(scope="session")
def sha256_of():
    """``sha256_of(folder)``: the sha256 of every file below ``folder`` (links and folders
    too), to show that a refused run left every input byte-identical and made nothing."""
    return _sha256_of

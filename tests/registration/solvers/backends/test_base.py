"""What the adapters share: which points of a pair are in use."""

import numpy as np
import pytest

from masknet.errors import MaskNetError
from masknet.registration.solvers.backends.base import (
    check_template_points,
    keep_source_points,
    points_in_use,
    usable,
)


def test_usable_keeps_all_where_under_three_points_are_kept():
    keep = np.array([[True, True, True, False], [True, False, False, False]])
    np.testing.assert_array_equal(usable(keep), [[True, True, True, False], [True] * 4])
    assert usable(None) is None


def test_keep_source_points_of_one_pair_only():
    source = np.arange(12.0).reshape(1, 4, 3)
    kept = keep_source_points(source, np.array([[True, False, True, True]]))
    np.testing.assert_array_equal(kept, source[:, [0, 2, 3]])
    assert keep_source_points(source, np.array([[True, False, False, False]])) is source
    batch = np.zeros((2, 4, 3))
    assert keep_source_points(batch, np.ones((2, 4), bool)) is batch  # a batch keeps its shape


def test_points_in_use_pair_by_pair():
    template, source = np.arange(24.0).reshape(2, 4, 3), np.arange(18.0).reshape(2, 3, 3)
    mask = np.array([[True, True, True, False], [False, True, True, True]])
    pairs = list(points_in_use(template, source, mask, None))
    assert [len(t) for t, _ in pairs] == [3, 3] and [len(s) for _, s in pairs] == [3, 3]
    np.testing.assert_array_equal(pairs[1][0], template[1, 1:])


def test_check_template_points_refuses_under_three():
    check_template_points(3)
    with pytest.raises(MaskNetError, match="kept 2 template point"):
        check_template_points(2)


def test_check_template_points_advises_on_what_the_caller_set():
    # Neither k nor a threshold: top-k is the rule, so the advice must not name a threshold.
    with pytest.raises(MaskNetError, match="k = the source's points") as default:
        check_template_points(1)
    with pytest.raises(MaskNetError, match="top-k with k=2; give k of at least 3") as top_k:
        check_template_points(2, k=2)
    with pytest.raises(MaskNetError, match="mask_threshold 0.9; lower it"):
        check_template_points(0, threshold=0.9)
    with pytest.raises(MaskNetError, match=r"\(the refiner's mask\)"):
        check_template_points(1, rule="the refiner's mask")
    for refused in (default, top_k):
        assert "threshold" not in str(refused.value)

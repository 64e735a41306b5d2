"""masknet.registration.options: typed options equal the keyword arguments they replace."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import MaskNetError, register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.registration import ICPCriteria, RobustOptions, Rounds, Selection


@pytest.fixture(scope="module")
def pair():
    shapes = load_modelnet40(bundled_sample_path(), "test").points
    pairs = make_test_pairs(shapes, 1, PairConfig(), seed=2)
    return pairs.template[0].numpy(), pairs.source[0].numpy()


def test_typed_options_equal_their_keywords(pair, small_masknet):
    template, source = pair
    cases = [
        ({"rounds": Rounds(2, refine=5)}, {"iterations": 2, "refine_iterations": 5}),
        ({"selection": Selection(threshold=0.4)}, {"threshold": 0.4}),
        ({"criteria": ICPCriteria(max_iterations=25)}, {"max_iterations": 25}),
    ]
    for typed, keywords in cases:
        a = register(template, source, model=small_masknet, precision="fp32", **typed)
        b = register(template, source, model=small_masknet, precision="fp32", **keywords)
        np.testing.assert_array_equal(a.transform, b.transform)


def test_typed_and_keyword_options_cannot_both_be_given(pair, small_masknet):
    template, source = pair
    with pytest.raises(MaskNetError, match="give iterations= or Rounds, not both"):
        register(template, source, model=small_masknet, iterations=3, rounds=Rounds(2))
    with pytest.raises(MaskNetError, match="for method='auto' or 'robust', not 'icp'"):
        register(template, source, method="icp", robust=RobustOptions(hypotheses=4))
    with pytest.raises(MaskNetError, match="for method='icp'"):
        register(template, source, method="robust", criteria=ICPCriteria())


def test_robust_options_object(pair):
    template, source = pair
    a = register(
        template, source, method="robust", robust=RobustOptions(hypotheses=4, candidates=2)
    )
    b = register(template, source, method="robust", hypotheses=4, candidates=2)
    np.testing.assert_array_equal(a.transform, b.transform)


def test_a_number_for_rounds_is_a_clear_error(pair):
    template, source = pair
    with pytest.raises(MaskNetError, match=r"rounds= takes a Rounds, got int \(for a number"):
        register(template, source, rounds=3)

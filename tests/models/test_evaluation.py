import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.models.evaluation import (holm, paired_tests, series_scores, stars,
                                              top_fraction_rmse)


def test_top10_rmse_is_rmse_over_the_largest_tenth_of_absolute_errors():
    err = np.arange(1, 21, dtype=float)            # 20 windows -> the 2 largest: 19, 20
    assert top_fraction_rmse(-err) == pytest.approx(np.sqrt((19 ** 2 + 20 ** 2) / 2))


def test_top10_rmse_uses_at_least_one_window():
    assert top_fraction_rmse(np.array([0.1, -0.5, 0.2])) == pytest.approx(0.5)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=1, max_size=200))
def test_top10_rmse_bounds_the_rmse_from_above(errs):
    e = np.array(errs)
    assert top_fraction_rmse(e) >= np.sqrt(np.mean(e ** 2)) - 1e-12
    assert top_fraction_rmse(e) <= np.abs(e).max() + 1e-12


def test_holm_matches_hand_computation():
    np.testing.assert_allclose(holm([0.01, 0.04, 0.03]), [0.03, 0.06, 0.06])


def test_holm_never_lowers_a_p_value_and_caps_at_one():
    p = np.array([0.2, 0.5, 0.9, 0.001])
    adj = holm(p)
    assert (adj >= p).all() and adj.max() <= 1.0


def test_stars_follow_the_paper():
    assert (stars(0.005), stars(0.02), stars(0.2)) == ("**", "*", "")


def test_paired_tests_find_a_clearly_worse_method_and_pair_by_series():
    rng = np.random.default_rng(0)
    n = 30
    series = np.repeat(np.arange(n), 10)
    material = np.repeat(np.array(["a", "b", "c"] * 10), 10)
    y = rng.random(len(series))
    good = series_scores("injection", y, y + rng.normal(0, 0.05, len(y)), series, material)
    bad = series_scores("e1", y, y + rng.normal(0, 0.3, len(y)), series, material)
    same = series_scores("e19", y, y + rng.normal(0, 0.05, len(y)), series, material)
    res = paired_tests({"injection": good, "e1": bad, "e19": same})
    assert res["e1"]["stars"] == "**" and res["e1"]["n"] == n
    assert res["e19"]["p_holm"] > 0.01
    assert set(good.summary()["by_material"]) == {"a", "b", "c"}

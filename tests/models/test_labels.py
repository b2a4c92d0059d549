import numpy as np
from hypothesis import given, settings, strategies as st

from incipient_slip.models.labels import (GROSS_SLIP_MM, gross_slip_travel_mm, mocap_mean_between,
                                          pseudo_stick_ratio)


def test_pseudo_stick_ratio_is_one_minus_force_ratio_before_slip_and_zero_after():
    ft = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 3.5])
    travel = np.array([0.0, 0.001, 0.002, 0.003, 0.05, 0.2])
    lab = pseudo_stick_ratio(ft, travel)
    assert lab.gross_slip_index == 4
    assert lab.tangential_force_slip_n == 4.0
    np.testing.assert_allclose(lab.pseudo_stick_ratio, [1.0, 0.75, 0.5, 0.25, 0.0, 0.0])


def test_force_slip_is_the_peak_force_when_the_force_drops_during_the_slide():
    lab = pseudo_stick_ratio(np.array([0.0, 2.0, 4.0, 1.0]), np.array([0, 0, 0, 0.1]))
    assert lab.tangential_force_slip_n == 4.0


def test_series_without_gross_slip_has_no_label():
    lab = pseudo_stick_ratio(np.arange(5.0), np.zeros(5))
    assert lab.gross_slip_index == -1
    assert np.isnan(lab.pseudo_stick_ratio).all()


def test_gross_slip_threshold_is_inclusive():
    lab = pseudo_stick_ratio(np.arange(4.0), np.array([0, 0, GROSS_SLIP_MM, 0]))
    assert lab.gross_slip_index == 2


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0, 10), min_size=3, max_size=40), st.integers(0, 39))
def test_labels_lie_in_unit_interval_and_vanish_after_slip(forces, k):
    ft = np.sort(np.array(forces))
    k = min(k, len(ft) - 1)
    travel = np.zeros(len(ft))
    travel[k] = 1.0
    s = pseudo_stick_ratio(ft, travel).pseudo_stick_ratio
    assert ((s >= 0) & (s <= 1)).all()
    assert (s[k:] == 0).all()


def test_travel_is_measured_within_the_period_so_a_jump_at_its_start_is_not_slip():
    t = np.arange(0, 3, 1 / 120)
    y = np.where(t < 1.0, 0.0, 0.3)             # deformation jump at the period start (1.0 s)
    y = y + np.where(t < 2.2, 0.0, 1.0)         # a slide in the middle of the period 2.0-2.5 s
    travel = gross_slip_travel_mm(t, y, np.array([1.0, 1.5, 2.0, 2.5, 3.0]))
    np.testing.assert_allclose(travel, [0, 0, 0, 1, 0], atol=1e-12)


def test_mocap_average_falls_back_to_interpolation_between_sparse_samples():
    t = np.array([0.0, 1.0])
    np.testing.assert_allclose(mocap_mean_between(t, np.array([0.0, 2.0]), np.array([0.4]),
                                                  np.array([0.6])), [1.0])


def test_true_ratio_label_is_the_periods_load_ratio_and_zero_in_gross_slip():
    from incipient_slip.models.labels import true_ratio_label
    lrs = np.array([0.9, 0.6, np.nan, 1.3, -0.1, 0.4])
    slip = np.array([False, False, False, False, False, True])
    np.testing.assert_allclose(true_ratio_label(lrs, slip), [0.9, 0.6, 0.0, 1.0, 0.0, 0.0])


def test_label_option_changes_only_the_targets(fake_injection_dir, tmp_path):
    # extension (not the paper's method): --label true-ratio trains on load_ratio_stick[k]
    import shutil
    import pytest
    from incipient_slip.models import dataset as ds
    from incipient_slip.models.features import feature_spec
    from incipient_slip.models.labels import label_series, true_ratio_label
    from incipient_slip.models.training import load_windows
    # the fake data's truth equals the pseudo label: make it differ (half, one nan period)
    shutil.copytree(fake_injection_dir, tmp_path / "d")
    fake_injection_dir = tmp_path / "d"
    for path in ds.series_paths(fake_injection_dir):
        z = dict(np.load(path))
        z["load_ratio_stick"] = 0.5 * z["load_ratio_stick"]
        z["load_ratio_stick"][3] = np.nan
        np.savez(path, **z)
    spec = feature_spec("e4")
    pseudo = load_windows(fake_injection_dir, spec, progress=False, after_slip="drop")
    true = load_windows(fake_injection_dir, spec, progress=False, after_slip="drop", label="true-ratio")
    np.testing.assert_array_equal(pseudo.X, true.X)
    np.testing.assert_array_equal(pseudo.period, true.period)
    expect = true_ratio_label(true.load_ratio_stick, np.zeros(len(true.y), bool))
    for path in ds.series_paths(fake_injection_dir):          # period k's value, 0 in gross slip
        s = ds.load_series(path)
        rows = true.series == s.index
        expect[rows] = true_ratio_label(s.load_ratio_stick, s.gross_slip)[true.period[rows]]
        np.testing.assert_allclose(pseudo.y[rows], label_series(s).pseudo_stick_ratio[pseudo.period[rows]])
    np.testing.assert_allclose(true.y, expect)
    assert not np.allclose(true.y, pseudo.y)
    with pytest.raises(ValueError):
        load_windows(fake_injection_dir, spec, progress=False, label="bogus")


# --- measured-ratio: 1 - F_T / (mu_hat F_hat), mu_hat the largest load ratio the contact held ---------

from incipient_slip.models.labels import (LabelRule, held_friction_coefficient, lagged_force,  # noqa: E402
                                          measured_ratio_label, rule_of_header)
import math  # noqa: E402

import pytest  # noqa: E402


def test_measured_ratio_at_constant_normal_force_is_the_papers_label():
    # F_N constant: the largest held F_T is F_T^slip when the onset period's F_T has dropped
    ft = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 3.5])
    travel = np.array([0.0, 0.001, 0.002, 0.003, 0.004, 0.2])
    fn = np.full(6, 2.7)
    np.testing.assert_allclose(measured_ratio_label(ft, fn, travel),
                               pseudo_stick_ratio(ft, travel).pseudo_stick_ratio)


def test_measured_ratio_recovers_the_load_ratio_under_a_per_period_redraw():
    rng = np.random.default_rng(3)
    mu, fn = 0.22, rng.choice(np.arange(1.1, 5.95, 0.4), size=200)
    truth = rng.uniform(0.0, 1.0, size=200)
    truth[17] = 0.0                                    # the contact reached its limit once
    ft = (1.0 - truth) * mu * fn
    label = measured_ratio_label(ft, fn, np.zeros(200))
    np.testing.assert_allclose(label, truth, atol=1e-12)
    # the paper's label on the same series reads low wherever F_N is above the onset's draw
    travel = np.zeros(200)
    travel[18] = 0.1
    paper = pseudo_stick_ratio(ft, travel).pseudo_stick_ratio[:18]
    assert np.all(paper[fn[:18] > fn[17] + 1e-9] < truth[:18][fn[:18] > fn[17] + 1e-9] + 1e-12)


def test_an_identified_lag_recovers_the_ratio_that_an_instant_friction_limit_misreads():
    rng = np.random.default_rng(5)
    mu, tau, fn = 0.2, 1.0, rng.choice([1.1, 3.5, 5.9], size=300)
    f_eff = lagged_force(fn, tau)
    truth = rng.uniform(0.0, 1.0, size=300)
    truth[40] = 0.0
    ft = (1.0 - truth) * mu * f_eff
    np.testing.assert_allclose(measured_ratio_label(ft, fn, np.zeros(300), friction_lag_s=tau), truth, atol=1e-9)
    assert np.abs(measured_ratio_label(ft, fn, np.zeros(300)) - truth).max() > 0.2


def test_lagged_force_is_the_first_order_lag_and_zero_lag_is_f_n():
    fn = np.array([1.1, 5.9, 5.9, 1.1])
    np.testing.assert_array_equal(lagged_force(fn, 0.0), fn)
    keep = math.exp(-0.5 / 0.5)
    expected = [1.1]
    for f in fn[1:]:
        expected.append(f + (expected[-1] - f) * keep)
    np.testing.assert_allclose(lagged_force(fn, 0.5), expected)
    assert np.all(np.diff(lagged_force(np.r_[1.1, np.full(40, 5.9)], 2.0)) > 0)   # rises towards a step, never past it
    assert lagged_force(np.r_[1.1, np.full(40, 5.9)], 2.0)[-1] <= 5.9


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 5.0), st.floats(0.0, 6.0), st.floats(-0.1, 0.5)), min_size=1, max_size=40),
       st.sampled_from([0.0, 0.3, 2.0]))
def test_measured_ratio_is_finite_in_0_1_and_0_where_the_rule_flags_a_slide(rows, lag):
    ft, fn, travel = (np.array(c) for c in zip(*rows))
    label = measured_ratio_label(ft, fn, travel, lag)
    sliding = travel >= GROSS_SLIP_MM
    assert np.all(label[sliding] == 0.0)
    if math.isfinite(held_friction_coefficient(ft, lagged_force(fn, lag), sliding)):
        assert np.all(np.isfinite(label)) and np.all((label >= 0.0) & (label <= 1.0))
    else:                                   # nothing held any load: no friction coefficient, no ratio
        assert np.all(np.isnan(label[~sliding]))


def test_label_rules_name_their_bad_input():
    with pytest.raises(ValueError, match="unknown"):
        LabelRule("pseudo-ish")
    with pytest.raises(ValueError, match=">= 0"):
        LabelRule("measured-ratio", -0.5)
    with pytest.raises(ValueError, match="measured-ratio label only"):
        LabelRule("pseudo", 0.5)
    assert rule_of_header({"label": "measured-ratio", "friction_lag_s": 0.5}) == LabelRule("measured-ratio", 0.5)
    assert rule_of_header({}) == LabelRule()

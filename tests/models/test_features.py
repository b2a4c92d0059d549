import numpy as np
import pytest

from incipient_slip.models import dataset as ds
from incipient_slip.models.features import (ELECTRODE_SUBSETS, METHODS, feature_spec, phi,
                                            series_feature_sets, series_features, spectrum_bin_matrix,
                                            valid_window_mask)


def test_paper_spectrum_has_109_ten_hz_bins_from_10_to_1100_hz():
    spec = feature_spec("injection")
    assert spec.window_samples == 2200
    assert spec.n_features == 109


def test_bin_matrix_averages_each_fft_line_once_within_the_band():
    m = spectrum_bin_matrix(2200, 2200, (10.0, 1100.0), 10.0)
    freqs = np.fft.rfftfreq(2200, 1 / 2200)
    np.testing.assert_allclose(m.sum(axis=0), 1.0, rtol=1e-6)
    used = m.sum(axis=1) > 0
    assert freqs[used].min() == 10 and freqs[used].max() == 1100


def test_sine_lands_in_its_bin_with_its_amplitude():
    spec = feature_spec("injection", log10=False)
    t = np.arange(2200) / 2200
    f = phi(100.0 * np.sin(2 * np.pi * 205 * t), spec)[0]
    assert np.argmax(f) == (205 - 10) // 10
    # Hann taper: a bin-centred sine of amplitude A reads A at its line, A/2 at the two
    # neighbours; the 10-line bin averages them to 2A / 10
    assert f.max() == pytest.approx(100.0 * 2 / 10, rel=0.02)


def test_log_spectrum_is_log10_of_amplitude_plus_floor():
    rng = np.random.default_rng(0)
    w = rng.normal(0, 50, (3, 2200))
    lin = phi(w, feature_spec("injection", log10=False))
    np.testing.assert_allclose(phi(w, feature_spec("injection")), np.log10(lin + 1e-3), rtol=1e-5)


def test_spectrum_ignores_a_dc_offset():
    rng = np.random.default_rng(1)
    w = rng.normal(0, 50, (1, 2200))
    spec = feature_spec("injection")
    np.testing.assert_allclose(phi(w, spec), phi(w + 1000, spec), atol=1e-4)


def test_vectorized_phi_equals_per_window_phi():
    rng = np.random.default_rng(2)
    w = rng.normal(0, 50, (5, 2200))
    spec = feature_spec("vibrotactile")
    np.testing.assert_allclose(phi(w, spec), np.vstack([phi(x, spec) for x in w]), rtol=1e-5)


def test_electrode_subsets_are_equal_interval_sparsifications_and_the_centre_electrode():
    assert ELECTRODE_SUBSETS["e19"] == tuple(range(1, 20))
    assert ELECTRODE_SUBSETS["e10"] == (1, 3, 5, 7, 9, 11, 13, 15, 17, 19)
    assert ELECTRODE_SUBSETS["e4"] == (1, 7, 13, 19)
    assert ELECTRODE_SUBSETS["e1"] == (17,)


def test_series_features_match_phi_of_the_window_ending_at_each_period(fake_injection_dir):
    s = ds.load_series(ds.series_paths(fake_injection_dir)[0])
    for method in ("injection", "e10"):
        spec = feature_spec(method)
        n_stream = len(s.pac_counts) if spec.stream == "pac" else len(s.electrode_counts)
        ends = s.period_end_s[valid_window_mask(s.period_end_s, spec, n_stream)]
        X = series_features(s, spec, ends)
        stop = int(round(ends[3] * spec.rate_hz))
        stream = s.pac_counts if spec.stream == "pac" else s.electrode_counts
        np.testing.assert_allclose(X[3], phi(stream[stop - spec.window_samples:stop], spec)[0], rtol=1e-4)


def test_series_features_cut_exactly_the_windows_ending_at_each_period(fake_injection_dir):
    """The windows are cut as a view of the stream (no index array): phi of them is phi of the
    slices stream[stop - n:stop] stacked, bit for bit."""
    s = ds.load_series(ds.series_paths(fake_injection_dir)[1])
    spec = feature_spec("injection")
    ends = s.period_end_s[valid_window_mask(s.period_end_s, spec, len(s.pac_counts))]
    stops = np.round(ends * spec.rate_hz).astype(int)
    assert len(stops) <= 512                    # one chunk: the same batch for both
    sliced = np.stack([s.pac_counts[stop - spec.window_samples:stop] for stop in stops])
    np.testing.assert_array_equal(series_features(s, spec, ends), phi(sliced, spec))


def test_feature_sets_sharing_an_fft_equal_each_spec_alone_bit_for_bit(fake_injection_dir):
    """Specs that differ only after the FFT (bins, band, log) share each window's FFT; the result
    is the floats of each spec alone, and of phi of the sliced windows."""
    s = ds.load_series(ds.series_paths(fake_injection_dir)[1])
    specs = [feature_spec("injection"), feature_spec("injection", bin_hz=2.0),
             feature_spec("injection", band_hz=(400.0, 1100.0), log10=False), feature_spec("e10"),
             feature_spec("injection", window_s=0.5), feature_spec("injection", bin_hz=50.0, window_s=0.5)]
    ends = s.period_end_s[valid_window_mask(s.period_end_s, specs[0], len(s.pac_counts))]
    got = series_feature_sets(s, specs, ends, chunk=64)      # several chunks
    for spec, X in zip(specs, got):
        np.testing.assert_array_equal(X, series_features(s, spec, ends, chunk=64))
        if spec.stream == "pac":
            stops = np.round(ends * spec.rate_hz).astype(int)
            sliced = np.stack([s.pac_counts[stop - spec.window_samples:stop] for stop in stops[:64]])
            np.testing.assert_array_equal(X[:64], phi(sliced, spec))
        assert X.shape == (len(ends), spec.n_features) and np.isfinite(X).all()


def test_first_valid_window_needs_a_full_window_of_data():
    spec = feature_spec("injection", window_s=1.0)
    mask = valid_window_mask(np.array([0.5, 1.0, 1.5]), spec, 10_000)
    assert mask.tolist() == [False, True, True]


def test_spec_hash_changes_with_any_phi_parameter():
    base = feature_spec("injection")
    assert base.spec_hash() != feature_spec("injection", bin_hz=5.0).spec_hash()
    assert base.spec_hash() != feature_spec("injection", window_s=0.5).spec_hash()
    assert len({feature_spec(m).spec_hash() for m in METHODS}) == len(METHODS)


def test_unknown_method_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown method 'e7'"):
        feature_spec("e7")

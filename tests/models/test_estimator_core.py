import numpy as np
import pytest

from incipient_slip.models import dataset as ds
from incipient_slip.models.estimator_core import (StreamError, StreamingEstimator, estimate_window)
from incipient_slip.models.features import feature_spec, series_features
from incipient_slip.models.modelfile import Model

PAC_NS = 1e9 / 2200


def _linear_model(method):
    spec = feature_spec(method)
    n = spec.n_features
    w = np.linspace(-0.1, 0.1, n)
    return Model(spec=spec, kind="linear", mean=np.zeros(n), scale=np.full(n, 10.0 if method != "injection" else 1.0),
                 weights=w, intercept=0.5)


def _pac_frames(pac, first_frame=0, seq0=0):
    """Yield (stamp_ns, seq, counts) of 22-sample frames stamped at their last sample."""
    for j in range(first_frame, len(pac) // 22):
        last = (j + 1) * 22 - 1
        yield int(round(last * PAC_NS)), seq0 + j, pac[j * 22:(j + 1) * 22]


def _feed_until(est, frames, end_ns):
    for stamp, seq, counts in frames:
        est.push(stamp, seq, counts)
        if stamp >= end_ns:
            return


@pytest.fixture(scope="module")
def series(fake_injection_dir):
    return ds.load_series(ds.series_paths(fake_injection_dir)[1])


def test_streamed_estimate_equals_offline_phi_and_predict(series):
    model = _linear_model("injection")
    est = StreamingEstimator(model)
    frames = _pac_frames(series.pac_counts)
    ends = series.period_end_s[2:8]
    offline = model.predict(series_features(series, model.spec, ends))
    for end, want in zip(ends, offline):
        end_ns = int(round(end * 1e9))
        _feed_until(est, frames, end_ns)
        s, valid, reason = est.estimate(end_ns)
        assert (valid, reason) == (True, "ok")
        assert s == pytest.approx(want, abs=1e-5)


def test_streamed_electrode_estimate_equals_offline(series):
    model = _linear_model("e4")
    est = StreamingEstimator(model)
    end = series.period_end_s[5]
    for j in range(int(round(end * 100)) + 1):
        est.push(int(round(j * 1e7)), j, series.electrode_counts[j])
    s, valid, _ = est.estimate(int(round(end * 1e9)))
    assert valid
    assert s == pytest.approx(model.predict(series_features(series, model.spec, [end]))[0], abs=1e-5)


def test_estimate_is_invalid_while_the_first_window_fills(series):
    est = StreamingEstimator(_linear_model("injection"))
    _feed_until(est, _pac_frames(series.pac_counts), int(0.5e9))
    assert est.estimate(int(0.5e9)) == (pytest.approx(np.nan, nan_ok=True), False, "filling")


def test_estimate_is_invalid_after_seq_gap_until_the_window_refills(series):
    est = StreamingEstimator(_linear_model("injection"))
    frames = list(_pac_frames(series.pac_counts))
    for stamp, seq, counts in frames[:200]:            # 2 s of frames
        est.push(stamp, seq, counts)
    assert est.estimate(int(2.0e9)).valid
    for stamp, seq, counts in frames[201:250]:         # frame 200 lost
        est.push(stamp, seq, counts)
    result = est.estimate(int(2.5e9))
    assert (result.valid, result.reason) == (False, "seq gap")
    assert est.gaps == 1
    for stamp, seq, counts in frames[250:352]:
        est.push(stamp, seq, counts)
    assert not est.estimate(int(3.0e9)).valid          # [2.0, 3.0) still misses frame 200
    assert est.estimate(int(3.5e9)).valid              # [2.5, 3.5) is whole again


def test_estimate_is_invalid_on_a_stale_stream(series):
    est = StreamingEstimator(_linear_model("injection"), stale_after_ns=50_000_000)
    _feed_until(est, _pac_frames(series.pac_counts), int(2.0e9))
    assert est.estimate(int(2.0e9)).valid
    assert est.estimate(int(2.5e9)) [1:] == (False, "stale")


def test_a_stamp_going_backwards_empties_the_window(series):
    est = StreamingEstimator(_linear_model("injection"))
    frames = list(_pac_frames(series.pac_counts))
    for stamp, seq, counts in frames[:200]:
        est.push(stamp, seq, counts)
    est.push(frames[10][0], 200, frames[10][2])
    assert est.estimate(frames[10][0]).reason == "stamp went backwards"


@pytest.mark.parametrize("bad", [np.zeros((2, 11), np.int16), np.zeros(22, np.float32), np.zeros(0, np.int16)])
def test_malformed_pac_frame_is_refused_and_leaves_the_buffer_intact(series, bad):
    est = StreamingEstimator(_linear_model("injection"))
    _feed_until(est, _pac_frames(series.pac_counts), int(2.0e9))
    with pytest.raises(StreamError):
        est.push(int(2.0e9), 10_000, bad)
    assert est.estimate(int(2.0e9)).valid


def test_electrode_frame_on_a_pac_model_is_refused():
    est = StreamingEstimator(_linear_model("injection"))
    with pytest.raises(StreamError, match="reads P_AC"):
        est.push_slow(0, 0, np.zeros(19, np.uint16))


def test_buffer_keeps_working_over_a_long_stream(series):
    est = StreamingEstimator(_linear_model("injection"), capacity_s=0.5)
    frames = _pac_frames(series.pac_counts)
    for k in range(2, 30):
        _feed_until(est, frames, int(k * 0.5e9))
        assert est.estimate(int(k * 0.5e9)).valid


def test_estimate_window_matches_the_model_on_phi(series):
    model = _linear_model("injection")
    w = series.pac_counts[:2200]
    assert estimate_window(model, w) == pytest.approx(model.predict(
        series_features(series, model.spec, [1.0]))[0], abs=1e-6)


def test_limit_blas_threads_returns_a_controller():
    from incipient_slip.models.estimator_core import limit_blas_threads
    with limit_blas_threads(1):
        pass

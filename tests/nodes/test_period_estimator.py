"""The estimator node's scheduling core (`PeriodEstimator`) without sockets: one estimate per
period boundary by stamps, catch-up over holes, resync after stamp jumps, invalid after seq
gaps, the wall-clock watchdog, and any uint64 stamp."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.messages import PERIOD_NS
from incipient_slip.models.estimator_core import MAX_CATCH_UP, PeriodEstimator
from incipient_slip.models.features import feature_spec
from incipient_slip.models.modelfile import Model

FRAME = 22                      # P_AC samples per 10 ms frame
FRAMES_PER_PERIOD = 50
WINDOW_S = 0.5


def small_model(window_s=WINDOW_S):
    spec = feature_spec("injection", window_s=window_s)
    n = spec.n_features
    return Model(spec=spec, kind="linear", mean=np.zeros(n), scale=np.ones(n),
                 weights=np.full(n, 1e-4), intercept=0.5)


MODEL = small_model()
COUNTS = np.random.default_rng(0).normal(0, 40, FRAME).astype(np.int16)


def frame_stamp(j: int, origin_ns: int = 0) -> int:
    """Stamp of P_AC frame j: its last sample, round((22 j + 21) 1e9 / 2200) ns after origin."""
    return origin_ns + ((FRAME * j + FRAME - 1) * 2_000_000_000 + 2200) // 4400


def feed(core, frames, seq_of=lambda j: j, origin_ns=0):
    """Pushes frames j (in order); returns every estimate in order and the warnings."""
    out, warnings = [], []
    for j in frames:
        estimates, warning = core.frame(frame_stamp(j, origin_ns), seq_of(j), COUNTS, now_s=0.0)
        out += estimates
        warnings += [warning] if warning else []
    return out, warnings


@settings(max_examples=60, deadline=None)
@given(st.sets(st.integers(1, 8 * FRAMES_PER_PERIOD - 2), max_size=60), st.booleans())
def test_every_boundary_gets_exactly_one_estimate_whatever_frames_are_lost(lost, renumber):
    """Lost frames (as seq gaps, or as a hole in a renumbered stream) never skip or repeat a period."""
    frames = [j for j in range(8 * FRAMES_PER_PERIOD) if j not in lost]
    seq_of = (lambda j: frames.index(j)) if renumber else (lambda j: j)
    out, _ = feed(PeriodEstimator(MODEL), frames, seq_of)
    assert [e.period for e in out] == list(range(8))
    assert [e.window_end_ns for e in out] == [(k + 1) * PERIOD_NS for k in range(8)]


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6 * FRAMES_PER_PERIOD - 2), st.integers(1, 40))
def test_no_estimate_after_a_seq_gap_is_valid_until_a_full_window_follows_it(gap_at, lost):
    frames = [j for j in range(6 * FRAMES_PER_PERIOD) if not gap_at <= j < gap_at + lost]
    core = PeriodEstimator(MODEL)
    out, _ = feed(core, frames)
    span_ns = (FRAME - 1) * 1e9 / 2200
    lost_ns = frame_stamp(gap_at) - span_ns                  # first sample lost
    resumed_ns = frame_stamp(gap_at + lost) - span_ns        # first sample after the gap
    window_ns = WINDOW_S * 1e9
    for e in out:                                            # a window that holds lost samples
        if e.window_end_ns - window_ns < resumed_ns - 1e9 / 4400 and e.window_end_ns > lost_ns:
            assert not e.valid, e
    if resumed_ns + window_ns <= out[-1].window_end_ns:
        assert out[-1].valid                       # a full window later it is valid again


def test_a_hole_is_caught_up_but_a_long_jump_resynchronizes():
    core = PeriodEstimator(MODEL)
    out, _ = feed(core, range(100))                                      # periods 0, 1
    hole = (MAX_CATCH_UP - 1) * FRAMES_PER_PERIOD                        # within the catch-up
    out2, warnings = feed(core, range(100 + hole, 100 + hole + 100), seq_of=lambda j: j - hole)
    assert [e.period for e in out + out2] == list(range(MAX_CATCH_UP + 3)) and not warnings
    jump = 1000 * FRAMES_PER_PERIOD                                      # 500 s: resync
    out3, warnings = feed(core, range(jump, jump + 100), seq_of=lambda j: j)
    assert [e.period for e in out3][-2:] == [jump // FRAMES_PER_PERIOD, jump // FRAMES_PER_PERIOD + 1]
    assert len(out3) <= 3 and "resynchronizing" in warnings[0] and core.resyncs == 1


def test_a_stamp_going_backwards_restarts_the_periods():
    core = PeriodEstimator(small_model(window_s=1.0))
    out, _ = feed(core, range(150))
    again, _ = feed(core, range(150), seq_of=lambda j: 150 + j)
    assert [e.period for e in out + again] == [0, 1, 2, 0, 1, 2]
    assert not again[0].valid and again[2].valid
    # the cause the wire carries (what the grip controller switches on), beside the words
    assert [e.cause for e in out] == ["filling", "ok", "ok"]
    assert again[0].cause == "backwards" and again[2].cause == "ok"


def test_watchdog_gives_one_stale_estimate_when_the_stream_stops():
    core = PeriodEstimator(MODEL, wall_timeout_s=0.3)
    core.frame(frame_stamp(0), 0, COUNTS, now_s=10.0)
    assert core.tick(10.29) == []
    [stale] = core.tick(10.3)
    assert stale.period == 0 and not stale.valid and stale.reason.startswith("stale") and stale.cause == "stale"
    assert core.tick(11.0) == [] and core.tick(20.0) == []                # once, not per tick
    core.frame(frame_stamp(1), 1, COUNTS, now_s=20.0)
    assert core.tick(20.31)[0].period == 1                                # armed again by a frame


@pytest.mark.parametrize("origin_ns", [2 ** 63 - 10 ** 9, 2 ** 64 - 5 * 10 ** 9])
def test_stamps_up_to_two_to_the_64_give_estimates_not_overflow(origin_ns):
    core = PeriodEstimator(MODEL)
    origin_ns -= origin_ns % PERIOD_NS
    out, warnings = feed(core, range(150), origin_ns=origin_ns)
    assert not warnings and [e.period for e in out] == [origin_ns // PERIOD_NS + k for k in range(3)]
    assert out[-1].valid and all(e.window_end_ns < 2 ** 64 for e in out)


def test_the_last_uint64_stamp_is_refused_and_counted_not_raised():
    core = PeriodEstimator(MODEL)
    feed(core, range(60))
    estimates, warning = core.frame(2 ** 64 - 1, 60, COUNTS, now_s=0.0)
    assert estimates == [] and "leaves no period boundary" in warning and core.refused == 1
    out, _ = feed(core, range(60, 120))
    assert [e.period for e in out] == [1]                                 # the stream goes on


def test_pzt_state_that_contradicts_the_model_invalidates_estimates():
    core = PeriodEstimator(MODEL)
    assert "PZT is off" in core.pzt(False)
    out, _ = feed(core, range(150))
    assert not any(e.valid for e in out) and "PZT is off" in out[-1].reason and out[-1].cause == "pzt_mismatch"
    assert core.pzt(True) == ""

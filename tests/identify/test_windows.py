"""The identifier's period windows (`identify.PeriodWindows`), pure: no sockets, no node."""
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from incipient_slip import identify
from incipient_slip.messages import PERIOD_NS

RATE = 120.0                      # mocap Hz: 60 samples a period, complete with 54


def samples(lo_ns: int, n: int = 60, y: float = 1.0) -> list[tuple[int, float]]:
    return [(lo_ns + int(i * 1e9 / RATE), y + i * 1e-3) for i in range(n)]


def test_lock_step_period_k_is_k_T_to_k_plus_1_T_and_takes_the_last_force_before_its_end():
    w = identify.PeriodWindows(real_time=False, mocap_rate_hz=RATE)
    w.tick(0, 123, 5.0)
    assert w.next() is None                        # no samples yet
    for s, y in samples(0):
        w.pose(s, y)
    w.force(PERIOD_NS - 1, 2.2)
    w.force(PERIOD_NS, 9.9)                        # after the period: not its F_N
    obs = w.next()
    assert isinstance(obs, identify.Observation)
    assert (obs.period, obs.normal_force_kpa, obs.actuator_mm, obs.t_end_s) == (0, 2.2, 5.0, PERIOD_NS / 1e9)
    assert len(obs.mocap_t_s) == 60 and obs.mocap_y_mm[0] == 1.0
    assert w.next() is None and w.next_period == 1      # period 1 waits for its tick


def test_a_period_waits_for_90_percent_of_its_samples_or_a_later_one():
    w = identify.PeriodWindows(real_time=False, mocap_rate_hz=RATE)
    w.tick(0, 0, 0.0)
    for s, y in samples(0, 50):
        w.pose(s, y)
    assert w.next() is None                        # 50 < 54: more may come
    w.pose(PERIOD_NS + 1, 0.0)                     # a sample of the next period: none will
    obs = w.next()
    assert len(obs.mocap_y_mm) == 50 and math.isnan(obs.normal_force_kpa)   # no F_N heard


def test_real_time_window_starts_settle_after_the_tick_and_takes_the_origin_off():
    w = identify.PeriodWindows(real_time=True, mocap_rate_hz=RATE, settle_s=0.5, origin_mm=12.5)
    tick = 10 * PERIOD_NS
    w.tick(0, tick, 13.0)
    for s, y in samples(tick, 60, y=7.0):          # during the settle: not the period's
        w.pose(s, y)
    for s, y in samples(tick + PERIOD_NS, 60, y=1.0):
        w.pose(s, y)
    w.pose(tick + 2 * PERIOD_NS, 0.0)
    obs = w.next()
    assert obs.actuator_mm == 0.5 and obs.mocap_y_mm[0] == 1.0 and len(obs.mocap_y_mm) == 60
    assert obs.t_end_s == (tick + 2 * PERIOD_NS) / 1e9


def test_a_hole_in_the_mocap_stream_is_observed_again_then_given_up():
    w = identify.PeriodWindows(real_time=True, mocap_rate_hz=RATE, settle_s=0.0, max_retries=2)
    w.tick(0, 0, 1.0)
    got = []
    for j in range(4):                             # each window holds only 10 samples
        for s, y in samples(j * PERIOD_NS, 10):
            w.pose(s, y)
        w.pose((j + 1) * PERIOD_NS, 0.0)
        got.append(w.next())
    assert [(r.retried, r.give_up) for r in got[:3]] == [(1, False), (2, False), (2, True)]
    assert all(isinstance(r, identify.WindowRetry) and r.period == 0 and r.samples <= 11 for r in got[:3])


def test_lock_step_has_no_retries_a_thin_window_is_a_period():
    w = identify.PeriodWindows(real_time=False, mocap_rate_hz=RATE)
    w.tick(0, 0, 0.0)
    for s, y in samples(0, 5):
        w.pose(s, y)
    w.pose(PERIOD_NS, 0.0)
    assert isinstance(w.next(), identify.Observation)


@settings(max_examples=40, deadline=None)
@given(cuts=st.lists(st.integers(0, 400), max_size=12), n_periods=st.integers(1, 4),
       real_time=st.booleans())
def test_however_the_samples_arrive_each_period_comes_once_in_order_from_its_own_window(cuts, n_periods,
                                                                                     real_time):
    """Fed all at once or in any chunks, with next() called between: the same periods, each from
    90 % or more of its own window's samples (a period is answered once 90 % are in), its F_N the
    last heard before its end."""
    settle = 0.25 if real_time else 0.0
    events = []
    for k in range(n_periods):
        start = k * 2 * PERIOD_NS if real_time else k * PERIOD_NS
        lo = start + (int(settle * 1e9) if real_time else 0)
        events += [("tick", k, start, 0.1 * k), ("force", lo + 10, 1.0 + k)]
        events += [("pose", s, y) for s, y in samples(lo, 60, y=float(k))]
    events.append(("pose", 10 * n_periods * PERIOD_NS, 0.0))

    def run(chunks):
        w = identify.PeriodWindows(real_time=real_time, mocap_rate_hz=RATE, settle_s=settle)
        out, i = [], 0
        for j in sorted(set(chunks)) + [len(events)]:
            for e in events[i:j]:
                getattr(w, e[0])(*e[1:])
            i = max(i, j)
            while (obs := w.next()) is not None:
                out.append(obs)
        return out

    at_once, chunked = run([]), run([min(c, len(events)) for c in cuts])
    assert [o.period for o in chunked] == [o.period for o in at_once] == list(range(n_periods))
    for a, b in zip(at_once, chunked):
        assert (b.normal_force_kpa, b.actuator_mm, b.t_end_s) == (a.normal_force_kpa, a.actuator_mm, a.t_end_s)
        n = len(b.mocap_t_s)
        assert 54 <= n <= 60 and np.array_equal(b.mocap_y_mm, a.mocap_y_mm[:n])
        assert np.all(b.mocap_y_mm - b.period < 0.1)           # only its own window's samples

"""control.PeriodOrigin: device clocks (host time) mapped onto the run's period clock by the first tick."""
from __future__ import annotations

import pytest
from hypothesis import given, strategies as st

from incipient_slip.control import PeriodOrigin
from incipient_slip.messages import PERIOD_NS


def test_stamps_mode_is_the_identity_and_holds_nothing():
    origin = PeriodOrigin("stamps")
    assert not origin.hold("frame") and origin.relative(123) == 123 and origin.tick(0, 10**18) == []


def test_unknown_mode_is_a_named_error():
    with pytest.raises(ValueError, match="period origin 'wall'"):
        PeriodOrigin("wall")


@given(host=st.integers(10**17, 2 * 10**18), step=st.integers(0, 5),
       offsets=st.lists(st.integers(-3 * PERIOD_NS, 3 * PERIOD_NS), max_size=30))
def test_tick_k_ends_period_k_and_held_messages_come_back_in_order(host, step, offsets):
    origin = PeriodOrigin("tick", held_max=100)
    assert origin.relative(host) is None                     # nothing before the origin is known
    for off in offsets:
        assert origin.hold(off)
    tick_stamp = host + (step + 1) * PERIOD_NS
    assert origin.tick(step, tick_stamp) == offsets           # replayed as they arrived
    assert origin.tick(step + 1, tick_stamp + PERIOD_NS) == []   # later ticks change nothing
    assert origin.relative(tick_stamp) == (step + 1) * PERIOD_NS
    assert origin.relative(tick_stamp - 1) // PERIOD_NS == step   # the tick's stamp closes period k
    assert origin.relative(host) is None and origin.before_origin == 1
    assert not origin.hold("late")


def test_held_messages_beyond_the_bound_drop_the_oldest():
    origin = PeriodOrigin("tick", held_max=3)
    for i in range(5):
        origin.hold(i)
    assert origin.tick(0, 10**18) == [2, 3, 4]

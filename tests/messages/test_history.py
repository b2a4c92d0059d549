"""Recordings of older schema versions read as the current version (messages.history); the live
wire still refuses them."""
from __future__ import annotations

from pathlib import Path

import msgpack
import pytest

import incipient_slip.messages as M
from incipient_slip.graph.bag import BagWriter, read_bag
from incipient_slip.messages.history import UPGRADES, current_body, decode_recorded

DEMO_V1 = Path(__file__).resolve().parents[1] / "data" / "demo_v1.mcap"


def old_body(**fields) -> bytes:
    """A body as an older build wrote it (its map in the old field order)."""
    return msgpack.packb(fields)


V1_TICK = old_body(type="ActuatorState", v=1, stamp_ns=1_000_000_000, seq=4, position_mm=0.25, step_index=1, busy=False)


def v1_estimate(reason: str, valid: bool = False) -> bytes:
    return old_body(type="SlipEstimate", v=1, stamp_ns=5, seq=0, stick_ratio=0.4 if valid else float("nan"), valid=valid,
                    method="injection", window_end_ns=5, latency_ns=1, period=0, reason=reason)


def v1_command(reason: str, hold: bool) -> bytes:
    return old_body(type="GripCommand", v=1, stamp_ns=5, seq=0, normal_force_kpa=2.9, hold=hold, period=3, reason=reason)


def test_an_old_tick_reads_with_period_and_the_live_wire_refuses_it():
    msg = decode_recorded(V1_TICK, "/actuator/state")
    assert msg == M.ActuatorState(position_mm=0.25, period=1, stamp_ns=1_000_000_000, seq=4)
    for strict in (lambda b: M.decode(b, M.ActuatorState), M.decode_any):
        with pytest.raises(M.MessageError, match="schema version 1"):
            strict(V1_TICK)


@pytest.mark.parametrize("reason, valid, cause", [
    ("ok", True, "ok"), ("filling", False, "filling"), ("seq gap", False, "seq_gap"),
    ("stale: no frame for 0.5 s", False, "stale"), ("stamp went backwards", False, "backwards"),
    ("no data", False, "no_data"), ("PZT is off but the injection model was trained with injection on", False,
                                    "pzt_mismatch"), ("something else", False, "unknown"),
])
def test_an_old_estimate_gets_the_cause_of_its_reason(reason, valid, cause):
    msg = decode_recorded(v1_estimate(reason, valid))
    assert (msg.cause, msg.reason, msg.valid) == (cause, reason, valid)


@pytest.mark.parametrize("reason, hold, cause", [
    ("", False, "law"), ("no action", False, "no_action"), ("collection schedule", False, "schedule"),
    ("stale estimate", True, "stale_estimate"), ("estimate marked invalid (filling)", True, "estimate_invalid"),
    ("stick ratio nan is not finite", True, "estimate_not_finite"),
    ("stick ratio 1.5 outside [0, 1]", True, "estimate_out_of_range"),
    ("estimate of method 'e19', controller runs 'injection'", True, "estimate_other_method"),
    ("grip", False, "unknown"),
])
def test_an_old_command_gets_the_cause_of_its_reason(reason, hold, cause):
    assert decode_recorded(v1_command(reason, hold)).cause == cause


def test_an_old_body_that_breaks_the_contract_is_still_refused():
    bad = old_body(type="ActuatorState", v=1, stamp_ns=1, seq=0, position_mm=0.0, step_index=-1, busy=False)
    with pytest.raises(M.MessageError, match="period"):
        decode_recorded(bad)
    with pytest.raises(M.MessageError, match="schema version 0"):
        decode_recorded(old_body(type="ActuatorState", v=0, stamp_ns=1, seq=0, position_mm=0.0, step_index=1, busy=False))


def test_replay_sends_the_current_body():
    current = M.encode(M.ActuatorState(position_mm=0.25, period=1, stamp_ns=1_000_000_000, seq=4))
    assert current_body(current) is current
    assert current_body(V1_TICK) == current


def test_every_upgrade_chain_ends_at_the_current_version():
    for name, version in UPGRADES:
        cls = M.MESSAGE_TYPES[name]
        while (name, version) in UPGRADES:
            version += 1
        assert version == cls.SCHEMA_VERSION, f"{name} v{version} is not the current v{cls.SCHEMA_VERSION}"


def test_a_recording_of_the_old_schema_reads_through_the_bag_reader(tmp_path):
    """The shipped demo as the older build wrote it, and a bag of old bodies written here."""
    ticks = [r.message() for r in read_bag(DEMO_V1, [M.ActuatorState.TOPIC])]
    assert [t.period for t in ticks] == [1, 2, 3, 4]
    path = tmp_path / "old.mcap"
    with BagWriter(path) as bag:
        bag.write_body("/actuator/state", "ActuatorState", V1_TICK, log_time_ns=1, stamp_ns=1_000_000_000, seq=4)
        bag.write_body("/slip/estimate", "SlipEstimate", v1_estimate("filling"), log_time_ns=2, stamp_ns=5, seq=0)
    got = [r.message() for r in read_bag(path)]
    assert [type(m).__name__ for m in got] == ["ActuatorState", "SlipEstimate"]
    assert got[0].period == 1 and got[1].cause == "filling"


def test_recover_saves_an_old_body_as_the_current_version(tmp_path):
    from incipient_slip.graph.bag import recover
    src, dst = tmp_path / "old.mcap", tmp_path / "fixed.mcap"
    with BagWriter(src) as bag:
        bag.write_body("/actuator/state", "ActuatorState", V1_TICK, log_time_ns=1, stamp_ns=1_000_000_000, seq=4)
    assert recover(src, dst).malformed == 0
    [rec] = read_bag(dst)
    assert rec.body == current_body(V1_TICK) and M.decode(rec.body, M.ActuatorState).period == 1

"""The emulated BioTac and bridge (devices/biotac_emulator.py) against the host side of the link
(devices/biotac.py BridgeLink), in one process: the sensor answers as the protocol says, the
reader decodes exactly what the sensor sampled, and every injected fault is counted where it
belongs. Progress is driven by handshakes (lock-step frames, polling until a condition)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from incipient_slip.devices import biotac as bt
from incipient_slip.devices import biotac_emulator as em


class ConstantSignals:
    def sample(self, channel, t_ns):
        return 1234


def test_slave_answers_sampling_commands_with_parity_and_timing_errors():
    slave = em.BiotacSpiSlave(ConstantSignals())
    slave.command(bt.command_byte("PDC"), 0, 0)
    assert bt.decode_word(*slave.read_word(bt.AFTER_COMMAND_DELAY_NS)) == 1234
    slave.command(bt.RESEND, 0, 0)
    assert bt.decode_word(*slave.read_word(10**6)) == 1234       # the last word again
    slave.command(bt.command_byte("PDC"), 0, 0)
    assert bt.word_status(*slave.read_word(bt.AFTER_COMMAND_DELAY_NS - 1)) == "insufficient_sampling_delay"
    slave.command(bt.command_byte("PDC") ^ 0x01, 0, 0)           # command parity broken
    assert bt.word_status(*slave.read_word(10**6)) == "parity_error"
    slave.command(bt.with_odd_parity(0x40 | 50), 0, 0)           # no channel 50
    assert bt.word_status(*slave.read_word(10**6)) == "channel_not_recognized"
    slave.command(bt.with_odd_parity(0x11), 0, 0)                # not a sampling command
    assert bt.word_status(*slave.read_word(10**6)) == "unknown_command"
    fresh = em.BiotacSpiSlave(ConstantSignals())
    fresh.command(bt.RESEND, 0, 0)
    assert bt.word_status(*fresh.read_word(10**6)) == "nothing_to_resend"


def test_slave_property_reads_and_an_absent_sensor():
    slave = em.BiotacSpiSlave(ConstantSignals(), serial="BT-42")
    slave.command(bt.READ_PROPERTY, bt.PROPERTIES["serial_number"], 0)
    assert bytes(slave.read_property_byte(0) for _ in range(6)) == b"BT-42\0"
    absent = em.BiotacSpiSlave(ConstantSignals(), present=False)
    absent.command(bt.READ_PROPERTY, bt.PROPERTIES["serial_number"], 0)
    assert absent.read_property_byte(0) == 0xFF
    assert absent.read_word(10**6) == b"\xff\xff"


def test_fault_plan_names_a_bad_item():
    with pytest.raises(ValueError, match="KIND@FRAME"):
        em.FaultPlan.parse("parity@3")
    assert em.FaultPlan.parse("crc@3, drop@3").at == {3: ["crc", "drop"]}


def rig_server(tmp_path, faults="", lockstep=True, present=True):
    signals = em.RigSignals("paper", "pla", seed=3, normal_force_kpa=3.0)
    bridge = em.EmulatedBridge([em.BiotacSpiSlave(signals, present=present)], em.FaultPlan.parse(faults))
    return em.PtyBridgeServer(bridge, tmp_path / "biotac", lockstep=lockstep, replug_after_s=0.2).start()


def poll_until(link, predicate, timeout_s=20.0):
    readings = []
    deadline = time.monotonic() + timeout_s
    while not predicate(readings):
        assert time.monotonic() < deadline, f"timed out in state {link.state}: {link.events}"
        readings += link.poll()
        time.sleep(0.002)
    return readings


def expected_pac(served):
    return np.array(served["pac"]) - bt.BiotacUnits().pac_zero_counts


def test_link_decodes_exactly_what_the_sensor_sampled(tmp_path):
    server = rig_server(tmp_path)
    link = bt.BridgeLink(str(tmp_path / "biotac"))
    try:
        readings = poll_until(link, lambda r: len(r) >= 120)
    finally:
        link.close()
        server.stop()
    assert link.properties["serial_number"].startswith("BT")
    assert [r.frame_index for r in readings] == list(range(len(readings)))
    for r, served in zip(readings, server.bridge.served):
        assert r.device_time_ns == (served["device_time_us"] - server.bridge.served[0]["device_time_us"]) * 1000
        np.testing.assert_array_equal(r.pac, served["pac"])
        np.testing.assert_array_equal(r.electrodes, served["electrodes"])
        assert (r.pdc, r.tac, r.tdc) == (served["pdc"], served["tac"], served["tdc"])
    pac = np.concatenate([r.pac for r in readings]).astype(int)
    assert pac.std() > 5, "P_AC should carry the simulated injection, not a constant"
    assert link.stream.counters.frames_ok == len(readings)
    assert not link.stream.counters.parity_errors.any() and link.stream.counters.crc_errors == 0


FAULTS = "parity_flip@30,parity_flip@31,error_word@40,error_word@41,crc@50,drop@60,repeat@70,counter_jump@80"


def test_every_injected_fault_is_counted_where_it_belongs(tmp_path):
    server = rig_server(tmp_path, FAULTS)
    link = bt.BridgeLink(str(tmp_path / "biotac"))
    try:
        readings = poll_until(link, lambda r: len(r) >= 100)
    finally:
        link.close()
        server.stop()
    c = link.stream.counters
    ch = bt.REPORTED_CHANNELS.index
    assert c.parity_errors[ch("E16")] == 1 and c.parity_errors[ch("PAC")] == 1   # slots 30, 31
    assert c.error_words[ch("TAC")] == 1 and c.error_words[ch("PAC")] == 1       # slots 40, 41
    assert c.parity_errors.sum() == 2 and c.error_words.sum() == 2
    assert c.error_word_kinds[bt.ERROR_NAMES.index("insufficient_sampling_delay")] == 2
    assert (c.crc_errors, c.frames_dropped, c.frames_repeated, c.counter_jumps) == (1, 2, 1, 1)
    assert (c.pac_frames_refused, c.slow_frames_refused) == (2, 2)
    by_index = {r.frame_index: r for r in readings}
    assert 50 not in by_index and 60 not in by_index and 49 in by_index and 51 in by_index
    assert by_index[30].electrodes is None and by_index[30].pac is not None
    assert by_index[31].pac is None and by_index[31].electrodes is not None
    assert by_index[41].pac is None and by_index[40].electrodes is None
    assert len([r for r in readings if r.frame_index == 70]) == 1


def test_missing_sensor_is_reported_and_retried(tmp_path):
    server = rig_server(tmp_path, present=False)
    link = bt.BridgeLink(str(tmp_path / "biotac"), min_backoff_s=0.05)
    try:
        poll_until(link, lambda r: link.state == "no_sensor")
        poll_until(link, lambda r: len([e for e in link.events if "no BioTac" in e[1]]) >= 2)
    finally:
        link.close()
        server.stop()
    assert "does not start with 'BT'" in link.events[0][1]


def test_a_sensor_lost_mid_stream_fails_every_word_never_a_stale_value(tmp_path):
    server = rig_server(tmp_path, "missing@20")
    link = bt.BridgeLink(str(tmp_path / "biotac"))
    try:
        readings = poll_until(link, lambda r: len(r) >= 30)
    finally:
        link.close()
        server.stop()
    assert all(r.pac is None and r.electrodes is None for r in readings[20:])
    assert all(r.pac is not None for r in readings[:20])
    lost = len(readings) - 20
    c = link.stream.counters
    assert c.parity_errors[bt.REPORTED_CHANNELS.index("PAC")] >= 22 * lost
    assert c.parity_errors[bt.REPORTED_CHANNELS.index("E01")] >= lost


def test_unplug_is_detected_and_the_link_reconnects(tmp_path):
    server = rig_server(tmp_path, "unplug@40")
    link = bt.BridgeLink(str(tmp_path / "biotac"), min_backoff_s=0.05)
    try:
        readings = poll_until(link, lambda r: link.connections >= 2 and len(r) >= 60)
    finally:
        link.close()
        server.stop()
    assert link.reconnects == 1 and server.unplugs == 1
    assert any("unplugged" in text for _, text in link.events)
    # the bridge rebooted: its clock restarted, the link's frame index restarted with it; frames
    # still in the port's buffer at the unplug are lost, as on USB
    index = [r.frame_index for r in readings]
    restart = index.index(0, 1) if index.count(0) == 2 else 0
    assert restart <= 40
    assert index[:restart] == list(range(restart)) and index[restart:] == list(range(len(index) - restart))


def test_real_time_bridge_drops_frames_the_host_does_not_read(tmp_path):
    server = rig_server(tmp_path, lockstep=False)
    link = bt.BridgeLink(str(tmp_path / "biotac"))
    try:
        poll_until(link, lambda r: len(r) >= 5)
        deadline = time.monotonic() + 20    # the host stops reading until the bridge drops a frame
        while server.tx_dropped == 0:
            assert time.monotonic() < deadline, "the emulated bridge never dropped a frame"
            time.sleep(0.01)
        poll_until(link, lambda r: link.stream.counters.bridge_tx_dropped >= 1)
    finally:
        link.close()
        server.stop()
    assert link.stream.counters.frames_dropped >= 1


def test_frames_the_emulator_sends_late_are_caught_up_not_dropped(tmp_path):
    """An emulator starved of the CPU (hardware never is) sends its overdue frames in a burst
    larger than the port's buffer; none is dropped for it, while the host keeps reading."""
    signals = em.RigSignals("paper", "pla", seed=3, normal_force_kpa=3.0)
    # one frame a second of wall time: after the catch-up the host has a second before the
    # next frame is due, so no frame sent on time meets a full buffer here
    server = em.PtyBridgeServer(em.EmulatedBridge([em.BiotacSpiSlave(signals)]), tmp_path / "biotac",
                                frames_per_s=1.0).start()
    link = bt.BridgeLink(str(tmp_path / "biotac"), stall_timeout_s=30.0)
    try:
        readings = poll_until(link, lambda r: len(r) >= 1)
        sent = len(server.bridge.served)
        server._next_due -= 100.0      # as if this process had not run for 100 frame periods
        deadline = time.monotonic() + 60   # the host does not read during the burst (10 kB > 4 kB)
        while len(server.bridge.served) < sent + 100:
            assert time.monotonic() < deadline, "the emulator never caught up"
            time.sleep(0.01)
        readings += poll_until(link, lambda r: len(r) >= 100)
    finally:
        link.close()
        server.stop()
    assert server.tx_dropped == 0
    assert link.stream.counters.frames_dropped == 0 and link.stream.counters.bridge_tx_dropped == 0
    index = [r.frame_index for r in readings]
    assert index == list(range(len(index)))


def test_a_bridge_left_streaming_by_a_previous_host_starts_clean(tmp_path):
    server = rig_server(tmp_path)
    first = bt.BridgeLink(str(tmp_path / "biotac"))
    try:
        poll_until(first, lambda r: len(r) >= 20)
        first._serial.close()              # the old host dies without stopping the bridge
        first._serial = None
        second = bt.BridgeLink(str(tmp_path / "biotac"))
        readings = poll_until(second, lambda r: len(r) >= 20)
    finally:
        second.close()
        server.stop()
    c = second.stream.counters
    assert (c.frames_dropped, c.counter_jumps, c.frames_repeated) == (0, 0, 0)
    assert [r.frame_index for r in readings] == list(range(len(readings)))

"""The optional Cheetah backend (devices/biotac_cheetah.py) on the fake `cheetah_py`
(devices/biotac_emulator.FakeCheetah): the public driver's queue, exact values, presence check,
unplug; and the reader node on it as a process (the fake installed as the module)."""
from __future__ import annotations

import signal
import time

import numpy as np

from incipient_slip.devices import biotac as bt
from incipient_slip.devices import biotac_emulator as em
from incipient_slip.devices.biotac_cheetah import CheetahLink, slot_padding_ns
from incipient_slip.graph.runtime import Node
from incipient_slip.messages import BiotacPac
from waiting import spin_until


def fake(present=True, n=1, realtime=False):
    slaves = [em.BiotacSpiSlave(em.RigSignals("paper", "pla", seed=2 + j), present=present) for j in range(n)]
    return em.FakeCheetah(slaves, realtime=realtime)


def poll_until(link, predicate, timeout_s=20.0):
    readings, deadline = [], time.monotonic() + timeout_s
    while not predicate(readings):
        assert time.monotonic() < deadline, f"timed out in state {link.state}: {link.events}"
        readings += link.poll()
        time.sleep(0.002)
    return readings


def test_each_slot_is_queued_as_the_public_driver_does():
    ch = fake(n=2)
    link = CheetahLink(n_biotacs=2, ch=ch)
    try:
        # streaming is set before the collecting thread's first submit: wait for both (a loaded
        # make test-load run read an empty queue just after the state changed)
        poll_until(link, lambda r: link.state == "streaming" and ch.submitted)
        slot = ch.submitted[0][:14]
    finally:
        link.close()
    cmd = bt.FRAME_SCHEDULE[0]
    assert slot == [("ss", 0x03), ("byte", cmd), ("byte", 0), ("ss", 0), ("delay", 50_000),
                    ("ss", 0x01), ("byte", 0), ("byte", 0), ("ss", 0x02), ("byte", 0), ("byte", 0),
                    ("ss", 0), ("delay", 10_000), ("delay", slot_padding_ns(2))]


def test_cheetah_link_reads_exactly_what_the_sensor_sampled():
    ch = fake()
    ch.slaves[0].history = []
    link = CheetahLink(ch=ch)
    try:
        readings = poll_until(link, lambda r: len(r) >= 60)
    finally:
        link.close()
    assert link.properties["serial_number"].startswith("BT")
    sampled = np.array(ch.slaves[0].history[:60 * 44]).reshape(60, 44)
    for r, row in zip(readings, sampled):
        np.testing.assert_array_equal(r.pac, row[bt.PAC_SLOTS])
        np.testing.assert_array_equal(r.electrodes, row[bt.ELECTRODE_SLOTS])
        assert (r.pdc, r.tac, r.tdc) == (row[bt.PDC_SLOT], row[bt.TAC_SLOT], row[bt.TDC_SLOT])
    assert [r.frame_index for r in readings] == list(range(len(readings)))
    c = link.stream.counters
    assert c.parity_errors.sum() == 0 and c.error_words.sum() == 0 and c.frames_dropped == 0


def test_cheetah_without_a_biotac_is_no_sensor():
    link = CheetahLink(ch=fake(present=False), min_backoff_s=0.05)
    try:
        poll_until(link, lambda r: link.state == "no_sensor")
    finally:
        link.close()
    assert "does not start with 'BT'" in link.events[-1][1]


def test_an_unplugged_adapter_is_reopened():
    ch = fake()
    link = CheetahLink(ch=ch, min_backoff_s=0.05)
    try:
        poll_until(link, lambda r: len(r) >= 10)
        ch.unplugged = True
        poll_until(link, lambda r: link.state == "disconnected")
        ch.unplugged = False
        poll_until(link, lambda r: link.connections == 2 and len(r) >= 10)
    finally:
        link.close()
    assert link.reconnects == 1
    assert any("Cheetah adapter failed" in text for _, text in link.events)


SHIM = '''"""cheetah_py for the test: the fake adapter with one emulated BioTac, in real time."""
import sys
from incipient_slip.devices import biotac_emulator as em
sys.modules[__name__] = em.FakeCheetah([em.BiotacSpiSlave(em.RigSignals("paper", "pla", seed=2))],
                                       realtime=True)
'''


def test_reader_node_on_the_cheetah_backend(graph, tmp_path):
    (tmp_path / "cheetah_py.py").write_text(SHIM)
    graph.env["PYTHONPATH"] = str(tmp_path)
    got = []
    probe = Node("test_probe", graph_dir=graph.dir, heartbeat_s=0)
    probe.create_subscription(BiotacPac, got.append)
    reader = graph.spawn(["python", "-m", "incipient_slip.nodes.biotac_reader", "backend:=cheetah",
                          "wait_subscribers:=1", "tare_on_start:=false"])
    try:
        spin_until(lambda: probe.spin_once(0.02), lambda: len(got) >= 50, 40, [reader], "50 P_AC frames")
    finally:
        probe.close()
    reader.terminate()
    assert reader.wait(10) == 128 + signal.SIGTERM
    assert [m.seq for m in got] == list(range(len(got)))
    assert np.diff([m.stamp_ns for m in got]).tolist() == [10_000_000] * (len(got) - 1)
    assert "on cheetah: streaming" in reader.stderr.read().decode()

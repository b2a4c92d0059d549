"""The biotac_reader node as a real process against the emulator as a real process on a pty:
what it publishes decodes to the emulator's values exactly, every fault kind is counted and
visible through `slip topic echo`, bad parameters exit 2 with one line."""
from __future__ import annotations

import signal
import json
import subprocess
import sys

import numpy as np
import pytest

from incipient_slip.devices import biotac as bt
from incipient_slip.graph.runtime import Node
from incipient_slip.messages import BiotacPac, BiotacSlow, BiotacStatus, BiotacTare
from waiting import spin_until

FAULTS = "parity_flip@30,parity_flip@31,error_word@40,error_word@41,crc@50,drop@60,repeat@70,counter_jump@80"
FRAMES = 300


class Probe(Node):
    def __init__(self, graph_dir):
        super().__init__("test_probe", graph_dir=graph_dir, heartbeat_s=0)
        self.pac, self.slow, self.status = [], [], []
        self.create_subscription(BiotacPac, self.pac.append)
        self.create_subscription(BiotacSlow, self.slow.append)
        self.create_subscription(BiotacStatus, self.status.append)
        self.tare_pub = self.create_publisher(BiotacTare)

    def spin_until(self, predicate, procs, timeout_s=40.0):
        spin_until(lambda: self.spin_once(0.02), predicate, timeout_s, procs, "the biotac reader")


def start_emulator(graph, tmp_path, *extra):
    link = tmp_path / "biotac"
    proc = graph.spawn(["python", "-m", "incipient_slip.devices.biotac_emulator", "--link", str(link),
                        "--seed", "5", "--served", str(tmp_path / "served.jsonl"), *extra])
    line = proc.stdout.readline().decode()
    assert "bridge on" in line, proc.stderr.read().decode()
    return proc, link


def test_reader_publishes_the_emulators_values_exactly_and_counts_every_fault(graph, tmp_path):
    emulator, link = start_emulator(graph, tmp_path, "--lockstep", "--faults", FAULTS, "--frames", str(FRAMES + 20))
    probe = Probe(graph.dir)
    reader = graph.spawn(["python", "-m", "incipient_slip.nodes.biotac_reader", f"port:={link}",
                          "wait_subscribers:=1", "status_period_s:=0.05", "tare_s:=0.5",
                          "stall_timeout_s:=60"])
    try:
        probe.spin_until(lambda: len(probe.pac) >= FRAMES and probe.status
                         and probe.status[-1].frames_ok >= FRAMES, [emulator, reader])
        echo = subprocess.run([sys.executable, "-m", "incipient_slip.cli", "topic", "echo", "/biotac/status",
                               "--json", "-n", "1"], env=graph.env, capture_output=True, text=True,
                              timeout=120)      # a hang guard: importing the CLI took 30 s under make test-load
    finally:
        probe.close()
    served = [json.loads(line) for line in (tmp_path / "served.jsonl").read_text().splitlines()]
    by_index = {i: s for i, s in enumerate(served)}     # lock-step from device time 0: seq = frame
    zero = bt.BiotacUnits().pac_zero_counts
    refused_pac, refused_slow = {31, 41}, {30, 40}
    lost = {50, 60}
    assert [m.seq for m in probe.pac[:100]] == [i for i in range(110) if i not in lost | refused_pac][:100]
    assert [m.seq for m in probe.slow[:100]] == [i for i in range(110) if i not in lost | refused_slow][:100]
    for m in probe.pac:
        np.testing.assert_array_equal(m.pac_counts, np.array(by_index[m.seq]["pac"]) - zero)
    for m in probe.slow:
        s = by_index[m.seq]
        np.testing.assert_array_equal(m.electrode_counts, s["electrodes"])
        assert (m.pdc_counts, m.tac_counts, m.tdc_counts) == (s["pdc"], s["tac"], s["tdc"])
    # device time: 10 ms per frame, exactly; P_AC stamped at its last sample
    slow_stamps = np.array([m.stamp_ns for m in probe.slow])
    seqs = np.array([m.seq for m in probe.slow])
    assert (np.diff(slow_stamps) == np.diff(seqs) * 10_000_000).all()
    pac0 = next(m for m in probe.pac if m.seq == probe.slow[0].seq)
    assert pac0.stamp_ns - probe.slow[0].stamp_ns == bt.PAC_LAST_SLOT_NS

    assert echo.returncode == 0, echo.stderr
    status = json.loads(echo.stdout)
    ch = bt.REPORTED_CHANNELS.index
    assert status["state"] == "streaming" and status["serial_number"].startswith("BT")
    assert status["parity_errors"][ch("E16")] == 1 and status["parity_errors"][ch("PAC")] == 1
    assert status["error_words"][ch("TAC")] == 1 and status["error_words"][ch("PAC")] == 1
    assert status["error_word_kinds"][bt.ERROR_NAMES.index("insufficient_sampling_delay")] == 2
    assert (status["crc_errors"], status["frames_dropped"], status["frames_repeated"],
            status["counter_jumps"]) == (1, 2, 1, 1)
    assert (status["pac_frames_refused"], status["slow_frames_refused"]) == (2, 2)
    assert status["tare_state"] == "done"
    reader.terminate()
    assert reader.wait(10) == 128 + signal.SIGTERM


def test_reader_reports_a_missing_sensor(graph, tmp_path):
    emulator, link = start_emulator(graph, tmp_path, "--missing-sensor")
    probe = Probe(graph.dir)
    reader = graph.spawn(["python", "-m", "incipient_slip.nodes.biotac_reader", f"port:={link}",
                          "status_period_s:=0.05"])
    try:
        probe.spin_until(lambda: any(s.state == "no_sensor" for s in probe.status), [emulator, reader])
    finally:
        probe.close()
    reader.terminate()
    assert reader.wait(10) == 128 + signal.SIGTERM
    assert "does not start with 'BT'" in reader.stderr.read().decode()
    assert not probe.pac and not probe.slow


@pytest.mark.parametrize("argv, message", [
    ([], "parameter port is required"),
    (["port:=/dev/null", "sensor:=7"], "sensor"),
    (["port:=/dev/null", "units:=/nonexistent/units.yaml"], "cannot read the BioTac units file"),
])
def test_reader_refuses_bad_parameters_in_one_line(argv, message):
    proc = subprocess.run([sys.executable, "-m", "incipient_slip.nodes.biotac_reader", *argv],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_tare_on_request_sets_the_pdc_baseline(graph, tmp_path):
    emulator, link = start_emulator(graph, tmp_path)
    probe = Probe(graph.dir)
    reader = graph.spawn(["python", "-m", "incipient_slip.nodes.biotac_reader", f"port:={link}",
                          "wait_subscribers:=1", "tare_on_start:=false", "status_period_s:=0.05"])
    try:
        probe.spin_until(lambda: len(probe.slow) >= 5, [emulator, reader])
        assert probe.slow[-1].pdc_tare_counts == 0 and probe.status[-1].tare_state == "none"
        while not probe.tare_pub.wait_for_subscribers(1, 0.1):
            assert reader.poll() is None
        probe.tare_pub.publish(BiotacTare(duration_s=0.3))
        probe.spin_until(lambda: probe.status and probe.status[-1].tare_state == "done", [emulator, reader])
        n = len(probe.slow)
        probe.spin_until(lambda: len(probe.slow) >= n + 3, [emulator, reader])
    finally:
        probe.close()
    reader.terminate()
    assert reader.wait(10) == 128 + signal.SIGTERM
    pdc = np.array([m.pdc_counts for m in probe.slow[-30:]])
    assert probe.slow[-1].pdc_tare_counts == pytest.approx(pdc.mean(), abs=5)
    assert "tare done" in reader.stderr.read().decode()


def test_a_port_that_appears_after_the_start_is_one_info_line_and_one_that_never_does_is_warned(graph, tmp_path):
    """The emulated rig opens its pty a moment after the reader starts: that is one line, not a
    warning per back-off; a port that is still missing after quiet_start_s is a warning. Each step
    waits for the line that says it happened (a loaded machine only slows them)."""
    late = tmp_path / "late"
    probe = Probe(graph.dir)
    reader = graph.spawn(["python", "-m", "incipient_slip.nodes.biotac_reader", f"port:={late / 'biotac'}",
                          "status_period_s:=0.05", "quiet_start_s:=300"])
    never = graph.spawn(["python", "-m", "incipient_slip.nodes.biotac_reader", "__name:=never",
                         f"port:={tmp_path / 'never'}", "status_period_s:=0.05", "quiet_start_s:=0.5"])
    said = []
    for raw in reader.stderr:                             # the reader tried, found no port, said so
        said.append(raw.decode())
        if "waiting up to" in said[-1]:
            break
    assert "waiting up to 300 s for the port to appear" in said[-1], said
    try:
        late.mkdir()
        emulator, _ = start_emulator(graph, late)
        probe.spin_until(lambda: len(probe.pac) >= 5, [emulator, reader])
    finally:
        probe.close()
    never_said = []
    for raw in never.stderr:     # its lines as they come (back-offs of at most 5 s; the test's timeout bounds it)
        never_said.append(raw.decode())
        if "WARNING: cannot open the bridge" in never_said[-1]:
            break
    for proc in (reader, never):
        proc.terminate()
        assert proc.wait(10) == 128 + signal.SIGTERM
    said.append(reader.stderr.read().decode())
    assert "".join(said).count("waiting up to") == 1 and "WARNING" not in "".join(said), said
    assert "".join(never_said).count("waiting up to") == 1 and "WARNING: cannot open" in never_said[-1], never_said

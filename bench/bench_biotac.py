"""BioTac reader benchmark: the frame rate it holds with zero loss, and its CPU per frame.

The reader (`nodes/biotac_reader.py`, a real process) reads an emulated bridge on a pty
(`devices/biotac_emulator.PtyBridgeServer` replaying frames made beforehand by the emulated
bridge from the simulated rig, so the emulator's own cost does not limit the rate). The bridge
paces frames in real time at R frames/s (the real bridge sends 100/s); this process subscribes to
/biotac/pac and checks every seq. A rate is *held* when every frame arrives, with no seq gap and
no frame dropped at the bridge or counted lost by the reader. The reader's CPU time (user + system,
from /proc) over the streaming span, divided by the frames, is its CPU per frame; at 100 frames/s
it is also given as a share of one core. Medians over REPEATS runs, with min-max.

    python bench/bench_biotac.py [--quick]

Emulated bridge on a pty, not a USB device: the kernel's USB-CDC path is not measured.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from incipient_slip.devices import biotac as bt
from incipient_slip.devices import biotac_emulator as em
from incipient_slip.graph.runtime import Node
from incipient_slip.messages import BiotacPac, BiotacStatus

TICK = os.sysconf("SC_CLK_TCK")


class ReplayBridge:
    """Frames packed beforehand by the emulated bridge, sent in order (duck-types EmulatedBridge)."""

    def __init__(self, n_frames: int):
        bridge = em.EmulatedBridge([em.BiotacSpiSlave(em.RigSignals("paper", "pla", seed=1))])
        self.props = bridge.property_frames()
        # the replies of n_frames frames, reused in a loop under a counter and clock that go on
        parsed = bt.FrameParser().feed(b"".join(bridge.next_frame()[0] for _ in range(n_frames)))
        self.replies = [f.replies for f in parsed]
        self.served: list = []
        self.counter = 0
        self.faults = em.FaultPlan()

    def property_frames(self):
        return self.props

    def start(self):
        pass

    def note_tx_dropped(self):
        pass

    def unplug_due(self):
        return False

    def next_frame(self):
        i = len(self.served)
        self.served.append(None)
        return [bt.pack_data_frame(i, i * bt.FRAME_US, self.replies[i % len(self.replies)], 1)]


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def run(rate_hz: float, n_frames: int, frames: ReplayBridge, graph_dir: Path) -> dict:
    """One run at rate_hz: frames received, gaps, losses, reader CPU per frame."""
    link = graph_dir / "biotac"
    frames.served = []
    server = em.PtyBridgeServer(frames, link, frames_per_s=rate_hz, max_frames=n_frames).start()
    env = dict(os.environ, SLIP_GRAPH_DIR=str(graph_dir))
    reader = subprocess.Popen([sys.executable, "-m", "incipient_slip.nodes.biotac_reader", f"port:={link}",
                               "wait_subscribers:=1", "tare_on_start:=false", "stall_timeout_s:=60",
                               "status_period_s:=0.2"], env=env, stderr=subprocess.DEVNULL)
    node = Node("bench_biotac", graph_dir=graph_dir, heartbeat_s=0)
    seqs, status = [], []
    sub = node.create_subscription(BiotacPac, lambda m: seqs.append(m.seq))
    node.create_subscription(BiotacStatus, status.append)
    cpu0 = t0 = None
    deadline = time.monotonic() + 30 + n_frames / rate_hz * 3
    quiet_since, last_n = time.monotonic(), 0
    try:
        while len(seqs) < n_frames and time.monotonic() < deadline:
            node.spin_once(0.01)
            if cpu0 is None and seqs:
                cpu0, t0 = cpu_s(reader.pid), time.monotonic()
            if len(seqs) != last_n:
                quiet_since, last_n = time.monotonic(), len(seqs)
            elif len(server.bridge.served) >= n_frames and time.monotonic() - quiet_since > 2.0:
                break                           # everything was sent; what is missing is lost
        cpu1, t1 = cpu_s(reader.pid), time.monotonic()
        # the last status, for the reader's own loss counters
        end = time.monotonic() + 1.0
        n_status = len(status)
        while len(status) == n_status and time.monotonic() < end:
            node.spin_once(0.05)
    finally:
        reader.terminate()
        reader.wait(10)
        node.close()
        server.stop()
    received = len(seqs)
    c = status[-1] if status else None
    lost = (n_frames - received) + sub.missed + server.tx_dropped + (c.frames_dropped if c else 0)
    return {"rate_hz": rate_hz, "received": received, "lost": lost, "gaps": sub.gaps,
            "cpu_per_frame_us": (cpu1 - cpu0) / max(1, received - 1) * 1e6,
            "cpu_share": (cpu1 - cpu0) / (t1 - t0) if t1 > t0 else float("nan")}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer frames and repeats")
    args = p.parse_args(argv)
    repeats = 1 if args.quick else 3
    seconds = 3.0 if args.quick else 6.0
    rates = [100, 500, 1000, 2000, 4000, 8000]
    frames = ReplayBridge(2000)
    print(f"emulated bridge on a pty; {repeats} run(s) per rate, {seconds:g} s each (simulated rig values)")
    print(f"{'frames/s':>9} {'received':>9} {'lost':>6} {'CPU/frame us (median, min-max)':>32} {'CPU share':>10}")
    held = 0
    for rate in rates:
        n = int(rate * seconds)
        results = []
        for _ in range(repeats):
            with tempfile.TemporaryDirectory(prefix="bb", dir="/tmp") as d:
                results.append(run(rate, n, frames, Path(d)))
        cpu = np.array([r["cpu_per_frame_us"] for r in results])
        share = np.median([r["cpu_share"] for r in results])
        lost = max(r["lost"] for r in results)
        print(f"{rate:>9} {min(r['received'] for r in results):>9} {lost:>6} "
              f"{np.median(cpu):>12.0f} ({cpu.min():.0f}-{cpu.max():.0f}){'':>8} {share:>9.1%}")
        if lost == 0:
            held = rate
        else:
            break
    print(f"highest rate held with zero loss: {held} frames/s ({held / bt.FRAME_RATE_HZ:g}x the BioTac's 100 frames/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

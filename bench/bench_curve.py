"""CURVE cost: the node runtime over SLIP_TRANSPORT=tcp (CURVE) vs tcp-insecure (plain), side by side.

Two receiver processes, each a `Node` subscribing to BiotacPac in a graph of its own: one with
`SLIP_TRANSPORT=tcp` (authenticated, encrypted), one with `tcp-insecure`. This process has one
publishing Node in each graph and sends to both, alternating blocks so that machine noise hits
both alike.

* latency: publish -> callback (wall clock stamped before encoding, read in the callback),
  messages SPACING_S apart so nothing queues: median, p99 and the spread of the block medians.
* CPU per message: FRAMES P_AC frames sent unthrottled to each path in turn, REPEATS times;
  CPU time (all threads, so ZeroMQ's I/O thread where the encryption happens) of the sender
  from the first send until the receiver has the last frame, and of the receiver over the same
  frames, divided by FRAMES: median and min..max of the repeats.

The last line is `curve/plain ratios: latency median X.XX, cpu send X.XX, cpu receive X.XX`.

`--permissions`: the tcp graph gets a permissions file (as a launch writes one) naming the two
nodes and their topics, so the receiver has a SUB per publisher and checks each topic's key
(security.py): the cost of per-node identity against the keystore-only tcp of the default.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from incipient_slip.messages import BiotacPac, RunEvent
from incipient_slip.graph.runtime import Node

BLOCKS = 8
PER_BLOCK = 300
SPACING_S = 0.002
FRAMES = 10_000
REPEATS = 5
MODES = ("tcp", "tcp-insecure")


def _receiver() -> None:
    """Receives BiotacPac; on RunEvent(kind=...) prints what it measured and resets."""
    node = Node("bench_rx", heartbeat_s=0)
    rows: list = []
    cpu0 = [None]

    def on_pac(msg):
        if cpu0[0] is None:
            cpu0[0] = time.process_time()
        rows.append((msg.seq, msg.stamp_ns, time.time_ns()))

    def on_event(msg):
        if msg.kind == "end":
            node.shutdown()
            return
        cpu = time.process_time() - cpu0[0] if cpu0[0] is not None else 0.0
        print(json.dumps({"rows": rows, "cpu_s": cpu}), flush=True)
        rows.clear()
        cpu0[0] = None

    node.create_subscription(BiotacPac, on_pac)
    node.create_subscription(RunEvent, on_event)
    print("ready", flush=True)
    node.spin()
    node.close()


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--rx":
        _receiver()
        return 0
    counts = np.arange(22, dtype=np.int16)
    paths = {}
    for mode in MODES:
        gdir = tempfile.mkdtemp(prefix="bc")
        if mode == "tcp" and "--permissions" in sys.argv[1:]:
            from pathlib import Path

            from incipient_slip.graph import security
            topics = [BiotacPac.TOPIC, RunEvent.TOPIC]
            security.write_permissions(security.keystore(Path(gdir)), {
                "bench_rx": {"publish": [], "subscribe": topics},
                "bench_tx_tcp": {"publish": topics, "subscribe": []}}, "bench_curve --permissions")
        env = dict(os.environ, SLIP_GRAPH_DIR=gdir, SLIP_TRANSPORT=mode)
        rx = subprocess.Popen([sys.executable, __file__, "--rx"], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True)
        assert rx.stdout.readline().strip() == "ready"
        os.environ["SLIP_TRANSPORT"] = mode
        node = Node(f"bench_tx_{mode}", graph_dir=gdir, heartbeat_s=0)
        pac, ev = node.create_publisher(BiotacPac), node.create_publisher(RunEvent)
        assert pac.wait_for_subscribers(1, 30) and ev.wait_for_subscribers(1, 30)
        paths[mode] = (rx, node, pac, ev)

    def collect(mode):
        rx, node, pac, ev = paths[mode]
        ev.publish(RunEvent(kind="step"))
        return json.loads(rx.stdout.readline())

    lat = {m: [] for m in MODES}
    block_medians = {m: [] for m in MODES}
    for b in range(BLOCKS):
        for mode in (MODES if b % 2 == 0 else MODES[::-1]):
            rx, node, pac, ev = paths[mode]
            for i in range(PER_BLOCK):
                pac.publish(BiotacPac(pac_counts=counts, stamp_ns=time.time_ns()))
                time.sleep(SPACING_S)
            rows = collect(mode)["rows"]
            d = [(r[2] - r[1]) / 1e3 for r in rows]
            assert len(d) == PER_BLOCK, (mode, len(d))
            lat[mode] += d
            block_medians[mode].append(float(np.median(d)))
    cpu_tx = {m: [] for m in MODES}
    cpu_rx = {m: [] for m in MODES}
    for r in range(REPEATS):
        for mode in (MODES if r % 2 == 0 else MODES[::-1]):
            rx, node, pac, ev = paths[mode]
            t0 = time.process_time()
            for i in range(FRAMES):
                pac.publish(BiotacPac(pac_counts=counts))
            got = collect(mode)
            cpu_tx[mode].append((time.process_time() - t0) / FRAMES * 1e6)
            assert len(got["rows"]) == FRAMES, (mode, len(got["rows"]))
            cpu_rx[mode].append(got["cpu_s"] / FRAMES * 1e6)
    for mode in MODES:
        rx, node, pac, ev = paths[mode]
        ev.publish(RunEvent(kind="end"))
        rx.wait(timeout=30)
        node.close()

    def spread(v):
        return f"median {np.median(v):7.1f}  (min {np.min(v):.1f} .. max {np.max(v):.1f})"
    print(f"{BLOCKS} alternating latency blocks of {PER_BLOCK} P_AC frames, {SPACING_S * 1e3:g} ms apart; "
          f"{REPEATS} x {FRAMES} unthrottled frames per path for CPU")
    for mode in MODES:
        a = np.array(lat[mode])
        print(f"{mode:13s} latency us: median {np.median(a):6.1f}  p99 {np.percentile(a, 99):7.1f}  "
              f"block medians {min(block_medians[mode]):.1f} .. {max(block_medians[mode]):.1f}")
        print(f"{mode:13s} CPU us/msg send:    {spread(cpu_tx[mode])}")
        print(f"{mode:13s} CPU us/msg receive: {spread(cpu_rx[mode])}")
    ratio = lambda d: np.median(d["tcp"]) / np.median(d["tcp-insecure"])  # noqa: E731
    print(f"curve/plain ratios: latency median {ratio(lat):.2f}, cpu send {ratio(cpu_tx):.2f}, "
          f"cpu receive {ratio(cpu_rx):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

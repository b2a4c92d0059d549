"""Node graph benchmark: one-hop latency and zero-loss throughput, runtime vs raw pyzmq + msgpack.

Two receiver processes run side by side: one is a `Node` subscribing to BiotacPac (the runtime:
announcement-file discovery, XPUB/SUB over ipc, validated decode, seq-gap counting, callback),
the other a bare SUB socket that `msgpack.unpackb`s the same P_AC-sized body. This process
sends to both, alternating blocks so that machine noise hits both alike.

* latency: publish -> callback, wall clock stamped just before encoding and read in the
  callback, messages spaced SPACING_S apart so nothing queues; median and p99 per path.
* throughput: FRAMES P_AC frames sent unthrottled (queues are large, so nothing is dropped);
  every seq is checked on receipt; rate = frames / receive span.

The last line is `graph/raw p99 ratio = X.XX`.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import msgpack
import numpy as np
import zmq

from incipient_slip.messages import BiotacPac, RunEvent
from incipient_slip.graph.runtime import Node

BLOCKS = 6              # alternating latency blocks per path
PER_BLOCK = 400
SPACING_S = 0.002
FRAMES = 20_000         # throughput phase


def _recv_graph(n_lat: int, n_thr: int) -> None:
    node = Node("bench_rx", heartbeat_s=0)
    rows = []

    def on_pac(msg):
        rows.append((msg.seq, msg.stamp_ns, time.time_ns()))

    sub = node.create_subscription(BiotacPac, on_pac)
    node.create_subscription(RunEvent, lambda m: node.shutdown())
    print("ready", flush=True)
    node.spin()
    node.close()
    print(json.dumps({"rows": rows, "gaps": sub.gaps, "dropped": sub.dropped}), flush=True)


def _recv_raw(endpoint: str) -> None:
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.RCVHWM, 100_000)
    sock.setsockopt(zmq.SUBSCRIBE, b"/biotac/pac\0")
    sock.connect(endpoint)
    print("ready", flush=True)
    rows, gaps, last = [], 0, None
    while True:
        _, body = sock.recv_multipart()
        msg = msgpack.unpackb(body)
        if msg.get("stop"):
            break
        now = time.time_ns()
        seq = msg["seq"]
        if last is not None and seq != last + 1:
            gaps += 1
        last = seq
        rows.append((seq, msg["stamp_ns"], now))
    sock.close(0)
    print(json.dumps({"rows": rows, "gaps": gaps, "dropped": 0}), flush=True)


def _raw_body(seq: int, counts: np.ndarray) -> bytes:
    # the same map the runtime sends, built by hand as a raw pyzmq user would
    return msgpack.packb({"type": "BiotacPac", "v": 1, "stamp_ns": time.time_ns(), "seq": seq,
                          "pac_counts": {"dtype": "<i2", "shape": [22], "data": counts.tobytes()},
                          "pa_per_count": 0.37}, use_bin_type=True)


def _stats(rows, first_seq, n):
    lat = np.array([(r - s) / 1e3 for q, s, r in rows if first_seq <= q < first_seq + n])
    return lat


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--rx-graph":
        _recv_graph(0, 0)
        return 0
    if len(sys.argv) > 1 and sys.argv[1] == "--rx-raw":
        _recv_raw(sys.argv[2])
        return 0

    tmp = tempfile.mkdtemp(prefix="sgb", dir="/tmp")
    os.environ["SLIP_GRAPH_DIR"] = tmp
    raw_ep = f"ipc://{tmp}/raw.sock"
    ctx = zmq.Context.instance()
    raw_pub = ctx.socket(zmq.XPUB)
    raw_pub.setsockopt(zmq.SNDHWM, 100_000)
    raw_pub.bind(raw_ep)
    node = Node("bench_tx", heartbeat_s=0)
    pub = node.create_publisher(BiotacPac)
    stop_pub = node.create_publisher(RunEvent)

    rx = {"graph": subprocess.Popen([sys.executable, __file__, "--rx-graph"], stdout=subprocess.PIPE, text=True),
          "raw": subprocess.Popen([sys.executable, __file__, "--rx-raw", raw_ep], stdout=subprocess.PIPE, text=True)}
    for p in rx.values():
        assert p.stdout.readline().strip() == "ready"
    assert pub.wait_for_subscribers(1, 10) and stop_pub.wait_for_subscribers(1, 10)
    assert raw_pub.poll(10_000) and raw_pub.recv()[0] == 1      # the raw SUB's subscription

    counts = np.arange(22, dtype=np.int16)
    msg = BiotacPac(pac_counts=counts)
    raw_seq = 0
    # latency: alternate blocks, messages spaced so that nothing queues
    for block in range(2 * BLOCKS):
        graph_turn = block % 2 == 0
        next_t = time.perf_counter()
        for _ in range(PER_BLOCK):
            next_t += SPACING_S
            while (d := next_t - time.perf_counter()) > 0:
                time.sleep(d)
            if graph_turn:
                pub.publish(msg)
            else:
                raw_pub.send_multipart([b"/biotac/pac\0", _raw_body(raw_seq, counts)])
                raw_seq += 1
    n_lat = BLOCKS * PER_BLOCK
    time.sleep(0.2)
    # throughput: unthrottled
    t_send = {}
    t0 = time.perf_counter()
    for _ in range(FRAMES):
        pub.publish(msg)
    t_send["graph"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(FRAMES):
        raw_pub.send_multipart([b"/biotac/pac\0", _raw_body(raw_seq, counts)])
        raw_seq += 1
    t_send["raw"] = time.perf_counter() - t0

    stop_pub.publish(RunEvent(kind="end"))
    raw_pub.send_multipart([b"/biotac/pac\0", msgpack.packb({"stop": True})])
    results = {}
    for name, p in rx.items():
        out, _ = p.communicate(timeout=120)
        results[name] = json.loads(out.strip().splitlines()[-1])
    node.close()
    raw_pub.close(0)

    print(f"node graph benchmark: BiotacPac ({len(msg.pac_counts)} x int16), ipc, 2 processes, "
          f"{os.cpu_count()} cores")
    p99, med = {}, {}
    for name in ("raw", "graph"):
        lat = _stats(results[name]["rows"], 0, n_lat)
        p99[name] = float(np.percentile(lat, 99))
        med[name] = float(np.median(lat))
        print(f"latency {name:5s}: n={len(lat)} median {np.median(lat):7.1f} us  "
              f"p99 {p99[name]:7.1f} us  max {lat.max():8.1f} us")
    for name in ("raw", "graph"):
        res = results[name]
        rows = [r for r in res["rows"] if r[0] >= n_lat]
        span = (rows[-1][2] - rows[0][2]) / 1e9 if len(rows) > 1 else float("nan")
        lost = FRAMES - len(rows)
        print(f"throughput {name:5s}: {len(rows)}/{FRAMES} frames, lost {lost}, gaps {res['gaps']}, "
              f"dropped {res['dropped']}: {len(rows) / span:8.0f} frames/s received "
              f"(send side {FRAMES / t_send[name]:8.0f} frames/s)")
    print(f"graph/raw median ratio = {med['graph'] / med['raw']:.2f}")
    print(f"graph/raw p99 ratio = {p99['graph'] / p99['raw']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Node graph benchmark: the wire codec, one-hop latency, zero-loss throughput and CPU per message
of the runtime, side by side with raw pyzmq + msgpack and (if installed) a zenoh pub/sub pair.

1. codec: decode + validate of a `/biotac/pac` and a `/biotac/slow` body by the wire decoder
   (msgspec, the hot path) and by the naming path (msgpack + per-field checks, which names what
   is wrong), and encode; median (min..max) of REPEATS timings of LOOPS calls each, in process.
2. profile: the pieces of one hop timed in process (timeit, best of 5), receive and send side.
3. latency: publish -> callback, wall clock stamped just before encoding and read in the
   receiver, messages SPACING_S apart so nothing queues; blocks alternate between the paths.
4. throughput and CPU: FRAMES P_AC frames sent unthrottled per path, REPEATS times, paths in
   turn (order rotating); every seq is checked on receipt (zero loss or the run says so); rate =
   frames / receive span; CPU = process CPU time (all threads: ZeroMQ's I/O threads, zenoh's
   runtime) of the sender from its first send until the receiver has the last frame, and of the
   receiver over the same frames, / FRAMES.

Receivers are separate processes: a runtime `Node` subscribing to BiotacPac (discovery, XPUB/SUB
over ipc, validated decode, seq-gap counting, callback), a bare SUB socket that `msgpack.unpackb`s
the same body, and a zenoh subscriber (peer mode, unix socket, reliable, blocking congestion
control) doing the same. The last lines are the ratios; results go to docs/performance.md.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import timeit

import msgpack
import numpy as np
import zmq

from incipient_slip import messages as M
from incipient_slip.messages import BiotacPac, BiotacSlow, RunEvent
from incipient_slip.graph.runtime import Node

try:
    import zenoh
except ImportError:       # an optional reference peer: pip install '.[bench]'
    zenoh = None

SPACING_S = 0.002
TOPIC = b"/biotac/pac\0"
ZKEY = "biotac/pac"


# --- receivers (separate processes) ------------------------------------------------------------

class _Rows:
    """Rows (seq, stamp_ns, recv_ns) since the last mark, CPU from the first of them, seq gaps."""

    def __init__(self):
        self.rows, self.cpu0, self.gaps, self.last = [], None, 0, None

    def add(self, seq, stamp_ns):
        if self.cpu0 is None:
            self.cpu0 = time.process_time()
        if self.last is not None and seq != self.last + 1:
            self.gaps += 1
        self.last = seq
        self.rows.append((seq, stamp_ns, time.time_ns()))

    def report(self, dropped=0):
        cpu = time.process_time() - self.cpu0 if self.cpu0 is not None else 0.0
        print(json.dumps({"rows": self.rows, "cpu_s": cpu, "gaps": self.gaps, "dropped": dropped}),
              flush=True)
        self.rows, self.cpu0, self.gaps = [], None, 0


def _rx_graph() -> None:
    node = Node("bench_rx", heartbeat_s=0)
    rows = _Rows()
    sub = node.create_subscription(BiotacPac, lambda m: rows.add(m.seq, m.stamp_ns))

    def on_event(msg):
        if msg.kind == "end":
            node.shutdown()
        else:
            rows.report(sub.dropped)

    node.create_subscription(RunEvent, on_event)
    print("ready", flush=True)
    node.spin()
    node.close()


def _rx_raw(endpoint: str) -> None:
    sock = zmq.Context.instance().socket(zmq.SUB)
    sock.setsockopt(zmq.RCVHWM, 100_000)
    sock.setsockopt(zmq.SUBSCRIBE, TOPIC)
    sock.connect(endpoint)
    print("ready", flush=True)
    rows = _Rows()
    while True:
        _, body = sock.recv_multipart()
        msg = msgpack.unpackb(body)
        if "mark" in msg:
            if msg["mark"] == "end":
                break
            rows.report()
            continue
        rows.add(msg["seq"], msg["stamp_ns"])
    sock.close(0)


def _zenoh_config(endpoint: str, listen: bool):
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint] if listen else []))
    if not listen:
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return conf


def _rx_zenoh(endpoint: str) -> None:
    session = zenoh.open(_zenoh_config(endpoint, listen=False))
    rows = _Rows()
    done = threading.Event()

    def on_sample(sample):
        msg = msgpack.unpackb(sample.payload.to_bytes())
        if "mark" in msg:
            if msg["mark"] == "end":
                done.set()
            else:
                rows.report()
            return
        rows.add(msg["seq"], msg["stamp_ns"])

    session.declare_subscriber(ZKEY, on_sample)
    print("ready", flush=True)
    done.wait()
    session.close()


# --- the sender's side -------------------------------------------------------------------------

def _raw_body(seq: int, counts: np.ndarray) -> bytes:
    # the same map the runtime sends, built by hand as a raw pyzmq (or zenoh) user would
    return msgpack.packb({"type": "BiotacPac", "v": 1, "stamp_ns": time.time_ns(), "seq": seq,
                          "pac_counts": {"dtype": "<i2", "shape": [22], "data": counts.tobytes()},
                          "pa_per_count": 0.37}, use_bin_type=True)


class _Paths:
    """The sender's end of every path: send(n) sends n P_AC frames, mark() asks the receiver
    for its rows and returns them."""

    def __init__(self, tmp: str, with_zenoh: bool):
        self.counts = np.arange(22, dtype=np.int16)
        self.msg = BiotacPac(pac_counts=self.counts)
        self.seq = {"raw": 0, "zenoh": 0}
        raw_ep = f"ipc://{tmp}/raw.sock"
        self.raw_pub = zmq.Context.instance().socket(zmq.XPUB)
        self.raw_pub.setsockopt(zmq.SNDHWM, 100_000)
        self.raw_pub.bind(raw_ep)
        self.node = Node("bench_tx", heartbeat_s=0)
        self.pub = self.node.create_publisher(BiotacPac)
        self.ev = self.node.create_publisher(RunEvent)
        cmds = {"graph": ["--rx", "graph"], "raw": ["--rx", "raw", raw_ep]}
        self.zpub = None
        if with_zenoh:
            z_ep = f"unixsock-stream/{tmp}/zenoh.sock"
            self.zsession = zenoh.open(_zenoh_config(z_ep, listen=True))
            self.zpub = self.zsession.declare_publisher(
                ZKEY, congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE)
            cmds["zenoh"] = ["--rx", "zenoh", z_ep]
        self.rx = {name: subprocess.Popen([sys.executable, __file__, *argv], stdout=subprocess.PIPE,
                                          text=True) for name, argv in cmds.items()}
        for p in self.rx.values():
            assert p.stdout.readline().strip() == "ready"
        assert self.pub.wait_for_subscribers(1, 30) and self.ev.wait_for_subscribers(1, 30)
        assert self.raw_pub.poll(30_000) and self.raw_pub.recv()[0] == 1   # the raw SUB's subscription
        if with_zenoh:   # zenoh has no subscription event: send marks until one comes back
            while True:
                self.zpub.put(msgpack.packb({"mark": "step"}))
                if self._poll_line("zenoh", 0.2):
                    break
        self.names = list(self.rx)

    def _poll_line(self, name, timeout_s):
        import select
        out = self.rx[name].stdout
        if select.select([out], [], [], timeout_s)[0]:
            return out.readline()
        return None

    def send(self, name: str, n: int) -> None:
        if name == "graph":
            publish, msg = self.pub.publish, self.msg
            for _ in range(n):
                publish(msg)
            return
        seq, counts = self.seq[name], self.counts
        if name == "raw":
            send = self.raw_pub.send_multipart
            for s in range(seq, seq + n):
                send([TOPIC, _raw_body(s, counts)])
        else:
            put = self.zpub.put
            for s in range(seq, seq + n):
                put(_raw_body(s, counts))
        self.seq[name] = seq + n

    def send_one(self, name: str) -> None:
        self.send(name, 1)

    def mark(self, name: str, kind: str = "step") -> dict | None:
        if name == "graph":
            self.ev.publish(RunEvent(kind=kind))
        elif name == "raw":
            self.raw_pub.send_multipart([TOPIC, msgpack.packb({"mark": kind})])
        else:
            self.zpub.put(msgpack.packb({"mark": kind}))
        return json.loads(self.rx[name].stdout.readline()) if kind == "step" else None

    def close(self) -> None:
        for name in self.names:
            self.mark(name, "end")
        for p in self.rx.values():
            p.wait(timeout=60)
        self.node.close()
        self.raw_pub.close(0)
        if self.zpub is not None:
            self.zsession.close()


# --- the sections ------------------------------------------------------------------------------

def _spread(values, fmt="{:.2f}") -> str:
    v = np.asarray(values, dtype=float)
    return f"{fmt.format(np.median(v))} ({fmt.format(v.min())}..{fmt.format(v.max())})"


def codec_section(repeats: int, loops: int = 20_000) -> None:
    from incipient_slip.messages import codec
    pac = BiotacPac(pac_counts=np.arange(22, dtype=np.int16), stamp_ns=time.time_ns(), seq=7)
    slow = BiotacSlow(electrode_counts=np.arange(19, dtype=np.uint16), pdc_counts=2100,
                      tac_counts=2000, tdc_counts=1900, pdc_tare_counts=2000,
                      stamp_ns=time.time_ns(), seq=7)
    print(f"codec, us per call: median (min..max) of {repeats} x {loops} calls, in process")
    for msg in (pac, slow):
        cls, body = type(msg), M.encode(msg)
        cases = {"decode+validate, wire (msgspec)": lambda: M.decode(body, cls),
                 "decode+validate, naming path": lambda: codec.decode_named(body, cls),
                 "encode": lambda: M.encode(msg, stamp_ns=1, seq=2)}
        times = {k: [] for k in cases}
        for r in range(repeats):
            for k in (list(cases) if r % 2 == 0 else list(cases)[::-1]):
                times[k].append(timeit.timeit(cases[k], number=loops) / loops * 1e6)
        for k, v in times.items():
            print(f"  {cls.TOPIC:13s} {k:34s} {_spread(v)}")
        a = np.median(times["decode+validate, naming path"])
        b = np.median(times["decode+validate, wire (msgspec)"])
        print(f"  {cls.TOPIC:13s} naming/wire decode ratio = {a / b:.1f}")


def profile_section(repeats: int) -> None:
    """Where one hop's CPU goes, in process: each piece timed alone (best of `repeats`), then the
    publish loop and the receive loop of two Nodes over ipc per message (CPU time of the process,
    ZeroMQ's I/O thread included; median (min..max) of `repeats` x 20000 messages). Public API
    only, so that the same section runs on an older checkout (PYTHONPATH=<its src>)."""
    n = 20_000
    msg = BiotacPac(pac_counts=np.arange(22, dtype=np.int16))
    body = M.encode(msg, stamp_ns=time.time_ns(), seq=0)
    pieces = [
        ("BiotacPac(...): construct + validate", lambda: BiotacPac(pac_counts=msg.pac_counts)),
        ("encode (stamp, seq)", lambda: M.encode(msg, stamp_ns=1, seq=2)),
        ("decode + validate", lambda: M.decode(body, BiotacPac)),
        ("time.time_ns()", time.time_ns),
    ]
    print(f"profile of one hop, us per message, in process (pieces: best of {repeats} x {n}; loops: "
          f"median (min..max) of {repeats} x {n}, process CPU):")
    for label, fn in pieces:
        best = min(timeit.repeat(fn, number=n, repeat=repeats)) / n * 1e6
        print(f"  {label:52s} {best:6.2f}")
    tmp = tempfile.mkdtemp(prefix="sgp", dir="/tmp")
    tx = Node("prof_tx", graph_dir=tmp, heartbeat_s=0)
    rx = Node("prof_rx", graph_dir=tmp, heartbeat_s=0)
    got = []
    rx.create_subscription(BiotacPac, lambda m: got.append(m.seq))
    pub = tx.create_publisher(BiotacPac)
    assert pub.wait_for_subscribers(1, 30)
    send, receive = [], []
    for _ in range(repeats):
        got.clear()
        c0 = time.process_time()
        for _ in range(n):
            pub.publish(msg)
        c1 = time.process_time()
        while len(got) < n:
            rx.spin_once(0.1)
        c2 = time.process_time()
        send.append((c1 - c0) / n * 1e6)
        receive.append((c2 - c1) / n * 1e6)
    print(f"  {'publish loop (stamp, encode, send; I/O thread)':52s} {_spread(send)}")
    print(f"  {'receive loop (recv, dispatch, decode, seq, callback)':52s} {_spread(receive)}")
    tx.close()
    rx.close()


def wire_sections(frames: int, repeats: int, blocks: int, per_block: int) -> None:
    tmp = tempfile.mkdtemp(prefix="sgb", dir="/tmp")
    os.environ["SLIP_GRAPH_DIR"] = tmp
    paths = _Paths(tmp, with_zenoh=zenoh is not None)
    names = paths.names
    for name in names:   # warm up every path, and start from empty rows
        paths.send(name, 1000)
        paths.mark(name)
    # latency: alternating blocks, messages spaced so that nothing queues
    lat = {n: [] for n in names}
    for b in range(blocks):
        for name in names[b % len(names):] + names[:b % len(names)]:
            next_t = time.perf_counter()
            for _ in range(per_block):
                next_t += SPACING_S
                while (d := next_t - time.perf_counter()) > 0:
                    time.sleep(d)
                paths.send_one(name)
            rows = paths.mark(name)["rows"]
            lat[name] += [(r - s) / 1e3 for _, s, r in rows]
    # throughput and CPU: unthrottled, paths in turn
    rate = {n: [] for n in names}
    cpu_tx = {n: [] for n in names}
    cpu_rx = {n: [] for n in names}
    lost = {n: 0 for n in names}
    for r in range(repeats):
        for name in names[r % len(names):] + names[:r % len(names)]:
            c0 = time.process_time()
            paths.send(name, frames)
            got = paths.mark(name)
            cpu_tx[name].append((time.process_time() - c0) / frames * 1e6)
            rows = got["rows"]
            lost[name] += frames - len(rows) + got["gaps"] + got["dropped"]
            span = (rows[-1][2] - rows[0][2]) / 1e9 if len(rows) > 1 else float("nan")
            rate[name].append(len(rows) / span / 1e3)
            cpu_rx[name].append(got["cpu_s"] / frames * 1e6)
    paths.close()

    print(f"latency (us), {blocks} alternating blocks of {per_block} P_AC frames {SPACING_S * 1e3:g} ms apart:")
    p99 = {}
    for name in names:
        a = np.array(lat[name])
        p99[name] = np.percentile(a, 99)
        print(f"  {name:6s} n={len(a)} median {np.median(a):7.1f}  p99 {p99[name]:7.1f}  max {a.max():8.1f}")
    print(f"throughput and CPU: {repeats} x {frames} unthrottled P_AC frames per path, "
          "median (min..max) of the repeats:")
    for name in names:
        total = np.array(cpu_tx[name]) + np.array(cpu_rx[name])
        print(f"  {name:6s} {_spread(rate[name], '{:.1f}')} k frames/s received, lost {lost[name]};  "
              f"CPU us/msg send {_spread(cpu_tx[name], '{:.1f}')}  receive "
              f"{_spread(cpu_rx[name], '{:.1f}')}  total {_spread(total, '{:.1f}')}")
    med = lambda d, n: float(np.median(d[n]))  # noqa: E731
    cpu = {n: med(cpu_tx, n) + med(cpu_rx, n) for n in names}
    print(f"graph/raw: throughput {med(rate, 'graph') / med(rate, 'raw'):.2f}, "
          f"CPU per message {cpu['graph'] / cpu['raw']:.2f}, latency median "
          f"{np.median(lat['graph']) / np.median(lat['raw']):.2f}")
    if "zenoh" in names:
        print(f"graph/zenoh: throughput {med(rate, 'graph') / med(rate, 'zenoh'):.2f}, "
              f"CPU per message {cpu['graph'] / cpu['zenoh']:.2f}")
    else:
        print("graph/zenoh: zenoh not installed (pip install '.[bench]')")
    print(f"graph/raw p99 ratio = {p99['graph'] / p99['raw']:.2f}")


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--rx":
        kind, rest = sys.argv[2], sys.argv[3:]
        {"graph": _rx_graph, "raw": _rx_raw, "zenoh": _rx_zenoh}[kind](*rest)
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=20_000, help="frames per throughput repeat")
    ap.add_argument("--repeats", type=int, default=5, help="throughput repeats (and codec repeats)")
    ap.add_argument("--blocks", type=int, default=6, help="latency blocks per path")
    ap.add_argument("--per-block", type=int, default=400, help="messages per latency block")
    ap.add_argument("--only", choices=("codec", "profile", "wire"), help="one section only")
    args = ap.parse_args()
    print(f"node graph benchmark: BiotacPac (22 x int16), {os.cpu_count()} cores, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())} at the start")
    if args.only in (None, "codec"):
        codec_section(args.repeats)
    if args.only in (None, "profile"):
        profile_section(args.repeats)
    if args.only in (None, "wire"):
        wire_sections(args.frames, args.repeats, args.blocks, args.per_block)
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())

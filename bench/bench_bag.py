"""Recorder flush policy benchmark: what finishing + fsyncing a chunk every 0.5 s costs.

Writes the same traffic with two policies, alternating runs so that machine noise hits both:

* old: mcap's default, 1 MiB chunks, no fsync until the file is closed (a SIGKILL loses
  everything since the last full chunk);
* new: the recorder's policy, a chunk finished, written and fsync'd every FLUSH_S of traffic
  (BagWriter.flush(), as the recorder's timer and write() call it);
* chunks: the same small chunks without the fsync (os.fsync patched out), to split the cost
  between smaller chunks and the disk sync.

Traffic: the shipped demo recording (tests/data/demo.mcap, the simulated rig's topic mix:
P_AC and slow BioTac frames at 100 Hz, mocap at 120 Hz, ...), repeated to SECONDS s with
shifted times. The file goes to --dir (default: the system temp dir; pick a directory on the
disk you record to, since fsync cost depends on it). Prints write time per run, median and
spread, messages/s, file size, and the median (min, max) of the new/old write-time ratio
over side-by-side pairs.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

from incipient_slip.graph.bag import FLUSH_S, BagWriter, read_bag

DEMO = Path(__file__).resolve().parents[1] / "tests" / "data" / "demo.mcap"
SECONDS = 60
REPEATS = 5


def traffic(seconds: int) -> list:
    """(topic, type, body, log_ns, stamp_ns, seq) of `seconds` s of demo-mix traffic."""
    demo = list(read_bag(DEMO))
    span = demo[-1].log_time_ns - demo[0].log_time_ns + 10_000_000
    reps = max(1, round(seconds * 1e9 / span))
    return [(r.topic, r.type_name, r.body, r.log_time_ns + k * span, r.stamp_ns + k * span, r.sequence)
            for k in range(reps) for r in demo]


def write(path: str, rows: list, flush_every_s: float | None) -> tuple[float, int, int]:
    """Seconds to write and close `rows`; file size; chunk flushes. None: mcap's policy."""
    t0 = time.perf_counter()
    bag = BagWriter(path, flush_s=None if flush_every_s is None else 1e9)
    next_flush = rows[0][3] + (flush_every_s or 0) * 1e9
    for topic, type_name, body, log_ns, stamp_ns, seq in rows:
        if flush_every_s is not None and log_ns >= next_flush:   # the recorder's timer, in traffic time
            bag.flush()
            next_flush = log_ns + flush_every_s * 1e9
        bag.write_body(topic, type_name, body, log_time_ns=log_ns, stamp_ns=stamp_ns, seq=seq)
    bag.close()
    return time.perf_counter() - t0, os.path.getsize(path), bag.flushes


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default=None, help="where to write (default: system temp dir)")
    parser.add_argument("--seconds", type=int, default=SECONDS, help="traffic per run (default 60)")
    parser.add_argument("--repeats", type=int, default=REPEATS, help="runs per policy (default 5)")
    args = parser.parse_args(argv)
    rows = traffic(args.seconds)
    n = len(rows)
    print(f"traffic: {n} messages = {args.seconds} s of the demo mix ({n / args.seconds:.0f} msg/s); "
          f"simulated-rig topics")
    policies = (("old", None, False), ("new", FLUSH_S, False), ("chunks", FLUSH_S, True))
    times: dict[str, list[float]] = {name: [] for name, *_ in policies}
    sizes, flushes = {}, {}
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        path = os.path.join(tmp, "bench.mcap")
        for _ in range(args.repeats):
            for name, every, no_fsync in policies:
                with mock.patch("os.fsync") if no_fsync else contextlib.nullcontext():
                    seconds, sizes[name], flushes[name] = write(path, rows, every)
                times[name].append(seconds)
    for name, *_ in policies:
        t = times[name]
        med = statistics.median(t)
        print(f"{name}: write+close {med * 1e3:7.1f} ms median (min {min(t) * 1e3:.1f}, max "
              f"{max(t) * 1e3:.1f}) = {n / med:,.0f} msg/s, {med / args.seconds * 1e3:.2f} ms per "
              f"recorded second; file {sizes[name] / 1024:.0f} KiB; {flushes[name]} flushes")
    per_s = sum(31 + len(r[2]) for r in rows) / args.seconds   # MCAP message record bytes
    print(f"what a SIGKILL can lose: old = one 1 MiB chunk = {(1 << 20) / per_s:.0f} s of this "
          f"traffic; new = {FLUSH_S} s")
    print(f"file size ratio new/old = {sizes['new'] / sizes['old']:.2f}")
    for name in ("chunks", "new"):
        pairs = sorted(t / old for old, t in zip(times["old"], times[name]))   # run side by side
        print(f"{name}/old write time ratio = {statistics.median(pairs):.2f} (median of "
              f"{len(pairs)} side-by-side runs; min {pairs[0]:.2f}, max {pairs[-1]:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Recordings -> data set benchmark (`slip dataset --from-recordings`): what one 450-period series costs.

One collection recording (`launch collect.yaml` on the simulated rig, the paper's 450 periods, made
once into the temp dir, or --recording FILE) is read, alternating runs so machine noise hits both:

* log order: `read_bag` in receive order across topics (mcap merges every chunk's messages by time);
* file order: `read_bag(file_order=True)`, what the import uses (each topic's messages still in
  receive order);
* read_series: the whole conversion of one recording (decode, checks, arrays);
* import 1 vs N workers: `import_recordings` of COPIES copies of the recording, on one process and
  on a forked pool of all cores.

Prints seconds per run, the median (min, max), and the median (min, max) of the side-by-side ratios.
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from incipient_slip.graph.bag import read_bag
from incipient_slip.lab.recordings import import_recordings, read_series

REPEATS = 5
COPIES = 4


def make_recording(where: Path) -> Path:
    out = where / "series.mcap"
    env = dict(os.environ, SLIP_GRAPH_DIR=tempfile.mkdtemp(prefix="sg", dir="/tmp"))
    subprocess.run([sys.executable, "-m", "incipient_slip.graph.launch", "collect.yaml", "speed:=50", "seed:=3",
                    "material:=pla", f"out:={out}"], check=True, env=env, capture_output=True)
    return out


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def summary(name: str, xs: list[float]) -> str:
    return f"{name:<24} median {statistics.median(xs):7.3f} s  (min {min(xs):.3f}, max {max(xs):.3f}; n={len(xs)})"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recording", type=Path, help="a collection recording (default: one made now)")
    ap.add_argument("--repeats", type=int, default=REPEATS)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rec = args.recording or make_recording(tmp)
        src = tmp / "copies"
        src.mkdir()
        for i in range(COPIES):
            shutil.copy(rec, src / f"series_{i:05d}.mcap")
        rows: dict[str, list] = {k: [] for k in ("log order", "file order", "read_series", "import 1 worker",
                                                 f"import {os.cpu_count()} workers")}
        for _ in range(args.repeats):
            rows["log order"].append(timed(lambda: sum(1 for _ in read_bag(rec))))
            rows["file order"].append(timed(lambda: sum(1 for _ in read_bag(rec, file_order=True))))
            rows["read_series"].append(timed(lambda: read_series(rec)))
            rows["import 1 worker"].append(timed(lambda: import_recordings(src, tmp / "d1", workers=1)))
            rows[f"import {os.cpu_count()} workers"].append(timed(lambda: import_recordings(src, tmp / "dn")))
        print(f"one 450-period recording ({rec.stat().st_size / 1e6:.1f} MB); load average {os.getloadavg()[0]:.1f}")
        for name, xs in rows.items():
            print(summary(name, xs))
        for a, b in (("log order", "file order"), ("import 1 worker", f"import {os.cpu_count()} workers")):
            ratios = [x / y for x, y in zip(rows[a], rows[b])]
            print(f"{a} / {b}: median {statistics.median(ratios):.2f} (min {min(ratios):.2f}, max {max(ratios):.2f})")
        per = statistics.median(rows[f"import {os.cpu_count()} workers"]) / COPIES
        print(f"a paper-scale session (5 materials x 100 series x 2 injection settings = 1000 recordings): "
              f"about {1000 * per / 60:.0f} min on this machine")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

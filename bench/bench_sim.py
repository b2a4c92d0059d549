"""Benchmark of the simulated rig (`make bench-sim`).

1. Cost per 500 ms period of scenes with fewer or more effects (median and spread of repeats).
2. Time to write the paper-scale data set: 5 materials x 100 series x 450 steps, with injection
   (scene paper) and without (scene no_injection), on all cores, to a temporary directory.
   `--fraction F` writes only that fraction of the series and extrapolates linearly (said so).
Last line: `paper-scale dataset seconds = X`.
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time

from incipient_slip.sim import Rig, load_scene
from incipient_slip.sim.dataset import write_dataset
from incipient_slip.sim.protocols import run_collection

SCENES = ("mechanics", "electrodes_only", "no_injection", "paper")


def per_period_ms(scene_name: str, repeats: int, steps: int) -> tuple[list[float], list[float]]:
    """Return per-period (wall, CPU) times in ms of `repeats` collection series of `steps` periods.
    CPU time (process_time) is what the machine's other load disturbs least."""
    scene = load_scene(scene_name)
    wall, cpu = [], []
    for r in range(repeats):
        rig = Rig(scene, scene.materials[r % len(scene.materials)], 1000 + r)
        t, c = time.perf_counter(), time.process_time()
        for _ in run_collection(rig, steps):
            pass
        wall.append((time.perf_counter() - t) / steps * 1e3)
        cpu.append((time.process_time() - c) / steps * 1e3)
    return wall, cpu


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fraction", type=float, default=1.0, help="fraction of the 2 x 500 series to write (default 1)")
    ap.add_argument("--repeats", type=int, default=7, help="repeats per scene for the per-effect cost")
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    args = ap.parse_args(argv)
    print(f"machine: {os.cpu_count()} cores; workers = {args.workers}; load average at start {os.getloadavg()[0]:.1f}")
    print("per-period cost (one 500 ms period, single process):")
    med = {}
    for name in SCENES:
        wall, cpu = per_period_ms(name, args.repeats, 450)
        med[name] = statistics.median(cpu)
        q = statistics.quantiles(cpu, n=4)
        print(f"  {name:16s} {len(load_scene(name).effects):2d} effects  CPU median {med[name]:6.3f} ms"
              f" (IQR {q[0]:.3f}..{q[2]:.3f}, min {min(cpu):.3f}, max {max(cpu):.3f}, n={len(cpu)});"
              f" wall median {statistics.median(wall):6.3f} ms")
    ideal = (med["paper"] + med["no_injection"]) * 450 * 500 / 1e3 / max(1, args.workers)
    print(f"compute-only estimate on {args.workers} idle cores (per-period CPU medians x 450 x 500 x 2 scenes / workers): {ideal:.1f} s")
    n = max(1, round(500 * args.fraction))
    tmp = tempfile.mkdtemp(prefix="bench_sim_")
    try:
        total, sizes = 0.0, 0
        for name in ("paper", "no_injection"):
            t = time.perf_counter()
            out = write_dataset(load_scene(name), n, 0, os.path.join(tmp, name), workers=args.workers, progress=False)
            dt = time.perf_counter() - t
            total += dt
            size = sum(p.stat().st_size for p in out.iterdir())
            sizes += size
            print(f"data set {name}: {n} series x 450 steps in {dt:.1f} s ({size / 1e6:.0f} MB)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    scale = 500 / n
    if scale != 1:
        print(f"measured {n} of 500 series per scene; extrapolated linearly x{scale:.2f}")
    print(f"on-disk size at paper scale ~ {sizes * scale / 1e9:.2f} GB; load average at end {os.getloadavg()[0]:.1f}")
    print(f"paper-scale dataset seconds = {total * scale:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

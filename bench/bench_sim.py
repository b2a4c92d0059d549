"""Benchmark of the simulated rig (`make bench-sim`).

1. Cost per 500 ms period of scenes with fewer or more effects (median and spread of repeats).
2. Time to write the paper-scale data set: 5 materials x 100 series x 450 steps, with injection
   (scene paper) and without (scene no_injection), on all cores, to a temporary directory.
   `--fraction F` writes only that fraction of the series and extrapolates linearly (said so).
3. `--against REV`: per-period CPU cost of this checkout's simulator against git revision REV's,
   measured side by side (interleaved fresh processes, one collection series each), as ratios
   with median and spread; REV's src/ and scenes/ are exported with `git archive`. Use this on a
   loaded machine instead of the full data set: the paper-scale time scales with the ratio.
4. `--stage1-against REV`: one stage-1 objective evaluation of the calibration
   (`mechanics_summary(paper, N, R)`, `--stage1-size N,R`, default the full 100,6), this checkout
   against REV, in interleaved fresh processes (`--repeats` each; the first, untimed evaluation
   of each process takes the imports and the compiled code's load): wall and CPU medians with
   spread, their ratio, and whether the two summaries are identical (they must be).
5. `--series-against REV`: one data-set series (`sim.dataset.simulate_series`, 450 steps) of
   scene paper alone and of paper with its no_injection view (as the studies write them), this
   checkout against REV, in interleaved fresh processes (`--repeats` each, `--series-per-run`
   series per process after an untimed one): CPU seconds per series, medians with spread, their
   ratio, and whether every array of every series is identical (it must be).
6. `--dask-vs-pool N`: wall time of one data set of N series (scene paper, 450 steps) written by
   the local process pool and by dask tasks on a LocalCluster of the same worker count (its
   start-up and shut-down included), interleaved, median of `--repeats`; the arrays are checked
   equal. This is what decides `slip dataset`'s default (docs/performance.md).
Last line: `paper-scale dataset seconds = X` (or, with --against, the ratio of the paper scene).
"""
from __future__ import annotations

import argparse
import ast
import os
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

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


_ONE_SERIES = """
import sys, time
from incipient_slip.sim import Rig, load_scene
from incipient_slip.sim.protocols import run_collection
out = {}
for name in sys.argv[2:]:
    sc = load_scene(name)
    rig = Rig(sc, sc.materials[int(sys.argv[1]) % len(sc.materials)], 1000 + int(sys.argv[1]))
    c = time.process_time()
    for _ in run_collection(rig, 450):
        pass
    out[name] = (time.process_time() - c) / 450 * 1e3
print(repr(out))
"""


def _interleaved(rev: str, repeats: int, script: str, args) -> dict | int:
    """Run `script` with `args(r)` in fresh processes, this checkout and git revision REV's src/ and
    scenes/ (exported with `git archive`) in turn, `repeats` times; return {tag: [last stdout line
    as a literal]} or an exit code."""
    root = Path(__file__).resolve().parents[1]
    tmp = Path(tempfile.mkdtemp(prefix="bench_sim_rev_"))
    try:
        tar = subprocess.run(["git", "-C", str(root), "archive", rev, "src", "scenes", "pyproject.toml"],
                             capture_output=True, check=False)
        if tar.returncode:
            print(f"bench_sim: error: git archive {rev}: {tar.stderr.decode().strip()}", file=sys.stderr)
            return 2
        (tmp / "rev.tar").write_bytes(tar.stdout)
        with tarfile.open(tmp / "rev.tar") as t:
            t.extractall(tmp / "rev", filter="data")
        runs = {"this": [], rev: []}
        for r in range(repeats):
            for tag, env, cwd in (("this", {}, root), (rev, {"PYTHONPATH": str(tmp / "rev" / "src")}, tmp / "rev")):
                o = subprocess.run([sys.executable, "-c", script, *args(r)], capture_output=True,
                                   text=True, env=dict(os.environ, **env), cwd=cwd, check=False)
                if o.returncode:
                    print(f"bench_sim: error: {tag}: {o.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
                    return 1
                runs[tag].append(ast.literal_eval(o.stdout.strip().splitlines()[-1]))
        return runs
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def against(rev: str, repeats: int) -> int:
    """Print per-period CPU cost ratios (this checkout / rev) per scene; return an exit code."""
    runs = _interleaved(rev, repeats, _ONE_SERIES, lambda r: (str(r), *SCENES))
    if isinstance(runs, int):
        return runs
    print(f"per-period CPU cost, this checkout vs {rev} ({repeats} interleaved series each; load average "
          f"{os.getloadavg()[0]:.1f}):")
    for name in SCENES:
        ratios = [a[name] / b[name] for a, b in zip(runs["this"], runs[rev])]
        print(f"  {name:16s} this {statistics.median(a[name] for a in runs['this']):6.3f} ms, {rev} "
              f"{statistics.median(b[name] for b in runs[rev]):6.3f} ms; ratio median {statistics.median(ratios):.2f} "
              f"(min {min(ratios):.2f}, max {max(ratios):.2f})")
    paper = statistics.median(a["paper"] / b["paper"] for a, b in zip(runs["this"], runs[rev]))
    print(f"paper scene cost ratio = {paper:.2f}")
    return 0


_STAGE1 = """
import json, os, sys, time
from incipient_slip.experiments.calibration import mechanics_summary
from incipient_slip.sim import load_scene
scene = load_scene("paper")
n, runs = int(sys.argv[1]), int(sys.argv[2])
mechanics_summary(scene, 2, 1, 1, 1)     # imports and the first load of compiled code, untimed
load = os.getloadavg()[0]
t, c = time.perf_counter(), time.process_time()
s = mechanics_summary(scene, n, runs, 1, 1)
print(repr((time.perf_counter() - t, time.process_time() - c, load, json.dumps(s, sort_keys=True))))
"""


def stage1_against(rev: str, repeats: int, size: str) -> int:
    """Print one stage-1 evaluation's wall and CPU time, this checkout against rev; return an exit code."""
    n, r = (int(v) for v in size.split(","))
    print(f"stage-1 evaluation mechanics_summary(paper, {n}, {r}), this checkout vs {rev}, {repeats} interleaved "
          f"fresh processes each; load average at start {os.getloadavg()[0]:.1f}")
    runs = _interleaved(rev, repeats, _STAGE1, lambda _: (str(n), str(r)))
    if isinstance(runs, int):
        return runs
    for tag, rows in runs.items():
        wall, cpu, load = ([row[i] for row in rows] for i in range(3))
        print(f"  {tag:10s} wall median {statistics.median(wall):7.3f} s (min {min(wall):.3f}, max {max(wall):.3f}); "
              f"CPU median {statistics.median(cpu):7.3f} s (min {min(cpu):.3f}, max {max(cpu):.3f}); "
              f"load {min(load):.1f}..{max(load):.1f}")
    ratios = [b[0] / a[0] for a, b in zip(runs["this"], runs[rev])]
    same = len({row[3] for rows in runs.values() for row in rows}) == 1
    print(f"  {rev} / this wall: median {statistics.median(ratios):.1f}x (min {min(ratios):.1f}, max {max(ratios):.1f}); "
          f"summaries identical: {same}; load average at end {os.getloadavg()[0]:.1f}")
    return 0 if same else 1


_SERIES = """
import hashlib, os, sys, time
from incipient_slip.sim import load_scene
from incipient_slip.sim.dataset import simulate_series
paper, views = load_scene("paper"), [load_scene("no_injection")]
simulate_series(paper, "pla", 1, 3, views)          # imports and the compiled code's load, untimed
k, start = int(sys.argv[1]), int(sys.argv[2])
h = hashlib.sha256()
out = {"load": os.getloadavg()[0]}
for name, vs in (("paper", []), ("paper+no_injection", views)):
    c = time.process_time()
    for i in range(start, start + k):
        res = simulate_series(paper, paper.materials[i % len(paper.materials)], 2000 + i, 450, vs)
        for d in res if vs else [res]:
            for key in sorted(d):
                h.update(key.encode() + d[key].tobytes())
    out[name] = (time.process_time() - c) / k
out["digest"] = h.hexdigest()
print(repr(out))
"""


def series_against(rev: str, repeats: int, per_run: int) -> int:
    """Print the CPU time of one data-set series, this checkout against rev; return an exit code."""
    print(f"data-set series (simulate_series, 450 steps), this checkout vs {rev}, {repeats} interleaved fresh "
          f"processes each of {per_run} series per case; load average at start {os.getloadavg()[0]:.1f}")
    runs = _interleaved(rev, repeats, _SERIES, lambda r: (str(per_run), str(r * per_run)))
    if isinstance(runs, int):
        return runs
    loads = [row["load"] for rows in runs.values() for row in rows]
    for case in ("paper", "paper+no_injection"):
        for tag, rows in runs.items():
            cpu = [row[case] for row in rows]
            print(f"  {case:20s} {tag:10s} CPU per series median {statistics.median(cpu):6.3f} s "
                  f"(min {min(cpu):.3f}, max {max(cpu):.3f})")
        ratios = [b[case] / a[case] for a, b in zip(runs["this"], runs[rev])]
        print(f"  {case:20s} {rev} / this: median {statistics.median(ratios):.2f}x "
              f"(min {min(ratios):.2f}, max {max(ratios):.2f})")
    same = all(a["digest"] == b["digest"] for a, b in zip(runs["this"], runs[rev]))
    print(f"every array identical: {same}; load average {min(loads):.1f}..{max(loads):.1f} during, "
          f"{os.getloadavg()[0]:.1f} at end")
    return 0 if same else 1


def dask_vs_pool(n_series: int, workers: int, repeats: int, steps: int = 450) -> int:
    """Print pool vs dask LocalCluster wall times of one data set, side by side; return an exit code."""
    import numpy as np
    from incipient_slip.cluster import open_client

    scene = load_scene("paper")
    times: dict = {"pool": [], "dask": []}
    tmp = Path(tempfile.mkdtemp(prefix="bench_sim_dask_"))
    try:
        for r in range(repeats):
            for how in ("pool", "dask"):
                out = tmp / f"{how}{r}"
                t = time.perf_counter()
                if how == "pool":
                    write_dataset(scene, n_series, 0, out, workers=workers, steps=steps, progress=False)
                else:
                    with open_client(workers=workers) as client:
                        write_dataset(scene, n_series, 0, out, steps=steps, progress=False, client=client)
                times[how].append(time.perf_counter() - t)
        for i in range(n_series):
            with np.load(tmp / "pool0" / f"series_{i:05d}.npz") as a, np.load(tmp / "dask0" / f"series_{i:05d}.npz") as b:
                if any(not np.array_equal(a[k], b[k]) for k in a.files):
                    print(f"bench_sim: error: series {i} differs between pool and dask", file=sys.stderr)
                    return 1
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    pool, dask = statistics.median(times["pool"]), statistics.median(times["dask"])
    print(f"data set paper, {n_series} series x {steps} steps, {workers} workers, {repeats} interleaved repeats, "
          f"load average {os.getloadavg()[0]:.1f}:")
    for how in ("pool", "dask"):
        print(f"  {how:4s} median {statistics.median(times[how]):6.2f} s (min {min(times[how]):.2f}, "
              f"max {max(times[how]):.2f})")
    print(f"dask / pool wall time = {dask / pool:.2f} (arrays identical)")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fraction", type=float, default=1.0, help="fraction of the 2 x 500 series to write (default 1)")
    ap.add_argument("--repeats", type=int, default=7, help="repeats per scene for the per-effect cost")
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    ap.add_argument("--against", metavar="REV", help="only compare per-period cost with git revision REV side by side")
    ap.add_argument("--stage1-against", dest="stage1_against", metavar="REV",
                    help="only compare one stage-1 calibration evaluation with git revision REV side by side")
    ap.add_argument("--stage1-size", dest="stage1_size", default="100,6", metavar="N,R",
                    help="collection series and no-action runs per material of --stage1-against (default 100,6)")
    ap.add_argument("--series-against", dest="series_against", metavar="REV",
                    help="only compare the CPU time of one data-set series with git revision REV side by side")
    ap.add_argument("--series-per-run", dest="series_per_run", type=int, default=4, metavar="K",
                    help="series per case in each process of --series-against (default 4)")
    ap.add_argument("--dask-vs-pool", dest="dask_vs_pool", type=int, metavar="N",
                    help="only compare pool and dask LocalCluster wall time of an N-series data set")
    ap.add_argument("--steps", type=int, default=450, help="periods per series for --dask-vs-pool (default 450)")
    args = ap.parse_args(argv)
    if args.dask_vs_pool:
        return dask_vs_pool(args.dask_vs_pool, args.workers, args.repeats, args.steps)
    if args.against:
        return against(args.against, args.repeats)
    if args.stage1_against:
        return stage1_against(args.stage1_against, args.repeats, args.stage1_size)
    if args.series_against:
        return series_against(args.series_against, args.repeats, args.series_per_run)
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

"""Benchmark of the estimation study's pieces, this checkout against another revision, side by side.

Pieces (each run in a fresh interpreter, the variants alternating, `--repeats` times):

* `windows`: the six methods' windows of both data sets under the paper's rule
  (`pipeline.load_all_windows`; with `--jobs`, where the code takes it), checked equal between
  the variants (a SHA-256 over every column of every method);
* `grid METHOD`: the study's SVR grid (28 candidates x 3 grouped folds) on the method's
  2000-window grid subsample of its training series, in process (`--jobs 1`) or on a pool,
  checked: the same choice and every row's RMSE within 1e-12 relative.

The older revision runs from `git archive REV` with PYTHONPATH pointing at it, so only the
public API both share is used. Prints each piece's median (min..max) wall time, the load average
around the runs and the ratio this / REV. The data sets are the study's (`--data`, a directory
holding paper_N_sS_450 and no_injection_N_sS_450, e.g. runs/data), or small ones simulated here.
Results go to docs/performance.md ("Reproducing every result").
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

_PIECE = r"""
import hashlib, inspect, json, os, sys, time
import numpy as np
from incipient_slip.models import pipeline
from incipient_slip.models.features import feature_spec
from incipient_slip.models.training import (grid_search_svr, held_out_series, load_windows, split_train_test,
                                            subsample_rows, svr_grid)
piece, dirs, jobs, arg = sys.argv[1], json.loads(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
if piece == "windows":
    kw = {"workers": jobs} if "workers" in inspect.signature(pipeline.load_all_windows).parameters else {}
    t = time.perf_counter()
    ws = pipeline.load_all_windows(dirs, progress=False, **kw)
    seconds = time.perf_counter() - t
    h = hashlib.sha256()
    for m in sorted(ws):
        for col in ("X", "y", "series", "material", "period", "stick_area_ratio", "load_ratio_stick",
                    "tangential_force_n", "normal_force_kpa", "post_slip"):
            h.update(np.ascontiguousarray(getattr(ws[m], col)).tobytes())
    out = {"seconds": seconds, "digest": h.hexdigest()}
else:
    with np.load(arg) as d:
        X, y, g = d["X"], d["y"], d["g"]
    kw = {"workers": jobs} if "workers" in inspect.signature(grid_search_svr).parameters else {}
    t = time.perf_counter()
    best, rows = grid_search_svr(X, y, g, svr_grid(X.shape[1]), progress=False, **kw)
    out = {"seconds": time.perf_counter() - t, "best": best, "rmse": [r["rmse"] for r in rows]}
print(json.dumps(out))
"""

_GRID_INPUT = r"""
import sys, json, numpy as np
from incipient_slip.models.features import feature_spec
from incipient_slip.models.pipeline import DATASET_OF_METHOD
from incipient_slip.models.training import held_out_series, load_windows, split_train_test, subsample_rows
dirs, method, out = json.loads(sys.argv[1]), sys.argv[2], sys.argv[3]
ws = load_windows(dirs[DATASET_OF_METHOD[method]], feature_spec(method), progress=False)
train, _ = split_train_test(ws, held_out_series(ws.series_materials()))
g = subsample_rows(len(train.y), 2000)
np.savez(out, X=train.X[g].astype(np.float64), y=train.y[g], g=train.series[g])
"""


def _run(code: str, args: list, env: dict, cwd: Path) -> dict:
    """Return the piece's JSON line, with "cpu_s": the CPU time of its process tree (pool workers too)."""
    import resource
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    o = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True,
                       env=dict(os.environ, **env), cwd=cwd, check=False)
    if o.returncode:
        raise SystemExit(f"bench_estimation: error: {o.stderr.strip().splitlines()[-3:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    lines = o.stdout.strip().splitlines()
    out = json.loads(lines[-1]) if lines else {}
    out["cpu_s"] = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return out


def _data(args, tmp: Path) -> dict:
    if args.data:
        found = {sc: sorted(Path(args.data).glob(f"{sc}_*_450")) for sc in ("paper", "no_injection")}
        if not all(found.values()):
            raise SystemExit(f"bench_estimation: error: {args.data} holds no paper_*_450 and no_injection_*_450")
        return {sc: str(v[-1]) for sc, v in found.items()}
    from incipient_slip.sim.dataset import write_dataset
    from incipient_slip.sim.scene import load_scene
    return {sc: str(write_dataset(load_scene(sc), args.series, 0, tmp / sc, workers=2, progress=False))
            for sc in ("paper", "no_injection")}


def _same(piece: str, a: dict, b: dict) -> bool:
    if piece == "windows":
        return a["digest"] == b["digest"]
    ra, rb = (a["rmse"], b["rmse"])
    return a["best"] == b["best"] and all(abs(x - z) <= 1e-12 * abs(z) for x, z in zip(ra, rb))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--against", default="main", metavar="REV", help="the revision to compare with (default main)")
    p.add_argument("--this", metavar="REV", help="time this revision instead of the working tree (so that "
                   "editing the tree during a run does not mix the variants)")
    p.add_argument("--data", type=Path, metavar="DIR", help="directory of the study's data sets (default: "
                   "simulate --series series per scene)")
    p.add_argument("--series", type=int, default=20)
    p.add_argument("--pieces", default="windows,grid:injection,grid:e19",
                   help="comma-separated: windows, grid:METHOD (default windows,grid:injection,grid:e19)")
    p.add_argument("--jobs", default="1,2", help="comma-separated --jobs values to time each piece with (default 1,2)")
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args()
    root = Path(__file__).resolve().parents[1]
    tmp = Path(tempfile.mkdtemp(prefix="bench_estimation_"))
    try:
        trees = {}
        for tag, rev in (("rev", a.against), ("this", a.this)):
            if rev is None:
                continue
            tar = subprocess.run(["git", "-C", str(root), "archive", rev, "src", "scenes", "pyproject.toml"],
                                 capture_output=True, check=False)
            if tar.returncode:
                print(f"bench_estimation: error: git archive {rev}: {tar.stderr.decode().strip()}", file=sys.stderr)
                return 2
            (tmp / f"{tag}.tar").write_bytes(tar.stdout)
            with tarfile.open(tmp / f"{tag}.tar") as t:
                t.extractall(tmp / tag, filter="data")
            trees[tag] = ({"PYTHONPATH": str(tmp / tag / "src")}, tmp / tag)
        dirs = _data(a, tmp)
        variants = {"this": trees.get("this", ({}, root)), a.against: trees["rev"]}
        jobs = [int(j) for j in a.jobs.split(",")]
        print(f"estimation pieces, this checkout vs {a.against}: data {dirs}, {os.cpu_count()} cores, "
              f"jobs {jobs}, {a.repeats} repeats alternating; load average {os.getloadavg()[0]:.1f}", flush=True)
        for piece in a.pieces.split(","):
            kind, _, method = piece.partition(":")
            arg = ""
            if kind == "grid":
                arg = tmp / f"grid_{method}.npz"
                _run(_GRID_INPUT, [json.dumps(dirs), method, arg], {}, root)
            for j in jobs:
                times: dict = {tag: [] for tag in variants}
                cpu: dict = {tag: [] for tag in variants}
                loads, first = [], None
                for rep in range(a.repeats):
                    order = list(variants) if rep % 2 == 0 else list(variants)[::-1]
                    for tag in order:
                        env, cwd = variants[tag]
                        load0 = os.getloadavg()[0]
                        got = _run(_PIECE, [kind, json.dumps(dirs), j, arg], env, cwd)
                        loads.append((load0, os.getloadavg()[0]))
                        times[tag].append(got["seconds"])
                        cpu[tag].append(got["cpu_s"])
                        first = first or got
                        if not _same(kind, got, first):
                            print(f"bench_estimation: error: {piece} differs between the variants", file=sys.stderr)
                            return 1
                        print(f"  {piece} jobs {j} {tag}: {got['seconds']:.1f} s, CPU {got['cpu_s']:.1f} s "
                              f"(interpreter included; load {load0:.1f} -> "
                              f"{os.getloadavg()[0]:.1f})", flush=True)
                med = {tag: statistics.median(v) for tag, v in times.items()}
                spread = {tag: f"{min(v):.1f}..{max(v):.1f}" for tag, v in times.items()}
                lo, hi = min(x for x, _ in loads), max(y for _, y in loads)
                print(f"{piece} jobs {j}: this {med['this']:.1f} s ({spread['this']}), {a.against} "
                      f"{med[a.against]:.1f} s ({spread[a.against]}), this / {a.against} "
                      f"{med['this'] / med[a.against]:.2f}; CPU this {statistics.median(cpu['this']):.1f} s, "
                      f"{a.against} {statistics.median(cpu[a.against]):.1f} s; same result; load {lo:.1f}-{hi:.1f}",
                      flush=True)
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())

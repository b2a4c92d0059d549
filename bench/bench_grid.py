"""Benchmark of the SVR grid search in process against a forked pool (`make bench-grid`).

The estimation study's grid (28 candidates x 3 grouped folds) on `--windows` injection windows of
a simulated data set, in process (`workers=1`) and on a pool of `--workers` forked processes,
interleaved `--repeats` times; every run must give the same rows (checked). Prints the wall times
(median and spread), the load average around each run and the ratio. This decides whether
`slip reproduce`'s `--jobs` should fit the grid on a pool (docs/performance.md, "Reproducing
every result"): the cells are independent, so on free cores the pool should take about 1/workers
of the time; on a machine busy with other jobs it gains nothing.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from incipient_slip.models.features import feature_spec
from incipient_slip.models.training import grid_search_svr, load_windows, subsample_rows, svr_grid
from incipient_slip.sim.dataset import write_dataset
from incipient_slip.sim.scene import load_scene


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--series", type=int, default=20, help="series of the paper scene to simulate (default 20)")
    p.add_argument("--windows", type=int, default=1500, help="windows in the grid (default 1500, as models)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--repeats", type=int, default=2)
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data = write_dataset(load_scene("paper"), a.series, 0, Path(tmp) / "paper", workers=2, progress=False)
        ws = load_windows(data, feature_spec("injection"), progress=False)
    rows = subsample_rows(len(ws.y), a.windows)
    X, y, groups = ws.X[rows].astype(float), ws.y[rows], ws.series[rows]
    grid = svr_grid(X.shape[1])
    times: dict[int, list[float]] = {1: [], a.workers: []}
    reference = None
    print(f"grid: {len(grid)} candidates x 3 folds on {len(y)} windows ({a.series} series), "
          f"{os.cpu_count()} cores", flush=True)
    for rep in range(a.repeats):
        for workers in (1, a.workers):
            load0, t0 = os.getloadavg()[0], time.perf_counter()
            best, got = grid_search_svr(X, y, groups, grid, progress=False, workers=workers)
            seconds = time.perf_counter() - t0
            reference = reference or got
            assert got == reference, "the pool's rows differ from the in-process rows"
            times[workers].append(seconds)
            print(f"  repeat {rep + 1}, workers {workers}: {seconds:.1f} s (load {load0:.1f} -> "
                  f"{os.getloadavg()[0]:.1f})", flush=True)
    for workers, v in times.items():
        print(f"workers {workers}: median {statistics.median(v):.1f} s ({min(v):.1f}-{max(v):.1f})")
    ratio = statistics.median(times[a.workers]) / statistics.median(times[1])
    print(f"pool / in process = {ratio:.2f} (same rows and choice: {best})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

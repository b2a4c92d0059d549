"""`slip dataset --scene ...`: the simulated rig's data sets (its calibration is the `calibration`
experiment, `slip reproduce calibration`). The `slip dataset` command itself is registered by
`lab.cli`, which adds `--from-recordings` (a rig's recordings) beside this."""
from __future__ import annotations

import time
from pathlib import Path

from incipient_slip.errors import UsageError


def _scene(name: str, overlay=None):
    from .scene import SceneError, load_scene
    try:
        return load_scene(name, overlay)
    except SceneError as exc:
        raise UsageError(str(exc)) from exc


def cmd_dataset(args) -> int:
    """Write a data set; return an exit code."""
    from ..cluster import check_scheduler, check_workers, open_client
    from .dataset import write_dataset

    if not args.scene or args.series is None:
        raise UsageError("give --scene and --series (a simulated data set) or --from-recordings DIR")
    scene = _scene(args.scene, args.params)
    check_scheduler(args.scheduler)
    if args.series < 1:
        raise UsageError(f"--series must be >= 1, got {args.series}")
    if args.workers is not None:
        check_workers(args.workers)
    if not 1 <= args.steps <= 100000:
        raise UsageError(f"--steps must be in 1..100000, got {args.steps}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a directory")
    if out.is_dir() and any(out.glob("series_*.npz")) and not args.overwrite:
        what = "a data set" if (out / "meta.json").exists() else "an unfinished data set (no meta.json)"
        raise UsageError(f"--out {out} already holds {what}; pass --overwrite or choose another directory")
    unknown = [m for m in (args.materials or []) if m not in scene.params["materials"]]
    if unknown:
        raise UsageError(f"unknown material(s) {', '.join(unknown)} (known: {', '.join(scene.params['materials'])})")
    t0 = time.perf_counter()
    kw = dict(materials=args.materials, steps=args.steps, progress=not args.quiet)
    if args.dask or args.scheduler:
        with open_client(args.scheduler, args.workers) as client:
            write_dataset(scene, args.series, args.seed, out, client=client, **kw)
    else:
        write_dataset(scene, args.series, args.seed, out, workers=args.workers, **kw)
    print(f"wrote {args.series} series of scene {scene.name!r} to {out} in {time.perf_counter() - t0:.1f} s")
    return 0


def add_arguments(p) -> None:
    """The simulated data set's arguments of `slip dataset` (lab.cli registers the command)."""
    p.description = ("Generate data-collection series on the simulated rig: per series 450 periods of "
        "500 ms, F_N redrawn each period from 1.1..5.9 kPa, the actuator stepping 23 mm in 450 steps. "
        "Writes meta.json + series_NNNNN.npz (format: docs/design.md). Series i uses material "
        "materials[i % n] and a seed derived from (--seed, i), so output is independent of --workers. "
        "Runs on a local process pool by default (it starts in milliseconds; a dask LocalCluster "
        "takes about a second, docs/performance.md); --dask runs the series as dask tasks on a "
        "LocalCluster, --scheduler tcp://HOST:PORT on a running dask cluster (--out then on a file "
        "system every worker can write).")
    p.add_argument("--scene", help="scene name in scenes/ (paper, no_injection, ...) or a YAML path")
    p.add_argument("--params", metavar="OVERLAY", help="an identified rig's params overlay on the scene "
                   "(launch identify.yaml; docs/identification.md)")
    p.add_argument("--series", type=int, help="number of series to write")
    p.add_argument("--seed", type=int, default=0, help="data set seed (default 0)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--materials", nargs="+", metavar="NAME", help="restrict to these materials (default: the scene's)")
    p.add_argument("--workers", type=int, default=None, help="worker processes, of the pool or of the "
                   "--dask LocalCluster (default: all cores)")
    p.add_argument("--dask", action="store_true", help="run the series as dask tasks on a LocalCluster")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the series as dask tasks on this "
                   "running scheduler (implies --dask)")
    p.add_argument("--steps", type=int, default=450, help="periods per series (default 450, the paper's)")
    p.add_argument("--overwrite", action="store_true", help="allow writing into a directory that holds a data set")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

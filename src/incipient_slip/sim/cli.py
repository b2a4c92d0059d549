"""`slip dataset` and `slip sim calibrate`: the simulated rig's command-line entry points."""
from __future__ import annotations

import time
from pathlib import Path

from incipient_slip.cli import fail
from incipient_slip.paths import repo_root


def _scene(name: str):
    from .scene import SceneError, load_scene
    try:
        return load_scene(name), None
    except SceneError as exc:
        return None, str(exc)


def cmd_dataset(args) -> int:
    """Write a data set; return an exit code."""
    from .dataset import write_dataset

    scene, err = _scene(args.scene)
    if err:
        return fail(err)
    if args.series < 1:
        return fail(f"--series must be >= 1, got {args.series}")
    if args.workers is not None and args.workers < 1:
        return fail(f"--workers must be >= 1, got {args.workers}")
    if not 1 <= args.steps <= 100000:
        return fail(f"--steps must be in 1..100000, got {args.steps}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        return fail(f"--out {out} exists and is not a directory")
    if out.is_dir() and any(out.glob("series_*.npz")) and not args.overwrite:
        return fail(f"--out {out} already holds a data set (series_*.npz); pass --overwrite or choose another directory")
    unknown = [m for m in (args.materials or []) if m not in scene.params["materials"]]
    if unknown:
        return fail(f"unknown material(s) {', '.join(unknown)} (known: {', '.join(scene.params['materials'])})")
    t0 = time.perf_counter()
    write_dataset(scene, args.series, args.seed, out, materials=args.materials, workers=args.workers,
                  steps=args.steps, progress=not args.quiet)
    print(f"wrote {args.series} series of scene {scene.name!r} to {out} in {time.perf_counter() - t0:.1f} s")
    return 0


def cmd_calibrate(args) -> int:
    """Run the calibration report; return an exit code."""
    from .calibrate import report_markdown, run_calibration
    from .docs import write_simulator_doc

    scene, err = _scene(args.scene)
    if err:
        return fail(err)
    if args.series < 1:
        return fail(f"--series must be >= 1, got {args.series}")
    if not scene.has("injection"):
        return fail(f"scene {scene.name!r} has no 'injection' effect; the 200 Hz band target needs it")
    out = Path(args.out)
    fig_dir = out.parent / "figures"
    res = run_calibration(scene, n_per_material=args.series, seed=args.seed, fig_dir=fig_dir)
    table = report_markdown(scene, res)
    print(table)
    write_simulator_doc(out, table, res["figures"])
    print(f"wrote {out} and {len(res['figures'])} figures in {fig_dir}")
    return 0


def register(subparsers, reproduce) -> None:
    """Add `slip dataset` and `slip sim calibrate` to the `slip` command."""
    p = subparsers.add_parser(
        "dataset", help="generate a simulated data set (paper protocol) into a directory",
        description="Generate data-collection series on the simulated rig: per series 450 periods of "
        "500 ms, F_N redrawn each period from 1.1..5.9 kPa, the actuator stepping 23 mm in 450 steps. "
        "Writes meta.json + series_NNNNN.npz (format: docs/design.md). Series i uses material "
        "materials[i % n] and a seed derived from (--seed, i), so output is independent of --workers.")
    p.add_argument("--scene", required=True, help="scene name in scenes/ (paper, no_injection, ...) or a YAML path")
    p.add_argument("--series", type=int, required=True, help="number of series to write")
    p.add_argument("--seed", type=int, default=0, help="data set seed (default 0)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--materials", nargs="+", metavar="NAME", help="restrict to these materials (default: the scene's)")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    p.add_argument("--steps", type=int, default=450, help="periods per series (default 450, the paper's)")
    p.add_argument("--overwrite", action="store_true", help="allow writing into a directory that holds a data set")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_dataset)

    sim = subparsers.add_parser("sim", help="simulated rig tools (calibrate)",
                                description="Tools for the simulated rig.")
    sim_sub = sim.add_subparsers(dest="sim_command", metavar="SUBCOMMAND", required=True)
    c = sim_sub.add_parser(
        "calibrate", help="compare the simulated rig with the paper's measured quantities",
        description="Run the calibration checks (travel at gross-slip onset, R of the 200 Hz band vs F_T, "
        "final y without control, gross slip within 23 mm, label distribution) and write the report with "
        "figures into docs/simulator.md (figures in docs/figures/sim_*.png).")
    c.add_argument("--scene", default="paper", help="scene name or YAML path (default paper; needs injection)")
    c.add_argument("--series", type=int, default=20, help="collection series per material (default 20)")
    c.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    c.add_argument("--out", default=str(repo_root() / "docs" / "simulator.md"), help="report path (default docs/simulator.md)")
    c.set_defaults(func=cmd_calibrate)

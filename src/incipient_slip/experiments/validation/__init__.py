"""The held-out closed loop over the simulated rig's uncertainty set (docs/calibration.md).

At each point of the uncertainty set (beta, the friction spread, the friction-limit lag; one at a
time around the fitted point, or with `--joint` every combination on a grid) the mechanics are first re-fitted to the open-loop targets T1-T4
(a point that cannot meet them is reported as inconsistent), then data sets are simulated with the
paper's collection protocol, the six slip models are trained on them (quick SVR), and the paper's
Table is run: 7 methods x N runs of the grip law (s_d 0.3, k 2 kPa) in-process on `sim.Rig`
(the same period-by-period semantics as launch/stabilize.yaml: the estimate of the 1.0 s window
ending at the period's end drives the next period's F_N; failure at y > 1.5 mm or F_N at 6.0 kPa),
plus the oracle (the law on the simulator's true load ratio) as a diagnostic. Points run as tasks on
dask.distributed (a LocalCluster by default, `--scheduler tcp://host:port` for a cluster); every task
is seeded by its point, so results do not depend on the worker count. Nothing here feeds back into
any parameter: this is the validation, and all of it is the simulated rig.

The experiment in modules: `spec` (methods, the uncertainty set, budgets), `planning` (options checked
before anything starts), `execution` (the dask tasks of `tasks`), `merging` (with kept results; the
summaries and the figures of `figures`), `report` (the docs blocks), `overlays` (an identified rig).
"""
from __future__ import annotations

from pathlib import Path

from incipient_slip import control

from .execution import execute
from .merging import merge
from .planning import Plan, plan
from .report import render
from .spec import JOINT, JOINT_SHORT, POINTS, RESULTS, SWEEP_SD, joint_points

__all__ = ["NAME", "HELP", "DOC", "RESULTS", "QUICK", "Plan", "add_arguments", "plan", "render", "run"]

NAME = "validation"

HELP = "the held-out stabilization Table over the simulated rig's uncertainty set (dask)"

DOC = "validation.md"

QUICK = ("4 of the 9 points (fitted, beta 1.25, mu spread 1, lag 1 s), each refitted once with at most 10 "
         "evaluations (full 25, then 40 when T1-T4' are missed), 30 training series per data set (full 100), "
         "2 runs per method (full 10), every run the full 450 steps; a point's consistency verdict can "
         "differ from the full run's")



def add_arguments(parser) -> None:
    """Add the validation's options."""
    parser.add_argument("--points", nargs="+", choices=list(POINTS), help="points of the uncertainty set (default all)")
    parser.add_argument("--joint", action="store_true",
                        help=f"also run the joint grid ({len(joint_points())} combinations of "
                             + ", ".join(f"{JOINT_SHORT[k]} {'/'.join(f'{v:g}' for v in vs)}" for k, vs in JOINT.items())
                             + "): every point is refitted to T1-T4, the Table runs only where that succeeds; "
                               "with --joint, --points defaults to none")
    parser.add_argument("--runs", type=int, help="closed-loop runs per method and point (quick 2, full 10)")
    parser.add_argument("--series", type=int, help="training series per data set and point (quick 30, full 100)")
    parser.add_argument("--steps", type=int, help=f"steps of a run (default {control.MAX_STEPS}, the paper's, on both budgets)")
    parser.add_argument("--sweep-at", dest="sweep_at", nargs="+", metavar="JOINT_POINT",
                        help="run these joint points again with the s_d sweep (--sweep-runs, default 3) and put "
                             "them into the joint results kept with --keep (names as in docs/validation.md, "
                             "e.g. 'beta 1, lag 1, mu spread 0.5')")
    parser.add_argument("--sweep-runs", dest="sweep_runs", type=int,
                        help=f"also sweep s_d over {SWEEP_SD} at each point with this many runs per method (default 0: no sweep)")
    parser.add_argument("--keep", type=Path, metavar="RESULTS_JSON",
                        help="a previous results.json whose points not run this time are kept in the report")
    parser.add_argument("--params", type=Path, nargs="+", metavar="OVERLAY",
                        help="params overlays of an identified rig (launch identify.yaml, docs/identification.md; "
                             "one per material, the pad's values from the last): predict the Table for that rig "
                             "on its identified materials at the values and at each end of their intervals, one at "
                             "a time (no refit to the paper's targets); results and page go to --out")
    parser.add_argument("--plan", action="store_true",
                        help="print what would run (points, refits, runs, what is kept) and exit; nothing starts")
    parser.add_argument("--workers", type=int, help="LocalCluster workers (default --jobs)")
    parser.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="a running dask scheduler instead of a LocalCluster")



def run(settings) -> dict:
    """Plan (every usage error first), execute on dask, merge with the kept results."""
    p = plan(settings)
    if settings.progress:
        print(p.describe(), flush=True)
    return merge(p, *execute(p, settings), settings)


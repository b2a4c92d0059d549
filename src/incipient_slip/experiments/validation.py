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
"""
from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path

import numpy as np

from incipient_slip.errors import UsageError

from incipient_slip import control
from incipient_slip.cluster import check_scheduler, open_client

from . import calibration as cal
from . import closed_loop as loop
from .timing import duration

NAME = "validation"
HELP = "the held-out stabilization Table over the simulated rig's uncertainty set (dask)"
DOC = "validation.md"
RESULTS = "validation_results.json"

TABLE_METHODS = ("none", "vibrotactile", "e1", "e4", "e10", "e19", "injection")
LABELS = {"none": "no action", "vibrotactile": "vibrotactile", "e1": "E1", "e4": "E4", "e10": "E10",
          "e19": "E19", "injection": "injection", "oracle": "oracle (true ratio; diagnostic)"}
SCENE_OF = {**control.SCENE_OF_METHOD, "oracle": "mechanics"}     # the oracle reads the truth: no sensor path
PAPER = {"none": (None, 2.48, 2.94, 450), "vibrotactile": (0.3, 1.32, 5.96, 397), "e1": (0.0, 0.89, 6.47, 139),
         "e4": (0.1, 2.52, 3.59, 450), "e10": (1.0, 1.55, 5.23, 450), "e19": (0.8, 1.40, 6.24, 435),
         "injection": (1.0, 1.38, 4.50, 450)}
# the uncertainty set of simulator v3 (docs/calibration.md, amendment 2): one parameter at a time at
# the ends of its plausible range; each point refits k_b and k_s and is excluded when it cannot meet
# T1-T4' and T7 (beta and the friction spread are fitted at the nominal point; their ends here bracket it)
POINTS = {
    "fitted": {},
    "beta 0.75": {"pre_slip.bulk_stiffening_exponent": 0.75},
    "beta 1.25": {"pre_slip.bulk_stiffening_exponent": 1.25},
    "mu spread 0.4": {"stick_slip.mu_spread_scale": 0.4},
    "mu spread 1": {"stick_slip.mu_spread_scale": 1.0},
    "lag 0.5 s": {"stick_slip.friction_limit_lag_s": 0.5},
    "lag 1 s": {"stick_slip.friction_limit_lag_s": 1.0},
    "creep b 0.005": {"stick_slip.rate_strengthening": 0.005},
    "creep b 0.05": {"stick_slip.rate_strengthening": 0.05},
}
# the joint uncertainty set: every combination; each point's own open-loop refit decides whether the
# open-loop data allow it, and only those points get the closed-loop Table
# (beta 0.75 and spread 0.4 are left out: their one-at-a-time points cannot meet the open-loop targets)
JOINT = {"pre_slip.bulk_stiffening_exponent": (1.0, 1.25),
         "stick_slip.friction_limit_lag_s": (0.0, 0.5, 1.0),
         "stick_slip.mu_spread_scale": (0.7, 1.0)}
JOINT_SHORT = {"pre_slip.bulk_stiffening_exponent": "beta", "stick_slip.friction_limit_lag_s": "lag",
               "stick_slip.mu_spread_scale": "mu spread"}


def joint_points() -> dict[str, dict]:
    """Return {name: overrides} for every combination of the joint uncertainty set."""
    import itertools
    keys = list(JOINT)
    return {", ".join(f"{JOINT_SHORT[k]} {v:g}" for k, v in zip(keys, combo)): dict(zip(keys, combo))
            for combo in itertools.product(*(JOINT[k] for k in keys))}


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


def _scene(name: str, params: dict):
    return dataclasses.replace(_loaded_scene(name), params=params)


@functools.lru_cache(maxsize=None)
def _loaded_scene(name: str):
    """The scene file, parsed once per process (every closed-loop run replaces its params)."""
    from incipient_slip.sim.scene import load_scene

    return load_scene(name)


def closed_loop(method: str, params: dict, material: str, seed: int, model, steps: int,
                s_d: float = control.DEFAULT_TARGET_STICK_RATIO, trace: list | None = None,
                stop_on_travel: bool = False) -> dict:
    """Return one run's outcome: the grip law on `method`'s estimate (or on the true ratio for
    'oracle', or no action for 'none') on the simulated rig with `params`, judged by the
    supervisor's own rules (the paper's protocol by default); `closed_loop.run_loop` runs it."""
    from incipient_slip.sim.rig import Rig

    rig = Rig(_scene(SCENE_OF[method], params), material, seed)
    estimate = (None if method == "none" else loop.true_ratio if method == "oracle"
                else loop.model_estimate(model))
    rules = control.SupervisorRules(max_steps=steps, end_on_failure=method != "none", stop_on_travel=stop_on_travel)
    slid = False
    for period in loop.run_loop(rig, estimate, control.ControlParams(target_stick_ratio=s_d), rules):
        out = period.out
        slid = slid or out.gross_slip
        if trace is not None:
            trace.append({"y": out.object_y_mm, "fn": period.force_kpa, "est": period.estimate,
                          "true": out.load_ratio_stick, "sar": out.stick_area_ratio})
    fn, verdict = period.command_kpa, period.verdict
    failed = "" if verdict.kind == "success" else ("F_N" if fn >= control.SAFETY_LIMIT_KPA - 1e-9
                                                   else "y" if period.travel_mm > control.FAILURE_TRAVEL_MM else "")
    return {"success": verdict.kind == "success" if method != "none" else None, "end": failed or "steps",
            "y": period.travel_mm, "fn": float(fn), "steps": period.step, "material": material,
            "slide_mm": float(rig.state.anchor_mm), "slid": bool(slid)}


SWEEP_SD = (0.3, 0.5, 0.7, 0.8)
CONTROLLED = tuple(m for m in TABLE_METHODS if m != "none") + ("oracle",)   # the methods that act on F_N
LABEL_METHODS = ("injection", "e10", "e19")     # the rows of another label than the paper's
# stage-1 refit per point: (collection series, no-action runs per material, evaluations); the second
# only when the first cannot meet T1-T4 (an open-loop rule, the same for every point)
REFITS = ((25, 2, 25), (50, 3, 40))
SWEEP_METHODS = ("injection", "e19", "e10", "e4", "oracle")
# the quick preview: four points (the fitted one and one end of each refitted parameter), one refit
# of at most 10 evaluations; every run the full 450 steps
QUICK_POINTS = ("fitted", "beta 1.25", "mu spread 1", "lag 1 s")
QUICK_REFITS = ((25, 2, 10),)
QUICK = ("4 of the 9 points (fitted, beta 1.25, mu spread 1, lag 1 s), each refitted once with at most 10 "
         "evaluations (full 25, then 40 when T1-T4' are missed), 30 training series per data set (full 100), "
         "2 runs per method (full 10), every run the full 450 steps; a point's consistency verdict can "
         "differ from the full run's")


def refit_task(name: str, overrides: dict, seed: int, refits=None) -> dict:
    """Return the point's stage-1 refit to T1-T4' and T7 and whether it meets them (docs/calibration.md);
    from the content-hashed cache (`incipient_slip.cache`) when the same refit of the same physics
    and code was done before."""
    from incipient_slip import cache
    from incipient_slip.sim.dataset import physics_fingerprint
    from incipient_slip.sim.scene import load_scene

    scene = cal.with_values(load_scene("paper"), {tuple(k.split(".")): v for k, v in overrides.items()})
    key = cache.digest("refit-1", name, physics_fingerprint(scene), seed, refits or REFITS,
                       cache.source_version(Path(cal.__file__)))
    return cache.cached("refit", key, lambda: _refit(name, overrides, scene, seed, refits))


def _refit(name: str, overrides: dict, scene, seed: int, refits) -> dict:
    t0 = time.perf_counter()
    n = 0
    for n_fit, runs_fit, evals in refits or REFITS:   # a second, larger refit only when the first misses T1-T4
        fit = cal.fit_mechanics(scene, n_fit, runs_fit, seed, evals, progress=False, stiffness_only=True)
        scene = cal.with_values(scene, {tuple(k.split(".")): v for k, v in fit["values"].items()})
        summ = fit["summary"]
        n += 1
        if cal.consistent_with_open_loop(summ):
            break
    return {"point": name, "overrides": overrides, "values": fit["values"], "summary": summ, "refits": n,
            "consistent": cal.consistent_with_open_loop(summ), "seconds": time.perf_counter() - t0}


def merge_overlays(docs: list[dict]) -> dict:
    """Return one overlay from several sessions of one rig (one per material): the materials of
    all, the pad's and the rig's entries from the last; provenance lists every session."""
    merged: dict = {"provenance": {}}
    for doc in docs:
        for section, entries in doc.items():
            if section == "provenance":
                continue
            if section == "materials":
                merged.setdefault("materials", {}).update(entries)
            else:
                merged.setdefault(section, {}).update(entries)
    sessions = [d["provenance"] for d in docs]
    last = sessions[-1]
    merged["provenance"] = {**last, "material": ", ".join(str(p.get("material")) for p in sessions),
                            "date": ", ".join(sorted({str(p.get("date")) for p in sessions})),
                            "sessions": sessions}
    return merged


def overlay_points(doc: dict) -> dict[str, dict]:
    """Return {point name: params} of an identified rig: the overlay's values, then each entry
    with an interval at its low and high end (one at a time). An end at the value itself (an
    entry without an interval, or one-sided) would repeat the identified point's Table: left out."""
    from incipient_slip.sim.scene import apply_overlay, load_params, overlay_entries

    base, _, _ = load_params("default")
    points = {"identified": apply_overlay(base, doc)}
    for name, entry in overlay_entries(doc).items():
        for end, v in zip(("low", "high"), entry.get("interval") or ()):
            if v == entry.get("value"):
                continue
            points[f"{'.'.join(name[-2:])} {end} {v:.3g}"] = apply_overlay(base, doc, values={name: v})
    return points


def point_task(name: str, overrides: dict, runs: int, n_series: int, steps: int, seed: int, work: str,
               sweep_runs: int = 0, refits=None, fit: dict | None = None, fig_dir: str | None = None,
               params: dict | None = None, materials: tuple | None = None) -> dict:
    """Return everything of one point: its stage-1 refit (`fit` when already done), model scores and
    the Table's runs. With `params` (an identified rig's) there is no refit: the rig's own values,
    and the Table runs on `materials` (the identified ones) only."""
    from incipient_slip.sim.rig import series_seed
    from incipient_slip.sim.scene import load_scene
    from incipient_slip.models.estimator_core import limit_blas_threads
    from incipient_slip.models.features import METHODS
    from incipient_slip.models.pipeline import load_all_windows, run_study
    from incipient_slip.models.training import relabel, series_targets

    from .datasets import ensure_dataset
    limit_blas_threads(1)
    t0 = time.perf_counter()
    if params is not None:
        fit = {"values": {}, "summary": None, "refits": 0, "consistent": None}
        scene = dataclasses.replace(load_scene("paper"), params=params)
    else:
        fit = fit or refit_task(name, overrides, seed, refits)
        scene = cal.with_values(load_scene("paper"), {tuple(k.split(".")): v
                                                      for k, v in {**overrides, **fit["values"]}.items()})
    summ, consistent = fit["summary"], fit["consistent"]
    d = Path(work) / _slug(name)
    # reused when the same physics made them before; no_injection's series come from paper's runs
    dirs = {"paper": ensure_dataset(_scene("paper", scene.params), n_series, seed + 1, d / "paper", workers=1,
                                    progress=False, views={d / "no_injection": _scene("no_injection", scene.params)}),
            "no_injection": d / "no_injection"}
    mats = tuple(materials) if materials else scene.materials
    by_label = {}
    # the other labels' rows where the answer reads them: the answer's methods, at the points the
    # open-loop data allow and the fitted one (10 minutes for `slip reproduce all`, issue 27)
    rows = label_rows(scene.params)
    if consistent is False and name != "fitted":
        rows = {"pseudo": rows["pseudo"]}
    # the features once (as run_study would read them); each other label only relabels the windows
    windows = load_all_windows(dirs, METHODS, progress=False)
    targets = series_targets(dirs["paper"], list(rows.values()))
    errors = label_error_by_fn(dirs["paper"], targets, len(rows))
    for n, (key, rule) in enumerate(rows.items()):
        methods = METHODS if key == "pseudo" else row_methods(key, rows)
        own = windows if key == "pseudo" else {
            m: relabel(windows[m], {i: t[n] for i, t in targets.items()}) for m in methods}
        study = run_study(dirs, methods=methods, quick=True, max_train=2000, grid_max=600, progress=False,
                          windows=own, label=rule)
        row = {"rule": {"name": rule.name, "friction_lag_s": rule.friction_lag_s},
               "label_error_by_fn": errors[n],
               "rmse": {m: float(r.scores.rmse.mean()) for m, r in study.results.items()},
               "top10": {m: float(r.scores.top10_rmse.mean()) for m, r in study.results.items()},
               "rmse_truth": {m: rmse_to_truth(r) for m, r in study.results.items()},
               "models": {m: r.model for m, r in study.results.items()}}
        row["runs"] = {method: [closed_loop(method, scene.params, mats[j % len(mats)], series_seed(seed + 2, j),
                                            row["models"].get(method), steps) for j in range(runs)]
                       for method in (TABLE_METHODS + ("oracle",) if key == "pseudo" else methods)}
        by_label[key] = row
    models = by_label["pseudo"].pop("models")
    table = by_label["pseudo"].pop("runs")
    for row in by_label.values():
        row.pop("models", None)
    sweep = {}
    for method in SWEEP_METHODS if sweep_runs else ():
        sweep[method] = {str(sd): [closed_loop(method, scene.params, mats[j % len(mats)], series_seed(seed + 3, j),
                                               models.get(method), steps, sd) for j in range(sweep_runs)]
                         for sd in SWEEP_SD}
    trajectory = (trajectory_figure(scene.params, models, mats[0], series_seed(seed + 2, 0), Path(fig_dir))
                  if fig_dir and name == "fitted" else None)
    return {"point": name, "overrides": overrides, "fit": {"values": fit["values"], "summary": summ,
                                                           "refits": fit["refits"], "seconds": fit.get("seconds")},
            "trajectory": trajectory,
            "sweep": sweep,
            "consistent": consistent, "rmse": by_label["pseudo"]["rmse"], "top10": by_label["pseudo"]["top10"],
            "runs": table, "labels": by_label, "seconds": time.perf_counter() - t0}


def row_methods(key: str, rows: dict) -> tuple:
    """The methods a label row runs: the answer's three, but where a lag-identified row exists, the
    row without the lag runs injection alone (it shows what an unidentified lag does to the method;
    the electrodes slide with every label: docs/validation.md)."""
    if key == "measured-ratio" and "measured-ratio, lag identified" in rows:
        return ("injection",)
    return LABEL_METHODS


def label_rows(params: dict) -> dict:
    """Return {row name: LabelRule} of the labels a point is run with: the paper's, the measured
    ratio with nothing identified (tau 0) and, where the point's friction limit lags, the measured
    ratio with that lag as if identified exactly (docs/estimation.md)."""
    from incipient_slip.models.labels import LabelRule

    rows = {"pseudo": LabelRule("pseudo"), "measured-ratio": LabelRule("measured-ratio")}
    lag = float(params["stick_slip"]["friction_limit_lag_s"])
    if lag > 0:
        rows["measured-ratio, lag identified"] = LabelRule("measured-ratio", lag)
    return rows


def label_error_by_fn(data_dir, targets: dict, n_labels: int) -> list[list[dict]]:
    """Return, per label, the label minus the simulator's true load ratio by F_N bin over every
    period of the collection series (the label's own windows: after the first onset too; no model).
    `targets` is `models.training.series_targets` of the same set: only F_N and the truth are read."""
    from incipient_slip.models.dataset import load_series, series_paths, series_index

    pairs = [[] for _ in range(n_labels)]
    for path in series_paths(data_dir):
        if series_index(path) not in targets:           # no gross slip: no label
            continue
        series = load_series(path, streams=False)
        truth = np.clip(np.nan_to_num(series.load_ratio_stick), 0.0, 1.0)
        for out, target in zip(pairs, targets[series.index]):
            out.extend(zip(series.normal_force_kpa.tolist(), (target - truth).tolist()))
    return [cal.label_report(p) for p in pairs]


def rmse_to_truth(result) -> float:
    """Return a method's held-out RMSE against the simulator's true load ratio (mean over series)."""
    from incipient_slip.models.evaluation import series_scores

    test = result.test
    truth = np.clip(np.nan_to_num(test.load_ratio_stick), 0.0, 1.0)
    return float(series_scores(result.method, truth, result.pred, test.series, test.material).rmse.mean())


def summarize(runs: list) -> dict:
    """Return success rate, mean final y, F_N and steps, and the paper's score of a method's runs."""
    succ = [r["success"] for r in runs if r["success"] is not None]
    rate = float(np.mean(succ)) if succ else None
    y = float(np.mean([r["y"] for r in runs]))
    fn = float(np.mean([r["fn"] for r in runs]))
    return {"success": rate, "y": y, "fn": fn, "steps": float(np.mean([r["steps"] for r in runs])),
            "score": control.score(rate or 0.0, max(y, 1e-6), max(fn, 1e-6))}


def budget(settings) -> dict:
    """Return the points, runs, series, steps and refits of the budget (the options override them)."""
    opt = settings.option
    return {"points": opt("points", [] if (opt("joint", False) or opt("sweep_at"))
                          else list(settings.pick(QUICK_POINTS, POINTS))),
            "runs": opt("runs", settings.pick(2, 10)), "series": opt("series", settings.pick(30, 100)),
            "steps": opt("steps", control.MAX_STEPS),      # quick too: shorter runs would all "succeed"
            "refits": opt("refits", settings.pick(QUICK_REFITS, None))}


@dataclasses.dataclass
class Plan:
    """What a validation run will do, checked before any cluster starts (`plan`; `--plan` prints it)."""

    names: list                     # the one-at-a-time (or identified rig's) points whose Table runs
    runs: int
    n_series: int
    steps: int
    refits: tuple | None
    joint: bool                     # refit every joint point, the Table where consistent
    grid: dict                      # the joint set {name: overrides}
    sweep_at: list                  # joint points run again with the s_d sweep
    sweep_runs: int | None
    scheduler: str | None
    workers: int
    work: Path
    old: dict = dataclasses.field(default_factory=dict)   # kept results (--keep, or the committed page's)
    kept_from: Path | None = None
    rig_points: dict = dataclasses.field(default_factory=dict)   # an identified rig's points (--params)
    provenance: dict | None = None
    rig_materials: tuple | None = None

    def sweep_of(self, name: str) -> int:
        """Runs per s_d of a point's sweep (0: none; a joint point only when --sweep-at)."""
        if name in self.sweep_at:
            return self.sweep_runs or 3
        return 0 if name in self.grid else (self.sweep_runs or 0)

    def describe(self) -> str:
        """Return the plan as lines a user can read before anything runs."""
        lines = [f"validation plan: {self.runs} runs per method, {self.n_series} training series per data set, "
                 f"{self.steps} steps per run; {'a running scheduler ' + self.scheduler if self.scheduler else f'a LocalCluster of {self.workers} workers'}"]
        if self.rig_points:
            lines.append(f"identified rig ({(self.provenance or {}).get('material')}): {len(self.rig_points)} points, "
                         f"no refit: {', '.join(self.rig_points)}")
        elif self.names:
            lines.append(f"one-at-a-time points ({len(self.names)}), each refitted to T1-T4' and T7, then the Table "
                         f"per label: {', '.join(self.names)}")
        elif not self.old.get("points"):
            lines.append("one-at-a-time points: none run and none kept (--keep RESULTS_JSON keeps a run's)")
        if self.joint:
            lines.append(f"joint set: {len(self.grid)} refits, the Table at each consistent one")
        if self.names or self.joint:
            lines.append(f"labels: pseudo (every method and the oracle); measured-ratio ({', '.join(LABEL_METHODS)}) at "
                         "the fitted point and where the refit meets the targets, and with the point's friction lag "
                         "as if identified where it has one (docs/estimation.md)")
        if self.sweep_at:
            lines.append(f"s_d sweep ({self.sweep_runs or 3} runs per cell) at: {', '.join(self.sweep_at)}")
        elif self.sweep_runs:
            lines.append(f"s_d sweep ({self.sweep_runs} runs per cell) at every one-at-a-time point")
        if self.kept_from:
            kept = [n for n in self.old.get("points", {}) if n not in self.names]
            lines.append(f"kept from {self.kept_from}: " + ", ".join(
                (["the joint set"] if "joint" in self.old and not self.joint else []) + kept or ["nothing"]))
        return "\n".join(lines)


def plan(settings) -> Plan:
    """Return the run's plan from the options; every usage error is raised here, before a cluster starts."""
    opt = settings.option
    joint = bool(opt("joint", False))
    b = budget(settings)
    names, runs, n_series, steps, refits = (b[k] for k in ("points", "runs", "series", "steps", "refits"))
    for label, v in (("--runs", runs), ("--series", n_series), ("--steps", steps)):
        if v < 1:
            raise UsageError(f"{label} must be >= 1, got {v}")
    scheduler = check_scheduler(opt("scheduler"))
    keep = opt("keep")
    if keep is None and not joint and settings.docs is not None and not opt("params"):
        # the page's joint set (hours of refits before issue 22) is not rerun without --joint:
        # keep it as committed instead of dropping it from the page
        committed = settings.results_file(RESULTS)
        if committed.is_file():
            keep = committed
    old = {}
    if keep:
        import json
        try:
            old = json.loads(Path(keep).read_text())
        except (OSError, ValueError) as e:
            raise UsageError(f"--keep {keep}: {e}") from None
    rig_points, provenance, rig_materials = {}, None, None
    if opt("params"):
        from incipient_slip.sim.scene import SceneError, load_overlay
        if settings.docs is not None:
            raise UsageError("--params predicts the Table of one identified rig: its page goes to --out, not into --docs")
        if joint or opt("points") or opt("sweep_at"):
            raise UsageError("--params runs the identified rig's own points; leave out --joint, --points and --sweep-at")
        try:
            doc = merge_overlays([load_overlay(path) for path in opt("params")])
            rig_points = overlay_points(doc)
        except SceneError as exc:
            raise UsageError(str(exc)) from None
        provenance = doc["provenance"]
        rig_materials = tuple(doc.get("materials", {})) or None   # the Table on the identified object(s)
        names = list(rig_points)
    grid = joint_points()
    sweep_at = opt("sweep_at") or []
    for n in sweep_at:
        if n not in grid:
            raise UsageError(f"--sweep-at {n!r}: not a point of the joint set (e.g. {next(iter(grid))!r})")
    if sweep_at and not joint and "joint" not in old:
        raise UsageError("--sweep-at needs the joint results: add --joint, or --keep a results file that has them")
    return Plan(list(names), runs, n_series, steps, refits, joint, grid, list(sweep_at), opt("sweep_runs"),
                scheduler, opt("workers", settings.jobs), Path(settings.work) / "data", old,
                Path(keep) if keep else None, rig_points, provenance, rig_materials)


def execute(p: Plan, settings) -> tuple[dict, dict, dict]:
    """Run the plan's tasks on dask; return the one-at-a-time Tables, the joint Tables and the joint
    refits without a Table, each {point: result}."""
    from dask.distributed import as_completed

    def table_future(name, overrides, fit=None):
        sweep = p.sweep_of(name)
        return client.submit(point_task, name, overrides, p.runs, p.n_series, p.steps, settings.seed, str(p.work),
                             sweep, p.refits, fit, str(settings.figures) if settings.figures else None,
                             p.rig_points.get(name), p.rig_materials,
                             key=f"validation-{_slug(name)}-{settings.seed}-sweep{sweep}",
                             pure=False)

    done, joint_done, refit_only = {}, {}, {}
    with open_client(p.scheduler, p.workers) as client:
        # the longest tasks first (a point whose friction limit lags runs one label row more), so
        # that the last task to finish is a short one
        names = sorted(p.names, key=lambda n: -float(POINTS.get(n, {}).get("stick_slip.friction_limit_lag_s", 0.0)))
        futures = ([table_future(n, POINTS.get(n, {})) for n in names]
                   + [table_future(n, p.grid[n]) for n in p.sweep_at])
        futures += [client.submit(refit_task, n, ov, settings.seed, p.refits,
                                  key=f"refit-{_slug(n)}-{settings.seed}", pure=False)
                    for n, ov in (p.grid.items() if p.joint else ()) if n not in p.sweep_at]
        total, i = len(futures), 0
        queue = as_completed(futures)
        for fut in queue:     # a consistent joint refit adds its Table to the queue
            res, i = fut.result(), i + 1
            verdict = {True: "consistent", False: "INCONSISTENT", None: "the identified rig's values, not refitted"}[
                res["consistent"]]
            if "runs" not in res:
                refit_only[res["point"]] = res
                if res["consistent"]:     # (a --sweep-at point has its Table with the sweep already)
                    queue.add(table_future(res["point"], res["overrides"], res))
                    total += 1
            elif res["point"] in p.grid:
                joint_done[res["point"]] = res
            else:
                done[res["point"]] = res
            if settings.progress:
                what = "refit" if "runs" not in res else "Table"
                print(f"  [{i}/{total}] {what} of {res['point']!r} done in {res['seconds']:.0f} s "
                      f"({verdict} with T1-T4', T7)", flush=True)
    return done, joint_done, refit_only


def merge(p: Plan, done: dict, joint_done: dict, refit_only: dict, settings) -> dict:
    """Return the results: this run's points over the kept ones, with their Tables and figures."""
    old = p.old
    points = {n: q for n, q in old.get("points", {}).items() if n not in p.names}
    points.update(done)
    points = {n: points[n] for n in (p.rig_points or POINTS) if n in points}
    for q in points.values():
        _summarize_point(q)
    kept_only = not done and old.get("points")      # the one-at-a-time points all come from --keep
    out = {"rig": p.provenance, "budget": settings.budget, "runs": old.get("runs", p.runs) if kept_only else p.runs,
           "series": old.get("series", p.n_series) if kept_only else p.n_series, "steps": p.steps, "points": points,
           "figure": _figure(points, settings.figures) if points else None}
    for q in joint_done.values():
        _summarize_point(q)
    if p.joint:
        out["joint"] = {"axes": {k: list(v) for k, v in JOINT.items()}, "runs": p.runs, "series": p.n_series,
                        "points": {n: joint_done.get(n) or {"point": n, "overrides": p.grid[n],
                                                            "consistent": False, "fit": refit_only[n]}
                                   for n in p.grid}}
    elif "joint" in old:
        out["joint"] = old["joint"]
        out["joint"]["points"].update(joint_done)
    if joint_done or p.joint:
        out["joint_figure"] = _joint_figure(out["joint"], settings.figures)
    elif "joint" in old:
        out["joint_figure"] = old.get("joint_figure")
    if done.get("fitted", {}).get("trajectory"):
        out["trajectory"] = done["fitted"]["trajectory"]
    elif old.get("trajectory"):
        out["trajectory"] = old["trajectory"]
    return out


def run(settings) -> dict:
    """Plan (every usage error first), execute on dask, merge with the kept results."""
    p = plan(settings)
    if settings.progress:
        print(p.describe(), flush=True)
    return merge(p, *execute(p, settings), settings)


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in ".-" else "_" for c in name)


def _summarize_point(p: dict) -> None:
    p["table"] = {m: summarize(r) for m, r in p["runs"].items()}
    for row in p.get("labels", {}).values():        # the pseudo row's runs are the point's own
        if "runs" in row:
            row["table"] = {m: summarize(r) for m, r in row["runs"].items()}
    p["sweep_table"] = {m: {sd: summarize(r) for sd, r in by_sd.items()} for m, by_sd in p.get("sweep", {}).items()}


def _figure(points: dict, fig_dir: Path) -> str:
    from incipient_slip.experiments.plots import pyplot, save
    plt = pyplot()

    methods = list(CONTROLLED)
    grid = np.array([[points[p]["table"][m]["success"] for m in methods] for p in points], float)
    fig, ax = plt.subplots(figsize=(8, 0.5 * len(points) + 1.8))
    im = ax.imshow(grid, vmin=0, vmax=1, cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(methods)), [LABELS[m] for m in methods], rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(points)), [p + (" (inconsistent)" if points[p]["consistent"] is False else "") for p in points],
                  fontsize=8)
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            ax.text(j, i, f"{grid[i, j]:.1f}", ha="center", va="center", color="w", fontsize=7)
    fig.colorbar(im, ax=ax, label="success rate")
    ax.set_title("SIMULATED RIG: where each method holds the object (success rate) over the uncertainty set",
                 fontsize=9)
    name = "validation_success.png"
    save(fig, fig_dir / name)
    return name


def _joint_figure(joint: dict, fig_dir: Path) -> str:
    """Write one panel per friction spread: beta x lag cells, each showing the success rate of every
    method where the point is consistent with T1-T4, hatched where the open-loop data exclude it."""
    from incipient_slip.experiments.plots import pyplot, save
    plt = pyplot()

    kb, kl, km = JOINT
    betas, lags, spreads = (joint["axes"][k] for k in (kb, kl, km))
    methods = list(CONTROLLED)
    by_key = {(p["overrides"][kb], p["overrides"][kl], p["overrides"][km]): p for p in joint["points"].values()}
    fig, axes = plt.subplots(1, len(spreads), figsize=(4.2 * len(spreads), 0.9 * len(betas) * len(methods) / 4 + 2),
                             sharey=True, squeeze=False, layout="constrained")
    im = None
    for ax, spread in zip(axes[0], spreads):
        grid = np.full((len(betas) * len(methods), len(lags)), np.nan)
        for i, b in enumerate(betas):
            for j, lag in enumerate(lags):
                p = by_key.get((b, lag, spread))
                if p and p.get("table"):
                    for m, method in enumerate(methods):
                        grid[i * len(methods) + m, j] = p["table"][method]["success"]
                else:
                    ax.add_patch(plt.Rectangle((j - 0.5, i * len(methods) - 0.5), 1, len(methods), fill=False,
                                               hatch="///", color="0.6", lw=0))
        im = ax.imshow(grid, vmin=0, vmax=1, cmap="viridis", aspect="auto")
        for r in range(grid.shape[0]):
            for c in range(grid.shape[1]):
                if np.isfinite(grid[r, c]):
                    ax.text(c, r, f"{grid[r, c]:.1f}", ha="center", va="center", color="w", fontsize=6)
        for i in range(1, len(betas)):
            ax.axhline(i * len(methods) - 0.5, color="k", lw=1.2)
        ax.set_xticks(range(len(lags)), [f"{v:g}" for v in lags], fontsize=8)
        ax.set_xlabel("friction-limit lag [s]", fontsize=8)
        ax.set_title(f"mu spread {spread:g}", fontsize=9)
    axes[0][0].set_yticks(range(len(betas) * len(methods)),
                          [f"beta {b:g}: {LABELS[m].split(' (')[0]}" for b in betas for m in methods], fontsize=6)
    fig.colorbar(im, ax=axes[0].tolist(), label="success rate", shrink=0.8)
    fig.suptitle("SIMULATED RIG: success rate over the joint uncertainty set "
                 "(hatched: excluded by the open-loop targets T1-T4', T7)", fontsize=9)
    name = "validation_joint.png"
    save(fig, fig_dir / name)
    return name


def trajectory_figure(params: dict, models: dict, material: str, seed: int, fig_dir: Path) -> str:
    """Write y, F_N and the estimate against s_d over one run per method (injection, E19, oracle);
    return the figure's file name."""
    from incipient_slip.experiments.plots import pyplot, save
    plt = pyplot()

    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    for method in ("injection", "e19", "oracle"):
        tr: list = []
        closed_loop(method, params, material, seed, models.get(method), control.MAX_STEPS, trace=tr)
        k = np.arange(1, len(tr) + 1)
        axes[0].plot(k, [r["est"] if method != "oracle" else r["true"] for r in tr], lw=0.8, label=LABELS[method])
        axes[1].plot(k, [r["fn"] for r in tr], lw=0.8)
        axes[2].plot(k, [r["y"] for r in tr], lw=0.8)
    axes[0].axhline(control.DEFAULT_TARGET_STICK_RATIO, color="k", ls="--", lw=0.7, label="s_d")
    axes[1].axhline(control.SAFETY_LIMIT_KPA, color="r", ls="--", lw=0.7)
    axes[2].axhline(control.FAILURE_TRAVEL_MM, color="r", ls="--", lw=0.7)
    for ax, name in zip(axes, ("estimate (oracle: true load ratio)", "F_N [kPa] (limit 6.0)", "y [mm] (limit 1.5)")):
        ax.set_ylabel(name, fontsize=8)
    axes[0].legend(fontsize=7)
    axes[2].set_xlabel("step (500 ms)")
    axes[0].set_title(f"SIMULATED RIG, fitted point: one controlled run ({material}, seed {seed}) per method", fontsize=9)
    name = "validation_trajectory.png"
    save(fig, fig_dir / name)
    return name


def _outcome(t: dict) -> str:
    """A method's cell: success rate (mean final y, mean final F_N); no action has no rate."""
    rate = "-" if t["success"] is None else f"{t['success']:.1f}"
    return f"{rate} ({t['y']:.2f} mm, {t['fn']:.1f} kPa)"


def _cell(v, fmt="{:.2f}") -> str:
    return "–" if v is None else fmt.format(v)


def render(results: dict) -> dict:
    """Return the Table at the fitted point beside the paper's, and success over the uncertainty set."""
    if results.get("rig"):
        return {"validation-rig": render_rig(results)}
    pts = results["points"]
    head = (f"Simulated rig, not measurements: {results['runs']} runs per method, {results['steps']} steps, models "
            f"trained on {results['series']} simulated series per data set (quick SVR), budget `{results['budget']}`.")
    blocks = {}
    if "fitted" in pts:
        t = pts["fitted"]["table"]
        lines = [head, "", "| | " + " | ".join(LABELS[m] for m in TABLE_METHODS) + " |",
                 "|---|" + "---|" * len(TABLE_METHODS)]
        for key, label, fmt, idx in (("success", "success rate", "{:.1f}", 0), ("y", "y [mm]", "{:.2f}", 1),
                                     ("fn", "F_N [kPa]", "{:.2f}", 2), ("steps", "steps", "{:.0f}", 3)):
            lines.append(f"| {label}, simulated | " + " | ".join(_cell(t[m][key], fmt) for m in TABLE_METHODS) + " |")
            lines.append(f"| {label}, paper | " + " | ".join(_cell(PAPER[m][idx], fmt) for m in TABLE_METHODS) + " |")
        lines.append("| score, simulated | " + " | ".join(f"{t[m]['score']:.2f}" for m in TABLE_METHODS) + " |")
        o = t["oracle"]
        lines += ["", f"Oracle (diagnostic, the law on the simulator's true load ratio): success {o['success']:.1f}, "
                  f"y {o['y']:.2f} mm, F_N {o['fn']:.2f} kPa."]
        if results.get("trajectory"):
            f = results["trajectory"]
            lines += ["", f"![simulated rig: one controlled run per method](figures/{f})",
                      f"*Simulated rig, not a measurement: `{f}` (the Table's first run at the fitted point, "
                      f"with the models trained at that point; the paper's trajectory shape is held out).*"]
        blocks["validation-fitted"] = "\n".join(lines)
    blocks["validation-answer"] = render_answer(results)
    methods = list(CONTROLLED)
    if results.get("joint"):
        blocks["validation-joint"] = _render_joint(results, head, methods)
    if not pts:
        return blocks
    lines = [head, "", "| point | consistent with T1-T4', T7 | k_b [N/mm] | k_s [N/mm] | "
             + " | ".join(LABELS[m] for m in methods) + " |", "|---|---|---|---|" + "---|" * len(methods)]
    for name, p in pts.items():
        v = p["fit"]["values"]
        lines.append(f"| {name} | {'yes' if p['consistent'] else 'no'} | {v['pre_slip.bulk_shear_n_per_mm']:.3f} | "
                     f"{v['stick_slip.spring_n_per_mm']:.4f} | " + " | ".join(
                         _outcome(p['table'][m])
                         for m in methods) + " |")
    lines += ["", "Cells: success rate (mean final y, mean final F_N).", "",
              f"![simulated rig: success over the uncertainty set](figures/{results['figure']})",
              f"*Simulated rig, not a measurement: `{results['figure']}`.*"]
    blocks["validation-set"] = "\n".join(lines)
    swept = {**pts, **(results.get("joint") or {}).get("points", {})}
    sw = {n: p["sweep_table"] for n, p in swept.items() if p.get("sweep_table")}
    if sw:
        n_sweep = max(len(r) for p in swept.values() for by_sd in p.get("sweep", {}).values() for r in by_sd.values())
        lines = [f"Simulated rig, not measurements: {n_sweep} runs per cell (seeds other than the Table's), "
                 f"{results['steps']} steps, the point's own models.", "", "| point | method | " + " | ".join(f"s_d {sd}" for sd in SWEEP_SD) + " |",
                 "|---|---|" + "---|" * len(SWEEP_SD)]
        for name, t in sw.items():
            for m, by_sd in t.items():
                lines.append(f"| {name} | {LABELS[m]} | " + " | ".join(
                    _outcome(by_sd[str(sd)])
                    for sd in SWEEP_SD) + " |")
        lines += ["", "Cells: success rate (mean final y, mean final F_N)."]
        blocks["validation-sweep"] = "\n".join(lines)
    return blocks


def render_rig(results: dict) -> str:
    """Return the Table predicted for an identified rig (`--params`), at its values and interval ends."""
    rig, methods = results["rig"], list(TABLE_METHODS) + ["oracle"]
    lines = [f"Prediction on the simulated rig fitted to an identified rig, not a measurement: rig "
             f"{rig.get('rig')}, material {rig.get('material')}, identified {rig.get('date')} "
             f"({rig.get('protocol')}); {results['runs']} runs per method, {results['steps']} steps, models trained "
             f"on {results['series']} simulated series per data set (quick SVR), budget `{results['budget']}`.", "",
             "| point | " + " | ".join(LABELS[m] for m in methods) + " |", "|---|" + "---|" * len(methods)]
    for name, p in results["points"].items():
        lines.append(f"| {name} | " + " | ".join(_outcome(p["table"][m]) for m in methods) + " |")
    lines += ["", "Cells: success rate (mean final y, mean final F_N). Rows: the overlay's values, then each "
              "identified parameter at one end of its interval with the others at their values."]
    return "\n".join(lines)


ANSWER_METHODS = ("oracle", "injection", "e10", "e19")


def _label_bias(fit: dict) -> str:
    return _bias((fit.get("summary") or {}).get("label_error_by_fn"))


def render_answer(results: dict) -> str:
    """Return the one answer at the top of docs/validation.md: can the paper's method hold the object
    at the fitted point, where in the uncertainty set the oracle, injection, E10 and E19 hold, and
    the pseudo label's bias by F_N there."""
    pts = dict(results.get("points", {}))
    pts.update({n: p for n, p in (results.get("joint") or {}).get("points", {}).items() if p.get("table")})
    joint_runs = (results.get("joint") or {}).get("runs")
    lines = ["Simulated rig (v3), not measurements; the paper's protocol (a run stops at the 6 kPa limit or after "
             f"{results['steps']} steps and is judged on its end state); {results['runs']} runs per method at the "
             "one-at-a-time points" + (f", {joint_runs} at the joint points (named with all three parameters)"
                                       if joint_runs else "") + "."]
    fitted = pts.get("fitted")
    if fitted and fitted.get("table"):
        t = fitted["table"]
        lines += ["", f"**At the fitted point:** injection {t['injection']['success']:.1f} "
                  f"(y {t['injection']['y']:.2f} mm, F_N {t['injection']['fn']:.2f} kPa), oracle {t['oracle']['success']:.1f} "
                  f"(y {t['oracle']['y']:.2f} mm, F_N {t['oracle']['fn']:.2f} kPa), E10 {t['e10']['success']:.1f}, "
                  f"E19 {t['e19']['success']:.1f}; paper: injection 1.0, E10 1.0, E19 0.8."]
        for key, table, _ in label_tables(fitted)[1:]:
            i = table["injection"]
            lines[-1] += (f" With the {key} label: injection {i['success']:.1f} (y {i['y']:.2f} mm, F_N {i['fn']:.2f} kPa), "
                          f"E10 {_success(table.get('e10'))}, E19 {_success(table.get('e19'))}.")
        for key, row in (fitted.get("labels") or {}).items():
            lines += ["", f"*Estimation at the fitted point, {key} label* (held-out series of the point's data set; "
                      "RMSE against the model's own label / against the true load ratio): " + ", ".join(
                          f"{LABELS[m]} {row['rmse'][m]:.3f} / {row['rmse_truth'][m]:.3f}" for m in row["rmse"]) + "."]
    ok = {n: p for n, p in pts.items() if p.get("table") and p.get("consistent")}
    if ok:
        lines += ["", f"Success rate at every point consistent with the open-loop targets ({len(ok)} points), a "
                  "row per training label where the point was run with it (docs/estimation.md: pseudo = the "
                  "paper's; measured-ratio = nothing identified; lag identified = the point's lag as if "
                  "`launch identify.yaml` measured it exactly), and the label minus the true load ratio by F_N "
                  "over the point's collection series (every period; the pseudo label before its onset where "
                  "the point predates the label rows). The oracle does not depend on the label:", "",
                  "| point | label | " + " | ".join(LABELS[m].split(" (")[0] for m in ANSWER_METHODS)
                  + " | label - truth by F_N |", "|---|---|" + "---|" * len(ANSWER_METHODS) + "---|"]
        for n, p in ok.items():
            for key, table, bias in label_tables(p):
                lines.append(f"| {n} | {key} | " + " | ".join(
                    _success((p['table'] if m == 'oracle' else table).get(m)) for m in ANSWER_METHODS)
                    + f" | {bias} |")
        keys = list(dict.fromkeys(key for p in ok.values() for key, _, _ in label_tables(p)))
        for m in ANSWER_METHODS:
            for key in (keys if m != "oracle" else ["pseudo"]):
                with_key = {n: t for n, p in ok.items() for k, t, _ in label_tables(p) if k == key and m in t}
                if not with_key:
                    continue
                held = [n for n, t in with_key.items() if t[m]["success"] >= 0.8]
                who = LABELS[m].split(" (")[0] + ("" if m == "oracle" else f" ({key})")
                lines += ["", f"* {who} holds (success >= 0.8) at {len(held)} of {len(with_key)} points"
                          + (": " + "; ".join(held) if held and len(held) < len(with_key) else "")]
        own = {n: dict((k, t) for k, t, _ in label_tables(p)) for n, p in ok.items()}
        own = {n: t.get("measured-ratio, lag identified") or t.get("measured-ratio") for n, t in own.items()}
        own = {n: t for n, t in own.items() if t and "injection" in t}
        if own:
            held = [n for n, t in own.items() if t["injection"]["success"] >= 0.8]
            missed = {n: t["injection"]["success"] for n, t in own.items() if n not in held}
            lines += ["", f"* injection (measured-ratio with the point's own friction lag: 0 where it has none, "
                      f"identified where it has one) holds at {len(held)} of {len(own)} points"
                      + ("; the others: " + "; ".join(f"{n} {v:.1f}" for n, v in missed.items()) if missed else "")]
    return "\n".join(lines)


def label_tables(p: dict) -> list:
    """Return [(label row, its Table, its label - truth by F_N)] of a point (pseudo only before the label rows)."""
    rows = p.get("labels") or {}
    out = [("pseudo", p["table"], _bias(rows.get("pseudo", {}).get("label_error_by_fn")) if rows
            else _label_bias(p.get("fit", {})))]
    return out + [(key, row["table"], _bias(row["label_error_by_fn"])) for key, row in rows.items()
                  if key != "pseudo" and row.get("table")]


def _success(row: dict | None) -> str:
    return f"{row['success']:.1f}" if row else "–"


def _bias(rows) -> str:
    # a mean that rounds to zero reads +0.00, never -0.00
    return ", ".join(f"{r['bin']} {r['mean'] if abs(r['mean']) >= 0.005 else 0.0:+.2f}" for r in rows or ()) or "–"


def task_times(pts: dict, cores: int = 16) -> str:
    """Return the joint set's per-task times (one single-threaded dask worker each) and what they
    add up to on 2 workers and on a `cores`-core cluster (where the longest task sets the time)."""
    refits = [p["fit"]["seconds"] for p in pts.values() if (p.get("fit") or {}).get("seconds")]
    tables = [p["seconds"] for p in pts.values() if p.get("table") and p.get("seconds")]
    if not refits and not tables:
        return "(no per-task times recorded)"
    span = lambda v: f"{min(v):.0f}–{max(v):.0f} s (sum {duration(sum(v))})" if v else "–"  # noqa: E731
    longest = max(refits or [0.0]) + max(tables or [0.0])
    return (f"Per-task times (simulated rig; one single-threaded dask worker per task, on the shared 2-core "
            f"machine): refits {span(refits)} for {len(refits)} of {len(pts)} points"
            + ("" if len(refits) == len(pts) else " (the others' refit time was not recorded by that run)")
            + f"; Tables {span(tables)} for {len(tables)} points. On 2 workers the recorded tasks take at least "
            f"{duration((sum(refits) + sum(tables)) / 2)}; on a {cores}-core cluster every point runs at once "
            f"and the longest refit plus the longest Table, {duration(longest)}, bounds the set "
            "(a refit is one Nelder-Mead fit, sequential; `--scheduler tcp://HOST:PORT` uses such a cluster).")


def _render_joint(results: dict, head: str, methods: list) -> str:
    """Return the joint set's block: which points the open-loop data allow, and the Table there."""
    joint = results["joint"]
    pts = joint["points"]
    ok = {n: p for n, p in pts.items() if p.get("table")}
    if "runs" in joint:
        fewer = " (fewer than the paper's 10, for time)" if joint["runs"] < 10 else ""
        head = (f"Simulated rig, not measurements: {joint['runs']} runs per method{fewer}, "
                f"{results['steps']} steps, models trained on {joint['series']} simulated series per data set (quick SVR).")
    lines = [head, "", f"{len(pts)} points, {len(ok)} consistent with T1-T4', T7 after their own refit.", "",
             "| point | T1 onset [mm] | T2 spread [mm] | T3 slips | T4' no-action y [mm] (slid) | T7 range [mm] | consistent |",
             "|---|---|---|---|---|---|---|"]
    for n, p in pts.items():
        f = p["fit"]["summary"]
        lines.append(f"| {n} | {f['T1']:.2f} | {f['T2']:.2f} | {f['T3']:.2f} | {f['T4']:.2f} ({f['T4_slid']:.2f}) | "
                     + "/".join(f"{v:.2f}" for v in f["T7"].values()) + f" | {'yes' if p['consistent'] else 'no'} |")
    lines += ["", "Closed loop at the consistent points (success rate, mean final y, mean final F_N):", "",
              "| point | k_b [N/mm] | k_s [N/mm] | " + " | ".join(LABELS[m] for m in methods) + " |",
              "|---|---|---|" + "---|" * len(methods)]
    for n, p in ok.items():
        v = p["fit"]["values"]
        lines.append(f"| {n} | {v['pre_slip.bulk_shear_n_per_mm']:.3f} | {v['stick_slip.spring_n_per_mm']:.4f} | "
                     + " | ".join(_outcome(p['table'][m]) for m in methods) + " |")
    lines += ["", task_times(pts)]
    if results.get("joint_figure"):
        f = results["joint_figure"]
        lines += ["", f"![simulated rig: success over the joint uncertainty set](figures/{f})",
                  f"*Simulated rig, not a measurement: `{f}`.*"]
    return "\n".join(lines)

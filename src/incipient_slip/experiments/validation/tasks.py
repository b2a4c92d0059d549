"""The validation's dask tasks: a point's stage-1 refit (`refit_task`) and its Table (`point_task`:
data sets, models per label row, the closed-loop runs, the s_d sweep), and one in-process
closed-loop run (`closed_loop`). Every task is seeded by its point."""
from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path

import numpy as np

from incipient_slip import control
from incipient_slip.sim.scene import with_values

from .. import closed_loop as loop
from .. import mechanics_fit
from .figures import trajectory_figure
from .spec import LABEL_METHODS, REFITS, SCENE_OF, SWEEP_METHODS, SWEEP_SD, TABLE_METHODS, slug


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


def refit_task(name: str, overrides: dict, seed: int, refits=None) -> dict:
    """Return the point's stage-1 refit to T1-T4' and T7 and whether it meets them (docs/calibration.md);
    from the content-hashed cache (`incipient_slip.cache`) when the same refit of the same physics
    and code was done before."""
    from incipient_slip import cache
    from incipient_slip.sim.dataset import physics_fingerprint
    from incipient_slip.sim.scene import load_scene

    scene = with_values(load_scene("paper"), {tuple(k.split(".")): v for k, v in overrides.items()})
    key = cache.digest("refit-1", name, physics_fingerprint(scene), seed, refits or REFITS,
                       cache.source_version(Path(mechanics_fit.__file__)))
    return cache.cached("refit", key, lambda: _refit(name, overrides, scene, seed, refits))


def _refit(name: str, overrides: dict, scene, seed: int, refits) -> dict:
    t0 = time.perf_counter()
    n = 0
    for n_fit, runs_fit, evals in refits or REFITS:   # a second, larger refit only when the first misses T1-T4
        fit = mechanics_fit.fit_mechanics(scene, n_fit, runs_fit, seed, evals, progress=False, stiffness_only=True)
        scene = with_values(scene, {tuple(k.split(".")): v for k, v in fit["values"].items()})
        summ = fit["summary"]
        n += 1
        if mechanics_fit.consistent_with_open_loop(summ):
            break
    return {"point": name, "overrides": overrides, "values": fit["values"], "summary": summ, "refits": n,
            "consistent": mechanics_fit.consistent_with_open_loop(summ), "seconds": time.perf_counter() - t0}


def point_task(name: str, overrides: dict, runs: int, n_series: int, steps: int, seed: int, work: str,
               sweep_runs: int = 0, refits=None, fit: dict | None = None, fig_dir: str | None = None,
               params: dict | None = None, materials: tuple | None = None) -> dict:
    """Return everything of one point: its stage-1 refit (`fit` when already done), model scores and
    the Table's runs. With `params` (an identified rig's) there is no refit: the rig's own values,
    and the Table runs on `materials` (the identified ones) only."""
    from incipient_slip.sim.rig import series_seed
    from incipient_slip.models.estimator_core import limit_blas_threads

    from ..datasets import ensure_dataset
    limit_blas_threads(1)
    t0 = time.perf_counter()
    fit, scene = _point_scene(name, overrides, seed, refits, fit, params)
    summ, consistent = fit["summary"], fit["consistent"]
    d = Path(work) / slug(name)
    # reused when the same physics made them before; no_injection's series come from paper's runs
    dirs = {"paper": ensure_dataset(_scene("paper", scene.params), n_series, seed + 1, d / "paper", workers=1,
                                    progress=False, views={d / "no_injection": _scene("no_injection", scene.params)}),
            "no_injection": d / "no_injection"}
    mats = tuple(materials) if materials else scene.materials
    # the other labels' rows where the answer reads them: the answer's methods, at the points the
    # open-loop data allow and the fitted one (10 minutes for `slip reproduce all`, issue 27)
    rows = label_rows(scene.params)
    if consistent is False and name != "fitted":
        rows = {"pseudo": rows["pseudo"]}
    by_label = label_studies(dirs, rows, scene.params, mats, runs, steps, seed)
    models = by_label["pseudo"].pop("models")
    table = by_label["pseudo"].pop("runs")
    for row in by_label.values():
        row.pop("models", None)
    sweep = sd_sweep(scene.params, models, mats, steps, seed, sweep_runs)
    trajectory = None
    if fig_dir and name == "fitted":
        first = series_seed(seed + 2, 0)
        trajectory = trajectory_figure(trajectory_traces(scene.params, models, mats[0], first), mats[0], first,
                                       Path(fig_dir))
    return {"point": name, "overrides": overrides, "fit": {"values": fit["values"], "summary": summ,
                                                           "refits": fit["refits"], "seconds": fit.get("seconds")},
            "trajectory": trajectory,
            "sweep": sweep,
            "consistent": consistent, "rmse": by_label["pseudo"]["rmse"], "top10": by_label["pseudo"]["top10"],
            "runs": table, "labels": by_label, "seconds": time.perf_counter() - t0}


def _point_scene(name: str, overrides: dict, seed: int, refits, fit: dict | None, params: dict | None):
    """Return (the point's stage-1 fit, its scene): an identified rig's own params without a refit,
    or the paper's scene at the point's overrides and refitted values."""
    from incipient_slip.sim.scene import load_scene

    if params is not None:
        return ({"values": {}, "summary": None, "refits": 0, "consistent": None},
                dataclasses.replace(load_scene("paper"), params=params))
    fit = fit or refit_task(name, overrides, seed, refits)
    return fit, with_values(load_scene("paper"), {tuple(k.split(".")): v
                                                  for k, v in {**overrides, **fit["values"]}.items()})


def label_studies(dirs: dict, rows: dict, params: dict, mats: tuple, runs: int, steps: int, seed: int) -> dict:
    """Return {label row: its study's scores, models and closed-loop runs}: the pseudo row trains
    every method and runs the Table and the oracle, each other row its own methods."""
    from incipient_slip.sim.rig import series_seed
    from incipient_slip.models.features import METHODS
    from incipient_slip.models.pipeline import load_all_windows, run_study
    from incipient_slip.models.training import relabel, series_targets

    by_label = {}
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
        row["runs"] = {method: [closed_loop(method, params, mats[j % len(mats)], series_seed(seed + 2, j),
                                            row["models"].get(method), steps) for j in range(runs)]
                       for method in (TABLE_METHODS + ("oracle",) if key == "pseudo" else methods)}
        by_label[key] = row
    return by_label


def sd_sweep(params: dict, models: dict, mats: tuple, steps: int, seed: int, sweep_runs: int) -> dict:
    """Return {method: {s_d: runs}} of the s_d sweep (empty without `sweep_runs`), on seeds other than the Table's."""
    from incipient_slip.sim.rig import series_seed

    sweep = {}
    for method in SWEEP_METHODS if sweep_runs else ():
        sweep[method] = {str(sd): [closed_loop(method, params, mats[j % len(mats)], series_seed(seed + 3, j),
                                               models.get(method), steps, sd) for j in range(sweep_runs)]
                         for sd in SWEEP_SD}
    return sweep


TRAJECTORY_METHODS = ("injection", "e19", "oracle")


def trajectory_traces(params: dict, models: dict, material: str, seed: int) -> dict[str, list]:
    """Return {method: per-period trace} of one full-length run per method of the trajectory figure."""
    traces = {}
    for method in TRAJECTORY_METHODS:
        traces[method] = []
        closed_loop(method, params, material, seed, models.get(method), control.MAX_STEPS, trace=traces[method])
    return traces


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
    return [mechanics_fit.label_report(p) for p in pairs]


def rmse_to_truth(result) -> float:
    """Return a method's held-out RMSE against the simulator's true load ratio (mean over series)."""
    from incipient_slip.models.evaluation import series_scores

    test = result.test
    truth = np.clip(np.nan_to_num(test.load_ratio_stick), 0.0, 1.0)
    return float(series_scores(result.method, truth, result.pred, test.series, test.material).rmse.mean())

"""The paper's stabilization Table on the simulated rig, with the gain k and target s_d sweeps.

Runs per method (no action, vibrotactile, E1, E4, E10, E19, injection) through
launch/stabilize.yaml (real processes, lock-step; `experiments.runner`); the Table beside the
paper's with Welch t-tests of the run scores against injection, trace figures, and on request
the gain k study (`--tune-k`), the s_d sweep (`--sweep`) and, as a labelled EXTENSION, the Table
of one method with another model file (`--model`). Parts not run this time keep their previous
results, so the page always shows the latest of each.

Modules: `table` (the statistics and the Table's text), `figures`, `report` (the page's blocks).
"""
from __future__ import annotations

import hashlib
import math
import os
import time
from pathlib import Path

import numpy as np

from incipient_slip import control
from incipient_slip.errors import UsageError
from incipient_slip.models.labels import SHIPPED_LABELS as LABELS
from incipient_slip.paths import repo_root

from ..runner import GraphRunner, RunSpec
from ..settings import Settings
from .figures import plot_sweep, plot_traces
from .report import render
from .table import TABLE_METHODS, aggregate, fmt, format_table_text, materials, table_rows

__all__ = ["NAME", "HELP", "DOC", "RESULTS", "QUICK", "add_arguments", "options", "render", "run"]

NAME = "stabilization"
HELP = "the stabilization Table, gain k study and s_d sweep through the node graph"
DOC = "stabilization.md"
RESULTS = "stab_results.json"       # in docs/figures/: the page's numbers, for --render-only
QUICK = ("2 runs per method (full 10), each the full 450 steps through the same node "
         "graph, so every run ends as a full run with its seed would; success rates are out of 2")
# the methods the other labels run by default (the paper's method: `slip reproduce all` stays within
# 10 minutes on 2 cores; --label-methods adds others, and docs/validation.md has every label's E10
# and E19 over the uncertainty set)
LABEL_METHODS = ("injection",)


def add_arguments(parser) -> None:
    """Add the Table's options: runs, methods, s_d, k, steps, the sweeps and the extension."""
    parser.add_argument("--runs", type=int, help="runs per method (quick 2, full 10)")
    parser.add_argument("--methods", nargs="+", choices=TABLE_METHODS, default=list(TABLE_METHODS),
                        help="methods to run (default all seven)")
    parser.add_argument("--s-d", dest="s_d", type=float, default=control.DEFAULT_TARGET_STICK_RATIO,
                        help=f"target stick ratio (default {control.DEFAULT_TARGET_STICK_RATIO})")
    parser.add_argument("--k", type=float, default=control.DEFAULT_GAIN_KPA,
                        help=f"grip gain, kPa per unit stick-ratio error (default {control.DEFAULT_GAIN_KPA})")
    parser.add_argument("--steps", type=int, help=f"steps of a run (default {control.MAX_STEPS}, the paper's, on both budgets)")
    parser.add_argument("--sweep", action="store_true", help="also sweep s_d over 0.1..0.8 per method")
    parser.add_argument("--sweep-runs", type=int, help="runs per sweep point (quick 1, full 3)")
    parser.add_argument("--tune-k", metavar="K1,K2,...", help="first run injection over these gains")
    parser.add_argument("--start", choices=("fork", "exec"), default="fork",
                        help="fork nodes from a pre-imported parent (default) or exec the launch command")
    parser.add_argument("--labels", nargs="+", choices=LABELS,
                        help="the training labels whose shipped models run the Table (default both: the "
                        "paper's pseudo label is the Table, measured-ratio rows beside it; docs/estimation.md)")
    parser.add_argument("--label-methods", nargs="+", choices=TABLE_METHODS[1:],
                        help="the methods the other labels run (default injection)")
    parser.add_argument("--model", type=Path, metavar="FILE",
                        help="EXTENSION: run only the one --methods method with FILE in its "
                        "estimator; kept apart from the Table (block stabilization-extension)")


def sweep_targets(settings: Settings) -> tuple[float, ...]:
    """Return the s_d values of the sweep."""
    return settings.pick(quick=(0.3, 0.7), full=(0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8))


def check(settings: Settings) -> None:
    """Checks the options before anything runs (`options`)."""
    options(settings)


def options(settings: Settings) -> dict:
    """Return the run options (runs, steps, methods, s_d, k, gains, ...) checked; UsageError if bad."""
    o = settings.options
    runs = settings.option("runs", settings.pick(quick=2, full=10))
    steps = settings.option("steps", control.MAX_STEPS)     # quick too: a shorter run would "succeed"
    s_d = float(settings.option("s_d", control.DEFAULT_TARGET_STICK_RATIO))
    k = float(settings.option("k", control.DEFAULT_GAIN_KPA))
    if runs < 1 or steps < 1:
        raise UsageError(f"--runs and --steps must be >= 1, got {runs} and {steps}")
    if not 0.0 <= s_d <= 1.0 or not (math.isfinite(k) and k > 0):
        raise UsageError(f"--s-d must be in [0, 1] and --k finite and > 0, got {s_d} and {k}")
    grid = None
    if o.get("tune_k"):
        try:
            grid = [float(x) for x in o["tune_k"].split(",")]
        except ValueError:
            raise UsageError(f"--tune-k takes gains separated by commas, got {o['tune_k']!r}") from None
        if not all(math.isfinite(g) and g > 0 for g in grid):
            raise UsageError(f"--tune-k gains must be finite and > 0, got {o['tune_k']!r}")
    methods = tuple(settings.option("methods", TABLE_METHODS))
    if o.get("model") is not None and (len(methods) != 1 or methods[0] == "none"):
        raise UsageError("--model needs exactly one --methods (not none)")
    return {"runs": runs, "steps": steps, "grid": grid, "methods": methods, "s_d": s_d, "k": k,
            "start": settings.option("start", "fork"),
            "sweep_runs": settings.option("sweep_runs", settings.pick(quick=1, full=3))}


def make_specs(methods, runs: int, s_d: float, k: float, steps: int, work: Path, tag: str,
               model: str = "", label: str = "pseudo") -> list[RunSpec]:
    """Return the runs; run i of every method uses seed i and material i mod n: same rigs."""
    mats = materials()
    specs = []
    for m in methods:
        for i in range(runs):
            spec = RunSpec(m, i, mats[i % len(mats)], s_d, k, steps, tag, model=model, label=label)
            spec.summary_path = work / f"{spec.name}.json"
            spec.log_path = work / f"{spec.name}.log"
            specs.append(spec)
    return specs


def _progress(total: int, t0: float, show: bool):
    done = [0]

    def report(i, s):
        done[0] += 1
        if show:
            print(f"  [{done[0]:>3}/{total}] {s['tag']:<6} {s['method']:<12} s_d {s['s_d']:<4g} "
                  f"seed {s['seed']} {s['material']:<5} {s['outcome']:<7} steps {s['steps']:>3} "
                  f"y {fmt(s['final_travel_mm'])} F_N {fmt(s['final_force_kpa'])} "
                  f"({s['launch_wall_s']:.1f} s, total {time.monotonic() - t0:.0f} s)", flush=True)
    return report


def of_label(summaries: list[dict], label: str) -> list[dict]:
    """The run summaries of one training label (a summary before the label was recorded: pseudo)."""
    return [s for s in summaries if (s.get("label") or "pseudo") == label]


def _compact(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k != "traces"}


def _previous(settings: Settings) -> dict:
    """Return the results of earlier runs (parts not run now keep them)."""
    import json
    path = settings.results_file(RESULTS)
    try:
        return json.loads(path.read_text()) if path.is_file() else {}
    except ValueError:
        return {}


def graphs_in_parallel(jobs: int) -> int:
    """Lock-step graphs are latency-bound (each period is five hops between processes, most of it
    waiting), so twice as many graphs as jobs keep the cores busy: the Table's 80 runs took 142-149 s
    with 4 graphs against 174-177 s with 2 on 2 cores, alternating (0.83x), with identical results
    (`slip reproduce stabilization --jobs 1` runs 2 graphs, `--jobs 2` 4)."""
    return 2 * jobs


def run(settings: Settings) -> dict:
    """Run the Table (and the k study, s_d sweep or extension when asked); return all results."""
    c = options(settings)
    results = _previous(settings)
    runner = GraphRunner(jobs=graphs_in_parallel(settings.jobs), start=c["start"])
    t0 = time.monotonic()
    if settings.options.get("model") is not None:
        results["extension"] = _run_extension(settings, c, runner)
        return results
    if c["grid"]:
        results["tune_k"] = _run_tune_k(settings, c, runner, t0)
        t0 = time.monotonic()

    labels = list(settings.option("labels", LABELS))
    other = [label for label in labels if label != "pseudo"]
    label_methods = [m for m in c["methods"] if m in settings.option("label_methods", LABEL_METHODS)]
    if not _run_table(settings, c, runner, t0, results, labels, other, label_methods):
        return results
    if settings.options.get("sweep"):
        results["sweep"] = _run_sweep(settings, c, runner, other, label_methods)
    if "sweep" in results:
        plot_sweep(results["sweep"], settings.figures / "stab_sweep.png")
    return results


def _run_tune_k(settings: Settings, c: dict, runner: GraphRunner, t0: float) -> dict:
    """The gain k study: injection's runs at every k of the grid."""
    specs = [s for k in c["grid"] for s in make_specs(("injection",), c["runs"], c["s_d"], k,
                                                       c["steps"], settings.work / "tune", f"k{k:g}")]
    summaries = runner.run(specs, _progress(len(specs), t0, settings.progress))
    rows = {}
    for k in c["grid"]:
        got = [s for s in summaries if s["k"] == k]
        rows[repr(k)] = {key: v for key, v in aggregate(got).items() if key != "run_scores"}
        rows[repr(k)]["holds_mean"] = float(np.mean([s.get("holds", 0) for s in got]))
    return {"s_d": c["s_d"], "runs": c["runs"], "rows": rows, "wall_s": round(time.monotonic() - t0, 1)}


def _run_table(settings: Settings, c: dict, runner: GraphRunner, t0: float, results: dict, labels: list,
               other: list, label_methods: list) -> bool:
    """The Table (pseudo label) and its rows with the other labels' models, into `results`;
    False when the pseudo label's Table was not asked for (then nothing more runs)."""
    work = settings.work
    specs = (make_specs(c["methods"], c["runs"], c["s_d"], c["k"], c["steps"], work / "table", "table")
             if "pseudo" in labels else [])
    specs += [s for label in other for s in make_specs(label_methods, c["runs"], c["s_d"],
                                                      c["k"], c["steps"], work / "table", "table", label=label)]
    done = runner.run(specs, _progress(len(specs), t0, settings.progress))
    table_wall = time.monotonic() - t0
    summaries = of_label(done, "pseudo")
    for label in other:
        got = of_label(done, label)
        rows = table_rows({m: [s for s in got if s["method"] == m] for m in label_methods})
        print(f"\nStabilization Table with the {label} models, SIMULATED rig:")
        print(format_table_text(rows))
        results.setdefault("labels", {})[label] = {"runs": c["runs"], "s_d": c["s_d"], "k": c["k"], "rows": rows,
                                                   "runs_detail": [_compact(s) for s in got]}
    if "pseudo" not in labels:
        return False
    by_method = {m: [s for s in summaries if s["method"] == m] for m in c["methods"]}
    rows = table_rows(by_method)
    print(f"\nStabilization Table, SIMULATED rig ({c['runs']} runs per method, s_d = {c['s_d']}, "
          f"k = {c['k']}, {runner.jobs} graphs in parallel, start={c['start']}): {table_wall:.1f} s")
    print(format_table_text(rows))
    results["table"] = {"runs": c["runs"], "s_d": c["s_d"], "k": c["k"], "steps": c["steps"],
                        "jobs": runner.jobs, "start": c["start"], "wall_s": round(table_wall, 1),
                        "cpus": os.cpu_count(), "rows": rows, "other_label_runs": len(done) - len(summaries),
                        "runs_detail": [_compact(s) for s in summaries]}
    plot_traces(by_method, settings.figures / "stab_traces.png")
    return True


def _run_sweep(settings: Settings, c: dict, runner: GraphRunner, other: list, label_methods: list) -> dict:
    """The s_d sweep: every controlled method (and the other labels' methods) at each target."""
    t1 = time.monotonic()
    sweep_methods = [m for m in c["methods"] if m != "none"]
    specs = [s for label in ["pseudo"] + other for sd in sweep_targets(settings)
             for s in make_specs(sweep_methods if label == "pseudo" else label_methods, c["sweep_runs"], sd,
                                 c["k"], c["steps"], settings.work / "sweep", "sweep", label=label)]
    done = runner.run(specs, _progress(len(specs), t1, settings.progress))

    def rows_of(label, methods):
        got = of_label(done, label)
        return {m: {repr(sd): {k: v for k, v in aggregate(
                    [s for s in got if s["method"] == m and s["s_d"] == sd]).items() if k != "run_scores"}
                    for sd in sweep_targets(settings)} for m in methods}
    return {"runs": c["sweep_runs"], "k": c["k"], "rows": rows_of("pseudo", sweep_methods),
            "labels": {label: rows_of(label, label_methods) for label in other},
            "wall_s": round(time.monotonic() - t1, 1)}


def _run_extension(settings: Settings, c: dict, runner: GraphRunner) -> dict:
    """The Table's runs of one method with another model file in its estimator (extension)."""
    from incipient_slip.models.estimator_core import load_model
    from incipient_slip.models.modelfile import ModelFileError
    method = c["methods"][0]
    model_path = Path(settings.options["model"]).resolve()
    try:
        model = load_model(model_path, method=method)        # refuses a spec of another method
    except (ModelFileError, ValueError, OSError) as exc:
        raise UsageError(f"--model {model_path}: {exc}") from exc
    t0 = time.monotonic()
    specs = make_specs((method,), c["runs"], c["s_d"], c["k"], c["steps"], settings.work / "extension",
                       "ext", str(model_path))
    summaries = runner.run(specs, _progress(len(specs), t0, settings.progress))
    rows = table_rows({method: summaries})
    print(f"\nEXTENSION (not the paper's method), SIMULATED rig, {method} with {model_path}")
    print(format_table_text(rows))
    try:
        model_rel = str(model_path.relative_to(repo_root()))
    except ValueError:
        model_rel = str(model_path)
    return {"method": method, "model": model_rel, "label": model.header.get("label", "pseudo"),
            "model_sha256": hashlib.sha256(model_path.read_bytes()).hexdigest(),
            "model_test_rmse": model.header.get("test_rmse_mean"),
            "runs": c["runs"], "s_d": c["s_d"], "k": c["k"], "steps": c["steps"],
            "wall_s": round(time.monotonic() - t0, 1), "row": rows[method],
            "runs_detail": [_compact(s) for s in summaries]}

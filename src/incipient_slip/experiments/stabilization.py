"""The paper's stabilization Table on the simulated rig, with the gain k and target s_d sweeps.

Runs per method (no action, vibrotactile, E1, E4, E10, E19, injection) through
launch/stabilize.yaml (real processes, lock-step; `experiments.runner`); the Table beside the
paper's with Welch t-tests of the run scores against injection, trace figures, and on request
the gain k study (`--tune-k`), the s_d sweep (`--sweep`) and, as a labelled EXTENSION, the Table
of one method with another model file (`--model`). Parts not run this time keep their previous
results, so the page always shows the latest of each.
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

from .plots import METHOD_LABELS, SIM_LABEL, pyplot, save
from .runner import GraphRunner, RunSpec
from .settings import Settings

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
# the paper's column order
TABLE_METHODS = ("none", "vibrotactile", "e1", "e4", "e10", "e19", "injection")
# the paper's Table (y and F_N at the last step; None where the paper gives none)
PAPER_TABLE = {
    "none": {"success": None, "y": 2.48, "fn": 2.94, "steps": 450},
    "vibrotactile": {"success": 0.3, "y": 1.32, "fn": 5.96, "steps": 397},
    "e1": {"success": 0.0, "y": 0.89, "fn": 6.47, "steps": 139},
    "e4": {"success": 0.1, "y": 2.52, "fn": 3.59, "steps": 450},
    "e10": {"success": 1.0, "y": 1.55, "fn": 5.23, "steps": 450},
    "e19": {"success": 0.8, "y": 1.40, "fn": 6.24, "steps": 435},
    "injection": {"success": 1.0, "y": 1.38, "fn": 4.50, "steps": 450},
}


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


# --- statistics ------------------------------------------------------------------------------

def run_score(summary: dict) -> float:
    """The paper's score of one run (success 0 or 1); nan when y or F_N is not positive."""
    y, fn = summary.get("final_travel_mm", math.nan), summary.get("final_force_kpa", math.nan)
    if not (isinstance(y, (int, float)) and isinstance(fn, (int, float)) and y > 0 and fn > 0):
        return math.nan
    return control.score(1.0 if summary.get("success") else 0.0, y, fn)


def aggregate(summaries: list[dict]) -> dict:
    """Success rate, mean/std of final y, F_N and steps, the Table score and per-run scores."""
    y = np.array([s["final_travel_mm"] for s in summaries], dtype=float)
    fn = np.array([s["final_force_kpa"] for s in summaries], dtype=float)
    steps = np.array([s["steps"] for s in summaries], dtype=float)
    success = np.array([bool(s.get("success")) for s in summaries])
    scores = np.array([run_score(s) for s in summaries])
    rate = float(success.mean()) if len(success) else math.nan
    y_mean, fn_mean = float(np.nanmean(y)), float(np.nanmean(fn))
    table_score = (control.score(rate, y_mean, fn_mean)
                   if y_mean > 0 and fn_mean > 0 else math.nan)
    errors = []
    for s in summaries:       # tracking: |estimate - s_d| after the first 10 steps
        est = np.array((s.get("traces") or {}).get("stick_ratio_estimate", [])[10:], dtype=float)
        if np.isfinite(est).any():
            errors.append(float(np.nanmean(np.abs(est - s.get("s_d", math.nan)))))
    return {"n": len(summaries), "success_rate": rate,
            "tracking_error": float(np.mean(errors)) if errors else math.nan,
            "y_mean": y_mean, "y_std": float(np.nanstd(y)), "fn_mean": fn_mean,
            "fn_std": float(np.nanstd(fn)), "steps_mean": float(np.mean(steps)),
            "score": table_score, "run_scores": scores.tolist(),
            "faults": int(sum(s.get("outcome") == "fault" for s in summaries)),
            "outcomes": {k: int(sum(s.get("outcome") == k for s in summaries))
                         for k in ("success", "failure", "fault")}}


def t_test_p(a, b) -> float:
    """Two-sided Welch t-test p-value of two samples of run scores (nan if undefined)."""
    from scipy import stats
    a, b = np.asarray(a, float), np.asarray(b, float)
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if len(a) < 2 or len(b) < 2:
        return math.nan
    if np.std(a) == 0 and np.std(b) == 0:
        return 1.0 if np.mean(a) == np.mean(b) else 0.0
    return float(stats.ttest_ind(a, b, equal_var=False).pvalue)


def stars(p: float) -> str:
    return "**" if p < 0.01 else ("*" if p < 0.05 else "")


def table_rows(results: dict[str, list[dict]]) -> dict[str, dict]:
    """Aggregate per method plus the p-value of its run scores against injection."""
    rows = {m: aggregate(results[m]) for m in TABLE_METHODS if results.get(m)}
    ref = rows.get("injection", {}).get("run_scores", [])
    for m, row in rows.items():
        row["p_vs_injection"] = math.nan if m == "injection" else t_test_p(row["run_scores"], ref)
    return rows


def fmt(v, spec=".2f", none="–") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return none
    return format(v, spec)


def format_table_markdown(rows: dict[str, dict]) -> str:
    """The Table, simulation beside the paper, as markdown."""
    methods = [m for m in TABLE_METHODS if m in rows]
    head = "| | " + " | ".join(METHOD_LABELS[m] for m in methods) + " |"
    sep = "|---|" + "---|" * len(methods)
    paper_score = {m: (control.score(PAPER_TABLE[m]["success"] or 0.0, PAPER_TABLE[m]["y"],
                                     PAPER_TABLE[m]["fn"])) for m in methods}

    def line(label, fn):
        return f"| {label} | " + " | ".join(fn(m) for m in methods) + " |"
    lines = [head, sep,
             line("success rate ↑ (sim)", lambda m: fmt(rows[m]["success_rate"])),
             line("success rate (paper)", lambda m: fmt(PAPER_TABLE[m]["success"])),
             line("y [mm] ↓ (sim)", lambda m: f"{fmt(rows[m]['y_mean'])} ± {fmt(rows[m]['y_std'])}"),
             line("y [mm] (paper)", lambda m: fmt(PAPER_TABLE[m]["y"])),
             line("F_N [kPa] ↓ (sim)", lambda m: f"{fmt(rows[m]['fn_mean'])} ± {fmt(rows[m]['fn_std'])}"),
             line("F_N [kPa] (paper)", lambda m: fmt(PAPER_TABLE[m]["fn"])),
             line("steps ↑ (sim)", lambda m: fmt(rows[m]["steps_mean"], ".0f")),
             line("steps (paper)", lambda m: fmt(PAPER_TABLE[m]["steps"], "d")),
             line("score ↑ (sim)", lambda m: fmt(rows[m]["score"]) + stars(rows[m]["p_vs_injection"])),
             line("score (paper's numbers)", lambda m: fmt(paper_score[m])),
             line("p vs injection (Welch, run scores)",
                  lambda m: "ref" if m == "injection" else fmt(rows[m]["p_vs_injection"], ".3g")),
             line("runs (success/failure/fault)",
                  lambda m: "/".join(str(rows[m]["outcomes"][k]) for k in ("success", "failure", "fault")))]
    return "\n".join(lines)


def format_table_text(rows: dict[str, dict]) -> str:
    """The Table for a terminal: one line per method."""
    out = [f"{'method':<17}{'succ':>6}{'(paper)':>8}{'y mm':>7}{'(paper)':>8}{'F_N kPa':>9}"
           f"{'(paper)':>8}{'steps':>7}{'(paper)':>8}{'score':>7}{'p':>9}"]
    for m in TABLE_METHODS:
        if m not in rows:
            continue
        r, p = rows[m], PAPER_TABLE[m]
        out.append(f"{METHOD_LABELS[m]:<17}{fmt(r['success_rate']):>6}{fmt(p['success']):>8}"
                   f"{fmt(r['y_mean']):>7}{fmt(p['y']):>8}{fmt(r['fn_mean']):>9}{fmt(p['fn']):>8}"
                   f"{fmt(r['steps_mean'], '.0f'):>7}{fmt(p['steps'], 'd'):>8}{fmt(r['score']):>7}"
                   f"{'ref' if m == 'injection' else fmt(r['p_vs_injection'], '.2g'):>9}")
    return "\n".join(out)


# --- figures ---------------------------------------------------------------------------------


def plot_traces(results: dict[str, list[dict]], path: Path) -> None:
    """y and F_N over steps, every run of every method (one column per method)."""
    plt = pyplot()
    methods = [m for m in TABLE_METHODS if results.get(m)]
    fig, axes = plt.subplots(3, len(methods), figsize=(2.4 * len(methods), 6.6), sharex=True,
                             squeeze=False)
    for j, m in enumerate(methods):
        for s in results[m]:
            tr = s.get("traces") or {}
            if not tr.get("step"):
                continue
            color = "tab:green" if s.get("success") else ("tab:red" if s.get("outcome") == "failure" else "tab:gray")
            axes[0, j].plot(tr["step"], tr["travel_mm"], color=color, lw=0.8, alpha=0.7)
            axes[1, j].plot(tr["step"], tr["force_kpa"], color=color, lw=0.8, alpha=0.7)
            axes[2, j].plot(tr["step"], tr["stick_ratio_estimate"], color=color, lw=0.6, alpha=0.6)
        axes[0, j].axhline(control.FAILURE_TRAVEL_MM, color="k", ls="--", lw=0.7)
        axes[1, j].axhline(control.SAFETY_LIMIT_KPA, color="k", ls="--", lw=0.7)
        axes[2, j].axhline(results[m][0].get("s_d", control.DEFAULT_TARGET_STICK_RATIO), color="k", ls="--", lw=0.7)
        if m != "none":
            axes[0, j].set_ylim(-0.1, 2.5)
        axes[1, j].set_ylim(0.8, 6.3)
        axes[2, j].set_ylim(-0.05, 1.05)
        axes[0, j].set_title(METHOD_LABELS[m], fontsize=9)
        axes[2, j].set_xlabel("step")
    axes[0, 0].set_ylabel("y [mm]")
    axes[1, 0].set_ylabel("F_N [kPa]")
    axes[2, 0].set_ylabel("estimated s")
    fig.suptitle(f"Stabilization traces ({SIM_LABEL}; green success, red failure, gray fault; "
                 f"dashed: failure limits, s_d)", fontsize=9)
    save(fig, path)


def sweep_lines(sweep: dict) -> list:
    """Return [(line name, method, {s_d: row})] of a sweep: the paper's label, then each other label."""
    out = [(METHOD_LABELS[m], m, sweep["rows"][m]) for m in TABLE_METHODS if m in sweep["rows"]]
    return out + [(f"{METHOD_LABELS[m]}, {label} label", m, by_sd) for label, rows in sweep.get("labels", {}).items()
                  for m, by_sd in rows.items()]


def plot_sweep(sweep: dict, path: Path) -> None:
    """Success rate, steps and final F_N against the target s_d, one line per method and label."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for name, m, by_sd in sweep_lines(sweep):
        xs = sorted(float(x) for x in by_sd)
        rows = [by_sd[repr(x)] if repr(x) in by_sd else by_sd[str(x)] for x in xs]
        style = dict(marker="o", lw=2.2 if m == "injection" else 1.0, label=name,
                     ls="--" if name != METHOD_LABELS[m] else "-")
        axes[0].plot(xs, [r["success_rate"] for r in rows], **style)
        axes[1].plot(xs, [r["steps_mean"] for r in rows], **style)
        axes[2].plot(xs, [r["fn_mean"] for r in rows], **style)
    for ax, label in zip(axes, ("success rate", "steps (mean)", "final F_N [kPa] (mean)")):
        ax.set_xlabel("target stick ratio s_d")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[2].axhline(control.SAFETY_LIMIT_KPA, color="k", ls="--", lw=0.7)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"s_d sweep ({SIM_LABEL})", fontsize=10)
    save(fig, path)


# --- the experiment --------------------------------------------------------------------------

def materials() -> tuple[str, ...]:
    """Return the materials runs cycle through: the paper scene's (one source: the sim params)."""
    from incipient_slip.sim.scene import load_scene
    return load_scene("paper").materials


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
    work = settings.work
    runner = GraphRunner(jobs=graphs_in_parallel(settings.jobs), start=c["start"])
    t0 = time.monotonic()
    if settings.options.get("model") is not None:
        results["extension"] = _run_extension(settings, c, runner)
        return results
    if c["grid"]:
        specs = [s for k in c["grid"] for s in make_specs(("injection",), c["runs"], c["s_d"], k,
                                                           c["steps"], work / "tune", f"k{k:g}")]
        summaries = runner.run(specs, _progress(len(specs), t0, settings.progress))
        rows = {}
        for k in c["grid"]:
            got = [s for s in summaries if s["k"] == k]
            rows[repr(k)] = {key: v for key, v in aggregate(got).items() if key != "run_scores"}
            rows[repr(k)]["holds_mean"] = float(np.mean([s.get("holds", 0) for s in got]))
        results["tune_k"] = {"s_d": c["s_d"], "runs": c["runs"], "rows": rows,
                             "wall_s": round(time.monotonic() - t0, 1)}
        t0 = time.monotonic()

    labels = list(settings.option("labels", LABELS))
    other = [label for label in labels if label != "pseudo"]
    specs = (make_specs(c["methods"], c["runs"], c["s_d"], c["k"], c["steps"], work / "table", "table")
             if "pseudo" in labels else [])
    label_methods = [m for m in c["methods"] if m in settings.option("label_methods", LABEL_METHODS)]
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
        return results
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

    if settings.options.get("sweep"):
        t1 = time.monotonic()
        sweep_methods = [m for m in c["methods"] if m != "none"]
        specs = [s for label in ["pseudo"] + other for sd in sweep_targets(settings)
                 for s in make_specs(sweep_methods if label == "pseudo" else label_methods, c["sweep_runs"], sd,
                                     c["k"], c["steps"], work / "sweep", "sweep", label=label)]
        done = runner.run(specs, _progress(len(specs), t1, settings.progress))

        def rows_of(label, methods):
            got = of_label(done, label)
            return {m: {repr(sd): {k: v for k, v in aggregate(
                        [s for s in got if s["method"] == m and s["s_d"] == sd]).items() if k != "run_scores"}
                        for sd in sweep_targets(settings)} for m in methods}
        results["sweep"] = {"runs": c["sweep_runs"], "k": c["k"], "rows": rows_of("pseudo", sweep_methods),
                            "labels": {label: rows_of(label, label_methods) for label in other},
                            "wall_s": round(time.monotonic() - t1, 1)}
    if "sweep" in results:
        plot_sweep(results["sweep"], settings.figures / "stab_sweep.png")
    return results


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


# --- the page's blocks -----------------------------------------------------------------------

def render(results: dict) -> dict[str, str]:
    """Return the generated blocks of docs/stabilization.md (every number: simulated rig)."""
    blocks = {}
    if "table" in results:
        blocks["stabilization-table"] = render_table(results["table"])
        blocks["stabilization-reading"] = render_reading(results["table"]["rows"])
        blocks["stabilization-cost"] = render_cost(results["table"])
    blocks["stabilization-k"] = render_k(results.get("tune_k"))
    blocks["stabilization-sweep"] = render_sweep(results.get("sweep"))
    blocks["stabilization-labels"] = render_labels(results.get("labels"), results.get("table", {}).get("rows", {}))
    blocks["stabilization-extension"] = render_extension(
        results.get("extension"), results.get("table", {}).get("rows", {}))
    return blocks


def render_table(t: dict) -> str:
    """Return the Table block: its set-up in one paragraph, then the Table."""
    return "\n".join([
        f"{t['runs']} runs per method, s_d = {t['s_d']}, k = {t['k']} kPa per unit stick ratio per "
        f"period, at most {t['steps']} steps (simulated rig). y and F_N are the values at each "
        "run's last step (mean ± sd over runs), as in the paper. Score = (0.1 + success)(10 / y + "
        "1 / F_N): the Table's row applies it to the method's success rate and mean y, F_N (as the "
        "paper does); the t-test (Welch, two-sided) compares per-run scores with injection's "
        "(* p < 0.05, ** p < 0.01).", "", format_table_markdown(t["rows"])])


def render_reading(rows: dict) -> str:
    """Return the bullets that read the Table (which method scores highest, how runs end)."""
    if not rows:
        return "(no runs)"
    inj = rows.get("injection", {})
    best = max(rows, key=lambda m: rows[m]["score"] if math.isfinite(rows[m]["score"]) else -1)
    out = [f"* Highest score in simulation: **{METHOD_LABELS[best]}** ({fmt(rows[best]['score'])}); "
           f"injection {fmt(inj.get('score'))}. "
           + ("In the paper injection scores highest too." if best == "injection"
              else "In the paper injection scores highest; on the simulated rig it does not.")]
    controlled = {m: r for m, r in rows.items() if m != "none"}
    if controlled and not any(r["success_rate"] > 0 for r in controlled.values()):
        out.append("* **No controlled run succeeds in simulation**, where the paper has injection and "
                   "E10 at 1.0.")
    for m, r in controlled.items():
        n = r["outcomes"]
        out.append(f"* {METHOD_LABELS[m]}: {n['success']} held, {n['failure']} failed, {n['fault']} "
                   f"faults; final y {fmt(r['y_mean'])} mm, F_N {fmt(r['fn_mean'])} kPa.")
    if "none" in rows:
        out.append(f"* No action ends at y {fmt(rows['none'].get('y_mean'))} mm (paper 2.48 mm).")
    return "\n".join(out)


def render_cost(t: dict) -> str:
    """Return the cost sentence: wall time of the Table and how it was run."""
    n = sum(r["n"] for r in t["rows"].values()) + t.get("other_label_runs", 0)
    what = f"{n} runs" + (", both labels" if t.get("other_label_runs") else "")
    return (f"The Table ({what}) took **{t['wall_s']} s** wall on {t.get('cpus')} cores with "
            f"{t['jobs']} graphs in parallel (start = {t['start']}; the machine was shared with "
            "other jobs).")


def render_k(tune: dict | None) -> str:
    """Return the gain study's table, or how to run it."""
    if not tune:
        return "(not run yet: `slip reproduce stabilization --tune-k 0.5,1,2,4,8`)"
    out = ["| k | success | steps | y [mm] | F_N [kPa] | score | mean abs(ŝ − s_d) |",
           "|---|---|---|---|---|---|---|"]
    for k, r in tune["rows"].items():
        out.append(f"| {float(k):g} | {fmt(r['success_rate'])} | {fmt(r['steps_mean'], '.0f')} | "
                   f"{fmt(r['y_mean'])} | {fmt(r['fn_mean'])} | {fmt(r['score'])} | "
                   f"{fmt(r.get('tracking_error'), '.3f')} |")
    out += ["", f"({tune['runs']} injection runs per k at s_d = {tune['s_d']}, simulated rig, "
            f"`--tune-k`, {tune['wall_s']} s.)"]
    return "\n".join(out)


def render_sweep(sweep: dict | None) -> str:
    """Return the s_d sweep's tables and reading, or how to run it."""
    if not sweep:
        return "(not run yet: `slip reproduce stabilization --sweep`)"
    rows_s = sweep["rows"]
    lines = sweep_lines(sweep)
    sds = sorted({float(x) for _, _, by_sd in lines for x in by_sd})
    out = []
    for metric, label, spec in (("success_rate", "success rate", ".2f"),
                                ("steps_mean", "steps (mean)", ".0f"),
                                ("fn_mean", "final F_N [kPa] (mean)", ".2f"),
                                ("tracking_error", "mean abs(ŝ − s_d)", ".3f")):
        out += [f"**{label}** ({sweep['runs']} runs per point, k = {sweep['k']}, simulated rig)", "",
                "| method | " + " | ".join(f"s_d {x:g}" for x in sds) + " |",
                "|---|" + "---|" * len(sds)]
        for name, _, by_sd in lines:
            cells = [fmt(by_sd.get(repr(x), {}).get(metric), spec) for x in sds]
            out.append(f"| {name} | " + " | ".join(cells) + " |")
        out.append("")
    inj_err = [rows_s.get("injection", {}).get(repr(x), {}).get("tracking_error", math.nan) for x in sds]
    n_success = sum(r.get("success_rate", 0) > 0 for m in rows_s for r in rows_s[m].values())
    out += ["Reading it (simulated rig):", ""]
    if n_success == 0:
        out.append("* With the paper's label no method succeeds at any s_d, so the paper's prediction "
                   "(electrodes failing above 0.7) cannot be tested with it on this simulated rig.")
    n_paper = len([m for m in TABLE_METHODS if m in rows_s])
    for i, (name, _, by_sd) in enumerate(lines):
        held = [x for x in sds if by_sd.get(repr(x), {}).get("success_rate", 0) >= 0.5]
        if i < n_paper and not held:       # the paper's label: only the rows that hold somewhere
            continue
        out.append(f"* {name}{' (the paper’s label)' if i < n_paper else ''}: holds in at least half the runs "
                   f"at s_d " + (", ".join(f"{x:g}" for x in held) or "none")
                   + " of " + ", ".join(f"{x:g}" for x in sds) + ".")
    if np.isfinite(inj_err).any():
        out.append(f"* Tracking error |ŝ − s_d| of injection over s_d: {fmt(np.nanmin(inj_err), '.3f')}"
                   f"–{fmt(np.nanmax(inj_err), '.3f')}.")
    return "\n".join(out)


def render_labels(labels: dict | None, main_rows: dict) -> str:
    """Return the Table per training label through the graph: the paper's pseudo label (the Table
    above) beside the others, method by method."""
    if not labels:
        return "(not run yet: `slip reproduce stabilization`)"
    out = ["| method | label | success rate | y (mm) | F_N (kPa) | steps | paper's success, y, F_N |",
           "|---|---|---|---|---|---|---|"]
    for m in TABLE_METHODS:
        p = PAPER_TABLE[m]
        if not any(m in v["rows"] for v in labels.values()):
            continue
        for label, rows in (("pseudo", main_rows), *((k, v["rows"]) for k, v in labels.items())):
            d = rows.get(m)
            if not d or m == "none":
                continue
            out.append(f"| {METHOD_LABELS[m]} | {label} | {fmt(d.get('success_rate'))} | {fmt(d.get('y_mean'))} ± "
                       f"{fmt(d.get('y_std'))} | {fmt(d.get('fn_mean'))} ± {fmt(d.get('fn_std'))} | "
                       f"{fmt(d.get('steps_mean'), '.0f')} | {fmt(p['success'])}, {fmt(p['y'])}, {fmt(p['fn'])} |")
    some = next(iter(labels.values()))
    return "\n".join([f"{some['runs']} runs per method and label through `launch stabilize.yaml label:=LABEL` "
                      f"(the shipped models of that label; the Table's seeds and materials, s_d = {some['s_d']}, "
                      f"k = {some['k']}); simulated rig, not measurements.", "", *out])


def render_extension(r: dict | None, main_rows: dict) -> str:
    """Return the extension's table (beside the Table's row of the same method) and reading."""
    if not r:
        return ("(not run yet: `slip reproduce stabilization --methods injection "
                "--model runs/extension/injection_true_ratio.npz`)")
    row, main = r["row"], main_rows.get(r["method"], {})

    def line(name, d):
        return (f"| {name} | {fmt(d.get('success_rate'))} | {fmt(d.get('y_mean'))} ± "
                f"{fmt(d.get('y_std'))} | {fmt(d.get('fn_mean'))} ± {fmt(d.get('fn_std'))} | "
                f"{fmt(d.get('steps_mean'), '.0f')} | {fmt(d.get('tracking_error'), '.3f')} |")
    table = ["| injection model (simulated rig) | success rate | y (mm) | F_N (kPa) | steps | "
             "mean abs(ŝ − s_d) |", "|---|---|---|---|---|---|"]
    if main:
        table.append(line("pseudo label (shipped, the Table above)", main))
    table.append(line(f"true ratio (extension, `{r['model']}`)", row))
    det = r.get("runs_detail", [])
    lim = [d for d in det if not d.get("success")
           and d.get("final_force_kpa", 0) >= control.SAFETY_LIMIT_KPA - 1e-6]
    low = [d for d in det if not d.get("success") and d not in lim]
    low_txt = ", ".join(f"{d['material']} at F_N {d['final_force_kpa']:.2f} kPa" for d in low)
    lim_txt = (f"{len(lim)} failed by reaching the F_N limit (after {', '.join(str(d['steps']) for d in lim)} steps)"
               if lim else "none reached the F_N limit")
    reading = (f"Reading it (simulated rig, extension): {sum(bool(d.get('success')) for d in det)} of "
               f"{len(det)} runs held all {r['steps']} steps (pseudo-label model: success rate "
               f"{fmt(main.get('success_rate'))}); {lim_txt} and {len(low)} failed on y > 1.5 mm"
               + (f" ({low_txt}). " if low else ". ")
               + ("So changing only the training target moves the loop towards holding, consistent "
                  "with the diagnosis that the pseudo label is a main cause here; "
                  if row.get("success_rate", 0) > main.get("success_rate", 0) else
                  "So changing only the training target does not make the loop hold; ")
               + "the true-ratio model's held-out RMSE to the true ratio is "
               f"{fmt(r.get('model_test_rmse'), '.3f')}.")
    return "\n".join([
        f"{r['runs']} runs through `launch stabilize.yaml method:={r['method']} model:=...` "
        f"(same seeds and materials as the Table, s_d = {r['s_d']}, k = {r['k']}, at most "
        f"{r['steps']} steps; model sha256 {r['model_sha256'][:8]}…, header label "
        f"`{r['label']}`). Regenerate: `slip reproduce stabilization --methods {r['method']} "
        f"--model {r['model']}`.", "", *table, "", reading])

"""`slip run plot SUMMARY [-o PNG]`: the figure of one stabilization run from its JSON summary.

The supervisor writes the summary of `launch stabilize.yaml` (also when the run is interrupted)
with one trace entry per judged period; this draws, over the periods, the estimated stick ratio
against the target s_d (and, on the simulated rig, the simulator's true ratio, dashed), the
normal force F_N with the 6.0 kPa safety limit and the object travel y with the 1.5 mm failure
limit. `make demo` runs it after the launch; plotting never touches the run or its verdict.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from incipient_slip import control
from incipient_slip.errors import UsageError

from .plots import METHOD_LABELS, SIM_LABEL, pyplot, save

# where the data came from -> what the figure says about it
SOURCE_NOTES = {"sim": f"{SIM_LABEL}, not a measurement",
                "emulated": f"emulated devices on the {SIM_LABEL}, not a measurement",
                "replay": "replay of a recording (open loop: the grip commands were not applied)",
                "hardware": "real rig"}
NUMERIC_TRACES = ("period", "step", "travel_mm", "force_kpa", "command_kpa", "stick_ratio_estimate",
                  *control.TRUTH_TRACES)


def load_summary(path: Path) -> dict:
    """Return the run summary at `path`, its traces as lists of floats (NaN for unknown) of one
    length; a missing, unreadable or malformed file is a UsageError naming it."""
    path = Path(path)
    summary = _read_summary(path)
    traces, lengths = _checked_traces(path, summary["traces"])
    if len(lengths) > 1:
        raise UsageError(f"{path}: traces of different lengths {sorted(lengths)} (a damaged summary)")
    n = lengths.pop() if lengths else 0
    if "period" not in traces:          # summaries before the period trace: periods from 0
        traces["period"] = [float(i) for i in range(n)]
    for key in NUMERIC_TRACES:
        traces.setdefault(key, [math.nan] * n)
    traces.setdefault("hold", [False] * n)
    return {**summary, "traces": traces}


def _read_summary(path: Path) -> dict:
    try:
        summary = json.loads(path.read_text())
    except FileNotFoundError:
        raise UsageError(f"{path}: no such file (the supervisor writes runs/stabilize_summary.json)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: cannot read it ({exc})") from None
    except ValueError as exc:
        raise UsageError(f"{path}: not a run summary (invalid JSON: {exc})") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("outcome"), str) \
            or not isinstance(summary.get("traces"), dict):
        raise UsageError(f"{path}: not a run summary (needs 'outcome' and 'traces')")
    return summary


def _checked_traces(path: Path, raw: dict) -> tuple[dict, set]:
    """Return the traces the summary has (numbers as floats, NaN for unknown; hold as bools) and their lengths."""
    traces, lengths = {}, set()
    for key in NUMERIC_TRACES:
        values = raw.get(key)
        if values is None:
            continue
        if not isinstance(values, list) or not all(
                v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in values):
            raise UsageError(f"{path}: trace {key!r} is not a list of numbers")
        traces[key] = [math.nan if v is None else float(v) for v in values]
        lengths.add(len(values))
    hold = raw.get("hold")
    if hold is not None:
        if not isinstance(hold, list) or not all(isinstance(v, (bool, int)) or v is None for v in hold):
            raise UsageError(f"{path}: trace 'hold' is not a list of true/false")
        traces["hold"] = [bool(v) for v in hold]
        lengths.add(len(hold))
    return traces, lengths


def outcome_line(summary: dict) -> str:
    """Return e.g. 'FAILURE: y = 1.612 mm > 1.5 mm (the paper's travel limit); 37 / 450 steps'."""
    detail = summary.get("detail") or ""
    steps = f"{summary.get('steps', len(summary['traces']['period']))} / {summary.get('max_steps', control.MAX_STEPS)} steps"
    return f"{summary['outcome'].upper()}" + (f": {detail}" if detail else "") + f"; {steps}"


PLOTTABLE = 1e6        # larger trace values are not drawn (no rig produces them)


def plot_run(summary: dict, path: Path) -> Path:
    """Write the three-panel figure of one run summary (as `load_summary` returns it) to `path`."""
    plt = pyplot()
    from matplotlib.ticker import MaxNLocator
    tr, n_dropped = _drawable(summary["traces"])
    x = tr["period"]
    s_d = summary.get("s_d")
    s_d = float(s_d) if isinstance(s_d, (int, float)) and math.isfinite(s_d) else None
    fig, (ax_s, ax_f, ax_y) = plt.subplots(3, 1, figsize=(10.0, 7.6), sharex=True)
    marker = dict(marker="o", ms=2.5) if len(x) <= 60 else {}
    _stick_panel(ax_s, x, tr, s_d, marker)
    _force_panel(ax_f, x, tr, marker)
    _travel_panel(ax_y, x, tr, marker)
    if not x:
        ax_s.text(0.5, 0.5, "no period was judged", transform=ax_s.transAxes, ha="center", va="center")
    if n_dropped:
        ax_y.text(0.01, 0.95, f"{n_dropped} value(s) beyond ±{PLOTTABLE:g} not drawn", transform=ax_y.transAxes,
                  ha="left", va="top", fontsize=8, color="tab:red")
    for ax in (ax_s, ax_f, ax_y):
        ax.grid(alpha=0.3)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7.5, frameon=False)
    fig.suptitle(_title(summary, s_d), fontsize=9.5)
    return save(fig, path)


def _drawable(traces: dict) -> tuple[dict, int]:
    """Return the traces with values no rig produces left out, and how many were: a hand-edited
    1e308 cannot be drawn (matplotlib's transforms overflow); the figure says how many."""
    tr = {k: (v if k == "hold" else [x if math.isfinite(x) and abs(x) < PLOTTABLE else math.nan for x in v])
          for k, v in traces.items()}
    n_dropped = sum(1 for k, v in traces.items() if k != "hold"
                    for x in v if math.isfinite(x) and abs(x) >= PLOTTABLE)
    return tr, n_dropped


def _stick_panel(ax_s, x, tr: dict, s_d: float | None, marker: dict) -> None:
    ax_s.plot(x, tr["stick_ratio_estimate"], color="tab:blue", lw=1.2, label="estimated ŝ", **marker)
    if any(math.isfinite(v) for v in tr["stick_ratio_true"]):
        ax_s.plot(x, tr["stick_ratio_true"], color="0.35", ls="--", lw=1.0,
                  label="true ratio 1 − Q/(μ_s F_N) (simulator's truth)")
    if s_d is not None:
        ax_s.axhline(s_d, color="tab:green", lw=1.0, label=f"target s_d = {s_d:g}")
    holds = [xi for xi, h in zip(x, tr["hold"]) if h]
    if holds:
        ax_s.plot(holds, [0.0] * len(holds), "|", color="tab:orange", ms=8, label="hold (no usable ŝ)")
    ax_s.set_ylim(-0.05, 1.05)
    ax_s.set_ylabel("stick ratio")


def _force_panel(ax_f, x, tr: dict, marker: dict) -> None:
    ax_f.plot(x, tr["force_kpa"], color="tab:purple", lw=1.2, label="F_N applied", **marker)
    ax_f.step(x, tr["command_kpa"], where="post", color="tab:purple", lw=0.8, ls=":", label="F_N command")
    ax_f.axhline(control.SAFETY_LIMIT_KPA, color="tab:red", ls="--", lw=1.0,
                 label=f"safety limit {control.SAFETY_LIMIT_KPA:g} kPa")
    ax_f.set_ylim(0.0, control.SAFETY_LIMIT_KPA + 0.6)
    ax_f.set_ylabel("F_N [kPa]")


def _travel_panel(ax_y, x, tr: dict, marker: dict) -> None:
    ax_y.plot(x, tr["travel_mm"], color="tab:brown", lw=1.2, label="object travel y", **marker)
    ax_y.axhline(control.FAILURE_TRAVEL_MM, color="tab:red", ls="--", lw=1.0,
                 label=f"failure limit {control.FAILURE_TRAVEL_MM:g} mm")
    # the axis spans the plausible travels (a hand-edited 1e308 would make the limits infinite)
    finite_y = [v for v in tr["travel_mm"] if math.isfinite(v)]
    ax_y.set_ylim(min([0.0, *finite_y]) - 0.05, max([control.FAILURE_TRAVEL_MM * 1.25, *finite_y]) * 1.05)
    ax_y.set_ylabel("y [mm]")
    ax_y.set_xlabel("period (500 ms each)")


def _title(summary: dict, s_d: float | None) -> str:
    rig = summary.get("rig") or "sim"
    method = summary.get("method") or "?"
    seed = summary.get("seed", "?")
    material = summary.get("material") or "scene default"
    label = f"{summary['label']} label" if summary.get("label") and method != "none" else ""
    model = ", ".join(x for x in (f"model {summary['model']}" if summary.get("model") else "", label) if x)
    model = f", {model}" if model else ""
    return (f"Stabilization run, {SOURCE_NOTES.get(rig, f'rig {rig}')}\n"
            f"method {METHOD_LABELS.get(method, method)}{model}, s_d {s_d if s_d is not None else '?'}, "
            f"k {summary.get('k', '?')}, material {material}, seed {seed}\n{outcome_line(summary)}")


def cmd_plot(args) -> int:
    summary = load_summary(args.summary)
    out = args.output or Path(args.summary).with_suffix(".png")
    try:
        path = plot_run(summary, out)
    except OSError as exc:
        raise UsageError(f"{out}: cannot write the figure ({exc})") from None
    print(f"wrote {path} ({SOURCE_NOTES.get(summary.get('rig') or 'sim', 'rig ' + str(summary.get('rig')))})")
    return 0


def register(subparsers) -> None:
    """Add `slip run plot`."""
    run = subparsers.add_parser("run", help="a stabilization run's summary (launch stabilize.yaml)")
    sub = run.add_subparsers(dest="tool", metavar="TOOL", required=True)
    p = sub.add_parser("plot", help="figure of a run summary: stick ratio vs s_d, F_N, y over the periods",
                       description=__doc__.split("\n\n")[1].replace("\n", " "))
    p.add_argument("summary", type=Path, metavar="SUMMARY", help="run summary JSON (e.g. runs/stabilize_summary.json)")
    p.add_argument("-o", "--output", type=Path, metavar="PNG", help="figure path (default: SUMMARY with .png)")
    p.set_defaults(func=cmd_plot)

"""The stabilization page's figures: the runs' traces per method and the s_d sweep."""
from __future__ import annotations

from pathlib import Path

from incipient_slip import control

from ..plots import METHOD_LABELS, SIM_LABEL, pyplot, save
from .table import TABLE_METHODS


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

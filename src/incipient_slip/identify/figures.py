"""Rig identification, the pictures: y against the spring load per F_N level with the fitted
lines and the slide onsets, and the lag trials' F_N and y around each step (matplotlib, Agg),
each labelled with the rig it came from. The identifier node writes them with its results;
`slip reproduce identification` draws them for one simulated identification."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .fit import slope_points
from .protocol import PERIOD_S


def figures(results: dict, records: list, out_dir: Path, stem: str = "identify") -> dict:
    """Draw y against the spring load per F_N level with the fitted lines, and the lag trials'
    slide onsets against the F_N step; return {protocol: path}."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rig, mat = results["inputs"]["rig"], results["inputs"]["material"]
    # rig:=emulated is the real device nodes around the same simulated contact: its numbers are simulated too
    label = f"rig: {rig}; material {mat}" + (" (SIMULATED RIG)" if str(rig).startswith("sim") else
                                             " (EMULATED DEVICES ON THE SIMULATED RIG)" if rig == "emulated" else "")
    paths = {"stiffness": _stiffness(plt, results, out_dir / f"{stem}_stiffness.png", label)}
    lag_recs = [r for r in records if r.phase in ("lag-hold", "lag-low", "lag-release")]
    if lag_recs:
        paths["lag"] = _lag(plt, results, lag_recs, out_dir / f"{stem}_lag.png", label)
    return paths


def _stiffness(plt, results: dict, path: Path, label: str) -> str:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for row in results["levels"]:
        if not row["q_n"]:
            continue
        q, y = np.array(row["q_n"]), np.array(row["y_mm"])
        style = ":" if row["phase"] == "run-in" else "-"
        line, = ax.plot(q, y - y[0], style, lw=1.2,
                        label=f"{row['fn_kpa']:.1f} kPa{' run-in' if row['phase'] == 'run-in' else ''}: "
                              f"k_b {row['k_b']:.3f} N/mm, mu {row['mu']:.3f}")
        if math.isfinite(row["k_b"]):
            m = slope_points(q)
            qq = np.array([q[m].min(), q[m].max()])
            c = float(np.mean(y[m] - y[0] - q[m] / row["k_b"]))
            ax.plot(qq, c + qq / row["k_b"], "k--", lw=0.6)
        if row["slid"]:
            ax.plot(q[-1], y[-1] - y[0], "x", color=line.get_color())
    st = results["stiffness"]
    if "beta" in st:
        ax.set_title(f"pre-slip: k_b = {st['k_ref']:.3f} N/mm (F/1 N)^{st['beta']:.2f}; x = slide onset", fontsize=9)
    ax.set_xlabel("spring load Q = k_s (u - y) [N]")
    ax.set_ylabel("object travel from zero load [mm]")
    ax.legend(fontsize=7)
    return _save(plt, fig, path, label)


def _lag(plt, results: dict, lag_recs: list, path: Path, label: str) -> str:
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 4.5), sharex=True)
    trials = sorted({r.trial for r in lag_recs})
    for t in trials:
        rs = [r for r in lag_recs if r.trial == t]
        k0 = next((r.period for r in rs if r.phase == "lag-low"), rs[0].period)
        x = [(r.period - k0) * PERIOD_S for r in rs]
        row = next((lt for lt in results["lag_trials"] if lt["trial"] == t), {})
        a1.step(x, [r.fn_kpa for r in rs], where="post", lw=1)
        a2.plot(x, [r.y_mm - rs[0].y_mm for r in rs], "-o", ms=2, lw=1, label=f"r = {row.get('r', math.nan):.2f}")
    a1.set_ylabel("F_N [kPa]")
    a2.set_ylabel("y - y(step) [mm]")
    a2.set_xlabel("time after the F_N step down [s]")
    lag = results["lag"]
    if lag:
        a1.set_title(f"friction-limit response: tau = {lag['tau_s']:.2f} s "
                     f"[{lag['tau_interval'][0]:.2f}, {lag['tau_interval'][1]:.2f}]", fontsize=9)
    a2.legend(fontsize=7)
    return _save(plt, fig, path, label)


def _save(plt, fig, path: Path, label: str) -> str:
    """Label a picture with the rig it came from, write it and close it."""
    fig.text(0.01, -0.03, label, fontsize=7)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return str(path)

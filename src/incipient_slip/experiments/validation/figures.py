"""The validation's figures: success over the uncertainty set, over the joint grid, and one run's
trajectory per method. Matplotlib is imported inside (`experiments.plots`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from incipient_slip import control

from . import spec
from .spec import CONTROLLED, LABELS


def success_figure(points: dict, fig_dir: Path) -> str:
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


def joint_figure(joint: dict, fig_dir: Path) -> str:
    """Write one panel per friction spread: beta x lag cells, each showing the success rate of every
    method where the point is consistent with T1-T4, hatched where the open-loop data exclude it."""
    from incipient_slip.experiments.plots import pyplot, save
    plt = pyplot()

    kb, kl, km = spec.JOINT
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


def trajectory_figure(traces: dict[str, list], material: str, seed: int, fig_dir: Path) -> str:
    """Write y, F_N and the estimate against s_d over one run per method (injection, E19, oracle:
    `tasks.trajectory_traces`); return the figure's file name."""
    from incipient_slip.experiments.plots import pyplot, save
    plt = pyplot()

    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    for method, tr in traces.items():
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

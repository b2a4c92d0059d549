"""Calibration report: the paper's measured quantities side by side with the simulated rig's.

Targets (RIG.md section 1): travel at gross-slip onset 1.5 +/- 0.4 mm; Pearson R of the 200 Hz
band amplitude vs F_T at fixed F_N, 0.97; final y ~2.5 mm with no control; gross slip within the
23 mm travel at every F_N and material; the distribution of labels s.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .protocols import COLLECTION_FORCES_KPA, run_collection, run_constant
from .rig import Rig, series_seed
from .scene import Scene, validate_effects

MECHANICS = ("contact", "stick_slip", "mocap")
VIBRATION = ("contact", "stick_slip", "fingertip_modes", "injection", "vibrotactile", "ambient_noise", "adc")


def subset(scene: Scene, effects) -> Scene:
    """Return the scene restricted to `effects` (those it has)."""
    keep = validate_effects([e for e in effects if scene.has(e)], scene.source or scene.name)
    return dataclasses.replace(scene, effects=keep)


def band_amplitude(pac_counts_window: np.ndarray, fs_hz: float, lo_hz: float = 150.0, hi_hz: float = 250.0) -> float:
    """Return the mean FFT magnitude (counts) of a Hann-windowed window within [lo, hi] Hz."""
    x = pac_counts_window.astype(np.float64)
    spec = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(len(x))))
    f = np.fft.rfftfreq(len(x), 1.0 / fs_hz)
    return float(spec[(f >= lo_hz) & (f <= hi_hz)].mean())


def collection_stats(scene: Scene, n_per_material: int, seed: int, steps: int = 450) -> dict:
    """Return onset travel, label distribution and per-series records from collection runs."""
    from incipient_slip.models.labels import gross_slip_travel_mm, pseudo_stick_ratio

    mech = subset(scene, MECHANICS)
    rows, labels = [], []
    for mi, mat in enumerate(scene.materials):
        for j in range(n_per_material):
            rig = Rig(mech, mat, series_seed(seed, mi * 1000 + j))
            outs = list(run_collection(rig, steps))
            t = np.concatenate([o.mocap_t_s for o in outs])
            y = np.concatenate([o.mocap_y_mm for o in outs])
            end = np.array([o.t_start_s + rig.period_s for o in outs])
            ft = np.array([o.tangential_force_n for o in outs])
            ytrue = np.array([o.object_y_mm for o in outs])
            gross = np.array([o.gross_slip for o in outs])
            lab = pseudo_stick_ratio(ft, gross_slip_travel_mm(t, y, end))
            k = lab.gross_slip_index
            k_true = int(np.argmax(gross)) if gross.any() else -1
            rows.append({"material": mat, "k_rule": k, "k_true": k_true,
                         "y_before_rule": float(ytrue[k - 1]) if k > 0 else np.nan,
                         "y_at_rule": float(ytrue[k]) if k >= 0 else np.nan,
                         "y_before_true": float(ytrue[k_true - 1]) if k_true > 0 else np.nan,
                         "sar": np.array([o.stick_area_ratio for o in outs]),
                         "lrs": np.array([o.load_ratio_stick for o in outs]),
                         "pseudo": lab.pseudo_stick_ratio, "y": ytrue, "ft": ft,
                         "fn": np.array([o.normal_force_kpa for o in outs])})
            if k >= 0:
                labels.append(lab.pseudo_stick_ratio[:k])
    return {"rows": rows, "labels": np.concatenate(labels) if labels else np.zeros(0)}


def band_correlation(scene: Scene, forces_kpa=(2.3, 3.5, 4.7), seed: int = 1, steps: int = 450) -> dict:
    """Return Pearson R of the 200 Hz band amplitude vs F_T during stick, per (material, F_N)."""
    vib = subset(scene, VIBRATION)
    if not vib.has("injection"):
        raise ValueError(f"scene {scene.name!r} has no 'injection' effect; the 200 Hz band check needs it")
    out = {}
    fs = vib.params["timing"]["pac_rate_hz"]
    for mi, mat in enumerate(vib.materials):
        for fi, fn in enumerate(forces_kpa):
            rig = Rig(vib, mat, series_seed(seed, 100 * mi + fi))
            prev, amps, fts = None, [], []
            for o in run_constant(rig, fn, steps):
                if o.gross_slip:
                    break
                if prev is not None:
                    amps.append(band_amplitude(np.concatenate([prev.pac_counts, o.pac_counts]), fs))
                    fts.append(o.tangential_force_n)
                prev = o
            amps, fts = np.array(amps), np.array(fts)
            r = float(np.corrcoef(fts, amps)[0, 1]) if len(amps) > 3 else np.nan
            out[(mat, fn)] = {"r": r, "ft": fts, "amp": amps}
    return out


def no_control(scene: Scene, fn_kpa: float = 2.94, seeds: int = 10, seed: int = 2, steps: int = 450) -> dict:
    """Return y at the step where y first exceeds 1.5 mm (the paper's failure rule) at constant F_N."""
    mech = subset(scene, MECHANICS)
    res = {}
    for mi, mat in enumerate(scene.materials):
        ys, ks, yslide = [], [], []
        for j in range(seeds):
            rig = Rig(mech, mat, series_seed(seed, 100 * mi + j))
            y_fail = None
            for o in run_constant(rig, fn_kpa, steps):
                if y_fail is None and o.object_y_mm > 1.5:
                    y_fail, k_fail = o.object_y_mm, o.period_index
                if o.gross_slip:
                    yslide.append(o.object_y_mm)
                    break
            ys.append(y_fail if y_fail is not None else o.object_y_mm)
            ks.append(k_fail if y_fail is not None else o.period_index)
        res[mat] = (float(np.mean(ys)), float(np.mean(ks)), float(np.mean(yslide)) if yslide else float("nan"))
    return res


def slip_coverage(scene: Scene, seed: int = 3, steps: int = 450) -> dict:
    """Return, per material, the largest actuator position (mm) at first gross slip over all F_N
    (nan when some F_N never slips within the travel)."""
    mech = subset(scene, ("contact", "stick_slip"))
    res = {}
    for mi, mat in enumerate(scene.materials):
        worst = 0.0
        for fi, fn in enumerate(COLLECTION_FORCES_KPA):
            rig = Rig(mech, mat, series_seed(seed, 100 * mi + fi))
            u = np.nan
            for o in run_constant(rig, float(fn), steps):
                if o.gross_slip:
                    u = o.actuator_mm
                    break
            worst = max(worst, u) if np.isfinite(u) else np.nan
            if not np.isfinite(worst):
                break
        res[mat] = worst
    return res


def figures(stats: dict, corr: dict, fig_dir: Path) -> list[str]:
    """Write the calibration figures (PNG) and return their file names."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig_dir.mkdir(parents=True, exist_ok=True)
    names = []
    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    for row in stats["rows"][:: max(1, len(stats["rows"]) // 5)][:5]:
        axes[0].plot(row["y"], lw=0.8)
        axes[1].plot(row["ft"], lw=0.8)
        axes[2].plot(row["pseudo"], lw=0.8)
        axes[3].plot(row["fn"], lw=0.5)
    for ax, lab in zip(axes, ["y [mm]", "F_T [N]", "pseudo s", "F_N [kPa]"]):
        ax.set_ylabel(lab)
    axes[3].set_xlabel("period (500 ms)")
    axes[0].set_title("Simulated rig: data-collection series (cf. paper Fig. slip_time)")
    fig.tight_layout()
    fig.savefig(fig_dir / "sim_collection_series.png", dpi=110)
    plt.close(fig)
    names.append("sim_collection_series.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    for (mat, fn), c in list(corr.items()):
        if mat == next(iter(corr))[0]:
            ax.plot(c["ft"], c["amp"], ".", ms=3, label=f"{mat}, F_N={fn} kPa, R={c['r']:.2f}")
    ax.set_xlabel("F_T [N]")
    ax.set_ylabel("200 Hz band amplitude [counts]")
    ax.set_title("Simulated rig: 200 Hz band vs F_T at fixed F_N (paper R=0.97)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(fig_dir / "sim_band200_vs_ft.png", dpi=110)
    plt.close(fig)
    names.append("sim_band200_vs_ft.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.hist(stats["labels"], bins=20, range=(0, 1), color="tab:blue")
    ax.set_xlabel("pseudo-stick ratio s (before gross slip)")
    ax.set_ylabel("samples")
    ax.set_title("Simulated rig: label distribution (collection protocol)")
    fig.tight_layout()
    fig.savefig(fig_dir / "sim_label_hist.png", dpi=110)
    plt.close(fig)
    names.append("sim_label_hist.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    sar = np.concatenate([r["sar"][: r["k_rule"]] for r in stats["rows"] if r["k_rule"] > 0])
    ps = np.concatenate([r["pseudo"][: r["k_rule"]] for r in stats["rows"] if r["k_rule"] > 0])
    ax.plot(ps, sar, ".", ms=2, alpha=0.4)
    ax.plot([0, 1], [0, 1], "k--", lw=0.8)
    ax.set_xlabel("pseudo-stick ratio (paper's label rule)")
    ax.set_ylabel("true stick-area ratio (c/a)^2")
    ax.set_title("Simulated rig: label vs true stick-area ratio")
    fig.tight_layout()
    fig.savefig(fig_dir / "sim_label_vs_truth.png", dpi=110)
    plt.close(fig)
    names.append("sim_label_vs_truth.png")
    return names


def run_calibration(scene: Scene, n_per_material: int = 20, seed: int = 0, fig_dir: Path | None = None) -> dict:
    """Return all calibration numbers (and write figures when fig_dir is given)."""
    stats = collection_stats(scene, n_per_material, seed)
    corr = band_correlation(scene, seed=seed + 1) if scene.has("injection") else {}
    nc = no_control(scene, seed=seed + 2)
    cov = slip_coverage(scene, seed=seed + 3)
    rows = stats["rows"]
    yb = np.array([r["y_before_rule"] for r in rows])
    ya = np.array([r["y_at_rule"] for r in rows])
    yt = np.array([r["y_before_true"] for r in rows])
    kr = np.array([r["k_rule"] for r in rows])
    rs = np.array([c["r"] for c in corr.values()]) if corr else np.array([np.nan])
    lab = stats["labels"]
    res = {
        "travel_before_rule_mm": (np.nanmean(yb), np.nanstd(yb)),
        "travel_at_rule_mm": (np.nanmean(ya), np.nanstd(ya)),
        "travel_before_true_mm": (np.nanmean(yt), np.nanstd(yt)),
        "onset_period": (float(np.mean(kr[kr >= 0])) if (kr >= 0).any() else np.nan, float(np.mean(kr < 0))),
        "r_band200": (float(np.nanmedian(rs)), float(np.nanmin(rs)), float(np.nanmax(rs))),
        "no_control": nc, "coverage": cov,
        "label_hist": np.histogram(lab, bins=10, range=(0, 1))[0] if lab.size else np.zeros(10, int),
        "n_series": len(rows),
        "figures": figures(stats, corr, fig_dir) if fig_dir is not None and corr else [],
    }
    return res


def report_markdown(scene: Scene, res: dict) -> str:
    """Return the calibration table as markdown (the section written into docs/simulator.md)."""
    tb = res["travel_before_rule_mm"]
    ta = res["travel_at_rule_mm"]
    tt = res["travel_before_true_mm"]
    r = res["r_band200"]
    nc = res["no_control"]
    ycn = np.mean([v[0] for v in nc.values()])
    cov = res["coverage"]
    worst = max(cov.values()) if all(np.isfinite(v) for v in cov.values()) else float("nan")
    hist = res["label_hist"]
    lines = [
        f"Scene `{scene.name}`, {res['n_series']} collection series (all materials); simulated rig, not measurements.",
        "",
        "| quantity | paper | simulated rig |",
        "|---|---|---|",
        f"| travel y at gross-slip onset (label rule; y before the onset period) | 1.5 +/- 0.4 mm | {tb[0]:.2f} +/- {tb[1]:.2f} mm |",
        f"| travel y at the end of the onset period (after the slide) | - | {ta[0]:.2f} +/- {ta[1]:.2f} mm |",
        f"| travel y before the true first slide | - | {tt[0]:.2f} +/- {tt[1]:.2f} mm |",
        f"| Pearson R of the \"200 Hz\" band (150-250 Hz) amplitude vs F_T at fixed F_N; negative = falls as F_T rises, as in the paper (median, min..max over 5 materials x 3 F_N) | 0.97 | {r[0]:.3f} ({r[1]:.3f}..{r[2]:.3f}) |",
        f"| final y with no control (F_N = 2.94 kPa, run ends when y > 1.5 mm) | 2.48 mm | {ycn:.2f} mm "
        f"({', '.join(f'{m} {v[0]:.2f}' for m, v in nc.items())}) |",
        f"| y after the first gross slide at 2.94 kPa (run not stopped) | (2.48 mm, other reading) | "
        f"{np.nanmean([v[2] for v in nc.values()]):.2f} mm |",
        f"| gross slip within 23 mm at every F_N 1.1..5.9 kPa, every material | yes | "
        f"{'yes' if np.isfinite(worst) and worst <= 23.0 else 'NO'} (latest onset at actuator {worst:.1f} mm) |",
        f"| mean onset period (label rule) / series without onset | - | {res['onset_period'][0]:.0f} / {res['onset_period'][1]:.0%} |",
        f"| label distribution s before onset (10 bins 0..1) | not given | {' '.join(str(int(h)) for h in hist)} |",
    ]
    return "\n".join(lines)

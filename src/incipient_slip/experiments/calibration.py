"""The simulator's calibration: the paper's measured quantities beside the simulated rig's.

Targets (RIG.md section 1): travel at gross-slip onset 1.5 +/- 0.4 mm; Pearson R of the 200 Hz
band amplitude vs F_T at fixed F_N, 0.97; final y ~2.5 mm with no control; gross slip within the
23 mm travel at every F_N and material; the distribution of labels s.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from typing import TYPE_CHECKING

from incipient_slip.errors import UsageError

from .settings import Settings

if TYPE_CHECKING:
    from incipient_slip.sim.scene import Scene

NAME = "calibration"
HELP = "the simulated rig against the paper's measured quantities"
DOC = "simulator.md"



def add_arguments(parser) -> None:
    """Add the scene and the number of collection series."""
    parser.add_argument("--scene", default="paper", help="scene name or YAML path (default paper; needs injection)")
    parser.add_argument("--series", type=int, help="collection series per material (quick 1, full 20)")


def run(settings: Settings) -> dict:
    """Run the calibration checks on the scene; write the figures; return the numbers."""
    from incipient_slip.sim.scene import SceneError, load_scene
    try:
        scene = load_scene(settings.option("scene", "paper"))
    except SceneError as exc:
        raise UsageError(str(exc)) from exc
    n = settings.option("series", settings.pick(quick=1, full=20))
    if n < 1:
        raise UsageError(f"--series must be >= 1, got {n}")
    if not scene.has("injection"):
        raise UsageError(f"scene {scene.name!r} has no 'injection' effect; the 200 Hz band target needs it")
    res = run_calibration(scene, n_per_material=n, seed=settings.seed, fig_dir=settings.figures)
    return {**res, "scene": scene.name, "series_per_material": n}


def render(results: dict) -> dict[str, str]:
    """Return the calibration block of docs/simulator.md: the table and its figures."""
    figs = "\n".join(f"![simulated rig: {f}](figures/{f})\n*Simulated rig, not a measurement: `{f}`.*\n"
                     for f in results["figures"])
    return {"calibration": f"{report_markdown(results['scene'], results)}\n\n{figs}"}


MECHANICS = ("contact", "stick_slip", "mocap")
VIBRATION = ("contact", "stick_slip", "fingertip_modes", "injection", "vibrotactile", "ambient_noise", "adc")


def subset(scene: Scene, effects) -> Scene:
    """Return the scene restricted to `effects` (those it has)."""
    from incipient_slip.sim.scene import validate_effects
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
    from incipient_slip.sim.protocols import run_collection
    from incipient_slip.sim.rig import Rig, series_seed
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
                         "u_at_rule": float(outs[k].actuator_mm) if k >= 0 else np.nan,
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
    from incipient_slip.sim.protocols import run_constant
    from incipient_slip.sim.rig import Rig, series_seed
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
    """Return, per material, (mean final y, mean first step with y > 1.5 mm or nan, fraction of runs with
    a gross slide) at constant F_N for all `steps` periods, as the paper's no-action runs."""
    from incipient_slip.sim.protocols import run_constant
    from incipient_slip.sim.rig import Rig, series_seed
    mech = subset(scene, MECHANICS)
    res = {}
    for mi, mat in enumerate(scene.materials):
        ys, ks, slid = [], [], []
        for j in range(seeds):
            rig = Rig(mech, mat, series_seed(seed, 100 * mi + j))
            k_fail, any_slide = np.nan, False
            for o in run_constant(rig, fn_kpa, steps):
                if np.isnan(k_fail) and o.object_y_mm > 1.5:
                    k_fail = o.period_index
                any_slide |= o.gross_slip
            ys.append(o.object_y_mm)
            ks.append(k_fail)
            slid.append(any_slide)
        res[mat] = (float(np.mean(ys)), float(np.nanmean(ks)) if np.isfinite(ks).any() else float("nan"),
                    float(np.mean(slid)))
    return res


def oracle_hold(scene: Scene, seeds: int = 3, seed: int = 4, steps: int = 450) -> dict:
    """Physical-plausibility check: the paper's grip law fed the simulator's TRUE pseudo-stick ratio
    (load_ratio_stick) must be able to hold the object (y <= 1.5 mm for all steps).

    Uses `incipient_slip.control` unchanged (s_d = 0.3, k = 2 kPa, F_N in 1.1..6.0 kPa, 0.5 kPa per
    period, start at 2.9 kPa). Returns per material the mean final y, final F_N, max y, final s,
    the fraction of runs that held, and the mean first step with y > 1.5 mm (nan if none)."""
    from incipient_slip.sim.protocols import run_closed_loop
    from incipient_slip.sim.rig import Rig, series_seed
    from incipient_slip.control import DEFAULT_INITIAL_FORCE_KPA, FAILURE_TRAVEL_MM, ControlParams, next_force

    mech = subset(scene, MECHANICS)
    cp = ControlParams()
    res = {}
    for mi, mat in enumerate(scene.materials):
        rows = []
        for j in range(seeds):
            force = [DEFAULT_INITIAL_FORCE_KPA]

            def controller(last, force=force):
                if last is not None:
                    force[0] = next_force(force[0], last.load_ratio_stick, cp).normal_force_kpa
                return force[0]

            rig = Rig(mech, mat, series_seed(seed, 100 * mi + j))
            ys, k_fail = [], np.nan
            for o in run_closed_loop(rig, controller, steps):
                ys.append(o.object_y_mm)
                if np.isnan(k_fail) and (o.object_y_mm > FAILURE_TRAVEL_MM or o.normal_force_kpa >= cp.safety_limit_kpa):
                    k_fail = o.period_index
            rows.append((o.object_y_mm, o.normal_force_kpa, max(ys), o.load_ratio_stick, float(np.isnan(k_fail)), k_fail))
        a = np.array(rows)
        res[mat] = {"y": float(a[:, 0].mean()), "fn": float(a[:, 1].mean()), "y_max": float(a[:, 2].max()),
                    "s": float(a[:, 3].mean()), "held": float(a[:, 4].mean()),
                    "k_fail": float(np.nanmean(a[:, 5])) if np.isfinite(a[:, 5]).any() else float("nan")}
    return res


def slip_coverage(scene: Scene, seed: int = 3, steps: int = 450) -> dict:
    """Return, per material, the largest constant F_N (kPa, collection grid) at which gross slip starts
    within the travel (nan when none does). The collection protocol's own coverage (every series
    reaches gross slip) is in `collection_stats`."""
    from incipient_slip.sim.protocols import COLLECTION_FORCES_KPA, run_constant
    from incipient_slip.sim.rig import Rig, series_seed
    mech = subset(scene, ("contact", "stick_slip"))
    res = {}
    for mi, mat in enumerate(scene.materials):
        best = float("nan")
        for fi, fn in enumerate(COLLECTION_FORCES_KPA):
            rig = Rig(mech, mat, series_seed(seed, 100 * mi + fi))
            if any(o.gross_slip for o in run_constant(rig, float(fn), steps)):
                best = float(fn)
            else:
                break
        res[mat] = best
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
    orc = oracle_hold(scene, seed=seed + 4)
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
        "no_control": nc, "coverage": cov, "oracle": orc,
        "onset_by_material": {m: float(np.nanmean([r["y_before_rule"] for r in rows if r["material"] == m]))
                              for m in scene.materials},
        "latest_onset_actuator_mm": float(np.nanmax([r["u_at_rule"] for r in rows])) if (kr >= 0).any() else np.nan,
        "label_hist": np.histogram(lab, bins=10, range=(0, 1))[0] if lab.size else np.zeros(10, int),
        "n_series": len(rows),
        "figures": figures(stats, corr, fig_dir) if fig_dir is not None and corr else [],
    }
    return res


def report_markdown(scene_name: str, res: dict) -> str:
    """Return the calibration table as markdown (the section written into docs/simulator.md)."""
    tb = res["travel_before_rule_mm"]
    ta = res["travel_at_rule_mm"]
    tt = res["travel_before_true_mm"]
    r = res["r_band200"]
    nc = res["no_control"]
    ycn = np.mean([v[0] for v in nc.values()])
    cov = res["coverage"]
    orc = res["oracle"]
    n_held = sum(v["held"] >= 1.0 for v in orc.values())
    hist = res["label_hist"]
    per = res["onset_by_material"]
    no_onset = res["onset_period"][1]
    held = all(v["held"] == 1.0 for v in orc.values())
    lines = [
        f"Scene `{scene_name}`, {res['n_series']} collection series (all materials); simulated rig, not measurements.",
        "",
        "| quantity | paper | simulated rig |",
        "|---|---|---|",
        f"| travel y at gross-slip onset (label rule; y before the onset period) | 1.5 +/- 0.4 mm | {tb[0]:.2f} +/- {tb[1]:.2f} mm "
        f"({', '.join(f'{m} {v:.2f}' for m, v in per.items())}) |",
        f"| travel y at the end of the onset period (after the slide) | - | {ta[0]:.2f} +/- {ta[1]:.2f} mm |",
        f"| travel y before the true first slide | - | {tt[0]:.2f} +/- {tt[1]:.2f} mm |",
        f"| Pearson R of the \"200 Hz\" band (150-250 Hz) amplitude vs F_T at fixed F_N; negative = falls as F_T rises, as in the paper (median, min..max over 5 materials x 3 F_N) | 0.97 | {r[0]:.3f} ({r[1]:.3f}..{r[2]:.3f}) |",
        f"| final y with no action (F_N = 2.94 kPa, all 450 steps, mean of 10 runs) | 2.48 mm | {ycn:.2f} mm "
        f"({', '.join(f'{m} {v[0]:.2f}' for m, v in nc.items())}) |",
        f"| no action: runs with a gross slide / mean first step with y > 1.5 mm | - | "
        f"{', '.join(f'{m} {v[2]:.0%}/{v[1]:.0f}' for m, v in nc.items())} |",
        f"| gross slip within 23 mm in the collection protocol, every material (series without onset; latest onset) | yes | "
        f"{'yes' if no_onset == 0 else 'NO'} ({no_onset:.0%}; actuator {res['latest_onset_actuator_mm']:.1f} mm) |",
        f"| largest constant F_N that slides grossly within 23 mm | - | "
        f"{', '.join(f'{m} {v:.1f} kPa' for m, v in cov.items())} |",
        f"| ORACLE: paper's law (s_d 0.3, k 2 kPa, 1.1..6.0 kPa, 0.5 kPa/period) on the true load_ratio_stick holds y <= 1.5 mm for 450 steps | possible (injection: y 1.38 mm, F_N 4.50 kPa) | "
        f"{'yes' if held else f'on {n_held} of {len(orc)} materials'}: final y / F_N / held " + ", ".join(
            f"{m} {v['y']:.2f} mm / {v['fn']:.2f} kPa / {v['held']:.0%}" for m, v in orc.items()) + " |",
        f"| mean onset period (label rule) / series without onset | - | {res['onset_period'][0]:.0f} / {no_onset:.0%} |",
        f"| label distribution s before onset (10 bins 0..1) | not given | {' '.join(str(int(h)) for h in hist)} |",
    ]
    return "\n".join(lines)

"""Fit the simulated rig to the paper's open-loop measurements only (targets: docs/calibration.md).

Stage 1 (mechanics, `experiments.mechanics_fit`) fits the pad's bulk shear stiffness and the tension spring with
scipy.optimize (Nelder-Mead in log space, common random numbers so the objective is
deterministic) to T1-T4: onset travel mean and spread, every collection series slips within
23 mm, the pooled no-action final y. Stage 2 (vibration) checks the F_N channel of the modes on
a documented grid against the prior P1 and the 200 Hz band target T5. Nothing here runs a
closed loop; the objective reads only the pre-registered open-loop targets. The fitted values
are written with their provenance into the params file (`--write-params`), and a target-by-target
table (paper / simulated rig / within tolerance) is printed and rendered.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import re
from pathlib import Path

import numpy as np

from incipient_slip.errors import UsageError
from incipient_slip.sim.scene import Scene, with_effects, with_values

from .mechanics_fit import FITTED, MECHANICS, TARGETS, beta_interval, fit_mechanics, mechanics_checks, range_ok

# `slip` imports this module to build its parser: the simulator, scipy and the models are
# imported inside the functions that use them.

NAME = "calibration"
HELP = "fit the simulated rig to the paper's open-loop measurements; target-by-target table"
DOC = "calibration.md"
QUICK = ("25 collection series and 2 no-action runs per material per objective evaluation "
         "(full 100 and 6), at most 30 evaluations (full 80), 40 series per data set for the T6 pattern "
         "(full 100); every run keeps the full protocol, so the fit lands near, not on, the full fit")
RESULTS = "calibration_results.json"

VIBRATION = ("contact", "stick_slip", "fingertip_modes", "injection", "vibrotactile", "ambient_noise", "adc")
FN_GAIN_GRID = (0.0, 0.1, 0.2, 0.3, 0.5, 1.0)
# Where stage 1's optimizer starts: fixed here, never read from the params file the fit writes (a
# start read from it made each rerun a new fit: J 0.628 at the start, 0.587 after 30 evaluations).
# The values are the first v3 fit's (2026-11-25: 60 series, 4 runs, 30 evaluations).
START = {FITTED[0]: 0.489519, FITTED[1]: 0.0327175, FITTED[2]: 1.0605, FITTED[3]: 0.545084}


def add_arguments(parser) -> None:
    """Add the calibration's own options."""
    parser.add_argument("--series", type=int, help="collection series per objective evaluation (quick 25, full 100)")
    parser.add_argument("--runs", type=int, help="no-action runs per material (quick 2, full 6)")
    parser.add_argument("--maxfev", type=int, help="objective evaluations of the optimizer (quick 30, full 80)")
    parser.add_argument("--estimation-series", dest="estimation_series", type=int,
                        help="series per simulated data set of the T6 estimation pattern (quick 40, full 100)")
    parser.add_argument("--skip-estimation", dest="skip_estimation", action="store_true",
                        help="skip stage 2's estimation pattern (T6) and the electrode grid")
    parser.add_argument("--electrode-grid", dest="electrode_grid", action="store_true",
                        help="re-grid the electrode nuisance amplitudes on T6 (27 estimation studies); default: "
                             "check T6 at the params file's values")
    parser.add_argument("--skip-beta-interval", dest="skip_beta_interval", action="store_true",
                        help="skip the scan of the beta interval that the open-loop targets allow")
    parser.add_argument("--scene", default="paper", help="scene to calibrate (default paper)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="fix a parameter before fitting (a point of the uncertainty set), repeatable")
    parser.add_argument("--write-params", action="store_true",
                        help="write the fitted values with provenance into the params file")


def parse_overrides(items) -> dict:
    """Return {(section, key): float} from 'section.key=value' strings (UsageError names a bad one)."""
    out = {}
    for item in items or ():
        m = re.fullmatch(r"([a-z_]+)\.([a-z_]+)=(.+)", item.strip())
        if not m:
            raise UsageError(f"--set {item!r}: expected SECTION.KEY=VALUE")
        try:
            value = float(m.group(3))
        except ValueError:
            raise UsageError(f"--set {item!r}: value is not a number") from None
        if not math.isfinite(value):
            raise UsageError(f"--set {item!r}: value must be finite")
        out[(m.group(1), m.group(2))] = value
    return out


# --- stage 2: vibration path ---------------------------------------------------------------------

def band_gain(p_modes: dict, a_mm: float, sar: float, shear: float, fs_hz: float, lo=150.0, hi=250.0) -> float:
    """Return the mean magnitude of the modal path's frequency response over [lo, hi] Hz."""
    from scipy import signal

    from incipient_slip.sim.fingertip_modes import mode_sos, mode_state
    sos = mode_sos(p_modes, *mode_state(p_modes, a_mm, sar, shear), fs_hz)
    f, h = signal.sosfreqz(sos, worN=np.linspace(lo, hi, 41), fs=fs_hz)
    return float(np.mean(np.abs(h)))


def fn_channel_ratio(scene: Scene) -> float:
    """Return P1: |band(5.9 kPa) - band(1.1 kPa)| in full stick over |band(s=1) - band(s=0)| at 2.9 kPa."""
    from incipient_slip.sim import contact
    p = scene.params
    c = p["contact"]
    pm = {k: (np.asarray(v, float) if isinstance(v, list) else v) for k, v in p["fingertip_modes"].items()}
    fs = p["timing"]["pac_rate_hz"]
    r = contact.effective_radius_mm(c)
    e_star, _ = contact.effective_moduli_mpa(c, 3000.0)

    def a(kpa):
        return contact.contact_radius_mm(kpa * c["newton_per_kpa"], r, e_star, c["contact_saturation_radius_mm"])

    fn_span = abs(band_gain(pm, a(5.9), 1.0, 0.0, fs) - band_gain(pm, a(1.1), 1.0, 0.0, fs))
    stick_span = abs(band_gain(pm, a(2.9), 1.0, 0.0, fs) - band_gain(pm, a(2.9), 0.0, 0.0, fs))
    return fn_span / stick_span if stick_span > 0 else math.inf


def band_amplitude(pac_counts_window: np.ndarray, fs_hz: float, lo_hz: float = 150.0, hi_hz: float = 250.0) -> float:
    """Return the mean FFT magnitude (counts) of a Hann-windowed window within [lo, hi] Hz."""
    x = pac_counts_window.astype(np.float64)
    spec = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(len(x))))
    f = np.fft.rfftfreq(len(x), 1.0 / fs_hz)
    return float(spec[(f >= lo_hz) & (f <= hi_hz)].mean())


def band_correlation(scene: Scene, seed: int, forces_kpa=(2.3, 3.5, 4.7)) -> dict:
    """Return Pearson R of the 150-250 Hz band amplitude vs F_T during stick per 'material@F_N'."""
    from incipient_slip.sim.protocols import run_constant
    from incipient_slip.sim.rig import Rig, series_seed
    vib = with_effects(scene, VIBRATION)
    fs = vib.params["timing"]["pac_rate_hz"]
    out = {}
    for mi, mat in enumerate(vib.materials):
        for fi, fn in enumerate(forces_kpa):
            rig = Rig(vib, mat, series_seed(seed, 100 * mi + fi))
            prev, amps, fts = None, [], []
            for o in run_constant(rig, fn):
                if o.gross_slip:
                    break
                if prev is not None:
                    amps.append(band_amplitude(np.concatenate([prev.pac_counts, o.pac_counts]), fs))
                    fts.append(o.tangential_force_n)
                prev = o
            out[f"{mat}@{fn}"] = float(np.corrcoef(fts, amps)[0, 1]) if len(amps) > 3 else math.nan
    return out


def vibration_summary(scene: Scene, seed: int) -> dict:
    """Return T5 (median |R|, one sign?) and P1 for the scene."""
    rs = np.array(list(band_correlation(scene, seed).values()))
    finite = rs[np.isfinite(rs)]
    one_sign = bool(finite.size and (np.all(finite > 0) or np.all(finite < 0)))
    return {"T5": float(np.median(np.abs(finite))) if finite.size else math.nan, "T5_one_sign": one_sign,
            "T5_sign": "+" if finite.size and np.median(finite) > 0 else "-",
            "T5_range": [float(finite.min()), float(finite.max())] if finite.size else [math.nan, math.nan],
            "P1": fn_channel_ratio(scene)}


def fit_fn_channel(scene: Scene, seed: int) -> dict:
    """Return the F_N channel gain from the grid: the prior value if it meets P1 and T5, else the
    feasible grid value nearest to it (the data bound it; they do not pin it)."""
    prior = scene.params["fingertip_modes"]["fn_channel_gain"]
    rows = []
    for g in FN_GAIN_GRID:
        sc = with_values(scene, {("fingertip_modes", "fn_channel_gain"): g})
        rows.append({"gain": g, "P1": fn_channel_ratio(sc)})
    feasible = [r["gain"] for r in rows if r["P1"] <= 0.5]
    chosen = min(feasible, key=lambda g: abs(g - prior)) if feasible else min(rows, key=lambda r: r["P1"])["gain"]
    return {"grid": rows, "value": float(chosen), "prior": float(prior)}


def collection_figure(scene: Scene, seed: int, fig_dir: Path, n: int = 5) -> str:
    """Write the figure of `n` collection series at the scene's parameters; return its file name."""
    from incipient_slip.experiments.plots import pyplot, save
    plt = pyplot()

    from incipient_slip.models.labels import gross_slip_travel_mm, pseudo_stick_ratio
    from incipient_slip.sim.protocols import run_collection
    from incipient_slip.sim.rig import Rig, series_seed

    mech = with_effects(scene, MECHANICS)
    fig, axes = plt.subplots(5, 1, figsize=(7, 9), sharex=True)
    for i in range(n):
        rig = Rig(mech, scene.materials[i % len(scene.materials)], series_seed(seed, i))
        outs = list(run_collection(rig))
        t = np.concatenate([o.mocap_t_s for o in outs])
        y = np.concatenate([o.mocap_y_mm for o in outs])
        end = np.array([o.t_start_s + rig.period_s for o in outs])
        ft = np.array([o.tangential_force_n for o in outs])
        lab = pseudo_stick_ratio(ft, gross_slip_travel_mm(t, y, end))
        for ax, v in zip(axes, ([o.object_y_mm for o in outs], ft, lab.pseudo_stick_ratio,
                                [o.stick_area_ratio for o in outs], [o.normal_force_kpa for o in outs])):
            ax.plot(v, lw=0.8 if ax is not axes[4] else 0.4, label=rig.material if ax is axes[0] else None)
    for ax, name in zip(axes, ("y [mm]", "F_T [N]", "pseudo s (label)", "true (c/a)^2", "F_N [kPa]")):
        ax.set_ylabel(name, fontsize=8)
    axes[0].legend(fontsize=7, ncol=5)
    axes[4].set_xlabel("period (500 ms)")
    axes[0].set_title("SIMULATED RIG (fitted, open loop): collection series, cf. the paper's data-collection figure",
                      fontsize=9)
    name = "calibration_collection.png"
    save(fig, fig_dir / name)
    return name


# --- params file ---------------------------------------------------------------------------------

def write_params(path: Path, fitted: dict) -> None:
    """Rewrite value and source of each fitted 'section.key' in the params YAML (one-line entries)."""
    text = Path(path).read_text()
    for name, (value, source) in fitted.items():
        section, key = name.split(".")
        sec = re.search(rf"^{section}:\n((?:  .*\n|\s*#.*\n)*)", text, re.M)
        if not sec:
            raise KeyError(f"{path}: no section {section}")
        body = sec.group(1)
        pat = re.compile(rf'^(  {key}: \{{value: )[^,]+(, unit: [^,]+, source: )"[^"]*"\}}', re.M)
        if not pat.search(body):
            raise KeyError(f"{path}: no one-line entry {section}.{key}")
        new_body = pat.sub(lambda m: f'{m.group(1)}{value:.6g}{m.group(2)}"{source}"}}', body, count=1)
        text = text[:sec.start(1)] + new_body + text[sec.end(1):]
    Path(path).write_text(text)


# --- the experiment ------------------------------------------------------------------------------

def _tick(ok: bool) -> str:
    return "yes" if ok else "NO"


def target_rows(mech: dict, vib: dict) -> list[dict]:
    """Return the target-by-target rows: id, what, paper, simulated, tolerance, within."""
    t7, ok = mech["T7"], mechanics_checks(mech)
    return [
        {"id": "T1", "paper": "1.5", "sim": f"{mech['T1']:.2f} (other readings: end of the period before the onset "
         f"{mech['T1_prev']:.2f}, end of the onset period {mech['T1_end']:.2f})",
         "tol": TARGETS["T1"][2], "ok": ok["T1"]},
        {"id": "T2", "paper": "0.4", "sim": f"{mech['T2']:.2f}", "tol": TARGETS["T2"][2], "ok": ok["T2"]},
        {"id": "T3", "paper": "all", "sim": f"{mech['T3']:.2f}", "tol": TARGETS["T3"][2], "ok": ok["T3"]},
        {"id": "T4", "paper": "2.48, gross slip", "sim": f"{mech['T4']:.2f}, slid {mech['T4_slid']:.2f} (" + ", ".join(
            f"{m} {v:.2f} mm = slide {mech['no_action_split'][m][0]:.2f} + shear {mech['no_action_split'][m][1]:.2f}"
            f"{'' if mech['no_action_slid_by_material'][m] else ' (no slide)'}"
            for m, v in mech["no_action_by_material"].items()) + ")",
         "tol": TARGETS["T4"][2], "ok": ok["T4"]},
        {"id": "T5", "paper": "R = 0.97", "sim": f"median |R| {vib['T5']:.2f}, sign {vib['T5_sign']}"
         f"{'' if vib['T5_one_sign'] else ' (MIXED signs)'} ({vib['T5_range'][0]:.2f}..{vib['T5_range'][1]:.2f})",
         "tol": TARGETS["T5"][2], "ok": vib["T5"] >= 0.9 and vib["T5_one_sign"]},
        {"id": "P1", "paper": "barely suppressed", "sim": f"{vib['P1']:.2f}", "tol": TARGETS["P1"][2], "ok": vib["P1"] <= 0.5},
        {"id": "T7", "paper": "1.5 +/- 0.4", "sim": ", ".join(f"{k} kPa {v:.2f}" for k, v in t7.items()),
         "tol": TARGETS["T7"][2], "ok": ok["T7"]},
    ]


def check(settings) -> None:
    """Checks --scene and --set before anything runs (`_scene_to_fit`)."""
    _scene_to_fit(settings.option("scene", "paper"), parse_overrides(settings.option("overrides", [])))


def run(settings) -> dict:
    """Fit stage 1 and stage 2 and return the fitted values, the target table and provenance."""
    from incipient_slip.sim.scene import PARAMS_DIR
    opt = settings.option
    n_series, runs, maxfev = _sizes(settings)
    fixed = parse_overrides(opt("overrides", []))
    scene = _scene_to_fit(opt("scene", "paper"), fixed)
    if settings.progress:
        print(f"stage 1 (mechanics): {n_series} collection series + {runs} no-action runs per material "
              f"per evaluation, at most {maxfev} evaluations (simulated rig)", flush=True)
    mech = fit_mechanics(scene, n_series, runs, settings.seed, maxfev, settings.progress)
    scene = with_values(scene, {tuple(k.split(".")): v for k, v in mech["values"].items()})
    betas = []
    if not opt("skip_beta_interval", False):
        if settings.progress:
            print("stage 1b (the interval of beta that T1-T4' and T7 allow; k_b and k_s refitted per beta)", flush=True)
        betas = beta_interval(scene, max(20, n_series // 2), max(1, runs // 2), settings.seed,
                              maxfev=settings.pick(8, 15), progress=settings.progress, workers=settings.jobs)
    fn = fit_fn_channel(scene, settings.seed)
    scene = with_values(scene, {("fingertip_modes", "fn_channel_gain"): fn["value"]})
    if settings.progress:
        print("stage 2 (vibration): F_N channel grid, 200 Hz band check", flush=True)
    vib = vibration_summary(scene, settings.seed + 7)
    rows = target_rows(mech["summary"], vib)
    figure = collection_figure(scene, settings.seed + 5, settings.figures)
    el = None
    if not opt("skip_estimation", False):
        el = _estimation_pattern(settings, scene)
        items = el["items"]
        rows.append({"id": "T6", "paper": "pattern (a)-(e)", "sim": "; ".join(
            f"({k}) {'pass' if ok else 'FAIL'}: {detail}" for k, (ok, detail) in items.items()),
            "tol": "all five items", "ok": all(ok for ok, _ in items.values())})
    fitted = _fitted_with_provenance(settings, n_series, runs, mech, betas, fn, el)
    if opt("write_params", False):       # (not in the results: they are the same with or without it)
        if fixed:
            raise UsageError("--write-params with --set would store a point of the uncertainty set as the nominal fit")
        path = PARAMS_DIR / "default.yaml"
        write_params(path, fitted)
        print(f"wrote the fitted values into {path}", flush=True)
    return {"fitted": {k: v[0] for k, v in fitted.items()}, "provenance": {k: v[1] for k, v in fitted.items()},
            "fixed": {f"{s}.{k}": v for (s, k), v in fixed.items()}, "mechanics": mech, "fn_channel": fn,
            "beta_interval": betas,
            "vibration": vib, "electrodes": el, "targets": rows, "figure": figure, "budget": settings.budget,
            "all_within": all(r["ok"] for r in rows)}


def _sizes(settings) -> tuple[int, int, int]:
    """Return stage 1's collection series, no-action runs and evaluations (UsageError below 1)."""
    opt = settings.option
    n_series = opt("series", settings.pick(25, 100))
    runs = opt("runs", settings.pick(2, 6))
    maxfev = opt("maxfev", settings.pick(30, 80))
    for label, v in (("--series", n_series), ("--runs", runs), ("--maxfev", maxfev)):
        if v < 1:
            raise UsageError(f"{label} must be >= 1, got {v}")
    return n_series, runs, maxfev


def _scene_to_fit(name: str, fixed: dict) -> Scene:
    """Return the scene to calibrate with the --set values (UsageError: unknown, or no injection for T5)."""
    from incipient_slip.sim.scene import SceneError, load_scene

    try:
        scene = load_scene(name)
        scene = with_values(scene, {**START, **fixed})     # --set wins over the start
    except (SceneError, KeyError) as exc:
        raise UsageError(str(exc).strip("'")) from exc
    if not scene.has("injection"):
        raise UsageError(f"scene {scene.name!r} has no 'injection' effect; the 200 Hz band target T5 needs it")
    return scene


def _estimation_pattern(settings, scene: Scene) -> dict:
    """Stage 2's T6: the estimation pattern at the params file's electrode values, or their grid."""
    opt = settings.option
    n_est = opt("estimation_series", settings.pick(40, 100))
    if settings.progress:
        print(f"stage 2 (estimation pattern T6): electrode grid {ELECTRODE_GRID}, {n_est} series per data set",
              flush=True)
    return (fit_electrodes if opt("electrode_grid", False) else check_pattern)(
        scene, n_est, settings.seed + 11, Path(settings.work) / "data", settings.progress, settings.jobs)


def _fitted_with_provenance(settings, n_series: int, runs: int, mech: dict, betas: list, fn: dict,
                            el: dict | None) -> dict:
    """Return {parameter: (fitted value, its provenance)} of stage 1, the F_N channel and, with
    --electrode-grid, the electrodes."""
    # no run date in the provenance: the page and the params file are what the command makes, on any day
    prov = (f"fitted (slip reproduce calibration, budget {settings.budget}, seed {settings.seed}, "
            f"{n_series} collection series, {runs} no-action runs per material, T7 ramps at 5 levels; Nelder-Mead, "
            f"objective J {mech['objective']:.3f} on T1-T4', T7 of docs/calibration.md, amendment 2)")
    t7_betas = [r["beta"] for r in betas if all(range_ok(v) for v in r["T7"].values())]
    b_range = (f"; T7 allows beta {min(t7_betas):g}..{max(t7_betas):g} on the grid {[r['beta'] for r in betas]} "
               f"(k_b, k_s refitted per beta)" if t7_betas else "; no beta of the grid meets T7" if betas else "")
    fitted = {"pre_slip.bulk_shear_n_per_mm": (mech["values"]["pre_slip.bulk_shear_n_per_mm"],
                                               prov + ": onset travel T1/T2 at the start of the slide, T7"),
              "pre_slip.bulk_stiffening_exponent": (mech["values"]["pre_slip.bulk_stiffening_exponent"],
                                                    prov + ": the deformable range T7 across 1.1-5.9 kPa" + b_range),
              "stick_slip.spring_n_per_mm": (mech["values"]["stick_slip.spring_n_per_mm"],
                                             prov + ": no-action final y and slide T4', with T3 as a constraint"),
              "stick_slip.mu_spread_scale": (mech["values"]["stick_slip.mu_spread_scale"],
                                             prov + ": bounded by T4' (a wide spread leaves high-friction materials "
                                             "unslid and low-friction ones far past 2.48 mm; amendment 2a); range 0.1-1.5"),
              "fingertip_modes.fn_channel_gain": (fn["value"], f"prior 0.3 (paper: the biomimetic structure barely "
                                                  f"suppresses propagation by normal force), bounded by P1 <= 0.5 on the grid "
                                                  f"{list(FN_GAIN_GRID)} (slip reproduce calibration); the data bound it, "
                                                  f"they do not pin it")}
    if el is not None and settings.option("electrode_grid", False):
        eprov = (f"fitted (slip reproduce calibration, budget {settings.budget}): documented grid "
                 f"{ELECTRODE_GRID} on the estimation pattern T6 (0.5 per failed item, ties to the smaller amplitude)")
        fitted["electrodes.core_stiction_ratio"] = (el["core_stiction_ratio"], eprov + "; prior range 0-0.3")
        fitted["electrodes.contact_offset_counts"] = (el["contact_offset_counts"], eprov + "; prior range 0-15")
        fitted["electrodes.drift_counts"] = (el["drift_counts"], eprov + "; stationary std of the OU drift, prior range 0-10")
    return fitted


def render(results: dict) -> dict:
    """Return the target-by-target table and the fitted values as markdown blocks."""
    lines = ["Simulated rig, not measurements. Budget `" + results["budget"] + "`.", "",
             "| target | what | paper | simulated rig | tolerance | within |", "|---|---|---|---|---|---|"]
    for r in results["targets"]:
        lines.append(f"| {r['id']} | {TARGETS[r['id']][0]} | {r['paper']} | {r['sim']} | {r['tol']} | {_tick(r['ok'])} |")
    lines += ["", "| fitted parameter | value | provenance |", "|---|---|---|"]
    for k, v in results["fitted"].items():
        lines.append(f"| `{k}` | {v:.5g} | {results['provenance'][k]} |")
    if results.get("fixed"):
        lines += ["", "Fixed for this fit: " + ", ".join(f"`{k}` = {v}" for k, v in results["fixed"].items())]
    m = results["mechanics"]["summary"]
    if results.get("beta_interval"):
        lines += ["", "The interval of beta (k_b and k_s refitted at each beta; T7 levels 1.1/2.3/3.5/4.7/5.9 kPa):", "",
                  "| beta | k_b [N/mm at 1 N] | k_s [N/mm] | T7 [mm] | meets T7 | objective | meets every target |",
                  "|---|---|---|---|---|---|---|"]
        for r in results["beta_interval"]:
            lines.append(f"| {r['beta']:g} | {r['k_b']:.3f} | {r['k_s']:.4f} | "
                         + "/".join(f"{v:.2f}" for v in r["T7"].values())
                         + f" | {_tick(all(range_ok(v) for v in r['T7'].values()))} | {r['J']:.2f} | {_tick(r['consistent'])} |")
        if any(all(range_ok(v) for v in r["T7"].values()) and not r["consistent"] for r in results["beta_interval"]):
            lines += ["", "(Where T7 is met and another target is not, it is the scan's smaller refit (half the series "
                      "and runs) that misses it: see the fitted point's row above.)"]
    lines += ["", "The pseudo label under the simulated collection protocol (reported, not fitted): onset periods by F_N "
              + ", ".join(f"{k} kPa: {v}" for k, v in m["onset_fn_counts"].items())
              + f" (the friction limit's effective F_N there {m['onset_f_eff_mean_kpa']:.2f} kPa on average); "
              "label - true load ratio by F_N: "
              + ", ".join(f"{r['bin']} {r['mean']:+.2f} (SD {r['sd']:.2f})" for r in m["label_error_by_fn"]) + "."]
    lines += ["", "Onset travel by material (mm): " + ", ".join(f"{k} {v:.2f}" for k, v in m["onset_by_material"].items())
              + f"; largest travel within one period: {m['max_period_travel_mm']:.2f} mm."]
    if results.get("figure"):
        lines += ["", f"![simulated rig: collection series at the fitted point](figures/{results['figure']})",
                  f"*Simulated rig, not a measurement: `{results['figure']}` (open loop, fitted parameters).*"]
    return {"calibration-table": "\n".join(lines)}


# --- stage 2: estimation pattern (T6) and the electrode nuisance amplitudes ---------------------

ELECTRODE_METHODS = ("e19", "e10", "e4", "e1")
ELECTRODE_GRID = {"core_stiction_ratio": (0.0, 0.1, 0.2), "contact_offset_counts": (0.0, 5.0, 10.0),
                  "drift_counts": (1.0, 3.0, 5.0)}


def _simulate(sets: dict, n_series: int, seed: int, work: Path, progress: bool, workers: int = 1) -> None:
    """Simulate the data sets {name: scene} into WORK/name, in one pass: the first scene's runs
    give the others' series exactly (`sim.dataset.view_kind`: the same parameters, fewer effects)."""
    from incipient_slip.sim.dataset import write_dataset

    (name, scene), *views = sets.items()
    for n in sets:
        for stale in (Path(work) / n).glob("series_*.npz"):
            stale.unlink()
    write_dataset(scene, n_series, seed, Path(work) / name, workers=workers, progress=progress,
                  views={Path(work) / n: sc for n, sc in views})


def _study(scene_name: str, methods, work: Path) -> dict:
    """Return {method: per-method scores} of a quick estimation study on the data set WORK/scene_name."""
    from incipient_slip.models.pipeline import run_study

    d = Path(work) / scene_name
    dirs = {"paper": d, "no_injection": d}
    study = run_study(dirs, methods=methods, quick=True, max_train=2000, grid_max=600, progress=False)
    out = {}
    for m, r in study.results.items():
        y, err = r.test.y, r.pred - r.test.y
        hi, mid = y > 0.7, (y > 0.3) & (y <= 0.7)
        out[m] = {"rmse": float(r.scores.rmse.mean()), "top10": float(r.scores.top10_rmse.mean()),
                  "rmse_s_above_0.7": float(np.sqrt(np.mean(err[hi] ** 2))) if hi.any() else math.nan,
                  "rmse_s_mid": float(np.sqrt(np.mean(err[mid] ** 2))) if mid.any() else math.nan,
                  "by_material": {k: v["rmse"] for k, v in r.scores.summary()["by_material"].items()}}
    return out


def pattern_items(scores: dict) -> dict:
    """Return the T6 items (a)-(e) of docs/calibration.md as {item: (passed, detail)}."""
    r = {m: v["rmse"] for m, v in scores.items()}
    t = {m: v["top10"] for m, v in scores.items()}
    others = [r[m] for m in ("injection", "e19", "e10", "e4")]
    a = r["vibrotactile"] > 1.25 * max(others) and r["e1"] > 1.25 * max(others)
    b = all(abs(r["injection"] - r[m]) <= 0.25 * r[m] for m in ("e19", "e10", "e4"))
    c = t["injection"] <= min(t.values())
    d = all(scores[m]["rmse_s_above_0.7"] > scores[m]["rmse_s_mid"] for m in ("e19", "e10", "e4"))
    inj = scores["injection"]["by_material"]
    e = max(inj.values()) <= 1.5 * np.mean(list(inj.values()))
    return {"a": (a, f"vibrotactile {r['vibrotactile']:.3f}, E1 {r['e1']:.3f} vs others <= {max(others):.3f}"),
            "b": (b, "mean RMSE " + ", ".join(f"{m} {r[m]:.3f}" for m in ("injection", "e19", "e10", "e4"))),
            "c": (c, "top-10 % RMSE " + ", ".join(f"{m} {v:.3f}" for m, v in t.items())),
            "d": (d, "electrodes RMSE s>0.7 / mid " + ", ".join(
                f"{m} {scores[m]['rmse_s_above_0.7']:.3f}/{scores[m]['rmse_s_mid']:.3f}" for m in ("e19", "e10", "e4"))),
            "e": (e, "injection by material " + ", ".join(f"{m} {v:.3f}" for m, v in inj.items()))}


def pattern_objective(items: dict) -> float:
    """Return the T6 part of the objective: 0.5 per failed item (docs/calibration.md)."""
    return 0.5 * sum(not ok for ok, _ in items.values())


def fit_electrodes(scene: Scene, n_series: int, seed: int, work: Path, progress: bool, workers: int = 1) -> dict:
    """Return the electrode nuisance amplitudes from the documented grid (T6 items b and d decide;
    ties go to the smaller amplitudes), the estimation scores at them and the grid's rows."""
    from incipient_slip.sim.scene import load_scene
    _simulate({"paper": scene, "no_injection": dataclasses.replace(load_scene("no_injection"), params=scene.params)},
              n_series, seed, work, progress, workers)
    vib = _study("paper", ("injection",), work)
    vt = _study("no_injection", ("vibrotactile",), work)
    rows, best = [], None
    eo = load_scene("electrodes_only")
    names = list(ELECTRODE_GRID)
    for point in itertools.product(*ELECTRODE_GRID.values()):
        values = dict(zip(names, point))
        sc = with_values(dataclasses.replace(eo, params=scene.params),
                         {("electrodes", k): v for k, v in values.items()})
        _simulate({"electrodes": sc}, n_series, seed, work, progress, workers)
        el = _study("electrodes", ELECTRODE_METHODS, work)
        scores = {**vib, **vt, **el}
        items = pattern_items(scores)
        j = pattern_objective(items)
        rows.append({**values, "J": j, "items": {k: bool(v[0]) for k, v in items.items()}})
        if progress:
            print("  electrodes " + ", ".join(f"{k} {v}" for k, v in values.items()) + ": items "
                  + " ".join(f"{k}{'+' if v[0] else '-'}" for k, v in items.items()) + f" -> J {j}", flush=True)
        if best is None or j < best[0] - 1e-12:
            best = (j, values, scores, items)
    j, values, scores, items = best
    return {**values, "objective": j, "grid": rows,
            "scores": scores, "items": {k: [bool(v[0]), v[1]] for k, v in items.items()}}


def check_pattern(scene: Scene, n_series: int, seed: int, work: Path, progress: bool, workers: int = 1) -> dict:
    """Return T6 at the params file's electrode amplitudes (one study per scene, no grid)."""
    from incipient_slip.sim.scene import load_scene
    at = {n: dataclasses.replace(load_scene(n), params=scene.params) for n in ("no_injection", "electrodes_only")}
    _simulate({"paper": scene, "no_injection": at["no_injection"], "electrodes": at["electrodes_only"]},
              n_series, seed, work, progress, workers)
    vib = _study("paper", ("injection",), work)
    vt = _study("no_injection", ("vibrotactile",), work)
    el = _study("electrodes", ELECTRODE_METHODS, work)
    scores = {**vib, **vt, **el}
    items = pattern_items(scores)
    return {**{k: scene.params["electrodes"][k] for k in ELECTRODE_GRID}, "objective": pattern_objective(items),
            "grid": [], "scores": scores, "items": {k: [bool(v[0]), v[1]] for k, v in items.items()}}

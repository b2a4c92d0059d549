"""Why the closed loop fails on the simulated rig: the estimate vs the pseudo label vs the truth.

Everything runs in this process on the simulated rig (`sim.Rig`), the shipped models
(`models/<method>.npz` via `estimator_core`) and the grip law (`control.next_force`); nothing in
the simulator, the models or the controller is changed. Per period it records the model's
estimate ŝ over the estimator node's 1.0 s window (this period and the previous one; period 0
is "filling" and the controller holds), the pseudo label a collection series would give at this
F_T, s_pseudo = clip(1 − F_T / F_T^slip) with F_T^slip the median slip force of the material's
training collection series (the `models` experiment's data set, labelled by `models.labels`),
and the simulator's true load ratio 1 − Q / (μ_s F_N) (`load_ratio_stick`).

Runs: (1) the closed loop of injection (scene paper) and E19 (scene electrodes_only) as in
`launch stabilize.yaml` (s_d 0.3, k 2, F_N from 2.9 kPa; the paper's protocol: ends at the F_N
limit or after all steps, judged on the end state); (2) the oracle loop (the same law on the true load ratio, scene paper) with both models
evaluated on its windows; (3) actuator held, F_N stepped 2 → 5 kPa at fixed F_T.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from incipient_slip import control
from incipient_slip.errors import UsageError

from . import closed_loop as loop
from .plots import METHOD_LABELS, pyplot, save
from .settings import Settings

NAME = "diagnosis"
HELP = "why the closed loop fails on the simulated rig: estimate vs pseudo label vs truth"
DOC = "stabilization.md"
SCENE_OF = {m: control.SCENE_OF_METHOD[m] for m in ("injection", "e19")}
QUICK = ("rig seed 0 only (full 0 and 5), every loop the full 450 steps, F_T at slip from the "
         "10-series data set (full 100)")
METHODS = tuple(SCENE_OF)
TRAINING_SEED, TRAINING_SERIES = 7, 100      # the shipped models' data set (experiments.models)


def add_arguments(parser) -> None:
    """Add the material, the rig seeds and the data-set cache."""
    parser.add_argument("--material", default="pla", help="material (default pla)")
    parser.add_argument("--seeds", help="rig seeds, comma separated (quick 0, full 0,5: the Table's "
                        "PLA runs)")
    parser.add_argument("--data", type=Path, metavar="DIR", help="data-set cache (default runs/data)")


def slip_force_stats(material: str, data_dir: Path) -> dict:
    """Return F_T^slip and the F_N at slip of one material's collection series ({"n_series": 0}
    when none of them slipped)."""
    from incipient_slip.models.dataset import load_series, series_paths
    from incipient_slip.models.labels import label_series
    ft, fn, k = [], [], []
    for p in series_paths(data_dir):
        s = load_series(p)
        if s.material != material:
            continue
        lab = label_series(s)
        if lab.gross_slip_index < 0:
            continue
        ft.append(lab.tangential_force_slip_n)
        fn.append(float(s.normal_force_kpa[lab.gross_slip_index]))
        k.append(lab.gross_slip_index)
    if not ft:
        return {"n_series": 0}
    ft, fn = np.array(ft), np.array(fn)
    return {"n_series": len(ft), "ft_slip_median_n": float(np.median(ft)),
            "ft_slip_q25_n": float(np.percentile(ft, 25)), "ft_slip_q75_n": float(np.percentile(ft, 75)),
            "fn_at_slip_median_kpa": float(np.median(fn)), "k_slip_median": float(np.median(k))}


def _estimates(models: dict, use) -> dict:
    """The estimator node's answer of each model in `use` for a window (`closed_loop.model_estimate`)."""
    return {m: loop.model_estimate(models[m]) for m in use}


def record(out, ests: dict, ft_slip: float, state=None) -> dict:
    """Return one period's record: forces, travel (and, given the rig's contact state, its split into
    slide, pad shear and interfacial part), true ratio, pseudo label and estimates."""
    split = {} if state is None else {"slide_mm": state.anchor_mm, "bulk_mm": state.bulk_mm,
                                       "interfacial_mm": state.interfacial_mm}
    return {"k": out.period, "fn_kpa": out.normal_force_kpa, "ft_n": out.tangential_force_n,
            "y_mm": out.object_y_mm, **split, "true": out.load_ratio_stick,
            "pseudo": float(np.clip(1.0 - out.tangential_force_n / ft_slip, 0.0, 1.0)),
            **{f"est_{m}": v for m, v in ests.items()}}


def closed_loop(method: str, material: str, seed: int, models: dict, ft_slip: float,
                steps: int = 450, oracle: bool = False) -> list[dict]:
    """Return the per-period records of one run of the paper's law (`closed_loop.run_loop`), driven
    by `method`'s estimate or (oracle) by the simulator's true load ratio; the oracle's records
    carry every model's estimate of its windows."""
    from incipient_slip.sim.rig import Rig
    from incipient_slip.sim.scene import load_scene
    rig = Rig(load_scene("paper" if oracle else SCENE_OF[method]), material, seed)
    ests = _estimates(models, METHODS if oracle else (method,))
    drive = loop.true_ratio if oracle else ests[method]
    rows, prev = [], None
    for period in loop.run_loop(rig, drive, rules=control.SupervisorRules(max_steps=steps)):
        out = period.out
        rows.append(record(out, {m: (period.estimate if not oracle and m == method else e(prev, out))
                                 for m, e in ests.items()}, ft_slip, rig.state))
        prev = out
    if period.verdict.ended:      # the paper's protocol: the F_N limit, or the end state after all steps
        fn = period.command_kpa
        rows[-1]["end"] = ("F_N at 6.0 kPa" if fn >= control.SAFETY_LIMIT_KPA - 1e-9 else
                           "y > 1.5 mm at the end" if period.travel_mm > control.FAILURE_TRAVEL_MM else "held")
    return rows


def force_step(material: str, seed: int, models: dict, ft_slip: float, target_true: float,
               n_hold: int = 6, max_load: int = 300) -> list[dict]:
    """Load the spring at 2 kPa until the true ratio falls below target_true, then hold the
    actuator: n_hold periods at 2 kPa, n_hold at 5 kPa (both models, scene paper)."""
    from incipient_slip.sim.rig import Rig
    from incipient_slip.sim.scene import load_scene
    rig = Rig(load_scene("paper"), material, seed)
    ests, rows = _estimates(models, METHODS), []
    for _ in range(max_load):
        prev = rig.step_period(2.0)
        if prev.load_ratio_stick < target_true:
            break
    for phase, fn in (("2 kPa", 2.0), ("5 kPa", 5.0)):
        for _ in range(n_hold):
            out = rig.step_period(fn, actuator_step=False)
            rows.append({**record(out, {m: e(prev, out) for m, e in ests.items()}, ft_slip), "phase": phase})
            prev = out
    return rows


def check(settings: Settings) -> list[int]:
    """Return the rig seeds of --seeds; UsageError if they are not integers."""
    try:
        return [int(s) for s in str(settings.option("seeds", settings.pick(quick="0", full="0,5"))).split(",")]
    except ValueError:
        raise UsageError(f"--seeds takes integers separated by commas, got {settings.option('seeds')!r}") from None


def run(settings: Settings) -> dict:
    """Run the loops, the oracle and the F_N step test; write the figures and per-period records."""
    from incipient_slip.models.estimator_core import default_model_path, limit_blas_threads, load_model

    from .datasets import study_datasets
    seeds = check(settings)
    material = settings.option("material", "pla")
    steps = control.MAX_STEPS      # quick too: the loops end as the full ones do
    limit_blas_threads(1)
    models = {m: load_model(method=m) for m in METHODS}
    data = study_datasets(settings, settings.pick(quick=10, full=TRAINING_SERIES),
                          450, seed=TRAINING_SEED, scenes=("paper",))["paper"]
    slip = slip_force_stats(material, data)
    if slip["n_series"] == 0:
        raise UsageError(f"no collection series of material {material!r} in {data}")
    ft_slip = slip["ft_slip_median_n"]
    res = {"material": material, "seeds": seeds, "slip": slip, "loops": {}, "oracle": {}, "step": {}}
    for seed in seeds:
        for m in METHODS:
            res["loops"][f"{m}/{seed}"] = closed_loop(m, material, seed, models, ft_slip, steps)
        res["oracle"][str(seed)] = closed_loop("injection", material, seed, models, ft_slip, steps, oracle=True)
        for tgt in (0.6, 0.3):
            res["step"][f"{seed}/{tgt}"] = force_step(material, seed, models, ft_slip, tgt,
                                                      max_load=300)
    records = settings.work / "diagnosis_records.json"
    records.parent.mkdir(parents=True, exist_ok=True)
    records.write_text(json.dumps(res, default=float) + "\n")
    plot(res, settings.figures / "stab_diagnosis.png")
    return {"material": material, "seeds": seeds, "slip": slip, "steps": steps,
            "models": {m: {"sha256": hashlib.sha256(default_model_path(m).read_bytes()).hexdigest(),
                           "training_data_hash": models[m].header.get("training_data_hash")}
                       for m in METHODS},
            **summarize(res)}


def _corr(rows, key, ref, diverged=False):
    """Return (correlation, RMSE) of ŝ with a reference; diverged: only periods where the
    pseudo label and the true ratio differ by > 0.1 (F_N above the F_N at which series slipped)."""
    a = np.array([(r[key], r[ref]) for r in rows if np.isfinite(r[key])
                  and (not diverged or abs(r["pseudo"] - r["true"]) > 0.1)])
    if len(a) < 3:
        return float("nan"), float("nan")
    return float(np.corrcoef(a[:, 0], a[:, 1])[0, 1]), float(np.sqrt(np.mean((a[:, 0] - a[:, 1]) ** 2)))


def _split(row: dict) -> list | None:
    """Return [slide, pad shear, interfacial] of a record's y in mm (None for records without it)."""
    return [row["slide_mm"], row["bulk_mm"], row["interfacial_mm"]] if "bulk_mm" in row else None


def _split_cell(split) -> str:
    return "–" if not split else " + ".join(f"{v:.2f}" for v in split)


def summarize(res: dict) -> dict:
    """Return the per-run numbers of the page's tables from the per-period records."""
    summary = {"loops": {}, "oracle": {}, "step": {}}
    for name, rows in res["loops"].items():
        m = name.split("/")[0]
        last = rows[-1]
        low = [r[f"est_{m}"] - r["true"] for r in rows if r["fn_kpa"] <= control.DEFAULT_MIN_FORCE_KPA + 1e-9
               and r["k"] >= 60]
        summary["loops"][name] = {
            "end": last.get("end", f"{len(rows)} steps"), "steps": len(rows), "fn": last["fn_kpa"],
            "y": last["y_mm"], "y_split": _split(last), "est_last": last[f"est_{m}"], "pseudo_last": last["pseudo"],
            "true_last": last["true"], "rmse_pseudo": _corr(rows, f"est_{m}", "pseudo")[1],
            "rmse_true": _corr(rows, f"est_{m}", "true")[1],
            "n_diverged": sum(abs(r["pseudo"] - r["true"]) > 0.1 for r in rows),
            "rmse_pseudo_div": _corr(rows, f"est_{m}", "pseudo", True)[1],
            "rmse_true_div": _corr(rows, f"est_{m}", "true", True)[1],
            "low_force_bias_vs_true": float(np.mean(low)) if low else float("nan")}
    for seed, rows in res["oracle"].items():
        late = [r for r in rows if r["k"] >= 100] or rows
        d = {"end": rows[-1].get("end", f"{len(rows)} steps"), "steps": len(rows), "fn": rows[-1]["fn_kpa"],
             "y": rows[-1]["y_mm"], "y_split": _split(rows[-1]), "true_late": float(np.mean([r["true"] for r in late])),
             "pseudo_late": float(np.mean([r["pseudo"] for r in late]))}
        for m in METHODS:
            d[f"est_{m}_late"] = float(np.nanmean([r[f"est_{m}"] for r in late]))
            d[f"rmse_{m}_pseudo"] = _corr(rows, f"est_{m}", "pseudo", diverged=True)[1]
            d[f"rmse_{m}_true"] = _corr(rows, f"est_{m}", "true", diverged=True)[1]
        summary["oracle"][seed] = d
    for name, rows in res["step"].items():
        summary["step"][name] = {ph: {k: float(np.mean([r[k] for r in rows if r["phase"] == ph][-4:]))
                                      for k in ("ft_n", "true", "pseudo", "est_injection", "est_e19")}
                                 for ph in ("2 kPa", "5 kPa")}
    return summary


# --- the page's blocks -----------------------------------------------------------------------

def _f(v, spec=".2f") -> str:
    return "–" if v is None or not np.isfinite(v) else format(v, spec)


def render(results: dict) -> dict[str, str]:
    """Return the diagnosis blocks of docs/stabilization.md (every number: simulated rig)."""
    s, mats = results["slip"], results["material"]
    setup = (f"{mats}, seeds {', '.join(map(str, results['seeds']))}, at most {results['steps']} steps "
             f"(simulated rig). Models: " + ", ".join(
                 f"`models/{m}.npz` sha256 {v['sha256'][:8]}…" for m, v in results["models"].items())
             + f". F_T^slip = {s['ft_slip_median_n']:.3f} N (median of the {s['n_series']} {mats} "
             f"training series, IQR {s['ft_slip_q25_n']:.3f}–{s['ft_slip_q75_n']:.3f} N); F_N at "
             f"slip: median {s['fn_at_slip_median_kpa']:.2f} kPa.")
    loops = ["| run (simulated rig) | end | steps | final F_N [kPa] | y [mm] | y = slide + pad shear + "
             "interfacial [mm] | ŝ / pseudo / true at the end "
             "| RMSE of ŝ vs pseudo / vs true where they differ by > 0.1 (periods) |",
             "|---|---|---|---|---|---|---|---|"]
    for name, d in results["loops"].items():
        m, seed = name.split("/")
        label = METHOD_LABELS[m].removesuffix(" (ours)")
        loops.append(f"| {label} loop, seed {seed} | {d['end']} | {d['steps']} | {_f(d['fn'])} | "
                     f"{_f(d['y'])} | {_split_cell(d.get('y_split'))} | {_f(d['est_last'])} / {_f(d['pseudo_last'])} / {_f(d['true_last'])} | "
                     f"{_f(d['rmse_pseudo_div'])} / {_f(d['rmse_true_div'])} ({d['n_diverged']}) |")
    for seed, d in results["oracle"].items():
        loops.append(f"| oracle, seed {seed} | {d['end']} | {d['steps']} | {_f(d['fn'])} | {_f(d['y'])} | "
                     f"{_split_cell(d.get('y_split'))} | "
                     f"mean k ≥ 100: ŝ injection {_f(d['est_injection_late'])}, E19 {_f(d['est_e19_late'])} "
                     f"/ {_f(d['pseudo_late'])} / {_f(d['true_late'])} | injection "
                     f"{_f(d['rmse_injection_pseudo'])} / {_f(d['rmse_injection_true'])}, E19 "
                     f"{_f(d['rmse_e19_pseudo'])} / {_f(d['rmse_e19_true'])} |")
    step = ["| seed, F_T | true ratio 2 → 5 kPa | pseudo label | ŝ injection 2 → 5 | ŝ E19 2 → 5 |",
            "|---|---|---|---|---|"]
    for name, d in results["step"].items():
        lo, hi = d["2 kPa"], d["5 kPa"]
        step.append(f"| {name.split('/')[0]}, {lo['ft_n']:.3f} N | {_f(lo['true'])} → {_f(hi['true'])} | "
                    f"{_f(lo['pseudo'])} | {_f(lo['est_injection'])} → {_f(hi['est_injection'])} | "
                    f"{_f(lo['est_e19'])} → {_f(hi['est_e19'])} |")
    return {"diagnosis-setup": setup, "diagnosis-loops": "\n".join(loops), "diagnosis-step": "\n".join(step)}


def plot(res: dict, path: Path) -> None:
    """Write the loop figure to `path` and the F_N step figure beside it (`*_step.png`)."""
    plt = pyplot()
    seed = str(res["seeds"][0])
    fig, ax = plt.subplots(2, 3, figsize=(15, 7.5), sharex="col")
    panels = [("injection", res["loops"][f"injection/{seed}"], "injection loop"),
              ("e19", res["loops"][f"e19/{seed}"], "E19 loop"),
              (None, res["oracle"][seed], "oracle loop (law on true ratio)")]
    for j, (m, rows, title) in enumerate(panels):
        k = [r["k"] for r in rows]
        a = ax[0, j]
        a.plot(k, [r["true"] for r in rows], "k-", lw=1.8, label="true load ratio 1 − Q/(μ_s F_N)")
        a.plot(k, [r["pseudo"] for r in rows], "C3--", lw=1.8, label="pseudo label 1 − F_T/F_T^slip (median)")
        for mm in ((m,) if m else METHODS):
            a.plot(k, [r[f"est_{mm}"] for r in rows], ".", ms=3, color="C0" if mm == "injection" else "C2",
                   label=f"ŝ {mm}")
        a.axhline(0.3, color="grey", lw=0.8, ls=":")
        a.set_ylim(-0.05, 1.05)
        a.set_title(f"{title}, {res['material']} seed {seed}")
        a.legend(fontsize=7, loc="lower left")
        b = ax[1, j]
        b.plot(k, [r["fn_kpa"] for r in rows], "C1-", label="F_N [kPa]")
        b.plot(k, [r["ft_n"] * 10 for r in rows], "C4-", label="F_T [N] × 10")
        b.plot(k, [r["y_mm"] for r in rows], "C5-", label="y [mm]")
        b.axhline(control.SAFETY_LIMIT_KPA, color="grey", lw=0.8, ls=":")
        b.set_xlabel("period k")
        b.legend(fontsize=7, loc="upper left")
    fig.suptitle("Simulated rig: injection's estimate follows the pseudo label (load progress), not the "
                 "true load ratio; E19's reads high at 1.1 kPa, where label and truth coincide", fontsize=11)
    save(fig, path)

    # F_N step figure
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
    for a, tgt in zip(ax, ("0.6", "0.3")):
        for s in res["seeds"]:
            rows = res["step"][f"{s}/{tgt}"]
            x = np.arange(len(rows))
            a.plot(x, [r["true"] for r in rows], "k-", lw=1.5, label="true" if s == res["seeds"][0] else None)
            a.plot(x, [r["pseudo"] for r in rows], "C3--", label="pseudo label" if s == res["seeds"][0] else None)
            a.plot(x, [r["est_injection"] for r in rows], "C0o-", ms=3, label="ŝ injection" if s == res["seeds"][0] else None)
            a.plot(x, [r["est_e19"] for r in rows], "C2s-", ms=3, label="ŝ E19" if s == res["seeds"][0] else None)
        n = len(rows) // 2
        a.axvline(n - 0.5, color="grey", ls=":")
        a.set_title(f"actuator held, F_N 2 → 5 kPa at period {n} (true s at 2 kPa < {tgt})", fontsize=9)
        a.set_xlabel("period after hold")
        a.legend(fontsize=7)
    fig.suptitle(f"Simulated rig ({res['material']}): estimate response to a step in F_N at fixed F_T", fontsize=10)
    save(fig, path.with_name(path.stem + "_step.png"))

"""Rig identification on the simulated rig in-process: hidden parameters recovered, and its pictures.

`slip reproduce identification` draws hidden parameter sets across their plausible ranges
(`hidden_set`), hides each in the simulated rig, runs the identification protocols in-process and
renders truth against identified into docs/identification.md ("How close"), with the pictures of
the first set (`identify.figures`, the ones the `identifier` node writes).

`identify_sim` drives `identify.run_protocol` (the same generator the `identifier` node runs
on rig:=sim, emulated or hardware) against `sim.Rig` directly, one `step_period` per period with
the commanded actuator position. Simulated rig, not a measurement.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from incipient_slip import identify

from .settings import Settings

NAME = "identification"
HELP = "rig identification on the simulated rig: hidden parameters recovered in-process"
DOC = "identification.md"
QUICK = "4 hidden sets (full 16)"
RESULTS = "identification_results.json"      # in docs/figures/: the page's numbers, for --render-only
SEED = 0

MECHANICS = ("contact", "stick_slip", "mocap")
# plausible ranges of the identified parameters (sim/params/default.yaml's sources)
HIDDEN_RANGES = {"pre_slip.bulk_shear_n_per_mm": (0.3, 0.8), "pre_slip.bulk_stiffening_exponent": (0.6, 1.4),
                 "stick_slip.friction_limit_lag_s": (0.0, 1.5), "mu": (0.4, 0.75)}


def hidden_set(seed: int) -> dict:
    """Return {parameter: value} drawn uniformly over HIDDEN_RANGES (mu: the material's own)."""
    rng = np.random.default_rng(seed)
    return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in HIDDEN_RANGES.items()}


def scene_with(hidden: dict, material: str = "pla", scene_name: str = "mechanics"):
    """Return the mechanics scene with the hidden values; mu is set as the material's identified mu."""
    from incipient_slip.sim.scene import load_scene, with_values

    scene = load_scene(scene_name)
    values = {tuple(k.split(".")): v for k, v in hidden.items() if k != "mu"}
    if "mu" in hidden:
        values[("materials", material)] = {**scene.params["materials"][material], "mu_identified": hidden["mu"]}
    return with_values(scene, values)


def identify_sim(scene, material: str, seed: int, plan: identify.Plan | None = None,
                 inputs: identify.Inputs | None = None) -> tuple[list, dict]:
    """Run the protocols on a simulated rig in-process; return (records, identify.analyze results)."""
    from incipient_slip.sim.rig import Rig

    plan = plan or identify.Plan()
    p = scene.params
    inputs = inputs or identify.Inputs(spring_n_per_mm=p["stick_slip"]["spring_n_per_mm"],
                                       newton_per_kpa=p["contact"]["newton_per_kpa"], material=material,
                                       rig=f"sim (scene {scene.name}, seed {seed})")
    rig = Rig(scene, material, seed)
    records: list = []
    gen = identify.run_protocol(plan, inputs, records)
    cmd = next(gen)
    while True:
        rig.state.actuator_mm = cmd.actuator_mm
        out = rig.step_period(cmd.normal_force_kpa, actuator_step=False)
        obs = identify.Observation(out.period, out.normal_force_kpa, out.actuator_mm,
                                   out.t_start_s + rig.period_s, out.mocap_t_s, out.mocap_y_mm)
        try:
            cmd = gen.send(obs)
        except StopIteration:
            break
    results = identify.analyze(records, inputs)
    results["truth"] = {"mu_series": float(rig.mu_s)}
    return records, results


def recovery_table(n_sets: int, first_seed: int = 0, material: str = "pla", figures=None) -> list[dict]:
    """Return per hidden set the truth and what the protocols identified (docs/identification.md);
    with `figures` (a directory) the first set's pictures go there."""
    import time

    rows = []
    for hs in range(first_seed, first_seed + n_sets):
        hidden = hidden_set(hs)
        t0 = time.perf_counter()
        records, res = identify_sim(scene_with(hidden, material), material, hs)
        st, lag = res["stiffness"], res["lag"]
        rows.append({"set": hs, "periods": len(records), "seconds": time.perf_counter() - t0,
                     "k_b": (hidden["pre_slip.bulk_shear_n_per_mm"], st.get("k_ref", math.nan)),
                     "beta": (hidden["pre_slip.bulk_stiffening_exponent"], st.get("beta", math.nan)),
                     "mu": (res["truth"]["mu_series"], st.get("mu", math.nan)),
                     "lag": (hidden["stick_slip.friction_limit_lag_s"], lag.get("tau_s", math.nan))})
        if figures is not None and hs == first_seed:
            from incipient_slip.identify.figures import figures as draw

            rows[-1]["figures"] = sorted(Path(v).name for v in draw(res, records, figures, stem=NAME).values())
    return rows


def largest_errors(rows: list[dict]) -> dict:
    """The largest error over the sets: k_b and mu relative, beta and the lag (s) absolute."""
    return {"k_b": max(abs(r["k_b"][1] / r["k_b"][0] - 1) for r in rows),
            "beta": max(abs(r["beta"][1] - r["beta"][0]) for r in rows),
            "mu": max(abs(r["mu"][1] / r["mu"][0] - 1) for r in rows),
            "lag": max(abs(r["lag"][1] - r["lag"][0]) for r in rows)}


def add_arguments(parser) -> None:
    parser.add_argument("--sets", type=int, help="hidden sets (default 16; quick 4)")


def run(settings: Settings) -> dict:
    n = settings.option("sets", settings.pick(quick=4, full=16))
    if n < 1:
        raise ValueError("--sets must be >= 1")
    settings.figures.mkdir(parents=True, exist_ok=True)
    rows = recovery_table(n, settings.seed, figures=settings.figures)
    return {"budget": settings.budget, "sets": n, "first_seed": settings.seed, "rows": rows,
            "largest": largest_errors(rows)}


def render(results: dict) -> dict[str, str]:
    """The recovery table: every hidden set's truth against what was identified, and the largest errors."""
    big = results["largest"]
    lines = [f"Hidden sets {results['first_seed']}..{results['first_seed'] + results['sets'] - 1} "
             f"(`slip reproduce identification`): the largest error over the {results['sets']} sets is "
             f"**k_b {100 * big['k_b']:.1f} %**, **beta {big['beta']:.3f}**, **mu {100 * big['mu']:.1f} %** "
             f"of the rig's own and **lag {big['lag']:.3f} s**.", "",
             "| set | periods | k_b true -> identified | beta | mu (rig's own) | lag [s] |", "|---|---|---|---|---|---|"]
    for r in results["rows"]:
        lines.append(f"| {r['set']} | {r['periods']} | " + " | ".join(
            f"{t:.3f} -> {v:.3f}" for t, v in (r["k_b"], r["beta"], r["mu"], r["lag"])) + " |")
    return {"identification-recovery": "\n".join(lines)}

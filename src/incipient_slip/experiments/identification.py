"""Rig identification on the simulated rig in-process, its pictures, and hidden-parameter recovery.

`identify_sim` drives `identify.run_protocol` (the same generator the `identifier` node runs
on rig:=sim, emulated or hardware) against `sim.Rig` directly, one `step_period` per period with
the commanded actuator position. `figures` draws one picture per protocol from the results
(identify.analyze), labelled with the rig they came from. `hidden_set` draws parameters other
than the defaults across their plausible ranges (the recovery tests and docs/identification.md).
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from incipient_slip import identify

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
    from incipient_slip.sim.scene import load_scene

    scene = load_scene(scene_name)
    params = {k: (dict(v) if isinstance(v, dict) else v) for k, v in scene.params.items()}
    params["materials"] = {m: dict(v) for m, v in params["materials"].items()}
    for key, value in hidden.items():
        if key == "mu":
            params["materials"][material]["mu_identified"] = value
            continue
        section, name = key.split(".")
        params[section][name] = value
    return dataclasses.replace(scene, params=params)


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
        obs = identify.Observation(out.period_index, out.normal_force_kpa, out.actuator_mm,
                                   out.t_start_s + rig.period_s, out.mocap_t_s, out.mocap_y_mm)
        try:
            cmd = gen.send(obs)
        except StopIteration:
            break
    results = identify.analyze(records, inputs)
    results["truth"] = {"mu_series": float(rig.mu_s)}
    return records, results


def figures(results: dict, records: list, out_dir: Path, stem: str = "identify") -> dict:
    """Draw y against the spring load per F_N level with the fitted lines, and the lag trials'
    slide onsets against the F_N step; return {protocol: path}."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rig, mat = results["inputs"]["rig"], results["inputs"]["material"]
    label = f"rig: {rig}; material {mat}" + (" (SIMULATED RIG)" if str(rig).startswith("sim") else "")
    paths = {}
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
            qq = np.array([0.3 * q.max(), q.max()])
            m = q >= 0.3 * q.max()
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
    fig.text(0.01, 0.01, label, fontsize=7)
    p = out_dir / f"{stem}_stiffness.png"
    fig.savefig(p, dpi=110, bbox_inches="tight")
    plt.close(fig)
    paths["stiffness"] = str(p)

    lag_recs = [r for r in records if r.phase in ("lag-hold", "lag-low", "lag-release")]
    if lag_recs:
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 4.5), sharex=True)
        trials = sorted({r.trial for r in lag_recs})
        for t in trials:
            rs = [r for r in lag_recs if r.trial == t]
            k0 = next((r.period for r in rs if r.phase == "lag-low"), rs[0].period)
            x = [(r.period - k0) * identify.PERIOD_S for r in rs]
            row = next((x for x in results["lag_trials"] if x["trial"] == t), {})
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
        fig.text(0.01, 0.01, label, fontsize=7)
        p = out_dir / f"{stem}_lag.png"
        fig.savefig(p, dpi=110, bbox_inches="tight")
        plt.close(fig)
        paths["lag"] = str(p)
    return paths

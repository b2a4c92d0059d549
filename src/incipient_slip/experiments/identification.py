"""Rig identification on the simulated rig in-process, its pictures, and hidden-parameter recovery.

`identify_sim` drives `identify.run_protocol` (the same generator the `identifier` node runs
on rig:=sim, emulated or hardware) against `sim.Rig` directly, one `step_period` per period with
the commanded actuator position. `hidden_set` draws parameters other
than the defaults across their plausible ranges (the recovery tests and docs/identification.md).
"""
from __future__ import annotations


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

    from .calibration import with_values

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
        obs = identify.Observation(out.period_index, out.normal_force_kpa, out.actuator_mm,
                                   out.t_start_s + rig.period_s, out.mocap_t_s, out.mocap_y_mm)
        try:
            cmd = gen.send(obs)
        except StopIteration:
            break
    results = identify.analyze(records, inputs)
    results["truth"] = {"mu_series": float(rig.mu_s)}
    return records, results


def recovery_table(n_sets: int, first_seed: int = 0, material: str = "pla") -> list[dict]:
    """Return per hidden set the truth and what the protocols identified (docs/identification.md)."""
    import math
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
    return rows


def main(argv=None) -> int:
    """Print the hidden-parameter recovery table on the simulated rig (in-process)."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m incipient_slip.experiments.identification",
        description="Draw hidden parameters across their plausible ranges, run the identification "
                    "protocols on the simulated rig in-process and print truth against identified "
                    "(docs/identification.md, 'How close'). Simulated rig, not a measurement.")
    parser.add_argument("--sets", type=int, default=16, help="hidden sets (default 16)")
    parser.add_argument("--first-seed", type=int, default=0, help="seed of the first set (default 0)")
    args = parser.parse_args(argv)
    if args.sets < 1:
        parser.error("--sets must be >= 1")
    rows = recovery_table(args.sets, args.first_seed)
    print("set | periods | s | k_b true -> id | beta true -> id | mu (rig's own) -> id | lag true -> id [s]")
    for r in rows:
        print(f"{r['set']:3d} | {r['periods']:5d} | {r['seconds']:.1f} | " + " | ".join(
            f"{t:.3f} -> {v:.3f}" for t, v in (r["k_b"], r["beta"], r["mu"], r["lag"])))
    err = {"k_b (relative)": max(abs(v / t - 1) for r in rows for t, v in [r["k_b"]]),
           "beta": max(abs(v - t) for r in rows for t, v in [r["beta"]]),
           "mu (relative)": max(abs(v / t - 1) for r in rows for t, v in [r["mu"]]),
           "lag [s]": max(abs(v - t) for r in rows for t, v in [r["lag"]])}
    print("largest error: " + ", ".join(f"{k} {v:.3f}" for k, v in err.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Writes tests/data/sim_series.json: a SHA-256 digest of every array of a set of simulated series
(data-collection series of each scene, material and several seeds, series written with views,
a parameter variant, and closed-loop runs that switch the PZT and hold the actuator), as the
simulator computed them when the file was written. The sensor arrays are quantized counts, which
a last-bit change of the float signal path would rarely change, so the file also holds digests of
that path's floats: the filter and electrode states after every period of the collection series
("... states") and the unquantized outputs of the signal path's functions on many inputs
("components").

    .venv/bin/python tests/data/make_sim_series.py tests/data/sim_series.json

tests/sim/test_dataset_and_cli.py asserts that this checkout computes the same digests: the
simulator's results stay the same bit for bit under speed work. Run this only when the physics
is meant to change, and say so in the commit."""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import sys

import numpy as np

from incipient_slip.sim import Rig, load_scene
from incipient_slip.sim.adc import pac_to_counts, to_uint12
from incipient_slip.sim.dataset import simulate_series
from incipient_slip.sim.electrodes import Electrodes, electrode_counts_mean
from incipient_slip.sim.fingertip_modes import mode_sos, mode_state
from incipient_slip.sim.pdc import pdc_counts
from incipient_slip.sim.protocols import collection_forces_kpa
from incipient_slip.sim.temperature import temperature_counts

STEPS = 450           # a whole series: stick, slides (split periods) and re-sticks
SCENES = ("paper", "no_injection", "electrodes_only", "mechanics")
VIEWS = ("no_injection", "electrodes_only", "mechanics")


def digest(a) -> str:
    a = np.asarray(a)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:24]


def _lagged(name: str):
    scene = load_scene(name)
    params = copy.deepcopy(scene.params)
    params["stick_slip"]["friction_limit_lag_s"] = 1.0
    params["electrodes"]["settling_time_s"] = 0.0
    return dataclasses.replace(scene, params=params)


def _states(scene, material: str, seed: int) -> dict:
    # the floats behind the counts, after every period: modal filter (and its PZT-absent twin's)
    # state, band and ambient filter states, the electrodes' settled counts and drift
    rig = Rig(scene, material, seed, pac_without_pzt=scene.has("injection") and scene.has("fingertip_modes"))
    parts = {"modes": lambda: rig.modes.zi, "twin": lambda: rig.filter_without_pzt.zi,
             "band": lambda: rig.band.zi, "ambient": lambda: rig.ambient.filter.zi,
             "settled": lambda: rig.electrodes.settled, "drift": lambda: rig.electrodes.drift}
    rows = {name: [] for name in parts}
    for fn in collection_forces_kpa(seed, STEPS):
        rig.step_period(float(fn))
        for name, get in parts.items():
            try:
                rows[name].append(np.array(get(), dtype=np.float64))
            except AttributeError:                  # the scene has no such effect
                pass
    return {name: np.stack(r) for name, r in rows.items() if r}


def _components() -> dict:
    # the signal path's functions on their own, unquantized, on many inputs (P_AC and slow counts
    # at and beside the rounding and clipping edges)
    p = load_scene("paper").params
    rng = np.random.default_rng(2026)
    out: dict = {}
    modes = p["fingertip_modes"]
    sos = []
    for a, sar, shear, damp in zip(rng.uniform(0, 8, 400), np.r_[rng.uniform(-0.2, 1.2, 396), 0.0, 1.0, 0.5, 1e-300],
                                   rng.normal(0, 0.3, 400), rng.uniform(0, 0.02, 400)):
        freq, zeta = mode_state(modes, float(a), float(sar), float(shear), float(damp))
        sos.append(np.concatenate([freq, zeta, mode_sos(modes, freq, zeta, 2200.0).ravel()]))
    out["modes"] = np.array(sos)
    ep = p["electrodes"]
    out["electrode_mean"] = np.array([electrode_counts_mean(ep, float(f), float(a), float(s)) for f, a, s in
                                      zip(rng.uniform(0, 8, 300), rng.uniform(0, 8, 300), rng.normal(0, 2, 300))])
    for tau in (ep["settling_time_s"], 0.0):
        el = Electrodes(dict(ep, settling_time_s=tau), np.random.default_rng(5), 50, 0.5)
        erng = np.random.default_rng(6)
        out[f"electrodes tau {tau}"] = np.concatenate(
            [el(erng, 50, float(f), float(a), float(s)) for f, a, s in
             zip(rng.uniform(0, 8, 70), rng.uniform(0, 8, 70), rng.normal(0, 2, 70))])
    prng = np.random.default_rng(7)
    out["pdc"] = np.concatenate([pdc_counts(prng, 50, float(f), p["pdc"], p["adc"]["pdc_pa_per_count"])
                                 for f in rng.uniform(0, 8, 100)])
    out["temperature"] = np.concatenate([np.concatenate(temperature_counts(prng, 50, p["temperature"]))
                                         for _ in range(100)])
    pa, lim = p["adc"]["pac_pa_per_count"], p["adc"]["pac_range_pa"]
    edges = np.r_[np.arange(-2100, 2100) + 0.5, np.arange(-2100, 2100)] * pa
    x = np.r_[edges, np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf), rng.normal(0, 400, 20000), 0.0, -0.0]
    out["pac_counts"] = pac_to_counts(x, pa, lim)
    slow = np.r_[np.arange(-3, 4100) + 0.5, np.arange(-3, 4100), rng.uniform(-100, 4200, 10000)]
    slow = np.r_[slow, np.nextafter(slow, np.inf), np.nextafter(slow, -np.inf)]
    out["uint12"] = to_uint12(slow[:len(slow) // 22 * 22].reshape(-1, 22), 4095)
    return out


def _closed_loop(material: str, seed: int) -> dict:
    # the rig_sim node's and the closed loop's use: F_N from a rule, the PZT switched and its
    # intensity changed, the actuator held some periods
    rig = Rig(load_scene("paper"), material, seed)
    outs = []
    for k in range(300):
        if k % 37 == 0:
            rig.set_injection(k % 74 != 0, -6.0 + (k % 5))
        fn = 1.1 + 0.02 * k if k < 150 else max(0.5, 4.0 - 0.03 * (k - 150))
        outs.append(rig.step_period(fn, actuator_step=k % 11 != 0))
    res = {}
    for field in dataclasses.fields(outs[0]):
        values = [getattr(o, field.name) for o in outs]
        res[field.name] = (np.concatenate(values) if isinstance(values[0], np.ndarray)
                           else np.array(values))
    return res


def cases() -> dict[str, dict]:
    """Return {case: {array name: its arrays}}."""
    out = {}
    for name in SCENES:
        scene = load_scene(name)
        for i, material in enumerate(scene.materials):
            for seed in (3 + i, 1000 + 7 * i):
                out[f"{name} {material} {seed}"] = simulate_series(scene, material, seed, STEPS)
    for source in (load_scene("paper"), _lagged("paper")):
        views = [load_scene(v) if source.name == "paper" and source.params == load_scene("paper").params
                 else _lagged(v) for v in VIEWS]
        tag = "default" if source.params == load_scene("paper").params else "lagged"
        for material, seed in (("pla", 5), ("tpu", 77)):
            for view, data in zip(("paper",) + VIEWS, simulate_series(source, material, seed, STEPS, views)):
                out[f"views {tag} {view} {material} {seed}"] = data
    for material, seed in (("abs", 11), ("tpu", 12)):
        out[f"closed loop {material} {seed}"] = _closed_loop(material, seed)
    for name in ("paper", "no_injection", "electrodes_only"):
        for material, seed in (("pla", 21), ("nylon", 22)):
            out[f"{name} {material} {seed} states"] = _states(load_scene(name), material, seed)
    out["components"] = _components()
    return out


def digests() -> dict[str, dict[str, str]]:
    return {case: {k: digest(v) for k, v in sorted(arrays.items())} for case, arrays in cases().items()}


if __name__ == "__main__":
    with open(sys.argv[1], "w") as f:
        json.dump(digests(), f, indent=1, sort_keys=True)
        f.write("\n")

"""Writes tests/data/sim_series.json: a SHA-256 digest of every array of a set of simulated series
(data-collection series of each scene, material and several seeds, series written with views,
a parameter variant, and closed-loop runs that switch the PZT and hold the actuator), as the
simulator computed them when the file was written.

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
from incipient_slip.sim.dataset import simulate_series

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
    return out


def digests() -> dict[str, dict[str, str]]:
    return {case: {k: digest(v) for k, v in sorted(arrays.items())} for case, arrays in cases().items()}


if __name__ == "__main__":
    with open(sys.argv[1], "w") as f:
        json.dump(digests(), f, indent=1, sort_keys=True)
        f.write("\n")

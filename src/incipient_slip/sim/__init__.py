"""The simulated rig: contact, stick-slip, vibration propagation and sensors, driven by scenes.

Public API: `Rig`, `PeriodOutput`, `load_scene`, `Scene`, `SceneError`, `SimulationError`,
`series_seed`; protocols in `sim.protocols`, data sets in `sim.dataset`.

The names load on first use (PEP 562): importing a light module of the package (`sim.adc`
for `slip bag`, `sim.cli` for `slip --help`) does not import the simulator, scipy and numba.
"""
from __future__ import annotations

import importlib

__all__ = ["PeriodOutput", "Rig", "Scene", "SceneError", "SimulationError", "load_scene", "series_seed"]

_HOME = {"PeriodOutput": "rig", "Rig": "rig", "series_seed": "rig", "Scene": "scene", "SceneError": "scene",
         "load_scene": "scene", "SimulationError": "stick_slip"}


def __getattr__(name: str):
    if name in _HOME:
        return getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

"""The simulated rig: contact, stick-slip, vibration propagation and sensors, driven by scenes.

Public API: `Rig`, `PeriodOutput`, `load_scene`, `Scene`, `SceneError`, `SimulationError`,
`series_seed`; protocols in `sim.protocols`, data sets in `sim.dataset`.
"""
from .rig import PeriodOutput, Rig, series_seed
from .scene import Scene, SceneError, load_scene
from .stick_slip import SimulationError

__all__ = ["PeriodOutput", "Rig", "Scene", "SceneError", "SimulationError", "load_scene", "series_seed"]

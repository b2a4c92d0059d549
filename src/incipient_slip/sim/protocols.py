"""Experiment protocols that drive a Rig: data collection (F_N redrawn each period) and closed loop.

Both call `Rig.step_period` once per 500 ms period, exactly as the rig_sim node does.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Iterator

import numpy as np

if TYPE_CHECKING:          # the draws alone (force_schedule on a lab PC) need no simulator, scipy or numba
    from .rig import PeriodOutput, Rig

# 1.1, 1.5, ..., 5.9 kPa (13 values, paper)
COLLECTION_FORCES_KPA = np.round(np.arange(1.1, 5.9 + 1e-9, 0.4), 1)
PROTOCOL_STREAM = 0x5EED  # spawn key of the protocol's own random stream


def protocol_rng(seed: int) -> np.random.Generator:
    """Return the protocol's random stream for a series seed (independent of the rig's streams)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(PROTOCOL_STREAM,)))


def collection_forces_kpa(seed: int, steps: int) -> np.ndarray:
    """Return the F_N of each period for data collection: uniform draws from 1.1, 1.5, ..., 5.9 kPa."""
    return protocol_rng(seed).choice(COLLECTION_FORCES_KPA, size=steps)


def run_collection(rig: Rig, steps: int = 450) -> Iterator[PeriodOutput]:
    """Yield the periods of one data-collection series (the paper's protocol)."""
    for fn in collection_forces_kpa(rig.seed, steps):
        yield rig.step_period(float(fn))


def run_closed_loop(rig: Rig, controller: Callable[[PeriodOutput | None], float], steps: int = 450,
                    stop: Callable[[PeriodOutput], bool] | None = None) -> Iterator[PeriodOutput]:
    """Yield periods where F_N comes from `controller(last_output)` (None before the first period);
    ends after `steps` periods or when `stop(output)` is True."""
    last = None
    for _ in range(steps):
        last = rig.step_period(float(controller(last)))
        yield last
        if stop is not None and stop(last):
            return


def run_constant(rig: Rig, normal_force_kpa: float, steps: int = 450) -> Iterator[PeriodOutput]:
    """Yield periods at a constant F_N (no control)."""
    return run_closed_loop(rig, lambda _: normal_force_kpa, steps)

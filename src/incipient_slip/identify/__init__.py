"""Rig identification: the protocols that measure what the simulator cannot know, and their fit.

* `identify.protocol`: `Plan`, `Inputs`, what a period shows (`Observation`, `Record`) and
  `run_protocol`, the one generator every rig runs (docs/identification.md, "The protocols");
* `identify.windows`: which mocap and F_N samples make a period on a lock-step or a real-time
  rig (`PeriodWindows`, pure: the `identifier` node feeds it);
* `identify.fit`: k_b(F_N), beta, mu, the lag and the no-action check (`analyze`);
* `identify.overlay`: the params overlay and the files a run writes (`write_outputs`);
* `identify.figures`: the pictures (matplotlib, imported on use).

The names below are the package's API (`from incipient_slip import identify; identify.Plan`).
Layering: imports `models.labels` (the paper's gross-slip rule), `control` (the safety limit) and
`messages` (the period); imported by `nodes.identifier` and `experiments`.
"""
from __future__ import annotations

from .fit import analyze, fit_lag, fit_stiffness, lag_trials, no_action_result, stiffness_levels, t95
from .overlay import UNBOUNDED, overlay, write_outputs
from .protocol import (PERIOD_S, Command, IdentificationError, Inputs, Observation, Plan, Protocol, Record,
                       ramp_slid, read_period, run_protocol, spring_load_n)
from .windows import PeriodWindows, WindowRetry

__all__ = ["PERIOD_S", "UNBOUNDED", "Command", "IdentificationError", "Inputs", "Observation", "PeriodWindows",
           "Plan", "Protocol", "Record", "WindowRetry", "analyze", "fit_lag", "fit_stiffness", "lag_trials",
           "no_action_result", "overlay", "ramp_slid", "read_period", "run_protocol", "spring_load_n",
           "stiffness_levels", "t95", "write_outputs"]

"""The paper's closed loop in this process, with the period semantics of `launch stabilize.yaml` in lock-step.

Period k runs on the simulated rig at F_N(k) (`sim.protocols.run_closed_loop`, one
`Rig.step_period` per period as rig_sim does). The estimate of the 1.0 s window ending at the
period's end (this period and the previous one; period 0 is "filling" and the controller holds)
drives F_N(k+1) through the controller's own law (`control.next_force`), and the supervisor's
own rule (`control.judge_step`) judges the period on the travel of its last mocap pose (what the
supervisor reads; the true y without mocap) and the force just commanded. Validation and diagnosis run their loops here; tests/experiments/test_closed_loop.py
holds one run equal, period by period, to the run summary of the node graph.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from incipient_slip import control

# estimate(previous period or None, this period) -> stick ratio (nan: no usable estimate)
Estimate = Callable[[object, object], float]


@dataclass(frozen=True)
class LoopPeriod:
    """One period of a closed-loop run: what the rig did and what the loop answered."""

    step: int                  # periods done, 1-based (the supervisor's count)
    out: object                # the rig's `PeriodOutput`
    force_kpa: float           # F_N applied in this period
    travel_mm: float           # y of the period's last mocap pose, as the supervisor judges it
    estimate: float            # the stick ratio that drove the answer (nan: held or no action)
    command_kpa: float         # F_N commanded for the next period
    hold: bool                 # the answer held the force (no usable estimate)
    verdict: control.Verdict   # the supervisor's verdict after this period (kind "" = goes on)


def raw_window(prev, out, stream: str) -> np.ndarray:
    """Return the estimator node's 1.0 s window: the last two periods of the model's stream."""
    if stream == "pac":
        return np.concatenate([prev.pac_counts, out.pac_counts])
    return np.concatenate([prev.electrode_counts, out.electrode_counts])


def model_estimate(model) -> Estimate:
    """The estimator node's answer from a loaded model: nan while the window fills (period 0)."""
    from incipient_slip.models.estimator_core import estimate_window

    def estimate(prev, out) -> float:
        return math.nan if prev is None else estimate_window(model, raw_window(prev, out, model.spec.stream))
    return estimate


def true_ratio(prev, out) -> float:
    """The oracle: the simulator's true load ratio 1 - Q / (mu_s F), which no sensor measures."""
    return out.load_ratio_stick


def measured_travel_mm(out) -> float:
    """Return the travel the supervisor judges: the period's last mocap pose (true y without mocap)."""
    return float(out.mocap_y_mm[-1]) if out.mocap_y_mm is not None and len(out.mocap_y_mm) else out.object_y_mm


def run_loop(rig, estimate: Estimate | None, params: control.ControlParams = control.ControlParams(),
             rules: control.SupervisorRules = control.SupervisorRules(),
             initial_force_kpa: float = control.DEFAULT_INITIAL_FORCE_KPA) -> Iterator[LoopPeriod]:
    """Yield the periods of one run until the supervisor's verdict ends it (or `rules.max_steps`).

    `estimate` None is the paper's "no action": F_N stays where it started and no hold counts."""
    from incipient_slip.sim.protocols import run_closed_loop

    force = float(initial_force_kpa)
    prev, holds, verdict = None, 0, control.Verdict()
    periods = run_closed_loop(rig, lambda _last: force, rules.max_steps, stop=lambda _out: verdict.ended)
    for step, out in enumerate(periods, start=1):
        applied = force
        if estimate is None:
            s, hold = math.nan, False
        else:
            s = float(estimate(prev, out))
            decision = control.next_force(force, s, params, problem=control.Problem()
                                          if math.isfinite(s) else control.Problem("estimate_invalid", "filling"))
            force, hold = decision.normal_force_kpa, decision.hold
            holds = holds + 1 if hold else 0
        prev = out
        travel = measured_travel_mm(out)
        verdict = control.judge_step(step, travel, force, holds, rules)
        yield LoopPeriod(step, out, applied, travel, s, force, hold, verdict)

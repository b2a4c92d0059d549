"""The grip law: pure functions of the estimate and the last force, no state, no clock.

The paper (eq. "action") changes the normal force each sampling period by a(s) = k (s - s_d).
We apply it with the sign that makes a *lower* stick ratio *raise* the normal force:

    F_N[k+1] = clamp(F_N[k] - a(s_k), F_min, F_max),  a(s) = k (s - s_d),  k > 0

rate limited to ``max_step_kpa`` per period and clamped so F_N never exceeds the safety limit
(6.0 kPa, RIG.md). An estimate that is missing, stale, marked invalid, NaN, outside [0, 1], of
another period or of another method never moves the force: the controller holds the last safe
force and says why (``hold=True``, a ``cause`` of the closed set `GRIP_CAUSES` and a ``reason``
for people). :func:`applied_force` is the clamp of the node that moves the hardware.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from incipient_slip.messages import GRIP_CAUSES

SAFETY_LIMIT_KPA = 6.0          # paper: failure when F_N > 6.0 kPa (the robot's safety limit)
FAILURE_TRAVEL_MM = 1.5         # paper: failure when y > 1.5 mm (mean travel at gross slip)
MAX_STEPS = 450                 # paper: 23 mm in 450 actuator steps, one per period
DEFAULT_TARGET_STICK_RATIO = 0.3
# Chosen once on the simulated rig for the injection method and used for every method
# (docs/stabilization.md, "Choice of k"): kPa of normal-force change per unit of stick-ratio
# error per 500 ms period.
DEFAULT_GAIN_KPA = 2.0
DEFAULT_MAX_STEP_KPA = 0.5      # rate limit per period (the collection grid moved 0.4 kPa steps)
DEFAULT_INITIAL_FORCE_KPA = 2.9  # paper: "no action" ends at 2.94 kPa, i.e. the initial grip
DEFAULT_MIN_FORCE_KPA = 1.1     # lowest F_N of the paper's collection grid: contact is kept

# The simulated scene each closed-loop method runs on: the PZT on only for injection, no
# vibration path for the electrode methods, mechanics only for no action (the rig's physics
# streams are the same). The one table: rig_sim and emulated_rig read it (scene:="" follows
# method:=, as stabilize.yaml and collect.yaml leave it) and so do the experiments.
SCENE_OF_METHOD = {"injection": "paper", "vibrotactile": "no_injection", "e19": "electrodes_only",
                   "e10": "electrodes_only", "e4": "electrodes_only", "e1": "electrodes_only",
                   "none": "mechanics"}


def scene_of(scene: str, method: str) -> str:
    """`scene`, or when it is "" the scene of `method` (SCENE_OF_METHOD); ValueError for an
    unknown method."""
    if scene:
        return scene
    if method not in SCENE_OF_METHOD:
        raise ValueError(f"no scene for method {method!r} (known: {', '.join(SCENE_OF_METHOD)}); "
                         f"name one with scene:=")
    return SCENE_OF_METHOD[method]


@dataclass(frozen=True)
class ControlParams:
    """Parameters of the grip law; forces in kPa of P_DC (the paper's F_N unit)."""

    target_stick_ratio: float = DEFAULT_TARGET_STICK_RATIO
    gain_kpa: float = DEFAULT_GAIN_KPA
    max_step_kpa: float = DEFAULT_MAX_STEP_KPA
    min_force_kpa: float = DEFAULT_MIN_FORCE_KPA
    max_force_kpa: float = SAFETY_LIMIT_KPA
    safety_limit_kpa: float = SAFETY_LIMIT_KPA

    def __post_init__(self):
        checks = {
            "target_stick_ratio": 0.0 <= self.target_stick_ratio <= 1.0,
            "gain_kpa": math.isfinite(self.gain_kpa) and self.gain_kpa >= 0.0,
            "max_step_kpa": math.isfinite(self.max_step_kpa) and self.max_step_kpa > 0.0,
            "min_force_kpa": 0.0 <= self.min_force_kpa <= self.max_force_kpa,
            "max_force_kpa": self.max_force_kpa <= self.safety_limit_kpa,
            "safety_limit_kpa": math.isfinite(self.safety_limit_kpa) and self.safety_limit_kpa > 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"ControlParams: invalid {', '.join(bad)} in {self!r} "
                             f"(need 0<=s_d<=1, k>=0, step>0, 0<=min<=max<=safety limit)")


@dataclass(frozen=True)
class Problem:
    """Why an estimate must not drive the force: a cause of `GRIP_CAUSES` (what code switches
    on) and the text for people. Falsy when there is none (the estimate is usable)."""

    cause: str = ""
    text: str = ""

    def __post_init__(self):
        if self.cause and self.cause not in GRIP_CAUSES:
            raise ValueError(f"Problem: cause {self.cause!r} is not one of {GRIP_CAUSES}")

    def __bool__(self) -> bool:
        return bool(self.cause)


NO_PROBLEM = Problem()


@dataclass(frozen=True)
class ControlDecision:
    """The force to command for the next period, and whether it is a hold (with its cause of
    `GRIP_CAUSES` and the reason in words)."""

    normal_force_kpa: float
    hold: bool
    reason: str = ""
    cause: str = "law"


def action(stick_ratio: float, target_stick_ratio: float, gain_kpa: float) -> float:
    """The paper's a(s) = k (s - s_d) in kPa; the force changes by -a (low s raises F_N)."""
    return gain_kpa * (stick_ratio - target_stick_ratio)


def clamp_force(force_kpa: float, params: ControlParams) -> float:
    """The force limited to [min_force, max_force]; never above the safety limit, never NaN."""
    if not math.isfinite(force_kpa):
        raise ValueError(f"clamp_force: non-finite force {force_kpa!r}")
    return min(max(force_kpa, params.min_force_kpa), params.max_force_kpa)


def problem_of(stick_ratio, valid: bool = True, period: int | None = None,
               expected_period: int | None = None, method: str | None = None,
               expected_method: str | None = None) -> Problem:
    """Why an estimate must not drive the force (`NO_PROBLEM`, falsy, when it is usable).

    Rejects: marked invalid, not a number, NaN/inf, outside [0, 1], a period other than the one
    being answered, a method other than the controller's.
    """
    if not valid:
        return Problem("estimate_invalid", "estimate marked invalid")
    if isinstance(stick_ratio, bool) or not isinstance(stick_ratio, (int, float)):
        return Problem("estimate_not_finite", f"stick ratio is not a number ({type(stick_ratio).__name__})")
    if not math.isfinite(stick_ratio):
        return Problem("estimate_not_finite", f"stick ratio {stick_ratio} is not finite")
    if not 0.0 <= stick_ratio <= 1.0:
        return Problem("estimate_out_of_range", f"stick ratio {stick_ratio:.4g} outside [0, 1]")
    if expected_period is not None and period != expected_period:
        return Problem("estimate_other_period", f"estimate for period {period}, expected {expected_period}")
    if expected_method is not None and method != expected_method:
        return Problem("estimate_other_method", f"estimate of method {method!r}, controller runs {expected_method!r}")
    return NO_PROBLEM


def estimate_problem(stick_ratio, valid: bool = True, period: int | None = None,
                     expected_period: int | None = None, method: str | None = None,
                     expected_method: str | None = None) -> str:
    """The text of :func:`problem_of` ("" when the estimate is usable)."""
    return problem_of(stick_ratio, valid, period, expected_period, method, expected_method).text


def hold(current_force_kpa: float, reason: str, params: ControlParams,
         cause: str = "stale_estimate") -> ControlDecision:
    """Keep the last safe force (clamped, in case the caller's force was never safe)."""
    return ControlDecision(clamp_force(current_force_kpa, params), True, reason, cause)


def next_force(current_force_kpa: float, stick_ratio, params: ControlParams,
               problem: Problem | str = "") -> ControlDecision:
    """The decision for one period: the law on a usable estimate, otherwise a hold.

    `problem` is the caller's reason the estimate is unusable (stale, wrong period, ...; a
    :class:`Problem`, or text alone, whose cause is then "unknown"); the stick ratio is checked
    here as well, so a bad number can never ramp the force.
    """
    if isinstance(problem, str):
        problem = Problem("unknown", problem) if problem else NO_PROBLEM
    problem = problem or problem_of(stick_ratio)
    if problem:
        return hold(current_force_kpa, problem.text, params, problem.cause)
    current = clamp_force(current_force_kpa, params)
    change = -action(float(stick_ratio), params.target_stick_ratio, params.gain_kpa)
    change = min(max(change, -params.max_step_kpa), params.max_step_kpa)
    return ControlDecision(clamp_force(current + change, params), False, "", "law")


def applied_force(command_kpa: float, current_kpa: float, limit_kpa: float = SAFETY_LIMIT_KPA,
                  max_step_kpa: float = math.inf) -> float:
    """The force a node that moves the hardware applies for a command: at most `max_step_kpa` from
    the current force (the law's own rate limit, kept where the force is applied), within [0, limit].

    The second line of defence (the controller limits first): a non-finite command keeps the
    current force.
    """
    if not math.isfinite(command_kpa):
        return min(max(current_kpa, 0.0), limit_kpa)
    # a hair of slack: the controller's own steps of exactly max_step pass unchanged
    if math.isfinite(current_kpa) and abs(command_kpa - current_kpa) > max_step_kpa * (1.0 + 1e-9):
        command_kpa = min(max(command_kpa, current_kpa - max_step_kpa), current_kpa + max_step_kpa)
    return min(max(command_kpa, 0.0), limit_kpa)

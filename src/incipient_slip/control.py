"""Grip control law, supervisor rules and the paper's score: pure functions, no sockets.

The paper (eq. "action") changes the normal force each sampling period by a(s) = k (s - s_d).
We apply it with the sign that makes a *lower* stick ratio *raise* the normal force:

    F_N[k+1] = clamp(F_N[k] - a(s_k), F_min, F_max),  a(s) = k (s - s_d),  k > 0

rate limited to ``max_step_kpa`` per period and clamped so F_N never exceeds the safety limit
(6.0 kPa, RIG.md). An estimate that is missing, stale, marked invalid, NaN, outside [0, 1], of
another period or of another method never moves the force: the controller holds the last safe
force and says why (``hold=True``, ``reason``).

The supervisor's rules (:func:`judge_step`) end a run on the paper's failure conditions
(y > 1.5 mm; F_N reaching the 6.0 kPa safety limit), on a fault (repeated holds: the estimate
stream is gone) or after 450 steps (success). The score is the paper's eq. "reward",
(w1 + success rate)(w2 / y + w3 / F_N) with (w1, w2, w3) = (0.1, 10, 1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from incipient_slip.errors import EXIT_FAILURE, EXIT_FAULT, EXIT_SUCCESS

SAFETY_LIMIT_KPA = 6.0          # paper: failure when F_N > 6.0 kPa (the robot's safety limit)
FAILURE_TRAVEL_MM = 1.5         # paper: failure when y > 1.5 mm (mean travel at gross slip)
MAX_STEPS = 450                 # paper: 23 mm in 450 actuator steps, one per period
SCORE_WEIGHTS = (0.1, 10.0, 1.0)
DEFAULT_TARGET_STICK_RATIO = 0.3
# Chosen once on the simulated rig for the injection method and used for every method
# (docs/stabilization.md, "Choice of k"): kPa of normal-force change per unit of stick-ratio
# error per 500 ms period.
DEFAULT_GAIN_KPA = 2.0
DEFAULT_MAX_STEP_KPA = 0.5      # rate limit per period (the collection grid moved 0.4 kPa steps)
DEFAULT_INITIAL_FORCE_KPA = 2.9  # paper: "no action" ends at 2.94 kPa, i.e. the initial grip
DEFAULT_MIN_FORCE_KPA = 1.1     # lowest F_N of the paper's collection grid: contact is kept


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
class ControlDecision:
    """The force to command for the next period, and whether it is a hold (with the reason)."""

    normal_force_kpa: float
    hold: bool
    reason: str = ""


def action(stick_ratio: float, target_stick_ratio: float, gain_kpa: float) -> float:
    """The paper's a(s) = k (s - s_d) in kPa; the force changes by -a (low s raises F_N)."""
    return gain_kpa * (stick_ratio - target_stick_ratio)


def clamp_force(force_kpa: float, params: ControlParams) -> float:
    """The force limited to [min_force, max_force]; never above the safety limit, never NaN."""
    if not math.isfinite(force_kpa):
        raise ValueError(f"clamp_force: non-finite force {force_kpa!r}")
    return min(max(force_kpa, params.min_force_kpa), params.max_force_kpa)


def estimate_problem(stick_ratio, valid: bool = True, period: int | None = None,
                     expected_period: int | None = None, method: str | None = None,
                     expected_method: str | None = None) -> str:
    """Why an estimate must not drive the force ("" when it is usable).

    Rejects: marked invalid, not a number, NaN/inf, outside [0, 1], a period other than the one
    being answered, a method other than the controller's.
    """
    if not valid:
        return "estimate marked invalid"
    if isinstance(stick_ratio, bool) or not isinstance(stick_ratio, (int, float)):
        return f"stick ratio is not a number ({type(stick_ratio).__name__})"
    if not math.isfinite(stick_ratio):
        return f"stick ratio {stick_ratio} is not finite"
    if not 0.0 <= stick_ratio <= 1.0:
        return f"stick ratio {stick_ratio:.4g} outside [0, 1]"
    if expected_period is not None and period != expected_period:
        return f"estimate for period {period}, expected {expected_period}"
    if expected_method is not None and method != expected_method:
        return f"estimate of method {method!r}, controller runs {expected_method!r}"
    return ""


def hold(current_force_kpa: float, reason: str, params: ControlParams) -> ControlDecision:
    """Keep the last safe force (clamped, in case the caller's force was never safe)."""
    return ControlDecision(clamp_force(current_force_kpa, params), True, reason)


def next_force(current_force_kpa: float, stick_ratio, params: ControlParams,
               problem: str = "") -> ControlDecision:
    """The decision for one period: the law on a usable estimate, otherwise a hold.

    `problem` is the caller's reason the estimate is unusable (stale, wrong period, ...);
    the stick ratio is checked here as well, so a bad number can never ramp the force.
    """
    problem = problem or estimate_problem(stick_ratio)
    if problem:
        return hold(current_force_kpa, problem, params)
    current = clamp_force(current_force_kpa, params)
    change = -action(float(stick_ratio), params.target_stick_ratio, params.gain_kpa)
    change = min(max(change, -params.max_step_kpa), params.max_step_kpa)
    return ControlDecision(clamp_force(current + change, params), False, "")


# --- supervisor ----------------------------------------------------------------------------

@dataclass(frozen=True)
class SupervisorRules:
    """When a run ends (paper: y > 1.5 mm or F_N > 6.0 kPa fails; 450 steps succeed)."""

    max_travel_mm: float = FAILURE_TRAVEL_MM
    safety_limit_kpa: float = SAFETY_LIMIT_KPA
    max_steps: int = MAX_STEPS
    max_consecutive_holds: int = 3
    end_on_failure: bool = True   # False for "no action": run all steps, report the final y


@dataclass(frozen=True)
class Verdict:
    """The end of a run: kind is "success", "failure" or "fault"; empty kind = keep going."""

    kind: str = ""
    detail: str = ""

    @property
    def ended(self) -> bool:
        return bool(self.kind)


EXIT_CODES = {"success": EXIT_SUCCESS, "failure": EXIT_FAILURE, "fault": EXIT_FAULT}


def judge_step(steps_done: int, travel_mm: float, force_kpa: float, consecutive_holds: int,
               rules: SupervisorRules) -> Verdict:
    """The supervisor's verdict after a completed step (faults and failures before success).

    A force *at* the safety limit counts as a failure: the controller clamps at the limit, so
    reaching it is the paper's "the stabilization continues until F_N reaches a safety limit".
    """
    if consecutive_holds >= rules.max_consecutive_holds:
        return Verdict("fault", f"{consecutive_holds} consecutive holds: no usable estimate")
    if not (math.isfinite(travel_mm) and math.isfinite(force_kpa)):
        return Verdict("fault", f"non-finite measurement y={travel_mm} F_N={force_kpa}")
    if rules.end_on_failure:
        if travel_mm > rules.max_travel_mm:
            return Verdict("failure", f"y = {travel_mm:.3f} mm > {rules.max_travel_mm} mm (gross slip)")
        if force_kpa >= rules.safety_limit_kpa - 1e-9:
            return Verdict("failure", f"F_N = {force_kpa:.3f} kPa reached the safety limit "
                                      f"{rules.safety_limit_kpa} kPa")
    if steps_done >= rules.max_steps:
        ok = travel_mm <= rules.max_travel_mm and force_kpa < rules.safety_limit_kpa - 1e-9
        return (Verdict("success", f"{steps_done} steps without failure") if ok else
                Verdict("failure", f"{steps_done} steps; final y = {travel_mm:.3f} mm, "
                                   f"F_N = {force_kpa:.3f} kPa"))
    return Verdict()


# --- score ---------------------------------------------------------------------------------

def score(success_rate: float, travel_mm: float, force_kpa: float,
          weights: tuple[float, float, float] = SCORE_WEIGHTS) -> float:
    """The paper's achievement score (w1 + success)(w2 / y + w3 / F_N); higher is better."""
    w1, w2, w3 = weights
    if travel_mm <= 0 or force_kpa <= 0:
        raise ValueError(f"score: y and F_N must be positive, got y={travel_mm}, F_N={force_kpa}")
    return (w1 + success_rate) * (w2 / travel_mm + w3 / force_kpa)

"""Grip control: the law, the controller's answerer, the supervisor's judge and the period clock.
Pure code, no sockets, no clock of its own (callers pass the time).

* `law`: the paper's grip law a(s) = k (s - s_d), its clamps and rate limit, why an estimate
  cannot drive the force (a cause of the closed set `GRIP_CAUSES`), the clamp of the node that
  applies the force (`applied_force`), the paper's constants and the scene of each method;
* `answerer`: the grip controller's per-period bookkeeping (`PeriodAnswerer`), which returns the
  wire `GripCommand`s the node publishes;
* `judge`: the supervisor's rules and verdict by period (`RunJudge`), the run summary, the score;
* `closers`: when a period's data are in, one closer per mode (lock-step: the rig's tick; real
  time: data and deadlines), asked by the judge;
* `clock`: stamps onto the run's period clock (`PeriodOrigin`), for the estimator and supervisor.

The names other modules use are re-exported here (`from incipient_slip.control import X`).
"""
from incipient_slip.control.answerer import MAX_TICK_SKIP, Notice, PeriodAnswerer
from incipient_slip.control.clock import PERIOD_ORIGINS, PeriodOrigin
from incipient_slip.control.closers import LockstepCloser, RealTimeCloser
from incipient_slip.control.judge import (
    EXIT_CODES, SCORE_WEIGHTS, TRACES, TRUTH_TRACES, RunJudge, SupervisorRules, Verdict, format_summary,
    judge_step, score,
)
from incipient_slip.control.law import (
    DEFAULT_GAIN_KPA, DEFAULT_INITIAL_FORCE_KPA, DEFAULT_MAX_STEP_KPA, DEFAULT_MIN_FORCE_KPA,
    DEFAULT_TARGET_STICK_RATIO, FAILURE_TRAVEL_MM, MAX_STEPS, SAFETY_LIMIT_KPA, SCENE_OF_METHOD,
    ControlDecision, ControlParams, Problem, action, applied_force, clamp_force, estimate_problem, hold,
    next_force, problem_of, scene_of,
)

__all__ = [
    "MAX_TICK_SKIP", "Notice", "PeriodAnswerer", "PERIOD_ORIGINS", "PeriodOrigin", "LockstepCloser",
    "RealTimeCloser", "EXIT_CODES", "SCORE_WEIGHTS", "TRACES", "TRUTH_TRACES", "RunJudge", "SupervisorRules",
    "Verdict", "format_summary", "judge_step", "score", "DEFAULT_GAIN_KPA", "DEFAULT_INITIAL_FORCE_KPA",
    "DEFAULT_MAX_STEP_KPA", "DEFAULT_MIN_FORCE_KPA", "DEFAULT_TARGET_STICK_RATIO", "FAILURE_TRAVEL_MM",
    "MAX_STEPS", "SAFETY_LIMIT_KPA", "SCENE_OF_METHOD", "ControlDecision", "ControlParams", "Problem",
    "action", "applied_force", "clamp_force", "estimate_problem", "hold", "next_force", "problem_of",
    "scene_of",
]

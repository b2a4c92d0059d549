"""Rig identification, the protocols: what one period shows and what the next one does.

One protocol, written once as a generator, drives every rig: the in-process simulated rig
(`experiments.identification`), and the graph's `identifier` node on rig:=sim, emulated or
hardware. Each 500 ms period it receives what the sensors saw (`Observation`: F_N applied, the
actuator's position, the object's mocap samples) and answers with the next period's `Command`
(F_N and an absolute actuator position). Three protocols run in order (docs/identification.md):

1. **Pre-slip stiffness and range.** At each F_N level (highest first; the first level twice,
   a run-in: the first loading of a fresh contact includes the interfacial micro-slip, after a
   slide the interface stays locked forward and the ramps show the pad's bulk shear alone) the
   actuator steps `step_mm` per period from zero spring load until the paper's gross-slip rule
   fires (0.02 mm within the second half of the window) or the travel limit.
2. **Friction-limit response.** At the top level the spring is loaded to a fraction of the
   friction limit at the low level, F_N steps down, and the periods until the slide starts time
   how fast the friction limit follows the grip.
3. **No-action check.** The paper's no-action run: constant F_N, the paper's 450 steps of
   23/450 mm from zero load; the final y and whether it slid.

Safety lives in the plan: F_N never above `control.SAFETY_LIMIT_KPA` (the nodes that move the
hardware clamp again), the actuator within [0, max_travel_mm], a trial ends at the first slide
period, and every trial ends at zero spring load (the actuator follows the object back).

Quantities the sensors cannot give are `Inputs` with their uncertainty: the spring constant k_s
(Q is computed from it) and the kPa -> N gain of P_DC. The fit is `identify.fit`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Generator

import numpy as np

from incipient_slip import control
from incipient_slip.models import labels

PERIOD_S = 0.5
SECOND_HALF_S = PERIOD_S / 2

class IdentificationError(ValueError):
    """Bad plan, inputs or measurements; the message says which and why."""


@dataclass(frozen=True)
class Inputs:
    """What the rig's sensors cannot measure, with relative standard uncertainties (measure by hand:
    docs/identification.md)."""

    spring_n_per_mm: float = 0.0327175
    spring_rel_sd: float = 0.03
    newton_per_kpa: float = 0.4
    gain_rel_sd: float = 0.1
    material: str = "pla"
    rig: str = "sim"

    def check(self) -> None:
        for name in ("spring_n_per_mm", "newton_per_kpa"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise IdentificationError(f"input {name} must be a positive number, got {v}")
        for name in ("spring_rel_sd", "gain_rel_sd"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0 <= v < 1):
                raise IdentificationError(f"input {name} must be in [0, 1), got {v}")


@dataclass(frozen=True)
class Plan:
    """The protocols' settings (defaults: docs/identification.md)."""

    levels_kpa: tuple = (5.9, 4.7, 3.5, 2.3, 1.1)
    step_mm: float = 0.1                 # actuator step per period on a ramp
    slide_rise_mm: float = 0.02          # a ramp slid when y rises this much above its stuck steps
    slide_needs_rise: bool = False       # real-time rigs: the paper's within-period rule alone ends no ramp
    settle_periods: int = 6              # periods at a new F_N before a ramp starts
    max_rise_kpa: float = 1.0            # F_N rises at most this per period (a press loop overshoots a big step)
    max_travel_mm: float = 48.0          # the actuator never goes past this (stage limit)
    unload_periods: int = 4              # periods the actuator follows the object back to zero load
    lag_high_kpa: float = 5.9
    lag_low_kpa: float = 2.3              # the slide it lets go is r mu (F_hi - F_lo) / k_s: <= ~7 mm
    lag_fractions: tuple = (0.08, 0.12, 0.2, 0.35)   # where Q/mu sits between F_lo (0) and F_hi (1)
    lag_load_step_mm: float = 1.0        # fast ramp of the lag trials (far below their friction limit)
    lag_max_periods: int = 16            # periods at F_lo waiting for the slide
    lag_release_periods: int = 8         # periods back at F_hi (the slide ends)
    no_action_kpa: float = 2.94
    no_action_steps: int = 450
    no_action_travel_mm: float = 23.0
    protocols: tuple = ("stiffness", "lag", "no_action")

    def check(self) -> None:
        limit = control.SAFETY_LIMIT_KPA
        forces = list(self.levels_kpa) + [self.lag_high_kpa, self.lag_low_kpa, self.no_action_kpa]
        for f in forces:
            if not (math.isfinite(f) and 0 < f <= limit):
                raise IdentificationError(f"every F_N of the plan must be in (0, {limit}] kPa, got {f}")
        if len(self.levels_kpa) < 2 and "stiffness" in self.protocols:
            raise IdentificationError("the stiffness protocol needs at least two F_N levels (beta)")
        if not (math.isfinite(self.max_rise_kpa) and self.max_rise_kpa > 0):
            raise IdentificationError(f"max_rise_kpa must be > 0, got {self.max_rise_kpa}")
        if not 0 < self.slide_rise_mm <= 1.0:
            raise IdentificationError(f"slide_rise_mm must be in (0, 1], got {self.slide_rise_mm}")
        if not 0 < self.step_mm <= 1.0:
            raise IdentificationError(f"step_mm must be in (0, 1], got {self.step_mm}")
        if not self.lag_low_kpa < self.lag_high_kpa:
            raise IdentificationError("lag_low_kpa must be below lag_high_kpa")
        if not all(0 < r < 1 for r in self.lag_fractions):
            raise IdentificationError("lag_fractions must lie in (0, 1)")
        unknown = set(self.protocols) - {"stiffness", "lag", "no_action"}
        if unknown:
            raise IdentificationError(f"unknown protocols {sorted(unknown)} (known: stiffness, lag, no_action)")
        if "lag" in self.protocols and "stiffness" not in self.protocols:
            raise IdentificationError("the lag protocol needs mu from the stiffness protocol")


@dataclass(frozen=True)
class Command:
    """The next period: F_N (kPa) and the actuator's absolute position (mm)."""

    normal_force_kpa: float
    actuator_mm: float
    phase: str
    trial: int


@dataclass
class Observation:
    """What one period showed: F_N applied, actuator position, mocap samples (absolute s, mm)."""

    period: int
    normal_force_kpa: float
    actuator_mm: float
    t_end_s: float
    mocap_t_s: np.ndarray
    mocap_y_mm: np.ndarray


@dataclass
class Record:
    """One period as the fit reads it."""

    period: int
    phase: str
    trial: int
    fn_kpa: float
    u_mm: float
    y_mm: float          # mean mocap y over the period's second half
    travel_mm: float     # the paper's rule: travel within the period
    rise_mm: float       # y's rise since the previous period's second half
    slid: bool           # the paper's rule fired
    onset: bool = False  # the protocol ended a ramp here: the slide's first period


def read_period(obs: Observation, prev_y: float | None) -> tuple[float, float, float]:
    """Return (y over the second half, the paper's rule's travel within the period, the rise of y
    from the previous period's second half). The rule is what `slid` means; the rise also
    catches a slide over within the first 25 ms, but only at constant F_N (a change of F_N moves
    the object through the pad's deformation without a slide, which is why the paper reads the
    travel within the period)."""
    t, y = np.asarray(obs.mocap_t_s, float), np.asarray(obs.mocap_y_mm, float)
    if len(t) < 2 or not np.all(np.isfinite(y)):
        raise IdentificationError(f"period {obs.period}: no usable mocap samples ({len(t)})")
    end = np.array([obs.t_end_s])
    y_half = float(labels.mocap_mean_between(t, y, end - SECOND_HALF_S, end)[0])
    travel = float(labels.gross_slip_travel_mm(t, y, end)[0])
    rise = y_half - prev_y if prev_y is not None else 0.0
    return y_half, travel, float(rise)


Protocol = Generator[Command, Observation, None]


def spring_load_n(rec: Record, ks: float) -> float:
    """The spring's pull in a period, Q = k_s (u - y) (N): what the sensors cannot give directly."""
    return ks * (rec.u_mm - rec.y_mm)


def ramp_slid(ramp: list[Record], rise_mm: float = labels.GROSS_SLIP_MM, needs_rise: bool = False) -> bool:
    """The last period of a ramp (constant F_N, one actuator step per period) slid: the paper's
    rule, or y rose `rise_mm` more than the ramp's stuck steps raise it (the median of the
    previous five rises: on a soft pad a step alone raises y by up to ~0.02 mm). On a real-time
    rig the robot's press loop moves F_N a little every period and y with it, so the rise test
    needs a wider margin there (Plan.slide_rise_mm), and with `needs_rise` the rise alone decides:
    a press move that lands inside the window moves y by 0.02 mm there without a slide (the paper's
    rule ended a 2.3 kPa ramp at half its friction limit; docs/identification.md)."""
    rec = ramp[-1]
    before = [r.rise_mm for r in ramp[-6:-1]]
    rose = len(before) >= 3 and rec.rise_mm - float(np.median(before)) >= rise_mm
    return rose if needs_rise else rec.slid or rose


def run_protocol(plan: Plan, inputs: Inputs, records: list[Record]) -> Protocol:
    """The three protocols as one generator: send it each period's Observation, it yields the
    next Command (first `next()` gives the first command). `records` fills as periods come in."""
    plan.check()
    inputs.check()
    ks = inputs.spring_n_per_mm
    state = {"y": None, "fn": None}

    def period(fn: float, u: float, phase: str, trial: int) -> Generator[Command, Observation, Record]:
        fn = min(float(fn), control.SAFETY_LIMIT_KPA)
        if state["fn"] is not None:                  # down at once (less force), up rate-limited
            fn = min(fn, state["fn"] + plan.max_rise_kpa)
        state["fn"] = fn
        u = min(max(float(u), 0.0), plan.max_travel_mm)
        obs = yield Command(fn, u, phase, trial)
        y, travel, rise = read_period(obs, state["y"])
        state["y"] = y
        rec = Record(obs.period, phase, trial, float(obs.normal_force_kpa), float(obs.actuator_mm), y, travel,
                     rise, travel >= labels.GROSS_SLIP_MM)
        records.append(rec)
        return rec

    def settle(fn: float, u: float, trial: int) -> Generator[Command, Observation, Record]:
        """Bring F_N to `fn` (rate-limited) and hold it `settle_periods` periods."""
        while state["fn"] is None or state["fn"] < min(fn, control.SAFETY_LIMIT_KPA) - 1e-9:
            yield from period(fn, u, "settle", trial)
        for _ in range(plan.settle_periods):
            rec = yield from period(fn, u, "settle", trial)
        return rec

    def unload(fn: float, u: float, trial: int) -> Generator[Command, Observation, float]:
        """Move the actuator onto the object (zero spring load) and return its position."""
        for _ in range(plan.unload_periods):
            rec = yield from period(fn, u, "unload", trial)
            u = rec.y_mm
        return u

    trial, u, fn = 0, 0.0, plan.no_action_kpa
    mu_onsets: list[float] = []
    if "stiffness" in plan.protocols:
        levels = (plan.levels_kpa[0],) + tuple(plan.levels_kpa)
        for i, fn in enumerate(levels):
            phase = "run-in" if i == 0 else "ramp"
            yield from settle(fn, u, trial)
            ramp: list[Record] = []
            while True:
                ramp.append((yield from period(fn, u, phase, trial)))
                slid = ramp_slid(ramp, plan.slide_rise_mm, plan.slide_needs_rise)
                if slid or u >= plan.max_travel_mm:
                    break
                u = min(u + plan.step_mm, plan.max_travel_mm)
            if slid and len(ramp) >= 2:
                ramp[-1].onset = True
                prev = ramp[-2]
                mu_onsets.append(spring_load_n(prev, ks) / (fn * inputs.newton_per_kpa))
            u = yield from unload(fn, u, trial)
            trial += 1
    if "lag" in plan.protocols and mu_onsets:
        mu = float(np.median(mu_onsets))
        hi, lo = plan.lag_high_kpa, plan.lag_low_kpa
        for r in plan.lag_fractions:
            q_target = mu * (lo + r * (hi - lo)) * inputs.newton_per_kpa
            fn = hi
            rec = yield from settle(hi, u, trial)
            while ks * (u - rec.y_mm) < q_target and u < plan.max_travel_mm:
                gap_mm = (q_target - ks * (u - rec.y_mm)) / ks
                u = min(u + min(plan.lag_load_step_mm, gap_mm * 1.02 + 1e-3), plan.max_travel_mm)
                rec = yield from period(hi, u, "lag-load", trial)
            yield from period(hi, u, "lag-hold", trial)
            for _ in range(plan.lag_max_periods):
                rec = yield from period(lo, u, "lag-low", trial)
                if rec.slid:
                    break
            for _ in range(plan.lag_release_periods):
                yield from period(hi, u, "lag-release", trial)
            u = yield from unload(hi, u, trial)
            trial += 1
    if "no_action" in plan.protocols:
        fn = plan.no_action_kpa
        yield from settle(fn, u, trial)
        u0 = u
        step = plan.no_action_travel_mm / plan.no_action_steps
        for k in range(plan.no_action_steps):
            yield from period(fn, u0 + k * step, "no-action", trial)
        u = yield from unload(fn, u0 + plan.no_action_steps * step, trial)
    yield from period(fn, u, "done", -1)

"""Rig identification: the protocols that measure what the simulator cannot know, and their fit.

One protocol, written once as a generator, drives every rig: the in-process simulated rig
(`experiments.identification`), and the graph's `identifier` node on rig:=sim, emulated or
hardware. Each 500 ms period it receives what the sensors saw (`Observation`: F_N applied, the
actuator's position, the object's mocap samples) and answers with the next period's `Command`
(F_N and an absolute actuator position). Three protocols run in order (docs/identification.md):

1. **Pre-slip stiffness and range.** At each F_N level (highest first; the first level twice,
   a run-in: the first loading of a fresh contact includes the interfacial micro-slip, after a
   slide the interface stays locked forward and the ramps show the pad's bulk shear alone) the
   actuator steps `step_mm` per period from zero spring load until the paper's gross-slip rule
   fires (0.02 mm within the second half of the window) or the travel limit. From y against the
   spring load Q = k_s (u - y): the pad's tangential stiffness k_b per level (slope), then
   k_b(F) = k_ref (F / 1 N)^beta by a log-log fit, mu = Q_onset / F_N per level and the travel
   at onset (the deformable range).
2. **Friction-limit response.** At the top level the spring is loaded to a fraction of the
   friction limit at the low level, F_N steps down, and the periods until the slide starts time
   how fast the friction limit follows the grip: a first-order lag tau gives the onset when
   F_lo + (F_hi - F_lo) e^(-t/tau) falls to Q/mu, so each trial brackets tau; F_N then steps up
   again (the periods until the slide ends are recorded).
3. **No-action check.** The paper's no-action run: constant F_N, the paper's 450 steps of
   23/450 mm from zero load; the final y and whether it slid.

Safety lives in the plan: F_N never above `control.SAFETY_LIMIT_KPA` (the nodes that move the
hardware clamp again), the actuator within [0, max_travel_mm], a trial ends at the first slide
period, and every trial ends at zero spring load (the actuator follows the object back).

Quantities the sensors cannot give are `Inputs` with their uncertainty: the spring constant k_s
(Q is computed from it) and the kPa -> N gain of P_DC. Layering: imports `models.labels` (the
paper's gross-slip rule) and `control`; imported by `nodes.identifier` and `experiments`.
"""
from __future__ import annotations

import datetime as _dt
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Generator

import numpy as np

from incipient_slip import control
from incipient_slip.models import labels

PERIOD_S = 0.5
SECOND_HALF_S = PERIOD_S / 2
# what an overlay entry without an interval says: the plan left nothing to bound it with
UNBOUNDED = "too few levels or trials to bound it: identify with 3 or more F_N levels"


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


def ramp_slid(ramp: list[Record], rise_mm: float = labels.GROSS_SLIP_MM) -> bool:
    """The last period of a ramp (constant F_N, one actuator step per period) slid: the paper's
    rule, or y rose `rise_mm` more than the ramp's stuck steps raise it (the median of the
    previous five rises: on a soft pad a step alone raises y by up to ~0.02 mm). On a real-time
    rig the robot's press loop moves F_N a little every period and y with it, so the rise test
    needs a wider margin there (Plan.slide_rise_mm, docs/identification.md)."""
    rec = ramp[-1]
    if rec.slid:
        return True
    before = [r.rise_mm for r in ramp[-6:-1]]
    return len(before) >= 3 and rec.rise_mm - float(np.median(before)) >= rise_mm


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
                if ramp_slid(ramp, plan.slide_rise_mm) or u >= plan.max_travel_mm:
                    break
                u = min(u + plan.step_mm, plan.max_travel_mm)
            if ramp_slid(ramp, plan.slide_rise_mm) and len(ramp) >= 2:
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


# --- the fit -------------------------------------------------------------------------------------

def t95(dof: int) -> float:
    """Two-sided 95 % Student t quantile (inf without degrees of freedom)."""
    from scipy.stats import t

    return float(t.ppf(0.975, dof)) if dof > 0 else math.inf


def _trials(records, phases) -> dict[int, list[Record]]:
    out: dict[int, list[Record]] = {}
    for r in records:
        if r.phase in phases:
            out.setdefault(r.trial, []).append(r)
    return out


def stiffness_levels(records: list[Record], inputs: Inputs) -> list[dict]:
    """Per ramp: F_N, k_b (N/mm) and its standard error from y against Q over the stuck periods,
    the onset load, mu and the travel at onset (from the ramp's zero-load y)."""
    from scipy.stats import linregress

    ks, gain = inputs.spring_n_per_mm, inputs.newton_per_kpa
    rows = []
    for trial, recs in sorted(_trials(records, ("ramp", "run-in")).items()):
        end = next((i for i, r in enumerate(recs) if r.onset), None)
        stuck, slid = (recs, []) if end is None else (recs[:end], recs[end:])
        fn = float(np.median([r.fn_kpa for r in recs]))
        row = {"trial": trial, "phase": recs[0].phase, "fn_kpa": fn, "fn_n": fn * gain, "periods": len(recs),
               "slid": bool(slid), "k_b": math.nan, "k_b_se": math.nan, "mu": math.nan,
               "onset_travel_mm": math.nan, "q_n": [], "y_mm": []}
        if len(stuck) >= 5:
            q = np.array([spring_load_n(r, ks) for r in stuck])
            y = np.array([r.y_mm for r in stuck])
            row["q_n"], row["y_mm"] = q.tolist(), y.tolist()
            # the upper part of the ramp (Q above 30 % of the largest) is the pad's bulk shear alone;
            # near zero load the interface's locked micro-slip still settles
            m = q >= 0.3 * q.max()
            if m.sum() >= 4 and np.ptp(q[m]) > 0:
                line = linregress(q[m], y[m])
                if line.slope > 0:
                    row["k_b"], row["k_b_se"] = 1.0 / line.slope, line.stderr / line.slope ** 2
            if slid:
                last = stuck[-1]
                # the limit lies between the last stuck load and the next step's: take the middle
                q_on = spring_load_n(last, ks) * (1.0 + 0.5 * plan_step_fraction(stuck, ks))
                row["mu"] = q_on / (fn * gain)
                row["onset_travel_mm"] = last.y_mm - stuck[0].y_mm
                row["q_onset_n"] = q_on
        rows.append(row)
    return rows


def plan_step_fraction(stuck: list[Record], ks: float) -> float:
    """Return the last step's load increment as a fraction of the last stuck load."""
    if len(stuck) < 2:
        return 0.0
    q1, q0 = spring_load_n(stuck[-1], ks), spring_load_n(stuck[-2], ks)
    return max(0.0, (q1 - q0) / q1) if q1 > 0 else 0.0


def fit_stiffness(rows: list[dict], inputs: Inputs, ref_force_n: float = 1.0) -> dict:
    """Return k_ref (N/mm at ref_force_n) and beta with 95 % intervals from the ramps after the
    run-in (log k_b = log k_ref + beta log(F / F_ref), least squares over the levels), and mu."""
    from scipy.stats import linregress

    ramps = [r for r in rows if r["phase"] == "ramp" and math.isfinite(r["k_b"])]
    out: dict = {"ref_force_n": ref_force_n, "levels": len(ramps)}
    if len(ramps) >= 2:
        x = np.log(np.array([r["fn_n"] for r in ramps]) / ref_force_n)
        z = np.log(np.array([r["k_b"] for r in ramps]))
        line = linregress(x, z)
        beta, log_k = float(line.slope), float(line.intercept)
        dof = len(ramps) - 2
        t = t95(dof)
        # two levels fit exactly: no interval (linregress reports 0 there)
        se_beta, se_logk = (line.stderr, line.intercept_stderr) if dof > 0 else (math.inf, math.inf)
        # the inputs: Q scales with k_s (so k_b does); the gain moves F, so k_ref by gain^-beta
        rel_in = math.hypot(inputs.spring_rel_sd, beta * inputs.gain_rel_sd)
        k = math.exp(log_k)
        rel = math.hypot(t * se_logk, 1.96 * rel_in)
        out.update(k_ref=k, k_ref_interval=[k * math.exp(-rel), k * math.exp(rel)],
                   k_ref_stat_interval=[k * math.exp(-t * se_logk), k * math.exp(t * se_logk)],
                   beta=beta, beta_interval=[beta - t * se_beta, beta + t * se_beta])
    mus = [r["mu"] for r in rows if r["phase"] == "ramp" and math.isfinite(r["mu"])]
    if mus:
        mu = float(np.mean(mus))
        half = t95(len(mus) - 1) * float(np.std(mus, ddof=1)) / math.sqrt(len(mus)) if len(mus) > 1 else math.inf
        rel_in = math.hypot(inputs.spring_rel_sd, inputs.gain_rel_sd)
        total = math.hypot(half, 1.96 * rel_in * mu)
        out.update(mu=mu, mu_stat_interval=[mu - half, mu + half], mu_interval=[mu - total, mu + total],
                   mu_levels=len(mus))
    travel = [r["onset_travel_mm"] for r in rows if math.isfinite(r["onset_travel_mm"])]
    if travel:
        out["onset_travel_mm"] = {"mean": float(np.mean(travel)), "min": float(np.min(travel)),
                                  "max": float(np.max(travel)), "n": len(travel)}
    return out


def lag_trials(records: list[Record], inputs: Inputs, stiff: dict) -> list[dict]:
    """Per lag trial: the spring load at F_lo, its place r between F_lo and F_hi, the onset
    period after the step (1 = the first period at F_lo; None: no slide) and the tau interval it
    gives (the onset is read per period, so t_on is known to within one period).

    The load at F_lo is not the load held at F_hi: the pad softens with the grip at once, the
    object moves on and the spring relaxes (by ~15 %). It is read from the first period at F_lo
    when that one stuck, else predicted from the fitted k_b(F_N)."""
    ks, gain = inputs.spring_n_per_mm, inputs.newton_per_kpa
    mu = stiff["mu"]

    def k_b(f_n):
        return stiff["k_ref"] * (f_n / stiff["ref_force_n"]) ** stiff["beta"]
    rows = []
    for trial, recs in sorted(_trials(records, ("lag-hold", "lag-low", "lag-release")).items()):
        hold = [r for r in recs if r.phase == "lag-hold"]
        low = [r for r in recs if r.phase == "lag-low"]
        release = [r for r in recs if r.phase == "lag-release"]
        if not hold or not low:
            continue
        q_hold = spring_load_n(hold[-1], ks)
        f_hi, f_lo = hold[-1].fn_kpa * gain, low[0].fn_kpa * gain
        if not low[0].slid:
            q = spring_load_n(low[0], ks)
        elif "k_ref" in stiff:
            q = q_hold / (1.0 + ks * (1.0 / k_b(f_lo) - 1.0 / k_b(f_hi)))
        else:
            q = q_hold
        r = (q / mu - f_lo) / (f_hi - f_lo)
        # time the onset against the P_DC step (the F_N applied reaching 90 % of the step), not the
        # command: a robot's press loop takes its own time to unload the finger
        target = min(r.fn_kpa for r in low)
        hi_kpa = hold[-1].fn_kpa
        step_at = next((i for i, rec in enumerate(low) if rec.fn_kpa <= target + 0.1 * (hi_kpa - target)), 0)
        slide_at = next((i for i, rec in enumerate(low) if rec.slid), None)
        onset = None if slide_at is None else max(1, slide_at - step_at + 1)
        row = {"trial": trial, "q_n": q, "r": r, "onset_period": onset, "pdc_step_period": step_at + 1,
               "tau_interval": None,
               "slide_end_periods": next((i + 1 for i, rec in enumerate(release) if not rec.slid), None)}
        if onset is not None and 0 < r < 1:
            lr = -math.log(r)
            row["tau_interval"] = [(onset - 1) * PERIOD_S / lr, onset * PERIOD_S / lr]
        rows.append(row)
    return rows


def fit_lag(rows: list[dict]) -> dict:
    """Return tau (s) and its interval: the intersection of the trials' intervals (their union
    when they disagree, e.g. from noise near a period boundary)."""
    ivs = [r["tau_interval"] for r in rows if r["tau_interval"]]
    if not ivs:
        return {}
    lo, hi = max(i[0] for i in ivs), min(i[1] for i in ivs)
    agree = lo <= hi
    if not agree:
        lo, hi = min(i[0] for i in ivs), max(i[1] for i in ivs)
    return {"tau_s": 0.5 * (lo + hi), "tau_interval": [lo, hi], "trials": len(ivs), "consistent": agree}


def no_action_result(records: list[Record]) -> dict:
    recs = [r for r in records if r.phase == "no-action"]
    if not recs:
        return {}
    return {"fn_kpa": float(np.median([r.fn_kpa for r in recs])), "steps": len(recs),
            "final_y_mm": recs[-1].y_mm - recs[0].y_mm, "slid": any(r.slid for r in recs),
            "first_slide_step": next((i for i, r in enumerate(recs) if r.slid), None)}


def analyze(records: list[Record], inputs: Inputs) -> dict:
    """Return every measured quantity with its interval (the identification's results)."""
    rows = stiffness_levels(records, inputs)
    stiff = fit_stiffness(rows, inputs)
    lag = lag_trials(records, inputs, stiff) if "mu" in stiff else []
    return {"inputs": asdict(inputs), "levels": rows, "stiffness": stiff, "lag_trials": lag,
            "lag": fit_lag(lag), "no_action": no_action_result(records), "periods": len(records)}


# --- the params overlay --------------------------------------------------------------------------

def overlay(results: dict, protocol: str = "launch identify.yaml", date: str | None = None) -> dict:
    """Return the params overlay: only the identified parameters, each {value, unit, source,
    interval}, plus the inputs used and the provenance (sim.scene.load_params(..., overlay=)
    applies it)."""
    inp, stiff, lag = results["inputs"], results["stiffness"], results["lag"]
    date = date or _dt.date.today().isoformat()
    src = f"identified ({protocol}, rig {inp['rig']}, material {inp['material']}, {date})"
    doc: dict = {"provenance": {"date": date, "rig": inp["rig"], "material": inp["material"], "protocol": protocol,
                                "inputs": {k: inp[k] for k in ("spring_n_per_mm", "spring_rel_sd", "newton_per_kpa",
                                                               "gain_rel_sd")}}}

    def entry(value, unit, interval, what, positive=False):
        out = {"value": float(value), "unit": unit, "source": f"{src}: {what}"}
        if not all(math.isfinite(v) for v in interval):    # e.g. two levels fit k_b exactly
            out["source"] += f"; no interval ({UNBOUNDED})"
        elif positive and interval[0] <= 0:                # a noisy pair of levels: t95(1) = 12.7
            out["source"] += f"; no interval (it reaches {interval[0]:.3g}: {UNBOUNDED})"
        else:
            out["interval"] = [float(interval[0]), float(interval[1])]
        return out

    pre, ss = {}, {}
    if "k_ref" in stiff:
        pre["bulk_shear_n_per_mm"] = entry(stiff["k_ref"], "N/mm", stiff["k_ref_interval"],
                                           f"k_b at {stiff['ref_force_n']:g} N from {stiff['levels']} ramps",
                                           positive=True)
        pre["bulk_ref_force_n"] = {"value": float(stiff["ref_force_n"]), "unit": "N", "source": f"{src}: reference force"}
        pre["bulk_stiffening_exponent"] = entry(stiff["beta"], "-", stiff["beta_interval"], "log-log slope of k_b(F_N)")
    if lag:
        ss["friction_limit_lag_s"] = entry(lag["tau_s"], "s", lag["tau_interval"],
                                           f"slide onsets after F_N steps ({lag['trials']} trials)")
    rel = inp["spring_rel_sd"]
    ss["spring_n_per_mm"] = entry(inp["spring_n_per_mm"], "N/mm",
                                  [inp["spring_n_per_mm"] * (1 - 1.96 * rel), inp["spring_n_per_mm"] * (1 + 1.96 * rel)],
                                  "input (measured by hand)")
    g, grel = inp["newton_per_kpa"], inp["gain_rel_sd"]
    doc["contact"] = {"newton_per_kpa": entry(g, "N/kPa", [g * (1 - 1.96 * grel), g * (1 + 1.96 * grel)],
                                              "input (measured by hand)")}
    if pre:
        doc["pre_slip"] = pre
    doc["stick_slip"] = ss
    if "mu" in stiff:
        doc["materials"] = {inp["material"]: {"mu_identified": entry(stiff["mu"], "-", stiff["mu_interval"],
                                                                      f"Q/F_N at onset, {stiff['mu_levels']} levels",
                                                                      positive=True)}}
    return doc


def figures(results: dict, records: list, out_dir: Path, stem: str = "identify") -> dict:
    """Draw y against the spring load per F_N level with the fitted lines, and the lag trials'
    slide onsets against the F_N step; return {protocol: path}."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rig, mat = results["inputs"]["rig"], results["inputs"]["material"]
    # rig:=emulated is the real device nodes around the same simulated contact: its numbers are simulated too
    label = f"rig: {rig}; material {mat}" + (" (SIMULATED RIG)" if str(rig).startswith("sim") else
                                             " (EMULATED DEVICES ON THE SIMULATED RIG)" if rig == "emulated" else "")
    paths = {}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for row in results["levels"]:
        if not row["q_n"]:
            continue
        q, y = np.array(row["q_n"]), np.array(row["y_mm"])
        style = ":" if row["phase"] == "run-in" else "-"
        line, = ax.plot(q, y - y[0], style, lw=1.2,
                        label=f"{row['fn_kpa']:.1f} kPa{' run-in' if row['phase'] == 'run-in' else ''}: "
                              f"k_b {row['k_b']:.3f} N/mm, mu {row['mu']:.3f}")
        if math.isfinite(row["k_b"]):
            qq = np.array([0.3 * q.max(), q.max()])
            m = q >= 0.3 * q.max()
            c = float(np.mean(y[m] - y[0] - q[m] / row["k_b"]))
            ax.plot(qq, c + qq / row["k_b"], "k--", lw=0.6)
        if row["slid"]:
            ax.plot(q[-1], y[-1] - y[0], "x", color=line.get_color())
    st = results["stiffness"]
    if "beta" in st:
        ax.set_title(f"pre-slip: k_b = {st['k_ref']:.3f} N/mm (F/1 N)^{st['beta']:.2f}; x = slide onset", fontsize=9)
    ax.set_xlabel("spring load Q = k_s (u - y) [N]")
    ax.set_ylabel("object travel from zero load [mm]")
    ax.legend(fontsize=7)
    paths["stiffness"] = _save(plt, fig, out_dir / f"{stem}_stiffness.png", label)

    lag_recs = [r for r in records if r.phase in ("lag-hold", "lag-low", "lag-release")]
    if lag_recs:
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 4.5), sharex=True)
        trials = sorted({r.trial for r in lag_recs})
        for t in trials:
            rs = [r for r in lag_recs if r.trial == t]
            k0 = next((r.period for r in rs if r.phase == "lag-low"), rs[0].period)
            x = [(r.period - k0) * PERIOD_S for r in rs]
            row = next((lt for lt in results["lag_trials"] if lt["trial"] == t), {})
            a1.step(x, [r.fn_kpa for r in rs], where="post", lw=1)
            a2.plot(x, [r.y_mm - rs[0].y_mm for r in rs], "-o", ms=2, lw=1, label=f"r = {row.get('r', math.nan):.2f}")
        a1.set_ylabel("F_N [kPa]")
        a2.set_ylabel("y - y(step) [mm]")
        a2.set_xlabel("time after the F_N step down [s]")
        lag = results["lag"]
        if lag:
            a1.set_title(f"friction-limit response: tau = {lag['tau_s']:.2f} s "
                         f"[{lag['tau_interval'][0]:.2f}, {lag['tau_interval'][1]:.2f}]", fontsize=9)
        a2.legend(fontsize=7)
        paths["lag"] = _save(plt, fig, out_dir / f"{stem}_lag.png", label)
    return paths


def _save(plt, fig, path: Path, label: str) -> str:
    """Label a picture with the rig it came from, write it and close it."""
    fig.text(0.01, -0.03, label, fontsize=7)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return str(path)


def write_outputs(results: dict, records: list[Record], out_dir, protocol: str = "launch identify.yaml") -> dict:
    """Write results JSON (with every period), the params overlay YAML and the pictures into
    out_dir; return {what: path}. A picture that cannot be drawn is reported, never loses data."""
    import json

    import yaml

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"results": out_dir / "identify_results.json", "overlay": out_dir / "identify_overlay.yaml"}
    doc = {**results, "records": [asdict(r) for r in records]}
    paths["results"].write_text(json.dumps(doc, indent=1, default=float))
    ov = overlay(results, protocol)
    header = ("# Params overlay of an identified rig (docs/identification.md): only the identified parameters,\n"
              "# each with its 95 % interval; use it with --params (slip reproduce validation --params FILE).\n")
    paths["overlay"].write_text(header + yaml.safe_dump(ov, sort_keys=False))
    try:
        paths.update(figures(results, records, out_dir))
    except Exception as exc:     # a figure never costs the measurements
        paths["figure_error"] = f"pictures not drawn: {exc}"
    return {k: str(v) for k, v in paths.items()}


__all__ = ["Command", "IdentificationError", "Inputs", "Observation", "Plan", "Record", "analyze", "overlay",
           "read_period", "run_protocol", "write_outputs"]

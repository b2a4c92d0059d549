"""Rig identification, the fit: the pad's stiffness k_b(F_N), mu, the friction limit's lag, the
no-action check, from the periods the protocols recorded (`identify.protocol.Record`).

Stiffness: per ramp, k_b = 1/slope of y against the spring load Q = k_s (u - y) up to 80 % of
its largest stuck load (SLOPE_RANGE), the onset load (the middle between the last stuck step and the next), mu = Q_onset /
F_N; then log k_b = log k_ref + beta log(F_N / 1 N) by least squares over the levels after the
run-in. Lag: each trial's onset after the F_N step down brackets tau. scipy is imported on use.
"""
from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from .protocol import PERIOD_S, Inputs, Record, spring_load_n

# the part of a ramp's stuck load (fraction of its largest) whose slope is the pad's bulk shear:
# up to 80 % of it. Near the onset a dip of F_N lowers the friction limit to the load and the
# contact slips partly (a real-time rig's press loop moves F_N by ~0.04 kPa every period, 4 % at
# 1.1 kPa): on rig:=emulated such a period, too small for the slide rules, sat at the top of the
# ramp and levered its slope (k_b 13 % low at 1.1 kPa, docs/identification.md). From zero load:
# more periods against that F_N ripple (the lock-step rig's micro-slip settling near zero load
# costs < 1.1 % there, 16 hidden sets).
SLOPE_RANGE = (0.0, 0.8)

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
            m = slope_points(q)
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


def slope_points(q: np.ndarray) -> np.ndarray:
    """The stuck periods of a ramp the slope is read from: Q within SLOPE_RANGE of the largest."""
    lo, hi = SLOPE_RANGE
    return (q >= lo * q.max()) & (q <= hi * q.max())


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

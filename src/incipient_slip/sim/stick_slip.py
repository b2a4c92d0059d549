"""Object on a rail pulled through a tension spring by a stepping actuator: stick, pre-slip, slide.

While stuck the object sits at y = anchor + delta(Q) with Q = k_s (u - y): a bracketed root
(brentq). Past mu_s F_N the object slides with kinetic friction mu_k F_N, mass m and rail
damping; the slide is solved in closed form (damped oscillator with constant forcing) and
ends at the event where the velocity returns to zero, where the stick condition is checked
again (event-based, no time stepping, so a stiff spring with a tiny mass costs the same).
Units: mm, s, N, kg.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq


class SimulationError(FloatingPointError):
    """The physics produced a non-finite or inconsistent value; the message names the step."""


@dataclass
class Segment:
    """One piece of the object's motion inside a period: constant (stuck) or a slide."""

    t0: float
    t1: float
    y0: float
    v0: float = 0.0
    y_eq: float = 0.0        # slide: equilibrium of the forced oscillator
    sliding: bool = False


@dataclass
class RailState:
    """Object travel y (mm), velocity v (mm/s), stick anchor (mm), actuator u (mm), sliding flag."""

    y_mm: float = 0.0
    v_mm_s: float = 0.0
    anchor_mm: float = 0.0
    actuator_mm: float = 0.0
    contact_disp_mm: float = 0.0      # locked pre-slip displacement (Mindlin-Deresiewicz memory)
    sliding: bool = False
    segments: list = field(default_factory=list)


def _delta(q: float, mu_fn: float, dmax: float) -> float:
    """Scalar Mindlin displacement (mm) for load q, fast path of partial_slip.displacement_mm."""
    if mu_fn <= 0.0:
        return 0.0
    s = 1.0 - abs(q) / mu_fn
    if s <= 0.0:
        return math.copysign(dmax, q)
    return math.copysign(dmax * (1.0 - s ** (2.0 / 3.0)), q)


def solve_stick(anchor: float, u: float, k: float, mu_fn: float, dmax: float,
                locked: float = -math.inf) -> tuple[int, float]:
    """Return (0, y) when the contact sticks at y solving y = anchor + max(locked, delta(k (u - y))),
    else (+1, nan) for forward gross slip or (-1, nan) for backward gross slip.

    `locked` is the displacement the contact already holds: a rise of F_N grows the stick
    region with zero traction, so the contact does not spring back (Mindlin-Deresiewicz,
    simplified to a forward ratchet)."""
    if mu_fn <= 0.0:
        return (0, u) if u == anchor else (1 if u > anchor else -1, math.nan)
    y_lo = u - mu_fn / k          # Q = +mu F_N
    y_hi = u + mu_fn / k          # Q = -mu F_N

    def g(y: float) -> float:
        return y - anchor - max(locked, _delta(k * (u - y), mu_fn, dmax))

    # decide with the same function the root finder sees, so rounding cannot break the bracket
    g_lo, g_hi = g(y_lo), g(y_hi)
    if g_lo > 0.0:
        return 1, math.nan
    if g_hi < 0.0:
        return -1, math.nan
    if g_lo == 0.0:
        return 0, y_lo            # exactly at the limit: stuck with s = 0
    if g_hi == 0.0:
        return 0, y_hi
    y = brentq(g, y_lo, y_hi, xtol=1e-13, rtol=4 * np.finfo(float).eps, maxiter=200)
    return 0, y


def slide_position(seg: Segment, omega: float, zeta: float, t):
    """Return y(t) (mm) on a slide segment, t absolute within the period (array ok)."""
    tau = np.asarray(t) - seg.t0
    wd = omega * math.sqrt(1.0 - zeta * zeta)
    sig = zeta * omega
    e0 = seg.y0 - seg.y_eq
    b = (seg.v0 + sig * e0) / wd
    return seg.y_eq + np.exp(-sig * tau) * (e0 * np.cos(wd * tau) + b * np.sin(wd * tau))


def _slide_state(e0: float, v0: float, omega: float, zeta: float, tau: float) -> tuple[float, float]:
    wd = omega * math.sqrt(1.0 - zeta * zeta)
    sig = zeta * omega
    ex, c, s = math.exp(-sig * tau), math.cos(wd * tau), math.sin(wd * tau)
    e = ex * (e0 * c + (v0 + sig * e0) / wd * s)
    v = ex * (v0 * c - (sig * v0 + omega * omega * e0) / wd * s)
    return e, v


def _stop_time(e0: float, v0: float, omega: float, zeta: float) -> float:
    """Return the first tau > 0 where the slide velocity is zero."""
    wd = omega * math.sqrt(1.0 - zeta * zeta)
    c = (zeta * omega * v0 + omega * omega * e0) / wd
    theta = math.atan2(v0, c) % math.pi
    if theta < 1e-12:
        theta = math.pi
    return theta / wd


def step_rail(st: RailState, *, normal_force_n: float, mu_s: float, mu_k: float, dmax: float,
              k: float, mass_kg: float, zeta: float, period_s: float, max_events: int,
              step: int) -> RailState:
    """Advance the rail by one period at fixed actuator position and F_N; fill st.segments."""
    omega = math.sqrt(1000.0 * k / mass_kg)       # k in N/mm -> N/m
    fs_lim = mu_s * normal_force_n
    fk = mu_k * normal_force_n
    u = st.actuator_mm
    t = 0.0
    st.segments = []
    for _ in range(max_events):
        if not st.sliding:
            direction, y = solve_stick(st.anchor_mm, u, k, fs_lim, dmax, st.contact_disp_mm)
            if direction == 0:
                st.y_mm, st.v_mm_s = y, 0.0
                st.contact_disp_mm = y - st.anchor_mm
                st.segments.append(Segment(t, period_s, y))
                break
            # the contact reaches full deformation, then the whole patch slides
            if fs_lim > 0:
                st.y_mm = st.anchor_mm + (max(st.contact_disp_mm, dmax) if direction > 0 else -dmax)
            st.v_mm_s = 0.0
            st.sliding = True
        direction = math.copysign(1.0, st.v_mm_s) if st.v_mm_s != 0.0 else math.copysign(1.0, u - st.y_mm)
        y_eq = u - direction * fk / k
        e0 = st.y_mm - y_eq
        tau = _stop_time(e0, st.v_mm_s, omega, zeta) if fs_lim > 0 else math.inf
        seg = Segment(t, min(t + tau, period_s), st.y_mm, st.v_mm_s, y_eq, True)
        st.segments.append(seg)
        if t + tau >= period_s:
            e, v = _slide_state(e0, st.v_mm_s, omega, zeta, period_s - t)
            st.y_mm, st.v_mm_s = y_eq + e, v
            break
        e, _ = _slide_state(e0, st.v_mm_s, omega, zeta, tau)
        t += tau
        st.y_mm, st.v_mm_s = y_eq + e, 0.0
        q = k * (u - st.y_mm)
        if abs(q) <= fs_lim:
            st.sliding = False
            st.contact_disp_mm = _delta(q, fs_lim, dmax)
            st.anchor_mm = st.y_mm - st.contact_disp_mm
    else:
        raise SimulationError(f"step {step}: more than {max_events} stick/slide switches in one period "
                              f"(F_N={normal_force_n} N, mu_s={mu_s}, mu_k={mu_k}, damping ratio={zeta})")
    if not (math.isfinite(st.y_mm) and math.isfinite(st.v_mm_s) and math.isfinite(st.anchor_mm)):
        raise SimulationError(f"step {step}: non-finite rail state y={st.y_mm} v={st.v_mm_s} anchor={st.anchor_mm}")
    return st


def positions(st: RailState, omega: float, zeta: float, t: np.ndarray) -> np.ndarray:
    """Return the object travel y(t) in mm at times t (s, within the last period)."""
    y = np.empty_like(t)
    for seg in st.segments:
        m = (t >= seg.t0) & (t < seg.t1) if seg is not st.segments[-1] else (t >= seg.t0)
        if seg.sliding:
            y[m] = slide_position(seg, omega, zeta, t[m])
        else:
            y[m] = seg.y0
    return y

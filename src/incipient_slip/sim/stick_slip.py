"""One contact state: the pad's reversible bulk shear, the interfacial Mindlin part and creep sliding.

The object's travel is y = anchor + delta_bulk + delta_int, with

* anchor: how far the contact has slid grossly on the object (changes only while sliding);
* delta_bulk = Q / k_b(F_N): reversible shear of the soft pad (skin + fluid). It springs back at
  once when F_N rises (k_b grows with F_N, exponent beta), as the paper's gross-slip rule assumes
  (the object moves with F_N changes without slipping);
* delta_int: the interfacial Cattaneo-Mindlin displacement, small, with memory (Mindlin-Deresiewicz,
  simplified to a forward ratchet, capped at its current maximum delta_int_max(F)).

The stick-area ratio of the contact is the one of the Cattaneo state holding the same interfacial
displacement: (c/a)^2 = 1 - delta_int / delta_int_max. That single number is what the modes, the
micro-slip bursts and the reported truth use.

Gross sliding is creep-like (soft skin): the friction coefficient rises weakly with sliding speed,
mu(v) = mu_s + b ln(1 + v / v_ref), so the slide relaxes the spring smoothly instead of jumping.
With the pad springs in series, dQ/dt = -k_eff v, and z = (Q / F - mu_s) / b obeys
dz/dt = -lambda (e^z - 1), lambda = k_eff v_ref / (F b): w = e^-z relaxes as w(t) = 1 - (1 - w0) e^-lambda t
(closed form, no time step). The slide ends (re-stick) when v falls to v_stick.
Units: mm, s, N.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq


class SimulationError(FloatingPointError):
    """The physics produced a non-finite or inconsistent value; the message names the step."""


@dataclass
class ContactState:
    """The whole mechanical state; every consumer (modes, electrodes, truth) reads it from here."""

    y_mm: float = 0.0               # object travel at the end of the period
    actuator_mm: float = 0.0        # actuator position during the period
    anchor_mm: float = 0.0          # gross slide accumulated so far
    bulk_mm: float = 0.0            # reversible bulk shear of the pad, Q / k_b
    interfacial_mm: float = 0.0     # interfacial (Mindlin) displacement, with memory
    interfacial_max_mm: float = 0.0  # its maximum at the current contact (full slip)
    tangential_force_n: float = 0.0
    friction_limit_n: float = 0.0   # mu_s F_eff
    stick_area_ratio: float = 1.0   # (c/a)^2 = 1 - interfacial / interfacial_max
    sliding: bool = False           # the contact ended the period sliding
    slide_t0_s: float = 0.0         # slide within this period: start ...
    slide_t1_s: float = 0.0         # ... and end (== t0 when there was no slide)
    slide_q0_n: float = 0.0         # Q at the slide's start
    slide_lambda: float = 0.0       # relaxation rate (1/s)
    slide_bf_n: float = 0.0         # b F: Q = mu_s F + b F z during the slide


def cattaneo_mm(q: float, mu_fn: float, dmax: float) -> float:
    """Return the monotonic Cattaneo displacement dmax (1 - s^(2/3)), s = 1 - |Q|/mu F_N (signed)."""
    if mu_fn <= 0.0:
        return 0.0
    s = 1.0 - abs(q) / mu_fn
    if s <= 0.0:
        return math.copysign(dmax, q)
    return math.copysign(dmax * (1.0 - s ** (2.0 / 3.0)), q)


def interfacial_mm(q: float, mu_fn: float, dmax: float, locked: float) -> float:
    """Return the interfacial displacement under load q: the ratchet max(locked, Cattaneo), capped at dmax."""
    return min(max(locked, cattaneo_mm(q, mu_fn, dmax)), dmax)


def solve_stick(anchor: float, u: float, k: float, mu_fn: float, dmax: float,
                locked: float = -math.inf, k_bulk: float = math.inf) -> tuple[int, float]:
    """Return (0, y) when the contact sticks at y = anchor + Q/k_bulk + interfacial(Q), Q = k (u - y),
    else (+1, nan) for forward gross slip or (-1, nan) for backward gross slip.

    `locked` is the interfacial displacement the contact already holds (a rise of F_N grows the
    stick region with zero traction, so the interfacial part does not spring back; the bulk does)."""
    if mu_fn <= 0.0:
        return (0, u) if u == anchor else (1 if u > anchor else -1, math.nan)
    comp = 0.0 if math.isinf(k_bulk) else 1.0 / k_bulk
    y_lo = u - mu_fn / k          # Q = +mu F_N
    y_hi = u + mu_fn / k          # Q = -mu F_N

    def g(y: float) -> float:
        q = k * (u - y)
        return y - anchor - q * comp - max(locked, cattaneo_mm(q, mu_fn, dmax))

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


def _creep_z(z0: float, lam: float, tau) -> np.ndarray:
    """Return z(tau) = -ln(1 - (1 - e^-z0) e^-lam tau), clipped to [0, z0] (array ok)."""
    one_minus_w0 = -math.expm1(-z0)
    arg = one_minus_w0 * np.exp(-lam * np.asarray(tau, float))
    with np.errstate(divide="ignore"):
        z = -np.log1p(-np.minimum(arg, 1.0))
    return np.clip(z, 0.0, z0)


def step_contact(st: ContactState, *, friction_force_n: float, mu_s: float,
                 dmax_int: float, k_spring: float, k_bulk: float, rate_b: float, v_ref: float,
                 v_stick: float, period_s: float, step: int) -> ContactState:
    """Advance the contact by one period at fixed actuator position; return the updated state.

    friction_force_n is the normal force the friction limit and interfacial compliance follow
    (F_N, or F_N lagged); k_bulk is the pad's shear stiffness at the period's actual F_N."""
    u = st.actuator_mm
    mu_fn = mu_s * friction_force_n
    st.friction_limit_n = mu_fn
    st.interfacial_max_mm = dmax_int
    st.slide_t0_s = st.slide_t1_s = 0.0
    st.sliding = False
    if mu_fn <= 0.0 or friction_force_n <= 0.0:      # no contact: the spring pulls the object along
        if st.y_mm != u:
            st.slide_t1_s, st.slide_bf_n = 1e-9, 0.0      # a free move at the period start counts as gross slip
        st.anchor_mm = st.y_mm = u
        st.bulk_mm = st.interfacial_mm = 0.0
        st.tangential_force_n = 0.0
        st.stick_area_ratio = 0.0
        return st
    locked = min(st.interfacial_mm, dmax_int)
    direction, y = solve_stick(st.anchor_mm, u, k_spring, mu_fn, dmax_int, locked, k_bulk)
    if direction == 0:
        q = k_spring * (u - y)
        st.y_mm, st.tangential_force_n = y, q
        st.bulk_mm = q / k_bulk
        st.interfacial_mm = interfacial_mm(q, mu_fn, dmax_int, locked)
    else:
        # gross slip: full interfacial slip; the anchor creeps until the velocity falls to v_stick
        k_eff = 1.0 / (1.0 / k_spring + 1.0 / k_bulk)
        sign = float(direction)
        q0 = sign * k_eff * (sign * (u - st.anchor_mm) - dmax_int)      # Q with the anchor where it is
        z0 = (abs(q0) / friction_force_n - mu_s) / rate_b
        lam = k_eff * v_ref / (friction_force_n * rate_b)
        z_stop = math.log1p(v_stick / v_ref)
        if z0 > z_stop:
            w0m = -math.expm1(-z0)                                       # 1 - w0
            t_stop = math.log(w0m / -math.expm1(-z_stop)) / lam
            t_end = min(t_stop, period_s)
            z = float(_creep_z(z0, lam, t_end))
            st.sliding = t_stop > period_s
            st.slide_t1_s, st.slide_q0_n, st.slide_lambda = t_end, q0, lam
            st.slide_bf_n = rate_b * friction_force_n
        else:
            z = max(z0, 0.0)
            st.slide_t1_s, st.slide_q0_n, st.slide_lambda = 0.0, q0, lam
        q = sign * friction_force_n * (mu_s + rate_b * z)
        st.anchor_mm += (q0 - q) / k_eff
        st.tangential_force_n = q
        st.bulk_mm = q / k_bulk
        st.interfacial_mm = sign * dmax_int
        st.y_mm = st.anchor_mm + st.bulk_mm + st.interfacial_mm
    st.stick_area_ratio = 1.0 - min(1.0, abs(st.interfacial_mm) / dmax_int) if dmax_int > 0 else 1.0
    if st.sliding:
        st.stick_area_ratio = 0.0
    for name in ("y_mm", "anchor_mm", "tangential_force_n", "bulk_mm", "interfacial_mm"):
        if not math.isfinite(getattr(st, name)):
            raise SimulationError(f"step {step}: non-finite contact state {name}={getattr(st, name)} "
                                  f"(F={friction_force_n} N, mu_s={mu_s}, k_bulk={k_bulk})")
    return st


def positions(st: ContactState, k_spring: float, t: np.ndarray) -> np.ndarray:
    """Return the object travel y(t) in mm at times t (s, within the last period).

    Outside a slide the object sits where the period leaves it (the pad deforms at once with F_N
    and the actuator step); during the slide y = u - Q(t) / k_spring with Q relaxing in closed form."""
    y = np.full(np.shape(t), st.y_mm, dtype=float)
    m = np.asarray(t) < st.slide_t1_s
    if st.slide_t1_s <= st.slide_t0_s or not np.any(m) or st.slide_bf_n <= 0.0:
        return y
    sign = math.copysign(1.0, st.slide_q0_n)
    z0 = (abs(st.slide_q0_n) - st.friction_limit_n) / st.slide_bf_n
    q = st.friction_limit_n + st.slide_bf_n * _creep_z(z0, st.slide_lambda, np.asarray(t)[m] - st.slide_t0_s)
    y[m] = st.actuator_mm - sign * q / k_spring
    return y

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

import numpy as np

from . import mechanics
from .mechanics import _creep_z, cattaneo_mm, interfacial_mm  # noqa: F401  (the compiled physics, re-exported)


class SimulationError(FloatingPointError):
    """The physics produced a non-finite or inconsistent value; the message names the step."""


class ContactState:
    """The whole mechanical state; every consumer (modes, electrodes, truth) reads it from here.

    Named float attributes over one float64 array, `values` (layout `mechanics.STATE`), which the
    compiled physics updates in place:

    y_mm: object travel at the end of the period; actuator_mm: actuator position during the period;
    anchor_mm: gross slide accumulated so far; bulk_mm: reversible bulk shear of the pad, Q / k_b;
    interfacial_mm: interfacial (Mindlin) displacement, with memory; interfacial_max_mm: its maximum
    at the current contact (full slip); tangential_force_n; friction_limit_n: mu_s F_eff;
    stick_area_ratio: (c/a)^2 = 1 - interfacial / interfacial_max; sliding: the contact ended the
    period sliding (bool); slide_t0_s, slide_t1_s: the slide within this period (t1 == t0 when there
    was none); slide_q0_n: Q at the slide's start; slide_lambda: relaxation rate (1/s); slide_bf_n:
    b F, Q = mu_s F + b F z during the slide; friction_force_n: the normal force the friction limit
    follows (lagged F_N; nan before the first period).
    """

    __slots__ = ("values",)

    def __init__(self, **fields):
        self.values = mechanics.new_state()
        for name, value in fields.items():
            if name not in mechanics.STATE:
                raise TypeError(f"ContactState has no field {name!r}")
            setattr(self, name, value)

    def __repr__(self) -> str:
        return "ContactState(" + ", ".join(f"{n}={getattr(self, n)!r}" for n in mechanics.STATE) + ")"


def _field(i: int):
    def get(self):
        return float(self.values[i])

    def put(self, value):
        self.values[i] = value
    return property(get, put)


for _i, _name in enumerate(mechanics.STATE):
    setattr(ContactState, _name, _field(_i))
ContactState.sliding = property(lambda self: bool(self.values[mechanics.SLIDING]),
                                lambda self, v: self.values.__setitem__(mechanics.SLIDING, 1.0 if v else 0.0))


def solve_stick(anchor: float, u: float, k: float, mu_fn: float, dmax: float,
                locked: float = -math.inf, k_bulk: float = math.inf) -> tuple[int, float]:
    """Return (0, y) when the contact sticks at y = anchor + Q/k_bulk + interfacial(Q), Q = k (u - y),
    else (+1, nan) for forward gross slip or (-1, nan) for backward gross slip.

    `locked` is the interfacial displacement the contact already holds (a rise of F_N grows the
    stick region with zero traction, so the interfacial part does not spring back; the bulk does).
    The root is scipy's brentq (xtol 1e-13, rtol 4 eps), compiled (`mechanics.solve_stick`)."""
    direction, y = mechanics.solve_stick(float(anchor), float(u), float(k), float(mu_fn), float(dmax),
                                         float(locked), float(k_bulk))
    if direction == mechanics.BRENTQ_FAILED:
        raise SimulationError(f"the stick solve did not converge (u={u}, mu F_N={mu_fn}, k_bulk={k_bulk})")
    return direction, y


def raise_status(status: int, step: int, friction_force_n: float, mu_s: float, k_bulk: float,
                 values: np.ndarray) -> None:
    """Raise the SimulationError that a nonzero `mechanics.step_contact` status stands for."""
    if status == mechanics.BRENTQ_FAILED:
        raise SimulationError(f"step {step}: the stick solve did not converge "
                              f"(F={friction_force_n} N, mu_s={mu_s}, k_bulk={k_bulk})")
    name = mechanics.CHECKED[status - mechanics.NONFINITE]
    raise SimulationError(f"step {step}: non-finite contact state {name}={values[mechanics.STATE.index(name)]} "
                          f"(F={friction_force_n} N, mu_s={mu_s}, k_bulk={k_bulk})")


def step_contact(st: ContactState, *, friction_force_n: float, mu_s: float,
                 dmax_int: float, k_spring: float, k_bulk: float, rate_b: float, v_ref: float,
                 v_stick: float, period_s: float, step: int) -> ContactState:
    """Advance the contact by one period at fixed actuator position; return the updated state.

    friction_force_n is the normal force the friction limit and interfacial compliance follow
    (F_N, or F_N lagged); k_bulk is the pad's shear stiffness at the period's actual F_N."""
    args = [float(v) for v in (friction_force_n, mu_s, dmax_int, k_spring, k_bulk, rate_b, v_ref, v_stick, period_s)]
    status = mechanics.step_contact(st.values, *args)
    if status:
        raise_status(status, step, friction_force_n, mu_s, k_bulk, st.values)
    return st


def positions(st: ContactState, k_spring: float, t: np.ndarray) -> np.ndarray:
    """Return the object travel y(t) in mm at times t (s, within the last period).

    Outside a slide the object sits where the period leaves it (the pad deforms at once with F_N
    and the actuator step); during the slide y = u - Q(t) / k_spring with Q relaxing in closed form."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    y = np.empty(t.shape)
    mechanics.positions(st.values, float(k_spring), t.reshape(-1), y.reshape(-1))
    return y

"""The rig's mechanics, compiled: contact size, pad stiffness, stick solve, creep slide, one period.

Every function here is the physics itself, not a copy: `period_mocap` (`period` and the period's
mocap samples) is the mechanics stage of every period of every scene (`sim.stages`: data sets,
the `rig_sim` node, the closed loop), and `Rig.run_mechanics` calls `run_series`, which loops the
same `period_mocap` plus the paper's gross-slip rule over a whole series in one call (the
calibration's and the validation's stage-1 fits, which simulate only the mechanics). The explanation of the model is in `contact`
and `stick_slip`, which re-export the functions below under their documented names.

Bit for bit: the compiled code does the arithmetic of the Python it replaced in the same order,
with the same C library calls (numba lowers math.exp, log, expm1, log1p and ** to libm, as CPython
does; cbrt is libm's, declared as an external function: numba has no math.cbrt). Python's min/max
(first argument on ties) are spelled out, and the stick solve is scipy's `brentq`
(scipy/optimize/Zeros/brentq.c, scipy >= 1.11) written out here. The creep relaxation `_creep_z`
and the no-sample interpolation of the slip rule stay numpy calls (numpy's SIMD exp and log1p
differ from libm in the last bit), made from the compiled code through `numba.objmode`; they run
only in slide periods. Tests assert `==` against scipy's brentq, against the array form of the
slip rule, between `run_series` and `step_period`, and against the committed calibration summary
(tests/sim/test_mechanics.py).

All compiled functions live in this one file on purpose: numba's on-disk cache (`cache=True`)
is invalidated only by a change of the file a function is defined in, not of the files it calls.
The state of the contact is a float64 array (`STATE`, indices below) that `stick_slip.ContactState`
wraps with named attributes; the parameters are a float64 array (`PARAMS`) built by the Rig.
Units: mm, s, N.
"""
from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, types

# --- the contact state (stick_slip.ContactState names these) ----------------------------------
STATE = ("y_mm", "actuator_mm", "anchor_mm", "bulk_mm", "interfacial_mm", "interfacial_max_mm",
         "tangential_force_n", "friction_limit_n", "stick_area_ratio", "sliding", "slide_t0_s",
         "slide_t1_s", "slide_q0_n", "slide_lambda", "slide_bf_n", "friction_force_n")
(Y, ACTUATOR, ANCHOR, BULK, INTERFACIAL, INTERFACIAL_MAX, Q, FRICTION_LIMIT, SAR, SLIDING, SLIDE_T0,
 SLIDE_T1, SLIDE_Q0, SLIDE_LAMBDA, SLIDE_BF, F_EFF) = range(len(STATE))
# statuses of step_contact: 0, BRENTQ_FAILED (the stick solve did not converge; scipy raised), or
# NONFINITE + i when CHECKED[i] came out non-finite (the fields it checks, in its order)
BRENTQ_FAILED = 2            # also solve_stick's direction then (not -1, 0 or +1)
CHECKED = ("y_mm", "anchor_mm", "tangential_force_n", "bulk_mm", "interfacial_mm")
NONFINITE = 10
_XTOL, _RTOL, _MAXITER = 1e-13, 4 * np.finfo(float).eps, 200    # the stick solve's brentq settings

# --- the rig's constants for the mechanics (Rig.mech_params holds them) -------------------------
PARAMS = ("newton_per_kpa", "min_contact_force_n", "friction_limit_lag_s", "period_s", "radius_mm",
          "e_star_mpa", "contact_saturation_radius_mm", "mu_series", "mu_period_jitter",
          "bulk_shear_n_per_mm", "bulk_ref_force_n", "bulk_stiffening_exponent", "g_star_int_mpa",
          "spring_n_per_mm", "rate_strengthening", "creep_reference_velocity_mm_s",
          "restick_velocity_mm_s", "step_mm", "mocap_rate_hz", "mocap_noise_mm")
(P_KPA_N, P_MIN_FORCE, P_LAG, P_PERIOD, P_RADIUS, P_E_STAR, P_A_SAT, P_MU_SERIES, P_MU_JITTER,
 P_BULK_REF, P_BULK_REF_FORCE, P_BULK_EXP, P_G_STAR_INT, P_K_SPRING, P_RATE_B, P_V_REF, P_V_STICK,
 P_STEP, P_MOCAP_RATE, P_MOCAP_NOISE) = range(len(PARAMS))

# --- the columns run_series fills per period ------------------------------------------------------
COLUMNS = ("object_y_mm", "tangential_force_n", "stick_area_ratio", "load_ratio_stick", "gross_slip",
           "sliding", "slide_q0_n", "actuator_mm", "friction_force_n", "travel_mm")
(C_Y, C_Q, C_SAR, C_S, C_GROSS, C_SLIDING, C_Q0, C_ACT, C_F_EFF, C_TRAVEL) = range(len(COLUMNS))
# run_series status beyond step_contact's: a non-finite output of the period (Rig.step_period's check)
OUTPUT_CHECKED = ("tangential_force_n", "object_y_mm", "stick_area_ratio", "load_ratio_stick")
OUTPUT_STATUS = 100          # status OUTPUT_STATUS + i names OUTPUT_CHECKED[i]

_cbrt = types.ExternalFunction("cbrt", types.float64(types.float64))   # libm's, which CPython's math.cbrt calls


_warm = False
# any plausible rig: warm_up only walks the code paths (a stick, a slide and its two numpy callbacks)
_WARM_PARAMS = {"newton_per_kpa": 0.4, "min_contact_force_n": 1e-4, "friction_limit_lag_s": 0.0, "period_s": 0.5,
                "radius_mm": 6.7, "e_star_mpa": 0.05, "contact_saturation_radius_mm": 5.0, "mu_series": 0.55,
                "mu_period_jitter": 0.01, "bulk_shear_n_per_mm": 0.5, "bulk_ref_force_n": 1.0,
                "bulk_stiffening_exponent": 1.0, "g_star_int_mpa": 0.2, "spring_n_per_mm": 0.03,
                "rate_strengthening": 0.02, "creep_reference_velocity_mm_s": 1.0, "restick_velocity_mm_s": 0.005,
                "step_mm": 0.05, "mocap_rate_hz": 120.0, "mocap_noise_mm": 0.005}


def warm_up() -> None:
    """Load the compiled mechanics and their numpy callbacks once per process (from numba's cache,
    or compiled on a fresh checkout): ~0.3 s that would otherwise fall on the first period, which
    a real-time driver (rig_sim, the emulated rig) must deliver on time."""
    global _warm
    if _warm:
        return
    p = np.array([_WARM_PARAMS[name] for name in PARAMS])
    s = new_state()
    tt, draws = np.arange(4) / p[P_MOCAP_RATE], np.zeros(4)
    period_mocap(s, p, 0, 3.0, 0.0, True, draws, tt, np.empty(4), np.empty(4))     # stuck
    s[ACTUATOR] = 50.0                      # far beyond the friction limit: a slide
    period_mocap(s, p, 1, 3.0, 0.0, True, draws, tt, np.empty(4), np.empty(4))
    period_mocap(s, p, 2, 3.0, 0.0, False, draws, tt[:0], np.empty(0), np.empty(0))   # a scene without mocap
    _warm = True


def new_state() -> np.ndarray:
    """Return the state of a rig before its first period (no friction force seen yet: nan)."""
    s = np.zeros(len(STATE))
    s[SAR] = 1.0
    s[F_EFF] = math.nan
    return s


@njit(cache=True)
def _min(a, b):
    """Python's min(a, b): the first argument unless the second is smaller."""
    return b if b < a else a


@njit(cache=True)
def _signbit(x):
    """C's signbit for a float that is not nan: True for negative numbers and -0.0."""
    return x < 0.0 or (x == 0.0 and math.copysign(1.0, x) < 0.0)


@njit(cache=True)
def _max(a, b):
    """Python's max(a, b): the first argument unless the second is larger."""
    return b if b > a else a


# --- contact (explained in sim/contact.py) --------------------------------------------------------

@njit(cache=True)
def hertz_radius_mm(normal_force_n, radius_mm, e_star_mpa):
    """Return the Hertz contact radius a_H = (3 F R / 4 E*)^(1/3) in mm (0 without contact)."""
    return _cbrt(3.0 * _max(normal_force_n, 0.0) * radius_mm / (4.0 * e_star_mpa))


@njit(cache=True)
def contact_radius_mm(normal_force_n, radius_mm, e_star_mpa, saturation_mm):
    """Return the contact radius a = a_sat (1 - exp(-a_H / a_sat)) in mm: Hertz at small loads, < a_sat always."""
    a_h = hertz_radius_mm(normal_force_n, radius_mm, e_star_mpa)
    return -saturation_mm * math.expm1(-a_h / saturation_mm)


@njit(cache=True)
def bulk_shear_stiffness_n_per_mm(ref_n_per_mm, normal_force_n, ref_force_n, exponent, min_force_n):
    """Return the pad's bulk shear stiffness k_b = k_ref (F_N / F_ref)^beta in N/mm, F_N clamped at
    the no-contact threshold so k_b stays positive and finite as F_N -> 0."""
    f = _max(float(normal_force_n), float(min_force_n))
    return ref_n_per_mm * (f / ref_force_n) ** float(exponent)    # libm pow, as Python's float ** int


@njit(cache=True)
def interfacial_max_mm(mu_fn_n, g_star_mpa, a_mm):
    """Return the interfacial Mindlin displacement at full slip, 3 mu F_N / (16 G* a), in mm."""
    if a_mm <= 0.0:
        return 0.0
    return 3.0 * mu_fn_n / (16.0 * g_star_mpa * a_mm)


# --- stick-slip (explained in sim/stick_slip.py) --------------------------------------------------

@njit(cache=True)
def cattaneo_mm(q, mu_fn, dmax):
    """Return the monotonic Cattaneo displacement dmax (1 - s^(2/3)), s = 1 - |Q|/mu F_N (signed)."""
    if mu_fn <= 0.0:
        return 0.0
    s = 1.0 - abs(q) / mu_fn
    if s <= 0.0:
        return math.copysign(dmax, q)
    return math.copysign(dmax * (1.0 - s ** (2.0 / 3.0)), q)


@njit(cache=True)
def load_ratio_stick(q, friction_limit_n):
    """Return the paper's pseudo-stick ratio s = 1 - |Q| / (mu F_N), clipped to [0, 1]."""
    return _min(1.0, _max(0.0, 1.0 - abs(q) / friction_limit_n))


@njit(cache=True)
def stick_area_ratio(interfacial, dmax):
    """Return the true stick-area ratio (c/a)^2 = 1 - |delta_int| / delta_int,max (1 without an
    interfacial range); on the monotonic Cattaneo path it equals s^(2/3)."""
    return 1.0 - _min(1.0, abs(interfacial) / dmax) if dmax > 0 else 1.0


@njit(cache=True)
def interfacial_mm(q, mu_fn, dmax, locked):
    """Return the interfacial displacement under load q: the ratchet max(locked, Cattaneo), capped at dmax."""
    return _min(_max(locked, cattaneo_mm(q, mu_fn, dmax)), dmax)


@njit(cache=True)
def _stick_gap(y, anchor, u, k, comp, locked, mu_fn, dmax):
    """The stick equation g(y) = y - anchor - Q/k_bulk - interfacial(Q), Q = k (u - y); 0 where it sticks."""
    q = k * (u - y)
    return y - anchor - q * comp - _max(locked, cattaneo_mm(q, mu_fn, dmax))


@njit(cache=True)
def _brentq_stick(xa, xb, anchor, u, k, comp, locked, mu_fn, dmax, xtol, rtol, maxiter):
    """Return (root of _stick_gap in [xa, xb], converged): scipy's brentq step for step
    (scipy/optimize/Zeros/brentq.c as of scipy 1.11-1.17: signs compared by sign bit)."""
    xpre, xcur = xa, xb
    xblk, fblk, spre, scur = 0.0, 0.0, 0.0, 0.0
    fpre = _stick_gap(xpre, anchor, u, k, comp, locked, mu_fn, dmax)
    fcur = _stick_gap(xcur, anchor, u, k, comp, locked, mu_fn, dmax)
    if math.isnan(fpre) or math.isnan(fcur):            # scipy's wrapper raises on a nan value
        return math.nan, False
    if fpre == 0:
        return xpre, True
    if fcur == 0:
        return xcur, True
    if _signbit(fpre) == _signbit(fcur):
        return math.nan, False
    for _ in range(maxiter):
        if fpre != 0 and fcur != 0 and _signbit(fpre) != _signbit(fcur):
            xblk = xpre
            fblk = fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre = xcur
            xcur = xblk
            xblk = xpre
            fpre = fcur
            fcur = fblk
            fblk = fpre
        delta = (xtol + rtol * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0 or abs(sbis) < delta:
            return xcur, True
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)            # interpolate
            else:
                dpre = (fpre - fcur) / (xpre - xcur)                    # extrapolate
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            lim = 3 * abs(sbis) - delta
            if 2 * abs(stry) < (abs(spre) if abs(spre) < lim else lim):   # C's MIN(a, b)
                spre = scur                                             # good short step
                scur = stry
            else:
                spre = sbis                                             # bisect
                scur = sbis
        else:
            spre = sbis                                                 # bisect
            scur = sbis
        xpre = xcur
        fpre = fcur
        if abs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0 else -delta
        fcur = _stick_gap(xcur, anchor, u, k, comp, locked, mu_fn, dmax)
        if math.isnan(fcur):
            return math.nan, False
    return xcur, False


@njit(cache=True)
def solve_stick(anchor, u, k, mu_fn, dmax, locked=-math.inf, k_bulk=math.inf):
    """Return (0, y) when the contact sticks at y = anchor + Q/k_bulk + interfacial(Q), Q = k (u - y),
    else (+1, nan) for forward gross slip or (-1, nan) for backward gross slip; (BRENTQ_FAILED, nan)
    when the root finder does not converge in 200 iterations.

    `locked` is the interfacial displacement the contact already holds (a rise of F_N grows the
    stick region with zero traction, so the interfacial part does not spring back; the bulk does)."""
    if mu_fn <= 0.0:
        if u == anchor:
            return 0, u
        return (1 if u > anchor else -1), math.nan
    comp = 0.0 if math.isinf(k_bulk) else 1.0 / k_bulk
    y_lo = u - mu_fn / k          # Q = +mu F_N
    y_hi = u + mu_fn / k          # Q = -mu F_N
    # decide with the same function the root finder sees, so rounding cannot break the bracket
    g_lo = _stick_gap(y_lo, anchor, u, k, comp, locked, mu_fn, dmax)
    g_hi = _stick_gap(y_hi, anchor, u, k, comp, locked, mu_fn, dmax)
    if g_lo > 0.0:
        return 1, math.nan
    if g_hi < 0.0:
        return -1, math.nan
    if g_lo == 0.0:
        return 0, y_lo            # exactly at the limit: stuck with s = 0
    if g_hi == 0.0:
        return 0, y_hi
    y, ok = _brentq_stick(y_lo, y_hi, anchor, u, k, comp, locked, mu_fn, dmax, _XTOL, _RTOL, _MAXITER)
    return (0 if ok else BRENTQ_FAILED), y


def _creep_z(z0: float, lam: float, tau) -> np.ndarray:
    """Return z(tau) = -ln(1 - (1 - e^-z0) e^-lam tau), clipped to [0, z0] (array ok; numpy's exp and log1p)."""
    one_minus_w0 = -math.expm1(-z0)
    arg = one_minus_w0 * np.exp(-lam * np.asarray(tau, float))
    with np.errstate(divide="ignore"):
        z = -np.log1p(-np.minimum(arg, 1.0))
    return np.clip(z, 0.0, z0)


@njit(cache=True)
def step_contact(s, friction_force_n, mu_s, dmax_int, k_spring, k_bulk, rate_b, v_ref, v_stick, period_s):
    """Advance the contact state `s` by one period at fixed actuator position; return a status:
    0, BRENTQ_FAILED, or NONFINITE + i when CHECKED[i] came out non-finite.

    friction_force_n is the normal force the friction limit and interfacial compliance follow
    (F_N, or F_N lagged); k_bulk is the pad's shear stiffness at the period's actual F_N."""
    u = s[ACTUATOR]
    mu_fn = mu_s * friction_force_n
    s[FRICTION_LIMIT] = mu_fn
    s[INTERFACIAL_MAX] = dmax_int
    s[SLIDE_T0] = 0.0
    s[SLIDE_T1] = 0.0
    s[SLIDING] = 0.0
    if mu_fn <= 0.0 or friction_force_n <= 0.0:      # no contact: the spring pulls the object along
        if s[Y] != u:
            s[SLIDE_T1] = 1e-9                       # a free move at the period start counts as gross slip
            s[SLIDE_BF] = 0.0
        s[ANCHOR] = u
        s[Y] = u
        s[BULK] = 0.0
        s[INTERFACIAL] = 0.0
        s[Q] = 0.0
        s[SAR] = 0.0
        return 0
    locked = _min(s[INTERFACIAL], dmax_int)
    direction, y = solve_stick(s[ANCHOR], u, k_spring, mu_fn, dmax_int, locked, k_bulk)
    if direction == BRENTQ_FAILED:
        return BRENTQ_FAILED
    if direction == 0:
        q = k_spring * (u - y)
        s[Y] = y
        s[Q] = q
        s[BULK] = q / k_bulk
        s[INTERFACIAL] = interfacial_mm(q, mu_fn, dmax_int, locked)
    else:
        # gross slip: full interfacial slip; the anchor creeps until the velocity falls to v_stick
        k_eff = 1.0 / (1.0 / k_spring + 1.0 / k_bulk)
        sign = float(direction)
        q0 = sign * k_eff * (sign * (u - s[ANCHOR]) - dmax_int)         # Q with the anchor where it is
        z0 = (abs(q0) / friction_force_n - mu_s) / rate_b
        lam = k_eff * v_ref / (friction_force_n * rate_b)
        z_stop = math.log1p(v_stick / v_ref)
        if z0 > z_stop:
            w0m = -math.expm1(-z0)                                       # 1 - w0
            t_stop = math.log(w0m / -math.expm1(-z_stop)) / lam
            t_end = _min(t_stop, period_s)
            with numba.objmode(z="float64"):
                z = float(_creep_z(z0, lam, t_end))
            s[SLIDING] = 1.0 if t_stop > period_s else 0.0
            s[SLIDE_T1] = t_end
            s[SLIDE_Q0] = q0
            s[SLIDE_LAMBDA] = lam
            s[SLIDE_BF] = rate_b * friction_force_n
        else:
            z = _max(z0, 0.0)
            s[SLIDE_T1] = 0.0
            s[SLIDE_Q0] = q0
            s[SLIDE_LAMBDA] = lam
        q = sign * friction_force_n * (mu_s + rate_b * z)
        s[ANCHOR] += (q0 - q) / k_eff
        s[Q] = q
        s[BULK] = q / k_bulk
        s[INTERFACIAL] = sign * dmax_int
        s[Y] = s[ANCHOR] + s[BULK] + s[INTERFACIAL]
    s[SAR] = stick_area_ratio(s[INTERFACIAL], dmax_int)
    if s[SLIDING] != 0.0:
        s[SAR] = 0.0
    for i, j in enumerate((Y, ANCHOR, Q, BULK, INTERFACIAL)):
        if not math.isfinite(s[j]):
            return NONFINITE + i
    return 0


@njit(cache=True)
def positions(s, k_spring, t, y):
    """Fill y with the object travel y(t) in mm at times t (s, within the last period).

    Outside a slide the object sits where the period leaves it (the pad deforms at once with F_N
    and the actuator step); during the slide y = u - Q(t) / k_spring with Q relaxing in closed form."""
    y[:] = s[Y]
    t1 = s[SLIDE_T1]
    n = 0
    for i in range(t.size):
        if t[i] < t1:
            n += 1
    if t1 <= s[SLIDE_T0] or n == 0 or s[SLIDE_BF] <= 0.0:
        return
    tau = np.empty(n)
    j = 0
    for i in range(t.size):
        if t[i] < t1:
            tau[j] = t[i] - s[SLIDE_T0]
            j += 1
    sign = math.copysign(1.0, s[SLIDE_Q0])
    z0 = (abs(s[SLIDE_Q0]) - s[FRICTION_LIMIT]) / s[SLIDE_BF]
    lam = s[SLIDE_LAMBDA]
    with numba.objmode(z="float64[::1]"):
        z = np.ascontiguousarray(_creep_z(z0, lam, tau), dtype=np.float64)
    j = 0
    for i in range(t.size):
        if t[i] < t1:
            q = s[FRICTION_LIMIT] + s[SLIDE_BF] * z[j]
            y[i] = s[ACTUATOR] - sign * q / k_spring
            j += 1


# --- one period of the rig's mechanics (sim.stages.MechanicsStage) -----------------------------------------

@njit(cache=True)
def period(s, p, normal_force_kpa, friction_draw, has_stick_slip):
    """Advance the mechanics of one period at F_N (kPa): the friction limit's force (lagged), the
    contact radius, the period's friction, the pad's stiffness and the contact step.

    `friction_draw` is the period's standard normal of the rig's friction stream. Returns
    (status of step_contact, F_N in N (0 without contact), in contact, a (mm), k_bulk (N/mm),
    stick-area ratio, load ratio s, Q (N), gross slip, slide duration (s))."""
    fn_n = normal_force_kpa * p[P_KPA_N]
    in_contact = fn_n >= p[P_MIN_FORCE]
    out_fn = fn_n if in_contact else 0.0
    lag = p[P_LAG]
    if math.isnan(s[F_EFF]) or lag <= 0.0 or not in_contact:
        s[F_EFF] = out_fn
    else:
        s[F_EFF] = out_fn + (s[F_EFF] - out_fn) * math.exp(-p[P_PERIOD] / lag)
    f_eff = s[F_EFF]
    a_mm = contact_radius_mm(f_eff, p[P_RADIUS], p[P_E_STAR], p[P_A_SAT]) if in_contact else 0.0
    jit = 1.0 + p[P_MU_JITTER] * friction_draw
    mu_s = p[P_MU_SERIES] * jit
    k_bulk = bulk_shear_stiffness_n_per_mm(p[P_BULK_REF], out_fn, p[P_BULK_REF_FORCE], p[P_BULK_EXP], p[P_MIN_FORCE])
    dmax_int = interfacial_max_mm(mu_s * f_eff, p[P_G_STAR_INT], a_mm)
    status, sar, s_ratio, q, gross, slide_s = 0, 1.0, 1.0, 0.0, False, 0.0
    if has_stick_slip:
        status = step_contact(s, f_eff if in_contact else 0.0, mu_s, dmax_int, p[P_K_SPRING], k_bulk,
                              p[P_RATE_B], p[P_V_REF], p[P_V_STICK], p[P_PERIOD])
        slide_s = s[SLIDE_T1] - s[SLIDE_T0]
        gross = slide_s > 0.0
        q = s[Q]
        sar = s[SAR]
        if s[SLIDING] != 0.0 or not in_contact:
            s_ratio = 0.0
        else:
            s_ratio = load_ratio_stick(q, s[FRICTION_LIMIT])
    return status, out_fn, in_contact, a_mm, k_bulk, sar, s_ratio, q, gross, slide_s


@njit(cache=True)
def period_mocap(s, p, step, normal_force_kpa, friction_draw, has_stick_slip, mocap_draws, tt, mt, my):
    """The mechanics stage of one period (the one compiled step of `Rig.step_period` and of
    `run_series`): `period`, then, when the scene has mocap (tt.size > 0), the period's mocap
    samples: times mt = step T + tt and measured travel my = y(tt) + draw * noise.

    Returns `period`'s tuple; mt and my are filled only when its status is 0."""
    res = period(s, p, normal_force_kpa, friction_draw, has_stick_slip)
    if res[0] == 0 and tt.size:
        t0 = step * p[P_PERIOD]
        positions(s, p[P_K_SPRING], tt, my)
        for i in range(tt.size):
            mt[i] = t0 + tt[i]
            my[i] = my[i] + mocap_draws[i] * p[P_MOCAP_NOISE]
    return res


@njit(cache=True)
def output_status(q, y, sar, s_ratio):
    """0, or OUTPUT_STATUS + i for the first non-finite OUTPUT_CHECKED[i] of a period's truth."""
    for i, v in enumerate((q, y, sar, s_ratio)):
        if not math.isfinite(v):
            return OUTPUT_STATUS + i
    return 0


# --- the paper's gross-slip rule on one period of mocap (models/labels.py) ------------------------

@njit(cache=True)
def _bisect_left(t, x):
    lo, hi = 0, t.size
    while lo < hi:
        mid = (lo + hi) // 2
        if t[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _mean_between(t, y, csum, t0, t1):
    lo, hi = _bisect_left(t, t0 - 1e-9), _bisect_left(t, t1 - 1e-9)
    if hi > lo:
        return (csum[hi] - csum[lo]) / (hi - lo)
    with numba.objmode(v="float64"):
        v = float(np.interp(0.5 * (t0 + t1), t, y))
    return v


@njit(cache=True)
def period_travel_mm(mocap_t_s, mocap_y_mm, period_end_s, span_s, early_s, late_s):
    """Return `labels.gross_slip_travel_mm` for one period end, bit for bit: the mean mocap position
    over the period's last `late_s` minus the mean over its first `early_s` (running sum, left
    bisection, np.interp where an interval holds no sample)."""
    csum = np.empty(mocap_y_mm.size + 1)
    csum[0] = 0.0
    acc = 0.0
    for i in range(mocap_y_mm.size):
        acc += mocap_y_mm[i]
        csum[i + 1] = acc
    start = period_end_s - span_s
    return (_mean_between(mocap_t_s, mocap_y_mm, csum, period_end_s - late_s, period_end_s)
            - _mean_between(mocap_t_s, mocap_y_mm, csum, start, start + early_s))


# --- a whole series (Rig.run_mechanics) ----------------------------------------------------------

@njit(cache=True)
def run_series(s, p, first_step, forces_kpa, friction_draws, mocap_draws, actuator_step, stop_travel_mm,
               rule, out):
    """Run the periods of `forces_kpa` as Rig.step_period would on a scene with the effects contact,
    stick_slip and mocap, filling out[k, COLUMNS]; stop after the first period whose mocap travel
    (`period_travel_mm` with `rule` = (span, early, late)) is >= stop_travel_mm.

    `friction_draws[k]` and `mocap_draws[k]` are the period's draws of the rig's friction and mocap
    streams. Returns (periods run, status, step of the status): status 0, a step_contact status, or
    OUTPUT_STATUS + i for a non-finite OUTPUT_CHECKED[i]."""
    n_mocap = mocap_draws.shape[1]
    tt = np.arange(n_mocap) / p[P_MOCAP_RATE]
    mt = np.empty(n_mocap)
    my = np.empty(n_mocap)
    for k in range(forces_kpa.size):
        step = first_step + k
        actuator = s[ACTUATOR]
        status, _, _, _, _, sar, s_ratio, q, gross, _ = period_mocap(s, p, step, forces_kpa[k], friction_draws[k],
                                                                     True, mocap_draws[k], tt, mt, my)
        if status == 0:
            status = output_status(q, s[Y], sar, s_ratio)
        if status != 0:
            return k, status, step
        t0 = step * p[P_PERIOD]
        travel = period_travel_mm(mt, my, t0 + p[P_PERIOD], rule[0], rule[1], rule[2])
        row = out[k]
        row[C_Y] = s[Y]
        row[C_Q] = q
        row[C_SAR] = sar
        row[C_S] = s_ratio
        row[C_GROSS] = 1.0 if gross else 0.0
        row[C_SLIDING] = s[SLIDING]
        row[C_Q0] = s[SLIDE_Q0]
        row[C_ACT] = actuator
        row[C_F_EFF] = s[F_EFF]
        row[C_TRAVEL] = travel
        if actuator_step:
            s[ACTUATOR] += p[P_STEP]
        if travel >= stop_travel_mm:
            return k + 1, 0, step
    return forces_kpa.size, 0, first_step + forces_kpa.size

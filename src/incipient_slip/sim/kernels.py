"""The signal path's arithmetic, compiled: the modal filter's coefficients, the electrodes' settling
and noise, and the ADC conversions of one period.

`Rig.step_period` runs ~450 x 1000 times per data set, and what it did between its few large
array operations (random draws, the sos filters) was ~40 small numpy calls on arrays of 4-1100
elements, each costing more in dispatch than in arithmetic. These loops do the same arithmetic
in the same order with the same IEEE operations (+ - * / and sqrt, correctly rounded in numpy and
in compiled code alike; no fast-math, so no fused multiply-add and no reassociation), so the
results are identical bit for bit. Transcendental functions (sin, cos, the ** 1.5 of the
electrodes) stay numpy calls between the kernels: numpy's SIMD loops may differ from libm in the
last bit (see `mechanics`). np.minimum/np.maximum propagate NaN; the comparisons below are
written so that they do too. tests/sim/test_dataset_and_cli.py asserts whole series against a
reference computed before these kernels existed.

Every compiled function of the signal path lives in this one file (numba's on-disk cache follows
the file a function is defined in); none calls into another file.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def mode_state(f0, z0, normal_gain, normal_stiffening, tangential_restraint, sqrt_sar, shear_stiffening,
               abs_strain, friction_damping, slip_fraction, material_damping, freq, zeta):
    """Fill freq and zeta (fingertip_modes.mode_state's arithmetic)."""
    for i in range(f0.size):
        stiff = (1.0 + normal_gain * normal_stiffening[i] + tangential_restraint[i] * sqrt_sar
                 + shear_stiffening[i] * abs_strain)
        freq[i] = f0[i] * np.sqrt(stiff)
        zeta[i] = z0[i] + friction_damping[i] * slip_fraction + material_damping


@njit(cache=True)
def mode_w0(freq, zeta, coupling, f_max, fs_hz, two_pi, w0, amp):
    """Fill the modes' normalized frequencies w0 and peak amplitudes sqrt(gain) (mode_sos, part 1)."""
    for i in range(freq.size):
        f = f_max if freq[i] > f_max else freq[i]                       # np.minimum(freq, f_max)
        gain = coupling[i] / (2.0 * zeta[i])
        gain = 1e-3 if gain < 1e-3 else gain                            # np.maximum(gain, 1e-3)
        amp[i] = np.sqrt(gain)
        w0[i] = two_pi * f / fs_hz


@njit(cache=True)
def mode_sections(sin_w0, cos_w0, zeta, amp, sos):
    """Fill the peaking biquads sos (n, 6) from sin(w0), cos(w0) (mode_sos, part 2)."""
    for i in range(zeta.size):
        alpha = sin_w0[i] * zeta[i]
        cw = -2.0 * cos_w0[i]
        a0 = 1.0 + alpha / amp[i]
        sos[i, 0] = (1.0 + alpha * amp[i]) / a0
        sos[i, 1] = cw / a0
        sos[i, 2] = (1.0 - alpha * amp[i]) / a0
        sos[i, 3] = 1.0
        sos[i, 4] = cw / a0
        sos[i, 5] = (1.0 - alpha / amp[i]) / a0


@njit(cache=True)
def electrode_ratio(pos, center, shift_x, w2, out):
    """Fill out (19,) with w^2 / (w^2 + r_e^2), r_e the distance of electrode e from the contact
    centre shifted by shift_x along x (electrodes.load_share; r^2 summed x, y, z in that order, as
    numpy's sum over an axis of 3 does)."""
    cx, cy, cz = center[0] + shift_x, center[1] + 0.0, center[2] + 0.0
    for j in range(pos.shape[0]):
        dx, dy, dz = pos[j, 0] - cx, pos[j, 1] - cy, pos[j, 2] - cz
        r2 = dx * dx + dy * dy + dz * dz
        out[j] = w2 / (w2 + r2)


@njit(cache=True)
def electrode_counts(normal_force_kpa, share, baseline_kohm, kpa_sensitivity, out):
    """Fill the settled counts (19,) from each electrode's share of the load, (w^2 / (w^2 + r^2))^1.5."""
    for j in range(share.size):
        z_kohm = baseline_kohm * (1.0 + kpa_sensitivity * (normal_force_kpa * share[j]))
        out[j] = 4095.0 / (1.0 + z_kohm / 10.0)


@njit(cache=True)
def electrode_period(normal_force_kpa, share, baseline_kohm, kpa_sensitivity, target, settled, settle_w, offset,
                     drift, drift_decay, drift_innovation, noise, out):
    """One period of the electrodes (Electrodes.__call__): step the drift, fill `target` with the
    settled counts of this contact (electrode_counts), out (n, 19) with the settling means plus
    offsets, drift and noise, and move `settled` to the last sample's mean."""
    n, m = noise.shape
    for j in range(m):
        drift[j] = drift[j] * drift_decay + drift_innovation[j]
    electrode_counts(normal_force_kpa, share, baseline_kohm, kpa_sensitivity, target)
    for i in range(n):
        for j in range(m):
            mean = target[j] + (settled[j] - target[j]) * settle_w[i]
            out[i, j] = mean + offset[j] + drift[j] + noise[i, j]
            if i == n - 1:
                settled[j] = mean


@njit(cache=True)
def pac_drive(unit, gain, bursts, x):
    """Fill x with the P_AC before the modes (Rig.step_period): 0 + unit * gain (the PZT; unit None
    when it is off or absent) + bursts (None without the vibrotactile effect)."""
    for i in range(x.size):
        v = 0.0
        if unit is not None:
            v = v + unit[i] * gain
        if bursts is not None:
            v = v + bursts[i]
        x[i] = v


@njit(cache=True)
def add_at(x, index, values):
    """x[index[k]] += values[k] for k in order (np.add.at's unbuffered, in-order sums)."""
    for k in range(index.size):
        x[index[k]] += values[k]


@njit(cache=True)
def scaled_sum(a, a_scale, b, b_scale, out):
    """Fill out with a * a_scale + b * b_scale (out may be a)."""
    for i in range(out.size):
        out[i] = a[i] * a_scale + b[i] * b_scale


@njit(cache=True)
def pac_counts(x, plus, inv_pa_per_count, lim, out):
    """Fill int16 out with round((x + plus) / pa_per_count) clipped to +/- lim (adc.pac_to_counts;
    plus None: x alone); return whether every x (+ plus) was finite."""
    finite = True
    for i in range(x.size):
        v = x[i]
        if plus is not None:
            v = v + plus[i]
        if not np.isfinite(v):
            finite = False                    # the caller raises; the count is not used
            out[i] = 0
            continue
        c = np.rint(v * inv_pa_per_count)
        c = lim if c > lim else c
        c = -lim if c < -lim else c
        out[i] = np.int16(c)
    return finite


@njit(cache=True)
def uint12_counts(x, full_scale, out):
    """Fill uint16 out (same shape as x) with round(x) clipped to [0, full_scale] (adc.to_uint12)."""
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            c = np.rint(x[i, j])
            if np.isnan(c):
                out[i, j] = 0                 # numpy's cast of nan on x86; not reached with finite inputs
                continue
            c = full_scale if c > full_scale else c
            c = 0.0 if c < 0.0 else c
            out[i, j] = np.uint16(c)


@njit(cache=True)
def pdc_counts(normal_force_kpa, draws, noise_kpa, baseline_counts, pa_per_count, out):
    """Fill out with P_DC counts (pdc.pdc_counts): baseline + (F_N + noise) 1000 / pa_per_count."""
    for i in range(draws.size):
        out[i] = baseline_counts + (normal_force_kpa + draws[i] * noise_kpa) * 1000.0 / pa_per_count


@njit(cache=True)
def level_plus_noise(level, draws, noise, out):
    """Fill out with level + draws * noise (temperature.temperature_counts)."""
    for i in range(draws.size):
        out[i] = level + draws[i] * noise


@njit(cache=True, inline="always")
def _cascade(sos, x, z):
    """Return one sample x through the sections sos (n, 6), updating their states z (n, 2):
    scipy.signal.sosfilt's transposed direct form II, its operations in its order
    (`_sosfilt_float`)."""
    for s in range(sos.shape[0]):
        x_new = sos[s, 0] * x + z[s, 0]
        z[s, 0] = sos[s, 1] * x - sos[s, 4] * x_new + z[s, 1]
        z[s, 1] = sos[s, 2] * x - sos[s, 5] * x_new
        x = x_new
    return x


@njit(cache=True)
def sosfilt_pair(sos_x, x, zx, sos_y, y, zy):
    """Filter x through the sections sos_x from the state zx and y through sos_y from zy, in place
    (states updated), both signals (of one length) in one loop. Each recursion is latency-bound
    (~6 ns a sample here); two independent ones interleave, so the second costs little
    (`sos.filter_pair`)."""
    for n in range(x.size):
        x[n] = _cascade(sos_x, x[n], zx)
        y[n] = _cascade(sos_y, y[n], zy)


_warm = False


def warm_up() -> None:
    """Load every kernel, for each argument layout the rig passes, once per process (from numba's
    cache, or compiled on a fresh checkout), so that it does not fall on a real-time driver's first
    period (as `mechanics.warm_up`)."""
    global _warm
    if _warm:
        return
    v, w, o = np.ones(3), np.ones(3), np.empty(3)
    mode_state(v, v, 0.5, v, v, 0.5, v, 0.5, v, 0.5, 0.0, o, np.empty(3))
    mode_w0(v, v, v, 1.0, 2.0, 6.0, o, np.empty(3))
    mode_sections(v, v, v, v, np.empty((3, 6)))
    slow = np.zeros((2, 22))
    electrode_ratio(np.ones((3, 3)), v, 0.0, 1.0, o)
    electrode_counts(1.0, v, 1.0, 1.0, o)
    for out in (slow[:, :3], np.empty((2, 3))):                  # into the slow block, or a fresh array
        electrode_period(1.0, v, 1.0, 1.0, o, np.ones(3), np.ones(2), v, np.ones(3), 0.5, w, np.ones((2, 3)), out)
    pdc_counts(1.0, np.ones(2), 1.0, 1.0, 1.0, slow[:, 19])
    pdc_counts(1.0, np.ones(2), 1.0, 1.0, 1.0, np.empty(2))
    for draws in (np.ones((2, 2))[0], np.ones(2)):
        for out in (slow[:, 20], np.empty(2)):
            level_plus_noise(1.0, draws, 1.0, out)
    uint12_counts(slow, 4095.0, np.empty((2, 22), np.uint16))
    x = np.empty(3)
    for unit in (None, v):
        for bursts in (None, w):
            pac_drive(unit, 1.0, bursts, x)
    for plus in (None, w):
        pac_counts(v, plus, 1.0, 10.0, np.empty(3, np.int16))
    scaled_sum(v, 1.0, w, 1.0, x)
    add_at(x, np.zeros(2, np.int64), np.ones(2))
    sosfilt_pair(np.ones((2, 6)), np.ones(3), np.zeros((2, 2)), np.ones((1, 6)), np.ones(3), np.zeros((1, 2)))
    _warm = True

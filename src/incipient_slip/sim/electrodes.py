"""The 19 BioTac electrodes: impedance follows local skin compression over each electrode.

Local compression is the contact load spread over the fluid layer, p_e = P (w^2 / (w^2 + r_e^2))^(3/2)
with w^2 = a^2 + h^2, centred on the contact point shifted by the *inner* skin's tangential
displacement; impedance Z = Z0 (1 + kappa p_e); counts = 4095 / (1 + Z / 10 kOhm) (BioTac formula
inverted). Nuisance physics that the paper blames for the electrodes' large errors near full stick:

* inner-skin stiction on the core: the inner skin follows the pad's shear only once the shear load
  exceeds a stiction threshold proportional to F_N (a play operator with half-width
  core_stiction_ratio F_N / k_b, i.e. a fixed band of load ratio near full stick, with memory);
* per-contact baseline offsets (where and how the object sits on the pad differs per series);
* post-contact settling: the fluid redistributes, so a change of load reaches the electrodes with
  a first-order lag (time constant settling_time_s, per 100 Hz sample);
* baseline drift: an Ornstein-Uhlenbeck process (stationary std drift_counts, time constant
  drift_time_s) whose initial value is drawn from its stationary distribution, so a series does
  not start at zero drift.
"""
from __future__ import annotations

import math

import numpy as np

from . import kernels


def play(x_in: float, target: float, half_width: float) -> float:
    """Return the new inner position of a play (backlash) operator: it moves only when the target is
    more than half_width away, and then by just enough."""
    if target - x_in > half_width:
        return target - half_width
    if x_in - target > half_width:
        return target + half_width
    return x_in


def load_share(pos_mm: np.ndarray, center_mm: np.ndarray, p: dict, a_mm: float, shift_mm: float) -> np.ndarray:
    """Return each electrode's share (19,) of the contact load, (w^2 / (w^2 + r_e^2))^(3/2), for the
    electrode positions and contact centre (mm), contact radius a and inner-skin shift."""
    w2 = a_mm**2 + p["fluid_depth_mm"] ** 2
    share = np.empty(len(pos_mm))
    kernels.electrode_ratio(pos_mm, center_mm, p["displacement_coupling"] * shift_mm, w2, share)
    return np.power(share, 1.5, out=share)                 # numpy's power (kernels' docstring)


def electrode_counts_mean(p: dict, normal_force_kpa: float, a_mm: float, shift_mm: float,
                          pos_mm: np.ndarray | None = None, center_mm: np.ndarray | None = None,
                          out: np.ndarray | None = None) -> np.ndarray:
    """Return the noise-free settled counts (19,) for F_N (kPa), contact radius a and inner-skin shift
    (into `out` when given; pos_mm and center_mm: p's positions as arrays, when the caller has them)."""
    pos = np.asarray(p["positions_mm"], float) if pos_mm is None else pos_mm
    center = np.asarray(p["contact_center_mm"], float) if center_mm is None else center_mm
    out = np.empty(len(pos)) if out is None else out
    kernels.electrode_counts(float(normal_force_kpa), load_share(pos, center, p, a_mm, shift_mm),
                             float(p["baseline_kohm"]), float(p["kpa_sensitivity"]), out)
    return out


class Electrodes:
    """Electrode sampler of one series: inner-skin play, settling lag, contact offsets, OU drift, noise."""

    def __init__(self, p: dict, rng: np.random.Generator, n: int = 50, period_s: float = 0.5, block: int = 32):
        self.p = p
        self.n, self.block, self.period_s = n, block, period_s
        self.buf_drift = np.empty((0, 19))
        self.i = 0
        self.inner_mm = 0.0
        self.settled = None                       # counts the fluid has settled to (19,)
        self.offset = rng.standard_normal(19) * p["contact_offset_counts"]
        self.drift_decay = math.exp(-period_s / p["drift_time_s"])
        self.drift = rng.standard_normal(19) * p["drift_counts"]            # stationary start
        tau = p["settling_time_s"]
        t = (np.arange(n) + 1) * (period_s / n)
        with np.errstate(over="ignore", under="ignore"):     # tau -> 0: no settling (weights 0)
            self.settle_w = np.exp(-t / tau) if tau > 0 else np.zeros(n)
        self.pos = np.asarray(p["positions_mm"], float)
        self.center = np.asarray(p["contact_center_mm"], float)
        self.target = np.empty(len(self.pos))
        self.baseline_kohm, self.kpa_sensitivity = float(p["baseline_kohm"]), float(p["kpa_sensitivity"])

    def inner_shift(self, pad_shear_mm: float, stiction_mm: float) -> float:
        """Return the inner skin's displacement after the pad sheared to pad_shear_mm (play operator)."""
        self.inner_mm = play(self.inner_mm, pad_shear_mm, max(stiction_mm, 0.0))
        return self.inner_mm

    def __call__(self, rng: np.random.Generator, n: int, normal_force_kpa: float, a_mm: float,
                 shift_mm: float, out: np.ndarray | None = None) -> np.ndarray:
        """Return (n, 19) counts (unquantized) for this period's contact (into `out` when given):
        target + (settled - target) exp(-t / tau) per sample, plus offsets, drift and noise."""
        if n != self.n:
            raise ValueError(f"electrodes: built for {self.n} samples per period, asked for {n}")
        p = self.p
        if self.i >= len(self.buf_drift):   # noise drawn in blocks of periods (fewer generator calls)
            innov = math.sqrt(max(0.0, 1.0 - self.drift_decay**2)) * p["drift_counts"]
            self.buf_drift = rng.standard_normal((self.block, 19)) * innov
            self.buf_noise = rng.standard_normal((self.block, n, 19)) * p["noise_counts"]
            self.i = 0
        i = self.i
        self.i += 1
        if self.settled is None:                                     # settling from the untouched pad
            self.settled = electrode_counts_mean(p, 0.0, 0.0, 0.0, self.pos, self.center)
        out = np.empty((n, 19)) if out is None else out
        kernels.electrode_period(float(normal_force_kpa), load_share(self.pos, self.center, p, a_mm, shift_mm),
                                 self.baseline_kohm, self.kpa_sensitivity, self.target, self.settled, self.settle_w,
                                 self.offset, self.drift, self.drift_decay, self.buf_drift[i], self.buf_noise[i], out)
        return out

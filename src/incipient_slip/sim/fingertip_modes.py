"""Vibration propagation through a few fingertip modes whose frequency and damping follow the contact state.

Each mode is a peaking biquad (second-order section) with peak gain coupling / (2 zeta) at f.
The paper's mechanism: the propagation depends on the stick state and the deformation of the soft
structure. Each mode's stiffness gains

* tangential restraint of the stick region, proportional to c/a = sqrt(stick-area ratio);
* the pad's shear deformation (bulk shear / pad thickness), `shear_stiffening`;
* a contact-size (F_N) channel, normal_stiffening (a / ref_radius) scaled by `fn_channel_gain`
  (the paper states the biomimetic structure barely suppresses propagation by normal force, so
  this channel is a small prior, only as strong as fitted; docs/calibration.md).

The slipping part of the contact (area fraction 1 - (c/a)^2) adds friction damping. The stick
state enters only through the contact state's stick-area ratio, the same number the truth reports.
Coefficients change once per period (or at a slide); the section states are carried over.
"""
from __future__ import annotations

import numpy as np

from .sos import SosFilter


def mode_state(p: dict, a_mm: float, stick_area_ratio: float, shear_strain: float = 0.0,
               material_damping: float = 0.0):
    """Return (freq_hz, damping_ratio) arrays of the modes for contact radius a, stick-area ratio
    (c/a)^2 and pad shear strain (bulk shear / pad thickness)."""
    f0 = np.asarray(p["freq_hz"], float)
    z0 = np.asarray(p["damping_ratio"], float)
    rel = a_mm / p["ref_radius_mm"]
    sar = min(max(stick_area_ratio, 0.0), 1.0)
    stiff = (1.0 + p["fn_channel_gain"] * rel * np.asarray(p["normal_stiffening"])
             + np.asarray(p["tangential_restraint"]) * np.sqrt(sar)
             + np.asarray(p["shear_stiffening"]) * abs(shear_strain))
    freq = f0 * np.sqrt(stiff)
    zeta = z0 + np.asarray(p["friction_damping"]) * (1.0 - sar) + material_damping
    return freq, zeta


def mode_sos(p: dict, freq_hz: np.ndarray, zeta: np.ndarray, fs_hz: float) -> np.ndarray:
    """Return the cascade of peaking biquads (n_modes, 6) for the given mode frequencies and damping."""
    f = np.minimum(freq_hz, 0.45 * fs_hz)
    gain = np.maximum(np.asarray(p["coupling"], float) / (2.0 * zeta), 1e-3)
    amp = np.sqrt(gain)
    w0 = 2 * np.pi * f / fs_hz
    alpha = np.sin(w0) * zeta          # sin(w0) / (2 Q), Q = 1 / (2 zeta)
    cw = -2.0 * np.cos(w0)
    a0 = 1.0 + alpha / amp
    sos = np.stack([(1.0 + alpha * amp) / a0, cw / a0, (1.0 - alpha * amp) / a0,
                    np.ones_like(a0), cw / a0, (1.0 - alpha / amp) / a0], axis=1)
    return sos


class ModalPath:
    """The fingertip's modal filter with carried state; `last_state` records what it was last given."""

    def __init__(self, p: dict, fs_hz: float):
        self.fs = fs_hz
        self.p = {k: (np.asarray(v, float) if isinstance(v, list) else v) for k, v in p.items()}
        self.filter = SosFilter(np.zeros((len(p["freq_hz"]), 6)))
        self.last_state: tuple[float, float, float] | None = None

    @property
    def zi(self) -> np.ndarray:
        return self.filter.zi

    def __call__(self, x: np.ndarray, a_mm: float, stick_area_ratio: float, shear_strain: float = 0.0,
                 material_damping: float = 0.0) -> np.ndarray:
        """Filter x (contiguous float64, modified in place) with the modes of this contact state."""
        self.last_state = (a_mm, stick_area_ratio, shear_strain)
        sos = mode_sos(self.p, *mode_state(self.p, a_mm, stick_area_ratio, shear_strain, material_damping), self.fs)
        return self.filter.filter_inplace(x, sos)

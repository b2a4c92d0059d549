"""Vibration propagation through a few fingertip modes whose frequency and damping follow the contact.

Each mode is a peaking biquad (second-order section) with peak gain coupling / (2 zeta) at f.
Contact raises f (Hertz normal stiffness ~ a; Mindlin tangential stiffness of the stick region
~ c = a s^(1/3)) and the slipping annulus (area fraction 1 - s^(2/3)) adds friction damping.
Coefficients change once per period (or at a slide); the section states are carried over.
"""
from __future__ import annotations

import numpy as np

from .sos import SosFilter


def mode_state(p: dict, a_mm: float, stick_ratio: float, material_damping: float = 0.0):
    """Return (freq_hz, damping_ratio) arrays of the modes for contact radius a and load ratio s."""
    f0 = np.asarray(p["freq_hz"], float)
    z0 = np.asarray(p["damping_ratio"], float)
    rel = a_mm / p["ref_radius_mm"]
    s = min(max(stick_ratio, 0.0), 1.0)
    stiff = 1.0 + rel * (np.asarray(p["normal_stiffening"]) + np.asarray(p["tangential_restraint"]) * s ** (1 / 3))
    freq = f0 * np.sqrt(stiff)
    zeta = z0 + rel * (np.asarray(p["friction_damping"]) * (1.0 - s ** (2 / 3)) + material_damping)
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
    """The fingertip's modal filter with carried state."""

    def __init__(self, p: dict, fs_hz: float):
        self.fs = fs_hz
        self.p = {k: (np.asarray(v, float) if isinstance(v, list) else v) for k, v in p.items()}
        self.filter = SosFilter(np.zeros((len(p["freq_hz"]), 6)))

    @property
    def zi(self) -> np.ndarray:
        return self.filter.zi

    def __call__(self, x: np.ndarray, a_mm: float, stick_ratio: float, material_damping: float = 0.0) -> np.ndarray:
        """Filter x (contiguous float64, modified in place) with the modes of this contact state."""
        sos = mode_sos(self.p, *mode_state(self.p, a_mm, stick_ratio, material_damping), self.fs)
        return self.filter.filter_inplace(x, sos)

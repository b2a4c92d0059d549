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

from . import kernels
from .sos import SosFilter, filter_pair


def mode_state(p: dict, a_mm: float, stick_area_ratio: float, shear_strain: float = 0.0,
               material_damping: float = 0.0, out: tuple[np.ndarray, np.ndarray] | None = None):
    """Return (freq_hz, damping_ratio) arrays of the modes for contact radius a, stick-area ratio
    (c/a)^2 and pad shear strain (bulk shear / pad thickness):

        freq = f0 sqrt(1 + fn_channel_gain (a / ref_radius) normal_stiffening
                         + tangential_restraint sqrt(sar) + shear_stiffening |strain|)
        zeta = z0 + friction_damping (1 - sar) + material_damping,  sar clipped to [0, 1]

    (into `out` = (freq, zeta) when given)"""
    f0 = np.asarray(p["freq_hz"], float)
    freq, zeta = (np.empty(f0.size), np.empty(f0.size)) if out is None else out
    sar = min(max(stick_area_ratio, 0.0), 1.0)
    kernels.mode_state(f0, np.asarray(p["damping_ratio"], float),
                       float(p["fn_channel_gain"] * (a_mm / p["ref_radius_mm"])),
                       np.asarray(p["normal_stiffening"], float), np.asarray(p["tangential_restraint"], float),
                       float(np.sqrt(sar)), np.asarray(p["shear_stiffening"], float), float(abs(shear_strain)),
                       np.asarray(p["friction_damping"], float), float(1.0 - sar), float(material_damping), freq, zeta)
    return freq, zeta


def mode_sos(p: dict, freq_hz: np.ndarray, zeta: np.ndarray, fs_hz: float, out: np.ndarray | None = None,
             work: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Return the cascade of peaking biquads (n_modes, 6) for the given mode frequencies and damping:
    peak gain max(coupling / (2 zeta), 1e-3) at min(freq, 0.45 fs) (audio-EQ cookbook peaking EQ,
    alpha = sin(w0) zeta, i.e. Q = 1 / (2 zeta)); into `out` when given (`work`: two scratch arrays)."""
    n = len(zeta)
    w0, amp = (np.empty(n), np.empty(n)) if work is None else work
    sos = np.empty((n, 6)) if out is None else out
    zeta = np.asarray(zeta, float)
    kernels.mode_w0(np.asarray(freq_hz, float), zeta, np.asarray(p["coupling"], float), float(0.45 * fs_hz),
                    float(fs_hz), 2 * np.pi, w0, amp)
    kernels.mode_sections(np.sin(w0), np.cos(w0), zeta, amp, sos)   # numpy's sin and cos (module docstring)
    return sos


class ModalPath:
    """The fingertip's modal filter with carried state; `last_state` records what it was last given."""

    def __init__(self, p: dict, fs_hz: float):
        self.fs = fs_hz
        self.p = {k: (np.asarray(v, float) if isinstance(v, list) else v) for k, v in p.items()}
        self.filter = SosFilter(np.zeros((len(p["freq_hz"]), 6)))
        self.last_state: tuple[float, float, float] | None = None
        n = len(p["freq_hz"])
        self.buffers = [np.empty(n) for _ in range(4)]        # freq, zeta, w0, amp of the last call

    @property
    def zi(self) -> np.ndarray:
        return self.filter.zi

    def __call__(self, x: np.ndarray, a_mm: float, stick_area_ratio: float, shear_strain: float = 0.0,
                 material_damping: float = 0.0, twin: tuple[np.ndarray, SosFilter] | None = None) -> np.ndarray:
        """Filter x (contiguous float64, modified in place) with the modes of this contact state;
        twin = (y, its filter): filter y too, with the same coefficients from its own filter's
        state (the PZT-absent twin of `Rig`), in the same loop."""
        self.last_state = (a_mm, stick_area_ratio, shear_strain)
        freq, zeta, w0, amp = self.buffers
        mode_state(self.p, a_mm, stick_area_ratio, shear_strain, material_damping, out=(freq, zeta))
        sos = mode_sos(self.p, freq, zeta, self.fs, work=(w0, amp))
        if twin is None:
            return self.filter.filter_inplace(x, sos)
        y, other = twin
        self.filter.sos = other.sos = np.ascontiguousarray(sos)
        filter_pair(self.filter, x, other, y)
        return x

"""The stages of one simulated period, built once from the scene (MuJoCo's `mj_step` style).

`Rig.step_period` runs them in this order; a scene without an effect has no stage for it:

1. `MechanicsStage` (always): the contact's mechanics and the object's mocap samples, one compiled
   call (`mechanics.period_mocap`, the same function `mechanics.run_series` loops over a series).
   Its result, `Contact`, is what every later stage reads.
2. `PacStage` (injection, vibrotactile or ambient noise): the P_AC drive (the PZT's band noise,
   the micro-slip bursts), the fingertip's modes, the ambient hum and the conversion to counts;
   optionally the same period without the PZT (`pac_without_pzt`, a scene view of the data sets).
3. `SlowStage` (electrodes, P_DC or temperature): the 100 Hz channels, one 12-bit conversion.
4. `check_truth`: the period's truth is finite.

Each stage draws only from its own random streams (`rig.STREAMS`), so the order of the stages
never changes a number; within a stage the draws are in the order they always were (the
simulator is bit for bit against tests/data/sim_series.json).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import adc, kernels, mechanics
from .ambient_noise import AmbientNoise
from .electrodes import Electrodes
from .fingertip_modes import ModalPath
from .injection import PztSource
from .pdc import pdc_counts
from .sos import SosFilter, filter_pair
from .stick_slip import ContactState, SimulationError, raise_status
from .temperature import temperature_counts
from .vibrotactile import bursts_pa


@dataclass(frozen=True)
class Contact:
    """What the mechanics stage leaves for the others: one period's contact (N, mm, s)."""

    period: int
    t_start_s: float
    normal_force_kpa: float
    normal_force_n: float        # 0 without contact
    in_contact: bool
    a_mm: float                  # contact radius
    k_bulk: float                # the pad's shear stiffness at this F_N (N/mm)
    stick_area_ratio: float
    load_ratio_stick: float
    tangential_force_n: float
    gross_slip: bool
    slide_s: float               # the slide's duration within the period
    slide_t0_s: float            # its start within the period
    bulk_mm: float               # the pad's bulk shear Q / k_b at the end of the period
    mocap_t_s: np.ndarray | None
    mocap_y_mm: np.ndarray | None


class MechanicsStage:
    """Contact, stick-slip and mocap of one period on the rig's contact state."""

    def __init__(self, state: ContactState, params: np.ndarray, mu_s: float, friction: np.random.Generator,
                 has_stick_slip: bool, mocap: np.random.Generator | None, mocap_tt: np.ndarray | None):
        self.state, self.params, self.mu_s = state, params, mu_s
        self.friction, self.mocap = friction, mocap
        self.has_stick_slip = has_stick_slip
        self.tt = mocap_tt if mocap_tt is not None else np.empty(0)
        self.period_s = float(params[mechanics.P_PERIOD])

    def __call__(self, k: int, fn_kpa: float) -> Contact:
        st, n = self.state, self.tt.size
        draw = self.friction.standard_normal()
        mocap = self.mocap.standard_normal(n) if self.mocap is not None else self.tt
        mt, my = np.empty(n), np.empty(n)
        status, out_fn, in_contact, a_mm, k_bulk, sar, s_ratio, q, gross, slide_s = mechanics.period_mocap(
            st.values, self.params, k, fn_kpa, draw, self.has_stick_slip, mocap, self.tt, mt, my)
        if status:
            f = st.friction_force_n if in_contact else 0.0
            raise_status(status, k, f if not math.isnan(f) else None, self.mu_s, k_bulk, st.values)
        has_mocap = self.mocap is not None
        return Contact(k, k * self.period_s, fn_kpa, out_fn, in_contact, a_mm, k_bulk, sar, s_ratio, float(q), gross,
                       slide_s, st.slide_t0_s, st.bulk_mm, mt if has_mocap else None, my if has_mocap else None)


class PacStage:
    """P_AC of one period (2200 Hz counts): the PZT's noise, micro-slip bursts, the fingertip's
    modes and the ambient hum, as the scene has them."""

    def __init__(self, p: dict, has, fs: float, n: int, rng: dict, roughness: float, material_damping: float,
                 pac_without_pzt: bool):
        self.p, self.fs, self.n, self.rng = p, fs, n, rng
        self.roughness, self.material_damping = roughness, material_damping
        self.band = PztSource(p["injection"], fs, n) if has("injection") else None
        self.modes = ModalPath(p["fingertip_modes"], fs) if has("fingertip_modes") else None
        self.ambient = AmbientNoise(p["ambient_noise"], fs, n) if has("ambient_noise") else None
        self.has_vibrotactile = has("vibrotactile")
        self.pad_thickness_mm = p["fingertip_modes"]["pad_thickness_mm"] if "fingertip_modes" in p else None
        self.pac_without_pzt = pac_without_pzt
        self.filter_without_pzt = (SosFilter(np.zeros((len(p["fingertip_modes"]["freq_hz"]), 6)))
                                   if pac_without_pzt and self.modes is not None else None)

    def __call__(self, c: Contact, prev_sar: float, pzt_on: bool, pzt_db: float,
                 sar_seen: dict) -> tuple[np.ndarray, np.ndarray | None]:
        """Return (P_AC counts, the same period's counts without the PZT or None); `sar_seen`
        gets the stick ratio the modes used."""
        x, off = self._drive(c, prev_sar, pzt_on, pzt_db)
        if self.modes is not None:
            self._modes(c, x, off)
            sar_seen["modes"] = self.modes.last_state[1]
        hum = self.ambient.next(self.rng["ambient"]) if self.ambient is not None else None
        ad = self.p["adc"]
        pac, finite = adc.pac_to_counts_finite(x, ad["pac_pa_per_count"], ad["pac_range_pa"], hum)
        pac_off = None
        if off is not None:
            pac_off, finite_off = adc.pac_to_counts_finite(off, ad["pac_pa_per_count"], ad["pac_range_pa"], hum)
            finite = finite and finite_off
        if not finite:
            raise SimulationError(f"step {c.period}: non-finite P_AC (F_N={c.normal_force_kpa} kPa, "
                                  f"s={c.load_ratio_stick})")
        return pac, pac_off

    def _drive(self, c: Contact, prev_sar: float, pzt_on: bool, pzt_db: float):
        """The drive of the modes (Pa): the PZT's band noise and the bursts; and its PZT-absent twin."""
        p, rng, n = self.p, self.rng, self.n
        if self.band is not None and self.ambient is not None and self.band.due and self.ambient.due:
            # both noises start a block: their filters run in one loop (sos.filter_pair)
            x, y = self.band.draw(rng["injection"]), self.ambient.draw(rng["ambient"])
            filter_pair(self.band.filter, x, self.ambient.filter, y)
            self.band.fill(x)
            self.ambient.fill(y)
        # the PZT's band noise is drawn even when it is off (the streams stay aligned)
        unit = self.band.next(rng["injection"]) if self.band is not None else None
        gain = p["injection"]["pa_per_unit"] * 10.0 ** (pzt_db / 20.0) if pzt_on else 0.0
        bursts = (bursts_pa(rng["vibrotactile"], n, self.fs, p["vibrotactile"], prev_sar - c.stick_area_ratio,
                            c.slide_s, c.slide_t0_s, self.roughness, p["injection"]["pa_per_unit"])
                  if self.has_vibrotactile else None)
        x = np.empty(n)
        kernels.pac_drive(unit if pzt_on else None, gain, bursts, x)
        # the PZT-absent twin (pac_without_pzt): the same sums in the same order, minus the PZT term
        off = None
        if self.pac_without_pzt:
            off = np.empty(n)
            kernels.pac_drive(None, 0.0, bursts, off)
        return x, off

    def _modes(self, c: Contact, x: np.ndarray, off: np.ndarray | None) -> None:
        """Filter the drive (and its twin, same coefficients, own state) through the modes, in place:
        a gross slip splits the period at the slide's end (sliding modes, then the stick ratio's)."""
        n = self.n
        shear_strain = c.bulk_mm / self.pad_thickness_mm if self.pad_thickness_mm is not None else 0.0
        n_split = min(n, int(math.ceil((c.slide_t0_s + c.slide_s) * self.fs))) if c.gross_slip else 0
        for part, s_part in ((slice(0, n_split), 0.0), (slice(n_split, n), c.stick_area_ratio)):
            if part.stop > part.start:
                self.modes(x[part], c.a_mm, s_part, shear_strain, self.material_damping,
                           twin=None if off is None else (off[part], self.filter_without_pzt))


class SlowStage:
    """The 100 Hz channels of one period, one 12-bit conversion of columns E1..E19, P_DC, T_AC, T_DC:
    returns (electrodes, pdc, tac, tdc) counts, None for a channel the scene does not have."""

    def __init__(self, p: dict, has, rng: dict, n_slow: int, period_s: float):
        self.p, self.rng, self.n = p, rng, n_slow
        self.electrodes = Electrodes(p["electrodes"], rng["electrodes"], n_slow, period_s) if has("electrodes") else None
        self.has_pdc, self.has_temperature = has("pdc"), has("temperature")

    def __call__(self, c: Contact):
        p, rng, n = self.p, self.rng, self.n
        slow = np.zeros((n, 22))
        if self.electrodes is not None:
            stiction_mm = p["electrodes"]["core_stiction_ratio"] * c.normal_force_n / c.k_bulk
            shift = self.electrodes.inner_shift(c.bulk_mm if c.in_contact else 0.0, stiction_mm)
            self.electrodes(rng["electrodes"], n, c.normal_force_kpa if c.in_contact else 0.0, c.a_mm, shift,
                            out=slow[:, :19])
        if self.has_pdc:
            pdc_counts(rng["pdc"], n, c.normal_force_kpa, p["pdc"], p["adc"]["pdc_pa_per_count"], out=slow[:, 19])
        if self.has_temperature:
            temperature_counts(rng["temperature"], n, p["temperature"], out=(slow[:, 20], slow[:, 21]))
        slow = adc.to_uint12(slow, int(p["adc"]["full_scale_counts"]))
        elec = slow[:, :19].copy() if self.electrodes is not None else None
        pdc = slow[:, 19].copy() if self.has_pdc else None
        tac, tdc = (slow[:, 20].copy(), slow[:, 21].copy()) if self.has_temperature else (None, None)
        return elec, pdc, tac, tdc


def check_truth(c: Contact, y_mm: float) -> None:
    """Raise SimulationError when the period's truth is not finite (the first such field named)."""
    status = mechanics.output_status(c.tangential_force_n, y_mm, c.stick_area_ratio, c.load_ratio_stick)
    if status:
        name = mechanics.OUTPUT_CHECKED[status - mechanics.OUTPUT_STATUS]
        value = (c.tangential_force_n, y_mm, c.stick_area_ratio, c.load_ratio_stick)[status - mechanics.OUTPUT_STATUS]
        raise SimulationError(f"step {c.period}: non-finite {name} = {value}")

"""The simulated rig: one physics core stepped one 500 ms sampling period at a time.

Both drivers call exactly this: the in-process data set generator (`sim.dataset`) and the
`rig_sim` node. Usage::

    rig = Rig(load_scene("paper"), material="pla", seed=7)
    rig.set_injection(True, 0.0)                 # PZT on at I = 0 dB (scene default)
    out = rig.step_period(normal_force_kpa=3.1)  # one period; the actuator steps at its end
    out.pac_counts      # int16 (1100,) or None when the scene has no P_AC effect

Period k spans [k T, (k+1) T) with T = 0.5 s. The actuator position is constant during the
period and steps 23/450 mm at its end when `actuator_step` is True. Effects not listed in the
scene are not computed and their outputs are None.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import contact, kernels, mechanics
from .feasibility import material_mu
from .scene import Scene, load_scene  # noqa: F401  (re-exported)
from .stages import Contact, MechanicsStage, PacStage, SlowStage, check_truth
from .stick_slip import ContactState, SimulationError, raise_status

MECHANICS = ("contact", "stick_slip", "mocap")   # the effects `run_mechanics` computes, all of them
STREAMS = ("friction", "injection", "vibrotactile", "ambient", "electrodes", "pdc", "temperature", "mocap")


@dataclass
class PeriodOutput:
    """One 500 ms period of sensor streams (raw counts) and physical truth.

    Sensor arrays are None when the scene does not compute the effect behind them.
    """

    period: int
    t_start_s: float
    pac_counts: np.ndarray | None          # int16 (1100,), 0.37 Pa/count, 2200 Hz
    electrode_counts: np.ndarray | None    # uint16 (50, 19), 100 Hz
    pdc_counts: np.ndarray | None          # uint16 (50,)
    tac_counts: np.ndarray | None          # uint16 (50,)
    tdc_counts: np.ndarray | None          # uint16 (50,)
    mocap_t_s: np.ndarray | None           # float64 (60,), absolute series time
    mocap_y_mm: np.ndarray | None          # float64 (60,), measured travel
    normal_force_kpa: float                # F_N during the period
    tangential_force_n: float              # spring force F_T at the end of the period
    actuator_mm: float                     # actuator position during the period
    object_y_mm: float                     # true travel at the end of the period
    stick_area_ratio: float                # true (c/a)^2 at the end (0 while sliding)
    load_ratio_stick: float                # 1 - Q / (mu_s F_N) at the end (0 while sliding)
    gross_slip: bool                       # the object slid during this period
    pzt_on: bool
    pzt_intensity_db: float


def series_seed(dataset_seed: int, series_index: int) -> int:
    """Return a series' own seed (int63) derived from (dataset seed, series index) by SeedSequence."""
    state = np.random.SeedSequence(int(dataset_seed), spawn_key=(int(series_index),)).generate_state(2, np.uint32)
    return int((int(state[0]) << 31) ^ int(state[1])) & 0x7FFF_FFFF_FFFF_FFFF


class Rig:
    """A simulated rig for one material and seed; `step_period` advances one sampling period."""

    def __init__(self, scene: Scene, material: str, seed: int, pac_without_pzt: bool = False):
        """pac_without_pzt: also compute, each period, the P_AC the same period would have had
        with the PZT absent (the no-injection scene's, exactly: same draws, its own modal filter
        state) into `last_pac_without_pzt`, so one run gives both scenes' data (`sim.dataset`)."""
        if material not in scene.params["materials"]:
            raise ValueError(f"unknown material {material!r} (known: {', '.join(scene.params['materials'])})")
        self.scene, self.material, self.seed = scene, material, int(seed)
        p = scene.params
        self.p = p
        tm = p["timing"]
        self.fs = float(tm["pac_rate_hz"])
        self.period_s = float(tm["period_s"])
        self.n_pac = int(round(self.fs * self.period_s))
        self.n_slow = int(round(tm["slow_rate_hz"] * self.period_s))
        self.n_mocap = int(round(tm["mocap_rate_hz"] * self.period_s))
        children = np.random.SeedSequence(self.seed).spawn(len(STREAMS))
        self.rng = {name: np.random.default_rng(ss) for name, ss in zip(STREAMS, children)}
        mat = p["materials"][material]
        ss = p["stick_slip"]
        self.mu_s = material_mu(p, material) * (1.0 + ss["mu_series_jitter"] * self.rng["friction"].standard_normal())
        self.roughness = mat["roughness"]
        c = p["contact"]
        self.radius_mm = contact.effective_radius_mm(c)
        self.e_star, _ = contact.effective_moduli_mpa(c, mat["object_modulus_mpa"])
        self.g_star_int = contact.interfacial_shear_modulus_mpa(c, mat["object_modulus_mpa"])
        # soft objects add a little damping to the modes (assumption: proportional to skin/object compliance ratio)
        self.material_damping = 0.01 * min(1.0, c["skin_modulus_mpa"] / mat["object_modulus_mpa"])
        self.spring_n_per_mm = ss["spring_n_per_mm"]
        self.step_mm = ss["actuator_travel_mm"] / ss["actuator_steps"]
        self.state = ContactState()
        ps = p["pre_slip"]
        values = {"newton_per_kpa": c["newton_per_kpa"], "min_contact_force_n": c["min_contact_force_n"],
                  "friction_limit_lag_s": ss["friction_limit_lag_s"], "period_s": self.period_s,
                  "radius_mm": self.radius_mm, "e_star_mpa": self.e_star,
                  "contact_saturation_radius_mm": c["contact_saturation_radius_mm"], "mu_series": self.mu_s,
                  "mu_period_jitter": ss["mu_period_jitter"], "bulk_shear_n_per_mm": ps["bulk_shear_n_per_mm"],
                  "bulk_ref_force_n": ps["bulk_ref_force_n"],
                  "bulk_stiffening_exponent": ps["bulk_stiffening_exponent"], "g_star_int_mpa": self.g_star_int,
                  "spring_n_per_mm": self.spring_n_per_mm, "rate_strengthening": ss["rate_strengthening"],
                  "creep_reference_velocity_mm_s": ss["creep_reference_velocity_mm_s"],
                  "restick_velocity_mm_s": ss["restick_velocity_mm_s"], "step_mm": self.step_mm,
                  "mocap_rate_hz": tm["mocap_rate_hz"],
                  "mocap_noise_mm": p["mocap"]["noise_mm"] if "mocap" in p else 0.0}
        self.mech_params = np.array([float(values[name]) for name in mechanics.PARAMS])
        mechanics.warm_up()                              # once per process, not in the first period
        kernels.warm_up()
        self.period = 0
        self.prev_sar = 1.0
        self.pzt_on = scene.has("injection")
        self.pzt_db = scene.injection_db
        self.last_pac_without_pzt: np.ndarray | None = None
        self.last_sar_seen: dict[str, float] = {}
        self._build_stages(pac_without_pzt)

    def _build_stages(self, pac_without_pzt: bool) -> None:
        """The period's stages for the scene's effects (`sim.stages`), once; the filters and
        electrodes they own stay reachable as rig.band, rig.modes, rig.ambient, rig.electrodes."""
        scene, p, has = self.scene, self.p, self.scene.has
        self.has_pac = has("injection") or has("vibrotactile") or has("ambient_noise")
        if pac_without_pzt and not self.has_pac:
            raise ValueError(f"scene {scene.name!r} has no P_AC effect; pac_without_pzt needs one")
        self.pac_without_pzt = pac_without_pzt
        mocap_tt = np.arange(self.n_mocap) / p["timing"]["mocap_rate_hz"] if has("mocap") else None
        self.mechanics_stage = MechanicsStage(self.state, self.mech_params, self.mu_s, self.rng["friction"],
                                        has("stick_slip"), self.rng["mocap"] if has("mocap") else None, mocap_tt)
        self.pac_stage = (PacStage(p, has, self.fs, self.n_pac, self.rng, self.roughness, self.material_damping,
                             pac_without_pzt) if self.has_pac else None)
        self.slow_stage = (SlowStage(p, has, self.rng, self.n_slow, self.period_s)
                     if has("electrodes") or has("pdc") or has("temperature") else None)
        for name in ("band", "modes", "ambient", "filter_without_pzt"):
            setattr(self, name, getattr(self.pac_stage, name, None))
        self.electrodes = getattr(self.slow_stage, "electrodes", None)

    @property
    def friction_force_n(self) -> float | None:
        """The normal force (N) the friction limit follows (F_N lagged), None before the first period."""
        f = self.state.friction_force_n
        return None if math.isnan(f) else f

    def set_injection(self, on: bool, intensity_db: float | None = None) -> None:
        """Switch the PZT noise on or off and set its intensity I (dB); needs the 'injection' effect."""
        if on and not self.scene.has("injection"):
            raise ValueError(f"scene {self.scene.name!r} has no 'injection' effect; cannot switch the PZT on")
        if intensity_db is not None:
            if not math.isfinite(intensity_db):
                raise ValueError(f"PZT intensity must be finite, got {intensity_db}")
            self.pzt_db = float(intensity_db)
        self.pzt_on = bool(on)

    def step_period(self, normal_force_kpa: float, actuator_step: bool = True) -> PeriodOutput:
        """Return the sensor streams and truth of the next 500 ms period at normal force F_N (kPa)."""
        k = self.period
        fn_kpa = float(normal_force_kpa)
        if not math.isfinite(fn_kpa) or fn_kpa < 0.0:
            raise ValueError(f"step {k}: normal_force_kpa must be finite and >= 0, got {normal_force_kpa}")
        c = self.mechanics_stage(k, fn_kpa)
        self.last_sar_seen = {}
        pac = None
        if self.pac_stage is not None:
            pac, off = self.pac_stage(c, self.prev_sar, self.pzt_on, self.pzt_db, self.last_sar_seen)
            if self.pac_without_pzt:
                self.last_pac_without_pzt = off
        elec, pdc, tac, tdc = self.slow_stage(c) if self.slow_stage is not None else (None,) * 4
        st = self.state
        check_truth(c, st.y_mm)
        out = self._output(c, pac, elec, pdc, tac, tdc)
        self.prev_sar = c.stick_area_ratio
        self.period += 1
        if actuator_step:
            st.actuator_mm += self.step_mm
        return out

    def _output(self, c: Contact, pac, elec, pdc, tac, tdc) -> PeriodOutput:
        st = self.state
        return PeriodOutput(
            period=c.period, t_start_s=c.t_start_s, pac_counts=pac, electrode_counts=elec, pdc_counts=pdc,
            tac_counts=tac, tdc_counts=tdc, mocap_t_s=c.mocap_t_s, mocap_y_mm=c.mocap_y_mm,
            normal_force_kpa=c.normal_force_kpa, tangential_force_n=c.tangential_force_n,
            actuator_mm=st.actuator_mm, object_y_mm=st.y_mm, stick_area_ratio=c.stick_area_ratio,
            load_ratio_stick=c.load_ratio_stick, gross_slip=c.gross_slip,
            pzt_on=self.pzt_on and self.band is not None, pzt_intensity_db=self.pzt_db)

    def run_mechanics(self, normal_force_kpa, travel_rule: tuple[float, float, float], actuator_step: bool = True,
                      stop_travel_mm: float = math.inf) -> dict[str, np.ndarray]:
        """Run one period per F_N in `normal_force_kpa` in one compiled call and return their truth
        as arrays: exactly the numbers of as many `step_period` calls (same state afterwards, same
        random streams), for a scene whose effects are MECHANICS (contact, stick_slip, mocap).

        Keys: `mechanics.COLUMNS` (object_y_mm, tangential_force_n, stick_area_ratio,
        load_ratio_stick, gross_slip and sliding as bools, slide_q0_n, actuator_mm during the
        period, friction_force_n after it, and travel_mm: the object's travel within the period
        on its mocap samples, as `models.labels.gross_slip_travel_mm` reads it, with
        `travel_rule` = (span, early, late) in s, that rule's constants) plus normal_force_kpa.
        Stops after the first period whose travel_mm is >= stop_travel_mm (the arrays end there).
        The mocap samples themselves are not returned."""
        if set(self.scene.effects) != set(MECHANICS):
            raise ValueError(f"run_mechanics needs a scene with the effects {', '.join(MECHANICS)}; "
                             f"scene {self.scene.name!r} has {', '.join(self.scene.effects)}")
        forces = np.array(normal_force_kpa, dtype=np.float64).reshape(-1)
        bad = np.flatnonzero(~(np.isfinite(forces) & (forces >= 0.0)))
        if bad.size:
            raise ValueError(f"step {self.period + int(bad[0])}: normal_force_kpa must be finite and >= 0, "
                             f"got {forces[bad[0]]}")
        n = forces.size
        streams = (self.rng["friction"], self.rng["mocap"])
        saved = [g.bit_generator.state for g in streams]
        friction = streams[0].standard_normal(n)            # the draws n step_period calls would make
        mocap = streams[1].standard_normal((n, self.n_mocap))
        out = np.empty((n, len(mechanics.COLUMNS)))
        done, status, step = mechanics.run_series(self.state.values, self.mech_params, self.period, forces, friction,
                                                  mocap, bool(actuator_step), float(stop_travel_mm),
                                                  np.array(travel_rule, dtype=np.float64), out)
        if done < n:                                        # stopped early: leave the streams where
            for g, st in zip(streams, saved):               # `done` step_period calls would
                g.bit_generator.state = st
            streams[0].standard_normal(done)
            streams[1].standard_normal((done, self.n_mocap))
        self.period += done                               # the periods before a failing one count
        self.last_sar_seen = {}
        if done:
            self.prev_sar = float(out[done - 1, mechanics.C_SAR])
        if status >= mechanics.OUTPUT_STATUS:
            name = mechanics.OUTPUT_CHECKED[status - mechanics.OUTPUT_STATUS]
            raise SimulationError(f"step {step}: non-finite {name}")
        if status:
            raise_status(status, step, self.state.friction_force_n, self.mu_s, math.nan, self.state.values)
        res = {name: out[:done, i] for i, name in enumerate(mechanics.COLUMNS)}
        res["gross_slip"] = res["gross_slip"] != 0.0
        res["sliding"] = res["sliding"] != 0.0
        res["normal_force_kpa"] = forces[:done]
        return res

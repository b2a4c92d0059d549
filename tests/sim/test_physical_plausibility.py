"""Physical-plausibility checks of the mechanics (not tuned toward any estimation method).

* The Mindlin-Deresiewicz "ratchet" (no spring-back when F_N rises) must not make the travel grow
  without bound when F_N cycles at (nearly) constant tangential load below mu F_N,min: frictional
  shakedown of an uncoupled (similar-material Hertz) contact (Klarbring, Ciavarella & Barber 2007).
* ORACLE: the paper's grip law fed the simulator's TRUE pseudo-stick ratio. The paper shows that
  holding the object (y <= 1.5 mm for 450 steps) is possible. With the normal-force-dependent
  tangential stiffness (Pataky et al. 2005; docs/simulator.md) it holds on PLA, ABS, PETG and
  nylon; TPU (whose assumed friction puts its onset travel outside the paper's range) is a strict xfail.
"""
import numpy as np
import pytest

from incipient_slip.control import SAFETY_LIMIT_KPA
from incipient_slip.sim import Rig, load_scene
from incipient_slip.sim import contact, partial_slip
from incipient_slip.experiments.calibration import oracle_hold
from incipient_slip.sim.scene import scene_from_dict


def _mechanics(**stick_slip):
    return scene_from_dict({"effects": ["contact", "stick_slip", "mocap"], "overrides": {"stick_slip": stick_slip}},
                           "test.yaml")


@pytest.mark.parametrize("material", ["pla", "tpu"])
def test_ratchet_shakes_down_when_fn_cycles_at_constant_actuator(material):
    rig = Rig(_mechanics(mu_period_jitter=0.0), material, 11)
    for _ in range(120):                       # load the spring at high F_N, well below mu F_N,min
        rig.step_period(5.9)
    q0 = rig.k * (rig.rail.actuator_mm - rig.rail.y_mm)
    assert q0 < 0.8 * rig.mu_s * 1.1 * rig.p["contact"]["newton_per_kpa"]
    outs = [rig.step_period(1.1 if k % 2 else 5.9, actuator_step=False) for k in range(300)]
    y = np.array([o.object_y_mm for o in outs])
    assert not any(o.gross_slip for o in outs)
    assert np.all(np.diff(y) >= -1e-12)        # no spring-back (ratchet) ...
    assert y[-1] - y[3] < 1e-9                 # ... but no growth after the first low-F_N period
    # bounded by the Mindlin displacement at F_N,min under the initial load q0 (Q only falls as y grows)
    c = rig.p["contact"]
    fn_min = 1.1 * c["newton_per_kpa"]
    a_min = contact.contact_radius_mm(fn_min, rig.radius_mm, rig.e_star)
    g_min = contact.tangential_shear_modulus_mpa(rig.g_star_t_ref, fn_min, c["tangential_ref_force_n"],
                                                 c["tangential_stiffening_exponent"], c["min_contact_force_n"])
    bound = partial_slip.displacement_mm(q0, rig.mu_s * fn_min,
                                         partial_slip.max_displacement_mm(rig.mu_s * fn_min, g_min, a_min))
    assert y[-1] <= bound + 1e-9, (y[-1], bound)


@pytest.fixture(scope="module")
def oracle():
    return oracle_hold(load_scene("mechanics"), seeds=1)


def test_oracle_drives_the_true_stick_ratio_to_the_target_without_gross_slip(oracle):
    for mat, r in oracle.items():
        assert abs(r["s"] - 0.3) < 0.05, (mat, r)
        assert 1.1 <= r["fn"] < SAFETY_LIMIT_KPA, (mat, r)
        assert r["y_max"] < 3.0, (mat, r)      # pre-slip only: a gross slide would carry it further


@pytest.mark.parametrize("material", [
    "pla", "abs", "petg", "nylon",
    pytest.param("tpu", marks=pytest.mark.xfail(
        strict=True, reason="known miss: TPU (mu_s 0.85, an assumption) has onset travel ~2.5 mm, outside "
                            "1.5 +/- 0.4 mm; 0.55 delta_max at s = 0.3 is ~1.55 mm > 1.5 mm; see docs/simulator.md")),
])
def test_oracle_holds_the_object(oracle, material):
    r = oracle[material]
    assert r["held"] == 1.0 and r["y_max"] <= 1.5, r

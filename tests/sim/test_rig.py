"""The stepping API: shapes, dtypes, effects on/off, determinism per seed."""

import numpy as np
import pytest
from scipy import signal

from incipient_slip.sim import Rig, load_scene, series_seed
from incipient_slip.sim.sos import sosfilt_state


def test_period_output_has_the_documented_shapes_and_dtypes():
    out = Rig(load_scene("paper"), "pla", 0).step_period(3.1)
    assert out.pac_counts.dtype == np.int16 and out.pac_counts.shape == (1100,)
    assert out.electrode_counts.dtype == np.uint16 and out.electrode_counts.shape == (50, 19)
    for name in ("pdc_counts", "tac_counts", "tdc_counts"):
        arr = getattr(out, name)
        assert arr.dtype == np.uint16 and arr.shape == (50,)
    assert out.mocap_t_s.shape == out.mocap_y_mm.shape == (60,)
    assert out.stick_area_ratio == pytest.approx(1.0) and out.load_ratio_stick == pytest.approx(1.0)
    assert out.tangential_force_n == pytest.approx(0.0, abs=1e-12)


def test_effects_not_in_the_scene_produce_none():
    out = Rig(load_scene("mechanics"), "pla", 0).step_period(3.1)
    assert out.pac_counts is None and out.electrode_counts is None and out.pdc_counts is None
    assert out.mocap_y_mm is not None


def test_same_seed_same_data_other_seed_other_data():
    a, b, c = (Rig(load_scene("paper"), "abs", s) for s in (5, 5, 6))
    for _ in range(3):
        oa, ob, oc = a.step_period(2.3), b.step_period(2.3), c.step_period(2.3)
    assert np.array_equal(oa.pac_counts, ob.pac_counts) and np.array_equal(oa.electrode_counts, ob.electrode_counts)
    assert not np.array_equal(oa.pac_counts, oc.pac_counts)


def test_injection_off_keeps_the_mechanics_identical():
    on, off = Rig(load_scene("paper"), "pla", 3), Rig(load_scene("no_injection"), "pla", 3)
    for k in range(40):
        o1, o2 = on.step_period(2.0 + 0.1 * (k % 5)), off.step_period(2.0 + 0.1 * (k % 5))
    assert o1.object_y_mm == o2.object_y_mm and o1.tangential_force_n == o2.tangential_force_n
    assert np.std(o1.pac_counts) > 5 * np.std(o2.pac_counts)
    assert o1.pzt_on and not o2.pzt_on


def test_switching_the_pzt_on_without_the_effect_is_an_error():
    with pytest.raises(ValueError, match="no 'injection' effect"):
        Rig(load_scene("no_injection"), "pla", 0).set_injection(True, 0.0)


def test_unknown_material_is_an_error_naming_the_known_ones():
    with pytest.raises(ValueError, match="unknown material 'wood'.*pla"):
        Rig(load_scene("paper"), "wood", 0)


def test_fast_sos_path_equals_scipy_sosfilt():
    sos = signal.butter(4, [20, 900], btype="bandpass", fs=2200, output="sos")
    x = np.random.default_rng(1).standard_normal(3000)
    zi = np.random.default_rng(2).standard_normal((sos.shape[0], 2))
    y1, z1 = sosfilt_state(sos, x, zi)
    y2, z2 = signal.sosfilt(sos, x, zi=zi)
    assert np.array_equal(y1, y2) and np.array_equal(z1, z2)


def test_paired_sos_filtering_equals_scipy_sosfilt_on_each_signal():
    # the modal filter and its PZT-absent twin, and the band and ambient noise blocks, are filtered
    # two at a time in one loop (sos.filter_pair): each signal must get exactly scipy's sosfilt
    # from its own state, whatever the other's sections and signal are
    from incipient_slip.sim.sos import SosFilter, filter_pair
    rng = np.random.default_rng(3)
    random_sos = rng.normal(0, 0.3, (4, 6))
    random_sos[:, 3] = 1.0
    filters = (signal.butter(4, [20, 900], btype="bandpass", fs=2200, output="sos"),
               signal.butter(2, 30, fs=2200, output="sos"), random_sos)
    for sos_a in filters:
        for sos_b in filters:
            for scale in (1e-3, 1.0, 1e3):
                x, y = rng.standard_normal(1100) * scale, rng.standard_normal(1100)
                a, b = SosFilter(sos_a), SosFilter(sos_b)
                a.z[0], b.z[0] = rng.standard_normal((len(sos_a), 2)), rng.standard_normal((len(sos_b), 2))
                want_x, want_y = signal.sosfilt(sos_a, x, zi=a.zi), signal.sosfilt(sos_b, y, zi=b.zi)
                filter_pair(a, x, b, y)
                for got, want in ((x, want_x[0]), (a.zi, want_x[1]), (y, want_y[0]), (b.zi, want_y[1])):
                    assert np.array_equal(got, want)


def test_series_seed_depends_on_dataset_seed_and_index():
    seeds = {series_seed(s, i) for s in range(3) for i in range(50)}
    assert len(seeds) == 150 and all(0 <= s < 2**63 for s in seeds)


def test_actuator_steps_23_mm_in_450_periods():
    rig = Rig(load_scene("mechanics"), "tpu", 0)
    outs = [rig.step_period(5.9) for _ in range(450)]
    assert outs[0].actuator_mm == 0.0
    assert outs[-1].actuator_mm == pytest.approx(23.0 * 449 / 450)
    assert rig.state.actuator_mm == pytest.approx(23.0)


def test_gross_slip_period_has_zero_stick_ratio_and_positive_travel():
    rig = Rig(load_scene("mechanics"), "nylon", 0)
    outs = [rig.step_period(1.1) for _ in range(450)]
    first = next(o for o in outs if o.gross_slip)
    before = outs[first.period - 1]
    assert before.load_ratio_stick < 0.1 and first.load_ratio_stick == 0.0
    # creep: once sliding, the object follows the actuator's pace on average (23/450 mm per period;
    # the period-to-period friction jitter can make single periods stick), which the paper's
    # 0.02 mm per period rule sees
    k = first.period
    pace = (outs[k + 20].object_y_mm - outs[k].object_y_mm) / 20
    assert 0.02 < pace < 0.1
    assert first.object_y_mm > before.object_y_mm


def test_fewer_effects_means_fewer_outputs_not_different_mechanics():
    full, mech = load_scene("paper"), load_scene("mechanics")
    a, b = Rig(full, "petg", 9), Rig(mech, "petg", 9)
    for _ in range(100):
        oa, ob = a.step_period(1.5), b.step_period(1.5)
    assert oa.object_y_mm == ob.object_y_mm and np.array_equal(oa.mocap_y_mm, ob.mocap_y_mm)


def test_block_generated_band_noise_equals_period_by_period_filtering():
    from incipient_slip.sim.injection import PztSource, band_sos
    p = load_scene("paper").params["injection"]
    src = PztSource(p, 2200.0, 1100, block=4)
    rng = np.random.default_rng(3)
    got = np.concatenate([src.next(rng) for _ in range(8)])
    raw = np.random.default_rng(3).standard_normal(8 * 1100)
    sos = band_sos(p, 2200.0)
    zi, parts = np.zeros((sos.shape[0], 2)), []
    for k in range(8):
        y, zi = signal.sosfilt(sos, raw[k * 1100:(k + 1) * 1100], zi=zi)
        parts.append(y)
    assert np.allclose(got, np.concatenate(parts), rtol=0, atol=1e-12)


def test_no_kernel_compiles_or_loads_after_the_rig_is_built():
    # the signal path's compiled kernels are loaded by Rig() (kernels.warm_up), for every argument
    # type the periods pass, so no load or compile falls on a real-time driver's first period
    import numba
    from incipient_slip.sim import kernels
    from incipient_slip.sim.dataset import simulate_series
    dispatchers = {n: f for n, f in vars(kernels).items() if isinstance(f, numba.core.registry.CPUDispatcher)}
    Rig(load_scene("paper"), "pla", 1)
    before = {n: len(f.signatures) for n, f in dispatchers.items()}
    simulate_series(load_scene("paper"), "pla", 5, 450, [load_scene("no_injection"), load_scene("electrodes_only")])
    for name in ("no_injection", "electrodes_only"):
        simulate_series(load_scene(name), "tpu", 7, 100)
    rig = Rig(load_scene("paper"), "abs", 3)
    rig.set_injection(False)
    for _ in range(3):
        rig.step_period(2.0)
    assert {n: len(f.signatures) for n, f in dispatchers.items()} == before

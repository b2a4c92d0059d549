"""Rig identification: hidden parameters drawn by the test are recovered within stated tolerances
(in-process on sim.Rig, and once through the graph: launch identify.yaml rig:=sim), bad input is
a named error, and the overlay goes back into the simulator's params.

Tolerances (docs/identification.md, "How close"): k_b +/- 10 % and beta +/- 0.15 (the ramps' only
noise is mocap jitter, 0.005 mm per sample; measured errors stay below 1 % and 0.01); mu +/- 5 %
of the rig's own (series) friction (the onset is read at the weakest period: 1 % per-period
jitter, one step of load); lag +/- 0.2 s (each onset is read per 500 ms period, so one trial
brackets tau to 0.5 s / -ln r; four trials narrow it to ~0.1-0.3 s).
"""
from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from incipient_slip import identify
from incipient_slip.experiments import identification as idn
from incipient_slip.experiments.validation import overlays as rig_overlays
from incipient_slip.sim.scene import SceneError, apply_overlay, load_overlay, load_params

LAUNCH = Path(__file__).parents[2] / "launch" / "identify.yaml"


def assert_recovered(hidden: dict, results: dict) -> None:
    st_, lag = results["stiffness"], results["lag"]
    assert abs(st_["k_ref"] / hidden["pre_slip.bulk_shear_n_per_mm"] - 1) <= 0.10
    assert abs(st_["beta"] - hidden["pre_slip.bulk_stiffening_exponent"]) <= 0.15
    assert abs(st_["mu"] / results["truth"]["mu_series"] - 1) <= 0.05
    assert abs(lag["tau_s"] - hidden["stick_slip.friction_limit_lag_s"]) <= 0.2
    for key in ("k_ref_interval", "beta_interval", "mu_interval"):
        assert all(math.isfinite(v) for v in st_[key])


@pytest.mark.parametrize("hidden_seed", [0, 3, 8, 13])
def test_hidden_parameters_are_recovered_on_the_simulated_rig(hidden_seed):
    hidden = idn.hidden_set(hidden_seed)
    _, results = idn.identify_sim(idn.scene_with(hidden), "pla", hidden_seed)
    assert_recovered(hidden, results)
    assert results["stiffness"]["levels"] >= 4 and results["lag"]["trials"] >= 3
    assert results["no_action"]["steps"] == 450


# derandomized: the same draws in every run, so a fresh clone's CI does not search anew each time;
# an open search once found the draw below the lag tolerance misses (test_known_limit_...)
@settings(max_examples=6, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(k=st.floats(0.3, 0.8), beta=st.floats(0.6, 1.4), lag=st.floats(0.0, 1.5), mu=st.floats(0.4, 0.75),
       seed=st.integers(0, 2 ** 31))
def test_recovery_holds_across_the_plausible_ranges(k, beta, lag, mu, seed):
    hidden = {"pre_slip.bulk_shear_n_per_mm": k, "pre_slip.bulk_stiffening_exponent": beta,
              "stick_slip.friction_limit_lag_s": lag, "mu": mu}
    plan = identify.Plan(protocols=("stiffness", "lag"))
    _, results = idn.identify_sim(idn.scene_with(hidden), "abs", seed, plan)
    assert_recovered(hidden, results)


def test_known_limit_a_long_lag_draw_reads_the_lag_high():
    """docs/identification.md, "A known limit": the ramps read mu at the weakest period, which biases
    tau up at long lags and small r. An open search found this draw 0.001 s beyond the tolerance
    (1.576 s for 1.375 s); on the refitted rig of 2026-11-28 it reads 1.475 s: inside, still high."""
    hidden = {"pre_slip.bulk_shear_n_per_mm": 0.5625, "pre_slip.bulk_stiffening_exponent": 1.1875,
              "stick_slip.friction_limit_lag_s": 1.375, "mu": 0.5}
    _, results = idn.identify_sim(idn.scene_with(hidden), "abs", 15456, identify.Plan(protocols=("stiffness", "lag")))
    assert_recovered(hidden, results)
    assert results["lag"]["tau_s"] > hidden["stick_slip.friction_limit_lag_s"] + 0.05    # the bias is there


def test_a_level_that_cannot_slide_within_the_travel_gives_stiffness_but_no_mu():
    hidden = {"pre_slip.bulk_shear_n_per_mm": 0.5, "pre_slip.bulk_stiffening_exponent": 1.0,
              "stick_slip.friction_limit_lag_s": 0.0, "mu": 0.9}
    plan = identify.Plan(levels_kpa=(5.9, 2.3, 1.1), protocols=("stiffness",), max_travel_mm=30.0)
    records, results = idn.identify_sim(idn.scene_with(hidden), "pla", 1, plan)
    top = [r for r in results["levels"] if r["fn_kpa"] == 5.9 and r["phase"] == "ramp"][0]
    assert not top["slid"] and math.isnan(top["mu"]) and math.isfinite(top["k_b"])
    assert max(r.u_mm for r in records) <= 30.0
    assert results["stiffness"]["mu_levels"] == 2


@pytest.mark.parametrize("plan, message", [
    (dict(levels_kpa=(7.0, 2.0)), "F_N of the plan"),
    (dict(levels_kpa=(float("nan"), 2.0)), "F_N of the plan"),
    (dict(levels_kpa=(3.0,)), "at least two"),
    (dict(step_mm=0.0), "step_mm"),
    (dict(lag_fractions=(0.0, 0.5)), "lag_fractions"),
    (dict(protocols=("stiffness", "dance")), "unknown protocols"),
    (dict(protocols=("lag",)), "needs mu"),
])
def test_a_bad_plan_is_a_named_error(plan, message):
    with pytest.raises(identify.IdentificationError, match=message):
        next(identify.run_protocol(identify.Plan(**plan), identify.Inputs(), []))


def test_bad_inputs_and_missing_mocap_are_named_errors():
    with pytest.raises(identify.IdentificationError, match="spring_n_per_mm"):
        identify.Inputs(spring_n_per_mm=0.0).check()
    with pytest.raises(identify.IdentificationError, match="gain_rel_sd"):
        identify.Inputs(gain_rel_sd=1.5).check()
    gen = identify.run_protocol(identify.Plan(), identify.Inputs(), [])
    next(gen)
    with pytest.raises(identify.IdentificationError, match="no usable mocap"):
        gen.send(identify.Observation(0, 5.9, 0.0, 0.5, np.array([]), np.array([])))


def test_every_command_stays_within_the_safety_limits():
    records, _ = idn.identify_sim(idn.scene_with(idn.hidden_set(5)), "nylon", 5)
    assert max(r.fn_kpa for r in records) <= 6.0
    rises = np.diff([r.fn_kpa for r in records])
    assert rises.max() <= identify.Plan().max_rise_kpa + 1e-9 and rises.min() < -1.0   # up slowly, down at once
    assert min(r.u_mm for r in records) >= 0.0 and max(r.u_mm for r in records) <= identify.Plan().max_travel_mm
    # every trial ends unloaded: the spring load after each unload is below 2 % of the largest
    ks = idn.scene_with(idn.hidden_set(5)).params["stick_slip"]["spring_n_per_mm"]
    loads = [ks * (r.u_mm - r.y_mm) for r in records]
    ends = [i for i, r in enumerate(records[:-1]) if r.phase == "unload" and records[i + 1].phase != "unload"]
    assert ends and all(abs(loads[i]) <= 0.02 * max(loads) for i in ends)


def test_the_overlay_goes_back_into_the_params_and_predicts_points(tmp_path):
    hidden = idn.hidden_set(2)
    records, results = idn.identify_sim(idn.scene_with(hidden), "petg", 2)
    paths = identify.write_outputs(results, records, tmp_path)
    assert Path(paths["stiffness"]).stat().st_size > 0 and Path(paths["lag"]).stat().st_size > 0
    doc = load_overlay(paths["overlay"])
    assert doc["provenance"]["material"] == "petg"
    base, _, _ = load_params("default")
    params = apply_overlay(base, doc)
    assert params["pre_slip"]["bulk_shear_n_per_mm"] == pytest.approx(results["stiffness"]["k_ref"])
    assert params["materials"]["petg"]["mu_identified"] == pytest.approx(results["stiffness"]["mu"])
    from incipient_slip.sim.feasibility import material_mu
    assert material_mu(params, "petg") == pytest.approx(results["stiffness"]["mu"])
    points = rig_overlays.overlay_points(doc)
    assert "identified" in points and len(points) == 1 + 2 * 6     # 6 entries with intervals
    low = points[next(n for n in points if n.startswith("pre_slip.bulk_stiffening_exponent low"))]
    assert low["pre_slip"]["bulk_stiffening_exponent"] == pytest.approx(results["stiffness"]["beta_interval"][0])


def test_a_file_that_is_not_an_overlay_is_refused(tmp_path):
    bad = tmp_path / "x.yaml"
    bad.write_text("pre_slip: {bulk_shear_n_per_mm: {value: 1, unit: N/mm, source: x}}\n")
    with pytest.raises(SceneError, match="not a params overlay"):
        load_overlay(bad)
    doc = {"provenance": {}, "pre_slip": {"no_such_thing": {"value": 1.0, "unit": "-", "source": "x"}}}
    with pytest.raises(SceneError, match="unknown parameter"):
        apply_overlay(load_params("default")[0], doc)
    doc = {"provenance": {}, "pre_slip": {"bulk_shear_n_per_mm": {"value": float("nan"), "unit": "-", "source": "x"}}}
    with pytest.raises(SceneError, match="finite"):
        apply_overlay(load_params("default")[0], doc)


def test_a_two_level_plan_writes_values_without_intervals_that_validation_takes(tmp_path):
    """Two levels leave one after the run-in: k_b and beta fit exactly. The overlay once held
    intervals [0, inf] and [-inf, inf], and validation then ran the rig at k_b = 0 (a
    ZeroDivisionError); now those entries have a value only, and the points are the others'."""
    plan = identify.Plan(levels_kpa=(2.3, 1.1), protocols=("stiffness",))
    records, results = idn.identify_sim(idn.scene_with(idn.hidden_set(2)), "petg", 2, plan)
    assert not all(math.isfinite(v) for v in results["stiffness"]["k_ref_interval"])
    doc = load_overlay(identify.write_outputs(results, records, tmp_path)["overlay"])
    k_b = doc["pre_slip"]["bulk_shear_n_per_mm"]
    assert "interval" not in k_b and identify.UNBOUNDED in k_b["source"]
    assert "interval" not in doc["pre_slip"]["bulk_stiffening_exponent"]
    points = rig_overlays.overlay_points(doc)
    assert not [n for n in points if n.startswith("pre_slip.")] and "identified" in points


def test_an_identified_mu_whose_interval_reaches_zero_is_written_without_it():
    """Two noisy levels on a real rig (t95(1) = 12.7): the overlay keeps mu's value and says why
    it has no interval, so validation --params takes it (an interval reaching 0 is refused)."""
    plan = identify.Plan(levels_kpa=(2.3, 1.1), protocols=("stiffness",))
    _, results = idn.identify_sim(idn.scene_with(idn.hidden_set(2)), "petg", 2, plan)
    results["stiffness"]["mu_interval"] = [-0.1, 1.2]
    doc = identify.overlay(results)
    mu = doc["materials"]["petg"]["mu_identified"]
    assert "interval" not in mu and "it reaches -0.1" in mu["source"]
    apply_overlay(load_params("default")[0], doc)          # accepted


@pytest.mark.parametrize("entry, words", [
    ({"value": 0.5, "unit": "N/mm", "source": "x", "interval": [0.0, float("inf")]}, "two finite numbers"),
    ({"value": 0.5, "unit": "N/mm", "source": "x", "interval": [0.0, 0.9]}, "must be > 0"),
    ({"value": 0.5, "unit": "N/mm", "source": "x", "interval": [0.6, 0.9]}, "does not hold its value"),
    ({"value": 0.5, "unit": "N/mm", "source": "x", "interval": [0.4]}, "two finite numbers"),
    ({"value": -0.5, "unit": "N/mm", "source": "x"}, "must be > 0"),
])
def test_an_overlay_with_an_interval_the_rig_cannot_run_is_refused_in_one_line(entry, words):
    doc = {"provenance": {}, "pre_slip": {"bulk_shear_n_per_mm": entry}}
    with pytest.raises(SceneError, match=words):
        apply_overlay(load_params("default")[0], doc)


def test_an_identified_mu_whose_interval_reaches_zero_is_refused():
    """Two noisy levels give t95(1) = 12.7: a mu interval can reach below 0 on a real rig."""
    mu = {"value": 0.5, "unit": "-", "source": "x", "interval": [-0.2, 1.2]}
    with pytest.raises(SceneError, match=r"pla.mu_identified: interval .* \(must be > 0\)"):
        apply_overlay(load_params("default")[0], {"provenance": {}, "materials": {"pla": {"mu_identified": mu}}})


def test_launch_identify_recovers_hidden_parameters_through_the_graph(graph, tmp_path):
    """The same protocols through real processes and sockets: rig_sim (commanded, lock-step) and
    the identifier node; the scene file hides parameters other than the defaults."""
    hidden = {"pre_slip.bulk_shear_n_per_mm": 0.62, "pre_slip.bulk_stiffening_exponent": 1.25,
              "stick_slip.friction_limit_lag_s": 0.6, "mu": 0.5}
    scene = tmp_path / "hidden.yaml"
    materials = load_params("default")[0]["materials"]
    scene.write_text(yaml.safe_dump({
        "name": "hidden", "params": "default", "effects": ["contact", "stick_slip", "mocap"],
        "overrides": {"pre_slip": {"bulk_shear_n_per_mm": 0.62, "bulk_stiffening_exponent": 1.25},
                      "stick_slip": {"friction_limit_lag_s": 0.6},
                      "materials": {"pla": {**materials["pla"], "mu_identified": 0.5}}}}))
    out = tmp_path / "out"
    done = graph.spawn([sys.executable, "-m", "incipient_slip.graph.launch", str(LAUNCH), f"scene:={scene}",
                        f"out_dir:={out}", "levels_kpa:=4.7,3.5,2.3,1.1", "protocols:=stiffness,lag", "seed:=4"])
    stdout, stderr = done.communicate(timeout=240)
    assert done.returncode == 0, stderr.decode()[-2000:]
    # progress: one line per phase (a real rig takes minutes per level), not one per period
    phases = [line for line in stderr.decode().splitlines() if re.match(r"\[identifier\] period \d+: ", line)]
    assert any("ramp (F_N 4.70 kPa)" in line for line in phases) and 8 <= len(phases) <= 60, phases
    doc = load_overlay(out / "identify_overlay.yaml")
    assert doc["pre_slip"]["bulk_shear_n_per_mm"]["value"] == pytest.approx(0.62, rel=0.10)
    assert doc["pre_slip"]["bulk_stiffening_exponent"]["value"] == pytest.approx(1.25, abs=0.15)
    assert doc["materials"]["pla"]["mu_identified"]["value"] == pytest.approx(0.5, rel=0.10)   # + series spread
    assert doc["stick_slip"]["friction_limit_lag_s"]["value"] == pytest.approx(0.6, abs=0.2)
    assert (out / "identify_stiffness.png").is_file() and (out / "identify_results.json").is_file()


def test_the_identifier_refuses_a_plan_above_the_safety_limit_before_anything_moves(graph):
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.identifier", "levels_kpa:=7.5,2.0"])
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and b"F_N of the plan" in err


@pytest.mark.slow
def test_launch_identify_through_the_emulated_devices_recovers_one_hidden_set(graph, tmp_path):
    """rig:=emulated: the real device nodes (BioTac reader, mocap bridge, Zaber stage in commanded
    mode, UR5 pressing on P_DC) against the emulators around one simulated contact, in real time.
    Two levels, stiffness only (a real-time period takes ~1 s); the press loop's F_N ripple is the
    extra noise (the bounds below: docs/identification.md, "Identification to 10 %")."""
    materials = load_params("default")[0]["materials"]
    scene = tmp_path / "hidden.yaml"
    scene.write_text(yaml.safe_dump({
        "name": "hidden", "params": "default",
        "effects": ["contact", "stick_slip", "mocap", "pdc", "temperature", "electrodes", "adc"],
        "overrides": {"pre_slip": {"bulk_shear_n_per_mm": 0.58, "bulk_stiffening_exponent": 0.85},
                      "materials": {"pla": {**materials["pla"], "mu_identified": 0.48}}}}))
    out = tmp_path / "out"
    emu = tmp_path / "emu"
    done = graph.spawn([sys.executable, "-m", "incipient_slip.graph.launch", str(LAUNCH), "rig:=emulated",
                        f"scene:={scene}", f"out_dir:={out}", f"emu_dir:={emu}", "emu_natnet_port:=41560",
                        "levels_kpa:=2.3,1.1", "step_mm:=0.5", "protocols:=stiffness"])
    stdout, stderr = done.communicate(timeout=900)
    assert done.returncode == 0, stderr.decode()[-3000:]
    doc = load_overlay(out / "identify_overlay.yaml")
    assert doc["provenance"]["rig"] == "emulated"
    # The spread over repeated runs (bench/bench_identify_emulated.py, docs/identification.md,
    # "Identification to 10 %"): the press loop's F_N ripple once let the contact slip partly just
    # below a ramp's onset, which levered its slope; the slope is now read up to 80 % of the ramp's
    # load. mu is the rig's own: the emulated contact (seed 0) draws its friction 5.8 % above the
    # hidden mu (the series spread), which the 15 % bound here used to absorb. On a miss the message
    # carries the identifier's log.
    from incipient_slip.sim.rig import Rig
    from incipient_slip.sim.scene import load_scene
    mu_rig = Rig(load_scene(str(scene)), "pla", 0).mu_s
    log = "\n".join(line for line in stderr.decode().splitlines() if line.startswith(("[identifier]", "[ur5]")))
    assert doc["pre_slip"]["bulk_shear_n_per_mm"]["value"] == pytest.approx(0.58, rel=0.10), log[-3000:]
    assert doc["pre_slip"]["bulk_stiffening_exponent"]["value"] == pytest.approx(0.85, abs=0.15), log[-3000:]
    mu = doc["materials"]["pla"]["mu_identified"]
    assert mu["interval"][0] <= mu_rig <= mu["interval"][1], (mu, log[-3000:])
    assert mu["value"] == pytest.approx(mu_rig, rel=0.10), log[-3000:]


def test_an_overlay_reaches_every_command_that_takes_the_simulators_params(graph, tmp_path):
    records, results = idn.identify_sim(idn.scene_with(idn.hidden_set(6)), "pla", 6,
                                        identify.Plan(protocols=("stiffness",)))
    overlay = identify.write_outputs(results, records, tmp_path)["overlay"]
    from incipient_slip.sim.scene import load_scene
    scene = load_scene("paper", overlay)
    assert scene.params["pre_slip"]["bulk_stiffening_exponent"] == pytest.approx(results["stiffness"]["beta"])
    assert scene.params["materials"]["pla"]["mu_identified"] == pytest.approx(results["stiffness"]["mu"])
    bad = subprocess.run([sys.executable, "-m", "incipient_slip.cli", "dataset", "--scene", "mechanics", "--params",
                          str(tmp_path / "missing.yaml"), "--series", "1", "--out", str(tmp_path / "d")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "params overlay not found" in bad.stderr
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.rig_sim", f"params:={tmp_path / 'x.yaml'}"])
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and b"params overlay not found" in err


def test_a_robot_that_reports_a_stop_ends_the_identification(graph, probe, tmp_path):
    from incipient_slip.messages import RobotState
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.identifier", "clock:=tick_start",
                        f"out_dir:={tmp_path}", "wait_timeout_s:=0"])
    pub = probe.node.create_publisher(RobotState)
    probe.until(lambda: pub.subscriber_count() >= 1, 60, procs=[proc], what="the identifier reading /robot/state")
    pub.publish(RobotState(normal_force_kpa=2.0, state="stopped"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 3 and b"the robot stopped" in err


def test_overlays_of_several_materials_merge_into_one_rig(tmp_path):
    overlays = []
    for material, seed in (("pla", 1), ("tpu", 2)):
        records, results = idn.identify_sim(idn.scene_with(idn.hidden_set(seed), material), material, seed,
                                            identify.Plan(protocols=("stiffness",)))
        overlays.append(load_overlay(identify.write_outputs(results, records, tmp_path / material)["overlay"]))
    doc = rig_overlays.merge_overlays(overlays)
    assert set(doc["materials"]) == {"pla", "tpu"} and doc["provenance"]["material"] == "pla, tpu"
    assert doc["pre_slip"] == overlays[-1]["pre_slip"]
    points = rig_overlays.overlay_points(doc)
    assert any(n.startswith("pla.mu_identified") for n in points) and any(n.startswith("tpu.mu_identified") for n in points)


@pytest.mark.parametrize("rig", ["sim", "emulated", "hardware"])
def test_identify_launch_resolves_each_rig_with_the_stage_commanded_and_the_clock_it_needs(rig):
    from incipient_slip.graph.launch import find_launch_file, load
    got = {n.name: n for n in load(find_launch_file("identify.yaml"), {"rig": rig}).nodes}
    ident = got["identifier"].params
    assert got["identifier"].required and ident["rig"] == rig
    if rig == "sim":
        assert set(got) == {"rig_sim", "identifier"}
        assert got["rig_sim"].params["protocol"] == "commanded" and ident["clock"] == "tick_end"
        assert ident["levels_kpa"] == "5.9,4.7,3.5,2.3,1.1" and ident["slide_rise_mm"] == 0.02
        assert ident["slide_needs_rise"] is False
    else:
        assert {"linear_actuator", "ur5", "mocap_bridge", "biotac_reader"} <= set(got)
        assert got["linear_actuator"].params["mode"] == "commanded" and got["linear_actuator"].required
        assert ident["clock"] == "tick_start" and ident["slide_rise_mm"] == 0.08 and ident["slide_needs_rise"] is True
        # a press loop ripples F_N: the plan stays clear of the 6.0 kPa limit where the robot retracts
        assert max(float(x) for x in ident["levels_kpa"].split(",")) <= 5.5 and ident["lag_high_kpa"] <= 5.5
    if rig == "hardware":
        assert got["rig_check"].gate and "emulated_rig" not in got


def test_a_partial_slip_just_below_the_onset_does_not_lever_the_ramps_slope():
    """rig:=emulated: the press loop moves F_N ~4 % a period at 1.1 kPa; a dip near the onset lets
    the contact slip partly (0.1 mm), too little for the slide rules, so that period counted as
    stuck, at the top of the ramp, and read k_b 13 % low (the fit took Q above 30 % of the largest,
    top included). The slope is read up to 80 % of the largest stuck load."""
    ks, k_b, gain, fn = 0.0327175, 0.29, 0.4, 1.1
    inputs = identify.Inputs(spring_n_per_mm=ks, newton_per_kpa=gain)
    records, y_prev = [], 0.0
    for i in range(17):
        u = 0.5 * i
        y = ks * u / (k_b + ks) + (0.10 if i == 15 else 0.0) + (0.5 if i == 16 else 0.0)
        records.append(identify.Record(i, "ramp", 1, fn, u, y, 0.0, y - y_prev, i == 16, onset=i == 16))
        y_prev = y
    row = identify.stiffness_levels(records, inputs)[0]
    assert row["k_b"] == pytest.approx(k_b, rel=0.01)


def test_on_a_real_time_rig_a_press_move_inside_the_window_ends_no_ramp():
    """rig:=emulated: a press move that landed inside a period's window moved y 0.024 mm there, the
    paper's within-period rule fired at half the friction limit and ended the 2.3 kPa ramp (mu read
    45 % low). With slide_needs_rise (real-time rigs) only y's rise above the stuck steps ends it."""
    ks, k_b = 0.0327175, 0.54
    plan = identify.Plan(levels_kpa=(2.3, 1.1), step_mm=0.5, slide_rise_mm=0.08, protocols=("stiffness",),
                         slide_needs_rise=True)
    records: list = []
    gen = identify.run_protocol(plan, identify.Inputs(spring_n_per_mm=ks), records)
    cmd, k, y = next(gen), 0, 0.0
    limit_n = 0.5 * 0.4 * 2.3                          # mu F_N
    while True:
        q = ks * cmd.actuator_mm * k_b / (k_b + ks)
        slide = q > limit_n
        y = cmd.actuator_mm - (0.1 if slide else q / ks)
        t = np.arange(54) / 120.0 + k * 0.5
        jump = 0.024 if k == 60 else 0.0                # a press move inside period 60's window
        ys = np.where(t - k * 0.5 >= 0.25, y + jump, y) if not slide else np.linspace(y - 0.3, y, 54)
        try:
            cmd = gen.send(identify.Observation(k, cmd.normal_force_kpa, cmd.actuator_mm, (k + 1) * 0.5, t, ys))
        except StopIteration:
            break
        k += 1
    assert any(r.period == 60 and r.slid and not r.onset for r in records)   # the rule fired, the ramp went on
    before_onset = [records[i - 1] for i, r in enumerate(records) if r.onset]
    assert len(before_onset) == 3 and all(identify.spring_load_n(r, ks) > 0.9 * limit_n for r in before_onset[:2])

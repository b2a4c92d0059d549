"""`slip calibrate pdc | press-gain | spring` on the emulated rig recover the calibration hidden in
it (the emulator is given newton_per_kpa and spring_n_per_mm other than the scene's); the file
they write is what the nodes read (rig_config -> calibration), and each bad input is one line."""
from __future__ import annotations

import random
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from incipient_slip.devices import calibration
from incipient_slip.errors import UsageError

HIDDEN_NEWTON_PER_KPA = 0.55      # the scene's: 0.4
HIDDEN_SPRING_N_PER_MM = 0.05     # the scene's: 0.0327


# --- the fits and the file, alone ----------------------------------------------------------

def test_fit_line_recovers_slope_and_its_standard_error():
    x = [1.0, 2.0, 3.0, 4.0]
    slope, intercept, se, rms = calibration.fit_line(x, [2.1, 3.9, 6.1, 7.9])
    assert slope == pytest.approx(1.96) and intercept == pytest.approx(0.1) and 0 < se < 0.1 and rms < 0.2
    with pytest.raises(ValueError, match="at least 3"):
        calibration.fit_line([1, 2], [1, 2])
    with pytest.raises(ValueError, match="same x"):
        calibration.fit_line([1, 1, 1], [1, 2, 3])


def test_press_gain_is_the_fraction_of_the_steepest_stiffness_in_range():
    depth = [0.0, 1.0, 2.0, 3.0, 4.0]
    kpa = [0.0, 0.5, 1.5, 3.0, 7.0]          # secants 0.5, 1, 1.5, 4 kPa/mm; mid 0.25 1 2.25 5
    gain, stiff = calibration.press_gain(depth, kpa, 1.0, 3.0, 0.8)
    assert stiff == 1.5 and gain == pytest.approx(0.8 / 1.5)
    with pytest.raises(ValueError, match="no two neighbouring"):
        calibration.press_gain(depth, kpa, 10.0, 12.0, 0.8)


def test_the_ur5_node_takes_its_gain_from_the_calibration_and_one_number_has_one_place(tmp_path):
    from incipient_slip.graph.params import merge_params
    from incipient_slip.nodes.ur5 import UR5
    rig = tmp_path / "rig.yaml"
    rig.write_text("calibration: cal.yaml\nur5: {robot_address: 127.0.0.9}\n")
    assert calibration.node_values(rig, "ur5", {}) == {}           # no file yet: not calibrated
    calibration.save_section(rig, "press_gain", {"gain_mm_per_kpa": 0.61})
    assert calibration.node_values(rig, "ur5", {"robot_address": "x"}) == {"gain_mm_per_kpa": 0.61}
    merge_params("ur5", UR5.PARAMS, {"robot_address": "x", **calibration.node_values(rig, "ur5", {})})
    with pytest.raises(UsageError, match="sets gain_mm_per_kpa, which the calibration file"):
        calibration.node_values(rig, "ur5", {"gain_mm_per_kpa": 0.05})
    (tmp_path / "cal.yaml").write_text("press_gain: {gain_mm_per_kpa: 1}\nfoo: {}\n")
    with pytest.raises(UsageError, match="expected sections of pdc, spring, press_gain"):
        calibration.load(rig)
    rig.write_text("ur5: {}\n")
    with pytest.raises(UsageError, match="names no calibration file"):
        calibration.save_section(rig, "pdc", {"newton_per_kpa": 0.4})


# --- on the emulated rig -------------------------------------------------------------------

@pytest.fixture(scope="module")
def emulated(tmp_path_factory):
    """The emulated rig in this process (the commands run in their own), the calibration hidden."""
    pytest.importorskip("rtde_control", reason="ur-rtde has no wheel here (CPython 3.10-3.12, x86-64 Linux)")
    from incipient_slip.devices.emulated_rig import EmulatedRig
    from incipient_slip.devices.natnet_emulator import free_udp_port_pair
    from incipient_slip.devices.zaber_emulator import DEFAULT_MICROSTEPS_PER_MM
    d = tmp_path_factory.mktemp("cal")
    port = free_udp_port_pair()
    rig = EmulatedRig(d / "emu", robot_address=f"127.0.{random.randint(1, 254)}.{random.randint(2, 254)}",
                      natnet_command_port=port, natnet_data_port=port + 1, speed_mm_s=50.0,
                      newton_per_kpa=HIDDEN_NEWTON_PER_KPA, spring_n_per_mm=HIDDEN_SPRING_N_PER_MM).start()
    stop = threading.Event()

    def tick():
        while not stop.wait(0.01):
            rig.tick()
    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    config = d / "rig.yaml"
    config.write_text(yaml.safe_dump({
        "calibration": "calibration.yaml",
        "zaber": {"port": str(rig.zaber_link), "microsteps_per_mm": DEFAULT_MICROSTEPS_PER_MM,
                  "start_mm": 0.0, "limit_min_mm": 0.0, "limit_max_mm": 50.0},
        "ur5": {"robot_address": rig.ur.address,
                "safety_limit_kpa": 6.0, "max_press_mm": 10.0, "press_axis": "z", "press_sign": 1.0,
                "speed_m_s": 0.05}}))
    yield rig, config
    stop.set()
    thread.join()
    rig.stop()


def run_calibrate(args: list[str], answer) -> tuple[int, str]:
    """Runs `slip calibrate ARGS`, answering each question (a line ending in '?') with answer()."""
    proc = subprocess.Popen([sys.executable, "-m", "incipient_slip.cli", "calibrate", *args],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out = []
    try:
        for line in proc.stdout:
            out.append(line)
            if line.rstrip().endswith("?"):
                proc.stdin.write(f"{answer():.6f}\n")
                proc.stdin.flush()
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, "".join(out) + proc.stderr.read()


SWEEP = ["--step-mm", "1.0", "--settle-s", "1.0", "--average-s", "0.4"]


@pytest.mark.timeout(300)
def test_pdc_and_press_gain_recover_the_hidden_finger(emulated):
    rig, config = emulated
    code, text = run_calibrate(["pdc", "--config", str(config), "--biotac-port", str(rig.biotac_link), *SWEEP,
                                "--instrument", "the emulated scale"],
                               lambda: rig.instruments()["scale_n"])
    assert code == 0, text
    cal = calibration.load(config)["pdc"]
    # P_DC is F_N in kPa plus the sensor's noise, quantized at 36.5 Pa a count: 2 % over 0.5-6 kPa
    assert cal["newton_per_kpa"] == pytest.approx(HIDDEN_NEWTON_PER_KPA, rel=0.02), text
    assert cal["instrument"] == "the emulated scale" and len(cal["points_kpa_n"]) >= 3
    assert abs(rig.depth_mm()) < 0.01                  # the robot went back to its start pose

    code, text = run_calibrate(["press-gain", "--config", str(config), "--biotac-port", str(rig.biotac_link),
                                *SWEEP], lambda: pytest.fail("press-gain asks nothing"))
    assert code == 0, text
    gain = calibration.load(config)["press_gain"]
    depths = [d for d, _ in gain["points_mm_kpa"]]
    press = rig.shared.press                           # the true contact, with the hidden gain
    want, _ = calibration.press_gain(depths, [press.normal_force_kpa(d) for d in depths], 1.0, 6.0, 0.8)
    assert gain["gain_mm_per_kpa"] == pytest.approx(want, rel=0.05), text
    # ...which the scene's own finger (0.4 N/kPa) would not give: the test can tell them apart
    from incipient_slip.devices.emulated_rig import HertzPress
    scene = HertzPress(press.radius_mm, press.e_star_mpa, 0.4)
    other, _ = calibration.press_gain(depths, [scene.normal_force_kpa(d) for d in depths], 1.0, 6.0, 0.8)
    assert abs(other - want) / want > 0.15

    # the ur5 node reads it through rig_config
    from incipient_slip.devices.rig_config import apply_rig_config

    class Stub:
        name = "ur5"
        params = {"rig_config": str(config)}
        PARAMS = __import__("incipient_slip.nodes.ur5", fromlist=["UR5"]).UR5.PARAMS

        def param(self, key):
            return self.params[key]
    stub = Stub()
    apply_rig_config(stub, "ur5", {"rig_config": str(config)})
    assert stub.params["gain_mm_per_kpa"] == gain["gain_mm_per_kpa"]


@pytest.mark.timeout(120)
def test_spring_recovers_the_hidden_spring_constant(emulated):
    rig, config = emulated
    code, text = run_calibrate(["spring", "--config", str(config), "--points-mm", "2,5,10,15,23"],
                               lambda: rig.instruments()["spring_gauge_n"])
    assert code == 0, text
    cal = calibration.load(config)["spring"]
    assert cal["spring_n_per_mm"] == pytest.approx(HIDDEN_SPRING_N_PER_MM, rel=0.01), text
    assert abs(cal["slack_mm"]) < 0.05
    assert abs(rig.zaber.position_mm) < 1e-3           # back at start_mm: the spring slack
    code, text = run_calibrate(["show", "--config", str(config)], lambda: None)
    assert code == 0 and "spring_n_per_mm" in text


def test_bad_inputs_are_one_line_each(tmp_path):
    config = tmp_path / "rig.yaml"
    config.write_text("calibration: cal.yaml\nzaber: {port: /dev/ttyNOPE7}\nur5: {}\n")
    code, text = run_calibrate(["spring", "--config", str(config)], lambda: 0.0)
    assert code == 2 and "cannot open the Zaber stage's port /dev/ttyNOPE7" in text and text.count("\n") == 1
    code, text = run_calibrate(["spring", "--config", str(config), "--points-mm", "1,2"], lambda: 0.0)
    assert code == 2 and "3 or more points" in text
    code, text = run_calibrate(["pdc", "--config", str(tmp_path / "none.yaml"), "--biotac-port", "/dev/x"],
                               lambda: 0.0)
    assert code == 2 and "cannot read it" in text


def test_a_reading_takes_its_unit_and_a_bad_one_is_asked_again(monkeypatch, capsys):
    import io

    from incipient_slip.nodes import calibrate
    grams = {"": 1.0, "N": 1.0, "g": calibrate.GRAVITY / 1000.0, "kg": calibrate.GRAVITY}
    monkeypatch.setattr("sys.stdin", io.StringIO("twelve\n-\n153 g\n"))
    assert calibrate.ask("load?", grams) == pytest.approx(0.153 * 9.80665)
    assert capsys.readouterr().out.count("not a reading") == 2
    monkeypatch.setattr("sys.stdin", io.StringIO("0.5 lb\n"))
    with pytest.raises(UsageError, match="input ended"):
        calibrate.ask("load?", grams)

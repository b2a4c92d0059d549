"""rig:=emulated: every real device node against the emulators, which share ONE simulated contact.

The shared contact is the simulator's own physics (checked exactly against `sim.Rig`); the closed
loop through every device node ends like `rig:=sim` for the same seed, within the tolerances
below; collect.yaml rig:=emulated records an MCAP.
"""
from __future__ import annotations

import json
import math
import os
import random
import resource
import sys
import wave
from pathlib import Path

import numpy as np
import pytest

from incipient_slip.devices.emulated_rig import ContactSignals, HertzPress, SharedContact, wav_rms
from incipient_slip.devices.natnet_emulator import free_udp_port_pair
from incipient_slip.graph.bag import read_bag
from incipient_slip.sim.rig import Rig, load_scene

STEPS = 20
# Why these tolerances: on the emulated rig F_N is P_DC as the BioTac reads it (0.0365 kPa a
# count plus the sensor's noise) after the ur5 node's press loop, which applies a command one to
# two periods later than the lock-step simulator does; the grip controller moves F_N at most
# 0.5 kPa a period, so a one-period lag is at most 0.5 kPa. The travel y lags by at most one
# actuator step (23/450 = 0.051 mm) plus the mocap noise; 0.1 mm is two steps.
FORCE_TOL_KPA = 0.5
TRAVEL_TOL_MM = 0.1


def test_hertz_press_is_the_inverse_of_its_depth():
    rig = Rig(load_scene("paper"), "pla", 0)
    press = HertzPress.of(rig)
    assert press.normal_force_kpa(0.0) == 0.0 and press.normal_force_kpa(-1.0) == 0.0
    for kpa in (0.5, 2.9, 6.0):
        assert press.normal_force_kpa(press.depth_mm(kpa)) == pytest.approx(kpa, rel=1e-12)
    # the contact radius of that press is the simulator's Hertz radius: a^2 = R d
    d = press.depth_mm(2.9)
    from incipient_slip.sim import contact
    a = contact.hertz_radius_mm(2.9 * press.newton_per_kpa, rig.radius_mm, rig.e_star)
    assert a * a == pytest.approx(rig.radius_mm * d, rel=1e-9)


def test_shared_contact_is_the_simulated_rig_with_its_inputs_read_from_the_devices():
    """Inputs from the 'devices' (a press depth, a stage position) give exactly sim.Rig's periods."""
    step_mm = 23.0 / 450
    positions = iter([0.0, 0.0, step_mm, 2 * step_mm, 3 * step_mm])
    depths = iter([3.0, 3.2, 3.4, 3.4, 2.0])
    shared = SharedContact("paper", "pla", 5, actuator_mm=lambda: next(positions), depth_mm=lambda: next(depths))
    rig = Rig(load_scene("paper"), "pla", 5)
    press = HertzPress.of(rig)
    for k, (pos, depth) in enumerate(zip([0.0, 0.0, step_mm, 2 * step_mm, 3 * step_mm], [3.0, 3.2, 3.4, 3.4, 2.0])):
        rig.state.actuator_mm = pos
        want = rig.step_period(press.normal_force_kpa(depth), actuator_step=False)
        got = shared.period(k)
        assert np.array_equal(got.pac_counts, want.pac_counts)
        assert np.array_equal(got.electrode_counts, want.electrode_counts)
        assert np.array_equal(got.pdc_counts, want.pdc_counts)
        assert got.object_y_mm == want.object_y_mm
        assert shared.truth[k].normal_force_kpa == pytest.approx(press.normal_force_kpa(depth))
    assert shared.period(2) is shared.outputs[2]          # periods are stepped once, then kept


def test_shared_contact_hides_its_calibration_in_the_scene_values_and_leaves_the_scene_as_loaded():
    hidden = {("contact", "newton_per_kpa"): 0.55, ("stick_slip", "spring_n_per_mm"): 0.05}
    shared = SharedContact("paper", "pla", 0, overrides=hidden)
    assert shared.press.newton_per_kpa == 0.55
    assert shared.rig.scene.params["stick_slip"]["spring_n_per_mm"] == 0.05
    assert load_scene("paper").params["contact"]["newton_per_kpa"] == 0.4
    with pytest.raises(KeyError, match="contact.no_such_key"):
        SharedContact("paper", "pla", 0, overrides={("contact", "no_such_key"): 1.0})


def test_biotac_channels_follow_the_contact_clock():
    clock = iter([100.0, 100.0, 100.7, 100.7])
    shared = SharedContact("paper", "pla", 1, depth_mm=lambda: 3.4, clock=lambda: next(clock))
    signals = ContactSignals(shared)
    pdc = signals.sample("PDC", 0)                  # contact time 0.0 s: period 0, slow row 0
    assert pdc == int(shared.period(0).pdc_counts[0])
    # 0.7 s of contact time later is period 1, row 20, whatever the sensor's own clock says
    assert signals.sample("PDC", 700_000_000) == int(shared.period(1).pdc_counts[20])


def test_wav_rms_reads_the_tail_of_a_growing_file(tmp_path):
    path = tmp_path / "pzt.wav"
    assert wav_rms(path, 0.1) is None
    w = wave.open(str(path), "wb")
    w.setnchannels(1), w.setsampwidth(2), w.setframerate(8000)
    w.writeframes(np.zeros(8000, "<i2").tobytes())
    w.writeframes(np.full(800, 16384, "<i2").tobytes())
    w._file.flush()                                  # as the injector's file, not yet closed
    assert wav_rms(path, 0.1) == pytest.approx(16384 / 32767, rel=1e-6)
    assert wav_rms(path, 0.2) == pytest.approx(16384 / 32767 / math.sqrt(2), rel=1e-6)
    w.close()


# --- the whole loop through the device nodes ---------------------------------------------------



def _emulated_args(tmp_path) -> list[str]:
    return [f"emu_dir:={tmp_path / 'emu'}", f"emu_natnet_port:={free_udp_port_pair()}",
            f"emu_address:=127.0.{random.randint(1, 254)}.{random.randint(2, 254)}"]


def _launch(graph, args, timeout):
    proc = graph.spawn([sys.executable, "-m", "incipient_slip.graph.launch", *args])
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, err.decode()


@pytest.mark.timeout(420)        # hang guards: a loaded machine (make test-load) takes minutes
def test_emulated_closed_loop_ends_like_the_simulated_rig_for_the_same_seed(graph, tmp_path):
    pytest.importorskip("rtde_control", reason="ur-rtde has no wheel for this Python: the ur5 node cannot run")
    seed = 0
    results = {}
    for rig, extra in (("sim", []), ("emulated", _emulated_args(tmp_path))):
        summary = tmp_path / f"{rig}.json"
        code, err = _launch(graph, ["stabilize.yaml", f"rig:={rig}", f"steps:={STEPS}", f"seed:={seed}",
                                    f"summary:={summary}", "quiet:=true", *extra], 200)
        assert code in (0, 1), err[-4000:]              # success or the paper's failure, never a fault
        results[rig] = json.loads(summary.read_text())
    sim, emu = results["sim"], results["emulated"]
    assert emu["rig"] == "emulated" and emu["steps"] == STEPS, (emu, err[-3000:])
    assert (emu["outcome"], emu["steps"]) == (sim["outcome"], sim["steps"])
    assert abs(emu["final_force_kpa"] - sim["final_force_kpa"]) <= FORCE_TOL_KPA, (sim, emu)
    assert abs(emu["final_travel_mm"] - sim["final_travel_mm"]) <= TRAVEL_TOL_MM, (sim, emu)
    # real time: 20 periods of 500 ms cannot take less than 10 s on the emulated rig
    assert emu["wall_s"] >= STEPS * 0.5 - 0.5


@pytest.mark.timeout(300)
def test_emulated_collection_records_every_device_topic(graph, tmp_path):
    pytest.importorskip("rtde_control", reason="ur-rtde has no wheel for this Python: the ur5 node cannot run")
    out = tmp_path / "series.mcap"
    code, err = _launch(graph, ["collect.yaml", "rig:=emulated", "steps:=4", f"out:={out}",
                                *_emulated_args(tmp_path)], 240)
    assert code == 0, err[-4000:]
    counts: dict[str, int] = {}
    for record in read_bag(out):
        counts[record.topic] = counts.get(record.topic, 0) + 1
    assert counts["/actuator/state"] == 4
    for topic in ("/biotac/pac", "/biotac/slow", "/object/pose", "/robot/state", "/pzt/state"):
        assert counts.get(topic, 0) > 0, (topic, counts)
    # 4 periods of 500 ms at 100 frames/s (the recording spans at least the pull)
    assert counts["/biotac/pac"] >= 150


def _nice_of(pid: int) -> int:
    return os.getpriority(os.PRIO_PROCESS, pid)


@pytest.mark.timeout(120)
def test_the_emulators_run_at_a_raised_priority(graph, tmp_path):
    """The devices the emulated rig stands in for are never starved: every thread of the node
    (the BioTac, Zaber, NatNet and UR emulators among them) runs at nice -10, or it says why not."""
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.emulated_rig", f"dir:={tmp_path / 'emu'}",
                        f"natnet_command_port:={free_udp_port_pair()}",
                        f"natnet_data_port:={free_udp_port_pair()}",
                        f"robot_address:=127.0.{random.randint(1, 254)}.{random.randint(2, 254)}"])
    lines = []
    for raw in proc.stderr:          # every line up to the start-up one (the test's timeout bounds it)
        lines.append(raw.decode())
        if "real time" in lines[-1]:
            break
    assert "real time" in lines[-1], "".join(lines)
    threads = {int(t.name): Path(f"/proc/{proc.pid}/task/{t.name}/comm").read_text().strip()
               for t in Path(f"/proc/{proc.pid}/task").iterdir()}
    allowed = os.geteuid() == 0 or resource.getrlimit(resource.RLIMIT_NICE)[0] >= 30    # 20 - (-10)
    if not allowed:
        assert any("runs at the normal priority" in line for line in lines), "".join(lines)
        return
    assert "nice -10" in lines[-1]
    assert _nice_of(proc.pid) == -10
    # every thread: the main loop, the BioTac, Zaber, NatNet and UR emulators, ZeroMQ's own
    assert len(threads) >= 5, threads
    assert all(_nice_of(tid) == -10 for tid in threads), {(t, threads[t]): _nice_of(t) for t in threads}

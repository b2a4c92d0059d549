"""rig:=hardware: config/rig.yaml is read by the device nodes, and with no device attached the
launch ends within seconds with exit 2 and one line per missing device; rig_check passes when
the emulated devices answer."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from incipient_slip.devices import pzt, rig_config
from incipient_slip.devices.natnet_emulator import NatNetEmulator, free_udp_port
from incipient_slip.devices.zaber_emulator import ZaberEmulator
from incipient_slip.errors import UsageError

pytestmark = pytest.mark.timeout(90)
REPO = Path(__file__).resolve().parents[2]




def missing_rig(tmp_path) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({
        "natnet": {"server_address": "127.0.0.1", "local_address": "127.0.0.1",
                   "command_port": free_udp_port(), "data_port": free_udp_port()},
        "zaber": {"port": str(tmp_path / "ttyNOPE")},
        "ur5": {"robot_address": "127.1.0.1"},     # no fake controller of the tests uses it
    }))
    return path


def test_shipped_rig_config_fits_every_device_node():
    from incipient_slip.nodes.linear_actuator import LinearActuator
    from incipient_slip.nodes.mocap_bridge import MocapBridge
    from incipient_slip.nodes.ur5 import UR5
    from incipient_slip.graph.params import merge_params
    for node, section in ((MocapBridge, "natnet"), (LinearActuator, "zaber"), (UR5, "ur5")):
        merge_params(section, node.PARAMS, rig_config.load_section(REPO / "config" / "rig.yaml", section))


def test_unknown_key_in_a_section_is_named(tmp_path, graph):
    path = tmp_path / "rig.yaml"
    path.write_text("zaber: {port: /dev/null, speed: 3}\n")
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.linear_actuator", f"rig_config:={path}"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and "[zaber]" in err.decode() and "'speed'" in err.decode()


def test_missing_section_is_a_param_error(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text("natnet: {}\n")
    with pytest.raises(UsageError, match="no section 'zaber'"):
        rig_config.load_section(path, "zaber")


@pytest.mark.parametrize("launch_file", ["stabilize.yaml", "collect.yaml"])
def test_hardware_launch_without_devices_exits_2_with_one_line_per_device(tmp_path, graph, launch_file):
    proc = graph.spawn([str(Path(sys.executable).parent / "launch"), launch_file, "rig:=hardware",
                        f"rig_config:={missing_rig(tmp_path)}", f"biotac_port:={tmp_path / 'ttyNOPE2'}"],
                       cwd=REPO)
    _, err = proc.communicate(timeout=60)
    text = err.decode()
    assert proc.returncode == 2, text
    lines = [l for l in text.splitlines() if l.startswith("[rig_check]") and "shutting down" not in l]
    # the PZT's sound card is checked too: missing here unless this machine has sounddevice and a card
    card = ["pzt"] if pzt.check_output_device() else []
    assert [re.match(r"\[rig_check\] (\w+):", l).group(1) for l in lines] == ["natnet", "zaber", "ur5", "biotac", *card]
    assert "127.0.0.1" in lines[0] and "ttyNOPE" in lines[1] and "127.1.0.1" in lines[2]
    # a gate: no device node was started beside the check (they slowed it down and had to stop)
    assert re.search(r"gate rig_check exited with exit code 2; not started: [\w, ]*biotac_reader", text)
    n = 4 + len(card)
    assert re.search(rf"\[rig_check\] shutting down: {n} of 5 device\(s\) missing \(checked in [\d.]+ s, "
                     r"slowest (natnet|zaber|ur5|biotac|pzt)\)", text)


def test_the_pzt_check_names_what_is_missing(monkeypatch):
    def absent():
        raise RuntimeError("the PZT's sound card needs the sounddevice package and PortAudio (pip install ...)")
    monkeypatch.setattr(pzt, "load_sounddevice", absent)
    assert pzt.check_output_device().startswith("pzt: the PZT's sound card needs the sounddevice package")

    class NoCard:
        @staticmethod
        def check_output_settings(**kw):
            raise ValueError(f"No output device matching {kw['device']!r}")
    monkeypatch.setattr(pzt, "load_sounddevice", lambda: NoCard)
    line = pzt.check_output_device("USB Audio", 48000)
    assert "sound card USB Audio cannot play mono float32 at 48000 Hz" in line and "No output device" in line
    assert (pzt.output_device(""), pzt.output_device("3"), pzt.output_device("USB Audio")) == (None, 3, "USB Audio")


def test_rig_check_passes_when_the_emulated_devices_answer(tmp_path, graph):
    data_port = free_udp_port()
    with NatNetEmulator((4, 1), data_port=data_port) as mocap, ZaberEmulator() as stage:
        fake = subprocess.Popen([sys.executable, "-m", "incipient_slip.devices.fake_ur", "--address", "127.0.0.1"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            if not fake.stdout.readline().startswith("{"):
                pytest.skip("ports 29999/30003/30004 on 127.0.0.1 are taken")
            path = tmp_path / "rig.yaml"
            path.write_text(yaml.safe_dump({
                "natnet": {"server_address": "127.0.0.1", "command_port": mocap.command_port, "data_port": data_port},
                "zaber": {"port": stage.port}, "ur5": {"robot_address": "127.0.0.1"}}))
            proc = graph.spawn(["python", "-m", "incipient_slip.nodes.rig_check", f"rig_config:={path}", "stay:=false"])
            _, err = proc.communicate(timeout=30)
        finally:
            fake.stdin.close()
            fake.wait(timeout=10)
    assert proc.returncode == 0 and "all 3 devices answer: natnet, zaber, ur5" in err.decode()


def test_slip_rig_check_needs_the_lab_s_own_config(graph):
    """No default: copied from the README it must not probe the shipped example addresses."""
    proc = graph.spawn([str(Path(sys.executable).parent / "slip"), "rig", "check"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and "the following arguments are required: --config" in err.decode()


def test_rig_check_names_a_stage_that_does_not_fit_its_section(tmp_path, graph):
    with ZaberEmulator(limit_max_mm=25.0) as stage:
        path = tmp_path / "rig.yaml"
        path.write_text(yaml.safe_dump({"zaber": {"port": stage.port, "limit_max_mm": 50.0}}))
        proc = graph.spawn([str(Path(sys.executable).parent / "slip"), "rig", "check", "--config", str(path)])
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert f"[rig_check] zaber: {stage.port}: the configured travel [0, 50] mm is outside the device's " \
           f"limit.min..limit.max = [0.000, 25.000] mm" in err.decode()


def test_robot_recover_without_a_robot_node_is_exit_2(graph):
    proc = graph.spawn([str(Path(sys.executable).parent / "slip"), "robot", "recover", "--timeout", "0.5"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and "no ur5 node" in err.decode()


def biotac_bridge(graph, tmp_path, *extra) -> Path:
    """An emulated BioTac bridge on a pty; the path of its link once it is there."""
    link = tmp_path / "biotac"
    proc = graph.spawn(["python", "-m", "incipient_slip.devices.biotac_emulator", "--link", str(link), *extra])
    assert proc.stdout.readline().startswith(b"biotac emulator: bridge on"), proc.communicate()[1].decode()
    return link


def rig_check(graph, tmp_path, biotac_port, timeout_s=3.0):
    path = tmp_path / "rig.yaml"
    path.write_text("{}\n")           # no device sections: only the BioTac port is checked
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.rig_check", f"rig_config:={path}",
                        f"biotac_port:={biotac_port}", "stay:=false", f"timeout_s:={timeout_s}"])
    _, err = proc.communicate(timeout=60)
    return proc.returncode, err.decode()


def test_rig_check_passes_a_bridge_whose_sensor_answers_and_streams(graph, tmp_path):
    rc, err = rig_check(graph, tmp_path, biotac_bridge(graph, tmp_path))
    assert rc == 0 and "all 1 devices answer: biotac" in err


def test_rig_check_refuses_a_bridge_without_a_sensor(graph, tmp_path):
    rc, err = rig_check(graph, tmp_path, biotac_bridge(graph, tmp_path, "--missing-sensor"))
    assert rc == 2 and "[rig_check] biotac: no BioTac on sensor slot 0" in err and "next attempt" not in err


def test_rig_check_refuses_a_port_where_no_bridge_answers(graph, tmp_path):
    master, slave = os.openpty()             # a serial port with nobody behind it
    try:
        rc, err = rig_check(graph, tmp_path, os.ttyname(slave), timeout_s=1.0)
    finally:
        os.close(master)
        os.close(slave)
    assert rc == 2 and "[rig_check] biotac: the bridge on" in err and "did not answer the property request" in err

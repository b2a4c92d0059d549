"""rig_check: are the real rig's devices there? One line per missing device, exit 2.

    slip rig check --config FILE [--biotac-port PORT] [--pzt-device [CARD]]

(the operator's spelling; `launch ... rig:=hardware` runs this node as its gate).

Checks every device section of the rig configuration at once, each within `timeout_s`:
the NatNet server answers a connect with its server info, the Zaber stage answers a status
poll on its serial port and what it reports (axis count, resolution, travel limits) fits its
section (`zaber.check_stage`), the UR controller accepts connections on RTDE (30004) and the
dashboard (29999, with its banner), the BioTac bridge (`biotac_port`, the launch files' arg of
that name) answers the property request for a sensor whose serial number starts with "BT" and
streams a frame of it (a bridge with no sensor, or one that never streams, is missing), and
with `pzt:=true` the PZT amplifier's sound card (`pzt_device`) takes a mono stream (sounddevice
and PortAudio installed, the card there). Each
line says how long its check took, and the last line which device was the slowest.

`launch ... rig:=hardware` starts it as a gate (`gate: true`, `stay: false`), before any device
node: with a device missing the launch ends with its lines and exit code 2 (about timeout_s
after the launch started, as no other node is starting beside it); with all present it prints
one line and exits 0, and the device nodes start. By hand (`stay: true`, the default) it stays
up after success.
"""
from __future__ import annotations

import socket
import time
from concurrent.futures import ThreadPoolExecutor

from incipient_slip.devices import biotac, natnet, pzt, rig_config, zaber
from incipient_slip.errors import UsageError
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node

EXIT_MISSING = 2


def check_natnet(cfg: dict, timeout_s: float) -> str:
    """"" when a NatNet server answers, else the line naming what to check."""
    server = cfg.get("server_address", "127.0.0.1")
    port = int(cfg.get("command_port", natnet.DEFAULT_COMMAND_PORT))
    client = natnet.NatNetClient(server, local_address=cfg.get("local_address", "127.0.0.1"),
                                 command_port=port, data_port=int(cfg.get("data_port", natnet.DEFAULT_DATA_PORT)),
                                 multicast=bool(cfg.get("multicast", False)),
                                 connect_timeout_s=min(0.5, timeout_s))
    try:
        client.open()
    except OSError as exc:
        return f"natnet: {exc}"
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and client.server_info is None:
            client.poll()
            time.sleep(0.01)
    finally:
        client.close()
    if client.server_info is None:
        return (f"natnet: no NatNet server at {server}:{port} (no server info in {timeout_s:g} s): "
                f"is Motive running there with streaming on, Local Interface = that address?")
    return ""


def check_zaber(cfg: dict, timeout_s: float) -> str:
    """"" when the Zaber stage answers on its port, else the line naming port and fix."""
    import serial
    port = cfg.get("port", "/dev/ttyUSB0")
    try:
        link = serial.Serial(port, int(cfg.get("baud", zaber.DEFAULT_BAUD)), timeout=0.02)
    except (serial.SerialException, OSError) as exc:
        return f"zaber: cannot open {port}: {exc}"
    try:
        axis, steps_mm = int(cfg.get("axis", 1)), float(cfg.get("microsteps_per_mm", 20997.375))
        client = zaber.ZaberClient(link, device=int(cfg.get("device", 1)), axis=axis,
                                   microsteps_per_mm=steps_mm, timeout_s=timeout_s / 3, name=port)
        client.status()
        mismatch = zaber.check_stage(client.read_stage(), axis=axis, microsteps_per_mm=steps_mm,
                                     resolution=int(cfg.get("resolution", zaber.DEFAULT_RESOLUTION)),
                                     limit_min_mm=float(cfg.get("limit_min_mm", 0.0)),
                                     limit_max_mm=float(cfg.get("limit_max_mm", 50.0)))
    except zaber.ZaberError as exc:
        return f"zaber: {exc}"
    finally:
        link.close()
    return f"zaber: {port}: {mismatch}" if mismatch else ""


def check_ur5(cfg: dict, timeout_s: float) -> str:
    """"" when the UR controller accepts RTDE and dashboard connections, else the line."""
    host = cfg.get("robot_address", "192.168.1.5")
    try:
        socket.create_connection((host, 30004), timeout=timeout_s).close()
        with socket.create_connection((host, 29999), timeout=timeout_s) as dash:
            dash.settimeout(timeout_s)
            banner = dash.recv(256).decode("utf-8", "replace")
    except OSError as exc:
        return f"ur5: no UR controller at {host} (RTDE 30004, dashboard 29999: {exc}): is the robot on and robot_address its IP?"
    if "Universal Robots Dashboard" not in banner:
        return f"ur5: {host}:29999 answered {banner.strip()[:60]!r}, not a UR dashboard server"
    return ""


def check_biotac(cfg: dict, timeout_s: float) -> str:
    """"" when the BioTac bridge answers its property request for a sensor whose serial number
    says it is a BioTac and then streams a frame of it, else the line naming what failed (the
    port, a bridge that does not answer, no sensor, no frame): the reader's own handshake."""
    port = cfg.get("port", "/dev/ttyACM0")
    link = biotac.BridgeLink(port, handshake_timeout_s=0.8 * timeout_s)
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            if link.poll():
                return ""
            failed = [text for level, text in link.events if level != "info"]
            if failed:                       # the first attempt failed: say why, no retry
                return f"biotac: {failed[0].split('; next attempt')[0]}"
            time.sleep(0.01)
    finally:
        link.close()
    what = "no frame" if link.state == "streaming" else "no answer to the property request"
    return f"biotac: the bridge on {port}: {what} within {timeout_s:g} s"


def check_pzt(cfg: dict, timeout_s: float) -> str:
    """"" when the PZT amplifier's sound card (`pzt_device`, '' = the default output) takes the
    injector's stream, else the line naming what is missing (sounddevice, PortAudio, the card)."""
    return pzt.check_output_device(cfg.get("device", ""), int(cfg.get("sample_rate_hz", 48000)))


CHECKS = {"natnet": check_natnet, "zaber": check_zaber, "ur5": check_ur5, "biotac": check_biotac,
          "pzt": check_pzt}


class RigCheck(Node):
    """Checks that every device of config/rig.yaml answers; exit 2 with one line per missing one."""

    INPUTS: dict = {}
    OUTPUTS: dict = {}
    PARAMS = {
        "rig_config": Param("config/rig.yaml", help="the rig configuration file"),
        "timeout_s": Param(3.0, lo=0.1, hi=60.0, help="each device must answer within this"),
        "stay": Param(True, choices=(False, True), help="after success stay up until stopped"),
        "biotac_port": Param("", help="the BioTac bridge's serial port to check (the launch arg; '' = not checked)"),
        "pzt": Param(False, choices=(False, True), help="also check the PZT amplifier's sound card (the launch's)"),
        "pzt_device": Param("", help="with pzt: the sound card, sounddevice name or index ('' = default output)"),
    }

    def __init__(self, **kwargs):
        super().__init__("rig_check", **kwargs)
        path, timeout_s = self.param("rig_config"), self.param("timeout_s")
        try:
            sections = {name: rig_config.load_section(path, name) for name in CHECKS
                        if _has_section(path, name)}
        except UsageError as exc:
            raise ParamError(str(exc)) from None
        if self.param("biotac_port"):
            sections["biotac"] = {"port": self.param("biotac_port")}
        if self.param("pzt"):
            sections["pzt"] = {"device": self.param("pzt_device")}
        if not sections:
            raise ParamError(f"rig_config {path}: no device sections ({', '.join(CHECKS)})")
        with ThreadPoolExecutor(len(sections)) as pool:      # in parallel: the slowest one sets the time
            results = dict(zip(sections, pool.map(lambda n: _timed(CHECKS[n], sections[n], timeout_s), sections)))
        missing = [f"{line} ({took:.1f} s)" for line, took in results.values() if line]
        for line in missing:
            self.log(line)
        slowest = max(results, key=lambda n: results[n][1])
        took = f"checked in {results[slowest][1]:.1f} s, slowest {slowest}"
        if missing:
            self.shutdown(f"{len(missing)} of {len(results)} device(s) missing ({took})", EXIT_MISSING)
        else:
            self.log(f"all {len(results)} devices answer: {', '.join(results)} ({took})")
            if not self.param("stay"):
                self.shutdown("devices present")


def _timed(check, cfg: dict, timeout_s: float) -> tuple[str, float]:
    """(the check's line, seconds it took)."""
    start = time.monotonic()
    line = check(cfg, timeout_s)
    return line, time.monotonic() - start


def _has_section(path: str, name: str) -> bool:
    try:
        rig_config.load_section(path, name)
    except UsageError as exc:
        if "no section" in str(exc):
            return False
        raise
    return True


def main(argv=None):
    return run_node(RigCheck, argv)


if __name__ == "__main__":
    raise SystemExit(main())

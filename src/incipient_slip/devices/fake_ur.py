"""A fake Universal Robots controller on a loopback address: dashboard (29999), script (30003)
and RTDE (30004) servers that ur-rtde's own interfaces connect to, with first-order motion.

    python -m incipient_slip.devices.fake_ur --address 127.0.0.2

Written from the RTDE protocol and from what ur-rtde sends (docs/hardware.md, "UR5"); no code
of theirs. What it speaks:

* RTDE (big-endian; header u16 size incl. itself, u8 type): `V` protocol version (accepted),
  `v` controller version (4 x u32), `O` output setup (f64 frequency, names; answers a recipe
  id and the types, NOT_FOUND for names it does not know), `I` input setup (answers the next
  recipe id and the types, IN_USE when that fault is on), `S` start / `P` pause (u8 success),
  `U` data packages both ways: outputs at the requested frequency, inputs written to the
  controller's registers.
* Script (30003): a program text `def name(): ... end`. One that contains ur-rtde's control
  loop runs as the register handshake of that script: output int register 0 is 1 (ready) when
  input int register 0 is 0; a command (MOVEL 3, SERVOL 24, FORCE_MODE 6, STOP_SCRIPT 255, ...)
  runs once and sets it to 2 (done) -- for a blocking MOVEL when the motion ends.
  SET_WATCHDOG 35 arms the script's `rtde_set_watchdog` on input int register 0 with the
  minimum frequency in input double register 0 and the action "stop": when no data package
  writes that register for 1/frequency s (ur-rtde's kickWatchdog sends one), the program stops
  (`stats["watchdog_stops"]`). A stopped program has no watchdog.
* Dashboard: the text commands ur-rtde uses (PolyscopeVersion, get serial number, is in
  remote control, stop, unlock protective stop, close safety popup, power on, brake release,
  safetystatus, robotmode, programState, running, quit).

Motion: the TCP approaches a moveL target first-order (`time_constant_s`), finishing within
1 um. Faults (methods): `protective_stop()`, `emergency_stop()` / `release_emergency_stop()`,
`stop_program()` (the script stops), `drop_connections()` (every socket closes),
`in_use = True` (input setups answer IN_USE, as when EtherNet/IP, PROFINET or Modbus holds the
registers). Not verified against a real controller: that a protective stop leaves the program
STOPPED (rather than PAUSED), and the exact dashboard texts beyond those ur-rtde checks.
"""
from __future__ import annotations

import argparse
import json
import math
import selectors
import socket
import struct
import sys
import threading
import time
from collections import Counter

from incipient_slip.devices.emulator import ThreadedEmulator

__all__ = ["FakeURController", "main", "DASHBOARD_PORT", "SCRIPT_PORT", "RTDE_PORT"]

DASHBOARD_PORT, SCRIPT_PORT, RTDE_PORT = 29999, 30003, 30004
CONTROL_SCRIPT_MARK = "RTDE Control Script"      # ur-rtde's control loop announces itself so

# RTDE message types
RTDE_REQUEST_PROTOCOL_VERSION, RTDE_GET_URCONTROL_VERSION = ord("V"), ord("v")
RTDE_TEXT_MESSAGE, RTDE_DATA_PACKAGE = ord("M"), ord("U")
RTDE_SETUP_OUTPUTS, RTDE_SETUP_INPUTS = ord("O"), ord("I")
RTDE_START, RTDE_PAUSE = ord("S"), ord("P")

_FORMATS = {"DOUBLE": "d", "UINT32": "I", "INT32": "i", "UINT64": "Q", "UINT8": "B", "BOOL": "?",
            "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I"}
_OUTPUTS = {
    "timestamp": "DOUBLE", "target_q": "VECTOR6D", "target_qd": "VECTOR6D", "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D", "target_moment": "VECTOR6D", "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D", "actual_current": "VECTOR6D", "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D", "actual_TCP_speed": "VECTOR6D", "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D", "target_TCP_speed": "VECTOR6D",
    "actual_digital_input_bits": "UINT64", "joint_temperatures": "VECTOR6D",
    "actual_execution_time": "DOUBLE", "robot_mode": "INT32", "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32", "safety_status": "INT32", "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE", "target_speed_fraction": "DOUBLE", "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE", "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE", "actual_joint_voltage": "VECTOR6D",
    "actual_digital_output_bits": "UINT64", "runtime_state": "UINT32",
    "standard_analog_input0": "DOUBLE", "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE", "standard_analog_output1": "DOUBLE",
    "robot_status_bits": "UINT32", "safety_status_bits": "UINT32", "ft_raw_wrench": "VECTOR6D",
    "payload": "DOUBLE", "payload_cog": "VECTOR3D", "payload_inertia": "VECTOR6D",
}
_OUTPUTS.update({f"output_int_register_{i}": "INT32" for i in range(48)})
_OUTPUTS.update({f"output_double_register_{i}": "DOUBLE" for i in range(48)})
_INPUTS = {f"input_int_register_{i}": "INT32" for i in range(48)}
_INPUTS.update({f"input_double_register_{i}": "DOUBLE" for i in range(48)})
_INPUTS["external_force_torque"] = "VECTOR6D"

# ur-rtde's control script command numbers this controller carries out
NO_CMD, MOVEL, FORCE_MODE, SERVOL, SET_WATCHDOG, STOP_SCRIPT = 0, 3, 6, 24, 35, 255
WATCHDOG_REGISTER = "input_int_register_0"     # what ur-rtde's script watches (kickWatchdog writes it)
_REALTIME = {24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71}
# runtime_state, safety status bits, robot/safety modes (RTDE guide)
STOPPED, PLAYING = 1, 2
BIT_NORMAL, BIT_PROTECTIVE, BIT_ROBOT_ESTOP, BIT_ESTOP = 0, 2, 6, 7
ROBOT_MODE_POWER_OFF, ROBOT_MODE_RUNNING = 3, 7
SAFETY_NORMAL, SAFETY_PROTECTIVE, SAFETY_ROBOT_ESTOP = 1, 3, 7
FINISH_M = 1e-6


class _Conn:
    """One client connection: its kind, input and output buffers, and (RTDE) recipes."""

    def __init__(self, kind: str):
        self.kind = kind
        self.buf = b""
        self.out = bytearray()                  # what the client has not taken yet
        self.inputs: dict[int, tuple[list, struct.Struct]] = {}
        self.outputs: tuple | None = None       # (names, struct, period_s)
        self.started = False
        self.next_due = 0.0


MAX_BACKLOG = 64 * 1024    # a client this far behind gets no new data packages until it reads


class FakeURController(ThreadedEmulator):
    """A UR controller (PolyScope `version`) on `address`: see the module docstring."""

    THREAD_NAME = "fake-ur"

    def __init__(self, address: str = "127.0.0.2", *, version=(5, 9, 4, 1031232),
                 serial_number: str = "20195500000", remote_control: bool = True,
                 tcp_pose=(0.4, 0.0, 0.3, 0.0, 3.1416, 0.0), time_constant_s: float = 0.03,
                 ports=(DASHBOARD_PORT, SCRIPT_PORT, RTDE_PORT)):
        self.address, self.version, self.serial_number = address, tuple(version), serial_number
        self.remote_control = remote_control
        self.time_constant_s = time_constant_s
        self.ports = ports
        self.in_use = False
        self.stats: Counter = Counter()
        self.commands: list[tuple] = []            # (command number, doubles) carried out
        self.scripts: list[str] = []
        self._lock = threading.RLock()
        self._pose = list(map(float, tcp_pose))
        self._target = list(self._pose)
        self._moving = False
        self._blocking_move = False
        self._in: dict[str, object] = {}
        self._out_int = [0] * 48
        self._out_double = [0.0] * 48
        self.runtime_state = STOPPED
        self._executing = False
        self._watchdog_s = None                    # armed: longest gap between register updates
        self._watchdog_fed = 0.0
        self.protective = self.estop = False
        self.powered = True
        self._sel = selectors.DefaultSelector()
        self._listeners: list[socket.socket] = []
        self._conns: dict[socket.socket, object] = {}
        super().__init__()
        self._t0 = time.monotonic()
        self._last = self._t0

    # --- control (any thread) ---

    def _open(self) -> None:
        """Binds the three ports on `address` (OSError if taken); the thread serves them."""
        for port, kind in zip(self.ports, ("dashboard", "script", "rtde")):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((self.address, port))
            except OSError:
                s.close()
                self._close_all()
                raise
            s.listen(8)
            s.setblocking(False)
            self._listeners.append(s)
            self._sel.register(s, selectors.EVENT_READ, ("listen", kind))

    def _close(self) -> None:
        self._close_all()

    @property
    def tcp_pose(self) -> list:
        with self._lock:
            return list(self._pose)

    @property
    def program_running(self) -> bool:
        return self.runtime_state == PLAYING

    def protective_stop(self) -> None:
        """As a collision or a safety limit: motion halts, the program stops, bit 2 is set."""
        with self._lock:
            self.protective = True
            self._halt()
            self.stats["protective_stops"] += 1

    def emergency_stop(self) -> None:
        """The e-stop button: motion halts, the program stops, the arm powers off."""
        with self._lock:
            self.estop = True
            self.powered = False
            self._halt()
            self.stats["emergency_stops"] += 1

    def release_emergency_stop(self) -> None:
        """The button is pulled out again (the arm stays off until power on / brake release)."""
        with self._lock:
            self.estop = False

    def stop_program(self) -> None:
        """The program stops (an error in the script, or someone pressed stop on the pendant)."""
        with self._lock:
            self._halt()

    def drop_connections(self) -> None:
        """Closes every client socket, as when the network cable is pulled for a moment."""
        with self._lock:
            for conn in list(self._conns):
                self._drop(conn)
            self.stats["drops"] += 1

    # --- server thread ---

    def _close_all(self) -> None:
        for conn in list(self._conns):
            self._drop(conn)
        for s in self._listeners:
            try:
                self._sel.unregister(s)
            except (KeyError, ValueError):
                pass
            s.close()
        self._listeners = []

    def _drop(self, conn) -> None:
        try:
            self._sel.unregister(conn)
        except (KeyError, ValueError):
            pass
        self._conns.pop(conn, None)
        conn.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                due = [st.next_due for st in self._conns.values() if st.started]
            wait = min([0.01] + [max(0.0, d - now) for d in due])
            for key, events in self._sel.select(wait):
                kind = key.data
                with self._lock:
                    if kind[0] == "listen":
                        self._accept(key.fileobj, kind[1])
                        continue
                    if events & selectors.EVENT_WRITE:
                        self._flush(key.fileobj)
                    if events & selectors.EVENT_READ and key.fileobj in self._conns:
                        self._read(key.fileobj, kind)
            with self._lock:
                self._step(time.monotonic())
                self._stream(time.monotonic())

    def _accept(self, listener, kind) -> None:
        try:
            conn, _ = listener.accept()
        except OSError:
            return
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._conns[conn] = _Conn(kind)
        self._sel.register(conn, selectors.EVENT_READ, ("conn", kind))
        self.stats[f"connections:{kind}"] += 1
        if kind == "dashboard":
            self._send(conn, b"Connected: Universal Robots Dashboard Server\n")

    def _read(self, conn, kind) -> None:
        try:
            data = conn.recv(65536)
        except OSError:
            data = b""
        if not data:
            self._drop(conn)
            return
        state = self._conns.get(conn)
        if state is None:
            return
        if kind[1] == "rtde":
            state.buf += data
            while len(state.buf) >= 3:
                size, mtype = struct.unpack_from(">HB", state.buf)
                if size < 3:
                    self.stats["rtde_bad_headers"] += 1
                    self._drop(conn)
                    return
                if len(state.buf) < size:
                    break
                payload, state.buf = state.buf[3:size], state.buf[size:]
                self._rtde(conn, state, mtype, payload)
        elif kind[1] == "dashboard":
            state.buf += data
            while b"\n" in state.buf and conn in self._conns:
                line, state.buf = state.buf.split(b"\n", 1)
                self._dashboard(conn, line.decode("utf-8", "replace").strip())
        else:
            state.buf += data
            self._script(state)

    def _send(self, conn, data: bytes, droppable: bool = False) -> None:
        """Queues `data` for the client and sends what the socket takes now, never blocking
        (one client that stops reading must not stall the others); a droppable data package
        is skipped while the client is more than MAX_BACKLOG behind."""
        state = self._conns.get(conn)
        if state is None:
            return
        if droppable and len(state.out) > MAX_BACKLOG:
            self.stats["rtde_packages_skipped"] += 1
            return
        state.out += data
        self._flush(conn)

    def _flush(self, conn) -> None:
        state = self._conns.get(conn)
        if state is None:
            return
        try:
            sent = conn.send(state.out) if state.out else 0
        except BlockingIOError:
            sent = 0
        except OSError:
            self._drop(conn)
            return
        del state.out[:sent]
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if state.out else 0)
        try:
            self._sel.modify(conn, events, ("conn", state.kind))
        except (KeyError, ValueError):
            pass

    # --- RTDE ---

    def _reply(self, conn, mtype: int, payload: bytes = b"", droppable: bool = False) -> None:
        self._send(conn, struct.pack(">HB", len(payload) + 3, mtype) + payload, droppable)

    def _rtde(self, conn, st: _Conn, mtype: int, payload: bytes) -> None:
        self.stats[f"rtde:{chr(mtype)}"] += 1
        if mtype == RTDE_REQUEST_PROTOCOL_VERSION:
            self._reply(conn, mtype, b"\x01")
        elif mtype == RTDE_GET_URCONTROL_VERSION:
            self._reply(conn, mtype, struct.pack(">4I", *self.version))
        elif mtype == RTDE_SETUP_OUTPUTS:
            if len(payload) < 8:
                self._reply(conn, mtype, b"\x00")
                return
            (frequency,) = struct.unpack_from(">d", payload)
            names = [n for n in payload[8:].decode("ascii", "replace").split(",") if n]
            types = [_OUTPUTS.get(n, "NOT_FOUND") for n in names]
            ok = "NOT_FOUND" not in types and 0 < frequency <= 500
            if ok:
                fmt = ">B" + "".join(_FORMATS[t] for t in types)
                st.outputs = (names, struct.Struct(fmt), 1.0 / frequency)
            self._reply(conn, mtype, bytes([1 if ok else 0]) + ",".join(types).encode())
        elif mtype == RTDE_SETUP_INPUTS:
            names = [n for n in payload.decode("ascii", "replace").split(",") if n]
            types = [_INPUTS.get(n, "NOT_FOUND") for n in names]
            if self.in_use:
                types = ["IN_USE" if n.startswith("input_") else t for n, t in zip(names, types)]
            if "NOT_FOUND" in types or "IN_USE" in types:
                self._reply(conn, mtype, b"\x00" + ",".join(types).encode())
                return
            recipe = len(st.inputs) + 1
            st.inputs[recipe] = (names, struct.Struct(">B" + "".join(_FORMATS[t] for t in types)))
            self._reply(conn, mtype, bytes([recipe]) + ",".join(types).encode())
        elif mtype == RTDE_START:
            st.started = st.outputs is not None
            st.next_due = time.monotonic()
            self._reply(conn, mtype, b"\x01" if st.started else b"\x00")
        elif mtype == RTDE_PAUSE:
            st.started = False
            self._reply(conn, mtype, b"\x01")
        elif mtype == RTDE_DATA_PACKAGE:
            recipe = payload[0] if payload else 0
            spec = st.inputs.get(recipe)
            if spec is None or len(payload) != spec[1].size:
                self.stats["rtde_bad_packages"] += 1
                return
            values = spec[1].unpack(payload)[1:]
            if WATCHDOG_REGISTER in spec[0]:
                self._watchdog_fed = time.monotonic()
            i = 0
            for name in spec[0]:
                n = 6 if name == "external_force_torque" else 1
                self._in[name] = values[i] if n == 1 else values[i:i + n]
                i += n
            self._script_tick()
        else:
            self.stats["rtde_unknown"] += 1

    def _value(self, name: str, now: float):
        if name.startswith("output_int_register_"):
            return self._out_int[int(name.rsplit("_", 1)[1])]
        if name.startswith("output_double_register_"):
            return self._out_double[int(name.rsplit("_", 1)[1])]
        if name == "timestamp":
            return now - self._t0
        if name in ("actual_TCP_pose",):
            return tuple(self._pose)
        if name == "target_TCP_pose":
            return tuple(self._target)
        if name == "runtime_state":
            return self.runtime_state
        if name == "safety_status_bits":
            bits = 0 if (self.protective or self.estop) else 1 << BIT_NORMAL
            bits |= (1 << BIT_PROTECTIVE) if self.protective else 0
            bits |= ((1 << BIT_ROBOT_ESTOP) | (1 << BIT_ESTOP)) if self.estop else 0
            return bits
        if name == "robot_status_bits":
            return (1 if self.powered else 0) | (2 if self.runtime_state == PLAYING else 0)
        if name == "robot_mode":
            return ROBOT_MODE_RUNNING if self.powered else ROBOT_MODE_POWER_OFF
        if name in ("safety_mode", "safety_status"):
            return SAFETY_ROBOT_ESTOP if self.estop else SAFETY_PROTECTIVE if self.protective else SAFETY_NORMAL
        if name in ("speed_scaling", "target_speed_fraction"):
            return 1.0
        kind = _OUTPUTS[name]
        width = {"VECTOR6D": 6, "VECTOR3D": 3, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}.get(kind, 1)
        zero = 0.0 if kind in ("DOUBLE", "VECTOR3D", "VECTOR6D") else 0
        return (zero,) * width if width > 1 else zero

    def _stream(self, now: float) -> None:
        for conn, st in list(self._conns.items()):
            if not st.started or now < st.next_due:
                continue
            names, packer, period = st.outputs
            st.next_due += period
            if st.next_due < now:
                st.next_due = now + period
            values = [1]
            for name in names:
                v = self._value(name, now)
                values.extend(v if isinstance(v, tuple) else (v,))
            self._reply(conn, RTDE_DATA_PACKAGE, packer.pack(*values), droppable=True)

    # --- the program (ur-rtde's control script, as its register handshake) ---

    def _script(self, state: _Conn) -> None:
        text = state.buf.decode("utf-8", "replace")
        lines = text.split("\n")
        if not lines[0].startswith("def ") or not any(line == "end" for line in lines[1:]):
            return                                   # program not complete yet
        state.buf = b""
        self.scripts.append(text)
        self.stats["scripts"] += 1
        if self.protective or self.estop or not self.powered:
            self.stats["scripts_refused"] += 1       # a stopped robot does not start programs
            return
        if CONTROL_SCRIPT_MARK in text:
            self.runtime_state = PLAYING
            self._executing = False
            self._out_int[0] = 1                     # signal_ready()

    def _script_tick(self) -> None:
        if self.runtime_state != PLAYING or self._blocking_move:
            return
        cmd = int(self._in.get("input_int_register_0", 0))
        if cmd in _REALTIME:
            self._process(cmd)
            self._out_int[0] = 1
        elif cmd == NO_CMD:
            self._executing = False
            self._out_int[0] = 1
        elif not self._executing:
            self._executing = True
            self._process(cmd)

    def _process(self, cmd: int) -> None:
        doubles = [float(self._in.get(f"input_double_register_{i}", 0.0)) for i in range(8)]
        self.commands.append((cmd, doubles))
        if cmd == STOP_SCRIPT:
            self._halt()
            return
        if cmd == SET_WATCHDOG:       # rtde_set_watchdog(WATCHDOG_REGISTER, min frequency, "stop")
            self._watchdog_s = 1.0 / doubles[0] if doubles[0] > 0 else None
            self._watchdog_fed = time.monotonic()
        if cmd in (MOVEL, SERVOL):
            self._target = doubles[:6]
            self._moving = True
            if cmd == MOVEL and int(self._in.get("input_int_register_1", 0)) == 0:
                self._blocking_move = True           # movel() returns when the motion ends
                return
        if cmd not in _REALTIME:
            self._out_int[0] = 2                     # signal_done_with_cmd()

    def _step(self, now: float) -> None:
        dt, self._last = now - self._last, now
        if self._watchdog_s is not None and now - self._watchdog_fed > self._watchdog_s:
            self._halt()              # the watchdog's action "stop": the program stops
            self.stats["watchdog_stops"] += 1
        if not self._moving:
            return
        alpha = 1.0 - math.exp(-dt / self.time_constant_s)
        self._pose = [p + (t - p) * alpha for p, t in zip(self._pose, self._target)]
        if max(abs(t - p) for p, t in zip(self._pose[:3], self._target[:3])) < FINISH_M:
            self._pose = list(self._target)
            self._moving = False
            if self._blocking_move:
                self._blocking_move = False
                self._out_int[0] = 2

    def _halt(self) -> None:
        self._target = list(self._pose)
        self._moving = self._blocking_move = self._executing = False
        self._watchdog_s = None       # a stopped program has no watchdogs
        self.runtime_state = STOPPED
        self._out_int[0] = 0

    # --- dashboard ---

    def _dashboard(self, conn, line: str) -> None:
        self.stats["dashboard_commands"] += 1
        v = ".".join(map(str, self.version))
        safety = ("ROBOT_EMERGENCY_STOP" if self.estop else "PROTECTIVE_STOP" if self.protective
                  else "NORMAL")
        answers = {
            "PolyscopeVersion": f"URSoftware {v} (Jan 05 2021)",
            "get serial number": self.serial_number,
            "is in remote control": "true" if self.remote_control else "false",
            "safetystatus": f"Safetystatus: {safety}",
            "safetymode": f"Safetymode: {safety}",
            "robotmode": f"Robotmode: {'RUNNING' if self.powered else 'POWER_OFF'}",
            "running": f"Program running: {'true' if self.program_running else 'false'}",
            "programState": "PLAYING rtde_control" if self.program_running else "STOPPED <unnamed>",
        }
        if line in answers:
            reply = answers[line]
        elif line == "stop":
            self._halt()
            reply = "Stopped"
        elif line == "unlock protective stop":
            if self.protective and not self.estop:
                self.protective = False
                reply = "Protective stop releasing"
            else:
                reply = "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking"
        elif line == "close safety popup":
            reply = "closing safety popup"
        elif line == "close popup":
            reply = "closing popup"
        elif line == "power on":
            self.powered = self.powered or not self.estop
            reply = "Powering on"
        elif line == "brake release":
            reply = "Brake releasing"
        elif line == "quit":
            self._send(conn, b"Disconnected\n")
            self._drop(conn)        # what is still queued is lost, as when the server hangs up
            return
        else:
            reply = f"could not understand: '{line}'"
        self._send(conn, reply.encode() + b"\n")


CONTROL_COMMANDS = ("protective_stop", "emergency_stop", "release_emergency_stop", "stop_program",
                    "drop_connections", "in_use", "remote_control", "state")


def _control(controller: FakeURController, line: str) -> dict:
    """Carries out one control line from stdin; returns the answer printed as JSON."""
    words = line.split()
    if not words or words[0] not in CONTROL_COMMANDS:
        return {"error": f"unknown control {line!r}; one of {', '.join(CONTROL_COMMANDS)}"}
    name = words[0]
    if name in ("in_use", "remote_control"):
        setattr(controller, name, len(words) > 1 and words[1] in ("1", "true", "on"))
    elif name != "state":
        getattr(controller, name)()
    with controller._lock:
        return {"tcp_pose": controller.tcp_pose, "program_running": controller.program_running,
                "protective_stop": controller.protective, "emergency_stop": controller.estop,
                "powered": controller.powered, "commands": [c for c, _ in controller.commands],
                "scripts": len(controller.scripts), "stats": dict(controller.stats)}


def main(argv=None) -> int:
    """Runs a fake UR controller until stdin closes or Ctrl-C.

    ur-rtde's constructors hold Python's GIL while they connect, so the fake must run in
    another process than the interfaces it serves; tests drive its faults through stdin: one
    control per line (see CONTROL_COMMANDS), each answered by one JSON line on stdout.
    """
    parser = argparse.ArgumentParser(
        prog="python -m incipient_slip.devices.fake_ur",
        description="A fake UR controller (dashboard 29999, script 30003, RTDE 30004) for ur-rtde. "
                    f"Controls on stdin, one per line: {', '.join(CONTROL_COMMANDS)}.")
    parser.add_argument("--address", default="127.0.0.2", help="loopback address to serve on (default 127.0.0.2)")
    parser.add_argument("--no-remote-control", action="store_true", help="answer 'is in remote control' with false")
    args = parser.parse_args(argv)
    controller = FakeURController(args.address, remote_control=not args.no_remote_control)
    try:
        controller.start()
    except OSError as exc:
        print(f"fake_ur: cannot serve on {args.address}: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({"ready": args.address, "version": list(controller.version)}), flush=True)
    try:
        for line in sys.stdin:
            if line.strip():
                print(json.dumps(_control(controller, line.strip())), flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        controller.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())

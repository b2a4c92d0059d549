"""`slip calibrate pdc | spring | press-gain | show`: the rig's three calibrations, done with
the rig's own devices and one reference instrument each (docs/hardware/setup.md, "Calibration").

Each command opens the devices itself, from the sections of `--config FILE` (as `slip rig check`
does): no graph and no device node may be running (the robot and the ports take one client).
It writes its section of the calibration file that rig.yaml names (`devices.calibration`), which
the nodes read through `rig_config`.

* `pdc`: the robot presses the fingertip on a scale (or a load cell) in depth steps; at each step
  the command reads the tared P_DC and asks for the scale's reading. newton_per_kpa = the slope
  of the reference force against P_DC.
* `press-gain`: the same depth sweep on the object itself, no reference needed; the press loop's
  gain is a fraction of 1 / the steepest contact stiffness in the working range
  (`calibration.press_gain`).
* `spring`: the object's end of the spring is held by a force gauge fixed to the rail; the stage
  moves to each point and the command asks for the gauge's reading. spring_n_per_mm = the slope.
"""
from __future__ import annotations

import argparse
import math
import re
import socket
import sys
import time

from incipient_slip.devices import calibration
from incipient_slip.errors import UsageError

__all__ = ["register"]

RTDE_PORT = 30004
GRAVITY = 9.80665


# --- the devices, opened directly ----------------------------------------------------------

class PdcProbe:
    """The BioTac through its bridge with the reader's handshake, tare and units: tared P_DC, kPa."""

    def __init__(self, port: str, units_path: str = "", tare_s: float = 3.0):
        from incipient_slip.devices import biotac as bt
        self.bt = bt
        try:
            self.units = bt.load_units(units_path)
        except ValueError as exc:
            raise UsageError(f"--units: {exc}") from None
        self.link = bt.BridgeLink(port)
        self.tare = bt.Tare(frames=int(round(tare_s * bt.FRAME_RATE_HZ)))
        self.port = port
        self.last: list[int] = []

    def _poll(self) -> None:
        for r in self.link.poll():
            if r.electrodes is not None:
                if self.tare.state == "none":
                    self.tare.start()
                self.tare.add(r.pdc, r.electrodes)
                self.last.append(int(r.pdc))
        failed = [text for level, text in self.link.events if level not in ("info",)]
        self.link.events.clear()
        if failed and self.link.connections == 0:
            raise UsageError(f"BioTac: {failed[0].split('; next attempt')[0]}")

    def wait_tared(self, timeout_s: float) -> str:
        """Streams and tares (finger free); returns the tare's line."""
        deadline = time.monotonic() + timeout_s
        while self.tare.state not in ("done", "refused"):
            if time.monotonic() > deadline:
                raise UsageError(f"BioTac on {self.port}: no tare within {timeout_s:g} s "
                                 f"(state {self.link.state}): is the bridge streaming?")
            self._poll()
            time.sleep(0.005)
        if self.tare.state == "refused":
            raise UsageError(f"BioTac tare refused: {self.tare.detail}")
        return self.tare.detail

    def mean_kpa(self, settle_s: float, duration_s: float) -> float:
        """Mean tared P_DC over `duration_s` after `settle_s`, kPa. The port is read all along:
        frames left in it would be old ones (the bridge drops what does not fit, not the oldest)."""
        end = time.monotonic() + settle_s
        while time.monotonic() < end:
            self._poll()
            time.sleep(0.005)
        self.last = []
        end = time.monotonic() + duration_s
        while time.monotonic() < end or not self.last:
            self._poll()
            time.sleep(0.005)
            if time.monotonic() > end + 2.0:
                raise UsageError(f"BioTac on {self.port}: no frame for 2 s")
        counts = sum(self.last) / len(self.last)
        return (counts - self.tare.pdc_tare_counts) * self.units.pdc_pa_per_count / 1000.0

    def close(self) -> None:
        self.link.close()


class Press:
    """The UR5 moved along the pressing axis from its start pose (ur-rtde, blocking moveL)."""

    def __init__(self, cfg: dict):
        from incipient_slip.devices.ur5 import explain
        self.host = str(cfg.get("robot_address", "192.168.1.5"))
        self.axis = "xyz".index(str(cfg.get("press_axis", "z")))
        self.sign = float(cfg.get("press_sign", 1.0))
        self.speed = float(cfg.get("speed_m_s", 0.01))
        self.accel = float(cfg.get("accel_m_s2", 0.1))
        try:
            socket.create_connection((self.host, RTDE_PORT), timeout=2.0).close()
        except OSError as exc:
            raise UsageError(f"no UR controller at {self.host}:{RTDE_PORT} ({exc}): is the robot on "
                             f"and robot_address its IP? (and no ur5 node running)") from None
        try:
            import rtde_control
            import rtde_receive
        except ImportError:
            raise UsageError("ur-rtde is not installed: pip install -e '.[hardware]'") from None
        try:
            self.receive = rtde_receive.RTDEReceiveInterface(self.host)
            self.control = rtde_control.RTDEControlInterface(self.host)
        except Exception as exc:       # ur-rtde raises RuntimeError texts
            raise UsageError(explain(exc, self.host)) from None
        self.start = list(self.receive.getActualTCPPose())

    def to_depth(self, depth_mm: float) -> float:
        """Moves to `depth_mm` below the start pose along the pressing axis; the depth reached."""
        pose = list(self.start)
        pose[self.axis] -= self.sign * depth_mm / 1000.0
        if not self.control.moveL(pose, self.speed, self.accel):
            raise UsageError(f"robot {self.host}: moveL to {depth_mm:.2f} mm refused (protective stop?)")
        actual = list(self.receive.getActualTCPPose())
        return self.sign * (self.start[self.axis] - actual[self.axis]) * 1000.0

    def close(self) -> None:
        try:
            self.control.moveL(self.start, self.speed, self.accel)
            self.control.stopScript()
        finally:
            self.control.disconnect()
            self.receive.disconnect()


# --- the procedures ------------------------------------------------------------------------

def ask(prompt: str, unit_words: dict) -> float:
    """One reading from the operator (stdin): a number with an optional unit (`unit_words`:
    unit -> factor to the base unit); UsageError when the input ends."""
    while True:
        print(prompt, flush=True)
        line = sys.stdin.readline()
        if not line:
            raise UsageError("the input ended before the last reading (nothing written)")
        m = re.fullmatch(r"\s*([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([a-zA-Z]*)\s*", line)
        if m and (m.group(2) or "") in unit_words and math.isfinite(float(m.group(1))):
            return float(m.group(1)) * unit_words[m.group(2) or ""]
        print(f"  not a reading: {line.strip()!r} (a number, unit {' or '.join(u or '(none)' for u in unit_words)})",
              flush=True)


def sweep(args, cfg: dict, reference=None) -> list[tuple]:
    """Presses in `--step-mm` steps until tared P_DC reaches `--max-kpa` (or max_press_mm); at
    each step waits `--settle-s` and averages P_DC over `--average-s`. (depth, kPa[, reference])."""
    max_kpa = args.max_kpa if args.max_kpa is not None else float(cfg.get("safety_limit_kpa", 6.0))
    max_press = float(cfg.get("max_press_mm", 10.0))
    probe = PdcProbe(args.biotac_port, args.units)
    try:
        print(f"taring the BioTac: keep the finger free ({probe.wait_tared(30.0)})", flush=True)
        robot = Press(cfg)
        points = []
        try:
            depth = 0.0
            while True:
                depth = round(depth + args.step_mm, 6)
                if depth > max_press:
                    print(f"stopped at max_press_mm {max_press:g} mm", flush=True)
                    break
                reached = robot.to_depth(depth)
                kpa = probe.mean_kpa(args.settle_s, args.average_s)
                line = f"depth {reached:.3f} mm: P_DC {kpa:.3f} kPa"
                print(line, flush=True)
                points.append((reached, kpa) if reference is None else (reached, kpa, reference(line)))
                if kpa >= max_kpa:
                    break
        finally:
            robot.close()
    finally:
        probe.close()
    return points


def cmd_pdc(args) -> int:
    cfg = _section(args.config, "ur5")
    grams = {"": 1.0, "N": 1.0, "g": GRAVITY / 1000.0, "kg": GRAVITY}
    points = sweep(args, cfg, lambda line: ask(f"{line}; reference load (N, or g / kg)?", grams))
    used = [(kpa, n) for _, kpa, n in points if kpa >= args.min_kpa]
    if len(used) < 3:
        raise UsageError(f"only {len(used)} steps with P_DC >= {args.min_kpa:g} kPa: start the robot "
                         f"closer to the scale (the start pose just touches it) or lower --step-mm")
    slope, intercept, se, rms = calibration.fit_line([k for k, _ in used], [n for _, n in used])
    path = calibration.save_section(args.config, "pdc", {
        "newton_per_kpa": round(slope, 6), "rel_sd": round(se / slope, 6), "intercept_n": round(intercept, 6),
        "rms_residual_n": round(rms, 6), "instrument": args.instrument,
        "points_kpa_n": [[round(k, 4), round(n, 5)] for k, n in used]})
    print(f"newton_per_kpa {slope:.4f} N/kPa (+/- {se:.4f}; intercept {intercept:+.3f} N, residual "
          f"{rms:.3f} N RMS, {len(used)} points) -> {path} [pdc]", flush=True)
    return 0


def cmd_press_gain(args) -> int:
    cfg = _section(args.config, "ur5")
    points = sweep(args, cfg)
    hi = args.max_kpa if args.max_kpa is not None else float(cfg.get("safety_limit_kpa", 6.0))
    try:
        gain, stiffness = calibration.press_gain([d for d, _ in points], [k for _, k in points],
                                                 args.min_kpa, hi, args.fraction)
    except ValueError as exc:
        raise UsageError(f"press gain: {exc}") from None
    path = calibration.save_section(args.config, "press_gain", {
        "gain_mm_per_kpa": round(gain, 6), "stiffness_kpa_per_mm": round(stiffness, 6),
        "fraction": args.fraction, "range_kpa": [args.min_kpa, hi],
        "points_mm_kpa": [[round(d, 4), round(k, 4)] for d, k in points]})
    print(f"gain_mm_per_kpa {gain:.4f} mm/kPa ({args.fraction:g} / the steepest stiffness "
          f"{stiffness:.3f} kPa/mm between {args.min_kpa:g} and {hi:g} kPa) -> {path} [press_gain]",
          flush=True)
    return 0


def cmd_spring(args) -> int:
    import serial

    from incipient_slip.devices import zaber
    cfg = _section(args.config, "zaber")
    port, steps_mm = str(cfg.get("port", "/dev/ttyUSB0")), float(cfg.get("microsteps_per_mm", 20997.375))
    start, lo, hi = (float(cfg.get(k, d)) for k, d in (("start_mm", 0.0), ("limit_min_mm", 0.0), ("limit_max_mm", 50.0)))
    points = [float(x) for x in args.points_mm.split(",")]
    if len(points) < 3 or any(not lo <= start + x <= hi for x in points):
        raise UsageError(f"--points-mm needs 3 or more points, each with start_mm + x within "
                         f"[limit_min_mm, limit_max_mm] = [{lo:g}, {hi:g}] (start_mm {start:g})")
    try:
        link = serial.Serial(port, int(cfg.get("baud", zaber.DEFAULT_BAUD)), timeout=0.02)
    except (serial.SerialException, OSError) as exc:
        raise UsageError(f"cannot open the Zaber stage's port {port}: {exc}") from None
    newtons = {"": 1.0, "N": 1.0, "mN": 1e-3}
    readings = []
    try:
        client = zaber.ZaberClient(link, device=int(cfg.get("device", 1)), axis=int(cfg.get("axis", 1)),
                                   microsteps_per_mm=steps_mm, name=port)
        mismatch = zaber.check_stage(client.read_stage(), axis=client.axis, microsteps_per_mm=steps_mm,
                                     resolution=int(cfg.get("resolution", zaber.DEFAULT_RESOLUTION)),
                                     limit_min_mm=lo, limit_max_mm=hi)
        if mismatch:
            raise UsageError(f"zaber {port}: {mismatch}")
        client.ensure_homed()
        try:
            for x in points:
                client.move_abs_mm(start + x)
                client.wait_idle(60.0)
                at = client.position_mm() - start
                readings.append((at, ask(f"stage at start_mm + {at:.3f} mm; force gauge reading (N)?", newtons)))
        finally:
            client.move_abs_mm(start)
            client.wait_idle(60.0)
    except zaber.ZaberError as exc:
        raise UsageError(f"zaber {port}: {exc}") from None
    finally:
        link.close()
    used = [(x, f) for x, f in readings if f > args.min_n]
    if len(used) < 3:
        raise UsageError(f"only {len(used)} readings above {args.min_n:g} N: the spring was slack; "
                         f"pull further (--points-mm)")
    slope, intercept, se, rms = calibration.fit_line([x for x, _ in used], [f for _, f in used])
    if not slope > 0:
        raise UsageError(f"the gauge's force does not rise with the pull (slope {slope:.4g} N/mm)")
    path = calibration.save_section(args.config, "spring", {
        "spring_n_per_mm": round(slope, 7), "rel_sd": round(se / slope, 6),
        "slack_mm": round(-intercept / slope, 4), "rms_residual_n": round(rms, 6),
        "instrument": args.instrument, "points_mm_n": [[round(x, 4), round(f, 5)] for x, f in used]})
    print(f"spring_n_per_mm {slope:.5f} N/mm (+/- {se:.5f}; zero force at start_mm + "
          f"{-intercept / slope:.2f} mm, residual {rms:.4f} N RMS, {len(used)} points) -> {path} [spring]",
          flush=True)
    return 0


def cmd_show(args) -> int:
    path = calibration.path_of(args.config)
    doc = calibration.load(args.config)
    if path is None:
        print(f"{args.config} names no calibration file (add `calibration: calibration.yaml`)")
        return 1
    for name in calibration.SECTIONS:
        s = doc.get(name)
        key = {"pdc": "newton_per_kpa", "spring": "spring_n_per_mm", "press_gain": "gain_mm_per_kpa"}[name]
        print(f"{name}: " + (f"{key} {s[key]} (rel sd {s.get('rel_sd', 'n/a')}, {s.get('date', '?')})"
                             if s else f"not calibrated: slip calibrate {name.replace('_', '-')} --config {args.config}"))
    if "pdc" in doc and "spring" in doc:
        print(f"launch identify.yaml rig:=hardware rig_config:={args.config} "
              f"newton_per_kpa:={doc['pdc']['newton_per_kpa']} gain_rel_sd:={doc['pdc']['rel_sd']} "
              f"spring_n_per_mm:={doc['spring']['spring_n_per_mm']} spring_rel_sd:={doc['spring']['rel_sd']}")
    return 0


def _section(path: str, name: str) -> dict:
    from incipient_slip.devices import rig_config
    return rig_config.load_section(path, name)


def register(subparsers) -> None:
    """Adds `slip calibrate` to the `slip` command."""
    cal = subparsers.add_parser(
        "calibrate", help="the rig's calibrations: P_DC -> F_N, the spring, the press gain",
        description="Measures one calibration of the real rig with its own devices and a reference "
        "instrument, and writes it to the calibration file that --config names (`calibration:`), "
        "where the nodes read it. No graph may be running (the commands open the devices "
        "themselves). Procedures: docs/hardware/setup.md, \"Calibration\".")
    sub = cal.add_subparsers(dest="tool", metavar="TOOL", required=True)

    def common(p, biotac: bool):
        p.add_argument("--config", required=True, metavar="FILE",
                       help="your rig configuration (a copy of config/rig.yaml with your addresses)")
        if biotac:
            p.add_argument("--biotac-port", required=True, metavar="PORT", help="the BioTac bridge's serial port")
            p.add_argument("--units", default="", metavar="FILE", help="BioTac units file, as biotac_reader units:=")
            p.add_argument("--step-mm", type=float, default=0.5, help="press depth step (default 0.5 mm)")
            p.add_argument("--max-kpa", type=float, default=None,
                           help="stop pressing at this tared P_DC (default: safety_limit_kpa of [ur5])")
            p.add_argument("--settle-s", type=float, default=1.5, help="wait after each step (default 1.5 s)")
            p.add_argument("--average-s", type=float, default=0.5, help="P_DC averaged over this (default 0.5 s)")

    p = sub.add_parser("pdc", help="P_DC -> F_N (newton_per_kpa): the robot presses the finger on a scale",
                       description="The robot presses the fingertip on a scale in depth steps from its "
                       "start pose (where it just touches the scale), up to --max-kpa; at each step it "
                       "prints the tared P_DC and asks for the scale's reading (N, or g / kg: `153 g`). "
                       "Writes newton_per_kpa (the slope of force on P_DC), its relative SD and the "
                       "points to [pdc] of the calibration file. The BioTac is tared first: keep the "
                       "finger free when it starts.")
    common(p, True)
    p.add_argument("--min-kpa", type=float, default=0.5, help="fit only steps at or above this P_DC (default 0.5)")
    p.add_argument("--instrument", default="", help="the reference you used, kept in the file (e.g. 'scale XY, 0.1 g')")
    p.set_defaults(func=cmd_pdc)

    p = sub.add_parser("press-gain", help="the ur5 node's gain_mm_per_kpa: a press sweep on the object",
                       description="The robot presses the fingertip on the object (start pose: just "
                       "touching) in depth steps up to --max-kpa and measures P_DC at each; the contact "
                       "stiffness is the secant between neighbouring steps. gain_mm_per_kpa = "
                       "--fraction / the steepest stiffness between --min-kpa and --max-kpa, so that "
                       "the press loop never overshoots there. Writes [press_gain], which the ur5 node "
                       "reads through rig_config.")
    common(p, True)
    p.add_argument("--min-kpa", type=float, default=1.0, help="working range's low end (default 1 kPa)")
    p.add_argument("--fraction", type=float, default=0.8,
                   help="gain x steepest stiffness (default 0.8; 1 would settle in one period)")
    p.set_defaults(func=cmd_press_gain)

    p = sub.add_parser("spring", help="the spring constant: the stage pulls against a force gauge",
                       description="With the object's end of the spring held by a force gauge fixed "
                       "to the rail, the stage moves to start_mm + each of --points-mm; at each it asks "
                       "for the gauge's reading (N or mN), then returns to start_mm. Writes "
                       "spring_n_per_mm (the slope), its relative SD and slack_mm (zero force) to "
                       "[spring] of the calibration file.")
    common(p, False)
    p.add_argument("--points-mm", default="4,8,12,16,20,23",
                   help="pulls from start_mm, comma-separated (default 4,8,12,16,20,23: the protocol's 23 mm)")
    p.add_argument("--min-n", type=float, default=0.0, help="fit only readings above this (a slack spring reads 0)")
    p.add_argument("--instrument", default="", help="the gauge you used, kept in the file")
    p.set_defaults(func=cmd_spring)

    p = sub.add_parser("show", help="what the calibration file holds, and the identification's launch args")
    p.add_argument("--config", required=True, metavar="FILE", help="your rig configuration")
    p.set_defaults(func=cmd_show)

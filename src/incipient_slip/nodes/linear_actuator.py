"""linear_actuator: the Zaber stage that pulls the object, one step per period (the paper's
protocol: 23 mm in 450 steps, one step each 500 ms), publishing /actuator/state.

    python -m incipient_slip.nodes.linear_actuator port:=/dev/ttyUSB0 microsteps_per_mm:=20997.375

At start it opens the port, checks that the device answers, reads what the stage is (device
id, axis count, microstep resolution, travel limits: `zaber.ZaberClient.read_stage`) and checks
the configuration against it (`zaber.check_stage`: the axis exists, `resolution` is the device's,
[limit_min_mm, limit_max_mm] lies within the device's limits; exit 2 with the line saying what to
change), homes the axis if it has no reference position (WR) and moves to `start_mm`. Then every `period_s` it moves to the next
absolute target `start_mm + (k + 1) * travel_mm / steps` (absolute targets: no rounding drift,
and a lost reply can be resent safely), waits until IDLE, reads the position back and
publishes `ActuatorState(period=k)`: the period tick the grip controller answers. With
`lockstep: true` step k + 1 waits for the `GripCommand` of period k. Step 0 waits (at most
`wait_timeout_s`) until the readers the launch names for its outputs have subscribed (started by
hand: until the tick has `wait_subscribers` readers), so period 0 is not lost, and
with `wait_tare: true` also until the BioTac reader's tare is done (`/biotac/status`), so no
period runs on an untared P_DC (F_N would read tens of kPa). Period 0 starts when they are: its
step and tick come one period later.

`mode: commanded` (rig identification, launch/identify.yaml): no steps of its own; each
`ActuatorCommand(period=k)` moves the stage to `start_mm + position_mm` (clamped to the limits,
with a warning) and publishes `ActuatorState(period=k)` once the move is done and read back;
an older or repeated period is refused and counted. A move may take `move_timeout_s` plus its
distance at `speed_mm_s`. On shutdown (the end, Ctrl-C, SIGTERM) it moves back to start_mm, where
the tension spring is slack, so an interrupted identification leaves the rig unloaded. Commands before the readers and the tare are in wait for them (the
newest kept).

Safety of its own: a target outside [limit_min_mm, limit_max_mm] is refused; a fault flag (FS
stalled), a lost reference (WR after a reset), no reply, or a position that is not the target
stops the protocol: the stage is told to stop and the node exits 3 with one line. A serial port
that cannot be opened or a device that does not answer at start is exit 2 (a missing device).
"""
from __future__ import annotations

import time

from incipient_slip.devices import zaber
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.devices.rig_config import apply_rig_config
from incipient_slip.messages import ActuatorCommand, ActuatorState, BiotacStatus, GripCommand

EXIT_NO_DEVICE = 2
EXIT_FAULT = 3
PAPER_TRAVEL_MM = 23.0
PAPER_STEPS = 450


def step_target_mm(k: int, start_mm: float, travel_mm: float, steps: int) -> float:
    """Where the stage stands after step k (0-based): start + (k + 1) travel / steps, mm."""
    return start_mm + (k + 1) * travel_mm / steps


class LinearActuator(Node):
    """Pulls the object one step per period on a Zaber stage and publishes the period tick."""

    INPUTS = {GripCommand.TOPIC: GripCommand, BiotacStatus.TOPIC: BiotacStatus, ActuatorCommand.TOPIC: ActuatorCommand}
    OPTIONAL_INPUTS = frozenset({GripCommand.TOPIC, ActuatorCommand.TOPIC})    # by mode
    OUTPUTS = {ActuatorState.TOPIC: ActuatorState}
    PARAMS = {
        "rig_config": Param("", help="config/rig.yaml: unset parameters from its zaber section"),
        "port": Param("/dev/ttyUSB0", help="serial port of the Zaber stage"),
        "baud": Param(zaber.DEFAULT_BAUD, choices=(9600, 19200, 38400, 57600, 115200), help="baud rate"),
        "device": Param(1, lo=1, hi=99, help="device address"),
        "axis": Param(1, lo=1, hi=9, help="axis number"),
        "microsteps_per_mm": Param(20997.375, lo=1.0, hi=1e7, help="microsteps per mm at `resolution` "
                                   "(the stage's datasheet: 1 / microstep size; config/rig.yaml)"),
        "resolution": Param(zaber.DEFAULT_RESOLUTION, lo=1, hi=4096,
                            help="microsteps per full step that microsteps_per_mm is for; the device's "
                                 "own (get resolution) must match"),
        "travel_mm": Param(PAPER_TRAVEL_MM, lo=0.0, hi=500.0, help="total pull (paper: 23 mm)"),
        "steps": Param(PAPER_STEPS, lo=1, hi=100000, help="number of steps (paper: 450)"),
        "period_s": Param(0.5, lo=0.01, hi=60.0, help="one step per period (paper: 500 ms)"),
        "start_mm": Param(0.0, lo=-1000.0, hi=1000.0, help="absolute position of step 0's start"),
        "limit_min_mm": Param(0.0, lo=-1000.0, hi=1000.0, help="never command below this (within the device's limit.min)"),
        "limit_max_mm": Param(50.0, lo=-1000.0, hi=1000.0, help="never command above this (within the device's limit.max)"),
        "tolerance_mm": Param(0.005, lo=0.0, hi=1.0, help="read-back position must be this close"),
        "open_timeout_s": Param(0.0, lo=0.0, hi=600.0, help="keep trying the port and device this long at start"),
        "reply_timeout_s": Param(0.5, lo=0.01, hi=10.0, help="wait this long for a reply"),
        "move_timeout_s": Param(0.4, lo=0.01, hi=60.0, help="a step must finish within this"),
        "home_timeout_s": Param(60.0, lo=0.1, hi=600.0, help="homing must finish within this"),
        "lockstep": Param(False, choices=(False, True), help="step k+1 waits for GripCommand(period=k)"),
        "mode": Param("steps", choices=("steps", "commanded"),
                      help="steps: the paper's pull, one step per period; commanded: go where /actuator/command says"),
        "speed_mm_s": Param(5.0, lo=0.01, hi=1000.0, help="commanded: a move may take move_timeout_s + distance / this"),
        "exit_when_done": Param(False, choices=(False, True), help="exit 0 after the last step"),
        "wait_subscribers": Param(1, lo=0, hi=100, help="started by hand: step 0 waits for this many readers of the tick"),
        "wait_timeout_s": Param(10.0, lo=0.0, hi=3600.0, help="then starts anyway, with a warning"),
        "wait_tare": Param(False, choices=(False, True), help="step 0 also waits for the BioTac reader's tare"),
    }

    def __init__(self, port=None, **kwargs):
        super().__init__("linear_actuator", **kwargs)
        apply_rig_config(self, "zaber", kwargs.get("params"))
        p = self.param
        if not p("limit_min_mm") <= p("start_mm") <= p("limit_max_mm"):
            raise ParamError(f"start_mm:={p('start_mm')} is outside [limit_min_mm, limit_max_mm]"
                             f" = [{p('limit_min_mm')}, {p('limit_max_mm')}]")
        self.steps, self.steps_done, self.answered = p("steps"), 0, -1
        self.done = self.failed = False
        self.state_pub = self.create_publisher(ActuatorState)
        self.create_subscription(GripCommand, self.on_grip)
        self.tared = not p("wait_tare")
        if not self.tared:
            self.create_subscription(BiotacStatus, self.on_biotac_status)
        self.commanded = p("mode") == "commanded"
        self.pending: ActuatorCommand | None = None
        self.last_period, self.refused = -1, 0
        if self.commanded:
            self.create_subscription(ActuatorCommand, self.on_command)
        self.client = zaber.ZaberClient(port or self._open(), device=p("device"), axis=p("axis"),
                                        microsteps_per_mm=p("microsteps_per_mm"),
                                        timeout_s=p("reply_timeout_s"), name=p("port"))
        if self.commanded:         # before the port closes
            self.on_shutdown(self._unload)
        self.on_shutdown(self._close)
        if not self._startup():
            return
        self._wait_until = time.monotonic() + p("wait_timeout_s")
        self._started = False
        self.create_timer(p("period_s") if not self.commanded else 0.05, self.step)

    def _open(self):
        import serial     # pyserial; imported here so that tests can pass a port of their own
        deadline = time.monotonic() + self.param("open_timeout_s")
        while True:
            try:
                return serial.Serial(self.param("port"), self.param("baud"), timeout=0.02)
            except (serial.SerialException, OSError) as exc:
                if time.monotonic() >= deadline:
                    raise ParamError(f"cannot open the Zaber stage's serial port "
                                     f"{self.param('port')}: {exc}") from None
            time.sleep(0.2)

    def _startup(self) -> bool:
        deadline = time.monotonic() + self.param("open_timeout_s")
        while True:
            try:
                self.client.status()
                break
            except zaber.ZaberTimeout as exc:
                if time.monotonic() >= deadline:
                    self.log(f"linear_actuator: {exc}")
                    self.shutdown("no Zaber device", EXIT_NO_DEVICE)
                    return False
        p = self.param
        try:
            info = self.client.read_stage()
        except zaber.ZaberError as exc:
            self.log(f"linear_actuator: cannot read what the stage is: {exc}")
            self.shutdown("no Zaber stage information", EXIT_NO_DEVICE)
            return False
        mismatch = zaber.check_stage(info, axis=p("axis"), microsteps_per_mm=p("microsteps_per_mm"),
                                     resolution=p("resolution"), limit_min_mm=p("limit_min_mm"),
                                     limit_max_mm=p("limit_max_mm"))
        if mismatch:
            self.log(f"linear_actuator: {p('port')}: {mismatch}")
            self.shutdown("configuration does not fit the stage", EXIT_NO_DEVICE)
            return False
        self.log(f"Zaber stage on {p('port')}: {info.describe(p('microsteps_per_mm'))}")
        try:
            if self.client.ensure_homed(self.param("home_timeout_s")):
                self.log("homed the stage (it had no reference position)")
            self._move_to(self.param("start_mm"), "the move to start_mm")
        except zaber.ZaberError as exc:
            self._fault(str(exc))
            return False
        if self.commanded:
            self.log(f"at {self.param('start_mm'):g} mm; commanded: one move per /actuator/command")
        else:
            self.log(f"at {self.param('start_mm'):g} mm; {self.steps} steps of "
                     f"{1000 * self.param('travel_mm') / self.steps:.1f} um, one per "
                     f"{self.param('period_s'):g} s")
        return True

    def on_biotac_status(self, msg: BiotacStatus):
        if msg.tare_state == "done" and not self.tared:
            self.tared = True
            self.log("BioTac tared: the pull may start")

    def on_grip(self, msg: GripCommand):
        self.answered = max(self.answered, msg.period)

    def step(self):
        if self.done or self.failed or self.stopping:
            return
        k = self.steps_done
        if not self._started:
            if self.readers:           # in a launch: the readers it names, by name
                missing = self.missing_readers()
                short = f"readers {', '.join(missing)} not subscribed" if missing else ""
            else:                      # started by hand: a count
                short = (f"fewer than {self.param('wait_subscribers')} reader(s) of {self.state_pub.topic}"
                         if self.state_pub.subscriber_count() < self.param("wait_subscribers") else "")
            if (short or not self.tared) and time.monotonic() < self._wait_until:
                return                 # no step before the tick has its readers (slow joiner)
            if short:
                self.warn(f"{short} after {self.param('wait_timeout_s'):g} s; starting")
            if not self.tared:
                self.warn(f"no BioTac tare after {self.param('wait_timeout_s'):g} s; starting")
            self._started = True
            return        # period 0 starts now (after the tare): its step and tick come one period later
        if self.commanded:
            self.move_commanded()
            return
        if self.param("lockstep") and k > 0 and self.answered < k - 1:
            self.warn(f"step {k} waits for the grip command of period {k - 1}", throttle_s=5.0)
            return
        target = step_target_mm(k, self.param("start_mm"), self.param("travel_mm"), self.steps)
        try:
            position = self._move_to(target, f"step {k}")
        except zaber.ZaberError as exc:
            self._fault(f"step {k}: {exc}")
            return
        self.state_pub.publish(ActuatorState(position_mm=position, period=k, busy=False))
        self.steps_done += 1
        if self.steps_done >= self.steps:
            self.done = True
            self.log(f"protocol done: {self.steps} steps, at {position:.4f} mm")
            if self.param("exit_when_done"):
                self.shutdown("protocol done")

    def on_command(self, msg: ActuatorCommand):
        if msg.period <= max(self.last_period, self.pending.period if self.pending else -1):
            self.refused += 1
            self.warn(f"refused ActuatorCommand(period={msg.period}): period {self.last_period} is done "
                      f"({self.refused} refused)", throttle_s=1.0)
            return
        self.pending = msg
        if self._started:
            self.move_commanded()

    def move_commanded(self):
        """Commanded mode: move to the newest command's position and publish its tick."""
        msg, self.pending = self.pending, None
        if msg is None or self.failed:
            return
        lo, hi = self.param("limit_min_mm"), self.param("limit_max_mm")
        target = self.param("start_mm") + msg.position_mm
        clamped = min(max(target, lo), hi)
        if clamped != target:
            self.warn(f"ActuatorCommand(period={msg.period}) to {target:.4f} mm is outside [{lo}, {hi}] mm; "
                      f"moving to {clamped:.4f} mm", throttle_s=1.0)
        try:
            position = self._move_at_speed(clamped, f"command {msg.period}")
        except zaber.ZaberError as exc:
            self._fault(f"command {msg.period}: {exc}")
            return
        self.last_period = msg.period
        self.steps_done += 1                   # moves done (the log at the end)
        self.state_pub.publish(ActuatorState(position_mm=position, period=msg.period, busy=False))

    def _move_at_speed(self, target_mm: float, during: str) -> float:
        """A commanded-mode move of any length: it may take move_timeout_s plus its distance at speed_mm_s."""
        distance = abs(target_mm - self.client.position_mm())
        return self._move_to(target_mm, during, self.param("move_timeout_s") + distance / self.param("speed_mm_s"))

    def _move_to(self, target_mm: float, during: str, timeout_s: float | None = None) -> float:
        """Moves to `target_mm` within the configured limits and returns the position read back."""
        lo, hi = self.param("limit_min_mm"), self.param("limit_max_mm")
        if not lo <= target_mm <= hi:
            raise zaber.ZaberError(f"target {target_mm:.4f} mm is outside the configured travel "
                                   f"[{lo}, {hi}] mm: refused")
        self.client.move_abs_mm(target_mm)
        if timeout_s is None:
            timeout_s = self.param("move_timeout_s") if during.startswith("step") else self.param("home_timeout_s")
        self.client.wait_idle(timeout_s, during)
        position = self.client.position_mm()
        if abs(position - target_mm) > self.param("tolerance_mm"):
            raise zaber.ZaberError(f"stage at {position:.4f} mm after {during}, target "
                                   f"{target_mm:.4f} mm (tolerance {self.param('tolerance_mm')} mm)")
        return position

    def _fault(self, text: str):
        self.failed = True
        try:
            self.client.stop()
        except zaber.ZaberError:
            pass
        self.log(f"linear_actuator: FAULT: {text}; the stage is stopped, the run cannot go on")
        self.shutdown("stage fault", EXIT_FAULT)

    def _unload(self):
        """Commanded mode ends with the stage at start_mm, where the tension spring is slack: an
        interrupted identification leaves the rig unloaded whatever its other nodes do."""
        if self.failed or self.last_period < 0:
            return
        try:
            self._move_at_speed(self.param("start_mm"), "the move back to start_mm")
            self.log(f"back at start_mm {self.param('start_mm'):g} mm: the spring is slack")
        except zaber.ZaberError as exc:
            self.log(f"linear_actuator: could not move back to start_mm: {exc}; the spring may be loaded")

    def _close(self):
        done = f"moves done {self.steps_done}" if self.commanded else f"steps done {self.steps_done}/{self.steps}"
        self.log(f"{done}; serial {dict(self.client.stats)}")
        close = getattr(self.client.port, "close", None)
        if close is not None:
            close()


def main(argv=None):
    return run_node(LinearActuator, argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""Zaber ASCII protocol over a serial port: message format, checksums, replies, and a client.

Written from Zaber's public protocol description (docs/hardware.md, "Zaber"); no code of
theirs. A command is `/device axis id command data:CC` and a newline; the device answers
`@dd a id OK|RJ IDLE|BUSY ww data[:CC]` and CR LF, where `ww` is its highest-priority warning
flag (`--` for none). `#` lines carry extra information, `!` lines are alerts (off by default).
The checksum is the two's complement of the byte sum of the text between the leading
character and the colon, mod 256, in upper-case hex.

The client sends every command with a message id (0..99, cycling, two digits) and a checksum,
reads lines until the reply with its device, axis and id (one or two digits: `@01 1 5 OK ...`
and `@01 1 05 OK ...` are the same reply), and drops (and counts) everything else:
a garbled line, a wrong checksum, a reply to an earlier command that timed out. A rejected
command raises `ZaberRejected` with the reason spelled out; a fault flag (F...) raises
`ZaberFault`; no reply raises `ZaberTimeout`. Relative moves are never retried: only the
idempotent status poll, reads, stop and absolute moves are.

What the stage is comes from the device itself (`read_stage`: device id, peripheral id, axis
count, microstep resolution, travel limits), checked against the rig configuration by
`check_stage` (docs/hardware-motion.md, "Zaber: our driver, not zaber-motion"). The one thing a
device does not report is the length of its microstep: that is the configuration's
`microsteps_per_mm`, from the stage's datasheet at the `resolution` it is given for.
"""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass

__all__ = ["ZaberError", "ZaberTimeout", "ZaberRejected", "ZaberFault", "ZaberLineError",
           "Reply", "checksum", "format_command", "parse_line", "ZaberClient",
           "REJECTION_REASONS", "WARNING_FLAGS", "DEFAULT_BAUD", "DEFAULT_RESOLUTION", "StageInfo",
           "check_stage"]

DEFAULT_BAUD = 115200
DEFAULT_RESOLUTION = 64  # microsteps per full step at which Zaber's datasheets give the microstep size
MAX_LATE_LINES = 64      # lines read after a reply's deadline (what came while this process waited)

# Why a device rejects a command (the data of an RJ reply), in words a user can act on.
REJECTION_REASONS = {
    "BADDATA": "a value is out of range or not a number (e.g. a position beyond limit.min/limit.max)",
    "BADCOMMAND": "the device does not know this command (check the firmware's command set)",
    "BADAXIS": "no such axis on this device",
    "BADMESSAGEID": "the message id is not 0..99",
    "DEVICEONLY": "the command must be sent to axis 0",
    "AGAIN": "the device is busy with a previous command; send it again",
    "FULL": "the device's command buffer is full",
    "LOCKSTEP": "the axis is in a lockstep group",
    "NOACCESS": "the setting needs a higher access level",
    "PARKED": "the axis is parked: send 'tools parking unpark'",
    "STATUSBUSY": "the command needs the axis to be idle",
}
# Flags in the warning field; F* are faults that stop motion, W* warnings, N* notices.
WARNING_FLAGS = {
    "FS": "stalled and stopped (the load blocked the stage)",
    "FD": "driver disabled", "FQ": "encoder error", "FT": "excessive twist",
    "FE": "limit error", "FB": "stream bounds error", "FP": "path deviation",
    "FO": "overdrive limit exceeded", "FM": "motor mismatch",
    "WR": "no reference position: the axis must be homed",
    "WH": "device not homed", "WL": "unexpected limit trigger", "WV": "voltage out of range",
    "WT": "temperature too high", "WM": "displaced when stationary", "WP": "invalid calibration",
    "NC": "manual control", "NI": "command interrupted", "ND": "stream discontinuity",
    "NU": "setting update pending", "NJ": "joystick calibration in progress",
}


class ZaberError(RuntimeError):
    """Base of the errors the client raises; the text names port, device, axis and command."""


class ZaberTimeout(ZaberError):
    """No reply to a command within the timeout."""


class ZaberRejected(ZaberError):
    """The device answered RJ; `reason` is its rejection reason (BADDATA, BADCOMMAND, ...)."""

    def __init__(self, text: str, reason: str):
        self.reason = reason
        super().__init__(text)


class ZaberFault(ZaberError):
    """The device reports a fault flag (F...) or lost its position (WR) in the middle of work."""

    def __init__(self, text: str, flag: str):
        self.flag = flag
        super().__init__(text)


class ZaberLineError(ValueError):
    """A line that is not a well-formed message, or whose checksum is wrong; `reason` is a key."""

    def __init__(self, reason: str, line: str):
        self.reason = reason
        super().__init__(f"{reason}: {line[:80]!r}")


@dataclass(frozen=True)
class Reply:
    """One message from a device: kind '@' reply, '!' alert or '#' info."""

    kind: str
    device: int
    axis: int
    message_id: int | None
    flag: str = ""          # OK or RJ (replies)
    status: str = ""        # IDLE or BUSY (replies, alerts)
    warning: str = "--"     # highest-priority warning flag, "--" for none
    data: str = ""

    @property
    def busy(self) -> bool:
        return self.status == "BUSY"


def checksum(text: str) -> str:
    """The two-hex-digit checksum of `text` (the part between the leading character and ':')."""
    return f"{(-sum(text.encode('ascii'))) & 0xFF:02X}"


def format_command(device: int, axis: int, message_id: int | None, command: str,
                   with_checksum: bool = True) -> bytes:
    """The bytes of one command line, e.g. b"/1 1 07 move rel 1000:A3\\n"."""
    body = f"{device} {axis}" + (f" {message_id:02d}" if message_id is not None else "")
    body += f" {command}" if command else ""
    return (f"/{body}" + (f":{checksum(body)}" if with_checksum else "") + "\n").encode("ascii")


def message_id_of(word: str) -> int | None:
    """The message id a word is (0..99, one or two digits: devices echo `5` as well as
    `05`), or None when the word is not one."""
    return int(word) if 1 <= len(word) <= 2 and word.isdigit() and word.isascii() else None


def _split_checksum(text: str, line: str) -> str:
    if len(text) >= 3 and text[-3] == ":":
        body, cc = text[:-3], text[-2:]
        if checksum(body) != cc.upper():
            raise ZaberLineError("checksum", line)
        return body
    return text


def parse_line(line: str) -> Reply:
    """The Reply in one received line (without CR LF); ZaberLineError when malformed."""
    if not line or line[0] not in "@!#" or not line.isprintable():
        raise ZaberLineError("garbled", line)
    kind = line[0]
    body = _split_checksum(line[1:], line)
    words = body.split(" ")
    try:
        device, axis = int(words[0]), int(words[1])
    except (IndexError, ValueError):
        raise ZaberLineError("garbled", line) from None
    rest = words[2:]
    message_id = message_id_of(rest[0]) if rest else None
    if message_id is not None:
        rest = rest[1:]
    if kind == "#":
        return Reply(kind, device, axis, message_id, data=" ".join(rest))
    if kind == "!":
        if len(rest) < 2 or rest[0] not in ("IDLE", "BUSY"):
            raise ZaberLineError("garbled", line)
        return Reply(kind, device, axis, message_id, status=rest[0], warning=rest[1],
                     data=" ".join(rest[2:]))
    if (len(rest) < 4 or rest[0] not in ("OK", "RJ") or rest[1] not in ("IDLE", "BUSY")
            or len(rest[2]) != 2):
        raise ZaberLineError("garbled", line)
    return Reply(kind, device, axis, message_id, rest[0], rest[1], rest[2], " ".join(rest[3:]))


@dataclass(frozen=True)
class StageInfo:
    """What a Zaber device reports about itself and one axis (`ZaberClient.read_stage`)."""

    device_id: int
    axis_count: int
    peripheral_id: int      # 0: an integrated device (no separate peripheral)
    resolution: int         # microsteps per full step
    limit_min: int          # travel limits, microsteps
    limit_max: int

    def describe(self, microsteps_per_mm: float) -> str:
        return (f"device id {self.device_id}, peripheral id {self.peripheral_id}, "
                f"{self.axis_count} axis(es), resolution {self.resolution}, travel "
                f"{self.limit_min / microsteps_per_mm:.3f}..{self.limit_max / microsteps_per_mm:.3f} mm")


def check_stage(info: StageInfo, *, axis: int, microsteps_per_mm: float, resolution: int,
                limit_min_mm: float, limit_max_mm: float) -> str:
    """"" when the configuration fits the stage the device reports, else the line saying what
    does not and what to change: the axis exists, the device's microstep resolution is the one
    `microsteps_per_mm` is given for, and [limit_min_mm, limit_max_mm] lies within the device's
    own limit.min..limit.max (a configured travel beyond them is a wrong stage or a wrong
    microstep size; the device would refuse those moves with BADDATA mid-run)."""
    if axis > info.axis_count:
        return (f"axis {axis} is configured but the device (id {info.device_id}) has "
                f"{info.axis_count} axis(es): set axis to 1..{info.axis_count}")
    if info.resolution != resolution:
        return (f"the axis's microstep resolution is {info.resolution} microsteps per step but "
                f"microsteps_per_mm {microsteps_per_mm:g} is configured for resolution {resolution}: "
                f"set microsteps_per_mm to {microsteps_per_mm * info.resolution / resolution:g} and "
                f"resolution to {info.resolution}, or set the device back ('set resolution {resolution}')")
    lo, hi = info.limit_min / microsteps_per_mm, info.limit_max / microsteps_per_mm
    if not (lo - 1e-9 <= limit_min_mm and limit_max_mm <= hi + 1e-9):
        return (f"the configured travel [{limit_min_mm:g}, {limit_max_mm:g}] mm is outside the "
                f"device's limit.min..limit.max = [{lo:.3f}, {hi:.3f}] mm at microsteps_per_mm "
                f"{microsteps_per_mm:g} (device id {info.device_id}): a shorter stage than "
                f"configured, or a wrong microsteps_per_mm; set limit_min_mm/limit_max_mm within it")
    return ""


class ZaberClient:
    """Talks to one axis of one Zaber device on a serial port (pyserial or any object with
    write(), readline() honouring a timeout, and reset_input_buffer()).

    `microsteps_per_mm` converts positions; it comes from the rig configuration (the stage's
    microstep size), never from Zaber's online device database.
    """

    def __init__(self, port, *, device: int = 1, axis: int = 1, microsteps_per_mm: float,
                 timeout_s: float = 1.0, poll_s: float = 0.01, name: str = "serial port",
                 clock=time.monotonic):
        if not microsteps_per_mm > 0:
            raise ValueError(f"microsteps_per_mm must be > 0, got {microsteps_per_mm}")
        self.port, self.device, self.axis = port, device, axis
        self.microsteps_per_mm = microsteps_per_mm
        self.timeout_s, self.poll_s, self.name, self.clock = timeout_s, poll_s, name, clock
        self.stats: Counter = Counter()
        self.alerts: list[Reply] = []
        self.last_reply: Reply | None = None
        self._next_id = 0

    # --- one exchange ---

    def command(self, command: str, *, retries: int = 0, axis: int | None = None) -> Reply:
        """The device's OK reply to `command` ("" polls status); raises ZaberRejected on RJ,
        ZaberTimeout without a reply (after `retries` more tries: only for idempotent ones).
        `axis=0` sends it to the device as a whole (device-scope settings)."""
        axis = self.axis if axis is None else axis
        for attempt in range(retries + 1):
            message_id = self._next_id
            self._next_id = (self._next_id + 1) % 100
            self.port.write(format_command(self.device, axis, message_id, command))
            self.stats["commands"] += 1
            reply = self._await(message_id, axis)
            if reply is not None:
                break
            self.stats["timeouts"] += 1
        else:
            raise ZaberTimeout(f"no reply from {self.name} device {self.device} axis {axis} "
                               f"to {command or '(status poll)'!r} within {self.timeout_s:g} s "
                               f"(powered, cabled, at the configured baud rate, ASCII protocol?)")
        self.last_reply = reply
        if reply.flag == "RJ":
            self.stats["rejected"] += 1
            why = REJECTION_REASONS.get(reply.data, "unknown reason")
            raise ZaberRejected(f"{self.name} device {self.device} axis {axis} rejected "
                                f"{command!r}: {reply.data} ({why})", reply.data)
        return reply

    def get_int(self, setting: str, *, axis: int | None = None) -> int:
        """The integer value of `setting` (`get SETTING`); ZaberError when it is not one."""
        reply = self.command(f"get {setting}", retries=2, axis=axis)
        try:
            return int(reply.data.split()[0])
        except (IndexError, ValueError):
            raise ZaberError(f"{self.name}: 'get {setting}' answered {reply.data!r}, not an integer") from None

    def read_stage(self) -> "StageInfo":
        """What the device says it is: device id and axis count (device scope, axis 0), and the
        axis's peripheral id, microstep resolution and travel limits (microsteps)."""
        return StageInfo(device_id=self.get_int("deviceid", axis=0),
                         axis_count=self.get_int("system.axiscount", axis=0),
                         peripheral_id=self.get_int("peripheralid"),
                         resolution=self.get_int("resolution"),
                         limit_min=self.get_int("limit.min"), limit_max=self.get_int("limit.max"))

    def _await(self, message_id: int, axis: int) -> Reply | None:
        """The reply with `message_id`, or None when none came within `timeout_s`. The deadline
        is checked before each read, so what arrived while this process was not run (a loaded
        host) is still read once the deadline has passed: the timeout is the device's silence,
        not this process's lateness (lines already waiting are read, at most MAX_LATE_LINES)."""
        deadline = self.clock() + self.timeout_s
        late_lines = 0
        while True:
            expired = self.clock() >= deadline
            raw = self.port.readline()
            if expired and (not raw or late_lines >= MAX_LATE_LINES):
                return None
            late_lines += expired
            if not raw:
                continue
            if not raw.endswith(b"\n"):
                self._drop("partial", raw)
                continue
            try:
                reply = parse_line(raw.decode("ascii").rstrip("\r\n"))
            except (UnicodeDecodeError, ZaberLineError) as exc:
                self._drop(getattr(exc, "reason", "garbled"), raw)
                continue
            if reply.kind == "!":
                self.alerts.append(reply)
                self.stats["alerts"] += 1
            elif reply.kind == "#":
                self.stats["info"] += 1
            elif (reply.device, reply.axis, reply.message_id) != (self.device, axis, message_id):
                self._drop("foreign_reply", raw)   # another axis, or a late reply to a timed-out command
            else:
                return reply

    def _drop(self, reason: str, raw: bytes) -> None:
        self.stats["dropped"] += 1
        self.stats[f"dropped:{reason}"] += 1

    # --- what the actuator node uses ---

    def status(self) -> Reply:
        """A status poll (the empty command): BUSY/IDLE and the warning flag."""
        return self.command("", retries=2)

    def position_mm(self) -> float:
        """The axis position, mm."""
        reply = self.command("get pos", retries=2)
        try:
            return int(reply.data.split()[0]) / self.microsteps_per_mm
        except (IndexError, ValueError):
            raise ZaberError(f"{self.name}: 'get pos' answered {reply.data!r}, not a number") from None

    def to_microsteps(self, mm: float) -> int:
        """`mm` in whole microsteps."""
        return round(mm * self.microsteps_per_mm)

    def move_abs_mm(self, mm: float) -> Reply:
        """Starts a move to `mm` (returns at once; see wait_idle). An absolute move is
        idempotent, so a lost reply is retried; a relative one never is."""
        return self.command(f"move abs {self.to_microsteps(mm)}", retries=2)

    def move_rel_mm(self, mm: float) -> Reply:
        """Starts a move by `mm` (returns at once; see wait_idle)."""
        return self.command(f"move rel {self.to_microsteps(mm)}")

    def home(self) -> Reply:
        """Starts homing (returns at once; see wait_idle)."""
        return self.command("home")

    def stop(self) -> Reply:
        """Decelerates to a stop."""
        return self.command("stop", retries=2)

    def clear_warnings(self) -> list[str]:
        """Clears the clearable warning flags; returns the flags that were set."""
        reply = self.command("warnings clear", retries=2)
        return reply.data.split()[1:]

    def check(self, reply: Reply, during: str) -> Reply:
        """`reply` when its warning flag allows work to go on; ZaberFault for a fault flag or a
        lost reference (WR) `during` a move."""
        flag = reply.warning
        if flag.startswith("F") or (flag == "WR" and during != "homing"):
            raise ZaberFault(f"{self.name} device {self.device} axis {self.axis} reports {flag} "
                             f"({WARNING_FLAGS.get(flag, 'see the protocol manual')}) during "
                             f"{during}", flag)
        return reply

    def wait_idle(self, timeout_s: float, during: str = "a move") -> Reply:
        """Polls status until IDLE (checking the warning flag each time); ZaberTimeout when the
        axis is still BUSY after `timeout_s`: a BUSY asked for after the deadline (one asked
        before it and read late, on a loaded host, says nothing about the device then)."""
        deadline = self.clock() + timeout_s
        while True:
            expired = self.clock() >= deadline
            reply = self.check(self.status(), during)
            if not reply.busy:
                return reply
            if expired:
                raise ZaberTimeout(f"{self.name} device {self.device} axis {self.axis} still "
                                   f"BUSY after {timeout_s:g} s during {during}")
            time.sleep(self.poll_s)

    def ensure_homed(self, timeout_s: float = 60.0) -> bool:
        """Homes the axis when it has no reference position (WR); True when it homed."""
        if self.status().warning != "WR":
            return False
        self.home()
        self.wait_idle(timeout_s, during="homing")
        if self.status().warning == "WR":
            raise ZaberFault(f"{self.name} device {self.device} axis {self.axis} still has no "
                             f"reference position after homing", "WR")
        return True

"""A one-axis Zaber ASCII device on a pseudo-terminal, with faults.

    python -m incipient_slip.devices.zaber_emulator      # prints the port to open

It reads command lines on the pty and answers as a Zaber device does: the message id echoed
(two digits, or as a plain number with `pad_ids=False`),
the command's checksum verified, replies with a checksum when `comm.checksum` is 1, BUSY for a
move's duration (first-order: constant speed `maxspeed`) then IDLE, moves beyond limit.min /
limit.max rejected with BADDATA, unknown commands with BADCOMMAND, the WR flag until the axis
is homed, alerts (`!01 1 IDLE --`) after a move when `comm.alert` is 1. It reports what it is
as a device does: `get deviceid` and `get system.axiscount` on axis 0 (device scope; on axis 1
RJ DEVICEONLY), `get peripheralid` (0: an integrated stage), `get resolution` (microsteps per
full step, 64 unless given) and `get limit.min` / `get limit.max` on the axis. The device id is
a parameter (default 50000, no particular product): real ids name products in Zaber's device
database.

Faults, for the next n lines it would send (`inject(fault, n)`): `no_reply`, `garble` (noise
in place of the reply), `bad_checksum`; and events: `reset()` (as a power cycle: the move
stops, the position is lost, WR until homed), `stall_at(mm)` (the next move stops there with
FS, "stalled and stopped", until `warnings clear`). Not verified against a real device: that a
command with a wrong checksum is dropped without a reply (this emulator drops it).
"""
from __future__ import annotations

import argparse
import os
import select
import sys
import threading
import time
import tty
from collections import Counter, deque

from incipient_slip.devices.emulator import ThreadedEmulator
from incipient_slip.devices.zaber import checksum, message_id_of

__all__ = ["ZaberEmulator", "main", "DEFAULT_MICROSTEPS_PER_MM"]

DEFAULT_MICROSTEPS_PER_MM = 1000.0 / 0.047625   # X-LSM microstep 0.047625 um
FAULTS = ("no_reply", "garble", "bad_checksum")


class ZaberEmulator(ThreadedEmulator):
    """A Zaber device (`device`, one axis) behind a pty; `port` is the path to open."""

    THREAD_NAME = "zaber-emulator"

    def __init__(self, *, device: int = 1, microsteps_per_mm: float = DEFAULT_MICROSTEPS_PER_MM,
                 limit_min_mm: float = 0.0, limit_max_mm: float = 50.0, speed_mm_s: float = 5.0,
                 homed: bool = False, reply_checksums: bool = False, alerts: bool = False,
                 pad_ids: bool = True, device_id: int = 50000, resolution: int = 64,
                 clock=time.monotonic):
        self.device = device
        self.device_id, self.resolution = device_id, resolution
        self.microsteps_per_mm = microsteps_per_mm
        self.limit_min = round(limit_min_mm * microsteps_per_mm)
        self.limit_max = round(limit_max_mm * microsteps_per_mm)
        self.maxspeed = max(1, round(speed_mm_s * microsteps_per_mm))     # microsteps/s
        self.homed = homed
        self.reply_checksums, self.alerts = reply_checksums, alerts
        self.pad_ids = pad_ids          # False: the id echoed without a leading zero (`5`)
        self.clock = clock
        self.stats: Counter = Counter()
        self.commands: list[str] = []
        self.warnings: set[str] = set()
        self._lock = threading.RLock()
        self._faults: deque = deque()
        self._stall_at: int | None = None
        self._pos = 0.0
        self._move: tuple | None = None     # (start_pos, target, t_start, duration)
        self._buf = b""
        self._master = self._slave = None
        super().__init__()
        self.port = ""

    # --- control ---

    def _open(self) -> None:
        """Opens the pty (raw, no echo); the thread serves it."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)

    def _close(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None

    def inject(self, fault: str, n: int = 1) -> None:
        """The next n lines it sends suffer `fault` (no_reply, garble, bad_checksum)."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; one of {', '.join(FAULTS)}")
        with self._lock:
            self._faults.extend([fault] * n)

    def stall_at(self, mm: float) -> None:
        """The next move that passes `mm` stops there with the FS fault flag."""
        with self._lock:
            self._stall_at = round(mm * self.microsteps_per_mm)

    def reset(self) -> None:
        """As a power cycle: motion stops, the position is lost (0), WR until homed."""
        with self._lock:
            self._move = None
            self._pos = 0.0
            self.homed = False
            self.warnings.clear()
            self.stats["resets"] += 1

    @property
    def position_mm(self) -> float:
        with self._lock:
            self._advance()
            return self._pos / self.microsteps_per_mm

    # --- the device ---

    def _serve(self) -> None:
        while not self._stop.is_set():
            readable, _, _ = select.select([self._master], [], [], 0.02)
            with self._lock:
                self._advance()
            if not readable:
                continue
            try:
                chunk = os.read(self._master, 4096)
            except OSError:
                return
            self._buf += chunk
            while True:
                cut = min((i for i in (self._buf.find(b"\n"), self._buf.find(b"\r")) if i >= 0),
                          default=-1)
                if cut < 0:
                    break
                line, self._buf = self._buf[:cut], self._buf[cut + 1:]
                if line:
                    with self._lock:
                        self._on_line(line.decode("ascii", "replace"))

    def _advance(self) -> None:
        """Moves the axis along its current move to now; ends it (or stalls it) when due."""
        if self._move is None:
            return
        start, target, t0, duration = self._move
        frac = 1.0 if duration <= 0 else min(1.0, (self.clock() - t0) / duration)
        pos = start + (target - start) * frac
        stall = self._stall_at
        if stall is not None and min(start, target) <= stall <= max(start, target) and (
                (target >= start and pos >= stall) or (target < start and pos <= stall)):
            self._pos, self._move, self._stall_at = float(stall), None, None
            self.warnings.add("FS")
            self.stats["stalls"] += 1
            self._alert()
            return
        self._pos = pos
        if frac >= 1.0:
            self._pos, self._move = float(target), None
            self._alert()

    def _alert(self) -> None:
        if self.alerts:
            self._send(f"!{self.device:02d} 1 IDLE {self._flag()}")

    def _flag(self) -> str:
        flags = set(self.warnings) | ({"WR"} if not self.homed else set())
        for flag in ("FS", "WR"):        # highest priority first
            if flag in flags:
                return flag
        return min(flags) if flags else "--"

    def _on_line(self, line: str) -> None:
        self.stats["lines"] += 1
        if not line.startswith("/"):
            self.stats["ignored"] += 1
            return
        body = line[1:].strip()
        if len(body) >= 3 and body[-3] == ":":
            body, cc = body[:-3], body[-2:]
            if checksum(body) != cc.upper():
                self.stats["bad_command_checksums"] += 1
                return
        words = body.split()
        device = int(words[0]) if words and words[0].isdigit() else 0
        if device not in (0, self.device):
            return
        axis = int(words[1]) if len(words) > 1 and words[1].isdigit() else 0
        rest = words[2:] if len(words) > 1 and words[1].isdigit() else words[1:]
        message_id = message_id_of(rest[0]) if rest else None
        if message_id is not None:
            rest = rest[1:]
        command = " ".join(rest)
        self.commands.append(command)
        flag, data = self._execute(rest, axis)
        mid = "" if message_id is None else f" {message_id:02d}" if self.pad_ids else f" {message_id}"
        head = f"@{self.device:02d} {axis}{mid}"
        self._send(f"{head} {flag} {'BUSY' if self._move else 'IDLE'} {self._flag()} {data}")

    def _execute(self, words: list[str], axis: int) -> tuple[str, str]:
        """(OK|RJ, data) of one command."""
        if axis not in (0, 1):
            return "RJ", "BADAXIS"
        if not words:
            return "OK", "0"
        cmd = " ".join(words[:2])
        try:
            if cmd in ("move abs", "move rel") and len(words) == 3:
                value = int(words[2])
                target = value if words[1] == "abs" else round(self._pos) + value
                if not self.limit_min <= target <= self.limit_max:
                    return "RJ", "BADDATA"
                self._start_move(target)
                return "OK", "0"
            if cmd == "get pos" and len(words) == 2:
                return "OK", str(round(self._pos))
            if cmd in ("get deviceid", "get system.axiscount") and len(words) == 2:
                if axis != 0:
                    return "RJ", "DEVICEONLY"
                return "OK", str(self.device_id if cmd == "get deviceid" else 1)
            if cmd in ("get limit.max", "get limit.min", "get maxspeed", "get resolution",
                       "get peripheralid") and len(words) == 2:
                return "OK", str({"get limit.max": self.limit_max, "get limit.min": self.limit_min,
                                  "get maxspeed": self.maxspeed, "get resolution": self.resolution,
                                  "get peripheralid": 0}[cmd])
            if cmd == "set maxspeed" and len(words) == 3:
                value = int(words[2])
                if value <= 0:
                    return "RJ", "BADDATA"
                self.maxspeed = value
                return "OK", "0"
            if cmd in ("set comm.alert", "set comm.checksum") and len(words) == 3:
                if words[2] not in ("0", "1"):
                    return "RJ", "BADDATA"
                setattr(self, "alerts" if cmd.endswith("alert") else "reply_checksums", words[2] == "1")
                return "OK", "0"
        except ValueError:
            return "RJ", "BADDATA"
        if words == ["home"]:
            self._start_move(self.limit_min, homing=True)
            return "OK", "0"
        if words == ["stop"]:
            self._move = None
            return "OK", "0"
        if words in (["warnings"], ["warnings", "clear"]):
            flags = sorted(set(self.warnings) | ({"WR"} if not self.homed else set()))
            if words[-1] == "clear":
                self.warnings.clear()
            return "OK", " ".join([f"{len(flags):02d}"] + flags)
        if words == ["system", "reset"]:
            self.reset()
            return "OK", "0"
        return "RJ", "BADCOMMAND"

    def _start_move(self, target: int, homing: bool = False) -> None:
        distance = abs(target - self._pos)
        self._move = (self._pos, target, self.clock(), distance / self.maxspeed)
        if homing:
            self.homed = True
            self.warnings.discard("FS")

    def _send(self, text: str) -> None:
        fault = self._faults.popleft() if self._faults else None
        if fault == "no_reply":
            self.stats["faults:no_reply"] += 1
            return
        if fault == "garble":
            self.stats["faults:garble"] += 1
            text = text[:3] + "\x07\x1b" + text[7:]
        line = text
        if self.reply_checksums or fault == "bad_checksum":
            cc = checksum(text[1:])
            if fault == "bad_checksum":
                self.stats["faults:bad_checksum"] += 1
                cc = f"{(int(cc, 16) + 1) & 0xFF:02X}"
            line = f"{text}:{cc}"
        self.stats["sent"] += 1
        try:
            os.write(self._master, (line + "\r\n").encode("ascii", "replace"))
        except OSError:
            self.stats["write_errors"] += 1


def main(argv=None) -> int:
    """Serves an emulated Zaber stage on a pty until Ctrl-C; prints the port path."""
    parser = argparse.ArgumentParser(prog="python -m incipient_slip.devices.zaber_emulator",
                                     description="An emulated one-axis Zaber ASCII stage on a pty.")
    parser.add_argument("--homed", action="store_true", help="start homed (no WR flag)")
    parser.add_argument("--speed-mm-s", type=float, default=5.0, help="move speed (default 5 mm/s)")
    parser.add_argument("--link", default="", help="also make this path a symlink to the port")
    args = parser.parse_args(argv)
    emulator = ZaberEmulator(homed=args.homed, speed_mm_s=args.speed_mm_s).start()
    if args.link:
        if os.path.lexists(args.link):
            os.unlink(args.link)
        os.symlink(emulator.port, args.link)
    print(emulator.port, flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        return 0
    finally:
        emulator.stop()
        if args.link and os.path.islink(args.link):
            os.unlink(args.link)


if __name__ == "__main__":
    sys.exit(main())

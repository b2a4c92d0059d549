"""A BioTac and its USB bridge, emulated at the byte level, behind a pty; values from the rig physics.

    python -m incipient_slip.devices.biotac_emulator --link /tmp/biotac [--lockstep]
        [--faults parity_flip@50,crc@80,unplug@300] [--seed 0 --material pla --normal-force-kpa 3]

Three layers, each speaking what the real part speaks:

* `BiotacSpiSlave`: one sensor on the SPI bus. It answers a sampling command with the channel's
  12-bit value (odd parity in both bytes), property reads byte by byte, `E-` (insufficient
  sampling delay) when a read follows the command by less than 50 µs of simulated time, `EX` for
  a channel it does not have, `EE` when the command byte fails its parity, `E?` for commands it
  does not know. An absent sensor leaves MISO high (0xFF bytes).
* `EmulatedBridge`: the firmware (firmware/biotac_bridge) in Python: the 44-slot schedule at
  4.4 kHz of simulated time, frames packed by `devices.biotac.pack_data_frame`, faults injected.
* `PtyBridgeServer`: the USB-CDC port. A pty whose slave is reachable through a stable symlink
  (like /dev/serial/by-id), host commands `S`, `X`, `?`; "real time" writes a frame every 10 ms
  of wall time and drops frames the host does not take (as the firmware does; frames this
  process sends late, when it was not given the CPU in time, are caught up, never dropped: the
  hardware it stands in for is never starved), "lock-step"
  writes the next frame as soon as the pty has taken the last one, so its buffer back-pressures
  the emulator and nothing is dropped (device time is simulated time).
  Unplug closes the pty (the host's reads fail with EIO) and replugs a new one after a delay.

`FakeCheetah` is the same sensors behind a fake of Total Phase's `cheetah_py` (the queue and
batch calls the Cheetah backend uses), for the reader's optional Cheetah backend.

`RigSignals` steps the simulator's rig (`sim.Rig`) one 500 ms period at a time and serves its
raw counts, so the emulated sensor feels the simulated contact. Every frame's served values are
kept (`--served FILE` writes them as JSON lines) so tests can check the reader's output exactly.
"""
from __future__ import annotations

import argparse
import errno
import fcntl
import json
import os
import select
import signal
import struct
import sys
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from incipient_slip.devices import biotac as bt
from incipient_slip.devices.emulator import ThreadedEmulator
from incipient_slip.messages import PAC_RATE_HZ, SLOW_RATE_HZ

FAULT_KINDS = ("parity_flip", "error_word", "crc", "drop", "repeat", "counter_jump", "missing", "unplug")
COUNTER_JUMP = 1000      # frames a "counter_jump" fault adds to the bridge's counter


# --- signals ------------------------------------------------------------------------------

class PeriodSignals:
    """12-bit channel values at a time of the sensor's clock, read from simulated periods.

    P_AC sample i (2200 Hz) and slow frame f (100 Hz) are taken from the period that holds them
    (`period(k)`, a `sim.rig.PeriodOutput`, given by the subclass). P_AC counts are offset by the
    units' `pac_zero_counts` (the sensor's AC-coupled mid-scale) and clipped to 12 bits.
    """

    DEFAULTS = {"PDC": 2000, "TAC": 2047, "TDC": 2400, "HAL": 0, "ELECTRODE": 3000}
    zero: int
    n_pac: int
    n_slow: int

    def period(self, k: int):
        raise NotImplementedError

    def sample(self, channel: str, t_ns: int) -> int:
        """Return the channel's 12-bit value at t_ns of the sensor's clock."""
        if channel == "PAC":
            i = t_ns * PAC_RATE_HZ // 1_000_000_000
            out = self.period(i // self.n_pac)
            if out.pac_counts is None:
                return self.zero
            return int(min(4095, max(0, int(out.pac_counts[i % self.n_pac]) + self.zero)))
        f = t_ns * SLOW_RATE_HZ // 1_000_000_000
        out = self.period(f // self.n_slow)
        row = f % self.n_slow
        if channel.startswith("E"):
            e = out.electrode_counts
            return int(e[row, int(channel[1:]) - 1]) if e is not None else self.DEFAULTS["ELECTRODE"]
        series = {"PDC": out.pdc_counts, "TAC": out.tac_counts, "TDC": out.tdc_counts}.get(channel)
        return int(series[row]) if series is not None else self.DEFAULTS[channel]


class RigSignals(PeriodSignals):
    """The channels of a simulated rig of its own: periods are simulated in order as time reaches
    them, at a constant normal force with the actuator stepping each period (set
    `normal_force_kpa` to change it)."""

    def __init__(self, scene: str = "paper", material: str = "", seed: int = 0,
                 normal_force_kpa: float = 3.0, units: bt.BiotacUnits = bt.BiotacUnits()):
        from incipient_slip.sim.rig import Rig, load_scene
        loaded = load_scene(scene)
        self.rig = Rig(loaded, material or loaded.materials[0], seed)
        self.normal_force_kpa = normal_force_kpa
        self.zero = units.pac_zero_counts
        self.n_pac, self.n_slow = self.rig.n_pac, self.rig.n_slow
        self.last_period = -1
        self.out = None

    def period(self, k: int):
        if k < self.last_period:
            raise ValueError(f"period {k} is in the past (the rig is at period {self.last_period})")
        while self.last_period < k:
            self.out = self.rig.step_period(self.normal_force_kpa)
            self.last_period += 1
        return self.out


# --- the sensor ---------------------------------------------------------------------------

SAMPLED = {name for name in bt.CHANNELS if name != "REV"}


class BiotacSpiSlave:
    """One BioTac as the SPI bus sees it: commands in, parity-protected replies out."""

    def __init__(self, signals, serial: str = "BT-EMU-0001", firmware: str = "0216",
                 flex: str = "3.1", cpu_speed: int = 16000, present: bool = True):
        self.signals = signals
        self.present = present
        self.props = {bt.PROPERTIES["serial_number"]: serial.encode() + b"\0",
                      bt.PROPERTIES["firmware_version"]: firmware.encode() + b"\0",
                      bt.PROPERTIES["flex_version"]: flex.encode() + b"\0",
                      bt.PROPERTIES["cpu_speed"]: cpu_speed.to_bytes(2, "big")}
        self.sampled: int | None = None      # the value of the last sampling command
        self.history: list[int] | None = None    # a list: every sampled value is appended (tests)
        self._word: bytes | None = None      # the reply waiting to be clocked out
        self._ready_ns = 0
        self._last_word: bytes | None = None
        self._prop = b""
        self._shifting = b""                 # the rest of a word being clocked out byte by byte

    @staticmethod
    def _error(name: str) -> bytes:
        return bt.ERROR_WORD_OF[name].to_bytes(2, "big")

    def command(self, cmd: int, arg: int, t_ns: int) -> None:
        """Takes a two-byte command shifted in at t_ns."""
        if not self.present:
            return
        self._prop = b""
        self._shifting = b""
        self.sampled = None
        self._ready_ns = t_ns + bt.AFTER_COMMAND_DELAY_NS
        if not bt.ODD_PARITY[cmd]:
            self._word = self._error("parity_error")
        elif cmd == bt.READ_PROPERTY:
            self._word = None
            self._prop = self.props.get(arg, b"")
            if arg not in self.props:
                self._word = self._error("unknown_command")
        elif cmd == bt.RESEND:
            self._word = self._last_word or self._error("nothing_to_resend")
        elif cmd & 0x80:
            name = bt.CHANNEL_OF_INDEX.get(bt.channel_of_command(cmd))
            if name in SAMPLED:
                self.sampled = self.signals.sample(name, t_ns)
                if self.history is not None:
                    self.history.append(self.sampled)
                self._word = bt.encode_word(self.sampled)
            else:
                self._word = self._error("channel_not_recognized")
        else:
            self._word = self._error("unknown_command")

    def read_word(self, t_ns: int) -> bytes:
        """Returns the two bytes clocked out at t_ns."""
        if not self.present:
            return b"\xff\xff"
        word, self._word = self._word, None
        if word is None:
            return b"\x00\x00"           # nothing pending: MISO low (fails parity); not verified
        if t_ns < self._ready_ns:
            return self._error("insufficient_sampling_delay")
        self._last_word = word
        return word

    def read_spi_byte(self, t_ns: int) -> int:
        """Returns one byte clocked out at t_ns: of the pending word, else of a property read."""
        if not self.present:
            return 0xFF
        if not self._shifting and self._word is not None and not self._prop:
            self._shifting = self.read_word(t_ns)
        if self._shifting:
            byte, self._shifting = self._shifting[0], self._shifting[1:]
            return byte
        return self.read_property_byte(t_ns)

    def read_property_byte(self, t_ns: int) -> int:
        """Returns the next byte of a property read (0x00 past its end, 0xFF when absent)."""
        if not self.present:
            return 0xFF
        if not self._prop:
            return 0x00
        byte, self._prop = self._prop[0], self._prop[1:]
        return byte


# --- the bridge -----------------------------------------------------------------------------

@dataclass
class FaultPlan:
    """Faults by frame counter (`at`), plus random data faults at `rate` per frame (seeded)."""

    at: dict[int, list[str]] = field(default_factory=dict)
    rate: float = 0.0
    seed: int = 0

    @classmethod
    def parse(cls, text: str, rate: float = 0.0, seed: int = 0) -> "FaultPlan":
        """The plan of "kind@frame,kind@frame" (kinds: FAULT_KINDS); ValueError names a bad item."""
        at: dict[int, list[str]] = {}
        for item in filter(None, (s.strip() for s in text.split(","))):
            kind, _, frame = item.partition("@")
            if kind not in FAULT_KINDS or not frame.isdigit():
                raise ValueError(f"fault {item!r} is not KIND@FRAME with KIND one of {', '.join(FAULT_KINDS)}")
            at.setdefault(int(frame), []).append(kind)
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"fault rate must be in [0, 1], got {rate}")
        return cls(at, rate, seed)


class EmulatedBridge:
    """The bridge firmware: runs the 44-slot schedule on its sensors, packs and faults frames.

    Fault effects (a fault at counter c acts on that frame; the slot hit is c mod 44, sensor 0):
    parity_flip flips bit 0 of the reply's second byte on the wire; error_word reads that slot
    10 µs after its command, so the sensor itself answers "E-"; crc corrupts the CRC; drop loses
    the frame (the counter advances); repeat sends it twice; counter_jump adds 1000 to the
    counter from then on; missing removes sensor 0 from the bus; unplug is the server's.
    """

    def __init__(self, slaves: list[BiotacSpiSlave], faults: FaultPlan | None = None):
        if not 1 <= len(slaves) <= bt.MAX_BIOTACS:
            raise ValueError(f"a bridge holds 1..{bt.MAX_BIOTACS} sensors, got {len(slaves)}")
        self.slaves = slaves
        self.faults = faults or FaultPlan()
        self.rng = np.random.default_rng(self.faults.seed)
        self.counter = 0
        self.boot_ns = 0          # sensor time at the bridge's boot (device time counts from it)
        self.t_ns = 0             # sensor time of the next frame
        self.served: list[dict] = []   # sensor 0's values per frame, as sampled
        self.faults_done: list[tuple[int, str]] = []
        self._status = bt.STATUS_STARTED

    def reboot(self) -> None:
        """A power cycle (unplug): the device clock restarts; the sensors' world goes on."""
        self.boot_ns = self.t_ns
        self.counter = 0

    def start(self) -> None:
        self._status |= bt.STATUS_STARTED

    def note_tx_dropped(self) -> None:
        self._status |= bt.STATUS_TX_DROPPED

    def property_frames(self) -> bytes:
        """Reads every sensor's properties as the firmware does; returns the property frames."""
        out = bytearray()
        t = self.t_ns
        for j, slave in enumerate(self.slaves):
            for name in bt.BRIDGE_PROPERTIES:
                pid = bt.PROPERTIES[name]
                slave.command(bt.READ_PROPERTY, pid, t)
                t += bt.AFTER_COMMAND_DELAY_NS
                if name == "cpu_speed":
                    data = bytes(slave.read_property_byte(t) for _ in range(2))
                else:
                    data = bytearray()
                    while len(data) < bt.PROPERTY_MAX_BYTES:
                        byte = slave.read_property_byte(t)
                        t += bt.INTERWORD_DELAY_NS
                        if byte in (0x00, 0xFF):
                            break
                        data.append(byte)
                out += bt.pack_property_frame(j, pid, bytes(data))
        return bytes(out)

    def next_frame(self) -> list[bytes]:
        """Samples one 10 ms frame; returns what goes on the wire (0, 1 or 2 frames)."""
        kinds = list(self.faults.at.get(self.counter, ()))
        if self.faults.rate and self.rng.random() < self.faults.rate:
            kinds.append(str(self.rng.choice(FAULT_KINDS[:6])))
        for kind in kinds:
            self.faults_done.append((self.counter, kind))
        if "missing" in kinds:
            self.slaves[0].present = False
        if "counter_jump" in kinds:
            self.counter += COUNTER_JUMP
        hit = self.counter % bt.SLOTS_PER_FRAME
        n = len(self.slaves)
        replies = bytearray(bt.SLOTS_PER_FRAME * 2 * n)
        served = np.zeros(bt.SLOTS_PER_FRAME, dtype=np.int32)
        start = self.t_ns
        for slot, cmd in enumerate(bt.FRAME_SCHEDULE):
            t = start + bt.slot_offset_ns(slot)
            for slave in self.slaves:
                slave.command(cmd, 0x00, t)
            served[slot] = -1 if self.slaves[0].sampled is None else self.slaves[0].sampled
            read_t = t + (10_000 if ("error_word" in kinds and slot == hit) else bt.AFTER_COMMAND_DELAY_NS)
            for j, slave in enumerate(self.slaves):
                word = slave.read_word(read_t + j * bt.INTERWORD_DELAY_NS)
                replies[(slot * n + j) * 2:(slot * n + j) * 2 + 2] = word
        if "parity_flip" in kinds:
            replies[hit * n * 2 + 1] ^= 0x01
        device_us = (start - self.boot_ns) // 1000
        frame = bytearray(bt.pack_data_frame(self.counter, device_us, bytes(replies), n, status=self._status))
        self.served.append({"counter": self.counter, "device_time_us": device_us & 0xFFFFFFFF,
                            "pac": served[bt.PAC_SLOTS].tolist(),
                            "electrodes": served[bt.ELECTRODE_SLOTS].tolist(),
                            "pdc": int(served[bt.PDC_SLOT]), "tac": int(served[bt.TAC_SLOT]),
                            "tdc": int(served[bt.TDC_SLOT]), "faults": kinds})
        self._status = 0
        self.counter = (self.counter + 1) & 0xFFFFFFFF
        self.t_ns = start + bt.FRAME_US * 1000
        if "crc" in kinds:
            frame[-1] ^= 0xFF
        if "drop" in kinds:
            return []
        if "repeat" in kinds:
            return [bytes(frame), bytes(frame)]
        return [bytes(frame)]

    def unplug_due(self) -> bool:
        """True when an unplug fault is planned at the next frame's counter."""
        return "unplug" in self.faults.at.get(self.counter, ())


# --- the USB port -------------------------------------------------------------------------------

class PtyBridgeServer(ThreadedEmulator):
    """Serves an EmulatedBridge on a pty reachable at `link` (a symlink to the pty's slave)."""

    # Bytes unread by the host beyond which frames are dropped (real time), as the firmware drops
    # what USB cannot take. 4095 is also the most the pty's line discipline reports unread.
    BACKLOG_BYTES = 4095
    # Frames sent late (this process starved) are held up to this much (about 6 s of frames)
    LATE_BACKLOG_BYTES = 64 * 1024
    THREAD_NAME = "biotac-emulator"
    JOIN_TIMEOUT_S = 5.0

    def __init__(self, bridge: EmulatedBridge, link: str | Path, lockstep: bool = False,
                 replug_after_s: float = 1.0, served_path: str | Path | None = None,
                 max_frames: int = 0, frames_per_s: float = bt.FRAME_RATE_HZ):
        self.bridge, self.link, self.lockstep = bridge, Path(link), lockstep
        self.replug_after_s = replug_after_s
        self.max_frames = max_frames     # frames to stream in all (0: no limit), then stay idle
        self.frame_period_s = 1.0 / frames_per_s   # real time; faster than 100/s for benchmarks
        self.served_file = open(served_path, "w") if served_path else None
        self.streaming = False
        self.unplugs = 0
        self.tx_dropped = 0      # frames dropped because the host did not read (real time)
        self.error: Exception | None = None
        super().__init__()
        self._master = self._slave = -1
        self._out = bytearray()
        self._catching_up = False
        self._idle_since: float | None = None     # when the last stream stopped (real time)
        self.ready = threading.Event()

    def plug(self) -> None:
        """Creates the pty (raw mode) and points the link at it."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        tmp = self.link.with_name(self.link.name + ".new")
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(os.ttyname(self._slave))
        os.replace(tmp, self.link)
        self.streaming = False
        self._out.clear()

    def unplug(self) -> None:
        """Removes the link and closes the pty: the host's next read fails with EIO."""
        self._close_pty()
        self.unplugs += 1

    def _close_pty(self) -> None:
        if self.link.is_symlink():
            self.link.unlink()
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    def _open(self) -> None:
        self.plug()

    def start(self) -> "PtyBridgeServer":
        """Plugs in and serves on a thread; returns self once it serves (or failed: `error`)."""
        super().start()
        self.ready.wait(5.0)
        return self

    def _close(self) -> None:
        if self._master >= 0:
            self._close_pty()
        if self.served_file:
            self.served_file.close()

    def _host_commands(self, data: bytes) -> None:
        for c in data:
            if c == ord("S") and not self.streaming:
                self.streaming = True
                self.bridge.start()
                self._next_due = time.monotonic()
                if not self.lockstep and self._idle_since is not None:
                    # the sensor's world and the bridge's clock went on while nothing streamed:
                    # the first frame is sampled now, not where the last stream stopped (a host
                    # that reconnected saw the contact as it was when it left, seconds late)
                    idle = int((self._next_due - self._idle_since) / self.frame_period_s)
                    self.bridge.t_ns += idle * bt.FRAME_US * 1000
            elif c in (ord("X"), ord("?")):
                if self.streaming:
                    self._idle_since = time.monotonic()
                self.streaming = False
                if c == ord("?"):
                    self._out += self.bridge.property_frames()

    def _flush(self) -> None:
        while self._out:
            try:
                n = os.write(self._master, self._out)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno in (errno.EIO, errno.EAGAIN):
                    return
                raise
            del self._out[:n]

    def _unread(self) -> int:
        """Bytes written to the port that the host has not read yet."""
        return struct.unpack("i", fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0"))[0]

    def _serve(self) -> None:
        try:
            self.serve()
        except Exception as exc:      # the CLI reports it and exits 1 instead of going silent
            self.error = exc
            self.ready.set()

    def serve(self) -> None:
        """Runs until stop(): host commands, frames on schedule, faults, unplug/replug."""
        self._next_due = time.monotonic()
        self.ready.set()
        while not self._stop.is_set():
            now = time.monotonic()
            if self.streaming and not self.lockstep:
                wait = max(0.0, self._next_due - now)
            elif self.streaming and not self._out:
                wait = 0.0
            else:
                wait = 0.05
            want_write = [self._master] if self._out else []
            readable, _, _ = select.select([self._master], want_write, [], wait)
            if readable:
                try:
                    self._host_commands(os.read(self._master, 256))
                except OSError as exc:
                    if exc.errno != errno.EIO:     # EIO: no process has the port open
                        raise
                    time.sleep(0.01)
            self._flush()
            if not self.streaming or (self.max_frames and len(self.bridge.served) >= self.max_frames):
                continue
            if self.lockstep:
                if self._out:
                    continue
            elif time.monotonic() < self._next_due:
                continue
            if self.bridge.unplug_due():
                self.bridge.faults.at[self.bridge.counter].remove("unplug")
                self.bridge.faults_done.append((self.bridge.counter, "unplug"))
                self.unplug()
                if self._stop.wait(self.replug_after_s):
                    return
                self.bridge.reboot()
                self.plug()
                continue
            frames = self.bridge.next_frame()
            if self.served_file:
                self.served_file.write(json.dumps(self.bridge.served[-1]) + "\n")
                self.served_file.flush()
            if not self.lockstep:
                # a frame due a period or more ago is late because this process was not run
                # (real hardware never is): the burst that catches up goes out and the pty holds
                # it until the host has read it down to the firmware's buffer; only then are
                # frames dropped for a host that does not read, as the firmware drops them
                backlog = len(self._out) + self._unread()
                if time.monotonic() - self._next_due > self.frame_period_s:
                    self._catching_up = True
                elif backlog < self.BACKLOG_BYTES:
                    self._catching_up = False
                self._next_due += self.frame_period_s
                if backlog >= (self.LATE_BACKLOG_BYTES if self._catching_up else self.BACKLOG_BYTES):
                    self.bridge.note_tx_dropped()   # the host is not reading: drop, as the firmware does
                    self.tx_dropped += 1
                    continue
            for frame in frames:
                self._out += frame
            self._flush()


def build(args) -> PtyBridgeServer:
    """The server described by parsed command-line arguments (also used by tests)."""
    units = bt.load_units(args.units)
    slaves = []
    for j in range(args.n_biotacs):
        signals = RigSignals(args.scene, args.material, args.seed + j, args.normal_force_kpa, units)
        present = not (j == 0 and args.missing_sensor)
        slaves.append(BiotacSpiSlave(signals, serial=f"BT-EMU-{j + 1:04d}", present=present))
    faults = FaultPlan.parse(args.faults, args.fault_rate, args.seed)
    return PtyBridgeServer(EmulatedBridge(slaves, faults), args.link, lockstep=args.lockstep,
                           replug_after_s=args.replug_after_s, served_path=args.served,
                           max_frames=args.frames)


def make_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m incipient_slip.devices.biotac_emulator",
                                description="An emulated BioTac bridge on a pty (see docs/hardware.md).")
    p.add_argument("--link", required=True, help="path of the symlink to the pty (the reader's port:=)")
    p.add_argument("--lockstep", action="store_true",
                   help="write frames as fast as the port takes them, none dropped "
                        "(default: real time, 100 frames/s)")
    p.add_argument("--faults", default="", help=f"KIND@FRAME,... with KIND in {', '.join(FAULT_KINDS)}")
    p.add_argument("--fault-rate", type=float, default=0.0, help="random data faults per frame, 0..1")
    p.add_argument("--missing-sensor", action="store_true", help="no BioTac on the bus (serial reads 0xFF)")
    p.add_argument("--n-biotacs", type=int, default=1, choices=range(1, bt.MAX_BIOTACS + 1))
    p.add_argument("--scene", default="paper", help="simulator scene (default: paper)")
    p.add_argument("--material", default="", help="object material (default: the scene's first)")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated rig and of random faults")
    p.add_argument("--normal-force-kpa", type=float, default=3.0, help="constant F_N of the simulated contact")
    p.add_argument("--units", default="", help="units YAML (pac_zero_counts offsets P_AC)")
    p.add_argument("--replug-after-s", type=float, default=1.0, help="seconds an unplug lasts")
    p.add_argument("--frames", type=int, default=0, help="stream this many frames, then stay silent (0: forever)")
    p.add_argument("--served", default=None, help="write the values served per frame as JSON lines")
    return p


def main(argv: list[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    try:
        server = build(args)
    except ValueError as exc:
        print(f"biotac_emulator: {exc}", file=sys.stderr)
        return 2
    server.start()
    signal.signal(signal.SIGTERM, lambda *_: server._stop.set())
    print(f"biotac emulator: bridge on {args.link} ({'lock-step' if args.lockstep else 'real time'})",
          flush=True)
    try:
        while server._thread.is_alive():
            server._thread.join(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    if server.error is not None:
        print(f"biotac_emulator: stopped by {type(server.error).__name__}: {server.error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())


# --- a fake `cheetah_py` ------------------------------------------------------------------------

class FakeCheetah:
    """The subset of Total Phase's `cheetah_py` the Cheetah backend uses, on emulated sensors.

    Install it as the module (`sys.modules["cheetah_py"] = FakeCheetah(slaves)`). Queued
    operations run on simulated time: bytes take 8 bits at the set bitrate, delays their length;
    bytes shifted while one or more sensors are selected go to each of them, and a sensor turns
    the bytes of one selection into a command (first byte non-zero) or a read (zeros). With
    `realtime`, a collected batch is returned no earlier than its simulated end on the wall clock.
    """

    CH_SPI_BITORDER_MSB = 0
    CH_TARGET_POWER_ON = 0x03
    CH_PORT_NOT_FREE = 0x8000

    def __init__(self, slaves: list[BiotacSpiSlave], realtime: bool = False, n_adapters: int = 1):
        self.slaves, self.realtime, self.n_adapters = slaves, realtime, n_adapters
        self.t_ns = 0
        self.bitrate_khz = 1000
        self.queue: list[tuple] = []
        self.submitted: list[list[tuple]] = []
        self.open_handles: set[int] = set()
        self.unplugged = False
        self._t0_wall = None

    # device and configuration ------------------------------------------------------------
    def ch_find_devices_ext(self, devices, unique_ids):
        n = 0 if self.unplugged else self.n_adapters
        ports = [i | (self.CH_PORT_NOT_FREE if i + 1 in self.open_handles else 0) for i in range(n)]
        return n, ports, [1000 + i for i in range(n)]

    def ch_open(self, port):
        if self.unplugged or not 0 <= port < self.n_adapters:
            return -1
        self.open_handles.add(port + 1)
        return port + 1

    def ch_close(self, handle):
        self.open_handles.discard(handle)
        return 0

    def ch_status_string(self, status):
        return {-1: "CH_UNABLE_TO_OPEN"}.get(status, f"status {status}")

    def ch_spi_configure(self, handle, polarity, phase, bitorder, ss_polarity):
        return 0

    def ch_target_power(self, handle, mode):
        return mode

    def ch_sleep_ms(self, ms):
        return ms

    def ch_spi_bitrate(self, handle, khz):
        self.bitrate_khz = khz
        return khz

    # the queue ---------------------------------------------------------------------------
    def ch_spi_queue_clear(self, handle):
        self.queue = []
        return 0

    def ch_spi_queue_oe(self, handle, enable):
        return 0

    def ch_spi_queue_ss(self, handle, mask):
        self.queue.append(("ss", mask))
        return 0

    def ch_spi_queue_byte(self, handle, count, value):
        self.queue.extend([("byte", value)] * count)
        return count

    def ch_spi_queue_delay_ns(self, handle, ns):
        self.queue.append(("delay", int(ns)))
        return ns

    def ch_spi_batch_length(self, handle):
        return sum(1 for op in self.queue if op[0] == "byte")

    def ch_spi_batch_shift(self, handle, num_bytes):
        self._check(handle)
        data = self._run(self.queue)
        return len(data), array_of(data[:num_bytes] if num_bytes else b"")

    def ch_spi_async_submit(self, handle):
        self._check(handle)
        self.submitted.append(list(self.queue))
        return 0

    def ch_spi_async_collect(self, handle, num_bytes):
        self._check(handle)
        if not self.submitted:
            return -1, array_of(b"")
        data = self._run(self.submitted.pop(0))
        if self.realtime:
            if self._t0_wall is None:
                self._t0_wall = time.monotonic() - self.t_ns / 1e9
            delay = self._t0_wall + self.t_ns / 1e9 - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        return min(len(data), num_bytes), array_of(data[:num_bytes])

    def _check(self, handle):
        if self.unplugged or handle not in self.open_handles:
            raise OSError("Cheetah adapter not connected")

    def _run(self, ops) -> bytes:
        """Executes queued operations on the sensors; returns the MISO bytes."""
        miso = bytearray()
        selected: list[int] = []
        mosi: list[int] = []
        byte_ns = 8_000_000 // self.bitrate_khz
        for kind, value in ops:
            if kind == "delay":
                self.t_ns += value
            elif kind == "byte":
                self.t_ns += byte_ns
                mosi.append(value)
                if len(selected) == 1 and not (mosi and mosi[0]):
                    slave = self.slaves[selected[0]]
                    miso.append(slave.read_spi_byte(self.t_ns))
                else:
                    miso.append(0xFF if not selected else 0x00)
            else:   # chip selects change: the selection that ends takes its bytes as a command
                if mosi and mosi[0] and len(mosi) >= 2:
                    for j in selected:
                        self.slaves[j].command(mosi[0], mosi[1], self.t_ns)
                selected = [j for j in range(len(self.slaves)) if value >> j & 1]
                mosi = []
                self.t_ns += byte_ns
        return bytes(miso)


def array_of(data: bytes):
    from array import array
    return array("B", data)

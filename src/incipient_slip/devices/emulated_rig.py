"""The emulated rig: every device emulator around ONE simulated contact (`sim.Rig`), in real time.

    python -m incipient_slip.nodes.emulated_rig dir:=/tmp/emu robot_address:=127.0.0.3

A stand-in for the physical world of the paper's rig. The real device nodes talk to it through
the devices' own protocols, exactly as on the lab's rig:

* the BioTac and its bridge on a pty (`biotac_emulator`), `<dir>/biotac`;
* the Zaber stage on a pty (`zaber_emulator`), `<dir>/zaber`;
* Motive's NatNet server on 127.0.0.1 (`natnet_emulator`), rigid body 1, the rail along y;
* the UR controller on a loopback address (`fake_ur`), ports 29999 / 30003 / 30004;
* the PZT amplifier's input: the WAV file that `pzt_injector backend:=file` writes, `<dir>/pzt.wav`.

`SharedContact` owns the `sim.Rig` and steps it one 500 ms period at a time as wall time (from
the contact's start) reaches the period; the inputs of a period are read once, at its start:

* the actuator position = the stage's position less `start_mm` (the rail spring's end);
* the normal force F_N from the UR's TCP: the depth d the TCP has moved along the pressing axis
  since its start pose (where the finger just touches the object, so the BioTac's start-up tare
  sees no contact) gives F_N by Hertz with the simulator's E* and R,
  F = 4/3 E* sqrt(R) d^(3/2) (sphere on sphere, `sim.contact`), divided by the scene's
  `newton_per_kpa`. (The simulator's contact radius is Hertz at small loads and saturates at
  larger ones; it defines no indentation, so the press law stays Hertz: an assumption.) With
  the paper scene's soft skin (E* = 0.053 MPa, R = 6.7 mm) 2.9 kPa is a 3.4 mm press and the
  contact stiffness there is 1.27 kPa/mm: the `ur5` node's press loop needs a gain near
  1 / 1.27 = 0.8 mm/kPa to settle within a few periods (the emulated launch sets it);
* the PZT: the RMS of the last `pzt_window_s` of the injector's WAV switches the injection on
  (above `pzt_on_rms`) at I = 20 log10(RMS / rated_rms) dB, or off.

Its outputs feed the emulators: the BioTac serves the period's P_AC, electrodes, P_DC and
temperatures (`ContactSignals`, the sensor's clock mapped onto the contact's), the NatNet
server streams the object's pose at the mocap sample of the current time. `truth` keeps each
period's inputs and state (F_N applied, actuator, travel, stick ratio) for tests and logs.
The rig's calibration can be hidden in it (`newton_per_kpa`, `spring_n_per_mm`: the scene's
values replaced) and `instruments()` reads the reference instruments `slip calibrate` asks the
operator for, so that a test can check that the calibration recovers the hidden values.
Not emulated: lock-step (the devices run in real time only) and the P_AC path from the PZT's
waveform itself (the simulator's own noise source is scaled to the measured intensity).
"""
from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from incipient_slip.devices import biotac as bt
from incipient_slip.devices.biotac_emulator import PeriodSignals
from incipient_slip.sim.rig import PeriodOutput, Rig, load_scene
from incipient_slip.sim.scene import with_values

KEEP_PERIODS = 40          # periods kept for a sensor clock running behind (20 s)
NATNET_BODY_ID = 1
OBJECT_START_M = (0.0, 0.0, 0.0)    # the body at zero travel: Motive's origin set there, as in the lab


@dataclass(frozen=True)
class HertzPress:
    """F_N (kPa) from the finger's press depth (mm), by the simulator's own Hertz contact."""

    radius_mm: float
    e_star_mpa: float
    newton_per_kpa: float

    @classmethod
    def of(cls, rig: Rig) -> "HertzPress":
        return cls(rig.radius_mm, rig.e_star, float(rig.p["contact"]["newton_per_kpa"]))

    def normal_force_kpa(self, depth_mm: float) -> float:
        """Return F_N in kPa at press depth d mm (0 for d <= 0: not touching)."""
        if not depth_mm > 0.0:
            return 0.0
        force_n = 4.0 / 3.0 * self.e_star_mpa * math.sqrt(self.radius_mm) * depth_mm ** 1.5
        return force_n / self.newton_per_kpa

    def depth_mm(self, normal_force_kpa: float) -> float:
        """Return the press depth in mm that gives F_N kPa (the inverse of normal_force_kpa)."""
        force_n = max(normal_force_kpa, 0.0) * self.newton_per_kpa
        return (3.0 * force_n / (4.0 * self.e_star_mpa * math.sqrt(self.radius_mm))) ** (2.0 / 3.0)


@dataclass(frozen=True)
class PeriodTruth:
    """One period of the shared contact: its inputs and the physical state at its end."""

    period: int
    normal_force_kpa: float
    actuator_mm: float
    depth_mm: float
    pzt_on: bool
    pzt_intensity_db: float
    object_y_mm: float
    stick_area_ratio: float
    gross_slip: bool


def wav_rms(path: str | Path, window_s: float) -> float | None:
    """Return the RMS (full scale = 1) of the last `window_s` of a growing 16-bit mono WAV.

    None while the file does not exist or holds no complete sample yet. The header is the
    44 bytes `wave` writes; its sizes are not trusted (they are patched only at close).
    """
    try:
        with open(path, "rb") as f:
            head = f.read(44)
            if len(head) < 44 or head[:4] != b"RIFF":
                return None
            fs = int.from_bytes(head[24:28], "little")
            size = os.fstat(f.fileno()).st_size - 44
            n = min(size // 2, max(1, int(window_s * fs)))
            if n <= 0:
                return None
            f.seek(44 + (size // 2 - n) * 2)
            pcm = np.frombuffer(f.read(2 * n), dtype="<i2")
    except FileNotFoundError:
        return None
    if pcm.size == 0:
        return None
    return float(np.sqrt(np.mean((pcm / 32767.0) ** 2)))


class SharedContact:
    """The one simulated contact every emulator reads and writes; steps in real time.
    `overrides` ({(section, key): value}) replaces scene params (the hidden calibration:
    the finger's newton_per_kpa, the rail's spring; `sim.scene.with_values`)."""

    def __init__(self, scene: str = "paper", material: str = "", seed: int = 0, *,
                 actuator_mm=lambda: 0.0, depth_mm=lambda: 0.0, pzt_rms=lambda: None,
                 rated_rms: float = 0.25, pzt_on_rms: float = 1e-4, clock=time.monotonic,
                 overrides: dict | None = None):
        loaded = with_values(load_scene(scene), overrides or {})
        self.rig = Rig(loaded, material or loaded.materials[0], seed)
        self.press = HertzPress.of(self.rig)
        self.period_s = self.rig.period_s
        self.actuator_mm, self.depth_mm, self.pzt_rms = actuator_mm, depth_mm, pzt_rms
        self.rated_rms, self.pzt_on_rms = rated_rms, pzt_on_rms
        self.clock = clock
        self.t0: float | None = None
        self.outputs: dict[int, PeriodOutput] = {}
        self.truth: list[PeriodTruth] = []
        self._lock = threading.RLock()

    def start(self) -> None:
        """Time 0 of the contact: period k spans [k T, (k+1) T) of wall time from now."""
        with self._lock:
            if self.t0 is None:
                self.t0 = self.clock()

    def now_ns(self) -> int:
        self.start()
        return int((self.clock() - self.t0) * 1e9)

    def period(self, k: int) -> PeriodOutput:
        """Return period k's output, stepping the rig up to it (inputs read at each step)."""
        with self._lock:
            while len(self.truth) <= k:
                self._step()
            if k not in self.outputs:
                raise ValueError(f"period {k} is no longer kept (the contact is at period "
                                 f"{len(self.truth) - 1}; a reader {KEEP_PERIODS} periods behind)")
            return self.outputs[k]

    def _step(self) -> None:
        rig = self.rig
        rig.state.actuator_mm = float(self.actuator_mm())
        depth = float(self.depth_mm())
        force = self.press.normal_force_kpa(depth)
        if rig.scene.has("injection"):
            rms = self.pzt_rms()
            if rms is not None:
                on = rms > self.pzt_on_rms
                rig.set_injection(on, 20.0 * math.log10(rms / self.rated_rms) if on else None)
        out = rig.step_period(force, actuator_step=False)
        k = out.period
        self.outputs[k] = out
        self.outputs.pop(k - KEEP_PERIODS, None)
        self.truth.append(PeriodTruth(k, force, out.actuator_mm, depth, out.pzt_on, out.pzt_intensity_db,
                                      out.object_y_mm, out.stick_area_ratio, out.gross_slip))

    def object_y_mm(self, t_ns: int) -> float:
        """Return the measured travel (mocap, 120 Hz) at contact time t_ns."""
        k = t_ns // int(self.period_s * 1e9)
        out = self.period(k)
        if out.mocap_y_mm is None:
            return out.object_y_mm
        j = int((t_ns - k * self.period_s * 1e9) * len(out.mocap_y_mm) / (self.period_s * 1e9))
        return float(out.mocap_y_mm[min(j, len(out.mocap_y_mm) - 1)])


class ContactSignals(PeriodSignals):
    """The BioTac's 12-bit channels from the shared contact.

    The sensor's clock (time since the bridge's first sample) is mapped onto the contact's once,
    at the first sample, so a reader that starts late still feels the present contact.
    """

    def __init__(self, shared: SharedContact, units: bt.BiotacUnits = bt.BiotacUnits()):
        self.shared = shared
        self.zero = units.pac_zero_counts
        self.n_pac, self.n_slow = shared.rig.n_pac, shared.rig.n_slow
        self.offset_ns: int | None = None

    def period(self, k: int):
        return self.shared.period(k)

    def sample(self, channel: str, t_ns: int) -> int:
        """Return the channel's 12-bit value at t_ns of the sensor's clock."""
        if self.offset_ns is None:
            self.offset_ns = self.shared.now_ns() - t_ns
        return super().sample(channel, t_ns + self.offset_ns)


class EmulatedRig:
    """The emulators of every device around one SharedContact; `start()`, `tick()`, `stop()`."""

    def __init__(self, directory: str | Path, *, scene: str = "paper", material: str = "", seed: int = 0,
                 robot_address: str = "127.0.0.3", natnet_command_port: int = 41510,
                 natnet_data_port: int = 41511, natnet_version=(4, 1),
                 start_mm: float = 0.0, speed_mm_s: float = 5.0, press_axis: int = 2,
                 press_sign: float = 1.0, rated_rms: float = 0.25, pzt_window_s: float = 0.1,
                 newton_per_kpa: float | None = None, spring_n_per_mm: float | None = None):
        from incipient_slip.devices.biotac_emulator import BiotacSpiSlave, EmulatedBridge, PtyBridgeServer
        from incipient_slip.devices.fake_ur import FakeURController
        from incipient_slip.devices.natnet_emulator import NatNetEmulator
        from incipient_slip.devices.zaber_emulator import ZaberEmulator

        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.biotac_link, self.zaber_link = self.dir / "biotac", self.dir / "zaber"
        self.pzt_path = self.dir / "pzt.wav"
        if self.pzt_path.exists():       # a previous run's sink: not this run's PZT
            self.pzt_path.unlink()
        self.start_mm, self.press_axis, self.press_sign = start_mm, press_axis, press_sign
        self.zaber = ZaberEmulator(speed_mm_s=speed_mm_s)
        self.ur = FakeURController(robot_address)
        self.tcp_start = list(self.ur.tcp_pose)
        self.natnet = NatNetEmulator(natnet_version, address="127.0.0.1", command_port=natnet_command_port,
                                     data_port=natnet_data_port, body_id=NATNET_BODY_ID)
        hidden = {("contact", "newton_per_kpa"): newton_per_kpa, ("stick_slip", "spring_n_per_mm"): spring_n_per_mm}
        self.shared = SharedContact(
            scene, material, seed, actuator_mm=lambda: self.zaber.position_mm - self.start_mm,
            depth_mm=self.depth_mm, pzt_rms=lambda: wav_rms(self.pzt_path, pzt_window_s),
            rated_rms=rated_rms, overrides={k: float(v) for k, v in hidden.items() if v is not None})
        slave = BiotacSpiSlave(ContactSignals(self.shared), serial="BT-EMU-0001")
        self.biotac = PtyBridgeServer(EmulatedBridge([slave]), self.biotac_link)

    def depth_mm(self) -> float:
        """The TCP's press depth since its start pose, mm (positive: pressing)."""
        a = self.press_axis
        return self.press_sign * (self.tcp_start[a] - self.ur.tcp_pose[a]) * 1000.0

    def instruments(self) -> dict:
        """What the lab's reference instruments of `slip calibrate` would read now, N: a scale
        under the finger (the normal force of the present press depth: the object stands in for
        the scale) and a force gauge holding the object's end of the spring at the rail's zero
        (the spring's force at the stage's pull from start_mm)."""
        p = self.shared.rig.p
        depth = self.depth_mm()
        return {"scale_n": self.shared.press.normal_force_kpa(depth) * self.shared.press.newton_per_kpa,
                "spring_gauge_n": max(self.zaber.position_mm - self.start_mm, 0.0)
                * float(p["stick_slip"]["spring_n_per_mm"])}

    def start(self) -> "EmulatedRig":
        """Starts every emulator (OSError when an address or port is taken) and the contact's clock."""
        self.ur.start()
        self.natnet.start()
        self.zaber.start()
        tmp = self.zaber_link.with_name(self.zaber_link.name + ".new")
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(self.zaber.port)
        os.replace(tmp, self.zaber_link)
        self.biotac.start()
        self.shared.start()
        self.tick()
        return self

    def tick(self) -> None:
        """Steps the contact to the present and sets the NatNet body's pose (call > 120 Hz)."""
        y_mm = self.shared.object_y_mm(self.shared.now_ns())
        x, y, z = OBJECT_START_M
        self.natnet.set_pose((x, y + y_mm / 1000.0, z))

    def error(self) -> Exception | None:
        """The BioTac server's error, if its thread ended on one."""
        return self.biotac.error

    def stop(self) -> None:
        for part in (self.biotac, self.zaber, self.natnet, self.ur):
            part.stop()
        if self.zaber_link.is_symlink():
            self.zaber_link.unlink()

"""pzt_injector: band-limited white noise into the PZT on /pzt/command; publishes /pzt/state.

    python -m incipient_slip.nodes.pzt_injector backend:=sounddevice [device:=hw:1]
    python -m incipient_slip.nodes.pzt_injector backend:=file path:=runs/pzt.wav   (dry run)

The signal is `devices.pzt.Injector`'s: Gaussian noise through a 10–1100 Hz band-pass with
carried filter state, RMS `rated_rms * 10**(I/20)` (0 dB = the amplifier's rated input), hard
clip at `clip_level`, a `ramp_s` ramp on every start, stop and intensity change. The sound card
pulls blocks itself; the file and none backends are paced by the monotonic clock (`Pacer`),
which counts underflows when the node falls behind. When no other node's heartbeat (nor a
command) has arrived for `heartbeat_timeout_s`, the output ramps to zero and stays off until
the next command. On shutdown it ramps to zero before closing the output.
"""
from __future__ import annotations

import os
import time

import numpy as np

from incipient_slip.devices import pzt
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.messages import Heartbeat, PztCommand, PztOutput, PztState


class PztInjector(Node):
    """Drives the PZT with band-limited noise; reports its state and output health."""

    PARAMS = {
        "backend": Param("sounddevice", choices=pzt.BACKENDS, help="sound card, WAV file (dry run) or none"),
        "device": Param("", help="sounddevice output device (name or index; '' = default)"),
        "path": Param("pzt.wav", help="WAV file of the file backend"),
        "sample_rate_hz": Param(48000, lo=4000, hi=192000, help="output sample rate, Hz"),
        "block_s": Param(0.01, lo=0.001, hi=0.1, help="block length, s"),
        "band_low_hz": Param(10.0, lo=1.0, hi=1000.0, help="band-pass lower edge, Hz (paper: 10)"),
        "band_high_hz": Param(1100.0, lo=100.0, hi=20000.0, help="band-pass upper edge, Hz (paper: 1100)"),
        "filter_order": Param(6, lo=1, hi=10, help="Butterworth order of each band edge (6: 36 dB per octave)"),
        "rated_rms": Param(0.25, lo=0.0, hi=1.0, help="output RMS at 0 dB (the amplifier's rated input), full scale = 1"),
        "clip_level": Param(1.0, lo=0.01, hi=1.0, help="hard clip, output full-scale units"),
        "ramp_s": Param(0.03, lo=0.02, hi=0.05, help="ramp on start, stop and intensity change, s"),
        "enabled": Param(False, help="noise on at start"),
        "intensity_db": Param(0.0, lo=-120.0, hi=20.0, help="intensity I at start, dB"),
        # liveness: every node beats once a second, so 3 s is three missed beats of every other
        # node (the graph is gone), not one late beat on a loaded host
        "heartbeat_timeout_s": Param(3.0, lo=0.0, hi=60.0, help="no other node's heartbeat this long: the graph is gone, ramp to zero (0 = off)"),
        "state_period_s": Param(0.1, lo=0.01, hi=10.0, help="period of /pzt/state and /pzt/output, s"),
        "seed": Param(0, lo=0, help="seed of the noise"),
    }
    INPUTS = {"/pzt/command": PztCommand, "/heartbeat": Heartbeat}
    OPTIONAL_INPUTS = frozenset({"/pzt/command"})      # the launch sets the injection; a command may switch it
    OUTPUTS = {"/pzt/state": PztState, "/pzt/output": PztOutput, "/heartbeat": Heartbeat}

    def __init__(self, **kwargs):
        super().__init__("pzt_injector", **kwargs)
        fs = self.param("sample_rate_hz")
        self.block = max(1, int(round(self.param("block_s") * fs)))
        try:
            self.injector = pzt.Injector(fs, (self.param("band_low_hz"), self.param("band_high_hz")),
                                         self.param("filter_order"), self.param("rated_rms"),
                                         self.param("clip_level"), self.param("ramp_s"), self.param("seed"))
            backend = self.param("backend")
            if backend == "sounddevice":
                self.output = pzt.SoundDeviceBackend(self.injector, fs, self.block, self.param("device"))
            else:
                self.output = pzt.FileBackend(self.param("path"), fs) if backend == "file" else pzt.NullBackend()
        except (ValueError, RuntimeError, OSError) as exc:
            raise ParamError(f"node {self.name!r}: {exc}") from None
        self.pacer = pzt.Pacer(fs, self.block)
        self.injector.set(self.param("enabled"), self.param("intensity_db"))
        self.last_alive = time.monotonic()
        self.state_pub = self.create_publisher(PztState)
        self.output_pub = self.create_publisher(PztOutput)
        self.create_subscription(PztCommand, self.on_command)
        self.create_subscription(Heartbeat, self.on_heartbeat)
        if not self.output.pulls:
            self.create_timer(self.param("block_s") / 2, self.pump)
        self.create_timer(self.param("state_period_s"), self.publish_state)
        self.on_shutdown(self.ramp_down_and_close)

    def on_command(self, msg: PztCommand) -> None:
        self.last_alive = time.monotonic()
        self.injector.set(msg.enabled, msg.intensity_db)
        self.publish_state()

    def on_heartbeat(self, msg: Heartbeat) -> None:
        if msg.node != self.name or msg.pid != os.getpid():
            self.last_alive = time.monotonic()

    def pump(self) -> None:
        silent, noisy = self.pacer.blocks_due(time.monotonic())
        if silent:
            self.warn(f"output underflow: {silent} blocks of silence (the node fell behind)", throttle_s=1.0)
            self.output.write(np.zeros(silent * self.block, dtype=np.float32))
        for _ in range(noisy):
            self.output.write(self.injector.block(self.block))

    def publish_state(self) -> None:
        timeout = self.param("heartbeat_timeout_s")
        if timeout and self.injector.enabled and time.monotonic() - self.last_alive > timeout:
            self.warn(f"no heartbeat from the graph for {timeout:g} s: ramping the PZT to zero")
            self.injector.set(False, self.injector.intensity_db)
        self.state_pub.publish(PztState(enabled=self.injector.enabled, intensity_db=self.injector.intensity_db,
                                        band_low_hz=self.injector.band_hz[0], band_high_hz=self.injector.band_hz[1]))
        underflows = getattr(self.output, "underflows", self.pacer.underflows)
        self.output_pub.publish(PztOutput(backend=self.output.name, output_rms=self.injector.gain,
                                          underflows=underflows, clipped_samples=self.injector.clipped_samples))

    def ramp_down_and_close(self) -> None:
        self.injector.set(False, self.injector.intensity_db)
        if self.output.pulls:
            time.sleep(self.param("ramp_s") + 2 * self.param("block_s"))
        else:
            while self.injector.ramping:
                self.output.write(self.injector.block(self.block))
            self.output.write(self.injector.block(self.block))
        self.output.close()


def main(argv=None):
    return run_node(PztInjector, argv)


if __name__ == "__main__":
    raise SystemExit(main())

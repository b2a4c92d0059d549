"""biotac_reader: the BioTac through its USB bridge, published as /biotac/pac and /biotac/slow.

    python -m incipient_slip.nodes.biotac_reader port:=/dev/ttyACM0 [sensor:=0] [units:=lab.yaml]
    python -m incipient_slip.nodes.biotac_reader backend:=cheetah [n_biotacs:=3]   (Total Phase Cheetah)

Opens the bridge (firmware/biotac_bridge, docs/hardware.md) with pyserial, or a Cheetah SPI
adapter when `backend:=cheetah` and Total Phase's `cheetah_py` is installed; checks that a BioTac
is present (serial number starts with "BT"), then publishes each 10 ms frame: `/biotac/pac` (22
P_AC samples, counts about the units' zero) and `/biotac/slow` (E1..E19, P_DC, T_AC, T_DC).
Stamps are the bridge's device clock, anchored once per connection to the host's wall clock:
P_AC at its last sample, the slow channels at the frame's start. `seq` is the frame index of
device time, so a frame that was lost or refused is a seq gap for every subscriber.

Every fault is counted and published on `/biotac/status` (per channel for parity failures and
error words): a word that fails refuses its stream for that frame, never replaced by an older
value. A tare (3 s untouched mean and variance; touch = P_DC above mean + 50 sd for 5 frames)
runs at start (`tare_on_start`) and on each `/biotac/tare` request. An unplugged or silent
bridge is reopened with back-off; every state change is logged.
"""
from __future__ import annotations

import time

import numpy as np

from incipient_slip.devices import biotac as bt
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.messages import BiotacPac, BiotacSlow, BiotacStatus, BiotacTare, Heartbeat


class BiotacReader(Node):
    """Reads one BioTac through the bridge; publishes its frames and its fault counters."""

    PARAMS = {
        "backend": Param("bridge", choices=("bridge", "cheetah"),
                         help="USB bridge on a serial port, or a Total Phase Cheetah (needs cheetah_py)"),
        "port": Param("", help="serial port of the bridge (e.g. /dev/ttyACM0 or an emulator's link)"),
        "quiet_start_s": Param(5.0, lo=0.0, hi=600.0, help="a port that cannot be opened before the first "
                               "connection within this is one info line, not a warning per back-off"),
        "n_biotacs": Param(1, lo=1, hi=bt.MAX_BIOTACS, help="sensors on the Cheetah's bus (cheetah backend)"),
        "cheetah_port": Param(-1, lo=-1, hi=127, help="Cheetah adapter port (-1: the first free one)"),
        "sensor": Param(0, lo=0, hi=bt.MAX_BIOTACS - 1, help="which sensor of the bridge (chip select 0..4)"),
        "units": Param("", help="YAML file overriding the BioTac units (docs/hardware.md)"),
        "tare_on_start": Param(True, help="tare once streaming starts (keep the finger untouched)"),
        "tare_s": Param(3.0, lo=0.1, hi=60.0, help="tare duration, s"),
        "status_period_s": Param(0.5, lo=0.01, hi=60.0, help="period of /biotac/status, s"),
        "poll_s": Param(0.005, lo=0.001, hi=0.05, help="how often the port is read, s"),
        "max_backoff_s": Param(5.0, lo=0.1, hi=60.0, help="longest wait between reconnection attempts, s"),
        "stall_timeout_s": Param(1.0, lo=0.05, hi=60.0, help="no data this long while streaming: reconnect"),
        "wait_subscribers": Param(0, lo=0, hi=100, help="open the bridge only once this many subscribers "
                                  "read /biotac/pac (recordings and tests lose no first frame)"),
    }
    INPUTS = {"/biotac/tare": BiotacTare}
    OPTIONAL_INPUTS = frozenset({"/biotac/tare"})      # an operator's re-tare (`slip topic pub`), not the launch's
    # /heartbeat: the runtime's own publisher, refused by the INPUTS/OUTPUTS check unless declared
    OUTPUTS = {"/biotac/pac": BiotacPac, "/biotac/slow": BiotacSlow, "/biotac/status": BiotacStatus,
               "/heartbeat": Heartbeat}

    def __init__(self, **kwargs):
        super().__init__("biotac_reader", **kwargs)
        try:
            self.units = bt.load_units(self.param("units"))
        except ValueError as exc:
            raise ParamError(f"node {self.name!r}: parameter units: {exc}") from None
        self.link = self.make_link()
        self.tare = bt.Tare(frames=int(round(self.param("tare_s") * bt.FRAME_RATE_HZ)))
        self.pac_pub = self.create_publisher(BiotacPac)
        self.slow_pub = self.create_publisher(BiotacSlow)
        self.status_pub = self.create_publisher(BiotacStatus)
        self.create_subscription(BiotacTare, self.on_tare)
        self.create_timer(self.param("poll_s"), self.poll)
        self.create_timer(self.param("status_period_s"), self.publish_status)
        self.on_shutdown(self.link.close)
        self.anchor_ns = 0
        self.seq_base = 0
        self.last_seq = -1
        self.connection = 0
        self.tare_state = "none"
        self.waiting = self.param("wait_subscribers") > 0
        self.started = time.monotonic()
        self.said_waiting = False

    def make_link(self):
        """The bridge link, or the Cheetah link (same interface); ParamError if it cannot be made."""
        backoff, stall = self.param("max_backoff_s"), self.param("stall_timeout_s")
        if self.param("backend") == "bridge":
            if not self.param("port"):
                raise ParamError(f"node {self.name!r}: parameter port is required (the bridge's serial port)")
            return bt.BridgeLink(self.param("port"), self.param("sensor"), max_backoff_s=backoff,
                                 stall_timeout_s=stall)
        from incipient_slip.devices.biotac_cheetah import CheetahLink
        try:
            return CheetahLink(self.param("sensor"), self.param("n_biotacs"), self.param("cheetah_port"),
                               max_backoff_s=backoff, stall_timeout_s=stall)
        except (RuntimeError, ValueError) as exc:
            raise ParamError(f"node {self.name!r}: {exc}") from None

    def _quiet_start(self) -> bool:
        """Whether a port that cannot be opened is still part of the start: no connection yet,
        and less than quiet_start_s since ours (an emulated rig started beside us opens its ports
        a moment after; a wrong port on the real rig is warned about, every attempt, after that)."""
        return self.link.connections == 0 and time.monotonic() - self.started < self.param("quiet_start_s")

    def on_tare(self, msg: BiotacTare) -> None:
        self.tare.frames = int(round(msg.duration_s * bt.FRAME_RATE_HZ))
        self.tare.start()
        self.log(f"tare requested: keep the finger untouched for {msg.duration_s:g} s")

    def poll(self) -> None:
        if self.waiting:
            if self.pac_pub.subscriber_count() < self.param("wait_subscribers"):
                return
            self.waiting = False
        state = self.link.state
        readings = self.link.poll()
        for level, text in self.link.events:
            if level == "absent" and self._quiet_start():
                if not self.said_waiting:       # one line, not one warning per back-off
                    self.said_waiting = True
                    self.log(f"waiting up to {self.param('quiet_start_s'):g} s for the port to appear ({text})")
                continue
            self.log(text) if level == "info" else self.warn(text)
        self.link.events.clear()
        if self.link.connections != self.connection:     # a new connection: re-anchor the clock
            self.connection = self.link.connections
            self.anchor_ns = time.time_ns()
            # after a reconnection one seq is left out, so subscribers see the discontinuity
            self.seq_base = 0 if self.last_seq < 0 else self.last_seq + 2
            if self.param("tare_on_start") and self.tare.state == "none":
                self.tare.start()
        for r in readings:
            self.publish_reading(r)
        if self.link.state != state:
            self.publish_status()
        if self.tare.state != self.tare_state:
            self.tare_state = self.tare.state
            if self.tare.state in ("done", "refused"):
                (self.log if self.tare.state == "done" else self.warn)(f"tare {self.tare.state}: {self.tare.detail}")
            self.publish_status()

    def publish_reading(self, r: bt.Reading) -> None:
        seq = self.last_seq = self.seq_base + r.frame_index
        stamp = self.anchor_ns + r.device_time_ns
        if r.pac is not None:
            pac = (r.pac.astype(np.int16) - np.int16(self.units.pac_zero_counts))
            self.pac_pub.publish(BiotacPac(pac_counts=pac, pa_per_count=self.units.pac_pa_per_count,
                                           stamp_ns=stamp + bt.PAC_LAST_SLOT_NS, seq=seq), keep_seq=True)
        if r.electrodes is not None:
            self.tare.add(r.pdc, r.electrodes)
            self.slow_pub.publish(BiotacSlow(
                electrode_counts=r.electrodes, pdc_counts=r.pdc, tac_counts=r.tac, tdc_counts=r.tdc,
                pdc_pa_per_count=self.units.pdc_pa_per_count, pdc_tare_counts=self.tare.pdc_tare_counts,
                stamp_ns=stamp, seq=seq), keep_seq=True)

    def publish_status(self) -> None:
        c, props = self.link.stream.counters, self.link.properties
        self.status_pub.publish(BiotacStatus(
            state=self.link.state, port=self.link.port,
            serial_number=str(props.get("serial_number", "")),
            firmware_version=str(props.get("firmware_version", "")),
            frames_ok=c.frames_ok, frames_dropped=c.frames_dropped, frames_repeated=c.frames_repeated,
            counter_jumps=c.counter_jumps, crc_errors=c.crc_errors, header_errors=c.header_errors,
            bytes_skipped=c.bytes_skipped, pattern_mismatches=c.pattern_mismatches,
            bridge_overruns=c.bridge_overruns, bridge_tx_dropped=c.bridge_tx_dropped,
            pac_frames_refused=c.pac_frames_refused, slow_frames_refused=c.slow_frames_refused,
            reconnects=self.link.reconnects, parity_errors=c.parity_errors.astype("<u4"),
            error_words=c.error_words.astype("<u4"), error_word_kinds=c.error_word_kinds.astype("<u4"),
            last_error_word=c.last_error_word, tare_state=self.tare.state, touching=self.tare.touching,
            detail=self.tare.detail))


def main(argv=None):
    return run_node(BiotacReader, argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""The BioTac through a Total Phase Cheetah SPI adapter (optional; needs Total Phase's `cheetah_py`).

The Cheetah cannot stream on its own clock: the host queues a batch of SPI operations (selects,
bytes, delays) whose delays make the 4.4 kHz schedule, and keeps the adapter busy by submitting
batches ahead (`PIPELINE` in flight) and collecting each as it completes. The queue follows
SynTouch's C library for the Cheetah (kth-ros-pkg/biotac_driver, biotac.c): per slot, select
all, `[cmd, 0x00]`, deselect, 50 µs, then two bytes from each sensor in turn, 10 µs, and the
padding that makes the slot 1/4400 s long; properties are read as in its property reader.

Every collected frame is repacked as a bridge frame (`devices.biotac.pack_data_frame`) with the
frame index as its counter and the schedule's time (frame k at k x 10 ms) as its device time, so
`BridgeStream` checks parity and error words and counts faults exactly as for the USB bridge.
A batch the host failed to resubmit in time leaves a gap the adapter does not report: the
schedule time then runs ahead of real time, unseen (a limit of the adapter, not of this code).

`CheetahLink` has the interface of `BridgeLink` (poll, state, events, properties, stream,
reconnects, connections, close). A thread collects batches so `poll()` never blocks.
"""
from __future__ import annotations

import queue
import threading
import time
from array import array

from incipient_slip.devices import biotac as bt
from incipient_slip.devices.queues import waiting

FRAMES_PER_BATCH = 5            # 50 ms batches, as in SynTouch's library
PIPELINE = 4                    # batches submitted ahead
BITRATE_KHZ = 4400
SELECT = (0x01, 0x02, 0x04, 0x08, 0x10)


def import_cheetah():
    """Return the `cheetah_py` module; RuntimeError says how to get it when it is missing."""
    try:
        import cheetah_py
    except ImportError:
        raise RuntimeError("backend cheetah needs Total Phase's cheetah_py (from the Cheetah software "
                           "package, not PyPI's cheetah-spi) on the Python path") from None
    return cheetah_py


def slot_padding_ns(n_biotacs: int) -> int:
    """Return the delay that completes one slot to 1/4400 s after its bytes and fixed delays."""
    shift_ns = ((2 + 2 * n_biotacs) * 8 + (n_biotacs + 3) * 8) * 1_000_000 // BITRATE_KHZ
    slot_ns = 1_000_000_000 // bt.SLOT_RATE_HZ
    return max(0, slot_ns - shift_ns - bt.AFTER_COMMAND_DELAY_NS - bt.INTERWORD_DELAY_NS * n_biotacs)


class CheetahLink:
    """The sensor bus on a Cheetah adapter: properties, presence check, batches, reconnect."""

    def __init__(self, sensor: int = 0, n_biotacs: int = 1, device_port: int = -1, ch=None,
                 min_backoff_s: float = 0.2, max_backoff_s: float = 5.0, stall_timeout_s: float = 1.0,
                 clock=time.monotonic):
        if not 0 <= sensor < n_biotacs <= bt.MAX_BIOTACS:
            raise ValueError(f"sensor {sensor} must be below n_biotacs {n_biotacs} (at most {bt.MAX_BIOTACS})")
        self.ch = ch or import_cheetah()
        self.sensor, self.n = sensor, n_biotacs
        self.device_port = device_port
        self.port = f"cheetah:{device_port}" if device_port >= 0 else "cheetah"
        self.min_backoff_s, self.max_backoff_s, self.stall_timeout_s = min_backoff_s, max_backoff_s, stall_timeout_s
        self.clock = clock
        self.stream = bt.BridgeStream(sensor)
        self.state = "disconnected"
        self.events: list[tuple[str, str]] = []
        self.reconnects = 0
        self.connections = 0
        self._handle = None
        self._frames: queue.Queue = queue.Queue()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._backoff = min_backoff_s
        self._next_try = 0.0
        self._last_data = 0.0

    @property
    def properties(self) -> dict:
        return self.stream.properties

    def poll(self) -> list[bt.Reading]:
        """Return the readings collected since the last call; connects when it is time."""
        now = self.clock()
        if self.state in ("disconnected", "no_sensor"):
            if now >= self._next_try:
                self._connect(now)
            return []
        readings = []
        for item in waiting(self._frames):
            if isinstance(item, Exception):
                self._drop(f"Cheetah adapter failed ({item}); reconnecting", now)
                self.reconnects += 1
                return readings
            self._last_data = now
            readings += self.stream.feed(item)
        if now - self._last_data > self.stall_timeout_s:
            self._drop(f"no batch from the Cheetah for {self.stall_timeout_s:g} s; reconnecting", now)
            self.reconnects += 1
        return readings

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self._handle is not None:
            try:
                self.ch.ch_spi_queue_oe(self._handle, 0)
                self.ch.ch_close(self._handle)
            except Exception:
                pass
            self._handle = None

    # --- connection -----------------------------------------------------------------------

    def _connect(self, now: float) -> None:
        ch = self.ch
        try:
            handle = self._open()
        except Exception as exc:
            self._retry(f"cannot open the Cheetah adapter ({exc})", now)
            return
        self._handle = handle
        ch.ch_spi_configure(handle, 0, 0, ch.CH_SPI_BITORDER_MSB, 0x0)   # mode 0, selects active low
        ch.ch_target_power(handle, ch.CH_TARGET_POWER_ON)
        ch.ch_sleep_ms(100)
        ch.ch_spi_bitrate(handle, BITRATE_KHZ)
        ch.ch_spi_queue_clear(handle)
        ch.ch_spi_queue_oe(handle, 1)
        self.stream.restart()
        self.stream.properties.clear()
        for name in bt.BRIDGE_PROPERTIES:
            pid = bt.PROPERTIES[name]
            self.stream.properties[name] = bt.decode_property(pid, self._read_property(pid))
        serial_number = str(self.stream.properties["serial_number"])
        if not serial_number.startswith("BT"):
            self.close()
            self.state = "no_sensor"
            self._retry(f"no BioTac on sensor slot {self.sensor} of the Cheetah (serial number "
                        f"{serial_number!r} does not start with 'BT'): check the sensor's cable", now)
            return
        self._stop.clear()
        self._frames = queue.Queue()
        self._thread = threading.Thread(target=self._collect, name="cheetah", daemon=True)
        self._thread.start()
        self.state = "streaming"
        self.connections += 1
        self._last_data = now
        self._backoff = self.min_backoff_s
        self.events.append(("info", f"BioTac {serial_number} (firmware "
                                    f"{self.stream.properties['firmware_version']}) on {self.port}: streaming"))

    def _open(self):
        ch = self.ch
        port = self.device_port
        if port < 0:
            count, ports, _ = ch.ch_find_devices_ext(array("H", bytes(32)), array("I", bytes(64)))
            free = [p for p in list(ports)[:max(0, count)] if not p & ch.CH_PORT_NOT_FREE]
            if not free:
                raise RuntimeError("no free Cheetah adapter found" if count <= 0 else
                                   f"all {count} Cheetah adapters are in use")
            port = free[0]
        handle = ch.ch_open(port)
        if handle <= 0:
            raise RuntimeError(f"ch_open({port}) failed: {ch.ch_status_string(handle)}")
        return handle

    def _read_property(self, pid: int) -> bytes:
        """Reads one property of our sensor, byte by byte, as SynTouch's library does."""
        ch, h, select = self.ch, self._handle, SELECT[self.sensor]
        ch.ch_spi_queue_clear(h)
        ch.ch_spi_queue_ss(h, select)
        ch.ch_spi_queue_byte(h, 1, bt.READ_PROPERTY)
        ch.ch_spi_queue_byte(h, 1, pid)
        ch.ch_spi_queue_ss(h, 0)
        ch.ch_spi_queue_delay_ns(h, bt.AFTER_COMMAND_DELAY_NS)
        ch.ch_spi_batch_shift(h, 2)
        if pid == bt.PROPERTIES["cpu_speed"]:
            ch.ch_spi_queue_clear(h)
            ch.ch_spi_queue_ss(h, select)
            ch.ch_spi_queue_byte(h, 2, 0x00)
            ch.ch_spi_queue_ss(h, 0)
            _, data = ch.ch_spi_batch_shift(h, 2)
            return bytes(data[:2])
        out = bytearray()
        while len(out) < bt.PROPERTY_MAX_BYTES:
            ch.ch_spi_queue_clear(h)
            ch.ch_spi_queue_ss(h, select)
            ch.ch_spi_queue_byte(h, 1, 0x00)
            _, data = ch.ch_spi_batch_shift(h, 1)
            if data[0] in (0x00, 0xFF):
                break
            out.append(data[0])
        ch.ch_spi_queue_clear(h)
        ch.ch_spi_queue_ss(h, 0)
        ch.ch_spi_batch_shift(h, 0)
        return bytes(out)

    def _queue_batch(self) -> int:
        """Queues FRAMES_PER_BATCH frames of the schedule; returns the bytes a batch shifts."""
        ch, h, n = self.ch, self._handle, self.n
        padding = slot_padding_ns(n)
        ch.ch_spi_queue_clear(h)
        for _ in range(FRAMES_PER_BATCH):
            for cmd in bt.FRAME_SCHEDULE:
                ch.ch_spi_queue_ss(h, sum(SELECT[:n]))
                ch.ch_spi_queue_byte(h, 1, cmd)
                ch.ch_spi_queue_byte(h, 1, 0x00)
                ch.ch_spi_queue_ss(h, 0)
                ch.ch_spi_queue_delay_ns(h, bt.AFTER_COMMAND_DELAY_NS)
                for j in range(n):
                    ch.ch_spi_queue_ss(h, SELECT[j])
                    ch.ch_spi_queue_byte(h, 2, 0x00)
                ch.ch_spi_queue_ss(h, 0)
                ch.ch_spi_queue_delay_ns(h, bt.INTERWORD_DELAY_NS)
                ch.ch_spi_queue_delay_ns(h, padding)
        return ch.ch_spi_batch_length(h)

    def _collect(self) -> None:
        """Thread: keeps PIPELINE batches in flight, repacks each collected one as bridge frames."""
        ch, h, n = self.ch, self._handle, self.n
        try:
            length = self._queue_batch()
            for _ in range(PIPELINE):
                ch.ch_spi_async_submit(h)
            per_slot = 2 + 2 * n
            counter = 0
            while not self._stop.is_set():
                count, data = ch.ch_spi_async_collect(h, length)
                if count != length:
                    raise RuntimeError(f"collected {count} of {length} bytes "
                                       f"({ch.ch_status_string(count) if count < 0 else 'short batch'})")
                ch.ch_spi_async_submit(h)
                raw = bytes(data[:length])
                out = bytearray()
                for f in range(FRAMES_PER_BATCH):
                    replies = b"".join(raw[(f * bt.SLOTS_PER_FRAME + s) * per_slot + 2:
                                           (f * bt.SLOTS_PER_FRAME + s + 1) * per_slot]
                                       for s in range(bt.SLOTS_PER_FRAME))
                    out += bt.pack_data_frame(counter, counter * bt.FRAME_US, replies, n)
                    counter += 1
                self._frames.put(bytes(out))
        except Exception as exc:      # the adapter vanished or failed: the link reconnects
            self._frames.put(exc)

    def _drop(self, why: str, now: float) -> None:
        self.close()
        self.state = "disconnected"
        self._retry(why, now)

    def _retry(self, why: str, now: float) -> None:
        self.events.append(("warn", f"{why}; next attempt in {self._backoff:.1f} s"))
        self._next_try = now + self._backoff
        self._backoff = min(self._backoff * 2, self.max_backoff_s)

"""The message of every topic: one frozen dataclass per topic, each field with its wire kind.

Field kinds (widths, units, bounds, NaN rules) are declared with the helpers of `fields`; the
codec (`codec`) and docs/messages.md follow from these declarations.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from incipient_slip.messages.fields import Message, array, flag, integer, real, text

PERIOD_NS = 500_000_000         # the paper samples every 500 ms; messages carry its index
PAC_RATE_HZ = 2200              # BioTac P_AC
SLOW_RATE_HZ = 100              # BioTac P_DC, T_AC, T_DC and electrodes
MOCAP_RATE_HZ = 120             # motion capture of the object
PAC_SAMPLES_PER_FRAME = 22      # 2200 Hz P_AC in 10 ms frames
ELECTRODE_COUNT = 19
ADC_MAX = 4095                  # the BioTac's 12-bit ADC
STEP_LIMIT = (1 << 32) - 1      # steps and periods fit a uint32 (68 years of periods)
METHODS = ("injection", "vibrotactile", "e19", "e10", "e4", "e1", "none")
RUN_EVENT_KINDS = ("start", "step", "success", "failure", "fault", "end")
ROBOT_STATES = ("ready", "stopped", "reconnecting")
_NO_PERIOD = "-1: not tied to a period"
# The BioTac reader's per-channel fault counters follow BIOTAC_CHANNELS; its error-word counts
# follow BIOTAC_ERROR_WORDS (the sensor's 0xA5xx replies, devices/biotac.py).
BIOTAC_CHANNELS = ("PAC", "PDC", "TAC", "TDC") + tuple(f"E{i:02d}" for i in range(1, 20))
BIOTAC_ERROR_WORDS = ("parity_error", "unknown_command", "insufficient_delay", "insufficient_sampling_delay",
                      "channel_not_recognized", "nothing_to_resend", "read_only", "write_error")
BIOTAC_LINK_STATES = ("disconnected", "handshake", "no_sensor", "streaming")
TARE_STATES = ("none", "collecting", "done", "refused")
# Why an estimate is what it is (SlipEstimate.cause; the reason field says it in words):
# ok; filling (the window is not full yet: the start of every run, and after a reset); seq_gap
# (messages were lost: the window was emptied); stale (no frame for too long, or a stamp jump);
# backwards (the source's stamps went back: it restarted); no_data (no frame yet); pzt_mismatch
# (the PZT state contradicts the model); unknown (a publisher that names none).
ESTIMATE_CAUSES = ("ok", "filling", "seq_gap", "stale", "backwards", "no_data", "pzt_mismatch", "unknown")
# Why a grip command asks for its force (GripCommand.cause; the reason field says it in words):
# law (the grip law on a usable estimate); no_action (method none); schedule (a planned force:
# collection, identification); stale_estimate (a hold: no estimate in time); estimate_invalid,
# estimate_not_finite, estimate_out_of_range, estimate_other_period, estimate_other_method (a
# hold: the estimate of the period could not drive the force); unknown (a publisher that names none).
GRIP_CAUSES = ("law", "no_action", "schedule", "stale_estimate", "estimate_invalid", "estimate_not_finite",
               "estimate_out_of_range", "estimate_other_period", "estimate_other_method", "unknown")


def _counts(n: int, note: str):
    return array("<u4", (n,), note=note, default_factory=lambda: np.zeros(n, "<u4"))


@dataclass(frozen=True, eq=False)
class BiotacPac(Message):
    TOPIC: ClassVar[str] = "/biotac/pac"
    DESCRIPTION: ClassVar[str] = ("BioTac P_AC: 22 samples of one 10 ms frame at 2200 Hz, ADC counts "
                                  "about the sensor's zero (signed)")
    pac_counts: np.ndarray = array("<i2", (PAC_SAMPLES_PER_FRAME,), unit="ADC counts",
                                   note="the raw 12-bit value less pac_zero_counts (units file; "
                                        "default 2048, mid-scale)")
    pa_per_count: float = real(0.37, unit="Pa/count", low=0.0)


@dataclass(frozen=True, eq=False)
class BiotacSlow(Message):
    TOPIC: ClassVar[str] = "/biotac/slow"
    DESCRIPTION: ClassVar[str] = "BioTac slow channels at 100 Hz: P_DC, E1..E19, T_AC, T_DC (counts)"
    electrode_counts: np.ndarray = array("<u2", (ELECTRODE_COUNT,), unit="ADC counts")
    pdc_counts: int = integer("uint16", unit="ADC counts", high=ADC_MAX)
    tac_counts: int = integer("uint16", unit="ADC counts", high=ADC_MAX)
    tdc_counts: int = integer("uint16", unit="ADC counts", high=ADC_MAX)
    pdc_pa_per_count: float = real(36.5, unit="Pa/count", low=0.0)
    pdc_tare_counts: int = integer("uint16", unit="ADC counts", high=ADC_MAX)

    @property
    def pdc_kpa(self) -> float:
        """P_DC above the out-of-contact tare, in kPa (the paper's F_N)."""
        return (self.pdc_counts - self.pdc_tare_counts) * self.pdc_pa_per_count / 1000.0


@dataclass(frozen=True, eq=False)
class BiotacStatus(Message):
    TOPIC: ClassVar[str] = "/biotac/status"
    DESCRIPTION: ClassVar[str] = ("BioTac reader health: link state, sensor identity, tare, and every "
                                  "fault counted since the reader started")
    state: str = text("disconnected", choices=BIOTAC_LINK_STATES)
    port: str = text("")
    serial_number: str = text("")
    firmware_version: str = text("")
    frames_ok: int = integer("uint64")
    frames_dropped: int = integer("uint64", note="missing by device time while connected: lost on USB "
                                  "or refused (CRC, header, pattern; counted there too); not those "
                                  "missed while disconnected (unplug, stall: see reconnects)")
    frames_repeated: int = integer("uint64")
    counter_jumps: int = integer("uint64")
    crc_errors: int = integer("uint64")
    header_errors: int = integer("uint64")
    bytes_skipped: int = integer("uint64", note="bytes outside frames: garbage, and the rest of a frame "
                                 "refused for its CRC or header (its 2 sync bytes are not counted here)")
    pattern_mismatches: int = integer("uint64", note="frames of another slot schedule, refused")
    bridge_overruns: int = integer("uint64")
    bridge_tx_dropped: int = integer("uint64")
    pac_frames_refused: int = integer("uint64")
    slow_frames_refused: int = integer("uint64")
    reconnects: int = integer("uint64")
    parity_errors: np.ndarray = _counts(len(BIOTAC_CHANNELS), "per channel, BIOTAC_CHANNELS order: words "
                                        "failing parity that are not an error word")
    error_words: np.ndarray = _counts(len(BIOTAC_CHANNELS), "per channel, BIOTAC_CHANNELS order: the "
                                      "sensor's error words (0xA5xx; they fail parity too, counted only here)")
    error_word_kinds: np.ndarray = _counts(len(BIOTAC_ERROR_WORDS), "per kind, BIOTAC_ERROR_WORDS order")
    last_error_word: str = text("")
    tare_state: str = text("none", choices=TARE_STATES)
    touching: bool = flag(False)
    detail: str = text("")


@dataclass(frozen=True, eq=False)
class BiotacTare(Message):
    TOPIC: ClassVar[str] = "/biotac/tare"
    DESCRIPTION: ClassVar[str] = "Request: tare the BioTac over duration_s untouched (mean and variance)"
    duration_s: float = real(3.0, unit="s", low=0.1, high=60.0)


@dataclass(frozen=True, eq=False)
class PztCommand(Message):
    TOPIC: ClassVar[str] = "/pzt/command"
    DESCRIPTION: ClassVar[str] = "Start/stop the PZT white-noise injection at intensity I dB"
    enabled: bool = flag(True)
    intensity_db: float = real(0.0, unit="dB", low=-120.0, high=20.0)


@dataclass(frozen=True, eq=False)
class PztState(Message):
    TOPIC: ClassVar[str] = "/pzt/state"
    DESCRIPTION: ClassVar[str] = "PZT injector state: on/off, intensity, band"
    LATCHED: ClassVar[bool] = True      # sent at start and on change: a late reader gets the last one
    enabled: bool = flag(False)
    intensity_db: float = real(0.0, unit="dB", low=-120.0, high=20.0)
    band_low_hz: float = real(10.0, unit="Hz", low=0.0)
    band_high_hz: float = real(1100.0, unit="Hz", low=0.0)


@dataclass(frozen=True, eq=False)
class PztOutput(Message):
    TOPIC: ClassVar[str] = "/pzt/output"
    DESCRIPTION: ClassVar[str] = "PZT output health: backend, present RMS, underflows and clipped samples"
    backend: str = text("")
    output_rms: float = real(0.0, unit="full scale", low=0.0)
    underflows: int = integer("uint64")
    clipped_samples: int = integer("uint64")


@dataclass(frozen=True, eq=False)
class ObjectPose(Message):
    TOPIC: ClassVar[str] = "/object/pose"
    DESCRIPTION: ClassVar[str] = ("Object pose from motion capture; travel along the rail is "
                                  "position_mm[1] (the paper's y)")
    position_mm: np.ndarray = array("<f8", (3,), unit="mm")
    orientation_xyzw: np.ndarray = array("<f8", (4,), note="unit quaternion x, y, z, w")
    tracking_valid: bool = flag(True)
    body_id: int = integer("uint32", 1)

    @property
    def travel_mm(self) -> float:
        """Object travel y along the rail, mm."""
        return float(self.position_mm[1])


@dataclass(frozen=True, eq=False)
class ActuatorCommand(Message):
    TOPIC: ClassVar[str] = "/actuator/command"
    SCHEMA_VERSION: ClassVar[int] = 2      # 2: absolute position_mm and period (was a relative move_mm)
    DESCRIPTION: ClassVar[str] = ("Move the linear actuator to position_mm for the next period (identification; "
                                  "positive pulls); the applying node clamps to its own limits")
    position_mm: float = real(0.0, unit="mm", low=-50.0, high=50.0,
                              note="absolute, from the actuator's zero-load origin (start_mm)")
    period: int = integer("int64", -1, low=-1, high=STEP_LIMIT, note=_NO_PERIOD)


@dataclass(frozen=True, eq=False)
class ActuatorState(Message):
    TOPIC: ClassVar[str] = "/actuator/state"
    SCHEMA_VERSION: ClassVar[int] = 2      # 2: step_index renamed period (one name for the period index)
    DESCRIPTION: ClassVar[str] = ("Linear actuator position and the period it just ended (one step per "
                                  "period: the tick the grip controller answers)")
    position_mm: float = real(0.0, unit="mm")
    period: int = integer("uint32")
    busy: bool = flag(False)


@dataclass(frozen=True, eq=False)
class GripCommand(Message):
    TOPIC: ClassVar[str] = "/grip/command"
    SCHEMA_VERSION: ClassVar[int] = 2      # 2: cause, the closed set GRIP_CAUSES beside the reason
    DESCRIPTION: ClassVar[str] = ("Normal force target for the robot; hold=True means keep the "
                                  "last safe force (stale/invalid estimate)")
    normal_force_kpa: float = real(0.0, unit="kPa", low=0.0, high=100.0,
                                   note="P_DC range; the applying node clamps to its safety limit")
    hold: bool = flag(False)
    period: int = integer("int64", -1, low=-1, high=STEP_LIMIT, note=_NO_PERIOD)
    reason: str = text("", note="for people; code switches on cause")
    cause: str = text("unknown", choices=GRIP_CAUSES, note="why this force (holds: why the estimate could "
                      "not drive it); messages/types.py says what each means")


@dataclass(frozen=True, eq=False)
class RobotState(Message):
    TOPIC: ClassVar[str] = "/robot/state"
    SCHEMA_VERSION: ClassVar[int] = 2      # 2: emergency_stop, program_running, state, period
    DESCRIPTION: ClassVar[str] = "Robot end-effector state and the normal force it applies"
    normal_force_kpa: float = real(0.0, unit="kPa")
    tcp_z_mm: float = real(0.0, unit="mm")
    protective_stop: bool = flag(False)
    emergency_stop: bool = flag(False)
    program_running: bool = flag(True)
    state: str = text("ready", choices=ROBOT_STATES,
                      note="stopped: holds until an explicit recovery (slip robot recover)")
    period: int = integer("int64", -1, low=-1, high=STEP_LIMIT, note="-1: no command applied yet")


@dataclass(frozen=True, eq=False)
class RobotRecover(Message):
    TOPIC: ClassVar[str] = "/robot/recover"
    DESCRIPTION: ClassVar[str] = ("An operator's explicit request that the robot node recover "
                                  "from a stop (never automatic)")
    note: str = text("")


@dataclass(frozen=True, eq=False)
class SlipEstimate(Message):
    TOPIC: ClassVar[str] = "/slip/estimate"
    SCHEMA_VERSION: ClassVar[int] = 2      # 2: cause, the closed set ESTIMATE_CAUSES beside the reason
    DESCRIPTION: ClassVar[str] = ("Estimated stick ratio of one window; valid=False after a seq "
                                  "gap or stale stream, with the reason")
    stick_ratio: float = real(float("nan"), nan=True,
                              note="NaN: no number; consumers check valid and [0, 1]")
    valid: bool = flag(False)
    method: str = text("injection", choices=METHODS)
    window_end_ns: int = integer("uint64", unit="ns")
    latency_ns: int = integer("uint64", unit="ns")
    period: int = integer("int64", -1, low=-1, high=STEP_LIMIT, note=_NO_PERIOD)
    reason: str = text("", note="for people; code switches on cause")
    cause: str = text("unknown", choices=ESTIMATE_CAUSES, note="why the estimate is (in)valid; "
                      "messages/types.py says what each means")


@dataclass(frozen=True, eq=False)
class SimTruth(Message):
    TOPIC: ClassVar[str] = "/sim/truth"
    DESCRIPTION: ClassVar[str] = ("The simulated rig's physical truth at the end of one period "
                                  "(simulated rig only: no sensor measures it)")
    period: int = integer("int64", -1, low=-1, high=STEP_LIMIT, note=_NO_PERIOD)
    stick_ratio: float = real(float("nan"), nan=True,
                              note="true load ratio 1 - Q/(mu_s F_N) in [0, 1], 0 while sliding")
    stick_area_ratio: float = real(float("nan"), nan=True, note="true (c/a)^2 in [0, 1], 0 while sliding")
    tangential_force_n: float = real(float("nan"), unit="N", nan=True, note="spring force F_T")
    gross_slip: bool = flag(False)


@dataclass(frozen=True, eq=False)
class RunEvent(Message):
    TOPIC: ClassVar[str] = "/run/event"
    DESCRIPTION: ClassVar[str] = "Run lifecycle: start, step, success, failure, fault, end"
    kind: str = text("step", choices=RUN_EVENT_KINDS)
    step: int = integer("uint32")
    detail: str = text("")
    object_travel_mm: float = real(float("nan"), unit="mm", nan=True, note="NaN: unknown")
    normal_force_kpa: float = real(float("nan"), unit="kPa", nan=True, note="NaN: unknown")


@dataclass(frozen=True, eq=False)
class Heartbeat(Message):
    TOPIC: ClassVar[str] = "/heartbeat"
    DESCRIPTION: ClassVar[str] = "Node liveness with its drop and gap counters"
    node: str = text("", max_bytes=255)
    pid: int = integer("uint32")
    uptime_s: float = real(0.0, unit="s", low=0.0)
    malformed_dropped: int = integer("uint64")
    seq_gaps: int = integer("uint64")


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.__name__: cls for cls in (
        BiotacPac, BiotacSlow, BiotacStatus, BiotacTare, PztCommand, PztState, PztOutput, ObjectPose, ActuatorCommand, ActuatorState,
        GripCommand, RobotState, RobotRecover, SlipEstimate, SimTruth, RunEvent, Heartbeat)
}
DEFAULT_TOPICS: dict[str, type[Message]] = {cls.TOPIC: cls for cls in MESSAGE_TYPES.values()}

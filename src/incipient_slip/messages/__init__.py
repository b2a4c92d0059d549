"""The wire contract: every topic's typed message, its schema version and its msgpack codec.

Read `types` first (one dataclass per topic), then `fields` (what each field kind allows on the
wire: widths, units, bounds, NaN rules, limits) and `codec` (frames and bodies; every malformed
input raises the one :class:`MessageError`). docs/messages.md is generated from these
declarations; `history` reads recordings of older versions. Nothing outside this package builds message dicts by hand.
"""
from incipient_slip.messages.codec import (
    body_encoder, decode, decode_any, encode, split_frames, to_plain, topic_frame,
)
from incipient_slip.messages.history import current_body, decode_recorded
from incipient_slip.messages.fields import MAX_BODY_BYTES, MAX_STRING, Message, MessageError
from incipient_slip.messages.types import (
    BIOTAC_CHANNELS, BIOTAC_ERROR_WORDS, DEFAULT_TOPICS, ELECTRODE_COUNT, ESTIMATE_CAUSES, GRIP_CAUSES,
    MESSAGE_TYPES, METHODS,
    MOCAP_RATE_HZ, PAC_RATE_HZ, PAC_SAMPLES_PER_FRAME, PERIOD_NS, RUN_EVENT_KINDS, SLOW_RATE_HZ,
    ActuatorCommand, ActuatorState, BiotacPac, BiotacSlow, BiotacStatus, BiotacTare, GripCommand,
    Heartbeat, ObjectPose, PztCommand, PztOutput, PztState, RobotRecover, RobotState, RunEvent,
    SimTruth, SlipEstimate,
)

__all__ = [
    "MessageError", "Message", "encode", "body_encoder", "decode", "decode_any", "decode_recorded", "current_body",
    "topic_frame", "split_frames",
    "to_plain", "MESSAGE_TYPES", "DEFAULT_TOPICS", "MAX_BODY_BYTES", "MAX_STRING",
    "BiotacPac", "BiotacSlow", "PztCommand", "PztState", "ObjectPose", "ActuatorCommand",
    "ActuatorState", "GripCommand", "RobotState", "RobotRecover", "SlipEstimate", "RunEvent",
    "Heartbeat", "SimTruth",
    "PAC_SAMPLES_PER_FRAME", "ELECTRODE_COUNT", "METHODS", "RUN_EVENT_KINDS",
    "PERIOD_NS", "PAC_RATE_HZ", "SLOW_RATE_HZ", "MOCAP_RATE_HZ",
    "BiotacStatus", "BiotacTare", "PztOutput", "BIOTAC_CHANNELS", "BIOTAC_ERROR_WORDS",
    "ESTIMATE_CAUSES", "GRIP_CAUSES",
]

"""Older schema versions a recording may hold, and how each reads as the current version.

The live wire speaks one version per type (`codec.decode` refuses every other: publishers and
subscribers of one graph run the same build). Recordings outlive builds, so their readers
(`graph.bag.BagRecord.message`, replay, recover, export, the lab's import) decode through
:func:`decode_recorded`, which takes a body of an older version listed in `UPGRADES`, rewrites
its map as the current version would carry it, and validates that map field by field as any
body is. :func:`current_body` gives the bytes a replay puts on the wire (a current body as it
is; an older one re-encoded at the current version, its stamp and seq kept).

One entry per (type, old version); each takes the old map and returns the new one. A type whose
version goes up without an entry here makes its old recordings unreadable (a MessageError on
`v`), which tests/messages/test_history.py guards for the versions listed here.
"""
from __future__ import annotations

from typing import Callable

from incipient_slip.messages.codec import _unpack, _validate_fields, decode_any, encode
from incipient_slip.messages.fields import Message, MessageError
from incipient_slip.messages.types import MESSAGE_TYPES

__all__ = ["UPGRADES", "decode_recorded", "current_body", "estimate_cause_of", "grip_cause_of"]


def estimate_cause_of(reason: str, valid: bool) -> str:
    """The `ESTIMATE_CAUSES` entry of a v1 SlipEstimate's reason text (the estimator's words)."""
    if valid:
        return "ok"
    for prefix, cause in (("filling", "filling"), ("seq gap", "seq_gap"), ("stale", "stale"),
                          ("stamp went backwards", "backwards"), ("no data", "no_data"), ("PZT is", "pzt_mismatch")):
        if reason.startswith(prefix):
            return cause
    return "unknown"


def grip_cause_of(reason: str, hold: bool) -> str:
    """The `GRIP_CAUSES` entry of a v1 GripCommand's reason text (the controller's words)."""
    if not hold:
        return {"": "law", "no action": "no_action", "collection schedule": "schedule"}.get(reason, "unknown")
    for prefix, cause in (("stale estimate", "stale_estimate"), ("estimate marked invalid", "estimate_invalid"),
                          ("estimate for period", "estimate_other_period"), ("estimate of method", "estimate_other_method")):
        if reason.startswith(prefix):
            return cause
    if reason.startswith("stick ratio"):
        if "is not a number" in reason or "is not finite" in reason:
            return "estimate_not_finite"
        if "outside [0, 1]" in reason:
            return "estimate_out_of_range"
    return "unknown"


def _actuator_state_1(body: dict) -> dict:
    """v1 -> v2: step_index renamed period."""
    body = dict(body)
    if "step_index" in body:
        body["period"] = body.pop("step_index")
    return body


def _with_cause(cause_of: Callable[[str, bool], str], flag: str) -> Callable[[dict], dict]:
    def upgrade(body: dict) -> dict:
        """v1 -> v2: the cause, read from the reason text (unknown when it is not the code's)."""
        reason, value = body.get("reason"), body.get(flag)
        cause = cause_of(reason, value) if isinstance(reason, str) and isinstance(value, bool) else "unknown"
        return {**body, "cause": cause}
    return upgrade


UPGRADES: dict[tuple[str, int], Callable[[dict], dict]] = {
    ("ActuatorState", 1): _actuator_state_1,
    ("SlipEstimate", 1): _with_cause(estimate_cause_of, "valid"),
    ("GripCommand", 1): _with_cause(grip_cause_of, "hold"),
}


def _upgraded(body: bytes, topic: str) -> Message | None:
    """The message of an older-version body listed in UPGRADES; None if the body is not one."""
    obj = _unpack(body, topic)
    name, version = obj.get("type"), obj.get("v")
    if not isinstance(name, str) or type(version) is not int or name not in MESSAGE_TYPES:
        return None
    cls = MESSAGE_TYPES[name]
    while version != cls.SCHEMA_VERSION and (name, version) in UPGRADES:
        obj = UPGRADES[name, version](obj)
        version += 1
    if version != cls.SCHEMA_VERSION:
        return None
    return _validate_fields(cls, {**obj, "v": version}, topic)


def _recorded(body: bytes, topic: str) -> tuple[Message, bool]:
    """(the message in a recorded body, whether the body was of an older version in UPGRADES);
    MessageError for anything else, as `decode_any`."""
    try:
        return decode_any(body, topic), False
    except MessageError as exc:
        if exc.field != "v":
            raise
        msg = _upgraded(body, topic)
        if msg is None:
            raise
        return msg, True


def decode_recorded(body: bytes, topic: str = "?") -> Message:
    """The message in a recorded body, of the current version or of an older one in UPGRADES
    (read as the current version); MessageError for anything else, as `decode_any`."""
    return _recorded(body, topic)[0]


def current_body(body: bytes, topic: str = "?") -> bytes:
    """The body at the current version: `body` itself when it is current, else the older body
    upgraded and re-encoded (stamp and seq kept); MessageError for a malformed body."""
    msg, upgraded = _recorded(body, topic)
    return encode(msg) if upgraded else body

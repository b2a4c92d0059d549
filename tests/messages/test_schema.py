"""The JSON schema written into recordings carries the decoder's bounds, enums and limits: it
accepts every body the decoder accepts and refuses the out-of-range scalars the decoder refuses."""
from __future__ import annotations

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from jsonschema import Draft202012Validator

from incipient_slip import messages as M
from incipient_slip.messages.fields import INT_RANGES, Scalar, field_specs
from incipient_slip.messages.schema import json_schema

from test_hostile import _mutate, body_of, outcome, pack, sample
from test_messages import any_message

VALIDATORS = {cls: Draft202012Validator(json_schema(cls)) for cls in M.MESSAGE_TYPES.values()}


@pytest.mark.parametrize("cls", list(M.MESSAGE_TYPES.values()), ids=lambda c: c.__name__)
def test_schemas_are_valid_json_schema_with_every_declared_bound(cls):
    schema = json_schema(cls)
    Draft202012Validator.check_schema(schema)
    for name, spec in field_specs(cls):
        prop = schema["properties"][name]
        if not isinstance(spec, Scalar):
            assert prop["properties"]["dtype"] == {"const": spec.dtype}
            assert prop["properties"]["shape"] == {"const": list(spec.shape)}
            continue
        assert prop["x-wire"] == spec.wire
        assert (prop.get("minimum"), prop.get("maximum")) == (spec.low, spec.high)
        assert prop.get("enum") == (list(spec.choices) if spec.choices else None)
        assert prop.get("x-nan", False) == (spec.kind is float and not spec.finite)
        if spec.kind is int:
            assert (spec.low, spec.high) != (None, None) and spec.low >= INT_RANGES[spec.wire][0]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(any_message, st.data())
def test_schema_accepts_every_body_the_decoder_accepts(msg, data):
    cls = type(msg)
    assert VALIDATORS[cls].is_valid(body_of(msg))
    body = pack(_mutate(body_of(msg), data))
    if isinstance(outcome(body, cls), M.Message):
        assert VALIDATORS[cls].is_valid(msgpack.unpackb(body, raw=False))


@pytest.mark.parametrize("cls, name, value", [
    (M.ActuatorState, "period", 1 << 32),
    (M.GripCommand, "period", -2),
    (M.GripCommand, "normal_force_kpa", 100.5),
    (M.BiotacSlow, "pdc_counts", 4096),
    (M.BiotacPac, "stamp_ns", -1),
    (M.BiotacPac, "seq", True),
    (M.SlipEstimate, "method", "magic"),
    (M.PztCommand, "intensity_db", 21.0),
    (M.Heartbeat, "node", "n" * 256),
    (M.RunEvent, "extra", 1),
])
def test_schema_refuses_what_the_decoder_refuses(cls, name, value):
    body = body_of(sample(cls))
    body[name] = value
    assert isinstance(outcome(pack(body), cls), M.MessageError)
    assert not VALIDATORS[cls].is_valid(body)


def test_a_version_given_as_bool_or_str_is_refused_by_the_schema_too():
    # (JSON Schema counts 1.0 as the integer 1; its `x-wire: int` says what the decoder enforces)
    body = body_of(sample(M.BiotacPac))
    for version in (True, "1", 2):
        body["v"] = version
        assert not VALIDATORS[M.BiotacPac].is_valid(body), version

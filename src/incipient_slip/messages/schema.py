"""The JSON Schema of a message's msgpack body, derived from its field declarations.

Recordings embed it (MCAP schema records, encoding "jsonschema"), so a reader in another
language sees the same widths, bounds, enums and limits as the decoder enforces. JSON Schema
cannot say everything a msgpack body holds; the gaps are named in `x-` keywords:
`x-wire` (the msgpack type and integer width; JSON Schema counts 1.0 as an integer, the
decoder does not), `x-unit`, `x-nan` (the float may be NaN or
+-inf, which JSON numbers cannot carry), `x-max-utf8-bytes` (the string limit is in bytes,
`maxLength` in characters) and, for array data, `x-msgpack: "bin"`.
"""
from __future__ import annotations

import math

import numpy as np

from incipient_slip.messages.fields import MAX_BODY_BYTES, Message

__all__ = ["json_schema"]

_JSON_TYPES = {"bool": "boolean", "int": "integer", "float": "number", "str": "string"}


def json_schema(msg_type: type[Message]) -> dict:
    """A JSON Schema (2020-12) of the msgpack map that carries `msg_type` on the wire."""
    desc = msg_type.schema()
    props = {"type": {"const": desc["type"]},
             "v": {"const": desc["version"], "x-wire": "int",
                   "description": "schema version: an int, never 1.0 or true"}}
    for name, spec in desc["fields"].items():
        props[name] = _array(spec) if "array" in spec else _scalar(spec)
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": desc["type"], "description": desc["description"], "type": "object",
            "properties": props, "required": list(props), "additionalProperties": False,
            "x-max-body-bytes": MAX_BODY_BYTES, "x-incipient-slip": desc}


def _scalar(spec: dict) -> dict:
    out = {"type": _JSON_TYPES[spec["type"]], "x-wire": spec["wire"]}
    if "min" in spec:
        out["minimum"] = spec["min"]
    if "max" in spec:
        out["maximum"] = spec["max"]
    if "enum" in spec:
        out["enum"] = spec["enum"]
    if "max_bytes" in spec:
        out["maxLength"] = spec["max_bytes"]
        out["x-max-utf8-bytes"] = spec["max_bytes"]
    if spec.get("nan"):
        out["x-nan"] = True
    return _annotate(out, spec)


def _array(spec: dict) -> dict:
    dtype = np.dtype(spec["array"])
    nbytes = math.prod(spec["shape"]) * dtype.itemsize
    finite = ", all finite" if dtype.kind == "f" else ""
    out = {
        "type": "object",
        "description": f"numpy array, dtype {spec['array']}, shape {spec['shape']}{finite}; "
                       f"data = {nbytes} raw little-endian bytes, C order (msgpack bin)",
        "properties": {"dtype": {"const": spec["array"]},
                       "shape": {"const": spec["shape"]},
                       "data": {"x-msgpack": "bin", "x-bytes": nbytes}},
        "required": ["dtype", "shape", "data"],
        "additionalProperties": False,
    }
    return _annotate(out, spec)


def _annotate(out: dict, spec: dict) -> dict:
    if "unit" in spec:
        out["x-unit"] = spec["unit"]
    if "note" in spec:
        out["description"] = (out.get("description", "") + "; " if "description" in out else "") + spec["note"]
    return out

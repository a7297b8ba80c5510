"""Foxglove's official message schemas, taken from the foxglove-sdk wheel and not from navd,
for tests/test_foxglove_mcap.py and tests/test_foxglove_ws.py.

The SDK ships no JSON Schema files.  Its message classes (``foxglove.messages.LocationFix``,
``PoseInFrame``, ...) give the official definition as ``get_schema()``: a protobuf
FileDescriptorSet (schema encoding ``protobuf``), the source Foxglove generates its other
schema forms from.  This module reads that descriptor with a small protobuf wire-format
decoder (no protobuf dependency) and offers

- :func:`official_json_schema`: the JSON Schema for JSON-encoded data, by the mapping rules
  of Foxglove's own generator (float64 -> number, time -> ``{sec, nsec}``, enum -> its
  numbers, repeated -> array), strict: no property that Foxglove's message does not have,
  and every field that is not protobuf ``optional`` present;
- :func:`sdk_round_trip`: the JSON object built into the SDK's own message class (unknown
  keyword or wrong type: ``TypeError``), encoded by the SDK, decoded from the wire with the
  descriptor and returned in JSON form, to compare with the object sent;
- :func:`schema_text_problems`: where a JSON Schema text (navd's) declares a property or
  type that the official schema does not have.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any

import foxglove.messages as fm

# FieldDescriptorProto.Type
_DOUBLE, _FLOAT, _INT64, _UINT64, _INT32 = 1, 2, 3, 4, 5
_FIXED64, _FIXED32, _BOOL, _STRING, _MESSAGE, _BYTES, _UINT32, _ENUM = 6, 7, 8, 9, 11, 12, 13, 14
_REPEATED = 3  # FieldDescriptorProto.Label
_TIMESTAMP, _DURATION = ".google.protobuf.Timestamp", ".google.protobuf.Duration"


@dataclass(frozen=True)
class Field:
    name: str
    number: int
    type: int
    type_name: str      # ".foxglove.Vector3", ".foxglove.LocationFix.PositionCovarianceType"
    repeated: bool
    optional: bool      # proto3 ``optional`` (added to the message later; may be absent)


@dataclass(frozen=True)
class Descriptors:
    messages: dict[str, list[Field]]      # ".foxglove.Pose" -> fields
    enums: dict[str, dict[int, str]]      # enum type -> {number: NAME}


def _required(f: Field) -> bool:
    """Foxglove's published JSON Schemas require the fields that are not ``optional``, but not
    lists of sub-messages (``metadata``)."""
    return not f.optional and not (f.repeated and f.type == _MESSAGE)


def _varint(b: bytes, i: int) -> tuple[int, int]:
    r = s = 0
    while True:
        c = b[i]
        i += 1
        r |= (c & 0x7F) << s
        s += 7
        if not c & 0x80:
            return r, i


def _wire(buf: bytes) -> Iterator[tuple[int, int, Any]]:
    """(field number, wire type, value) of a serialised protobuf message."""
    i = 0
    while i < len(buf):
        key, i = _varint(buf, i)
        num, wt = key >> 3, key & 7
        v: Any
        if wt == 0:
            v, i = _varint(buf, i)
        elif wt == 1:
            v, i = buf[i:i + 8], i + 8
        elif wt == 5:
            v, i = buf[i:i + 4], i + 4
        elif wt == 2:
            n, i = _varint(buf, i)
            v, i = buf[i:i + n], i + n
        else:
            raise ValueError(f"wire type {wt}")
        yield num, wt, v


def _read_message(buf: bytes, scope: str, out: Descriptors) -> None:
    """DescriptorProto: 1 name, 2 field, 3 nested_type, 4 enum_type."""
    parts = list(_wire(buf))
    name = f"{scope}.{next(v.decode() for n, _, v in parts if n == 1)}"
    fields: list[Field] = []
    for n, _, v in parts:
        if n == 2:  # FieldDescriptorProto: 1 name, 3 number, 4 label, 5 type, 6 type_name,
            #           17 proto3_optional
            f = {k: val for k, _, val in _wire(v)}
            fields.append(Field(name=f[1].decode(), number=f[3], type=f[5],
                                type_name=f.get(6, b"").decode(), repeated=f[4] == _REPEATED,
                                optional=bool(f.get(17, 0))))
        elif n == 3:
            _read_message(v, name, out)
        elif n == 4:
            _read_enum(v, name, out)
    out.messages[name] = fields


def _read_enum(buf: bytes, scope: str, out: Descriptors) -> None:
    """EnumDescriptorProto: 1 name, 2 value (EnumValueDescriptorProto: 1 name, 2 number)."""
    parts = list(_wire(buf))
    name = f"{scope}.{next(v.decode() for n, _, v in parts if n == 1)}"
    values: dict[int, str] = {}
    for n, _, v in parts:
        if n == 2:
            ev = {k: val for k, _, val in _wire(v)}
            values[ev.get(2, 0)] = ev[1].decode()
    out.enums[name] = values


def _sdk_class(schema_name: str) -> Any:
    return getattr(fm, schema_name.removeprefix("foxglove."))


@cache
def official_descriptors(schema_name: str) -> Descriptors:
    """The FileDescriptorSet of ``foxglove.messages.<Name>.get_schema()`` for ``schema_name``
    (``foxglove.LocationFix``), read into messages and enums."""
    schema = _sdk_class(schema_name).get_schema()
    assert (schema.name, schema.encoding) == (schema_name, "protobuf")
    out = Descriptors({}, {})
    for n, _, fdp in _wire(bytes(schema.data)):   # FileDescriptorSet.file
        assert n == 1
        parts = list(_wire(fdp))                   # FileDescriptorProto: 2 package 4 message 5 enum
        package = next((v.decode() for k, _, v in parts if k == 2), "")
        for k, _, v in parts:
            if k == 4:
                _read_message(v, f".{package}", out)
            elif k == 5:
                _read_enum(v, f".{package}", out)
    assert f".{schema_name}" in out.messages
    return out


def _sdk_enum(type_name: str) -> Any:
    """``.foxglove.LocationFix.PositionCovarianceType`` -> fm.LocationFixPositionCovarianceType"""
    return getattr(fm, type_name.removeprefix(".foxglove.").replace(".", ""))


def sdk_enum_members(type_name: str) -> dict[int, Any]:
    cls = _sdk_enum(type_name)
    return {m.value: m for m in (getattr(cls, a) for a in dir(cls) if a[:1].isupper())}


_TIME_SCHEMA = {"type": "object", "title": "time", "additionalProperties": False,
                "required": ["sec", "nsec"],
                "properties": {"sec": {"type": "integer", "minimum": 0},
                               "nsec": {"type": "integer", "minimum": 0,
                                        "maximum": 999_999_999}}}
_DURATION_SCHEMA = {**_TIME_SCHEMA, "title": "duration", "properties": {
    "sec": {"type": "integer"},
    "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}
_SCALAR = {_DOUBLE: {"type": "number"}, _FLOAT: {"type": "number"},
           _INT32: {"type": "integer"}, _INT64: {"type": "integer"},
           _UINT32: {"type": "integer", "minimum": 0}, _UINT64: {"type": "integer", "minimum": 0},
           _FIXED32: {"type": "integer", "minimum": 0}, _FIXED64: {"type": "integer", "minimum": 0},
           _BOOL: {"type": "boolean"}, _STRING: {"type": "string"},
           _BYTES: {"type": "string", "contentEncoding": "base64"}}


def _json_schema(d: Descriptors, message: str) -> dict[str, Any]:
    props: dict[str, Any] = {}
    for f in d.messages[message]:
        t: dict[str, Any]
        if f.type_name == _TIMESTAMP:
            t = _TIME_SCHEMA
        elif f.type_name == _DURATION:
            t = _DURATION_SCHEMA
        elif f.type == _MESSAGE:
            t = _json_schema(d, f.type_name)
        elif f.type == _ENUM:
            t = {"type": "integer", "enum": sorted(d.enums[f.type_name])}
        else:
            t = _SCALAR[f.type]
        props[f.name] = {"type": "array", "items": t} if f.repeated else t
    required = [f.name for f in d.messages[message] if _required(f)]
    return {"title": message.lstrip("."), "type": "object", "properties": props,
            "required": required, "additionalProperties": False}


def official_json_schema(schema_name: str) -> dict[str, Any]:
    """Strict JSON Schema of ``schema_name`` derived from the SDK's official definition."""
    return _json_schema(official_descriptors(schema_name), f".{schema_name}")


def _to_sdk(d: Descriptors, message: str, obj: Mapping[str, Any]) -> Any:
    fields = {f.name: f for f in d.messages[message]}
    kw: dict[str, Any] = {}
    for key, value in obj.items():
        if key not in fields:
            raise TypeError(f"{message}: no field {key!r}")
        f = fields[key]

        def one(v: Any, f: Field = f) -> Any:
            if f.type_name == _TIMESTAMP:
                return fm.Timestamp(**v)
            if f.type_name == _DURATION:
                return fm.Duration(**v)
            if f.type == _MESSAGE:
                return _to_sdk(d, f.type_name, v)
            if f.type == _ENUM:
                return sdk_enum_members(f.type_name)[v]
            return v
        kw[key] = [one(v) for v in value] if f.repeated else one(value)
    return getattr(fm, message.removeprefix(".foxglove."))(**kw)


def _scalar(f: Field, wt: int, v: Any) -> list[Any]:
    if f.type == _DOUBLE:
        return [x for (x,) in struct.iter_unpack("<d", v)]   # one, or a packed run
    if f.type == _FLOAT:
        return [x for (x,) in struct.iter_unpack("<f", v)]
    if f.type == _STRING:
        return [v.decode()]
    if f.type == _BYTES:
        return [v]
    if wt == 2:  # packed varints
        out, i = [], 0
        while i < len(v):
            x, i = _varint(v, i)
            out.append(x)
        vals = out
    else:
        vals = [v]
    if f.type == _BOOL:
        return [bool(x) for x in vals]
    if f.type in (_INT32, _INT64):
        return [x - (1 << 64) if x >= 1 << 63 else x for x in vals]
    return vals


def _decode(d: Descriptors, message: str, buf: bytes) -> dict[str, Any]:
    """Wire bytes -> the message in Foxglove's JSON form, absent required fields at their
    proto3 defaults (proto3 does not encode a default value)."""
    by_num = {f.number: f for f in d.messages[message]}
    out: dict[str, Any] = {}
    for num, wt, v in _wire(buf):
        f = by_num[num]
        if f.type_name in (_TIMESTAMP, _DURATION):
            w = {k: x for k, _, x in _wire(v)}
            vals: list[Any] = [{"sec": w.get(1, 0), "nsec": w.get(2, 0)}]
        elif f.type == _MESSAGE:
            vals = [_decode(d, f.type_name, v)]
        else:
            vals = _scalar(f, wt, v)
        if f.repeated:
            out.setdefault(f.name, []).extend(vals)
        else:
            out[f.name] = vals[-1]
    for f in d.messages[message]:
        if f.name in out or not _required(f):
            continue
        if f.repeated:
            out[f.name] = []
        elif f.type_name in (_TIMESTAMP, _DURATION):
            out[f.name] = {"sec": 0, "nsec": 0}
        elif f.type == _MESSAGE:
            out[f.name] = _decode(d, f.type_name, b"")
        else:
            out[f.name] = {_STRING: "", _BYTES: b"", _BOOL: False}.get(f.type, 0)
    return out


def decode_official(schema_name: str, data: bytes) -> dict[str, Any]:
    """A ``schema_name`` message's protobuf bytes, decoded with the official descriptor, in
    Foxglove's JSON form."""
    return _decode(official_descriptors(schema_name), f".{schema_name}", data)


def sdk_round_trip(schema_name: str, obj: Mapping[str, Any]) -> dict[str, Any]:
    """``obj`` (a JSON message) -> the SDK's own message class -> its protobuf encoding ->
    decoded again with the official descriptor, in JSON form."""
    d = official_descriptors(schema_name)
    return decode_official(schema_name, _to_sdk(d, f".{schema_name}", obj).encode())


def schema_text_problems(schema: Mapping[str, Any], official: Mapping[str, Any],
                         path: str = "") -> list[str]:
    """Properties or types that ``schema`` declares and ``official`` does not have."""
    bad: list[str] = []
    title = schema.get("title")
    if title is not None and "title" in official and title != official["title"]:
        bad.append(f"{path or '/'}: title {title!r}, official {official['title']!r}")
    otype = official.get("type")
    if "type" in schema and schema["type"] != otype:
        bad.append(f"{path or '/'}: type {schema['type']!r}, official {otype!r}")
    if "enum" in schema and not set(schema["enum"]) <= set(official.get("enum", [])):
        bad.append(f"{path}: enum {schema['enum']}, official {official.get('enum')}")
    if "items" in schema:
        bad += schema_text_problems(schema["items"], official.get("items", {}), f"{path}[]")
    oprops = official.get("properties", {})
    for k, sub in schema.get("properties", {}).items():
        if k not in oprops:
            bad.append(f"{path}/{k}: not a field of {official.get('title')}")
        else:
            bad += schema_text_problems(sub, oprops[k], f"{path}/{k}")
    return bad


def assert_official(schema_name: str, obj: Mapping[str, Any]) -> None:
    """``obj`` is a valid ``schema_name`` message by Foxglove's definition: it validates under
    :func:`official_json_schema`, and the SDK's own message class carries it unchanged."""
    import jsonschema

    jsonschema.Draft7Validator(official_json_schema(schema_name)).validate(obj)
    assert sdk_round_trip(schema_name, obj) == obj, schema_name

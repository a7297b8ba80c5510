"""Configuration loading: TOML with a unit in every key name, converted to SI once at load.

``load_config(path, overrides)`` returns the raw tables; :func:`build_section` turns one
table into its typed section (the one builder every section of navd goes through:
:mod:`navd.config.estimator`, :mod:`navd.config.aiding`, :mod:`navd.config.daemon`).  Overrides are
``section.key=value`` strings whose value is parsed as a TOML literal (bare words are taken
as strings), e.g. ``estimator.mode=traditional`` or ``gnss.lever_arm_m=[0.5, 0, -0.2]``.
"""

from __future__ import annotations

import functools
import math
import tomllib
import typing
from collections.abc import Mapping
from dataclasses import Field, field, fields
from pathlib import Path
from typing import Any, TypeVar

from navd.units import DEG, G0

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value is missing, unknown or of the wrong type/unit."""


def parse_override(text: str, *, min_depth: int = 2) -> tuple[list[str], Any]:
    """``"a.b.c=value"`` -> (["a", "b", "c"], value): the value parsed as a TOML literal (a
    bare word is taken as a string).  ``min_depth``: fewest dotted parts (2: section.key)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} is not of the form section.key=value")
    key, raw = text.split("=", 1)
    parts = key.strip().split(".")
    if len(parts) < min_depth or not all(parts):
        raise ConfigError(f"override key {key!r} must be section.key")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return parts, value


def set_override(data: dict[str, Any], parts: list[str], value: Any) -> None:
    """Set ``data[parts[0]]...[parts[-1]] = value``, creating tables on the way."""
    if not parts or not all(parts):
        raise ConfigError(f"{'.'.join(parts)}: bad override key")
    node = data
    for i, p in enumerate(parts[:-1]):
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ConfigError(f"{'.'.join(parts[: i + 1])}: is not a table, cannot set "
                              f"{'.'.join(parts)}")
    node[parts[-1]] = value


def load_config(path: str | Path | None, overrides: list[str] | None = None) -> dict[str, Any]:
    """Read a TOML file (None: built-in defaults only) and apply ``section.key=value``."""
    data: dict[str, Any] = {}
    if path is not None:
        try:
            with open(path, "rb") as fh:
                data = tomllib.load(fh)
        except OSError as exc:
            raise ConfigError(f"cannot read config {path}: {exc}") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config {path} is not valid TOML: {exc}") from exc
    return apply_overrides(data, overrides or [])


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Set each ``section.key=value`` in the TOML tables ``data`` (in place); returns it."""
    for ov in overrides:
        parts, value = parse_override(ov)
        try:
            set_override(data, parts, value)
        except ConfigError as exc:
            raise ConfigError(f"override {ov!r}: {exc}") from None
    return data


# -- the one typed-section builder -------------------------------------------------------------
#
# Every section of every part of navd is a frozen dataclass whose fields are declared with
# :func:`setting`.  The naming rule: the TOML key is ``<name>_<unit>`` (bare ``<name>`` when
# the value has no unit); the attribute is ``<name>`` and holds the value in SI units
# (seconds, Hz, m, rad, m/s^2, ...).  :func:`build_section` is the only code that turns a TOML
# table into a section: types, unit conversion, choices, required keys, unknown keys, then the
# section's own ``validate()`` for ranges.

# unit suffix -> factor to SI
_UNITS: dict[str, float] = {
    "deg": DEG, "rad": 1.0, "m": 1.0, "mps": 1.0, "s": 1.0, "ms": 1e-3, "hz": 1.0,
    "dps": DEG, "mps2": 1.0, "mg": 1e-3 * G0,
    "days": 86_400.0,
    "bytes": 1.0,
    "deg_per_h": DEG / 3600.0,
    "deg_per_sqrt_h": DEG / 60.0,  # deg/sqrt(h) -> rad/sqrt(s)
    "deg_per_sqrt_s": DEG,  # deg/sqrt(s) -> rad/sqrt(s)
    "dps_per_sqrt_s": DEG,  # (deg/s)/sqrt(s) -> rad/s/sqrt(s)
    "pct": 0.01,
    "mps_per_sqrt_s": 1.0,
    "mps_per_sqrt_h": 1.0 / 60.0,
    "deg_per_h_per_sqrt_h": DEG / 3600.0 / 60.0,  # (deg/h)/sqrt(h) -> rad/s/sqrt(s)
    "mps2_per_sqrt_s": 1.0,
    "rps_per_lsb": 1.0,  # rad/s per LSB
    "mps2_per_lsb": 1.0,  # m/s^2 per LSB
}

Vec3 = tuple[float, float, float]

_DESCRIBE: dict[Any, str] = {
    bool: "true or false", int: "an integer", float: "a number", str: "a string",
    tuple[str, ...]: "a list of strings", tuple[int, ...]: "a list of integers",
    tuple[tuple[int, int], ...]: "a list of [int, int] pairs",
}


def to_si(value: float, unit: str) -> float:
    """``value`` given in ``unit`` (a key suffix, "" = unitless), in SI."""
    return value * _UNITS[unit] if unit else value


def from_si(value: float, unit: str) -> float:
    """Inverse of :func:`to_si` (for files and messages that are written in the key's unit)."""
    return value / _UNITS[unit] if unit else value


def setting(default: Any, unit: str = "", *, choices: tuple[Any, ...] = (),
            required: str = "") -> Any:
    """A section field.  Its TOML key is ``<name>_<unit>`` (``<name>`` when ``unit`` is "");
    ``default`` is given in ``unit`` (as a user writes it) and stored in SI.

    choices: the allowed values (checked by :func:`build_section`).
    required: the key must be written in the table; the text says why (error message).
    """
    if unit and unit not in _UNITS:
        raise ValueError(f"unknown unit suffix {unit!r}")
    if unit and isinstance(default, tuple):
        default = tuple(to_si(float(v), unit) for v in default)
    elif unit and isinstance(default, float):
        default = to_si(default, unit)
    meta = {"unit": unit, "choices": choices, "required": required}
    return field(default=default, metadata=meta)


def toml_key(f: Field[Any]) -> str:
    """The TOML key of a section field: ``<name>_<unit>`` or ``<name>``."""
    unit = f.metadata.get("unit", "")
    return f"{f.name}_{unit}" if unit else f.name


def toml_keys(cls: type) -> list[str]:
    """A section's TOML keys, in declaration order."""
    return [toml_key(f) for f in fields(cls)]


def check(ok: bool, section: str, key: str, expected: str) -> None:
    """Raise ``ConfigError("[section] key must be <expected>")`` unless ``ok``."""
    if not ok:
        raise ConfigError(f"[{section}] {key} must be {expected}")


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _convert(where: str, value: Any, unit: str, tp: Any) -> Any:
    """``value`` as type ``tp`` (SI when ``unit``), or ConfigError naming ``where``."""
    if tp is float:
        if not _is_num(value):
            raise ConfigError(f"{where} must be a number{' in ' + unit if unit else ''}, "
                              f"got {value!r}")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{where} must be finite, got {value!r}")
        return to_si(float(value), unit)
    if tp == Vec3:
        if not isinstance(value, list) or len(value) != 3 or not all(map(_is_num, value)):
            raise ConfigError(f"{where} must be a list of 3 numbers in {unit or 'SI'}")
        if not all(math.isfinite(float(v)) for v in value):
            raise ConfigError(f"{where} must be finite, got {value!r}")
        return tuple(to_si(float(v), unit) for v in value)
    ok: Any = None
    if ((tp is bool and isinstance(value, bool)) or (tp is int and _is_int(value))
            or (tp is str and isinstance(value, str))):
        ok = value
    elif isinstance(value, list):
        if ((tp == tuple[str, ...] and all(isinstance(v, str) for v in value))
                or (tp == tuple[int, ...] and all(map(_is_int, value)))):
            ok = tuple(value)
        elif tp == tuple[tuple[int, int], ...] and all(
                isinstance(p, list) and len(p) == 2 and all(map(_is_int, p)) for p in value):
            ok = tuple((p[0], p[1]) for p in value)
    if ok is None:
        raise ConfigError(f"{where} must be {_DESCRIBE.get(tp, str(tp))}, got {value!r}")
    return ok


def build_section(cls: type[T], section: str, table: Any) -> T:
    """Section dataclass ``cls`` from its TOML table (``{}``: all defaults).

    Raises ConfigError, naming ``[section] key`` and what it expects, for: a table that is
    not a table, an unknown key (listing the valid ones), a missing required key, a value of
    the wrong type, a non-finite number, a value outside ``choices``, and whatever the
    section's ``validate()`` refuses.
    """
    if not isinstance(table, Mapping):
        raise ConfigError(f"[{section}] must be a table")
    hints = _hints(cls)  # type: ignore[arg-type]
    by_key = {toml_key(f): f for f in fields(cls)}  # type: ignore[arg-type]
    missing: dict[str, list[str]] = {}
    for key, f in by_key.items():
        why = f.metadata.get("required", "")
        if why and key not in table:
            missing.setdefault(why, []).append(key)
    for why, keys in missing.items():
        raise ConfigError(f"[{section}] {', '.join(keys)} missing: {why}")
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key not in by_key:
            raise ConfigError(f"[{section}] unknown key {key!r}; expected one of: "
                              f"{', '.join(by_key)}")
        f = by_key[key]
        where = f"[{section}] {key}"
        v = _convert(where, value, f.metadata.get("unit", ""), hints[f.name])
        allowed = f.metadata.get("choices", ())
        if allowed and v not in allowed:
            raise ConfigError(f"{where} = {v!r}; expected one of {allowed}")
        kwargs[f.name] = v
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        validate()
    return obj

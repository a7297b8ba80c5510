"""Configuration loading: TOML with a unit in every key name, converted to SI once at load.

``load_config(path, overrides)`` returns the raw tables (so each part of navd reads its own
sections); :class:`EstimatorConfig` is the estimator's typed, SI view.  Overrides are
``section.key=value`` strings whose value is parsed as a TOML literal (bare words are taken
as strings), e.g. ``estimator.mode=traditional`` or ``gnss.lever_arm_m=[0.5, 0, -0.2]``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import field, fields
from pathlib import Path
from typing import Any

from navd.units import DEG, G0


class ConfigError(ValueError):
    """A configuration value is missing, unknown or of the wrong type/unit."""


def parse_override(text: str) -> tuple[list[str], Any]:
    if "=" not in text:
        raise ConfigError(f"override {text!r} is not of the form section.key=value")
    key, raw = text.split("=", 1)
    parts = key.strip().split(".")
    if len(parts) < 2 or not all(parts):
        raise ConfigError(f"override key {key!r} must be section.key")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return parts, value


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
        node = data
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override {ov!r}: {p} is not a table")
        node[parts[-1]] = value
    return data


# unit suffix -> factor to SI
_UNITS: dict[str, float] = {
    "deg": DEG, "rad": 1.0, "m": 1.0, "mps": 1.0, "s": 1.0, "ms": 1e-3, "hz": 1.0,
    "dps": DEG, "mps2": 1.0, "mg": 1e-3 * G0,
    "deg_per_h": DEG / 3600.0,
    "deg_per_sqrt_h": DEG / 60.0,  # deg/sqrt(h) -> rad/sqrt(s)
    "mps_per_sqrt_s": 1.0,
    "mps_per_sqrt_h": 1.0 / 60.0,
    "deg_per_h_per_sqrt_h": DEG / 3600.0 / 60.0,  # (deg/h)/sqrt(h) -> rad/s/sqrt(s)
    "mps2_per_sqrt_s": 1.0,
}


def _convert(section: str, key: str, value: Any, unit: str, kind: type) -> Any:
    where = f"[{section}] {key}"
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return value
    factor = _UNITS[unit] if unit else 1.0
    if kind is tuple:
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool)
                           for v in value)):
            raise ConfigError(f"{where} must be a list of 3 numbers in {unit or 'SI'}")
        if not all(math.isfinite(float(v)) for v in value):
            raise ConfigError(f"{where} must be finite, got {value!r}")
        return tuple(float(v) * factor for v in value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where} must be a number in {unit}, got {value!r}")
    if not math.isfinite(float(value)):
        raise ConfigError(f"{where} must be finite, got {value!r}")
    return float(value) * factor


def build_section(cls: type, section: str, table: dict[str, Any]) -> Any:
    """Build dataclass ``cls`` from a table whose keys are ``<field>_<unit>`` (or bare)."""
    if not isinstance(table, dict):
        raise ConfigError(f"[{section}] must be a table")
    spec = {f.name: f for f in fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        match = None
        for name, f in spec.items():
            unit = f.metadata.get("unit", "")
            full = f"{name}_{unit}" if unit else name
            if key == full:
                match = (name, unit, f.metadata.get("kind", f.type))
                break
        if match is None:
            expected = ", ".join(
                f"{n}_{f.metadata['unit']}" if f.metadata.get("unit") else n
                for n, f in spec.items())
            raise ConfigError(f"[{section}] unknown key {key!r}; expected one of: {expected}")
        name, unit, kind = match
        kind_t: type = {"float": float, "bool": bool, "str": str, "int": int,
                        "tuple": tuple}[str(kind)]
        kwargs[name] = _convert(section, key, value, unit, kind_t)
    return cls(**kwargs)


def unit_field(default: float, unit: str) -> Any:
    """A float field whose TOML key is ``<name>_<unit>``; the default is given in that unit."""
    si = default * (_UNITS[unit] if unit else 1.0)
    return field(default=si, metadata={"unit": unit, "kind": "float"})



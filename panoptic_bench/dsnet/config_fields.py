"""Conversion between YAML mappings and the frozen dataclasses of :mod:`.config`.

Values are checked against each field's annotation (bool, int, float, str, enums, fixed-length
and variable-length tuples); lists become tuples and enum values become members.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import types
import typing
from pathlib import Path
from typing import Any

from panoptic_bench.errors import InputError

__all__ = ["section_from_dict", "section_to_dict"]


def section_from_dict(kind: type, name: str, values: Any, source: str | Path | None) -> Any:
    """Build the frozen dataclass ``kind`` (config section ``name``) from a YAML mapping.

    Unknown keys and values of the wrong type are :class:`InputError` naming
    ``section.key`` and ``source``.
    """
    if not isinstance(values, dict):
        raise InputError(f"config section {name!r} must be a mapping", source)
    fields = {f.name: f for f in dataclasses.fields(kind)}
    unknown = sorted(set(values) - set(fields), key=str)  # keys may mix int and str
    if unknown:
        raise InputError(
            f"unknown config key '{name}.{unknown[0]}'; known keys: {', '.join(fields)}", source
        )
    hints = typing.get_type_hints(kind)
    kwargs = {
        key: _coerce(hints[key], value, f"{name}.{key}", source) for key, value in values.items()
    }
    return kind(**kwargs)


def _coerce(hint: Any, value: Any, key: str, source: str | Path | None) -> Any:
    """Check ``value`` against the annotation ``hint``; lists become tuples, names become enums."""
    origin = typing.get_origin(hint)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        try:
            return hint(value)
        except ValueError:
            names = ", ".join(m.value for m in hint)
            raise InputError(f"{key} must be one of {names}, got {value!r}", source) from None
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list | tuple):
            raise InputError(f"{key} must be a list, got {value!r}", source)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v, key, source) for v in value)
        if len(value) != len(args):
            raise InputError(f"{key} must have {len(args)} entries, got {len(value)}", source)
        return tuple(_coerce(a, v, key, source) for a, v in zip(args, value))
    if origin in (typing.Union, types.UnionType):
        raise TypeError(f"unsupported annotation for {key}")  # pragma: no cover
    if hint is bool:
        if not isinstance(value, bool):
            raise InputError(f"{key} must be true or false, got {value!r}", source)
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(f"{key} must be an integer, got {value!r}", source)
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"{key} must be a number, got {value!r}", source)
        if not math.isfinite(value):
            raise InputError(f"{key} must be a finite number, got {value!r}", source)
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise InputError(f"{key} must be a quoted string, got {value!r}", source)
        return value
    raise TypeError(f"unsupported annotation {hint!r} for {key}")  # pragma: no cover


def section_to_dict(section: Any) -> dict[str, Any]:
    """Plain dict of builtins (enums as their values, tuples as lists) of a section."""
    return {f.name: _plain(getattr(section, f.name)) for f in dataclasses.fields(section)}


def _plain(value: Any) -> Any:
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value

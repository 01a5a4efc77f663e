"""Typed values of world profile keys: coercion of YAML values and range checks.

:class:`~panoptic_bench.datasets.synthetic.profile.WorldProfile` uses these to turn a mapping of
overrides (a profile file) into typed fields and to validate optional ranges.
"""

from __future__ import annotations

import typing
from pathlib import Path
from typing import Any

from panoptic_bench.errors import InputError

__all__ = ["coerce", "near_upper_ok", "optional"]


def optional(values: tuple[float, ...], n: int, lo: float, hi: float) -> bool:
    """True when ``values`` is empty or ``n`` numbers in ``[lo, hi]``."""
    return len(values) in (0, n) and all(lo <= v <= hi for v in values)


def near_upper_ok(values: tuple[float, ...]) -> bool:
    """True when ``values`` is empty or ``(r0, k, z)`` with r0 in [0.5, 20] m, k in [0.5, 10],
    z in [0, 1] (``rem_near_upper``)."""
    if len(values) == 0:
        return True
    if len(values) != 3:
        return False
    r0, k, z = values
    return 0.5 <= r0 <= 20.0 and 0.5 <= k <= 10.0 and 0.0 <= z <= 1.0


def coerce(hint: Any, value: Any, key: str, source: str | Path | None) -> Any:
    """``value`` as the type ``hint`` of the profile field ``key`` (tuples of floats, bool,
    float, str); a value of the wrong type is :class:`InputError` naming the key and ``source``."""
    if typing.get_origin(hint) is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list | tuple):
            raise InputError(f"world profile key {key!r} must be a list, got {value!r}", source)
        if not (len(args) == 2 and args[1] is Ellipsis) and len(value) != len(args):
            raise InputError(f"world profile key {key!r} needs {len(args)} numbers", source)
        return tuple(coerce(float, v, key, source) for v in value)
    if hint is bool:
        if not isinstance(value, bool):
            raise InputError(f"world profile key {key!r} must be true or false", source)
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"world profile key {key!r} must be a number, got {value!r}", source)
        return float(value)
    if not isinstance(value, str):
        raise InputError(f"world profile key {key!r} must be a string, got {value!r}", source)
    return value

"""Small validation helpers shared by every config and env constructor.

Each check raises :class:`~binpick.errors.ConfigError` with a single line naming the parameter,
the value given and the allowed range, so a user never has to read a traceback to fix input.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from binpick.errors import ConfigError


def check_range(
    name: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
    integer: bool = False,
) -> Any:
    """Return ``value`` if it is a finite number within [low, high]; raise ConfigError otherwise."""
    kind = "an integer" if integer else "a number"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{name} must be {kind}{_range_text(low, high, low_inclusive, high_inclusive)}, got {value!r}")
    if integer and not float(value).is_integer():
        raise ConfigError(f"{name} must be an integer{_range_text(low, high, low_inclusive, high_inclusive)}, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{name} must be finite, got {value!r}")
    too_low = low is not None and (value < low if low_inclusive else value <= low)
    too_high = high is not None and (value > high if high_inclusive else value >= high)
    if too_low or too_high:
        raise ConfigError(f"{name} must be{_range_text(low, high, low_inclusive, high_inclusive)}, got {value!r}")
    return int(value) if integer else value


def check_choice(name: str, value: Any, choices: Iterable[Any]) -> Any:
    """Return ``value`` if it is one of ``choices``; raise ConfigError listing them otherwise."""
    options = list(choices)
    if value not in options:
        listed = ", ".join(repr(c) for c in options)
        raise ConfigError(f"{name} must be one of {listed}, got {value!r}")
    return value


def _range_text(low: float | None, high: float | None, low_inc: bool, high_inc: bool) -> str:
    if low is None and high is None:
        return ""
    if high is None:
        return f" {'>=' if low_inc else '>'} {low}"
    if low is None:
        return f" {'<=' if high_inc else '<'} {high}"
    left = "[" if low_inc else "("
    right = "]" if high_inc else ")"
    return f" in {left}{low}, {high}{right}"

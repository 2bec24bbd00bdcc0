"""Validated configuration: range/choice checks and YAML -> dataclass loading.

Each check raises :class:`~binpick.core.errors.ConfigError` with a single line naming the parameter,
the value given and the allowed range, so a user never has to read a traceback to fix input.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import types
import typing
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TypeVar


from binpick.core.errors import ConfigError
from binpick.core.files import parse_yaml, read_text

T = TypeVar("T")


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
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
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


def check_vector(name: str, value: Any, length: int, low: float | None = None, high: float | None = None,
                 **bounds: bool) -> list[float]:
    """``length`` finite numbers in [low, high] (a list or tuple); one ConfigError line otherwise."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or not hasattr(value, "__iter__"):
        raise ConfigError(f"{name} must be a list of {length} numbers, got {value!r}")
    if len(value) != length:
        raise ConfigError(f"{name} must have {length} entries, got {len(value)}")
    return [float(check_range(f"{name}[{i}]", v, low, high, **bounds)) for i, v in enumerate(value)]


def check_pair(name: str, value: Any, low: float, high: float, integer: bool = False) -> tuple:
    """A range ``[low, high]`` (a single number means ``[v, v]``) within the bounds, low <= high."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = (value, value)
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ConfigError(f"{name} must be a range [low, high], got {value!r}")
    lo, hi = (check_range(f"{name}[{i}]", v, low, high, integer=integer) for i, v in enumerate(value))
    if lo > hi:
        raise ConfigError(f"{name} must be [low, high] with low <= high, got {list(value)}")
    return (int(lo), int(hi)) if integer else (float(lo), float(hi))


def check_bool(name: str, value: Any) -> bool:
    """``value`` if it is true or false (not a string that merely looks truthy)."""
    if not isinstance(value, bool):
        raise ConfigError(f"{name} must be true or false, got {value!r}")
    return value


def check_choice(name: str, value: Any, choices: Iterable[Any]) -> Any:
    """Return ``value`` if it is one of ``choices``; raise ConfigError listing them otherwise."""
    options = list(choices)
    if value not in options:
        listed = ", ".join(repr(c) for c in options)
        raise ConfigError(f"{name} must be one of {listed}, got {value!r}{did_you_mean(value, options)}")
    return value


def did_you_mean(given: Any, known: Iterable[Any]) -> str:
    """`` (did you mean 'x'?)`` for the nearest known name to a mistyped one (case ignored), else ``""``."""
    import difflib

    names = {str(k).lower(): str(k) for k in known}
    near = difflib.get_close_matches(str(given).lower(), list(names), n=1, cutoff=0.6)
    return f" (did you mean {names[near[0]]!r}?)" if near else ""


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


# ---------------------------------------------------------------------- YAML -> dataclasses
def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping; a missing file, bad syntax or a non-mapping is one ConfigError line."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"config file {str(path)!r} does not exist")
    text = read_text(path, "config file")  # a folder, a FIFO, unreadable or not UTF-8: one line
    data = parse_yaml(text, str(path))  # bad syntax, a key twice, a bomb: one line
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of keys to values at the top level")
    return data


def from_dict(cls: type[T], data: dict[str, Any] | None, where: str = "config") -> T:
    """Build dataclass ``cls`` from a mapping, checking keys and types; nested dataclasses recurse.

    Unknown keys and wrong types raise one ConfigError naming the dotted key (``config.gp.iterations``).
    Range checks belong in each dataclass's ``__post_init__``.
    """
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    unknown = [k for k in data if k not in names]
    if unknown:
        near = did_you_mean(unknown[0], names)
        raise ConfigError(f"{where} has no key {unknown[0]!r}{near or '; valid keys: ' + ', '.join(names)}")
    values = {key: _convert(hints[key], value, f"{where}.{key}") for key, value in data.items()}
    return cls(**values)


def to_dict(instance: Any) -> dict[str, Any]:
    """A dataclass as plain YAML-able data."""
    return dataclasses.asdict(instance)


def _convert(hint: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        errors = []
        for option in options:
            try:
                return _convert(option, value, where)
            except ConfigError as error:
                errors.append(error)
        raise errors[0]
    if origin is typing.Literal:
        return check_choice(where, value, args)
    if dataclasses.is_dataclass(hint):
        return from_dict(hint, value, where)
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ConfigError(f"{where} must be a number, got {value!r}")
        if not math.isfinite(value):  # NaN passes every comparison a range check makes: refused here, once for all
            raise ConfigError(f"{where} must be a finite number, got {value!r}")
        return float(value)
    if hint is str:
        if value is None:  # YAML's empty value, and --set KEY= on the command line
            raise ConfigError(f"{where} must be a string, got nothing (for an empty string write {where.split('.')[-1]}: '' in YAML, --set 'KEY=\"\"' on the command line)")
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        return value
    if origin is list or hint is list:
        if not isinstance(value, list):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        item = args[0] if args else Any
        return [_convert(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict or hint is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where} must be a mapping, got {value!r}")
        return dict(value)
    return value


def apply_overrides(data: dict[str, Any], overrides: dict[str, Any] | None, where: str = "--set") -> dict[str, Any]:
    """``{"train.epochs": 2}`` into the nested mapping ``data`` (a copy): the one override path of every
    command that takes a config. Applied *before* validation, so an override is checked like the file."""
    import copy

    data = copy.deepcopy(data)
    for dotted, value in (overrides or {}).items():
        node = data
        *parents, leaf = dotted.split(".")
        if not leaf or not all(parents):
            raise ConfigError(f"{where} {dotted!r}: expected KEY or SECTION.KEY")
        for key in parents:
            child = node.setdefault(key, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{where} {dotted!r}: {key} is not a section")
            node = child
        node[leaf] = value
    return data


def load_config(cls: type[T], path: str | Path, overrides: dict[str, Any] | None = None) -> T:
    """A YAML config file with ``--set`` overrides applied, validated once as dataclass ``cls``. Its
    ``task:`` key (which job ``binpick train`` runs it as) is not part of any job's settings."""
    data = apply_overrides(load_yaml(path), overrides)
    data.pop("task", None)
    return from_dict(cls, data, where=Path(path).name)


def load_named(cls: type[T], name: str | Path, folder: Path, builtin: str, what: str) -> T:
    """A config that is named (``builtin``: the class's defaults; another name: ``folder/<name>.yaml``,
    shipped with binpick) or given as the path of a YAML file; anything else is one line listing the names."""
    name = str(name)
    if name == builtin:
        return cls()
    path = folder / f"{name}.yaml" if "/" not in name and not name.endswith((".yaml", ".yml")) else Path(name)
    if not path.is_file():
        known = ", ".join([builtin, *sorted(p.stem for p in folder.glob("*.yaml"))])
        raise ConfigError(f"{what} {name!r} is neither a known {what} ({known}) nor a YAML file")
    return load_config(cls, path)


def ranges_dict(instance: Any) -> dict[str, Any]:
    """A dataclass of ranges as JSON (tuples as lists): what a data set's manifest records."""
    return {item.name: list(v) if isinstance(v := getattr(instance, item.name), tuple) else v
            for item in dataclasses.fields(instance)}


def load_run_config(cls: type[T], run_dir: str | Path) -> T:
    """The validated config a run folder was started with (``run_dir/config.yaml``)."""
    path = Path(run_dir) / "config.yaml"
    data = load_yaml(path)
    data.pop("task", None)  # which job the run is (binpick.core.jobs), not one of its settings
    return from_dict(cls, data, where=str(path))

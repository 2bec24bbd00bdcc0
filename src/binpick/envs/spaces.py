"""Gymnasium spaces as JSON data and back: what a saved policy or a ROS server says about its inputs
and outputs without pickling a Python object (Box, Discrete, and Dicts of them)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from binpick.core.errors import InputFileError

_BIG = 1e30  # ±inf is written as ±1e30: JSON has no infinity
MAX_ELEMENTS = 2**25  # a Box larger than this (a 3000 x 3000 colour image is 27 M) is no policy's input


def describe_space(space: gym.Space) -> dict[str, Any]:
    """A Box, Discrete or Dict of them as JSON-able data (inverse: :func:`build_space`). Bounds that are
    the same everywhere are written once."""
    if isinstance(space, gym.spaces.Dict):
        return {key: describe_space(sub) for key, sub in space.spaces.items()}
    if isinstance(space, gym.spaces.Discrete):
        return {"discrete": int(space.n), "start": int(space.start)}
    if isinstance(space, gym.spaces.Box):
        def bound(values: np.ndarray) -> Any:
            finite = np.nan_to_num(np.asarray(values, dtype=np.float64), posinf=_BIG, neginf=-_BIG)
            return float(finite.flat[0]) if finite.size and np.all(finite == finite.flat[0]) else finite.tolist()

        return {"shape": list(space.shape), "low": bound(space.low), "high": bound(space.high), "dtype": str(space.dtype)}
    raise TypeError(f"only Box, Discrete and Dict spaces can be described, not {type(space).__name__}")


MAX_DEPTH = 8  # Dicts of Dicts deeper than this describe no observation


def values_in(description: Any, depth: int = 0) -> int:
    """How many values a described space holds, all its Boxes together (a Dict of many Boxes each under
    :data:`MAX_ELEMENTS` can still be more than memory holds); too deep a nesting is an error."""
    if depth > MAX_DEPTH:
        raise ValueError(f"Dicts nested deeper than {MAX_DEPTH}")
    if not isinstance(description, dict) or "discrete" in description:
        return 1
    if "shape" in description:
        shape = [int(v) for v in description["shape"]]
        return int(np.prod(shape, dtype=object)) if all(side >= 0 for side in shape) else 0
    return sum(values_in(sub, depth + 1) for sub in description.values())


def build_space(description: Any, where: str = "space", checked: bool = False) -> gym.Space:
    """The space :func:`describe_space` described; anything malformed is one line naming ``where``."""
    try:
        if not checked and values_in(description) > MAX_ELEMENTS:
            raise ValueError(f"its spaces hold more than {MAX_ELEMENTS:,} values together, more than any policy reads")
        if not isinstance(description, dict):
            raise ValueError("not a mapping")
        if "discrete" in description:
            return gym.spaces.Discrete(int(description["discrete"]), start=int(description.get("start", 0)))
        if "shape" in description:
            shape = tuple(int(v) for v in description["shape"])
            if any(side < 0 for side in shape):
                raise ValueError(f"shape {list(shape)} has a negative side")
            if int(np.prod(shape, dtype=object)) > MAX_ELEMENTS:
                raise ValueError(f"shape {list(shape)} holds more than {MAX_ELEMENTS:,} values, more than any policy reads")
            dtype = np.dtype(description["dtype"])
            if dtype.kind not in "fiub":
                raise ValueError(f"dtype {dtype} is not numeric")

            def bound(values: Any) -> np.ndarray:
                array = np.broadcast_to(np.asarray(values, dtype=np.float64), shape).copy()
                array[array <= -_BIG], array[array >= _BIG] = -np.inf, np.inf
                return array

            low, high = bound(description["low"]), bound(description["high"])
            if dtype.kind != "f":
                low, high = np.nan_to_num(low, neginf=np.iinfo(dtype).min), np.nan_to_num(high, posinf=np.iinfo(dtype).max)
            return gym.spaces.Box(low.astype(dtype), high.astype(dtype), shape=shape, dtype=dtype)
        if not description:
            raise ValueError("empty")
        return gym.spaces.Dict({str(key): build_space(sub, f"{where}.{key}", checked=True) for key, sub in description.items()})
    except InputFileError:
        raise
    except (TypeError, ValueError, KeyError, OverflowError, MemoryError) as error:
        raise InputFileError(f"{where} is not a valid space description ({error})") from None

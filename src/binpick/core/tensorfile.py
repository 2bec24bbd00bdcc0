"""Weights and checkpoints that hold no code: tensors in safetensors, everything else in JSON.

A pickle (``torch.save``, ``pickle.dump``, a Stable-Baselines3 zip) can run any code when it is
loaded, and people share weights files. binpick's own formats are therefore one safetensors file:
its tensors, plus a JSON document in the safetensors header that says what the file is
(``binpick_format``) and holds the rest (config, shapes, counters, histories).

:func:`pack` turns a nested structure of dicts, lists, tuples, numbers, strings, tensors and numpy
arrays (a model's and an optimiser's ``state_dict``, say) into flat named tensors and a JSON skeleton;
:func:`unpack` reverses it and accepts nothing else, so reading a file can only ever produce data.

Older ``.pt`` files are read only through :func:`load_legacy_torch`, that is
``torch.load(weights_only=True)``, which refuses anything but tensors and plain containers.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from binpick.core.errors import InputFileError
from binpick.core.files import atomic_write_bytes, read_bytes, require_file

FORMAT_KEY = "binpick_format"
META_KEY = "binpick_meta"
_TENSOR, _ARRAY, _TUPLE, _DICT = "__tensor__", "__ndarray__", "__tuple__", "__dict__"


# ---------------------------------------------------------------------- nested state <-> tensors + JSON
def pack(tree: Any, prefix: str = "") -> tuple[dict[str, torch.Tensor], Any]:
    """``(tensors, skeleton)``: every tensor or array in ``tree`` under a dotted name, and a JSON-able
    skeleton that refers to them. Dict keys may be strings or integers (optimiser states use both)."""
    tensors: dict[str, torch.Tensor] = {}

    def walk(node: Any, name: str) -> Any:
        if isinstance(node, torch.Tensor):
            tensors[name] = node.detach().cpu().contiguous().clone()
            return {_TENSOR: name}
        if isinstance(node, np.ndarray):
            if node.dtype == object:
                raise TypeError(f"{name}: object arrays cannot be stored without pickle")
            tensors[name] = torch.from_numpy(np.ascontiguousarray(node).copy())
            return {_ARRAY: name}
        if isinstance(node, np.generic):
            return node.item()
        if node is None or isinstance(node, (bool, int, float, str)):
            return node
        if isinstance(node, dict):
            items = []
            for key, value in node.items():
                if not isinstance(key, (str, int)) or isinstance(key, bool):
                    raise TypeError(f"{name}: dict keys must be strings or integers, got {type(key).__name__}")
                items.append([key, walk(value, f"{name}.{key}" if name else str(key))])
            return {_DICT: items}
        if isinstance(node, (list, tuple)):
            values = [walk(value, f"{name}.{i}" if name else str(i)) for i, value in enumerate(node)]
            return {_TUPLE: values} if isinstance(node, tuple) else values
        raise TypeError(f"{name or 'state'}: cannot store a {type(node).__name__} without pickle")

    return tensors, walk(tree, prefix)


def unpack(tensors: dict[str, torch.Tensor], skeleton: Any, where: str = "state") -> Any:
    """The structure :func:`pack` took apart; a skeleton that names a missing tensor is one line."""

    def walk(node: Any) -> Any:
        if node is None or isinstance(node, (bool, int, float, str)):
            return node
        if isinstance(node, list):
            return [walk(value) for value in node]
        if isinstance(node, dict) and len(node) == 1:
            (tag, value), = node.items()
            if tag in (_TENSOR, _ARRAY):
                if not isinstance(value, str) or value not in tensors:
                    raise InputFileError(f"{where} is damaged: it refers to a tensor {value!r} it does not hold")
                return tensors[value] if tag == _TENSOR else tensors[value].numpy()
            if tag == _TUPLE and isinstance(value, list):
                return tuple(walk(v) for v in value)
            if tag == _DICT and isinstance(value, list):
                result = {}
                for item in value:
                    if not (isinstance(item, list) and len(item) == 2 and isinstance(item[0], (str, int))):
                        raise InputFileError(f"{where} is damaged: a mapping entry is not a [key, value] pair")
                    result[item[0]] = walk(item[1])
                return result
        raise InputFileError(f"{where} is damaged: unexpected entry {str(node)[:60]!r}")

    return walk(skeleton)


# ---------------------------------------------------------------------- files
def save(path: str | Path, format: str, tensors: dict[str, torch.Tensor] | None = None, meta: dict[str, Any] | None = None,
         state: Any = None) -> Path:
    """Write ``tensors`` (flat) and/or ``state`` (nested, see :func:`pack`) with JSON ``meta`` atomically."""
    from safetensors.torch import save as to_bytes

    flat = {name: t.detach().cpu().contiguous().clone() for name, t in (tensors or {}).items()}
    document: dict[str, Any] = {"meta": meta or {}}
    if state is not None:
        packed, skeleton = pack(state, "state")
        clash = set(packed) & set(flat)
        if clash:
            raise ValueError(f"tensor names used twice: {sorted(clash)[:3]}")
        flat.update(packed)
        document["state"] = skeleton
    header = {FORMAT_KEY: format, META_KEY: json.dumps(document)}
    return atomic_write_bytes(path, to_bytes(flat, metadata=header))


def load(path: str | Path, formats: str | tuple[str, ...], what: str = "file") -> tuple[dict[str, torch.Tensor], dict[str, Any], Any]:
    """``(tensors, meta, state)`` of a file written by :func:`save` in one of ``formats``.

    Anything else — a pickle, a damaged file, another format — is one :class:`InputFileError` line;
    nothing in the file is ever executed."""
    from safetensors import SafetensorError
    from safetensors.torch import load as from_bytes

    path = Path(path)
    formats = (formats,) if isinstance(formats, str) else formats
    data = read_bytes(path, what)
    try:
        tensors = from_bytes(data)
        header = _header(data)
    except (SafetensorError, ValueError, OSError, UnicodeDecodeError, RecursionError, MemoryError) as error:
        detail = str(error).splitlines()[0][:120] if str(error) else type(error).__name__
        raise InputFileError(f"{what} {str(path)!r} is not a safetensors file ({detail})") from None
    metadata = header.get("__metadata__") or {}
    found = metadata.get(FORMAT_KEY)
    if found not in formats:
        kind = f"a {found!r} file" if found else "not a binpick file"
        raise InputFileError(f"{what} {str(path)!r} is {kind}; expected {' or '.join(repr(f) for f in formats)}")
    try:
        document = json.loads(metadata.get(META_KEY, "{}"))
    except (ValueError, RecursionError, TypeError):  # not JSON, nested past reading, a number past converting
        raise InputFileError(f"{what} {str(path)!r} is damaged: its metadata is not valid JSON") from None
    if not isinstance(document, dict) or not isinstance(document.get("meta", {}), dict):
        raise InputFileError(f"{what} {str(path)!r} is damaged: its metadata is not a JSON object")
    state = unpack(tensors, document["state"], f"{what} {str(path)!r}") if "state" in document else None
    return tensors, document.get("meta", {}), state


def _header(data: bytes) -> dict[str, Any]:
    """The JSON header of a safetensors byte string (where its metadata lives)."""
    if len(data) < 8:
        raise ValueError("too short")
    size = int.from_bytes(data[:8], "little")
    if size > len(data) - 8:
        raise ValueError("header larger than the file")
    header = json.loads(data[8:8 + size].decode("utf-8"))
    if not isinstance(header, dict):
        raise ValueError("header is not an object")
    return header


def restore(parts: dict[str, Any], state: dict[str, Any], where: str) -> None:
    """``part.load_state_dict(state[name])`` for each named module or optimiser; a checkpoint of
    another network (missing keys, other shapes) is one line naming ``where``."""
    try:
        for name, part in parts.items():
            part.load_state_dict(state[name])
    except (RuntimeError, ValueError, KeyError) as error:
        raise InputFileError(f"{where} does not fit this run's network ({str(error).splitlines()[0][:120]})") from None


def is_safetensors(path: str | Path) -> bool:
    """Is this a safetensors file: named so, or starting like one (an 8-byte header length, then a
    JSON object)? Decides between :func:`load` and :func:`load_legacy_torch`."""
    if str(path).endswith(".safetensors"):
        return True
    try:
        with open(path, "rb") as handle:
            head = handle.read(9)
    except OSError:
        return True  # let load() report the missing or unreadable file
    return len(head) < 9 or head[8:9] == b"{"


def load_legacy_torch(path: str | Path, what: str = "file") -> Any:
    """An older binpick ``.pt`` file, through ``torch.load(weights_only=True)`` only: tensors and plain
    containers load, anything that would run code (a crafted pickle) is refused in one line."""
    import pickle

    from safetensors import SafetensorError

    path = Path(path)
    require_file(path, what)  # missing / a folder / unreadable: one line, without reading it twice
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        first = str(error).splitlines()[0] if str(error) else ""
        if "Weights only load failed" in first or "Unsupported" in str(error):
            raise InputFileError(f"refusing to load {what} {str(path)!r}: it holds Python objects other than tensors, "
                                 "which could run code when loaded (binpick reads only safetensors, or plain tensors "
                                 "from older .pt files)") from None
        raise InputFileError(f"{what} {str(path)!r} is not a readable weights file ({first[:100]})") from None
    except (RuntimeError, EOFError, ValueError, OSError, KeyError, AttributeError, ImportError, TypeError,
            SafetensorError) as error:
        detail = str(error).splitlines()[0][:100] if str(error) else type(error).__name__
        raise InputFileError(f"{what} {str(path)!r} is not a readable weights file ({detail})") from None

"""Reading and writing files for people: atomic writes, and one clear line when a path is wrong.

Writes go to a unique temporary file beside the target, are flushed to disk (``fsync``) and then
renamed over it, so a crash or ``kill -9`` leaves the previous file or the new one, never half of
one, and two writers never share a temporary name. Reads turn the ways a file can be wrong (missing,
a folder, not UTF-8, not JSON) into an :class:`~binpick.core.errors.InputFileError` that names the file.
"""

from __future__ import annotations

import functools
import json
import os
import stat
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from binpick.core.errors import InputFileError, OutputPathError

if TYPE_CHECKING:
    import numpy as np


def _reason(error: OSError) -> str:
    return error.strerror or type(error).__name__


# ---------------------------------------------------------------------- writing
def ensure_dir(path: str | Path, what: str = "folder") -> Path:
    """Create folder ``path`` (and its parents); a file in the way or no permission is one line."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputPathError(f"{what}: cannot create folder {str(path)!r}: a file with that name exists") from None
    except OSError as error:
        raise OutputPathError(f"{what}: cannot create folder {str(path)!r}: {_reason(error)}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise OutputPathError(f"{what}: folder {str(path)!r} is not writable")
    return path


def check_output_file(path: str | Path, what: str = "output") -> Path:
    """Check *before* long work starts that ``path`` can be written: not a folder, parent creatable."""
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{what}: {str(path)!r} is a folder, not a file")
    ensure_dir(path.parent if str(path.parent) else Path("."), what)
    if path.exists() and not os.access(path, os.W_OK):
        raise OutputPathError(f"{what}: {str(path)!r} is not writable")
    return path


def atomic_write(path: str | Path, write: Callable[[IO[bytes]], None]) -> Path:
    """Call ``write(handle)`` on a temporary file, fsync it and rename it to ``path``."""
    path = Path(path)
    ensure_dir(path.parent, f"writing {path.name}")
    try:
        descriptor, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as error:
        raise OutputPathError(f"cannot write {str(path)!r}: {_reason(error)}") from None
    try:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except OSError as error:
        Path(temporary).unlink(missing_ok=True)
        if isinstance(error, IsADirectoryError) or path.is_dir():
            raise OutputPathError(f"cannot write {str(path)!r}: it is a folder") from None
        raise OutputPathError(f"cannot write {str(path)!r}: {_reason(error)}") from None
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)
    return path


def fsync_dir(folder: Path) -> None:
    """Make a rename durable: fsync the folder that holds the renamed entry (POSIX)."""
    try:
        descriptor = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(descriptor)
    except OSError:
        pass
    finally:
        os.close(descriptor)


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    return atomic_write(path, lambda handle: handle.write(data))


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, data: Any, indent: int | None = 2) -> Path:
    return atomic_write_text(path, json.dumps(data, indent=indent))


def cache_folder(name: str) -> Path:
    """binpick's cache folder ``name`` ($XDG_CACHE_HOME/binpick/NAME, ~/.cache without it, the temporary
    folder without a home): what binpick can make again, kept so that it is made once."""
    try:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    except RuntimeError:  # no home directory (a service account)
        root = Path(tempfile.gettempdir())
    return root / "binpick" / name


# ---------------------------------------------------------------------- reading
MAX_FILE_BYTES = 2 << 30  # 2 GiB: no file binpick reads whole is larger (data sets are read file by file)
MAX_IMAGE_PIXELS = 80_000_000  # decoded pixels: 10000 x 8000 (below PIL's own bomb warning, 89 million)


def require_file(path: str | Path, what: str = "file", max_bytes: int = MAX_FILE_BYTES) -> Path:
    """``path`` if it is a readable regular file of at most ``max_bytes``; missing, a folder, a FIFO
    or device (reading one can block for ever), too large or unreadable is one line (nothing is read)."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InputFileError(f"{what} {str(path)!r} does not exist") from None
    except OSError as error:
        raise InputFileError(f"cannot read {what} {str(path)!r}: {_reason(error)}") from None
    if stat.S_ISDIR(info.st_mode):
        raise InputFileError(f"{what} {str(path)!r} is a folder, not a file")
    if not stat.S_ISREG(info.st_mode):
        raise InputFileError(f"{what} {str(path)!r} is not a regular file (a FIFO, device or socket): give a file")
    if info.st_size > max_bytes:
        raise InputFileError(f"{what} {str(path)!r} is {info.st_size / 2**20:.0f} MiB, more than binpick reads "
                             f"({max_bytes / 2**20:.0f} MiB)")
    if not os.access(path, os.R_OK):
        raise InputFileError(f"cannot read {what} {str(path)!r}: permission denied")
    return path


def inside(root: str | Path, name: Any, what: str = "file") -> Path:
    """``root / name`` for a file name a data set, record or run gives, refused in one line if it
    would leave ``root`` (an absolute name, ``..``, or a symbolic link pointing out): a data set only
    ever reads and names its own files."""
    if not isinstance(name, str) or not name or "\x00" in name:
        raise InputFileError(f"{what} name {str(name)[:80]!r} must be a non-empty path inside {str(root)!r}")
    base = _resolved(str(root))
    target = (base / name).resolve()
    if not target.is_relative_to(base):
        raise InputFileError(f"{what} {name[:120]!r} lies outside {str(root)!r} (or is a link that leads out of it): "
                             "a data set names only its own files")
    return base / name


@functools.lru_cache(maxsize=64)
def _resolved(root: str) -> Path:
    return Path(root).resolve()


@contextmanager
def opened_image(path: str | Path, what: str = "image", max_pixels: int = MAX_IMAGE_PIXELS) -> Iterator[Any]:
    """A PIL image of a regular file, its size checked from the header before any pixel is decoded
    (a decompression bomb is refused, not decoded); failures while opening or decoding inside the
    ``with`` are one line naming the file."""
    import warnings

    from PIL import Image

    from binpick.core.errors import BinpickError

    path = require_file(path, what)
    try:
        with warnings.catch_warnings():  # only while the header is read: PIL warns past its own limit
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            image = Image.open(path)
        with image:
            width, height = image.size
            if width * height > max_pixels:
                raise InputFileError(f"{what} {str(path)!r} is {width}x{height} pixels ({width * height / 1e6:.0f} "
                                     f"megapixels), more than binpick decodes ({max_pixels / 1e6:.0f})")
            yield image
    except BinpickError:
        raise
    except (Image.DecompressionBombWarning, Image.DecompressionBombError):  # PIL's own guard, past its larger limit
        raise InputFileError(f"{what} {str(path)!r} declares more pixels than binpick decodes "
                             f"({max_pixels / 1e6:.0f} megapixels): a decompression bomb or a damaged file") from None
    except (OSError, ValueError, SyntaxError, EOFError, IndexError, TypeError, MemoryError) as error:
        detail = str(error).splitlines()[0][:100] if str(error) else type(error).__name__
        raise InputFileError(f"cannot read {what} {str(path)!r}: {detail}") from None


def read_bytes(path: str | Path, what: str = "file", max_bytes: int = MAX_FILE_BYTES) -> bytes:
    path = Path(path)
    if path.exists():
        require_file(path, what, max_bytes)  # no FIFO, device or oversized file is opened
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise InputFileError(f"{what} {str(path)!r} does not exist") from None
    except IsADirectoryError:
        raise InputFileError(f"{what} {str(path)!r} is a folder, not a file") from None
    except OSError as error:
        raise InputFileError(f"cannot read {what} {str(path)!r}: {_reason(error)}") from None


def read_text(path: str | Path, what: str = "file") -> str:
    """UTF-8 text; anything else is one line naming the file and the first bad byte."""
    data = read_bytes(path, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise InputFileError(f"{what} {str(path)!r} is not UTF-8 text (byte 0x{data[error.start]:02x} "
                             f"at position {error.start})") from None


def read_json(path: str | Path, what: str = "JSON file") -> Any:
    text = read_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise InputFileError(f"{what} {str(path)!r} is not valid JSON ({error.msg} at line {error.lineno})") from None
    except RecursionError:
        raise InputFileError(f"{what} {str(path)!r} nests too deeply to be a binpick file") from None
    except ValueError as error:  # e.g. a number of more digits than Python converts
        raise InputFileError(f"{what} {str(path)!r} is not valid JSON ({str(error)[:80]})") from None


MAX_YAML_NODES = 1_000_000  # values after aliases are expanded: far above any config, far below a bomb
MAX_YAML_DEPTH = 64  # nesting levels: configs nest three or four


def parse_yaml(text: str, where: str) -> Any:
    """YAML as binpick reads it everywhere (configs, ``--set`` values, camera.yaml, products files):
    safe (no tags that build objects), a key twice in one mapping refused, aliases that would expand
    past ``MAX_YAML_NODES`` values (a "billion laughs") or nesting past ``MAX_YAML_DEPTH`` levels
    refused before anything is built. Every failure is one ``InputFileError`` line naming ``where``."""
    import yaml

    loader = _strict_loader()(text)
    try:
        node = loader.get_single_node()  # parsed once: checked as composed, then built from the same nodes
        if node is None:
            return None
        _check_expansion(node, where)
        return loader.construct_document(node)
    except _DuplicateKey as duplicate:
        raise InputFileError(f"{where}: key {duplicate.key!r} appears twice in one mapping (line {duplicate.line})") from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = str(getattr(error, "problem", None) or str(error).splitlines()[0])
        if "flow level" in problem or "depth" in problem:
            raise InputFileError(f"{where} nests too deeply to be a binpick file") from None
        raise InputFileError(f"{where}: invalid YAML{at}: {problem[:120]}") from None
    except RecursionError:
        raise InputFileError(f"{where} nests too deeply to be a binpick file") from None
    except ValueError as error:  # a number of more digits than Python converts
        raise InputFileError(f"{where}: a value cannot be read ({str(error)[:80]})") from None
    finally:
        loader.dispose()


class _DuplicateKey(Exception):
    def __init__(self, key: str, line: int) -> None:
        super().__init__(key)
        self.key, self.line = key, line


@functools.cache
def _strict_loader():
    """libyaml's safe loader where present (10x faster), refusing a key given twice in one mapping."""
    import yaml

    base = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

    class StrictLoader(base):  # type: ignore[valid-type, misc]
        def construct_mapping(self, node, deep=False):
            seen: set = set()
            for key_node, _ in node.value:
                if isinstance(key_node, yaml.ScalarNode) and key_node.tag != "tag:yaml.org,2002:merge":
                    key = (type(value := self.construct_object(key_node)).__name__, value)  # yes/true alike, 1 and "1" not
                    if key in seen:
                        raise _DuplicateKey(key_node.value, key_node.start_mark.line + 1)
                    seen.add(key)
            return super().construct_mapping(node, deep)

    return StrictLoader


def _check_expansion(root, where: str) -> None:
    """Values and depth of a composed YAML document as it would be built, aliases expanded (each
    node counted once per reference, computed once per node: linear in the file's size)."""
    import yaml

    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    open_nodes: set[int] = set()  # entered, not yet sized: meeting one again is a cycle
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if key in size:
            continue
        children = ([n for pair in node.value for n in pair] if isinstance(node, yaml.MappingNode)
                    else list(node.value) if isinstance(node, yaml.SequenceNode) else [])
        if not done:
            if key in open_nodes:
                raise InputFileError(f"{where}: a value contains itself through an alias")
            open_nodes.add(key)
            stack.append((node, True))
            stack.extend((child, False) for child in children if id(child) not in size)
            continue
        open_nodes.discard(key)
        size[key] = 1 + sum(size.get(id(child), 0) for child in children)
        depth[key] = 1 + max((depth.get(id(child), 0) for child in children), default=0)
        if size[key] > MAX_YAML_NODES:
            raise InputFileError(f"{where}: its aliases expand to more than {MAX_YAML_NODES:,} values "
                                 "(a YAML bomb?): binpick reads files without them")
        if depth[key] > MAX_YAML_DEPTH:
            raise InputFileError(f"{where} nests too deeply to be a binpick file (over {MAX_YAML_DEPTH} levels)")


def read_yaml(path: str | Path, what: str = "YAML file") -> Any:
    """A YAML file read through :func:`parse_yaml` (a regular file, UTF-8, bounded)."""
    return parse_yaml(read_text(path, what), f"{what} {str(path)!r}")


def read_npz(path: str | Path, what: str = "array file") -> dict[str, Any]:
    """Arrays of an ``.npz`` file, read with ``allow_pickle=False``: object arrays are refused, so
    nothing in the file can run code."""
    import zipfile

    import numpy as np

    path = Path(path)
    if not path.is_file():  # (FIFOs and devices are not files: nothing blocks)
        raise InputFileError(f"{what} {str(path)!r} does not exist")
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError, MemoryError) as error:
        detail = str(error).splitlines()[0][:100] if str(error) else type(error).__name__
        raise InputFileError(f"{what} {str(path)!r} is not a readable npz file ({detail})") from None


def read_json_object(path: str | Path, what: str, keys: dict[str, type | tuple[type, ...]] | None = None) -> dict[str, Any]:
    """A JSON mapping that must hold ``keys`` of the given types (a damaged file is one line)."""
    data = read_json(path, what)
    if not isinstance(data, dict):
        raise InputFileError(f"{what} {str(path)!r} is damaged: expected a JSON object, got {type(data).__name__}")
    require_fields(data, keys or {}, f"{what} {str(path)!r}")
    return data


def require_fields(data: dict[str, Any], keys: dict[str, type | tuple[type, ...]], where: str) -> dict[str, Any]:
    """Check that ``data`` holds each key with a value of the given type(s); one line if not."""
    for key, kind in keys.items():
        if key not in data:
            raise InputFileError(f"{where} is damaged: it has no {key!r}")
        value = data[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if isinstance(value, bool) and bool not in kinds:
            ok = False
        else:
            ok = isinstance(value, kinds)
        if not ok:
            names = " or ".join(k.__name__ for k in kinds)
            raise InputFileError(f"{where} is damaged: {key!r} must be {names}, got {type(value).__name__}")
    return data


def read_image(path: str | Path, keep_alpha: bool = False, what: str = "image") -> np.ndarray:
    """RGB uint8 (H, W, 3), or RGBA where the file has transparency and ``keep_alpha``; an
    unreadable or empty file is one clear line."""
    import numpy as np

    with opened_image(path, what) as image:
        alpha = keep_alpha and (image.mode in ("RGBA", "LA", "PA") or "transparency" in image.info)
        array = np.asarray(image.convert("RGBA" if alpha else "RGB"))
    if array.size == 0 or min(array.shape[:2]) < 8:
        raise InputFileError(f"image {str(path)!r} is empty or smaller than 8 pixels")
    return array

"""Load and save cubes (``.npy`` / ``.npz``) and detection results (tracks as JSON).

Cubes follow the package convention ``(T, H, W)`` or ``(B, T, H, W)`` (``T`` scans, ``H`` rows
``y``, ``W`` columns ``x``) and are checked with :func:`hocnet._check.as_cube` on load and save.

Every write is atomic: the data go to a temporary file in the target's directory, which is then
renamed over the target (``os.replace``), so a failed write leaves neither a half-written file nor
the temporary file behind, and an existing file is only replaced by a complete one.

Tracks are written as::

    {"meta": {...}, "tracks": [{"id": 1, "score": 3.2, "points": [[t, y, x], ...]}, ...]}

with one track per line.

Real sensor frames (a folder or glob of PNG / BMP / TIFF images, or a ``.npy`` / ``.npz`` with a
named array) are read by :func:`load_frames` (defined in :mod:`hocnet.data.frames`, re-exported
here): see there for the order (natural sort of the file names) and dtype rules (no rescaling;
colour converted to grey with a warning).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import uuid
import zipfile
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np
import torch

from hocnet._check import as_cube, check_int, check_number, restore_batch
from hocnet.data.frames import load_frames

__all__ = ["load_cube", "load_frames", "load_tracks_json", "save_cube", "save_tracks_json"]

_CUBE_SUFFIXES = (".npy", ".npz")


def _check_path(path: Any) -> Path:
    if isinstance(path, bytes) or not isinstance(path, str | os.PathLike):
        raise TypeError(f"`path`: expected a str or os.PathLike, got {type(path).__name__}")
    return Path(path)


def _cube_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _CUBE_SUFFIXES:
        raise ValueError(f"`path`: expected a .npy or .npz file, got '{path}'")
    return suffix


def _atomic_write(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Call ``write`` on a temporary file next to ``path``, then rename it to ``path``."""
    directory = path.parent
    if not directory.is_dir():
        raise FileNotFoundError(f"`path`: directory '{directory}' of '{path}' does not exist")
    if path.is_dir():
        raise ValueError(f"`path`: expected a file name, got the directory '{path}'")
    tmp = directory / f".{path.name}.{uuid.uuid4().hex}.tmp"
    try:
        # O_EXCL: never clobber anything; mode 0o666 lets the umask decide like a plain open().
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as err:
        raise _write_error(path, err) from None
    try:
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except OSError as err:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise _write_error(path, err) from None
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


# numpy reports a short write (a full disk) as "163840 requested and 159616 written", no errno
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written")


def is_disk_full(err: BaseException) -> bool:
    """Whether an ``OSError`` means the disk is full (``ENOSPC``, ``EDQUOT`` or a short write).

    Examples:
        >>> is_disk_full(OSError(errno.ENOSPC, "No space left on device"))
        True
        >>> is_disk_full(OSError("163840 requested and 159616 written"))
        True
        >>> is_disk_full(PermissionError(errno.EACCES, "Permission denied"))
        False
    """
    if not isinstance(err, OSError):
        return False
    codes = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)}
    return err.errno in codes or bool(_SHORT_WRITE.search(str(err)))


def _write_error(path: Path, err: OSError) -> OSError:
    """An ``OSError`` naming the user's ``path`` (never the temporary file) and the cause."""
    if is_disk_full(err):
        reason, code = "no space left on device", errno.ENOSPC
    else:
        reason, code = (err.strerror or str(err) or type(err).__name__), err.errno
    new = type(err)(f"`path`: could not write '{path}': {reason}")
    new.errno = code
    return new


def load_cube(
    path: str | os.PathLike, *, key: str | None = None, binary: bool = False
) -> torch.Tensor:
    """Load a cube of scans from a ``.npy`` or ``.npz`` file.

    Args:
        path: the file; its extension (``.npy`` or ``.npz``) selects the format.
        key: for ``.npz``: the array to load. ``None`` loads the only array of the archive.
        binary: require 0/1 values and return a ``bool`` cube.

    Returns:
        The cube as stored, ``(T, H, W)`` or ``(B, T, H, W)``: its own dtype (unsigned integer
        types wider than 8 bits become ``int64``; values above ``2**63 - 1`` are refused, never
        wrapped to negative numbers), or ``bool`` if ``binary``.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        TypeError: if ``path`` or ``key`` has the wrong type.
        ValueError: wrong extension, a file that is not a valid .npy / .npz (such as a text
            file; pickled objects are never loaded), missing or ambiguous ``key`` (the message
            lists the archive's keys), wrong rank, NaN/inf, unsigned values that do not fit in
            int64, or non-binary values with ``binary=True``. Every message names the path.

    Examples:
        >>> import tempfile, pathlib
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> save_cube(folder / "scene.npz", torch.zeros(3, 4, 5, dtype=torch.bool))
        >>> load_cube(folder / "scene.npz", binary=True).shape
        torch.Size([3, 4, 5])
    """
    p = _check_path(path)
    suffix = _cube_suffix(p)
    if key is not None and not isinstance(key, str):
        raise TypeError(f"`key`: expected a str or None, got {type(key).__name__}")
    if key is not None and suffix == ".npy":
        raise ValueError(f"`key`: expected None for the .npy file '{p}', got {key!r}")
    if not p.is_file():
        raise FileNotFoundError(f"`path`: no such file '{p}'")
    readable = (OSError, ValueError, EOFError, zipfile.BadZipFile)
    try:
        with open(p, "rb") as handle:
            magic = handle.read(6)
    except PermissionError:
        raise
    except OSError as err:
        raise ValueError(f"`path`: could not read '{p}': {err.strerror or err}") from None
    if not magic.startswith((_NPY_MAGIC, _ZIP_MAGIC)):
        kind = "a valid .npy file" if suffix == ".npy" else "a valid .npz archive"
        raise ValueError(
            f"`path`: '{p}' is not {kind} (it does not start with the {suffix} signature); "
            "save arrays with numpy.save / numpy.savez or hocnet.data.save_cube"
        )
    try:
        loaded = np.load(p, allow_pickle=False)
    except readable as err:
        if isinstance(err, PermissionError):
            raise
        raise ValueError(f"`path`: could not read '{p}' as {suffix}: {_why(err)}") from None
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            if suffix == ".npy":
                raise ValueError(f"`path`: expected a .npy array in '{p}', got a .npz archive")
            key = _pick_key(p, loaded.files, key)
            try:
                array = loaded[key]
            except readable as err:
                raise ValueError(
                    f"`path`: could not read {key!r} from '{p}': {_why(err)}"
                ) from None
    elif suffix == ".npz":
        raise ValueError(f"`path`: expected a .npz archive in '{p}', got a .npy array")
    else:
        array = loaded
    if not isinstance(array, np.ndarray):
        raise ValueError(f"`path`: expected an array in '{p}', got {type(array).__name__}")
    if not array.dtype.isnative:
        array = array.astype(array.dtype.newbyteorder("="))
    if array.dtype.kind == "u" and array.dtype.itemsize > 1:
        top = int(array.max()) if array.size else 0
        if top > np.iinfo(np.int64).max:
            raise ValueError(
                f"`path`: '{p}' holds {array.dtype} values up to {top}, above the int64 range "
                f"(<= {np.iinfo(np.int64).max}); rescale the data or save it as float64"
            )
        array = array.astype(np.int64)
    try:
        cube, batched = as_cube("cube", torch.as_tensor(array), binary=binary)
    except (TypeError, ValueError, RuntimeError) as err:
        raise ValueError(f"`path`: '{p}' does not hold a valid cube: {err}") from None
    return restore_batch(cube, batched)


_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = b"PK"


def _why(err: BaseException) -> str:
    """Why numpy failed to load a file, without its advice to load pickled data unsafely."""
    text = str(err)
    if "pickle" in text.lower():
        return "it holds Python objects (pickled data), which hocnet never loads"
    return text or type(err).__name__


def _pick_key(path: Path, keys: list[str], key: str | None) -> str:
    listing = ", ".join(repr(k) for k in keys) or "none"
    if key is None:
        if len(keys) != 1:
            raise ValueError(
                f"`key`: expected one of {listing} for '{path}' (it holds {len(keys)} arrays), "
                "got None"
            )
        return keys[0]
    if key not in keys:
        raise ValueError(f"`key`: expected one of {listing} for '{path}', got {key!r}")
    return key


def save_cube(path: str | os.PathLike, cube: Any, *, key: str = "cube") -> None:
    """Save a cube to ``.npy`` or ``.npz`` (compressed), atomically.

    Args:
        path: target file; the extension selects the format. Its directory must exist.
        cube: ``(T, H, W)`` or ``(B, T, H, W)`` tensor or array (``bool``, integer or float,
            finite). It is stored with its shape and dtype (``bfloat16`` as ``float32``).
        key: name of the array inside a ``.npz`` archive.

    Raises:
        TypeError: if ``path``, ``cube`` or ``key`` has the wrong type.
        ValueError: wrong extension, wrong rank, NaN/inf.
        FileNotFoundError: if the directory of ``path`` does not exist.
        OSError: if the write fails; the message names ``path`` (never the temporary file) and
            says "no space left on device" when the disk is full.

    Examples:
        >>> import tempfile, pathlib
        >>> target = pathlib.Path(tempfile.mkdtemp()) / "cube.npy"
        >>> save_cube(target, torch.ones(2, 3, 3))
        >>> load_cube(target).sum().item()
        18.0
    """
    p = _check_path(path)
    suffix = _cube_suffix(p)
    if not isinstance(key, str) or not key:
        raise TypeError(f"`key`: expected a non-empty str, got {key!r}")
    checked, batched = as_cube("cube", cube)
    tensor = restore_batch(checked, batched).detach().cpu()
    if tensor.dtype == torch.bfloat16:
        tensor = tensor.float()
    array = tensor.numpy()

    def write(handle: IO[bytes]) -> None:
        if suffix == ".npy":
            np.save(handle, array, allow_pickle=False)
        else:
            np.savez_compressed(handle, **{key: array})

    _atomic_write(p, write)


def _json_default(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.tolist()
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, set | frozenset):
        return sorted(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _points_list(name: str, points: Any) -> list[list[int]]:
    try:
        tensor = torch.as_tensor(points)
    except (TypeError, ValueError, RuntimeError):
        raise TypeError(
            f"`{name}`: expected an (N, 3) integer tensor, got {type(points).__name__}"
        ) from None
    if tensor.numel() == 0:
        return []
    if tensor.dim() != 2 or tensor.shape[1] != 3:
        raise ValueError(
            f"`{name}`: expected shape (N, 3) rows (t, y, x), got {tuple(tensor.shape)}"
        )
    if tensor.dtype == torch.bool or tensor.is_complex():
        raise TypeError(f"`{name}`: expected integer coordinates, got dtype {tensor.dtype}")
    if tensor.is_floating_point():
        if not bool(torch.isfinite(tensor).all()) or bool((tensor != tensor.round()).any()):
            raise ValueError(f"`{name}`: expected integer coordinates, got non-integer values")
    return tensor.to(torch.int64).tolist()


def _field(track: Any, name: str) -> Any:
    if isinstance(track, Mapping):
        return track[name]
    return getattr(track, name)


def save_tracks_json(path: str | os.PathLike, tracks: Iterable[Any], **meta: Any) -> None:
    """Save tracks and metadata to a JSON file, atomically.

    Args:
        path: target file (conventionally ``.json``); its directory must exist.
        tracks: objects with ``.points`` (``(N, 3)`` integer tensor of ``(t, y, x)`` rows), ``.id``
            (int) and ``.score`` (finite float), or mappings with those keys (such as the dicts
            returned by :func:`load_tracks_json`).
        **meta: JSON-serialisable metadata stored under ``"meta"`` (tensors, numpy values and
            paths are converted).

    Raises:
        TypeError: a track lacks a field or a value has the wrong type, or ``meta`` is not
            JSON-serialisable.
        ValueError: bad point shapes, non-integer points, non-finite scores or NaN in ``meta``.
        FileNotFoundError: if the directory of ``path`` does not exist.

    Examples:
        >>> import tempfile, pathlib
        >>> from types import SimpleNamespace
        >>> target = pathlib.Path(tempfile.mkdtemp()) / "tracks.json"
        >>> track = SimpleNamespace(id=1, score=3.25, points=torch.tensor([[0, 5, 7], [1, 5, 8]]))
        >>> save_tracks_json(target, [track], method="hoc")
        >>> print(target.read_text(), end="")
        {
          "meta": {"method": "hoc"},
          "tracks": [
            {"id": 1, "score": 3.25, "points": [[0, 5, 7], [1, 5, 8]]}
          ]
        }
    """
    p = _check_path(path)
    if isinstance(tracks, str | bytes | Mapping) or not isinstance(tracks, Iterable):
        raise TypeError(f"`tracks`: expected a sequence of tracks, got {type(tracks).__name__}")
    lines = []
    for i, track in enumerate(tracks):
        try:
            raw_points, raw_id, raw_score = (_field(track, f) for f in ("points", "id", "score"))
        except (AttributeError, KeyError, TypeError):
            raise TypeError(
                f"`tracks[{i}]`: expected an object with .points, .id and .score, "
                f"got {type(track).__name__}"
            ) from None
        entry = {
            "id": check_int(f"tracks[{i}].id", raw_id),
            "score": check_number(f"tracks[{i}].score", raw_score),
            "points": _points_list(f"tracks[{i}].points", raw_points),
        }
        lines.append(json.dumps(entry))
    for name, value in meta.items():
        try:
            json.dumps(value, default=_json_default, allow_nan=False)
        except (TypeError, ValueError) as err:
            kind = ValueError if isinstance(err, ValueError) else TypeError
            raise kind(f"`meta[{name!r}]`: expected a JSON-serialisable value, got {err}") from None
    meta_text = json.dumps(meta, default=_json_default, allow_nan=False)
    body = ",\n    ".join(lines)
    tracks_text = f"[\n    {body}\n  ]" if lines else "[]"
    text = f'{{\n  "meta": {meta_text},\n  "tracks": {tracks_text}\n}}\n'
    _atomic_write(p, lambda handle: handle.write(text.encode("utf-8")))


def load_tracks_json(
    path: str | os.PathLike, *, return_meta: bool = False
) -> list[dict[str, Any]] | tuple[list[dict[str, Any]], dict[str, Any]]:
    """Load tracks written by :func:`save_tracks_json`.

    Args:
        path: the JSON file.
        return_meta: also return the ``"meta"`` dictionary.

    Returns:
        A list of dicts ``{"id": int, "score": float, "points": (N, 3) int64 tensor of (t, y, x)}``
        in file order, or ``(tracks, meta)`` if ``return_meta``.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if the file is not valid JSON or not in the tracks format (naming the path).

    Examples:
        >>> import tempfile, pathlib
        >>> target = pathlib.Path(tempfile.mkdtemp()) / "tracks.json"
        >>> save_tracks_json(target, [{"id": 2, "score": 1.5, "points": [[3, 4, 5]]}], v=4)
        >>> tracks, meta = load_tracks_json(target, return_meta=True)
        >>> tracks[0]["id"], tracks[0]["points"].tolist(), meta
        (2, [[3, 4, 5]], {'v': 4})
    """
    p = _check_path(path)
    if not p.is_file():
        raise FileNotFoundError(f"`path`: no such file '{p}'")
    try:
        document = json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"`path`: '{p}' is not valid JSON: {err}") from None

    def bad(what: str) -> ValueError:
        return ValueError(f"`path`: expected {what} in '{p}'")

    if not isinstance(document, dict) or not isinstance(document.get("tracks"), list):
        raise bad('a JSON object with a "tracks" list')
    meta = document.get("meta", {})
    if not isinstance(meta, dict):
        raise bad('"meta" to be an object')
    out = []
    for i, entry in enumerate(document["tracks"]):
        if not isinstance(entry, dict) or not {"id", "score", "points"} <= entry.keys():
            raise bad(f'track {i} to be an object with "id", "score" and "points"')
        track_id, score, points = entry["id"], entry["score"], entry["points"]
        if isinstance(track_id, bool) or not isinstance(track_id, int):
            raise bad(f'an integer "id" for track {i}, got {track_id!r}')
        if isinstance(score, bool) or not isinstance(score, int | float):
            raise bad(f'a number "score" for track {i}, got {score!r}')
        rows_ok = isinstance(points, list) and all(
            isinstance(row, list)
            and len(row) == 3
            and all(isinstance(c, int) and not isinstance(c, bool) for c in row)
            for row in points
        )
        if not rows_ok:
            raise bad(f'"points" of track {i} to be a list of [t, y, x] integer rows')
        try:
            tensor = torch.tensor(points, dtype=torch.int64).reshape(-1, 3)
        except (OverflowError, RuntimeError, ValueError):
            raise bad(f'"points" of track {i} to fit in int64') from None
        out.append({"id": track_id, "score": float(score), "points": tensor})
    return (out, meta) if return_meta else out

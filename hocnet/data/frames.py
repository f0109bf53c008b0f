"""Load real sensor frames: a folder or glob of images, a ``.npy`` cube or a ``.npz`` array.

Images are decoded by Pillow (no decoder of our own). Rules:

* **Sources.** A folder: every regular, non-hidden file in it must be an image (``.png``,
  ``.bmp``, ``.tif``, ``.tiff``; other files are an error naming the file, so nothing is skipped
  silently); a glob pattern (``"clip/frame_*.png"``): every match must be such an image; one
  image file: its frames (a multi-page TIFF gives several); a ``.npy`` file: a ``(T, H, W)``
  array; a ``.npz`` file: the array ``key`` (``None``: the archive's only array).
* **Order.** Image files are sorted by *natural* order of their names: runs of digits compare as
  numbers, the rest as text, case-insensitively (``frame2`` before ``frame10``); exact ties fall
  back to the plain name. With zero-padded numbers (recommended: ``frame_0001.png``) natural and
  lexicographic order agree.
* **Values.** Pixel values are not rescaled: 8-bit frames hold 0-255, 16-bit frames 0-65535
  (Pillow modes ``L``, ``I;16*``, ``I``, ``F`` and ``1`` keep their values). Colour frames
  (``RGB``, ``RGBA``, ``P``, ``LA``, ...) are converted to grey with Pillow's ``convert("L")``
  (ITU-R 601-2 luma, ``L = 0.299 R + 0.587 G + 0.114 B``) and a ``UserWarning`` says so. Every
  frame must have the same size and the same bit depth.
* The result is a new ``(T, H, W)`` tensor of ``dtype``; the source files are only read.
"""

from __future__ import annotations

import glob
import os
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hocnet._check import as_cube

__all__ = ["IMAGE_SUFFIXES", "frame_files", "load_frames", "natural_key"]

IMAGE_SUFFIXES = (".png", ".bmp", ".tif", ".tiff")
"""File name endings read as image frames (case-insensitive)."""

_GREY_MODES = {"L", "1", "I;16", "I;16B", "I;16L", "I;16N", "I", "F"}
_GLOB_CHARS = re.compile(r"[*?\[]")


def natural_key(name: str) -> tuple[Any, ...]:
    """Sort key of the natural order: digit runs as numbers, text case-insensitively.

    Examples:
        >>> sorted(["f10.png", "f2.png", "F1.png"], key=natural_key)
        ['F1.png', 'f2.png', 'f10.png']
    """
    parts = re.split(r"(\d+)", name)
    key = tuple((0, int(p), "") if p.isdigit() else (1, 0, p.lower()) for p in parts if p)
    return (key, name)


def _is_image(path: Path) -> bool:
    return path.suffix.lower() in IMAGE_SUFFIXES


def _image_files(source: str, path: Path | None) -> list[Path]:
    if path is not None and path.is_dir():
        files = sorted(
            (p for p in path.iterdir() if p.is_file() and not p.name.startswith(".")),
            key=lambda p: natural_key(p.name),
        )
        if not files:
            raise ValueError(
                f"`source`: expected a folder with image frames, got an empty folder {source}"
            )
    else:
        matches = [Path(p) for p in glob.glob(source)]
        files = sorted((p for p in matches if p.is_file()), key=lambda p: natural_key(p.name))
        if not files:
            raise ValueError(f"`source`: expected a pattern matching image files, got {source!r}")
    for p in files:
        if not _is_image(p):
            raise ValueError(
                f"`source`: expected only image frames ({', '.join(IMAGE_SUFFIXES)}) in "
                f"{source}, got the file {p.name}"
            )
    return files


def frame_files(source: str | os.PathLike) -> list[Path]:
    """The image files :func:`load_frames` reads from a folder, a glob or one image, in order.

    Args:
        source: a folder, a glob pattern or an image file (for a ``.npy`` / ``.npz``: ``[]``).

    Returns:
        The files in natural order of their names.

    Raises:
        ValueError: as :func:`load_frames` (empty folder, a non-image file in it, no match).
        FileNotFoundError: ``source`` is neither a path nor a pattern.

    Examples:
        >>> import tempfile, pathlib
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> for name in ("f10.png", "f2.png"):
        ...     _ = (folder / name).write_bytes(b"")
        >>> [p.name for p in frame_files(folder)]
        ['f2.png', 'f10.png']
    """
    text = os.fspath(source)
    path = Path(text)
    if path.is_dir():
        return _image_files(text, path)
    if path.is_file():
        return [path] if _is_image(path) else []
    if _GLOB_CHARS.search(text):
        return _image_files(text, None)
    raise FileNotFoundError(f"`source`: expected an existing file or folder, got {text}")


def _decode(file: Path, source: str) -> tuple[list[np.ndarray], bool]:
    """Frames of one image file as numpy arrays, and whether a colour frame was converted."""
    from PIL import Image, ImageSequence, UnidentifiedImageError

    out: list[np.ndarray] = []
    colour = False
    try:
        with Image.open(file) as image:
            for page in ImageSequence.Iterator(image):
                if page.mode not in _GREY_MODES:
                    page = page.convert("L")
                    colour = True
                array = np.array(page)
                if array.dtype == np.bool_:
                    array = array.astype(np.uint8)
                array = array.astype(array.dtype.newbyteorder("="), copy=False)
                out.append(array)
    except UnidentifiedImageError:
        raise ValueError(
            f"`source`: expected image frames in {source}, got {file.name} which is not a "
            "readable image"
        ) from None
    except (OSError, ValueError, SyntaxError) as exc:
        raise ValueError(
            f"`source`: expected readable image frames in {source}, got {file.name} ({exc})"
        ) from None
    return out, colour


def _from_images(files: list[Path], source: str) -> np.ndarray:
    frames: list[np.ndarray] = []
    first: tuple[Path, tuple[int, ...], np.dtype] | None = None
    converted: list[str] = []
    for file in files:
        pages, colour = _decode(file, source)
        if colour:
            converted.append(file.name)
        for array in pages:
            if array.ndim != 2:
                raise ValueError(
                    f"`source`: expected single-channel frames in {source}, got shape "
                    f"{array.shape} in {file.name}"
                )
            if first is None:
                first = (file, array.shape, array.dtype)
            elif array.shape != first[1]:
                raise ValueError(
                    f"`source`: expected frames of one size in {source}, got {array.shape[0]} x "
                    f"{array.shape[1]} in {file.name} and {first[1][0]} x {first[1][1]} in "
                    f"{first[0].name}"
                )
            elif array.dtype != first[2]:
                raise ValueError(
                    f"`source`: expected frames of one bit depth in {source}, got {array.dtype} "
                    f"in {file.name} and {first[2]} in {first[0].name}"
                )
            frames.append(array)
    if converted:
        shown = ", ".join(converted[:3]) + (" ..." if len(converted) > 3 else "")
        warnings.warn(
            f"load_frames: {len(converted)} colour frame(s) of {source} converted to grey "
            f"(Pillow convert('L'), L = 0.299 R + 0.587 G + 0.114 B): {shown}",
            UserWarning,
            stacklevel=3,
        )
    return np.stack(frames)


def _from_array_file(path: Path, source: str, key: str | None) -> np.ndarray:
    try:
        loaded = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(
            f"`source`: expected a readable .npy/.npz file, got {source} ({exc})"
        ) from None
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            names = list(loaded.files)
            if key is None:
                if len(names) != 1:
                    raise ValueError(
                        f"`key`: expected the name of the array in {source} (one of {names}), "
                        "got None"
                    )
                key = names[0]
            if key not in names:
                raise ValueError(f"`key`: expected one of {names} in {source}, got {key!r}")
            try:
                return np.array(loaded[key])
            except ValueError as exc:
                raise ValueError(
                    f"`source`: could not read {key!r} from {source} ({exc})"
                ) from None
    if key is not None:
        raise ValueError(f"`key`: expected None for a .npy file ({source}), got {key!r}")
    return np.array(loaded)


def load_frames(
    source: str | os.PathLike,
    *,
    key: str | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """Load a clip of frames as a ``(T, H, W)`` tensor.

    See the module docstring for the accepted sources, the order of image files (natural, by
    name) and the value rules (no rescaling; colour to grey with a warning).

    Args:
        source: a folder of images, a glob pattern, one image file, a ``.npy`` or a ``.npz``.
        key: the array of a ``.npz`` (``None``: its only array); must be ``None`` otherwise.
        dtype: dtype of the result (default float32; values are not rescaled).

    Returns:
        ``(T, H, W)`` tensor of ``dtype``.

    Raises:
        FileNotFoundError: ``source`` is neither an existing path nor a pattern with a match.
        TypeError: ``source`` is not a path, or the array is not numeric.
        ValueError: empty folder, non-image or unreadable file, mixed sizes or bit depths,
            wrong ``key``, an array that is not ``(T, H, W)``, NaN/inf; the message names
            ``source`` and the offending file.

    Examples:
        >>> import tempfile, pathlib
        >>> from PIL import Image
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> for i in (1, 2, 10):
        ...     Image.fromarray(np.full((4, 6), i, np.uint8)).save(folder / f"f{i}.png")
        >>> frames = load_frames(folder)
        >>> frames.shape, frames[:, 0, 0].tolist()
        (torch.Size([3, 4, 6]), [1.0, 2.0, 10.0])
    """
    if not isinstance(source, str | os.PathLike):
        raise TypeError(f"`source`: expected a path or glob pattern, got {type(source).__name__}")
    if not isinstance(dtype, torch.dtype):
        raise TypeError(f"`dtype`: expected a torch.dtype, got {type(dtype).__name__}")
    text = os.fspath(source)
    path = Path(text)
    if path.is_dir():
        if key is not None:
            raise ValueError(f"`key`: expected None for a folder of images ({text}), got {key!r}")
        array = _from_images(_image_files(text, path), text)
    elif path.is_file():
        suffix = path.suffix.lower()
        if suffix in (".npy", ".npz"):
            array = _from_array_file(path, text, key)
        elif _is_image(path):
            if key is not None:
                raise ValueError(f"`key`: expected None for an image file ({text}), got {key!r}")
            array = _from_images([path], text)
        else:
            raise ValueError(
                f"`source`: expected a folder, glob, image ({', '.join(IMAGE_SUFFIXES)}), .npy "
                f"or .npz, got the file {text}"
            )
    elif _GLOB_CHARS.search(text):
        if key is not None:
            raise ValueError(f"`key`: expected None for a glob of images ({text}), got {key!r}")
        array = _from_images(_image_files(text, None), text)
    else:
        raise FileNotFoundError(f"`source`: expected an existing file or folder, got {text}")
    if array.dtype.kind == "u" and array.dtype.itemsize > 1:
        array = array.astype(np.int64)  # torch supports only uint8 among unsigned dtypes
    elif array.dtype.kind in "iuf":
        array = array.astype(array.dtype.newbyteorder("="), copy=False)
    if array.dtype.kind not in "biuf":
        raise TypeError(f"`source`: expected numeric frames in {text}, got dtype {array.dtype}")
    if array.ndim != 3:
        raise ValueError(
            f"`source`: expected frames of shape (T, H, W) in {text}, got {tuple(array.shape)}"
        )
    cube, _ = as_cube("source", torch.from_numpy(np.ascontiguousarray(array)))
    return cube[0].to(dtype)

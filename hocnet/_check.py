"""The one input-validation helper of hocnet.

Every public function validates its arguments through these helpers. Each raises ``TypeError`` or
``ValueError`` with a one-line message of the form ``"`name`: expected ..., got ..."`` so that a
user (and the command line, which prints the message and exits with code 2) can see at once which
argument was wrong, what was expected and what was received.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch

__all__ = [
    "as_cube",
    "check_choice",
    "check_finite",
    "check_int",
    "check_number",
    "check_seed",
    "restore_batch",
]


def _describe(value: Any) -> str:
    """Short description of a value for error messages."""
    if isinstance(value, torch.Tensor):
        return f"tensor of shape {tuple(value.shape)} and dtype {value.dtype}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_int(
    name: str, value: Any, *, minimum: int | None = None, maximum: int | None = None
) -> int:
    """Validate an integer argument and return it as ``int``.

    Args:
        name: argument name used in the error message.
        value: the value to check (``bool`` is rejected).
        minimum: smallest allowed value (inclusive), or ``None``.
        maximum: largest allowed value (inclusive), or ``None``.

    Returns:
        The value as a Python ``int``.

    Raises:
        TypeError: if ``value`` is not an integer.
        ValueError: if it is out of range.

    Examples:
        >>> check_int("order", 2, minimum=1)
        2
    """
    if isinstance(value, bool) or not isinstance(value, int | torch.SymInt):
        if isinstance(value, torch.Tensor) and value.numel() == 1 and not value.is_floating_point():
            value = int(value.item())
        elif hasattr(value, "__index__") and not isinstance(value, bool):
            value = int(value.__index__())
        else:
            raise TypeError(f"`{name}`: expected an integer, got {_describe(value)}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ValueError(f"`{name}`: expected an integer >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise ValueError(f"`{name}`: expected an integer <= {maximum}, got {value}")
    return value


def check_number(
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
) -> float:
    """Validate a finite real number, optionally inside an interval, and return it as ``float``.

    Args:
        name: argument name used in the error message.
        value: the value to check.
        low: lower bound or ``None``.
        high: upper bound or ``None``.
        low_inclusive: whether ``low`` itself is allowed.
        high_inclusive: whether ``high`` itself is allowed.

    Returns:
        The value as a Python ``float``.

    Raises:
        TypeError: if ``value`` is not a real number.
        ValueError: if it is NaN, infinite or out of range.

    Examples:
        >>> check_number("delta", 0.5, low=0.0, high=3.2, low_inclusive=False)
        0.5
    """
    if isinstance(value, torch.Tensor) and value.numel() == 1:
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, int | float):
        try:
            value = float(value)  # numpy scalars
        except (TypeError, ValueError):
            raise TypeError(f"`{name}`: expected a real number, got {_describe(value)}") from None
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"`{name}`: expected a finite number, got {value}")
    lo_ok = low is None or (value >= low if low_inclusive else value > low)
    hi_ok = high is None or (value <= high if high_inclusive else value < high)
    if not (lo_ok and hi_ok):
        left = "-inf" if low is None else f"{low:g}"
        right = "inf" if high is None else f"{high:g}"
        interval = (
            ("[" if low_inclusive and low is not None else "(")
            + f"{left}, {right}"
            + ("]" if high_inclusive and high is not None else ")")
        )
        raise ValueError(f"`{name}`: expected a number in {interval}, got {value:g}")
    return value


def check_choice(name: str, value: Any, choices: Sequence[str]) -> str:
    """Validate that ``value`` is one of ``choices``.

    Examples:
        >>> check_choice("direction", "forward", ("forward", "backward"))
        'forward'
    """
    if not isinstance(value, str) or value not in choices:
        options = ", ".join(repr(c) for c in choices)
        raise ValueError(f"`{name}`: expected one of {options}, got {_describe(value)}")
    return value


#: Largest seed ``torch.Generator.manual_seed`` accepts (an unsigned 64-bit integer).
MAX_SEED = 2**64 - 1


def check_seed(name: str, seed: Any) -> int | None:
    """Validate a seed: ``None`` or an integer in ``[0, 2**64 - 1]``.

    The upper bound is that of ``torch.Generator.manual_seed``; a larger seed would otherwise fail
    inside torch with an overflow message that does not name the argument.

    Raises:
        TypeError: if ``seed`` is not an integer.
        ValueError: if it is negative or larger than ``2**64 - 1``.

    Examples:
        >>> check_seed("seed", 3)
        3
        >>> check_seed("seed", 2**70)
        Traceback (most recent call last):
        ...
        ValueError: `seed`: expected an integer <= 18446744073709551615, got 1180591620717411303424
    """
    if seed is None:
        return None
    return check_int(name, seed, minimum=0, maximum=MAX_SEED)


def check_finite(name: str, tensor: torch.Tensor) -> torch.Tensor:
    """Raise ``ValueError`` if a floating tensor holds NaN or infinity.

    Examples:
        >>> check_finite("frames", torch.zeros(2, 3)).shape
        torch.Size([2, 3])
    """
    if tensor.is_floating_point() and tensor.numel() and not bool(torch.isfinite(tensor).all()):
        bad = int((~torch.isfinite(tensor)).sum())
        raise ValueError(f"`{name}`: expected finite values, got {bad} NaN/inf entries")
    return tensor


def as_cube(
    name: str,
    value: Any,
    *,
    binary: bool = False,
    min_frames: int = 1,
    dtype: torch.dtype | None = None,
) -> tuple[torch.Tensor, bool]:
    """Validate a cube of scans and return it batched as ``(B, T, H, W)``.

    Accepts a tensor or array of shape ``(T, H, W)`` (returned with a leading batch axis and
    ``batched=False``) or ``(B, T, H, W)``.

    Args:
        name: argument name used in error messages.
        value: ``torch.Tensor`` or anything ``torch.as_tensor`` accepts (numpy arrays).
        binary: require values in {0, 1} (``bool`` or 0/1 numbers).
        min_frames: smallest allowed ``T``.
        dtype: convert to this dtype after validation (``None`` keeps the dtype, except that
            binary cubes are returned as ``bool``).

    Returns:
        ``(cube, batched)``: the ``(B, T, H, W)`` tensor and whether the input had a batch axis.

    Raises:
        TypeError: if the value is not array-like or has a non-numeric dtype.
        ValueError: wrong rank, empty spatial size, too few frames, NaN/inf, non-binary values.

    Examples:
        >>> cube, batched = as_cube("frames", torch.zeros(5, 8, 8), binary=True)
        >>> cube.shape, cube.dtype, batched
        (torch.Size([1, 5, 8, 8]), torch.bool, False)
    """
    if not isinstance(value, torch.Tensor):
        try:
            value = torch.as_tensor(value)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`{name}`: expected a tensor or array of shape (T, H, W) or (B, T, H, W), "
                f"got {type(value).__name__}"
            ) from None
    if value.dtype in _WIDE_UNSIGNED:
        value = _unsigned_to_int64(name, value)
    if value.is_complex() or not (value.is_floating_point() or value.dtype in _INT_DTYPES):
        raise TypeError(f"`{name}`: expected a real or boolean tensor, got dtype {value.dtype}")
    if value.dim() not in (3, 4):
        raise ValueError(
            f"`{name}`: expected shape (T, H, W) or (B, T, H, W), got {tuple(value.shape)}"
        )
    batched = value.dim() == 4
    cube = value if batched else value.unsqueeze(0)
    _, t, h, w = cube.shape
    if h < 1 or w < 1:
        raise ValueError(f"`{name}`: expected non-empty frames, got shape {tuple(value.shape)}")
    if t < min_frames:
        frames = "frame" if min_frames == 1 else "frames"
        raise ValueError(f"`{name}`: expected at least {min_frames} {frames} (T), got {t}")
    check_finite(name, cube)
    if binary:
        if cube.dtype != torch.bool:
            bad = (cube != 0) & (cube != 1)
            if bool(bad.any()):
                example = cube[bad][0].item()
                raise ValueError(
                    f"`{name}`: expected binary values (0/1 or bool), got {int(bad.sum())} "
                    f"other values such as {example:g}"
                )
            cube = cube != 0
        if dtype is not None:
            cube = cube.to(dtype)
    elif dtype is not None:
        cube = cube.to(dtype)
    return cube, batched


_INT_DTYPES = (
    torch.bool,
    torch.uint8,
    torch.int8,
    torch.int16,
    torch.int32,
    torch.int64,
)


_WIDE_UNSIGNED = (torch.uint16, torch.uint32, torch.uint64)

_INT64_MAX = 2**63 - 1


def _unsigned_to_int64(name: str, value: torch.Tensor) -> torch.Tensor:
    """Convert a uint16/32/64 tensor to int64, refusing values above ``2**63 - 1``.

    torch has few kernels for the wide unsigned dtypes, and a plain cast of a uint64 above
    ``2**63 - 1`` wraps to a negative number, so such values are refused, not converted.
    """
    if value.dtype == torch.uint64 and value.numel():
        # no comparison kernels for uint64: test the sign bit of the int64 view instead
        as_signed = value.view(torch.int64)
        if bool((as_signed < 0).any()):
            n_big = int((as_signed < 0).sum())
            raise ValueError(
                f"`{name}`: expected integer values that fit in int64 (<= {_INT64_MAX}), got "
                f"{n_big} uint64 values above it; rescale or convert the data to float64 first"
            )
        return as_signed.clone()
    return value.to(torch.int64)


def restore_batch(tensor: torch.Tensor, batched: bool) -> torch.Tensor:
    """Drop the leading batch axis added by :func:`as_cube` when the input was unbatched.

    Examples:
        >>> restore_batch(torch.zeros(1, 2, 3, 3), False).shape
        torch.Size([2, 3, 3])
    """
    return tensor if batched else tensor[0]

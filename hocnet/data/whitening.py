"""Background removal ("whitening") by anti-mean and anti-median ring filters [NR08].

[NR08] whitens each frame by subtracting from every pixel a local background estimate taken from
the pixels around it: the mean (anti-mean) or the median (anti-median) of a *ring*. The ring is
the ``outer x outer`` window centred on the pixel minus the ``inner x inner`` guard window, also
centred on the pixel, which keeps the pixel itself and the spread of a point target's PSF out of
the background estimate. Defaults: ``outer=7``, ``inner=3`` (a 40-pixel ring of width 2 around
a 3x3 guard).

Conventions:

* **Borders** are handled by reflection padding without repeating the edge pixel
  (``torch.nn.functional.pad(..., mode="reflect")``, numpy's ``"reflect"``: ``x[-1] = x[1]``),
  so the ring of a border pixel is mirrored into the frame; nothing wraps around. The window
  must fit into the frame: ``outer <= H`` and ``outer <= W``.
* **Median.** The ring always has an even number of pixels (``outer**2 - inner**2`` with both
  odd); the median is the *lower* of the two middle values (``torch.median``'s convention), not
  their average.
* Frames are ``(B, T, H, W)`` or ``(T, H, W)``; each frame is filtered independently and the
  output has the input's shape. Floating inputs keep their dtype, integer or boolean inputs are
  converted to float32. NaN/inf input is an error, and so are finite values so large that the
  filter overflows the dtype (such as 3e38 in float32): the error says so and names ``frames``,
  instead of handing on infinities that a later check would report as NaN/inf input.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from hocnet._check import as_cube, check_int, restore_batch

__all__ = ["AntiMean", "AntiMedian", "anti_mean", "anti_median", "get_ring_kernel"]

# Largest number of gathered ring values held at once by the anti-median (float elements).
_MEDIAN_CHUNK = 1 << 23


def _check_ring(outer: Any, inner: Any) -> tuple[int, int]:
    outer = check_int("outer", outer, minimum=3)
    if outer % 2 == 0:
        raise ValueError(f"`outer`: expected an odd integer, got {outer}")
    inner = check_int("inner", inner, minimum=1)
    if inner % 2 == 0:
        raise ValueError(f"`inner`: expected an odd integer, got {inner}")
    if inner >= outer:
        raise ValueError(f"`inner`: expected an integer < outer ({outer}), got {inner}")
    return outer, inner


def get_ring_kernel(
    outer: int = 7,
    inner: int = 3,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    """Ring-averaging kernel: ``1 / count`` on the ring, 0 on the guard window.

    The ring is the ``outer x outer`` window minus its centred ``inner x inner`` guard window;
    ``count = outer**2 - inner**2``, so the kernel sums to 1.

    Args:
        outer: odd outer window width, >= 3.
        inner: odd guard window width, ``1 <= inner < outer``.
        device: device of the kernel.
        dtype: dtype of the kernel (default: the default float dtype).

    Returns:
        Tensor of shape ``(outer, outer)``.

    Raises:
        TypeError: if a size is not an integer.
        ValueError: if a size is even or ``inner >= outer``.

    Examples:
        >>> get_ring_kernel(3, 1) * 8
        tensor([[1., 1., 1.],
                [1., 0., 1.],
                [1., 1., 1.]])
    """
    outer, inner = _check_ring(outer, inner)
    kernel = torch.ones(outer, outer, device=device, dtype=dtype)
    lo = (outer - inner) // 2
    kernel[lo : lo + inner, lo : lo + inner] = 0
    return kernel / (outer * outer - inner * inner)


def _prepare(
    frames: Any, kernel: torch.Tensor
) -> tuple[torch.Tensor, tuple[int, int, int, int], bool, int]:
    """Validate frames against a ring kernel.

    Returns:
        ``(padded, shape, batched, r)``: the reflection-padded frames ``(B*T, 1, H+2r, W+2r)``,
        the batched shape ``(B, T, H, W)``, whether the input was batched, and the radius.
    """
    cube, batched = as_cube("frames", frames)
    if not cube.is_floating_point():
        cube = cube.to(torch.float32)
    b, t, h, w = cube.shape
    outer = kernel.shape[-1]
    if outer > h or outer > w:
        raise ValueError(
            f"`outer`: expected a window no larger than the frame ({h} x {w}), got {outer}"
        )
    r = outer // 2
    flat = cube.reshape(b * t, 1, h, w)
    return F.pad(flat, (r, r, r, r), mode="reflect"), (b, t, h, w), batched, r


def _anti_mean(frames: Any, kernel: torch.Tensor) -> torch.Tensor:
    padded, shape, batched, r = _prepare(frames, kernel)
    # Identity minus the ring mean, as one fixed convolution. The weights are rebuilt from the
    # ring's support in the frames' dtype, so a float32 buffer costs no float64 precision.
    ring = kernel.to(padded.device) > 0
    weight = ring.to(padded.dtype) / -ring.sum().to(padded.dtype)
    weight[r, r] += 1.0
    out = F.conv2d(padded, weight[None, None])
    _check_overflow("anti-mean", padded, out)
    return restore_batch(out.reshape(shape), batched)


def _anti_median(frames: Any, kernel: torch.Tensor) -> torch.Tensor:
    padded, shape, batched, r = _prepare(frames, kernel)
    n = padded.shape[0]
    h, w = shape[2], shape[3]
    ring = (kernel.reshape(-1) > 0).nonzero().squeeze(1).to(padded.device)
    median = torch.empty(n, h * w, dtype=padded.dtype, device=padded.device)
    step = max(1, _MEDIAN_CHUNK // (ring.numel() * h * w))
    for start in range(0, n, step):
        patches = F.unfold(padded[start : start + step], kernel.shape[-1])  # (n', k*k, H*W)
        median[start : start + step] = patches.index_select(1, ring).median(dim=1).values
    out = padded[:, 0, r : r + h, r : r + w] - median.reshape(n, h, w)
    _check_overflow("anti-median", padded, out)
    return restore_batch(out.reshape(shape), batched)


def _check_overflow(what: str, frames: torch.Tensor, out: torch.Tensor) -> None:
    """Raise if the (finite) input overflowed the dtype inside the filter."""
    if out.numel() and not bool(torch.isfinite(out).all()):
        largest = float(frames.abs().max())
        limit = torch.finfo(out.dtype).max
        raise ValueError(
            f"`frames`: values too large for {str(out.dtype).replace('torch.', '')} after "
            f"{what} whitening (largest |value| {largest:.3g}, the dtype holds up to "
            f"{limit:.3g}): {int((~torch.isfinite(out)).sum())} whitened values overflowed; "
            "rescale the frames"
        )


def anti_mean(frames: torch.Tensor, outer: int = 7, inner: int = 3) -> torch.Tensor:
    """Anti-mean whitening [NR08]: each pixel minus the mean of its surrounding ring.

    Implemented as one fixed convolution with ``delta - ring`` (the identity minus
    :func:`get_ring_kernel`) on reflection-padded frames.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` intensities.
        outer: odd outer window width, ``3 <= outer <= min(H, W)``.
        inner: odd guard window width, ``1 <= inner < outer``.

    Returns:
        Whitened frames, same shape as ``frames`` (float; float32 for non-float input).

    Raises:
        TypeError: non-numeric frames or non-integer sizes.
        ValueError: wrong rank, NaN/inf, even sizes, ``inner >= outer``, window larger than
            the frame, or values so large that the filter overflows the dtype.

    Examples:
        >>> frames = torch.zeros(2, 9, 9)
        >>> frames[:, 4, 4] = 8.0
        >>> out = anti_mean(frames)
        >>> out.shape, float(out[0, 4, 4])
        (torch.Size([2, 9, 9]), 8.0)
    """
    return _anti_mean(frames, get_ring_kernel(outer, inner))


def anti_median(frames: torch.Tensor, outer: int = 7, inner: int = 3) -> torch.Tensor:
    """Anti-median whitening [NR08]: each pixel minus the (lower) median of its ring.

    The ring values are gathered with ``unfold`` from reflection-padded frames; for the even
    ring size the lower of the two middle values is used (``torch.median``).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` intensities.
        outer: odd outer window width, ``3 <= outer <= min(H, W)``.
        inner: odd guard window width, ``1 <= inner < outer``.

    Returns:
        Whitened frames, same shape as ``frames`` (float; float32 for non-float input).

    Raises:
        TypeError: non-numeric frames or non-integer sizes.
        ValueError: wrong rank, NaN/inf, even sizes, ``inner >= outer``, window larger than
            the frame, or values so large that the filter overflows the dtype.

    Examples:
        >>> frames = torch.ones(3, 8, 8)
        >>> frames[1, 3, 5] = 11.0
        >>> out = anti_median(frames)
        >>> float(out.abs().sum()), float(out[1, 3, 5])
        (10.0, 10.0)
    """
    return _anti_median(frames, get_ring_kernel(outer, inner))


class AntiMean(nn.Module):
    """Anti-mean whitening as a module; see :func:`anti_mean`.

    The ring kernel (:func:`get_ring_kernel`) is registered as the buffer ``kernel``.

    Args:
        outer: odd outer window width, >= 3.
        inner: odd guard window width, ``1 <= inner < outer``.

    Shape:
        - Input: ``(B, T, H, W)`` or ``(T, H, W)``.
        - Output: same as the input.

    Examples:
        >>> AntiMean(5, 1)(torch.randn(2, 4, 16, 16)).shape
        torch.Size([2, 4, 16, 16])
    """

    kernel: torch.Tensor

    def __init__(self, outer: int = 7, inner: int = 3) -> None:
        super().__init__()
        self.outer, self.inner = _check_ring(outer, inner)
        self.register_buffer("kernel", get_ring_kernel(outer, inner))

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """Whiten ``frames`` (see :func:`anti_mean`)."""
        return _anti_mean(frames, self.kernel)

    def extra_repr(self) -> str:
        """Window sizes, shown in the module's repr."""
        return f"outer={self.outer}, inner={self.inner}"


class AntiMedian(nn.Module):
    """Anti-median whitening as a module; see :func:`anti_median`.

    The ring kernel (:func:`get_ring_kernel`) is registered as the buffer ``kernel``; its
    non-zero entries select the ring.

    Args:
        outer: odd outer window width, >= 3.
        inner: odd guard window width, ``1 <= inner < outer``.

    Shape:
        - Input: ``(B, T, H, W)`` or ``(T, H, W)``.
        - Output: same as the input.

    Examples:
        >>> AntiMedian()(torch.randn(4, 16, 16)).shape
        torch.Size([4, 16, 16])
    """

    kernel: torch.Tensor

    def __init__(self, outer: int = 7, inner: int = 3) -> None:
        super().__init__()
        self.outer, self.inner = _check_ring(outer, inner)
        self.register_buffer("kernel", get_ring_kernel(outer, inner))

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """Whiten ``frames`` (see :func:`anti_median`)."""
        return _anti_median(frames, self.kernel)

    def extra_repr(self) -> str:
        """Window sizes, shown in the module's repr."""
        return f"outer={self.outer}, inner={self.inner}"

"""Intensity frames to binary returns by a per-frame CFAR threshold, for the HOC (our addition).

The HOC of [LA98] (R.-J. Liou, M. R. Azimi-Sadjadi, IEEE TAES 34(2), 1998) works on binary
scans: each pixel a detection (1) or not (0). Real sensors give intensities; this module turns
whitened (and background-removed) frames into such scans with a per-frame ordered-statistic
CFAR (constant false-alarm rate) threshold: in every frame the ``n = floor(pfa * H * W)``
highest pixels are kept, i.e. the threshold of frame ``t`` is its ``(n + 1)``-th largest value
``tau_t`` and the return is ``frame > tau_t``. On a frame of clutter alone (what the whitening
aims at) this gives the false-alarm probability ``pfa`` per pixel whatever the clutter's level
and distribution; a target bright enough to be among the ``n`` highest pixels survives.

Our reading: [LA98] assumes binary scans with a given clutter density and says nothing about how
they are made; the ordered statistic is our choice (no noise model needed). Ties at ``tau_t``
are all dropped, so a frame may keep fewer than ``n`` pixels; with ``pfa * H * W < 1`` nothing
is kept.

Frames are ``(B, T, H, W)`` or ``(T, H, W)``; the output has the same shape, dtype ``bool``.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn

from hocnet._check import as_cube, check_number, restore_batch

__all__ = ["CFARBinarize", "cfar_binarize", "cfar_thresholds"]


def _check_pfa(pfa: Any) -> float:
    return check_number("pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False)


def cfar_thresholds(frames: torch.Tensor, pfa: float = 1e-3) -> torch.Tensor:
    """Per-frame CFAR thresholds: the ``(floor(pfa H W) + 1)``-th largest value of each frame.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` real frames (whitened intensities), finite.
        pfa: false-alarm probability per pixel, in ``(0, 1)``.

    Returns:
        ``(B, T)`` or ``(T,)`` thresholds in the frames' float dtype (float32 for integer
        input); ``+inf`` where ``floor(pfa H W) = 0`` (nothing passes).

    Raises:
        TypeError: non-numeric frames or ``pfa``.
        ValueError: wrong rank, NaN/inf, ``pfa`` outside ``(0, 1)``.

    Examples:
        >>> frames = torch.arange(10.0).reshape(1, 2, 5)
        >>> cfar_thresholds(frames, pfa=0.2).tolist()  # keep the 2 highest of 10
        [7.0]
    """
    cube, batched = as_cube("frames", frames, min_frames=0)
    pfa = _check_pfa(pfa)
    if not cube.is_floating_point():
        cube = cube.to(torch.float32)
    b, t, h, w = cube.shape
    n_pixels = h * w
    keep = math.floor(pfa * n_pixels)
    if keep == 0 or b * t == 0:
        out = torch.full((b, t), math.inf, dtype=cube.dtype, device=cube.device)
    else:
        flat = cube.reshape(b * t, n_pixels)
        out = torch.kthvalue(flat, n_pixels - keep, dim=1).values.reshape(b, t)
    return restore_batch(out, batched)


def cfar_binarize(frames: torch.Tensor, pfa: float = 1e-3) -> torch.Tensor:
    """Binary returns ``frame > tau_t`` with the per-frame CFAR thresholds ``tau_t``.

    Apply to whitened frames (after background removal): the threshold is an ordered statistic
    of each frame, so every frame keeps at most ``floor(pfa H W)`` pixels.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` real frames, finite.
        pfa: false-alarm probability per pixel, in ``(0, 1)``.

    Returns:
        ``bool`` cube shaped like ``frames``.

    Raises:
        TypeError: non-numeric frames or ``pfa``.
        ValueError: wrong rank, NaN/inf, ``pfa`` outside ``(0, 1)``.

    Examples:
        >>> frames = torch.zeros(2, 8, 8)
        >>> frames[0, 2, 3] = 5.0
        >>> frames[1, 6, 1] = 4.0
        >>> binary = cfar_binarize(frames, pfa=1 / 64)
        >>> binary.nonzero().tolist()
        [[0, 2, 3], [1, 6, 1]]
    """
    cube, batched = as_cube("frames", frames, min_frames=0)
    if not cube.is_floating_point():
        cube = cube.to(torch.float32)
    tau = cfar_thresholds(cube, pfa)
    return restore_batch(cube > tau[..., None, None], batched)


class CFARBinarize(nn.Module):
    """Per-frame CFAR binarisation as a module; see :func:`cfar_binarize`.

    Args:
        pfa: false-alarm probability per pixel, in ``(0, 1)``.

    Shape:
        - Input: ``(B, T, H, W)`` or ``(T, H, W)`` real frames.
        - Output: ``bool``, same shape.

    Examples:
        >>> CFARBinarize(0.01)(torch.randn(2, 3, 20, 20)).sum(dim=(-2, -1)).tolist()
        [[4, 4, 4], [4, 4, 4]]
    """

    def __init__(self, pfa: float = 1e-3) -> None:
        super().__init__()
        self.pfa = _check_pfa(pfa)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """Binarise ``frames`` (see :func:`cfar_binarize`)."""
        return cfar_binarize(frames, self.pfa)

    def extra_repr(self) -> str:
        """The false-alarm probability, shown in the module's repr."""
        return f"pfa={self.pfa:g}"

"""Pure kernel builders for the (modified) high-order correlation network of [LA98].

A move is ``(i, j) = (dx, dy)`` in pixels per scan, ``|i|, |j| <= v``; the velocity window holds
``M = (2v + 1) ** 2`` moves, enumerated row-major over ``(j, i)``: move index
``m = (j + v) * (2v + 1) + (i + v)``. The zero move has index ``M // 2``.

The turn between two moves is the wrapped absolute difference of their bearings ``atan2(j, i)``
in ``[0, pi]`` (eq. 6 and 9b of [LA98]); a turn involving a zero move is 0 (our reading: the
bearing of a zero move is undefined in eq. 6). A second move ``m2`` is *allowed* after a first
move ``m1`` when ``turn(m1, m2) <= delta + 1e-9`` (modified HOC, eq. 5-6); ``delta=None`` means no
curvature constraint (every pair allowed).

The original HOC of eq. (4) has no second move: its layer correlates two scans through the whole
``(2v + 1) x (2v + 1)`` window, the :func:`get_window_kernel`.

Every builder is pure and takes ``device=`` / ``dtype=``; the layers register the results as
buffers (kornia style).
"""

from __future__ import annotations

import math

import torch

from hocnet._check import check_int, check_number

__all__ = [
    "TURN_TOLERANCE",
    "allowed_moves",
    "get_direction_mask_kernels",
    "get_shift_kernels",
    "get_window_kernel",
    "move_offsets",
    "turn_angles",
]

TURN_TOLERANCE = 1e-9
"""Slack added to ``delta`` when comparing turns, so exact 45-degree turns pass at pi/4."""


def _check_v(v: int) -> int:
    return check_int("v", v, minimum=1)


def _check_delta(delta: float) -> float:
    return check_number("delta", delta, low=0.0, high=math.pi, low_inclusive=False)


def move_offsets(v: int, *, device: torch.device | str | None = None) -> torch.Tensor:
    """All moves of the velocity window.

    Args:
        v: velocity window half-width (moves ``|i|, |j| <= v``).
        device: device of the result.

    Returns:
        ``(M, 2)`` int64 tensor of ``(i, j) = (dx, dy)``, ``M = (2v + 1) ** 2``, row-major over
        ``(j, i)`` so that index ``(j + v) * (2v + 1) + (i + v)`` holds move ``(i, j)``.

    Examples:
        >>> move_offsets(1)[:3].tolist()
        [[-1, -1], [0, -1], [1, -1]]
        >>> move_offsets(4).shape
        torch.Size([81, 2])
    """
    v = _check_v(v)
    r = torch.arange(-v, v + 1, device=device)
    jj, ii = torch.meshgrid(r, r, indexing="ij")
    return torch.stack([ii.reshape(-1), jj.reshape(-1)], dim=1)


def turn_angles(
    first: torch.Tensor, second: torch.Tensor, *, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """Turn angle between moves, wrapped into ``[0, pi]``; 0 when either move is zero.

    Args:
        first: ``(..., 2)`` moves ``(i, j)``.
        second: ``(..., 2)`` moves, broadcastable against ``first``.
        dtype: floating dtype of the computation and the result.

    Returns:
        ``(...)`` turn angles in radians.

    Examples:
        >>> turn_angles(torch.tensor([1, 0]), torch.tensor([1, 1])).item()  # 45 degrees
        0.7853981633974483
        >>> turn_angles(torch.tensor([1, 0]), torch.tensor([0, 0])).item()  # zero move
        0.0
    """
    a = torch.atan2(first[..., 1].to(dtype), first[..., 0].to(dtype))
    b = torch.atan2(second[..., 1].to(dtype), second[..., 0].to(dtype))
    diff = torch.remainder(b - a, 2 * math.pi)
    turn = torch.minimum(diff, 2 * math.pi - diff)
    zero = (first == 0).all(-1) | (second == 0).all(-1)
    return torch.where(zero, torch.zeros_like(turn), turn)


def allowed_moves(
    v: int,
    delta: float | None = math.pi / 4,
    *,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """Table of allowed (first move, second move) pairs.

    Args:
        v: velocity window half-width.
        delta: curvature limit in radians, in ``(0, pi]`` (modified HOC, eq. 5-6), or ``None``
            for no curvature constraint (every pair allowed, like ``delta=pi``).
        device: device of the result.

    Returns:
        ``(M, M)`` bool tensor ``A[m1, m2]``, ``M = (2v + 1) ** 2``.

    Examples:
        >>> a = allowed_moves(4, math.pi / 4)
        >>> moving = torch.arange(81) != 40  # first moves other than the zero move
        >>> a.shape, round(a[moving].float().mean().item(), 3)  # about a quarter of the window
        (torch.Size([81, 81]), 0.284)
        >>> bool(allowed_moves(2, None).all())
        True
    """
    moves = move_offsets(v, device=device)
    if delta is None:
        return torch.ones(moves.shape[0], moves.shape[0], dtype=torch.bool, device=device)
    delta = _check_delta(delta)
    turns = turn_angles(moves[:, None, :], moves[None, :, :])
    return turns <= delta + TURN_TOLERANCE


def get_direction_mask_kernels(
    v: int,
    delta: float | None = math.pi / 4,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """Direction-masked kernels: one per first move, marking its allowed second moves.

    Used as ``conv2d(Y_{t+2}, K, padding=v)``: channel ``m1`` at pixel ``q`` counts the points of
    scan ``t + 2`` at ``q + m2`` over the second moves ``m2`` allowed after ``m1``.

    Args:
        v: velocity window half-width.
        delta: curvature limit (radians) or ``None`` (no curvature constraint).
        device: device of the result.
        dtype: dtype of the result.

    Returns:
        ``(M, 1, 2v + 1, 2v + 1)`` kernel with ``K[m1, 0, v + j2, v + i2] = A[m1, m2]``.

    Examples:
        >>> k = get_direction_mask_kernels(1, math.pi / 4)
        >>> k[5, 0].int().tolist()  # first move (1, 0): second moves within 45 degrees, or zero
        [[0, 0, 1], [0, 1, 1], [0, 0, 1]]
    """
    v = _check_v(v)
    a = allowed_moves(v, delta, device=device)
    side = 2 * v + 1
    return a.to(dtype).reshape(side * side, 1, side, side)


def get_shift_kernels(
    v: int,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """Shift kernels: one one-hot kernel per first move.

    Used as ``conv2d(P, S, padding=v)`` on an ``M``-channel input: the output at ``p`` is
    ``sum_m1 P[m1](p + m1)``, i.e. channel ``m1`` is read one first move ahead.

    Args:
        v: velocity window half-width.
        device: device of the result.
        dtype: dtype of the result.

    Returns:
        ``(1, M, 2v + 1, 2v + 1)`` kernel with ``S[0, m1, v + j1, v + i1] = 1``.

    Examples:
        >>> s = get_shift_kernels(1)
        >>> s.shape, s[0, 5].int().tolist()
        (torch.Size([1, 9, 3, 3]), [[0, 0, 0], [0, 0, 1], [0, 0, 0]])
    """
    v = _check_v(v)
    side = 2 * v + 1
    eye = torch.eye(side * side, device=device, dtype=dtype)
    return eye.reshape(1, side * side, side, side)


def get_window_kernel(
    v: int,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """The velocity-window kernel of the original HOC, eq. (2) and (4) of [LA98].

    Used as ``conv2d(Y_{t+1}, K, padding=v)``: the output at ``p`` is
    ``sum_{|i|, |j| <= v} Y_{t+1}(p + (i, j))``, the inner sum of eq. (4).

    Args:
        v: velocity window half-width.
        device: device of the result.
        dtype: dtype of the result.

    Returns:
        ``(1, 1, 2v + 1, 2v + 1)`` kernel of ones.

    Examples:
        >>> get_window_kernel(1)[0, 0].int().tolist()
        [[1, 1, 1], [1, 1, 1], [1, 1, 1]]
    """
    v = _check_v(v)
    side = 2 * v + 1
    return torch.ones(1, 1, side, side, device=device, dtype=dtype)

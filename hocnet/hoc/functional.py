"""Functional core of the high-order correlation (HOC) networks of [LA98].

Two networks, each with two interchangeable implementations that give bit-identical results:

- **Original HOC, eq. (4)**: a *two-scan* correlation. Each layer keeps a point of ``Y^(k-1)``
  at scan ``t`` when some point of ``Y^(k-1)`` lies in its ``(2v + 1) x (2v + 1)`` velocity
  window at scan ``t + 1``; there is no curvature or velocity-change constraint. Order ``k``
  covers ``k + 1`` scans ("``k + n_max = n_0``", section II)::

      Y^(k)_t = Y^(k-1)_t * g(conv2d(Y^(k-1)_{t+1}, ones((2v + 1, 2v + 1))))

- **Modified HOC, eq. (5)-(6)**: a three-scan correlation with the curvature limit ``delta``.
  Order ``k`` covers ``2k + 1`` scans (Proposition 1). The connectionist layer (Fig. 2)::

      D = g(conv2d(Y_{t+2}, K_mask))          # (M channels) continuation exists after move m1
      S = conv2d(Y_{t+1} * D, K_shift)        # sum over first moves, each read at p + m1
      Y'_t = Y_t * g(S)

``method="conv"`` runs the connectionist network (fixed-weight convolutions, products and hard
limiters; kernels from :mod:`hocnet.hoc.kernels`); ``method="sparse"`` evaluates the same sums
only at the points that are on (neighbour gathers and the allowed-move table for eq. 5-6, a
summed-area table for eq. 4); ``method="auto"`` picks ``"sparse"`` when at most
``SPARSE_DENSITY`` of the pixels are on (always for eq. 4) and the estimated cost allows it.

Forward layers read scans ``t + 1 (, t + 2)``; backward layers (eq. 10) read ``t - 1 (, t - 2)``.
``Y^(k)(t)`` is 0 wherever it cannot be evaluated: forward ``t > T - 1 - 2k`` (modified) or
``t > T - 1 - k`` (original), backward ``t < 2k`` (modified) or ``t < k`` (original). Scans
outside the cube count as empty, as do out-of-image neighbours (zero padding, nothing wraps).

Bounded cost (our addition): a move longer than the frame can never match, so every function
clamps the velocity window to ``v_eff = min(v, max(H, W) - 1)`` (results unchanged); before
allocating, the peak memory and the time of the chosen path are estimated and a
``ValueError`` naming ``v`` is raised when they exceed ``MEMORY_BUDGET`` / ``TIME_BUDGET``;
orders that need more scans than the cube holds answer at once with zeros; the sparse path
processes its points in bounded chunks.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Literal

import torch
import torch.nn.functional as F

from hocnet._check import as_cube, check_choice, check_int, check_number, restore_batch
from hocnet.hoc.kernels import (
    allowed_moves,
    get_direction_mask_kernels,
    get_shift_kernels,
    get_window_kernel,
)

__all__ = [
    "MEMORY_BUDGET",
    "SPARSE_DENSITY",
    "TIME_BUDGET",
    "chain_support",
    "density_bound",
    "density_warning",
    "effective_v",
    "hard_limiter",
    "hoc_layer",
    "hoc_levels",
    "hoc_mark",
    "mhoc_image",
    "modified_hoc",
    "original_hoc",
    "original_hoc_layer",
    "original_hoc_mark",
    "scans_needed",
    "support_from_levels",
]

Direction = Literal["forward", "backward"]
Method = Literal["auto", "conv", "sparse"]
Kind = Literal["modified", "original"]

SPARSE_DENSITY = 0.1
"""``method="auto"`` uses the sparse path when at most this fraction of the pixels is on."""

MEMORY_BUDGET = 1 << 30
"""Largest estimated peak allocation (bytes) of one HOC call; above it a ``ValueError`` names
``v`` (raise it, e.g. ``hocnet.hoc.functional.MEMORY_BUDGET = 8 << 30``, to allow more)."""

TIME_BUDGET = 60.0
"""Largest estimated time (seconds on one CPU core) of one HOC layer; above it a ``ValueError``
names ``v``. Estimates use throughputs measured on the development machine."""

_CHUNK_ELEMENTS = 1 << 24  # cap on (frames x channels x H x W) per convolution call
_SPARSE_CHUNK = 1 << 24  # cap on gathered neighbours (points x moves) per sparse step
_SLOT_CHUNK = 1 << 22  # cap on expanded move pairs per sparse step


def hard_limiter(c: torch.Tensor) -> torch.Tensor:
    """The hard limiter of [LA98] eq. (3): ``g(c) = 1 if c > 0 else 0`` (same dtype as ``c``).

    Examples:
        >>> hard_limiter(torch.tensor([-1.0, 0.0, 0.5, 3.0])).tolist()
        [0.0, 0.0, 1.0, 1.0]
    """
    return (c > 0).to(c.dtype)


def _step(direction: str) -> int:
    return 1 if check_choice("direction", direction, ("forward", "backward")) == "forward" else -1


def _tshift(y: torch.Tensor, s: int) -> torch.Tensor:
    """``z[:, t] = y[:, t + s]`` along dim 1, zero where ``t + s`` is outside ``[0, T)``."""
    if s == 0:
        return y
    n_t = y.shape[1]
    z = torch.zeros_like(y)
    if abs(s) >= n_t:
        return z
    if s > 0:
        z[:, : n_t - s] = y[:, s:]
    else:
        z[:, -s:] = y[:, : n_t + s]
    return z


def _chunks(channels: int, h: int, w: int) -> tuple[int, int]:
    """(frames, channels) per convolution call so that one call holds <= _CHUNK_ELEMENTS."""
    plane = max(1, h * w)
    per_channel = max(1, _CHUNK_ELEMENTS // plane)
    if channels <= per_channel:
        return max(1, per_channel // max(1, channels)), channels
    return 1, per_channel


def effective_v(v: int, h: int, w: int) -> int:
    """The velocity window half-width that can matter on ``h x w`` frames.

    A move ``(i, j)`` joins two pixels of one frame only if ``|i| <= w - 1`` and ``|j| <= h - 1``,
    so every window wider than ``max(h, w) - 1`` gives the same result as that one (the allowed
    move table of eq. 6 depends on the two moves only, not on ``v``). Every HOC function clamps
    ``v`` this way (our addition; results are unchanged).

    Args:
        v: requested half-width (``>= 1``).
        h: frame height.
        w: frame width.

    Returns:
        ``max(1, min(v, max(h, w) - 1))``.

    Examples:
        >>> effective_v(1000, 24, 16), effective_v(4, 480, 640)
        (23, 4)
    """
    v = check_int("v", v, minimum=1)
    return max(1, min(v, max(h, w) - 1))


def _crop_index(side: int, v_eff: int, device: torch.device) -> torch.Tensor:
    """Indices of the moves with ``|i|, |j| <= v_eff`` in the row-major window of ``side``."""
    v = side // 2
    r = torch.arange(v - v_eff, v + v_eff + 1, device=device)
    return (r[:, None] * side + r[None, :]).reshape(-1)


def _crop_modified(
    mask_kernels: torch.Tensor, shift_kernels: torch.Tensor, h: int, w: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Drop the moves longer than the frame: their terms read zero padding only (exact)."""
    m, _, side, _ = mask_kernels.shape
    v = side // 2
    v_eff = min(v, max(h, w) - 1)
    if v_eff >= v or m != side * side or tuple(shift_kernels.shape[1:]) != (m, side, side):
        return mask_kernels, shift_kernels
    idx = _crop_index(side, v_eff, mask_kernels.device)
    lo, hi = v - v_eff, v + v_eff + 1
    return (
        mask_kernels[idx][:, :, lo:hi, lo:hi],
        shift_kernels[:, idx][:, :, lo:hi, lo:hi],
    )


def _crop_window(window_kernel: torch.Tensor, h: int, w: int) -> torch.Tensor:
    side = window_kernel.shape[-1]
    v = side // 2
    v_eff = min(v, max(h, w) - 1)
    if v_eff >= v:
        return window_kernel
    return window_kernel[..., v - v_eff : v + v_eff + 1, v - v_eff : v + v_eff + 1]


def hoc_layer(
    y: torch.Tensor,
    mask_kernels: torch.Tensor,
    shift_kernels: torch.Tensor,
    *,
    direction: Direction = "forward",
    activation: Callable[[torch.Tensor], torch.Tensor] = hard_limiter,
) -> torch.Tensor:
    """One connectionist modified-HOC layer, eq. (5)-(6) (eq. 10 backward): ``Y^(k-1) -> Y^(k)``.

    Memory is bounded: the convolutions run in chunks of frames and of first-move channels, and
    moves longer than the frame are dropped (they only ever read zero padding).

    Args:
        y: ``(B, T, H, W)`` float cube ``Y^(k-1)`` (0/1 for the fixed network).
        mask_kernels: ``(M, 1, 2v + 1, 2v + 1)`` direction-masked kernels, from
            :func:`~hocnet.hoc.kernels.get_direction_mask_kernels` (or learned).
        shift_kernels: ``(1, M, 2v + 1, 2v + 1)`` shift kernels, from
            :func:`~hocnet.hoc.kernels.get_shift_kernels` (or learned).
        direction: ``"forward"`` (scans ``t + 1, t + 2``) or ``"backward"`` (``t - 1, t - 2``).
        activation: the limiter; :func:`hard_limiter` for the paper's network, a smooth
            surrogate when training.

    Returns:
        ``(B, T, H, W)`` cube ``Y^(k)`` of ``y``'s dtype.

    Examples:
        >>> f = torch.zeros(1, 3, 5, 5)
        >>> f[0, 0, 0, 0] = f[0, 1, 1, 1] = f[0, 2, 2, 2] = 1.0  # a diagonal track
        >>> k, s = get_direction_mask_kernels(1), get_shift_kernels(1)
        >>> hoc_layer(f, k, s)[0, :, 0, 0].tolist()
        [1.0, 0.0, 0.0]
    """
    s = _step(direction)
    b, n_t, h, w = y.shape
    mask_kernels, shift_kernels = _crop_modified(mask_kernels, shift_kernels, h, w)
    m, _, side, _ = mask_kernels.shape
    pad = side // 2
    y1 = _tshift(y, s).reshape(b * n_t, 1, h, w)
    y2 = _tshift(y, 2 * s).reshape(b * n_t, 1, h, w)
    out = torch.empty(b * n_t, 1, h, w, dtype=y.dtype, device=y.device)
    f_step, c_step = _chunks(m, h, w)
    for lo in range(0, b * n_t, f_step):
        hi = min(b * n_t, lo + f_step)
        acc = None
        for c0 in range(0, m, c_step):
            c1 = min(m, c0 + c_step)
            cont = activation(F.conv2d(y2[lo:hi], mask_kernels[c0:c1], padding=pad))
            part = F.conv2d(y1[lo:hi] * cont, shift_kernels[:, c0:c1], padding=pad)
            acc = part if acc is None else acc + part
        out[lo:hi] = activation(acc)
    return y * out.reshape(b, n_t, h, w)


def original_hoc_layer(
    y: torch.Tensor,
    window_kernel: torch.Tensor,
    *,
    direction: Direction = "forward",
    activation: Callable[[torch.Tensor], torch.Tensor] = hard_limiter,
) -> torch.Tensor:
    """One connectionist original-HOC layer, eq. (4) of [LA98]: ``Y^(k-1) -> Y^(k)``.

    ``Y^(k)_t(p) = Y^(k-1)_t(p) * g(sum_{|i|, |j| <= v} Y^(k-1)_{t+1}(p + (i, j)))``: a
    fixed-weight convolution of scan ``t + 1`` (``t - 1`` backward) with the window kernel, a
    hard limiter and a product with scan ``t``.

    Args:
        y: ``(B, T, H, W)`` float cube ``Y^(k-1)``.
        window_kernel: ``(1, 1, 2v + 1, 2v + 1)`` kernel, from
            :func:`~hocnet.hoc.kernels.get_window_kernel` (or learned).
        direction: ``"forward"`` (scan ``t + 1``) or ``"backward"`` (scan ``t - 1``).
        activation: the limiter (:func:`hard_limiter` for the paper's network).

    Returns:
        ``(B, T, H, W)`` cube ``Y^(k)`` of ``y``'s dtype.

    Examples:
        >>> f = torch.zeros(1, 3, 5, 5)
        >>> f[0, 0, 0, 0] = f[0, 1, 2, 0] = f[0, 2, 0, 0] = 1.0  # a jagged path: eq. (4) keeps it
        >>> original_hoc_layer(f, get_window_kernel(2))[0, :, 0, 0].tolist()
        [1.0, 0.0, 0.0]
    """
    s = _step(direction)
    b, n_t, h, w = y.shape
    window_kernel = _crop_window(window_kernel, h, w)
    pad = window_kernel.shape[-1] // 2
    y1 = _tshift(y, s).reshape(b * n_t, 1, h, w)
    out = torch.empty(b * n_t, 1, h, w, dtype=y.dtype, device=y.device)
    f_step, _ = _chunks(1, h + 2 * pad, w + 2 * pad)
    for lo in range(0, b * n_t, f_step):
        hi = min(b * n_t, lo + f_step)
        out[lo:hi] = activation(F.conv2d(y1[lo:hi], window_kernel, padding=pad))
    return y * out.reshape(b, n_t, h, w)


def hoc_mark(
    y_prev: torch.Tensor,
    marks: torch.Tensor,
    mask_kernels: torch.Tensor,
    shift_kernels: torch.Tensor,
    *,
    direction: Direction = "forward",
) -> torch.Tensor:
    """Marking pass through one modified-HOC layer: expand accepted points into chain members.

    Our addition (see :func:`chain_support`). The transpose of :func:`hoc_layer`. For every
    marked point ``p0`` at scan ``t`` and every triple ``(p0, p1, p2)`` accepted by the layer
    (all three on in ``y_prev``, move ``m1`` then an allowed move ``m2``), ``p1`` (scan
    ``t + 1``) and ``p2`` (scan ``t + 2``) are marked too (``t - 1``, ``t - 2`` backward). Uses
    the same kernels, transposed::

        p1 marked <=> Y(p1) * g(sum_m1 marks_t(p1 - m1) * g(conv2d(Y_{t+2}, K_mask))_m1(p1))
        p2 marked <=> Y(p2) * g(conv_transpose2d(marks_t(. - m1) * Y_{t+1} * cont, K_mask))

    Args:
        y_prev: ``(B, T, H, W)`` 0/1 float cube ``Y^(l-1)``.
        marks: ``(B, T, H, W)`` 0/1 float cube of marked points at level ``l`` (inside ``Y^(l)``).
        mask_kernels: ``(M, 1, 2v + 1, 2v + 1)`` direction-masked kernels.
        shift_kernels: ``(1, M, 2v + 1, 2v + 1)`` shift kernels.
        direction: ``"forward"`` or ``"backward"``.

    Returns:
        ``(B, T, H, W)`` 0/1 float cube of marks at level ``l - 1`` (``marks`` plus members).
    """
    s = _step(direction)
    b, n_t, h, w = y_prev.shape
    mask_kernels, shift_kernels = _crop_modified(mask_kernels, shift_kernels, h, w)
    m, _, side, _ = mask_kernels.shape
    pad = side // 2
    y1 = _tshift(y_prev, s).reshape(b * n_t, 1, h, w)
    y2 = _tshift(y_prev, 2 * s).reshape(b * n_t, 1, h, w)
    mk = marks.reshape(b * n_t, 1, h, w)
    mark1 = torch.zeros_like(mk)
    mark2 = torch.zeros_like(mk)
    f_step, c_step = _chunks(m, h, w)
    for lo in range(0, b * n_t, f_step):
        hi = min(b * n_t, lo + f_step)
        for c0 in range(0, m, c_step):
            c1 = min(m, c0 + c_step)
            cont = hard_limiter(F.conv2d(y2[lo:hi], mask_kernels[c0:c1], padding=pad))
            # marks(p - m1), one channel per first move
            incoming = F.conv_transpose2d(mk[lo:hi], shift_kernels[:, c0:c1], padding=pad)
            active = incoming * y1[lo:hi] * cont  # p1 reached by move m1 from a mark
            mark1[lo:hi] += active.sum(1, keepdim=True)
            mark2[lo:hi] += F.conv_transpose2d(active, mask_kernels[c0:c1], padding=pad)
    mark1 = _tshift(hard_limiter(mark1).reshape(b, n_t, h, w), -s) * y_prev
    mark2 = _tshift(hard_limiter(mark2).reshape(b, n_t, h, w), -2 * s) * y_prev
    return torch.clamp(marks + mark1 + mark2, max=1.0)


def original_hoc_mark(
    y_prev: torch.Tensor,
    marks: torch.Tensor,
    window_kernel: torch.Tensor,
    *,
    direction: Direction = "forward",
) -> torch.Tensor:
    """Marking pass through one original-HOC layer (eq. 4), our addition.

    The transpose of :func:`original_hoc_layer` (see :func:`chain_support`).

    Every point of ``y_prev`` at scan ``t + 1`` (``t - 1`` backward) inside the window of a
    marked point at scan ``t`` is marked too::

        p1 marked <=> Y(p1) * g(conv_transpose2d(marks_t, K_window)(p1))

    Args:
        y_prev: ``(B, T, H, W)`` 0/1 float cube ``Y^(l-1)``.
        marks: ``(B, T, H, W)`` 0/1 float marks at level ``l`` (inside ``Y^(l)``).
        window_kernel: ``(1, 1, 2v + 1, 2v + 1)`` window kernel.
        direction: ``"forward"`` or ``"backward"``.

    Returns:
        ``(B, T, H, W)`` 0/1 float cube of marks at level ``l - 1``.
    """
    s = _step(direction)
    b, n_t, h, w = y_prev.shape
    window_kernel = _crop_window(window_kernel, h, w)
    pad = window_kernel.shape[-1] // 2
    mk = marks.reshape(b * n_t, 1, h, w)
    reach = torch.empty_like(mk)
    f_step, _ = _chunks(1, h + 2 * pad, w + 2 * pad)
    for lo in range(0, b * n_t, f_step):
        hi = min(b * n_t, lo + f_step)
        reach[lo:hi] = hard_limiter(F.conv_transpose2d(mk[lo:hi], window_kernel, padding=pad))
    mark1 = _tshift(reach.reshape(b, n_t, h, w), -s) * y_prev
    return torch.clamp(marks + mark1, max=1.0)


# ----------------------------------------------------------------------------- sparse fast path


def _index(
    active: torch.Tensor, v: int
) -> tuple[torch.Tensor, tuple[torch.Tensor, ...], torch.Tensor]:
    """On-points of a bool cube: ``(flat, coords, vol)``.

    ``flat`` holds the flat indices of the ``n`` on-points, ``coords`` their ``(b, t, r, x)`` and
    ``vol`` an int32 index volume padded by ``v`` in space and one scan on each side in time
    (``-1`` where off).
    """
    b, n_t, h, w = active.shape
    dev = active.device
    flat = active.reshape(-1).nonzero().squeeze(1)
    n = flat.numel()
    coords = (flat // (w * h * n_t), (flat // (w * h)) % n_t, (flat // w) % h, flat % w)
    vol = torch.full((b, n_t + 2, h + 2 * v, w + 2 * v), -1, dtype=torch.int32, device=dev)
    vol[coords[0], coords[1] + 1, coords[2] + v, coords[3] + v] = torch.arange(
        n, dtype=torch.int32, device=dev
    )
    return flat, coords, vol


def _neighbours(
    ids: torch.Tensor | None,
    coords: tuple[torch.Tensor, ...],
    vol: torch.Tensor,
    v: int,
    s: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """On-neighbours in scan ``t + s`` of the points ``ids`` (point indices, ``None``: all).

    Returns ``(row, dst, move)``: for every neighbour, the position in ``ids`` of the point it
    neighbours (ascending), the neighbour's own point index and the move index ``m``.
    """
    bb, t, r, x = coords if ids is None else (c[ids] for c in coords)
    _, tp, hp, wp = vol.shape
    rng = torch.arange(-v, v + 1, device=vol.device)
    offsets = (rng[:, None] * wp + rng[None, :]).reshape(-1)  # move m = (j + v) * side + (i + v)
    base = ((bb * tp + t + 1 + s) * hp + r + v) * wp + x + v
    nb = vol.reshape(-1)[base[:, None] + offsets[None, :]]  # (n, M) neighbour ids, -1 if none
    row, move = (nb >= 0).nonzero(as_tuple=True)
    return row, nb[row, move].long(), move


def _expand(
    index: tuple[torch.Tensor, tuple[torch.Tensor, ...], torch.Tensor],
    allowed: torch.Tensor,
    v: int,
    s: int,
    ids0: torch.Tensor,
    max_slots: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
    """Accepted triples rooted at the points ``ids0``, by expanding move pairs.

    Returns ``(p0, p1, p2)`` point indices, or ``None`` when more than ``max_slots`` move pairs
    (or ``_SPARSE_CHUNK`` neighbours) would have to be held at once (the caller then takes the
    bounded path).
    """
    flat, coords, vol = index
    n = flat.numel()
    m = allowed.shape[0]
    dev = flat.device
    empty = flat.new_zeros(0)
    row1, mid, move1 = _neighbours(ids0, coords, vol, v, s)
    if mid.numel() == 0:
        return empty, empty, empty
    if ids0.numel() == n:  # every point is a root: one neighbour gather serves both moves
        inv, row2, end, move2, n_mid = mid, row1, mid, move1, n
    else:
        seen = torch.zeros(n, dtype=torch.bool, device=dev)
        seen[mid] = True
        uniq = seen.nonzero().squeeze(1)
        if uniq.numel() * m > _SPARSE_CHUNK:
            return None
        pos = torch.empty(n, dtype=torch.long, device=dev)
        pos[uniq] = torch.arange(uniq.numel(), device=dev)
        inv, n_mid = pos[mid], uniq.numel()
        row2, end, move2 = _neighbours(uniq, coords, vol, v, s)
    counts = torch.bincount(row2, minlength=n_mid)
    starts = torch.cumsum(counts, 0) - counts
    fan = counts[inv]  # second moves available after each first move
    ends = torch.cumsum(fan, 0)
    total = int(ends[-1])
    if max_slots is not None and (total > max_slots or total > 4 * n_mid * m):
        return None  # too many pairs: the matrix-product path is cheaper (dense clutter)
    # expand every first move into its candidate second moves (searchsorted, not
    # repeat_interleave, which is pathologically slow on small inputs with several threads)
    slots = torch.arange(total, device=dev)
    first = torch.searchsorted(ends, slots, right=True)
    within = slots - (ends - fan)[first]
    second = starts[inv[first]] + within
    ok = allowed[move1[first], move2[second]]
    first, second = first[ok], second[ok]
    return ids0[row1[first]], mid[first], end[second]


def _sparse_triples(
    active: torch.Tensor,
    allowed: torch.Tensor,
    v: int,
    s: int,
    roots: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Accepted triples among the on-points of a bool cube, evaluated only at those points.

    Returns every triple, so its output grows with the number of triples (use on sparse cubes).

    Args:
        active: ``(B, T, H, W)`` bool cube.
        allowed: ``(M, M)`` bool table of allowed (first, second) move pairs.
        v: velocity window half-width.
        s: +1 forward, -1 backward.
        roots: optional ``(B, T, H, W)`` bool cube inside ``active``: only triples starting at
            these points are returned (all on-points when ``None``).

    Returns:
        ``(flat, p0, p1, p2)``: ``flat`` is the ``(N,)`` flat index into ``active`` of each
        on-point, ``p0, p1, p2`` index into ``flat`` for every accepted triple.
    """
    index = _index(active, v)
    flat = index[0]
    empty = flat.new_zeros(0)
    if flat.numel() == 0:
        return flat, empty, empty, empty
    if roots is None:
        ids0 = torch.arange(flat.numel(), device=flat.device)
    else:
        ids0 = roots.reshape(-1)[flat].nonzero().squeeze(1)
    p0, p1, p2 = _expand(index, allowed, v, s, ids0)
    return flat, p0, p1, p2


def _move_masks(
    index: tuple[torch.Tensor, tuple[torch.Tensor, ...], torch.Tensor],
    ids: torch.Tensor,
    m: int,
    v: int,
    s: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Next-scan move masks of the points ``ids``.

    Returns ``(mask, row, dst, move)``: ``mask[r, m2] = 1.0`` when point ``ids[r]`` has an
    on-neighbour by move ``m2`` in the next scan, plus the lists of :func:`_neighbours`.
    """
    _, coords, vol = index
    row, dst, move = _neighbours(ids, coords, vol, v, s)
    mask = torch.zeros(ids.numel(), m, dtype=torch.float32, device=ids.device)
    mask[row, move] = 1.0
    return mask, row, dst, move


def _sparse_layer(active: torch.Tensor, allowed: torch.Tensor, v: int, s: int) -> torch.Tensor:
    """One modified-HOC layer on the sparse path: on-points that start an accepted triple.

    Roots are processed in chunks. A chunk whose move pairs are few is expanded pair by pair
    (:func:`_expand`); otherwise (dense clutter) ``cont[p1, m1] = any_m2 allowed[m1, m2] *
    next[p1, m2]`` is computed once by a matrix product per chunk of points and each root looks
    it up along its first moves. Memory stays bounded by ``_SPARSE_CHUNK`` per step plus
    ``N x M`` bools.
    """
    index = _index(active, v)
    flat = index[0]
    n = flat.numel()
    m = allowed.shape[0]
    dev = active.device
    out = torch.zeros(active.numel(), dtype=torch.bool, device=dev)
    if n == 0:
        return out.reshape(active.shape)
    ids_all = torch.arange(n, device=dev)
    step = max(1, _SPARSE_CHUNK // m)
    accepted = torch.zeros(n, dtype=torch.bool, device=dev)
    cont: torch.Tensor | None = None
    for lo in range(0, n, step):
        ids = ids_all[lo : lo + step]
        res = None if cont is not None else _expand(index, allowed, v, s, ids, _SLOT_CHUNK)
        if res is not None:
            accepted[res[0]] = True
            continue
        if cont is None:
            allowed_t = allowed.t().float()
            cont = torch.zeros(n, m, dtype=torch.bool, device=dev)
            for c0 in range(0, n, step):
                mask, _, _, _ = _move_masks(index, ids_all[c0 : c0 + step], m, v, s)
                cont[c0 : c0 + step] = (mask @ allowed_t) > 0
        row, mid, move = _neighbours(ids, index[1], index[2], v, s)
        accepted[ids[row[cont[mid, move]]]] = True
    out[flat[accepted]] = True
    return out.reshape(active.shape)


def _sparse_mark_level(
    below: torch.Tensor, marks: torch.Tensor, allowed: torch.Tensor, v: int, s: int
) -> torch.Tensor:
    """Marks at level ``l - 1`` from marks at level ``l`` (modified HOC, sparse, bounded)."""
    index = _index(below, v)
    flat = index[0]
    n = flat.numel()
    m = allowed.shape[0]
    dev = below.device
    out = marks.clone()
    if n == 0:
        return out
    view = out.view(-1)
    ids0 = marks.reshape(-1)[flat].nonzero().squeeze(1)
    step = max(1, _SPARSE_CHUNK // m)
    rest = []
    for lo in range(0, ids0.numel(), step):
        ids = ids0[lo : lo + step]
        res = _expand(index, allowed, v, s, ids, _SLOT_CHUNK)
        if res is None:
            rest.append(ids)
            continue
        view[flat[res[1]]] = True
        view[flat[res[2]]] = True
    if not rest:
        return out
    # dense chunks: incoming[p1, m1] = a marked root reaches p1 by move m1
    incoming = torch.zeros(n, m, dtype=torch.bool, device=dev)
    for ids in rest:
        _, mid, move = _neighbours(ids, index[1], index[2], v, s)
        incoming[mid, move] = True
    mids = incoming.any(1).nonzero().squeeze(1)
    allowed_f = allowed.float()
    for lo in range(0, mids.numel(), step):
        ids = mids[lo : lo + step]
        inc = incoming[ids]
        mask, row, dst, move = _move_masks(index, ids, m, v, s)
        cont = (mask @ allowed_f.t()) > 0  # [p1, m1]: an allowed continuation exists
        reach = (inc.float() @ allowed_f) > 0  # [p1, m2]: allowed after some incoming m1
        view[flat[ids[(inc & cont).any(1)]]] = True
        view[flat[dst[reach[row, move]]]] = True
    return out


def _sparse_marks(
    levels: list[torch.Tensor], allowed: torch.Tensor, v: int, s: int
) -> torch.Tensor:
    """Marking pass on the sparse path (modified HOC)."""
    marks = levels[-1].clone()
    for level in range(len(levels) - 1, 0, -1):
        if not marks.any():
            break
        marks = _sparse_mark_level(levels[level - 1], marks, allowed, v, s)
    return marks


def _window_counts(cube: torch.Tensor, pts: tuple[torch.Tensor, ...], v: int) -> torch.Tensor:
    """On-pixels of ``cube`` in the ``(2v + 1)^2`` window around each point (summed-area table)."""
    b, n_t, h, w = cube.shape
    sat = torch.zeros(b, n_t, h + 1, w + 1, dtype=torch.int32, device=cube.device)
    sat[:, :, 1:, 1:] = (
        cube.to(torch.int32).cumsum(2, dtype=torch.int32).cumsum(3, dtype=torch.int32)
    )
    bb, t, r, x = pts
    r0, r1 = (r - v).clamp(min=0), (r + v).clamp(max=h - 1) + 1
    x0, x1 = (x - v).clamp(min=0), (x + v).clamp(max=w - 1) + 1
    return sat[bb, t, r1, x1] - sat[bb, t, r0, x1] - sat[bb, t, r1, x0] + sat[bb, t, r0, x0]


def _coords(cube: torch.Tensor) -> tuple[torch.Tensor, ...]:
    return cube.nonzero(as_tuple=True)


def _sparse_original_layer(active: torch.Tensor, v: int, s: int) -> torch.Tensor:
    """Eq. (4) on the sparse path: on-points with an on-point in their window one scan on."""
    pts = _coords(active)
    out = torch.zeros_like(active)
    if pts[0].numel() == 0:
        return out
    keep = _window_counts(_tshift(active, s), pts, v) > 0
    out[tuple(c[keep] for c in pts)] = True
    return out


def _sparse_original_marks(levels: list[torch.Tensor], v: int, s: int) -> torch.Tensor:
    """Marking pass of eq. (4) on the sparse path (window counts of the marks one scan back)."""
    marks = levels[-1].clone()
    for level in range(len(levels) - 1, 0, -1):
        if not marks.any():
            break
        below = levels[level - 1]
        pts = _coords(below & ~marks)
        if pts[0].numel() == 0:
            continue
        keep = _window_counts(_tshift(marks, -s), pts, v) > 0
        marks[tuple(c[keep] for c in pts)] = True
    return marks


# ----------------------------------------------------------------------------- cost planning


@functools.lru_cache(maxsize=64)
def _allowed_cached(v: int, delta: float | None, device: str) -> torch.Tensor:
    """Read-only cached :func:`allowed_moves` table (built once per setting)."""
    return allowed_moves(v, delta, device=device)


def _gib(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:.2g} GiB"


# Throughputs of one CPU core, measured on the 2-core development machine (torch 2, float32):
_CONV_RATE = 2.5e9  # multiply-adds per second of conv2d with M channels
_MATMUL_RATE = 1.5e10  # flops per second of the (N, M) x (M, M) products of the sparse path
_GATHER_RATE = 1e8  # gathered neighbours (or summed-area lookups) per second
_SLOT_RATE = 2e7  # expanded move pairs per second


def _cost(
    path: str, shape: tuple[int, ...], n_on: int, v: int, delta: float | None
) -> tuple[float, float]:
    """Estimated (peak bytes, seconds on one core) of one layer on ``path``."""
    b, n_t, h, w = shape
    frames = b * n_t
    m = (2 * v + 1) ** 2
    cube = frames * h * w
    if delta is None:  # eq. (4): one window kernel, or a summed-area table
        if path == "conv":
            chunk = min(cube, _CHUNK_ELEMENTS) + _CHUNK_ELEMENTS
            return 4.0 * (6 * cube + 2 * chunk), float(cube) * m / _CONV_RATE
        return 4.0 * 2 * cube + 64.0 * n_on + cube, float(cube + n_on) / _GATHER_RATE
    # allowed table (bool + float64 turn angles and temporaries) and the two kernel banks
    tables = 60.0 * m * m
    if path == "conv":
        chunk = min(cube * m, _CHUNK_ELEMENTS)
        return tables + 4.0 * (6 * cube + 4 * chunk), 2.0 * cube * m * m / _CONV_RATE
    vol = 4.0 * b * (n_t + 2) * (h + 2 * v) * (w + 2 * v)
    steps = 24.0 * min(n_on * m, _SPARSE_CHUNK) + 48.0 * min(n_on * m, _SLOT_CHUNK)
    mem = tables + vol + 2.0 * n_on * m + steps + 64.0 * n_on
    density = n_on / max(1, cube)
    pairs = n_on * (m * density) ** 2  # expected move pairs of uniform clutter
    seconds = 3.0 * n_on * m / _GATHER_RATE + min(
        2.0 * n_on * m * m / _MATMUL_RATE, pairs / _SLOT_RATE
    )
    return mem, seconds


def _plan(method: str, cube: torch.Tensor, v: int, delta: float | None) -> str:
    """Resolve ``method`` and check the estimated cost against the budgets (names ``v``).

    ``"auto"`` prefers the sparse path up to ``SPARSE_DENSITY`` (always for eq. 4, whose sparse
    path is a summed-area table) and the conv path above, but takes the other one when the
    preferred path does not fit the budgets or is estimated 4x slower.
    """
    check_choice("method", method, ("auto", "conv", "sparse"))
    shape = tuple(cube.shape)
    n_on = int(cube.sum()) if cube.numel() else 0
    density = n_on / max(1, cube.numel())
    costs = {path: _cost(path, shape, n_on, v, delta) for path in ("conv", "sparse")}
    if method == "auto":
        first = "sparse" if density <= SPARSE_DENSITY or delta is None else "conv"
        other = "conv" if first == "sparse" else "sparse"
        order = (first, other)
        if costs[first][1] > 4 * costs[other][1]:
            order = (other, first)
    else:
        order = (method,)
    for path in order:
        mem, seconds = costs[path]
        if mem <= MEMORY_BUDGET and seconds <= TIME_BUDGET:
            return path
    path = order[0]
    mem, seconds = costs[path]
    _, n_t, h, w = shape
    raise ValueError(
        f"`v`: expected a velocity window small enough for this {n_t} x {h} x {w} cube "
        f"({100 * density:.3g} % on), got v={v} (after clamping to the frame): "
        f"method={path!r} needs about {_gib(mem)} and {seconds:.2g} s per layer "
        f"(budgets: MEMORY_BUDGET = {_gib(MEMORY_BUDGET)}, TIME_BUDGET = {TIME_BUDGET:g} s, "
        "in hocnet.hoc.functional); use a smaller `v` or a sparser cube"
    )


def _resolve_method(method: str, cube: torch.Tensor) -> str:
    """Resolve ``"auto"`` by density alone (kept for callers that only need the path name)."""
    check_choice("method", method, ("auto", "conv", "sparse"))
    if method != "auto":
        return method
    density = float(cube.sum()) / max(1, cube.numel())
    return "sparse" if density <= SPARSE_DENSITY else "conv"


def _check_common(order: int, v: int, delta: float | None) -> tuple[int, int, float | None]:
    order = check_int("order", order, minimum=1)
    v = check_int("v", v, minimum=1)
    if delta is not None:
        delta = check_number("delta", delta, low=0.0, high=math.pi, low_inclusive=False)
    return order, v, delta


def _beyond_scans(cube: torch.Tensor, order: int, delta: float | None, method: str) -> bool:
    """Whether ``Y^(order)`` is 0 by the scan count alone (``T`` below :func:`scans_needed`)."""
    check_choice("method", method, ("auto", "conv", "sparse"))
    kind = "original" if delta is None else "modified"
    return cube.shape[1] < scans_needed(order, kind)


def scans_needed(order: int, kind: Kind = "modified") -> int:
    """Scans spanned by one chain of order ``order``.

    ``2k + 1`` for the modified HOC (eq. 5, Proposition 1 of [LA98]), ``k + 1`` for the original
    HOC (eq. 4, "``k + n_max = n_0``").

    A cube with fewer scans gives ``Y^(k) = 0`` everywhere; the HOC functions then answer at once.

    Examples:
        >>> scans_needed(2), scans_needed(2, "original")
        (5, 3)
    """
    order = check_int("order", order, minimum=1)
    kind = check_choice("kind", kind, ("modified", "original"))
    return 2 * order + 1 if kind == "modified" else order + 1


# ----------------------------------------------------------------------------- public functions


def hoc_levels(
    frames: torch.Tensor,
    order: int,
    v: int = 4,
    delta: float | None = math.pi / 4,
    *,
    direction: Direction = "forward",
    method: Method = "auto",
) -> list[torch.Tensor]:
    """All levels ``[F, Y^(1), ..., Y^(order)]`` of the HOC recursion.

    ``delta`` a number: modified HOC, eq. (5)-(6) (eq. 10 backward); ``delta=None``: original
    HOC, eq. (4). Levels that cannot hold a point (the cube has fewer than
    :func:`scans_needed` scans, or the level below is empty) are not computed: they are one
    shared all-zero tensor (do not modify levels in place).

    Args:
        frames: ``(B, T, H, W)`` bool cube (already validated and batched).
        order: HOC order ``k >= 1``.
        v: velocity window half-width (clamped to :func:`effective_v`).
        delta: curvature limit (radians) or ``None`` for the original HOC.
        direction: ``"forward"`` or ``"backward"``.
        method: ``"auto"``, ``"conv"`` or ``"sparse"``.

    Returns:
        ``order + 1`` bool cubes of shape ``(B, T, H, W)``.

    Raises:
        ValueError: bad ``order``, ``v``, ``delta``, ``direction`` or ``method``; ``v`` whose
            estimated cost exceeds ``MEMORY_BUDGET`` or ``TIME_BUDGET``.

    Examples:
        >>> f = torch.ones(1, 4, 3, 3, dtype=torch.bool)
        >>> [int(y.sum()) for y in hoc_levels(f, 3, v=1, delta=None)]  # eq. (4): t <= T - 1 - k
        [36, 27, 18, 9]
    """
    order, v, delta = _check_common(order, v, delta)
    s = _step(direction)
    _, n_t, h, w = frames.shape
    v = effective_v(v, h, w)
    path = _plan(method, frames, v, delta)
    levels = [frames]
    reachable = n_t - 1 if delta is None else (n_t - 1) // 2  # highest order with any output
    zero: torch.Tensor | None = None
    y = frames.float() if path == "conv" else frames
    if path == "conv":
        if delta is None:
            window = get_window_kernel(v, device=frames.device)
        else:
            masks = get_direction_mask_kernels(v, delta, device=frames.device)
            shifts = get_shift_kernels(v, device=frames.device)
    else:
        allowed = None if delta is None else _allowed_cached(v, delta, str(frames.device))
    for level in range(1, order + 1):
        if level > reachable or not levels[-1].any():
            zero = torch.zeros_like(frames) if zero is None else zero
            levels.extend([zero] * (order + 1 - level))
            break
        if path == "conv":
            if delta is None:
                y = original_hoc_layer(y, window, direction=direction)
            else:
                y = hoc_layer(y, masks, shifts, direction=direction)
            levels.append(y > 0)
        elif delta is None:
            levels.append(_sparse_original_layer(levels[-1], v, s))
        else:
            levels.append(_sparse_layer(levels[-1], allowed, v, s))
    return levels


def modified_hoc(
    frames: torch.Tensor,
    order: int,
    v: int = 4,
    delta: float = math.pi / 4,
    direction: Direction = "forward",
    *,
    method: Method = "auto",
) -> torch.Tensor:
    """Modified high-order correlation of [LA98] eq. (5)-(6) (eq. 10 backward), order ``order``.

    A point survives order ``k`` when it starts (forward) or ends (backward) a chain accepted by
    ``k`` stacked layers: each layer keeps ``p0`` at scan ``t`` when some ``p1 = p0 + m1`` at
    ``t + 1`` and ``p2 = p1 + m2`` at ``t + 2`` survived the previous layer, with ``|m|`` in the
    velocity window ``v`` and the turn from ``m1`` to ``m2`` at most ``delta``; order ``k``
    covers ``2k + 1`` scans (Proposition 1).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube (bool or 0/1 numbers); ``B = 0``
            gives an empty result.
        order: HOC order ``k >= 1``; ``T < 2k + 1`` answers at once with zeros.
        v: velocity window half-width in pixels per scan (``>= 1``; clamped to
            :func:`effective_v`, results unchanged).
        delta: curvature limit in radians, in ``(0, pi]``.
        direction: ``"forward"`` (``Y^(k)(t) = 0`` for ``t > T - 1 - 2k``) or ``"backward"``
            (``Y^(k)(t) = 0`` for ``t < 2k``).
        method: ``"conv"`` (connectionist network), ``"sparse"`` (fast path) or ``"auto"``
            (sparse when at most ``SPARSE_DENSITY`` of the pixels are on). Results are identical.

    Returns:
        bool cube shaped like ``frames``.

    Raises:
        ValueError: wrong rank, non-binary values, ``order < 1``, ``v < 1``, ``delta`` outside
            ``(0, pi]``, unknown ``direction`` or ``method``, or a ``v`` whose estimated cost
            exceeds ``MEMORY_BUDGET`` / ``TIME_BUDGET``.

    Examples:
        >>> f = torch.zeros(5, 9, 9, dtype=torch.bool)
        >>> for t in range(5):
        ...     f[t, 4, 2 + t] = True  # a target moving right one pixel per scan
        >>> modified_hoc(f, order=2, v=1).nonzero().tolist()
        [[0, 4, 2]]
    """
    cube, batched = as_cube("frames", frames, binary=True)
    order, v, delta = _check_common(order, v, delta)
    if delta is None:
        raise TypeError("`delta`: expected a number in (0, pi], got None")
    if _beyond_scans(cube, order, delta, method):
        return restore_batch(torch.zeros_like(cube), batched)
    out = hoc_levels(cube, order, v, delta, direction=direction, method=method)[-1]
    return restore_batch(out, batched)


def original_hoc(
    frames: torch.Tensor,
    order: int,
    v: int = 4,
    direction: Direction = "forward",
    *,
    method: Method = "auto",
) -> torch.Tensor:
    """Original high-order correlation of [LA98] eq. (4): a two-scan correlation per layer.

    ``Y^(k)_t(x, y) = g[sum_{|i|, |j| <= v} Y^(k-1)_t(x, y) Y^(k-1)_{t+1}(x + i, y + j)]`` with
    ``Y^(0) = F``: a point survives a layer when some surviving point lies in its velocity window
    one scan later (earlier, backward). There is no curvature or velocity-change constraint
    ("beside the maximum target movement, this process does not impose any other constraints",
    section II). Order ``k`` covers ``k + 1`` scans, so ``Y^(k)(t) = 0`` for ``t > T - 1 - k``
    forward and ``t < k`` backward.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube; ``B = 0`` gives an empty result.
        order: HOC order ``k >= 1``; ``T < k + 1`` answers at once with zeros.
        v: velocity window half-width (``>= 1``; clamped to :func:`effective_v`).
        direction: ``"forward"`` or ``"backward"``.
        method: ``"conv"`` (window convolution), ``"sparse"`` (summed-area table at the
            on-points) or ``"auto"`` (``"sparse"``, the cheaper at any density). Results are
            identical.

    Returns:
        bool cube shaped like ``frames``.

    Raises:
        ValueError: as :func:`modified_hoc`.

    Examples:
        >>> f = torch.zeros(3, 7, 7, dtype=torch.bool)
        >>> f[0, 1, 1] = f[1, 2, 3] = f[2, 3, 5] = True  # constant move (2, 1)
        >>> original_hoc(f, 2, v=2)[0, 1, 1].item()
        True
        >>> f[2, 3, 5], f[2, 0, 1] = False, True  # a sharp turn: eq. (4) still keeps it
        >>> original_hoc(f, 2, v=2).nonzero().tolist()
        [[0, 1, 1]]
    """
    cube, batched = as_cube("frames", frames, binary=True)
    order, v, _ = _check_common(order, v, None)
    if _beyond_scans(cube, order, None, method):
        return restore_batch(torch.zeros_like(cube), batched)
    out = hoc_levels(cube, order, v, None, direction=direction, method=method)[-1]
    return restore_batch(out, batched)


def mhoc_image(
    frames: torch.Tensor,
    order: int = 2,
    v: int = 4,
    delta: float | None = math.pi / 4,
    *,
    method: Method = "auto",
) -> torch.Tensor:
    """The MHOC image of [LA98] section III-B: forward ``Y^(k)`` OR backward ``Y^(k)``.

    Section III-B combines the forward correlations of eq. (5) with the backward ones of eq. (10):
    "for a second-order modified HOC for ten scans of data ... the HOC images can be obtained
    from scans t1 to t6 ... the backward process would provide images from scans t10 to t5".
    Forward ``Y^(k)`` covers ``t <= T - 1 - 2k`` and backward ``t >= 2k``, so every scan holds
    output when ``2k <= T - 2k``, i.e. ``T >= 4k`` (order 2 needs 8 scans, 10 in the paper);
    a track present in all ``T`` scans then keeps all its points. Table II's "MHOC results"
    count the points of this image (our reading of what "after modified HOC" counts).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube.
        order: HOC order ``k >= 1``.
        v: velocity window half-width.
        delta: curvature limit in ``(0, pi]``; ``None`` combines the original HOC of eq. (4)
            instead (forward covers ``t <= T - 1 - k``, backward ``t >= k``).
        method: ``"auto"``, ``"conv"`` or ``"sparse"`` (identical results).

    Returns:
        bool cube shaped like ``frames`` (a subset of ``frames``).

    Raises:
        ValueError: as :func:`modified_hoc`.

    Examples:
        >>> f = torch.zeros(10, 12, 12, dtype=torch.bool)
        >>> for t in range(10):
        ...     f[t, 5, 1 + t] = True  # a 10-point track
        >>> int(mhoc_image(f, order=2, v=1).sum())  # all 10 points: t1-t6 forward, t5-t10 backward
        10
    """
    cube, batched = as_cube("frames", frames, binary=True)
    order, v, delta = _check_common(order, v, delta)
    image = torch.zeros_like(cube)
    for _, levels in _mhoc_levels(cube, order, v, delta, method):
        image |= levels[-1]
    return restore_batch(image, batched)


def _mhoc_levels(
    cube: torch.Tensor, order: int, v: int, delta: float | None, method: str
) -> list[tuple[int, list[torch.Tensor]]]:
    """``[(+1, forward levels), (-1, backward levels)]`` of :func:`mhoc_image` (checked input).

    Empty when the cube has too few scans for ``Y^(order)``. Shared with
    :func:`hocnet.hoc.identify.mhoc_candidates`, which also reads the level below the top.
    """
    if _beyond_scans(cube, order, delta, method):
        return []
    return [
        (step, hoc_levels(cube, order, v, delta, direction=direction, method=method))
        for direction, step in (("forward", 1), ("backward", -1))
    ]


def support_from_levels(
    levels: list[torch.Tensor],
    v: int = 4,
    delta: float | None = math.pi / 4,
    *,
    direction: Direction = "forward",
    method: Method = "auto",
) -> torch.Tensor:
    """Chain members of the points accepted at the top of ``levels`` (one direction).

    Our addition (see :func:`chain_support`).

    Args:
        levels: ``[F, Y^(1), ..., Y^(k)]`` bool cubes ``(B, T, H, W)``, as from
            :func:`hoc_levels` (or cached by the streaming detector).
        v: velocity window half-width (clamped to :func:`effective_v`).
        delta: curvature limit or ``None`` (original HOC, eq. 4).
        direction: direction in which ``levels`` were computed.
        method: ``"auto"``, ``"conv"`` (:func:`hoc_mark`) or ``"sparse"``.

    Returns:
        ``(B, T, H, W)`` bool cube of marked points.
    """
    s = _step(direction)
    v = check_int("v", v, minimum=1)
    if delta is not None:
        delta = check_number("delta", delta, low=0.0, high=math.pi, low_inclusive=False)
    _, _, h, w = levels[0].shape
    v = effective_v(v, h, w)
    if len(levels) == 1:
        return levels[0].clone()
    if not levels[-1].any():  # the top level is empty: nothing is marked
        return torch.zeros_like(levels[0])
    path = _plan(method, levels[0], v, delta)
    if path == "sparse":
        if delta is None:
            return _sparse_original_marks(levels, v, s)
        return _sparse_marks(levels, _allowed_cached(v, delta, str(levels[0].device)), v, s)
    dev = levels[0].device
    marks = levels[-1].float()
    if delta is None:
        window = get_window_kernel(v, device=dev)
        for level in range(len(levels) - 1, 0, -1):
            marks = original_hoc_mark(levels[level - 1].float(), marks, window, direction=direction)
        return marks > 0
    masks = get_direction_mask_kernels(v, delta, device=dev)
    shifts = get_shift_kernels(v, device=dev)
    for level in range(len(levels) - 1, 0, -1):
        marks = hoc_mark(levels[level - 1].float(), marks, masks, shifts, direction=direction)
    return marks > 0


def chain_support(
    frames: torch.Tensor,
    order: int,
    v: int = 4,
    delta: float | None = math.pi / 4,
    *,
    method: Method = "auto",
) -> torch.Tensor:
    """Every input point lying on at least one accepted chain, forward or backward (our addition).

    The paper's image is :func:`mhoc_image` (forward ``Y^(k)`` OR backward ``Y^(k)``). That image
    holds every point of a full-length track only when its two halves cover every scan:
    forward ``Y^(k)`` covers ``t <= T - 1 - 2k`` and backward ``t >= 2k``, so every scan is
    covered iff ``2k <= T - 2k``, i.e. ``T >= 4k`` (``T >= 2k`` for the original HOC, whose
    chains span ``k + 1`` scans); and a track shorter than the cube loses the points it has
    beyond those ranges. Chain support is needed for the orders where ``T < 4k`` (e.g. order 3
    in 10 scans), and for tracks that start or end inside the cube: the points accepted at order
    ``k`` in either direction are roots, and a marking pass (:func:`hoc_mark`, the transpose of
    each layer) walks back down the layers marking the members of every accepted triple (pair,
    for eq. 4) under a marked point, so every point of an accepted ``(2k + 1)``-point chain is
    kept. It keeps more clutter than :func:`mhoc_image` (the clutter chains' members too). See
    :func:`hocnet.hoc.reference.chain_support_reference` for the definition by recursion.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube.
        order: HOC order ``k >= 1``.
        v: velocity window half-width.
        delta: curvature limit in ``(0, pi]``, or ``None`` for the original HOC (eq. 4).
        method: ``"auto"``, ``"conv"`` or ``"sparse"``.

    Returns:
        bool cube shaped like ``frames``: the chain support (a subset of ``frames``).

    Examples:
        >>> f = torch.zeros(5, 9, 9, dtype=torch.bool)
        >>> for t in range(5):
        ...     f[t, 4, 2 + t] = True
        >>> f[2, 0, 8] = True  # an isolated clutter point
        >>> chain_support(f, order=2, v=1).sum().item()  # the 5 track points, not the clutter
        5
    """
    cube, batched = as_cube("frames", frames, binary=True)
    order, v, delta = _check_common(order, v, delta)
    _, _, h, w = cube.shape
    v = effective_v(v, h, w)
    support = torch.zeros_like(cube)
    if _beyond_scans(cube, order, delta, method):
        return restore_batch(support, batched)
    resolved = _plan(method, cube, v, delta)
    for direction in ("forward", "backward"):
        levels = hoc_levels(cube, order, v, delta, direction=direction, method=resolved)
        support |= support_from_levels(levels, v, delta, direction=direction, method=resolved)
    return restore_batch(support, batched)


# ----------------------------------------------------------------------------- density bounds


def density_bound(
    kind: Kind = "modified",
    v: int = 4,
    delta: float = math.pi / 4,
) -> float:
    """The clutter-density upper bound for discrimination of [LA98] section IV-B (a fraction).

    Section IV-B: the original HOC correlates a point with any pixel of its
    ``(2v + 1) x (2v + 1)`` window in the next scan, so random clutter of density ``rho``
    correlates "continuously" once ``rho (2v + 1)^2 >= 1``: the bound is ``1 / (2v + 1)^2``
    (``1/81 = 1.23 %`` for ``v = 4``). For the modified HOC the second move is confined by the
    curvature limit to a sector of opening ``2 delta``, i.e. a fraction ``2 delta / 2 pi`` of the
    window ("if the curvature constraint is chosen to be delta = pi/4, this window size is 1/4
    of the entire velocity window"), so the bound grows by ``pi / delta``:
    ``pi / (delta (2v + 1)^2)``, ``4/81 = 4.94 %`` for ``v = 4, delta = pi/4``. The paper prints
    ``(1/81) x 4 = 4.92 %``: it multiplied the rounded ``1.23 %`` by 4. The factor
    ``pi / delta`` for other ``delta`` is our reading of the paper's "1/4" (it gives only
    ``delta = pi/4``); the discrete table of :func:`~hocnet.hoc.kernels.allowed_moves` allows
    28.4 % of the window at ``v = 4, delta = pi/4`` (moves at exactly 45 degrees included).

    Args:
        kind: ``"modified"`` (eq. 5-6) or ``"original"`` (eq. 4).
        v: velocity window half-width (``>= 1``).
        delta: curvature limit in ``(0, pi]`` (modified only); the bound is capped at 1.

    Returns:
        The bound as a fraction of the pixels of one scan.

    Examples:
        >>> round(100 * density_bound("original"), 2), round(100 * density_bound("modified"), 2)
        (1.23, 4.94)
    """
    kind = check_choice("kind", kind, ("modified", "original"))
    v = check_int("v", v, minimum=1)
    window = (2 * v + 1) ** 2
    if kind == "original":
        return 1.0 / window
    delta = check_number("delta", delta, low=0.0, high=math.pi, low_inclusive=False)
    return min(1.0, math.pi / (delta * window))


def density_warning(
    frames: torch.Tensor,
    kind: Kind = "modified",
    v: int = 4,
    delta: float = math.pi / 4,
) -> str | None:
    """A warning when a scan is denser than the paper's bound (:func:`density_bound`), else None.

    Above the bound random clutter "provide[s] consistent correlations which in turn lead to
    false tracks" (section IV-B): the detector cannot discriminate and should say so. Densities
    are per scan ("the percentage of random noise pixels out of all possible pixels in one
    scan", footnote 1 of section II); the densest scan of the cube is compared.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube.
        kind: ``"modified"`` or ``"original"``.
        v: velocity window half-width.
        delta: curvature limit (modified only).

    Returns:
        A one-line message, or ``None`` when every scan is at or below the bound (or empty input).

    Examples:
        >>> density_warning(torch.zeros(4, 8, 8)) is None
        True
        >>> density_warning(torch.ones(4, 8, 8))[:40]
        'densest scan is 100 % on, above the 4.94'
    """
    cube, _ = as_cube("frames", frames, binary=True)
    bound = density_bound(kind, v, delta)
    if cube.numel() == 0:
        return None
    b, n_t, h, w = cube.shape
    per_scan = cube.reshape(b * n_t, h * w).float().mean(1)
    worst = float(per_scan.max())
    if worst <= bound:
        return None
    return (
        f"densest scan is {100 * worst:.3g} % on, above the {100 * bound:.3g} % bound of the "
        f"{kind} HOC (v={v}; [LA98] section IV-B): clutter correlates consistently and the "
        "detector cannot discriminate targets from it"
    )

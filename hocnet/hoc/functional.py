"""Functional core of the (modified) high-order correlation network of [LA98].

Two interchangeable implementations give bit-identical results:

- ``"conv"``, the connectionist network itself (section III-A of [LA98]): per layer, one
  direction-masked convolution per first move applied to scan ``t + 2``, a hard limiter, a product
  with scan ``t + 1``, one shift convolution per first move, a hard limiter and a product with
  scan ``t``::

      D = g(conv2d(Y_{t+2}, K_mask))          # (M channels) continuation exists after move m1
      S = conv2d(Y_{t+1} * D, K_shift)        # sum over first moves, each read at p + m1
      Y'_t = Y_t * g(S)

- ``"sparse"``, the fast path for large, sparse cubes: the same sums evaluated only at the
  points that are on, by gathering each point's neighbours in the next scan and joining pairs of
  moves through the allowed-move table.

``method="auto"`` picks ``"sparse"`` when at most ``SPARSE_DENSITY`` of the pixels are on.

Forward layers read scans ``t + 1, t + 2``; backward layers read ``t - 1, t - 2``. ``Y^(k)(t)`` is 0
wherever it cannot be evaluated (forward ``t > T - 1 - 2k``, backward ``t < 2k``): scans outside
the cube count as empty, as do out-of-image neighbours (zero padding, nothing wraps).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Literal

import torch
import torch.nn.functional as F

from hocnet._check import as_cube, check_choice, check_int, check_number, restore_batch
from hocnet.hoc.kernels import allowed_moves, get_direction_mask_kernels, get_shift_kernels

__all__ = [
    "SPARSE_DENSITY",
    "chain_support",
    "hard_limiter",
    "hoc_layer",
    "hoc_levels",
    "hoc_mark",
    "modified_hoc",
    "original_hoc",
    "support_from_levels",
]

Direction = Literal["forward", "backward"]
Method = Literal["auto", "conv", "sparse"]

SPARSE_DENSITY = 0.1
"""``method="auto"`` uses the sparse path when at most this fraction of the pixels is on."""

_CHUNK_ELEMENTS = 1 << 25  # cap on (frames x channels x H x W) per convolution call


def hard_limiter(c: torch.Tensor) -> torch.Tensor:
    """The hard limiter of [LA98]: ``g(c) = 1 if c > 0 else 0`` (same dtype as ``c``).

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


def _chunks(channels: int, h: int, w: int) -> int:
    """Frames per convolution call so that one call holds at most _CHUNK_ELEMENTS values."""
    return max(1, _CHUNK_ELEMENTS // max(1, channels * h * w))


def hoc_layer(
    y: torch.Tensor,
    mask_kernels: torch.Tensor,
    shift_kernels: torch.Tensor,
    *,
    direction: Direction = "forward",
    activation: Callable[[torch.Tensor], torch.Tensor] = hard_limiter,
) -> torch.Tensor:
    """One connectionist (modified) HOC layer: ``Y^(k-1) -> Y^(k)``.

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
    m, _, side, _ = mask_kernels.shape
    pad = side // 2
    y1 = _tshift(y, s).reshape(b * n_t, 1, h, w)
    y2 = _tshift(y, 2 * s).reshape(b * n_t, 1, h, w)
    out = torch.empty(b * n_t, 1, h, w, dtype=y.dtype, device=y.device)
    step = _chunks(m, h, w)
    for lo in range(0, b * n_t, step):
        hi = min(b * n_t, lo + step)
        cont = activation(F.conv2d(y2[lo:hi], mask_kernels, padding=pad))
        out[lo:hi] = activation(F.conv2d(y1[lo:hi] * cont, shift_kernels, padding=pad))
    return y * out.reshape(b, n_t, h, w)


def hoc_mark(
    y_prev: torch.Tensor,
    marks: torch.Tensor,
    mask_kernels: torch.Tensor,
    shift_kernels: torch.Tensor,
    *,
    direction: Direction = "forward",
) -> torch.Tensor:
    """Marking pass through one layer: expand accepted points into their chain members.

    The transpose of :func:`hoc_layer`. For every marked point ``p0`` at scan ``t`` and every
    triple ``(p0, p1, p2)`` accepted by the layer (all three on in ``y_prev``, move ``m1`` then an
    allowed move ``m2``), ``p1`` (scan ``t + 1``) and ``p2`` (scan ``t + 2``) are marked too
    (``t - 1``, ``t - 2`` backward). Uses the same kernels, transposed::

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
    m, _, side, _ = mask_kernels.shape
    pad = side // 2
    y1 = _tshift(y_prev, s).reshape(b * n_t, 1, h, w)
    y2 = _tshift(y_prev, 2 * s).reshape(b * n_t, 1, h, w)
    mk = marks.reshape(b * n_t, 1, h, w)
    mark1 = torch.empty_like(mk)
    mark2 = torch.empty_like(mk)
    step = _chunks(m, h, w)
    for lo in range(0, b * n_t, step):
        hi = min(b * n_t, lo + step)
        cont = hard_limiter(F.conv2d(y2[lo:hi], mask_kernels, padding=pad))
        incoming = F.conv_transpose2d(mk[lo:hi], shift_kernels, padding=pad)  # marks(p - m1)
        active = incoming * y1[lo:hi] * cont  # (n, M, H, W): p1 reached by move m1 from a mark
        mark1[lo:hi] = hard_limiter(active.sum(1, keepdim=True))
        mark2[lo:hi] = hard_limiter(F.conv_transpose2d(active, mask_kernels, padding=pad))
    mark1 = _tshift(mark1.reshape(b, n_t, h, w), -s) * y_prev
    mark2 = _tshift(mark2.reshape(b, n_t, h, w), -2 * s) * y_prev
    return torch.clamp(marks + mark1 + mark2, max=1.0)


# ----------------------------------------------------------------------------- sparse fast path


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


def _sparse_triples(
    active: torch.Tensor,
    allowed: torch.Tensor,
    v: int,
    s: int,
    roots: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Accepted triples among the on-points of a bool cube, evaluated only at those points.

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
    b, n_t, h, w = active.shape
    dev = active.device
    flat = active.reshape(-1).nonzero().squeeze(1)
    n = flat.numel()
    empty = flat.new_zeros(0)
    if n == 0:
        return flat, empty, empty, empty
    coords = (flat // (w * h * n_t), (flat // (w * h)) % n_t, (flat // w) % h, flat % w)
    # Index volume padded by v in space and by one scan on each side in time.
    vol = torch.full((b, n_t + 2, h + 2 * v, w + 2 * v), -1, dtype=torch.int32, device=dev)
    vol[coords[0], coords[1] + 1, coords[2] + v, coords[3] + v] = torch.arange(
        n, dtype=torch.int32, device=dev
    )
    if roots is None:  # every point is a root: one neighbour gather serves both moves
        ids0 = torch.arange(n, device=dev)
        row1, mid, move1 = _neighbours(None, coords, vol, v, s)
        inv, row2, end, move2, n_mid = mid, row1, mid, move1, n
    else:
        ids0 = roots.reshape(-1)[flat].nonzero().squeeze(1)
        row1, mid, move1 = _neighbours(ids0, coords, vol, v, s)
        seen = torch.zeros(n, dtype=torch.bool, device=dev)
        seen[mid] = True
        uniq = seen.nonzero().squeeze(1)
        pos = torch.empty(n, dtype=torch.long, device=dev)
        pos[uniq] = torch.arange(uniq.numel(), device=dev)
        inv, n_mid = pos[mid], uniq.numel()
        row2, end, move2 = _neighbours(uniq, coords, vol, v, s)
    if mid.numel() == 0:
        return flat, empty, empty, empty
    counts = torch.bincount(row2, minlength=n_mid)
    starts = torch.cumsum(counts, 0) - counts
    fan = counts[inv]  # second moves available after each first move
    # expand every first move into its candidate second moves (searchsorted, not
    # repeat_interleave, which is pathologically slow on small inputs with several threads)
    ends = torch.cumsum(fan, 0)
    slots = torch.arange(int(ends[-1]), device=dev)
    first = torch.searchsorted(ends, slots, right=True)
    within = slots - (ends - fan)[first]
    second = starts[inv[first]] + within
    ok = allowed[move1[first], move2[second]]
    first, second = first[ok], second[ok]
    return flat, ids0[row1[first]], mid[first], end[second]


def _sparse_layer(active: torch.Tensor, allowed: torch.Tensor, v: int, s: int) -> torch.Tensor:
    """One HOC layer on the sparse path: on-points that start an accepted triple."""
    flat, p0, _, _ = _sparse_triples(active, allowed, v, s)
    out = torch.zeros(active.numel(), dtype=torch.bool, device=active.device)
    out[flat[p0]] = True
    return out.reshape(active.shape)


def _sparse_marks(
    levels: list[torch.Tensor], allowed: torch.Tensor, v: int, s: int
) -> torch.Tensor:
    """Marking pass on the sparse path, expanding only the triples under marked points."""
    marks = levels[-1].clone()
    for level in range(len(levels) - 1, 0, -1):
        flat, _, p1, p2 = _sparse_triples(levels[level - 1], allowed, v, s, roots=marks)
        view = marks.view(-1)
        view[flat[p1]] = True
        view[flat[p2]] = True
    return marks


def _conv_marks(
    levels: list[torch.Tensor], v: int, delta: float | None, direction: str
) -> torch.Tensor:
    """Marking pass on the connectionist path."""
    masks = get_direction_mask_kernels(v, delta, device=levels[0].device)
    shifts = get_shift_kernels(v, device=levels[0].device)
    marks = levels[-1].float()
    for level in range(len(levels) - 1, 0, -1):
        marks = hoc_mark(levels[level - 1].float(), marks, masks, shifts, direction=direction)
    return marks > 0


# ----------------------------------------------------------------------------- public functions


@functools.lru_cache(maxsize=64)
def _allowed_cached(v: int, delta: float | None, device: str) -> torch.Tensor:
    """Read-only cached :func:`allowed_moves` table (built once per setting)."""
    return allowed_moves(v, delta, device=device)


def _resolve_method(method: str, cube: torch.Tensor) -> str:
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

    Args:
        frames: ``(B, T, H, W)`` bool cube (already validated and batched).
        order: HOC order ``k >= 1``.
        v: velocity window half-width.
        delta: curvature limit (radians) or ``None`` for the original HOC.
        direction: ``"forward"`` or ``"backward"``.
        method: ``"auto"``, ``"conv"`` or ``"sparse"``.

    Returns:
        ``order + 1`` bool cubes of shape ``(B, T, H, W)``.
    """
    order, v, delta = _check_common(order, v, delta)
    s = _step(direction)
    if _resolve_method(method, frames) == "sparse":
        allowed = _allowed_cached(v, delta, str(frames.device))
        levels = [frames]
        for _ in range(order):
            levels.append(_sparse_layer(levels[-1], allowed, v, s))
        return levels
    masks = get_direction_mask_kernels(v, delta, device=frames.device)
    shifts = get_shift_kernels(v, device=frames.device)
    levels = [frames]
    y = frames.float()
    for _ in range(order):
        y = hoc_layer(y, masks, shifts, direction=direction)
        levels.append(y > 0)
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
    """Modified high-order correlation of [LA98] eq. (5)-(6), recursed ``order`` times.

    A point survives order ``k`` when it starts (forward) or ends (backward) a chain accepted by
    ``k`` stacked layers: each layer keeps ``p0`` at scan ``t`` when some ``p1 = p0 + m1`` at
    ``t + 1`` and ``p2 = p1 + m2`` at ``t + 2`` survived the previous layer, with ``|m|`` in the
    velocity window ``v`` and the turn from ``m1`` to ``m2`` at most ``delta``.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube (bool or 0/1 numbers).
        order: HOC order ``k >= 1``.
        v: velocity window half-width in pixels per scan (``>= 1``).
        delta: curvature limit in radians, in ``(0, pi]``.
        direction: ``"forward"`` (``Y^(k)(t) = 0`` for ``t > T - 1 - 2k``) or ``"backward"``
            (``Y^(k)(t) = 0`` for ``t < 2k``).
        method: ``"conv"`` (connectionist network), ``"sparse"`` (fast path) or ``"auto"``
            (sparse when at most ``SPARSE_DENSITY`` of the pixels are on). Results are identical.

    Returns:
        bool cube shaped like ``frames``.

    Raises:
        ValueError: wrong rank, non-binary values, ``order < 1``, ``v < 1``, ``delta`` outside
            ``(0, pi]``, unknown ``direction`` or ``method``.

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
    """Original high-order correlation of [LA98] eq. (4): constant-velocity triples.

    Same network as :func:`modified_hoc` with the direction-masked kernels replaced by shift
    kernels (the second move must equal the first).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube.
        order: HOC order ``k >= 1``.
        v: velocity window half-width (``>= 1``).
        direction: ``"forward"`` or ``"backward"``.
        method: ``"auto"``, ``"conv"`` or ``"sparse"``.

    Returns:
        bool cube shaped like ``frames``.

    Examples:
        >>> f = torch.zeros(3, 7, 7, dtype=torch.bool)
        >>> f[0, 1, 1] = f[1, 2, 3] = f[2, 3, 5] = True  # constant move (2, 1)
        >>> original_hoc(f, 1, v=2)[0, 1, 1].item()
        True
        >>> f[2, 3, 5], f[2, 4, 4] = False, True  # now the move turns: rejected
        >>> original_hoc(f, 1, v=2).any().item()
        False
    """
    cube, batched = as_cube("frames", frames, binary=True)
    order, v, _ = _check_common(order, v, None)
    out = hoc_levels(cube, order, v, None, direction=direction, method=method)[-1]
    return restore_batch(out, batched)


def support_from_levels(
    levels: list[torch.Tensor],
    v: int = 4,
    delta: float | None = math.pi / 4,
    *,
    direction: Direction = "forward",
    method: Method = "auto",
) -> torch.Tensor:
    """Chain members of the points accepted at the top of ``levels`` (one direction).

    Args:
        levels: ``[F, Y^(1), ..., Y^(k)]`` bool cubes ``(B, T, H, W)``, as from
            :func:`hoc_levels` (or cached by the streaming detector).
        v: velocity window half-width.
        delta: curvature limit or ``None`` (original HOC).
        direction: direction in which ``levels`` were computed.
        method: ``"auto"``, ``"conv"`` (:func:`hoc_mark`) or ``"sparse"``.

    Returns:
        ``(B, T, H, W)`` bool cube of marked points.
    """
    s = _step(direction)
    if _resolve_method(method, levels[0]) == "sparse":
        return _sparse_marks(levels, _allowed_cached(v, delta, str(levels[0].device)), v, s)
    return _conv_marks(levels, v, delta, direction)


def chain_support(
    frames: torch.Tensor,
    order: int,
    v: int = 4,
    delta: float | None = math.pi / 4,
    *,
    method: Method = "auto",
) -> torch.Tensor:
    """Every input point lying on at least one accepted ``(2k + 1)``-point chain.

    Combines the forward and the backward network: the points accepted at order ``k`` in either
    direction are roots, and a marking pass (:func:`hoc_mark`, the transpose of each layer)
    walks back down the layers marking the members of every accepted triple under a marked
    point. So a target point in the last ``2k`` scans (which the forward network cannot
    evaluate) or in the middle of a short track is kept when its chain is. See
    :func:`hocnet.hoc.reference.chain_support_reference` for the definition by recursion.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube.
        order: HOC order ``k >= 1``.
        v: velocity window half-width.
        delta: curvature limit in ``(0, pi]``, or ``None`` for the original HOC.
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
    resolved = _resolve_method(method, cube)
    support = torch.zeros_like(cube)
    for direction in ("forward", "backward"):
        levels = hoc_levels(cube, order, v, delta, direction=direction, method=resolved)
        support |= support_from_levels(levels, v, delta, direction=direction, method=resolved)
    return restore_batch(support, batched)

"""Slow, loop-level reading of [LA98] eq. (4)-(6): the oracle the fast paths are tested against.

Nothing here is vectorised: every sum of eq. (4)-(6) is an explicit loop over scans, pixels and
moves, so that the code can be checked against the paper line by line. Use it on small cubes only.

With binary scans ``F_t(x, y)`` and the hard limiter ``g(c) = 1 if c > 0 else 0`` (eq. 3):

- original HOC, eq. (4) (``delta=None``), a *two-scan* correlation:
  ``Y^(k)_t(x, y) = g( sum_{|i|, |j| <= v} Y^(k-1)_t(x, y) Y^(k-1)_{t+1}(x + i, y + j) )``
  with ``Y^(0) = F``; order ``k`` covers ``k + 1`` scans ("k + n_max = n_0"), so
  ``Y^(k)_t`` can be 1 only for ``t <= T - 1 - k`` (forward);
- modified HOC, eq. (5)-(6), a three-scan correlation:
  ``Y^(k)_t(x, y) = g( Y^(k-1)_t(x, y) sum_{i1, j1} Y^(k-1)_{t+1}(x + i1, y + j1)
  sum_{(i2, j2) in D(i1, j1)} Y^(k-1)_{t+2}(x + i1 + i2, y + j1 + j2) )``
  where ``D(i1, j1)`` holds the second moves within the velocity window whose turn from the
  first move is at most ``delta`` (eq. 6); order ``k`` covers ``2k + 1`` scans (Proposition 1),
  so ``Y^(k)_t`` can be 1 only for ``t <= T - 1 - 2k`` (forward);
- backward (eq. 10): ``t + 1, t + 2`` become ``t - 1, t - 2``; the valid range is ``t >= k``
  (original) or ``t >= 2k`` (modified).

Scans outside the cube and pixels outside the frame count as empty.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "chain_support_reference",
    "hoc_levels_reference",
    "hoc_reference",
    "mhoc_image_reference",
    "turn_reference",
]


def turn_reference(i1: int, j1: int, i2: int, j2: int) -> float:
    """Turn angle between moves ``(i1, j1)`` and ``(i2, j2)`` in ``[0, pi]`` (0 for a zero move).

    Examples:
        >>> round(turn_reference(1, 0, 0, 1), 6)
        1.570796
    """
    if (i1 == 0 and j1 == 0) or (i2 == 0 and j2 == 0):
        return 0.0
    d = math.atan2(j2, i2) - math.atan2(j1, i1)
    d = d % (2 * math.pi)
    return min(d, 2 * math.pi - d)


def _allowed(i1: int, j1: int, i2: int, j2: int, delta: float) -> bool:
    return turn_reference(i1, j1, i2, j2) <= delta + 1e-9


def _pairs_at(
    y: np.ndarray, t: int, r: int, c: int, v: int, step: int
) -> list[tuple[tuple[int, int, int]]]:
    """Eq. (4): every ``p1`` at scan ``t + step`` in the window of the on-point (t, r, c)."""
    n_t, n_h, n_w = y.shape
    found = []
    t1 = t + step
    if not y[t, r, c] or not 0 <= t1 < n_t:
        return found
    for j in range(-v, v + 1):
        for i in range(-v, v + 1):
            r1, c1 = r + j, c + i
            if 0 <= r1 < n_h and 0 <= c1 < n_w and y[t1, r1, c1]:
                found.append(((t1, r1, c1),))
    return found


def _triples_at(
    y: np.ndarray, t: int, r: int, c: int, v: int, delta: float | None, step: int
) -> list[tuple[tuple[int, int, int], ...]]:
    """Followers accepted with the on-point (t, r, c).

    ``(p1,)`` pairs of eq. (4) when ``delta is None``, else ``(p1, p2)`` triples of eq. (5)-(6).
    """
    if delta is None:
        return _pairs_at(y, t, r, c, v, step)
    n_t, n_h, n_w = y.shape
    found = []
    if not y[t, r, c]:
        return found
    t1, t2 = t + step, t + 2 * step
    if not (0 <= t1 < n_t and 0 <= t2 < n_t):
        return found
    for j1 in range(-v, v + 1):
        for i1 in range(-v, v + 1):
            r1, c1 = r + j1, c + i1
            if not (0 <= r1 < n_h and 0 <= c1 < n_w) or not y[t1, r1, c1]:
                continue
            for j2 in range(-v, v + 1):
                for i2 in range(-v, v + 1):
                    r2, c2 = r1 + j2, c1 + i2
                    if not (0 <= r2 < n_h and 0 <= c2 < n_w) or not y[t2, r2, c2]:
                        continue
                    if _allowed(i1, j1, i2, j2, delta):
                        found.append(((t1, r1, c1), (t2, r2, c2)))
    return found


def hoc_levels_reference(
    frames: np.ndarray,
    order: int,
    v: int = 4,
    delta: float | None = math.pi / 4,
    direction: str = "forward",
) -> list[np.ndarray]:
    """All levels ``[F, Y^(1), ..., Y^(order)]`` of the HOC recursion, by explicit loops.

    Args:
        frames: ``(T, H, W)`` binary array.
        order: HOC order ``k >= 1``.
        v: velocity window half-width.
        delta: curvature limit (modified HOC, eq. 5-6), or ``None`` for the original HOC of
            eq. (4).
        direction: ``"forward"`` or ``"backward"``.

    Returns:
        ``order + 1`` boolean arrays of shape ``(T, H, W)``.
    """
    step = 1 if direction == "forward" else -1
    levels = [np.asarray(frames).astype(bool)]
    for _ in range(order):
        y = levels[-1]
        out = np.zeros_like(y)
        n_t, n_h, n_w = y.shape
        for t in range(n_t):
            for r in range(n_h):
                for c in range(n_w):
                    out[t, r, c] = len(_triples_at(y, t, r, c, v, delta, step)) > 0
        levels.append(out)
    return levels


def hoc_reference(
    frames: np.ndarray,
    order: int,
    v: int = 4,
    delta: float | None = math.pi / 4,
    direction: str = "forward",
) -> np.ndarray:
    """``Y^(order)`` of eq. (4) (``delta=None``) or eq. (5)-(6), by explicit loops.

    Examples:
        >>> f = np.zeros((3, 5, 5), bool)
        >>> f[0, 0, 0] = f[1, 1, 1] = f[2, 2, 2] = True  # a diagonal track
        >>> bool(hoc_reference(f, 1, v=1)[0, 0, 0])
        True
        >>> hoc_reference(f, 2, v=1, delta=None)[:, 0, 0].tolist()  # eq. (4): k + 1 scans
        [True, False, False]
    """
    return hoc_levels_reference(frames, order, v, delta, direction)[-1]


def chain_support_reference(
    frames: np.ndarray, order: int, v: int = 4, delta: float | None = math.pi / 4
) -> np.ndarray:
    """Points lying on an accepted chain, forward or backward, by explicit recursion.

    A point accepted at the top level (``Y^(order) = 1``) is a root. The members of the chain of
    a point ``p`` at level ``l`` are ``p`` itself, the members of ``p`` at level ``l - 1``, and,
    for every accepted triple ``(p, p1, p2)`` of level ``l`` (all three in ``Y^(l-1)``, moves in
    the window, turn within ``delta``), the members of ``p1`` and ``p2`` at level ``l - 1``; with
    ``delta=None`` (eq. 4), for every ``p1`` of ``Y^(l-1)`` in the window of ``p`` at the next
    scan, the members of ``p1``.
    Level 0 members are the point alone. The result is the union over the forward and the
    backward roots.

    Args:
        frames: ``(T, H, W)`` binary array.
        order: HOC order.
        v: velocity window half-width.
        delta: curvature limit or ``None`` (original HOC).

    Returns:
        ``(T, H, W)`` bool array.
    """
    support = np.zeros(np.shape(frames), dtype=bool)
    for direction, step in (("forward", 1), ("backward", -1)):
        levels = hoc_levels_reference(frames, order, v, delta, direction)
        seen: set[tuple[tuple[int, int, int], int]] = set()

        def mark(p: tuple[int, int, int], level: int, levels=levels, seen=seen, step=step) -> None:
            if (p, level) in seen:
                return
            seen.add((p, level))
            support[p] = True
            if level == 0:
                return
            mark(p, level - 1)
            for followers in _triples_at(levels[level - 1], *p, v, delta, step):
                for q in followers:
                    mark(q, level - 1)

        top = levels[order]
        for p in zip(*np.nonzero(top), strict=True):
            mark(tuple(int(q) for q in p), order)
    return support


def mhoc_image_reference(
    frames: np.ndarray, order: int = 2, v: int = 4, delta: float | None = math.pi / 4
) -> np.ndarray:
    """The MHOC image of section III-B: forward ``Y^(order)`` OR backward ``Y^(order)`` (eq. 10).

    Examples:
        >>> f = np.zeros((5, 5, 5), bool)
        >>> for t in range(5):
        ...     f[t, 2, t] = True
        >>> mhoc_image_reference(f, 1, v=1)[:, 2].diagonal().tolist()
        [True, True, True, True, True]
    """
    fwd = hoc_reference(frames, order, v, delta, "forward")
    bwd = hoc_reference(frames, order, v, delta, "backward")
    return fwd | bwd

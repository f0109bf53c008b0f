"""Slow, loop-level reading of eq. (2)-(11) of [NR08]: the oracle for the DPA tests.

Plain Python loops over batch, frames, pixels and window offsets, in the frames' NumPy dtype, with
no vectorisation and no shared code with :mod:`hocnet.dpa.functional` (the direction of a move is
computed here from ``math.atan2``). Written from the paper's equations, in the paper's index
convention: ``w[h + j, h + i]`` weights ``ASF_{n-1}(x + i, y + j)`` (eq. 6). It implements the
reading documented in :func:`hocnet.dpa.functional.accumulate`:

* ``direction_step="paper"``: eq. (7) ``S(q) = ASF_{n-1}(q) * w_basic[j, i] * Var(q)`` over the
  window of ``p`` (``w_basic = W(9)``, ``Var(q) = V[d_{n-1}(q), dir(p - q)]``), eq. (8) origin
  ``= argmax S`` and direction ``d_n(p) = dir(p - origin)``, then eq. (11) with
  ``W(d_n(p))`` weighting every candidate of ``p`` (eq. 6);
* ``direction_step="source"``: ``term(q) = W(d_{n-1}(q))[j, i] * ASF_{n-1}(q)``; origin = argmax
  term; direction = ``dir(p - origin)``, combined with ``V`` when one is given.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

__all__ = ["accumulate_reference", "paper_var_table"]


def _numpy(value: Any) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    return np.asarray(value)


def _move_direction(dy: int, dx: int) -> int:
    """Direction index of the move ``(dx, dy)``: Figure 4's groups, 8 = in place.

    0..7 for directions 1..8 at 0, 45, ..., 315 degrees of ``atan2(dy, dx)``.
    """
    if dy == 0 and dx == 0:
        return 8
    degrees = math.degrees(math.atan2(dy, dx))
    return round(degrees / 45.0) % 8


def paper_var_table() -> np.ndarray:
    """Var of section 2.2.3 of [NR08] as a ``(9, 9)`` array.

    6 for the same direction, minus 1 per 45 degrees of difference (2 for opposite); our reading
    for direction 9: 6 against itself, 4 against a moving direction.

    Examples:
        >>> paper_var_table()[0].tolist()
        [6.0, 5.0, 4.0, 3.0, 2.0, 3.0, 4.0, 5.0, 4.0]
    """
    v = np.full((9, 9), 4.0)
    for a in range(8):
        for c in range(8):
            diff = abs(a - c) % 8
            v[a, c] = 6 - min(diff, 8 - diff)
    v[8, 8] = 6.0
    return v


def accumulate_reference(
    frames: Any,
    weights: Any,
    b: float,
    g: float,
    var_table: Any = None,
    *,
    smooth: float | None = None,
    direction_step: str = "paper",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Loop-level eq. (2)-(11) of [NR08] with direction estimation and tracking matrix.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` float array or tensor.
        weights: ``(D, k, k)`` with ``D`` in {1, 9}, paper convention ``[d, h + j, h + i]`` for
            the source ``(x + i, y + j)`` of the pixel ``(x, y)``.
        b: memory factor.
        g: sum/max mixing factor.
        var_table: optional ``(9, 9)`` direction-similarity table (``D = 9`` only); with
            ``direction_step="paper"`` ``None`` means :func:`paper_var_table`.
        smooth: temperature of the log-sum-exp max, or ``None`` for the hard max.
        direction_step: ``"paper"`` or ``"source"``.

    Returns:
        ``(asf, direction, origin)`` NumPy arrays shaped like ``frames`` (asf in the frames'
        dtype, the others int64).

    Examples:
        >>> frames, weights = np.ones((2, 3, 3)), np.ones((1, 1, 1))
        >>> asf, direction, origin = accumulate_reference(frames, weights, 0.5, 0.0)
        >>> asf[1, 0, 0].item(), origin[1, 2, 1].item()
        (1.5, 7)
    """
    f = _numpy(frames)
    if not np.issubdtype(f.dtype, np.floating):
        f = f.astype(np.float32)
    batched = f.ndim == 4
    if not batched:
        f = f[None]
    dt = f.dtype.type
    w = _numpy(weights).astype(f.dtype)
    n_dir, k, _ = w.shape
    paper = direction_step == "paper" and n_dir == 9
    if var_table is not None:
        v = _numpy(var_table).astype(np.float64)
    else:
        v = paper_var_table() if paper else None
    h = k // 2
    b, g = dt(b), dt(g)
    one_minus_g = dt(1) - g
    bsz, n_frames, height, width = f.shape
    asf = np.zeros_like(f)
    direction = np.zeros(f.shape, dtype=np.int64)
    origin = np.full(f.shape, -1, dtype=np.int64)
    for bi in range(bsz):
        asf[bi, 0] = f[bi, 0]
        direction[bi, 0] = 8 if n_dir == 9 else 0
        for n in range(1, n_frames):
            prev = asf[bi, n - 1]
            for y in range(height):
                for x in range(width):
                    window = [  # in-frame candidates (i, j) in row-major order (rows j first)
                        (i, j)
                        for j in range(-h, h + 1)
                        for i in range(-h, h + 1)
                        if 0 <= y + j < height and 0 <= x + i < width
                    ]
                    if paper:
                        # eq. (7)-(8): the source pixel and the direction of the current pixel
                        best, src = None, (0, 0)
                        for i, j in window:
                            w_basic = w[8, h + j, h + i]
                            if w_basic <= 0:
                                continue
                            d_q = direction[bi, n - 1, y + j, x + i]
                            var = dt(v[d_q, _move_direction(-j, -i)])
                            # in the frames' dtype: (w_basic * Var) * ASF, rounded as the fast path
                            score = (w_basic * var) * prev[y + j, x + i]
                            if best is None or score > best:
                                best, src = score, (i, j)
                        d_p = _move_direction(-src[1], -src[0])
                        # eq. (6): W(direction of p) weights its whole window
                        terms = [(w[d_p, h + j, h + i], prev[y + j, x + i]) for i, j in window]
                    else:
                        terms = []
                        for i, j in window:
                            d_q = direction[bi, n - 1, y + j, x + i] if n_dir == 9 else 0
                            terms.append((w[d_q, h + j, h + i], prev[y + j, x + i]))
                    total = dt(0)
                    candidates = []  # (term, (i, j)); impossible moves (weight 0) excluded
                    for (weight, value), (i, j) in zip(terms, window, strict=True):
                        term = weight * value
                        total = total + term
                        if weight > 0:
                            candidates.append((term, (i, j)))
                    if not candidates:
                        peak, arg = dt(0), (0, 0)
                    else:
                        top, arg = candidates[0]
                        for term, ij in candidates[1:]:
                            if term > top:
                                top, arg = term, ij
                        if smooth is None:
                            peak = top
                        else:
                            s = sum(
                                math.exp((float(c) - float(top)) / smooth) for c, _ in candidates
                            )
                            peak = dt(float(top) + smooth * math.log(s))
                    asf[bi, n, y, x] = f[bi, n, y, x] + b * (g * total + one_minus_g * peak)
                    if paper:
                        i, j = src
                        origin[bi, n, y, x] = (y + j) * width + (x + i)
                        direction[bi, n, y, x] = d_p
                        continue
                    i, j = arg
                    origin[bi, n, y, x] = (y + j) * width + (x + i)
                    if n_dir == 1:
                        direction[bi, n, y, x] = 0
                        continue
                    move = _move_direction(-j, -i)
                    if v is not None:
                        before = direction[bi, n - 1, y + j, x + i]
                        scores = [v[d, move] + v[d, before] for d in range(9)]
                        top_score = max(scores)
                        if scores[move] != top_score:
                            move = scores.index(top_score)
                    direction[bi, n, y, x] = move
    if not batched:
        return asf[0], direction[0], origin[0]
    return asf, direction, origin

"""Slow, loop-level reading of eq. (2)-(11) of [NR08]: the oracle for the DPA tests.

Plain Python loops over batch, frames, pixels and window offsets, in the frames' NumPy dtype, with
no vectorisation and no shared code with :mod:`hocnet.dpa.functional` (the direction of a move is
computed here from ``math.atan2``). It implements exactly the reading documented in
:func:`hocnet.dpa.functional.accumulate`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

__all__ = ["accumulate_reference"]


def _numpy(value: Any) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    return np.asarray(value)


def _move_direction(dy: int, dx: int) -> int:
    """Direction index (0..7 for directions 1..8 at 0, 45, ..., 315 deg; 8 = in place)."""
    if dy == 0 and dx == 0:
        return 8
    degrees = math.degrees(math.atan2(dy, dx))
    return round(degrees / 45.0) % 8


def accumulate_reference(
    frames: Any,
    weights: Any,
    b: float,
    g: float,
    var_table: Any = None,
    *,
    smooth: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Loop-level eq. (11) of [NR08] with direction estimation and tracking matrix.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` float array or tensor.
        weights: ``(D, k, k)`` with ``D`` in {1, 9}, indexed ``[d, h + dy, h + dx]`` for the
            move ``(dx, dy) = p - q``.
        b: memory factor.
        g: sum/max mixing factor.
        var_table: optional ``(9, 9)`` direction-similarity table (``D = 9`` only).
        smooth: temperature of the log-sum-exp max, or ``None`` for the hard max.

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
    v = None if var_table is None else _numpy(var_table).astype(np.float64)
    n_dir, k, _ = w.shape
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
            for y in range(height):
                for x in range(width):
                    total = dt(0)
                    best = None
                    best_q = (y, x)
                    candidates = []
                    for qy in range(y - h, y + h + 1):  # row-major window order of q
                        for qx in range(x - h, x + h + 1):
                            if not (0 <= qy < height and 0 <= qx < width):
                                continue  # outside the frame: excluded
                            d = direction[bi, n - 1, qy, qx] if n_dir == 9 else 0
                            weight = w[d, h + (y - qy), h + (x - qx)]
                            term = weight * asf[bi, n - 1, qy, qx]
                            total = total + term
                            if weight > 0:  # impossible moves are no candidates of the max
                                candidates.append(term)
                                if best is None or term > best:
                                    best, best_q = term, (qy, qx)
                    if best is None:
                        peak = dt(0)
                    elif smooth is None:
                        peak = best
                    else:
                        top = max(float(c) for c in candidates)
                        s = sum(math.exp((float(c) - top) / smooth) for c in candidates)
                        peak = dt(top + smooth * math.log(s))
                    asf[bi, n, y, x] = f[bi, n, y, x] + b * (g * total + one_minus_g * peak)
                    qy, qx = best_q
                    origin[bi, n, y, x] = qy * width + qx
                    if n_dir == 1:
                        direction[bi, n, y, x] = 0
                        continue
                    move = _move_direction(y - qy, x - qx)
                    if v is not None:
                        before = direction[bi, n - 1, qy, qx]
                        scores = [v[d, move] + v[d, before] for d in range(9)]
                        top_score = max(scores)
                        if scores[move] != top_score:
                            move = scores.index(top_score)
                    direction[bi, n, y, x] = move
    if not batched:
        return asf[0], direction[0], origin[0]
    return asf, direction, origin

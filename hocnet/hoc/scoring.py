"""Movement and curvature scores of [LA98] eq. (8)-(9) for a pair of successive moves.

Our reading of the paper, which reproduces its Table I exactly (see ``tests/hoc/test_scoring``):

- movement score, eq. (8): ``S_m = alpha1 * (A1 - |m2 - m1|^2)``, the squared Euclidean length of
  the change of velocity between the first move ``m1 = (i1, j1)`` and the second ``m2 = (i2, j2)``;
- curvature score, eq. (9): ``S_c = alpha2 * (A2 - theta)``, ``theta`` the turn from ``m1`` to
  ``m2`` in ``[0, pi]`` (0 when either move is zero, DESIGN section 2).

With Table I's constants (A1 = 9, alpha1 = 0.5, A2 = 2.356, alpha2 = 1.91) a straight,
constant-speed triple scores 4.5 and 4.5, and the right-angle turn (1, 0) -> (0, 1) scores
3.5 (movement) and 1.5 (curvature). The point score used for track identification is the mean of
the two, with the section IV-C defaults (A1 = 9, alpha1 = 1/3, A2 = 2.12, alpha2 = 2) and the
acceptance threshold 2.5: a straight track scores 3.62, a 45-degree turn with a one-pixel change
of velocity 2.67 (kept) and a right-angle turn 1.72 (rejected).
"""

from __future__ import annotations

import math

import torch

from hocnet._check import check_number

__all__ = [
    "DEFAULT_THRESHOLD",
    "curvature_score",
    "movement_score",
    "point_score",
]

DEFAULT_THRESHOLD = 2.5
"""Track acceptance threshold of section IV-C of [LA98]."""

Number = int | float | torch.Tensor


def _as_tensor(value: Number) -> torch.Tensor:
    if isinstance(value, torch.Tensor):
        return value
    return torch.as_tensor(value)


def _turn(i1: torch.Tensor, j1: torch.Tensor, i2: torch.Tensor, j2: torch.Tensor) -> torch.Tensor:
    a = torch.atan2(j1.double(), i1.double())
    b = torch.atan2(j2.double(), i2.double())
    diff = torch.remainder(b - a, 2 * math.pi)
    turn = torch.minimum(diff, 2 * math.pi - diff)
    zero = ((i1 == 0) & (j1 == 0)) | ((i2 == 0) & (j2 == 0))
    return torch.where(zero, torch.zeros_like(turn), turn)


def _out(result: torch.Tensor, *args: Number) -> torch.Tensor | float:
    if any(isinstance(a, torch.Tensor) for a in args):
        return result
    return float(result)


def movement_score(
    i1: Number, j1: Number, i2: Number, j2: Number, *, A1: float = 9.0, alpha1: float = 1 / 3
) -> torch.Tensor | float:
    """Movement score of eq. (8): ``alpha1 * (A1 - ((i2 - i1)^2 + (j2 - j1)^2))``.

    Args:
        i1: x of the first move (int or tensor; all arguments broadcast).
        j1: y of the first move.
        i2: x of the second move.
        j2: y of the second move.
        A1: maximum squared change of velocity that still scores positive.
        alpha1: scale.

    Returns:
        A float when all moves are Python numbers, else a float64 tensor of the broadcast shape.

    Examples:
        >>> movement_score(1, 0, 1, 0, A1=9, alpha1=0.5)
        4.5
        >>> movement_score(1, 0, 0, 1, A1=9, alpha1=0.5)
        3.5
    """
    A1 = check_number("A1", A1)
    alpha1 = check_number("alpha1", alpha1)
    ti1, tj1, ti2, tj2 = (_as_tensor(a).double() for a in (i1, j1, i2, j2))
    change = (ti2 - ti1) ** 2 + (tj2 - tj1) ** 2
    return _out(alpha1 * (A1 - change), i1, j1, i2, j2)


def curvature_score(
    i1: Number, j1: Number, i2: Number, j2: Number, *, A2: float = 2.12, alpha2: float = 2.0
) -> torch.Tensor | float:
    """Curvature score of eq. (9): ``alpha2 * (A2 - theta)``, ``theta`` the turn in [0, pi].

    Args:
        i1: x of the first move (int or tensor; all arguments broadcast).
        j1: y of the first move.
        i2: x of the second move.
        j2: y of the second move.
        A2: largest turn (radians) that still scores positive.
        alpha2: scale.

    Returns:
        A float when all moves are Python numbers, else a float64 tensor of the broadcast shape.

    Examples:
        >>> round(curvature_score(1, 0, 1, 0, A2=2.356, alpha2=1.91), 2)
        4.5
        >>> round(curvature_score(1, 0, 0, 1, A2=2.356, alpha2=1.91), 2)
        1.5
    """
    A2 = check_number("A2", A2)
    alpha2 = check_number("alpha2", alpha2)
    ti1, tj1, ti2, tj2 = (_as_tensor(a) for a in (i1, j1, i2, j2))
    ti1, tj1, ti2, tj2 = torch.broadcast_tensors(ti1, tj1, ti2, tj2)
    return _out(alpha2 * (A2 - _turn(ti1, tj1, ti2, tj2)), i1, j1, i2, j2)


def point_score(
    i1: Number,
    j1: Number,
    i2: Number,
    j2: Number,
    *,
    A1: float = 9.0,
    alpha1: float = 1 / 3,
    A2: float = 2.12,
    alpha2: float = 2.0,
) -> torch.Tensor | float:
    """Score of a point entered by move ``(i1, j1)`` and left by ``(i2, j2)``.

    The mean of :func:`movement_score` and :func:`curvature_score` (our reading of section
    III-B of [LA98]), compared with the threshold 2.5 of section IV-C.

    Examples:
        >>> round(point_score(2, 1, 2, 1), 2)  # straight, constant speed
        3.62
        >>> round(point_score(1, 0, 1, 1), 2)  # 45-degree turn
        2.67
        >>> point_score(1, 0, 0, 1) < 2.5  # right-angle turn
        True
    """
    m = movement_score(i1, j1, i2, j2, A1=A1, alpha1=alpha1)
    c = curvature_score(i1, j1, i2, j2, A2=A2, alpha2=alpha2)
    return 0.5 * (m + c)

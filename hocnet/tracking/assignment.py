"""Murty's k-best 2-D assignment over :func:`scipy.optimize.linear_sum_assignment`.

The global-hypothesis step of the track-oriented MHT ([PD] section 24.4.4, step 4) needs the ``k``
best ways to assign the measurements of a scan to the tracks of a hypothesis (or to "new track" /
"false alarm" dummy columns). Murty's algorithm (K. G. Murty, "An algorithm for ranking all the
assignments in order of increasing cost", Operations Research 16(3), 1968; in tracking: Cox and
Hingorani, IEEE PAMI 18(2), 1996) partitions the solution space around each best solution and
solves one ordinary assignment per subproblem.

Conventions: a cost matrix ``C`` of shape ``(n, m)``; an assignment is a set of ``min(n, m)``
pairs ``(row, col)`` using each row and each column at most once (every row is assigned when
``n <= m``, every column when ``n > m``). ``+inf`` marks a forbidden pair (the "large cost" of a
gate failure); an assignment may not use one. The cost of an assignment is the sum of its entries.
"""

from __future__ import annotations

import heapq
import itertools
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment

from hocnet._check import _describe, check_int

__all__ = ["Assignment", "brute_force_assignments", "k_best_assignments"]


class Assignment(NamedTuple):
    """One assignment: total ``cost`` and the pairs ``(rows[i], cols[i])`` sorted by row."""

    cost: float
    rows: np.ndarray
    cols: np.ndarray


def _cost_matrix(cost: Any) -> np.ndarray:
    try:
        c = np.array(cost, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"`cost`: expected a real 2-D array, got {_describe(cost)}") from None
    if c.ndim != 2:
        raise ValueError(f"`cost`: expected a 2-D matrix (n, m), got shape {c.shape}")
    if np.isnan(c).any() or np.isneginf(c).any():
        raise ValueError("`cost`: expected finite values or +inf (forbidden), got NaN or -inf")
    return c


def _solve(c: np.ndarray) -> tuple[float, np.ndarray, np.ndarray] | None:
    """Best assignment of ``c`` (rows <= cols), or ``None`` when every assignment is forbidden."""
    finite = np.isfinite(c)
    if not finite.all():
        # scipy accepts +inf as forbidden; replace it by a cost larger than any feasible total
        # so that an infeasible problem is recognised by the use of a forbidden pair.
        span = np.abs(c[finite]).sum() if finite.any() else 0.0
        big = 2.0 * span + 1.0
        c = np.where(finite, c, big)
    rows, cols = linear_sum_assignment(c)
    if not finite[rows, cols].all():
        return None
    return float(c[rows, cols].sum()), rows, cols


def k_best_assignments(cost: Any, k: int) -> list[Assignment]:
    """The ``k`` lowest-cost assignments of a (possibly rectangular) cost matrix, best first.

    Murty's partitioning: after the best solution ``{(r_1, c_1), ..., (r_p, c_p)}`` of a
    subproblem (its free rows in order), subproblem ``i`` forces the pairs ``1..i-1`` and forbids
    pair ``i``; the subproblems are disjoint and cover every other solution, so popping them from a
    priority queue yields the solutions in order of cost. Each subproblem is one call to
    :func:`scipy.optimize.linear_sum_assignment` with forbidden pairs at a cost larger than any
    feasible total.

    Args:
        cost: ``(n, m)`` real matrix; ``+inf`` forbids a pair. Either dimension may be 0 (then the
            only assignment is the empty one, of cost 0).
        k: number of assignments wanted (``>= 1``); fewer are returned when fewer exist.

    Returns:
        ``Assignment(cost, rows, cols)`` tuples in order of non-decreasing cost (ties in an
        unspecified order); an empty list when no assignment avoids the forbidden pairs.

    Raises:
        TypeError, ValueError: ``cost`` not a real 2-D matrix, NaN or ``-inf`` in it, bad ``k``.

    Examples:
        >>> [a.cost for a in k_best_assignments([[1.0, 2.0], [3.0, 1.0]], 3)]
        [2.0, 5.0]
        >>> a = k_best_assignments([[0.0, float("inf"), 1.0]], 2)
        >>> [(a_.cost, a_.cols.tolist()) for a_ in a]
        [(0.0, [0]), (1.0, [2])]
    """
    c = _cost_matrix(cost)
    k = check_int("k", k, minimum=1)
    transposed = c.shape[0] > c.shape[1]
    if transposed:
        c = c.T
    n = c.shape[0]
    if n == 0:
        empty = np.zeros(0, dtype=np.int64)
        return [Assignment(0.0, empty, empty.copy())]
    if n == 1:  # one row: the k best are the k smallest allowed entries (fast path)
        row = c[0]
        cols = np.flatnonzero(np.isfinite(row))
        cols = cols[np.argsort(row[cols], kind="stable")][:k]
        zero = np.zeros(1, dtype=np.int64)
        return [
            _result(float(row[j]), zero, np.array([j], dtype=np.int64), transposed) for j in cols
        ]
    first = _solve(c)
    if first is None:
        return []
    out: list[Assignment] = []
    tie = itertools.count()
    # queue entries: (cost, tie, rows, cols, forced pairs, forbidden pairs)
    queue: list[Any] = [(first[0], next(tie), first[1], first[2], (), ())]
    while queue and len(out) < k:
        total, _, rows, cols, forced, forbidden = heapq.heappop(queue)
        out.append(_result(total, rows, cols, transposed))
        if len(out) == k:
            break
        forced_rows = {r for r, _ in forced}
        free = [(int(r), int(cc)) for r, cc in zip(rows, cols) if int(r) not in forced_rows]
        sub = c.copy()
        for r, cc in forbidden:
            sub[r, cc] = np.inf
        for r, cc in forced:
            _force(sub, r, cc)
        fixed = list(forced)
        for r, cc in free:
            child = sub.copy()
            child[r, cc] = np.inf
            solved = _solve(child)
            if solved is not None:
                entry = (
                    solved[0],
                    next(tie),
                    solved[1],
                    solved[2],
                    tuple(fixed),
                    (*forbidden, (r, cc)),
                )
                heapq.heappush(queue, entry)
            _force(sub, r, cc)
            fixed.append((r, cc))
    return out


def _force(c: np.ndarray, r: int, col: int) -> None:
    """Force the pair ``(r, col)``: every other entry of row ``r`` and column ``col`` forbidden."""
    keep = c[r, col]
    c[r, :] = np.inf
    c[:, col] = np.inf
    c[r, col] = keep


def _result(total: float, rows: np.ndarray, cols: np.ndarray, transposed: bool) -> Assignment:
    rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
    if transposed:
        rows, cols = cols, rows
    order = np.argsort(rows, kind="stable")
    return Assignment(float(total), rows[order], cols[order])


def brute_force_assignments(cost: Any) -> list[Assignment]:
    """Every assignment avoiding forbidden pairs, sorted by cost: the slow reference of the tests.

    Enumerates all injective maps from the shorter side of ``cost`` to the longer one
    (``m! / (m - n)!`` of them), so use it only on small matrices.

    Args:
        cost: ``(n, m)`` real matrix, ``+inf`` forbidden.

    Returns:
        All feasible assignments in order of non-decreasing cost.

    Examples:
        >>> [a.cost for a in brute_force_assignments([[1.0, 2.0], [3.0, 1.0]])]
        [2.0, 5.0]
    """
    c = _cost_matrix(cost)
    transposed = c.shape[0] > c.shape[1]
    if transposed:
        c = c.T
    n, m = c.shape
    rows = np.arange(n)
    out = []
    for perm in itertools.permutations(range(m), n):
        cols = np.array(perm, dtype=np.int64)
        vals = c[rows, cols] if n else np.zeros(0)
        if np.isfinite(vals).all():
            out.append(_result(float(vals.sum()), rows, cols, transposed))
    out.sort(key=lambda a: a.cost)
    return out

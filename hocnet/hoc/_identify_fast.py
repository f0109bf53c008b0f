"""Faster equivalents of parts of track identification, for the streaming latency (our addition).

Each helper gives the same result as the :mod:`hocnet.hoc.identify` code it stands for (tested
against it on random inputs, ``tests/hoc/test_identify_fast.py``); none changes which points,
sequences or tracks are kept. :mod:`hocnet.hoc.identify` calls them (where, is said in each
docstring, "Wiring"); ``detect`` with them gives the same result, bit for bit, as with the code
they replace (``test_detect_wired_equals_unwired``).

Measured on 640 x 512 windows at 2 % clutter, order 2 (the scans of ``benchmarks/hoc.py
--stream``; process time per window, one thread, on the shared machine at load 5-10, so the
absolute values are inflated; the ratios are what counts): the near-duplicate tests 27 -> 1 ms
(:func:`kept_sharing_a_point`), the whole-sequence rows 23 -> 11-12 ms built once instead of
twice (:func:`whole_sequences_from_rows`), ``_best_paths`` 18.5 -> 11.7 ms
(:func:`best_paths`), ``_score_paths`` 7.5 -> 5.3 ms (:func:`score_paths_passing`).
Wired into :mod:`hocnet.hoc.identify` (with :func:`make_tracks`, :func:`pairs`, the
near-duplicate test reading the coordinates of the candidates' points only, and ``_sequences``
skipped where the whole-sequence scores replace it), the median process time of a
``StreamingDetector`` push at 2 % clutter (``benchmarks/hoc.py --stream --threads 1
--densities 0.02``, before and after at load 3-5): order 2 116 -> 69 ms (``mhoc``) and
199 -> 98 ms (``chain``), order 3 42 -> 28 ms and 74 -> 62 ms; over the max-pool floor
(process time, 12.4-12.9 ms): 9.3 -> 5.4, 15.6 -> 7.6, 3.2 -> 2.3 and 5.8 -> 4.8. Every
window still equals batch ``detect``.

Second round (the 4x target at 2 %, order 2, ``mhoc``): the helpers work on NumPy views of
the tensors (integer indexing and element-wise IEEE operations give the same bits; torch's
per-operation overhead, 5-30 us on 20 000 triples, and its slow advanced indexing are gone),
the chains are handed to the scoring as arrays (:class:`PathList`), and every point score of
a half-pixel move pair is read from a table (:func:`_score_table`, the same bits as the
references' element-wise scoring). Measured per window on the same scans (process time,
load 5-10, instrumented): :func:`best_paths` 13.6 -> 3.7 ms (DP columns restricted to the
finite chains, the chain table to triples whose bound reaches the pass mark),
:func:`score_paths_passing` 7.4 -> 2.5 ms, the whole-sequence rows 8.6 -> 2.3 ms
(:func:`whole_sequence_rows`), ``enumerate_paths_vectorised`` 5.6 -> 3.2 ms; with the
streaming detector's own changes (:mod:`hocnet.hoc.stream`) the median push (process time,
20 pushes, old and new code back to back at load 6) went 69.0 -> 39.9 ms at 2 %, order 2,
``mhoc`` (116.5 -> 54.4 ms with ``chain``; order 3: 37.7 -> 19.2 and 65.5 -> 32.2 ms; at 1 %:
9.1-10.8 ms from 13.0-18.9 ms); ``benchmarks/results/hoc_stream.md`` for the benchmark.

Third round (task h7speed, ``support="chain"`` at 2 %, order 2, whose identification had
grown with the lone-track and track-end rescues of ``identify._extensions``): old and new
code alternating on the same captured windows in one process (process time, medians of 15,
load 1-2): ``_extensions`` 26.8 -> 9.4 ms (:func:`unique_links` and :func:`extend_alone`
instead of a dictionary of lists over every triple, :func:`beats_scorer` instead of
``_score_paths`` per proposal, :func:`path_points`), an over-cap window's
``_enumerate_paths`` 14.9 -> 7.5 ms (:func:`hocnet.hoc._incremental.chain_clusters`, the
capped loop reading the accepted triples only, :class:`PathList` lazy, also across ``+``),
:func:`best_paths` 11.6 -> 10.1 ms (its first maximum by row reductions), :func:`fill_scores`
1.9 -> 1.3 ms; the median push (paired, 41 pushes) 72.8 -> 45.7 ms, every window equal.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from itertools import chain
from typing import Any

import numpy as np
import torch

__all__: list[str] = []


def kept_sharing_a_point(pts: list[int], kept_at: dict[int, list[int]]) -> list[int]:
    """The kept tracks (indices, ascending) that share at least one point with ``pts``.

    ``identify._is_near_duplicate(pts, kept, ...)`` can only answer ``True`` through a kept
    track ``K`` that shares a point with the candidate ``C``: it needs at least one differing
    point (``1 <= len(diff)``) and, next to every differing point, a point of ``C`` on ``K``
    (``_next_to_shared``). Asking only these tracks is therefore the same answer as asking all
    of them, with or without ``explained`` (the answer is "any kept track qualifies", so their
    order does not matter either).

    Wiring: in ``identify._select_tracks``, ask these tracks in both cases::

        others = [kept_scans[i] for i in kept_sharing_a_point(pts, kept_at)]

    instead of ``others = kept_scans`` when ``explained`` (every kept track: 161 000 track
    comparisons per 640 x 512 window at 2 % clutter, 27 ms of process time, against 1 ms).

    Args:
        pts: the candidate's point indices.
        kept_at: point index -> the indices of the kept tracks through it.

    Returns:
        Sorted indices into the kept tracks.

    Examples:
        >>> kept_sharing_a_point([4, 5, 6], {5: [0, 2], 6: [2], 9: [1]})
        [0, 2]
    """
    return sorted({i for q in pts for i in kept_at.get(q, ())})


def group_best(groups: torch.Tensor, key: torch.Tensor, n_groups: int) -> torch.Tensor:
    """``identify._group_best``: per group, the index of its largest key (first on ties), or -1.

    The same two scatter reductions (the group maximum, then the first index reaching it) on
    NumPy views (``ufunc.at``); NaN keys, integer keys or no entries: the reference.

    Wiring: ``identify._identify_sequences`` picks each image point's best sequence and end
    triples with ``group_best`` instead of ``_group_best``.

    Examples:
        >>> key = torch.tensor([1.0, 3.0, 3.0, 2.0], dtype=torch.float64)
        >>> group_best(torch.tensor([0, 0, 0, 2]), key, 4).tolist()
        [1, -1, 3, -1]
    """
    from hocnet.hoc.identify import _group_best

    if groups.numel() == 0 or not key.is_floating_point():
        return _group_best(groups, key, n_groups)
    k = key.numpy()
    if bool(np.isnan(k).any()):
        return _group_best(groups, key, n_groups)
    return torch.from_numpy(_group_best_np(groups.numpy(), k, n_groups))


def _group_best_np(g: np.ndarray, k: np.ndarray, n_groups: int) -> np.ndarray:
    """:func:`group_best` on arrays (no NaN in ``k``)."""
    best = np.full(n_groups, -math.inf, dtype=k.dtype)
    np.maximum.at(best, g, k)
    hit = np.flatnonzero(k == best[g])
    first = np.full(n_groups, g.size, dtype=np.int64)
    np.minimum.at(first, g[hit], hit)
    return np.where(first < g.size, first, -1)


def short_track_sequences(
    rows: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
    p0: torch.Tensor,
    p1: torch.Tensor,
    p2: torch.Tensor,
    is_root: torch.Tensor,
) -> torch.Tensor:
    """``identify._short_track_sequences`` on NumPy views: the same accepted triples.

    The same Case-1 test of every row, the same best row per short track
    (:func:`_group_best_np`, first on ties), the same marks. NaN keys: the reference.

    Wiring: ``identify._identify_sequences`` calls ``short_track_sequences`` instead of
    ``_short_track_sequences`` (same signature).

    Examples:
        >>> rows = (torch.tensor([0, 1]), torch.tensor([-1, 0]), torch.tensor([1, -1]),
        ...         torch.tensor([203.0, 203.0], dtype=torch.float64))
        >>> p0, p1, p2 = torch.tensor([0, 1]), torch.tensor([1, 2]), torch.tensor([2, 3])
        >>> short_track_sequences(rows, p0, p1, p2, torch.ones(4, dtype=torch.bool)).tolist()
        [True, True]
    """
    from hocnet.hoc.identify import _short_track_sequences

    c_idx, left_t, right_t, key_rows = (x.numpy() for x in rows)
    if bool(np.isnan(key_rows).any()):
        return _short_track_sequences(rows, p0, p1, p2, is_root)
    k = p0.numel()
    q0, q1, q2 = p0.numpy(), p1.numpy(), p2.numpy()
    root = is_root.numpy()
    lt, rt = np.maximum(left_t, 0), np.maximum(right_t, 0)
    case1 = root[q0[c_idx]] & root[q1[c_idx]] & root[q2[c_idx]]
    case1 &= ((left_t < 0) | root[q0[lt]]) & ((right_t < 0) | root[q2[rt]])
    accepted = np.zeros(k, dtype=bool)
    for half in (left_t, right_t):
        ok = np.flatnonzero(case1 & (half >= 0))
        if ok.size == 0:
            continue
        best = _group_best_np(half[ok], key_rows[ok], k)
        rsel = ok[best[best >= 0]]
        accepted[c_idx[rsel]] = True
        left, right = left_t[rsel], right_t[rsel]
        accepted[left[left >= 0]] = True
        accepted[right[right >= 0]] = True
    return torch.from_numpy(accepted)


def whole_sequences_from_rows(
    rows: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], k: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``identify._whole_sequences`` from rows already built by ``_whole_sequence_rows``.

    ``_identify_sequences`` builds the same rows twice with ``shared_points`` and
    ``score_span > 1`` (the defaults): once inside ``_whole_sequences`` and once for
    ``_short_track_sequences``, with the same arguments (``seq_kw is track_kw``).

    Wiring (in ``identify._identify_sequences``)::

        rows = None
        if track_kw is not None and track_kw["span"] > 1:
            a_in, a_out, _ = _edge_ids(n, p0, p1, p2)  # _sequences' other results unused
            rows = _whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, track_kw)
            left, right, key = whole_sequences_from_rows(rows, p0.numel())
        else:
            a_in, a_out, left, right, key = _sequences(n, p0, p1, p2, s)
        ...
        if shared_points:
            seq_kw = track_kw if track_kw is not None else {**score_kwargs, "span": 1}
            if rows is None or seq_kw is not track_kw:
                rows = _whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, seq_kw)

    Args:
        rows: ``(c_idx, left, right, key)`` of ``identify._whole_sequence_rows``.
        k: number of triples.

    Returns:
        ``(left, right, key)``, ``(k,)`` each, as ``identify._whole_sequences`` returns them.

    Examples:
        >>> rows = (torch.tensor([0, 0, 1]), torch.tensor([-1, -1, 0]),
        ...         torch.tensor([1, -1, -1]), torch.tensor([202.5, 101.0, 202.0]))
        >>> [t.tolist() for t in whole_sequences_from_rows(rows, 2)]
        [[-1, 0], [1, -1], [202.5, 202.0]]
    """
    c_idx, left_t, right_t, key_rows = rows
    best = group_best(c_idx, key_rows, k)
    return left_t[best], right_t[best], key_rows[best]


def fill_scores(
    scores_cube: torch.Tensor,
    flat: torch.Tensor,
    p0: torch.Tensor,
    p1: torch.Tensor,
    p2: torch.Tensor,
    s: torch.Tensor,
) -> None:
    """``identify._fill_scores``: each point's best score over its triples, written in place.

    The same per-point maxima (the same scatter reduction, middle points first, then the
    ends), written into the cube through NumPy views (fancy indexing without torch's
    per-operation overhead; one write for the three passes): a point keeps the value written
    first.

    Wiring: ``identify._identify_sequences`` calls ``fill_scores`` instead of ``_fill_scores``.

    Examples:
        >>> cube = torch.full((4,), math.nan, dtype=torch.float64)
        >>> fill_scores(cube, torch.tensor([0, 1, 3]), torch.tensor([0]), torch.tensor([1]),
        ...             torch.tensor([2]), torch.tensor([2.5], dtype=torch.float64))
        >>> cube.tolist()
        [2.5, 2.5, nan, 2.5]
    """
    cube = scores_cube.numpy()
    q = flat.numpy()
    # the three passes of the reference write a point's middle maximum if it has one (not
    # NaN), else its first-point one, else its last-point one, where the cube holds NaN: the
    # same values picked per point first, then one gather and one write into the cube
    value = None
    for members in (p1, p0, p2):
        best = torch.full((q.size,), -math.inf, dtype=torch.float64)
        best.scatter_reduce_(0, members, s, reduce="amax")
        b = best.numpy()
        value = b if value is None else np.where(value > -math.inf, value, b)
    has = value > -math.inf
    idx = q[has]
    cur = cube[idx]
    cube[idx] = np.where(np.isnan(cur), value[has], cur)


def whole_sequence_rows(
    a_in: torch.Tensor,
    a_out: torch.Tensor,
    p0: torch.Tensor,
    p1: torch.Tensor,
    p2: torch.Tensor,
    coords: torch.Tensor,
    track_kw: dict[str, Any],
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``identify._whole_sequence_rows``: the same rows, in the same order, with the same keys.

    Every five-point sequence (centre triple, left triple or -1, right triple or -1) with its
    whole-sequence key. The changes, none touching a value:

    - the left options of a centre (the triples ending with its in-edge, ascending, or -1 when
      there are none) and its right options are read off one stable counting sort of the
      out-edges and of the in-edges (the rows of ``_pairs`` + ``_product_rows`` without
      ``_pairs``' searches and the two option sorts);
    - the moves are taken doubled from the integer coordinates (``2 m``: every move of the
      rows is a whole or a half pixel), as sums of the triples' own moves coded linearly
      (:func:`_move_code`), and the three point scores of a row read from the table of every
      half-pixel move pair (:func:`_score_table`), the same bits as scoring them in one batch;
      where a row has no left (right) triple the score read is dropped by the same ``where``;
    - the key ``100 * count + total / count`` with the same IEEE operations in the same order.

    Moves beyond the table (:data:`TABLE_REACH`) or no triples: the reference runs.

    Wiring: ``identify._identify_sequences`` calls ``whole_sequence_rows`` instead of
    ``_whole_sequence_rows`` (same signature).

    Examples:
        >>> coords = torch.tensor([[t, 2, 2 + t] for t in range(5)])
        >>> p0, p1, p2 = torch.tensor([0, 1, 2]), torch.tensor([1, 2, 3]), torch.tensor([2, 3, 4])
        >>> a_in, a_out = torch.tensor([0, 1, 2]), torch.tensor([1, 2, 3])
        >>> kw = {"A1": 9.0, "alpha1": 1 / 3, "A2": 2.12, "alpha2": 2.0, "combine": "min"}
        >>> kw["span"] = 2
        >>> c, left, right, key = whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, kw)
        >>> c.tolist(), left.tolist(), right.tolist(), key.tolist()
        ([0, 1, 2], [-1, 0, 1], [1, 2, -1], [203.0, 303.0, 203.0])
    """
    from hocnet.hoc.identify import _whole_sequence_rows

    k = p0.numel()
    if k == 0:
        return _whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, track_kw)
    ai, ao = a_in.numpy(), a_out.numpy()
    q0_i, q1_i, q2_i = p0.numpy(), p1.numpy(), p2.numpy()
    n_e = int(max(ai.max(), ao.max())) + 1
    # triples by out-edge (the left options of a centre: out-edge == its in-edge) and by in-edge
    by_out = _stable_order(ao, n_e)
    by_in = _stable_order(ai, n_e)
    cnt_out = np.bincount(ao, minlength=n_e)
    cnt_in = np.bincount(ai, minlength=n_e)
    n_l, n_r = cnt_out[ai], cnt_in[ao]  # left / right triples of each centre
    lo_l = (np.cumsum(cnt_out) - cnt_out)[ai]
    lo_r = (np.cumsum(cnt_in) - cnt_in)[ao]
    ways_l, ways_r = np.maximum(n_l, 1), np.maximum(n_r, 1)
    n_rows = ways_l * ways_r
    c_idx = np.repeat(np.arange(k), n_rows)
    off = np.arange(c_idx.size) - np.repeat(np.cumsum(n_rows) - n_rows, n_rows)
    wr = ways_r[c_idx]
    li, ri = off // wr, off % wr
    has_l, has_r = n_l[c_idx] > 0, n_r[c_idx] > 0
    left_t = np.where(has_l, by_out[np.where(has_l, lo_l[c_idx] + li, 0)], -1)
    right_t = np.where(has_r, by_in[np.where(has_r, lo_r[c_idx] + ri, 0)], -1)
    # each triple's two moves as one linear code (``_move_code``); the rows' doubled moves
    # are sums of them: q1 -> q2 is the centre's first move, q0 -> q1 its left triple's,
    # q2 -> q3 the centre's second, q3 -> q4 its right triple's
    m1, m2, reach = _triple_moves(coords, q0_i, q1_i, q2_i)
    if reach is None:
        return _whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, track_kw)
    c1, c2 = m1[c_idx], m2[c_idx]
    lm = m1[np.maximum(left_t, 0)]  # q1 - q0 (read only with a left triple)
    rm = m2[np.maximum(right_t, 0)]  # q4 - q3 (read only with a right triple)
    kw = {key: val for key, val in track_kw.items() if key != "span"}
    # doubled moves: h_l = (q2 - q0) / 2 with a left triple (span > 1), else q2 - q1; likewise
    if track_kw["span"] > 1:
        h_l = np.where(has_l, c1 + lm, 2 * c1)
        h_r = np.where(has_r, c2 + rm, 2 * c2)
    else:
        h_l, h_r = 2 * c1, 2 * c2
    mid = c1 + c2  # 2 * ((q3 - q1) / 2)
    table = _score_table(kw, reach)
    centre = _read_table(table, h_l, h_r, reach)
    s1 = _read_table(table, np.where(has_l, 2 * lm, 0), mid, reach)  # q0 -> q1, (q3 - q1) / 2
    s3 = _read_table(table, mid, np.where(has_r, 2 * rm, 0), reach)  # (q3 - q1) / 2, q3 -> q4
    total = centre + np.where(has_l, s1, 0.0) + np.where(has_r, s3, 0.0)
    count = 1 + has_l.astype(np.int64) + has_r.astype(np.int64)
    key_rows = 100.0 * count + total / count
    return (
        torch.from_numpy(c_idx),
        torch.from_numpy(left_t),
        torch.from_numpy(right_t),
        torch.from_numpy(key_rows),
    )


def _move_code(dy: np.ndarray, dx: np.ndarray, reach: int) -> np.ndarray:
    """A doubled move ``(dy, dx)`` (each ``|.| <= reach``) as ``dx * w + dy``, ``w = 2 reach + 1``.

    Linear: the code of a sum (or multiple) of moves is the sum (multiple) of their codes, as
    long as the result stays within ``reach``; :func:`_read_table` reads the score of a pair.
    """
    return dx * (2 * reach + 1) + dy


def _triple_moves(
    coords: torch.Tensor, q0: np.ndarray, q1: np.ndarray, q2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int | None]:
    """Codes (``_move_code``) of each triple's two moves and the table reach they need.

    ``reach``: the table's half-width for sums of two moves doubled (at least 8, one table for
    ``v <= 4``); ``None`` when it would exceed :data:`TABLE_REACH`.
    """
    t = coords.numpy()
    y, x = t[:, 1], t[:, 2]
    dy1, dx1 = y[q1] - y[q0], x[q1] - x[q0]
    dy2, dx2 = y[q2] - y[q1], x[q2] - x[q1]
    big = max((int(np.abs(d).max()) for d in (dy1, dx1, dy2, dx2) if d.size), default=0)
    reach = max(8, 2 * big)
    if reach > TABLE_REACH:
        return dy1, dy1, None
    return _move_code(dy1, dx1, reach), _move_code(dy2, dx2, reach), reach


def _read_table(table: np.ndarray, h1: np.ndarray, h2: np.ndarray, reach: int) -> np.ndarray:
    """Scores of the doubled move pairs with codes ``h1``, ``h2`` (:func:`_move_code`)."""
    w = 2 * reach + 1
    off = reach * (w + 1)  # the code of (-reach, -reach) is -off
    return table[(h1 + off) * (w * w) + h2 + off]


def _stable_order(ids: np.ndarray, n_ids: int) -> np.ndarray:
    """Stable argsort of ids in ``[0, n_ids)`` (identity when sorted; 16-bit radix if they fit)."""
    if ids.size < 2 or bool((ids[1:] >= ids[:-1]).all()):
        return np.arange(ids.size)
    if n_ids <= 1 << 16:
        return np.argsort(ids.astype(np.uint16), kind="stable")
    return np.argsort(ids, kind="stable")


def pairs(keys: torch.Tensor, queries: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``identify._pairs`` for ids ``>= 0``: all ``(i, j)`` with ``keys[j] == queries[i]``.

    The same pairs in the same order (``i`` ascending, then ``j`` in ascending order within
    equal keys): the run of each id in the stable sort of ``keys`` starts at the number of
    smaller keys (a cumulative ``bincount``) instead of where ``searchsorted`` finds it; integer
    work only, linear in the number of ids.

    Wiring: ``identify._whole_sequence_rows`` joins the triples' edge ids
    (``identify._edge_ids``, ``>= 0``) with ``pairs`` instead of ``_pairs``.

    Args:
        keys: ``(M,)`` int64 ids, ``>= 0``.
        queries: ``(Q,)`` int64 ids, ``>= 0``.

    Returns:
        ``(i, j)``: int64 indices into ``queries`` and ``keys``.

    Examples:
        >>> i, j = pairs(torch.tensor([3, 1, 3]), torch.tensor([3, 2, 1]))
        >>> i.tolist(), j.tolist()
        ([0, 0, 2], [0, 2, 1])
    """
    order = torch.argsort(keys, stable=True)
    n_ids = max((int(x.max()) for x in (keys, queries) if x.numel()), default=-1) + 1
    count = torch.bincount(keys, minlength=n_ids)
    lo = (torch.cumsum(count, 0) - count)[queries]
    cnt = count[queries]
    i = torch.repeat_interleave(torch.arange(queries.numel()), cnt)
    start = torch.repeat_interleave(lo - torch.cumsum(cnt, 0) + cnt, cnt)
    j = order[start + torch.arange(i.numel())]
    return i, j


def best_paths(
    n: int,
    p0: torch.Tensor,
    p1: torch.Tensor,
    p2: torch.Tensor,
    s: torch.Tensor,
    a_in: torch.Tensor,
    a_out: torch.Tensor,
    n_t: int,
    threshold: float,
    min_points: int,
    points: torch.Tensor,
) -> list[list[int]]:
    """``identify._best_paths`` with the same arithmetic in fewer, cheaper array passes.

    Same arguments, same chains in the same order. The changes, none touching a value:

    - the work is done on NumPy views of the tensors (integer indexing and element-wise
      ``+``, ``-``, comparisons and ``where``: the same IEEE operations, the same bits; no
      per-operation dispatch overhead of torch, about 5-30 us per call on 20 000 triples);
    - the dynamic-programming sweeps group the triples by their joining edge once (a stable
      sort; the in-edges come sorted) and take each column's group maximum and the first
      triple reaching it with two segment reductions (``reduceat``) instead of two scatter
      reductions and a ``nonzero`` per column: the same continuation (the largest sum, the
      lowest triple index on ties, none where every sum is ``-inf``);
    - the table of chain sums over (backward length, forward length) is built only for the
      triples whose bound reaches the pass mark, as ``(L, L, Ks)`` in place: every entry is
      the same ``(bw + fw) - w``; its flat arg-max per triple, the first maximum in
      ``(lb, lf)`` order as ``argmax`` gives it, is the lowest row equal to the column
      maximum (two reductions along rows; the sums are finite or ``-inf``, never NaN);
    - the chains are read off the pointer walks (the table of ``identify._walk``) with one
      filter and one ``tolist`` for all of them, not a Python filter per chain.

    With NaN scores (never produced by :func:`~hocnet.hoc.scoring.point_score` on integer
    moves), the reference itself runs. Measured on the 640 x 512, 2 % clutter, order-2
    windows of ``benchmarks/hoc.py --stream`` (20 000 triples, 13 000 points asked): 12.3 ->
    see the module notes.

    Wiring: ``identify._extensions`` calls ``best_paths`` instead of ``_best_paths`` (same
    signature).

    Examples:
        >>> p0, p1, p2 = torch.tensor([0, 1, 2]), torch.tensor([1, 2, 3]), torch.tensor([2, 3, 4])
        >>> a_in, a_out = torch.tensor([0, 1, 2]), torch.tensor([1, 2, 3])
        >>> s = torch.tensor([3.0, 3.0, 3.0], dtype=torch.float64)
        >>> middle = torch.tensor([False, False, True, False, False])
        >>> best_paths(5, p0, p1, p2, s, a_in, a_out, 5, 2.5, 5, middle)  # triples 0, 1, 2
        [[0, 1, 2]]
    """
    k = p0.numel()
    w = (s - threshold).numpy()
    if k == 0 or not bool(np.isfinite(w).all()):
        from hocnet.hoc.identify import _best_paths

        return _best_paths(n, p0, p1, p2, s, a_in, a_out, n_t, threshold, min_points, points)
    ai, ao = a_in.numpy(), a_out.numpy()
    n_e = int(max(ai.max(), ao.max())) + 1
    L = max(1, n_t - 2)  # most triples on one chain
    neg = -math.inf

    def sweep(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # best[l]: best sum of a chain starting at triple k and continuing l triples (through
        # dst -> src edges); ptr[l]: the next triple (-1: none); (L, K), one row per length
        best = np.full((L, k), neg)
        ptr = np.full((L, k), -1, dtype=np.int32 if k < 1 << 31 else np.int64)  # half the pages
        best[0] = w
        idx = np.arange(k)  # the triples whose previous column is finite
        top = np.empty(n_e)  # per column: refilled, not reallocated (no fresh pages)
        first = np.empty(n_e, dtype=np.int64)
        for ell in range(1, L):
            col = best[ell - 1]
            g, key = src[idx], col[idx]
            top.fill(neg)
            np.maximum.at(top, g, key)  # each edge's largest sum
            hit = key == top[g]
            first.fill(k)
            np.minimum.at(first, g[hit], idx[hit])  # the lowest triple reaching it
            nxt = first[dst]
            idx = np.flatnonzero(nxt < k)
            if idx.size == 0:
                break  # no chain continues further: the remaining columns stay empty
            nxt = nxt[idx]
            best[ell, idx] = w[idx] + col[nxt]
            ptr[ell, idx] = nxt
        return best, ptr

    fw, fptr = sweep(ai, ao)  # continue with a triple starting on my out-edge
    bw, bptr = sweep(ao, ai)  # continue with a triple ending on my in-edge
    pts = points.numpy()
    q0, q1, q2 = p0.numpy(), p1.numpy(), p2.numpy()
    sub = np.flatnonzero(pts[q0] | pts[q1] | pts[q2])
    # a triple's table maximum is at most (max bw + max fw) - w (rounding is monotone): only
    # triples whose bound reaches the pass mark can be chosen (nor own a point that is)
    bound = (bw.max(axis=0)[sub] + fw.max(axis=0)[sub]) - w[sub]
    sub = sub[bound >= -1e-9]
    ks = sub.size
    if ks == 0:
        return []
    # the (L, L, Ks) table of chain sums over (backward length, forward length), each entry
    # (bw + fw) - w; the flat arg-max keeps the first maximum in (lb, lf) order
    length = np.arange(L)[:, None] + np.arange(L)[None, :] + 3
    bw_s, fw_s = np.take(bw, sub, axis=1), np.take(fw, sub, axis=1)
    total = bw_s[:, None, :] + fw_s[None, :, :]  # one table, the rest in place (same ops)
    total -= w[sub][None, None, :]
    total[length < min_points] = neg
    total = total.reshape(L * L, ks)
    # ``argmax(axis=0)`` (the first maximal row of each column; no NaN here: the sums are
    # finite or -inf) as a column maximum and the lowest row reaching it: two reductions
    # along rows instead of one short arg-max per column (6 ms -> 1 ms on 10 000 columns)
    rows = np.arange(L * L, dtype=np.min_scalar_type(L * L))
    arg = np.where(total == total.max(axis=0), rows[:, None], rows[-1]).min(axis=0)
    arg = arg.astype(np.int64)
    flat_best = total[arg, np.arange(ks)]
    members = np.concatenate([q0[sub], q1[sub], q2[sub]])
    values = np.tile(flat_best, 3)
    top = np.full(n, neg)
    np.maximum.at(top, members, values)
    hit = np.flatnonzero(values == top[members])
    owner = np.full(n, 3 * ks, dtype=np.int64)
    np.minimum.at(owner, members[hit], hit)  # the first triple reaching the point's best
    local = owner[pts & (owner < 3 * ks)] % ks
    local = np.sort(local[flat_best[local] >= -1e-9])
    if local.size == 0:
        return []
    local = local[np.concatenate(([True], local[1:] != local[:-1]))]  # unique, ascending
    chosen = sub[local]
    nb, nf = arg[local] // L, arg[local] % L
    # the rows of ``_walk`` (its table before the per-row filter), backward ones reversed, and
    # the chosen triple between: one filter and one ``tolist`` for all chains
    table = np.concatenate(
        [_walk_table(bptr, chosen, nb)[:, ::-1], chosen[:, None], _walk_table(fptr, chosen, nf)],
        axis=1,
    )
    keep = table >= 0
    flat = table[keep].tolist()
    ends = np.cumsum(keep.sum(axis=1)).tolist()
    return [flat[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]


def _walk_table(ptr: np.ndarray, start: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """``identify._walk`` before its per-row filter: ``(M, max steps)``, -1 past a row's end.

    ``identify._walk`` returns each row's entries ``>= 0`` of this table, in order; ``ptr`` is
    ``(L, K)`` (one row per chain length).
    """
    n_steps = int(steps.max()) if steps.size else 0
    cur = start.copy()
    rem = steps.copy()
    table = np.full((start.size, n_steps), -1, dtype=np.int64)
    for i in range(n_steps):
        on = rem > 0
        cur = np.where(on, ptr[np.maximum(rem, 0), cur], cur)
        table[:, i] = np.where(on, cur, -1)
        rem = rem - 1
    return table


class PathList(Sequence):
    """Chains of triples (a sequence of lists) that also carry their arrays, grouped by length.

    ``groups``: per chain length, ``(index, triples)``: the positions of the chains of that
    length in the list (ascending) and their triples, an ``(R, length)`` int64 array (row ``r``
    is chain ``index[r]``). Built by :func:`hocnet.hoc._incremental.enumerate_paths_vectorised`
    from the arrays it grows the chains in, so that :func:`score_paths_passing` need not turn
    the lists back into arrays (several groups may hold chains of one length, e.g. after
    ``+``). Equal to the plain list of its chains (``==``, ``+``, iteration, indexing); the
    Python lists are built from ``groups`` only when first asked for
    (the default identification reads ``groups`` and the length only: building and freeing
    20 000 lists cost about 2 ms per 640 x 512 window at 2 % clutter).
    """

    __slots__ = ("_n", "_rows", "groups")
    __hash__ = None  # type: ignore[assignment]  # mutable-list semantics: unhashable

    def __init__(
        self,
        rows: list[list[int]] | None,
        groups: list[tuple[np.ndarray, np.ndarray]],
        n: int | None = None,
    ):
        self.groups = groups
        self._rows = rows
        self._n = len(rows) if rows is not None else int(n or 0)

    def _list(self) -> list[list[int]]:
        if self._rows is None:
            rows: list[Any] = [None] * self._n
            for at, tri in self.groups:
                for i, row in zip(at.tolist(), tri.tolist(), strict=True):
                    rows[i] = row
            self._rows = rows
        return self._rows

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i: Any) -> Any:
        return self._list()[i]

    def __iter__(self) -> Iterator[list[int]]:
        return iter(self._list())

    def __eq__(self, other: object) -> bool:
        if isinstance(other, PathList):
            other = other._list()
        if isinstance(other, list):
            return self._list() == other
        return NotImplemented

    def __add__(self, other: Any) -> PathList:
        """The chains of both, as a :class:`PathList` (its groups: both lists' groups)."""
        if isinstance(other, PathList):
            more = other.groups
        elif isinstance(other, list):
            more = _path_groups(other) if other else []
        else:
            return NotImplemented
        shifted = [(index + self._n, tri) for index, tri in more]
        return PathList(None, [*self.groups, *shifted], self._n + len(other))

    def __radd__(self, other: Any) -> list[list[int]]:
        return other + self._list()

    def __repr__(self) -> str:
        return repr(self._list())


def _path_groups(paths: list[list[int]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """``PathList.groups`` of a plain list of chains (ascending length)."""
    groups = getattr(paths, "groups", None)
    if groups is not None:
        return sorted(groups, key=lambda g: g[1].shape[1])
    lens = np.fromiter(map(len, paths), dtype=np.int64, count=len(paths))
    every = np.fromiter(chain.from_iterable(paths), dtype=np.int64, count=int(lens.sum()))
    offset = np.cumsum(lens) - lens
    order = np.argsort(lens, kind="stable")  # by length, path order within a length
    length, start = np.unique(lens[order], return_index=True)
    out = []
    for rows, n_tr in zip(np.split(order, start[1:]), length.tolist(), strict=True):
        out.append((rows, every[offset[rows][:, None] + np.arange(n_tr)]))
    return out


_TABLES: dict[tuple[Any, ...], np.ndarray] = {}


def _score_table(kw: dict[str, Any], reach: int) -> np.ndarray:
    """:func:`~hocnet.hoc.scoring.point_score` of every pair of half-pixel moves, flat.

    Entry ``((a * w + b) * w + c) * w + d``, ``w = 2 * reach + 1``, is the score of the first
    move ``(i1, j1) = ((a - reach) / 2, (b - reach) / 2)`` and the second move ``(i2, j2) =
    ((c - reach) / 2, (d - reach) / 2)``: all moves of components ``k / 2``, ``|k| <= reach``,
    scored in one call and kept per score arguments (a few milliseconds, once).

    Same bits as the references: they score float64 moves given as column slices of ``(M, 3)``
    move tensors (``m1[:, 2]``, ``m1[:, 1]``, ...), and so does this table (columns of an
    ``(M, 4)`` tensor). On such strided inputs torch evaluates ``atan2`` element by element,
    whatever the batch (measured: the same bits in one batch, in chunks of 7 and one by one,
    ``tests/hoc/test_identify_fast.py::test_score_table_equals_point_score``). Not used for
    ``identify._triple_scores``: it passes *integer* moves, which ``point_score`` converts to
    contiguous float64 tensors, and on contiguous inputs the SIMD ``atan2`` of full blocks
    differs in the last bit from the element-wise one of the tail (e.g. the turn of (-2, -3) ->
    (-3, -1): 0.6610431688506866 in a block of 16, 0.6610431688506875 alone).
    """
    from hocnet.hoc.scoring import point_score

    key = (tuple(sorted(kw.items())), reach)
    table = _TABLES.get(key)
    if table is None:
        vals = torch.arange(-reach, reach + 1, dtype=torch.float64) / 2
        g = torch.cartesian_prod(vals, vals, vals, vals)  # (M, 4): strided columns, as the callers'
        scores = point_score(g[:, 0], g[:, 1], g[:, 2], g[:, 3], **kw)
        table = torch.as_tensor(scores, dtype=torch.float64).numpy()
        _TABLES[key] = table
    return table


TABLE_REACH = 16
"""Largest doubled move component (pixels x 2) scored from the table (``v <= 8``); larger
moves are scored directly."""


def half_move_scores(h1: np.ndarray, h2: np.ndarray, kw: dict[str, Any]) -> np.ndarray | None:
    """``point_score`` of moves given doubled: ``h1 = 2 * m1``, ``h2 = 2 * m2``, ``(M, 2)`` int.

    Columns ``(y, x)`` (as ``coords[:, 1:]``); the first move is ``(i1, j1) = (x, y) / 2``. The
    scores are read from :func:`_score_table`; ``None`` when a component exceeds
    :data:`TABLE_REACH` (the caller then scores directly).
    """
    if h1.size == 0:
        return np.zeros(0)
    reach = int(max(np.abs(h1).max(), np.abs(h2).max()))
    if reach > TABLE_REACH:
        return None
    reach = max(reach, 8)  # one table for every scene with v <= 4
    w = 2 * reach + 1
    table = _score_table(kw, reach)
    h1 = h1 + reach
    h2 = h2 + reach
    return table[((h1[:, 1] * w + h1[:, 0]) * w + h2[:, 1]) * w + h2[:, 0]]


def score_paths_passing(
    paths: list[list[int]],
    p0: torch.Tensor,
    p1: torch.Tensor,
    p2: torch.Tensor,
    s: torch.Tensor,
    coords: torch.Tensor,
    min_points: int,
    track_kw: dict[str, Any] | None,
    threshold: float,
) -> list[tuple[float, list[int], list[float]]]:
    """``identify._score_paths`` without the paths that score below ``threshold``.

    The same ``(score, points, point scores)`` entries, in the same order, as
    ``[item for item in _score_paths(...) if not item[0] < threshold]`` (the filter
    ``_select_tracks`` applies first): the paths grouped by length as there (the arrays of a
    :class:`PathList`, else built from the lists with one pass each), each point's moves over
    ``span`` scans from the integer coordinates, its score read from the table of every
    half-pixel move pair (:func:`half_move_scores`; the same bits as scoring it in the batch
    of ``_score_paths``; directly, as there, for spans above 2 or long moves), and the same row
    means (``torch.mean`` of the same ``(R, length)`` rows), so the same bits; only the rows
    that pass are turned into Python lists (at 2 % clutter on a 640 x 512 window, about 300 of
    10 000 paths).

    Wiring: in ``identify._select_tracks``::

        for score, pts, pscores in score_paths_passing(
            paths, p0, p1, p2, s, coords, min_points, track_kw, threshold
        ):
            # (no ``if score < threshold: continue``)

    Examples:
        >>> coords = torch.tensor([[t, 2, 2 + t] for t in range(5)])
        >>> p0, p1, p2 = torch.tensor([0, 1, 2]), torch.tensor([1, 2, 3]), torch.tensor([2, 3, 4])
        >>> s = torch.tensor([3.0, 3.0, 3.0], dtype=torch.float64)
        >>> score_paths_passing([[0, 1, 2], [0]], p0, p1, p2, s, coords, 5, None, 2.5)
        [(3.0, [0, 1, 2, 3, 4], [3.0, 3.0, 3.0])]
    """
    from hocnet.hoc.scoring import point_score

    if not paths:
        return []
    q0, q1, q2 = p0.numpy(), p1.numpy(), p2.numpy()
    xy = coords.numpy()
    span = track_kw["span"] if track_kw is not None else 0
    kw = {key: val for key, val in (track_kw or {}).items() if key != "span"}
    table = codes = None
    if track_kw is not None and span <= 2:  # moves of components k / 2: the table
        m1c, m2c, reach = _triple_moves(coords, q0, q1, q2)
        if reach is not None:
            table, codes = _score_table(kw, reach), (m1c, m2c, reach)
    found: list[tuple[int, tuple[float, list[int], list[float]]]] = []
    for rows, tri in _path_groups(paths):
        n_tr = tri.shape[1]
        if n_tr + 2 < min_points:
            continue
        pts = None
        if track_kw is None:
            pscores = s[torch.from_numpy(tri)]
        elif codes is not None:
            flat = _path_table_scores(table, codes, tri, span)
            pscores = torch.from_numpy(flat)
        else:  # as ``_score_paths``: the float moves, scored directly
            n = n_tr + 2
            pts = np.concatenate([q0[tri[:, :1]], q1[tri[:, :1]], q2[tri]], axis=1)
            p = xy[pts][:, :, 1:]  # (R, n, 2) integer (y, x)
            i = np.arange(1, n - 1)
            s1 = np.minimum(i, span)
            s2 = np.minimum(n - 1 - i, span)
            d1 = p[:, i] - p[:, i - s1]  # (R, n - 2, 2): s1 times the first move
            d2 = p[:, i + s2] - p[:, i]
            m1 = torch.from_numpy(d1 / s1[None, :, None].astype(np.float64)).reshape(-1, 2)
            m2 = torch.from_numpy(d2 / s2[None, :, None].astype(np.float64)).reshape(-1, 2)
            flat = torch.as_tensor(
                point_score(m1[:, 1], m1[:, 0], m2[:, 1], m2[:, 0], **kw), dtype=torch.float64
            ).numpy()
            pscores = torch.from_numpy(np.ascontiguousarray(flat.reshape(tri.shape)))
        means = pscores.mean(dim=1)
        keep = (~(means < threshold)).nonzero().squeeze(1)  # NaN passes, as `score < t` does
        if keep.numel() == 0:
            continue
        means_l = means[keep].tolist()
        k_np = keep.numpy()
        if pts is None:  # the points of the passing rows only
            t_k = tri[k_np]
            pts = np.concatenate([q0[t_k[:, :1]], q1[t_k[:, :1]], q2[t_k]], axis=1)
        else:
            pts = pts[k_np]
        pts_l, ps_l = pts.tolist(), pscores[keep].tolist()
        for r, i in enumerate(rows[k_np].tolist()):
            found.append((i, (means_l[r], pts_l[r], ps_l[r])))
    found.sort(key=lambda item: item[0])  # path order
    return [item for _, item in found]


def _path_table_scores(
    table: np.ndarray,
    codes: tuple[np.ndarray, np.ndarray, int],
    tri: np.ndarray,
    span: int,
) -> np.ndarray:
    """Interior point scores ``(R, n_tr)`` of chains of ``n_tr`` triples (``span <= 2``).

    What ``_score_paths`` computes for each interior point ``i`` of an ``n``-point path: the
    moves ``(p[i] - p[i - s1]) / s1`` and ``(p[i + s2] - p[i]) / s2`` (``s1 = min(i, span)``,
    ``s2 = min(n - 1 - i, span)``), here doubled and summed from the coded moves between
    successive points (``M[:, j]``: point ``j`` to ``j + 1``, the first triple's first move, then
    each triple's second move), and scored from the table.
    """
    m1c, m2c, reach = codes
    w = 2 * reach + 1
    off = reach * (w + 1)
    moves = np.concatenate([m1c[tri[:, :1]], m2c[tri]], axis=1)  # (R, n - 1)
    n_in = tri.shape[1]  # interior points: i = 1 .. n - 2, column i - 1
    h1 = 2 * moves[:, :n_in]  # s1 = 1: 2 (p[i] - p[i - 1])
    h2 = 2 * moves[:, 1 : n_in + 1]  # s2 = 1: 2 (p[i + 1] - p[i])
    if span >= 2:
        h1[:, 1:] = moves[:, : n_in - 1] + moves[:, 1:n_in]  # i >= 2: p[i] - p[i - 2]
        h2[:, :-1] = moves[:, 1:n_in] + moves[:, 2 : n_in + 1]  # i <= n - 3: p[i + 2] - p[i]
    return table[(h1 + off) * (w * w) + h2 + off]


def make_tracks(
    kept: list[tuple[float, list[int], list[float]]], coords: torch.Tensor, batch: int
) -> list[Any]:
    """The :class:`~hocnet.hoc.identify.Track` of every kept candidate, built in one go.

    The same tracks as ``identify._make_track(pts, pscores, coords, batch)`` followed by
    ``track.score = score`` (what ``_select_tracks`` does for each kept candidate, one at a
    time): points ``coords[pts]``, point scores ``[pscores[0], *pscores, pscores[-1]]``,
    ``id`` 0. Each track's ``points`` and ``point_scores`` are disjoint slices of one tensor
    each (two index/copy passes for all tracks, not four tensor constructions per track).

    Wiring: in ``identify._select_tracks``, collect ``(score, pts, pscores)`` of the kept
    candidates in the loop (``kept_items``) instead of calling ``_make_track``, then::

        tracks = list(zip(make_tracks(kept_items, coords, batch),
                          [pts for _, pts, _ in kept_items]))

    Args:
        kept: per kept candidate ``(score, point indices, interior point scores)``.
        coords: ``(N, 3)`` int64 ``(t, y, x)`` of the candidate points.
        batch: scene index.

    Examples:
        >>> coords = torch.tensor([[0, 1, 1], [1, 1, 2], [2, 1, 3]])
        >>> [tr] = make_tracks([(3.0, [0, 1, 2], [3.0])], coords, 0)
        >>> tr.points.tolist(), tr.score, tr.point_scores.tolist()
        ([[0, 1, 1], [1, 1, 2], [2, 1, 3]], 3.0, [3.0, 3.0, 3.0])
    """
    from hocnet.hoc.identify import Track

    if not kept:
        return []
    lens = [len(pts) for _, pts, _ in kept]
    every = chain.from_iterable(pts for _, pts, _ in kept)
    idx = torch.from_numpy(np.fromiter(every, dtype=np.int64, count=sum(lens)))
    points = coords.index_select(0, idx).split(lens)
    ps_lens = [len(ps) + 2 for _, _, ps in kept]
    ends = chain.from_iterable((ps[0], *ps, ps[-1]) for _, _, ps in kept)
    point_scores = torch.from_numpy(np.fromiter(ends, dtype=np.float64, count=sum(ps_lens))).split(
        ps_lens
    )
    return [
        Track(points=pt, id=0, score=score, point_scores=ps, batch=batch)
        for (score, _, _), pt, ps in zip(kept, points, point_scores, strict=True)
    ]


def unique_links(
    a_in: torch.Tensor, a_out: torch.Tensor, accepted: torch.Tensor | None
) -> tuple[np.ndarray, np.ndarray]:
    """Per triple: the only accepted triple continuing it, and the only one leading into it.

    What ``identify._extend_alone`` reads off ``identify._accepted_links`` (the accepted
    triples by in-edge and by out-edge, one Python list per edge, built over every triple):
    ``after[k]`` is the accepted triple whose in-edge is ``a_out[k]`` when there is exactly
    one such triple, else -1; ``before[k]`` likewise the accepted triple whose out-edge is
    ``a_in[k]``. Two counting passes over the edge ids instead of a dictionary of lists (about
    15 ms per 640 x 512 window at 2 % clutter, 30 000 triples, against 1 ms).

    Wiring: ``identify._extensions`` builds ``links = unique_links(a_in, a_out, accepted)``
    for :func:`extend_alone` instead of ``_accepted_links`` for ``_extend_alone``.

    Args:
        a_in: ``(K,)`` int64 in-edge id of each triple (``>= 0``).
        a_out: ``(K,)`` int64 out-edge id of each triple (``>= 0``).
        accepted: ``(K,)`` bool, the accepted triples, or ``None`` (all).

    Returns:
        ``(after, before)``: ``(K,)`` int64 triple indices each (-1: none or several).

    Examples:
        >>> a_in, a_out = torch.tensor([0, 1, 1, 2]), torch.tensor([1, 2, 3, 4])
        >>> [x.tolist() for x in unique_links(a_in, a_out, None)]  # 0: two continuations
        [[-1, 3, -1, -1], [-1, 0, 0, 1]]
    """
    ai, ao = a_in.numpy(), a_out.numpy()
    if ai.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    n_e = int(max(ai.max(), ao.max())) + 1
    acc = np.arange(ai.size) if accepted is None else np.flatnonzero(accepted.numpy())
    out: list[list[int]] = []
    for by, at in ((ai, ao), (ao, ai)):  # (continuations: by in-edge, read at the out-edge)
        only = np.full(n_e, -1, dtype=np.int64)
        only[by[acc]] = acc  # one of the triples on each edge (the only one where count 1)
        only[np.bincount(by[acc], minlength=n_e) != 1] = -1
        out.append(only[at])  # read a few entries per lone track: no Python list of all
    return out[0], out[1]


def extend_alone(
    path: list[int],
    links: tuple[np.ndarray, np.ndarray],
    a0: list[int] | np.ndarray,
    a2: list[int] | np.ndarray,
    root: list[bool],
    point_tracks: dict[int, list[int]],
) -> list[int]:
    """``identify._extend_alone`` with the links of :func:`unique_links`: the same track.

    At each end, while exactly one accepted triple continues the track (``after`` of its last
    triple, ``before`` of its first) and its new point is an image point on no accepted track,
    it is added.

    Wiring: ``identify._extensions`` calls ``extend_alone(path, unique_links(...), ...)``
    instead of ``_extend_alone(path, _accepted_links(...), ...)``.

    Examples:
        >>> a_in, a_out = torch.tensor([0, 1, 2, 3]), torch.tensor([1, 2, 3, 4])
        >>> links = unique_links(a_in, a_out, None)
        >>> a0, a2 = [0, 1, 2, 3], [2, 3, 4, 5]
        >>> extend_alone([1], links, a0, a2, [True] * 6, {})
        [0, 1, 2, 3]
    """
    after, before = links
    path = list(path)  # triples move forward in time: an extension never meets the path
    while True:
        k = int(after[path[-1]])
        if k < 0 or not root[q := int(a2[k])] or q in point_tracks:
            break
        path.append(k)
    while True:
        k = int(before[path[0]])
        if k < 0 or not root[q := int(a0[k])] or q in point_tracks:
            break
        path.insert(0, k)
    return path


def beats_scorer(
    p0: torch.Tensor,
    p1: torch.Tensor,
    p2: torch.Tensor,
    s: torch.Tensor,
    coords: torch.Tensor,
    track_kw: dict[str, Any] | None,
) -> Callable[[list[int], list[float]], bool]:
    """``identify._beats`` for many paths of one scene: the same answers.

    ``_beats(path, scores, ...)`` scores one path with ``_score_paths`` (the moves and point
    scores of every triple of the scene are not needed, but its float moves and batch scoring
    cost about 0.3 ms a call). The returned function scores the path as
    :func:`score_paths_passing` does (the same bits as ``_score_paths``: the point scores read
    from the half-pixel table, the row mean by ``torch.mean`` of the same ``(1, n)`` row), with
    the triples' move codes computed once, on the first call; spans above 2 or long moves: the
    reference.

    Wiring: ``identify._extensions`` makes one ``beats = beats_scorer(p0, p1, p2, s, coords,
    track_kw)`` and calls ``beats(sub, rivals)`` instead of ``_beats(sub, rivals, p0, p1, p2,
    s, coords, track_kw)``.

    Examples:
        >>> coords = torch.tensor([[t, 2, 2 + t] for t in range(5)])
        >>> p0, p1, p2 = torch.tensor([0, 1, 2]), torch.tensor([1, 2, 3]), torch.tensor([2, 3, 4])
        >>> s = torch.tensor([3.0, 3.0, 3.0], dtype=torch.float64)
        >>> beats = beats_scorer(p0, p1, p2, s, coords, None)
        >>> beats([0, 1, 2], [2.9]), beats([0, 1, 2], [2.9, 3.0])
        (True, False)
    """
    from hocnet.hoc.identify import _beats

    span = track_kw["span"] if track_kw is not None else 0
    state: dict[str, Any] = {}

    def beats(path: list[int], scores: list[float]) -> bool:
        if not path or (track_kw is not None and span > 2):
            return _beats(path, scores, p0, p1, p2, s, coords, track_kw)
        tri = np.asarray([path], dtype=np.int64)
        if track_kw is None:
            pscores = s[torch.from_numpy(tri)]
        else:
            if not state:
                kw = {key: val for key, val in track_kw.items() if key != "span"}
                m1c, m2c, reach = _triple_moves(coords, p0.numpy(), p1.numpy(), p2.numpy())
                state["codes"] = None if reach is None else (m1c, m2c, reach)
                state["table"] = None if reach is None else _score_table(kw, reach)
            if state["codes"] is None:
                return _beats(path, scores, p0, p1, p2, s, coords, track_kw)
            table, codes = state["table"], state["codes"]
            pscores = torch.from_numpy(_path_table_scores(table, codes, tri, span))
        score = pscores.mean(dim=1).tolist()[0]
        return all(score > other for other in scores)

    return beats


def path_points(
    paths: list[list[int]], p0: torch.Tensor, p1: torch.Tensor, p2: torch.Tensor
) -> list[list[int]]:
    """The points of every chain of triples: ``[p0[c[0]], p1[c[0]], *(p2[k] for k in c)]``.

    What ``identify._extensions`` builds per proposed track from Python lists of every
    triple's points (three lists of 30 000 entries per 640 x 512 window at 2 % clutter, for a
    few hundred chains): here one gather over the chains' triples.

    Wiring: ``identify._extensions`` iterates ``zip(paths, path_points(paths, p0, p1, p2))``
    instead of building each ``pts`` from ``p0.tolist()``, ``p1.tolist()``, ``p2.tolist()``.

    Examples:
        >>> p0, p1, p2 = torch.tensor([0, 1, 2]), torch.tensor([1, 2, 3]), torch.tensor([2, 3, 4])
        >>> path_points([[0, 1], [2]], p0, p1, p2)
        [[0, 1, 2, 3], [2, 3, 4]]
    """
    if not paths:
        return []
    lens = np.fromiter(map(len, paths), dtype=np.int64, count=len(paths))
    tri = np.fromiter(chain.from_iterable(paths), dtype=np.int64, count=int(lens.sum()))
    starts = np.cumsum(lens) - lens  # each chain's first triple in ``tri``
    at = starts + 2 * np.arange(lens.size)  # each chain's first point in the output
    out = np.empty(tri.size + 2 * lens.size, dtype=np.int64)
    first = tri[starts]
    out[at] = p0.numpy()[first]
    out[at + 1] = p1.numpy()[first]
    out[np.arange(tri.size) - np.repeat(starts, lens) + np.repeat(at + 2, lens)] = p2.numpy()[tri]
    flat = out.tolist()
    ends = np.cumsum(lens + 2).tolist()
    return [flat[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]


def mark_cleaned(cleaned: torch.Tensor, flat: torch.Tensor, point_lists: list[list[int]]) -> None:
    """``cleaned[flat[points]] = True`` for every point of ``point_lists``, in place.

    What ``identify._select_tracks`` does with the kept tracks' points
    (``torch.tensor`` of a Python list of every point, then two torch indexing calls), with
    one ``fromiter`` and NumPy views of the same buffers.

    Wiring: ``identify._select_tracks`` calls ``mark_cleaned(cleaned, flat, [pts for _, pts in
    tracks])``.

    Examples:
        >>> cleaned = torch.zeros(6, dtype=torch.bool)
        >>> mark_cleaned(cleaned, torch.tensor([1, 3, 5]), [[0, 2], [2]])
        >>> cleaned.nonzero().squeeze(1).tolist()
        [1, 5]
    """
    n = sum(map(len, point_lists))
    if n == 0:
        return
    kept = np.fromiter(chain.from_iterable(point_lists), dtype=np.int64, count=n)
    if cleaned.is_contiguous() and flat.is_contiguous():
        cleaned.numpy()[flat.numpy()[kept]] = True
    else:
        cleaned[flat[torch.from_numpy(kept)]] = True

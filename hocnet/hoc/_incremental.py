"""Vectorised helpers of track identification, for the streaming latency (our addition).

:func:`hocnet.hoc.identify.detect` and :class:`hocnet.hoc.stream.StreamingDetector` identify
tracks on every window ([LA98] section III-B); the streaming detector must do it within a scan
period. These helpers replace per-candidate Python loops of :mod:`hocnet.hoc.identify` by array
operations (NumPy views of the tensors: integer work only) that produce the same result in the
same order (each tested against the loop it replaces, ``tests/hoc/test_stream.py``).
"""

from __future__ import annotations

import numpy as np
import torch

from hocnet.hoc._identify_fast import PathList

__all__: list[str] = []


def enumerate_paths_vectorised(
    accepted: torch.Tensor,
    a_in: torch.Tensor,
    a_out: torch.Tensor,
    s: torch.Tensor,
    max_candidates: int,
) -> PathList | None:
    """Maximal chains of accepted triples, in the order of the depth-first loop, or ``None``.

    The same chains as ``identify._enumerate_paths`` (a triple ``k`` continues a chain ending
    with triple ``j`` when ``a_in[k] == a_out[j]``; chains start at the accepted triples whose
    in-edge ends no accepted triple), in the same order: starts by descending score (ties: lower
    index first), and below each chain its continuations likewise; a chain is listed once it
    has no continuation. The loop visits the chains depth first; here they grow all at once,
    one triple per step, and are ordered at the end by their sequence of ranks (position of the
    start among the starts, of each continuation among its siblings; no listed chain is a prefix
    of another, so the order is total).

    Returns ``None`` when ``max_candidates`` or more chains exist: the loop then caps the
    enumeration (its ``capped`` rule), which this function does not reproduce. Below that count
    the loop's cap never applies (its stack holds disjoint open chains, each ending in at least
    one listed chain), so the result is the loop's.

    Args:
        accepted: ``(K,)`` bool, the accepted triples.
        a_in: ``(K,)`` int64 in-edge id of each triple.
        a_out: ``(K,)`` int64 out-edge id of each triple.
        s: ``(K,)`` float64 score of each triple.
        max_candidates: the cap of the loop.

    Returns:
        The chains as lists of triple indices (a :class:`~hocnet.hoc._identify_fast.PathList`:
        also their arrays, per length), or ``None``.
    """
    idx = np.flatnonzero(accepted.numpy())
    if idx.size == 0:
        return PathList([], [])
    ai, ao, sc = a_in.numpy()[idx], a_out.numpy()[idx], s.numpy()[idx]
    n_e = int(max(ai.max(), ao.max())) + 1  # edge ids are small (torch.unique)
    # continuations grouped by in-edge, each group by descending score, then index
    order = np.argsort(-sc, kind="stable")
    order = order[_stable_argsort(ai[order], n_e)]
    count = np.bincount(ai, minlength=n_e)  # triples starting with each edge
    lo = (np.cumsum(count) - count)[ao]  # first continuation of each triple in `order`
    fan = count[ao]
    ends_one = np.zeros(n_e, dtype=bool)
    ends_one[ao] = True
    starts = np.flatnonzero(~ends_one[ai])
    starts = starts[np.argsort(-sc[starts], kind="stable")]
    paths = starts[:, None]
    ranks = np.arange(starts.size)[:, None]
    done_paths: list[np.ndarray] = []
    done_ranks: list[np.ndarray] = []
    n_done = 0
    while paths.shape[0]:
        last = paths[:, -1]
        cnt = fan[last]
        leaf = cnt == 0
        n_leaf = int(np.count_nonzero(leaf))
        if n_leaf:
            done_paths.append(paths[leaf])
            done_ranks.append(ranks[leaf])
            n_done += n_leaf
            grow = ~leaf
            cnt, paths, ranks, last = cnt[grow], paths[grow], ranks[grow], last[grow]
        if n_done + paths.shape[0] >= max_candidates:
            return None  # at least this many chains: the loop's cap decides
        if not paths.shape[0]:
            break
        rep = np.repeat(np.arange(cnt.size), cnt)
        within = np.arange(rep.size) - (np.cumsum(cnt) - cnt)[rep]
        child = order[lo[last[rep]] + within]
        paths = np.concatenate([paths[rep], child[:, None]], axis=1)
        ranks = np.concatenate([ranks[rep], within[:, None]], axis=1)
    if not done_paths:
        return PathList([], [])
    perm = _rank_order(done_ranks, starts.size, int(fan.max()) + 1)
    rows: list[list[int]] = []
    for p in done_paths:  # one list per chain, its length that of its group
        rows.extend(idx[p].tolist())
    # the same chains as arrays, per length, for the scoring (``PathList.groups``)
    rank = np.empty_like(perm)
    rank[perm] = np.arange(perm.size)
    groups = []
    base = 0
    for p in done_paths:
        at = rank[base : base + p.shape[0]]
        sort = np.argsort(at)
        groups.append((at[sort], idx[p[sort]]))
        base += p.shape[0]
    return PathList([rows[i] for i in perm.tolist()], groups)


def _stable_argsort(ids: np.ndarray, n_ids: int) -> np.ndarray:
    """Stable argsort of ids in ``[0, n_ids)`` (as 16-bit keys, NumPy's radix sort, if they fit)."""
    if n_ids <= 1 << 16:
        return np.argsort(ids.astype(np.uint16), kind="stable")
    return np.argsort(ids, kind="stable")


def _rank_order(ranks: list[np.ndarray], n_start: int, n_sib: int) -> np.ndarray:
    """Permutation sorting the chains (groups of equal length) lexicographically by rank.

    ``ranks``: per group an ``(R, w)`` int64 array (or tensor) of ranks (column 0 below
    ``n_start``, the others below ``n_sib``); no row is a prefix of another. Rows are packed
    into one int64 key (mixed radix, rank + 1 so that a shorter row pads with 0) and sorted
    once (the keys are distinct); when the key could overflow, stable sorts column by column
    (last column first) over the padded rows.
    """
    ranks = [np.asarray(r, dtype=np.int64) for r in ranks]
    width = max(r.shape[1] for r in ranks)
    base = n_sib + 1
    if (n_start + 1) * base ** (width - 1) < 2**62:
        weights = base ** np.arange(width - 1, -1, -1, dtype=np.int64)
        key = np.concatenate([((r + 1) * weights[: r.shape[1]]).sum(1) for r in ranks])
        return np.argsort(key, kind="stable")
    pad_r = np.concatenate(
        [np.pad(r, ((0, 0), (0, width - r.shape[1])), constant_values=-1) for r in ranks]
    )
    perm = np.arange(pad_r.shape[0])
    for col in range(width - 1, -1, -1):  # lexicographic: stable sorts, last column first
        perm = perm[np.argsort(pad_r[perm, col], kind="stable")]
    return perm

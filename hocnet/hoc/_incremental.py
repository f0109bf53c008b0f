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

    The same chains as ``identify._enumerate_paths_loop`` (a triple ``k`` continues a chain
    ending with triple ``j`` when ``a_in[k] == a_out[j]``; chains start at the accepted triples
    whose in-edge ends no accepted triple), in the same order: starts by descending score (ties:
    lower index first), and below each chain its continuations likewise; a chain is listed once
    it has no continuation.

    How: the chains from each triple are counted first (:func:`_chain_counts`; 1 for a triple
    without continuation, else the sum over its continuations). Their total decides the cap at
    once, before any chain is listed. Below it the counts give every chain its place in the
    loop's order directly: a start's chains follow those of the starts before it, and a
    continuation's chains follow those of its siblings before it. The chains then grow all at
    once, one triple per step, each carrying that place, and are listed in it (no sort of the
    chains).

    Returns ``None`` when ``max_candidates`` or more chains exist: the loop then caps the
    enumeration (its ``capped`` rule), which this function does not reproduce. Below that count
    the loop's cap never applies (its stack holds disjoint open chains, each ending in at least
    one listed chain, so it never holds more than the chains left), so the result is the
    loop's; at or above it the loop caps (its stack or its list reaches the count), so ``None``
    is returned exactly when the loop's ``capped`` is true.

    Args:
        accepted: ``(K,)`` bool, the accepted triples.
        a_in: ``(K,)`` int64 in-edge id of each triple (``>= 0``).
        a_out: ``(K,)`` int64 out-edge id of each triple (``>= 0``); the chains must form a
            directed acyclic graph (edge ids of later scans: the case of every caller).
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
    count = np.bincount(ai, minlength=n_e)  # triples starting with each edge
    fan = count[ao]  # continuations of each triple
    ends_one = np.zeros(n_e, dtype=bool)
    ends_one[ao] = True
    is_start = ~ends_one[ai]
    chains = _chain_counts(ai, ao, fan, n_e, max_candidates)
    if int(chains[is_start].sum()) >= max_candidates:
        return None  # at least this many chains: the loop's cap decides
    # starts and continuations by descending score, then index (one stable sort for both)
    by_score = _stable_argsort_values(-sc)
    starts = by_score[is_start[by_score]]
    per_start = chains[starts]
    # continuations grouped by in-edge, each group by descending score, then index
    order = by_score[_stable_argsort(ai[by_score], n_e)]
    lo = (np.cumsum(count) - count)[ao]  # first continuation of each triple in `order`
    # place of a continuation's chains after its siblings before it: before[i] - before[lo]
    below = chains[order]
    before = np.cumsum(below) - below
    paths = starts[:, None]
    place = np.cumsum(per_start) - per_start
    done_paths: list[np.ndarray] = []
    done_place: list[np.ndarray] = []
    while paths.shape[0]:
        last = paths[:, -1]
        cnt = fan[last]
        leaf = cnt == 0
        if leaf.any():
            done_paths.append(paths[leaf])
            done_place.append(place[leaf])
        rep = np.repeat(np.arange(cnt.size), cnt)  # the leaves repeat 0 times: dropped
        if not rep.size:
            break
        # rows of `order`: the continuations of each open chain, in their order
        first = lo[last][rep]
        at = np.arange(rep.size) - (np.cumsum(cnt) - cnt)[rep] + first
        paths = np.concatenate([paths[rep], order[at][:, None]], axis=1)
        place = place[rep] + before[at] - before[first]
    if not done_paths:
        return PathList([], [])
    groups = []
    for p, at in zip(done_paths, done_place, strict=True):
        sort = np.argsort(at)
        groups.append((at[sort], idx[p[sort]]))
    # the places are 0 .. n - 1, each once: the lists are built from the groups when asked for
    return PathList(None, groups, sum(int(at.size) for at in done_place))


def _chain_counts(
    a_in: np.ndarray, a_out: np.ndarray, fan: np.ndarray, n_e: int, cap: int
) -> np.ndarray:
    """Maximal chains from each triple (``(K,)`` int64), each count capped at ``cap``.

    ``chains[j] = 1`` when no triple continues ``j`` (``fan[j] == 0``), else the sum of
    ``chains[k]`` over its continuations ``k`` (``a_in[k] == a_out[j]``), capped at ``cap``:
    iterated from all ones to the fixed point (at most the longest chain's length + 1 rounds,
    over the triples with continuations only). Capping keeps the sums exact in float64 and
    loses nothing the caller needs: a capped sum is ``cap`` or more either way, and below
    ``cap`` every count is exact.
    """
    chains = np.ones(a_in.size, dtype=np.int64)
    inner = np.flatnonzero(fan > 0)
    out_inner = a_out[inner]
    weights = np.ones(a_in.size, dtype=np.float64)
    for _ in range(a_in.size + 1):
        per_edge = np.bincount(a_in, weights=weights, minlength=n_e)
        new = np.minimum(per_edge[out_inner], cap)
        if np.array_equal(new, weights[inner]):
            break
        weights[inner] = new
    chains[inner] = weights[inner].astype(np.int64)
    return chains


def _stable_argsort(ids: np.ndarray, n_ids: int) -> np.ndarray:
    """Stable argsort of ids in ``[0, n_ids)`` (as 16-bit keys, NumPy's radix sort, if they fit)."""
    if n_ids <= 1 << 16:
        return np.argsort(ids.astype(np.uint16), kind="stable")
    return np.argsort(ids, kind="stable")


def _stable_argsort_values(x: np.ndarray) -> np.ndarray:
    """``np.argsort(x, kind="stable")`` of float values, by their ranks when few are distinct.

    Triple scores take few distinct values (one per pair of moves): their ranks among the
    distinct values (``np.unique``, which groups equal values as the sort does, NaN last) are
    sorted as 16-bit keys by NumPy's radix sort, about 3x faster than the float sort.
    """
    distinct, rank = np.unique(x, return_inverse=True)
    if distinct.size <= 1 << 16:
        return np.argsort(rank.reshape(-1).astype(np.uint16), kind="stable")
    return np.argsort(x, kind="stable")


def chain_clusters(
    accepted: torch.Tensor, a_in: torch.Tensor, a_out: torch.Tensor, cap: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """``identify._chain_clusters`` with the chain counts capped at ``cap``.

    The same clusters, numbered the same way (by their first triple), and per cluster the
    number of maximal chains when it is below ``cap``, else a number ``>= cap``: the counts per
    triple come from :func:`_chain_counts` (NumPy, each capped at ``cap``) instead of a float
    fixed point in torch. A cluster holding fewer than ``cap`` chains has no triple with
    ``cap`` or more (each chain from a triple extends to a distinct chain of its cluster), so
    its count is exact; one holding more has a capped start or an exact sum ``>= cap``. What
    ``identify._enumerate_paths`` reads off the counts (the clusters whose running total, in
    ascending count order, stays below ``max_candidates``, and that total) is therefore the
    same with ``cap = max_candidates``.

    Wiring: ``identify._enumerate_paths`` calls ``chain_clusters(accepted, a_in, a_out,
    max_candidates)`` instead of ``_chain_clusters(accepted, a_in, a_out)``.

    Args:
        accepted: ``(K,)`` bool, the accepted triples.
        a_in: ``(K,)`` int64 in-edge id of each triple (``>= 0``).
        a_out: ``(K,)`` int64 out-edge id of each triple (``>= 0``; a directed acyclic graph).
        cap: where the counts stop (``>= 1``).

    Returns:
        ``(cluster, count)``: ``(K_acc,)`` int64 cluster of each accepted triple (in index
        order) and ``(C,)`` float64 chains per cluster (capped as above).

    Examples:
        >>> accepted = torch.tensor([True, True, True, True])
        >>> a_in, a_out = torch.tensor([0, 1, 1, 5]), torch.tensor([1, 2, 3, 6])
        >>> cluster, count = chain_clusters(accepted, a_in, a_out, 100)
        >>> cluster.tolist(), count.tolist()
        ([0, 0, 0, 1], [2.0, 1.0])
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    idx = np.flatnonzero(accepted.numpy())
    if idx.size == 0:
        return torch.zeros(0, dtype=torch.long), torch.zeros(0, dtype=torch.float64)
    ai, ao = a_in.numpy()[idx], a_out.numpy()[idx]
    k = idx.size
    n_e = int(max(ai.max(), ao.max())) + 1
    graph = coo_matrix((np.ones(k), (ai, ao)), shape=(n_e, n_e))
    _, labels = connected_components(graph, directed=False)
    raw = labels[ai]
    # clusters numbered by their first triple (the reference's numbering)
    first = np.full(int(labels.max()) + 1, k, dtype=np.int64)
    np.minimum.at(first, raw, np.arange(k))
    present = np.flatnonzero(first < k)
    rank = np.empty(first.size, dtype=np.int64)
    rank[present[np.argsort(first[present])]] = np.arange(present.size)  # distinct: no ties
    cluster = rank[raw]
    fan = np.bincount(ai, minlength=n_e)[ao]
    chains = _chain_counts(ai, ao, fan, n_e, cap)
    ends_one = np.zeros(n_e, dtype=bool)
    ends_one[ao] = True
    is_start = ~ends_one[ai]
    count = np.bincount(
        cluster[is_start], weights=chains[is_start].astype(np.float64), minlength=present.size
    )
    return torch.from_numpy(cluster), torch.from_numpy(count)

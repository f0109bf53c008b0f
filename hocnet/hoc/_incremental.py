"""Vectorised helpers of track identification, for the streaming latency (our addition).

:func:`hocnet.hoc.identify.detect` and :class:`hocnet.hoc.stream.StreamingDetector` identify
tracks on every window ([LA98] section III-B); the streaming detector must do it within a scan
period. These helpers replace per-candidate Python loops of :mod:`hocnet.hoc.identify` by tensor
operations that produce the same result in the same order (each tested against the loop it
replaces, ``tests/hoc/test_stream.py``).
"""

from __future__ import annotations

import torch

__all__: list[str] = []


def enumerate_paths_vectorised(
    accepted: torch.Tensor,
    a_in: torch.Tensor,
    a_out: torch.Tensor,
    s: torch.Tensor,
    max_candidates: int,
) -> list[list[int]] | None:
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
        The chains as lists of triple indices, or ``None``.
    """
    idx = accepted.nonzero().squeeze(1)
    if idx.numel() == 0:
        return []
    ai, ao, sc = a_in[idx], a_out[idx], s[idx]
    n_e = int(torch.maximum(ai.max(), ao.max())) + 1  # edge ids are small (torch.unique)
    # continuations grouped by in-edge, each group by descending score, then index
    order = torch.argsort(-sc, stable=True)
    order = order[torch.argsort(ai[order], stable=True)]
    count = torch.bincount(ai, minlength=n_e)  # triples starting with each edge
    lo = (torch.cumsum(count, 0) - count)[ao]  # first continuation of each triple in `order`
    fan = count[ao]
    ends_one = torch.zeros(n_e, dtype=torch.bool)
    ends_one[ao] = True
    starts = (~ends_one[ai]).nonzero().squeeze(1)
    starts = starts[torch.argsort(-sc[starts], stable=True)]
    paths = starts[:, None]
    ranks = torch.arange(starts.numel())[:, None]
    done_paths: list[torch.Tensor] = []
    done_ranks: list[torch.Tensor] = []
    n_done = 0
    while paths.shape[0]:
        last = paths[:, -1]
        cnt = fan[last]
        leaf = cnt == 0
        n_leaf = int(leaf.sum())
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
        rep = torch.repeat_interleave(cnt)
        within = torch.arange(rep.numel()) - (torch.cumsum(cnt, 0) - cnt)[rep]
        child = order[lo[last[rep]] + within]
        paths = torch.cat([paths[rep], child[:, None]], dim=1)
        ranks = torch.cat([ranks[rep], within[:, None]], dim=1)
    if not done_paths:
        return []
    perm = _rank_order(done_ranks, starts.numel(), int(fan.max()) + 1)
    rows: list[list[int]] = []
    for p in done_paths:  # one list per chain, its length that of its group
        rows.extend(idx[p].tolist())
    return [rows[i] for i in perm.tolist()]


def _rank_order(ranks: list[torch.Tensor], n_start: int, n_sib: int) -> torch.Tensor:
    """Permutation sorting the chains (groups of equal length) lexicographically by rank.

    ``ranks``: per group an ``(R, w)`` int64 tensor of ranks (column 0 below ``n_start``, the
    others below ``n_sib``); no row is a prefix of another. Rows are packed into one int64 key
    (mixed radix, rank + 1 so that a shorter row pads with 0) and sorted once; when the key
    could overflow, stable sorts column by column (last column first) over the padded rows.
    """
    width = max(r.shape[1] for r in ranks)
    base = n_sib + 1
    if (n_start + 1) * base ** (width - 1) < 2**62:
        weights = base ** torch.arange(width - 1, -1, -1)
        key = torch.cat([((r + 1) * weights[: r.shape[1]]).sum(1) for r in ranks])
        return torch.argsort(key)
    pad_r = torch.cat(
        [torch.nn.functional.pad(r, (0, width - r.shape[1]), value=-1) for r in ranks]
    )
    perm = torch.arange(pad_r.shape[0])
    for col in range(width - 1, -1, -1):  # lexicographic: stable sorts, last column first
        perm = perm[torch.argsort(pad_r[perm, col], stable=True)]
    return perm

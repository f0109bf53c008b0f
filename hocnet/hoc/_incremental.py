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
    # continuations grouped by in-edge, each group by descending score, then index
    order = torch.argsort(-sc, stable=True)
    order = order[torch.argsort(ai[order], stable=True)]
    grouped = ai[order]
    lo = torch.searchsorted(grouped, ao)
    fan = torch.searchsorted(grouped, ao, right=True) - lo
    starts = (~torch.isin(ai, ao)).nonzero().squeeze(1)
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
        if bool(leaf.any()):
            done_paths.append(paths[leaf])
            done_ranks.append(ranks[leaf])
            n_done += int(leaf.sum())
        cnt = cnt[~leaf]
        paths, ranks, last = paths[~leaf], ranks[~leaf], last[~leaf]
        if n_done + paths.shape[0] >= max_candidates:
            return None  # at least this many chains: the loop's cap decides
        if not paths.shape[0]:
            break
        rep = torch.repeat_interleave(torch.arange(paths.shape[0]), cnt)
        within = torch.arange(rep.numel()) - torch.repeat_interleave(
            torch.cumsum(cnt, 0) - cnt, cnt
        )
        child = order[lo[last[rep]] + within]
        paths = torch.cat([paths[rep], child[:, None]], dim=1)
        ranks = torch.cat([ranks[rep], within[:, None]], dim=1)
    if not done_paths:
        return []
    width = max(p.shape[1] for p in done_paths)
    pad_p = torch.cat(
        [torch.nn.functional.pad(p, (0, width - p.shape[1]), value=-1) for p in done_paths]
    )
    pad_r = torch.cat(
        [torch.nn.functional.pad(r, (0, width - r.shape[1]), value=-1) for r in done_ranks]
    )
    perm = torch.arange(pad_r.shape[0])
    for col in range(width - 1, -1, -1):  # lexicographic: stable sorts, last column first
        perm = perm[torch.argsort(pad_r[perm, col], stable=True)]
    rows = pad_p[perm]
    glob = torch.where(rows >= 0, idx[rows.clamp_min(0)], -1).tolist()
    return [[k for k in row if k >= 0] for row in glob]

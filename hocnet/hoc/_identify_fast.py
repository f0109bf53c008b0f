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
"""

from __future__ import annotations

import math
from itertools import chain
from typing import Any

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
    from hocnet.hoc.identify import _group_best

    c_idx, left_t, right_t, key_rows = rows
    best = _group_best(c_idx, key_rows, k)
    return left_t[best], right_t[best], key_rows[best]


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
    """``identify._best_paths`` with the same arithmetic in fewer, smaller tensor passes.

    Same arguments, same chains in the same order. Three changes, none touching a value:

    - the dynamic-programming sweeps write each column whole (``where`` on the "has a
      continuation" mask) instead of through boolean-mask indexing (a ``nonzero`` per write);
      ``ptr`` is the continuation itself, ``-1`` where there is none, as before;
    - the ``(K, L, L)`` table of chain sums over (backward length, forward length) is reduced
      one backward length at a time (``(K, L)`` each, in cache): every entry is the same
      ``(bw + fw) - w``, and the flat arg-max keeps the first maximum in ``(lb, lf)`` order
      (``torch.max`` returns the first maximal index of a row; a later ``lb`` replaces the
      running best only when strictly greater);
    - the chains are read off the pointer walks (the table of ``identify._walk``) with one
      filter and one ``tolist`` for all of them, not a Python filter per chain.

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
    from hocnet.hoc.identify import _group_best

    k = p0.numel()
    n_e = int(torch.maximum(a_in.max(), a_out.max())) + 1
    L = max(1, n_t - 2)  # most triples on one chain
    w = s - threshold
    neg = -math.inf
    neg_col = torch.full((k,), neg, dtype=torch.float64)
    none_col = torch.full((k,), -1, dtype=torch.long)

    def sweep(src: torch.Tensor, dst: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # best[:, l]: best sum of a chain starting at triple k and continuing l triples
        # (through dst -> src edges); ptr[:, l]: the next triple (-1: none)
        best, ptr = [w], [none_col]
        for _ in range(1, L):
            col = best[-1]
            ok = col > neg
            if not bool(ok.any()):
                best.append(neg_col)
                ptr.append(none_col)
                continue
            idx = ok.nonzero().squeeze(1)
            g = _group_best(src[idx], col[idx], n_e)
            nxt = torch.where(g >= 0, idx[g.clamp_min(0)], -1)[dst]
            best.append(torch.where(nxt >= 0, w + col[nxt.clamp_min(0)], neg))
            ptr.append(nxt)
        return torch.stack(best, dim=1), torch.stack(ptr, dim=1)

    fw, fptr = sweep(a_in, a_out)  # continue with a triple starting on my out-edge
    bw, bptr = sweep(a_out, a_in)  # continue with a triple ending on my in-edge
    sub = (points[p0] | points[p1] | points[p2]).nonzero().squeeze(1)
    ks = sub.numel()
    if ks == 0:
        return []
    bw_s, fw_s, w_s = bw[sub], fw[sub], w[sub][:, None]
    lf = torch.arange(L)
    flat_best = arg = None
    for lb in range(L):
        total = bw_s[:, lb : lb + 1] + fw_s - w_s  # (Ks, L): the table's row block lb
        total = torch.where(lf + lb + 3 >= min_points, total, neg)
        val, a = total.max(dim=1)
        if flat_best is None:
            flat_best, arg = val, a
        else:
            better = val > flat_best
            flat_best = torch.where(better, val, flat_best)
            arg = torch.where(better, a + lb * L, arg)
    members = torch.cat([p0[sub], p1[sub], p2[sub]])
    values = flat_best.repeat(3)
    owner = _group_best(members, values, n)
    local = owner[points & (owner >= 0)] % max(ks, 1)
    local = torch.unique(local[flat_best[local] >= -1e-9])
    if local.numel() == 0:
        return []
    chosen = sub[local]
    nb, nf = arg[local] // L, arg[local] % L
    # the rows of ``_walk`` (its table before the per-row filter), backward ones reversed, and
    # the chosen triple between: one filter and one ``tolist`` for all chains
    table = torch.cat([_walk_table(bptr, chosen, nb).flip(1), chosen[:, None]], dim=1)
    table = torch.cat([table, _walk_table(fptr, chosen, nf)], dim=1)
    keep = table >= 0
    flat = table[keep].tolist()
    ends = torch.cumsum(keep.sum(dim=1), 0).tolist()
    return [flat[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]


def _walk_table(ptr: torch.Tensor, start: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
    """``identify._walk`` before its per-row filter: ``(M, max steps)``, -1 past a row's end.

    ``identify._walk`` returns each row's entries ``>= 0`` of this table, in order.
    """
    n_steps = int(steps.max()) if steps.numel() else 0
    cur = start.clone()
    rem = steps.clone()
    cols = [torch.full((start.numel(), 0), -1, dtype=torch.long)]
    for _ in range(n_steps):
        on = rem > 0
        nxt = ptr[cur, rem.clamp_min(0)]
        cur = torch.where(on, nxt, cur)
        cols.append(torch.where(on, cur, -1)[:, None])
        rem = rem - 1
    return torch.cat(cols, dim=1)


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
    ``_select_tracks`` applies first): the same tensors, built from one flat list per path
    length (not a nested list), the same element-wise scores and row means, so the same bits;
    only the rows that pass are turned into Python lists (at 2 % clutter on a 640 x 512
    window, about 300 of 10 000 paths).

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
    lens = torch.tensor(list(map(len, paths)), dtype=torch.long)
    every = torch.tensor(list(chain.from_iterable(paths)), dtype=torch.long)
    offset = torch.cumsum(lens, 0) - lens
    order = torch.argsort(lens, stable=True)  # by length, path order within a length
    length, count = torch.unique_consecutive(lens[order], return_counts=True)
    xy = coords.to(torch.float64) if track_kw is not None else coords
    groups = []
    moves: list[tuple[torch.Tensor, torch.Tensor]] = []
    for rows, n_tr in zip(order.split(count.tolist()), length.tolist(), strict=True):
        if n_tr + 2 < min_points:
            continue
        tri = every[offset[rows][:, None] + torch.arange(n_tr)]  # (R, n_tr)
        pts = torch.cat([p0[tri[:, :1]], p1[tri[:, :1]], p2[tri]], dim=1)  # (R, n_tr + 2)
        groups.append((rows, tri, pts))
        if track_kw is not None:
            n = n_tr + 2
            span = track_kw["span"]
            p = xy[pts]
            i = torch.arange(1, n - 1)
            s1 = torch.clamp(i, max=span)
            s2 = torch.clamp(n - 1 - i, max=span)
            m1 = (p[:, i] - p[:, i - s1]) / s1.to(torch.float64)[None, :, None]
            m2 = (p[:, i + s2] - p[:, i]) / s2.to(torch.float64)[None, :, None]
            moves.append((m1.reshape(-1, 3), m2.reshape(-1, 3)))
    if track_kw is not None and moves:
        kw = {key: val for key, val in track_kw.items() if key != "span"}
        m1 = torch.cat([m for m, _ in moves])
        m2 = torch.cat([m for _, m in moves])
        flat_scores = torch.as_tensor(
            point_score(m1[:, 2], m1[:, 1], m2[:, 2], m2[:, 1], **kw), dtype=torch.float64
        )
        parts = flat_scores.split([m.shape[0] for m, _ in moves])
    found: list[tuple[int, tuple[float, list[int], list[float]]]] = []
    for g, (rows, tri, pts) in enumerate(groups):
        pscores = s[tri] if track_kw is None else parts[g].reshape(tri.shape)
        means = pscores.mean(dim=1)
        keep = (~(means < threshold)).nonzero().squeeze(1)  # NaN passes, as `score < t` does
        if keep.numel() == 0:
            continue
        means_l = means[keep].tolist()
        pts_l, ps_l = pts[keep].tolist(), pscores[keep].tolist()
        for r, i in enumerate(rows[keep].tolist()):
            found.append((i, (means_l[r], pts_l[r], ps_l[r])))
    found.sort(key=lambda item: item[0])  # path order
    return [item for _, item in found]


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
    idx = torch.tensor(list(chain.from_iterable(pts for _, pts, _ in kept)), dtype=torch.long)
    points = coords[idx].split(lens)
    ends = chain.from_iterable((ps[0], *ps, ps[-1]) for _, _, ps in kept)
    point_scores = torch.tensor(list(ends), dtype=torch.float64).split(
        [len(ps) + 2 for _, _, ps in kept]
    )
    return [
        Track(points=pt, id=0, score=score, point_scores=ps, batch=batch)
        for (score, _, _), pt, ps in zip(kept, points, point_scores, strict=True)
    ]

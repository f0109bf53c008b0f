"""Track identification and data association after the HOC network (section III-B of [LA98]).

The chain support of :func:`~hocnet.hoc.functional.chain_support` still holds the clutter points
that happen to line up with a target or with each other. Track identification turns the support
into tracks:

1. every triple of support points at scans ``t, t + 1, t + 2`` whose moves lie in the velocity
   window and turn by at most ``delta`` is scored with :func:`~hocnet.hoc.scoring.point_score`
   (the mean of the movement and curvature scores, eq. 8-9) at its middle point;
2. triples are taken greedily, best score first: a triple links the incoming move of its middle
   point to the outgoing one when neither move is linked at that point yet. A point may carry two
   links (two tracks through one pixel at a crossing); a split point starts a new branch. This is
   the paper's rule "where a point has several continuations the higher-scoring one wins", with
   the five-point sequence of a point read as its linked neighbours two scans either side;
3. links are chained into tracks; a point's score is the score of its link on that track (end
   points take their neighbour's); a track's score is the mean of its point scores. Tracks
   shorter than ``min_points`` or scoring below ``threshold`` (2.5, section IV-C) are rejected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from hocnet._check import as_cube, check_int, check_number, restore_batch
from hocnet.hoc.functional import Method, _allowed_cached, _sparse_triples, chain_support
from hocnet.hoc.scoring import DEFAULT_THRESHOLD, point_score

__all__ = ["HOCResult", "Track", "detect", "identify_tracks"]


@dataclass
class Track:
    """One identified track.

    Attributes:
        points: ``(N, 3)`` int64 tensor of ``(t, y, x)``, one row per scan, ordered by scan.
        id: track number (1-based, unique within a result).
        score: mean of ``point_scores``.
        point_scores: ``(N,)`` float64 tensor, the score of each point on this track.
        batch: index of the scene in a batched input (0 for unbatched input).
    """

    points: torch.Tensor
    id: int
    score: float
    point_scores: torch.Tensor = field(repr=False)
    batch: int = 0

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def first_scan(self) -> int:
        """Scan of the first point."""
        return int(self.points[0, 0])

    @property
    def last_scan(self) -> int:
        """Scan of the last point."""
        return int(self.points[-1, 0])


@dataclass
class HOCResult:
    """Output of :func:`detect`.

    Attributes:
        support: bool cube shaped like the input: points on an accepted HOC chain.
        tracks: accepted tracks (each with its ``batch`` index for batched input).
        scores: float64 cube shaped like the input: each support point's best point score over
            the triples through it (NaN where there is no such triple or no point).
        cleaned: bool cube shaped like the input: the points of the accepted tracks.
    """

    support: torch.Tensor
    tracks: list[Track]
    scores: torch.Tensor
    cleaned: torch.Tensor


def _identify_one(
    support: torch.Tensor,
    v: int,
    delta: float,
    threshold: float,
    min_points: int,
    max_tracks_per_point: int,
    score_kwargs: dict[str, float],
    batch: int,
) -> tuple[list[Track], torch.Tensor, torch.Tensor]:
    """Identify tracks in one ``(T, H, W)`` support cube."""
    n_t, h, w = support.shape
    allowed = _allowed_cached(v, delta, "cpu")
    flat, p0, p1, p2 = _sparse_triples(support[None], allowed, v, 1)
    coords = torch.stack([flat // (h * w), (flat // w) % h, flat % w], dim=1)  # (N, 3) t, y, x
    scores_cube = torch.full((n_t * h * w,), math.nan, dtype=torch.float64)
    cleaned = torch.zeros(n_t * h * w, dtype=torch.bool)
    if p0.numel() == 0:
        return [], scores_cube.reshape(n_t, h, w), cleaned.reshape(n_t, h, w)
    m1 = coords[p1] - coords[p0]
    m2 = coords[p2] - coords[p1]
    s = point_score(m1[:, 2], m1[:, 1], m2[:, 2], m2[:, 1], **score_kwargs)
    # best score of each point over the triples through it (any position)
    for members in (p1, p0, p2):
        best = torch.full((flat.numel(),), -math.inf, dtype=torch.float64)
        best.scatter_reduce_(0, members, s, reduce="amax")
        has = best > -math.inf
        cur = scores_cube[flat[has]]
        scores_cube[flat[has]] = torch.where(torch.isnan(cur), best[has], cur)

    n = flat.numel()
    order = torch.argsort(-s, stable=True).tolist()
    a_l, p_l, c_l, s_l = p0.tolist(), p1.tolist(), p2.tolist(), s.tolist()
    in_used: set[int] = set()
    out_used: set[int] = set()
    links_at: dict[int, int] = {}
    next_edge: dict[int, int] = {}
    link_score: dict[int, float] = {}  # keyed by outgoing edge of the link
    has_prev: set[int] = set()
    for k in order:
        a, p, c = a_l[k], p_l[k], c_l[k]
        e_in, e_out = a * n + p, p * n + c
        if e_in in in_used or e_out in out_used or links_at.get(p, 0) >= max_tracks_per_point:
            continue
        in_used.add(e_in)
        out_used.add(e_out)
        links_at[p] = links_at.get(p, 0) + 1
        next_edge[e_in] = e_out
        link_score[e_in] = s_l[k]
        has_prev.add(e_out)

    tracks: list[Track] = []
    starts = sorted(e for e in next_edge if e not in has_prev)
    for e in starts:
        pts = [e // n, e % n]
        pscores = [link_score[e]]
        while e in next_edge:
            nxt = next_edge[e]
            if nxt in next_edge:
                pscores.append(link_score[nxt])
            pts.append(nxt % n)
            e = nxt
        # interior points carry their link scores; the ends copy their neighbour's
        point_scores = torch.tensor([pscores[0], *pscores, pscores[-1]], dtype=torch.float64)
        score = float(point_scores.mean())
        if len(pts) < min_points or score < threshold:
            continue
        idx = torch.tensor(pts)
        tracks.append(
            Track(
                points=coords[idx].clone(),
                id=0,
                score=score,
                point_scores=point_scores,
                batch=batch,
            )
        )
        cleaned[flat[idx]] = True
    tracks.sort(key=lambda tr: tuple(tr.points[0].tolist()) + tuple(tr.points[-1].tolist()))
    return tracks, scores_cube.reshape(n_t, h, w), cleaned.reshape(n_t, h, w)


def _score_kwargs(A1: float, alpha1: float, A2: float, alpha2: float) -> dict[str, float]:
    return {
        "A1": check_number("A1", A1),
        "alpha1": check_number("alpha1", alpha1),
        "A2": check_number("A2", A2),
        "alpha2": check_number("alpha2", alpha2),
    }


def identify_tracks(
    support: torch.Tensor,
    v: int = 4,
    delta: float = math.pi / 4,
    *,
    threshold: float = DEFAULT_THRESHOLD,
    min_points: int = 5,
    max_tracks_per_point: int = 2,
    A1: float = 9.0,
    alpha1: float = 1 / 3,
    A2: float = 2.12,
    alpha2: float = 2.0,
) -> tuple[list[Track], torch.Tensor, torch.Tensor]:
    """Link support points into scored tracks (section III-B of [LA98]; see the module notes).

    Args:
        support: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube, usually the chain support.
        v: velocity window half-width of the links.
        delta: largest turn between successive links, radians in ``(0, pi]``.
        threshold: smallest accepted track score.
        min_points: smallest accepted track length (points).
        max_tracks_per_point: how many tracks may share one point (2: crossings).
        A1: movement-score constant of eq. (8).
        alpha1: movement-score scale of eq. (8).
        A2: curvature-score constant of eq. (9).
        alpha2: curvature-score scale of eq. (9).

    Returns:
        ``(tracks, scores, cleaned)``: the accepted tracks (ids 1, 2, ... in order of first
        point; ``batch`` set for batched input), the per-point best score cube (float64, NaN
        where no triple) and the bool cube of accepted track points, both shaped like
        ``support``.

    Examples:
        >>> s = torch.zeros(6, 12, 12, dtype=torch.bool)
        >>> for t in range(6):
        ...     s[t, 2 + t, 1 + 2 * t] = True
        >>> tracks, scores, cleaned = identify_tracks(s)
        >>> len(tracks), len(tracks[0]), round(tracks[0].score, 2)
        (1, 6, 3.62)
    """
    cube, batched = as_cube("support", support, binary=True)
    v = check_int("v", v, minimum=1)
    delta = check_number("delta", delta, low=0.0, high=math.pi, low_inclusive=False)
    threshold = check_number("threshold", threshold)
    min_points = check_int("min_points", min_points, minimum=1)
    max_tracks_per_point = check_int("max_tracks_per_point", max_tracks_per_point, minimum=1)
    kw = _score_kwargs(A1, alpha1, A2, alpha2)
    cube = cube.cpu()
    all_tracks: list[Track] = []
    scores, cleaned = [], []
    for b in range(cube.shape[0]):
        tr, sc, cl = _identify_one(
            cube[b], v, delta, threshold, min_points, max_tracks_per_point, kw, b
        )
        all_tracks.extend(tr)
        scores.append(sc)
        cleaned.append(cl)
    for i, track in enumerate(all_tracks, start=1):
        track.id = i
    return (
        all_tracks,
        restore_batch(torch.stack(scores), batched),
        restore_batch(torch.stack(cleaned), batched),
    )


def detect(
    frames: torch.Tensor,
    order: int = 2,
    v: int = 4,
    delta: float = math.pi / 4,
    *,
    threshold: float = DEFAULT_THRESHOLD,
    min_points: int | None = None,
    max_tracks_per_point: int = 2,
    method: Method = "auto",
    A1: float = 9.0,
    alpha1: float = 1 / 3,
    A2: float = 2.12,
    alpha2: float = 2.0,
) -> HOCResult:
    """Detect multiple targets in a binary multi-scan cube with the modified HOC of [LA98].

    Runs the forward and backward order-``k`` network, keeps the chain support (every point on
    an accepted ``2k + 1``-point chain, so no point of a complete track is lost, Proposition 1),
    then identifies and scores tracks (:func:`identify_tracks`).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube (bool or 0/1).
        order: HOC order ``k >= 1``.
        v: velocity window half-width (pixels per scan).
        delta: curvature limit in radians, ``(0, pi]``.
        threshold: smallest accepted track score (2.5 in [LA98] section IV-C).
        min_points: smallest accepted track length; default ``2 * order + 1``.
        max_tracks_per_point: tracks that may share a point (crossings).
        method: HOC implementation, ``"auto"``, ``"conv"`` or ``"sparse"``.
        A1: movement-score constant of eq. (8).
        alpha1: movement-score scale of eq. (8).
        A2: curvature-score constant of eq. (9).
        alpha2: curvature-score scale of eq. (9).

    Returns:
        :class:`HOCResult` with ``support``, ``tracks``, ``scores`` and ``cleaned``.

    Examples:
        >>> g = torch.Generator().manual_seed(0)
        >>> f = torch.rand(10, 40, 40, generator=g) < 0.01  # 1 % clutter
        >>> for t in range(10):
        ...     f[t, 5 + 2 * t, 3 + 3 * t] = True  # a target moving (3, 2) per scan
        >>> result = detect(f, order=2)
        >>> [(len(tr), tr.first_scan, tr.last_scan) for tr in result.tracks]
        [(10, 0, 9)]
    """
    cube, batched = as_cube("frames", frames, binary=True)
    order = check_int("order", order, minimum=1)
    min_points = 2 * order + 1 if min_points is None else check_int("min_points", min_points)
    support = chain_support(cube, order, v, delta, method=method)
    tracks, scores, cleaned = identify_tracks(
        support,
        v,
        delta,
        threshold=threshold,
        min_points=min_points,
        max_tracks_per_point=max_tracks_per_point,
        A1=A1,
        alpha1=alpha1,
        A2=A2,
        alpha2=alpha2,
    )
    return HOCResult(
        support=restore_batch(support, batched),
        tracks=tracks,
        scores=restore_batch(scores, True) if batched else scores[0],
        cleaned=restore_batch(cleaned, True) if batched else cleaned[0],
    )

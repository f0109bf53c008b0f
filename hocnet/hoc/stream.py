"""Continuous (sliding-window) operation of the HOC detector: section IV-A and Fig. 5 of [LA98].

[LA98] section IV-A ("Continuous Mode Operation") runs the detector with a limited memory: the
newest scan replaces the oldest, and a decision is made on the scans in memory, "like a moving
window process in the time domain". Its Fig. 5 processes 16 scans and reports the 10-scan
intervals 1-10, 3-12, 5-14 and 7-16 (Fig. 5(c)-(f)): ``StreamingDetector(window=10, stride=2)``.
Every window's result equals :func:`~hocnet.hoc.identify.detect` on the same scans.

Incremental evaluation (our addition; the paper only says the network "records all the
information that is required"). A forward ``Y^(l)(t)`` depends on scans ``t .. t + 2l`` only and a
backward ``Y^(l)(t)`` on scans ``t - 2l .. t``, so each value is computed once, as soon as its last
scan arrives, and stays valid while its first scan is in the window. A pushed scan ``n`` makes
evaluable, per level ``l = 1 .. k``: the forward entry at ``t = n - 2l`` and the backward entry at
``t = n``. These ``2k`` entries, computed from one neighbour look-up between scans ``n - 1`` and
``n`` (the pairs within the velocity window, filtered to the survivors of each level), are all
the layer work of a push. The chain support
(:func:`~hocnet.hoc.functional.chain_support`) is a union over its roots, so it decomposes the
same way: the marking tree ``M_r`` of the forward roots at scan ``r`` (``Y^(k)(r)``, scans
``r .. r + 2k``) and of the backward roots at ``r`` (scans ``r - 2k .. r``) is computed once, when
scan ``r + 2k`` (forward) or ``r`` (backward) arrives. A window ``[s, n]`` is the union of the
forward trees with ``s <= r <= n - 2k`` and the backward trees with ``s + 2k <= r <= n``; backward
entries that reach before ``s`` are left out, exactly as the batch computation on the window
cannot evaluate them.

What is cached, keyed by absolute scan number and stored as sorted flat pixel indices ``y * W + x``
(memory grows with the number of on-points in the window, not with the number of pushed scans):

- the on-points of every scan in the window (level 0);
- the links of every pair of successive scans: the on-point pairs within the velocity window
  (read in both time directions);
- per direction and level ``l``: the points of ``Y^(l)(t)`` and the accepted triples of
  ``Y^(l-1)`` rooted at scan ``t`` (the edges the marking pass walks);
- per direction: the marking tree ``M_r`` of every root scan ``r`` in the window.

Entries of scans that have left the window are dropped. With ``method="conv"`` the layer
entries and trees come from the connectionist layer on the 3 (trees: ``2k + 1``) scans involved,
and no links or triples are kept.

Track identification (section III-B) runs once per window, as in ``detect``, on the window's
candidate points (image plus the points its top-layer moves name, ``support="mhoc"``) or its
chain support. Its decisions (each image point's best five-point sequence, near-duplicates,
track ends) are taken over the whole window, so it is not incremental. Reusing them across
windows would pay little: with ``stride=1`` the window's candidates change at 9 of its 10 scans
from one push to the next (the image gains forward roots at ``n - 2k`` and loses backward roots
at ``start + 2k``, besides the scans entering and leaving), and measured on a 640 x 512 sensor
at 2 % clutter, order 2, 85 % of a window's candidate triples were in the previous window but
only 6-8 % lie in connected groups of triples (the unit identification decides on) that are
unchanged. It starts from what the cache holds: the candidate triples are the cached
first-layer triples of each root scan (the join of the full links, made once when the scan two
later arrived) with all three points among the window's candidates
(:meth:`StreamingDetector._window_triples_cached`; the same triples in the same order as
joining the links restricted to the candidates, and as the batch call, which builds a padded
index volume of the window and scans the cube for that), and its per-candidate loops are
vectorised (:mod:`hocnet.hoc._incremental`, :mod:`hocnet.hoc._identify_fast`; shared with
``detect``). The look-ups, joins and unions of a push work on NumPy views of the same buffers
(the same integer results without torch's per-operation overhead).
Where a push's time goes with ``support="chain"`` at 2 % clutter, order 2, 640 x 512 (process
time per push, 40 pushes, wrappers around the functions, on the shared machine at load 1-5):
of a 43 ms median push, 35 ms is the one identification call (``_select_tracks`` 10,
``_extensions`` 9 of which :func:`~hocnet.hoc._identify_fast.best_paths` 4.5,
``_enumerate_paths`` 4, ``whole_sequence_rows`` 3, ``_triple_scores`` 1.5, ``_edge_ids`` 1)
and 8 ms the incremental HOC part above; the window holds about 30 000 candidate triples and
about 20 000 maximal chains, at or near ``max_candidates`` (5 of 31 windows of seed 0 over
it). Two rounds of work on it, each measured as the median of paired old/new pushes on the
same scans in one process: counting the chains before listing them
(:func:`~hocnet.hoc._incremental.enumerate_paths_vectorised`), the block-count pre-check of
:meth:`StreamingDetector._local_points` and the conflict-free path of
:meth:`StreamingDetector._associate` saved 1.7 ms of a 62 ms push (load about 11); then
(task h7speed) the lone-track extension's links as two arrays instead of a dictionary of
lists over every triple (:func:`~hocnet.hoc._identify_fast.unique_links`, about 15 ms), one
scorer for the track-end proposals (:func:`~hocnet.hoc._identify_fast.beats_scorer`), the
chains' Python lists built only when read (:class:`~hocnet.hoc._identify_fast.PathList`), the
over-cap clusters counted in NumPy (:func:`~hocnet.hoc._incremental.chain_clusters`), the
first maximum of ``best_paths`` by row reductions, and a few NumPy views in place of
``tolist`` of every triple: 72.8 -> 45.7 ms per push (41 pushes, load about 2; 5.7x -> 3.6x
the max-pool floor in process time), every window equal to the old code's. Not cached across
pushes, though the root scans' triples are: their scores (``identify._triple_scores`` scores
them in one contiguous batch, whose SIMD blocks and element-wise tail differ in the last bit,
see :func:`~hocnet.hoc._identify_fast._score_table`, so a score depends on the batch it is
computed in) and what is built on them (edge ids, whole-sequence rows).
What still scales with the window's area: the float64 ``scores`` cube of the result (26 MB,
NaN-filled, for 10 x 512 x 640) and the bool cubes of the result. Python's cyclic garbage
collector is paused during a push (:func:`_gc_paused`). Measured on a 640 x 512 sensor:
``benchmarks/results/hoc_stream.md``. A window denser than the modified HOC's bound
(:func:`~hocnet.hoc.functional.density_bound`) is flagged and not identified, as in ``detect``.
"""

from __future__ import annotations

import contextlib
import gc
import math
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch

from hocnet._check import as_cube, check_choice, check_int, check_number
from hocnet.hoc.functional import density_bound, hoc_layer, support_from_levels
from hocnet.hoc.identify import (
    DEFAULT_DEDUPE,
    DEFAULT_SHARED_POINTS,
    LOCAL_SATURATION,
    MAX_CANDIDATES,
    HOCResult,
    Identify,
    Track,
    _dedupe_scans,
    _identify,
    _identify_sequences,
    _local_saturation,
    _score_kwargs,
    _track_kwargs,
)
from hocnet.hoc.kernels import allowed_moves, get_direction_mask_kernels, get_shift_kernels
from hocnet.hoc.scoring import COMBINE, DEFAULT_COMBINE, DEFAULT_SCORE_SPAN, DEFAULT_THRESHOLD

__all__ = ["StreamResult", "StreamingDetector"]

Method = Literal["auto", "conv", "sparse"]
Support = Literal["chain", "mhoc"]


@dataclass
class StreamResult:
    """Result for one window of the stream.

    Attributes:
        start: absolute scan number of the window's first scan (0-based).
        stop: absolute scan number one past the window's last scan.
        result: :class:`~hocnet.hoc.identify.HOCResult` for the window, with window-local scan
            numbers ``t in [0, window)`` in its ``(window, H, W)`` cubes and its tracks; track ids
            are kept across windows (a track inherits the id of the previous window's track it
            shares the most points with).
        candidates: with ``support="mhoc"``, the ``(window, H, W)`` bool cube of the image
            plus the points named by the top-layer moves of its points (the members of its
            five-point sequences, [LA98] section III-B); ``None`` with ``support="chain"``.
    """

    start: int
    stop: int
    result: HOCResult
    candidates: torch.Tensor | None = None

    @property
    def tracks(self) -> list[Track]:
        """The window's tracks with *absolute* scan numbers in their points."""
        out = []
        for tr in self.result.tracks:
            pts = tr.points.clone()
            pts[:, 0] += self.start
            out.append(Track(points=pts, id=tr.id, score=tr.score, point_scores=tr.point_scores))
        return out


# ----------------------------------------------------------------------------- private helpers

_EMPTY = torch.zeros(0, dtype=torch.long)
Edges = tuple[torch.Tensor, torch.Tensor, torch.Tensor]
_NO_EDGES: Edges = (_EMPTY, _EMPTY, _EMPTY)


def _tensors(*arrays: np.ndarray) -> Edges:
    """NumPy int arrays as int64 tensors (no copy when they are int64 already)."""
    return tuple(torch.from_numpy(np.ascontiguousarray(x, dtype=np.int64)) for x in arrays)


class _Grid:
    """Neighbour look-up between two ``(H, W)`` scans through a reusable padded index image.

    The on-points of the later scan (sorted flat indices ``y * W + x``) are written into a
    ``(H + 2v) x (W + 2v)`` int32 image (``-1`` elsewhere, so nothing wraps and out-of-image
    neighbours are empty, as in :mod:`hocnet.hoc.functional`); the image is cleared again after
    use, so a look-up costs ``(2v + 1)^2`` reads per point, not the frame size.
    """

    def __init__(self, h: int, w: int, v: int) -> None:
        self.h, self.w, self.v = h, w, v
        self.wp = w + 2 * v
        self.image = torch.full(((h + 2 * v) * self.wp,), -1, dtype=torch.int32)
        self.flags = torch.zeros(h * w, dtype=torch.bool)
        self.slots = torch.full((h * w,), -1, dtype=torch.int64)
        rng = torch.arange(-v, v + 1)
        # move m = (j + v) * (2v + 1) + (i + v) for (i, j) = (dx, dy): kernels.move_offsets order
        self.offsets = (rng[:, None] * self.wp + rng[None, :]).reshape(-1)
        self.n_moves = self.offsets.numel()
        # which padded pixels hold a point of the later scan, and every (2v + 1)^2 patch of it
        # (a strided view: patch [y, x] is centred on pixel (y, x), its entries in move order)
        self.present = np.zeros((h + 2 * v) * self.wp, dtype=bool)
        side = 2 * v + 1
        self.patches = np.lib.stride_tricks.sliding_window_view(
            self.present.reshape(h + 2 * v, self.wp), (side, side)
        )

    def reserve(self, n: int) -> None:
        """Make :meth:`join` accept point numbers below ``n`` (grows the slot image if needed)."""
        if n > self.slots.numel():
            self.slots = torch.full((n,), -1, dtype=torch.int64)

    def _padded(self, points: np.ndarray) -> np.ndarray:
        return (points // self.w + self.v) * self.wp + points % self.w + self.v

    def edges(self, a: torch.Tensor, b: torch.Tensor) -> Edges:
        """Every pair ``(p, q)``, ``p`` in ``a``, ``q`` in ``b``, ``q - p`` in the velocity window.

        Args:
            a: ``(N,)`` sorted flat indices of the on-points of one scan.
            b: ``(N',)`` sorted flat indices of the on-points of another scan.

        Returns:
            ``(src, dst, move)``: ``(E,)`` int64 flat indices of ``p`` and ``q`` and the move
            index of ``q - p``, sorted by ``src``.
        """
        if a.numel() == 0 or b.numel() == 0:
            return _NO_EDGES
        # NumPy views of the same buffers: the same reads and writes without torch's
        # per-operation overhead (the order of ``nonzero`` is row-major in both)
        image = self.image.numpy()
        an, bn = a.numpy(), b.numpy()
        pos = self._padded(bn)
        image[pos] = np.arange(bn.size, dtype=np.int32)
        self.present[pos] = True
        try:
            # each point's patch of the presence image (one strided copy per point), then the
            # later scan's point numbers at the hits only
            hit = self.patches[an // self.w, an % self.w].reshape(an.size, -1)
            row, move = np.nonzero(hit)  # row-major: ascending row, then move
            nb = image[self._padded(an)[row] + self.offsets.numpy()[move]]
            return _tensors(an[row], bn[nb], move)
        finally:
            image[pos] = -1
            self.present[pos] = False

    def member(self, x: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        """``(N,)`` bool: which of the flat indices ``x`` are among ``points`` (one frame)."""
        flags = self.flags.numpy()
        pts = points.numpy()
        flags[pts] = True
        try:
            return torch.from_numpy(flags[x.numpy()])
        finally:
            flags[pts] = False

    def restrict(self, edges: Edges, src_set: torch.Tensor, dst_set: torch.Tensor) -> Edges:
        """The edges with both ends in the given point sets; order kept."""
        src, dst, move = edges
        keep = (self.member(src, src_set) & self.member(dst, dst_set)).numpy()
        return _tensors(src.numpy()[keep], dst.numpy()[keep], move.numpy()[keep])

    def join(self, first: Edges, second: Edges, allowed: torch.Tensor) -> Edges:
        """Accepted triples ``(p0, p1, p2)``: ``p0 -> p1`` in ``first``, ``p1 -> p2`` in ``second``.

        The sums of one HOC layer (eq. 5-6 of [LA98]) evaluated only at on-points: a first move
        ``m1`` followed by a second move ``m2`` with ``allowed[m1, m2]`` (the join of
        ``functional._sparse_triples``, restricted to one root scan). ``second`` must be sorted
        by its source. Points are flat pixel indices or any other numbers below the slot
        image's size (:meth:`reserve`; the window's candidate numbers in
        :meth:`StreamingDetector._window_triples`).

        Returns:
            ``(p0, p1, p2)``: ``(N,)`` int64 point numbers, one entry per accepted triple, sorted
            by ``p0`` when ``first`` is sorted by its source.
        """
        if first[0].numel() == 0 or second[0].numel() == 0:
            return _NO_EDGES
        a, b, m1 = (x.numpy() for x in first)
        b2, c, m2 = (x.numpy() for x in second)
        # runs of equal middle points in ``second`` (sorted by its source)
        new = np.empty(b2.size, dtype=bool)
        new[0] = True
        np.not_equal(b2[1:], b2[:-1], out=new[1:])
        starts = np.flatnonzero(new)
        mids = b2[starts]
        counts = np.diff(np.append(starts, b2.size))
        slots = self.slots.numpy()
        slots[mids] = np.arange(mids.size)
        try:
            u = slots[b]  # the middle point's row in `mids`, -1 if it has no second move
        finally:
            slots[mids] = -1
        has = u >= 0
        u = np.maximum(u, 0)
        lo = starts[u]
        fan = np.where(has, counts[u], 0)  # second moves after each first move
        ends = np.cumsum(fan)
        total = int(ends[-1])
        if total == 0:
            return _NO_EDGES
        # expand every first move into its second moves
        f = np.repeat(np.arange(fan.size), fan)
        g = lo[f] + np.arange(total) - (ends - fan)[f]
        ok = allowed.numpy()[m1[f], m2[g]]
        f, g = f[ok], g[ok]
        return _tensors(a[f], b[f], c[g])

    def reverse(self, edges: Edges) -> Edges:
        """The same pairs read the other way round in time (move ``-m``), sorted by source."""
        src, dst, move = (x.numpy() for x in edges)
        order = np.argsort(dst, kind="stable")
        return _tensors(dst[order], src[order], self.n_moves - 1 - move[order])


class _Direction:
    """Cache of one direction (``s = +1`` forward, ``-1`` backward), keyed by absolute scan.

    Attributes:
        s: time step of the layers, +1 (forward: scans ``t + 1, t + 2``) or -1 (backward).
        levels: ``levels[l][t]``: sorted flat indices of ``Y^(l)(t)``; ``levels[0]`` is the
            detector's dict of input scans.
        links: ``links[t]``: pairs of on-points of scans ``t`` and ``t + s`` within the velocity
            window (:meth:`_Grid.edges`), sorted by the point at ``t``.
        triples: ``triples[l][t]``: the accepted triples of ``Y^(l-1)`` rooted at scan ``t``.
        trees: ``trees[r]``: the marking tree of the roots ``Y^(k)(r)``, its points at scans
            ``r, r + s, ..., r + 2ks``.
    """

    def __init__(self, s: int, order: int, scans: dict[int, torch.Tensor]) -> None:
        self.s = s
        self.levels: list[dict[int, torch.Tensor]] = [scans] + [{} for _ in range(order)]
        self.links: dict[int, Edges] = {}
        self.triples: list[dict[int, Edges]] = [{} for _ in range(order + 1)]
        self.trees: dict[int, list[torch.Tensor]] = {}

    def drop_before(self, first: int) -> None:
        """Forget every entry of a scan before ``first`` (level 0 is owned by the detector)."""
        for cache in (*self.levels[1:], *self.triples[1:], self.links, self.trees):
            for t in [t for t in cache if t < first]:
                del cache[t]


@contextlib.contextmanager
def _gc_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector for one push (our addition, latency only).

    A push allocates and frees many small Python lists (candidate tracks, their points); the
    allocations trigger collections whose full (oldest-generation) passes walk every live
    Python object of the process, tens of milliseconds with torch and numpy loaded (measured,
    identification of one 640 x 512 window at 1 % clutter, order 2, in a script whose full
    collections fell inside the call: 106 -> 52 ms with the collector paused; with the earlier
    per-path loops at 2 %, median 2090 -> 1814 ms; no change where no full collection falls
    inside a push). The push's
    own objects hold no reference cycles and are freed by reference counting when it returns,
    so pausing changes no result and leaves no garbage behind. The collector is resumed (if it
    was enabled) when the push returns or raises. Like :mod:`timeit`, which pauses it too.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _identify_window(
    work: torch.Tensor,
    roots: torch.Tensor | None,
    triples: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None,
    kwargs: dict[str, Any],
) -> tuple[list[Track], torch.Tensor, torch.Tensor, bool]:
    """Track identification of one ``(window, H, W)`` window, as :func:`detect` runs it.

    With ``triples`` (``method="paper"`` / ``"assignment"``): the sequence identification of
    :func:`~hocnet.hoc.identify.identify_tracks` on the window's candidate points, fed the
    candidate triples the detector built from its cached links (no window-sized index volume);
    else the whole :func:`~hocnet.hoc.identify.identify_tracks` call.
    """
    if triples is None:
        return _identify(work, roots=roots, **kwargs)
    kw = _score_kwargs(
        kwargs["A1"], kwargs["alpha1"], kwargs["A2"], kwargs["alpha2"], kwargs["combine"]
    )
    tracks, scores, cleaned, capped = _identify_sequences(
        work,
        roots,
        kwargs["v"],
        kwargs["delta"],
        kwargs["threshold"],
        kwargs["min_points"],
        kw,
        0,
        kwargs["method"],
        kwargs["max_candidates"],
        dedupe=kwargs["dedupe"],
        track_kw=_track_kwargs(kw, kwargs["score_span"], kwargs["track_combine"]),
        shared_points=kwargs["shared_points"],
        rescue=kwargs["track_ends"],
        triples=triples,
    )
    for i, track in enumerate(tracks, start=1):
        track.id = i
    return tracks, scores, cleaned, capped


def _union(parts: list[torch.Tensor]) -> torch.Tensor:
    """Sorted distinct values of the parts (``torch.unique`` of their concatenation)."""
    if len(parts) == 1:
        return parts[0]
    x = np.sort(np.concatenate([p.numpy() for p in parts]))
    keep = np.empty(x.size, dtype=bool)
    keep[:1] = True
    np.not_equal(x[1:], x[:-1], out=keep[1:])
    return torch.from_numpy(x[keep])


# ----------------------------------------------------------------------------- detector


class StreamingDetector:
    """Sliding-window modified-HOC detector, incremental per pushed scan ([LA98] IV-A, Fig. 5).

    Push ``(H, W)`` binary scans one at a time; once ``window`` scans have arrived, every
    ``stride``-th push returns the result for the latest ``window`` scans, equal to
    :func:`~hocnet.hoc.identify.detect` on that ``(window, H, W)`` cube with the same arguments
    (``support``, ``identify``, ``combine``, ...). A push costs one neighbour look-up between
    the previous and the new scan, the ``2k`` layer entries it makes evaluable and one marking
    tree per direction (see the module notes for what is cached; none of this depends on
    ``window``), then, when a result is due, the window's candidate points, their triples from
    the cached links and one track identification on them (per window, see the module notes).

    Args:
        window: scans per window (``>= 2 * order + 1``); 10 in [LA98] Fig. 5.
        stride: scans between two returned windows (``>= 1``); 2 in [LA98] Fig. 5. A
            stride larger than ``window`` leaves the ``stride - window`` scans between two
            windows in no window (never detected on): a :class:`UserWarning` says so.
        order: HOC order ``k >= 1``.
        v: velocity window half-width in pixels per scan (``>= 1``).
        delta: curvature limit in radians, in ``(0, pi]``.
        threshold: smallest accepted track score (see :func:`~hocnet.hoc.identify.detect`).
        min_points: smallest accepted track length (``>= 1``), default ``2 * order + 1``.
        max_tracks_per_point: tracks that may share a point (``>= 1``).
        method: layer implementation: ``"auto"`` and ``"sparse"`` evaluate the new layer entries
            and marking trees on the on-points only; ``"conv"`` runs the connectionist layer
            (:func:`~hocnet.hoc.functional.hoc_layer`, :func:`~hocnet.hoc.functional.hoc_mark`)
            on the three (marking: ``2k + 1``) scans involved. Results are identical.
        support: as in :func:`~hocnet.hoc.identify.detect`: ``"mhoc"`` (default, [LA98]
            section III-B: the forward ``Y^(k)`` OR the backward ``Y^(k)`` of the window, read
            from the cache) or ``"chain"`` (our addition, the chain support of
            :func:`~hocnet.hoc.functional.chain_support`).
        A1: movement-score constant of eq. (8).
        alpha1: movement-score scale of eq. (8).
        A2: curvature-score constant of eq. (9).
        alpha2: curvature-score scale of eq. (9).
        identify: track identification, ``"paper"``, ``"greedy"`` or ``"assignment"``
            (:func:`~hocnet.hoc.identify.identify_tracks`).
        combine: point-score combination (:func:`~hocnet.hoc.scoring.point_score`).
        max_candidates: cap on candidate tracks per window.
        dedupe: drop near-duplicate tracks (our addition,
            :func:`~hocnet.hoc.identify.identify_tracks`).
        score_span: scans a track's moves are averaged over when it is scored
            (:func:`~hocnet.hoc.scoring.track_point_scores`; as in
            :func:`~hocnet.hoc.identify.detect`).
        shared_points: several five-point sequences per image point at crossings (as in
            :func:`~hocnet.hoc.identify.detect`).
        track_combine: combination for the track scores only (``None``: ``combine``; as in
            :func:`~hocnet.hoc.identify.detect`).
        track_ends: run the track-ends step (our addition; as in
            :func:`~hocnet.hoc.identify.detect`).

    Raises:
        TypeError: an argument of the wrong type (named in the message).
        ValueError: an argument out of range (named in the message); from :meth:`push`, a scan
            that is not one binary ``(H, W)`` frame or whose size differs from the first scan.

    Examples:
        >>> det = StreamingDetector(window=6, stride=2, order=2, v=2)
        >>> outs = []
        >>> for t in range(10):
        ...     scan = torch.zeros(12, 20, dtype=torch.bool)
        ...     scan[5, t + 2] = True  # a target moving right
        ...     outs.append(det.push(scan))
        >>> [(o.start, o.stop, len(o.tracks)) for o in outs if o is not None]
        [(0, 6, 1), (2, 8, 1), (4, 10, 1)]
    """

    def __init__(
        self,
        window: int = 10,
        stride: int = 2,
        *,
        order: int = 2,
        v: int = 4,
        delta: float = math.pi / 4,
        threshold: float = DEFAULT_THRESHOLD,
        min_points: int | None = None,
        max_tracks_per_point: int = 2,
        method: Method = "auto",
        support: Support = "mhoc",
        A1: float = 9.0,
        alpha1: float = 1 / 3,
        A2: float = 2.12,
        alpha2: float = 2.0,
        identify: Identify = "paper",
        combine: str = DEFAULT_COMBINE,
        max_candidates: int = MAX_CANDIDATES,
        dedupe: bool | int = DEFAULT_DEDUPE,
        score_span: int = DEFAULT_SCORE_SPAN,
        shared_points: bool = DEFAULT_SHARED_POINTS,
        track_combine: str | None = None,
        track_ends: bool = True,
    ) -> None:
        self.order = check_int("order", order, minimum=1)
        self.window = check_int("window", window, minimum=2 * self.order + 1)
        self.stride = check_int("stride", stride, minimum=1)
        if self.stride > self.window:
            skipped = self.stride - self.window
            warnings.warn(
                f"`stride`: {self.stride} is larger than `window` = {self.window}: the "
                f"{skipped} scan{'s' * (skipped != 1)} between two windows are in no window "
                "(never detected on); use stride <= window",
                UserWarning,
                stacklevel=2,
            )
        self.v = check_int("v", v, minimum=1)
        self.delta = check_number("delta", delta, low=0.0, high=math.pi, low_inclusive=False)
        self.method = check_choice("method", method, ("auto", "conv", "sparse"))
        self.support = check_choice("support", support, ("chain", "mhoc"))
        self.threshold = check_number("threshold", threshold)
        self.min_points = (
            2 * self.order + 1
            if min_points is None
            else check_int("min_points", min_points, minimum=1)
        )
        self.max_tracks_per_point = check_int(
            "max_tracks_per_point", max_tracks_per_point, minimum=1
        )
        self._identify_kwargs: dict[str, Any] = {
            "v": self.v,
            "delta": self.delta,
            "threshold": self.threshold,
            "min_points": self.min_points,
            "max_tracks_per_point": self.max_tracks_per_point,
            "A1": check_number("A1", A1),
            "alpha1": check_number("alpha1", alpha1),
            "A2": check_number("A2", A2),
            "alpha2": check_number("alpha2", alpha2),
            "method": check_choice("identify", identify, ("paper", "greedy", "assignment")),
            "combine": check_choice("combine", combine, COMBINE),
            "max_candidates": check_int("max_candidates", max_candidates, minimum=1),
            "dedupe": _dedupe_scans(dedupe),
            "score_span": check_int("score_span", score_span, minimum=1),
            "shared_points": bool(shared_points),
            "track_combine": (
                None
                if track_combine is None
                else check_choice("track_combine", track_combine, COMBINE)
            ),
            "track_ends": bool(track_ends),
        }
        self._bound = density_bound("modified", self.v, self.delta)
        self._allowed = allowed_moves(self.v, self.delta)  # the table of the batch layers
        self._kernels: tuple[torch.Tensor, torch.Tensor] | None = None  # method="conv" only
        self.reset()

    def reset(self) -> None:
        """Forget all scans (the next push starts a new stream at scan 0; ids restart at 1)."""
        self.pushed = 0
        self._shape: tuple[int, int] | None = None
        self._grid: _Grid | None = None
        self._scans: dict[int, torch.Tensor] = {}
        # per scan: flat pixels near a locally saturated window (detect's LOCAL_SATURATION)
        self._local: dict[int, torch.Tensor] = {}
        self._dirs = (
            _Direction(1, self.order, self._scans),
            _Direction(-1, self.order, self._scans),
        )
        self._previous: tuple[np.ndarray, np.ndarray, list[int]] | None = None
        self._next_id = 1

    # ------------------------------------------------------------------------- input

    def _frame(self, scan: Any) -> torch.Tensor:
        """Validate one ``(H, W)`` binary scan; return its on-points as sorted flat indices."""
        if not isinstance(scan, torch.Tensor):
            try:
                scan = torch.as_tensor(scan)
            except (TypeError, ValueError, RuntimeError):
                raise TypeError(
                    f"`scan`: expected a tensor or array of shape (H, W), got {type(scan).__name__}"
                ) from None
        if scan.dim() != 2:
            raise ValueError(
                f"`scan`: expected one scan of shape (H, W), got shape {tuple(scan.shape)}"
            )
        if min(scan.shape) < 1:
            raise ValueError(f"`scan`: expected a non-empty scan, got shape {tuple(scan.shape)}")
        cube, _ = as_cube("scan", scan[None], binary=True)
        frame = cube[0, 0].cpu()
        shape = (int(frame.shape[0]), int(frame.shape[1]))
        if self._shape is None:
            self._shape = shape
            self._grid = _Grid(*shape, self.v)
        elif shape != self._shape:
            raise ValueError(
                f"`scan`: expected shape {self._shape} like the previous scans, got {shape}"
            )
        return frame.reshape(-1).nonzero().squeeze(1)

    # ------------------------------------------------------------------------- layers

    def _conv_entry(self, parts: list[torch.Tensor], s: int) -> torch.Tensor:
        """One connectionist layer evaluated at the first of three scans (in layer direction)."""
        h, w = self._shape
        y = torch.zeros(3, h * w)
        for i, p in enumerate(parts if s > 0 else parts[::-1]):
            y[i, p] = 1.0
        if self._kernels is None:
            self._kernels = (
                get_direction_mask_kernels(self.v, self.delta),
                get_shift_kernels(self.v),
            )
        direction = "forward" if s > 0 else "backward"
        out = hoc_layer(y.reshape(1, 3, h, w), *self._kernels, direction=direction)
        return out[0, 0 if s > 0 else 2].reshape(-1).nonzero().squeeze(1)

    def _update_links(self, n: int) -> None:
        """Pairs between scans ``n - 1`` and ``n``: the only neighbour look-up of a push."""
        if n == 0 or self.method == "conv":
            return
        fwd, bwd = self._dirs
        fwd.links[n - 1] = self._grid.edges(self._scans[n - 1], self._scans[n])
        bwd.links[n] = self._grid.reverse(fwd.links[n - 1])

    def _update_levels(self, cache: _Direction, n: int) -> None:
        """Compute the level entries that scan ``n`` makes evaluable in one direction.

        Forward: ``Y^(l)(n - 2l)``; backward: ``Y^(l)(n)``, for ``l = 1 .. k``.
        """
        s = cache.s
        for level in range(1, self.order + 1):
            t = n - 2 * level if s > 0 else n
            if t < 0:
                continue
            below = cache.levels[level - 1]
            if self.method == "conv":
                parts = [below.get(t + s * i, _EMPTY) for i in range(3)]
                cache.levels[level][t] = self._conv_entry(parts, s)
                continue
            first = cache.links.get(t, _NO_EDGES)
            second = cache.links.get(t + s, _NO_EDGES)
            if level > 1:  # the links between points that survived the level below
                y0, y1, y2 = (below.get(t + s * i, _EMPTY) for i in range(3))
                first = self._grid.restrict(first, y0, y1)
                second = self._grid.restrict(second, y1, y2)
            triples = self._grid.join(first, second, self._allowed)
            cache.triples[level][t] = triples
            cache.levels[level][t] = torch.unique_consecutive(triples[0])  # p0 comes sorted

    def _tree_sparse(self, cache: _Direction, r: int, depth: int) -> list[torch.Tensor]:
        """Marking tree of the roots at scan ``r``: its points at scans ``r + s * j``.

        The marking pass of :func:`~hocnet.hoc.functional.support_from_levels`, restricted to
        one root scan and to the top ``depth`` levels: level by level from ``k`` down to
        ``k - depth + 1``, every triple of ``Y^(l-1)`` rooted at a marked point marks its two
        other members. ``depth = k``: the chain support's tree (``j = 0 .. 2k``); ``depth = 1``:
        the roots and the points their top-layer moves name (``j = 0, 1, 2``).
        """
        k, s = self.order, cache.s
        marks = [cache.levels[k][r]] + [_EMPTY] * (2 * depth)
        for level in range(k, k - depth, -1):
            adds: list[list[torch.Tensor]] = [[] for _ in range(2 * depth + 1)]
            for j in range(2 * (k - level) + 1):
                if marks[j].numel() == 0:
                    continue
                a, b, c = cache.triples[level][r + s * j]
                hit = self._grid.member(a, marks[j])
                adds[j + 1].append(b[hit])
                adds[j + 2].append(c[hit])
            for j, extra in enumerate(adds):
                if extra:
                    marks[j] = _union([marks[j], *extra])
        return marks

    def _tree_conv(self, cache: _Direction, r: int, depth: int) -> list[torch.Tensor]:
        """:meth:`_tree_sparse` through :func:`hoc_mark` on the ``2 * depth + 1`` scans."""
        k, s = self.order, cache.s
        h, w = self._shape
        n_t = 2 * depth + 1
        first = r if s > 0 else r - 2 * depth  # earliest scan of the sub-cube
        levels = []
        for level in range(k - depth, k + 1):
            cube = torch.zeros(n_t, h * w, dtype=torch.bool)
            for i in range(n_t):
                t = first + i
                # cached values (marks reach only the evaluable ones); the top only at r
                if t in cache.levels[level] and (level < k or t == r):
                    cube[i, cache.levels[level][t]] = True
            levels.append(cube.reshape(1, n_t, h, w))
        direction = "forward" if s > 0 else "backward"
        marks = support_from_levels(levels, self.v, self.delta, direction=direction, method="conv")
        flat = marks[0].reshape(n_t, -1)
        return [flat[r + s * j - first].nonzero().squeeze(1) for j in range(n_t)]

    def _update_tree(self, cache: _Direction, n: int) -> None:
        r = n - 2 * self.order if cache.s > 0 else n
        if r < 0 or r not in cache.levels[self.order]:
            return
        tree = self._tree_conv if self.method == "conv" else self._tree_sparse
        cache.trees[r] = tree(cache, r, self.order if self.support == "chain" else 1)

    # ------------------------------------------------------------------------- public

    def push(self, scan: torch.Tensor) -> StreamResult | None:
        """Add one scan; return the window result when one is due.

        Args:
            scan: one ``(H, W)`` binary scan (bool or 0/1 numbers, tensor or array), the same
                ``(H, W)`` as the first scan.

        Returns:
            :class:`StreamResult` when at least ``window`` scans have arrived and ``stride``
            scans have arrived since the last result (the first at the ``window``-th push), else
            ``None``.

        Raises:
            TypeError: ``scan`` is not array-like or not real/boolean.
            ValueError: ``scan`` is not 2-D (a ``(T, H, W)`` stack is refused, push its scans
                one by one), is empty, holds values other than 0/1, or its size differs from the
                first scan's. A refused scan leaves the detector unchanged.
        """
        with _gc_paused():
            return self._push(scan)

    def _push(self, scan: torch.Tensor) -> StreamResult | None:
        """:meth:`push` with the garbage collector paused."""
        points = self._frame(scan)
        n = self.pushed
        self.pushed += 1
        first = n + 1 - self.window  # the first scan any current or future window can hold
        for t in [t for t in self._scans if t < first]:
            del self._scans[t]
            self._local.pop(t, None)
        self._scans[n] = points
        self._local[n] = self._local_points(points)
        for cache in self._dirs:
            cache.drop_before(first)
        self._update_links(n)
        for cache in self._dirs:
            self._update_levels(cache, n)
            self._update_tree(cache, n)
        if self.pushed < self.window or (self.pushed - self.window) % self.stride:
            return None
        return self._emit()

    def _local_points(self, points: torch.Tensor) -> torch.Tensor:
        """Flat pixels of one scan near a locally saturated window (as :func:`detect` marks).

        First the exact pre-check of :func:`~hocnet.hoc.identify._local_saturation` (a window
        lies within 2 x 2 aligned ``(2v + 1)``-pixel blocks: no 2 x 2 block group over the
        limit, no saturated window), its block counts taken from the on-points (one
        ``bincount``) instead of the frame; only when it fails the frame goes through
        ``_local_saturation``.
        """
        h, w = self._shape
        side = 2 * self.v + 1
        hb, wb = -(-h // side) + 1, -(-w // side) + 1
        pix = points.numpy()
        blocks = np.bincount((pix // w // side) * wb + pix % w // side, minlength=hb * wb).reshape(
            hb, wb
        )
        quads = blocks[:-1, :-1] + blocks[1:, :-1] + blocks[:-1, 1:] + blocks[1:, 1:]
        if not (quads > LOCAL_SATURATION * side * side + 0.5).any():
            return _EMPTY
        scan = torch.zeros(h * w, dtype=torch.bool)
        scan[points] = True
        local = _local_saturation(scan.reshape(1, 1, h, w), self.v)
        return local.flatten().nonzero().squeeze(1)

    def _window_points(self, start: int, trees: bool) -> list[torch.Tensor]:
        """Per scan of the window starting at ``start``: sorted flat pixel indices.

        The points of :meth:`_window_cube` with ``trees``, one tensor per scan, without the cube.
        """
        n, k = self.pushed - 1, self.order
        parts: list[list[torch.Tensor]] = [[] for _ in range(self.window)]
        for cache, roots in zip(
            self._dirs, (range(start, n - 2 * k + 1), range(start + 2 * k, n + 1)), strict=True
        ):
            for r in roots:
                if trees:
                    for j, pts in enumerate(cache.trees.get(r, ())):
                        parts[r + cache.s * j - start].append(pts)
                else:
                    parts[r - start].append(cache.levels[k].get(r, _EMPTY))
        return [_union(p) if p else _EMPTY for p in parts]

    def _window_triples(
        self, start: int, points: list[torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(flat, p0, p1, p2)`` of the forward triples among the window's candidate points.

        What ``functional._sparse_triples`` returns on the ``(window, H, W)`` cube of
        ``points`` (same triples, same order: by first point, then first move, then second
        move), built from the cached links of successive scans restricted to the candidates
        and joined scan by scan (:meth:`_Grid.join`), without the cube's padded index volume.
        """
        h, w = self._shape
        hw = h * w
        n_t = self.window
        sizes = [int(p.numel()) for p in points]
        flat = torch.cat([p + t * hw for t, p in enumerate(points)])
        cached = self._dirs[0].triples[1]
        if all(start + t in cached for t in range(n_t - 2)):
            return (flat, *self._window_triples_cached(start, points, sizes))
        links = [self._dirs[0].links.get(start + t, _NO_EDGES) for t in range(n_t - 1)]
        # the links' ends as candidate numbers (their rank in `flat`, -1: not a candidate), one
        # scan at a time through the grid's slot image: no search over the window's candidates
        slots = self._grid.slots
        src: list[torch.Tensor] = [_EMPTY] * (n_t - 1)
        dst: list[torch.Tensor] = [_EMPTY] * (n_t - 1)
        first = 0
        for t, p in enumerate(points):
            slots[p] = torch.arange(first, first + sizes[t])
            try:
                if t < n_t - 1:
                    src[t] = slots[links[t][0]]
                if t > 0:
                    dst[t - 1] = slots[links[t - 1][1]]
            finally:
                slots[p] = -1
            first += sizes[t]
        pairs = []
        for t in range(n_t - 1):
            keep = (src[t] >= 0) & (dst[t] >= 0)
            pairs.append((src[t][keep], dst[t][keep], links[t][2][keep]))
        # numbered by scan, then pixel: the order of the pixel indices within each scan, so
        # `join` sees the same order and returns the same triples in the same order
        self._grid.reserve(flat.numel())
        parts = [self._grid.join(pairs[t], pairs[t + 1], self._allowed) for t in range(n_t - 2)]
        p0, p1, p2 = (torch.cat([part[i] for part in parts]) for i in range(3))
        return flat, p0, p1, p2

    def _window_triples_cached(
        self, start: int, points: list[torch.Tensor], sizes: list[int]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(p0, p1, p2)`` of :meth:`_window_triples` from the cached first-layer triples.

        The forward triples of ``Y^(1)`` rooted at each scan (``triples[1]``, cached when the
        scan two later arrived) are the join of the full links, sorted by first point, first
        move, second move; those with all three points among the window's candidates are the
        join of the links restricted to the candidates (same triples, same order). Each scan's
        candidates are numbered through the grid's slot image once (NumPy views, no search),
        and every triple end lying in that scan is read there.
        """
        n_t = self.window
        cached = [self._dirs[0].triples[1][start + t] for t in range(n_t - 2)]
        ends = [[part.numpy() for part in tri] for tri in cached]
        slots = self._grid.slots.numpy()
        mapped: list[list[np.ndarray]] = [[np.empty(0, np.int64)] * 3 for _ in cached]
        first = 0
        for t, p in enumerate(points):
            pix = p.numpy()
            slots[pix] = np.arange(first, first + sizes[t])
            try:
                for j in range(3):  # the triples rooted at t - j hold their point j here
                    r = t - j
                    if 0 <= r < n_t - 2:
                        mapped[r][j] = slots[ends[r][j]]
            finally:
                slots[pix] = -1
            first += sizes[t]
        out: list[list[np.ndarray]] = [[], [], []]
        for a, b, c in mapped:
            keep = (a >= 0) & (b >= 0) & (c >= 0)
            for j, x in enumerate((a, b, c)):
                out[j].append(x[keep])
        p0, p1, p2 = (torch.from_numpy(np.concatenate(parts)) for parts in out)
        return p0, p1, p2

    def _window_cube(self, start: int, trees: bool) -> torch.Tensor:
        """A ``(window, H, W)`` cube of the window starting at absolute scan ``start``.

        ``trees``: the union of the cached marking trees of the window's roots (the chain
        support, or with ``support="mhoc"`` the candidates); else the image, forward ``Y^(k)``
        OR backward ``Y^(k)``. Forward roots ``start <= r <= n - 2k``, backward roots
        ``start + 2k <= r <= n``, as the batch computation on the window.
        """
        h, w = self._shape
        n, k = self.pushed - 1, self.order
        hw = h * w
        parts = []
        for cache, roots in zip(
            self._dirs, (range(start, n - 2 * k + 1), range(start + 2 * k, n + 1)), strict=True
        ):
            for r in roots:
                if trees:
                    for j, pts in enumerate(cache.trees.get(r, ())):
                        parts.append(pts + (r + cache.s * j - start) * hw)
                else:
                    parts.append(cache.levels[k].get(r, _EMPTY) + (r - start) * hw)
        cube = torch.zeros(self.window * hw, dtype=torch.bool)
        if parts:
            cube[torch.cat(parts)] = True
        return cube.reshape(self.window, h, w)

    def _cube(self, points: list[torch.Tensor]) -> torch.Tensor:
        """The ``(window, H, W)`` bool cube of per-scan flat pixel indices."""
        h, w = self._shape
        cube = torch.zeros(self.window, h * w, dtype=torch.bool)
        for t, p in enumerate(points):
            cube[t, p] = True
        return cube.reshape(self.window, h, w)

    def _emit(self) -> StreamResult:
        """The window's result, as :func:`~hocnet.hoc.identify.detect` computes it."""
        start = self.pushed - self.window
        h, w = self._shape
        count = sum(int(self._scans[t].numel()) for t in range(start, self.pushed))
        # detect's float32 mean of the cube (exact: an integer count over the cube size)
        density = float(torch.tensor(float(count)) / (self.window * h * w))
        dense = density > self._bound
        candidates = None
        if dense:  # detect shows the image and skips identification (bounded work)
            support = self._window_cube(start, trees=False)
            if self.support == "mhoc":
                candidates = support.clone()
            work, roots = None, None
        else:
            sparse = self.method != "conv" and self._identify_kwargs["method"] != "greedy"
            points = self._window_points(start, trees=True)
            if self.support == "chain":
                support = work = self._cube(points)
                roots = None
            else:
                support = roots = self._window_cube(start, trees=False)
                candidates = work = self._cube(points)
            triples = self._window_triples(start, points) if sparse else None
        notes = []
        if dense:
            notes.append(
                f"clutter density {100 * density:.2f} % is above the modified "
                f"HOC's discrimination bound {100 * self._bound:.2f} % ([LA98] section IV-B): the "
                "detector cannot tell targets from clutter here; track identification skipped"
            )
            tracks: list[Track] = []
            scores = torch.full(support.shape, math.nan, dtype=torch.float64)
            cleaned = torch.zeros_like(support)
        else:
            local_pts = [self._local[t] for t in range(start, self.pushed)]
            if any(p.numel() for p in local_pts):  # as detect: left out of identification
                local = self._cube(local_pts)
                scans = local.flatten(1).any(dim=1).nonzero().squeeze(1).tolist()
                side = 2 * self.v + 1
                notes.append(
                    f"clutter density above {100 * LOCAL_SATURATION:.0f} % in {side} x {side} "
                    f"windows of scans {scans} (the discrimination bound is "
                    f"{100 * self._bound:.2f} %, [LA98] section IV-B): "
                    f"{int((work & local).sum())} candidate points there left out of track "
                    "identification"
                )
                work = work & ~local
                triples = None  # the whole identify_tracks call on the reduced window
            tracks, scores, cleaned, capped = _identify_window(
                work, roots, triples, self._identify_kwargs
            )
            if capped:
                notes.append(
                    "track identification enumerated more than "
                    f"{self._identify_kwargs['max_candidates']} candidate tracks in a scene; "
                    "the largest clusters of linked triples followed their best continuation only"
                )
        for note in notes:
            warnings.warn(note, RuntimeWarning, stacklevel=4)
        self._associate(tracks, start)
        result = HOCResult(
            support=support,
            tracks=tracks,
            scores=scores,
            cleaned=cleaned,
            saturated=bool(notes),
            warnings=notes,
        )
        return StreamResult(start=start, stop=self.pushed, result=result, candidates=candidates)

    def _associate(self, tracks: list[Track], start: int) -> None:
        """Give each track the id of the previous window's track it shares most points with.

        Tracks are taken in order; each takes the not yet taken previous track with the largest
        overlap (the first one on ties), or a new id when it shares no point with any.
        """
        h, w = self._shape
        if tracks:
            pts = torch.cat([tr.points for tr in tracks]).numpy()
            keys = ((pts[:, 0] + start) * h + pts[:, 1]) * w + pts[:, 2]
            sizes = np.fromiter(
                (tr.points.shape[0] for tr in tracks), dtype=np.int64, count=len(tracks)
            )
            labels = np.repeat(np.arange(len(tracks)), sizes)
        else:
            keys = labels = np.zeros(0, dtype=np.int64)
        ids: list[int] = []
        if self._previous is not None and self._previous[2] and tracks:
            prev_keys, prev_labels, prev_ids = self._previous
            lo = np.searchsorted(prev_keys, keys, side="left")
            hi = np.searchsorted(prev_keys, keys, side="right")
            count = hi - lo
            rows = np.repeat(labels, count)
            offset = np.repeat(lo - (np.cumsum(count) - count), count)
            cols = prev_labels[np.arange(rows.size) + offset]
            n_prev = len(prev_ids)
            pair = np.sort(rows * n_prev + cols)
            first = np.empty(pair.size, dtype=bool)
            first[:1] = True
            np.not_equal(pair[1:], pair[:-1], out=first[1:])
            at = np.flatnonzero(first)
            overlap = np.diff(np.append(at, pair.size))  # points shared by each pair of tracks
            pair = pair[at]
            cur, prev = pair // n_prev, pair % n_prev
            # candidates of each track: largest overlap first, then the earlier previous track
            most = int(overlap.max()) if overlap.size else 0
            order = np.argsort((cur * (most + 1) + most - overlap) * n_prev + prev)
            cur, prev = cur[order], prev[order]
            head = np.empty(cur.size, dtype=bool)  # each track's first candidate
            head[:1] = True
            np.not_equal(cur[1:], cur[:-1], out=head[1:])
            best = prev[head]
            if np.unique(best).size == best.size:
                # no two tracks want the same previous track first: taken in order, each
                # takes its first candidate (the loop below gives the same ids)
                choice = np.full(len(tracks), -1, dtype=np.int64)
                choice[cur[head]] = best
                ids = [prev_ids[j] if j >= 0 else self._new_id() for j in choice.tolist()]
            else:
                candidates: dict[int, list[int]] = {}
                for i, j in zip(cur.tolist(), prev.tolist(), strict=True):
                    candidates.setdefault(i, []).append(j)
                taken: set[int] = set()
                for i in range(len(tracks)):
                    j = next((j for j in candidates.get(i, ()) if j not in taken), None)
                    if j is None:
                        ids.append(self._new_id())
                    else:
                        taken.add(j)
                        ids.append(prev_ids[j])
        else:
            ids = [self._new_id() for _ in tracks]
        for tr, i in zip(tracks, ids, strict=True):
            tr.id = i
        order = np.argsort(keys, kind="stable")
        self._previous = (keys[order], labels[order], ids)

    def _new_id(self) -> int:
        self._next_id += 1
        return self._next_id - 1

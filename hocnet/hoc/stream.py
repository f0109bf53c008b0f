"""Continuous (sliding-window) operation of the HOC detector, section IV-A of [LA98].

Scans arrive one at a time; a window of the latest ``window`` scans is processed every ``stride``
scans (windows 1-10, 3-12, 5-14, ... for ``window=10, stride=2``). The layer outputs of scans
still in the window are cached and reused: each pushed scan costs one forward and one backward
evaluation per layer on three scans, not a recomputation of the whole window.

Why the cache is exact: a forward ``Y^(l)(t)`` depends on scans ``t .. t + 2l`` only, so it can be
computed once, as soon as scan ``t + 2l`` arrives, and stays valid while scan ``t`` is in the
window. A backward ``Y^(l)(t)`` depends on scans ``t - 2l .. t``: it is computed when scan ``t``
arrives, and within a window starting at scan ``s`` it counts only while ``t - 2l >= s`` (the batch
computation on the window cannot evaluate it earlier), so older entries are masked, not
recomputed. Results are therefore identical to :func:`~hocnet.hoc.identify.detect` on the window.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import torch

from hocnet._check import as_cube, check_int, check_number
from hocnet.hoc.functional import (
    Method,
    _allowed_cached,
    _resolve_method,
    _sparse_triples,
    hoc_levels,
    support_from_levels,
)
from hocnet.hoc.identify import HOCResult, Track, identify_tracks
from hocnet.hoc.scoring import DEFAULT_THRESHOLD

__all__ = ["StreamResult", "StreamingDetector"]


@dataclass
class StreamResult:
    """Result for one window of the stream.

    Attributes:
        start: absolute scan number of the window's first scan (0-based).
        stop: absolute scan number one past the window's last scan.
        result: :class:`~hocnet.hoc.identify.HOCResult` for the window, with window-local scan
            numbers ``t in [0, window)`` in its cubes and tracks; track ids are kept across
            windows (a track inherits the id of the previous window's track it shares the most
            points with).
    """

    start: int
    stop: int
    result: HOCResult

    @property
    def tracks(self) -> list[Track]:
        """The window's tracks with *absolute* scan numbers in their points."""
        out = []
        for tr in self.result.tracks:
            pts = tr.points.clone()
            pts[:, 0] += self.start
            out.append(Track(points=pts, id=tr.id, score=tr.score, point_scores=tr.point_scores))
        return out


class StreamingDetector:
    """Sliding-window modified-HOC detector with cached layer outputs.

    Args:
        window: scans per window (``>= 2 * order + 1``).
        stride: scans between two processed windows.
        order: HOC order ``k``.
        v: velocity window half-width.
        delta: curvature limit in ``(0, pi]``.
        threshold: track acceptance threshold (see :func:`~hocnet.hoc.identify.detect`).
        min_points: smallest accepted track length, default ``2 * order + 1``.
        method: HOC implementation: ``"conv"`` runs the connectionist layers for the per-scan
            updates and the marking pass; ``"auto"`` and ``"sparse"`` use the sparse path for the
            updates (three scans at a time) and choose by density for the marking pass.

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
        method: Method = "auto",
    ) -> None:
        self.order = check_int("order", order, minimum=1)
        self.window = check_int("window", window, minimum=2 * self.order + 1)
        self.stride = check_int("stride", stride, minimum=1)
        self.v = check_int("v", v, minimum=1)
        self.delta = check_number("delta", delta, low=0.0, high=math.pi, low_inclusive=False)
        self.threshold = check_number("threshold", threshold)
        self.min_points = (
            2 * self.order + 1 if min_points is None else check_int("min_points", min_points)
        )
        self.method = method
        _resolve_method(method, torch.zeros(1))  # validate the name now
        self._allowed = _allowed_cached(self.v, self.delta, "cpu")
        self.reset()

    def reset(self) -> None:
        """Forget all scans."""
        self.pushed = 0
        self._shape: tuple[int, int] | None = None
        # _fwd[l] / _bwd[l]: deque of (scan number, (H, W) bool) for level l (0 = input scans)
        self._fwd: list[deque] = [deque(maxlen=self.window) for _ in range(self.order + 1)]
        self._bwd: list[deque] = [deque(maxlen=self.window) for _ in range(self.order + 1)]
        self._previous: list[Track] = []
        self._next_id = 1

    def _layer(self, scans: list[torch.Tensor], direction: str) -> torch.Tensor:
        """One layer evaluated at the first (forward) or last (backward) of three scans."""
        at = 0 if direction == "forward" else 2
        if not scans[at].any():
            return torch.zeros_like(scans[at])
        cube = torch.stack(scans)[None]
        if self.method == "conv":
            return hoc_levels(cube, 1, self.v, self.delta, direction=direction, method="conv")[1][
                0, at
            ]
        roots = torch.zeros_like(cube)
        roots[0, at] = cube[0, at]
        s = 1 if direction == "forward" else -1
        flat, p0, _, _ = _sparse_triples(cube, self._allowed, self.v, s, roots=roots)
        out = torch.zeros(cube.numel(), dtype=torch.bool)
        out[flat[p0]] = True
        return out.reshape(cube.shape)[0, at]

    def push(self, scan: torch.Tensor) -> StreamResult | None:
        """Add one ``(H, W)`` binary scan; return the window result when one is due.

        Returns:
            :class:`StreamResult` when the window is full and ``stride`` scans have arrived
            since the last result, else ``None``.
        """
        cube, _ = as_cube("scan", scan[None] if torch.is_tensor(scan) else [scan], binary=True)
        frame = cube[0, 0].cpu()
        if self._shape is None:
            self._shape = tuple(frame.shape)
        elif tuple(frame.shape) != self._shape:
            raise ValueError(
                f"`scan`: expected shape {self._shape} like the previous scans, "
                f"got {tuple(frame.shape)}"
            )
        n = self.pushed
        self.pushed += 1
        self._fwd[0].append((n, frame))
        self._bwd[0].append((n, frame))
        for level in range(1, self.order + 1):
            below = self._fwd[level - 1]
            t = n - 2 * level  # forward level-l output that became computable
            if t >= 0 and len(below) >= 3 and below[-3][0] == t:
                value = self._layer([below[-3][1], below[-2][1], below[-1][1]], "forward")
                self._fwd[level].append((t, value))
            below = self._bwd[level - 1]
            if len(below) >= 3 and below[-3][0] == n - 2:
                value = self._layer([below[-3][1], below[-2][1], below[-1][1]], "backward")
                self._bwd[level].append((n, value))
        if self.pushed < self.window or (self.pushed - self.window) % self.stride:
            return None
        return self._emit()

    def _levels(self, cache: list[deque], start: int, backward: bool) -> list[torch.Tensor]:
        h, w = self._shape
        levels = []
        for level, entries in enumerate(cache):
            cube = torch.zeros(self.window, h, w, dtype=torch.bool)
            for t, value in entries:
                if t < start or (backward and t - 2 * level < start):
                    continue
                cube[t - start] = value
            levels.append(cube[None])
        return levels

    def _emit(self) -> StreamResult:
        start = self.pushed - self.window
        frames = self._levels(self._fwd, start, backward=False)[0]
        method = _resolve_method(self.method, frames)
        support = torch.zeros_like(frames)
        for direction, cache in (("forward", self._fwd), ("backward", self._bwd)):
            levels = self._levels(cache, start, backward=direction == "backward")
            support |= support_from_levels(
                levels, self.v, self.delta, direction=direction, method=method
            )
        tracks, scores, cleaned = identify_tracks(
            support[0],
            self.v,
            self.delta,
            threshold=self.threshold,
            min_points=self.min_points,
        )
        self._associate(tracks, start)
        result = HOCResult(support=support[0], tracks=tracks, scores=scores, cleaned=cleaned)
        return StreamResult(start=start, stop=self.pushed, result=result)

    def _associate(self, tracks: list[Track], start: int) -> None:
        """Give each track the id of the previous window's track it shares most points with."""
        previous = {tr.id: {tuple(p) for p in tr.points.tolist()} for tr in self._previous}
        taken: set[int] = set()
        kept = []
        for tr in tracks:
            pts = {(t + start, y, x) for t, y, x in tr.points.tolist()}
            best, overlap = None, 0
            for pid, ppts in previous.items():
                common = len(pts & ppts)
                if pid not in taken and common > overlap:
                    best, overlap = pid, common
            if best is None:
                best = self._next_id
                self._next_id += 1
            taken.add(best)
            tr.id = best
            absolute = tr.points.clone()
            absolute[:, 0] += start
            kept.append(
                Track(points=absolute, id=best, score=tr.score, point_scores=tr.point_scores)
            )
        self._previous = kept

"""Detection metrics shared by the HOC ([LA98]) and DPA ([NR08]) detectors.

Point metrics compare a detector's binary output cube with the input cube and the ground truth:

- **clutter rejection** (section IV of [LA98]): removed clutter points / input clutter points,
  where the input clutter points are the on-pixels of ``frames`` that are not in ``target_mask``;
- **target points lost**: input target points (on in ``frames`` and in ``target_mask``) that are
  not in the output ([LA98] reports 0 in all its setups);
- **points remaining**: on-pixels of the output.

These take ``(B, T, H, W)`` or unbatched ``(T, H, W)`` cubes and return one value per scene: a
``(B,)`` tensor for batched input, a Python number for unbatched input.

Track metrics compare ground-truth tracks with found tracks, both as ``(N, 3)`` rows
``(t, y, x)`` (or objects with such a ``.points`` attribute, like
:class:`hocnet.hoc.Track`): :func:`track_recall` and :func:`false_tracks`.

Score metrics (:func:`pd_pfa`, :func:`roc_curve`) threshold a score cube against a truth mask,
pooled over all cells (and all batch elements), optionally restricted to the ``valid`` cells.

Small-target detection measures on per-frame candidate detections (re-exported from
:mod:`hocnet.detection_metrics`, issue 10): :func:`detect_peaks` (local maxima, NMS, at most N
per frame), :func:`detection_roc_curve` (Pd versus false alarms per frame and per pixel over a
threshold sweep, 3-pixel hit radius by default; :func:`hocnet.detection_metrics.roc_curve`),
:func:`pd_at_fa` (Pd at a false-alarm rate per frame or per pixel), :func:`roc_auc` (normalised
ROC area), :class:`DetectionROC`, :func:`write_detections` / :func:`read_detections`
(``detections.csv``).

All functions validate their inputs through :mod:`hocnet._check` and raise ``TypeError`` /
``ValueError`` naming the argument.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from hocnet._check import as_cube, check_int, check_number
from hocnet.detection_metrics import ROC as DetectionROC
from hocnet.detection_metrics import (
    detect_peaks,
    pd_at_fa,
    read_detections,
    roc_auc,
    write_detections,
)
from hocnet.detection_metrics import roc_curve as detection_roc_curve

__all__ = [
    "DetectionROC",
    "TrackRecall",
    "clutter_rejection",
    "detect_peaks",
    "detection_roc_curve",
    "false_tracks",
    "pd_at_fa",
    "pd_pfa",
    "points_remaining",
    "read_detections",
    "roc_auc",
    "roc_curve",
    "target_points_lost",
    "track_recall",
    "write_detections",
]


# ----------------------------------------------------------------------------- helpers


def _binary_like(name: str, value: Any, ref_name: str, ref: torch.Tensor) -> torch.Tensor:
    """Validate a binary cube with exactly the (batched) shape of ``ref``; return it batched."""
    cube, batched = as_cube(name, value, binary=True)
    shape = tuple(cube.shape) if batched else tuple(cube.shape[1:])
    want = tuple(ref.shape)
    if shape != want:
        raise ValueError(f"`{name}`: expected shape {want} like `{ref_name}`, got {shape}")
    return cube


def _per_scene(counts: torch.Tensor, batched: bool) -> torch.Tensor | int | float:
    """``(B,)`` tensor for batched input, a Python number for unbatched input."""
    if batched:
        return counts
    return counts[0].item()


def _point_args(
    frames: Any, output: Any, target_mask: Any
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, bool]:
    f, batched = as_cube("frames", frames, binary=True)
    raw = f if batched else f[0]
    o = _binary_like("output", output, "frames", raw)
    m = _binary_like("target_mask", target_mask, "frames", raw)
    return f, o, m, batched


def _rows(name: str, value: Any) -> torch.Tensor:
    """Validate one track: ``(N, 3)`` integer rows ``(t, y, x)`` or an object with ``.points``."""
    points = getattr(value, "points", value)
    if not isinstance(points, torch.Tensor):
        try:
            points = torch.as_tensor(points)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`{name}`: expected (N, 3) rows (t, y, x) or an object with `.points`, "
                f"got {type(value).__name__}"
            ) from None
    if points.numel() == 0:
        return torch.zeros(0, 3, dtype=torch.int64)
    if points.is_floating_point() or points.is_complex() or points.dtype == torch.bool:
        raise TypeError(f"`{name}`: expected integer (t, y, x) rows, got dtype {points.dtype}")
    if points.dim() != 2 or points.shape[1] != 3:
        raise ValueError(f"`{name}`: expected shape (N, 3) of (t, y, x), got {tuple(points.shape)}")
    return points.long().cpu()


def _track_list(name: str, tracks: Any) -> list[Any]:
    if isinstance(tracks, torch.Tensor) or isinstance(tracks, str | bytes):
        raise TypeError(
            f"`{name}`: expected a sequence of tracks, got {type(tracks).__name__} "
            "(wrap a single track in a list)"
        )
    if not isinstance(tracks, Sequence):
        raise TypeError(f"`{name}`: expected a sequence of tracks, got {type(tracks).__name__}")
    return list(tracks)


def _scores(name: str, value: Any) -> torch.Tensor:
    """Validate a real score tensor; NaN means "no score" and becomes ``-inf``.

    Floating scores keep their dtype (so ``scores >= threshold`` compares as torch would, in
    the scores' precision); integer scores become float64.
    """
    if not isinstance(value, torch.Tensor):
        try:
            value = torch.as_tensor(value)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`{name}`: expected a real tensor or array, got {type(value).__name__}"
            ) from None
    if value.is_complex() or value.dtype == torch.bool:
        raise TypeError(f"`{name}`: expected a real tensor, got dtype {value.dtype}")
    value = value.detach().cpu()
    if not value.is_floating_point():
        value = value.to(torch.float64)
    return torch.where(torch.isnan(value), torch.full_like(value, -torch.inf), value)


def _score_args(scores: Any, truth_mask: Any, valid: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Flattened ``(scores, truth)`` over the valid cells."""
    s = _scores("scores", scores)
    truth, batched = as_cube("truth_mask", truth_mask, binary=True)
    want = tuple(truth.shape) if batched else tuple(truth.shape[1:])
    if tuple(s.shape) != want:
        raise ValueError(f"`scores`: expected shape {want} like `truth_mask`, got {tuple(s.shape)}")
    s = s.reshape(-1)
    t = truth.reshape(-1)
    if valid is not None:
        keep = _binary_like("valid", valid, "truth_mask", truth if batched else truth[0])
        keep = keep.reshape(-1)
        s, t = s[keep], t[keep]
    return s, t


# ----------------------------------------------------------------------------- point metrics


def clutter_rejection(
    frames: torch.Tensor, output: torch.Tensor, target_mask: torch.Tensor
) -> torch.Tensor | float:
    """Clutter rejection rate: removed clutter points / input clutter points ([LA98] section IV).

    The input clutter points are the on-pixels of ``frames`` outside ``target_mask``; a clutter
    point is removed when it is off in ``output``. Output points that are not input points do
    not enter (they are neither input clutter nor removed). A scene without input clutter has
    rejection ``1.0`` (nothing to reject, nothing kept), so the result is never NaN.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary input cube (bool or 0/1).
        output: binary detector output, same shape as ``frames``.
        target_mask: binary ground-truth target pixels, same shape as ``frames`` (may contain
            pixels that are off in ``frames``, e.g. missed target points; they are ignored).

    Returns:
        ``(B,)`` float64 tensor for batched input, a ``float`` in ``[0, 1]`` for unbatched input.

    Raises:
        TypeError: non-numeric inputs.
        ValueError: wrong rank, non-binary values, or shapes that differ from ``frames``.

    Examples:
        >>> f = torch.zeros(3, 4, 4, dtype=torch.bool)
        >>> f[0, 0, 0] = f[1, 1, 1] = f[2, 2, 2] = True  # target
        >>> f[0, 3, 3] = f[1, 3, 0] = f[2, 0, 3] = f[2, 3, 3] = True  # four clutter points
        >>> truth = torch.zeros_like(f)
        >>> truth[0, 0, 0] = truth[1, 1, 1] = truth[2, 2, 2] = True
        >>> out = truth.clone()
        >>> out[2, 3, 3] = True  # one clutter point survives
        >>> clutter_rejection(f, out, truth)
        0.75
        >>> clutter_rejection(f[None].expand(2, -1, -1, -1), out[None].expand(2, -1, -1, -1),
        ...                   truth[None].expand(2, -1, -1, -1)).tolist()
        [0.75, 0.75]
    """
    f, o, m, batched = _point_args(frames, output, target_mask)
    clutter = f & ~m
    n_in = clutter.sum(dim=(1, 2, 3))
    n_removed = (clutter & ~o).sum(dim=(1, 2, 3))
    rate = torch.where(
        n_in > 0, n_removed.double() / n_in.clamp(min=1).double(), torch.ones_like(n_in).double()
    )
    return _per_scene(rate, batched)


def target_points_lost(
    frames: torch.Tensor, output: torch.Tensor, target_mask: torch.Tensor
) -> torch.Tensor | int:
    """Input target points that are not in the output ([LA98]: 0 in all its setups).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary input cube.
        output: binary detector output, same shape as ``frames``.
        target_mask: binary ground-truth target pixels, same shape as ``frames``. Only the
            target pixels that are on in ``frames`` count (a missed return cannot be lost).

    Returns:
        ``(B,)`` int64 tensor for batched input, an ``int`` for unbatched input.

    Raises:
        TypeError: non-numeric inputs.
        ValueError: wrong rank, non-binary values, or shapes that differ from ``frames``.

    Examples:
        >>> f = torch.zeros(3, 4, 4, dtype=torch.bool)
        >>> f[0, 0, 0] = f[1, 1, 1] = f[2, 2, 2] = True
        >>> truth = f.clone()
        >>> out = f.clone()
        >>> out[2, 2, 2] = False
        >>> target_points_lost(f, out, truth)
        1
    """
    f, o, m, batched = _point_args(frames, output, target_mask)
    lost = (f & m & ~o).sum(dim=(1, 2, 3))
    return _per_scene(lost, batched)


def points_remaining(output: torch.Tensor) -> torch.Tensor | int:
    """Number of on-points in a detector output.

    Args:
        output: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube.

    Returns:
        ``(B,)`` int64 tensor for batched input, an ``int`` for unbatched input.

    Examples:
        >>> points_remaining(torch.eye(4, dtype=torch.bool)[None])
        4
        >>> points_remaining(torch.ones(2, 1, 2, 3)).tolist()
        [6, 6]
    """
    o, batched = as_cube("output", output, binary=True)
    return _per_scene(o.sum(dim=(1, 2, 3)), batched)


# ----------------------------------------------------------------------------- track metrics


@dataclass(frozen=True)
class TrackRecall:
    """Result of :func:`track_recall`.

    Attributes:
        found: per true track (in input order): ``True`` if found, ``False`` if missed, ``None``
            if not evaluated (fewer than ``min_points`` of its points in the window).
        matched: per true track, the index into ``found_tracks`` of the best-overlapping found
            track (``None`` when not evaluated or no found track shares a point with it).
        overlap: per true track, the best overlap fraction (``None`` when not evaluated).
    """

    found: tuple[bool | None, ...]
    matched: tuple[int | None, ...]
    overlap: tuple[float | None, ...]

    @property
    def n_evaluated(self) -> int:
        """Number of true tracks with enough points in the window."""
        return sum(f is not None for f in self.found)

    @property
    def n_found(self) -> int:
        """Number of evaluated true tracks that were found."""
        return sum(f is True for f in self.found)

    @property
    def recall(self) -> float:
        """Found / evaluated true tracks; ``1.0`` when no true track is evaluated (never NaN)."""
        return self.n_found / self.n_evaluated if self.n_evaluated else 1.0


def track_recall(
    true_tracks: Sequence[Any],
    found_tracks: Sequence[Any],
    *,
    min_overlap: float = 0.8,
    min_points: int = 5,
    window: tuple[int, int] | None = None,
) -> TrackRecall:
    """Which true tracks were found.

    A true track is evaluated when at least ``min_points`` of its points lie in the window
    (``2k + 1 = 5`` points for the order-2 HOC, the shortest track it can detect). It is
    *found* when one found track contains at least ``min_overlap`` of those points (exact
    ``(t, y, x)`` matches). One found track may find several true tracks (e.g. a split branch
    and its parent share their first point).

    Args:
        true_tracks: ground-truth tracks, each ``(N, 3)`` integer rows ``(t, y, x)``.
        found_tracks: found tracks, each ``(N, 3)`` rows or an object with ``.points`` (e.g.
            :class:`hocnet.hoc.Track`), in the same scan numbering as ``true_tracks``.
        min_overlap: required fraction of the true track's in-window points, in ``(0, 1]``.
        min_points: smallest number of in-window points for a true track to be evaluated.
        window: ``(start, stop)`` scans (``start <= t < stop``) or ``None`` for all scans.

    Returns:
        :class:`TrackRecall` with ``found``, ``matched``, ``overlap`` and ``recall``.

    Raises:
        TypeError: tracks that are not integer ``(N, 3)`` rows.
        ValueError: ``min_overlap`` outside ``(0, 1]``, ``min_points < 1`` or a bad window.

    Examples:
        >>> true = [torch.tensor([[t, 5, 2 * t] for t in range(6)]),
        ...         torch.tensor([[t, 20, 20] for t in range(3)])]
        >>> found = [torch.tensor([[t, 5, 2 * t] for t in range(1, 6)])]  # 5 of 6 points
        >>> r = track_recall(true, found)
        >>> r.found, r.matched, r.recall
        ((True, None), (0, None), 1.0)
        >>> track_recall(true, found, min_overlap=0.9).found
        (False, None)
    """
    true_list = [
        _rows(f"true_tracks[{i}]", t) for i, t in enumerate(_track_list("true_tracks", true_tracks))
    ]
    found_list = [
        _rows(f"found_tracks[{i}]", t)
        for i, t in enumerate(_track_list("found_tracks", found_tracks))
    ]
    min_overlap = check_number("min_overlap", min_overlap, low=0.0, high=1.0, low_inclusive=False)
    min_points = check_int("min_points", min_points, minimum=1)
    if window is not None:
        if not isinstance(window, Sequence) or isinstance(window, str) or len(window) != 2:
            raise TypeError(f"`window`: expected a pair (start, stop) or None, got {window!r}")
        start = check_int("window[0]", window[0], minimum=0)
        stop = check_int("window[1]", window[1], minimum=start + 1)
    found_sets = [{tuple(p) for p in f.tolist()} for f in found_list]
    found: list[bool | None] = []
    matched: list[int | None] = []
    overlaps: list[float | None] = []
    for pts in true_list:
        if window is not None and pts.numel():
            pts = pts[(pts[:, 0] >= start) & (pts[:, 0] < stop)]
        rows = {tuple(p) for p in pts.tolist()}
        if len(rows) < min_points:
            found.append(None)
            matched.append(None)
            overlaps.append(None)
            continue
        best, best_common = None, 0
        for j, fs in enumerate(found_sets):
            common = len(rows & fs)
            if common > best_common:
                best, best_common = j, common
        frac = best_common / len(rows)
        found.append(frac >= min_overlap - 1e-12)
        matched.append(best)
        overlaps.append(frac)
    return TrackRecall(found=tuple(found), matched=tuple(matched), overlap=tuple(overlaps))


def false_tracks(
    found_tracks: Sequence[Any],
    target_mask: torch.Tensor,
    *,
    min_target_fraction: float = 0.5,
) -> torch.Tensor | int:
    """Number of found tracks whose points are mostly clutter.

    A found track is false when fewer than ``min_target_fraction`` of its points are target
    pixels (so a track that is exactly half target is not false at the default 0.5). Points
    outside the cube count as clutter.

    Args:
        found_tracks: tracks, each ``(N, 3)`` integer rows ``(t, y, x)`` or an object with
            ``.points``. With a batched mask each track must have a ``.batch`` attribute (as
            :class:`hocnet.hoc.Track` has) naming its scene.
        target_mask: ``(T, H, W)`` or ``(B, T, H, W)`` binary ground-truth target pixels.
        min_target_fraction: fraction of target points a track needs to be true, in ``(0, 1]``.

    Returns:
        ``int`` for an unbatched mask, ``(B,)`` int64 tensor of counts per scene for a batched
        one.

    Raises:
        TypeError: bad tracks, or raw tensors with a batched mask.
        ValueError: bad mask or fraction, or a track's ``batch`` out of range.

    Examples:
        >>> mask = torch.zeros(5, 8, 8, dtype=torch.bool)
        >>> for t in range(5):
        ...     mask[t, 1, t] = True
        >>> real = torch.tensor([[t, 1, t] for t in range(5)])
        >>> fake = torch.tensor([[t, 6, 7 - t] for t in range(5)])
        >>> false_tracks([real, fake], mask)
        1
    """
    tracks = _track_list("found_tracks", found_tracks)
    mask, batched = as_cube("target_mask", target_mask, binary=True)
    frac = check_number(
        "min_target_fraction", min_target_fraction, low=0.0, high=1.0, low_inclusive=False
    )
    n_b, n_t, h, w = mask.shape
    counts = torch.zeros(n_b, dtype=torch.int64)
    for i, tr in enumerate(tracks):
        pts = _rows(f"found_tracks[{i}]", tr)
        b = 0
        if batched:
            if not hasattr(tr, "batch"):
                raise TypeError(
                    f"`found_tracks[{i}]`: expected an object with `.batch` for a batched "
                    f"`target_mask`, got {type(tr).__name__}"
                )
            b = check_int(f"found_tracks[{i}].batch", tr.batch, minimum=0, maximum=n_b - 1)
        if pts.shape[0] == 0:
            continue
        t, y, x = pts.unbind(1)
        inside = (t >= 0) & (t < n_t) & (y >= 0) & (y < h) & (x >= 0) & (x < w)
        hits = torch.zeros(pts.shape[0], dtype=torch.bool)
        hits[inside] = mask[b, t[inside], y[inside], x[inside]]
        if float(hits.double().mean()) < frac - 1e-12:
            counts[b] += 1
    return _per_scene(counts, batched)


# ----------------------------------------------------------------------------- score metrics


def pd_pfa(
    scores: torch.Tensor,
    truth_mask: torch.Tensor,
    threshold: float,
    *,
    valid: torch.Tensor | None = None,
) -> tuple[float, float]:
    """Probability of detection and of false alarm at one threshold, pooled over all cells.

    A cell is declared a detection when ``score >= threshold`` (compared in the scores' dtype,
    as ``torch`` compares a tensor with a Python number). ``Pd`` = detected truth cells /
    truth cells, ``Pfa`` = detected non-truth cells / non-truth cells, both counted over the
    ``valid`` cells only (all cells by default; pass the input cube to count per input point,
    in which case ``1 - Pfa`` is the clutter rejection). NaN scores mean "no score" and are
    never detected (the HOC ``scores`` cube is NaN off the support). With no truth cells
    ``Pd = 1.0``, with no non-truth cells ``Pfa = 0.0`` (never NaN).

    Args:
        scores: ``(B, T, H, W)`` or ``(T, H, W)`` real scores (NaN allowed, see above).
        truth_mask: binary cube of the same shape: the target cells.
        threshold: detection threshold (finite).
        valid: optional binary cube of the same shape: the cells that count.

    Returns:
        ``(pd, pfa)`` as floats.

    Raises:
        TypeError: non-real scores or non-numeric masks.
        ValueError: shape mismatch, non-binary masks, non-finite threshold.

    Examples:
        >>> scores = torch.tensor([[[0.9, 0.2], [0.7, float("nan")]]])
        >>> truth = torch.tensor([[[True, False], [False, True]]])
        >>> pd_pfa(scores, truth, 0.5)
        (0.5, 0.5)
    """
    s, t = _score_args(scores, truth_mask, valid)
    threshold = check_number("threshold", threshold)
    det = s >= torch.tensor(threshold, dtype=torch.float64).to(s.dtype)
    n_pos, n_neg = int(t.sum()), int((~t).sum())
    pd = int((det & t).sum()) / n_pos if n_pos else 1.0
    pfa = int((det & ~t).sum()) / n_neg if n_neg else 0.0
    return pd, pfa


def roc_curve(
    scores: torch.Tensor,
    truth_mask: torch.Tensor,
    thresholds: Sequence[float] | torch.Tensor | None = None,
    *,
    valid: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Receiver operating characteristic: ``(Pfa, Pd)`` over a range of thresholds.

    Same conventions as :func:`pd_pfa` (detection at ``score >= threshold``, NaN never
    detected, pooled over the ``valid`` cells), evaluated for all thresholds at once by sorting.

    Args:
        scores: ``(B, T, H, W)`` or ``(T, H, W)`` real scores.
        truth_mask: binary cube of the same shape.
        thresholds: thresholds to evaluate (any order, kept as given); ``None`` uses ``+inf``
            followed by every distinct finite score in decreasing order, so the curve starts at
            ``(0, 0)`` (unless some scores are ``+inf``) and ends at the lowest score. A
            threshold of ``-inf`` detects every cell, NaN-scored ones included.
        valid: optional binary cube of the same shape: the cells that count.

    Returns:
        ``(pfa, pd, thresholds)``: three float64 tensors of the same length.

    Raises:
        TypeError: non-real scores or thresholds.
        ValueError: shape mismatch, non-binary masks, NaN thresholds.

    Examples:
        >>> scores = torch.tensor([[[4.0, 1.0], [3.0, 2.0]]])
        >>> truth = torch.tensor([[[True, False], [False, True]]])
        >>> pfa, pd, thr = roc_curve(scores, truth)
        >>> thr.tolist()
        [inf, 4.0, 3.0, 2.0, 1.0]
        >>> pd.tolist()
        [0.0, 0.5, 0.5, 1.0, 1.0]
        >>> pfa.tolist()
        [0.0, 0.0, 0.5, 0.5, 1.0]
    """
    s, t = _score_args(scores, truth_mask, valid)
    if thresholds is None:
        finite = torch.unique(s[torch.isfinite(s)]).to(torch.float64)
        thr = torch.cat([torch.tensor([torch.inf], dtype=torch.float64), finite.flip(0)])
    else:
        if isinstance(thresholds, str | bytes):
            raise TypeError("`thresholds`: expected a sequence of numbers, got str")
        try:
            thr = torch.as_tensor(thresholds, dtype=torch.float64).reshape(-1)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`thresholds`: expected a sequence of numbers, got {type(thresholds).__name__}"
            ) from None
        if bool(torch.isnan(thr).any()):
            raise ValueError("`thresholds`: expected numbers, got NaN")
    order = torch.argsort(s)
    s_sorted = s[order]
    pos_cum = torch.cat([torch.zeros(1, dtype=torch.int64), t[order].long().cumsum(0)])
    n, n_pos = s.numel(), int(t.sum())
    n_neg = n - n_pos
    # cells below each threshold, compared in the scores' precision
    first = torch.searchsorted(s_sorted, thr.to(s.dtype), side="left")
    detected = n - first
    tp = n_pos - pos_cum[first]
    fp = detected - tp
    pd = tp.double() / n_pos if n_pos else torch.ones_like(thr)
    pfa = fp.double() / n_neg if n_neg else torch.zeros_like(thr)
    return pfa, pd, thr

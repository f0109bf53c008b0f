"""Per-frame detections and the standard small-target detection measures (our addition).

* :func:`detect_peaks` turns a score cube into candidate detections ``(frame, x, y, score)``:
  local maxima after non-maximum suppression, at most ``max_per_frame`` per frame, highest first.
* :func:`roc_curve` scores detections against the target's true pixel per frame over a threshold
  sweep: probability of detection (Pd) versus false alarms per frame (and per pixel);
  :func:`pd_at_fa` and :func:`roc_auc` summarise the curve.
* :func:`write_detections` / :func:`read_detections`: the ``detections.csv`` file, columns
  ``frame,x,y,score``.

Conventions: ``x`` is the column and ``y`` the row, both 0-based; ``frame`` is the 0-based frame
index. Detections are ``(N, 4)`` float64 tensors with columns ``frame, x, y, score``. Truth is
``(T, 2)`` ``(x, y)`` per frame (NaN rows: no target in that frame).
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import torch
import torch.nn.functional as F

from hocnet._check import as_cube, check_int, check_number
from hocnet.data.io import _atomic_write

__all__ = [
    "DETECTION_COLUMNS",
    "ROC",
    "detect_peaks",
    "pd_at_fa",
    "read_detections",
    "roc_auc",
    "roc_curve",
    "write_detections",
]

DETECTION_COLUMNS = ("frame", "x", "y", "score")
"""Columns of ``detections.csv`` and of the ``(N, 4)`` detection tensors."""


def _peaks(scores: torch.Tensor, radius: int) -> torch.Tensor:
    """``(N, H, W)`` bool: pixels that are the maximum of their ``(2r+1)^2`` in-frame window.

    Ties: among equal values in a window the pixel with the lowest flat index (row-major) wins,
    so a plateau gives one peak.
    """
    if radius == 0:
        return torch.ones_like(scores, dtype=torch.bool)
    _, h, w = scores.shape
    k = 2 * radius + 1
    pooled = F.max_pool2d(scores.unsqueeze(1), k, stride=1, padding=radius).squeeze(1)
    peak = scores >= pooled
    padded = F.pad(scores, (radius, radius, radius, radius), value=math.nan)
    for dy in range(-radius, 1):
        for dx in range(-radius, radius + 1):
            if dy == 0 and dx >= 0:
                break
            shifted = padded[:, radius + dy : radius + dy + h, radius + dx : radius + dx + w]
            peak &= shifted != scores
    return peak


def detect_peaks(
    scores: torch.Tensor,
    *,
    radius: int = 2,
    max_per_frame: int = 50,
    threshold: float | None = None,
    mask: torch.Tensor | None = None,
) -> torch.Tensor | list[torch.Tensor]:
    """Candidate detections of every frame: local maxima, non-maximum suppressed.

    A pixel is a candidate if no pixel of its ``(2 radius + 1)^2`` window (inside the frame) has
    a larger score, and none with a lower row-major index an equal one (a plateau gives one
    candidate). Of each frame's candidates (with ``score > threshold`` if given) the
    ``max_per_frame`` highest are kept, highest first (equal scores: lower row-major index
    first).

    Args:
        scores: ``(T, H, W)`` or ``(B, T, H, W)`` score cube (what the method thresholds).
        radius: NMS radius in pixels, ``>= 0`` (0: every pixel is a candidate).
        max_per_frame: most detections per frame, ``>= 1``.
        threshold: keep only scores strictly above it (``None``: no threshold).
        mask: bool cube shaped like ``scores``: only its pixels can be detections, and they are
            the only pixels taking part in the NMS (scores elsewhere are ignored and may be
            NaN; e.g. the HOC's support points).

    Returns:
        ``(N, 4)`` float64 detections ``frame, x, y, score`` ordered by frame, then decreasing
        score; a list of ``B`` such tensors for a batched cube.

    Raises:
        TypeError: non-numeric scores or arguments.
        ValueError: wrong rank, NaN/inf, out-of-range arguments.

    Examples:
        >>> scores = torch.zeros(2, 5, 5)
        >>> scores[0, 1, 3] = 2.0
        >>> scores[1, 4, 0] = 1.0
        >>> detect_peaks(scores, max_per_frame=1).tolist()
        [[0.0, 3.0, 1.0, 2.0], [1.0, 0.0, 4.0, 1.0]]
        >>> support = torch.zeros(2, 5, 5, dtype=torch.bool)
        >>> support[1, 2, 2] = True
        >>> detect_peaks(scores, mask=support).tolist()
        [[1.0, 2.0, 2.0, 0.0]]
    """
    if mask is not None:
        if not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool:
            raise TypeError(f"`mask`: expected a bool tensor, got {type(mask).__name__}")
        raw = torch.as_tensor(scores)
        if tuple(mask.shape) != tuple(raw.shape):
            raise ValueError(
                f"`mask`: expected the shape of `scores` {tuple(raw.shape)}, got "
                f"{tuple(mask.shape)}"
            )
        scores = torch.where(mask, raw, torch.zeros((), dtype=raw.dtype))
    cube, batched = as_cube("scores", scores, min_frames=0)
    radius = check_int("radius", radius, minimum=0)
    max_per_frame = check_int("max_per_frame", max_per_frame, minimum=1)
    if threshold is not None:
        threshold = check_number("threshold", threshold)
    if not cube.is_floating_point():
        cube = cube.to(torch.float64)
    allowed = None
    if mask is not None:
        allowed = mask if batched else mask.unsqueeze(0)
        cube = cube.masked_fill(~allowed, -math.inf)
    b, t, h, w = cube.shape
    out = []
    for i in range(b):
        s = cube[i]
        keep = _peaks(s, radius)
        if allowed is not None:
            keep &= allowed[i]
        if threshold is not None:
            keep &= s > threshold
        values = s.reshape(t, h * w)
        key = values.masked_fill(~keep.reshape(t, h * w), -math.inf)
        order = torch.sort(key, dim=1, descending=True, stable=True).indices[:, :max_per_frame]
        kept = keep.reshape(t, h * w).gather(1, order)
        frame = torch.arange(t).unsqueeze(1).expand_as(order)[kept]
        flat = order[kept]
        det = torch.stack(
            [
                frame.to(torch.float64),
                (flat % w).to(torch.float64),
                (flat // w).to(torch.float64),
                values[frame, flat].to(torch.float64),
            ],
            dim=1,
        )
        out.append(det.reshape(-1, 4))
    return out if batched else out[0]


def _check_detections(name: str, detections: Any) -> torch.Tensor:
    if not isinstance(detections, torch.Tensor):
        try:
            detections = torch.as_tensor(detections, dtype=torch.float64)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`{name}`: expected an (N, 4) tensor of frame, x, y, score, "
                f"got {type(detections).__name__}"
            ) from None
    if detections.is_complex() or detections.dtype == torch.bool:
        raise TypeError(f"`{name}`: expected a real tensor, got dtype {detections.dtype}")
    if detections.numel() == 0:
        detections = detections.reshape(0, 4)
    if detections.dim() != 2 or detections.shape[1] != 4:
        raise ValueError(
            f"`{name}`: expected shape (N, 4) (frame, x, y, score), got {tuple(detections.shape)}"
        )
    detections = detections.to(torch.float64)
    if not bool(torch.isfinite(detections).all()):
        raise ValueError(f"`{name}`: expected finite values, got NaN/inf entries")
    frames = detections[:, 0]
    if bool((frames < 0).any()) or bool((frames != frames.round()).any()):
        raise ValueError(f"`{name}`: expected non-negative integer frame indices in column 0")
    return detections


def _check_truth(truth_xy: Any) -> torch.Tensor:
    if not isinstance(truth_xy, torch.Tensor):
        try:
            truth_xy = torch.as_tensor(truth_xy, dtype=torch.float64)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`truth_xy`: expected a (T, 2) tensor of (x, y), got {type(truth_xy).__name__}"
            ) from None
    if truth_xy.is_complex() or truth_xy.dtype == torch.bool:
        raise TypeError(f"`truth_xy`: expected a real tensor, got dtype {truth_xy.dtype}")
    if truth_xy.dim() != 2 or truth_xy.shape[1] != 2:
        raise ValueError(f"`truth_xy`: expected shape (T, 2), got {tuple(truth_xy.shape)}")
    truth_xy = truth_xy.to(torch.float64)
    if bool(torch.isinf(truth_xy).any()):
        raise ValueError("`truth_xy`: expected finite values or NaN (no target), got inf")
    return truth_xy


@dataclass
class ROC:
    """Pd versus false alarms over a threshold sweep (:func:`roc_curve`).

    Entry ``i`` of each curve is the operating point "detections with ``score >=
    thresholds[i]``": entry 0 is ``+inf`` (nothing detected), then every distinct score of the
    evaluated detections in decreasing order.

    Attributes:
        thresholds: ``(K,)`` decreasing thresholds.
        pd: ``(K,)`` fraction of the target frames with a hit at or above the threshold.
        fa_per_frame: ``(K,)`` false alarms at or above the threshold per evaluated frame.
        fa_per_pixel: ``(K,)`` ``fa_per_frame / (H W)`` (NaN if the frame size is not given).
        n_frames: number of evaluated frames.
        n_target_frames: evaluated frames with a target (the denominator of Pd).
    """

    thresholds: torch.Tensor
    pd: torch.Tensor
    fa_per_frame: torch.Tensor
    fa_per_pixel: torch.Tensor
    n_frames: int
    n_target_frames: int


def roc_curve(
    detections: torch.Tensor,
    truth_xy: torch.Tensor,
    *,
    frames: Iterable[int] | None = None,
    hit_radius: float = 3.0,
    frame_shape: tuple[int, int] | None = None,
) -> ROC:
    """Pd and false alarms of detections against the true target pixel, over all thresholds.

    A detection of frame ``t`` is a *hit* if its Euclidean distance to ``truth_xy[t]`` is
    ``<= hit_radius`` pixels, else a *false alarm*. At threshold ``tau`` (detections with
    ``score >= tau``): frame ``t`` is detected if it has a hit; ``Pd`` is the fraction of the
    evaluated frames with a target that are detected; the false alarms per frame are the false
    alarms of the evaluated frames divided by their number. Extra hits in a frame (two
    candidates near the target) count neither as detections nor as false alarms.

    Args:
        detections: ``(N, 4)`` ``frame, x, y, score`` (e.g. :func:`detect_peaks`).
        truth_xy: ``(T, 2)`` true ``(x, y)`` per frame; a NaN row means no target in that frame.
        frames: the frame indices to evaluate (default ``0 .. T - 1``); detections of other
            frames are ignored.
        hit_radius: hit radius in pixels, ``>= 0`` (default 3).
        frame_shape: ``(H, W)`` for the false alarms per pixel.

    Returns:
        :class:`ROC`.

    Raises:
        TypeError: wrong argument types.
        ValueError: wrong shapes, NaN/inf detections, frames outside ``0 .. T - 1``.

    Examples:
        >>> det = torch.tensor([[0, 5, 5, 3.0], [0, 1, 1, 2.0], [1, 9, 9, 4.0], [1, 6, 5, 1.0]])
        >>> roc = roc_curve(det, torch.tensor([[5.0, 5.0], [5.0, 5.0]]))
        >>> roc.thresholds.tolist(), roc.pd.tolist(), roc.fa_per_frame.tolist()
        ([inf, 4.0, 3.0, 2.0, 1.0], [0.0, 0.0, 0.5, 0.5, 1.0], [0.0, 0.5, 0.5, 1.0, 1.0])
    """
    det = _check_detections("detections", detections)
    truth = _check_truth(truth_xy)
    hit_radius = check_number("hit_radius", hit_radius, low=0.0)
    t = truth.shape[0]
    if frames is None:
        chosen = torch.arange(t)
    else:
        chosen = torch.as_tensor(list(frames), dtype=torch.int64)
        if chosen.numel() and (int(chosen.min()) < 0 or int(chosen.max()) >= t):
            raise ValueError(
                f"`frames`: expected frame indices in 0 .. {t - 1}, got "
                f"{int(chosen.min())} .. {int(chosen.max())}"
            )
        chosen = chosen.unique()
    pixels = math.nan
    if frame_shape is not None:
        fh, fw = (check_int("frame_shape", v, minimum=1) for v in frame_shape)
        pixels = float(fh * fw)
    evaluated = torch.zeros(max(t, 1), dtype=torch.bool)
    evaluated[chosen] = True
    fidx = det[:, 0].to(torch.int64)
    inside = fidx < t
    det, fidx = det[inside], fidx[inside]
    keep = evaluated[fidx]
    det, fidx = det[keep], fidx[keep]
    has_target = ~truth.isnan().any(dim=1)
    n_frames = int(chosen.numel())
    n_target = int(has_target[chosen].sum()) if n_frames else 0
    dist = torch.hypot(det[:, 1] - truth[fidx, 0], det[:, 2] - truth[fidx, 1])
    hit = has_target[fidx] & (dist <= hit_radius)
    # best hit score per frame
    best = torch.full((max(t, 1),), -math.inf, dtype=torch.float64)
    if bool(hit.any()):
        best.scatter_reduce_(0, fidx[hit], det[hit, 3], reduce="amax")
    frame_best = best[chosen][has_target[chosen]]
    frame_best = frame_best[torch.isfinite(frame_best)]
    fa_scores = det[~hit, 3]
    levels = det[:, 3].unique(sorted=True).flip(0)
    thresholds = torch.cat([torch.tensor([math.inf], dtype=torch.float64), levels])
    # counts of values >= each threshold
    hits_sorted = frame_best.sort().values
    fa_sorted = fa_scores.sort().values
    n_hits = hits_sorted.numel() - torch.searchsorted(hits_sorted, thresholds, right=False)
    n_fa = fa_sorted.numel() - torch.searchsorted(fa_sorted, thresholds, right=False)
    pd = n_hits.to(torch.float64) / n_target if n_target else torch.full_like(thresholds, math.nan)
    fa = n_fa.to(torch.float64) / n_frames if n_frames else torch.full_like(thresholds, math.nan)
    return ROC(thresholds, pd, fa, fa / pixels, n_frames, n_target)


def pd_at_fa(roc: ROC, fa: float = 1.0, *, per: str = "frame") -> float:
    """Largest Pd among the operating points with at most ``fa`` false alarms per frame (pixel).

    Args:
        roc: a :class:`ROC`.
        fa: false alarms per frame (``per="frame"``) or per pixel (``per="pixel"``), ``>= 0``.
        per: ``"frame"`` or ``"pixel"`` (needs ``frame_shape`` in :func:`roc_curve`).

    Returns:
        Pd in ``[0, 1]`` (NaN if the ROC has no target frame).

    Raises:
        ValueError: ``fa < 0``, an unknown ``per``, or ``per="pixel"`` on a ROC made without
            ``frame_shape``.

    Examples:
        >>> det = torch.tensor([[0, 5, 5, 3.0], [0, 1, 1, 2.0], [1, 9, 9, 4.0], [1, 6, 5, 1.0]])
        >>> roc = roc_curve(det, torch.tensor([[5.0, 5.0], [5.0, 5.0]]))
        >>> pd_at_fa(roc, 0.5), pd_at_fa(roc, 1.0), pd_at_fa(roc, 0.0)
        (0.5, 1.0, 0.0)
        >>> roc = roc_curve(det, torch.tensor([[5.0, 5.0], [5.0, 5.0]]), frame_shape=(10, 10))
        >>> pd_at_fa(roc, 0.005, per="pixel")
        0.5
    """
    fa = check_number("fa", fa, low=0.0)
    if per not in ("frame", "pixel"):
        raise ValueError(f"`per`: expected 'frame' or 'pixel', got {per!r}")
    rates = roc.fa_per_frame if per == "frame" else roc.fa_per_pixel
    if per == "pixel" and bool(rates.isnan().any()) and roc.n_frames:
        raise ValueError("`per`: 'pixel' needs a ROC made with `frame_shape`")
    ok = rates <= fa * (1 + 1e-12) + 1e-15
    if roc.n_target_frames == 0:
        return math.nan
    return float(roc.pd[ok].max()) if bool(ok.any()) else 0.0


def roc_auc(roc: ROC, max_fa: float = 1.0) -> float:
    """Normalised area under Pd versus false alarms per frame, for ``0 <= FA <= max_fa``.

    ``(1 / max_fa) * integral_0^max_fa Pd(x) dx`` with ``Pd(x) = pd_at_fa(roc, x)`` (a step
    function: the best Pd reachable with at most ``x`` false alarms per frame). 1 means the
    target is always found before any false alarm; the single-frame score in [0, 1].

    Args:
        roc: a :class:`ROC`.
        max_fa: upper end of the false-alarm range, ``> 0``.

    Returns:
        Area in ``[0, 1]`` (NaN if the ROC has no target frame).

    Examples:
        >>> det = torch.tensor([[0, 5, 5, 3.0], [0, 1, 1, 2.0], [1, 9, 9, 4.0], [1, 6, 5, 1.0]])
        >>> roc = roc_curve(det, torch.tensor([[5.0, 5.0], [5.0, 5.0]]))
        >>> roc_auc(roc, 1.0)
        0.25
    """
    max_fa = check_number("max_fa", max_fa, low=0.0, low_inclusive=False)
    if roc.n_target_frames == 0:
        return math.nan
    fa = roc.fa_per_frame.clamp(max=max_fa)
    pd = torch.cummax(roc.pd, dim=0).values  # FA is non-decreasing along the sweep
    # step function: Pd = pd[i] on [fa[i], fa[i+1]), the last up to max_fa
    ends = torch.cat([fa[1:], torch.tensor([max_fa], dtype=fa.dtype)])
    return float(((ends - fa).clamp(min=0) * pd).sum() / max_fa)


# ----------------------------------------------------------------------------- files


def write_detections(
    path: str | os.PathLike, detections: torch.Tensor, *, overwrite: bool = False
) -> Path:
    """Write detections to a CSV file with the header ``frame,x,y,score``.

    ``frame``, ``x`` and ``y`` are written as integers when they are whole numbers, ``score``
    with ``repr`` precision (exact round trip). The file is written to a temporary file in the
    same folder and renamed into place (atomic: a reader never sees half a file).

    Args:
        path: the ``.csv`` file.
        detections: ``(N, 4)`` ``frame, x, y, score``.
        overwrite: replace an existing file (default: refuse, so an input is never overwritten).

    Returns:
        The path written.

    Raises:
        FileExistsError: the file exists and ``overwrite`` is false.
        TypeError, ValueError: invalid detections.

    Examples:
        >>> import tempfile, pathlib
        >>> p = pathlib.Path(tempfile.mkdtemp()) / "detections.csv"
        >>> _ = write_detections(p, torch.tensor([[0, 3, 1, 2.5]]))
        >>> p.read_text().splitlines()
        ['frame,x,y,score', '0,3,1,2.5']
    """
    det = _check_detections("detections", detections)
    target = Path(path)
    if target.exists() and not overwrite:
        raise FileExistsError(
            f"`path`: expected a new file (overwrite=True replaces it), got existing {target}"
        )

    def number(v: float) -> str:
        return str(int(v)) if float(v).is_integer() and abs(v) < 2**53 else repr(float(v))

    def write(handle: IO[bytes]) -> None:
        text = io.StringIO(newline="")
        writer = csv.writer(text, lineterminator="\n")
        writer.writerow(DETECTION_COLUMNS)
        for f, x, y, s in det.tolist():
            writer.writerow([number(f), number(x), number(y), repr(float(s))])
        handle.write(text.getvalue().encode())

    # atomic, and created with mode 0o666 minus the umask like every other output (new user:
    # a tempfile.mkstemp file kept its 0600 mode after the rename)
    _atomic_write(target, write)
    return target


def read_detections(path: str | os.PathLike) -> torch.Tensor:
    r"""Read a ``detections.csv`` written by :func:`write_detections` (or by hand).

    Args:
        path: the ``.csv`` file; header ``frame,x,y,score`` (extra columns are not allowed).

    Returns:
        ``(N, 4)`` float64 detections.

    Raises:
        FileNotFoundError: no such file.
        ValueError: wrong header or a bad value (the message names the file and line).

    Examples:
        >>> import tempfile, pathlib
        >>> p = pathlib.Path(tempfile.mkdtemp()) / "d.csv"
        >>> _ = p.write_text("frame,x,y,score\n2,4,5,0.25\n")
        >>> read_detections(p).tolist()
        [[2.0, 4.0, 5.0, 0.25]]
    """
    source = Path(path)
    rows: list[list[float]] = []
    with open(source, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None or tuple(h.strip() for h in header) != DETECTION_COLUMNS:
            raise ValueError(
                f"`path`: expected the header 'frame,x,y,score' in {source}, got {header}"
            )
        for line, row in enumerate(reader, start=2):
            if not row:
                continue
            if len(row) != 4:
                raise ValueError(
                    f"`path`: expected 4 values on line {line} of {source}, got {len(row)}"
                )
            try:
                values = [float(v) for v in row]
            except ValueError:
                raise ValueError(
                    f"`path`: expected numbers on line {line} of {source}, got {row}"
                ) from None
            rows.append(values)
    det = torch.tensor(rows, dtype=torch.float64).reshape(-1, 4)
    try:
        return _check_detections("path", det)
    except ValueError as exc:
        raise ValueError(f"{exc} (file {source})") from None

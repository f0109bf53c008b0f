"""Trajectory retrieval and multi-target detection for the DPA [NR08].

:func:`backtrack` follows the tracking matrix (eq. 8 of [NR08], ``DPAState.origin``) backwards
from a pixel of the last frame and returns the trajectory that produced its accumulated score.
:func:`detect` finds several targets: non-maximum suppression (NMS) on the last-frame ASF, an
optional threshold -- fixed, or a constant-false-alarm-rate (CFAR) threshold estimated from
target-free sequences by :func:`cfar_threshold` (the "future research" of [NR08]) -- and one
back-tracked :class:`DPATrack` per kept peak. Without a threshold the tracks are only the
top-ranked *candidates* (``confirmed=False``): [NR08] takes the highest pixel as the target, which
finds a "target" in pure noise too. Tracks that meet (two targets crossing) are separated by
joint back-tracking or re-tracking so that each keeps its own target (our addition, see
:func:`detect`).

Conventions: positions are ``(x, y)`` = (column, row) pixel indices, flat indices are
``y * W + x``; the pixel containing a float position ``(x, y)`` is
``(floor(x + 0.5), floor(y + 0.5))`` (pixel centres sit on integer coordinates, as in
:mod:`hocnet.data.infrared`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from hocnet._check import (
    as_cube,
    check_choice,
    check_finite,
    check_int,
    check_number,
    restore_batch,
)
from hocnet.dpa.functional import DPAState, accumulate
from hocnet.dpa.matrices import PAPER_SIGMA
from hocnet.dpa.metrics import _upper_quantile

__all__ = ["EXCLUSIVE_METHODS", "DPADetection", "DPATrack", "backtrack", "cfar_threshold", "detect"]

#: The ways :func:`detect` separates tracks that meet (``exclusive``; ``True`` is the first,
#: ``False`` none: the plain back-tracking of [NR08]).
EXCLUSIVE_METHODS = ("straightest", "joint", "retrack")

MASK_RADIUS = 1
"""Re-tracking (``detect(exclusive="retrack")``): pixels within this Chebyshev distance of the
other track are replaced by the frame median."""

ENCOUNTER_RADIUS = 2
"""Joint back-tracking: two tracks at most this Chebyshev distance (px) apart are in an
encounter and are continued by their own motion. Tracks that come this close are the pairs the
joint and the default method separate. (Measured on the crossing scenes of
``experiments/dpa_crossing.py``, 20 seeds per setting: 1 separates up to 2 scenes fewer per
setting, 3 up to 7 fewer.)"""

VELOCITY_FRAMES = 10
"""Joint back-tracking: a track's velocity is the mean of at most this many of its moves before
the encounter (20 measured the same)."""

MEET_RADIUS = 1.5
"""Joint back-tracking: predicted positions at most this Chebyshev distance (px) apart are the
crossing itself, where the two tracks may share pixels (1 and 2 measured at most 1 scene in 20
fewer)."""

REACH = 1.5
"""Joint back-tracking: a track's candidate pixels lie at most this Chebyshev distance (px) from
its predicted position (1 and 2 measured at most 1 scene in 20 fewer)."""

SPREAD = math.sqrt(PAPER_SIGMA**2 + 0.5**2 / 3)
"""Joint back-tracking: standard deviation (px) of the Gaussian weight around the predicted
position, that of ``W_basic`` (eq. 5 of [NR08]: the target spread ``PAPER_SIGMA`` and the
U[-0.5, 0.5] jitter, variance 1/12)."""


# ----------------------------------------------------------------------------- results


@dataclass
class DPATrack:
    """One back-tracked target of :func:`detect`.

    Attributes:
        positions: ``(T, 2)`` int64 ``(x, y)`` pixel of the track in every frame.
        scores: ``(T,)`` float: the ASF at each back-tracked pixel (detached).
        score: the last-frame ASF at the end point (the detection statistic).
        id: 1-based index of the track within its :class:`DPADetection`.
        batch: index of the scene in the batch (0 for unbatched input).
        confirmed: ``True`` if ``score`` passed a detection threshold (fixed or CFAR);
            ``False`` for an unthresholded candidate (see :func:`detect`).
        retracked: ``True`` if the track's path differs from its plain back-tracking of [NR08]
            because it was separated from another track (joint back-tracking or re-tracking,
            see ``exclusive`` in :func:`detect`).
    """

    positions: torch.Tensor
    scores: torch.Tensor
    score: float
    id: int
    batch: int = 0
    confirmed: bool = True
    retracked: bool = False

    @property
    def points(self) -> torch.Tensor:
        """``(T, 3)`` int64 rows ``(t, y, x)``, the track format of :mod:`hocnet.metrics`.

        Examples:
            >>> track = DPATrack(torch.tensor([[4, 1], [5, 1]]), torch.zeros(2), 0.0, 1)
            >>> track.points.tolist()
            [[0, 1, 4], [1, 1, 5]]
        """
        t = torch.arange(self.positions.shape[0], device=self.positions.device)
        return torch.stack([t, self.positions[:, 1], self.positions[:, 0]], dim=1)


@dataclass
class DPADetection:
    """Result of :func:`detect`.

    Attributes:
        state: the :class:`~hocnet.dpa.functional.DPAState` of the frames (input batching).
        tracks: the detected tracks, ordered by scene and, within a scene, by decreasing
            ``score`` (ties: lowest flat index of the end point first).
        threshold: the detection threshold used, or ``None`` (no threshold: top-k peaks only).
    """

    state: DPAState
    tracks: list[DPATrack]
    threshold: float | None

    @property
    def confirmed(self) -> bool:
        """Whether the tracks passed a threshold (``False``: unthresholded candidates)."""
        return self.threshold is not None

    @property
    def note(self) -> str:
        """One line saying what the tracks are (for printing next to them).

        Examples:
            >>> DPADetection(None, [], None).note.split(":")[0]
            'unthresholded'
        """
        if self.threshold is None:
            return (
                "unthresholded: the tracks are the highest-ranked candidates, not detections "
                "(pure noise has candidates too); give `threshold`, or `target_free` for a CFAR "
                "threshold, to confirm them"
            )
        return f"detections above the threshold {self.threshold:.6g}"


# ----------------------------------------------------------------------------- helpers


def _check_overflow(name: str, asf: torch.Tensor, detail: str = "") -> None:
    """Raise if the ASF holds NaN/inf: the recursion overflowed (the frames are finite)."""
    finite = torch.isfinite(asf.detach())
    if asf.numel() == 0 or bool(finite.all()):
        return
    bad = ~finite if finite.dim() == 4 else ~finite.unsqueeze(0)  # (B, T, H, W)
    frame = int(torch.nonzero(bad.flatten(2).any(dim=2).any(dim=0)).flatten()[0])
    raise ValueError(
        f"`{name}`: the accumulated score (ASF) overflowed: {int(bad.sum())} NaN/inf values, "
        f"the first in frame {frame}. accumulate checks that its frames are finite, so the "
        "recursion of eq. (11) blew up: the memory b is too large for this g and these "
        f"matrices (eq. 12-14: keep b * (g sum(w) + (1 - g) max(w)) <= 1){detail}"
    )


def _check_state(state: Any) -> DPAState:
    """Validate a :class:`DPAState` and return its batched form with int64 ``origin``."""
    if not isinstance(state, DPAState):
        raise TypeError(f"`state`: expected a DPAState, got {type(state).__name__}")
    if not isinstance(state.asf, torch.Tensor) or not isinstance(state.origin, torch.Tensor):
        raise TypeError("`state`: expected tensors in `asf` and `origin`, got other types")
    s = state.as_batched()
    asf, origin = s.asf, s.origin
    if asf.dim() != 4 or origin.shape != asf.shape:
        raise ValueError(
            "`state`: expected `asf` and `origin` of the same shape (B, T, H, W), got "
            f"{tuple(asf.shape)} and {tuple(origin.shape)}"
        )
    if not asf.is_floating_point():
        raise TypeError(f"`state`: expected a floating `asf`, got dtype {asf.dtype}")
    if origin.is_floating_point() or origin.is_complex() or origin.dtype == torch.bool:
        raise TypeError(f"`state`: expected an integer `origin`, got dtype {origin.dtype}")
    _, n_t, height, width = asf.shape
    if min(n_t, height, width) < 1:
        raise ValueError(f"`state`: expected non-empty frames, got shape {tuple(asf.shape)}")
    _check_overflow("state", asf)
    origin = origin.long()
    links = origin[:, 1:]
    if links.numel() and bool(((links < 0) | (links >= height * width)).any()):
        raise ValueError(
            f"`state`: expected `origin` in [0, H * W) = [0, {height * width}) in frames 1.., "
            f"got values in [{int(links.min())}, {int(links.max())}]"
        )
    return DPAState(asf, s.direction, origin, True)


def _pixel_index(name: str, xy: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Flat index ``y * W + x`` of the pixels containing the ``(..., 2)`` ``(x, y)`` points."""
    if xy.is_floating_point():
        xy = torch.floor(xy + 0.5)
    xy = xy.long()
    x, y = xy[..., 0], xy[..., 1]
    outside = (x < 0) | (x >= width) | (y < 0) | (y >= height)
    if bool(outside.any()):
        bad = xy[outside][0].tolist()
        raise ValueError(
            f"`{name}`: expected (x, y) inside the W x H = {width} x {height} frame, "
            f"got {tuple(bad)}"
        )
    return y * width + x


def _start_index(start: Any, state: DPAState, batched: bool) -> torch.Tensor:
    """Validate ``start`` and return the ``(B,)`` flat index of the start pixels."""
    bsz, _, height, width = state.asf.shape
    if not isinstance(start, torch.Tensor):
        try:
            start = torch.as_tensor(start)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`start`: expected a tensor of (x, y) pixels, got {type(start).__name__}"
            ) from None
    if start.is_complex() or start.dtype == torch.bool:
        raise TypeError(f"`start`: expected a real tensor, got dtype {start.dtype}")
    shapes = [(2,), (bsz, 2)] if batched else [(2,)]
    if tuple(start.shape) not in shapes:
        wanted = " or ".join(str(s) for s in shapes)
        raise ValueError(f"`start`: expected shape {wanted}, got {tuple(start.shape)}")
    check_finite("start", start)
    if start.is_floating_point():
        if bool((start != torch.round(start)).any()):
            raise ValueError(
                f"`start`: expected integer pixel coordinates (x, y) (a pixel of the last frame), "
                f"got {start.tolist()}"
            )
        start = start.long()
    index = _pixel_index("start", start.to(state.asf.device), height, width)
    return index.expand(bsz) if index.dim() == 0 else index


def _follow(origin: torch.Tensor, batch: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Follow ``origin`` ``(B, T, H * W)`` back from the last frame: ``(M, T)`` flat indices."""
    n_t = origin.shape[1]
    path = torch.empty(index.shape[0], n_t, dtype=torch.int64, device=origin.device)
    path[:, n_t - 1] = index
    for t in range(n_t - 1, 0, -1):
        index = origin[batch, t, index]
        path[:, t - 1] = index
    return path


def _to_xy(flat: torch.Tensor, width: int) -> torch.Tensor:
    """``(..., 2)`` ``(x, y)`` of flat indices."""
    return torch.stack([flat % width, flat // width], dim=-1)


def _local_maxima(scores: torch.Tensor, radius: int) -> torch.Tensor:
    """NMS peaks of ``(B, H, W)`` scores: ``(B, H, W)`` bool.

    A pixel is a peak if no in-frame pixel of its ``(2r + 1) x (2r + 1)`` neighbourhood is
    larger and none with a lower flat index is equal (so a plateau has one peak, its first
    pixel in row-major order).
    """
    if radius == 0:
        return torch.ones_like(scores, dtype=torch.bool)
    _, height, width = scores.shape
    k = 2 * radius + 1
    # max_pool2d pads with -inf: out-of-frame pixels never win
    pooled = F.max_pool2d(scores.unsqueeze(1), k, stride=1, padding=radius).squeeze(1)
    peak = scores >= pooled
    padded = F.pad(scores, (radius, radius, radius, radius), value=float("nan"))
    for dy in range(-radius, 1):
        for dx in range(-radius, radius + 1):
            if dy == 0 and dx >= 0:
                break
            # neighbour q = p + (dx, dy) has a lower flat index; NaN (outside) never ties
            shifted = padded[
                :, radius + dy : radius + dy + height, radius + dx : radius + dx + width
            ]
            peak &= shifted != scores
    return peak


def _select_peaks(
    last: torch.Tensor, radius: int, threshold: float | None, max_targets: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(batch, flat index, value)`` of the kept peaks, by scene then decreasing value."""
    bsz = last.shape[0]
    keep = _local_maxima(last, radius)
    if threshold is not None:
        keep &= last > torch.tensor(threshold, dtype=torch.float64).to(last.dtype)
    values = last.reshape(bsz, -1)
    keep = keep.reshape(bsz, -1)
    # rank the kept peaks first; stable sort: equal values keep the lowest flat index first
    key = values.masked_fill(~keep, float("-inf"))
    order = torch.sort(key, dim=1, descending=True, stable=True).indices
    order = order[:, : min(max_targets, order.shape[1])]
    kept = keep.gather(1, order)
    batch = torch.arange(bsz, device=last.device).unsqueeze(1).expand_as(order)[kept]
    flat = order[kept]
    return batch, flat, values[batch, flat]


# ----------------------------------------------------------------------------- API


def backtrack(state: DPAState, start: torch.Tensor | None = None) -> torch.Tensor:
    """Retrieve a trajectory from the tracking matrix of the DPA, eq. (8) of [NR08].

    Starting at a pixel ``p_{T-1}`` of the last frame, ``p_{n-1} = origin_n(p_n)`` for
    ``n = T - 1, ..., 1`` (section 2.2.4 of [NR08]). With the paper's direction step
    (``accumulate(..., direction_step="paper")``, the default) ``origin_n(p)`` is eq. (8)'s
    argmax: the source pixel with the highest ``Source_Pixel_Score`` of eq. (7)
    (``ASF_{n-1}(q) * w_basic * Var``), which need not be the term that won the max of
    eq. (11). With ``direction_step="source"`` (our earlier reading) it is the source pixel
    whose weighted term won the max of eq. (11).

    Notes:
        Our reading of [NR08]: without ``start`` the trajectory ends at the pixel with the
        highest last-frame ASF (ties: lowest flat index ``y * W + x``). ``start`` is a pixel:
        integer coordinates (an integer tensor, or floats with integer values); a fractional
        start such as ``[3.5, 2]`` raises instead of being rounded or truncated silently. An
        empty batch (``B = 0``) gives an empty ``(0, T, 2)`` result.

    Args:
        state: a :class:`~hocnet.dpa.functional.DPAState` from
            :func:`~hocnet.dpa.functional.accumulate`, batched ``(B, T, H, W)`` or unbatched
            ``(T, H, W)``.
        start: ``(B, 2)`` (batched state; a ``(2,)`` start is used for every scene) or ``(2,)``
            ``(x, y)`` pixel of the last frame, inside the frame, or ``None`` for the highest
            last-frame ASF.

    Returns:
        ``(B, T, 2)`` int64 ``(x, y)`` per frame, or ``(T, 2)`` for an unbatched state.

    Raises:
        TypeError: if ``state`` is not a DPAState or ``start`` is not a real tensor.
        ValueError: inconsistent state, a non-finite ASF (the recursion overflowed: the message
            says so and names the first frame), wrong ``start`` shape, a fractional ``start``,
            or a start outside the frame.

    Examples:
        >>> from hocnet.dpa.functional import accumulate
        >>> frames = torch.zeros(4, 9, 9)
        >>> for t in range(4):
        ...     frames[t, 4, 2 + t] = 1.0  # a target moving +x, one pixel per frame
        >>> state = accumulate(frames, torch.ones(1, 3, 3) / 9, b=1.0, g=0.0)
        >>> backtrack(state).tolist()
        [[2, 4], [3, 4], [4, 4], [5, 4]]
        >>> backtrack(state, start=torch.tensor([0, 0])).tolist()  # a background pixel
        [[0, 0], [0, 0], [0, 0], [0, 0]]
    """
    s = _check_state(state)
    bsz, n_t, _, width = s.asf.shape
    if bsz == 0:
        if start is not None:
            _start_index(start, s, state.batched)
        return torch.zeros(0, n_t, 2, dtype=torch.int64, device=s.asf.device)
    if start is None:
        index = s.asf[:, -1].detach().reshape(bsz, -1).argmax(dim=1)  # first maximum
    else:
        index = _start_index(start, s, state.batched)
    batch = torch.arange(bsz, device=index.device)
    path = _follow(s.origin.reshape(bsz, n_t, -1), batch, index)
    return restore_batch(_to_xy(path, width), state.batched)


def cfar_threshold(
    target_free: torch.Tensor,
    weights: torch.Tensor,
    b: float | torch.Tensor,
    g: float | torch.Tensor,
    *,
    pfa: float = 1e-3,
    nms_radius: int = 3,
    var_table: torch.Tensor | None = None,
    smooth: float | None = None,
    samples: str = "pixels",
    **options: Any,
) -> float:
    """CFAR threshold on the last-frame ASF for a requested false-alarm rate.

    Runs :func:`~hocnet.dpa.functional.accumulate` on target-free sequences (whitened exactly
    like the data), collects last-frame ASF values and returns their empirical upper
    ``pfa``-quantile: with ``N`` samples and ``m = floor(pfa * N)``, the ``(m + 1)``-th largest
    sample, so exactly ``m`` samples (fewer with ties) lie strictly above it and the empirical
    false-alarm rate on ``target_free`` is in ``(pfa - 1/N, pfa]``. :func:`detect` keeps peaks
    strictly above the threshold.

    Notes:
        Our reading of [NR08] (which leaves a CFAR threshold to future research):
        ``samples="pixels"`` (default) uses every last-frame pixel of every sequence
        (``N = B * H * W``), so ``pfa`` is the per-pixel probability that background exceeds
        the threshold, the usual per-pixel Pfa; since :func:`detect` only reports NMS peaks,
        the expected number of false detections per scene is at most ``pfa * H * W``.
        ``samples="peaks"`` uses only the local maxima after NMS of radius ``nms_radius``
        (the candidates :func:`detect` actually thresholds), so ``pfa`` is the probability that
        a background *peak* is reported. ``nms_radius`` is used only with ``"peaks"``.

    Args:
        target_free: target-free whitened frames ``(B, T, H, W)`` or ``(T, H, W)``.
        weights: probability matrices ``(D, k, k)``, as for ``accumulate``.
        b: memory factor in ``[0, b_limit(weights, g)]`` (eq. (12)-(14)).
        g: sum/max mixing in ``[0, 1]``.
        pfa: requested false-alarm probability in ``(0, 1)``; needs ``pfa >= 1 / N``.
        nms_radius: NMS radius ``>= 0`` (``samples="peaks"`` only).
        var_table: optional ``(9, 9)`` direction-similarity table.
        smooth: optional log-sum-exp temperature ``> 0``.
        samples: ``"pixels"`` or ``"peaks"``, see Notes.
        **options: further keyword arguments of ``accumulate`` (passed on unchanged).

    Returns:
        The threshold, a float.

    Raises:
        TypeError: wrong argument types.
        ValueError: out-of-range arguments, ``pfa < 1 / N`` (the message says how many
            samples would be needed), no sequence of ``target_free`` whose last-frame ASF
            varies (sequences where :func:`detect` would find no peak -- a constant last-frame
            ASF, or frames that are each constant -- give no sample and are left out), ``b``
            above the memory range of eq. (12)-(14), or an ASF that overflowed in the
            recursion (both raised by ``accumulate``, naming ``b``).

    Examples:
        >>> noise = torch.randn(4, 3, 16, 16, generator=torch.Generator().manual_seed(0))
        >>> w = torch.ones(1, 3, 3) / 9
        >>> thr = cfar_threshold(noise, w, 0.8, 0.5, pfa=0.01)
        >>> state = accumulate(noise, w, 0.8, 0.5)
        >>> int((state.asf[:, -1] > thr).sum())  # floor(0.01 * 4 * 16 * 16) = 10
        10
    """
    cube, _ = as_cube("target_free", target_free)
    pfa = check_number("pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False)
    nms_radius = check_int("nms_radius", nms_radius, minimum=0)
    samples = check_choice("samples", samples, ("pixels", "peaks"))
    if not cube.is_floating_point():  # bool / integer frames, as accumulate takes them
        cube = cube.to(torch.get_default_dtype())
    state = accumulate(cube, weights, b, g, var_table=var_table, smooth=smooth, **options)
    last = state.asf[:, -1].detach()
    # only sequences whose last frame can have a peak in detect (the same rule): a constant
    # last-frame ASF, or frames that are each constant, give no candidate, so no sample
    flat_last = last.flatten(1)
    usable = flat_last.amax(dim=1) != flat_last.amin(dim=1)
    frame_range = cube.flatten(2).amax(dim=2) - cube.flatten(2).amin(dim=2)  # (B, T)
    usable &= ~(frame_range == 0).all(dim=1).to(usable.device)
    if cube.shape[0] and not bool(usable.any()):
        raise ValueError(
            "`target_free`: expected at least one sequence whose last-frame scores vary (the "
            "CFAR samples are the last-frame ASF of each sequence; a constant one, e.g. a frame "
            "0 after background removal or flat frames, can have no detection), got "
            f"{cube.shape[0]} sequence{'s' * (cube.shape[0] != 1)} of {cube.shape[1]} frame"
            f"{'s' * (cube.shape[1] != 1)}, none usable"
        )
    last = last[usable]
    if samples == "pixels":
        values = last.reshape(-1)
        what = "last-frame pixels of `target_free` (B * H * W)"
    else:
        values = last[_local_maxima(last, nms_radius)]
        what = f"last-frame NMS peaks (radius {nms_radius}) of `target_free`"
    return float(_upper_quantile(values, pfa, what))


def _median_fill(frames: torch.Tensor, paths: list[torch.Tensor], radius: int) -> torch.Tensor:
    """Frames with the pixels near ``paths`` replaced by their frame's median.

    ``frames`` ``(T, H, W)``; ``paths`` ``(T,)`` flat indices; pixels within ``radius``
    (Chebyshev) of a path are replaced (the track's signal removed, the background level kept).
    """
    n_t, height, width = frames.shape
    hit = torch.zeros(n_t, height * width, dtype=frames.dtype, device=frames.device)
    frame = torch.arange(n_t, device=frames.device)
    for path in paths:
        hit[frame, path] = 1.0
    hit = hit.view(n_t, 1, height, width)
    if radius > 0:
        hit = F.max_pool2d(hit, 2 * radius + 1, stride=1, padding=radius)
    mask = hit.view(n_t, height, width) > 0
    level = frames.reshape(n_t, -1).median(dim=1).values.view(n_t, 1, 1)
    return torch.where(mask, level.expand_as(frames), frames)


def _shared(a: torch.Tensor, b: torch.Tensor, width: int) -> float:
    """Fraction of frames where two ``(T,)`` flat paths lie within 1 px (Chebyshev)."""
    gap = (_to_xy(a, width) - _to_xy(b, width)).abs().amax(dim=-1)
    return float((gap <= 1).double().mean())


def _meet(a: torch.Tensor, b: torch.Tensor, width: int) -> bool:
    """Whether two ``(T,)`` flat paths come within ``ENCOUNTER_RADIUS`` (Chebyshev) in a frame."""
    gap = (_to_xy(a, width) - _to_xy(b, width)).abs().amax(dim=-1)
    return bool((gap <= ENCOUNTER_RADIUS).any())


def _bend(paths: list[torch.Tensor], width: int) -> float:
    """Sum over the paths of the squared residuals of a straight-line fit ``(x, y)(t)``."""
    total = 0.0
    for path in paths:
        xy = _to_xy(path, width).double()
        n_t = xy.shape[0]
        if n_t < 3:
            continue
        t = torch.arange(n_t, dtype=torch.float64, device=xy.device)
        design = torch.stack([torch.ones_like(t), t], dim=1)
        coef = torch.linalg.lstsq(design, xy).solution
        total += float((design @ coef - xy).square().sum())
    return total


def _separate(
    paths: list[torch.Tensor],
    clash,
    resolve,
) -> list[tuple[int, torch.Tensor, bool]]:
    """Resolve tracks of one scene that clash: ``[(candidate, path, changed)]``.

    Candidates are taken by decreasing score. A candidate whose path ``clash(path, other)``
    with an accepted track ``j`` is resolved by ``resolve(path_j, path)``, which returns the
    new pair ``(path_j, path)`` or ``None`` (the candidate is a duplicate of ``j`` and is
    dropped, ``j`` unchanged).
    """
    accepted: list[list] = []  # [candidate index, path, changed]
    for i, path in enumerate(paths):
        k = next((k for k, (_, other, _) in enumerate(accepted) if clash(path, other)), None)
        if k is None:
            accepted.append([i, path, False])
            continue
        other = accepted[k][1]
        pair = resolve(other, path)
        if pair is None:
            continue  # a duplicate of a stronger track
        new_j, new_i = pair
        accepted[k][1:] = [new_j, accepted[k][2] or not torch.equal(new_j, other)]
        accepted.append([i, new_i, not torch.equal(new_i, path)])
    return [(i, p, r) for i, p, r in accepted]


def _retrack_options(
    frames: torch.Tensor,
    path_j: torch.Tensor,
    path_i: torch.Tensor,
    accumulate_one,
    width: int,
    max_shared: float,
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The re-tracked pairs ``(path_j, path_i)`` that no longer share more than ``max_shared``.

    Either ``i`` is back-tracked again from its end pixel on the ``(T, H, W)`` ``frames`` with
    ``j``'s pixels (and their neighbours within ``MASK_RADIUS``) removed, or ``j`` is, on the
    frames with ``i``'s pixels removed (``accumulate_one(masked_frames, end)``: the new path).
    """
    options = []
    new_i = accumulate_one(_median_fill(frames, [path_j], MASK_RADIUS), path_i[-1])
    if _shared(new_i, path_j, width) <= max_shared:
        options.append((path_j, new_i))
    new_j = accumulate_one(_median_fill(frames, [path_i], MASK_RADIUS), path_j[-1])
    if _shared(path_i, new_j, width) <= max_shared:
        options.append((new_j, path_i))
    return options


def _straightest(
    options: list[tuple[torch.Tensor, torch.Tensor]], width: int
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """The pair with the smallest :func:`_bend` (ties: the first), or ``None`` if no option."""
    if not options:
        return None
    return min(options, key=lambda pair: _bend(list(pair), width))


def _allowed_moves(weights: torch.Tensor) -> torch.Tensor:
    """``(M, 2)`` int64 offsets ``(i, j)``, ``q = p + (i, j)``, allowed by ``weights``.

    The offsets with a positive weight in some direction of ``weights`` ``(D, k, k)`` (paper
    index convention, eq. (6)), in row-major order (row ``j``, then column ``i``).
    """
    w = torch.as_tensor(weights).detach()
    h = w.shape[-1] // 2
    j, i = torch.nonzero((w > 0).any(dim=0), as_tuple=True)
    return torch.stack([i - h, j - h], dim=1).cpu()


def _best_pair(
    s1: torch.Tensor, s2: torch.Tensor, xy1: torch.Tensor, xy2: torch.Tensor, share: bool
) -> tuple[int, int]:
    """Indices ``(a, b)`` maximising ``s1[a] + s2[b]`` over the pairs of candidate pixels.

    The pixels ``xy1[a]`` and ``xy2[b]`` must lie more than 1 px apart (Chebyshev) unless
    ``share`` (or no pair is that far apart). Ties: the first pair in row-major ``(a, b)`` order.
    """
    total = s1.unsqueeze(1) + s2.unsqueeze(0)
    if not share:
        apart = (xy1.unsqueeze(1) - xy2.unsqueeze(0)).abs().amax(dim=-1) > 1
        if bool(apart.any()):
            total = total.masked_fill(~apart, -math.inf)
    flat = int(torch.argmax(total.reshape(-1)))  # the first maximum
    return flat // s2.shape[0], flat % s2.shape[0]


def _candidates(
    p: torch.Tensor, guess: torch.Tensor, moves: torch.Tensor, height: int, width: int
) -> torch.Tensor:
    """``(N, 2)`` ``(x, y)`` allowed predecessors of ``p`` within ``REACH`` of ``guess``.

    If none is, the in-frame allowed predecessor nearest ``guess`` (Euclidean; ties: first in
    row-major order of the moves).
    """
    q = p + moves
    inside = (q[:, 0] >= 0) & (q[:, 0] < width) & (q[:, 1] >= 0) & (q[:, 1] < height)
    err = q.double() - guess
    near = inside & (err.abs().amax(dim=1) <= REACH)
    if bool(near.any()):
        return q[near]
    dist = err.square().sum(dim=1).masked_fill(~inside, math.inf)
    return q[int(torch.argmin(dist))].view(1, 2)


def _joint(
    asf: torch.Tensor,
    origin: torch.Tensor,
    moves: torch.Tensor,
    ends: tuple[int, int],
    height: int,
    width: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Joint back-tracking of two tracks ending at the flat pixels ``ends`` (one scene).

    ``asf`` ``(T, H * W)`` and ``origin`` ``(T, H * W)`` of the scene, ``moves`` the allowed
    offsets ``(M, 2)``. Returns the two ``(T,)`` flat paths. See ``exclusive`` in :func:`detect`.
    """
    n_t = asf.shape[0]
    paths = [[int(ends[0])], [int(ends[1])]]
    steps: list[list[torch.Tensor]] = [[], []]  # each track's moves outside encounters
    guess: list[torch.Tensor] | None = None
    velocity: list[torch.Tensor] = []
    for n in range(n_t - 1, 0, -1):
        p = [_to_xy(torch.tensor(path[-1]), width) for path in paths]
        gap = int((p[0] - p[1]).abs().max())
        if guess is not None and gap > ENCOUNTER_RADIUS:
            if float((guess[0] - guess[1]).abs().max()) > ENCOUNTER_RADIUS:
                guess = None  # the encounter is over
        if guess is None and gap > ENCOUNTER_RADIUS:
            for i in range(2):  # apart: follow the tracking matrix, eq. (8)
                q = int(origin[n, paths[i][-1]])
                steps[i].append(p[i] - _to_xy(torch.tensor(q), width))
                paths[i].append(q)
            continue
        if guess is None:  # entering an encounter: freeze each track's velocity
            velocity = [
                torch.stack(s[-VELOCITY_FRAMES:]).double().mean(dim=0)
                if s
                else torch.zeros(2, dtype=torch.float64)
                for s in steps
            ]
            guess = [p[i].double() for i in range(2)]
        guess = [guess[i] - velocity[i] for i in range(2)]
        cands, scores = [], []
        for i in range(2):
            q = _candidates(p[i], guess[i], moves, height, width)
            near = torch.exp(-(q.double() - guess[i]).square().sum(dim=1) / (2 * SPREAD**2))
            cands.append(q)
            scores.append(near * asf[n - 1, q[:, 1] * width + q[:, 0]].double())
        share = float((guess[0] - guess[1]).abs().max()) <= MEET_RADIUS
        a, b = _best_pair(scores[0], scores[1], cands[0], cands[1], share)
        for i, k in ((0, a), (1, b)):
            x, y = (int(v) for v in cands[i][k])
            paths[i].append(y * width + x)
    out = [torch.tensor(path[::-1], dtype=torch.int64, device=origin.device) for path in paths]
    return out[0], out[1]


def _exclusive_method(exclusive: Any) -> str | None:
    """Validate ``exclusive``: ``None`` (plain back-tracking) or one of ``EXCLUSIVE_METHODS``."""
    if isinstance(exclusive, bool):
        return EXCLUSIVE_METHODS[0] if exclusive else None
    if not isinstance(exclusive, str):
        raise TypeError(
            "`exclusive`: expected True, False or one of "
            f"{', '.join(repr(m) for m in EXCLUSIVE_METHODS)}, got {exclusive!r}"
        )
    return check_choice("exclusive", exclusive, EXCLUSIVE_METHODS)


def detect(
    frames: torch.Tensor,
    weights: torch.Tensor,
    b: float | torch.Tensor,
    g: float | torch.Tensor,
    *,
    max_targets: int = 5,
    nms_radius: int = 3,
    threshold: float | None = None,
    target_free: torch.Tensor | None = None,
    pfa: float = 1e-3,
    var_table: torch.Tensor | None = None,
    smooth: float | None = None,
    exclusive: bool | str = True,
    max_shared: float = 0.25,
    **options: Any,
) -> DPADetection:
    """Detect several targets with the DPA [NR08] and back-track each of them.

    1. :func:`~hocnet.dpa.functional.accumulate` the frames;
    2. non-maximum suppression on the last-frame ASF: a pixel is a peak if it is the maximum of
       its ``(2r + 1) x (2r + 1)`` neighbourhood, ``r = nms_radius`` (out-of-frame pixels are
       excluded; ties go to the lowest flat index ``y * W + x``, so a plateau gives one peak);
       a scene whose last-frame ASF is constant, or whose frames are each constant (e.g. all
       zero), has no peak: no pixel stands out;
    3. keep the peaks strictly above ``threshold`` (or above
       :func:`cfar_threshold` ``(target_free, ..., pfa=pfa)`` when ``target_free`` is given; with
       neither, no threshold), at most ``max_targets`` per scene, highest first;
    4. :func:`backtrack` each kept peak;
    5. with ``exclusive`` (default ``True``: ``"straightest"``), separate tracks that meet,
       so that each target keeps one track: see Notes.

    Notes:
        **Without a threshold nothing is a detection.** [NR08] takes the highest last-frame
        pixel as the target, which finds one in pure noise as well. Without ``threshold`` or
        ``target_free`` the tracks are the ``max_targets`` highest-ranked candidates, each with
        ``confirmed=False``, and :attr:`DPADetection.note` says so; give a threshold (e.g. a
        CFAR one from target-free frames, ``pfa``) to report only what passes it
        (``confirmed=True``).

        **Crossing targets (our addition).** Each peak is back-tracked on its own, so where two
        targets cross, the tracking matrix of the pixels at the crossing points to one of them
        only: a second track follows its target back to the crossing and the other target
        before it (sharing its early pixels with the first track, or "bouncing" into the other
        target's past). ``exclusive`` chooses how tracks are kept apart:

        * ``"joint"``: **joint back-tracking**. A track that comes within
          ``ENCOUNTER_RADIUS`` = 2 px (Chebyshev) of a stronger track in some frame is
          back-tracked again together with it, from both end pixels, frame by frame backwards.
          While the two are more than 2 px apart each follows the tracking matrix (eq. (8), so
          a pair that never meets is unchanged). When they come within 2 px (an *encounter*),
          each track's velocity is frozen at the mean of its last ``VELOCITY_FRAMES`` = 10
          moves and its position is predicted by that constant velocity (the paper's motion
          model: targets move "in a smooth manner with only gradual changes in direction and
          speed", section 2.2); each track's candidates are its allowed predecessors (the
          support of ``weights``) within ``REACH`` = 1.5 px of its prediction, scored
          ``exp(-|q - prediction|^2 / (2 s^2)) * ASF_{n-1}(q)`` with ``s = SPREAD`` = 0.92 px,
          the spread of ``W_basic`` (Gaussian target spread and U[-0.5, 0.5] jitter, eq. (5));
          and the pair of predecessors with the largest sum of scores is taken (brute force over
          the candidate pairs), the two pixels more than 1 px apart except where the two
          predictions are within ``MEET_RADIUS`` = 1.5 px (the crossing itself). The encounter
          ends when both the tracks and their predictions are more than 2 px apart again. If
          the two new tracks still share more than ``max_shared`` of their frames (within
          1 px), the weaker one is a duplicate of the stronger and is dropped.
        * ``"retrack"`` (the earlier method): a track that shares more than ``max_shared`` of
          its frames (within 1 px) with a stronger track is re-tracked: the DPA is run again on
          the frames with the other track's pixels (and their 8 neighbours) replaced by the
          frame median, and the peak is back-tracked from the same end pixel. Both assignments
          are tried (re-track the weaker track, or the stronger one on the frames without the
          weaker one) and the pair with the straighter tracks is kept; if neither pair
          separates, the weaker track is a duplicate and is dropped.
        * ``"straightest"`` (``True``, the default): for a track that meets a stronger one
          (within 2 px), the candidate pairs are the joint pair, and the re-tracked pairs if the
          two plain tracks share more than ``max_shared`` of their frames (else the plain pair
          itself); of those whose tracks share at most ``max_shared``, the pair with the
          straighter tracks (least sum of squared residuals of straight lines ``(x, y)(t)``, one
          per track: the paper's motion model penalises turns, Figure 2) is kept, the joint pair
          on ties; with none, the weaker track is a duplicate and is dropped. It costs the two
          extra DPA runs of re-tracking per sharing pair.
        * ``False``: the plain back-tracking of [NR08], every peak on its own.

        Changed tracks have ``retracked=True``; their ``score`` is still the last-frame ASF of
        the original run, their ``scores`` the ASF along the new path. Measured
        (``hocnet reproduce dpa-crossing``, ``experiments/results/dpa-crossing.md``): two
        18 dB targets on crossing diagonals meeting at frame 12 of 25, 7 x 7 matrices
        (``v_max = 2``), b of EMC 0.8, 20 seeds; scenes with one track per target (each within
        1.5 px of one target in >= 80 % of the frames), plain / retrack / joint / straightest,
        and in brackets the scenes where each target *alone* is back-tracked that well:

        =========  ===  ======================  ======================
        px/frame   g    paper step              ``"source"`` step
        =========  ===  ======================  ======================
        0.5        1    0 / 11 / 20 / 20 (20)   0 / 1 / 20 / 20 (20)
        0.5        0    0 / 8 / 17 / 18 (19)    0 / 11 / 20 / 20 (20)
        0.71       1    0 / 10 / 20 / 20 (19)   0 / 5 / 20 / 20 (20)
        0.71       0    0 / 5 / 16 / 16 (13)    0 / 6 / 17 / 17 (14)
        1          1    0 / 9 / 18 / 18 (18)    0 / 7 / 20 / 20 (19)
        1          0    0 / 2 / 6 / 6 (4)       0 / 1 / 7 / 7 (3)
        1.41       1    0 / 0 / 1 / 1 (0)       0 / 9 / 16 / 16 (14)
        1.5        1    0 / 0 / 3 / 3 (2)       0 / 9 / 17 / 17 (16)
        near miss  1    8 / 20 / 17 / 20 (19)   12 / 20 / 18 / 20 (20)
        near miss  0    0 / 11 / 4 / 11 (9)     0 / 14 / 8 / 13 (14)
        overtake   1    17 / 20 / 19 / 20 (20)  11 / 19 / 19 / 19 (19)
        overtake   0    3 / 15 / 14 / 16 (13)   0 / 9 / 7 / 9 (8)
        =========  ===  ======================  ======================

        1.41 px/frame is issue 8's scene; at 1.41 and 1.5 px/frame with g = 0 every method
        gives 0 of 20, and so does a lone target. "Near miss": the 0.71 px/frame crossing with
        one path 3 px lower (the targets pass 3 px apart); "overtake": a 1 px/frame target
        passes a 0.2 px/frame one 2 px beside it. On crossings joint back-tracking comes within
        2 scenes of what a lone target allows, and often exceeds it (the predictions carry a
        track through frames where the DPA lags); where the DPA cannot follow a lone target
        (the paper step above about 1 px/frame, g = 0 from 1 px/frame) no separation helps. It
        assumes straight motion through the encounter (a target that turns while it meets
        another is not followed) and relies on the tracking matrix before it: where a plain
        track stalls or is captured by the other target before the tracks are within 2 px (the
        near miss at g = 0), re-tracking does better, hence the default, which keeps the
        straighter of the two. :data:`EXCLUSIVE_METHODS` lists the methods.

        Our reading of [NR08]: a detection is a peak strictly above the threshold (so the CFAR
        threshold's empirical false-alarm rate is at most ``pfa``); the CFAR threshold is the
        per-pixel one of :func:`cfar_threshold` with its default ``samples="pixels"``. An
        empty batch (``B = 0``) gives an empty result.

    Args:
        frames: whitened frames ``(B, T, H, W)`` or ``(T, H, W)``; bool or integer frames
            are converted to the default float dtype (as ``accumulate`` does).
        weights: probability matrices ``(D, k, k)``, as for ``accumulate``.
        b: memory factor in ``[0, b_limit(weights, g)]`` (eq. (12)-(14)).
        g: sum/max mixing in ``[0, 1]``.
        max_targets: largest number of tracks per scene, ``>= 1``.
        nms_radius: NMS radius ``r >= 0`` (``0``: every pixel is a peak).
        threshold: fixed detection threshold, or ``None``.
        target_free: target-free frames ``(B', T', H', W')`` or ``(T', H', W')``, whitened like
            ``frames``, to estimate a CFAR threshold; not together with ``threshold``.
        pfa: false-alarm probability of the CFAR threshold, in ``(0, 1)``.
        var_table: optional ``(9, 9)`` direction-similarity table.
        smooth: optional log-sum-exp temperature ``> 0``.
        exclusive: how to separate tracks that meet: ``"straightest"`` or ``True`` (the
            default: the straighter of the joint and the re-tracked pairs), ``"joint"`` (joint
            back-tracking), ``"retrack"`` (re-tracking on masked frames), or ``False`` (the
            plain back-tracking of [NR08]); see Notes.
        max_shared: largest fraction of frames, in ``[0, 1)``, that two tracks may share
            (within 1 px): above it ``"retrack"`` re-tracks, and a pair still above it after
            the separation is a duplicate (the weaker track is dropped).
        **options: further keyword arguments of ``accumulate`` (passed on unchanged).

    Returns:
        :class:`DPADetection` with the state, the tracks (each ``positions`` ``(T, 2)``
        ``(x, y)``) and the threshold used.

    Raises:
        TypeError: wrong argument types (``exclusive`` neither a bool nor a string).
        ValueError: out-of-range arguments, an unknown ``exclusive`` method, both
            ``threshold`` and ``target_free``, ``target_free`` frames of another size
            ``(H, W)`` than ``frames``, ``b`` above the memory range of eq. (12)-(14),
            or an accumulated score that overflowed in the recursion (both raised by
            ``accumulate``, naming ``b``).

    Examples:
        >>> frames = torch.zeros(3, 16, 16)
        >>> for t in range(3):
        ...     frames[t, 3, 2 + t] = 1.0
        ...     frames[t, 12, 12 - t] = 0.9
        >>> result = detect(frames, torch.ones(1, 3, 3) / 9, 1.0, 0.0, threshold=0.5)
        >>> [(tr.id, tr.positions[-1].tolist(), tr.confirmed) for tr in result.tracks]
        [(1, [4, 3], True), (2, [10, 12], True)]
        >>> result.tracks[1].positions[0].tolist()
        [12, 12]
        >>> detect(frames, torch.ones(1, 3, 3) / 9, 1.0, 0.0).tracks[0].confirmed
        False
        >>> detect(torch.zeros(3, 16, 16), torch.ones(1, 3, 3) / 9, 1.0, 0.0).tracks
        []
    """
    max_targets = check_int("max_targets", max_targets, minimum=1)
    nms_radius = check_int("nms_radius", nms_radius, minimum=0)
    pfa = check_number("pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False)
    method = _exclusive_method(exclusive)
    max_shared = check_number("max_shared", max_shared, low=0.0, high=1.0, high_inclusive=False)
    if threshold is not None:
        if target_free is not None:
            raise ValueError(
                "`threshold`: expected None when `target_free` is given (the CFAR threshold is "
                f"estimated from it), got {threshold!r}"
            )
        threshold = check_number("threshold", threshold)
    cube, _ = as_cube("frames", frames)
    if not cube.is_floating_point():  # bool / integer frames, as accumulate takes them
        cube = cube.to(torch.get_default_dtype())
    if target_free is not None:
        free, _ = as_cube("target_free", target_free)
        if tuple(free.shape[-2:]) != tuple(cube.shape[-2:]):
            raise ValueError(
                "`target_free`: expected frames of the size of `frames`, (H, W) = "
                f"{tuple(cube.shape[-2:])}, got {tuple(free.shape[-2:])}"
            )
    if cube.shape[0] == 0:
        if target_free is not None:
            threshold = cfar_threshold(
                target_free,
                weights,
                b,
                g,
                pfa=pfa,
                nms_radius=nms_radius,
                var_table=var_table,
                smooth=smooth,
                **options,
            )
        empty = torch.zeros(cube.shape, dtype=cube.dtype if cube.is_floating_point() else None)
        index = torch.zeros(cube.shape, dtype=torch.int64)
        return DPADetection(DPAState(empty, index, index - 1, True), [], threshold)
    state = accumulate(frames, weights, b, g, var_table=var_table, smooth=smooth, **options)
    if target_free is not None:
        threshold = cfar_threshold(
            target_free,
            weights,
            b,
            g,
            pfa=pfa,
            nms_radius=nms_radius,
            var_table=var_table,
            smooth=smooth,
            **options,
        )
    s = state.as_batched()
    bsz, n_t, height, width = s.asf.shape
    asf = s.asf.detach().reshape(bsz, n_t, -1)
    last = asf[:, -1]
    # no pixel stands out (constant last ASF, or spatially constant frames): no peak
    flat_scene = last.amax(dim=1) == last.amin(dim=1)
    frame_range = cube.flatten(2).amax(dim=2) - cube.flatten(2).amin(dim=2)  # (B, T)
    flat_scene |= (frame_range == 0).all(dim=1).to(flat_scene.device)
    batch, flat, value = _select_peaks(
        last.view(bsz, height, width), nms_radius, threshold, max_targets
    )
    keep = ~flat_scene[batch]
    batch, flat, value = batch[keep], flat[keep], value[keep]
    path = _follow(s.origin.reshape(bsz, n_t, -1), batch, flat)  # (M, T)
    found = [(int(batch[i]), i, path[i], False) for i in range(path.shape[0])]
    if method is not None and n_t > 2 and path.shape[0] > 1:
        whitened = (cube if cube.is_floating_point() else cube.to(s.asf.dtype)).detach()
        moves = _allowed_moves(weights)
        origin_cpu = s.origin.reshape(bsz, n_t, -1).cpu()
        asf_cpu = asf.cpu()

        def retrack(masked: torch.Tensor, end: torch.Tensor) -> torch.Tensor:
            one = accumulate(
                masked.unsqueeze(0), weights, b, g, var_table=var_table, smooth=smooth, **options
            ).as_batched()
            origin = one.origin.reshape(1, n_t, -1)
            zero = torch.zeros(1, dtype=torch.int64, device=origin.device)
            return _follow(origin, zero, end.view(1).to(origin.device))[0]

        found = []
        for scene in range(bsz):

            def resolve(path_j: torch.Tensor, path_i: torch.Tensor, scene: int = scene):
                choices = []
                if method != "retrack":
                    ends = (int(path_j[-1]), int(path_i[-1]))
                    pair = _joint(asf_cpu[scene], origin_cpu[scene], moves, ends, height, width)
                    pair = tuple(q.to(path_i.device) for q in pair)
                    if _shared(*pair, width) <= max_shared:
                        choices.append(pair)
                if method == "joint":
                    return choices[0] if choices else None
                if _shared(path_j, path_i, width) > max_shared:
                    choices += _retrack_options(
                        whitened[scene], path_j, path_i, retrack, width, max_shared
                    )
                else:  # a pair that meets without sharing: the plain tracks are an option
                    choices.append((path_j, path_i))
                return _straightest(choices, width)

            if method == "retrack":
                clash = lambda a, b: _shared(a, b, width) > max_shared  # noqa: E731
            else:
                clash = lambda a, b: _meet(a, b, width)  # noqa: E731
            members = torch.nonzero(batch == scene).flatten().tolist()
            kept = _separate([path[i] for i in members], clash, resolve)
            found += [(scene, members[k], p, r) for k, p, r in sorted(kept, key=lambda x: x[0])]
    frame = torch.arange(n_t, device=path.device)
    tracks = []
    for scene, i, p, retracked in found:
        tracks.append(
            DPATrack(
                positions=_to_xy(p, width),
                scores=asf[scene, frame, p],
                score=float(value[i]),
                id=len(tracks) + 1,
                batch=scene,
                confirmed=threshold is not None,
                retracked=retracked,
            )
        )
    return DPADetection(state=state, tracks=tracks, threshold=threshold)

"""``hocnet track``: from pixels to confirmed tracks (a detector's plots into the SB-MHT of [PD]).

The detector runs over the sequence and gives per-frame plots (pixel coordinates ``x`` = column,
``y`` = row); the track-oriented MHT (:class:`hocnet.tracking.mht.MHT`) turns them into confirmed
tracks with identities:

* ``--detector hoc``: the modified HOC of [LA98] on a BINARY ``(T, H, W)`` cube (or intensity
  frames binarised as by ``hocnet detect --threshold-pfa``), streaming
  (:class:`hocnet.hoc.stream.StreamingDetector`, sliding windows): the plots of frame ``t`` are
  the points kept on identified HOC tracks in the windows holding ``t`` (union over windows;
  frames after the last full stride get one more window ending at the last frame).
* ``--detector dpa``: the DPA of [NR08] on INTENSITY frames with the pre-processing of
  ``hocnet detect --method dpa``; the plots of frame ``t`` are the local maxima of the causal
  ASF of frame ``t`` (the ``detections.csv`` of ``hocnet detect``), above the DPA's CFAR
  threshold when one is set, at most ``--max-per-frame``.

The input (a ``.npy`` / ``.npz`` sequence or image frames), the detector options and their
validation are those of ``hocnet detect`` (:mod:`hocnet.cli._inputs`), and so is the detection
(:mod:`hocnet.cli.detect`; here frame by frame, with the same plots as the batch path:
tested; with ``--register`` a shift can differ by 0.01 px, see :func:`_white_frames`).

What is online (frame ``n`` processed when it is read, in order; the MHT steps frame by frame
as the detector's plots become final, ``mht.step(z, time=t)``):

* HOC (:func:`_hoc_plots`): a window's density and identification run when its last frame
  arrives; the plots of frame ``t`` are final, and fed to the MHT, after frame
  ``s + window - 1``, ``s`` the last window start ``<= t``: a delay of at most ``window - 1``
  frames (9 with the defaults: frame ``s`` waits ``window - 1`` frames, frame
  ``s + stride - 1`` waits ``window - stride``).
  With ``--threshold-pfa`` each frame is pre-processed and binarised when it is read.
* DPA (:func:`_dpa_plots`): each frame's pre-processing, its ASF (one step of the recursion
  from the previous frame's, :func:`hocnet.dpa.accumulate` with ``initial``) and its plots, at
  that frame: no delay.
* Pre-processing (:func:`_white_frames`): registration of frames ``n - 1`` and ``n``, the
  temporal background of frame ``n`` from its ``--background-window`` previous frames,
  whitening of frame ``n``: causal, a history of ``--background-window`` frames.
* The MHT's false-alarm density (a constructor constant) defaults to the mean number of plots
  per frame over the first ``K = --lambda-fa-frames`` frames that can have plots (5; at least
  0.1 per frame, warned about when at that floor; the DPA's frame 0 with background removal
  and flat frames are not counted: they cannot have plots) divided by the frame area (an
  upper bound: targets are counted too; our choice), fixed after them; the new-target
  density to a tenth of it. The MHT is built once those ``K`` frames' plots are known (they
  are buffered until then); with ``--lambda-fa`` at once.

What is not online:

* The input is a file: it is read whole, and checked whole before any work (finite values,
  float32 range, flat frames for the DPA, the binary check of the HOC). Its number of frames
  ``T`` is known up front; the HOC uses it for its extra last window (``T - window .. T - 1``,
  when the strides do not reach the last frame).
* ``--target-free`` (the DPA's CFAR threshold) is a separate calibration sequence,
  pre-processed and accumulated as a whole before the first frame of SEQ.
* The warnings (dense windows, locally saturated patches, binarisation) are said once, after
  the last frame; the outputs are written at the end.
* Pre-processing costs more per frame than in batch: the background removal runs on the
  ``--background-window + 1`` frames of the history at every frame (about
  ``--background-window / 2`` times the batch work of that step).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import time
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from hocnet.cli import _inputs
from hocnet.cli._common import (
    PIPELINE_THREADS,
    CLIError,
    Writer,
    _check_destinations,
    _check_int,
    _check_number,
    _check_out_dir,
    _Formatter,
    _png_writer,
    _Problems,
    _progress,
    _reported_warnings,
    _show_progress,
    _table,
    _torch_threads,
    _write_outputs,
)

OUTPUT_NAMES = ("tracks.json", "tracks.png")

#: ``hocnet detect``'s DPA options left out here: ``--max-targets`` and ``--nms-radius`` shape
#: only the back-tracked tracks, not the plots.
_DPA_SKIP = ("max_targets", "nms_radius")
#: ``--window`` is one flag for both detectors (added with the HOC's options): the HOC's
#: sliding window (frames), or the DPA's probability-matrix size (pixels, as in ``hocnet
#: detect``; default: the preset's).
_DPA_NOT_ADDED = (*_DPA_SKIP, "window")
_HOC_DESTS = (*_inputs.HOC_DESTS, "window", "stride")
_DPA_DESTS = (
    *(d for d in _inputs.DPA_DESTS if d not in _DPA_SKIP),
    "direction_step",
    "max_per_frame",
)

_LABEL, _SELECTOR = "SEQ", "--detector"

#: Where ``hocnet track`` writes the registration shifts (``hocnet detect``: ``shifts.csv``).
_SHIFTS_AT = "tracks.json (meta.shifts)"

#: The ``status`` of a track in ``tracks.json`` (also in its ``meta.status``).
_STATUS = {
    "confirmed": "confirmed by the SPRT and still held at the last frame",
    "deleted": "confirmed earlier, then ended before the last frame (its score fell below the "
    "SPRT's deletion threshold, or every hypothesis that kept it was pruned); its points "
    "up to then are kept",
}


def _load(args: argparse.Namespace, binary: bool) -> tuple[Any, list[Path]]:
    """Load SEQ as a ``(T, H, W)`` tensor (bool for the HOC, else float64) and its image files."""
    import torch

    cube, files = _inputs.load_input(args.seq, args.key, binary, label=_LABEL, selector=_SELECTOR)
    if cube.dim() != 3:
        raise CLIError(
            f"SEQ: expected one sequence of shape (T, H, W), got shape {tuple(cube.shape)}"
        )
    if cube.dtype != torch.bool:
        cube = cube.double()
        bad = int((~torch.isfinite(cube)).sum())
        if bad:
            raise CLIError(f"SEQ: expected finite values, got {bad} NaN or infinite values")
    if min(cube.shape) == 0:
        raise CLIError(f"SEQ: expected a non-empty sequence, got shape {tuple(cube.shape)}")
    return cube, files


def _prepare(args: argparse.Namespace) -> dict[str, Any]:
    """Validate the detector's options (as ``hocnet detect`` does) before anything is read."""
    det = args.detector
    other = _DPA_DESTS if det == "hoc" else _HOC_DESTS
    mine = _HOC_DESTS if det == "hoc" else _DPA_DESTS
    for dest in other:
        if dest not in mine and getattr(args, dest, None) is not None:
            flag = "--" + dest.replace("_", "-")
            raise CLIError(f"{flag}: does not apply to --detector {det}")
    problems = _Problems()  # every bad option in one message, before any work
    with problems.check():
        _mht_params(args, [], 1.0)  # the tracker's options too
    if det == "hoc":
        params: dict[str, Any] = {}
        with problems.check():
            params = _inputs.prepare_hoc(args, _SELECTOR)
        order = params.get("order")
        if args.window is None:  # the default holds the order: 10, or 2 * order + 1
            window = max(10, 2 * order + 1) if order is not None else 10
        else:
            window = args.window
            with problems.check():
                window = _check_int("--window", window, minimum=1)
                if order is not None and args.order is not None and window < 2 * order + 1:
                    # the order is what the window must hold: name --order, and its range
                    raise CLIError(
                        f"--order: expected at most (--window - 1) // 2 = {(window - 1) // 2} "
                        f"for --window {window} (order k needs 2k + 1 frames per window), "
                        f"got {order}"
                    )
                if order is not None:
                    window = _check_int("--window", window, minimum=2 * order + 1)
        params["window"] = window
        stride = 2 if args.stride is None else args.stride
        with problems.check():
            stride = _check_int("--stride", stride, minimum=1)
            if isinstance(window, int) and stride > window:
                # never useful: the frames between windows would get no plots at all (the
                # tracker would take them as missed detections); refused, not warned
                raise CLIError(
                    f"--stride: expected at most --window = {window} (a larger stride leaves "
                    f"the {stride - window} frame{'s' * (stride - window != 1)} between two "
                    f"windows in no window: no plots there), got {stride}"
                )
        params["stride"] = stride
        problems.raise_all()
        return params
    dpa = argparse.Namespace(**vars(args))
    for dest in _DPA_SKIP:  # not options of this command: the preset's / detect's defaults
        setattr(dpa, dest, None)
    max_per_frame = 5 if args.max_per_frame is None else args.max_per_frame
    with problems.check():
        max_per_frame = _check_int("--max-per-frame", max_per_frame, minimum=1)
    params = {}
    with problems.check():
        from hocnet.cli.detect import _prepare_dpa  # --direction-step as in `hocnet detect`

        params = _prepare_dpa(dpa)
    problems.raise_all()
    params["max_per_frame"] = max_per_frame
    return params


def _check_order_fits(args: argparse.Namespace, n_frames: int, order: int) -> None:
    """Refuse an ``--order`` the sequence cannot hold, with the range it can (after loading)."""
    if n_frames >= 2 * order + 1:
        return
    if args.order is not None and n_frames >= 3:
        raise CLIError(
            f"--order: expected at most (T - 1) // 2 = {(n_frames - 1) // 2} for SEQ of T = "
            f"{n_frames} frames (order k needs 2k + 1 frames), got {order}"
        )
    raise CLIError(
        f"SEQ: expected at least 2 * order + 1 = {2 * order + 1} frames for --order "
        f"{order}, got {n_frames}"
    )


def _hoc_input(cube: Any, params: dict[str, Any]) -> tuple[Iterable[Any], dict[str, Any]]:
    """The binary frames of the HOC, in order, and ``info`` (``notes``, ``shifts``).

    A binary ``cube`` is its own frames. With ``--threshold-pfa`` the intensity frames are
    binarised frame by frame as ``hocnet detect`` does (:func:`hocnet.cli.detect.binarize_frames`):
    the pre-processing of :func:`_white_frames` (causal, frames ``n - background_window .. n``),
    then the ``floor(pfa H W)`` highest whitened pixels of the frame
    (:func:`hocnet.data.binarize.cfar_binarize`); ``info`` gets the registration shifts and the
    notes (shifts, points kept) once the last frame is out, and the warnings of
    ``binarize_frames`` are said then.
    """
    from hocnet.cli.detect import _bound_hoc, _check_float32_range

    n_frames = cube.shape[0]
    order = params["order"]
    if n_frames < 2 * order + 1:
        raise CLIError(
            f"SEQ: expected at least 2 * order + 1 = {2 * order + 1} frames for --order "
            f"{order}, got {n_frames}"
        )
    info: dict[str, Any] = {"notes": [], "shifts": None}
    _bound_hoc(cube, params)
    params["window"] = min(params["window"], n_frames)
    # one window then holds every frame: a stride beyond it skips nothing (no library warning)
    params["stride"] = min(params["stride"], params["window"])
    if params.get("threshold_pfa") is None:
        return cube, info
    _check_float32_range(cube, "`frames`")
    return _binarised(cube, params, info), info


def _binarised(cube: Any, params: dict[str, Any], info: dict[str, Any]) -> Iterator[Any]:
    """``--threshold-pfa``: each frame pre-processed and binarised as soon as it is read."""
    from hocnet.cli.detect import _binarised_note, _shifts_summary
    from hocnet.data.binarize import cfar_binarize

    pfa = params["threshold_pfa"]
    _, height, width = cube.shape
    points = 0
    for white in _white_frames(cube.float(), params, info):
        binary = cfar_binarize(white[None], pfa)[0]
        points += int(binary.sum())
        yield binary
    if info["shifts"] is not None:
        params["unregistered_pairs"] = info["unregistered_pairs"]
        info["notes"].append(
            _shifts_summary(info["shifts"], _SHIFTS_AT, params["unregistered_pairs"])
        )
    # said by the command as `hocnet: warning: ...`, as binarize_frames says them
    info["notes"].append(_binarised_note(pfa, height, width, points))


def _window_starts(n_t: int, window: int, stride: int) -> list[int]:
    """First frames of the HOC's windows: ``0, stride, 2 stride, ...`` and the extra last one.

    The streaming detector reports the windows starting at ``0, stride, 2 stride, ...`` (the
    last one ending at most at the last frame); when the strides do not reach the last frame,
    one more window ends there (start ``T - window``, not a multiple of ``stride``).

    Examples:
        >>> _window_starts(12, 5, 3)
        [0, 3, 6, 7]
    """
    starts = list(range(0, n_t - window + 1, stride))
    if (n_t - window) % stride:
        starts.append(n_t - window)
    return starts


def _window_density(count: int, window: int, h: int, w: int) -> float:
    """A window's clutter density as :class:`~hocnet.hoc.stream.StreamingDetector` computes it.

    The float32 quotient of its on-points over ``window H W`` (as :func:`~hocnet.hoc.detect`).
    """
    import torch

    return float(torch.tensor(float(count)) / (window * h * w))


@contextlib.contextmanager
def _no_window_notes() -> Iterator[None]:
    """Drop a window's own local-saturation note (:func:`_hoc_plots` says them once, at the end).

    Entered around each push, never across a ``yield`` (the filter is process-wide).
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*windows of scans", category=RuntimeWarning)
        yield


def _hoc_plots(
    cube: Iterable[Any], p: dict[str, Any], shape: tuple[int, int, int] | None = None
) -> Iterator[tuple[int, Any]]:
    """Per-frame plots ``(M_t, 2)`` (x, y) of the streaming HOC, yielded as frames become final.

    Frames are read one at a time (iterating over ``cube``) and kept only while a window
    still needs them (the last ``window``). When frame ``n`` arrives, the window ending at
    ``n`` (if any) is complete: its density (on-points over ``window H W``) is computed then,
    and if it is above the modified HOC's discrimination bound
    (:func:`~hocnet.hoc.functional.density_bound`, [LA98] section IV-B) it is skipped (no
    plots, not pushed: streaming through a saturated cube costs without bound, a 20 x 32 x 32
    cube of ones took 45 s). Otherwise its frames not yet pushed are pushed to the
    :class:`~hocnet.hoc.stream.StreamingDetector` of the current run of consecutive sparse
    windows (a new detector after a dense window), whose windows are those of one detector
    over the whole sequence (each equals :func:`~hocnet.hoc.detect` on its scans); the extra
    last window (:func:`_window_starts`) is one :func:`~hocnet.hoc.detect` call. The plots of
    frame ``t`` are the points kept on identified tracks (``cleaned``) in every window holding
    ``t``; ``(t, plots_t)`` is yielded as soon as every window that can hold ``t`` is done,
    that is after frame ``s + window - 1`` with ``s`` the last window start ``<= t`` (at most
    ``window - 1`` frames of delay; the number of frames ``T`` is known from the input, which
    fixes the extra last window).

    The warnings (dense windows, with their count; locally saturated patches,
    ``LOCAL_SATURATION`` of :mod:`hocnet.hoc.identify`, with the sequence's frame numbers rather
    than once per window with the window's scan numbers) are said once, after the last frame
    (:func:`warnings.warn`, said by the command as ``hocnet: warning: ...``).

    Args:
        cube: ``(T, H, W)`` bool scans, or any iterable of ``(H, W)`` bool scans (a stream).
        p: the HOC options (:func:`hocnet.cli.detect.hoc_kwargs`), ``window``, ``stride``,
            ``min_speed``.
        shape: ``(T, H, W)``; default ``cube.shape``.

    Yields:
        ``(t, plots)``: frame ``t`` in order ``0 .. T - 1``, ``plots`` ``(M_t, 2)`` float64
        ``(x, y)`` pixel positions in row-major order.
    """
    import torch

    from hocnet.cli.detect import hoc_kwargs
    from hocnet.hoc import density_bound, detect, reject_slow_tracks
    from hocnet.hoc.identify import LOCAL_SATURATION, _local_saturation
    from hocnet.hoc.stream import StreamingDetector

    kw = hoc_kwargs(p)
    window, stride = p["window"], p["stride"]
    n_t, h, w = tuple(cube.shape) if shape is None else shape  # type: ignore[attr-defined]
    starts = _window_starts(n_t, window, stride)
    extra = starts[-1] if starts[-1] % stride else None
    bound = density_bound("modified", p["v"], math.radians(p["delta"]))

    def cleaned(result: Any) -> Any:
        if p["min_speed"] > 0:
            result = reject_slow_tracks(result, p["min_speed"])
        return result.cleaned

    frames: dict[int, Any] = {}  # the frames a window still needs
    counts: dict[int, int] = {}
    kept: dict[int, Any] = {}  # frames not yet yielded: (H, W) bool, kept points
    saturated: list[int] = []  # frames with a locally saturated patch
    dense: list[int] = []
    densities: list[float] = []
    identified: list[int] = []
    det: Any = None
    run0 = pushed = 0  # the detector's first frame, the next frame to push to it
    done = 0  # windows done (index into `starts`)
    emitted = 0
    for n, scan in enumerate(cube):
        frames[n] = scan
        counts[n] = int(frames[n].sum())
        kept[n] = torch.zeros(h, w, dtype=torch.bool)
        if bool(_local_saturation(frames[n].reshape(1, 1, h, w).bool(), kw["v"]).any()):
            saturated.append(n)
        while done < len(starts) and starts[done] + window - 1 == n:
            s = starts[done]
            done += 1
            density = _window_density(sum(counts[t] for t in range(s, n + 1)), window, h, w)
            densities.append(density)
            if density > bound:  # not identified, not pushed; the run of windows ends
                dense.append(s)
                det = None
                continue
            identified.append(s)
            if s == extra:  # the last frames: one final window ending at the last frame
                last = torch.stack([frames[t] for t in range(s, n + 1)])
                with _no_window_notes():
                    out = cleaned(detect(last, **kw))
            else:
                if det is None:
                    det = StreamingDetector(window=window, stride=stride, **kw)
                    run0 = pushed = s
                result = None
                with _no_window_notes():
                    for t in range(pushed, n + 1):
                        result = det.push(frames[t])
                pushed = n + 1
                assert result is not None and run0 + result.start == s
                out = cleaned(result.result)
            for i, t in enumerate(range(s, n + 1)):
                kept[t] |= out[i]
        # no window needs them any more (nor the running detector: stride > window pushes the
        # frames between windows too)
        for t in [t for t in frames if t <= n + 1 - window and (det is None or t < pushed)]:
            del frames[t], counts[t]
        final = starts[done] if done < len(starts) else n_t  # frames before it are final
        while emitted <= n and emitted < final:
            yield emitted, kept.pop(emitted).nonzero().double()[:, [1, 0]]
            emitted += 1
    if dense:
        warnings.warn(
            f"clutter density above the modified HOC's discrimination bound {100 * bound:.2f} % "
            f"([LA98] section IV-B) in {len(dense)} of {len(starts)} windows (densest "
            f"{100 * max(densities):.2f} %): the detector cannot tell targets from clutter there; "
            "track identification skipped, no plots from those windows",
            RuntimeWarning,
            stacklevel=2,
        )
    covered = {t for s in identified for t in range(s, s + window)}  # identified frames only
    shown = [t for t in saturated if t in covered]
    if shown:
        side = 2 * kw["v"] + 1
        warnings.warn(
            f"clutter density above {100 * LOCAL_SATURATION:.0f} % in {side} x {side} windows "
            f"of frames {shown}: the points there are left out of track identification",
            RuntimeWarning,
            stacklevel=2,
        )


def _dpa_setup(cube: Any, params: dict[str, Any]) -> dict[str, Any]:
    """What the DPA needs before the first frame: checks, matrices, ``b`` and the threshold.

    The frame count and size checks of ``hocnet track``, then the set-up shared with
    ``hocnet detect --method dpa`` (:func:`hocnet.cli.detect.dpa_setup`): the input checks
    (over the whole loaded sequence: finite values, float32 range, flat frames), the
    probability matrices (``--preset``), ``b`` and the detection threshold, fixed
    (``--asf-threshold``) or CFAR from ``--target-free`` (a separate calibration sequence,
    pre-processed and accumulated as a whole: not the input).

    Returns:
        ``{"weights", "b", "threshold", "params"}``; ``params``: the options with the values
        used (``b``, ``threshold_used``, ``cfar``).
    """
    from hocnet.cli.detect import DETECTION_NMS_RADIUS, MIN_DPA_FRAMES, dpa_setup

    params = dict(params)
    frame_names = params.pop("frame_names", None)
    size, (n_t, height, width) = params["window"], cube.shape
    background = params["background"] != "none"
    if n_t < max(2 + background, MIN_DPA_FRAMES):  # the tracker needs plots in two frames
        because = (
            f"; frame 0 has no plots with --background {params['background']} (no past frames)"
            * background
        )
        raise CLIError(
            f"SEQ: expected at least {2 + background} frames for --detector dpa, got {n_t} (the "
            f"tracker needs plots in 2 frames to confirm a track{because})"
        )
    if min(height, width) < size:
        raise CLIError(
            f"SEQ: expected frames of at least {size} x {size} for the {size} x {size} DPA "
            f"matrices (--window, default of --preset {params['preset']}), got {height} x "
            f"{width}"
        )
    setup = dpa_setup(cube, params, _LABEL, frame_names, cfar=True)
    b, threshold = setup["b"], setup["threshold"]
    params = {k: v for k, v in params.items() if k != "target_free"}
    params.update(
        b=b,
        threshold_used=threshold,
        cfar=setup["target_free"] is not None,
        detections_nms_radius=DETECTION_NMS_RADIUS,
    )
    return {"weights": setup["weights"], "b": b, "threshold": threshold, "params": params}


def _white_frames(frames: Any, params: dict[str, Any], info: dict[str, Any]) -> Iterator[Any]:
    """The pre-processing of ``hocnet detect`` (:func:`~hocnet.cli.detect._preprocess`), per frame.

    Frame ``n`` (float32 ``(H, W)``) is yielded from frames ``n - background_window .. n``
    only: registration by phase correlation of frames ``n - 1`` and ``n``
    (:func:`~hocnet.data.background.estimate_shifts`; the offsets are the running sums of the
    shifts), the causal temporal background of frame ``n`` from its ``background_window``
    previous frames (:func:`~hocnet.data.background.remove_background` on those frames and
    frame ``n``, moved by the offsets), the spatial whitening of frame ``n``. Every step is
    causal, so this is the batch pre-processing of the whole sequence, frame by frame; the
    results are equal (tested) except for float32 rounding in the registration: the FFTs of
    one pair and of the whole sequence at once round differently, which moved one shift of
    23 by one 0.01 px step of the sub-pixel search on a test scene (given the same shifts, the
    frames are equal).
    Cost: the background removal runs on the ``background_window + 1`` frames of the history
    at every frame (it returns every frame's background; only the last one is kept), about
    ``background_window / 2`` times the batch work of that step (measured, 40 x 256 x 256,
    ``--preset recommended``, one thread: 4.2-4.8 s frame by frame, 1.3-1.7 s in batch).

    ``info`` receives ``shifts`` (``(T, 2)`` or ``None``) and ``unregistered_pairs`` (the pairs
    the peak test left at shift 0) once the last frame is yielded.
    """
    import torch

    from hocnet.data.background import estimate_shifts, remove_background
    from hocnet.data.whitening import anti_mean, anti_median

    n_t, height, width = frames.shape
    register, method, span = params["register"], params["background"], params["background_window"]
    whiten = {"mean": anti_mean, "median": anti_median}.get(params["whiten"])
    outer = min(7, *(n if n % 2 else n - 1 for n in (height, width)))
    if whiten is not None and outer < 3:
        raise CLIError(f"--whiten: frames of {height} x {width} are too small for a ring")
    inner = 3 if outer >= 5 else 1

    def overflow(step: str) -> CLIError:
        return CLIError(
            f"`frames`: values too large for float32 in the {step} (largest |value| "
            f"{float(frames.abs().max()):.3g}); rescale the frames"
        )

    shifts: list[Any] = []
    rejected = 0
    for n in range(n_t):
        x = frames[n]
        offsets = None
        if register:
            shift = torch.zeros(2, dtype=frames.dtype)
            if n:
                pair, weak = estimate_shifts(frames[n - 1 : n + 1], return_rejected=True)
                shift, rejected = pair[1], rejected + int(weak[1])
                if not bool(torch.isfinite(shift).all()):
                    raise overflow("registration (--register)")
            shifts.append(shift)
            offsets = torch.stack(shifts).cumsum(dim=0)  # the batch's cumsum, on its prefix
        if method != "none":
            first = max(0, n - span)
            x = remove_background(
                frames[first : n + 1],
                method,
                span,
                offsets=None if offsets is None else offsets[first:],
            )[-1]
            if not bool(torch.isfinite(x).all()):
                raise overflow("background removal (--background)")
        if whiten is not None:
            x = whiten(x[None], outer, inner)[0]
        if n == n_t - 1 and register:
            info["shifts"] = torch.stack(shifts)
            info["unregistered_pairs"] = rejected
        yield x


def _dpa_plots(cube: Any, params: dict[str, Any]) -> tuple[Iterator[tuple[int, Any]], dict]:
    """Per-frame plots of the DPA (local maxima of the causal ASF), frame by frame.

    The setup (:func:`_dpa_setup`) runs at once (its errors before any frame); then each
    frame is pre-processed (:func:`_white_frames`), its ASF is one step of the recursion
    from the previous frame's (:func:`hocnet.dpa.accumulate` with ``initial``: the same ASF
    as the batch call on the whole sequence), and its plots are the local maxima of that ASF
    (:func:`hocnet.detection_metrics.detect_peaks`, radius ``DETECTION_NMS_RADIUS``) above the
    threshold when one is set, at most ``max_per_frame``, none on a constant ASF (e.g. frame 0
    after background removal). ``(t, plots_t)`` is yielded at frame ``t``: no delay.

    Returns:
        ``(stream, info)``: the generator of ``(t, (M_t, 2) float64 (x, y))`` and a dict whose
        ``meta`` (the parameters used) and ``shifts`` (registration, or ``None``) are complete
        once the stream is exhausted.
    """
    import torch

    from hocnet.cli.detect import DETECTION_NMS_RADIUS
    from hocnet.detection_metrics import detect_peaks
    from hocnet.dpa import accumulate

    setup = _dpa_setup(cube, params)
    used = setup["params"]
    per_frame = params["max_per_frame"]
    threshold = setup["threshold"]
    info: dict[str, Any] = {"shifts": None}

    def stream() -> Iterator[tuple[int, Any]]:
        state = None
        white = _white_frames(cube.float(), used, info)
        for t, frame in enumerate(white):
            state = accumulate(
                frame[None],
                setup["weights"],
                setup["b"],
                used["g"],
                direction_step=used["direction_step"],
                initial=state,
            )
            asf = state.asf.detach().double()  # (1, H, W)
            found = detect_peaks(
                asf, radius=DETECTION_NMS_RADIUS, max_per_frame=per_frame, threshold=threshold
            )
            flat = asf.flatten()
            if flat.numel() and bool(flat.max() == flat.min()):
                found = found[:0]  # a constant frame (e.g. frame 0 after background removal)
            yield t, found[:, 1:3].to(torch.float64)
        if "unregistered_pairs" in info:
            used["unregistered_pairs"] = info["unregistered_pairs"]
        info["meta"] = {
            "preset": used["preset"],
            "max_per_frame": per_frame,
            "asf_threshold": threshold,
            "cfar": used["cfar"],
            "nms_radius": DETECTION_NMS_RADIUS,
            **{
                k: used[k]
                for k in (
                    "g",
                    "b",
                    "window",
                    "direction_step",
                    "v_max",
                    "equal_gain",
                    "pfa",
                    *_inputs.PRE_DESTS,
                    "unregistered_pairs",
                )
                if k in used
            },
        }

    return stream(), info


#: Frames whose plots give the default ``--lambda-fa`` (``--lambda-fa-frames``).
LAMBDA_FA_FRAMES = 5


def _mht_params(
    args: argparse.Namespace,
    plots: list[Any],
    area: float,
    *,
    counted: list[int] | None = None,
    skipped: list[int] | None = None,
) -> dict[str, Any]:
    """The tracker's parameters; the default densities from ``plots``, the first K frames' plots.

    ``--lambda-fa`` defaults to the mean number of plots per frame over ``plots`` (at least 0.1
    per frame) divided by the frame ``area``; ``--lambda-nt`` to a tenth of ``--lambda-fa``.
    ``lambda_fa_source`` / ``lambda_nt_source`` say where each value came from.

    ``counted``: the frames ``plots`` are of (the first ``K`` frames that can have plots,
    :func:`_run_mht`); ``skipped``: the frames before the last counted one that were left out
    (before the detector's first possible plot, or flat). Both are recorded
    (``lambda_fa_frames_counted`` / ``lambda_fa_frames_skipped``), and so is an estimate at
    its floor (``lambda_fa_at_floor``: fewer than 0.1 plots per counted frame), which
    :func:`_run_mht` warns about when the whole sequence has more plots than that.
    """
    pd = _check_number(
        "--pd", args.pd, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
    )
    meas = _check_number("--meas-std", args.meas_std, low=0.0, low_inclusive=False)
    frames = getattr(args, "lambda_fa_frames", None)
    if frames is not None:
        frames = _check_int("--lambda-fa-frames", frames, minimum=1)
        if args.lambda_fa is not None:
            raise CLIError(
                "--lambda-fa-frames: expected no --lambda-fa-frames with --lambda-fa (it sets "
                "the frames that give the default --lambda-fa), got both"
            )
    n_plots = sum(int(p.shape[0]) for p in plots)
    extra: dict[str, Any] = {}
    if args.lambda_fa is None:
        lam = max(n_plots / max(len(plots), 1), 0.1) / area
        k = LAMBDA_FA_FRAMES if frames is None else frames
        which = (
            f"the first {len(plots)} frame{'s' * (len(plots) != 1)}"
            if counted is None or counted == list(range(len(counted)))
            else f"{len(plots)} frame{'s' * (len(plots) != 1)} ({_frame_list(counted)})"
        )
        last = len(plots) - 1 if counted is None else (counted[-1] if counted else 0)
        source = (
            f"default: mean plots per frame over {which} ({n_plots} plots; at least 0.1 per "
            f"frame) / frame area {area:g} px, fixed from frame {last} on (--lambda-fa-frames "
            f"{k})"
        )
        if skipped:
            source += (
                f"; not counted: frame{'s' * (len(skipped) != 1)} {_frame_list(skipped)} "
                "(no possible plot: before the detector's first plot frame, or flat)"
            )
        if counted is not None:
            extra = {
                "lambda_fa_frames_counted": counted,
                "lambda_fa_frames_skipped": skipped or [],
                "lambda_fa_at_floor": n_plots < 0.1 * max(len(plots), 1),
            }
    else:
        lam = _check_number("--lambda-fa", args.lambda_fa, low=0.0, low_inclusive=False)
        source = "--lambda-fa"
    lam_nt = (
        lam / 10
        if args.lambda_nt is None
        else _check_number("--lambda-nt", args.lambda_nt, low=0.0, low_inclusive=False)
    )
    return {
        "filter": args.filter,
        "pd": pd,
        "meas_std": meas,
        "sigma_a": _check_number("--sigma-a", args.sigma_a, low=0.0),
        "velocity_std": _check_number(
            "--velocity-std", args.velocity_std, low=0.0, low_inclusive=False
        ),
        "lambda_fa": lam,
        "lambda_fa_source": source,
        **extra,
        "lambda_nt": lam_nt,
        "lambda_nt_source": "--lambda-nt" if args.lambda_nt is not None else "lambda_fa / 10",
        "n_hypotheses": _check_int("--n-hypotheses", args.n_hypotheses, minimum=1),
        "n_scan": _check_int("--n-scan", args.n_scan, minimum=0),
        "alpha": _check_number(
            "--alpha", args.alpha, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
        ),
        "beta": _check_number(
            "--beta", args.beta, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
        ),
    }


def _build_mht(p: dict[str, Any]) -> Any:
    """The MHT of the parameters ``p`` (:func:`_mht_params`)."""
    from functools import partial

    import torch

    from hocnet.tracking.kalman import constant_velocity
    from hocnet.tracking.mht import MHT, CVKalmanFilter, IMMFilter

    if p["filter"] == "imm":
        filt: Any = IMMFilter(
            [
                partial(constant_velocity, sigma_a=p["sigma_a"]),
                partial(constant_velocity, sigma_a=10 * p["sigma_a"]),
            ],
            [[0.95, 0.05], [0.05, 0.95]],
            initial_mu=[0.5, 0.5],
            velocity_std=p["velocity_std"],
        )
    else:
        filt = CVKalmanFilter(p["sigma_a"], p["velocity_std"])
    try:
        return MHT(
            filt,
            R=(p["meas_std"] ** 2) * torch.eye(2, dtype=torch.float64),
            pd=p["pd"],
            lambda_fa=p["lambda_fa"],
            lambda_nt=p["lambda_nt"],
            alpha=p["alpha"],
            beta=p["beta"],
            n_hypotheses=p["n_hypotheses"],
            n_scan=p["n_scan"],
        )
    except ValueError as err:  # e.g. alpha + beta >= 1
        raise CLIError(str(err).replace("`alpha`", "--alpha").replace("`beta`", "--beta")) from None


def _frame_list(frames: list[int]) -> str:
    """Frame numbers as said in messages: ``0-4`` for a run, else ``0, 2, 5`` (at most 8).

    Examples:
        >>> _frame_list([1, 2, 3]), _frame_list([0, 2, 5]), _frame_list([])
        ('1-3', '0, 2, 5', 'none')
    """
    if not frames:
        return "none"
    if len(frames) > 2 and frames == list(range(frames[0], frames[-1] + 1)):
        return f"{frames[0]}-{frames[-1]}"
    return ", ".join(map(str, frames[:8])) + (", ..." if len(frames) > 8 else "")


def _run_mht(
    stream: Iterable[tuple[int, Any]],
    args: argparse.Namespace,
    n_frames: int,
    area: float,
    uncounted: Iterable[int] = (),
) -> tuple[list[Any], list[Any], dict[str, Any]]:
    """Feed the plots to the MHT as they arrive: ``(tracks, plots, mht_params)``.

    With ``--lambda-fa`` the MHT is built before the first frame; else once the plots of the
    first ``K = --lambda-fa-frames`` frames that can have plots (all of them if fewer) are
    known, which fixes its false-alarm density (a constructor constant), and the buffered
    frames are stepped then. ``uncounted``: frames that cannot have plots (the DPA's frame 0
    with background removal, flat frames), buffered but not counted in the estimate (their
    zero plots would pull it down, to its floor, and give false confirmed tracks). An estimate
    at its floor is warned about (:class:`RuntimeWarning`, the CLI's one ``hocnet: warning:``
    line) when the sequence's frames that can have plots have more than 0.1 plots per frame.
    """
    frames = LAMBDA_FA_FRAMES if args.lambda_fa_frames is None else args.lambda_fa_frames
    fixed = args.lambda_fa is not None
    skip = set(uncounted)
    plots: list[Any] = []
    counted: list[int] = []
    mht: Any = None
    params: dict[str, Any] = {}

    def build() -> Any:
        nonlocal params
        if fixed:
            params = _mht_params(args, [], area)
        else:
            skipped = [i for i in range(len(plots)) if i in skip]
            params = _mht_params(
                args, [plots[i] for i in counted], area, counted=counted, skipped=skipped
            )
        built = _build_mht(params)
        for i, zi in enumerate(plots):  # the buffered frames
            built.step(zi, time=float(i))
        return built

    for t, z in stream:
        assert t == len(plots)
        plots.append(z)
        if mht is not None:
            mht.step(z, time=float(t))
            continue
        if t not in skip:
            counted.append(t)
        if fixed or len(counted) >= frames or t >= n_frames - 1:
            mht = build()
    if mht is None:  # the stream ended early
        mht = build()
    if params.get("lambda_fa_at_floor"):
        later = [int(z.shape[0]) for t, z in enumerate(plots) if t not in skip]
        mean = sum(later) / max(len(later), 1)
        if mean > 0.1:  # the floor was too low for this sequence: false tracks likely
            n = len(params["lambda_fa_frames_counted"])
            warnings.warn(
                f"--lambda-fa: the default estimate is at its floor (0.1 plots per frame: "
                f"{sum(int(plots[i].shape[0]) for i in params['lambda_fa_frames_counted'])} "
                f"plots in the {n} counted frame{'s' * (n != 1)}) while the sequence has "
                f"{mean:.2g} plots per frame: confirmed tracks may be false; set --lambda-fa, "
                "or a larger --lambda-fa-frames",
                RuntimeWarning,
                stacklevel=2,
            )
    return mht.all_tracks(), plots, params


def _track_dicts(tracks: list[Any], plots: list[Any]) -> list[dict[str, Any]]:
    out = []
    for tr in tracks:
        points = [
            [t, float(plots[t][j, 0]), float(plots[t][j, 1]), j] for t, j in tr.associations()
        ]
        out.append(
            {
                "id": int(tr.id),
                "status": tr.status,
                "score": float(tr.score),
                "first_frame": int(tr.birth),
                "last_frame": int(tr.birth + len(tr.measurements) - 1),
                "state": [float(v) for v in tr.state],
                "covariance": [[float(v) for v in row] for row in tr.covariance],
                "points": points,
            }
        )
    return out


#: The colour of the track ids in ``tracks.png`` (drawn with a white outline).
LABEL_COLOUR = "navy"


def _figure(cube: Any, plots: list[Any], tracks: list[dict[str, Any]], title: str) -> Any:
    from matplotlib import patheffects
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 6), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    image = cube.double().amax(0) if cube.dtype.is_floating_point else cube.amax(0).double()
    ax.imshow(image.numpy(), cmap="gray", origin="upper", interpolation="nearest")
    allp = [p for p in plots if p.shape[0]]
    if allp:
        import torch

        xy = torch.cat(allp).numpy()
        ax.scatter(xy[:, 0], xy[:, 1], s=4, c="tab:orange", alpha=0.5, label="plots")
    for tr in tracks:
        pts = tr["points"]
        xs, ys = [p[1] for p in pts], [p[2] for p in pts]
        ax.plot(xs, ys, "-o", ms=2, lw=1.2)
        if pts:  # dark text in a white outline: readable on white HOC points and on black
            ax.annotate(
                str(tr["id"]),
                (xs[-1], ys[-1]),
                color=LABEL_COLOUR,
                fontsize=9,
                fontweight="bold",
                path_effects=[patheffects.withStroke(linewidth=2.5, foreground="white")],
            )
    ax.set_title(title)
    ax.set_xlabel("x (column)")
    ax.set_ylabel("y (row)")
    return fig


def _cmd_track(args: argparse.Namespace) -> int:
    from hocnet.cli.detect import _shifts_summary

    det = args.detector
    det_params = _prepare(args)
    binary = det == "hoc" and det_params.pop("binary", True)
    out = _check_out_dir(args.out)
    _inputs.out_inside_input(out, args.seq, _LABEL)
    inputs = _inputs.input_paths(args.seq, _LABEL)
    if getattr(args, "target_free", None) is not None:  # a file, or image frames like the input
        inputs.update(_inputs.input_paths(args.target_free, "--target-free"))
        _inputs.out_inside_input(out, args.target_free, "--target-free")
    names = [n for n in OUTPUT_NAMES if not (args.no_plot and n.endswith(".png"))]
    _check_destinations(out, names, inputs, force=args.force)
    cube, files = _load(args, binary)
    inputs.update(_inputs.frame_paths(files, _LABEL))
    _check_destinations(out, names, inputs, force=args.force)
    n_t, h, w = cube.shape
    if det == "hoc":
        _check_order_fits(args, n_t, det_params["order"])
    messages: list[str] = []
    start = time.perf_counter()
    with _torch_threads(PIPELINE_THREADS), _reported_warnings(messages):
        if det == "hoc":
            scans, info = _hoc_input(cube, det_params)
            stream = _hoc_plots(scans, det_params, shape=(n_t, h, w))
        else:
            names = {"frame_names": [file.name for file in files]}  # said about flat frames
            stream, info = _dpa_plots(cube, {**det_params, **names})
        bar = _progress(stream, desc="track", total=n_t, enabled=_show_progress(args))
        uncounted: list[int] = []
        if det == "dpa":  # frames that cannot have plots: not in the default --lambda-fa
            from hocnet.cli.detect import first_plot_frame

            flat = (cube.amax(dim=(-2, -1)) == cube.amin(dim=(-2, -1))).tolist()
            first = first_plot_frame(det_params)
            uncounted = [t for t in range(n_t) if t < first or flat[t]]
        tracks, plots, params = _run_mht(bar, args, n_t, float(h * w), uncounted)
        notes: list[str] = list(info.get("notes", []))
        shifts = info["shifts"]
        if det == "dpa":
            det_params = info["meta"]
            if shifts is not None:
                weak = det_params.get("unregistered_pairs")
                notes.append(_shifts_summary(shifts, _SHIFTS_AT, weak))
    runtime = time.perf_counter() - start
    rows = _track_dicts(tracks, plots)
    meta = {
        "detector": det,
        "detector_params": det_params,
        "mht_params": params,
        "input": str(Path(args.seq).resolve()),
        "input_shape": [n_t, h, w],
        **({"key": args.key} if args.key is not None else {}),
        **({"input_frames": [file.name for file in files]} if files else {}),
        **({"shifts": [[float(v) for v in s] for s in shifts]} if shifts is not None else {}),
        "plots_per_frame": [int(p.shape[0]) for p in plots],
        **({"warnings": messages} if messages else {}),
        "status": _STATUS,
        "coordinates": "pixels, x = column, y = row; points are [frame, x, y, plot index]",
        "state": "[x, vx, y, vy] at the last frame of the track (px, px/frame)",
    }
    payload = {"meta": meta, "tracks": rows}
    text = json.dumps(payload, indent=1)
    writers: dict[str, Writer] = {"tracks.json": lambda path: path.write_text(text)}
    if not args.no_plot:
        title = f"{det.upper()} + MHT: {len(rows)} track{'s' * (len(rows) != 1)}"
        writers["tracks.png"] = _png_writer(_figure(cube, plots, rows, title))
    paths = _write_outputs(out, writers, inputs, force=args.force)
    n_plots = sum(meta["plots_per_frame"])
    deleted = sum(r["status"] == "deleted" for r in rows)
    ended = (
        ""
        if not deleted
        else " (deleted by the end)"
        if deleted == len(rows) == 1
        else f" ({deleted} of them deleted by the end)"
    )
    print(
        f"track: {det} + MHT on {n_t} x {h} x {w}: {n_plots} plots, {len(rows)} confirmed "
        f"track{'s' * (len(rows) != 1)}{ended} ({runtime:.2f} s)"
    )
    for note in notes:
        print(f"  {note}")
    if rows:
        table = [
            (
                r["id"],
                f"{r['first_frame']}-{r['last_frame']}",
                len(r["points"]),
                f"{r['score']:.1f}",
                r["status"],
                f"({r['state'][0]:.1f}, {r['state'][2]:.1f})",
                f"({r['state'][1]:+.2f}, {r['state'][3]:+.2f})",
            )
            for r in rows
        ]
        print(_table(("id", "frames", "plots", "score", "status", "x, y", "vx, vy"), table))
    print(f"wrote {len(paths)} files to {out}/: {', '.join(p.name for p in paths)}")
    return 0


_EPILOG = """\
input:
  SEQ is one sequence (T, H, W), read as by 'hocnet detect': a .npy file, an array of a .npz
  (--key), or image frames: a folder (every file in it must be a PNG / BMP / TIFF frame, all
  of one size), a glob pattern (quote it: 'clip/frame_*.png') or one (multi-page) image file,
  sorted by name in natural order, values not rescaled, colour converted to grey.

detectors (their options, defaults and messages are those of 'hocnet detect'):
  hoc  the modified HOC of [LA98], streaming over sliding windows (--window, --stride), on a
       BINARY cube (bool or 0/1 values), or on intensity frames with --threshold-pfa P
       (pre-processed, then binarised per frame by a CFAR threshold, as 'hocnet detect' does)
  dpa  the DPA of [NR08] with the pre-processing of 'hocnet detect --method dpa' (--preset),
       on INTENSITY frames; plots = local maxima of each frame's causal ASF

online (streaming; see the module hocnet.cli.track):
  frames are processed in order as they are read, and the tracker steps frame by frame as
  the plots of a frame become final:
    hoc  a window is identified when its last frame arrives; frame t's plots are final after
         frame s + window - 1 (s: the last window start <= t): at most window - 1 frames late
    dpa  pre-processing, ASF step and plots of frame t at frame t (no delay)
    pre-processing (dpa, hoc --threshold-pfa): causal, registration on frames n - 1 and n,
         background of frame n from its --background-window previous frames, whitening of n
    --lambda-fa (default): from the plots of the first --lambda-fa-frames frames only (not
         counting frames that cannot have plots: dpa frame 0 with background removal, flat
         frames), fixed after them; the tracker starts once they are known (at once with
         --lambda-fa)
  not online: SEQ is a file, read and checked whole before any work (its number of frames
  fixes the HOC's extra last window); --target-free is calibration data, processed whole
  first; warnings are said, and outputs written, at the end.
  The plots are those of the batch computation ('hocnet detect'), except that a registration
  shift can differ by 0.01 px (float32 FFT rounding of one pair vs the whole sequence).
  Progress: a bar on stderr (frames done) when it is a terminal, unless -q.

tracker:
  the track-oriented structured-branching MHT of [PD] (hocnet.tracking.mht.MHT): chi-square
  gating, LLR track score with Wald's SPRT (confirm at ln((1 - beta) / alpha), delete at
  ln(beta / (1 - alpha))), Murty k-best global hypotheses, N-scan pruning; the motion model
  is an IMM of two constant-velocity models (--sigma-a and 10 x --sigma-a) or one CV model.
  Every track listed was confirmed; its status says how it ended:
    confirmed  still held at the last frame
    deleted    ended before the last frame (score below the SPRT's deletion threshold, or
               pruned); its points up to then are kept
  Fewest frames: 2 * order + 1 for --detector hoc (5 for the default --order 2); for
  --detector dpa 3 with background removal (the default: frame 0 has no past frames, so no
  plots), 2 with --background none; the tracker confirms a track at its second plot at the
  earliest (at the fourth on a simulated 12 dB IR sequence with --preset paper, defaults).

outputs (in --out DIR, all or nothing; an input is never replaced, SEQ or any of its image
frames, --target-free; nor a file hocnet did not write unless --force; DIR may not be the
input folder of frames or inside it; nothing is written if the input or an option is invalid):
  tracks.json  {"meta": {...}, "tracks": [{"id", "status", "score", "first_frame",
               "last_frame", "state", "covariance", "points": [[frame, x, y, plot], ...]}]};
               meta.shifts: the registration shifts (dx, dy) per frame, with --register
  tracks.png   the maximum over frames, the plots and the tracks with their ids

examples:
  hocnet track scans.npy --detector hoc --out tracks
  hocnet track frames.npy --detector dpa --pd 0.8 --out tracks
  hocnet track clip_folder/ --detector dpa --out tracks
  hocnet track 'clip/*.png' --detector hoc --threshold-pfa 0.001 --out tracks
"""


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``track`` on the ``hocnet`` subcommand parser."""
    p = commands.add_parser(
        "track",
        help="detect and track: a detector's plots into the MHT of [PD] (confirmed tracks)",
        description="Run a detector over a sequence (a .npy/.npz cube or image frames) and\n"
        "feed its per-frame plots (pixel coordinates) to the track-oriented MHT of [PD]\n"
        "online, frame by frame (see 'online' below);\n"
        "print the confirmed tracks and write them as JSON and a picture.",
        epilog=_EPILOG,
        formatter_class=_Formatter,
    )
    _inputs.add_input_arguments(p, "seq", _LABEL, what="sequence (T, H, W)")
    p.add_argument(
        "--detector", choices=("hoc", "dpa"), default="hoc", help="detector (default: hoc)"
    )
    p.add_argument(
        "--out", default="track-output", metavar="DIR", help="output folder (default: track-output)"
    )
    p.add_argument("--no-plot", action="store_true", help="do not write tracks.png")
    p.add_argument(
        "--force", action="store_true", help="replace files in --out that hocnet did not write"
    )
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bar (shown on stderr only when it is a terminal, after 2 s)",
    )
    hoc = p.add_argument_group("hoc options (--detector hoc; as in 'hocnet detect')")
    _inputs.add_hoc_options(hoc, label=_LABEL, selector=_SELECTOR)
    hoc.add_argument(
        "--window",
        type=int,
        default=None,
        metavar="N",
        help="hoc: frames per window, >= 2 * order + 1 (default: 10, or 2 * order + 1 if "
        "larger); dpa: probability-matrix size in pixels, odd, at most the frame size, as "
        "--window of 'hocnet detect' (default: the --preset's)",
    )
    hoc.add_argument(
        "--stride",
        type=int,
        default=None,
        metavar="N",
        help="frames between windows, at most --window (default: 2)",
    )
    dpa = p.add_argument_group("dpa options (--detector dpa; as in 'hocnet detect')")
    _inputs.add_dpa_options(
        dpa,
        skip=_DPA_NOT_ADDED,
        helps={"asf_threshold": "keep the plots whose ASF is above S (default: no threshold)"},
    )
    from hocnet.cli.detect import _DIRECTION_STEP_HELP

    dpa.add_argument(
        "--direction-step", choices=("paper", "source"), default=None, help=_DIRECTION_STEP_HELP
    )
    dpa.add_argument(
        "--max-per-frame",
        type=int,
        default=None,
        metavar="N",
        help="most plots per frame (default: 5)",
    )
    _inputs.add_preprocess_options(
        p.add_argument_group(
            "pre-processing of intensity frames (--detector dpa, or --detector hoc with "
            "--threshold-pfa; in this order: registration, background removal, whitening)"
        ),
        selector=_SELECTOR,
        shifts_to=_SHIFTS_AT,
    )
    mht = p.add_argument_group("tracker options")
    mht.add_argument(
        "--filter", choices=("imm", "cv"), default="imm", help="motion model (default: imm)"
    )
    mht.add_argument(
        "--pd", type=float, default=0.9, metavar="P", help="detection probability (default: 0.9)"
    )
    mht.add_argument(
        "--meas-std",
        type=float,
        default=1.0,
        metavar="PX",
        help="plot position noise, px (default: 1)",
    )
    mht.add_argument(
        "--sigma-a",
        type=float,
        default=0.05,
        metavar="A",
        help="acceleration noise, px/frame^2 (default: 0.05)",
    )
    mht.add_argument(
        "--velocity-std",
        type=float,
        default=2.0,
        metavar="V",
        help="velocity std of a new track, px/frame (default: 2)",
    )
    mht.add_argument(
        "--lambda-fa",
        type=float,
        default=None,
        metavar="D",
        help="false-alarm density per pixel (default: mean plots per frame over the first "
        "--lambda-fa-frames frames that can have plots, at least 0.1, / frame area; fixed "
        "after them)",
    )
    mht.add_argument(
        "--lambda-fa-frames",
        type=int,
        default=None,
        metavar="K",
        help=f"frames whose plots give the default --lambda-fa (default: {LAMBDA_FA_FRAMES}; "
        "the tracker starts once their plots are known)",
    )
    mht.add_argument(
        "--lambda-nt",
        type=float,
        default=None,
        metavar="D",
        help="new-target density per pixel (default: lambda-fa / 10)",
    )
    mht.add_argument(
        "--n-hypotheses",
        type=int,
        default=10,
        metavar="N",
        help="hypotheses per cluster (default: 10)",
    )
    mht.add_argument(
        "--n-scan", type=int, default=3, metavar="N", help="N-scan pruning depth (default: 3)"
    )
    mht.add_argument(
        "--alpha",
        type=float,
        default=1e-3,
        metavar="A",
        help="SPRT false-confirmation probability (default: 1e-3)",
    )
    mht.add_argument(
        "--beta",
        type=float,
        default=0.1,
        metavar="B",
        help="SPRT true-deletion probability (default: 0.1)",
    )
    p.set_defaults(func=_cmd_track)

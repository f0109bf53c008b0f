"""``hocnet detect``: run the HOC [LA98] or the DPA [NR08] on a user's data."""

from __future__ import annotations

import argparse
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch
from hocnet.cli._common import (
    _FLAGS,
    PIPELINE_THREADS,
    CLIError,
    Writer,
    _check_destinations,
    _check_int,
    _check_out_dir,
    _Formatter,
    _one_line,
    _png_writer,
    _Problems,
    _progress,
    _reported_warnings,
    _show_progress,
    _Stages,
    _to_flags,
    _torch_threads,
    _write_outputs,
)
from hocnet.cli._inputs import (
    DPA_DESTS,
    HOC_DESTS,
    add_dpa_options,
    add_hoc_options,
    add_input_arguments,
    add_preprocess_options,
    check_target_free,
    frame_paths,
    input_paths,
    load_input,
    out_inside_input,
    prepare_dpa,
    prepare_hoc,
)

# detection methods
# --------------------------------------------------------------------------------------------


@dataclass
class Detection:
    """What a detection method returns to the command line.

    Attributes:
        result: the method's own result (plotted with :func:`hocnet.plot.plot_before_after`);
            it must have ``.support``, ``.cleaned`` (bool cubes shaped like the input) and
            ``.tracks`` (objects with ``.points`` ``(N, 3)`` of ``(t, y, x)``, ``.id``, ``.score``
            and ``.batch``).
        params: the method's parameters as JSON-friendly values (stored in ``tracks.json``).
        outputs: files to write besides ``tracks.json`` (name -> writer); ``None`` writes the
            HOC outputs ``cleaned.npy``, ``support.npy`` and ``detection.png``.
        summary: the line printed after a run; ``None`` prints the HOC point counts.
        extra_outputs: files written besides the HOC outputs when ``outputs`` is ``None``
            (``detections.csv``, ``binary.npy``, ``shifts.csv``).
        cube: the binary cube the HOC ran on when it differs from the input (intensity frames
            binarised by ``--threshold-pfa``); ``None``: the input.
        notes: lines printed after the summary.
    """

    result: Any
    params: dict[str, Any] = field(default_factory=dict)
    outputs: dict[str, Writer] | None = None
    summary: str | None = None
    extra_outputs: dict[str, Writer] = field(default_factory=dict)
    cube: Any = None
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class _Method:
    """A detector the command line can run.

    ``output_names`` are the files every run writes (batched or not); ``scene_outputs``: it
    also writes ``detections.csv`` and ``detection.png`` (``detections_000.csv``,
    ``detection_000.png``, ... for a batch). Both are checked before any work
    (:func:`_planned_names`).
    """

    name: str
    help: str
    add_options: Callable[[argparse._ArgumentGroup], None]
    option_dests: tuple[str, ...]
    prepare: Callable[[argparse.Namespace], dict[str, Any]]
    run: Callable[[torch.Tensor, dict[str, Any]], Detection]
    binary: bool = True
    output_names: tuple[str, ...] = ("tracks.json",)
    scene_outputs: bool = False


#: Batches at least this large are detected scene by scene under a progress bar.
_PROGRESS_BATCH = 8


#: Largest (M, M) move table (M = (2v + 1)**2 moves, float64) the command line lets HOC build.
_MAX_MOVE_TABLE_BYTES = 2**31


def _bound_hoc(cube: torch.Tensor, params: dict[str, Any]) -> None:
    """Refuse at once what cannot work (an order or a velocity window too large for the cube).

    An order k needs 2k + 1 scans; a move larger than the frame leaves it; and the (M, M) move
    tables of a huge v (M = (2v + 1)**2 moves) would not fit in memory.
    """
    n_t, height, width = cube.shape[-3:]
    order, v = params["order"], params["v"]
    if n_t < 3:  # no order fits: name the input, and the minimum
        raise CLIError(
            "CUBE: expected at least 3 scans for the HOC (order k needs "
            f"2k + 1 scans: 3 for --order 1, {2 * order + 1} for --order {order}), got {n_t}"
        )
    problems = _Problems()  # a bad --order and a bad --v: said together
    if 2 * order + 1 > n_t:
        problems.messages.append(
            f"--order: expected at most (T - 1) // 2 = {(n_t - 1) // 2} for a cube of T = {n_t} "
            f"scans (order k needs 2k + 1 scans), got {order}"
        )
    largest = max(height, width) - 1
    moves = (2 * v + 1) ** 2
    if v > largest:
        problems.messages.append(
            f"--v: expected at most max(H, W) - 1 = {largest} for frames of {height} x {width} "
            f"(a larger move leaves the frame), got {v}"
        )
    elif 8 * moves * moves > _MAX_MOVE_TABLE_BYTES:
        limit = int(((_MAX_MOVE_TABLE_BYTES / 8) ** 0.25 - 1) // 2)
        problems.messages.append(
            f"--v: expected at most {limit} (the (2v + 1)^4 move tables of v = {v} would need "
            f"{8 * moves * moves / 2**30:.0f} GiB), got {v}"
        )
    problems.raise_all()


def binarize_frames(
    frames: torch.Tensor, params: dict[str, Any]
) -> tuple[torch.Tensor, torch.Tensor | None, str]:
    """Intensity frames into the binary cube of the HOC (``--threshold-pfa``).

    Pre-processing (:func:`_preprocess`: registration, causal background removal, whitening),
    then per frame the ``floor(pfa H W)`` highest whitened pixels
    (:func:`hocnet.data.binarize.cfar_binarize`, our addition).

    Args:
        frames: ``(T, H, W)`` or ``(B, T, H, W)`` intensities.
        params: ``threshold_pfa`` and the pre-processing parameters of :func:`prepare_hoc`.

    Returns:
        ``(binary, shifts, note)``: the bool cube shaped like ``frames``, the registration
        shifts (``None`` without registration) and a one-line summary.
    """
    from hocnet.data.binarize import cfar_binarize

    pfa = params["threshold_pfa"]
    _check_float32_range(frames, "`frames`")
    white, shifts = _preprocess(frames, params)
    binary = cfar_binarize(white, pfa)
    height, width = binary.shape[-2:]
    note = _binarised_note(pfa, height, width, int(binary.sum()))
    return binary, shifts, note


def _binarised_note(pfa: float, height: int, width: int, points: int, stacklevel: int = 2) -> str:
    """The note of ``--threshold-pfa`` on ``points`` kept in frames of ``height x width``.

    Shared by :func:`binarize_frames` (the whole cube) and ``hocnet track`` (frame by frame).
    Warns (:class:`RuntimeWarning`, said by the commands as ``hocnet: warning: ...``) when
    ``pfa H W < 1`` (every frame keeps 0 points) or when no point is kept at all.
    ``stacklevel``: the one the caller would give :func:`warnings.warn` itself (2: the
    warnings point at the caller's caller).

    Returns:
        The one-line summary ``binarised: N points (CFAR, pfa P per pixel, at most K per frame)``.

    Examples:
        >>> _binarised_note(0.01, 20, 20, 7)
        'binarised: 7 points (CFAR, pfa 0.01 per pixel, at most 4 per frame)'
    """
    per_frame = math.floor(pfa * height * width)
    if per_frame < 1:
        warnings.warn(
            f"--threshold-pfa: {pfa:g} x {height} x {width} pixels = {pfa * height * width:.3g} "
            "expected false points per frame (< 1): every frame keeps 0 points and the HOC gets "
            f"an empty cube; give at least 1 / (H W) = {1 / (height * width):.3g}",
            RuntimeWarning,
            stacklevel=stacklevel + 1,
        )
    elif points == 0:
        warnings.warn(
            f"--threshold-pfa: no point is left after the binarisation at pfa {pfa:g} (every "
            "frame is flat after the pre-processing); the HOC gets an empty cube",
            RuntimeWarning,
            stacklevel=stacklevel + 1,
        )
    return (
        f"binarised: {points} points (CFAR, pfa {pfa:g} per pixel, at most {per_frame} per frame)"
    )


def hoc_kwargs(params: dict[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :func:`hocnet.hoc.detect` from the HOC options (delta in radians).

    Examples:
        >>> p = {"order": 2, "v": 4, "delta": 180.0, "threshold": 2.5, "min_points": 5}
        >>> round(hoc_kwargs(p)["delta"], 4)
        3.1416
    """
    return {
        "order": params["order"],
        "v": params["v"],
        "delta": math.radians(params["delta"]),
        "threshold": params["threshold"],
        "min_points": params["min_points"],
        "support": params.get("support", "mhoc"),
    }


def _support_name(params: dict[str, Any]) -> str:
    """What ``support.npy`` holds, as the summary names it.

    Examples:
        >>> _support_name({"support": "mhoc"}), _support_name({"support": "chain"})
        ('MHOC image', 'chain support')
    """
    if params.get("weights") is not None:
        return "learned support"
    return {"chain": "chain support"}.get(params.get("support", "mhoc"), "MHOC image")


def _run_hoc(cube: torch.Tensor, params: dict[str, Any]) -> Detection:
    """Run :func:`hocnet.hoc.detect`; a large batch goes scene by scene with a progress bar.

    Scene by scene gives the same result as one batched call (the HOC network and the track
    identification treat batch elements independently): ids are renumbered over the batch and
    each track's ``batch`` is set, as :func:`~hocnet.hoc.detect` does.
    """
    import torch

    from hocnet.hoc import HOCResult, detect

    pfa = params.get("threshold_pfa")
    outputs: dict[str, Writer] = {}
    notes: list[str] = []
    _bound_hoc(cube, params)  # before the pre-processing: --order and --v fit the input's shape
    if pfa is not None:
        from hocnet.data.io import save_cube

        cube, shifts, binarised = binarize_frames(cube, params)
        binary = cube
        outputs["binary.npy"] = lambda path: save_cube(path, binary)
        if shifts is not None:
            outputs["shifts.csv"] = _shifts_writer(shifts)
            notes.append(_shifts_summary(shifts, unregistered=params.get("unregistered_pairs")))
        notes.append(binarised)
    model = params.pop("model", None)
    kwargs = hoc_kwargs(params)
    if model is not None:  # --weights: the support of the learned network
        from hocnet.learn.apply import detect_hoc

        def detect(frames: Any, **kw: Any) -> Any:
            return detect_hoc(frames, model, threshold=kw["threshold"], min_points=kw["min_points"])

    detection_params = {**params, "delta_unit": "degrees"}
    detection_params.pop("binary", None)

    def finish(result: Any) -> Detection:
        if params["min_speed"] > 0:
            from hocnet.hoc import reject_slow_tracks

            result = reject_slow_tracks(result, params["min_speed"])
        scores = getattr(result, "scores", None)
        if scores is None:  # no per-point scores: 1.0 per kept point
            scores = result.cleaned.double()
            detection_params["detection_score"] = "1.0 per point on a kept track"
        else:
            detection_params["detection_score"] = "HOC point score of the support points"
        detection_params["detections_nms_radius"] = DETECTION_NMS_RADIUS
        # with --min-speed only the points of the moving tracks are candidate detections
        keep = result.cleaned if params["min_speed"] > 0 else result.support
        outputs.update(_detection_writers(scores, params["max_per_frame"], keep=keep))
        return Detection(
            result=result, params=detection_params, extra_outputs=outputs, cube=cube, notes=notes
        )

    if cube.dim() == 3 or cube.shape[0] < _PROGRESS_BATCH:
        return finish(detect(cube, **kwargs))
    parts = []
    scenes = range(cube.shape[0])
    for b in _progress(
        scenes, desc="hoc", total=len(scenes), enabled=params.get("progress", False)
    ):
        part = detect(cube[b], **kwargs)
        for track in part.tracks:
            track.batch = b
        parts.append(part)
    tracks = [track for part in parts for track in part.tracks]
    for i, track in enumerate(tracks, start=1):
        track.id = i
    result = HOCResult(
        support=torch.stack([p.support for p in parts]),
        tracks=tracks,
        scores=torch.stack([p.scores for p in parts]),
        cleaned=torch.stack([p.cleaned for p in parts]),
    )
    return finish(result)


#: NMS radius (pixels) of the per-frame candidate detections of ``detections.csv``.
DETECTION_NMS_RADIUS = 2

#: Fewest frames the command line runs the DPA on (``hocnet detect``, ``hocnet track``).
MIN_DPA_FRAMES = 2


def first_plot_frame(params: dict[str, Any]) -> int:
    """The first frame that can have DPA plots with these pre-processing options.

    With background removal (``--background`` not ``none``) frame 0 has no past frames: it is
    all zero after the removal, its ASF is constant and it has no plot (nor CFAR sample), so
    the first is frame 1; without, frame 0.

    Examples:
        >>> first_plot_frame({"background": "median"}), first_plot_frame({"background": "none"})
        (1, 0)
    """
    return int(params.get("background", "none") != "none")


def _check_float32_range(cube: torch.Tensor, label: str) -> None:
    """Refuse finite values that would become infinite in float32, in which the DPA computes."""
    import torch

    if cube.is_floating_point() and cube.dtype != torch.float32 and cube.numel():
        largest = float(cube.abs().max())
        limit = float(torch.finfo(torch.float32).max)
        if largest > limit:
            raise CLIError(
                f"{label}: values too large for float32, in which the DPA computes (largest "
                f"|value| {largest:.3g}, float32 holds up to {limit:.3g}); rescale the frames"
            )


def _preprocess(
    frames: torch.Tensor, params: dict[str, Any], label: str = "`frames`"
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Registration, causal background removal and whitening of intensity frames.

    Args:
        frames: ``(T, H, W)`` or ``(B, T, H, W)`` intensities.
        params: ``register``, ``background``, ``background_window``, ``whiten``.
        label: the input's name in error messages.

    Returns:
        ``(white, shifts)``: float32 frames shaped like the input, and the shifts ``(.., T, 2)``
        ``(dx, dy)`` of each frame relative to the previous one (``None`` without registration).
        Every step is causal: frame ``n`` of the output depends on frames ``0..n`` only.
    """
    import torch

    from hocnet.data.background import estimate_shifts, remove_background
    from hocnet.data.whitening import anti_mean, anti_median

    x = frames.float()
    height, width = x.shape[-2:]
    shifts = offsets = None

    def overflow(step: str) -> CLIError:
        return CLIError(
            f"{label}: values too large for float32 in the {step} (largest |value| "
            f"{float(frames.abs().max()):.3g}); rescale the frames"
        )

    try:
        if params["register"]:
            # pairs without a significant correlation peak keep (0, 0) (noise, flat or very
            # smooth frames); counted, and said with the shifts
            shifts, rejected = estimate_shifts(x, return_rejected=True)
            if not bool(torch.isfinite(shifts).all()):
                raise overflow("registration (--register)")
            if label == "`frames`":  # the input's, not --target-free's
                params["unregistered_pairs"] = int(rejected.sum())
            offsets = shifts.cumsum(dim=-2)
        if params["background"] != "none":
            x = remove_background(
                x, params["background"], params["background_window"], offsets=offsets
            )
            if not bool(torch.isfinite(x).all()):
                raise overflow("background removal (--background)")
    except ValueError as err:
        raise ValueError(str(err).replace("`frames`", label)) from None
    whiten = {"mean": anti_mean, "median": anti_median}.get(params["whiten"])
    if whiten is not None:
        outer = min(7, *(n if n % 2 else n - 1 for n in (height, width)))
        if outer < 3:
            raise CLIError(f"--whiten: frames of {height} x {width} are too small for a ring")
        inner = 3 if outer >= 5 else 1
        try:
            x = whiten(x, outer, inner)
        except ValueError as err:  # name the right input
            raise ValueError(str(err).replace("`frames`", label)) from None
    return x, shifts


def _shifts_writer(shifts: torch.Tensor) -> Writer:
    """``shifts.csv``: ``[batch,]frame,dx,dy,offset_x,offset_y`` in pixels (x column, y row)."""
    import csv

    batched = shifts.dim() == 3
    cube = shifts if batched else shifts.unsqueeze(0)
    offsets = cube.cumsum(dim=-2)
    header = ["batch"] * batched + ["frame", "dx", "dy", "offset_x", "offset_y"]
    rows = [
        [b] * batched + [t, *(f"{float(v):.4f}" for v in (*cube[b, t], *offsets[b, t]))]
        for b in range(cube.shape[0])
        for t in range(cube.shape[1])
    ]

    def write(path: Path) -> None:
        with open(path, "w", newline="") as handle:
            writer = csv.writer(handle, lineterminator="\n")
            writer.writerow(header)
            writer.writerows(rows)

    return write


def _shifts_summary(
    shifts: torch.Tensor, where: str = "shifts.csv", unregistered: int | None = None
) -> str:
    """One line about the estimated camera motion; ``where``: the output that lists the shifts.

    ``unregistered``: the frame pairs left at shift 0 without a significant phase-correlation
    peak (the rejected pairs of :func:`hocnet.data.background.estimate_shifts`), said when
    there are any. Such a pair need not lack structure: phase correlation whitens the
    spectrum, so a very smooth texture (e.g. blurred with sigma 3 px) gives a peak below the
    test's threshold too; the wording says so.

    Examples:
        >>> import torch
        >>> _shifts_summary(torch.zeros(4, 2), unregistered=3)  # doctest: +ELLIPSIS
        'registration: no reliable registration peak in 3 of 3 frame pairs (noise, flat or ...'
    """
    from hocnet.data.background import REGISTRATION_PFA

    step = shifts.norm(dim=-1)
    drift = shifts.sum(dim=-2).reshape(-1, 2)
    far = int(drift.norm(dim=-1).argmax()) if drift.numel() else 0
    dx, dy = (float(v) for v in drift[far]) if drift.numel() else (0.0, 0.0)
    pairs = drift.shape[0] * max(shifts.shape[-2] - 1, 0)
    if unregistered and unregistered == pairs:  # nothing was registered: no motion measured
        return (
            f"registration: no reliable registration peak in {unregistered} of {pairs} frame "
            f"pairs (noise, flat or very smooth frames; shifts kept at 0; phase-correlation "
            f"peak test at pfa {REGISTRATION_PFA:g}); see {where}"
        )
    weak = (
        f"; no reliable registration peak in {unregistered} of {pairs} frame pairs (noise, "
        "flat or very smooth frames; shifts kept at 0)"
        if unregistered
        else ""
    )
    return (
        f"registration: mean shift {float(step.mean()) if step.numel() else 0.0:.2f} px/frame, "
        f"largest {float(step.max()) if step.numel() else 0.0:.2f} px, total drift "
        f"({dx:+.1f}, {dy:+.1f}) px (x, y){weak}; see {where}"
    )


def _detection_writers(
    scores: torch.Tensor, max_per_frame: int, keep: torch.Tensor | None = None
) -> dict[str, Writer]:
    """``detections.csv`` (``detections_000.csv``, ... for a batch) from a score cube.

    Candidates are the local maxima of each frame's scores (NMS radius
    :data:`DETECTION_NMS_RADIUS`), at most ``max_per_frame`` per frame, highest first. With
    ``keep`` (a bool cube), only pixels where it is true can be detections (NaN scores elsewhere
    are allowed). A frame whose scores are all equal (such as frame 0 after background
    removal) has no detection.
    """
    import torch

    from hocnet.detection_metrics import detect_peaks, write_detections

    s = scores.double()
    if keep is not None:
        keep = keep & torch.isfinite(s)
    found = detect_peaks(s, radius=DETECTION_NMS_RADIUS, max_per_frame=max_per_frame, mask=keep)
    batched = isinstance(found, list)
    parts = found if batched else [found]
    flat = s.reshape(*s.shape[:-2], -1)
    constant = flat.amax(dim=-1) == flat.amin(dim=-1)  # no pixel stands out: no detection
    constant = constant if batched else constant.unsqueeze(0)
    writers: dict[str, Writer] = {}
    for i, det in enumerate(parts):
        if det.numel() and keep is None:
            det = det[~constant[i][det[:, 0].long()]]
        name = f"detections_{i:03d}.csv" if batched else "detections.csv"
        writers[name] = lambda path, det=det: write_detections(path, det, overwrite=True)
    return writers


def _check_flat_frames(
    cube: torch.Tensor, label: str, frame_names: list[str] | None = None
) -> None:
    """Refuse input whose every frame is flat; warn about the flat frames of other input.

    A flat frame (one constant value, zero variance) holds no evidence: the whitening maps it
    to 0 and the DPA's scores on it are rounding noise, so tracks on flat frames only are
    meaningless.

    Args:
        cube: ``(T, H, W)`` or ``(B, T, H, W)`` intensities.
        label: the input's name in messages (``CUBE``, ``SEQ``).
        frame_names: the image file of each frame (named in the messages), if any.

    Raises:
        CLIError: every frame is flat (exit code 2).

    Examples:
        >>> import torch
        >>> _check_flat_frames(torch.rand(3, 4, 4), "CUBE")
        >>> _check_flat_frames(torch.ones(3, 4, 4), "CUBE")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        hocnet.cli._common.CLIError: CUBE: all 3 frames are flat ...
    """
    if cube.numel() == 0:
        return
    flat = cube.amax(dim=(-2, -1)) == cube.amin(dim=(-2, -1))  # (..., T)
    n_flat, n_frames = int(flat.sum()), flat.numel()
    if n_flat == 0:
        return
    where = flat.reshape(-1, flat.shape[-1]).nonzero().tolist()
    batched = cube.dim() == 4

    def name(b: int, t: int) -> str:
        text = f"{b}:{t}" if batched else str(t)
        return f"{text} '{frame_names[t]}'" if frame_names and not batched else text

    shown = ", ".join(name(b, t) for b, t in where[:6]) + (", ..." if n_flat > 6 else "")
    which = "frames (batch:frame)" if batched else "frames"
    if n_flat == n_frames:
        first = float(cube.reshape(-1)[0])
        value = (
            f"the constant value {first:g}"
            if bool((cube == first).all())
            else "one constant value per frame"
        )
        files = ""
        if frame_names:
            files = f" ('{frame_names[0]}'" + (
                f" ... '{frame_names[-1]}')" if len(frame_names) > 1 else ")"
            )
        raise CLIError(
            f"{label}: all {n_frames} frames are flat{files} ({value}, zero variance): "
            "nothing can be detected; the DPA needs intensity frames whose values vary"
        )
    warnings.warn(
        f"{label}: {n_flat} of {n_frames} frames are flat (one constant value, zero variance), "
        f"{which} {shown} (0-based): they hold no evidence (0 after the whitening), the DPA "
        "only carries the earlier frames' scores through them",
        RuntimeWarning,
        stacklevel=2,
    )


def dpa_setup(
    cube: torch.Tensor,
    params: dict[str, Any],
    label: str,
    frame_names: list[str] | None = None,
    *,
    weights: torch.Tensor | None = None,
    cfar: bool = False,
) -> dict[str, Any]:
    """The DPA set-up of ``hocnet detect`` (whole batch) and ``hocnet track`` (frame by frame).

    The command's own checks of the frame count and size come first; then, in this order:
    no flat frame (:func:`_check_flat_frames`) and values within float32 in ``cube`` and in
    ``--target-free`` (whose frames must be ``H x W`` too); the probability matrices of
    [NR08] (:func:`hocnet.dpa.probability_matrices` of ``window``, ``v_max``, ``jitter``,
    ``p``, ``penalty_step``, or the learned ``weights`` of ``--weights``), their gain
    equalised with ``--equal-gain`` (:func:`hocnet.dpa.equalize_gain`); ``b``, from ``--b``
    or :func:`hocnet.dpa.effective_memory` (``--memory``); the target-free frames
    pre-processed like the input (:func:`_preprocess`).

    Args:
        cube: the input, ``(T, H, W)`` or ``(B, T, H, W)`` intensities.
        params: the DPA options (:func:`prepare_dpa`) and the pre-processing options.
        label: the input's name in messages (``CUBE``, ``SEQ``).
        frame_names: the image files of the frames, if any (named by the flat-frame check).
        weights: learned ``(D, k, k)`` matrices replacing the built ones, or ``None``.
        cfar: with ``--target-free``, compute the CFAR threshold here
            (:func:`hocnet.dpa.backtrack.cfar_threshold` at ``pfa``, ``nms_radius``); without,
            :func:`hocnet.dpa.backtrack.detect` computes it from ``target_free``.

    Returns:
        ``{"weights", "b", "target_free", "threshold"}``: the ``(D, k, k)`` float matrices, the
        memory factor, the pre-processed target-free frames (``None`` without
        ``--target-free``) and the ASF threshold: the CFAR one with ``cfar`` and
        ``--target-free``, else ``--asf-threshold`` (``None``: no threshold).

    Raises:
        CLIError: all frames flat, values beyond float32, ``--target-free`` frames of another
            size (:func:`check_target_free`), or a pre-processing overflow (one line each).

    Examples:
        >>> import torch
        >>> from hocnet.cli import build_parser
        >>> params = _prepare_dpa(build_parser().parse_args(["detect", "x.npy", "--method", "dpa"]))
        >>> setup = dpa_setup(torch.rand(4, 16, 16), params, "CUBE")
        >>> tuple(setup["weights"].shape), round(setup["b"], 4), setup["threshold"]
        ((9, 5, 5), 3.1967, None)
    """
    from hocnet.dpa import effective_memory, equalize_gain, probability_matrices
    from hocnet.dpa.backtrack import cfar_threshold

    _check_flat_frames(cube, label, frame_names)
    _check_float32_range(cube, "`frames`")
    target_free = params["target_free"]
    if target_free is not None:
        check_target_free(target_free, tuple(cube.shape[-2:]), label)
        _check_float32_range(target_free, "`target_free`")
        # the CFAR samples are the last-frame ASF of each target-free sequence: that frame
        # must be one that can have plots, i.e. after frame 0 with background removal (frame
        # 0 has no past frames: all zero, a threshold of 0)
        need = 1 + first_plot_frame(params)
        got = int(target_free.shape[-3])
        if got < need:
            raise CLIError(
                f"--target-free: expected at least {need} frames for these options "
                f"(--background {params['background']}: frame 0 has no past frames, its "
                f"scores are all 0 and give no CFAR sample), got {got}"
                if need > 1
                else f"--target-free: expected at least {need} frames, got {got}"
            )
    if weights is None:
        weights = probability_matrices(
            window=params["window"],
            v_max=params["v_max"],
            jitter=params["jitter"],
            p=params["p"],
            penalty_step=params["penalty_step"],
        )
    if params["equal_gain"]:
        weights = equalize_gain(weights, params["g"])
    b = params["b"]
    if b is None:
        b = float(
            effective_memory(
                weights, params["g"], params["memory"], direction=params["memory_direction"]
            )
        )
    threshold = params["asf_threshold"]
    if target_free is not None:
        target_free, _ = _preprocess(target_free, params, "`target_free`")
        if cfar:
            threshold = cfar_threshold(
                target_free,
                weights,
                b,
                params["g"],
                pfa=params["pfa"],
                nms_radius=params["nms_radius"],
                direction_step=params["direction_step"],
            )
    return {"weights": weights, "b": b, "target_free": target_free, "threshold": threshold}


def _run_dpa(cube: torch.Tensor, params: dict[str, Any]) -> Detection:
    """Pre-process, accumulate (eq. 11 of [NR08]), pick the last-frame peaks, back-track them.

    Also writes the causal per-frame candidate detections of the ASF (``detections.csv``): the
    ASF of frame ``n`` is built from frames ``0..n`` only, and so is every pre-processing step.
    """
    import torch

    from hocnet.data.io import save_cube
    from hocnet.dpa.backtrack import detect
    from hocnet.plot import plot_dpa

    label = params.pop("label", "CUBE")  # the input's name in messages (track: SEQ)
    frame_names = params.pop("frame_names", None)  # the image files of the frames, if any
    n_t = cube.shape[-3]
    if n_t < MIN_DPA_FRAMES:
        raise CLIError(
            f"{label}: expected at least {MIN_DPA_FRAMES} frames for the DPA (it accumulates "
            f"evidence over frames; one frame is a single-frame detector), got {n_t}"
        )
    height, width = cube.shape[-2:]
    window = params["window"]
    if window > min(height, width):
        raise CLIError(
            f"--window: expected at most the frame size min(H, W) = {min(height, width)}, "
            f"got {window}"
        )
    model = params.pop("model", None)
    weights = None
    if model is not None:  # --weights: the learned matrices, b and g
        with torch.no_grad():
            weights = model.weights.detach().float()
            params.update(g=float(model.g), b=float(model.b), equal_gain=False)
        params.update(window=weights.shape[-1], direction_step=model.direction_step)
        params.pop("v_max", None)
        params.pop("p", None)
        params.pop("penalty_step", None)
    setup = dpa_setup(cube, params, label, frame_names, weights=weights)
    frames = cube.float()
    white, shifts = _preprocess(frames, params)
    weights, b, target_free = setup["weights"], setup["b"], setup["target_free"]
    found = detect(
        white,
        weights,
        b,
        params["g"],
        max_targets=params["max_targets"],
        nms_radius=params["nms_radius"],
        threshold=params["asf_threshold"],
        target_free=target_free,
        pfa=params["pfa"],
        direction_step=params["direction_step"],
        var_table=None if model is None else model.var_table,
    )
    asf = found.state.asf
    batched = frames.dim() == 4
    n_t = frames.shape[-3]
    tracks, support = found.tracks, torch.zeros(frames.shape, dtype=torch.bool)
    t = torch.arange(n_t)
    for tr in tracks:
        (support[tr.batch] if batched else support)[t, tr.points[:, 1], tr.points[:, 2]] = True
    result = argparse.Namespace(
        support=support, cleaned=support, tracks=tracks, state=found.state, shifts=shifts
    )
    outputs: dict[str, Writer] = {"asf.npy": lambda path: save_cube(path, asf)}
    outputs.update(_detection_writers(asf, params["max_per_frame"]))
    if shifts is not None:
        outputs["shifts.csv"] = _shifts_writer(shifts)
    scenes = range(frames.shape[0]) if batched else [None]
    for i in scenes:
        one = found.tracks if i is None else [tr for tr in found.tracks if tr.batch == i]
        fig = plot_dpa(
            white if i is None else white[i],
            asf if i is None else asf[i],
            [tr.positions for tr in one],
            scores=[tr.score for tr in one],
            title="DPA detection" + ("" if i is None else f" (batch element {i})"),
        )
        outputs["detection.png" if i is None else f"detection_{i:03d}.png"] = _png_writer(fig)
    params = {k: v for k, v in params.items() if k != "target_free"}
    params.update(
        b=b,
        threshold_used=found.threshold,
        cfar=target_free is not None,
        confirmed=found.confirmed,
        note=found.note,
        detections_nms_radius=DETECTION_NMS_RADIUS,
    )
    summary = (
        f"dpa: {len(tracks)} track{'s' * (len(tracks) != 1)} in "
        f"{' x '.join(map(str, frames.shape))} frames (preset {params['preset']}, g = "
        f"{params['g']:g}, b = {b:.4g}, threshold = "
        f"{_threshold_text(found.threshold, params['pfa'] if target_free is not None else None)})"
    )
    if not found.confirmed:
        summary += "\n  note: " + _to_flags(found.note, _FLAGS["dpa"])
    if shifts is not None:
        summary += "\n  " + _shifts_summary(shifts, unregistered=params.get("unregistered_pairs"))
    return Detection(result=result, params=params, outputs=outputs, summary=summary)


def _threshold_text(threshold: float | None, pfa: float | None) -> str:
    """The DPA's ASF threshold as printed: 4 significant digits, its units and its origin.

    ``pfa``: the CFAR's false-alarm probability when the threshold comes from ``--target-free``
    (``None``: the fixed ``--asf-threshold``). The ASF accumulates whitened frames, so it is in
    the input's intensity units (grey levels for 8- or 16-bit frames); ``tracks.json`` keeps the
    exact value (``meta.threshold_used``).

    Examples:
        >>> _threshold_text(3.1415926535, None)
        '3.142 (ASF, input intensity units; --asf-threshold)'
        >>> _threshold_text(60.904544830322266, 0.01)
        '60.9 (ASF, input intensity units; CFAR at --pfa 0.01 on --target-free)'
        >>> _threshold_text(None, None)
        'none'
    """
    if threshold is None:
        return "none"
    origin = "--asf-threshold" if pfa is None else f"CFAR at --pfa {pfa:g} on --target-free"
    return f"{threshold:.4g} (ASF, input intensity units; {origin})"


#: ``--direction-step``: the direction step of ``hocnet.dpa.accumulate`` (``hocnet detect`` only).
_DIRECTION_STEP_HELP = (
    "direction step of the DPA (hocnet.dpa.accumulate): 'paper' = eq. (7)-(8) of [NR08] (the "
    "current pixel's direction first, from W_basic), 'source' = each source pixel's own previous "
    "direction picks its matrix (our earlier reading) (default: paper in both presets). For "
    "targets faster than about 0.5 px/frame use --g 1 --direction-step source (see 'target "
    "speed' below)"
)


def _add_dpa_options(group: argparse._ArgumentGroup) -> None:
    """The DPA options of :func:`add_dpa_options` plus ``--direction-step``."""
    add_dpa_options(group)
    group.add_argument(
        "--direction-step", choices=("paper", "source"), default=None, help=_DIRECTION_STEP_HELP
    )


def _prepare_dpa(args: argparse.Namespace) -> dict[str, Any]:
    """:func:`prepare_dpa`, with ``--direction-step`` replacing the preset's direction step."""
    params = prepare_dpa(args)
    if getattr(args, "direction_step", None) is not None:
        params["direction_step"] = args.direction_step
    return params


_METHODS: dict[str, _Method] = {
    "hoc": _Method(
        name="hoc",
        help="modified high-order correlation of [LA98] (binary cubes)",
        add_options=add_hoc_options,
        option_dests=HOC_DESTS,
        prepare=prepare_hoc,
        run=_run_hoc,
        output_names=("tracks.json", "cleaned.npy", "support.npy"),
        scene_outputs=True,
    ),
    "dpa": _Method(
        name="dpa",
        help="dynamic-programming track-before-detect of [NR08] (float frames)",
        add_options=_add_dpa_options,
        option_dests=(*DPA_DESTS, "direction_step"),
        prepare=_prepare_dpa,
        run=_run_dpa,
        binary=False,
        output_names=("tracks.json", "asf.npy"),
        scene_outputs=True,
    ),
}


#: Options that --weights replaces with the checkpoint's learned values.
_WEIGHTS_REPLACE = {
    "dpa": ("g", "b", "window", "v_max", "equal_gain", "direction_step"),
    "hoc": ("order", "v", "delta", "support"),
}


def _load_weights(args: argparse.Namespace, method: str, params: dict[str, Any]) -> None:
    """``--weights CKPT``: the learned module in ``params["model"]`` (one-line errors)."""
    if args.weights is None:
        return
    for dest in _WEIGHTS_REPLACE[method]:
        if getattr(args, dest, None) is not None:
            flag = "--" + dest.replace("_", "-")
            raise CLIError(f"{flag}: set by the checkpoint of --weights, drop one of the two")
    import importlib.util

    if importlib.util.find_spec("lightning") is None:
        raise CLIError("--weights: needs the learn extra: pip install -e '.[learn]'")
    from hocnet.learn.apply import hoc_settings, load_detector

    try:
        model = load_detector(args.weights, method)
    except OSError as err:
        raise CLIError(f"--weights: cannot read '{args.weights}': {err.strerror or err}") from None
    except ValueError as err:
        raise CLIError(_one_line(str(err).replace("`ckpt_path`", "--weights"))) from None
    params["model"] = model
    params["weights"] = str(Path(args.weights).resolve())
    if method == "dpa":
        params["window"] = int(model.weights.shape[-1])
    if method == "hoc":
        params["support"] = "learned"  # the learned network's own support
        hp = hoc_settings(model)
        delta = 180.0 if hp["delta"] is None else math.degrees(hp["delta"])
        params.update(order=hp["order"], v=hp["v"], delta=delta)
        if args.min_points is None:
            params["min_points"] = 2 * hp["order"] + 1


def _prepare_method(args: argparse.Namespace) -> tuple[_Method, dict[str, Any]]:
    method = _METHODS[args.method]
    problems = _Problems()  # options of the other method and bad values: said together
    for other in _METHODS.values():
        if other is method:
            continue
        for dest in other.option_dests:
            if dest not in method.option_dests and getattr(args, dest, None) is not None:
                flag = "--" + dest.replace("_", "-")
                problems.messages.append(
                    f"{flag}: applies to --method {other.name}, not {method.name}"
                )
    params: dict[str, Any] = {}
    with problems.check():
        params = method.prepare(args)
    problems.raise_all()
    return method, params


# --------------------------------------------------------------------------------------------
# hocnet detect
# --------------------------------------------------------------------------------------------


def _planned_names(
    method: _Method, params: dict[str, Any], args: argparse.Namespace, shape: Any = None
) -> list[str]:
    """The files a run will write, as far as known before detecting.

    Without ``shape`` (before loading): ``method.output_names`` only; with the input's shape:
    also the per-scene files (one per batch element for a ``(B, T, H, W)`` input),
    ``binary.npy`` (``--threshold-pfa``) and ``shifts.csv`` (registration).
    """
    names = list(method.output_names)
    if shape is None:
        return names
    if method.scene_outputs:
        batch = [None] if len(shape) == 3 else list(range(shape[0]))
        for b in batch:
            names.append("detections.csv" if b is None else f"detections_{b:03d}.csv")
            if not args.no_plot:
                names.append("detection.png" if b is None else f"detection_{b:03d}.png")
    if params.get("threshold_pfa") is not None:
        names.append("binary.npy")
    if params.get("register"):
        names.append("shifts.csv")
    return names


def _cmd_detect(args: argparse.Namespace) -> int:
    import torch

    from hocnet.data.io import save_cube, save_tracks_json
    from hocnet.plot import plot_before_after

    problems = _Problems()  # every bad option in one message, before any work
    max_per_frame = args.max_per_frame
    with problems.check():
        max_per_frame = _check_int("--max-per-frame", max_per_frame, minimum=1)
    with problems.check():
        method, params = _prepare_method(args)
    problems.raise_all()
    _load_weights(args, method.name, params)
    params["max_per_frame"] = max_per_frame
    binary = params.pop("binary", method.binary)
    out = _check_out_dir(args.out)
    out_inside_input(out, args.cube)
    inputs = input_paths(args.cube)
    if getattr(args, "target_free", None) is not None:  # a file, or image frames like the input
        inputs.update(input_paths(args.target_free, "--target-free"))
        out_inside_input(out, args.target_free, "--target-free")
    if args.weights is not None:
        inputs["--weights"] = Path(args.weights)
    # no directory in the way, no input replaced: checked now, before any work; files hocnet
    # did not write once the input's shape gives every name (in one message), before the
    # detection; all of it again before writing
    force = bool(getattr(args, "force", False))
    _check_destinations(out, _planned_names(method, params, args), inputs, force=True)
    stages = _Stages(["load", method.name, "pictures", "write"], enabled=_show_progress(args))
    with stages:
        stages.next("load")
        cube, files = load_input(args.cube, args.key, binary)
        inputs.update(frame_paths(files))
        if files and method.name == "dpa":  # named in the messages about single frames
            params["frame_names"] = [file.name for file in files]
        planned = _planned_names(method, params, args, tuple(cube.shape))
        _check_destinations(out, planned, inputs, force=force)
        batched = cube.dim() == 4
        if batched and cube.shape[0] == 0:
            raise CLIError(
                f"CUBE: '{args.cube}' holds a batch of 0 scenes (shape {tuple(cube.shape)}); "
                "nothing to detect"
            )

        stages.next(f"{method.name} on {' x '.join(map(str, cube.shape))}")
        start = time.perf_counter()
        params["progress"] = stages.enabled
        messages: list[str] = []
        with _torch_threads(PIPELINE_THREADS):
            with _reported_warnings(messages):  # e.g. a density above the HOC's bound: said
                detection = method.run(cube, params)
            if messages:  # and kept
                detection.params["warnings"] = messages
        params.pop("progress", None)
        detection.params.pop("progress", None)
        runtime = time.perf_counter() - start
        result = detection.result
        tracks = list(result.tracks)
        support, cleaned = result.support, result.cleaned
        scans = cube if detection.cube is None else detection.cube

        points_in, points_support, points_kept = (
            int(c.sum()) if c.dtype == torch.bool else None for c in (scans, support, cleaned)
        )
        meta: dict[str, Any] = {
            "method": method.name,
            **detection.params,
            "max_per_frame": params["max_per_frame"],
            "input": str(Path(args.cube).resolve()),
            "input_shape": list(cube.shape),
        }
        if files:
            meta["input_frames"] = [file.name for file in files]
        if scans.dtype == torch.bool:
            meta.update(points_in=points_in, points_support=points_support, points_out=points_kept)
        else:
            meta["track_pixels"] = points_kept
        if args.key is not None:
            meta["key"] = args.key
        if batched:
            meta["track_batch"] = [int(tr.batch) for tr in tracks]

        writers: dict[str, Writer] = {
            "tracks.json": lambda path: save_tracks_json(path, tracks, **meta),
        }
        if detection.outputs is not None:
            writers.update(
                {
                    k: w
                    for k, w in detection.outputs.items()
                    if not (args.no_plot and k.endswith(".png"))
                }
            )
        else:
            writers["cleaned.npy"] = lambda path: save_cube(path, cleaned)
            writers["support.npy"] = lambda path: save_cube(path, support)
            writers.update(detection.extra_outputs)
        if detection.outputs is None and not args.no_plot:
            stages.next("pictures")
            scenes = range(scans.shape[0]) if batched else [None]
            progress = _progress(scenes, desc="pictures", total=len(scenes), enabled=stages.enabled)
            for b in progress:
                one = result if b is None else _select(result, b)
                frames = scans if b is None else scans[b]
                label = "" if b is None else f" (batch element {b})"
                fig = plot_before_after(
                    frames,
                    one,
                    title=f"{method.name.upper()} detection in {Path(args.cube).name}{label}",
                )
                name = "detection.png" if b is None else f"detection_{b:03d}.png"
                writers[name] = _png_writer(fig)

        stages.next("write")
        paths = _write_outputs(out, writers, inputs, force=force)
    if detection.summary is not None:
        print(f"{detection.summary} ({runtime:.2f} s)")
    else:
        image = _support_name(detection.params)
        brought = ""
        if points_kept is not None and points_support is not None and points_kept > points_support:
            brought = f" (identification brings back points the {image} misses)"
        print(
            f"{method.name}: {len(tracks)} track{'s' * (len(tracks) != 1)} in "
            f"{' x '.join(map(str, scans.shape))} cube ({runtime:.2f} s); points in: "
            f"{points_in}, in the {image}: {points_support}, kept on tracks: {points_kept}"
            f"{brought}"
        )
    for note in detection.notes:
        print(f"  {note}")
    print(f"wrote {len(paths)} files to {out}/: {', '.join(p.name for p in paths[:6])}", end="")
    print(f", ... ({len(paths) - 6} more)" if len(paths) > 6 else "")
    return 0


def _select(result: Any, b: int) -> Any:
    """Batch element ``b`` of a batched result, as an object with support/cleaned/tracks."""
    return argparse.Namespace(
        support=result.support[b],
        cleaned=result.cleaned[b],
        tracks=[tr for tr in result.tracks if tr.batch == b],
    )


_DETECT_EPILOG = """\
methods:
  hoc  the modified high-order correlation (HOC) of [LA98] on a BINARY cube: bool or 0/1
       values, shape (T, H, W) = (scans, rows y, columns x), or a batch (B, T, H, W). With
       --threshold-pfa P it takes INTENSITY frames: pre-processed (below), then binarised per
       frame by a CFAR threshold (the floor(P H W) highest whitened pixels; our addition).
  dpa  the dynamic-programming track-before-detect (DPA) of [NR08] on INTENSITY frames: real
       numbers (e.g. an infrared sequence), same shapes. The frames are pre-processed, the
       accumulated score function (ASF) is built frame by frame, its last-frame peaks are
       back-tracked into tracks. Its defaults come from --preset (see below).

input:
  CUBE is a .npy file or a .npz archive (pick the array with --key if it holds several), or
  image frames: a folder (every file in it must be a PNG / BMP / TIFF frame), a glob pattern
  (quote it: 'clip/frame_*.png') or one (multi-page) image file. Frames are sorted by name in
  natural order (frame2 before frame10), values are not rescaled (8-bit 0-255, 16-bit
  0-65535), colour frames are converted to grey (L = 0.299 R + 0.587 G + 0.114 B) with a note
  on stderr (see hocnet.data.load_frames). Make a .npy from your own frames with
  numpy.save("cube.npy", array) or hocnet.data.save_cube("cube.npy", array). Fewest frames:
  2k + 1 for --method hoc (--order k: 5 by default), 2 for --method dpa. --out may not be
  the input folder of frames nor a folder inside it.

outputs of every method (in --out DIR):
  tracks.json    the tracks: {"meta": {...}, "tracks": [{"id", "score", "points": [[t, y, x],
                 ...]}]}
                 meta holds the method and every parameter used, the input path and shape
  detections.csv per-frame candidate detections, columns frame,x,y,score (x = column, y = row,
                 0-based): local maxima (non-maximum suppression radius 2), at most
                 --max-per-frame per frame, highest score first; threshold the score to choose
                 an operating point. dpa: the ASF of that frame, causal (frame n uses frames
                 0..n only); hoc: the HOC point score of the support points.
  shifts.csv     with registration: frame,dx,dy,offset_x,offset_y, the estimated camera shift of
                 each frame relative to the previous one and to frame 0, in pixels; a frame
                 pair without a reliable registration peak (no significant phase-correlation
                 peak: noise, flat or very smooth frames) keeps (0, 0), counted on stdout and
                 in meta["unregistered_pairs"]

outputs of --method hoc:
  cleaned.npy   bool cube of the points on the identified tracks, shaped like the input
  support.npy   bool cube of the points on at least one accepted HOC chain, shaped like the input
  binary.npy    with --threshold-pfa: the binarised frames the HOC ran on
  detection.png input points next to the detection

outputs of --method dpa:
  asf.npy       the accumulated score function, float32, shaped like the input
  detection.png the whitened last frame, the last-frame ASF, and each track with its score
  Without --asf-threshold or --target-free the tracks are the highest-ranked candidates, not
  confirmed detections (pure noise has candidates too); tracks.json says so ("confirmed").

  Batched (B, T, H, W) input gives ONE set of files with the batch axis; track ids run over
  the whole batch and meta["track_batch"][i] is the batch element of the i-th track; one picture
  and one detections file per element, detection_000.png, detections_000.csv, ... (--no-plot
  skips the pictures). Files of the same names already in DIR are replaced only if hocnet
  wrote them and nobody changed them since (DIR/.hocnet-outputs.json records the size and
  modification time of each file written), or with --force; an output never replaces an
  input file (CUBE, --target-free, or any of their image frames). Nothing is written if the
  input or an option is invalid, and either every file is written or none.

defaults (--method dpa):
  The library functions (hocnet.dpa.probability_matrices, accumulate, DPA) default to the
  DPA as [NR08] builds it (hocnet.dpa.presets.PAPER, --preset paper): 7 x 7 matrices, v-max 2
  px/frame + 0.5 px jitter, p 0.5, x 3, g = 0, b = 4.67 from the effective memory 0.8 of
  direction 9 (eq. 12-14), the paper's direction step, no equal gain, anti-mean whitening, no
  registration, no background removal. This command defaults to the pipeline measured best
  on six real infrared clips (hocnet.dpa.presets.RECOMMENDED, --preset recommended):
  registration + median background of the 10 previous frames + anti-mean whitening + DPA with
  5 x 5 matrices (v-max 1), g = 0, equal gain, memory 0.4. On those clips (frames 10-99) it
  found the target with Pd 0.985 on average (every clip >= 0.956) at <= 1 false alarm per
  frame, against 0.465 for a single-frame detector and 0.046 for --preset paper
  (experiments/results/real-ir.md). The memory 0.4 and the background window 10 were tuned on
  those six clips.

target speed (--method dpa; experiments/results/dpa-pd-snr.md: one 17 dB target in clear sky,
20 scenes per speed; an option holds where the track is on the target in >= 80 % of the frames;
the speed is relative to the background the pre-processing removes):
  default (recommended)                  holds 0.25-0.5 px/frame (0.78 at 1, 0.19 at 1.5); a
                                         target standing still (0.11) is removed by the median
                                         background: add --no-register --background none
                                         (holds 0-1 px/frame, 0.87 at 1)
  --g 1 --direction-step source          holds 0.25-1 px/frame (0.95 at 1, 0.79 at 1.5)
  --preset paper                         holds 0-0.5 px/frame (0.40 at 1)
  --preset paper --g 1 --direction-step source
                                         holds 0-1.5 px/frame (0.93 at 1, 0.84 at 1.5)
  No option holds at 2 px/frame (best 0.44, --preset paper --g 1 --direction-step source) or
  at 2.5 px/frame (best 0.25).

references:
  [LA98] R.-J. Liou, M. R. Azimi-Sadjadi, Multiple target detection using modified high order
         correlations, IEEE Trans. Aerospace and Electronic Systems 34(2), 1998.
  [NR08] O. Nichtern, S. R. Rotman, Parameter adjustment for a dynamic programming
         track-before-detect-based target detection algorithm, EURASIP J. Adv. Signal
         Process. 2008.

examples:
  hocnet detect scans.npz --key cube --method hoc --order 2 --v 4 --delta 45 --out results
  hocnet detect frames.npy --method dpa --out results
  hocnet detect frames.npy --method dpa --preset paper --g 1 --out results
  hocnet detect clip_folder/ --method dpa --out results
  hocnet detect 'clip/*.png' --method hoc --threshold-pfa 0.001 --out results
"""


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``detect`` on the ``hocnet`` subcommand parser."""
    detect = commands.add_parser(
        "detect",
        help="detect tracks in your own data (.npy/.npz or image frames): HOC, DPA",
        description="Detect the tracks of moving targets in your own data: --method hoc (the\n"
        "default) on a binary multi-scan cube (or intensity frames with --threshold-pfa),\n"
        "--method dpa on intensity frames. Writes the tracks (JSON), the per-frame candidate\n"
        "detections (detections.csv) and, per method, the cleaned and support cubes (hoc) or\n"
        "the accumulated score function (dpa), and a picture.",
        epilog=_DETECT_EPILOG,
        formatter_class=_Formatter,
    )
    add_input_arguments(detect, "cube", "CUBE")
    detect.add_argument(
        "--method",
        choices=sorted(_METHODS),
        default="hoc",
        help="detector (default: hoc): "
        + "; ".join(f"{m.name} = {m.help}" for m in _METHODS.values()),
    )
    detect.add_argument(
        "--out",
        default="detect-output",
        metavar="DIR",
        help="output folder (default: detect-output)",
    )
    detect.add_argument("--no-plot", action="store_true", help="do not write the PNG picture(s)")
    detect.add_argument(
        "--force", action="store_true", help="replace files in --out that hocnet did not write"
    )
    detect.add_argument(
        "--weights",
        default=None,
        metavar="CKPT",
        help="learned weights: a checkpoint of `hocnet train` (dpa: a DPATuner's b, g and "
        "matrices; hoc: a LearnedHOCSystem's kernels, order, v and delta) used instead of the "
        "fixed ones; read with torch.load(weights_only=True); needs the learn extra. The "
        "pre-processing still follows --preset: hocnet train dpa trains on anti-mean whitened "
        "frames, i.e. --preset paper's pre-processing",
    )
    detect.add_argument(
        "--max-per-frame",
        type=int,
        default=50,
        metavar="N",
        help="most candidate detections per frame in detections.csv, >= 1 (default: 50)",
    )
    for method in _METHODS.values():
        method.add_options(
            detect.add_argument_group(f"{method.name} options (--method {method.name})")
        )
    add_preprocess_options(
        detect.add_argument_group(
            "pre-processing of intensity frames (--method dpa, or --method hoc with "
            "--threshold-pfa; in this order: registration, background removal, whitening)"
        )
    )
    detect.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bars (also off when stderr is not a terminal)",
    )
    detect.set_defaults(func=_cmd_detect)

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
code (:mod:`hocnet.cli.detect`).

The MHT's false-alarm density defaults to the mean number of plots per frame divided by the
frame area (an upper bound: targets are counted too; our choice), the new-target density to a
tenth of it.
"""

from __future__ import annotations

import argparse
import json
import math
import time
import warnings
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
    _reported_warnings,
    _table,
    _torch_threads,
    _write_outputs,
)

OUTPUT_NAMES = ("tracks.json", "tracks.png")

#: ``hocnet detect``'s DPA options left out here: ``--max-targets`` and ``--nms-radius`` shape
#: only the back-tracked tracks, not the plots; ``--window`` is the HOC's sliding window here
#: (the DPA's matrix size follows ``--preset``).
_DPA_SKIP = ("window", "max_targets", "nms_radius")
_HOC_DESTS = (*_inputs.HOC_DESTS, "window", "stride")
_DPA_DESTS = (*(d for d in _inputs.DPA_DESTS if d not in _DPA_SKIP), "max_per_frame")

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
        params = _inputs.prepare_dpa(dpa)
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


def _hoc_input(cube: Any, params: dict[str, Any]) -> tuple[Any, list[str], Any]:
    """The binary cube of the HOC (``--threshold-pfa``: binarised), notes and shifts."""
    from hocnet.cli.detect import _bound_hoc, _shifts_summary, binarize_frames

    n_frames = cube.shape[0]
    order = params["order"]
    if n_frames < 2 * order + 1:
        raise CLIError(
            f"SEQ: expected at least 2 * order + 1 = {2 * order + 1} frames for --order "
            f"{order}, got {n_frames}"
        )
    notes: list[str] = []
    shifts = None
    if params.get("threshold_pfa") is not None:
        cube, shifts, note = binarize_frames(cube, params)
        if shifts is not None:
            notes.append(_shifts_summary(shifts, _SHIFTS_AT, params.get("unregistered_pairs")))
        notes.append(note)
    _bound_hoc(cube, params)
    params["window"] = min(params["window"], n_frames)
    return cube, notes, shifts


def _windows(cube: Any, p: dict[str, Any]) -> tuple[list[int], list[int], list[float], float]:
    """The windows of the streaming HOC: starts, the dense ones, densities and the bound.

    The streaming detector reports the windows starting at ``0, stride, 2 stride, ...`` (the
    last one ending at most at the last frame), and :func:`_hoc_plots` adds one final window
    ending at the last frame when the strides do not reach it. A window is dense when its
    clutter density (its on-points over ``window H W``, computed as
    :class:`~hocnet.hoc.stream.StreamingDetector` and :func:`~hocnet.hoc.detect` do) is above
    the modified HOC's discrimination bound
    (:func:`~hocnet.hoc.functional.density_bound`, [LA98] section IV-B): both skip its track
    identification, so it has no plots, and :func:`_hoc_plots` does not compute it at all.
    """
    import torch

    from hocnet.hoc import density_bound

    n_t, h, w = cube.shape
    window, stride = p["window"], p["stride"]
    starts = list(range(0, n_t - window + 1, stride))
    if (n_t - window) % stride:
        starts.append(n_t - window)
    counts = [0, *cube.reshape(n_t, -1).sum(dim=1).cumsum(0).tolist()]
    bound = density_bound("modified", p["v"], math.radians(p["delta"]))
    densities = [
        float(torch.tensor(float(counts[s + window] - counts[s])) / (window * h * w))
        for s in starts
    ]
    dense = [s for s, d in zip(starts, densities, strict=True) if d > bound]
    return starts, dense, densities, bound


def _hoc_plots(cube: Any, p: dict[str, Any]) -> list[Any]:
    """Per-frame plots ``(M_t, 2)`` (x, y) of the streaming HOC.

    Windows denser than the HOC's bound (:func:`_windows`) are skipped, with one warning
    (:func:`warnings.warn`, said by the command as ``hocnet: warning: ...``): their result
    would be empty, and streaming through them costs without bound (a 20 x 32 x 32 cube of
    ones took 45 s, one of 40 x 64 x 64 more than 500 s). Each run of consecutive sparse
    windows is streamed by its own :class:`~hocnet.hoc.stream.StreamingDetector`, whose
    windows are those of one detector over the whole sequence (every window's result equals
    :func:`~hocnet.hoc.detect` on its scans). Locally saturated patches (``LOCAL_SATURATION``
    of :mod:`hocnet.hoc.identify`: left out of identification by every window) are said once,
    with the frame numbers of the sequence, instead of once per window with the window's own
    scan numbers.
    """
    import torch

    from hocnet.cli.detect import hoc_kwargs
    from hocnet.hoc import detect, reject_slow_tracks
    from hocnet.hoc.identify import LOCAL_SATURATION, _local_saturation
    from hocnet.hoc.stream import StreamingDetector

    kw = hoc_kwargs(p)
    window, stride = p["window"], p["stride"]

    def cleaned(result: Any) -> Any:
        if p["min_speed"] > 0:
            result = reject_slow_tracks(result, p["min_speed"])
        return result.cleaned

    n_t, h, w = cube.shape
    kept = torch.zeros(n_t, h, w, dtype=torch.bool)
    starts, dense, densities, bound = _windows(cube, p)
    if dense:
        warnings.warn(
            f"clutter density above the modified HOC's discrimination bound {100 * bound:.2f} % "
            f"([LA98] section IV-B) in {len(dense)} of {len(starts)} windows (densest "
            f"{100 * max(densities):.2f} %): the detector cannot tell targets from clutter there; "
            "track identification skipped, no plots from those windows",
            RuntimeWarning,
            stacklevel=2,
        )
    aligned = [s for s in starts if s % stride == 0 and s not in dense]
    # frames of the windows that are identified (the dense ones are said above)
    covered = {t for s0 in aligned for t in range(s0, s0 + window)}
    if starts[-1] % stride and starts[-1] not in dense:
        covered |= set(range(starts[-1], n_t))
    local = _local_saturation(cube[None].bool(), kw["v"])[0]
    frames = [t for t in local.flatten(1).any(dim=1).nonzero().squeeze(1).tolist() if t in covered]
    if frames:
        side = 2 * kw["v"] + 1
        warnings.warn(
            f"clutter density above {100 * LOCAL_SATURATION:.0f} % in {side} x {side} windows "
            f"of frames {frames}: the points there are left out of track identification",
            RuntimeWarning,
            stacklevel=2,
        )
    runs: list[list[int]] = []
    for s in aligned:  # consecutive sparse windows share one streaming detector
        if runs and s == runs[-1][-1] + stride:
            runs[-1].append(s)
        else:
            runs.append([s])
    with warnings.catch_warnings():  # said once above, with the sequence's frame numbers
        warnings.filterwarnings("ignore", message=".*windows of scans", category=RuntimeWarning)
        for run in runs:
            det = StreamingDetector(window=window, stride=stride, **kw)
            for t in range(run[0], run[-1] + window):
                out = det.push(cube[t])
                if out is not None:
                    kept[run[0] + out.start : run[0] + out.stop] |= cleaned(out.result)
        last = starts[-1]
        if last % stride and last not in dense:  # the last frames: one final window at the end
            kept[last:] |= cleaned(detect(cube[last:], **kw))
    plots = []
    for t in range(n_t):
        yx = kept[t].nonzero().double()
        plots.append(yx[:, [1, 0]])
    return plots


def _dpa_plots(cube: Any, params: dict[str, Any]) -> tuple[list[Any], dict[str, Any], Any]:
    """Per-frame plots of the DPA (local maxima of the causal ASF), its parameters and shifts."""
    import torch

    from hocnet.cli.detect import DETECTION_NMS_RADIUS, _run_dpa
    from hocnet.detection_metrics import detect_peaks

    per_frame = params["max_per_frame"]
    size, (n_t, height, width) = params["window"], cube.shape
    background = params["background"] != "none"
    if n_t < 2 + background:  # a tracker needs plots in two frames to confirm a track
        because = (
            f"; frame 0 has no plots with --background {params['background']} (no past frames)"
            * background
        )
        raise CLIError(
            f"SEQ: expected at least {2 + background} frames for --detector dpa, got {n_t} (the "
            f"tracker needs plots in 2 frames to confirm a track{because})"
        )
    if min(height, width) < size:  # `hocnet detect` would name its --window, not an option here
        raise CLIError(
            f"SEQ: expected frames of at least {size} x {size} for the {size} x {size} DPA "
            f"matrices of --preset {params['preset']}, got {height} x {width}"
        )
    detection = _run_dpa(cube, {**params, "label": _LABEL})
    asf = detection.result.state.asf.double()
    threshold = detection.params.get("threshold_used")
    found = detect_peaks(
        asf, radius=DETECTION_NMS_RADIUS, max_per_frame=per_frame, threshold=threshold
    )
    plots = []
    for t in range(cube.shape[0]):
        rows = found[found[:, 0] == t]
        flat = asf[t].flatten()
        if flat.numel() and bool(flat.max() == flat.min()):
            rows = rows[:0]  # a constant frame (e.g. frame 0 after background removal)
        plots.append(rows[:, 1:3].to(torch.float64))
    used = detection.params
    meta = {
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
                "v_max",
                "equal_gain",
                "pfa",
                *_inputs.PRE_DESTS,
                "unregistered_pairs",
            )
            if k in used
        },
    }
    return plots, meta, detection.result.shifts


def _mht_params(args: argparse.Namespace, plots: list[Any], area: float) -> dict[str, Any]:
    pd = _check_number(
        "--pd", args.pd, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
    )
    meas = _check_number("--meas-std", args.meas_std, low=0.0, low_inclusive=False)
    n_plots = sum(int(p.shape[0]) for p in plots)
    if args.lambda_fa is None:
        lam = max(n_plots / max(len(plots), 1), 0.1) / area
    else:
        lam = _check_number("--lambda-fa", args.lambda_fa, low=0.0, low_inclusive=False)
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
        "lambda_nt": lam_nt,
        "n_hypotheses": _check_int("--n-hypotheses", args.n_hypotheses, minimum=1),
        "n_scan": _check_int("--n-scan", args.n_scan, minimum=0),
        "alpha": _check_number(
            "--alpha", args.alpha, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
        ),
        "beta": _check_number(
            "--beta", args.beta, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
        ),
    }


def _run_mht(plots: list[Any], p: dict[str, Any]) -> list[Any]:
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
        mht = MHT(
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
    for t, z in enumerate(plots):
        mht.step(z, time=float(t))
    return mht.all_tracks()


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
    notes: list[str] = []
    messages: list[str] = []
    shifts = None
    start = time.perf_counter()
    with _torch_threads(PIPELINE_THREADS), _reported_warnings(messages):
        if det == "hoc":
            scans, notes, shifts = _hoc_input(cube, det_params)
            plots = _hoc_plots(scans, det_params)
        else:
            names = {"frame_names": [file.name for file in files]}  # said about flat frames
            plots, det_params, shifts = _dpa_plots(cube, {**det_params, **names})
            if shifts is not None:
                weak = det_params.get("unregistered_pairs")
                notes.append(_shifts_summary(shifts, _SHIFTS_AT, weak))
        params = _mht_params(args, plots, float(h * w))
        tracks = _run_mht(plots, params)
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
        "feed its per-frame plots (pixel coordinates) to the track-oriented MHT of [PD];\n"
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
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    hoc = p.add_argument_group("hoc options (--detector hoc; as in 'hocnet detect')")
    _inputs.add_hoc_options(hoc, label=_LABEL, selector=_SELECTOR)
    hoc.add_argument(
        "--window",
        type=int,
        default=None,
        metavar="N",
        help="frames per window, >= 2 * order + 1 (default: 10, or 2 * order + 1 if larger)",
    )
    hoc.add_argument(
        "--stride", type=int, default=None, metavar="N", help="frames between windows (default: 2)"
    )
    dpa = p.add_argument_group("dpa options (--detector dpa; as in 'hocnet detect')")
    _inputs.add_dpa_options(
        dpa,
        skip=_DPA_SKIP,
        helps={"asf_threshold": "keep the plots whose ASF is above S (default: no threshold)"},
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
        help="false-alarm density per pixel (default: plots per frame / frame area)",
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

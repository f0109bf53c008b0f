"""``hocnet track``: from pixels to confirmed tracks (a detector's plots into the SB-MHT of [PD]).

The detector runs over the sequence and gives per-frame plots (pixel coordinates ``x`` = column,
``y`` = row); the track-oriented MHT (:class:`hocnet.tracking.mht.MHT`) turns them into confirmed
tracks with identities:

* ``--detector hoc``: the modified HOC of [LA98] on a BINARY ``(T, H, W)`` cube, streaming
  (:class:`hocnet.hoc.stream.StreamingDetector`, sliding windows): the plots of frame ``t`` are
  the points kept on identified HOC tracks in the windows holding ``t`` (union over windows;
  frames after the last full stride get one more window ending at the last frame).
* ``--detector dpa``: the DPA of [NR08] on INTENSITY frames with the pre-processing of
  ``hocnet detect --method dpa``; the plots of frame ``t`` are the local maxima of the causal
  ASF of frame ``t`` (the ``detections.csv`` of ``hocnet detect``), above the DPA's CFAR
  threshold when one is set, at most ``--max-per-frame``.

The MHT's false-alarm density defaults to the mean number of plots per frame divided by the
frame area (an upper bound: targets are counted too; our choice), the new-target density to a
tenth of it.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

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
    _table,
    _torch_threads,
    _write_outputs,
)

OUTPUT_NAMES = ("tracks.json", "tracks.png")

_HOC_DESTS = ("order", "v", "delta", "window", "stride")
_DPA_DESTS = ("preset", "max_per_frame")


def _load(args: argparse.Namespace) -> Any:
    """Load SEQ as a float64 ``(T, H, W)`` tensor (binary for the HOC)."""
    import torch

    from hocnet.data.io import load_cube

    try:
        cube = load_cube(args.seq, key=args.key, binary=args.detector == "hoc")
    except (ValueError, TypeError, OSError) as err:
        message = str(err).replace("`path`", "SEQ").replace("`key`", "--key")
        message = message.replace("`cube`: ", "")
        if args.detector == "hoc" and "binary" in message:
            message += "; --detector hoc needs a binary cube, use --detector dpa on intensities"
        raise CLIError(message) from None
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
    return cube


def _hoc_params(args: argparse.Namespace, n_frames: int) -> dict[str, Any]:
    order = _check_int("--order", 2 if args.order is None else args.order, minimum=1)
    v = _check_int("--v", 4 if args.v is None else args.v, minimum=1)
    delta = _check_number(
        "--delta",
        45.0 if args.delta is None else args.delta,
        low=0.0,
        high=180.0,
        low_inclusive=False,
    )
    window = _check_int(
        "--window", 10 if args.window is None else args.window, minimum=2 * order + 1
    )
    stride = _check_int("--stride", 2 if args.stride is None else args.stride, minimum=1)
    if n_frames < 2 * order + 1:
        raise CLIError(
            f"SEQ: expected at least 2 * order + 1 = {2 * order + 1} frames for --order "
            f"{order}, got {n_frames}"
        )
    return {
        "order": order,
        "v": v,
        "delta": delta,
        "window": min(window, n_frames),
        "stride": stride,
    }


def _hoc_plots(cube: Any, p: dict[str, Any]) -> list[Any]:
    """Per-frame plots ``(M_t, 2)`` (x, y) of the streaming HOC."""
    import torch

    from hocnet.hoc.stream import StreamingDetector

    det = StreamingDetector(
        window=p["window"],
        stride=p["stride"],
        order=p["order"],
        v=p["v"],
        delta=math.radians(p["delta"]),
    )
    n_t, h, w = cube.shape
    kept = torch.zeros(n_t, h, w, dtype=torch.bool)
    for t in range(n_t):
        out = det.push(cube[t])
        if out is not None:
            kept[out.start : out.stop] |= out.result.cleaned
    if (n_t - p["window"]) % p["stride"]:  # the last frames: one final window at the end
        from hocnet.hoc import detect

        last = detect(
            cube[n_t - p["window"] :], order=p["order"], v=p["v"], delta=math.radians(p["delta"])
        )
        kept[n_t - p["window"] :] |= last.cleaned
    plots = []
    for t in range(n_t):
        yx = kept[t].nonzero().double()
        plots.append(yx[:, [1, 0]])
    return plots


def _dpa_plots(cube: Any, args: argparse.Namespace) -> tuple[list[Any], dict[str, Any]]:
    """Per-frame plots of the DPA (local maxima of the causal ASF) and the DPA parameters."""
    import torch

    from hocnet.cli.detect import DETECTION_NMS_RADIUS, _prepare_dpa, _run_dpa
    from hocnet.detection_metrics import detect_peaks

    ns = argparse.Namespace(
        preset=args.preset,
        g=None,
        b=None,
        window=None,
        v_max=None,
        max_targets=None,
        nms_radius=None,
        asf_threshold=None,
        pfa=None,
        target_free=None,
        equal_gain=None,
        register=None,
        background=None,
        background_window=None,
        whiten=None,
    )
    params = _prepare_dpa(ns)
    per_frame = _check_int(
        "--max-per-frame", 5 if args.max_per_frame is None else args.max_per_frame, minimum=1
    )
    params["max_per_frame"] = per_frame
    detection = _run_dpa(cube, params)
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
    meta = {
        "preset": params["preset"],
        "max_per_frame": per_frame,
        "asf_threshold": threshold,
        "nms_radius": DETECTION_NMS_RADIUS,
    }
    return plots, meta


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


def _figure(cube: Any, plots: list[Any], tracks: list[dict[str, Any]], title: str) -> Any:
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
        if pts:
            ax.annotate(str(tr["id"]), (xs[-1], ys[-1]), color="cyan", fontsize=9)
    ax.set_title(title)
    ax.set_xlabel("x (column)")
    ax.set_ylabel("y (row)")
    return fig


def _cmd_track(args: argparse.Namespace) -> int:
    det = args.detector
    other = _DPA_DESTS if det == "hoc" else _HOC_DESTS
    for dest in other:
        if getattr(args, dest, None) is not None:
            flag = "--" + dest.replace("_", "-")
            raise CLIError(f"{flag}: does not apply to --detector {det}")
    out = _check_out_dir(args.out)
    inputs = {"SEQ": Path(args.seq)}
    names = [n for n in OUTPUT_NAMES if not (args.no_plot and n.endswith(".png"))]
    _check_destinations(out, names, inputs, force=args.force)
    cube = _load(args)
    n_t, h, w = cube.shape
    start = time.perf_counter()
    with _torch_threads(PIPELINE_THREADS):
        if det == "hoc":
            det_params = _hoc_params(args, n_t)
            plots = _hoc_plots(cube, det_params)
        else:
            plots, det_params = _dpa_plots(cube, args)
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
        "plots_per_frame": [int(p.shape[0]) for p in plots],
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
    print(
        f"track: {det} + MHT on {n_t} x {h} x {w}: {n_plots} plots, {len(rows)} confirmed "
        f"track{'s' * (len(rows) != 1)} ({runtime:.2f} s)"
    )
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
detectors:
  hoc  the modified HOC of [LA98], streaming over sliding windows (--window, --stride), on a
       BINARY cube (T, H, W) of bool or 0/1 values
  dpa  the DPA of [NR08] with the pre-processing of 'hocnet detect --method dpa' (--preset),
       on INTENSITY frames (T, H, W); plots = local maxima of each frame's causal ASF

tracker:
  the track-oriented structured-branching MHT of [PD] (hocnet.tracking.mht.MHT): chi-square
  gating, LLR track score with Wald's SPRT (confirm at ln((1 - beta) / alpha), delete at
  ln(beta / (1 - alpha))), Murty k-best global hypotheses, N-scan pruning; the motion model
  is an IMM of two constant-velocity models (--sigma-a and 10 x --sigma-a) or one CV model.

outputs (in --out DIR, all or nothing; an input is never replaced, nor a file hocnet did not
write unless --force):
  tracks.json  {"meta": {...}, "tracks": [{"id", "status", "score", "first_frame",
               "last_frame", "state", "covariance", "points": [[frame, x, y, plot], ...]}]}
  tracks.png   the maximum over frames, the plots and the tracks with their ids

examples:
  hocnet track scans.npy --detector hoc --out tracks
  hocnet track frames.npy --detector dpa --pd 0.8 --out tracks
"""


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``track`` on the ``hocnet`` subcommand parser."""
    p = commands.add_parser(
        "track",
        help="detect and track: a detector's plots into the MHT of [PD] (confirmed tracks)",
        description="Run a detector over a sequence and feed its per-frame plots (pixel\n"
        "coordinates) to the track-oriented MHT of [PD]; print the confirmed tracks\n"
        "and write them as JSON and a picture.",
        epilog=_EPILOG,
        formatter_class=_Formatter,
    )
    p.add_argument("seq", metavar="SEQ", help="input: a .npy / .npz sequence (T, H, W)")
    p.add_argument("--key", default=None, metavar="K", help="array name inside a .npz")
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
    hoc = p.add_argument_group("hoc options (--detector hoc)")
    hoc.add_argument("--order", type=int, default=None, metavar="K", help="HOC order (default: 2)")
    hoc.add_argument(
        "--v", type=int, default=None, metavar="V", help="velocity window (default: 4)"
    )
    hoc.add_argument(
        "--delta",
        type=float,
        default=None,
        metavar="DEG",
        help="curvature limit, degrees (default: 45)",
    )
    hoc.add_argument(
        "--window", type=int, default=None, metavar="N", help="frames per window (default: 10)"
    )
    hoc.add_argument(
        "--stride", type=int, default=None, metavar="N", help="frames between windows (default: 2)"
    )
    dpa = p.add_argument_group("dpa options (--detector dpa)")
    dpa.add_argument(
        "--preset",
        choices=("recommended", "paper"),
        default=None,
        help="DPA and pre-processing defaults, as in 'hocnet detect' (default: recommended)",
    )
    dpa.add_argument(
        "--max-per-frame",
        type=int,
        default=None,
        metavar="N",
        help="most plots per frame (default: 5)",
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

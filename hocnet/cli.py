"""The ``hocnet`` command line.

Subcommands (each has ``--help``):

* ``hocnet demo``: simulate a Table-III-like scene of [LA98], run the HOC detector, print true
  versus found tracks, clutter rejection, target points lost and runtime, and write pictures.
* ``hocnet detect CUBE``: run a detector on a user's binary cube (``.npy`` / ``.npz``) and write
  ``tracks.json``, ``cleaned.npy``, ``support.npy`` and a picture.
* ``hocnet reproduce NAME`` / ``hocnet reproduce --list``: run one of the repository's experiment
  scripts (``experiments/*.py``).

Errors in the user's input (bad file, wrong shape, non-binary values, out-of-range option,
unknown experiment) are reported as one line ``hocnet: error: <message>`` on stderr with exit
code 2, and nothing is written: every command validates its input and finishes its computation
before it creates any output, then writes into a temporary directory next to the output directory
and renames it into place.

Detectors are registered in ``_METHODS`` (name -> options + runner); adding a method (such as the
DPA of [NR08]) means writing its ``_add_*_options`` and ``_run_*`` functions and one registry
entry. Options of a method that was not selected are rejected, so one method's flags cannot be
silently ignored by another.

Set ``HOCNET_DEBUG=1`` to get the full traceback instead of the one-line error.

Examples:
    >>> main(["--version"])  # doctest: +ELLIPSIS
    hocnet ...
    0
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import math
import os
import re
import shutil
import sys
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, NoReturn

import hocnet

if TYPE_CHECKING:
    import torch

__all__ = ["main"]

PROG = "hocnet"
EXPERIMENTS_ENV = "HOCNET_EXPERIMENTS_DIR"
DEBUG_ENV = "HOCNET_DEBUG"


def _check_int(name: str, value: Any, **bounds: Any) -> int:
    """:func:`hocnet._check.check_int`, imported late so that ``--help`` does not load torch."""
    from hocnet._check import check_int

    return check_int(name, value, **bounds)


def _check_number(name: str, value: Any, **bounds: Any) -> float:
    """:func:`hocnet._check.check_number`, imported late (see :func:`_check_int`)."""
    from hocnet._check import check_number

    return check_number(name, value, **bounds)


class CLIError(Exception):
    """A user error: printed as ``hocnet: error: <message>``, exit code 2."""


class _Parser(argparse.ArgumentParser):
    """Argument parser whose usage errors are one line and go through :class:`CLIError`."""

    def error(self, message: str) -> NoReturn:
        raise CLIError(f"{message} (see '{self.prog} --help')")


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Keep the layout of the (pre-wrapped) descriptions and epilogs."""


# --------------------------------------------------------------------------------------------
# output: compute everything first, then write atomically
# --------------------------------------------------------------------------------------------

Writer = Callable[[Path], None]


def _check_out_dir(out: Path) -> Path:
    """Reject an output path that can never become a directory, before any work is done."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out: expected a directory, got the existing file '{out}'")
    for parent in out.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise CLIError(f"--out: '{parent}' is a file, cannot create '{out}' inside it")
            if not os.access(parent, os.W_OK) and not out.exists():
                raise CLIError(f"--out: cannot create '{out}': '{parent}' is not writable")
            break
    return out


def _write_outputs(out: Path, writers: dict[str, Writer]) -> list[Path]:
    """Write files into ``out`` all-or-nothing.

    Each writer is called with its path inside a fresh temporary directory next to ``out``. If
    every writer succeeds, the temporary directory is renamed to ``out`` (or, if ``out`` already
    exists, its files are moved in one by one, replacing files of the same names). On failure the
    temporary directory, and any parent directories created for it, are removed.

    Returns:
        The final paths, in the order of ``writers``.
    """
    out = _check_out_dir(out)
    created: Path | None = None
    for parent in [out.absolute(), *out.absolute().parents]:
        if parent.exists():
            break
        created = parent
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-{uuid.uuid4().hex[:12]}"
    try:
        tmp.mkdir()
        for name, write in writers.items():
            write(tmp / name)
        if out.exists():
            for name in writers:
                os.replace(tmp / name, out / name)
            tmp.rmdir()
        else:
            os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created is not None and created != out.absolute():
            shutil.rmtree(created, ignore_errors=True)
        raise
    return [out / name for name in writers]


def _png_writer(fig: Any) -> Writer:
    """Render a figure to PNG bytes now; the returned writer only copies bytes to disk."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=fig.dpi)
    data = buffer.getvalue()
    return lambda path: path.write_bytes(data)


# --------------------------------------------------------------------------------------------
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
    """

    result: Any
    params: dict[str, Any] = field(default_factory=dict)
    outputs: dict[str, Writer] | None = None
    summary: str | None = None


@dataclass(frozen=True)
class _Method:
    """A detector the command line can run."""

    name: str
    help: str
    add_options: Callable[[argparse._ArgumentGroup], None]
    option_dests: tuple[str, ...]
    prepare: Callable[[argparse.Namespace], dict[str, Any]]
    run: Callable[[torch.Tensor, dict[str, Any]], Detection]
    binary: bool = True


def _add_hoc_options(group: argparse._ArgumentGroup) -> None:
    group.add_argument(
        "--order", type=int, default=None, metavar="K", help="HOC order k >= 1 (default: 2)"
    )
    group.add_argument(
        "--v",
        type=int,
        default=None,
        metavar="V",
        help="velocity window: largest |dx|, |dy| per scan in pixels, >= 1 (default: 4)",
    )
    group.add_argument(
        "--delta",
        type=float,
        default=None,
        metavar="DEG",
        help="largest turn between successive moves, in DEGREES, in (0, 180] (default: 45)",
    )
    group.add_argument(
        "--threshold",
        type=float,
        default=None,
        metavar="S",
        help="smallest accepted track score, eq. (8)-(9) of [LA98] (default: 2.5)",
    )
    group.add_argument(
        "--min-points",
        type=int,
        default=None,
        metavar="N",
        help="smallest accepted track length in points, >= 1 (default: 2 * order + 1)",
    )


def _prepare_hoc(args: argparse.Namespace) -> dict[str, Any]:
    """Validate the HOC options (flag names in the messages) and fill in defaults."""
    order = _check_int("--order", 2 if args.order is None else args.order, minimum=1)
    v = _check_int("--v", 4 if args.v is None else args.v, minimum=1)
    delta = _check_number(
        "--delta",
        45.0 if args.delta is None else args.delta,
        low=0.0,
        high=180.0,
        low_inclusive=False,
    )
    threshold = _check_number("--threshold", 2.5 if args.threshold is None else args.threshold)
    min_points = 2 * order + 1 if args.min_points is None else args.min_points
    min_points = _check_int("--min-points", min_points, minimum=1)
    return {
        "order": order,
        "v": v,
        "delta": delta,
        "threshold": threshold,
        "min_points": min_points,
    }


#: Batches at least this large are detected scene by scene under a progress bar.
_PROGRESS_BATCH = 8


def _run_hoc(cube: torch.Tensor, params: dict[str, Any]) -> Detection:
    """Run :func:`hocnet.hoc.detect`; a large batch goes scene by scene with a progress bar.

    Scene by scene gives the same result as one batched call (the HOC network and the track
    identification treat batch elements independently): ids are renumbered over the batch and
    each track's ``batch`` is set, as :func:`~hocnet.hoc.detect` does.
    """
    import torch

    from hocnet.hoc import HOCResult, detect

    kwargs = {
        "order": params["order"],
        "v": params["v"],
        "delta": math.radians(params["delta"]),
        "threshold": params["threshold"],
        "min_points": params["min_points"],
    }
    detection_params = {**params, "delta_unit": "degrees"}
    if cube.dim() == 3 or cube.shape[0] < _PROGRESS_BATCH:
        return Detection(result=detect(cube, **kwargs), params=detection_params)
    parts = []
    for b in _progress(range(cube.shape[0]), desc="hoc", total=cube.shape[0], min_items=0):
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
    return Detection(result=result, params=detection_params)


def _add_dpa_options(group: argparse._ArgumentGroup) -> None:
    group.add_argument(
        "--g",
        type=float,
        default=None,
        metavar="G",
        help="sum/max mixing of eq. (11) of [NR08], in [0, 1] (default: 1)",
    )
    group.add_argument(
        "--b",
        type=float,
        default=None,
        metavar="B",
        help="memory factor, >= 0 (default: the effective-memory b of eq. (12)-(14) for g)",
    )
    group.add_argument(
        "--window",
        type=int,
        default=None,
        metavar="K",
        help="probability-matrix size, odd, at most the frame size (default: 7)",
    )
    group.add_argument(
        "--v-max",
        type=float,
        default=None,
        metavar="V",
        help="largest target speed in pixels per frame, > 0 (default: 2.5)",
    )
    group.add_argument(
        "--equal-gain",
        action="store_true",
        default=None,
        help="rescale the direction matrices to one per-step gain (beyond [NR08]; "
        "recommended for sub-pixel targets that stay in place, see hocnet.dpa.equalize_gain)",
    )
    group.add_argument(
        "--whiten",
        choices=("mean", "median", "none"),
        default=None,
        help="anti-mean / anti-median whitening (7 x 7 ring, 3 x 3 guard) or none (default: mean)",
    )
    group.add_argument(
        "--max-targets",
        type=int,
        default=None,
        metavar="N",
        help="largest number of tracks per sequence, >= 1 (default: 5)",
    )
    group.add_argument(
        "--nms-radius",
        type=int,
        default=None,
        metavar="R",
        help="non-maximum suppression radius on the last ASF, >= 0 (default: 3)",
    )
    group.add_argument(
        "--asf-threshold",
        type=float,
        default=None,
        metavar="S",
        help="keep last-frame ASF peaks above S (default: no threshold, the top peaks)",
    )
    group.add_argument(
        "--target-free",
        default=None,
        metavar="FILE",
        help="target-free frames (.npy/.npz) for a CFAR threshold at --pfa",
    )
    group.add_argument(
        "--pfa",
        type=float,
        default=None,
        metavar="P",
        help="false-alarm probability per pixel of the CFAR threshold (default: 1e-3)",
    )


def _prepare_dpa(args: argparse.Namespace) -> dict[str, Any]:
    """Validate the DPA options (flag names in the messages) and fill in defaults."""
    g = _check_number("--g", 1.0 if args.g is None else args.g, low=0.0, high=1.0)
    b = None if args.b is None else _check_number("--b", args.b, low=0.0)
    window = _check_int("--window", 7 if args.window is None else args.window, minimum=1)
    if window % 2 == 0:
        raise CLIError(f"--window: expected an odd integer, got {window}")
    v_max = _check_number(
        "--v-max", 2.5 if args.v_max is None else args.v_max, low=0.0, low_inclusive=False
    )
    max_targets = _check_int(
        "--max-targets", 5 if args.max_targets is None else args.max_targets, minimum=1
    )
    nms_radius = _check_int(
        "--nms-radius", 3 if args.nms_radius is None else args.nms_radius, minimum=0
    )
    threshold = (
        None if args.asf_threshold is None else _check_number("--asf-threshold", args.asf_threshold)
    )
    pfa = _check_number(
        "--pfa",
        1e-3 if args.pfa is None else args.pfa,
        low=0.0,
        high=1.0,
        low_inclusive=False,
        high_inclusive=False,
    )
    if threshold is not None and args.target_free is not None:
        raise CLIError("--asf-threshold: expected no fixed threshold together with --target-free")
    target_free = None
    if args.target_free is not None:
        from hocnet.data.io import load_cube

        try:
            target_free = load_cube(args.target_free)
        except (ValueError, TypeError, OSError) as err:
            raise CLIError(str(err).replace("`path`", "--target-free")) from None
    return {
        "g": g,
        "b": b,
        "window": window,
        "v_max": v_max,
        "whiten": args.whiten or "mean",
        "equal_gain": bool(args.equal_gain),
        "max_targets": max_targets,
        "nms_radius": nms_radius,
        "asf_threshold": threshold,
        "pfa": pfa,
        "target_free": target_free,
    }


def _run_dpa(cube: torch.Tensor, params: dict[str, Any]) -> Detection:
    """Whiten, accumulate (eq. 11 of [NR08]), pick the last-frame peaks and back-track them."""
    import torch

    from hocnet.data.io import save_cube
    from hocnet.data.whitening import anti_mean, anti_median
    from hocnet.dpa import effective_memory, equalize_gain, probability_matrices
    from hocnet.dpa.backtrack import detect
    from hocnet.plot import plot_dpa

    frames = cube.float()
    height, width = frames.shape[-2:]
    window = params["window"]
    if window > min(height, width):
        raise CLIError(
            f"--window: expected at most the frame size min(H, W) = {min(height, width)}, "
            f"got {window}"
        )
    whiten = {"mean": anti_mean, "median": anti_median}.get(params["whiten"])
    if whiten is not None:
        outer = min(7, *(n if n % 2 else n - 1 for n in (height, width)))
        if outer < 3:
            raise CLIError(f"--whiten: frames of {height} x {width} are too small for a ring")
        inner = 3 if outer >= 5 else 1

        def whitened(x: torch.Tensor) -> torch.Tensor:
            return whiten(x.float(), outer, inner)
    else:

        def whitened(x: torch.Tensor) -> torch.Tensor:
            return x.float()

    white = whitened(frames)
    weights = probability_matrices(window=window, v_max=params["v_max"])
    if params["equal_gain"]:
        weights = equalize_gain(weights, params["g"])
    b = params["b"]
    if b is None:
        b = float(effective_memory(weights, params["g"]))
    target_free = params["target_free"]
    if target_free is not None:
        target_free = whitened(target_free)
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
    )
    asf = found.state.asf
    batched = frames.dim() == 4
    n_t = frames.shape[-3]
    tracks, support = found.tracks, torch.zeros(frames.shape, dtype=torch.bool)
    t = torch.arange(n_t)
    for tr in tracks:
        (support[tr.batch] if batched else support)[t, tr.points[:, 1], tr.points[:, 2]] = True
    result = argparse.Namespace(support=support, cleaned=support, tracks=tracks, state=found.state)
    outputs: dict[str, Writer] = {"asf.npy": lambda path: save_cube(path, asf)}
    scenes = range(frames.shape[0]) if batched else [None]
    for i in scenes:
        one = found.tracks if i is None else [tr for tr in found.tracks if tr.batch == i]
        fig = plot_dpa(
            white if i is None else white[i],
            asf if i is None else asf[i],
            [tr.positions for tr in one],
            title="DPA detection" + ("" if i is None else f" (batch element {i})"),
        )
        outputs["detection.png" if i is None else f"detection_{i:03d}.png"] = _png_writer(fig)
    params = {k: v for k, v in params.items() if k != "target_free"}
    params.update(b=b, threshold_used=found.threshold, cfar=target_free is not None)
    summary = (
        f"dpa: {len(tracks)} track{'s' * (len(tracks) != 1)} in "
        f"{' x '.join(map(str, frames.shape))} frames (g = {params['g']:g}, b = {b:.4g}, "
        f"threshold = {found.threshold if found.threshold is not None else 'none'})"
    )
    return Detection(result=result, params=params, outputs=outputs, summary=summary)


_METHODS: dict[str, _Method] = {
    "hoc": _Method(
        name="hoc",
        help="modified high-order correlation of [LA98] (binary cubes)",
        add_options=_add_hoc_options,
        option_dests=("order", "v", "delta", "threshold", "min_points"),
        prepare=_prepare_hoc,
        run=_run_hoc,
    ),
    "dpa": _Method(
        name="dpa",
        help="dynamic-programming track-before-detect of [NR08] (float frames)",
        add_options=_add_dpa_options,
        option_dests=(
            "g",
            "b",
            "window",
            "v_max",
            "equal_gain",
            "whiten",
            "max_targets",
            "nms_radius",
            "asf_threshold",
            "target_free",
            "pfa",
        ),
        prepare=_prepare_dpa,
        run=_run_dpa,
        binary=False,
    ),
}


def _prepare_method(args: argparse.Namespace) -> tuple[_Method, dict[str, Any]]:
    method = _METHODS[args.method]
    for other in _METHODS.values():
        if other is method:
            continue
        for dest in other.option_dests:
            if dest not in method.option_dests and getattr(args, dest, None) is not None:
                flag = "--" + dest.replace("_", "-")
                raise CLIError(f"{flag}: applies to --method {other.name}, not {method.name}")
    return method, method.prepare(args)


# --------------------------------------------------------------------------------------------
# shared helpers
# --------------------------------------------------------------------------------------------


def _point_set(points: torch.Tensor) -> set[tuple[int, int, int]]:
    return {tuple(int(c) for c in row) for row in points.reshape(-1, 3).tolist()}


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """Plain fixed-width table (columns left-aligned, two spaces apart)."""
    cells = [list(map(str, header)), *([str(c) for c in row] for row in rows)]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join("  " + line for line in lines)


def _scans(points: torch.Tensor) -> str:
    t = points.reshape(-1, 3)[:, 0]
    return "-" if t.numel() == 0 else f"{int(t.min())}-{int(t.max())}"


# --------------------------------------------------------------------------------------------
# hocnet demo
# --------------------------------------------------------------------------------------------


def _match_tables(scene: Any, tracks: Sequence[Any]) -> tuple[str, str, int]:
    """Tables of true tracks versus found tracks, and the number of false tracks.

    A true track is covered by the found track sharing most of its points. A found track is
    false when fewer than half of its points are target points
    (:func:`hocnet.metrics.false_tracks`);
    otherwise it belongs to the true track holding at least half of its points, or is "mixed"
    (target points of several tracks, e.g. a wrong link at a crossing).
    """
    from hocnet.metrics import false_tracks

    truth = [_point_set(tr) for tr in scene.tracks]
    found = [_point_set(tr.points) for tr in tracks]
    names = []
    for label in scene.track_labels:
        parent = scene.split_parents.get(label)
        names.append(f"{label} (branch of {parent})" if parent is not None else str(label))

    true_rows = []
    for name, points, pts in zip(names, truth, scene.tracks):
        overlaps = [len(points & f) for f in found]
        best = max(range(len(found)), key=lambda k: (overlaps[k], -k), default=None)
        if best is None or overlaps[best] == 0:
            true_rows.append([name, len(points), _scans(pts), "-", f"0/{len(points)}", "0 %"])
        else:
            n = overlaps[best]
            share = f"{100.0 * n / len(points):.0f} %" if points else "n/a"
            true_rows.append(
                [name, len(points), _scans(pts), tracks[best].id, f"{n}/{len(points)}", share]
            )

    found_rows = []
    n_false = 0
    for track, points in zip(tracks, found):
        overlaps = [len(points & t) for t in truth]
        on_target = int(scene.target_mask[tuple(track.points.t())].sum())
        best = max(range(len(truth)), key=lambda k: (overlaps[k], -k), default=None)
        if false_tracks([track.points], scene.target_mask):
            match = "FALSE"
            n_false += 1
        elif best is not None and 2 * overlaps[best] >= len(points):
            match = names[best]
        else:
            touched = [str(lab) for lab, n in zip(scene.track_labels, overlaps) if n]
            match = f"mixed ({', '.join(touched)})"
        found_rows.append(
            [
                track.id,
                len(points),
                _scans(track.points),
                f"{track.score:.2f}",
                match,
                f"{on_target}/{len(points)}",
            ]
        )
    true_table = _table(
        ["true track", "points", "scans", "found track", "covered", "fraction"], true_rows
    )
    found_table = _table(
        ["found track", "points", "scans", "score", "true track", "on target"], found_rows
    )
    return true_table, found_table, n_false


def _demo_dpa(seed: int, writers: dict[str, Writer], *, plot: bool) -> None:
    """The DPA part of the demo: one dim target in a clear-sky IR sequence ([NR08])."""
    from hocnet.data.infrared import IRTarget, simulate_ir
    from hocnet.data.whitening import anti_mean
    from hocnet.dpa import detect, effective_memory, probability_matrices, tracking_success

    snr_db, g = 12.0, 0.0
    target = IRTarget(12.0, 16.0, 0.8, 0.3, snr_db=snr_db)
    seq = simulate_ir((25, 64, 64), [target], clouds="clear", jitter=0.25, seed=seed)
    start = time.perf_counter()
    white = anti_mean(seq.frames)
    weights = probability_matrices(window=7, v_max=2.5)
    b = float(effective_memory(weights, g))
    found = detect(white, weights, b, g, max_targets=1)
    runtime = time.perf_counter() - start
    truth = seq.positions[0]
    print(
        f"\nDPA ([NR08]): one target at {snr_db:g} dB peak SNR moving (0.8, 0.3) px/frame, "
        f"25 frames of 64 x 64, clear sky, jitter 0.25 px; anti-mean whitening, 7 x 7 matrices, "
        f"g = {g:g}, b = {b:.3g} (effective memory 0.8)"
    )
    if found.tracks:
        track = found.tracks[0].positions
        error = (track.to(truth.dtype) - truth).norm(dim=-1)
        within = int((error <= 1.5).sum())
        ok = bool(tracking_success(track, truth))
        print(
            f"Back-tracked track: within 1.5 px of the truth in {within} of {len(error)} frames "
            f"(mean error {float(error.mean()):.2f} px): "
            f"{'tracked' if ok else 'NOT tracked'} (>= 80 % of frames)"
        )
    else:
        print("Back-tracked track: none")
    print(f"Runtime: {runtime:.2f} s (whitening + accumulation + back-tracking)")
    if plot:
        from hocnet.plot import plot_dpa

        fig = plot_dpa(
            white,
            found.state.asf,
            [tr.positions for tr in found.tracks],
            truth=truth,
            title=f"hocnet demo: DPA of [NR08], {snr_db:g} dB target, seed {seed}",
        )
        writers["demo_dpa.png"] = _png_writer(fig)


def _cmd_demo(args: argparse.Namespace) -> int:
    from hocnet.data.binary import paper_scene
    from hocnet.hoc import detect
    from hocnet.metrics import clutter_rejection, target_points_lost
    from hocnet.plot import plot_before_after, plot_cube_3d

    seed = _check_int("--seed", args.seed, minimum=0)
    density = _check_number("--density", args.density, low=0.0, high=1.0)
    order = _check_int("--order", args.order, minimum=1)
    out = _check_out_dir(Path(args.out))

    scene = paper_scene("table3", density, seed=seed)
    start = time.perf_counter()
    result = detect(scene.cube, order=order)
    runtime = time.perf_counter() - start

    n_t, n_h, n_w = scene.cube.shape
    true_table, found_table, n_false = _match_tables(scene, result.tracks)
    mask = scene.target_mask
    c_in, t_in = int(scene.n_clutter_points), int(scene.n_target_points)
    c_support, c_tracks = (
        int((scene.clutter_mask & o).sum()) for o in (result.support, result.cleaned)
    )
    rejection_support = clutter_rejection(scene.cube, result.support, mask)
    rejection_tracks = clutter_rejection(scene.cube, result.cleaned, mask)
    lost_support = target_points_lost(scene.cube, result.support, mask)
    lost_tracks = target_points_lost(scene.cube, result.cleaned, mask)

    title = (
        f"hocnet demo: Table-III-like scene of [LA98], clutter density {density:g}, seed {seed}, "
        f"HOC order {order}"
    )
    writers: dict[str, Writer] = {}
    if not args.no_plot:
        fig = plot_before_after(
            scene.cube, result, labels=scene.labels, true_tracks=scene.tracks, title=title
        )
        writers["demo_before_after.png"] = _png_writer(fig)
        fig = plot_cube_3d(
            scene.cube,
            labels=scene.labels,
            title=f"Input scans: {int(scene.cube.sum())} points "
            f"(clutter density {density:g}, seed {seed})",
        )
        writers["demo_3d.png"] = _png_writer(fig)

    print(
        f"Scene: Table-III-like scene of [LA98], {n_t} scans of {n_h} x {n_w} pixels, "
        f"clutter density {density:g}, seed {seed}: {len(scene.tracks)} true tracks, "
        f"{t_in} target points, {c_in} clutter points"
    )
    print(f"Detector: modified HOC, order {order}, v = 4, delta = 45 deg, threshold 2.5\n")
    print("True tracks (each covered by the found track sharing most of its points):")
    print(true_table)
    print(f"\nFound tracks: {len(result.tracks)} ({n_false} false):")
    print(found_table if result.tracks else "  (none)")
    print()
    print(
        f"Clutter rejection after HOC support:           {100 * rejection_support:.1f} % "
        f"({c_support} of {c_in} clutter points left)"
    )
    print(
        f"Clutter rejection after track identification: {100 * rejection_tracks:.1f} % "
        f"({c_tracks} left)"
    )
    print(
        f"Target points lost: {lost_support} of {t_in} after HOC support, "
        f"{lost_tracks} after track identification"
    )
    print(f"Runtime: {runtime:.2f} s (HOC support + track identification)")
    if not args.no_dpa:
        _demo_dpa(seed, writers, plot=not args.no_plot)
    if writers:
        for path in _write_outputs(out, writers):
            print(f"wrote {path}")
    return 0


# --------------------------------------------------------------------------------------------
# hocnet detect
# --------------------------------------------------------------------------------------------


def _cmd_detect(args: argparse.Namespace) -> int:
    import torch

    from hocnet.data.io import load_cube, save_cube, save_tracks_json
    from hocnet.plot import plot_before_after

    method, params = _prepare_method(args)
    out = _check_out_dir(Path(args.out))
    try:
        cube = load_cube(args.cube, key=args.key, binary=method.binary)
    except (ValueError, TypeError, OSError) as err:
        message = str(err).replace("`path`", "CUBE").replace("`key`", "--key")
        raise CLIError(message.replace("`cube`: ", "")) from None
    batched = cube.dim() == 4

    start = time.perf_counter()
    detection = method.run(cube, params)
    runtime = time.perf_counter() - start
    result = detection.result
    tracks = list(result.tracks)
    support, cleaned = result.support, result.cleaned

    points_in, points_support, points_kept = (
        int(c.sum()) if c.dtype == torch.bool else None for c in (cube, support, cleaned)
    )
    meta: dict[str, Any] = {
        "method": method.name,
        **detection.params,
        "input": str(Path(args.cube).resolve()),
        "input_shape": list(cube.shape),
    }
    if method.binary:
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
    if detection.outputs is None and not args.no_plot:
        scenes = range(cube.shape[0]) if batched else [None]
        progress = _progress(scenes, desc="plotting", total=len(scenes), min_items=8)
        for b in progress:
            one = result if b is None else _select(result, b)
            frames = cube if b is None else cube[b]
            label = "" if b is None else f" (batch element {b})"
            fig = plot_before_after(
                frames,
                one,
                title=f"{method.name.upper()} detection in {Path(args.cube).name}{label}",
            )
            writers["detection.png" if b is None else f"detection_{b:03d}.png"] = _png_writer(fig)

    paths = _write_outputs(out, writers)
    if detection.summary is not None:
        print(f"{detection.summary} ({runtime:.2f} s)")
    else:
        print(
            f"{method.name}: {len(tracks)} track{'s' * (len(tracks) != 1)} in "
            f"{' x '.join(map(str, cube.shape))} cube ({runtime:.2f} s); points in: {points_in}, "
            f"in the support: {points_support}, kept on tracks: {points_kept}"
        )
    print(f"wrote {len(paths)} files to {out}/: {', '.join(p.name for p in paths[:5])}", end="")
    print(f", ... ({len(paths) - 5} more)" if len(paths) > 5 else "")
    return 0


def _select(result: Any, b: int) -> Any:
    """Batch element ``b`` of a batched result, as an object with support/cleaned/tracks."""
    return argparse.Namespace(
        support=result.support[b],
        cleaned=result.cleaned[b],
        tracks=[tr for tr in result.tracks if tr.batch == b],
    )


def _progress(items: Any, *, desc: str, total: int, min_items: int) -> Any:
    """A tqdm bar on stderr when there are at least ``min_items`` items, else the items."""
    if total < min_items:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=desc, total=total, leave=False, file=sys.stderr)


# --------------------------------------------------------------------------------------------
# hocnet reproduce
# --------------------------------------------------------------------------------------------


@dataclass
class Experiment:
    """An experiment script found in the experiments folder."""

    name: str
    description: str
    path: Path
    run: Callable[..., Any]


def experiments_dir(override: str | os.PathLike | None = None) -> Path:
    """The experiments folder: ``override``, else ``$HOCNET_EXPERIMENTS_DIR``, else the repo's.

    The repository's folder is ``<repo>/experiments`` next to the ``hocnet`` package; it does not
    exist when hocnet is installed without the repository (then a :class:`CLIError` says so).
    """
    if override is not None:
        folder, source = Path(override), "--experiments-dir"
    elif os.environ.get(EXPERIMENTS_ENV):
        folder, source = Path(os.environ[EXPERIMENTS_ENV]), f"${EXPERIMENTS_ENV}"
    else:
        folder = Path(hocnet.__file__).resolve().parents[1] / "experiments"
        source = "the repository"
    if not folder.is_dir():
        hint = (
            " (hocnet seems to be installed without its repository; run from a clone, or set "
            f"{EXPERIMENTS_ENV})"
            if source == "the repository"
            else ""
        )
        raise CLIError(f"experiments folder '{folder}' from {source} does not exist{hint}")
    return folder


def _import_script(path: Path) -> ModuleType:
    """Import one script by file path (its folder is on ``sys.path`` while it is imported)."""
    module_name = f"_hocnet_experiments.{path.stem}"
    if module_name in sys.modules and getattr(sys.modules[module_name], "__file__", None) == str(
        path
    ):
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path.name}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(module_name, None)
        raise
    finally:
        with contextlib.suppress(ValueError):
            sys.path.remove(str(path.parent))
    return module


def _as_experiment(module: ModuleType, path: Path) -> Experiment | None:
    name = getattr(module, "NAME", None)
    run = getattr(module, "run", None)
    if not isinstance(name, str) or not callable(run):
        return None  # a helper module, not an experiment
    description = getattr(module, "DESCRIPTION", None) or (module.__doc__ or "").strip()
    return Experiment(name, " ".join(str(description).split()), path, run)


def find_experiments(folder: Path) -> tuple[list[Experiment], dict[str, str]]:
    """Import every ``*.py`` in ``folder`` not starting with ``_``.

    Returns:
        ``(experiments, failures)``: the scripts defining ``NAME`` and ``run``, sorted by name,
        and ``{file name: one-line error}`` for scripts that could not be imported.
    """
    found: list[Experiment] = []
    failures: dict[str, str] = {}
    for path in sorted(folder.glob("*.py")):
        if path.name.startswith("_"):
            continue
        try:
            module = _import_script(path)
        except Exception as err:  # a broken script must not hide the others
            failures[path.name] = _one_line(f"{type(err).__name__}: {err}")
            continue
        experiment = _as_experiment(module, path)
        if experiment is not None:
            found.append(experiment)
    return sorted(found, key=lambda e: e.name), failures


def _find_experiment(folder: Path, name: str) -> Experiment:
    # fast path: the script named after the experiment ("hoc-table2" -> hoc_table2.py)
    guess = folder / f"{name.replace('-', '_')}.py"
    if guess.is_file() and not guess.name.startswith("_"):
        with contextlib.suppress(Exception):
            experiment = _as_experiment(_import_script(guess), guess)
            if experiment is not None and experiment.name == name:
                return experiment
    experiments, failures = find_experiments(folder)
    for experiment in experiments:
        if name in (experiment.name, experiment.path.stem):
            return experiment
    available = ", ".join(e.name for e in experiments) or "none"
    broken = f"; could not import: {', '.join(failures)}" if failures else ""
    raise CLIError(
        f"unknown experiment {name!r}; available: {available}{broken} (see 'hocnet reproduce "
        "--list')"
    )


def _cmd_reproduce(args: argparse.Namespace) -> int:
    if args.list and args.name is not None:
        raise CLIError("give either NAME or --list, not both")
    if not args.list and args.name is None:
        raise CLIError("expected an experiment NAME or --list (see 'hocnet reproduce --help')")
    seeds = None if args.seeds is None else _check_int("--seeds", args.seeds, minimum=1)
    folder = experiments_dir(args.experiments_dir)
    if args.list:
        experiments, failures = find_experiments(folder)
        if not experiments and not failures:
            print(f"no experiments in {folder}")
        width = max((len(e.name) for e in experiments), default=0)
        for experiment in experiments:
            print(f"{experiment.name.ljust(width)}  {experiment.description}")
        for file_name, error in failures.items():
            print(f"{file_name}: could not import ({error})", file=sys.stderr)
        return 0
    experiment = _find_experiment(folder, args.name)
    out_dir = None if args.out is None else _check_out_dir(Path(args.out))
    start = time.perf_counter()
    written = experiment.run(quick=args.quick, seeds=seeds, out_dir=out_dir, progress=True)
    runtime = time.perf_counter() - start
    print(f"{experiment.name}: done in {runtime:.1f} s; results in {written}")
    return 0


# --------------------------------------------------------------------------------------------
# parser and entry point
# --------------------------------------------------------------------------------------------

_DETECT_EPILOG = """\
input:
  CUBE is a .npy file or a .npz archive (pick the array with --key if it holds several) with a
  binary cube (bool or 0/1) of shape (T, H, W) = (scans, rows y, columns x), or a batch
  (B, T, H, W) of such cubes.

outputs (in --out DIR):
  tracks.json   the tracks: {"meta": {...}, "tracks": [{"id", "score", "points": [[t, y, x], ...]}]}
                meta holds the method and its parameters (delta in degrees), the input path and
                shape, and points_in / points_support / points_out
  cleaned.npy   bool cube of the points on the identified tracks, shaped like the input
  support.npy   bool cube of the points on at least one accepted HOC chain, shaped like the input
  detection.png input points next to the detection
  Batched (B, T, H, W) input gives ONE set of files with the batch axis: cleaned.npy and
  support.npy are (B, T, H, W), track ids run over the whole batch and meta["track_batch"][i] is
  the batch element of the i-th track; one picture per element, detection_000.png, ...
  (--no-plot skips them). Files of the same names already in DIR are replaced. Nothing is written
  if the input or an option is invalid.

example:
  hocnet detect scans.npz --key cube --method hoc --order 2 --v 4 --delta 45 --out results
"""

_REPRODUCE_EPILOG = f"""\
Experiment scripts are the files experiments/*.py of the hocnet repository (not starting with
'_'); each defines NAME, DESCRIPTION and run(quick, seeds, out_dir, progress). The folder can be
changed with the environment variable {EXPERIMENTS_ENV}.
"""


def build_parser() -> argparse.ArgumentParser:
    """The ``hocnet`` argument parser (exposed for documentation and tests)."""
    parser = _Parser(
        prog=PROG,
        description="Track-before-detect for dim multiple moving targets: modified high-order\n"
        "correlation (HOC) of [LA98] on binary multi-scan cubes.",
        epilog="Run 'hocnet COMMAND --help' for the options of each command.",
        formatter_class=_Formatter,
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {hocnet.__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    demo = commands.add_parser(
        "demo",
        help="simulate a Table-III-like scene, detect its tracks, print a summary, write PNGs",
        description="Simulate the crossing / splitting / parallel tracks of Table III of [LA98]\n"
        "(10 scans of 60 x 60 pixels, uniform clutter), run the modified HOC detector, and\n"
        "print true versus found tracks, clutter rejection, target points lost and runtime;\n"
        "then run the DPA of [NR08] on a simulated IR sequence with one dim target.\n"
        "Writes DIR/demo_before_after.png, DIR/demo_3d.png and DIR/demo_dpa.png.",
        formatter_class=_Formatter,
    )
    demo.add_argument(
        "--out",
        default="demo-output",
        metavar="DIR",
        help="folder for the pictures (default: demo-output)",
    )
    demo.add_argument(
        "--seed", type=int, default=0, metavar="N", help="random seed, >= 0 (default: 0)"
    )
    demo.add_argument(
        "--density",
        type=float,
        default=0.014,
        metavar="D",
        help="clutter density: fraction of pixels per scan, in [0, 1] (default: 0.014)",
    )
    demo.add_argument(
        "--order", type=int, default=2, metavar="K", help="HOC order, >= 1 (default: 2)"
    )
    demo.add_argument("--no-plot", action="store_true", help="print the summary only, no PNGs")
    demo.add_argument("--no-dpa", action="store_true", help="skip the DPA part of the demo")
    demo.set_defaults(func=_cmd_demo)

    detect = commands.add_parser(
        "detect",
        help="detect tracks in your own binary cube (.npy/.npz)",
        description="Detect the tracks of moving targets in a binary multi-scan cube; write the\n"
        "tracks (JSON), the cleaned cube, the support cube and a picture.",
        epilog=_DETECT_EPILOG,
        formatter_class=_Formatter,
    )
    detect.add_argument("cube", metavar="CUBE", help="input cube, .npy or .npz")
    detect.add_argument(
        "--key", default=None, metavar="K", help="array name inside a .npz (default: its only one)"
    )
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
    for method in _METHODS.values():
        method.add_options(
            detect.add_argument_group(f"{method.name} options (--method {method.name})")
        )
    detect.set_defaults(func=_cmd_detect)

    reproduce = commands.add_parser(
        "reproduce",
        help="run an experiment script (a table or figure of the papers); --list shows them",
        description="Run one experiment of the repository's experiments/ folder, or list them.",
        epilog=_REPRODUCE_EPILOG,
        formatter_class=_Formatter,
    )
    reproduce.add_argument("name", nargs="?", metavar="NAME", help="experiment name")
    reproduce.add_argument("--list", action="store_true", help="list the experiments and exit")
    reproduce.add_argument(
        "--quick", action="store_true", help="small, fast version (fewer scenes / seeds)"
    )
    reproduce.add_argument(
        "--seeds",
        type=int,
        default=None,
        metavar="N",
        help="number of seeds (default: the script's)",
    )
    reproduce.add_argument(
        "--out", default=None, metavar="DIR", help="output folder (default: the script's)"
    )
    reproduce.add_argument("--experiments-dir", default=None, help=argparse.SUPPRESS)
    reproduce.set_defaults(func=_cmd_reproduce)
    return parser


def _one_line(message: str) -> str:
    return " ".join(str(message).split()) or "unknown error"


def _fail(message: str) -> int:
    message = re.sub(r"`(--[\w-]+)`", r"\1", _one_line(message))  # `--v`: -> --v:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``hocnet`` command line.

    Args:
        argv: the arguments after the program name; ``None`` uses ``sys.argv[1:]``.

    Returns:
        The exit code: 0 on success, 2 for a usage or input error (one line on stderr,
        ``hocnet: error: ...``), 130 when interrupted.

    Examples:
        >>> main(["reproduce"])
        2
    """
    parser = build_parser()
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit as exit_:  # --help / --version
            return exit_.code if isinstance(exit_.code, int) else 0
        return int(args.func(args))
    except CLIError as err:
        return _fail(str(err))
    except (ValueError, TypeError, OSError) as err:
        if os.environ.get(DEBUG_ENV):
            raise
        return _fail(str(err) or type(err).__name__)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

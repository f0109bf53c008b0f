"""``hocnet demo``: simulate a scene, run both detectors, print a summary, write pictures."""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch
from hocnet.cli._common import (
    CLIError,
    Writer,
    _check_destinations,
    _check_int,
    _check_number,
    _check_out_dir,
    _Formatter,
    _png_writer,
    _show_progress,
    _Stages,
    _table,
    _write_outputs,
)


def _point_set(points: torch.Tensor) -> set[tuple[int, int, int]]:
    return {tuple(int(c) for c in row) for row in points.reshape(-1, 3).tolist()}


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

    # A target at the paper's speeds (0.2-0.3 px/frame, [NR08] section 3) and the paper's
    # sum recursion (g = 1, b = 0.8); faster targets need other options (README, DPA results).
    snr_db, g, velocity = 12.0, 1.0, (0.3, 0.1)
    target = IRTarget(12.0, 16.0, *velocity, snr_db=snr_db)
    seq = simulate_ir((25, 64, 64), [target], clouds="clear", jitter=0.25, seed=seed)
    start = time.perf_counter()
    white = anti_mean(seq.frames)
    weights = probability_matrices()
    b = float(effective_memory(weights, g))
    found = detect(white, weights, b, g, max_targets=1)
    runtime = time.perf_counter() - start
    truth = seq.positions[0]
    print(
        f"\nDPA ([NR08]): one target at {snr_db:g} dB peak SNR moving {velocity} px/frame, "
        f"25 frames of 64 x 64, clear sky, jitter 0.25 px; anti-mean whitening, the paper's "
        f"7 x 7 matrices, g = {g:g}, b = {b:.3g} (effective memory 0.8)"
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
            scores=[tr.score for tr in found.tracks],
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
    out = _check_out_dir(args.out)
    names = [] if args.no_plot else ["demo_before_after.png", "demo_3d.png", "demo_dpa.png"]
    if args.no_dpa:
        names = [n for n in names if n != "demo_dpa.png"]
    _check_destinations(out, names, force=args.force)

    stages = _Stages(["scene", "hoc", "dpa", "write"], enabled=_show_progress(args))
    with stages:
        stages.next("simulate the scene")
        scene = paper_scene("table3", density, seed=seed)
        if 2 * order + 1 > scene.cube.shape[0]:
            raise CLIError(
                f"--order: expected at most {(scene.cube.shape[0] - 1) // 2} for the demo's "
                f"{scene.cube.shape[0]} scans (order k needs 2k + 1 scans), got {order}"
            )
        stages.next("hoc")
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
            f"hocnet demo: Table-III-like scene of [LA98], clutter density {density:g}, "
            f"seed {seed}, HOC order {order}"
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
                true_tracks=scene.tracks,  # the legend counts agree with the printed table
                track_labels=scene.track_labels,
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
            stages.next("dpa")
            _demo_dpa(seed, writers, plot=not args.no_plot)
        stages.next("write")
        paths = _write_outputs(out, writers, force=args.force) if writers else []
    for path in paths:
        print(f"wrote {path}")
    return 0


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``demo`` on the ``hocnet`` subcommand parser."""
    demo = commands.add_parser(
        "demo",
        help="simulate a Table-III-like scene, detect its tracks, print a summary, write PNGs",
        description="Simulate the crossing / splitting / parallel tracks of Table III of [LA98]\n"
        "(10 scans of 60 x 60 pixels, uniform clutter), run the modified HOC detector, and\n"
        "print true versus found tracks, clutter rejection, target points lost and runtime;\n"
        "then run the DPA of [NR08] on a simulated IR sequence with one dim target.\n"
        "Writes DIR/demo_before_after.png, DIR/demo_3d.png and DIR/demo_dpa.png (a rerun\n"
        "replaces them; a file of these names that hocnet did not write needs --force).",
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
    demo.add_argument(
        "--force", action="store_true", help="replace files in --out that hocnet did not write"
    )
    demo.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bars (also off when stderr is not a terminal)",
    )
    demo.set_defaults(func=_cmd_demo)

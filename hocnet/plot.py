"""Pictures of binary scans, detections and maps (matplotlib).

Every function builds a :class:`matplotlib.figure.Figure` directly (no ``pyplot``), rendered by the
Agg backend when saved: nothing here changes the user's matplotlib backend, opens a window or keeps
figures alive in a global figure manager. Each function returns the figure (or the figure of the
``ax`` it was given) and, when ``path`` is set, also saves it there (the format follows the
extension, e.g. ``.png``).

Conventions (those of the whole package): cubes are ``(T, H, W)`` (``T`` scans, ``H`` rows ``y``,
``W`` columns ``x``); a track is an ``(N, 3)`` array of ``(t, y, x)`` rows. Image panels show
``x`` to the right and ``y`` *down*, like the image itself, with pixel units on both axes.

* :func:`plot_cube_3d`: the scans as a 3-D point cloud ``(x, y, scan)``, clutter small and grey,
  targets coloured (or all points coloured by scan when there are no labels).
* :func:`plot_before_after`: the input points next to the detection (support, identified tracks,
  true tracks).
* :func:`plot_tracks`: tracks alone, in the image plane.
* :func:`plot_map`: a 2-D map such as a DPA accumulated score function or a score image.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib as mpl
import numpy as np
import torch
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from hocnet._check import as_cube, check_int

__all__ = ["plot_before_after", "plot_cube_3d", "plot_dpa", "plot_map", "plot_tracks"]

_SCAN_CMAP = "viridis"
_TRACK_COLORS = mpl.colormaps["tab10"].colors
_CLUTTER_COLOR = "0.6"
_SUPPORT_COLOR = "0.55"
#: More identified tracks than this and the legend shows one generic entry instead of one per track.
_MAX_LEGEND_TRACKS = 12
#: More input points than this and :func:`plot_before_after` draws the input as a density image
#: (points per pixel over the scans) instead of one marker per point, which at real sizes
#: (328k points in 512 x 640 x 100) would merge into one solid block.
MAX_SCATTER_POINTS = 20_000

PathLike = str | os.PathLike


# --------------------------------------------------------------------------------------------
# input helpers
# --------------------------------------------------------------------------------------------


def _scene_cube(name: str, value: Any) -> torch.Tensor:
    """A binary ``(T, H, W)`` cube (a ``(1, T, H, W)`` batch of one is accepted)."""
    cube, batched = as_cube(name, value, binary=True)
    if batched and cube.shape[0] != 1:
        raise ValueError(
            f"`{name}`: expected one scene (T, H, W), got a batch of {cube.shape[0]} scenes; "
            "plot one element at a time"
        )
    return cube[0].cpu()


def _labels_like(labels: Any, cube: torch.Tensor) -> torch.Tensor | None:
    """Validate ``labels`` (integers shaped like ``cube``, batch of one allowed)."""
    if labels is None:
        return None
    if not isinstance(labels, torch.Tensor):
        try:
            labels = torch.as_tensor(labels)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`labels`: expected an integer tensor shaped like the cube, "
                f"got {type(labels).__name__}"
            ) from None
    if labels.dim() == 4 and labels.shape[0] == 1:
        labels = labels[0]
    if labels.is_floating_point() or labels.is_complex():
        raise TypeError(f"`labels`: expected an integer tensor, got dtype {labels.dtype}")
    if tuple(labels.shape) != tuple(cube.shape):
        raise ValueError(
            f"`labels`: expected shape {tuple(cube.shape)} (like the cube), "
            f"got {tuple(labels.shape)}"
        )
    return labels.cpu().long()


def _shape(value: Any) -> tuple[int, int, int]:
    """Validate a ``(T, H, W)`` shape."""
    if isinstance(value, torch.Size):
        value = tuple(value)
    if isinstance(value, str) or not isinstance(value, Sequence) or len(value) != 3:
        raise TypeError(f"`shape`: expected a triple (T, H, W) of positive integers, got {value!r}")
    t, h, w = (check_int(f"shape[{i}]", v, minimum=1) for i, v in enumerate(value))
    return t, h, w


def _points(name: str, track: Any) -> tuple[np.ndarray, int | None, float | None]:
    """``(N, 3)`` int array of ``(t, y, x)`` rows plus the id and score if the track has them.

    Accepts a :class:`~hocnet.hoc.Track` (or anything with ``.points``), a mapping with a
    ``"points"`` key (as returned by :func:`hocnet.data.io.load_tracks_json`), or the points
    themselves as a tensor, array or nested list.
    """
    track_id = score = None
    if isinstance(track, Mapping):
        if "points" not in track:
            raise TypeError(
                f"`{name}`: expected a mapping with a 'points' key, got keys {list(track)}"
            )
        raw, track_id, score = track["points"], track.get("id"), track.get("score")
    elif hasattr(track, "points"):
        raw = track.points
        track_id, score = getattr(track, "id", None), getattr(track, "score", None)
    else:
        raw = track
    if isinstance(raw, torch.Tensor):
        raw = raw.detach().cpu().numpy()
    try:
        arr = np.asarray(raw)
    except (TypeError, ValueError):
        arr = np.asarray([None])  # ragged nested lists: reported below
    if arr.size == 0:
        arr = np.zeros((0, 3))
    if arr.dtype.kind not in "biuf" or arr.ndim != 2 or arr.shape[1] != 3:
        got = f"shape {arr.shape}" if arr.dtype.kind in "biuf" else type(track).__name__
        raise ValueError(f"`{name}`: expected (N, 3) points of (t, y, x), got {got}")
    pts = arr.astype(np.float64)
    if not np.isfinite(pts).all():
        raise ValueError(f"`{name}`: expected finite points, got NaN or inf")
    pts = pts[np.argsort(pts[:, 0], kind="stable")]
    return (
        pts,
        None if track_id is None else int(track_id),
        None if score is None else float(score),
    )


def _track_list(name: str, tracks: Any) -> list[tuple[np.ndarray, int | None, float | None]]:
    if tracks is None:
        return []
    if isinstance(tracks, str | bytes | torch.Tensor | np.ndarray) or not isinstance(
        tracks, Iterable
    ):
        raise TypeError(f"`{name}`: expected a list of tracks, got {type(tracks).__name__}")
    return [_points(f"{name}[{i}]", tr) for i, tr in enumerate(tracks)]


# --------------------------------------------------------------------------------------------
# figure helpers
# --------------------------------------------------------------------------------------------


def _new_figure(figsize: tuple[float, float]) -> Figure:
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _axes(ax: Axes | None, figsize: tuple[float, float], projection: str | None = None) -> Axes:
    if ax is None:
        return _new_figure(figsize).add_subplot(projection=projection)
    if not isinstance(ax, Axes):
        raise TypeError(f"`ax`: expected a matplotlib Axes or None, got {type(ax).__name__}")
    if projection == "3d" and getattr(ax, "name", None) != "3d":
        raise ValueError(f"`ax`: expected a 3-D Axes (projection='3d'), got a {ax.name!r} Axes")
    return ax


def _save(fig: Figure, path: PathLike | None) -> None:
    if path is None:
        return
    if isinstance(path, bytes) or not isinstance(path, str | os.PathLike):
        raise TypeError(f"`path`: expected a str, os.PathLike or None, got {type(path).__name__}")
    target = Path(path)
    if not target.parent.is_dir():
        raise FileNotFoundError(f"`path`: directory '{target.parent}' does not exist")
    fig.savefig(target, dpi=fig.dpi)


def _image_axes(ax: Axes, height: int, width: int) -> None:
    """Pixel axes of an image plane: x right, y down, equal aspect, integer ticks."""
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (pixels)")
    ax.set_ylabel("y (pixels)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))


def _scan_norm(n_scans: int) -> mpl.colors.Normalize:
    return mpl.colors.Normalize(vmin=0, vmax=max(n_scans - 1, 1))


def _scan_colorbar(fig: Figure, ax: Axes, n_scans: int, **kwargs: Any) -> None:
    mappable = mpl.cm.ScalarMappable(norm=_scan_norm(n_scans), cmap=_SCAN_CMAP)
    bar = fig.colorbar(mappable, ax=ax, **kwargs)
    bar.set_label("scan")
    bar.locator = MaxNLocator(integer=True)
    bar.update_ticks()


def _is_false(points: np.ndarray, truth: set[tuple[int, ...]]) -> bool:
    """A track is false when fewer than half of its points lie on true tracks.

    The rule of :func:`hocnet.metrics.false_tracks` with its default fraction 0.5.
    """
    rows = [tuple(int(c) for c in row) for row in points]
    return 2 * sum(row in truth for row in rows) < len(rows)


def _draw_tracks(
    ax: Axes,
    tracks: list[tuple[np.ndarray, int | None, float | None]],
    true_tracks: list[tuple[np.ndarray, int | None, float | None]],
) -> list[Any]:
    """Draw identified tracks (coloured, id at the start, arrow at the end) and true tracks.

    True tracks are dashed black lines drawn on top, so they stay visible where a found track
    follows them. With true tracks given, a found track with fewer than half of its points on
    true tracks is marked "false" in the legend. Returns the legend handles.
    """
    handles: list[Any] = []
    truth_points = {tuple(int(c) for c in row) for pts, _, _ in true_tracks for row in pts}
    false = [bool(true_tracks) and _is_false(pts, truth_points) for pts, _, _ in tracks]
    # Legend: every track up to _MAX_LEGEND_TRACKS; beyond that the false ones first, then the
    # best-scoring ones, and one "+ N more" line, so a false track is never hidden in a count.
    order = sorted(
        range(len(tracks)),
        key=lambda k: (not false[k], -(tracks[k][2] if tracks[k][2] is not None else 0.0), k),
    )
    listed = set(order[:_MAX_LEGEND_TRACKS])
    entries: dict[int, Any] = {}
    for k, (pts, track_id, score) in enumerate(tracks):
        color = _TRACK_COLORS[k % len(_TRACK_COLORS)]
        name = f"{track_id}" if track_id is not None else f"{k + 1}"
        ax.plot(
            pts[:, 2], pts[:, 1], "-o", color=color, lw=2.2, ms=4.5, mec="white", mew=0.6, zorder=3
        )
        if len(pts) > 1:
            # arrow head on the last move: the direction of motion
            ax.annotate(
                "",
                xy=(pts[-1, 2], pts[-1, 1]),
                xytext=(pts[-2, 2], pts[-2, 1]),
                arrowprops={"arrowstyle": "-|>", "color": color, "lw": 2.2, "mutation_scale": 14},
                zorder=3,
            )
        if len(pts):
            # id just before the first point, opposite to the first move
            x0, y0 = pts[0, 2], pts[0, 1]
            dx, dy = (pts[1, 2] - x0, pts[1, 1] - y0) if len(pts) > 1 else (1.0, 0.0)
            norm = max(float(np.hypot(dx, dy)), 1e-9)
            ax.annotate(
                name,
                (x0, y0),
                xytext=(-10 * dx / norm, 10 * dy / norm),
                textcoords="offset points",
                ha="center",
                va="center",
                fontsize=8,
                fontweight="bold",
                color=color,
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": color, "lw": 0.8},
                zorder=6,
            )
        if k in listed:
            text = f"track {name}: {len(pts)} pts"
            if score is not None:
                text += f", score {score:.2f}"
            if false[k]:
                text += " (false)"
            entries[k] = Line2D([], [], marker="o", color=color, lw=2.2, ms=4.5, label=text)
    keys = sorted(entries) if len(tracks) <= _MAX_LEGEND_TRACKS else order[:_MAX_LEGEND_TRACKS]
    handles.extend(entries[k] for k in keys)
    if len(tracks) > len(listed):
        more = len(tracks) - len(listed)
        handles.append(
            Line2D(
                [],
                [],
                marker="o",
                color=_TRACK_COLORS[0],
                lw=2.2,
                label=f"+ {more} more track{'s' * (more != 1)} ({len(tracks)} in all)",
            )
        )
    for pts, _, _ in true_tracks:
        ax.plot(pts[:, 2], pts[:, 1], ls=(0, (3, 2)), lw=1.1, color="black", zorder=5)
    if true_tracks:
        handles.insert(0, Line2D([], [], ls=(0, (3, 2)), lw=1.1, color="black", label="true track"))
    return handles


def _legend(ax: Axes, handles: list[Any], *, outside: bool = True) -> None:
    if not handles:
        return
    if outside:
        ax.legend(
            handles=handles,
            loc="upper left",
            bbox_to_anchor=(1.02, 1.0),
            fontsize=8,
            frameon=False,
            borderaxespad=0.0,
        )
    else:
        ax.legend(handles=handles, loc="best", fontsize=8, framealpha=0.85)


# --------------------------------------------------------------------------------------------
# public functions
# --------------------------------------------------------------------------------------------


def plot_cube_3d(
    cube: torch.Tensor | np.ndarray,
    *,
    labels: torch.Tensor | np.ndarray | None = None,
    true_tracks: Sequence[Any] | None = None,
    track_labels: Sequence[int] | None = None,
    ax: Axes | None = None,
    title: str | None = None,
    path: PathLike | None = None,
) -> Figure:
    """Draw the points of a binary cube as a 3-D cloud over ``(x, y, scan)``.

    With ``labels`` (ground truth, ``0`` = clutter) clutter points are small and grey and each
    target label gets its own colour; without labels every point is coloured by its scan.

    With ``true_tracks`` the legend counts each true track's own points (a point shared by two
    crossing tracks counts for both, as in the tables of ``hocnet demo``), and clutter is every
    point on no true track; with ``labels`` alone a shared point counts once, for the label it
    carries.

    Args:
        cube: ``(T, H, W)`` binary cube (bool or 0/1; a ``(1, T, H, W)`` batch of one is accepted).
        labels: integer cube shaped like ``cube`` (``0`` clutter/empty, ``k >= 1`` target ``k``),
            e.g. :attr:`hocnet.data.binary.BinaryScene.labels`, or ``None``.
        true_tracks: ground-truth tracks, each ``(N, 3)`` points of ``(t, y, x)``
            (e.g. :attr:`~hocnet.data.binary.BinaryScene.tracks`), or ``None``.
        track_labels: the name of each true track in the legend (default ``1, 2, ...``).
        ax: a 3-D axes to draw into (``projection="3d"``); ``None`` makes a new figure.
        title: axes title; ``None`` gives a summary such as ``"Input: 553 points in 10 scans"``.
        path: if given, save the figure there.

    Returns:
        The :class:`~matplotlib.figure.Figure`.

    Examples:
        >>> cube = torch.zeros(4, 8, 8, dtype=torch.bool)
        >>> cube[:, 2, 3] = True
        >>> fig = plot_cube_3d(cube)
        >>> type(fig).__name__, fig.axes[0].get_zlabel()
        ('Figure', 'scan')
    """
    points = _scene_cube("cube", cube)
    lab = _labels_like(labels, points)
    n_scans, height, width = points.shape
    ax = _axes(ax, (7.5, 6.5), projection="3d")
    fig = ax.figure
    t, y, x = (a.numpy() for a in torch.nonzero(points, as_tuple=True))
    handles: list[Any] = []
    truth = _track_list("true_tracks", true_tracks)
    if truth:
        names = list(track_labels) if track_labels is not None else list(range(1, len(truth) + 1))
        if len(names) != len(truth):
            raise ValueError(
                f"`track_labels`: expected one label per true track ({len(truth)}), "
                f"got {len(names)}"
            )
        lab = torch.zeros(points.shape, dtype=torch.int64)
        members = []
        for k, (pts, _, _) in enumerate(truth):
            idx = torch.as_tensor(pts, dtype=torch.int64).reshape(-1, 3)
            inside = (
                (idx >= 0).all(dim=1)
                & (idx[:, 0] < n_scans)
                & (idx[:, 1] < height)
                & (idx[:, 2] < width)
            )
            idx = idx[inside]
            idx = idx[points[idx[:, 0], idx[:, 1], idx[:, 2]]]  # on-points only
            members.append(torch.unique(idx, dim=0))
            lab[idx[:, 0], idx[:, 1], idx[:, 2]] = k + 1
        on_track = lab[points].numpy() > 0
        ax.scatter(
            x[~on_track],
            y[~on_track],
            t[~on_track],
            s=3,
            color=_CLUTTER_COLOR,
            alpha=0.5,
            depthshade=False,
        )
        handles.append(
            Line2D(
                [],
                [],
                ls="",
                marker="o",
                ms=3,
                color=_CLUTTER_COLOR,
                label=f"clutter ({int((~on_track).sum())})",
            )
        )
        for k, idx in enumerate(members):
            color = _TRACK_COLORS[k % len(_TRACK_COLORS)]
            tt, yy, xx = (idx[:, i].numpy() for i in range(3))
            ax.scatter(
                xx, yy, tt, s=26, color=color, edgecolors="black", linewidths=0.4, depthshade=False
            )
            order = np.argsort(tt, kind="stable")
            ax.plot(xx[order], yy[order], tt[order], color=color, lw=1.0, alpha=0.8)
            handles.append(
                Line2D(
                    [],
                    [],
                    lw=1.0,
                    marker="o",
                    ms=6,
                    color=color,
                    mec="black",
                    mew=0.4,
                    label=f"target {names[k]} ({len(idx)})",
                )
            )
    elif lab is None:
        ax.scatter(x, y, t, c=t, cmap=_SCAN_CMAP, norm=_scan_norm(n_scans), s=9, depthshade=False)
        _scan_colorbar(fig, ax, n_scans, shrink=0.6, pad=0.08)
    else:
        point_labels = lab[points].numpy()
        clutter = point_labels == 0
        ax.scatter(
            x[clutter],
            y[clutter],
            t[clutter],
            s=3,
            color=_CLUTTER_COLOR,
            alpha=0.5,
            depthshade=False,
        )
        handles.append(
            Line2D(
                [],
                [],
                ls="",
                marker="o",
                ms=3,
                color=_CLUTTER_COLOR,
                label=f"clutter ({int(clutter.sum())})",
            )
        )
        for k, value in enumerate(np.unique(point_labels[~clutter])):
            sel = point_labels == value
            color = _TRACK_COLORS[k % len(_TRACK_COLORS)]
            ax.scatter(
                x[sel],
                y[sel],
                t[sel],
                s=26,
                color=color,
                edgecolors="black",
                linewidths=0.4,
                depthshade=False,
            )
            if len(np.unique(t[sel])) == int(sel.sum()) > 1:  # one point per scan: join them
                ax.plot(x[sel], y[sel], t[sel], color=color, lw=1.0, alpha=0.8)
            handles.append(
                Line2D(
                    [],
                    [],
                    ls="-" if len(np.unique(t[sel])) == int(sel.sum()) > 1 else "",
                    lw=1.0,
                    marker="o",
                    ms=6,
                    color=color,
                    mec="black",
                    mew=0.4,
                    label=f"target {int(value)} ({int(sel.sum())})",
                )
            )
    ax.set_xlim(0, width - 1)
    ax.set_ylim(height - 1, 0)  # y down, as in the image
    ax.set_zlim(0, max(n_scans - 1, 1))
    ax.set_xlabel("x (pixels)")
    ax.set_ylabel("y (pixels)")
    ax.set_zlabel("scan")
    ax.zaxis.set_major_locator(MaxNLocator(integer=True))
    ax.view_init(elev=22, azim=-60)
    if title is None:
        title = f"Input: {len(t)} points in {n_scans} scans of {height} x {width} pixels"
    ax.set_title(title)
    if handles:
        ax.legend(handles=handles, loc="upper left", fontsize=8, framealpha=0.85)
    _save(fig, path)
    return fig


def plot_before_after(
    frames: torch.Tensor | np.ndarray,
    result_or_cleaned: Any,
    *,
    labels: torch.Tensor | np.ndarray | None = None,
    true_tracks: Sequence[Any] | None = None,
    title: str | None = None,
    path: PathLike | None = None,
) -> Figure:
    """Show the input points next to a detection, in the image plane.

    Left: every input point, coloured by scan (with ``labels``, target points get a black ring);
    above :data:`MAX_SCATTER_POINTS` points, the number of input points per pixel as an image.
    Right: the detection. For a detection result (anything with ``.tracks``, such as
    :class:`hocnet.hoc.HOCResult`) the support points that are on no accepted track are faint
    grey, each identified track is a coloured line with its id at its first point, and the true
    tracks, if given, are dashed black lines. For a plain cube (e.g. a cleaned cube) its points
    are drawn coloured by scan.

    Args:
        frames: ``(T, H, W)`` binary input cube (a batch of one is accepted).
        result_or_cleaned: a result with ``.tracks`` (and optionally ``.support`` and
            ``.cleaned``, ``(T, H, W)`` bool cubes), or a ``(T, H, W)`` binary cube of the kept
            points.
        labels: integer ground-truth labels shaped like ``frames`` (``0`` = clutter), or ``None``.
        true_tracks: ground-truth tracks, each ``(N, 3)`` points of ``(t, y, x)``, or ``None``.
        title: figure title (``None``: none).
        path: if given, save the figure there.

    Returns:
        The :class:`~matplotlib.figure.Figure` with two panels.

    Examples:
        >>> cube = torch.zeros(5, 10, 10, dtype=torch.bool)
        >>> cube[torch.arange(5), 2, torch.arange(5) + 1] = True
        >>> fig = plot_before_after(cube, cube, true_tracks=[[[0, 2, 1], [4, 2, 5]]])
        >>> type(fig).__name__, [ax.get_xlabel() for ax in fig.axes[:2]]
        ('Figure', ['x (pixels)', 'x (pixels)'])
    """
    points = _scene_cube("frames", frames)
    lab = _labels_like(labels, points)
    n_scans, height, width = points.shape
    truth = _track_list("true_tracks", true_tracks)

    if hasattr(result_or_cleaned, "tracks"):
        tracks = _track_list("result_or_cleaned.tracks", result_or_cleaned.tracks)
        support = getattr(result_or_cleaned, "support", None)
        cleaned = getattr(result_or_cleaned, "cleaned", None)
        support = None if support is None else _scene_cube("result_or_cleaned.support", support)
        cleaned = None if cleaned is None else _scene_cube("result_or_cleaned.cleaned", cleaned)
        kept_cube = None
    else:
        tracks, support, cleaned = [], None, None
        kept_cube = _scene_cube("result_or_cleaned", result_or_cleaned)
    for name, other in (("support", support), ("cleaned", cleaned), ("cleaned", kept_cube)):
        if other is not None and other.shape != points.shape:
            raise ValueError(
                f"`result_or_cleaned`: expected a {name} cube of shape {tuple(points.shape)} "
                f"(like `frames`), got {tuple(other.shape)}"
            )

    fig = _new_figure((13.0, 6.0))
    left, right = fig.subplots(1, 2, sharex=True, sharey=True)
    norm = _scan_norm(n_scans)

    # input
    t, y, x = (a.numpy() for a in torch.nonzero(points, as_tuple=True))
    n_in = len(t)
    dense = n_in > MAX_SCATTER_POINTS
    if dense:
        counts = points.sum(dim=0).numpy()
        shown = left.imshow(
            np.ma.masked_equal(counts, 0),
            cmap="magma_r",
            origin="upper",
            interpolation="nearest",
            vmin=1,
            vmax=max(int(counts.max()), 2),
        )
        bar = fig.colorbar(shown, ax=left, location="left", shrink=0.8, pad=0.02)
        bar.set_label(f"input points per pixel (of {n_scans} scans)")
    else:
        left.scatter(x, y, c=t, cmap=_SCAN_CMAP, norm=norm, s=10, zorder=2)
    left_handles: list[Any] = []
    if lab is not None:
        on_target = lab[points].numpy() > 0
        if dense and int(on_target.sum()) > MAX_SCATTER_POINTS:
            on_target = on_target & (np.arange(n_in) % (int(on_target.sum()) // 5000 + 1) == 0)
        left.scatter(
            x[on_target],
            y[on_target],
            s=42,
            facecolors="none",
            edgecolors="black",
            linewidths=0.9,
            zorder=3,
        )
        left_handles.append(
            Line2D(
                [],
                [],
                ls="",
                marker="o",
                ms=7,
                mfc="none",
                mec="black",
                label=f"target point ({int(on_target.sum())})",
            )
        )
        n_target = int((lab[points] > 0).sum())
        left.set_title(
            f"Input: {n_in} points in {n_scans} scans "
            f"({n_in - n_target} clutter, {n_target} target)"
        )
    else:
        left.set_title(f"Input: {n_in} points in {n_scans} scans")
    if dense:
        left.set_title(left.get_title() + "\n(density: too many points to draw one by one)")
    _image_axes(left, height, width)
    if left_handles:
        left.legend(
            handles=left_handles,
            loc="upper center",
            bbox_to_anchor=(0.5, -0.09),
            fontsize=8,
            frameon=False,
        )

    # detection
    right_handles: list[Any] = []
    if kept_cube is not None:
        kt, ky, kx = (a.numpy() for a in torch.nonzero(kept_cube, as_tuple=True))
        right.scatter(kx, ky, c=kt, cmap=_SCAN_CMAP, norm=norm, s=12, zorder=2)
        right.set_title(f"Detection: {len(kt)} of {n_in} points kept")
        right_handles += _draw_tracks(right, [], truth)
    else:
        if support is not None:
            faint = support & ~cleaned if cleaned is not None else support
            st, sy, sx = (a.numpy() for a in torch.nonzero(faint, as_tuple=True))
            if len(st) > MAX_SCATTER_POINTS:  # draw each pixel once, not each (scan, pixel)
                sy, sx = (a.numpy() for a in torch.nonzero(faint.any(dim=0), as_tuple=True))
            right.scatter(sx, sy, s=9, color=_SUPPORT_COLOR, alpha=0.45, zorder=1, rasterized=True)
            right_handles.append(
                Line2D(
                    [],
                    [],
                    ls="",
                    marker="o",
                    ms=4,
                    color=_SUPPORT_COLOR,
                    alpha=0.6,
                    label=f"support, on no track ({len(st)})",
                )
            )
        right_handles += _draw_tracks(right, tracks, truth)
        kept = int(cleaned.sum()) if cleaned is not None else None
        summary = f"Detection: {len(tracks)} track{'s' if len(tracks) != 1 else ''}"
        if kept is not None:
            summary += f", {kept} of {n_in} points on tracks"
        right.set_title(summary)
    _image_axes(right, height, width)
    right.yaxis.set_tick_params(labelleft=True)
    _legend(right, right_handles)
    if not dense:
        _scan_colorbar(fig, left, n_scans, location="left", shrink=0.8, pad=0.02)
    if title is not None:
        fig.suptitle(title)
    _save(fig, path)
    return fig


def plot_tracks(
    tracks: Sequence[Any],
    shape: Sequence[int],
    *,
    true_tracks: Sequence[Any] | None = None,
    ax: Axes | None = None,
    title: str | None = None,
    path: PathLike | None = None,
) -> Figure:
    """Draw tracks in the image plane of a ``(T, H, W)`` cube.

    Each track is a coloured line through its points (ordered by scan) with its id at its first
    point; true tracks, if given, are dashed black lines.

    Args:
        tracks: identified tracks: :class:`hocnet.hoc.Track` objects, dicts with ``"points"``
            (and optional ``"id"``, ``"score"``) as from :func:`hocnet.data.io.load_tracks_json`,
            or ``(N, 3)`` arrays of ``(t, y, x)`` rows.
        shape: ``(T, H, W)`` of the cube the tracks come from (sets the axes to ``W x H`` pixels).
        true_tracks: ground-truth tracks in the same forms, or ``None``.
        ax: axes to draw into; ``None`` makes a new figure.
        title: axes title; ``None`` gives ``"<K> tracks"``.
        path: if given, save the figure there.

    Returns:
        The :class:`~matplotlib.figure.Figure`.

    Examples:
        >>> fig = plot_tracks([], (5, 10, 10))
        >>> type(fig).__name__
        'Figure'
        >>> fig = plot_tracks([torch.tensor([[0, 1, 1], [1, 2, 3]])], (5, 10, 10))
        >>> fig.axes[0].get_title()
        '1 track'
    """
    _, height, width = _shape(shape)
    drawn = _track_list("tracks", tracks)
    truth = _track_list("true_tracks", true_tracks)
    ax = _axes(ax, (8.5, 6.0))
    handles = _draw_tracks(ax, drawn, truth)
    _image_axes(ax, height, width)
    ax.set_title(title if title is not None else f"{len(drawn)} track{'s' * (len(drawn) != 1)}")
    _legend(ax, handles)
    _save(ax.figure, path)
    return ax.figure


def plot_map(
    image: torch.Tensor | np.ndarray,
    *,
    ax: Axes | None = None,
    title: str | None = None,
    colorbar: bool = True,
    path: PathLike | None = None,
) -> Figure:
    """Show a 2-D map (e.g. an accumulated score function) as an image with pixel axes.

    Args:
        image: ``(H, W)`` real or boolean tensor or array. NaN entries are left blank (e.g. the
            ``scores`` cube of :func:`hocnet.hoc.detect` where no triple passes).
        ax: axes to draw into; ``None`` makes a new figure.
        title: axes title, or ``None``.
        colorbar: add a colour bar.
        path: if given, save the figure there.

    Returns:
        The :class:`~matplotlib.figure.Figure`.

    Examples:
        >>> fig = plot_map(torch.arange(12.0).reshape(3, 4), title="ramp")
        >>> type(fig).__name__, fig.axes[0].get_title(), len(fig.axes)
        ('Figure', 'ramp', 2)
    """
    if not isinstance(image, torch.Tensor):
        try:
            image = torch.as_tensor(np.asarray(image))
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`image`: expected a 2-D tensor or array (H, W), got {type(image).__name__}"
            ) from None
    if image.is_complex() or not (image.is_floating_point() or image.dtype in _REAL_DTYPES):
        raise TypeError(f"`image`: expected a real or boolean tensor, got dtype {image.dtype}")
    if image.dim() != 2 or image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"`image`: expected shape (H, W), got {tuple(image.shape)}")
    data = image.detach().cpu().double().numpy()
    ax = _axes(ax, (6.5, 5.5))
    shown = ax.imshow(
        np.ma.masked_invalid(data), cmap="viridis", origin="upper", interpolation="nearest"
    )
    height, width = data.shape
    _image_axes(ax, height, width)
    if title is not None:
        ax.set_title(title)
    if colorbar:
        ax.figure.colorbar(shown, ax=ax, shrink=0.85)
    _save(ax.figure, path)
    return ax.figure


_REAL_DTYPES = (torch.bool, torch.uint8, torch.int8, torch.int16, torch.int32, torch.int64)


def plot_dpa(
    frames: torch.Tensor | np.ndarray,
    asf: torch.Tensor | np.ndarray,
    tracks: Sequence[torch.Tensor] = (),
    *,
    scores: Sequence[float] | None = None,
    truth: torch.Tensor | np.ndarray | None = None,
    title: str | None = None,
    path: PathLike | None = None,
) -> Figure:
    """DPA result at a glance: the last frame with back-tracked tracks, and the last ASF map.

    Every track is drawn (line and a dot per frame, so a track that stays in one pixel is
    visible too, and a circle at its last position on both panels) and listed in the legend,
    with its score when ``scores`` is given, so that a weak (possibly false) track is not
    mistaken for a strong one.

    Args:
        frames: ``(T, H, W)`` (whitened) frames; the last one is shown.
        asf: ``(T, H, W)`` accumulated score function; the last frame is shown.
        tracks: back-tracked trajectories, each ``(T, 2)`` as ``(x, y)`` per frame.
        scores: one score per track (e.g. :attr:`hocnet.dpa.DPATrack.score`), or ``None``.
        truth: optional true positions ``(N, T, 2)`` or ``(T, 2)`` as ``(x, y)`` (dashed).
        title: figure title.
        path: if given, save the figure there.

    Returns:
        The :class:`~matplotlib.figure.Figure`.

    Examples:
        >>> fig = plot_dpa(torch.zeros(3, 8, 8), torch.zeros(3, 8, 8), [torch.zeros(3, 2)])
        >>> type(fig).__name__, len(fig.axes)
        ('Figure', 4)
    """
    frames_np = np.asarray(torch.as_tensor(frames).detach().cpu().float())
    asf_np = np.asarray(torch.as_tensor(asf).detach().cpu().float())
    if frames_np.ndim != 3 or asf_np.shape != frames_np.shape:
        raise ValueError(
            "`asf`: expected (T, H, W) frames and ASF of the same shape, got "
            f"{frames_np.shape} and {asf_np.shape}"
        )
    fig = _new_figure((11, 4.8))
    ax_frame, ax_asf = fig.subplots(1, 2)
    n_t = frames_np.shape[0]
    for ax, image, name in (
        (ax_frame, frames_np[-1], f"last frame (t = {n_t - 1}) with back-tracked tracks"),
        (ax_asf, asf_np[-1], "last-frame accumulated score (ASF)"),
    ):
        shown = ax.imshow(image, cmap="gray" if ax is ax_frame else "magma", origin="upper")
        fig.colorbar(shown, ax=ax, shrink=0.85)
        ax.set_title(name)
        ax.set_xlabel("x (pixels)")
        ax.set_ylabel("y (pixels)")
    if scores is not None:
        scores = [float(v) for v in scores]
        if len(scores) != len(tracks):
            raise ValueError(
                f"`scores`: expected one score per track ({len(tracks)}), got {len(scores)}"
            )
    colours = _colours(len(tracks))
    for i, tr in enumerate(tracks):
        xy = np.asarray(torch.as_tensor(tr).detach().cpu().float()).reshape(-1, 2)
        label = f"track {i + 1}"
        if scores is not None:
            label += f": score {scores[i]:.3g}"
        if len(xy) == 0:
            continue
        ax_frame.plot(
            xy[:, 0], xy[:, 1], "-o", color=colours[i], lw=1.8, ms=2.5, label=label, zorder=3
        )
        ax_frame.plot(xy[-1, 0], xy[-1, 1], "o", color=colours[i], mfc="none", ms=10, zorder=3)
        ax_asf.plot(xy[-1, 0], xy[-1, 1], "o", color=colours[i], mfc="none", ms=10)
    if truth is not None:
        true_np = np.asarray(torch.as_tensor(truth).detach().cpu().float())
        for k, xy in enumerate(true_np.reshape(-1, n_t, 2)):
            ax_frame.plot(
                xy[:, 0], xy[:, 1], "--", color="cyan", lw=1.2, label="truth" if k == 0 else None
            )
    if tracks or truth is not None:
        handles, labels = ax_frame.get_legend_handles_labels()
        fig.legend(
            handles, labels, loc="outside lower center", ncols=min(4, len(labels)), fontsize=8
        )
    if title:
        fig.suptitle(title)
    if path is not None:
        fig.savefig(path)
    return fig


def _colours(n: int) -> list[Any]:
    """``n`` distinct colours from matplotlib's tab10 / tab20 cycles."""
    cmap = mpl.colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]

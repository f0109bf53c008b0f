"""Shared helpers of the experiment scripts: seeds, mean ± std, tables, files, progress, CLI.

The experiment scripts load this module by file path (they are themselves imported by file path
by ``hocnet reproduce``), so it must not depend on ``experiments`` being a package.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import math
import pathlib
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any, TypeVar

import matplotlib

matplotlib.use("Agg")

from tqdm.auto import tqdm

T = TypeVar("T")

RESULTS_DIR = pathlib.Path(__file__).resolve().parent / "results"
"""Default output folder: ``experiments/results``."""

FULL_SEEDS = 20
"""Scenes per setting in a full run (the paper used one or six)."""

QUICK_SEEDS = 2
"""Scenes per setting in a quick (smoke) run."""

PAPER_NA_NOTE = (
    "n/a: [NR08] prints no value for this (its text is in ../shared/papers/NR08-dpa-tbd.txt); "
    "a `paper` column appears only where the paper prints the value."
)


def n_seeds(quick: bool, seeds: int | None) -> int:
    """Scenes per setting: ``seeds`` if given, else 2 (quick) or 20 (full).

    Examples:
        >>> n_seeds(False, None), n_seeds(True, None), n_seeds(True, 5)
        (20, 2, 5)
    """
    if seeds is not None:
        if int(seeds) < 1:
            raise ValueError(f"`seeds`: expected an integer >= 1, got {seeds}")
        return int(seeds)
    return QUICK_SEEDS if quick else FULL_SEEDS


def seed_list(base: int, n: int) -> list[int]:
    """Seeds ``base, base + 1, ..., base + n - 1`` (one per scene).

    Examples:
        >>> seed_list(100, 3)
        [100, 101, 102]
    """
    return [base + i for i in range(n)]


def quick_dir(name: str) -> pathlib.Path:
    """A fresh temporary folder for a quick (smoke) run's outputs."""
    import tempfile

    return pathlib.Path(tempfile.mkdtemp(prefix=f"hocnet-{name}-quick-"))


def out_dir_of(out_dir: pathlib.Path | str | None, *, quick: bool | None = None) -> pathlib.Path:
    """The output folder (created if needed).

    ``out_dir`` if given (also ``experiments/results`` given by hand); else :data:`RESULTS_DIR`
    for a full run, and a fresh temporary folder for a quick run, so that smoke numbers never
    replace the committed full results. ``quick=None`` reads the calling ``run``'s own ``quick``
    argument (the experiment scripts call ``out_dir_of(out_dir)`` from ``run(quick=...)``).

    Examples:
        >>> out_dir_of(None, quick=True) != RESULTS_DIR
        True
    """
    if out_dir is not None:
        if not str(out_dir).strip():
            raise ValueError(f"`out_dir`: expected a folder name, got {str(out_dir)!r}")
        path = pathlib.Path(out_dir)
    else:
        if quick is None:
            caller = sys._getframe(1).f_locals.get("quick")
            quick = caller if isinstance(caller, bool) else False
        path = quick_dir("experiment") if quick else RESULTS_DIR
    path.mkdir(parents=True, exist_ok=True)
    return path


def strict_out_dir_of(
    out: str | None, *, quick: bool, error: Callable[[str], Any]
) -> pathlib.Path | None:
    """:func:`out_dir_of` for scripts that write only with ``--out``, stricter on quick runs.

    ``None`` without ``out``; otherwise the folder (created). ``error`` (an argparse ``error``)
    is called for an empty name, and for a ``--quick`` run aimed into ``experiments/results``
    even when asked by hand (the diagnostic scripts' results there are notes made from full runs).

    Examples:
        >>> strict_out_dir_of(None, quick=True, error=print) is None
        True
    """
    if out is None:
        return None
    if not str(out).strip():
        error("--out: expected a folder name, got an empty string")
    if quick and pathlib.Path(out).resolve().is_relative_to(RESULTS_DIR.resolve()):
        error(f"--out: a --quick run does not write into {RESULTS_DIR}, got {out}")
    return out_dir_of(out, quick=quick)


def mean_std(values: Iterable[float], digits: int = 3, scale: float = 1.0) -> str:
    """Format ``mean ± std`` (sample std, ``ddof = 1``); one value alone, with ``(n = 1)``.

    A single value has no spread to report, so it is printed without a misleading ``± 0``.

    Examples:
        >>> mean_std([1.0, 2.0, 3.0], digits=2)
        '2.00 ± 1.00'
        >>> mean_std([0.5], digits=1, scale=100)
        '50.0 (n = 1)'
    """
    xs = [float(v) * scale for v in values]
    if not xs:
        return "n/a"
    m = sum(xs) / len(xs)
    s = math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1)) if len(xs) > 1 else 0.0
    return format_mean_std(m, s, len(xs), digits)


def format_mean_std(m: float, s: float, n: int, digits: int = 3) -> str:
    """Format an already computed mean and std of ``n`` values (``n = 1``: the value alone).

    Examples:
        >>> format_mean_std(2.0, 0.5, 3, 2), format_mean_std(2.0, 0.0, 1, 2)
        ('2.00 ± 0.50', '2.00 (n = 1)')
    """
    if n < 1:
        return "n/a"
    if n == 1:
        return f"{m:.{digits}f} (n = 1)"
    return f"{m:.{digits}f} ± {s:.{digits}f}"


def mean(values: Iterable[float]) -> float:
    """Arithmetic mean (NaN for no values).

    Examples:
        >>> mean([1, 2])
        1.5
    """
    xs = [float(v) for v in values]
    return sum(xs) / len(xs) if xs else math.nan


def std(values: Iterable[float]) -> float:
    """Sample standard deviation (``ddof = 1``; 0 for one value, NaN for none).

    Examples:
        >>> std([1, 2, 3])
        1.0
    """
    xs = [float(v) for v in values]
    if not xs:
        return math.nan
    if len(xs) == 1:
        return 0.0
    m = sum(xs) / len(xs)
    return math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1))


def pct(value: float, digits: int = 2) -> str:
    """Format a fraction as a percentage.

    Examples:
        >>> pct(0.0123)
        '1.23 %'
    """
    return f"{100 * value:.{digits}f} %"


def md_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A GitHub markdown table.

    Examples:
        >>> print(md_table(["a", "b"], [[1, "x"]]))
        | a | b |
        |---|---|
        | 1 | x |
    """
    lines = ["| " + " | ".join(str(h) for h in headers) + " |"]
    lines.append("|" + "|".join("---" for _ in headers) + "|")
    lines.extend("| " + " | ".join(str(c) for c in row) + " |" for row in rows)
    return "\n".join(lines)


def write_csv(path: pathlib.Path, rows: Sequence[dict[str, Any]]) -> pathlib.Path:
    """Write dict rows (the union of their keys, in first-seen order) to a CSV file."""
    fields: list[str] = []
    for row in rows:
        fields.extend(k for k in row if k not in fields)
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _csv_value(v) for k, v in row.items()})
    return path


def _csv_value(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


def write_text(path: pathlib.Path, text: str) -> pathlib.Path:
    """Write ``text`` (with a trailing newline) to ``path``."""
    path.write_text(text.rstrip("\n") + "\n")
    return path


def progress(
    iterable: Iterable[T], *, enabled: bool, desc: str, total: int | None = None
) -> Iterator[T]:
    """Wrap ``iterable`` in a tqdm progress bar (on stderr) when ``enabled``."""
    if not enabled:
        yield from iterable
        return
    yield from tqdm(iterable, desc=desc, total=total, leave=False, dynamic_ncols=True)


@contextlib.contextmanager
def single_thread() -> Iterator[None]:
    """Run torch single-threaded inside the block (the previous thread count is restored).

    The sparse HOC path is many small tensor operations; on a shared 2-core CPU the intra-op
    thread pool spends most of its time waiting (measured 10-100x slower than one thread while
    other processes were busy), so the experiments run with one torch thread.
    """
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


class Timer:
    """Wall-clock timer used as a context manager; ``seconds`` after exit.

    Examples:
        >>> with Timer() as timer:
        ...     pass
        >>> timer.seconds >= 0
        True
    """

    def __enter__(self) -> Timer:
        self._start = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc: object) -> None:
        self.seconds = time.perf_counter() - self._start


def header(
    title: str, description: str, *, quick: bool, n: int, seconds: float | None = None
) -> str:
    """Common top of a results markdown file."""
    mode = "quick (smoke) run" if quick else "full run"
    lines = [f"# {title}", "", description, "", f"- Mode: {mode}, {n} seeded scenes per setting."]
    if seconds is not None:
        lines.append(f"- Runtime: {seconds:.1f} s (wall clock, shared 2-core CPU).")
    return "\n".join(lines)


def main_for(
    name: str,
    description: str,
    run: Callable[..., pathlib.Path],
    argv: Sequence[str] | None = None,
) -> pathlib.Path:
    """The command line of an experiment script: ``--quick``, ``--seeds N``, ``--out DIR``."""
    parser = argparse.ArgumentParser(prog=name, description=description)
    parser.add_argument("--quick", action="store_true", help="small smoke run (2 seeds)")
    parser.add_argument("--seeds", type=int, default=None, help="scenes per setting")
    parser.add_argument(
        "--out",
        default=None,
        help=f"output folder (default: {RESULTS_DIR} for a full run, a new temporary folder "
        "for --quick; give the results folder by hand to overwrite it with a quick run)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    if args.out is not None and not str(args.out).strip():
        parser.error("--out: expected a folder name, got an empty string")
    out = args.out
    if out is None and args.quick:
        out = quick_dir(name)  # never over the committed full results
        print(f"{name}: quick run, writing to {out}", file=sys.stderr)
    return run(quick=args.quick, seeds=args.seeds, out_dir=out, progress=not args.no_progress)


# ----------------------------------------------------------------------------- HOC evaluation


def hoc_scene_metrics(
    cube: Any,
    target_mask: Any,
    true_tracks: Sequence[Any],
    result: Any,
    *,
    min_points: int,
) -> dict[str, Any]:
    """Point and track metrics of one HOC result (``hocnet.hoc.HOCResult``) on one scene.

    Returns a dict with the input counts, the points remaining / clutter rejection / target
    points lost after the chain support (``hoc_*``) and after track identification (``id_*``),
    the number of tracks found, the true tracks found (``track_recall`` with the default 80 %
    overlap, tracks with fewer than ``min_points`` points not evaluated), the false tracks
    (< 50 % target points) and the other tracks (mostly target points, but not the match of
    any true track: fragments, duplicates, and chains zig-zagging between close tracks).
    """
    from hocnet import metrics

    clutter = cube & ~target_mask
    recall = metrics.track_recall(true_tracks, result.tracks, min_points=min_points)
    row: dict[str, Any] = {
        "input_points": int(cube.sum()),
        "input_clutter": int(clutter.sum()),
        "input_target": int((cube & target_mask).sum()),
    }
    for key, out in (("hoc", result.support), ("id", result.cleaned)):
        row[f"{key}_remaining"] = metrics.points_remaining(out)
        row[f"{key}_clutter_remaining"] = int((clutter & out).sum())
        row[f"{key}_rejection"] = metrics.clutter_rejection(cube, out, target_mask)
        row[f"{key}_target_lost"] = metrics.target_points_lost(cube, out, target_mask)
    row["tracks_found"] = len(result.tracks)
    row["true_evaluated"] = recall.n_evaluated
    row["true_found"] = recall.n_found
    row["false_tracks"] = metrics.false_tracks(result.tracks, target_mask)
    matched = {m for m, f in zip(recall.matched, recall.found) if f}
    row["other_tracks"] = len(result.tracks) - len(matched) - row["false_tracks"]
    row["found_flags"] = recall.found
    return row


# ----------------------------------------------------------------------------- plotting


def plot_scene_xy(
    ax: Any,
    cube: Any,
    target_mask: Any,
    true_tracks: Sequence[Any],
    result: Any,
    *,
    title: str,
    point_size: float = 1.0,
) -> None:
    """x-y view of one scene: input points, HOC support, identified and true tracks.

    Identified tracks with at least half target points are drawn blue, false tracks red; true
    tracks are dashed black on top.
    """
    import torch

    _, y, x = cube.nonzero(as_tuple=True)
    ax.scatter(x, y, s=point_size, color="0.78", label="input points", rasterized=True)
    _, ys, xs = result.support.nonzero(as_tuple=True)
    ax.scatter(
        xs,
        ys,
        s=4 * point_size + 2,
        color="tab:orange",
        label="HOC support",
        rasterized=True,
    )
    shown = {"true": False, "false": False}
    for tr in result.tracks:
        p = tr.points
        hits = target_mask[p[:, 0], p[:, 1], p[:, 2]].to(torch.float64).mean()
        kind = "true" if float(hits) >= 0.5 else "false"
        colour = "tab:blue" if kind == "true" else "tab:red"
        label = None
        if not shown[kind]:
            label = "identified track (target)" if kind == "true" else "false track"
            shown[kind] = True
        ax.plot(p[:, 2], p[:, 1], "-", color=colour, lw=2.6, alpha=0.75, label=label)
    for i, tr in enumerate(true_tracks):
        ax.plot(tr[:, 2], tr[:, 1], "--", color="k", lw=0.9, label="true track" if i == 0 else None)
    ax.set_xlim(-0.5, cube.shape[-1] - 0.5)
    ax.set_ylim(cube.shape[-2] - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (column)")
    ax.set_ylabel("y (row)")
    ax.set_title(f"{title}\n{x.numel()} input points, {xs.numel()} on the HOC support")


# ----------------------------------------------------------------------------- DPA [NR08]

DPA_SCENES = ("NA23A-like", "NPA-like")
"""The two simulated scene families of the DPA experiments (``hocnet.data.infrared``)."""

# The paper's printed values (Table 2, eq. 15, ...) and the set-up of the [NR08] experiments live in
# ``_nr08.py`` (an earlier copy here, with a stale ``DPA_MATRICES`` of (7, 2.5) matrices, was
# removed: ``_nr08.MATRIX`` / ``_nr08.weights`` give the matrices of section 3).


def dpa_scene(
    scene: str,
    seeds: Sequence[int],
    *,
    shape: tuple[int, int, int] = (25, 64, 64),
    snr_db: float | None = None,
    speed: float | None = None,
) -> Any:
    """One simulated sequence per seed, stacked into a batched ``IRSequence``.

    Each scene is ``na23a_like(..., seed=s)`` or ``npa_like(..., seed=s)`` on its own, so a scene
    depends on its seed only (a quick run's scenes are the first scenes of a full run).

    Args:
        scene: ``"NA23A-like"`` or ``"NPA-like"``.
        seeds: one seed per scene.
        shape: ``(T, H, W)``.
        snr_db: peak SNR in dB (default: the preset's, Table 2's peak of [NR08] read as a
            peak-to-noise ratio; see ``hocnet.data.infrared``).
        speed: target speed in px/frame (default: the simulator's, 0.3 / 0.2).

    Returns:
        ``hocnet.data.infrared.IRSequence`` with a leading batch axis of ``len(seeds)``.
    """
    from hocnet.data.infrared import na23a_like, npa_like

    make = {"NA23A-like": na23a_like, "NPA-like": npa_like}[scene]
    kwargs: dict[str, Any] = {"shape": shape}
    if snr_db is not None:
        kwargs["snr_db"] = snr_db
    if speed is not None:
        kwargs["speed"] = speed
    return stack_sequences([make(seed=int(s), **kwargs) for s in seeds])


def stack_sequences(parts: Sequence[Any]) -> Any:
    """Stack unbatched ``IRSequence`` s (same shape and targets) into one batched sequence."""
    import torch

    from hocnet.data.infrared import IRSequence

    return IRSequence(
        frames=torch.stack([p.frames for p in parts]),
        positions=torch.stack([p.positions for p in parts]),
        target_free=torch.stack([p.target_free for p in parts]),
        clouds=torch.stack([p.clouds for p in parts]),
        jitter=torch.stack([p.jitter for p in parts]),
        targets=parts[0].targets,
        noise_sigma=parts[0].noise_sigma,
    )


def scene_speed(scene: str) -> float:
    """Default target speed (px/frame) of a DPA scene family: 0.3 (NA23A) or 0.2 (NPA)."""
    import inspect

    from hocnet.data.infrared import na23a_like, npa_like

    make = {"NA23A-like": na23a_like, "NPA-like": npa_like}[scene]
    return float(inspect.signature(make).parameters["speed"].default)


def dpa_tracked(trajectory: Any, positions: Any) -> tuple[Any, Any]:
    """Whether a back-tracked trajectory follows one of the true targets.

    ``hocnet.dpa.tracking_success`` (within 1.5 px in >= 80 % of the frames) against every
    target; the trajectory "tracks" when it follows at least one of them.

    Args:
        trajectory: ``(B, T, 2)`` back-tracked ``(x, y)``.
        positions: ``(B, N, T, 2)`` true ``(x, y)``.

    Returns:
        ``(tracked, which)``: bool ``(B,)`` and int64 ``(B,)`` index of the first target
        followed (-1 if none).
    """
    import torch

    from hocnet.dpa import tracking_success

    hits = torch.stack(
        [tracking_success(trajectory, positions[:, n]) for n in range(positions.shape[1])], dim=1
    )
    tracked = hits.any(dim=1)
    which = torch.where(tracked, hits.to(torch.int64).argmax(dim=1), -1)
    return tracked, which


def b_ranges(bs: Sequence[float], rates: Sequence[float], level: float = 0.5) -> str:
    """The b intervals (runs of consecutive grid values) whose rate is at least ``level``.

    Examples:
        >>> b_ranges([0.0, 0.2, 0.4, 0.6, 0.8], [0.2, 0.5, 0.9, 0.1, 0.6])
        '0.2-0.4, 0.8'
        >>> b_ranges([0.0, 1.0], [0.0, 0.4])
        'none'
    """
    runs: list[list[float]] = []
    previous = False
    for b, rate in zip(bs, rates):
        ok = rate >= level - 1e-12
        if ok and previous:
            runs[-1].append(b)
        elif ok:
            runs.append([b])
        previous = ok
    if not runs:
        return "none"
    return ", ".join(f"{r[0]:g}" if len(r) == 1 else f"{r[0]:g}-{r[-1]:g}" for r in runs)


def whiten(frames: Any, method: str = "anti_mean") -> Any:
    """Whiten ``(B, T, H, W)`` frames by ``anti_mean`` or ``anti_median`` (7 x 7 ring, 3 x 3 guard).

    Args:
        frames: intensities ``(B, T, H, W)``.
        method: ``"anti_mean"`` or ``"anti_median"`` (``hocnet.data.whitening``).

    Returns:
        The whitened frames, same shape.
    """
    from hocnet.data import whitening

    return {"anti_mean": whitening.anti_mean, "anti_median": whitening.anti_median}[method](frames)


def plot_band(
    ax: Any, x: Sequence[float], m: Sequence[float], s: Sequence[float], **kwargs: Any
) -> None:
    """A mean curve with a shaded mean ± std band (``kwargs`` go to ``ax.plot``)."""
    (line,) = ax.plot(x, m, **kwargs)
    low = [a - b for a, b in zip(m, s)]
    high = [a + b for a, b in zip(m, s)]
    ax.fill_between(x, low, high, color=line.get_color(), alpha=0.18, linewidth=0)


def blockwise_score(
    asf: Any, positions: Any, max_numbers: Sequence[int], *, last: int = 6, block: int = 5
) -> dict[int, Any]:
    """A_S under an alternative reading of eq. (16): Max_Numbers applied to every block.

    ``hocnet.dpa.algorithm_score`` averages the ``max_numbers`` highest values of the *target*
    block only and takes the background mean and std over all pixels of the 8 surrounding
    blocks, so its A_S can only fall as Max_Numbers grows. In this reading every one of the
    3 x 3 blocks is summarised by the mean of its ``max_numbers`` highest values, and
    ``Block_SNR = (target value - mean of the 8 background values) / std of the 8 background
    values`` (population std). Background blocks reaching outside the frame are left out. The
    score is the mean over the last ``last`` frames and over the targets, as in eq. (17).

    Args:
        asf: ``(B, T, H, W)`` ASF.
        positions: true ``(x, y)`` ``(B, N, T, 2)``.
        max_numbers: the Max_Numbers values to evaluate (each ``1 .. block**2``).
        last: number of final frames averaged.
        block: odd block size.

    Returns:
        ``{max_numbers: (B,) float64 scores}``.
    """
    import torch

    bsz, n_t = asf.shape[:2]
    n_targets = positions.shape[1]
    half = block // 2
    reach = block + half  # half-width of the 3 x 3 blocks
    images = asf[:, n_t - last :].detach().double()  # (B, L, H, W)
    padded = torch.nn.functional.pad(images, (reach,) * 4, value=float("nan"))
    xy = torch.floor(positions[:, :, n_t - last :].double() + 0.5).long()  # (B, N, L, 2)
    off = torch.arange(-reach, reach + 1)
    rows = (xy[..., 1, None] + reach + off)[..., :, None]  # (B, N, L, 3b, 1)
    cols = (xy[..., 0, None] + reach + off)[..., None, :]  # (B, N, L, 1, 3b)
    b_idx = torch.arange(bsz).view(bsz, 1, 1, 1, 1)
    l_idx = torch.arange(last).view(1, 1, last, 1, 1)
    patch = padded[b_idx, l_idx, rows, cols]  # (B, N, L, 3b, 3b)
    k = bsz * n_targets * last
    blocks = patch.reshape(k, 3, block, 3, block).permute(0, 1, 3, 2, 4).reshape(k, 9, -1)
    valid = ~torch.isnan(blocks).any(dim=-1)  # (K, 9) block fully inside the frame
    ordered = blocks.nan_to_num(nan=-math.inf).sort(dim=-1, descending=True).values
    out = {}
    for m in max_numbers:
        value = ordered[..., :m].mean(dim=-1)  # (K, 9)
        target = value[:, 4]
        bg = torch.cat([value[:, :4], value[:, 5:]], dim=1)
        ok = torch.cat([valid[:, :4], valid[:, 5:]], dim=1)
        count = ok.sum(dim=1).clamp_min(1)
        bg = bg.masked_fill(~ok, 0.0)
        mean_bg = bg.sum(dim=1) / count
        var = ((bg - mean_bg[:, None]).masked_fill(~ok, 0.0) ** 2).sum(dim=1) / count
        snr = (target - mean_bg) / var.sqrt().clamp_min(1e-12)
        out[m] = snr.view(bsz, n_targets * last).mean(dim=1)
    return out


def config_table(
    configs: Sequence[str],
    densities: Sequence[float],
    select: Callable[[float, str], list[dict]],
    paper_hoc: dict[float, float],
    paper_id: dict[float, float],
) -> str:
    """Side-by-side table of HOC configurations (k = 2) and the paper's printed row.

    ``select(density, config)`` gives the result rows of one cell; each row has
    ``hoc_rejection``, ``id_rejection`` (fractions) and ``id_target_lost``.
    """
    headers = ["configuration (k = 2)"]
    for d in densities:
        headers += [f"{pct(d, 1)}: after HOC (%)", f"{pct(d, 1)}: after identification (%)"]
    headers.append("target points lost (total)")
    body = [
        ["[LA98] as printed"]
        + [x for d in densities for x in (f"{paper_hoc[d]:.2f}", f"{paper_id[d]:.2f}")]
        + ["0"]
    ]
    for config in configs:
        cells = [config]
        lost = 0
        for d in densities:
            sel = select(d, config)
            cells.append(mean_std([r["hoc_rejection"] for r in sel], 2, scale=100))
            cells.append(mean_std([r["id_rejection"] for r in sel], 2, scale=100))
            lost += sum(r["id_target_lost"] for r in sel)
        cells.append(str(lost))
        body.append(cells)
    return md_table(headers, body)


# ----------------------------------------------------------------------------- engines (Ray)

ENGINES = ("loop", "ray")
"""Engines of the grid experiments: ``loop`` (here, one job after the other; the default) and
``ray`` (one Ray Tune trial per job through ``hocnet.sweep.run_sweep``, the ``sweep`` extra)."""

ENGINE_HELP = (
    " Engine options: --engine {loop,ray} (default loop; ray: Ray Tune via hocnet.sweep, the "
    "sweep extra), --ray-dir DIR (Ray's experiment folder), --resume (continue it), "
    "--address ADDRESS (join a Ray cluster), --num-cpus N (local Ray instance)."
)


def check_engine(engine: str) -> str:
    """``engine`` if it is one of :data:`ENGINES`, else a ValueError naming it."""
    if engine not in ENGINES:
        raise ValueError(f"`engine`: expected 'loop' or 'ray', got {engine!r}")
    return engine


def ray_map(
    script: str | pathlib.Path,
    function: str,
    jobs: Sequence[Any],
    shared: dict[str, Any],
    *,
    name: str,
    progress: bool = True,
    path: str | pathlib.Path | None = None,
    resume: bool = False,
    address: str | None = None,
    num_cpus: int | None = None,
) -> list[Any]:
    """``[script.function(job, **shared) for job in jobs]``, one Ray Tune trial per job.

    The trial (a closure, which Ray ships by value) imports the experiment ``script`` by its
    file stem from the script's folder in the worker, runs ``function`` single-threaded and
    reports its JSON-encoded result; ``shared`` goes to every trial as Ray's ``settings``
    (pickled, not JSON). Results come back in the order of ``jobs``, JSON-decoded (tuples become
    lists; floats, ints, strings and NaN are exact).

    Args:
        script: path of the experiment script (``__file__``).
        function: name of a module-level function ``f(job, **shared)`` of the script.
        jobs: picklable jobs.
        shared: keyword arguments of every call.
        name: experiment name (default Ray folder: a new temporary ``<name>-ray-*/<name>``).
        progress: Ray's progress table (``False``: quiet).
        path: Ray's experiment folder (``run_sweep``'s ``path``; ``None``: a new temporary one).
        resume: continue the experiment in ``path`` (finished trials are not rerun).
        address: join a running Ray cluster (``None``: an embedded local instance).
        num_cpus: CPUs of an embedded local instance (``None``: all).

    Raises:
        hocnet.sweep.RayMissingError: without Ray Tune.
        RuntimeError: some trial did not finish (the message says how to resume).
    """
    import json
    import tempfile

    from hocnet.sweep import require_ray, run_sweep

    _, tune = require_ray()
    script = pathlib.Path(script).resolve()
    here, stem = str(script.parent), script.stem
    settings = {"jobs": list(jobs), "shared": dict(shared)}

    def trial(config, settings):  # a closure, so that Ray ships it by value to its workers
        import importlib
        import json
        import sys

        from ray import tune

        if here not in sys.path:
            sys.path.insert(0, here)
        module = importlib.import_module(stem)
        with module.C.single_thread():
            out = getattr(module, function)(settings["jobs"][config["job"]], **settings["shared"])
        tune.report({"result": json.dumps(out)})

    if path is None:
        path = pathlib.Path(tempfile.mkdtemp(prefix=f"{name}-ray-")) / name
    space = {"job": tune.grid_search(list(range(len(settings["jobs"]))))}
    result = run_sweep(
        trial,
        space,
        path,
        settings=settings,
        resume=resume,
        address=address,
        num_cpus=num_cpus,
        quiet=not progress,
    )
    if result.done < len(jobs):
        raise RuntimeError(
            f"{len(jobs) - result.done} of {len(jobs)} Ray trials did not finish; rerun with "
            f"--engine ray --ray-dir {path} --resume"
        )
    ordered = sorted(result.rows, key=lambda r: int(r["job"]))
    return [json.loads(row["result"]) for row in ordered]


def engine_main(
    name: str,
    description: str,
    run: Callable[..., pathlib.Path],
    argv: Sequence[str] | None = None,
) -> pathlib.Path:
    """:func:`main_for` plus the engine options (``run`` takes ``engine=`` and ``ray=``).

    ``--engine {loop,ray}``, ``--ray-dir DIR``, ``--resume``, ``--address ADDRESS`` and
    ``--num-cpus N`` (the last four need ``--engine ray``; ``--resume`` needs ``--ray-dir``).
    """
    import functools

    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--engine", choices=ENGINES, default="loop")
    pre.add_argument("--ray-dir", default=None)
    pre.add_argument("--resume", action="store_true")
    pre.add_argument("--address", default=None)
    pre.add_argument("--num-cpus", type=int, default=None)
    args, rest = pre.parse_known_args(argv)
    if args.engine == "loop" and (args.ray_dir or args.resume or args.address or args.num_cpus):
        pre.error("--ray-dir, --resume, --address and --num-cpus need --engine ray")
    ray: dict[str, Any] = {"resume": args.resume, "address": args.address}
    ray["num_cpus"] = args.num_cpus
    if args.ray_dir is not None:
        ray["path"] = pathlib.Path(args.ray_dir)
    elif args.resume:
        pre.error("--resume needs --ray-dir (the folder of the run to continue)")
    runner = functools.partial(run, engine=args.engine, ray=ray if args.engine == "ray" else None)
    return main_for(name, description + ENGINE_HELP, runner, rest)


HOC_CONFIGS = {
    "paper": {},
    "mhoc + assignment": {"identify": "assignment"},
    "mhoc + greedy": {"identify": "greedy"},
    "chain + paper": {"support": "chain"},
    "chain + greedy (old default)": {"support": "chain", "identify": "greedy"},
    "one sequence per point (shared_points=False, the previous default)": {"shared_points": False},
    "combine=mean, span 1, dedupe=1 (earlier default)": {
        "combine": "mean",
        "score_span": 1,
        "dedupe": 1,
        "shared_points": False,
    },
    "combine=min, span 2, dedupe=1": {"dedupe": 1},
    "combine=min, span 1 (eq. 8-9 on one-scan moves; dedupe=2, shared points, track ends)": {
        "combine": "min",
        "score_span": 1,
    },
    "paper literally (min, span 1, no dedupe, one sequence per point, no track ends)": {
        "combine": "min",
        "score_span": 1,
        "dedupe": False,
        "shared_points": False,
        "track_ends": False,
    },
    "combine=min, span 3": {"combine": "min", "score_span": 3},
    "combine=mean, span 2": {"combine": "mean", "score_span": 2},
    "combine=sum, span 2": {"combine": "sum"},
    "combine=movement (eq. 8 alone), span 2": {"combine": "movement"},
}
"""HOC detector configurations of hoc-table2 and hoc-table3: ``detect`` keyword arguments
(order 2; order 3 runs :data:`HOC_ORDER3_CONFIGS`).

``"paper"`` is ``detect``'s defaults: MHOC image, section III-B identification, point score
``combine="min"`` on moves averaged over ``score_span=2`` scans (the whole five-point sequence,
our reading; :mod:`hocnet.hoc.identify`, "Point score") and several five-point sequences per
image point (``shared_points=True``, our reading; step 2 of the module notes; the previous
default ``shared_points=False`` is a row of its own). The last two rows are the other
point-score combinations of ``detect``, ``combine="sum"`` and ``"movement"``
(:func:`hocnet.hoc.scoring.point_score`), each a row of its own.
"""

HOC_ORDER3_CONFIGS = ("paper", "chain + paper")
"""Configurations of :data:`HOC_CONFIGS` hoc-table2 and hoc-table3 run at order 3: the MHOC
image (the paper; for 10 scans forward ``Y^(3)`` covers scans 1-4 and backward ``Y^(3)`` scans
7-10) and the chain support (our addition)."""

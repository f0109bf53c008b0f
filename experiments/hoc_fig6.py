"""Fig. 6 of [LA98]: clutter rejection versus clutter density, orders 1-4, 10 scans.

Clutter rejection (removed / input clutter points) of the modified HOC (v = 4, delta = pi/4) at
orders 1-4, after the HOC (the MHOC image, forward OR backward ``Y^(k)``) and after track
identification, and of the original HOC of eq. (4) (two-scan correlations, ``delta=None``) at
order 2, as its image (``mhoc_image(..., delta=None)``) and its chain support, on
clutter-only cubes of 10 x 100 x 100 pixels at 12 densities from 0.1 % to 8 % (geometric grid).
The theoretical density bounds of [LA98], 1/81 = 1.23 % (original HOC) and 4.92 % (modified HOC
with delta = pi/4, v = 4), are drawn as vertical lines. Each order's *empirical breakdown
density* is the lowest density at which the mean rejection after the HOC drops below 99 %
(interpolated linearly in log-density between the bracketing grid points).

A reference run on the Table III scene (60 x 60 x 10 with three tracks, order 2) shows the effect
of targets: clutter points next to a target line up with it and survive at any density.

Run: ``python experiments/hoc_fig6.py [--quick] [--seeds N] [--out DIR]`` or
``hocnet reproduce hoc-fig6``.
"""

from __future__ import annotations

import math
import pathlib
import sys
import warnings
from collections.abc import Sequence

# the helpers next to this file, also when the script is loaded by path (`hocnet reproduce`)
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _expkit as C
import matplotlib.pyplot as plt
import numpy as np
import torch

from hocnet import metrics
from hocnet.data.binary import paper_scene, simulate_binary
from hocnet.hoc import allowed_moves, chain_support, detect, mhoc_image

NAME = "hoc-fig6"
DESCRIPTION = (
    "Fig. 6 of [LA98]: clutter rejection versus clutter density for the modified HOC "
    "(v = 4, delta = pi/4) of orders 1-4 and the original HOC of order 2, 10 scans, with the "
    "theoretical density bounds and the empirical breakdown densities."
)

V = 4
DELTA = math.pi / 4
SHAPE = (10, 100, 100)
QUICK_SHAPE = (10, 48, 48)
DENSITIES = tuple(float(f"{d:.4g}") for d in np.geomspace(0.001, 0.08, 12))
QUICK_DENSITIES = (0.01, 0.04)
ORDERS = (1, 2, 3, 4)
ORIGINAL_ORDER = 2
TARGET_ORDER = 2
LEVEL = 0.99
SEED_BASE = 6000
BOUND_ORIGINAL = 1 / 81
BOUND_MODIFIED = 0.0492
CURVES = (
    *((f"k{k}", f"modified HOC, k = {k}") for k in ORDERS),
    (f"orig{ORIGINAL_ORDER}", f"original HOC, k = {ORIGINAL_ORDER} (chain support)"),
    (f"origimg{ORIGINAL_ORDER}", f"original HOC, k = {ORIGINAL_ORDER} (image, eq. 4)"),
)


def evaluate(
    densities: Sequence[float],
    seeds: Sequence[int],
    shape: tuple[int, int, int],
    progress: bool,
) -> list[dict]:
    """One row per (density, seed): rejection of every curve, plus the with-targets reference."""
    rows = []
    jobs = [(d, s) for d in densities for s in seeds]
    for density, seed in C.progress(jobs, enabled=progress, desc=NAME):
        cube = simulate_binary(shape, [], clutter_density=density, seed=seed).cube
        none = torch.zeros_like(cube)  # no target points
        row: dict = {"density": density, "seed": seed, "input_clutter": int(cube.sum())}
        for order in ORDERS:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # above the density bound detect warns
                result = detect(cube, order=order, v=V, delta=DELTA)
            row[f"k{order}_hoc"] = metrics.clutter_rejection(cube, result.support, none)
            row[f"k{order}_id"] = metrics.clutter_rejection(cube, result.cleaned, none)
            row[f"k{order}_tracks"] = len(result.tracks)
        support = chain_support(cube, ORIGINAL_ORDER, V, None)
        row[f"orig{ORIGINAL_ORDER}_hoc"] = metrics.clutter_rejection(cube, support, none)
        # the original HOC's image: forward OR backward Y^(2) of eq. (4), like the modified curves
        image = mhoc_image(cube, ORIGINAL_ORDER, V, None)
        row[f"origimg{ORIGINAL_ORDER}_hoc"] = metrics.clutter_rejection(cube, image, none)
        # reference with targets: the Table III scene (60 x 60 x 10, three tracks), same seed
        scene = paper_scene("table3-paper", density, seed=seed)
        result = detect(scene.cube, order=TARGET_ORDER, v=V, delta=DELTA)
        row["targets_hoc"] = metrics.clutter_rejection(
            scene.cube, result.support, scene.target_mask
        )
        row["targets_id"] = metrics.clutter_rejection(scene.cube, result.cleaned, scene.target_mask)
        row["targets_lost_hoc"] = metrics.target_points_lost(
            scene.cube, result.support, scene.target_mask
        )
        rows.append(row)
    return rows


def curve(rows: list[dict], densities: Sequence[float], key: str) -> tuple[list, list]:
    """Mean and std of column ``key`` at each density."""
    means = [C.mean(r[key] for r in rows if r["density"] == d) for d in densities]
    stds = [C.std(r[key] for r in rows if r["density"] == d) for d in densities]
    return means, stds


def breakdown(densities: Sequence[float], values: Sequence[float], level: float = LEVEL) -> str:
    """Lowest density where ``values`` drop below ``level``, log-linear interpolation.

    Returns a formatted percentage, ``"< lowest"`` if already below at the first grid point, or
    ``"> highest"`` if never below.

    Examples:
        >>> breakdown([0.01, 0.04], [1.0, 0.98])
        '2.00 %'
        >>> breakdown([0.01, 0.04], [0.9, 0.5])
        '< 1.00 %'
    """
    for i, v in enumerate(values):
        if v < level:
            if i == 0:
                return f"< {C.pct(densities[0])}"
            d0, d1 = math.log(densities[i - 1]), math.log(densities[i])
            v0 = values[i - 1]
            frac = (v0 - level) / (v0 - v) if v0 != v else 1.0
            return C.pct(math.exp(d0 + frac * (d1 - d0)))
    return f"> {C.pct(densities[-1])}"


def _rejection_table(rows: list[dict], densities: Sequence[float]) -> str:
    headers = ["density"]
    for key, label in CURVES:
        headers.append(f"{label}: after HOC (%)")
        if key.startswith("k"):
            headers.append(f"k = {key[1:]}: after identification (%)")
    body = []
    for d in densities:
        sel = [r for r in rows if r["density"] == d]
        cells = [C.pct(d)]
        for key, _ in CURVES:
            cells.append(C.mean_std([r[f"{key}_hoc"] for r in sel], 2, scale=100))
            if key.startswith("k"):
                cells.append(C.mean_std([r[f"{key}_id"] for r in sel], 2, scale=100))
        body.append(cells)
    return C.md_table(headers, body)


def _targets_table(rows: list[dict], densities: Sequence[float]) -> str:
    headers = [
        "density",
        f"k = {TARGET_ORDER}: after HOC (%)",
        f"k = {TARGET_ORDER}: after identification (%)",
        "target points lost after HOC (total)",
        "paper: target lost",
    ]
    body = []
    for d in densities:
        sel = [r for r in rows if r["density"] == d]
        body.append(
            [
                C.pct(d),
                C.mean_std([r["targets_hoc"] for r in sel], 2, scale=100),
                C.mean_std([r["targets_id"] for r in sel], 2, scale=100),
                sum(r["targets_lost_hoc"] for r in sel),
                "0",
            ]
        )
    return C.md_table(headers, body)


def _branching_estimate() -> float:
    """1 / mean number of allowed second moves per first move (v = 4, delta = pi/4)."""
    allowed = allowed_moves(V, DELTA)
    return 1.0 / float(allowed.sum(1).double().mean())


def _breakdown_table(rows: list[dict], densities: Sequence[float]) -> str:
    headers = [
        "detector",
        "empirical breakdown, after HOC",
        "empirical breakdown, after identification",
        "paper: theoretical bound",
    ]
    body = []
    for key, label in CURVES:
        hoc = breakdown(densities, curve(rows, densities, f"{key}_hoc")[0])
        ident = (
            breakdown(densities, curve(rows, densities, f"{key}_id")[0])
            if key.startswith("k")
            else "not computed"
        )
        bound = BOUND_MODIFIED if key.startswith("k") else BOUND_ORIGINAL
        body.append([label, hoc, ident, C.pct(bound)])
    return C.md_table(headers, body)


def _plot(
    rows: list[dict], densities: Sequence[float], path: pathlib.Path, shape: tuple[int, ...]
) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(15, 5.8), sharey=True)
    x = [100 * d for d in densities]
    colours = {
        "k1": "tab:blue",
        "k2": "tab:orange",
        "k3": "tab:green",
        "k4": "tab:red",
        f"orig{ORIGINAL_ORDER}": "tab:purple",
        f"origimg{ORIGINAL_ORDER}": "tab:brown",
    }
    for ax, stage, title in (
        (axes[0], "hoc", "after the HOC (MHOC image; original HOC: both)"),
        (axes[1], "id", "after track identification"),
    ):
        for key, label in CURVES:
            if stage == "id" and not key.startswith("k"):
                continue
            m, s = curve(rows, densities, f"{key}_{stage}")
            style = "-o" if key.startswith("k") else ":D"
            ax.errorbar(
                x,
                [100 * v for v in m],
                yerr=[100 * v for v in s],
                fmt=style,
                ms=4,
                capsize=2,
                color=colours[key],
                label=label,
            )
        if stage == "hoc":
            m, _ = curve(rows, densities, "targets_hoc")
            ax.plot(
                x,
                [100 * v for v in m],
                "--x",
                color="0.4",
                label=f"modified HOC, k = {TARGET_ORDER}, Table III scene (with targets)",
            )
        ax.axvline(
            100 * BOUND_ORIGINAL,
            color="k",
            ls="--",
            lw=1.0,
            label="[LA98] bound, original HOC: 1/81 = 1.23 %",
        )
        ax.axvline(
            100 * BOUND_MODIFIED,
            color="k",
            ls="-.",
            lw=1.0,
            label="[LA98] bound, modified HOC: 4.92 %",
        )
        ax.axhline(100 * LEVEL, color="0.6", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_xticks([0.1, 0.2, 0.5, 1, 2, 5, 8])
        ax.set_xticklabels(["0.1", "0.2", "0.5", "1", "2", "5", "8"])
        ax.set_xlabel("clutter density (%)")
        ax.set_title(f"Clutter rejection {title}")
        ax.grid(alpha=0.3, which="both")
        ax.set_ylim(-2, 102)
    axes[0].set_ylabel("clutter rejection (%) (mean ± std)")
    axes[0].legend(fontsize=8, loc="lower left", bbox_to_anchor=(0.0, 0.12))
    axes[1].legend(fontsize=8, loc="lower left", bbox_to_anchor=(0.0, 0.12))
    fig.suptitle(
        f"[LA98] Fig. 6: clutter rejection vs density, {shape[0]} scans, "
        f"{shape[1]} x {shape[2]} clutter-only cubes, v = 4, delta = pi/4 "
        f"(dotted grey line: {100 * LEVEL:.0f} % breakdown level)"
    )
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(
    *,
    quick: bool = False,
    seeds: int | None = None,
    out_dir: pathlib.Path | None = None,
    progress: bool = True,
) -> pathlib.Path:
    """Run the experiment; write ``<NAME>.md``, ``.csv`` and ``.png``; return the md path.

    Args:
        quick: smoke run (two densities, 2 seeds, 48 x 48 cubes).
        seeds: scenes per setting (default 20, quick 2).
        out_dir: output folder (default ``experiments/results``).
        progress: show a tqdm progress bar.

    Returns:
        Path of the markdown file.
    """
    n = C.n_seeds(quick, seeds)
    out = C.out_dir_of(out_dir)
    densities = QUICK_DENSITIES if quick else DENSITIES
    shape = QUICK_SHAPE if quick else SHAPE
    seed_values = C.seed_list(SEED_BASE, n)
    with C.single_thread(), C.Timer() as timer:
        rows = evaluate(densities, seed_values, shape, progress)
    table = _breakdown_table(rows, densities)
    branching = _branching_estimate()
    parts = [
        C.header(
            "[LA98] Fig. 6: clutter rejection versus density",
            DESCRIPTION,
            quick=quick,
            n=n,
            seconds=timer.seconds,
        ),
        f"- Cubes: clutter only, {shape[0]} scans x {shape[1]} x {shape[2]} pixels, "
        f"`simulate_binary(shape, [], clutter_density=d, seed=seed)`, seeds {seed_values[0]} .. "
        f"{seed_values[-1]} at every density (the same uniform draws thresholded at each "
        "density, so the clutter sets are nested and the curves are paired).",
        "- Modified HOC: `hocnet.hoc.detect(cube, order=k, v=4, delta=pi/4)`: *after HOC* is its "
        "support, the MHOC image (forward OR backward Y^(k), [LA98] section III-B), *after "
        "identification* its `cleaned` cube (tracks of >= 2k + 1 points, score >= 2.5). "
        "Original HOC of eq. (4): its image `mhoc_image(cube, 2, v=4, delta=None)` and its chain "
        "support `chain_support(cube, 2, v=4, delta=None)`.",
        "- Clutter rejection = removed clutter points / input clutter points (all input points "
        "are clutter here).",
        "- Above the modified HOC's bound (4.94 %, `density_bound`) `detect` flags the scene as "
        "saturated and skips track identification (no tracks, empty `cleaned`): the *after "
        "identification* values there (5.37 % and 8 %) are 100 % by construction, not a "
        "measurement, and the k = 4 breakdown after identification (> 8 %) rests on them "
        "(measured: above 99 % up to 3.61 %, the last grid point below the bound).",
        f"- **Empirical breakdown density**: the lowest density at which the mean rejection "
        f"drops below {100 * LEVEL:.0f} %, interpolated linearly in log-density between the two "
        "bracketing grid points (`<` / `>` when outside the grid).",
        "",
        "## Breakdown densities",
        "",
        table,
        "",
        "The `paper` column holds the theoretical density bounds stated in [LA98] (1/81 = 1.23 % "
        "for the original HOC; 4.92 % for the modified HOC with delta = pi/4, v = 4). For "
        "comparison, a branching estimate from our allowed-move table: a chain can continue "
        f"with {1 / branching:.2f} of the 81 second moves on average (turn <= 45 degrees, "
        "zero moves always allowed), so false chains multiply from one scan to the next above "
        f"p = 1/{1 / branching:.2f} = {C.pct(branching)} and die out geometrically with the "
        "order below it: the empirical breakdown of the modified HOC rises with k towards that "
        "limit. The original HOC of eq. (4) correlates each point with any point of its 9 x 9 "
        "window in the next scan (no curvature constraint), so its false chains multiply once "
        "the window holds about one clutter point, rho (2v+1)^2 >= 1, i.e. above 1/81 = 1.23 %: "
        "the measured breakdown (table above) is below that bound, as section IV-B predicts "
        "(the bound is where discrimination fails completely, our 99 % level is stricter).",
        "",
        "## Clutter rejection (mean ± std over the scenes)",
        "",
        _rejection_table(rows, densities),
        "",
        f"## Reference with targets: Table III scene (60 x 60 x 10), order {TARGET_ORDER}",
        "",
        "Same seeds. Clutter points adjacent to a target line up with it and are kept by the "
        "MHOC image at every density, so in this small, target-rich scene the rejection "
        "after the HOC saturates a few percent below 100 % even at the lowest densities; this "
        "is why the breakdown is measured on clutter-only cubes.",
        "",
        _targets_table(rows, densities),
        "",
        "Paper: Fig. 6 of [LA98] is a plot without printed values; its bounds (section IV-B) are "
        "1/81 = 1.23 % (original HOC) and (1/81) x 4 = 4.92 % (modified HOC, v = 4, "
        "delta = pi/4; 4/81 = 4.94 % unrounded). *After HOC* is now the paper's MHOC image "
        "(forward OR backward Y^(k)); above 4.94 % `detect` warns and skips identification.",
        "",
        f"![{NAME}]({NAME}.png)",
    ]
    text = "\n".join(parts)
    md = C.write_text(out / f"{NAME}.md", text)
    C.write_csv(
        out / f"{NAME}.csv",
        [  # the paper's theoretical bounds (percent, section IV-B) beside ours
            {
                **r,
                "paper_bound_modified_pct": 100 * BOUND_MODIFIED,
                "paper_bound_original_pct": round(100 * BOUND_ORIGINAL, 2),
            }
            for r in rows
        ],
    )
    _plot(rows, densities, out / f"{NAME}.png", shape)
    print(text)
    return md


def main(argv: Sequence[str] | None = None) -> pathlib.Path:
    """Command line entry point."""
    return C.main_for(NAME, DESCRIPTION, run, argv)


if __name__ == "__main__":
    main()

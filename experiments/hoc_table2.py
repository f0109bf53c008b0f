"""Table II of [LA98]: two 10-point tracks in a 520 x 320 x 10 cube at 0.8 - 2.0 % clutter.

For every density and seed, one scene ``paper_scene("table2", density, seed=base + i)`` is run
through the modified HOC detector (``hocnet.hoc.detect``, v = 4, delta = pi/4) at orders 2 and 3
(the same scenes for both orders). Reported per density and order (mean ± std over the scenes):
input points, points remaining and clutter rejection after the HOC (the MHOC image) and after
track identification (the ``cleaned`` cube), target points lost, tracks found versus the 2 true
ones, true tracks found (80 % point overlap) and false tracks. Order 3 runs twice: on the MHOC
image (the paper; it leaves scans 5-6 of 10 uncovered) and on the chain support
(``support="chain"``, our addition). The paper prints one scene per density, so the
identification column is also put into our scene-to-scene spread (min / median / max per
scene, and the share of our scenes at or above the printed value).

Run: ``python experiments/hoc_table2.py [--quick] [--seeds N] [--out DIR]`` or
``hocnet reproduce hoc-table2``.
"""

from __future__ import annotations

import math
import pathlib
import statistics
import sys
import warnings
from collections.abc import Sequence

# the helpers next to this file, also when the script is loaded by path (`hocnet reproduce`)
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _expkit as C
import _hoc_spread
import matplotlib.pyplot as plt

from hocnet.data.binary import paper_scene
from hocnet.hoc import detect

NAME = "hoc-table2"
DESCRIPTION = (
    "Table II of [LA98]: modified HOC (v = 4, delta = pi/4, orders 2 and 3) on two 10-point "
    "tracks in a 520 x 320 x 10 cube, clutter density 0.8 - 2.0 %."
)

DENSITIES = (0.008, 0.011, 0.014, 0.017, 0.020)
QUICK_DENSITIES = (0.008,)
ORDERS = (2, 3)
HEADLINE_ORDER = 2
SEED_BASE = 2000


CONFIGS = C.HOC_CONFIGS
"""Detector configurations (order 2): :data:`_expkit.HOC_CONFIGS` (shared with the other HOC
table)."""

ORDER3_CONFIGS = C.HOC_ORDER3_CONFIGS
"""Configurations run at order 3: :data:`_expkit.HOC_ORDER3_CONFIGS`."""

SPREAD_CONFIGS = ("paper", "mhoc + assignment")
"""Configurations whose per-scene spread is set beside the paper's single-scene value."""

PAPER_HOC = {0.008: 99.56, 0.011: 97.55, 0.014: 93.99, 0.017: 87.42, 0.02: 75.44}
"""[LA98] printed MHOC clutter rejection (%) per density."""

PAPER_ID = {0.008: 99.91, 0.011: 99.9, 0.014: 99.96, 0.017: 99.64, 0.02: 98.31}
"""[LA98] printed clutter rejection (%) after track identification per density."""

PAPER_ID_KEPT = {0.008: 1, 0.011: 19, 0.014: 9, 0.017: 103, 0.02: 558}
"""Clutter points [LA98] kept after identification: its printed points remained minus 20."""

PAPER_NOTES = (
    "Paper values are Table II of [LA98] as printed (one scene per density, 20 target points). "
    "Its counts and percentages disagree in two places: after HOC at 1.1 %, 510 - 20 = 490 of "
    "18260 clutter points kept is 97.32 % (printed 97.55 %); after identification at 0.8 %, 1 "
    "clutter point kept of 13310 is 99.99 % (printed 99.91 %). Elsewhere they agree: after HOC "
    "0.8 %: 78 - 20 = 58 of 13310 is 99.56 %; 1.4 %: 1386 of 23080 is 93.99 %; 1.7 %: 3558 of "
    "28280 is 87.42 %; 2.0 %: 8119 of 33060 is 75.44 %; after identification 1.4 %: 29 - 20 = 9 "
    "kept is 99.96 %, 2.0 %: 558 is 98.31 %."
)


def evaluate(
    densities: Sequence[float], orders: Sequence[int], seeds: Sequence[int], progress: bool
) -> tuple[list[dict], dict]:
    """One row per (density, order, seed), and the example kept for the plot.

    The example is the first seed's scene at the lowest density with the headline order.
    """
    rows = []
    example: dict = {}
    jobs = [(d, s) for d in densities for s in seeds]
    for density, seed in C.progress(jobs, enabled=progress, desc=NAME):
        scene = paper_scene("table2", density, seed=seed)
        for order, config in [
            (o, c) for o in orders for c in CONFIGS if o == 2 or c in ORDER3_CONFIGS
        ]:
            with C.Timer() as timer, warnings.catch_warnings():
                # order 3 on 10 scans: the MHOC image leaves scans 5-6 uncovered (reported)
                warnings.filterwarnings("ignore", message=".*cannot cover every scan")
                result = detect(scene.cube, order=order, v=4, delta=math.pi / 4, **CONFIGS[config])
            row = C.hoc_scene_metrics(
                scene.cube, scene.target_mask, scene.tracks, result, min_points=2 * order + 1
            )
            row.pop("found_flags")
            rows.append(
                {
                    "density": density,
                    "order": order,
                    "config": config,
                    "seed": seed,
                    **row,
                    "seconds": timer.seconds,
                }
            )
            if config != "paper":
                continue
            if density == densities[0] and seed == seeds[0] and order == HEADLINE_ORDER:
                example = {
                    "scene": scene,
                    "result": result,
                    "density": density,
                    "order": order,
                    "seed": seed,
                }
    return rows, example


def _select(rows: list[dict], density: float, order: int, config: str = "paper") -> list[dict]:
    return [
        r for r in rows if r["density"] == density and r["order"] == order and r["config"] == config
    ]


def _table(rows: list[dict], densities: Sequence[float], order: int, config: str = "paper") -> str:
    headers = [
        "density",
        "input points",
        "input clutter",
        "remaining after HOC",
        "rejection after HOC (%)",
        "target lost after HOC",
        "remaining after identification",
        "rejection after identification (%)",
        "target lost after identification",
        "paper: target lost",
        "tracks found (true: 2)",
        "true tracks found (of 2)",
        "false tracks",
    ]
    body = []
    for d in densities:
        sel = _select(rows, d, order, config)
        col = lambda key, sel=sel: [r[key] for r in sel]  # noqa: E731
        body.append(
            [
                C.pct(d, 1),
                C.mean_std(col("input_points"), 0),
                C.mean_std(col("input_clutter"), 0),
                C.mean_std(col("hoc_remaining"), 1),
                C.mean_std(col("hoc_rejection"), 2, scale=100),
                f"{sum(col('hoc_target_lost'))} (total)",
                C.mean_std(col("id_remaining"), 1),
                C.mean_std(col("id_rejection"), 3, scale=100),
                f"{sum(col('id_target_lost'))} (total)",
                "0",
                C.mean_std(col("tracks_found"), 2),
                C.mean_std(col("true_found"), 2),
                C.mean_std(col("false_tracks"), 2),
            ]
        )
    return C.md_table(headers, body)


def _plot(
    rows: list[dict],
    densities: Sequence[float],
    orders: Sequence[int],
    path: pathlib.Path,
    example: dict,
) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(17, 5.2))
    x = [100 * d for d in densities]
    colours = {2: "tab:blue", 3: "tab:orange"}
    ax = axes[0]
    for order in orders:
        for key, style, label in (
            ("hoc_rejection", "-o", "after HOC support"),
            ("id_rejection", "--s", "after track identification"),
        ):
            m = [100 * C.mean(r[key] for r in _select(rows, d, order)) for d in densities]
            s = [100 * C.std(r[key] for r in _select(rows, d, order)) for d in densities]
            ax.errorbar(
                x,
                m,
                yerr=s,
                fmt=style,
                color=colours.get(order),
                capsize=3,
                label=f"k = {order}, {label}",
            )
    ax.set_xlabel("clutter density (%)")
    ax.set_ylabel("clutter rejection (%)")
    ax.set_title("Clutter rejection (mean ± std over scenes)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)

    ax = axes[1]
    for order in orders:
        for key, style, label in (
            ("hoc_remaining", "-o", "after HOC support"),
            ("id_remaining", "--s", "after track identification"),
        ):
            m = [C.mean(r[key] for r in _select(rows, d, order)) for d in densities]
            ax.plot(x, m, style, color=colours.get(order), label=f"k = {order}, {label}")
    ax.axhline(20, color="k", lw=0.8, ls=":", label="target points (20)")
    ax.set_yscale("log")
    ax.set_xlabel("clutter density (%)")
    ax.set_ylabel("points remaining (mean, log scale)")
    ax.set_title("Points remaining")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)

    ax = axes[2]
    C.plot_scene_xy(
        ax,
        example["scene"].cube,
        example["scene"].target_mask,
        example["scene"].tracks,
        example["result"],
        title=(
            f"Example: density {100 * example['density']:.1f} %, k = {example['order']}, "
            f"seed {example['seed']}"
        ),
        point_size=0.3,
    )
    ax.legend(fontsize=7, loc="lower left", markerscale=3, framealpha=0.9)
    fig.suptitle("[LA98] Table II setup: two 10-point tracks, 520 x 320 x 10, v = 4, delta = pi/4")
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
        quick: smoke run (one density, 2 seeds).
        seeds: scenes per setting (default 20, quick 2).
        out_dir: output folder (default ``experiments/results``).
        progress: show a tqdm progress bar.

    Returns:
        Path of the markdown file.
    """
    n = C.n_seeds(quick, seeds)
    out = C.out_dir_of(out_dir)
    densities = QUICK_DENSITIES if quick else DENSITIES
    seed_values = C.seed_list(SEED_BASE, n)
    with C.single_thread(), C.Timer() as timer:
        rows, example = evaluate(densities, ORDERS, seed_values, progress)

    lost_hoc = sum(r["hoc_target_lost"] for r in rows)
    lost_id = sum(r["id_target_lost"] for r in rows)
    parts = [
        C.header(
            "[LA98] Table II: two tracks, 520 x 320 x 10",
            DESCRIPTION,
            quick=quick,
            n=n,
            seconds=timer.seconds,
        ),
        f"- Seeds: {seed_values[0]} .. {seed_values[-1]} (`paper_scene('table2', density, "
        "seed=seed)`); the same scenes for both orders.",
        "- Detector: `hocnet.hoc.detect(cube, order=k, v=4, delta=pi/4)` (its defaults: point "
        "score `combine='min'`, `score_span=2`, several five-point sequences per image point "
        "`shared_points=True`), track threshold 2.5, tracks of at least 2k + 1 "
        "points.",
        "- *After HOC* = the detector's support, the MHOC image (forward OR backward Y^(k), [LA98] "
        "section III-B; order 3 covers only scans 1-4 and 7-10 of 10, hence its lost points; "
        "order 3 also runs on the chain support, `support='chain'`, which covers every scan); "
        "*after identification* = the points of the accepted tracks (`cleaned`).",
        "- Clutter rejection = removed clutter points / input clutter points. Target points lost "
        "= input target points not in the output, summed over all scenes of the row.",
        "- A true track is *found* when one identified track contains >= 80 % of its points; a "
        "*false track* is an identified track with fewer than 50 % target points.",
        f"- Target points lost over all {len(rows)} runs: {lost_hoc} after the HOC support, "
        f"{lost_id} after track identification.",
        "",
        f"## Headline: order k = {HEADLINE_ORDER} (the detector's default)",
        "",
        _table(rows, densities, HEADLINE_ORDER),
        "",
    ]
    for order in ORDERS:
        if order == HEADLINE_ORDER:
            continue
        parts += [
            f"## Order k = {order}",
            "",
            f"MHOC image (the paper): for 10 scans forward Y^({order}) covers scans 1-"
            f"{10 - 2 * order} and backward Y^({order}) scans {2 * order + 1}-10, so the target "
            "points of the scans between are lost after the HOC (`detect` warns when T < 4k).",
            "",
            _table(rows, densities, order),
            "",
            f"Chain support (`support='chain'`, our addition): every point of an accepted "
            f"{2 * order + 1}-point chain, so every scan is covered:",
            "",
            _table(rows, densities, order, "chain + paper"),
            "",
        ]
    parts += [
        "## Configurations side by side with the paper (k = 2)",
        "",
        "*After HOC* is the detector's support: the MHOC image (forward OR backward Y^(k), the "
        "paper) or the chain support (our addition). `paper` = `detect`'s defaults: MHOC image, "
        "section III-B identification, point score `combine='min'` on moves averaged over "
        "`score_span=2` scans (each point scored on the two halves of its five-point sequence, "
        "our reading of 'compared as whole sequences'); `span 1` = eq. (8)-(9) on one-scan moves "
        "as printed; `paper literally` = section III-B with none of our additions (span 1, no "
        "`dedupe`, one sequence per point, no track-ends step); near-duplicate tracks "
        "differing at up to two scans dropped (`dedupe=2`, "
        "our addition; every configuration row uses it unless it says otherwise). See "
        "`hocnet.hoc.identify`, 'Point score'.",
        "",
        C.config_table(
            CONFIGS, densities, lambda d, c: _select(rows, d, 2, c), PAPER_HOC, PAPER_ID
        ),
        "",
        "`combine=sum` thresholds the sum of the two scores (up to 7.24) at the paper's 2.5; "
        "`combine=movement` is eq. (8) alone (with delta = pi/4 the curvature score never falls "
        "below 2.67, so it differs from `min` only where eq. (9) is the lower score).",
        "",
        PAPER_NOTES,
        "",
    ]
    spread, findings = _hoc_spread.spread_table(
        lambda d, c: _select(rows, d, 2, c), densities, SPREAD_CONFIGS, PAPER_ID, PAPER_ID_KEPT
    )
    medians = [
        statistics.median(r["id_clutter_remaining"] for r in _select(rows, d, 2)) for d in densities
    ]
    paper_kept = [PAPER_ID_KEPT[d] for d in densities]
    parts += [
        "## Identification column: the paper's one scene against our scene-to-scene spread (k = 2)",
        "",
        "[LA98] prints one scene per density (its Table II counts); our column is a mean over "
        f"{n} scenes. Per density: the clutter points kept after identification (the paper's "
        "printed points remained minus its 20 target points) and our clutter rejection per scene "
        "(min / median / max), the number of our scenes at or above the printed percentage "
        "(compared at its two decimals), and whether the printed value lies inside our "
        "per-scene range.",
        "",
        spread,
        "",
        *(f"- {f}" for f in findings),
        "- The paper's clutter kept after identification, "
        + " / ".join(f"{k:g}" for k in paper_kept)
        + f" at {' / '.join(C.pct(d, 1) for d in densities)}, "
        + ("rises" if _hoc_spread.monotonic(paper_kept) else "is not monotonic")
        + " with the density; our median per scene (`paper`), "
        + " / ".join(f"{m:g}" for m in medians)
        + ", "
        + ("rises with it." if _hoc_spread.monotonic(medians) else "is not monotonic either."),
        "",
        "## Where the paper disagrees with itself",
        "",
        "- Table I rows d and e turn by 90 degrees (Gamma = pi/2, curvature score (2.356 - "
        "pi/2) x 1.91 = 1.5 as printed), but (9b) requires Gamma <= delta and delta = pi/4 in "
        "every experiment: eq. (6) rejects those triples, so they never reach the scoring.",
        "- Section II says Y^(k) of the original HOC correlates 'k consecutive scans' and, in "
        "the same sentence, extends from t_n to t_{n+k} (k + 1 scans; also 'k + 1 consecutive "
        "scans' before Proposition 1 and k + n_max = n_0); we read k + 1.",
        "- Fig. 5(e)'s caption says scans 5-11, the text (section IV-A) 5-14; both OCRs agree; "
        "we use 5-14 (`hoc-fig5`).",
        "- Table II's identification column is not monotonic in the clutter kept (19 points at "
        "1.1 %, 9 at 1.4 %, 103 at 1.7 %), as one scene per density can give; its counts and "
        "percentages also disagree at 0.8 % (1 kept is 99.99 %, printed 99.91 %).",
        "",
    ]
    parts += [
        "Mean ± std over the scenes (sample std). The `paper: target lost` column is the value "
        "[LA98] states for its setups (0).",
        "",
        f"![{NAME}]({NAME}.png)",
    ]
    text = "\n".join(parts)
    md = C.write_text(out / f"{NAME}.md", text)
    C.write_csv(
        out / f"{NAME}.csv",
        [  # the paper's printed values (percent) beside ours, on every row of their density
            {
                **r,
                "paper_after_hoc_pct": PAPER_HOC.get(r["density"], ""),
                "paper_after_id_pct": PAPER_ID.get(r["density"], ""),
                "paper_target_lost": 0,
            }
            for r in rows
        ],
    )
    _plot(rows, densities, ORDERS, out / f"{NAME}.png", example)
    print(text)
    return md


def main(argv: Sequence[str] | None = None) -> pathlib.Path:
    """Command line entry point."""
    return C.main_for(NAME, DESCRIPTION, run, argv)


if __name__ == "__main__":
    main()

"""[NR08]: frame sampling (effective velocity) and Max_Numbers of the Block SNR.

The paper finds the DPA works best for an effective target velocity of 0.6 ± 0.15 px/frame,
reached by keeping every ``s_n``-th frame of a slow sequence, and scores the ASF with the Block
SNR of eq. (16) whose signal is the mean of the ``Max_Numbers`` highest values of the target
block (preferred: 3 for g = 0, 1 for g = 1).

Here, for ``s_n = 1 .. 7`` (1 .. 5 requested; 6 and 7 added to see past the edge of that
grid) every scene is simulated with ``1 + (T - 1) s_n`` frames and every ``s_n``-th frame is
kept, so the DPA always sees ``T = 25`` frames of a target whose apparent
speed is ``s_n`` times the simulator's (0.3 px/frame NA23A-like, 0.2 px/frame NPA-like). The DPA
(7 x 7 matrices for speeds up to 2.5 px/frame, which cover every effective velocity here) runs
with g = 0 and g = 1, each at two values of b: the *tuned* b (the b of a coarse grid with the
highest tracking rate at ``s_n = 1``, on separate tuning seeds: the "best b" rule of
``dpa-b-sweep``) and the effective-memory b (eq. 12-14, EMC 0.8). The algorithm score A_S
(eq. 17, last six frames) is computed for ``Max_Numbers = 1 .. 7``, under the Block SNR of
``hocnet.dpa`` and under an alternative per-block reading; reported is where the mean A_S peaks,
next to the A_S of the frames without accumulation (b = 0) as a reference.

Run: ``python experiments/dpa_sampling.py [--quick] [--seeds N] [--out DIR]`` or
``hocnet reproduce dpa-sampling``.
"""

from __future__ import annotations

import pathlib
import sys
from collections.abc import Sequence

# the helpers next to this file, also when the script is loaded by path (`hocnet reproduce`)
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _expkit as C
import matplotlib.pyplot as plt
import torch

from hocnet.dpa import (
    accumulate,
    algorithm_score,
    backtrack,
    effective_memory,
    probability_matrices,
)

NAME = "dpa-sampling"
DESCRIPTION = (
    "[NR08] frame sampling s_n = 1..7 (effective velocity s_n x true speed) and Max_Numbers "
    "1..7 of the Block SNR: where the algorithm score A_S of the DPA peaks, for g = 0 and "
    "g = 1, on NA23A-like and NPA-like sequences."
)

SEED_BASE = 7000
TUNE_SEED_BASE = 7500
FRAMES = 25
SIZE = 64
QUICK_FRAMES = 8
QUICK_SIZE = 32
SAMPLING = (1, 2, 3, 4, 5, 6, 7)
"""s_n of a full run: the requested 1 .. 5, extended to 7 to see past the edge of that grid."""
QUICK_SAMPLING = (1, 2)
MAX_NUMBERS = tuple(range(1, 8))
MATRIX = "7x7, v <= 2.5"
WHITENING = "anti_mean"
GS = (0.0, 1.0)
TUNE_GRID = {
    0.0: [float(b) for b in range(1, 9)],
    1.0: [round(0.1 * i, 2) for i in range(1, 11)],
}
"""Tuning grid of b per g (b = 0 is excluded: it switches the accumulation off)."""
QUICK_TUNE_GRID = {0.0: [2.0, 4.0, 8.0], 1.0: [0.2, 0.5, 1.0]}
LAST = 6
EMC = 0.8
READINGS = {
    "api": ("a_s_mn", "eq. (16) as in hocnet.dpa (MN on the target block only)"),
    "blockwise": ("a_s_blk_mn", "alternative: MN on every block (C.blockwise_score)"),
}
"""The two readings of the Block SNR: CSV column prefix and description."""


def _weights() -> torch.Tensor:
    window, v_max = C.DPA_MATRICES[MATRIX]
    return probability_matrices(window, v_max=v_max)


def sampled_scene(scene: str, seeds: Sequence[int], frames: int, size: int, step: int) -> tuple:
    """Whitened frames ``(B, frames, size, size)`` and positions, keeping every ``step``-th frame.

    The scene is simulated with ``1 + (frames - 1) * step`` frames (same seeds for every
    ``step``, so the clouds and the track geometry scale with the sequence length).
    """
    long = 1 + (frames - 1) * step
    seq = C.dpa_scene(scene, seeds, shape=(long, size, size))
    kept = seq.frames[:, ::step]
    return C.whiten(kept, WHITENING), seq.positions[:, :, ::step]


def tune_b(
    scenes: Sequence[str],
    weights: torch.Tensor,
    grid: dict[float, list[float]],
    seeds: Sequence[int],
    frames: int,
    size: int,
    progress: bool,
) -> tuple[dict, list[dict]]:
    """Tuned b per (scene, g): highest tracking rate at ``s_n = 1`` (ties: higher mean A_S)."""
    best, rows = {}, []
    data = {s: sampled_scene(s, seeds, frames, size, 1) for s in scenes}
    jobs = [(s, g, b) for s in scenes for g in grid for b in grid[g]]
    scores: dict = {}
    for scene, g, b in C.progress(jobs, enabled=progress, desc=f"{NAME} tuning"):
        whitened, positions = data[scene]
        state = accumulate(whitened, weights, b, g)
        a_s = algorithm_score(state.asf, positions, last=min(LAST, frames))
        tracked, _ = C.dpa_tracked(backtrack(state), positions)
        rate, a_mean = float(tracked.double().mean()), float(a_s.mean())
        scores.setdefault((scene, g), []).append((rate, a_mean, b))
        rows.append(
            {
                "table": "tuning",
                "scene": scene,
                "g": g,
                "b": b,
                "tracking_rate": rate,
                "a_s_mean": a_mean,
            }
        )
    for key, values in scores.items():
        best[key] = max(values)[2]
    return best, rows


def evaluate(
    scenes: Sequence[str],
    weights: torch.Tensor,
    bvalues: dict,
    sampling: Sequence[int],
    seeds: Sequence[int],
    frames: int,
    size: int,
    progress: bool,
) -> list[dict]:
    """One row per (scene, s_n, g, b choice, seed) with A_S for every Max_Numbers."""
    rows = []
    jobs = [(scene, step) for scene in scenes for step in sampling]
    for scene, step in C.progress(jobs, enabled=progress, desc=NAME):
        whitened, positions = sampled_scene(scene, seeds, frames, size, step)
        speed = C.scene_speed(scene)
        # reference: b = 0 (no accumulation, A_S of the single whitened frames; same for any g)
        off = algorithm_score(whitened, positions, last=min(LAST, frames))
        rows += [
            {
                "table": "reference",
                "scene": scene,
                "s_n": step,
                "v_eff": round(step * speed, 4),
                "b": 0.0,
                "seed": seed,
                "a_s_mn1": float(off[i]),
            }
            for i, seed in enumerate(seeds)
        ]
        for (sc, g, choice), b in bvalues.items():
            if sc != scene:
                continue
            state = accumulate(whitened, weights, b, g)
            tracked, _ = C.dpa_tracked(backtrack(state), positions)
            a_s = {
                m: algorithm_score(state.asf, positions, last=min(LAST, frames), max_numbers=m)
                for m in MAX_NUMBERS
            }
            blk = C.blockwise_score(state.asf, positions, MAX_NUMBERS, last=min(LAST, frames))
            for i, seed in enumerate(seeds):
                row = {
                    "table": "sampling",
                    "scene": scene,
                    "s_n": step,
                    "v_eff": round(step * speed, 4),
                    "g": g,
                    "b_choice": choice,
                    "b": round(float(b), 4),
                    "seed": seed,
                    "tracked": int(tracked[i]),
                }
                row.update({f"a_s_mn{m}": float(a_s[m][i]) for m in MAX_NUMBERS})
                row.update({f"a_s_blk_mn{m}": float(blk[m][i]) for m in MAX_NUMBERS})
                rows.append(row)
    return rows


def grid_means(
    rows: list[dict], scene: str, g: float, choice: str, sampling, reading: str = "api"
) -> list[list[float]]:
    """Mean A_S ``[s_n index][Max_Numbers index]`` of one (scene, g, b choice, reading)."""
    prefix = READINGS[reading][0]
    out = []
    for step in sampling:
        sel = [
            r
            for r in rows
            if r["table"] == "sampling"
            and r["scene"] == scene
            and r["g"] == g
            and r["b_choice"] == choice
            and r["s_n"] == step
        ]
        out.append([C.mean(r[f"{prefix}{m}"] for r in sel) for m in MAX_NUMBERS])
    return out


def peak_of(means: list[list[float]], sampling: Sequence[int]) -> tuple[int, int, float]:
    """``(s_n, Max_Numbers, A_S)`` of the largest mean A_S."""
    best = max(
        ((i, j) for i in range(len(sampling)) for j in range(len(MAX_NUMBERS))),
        key=lambda ij: means[ij[0]][ij[1]],
    )
    return sampling[best[0]], MAX_NUMBERS[best[1]], means[best[0]][best[1]]


def _tracking_rate(rows, scene, g, choice, step) -> float:
    sel = [
        r["tracked"]
        for r in rows
        if r["table"] == "sampling"
        and r["scene"] == scene
        and r["g"] == g
        and r["b_choice"] == choice
        and r["s_n"] == step
    ]
    return C.mean(sel)


def _summary_table(rows, scenes, bvalues, sampling) -> str:
    headers = [
        "sequence",
        "g",
        "b",
        "Block SNR reading",
        "A_S peak: s_n (effective velocity, px/frame)",
        "paper: preferred velocity",
        "A_S peak: Max_Numbers",
        "paper: Max_Numbers",
        "best s_n for each Max_Numbers 1..7",
        "best Max_Numbers for each s_n",
        "peak mean A_S",
        "s_n (v_eff) of the largest gain over b = 0 (api, MN = 1)",
    ]
    body = []
    for scene in scenes:
        speed = C.scene_speed(scene)
        ref = _reference_means(rows, scene, sampling)
        for g in GS:
            for choice in ("tuned", "EMC"):
                api = grid_means(rows, scene, g, choice, sampling, "api")
                gains = [api[i][0] - ref[i] for i in range(len(sampling))]
                best = max(range(len(sampling)), key=lambda i: gains[i])
                gain_cell = f"{sampling[best]} ({sampling[best] * speed:.2g}): {gains[best]:+.2f}"
                for reading in READINGS:
                    means = grid_means(rows, scene, g, choice, sampling, reading)
                    step, mn, value = peak_of(means, sampling)
                    per_mn = [
                        sampling[max(range(len(sampling)), key=lambda i, j=j: means[i][j])]
                        for j in range(len(MAX_NUMBERS))
                    ]
                    per_s = [
                        MAX_NUMBERS[max(range(len(MAX_NUMBERS)), key=lambda j, i=i: means[i][j])]
                        for i in range(len(sampling))
                    ]
                    body.append(
                        [
                            scene,
                            f"{g:g}",
                            f"{bvalues[scene, g, choice]:.3g} ({choice})",
                            reading,
                            f"{step} ({step * speed:.2g})",
                            C.PAPER_VELOCITY,
                            str(mn),
                            str(C.PAPER_MAX_NUMBERS[g]),
                            ", ".join(str(s) for s in per_mn),
                            ", ".join(str(m) for m in per_s),
                            f"{value:.2f}",
                            gain_cell,
                        ]
                    )
    return C.md_table(headers, body)


def _grid_table(rows, scene, g, choice, sampling, reading: str = "api") -> str:
    speed = C.scene_speed(scene)
    means = grid_means(rows, scene, g, choice, sampling, reading)
    headers = ["s_n", "v_eff (px/frame)", *(f"MN = {m}" for m in MAX_NUMBERS), "tracking"]
    body = []
    for i, step in enumerate(sampling):
        best = max(means[i])
        cells = [str(step), f"{step * speed:.2g}"]
        cells += [f"**{v:.2f}**" if v == best else f"{v:.2f}" for v in means[i]]
        cells.append(C.pct(_tracking_rate(rows, scene, g, choice, step), 0))
        body.append(cells)
    return C.md_table(headers, body)


def _reference_means(rows, scene, sampling) -> list[float]:
    """Mean A_S (MN = 1) without accumulation, per s_n."""
    return [
        C.mean(
            r["a_s_mn1"]
            for r in rows
            if r["table"] == "reference" and r["scene"] == scene and r["s_n"] == step
        )
        for step in sampling
    ]


def _reference_table(rows, scenes, bvalues, sampling) -> str:
    headers = [
        "s_n",
        *(f"{scene}: v_eff; A_S at b = 0 / tuned g = 0 / tuned g = 1" for scene in scenes),
    ]
    body = []
    for step in sampling:
        cells = [str(step)]
        for scene in scenes:
            ref = C.mean(
                r["a_s_mn1"]
                for r in rows
                if r["table"] == "reference" and r["scene"] == scene and r["s_n"] == step
            )
            i = list(sampling).index(step)
            tuned = [grid_means(rows, scene, g, "tuned", sampling)[i][0] for g in GS]
            cells.append(
                f"{step * C.scene_speed(scene):.2g}; {ref:.2f} / "
                + " / ".join(f"{v:.2f}" for v in tuned)
            )
        body.append(cells)
    return C.md_table(headers, body)


def _heatmap(ax, fig, means: torch.Tensor, sampling, speed: float, title: str) -> None:
    im = ax.imshow(means.numpy(), cmap="viridis", aspect="auto", origin="lower")
    span = float(means.max() - means.min())
    for i in range(means.shape[0]):
        for j in range(means.shape[1]):
            light = float(means[i, j] - means.min()) < 0.6 * span
            ax.text(
                j,
                i,
                f"{means[i, j]:.2f}",
                ha="center",
                va="center",
                fontsize=7.5,
                color="w" if light else "k",
            )
    i, j = divmod(int(means.argmax()), means.shape[1])
    ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="red", lw=2.2))
    ax.set_xticks(range(len(MAX_NUMBERS)), [str(m) for m in MAX_NUMBERS])
    ax.set_yticks(range(len(sampling)), [f"{s} ({s * speed:.1f})" for s in sampling])
    ax.set_xlabel("Max_Numbers")
    ax.set_ylabel("s_n (v_eff, px/frame)")
    ax.set_title(title, fontsize=9.5)
    fig.colorbar(im, ax=ax, label="mean A_S", shrink=0.9)


def _plot(rows, scenes, bvalues, sampling, path: pathlib.Path) -> None:
    keys = [(scene, g) for scene in scenes for g in GS]
    fig, axes = plt.subplots(
        len(READINGS),
        len(keys),
        figsize=(4.9 * len(keys), 1.6 + 2.9 * len(READINGS) * max(1.0, len(sampling) / 5)),
        layout="constrained",
        squeeze=False,
    )
    for r, reading in enumerate(READINGS):
        for c, (scene, g) in enumerate(keys):
            means = torch.tensor(grid_means(rows, scene, g, "tuned", sampling, reading))
            title = (
                f"{scene}, g = {g:g}, b = {bvalues[scene, g, 'tuned']:.3g} (tuned)\n"
                f"Block SNR: {reading}; paper: v 0.6 ± 0.15, MN {C.PAPER_MAX_NUMBERS[g]}"
            )
            _heatmap(axes[r, c], fig, means, sampling, C.scene_speed(scene), title)
    fig.suptitle(
        "[NR08] mean A_S over frame sampling s_n and Max_Numbers (red: peak). Top: eq. (16) as "
        "in hocnet.dpa; bottom: Max_Numbers applied to every block"
    )
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
        quick: smoke run (8 frames of 32 x 32, s_n = 1, 2, 3 tuning b values, 2 seeds).
        seeds: scenes per setting (default 20, quick 2); as many tuning scenes.
        out_dir: output folder (default ``experiments/results``).
        progress: show a tqdm progress bar.

    Returns:
        Path of the markdown file.
    """
    n = C.n_seeds(quick, seeds)
    out = C.out_dir_of(out_dir)
    frames, size = (QUICK_FRAMES, QUICK_SIZE) if quick else (FRAMES, SIZE)
    sampling = QUICK_SAMPLING if quick else SAMPLING
    grid = QUICK_TUNE_GRID if quick else TUNE_GRID
    scenes = C.DPA_SCENES
    seed_values = C.seed_list(SEED_BASE, n)
    tune_seeds = C.seed_list(TUNE_SEED_BASE, n)
    weights = _weights()
    with C.single_thread(), C.Timer() as timer:
        tuned, tune_rows = tune_b(scenes, weights, grid, tune_seeds, frames, size, progress)
        bvalues = {}
        for scene in scenes:
            for g in GS:
                bvalues[scene, g, "tuned"] = tuned[scene, g]
                bvalues[scene, g, "EMC"] = effective_memory(weights, g, EMC)
        rows = evaluate(scenes, weights, bvalues, sampling, seed_values, frames, size, progress)
    parts = [
        C.header(
            "[NR08] frame sampling (effective velocity) and Max_Numbers",
            DESCRIPTION,
            quick=quick,
            n=n,
            seconds=timer.seconds,
        ),
        f"- Scenes: `na23a_like` (0.3 px/frame) / `npa_like` (0.2 px/frame), {size} x {size}, "
        f"simulated with 1 + {frames - 1} s_n frames of which every s_n-th is kept ({frames} "
        "frames for the DPA); peak SNR "
        + ", ".join(f"{s} {C.DPA_SNR_DB[s]:g} dB" for s in scenes)
        + f"; evaluation seeds {seed_values[0]} .. {seed_values[-1]}, tuning seeds "
        f"{tune_seeds[0]} .. {tune_seeds[-1]}.",
        f"- Whitening: {WHITENING}. DPA: {MATRIX} direction-dependent probability matrices "
        "(default jitter 0.5, PSF FWHM 3, p 0.5, penalty step 3).",
        "- b: *tuned* = the b of the grid "
        + ", ".join(f"g = {g:g}: {grid[g][0]:g} .. {grid[g][-1]:g}" for g in GS)
        + " (b = 0 excluded: it switches the accumulation off) with the highest tracking rate at "
        "s_n = 1 on the tuning scenes (ties: higher mean A_S), the `dpa-b-sweep` rule; "
        "*EMC* = effective-memory b (eq. 12-14, EMC 0.8).",
        f"- A_S: `algorithm_score(asf, true positions, last={LAST}, block=5, max_numbers=MN)` "
        "(eq. 17), MN = 1 .. 7; mean over the scenes. The Max_Numbers of the metric does not "
        "change the DPA, only how its output is scored.",
        "- Block SNR readings: *api* = `hocnet.dpa.block_snr` (the mean of the MN highest values "
        "of the target block against the mean and std of all pixels of the 8 surrounding "
        "blocks): the target value can only fall as MN grows while the background is unchanged, "
        "so under this reading A_S is non-increasing in MN and peaks at MN = 1 by construction. "
        "*blockwise* = an alternative reading (our guess, `blockwise_score` in "
        "`experiments/_expkit.py`): every block is summarised by the mean of its MN highest "
        "values and the target value is compared with the mean and std of the 8 background "
        "values.",
        "- Tuned b: "
        + "; ".join(f"{s}, g = {g:g}: b = {tuned[s, g]:g}" for s in scenes for g in GS)
        + ".",
        "",
        "## Where A_S peaks",
        "",
        _summary_table(rows, scenes, bvalues, sampling),
        "",
        "*Best s_n for each Max_Numbers 1..7* lists, for MN = 1, 2, ..., 7, the sampling with the "
        "highest mean A_S; *best Max_Numbers for each s_n* the converse.",
        "",
        "## Reference: A_S without accumulation (b = 0) versus the DPA, MN = 1 (api)",
        "",
        _reference_table(rows, scenes, bvalues, sampling),
        "",
        "With b = 0 the ASF is the whitened frame itself: any trend of this column with s_n "
        "comes from the scenes (longer simulated sequences, more cloud drift between kept "
        "frames), not from the accumulation.",
        "",
    ]
    for scene in scenes:
        for g in GS:
            for choice, reading in (("tuned", "api"), ("EMC", "api"), ("tuned", "blockwise")):
                b = bvalues[scene, g, choice]
                parts += [
                    f"## {scene}, g = {g:g}, b = {b:.3g} ({choice}), Block SNR {reading}: mean "
                    "A_S per s_n x Max_Numbers",
                    "",
                    _grid_table(rows, scene, g, choice, sampling, reading),
                    "",
                ]
    parts += [
        "Bold: the best Max_Numbers of each row. *Tracking*: the back-tracked track follows a "
        "true target (within 1.5 px in >= 80 % of the kept frames). The `paper` columns are the "
        "values [NR08] states (preferred velocity 0.6 ± 0.15 px/frame; Max_Numbers 3 for g = 0, "
        "1 for g = 1).",
        "",
        f"Note: {C.PAPER_NA_NOTE}",
        "",
        f"![{NAME}]({NAME}.png)",
    ]
    text = "\n".join(parts)
    md = C.write_text(out / f"{NAME}.md", text)
    C.write_csv(out / f"{NAME}.csv", tune_rows + rows)
    _plot(rows, scenes, bvalues, sampling, out / f"{NAME}.png")
    print(text)
    return md


def main(argv: Sequence[str] | None = None) -> pathlib.Path:
    """Command line entry point."""
    return C.main_for(NAME, DESCRIPTION, run, argv)


if __name__ == "__main__":
    main()

"""Table 2 of [NR08]: the algorithm score A_S and tracking versus the memory factor b.

The two scene families of ``hocnet.data.infrared`` follow section 3 of [NR08]: ``na23a_like`` (one
target in clear sky, right to left at 0.3 px/frame, peak 60 x the noise: Table 2's maximal target
peak) and ``npa_like`` (two targets at 0.2 px/frame, the studied one engulfed in clouds, peak 30 x
the noise, cloud plateau ``NPA_CLOUDS``), and a third, our addition: the NA23A-like scene with a
fluctuating target peak (``na23a_like(fluctuation=0.4)``: the per-frame peak is exponential, mean
0.4 x 60 sigma before clipping at 60 sigma (mean 0.367 x after it), so that Table 2's peak is
the *maximal* one and some frames lose the target, as the paper's noisy frames), run with the
paper DPA only. 12 seeded scenes each,
sampled at the s_n where the paper finds Table 2's ranges
(every 4th frame for NA23A, section 3.2.1(3); every 3rd for NPA, section 3.2.2(1): 1.2 and 0.6
px/frame between kept frames, 25 kept frames), anti-mean whitened, run through the DPA
(``hocnet.dpa.accumulate``, eq. 11) with the 5 x 5 probability matrices of section 3 (target speeds
0-1 px/frame), for every b of a grid: g = 0 (max, b = 0 .. 8 step 0.2, the paper's grid) and g = 1
(sum, b = 0 .. 1 step 0.05). A b above ``hocnet.dpa.b_limit(weights, g)`` (7.99 at g = 0, 1 at
g = 1) is outside the memory range of eq. (12)-(14): ``accumulate`` refuses it, and it is skipped
and reported as such. Variants: the paper's DPA, its equal-gain matrices
(``equalize_gain``, our addition); the source direction step (our earlier reading, kept as an
option) is measured in ``dpa-pd-snr``. For each b: the algorithm score A_S of
eq. (16)-(17) as the paper prints it (30 x 80 blocks for NA23A at s_n = 4, 30 x 30 for NPA, the
target block and its 8 neighbours,
Max_Numbers 3 for g = 0 and 1 for g = 1 as in Table 2, mean over the last six frames), our earlier
centred reading beside it, and whether the track back-tracked from the highest last-frame ASF of
the nine blocks (section 2.3) follows the studied target (within 1.5 px in >= 80 % of the
frames). The b range where tracking occurred (>= 50 % of the scenes) is set beside Table 2, and
beside it the ranges of three more criteria (``_nr08.CRITERIA``): *located* (the last-frame
detection within 1.5 px of the target and nearer its current than its previous position,
section 3.2.1(3)'s "track and locate"), *MN highest on target* (the
Max_Numbers highest pixels of the last target block lie in the target's 3 x 3 footprint, Figure
16's section (1), ``hocnet.dpa.metrics.highest_on_target(..., footprint="3x3")``) and the
*good range* (both; our reading of section 3.2.1(3)'s "good range of EMCs"). Eq. (17)'s terms
(SNR_TB, mean and std SNR_NTB, ``algorithm_score_terms``) are recorded per b, and a noise-free run
(``noise_free_gain``) shows
how much memory adds to the moving target against a standing pixel. b per direction and the
eq. (15) constants of the matrices beside the paper's.

Run: ``python experiments/dpa_b_sweep.py [--quick] [--seeds N] [--out DIR]`` or
``hocnet reproduce dpa-b-sweep``. ``--engine ray`` (the ``sweep`` extra) runs the same grid on
Ray Tune through ``hocnet.sweep.run_sweep``, one trial per (scene, variant, g, b), with the same
rows; ``--ray-dir DIR`` keeps Ray's experiment folder there (default: a new temporary folder)
and ``--resume`` continues an interrupted run in it (finished trials are not rerun);
``--address`` joins a running Ray cluster. The default engine, ``loop``, is unchanged.
"""

from __future__ import annotations

import functools
import pathlib
import sys
from collections.abc import Sequence

# the helpers next to this file, also when the script is loaded by path (`hocnet reproduce`)
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _expkit as C
import _nr08 as P
import matplotlib.pyplot as plt
import torch

from hocnet.data.infrared import NPA_CLOUDS
from hocnet.dpa import accumulate, algorithm_score, b_limit, backtrack
from hocnet.dpa.metrics import algorithm_score_terms, highest_on_target

NAME = "dpa-b-sweep"
DESCRIPTION = (
    "Table 2 of [NR08]: algorithm score A_S (eq. 16-17 as printed, last six frames) and tracking "
    "versus the memory factor b of the DPA, g = 0 (b = 0..8) and g = 1 (b = 0..1), 5 x 5 "
    "matrices (paper DPA and equal gain), on NA23A-like and "
    "NPA-like sequences; b per direction and eq. (15) constants beside the paper's."
)

SEED_BASE = 6000
SHAPES = {"NA23A": (25, 90, 240), "NPA": (25, 90, 120), P.FLUCT: (25, 90, 240)}
"""Frames seen by the DPA (after sampling); NA23A is 240 wide for its 30 x 80 blocks."""
QUICK_SHAPES = {"NA23A": (8, 45, 90), "NPA": (8, 45, 60), P.FLUCT: (8, 45, 90)}
BLOCK = {"NA23A": (30, 80), "NPA": (30, 30), P.FLUCT: (30, 80)}
"""[NR08] section 3.2.1(2): 30 x 80 blocks for NA23A at s_n = 4; 30 x 30 otherwise."""
QUICK_BLOCK = {"NA23A": 15, "NPA": 15, P.FLUCT: 15}
SCENES = (*P.SCENES, P.FLUCT)
"""The presets after section 3 of [NR08] and the fluctuating NA23A-like variant (paper DPA only)."""
PAPER_GRID = 0.2
"""Step of the paper's b grid: "b = [0 ... 8] at intervals of 0.2" (section 3.2.1(1), g = 0); for
g = 1 the paper does not give its step, and every g = 1 value it prints (0.2, 0.6, 0.8) is on the
same 0.2 grid (our reading)."""


def scene_label(scene: str) -> str:
    """Display name of a scene key."""
    return "NA23A-like, fluctuating peak" if scene == P.FLUCT else f"{scene}-like"


def scene_variants(scene: str, table: dict) -> list[str]:
    """The variants run on a scene: all of ``table``; the paper DPA only on the variant scenes."""
    return [P.PAPER_DPA] if scene in P.VARIANT_SCENES else list(table)


SEEDS = 12
"""Scenes per setting in a full run (fewer than ``_expkit``'s 20 to stay within ~6 minutes)."""
B_GRID = {
    0.0: [round(0.2 * i, 2) for i in range(41)],
    1.0: [round(0.05 * i, 2) for i in range(21)],
}
QUICK_B_GRID = {0.0: [0.0, 4.8, 8.0], 1.0: [0.0, 0.8, 1.2]}
LAST = 6
EMC = 0.8
CRITERIA_KEYS = ("tracked", "located", "top_on_target", "good")
"""Per-scene criteria of the b range (``_nr08.CRITERIA``; ``top_on_target``: the Max_Numbers
highest pixels of the last target block are target pixels, ``highest_on_target``)."""
TERMS = ("snr_tb", "ntb_mean", "ntb_std")
"""The terms of eq. (17) (``algorithm_score_terms``), mean over the last frames."""
TRACK_LEVEL = 0.5
GOAL = {0.0: 0.4, 1.0: 0.1}
"""Issue 8's goal: b range ends within 0.4 (g = 0) and 0.1 (g = 1) of the paper's."""
DIRECTION_READING = "today's direction reading"
OUTSIDE = "outside the memory range of eq. (12)-(14)"


def variants(direction: bool = False) -> dict[str, dict]:
    """Variant label -> ``{"equal": bool, "options": accumulate kwargs}``.

    Today's direction reading is measured in ``dpa-pd-snr``; here only on request
    (``direction=True``), to keep the full run within about 6 minutes.
    """
    out = {P.PAPER_DPA: {"equal": False, "options": {}}, P.EQUAL: {"equal": True, "options": {}}}
    option = P.direction_option() if direction else None
    if option is not None:
        out[DIRECTION_READING] = {"equal": False, "options": option}
    return out


def _weights(variant: dict, g: float) -> torch.Tensor:
    return P.weights(equal_g=g if variant["equal"] else None)


def valid_bs(weights: torch.Tensor, g: float, bs: Sequence[float]) -> tuple[list, list]:
    """``(kept, skipped)``: the b of ``bs`` within ``[0, b_limit(weights, g)]`` and the rest."""
    limit = b_limit(weights, g) * (1 + 1e-6)  # accumulate allows float32 rounding above it
    return [b for b in bs if b <= limit], [b for b in bs if b > limit]


def _block_shape(block) -> tuple[int, int]:
    return (block, block) if isinstance(block, int) else tuple(block)


def sampled(scene: str, seeds: Sequence[int], shape: tuple[int, int, int]) -> tuple:
    """Whitened frames ``(B, T, H, W)`` and the studied target ``(B, T, 2)`` at Table 2's s_n.

    The scene is simulated with ``1 + (T - 1) s_n`` frames and every ``s_n``-th one is kept
    (``s_n = P.PAPER_SN_TABLE2[paper_name(scene)]``), as [NR08] samples its sequences.
    """
    step = P.PAPER_SN_TABLE2[P.paper_name(scene)]
    n_t, height, width = shape
    seq = P.scene(scene, seeds, shape=(1 + (n_t - 1) * step, height, width))
    frames = C.whiten(seq.frames[:, ::step], "anti_mean")
    return frames, seq.positions[:, 0, ::step]  # the studied target


def _job_rows(job: dict, frames, truth, weights, seeds, block) -> list[dict]:
    """The rows of one (scene, variant, g, b) job: one per seed."""
    scene, variant, g, b = job["scene"], job["variant"], job["g"], job["b"]
    state = accumulate(frames, weights, b, g, **job["options"])
    last = min(LAST, frames.shape[1])
    mn = P.PAPER_MAX_NUMBERS[g]
    terms = algorithm_score_terms(state.asf, truth, last=last, block=block[scene], max_numbers=mn)
    centred = algorithm_score(state.asf, truth, last=last, reading="centred")
    start = P.nine_block_start(state.asf, truth, block[scene])
    path = backtrack(state, start)
    hit, found = P.tracked(path, truth), P.located(path, truth)
    top = highest_on_target(state.asf, truth, block=block[scene], max_numbers=mn, footprint="3x3")
    return [
        {
            "table": "sweep",
            "scene": scene,
            "variant": variant,
            "g": g,
            "b": b,
            "seed": seed,
            "a_s": float(terms["score"][i]),
            "a_s_centred_mn1": float(centred[i]),
            "snr_tb": float(terms["snr_tb"][i]),
            "ntb_mean": float(terms["ntb_mean"][i]),
            "ntb_std": float(terms["ntb_std"][i]),
            "tracked": int(hit[i]),
            "located": int(found[i]),
            "top_on_target": int(top[i]),
            "good": int(found[i] and top[i]),
        }
        for i, seed in enumerate(seeds)
    ]


def _jobs(scenes, table, grid) -> list[dict]:
    """The (scene, variant, g, b) jobs of the grid, b within the memory range only."""
    weights = {(v, g): _weights(table[v], g) for v in table for g in grid}
    return [
        {
            "scene": s,
            "variant": v,
            "g": g,
            "b": b,
            "equal": table[v]["equal"],
            "options": dict(table[v]["options"]),
        }
        for s in scenes
        for v in scene_variants(s, table)
        for g in grid
        for b in valid_bs(weights[v, g], g, grid[g])[0]
        if not (table[v]["equal"] and g == 1.0)  # sum-to-one matrices: the same recursion
    ]


def evaluate(
    scenes, table, grid, seeds, shapes, block, progress, *, engine="loop", ray=None
) -> list[dict]:
    """One row per (scene, variant, g, b, seed), b within the memory range only.

    ``engine="loop"`` runs the jobs here, one after the other; ``engine="ray"`` runs each
    (scene, variant, g, b) job as one trial of a ``hocnet.sweep.run_sweep`` grid on Ray Tune
    (``ray``: its keyword arguments, e.g. ``path``, ``resume``, ``address``). Both give the
    same rows in the same order.
    """
    jobs = _jobs(scenes, table, grid)
    if engine == "ray":
        return _evaluate_ray(jobs, seeds, shapes, block, progress, **(ray or {}))
    C.check_engine(engine)
    data = {}
    for scene in scenes:
        data[scene] = sampled(scene, seeds, shapes[scene])
    weights = {(v, g): _weights(table[v], g) for v in table for g in grid}
    rows = []
    for job in C.progress(jobs, enabled=progress, desc=NAME):
        frames, truth = data[job["scene"]]
        w = weights[job["variant"], job["g"]]
        rows += _job_rows(job, frames, truth, w, seeds, block)
    return rows


@functools.lru_cache(maxsize=4)
def _sampled_cached(scene: str, seeds: tuple, shape: tuple) -> tuple:
    """:func:`sampled`, cached per Ray worker (every job of a scene reuses its frames)."""
    return sampled(scene, list(seeds), shape)


def ray_job(job: dict, seeds, shapes, block) -> list[dict]:
    """One job in a Ray worker: the same computation as the loop engine's."""
    frames, truth = _sampled_cached(job["scene"], tuple(seeds), tuple(shapes[job["scene"]]))
    weights = P.weights(equal_g=job["g"] if job["equal"] else None)
    return _job_rows(job, frames, truth, weights, seeds, block)


def _evaluate_ray(jobs, seeds, shapes, block, progress, **ray) -> list[dict]:
    """Run the jobs on Ray Tune, one trial per job (the ``--engine ray`` of this script)."""
    shared = {"seeds": list(seeds), "shapes": shapes, "block": block}
    per_job = C.ray_map(__file__, "ray_job", jobs, shared, name=NAME, progress=progress, **ray)
    return [row for rows in per_job for row in rows]


def summarise(rows, scene, variant, g, bs) -> dict:
    sel = [r for r in rows if r["scene"] == scene and r["variant"] == variant and r["g"] == g]
    a_mean, a_std, c_mean, rate = [], [], [], []
    extra: dict[str, list[float]] = {k: [] for k in (*CRITERIA_KEYS, *TERMS)}
    for b in bs:
        at = [r for r in sel if r["b"] == b]
        a_mean.append(C.mean(r["a_s"] for r in at))
        a_std.append(C.std(r["a_s"] for r in at))
        c_mean.append(C.mean(r["a_s_centred_mn1"] for r in at))
        rate.append(C.mean(r["tracked"] for r in at))
        for key in extra:
            extra[key].append(C.mean(float(r[key]) for r in at))
    ranges = C.b_ranges(bs, rate, TRACK_LEVEL)
    on_grid = [i for i, b in enumerate(bs) if abs(b / PAPER_GRID - round(b / PAPER_GRID)) < 1e-9]
    coarse = C.b_ranges([bs[i] for i in on_grid], [rate[i] for i in on_grid], TRACK_LEVEL)
    peak = max(range(len(bs)), key=lambda i: a_mean[i])
    criteria = {}
    for key in CRITERIA_KEYS:
        fine = C.b_ranges(bs, extra[key], TRACK_LEVEL)
        grid_range = C.b_ranges(
            [bs[i] for i in on_grid], [extra[key][i] for i in on_grid], TRACK_LEVEL
        )
        shown = fine if grid_range == fine else f"{fine} ({PAPER_GRID:g} grid: {grid_range})"
        criteria[key] = {"range": shown, "span": P.ends_of(fine)}
    return {
        **extra,
        "criteria": criteria,
        "b": list(bs),
        "a_mean": a_mean,
        "a_std": a_std,
        "c_mean": c_mean,
        "rate": rate,
        "range": ranges,
        "span": P.ends_of(ranges),
        "range_coarse": coarse,
        "peak_b": bs[peak],
        "peak_a": a_mean[peak],
    }


def _range_table(summaries, scenes, table, grid) -> str:
    headers = [
        "sequence",
        "g",
        "variant",
        "b where tracking occurred (>= 50 % of scenes)",
        f"same, on the paper's {PAPER_GRID:g} grid",
        "paper Table 2",
        "our ends - paper's",
        "within the goal (0.4 / 0.1)",
        "b of max mean A_S (A_S)",
        "EMC b: direction 9 / 1-8",
    ]
    body = []
    for scene in scenes:
        for g in grid:
            paper = P.PAPER_B_RANGE[P.paper_name(scene), g]
            for variant in scene_variants(scene, table):
                s = summaries[scene, variant, g]
                w = _weights(table[variant], g)
                span = s["span"]
                ok = (
                    span is not None
                    and max(abs(span[0] - paper[0]), abs(span[1] - paper[1])) <= GOAL[g] + 1e-9
                )
                body.append(
                    [
                        scene_label(scene),
                        f"{g:g}",
                        variant,
                        s["range"],
                        s["range_coarse"],
                        P.fmt_range(paper),
                        P.gap(span, paper),
                        "yes" if ok else "no",
                        f"{s['peak_b']:g} ({s['peak_a']:.2f})",
                        f"{P.emc_b(w[8], g, EMC):.3g} / {P.emc_b(w[0], g, EMC):.3g}",
                    ]
                )
    return C.md_table(headers, body)


def _criteria_table(summaries, scenes, table, grid) -> str:
    """The b range of each criterion (``CRITERIA_KEYS``) beside Table 2, with the gaps."""
    headers = ["sequence", "g", "variant", "paper Table 2"]
    labels = {
        "tracked": "tracked (>= 80 % of frames)",
        "located": "located (last frame)",
        "top_on_target": "MN highest on target",
        "good": "good range: located and MN highest on target",
    }
    for key in CRITERIA_KEYS:
        headers += [labels[key], "ends - paper's"]
    headers.append("within the goal (tracked / located / good)")
    body = []
    for scene in scenes:
        for g in grid:
            paper = P.PAPER_B_RANGE[P.paper_name(scene), g]
            for variant in scene_variants(scene, table):
                s = summaries[scene, variant, g]
                row = [scene_label(scene), f"{g:g}", variant, P.fmt_range(paper)]
                ok = []
                for key in CRITERIA_KEYS:
                    c = s["criteria"][key]
                    row += [c["range"], P.gap(c["span"], paper)]
                    if key != "top_on_target":
                        span = c["span"]
                        hit = (
                            span is not None
                            and max(abs(span[0] - paper[0]), abs(span[1] - paper[1]))
                            <= GOAL[g] + 1e-9
                        )
                        ok.append("yes" if hit else "no")
                row.append(" / ".join(ok))
                body.append(row)
    return C.md_table(headers, body)


def _terms_note(summaries, scenes) -> str:
    """Eq. (17)'s terms at b = 0, the A_S peak and the paper's lower end (paper DPA, g = 0)."""
    lines = []
    for scene in scenes:
        s = summaries[scene, P.PAPER_DPA, 0.0]
        low = P.PAPER_B_RANGE[P.paper_name(scene), 0.0][0]
        picks = sorted({0.0, s["peak_b"], low, 5.6} & set(s["b"]))
        cells = []
        for b in picks:
            i = s["b"].index(b)
            cells.append(
                f"b = {b:g}: A_S {s['a_mean'][i]:.1f}, SNR_TB {s['snr_tb'][i]:.2f}, "
                f"SNR_NTB {s['ntb_mean'][i]:.2f} ± {s['ntb_std'][i]:.3f}, MN highest on "
                f"target {C.pct(s['top_on_target'][i], 0)}"
            )
        lines.append(f"  - {scene_label(scene)}: " + "; ".join(cells) + ".")
    return "\n".join(lines)


GAIN_BS = (0.0, 2.4, 4.4, 5.0, 5.6, 5.8, 6.0)
"""The b of the noise-free gain table (g = 0)."""


def noise_free_gain(bs=GAIN_BS, seeds=(0, 1, 2, 3), quick: bool = False) -> list[dict]:
    """Noise-free NA23A-like target at s_n = 4 (1.2 px/frame): what memory does to it, per b.

    The ``na23a_like`` scene with the noise scaled down to 1e-6 of the peak (no whitening: a
    positive, noise-free target and jitter only), run through the paper DPA at g = 0. Per b:
    the last-frame ASF of the best pixel of the target's 3 x 3 footprint (around its rounded
    last-frame position, as ``highest_on_target(..., footprint="3x3")``) over the same at b = 0
    (its single-frame value; ``1 / (1 - gain)`` for a target whose score grows by ``gain`` per
    frame), the per-frame gain of a standing pixel ``b max W(9)``, and the best pixel outside
    the footprint (the trail or the pixel of origin) over the target's. Our diagnostic of the A_S
    curve.
    """
    from hocnet.data.infrared import na23a_like

    n_t, height, width = (8, 30, 60) if quick else (25, 40, 90)
    step = P.PAPER_SN_TABLE2["NA23A"]
    seqs = [
        na23a_like(shape=(1 + (n_t - 1) * step, height, width), seed=s, noise_sigma=1e-6)
        for s in seeds
    ]
    seq = C.stack_sequences(seqs)
    frames, truth = seq.frames[:, ::step].double(), seq.positions[:, 0, ::step]
    w = P.weights().double()
    ys = torch.arange(height).view(1, -1, 1).double()
    xs = torch.arange(width).view(1, 1, -1).double()
    tx = torch.floor(truth[:, -1, 0].double() + 0.5).view(-1, 1, 1)
    ty = torch.floor(truth[:, -1, 1].double() + 0.5).view(-1, 1, 1)
    near = ((xs - tx).abs() <= 1) & ((ys - ty).abs() <= 1)  # the 3 x 3 footprint

    def best(b: float) -> tuple[torch.Tensor, torch.Tensor]:
        last = accumulate(frames, w, b, 0.0).asf[:, -1]
        target = last.masked_fill(~near, -torch.inf).flatten(1).amax(dim=1)
        return target, last.masked_fill(near, -torch.inf).flatten(1).amax(dim=1)

    single, _ = best(0.0)
    out = []
    for b in bs:
        target, other = best(b)
        out.append(
            {
                "b": b,
                "standing": b * float(w[8].max()),
                "target": float((target / single).mean()),
                "other": float((other / target).mean()),
            }
        )
    return out


def _gain_table(gains: list[dict]) -> str:
    headers = [
        "b",
        "standing pixel's gain b max W(9)",
        "target's last ASF / its value at b = 0",
        "the target's gain 1 - ASF(b = 0) / ASF",
        "best non-target / target",
    ]
    body = [
        [
            f"{r['b']:g}",
            f"{r['standing']:.3f}",
            f"{r['target']:.2f}",
            f"{1 - 1 / r['target']:.3f}",
            f"{r['other']:.2f}",
        ]
        for r in gains
    ]
    return C.md_table(headers, body)


MEMORY_MATRICES = {
    "7 x 7, v_max 2 (section 2.2.1; the default)": (7, 2.0),
    "5 x 5, v_max 1 (section 3; this sweep's)": (5, 1.0),
}
"""Matrices whose b per direction and eq. (15) line are tabulated: (window, v_max)."""


def overtake_sentence(gains: list[dict]) -> str:
    """Where the best non-target pixel overtakes the target in the noise-free ``gains``.

    The first tabulated b whose ``other`` ratio (best non-target / target) exceeds 1 and the b
    before it, read from the measured rows (sorted by b).

    Examples:
        >>> overtake_sentence([{"b": 0.0, "other": 0.5}, {"b": 5.6, "other": 0.9},
        ...                    {"b": 5.8, "other": 1.1}])
        'between b = 5.6 and 5.8'
        >>> overtake_sentence([{"b": 0.0, "other": 0.5}, {"b": 6.0, "other": 0.9}])
        'nowhere up to b = 6'
        >>> overtake_sentence([{"b": 0.0, "other": 1.2}])
        'already at b = 0'
    """
    rows = sorted(gains, key=lambda r: r["b"])
    for i, r in enumerate(rows):
        if r["other"] > 1.0:
            return (
                f"between b = {rows[i - 1]['b']:g} and {r['b']:g}"
                if i
                else (f"already at b = {r['b']:g}")
            )
    return f"nowhere up to b = {rows[-1]['b']:g}"


PAPER_TOP_ON_TARGET = {5: 5.6, 3: 5.8}
"""[NR08] section 3.2.1(3), Figures 16-17: the b up to which the 5 (3) highest last-frame pixels
are target pixels, NA23A at g = 0, s_n = 4; above it trail pixels score higher."""


def _why_note(summaries, scenes, grid, gains: list[dict]) -> str:
    """Why our ranges differ from Table 2's, with the measured b = 0 rates."""
    at0 = "; ".join(
        f"{scene_label(s)}: "
        + " / ".join(
            f"g = {g:g} {C.pct(summaries[s, P.PAPER_DPA, g]['rate'][0], 0)}"
            for g in grid
            if summaries[s, P.PAPER_DPA, g]["b"][0] == 0.0
        )
        for s in scenes
    )
    w9 = P.weights()[8]
    still = 1.0 / float(w9.max())
    na23 = summaries["NA23A", P.PAPER_DPA, 0.0]["span"]
    na23_end = "no tracking" if na23 is None else f"{na23[1]:g}"
    crit = summaries["NA23A", P.PAPER_DPA, 0.0]["criteria"]
    loc = crit["located"]["span"]
    loc_end = "nowhere" if loc is None else f"up to {loc[1]:g}"
    top = crit["top_on_target"]["span"]
    top_end = "nowhere" if top is None else f"up to {top[1]:g}"
    return (
        "### Why the ranges differ (measured above; our reading where the paper is silent)\n\n"
        "- **Lower ends at g = 0 are not tracking limits in the paper.** At b = 0 eq. (2) is "
        "ASF = WF for every g, and the direction step of eq. (7)-(8) does not involve g or b, so "
        "the ASF, the tracking matrix and the track are the same for g = 0 and g = 1 "
        "(`test_b_zero_is_the_same_dpa_for_every_g`). Tracking at b = 0 (paper DPA) here: "
        f"{at0}. Table 2 nevertheless gives NPA tracking from b = 0 with g = 1 but from b = 2 "
        "with g = 0, which no single tracking criterion can give; for NA23 the text says the lower "
        "end 4.4 comes from the A_S curve (Figure 16, section 3.2.1(3)), not from a tracking "
        "failure. Our g = 0 lower ends (tracking) therefore start lower than the paper's.\n"
        "- **NA23 g = 1 starts at 0.2 in the paper**, i.e. the track is lost at b = 0: with a "
        "constant 60 sigma peak our NA23A-like target is found in every single frame (the paper "
        "says as much at s_n = 1: 'the algorithm is not needed for the detection'). The "
        "fluctuating variant (frames where the target fades) loses the track at b = 0 and keeps "
        "it with memory, as the paper; it also lowers the g = 0 upper end (faded frames let the "
        "trail win earlier).\n"
        "- **Upper ends at g = 0** are where the trail / pixel of origin (NA23) or the static "
        "cloud edges (NPA) overtake the moving target: a pixel standing still keeps "
        f"b max(W(9)) of its score per frame, which reaches 1 at b = 1 / max(W(9)) = {still:.3g} "
        "for the 5 x 5 matrices; the paper tracks NA23 'reliably' up to 5.6 and 'inaccurately' "
        f"up to 6.0 (Figure 18), our NA23A-like (paper DPA) up to {na23_end} (tracked in 80 % of "
        f"the frames); its last-frame detection is on the target {loc_end} (*located*, the "
        "paper's 'track and locate', table below), and its 3 highest target-block pixels are "
        f"target pixels {top_end} (paper: up to 5.8, Figure 16). The moving target's per-frame "
        "gain stays below a standing pixel's (noise-free table below), so the trail gains on it "
        f"as b grows; noise-free, the best non-target pixel overtakes the target "
        f"{overtake_sentence(gains)} (table below; the paper's 5 highest pixels are target pixels "
        f"up to b = {PAPER_TOP_ON_TARGET[5]:g} and its 3 highest up to {PAPER_TOP_ON_TARGET[3]:g}, "
        "Figures 16-17). "
        "NPA's upper end is set by the cloud plateau of "
        f"`NPA_CLOUDS`, chosen to match ({NPA_CLOUDS.amplitude:g} sigma).\n"
        "- **g = 1 upper ends**: the paper's 0.2 grid cannot resolve ends between 0.8 and 1; "
        "the column 'on the paper's 0.2 grid' reads ours on that grid. It does not cover b = "
        "1, which is on the grid: our NA23A-like scenes (and the fluctuating variant) track "
        "at b = 1, Table 2 ends NA23 g = 1 at 0.8. The paper is not consistent here: for s_n "
        "= 1 (section 3.2.1(1), Figure 11) it gives 'the relevant range of b is 0 <= b <= 1' "
        "for g = 1, with the A_S of the frames converging and the TB's SNR falling at around "
        "b = 1, and a 'snow ball' above b = 1 that grows until the target is engulfed; Table "
        "2's 0.2-0.8 repeats its summary (3.2.1(4)), which we read as the s_n = 4 result "
        "('the best tracking is achieved for b = 0.8', 3.2.1(3); Figure 19). At g = 1 the "
        "eq. (5) matrices sum to "
        "1, so b = 1 is exactly the EMC-1 limit of eq. (12)-(14): a standing pixel keeps all "
        "of its score (the library refuses b > 1, `b_limit`). Within our 25 frames the snow "
        "ball does not engulf the 60-sigma target (`python "
        "experiments/_dpa_snowball_diag.py`: NA23A-like at s_n = 4, g = 1, 6 seeds, 31 x 31 "
        "window around the target): at b = 0.6, 0.8 and 1 no pixel's ASF exceeds the target's "
        "in any of frames 1, 5, 10, 15, 20, 25; the ball (pixels >= half the target's ASF) covers "
        "2.2-2.8 px at b = 0.6, 2.5-3.3 at b = 0.8 and 3.0-4.8 at b = 1 (frames 5-25); the "
        "target's 8 neighbours hold 0.32-0.35, 0.34-0.38 and 0.38-0.41 of its ASF; its local "
        "SNR (over the window outside its 7 x 7) is 48.5 at frame 1 and 54.7, 44.6 and 15.7 "
        "at frame 25. So at b = 1 the TB's SNR falls, as the paper says, but the ball stays a "
        "few pixels wide and the target its highest pixel: the track holds in 6 of 6 scenes."
    )


def _memory_table() -> str:
    headers = [
        "matrices",
        "direction",
        "max(w)",
        "sum(w)",
        "b at g = 0 (EMC 0.8)",
        "b at g = 1",
        "eq. (15) ours: 1/b = slope g + intercept",
        "paper eq. (15)",
        "slope / intercept: ours vs paper",
        "paper b at g = 0",
    ]
    body = []
    for name, (window, v_max) in MEMORY_MATRICES.items():
        w = P.weights(window, v_max).double()
        for label, dirs in (("directions 1-8", range(8)), ("direction 9", [8])):
            ps, pi = P.PAPER_EQ15[label]
            lines = {tuple(round(v, 4) for v in P.memory_constants(w[d], EMC)) for d in dirs}
            slope, intercept = P.memory_constants(w[dirs[0]], EMC)
            d = dirs[0]
            body.append(
                [
                    name,
                    label + ("" if len(lines) == 1 else " (direction 1 shown; they differ)"),
                    f"{float(w[d].max()):.4f}",
                    f"{float(w[d].sum()):.4f}",
                    f"{P.emc_b(w[d], 0.0, EMC):.3f}",
                    f"{P.emc_b(w[d], 1.0, EMC):.3f}",
                    f"1/b = {slope:.3f} g + {intercept:.3f}",
                    f"1/b = {ps:.3f} g + {pi:.3f}",
                    f"{100 * (slope / ps - 1):+.1f} % / {100 * (intercept / pi - 1):+.1f} %",
                    f"{P.PAPER_B_G0[label]:g}",
                ]
            )
    return C.md_table(headers, body)


def _sweep_table(summaries, scene, table, g, bs, n) -> str:
    headers = ["b"]
    for variant in scene_variants(scene, table):
        headers += [
            f"A_S ({variant})",
            f"A_S centred MN 1 ({variant})",
            f"tracking ({variant})",
            f"located ({variant})",
            f"MN highest on target ({variant})",
        ]
    headers += ["SNR_TB (paper DPA)", "SNR_NTB mean ± std (paper DPA)"]
    body = []
    for b in bs:
        cells = [f"{b:g}"]
        for variant in scene_variants(scene, table):
            s = summaries[scene, variant, g]
            if b not in s["b"]:
                cells += [OUTSIDE, "", "", "", ""]
                continue
            i = s["b"].index(b)
            cells += [
                C.format_mean_std(s["a_mean"][i], s["a_std"][i], n, 2),
                f"{s['c_mean'][i]:.2f}",
                C.pct(s["rate"][i], 0),
                C.pct(s["located"][i], 0),
                C.pct(s["top_on_target"][i], 0),
            ]
        s = summaries[scene, P.PAPER_DPA, g]
        if b in s["b"]:
            i = s["b"].index(b)
            cells += [f"{s['snr_tb'][i]:.2f}", f"{s['ntb_mean'][i]:.2f} ± {s['ntb_std'][i]:.3f}"]
        else:
            cells += ["", ""]
        body.append(cells)
    return C.md_table(headers, body)


def _plot(summaries, scenes, table, grid, path: pathlib.Path) -> None:
    keys = [(s, g) for s in scenes for g in grid]
    fig, axes = plt.subplots(
        2, len(keys), figsize=(4.6 * len(keys), 7.6), layout="constrained", sharex="col"
    )
    colours = dict(zip(table, ("tab:blue", "tab:orange", "tab:green")))
    for col, (scene, g) in enumerate(keys):
        top, bottom = axes[0, col], axes[1, col]
        for variant in scene_variants(scene, table):
            s = summaries[scene, variant, g]
            C.plot_band(top, s["b"], s["a_mean"], s["a_std"], color=colours[variant], label=variant)
            bottom.plot(s["b"], [100 * r for r in s["rate"]], "-o", ms=3, color=colours[variant])
            bottom.plot(
                s["b"],
                [100 * r for r in s["located"]],
                "--",
                color=colours[variant],
                label="located (last frame), dashed",
            )
            bottom.plot(
                s["b"],
                [100 * r for r in s["good"]],
                ":",
                color=colours[variant],
                label="good range criterion, dotted",
            )
        low, high = P.PAPER_B_RANGE[P.paper_name(scene), g]
        for ax in (top, bottom):
            ax.axvspan(low, high, color="0.85", zorder=0, label="paper Table 2 range")
            ax.grid(alpha=0.3)
        bottom.axhline(100 * TRACK_LEVEL, color="k", ls=":", lw=1)
        top.set_title(f"{scene_label(scene)}, g = {g:g} (MN {P.PAPER_MAX_NUMBERS[g]})", fontsize=9)
        top.set_ylabel("A_S, eq. (16)-(17) (mean ± std)")
        bottom.set_ylabel("% of scenes (solid: tracked)")
        bottom.set_xlabel("memory factor b")
        bottom.set_ylim(-3, 103)
    handles: dict = {}
    for ax in axes.flat:
        for h, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, h)
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=4)
    fig.suptitle("[NR08] Table 2: A_S and tracking versus b (grey: the paper's range)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(
    *,
    quick: bool = False,
    seeds: int | None = None,
    out_dir: pathlib.Path | None = None,
    progress: bool = True,
    engine: str = "loop",
    ray: dict | None = None,
) -> pathlib.Path:
    """Run the experiment; write ``<NAME>.md``, ``.csv`` and ``.png``; return the md path.

    Args:
        quick: smoke run (8 frames of 45 x 90 / 45 x 60, 15 x 15 blocks, 3 b values per g,
            2 seeds).
        seeds: scenes per setting (default 12, quick 2).
        out_dir: output folder (default ``experiments/results``).
        progress: show a tqdm progress bar (``engine="ray"``: Ray's progress table).
        engine: ``"loop"`` (default) or ``"ray"`` (Ray Tune, see :func:`evaluate`).
        ray: keyword arguments of the Ray engine (``path``, ``resume``, ``address``,
            ``num_cpus``).

    Returns:
        Path of the markdown file.
    """
    n = C.n_seeds(quick, seeds) if (quick or seeds is not None) else SEEDS
    out = C.out_dir_of(out_dir)
    shapes = QUICK_SHAPES if quick else SHAPES
    block = QUICK_BLOCK if quick else BLOCK
    grid = QUICK_B_GRID if quick else B_GRID
    scenes = SCENES
    table = variants()
    seed_values = C.seed_list(SEED_BASE, n)
    with C.single_thread(), C.Timer() as timer:
        rows = evaluate(
            scenes, table, grid, seed_values, shapes, block, progress, engine=engine, ray=ray
        )
        gains = noise_free_gain(quick=quick)
    for row in [r for r in rows if table[r["variant"]]["equal"] is False and r["g"] == 1.0]:
        if row["variant"] == P.PAPER_DPA:  # equal gain at g = 1 is the paper's recursion
            rows.append({**row, "variant": P.EQUAL, "copied_from": P.PAPER_DPA})
    kept = {(v, g): valid_bs(_weights(table[v], g), g, grid[g]) for v in table for g in grid}
    summaries = {
        (s, v, g): summarise(rows, s, v, g, kept[v, g][0])
        for s in scenes
        for v in scene_variants(s, table)
        for g in grid
    }
    skipped = sorted({(g, b) for (_, g), (_, out) in kept.items() for b in out})
    limits = ", ".join(f"{b_limit(P.weights(), g):.3g} at g = {g:g}" for g in grid)
    skip_note = (
        f"- b above `b_limit(weights, g)` ({limits}; eq. (12)-(14): above it the effective "
        "memory coefficient exceeds 1 in every direction) is skipped, "
        + (
            "here " + ", ".join(f"b = {b:g} at g = {g:g}" for g, b in skipped) + f": {OUTSIDE}."
            if skipped
            else "none in this grid."
        )
    )
    missing = (
        ' The source direction step (our earlier reading, `direction_step="source"`) is '
        "measured side by side in `dpa-pd-snr`."
    )
    parts = [
        C.header(
            "[NR08] Table 2: A_S and tracking versus the memory factor b",
            DESCRIPTION,
            quick=quick,
            n=n,
            seconds=timer.seconds,
        ),
        "- Scenes (section 3 of [NR08]), sampled at the s_n of Table 2's ranges: NA23A-like "
        f"s_n = {P.PAPER_SN_TABLE2['NA23A']} (section 3.2.1(3)), NPA-like s_n = "
        f"{P.PAPER_SN_TABLE2['NPA']} (section 3.2.2(1)): every s_n-th frame of 1 + (T - 1) s_n "
        "simulated frames is kept. `na23a_like` "
        f"{' x '.join(map(str, shapes['NA23A']))} after sampling (one target in clear sky, right "
        f"to left at 0.3 px/frame, peak SNR {P.db(P.PAPER_PEAK['NA23A']):.1f} dB = Table 2's "
        "peak ~60 x the "
        f"noise) and `npa_like` {' x '.join(map(str, shapes['NPA']))} (two targets bottom to top "
        f"at 0.2 px/frame, the studied one under a cloud, peak {P.db(P.PAPER_PEAK['NPA']):.1f} "
        f"dB = ~30 x the noise, cloud plateau {NPA_CLOUDS.amplitude:g} x the noise: `NPA_CLOUDS`), "
        f"and *{scene_label(P.FLUCT)}* (`na23a_like(fluctuation={P.FLUCTUATION:g})`, our addition: "
        "the per-frame peak is exponential with mean "
        f"{P.FLUCTUATION:g} x the 60 sigma peak, clipped at it, so that 60 is the *maximal* peak "
        "of Table 2 and some frames lose the target, as the paper's noisy frames; paper DPA "
        "only), jitter 0.5 px, seeds "
        f"{seed_values[0]} .. {seed_values[-1]}; only the studied target (target 0) is scored, as "
        "in the paper.",
        "- Whitening: anti-mean (7 x 7 ring around a 3 x 3 guard), as the paper's antimedian-like "
        "mean filter of section 2.1.",
        "- DPA: `accumulate(frames, probability_matrices(5, v_max=1), b, g)` (section 3: 5 x 5 "
        "matrices for 0-1 px/frame); *equal gain*: `equalize_gain(..., g)` (our addition: every "
        "direction gets the per-step gain of direction 1; at g = 1 the eq. (5) matrices sum to 1 "
        "and already have equal gains, so its g = 1 rows repeat the paper DPA's)." + missing,
        f"- A_S: `algorithm_score(asf, truth, last={LAST}, block=B, "
        "max_numbers=MN)`, the paper's reading of eq. (16)-(17) (tiled blocks anchored on the "
        "target's first-frame pixel, per-block SNR, (SNR_TB - mean SNR_NTB) / std SNR_NTB), MN = "
        "3 for g = 0 and 1 for g = 1 (Table 2). *A_S centred*: our earlier reading "
        "(`reading='centred'`, 5 x 5 blocks centred on the truth, MN 1). Blocks B (rows x "
        "columns): "
        + ", ".join(
            f"{scene_label(s)} {' x '.join(map(str, _block_shape(block[s])))}" for s in scenes
        )
        + ".",
        skip_note,
        "- Tracking: the track back-tracked from the highest last-frame ASF of the nine blocks "
        "(section 2.3: the algorithm is run over the target block and its 8 neighbours; "
        "`_nr08.nine_block_start`) lies within 1.5 px of "
        "the studied target in >= 80 % of the frames. *Tracking occurred* at a b when it holds "
        "in >= 50 % of the scenes. Beside it (same >= 50 % rule): *located*, the last-frame "
        "detection (the start of that track) within 1.5 px of the target's last-frame position "
        "and nearer to it than to its previous-frame position, so a track one frame behind does "
        "not count (`_nr08.located`, "
        "section 3.2.1(3): 'able to track and locate the target'), *MN highest on target*, the "
        "Max_Numbers highest pixels of the last frame's target block all in the target's 3 x 3 "
        "footprint around its rounded last-frame position (our reading: the paper's target "
        "subtends about a pixel blurred by the 3 x 3 spread of W_basic; "
        "`hocnet.dpa.metrics.highest_on_target(..., footprint='3x3')`, Figure 16's section (1), "
        "Figures 17 and 19), and the *good range*, both at once (our reading of section "
        "3.2.1(3)'s 'good range of EMCs').",
        "",
        "## b range where tracking occurred, beside Table 2 of [NR08]",
        "",
        _range_table(summaries, scenes, table, grid),
        "",
        f"Paper: {P.PAPER_B_NOTE} Goal: ends within 0.4 (g = 0) and 0.1 (g = 1) of the paper's.",
        "",
        _why_note(summaries, scenes, grid, gains),
        "",
        "## b range by criterion, beside Table 2 of [NR08]",
        "",
        _criteria_table(summaries, scenes, table, grid),
        "",
        "Criteria per scene (a b counts when it holds in >= 50 % of the scenes): tracked = the "
        "back-tracked track within 1.5 px in >= 80 % of the frames (the table above); located = "
        "its last-frame pixel within 1.5 px of the target and nearer its current than its previous "
        "position; MN highest on target = the Max_Numbers highest pixels of the last target "
        "block in the target's 3 x 3 footprint; good = located and MN "
        "highest on target (section 3.2.1(3): 'the algorithm was able to track and locate the "
        "target up to b = 6.0. Using that and Figure 16 leads to the conclusion that a good "
        "range of EMCs would be 4.4 <= b <= 6'). The paper's lower ends are not failures of "
        "either criterion where the target is visible in every frame: see the notes above and "
        "below.",
        "",
        "## Why our A_S peaks early (NA23A-like, g = 0)",
        "",
        "Eq. (17)'s terms (paper DPA, g = 0, mean over the scenes and the last frames):",
        "",
        _terms_note(summaries, scenes),
        "",
        "Noise-free NA23A-like target at s_n = 4 (1.2 px/frame, jitter 0.5 px, paper DPA, g = "
        "0, 4 seeds; `noise_free_gain`):",
        "",
        _gain_table(gains),
        "",
        "Every step of the metric follows eq. (16)-(17) and section 2.3 as printed (population "
        "standard deviations, 30 x 80 blocks tiled on the first-frame target pixel, the last "
        "six frames, `tests/dpa/test_metrics.py` against loop oracles). What bends the curve is "
        "the DPA's response to a target moving 1.2 px/frame with the 5 x 5 matrices: the "
        "moving target's score grows by far less per frame than a standing pixel's (the "
        "matrices of every direction put their highest weight in place: 0.125 for directions "
        "1-8, 0.173 for direction 9, against 0.089 one pixel behind in the direction of "
        "motion), so memory adds little to the target (its ASF is only the factor of the "
        "table above times its single-frame peak) while it lets the pixels the target left "
        "behind (the trail) keep b max W(9) of their score per frame. SNR_TB is therefore flat "
        "while the highest pixels are target pixels and falls as trail pixels enter the "
        "Max_Numbers highest and the block's spread; the neighbour blocks barely change. With "
        "a 60 sigma peak the target is already found in every single frame at b = 0, so there "
        "is no rise for memory to produce: the paper's A_S rises towards its peak near b = 5 "
        "on frames where the target fades (section 3.2.1(1)); our fluctuating variant rises "
        "too, but the trail again bends it down early.",
        "",
        "## b per direction and eq. (15), beside the paper's",
        "",
        _memory_table(),
        "",
        "The paper's eq. (15) gives one line for directions 1-8 and one for direction 9 (the "
        "target standing in place); b = 0.8 / max(w) at g = 0 and 0.8 / sum(w) at g = 1 (eq. 13). "
        "The 7 x 7 matrices of section 2.2.1 (0-2 px/frame plus the jitter) give both lines within "
        "1 %; the 5 x 5 matrices of section 3 (0-1 px/frame), used in this sweep, have a higher "
        "peak in directions 1-8 (their penalty mass is spread over 25 instead of 49 cells), hence "
        "the larger intercept: eq. (15) matches the 7 x 7 matrices (our reading).",
        "",
    ]
    for scene in scenes:
        for g in grid:
            parts += [
                f"## {scene_label(scene)}, g = {g:g}: A_S (mean ± std) and tracking rate per b "
                f"(paper range {P.fmt_range(P.PAPER_B_RANGE[P.paper_name(scene), g])})",
                "",
                _sweep_table(summaries, scene, table, g, grid[g], n),
                "",
            ]
    parts += [
        "Mean ± std over the scenes (sample std; one scene: the value alone). The `paper` "
        "columns are [NR08]'s printed values (Table 2, eq. 15, section 2.2.6).",
        "",
        f"![{NAME}]({NAME}.png)",
    ]
    text = "\n".join(parts)
    md = C.write_text(out / f"{NAME}.md", text)
    C.write_csv(out / f"{NAME}.csv", rows)
    _plot(summaries, scenes, table, grid, out / f"{NAME}.png")
    print(text)
    return md


def main(argv: Sequence[str] | None = None) -> pathlib.Path:
    """Command line entry point (``_expkit``'s options plus the engine options)."""
    return C.engine_main(NAME, DESCRIPTION, run, argv)


if __name__ == "__main__":
    main()

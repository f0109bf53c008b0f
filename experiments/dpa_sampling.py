"""[NR08] section 3.2: frame sampling s_n (effective velocity) and Max_Numbers of the Block SNR.

The paper keeps every ``s_n``-th frame (s_n = 1 .. 5) of its slow sequences so that the target
moves faster, finds where tracking occurs (Table 2: NA23 s_n = 1-5, NPA 3-5) and where the
algorithm score A_S peaks (effective velocity 0.6 ± 0.15 px/frame for NA23, 0.8 ± 0.1 for NPA),
and picks the number of highest pixels taken as "target" in the Block SNR of eq. (16),
``Max_Numbers``, by maximising A_S (Table 2: 3 for g = 0, 1 for g = 1; NA23 measured at s_n = 4
with b = 4.8 for g = 0, section 3.2.1(3); NPA's Max_Numbers are those of its s_n = 3 study,
section 3.2.2(1)). The Max_Numbers peak is therefore read at s_n = 4 for NA23A and s_n = 3 for NPA.

Here every scene (``na23a_like`` / ``npa_like``, the presets after section 3, and the NA23A-like
variants: fluctuating peak, and one-pixel target ``psf="pixel"``, our choice departing from the
Gaussian target of eq. (1), the test scene of ``tests/dpa/test_metrics.py``) is simulated with
``1 + 24 s_n`` frames and every ``s_n``-th frame is kept, so the DPA (5 x 5 matrices, as in
section 3) always sees 25 frames. It runs with g = 0 and g = 1, each at the b the paper used
(4.8 and 0.8) and at the effective-memory b of direction 9 (eq. 12-14, EMC 0.8). A_S (eq. 16-17
as printed: tiled blocks anchored on the target's first-frame pixel, mean over the last six
frames) is computed for Max_Numbers = 1 .. 7 under the paper's reading and under our earlier
centred reading. Each scene uses ONE block size at every s_n, so that the A_S peak over s_n
compares velocities and not block sizes: 30 x 80 (NA23A, moving along x) / 80 x 30 (NPA, moving
along y; our reading: the paper does not say which blocks it used for NPA) since some s_n needs
them (``fast``: the target may leave a 30 x 30 block, NA23A s_n >= 2, NPA s_n >= 3; the paper
names s_n = 4), in frames that hold the nine blocks in full (NA23A 90 x 240, NPA 240 x 120 with
the studied target started at mid-height). A noise-free footprint table (``footprints``) shows
how many pixels the target lights in the last ASF. The section "NPA s_n lower end"
(:func:`visibility`) measures why NPA-like tracks at s_n = 1-2 where the paper does not: how often
the target is the highest whitened pixel of single frames, the target-to-clutter peak ratio, the
cloud drift per kept frame, and tracking per s_n for dimmer targets in the same scenes;
``--part visibility`` computes that section alone and puts it into the last run's results.

Run: ``python experiments/dpa_sampling.py [--quick] [--seeds N] [--out DIR] [--part ...]`` or
``hocnet reproduce dpa-sampling``. ``--engine ray`` (the ``sweep`` extra) runs the same grid on
Ray Tune through ``hocnet.sweep.run_sweep``, one trial per (scene, s_n), with the same rows;
``--ray-dir DIR`` keeps Ray's experiment folder there (default: a new temporary folder) and
``--resume`` continues an interrupted run in it; ``--address`` joins a running Ray cluster. The
default engine, ``loop``, is unchanged.
"""

from __future__ import annotations

import itertools
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
from hocnet.dpa import accumulate, algorithm_score, backtrack, block_snrs

NAME = "dpa-sampling"
DESCRIPTION = (
    "[NR08] frame sampling s_n = 1..5 (effective velocity s_n x true speed) and Max_Numbers "
    "1..7 of the Block SNR (eq. 16-17 as printed, and our earlier centred reading): where "
    "tracking occurs and where A_S peaks, g = 0 and g = 1, NA23A-like and NPA-like sequences, "
    "beside Table 2 of the paper."
)

SEED_BASE = 7000
FRAMES, QUICK_FRAMES = 25, 8
SAMPLING, QUICK_SAMPLING = (1, 2, 3, 4, 5), (1, 4)
MAX_NUMBERS = tuple(range(1, 8))
GS = (0.0, 1.0)
LAST = 6
EMC = 0.8
SPEED = {"NA23A": 0.3, "NPA": 0.2}
SCENES = (*P.SCENES, P.FLUCT, P.POINT)
"""The presets after section 3 of [NR08], the fluctuating and the one-pixel-target NA23A-like
variants."""
JITTER = 0.5
PSF_RADIUS = 1.0
"""Pixels the target lights beyond its centre pixel (the presets' 0.7 px Gaussian lights 3 x 3)."""


def scene_label(scene: str) -> str:
    """Display name of a scene key."""
    labels = {P.FLUCT: "NA23A-like, fluctuating peak", P.POINT: "NA23A-like, one-pixel target"}
    return labels.get(scene, f"{scene}-like")


def fast(scene: str, step: int, frames: int = FRAMES) -> bool:
    """Whether the target may leave a 30 x 30 target block at sampling ``step``.

    [NR08] section 3.2: "To keep the target in the 'target block', a larger block size of
    30 x 80 was used for fast targets instead of 30 x 30" (named for s_n = 4). The target starts
    at the block centre and travels ``speed s_n (frames - 1)`` px; the first-to-last jitter
    adds up to ``2 JITTER`` and the PSF lights ``PSF_RADIUS`` px beyond the centre, so the
    target may leave the block once ``travel + 2 JITTER + PSF_RADIUS`` exceeds half a 30-pixel
    block (NA23A: s_n >= 2, 14.4 + 2 px at s_n = 2; NPA: s_n >= 3, 14.4 + 2 px at s_n = 3), our
    reading of "fast".
    """
    travel = SPEED[P.paper_name(scene)] * step * (frames - 1) + 2.0 * JITTER + PSF_RADIUS
    return travel > 15.0


def long_blocks(scene: str, sampling: Sequence[int], frames: int = FRAMES) -> bool:
    """Whether a scene uses the long blocks at *every* s_n: some s_n of ``sampling`` is ``fast``.

    One block size across s_n, so that A_S compares effective velocities, not block sizes
    (eq. 17's NTB statistics depend on the block size).
    """
    return any(fast(scene, step, frames) for step in sampling)


def geometry(
    scene: str, step: int, quick: bool, sampling: Sequence[int] = SAMPLING
) -> tuple[tuple[int, int], tuple[int, int]]:
    """``(frame (H, W), block (rows, columns))`` of a scene, the same at every s_n of ``sampling``.

    The frame holds the nine blocks in full around the target's first-frame pixel: NA23A's
    target starts at the frame centre; NPA's is started at ``(45, 120)`` of a 240-row frame
    (:func:`npa_start`). ``step`` is kept for the callers (the geometry no longer depends on it).
    """
    del step
    if quick:
        return ((45, 90) if P.paper_name(scene) == "NA23A" else (45, 60)), (15, 15)
    if not long_blocks(scene, sampling):
        return ((90, 90) if P.paper_name(scene) == "NA23A" else (90, 120)), (30, 30)
    if P.paper_name(scene) == "NA23A":
        return (90, 240), (30, 80)  # [NR08] section 3.2.1(2): 30 x 80 blocks, moving along x
    return (240, 120), (80, 30)  # moving along y: 80 x 30, three of them above each other


def npa_start(shape: tuple[int, int]) -> tuple[float, float] | None:
    """``start`` of ``npa_like`` for a frame ``(H, W)``.

    The studied target at mid-height of a frame taller than 90 rows (the nine 80 x 30 blocks in
    full), else ``None`` (the preset's default).
    """
    height, _ = shape
    return (45.0, 0.5 * height) if height > 90 else None


def sampled_scene(scene: str, seeds: Sequence[int], frames: int, shape, step: int) -> tuple:
    """Whitened frames ``(B, frames, H, W)`` and the studied target's ``(B, frames, 2)``."""
    long = 1 + (frames - 1) * step
    extra = {}
    if P.paper_name(scene) == "NPA" and npa_start(shape) is not None:
        extra["start"] = npa_start(shape)
    seq = P.scene(scene, seeds, shape=(long, *shape), **extra)
    kept = seq.frames[:, ::step]
    return C.whiten(kept, "anti_mean"), seq.positions[:, 0, ::step]


def b_values(weights: torch.Tensor) -> dict[tuple[float, str], float]:
    """``{(g, choice): b}``: the paper's b (4.8 / 0.8) and the EMC b of direction 9."""
    out = {}
    for g in GS:
        out[g, "paper"] = P.PAPER_B_USED[g]
        out[g, "EMC"] = P.emc_b(weights[8], g, EMC)
    return out


def _snr_parts(asf: torch.Tensor, truth: torch.Tensor, block) -> dict[str, dict[int, torch.Tensor]]:
    """The terms of eq. (17) on the last frame, per Max_Numbers: ``{"tb", "ntb_mean", "ntb_std"}``.

    Block SNRs of eq. (16) (``block_snrs``) on the last frame's ASF, the blocks tiled around the
    target's first-frame pixel as in ``algorithm_score``; each ``(B,)`` per Max_Numbers.
    """
    anchor = torch.floor(truth[:, 0].double() + 0.5).long()
    out: dict[str, dict[int, torch.Tensor]] = {"tb": {}, "ntb_mean": {}, "ntb_std": {}}
    for m in MAX_NUMBERS:
        snr = block_snrs(asf[:, -1].detach(), anchor, block=block, max_numbers=m)
        ntb = torch.cat([snr[:, :4], snr[:, 5:]], dim=1)
        mean = ntb.nanmean(dim=1)
        std = ((ntb - mean[:, None]).square().nanmean(dim=1)).sqrt()
        out["tb"][m], out["ntb_mean"][m], out["ntb_std"][m] = snr[:, 4], mean, std
    return out


def _why_table(rows, scenes, sampling) -> str:
    """Mean TB SNR, NTB mean and NTB std (eq. 17's terms, last frame) per Max_Numbers."""
    headers = ["sequence", "g", "b", "term", *(f"MN = {m}" for m in MAX_NUMBERS)]
    body = []
    for scene in scenes:
        ref = _ref_sn(scene, sampling)
        for g in GS:
            sel = _sel(rows, scene, g, "paper", ref)
            for key, name in (
                ("tb", "SNR_TB"),
                ("ntb_mean", "mean SNR_NTB"),
                ("ntb_std", "std SNR_NTB"),
            ):
                body.append(
                    [
                        f"{scene_label(scene)} (s_n = {ref})",
                        f"{g:g}",
                        f"{sel[0]['b']:g}",
                        name,
                        *(f"{C.mean(r[f'{key}_mn{m}'] for r in sel):.3f}" for m in MAX_NUMBERS),
                    ]
                )
    return C.md_table(headers, body)


def evaluate(
    scenes,
    bvalues,
    weights,
    sampling,
    seeds,
    frames,
    quick,
    progress,
    *,
    engine: str = "loop",
    ray: dict | None = None,
) -> list[dict]:
    """One row per (scene, s_n, g, b choice, seed) with A_S for every Max_Numbers.

    ``engine="loop"`` runs the (scene, s_n) jobs here, one after the other; ``engine="ray"``
    runs each as one trial of a ``hocnet.sweep.run_sweep`` grid on Ray Tune (``ray``: the
    keyword arguments of ``_expkit.ray_map``: ``path``, ``resume``, ``address``, ``num_cpus``).
    Both run :func:`sampling_job` and give the same rows in the same order.
    """
    jobs = [(scene, step) for scene in scenes for step in sampling]
    shared = {
        "bvalues": bvalues,
        "weights": weights,
        "seeds": list(seeds),
        "frames": frames,
        "quick": quick,
        "sampling": sampling,
    }
    if C.check_engine(engine) == "ray":
        per_job = C.ray_map(
            __file__, "sampling_job", jobs, shared, name=NAME, progress=progress, **(ray or {})
        )
    else:
        per_job = [sampling_job(j, **shared) for j in C.progress(jobs, enabled=progress, desc=NAME)]
    return [row for rows in per_job for row in rows]


def sampling_job(job, bvalues, weights, seeds, frames, quick, sampling) -> list[dict]:
    """The rows of one (scene, s_n) job: one per (g, b choice, seed)."""
    scene, step = job
    rows = []
    shape, block = geometry(scene, step, quick, sampling)
    whitened, truth = sampled_scene(scene, seeds, frames, shape, step)
    last = min(LAST, frames)
    for (g, choice), b in bvalues.items():
        state = accumulate(whitened, weights, b, g)
        hit = P.tracked(backtrack(state, P.nine_block_start(state.asf, truth, block)), truth)
        paper = {
            m: algorithm_score(state.asf, truth, last=last, block=block, max_numbers=m)
            for m in MAX_NUMBERS
        }
        centred = {
            m: algorithm_score(state.asf, truth, last=last, max_numbers=m, reading="centred")
            for m in MAX_NUMBERS
        }
        parts = _snr_parts(state.asf, truth, block)
        for i, seed in enumerate(seeds):
            row = {
                "table": "sampling",
                "scene": scene,
                "s_n": step,
                "v_eff": round(step * SPEED[P.paper_name(scene)], 4),
                "block": f"{block[0]}x{block[1]}",
                "g": g,
                "b_choice": choice,
                "b": round(b, 4),
                "seed": seed,
                "tracked": int(hit[i]),
            }
            row.update({f"a_s_mn{m}": float(paper[m][i]) for m in MAX_NUMBERS})
            row.update({f"a_s_centred_mn{m}": float(centred[m][i]) for m in MAX_NUMBERS})
            for key, values in parts.items():
                row.update({f"{key}_mn{m}": float(values[m][i]) for m in MAX_NUMBERS})
            rows.append(row)
    return rows


VISIBILITY_PEAKS = (30.0, 24.0, 20.0, 15.0)
"""Peaks (x the noise) of the NPA-like target in :func:`visibility`: the preset's (Table 2's ~30)
and dimmer ones, down to the cloud plateau (15)."""
QUICK_VISIBILITY_PEAKS = (30.0, 15.0)
VISIBILITY = "NPA s_n lower end"
"""Title of the markdown section of :func:`visibility` (``--part visibility`` replaces it)."""
PARTS = ("all", "visibility")


def _target_masks(truth: torch.Tensor, shape, block) -> tuple[torch.Tensor, torch.Tensor]:
    """``(B, H, W)`` bool: the target block and the nine blocks, tiled as ``algorithm_score``."""
    rows, cols = block
    height, width = shape
    ys = torch.arange(height).view(1, -1, 1)
    xs = torch.arange(width).view(1, 1, -1)
    x0 = (torch.floor(truth[:, 0, 0].double() + 0.5).long() - cols // 2).view(-1, 1, 1)
    y0 = (torch.floor(truth[:, 0, 1].double() + 0.5).long() - rows // 2).view(-1, 1, 1)
    tb = (xs >= x0) & (xs < x0 + cols) & (ys >= y0) & (ys < y0 + rows)
    nine = (xs >= x0 - cols) & (xs < x0 + 2 * cols) & (ys >= y0 - rows) & (ys < y0 + 2 * rows)
    return tb, nine


def single_frame_visibility(whitened: torch.Tensor, truth: torch.Tensor, block) -> dict:
    """How visible the studied target is in single whitened frames (no DPA).

    Args:
        whitened: ``(B, T, H, W)`` anti-mean whitened kept frames.
        truth: ``(B, T, 2)`` ``(x, y)`` of the studied target.
        block: ``(rows, columns)`` of the blocks.

    Returns:
        ``(B,)`` tensors: ``on_tb`` / ``on_nine``, the fraction of frames whose highest pixel
        of the target block / of the nine blocks lies within 1.5 px of the target; ``ratio``,
        the median over the frames of the target's peak (highest pixel within 1.5 px) over the
        highest pixel of the nine blocks farther than 3 px from it (noise and cloud edges).
    """
    _, n_t, height, width = whitened.shape
    tb, nine = _target_masks(truth, (height, width), block)
    ys = torch.arange(height).view(1, -1, 1).double()
    xs = torch.arange(width).view(1, 1, -1).double()
    on_tb, on_nine, ratio = [], [], []
    for t in range(n_t):
        frame = whitened[:, t]
        for mask, out in ((tb, on_tb), (nine, on_nine)):
            flat = frame.masked_fill(~mask, float("-inf")).flatten(1).argmax(dim=1)
            pixel = torch.stack([flat % width, flat // width], dim=1).double()
            out.append(torch.linalg.vector_norm(pixel - truth[:, t].double(), dim=-1) <= 1.5)
        dist = torch.sqrt(
            (xs - truth[:, t, 0].double().view(-1, 1, 1)) ** 2
            + (ys - truth[:, t, 1].double().view(-1, 1, 1)) ** 2
        )
        target = frame.masked_fill(~(dist <= 1.5), float("-inf")).flatten(1).amax(dim=1)
        clutter = frame.masked_fill(~(nine & (dist > 3.0)), float("-inf")).flatten(1).amax(dim=1)
        ratio.append(target / clutter)
    return {
        "on_tb": torch.stack(on_tb, dim=1).double().mean(dim=1),
        "on_nine": torch.stack(on_nine, dim=1).double().mean(dim=1),
        "ratio": torch.stack(ratio, dim=1).double().median(dim=1).values,
    }


def visibility(seeds, frames, quick, sampling, weights, peaks, progress=False) -> list[dict]:
    """Why NPA-like tracks at low s_n: single-frame visibility and tracking per peak and s_n.

    [NR08] tracks NPA only from s_n = 3 (Table 2, section 3.2.2: the cloud edges "behave like
    targets"); our NPA-like scenes track from s_n = 1. For the studied target at each peak of
    ``peaks`` (x the noise; the preset: 30) and each s_n, the NPA-like scenes of the main table
    (same seeds, geometry and sampling; the peak changes the target only) give one row per seed:
    :func:`single_frame_visibility` of the whitened kept frames, the cloud drift per kept frame
    (the preset's ``NPA_CLOUDS.drift`` times s_n), and whether the DPA tracks the target (the
    main table's rule) at the paper's b, g = 0 (4.8) and g = 1 (0.8).
    """
    import math

    rows = []
    drift = math.hypot(*NPA_CLOUDS.drift)
    jobs = [(peak, step) for peak in peaks for step in sampling]
    for peak, step in C.progress(jobs, enabled=progress, desc=f"{NAME} visibility"):
        shape, block = geometry("NPA", step, quick, sampling)
        long = 1 + (frames - 1) * step
        extra = {} if npa_start(shape) is None else {"start": npa_start(shape)}
        seq = P.scene("NPA", seeds, shape=(long, *shape), snr_db=P.db(peak), **extra)
        whitened = C.whiten(seq.frames[:, ::step], "anti_mean")
        truth = seq.positions[:, 0, ::step]
        seen = single_frame_visibility(whitened, truth, block)
        hits = {}
        for g in GS:
            state = accumulate(whitened, weights, P.PAPER_B_USED[g], g)
            start = P.nine_block_start(state.asf, truth, block)
            hits[g] = P.tracked(backtrack(state, start), truth)
        for i, seed in enumerate(seeds):
            rows.append(
                {
                    "table": "visibility",
                    "scene": "NPA",
                    "peak": peak,
                    "s_n": step,
                    "v_eff": round(step * SPEED["NPA"], 4),
                    "cloud_drift": round(step * drift, 4),
                    "seed": seed,
                    "on_tb": float(seen["on_tb"][i]),
                    "on_nine": float(seen["on_nine"][i]),
                    "ratio": float(seen["ratio"][i]),
                    "tracked_g0": int(hits[0.0][i]),
                    "tracked_g1": int(hits[1.0][i]),
                }
            )
    return rows


def _visibility_table(rows, peaks, sampling) -> str:
    headers = [
        "peak (x noise)",
        "s_n",
        "v_eff (px/kept frame)",
        "cloud drift (px/kept frame)",
        "single frame: TB max on the target",
        "single frame: nine-block max on the target",
        "target / clutter peak (median)",
        "tracking g = 0 (b 4.8)",
        "tracking g = 1 (b 0.8)",
    ]
    body = []
    for peak in peaks:
        for step in sampling:
            sel = [r for r in rows if float(r["peak"]) == peak and int(r["s_n"]) == step]
            ratios = torch.tensor([float(r["ratio"]) for r in sel])
            body.append(
                [
                    f"{peak:g}" + (" (preset)" if peak == P.PAPER_PEAK["NPA"] else ""),
                    str(step),
                    f"{float(sel[0]['v_eff']):g}",
                    f"{float(sel[0]['cloud_drift']):.2f}",
                    C.pct(C.mean(r["on_tb"] for r in sel), 0),
                    C.pct(C.mean(r["on_nine"] for r in sel), 0),
                    f"{float(ratios.median()):.2f}",
                    C.pct(C.mean(r["tracked_g0"] for r in sel), 0),
                    C.pct(C.mean(r["tracked_g1"] for r in sel), 0),
                ]
            )
    return C.md_table(headers, body)


def _span(values: Sequence[float], fmt) -> str:
    """``"lo-hi"`` of ``values`` formatted by ``fmt`` (one value if they format alike)."""
    lo, hi = fmt(min(values)), fmt(max(values))
    return lo if lo == hi else f"{lo}-{hi}"


def visibility_section(rows, peaks, sampling) -> list[str]:
    """The markdown lines of the :data:`VISIBILITY` section (table and what it shows)."""

    def cell(peak, step, key):
        sel = [r for r in rows if float(r["peak"]) == peak and int(r["s_n"]) == step]
        if key == "ratio":
            return float(torch.tensor([float(r["ratio"]) for r in sel]).median())
        return C.mean(r[key] for r in sel)

    top = max(peaks)
    first, last = min(sampling), max(sampling)
    seen = [cell(top, s, "on_nine") for s in sampling]
    ratios = [cell(top, s, "ratio") for s in sampling]
    dim_lines, paper_like = [], False
    for peak in sorted(set(peaks) - {top}, reverse=True):
        rates = {g: [cell(peak, s, f"tracked_g{g:g}") for s in sampling] for g in (0, 1)}
        shown = "; ".join(f"g = {g} " + ", ".join(C.pct(r, 0) for r in rates[g]) for g in (0, 1))
        paper_like |= any(r[0] < 0.5 and max(r[1:], default=0.0) >= 0.5 for r in rates.values())
        falling = all(all(a >= b for a, b in itertools.pairwise(r)) for r in rates.values())
        single = [cell(peak, s, "on_nine") for s in sampling]
        peak_ratios = [cell(peak, s, "ratio") for s in sampling]
        dim_lines.append(
            f"{peak:g} x the noise (single-frame nine-block maximum on the target in "
            f"{_span(single, lambda v: C.pct(v, 0))} of the frames, target / clutter "
            f"{_span(peak_ratios, '{:.2f}'.format)}): tracking per s_n "
            f"{', '.join(map(str, sampling))}: {shown}"
            + (
                " (none at any s_n)"
                if not any(any(r) for r in rates.values())
                else (" (never rising with s_n)" if falling else "")
            )
        )
    g0 = [cell(top, s, "tracked_g0") for s in sampling]
    g0_range = C.b_ranges(list(sampling), g0, 0.5)
    paper_end = P.PAPER_SN_RANGE["NPA"][1]
    ends = P.ends_of(g0_range)
    dim = (
        "Dimmer targets (the same scenes with only the target's peak changed) "
        + (
            "bring the paper's pattern (no tracking at the lowest s_n, tracking at a higher "
            "one) in some setting: "
            if paper_like
            else "do not bring the paper's lower end back: "
        )
        + "; ".join(dim_lines)
        + ". "
    )
    lag = (
        f" g = 0's range ends ({g0_range} here) before the paper's upper end {paper_end}, "
        "consistent with the standing pixels' larger per-frame gain at g = 0 (not measured "
        "separately)."
        if ends is not None and ends[1] < paper_end
        else ""
    )
    return [
        f"## {VISIBILITY}: why NPA-like tracks at s_n = 1-2 (paper: from 3)",
        "",
        "[NR08] tracks NPA only from s_n = 3 on: its cloud edges 'behave like targets' and win "
        "the target block at low s_n (section 3.2.2). Ours track from s_n = 1 because the "
        f"NPA-like target at its {top:g}-sigma peak is visible in single frames: the highest "
        "whitened pixel of the nine blocks is on the target in "
        f"{_span(seen, lambda v: C.pct(v, 0))} of the kept frames at s_n "
        f"{first}-{last}, {_span(ratios, '{:.2f}'.format)} times (median) the highest pixel "
        "of noise or cloud edge farther than 3 px, so the DPA has nothing to overcome at "
        "s_n = 1. The cloud edges drift "
        f"{cell(top, first, 'cloud_drift'):.2f}-{cell(top, last, 'cloud_drift'):.2f} px per "
        "kept frame (the preset's drift times s_n): for the DPA they stand still at every s_n, "
        "and accumulate in place as well as a slow target does. "
        + dim
        + "Sampling makes the target faster per kept frame, while the static edges keep "
        "accumulating in place: at g = 0 a standing pixel keeps b max W(9) = 0.83 of its "
        "score per frame (b = 4.8, 5 x 5 matrices), a target moving 1 px per kept frame "
        "at most 0.60 (b max W(1)), 0.43 from the pixel one step behind. That our DPA "
        "follows faster targets worse is a difference from [NR08], which finds the "
        "algorithm effective near 1 px/frame and better for faster targets (it sampled "
        "targets only up to about 1.5 px/frame, NA23 at s_n = 5); "
        "`dpa-pd-snr`'s speed ablation (17 dB, clear sky) traces the lag at g = 0 to the "
        "memory b and at g = 1 to eq. (7)'s W_basic, and at 30 x the noise in clear sky the "
        "paper DPA stays on the truth in >= 0.9 of the frames up to 1.5 px/frame "
        "(README, *Target speed*). The gain the paper sees from its penalty matrices for "
        "targets near 1 px/frame is not reproduced." + lag,
        "",
        "`visibility` (same seeds, frames and blocks as above; TB: the target block; tracking: "
        "the rule above, share of the scenes):",
        "",
        _visibility_table(rows, peaks, sampling),
        "",
    ]


def merge_visibility(md_path: pathlib.Path, lines: Sequence[str]) -> str:
    """The markdown text of ``md_path`` with the :data:`VISIBILITY` section replaced by ``lines``.

    The section goes right before the first per-scene A_S grid (``## NA23A-like, g = 0``), where
    :func:`run` writes it; an earlier version of it is removed first.
    """
    text = md_path.read_text()
    head = f"## {VISIBILITY}"
    if head in text:
        before, rest = text.split(head, 1)
        after = rest[rest.index("\n## ") + 1 :]
        text = before + after
    anchor = "## NA23A-like, g = 0"
    if anchor not in text:
        raise ValueError(f"{md_path}: expected a '{anchor}' section to insert before")
    before, after = text.split(anchor, 1)
    return before + "\n".join(lines) + "\n" + anchor + after


FOOTPRINT_SCENES = ("NA23A", P.POINT)
"""Scenes of the noise-free footprint table: the presets' Gaussian target and the one-pixel one."""


def footprints(seeds, frames, quick, sampling, weights) -> dict[tuple[str, float], list[float]]:
    """Noise-free footprint of the target in the last ASF, at the paper's s_n and b.

    The target's own signal (``frames - target_free``: no noise, no clouds) of each scene,
    sampled every s_n-th frame (NA23A's s_n of Table 2, 4), anti-mean whitened and accumulated
    with the paper's b (4.8 at g = 0, 0.8 at g = 1); the seven highest pixels of the last
    frame's ASF relative to the highest one, averaged over the seeds (the jitter differs).

    Returns:
        ``{(scene, g): [1.0, r2, ..., r7]}``.
    """
    out = {}
    for scene in FOOTPRINT_SCENES:
        step = _ref_sn(scene, sampling)
        shape, _ = geometry(scene, step, quick, sampling)
        seq = P.scene(scene, seeds, shape=(1 + (frames - 1) * step, *shape))
        signal = (seq.frames - seq.target_free)[:, ::step]
        whitened = C.whiten(signal, "anti_mean")
        for g in GS:
            state = accumulate(whitened, weights, P.PAPER_B_USED[g], g)
            top = state.asf[:, -1].detach().flatten(1).double().topk(len(MAX_NUMBERS)).values
            rel = (top / top[:, :1]).mean(dim=0)
            out[scene, g] = [float(v) for v in rel]
    return out


def _footprint_table(prints, sampling) -> str:
    headers = ["target", "g", "b", "s_n", *(f"pixel {m}" for m in MAX_NUMBERS)]
    body = []
    for (scene, g), rel in prints.items():
        body.append(
            [
                scene_label(scene),
                f"{g:g}",
                f"{P.PAPER_B_USED[g]:g}",
                str(_ref_sn(scene, sampling)),
                *(f"{v:.2f}" for v in rel),
            ]
        )
    return C.md_table(headers, body)


def _sel(rows, scene, g, choice, step=None):
    return [
        r
        for r in rows
        if r["scene"] == scene
        and r["g"] == g
        and r["b_choice"] == choice
        and (step is None or r["s_n"] == step)
    ]


def means(rows, scene, g, choice, sampling, prefix="a_s_mn") -> list[list[float]]:
    """Mean A_S ``[s_n index][Max_Numbers index]``."""
    return [
        [C.mean(r[f"{prefix}{m}"] for r in _sel(rows, scene, g, choice, s)) for m in MAX_NUMBERS]
        for s in sampling
    ]


def _argmax(values: Sequence[float]) -> int:
    return max(range(len(values)), key=lambda i: values[i])


def _ref_sn(scene: str, sampling: Sequence[int]) -> int:
    """The s_n of the paper's Max_Numbers / Table 2 study of a scene (NA23A 4, NPA 3)."""
    ref = P.PAPER_SN_TABLE2[P.paper_name(scene)]
    return ref if ref in sampling else sampling[-1]


def _mn_table(rows, scenes, bvalues, sampling) -> str:
    headers = [
        "sequence",
        "g",
        "b",
        "A_S peak: Max_Numbers at the paper's s_n (NA23A 4, NPA 3; paper reading)",
        "same, per s_n " + ", ".join(str(s) for s in sampling),
        "centred reading: peak Max_Numbers",
        "paper Table 2",
    ]
    body = []
    for scene in scenes:
        ref = _ref_sn(scene, sampling)
        i_ref = list(sampling).index(ref)
        for (g, choice), b in bvalues.items():
            paper = means(rows, scene, g, choice, sampling)
            centred = means(rows, scene, g, choice, sampling, "a_s_centred_mn")
            body.append(
                [
                    scene,
                    f"{g:g}",
                    f"{b:.3g} ({choice})",
                    f"{MAX_NUMBERS[_argmax(paper[i_ref])]} (s_n = {ref})",
                    ", ".join(str(MAX_NUMBERS[_argmax(p)]) for p in paper),
                    str(MAX_NUMBERS[_argmax(centred[i_ref])]),
                    str(P.PAPER_MAX_NUMBERS[g]),
                ]
            )
    return C.md_table(headers, body)


def _sn_table(rows, scenes, bvalues, sampling) -> str:
    headers = [
        "sequence",
        "g",
        "b",
        "tracking rate per s_n " + ", ".join(str(s) for s in sampling),
        "s_n where tracking occurred (>= 50 %)",
        "paper Table 2",
        "A_S peak (MN of Table 2): s_n (v_eff px/frame)",
        "paper: v_eff of the A_S peak",
    ]
    body = []
    for scene in scenes:
        for (g, choice), b in bvalues.items():
            rates = [
                C.mean(r["tracked"] for r in _sel(rows, scene, g, choice, s)) for s in sampling
            ]
            mn = P.PAPER_MAX_NUMBERS[g]
            a_s = [
                C.mean(r[f"a_s_mn{mn}"] for r in _sel(rows, scene, g, choice, s)) for s in sampling
            ]
            best = sampling[_argmax(a_s)]
            body.append(
                [
                    scene,
                    f"{g:g}",
                    f"{b:.3g} ({choice})",
                    ", ".join(C.pct(r, 0) for r in rates),
                    C.b_ranges(list(sampling), rates, 0.5),
                    P.fmt_range(P.PAPER_SN_RANGE[P.paper_name(scene)]),
                    f"{best} ({best * SPEED[P.paper_name(scene)]:.2g})",
                    P.PAPER_VELOCITY[P.paper_name(scene)],
                ]
            )
    return C.md_table(headers, body)


def _grid_table(rows, scene, g, choice, sampling) -> str:
    values = means(rows, scene, g, choice, sampling)
    headers = ["s_n", "v_eff", "blocks", *(f"MN = {m}" for m in MAX_NUMBERS), "tracking"]
    body = []
    for i, step in enumerate(sampling):
        sel = _sel(rows, scene, g, choice, step)
        best = max(values[i])
        cells = [str(step), f"{step * SPEED[P.paper_name(scene)]:.2g}", sel[0]["block"]]
        cells += [f"**{v:.2f}**" if v == best else f"{v:.2f}" for v in values[i]]
        cells.append(C.pct(C.mean(r["tracked"] for r in sel), 0))
        body.append(cells)
    return C.md_table(headers, body)


def _plot(rows, scenes, bvalues, sampling, path: pathlib.Path) -> None:
    keys = [(scene, g) for g in GS for scene in scenes]
    fig, axes = plt.subplots(
        len(GS), len(scenes), figsize=(4.6 * len(scenes), 4.0 * len(GS)), layout="constrained"
    )
    axes = axes.reshape(-1)
    for ax, (scene, g) in zip(axes, keys):
        values = means(rows, scene, g, "paper", sampling)
        for i, step in enumerate(sampling):
            ax.plot(MAX_NUMBERS, values[i], "-o", ms=3, label=f"s_n = {step}")
        ax.axvline(P.PAPER_MAX_NUMBERS[g], color="0.5", ls=":", label="paper Max_Numbers")
        ax.set_title(f"{scene_label(scene)}, g = {g:g}, b = {bvalues[g, 'paper']:g}", fontsize=9)
        ax.set_xlabel("Max_Numbers")
        ax.set_ylabel("mean A_S (eq. 16-17)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("[NR08] A_S versus Max_Numbers per sampling s_n (paper reading)")
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
    part: str = "all",
) -> pathlib.Path:
    """Run the experiment; write ``<NAME>.md``, ``.csv`` and ``.png``; return the md path.

    Args:
        quick: smoke run (8 frames, small frames and 15 x 15 blocks, s_n = 1 and 4, 2 seeds).
        seeds: scenes per setting (default 20, quick 2).
        out_dir: output folder (default ``experiments/results``).
        progress: show a tqdm progress bar (``engine="ray"``: Ray's progress table).
        engine: ``"loop"`` (default) or ``"ray"`` (Ray Tune, see :func:`evaluate`).
        ray: keyword arguments of the Ray engine (``path``, ``resume``, ``address``,
            ``num_cpus``).
        part: ``"all"`` or ``"visibility"``: only the :data:`VISIBILITY` section
            (:func:`visibility`), put into the results of the last run in ``out_dir`` (its
            other sections and rows are kept as they are; run it with the same ``quick``).

    Returns:
        Path of the markdown file.

    Raises:
        ValueError: an unknown ``part``.
        FileNotFoundError: ``part="visibility"`` without earlier results in ``out_dir``.
    """
    if part not in PARTS:
        raise ValueError(f"`part`: expected one of {PARTS}, got {part!r}")
    n = C.n_seeds(quick, seeds)
    out = C.out_dir_of(out_dir)
    frames = QUICK_FRAMES if quick else FRAMES
    sampling = QUICK_SAMPLING if quick else SAMPLING
    scenes = SCENES
    seed_values = C.seed_list(SEED_BASE, n)
    weights = P.weights()
    bvalues = b_values(weights)
    peaks = QUICK_VISIBILITY_PEAKS if quick else VISIBILITY_PEAKS
    if part == "visibility":
        return _merge_visibility_part(out, seed_values, frames, quick, sampling, weights, peaks)
    with C.single_thread(), C.Timer() as timer:
        rows = evaluate(
            scenes,
            bvalues,
            weights,
            sampling,
            seed_values,
            frames,
            quick,
            progress,
            engine=engine,
            ray=ray,
        )
        prints = footprints(seed_values, frames, quick, sampling, weights)
        seen = visibility(seed_values, frames, quick, sampling, weights, peaks, progress)
    parts = [
        C.header(
            "[NR08] frame sampling (effective velocity) and Max_Numbers",
            DESCRIPTION,
            quick=quick,
            n=n,
            seconds=timer.seconds,
        ),
        f"- Scenes: `na23a_like` (0.3 px/frame, clear sky) / `npa_like` (0.2 px/frame, studied "
        f"target in clouds, cloud plateau {NPA_CLOUDS.amplitude:g} x the noise), presets' peak "
        "SNRs (Table 2's peaks 60 / 30 x the noise), *NA23A-like, fluctuating peak* "
        f"(`na23a_like(fluctuation={P.FLUCTUATION:g})`, our addition: per-frame peak exponential "
        f"with mean {P.FLUCTUATION:g} x the peak, clipped at it; see `dpa-b-sweep`), and "
        "*NA23A-like, one-pixel target* (`na23a_like(psf='pixel')`, our choice, departing from "
        "eq. (1)'s Gaussian target and PAPER_SIGMA: the whole peak in the pixel containing the "
        "jittered position, after the targets that 'subtend areas less than a pixel' and Figure "
        "19's one high pixel), simulated "
        f"with 1 + {frames - 1} s_n frames of which every s_n-th is kept; seeds "
        f"{seed_values[0]} .. {seed_values[-1]}. One frame and block size per scene at every "
        "s_n (the long blocks wherever some s_n needs them: the target may leave a 30 x 30 "
        "block once speed s_n 24 + 2 x 0.5 px jitter + 1 px PSF radius > 15 px, NA23A s_n >= 2, "
        "NPA s_n >= 3), so that A_S compares velocities, not block sizes; NPA's studied target "
        "starts at mid-height of a 240-row frame so that the nine 80 x 30 blocks are full: "
        + "; ".join(
            f"{s}: {geometry(s, 1, quick, sampling)[0][0]} x "
            f"{geometry(s, 1, quick, sampling)[0][1]}, blocks "
            f"{geometry(s, 1, quick, sampling)[1][0]} x {geometry(s, 1, quick, sampling)[1][1]}"
            for s in scenes
        )
        + ".",
        "- DPA: anti-mean whitening, `probability_matrices(5, v_max=1)`; b: *paper* = 4.8 "
        "(g = 0) and 0.8 (g = 1), the values [NR08] uses for its Max_Numbers study; *EMC* = "
        "0.8 / (g sum(w9) + (1 - g) max(w9)), direction 9 (eq. 12-14).",
        f"- A_S: `algorithm_score(asf, truth, last={LAST}, block=..., max_numbers=MN)` (paper "
        "reading of eq. 16-17, tiling anchored on the first-frame pixel of the studied target) "
        "and `reading='centred'` (our earlier one), MN = 1 .. 7.",
        "- Tracking: the track back-tracked from the highest last-frame ASF of the nine blocks "
        "(section 2.3 of [NR08]: the algorithm is run over the target block and its 8 "
        "neighbours; `_nr08.nine_block_start`) lies within 1.5 px of the studied target in >= 80 "
        "% of the frames; *tracking occurred* at an s_n when it holds in >= 50 % of the scenes.",
        "",
        "## Max_Numbers where A_S peaks, beside Table 2",
        "",
        _mn_table(rows, scenes, bvalues, sampling),
        "",
        "### Why A_S peaks where it does: the terms of eq. (17) per Max_Numbers",
        "",
        "A_S = (SNR_TB - mean SNR_NTB) / std SNR_NTB. SNR_TB falls as Max_Numbers grows, "
        "slowly while the highest pixels are pixels the target lights in the ASF (its footprint, "
        "[NR08]'s 'target pixels') and faster beyond; std SNR_NTB also falls with Max_Numbers in "
        "blocks of white noise (the mean of the few highest pixels varies less from block to "
        "block the more pixels it averages), so A_S peaks where the footprint ends only if SNR_TB "
        "falls faster there than std SNR_NTB. The footprints, noise-free (the target's own "
        "signal, no noise, no clouds; `footprints`): the seven highest pixels of the last ASF "
        "relative to the highest one, mean over the seeds, at NA23A's s_n of Table 2 and the "
        "paper's b (at g = 0 the max recursion keeps the pixels the target passed, b max(w) per "
        "frame; at g = 1 the sum spreads the score over the neighbours):",
        "",
        _footprint_table(prints, sampling),
        "",
        "Blocks with cloud edges keep their spread. Means over the scenes, last frame only, at "
        "the paper's s_n and b (A_S above is the mean over the last six frames):",
        "",
        _why_table(rows, scenes, sampling),
        "",
        "## s_n where tracking occurred and where A_S peaks, beside Table 2",
        "",
        _sn_table(rows, scenes, bvalues, sampling),
        "",
        *visibility_section(seen, peaks, sampling),
    ]
    for scene in scenes:
        for (g, choice), b in bvalues.items():
            parts += [
                f"## {scene_label(scene)}, g = {g:g}, b = {b:.3g} ({choice}): mean A_S "
                "(paper reading) per s_n x Max_Numbers",
                "",
                _grid_table(rows, scene, g, choice, sampling),
                "",
            ]
    parts += [
        "Bold: the best Max_Numbers of each row. *Tracking*: the back-tracked track follows the "
        "studied target (1.5 px, >= 80 % of the kept frames). The `paper` columns are [NR08]'s "
        "printed values (Table 2; sections 3.2.1(4) and 3.2.2(2) for the velocities).",
        "",
        f"![{NAME}]({NAME}.png)",
    ]
    text = "\n".join(parts)
    md = C.write_text(out / f"{NAME}.md", text)
    C.write_csv(out / f"{NAME}.csv", rows + seen)
    _plot(rows, scenes, bvalues, sampling, out / f"{NAME}.png")
    print(text)
    return md


def _merge_visibility_part(out, seeds, frames, quick, sampling, weights, peaks) -> pathlib.Path:
    """``part="visibility"``: compute :func:`visibility`, put it into the last run's results."""
    import csv

    md_path, csv_path = out / f"{NAME}.md", out / f"{NAME}.csv"
    if not (md_path.is_file() and csv_path.is_file()):
        raise FileNotFoundError(
            f"--part visibility: expected the results of a run in {out} ({md_path.name} and "
            f"{csv_path.name}); run the whole experiment first"
        )
    with C.single_thread(), C.Timer() as timer:
        seen = visibility(seeds, frames, quick, sampling, weights, peaks)
    lines = visibility_section(seen, peaks, sampling)
    lines += [f"Computed alone with `--part visibility` in {timer.seconds:.1f} s.", ""]
    text = merge_visibility(md_path, lines)
    with open(csv_path, newline="") as fh:
        kept = [r for r in csv.DictReader(fh) if r.get("table") != "visibility"]
    md = C.write_text(md_path, text)
    C.write_csv(csv_path, kept + seen)
    print(text)
    return md


def main(argv: Sequence[str] | None = None) -> pathlib.Path:
    """Command line entry point (``_expkit``'s options, the engine options and ``--part``)."""
    import argparse
    import functools

    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--part", choices=PARTS, default="all")
    args, rest = pre.parse_known_args(argv)
    part_help = (
        " --part {all,visibility}: everything (default) or only the NPA s_n lower-end section, "
        "put into the results of the last run in --out."
    )
    runner = functools.partial(run, part=args.part)
    return C.engine_main(NAME, DESCRIPTION + part_help, runner, rest)


if __name__ == "__main__":
    main()

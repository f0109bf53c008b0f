"""Draw Figure 3 of [NR08] from hocnet's matrices: ``docs/images/dpa_figure3.png``.

(a) the 7 x 7 ``W_basic`` (direction 9), (b) the eight ``W_penalty(d) * W_frame`` for 0-1 px/frame
(a 5 x 5 valid search area inside the 7 x 7 window; Figure 2's rule with x = 3), (c) the nine
``W(d)`` of eq. (5) for p = 0.5. As in the paper, every matrix is shown on its own 0-1 scale
(divided by its maximum). Rows are y (down), columns x; direction d moves at (d - 1) * 45 degrees
of atan2(dy, dx), so direction 1 is +x (right) and direction 3 is +y (down on screen).

Difference from the paper (our reading, drawn in the caption): the paper says of Figure 3 that "the
border pixels are zeroes accordingly using W_frame", but eq. (5) as printed multiplies only the
penalty by W_frame, so W_basic (panel a) and the p W_basic part of every W(d) (panel c) keep small
non-zero values on the 7 x 7 border ring, outside the 5 x 5 valid search area. :func:`border_effect`
measures what zeroing the border would change (b per direction, eq. (15)'s constants) and
:func:`border_tracking` what it changes in tracking; ``--border`` prints both.

Run::

    .venv/bin/python docs/dpa_figure3.py [OUT.png]
    .venv/bin/python docs/dpa_figure3.py --border   # the border measurement (about a minute)
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from hocnet.dpa.matrices import figure3_matrices, frame_matrix, probability_matrices

ARROWS = ["→ 0°", "↘ 45°", "↓ 90°", "↙ 135°", "← 180°", "↖ 225°", "↑ 270°", "↗ 315°", "in place"]


EMC = 0.8
"""Effective memory of eq. (12)-(14) for the b per direction."""


def border_variants(v_max: float = 1.0) -> dict[str, torch.Tensor]:
    """Figure 3's ``(9, 7, 7)`` W(d) with and without the border, float64.

    ``ours``: eq. (5) as printed (W_frame on the penalty only: the border keeps ``p W_basic``,
    W(9) = W_basic keeps its own); ``zeroed``: every W(d) times W_frame (the paper's caption);
    ``zeroed, renormalised``: the same, each matrix divided by its sum; ``5 x 5``:
    ``probability_matrices(5, v_max)``, padded with a zero border.
    """
    _, _, ours = figure3_matrices(v_max)
    frame = frame_matrix(7, v_max, 0.5, dtype=torch.float64)
    zeroed = ours * frame
    five = torch.nn.functional.pad(probability_matrices(5, v_max, dtype=torch.float64), (1,) * 4)
    return {
        "ours": ours,
        "zeroed": zeroed,
        "zeroed, renormalised": zeroed / zeroed.sum(dim=(-2, -1), keepdim=True),
        "5 x 5": five,
    }


def border_effect(v_max: float = 1.0) -> dict[str, dict[str, float]]:
    """What zeroing Figure 3's border changes: border mass, b per direction, eq. (15).

    For each of :func:`border_variants`: the mass outside W_frame (direction 1, direction 9;
    directions 1-8 are alike), b of eq. (12) for an EMC of 0.8 at g = 0 and g = 1
    (``b = 0.8 / (g sum W + (1 - g) max W)``), and eq. (15)'s ``1/b = slope g + intercept``
    (``slope = (sum - max) / 0.8``, ``intercept = max / 0.8``) for directions 1-8 and 9.

    Examples:
        >>> effect = border_effect()
        >>> round(effect["ours"]["b g=0, dir 9"], 3), effect["zeroed"]["border mass, dir 9"]
        (4.673, 0.0)
    """
    frame = frame_matrix(7, v_max, 0.5, dtype=torch.float64)
    out = {}
    for name, w in border_variants(v_max).items():
        total, peak = w.sum(dim=(-2, -1)), w.amax(dim=(-2, -1))
        row = {}
        for d, label in ((0, "dir 1"), (8, "dir 9")):
            row[f"border mass, {label}"] = float((w[d] * (1 - frame)).sum())
            row[f"largest border / max, {label}"] = float((w[d] * (1 - frame)).max() / peak[d])
        for g in (0.0, 1.0):
            for d, label in ((0, "dir 1"), (8, "dir 9")):
                gain = g * total[d] + (1 - g) * peak[d]
                row[f"b g={g:g}, {label}"] = float(EMC / gain)
        for d, label in ((0, "dirs 1-8"), (8, "dir 9")):
            row[f"slope, {label}"] = float((total[d] - peak[d]) / EMC)
            row[f"intercept, {label}"] = float(peak[d] / EMC)
        out[name] = row
    return out


def border_tracking(
    speeds: tuple[float, ...] = (0.0, 0.5, 1.0, 1.5), seeds: int = 20
) -> dict[tuple[str, float, float], float]:
    """Fraction of frames on the truth with each of :func:`border_variants` (paper direction step).

    The speed scenes of ``experiments/dpa_pd_snr.py`` (part 2): one 17 dB target in clear sky,
    25 frames of 64 x 64, course at 30 degrees through the centre, jitter 0.5 px, anti-mean
    whitened, seeds 8400..; b of direction 9's EMC 0.8; the track back-tracked from the highest
    last-frame ASF, on the truth within 1.5 px. Returns ``(variant, g, speed) -> fraction``.
    """
    import math

    from hocnet.data.infrared import IRTarget, simulate_ir
    from hocnet.data.whitening import anti_mean
    from hocnet.dpa import accumulate, backtrack

    t_len, h, w = 25, 64, 64
    out = {}
    variants = {k: v.float() for k, v in border_variants().items()}
    for v in speeds:
        vx, vy = v * math.cos(math.radians(30.0)), v * math.sin(math.radians(30.0))
        half = 0.5 * (t_len - 1)
        target = IRTarget(0.5 * w - half * vx, 0.5 * h - half * vy, vx, vy, snr_db=17.0)
        seqs = [
            simulate_ir((t_len, h, w), [target], clouds="clear", seed=8400 + i)
            for i in range(seeds)
        ]
        frames = anti_mean(torch.stack([s.frames for s in seqs]).float())
        truth = torch.stack([s.positions[0] for s in seqs]).double()
        for name, weights in variants.items():
            for g in (0.0, 1.0):
                last = weights[-1].double()
                b = EMC / float(g * last.sum() + (1 - g) * last.max())
                path = backtrack(accumulate(frames, weights, b, g)).double()
                near = torch.linalg.vector_norm(path - truth, dim=-1) <= 1.5
                out[name, g, v] = float(near.double().mean())
    return out


CAPTION = (
    "Difference from [NR08] (our reading): the paper says the border pixels of Figure 3 are "
    "zeroed by W_frame; eq. (5) as printed applies W_frame to the penalty only, so the border "
    "ring of (a) and (c) keeps W_basic's tail ({mass9:.2%} of W(9), {mass1:.2%} of W(1..8)).\n"
    "Zeroing it changes no b at g = 0 ({b1:.3f} for directions 1-8, {b9:.3f} for direction 9, "
    "EMC 0.8), b at g = 1 "
    "from 0.800 to {z1:.3f} / {z9:.3f}, and eq. (15)'s slopes from {s1:.3f} / {s9:.3f} to "
    "{zs1:.3f} / {zs9:.3f} (intercepts unchanged); docs/dpa_figure3.py --border."
)


def caption() -> str:
    """The caption line of the difference, with the numbers of :func:`border_effect`."""
    e = border_effect()
    ours, zeroed = e["ours"], e["zeroed"]
    return CAPTION.format(
        mass9=ours["border mass, dir 9"],
        mass1=ours["border mass, dir 1"],
        b1=ours["b g=0, dir 1"],
        b9=ours["b g=0, dir 9"],
        z1=zeroed["b g=1, dir 1"],
        z9=zeroed["b g=1, dir 9"],
        s1=ours["slope, dirs 1-8"],
        s9=ours["slope, dir 9"],
        zs1=zeroed["slope, dirs 1-8"],
        zs9=zeroed["slope, dir 9"],
    )


def draw(out: Path) -> Path:
    """Draw the three panels and save them to ``out`` (PNG)."""
    basic, penalties, weights = figure3_matrices()
    fig, axes = plt.subplots(3, 9, figsize=(18, 6.6))
    rows = [
        [basic] + [None] * 8,
        [*penalties, None],
        list(weights),
    ]
    titles = ["(a) W_basic (direction 9)", "(b) W_penalty(d) W_frame", "(c) W(d), p = 0.5"]
    for r, (mats, title) in enumerate(zip(rows, titles, strict=True)):
        for c, m in enumerate(mats):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            if m is None:
                ax.axis("off")
                continue
            top = float(m.max())
            ax.imshow((m / top).numpy(), cmap="gray", vmin=0, vmax=1)
            label = "direction 9" if (r == 0) else f"direction {c + 1}: {ARROWS[c]}"
            ax.set_title(label, fontsize=8)
            for y in range(7):
                for x in range(7):
                    value = float(m[y, x])
                    text = f"{value:.3g}" if r != 1 else f"{value:g}"
                    if r != 1 and value < 0.0005:
                        text = "0" if value == 0 else "<.001"
                    ax.text(
                        x,
                        y,
                        text,
                        ha="center",
                        va="center",
                        fontsize=4.5,
                        color="red" if value / top < 0.5 else "black",
                    )
        axes[r, 0].set_ylabel(title, fontsize=9)
    fig.suptitle(
        "Figure 3 of [NR08] rebuilt by hocnet.dpa.figure3_matrices (7 x 7, 0-1 px/frame, "
        "jitter U[-0.5, 0.5], Gaussian spread sigma = 0.871 px, x = 3, p = 0.5); "
        "each matrix scaled to its maximum",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.035, 1, 1))
    fig.text(0.5, 0.012, caption(), ha="center", va="bottom", fontsize=7.5, wrap=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _print_border() -> None:
    """``--border``: the tables of :func:`border_effect` and :func:`border_tracking`."""
    effect = border_effect()
    keys = list(next(iter(effect.values())))
    print("| quantity | " + " | ".join(effect) + " |")
    print("|---" * (len(effect) + 1) + "|")
    for key in keys:
        print(f"| {key} | " + " | ".join(f"{row[key]:.4g}" for row in effect.values()) + " |")
    tracking = border_tracking()
    speeds = sorted({v for _, _, v in tracking})
    print("\n| variant | g | " + " | ".join(f"{v:g} px/frame" for v in speeds) + " |")
    print("|---" * (len(speeds) + 2) + "|")
    for name in effect:
        for g in (0.0, 1.0):
            cells = " | ".join(f"{tracking[name, g, v]:.2f}" for v in speeds)
            print(f"| {name} | {g:g} | {cells} |")


if __name__ == "__main__":
    if sys.argv[1:] == ["--border"]:
        torch.set_num_threads(1)
        _print_border()
    else:
        target = (
            Path(sys.argv[1])
            if len(sys.argv) > 1
            else Path(__file__).parent / "images" / "dpa_figure3.png"
        )
        print(draw(target))

"""Draw Figure 3 of [NR08] from hocnet's matrices: ``docs/images/dpa_figure3.png``.

(a) the 7 x 7 ``W_basic`` (direction 9), (b) the eight ``W_penalty(d) * W_frame`` for 0-1 px/frame
(a 5 x 5 valid search area inside the 7 x 7 window; Figure 2's rule with x = 3), (c) the nine
``W(d)`` of eq. (5) for p = 0.5. As in the paper, every matrix is shown on its own 0-1 scale
(divided by its maximum). Rows are y (down), columns x; direction d moves at (d - 1) * 45 degrees
of atan2(dy, dx), so direction 1 is +x (right) and direction 3 is +y (down on screen).

Run::

    .venv/bin/python docs/dpa_figure3.py [OUT.png]
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from hocnet.dpa.matrices import figure3_matrices

ARROWS = ["→ 0°", "↘ 45°", "↓ 90°", "↙ 135°", "← 180°", "↖ 225°", "↑ 270°", "↗ 315°", "in place"]


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
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


if __name__ == "__main__":
    target = (
        Path(sys.argv[1])
        if len(sys.argv) > 1
        else Path(__file__).parent / "images" / "dpa_figure3.png"
    )
    print(draw(target))

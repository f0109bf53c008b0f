"""Diagnostic (ours): does [NR08]'s g = 1 "snow ball" form at b = 1 in our NA23A-like scenes?

[NR08] section 3.2.1(1) (s_n = 1, g = 1): "the relevant range of b is 0 <= b <= 1", the TB's SNR
falls at around b = 1, and above b = 1 a "snow ball" grows around the target "until the target
is engulfed in it". Table 2 gives NA23 g = 1 tracking at 0.2-0.8; ours (``dpa-b-sweep``) tracks
up to b = 1. At g = 1 the eq. (5) matrices sum to 1, so b = 1 is the EMC-1 limit of eq. (12)-(14)
(a standing pixel keeps all of its score) and the library refuses b > 1 (``b_limit``).

For the NA23A-like scenes of ``dpa-b-sweep`` (Table 2's s_n = 4, anti-mean whitened, 5 x 5
matrices, g = 1) and b in {0.6, 0.8, 1.0}, per frame n, mean over the seeds: the number of
pixels of the 31 x 31 window around the target whose ASF exceeds the target's (the highest ASF
of the target's 3 x 3), the ball's area (pixels of that window >= half the target's ASF), the
mean of the other 8 pixels of the target's 3 x 3 relative to its highest, and the target's local
SNR (target ASF minus the window's mean outside the 7 x 7 around it, over that part's std); and
the fraction of scenes tracked (``tracked``, back-tracked from the nine blocks' highest pixel).

Run: ``python experiments/_dpa_snowball_diag.py [--scene "NA23A"] [--seeds 6]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import _nr08 as P
import dpa_b_sweep as S
import torch

from hocnet.dpa import accumulate, backtrack

BS = (0.6, 0.8, 1.0)
FRAMES = (1, 5, 10, 15, 20, 25)
RADIUS = 15


def snowball(scene: str = "NA23A", n_seeds: int = 6, bs: Sequence[float] = BS) -> list[dict]:
    """One row per (b, frame): the means over ``n_seeds`` scenes (see the module docstring)."""
    seeds = list(range(S.SEED_BASE, S.SEED_BASE + n_seeds))
    frames, truth = S.sampled(scene, seeds, S.SHAPES[scene])
    weights = P.weights()
    rows = []
    for b in bs:
        state = accumulate(frames, weights, b, 1.0)
        asf = state.asf
        path = backtrack(state, P.nine_block_start(asf, truth, S.BLOCK[scene]))
        tracked = float(P.tracked(path, truth).double().mean())
        for n in FRAMES:
            above, ball, neighbours, snr = [], [], [], []
            for i in range(len(seeds)):
                x, y = (int(torch.floor(truth[i, n - 1, k] + 0.5)) for k in (0, 1))
                a = asf[i, n - 1]
                y0, x0 = max(0, y - RADIUS), max(0, x - RADIUS)
                win = a[y0 : y + RADIUS + 1, x0 : x + RADIUS + 1]
                own = a[max(0, y - 1) : y + 2, max(0, x - 1) : x + 2].flatten()
                own = own.sort(descending=True).values
                target = own[0]
                above.append(float((win > target).sum()))
                ball.append(float((win >= 0.5 * target).sum()))
                neighbours.append(float(own[1:].mean() / target))
                mask = torch.ones_like(win, dtype=torch.bool)
                cy, cx = y - y0, x - x0
                mask[max(0, cy - 3) : cy + 4, max(0, cx - 3) : cx + 4] = False
                rest = win[mask]
                snr.append(float((target - rest.mean()) / rest.std()))
            rows.append(
                {
                    "b": b,
                    "frame": n,
                    "above": sum(above) / len(above),
                    "ball": sum(ball) / len(ball),
                    "neighbours": sum(neighbours) / len(neighbours),
                    "snr": sum(snr) / len(snr),
                    "tracked": tracked,
                }
            )
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    """Print the table of :func:`snowball`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="NA23A")
    parser.add_argument("--seeds", type=int, default=6)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    print("b | frame | pixels above the target | ball area | 8 neighbours / target | SNR | tracked")
    for r in snowball(args.scene, args.seeds):
        print(
            f"{r['b']:g} | {r['frame']} | {r['above']:.1f} | {r['ball']:.1f} | "
            f"{r['neighbours']:.2f} | {r['snr']:.1f} | {r['tracked']:.2f}"
        )


if __name__ == "__main__":
    main()

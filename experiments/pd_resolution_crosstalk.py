"""Cross-talk between the civilian target 1 and the convoy 2, 3, 4, 7 with and without PCR5.

For the [PD] 24.6 scenario variant given on the command line (GMTI resolution cells in sigmas
or ``off``, convoy headway in s), runs the VS-IMMC SB-MHT on seeds 2400 .. 2409 without and with
the type term of eq. 24.48 and counts, over the confirmed tracks (assigned to a target by the
majority of their measurements), the samples of target 1's tracks updated by a convoy report and
the samples of the convoy's tracks updated by a target-1 report. Printed as one JSON line
``{"without"|"with": {"t1_in_convoy", "convoy_in_t1", "t1_samples", "convoy_samples"}}``.

Full runs (1200 s scenario, 10 seeds; the numbers of the cross-talk table of
``experiments/results/pd-resolution.md``, a note written by hand from the printed output)::

    python experiments/pd_resolution_crosstalk.py RESOLUTION HEADWAY   # e.g. ``2.5 4``, ``off 10``

Options: ``RESOLUTION HEADWAY`` (default ``off 10``), ``--seeds N`` (default 10; 1 with
``--quick``), ``--duration S`` (default 1200 s), ``--quick`` (smoke run: a ``QUICK_DURATION``
s scenario, once target 1 has joined the highway, and 1 seed; a few seconds), ``--out DIR``
(optional: also write the JSON to ``DIR/pd-resolution-crosstalk-RESOLUTION-HEADWAY.json``).
The output is printed; nothing is written without ``--out``, and a ``--quick`` run refuses an
``--out`` inside ``experiments/results``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
from collections.abc import Sequence

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _expkit as C
import numpy as np
import torch
from pd_scenario import SEED_BASE, _scenario_kwargs

from hocnet.tracking.evaluation import FALSE_ALARM, NO_MEASUREMENT, assign_tracks
from hocnet.tracking.pipeline import PDTrackerConfig, run_pd_tracker
from hocnet.tracking.scenario import PD_DURATION, pd_scenario

NAME = "pd-resolution-crosstalk"
CONVOY = (2, 3, 4, 7)
FULL_SEEDS = 10
QUICK_SEEDS = 1
QUICK_DURATION = 400.0
"""Smoke-run scenario length (s): target 1 departs at 250 s, on the convoy's highway."""


def crosstalk(
    resolution: float | None,
    headway: float,
    n_runs: int = FULL_SEEDS,
    *,
    duration: float = PD_DURATION,
) -> dict[str, dict]:
    """``{"without"|"with": counts}`` over ``n_runs`` seeds from ``SEED_BASE``.

    ``duration``: scenario length (s; the full runs use the default 1200 s).
    """
    torch.set_num_threads(1)
    out = {}
    for name in ("without", "with"):
        c = {"t1_in_convoy": 0, "convoy_in_t1": 0, "t1_samples": 0, "convoy_samples": 0}
        for seed in range(SEED_BASE, SEED_BASE + n_runs):
            sc = pd_scenario(seed=seed, duration=duration, **_scenario_kwargs(resolution, headway))
            run = run_pd_tracker(
                sc, type_tracking=name == "with", config=PDTrackerConfig(), seed=seed
            )
            owner = assign_tracks(run.tracks)
            for k, trk in run.tracks.items():
                ids = trk.truth_ids
                ids = ids[(ids != FALSE_ALARM) & (ids != NO_MEASUREMENT)]
                if owner[k] == 1:
                    c["t1_samples"] += int(ids.size)
                    c["convoy_in_t1"] += int(np.isin(ids, CONVOY).sum())
                elif owner[k] in CONVOY:
                    c["convoy_samples"] += int(ids.size)
                    c["t1_in_convoy"] += int((ids == 1).sum())
        out[name] = c
    return out


def _resolution(text: str) -> float | None:
    """``off`` or a positive number of sigmas (the RESOLUTION argument)."""
    if text == "off":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'off' or a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected 'off' or a number > 0, got {text!r}")
    return value


def main(argv: Sequence[str] | None = None) -> dict[str, dict]:
    """Command line entry point; prints the counts as one JSON line and returns them."""
    ap = argparse.ArgumentParser(prog=NAME, description=__doc__.splitlines()[0])
    ap.add_argument(
        "resolution",
        nargs="?",
        default="off",
        type=_resolution,
        help="GMTI resolution cells in sigmas, or off (default)",
    )
    ap.add_argument("headway", nargs="?", default=10.0, type=float, help="convoy headway (s)")
    ap.add_argument(
        "--seeds", type=int, default=None, help=f"seeds (default {FULL_SEEDS}, quick 1)"
    )
    ap.add_argument(
        "--duration",
        type=float,
        default=None,
        help=f"scenario length in s (default {PD_DURATION:g}, quick {QUICK_DURATION:g})",
    )
    ap.add_argument("--quick", action="store_true", help="smoke run (short scenario, 1 seed)")
    ap.add_argument("--out", default=None, help="also write the JSON to a file in DIR")
    a = ap.parse_args(argv)
    if a.seeds is None:
        a.seeds = QUICK_SEEDS if a.quick else FULL_SEEDS
    if a.seeds < 1:
        ap.error(f"--seeds: expected >= 1, got {a.seeds}")
    if a.duration is None:
        a.duration = QUICK_DURATION if a.quick else PD_DURATION
    path = None
    if a.out is not None:
        folder = C.strict_out_dir_of(a.out, quick=a.quick, error=ap.error)
        res_name = "off" if a.resolution is None else f"{a.resolution:g}"
        path = folder / f"{NAME}-{res_name}-{a.headway:g}.json"
    out = crosstalk(a.resolution, a.headway, a.seeds, duration=a.duration)
    text = json.dumps(out)
    print(text)
    if path is not None:
        path.write_text(text + "\n")
        print(f"{NAME}: written to {path}", file=sys.stderr)
    return out


if __name__ == "__main__":
    main()

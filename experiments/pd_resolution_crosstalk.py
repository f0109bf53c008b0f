"""Cross-talk between the civilian target 1 and the convoy 2, 3, 4, 7 with and without PCR5.

For the [PD] 24.6 scenario variant given on the command line (GMTI resolution cells in sigmas
or ``off``, convoy headway in s), runs the VS-IMMC SB-MHT on seeds 2400 .. 2409 without and with
the type term of eq. 24.48 and counts, over the confirmed tracks (assigned to a target by the
majority of their measurements), the samples of target 1's tracks updated by a convoy report and
the samples of the convoy's tracks updated by a target-1 report. Numbers of
``experiments/results/pd-resolution.md``.

Run: ``python experiments/pd_resolution_crosstalk.py RESOLUTION HEADWAY`` (e.g. ``2.5 4`` or
``off 10``).
"""

from __future__ import annotations

import json
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import numpy as np
import torch
from pd_scenario import SEED_BASE, _scenario_kwargs

from hocnet.tracking.evaluation import FALSE_ALARM, NO_MEASUREMENT, assign_tracks
from hocnet.tracking.pipeline import PDTrackerConfig, run_pd_tracker
from hocnet.tracking.scenario import pd_scenario

CONVOY = (2, 3, 4, 7)


def crosstalk(resolution: float | None, headway: float, n_runs: int = 10) -> dict[str, dict]:
    """``{"without"|"with": counts}`` over ``n_runs`` seeds from ``SEED_BASE``."""
    torch.set_num_threads(1)
    out = {}
    for name in ("without", "with"):
        c = {"t1_in_convoy": 0, "convoy_in_t1": 0, "t1_samples": 0, "convoy_samples": 0}
        for seed in range(SEED_BASE, SEED_BASE + n_runs):
            sc = pd_scenario(seed=seed, **_scenario_kwargs(resolution, headway))
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


if __name__ == "__main__":
    res = None if sys.argv[1] == "off" else float(sys.argv[1])
    print(json.dumps(crosstalk(res, float(sys.argv[2]))))

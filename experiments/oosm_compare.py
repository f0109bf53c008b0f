"""Before / after of the OOSM lag policy on the [PD] 24.6 experiment (issue 12, our addition).

Runs ``experiments/pd_scenario.py``'s :func:`evaluate` (same seeds, both configurations
without / with PCR5) for ``PDTrackerConfig(max_lag=None)`` (one-step A1, the previous
behaviour) and ``max_lag=N``, and prints per target the track purity, ARMSE and type purity and
the diagnostics (out-of-lag rows, OOSM fallbacks).

Run: ``OMP_NUM_THREADS=1 python experiments/oosm_compare.py --seeds 5 --max-lag 2 [--jobs 2]``.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import numpy as np
import pd_scenario as E
import torch

from hocnet.tracking.pipeline import PDTrackerConfig
from hocnet.tracking.scenario import PD_DURATION


def summary(res: dict) -> dict:
    out: dict = {"seeds": res["seeds"], "goals": {}, "targets": {}, "diag": {}}
    g = E.goals(res)
    out["goals"] = {k: v for k, v in g.items() if k != "armse_within"}
    for name, mets in res["metrics"].items():
        out["targets"][name] = {
            int(t): {
                "purity": m.track_purity,
                "armse": m.armse,
                "type_purity": m.type_purity,
                "length": m.length_ratio,
            }
            for t, m in mets.items()
        }
        out["diag"][name] = {
            k: float(np.mean([d[k] for d in res["diag"][name]])) for k in res["diag"][name][0]
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--max-lag", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--only", choices=("before", "after"), default=None)
    ap.add_argument("--json", type=pathlib.Path, default=None)
    a = ap.parse_args()
    torch.set_num_threads(1)
    settings = {"before (max_lag=None)": None, f"after (max_lag={a.max_lag})": a.max_lag}
    if a.only:
        settings = dict([list(settings.items())[0 if a.only == "before" else 1]])
    results = {}
    for label, ml in settings.items():
        res = E.evaluate(a.seeds, PD_DURATION, False, PDTrackerConfig(max_lag=ml), jobs=a.jobs)
        results[label] = summary(res)
        s = results[label]
        print(f"== {label}: seeds {s['seeds']}")
        for name, d in s["diag"].items():
            print(f"  {name} diagnostics: " + ", ".join(f"{k} {v:.1f}" for k, v in d.items()))
        print("  goals: " + ", ".join(f"{k} {v:.4f}" for k, v in s["goals"].items()))
        for name, tg in s["targets"].items():
            print(f"  {name}: target purity / ARMSE / type purity / length")
            for t, m in sorted(tg.items()):
                print(
                    f"    {t:2d}: {m['purity']:.3f} / {m['armse']:.1f} / "
                    f"{m['type_purity'] if math.isfinite(m['type_purity']) else float('nan'):.3f}"
                    f" / {m['length']:.3f}"
                )
        sys.stdout.flush()
    if a.json:
        a.json.write_text(json.dumps(results, indent=1, default=float))


if __name__ == "__main__":
    main()

"""Before / after of the OOSM lag policy on the [PD] 24.6 experiment (issue 12, our addition).

Runs ``experiments/pd_scenario.py``'s :func:`evaluate` (same seeds, both configurations
without / with PCR5) for ``PDTrackerConfig(max_lag=None)`` (one-step A1, the previous
behaviour) and ``max_lag=N``, and prints per target the track purity, ARMSE and type purity and
the diagnostics (out-of-lag rows, OOSM fallbacks).

Full run (1200 s scenario, 5 seeds; measured numbers in the "Before / after" section of
``experiments/results/oosm-lags.md``, a note written by hand from the printed output)::

    OMP_NUM_THREADS=1 python experiments/oosm_compare.py --seeds 5 --max-lag 2 [--jobs 2]

Options: ``--seeds N`` (default 5; 1 with ``--quick``), ``--max-lag N`` (default 2),
``--jobs J``, ``--only {before,after}``, ``--json FILE`` (the summary as JSON),
``--duration S`` (default 1200 s), ``--quick`` (smoke run: a ``QUICK_DURATION`` s scenario,
the first with video and UGS reports, and 1 seed; a few seconds), ``--out DIR`` (optional:
also write the printed output to ``DIR/oosm-compare.txt`` and the summary to
``DIR/oosm-compare.json``). The output is printed; nothing is written without ``--out`` or
``--json``, and a ``--quick`` run refuses an output inside ``experiments/results``.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
from collections.abc import Sequence

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import numpy as np
import pd_scenario as E
import torch

from hocnet.tracking.pipeline import PDTrackerConfig
from hocnet.tracking.scenario import PD_DURATION

NAME = "oosm-compare"
FULL_SEEDS = 5
QUICK_SEEDS = 1
QUICK_DURATION = 400.0
"""Smoke-run scenario length (s): video reports start at 245 s, UGS reports at 388 s."""


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


def _checked(path: pathlib.Path, quick: bool, error) -> pathlib.Path:
    """``path`` (its folder created); ``error`` for a ``--quick`` output in experiments/results."""
    E.C.strict_out_dir_of(str(path.parent), quick=quick, error=error)
    return path


def main(argv: Sequence[str] | None = None) -> str:
    """Command line entry point; prints the comparison and returns the printed text."""
    ap = argparse.ArgumentParser(prog=NAME, description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seeds", type=int, default=None, help=f"seeds (default {FULL_SEEDS}, quick 1)"
    )
    ap.add_argument("--max-lag", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--only", choices=("before", "after"), default=None)
    ap.add_argument("--json", type=pathlib.Path, default=None)
    ap.add_argument(
        "--duration",
        type=float,
        default=None,
        help=f"scenario length in s (default {PD_DURATION:g}, quick {QUICK_DURATION:g})",
    )
    ap.add_argument("--quick", action="store_true", help="smoke run (short scenario, 1 seed)")
    ap.add_argument(
        "--out", default=None, help=f"also write DIR/{NAME}.txt (output) and DIR/{NAME}.json"
    )
    a = ap.parse_args(argv)
    if a.seeds is None:
        a.seeds = QUICK_SEEDS if a.quick else FULL_SEEDS
    if a.seeds < 1:
        ap.error(f"--seeds: expected >= 1, got {a.seeds}")
    if a.jobs < 1:
        ap.error(f"--jobs: expected >= 1, got {a.jobs}")
    if a.duration is None:
        a.duration = QUICK_DURATION if a.quick else PD_DURATION
    if a.out is not None and not str(a.out).strip():
        ap.error("--out: expected a folder name, got an empty string")
    outputs = [] if a.json is None else [_checked(a.json, a.quick, ap.error)]
    if a.out is not None:
        out = pathlib.Path(a.out)
        outputs += [_checked(out / f"{NAME}.{ext}", a.quick, ap.error) for ext in ("txt", "json")]
    torch.set_num_threads(1)
    lines: list[str] = []

    def emit(line: str) -> None:
        lines.append(line)
        print(line)

    settings = {"before (max_lag=None)": None, f"after (max_lag={a.max_lag})": a.max_lag}
    if a.only:
        settings = dict([list(settings.items())[0 if a.only == "before" else 1]])
    results = {}
    for label, ml in settings.items():
        res = E.evaluate(a.seeds, a.duration, False, PDTrackerConfig(max_lag=ml), jobs=a.jobs)
        results[label] = summary(res)
        s = results[label]
        emit(f"== {label}: seeds {s['seeds']}")
        for name, d in s["diag"].items():
            emit(f"  {name} diagnostics: " + ", ".join(f"{k} {v:.1f}" for k, v in d.items()))
        emit("  goals: " + ", ".join(f"{k} {v:.4f}" for k, v in s["goals"].items()))
        for name, tg in s["targets"].items():
            emit(f"  {name}: target purity / ARMSE / type purity / length")
            for t, m in sorted(tg.items()):
                emit(
                    f"    {t:2d}: {m['purity']:.3f} / {m['armse']:.1f} / "
                    f"{m['type_purity'] if math.isfinite(m['type_purity']) else float('nan'):.3f}"
                    f" / {m['length']:.3f}"
                )
        sys.stdout.flush()
    text = "\n".join(lines) + "\n"
    summary_json = json.dumps(results, indent=1, default=float)
    if a.json:
        a.json.write_text(summary_json)
    if a.out is not None:
        out = pathlib.Path(a.out)
        (out / f"{NAME}.txt").write_text(text)
        (out / f"{NAME}.json").write_text(summary_json)
        print(f"{NAME}: written to {out}", file=sys.stderr)
    return text


if __name__ == "__main__":
    main()

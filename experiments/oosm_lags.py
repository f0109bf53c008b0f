"""Measure the delayed IMINT reports of the [PD] 24.6 scenario and their OOSM lags (issue 12).

For each seed (``SEED_BASE + i`` of ``experiments/pd_scenario.py``): the number of video / UGS
reports, their lag behind the tracker at arrival (seconds after the latest GMTI scan processed
before them, and the number of GMTI scans after their measurement time), and, by instrumenting
:class:`hocnet.tracking.pipeline.VSIMMRoadFilter` (no change to the pipeline), the rows (MHT
leaves) for which a delayed report was out of the OOSM lag, the reports concerned (an
out-of-lag row within ``NEAR`` m of the report), the lag of those rows in seconds and in filter
steps (the step count needs the multi-step lag memory: ``--max-lag N``, else only ``> 1``).

Full runs (1200 s scenario, 2 seeds; measured numbers in ``experiments/results/oosm-lags.md``,
a note written by hand from the printed output)::

    OMP_NUM_THREADS=1 python experiments/oosm_lags.py --seeds 2                # one-step A1
    OMP_NUM_THREADS=1 python experiments/oosm_lags.py --seeds 2 --max-lag 3    # lag memory

Options: ``--seeds N`` (default 2; 1 with ``--quick``), ``--duration S`` (default 1200 s),
``--max-lag N``, ``--pcr5`` (with the type tracker), ``--quick`` (smoke run: a
``QUICK_DURATION`` s scenario, the first with video and UGS reports, and 1 seed; a few
seconds), ``--out DIR`` (optional: also write the printed output to ``DIR/oosm-lags.txt``).
The output is printed; nothing is written without ``--out``, and a ``--quick`` run refuses an
``--out`` inside ``experiments/results``.
"""

from __future__ import annotations

import argparse
import collections
import pathlib
import sys
from collections.abc import Sequence

# the helpers next to this file, also when the script is loaded by path
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _expkit as C
import numpy as np
import torch

from hocnet.tracking import pipeline as P
from hocnet.tracking.scenario import pd_scenario

NAME = "oosm-lags"
SEED_BASE = 2400
NEAR = 300.0
FULL_SEEDS = 2
FULL_DURATION = 1200.0
QUICK_SEEDS = 1
QUICK_DURATION = 400.0
"""Smoke-run scenario length (s): video reports start at 245 s, UGS reports at 388 s."""


def report_lags(sc) -> dict[str, list[tuple[float, int]]]:
    """Per IMINT kind, ``(lag_s, lag_scans)`` of each report against the GMTI scans before it."""
    gmti_times: list[float] = []
    out: dict[str, list[tuple[float, int]]] = collections.defaultdict(list)
    for r in sc.reports:
        if r.kind == "gmti":
            if not gmti_times or gmti_times[-1] != r.time:
                gmti_times.append(r.time)
            continue
        if not gmti_times:
            continue
        tk = gmti_times[-1]
        n = sum(1 for t in gmti_times if t > r.time + 1e-9)
        out[r.kind].append((tk - r.time, n))
    return out


def instrumented_run(sc, *, type_tracking: bool, max_lag: int | None) -> dict:
    """Run the tracker and collect the out-of-lag rows of every delayed scan."""
    rec: dict = {"rows": [], "reports": set(), "retro_rows": 0, "retro_reports": set()}
    orig = P.VSIMMRoadFilter.innovation
    state = {"scan": 0}

    def innovation(self, states):
        out = orig(self, states)
        if self.kind != "gmti" and states["mu"].shape[0]:
            bad = ~states["lag_ok"]
            retro = states["retro"]
            x, _ = self._vs(states).combined()
            z = self._cur_z
            d = torch.cdist(x[:, [0, 2]], z[:, :2]) if z.shape[0] else None
            for i in torch.nonzero(retro).flatten().tolist():
                near = [] if d is None else torch.nonzero(d[i] < NEAR).flatten().tolist()
                for j in near:
                    rec["retro_reports"].add((state["scan"], j))
                if "lag_t" in states:
                    lt = states["lag_t"][i]
                    n = int((lt > self.time + 1e-9).sum())
                    birth = n < lt.numel() and bool(torch.isinf(lt[n]))
                    key = "birth" if birth else f"{n + 1} step(s)"
                    rec.setdefault("lag_steps", collections.Counter())[key] += 1
                    if near:
                        rec.setdefault("lag_steps_near", collections.Counter())[key] += 1
                if bool(bad[i]):
                    lag_s = float(states["t"][i] - self.time)
                    steps = None
                    if "lag_t" in states:
                        lt = states["lag_t"][i]
                        steps = int((lt > self.time + 1e-9).sum()) + 1
                    rec["rows"].append((self.kind, lag_s, steps))
                    rec.setdefault("last_step", []).append(
                        float(states["t"][i] - states["t_prev"][i])
                    )
                    for j in near:
                        rec["reports"].add((state["scan"], j, self.kind))
        return out

    orig_set = P.VSIMMRoadFilter.set_scan
    orig_step = P.MHT.step

    def step(self, z, **kw):
        self.filter._cur_z = torch.as_tensor(z)
        state["scan"] += 1
        return orig_step(self, z, **kw)

    P.VSIMMRoadFilter.innovation = innovation
    P.MHT.step = step
    try:
        cfg = P.PDTrackerConfig() if max_lag is None else P.PDTrackerConfig(max_lag=max_lag)
        run = P.run_pd_tracker(sc, type_tracking=type_tracking, config=cfg)
    finally:
        P.VSIMMRoadFilter.innovation = orig
        P.VSIMMRoadFilter.set_scan = orig_set
        P.MHT.step = orig_step
    rec["run"] = run
    return rec


def out_path(out: str | None, quick: bool, filename: str, error) -> pathlib.Path | None:
    """``out/filename`` (folder created), ``None`` without ``out``; ``error`` if not allowed.

    A ``--quick`` run never writes into ``experiments/results`` (the committed full results).
    """
    folder = C.strict_out_dir_of(out, quick=quick, error=error)
    if folder is None:
        return None
    return folder / filename


def main(argv: Sequence[str] | None = None) -> str:
    """Command line entry point; prints the measurements and returns the printed text."""
    ap = argparse.ArgumentParser(prog=NAME, description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seeds", type=int, default=None, help=f"seeds (default {FULL_SEEDS}, quick 1)"
    )
    ap.add_argument(
        "--duration",
        type=float,
        default=None,
        help=f"scenario length in s (default {FULL_DURATION:g}, quick {QUICK_DURATION:g})",
    )
    ap.add_argument("--max-lag", type=int, default=None)
    ap.add_argument("--pcr5", action="store_true")
    ap.add_argument("--quick", action="store_true", help="smoke run (short scenario, 1 seed)")
    ap.add_argument("--out", default=None, help=f"also write the output to DIR/{NAME}.txt")
    a = ap.parse_args(argv)
    if a.seeds is None:
        a.seeds = QUICK_SEEDS if a.quick else FULL_SEEDS
    if a.seeds < 1:
        ap.error(f"--seeds: expected >= 1, got {a.seeds}")
    if a.duration is None:
        a.duration = QUICK_DURATION if a.quick else FULL_DURATION
    path = out_path(a.out, a.quick, f"{NAME}.txt", ap.error)
    torch.set_num_threads(1)
    lines: list[str] = []

    def emit(line: str) -> None:
        lines.append(line)
        print(line)

    for i in range(a.seeds):
        seed = SEED_BASE + i
        sc = pd_scenario(seed=seed, duration=a.duration)
        lags = report_lags(sc)
        emit(f"seed {seed}: {len(sc.reports)} reports")
        for kind, v in sorted(lags.items()):
            arr = np.array(v)
            hist = collections.Counter(int(n) for n in arr[:, 1])
            emit(
                f"  {kind}: {len(v)} reports; lag behind the last GMTI scan "
                f"{arr[:, 0].min():.0f}..{arr[:, 0].max():.0f} s (mean {arr[:, 0].mean():.1f}); "
                f"GMTI scans after tau: {dict(sorted(hist.items()))}"
            )
        rec = instrumented_run(sc, type_tracking=a.pcr5, max_lag=a.max_lag)
        rows = rec["rows"]
        by_kind = collections.Counter(k for k, _, _ in rows)
        lag_s = np.array([v for _, v, _ in rows]) if rows else np.zeros(0)
        steps = collections.Counter(s for _, _, s in rows)
        rep = collections.Counter(k for _, _, k in rec["reports"])
        lo, hi, mean = (lag_s.min(), lag_s.max(), lag_s.mean()) if lag_s.size else (0.0, 0.0, 0.0)
        emit(
            f"  tracker: {rec['run'].out_of_lag} out-of-lag rows ({dict(by_kind)}), "
            f"reports with an out-of-lag row within {NEAR:g} m: {dict(rep)} of "
            f"{len(rec['retro_reports'])} (report, scan) pairs with an OOSM row nearby; "
            f"row lags {lo:.0f}..{hi:.0f} s (mean {mean:.1f}); steps {dict(steps)}"
        )
        ls = collections.Counter(round(v) for v in rec.get("last_step", []))
        emit(f"  last step length (t - t_prev) of the out-of-lag rows, s: {dict(ls)}")
        if "lag_steps" in rec:
            emit(
                f"  OOSM rows by lag (memory of {a.max_lag} steps): {dict(rec['lag_steps'])}; "
                f"with the report within {NEAR:g} m: {dict(rec.get('lag_steps_near', {}))}"
            )
        sys.stdout.flush()
    text = "\n".join(lines) + "\n"
    if path is not None:
        path.write_text(text)
        print(f"{NAME}: written to {path}", file=sys.stderr)
    return text


if __name__ == "__main__":
    main()

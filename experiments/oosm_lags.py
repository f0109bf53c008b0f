"""Measure the delayed IMINT reports of the [PD] 24.6 scenario and their OOSM lags (issue 12).

For each seed (``SEED_BASE + i`` of ``experiments/pd_scenario.py``): the number of video / UGS
reports, their lag behind the tracker at arrival (seconds after the latest GMTI scan processed
before them, and the number of GMTI scans after their measurement time), and, by instrumenting
:class:`hocnet.tracking.pipeline.VSIMMRoadFilter` (no change to the pipeline), the rows (MHT
leaves) for which a delayed report was out of the OOSM lag, the reports concerned (an
out-of-lag row within ``NEAR`` m of the report), the lag of those rows in seconds and in filter
steps (the step count needs the multi-step lag memory: ``--max-lag N``, else only ``> 1``).

Run: ``OMP_NUM_THREADS=1 python experiments/oosm_lags.py [--seeds 2] [--max-lag 1] [--pcr5]``.
"""

from __future__ import annotations

import argparse
import collections
import sys
from collections.abc import Sequence

import numpy as np
import torch

from hocnet.tracking import pipeline as P
from hocnet.tracking.scenario import pd_scenario

SEED_BASE = 2400
NEAR = 300.0


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


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--max-lag", type=int, default=None)
    ap.add_argument("--pcr5", action="store_true")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    for i in range(a.seeds):
        seed = SEED_BASE + i
        sc = pd_scenario(seed=seed, duration=a.duration)
        lags = report_lags(sc)
        print(f"seed {seed}: {len(sc.reports)} reports")
        for kind, v in sorted(lags.items()):
            arr = np.array(v)
            hist = collections.Counter(int(n) for n in arr[:, 1])
            print(
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
        print(
            f"  tracker: {rec['run'].out_of_lag} out-of-lag rows ({dict(by_kind)}), "
            f"reports with an out-of-lag row within {NEAR:g} m: {dict(rep)} of "
            f"{len(rec['retro_reports'])} (report, scan) pairs with an OOSM row nearby; "
            f"row lags {lo:.0f}..{hi:.0f} s (mean {mean:.1f}); steps {dict(steps)}"
        )
        ls = collections.Counter(round(v) for v in rec.get("last_step", []))
        print(f"  last step length (t - t_prev) of the out-of-lag rows, s: {dict(ls)}")
        if "lag_steps" in rec:
            print(
                f"  OOSM rows by lag (memory of {a.max_lag} steps): {dict(rec['lag_steps'])}; "
                f"with the report within {NEAR:g} m: {dict(rec.get('lag_steps_near', {}))}"
            )
        sys.stdout.flush()


if __name__ == "__main__":
    main()

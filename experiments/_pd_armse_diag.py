"""Diagnostic (ours): which samples make the per-target ARMSE of the [PD] 24.6 experiment.

Runs :func:`hocnet.tracking.pipeline.run_pd_tracker`'s loop on a few seeds and records, for every
sample of a confirmed track, what the tracker was doing: scan kind, stop-mode probability, time
since the last detection, the road section, the target of the current leaf's measurement and of
the final history. Writes a pickle of the samples and prints the worst contributors to the ARMSE.

Run: ``python experiments/_pd_armse_diag.py --seeds 2400-2409 --jobs 2 [--pcr5] [--out F]``.
``--trace SEED TARGET T0 T1`` (issue 12, ARMSE helper 2) prints, scan by scan between T0 and T1,
the target's reports, the gate distances of the three nearest rows (with their junction
hypotheses) and the confirmed tracks near the target with their leaves (score, mode
probabilities, road section, pending section tests, last measurement).
"""

from __future__ import annotations

import argparse
import math
import pathlib
import pickle
import sys
from typing import Any

import numpy as np
import torch

from hocnet.tracking.evaluation import (
    FALSE_ALARM,
    NO_MEASUREMENT,
    NO_TYPE,
    EstimatedTrack,
    assign_tracks,
    monte_carlo_metrics,
)
from hocnet.tracking.mht import MHT
from hocnet.tracking.pipeline import (
    PDTrackerConfig,
    _declared_type,
    _pd_tracker,
)
from hocnet.tracking.scenario import pd_scenario


def _confirmed_rows(mht: MHT) -> list[tuple[int, int]]:
    """(leaf index, family) of the confirmed tracks of the best hypotheses (as MHT.tracks)."""
    pos = {leaf.uid: i for i, leaf in enumerate(mht._leaves)}
    out = []
    for cl in mht._clusters:
        if not cl.hyps:
            continue
        for u in cl.hyps[0][1]:
            i = pos[u]
            if mht._leaves[i].status == "confirmed":
                out.append((i, mht._leaves[i].family))
    return out


def run_seed(seed: int, type_tracking: bool, config: PDTrackerConfig | None = None) -> dict:
    """One run with per-sample diagnostics."""
    torch.set_num_threads(1)
    cfg = PDTrackerConfig() if config is None else config
    sc = pd_scenario(seed=seed)
    filt, mht, scans = _pd_tracker(sc, cfg, type_tracking=type_tracking)
    rng = np.random.default_rng(seed)
    samples: dict[int, list[dict[str, Any]]] = {}
    last: dict[int, Any] = {}
    mht_time = None
    stop = filt._stop
    for k, scan in enumerate(scans):
        t_mht = scan.time if mht_time is None else max(mht_time, scan.time)
        filt.set_scan(scan.kind, scan.time)
        confirmed = mht.step(scan.z, time=t_mht, R=scan.R, bba=scan.bba if type_tracking else None)
        mht_time = t_mht
        rows = dict((fam, i) for i, fam in _confirmed_rows(mht))
        for trk in confirmed:
            st = trk.state
            i = rows[trk.id]
            s = mht._states
            leaf = mht._leaves[i]
            j = leaf.history[-1] if leaf.history else -1
            cur = NO_MEASUREMENT
            if j >= 0:
                tg = scans[k].reports[j].target_id
                cur = FALSE_ALARM if tg is None else int(tg)
            typ = _declared_type(trk.type_bba, rng) if type_tracking else NO_TYPE
            samples.setdefault(trk.id, []).append(
                {
                    "t": float(st[4]),
                    "x": float(st[0]),
                    "y": float(st[2]),
                    "vx": float(st[1]),
                    "vy": float(st[3]),
                    "k": k,
                    "kind": scan.kind,
                    "scan_time": float(scan.time),
                    "cur_id": cur,
                    "mu_stop": float(s["mu"][i, stop]) if stop is not None else 0.0,
                    "t_det": float(s["t_det"][i]),
                    "section": int(s["section"][i]),
                    "score": float(leaf.score),
                    "uid": leaf.uid,
                    "typ": typ,
                }
            )
            last[trk.id] = trk
    for trk in mht.all_tracks():
        last.setdefault(trk.id, trk)
    tracks: dict[int, EstimatedTrack] = {}
    for tid, smp in samples.items():
        trk = last[tid]
        smp.sort(key=lambda v: v["t"])
        ids = []
        for v in smp:
            i = v["k"] - trk.birth
            j = trk.measurements[i] if 0 <= i < len(trk.measurements) else -1
            if j >= 0:
                tg = scans[v["k"]].reports[j].target_id
                ids.append(FALSE_ALARM if tg is None else int(tg))
            else:
                ids.append(NO_MEASUREMENT)
            v["final_id"] = ids[-1]
        tracks[tid] = EstimatedTrack(
            [v["t"] for v in smp], [(v["x"], v["y"]) for v in smp], ids, [v["typ"] for v in smp]
        )
    return {"seed": seed, "samples": samples, "tracks": tracks, "truth": sc.truth}


def _job(args: tuple) -> dict:
    seed, pcr5, overrides = args
    cfg = PDTrackerConfig(**overrides)
    out = run_seed(seed, pcr5, cfg)
    from hocnet.tracking.evaluation import gospa

    g = gospa(out["truth"], out["tracks"], np.arange(0.0, 1200.0 + 1e-9, 10.0), c=200.0)
    out["gospa"] = float(np.mean(g["distance"]))
    return out


def _parse(items: list[str]) -> dict[str, Any]:
    import ast

    out = {}
    for it in items:
        k, _, v = it.partition("=")
        try:
            out[k] = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            out[k] = v
    return out


def analyse(runs: list[dict], top: int = 40) -> None:
    """Print per-target metrics and the worst samples with their context."""
    truth = runs[0]["truth"]
    met = monte_carlo_metrics(truth, [r["tracks"] for r in runs])
    rows = []
    for r in runs:
        asg = assign_tracks(r["tracks"])
        for tid, smp in r["samples"].items():
            tgt = asg.get(tid)
            if tgt is None:
                continue
            tr = truth[tgt]
            for v in smp:
                px = np.interp(v["t"], tr.times, tr.positions[:, 0])
                py = np.interp(v["t"], tr.times, tr.positions[:, 1])
                if v["t"] < tr.times[0] - 1e-9 or v["t"] > tr.times[-1] + 1e-9:
                    continue
                # nearest target at that time
                best, bd = None, math.inf
                for o, to in truth.items():
                    if to.times[0] <= v["t"] <= to.times[-1]:
                        ox = np.interp(v["t"], to.times, to.positions[:, 0])
                        oy = np.interp(v["t"], to.times, to.positions[:, 1])
                        d = math.hypot(v["x"] - ox, v["y"] - oy)
                        if d < bd:
                            best, bd = o, d
                rows.append(
                    {
                        **v,
                        "seed": r["seed"],
                        "track": tid,
                        "target": tgt,
                        "err": math.hypot(v["x"] - px, v["y"] - py),
                        "nearest": best,
                        "nearest_d": bd,
                        "coast": v["t"] - v["t_det"],
                    }
                )
    print(f"{len(rows)} samples in {len(runs)} runs")
    if "gospa" not in runs[0]:
        from hocnet.tracking.evaluation import gospa

        for r in runs:
            g = gospa(truth, r["tracks"], np.arange(0.0, 1200.0 + 1e-9, 10.0), c=200.0)
            r["gospa"] = float(np.mean(g["distance"]))
    if True:
        print(f"GOSPA mean {np.mean([r['gospa'] for r in runs]):.1f} m")
    print("target  ARMSE  armse_run  median  purity  length  n>100m  n>300m")
    summ = []
    for tid, m in met.items():
        summ.append((m.armse, m.track_purity, m.length_ratio))
        e = np.array([x["err"] for x in rows if x["target"] == tid])
        print(
            f"{tid:6d} {m.armse:7.1f} {m.armse_run:9.1f} {np.median(e):7.1f} "
            f"{m.track_purity:7.3f} {m.length_ratio:7.3f} {(e > 100).sum():7d} {(e > 300).sum():7d}"
        )
    a_, p_, l_ = (np.mean(v) for v in zip(*summ))
    print(f"mean    {a_:7.1f}                   {p_:7.3f} {l_:7.3f}")
    big = [x for x in rows if x["err"] > 100]
    print(f"\nsamples with error > 100 m: {len(big)}")

    def cls(x: dict) -> str:
        if x["nearest"] != x["target"] and x["nearest_d"] < 100:
            return "swap(on other target)"
        if x["coast"] > 25:
            return "coasting>25s"
        if x["mu_stop"] > 0.5:
            return "stop-model"
        if x["cur_id"] not in (x["target"], NO_MEASUREMENT):
            return "updated-by-other"
        return "other"

    from collections import Counter

    print(Counter(cls(x) for x in big))
    print(Counter((x["target"], cls(x)) for x in big).most_common(30))
    # per (seed, track) episodes
    eps: dict[tuple, list] = {}
    for x in big:
        eps.setdefault((x["seed"], x["track"], x["target"]), []).append(x)
    print("\nepisodes (seed, track, target): n, t range, max err, classes")
    for key, xs in sorted(eps.items(), key=lambda kv: -sum(v["err"] ** 2 for v in kv[1])):
        c = Counter(cls(x) for x in xs)
        print(
            key,
            len(xs),
            f"{xs[0]['t']:.0f}-{xs[-1]['t']:.0f}",
            f"{max(x['err'] for x in xs):.0f}",
            dict(c),
            "kinds",
            dict(Counter(x["kind"] for x in xs)),
        )
    print("\nworst samples:")
    for x in sorted(rows, key=lambda v: -v["err"])[:top]:
        print(
            f"s{x['seed']} trk{x['track']:4d} tgt{x['target']:2d} t={x['t']:7.1f} "
            f"{x['kind']:5s} err={x['err']:7.1f} near={x['nearest']}@{x['nearest_d']:.0f} "
            f"cur={x['cur_id']} fin={x['final_id']} mu0={x['mu_stop']:.2f} coast={x['coast']:.0f} "
            f"sec={x['section']}"
        )


def trace(seed: int, target: int, t0: float, t1: float, overrides: dict[str, Any]) -> None:
    """Scan-by-scan context of one target between ``t0`` and ``t1`` (``--trace``)."""
    torch.set_num_threads(1)
    cfg = PDTrackerConfig(**overrides)
    sc = pd_scenario(seed=seed)
    filt, mht, scans = _pd_tracker(sc, cfg, type_tracking=False)
    truth = sc.truth

    def pos(i: int, t: float) -> tuple[float, float]:
        tr = truth[i]
        return (
            float(np.interp(t, tr.times, tr.positions[:, 0])),
            float(np.interp(t, tr.times, tr.positions[:, 1])),
        )

    seen: dict[str, Any] = {}
    inner = filt.innovation

    def innovation(states: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        zp, S = inner(states)
        seen.update(zp=zp, S=S, st=states)
        return zp, S

    filt.innovation = innovation  # type: ignore[method-assign]
    mt = None
    for k, scan in enumerate(scans):
        t = scan.time if mt is None else max(mt, scan.time)
        filt.set_scan(scan.kind, scan.time)
        seen.clear()
        conf = mht.step(scan.z, time=t, R=scan.R, bba=None)
        mt = t
        if not t0 <= scan.time <= t1:
            continue
        tx, ty = pos(target, scan.time)
        rep = [j for j, r in enumerate(scan.reports) if r.target_id == target]
        zs = [np.round(scan.reports[j].z, 1).tolist() for j in rep]
        print(f"--- k={k} {scan.kind} t={scan.time:.0f} truth=({tx:.0f},{ty:.0f}) reports {zs}")
        if "st" in seen and scan.kind == "gmti":
            st, zp, S = seen["st"], seen["zp"], seen["S"]
            for j in rep:
                d = scan.z[j] - zp
                m = torch.einsum("ki,kij,kj->k", d, torch.linalg.inv(S + scan.R[j]), d)
                for i in torch.argsort(m)[:3].tolist():
                    av = st["p_avalid"][i].tolist() if "p_avalid" in st else None
                    print(
                        f"   report {j} row {i}: d2 {float(m[i]):.1f} "
                        f"zp {np.round(zp[i].tolist(), 1).tolist()} branches {av}"
                    )
        s = mht._states
        for trk in conf:
            x = trk.state
            if math.hypot(x[0] - tx, x[2] - ty) > 600:
                continue
            print(f"  track {trk.id} ({x[0]:.0f},{x[2]:.0f}) v=({x[1]:.1f},{x[3]:.1f})", end="")
            for i, lf in enumerate(mht._leaves):
                if lf.family == trk.id:
                    j = lf.history[-1] if lf.history else -1
                    ja = s["ja_valid"][i].tolist() if "ja_valid" in s else None
                    mu = np.round(s["mu"][i].tolist(), 2).tolist()
                    sec = int(s["section"][i])
                    print(f" [score {lf.score:.1f} mu {mu} sec {sec} ja {ja} h {j}]", end="")
            print()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="2400-2409")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--pcr5", action="store_true")
    ap.add_argument("--out", default=None)
    ap.add_argument("--load", default=None)
    ap.add_argument("--set", nargs="*", default=[], help="PDTrackerConfig overrides key=value")
    ap.add_argument("--trace", nargs=4, default=None, metavar=("SEED", "TARGET", "T0", "T1"))
    a = ap.parse_args()
    if a.trace:
        sd, tg, ta, tb = a.trace
        trace(int(sd), int(tg), float(ta), float(tb), _parse(a.set))
        return
    if a.load:
        runs = pickle.loads(pathlib.Path(a.load).read_bytes())
    else:
        lo, _, hi = a.seeds.partition("-")
        seeds = list(range(int(lo), int(hi or lo) + 1))
        tasks = [(s, a.pcr5, _parse(a.set)) for s in seeds]
        if a.jobs > 1:
            import multiprocessing

            with multiprocessing.get_context("spawn").Pool(a.jobs) as pool:
                runs = pool.map(_job, tasks, chunksize=1)
        else:
            runs = [_job(t) for t in tasks]
        if a.out:
            pathlib.Path(a.out).write_bytes(pickle.dumps(runs))
    analyse(runs)


if __name__ == "__main__":
    sys.exit(main())

"""Speed benchmark of the batched IMM of [PD] section 24.4.2 against filterpy's ``IMMEstimator``.

For 10, 100 and 1000 tracks with 3 modes (stop model M0, constant velocity with low and with high
process noise), one timed item is ``--scans`` full IMM cycles (mixing, mode-matched predict +
update, mode probabilities, combination) over all tracks on seeded data:

* hocnet -- :func:`hocnet.tracking.imm.imm_step` called once per scan on all tracks at once
  (plain IMM, ``pd=None``), with 1 and with 2 torch threads;
* filterpy -- one ``filterpy.kalman.IMMEstimator`` per track, ``predict(); update(z)`` looped over
  the same tracks and the same measurements.

Before timing, both run the same scans once and every scan's combined state and covariance, mode
probabilities and mode-matched states are compared (``rtol = atol = 1e-8``); the script fails if
they differ. False-alarm density is not an axis: the IMM takes one measurement per track (the
association that would see false alarms is not part of it), so its cost does not depend on it.

Run::

    .venv/bin/python benchmarks/tracking.py            # full table (about 2 minutes)
    .venv/bin/python benchmarks/tracking.py --quick    # smoke test: 10 and 100 tracks (seconds)

With ``--mht`` it times the track-oriented MHT instead (:mod:`hocnet.tracking.mht`): scans per
second versus number of targets (10, 100, 1000) and false-alarm density (0, 1e-9, 1e-8 per m^2),
written to ``benchmarks/results/tracking_mht.md``.

Options: ``--tracks 10,100``, ``--scans 10``, ``--seed 0``, ``--out STEM``. The table is printed
and written to ``benchmarks/results/tracking.md`` (``tracking_quick.md`` with ``--quick``).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# Idle OpenMP threads sleep instead of spinning (see benchmarks/dpa.py). Set before torch.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import torch
from _common import load_average, machine_line

from hocnet.tracking.imm import imm_step
from hocnet.tracking.kalman import constant_velocity, stop_model

DT = 10.0  # s between scans
SIGMA_LOW, SIGMA_HIGH = 0.05, 0.8  # process noise of the two CV modes (m/s^2)
H_POS = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])  # state (x, vx, y, vy), measure (x, y)
R = np.diag([25.0, 16.0])  # m^2
TRANS = np.array([[0.80, 0.15, 0.05], [0.10, 0.85, 0.05], [0.02, 0.18, 0.80]])  # P(i -> j)
TOL = 1e-8

FULL_TRACKS = (10, 100, 1000)
QUICK_TRACKS = (10, 100)
THREADS = (1, 2)
MIN_RUNS, MIN_TIME_S, MAX_RUNS = 3, 1.0, 30
QUICK_MIN_RUNS, QUICK_MIN_TIME_S = 2, 0.1
TARGET_TRACKS, TARGET_SPEEDUP = 1000, 50.0

RESULTS = Path(__file__).resolve().parent / "results"


@dataclass
class Row:
    """One number of tracks (rates in scans per second)."""

    tracks: int
    scans: int
    filterpy: float
    hocnet: dict[int, float]  # torch threads -> scans/s
    max_diff: float
    load: float


def models() -> tuple[torch.Tensor, torch.Tensor]:
    """``(F, Q)`` of the three modes, each ``(3, 4, 4)``: M0 stop, CV low noise, CV high noise."""
    F0, Q0 = stop_model(DT)
    F1, Q1 = constant_velocity(DT, SIGMA_LOW)
    F2, Q2 = constant_velocity(DT, SIGMA_HIGH)
    return torch.stack([F0, F1, F2]), torch.stack([Q0, Q1, Q2])


def make_data(n_tracks: int, n_scans: int, seed: int) -> dict[str, np.ndarray]:
    """Seeded initial states and ``(S, N, 2)`` measurements of targets that move or stop."""
    rng = np.random.default_rng(seed)
    x0 = rng.normal(size=(n_tracks, 4)) * np.array([1000.0, 5.0, 1000.0, 5.0])
    P0 = np.stack([np.diag(rng.uniform(10, 200, size=4)) for _ in range(n_tracks)])
    mu0 = rng.dirichlet(np.ones(3), size=n_tracks)
    moving = rng.random(n_tracks) < 0.7  # the others stand still (the stop model's case)
    truth = x0.copy()
    truth[~moving, 1::2] = 0.0
    f_cv = constant_velocity(DT, 0.0)[0].numpy()
    z = np.empty((n_scans, n_tracks, 2))
    for s in range(n_scans):
        truth = truth @ f_cv.T
        z[s] = truth[:, [0, 2]] + rng.normal(size=(n_tracks, 2)) * np.sqrt(np.diag(R))
    return {"x0": x0, "P0": P0, "mu0": mu0, "z": z}


def filterpy_imms(data: dict[str, np.ndarray], F: np.ndarray, Q: np.ndarray) -> list[Any]:
    """One fresh ``IMMEstimator`` per track, in the initial state of ``data``."""
    from filterpy.kalman import IMMEstimator, KalmanFilter

    imms = []
    for t in range(len(data["x0"])):
        filters = []
        for i in range(3):
            kf = KalmanFilter(dim_x=4, dim_z=2)
            kf.F, kf.Q, kf.H, kf.R = F[i], Q[i], H_POS, R
            kf.x, kf.P = data["x0"][t][:, None].copy(), data["P0"][t].copy()
            filters.append(kf)
        imms.append(IMMEstimator(filters, data["mu0"][t].copy(), TRANS))
    return imms


def run_filterpy(imms: list[Any], z: np.ndarray, check: Callable | None = None) -> None:
    """The timed filterpy item: every scan, ``predict(); update(z)`` on every track."""
    for s in range(len(z)):
        zs = z[s]
        for t, imm in enumerate(imms):
            imm.predict()
            imm.update(zs[t][:, None])
        if check is not None:
            check(s, imms)


def hocnet_state(data: dict[str, np.ndarray]) -> tuple[torch.Tensor, ...]:
    """``(mu, x, P)`` at the start: ``(N, 3)``, ``(N, 3, 4)``, ``(N, 3, 4, 4)``."""
    mu = torch.tensor(data["mu0"])
    x = torch.tensor(data["x0"])[:, None].repeat(1, 3, 1)
    P = torch.tensor(data["P0"])[:, None].repeat(1, 3, 1, 1)
    return mu, x, P


def run_hocnet(
    state: tuple[torch.Tensor, ...],
    z: torch.Tensor,
    consts: tuple[torch.Tensor, ...],
    check: Callable | None = None,
) -> None:
    """The timed hocnet item: one batched :func:`imm_step` per scan on all tracks."""
    mu, x, P = state
    trans, F, Q, H, Rt = consts
    for s in range(z.shape[0]):
        out = imm_step(mu, x, P, trans, F, Q, z[s], H, Rt)
        mu, x, P = out.mu, out.x, out.P
        if check is not None:
            check(s, out)


def best_time(
    setup: Callable[[], Any], work: Callable[[Any], None], min_runs: int, min_time: float
) -> float:
    """Least wall time of ``work(setup())`` over repeated runs (``setup`` is not timed)."""
    best, runs, spent = math.inf, 0, 0.0
    while True:
        arg = setup()
        t0 = time.perf_counter()
        work(arg)
        dt = time.perf_counter() - t0
        best, runs, spent = min(best, dt), runs + 1, spent + dt
        if runs >= MAX_RUNS or (runs >= min_runs and spent >= min_time):
            return best


def agreement(data: dict[str, np.ndarray], F: torch.Tensor, Q: torch.Tensor, consts) -> float:
    """Run both on all scans once; the largest scaled difference ``|a - b| / (atol + rtol |b|)``.

    Compared every scan: mode probabilities, combined state and covariance, mode-matched states
    and covariances. A value <= 1 means agreement to ``rtol = atol = 1e-8``.
    """
    outs: list[Any] = []
    run_hocnet(
        hocnet_state(data), torch.tensor(data["z"]), consts, check=lambda s, o: outs.append(o)
    )
    worst = 0.0

    def scaled(a: torch.Tensor, b: np.ndarray) -> float:
        return float(np.max(np.abs(a.numpy() - b) / (TOL + TOL * np.abs(b))))

    def check(s: int, imms: list[Any]) -> None:
        nonlocal worst
        o = outs[s]
        pairs = [
            (o.mu, np.stack([m.mu for m in imms])),
            (o.x_comb, np.stack([m.x[:, 0] for m in imms])),
            (o.P_comb, np.stack([m.P for m in imms])),
            (o.x, np.stack([[f.x[:, 0] for f in m.filters] for m in imms])),
            (o.P, np.stack([[f.P for f in m.filters] for m in imms])),
        ]
        worst = max(worst, *(scaled(a, b) for a, b in pairs))

    run_filterpy(filterpy_imms(data, F.numpy(), Q.numpy()), data["z"], check=check)
    return worst


def run_config(n_tracks: int, n_scans: int, seed: int, quick: bool) -> Row:
    """Check agreement, then time filterpy and hocnet (1 and 2 threads) on the same data."""
    load = load_average()
    min_runs = QUICK_MIN_RUNS if quick else MIN_RUNS
    min_time = QUICK_MIN_TIME_S if quick else MIN_TIME_S
    data = make_data(n_tracks, n_scans, seed)
    F, Q = models()
    consts = (torch.tensor(TRANS), F, Q, torch.tensor(H_POS), torch.tensor(R))
    torch.set_num_threads(1)
    diff = agreement(data, F, Q, consts)
    Fn, Qn = F.numpy(), Q.numpy()
    fp = best_time(
        lambda: filterpy_imms(data, Fn, Qn),
        lambda imms: run_filterpy(imms, data["z"]),
        min_runs,
        min_time,
    )
    z = torch.tensor(data["z"])
    rates = {}
    for threads in THREADS:
        torch.set_num_threads(threads)
        run_hocnet(hocnet_state(data), z[:1], consts)  # warm-up
        t = best_time(
            lambda: hocnet_state(data),
            lambda state: run_hocnet(state, z, consts),
            min_runs,
            min_time,
        )
        rates[threads] = n_scans / t
    return Row(n_tracks, n_scans, n_scans / fp, rates, diff, load)


def markdown(rows: list[Row], header: list[str]) -> str:
    """The table as Markdown, preceded by ``header``, followed by the verdict."""
    cols = ["tracks", "scans timed", "load at start", "filterpy scans/s"]
    for th in THREADS:
        cols += [f"hocnet {th} thread{'s' if th > 1 else ''} scans/s", f"speedup ({th})"]
    cols += ["max scaled diff", "agree 1e-8"]
    lines = [*header, "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        cells = [str(r.tracks), str(r.scans), f"{r.load:.2f}", f"{r.filterpy:.3g}"]
        for th in THREADS:
            cells += [f"{r.hocnet[th]:.3g}", f"{r.hocnet[th] / r.filterpy:.1f}x"]
        cells += [f"{r.max_diff:.2g}", "yes" if r.max_diff <= 1.0 else "NO"]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    hit = [r for r in rows if r.tracks == TARGET_TRACKS]
    if not hit:
        lines.append(f"Goal (>= {TARGET_SPEEDUP:g}x filterpy at {TARGET_TRACKS} tracks): not run.")
    else:
        r = hit[0]
        parts = []
        for th in THREADS:
            s = r.hocnet[th] / r.filterpy
            parts.append(f"{th} thread{'s' if th > 1 else ''}: {s:.1f}x " + _verdict(s))
        lines.append(
            f"Goal (issue 12: >= {TARGET_SPEEDUP:g}x filterpy at {TARGET_TRACKS} tracks): "
            + "; ".join(parts)
            + "."
        )
    return "\n".join(lines) + "\n"


def _verdict(speedup: float) -> str:
    return "PASS" if speedup >= TARGET_SPEEDUP else "FAIL"


def _ints(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in text.split(",") if p.strip())


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="10 and 100 tracks, 5 scans (smoke test)")
    p.add_argument("--tracks", type=_ints, help="comma-separated numbers of tracks")
    p.add_argument("--scans", type=int, help="scans per timed item (default 10, quick 5)")
    p.add_argument("--seed", type=int, default=0, help="data seed (default 0)")
    p.add_argument("--out", type=Path, help="output stem (default benchmarks/results/tracking)")
    p.add_argument(
        "--mht",
        action="store_true",
        help="benchmark the track-oriented MHT instead (scans/s vs targets and clutter density)",
    )
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print the table, write ``.md``; 1 if hocnet and filterpy disagree."""
    args = parse_args(argv)
    if args.mht:
        return mht_main(args)
    tracks = args.tracks or (QUICK_TRACKS if args.quick else FULL_TRACKS)
    n_scans = args.scans or (5 if args.quick else 10)
    out = args.out or RESULTS / ("tracking_quick" if args.quick else "tracking")
    started = time.perf_counter()
    load_before = load_average()
    rows = []
    for n in tracks:
        row = run_config(n, n_scans, args.seed, args.quick)
        rows.append(row)
        print(
            f"{n} tracks: filterpy {row.filterpy:.3g} scans/s, hocnet "
            + ", ".join(f"{th} thr {row.hocnet[th]:.3g}" for th in THREADS)
            + f" scans/s, max scaled diff {row.max_diff:.2g}",
            file=sys.stderr,
            flush=True,
        )
    total = time.perf_counter() - started
    threads_note = "/".join(map(str, THREADS))
    min_time = QUICK_MIN_TIME_S if args.quick else MIN_TIME_S
    min_runs = QUICK_MIN_RUNS if args.quick else MIN_RUNS
    header = [
        "# IMM speed: hocnet's batched IMM vs filterpy's IMMEstimator looped over tracks",
        "",
        machine_line(1, load_before, load_average(), total).replace(
            "torch threads = 1", f"torch threads = {threads_note} (per column)"
        ),
        f"- Timed item: {n_scans} scans of a full IMM cycle (mixing 24.33-24.35, mode-matched "
        "Kalman predict + update, mode probabilities 24.36, combination 24.37) on every track; "
        "3 modes: stop model M0, CV with process noise "
        f"{SIGMA_LOW:g} and {SIGMA_HIGH:g} m/s^2; dt = {DT:g} s; position measurements "
        f"(R = diag(25, 16) m^2); seeded data (seed {args.seed}), 70 % of targets moving. "
        "scans/s = scans / wall time, the least of >= "
        f"{min_runs} runs (more, up to {MAX_RUNS}, while under {min_time:g} s in total); "
        "building the filters / initial tensors is not timed.",
        "- hocnet: `hocnet.tracking.imm.imm_step` once per scan on all tracks (float64, CPU, "
        "plain IMM `pd=None`), with 1 and 2 torch threads. filterpy: one `IMMEstimator` of 3 "
        "`KalmanFilter`s per track, `predict(); update(z)` looped over the tracks, same data "
        "(numpy, single-threaded Python loop; timed once per row).",
        "- Agreement: before timing, both filtered the same scans and every scan's mode "
        "probabilities, combined state and covariance, mode-matched states and covariances were "
        "compared; max scaled diff = max |hocnet - filterpy| / (1e-8 + 1e-8 |filterpy|), so "
        "<= 1 means equal to rtol = atol = 1e-8.",
        "- False-alarm density is not an axis: the IMM takes one (associated) measurement per "
        "track and does no association, so its cost does not depend on the clutter.",
    ]
    text = markdown(rows, header)
    print(text)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text(text)
    print(f"wrote {out.with_suffix('.md')}", file=sys.stderr)
    if any(r.max_diff > 1.0 for r in rows):
        print("hocnet and filterpy disagree beyond 1e-8", file=sys.stderr)
        return 1
    return 0


# --------------------------------------------------------------------------------------------
# the track-oriented MHT (hocnet.tracking.mht): scans per second vs targets and clutter density
# --------------------------------------------------------------------------------------------

MHT_SIDE = 1e5  # m, side of the square surveillance region
MHT_DENSITIES = (0.0, 1e-9, 1e-8)  # false alarms per m^2 per scan: 0, 10, 100 per scan
MHT_QUICK_DENSITIES = (0.0, 1e-9)
MHT_PD = 0.9
MHT_WARM, MHT_TIMED, MHT_QUICK_TIMED = 5, 5, 3


def mht_data(n_targets: int, n_scans: int, density: float, seed: int) -> list[torch.Tensor]:
    """Seeded scans: CV targets (10 m/s per axis, std) seen with PD 0.9, plus uniform clutter."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, MHT_SIDE, (n_targets, 2))
    v = rng.normal(0, 10.0, (n_targets, 2))
    std = np.sqrt(np.diag(R))
    scans = []
    for k in range(n_scans):
        seen = rng.random(n_targets) < MHT_PD
        z = x[seen] + v[seen] * DT * k + rng.normal(size=(int(seen.sum()), 2)) * std
        clutter = rng.uniform(0, MHT_SIDE, (rng.poisson(density * MHT_SIDE**2), 2))
        scans.append(torch.from_numpy(np.concatenate([z, clutter])))
    return scans


@dataclass
class MHTRow:
    """One (targets, density) configuration of the MHT benchmark."""

    targets: int
    density: float
    plots: float  # mean measurements per timed scan
    rate: float  # timed scans per second
    leaves: int  # leaf tracks held after the last scan
    confirmed: int  # confirmed tracks after the last scan
    load: float


def run_mht_config(n_targets: int, density: float, timed: int, seed: int) -> MHTRow:
    """Warm up (track initiation) on ``MHT_WARM`` scans, then time ``timed`` scans."""
    from hocnet.tracking.mht import MHT, CVKalmanFilter

    load = load_average()
    torch.set_num_threads(1)
    scans = mht_data(n_targets, MHT_WARM + timed, density, seed)
    mht = MHT(
        CVKalmanFilter(sigma_a=0.5, velocity_std=15.0),
        R=torch.tensor(R),
        pd=MHT_PD,
        lambda_fa=max(density, 1e-10),
        lambda_nt=1e-10,
    )
    for k in range(MHT_WARM):
        mht.step(scans[k], time=DT * k)
    t0 = time.perf_counter()
    for k in range(MHT_WARM, MHT_WARM + timed):
        mht.step(scans[k], time=DT * k)
    spent = time.perf_counter() - t0
    plots = float(np.mean([len(z) for z in scans[MHT_WARM:]]))
    return MHTRow(n_targets, density, plots, timed / spent, mht.n_leaves, len(mht.tracks()), load)


def mht_main(args: argparse.Namespace) -> int:
    """The MHT table: printed and written to ``benchmarks/results/tracking_mht.md``."""
    tracks = args.tracks or (QUICK_TRACKS if args.quick else FULL_TRACKS)
    densities = MHT_QUICK_DENSITIES if args.quick else MHT_DENSITIES
    timed = args.scans or (MHT_QUICK_TIMED if args.quick else MHT_TIMED)
    out = args.out or RESULTS / ("tracking_mht_quick" if args.quick else "tracking_mht")
    started = time.perf_counter()
    load_before = load_average()
    rows = []
    for n in tracks:
        for density in densities:
            row = run_mht_config(n, density, timed, args.seed)
            rows.append(row)
            print(
                f"{n} targets, {density:g} /m^2: {row.rate:.3g} scans/s, {row.leaves} leaves, "
                f"{row.confirmed} confirmed",
                file=sys.stderr,
                flush=True,
            )
    total = time.perf_counter() - started
    cols = [
        "targets",
        "false alarms / m^2",
        "false alarms / scan",
        "plots / scan",
        "scans/s",
        "leaf tracks",
        "confirmed",
        "load at start",
    ]
    lines = [
        "# MHT speed: hocnet's track-oriented SB-MHT, scans per second",
        "",
        machine_line(1, load_before, load_average(), total).replace(
            "times are the least disturbed of several runs", "times vary from run to run"
        ),
        f"- Scenario: CV targets uniform in a {MHT_SIDE / 1e3:g} km square, velocity std 10 "
        f"m/s per axis, dt = {DT:g} s, PD {MHT_PD:g}, position noise R = diag(25, 16) m^2, "
        "uniform clutter of the given density; seeded (seed "
        f"{args.seed}).",
        "- `hocnet.tracking.mht.MHT` with `CVKalmanFilter(sigma_a=0.5, velocity_std=15)`, "
        "defaults otherwise (10 hypotheses per cluster, ratio 1e-6, 3-scan pruning, merging "
        f"over 3 scans, SPRT alpha 1e-3, beta 0.1). {MHT_WARM} untimed warm-up scans "
        f"(initiation), then {timed} timed scans, one run (the tracker's state evolves, so "
        "the timed scans are not repeated). No reference implementation is timed: filterpy "
        "and Stone Soup have no track-oriented MHT with track scores.",
        "",
        "| " + " | ".join(cols) + " |",
        "|" + "---|" * len(cols),
    ]
    for r in rows:
        cells = [
            str(r.targets),
            f"{r.density:g}",
            f"{r.density * MHT_SIDE**2:g}",
            f"{r.plots:.0f}",
            f"{r.rate:.3g}",
            str(r.leaves),
            str(r.confirmed),
            f"{r.load:.2f}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    print(text)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text(text)
    print(f"wrote {out.with_suffix('.md')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Speed benchmark of the modified HOC of [LA98]: loop reference, connectionist path, fast path.

For every cube size x clutter density x order, one timed item is the order-``k`` modified HOC
(``v = 4``, ``delta = pi/4``) run forward *and* backward on a seeded uniform-clutter cube. It is
timed with the loop reference (:func:`hocnet.hoc.reference.hoc_reference`, tiny cubes only), the
connectionist network (``method="conv"``) and the sparse fast path (``method="sparse"``), next to
one 9x9 max-pool pass over the same cube -- the floor any windowed detector pays. All outputs are
checked bit for bit (conv == sparse, and == reference where it runs). The peak memory of the fast
path is measured in a fresh ``spawn`` child process per configuration.

Run::

    .venv/bin/python benchmarks/hoc.py            # full table (several minutes)
    .venv/bin/python benchmarks/hoc.py --quick    # smoke test: small cubes, 2 % only (< 20 s)

Options: ``--sizes 16x320x520,10x60x60`` (``TxHxW``), ``--densities 0.02``, ``--orders 1,4``,
``--threads 2``, ``--seed 0``, ``--out STEM``. The table is printed and written to
``benchmarks/results/hoc.md`` with the raw numbers in ``hoc.csv`` (``hoc_quick.*`` with
``--quick``).

Streaming rows (``--stream``): :class:`hocnet.hoc.StreamingDetector` (``window=10, stride=1``) fed
scan by scan from a ``640 x 512`` sensor (uniform clutter 1 % and 2 % plus a few straight
targets, orders 2 and 3): median and 99th-percentile latency of a push (each push returns a
window result), split into the incremental HOC part and the track-identification call, next to
batch ``detect`` of the same 10-scan windows and one 9x9 max-pool pass over one scan (the floor),
all in the same run. Every window's streaming result is checked against batch ``detect``. Written
to ``benchmarks/results/hoc_stream.md`` / ``.csv`` (``hoc_stream_quick.*`` with ``--quick``: 256 x
320 sensor, 12 pushes)::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/hoc.py --stream --threads 1
    .venv/bin/python benchmarks/hoc.py --stream --quick
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import platform
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from datetime import UTC, datetime
from pathlib import Path
from typing import TypeVar

# Idle OpenMP threads sleep instead of spinning: on a shared 2-core machine spinning threads made
# small torch ops 10-100x slower (see benchmarks/dpa.py). Set before torch is imported.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import torch
import torch.nn.functional as F
from _common import memory_note as common_memory_note
from _common import peak_memory_mb, percentile

import hocnet.hoc.stream as hoc_stream
from hocnet.hoc.functional import modified_hoc
from hocnet.hoc.identify import HOCResult, detect
from hocnet.hoc.reference import hoc_reference

V = 4
DELTA = math.pi / 4
POOL = 9  # max-pool window of the floor (odd, padding POOL // 2 keeps the size)
REFERENCE_MAX_PIXELS = 6 * 16 * 16  # the Python loop reference runs only on cubes this small
MIN_RUNS = 3  # a time is the min over at least this many runs ...
MIN_TIME_S = 1.0  # ... and over as many more (up to MAX_RUNS) as fit in this much time ...
MAX_RUNS = 50
QUICK_MIN_TIME_S = 0.2  # MIN_TIME_S of --quick
SINGLE_S = 5.0  # ... except that an item whose first run takes longer than this runs once

FULL_SIZES = ((6, 16, 16), (10, 60, 60), (10, 320, 520), (16, 320, 520))
QUICK_SIZES = ((6, 16, 16), (10, 60, 60))
DENSITIES = (0.008, 0.02, 0.05)
QUICK_DENSITIES = (0.02,)
ORDERS = (1, 2, 4)

TARGET_SIZE = (16, 320, 520)
TARGET_DENSITY = 0.02
TARGET_ORDER = 4
TARGET_CONV_SPEEDUP = 20.0  # sparse must be at least this much faster than conv
TARGET_FLOOR_RATIO = 3.0  # sparse must be within this factor of the max-pool floor
TARGET_MEMORY_MB = 1024.0  # peak memory of the fast path

_R = TypeVar("_R")

RESULTS = Path(__file__).resolve().parent / "results"


@dataclass
class Row:
    """One configuration of the benchmark (times in seconds, memory in MB)."""

    size: str
    density: float
    order: int
    n_points: int
    reference_s: float | None
    conv_s: float
    conv_runs: int
    sparse_s: float
    maxpool_s: float
    conv_over_sparse: float
    sparse_over_maxpool: float
    sparse_mpix_per_s: float
    sparse_peak_mb: float
    sparse_peak_abs_mb: float
    survivors_fwd: int
    survivors_bwd: int
    identical: bool


# ----------------------------------------------------------------------------- helpers


def make_cube(size: tuple[int, int, int], density: float, seed: int) -> torch.Tensor:
    """Seeded ``(1, T, H, W)`` bool cube with each pixel on with probability ``density``."""
    gen = torch.Generator().manual_seed(seed)
    return torch.rand((1, *size), generator=gen) < density


def hoc_both(cube: torch.Tensor, order: int, method: str) -> tuple[torch.Tensor, torch.Tensor]:
    """The timed item: order-``k`` modified HOC forward and backward."""
    fwd = modified_hoc(cube, order, V, DELTA, "forward", method=method)
    bwd = modified_hoc(cube, order, V, DELTA, "backward", method=method)
    return fwd, bwd


def reference_both(cube: torch.Tensor, order: int) -> tuple[np.ndarray, np.ndarray]:
    """The timed item with the loop reference (unbatched numpy in, numpy out)."""
    arr = cube[0].numpy()
    return (
        hoc_reference(arr, order, V, DELTA, "forward"),
        hoc_reference(arr, order, V, DELTA, "backward"),
    )


def max_pool_floor(cube: torch.Tensor) -> torch.Tensor:
    """One 9x9 max-pool pass over every scan of the cube (the windowed-detector floor)."""
    b, n_t, h, w = cube.shape
    x = cube.float().reshape(b * n_t, 1, h, w)
    return F.max_pool2d(x, POOL, stride=1, padding=POOL // 2)


def timed(
    fn: Callable[[], _R],
    min_runs: int = MIN_RUNS,
    min_time: float = MIN_TIME_S,
    single: float = SINGLE_S,
) -> tuple[float, int, _R]:
    """Best wall time of ``fn`` over repeated runs.

    Runs ``fn`` at least ``min_runs`` times and keeps going (at most ``MAX_RUNS``) until
    ``min_time`` seconds were spent, taking the minimum -- the least disturbed run on a shared
    machine. An item whose first run exceeds ``single`` seconds is run once.

    Returns:
        ``(best seconds, number of runs, result of the last run)``.
    """
    best = math.inf
    runs = 0
    spent = 0.0
    while True:
        t0 = time.perf_counter()
        result = fn()
        dt = time.perf_counter() - t0
        best, runs, spent = min(best, dt), runs + 1, spent + dt
        if (runs == 1 and dt > single) or runs >= MAX_RUNS:
            return best, runs, result
        if runs >= min_runs and spent >= min_time:
            return best, runs, result


def _sparse_work(size: tuple[int, int, int], density: float, order: int, seed: int) -> None:
    """One fast-path item, building its own input cube (runs in the measuring child)."""
    hoc_both(make_cube(size, density, seed), order, "sparse")


def _warm_up() -> None:
    """Torch's one-time runtime set-up (thread pool, allocator arenas), not counted."""
    hoc_both(make_cube((6, 16, 16), 0.05, 0), 1, "sparse")


def sparse_peak_memory(
    size: tuple[int, int, int], density: float, order: int, seed: int, threads: int
) -> tuple[float, float]:
    """``(increment MB, absolute peak MB)`` of the fast path, in a fresh child process.

    The child is forked from a ``forkserver`` that has imported ``torch`` and ``hocnet`` and
    never run a computation; the input cube, the outputs and every temporary count, nothing of
    the parent benchmark process does (see ``benchmarks/_common.py``).
    """
    return peak_memory_mb(
        _sparse_work,
        (size, density, order, seed),
        _warm_up,
        threads,
        preload=("torch", "hocnet.hoc.functional"),
    )


# ----------------------------------------------------------------------------- benchmark


def run_config(
    size: tuple[int, int, int],
    density: float,
    order: int,
    seed: int,
    threads: int,
    quick: bool = False,
) -> Row:
    """Time and check one configuration (``quick``: the slow paths run once)."""
    slow: dict[str, float] = {"min_runs": 1, "min_time": 0.0} if quick else {}
    fast: dict[str, float] = {"min_time": QUICK_MIN_TIME_S} if quick else {}
    cube = make_cube(size, density, seed)
    pixels = cube.numel()

    sparse_s, _, (sf, sb) = timed(lambda: hoc_both(cube, order, "sparse"), **fast)
    conv_s, conv_runs, (cf, cb) = timed(lambda: hoc_both(cube, order, "conv"), **slow)
    maxpool_s, _, _ = timed(lambda: max_pool_floor(cube), **fast)
    identical = torch.equal(sf, cf) and torch.equal(sb, cb)

    reference_s: float | None = None
    if pixels <= REFERENCE_MAX_PIXELS:
        reference_s, _, (rf, rb) = timed(lambda: reference_both(cube, order), **slow)
        identical = (
            identical and np.array_equal(rf, sf[0].numpy()) and np.array_equal(rb, sb[0].numpy())
        )
    if not identical:
        raise AssertionError(f"outputs differ at size {size}, density {density}, order {order}")

    peak_mb, peak_abs_mb = sparse_peak_memory(size, density, order, seed, threads)
    return Row(
        size="x".join(map(str, size)),
        density=density,
        order=order,
        n_points=int(cube.sum()),
        reference_s=reference_s,
        conv_s=conv_s,
        conv_runs=conv_runs,
        sparse_s=sparse_s,
        maxpool_s=maxpool_s,
        conv_over_sparse=conv_s / sparse_s,
        sparse_over_maxpool=sparse_s / maxpool_s,
        sparse_mpix_per_s=pixels / sparse_s / 1e6,
        sparse_peak_mb=peak_mb,
        sparse_peak_abs_mb=peak_abs_mb,
        survivors_fwd=int(sf.sum()),
        survivors_bwd=int(sb.sum()),
        identical=identical,
    )


def warm_up() -> None:
    """One small call of each path so that one-time setup is not timed in the first row."""
    cube = make_cube((6, 16, 16), 0.05, 0)
    for method in ("sparse", "conv"):
        hoc_both(cube, 2, method)
    max_pool_floor(cube)


# ----------------------------------------------------------------------------- reporting


def _fmt_s(x: float | None) -> str:
    if x is None:
        return "—"
    return f"{x:.3g}" if x >= 1e-3 else f"{x:.2e}"


def markdown(rows: list[Row], header: list[str]) -> str:
    """The table as Markdown, preceded by ``header`` lines."""
    cols = (
        "size (TxHxW)",
        "density",
        "order",
        "points",
        "reference s",
        "conv s",
        "sparse s",
        "maxpool s",
        "conv/sparse",
        "sparse/maxpool",
        "sparse Mpix-scans/s",
        "sparse peak MB",
        "survivors f/b",
    )
    lines = [*header, "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        conv = _fmt_s(r.conv_s) + ("" if r.conv_runs > 1 else "¹")
        cells = (
            r.size,
            f"{r.density:g}",
            str(r.order),
            str(r.n_points),
            _fmt_s(r.reference_s),
            conv,
            _fmt_s(r.sparse_s),
            _fmt_s(r.maxpool_s),
            f"{r.conv_over_sparse:.1f}x",
            f"{r.sparse_over_maxpool:.2f}",
            f"{r.sparse_mpix_per_s:.1f}",
            f"{r.sparse_peak_mb:.1f}",
            f"{r.survivors_fwd}/{r.survivors_bwd}",
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def headline(rows: list[Row]) -> list[str]:
    """Headline lines for the target configuration, with PASS/FAIL, if it was run."""
    size = "x".join(map(str, TARGET_SIZE))
    hit = [
        r
        for r in rows
        if r.size == size and r.density == TARGET_DENSITY and r.order == TARGET_ORDER
    ]
    if not hit:
        return [
            f"Target configuration ({size}, {TARGET_DENSITY:.0%}, order {TARGET_ORDER}) not run."
        ]
    r = hit[0]
    speed_ok = r.conv_over_sparse >= TARGET_CONV_SPEEDUP
    floor_ok = r.sparse_over_maxpool <= TARGET_FLOOR_RATIO
    mem_ok = r.sparse_peak_mb < TARGET_MEMORY_MB and r.sparse_peak_abs_mb < TARGET_MEMORY_MB
    verdict = lambda ok: "PASS" if ok else "FAIL"  # noqa: E731
    what = f"{size}, {TARGET_DENSITY:.0%} clutter, order {TARGET_ORDER} forward + backward"
    return [
        f"Headline ({what}): "
        f"fast path = {r.sparse_s * 1e3:.0f} ms, conv = {r.conv_s:.1f} s "
        f"({r.conv_over_sparse:.0f}x), max-pool floor = {r.maxpool_s * 1e3:.0f} ms "
        f"(sparse/floor = {r.sparse_over_maxpool:.2f}), peak memory = {r.sparse_peak_mb:.0f} MB "
        f"(process total {r.sparse_peak_abs_mb:.0f} MB)",
        f"- fast path >= {TARGET_CONV_SPEEDUP:.0f}x faster than conv: "
        f"{verdict(speed_ok)} ({r.conv_over_sparse:.1f}x)",
        f"- fast path within {TARGET_FLOOR_RATIO:.0f}x of the max-pool floor: "
        f"{verdict(floor_ok)} ({r.sparse_over_maxpool:.2f}x)",
        f"- peak memory under 1 GB: {verdict(mem_ok)} ({r.sparse_peak_mb:.0f} MB above baseline, "
        f"{r.sparse_peak_abs_mb:.0f} MB process total)",
    ]


def write_csv(rows: list[Row], path: Path) -> None:
    """Raw numbers, one row per configuration."""
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=[f.name for f in fields(Row)])
        writer.writeheader()
        for r in rows:
            writer.writerow(asdict(r))


# ----------------------------------------------------------------------------- streaming rows

STREAM_SENSOR = (512, 640)  # (H, W): a 640 x 512 sensor
QUICK_STREAM_SENSOR = (256, 320)
STREAM_DENSITIES = (0.01, 0.02)
STREAM_ORDERS = (2, 3)
STREAM_WINDOW = 10
STREAM_STRIDE = 1
STREAM_PUSHES = 100  # measured pushes per configuration (each returns a window)
QUICK_STREAM_PUSHES = 12
STREAM_TARGETS = 8  # straight targets drawn into the clutter
STREAM_SUPPORTS = ("mhoc", "chain")
STREAM_TARGET_RATIO = {0.01: 2.0, 0.02: 4.0}  # median push / floor must be at most this


@dataclass
class StreamRow:
    """One streaming configuration (times in milliseconds)."""

    sensor: str
    density: float
    order: int
    support: str
    window: int
    stride: int
    pushes: int
    points_per_scan: float
    support_per_window: float
    tracks_per_window: float
    push_median_ms: float
    push_p99_ms: float
    hoc_median_ms: float
    identify_median_ms: float
    batch_median_ms: float
    batch_p99_ms: float
    floor_ms: float
    floor_during_ms: float
    push_over_floor: float
    batch_over_push: float
    equal_windows: int
    windows: int
    push_cpu_median_ms: float = math.nan
    floor_cpu_ms: float = math.nan


def stream_scans(shape: tuple[int, int], n_scans: int, density: float, seed: int) -> torch.Tensor:
    """Seeded ``(n_scans, H, W)`` bool scans: uniform clutter plus straight targets.

    Targets move 1-3 px per scan in random directions and wrap around the frame edges (a wrap
    is a jump the HOC does not link, so a target restarts there).
    """
    h, w = shape
    gen = torch.Generator().manual_seed(seed)
    scans = torch.rand((n_scans, h, w), generator=gen) < density
    start = torch.rand(STREAM_TARGETS, 2, generator=gen) * torch.tensor([h, w])
    angle = torch.rand(STREAM_TARGETS, generator=gen) * 2 * math.pi
    speed = 1.0 + 2.0 * torch.rand(STREAM_TARGETS, generator=gen)
    vel = torch.stack([speed * torch.sin(angle), speed * torch.cos(angle)], 1)
    t = torch.arange(n_scans, dtype=torch.float32)[:, None, None]
    pos = torch.floor(start[None] + t * vel[None] + 0.5).long()  # (T, targets, 2)
    ys, xs = pos[..., 0] % h, pos[..., 1] % w
    scans[torch.arange(n_scans)[:, None].expand_as(ys), ys, xs] = True
    return scans


def _record(result: HOCResult) -> tuple:
    """A compact, exact record of a window result (cubes as their on-points / finite values).

    The streaming rows keep this instead of the result (a 640 x 512 window result holds a 26 MB
    float64 ``scores`` cube: keeping all of them would hold gigabytes, which a streaming
    consumer does not); made outside the timed push.
    """
    finite = ~result.scores.isnan()
    return (
        result.support.nonzero(),
        result.cleaned.nonzero(),
        finite.nonzero(),
        result.scores[finite],
        [(t.points.tolist(), t.score, t.point_scores.tolist()) for t in result.tracks],
        len(result.tracks),
    )


def _same_record(a: tuple, b: tuple) -> bool:
    """Two :func:`_record` records are equal (cubes bit for bit, tracks point for point)."""
    return all(
        torch.equal(x, y) if isinstance(x, torch.Tensor) else x == y
        for x, y in zip(a, b, strict=True)
    )


def batch_result(window: torch.Tensor, order: int, support: str) -> HOCResult:
    """The batch computation a streaming window must equal: :func:`detect` with ``support``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the streaming side warns alike
        return detect(window, order=order, support=support)


def run_stream_config(
    shape: tuple[int, int],
    density: float,
    order: int,
    support: str,
    pushes: int,
    seed: int,
    quick: bool,
) -> StreamRow:
    """Time one streaming configuration and check every window against the batch result."""
    n_scans = STREAM_WINDOW + pushes
    scans = stream_scans(shape, n_scans, density, seed)
    det = hoc_stream.StreamingDetector(
        window=STREAM_WINDOW, stride=STREAM_STRIDE, order=order, support=support
    )
    spent: list[float] = []
    identify = hoc_stream._identify_window

    def timed_identify(*args, **kwargs):  # the identification share of a push
        t0 = time.perf_counter()
        out = identify(*args, **kwargs)
        spent.append(time.perf_counter() - t0)
        return out

    hoc_stream._identify_window = timed_identify
    one_scan = scans[:1][None]
    try:
        for t in range(STREAM_WINDOW - 1):  # fill the window (no result yet)
            det.push(scans[t])
        push_s, identify_s, floor_during, outs = [], [], [], []
        push_cpu, floor_cpu = [], []
        for t in range(STREAM_WINDOW - 1, n_scans):
            spent.clear()
            c0 = time.process_time()
            t0 = time.perf_counter()
            out = det.push(scans[t])
            push_s.append(time.perf_counter() - t0)
            push_cpu.append(time.process_time() - c0)
            identify_s.append(sum(spent))
            # kept as a compact record (untimed), the result itself is dropped
            outs.append((out.start, out.stop, _record(out.result)))
            del out
            pool, pool_cpu = [], []
            for _ in range(3):  # the floor under the same load, between pushes
                c0 = time.process_time()
                t0 = time.perf_counter()
                max_pool_floor(one_scan)
                pool.append(time.perf_counter() - t0)
                pool_cpu.append(time.process_time() - c0)
            floor_during.append(min(pool))
            floor_cpu.append(min(pool_cpu))
    finally:
        hoc_stream._identify_window = identify
    # the first push of the loop completes the first window: it is measured like the others
    batch_s, equal, support_sizes, track_counts = [], 0, [], []
    for start, stop, rec in outs:
        window = scans[start:stop]
        t0 = time.perf_counter()
        batch = batch_result(window, order, support)
        batch_s.append(time.perf_counter() - t0)
        equal += _same_record(rec, _record(batch))
        support_sizes.append(float(rec[0].shape[0]))
        track_counts.append(rec[5])
    floor_s, _, _ = timed(
        lambda: max_pool_floor(one_scan), min_time=QUICK_MIN_TIME_S if quick else 1.0
    )
    hoc_s = [p - i for p, i in zip(push_s, identify_s, strict=True)]
    med = percentile(push_s, 50)
    return StreamRow(
        sensor=f"{shape[1]}x{shape[0]}",
        density=density,
        order=order,
        support=support,
        window=STREAM_WINDOW,
        stride=STREAM_STRIDE,
        pushes=len(push_s),
        points_per_scan=float(scans.sum()) / n_scans,
        support_per_window=float(np.mean(support_sizes)),
        tracks_per_window=float(np.mean(track_counts)),
        push_median_ms=med * 1e3,
        push_p99_ms=percentile(push_s, 99) * 1e3,
        hoc_median_ms=percentile(hoc_s, 50) * 1e3,
        identify_median_ms=percentile(identify_s, 50) * 1e3,
        batch_median_ms=percentile(batch_s, 50) * 1e3,
        batch_p99_ms=percentile(batch_s, 99) * 1e3,
        floor_ms=floor_s * 1e3,
        floor_during_ms=percentile(floor_during, 50) * 1e3,
        push_over_floor=med / floor_s,
        batch_over_push=percentile(batch_s, 50) / med,
        equal_windows=equal,
        windows=len(outs),
        push_cpu_median_ms=percentile(push_cpu, 50) * 1e3,
        floor_cpu_ms=percentile(floor_cpu, 50) * 1e3,
    )


def stream_markdown(rows: list[StreamRow], header: list[str]) -> str:
    """The streaming table as Markdown, preceded by ``header`` lines, with the verdicts."""
    cols = (
        "sensor (WxH)",
        "clutter",
        "order",
        "support",
        "pushes",
        "points/scan",
        "support/window",
        "tracks/window",
        "push median ms",
        "push p99 ms",
        "HOC part median ms",
        "identify median ms",
        "batch median ms",
        "batch p99 ms",
        "max-pool floor ms",
        "floor between pushes ms",
        "push/floor",
        "push/floor between pushes",
        "HOC part/floor",
        "target",
        "batch/push",
        "push CPU median ms",
        "floor CPU ms",
        "push/floor CPU",
        "windows == batch",
    )
    lines = [*header, "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        limit = STREAM_TARGET_RATIO.get(r.density)
        target = (
            "—"
            if limit is None
            else f"<= {limit:g}x: " + ("PASS" if r.push_over_floor <= limit else "FAIL")
        )
        cells = (
            r.sensor,
            f"{r.density:.0%}",
            str(r.order),
            r.support,
            str(r.pushes),
            f"{r.points_per_scan:.0f}",
            f"{r.support_per_window:.0f}",
            f"{r.tracks_per_window:.1f}",
            f"{r.push_median_ms:.1f}",
            f"{r.push_p99_ms:.1f}",
            f"{r.hoc_median_ms:.1f}",
            f"{r.identify_median_ms:.1f}",
            f"{r.batch_median_ms:.1f}",
            f"{r.batch_p99_ms:.1f}",
            f"{r.floor_ms:.1f}",
            f"{r.floor_during_ms:.1f}",
            f"{r.push_over_floor:.2f}",
            f"{r.push_median_ms / r.floor_during_ms:.2f}",
            f"{r.hoc_median_ms / r.floor_ms:.2f}",
            target,
            f"{r.batch_over_push:.2f}",
            f"{r.push_cpu_median_ms:.1f}",
            f"{r.floor_cpu_ms:.1f}",
            f"{r.push_cpu_median_ms / r.floor_cpu_ms:.2f}",
            f"{r.equal_windows}/{r.windows}",
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def stream_main(args: argparse.Namespace) -> int:
    """The streaming rows: run, print, write ``hoc_stream.md`` / ``.csv``."""
    shape = QUICK_STREAM_SENSOR if args.quick else STREAM_SENSOR
    pushes = args.pushes or (QUICK_STREAM_PUSHES if args.quick else STREAM_PUSHES)
    densities = args.densities or STREAM_DENSITIES
    orders = args.orders or STREAM_ORDERS
    out = args.out or RESULTS / ("hoc_stream_quick" if args.quick else "hoc_stream")
    torch.set_num_threads(args.threads)
    started = time.perf_counter()
    load_before = os.getloadavg()
    warm = stream_scans((64, 64), 14, 0.02, 0)  # one-time set-up, not timed
    warm_det = hoc_stream.StreamingDetector(window=STREAM_WINDOW, stride=1, order=2)
    for t in range(14):
        warm_det.push(warm[t])
    detect(warm[:STREAM_WINDOW], order=2)
    max_pool_floor(warm[:1][None])
    rows = []
    loads = []
    configs = [(d, k, s) for s in args.supports for d in densities for k in orders]
    for density, order, support in configs:
        loads.append(os.getloadavg()[0])
        row = run_stream_config(shape, density, order, support, pushes, args.seed, args.quick)
        rows.append(row)
        print(
            f"{row.sensor} d={density:g} k={order} {support}: "
            f"push median {row.push_median_ms:.1f} "
            f"ms (HOC {row.hoc_median_ms:.1f} + identify {row.identify_median_ms:.1f}), "
            f"p99 {row.push_p99_ms:.1f} ms, batch {row.batch_median_ms:.1f} ms, floor "
            f"{row.floor_ms:.1f} ms, equal {row.equal_windows}/{row.windows}",
            file=sys.stderr,
            flush=True,
        )
    total = time.perf_counter() - started
    load_after = os.getloadavg()
    omp = os.environ.get("OMP_NUM_THREADS", "unset")
    header = [
        "# Streaming modified HOC: latency per pushed scan vs batch detect vs the max-pool floor",
        "",
        f"- {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, torch {torch.__version__}, "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch threads = "
        f"{args.threads}, OMP_NUM_THREADS={omp}, load average (1 min) {load_before[0]:.2f} -> "
        f"{load_after[0]:.2f} (per row at its start: "
        + ", ".join(f"{x:.1f}" for x in loads)
        + f"; the machine is shared with other jobs), total run {total:.0f} s.",
        f"- `StreamingDetector(window={STREAM_WINDOW}, stride={STREAM_STRIDE}, order=k)` with "
        "`detect`'s defaults (v = 4, delta = pi/4, threshold 2.5), fed one "
        f"(H, W) bool scan at a time: uniform clutter of the given density plus "
        f"{STREAM_TARGETS} straight targets at 1-3 px/scan (seed {args.seed}). After the first "
        f"{STREAM_WINDOW - 1} scans every push returns a window result; each of the "
        f"{pushes + 1} such pushes is timed on its own (wall clock).",
        "- HOC part: the push minus its track identification call (new layer entries, links, "
        "marking trees, window cubes, track-id association); identify: the one identification "
        "call on the window's candidate points.",
        "- support: `mhoc` (the default of `detect` and `StreamingDetector`, [LA98] III-B) = the "
        "image (forward Y^(k) OR backward Y^(k)) plus the points its top-layer moves name, "
        "identified by the paper's five-point sequences; `chain` = the chain support (our "
        "addition).",
        "- batch: the same 10-scan window computed in one go, every window: "
        "`hocnet.hoc.detect(window, order=k, support=...)`; "
        "`windows == batch`: windows whose streaming result equals it.",
        f"- max-pool floor: one `max_pool2d(scan.float(), {POOL}, stride=1, padding={POOL // 2})` "
        "pass over one (H, W) scan, min over repeated runs (at least 1 s) after the pushes; "
        "floor between pushes: the same pass timed after every push (min of 3), median over "
        "the pushes: the floor under the load the pushes saw.",
        "- each window's result is kept as a compact exact record (on-points of the cubes, finite "
        "scores, tracks; made outside the timed push) and then dropped, as a streaming consumer "
        "would; `windows == batch` compares these records (support, cleaned cube, scores cube, "
        "track points, scores and point scores).",
        "- target (issue 7): median push within 2x of the floor at 1 % clutter, 4x at 2 % "
        "(verdict against the min floor).",
        "- CPU columns: the same pushes and floor passes timed in process time "
        "(`time.process_time`, one thread), medians over the pushes (floor: min of 3 after each "
        "push): time slices lost to other jobs do not count, so the CPU ratio is the one to "
        "compare between runs at different loads (wall-clock ratios on the shared machine grow "
        "with the load: a push of 100+ ms is preempted where a 12 ms floor pass often is not).",
    ]
    text = stream_markdown(rows, header)
    print(text)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text(text)
    with out.with_suffix(".csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=[f.name for f in fields(StreamRow)])
        writer.writeheader()
        for r in rows:
            writer.writerow(asdict(r))
    print(f"wrote {out.with_suffix('.md')} and {out.with_suffix('.csv')}", file=sys.stderr)
    if any(r.equal_windows != r.windows for r in rows):
        print("streaming result differs from batch detect", file=sys.stderr)
        return 1
    return 0


# ----------------------------------------------------------------------------- command line


def _parse_size(text: str) -> tuple[int, int, int]:
    parts = text.lower().split("x")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"`--sizes`: expected TxHxW, got {text!r}")
    n_t, h, w = (int(p) for p in parts)
    return n_t, h, w


def _csv_of(conv: Callable[[str], _R]) -> Callable[[str], tuple[_R, ...]]:
    return lambda text: tuple(conv(p) for p in text.split(",") if p.strip())


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--quick",
        action="store_true",
        help="sizes 6x16x16 and 10x60x60, density 0.02 only (smoke test)",
    )
    p.add_argument(
        "--stream",
        action="store_true",
        help="streaming rows instead: StreamingDetector push latency on a 640 x 512 sensor",
    )
    p.add_argument(
        "--supports",
        type=_csv_of(str),
        default=STREAM_SUPPORTS,
        help="with --stream: comma-separated StreamingDetector supports (default mhoc,chain)",
    )
    p.add_argument(
        "--pushes",
        type=int,
        help=f"with --stream: measured pushes per configuration (default {STREAM_PUSHES})",
    )
    p.add_argument("--sizes", type=_csv_of(_parse_size), help="comma-separated TxHxW")
    p.add_argument("--densities", type=_csv_of(float), help="comma-separated clutter densities")
    p.add_argument("--orders", type=_csv_of(int), help="comma-separated HOC orders")
    p.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (default 2)")
    p.add_argument("--seed", type=int, default=0, help="cube seed (default 0)")
    p.add_argument("--out", type=Path, help="output stem (default benchmarks/results/hoc)")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print the table and the headline, write ``.md`` and ``.csv``."""
    args = parse_args(argv)
    if args.stream:
        return stream_main(args)
    sizes = args.sizes or (QUICK_SIZES if args.quick else FULL_SIZES)
    densities = args.densities or (QUICK_DENSITIES if args.quick else DENSITIES)
    orders = args.orders or ORDERS
    out = args.out or RESULTS / ("hoc_quick" if args.quick else "hoc")
    torch.set_num_threads(args.threads)

    started = time.perf_counter()
    load_before = os.getloadavg()
    warm_up()
    rows: list[Row] = []
    configs = [(s, d, k) for s in sizes for d in densities for k in orders]
    for i, (size, density, order) in enumerate(configs, 1):
        row = run_config(size, density, order, args.seed, args.threads, args.quick)
        rows.append(row)
        print(
            f"[{i}/{len(configs)}] {row.size} d={density:g} k={order}: "
            f"sparse {row.sparse_s:.3g} s, conv {row.conv_s:.3g} s, "
            f"maxpool {row.maxpool_s:.3g} s, peak {row.sparse_peak_mb:.1f} MB",
            file=sys.stderr,
            flush=True,
        )
    total = time.perf_counter() - started
    load_after = os.getloadavg()

    memory_note = "the peak is " + common_memory_note()
    min_time = QUICK_MIN_TIME_S if args.quick else MIN_TIME_S
    header = [
        "# Modified HOC speed: loop reference vs connectionist (conv) vs fast path (sparse)",
        "",
        f"- {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, torch {torch.__version__}, "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"torch threads = {args.threads}, load average {load_before[0]:.2f} -> "
        f"{load_after[0]:.2f} (other jobs may share the machine), total run {total:.0f} s.",
        f"- Timed item: order-k modified HOC (v = {V}, delta = pi/4) forward + backward on a "
        f"(1, T, H, W) bool cube, each pixel on with probability `density` "
        f"(torch.Generator seed {args.seed}). Times are wall seconds: the min over >= "
        f"{MIN_RUNS} runs (more, up to {MAX_RUNS}, while under {min_time:g} s in total), or a "
        f"single run when the first run exceeds {SINGLE_S:g} s (marked ¹)"
        + (" or in --quick mode for conv and reference." if args.quick else "."),
        f"- reference: the Python loop oracle `hoc_reference`, only for cubes of at most "
        f"{REFERENCE_MAX_PIXELS} pixels (— otherwise).",
        f"- maxpool: one `max_pool2d(x.float().reshape(B*T, 1, H, W), {POOL}, stride=1, "
        f"padding={POOL // 2})` pass over the same cube — the floor of any windowed detector.",
        "- sparse Mpix-scans/s: T*H*W cube pixels per second of the timed (forward + backward) "
        "fast-path item.",
        "- sparse peak MB: each configuration's fast path runs once in a fresh child process "
        "(`multiprocessing` forkserver that has imported torch + hocnet and computed nothing). "
        "Reported is its peak RSS after the run minus its RSS at the baseline (after the "
        "imports and one tiny warm-up call, before the cube is built; input cube, outputs and "
        "all temporaries count): "
        f"{memory_note}. Peak-RSS counters of a spawn child are not usable here: Linux "
        "carries `ru_maxrss` over exec, so a spawn child reports the parent's peak.",
        "- survivors f/b: points kept by the forward / backward network at that order.",
        "- identical: yes — conv and sparse outputs are bit-identical (torch.equal) in every row, "
        "and equal the loop reference wherever it ran.",
    ]
    lines = headline(rows)
    text = markdown(rows, header) + "\n" + "\n".join(lines) + "\n"
    print(text)
    print("identical: yes")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text(text)
    write_csv(rows, out.with_suffix(".csv"))
    print(f"wrote {out.with_suffix('.md')} and {out.with_suffix('.csv')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

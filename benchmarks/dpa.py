"""Speed benchmark of the DPA score accumulation of [NR08]: loop reference, `accumulate`, floor.

For every frame size x number of frames x window x number of matrices ``D``, on seeded
whitened-like frames (standard normal, float32, one sequence ``(1, T, H, W)``), it times in one
run:

* reference -- the Python loop oracle :func:`hocnet.dpa.reference.accumulate_reference`, on the
  tiny configurations only (4 frames of 12 x 12), where ``accumulate`` is checked against it;
* forward -- :func:`hocnet.dpa.functional.accumulate` on inputs that do not require grad;
* fwd+bwd -- ``accumulate(...).asf.sum().backward()`` with frames, weights, ``b`` and ``g``
  requiring grad (the forward pass included);
* floor -- one plain ``k x k`` unfold-max over the same stack,
  ``F.unfold(x.reshape(B*T, 1, H, W), k, padding=k // 2).max(1)``: the least any windowed
  max over every frame can cost.

The weights are ``probability_matrices(window=k, v_max=...)`` (``v_max`` 2 for 7 x 7, 1 for
5 x 5, plus the default 0.5 px jitter): all nine for ``D = 9``, the "in place" matrix alone for
``D = 1``; ``g = 0.5`` and ``b`` from ``effective_memory(weights, g)`` (effective memory 0.8 in
direction 9). ``D = 9`` is timed with both direction steps of ``accumulate`` ("paper", the
default, and "source"). The peak memory of fwd+bwd is
measured once per configuration in a fresh forkserver child (see ``benchmarks/_common.py``).

Run::

    .venv/bin/python benchmarks/dpa.py            # full table (about 5 minutes)
    .venv/bin/python benchmarks/dpa.py --quick    # smoke test: tiny + 64 x 64 only (< 20 s)

Options: ``--threads 2`` (``torch.set_num_threads``), ``--seed 0``, ``--out STEM``. The table is
printed and written to ``benchmarks/results/dpa.md`` with the raw numbers in ``dpa.csv``
(``dpa_quick.*`` with ``--quick``).

Full pipeline row (issue 10): one 100-frame 256 x 256 clip through the pipeline of
``hocnet detect --method dpa`` (``hocnet.dpa.presets.RECOMMENDED``: registration, median
background of 10 past frames, anti-mean whitening, DPA, per-frame detections), timed with 1 and
2 torch threads; target under 5 s. ``--pipeline`` runs only this row and writes
``benchmarks/results/dpa_pipeline.md``; the full run appends it to ``dpa.md``.
"""

from __future__ import annotations

import os

# Idle OpenMP threads sleep instead of spinning: on a machine shared with other processes a
# spinning thread of a 2-thread team waits out whole scheduler time slices at every barrier,
# which made the many small parallel ops of the recursion up to 50x slower in our runs. It has
# to be set before torch loads OpenMP; an explicit setting in the environment wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse
import csv
import sys
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from _common import (
    fmt_s,
    load_average,
    machine_line,
    memory_note,
    peak_memory_mb,
    timed,
)

from hocnet.dpa.functional import accumulate
from hocnet.dpa.matrices import effective_memory, probability_matrices
from hocnet.dpa.reference import accumulate_reference

G = 0.5  # sum/max mixing of every run
EMC = 0.8  # effective memory that sets b
V_MAX = {5: 1.0, 7: 2.0}  # largest speed (px/frame, + 0.5 jitter) of the matrices of each window

TINY = (12, 4)  # (frame size, frames) of the configurations with the loop reference
SIZES = (64, 128, 256)
QUICK_SIZES = (64,)
FRAMES = (10, 25)
WINDOWS = (5, 7)
DS = (1, 9)
STEPS = ("paper", "source")  # direction steps timed for D = 9 (D = 1 has none: "paper" only)

MIN_RUNS = 3  # a time is the min over at least this many runs ...
MIN_TIME_S = 1.0  # ... and more (up to MAX_RUNS) while less than this was spent on the item
MAX_RUNS = 30
QUICK_MIN_TIME_S = 0.15

# the targets of the issue, for 25 frames of 256 x 256, 7 x 7, D = 9
TARGET = (256, 25, 7, 9, "paper")
TARGET_FLOOR_RATIO = 4.0  # forward within this factor of the floor
TARGET_BACKWARD_RATIO = 3.0  # forward + backward within this factor of forward
TARGET_MEMORY_MB = 2048.0  # peak memory of forward + backward

RTOL, ATOL = 1e-5, 1e-5  # allclose of the ASF against the reference (float32)

RESULTS = Path(__file__).resolve().parent / "results"


@dataclass
class Row:
    """One configuration (times in seconds, memory in MB)."""

    size: int
    frames: int
    window: int
    d: int
    step: str
    reference_s: float | None
    forward_s: float
    forward_runs: int
    fwd_bwd_s: float
    fwd_bwd_runs: int
    floor_s: float
    forward_over_floor: float
    fwd_bwd_over_forward: float
    forward_mpix_frames_per_s: float
    peak_mb: float
    peak_abs_mb: float
    matches_reference: bool | None


# ----------------------------------------------------------------------------- the items


def make_inputs(
    size: int, n_frames: int, window: int, d: int, seed: int
) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Seeded standard-normal frames ``(1, T, H, W)``, the ``(D, k, k)`` matrices and ``b``."""
    gen = torch.Generator().manual_seed(seed)
    frames = torch.randn((1, n_frames, size, size), generator=gen, dtype=torch.float32)
    weights = probability_matrices(window, v_max=V_MAX[window], dtype=torch.float32)
    if d == 1:
        weights = weights[8:9].clone()  # the "in place" matrix
    return frames, weights, float(effective_memory(weights, G, EMC))


def forward(frames: torch.Tensor, weights: torch.Tensor, b: float, step: str) -> torch.Tensor:
    """The forward item: the ASF of ``accumulate`` (inputs not requiring grad)."""
    return accumulate(frames, weights, b, G, direction_step=step).asf


def forward_backward(
    frames: torch.Tensor, weights: torch.Tensor, b: float, step: str
) -> torch.Tensor:
    """The fwd+bwd item: ``accumulate`` with every input requiring grad, then ``backward``.

    Fresh leaves are made from the inputs (a cheap copy, part of the timed item) so that every
    run starts without gradients.
    """
    x = frames.detach().clone().requires_grad_(True)
    w = weights.detach().clone().requires_grad_(True)
    b_t = torch.tensor(b, requires_grad=True)
    g_t = torch.tensor(G, requires_grad=True)
    asf = accumulate(x, w, b_t, g_t, direction_step=step).asf
    asf.sum().backward()
    return asf.detach()


def floor(frames: torch.Tensor, window: int) -> torch.Tensor:
    """One plain ``k x k`` unfold-max over every frame of the stack."""
    b, n_t, h, w = frames.shape
    cols = F.unfold(frames.reshape(b * n_t, 1, h, w), window, padding=window // 2)
    return cols.max(1).values


def _memory_item(size: int, n_frames: int, window: int, d: int, step: str, seed: int) -> None:
    """What the memory child runs: build the inputs, then one fwd+bwd item."""
    frames, weights, b = make_inputs(size, n_frames, window, d, seed)
    forward_backward(frames, weights, b, step)


def _warm_up() -> None:
    """One tiny call of each item (one-time runtime setup, not timed or counted)."""
    for d in DS:
        for step in STEPS:
            frames, weights, b = make_inputs(12, 3, 5, d, 0)
            forward(frames, weights, b, step)
            forward_backward(frames, weights, b, step)
            floor(frames, 5)


def check_reference(
    frames: torch.Tensor, weights: torch.Tensor, b: float, step: str, quick: bool
) -> tuple[float, bool]:
    """Time the loop reference and compare ``accumulate`` with it (ASF, direction, origin)."""
    kwargs = {"min_runs": 1, "min_time": 0.0} if quick else {"min_time": 0.0}
    ref_s, _, (r_asf, r_dir, r_org) = timed(
        lambda: accumulate_reference(frames.numpy(), weights.numpy(), b, G, direction_step=step),
        **kwargs,
    )
    state = accumulate(frames, weights, b, G, direction_step=step)
    ok = (
        np.allclose(state.asf.numpy(), r_asf, rtol=RTOL, atol=ATOL)
        and np.array_equal(state.direction.numpy(), r_dir)
        and np.array_equal(state.origin.numpy(), r_org)
    )
    return ref_s, ok


def run_config(
    size: int, n_frames: int, window: int, d: int, step: str, seed: int, threads: int, quick: bool
) -> Row:
    """Time one configuration and measure its fwd+bwd peak memory."""
    frames, weights, b = make_inputs(size, n_frames, window, d, seed)
    opts = {
        "min_runs": MIN_RUNS,
        "min_time": QUICK_MIN_TIME_S if quick else MIN_TIME_S,
        "max_runs": MAX_RUNS,
    }
    with torch.no_grad():
        fwd_s, fwd_runs, asf = timed(lambda: forward(frames, weights, b, step), **opts)
    fb_s, fb_runs, asf_fb = timed(lambda: forward_backward(frames, weights, b, step), **opts)
    floor_s, _, _ = timed(lambda: floor(frames, window), **opts)
    if not torch.equal(asf, asf_fb):
        raise AssertionError(f"forward and fwd+bwd ASF differ at {size}, {n_frames}, {window}")

    reference_s: float | None = None
    matches: bool | None = None
    if (size, n_frames) == TINY:
        reference_s, matches = check_reference(frames, weights, b, step, quick)
        if not matches:
            raise AssertionError(
                f"accumulate differs from the loop reference at {size}x{size}, T={n_frames}, "
                f"{window}x{window}, D={d}, direction_step={step}"
            )

    peak_mb, peak_abs_mb = peak_memory_mb(
        _memory_item,
        (size, n_frames, window, d, step, seed),
        _warm_up,
        threads,
        preload=("torch", "hocnet.dpa.functional"),
    )
    return Row(
        size=size,
        frames=n_frames,
        window=window,
        d=d,
        step=step,
        reference_s=reference_s,
        forward_s=fwd_s,
        forward_runs=fwd_runs,
        fwd_bwd_s=fb_s,
        fwd_bwd_runs=fb_runs,
        floor_s=floor_s,
        forward_over_floor=fwd_s / floor_s,
        fwd_bwd_over_forward=fb_s / fwd_s,
        forward_mpix_frames_per_s=frames.numel() / fwd_s / 1e6,
        peak_mb=peak_mb,
        peak_abs_mb=peak_abs_mb,
        matches_reference=matches,
    )


# ----------------------------------------------------------------------------- reporting


COLUMNS = (
    "size",
    "T",
    "window",
    "D",
    "direction step",
    "reference s",
    "forward s",
    "fwd+bwd s",
    "floor s",
    "forward/floor",
    "(fwd+bwd)/forward",
    "forward Mpix-frames/s",
    "fwd+bwd peak MB",
)


def markdown_table(rows: list[Row]) -> list[str]:
    """The table as Markdown lines."""
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        cells = (
            f"{r.size}x{r.size}",
            str(r.frames),
            f"{r.window}x{r.window}",
            str(r.d),
            r.step if r.d == 9 else "—",
            fmt_s(r.reference_s),
            fmt_s(r.forward_s),
            fmt_s(r.fwd_bwd_s),
            fmt_s(r.floor_s),
            f"{r.forward_over_floor:.2f}",
            f"{r.fwd_bwd_over_forward:.2f}",
            f"{r.forward_mpix_frames_per_s:.2f}",
            f"{r.peak_mb:.0f}",
        )
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def headline(rows: list[Row]) -> list[str]:
    """The headline for 25 frames of 256 x 256, 7 x 7, D = 9, with PASS/FAIL per target."""
    size, n_frames, window, d, step = TARGET
    what = f"{n_frames} frames of {size}x{size}, {window}x{window}, D = {d}, {step} step"
    hit = [r for r in rows if (r.size, r.frames, r.window, r.d, r.step) == TARGET]
    if not hit:
        return [f"Headline ({what}): not run in this mode."]
    r = hit[0]
    floor_ok = r.forward_over_floor <= TARGET_FLOOR_RATIO
    back_ok = r.fwd_bwd_over_forward <= TARGET_BACKWARD_RATIO
    mem_ok = r.peak_mb < TARGET_MEMORY_MB and r.peak_abs_mb < TARGET_MEMORY_MB

    def verdict(ok: bool) -> str:
        return "PASS" if ok else "FAIL"

    return [
        f"Headline ({what}): forward {r.forward_s:.3g} s, fwd+bwd {r.fwd_bwd_s:.3g} s, "
        f"floor {r.floor_s:.3g} s, peak memory {r.peak_mb:.0f} MB "
        f"(process total {r.peak_abs_mb:.0f} MB)",
        f"- forward within {TARGET_FLOOR_RATIO:g}x of the floor: {verdict(floor_ok)} "
        f"({r.forward_over_floor:.2f}x)",
        f"- forward + backward within {TARGET_BACKWARD_RATIO:g}x of forward: "
        f"{verdict(back_ok)} ({r.fwd_bwd_over_forward:.2f}x)",
        f"- peak memory under 2 GB: {verdict(mem_ok)} ({r.peak_mb:.0f} MB above the baseline, "
        f"{r.peak_abs_mb:.0f} MB process total)",
    ]


def header_lines(
    args: argparse.Namespace, load_before: float, load_after: float, total_s: float
) -> list[str]:
    """Title and the notes on what was measured and how."""
    min_time = QUICK_MIN_TIME_S if args.quick else MIN_TIME_S
    tiny, tiny_t = TINY
    return [
        "# DPA score accumulation speed: loop reference vs `accumulate` vs unfold-max floor",
        "",
        machine_line(args.threads, load_before, load_after, total_s),
        f"- OMP_WAIT_POLICY = {os.environ.get('OMP_WAIT_POLICY', '')} (the script sets PASSIVE "
        "unless the environment sets it: idle OpenMP threads sleep instead of spinning, which "
        "keeps 2-thread timings meaningful while other processes share the 2 cores).",
        f"- Input: one sequence `(1, T, H, W)` of float32 standard-normal frames "
        f"(torch.Generator seed {args.seed}); weights `probability_matrices(window=k, "
        f"v_max=...)` (v_max {V_MAX[7]:g} for 7x7, {V_MAX[5]:g} for 5x5), all nine for D = 9, "
        f"the in-place matrix `[8:9]` for D = 1; g = {G:g}, b = "
        f"`effective_memory(weights, g, {EMC:g})` (direction 9); hard max, default var_table; "
        "D = 9 timed with both direction steps (`direction_step='paper'`, eq. (6)-(8) of "
        "[NR08], the default, and `'source'`); D = 1 has no direction step.",
        f"- Times are wall seconds, the min over >= {MIN_RUNS} runs (more, up to {MAX_RUNS}, "
        f"while under {min_time:g} s were spent on the item).",
        f"- reference: the Python loop oracle `accumulate_reference`, only for {tiny_t} frames "
        f"of {tiny}x{tiny} (— otherwise)"
        + (", single run in --quick mode" if args.quick else ", min over 3 runs")
        + "; there `accumulate` matches it (ASF allclose with rtol = atol = 1e-5, direction and "
        "origin equal).",
        "- forward: `accumulate(frames, weights, b, g)` on inputs that do not require grad, "
        "under `torch.no_grad()`.",
        "- fwd+bwd: fresh leaves of frames, weights, b and g requiring grad, "
        "`accumulate(...).asf.sum().backward()` — forward with the graph plus backward; "
        "(fwd+bwd)/forward divides it by the no-grad forward above.",
        "- floor: one `F.unfold(x.reshape(B*T, 1, H, W), k, padding=k//2).max(1)` over the same "
        "stack.",
        "- forward Mpix-frames/s: T*H*W input pixels per second of forward.",
        "- fwd+bwd peak MB: one fwd+bwd item (inputs built inside) in a fresh child process "
        "forked from a `multiprocessing` forkserver that has imported torch + hocnet and computed "
        "nothing; its peak RSS minus its RSS at the baseline (after one tiny warm-up call, before "
        f"the inputs are built), the peak being {memory_note()}.",
    ]


def write_csv(rows: list[Row], path: Path) -> None:
    """Raw numbers, one row per configuration."""
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=[f.name for f in fields(Row)])
        writer.writeheader()
        for r in rows:
            writer.writerow(asdict(r))


# ----------------------------------------------------------------------------- full pipeline

PIPELINE_SHAPE = (100, 256, 256)  # (T, H, W) of the full-pipeline row
PIPELINE_TARGET_S = 5.0
PIPELINE_RUNS = 3


def pipeline_frames(seed: int) -> torch.Tensor:
    """A seeded 8-bit-like clip: still textured ground, noise and one dim moving target."""
    t, h, w = PIPELINE_SHAPE
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    ground = 20 * torch.sin(xx / 5.0) * torch.cos(yy / 7.0) + 15 * (
        torch.rand(h, w, generator=g) > 0.95
    )
    frames = 80.0 + ground + 3.0 * torch.randn(t, h, w, generator=g)
    for n in range(t):
        frames[n, 100:102, 50 + n // 2 : 52 + n // 2] += 12.0
    return frames.clamp(0, 255).round()


def run_pipeline(frames: torch.Tensor) -> torch.Tensor:
    """Registration, background removal, whitening, DPA and the per-frame detections."""
    from hocnet.detection_metrics import detect_peaks
    from hocnet.dpa.presets import RECOMMENDED, preprocess, weights_and_b

    white, _ = preprocess(frames, RECOMMENDED)
    weights, b = weights_and_b(RECOMMENDED)
    asf = accumulate(white, weights, b, RECOMMENDED.g, direction_step=RECOMMENDED.direction_step)
    return detect_peaks(asf.asf, radius=2, max_per_frame=50)


def pipeline_lines(seed: int) -> list[str]:
    """The full-pipeline row at 1 and 2 torch threads (min over PIPELINE_RUNS runs)."""
    frames = pipeline_frames(seed)
    previous = torch.get_num_threads()
    results = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            with torch.no_grad():
                best = timed(lambda: run_pipeline(frames), min_runs=PIPELINE_RUNS, min_time=0.0)[0]
            results.append((threads, best))
            print(f"pipeline, {threads} thread(s): {best:.2f} s", file=sys.stderr, flush=True)
    finally:
        torch.set_num_threads(previous)
    t, h, w = PIPELINE_SHAPE
    lines = [
        "## Full pipeline (issue 10)",
        "",
        f"One clip of {t} frames of {h}x{w} (seeded textured ground + noise + a dim target) "
        "through the pipeline of `hocnet detect --method dpa` (`hocnet.dpa.presets.RECOMMENDED`):"
        " registration (phase correlation), median background of 10 past frames, anti-mean "
        "whitening, DPA (5x5, g = 0, equal gain, EMC 0.4, paper direction step), per-frame "
        f"detections (`detect_peaks`, NMS radius 2, 50 per frame). Min over {PIPELINE_RUNS} "
        f"runs. Target: under {PIPELINE_TARGET_S:g} s.",
        "",
        "| torch threads | seconds | under the target |",
        "|---|---|---|",
    ]
    for threads, best in results:
        verdict = "PASS" if best < PIPELINE_TARGET_S else "FAIL"
        lines.append(f"| {threads} | {best:.2f} | {verdict} |")
    return lines


# ----------------------------------------------------------------------------- command line


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="tiny + 64x64 only (smoke test)")
    p.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (default 2)")
    p.add_argument("--seed", type=int, default=0, help="frame seed (default 0)")
    p.add_argument("--out", type=Path, help="output stem (default benchmarks/results/dpa)")
    p.add_argument(
        "--pipeline", action="store_true", help="only the full-pipeline row (dpa_pipeline.md)"
    )
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print the table and the headline, write ``.md`` and ``.csv``."""
    args = parse_args(argv)
    if args.pipeline:
        load_before = load_average()
        started = time.perf_counter()
        lines = pipeline_lines(args.seed)
        total = time.perf_counter() - started
        text = "\n".join(
            [machine_line(args.threads, load_before, load_average(), total), "", *lines]
        )
        print(text)
        out = args.out or RESULTS / "dpa_pipeline"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".md").write_text(text + "\n")
        return 0
    out = args.out or RESULTS / ("dpa_quick" if args.quick else "dpa")
    torch.set_num_threads(args.threads)
    sizes = QUICK_SIZES if args.quick else SIZES

    started = time.perf_counter()
    load_before = load_average()
    print(f"load average (1 min) at the start: {load_before:.2f}", file=sys.stderr, flush=True)
    _warm_up()
    tiny, tiny_t = TINY

    def steps(d: int) -> tuple[str, ...]:
        return STEPS if d == 9 else STEPS[:1]

    configs = [(tiny, tiny_t, k, d, st) for k in WINDOWS for d in DS for st in steps(d)]
    configs += [
        (s, t, k, d, st)
        for s in sizes
        for t in FRAMES
        for k in WINDOWS
        for d in DS
        for st in steps(d)
    ]
    rows: list[Row] = []
    for i, (size, n_frames, window, d, step) in enumerate(configs, 1):
        row = run_config(size, n_frames, window, d, step, args.seed, args.threads, args.quick)
        rows.append(row)
        print(
            f"[{i}/{len(configs)}] {size}x{size} T={n_frames} {window}x{window} D={d} {step}: "
            f"forward {row.forward_s:.3g} s, fwd+bwd {row.fwd_bwd_s:.3g} s, "
            f"floor {row.floor_s:.3g} s, peak {row.peak_mb:.0f} MB",
            file=sys.stderr,
            flush=True,
        )
    total = time.perf_counter() - started
    load_after = load_average()
    print(f"load average (1 min) at the end: {load_after:.2f}", file=sys.stderr, flush=True)

    lines = [
        *header_lines(args, load_before, load_after, total),
        "",
        *markdown_table(rows),
        "",
        *headline(rows),
    ]
    if not args.quick:
        lines += ["", *pipeline_lines(args.seed)]
    text = "\n".join(lines) + "\n"
    print(text)
    print("matches reference: yes")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text(text)
    write_csv(rows, out.with_suffix(".csv"))
    print(f"wrote {out.with_suffix('.md')} and {out.with_suffix('.csv')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

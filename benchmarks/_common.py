"""Shared helpers of the benchmark scripts: min-of-runs timing, peak memory, machine line.

Imported by the scripts in this folder as ``from _common import ...`` (a script's own folder is
first on ``sys.path`` when it is run as ``.venv/bin/python benchmarks/<name>.py``).

Peak memory is measured the same way as in ``benchmarks/hoc.py``: the work runs once in a child
process forked from a ``multiprocessing`` forkserver that has imported the libraries and computed
nothing; after a tiny warm-up call the child resets its peak-RSS counter (``VmHWM``, by writing 5
to ``/proc/self/clear_refs``) to its current RSS, runs the work, and reports the new ``VmHWM``
minus that baseline. A ``spawn`` child is not usable for this: Linux carries ``ru_maxrss`` over
``exec``, so it would report the parent's peak.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import platform
import resource
import sys
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from typing import Any, TypeVar

import torch

_R = TypeVar("_R")

__all__ = [
    "fmt_s",
    "load_average",
    "machine_line",
    "memory_note",
    "peak_memory_mb",
    "percentile",
    "timed",
]


def timed(
    fn: Callable[[], _R], min_runs: int = 3, min_time: float = 0.5, max_runs: int = 30
) -> tuple[float, int, _R]:
    """Best wall time of ``fn``: the minimum over repeated runs.

    ``fn`` runs at least ``min_runs`` times and then again (at most ``max_runs`` times in all)
    while less than ``min_time`` seconds were spent in it, so fast items get more runs. The
    minimum is the least disturbed run on a machine shared with other jobs.

    Returns:
        ``(best seconds, number of runs, result of the last run)``.
    """
    best, runs, spent = math.inf, 0, 0.0
    while True:
        t0 = time.perf_counter()
        result = fn()
        dt = time.perf_counter() - t0
        best, runs, spent = min(best, dt), runs + 1, spent + dt
        if runs >= max_runs or (runs >= min_runs and spent >= min_time):
            return best, runs, result


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0-100) of ``values``, linear interpolation (numpy's default)."""
    ordered = sorted(values)
    if not ordered:
        return math.nan
    pos = (len(ordered) - 1) * q / 100
    lo = math.floor(pos)
    hi = min(lo + 1, len(ordered) - 1)
    return ordered[lo] + (ordered[hi] - ordered[lo]) * (pos - lo)


def load_average() -> float:
    """The 1-minute load average of the machine (``nan`` where unavailable)."""
    try:
        return os.getloadavg()[0]
    except OSError:
        return math.nan


def machine_line(threads: int, load_before: float, load_after: float, total_s: float) -> str:
    """One Markdown bullet: date, torch, CPU, threads, load average before -> after, run time."""
    return (
        f"- {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, torch {torch.__version__}, "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"torch threads = {threads}, load average (1 min) {load_before:.2f} at the start -> "
        f"{load_after:.2f} at the end (other processes share the machine, so times are the "
        f"least disturbed of several runs), total run {total_s:.0f} s."
    )


def fmt_s(x: float | None) -> str:
    """Seconds with 3 significant digits, ``—`` for a missing time."""
    if x is None:
        return "—"
    return f"{x:.3g}" if x >= 1e-3 else f"{x:.2e}"


# ----------------------------------------------------------------------------- peak memory


def _proc_status_mb() -> dict[str, float] | None:
    """``VmRSS`` and ``VmHWM`` of this process in MB from ``/proc/self/status`` (Linux)."""
    try:
        with open("/proc/self/status") as fh:
            lines = fh.readlines()
    except OSError:
        return None
    out = {}
    for line in lines:
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = int(value.split()[0]) / 1024
    return out if len(out) == 2 else None


def _reset_peak_rss() -> bool:
    """Reset this process's ``VmHWM`` to its current RSS (Linux ``clear_refs`` mode 5)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return False
    return True


def _maxrss_mb() -> float:
    """``ru_maxrss`` of this process in MB (Linux reports KiB, macOS bytes)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / (1024 * 1024) if sys.platform == "darwin" else rss / 1024


def _peak_child(
    work: Callable[..., Any], args: Sequence[Any], warm_up: Callable[[], Any], threads: int
) -> tuple[float, float, str]:
    """Runs in the child: peak RSS of ``work(*args)`` above the baseline after ``warm_up()``.

    ``warm_up`` takes torch's one-time runtime setup (thread pool, allocator arenas, autograd
    engine) out of the measurement; the counter is reset after it, before ``work`` builds its
    inputs, so inputs, outputs and every temporary of ``work`` count.

    Returns:
        ``(peak minus baseline MB, absolute peak MB, name of the counter used)``.
    """
    torch.set_num_threads(threads)
    warm_up()
    status = _proc_status_mb() if _reset_peak_rss() else None
    if status is not None:
        base, method = status["VmRSS"], "VmHWM"
    else:  # no /proc: ru_maxrss, which also counts the import-time high-water mark
        base, method = _maxrss_mb(), "ru_maxrss"
    work(*args)
    status = _proc_status_mb() if method == "VmHWM" else None
    peak = status["VmHWM"] if status is not None else _maxrss_mb()
    return max(0.0, peak - base), peak, method


MEMORY_METHODS: set[str] = set()  # the counters used so far (for :func:`memory_note`)


def peak_memory_mb(
    work: Callable[..., Any],
    args: Sequence[Any],
    warm_up: Callable[[], Any],
    threads: int,
    preload: Sequence[str] = ("torch",),
) -> tuple[float, float]:
    """``(increment MB, absolute peak MB)`` of one ``work(*args)`` in a fresh child process.

    ``work`` and ``warm_up`` must be picklable (module-level functions). The forkserver
    preloads ``__main__`` and the modules in ``preload``, once per parent process.
    """
    try:
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(["__main__", *preload])
    except ValueError:  # no forkserver on this platform
        ctx = mp.get_context("spawn")
    with ctx.Pool(1) as pool:
        inc, peak, method = pool.apply(_peak_child, (work, tuple(args), warm_up, threads))
    MEMORY_METHODS.add(method)
    return inc, peak


def memory_note() -> str:
    """How the peaks reported so far were measured, for a results header."""
    if MEMORY_METHODS == {"VmHWM"}:
        return (
            "`VmHWM` from /proc/self/status, reset to the current RSS at the baseline by "
            "writing 5 to /proc/self/clear_refs"
        )
    return (
        "`ru_maxrss` (no resettable VmHWM here), so usage below the import-time high-water "
        "mark reads as 0"
    )

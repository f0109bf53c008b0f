"""Per-target tracking metrics of [PD] 24.6.3 and GOSPA.

The chapter's measures of performance, per target ``n`` and averaged over ``N_mc`` Monte-Carlo
runs ([PD] 24.6.3, Tables 24.1-24.2, eq. 24.52): track length ratio, ARMSE, track purity and
type purity. The chapter defines them in one sentence each; our readings:

- **Track-to-target association** ("a test is used to associate a track to the most probable
  target"): a confirmed track goes to the target that originated most of its measurements
  (majority of the ``truth_ids`` of its updates; ties to the smaller target id). A track with no
  target-originated measurement is a false track and counts for no target.
- **Track length ratio**, eq. 24.52 prints ``R_n = sum_{k=1}^{N_mc} l_n / (N_mc L_n)`` with no
  run index on ``l_n`` (as printed the sum just gives ``l_n / L_n``): we read
  ``R_n = (1 / N_mc) sum_k l_n^k / L_n`` with ``l_n^k`` the *mean* duration (s, last minus first
  sample time, clipped to the target's lifetime) of the tracks associated with ``n`` in run
  ``k`` (0 if none) and ``L_n`` the duration of the true trajectory. A target lost and picked
  up again by a new track thus scores lower, as the chapter wants ("track as long as possible the
  target with one track"). ``length="max"`` or ``"sum"`` use the longest or the total duration
  (``"sum"`` is not clipped at 1, so that duplicate, overlapping tracks show as a ratio above 1).
- **ARMSE** ("the root mean square error averaged on the time"): at each time ``t`` of the
  truth grid the RMS over runs (and over the target's tracks alive then) of the position error
  ``|p_hat(t) - p(t)|``, then the mean over the times at which there was at least one estimate.
  Track samples are compared with the truth interpolated at their exact time and binned to the
  nearest truth time. With one run and one track it is the mean position error.
  ``TargetMetrics.armse_run`` is the other order the sentence allows ("These measures of
  performances are averaged on the number Monte-Carlo runs", 24.6.3): per run the RMS over the
  samples of the target's tracks, then the mean over the runs that track it (ours, reported
  beside). Both count every sample of a track associated with the target, also those after it
  lost the target (the chapter associates whole tracks, "a test is used to associate a track to
  the most probable target", and its track purity counts the wrong associations *on* such a
  track; nothing in 24.6.3 removes samples from the ARMSE).
- **Track purity** ("the ratio between the sum of correct association number on the track
  length"): over the tracks associated with ``n``, the number of updates with a measurement of
  ``n`` divided by the number of updates with a measurement (samples without one, i.e. coasting,
  are not counted, so a perfect tracker scores 1 at PD < 1).
- **Type purity**: over the same tracks, the number of samples whose declared type (e.g. the
  maximum of BetP, eq. 24.45) is the target's true type, divided by the number of samples with a
  type declaration; ``nan`` ("none" in Table 24.1) when the tracks declare no type.
- Track and type purity are averaged over the runs in which the target has at least one track.
- The brief of this module cites 24.49-24.51 for the purities: those equations are the sensors'
  class probabilities (see :mod:`hocnet.tracking.scenario`, where the backwards-printed aspect
  interval of 24.51 is read as ``pi/6 <= alpha <= 5 pi/6``).

GOSPA (our addition; the chapter has none): Rahmathullah, Garcia-Fernandez and Svensson (2017)
with ``alpha = 2``, computed by Stone Soup's ``GOSPAMetric`` when ``stonesoup`` is installed and
by an equivalent NumPy / SciPy implementation otherwise.
"""

from __future__ import annotations

import datetime
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from hocnet._check import check_choice, check_number

__all__ = [
    "FALSE_ALARM",
    "NO_MEASUREMENT",
    "NO_TYPE",
    "EstimatedTrack",
    "TargetMetrics",
    "assign_tracks",
    "gospa",
    "gospa_numpy",
    "monte_carlo_metrics",
    "target_metrics",
]

#: ``truth_ids`` value of an update by a false alarm.
FALSE_ALARM = -1
#: ``truth_ids`` value of a sample without a measurement (prediction only / missed detection).
NO_MEASUREMENT = -2
#: ``types`` value of a sample without a type declaration.
NO_TYPE = -1


def _int_array(name: str, value: Any, n: int, none_value: int) -> np.ndarray:
    if value is None:
        return np.full(n, none_value, dtype=np.int64)
    items = [none_value if v is None else v for v in value]
    arr = np.asarray(items)
    if arr.shape != (n,):
        raise ValueError(f"`{name}`: expected shape ({n},), got {arr.shape}")
    if n and not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"`{name}`: expected integers (or None), got dtype {arr.dtype}")
    return arr.astype(np.int64)


@dataclass(frozen=True)
class EstimatedTrack:
    """One estimated (confirmed) track, as needed by the metrics.

    Attributes:
        times: ``(N,)`` sample times (s), non-decreasing.
        positions: ``(N, 2)`` estimated positions ``(x, y)`` (m).
        truth_ids: ``(N,)`` id of the target whose measurement updated the track at each sample,
            :data:`FALSE_ALARM` (or ``None``) for a false alarm, :data:`NO_MEASUREMENT` for a
            sample without an update. Default: all :data:`NO_MEASUREMENT`.
        types: ``(N,)`` declared type index (e.g. into
            :data:`hocnet.tracking.scenario.VIDEO_CLASSES`) or :data:`NO_TYPE` (or ``None``).
            Default: no type.

    Raises:
        ValueError: shapes that disagree, non-finite or decreasing times, non-finite positions.

    Examples:
        >>> trk = EstimatedTrack([0.0, 10.0], [[0.0, 0.0], [100.0, 0.0]], [1, None])
        >>> trk.truth_ids.tolist(), trk.types.tolist()
        ([1, -1], [-1, -1])
    """

    times: Any
    positions: Any
    truth_ids: Any = None
    types: Any = None

    def __post_init__(self) -> None:
        t = np.asarray(self.times, dtype=np.float64).reshape(-1)
        p = np.asarray(self.positions, dtype=np.float64)
        if p.size == 0:
            p = p.reshape(0, 2)
        if p.ndim != 2 or p.shape != (t.size, 2):
            raise ValueError(f"`positions`: expected shape ({t.size}, 2), got {p.shape}")
        if not (np.isfinite(t).all() and np.isfinite(p).all()):
            raise ValueError("`times`: expected finite times and positions, got NaN/inf")
        if t.size > 1 and bool((np.diff(t) < 0).any()):
            raise ValueError("`times`: expected non-decreasing sample times, got a decrease")
        ids = self.truth_ids
        if ids is None:
            ids = np.full(t.size, NO_MEASUREMENT, dtype=np.int64)
        else:
            ids = _int_array("truth_ids", ids, t.size, FALSE_ALARM)
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "truth_ids", ids)
        object.__setattr__(self, "types", _int_array("types", self.types, t.size, NO_TYPE))

    @property
    def duration(self) -> float:
        """Last minus first sample time (s); 0 for an empty or one-sample track."""
        return float(self.times[-1] - self.times[0]) if self.times.size else 0.0


@dataclass(frozen=True)
class TargetMetrics:
    """The chapter's measures of performance for one target ([PD] Tables 24.1-24.2).

    Attributes:
        target_id: the target.
        length_ratio: track length ratio (eq. 24.52, our reading), in [0, 1].
        armse: averaged RMS position error (m); ``nan`` if the target was never tracked.
        track_purity: in [0, 1]; ``nan`` if never tracked.
        type_purity: in [0, 1]; ``nan`` if never tracked or no type declared ("none").
        n_tracks: mean number of tracks associated with the target per run.
        armse_run: per-run RMS position error (m) averaged over the runs that track the target
            (the other reading of 24.6.3, module docstring); ``nan`` if never tracked.
    """

    target_id: int
    length_ratio: float
    armse: float
    track_purity: float
    type_purity: float
    n_tracks: float
    armse_run: float = float("nan")


def _tracks(name: str, tracks: Mapping[Any, Any]) -> dict[Any, EstimatedTrack]:
    if not isinstance(tracks, Mapping):
        raise TypeError(f"`{name}`: expected a mapping track_id -> EstimatedTrack, got {tracks!r}")
    out = {}
    for k, v in tracks.items():
        if not isinstance(v, EstimatedTrack):
            raise TypeError(f"`{name}`: expected EstimatedTrack values, got {type(v).__name__}")
        out[k] = v
    return out


def assign_tracks(tracks: Mapping[Any, EstimatedTrack]) -> dict[Any, int | None]:
    """Associate each track with the target that originated most of its measurements.

    Our reading of "a test is used to associate a track to the most probable target" ([PD]
    24.6.3): the majority of the track's ``truth_ids`` that are target ids (false alarms and
    samples without measurement do not vote); ties go to the smaller target id; ``None`` when no
    target measurement updated the track (a false track).

    Args:
        tracks: ``{track_id: EstimatedTrack}``.

    Returns:
        ``{track_id: target_id or None}``.

    Examples:
        >>> assign_tracks({"a": EstimatedTrack([0, 1, 2], [[0, 0]] * 3, [3, 3, 5])})
        {'a': 3}
    """
    out: dict[Any, int | None] = {}
    for k, trk in _tracks("tracks", tracks).items():
        ids = trk.truth_ids[(trk.truth_ids != FALSE_ALARM) & (trk.truth_ids != NO_MEASUREMENT)]
        if not ids.size:
            out[k] = None
            continue
        vals, counts = np.unique(ids, return_counts=True)
        out[k] = int(vals[np.argmax(counts)])  # np.unique sorts: ties go to the smaller id
    return out


def _truth_arrays(truth: Mapping[int, Any]) -> dict[int, tuple[np.ndarray, np.ndarray, int]]:
    out = {}
    for tid, tr in truth.items():
        times = np.asarray(tr.times, dtype=np.float64)
        pos = np.asarray(tr.positions, dtype=np.float64)
        if times.ndim != 1 or pos.shape != (times.size, 2):
            raise ValueError(
                f"`truth`: expected times (T,) and positions (T, 2) for target {tid}, got "
                f"{times.shape} and {pos.shape}"
            )
        out[int(tid)] = (times, pos, int(getattr(tr, "video_class", NO_TYPE)))
    return out


def monte_carlo_metrics(
    truth: Mapping[int, Any],
    runs: Sequence[Mapping[Any, EstimatedTrack]],
    *,
    assignments: Sequence[Mapping[Any, int | None]] | None = None,
    length: str = "mean",
) -> dict[int, TargetMetrics]:
    """Per-target metrics of [PD] 24.6.3 averaged over Monte-Carlo runs (see module docstring).

    Args:
        truth: ``{target_id: truth}`` where ``truth`` has ``times`` ``(T,)``, ``positions``
            ``(T, 2)`` on a regular grid and ``video_class`` (the true type index, used by the type
            purity); e.g. :func:`hocnet.tracking.scenario.pd_ground_truth`.
        runs: one ``{track_id: EstimatedTrack}`` per run (the confirmed tracks).
        assignments: one ``{track_id: target_id or None}`` per run (default
            :func:`assign_tracks`).
        length: track length ``l_n^k`` of a run: ``"mean"`` (our reading of eq. 24.52), ``"max"``
            or ``"sum"`` of the durations of the target's tracks. Each duration is clipped to the
            target's life, so ``"mean"`` and ``"max"`` are at most 1 (the ``min(., 1)`` only
            removes round-off); ``"sum"`` is deliberately not clipped: overlapping tracks on one
            target (duplicates) add up, and a ratio above 1 shows them.

    Returns:
        ``{target_id: TargetMetrics}`` in the order of ``truth``.

    Raises:
        TypeError, ValueError: malformed truth, tracks or assignments.

    Examples:
        >>> class T:  # a target moving along x at 1 m/s for 10 s
        ...     times = np.arange(11.0)
        ...     positions = np.stack([np.arange(11.0), np.zeros(11)], 1)
        ...     video_class = 0
        >>> trk = EstimatedTrack(T.times, T.positions + [0.0, 3.0], [7] * 11, [0] * 11)
        >>> m = monte_carlo_metrics({7: T}, [{"a": trk}])[7]
        >>> m.length_ratio, m.armse, m.track_purity, m.type_purity
        (1.0, 3.0, 1.0, 1.0)
    """
    length = check_choice("length", length, ("mean", "max", "sum"))
    gt = _truth_arrays(truth)
    runs = [_tracks(f"runs[{k}]", r) for k, r in enumerate(runs)]
    if assignments is None:
        assignments = [assign_tracks(r) for r in runs]
    elif len(assignments) != len(runs):
        raise ValueError(
            f"`assignments`: expected one mapping per run ({len(runs)}), got {len(assignments)}"
        )
    n_mc = len(runs)
    out: dict[int, TargetMetrics] = {}
    for tid, (times, pos, true_type) in gt.items():
        life = float(times[-1] - times[0]) if times.size else 0.0
        dt = float(np.median(np.diff(times))) if times.size > 1 else 1.0
        se = np.zeros(times.size)
        cnt = np.zeros(times.size)
        ratios, purities, type_purities, n_tracks, run_rms = [], [], [], [], []
        for run, asg in zip(runs, assignments):
            run_se = run_n = 0.0
            mine = [trk for k, trk in run.items() if asg.get(k) == tid]
            n_tracks.append(len(mine))
            durations = []
            good = measured = typed = right_type = 0
            for trk in mine:
                if times.size:
                    lo = max(trk.times[0], times[0]) if trk.times.size else 0.0
                    hi = min(trk.times[-1], times[-1]) if trk.times.size else 0.0
                    durations.append(max(hi - lo, 0.0))
                    inside = (trk.times >= times[0] - 1e-9) & (trk.times <= times[-1] + 1e-9)
                    if inside.any():
                        tt = trk.times[inside]
                        ref = np.stack(
                            [np.interp(tt, times, pos[:, 0]), np.interp(tt, times, pos[:, 1])], 1
                        )
                        e2 = ((trk.positions[inside] - ref) ** 2).sum(1)
                        idx = np.clip(
                            np.rint((tt - times[0]) / dt).astype(np.int64), 0, se.size - 1
                        )
                        np.add.at(se, idx, e2)
                        np.add.at(cnt, idx, 1.0)
                        run_se += float(e2.sum())
                        run_n += float(e2.size)
                ids = trk.truth_ids
                good += int((ids == tid).sum())
                measured += int((ids != NO_MEASUREMENT).sum())
                typed += int((trk.types != NO_TYPE).sum())
                right_type += int(((trk.types == true_type) & (trk.types != NO_TYPE)).sum())
            if durations and life > 0:
                agg = {"mean": np.mean, "max": np.max, "sum": np.sum}[length](durations)
                ratios.append(min(float(agg) / life, 1.0) if length != "sum" else float(agg) / life)
            else:
                ratios.append(0.0)
            if run_n:
                run_rms.append(math.sqrt(run_se / run_n))
            if mine:
                purities.append(good / measured if measured else np.nan)
                type_purities.append(right_type / typed if typed else np.nan)
        rms = np.sqrt(se[cnt > 0] / cnt[cnt > 0])
        out[tid] = TargetMetrics(
            target_id=tid,
            length_ratio=float(np.mean(ratios)) if n_mc else float("nan"),
            armse=float(rms.mean()) if rms.size else float("nan"),
            track_purity=_nanmean(purities),
            type_purity=_nanmean(type_purities),
            n_tracks=float(np.mean(n_tracks)) if n_mc else float("nan"),
            armse_run=_nanmean(run_rms),
        )
    return out


def _nanmean(values: Sequence[float]) -> float:
    arr = np.asarray(values, dtype=np.float64)
    arr = arr[np.isfinite(arr)]
    return float(arr.mean()) if arr.size else float("nan")


def target_metrics(
    truth: Mapping[int, Any],
    tracks: Mapping[Any, EstimatedTrack],
    *,
    assignment: Mapping[Any, int | None] | None = None,
    length: str = "mean",
) -> dict[int, TargetMetrics]:
    """Per-target metrics of one run: :func:`monte_carlo_metrics` with ``N_mc = 1``.

    Examples:
        >>> class T:
        ...     times = np.arange(3.0)
        ...     positions = np.zeros((3, 2))
        ...     video_class = 0
        >>> target_metrics({1: T}, {})[1].length_ratio
        0.0
    """
    return monte_carlo_metrics(
        truth,
        [tracks],
        assignments=None if assignment is None else [assignment],
        length=length,
    )


# --------------------------------------------------------------------------------------------
# GOSPA
# --------------------------------------------------------------------------------------------


def gospa_numpy(estimates: Any, truths: Any, *, c: float, p: float = 2.0) -> dict[str, float]:
    """GOSPA between two finite point sets with ``alpha = 2`` (NumPy / SciPy).

    ``d = (sum_assigned min(|x - y|, c)^p + c^p / 2 (|X| + |Y| - 2 |assigned|))^(1/p)`` with the
    optimal assignment of ``min(|x - y|, c)^p``; pairs at distance ``>= c`` count as one missed
    and one false target. Components as Stone Soup's ``GOSPAMetric`` (p-th powers).

    Args:
        estimates: ``(M, D)`` estimated points.
        truths: ``(N, D)`` true points.
        c: cut-off distance (> 0).
        p: order (>= 1).

    Returns:
        ``{"distance", "localisation", "missed", "false"}``.

    Examples:
        >>> gospa_numpy([[0.0, 0.0]], [[3.0, 4.0], [100.0, 0.0]], c=10.0)["distance"] ** 2
        75.00000000000001
    """
    c = check_number("c", c, low=0.0, low_inclusive=False)
    p = check_number("p", p, low=1.0)
    x = np.asarray(estimates, dtype=np.float64)
    y = np.asarray(truths, dtype=np.float64)
    x = x.reshape(len(x), -1) if x.size else np.zeros((0, 1))
    y = y.reshape(len(y), -1) if y.size else np.zeros((0, 1))
    dummy = c**p / 2.0
    loc = 0.0
    n_pairs = 0
    if len(x) and len(y):
        d = np.linalg.norm(x[:, None, :] - y[None, :, :], axis=-1)
        cost = np.minimum(d, c) ** p
        rows, cols = linear_sum_assignment(cost)
        real = d[rows, cols] < c
        loc = float(cost[rows, cols][real].sum())
        n_pairs = int(real.sum())
    missed = dummy * (len(y) - n_pairs)
    false = dummy * (len(x) - n_pairs)
    return {
        "distance": float((loc + missed + false) ** (1.0 / p)),
        "localisation": loc,
        "missed": float(missed),
        "false": float(false),
    }


def _have_stonesoup() -> bool:
    try:
        import stonesoup.metricgenerator.ospametric  # noqa: F401
    except ImportError:
        return False
    return True


def _sets_at(
    t: float, truth: Mapping[int, Any], tracks: Mapping[Any, EstimatedTrack]
) -> tuple[np.ndarray, np.ndarray]:
    est, tru = [], []
    for trk in tracks.values():
        if trk.times.size and trk.times[0] - 1e-9 <= t <= trk.times[-1] + 1e-9:
            est.append(
                [
                    np.interp(t, trk.times, trk.positions[:, 0]),
                    np.interp(t, trk.times, trk.positions[:, 1]),
                ]
            )
    for tr in truth.values():
        times = np.asarray(tr.times, dtype=np.float64)
        pos = np.asarray(tr.positions, dtype=np.float64)
        if times.size and times[0] - 1e-9 <= t <= times[-1] + 1e-9:
            tru.append([np.interp(t, times, pos[:, 0]), np.interp(t, times, pos[:, 1])])
    return np.asarray(est, dtype=np.float64).reshape(-1, 2), np.asarray(
        tru, dtype=np.float64
    ).reshape(-1, 2)


def gospa(
    truth: Mapping[int, Any],
    tracks: Mapping[Any, EstimatedTrack],
    times: Any = None,
    *,
    c: float = 200.0,
    p: float = 2.0,
    backend: str = "auto",
) -> dict[str, np.ndarray]:
    """GOSPA (``alpha = 2``) between the targets and the tracks at each of ``times``.

    At time ``t`` the true set holds the targets alive at ``t`` and the estimated set the tracks
    alive at ``t`` (between their first and last samples), both linearly interpolated. Computed
    by Stone Soup's ``GOSPAMetric`` (``backend="stonesoup"``, default when installed) or by
    :func:`gospa_numpy` (``"numpy"``); both give the same numbers.

    Args:
        truth: ``{target_id: truth}`` with ``times`` ``(T,)`` and ``positions`` ``(T, 2)``.
        tracks: ``{track_id: EstimatedTrack}``.
        times: ``(K,)`` evaluation times (s); default: the sorted distinct track sample times.
        c: cut-off distance (m; ours: 200 m, about three GMTI cross-range deviations).
        p: order.
        backend: ``"auto"``, ``"stonesoup"`` or ``"numpy"``.

    Returns:
        ``{"times", "distance", "localisation", "missed", "false"}``, each ``(K,)`` float64.

    Raises:
        ImportError: ``backend="stonesoup"`` without ``stonesoup`` installed.

    Examples:
        >>> class T:
        ...     times = np.arange(3.0)
        ...     positions = np.zeros((3, 2))
        >>> g = gospa({1: T}, {"a": EstimatedTrack(T.times, T.positions)}, backend="numpy")
        >>> g["distance"].tolist()
        [0.0, 0.0, 0.0]
    """
    backend = check_choice("backend", backend, ("auto", "stonesoup", "numpy"))
    c = check_number("c", c, low=0.0, low_inclusive=False)
    p = check_number("p", p, low=1.0)
    tracks = _tracks("tracks", tracks)
    if times is None:
        all_t = [trk.times for trk in tracks.values()]
        times = np.unique(np.concatenate(all_t)) if all_t else np.zeros(0)
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    use_ss = backend == "stonesoup" or (backend == "auto" and _have_stonesoup())
    if use_ss:
        if not _have_stonesoup():
            raise ImportError(
                "`backend`: 'stonesoup' needs the stonesoup package (pip install stonesoup)"
            )
        from stonesoup.metricgenerator.ospametric import GOSPAMetric
        from stonesoup.types.state import State

        metric = GOSPAMetric(p=p, c=c)
        epoch = datetime.datetime(2000, 1, 1)
    keys = ("distance", "localisation", "missed", "false")
    out = {k: np.zeros(times.size) for k in keys}
    for i, t in enumerate(times):
        est, tru = _sets_at(float(t), truth, tracks)
        if use_ss and (len(est) or len(tru)):
            stamp = epoch + datetime.timedelta(seconds=float(t))
            res, _ = metric.compute_gospa_metric(
                [State(e.reshape(2, 1), timestamp=stamp) for e in est],
                [State(y.reshape(2, 1), timestamp=stamp) for y in tru],
            )
            vals = res.value
        else:
            vals = gospa_numpy(est, tru, c=c, p=p)
        for k in keys:
            out[k][i] = float(vals[k])
    return {"times": times, **out}

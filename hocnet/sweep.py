"""Parameter sweeps and training runs over configs on Ray Tune (our addition; optional extra).

Two kinds of sweep, both run by :func:`run_sweep` on Ray Tune (``pip install 'hocnet[sweep]'``):

* **DPA grids** (:func:`dpa_trial`, evaluated by :func:`evaluate_dpa` on simulated IR scenes):
  the memory factor ``b``, the sum/max mixing ``g``, the penalty step ``x`` of eq. (5) of [NR08]
  (``penalty_step``), the frame sampling ``s_n`` (section 3.2 of [NR08]), ``Max_Numbers`` of the
  block SNR (eq. 16) and the scene seeds. Each trial reports the algorithm score ``A_S``
  (eq. 16-17, the paper's reading), ``Pd`` at a per-pixel false-alarm probability (thresholds
  from the target-free ASF of the same scenes) and the back-tracking success rate.
* **Training runs over configs** (:func:`hocnet.learn.sweep.train_trial`): a
  :class:`~hocnet.learn.DPATuner` or :class:`~hocnet.learn.LearnedHOCSystem` per grid point
  (``model.*`` / ``data.*`` keys), fitted and tested with Lightning; the trial reports the test
  metrics. It lives in :mod:`hocnet.learn.sweep`, with the other Lightning code.

The engine lives at the top of the package, not in :mod:`hocnet.learn`, because a DPA grid needs
neither Lightning nor torchmetrics: only Ray Tune and the plain DPA. Ray is imported lazily, so
importing this module never needs it; :func:`require_ray` raises :class:`RayMissingError` (an
``ImportError``) with the install command.

:func:`run_sweep` starts an embedded local Ray instance (``ray.init()``) unless one is running,
or joins a cluster with ``address``; the experiment folder (``Tuner``'s ``storage_path / name``)
makes a sweep resumable with ``resume=True`` (``Tuner.restore``: finished trials are kept and
not rerun, errored ones are restarted, unfinished ones resumed). One row per trial (its grid
point, its metrics, ``trial_id``, ``status``) comes back, ready for :func:`write_rows_csv`.
"""

from __future__ import annotations

import csv
import functools
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from hocnet._check import check_choice, check_int, check_number

__all__ = [
    "DPA_AXES",
    "INSTALL_HINT",
    "DPASweepSettings",
    "RayMissingError",
    "SweepResult",
    "dpa_param_space",
    "dpa_trial",
    "evaluate_dpa",
    "require_ray",
    "run_sweep",
    "write_rows_csv",
]

INSTALL_HINT = "pip install 'hocnet[sweep]' (in a clone: pip install -e '.[sweep]')"
"""How to install the optional Ray Tune dependency."""

DPA_AXES = ("b", "g", "penalty_step", "s_n", "max_numbers", "seed")
"""The axes of a DPA grid, in the order of the rows of :func:`run_sweep`."""

DPA_DEFAULTS: dict[str, Any] = {
    "b": 0.8,
    "g": 1.0,
    "penalty_step": 3.0,
    "s_n": 1,
    "max_numbers": 1,
    "seed": 0,
}
"""Value of an axis missing from a grid point: the paper's g = 1, b = 0.8, x = 3, s_n = 1."""

SCENES = ("na23a", "npa", "ir")
"""Scene families of a DPA grid: :func:`~hocnet.data.na23a_like`, :func:`~hocnet.data.npa_like`,
and a centred target of :func:`~hocnet.data.simulate_ir` moving towards -x (``ir``)."""

_RAY_KEYS = frozenset(
    {
        "training_iteration",
        "time_total_s",
        "time_this_iter_s",
        "time_since_restore",
        "timesteps_total",
        "timesteps_since_restore",
        "iterations_since_restore",
        "episodes_total",
        "timestamp",
        "date",
        "done",
        "pid",
        "hostname",
        "node_ip",
        "config",
        "checkpoint_dir_name",
        "experiment_tag",
        "trial_id",
    }
)


class RayMissingError(ImportError):
    """Ray Tune, the optional ``sweep`` extra, is not installed."""


def require_ray() -> tuple[Any, Any]:
    """Import Ray and Ray Tune, or raise :class:`RayMissingError` saying how to install them.

    Returns:
        The modules ``(ray, ray.tune)``.

    Raises:
        RayMissingError: when ``ray[tune]`` cannot be imported.

    Examples:
        >>> try:
        ...     ray, tune = require_ray()
        ... except RayMissingError as err:
        ...     assert "hocnet[sweep]" in str(err)
    """
    try:
        import ray
        from ray import tune
    except ImportError as err:
        raise RayMissingError(f"sweeps need Ray Tune: {INSTALL_HINT}") from err
    return ray, tune


# --------------------------------------------------------------------------------------------
# DPA grids
# --------------------------------------------------------------------------------------------


def _shape3(name: str, value: Any) -> tuple[int, int, int]:
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != 3:
        raise TypeError(f"`{name}`: expected (T, H, W), got {value!r}")
    return tuple(check_int(name, v, minimum=1) for v in value)  # type: ignore[return-value]


@dataclass(frozen=True)
class DPASweepSettings:
    """The fixed part of a DPA grid: scenes, matrices and metric settings.

    Args:
        scene: ``"na23a"`` (:func:`~hocnet.data.na23a_like`: one target in clear sky, 0.3
            px/frame towards -x), ``"npa"`` (:func:`~hocnet.data.npa_like`: two targets, the
            studied one under a cloud) or ``"ir"`` (one target at the frame centre moving
            towards -x, :func:`~hocnet.data.simulate_ir`, ``clouds`` preset).
        shape: ``(T, H, W)`` of the frames the DPA sees, after the sampling ``s_n``: each scene
            is simulated with ``1 + (T - 1) s_n`` frames and every ``s_n``-th one is kept.
        scenes: scenes per trial (one batch, drawn from the trial's ``seed``).
        snr_db: peak SNR in dB; ``None`` for the preset's (NA23A 35.6, NPA 29.5, ir 12).
        speed: target speed in px/frame of the simulated sequence; ``None`` for the preset's
            (NA23A 0.3, NPA 0.2, ir 0.5).
        clouds: cloud preset for ``na23a`` / ``ir`` (``None``: ``"clear"`` / ``"wispy"``);
            must be ``None`` for ``npa`` (its clouds are fixed).
        window: odd size of the probability matrices (``probability_matrices(window, v_max)``).
        v_max: largest target speed of ``W_frame``, px/frame.
        p: W_basic mixing weight of eq. (5).
        whiten: ``"anti_mean"`` or ``"anti_median"`` (7 x 7 ring, 3 x 3 guard).
        pfa: per-pixel false-alarm probability of ``pd``; at least ``1 / (scenes H W)``.
        last: final frames averaged by ``A_S`` (clipped to ``T``).
        block: block of ``A_S`` (rows, columns) or one size; ``None``: ``min(30, H // 3,
            W // 3)`` square (the paper's 30 x 30 when the frame allows).
        radius: detection / tracking radius in pixels.
        direction_step: ``"paper"`` or ``"source"`` (:func:`~hocnet.dpa.accumulate`).

    Examples:
        >>> DPASweepSettings(scene="ir", shape=(6, 24, 24)).block_shape()
        (8, 8)
    """

    scene: str = "na23a"
    shape: tuple[int, int, int] = (10, 45, 45)
    scenes: int = 2
    snr_db: float | None = None
    speed: float | None = None
    clouds: str | None = None
    window: int = 5
    v_max: float = 1.0
    p: float = 0.5
    whiten: str = "anti_mean"
    pfa: float = 1e-3
    last: int = 6
    block: int | tuple[int, int] | None = None
    radius: float = 1.5
    direction_step: str = "paper"

    def __post_init__(self) -> None:
        check_choice("scene", self.scene, SCENES)
        object.__setattr__(self, "shape", _shape3("shape", self.shape))
        n = check_int("scenes", self.scenes, minimum=1)
        if self.snr_db is not None:
            check_number("snr_db", self.snr_db)
        if self.speed is not None:
            check_number("speed", self.speed, low=0.0, high=2.0)
        if self.clouds is not None:
            from hocnet.data.infrared import CLOUD_PRESETS

            if self.scene == "npa":
                raise ValueError(
                    f"`clouds`: expected None for scene 'npa' (its clouds are fixed), "
                    f"got {self.clouds!r}"
                )
            check_choice("clouds", self.clouds, tuple(CLOUD_PRESETS))
        window = check_int("window", self.window, minimum=1)
        if window % 2 == 0 or window > min(self.shape[1:]):
            raise ValueError(
                f"`window`: expected an odd size <= min(H, W) = {min(self.shape[1:])}, got {window}"
            )
        check_number("v_max", self.v_max, low=0.0)
        check_number("p", self.p, low=0.0, high=1.0)
        check_choice("whiten", self.whiten, ("anti_mean", "anti_median"))
        _, height, width = self.shape
        low = 1.0 / (n * height * width)
        check_number("pfa", self.pfa, low=low, high=1.0, high_inclusive=False)
        check_int("last", self.last, minimum=1)
        if self.block is not None:
            block = (self.block,) * 2 if isinstance(self.block, int) else tuple(self.block)
            if len(block) != 2:
                raise TypeError(f"`block`: expected a size or (rows, columns), got {self.block!r}")
            rows, cols = (check_int("block", v, minimum=1) for v in block)
            if 3 * rows > height or 3 * cols > width:
                raise ValueError(
                    f"`block`: expected 3 x 3 blocks to fit in {height} x {width}, "
                    f"got {rows} x {cols}"
                )
        elif min(height, width) < 3:
            raise ValueError(f"`shape`: expected H, W >= 3 for the A_S blocks, got {self.shape}")
        check_number("radius", self.radius, low=0.0, low_inclusive=False)
        check_choice("direction_step", self.direction_step, ("paper", "source"))

    def block_shape(self) -> tuple[int, int]:
        """The ``(rows, columns)`` of the ``A_S`` blocks."""
        if self.block is None:
            side = min(30, self.shape[1] // 3, self.shape[2] // 3)
            return side, side
        if isinstance(self.block, int):
            return self.block, self.block
        return int(self.block[0]), int(self.block[1])

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (``DPASweepSettings(**d)`` rebuilds it)."""
        return asdict(self)


def _grid_value(name: str, value: Any) -> Any:
    """One value of a DPA axis, validated."""
    if name == "b":
        return check_number("b", value, low=0.0)
    if name == "g":
        return check_number("g", value, low=0.0, high=1.0)
    if name == "penalty_step":
        return check_number("penalty_step", value, low=0.0, high=3.0)
    return check_int(name, value, minimum=1 if name in ("s_n", "max_numbers") else 0)


def dpa_param_space(**axes: Sequence[Any]) -> dict[str, Any]:
    """A Ray Tune ``param_space`` of :func:`tune.grid_search` axes for :func:`dpa_trial`.

    Args:
        **axes: values per axis of :data:`DPA_AXES` (``b``, ``g``, ``penalty_step``, ``s_n``,
            ``max_numbers``, ``seed``); each a non-empty sequence. Missing axes take
            :data:`DPA_DEFAULTS` in every trial.

    Returns:
        ``{axis: tune.grid_search(values)}``; the grid is the Cartesian product.

    Raises:
        RayMissingError: without Ray Tune.
        TypeError, ValueError: an unknown axis, an empty axis or a value out of range.

    Examples:
        >>> space = dpa_param_space(b=[0.4, 0.8], g=[1.0])  # doctest: +SKIP
        >>> space["b"]  # doctest: +SKIP
        {'grid_search': [0.4, 0.8]}
    """
    checked = check_dpa_axes(axes)
    _, tune = require_ray()
    return {name: tune.grid_search(values) for name, values in checked.items()}


def check_dpa_axes(axes: Mapping[str, Sequence[Any]]) -> dict[str, list[Any]]:
    """Validate DPA grid axes (see :func:`dpa_param_space`) without Ray; return them as lists.

    Examples:
        >>> check_dpa_axes({"b": [0, 0.8], "seed": [0, 1]})
        {'b': [0.0, 0.8], 'seed': [0, 1]}
    """
    out: dict[str, list[Any]] = {}
    for name, values in axes.items():
        if name not in DPA_AXES:
            raise ValueError(f"`axes`: expected names among {DPA_AXES}, got {name!r}")
        if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
            raise TypeError(f"`{name}`: expected a sequence of values, got {values!r}")
        if len(values) == 0:
            raise ValueError(f"`{name}`: expected at least one value, got none")
        out[name] = [_grid_value(name, v) for v in values]
    return out


@functools.lru_cache(maxsize=8)
def _scenes(settings: DPASweepSettings, s_n: int, seed: int) -> tuple[torch.Tensor, ...]:
    """Whitened frames, whitened target-free frames ``(B, T, H, W)``, positions ``(B, N, T, 2)``.

    Cached per worker process: every ``(b, g, x, Max_Numbers)`` of a grid reuses the scenes.
    """
    from hocnet.data import infrared, whitening

    n_t, height, width = settings.shape
    shape = (1 + (n_t - 1) * s_n, height, width)
    kwargs: dict[str, Any] = {"shape": shape, "batch": settings.scenes, "seed": seed}
    if settings.snr_db is not None:
        kwargs["snr_db"] = settings.snr_db
    if settings.scene == "na23a":
        if settings.speed is not None:
            kwargs["speed"] = settings.speed
        if settings.clouds is not None:
            kwargs["clouds"] = settings.clouds
        seq = infrared.na23a_like(**kwargs)
    elif settings.scene == "npa":
        if settings.speed is not None:
            kwargs["speed"] = settings.speed
        seq = infrared.npa_like(**kwargs)
    else:
        speed = 0.5 if settings.speed is None else settings.speed
        travel = speed * (shape[0] - 1)
        target = infrared.IRTarget(
            0.5 * width + 0.5 * travel,
            0.5 * height,
            -speed,
            0.0,
            snr_db=12.0 if settings.snr_db is None else settings.snr_db,
        )
        seq = infrared.simulate_ir(
            shape,
            [target],
            clouds=settings.clouds or "wispy",
            batch=settings.scenes,
            seed=seed,
        )
    whiten = {"anti_mean": whitening.anti_mean, "anti_median": whitening.anti_median}
    white = whiten[settings.whiten]
    frames = white(seq.frames[:, ::s_n].contiguous())
    free = white(seq.target_free[:, ::s_n].contiguous())
    return frames, free, seq.positions[:, :, ::s_n].contiguous()


def evaluate_dpa(config: Mapping[str, Any], settings: DPASweepSettings) -> dict[str, float]:
    """Run the DPA of [NR08] at one grid point on the settings' scenes; return its metrics.

    The scenes of ``settings`` (``settings.scenes`` of them, drawn from ``config["seed"]``,
    sampled every ``s_n``-th frame, whitened) go through ``accumulate(frames,
    probability_matrices(window, v_max, p=p, penalty_step=x), b, g)`` (eq. 2-11), as do their
    target-free twins (the same clouds and noise without the targets).

    Metrics:
        * ``valid``: 1 when ``b <= b_limit(weights, g)`` (the memory range of eq. 12-14); 0
          otherwise, and every other metric is NaN (the DPA refuses such a ``b``).
        * ``a_s`` / ``a_s_std``: mean / population std over the scenes of
          ``algorithm_score(asf, studied target, last, block, max_numbers)`` (eq. 16-17, the
          paper's reading; the studied target is target 0).
        * ``pd``: fraction of (scene, target) pairs detected in the last frame: some ASF pixel
          within ``radius`` px above the per-pixel threshold for ``pfa`` estimated on the
          target-free ASF of the same frame (:func:`~hocnet.dpa.frame_thresholds`,
          :func:`~hocnet.dpa.detection_probability`).
        * ``tracked``: fraction of scenes whose trajectory back-tracked (eq. 8) from the highest
          last-frame ASF follows some target (:func:`~hocnet.dpa.tracking_success`).
        * ``seconds``: wall time of the evaluation.

    Args:
        config: one grid point, keys among :data:`DPA_AXES` (missing ones: :data:`DPA_DEFAULTS`).
        settings: the fixed scenes and metric settings.

    Returns:
        The metrics above, as floats.

    Raises:
        TypeError, ValueError: a bad grid value.

    Examples:
        >>> settings = DPASweepSettings(scene="ir", shape=(4, 24, 24), snr_db=20.0, last=2)
        >>> metrics = evaluate_dpa({"b": 0.8, "g": 1.0}, settings)
        >>> sorted(metrics)
        ['a_s', 'a_s_std', 'pd', 'seconds', 'tracked', 'valid']
    """
    from hocnet.dpa import (
        accumulate,
        algorithm_score,
        b_limit,
        backtrack,
        detection_probability,
        frame_thresholds,
        probability_matrices,
        tracking_success,
    )

    start = time.perf_counter()
    point = {**DPA_DEFAULTS, **{k: v for k, v in config.items() if k in DPA_AXES}}
    point = {name: _grid_value(name, value) for name, value in point.items()}
    weights = probability_matrices(
        settings.window, v_max=settings.v_max, p=settings.p, penalty_step=point["penalty_step"]
    )
    b, g = point["b"], point["g"]
    if b > b_limit(weights, g) * (1 + 1e-6):
        nan = math.nan
        out = {"valid": 0.0, "a_s": nan, "a_s_std": nan, "pd": nan, "tracked": nan}
        return {**out, "seconds": time.perf_counter() - start}
    frames, free, positions = _scenes(settings, point["s_n"], point["seed"])
    options = {"direction_step": settings.direction_step}
    state = accumulate(frames, weights, b, g, **options)
    asf_free = accumulate(free, weights, b, g, **options).asf
    n_t = frames.shape[1]
    score = algorithm_score(
        state.asf,
        positions[:, 0],
        last=min(settings.last, n_t),
        block=settings.block_shape(),
        max_numbers=point["max_numbers"],
    ).double()
    thresholds = frame_thresholds(asf_free, settings.pfa)
    pd = detection_probability(state.asf, positions, thresholds, radius=settings.radius)
    path = backtrack(state)
    hit = torch.stack(
        [
            tracking_success(path, positions[:, i], radius=settings.radius)
            for i in range(positions.shape[1])
        ]
    ).any(dim=0)
    return {
        "valid": 1.0,
        "a_s": float(score.mean()),
        "a_s_std": float(score.std(unbiased=False)),
        "pd": float(pd[-1]),
        "tracked": float(hit.double().mean()),
        "seconds": time.perf_counter() - start,
    }


def _report(metrics: Mapping[str, Any]) -> None:
    """Report a trial's final metrics to Ray Tune."""
    _, tune = require_ray()
    tune.report(dict(metrics))


def dpa_trial(config: dict[str, Any], settings: DPASweepSettings | Mapping[str, Any]) -> None:
    """Ray Tune function trainable of a DPA grid: :func:`evaluate_dpa`, reported once.

    Pass it as ``tune.with_parameters(dpa_trial, settings=...)`` (:func:`run_sweep` does).
    One torch thread per trial (``cpus_per_trial`` trials share the machine's cores).
    """
    if not isinstance(settings, DPASweepSettings):
        settings = DPASweepSettings(**settings)
    torch.set_num_threads(1)
    _report(evaluate_dpa(config, settings))


# --------------------------------------------------------------------------------------------
# the engine
# --------------------------------------------------------------------------------------------


@dataclass
class SweepResult:
    """What :func:`run_sweep` returns.

    Attributes:
        rows: one dict per trial: its grid point (config keys), its metrics, ``trial_id`` and
            ``status`` (``"done"``, ``"error"`` or ``"unfinished"``; ``error`` holds the first
            line of the trial's error).
        path: the experiment folder (``storage_path / name``; pass it back with ``resume``).
        seconds: wall time of the run (Ray start-up included).
    """

    rows: list[dict[str, Any]]
    path: Path
    seconds: float

    @property
    def errors(self) -> int:
        """Number of trials that ended with an error."""
        return sum(row["status"] == "error" for row in self.rows)

    @property
    def done(self) -> int:
        """Number of finished trials."""
        return sum(row["status"] == "done" for row in self.rows)


def _flatten(config: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flatten(value, name + "/"))
        else:
            out[name] = value
    return out


def _rows(results: Any) -> list[dict[str, Any]]:
    rows = []
    for result in results:
        metrics = dict(result.metrics or {})
        row = _flatten(result.config or {})
        row.update({k: v for k, v in metrics.items() if k not in _RAY_KEYS})
        if result.error is not None:
            status = "error"
        elif metrics.get("done") or "training_iteration" in metrics:
            status = "done"
        else:
            status = "unfinished"
        row["trial_id"] = metrics.get("trial_id") or Path(str(result.path)).name.split("_")[1]
        row["status"] = status
        if result.error is not None:
            text = str(result.error).strip().splitlines()
            row["error"] = text[-1] if text else type(result.error).__name__
        rows.append(row)
    rows.sort(key=lambda r: str(r["trial_id"]))
    return rows


def _resources(cpus_per_trial: float) -> float:
    return check_number("cpus_per_trial", cpus_per_trial, low=0.0, low_inclusive=False)


def run_sweep(
    trainable: Callable[..., Any],
    param_space: Mapping[str, Any] | None,
    path: str | os.PathLike,
    *,
    settings: Any = None,
    resume: bool = False,
    address: str | None = None,
    num_cpus: int | None = None,
    cpus_per_trial: float = 1.0,
    max_concurrent: int | None = None,
    quiet: bool = False,
) -> SweepResult:
    """Run (or resume) a grid sweep on Ray Tune and return one row per trial.

    Args:
        trainable: a function trainable ``f(config, settings)`` that reports its metrics once
            (:func:`dpa_trial`, :func:`hocnet.learn.sweep.train_trial`, or your own); the Ray
            workers must be able to load it (a module-level function of an installed package,
            or a closure, which Ray ships by value).
        param_space: the grid (``{name: tune.grid_search([...])}``, e.g.
            :func:`dpa_param_space`); ignored with ``resume`` (the stored one is used).
        path: the experiment folder; its parent is Ray's ``storage_path`` (made absolute, as
            Ray requires) and its name the experiment's name.
        settings: passed to every trial as ``settings=`` (``tune.with_parameters``); give the
            same ones when resuming.
        resume: continue the experiment in ``path`` (``Tuner.restore``): finished trials are
            kept as they are and not rerun, errored trials are restarted from scratch and
            unfinished ones resumed.
        address: join a running Ray cluster (``ray.init(address=...)``: ``"auto"``, the GCS
            address ``"host:6379"`` or a client address ``"ray://host:10001"``); ``None``
            starts an embedded local instance when none is running in this process (and shuts
            it down afterwards). Ray 2.5x clusters may use token authentication: the client
            then needs the cluster's token (``RAY_AUTH_TOKEN``, see Ray's docs).
        num_cpus: CPUs of an embedded local instance (``None``: all of the machine's).
        cpus_per_trial: CPUs reserved per trial (Ray runs ``num_cpus / cpus_per_trial`` trials
            at a time).
        max_concurrent: at most this many trials at a time (``None``: as resources allow).
        quiet: no progress table and no worker logs (``verbose=0``, ``log_to_driver=False``).

    Returns:
        A :class:`SweepResult`.

    Raises:
        RayMissingError: without Ray Tune.
        ValueError: ``resume`` of a folder that holds no experiment, or a new sweep in a
            folder that already holds one.
    """
    ray, tune = require_ray()
    start = time.perf_counter()
    folder = Path(path).absolute()
    cpus = _resources(cpus_per_trial)
    if num_cpus is not None:
        num_cpus = check_int("num_cpus", num_cpus, minimum=1)
    if max_concurrent is not None:
        max_concurrent = check_int("max_concurrent", max_concurrent, minimum=1)
    stored = folder.is_dir() and any(folder.glob("experiment_state*.json"))
    if resume and not stored:
        raise ValueError(f"`path`: expected an experiment folder to resume, got '{folder}'")
    if not resume and folder.exists():
        raise ValueError(f"`path`: expected a new experiment folder, got the existing '{folder}'")
    started = False
    if not ray.is_initialized():
        import logging

        options: dict[str, Any] = {
            "include_dashboard": False,
            "logging_level": logging.ERROR if quiet else logging.WARNING,
            "log_to_driver": not quiet,
        }
        if address is not None:
            options["address"] = address
        elif num_cpus is not None:
            options["num_cpus"] = num_cpus
        ray.init(**options)
        started = True
    try:
        wrapped = tune.with_resources(
            tune.with_parameters(trainable, settings=settings), {"cpu": cpus}
        )
        if resume:
            tuner = tune.Tuner.restore(
                str(folder), wrapped, resume_unfinished=True, restart_errored=True
            )
        else:
            tuner = tune.Tuner(
                wrapped,
                param_space=dict(param_space or {}),
                tune_config=tune.TuneConfig(
                    max_concurrent_trials=max_concurrent, reuse_actors=True
                ),
                run_config=tune.RunConfig(
                    name=folder.name,
                    storage_path=str(folder.parent),
                    verbose=0 if quiet else 1,
                    failure_config=tune.FailureConfig(max_failures=0),
                ),
            )
        previous = os.environ.get("RAY_AIR_NEW_OUTPUT")
        if quiet:  # the new output engine prints its configuration box even at verbose=0
            os.environ["RAY_AIR_NEW_OUTPUT"] = "0"
        try:
            results = tuner.fit()
        finally:
            if quiet and previous is None:
                os.environ.pop("RAY_AIR_NEW_OUTPUT", None)
            elif quiet:
                os.environ["RAY_AIR_NEW_OUTPUT"] = previous
        rows = _rows(results)
    finally:
        if started:
            ray.shutdown()
    return SweepResult(rows=rows, path=folder, seconds=time.perf_counter() - start)


def write_rows_csv(rows: Sequence[Mapping[str, Any]], path: str | os.PathLike) -> Path:
    """Write rows (the union of their keys, first-seen order) to a CSV file; return its path.

    Floats are written with 6 significant digits; NaN as ``nan``; missing cells empty.

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     out = write_rows_csv([{"b": 0.8, "a_s": 1.5}, {"b": 1.0}], Path(tmp) / "r.csv")
        ...     out.read_text().splitlines()
        ['b,a_s', '0.8,1.5', '1,']
    """
    fields: list[str] = []
    for row in rows:
        fields.extend(k for k in row if k not in fields)
    out = Path(path)
    with open(out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.6g}" if isinstance(v, float) else v for k, v in row.items()})
    return out

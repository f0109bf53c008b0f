"""Training runs over configs on Ray Tune: one Lightning fit + test per grid point (our addition).

The trial of ``hocnet sweep train``; the engine (:func:`hocnet.sweep.run_sweep`) and the DPA grids
are in :mod:`hocnet.sweep`, which needs no Lightning.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import lightning as L
import torch

from hocnet._check import check_choice, check_int
from hocnet.learn.train import SYSTEMS
from hocnet.sweep import _report, require_ray

__all__ = [
    "TrainSweepSettings",
    "check_train_config",
    "train_metrics",
    "train_param_space",
    "train_trial",
]


@dataclass(frozen=True)
class TrainSweepSettings:
    """The fixed part of a training sweep.

    Args:
        system: ``"dpa"`` (:class:`~hocnet.learn.DPATuner` on
            :class:`~hocnet.learn.IRSceneDataModule`) or ``"hoc"``
            (:class:`~hocnet.learn.LearnedHOCSystem` on
            :class:`~hocnet.learn.BinarySceneDataModule`), as ``hocnet train``.
        max_epochs: training epochs per trial.
        fixed: ``"model.NAME"`` / ``"data.NAME"`` -> value, the same in every trial.
        seed: ``lightning.seed_everything`` seed of every trial.
        fast_dev_run: one batch of fit and test only (smoke runs).

    Examples:
        >>> TrainSweepSettings("dpa", max_epochs=1, fixed={"data.n_train": 4}).system
        'dpa'
    """

    system: str = "dpa"
    max_epochs: int = 1
    fixed: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0
    fast_dev_run: bool = False

    def __post_init__(self) -> None:
        check_choice("system", self.system, ("dpa", "hoc"))
        check_int("max_epochs", self.max_epochs, minimum=1)
        check_int("seed", self.seed, minimum=0)
        object.__setattr__(self, "fixed", dict(self.fixed))
        _check_train_keys(self.fixed)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (``TrainSweepSettings(**d)`` rebuilds it)."""
        return {**asdict(self), "fixed": dict(self.fixed)}


def _check_train_keys(values: Mapping[str, Any]) -> None:
    for key in values:
        if not isinstance(key, str) or key.split(".", 1)[0] not in ("model", "data"):
            raise ValueError(f"`grid`: expected keys 'model.NAME' or 'data.NAME', got {key!r}")


def train_param_space(grid: Mapping[str, Sequence[Any]]) -> dict[str, Any]:
    """A Ray Tune ``param_space`` for :func:`train_trial` from ``{"model.lr": [...], ...}``.

    Raises:
        RayMissingError: without Ray Tune.
        ValueError: a key that is not ``model.NAME`` / ``data.NAME``, or an empty axis.
    """
    _check_train_keys(grid)
    for key, values in grid.items():
        if len(values) == 0:
            raise ValueError(f"`{key}`: expected at least one value, got none")
    _, tune = require_ray()
    return {key: tune.grid_search(list(values)) for key, values in grid.items()}


def _build(config: Mapping[str, Any], settings: TrainSweepSettings) -> tuple[Any, Any]:
    """The system and data module of one grid point (``model.*`` / ``data.*`` arguments)."""
    values = {**settings.fixed, **config}
    _check_train_keys(values)
    model = {k[6:]: v for k, v in values.items() if k.startswith("model.")}
    data = {k[5:]: v for k, v in values.items() if k.startswith("data.")}
    system_cls, data_cls = SYSTEMS[settings.system]
    for name, cls, kwargs in (("model", system_cls, model), ("data", data_cls, data)):
        known = inspect.signature(cls.__init__).parameters
        for key in kwargs:
            if key not in known or key == "self":
                raise ValueError(
                    f"`grid`: expected {name}.NAME with NAME an argument of {cls.__name__}, "
                    f"got {name}.{key}"
                )
    return system_cls(**model), data_cls(**data)


def check_train_config(config: Mapping[str, Any], settings: TrainSweepSettings) -> None:
    """Build one grid point's system and data module (cheap: no scenes, no training).

    Raises:
        TypeError, ValueError: an unknown option or a bad value, before any trial starts.
    """
    _build(config, settings)


def train_metrics(config: Mapping[str, Any], settings: TrainSweepSettings) -> dict[str, float]:
    """Fit and test one training config (Lightning, no checkpoints, no logger); its metrics.

    The system and data module of ``settings.system`` are built from ``settings.fixed``
    updated by ``config`` (``model.NAME`` -> system argument, ``data.NAME`` -> data module
    argument), trained for ``settings.max_epochs`` epochs and tested on the held-out scenes.

    Returns:
        The test metrics (``test/...``), the last validation metrics (``val/...``) and
        ``seconds``.
    """
    start = time.perf_counter()
    L.seed_everything(settings.seed, verbose=False)
    system, module = _build(config, settings)
    trainer = L.Trainer(
        max_epochs=settings.max_epochs,
        accelerator="cpu",
        devices=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        fast_dev_run=settings.fast_dev_run,
    )
    trainer.fit(system, module)
    val = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("val/")}
    tested = trainer.test(system, module, verbose=False)
    test = {k: float(v) for k, v in (tested[0] if tested else {}).items()}
    return {**val, **test, "seconds": time.perf_counter() - start}


def train_trial(config: dict[str, Any], settings: TrainSweepSettings | Mapping[str, Any]) -> None:
    """Ray Tune function trainable of a training sweep: :func:`train_metrics`, reported once."""
    if not isinstance(settings, TrainSweepSettings):
        settings = TrainSweepSettings(**settings)
    torch.set_num_threads(1)
    _report(train_metrics(config, settings))

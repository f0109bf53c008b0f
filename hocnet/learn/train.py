"""``hocnet train dpa|hoc``: fit a system on simulated scenes with Lightning's ``LightningCLI``.

``hocnet train SYSTEM [options]`` builds a :class:`lightning.pytorch.cli.LightningCLI` over the
system's ``LightningModule`` and data module (:data:`SYSTEMS`): every ``__init__`` argument of
the system is an option ``--model.NAME``, of the data module ``--data.NAME`` and of the
``Trainer`` ``--trainer.NAME`` (``--help`` lists them all, with the docstrings' help texts);
``--config FILE.yaml`` reads them from a YAML file (:func:`config_path` gives the committed
configs ``hocnet/learn/configs/dpa.yaml`` and ``hoc.yaml``), ``--print_config`` prints the
resolved configuration and exits. The run fits the system, tests it on the held-out scenes,
prints the test metrics and the last checkpoint (load it with :func:`hocnet.learn.load_model`
or ``hocnet detect --weights CKPT``). CSV logs, the checkpoints and the resolved
``config.yaml`` land under ``--trainer.default_root_dir`` (default ``runs/SYSTEM``).

The defaults (10 epochs of 32 training scenes of 8 x 32 x 32) train and test in under a
minute on the 2-core CPU of the development machine, shared with other jobs (measured with
``OMP_NUM_THREADS=1 hocnet train dpa|hoc --no-progress``, wall clock including start-up: dpa
28 s, dpa with ``--model.matrices full`` 43 s, hoc 47 s).

Short forms kept from the earlier ``argparse`` front end: ``--max-epochs N``
(``--trainer.max_epochs``), ``--out DIR`` (``--trainer.default_root_dir``), ``--seed N``
(``--seed_everything``), ``--no-progress`` (``--trainer.enable_progress_bar false``), and
space-separated values of one option (``--data.shape 6 24 24``) are read as a list.
Needs the ``learn`` extra (``lightning``, ``torchmetrics``, ``jsonargparse[signatures]``).
"""

from __future__ import annotations

import pathlib
import sys
from collections.abc import Sequence
from typing import Any

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.loggers import CSVLogger

from hocnet._check import check_choice
from hocnet.learn.datamodules import BinarySceneDataModule, IRSceneDataModule
from hocnet.learn.systems import DPATuner, LearnedHOCSystem

__all__ = [
    "CONFIG_DIR",
    "DEFAULT_EPOCHS",
    "SYSTEMS",
    "ConfigError",
    "HocnetCLI",
    "build_cli",
    "config_path",
    "expand_argv",
    "train_main",
]

SYSTEMS: dict[str, tuple[type[L.LightningModule], type[L.LightningDataModule]]] = {
    "dpa": (DPATuner, IRSceneDataModule),
    "hoc": (LearnedHOCSystem, BinarySceneDataModule),
}
#: Folder of the committed YAML configs (``dpa.yaml``, ``hoc.yaml``).
CONFIG_DIR = pathlib.Path(__file__).parent / "configs"
#: Default epochs per system (with the systems' and data modules' defaults).
DEFAULT_EPOCHS = {"dpa": 10, "hoc": 10}

_SHORT = {
    "--max-epochs": "--trainer.max_epochs",
    "--out": "--trainer.default_root_dir",
    "--seed": "--seed_everything",
}


class ConfigError(ValueError):
    """An invalid option value found while building the system, data or trainer."""


def config_path(system: str) -> pathlib.Path:
    """The committed YAML config of ``system`` (``"dpa"`` or ``"hoc"``).

    Examples:
        >>> config_path("dpa").name
        'dpa.yaml'
    """
    return CONFIG_DIR / f"{check_choice('system', system, tuple(SYSTEMS))}.yaml"


def expand_argv(argv: Sequence[str]) -> list[str]:
    """Rewrite the short forms and space-separated lists into ``LightningCLI`` arguments.

    Examples:
        >>> expand_argv(["--max-epochs", "2", "--data.shape", "6", "16", "16", "--no-progress"])
        ['--trainer.max_epochs', '2', '--data.shape', '[6,16,16]', '--trainer.enable_progress_bar', 'false']
    """  # noqa: E501
    out: list[str] = []
    items = list(argv)
    i = 0
    while i < len(items):
        arg = items[i]
        if arg == "--no-progress":
            out += ["--trainer.enable_progress_bar", "false"]
            i += 1
            continue
        if not arg.startswith("--") or "=" in arg:
            out.append(arg)
            i += 1
            continue
        values = []
        j = i + 1
        while j < len(items) and not items[j].startswith("--"):
            values.append(items[j])
            j += 1
        out.append(_SHORT.get(arg, arg))
        if len(values) > 1 and arg.startswith(("--model.", "--data.", "--trainer.")):
            out.append("[" + ",".join(values) + "]")
        else:
            out += values
        i = j
    return out


class HocnetCLI(LightningCLI):
    """``LightningCLI`` whose default logger is a ``CSVLogger`` under the run's root folder.

    ``--trainer.logger`` unset or ``true`` (the default) becomes
    ``CSVLogger(default_root_dir, name="logs")`` (CSV logs, no TensorBoard needed); ``false``
    disables logging; a logger class is used as given.
    """

    def parse_arguments(self, parser: Any, args: Any) -> None:
        """Parse ``args`` (never ``sys.argv``: ``hocnet train`` passes its own arguments)."""
        self.config = parser.parse_args(args)

    def instantiate_trainer(self, **kwargs: Any) -> L.Trainer:
        """The trainer, with the CSV logger in place of ``logger=True``."""
        config = self._get(self.config_init, "trainer", default={})
        if config.get("logger") in (None, True):
            root = config.get("default_root_dir") or "."
            kwargs["logger"] = CSVLogger(str(root), name="logs")
        return super().instantiate_trainer(**kwargs)

    def instantiate_classes(self) -> None:
        """Instantiate; an option's ``ValueError`` / ``TypeError`` becomes :class:`ConfigError`."""
        try:
            super().instantiate_classes()
        except (ValueError, TypeError) as err:
            raise ConfigError(str(err)) from err


def build_cli(system: str, argv: Sequence[str]) -> HocnetCLI:
    """Parse ``argv`` (``LightningCLI`` arguments) and instantiate ``system``'s classes.

    Args:
        system: ``"dpa"`` (:class:`DPATuner` on :class:`IRSceneDataModule`) or ``"hoc"``
            (:class:`LearnedHOCSystem` on :class:`BinarySceneDataModule`).
        argv: arguments after the system name (see the module docstring; short forms allowed).

    Returns:
        The CLI with ``.model``, ``.datamodule`` and ``.trainer`` (nothing run yet).

    Raises:
        SystemExit: ``--help``, ``--print_config``, or a parse error (message on stderr).
        ConfigError: an option value the system, the data module or the trainer refuses.
    """
    system = check_choice("system", system, tuple(SYSTEMS))
    model_cls, data_cls = SYSTEMS[system]
    defaults = {
        "accelerator": "cpu",
        "max_epochs": DEFAULT_EPOCHS[system],
        "default_root_dir": f"runs/{system}",
        "log_every_n_steps": 1,
        "callbacks": [ModelCheckpoint(save_last=True)],
    }
    return HocnetCLI(
        model_cls,
        data_cls,
        trainer_defaults=defaults,
        seed_everything_default=0,
        save_config_kwargs={"overwrite": True},
        parser_kwargs={"prog": f"hocnet train {system}"},
        args=expand_argv(argv),
        run=False,
        auto_configure_optimizers=False,
    )


_USAGE = """\
usage: hocnet train {{dpa,hoc}} [--config FILE.yaml] [--print_config] [--model.NAME V] ...

Train the DPA's parameters (dpa: b, g, p, penalty or the full matrices of [NR08]) or the HOC
network's kernels (hoc, [LA98]) on simulated scenes with Lightning, then test on held-out
scenes. `hocnet train dpa --help` lists every option (model, data, trainer).

systems:
  dpa   DPATuner on IRSceneDataModule
  hoc   LearnedHOCSystem on BinarySceneDataModule

configs: {configs}
"""


def train_main(argv: Sequence[str]) -> int:
    """Run ``hocnet train`` with ``argv`` (without the ``train`` word); returns the exit code.

    Fits, tests, prints ``name = value`` per test metric and ``checkpoint: PATH``.

    Raises:
        SystemExit: ``--help``, ``--print_config`` or a parse error.
        ConfigError: an invalid option value (the message names the argument).

    Examples:
        >>> train_main(["dpa", "--help"])  # doctest: +SKIP
    """
    argv = list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_USAGE.format(configs=CONFIG_DIR), end="")
        return 0
    if argv[0] not in SYSTEMS:
        print(
            f"hocnet train: error: expected a system {' or '.join(SYSTEMS)}, got {argv[0]!r}",
            file=sys.stderr,
        )
        return 2
    cli = build_cli(argv[0], argv[1:])
    trainer, model, data = cli.trainer, cli.model, cli.datamodule
    trainer.fit(model, data)
    results = trainer.test(model, data, verbose=False)
    for key, value in sorted((results[0] if results else {}).items()):
        print(f"{key} = {value:.6g}")
    checkpoint = trainer.checkpoint_callback
    path = ""
    if isinstance(checkpoint, ModelCheckpoint):
        path = checkpoint.last_model_path or checkpoint.best_model_path
    print(f"checkpoint: {path or 'none (fast_dev_run or checkpointing off)'}")
    return 0

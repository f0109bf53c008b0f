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
(``--seed_everything``), ``--no-progress`` or ``-q`` (``--trainer.enable_progress_bar false``),
and space-separated values of one option (``--data.shape 6 24 24``) are read as a list.
The progress bar is off by default when stderr is not a terminal (logs, pipes):
``--trainer.enable_progress_bar`` is ``null`` (auto) unless given.

Errors (our addition over ``LightningCLI``'s): every parse or value error is a :class:`ConfigError`
of one line naming the flag (``--model.lr: expected a finite number, got nan``), raised before
anything is written and before the line ``Seed set to N``; ``--out`` must be a folder,
``--data.n_train`` and ``--data.n_test`` at least 1, ``--trainer.max_epochs`` / ``max_steps`` /
``limit_train_batches`` not 0. A run that fails while training removes the files it created
(earlier runs' versions are kept; an interrupted run keeps its checkpoints).
Needs the ``learn`` extra (``lightning``, ``torchmetrics``, ``jsonargparse[signatures]``).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import pathlib
import re
import shutil
import sys
from collections.abc import Sequence
from typing import Any

import lightning as L
from jsonargparse import DefaultHelpFormatter
from lightning.fabric.utilities.exceptions import MisconfigurationException
from lightning.fabric.utilities.seed import seed_everything
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
    "parse_error_message",
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
_NO_PROGRESS = ("--no-progress", "-q")
_SHORT_HELP = """\
short forms of hocnet train:
  --out DIR          = --trainer.default_root_dir (logs, checkpoints, config.yaml)
  --max-epochs N     = --trainer.max_epochs
  --seed N           = --seed_everything
  --no-progress, -q  = --trainer.enable_progress_bar false (off anyway when stderr is
                       not a terminal)
  --data.shape 6 24 24: space-separated values of one option are read as a list
"""


class ConfigError(ValueError):
    """An invalid option: one line naming the flag (``--model.lr: expected ...``)."""


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
        if arg in _NO_PROGRESS:
            out += ["--trainer.enable_progress_bar", "false"]
            i += 1
            continue
        if not arg.startswith("--") or "=" in arg:
            out.append(arg)
            i += 1
            continue
        values = []
        j = i + 1
        while j < len(items) and not items[j].startswith("--") and items[j] not in _NO_PROGRESS:
            values.append(items[j])
            j += 1
        out.append(_SHORT.get(arg, arg))
        if len(values) > 1 and arg.startswith(("--model.", "--data.", "--trainer.")):
            out.append("[" + ",".join(values) + "]")
        else:
            out += values
        i = j
    return out


# --------------------------------------------------------------------------------------------
# one-line errors naming the flag
# --------------------------------------------------------------------------------------------

_TYPE_WORDS = {
    "int": "an integer",
    "float": "a number",
    "bool": "true or false",
    "NoneType": "null",
    "str": "a string",
    "Sequence": "a list",
    "Iterable": "a list",
    "list": "a list",
}


def _one_line(message: str) -> str:
    return " ".join(str(message).split()) or "unknown error"


def _type_words(text: str) -> str:
    """``"<class 'float'>"`` -> ``"a number"``; ``"tuple with 3 elements"`` -> ``"3 values"``."""
    text = text.strip().rstrip(".")
    match = re.fullmatch(r"<class '(?:[\w.]+\.)?(\w+)'>", text)
    if match:
        return _TYPE_WORDS.get(match.group(1), match.group(1))
    text = re.sub(r"^(?:a |an )?tuple with (\d+) elements$", r"\1 values", text)
    return re.sub(r"<class '(?:[\w.]+\.)?(\w+)'>", r"\1", text)


def _relative(path: str) -> str:
    """``path`` relative to the working folder when it lies inside it."""
    try:
        rel = os.path.relpath(path)
    except ValueError:
        return path
    return path if rel.startswith("..") else rel


def _nonfinite(text: str) -> bool:
    try:
        return not math.isfinite(float(text))
    except ValueError:
        return False


def parse_error_message(message: str, short: dict[str, str] | None = None) -> str:
    r"""One line naming the flag from a ``jsonargparse`` parse error.

    ``Parser key "X": ...`` becomes ``--X: ...`` (or the short form in ``short``, such as
    ``{"seed_everything": "--seed"}``, when the user typed it), the type names become words.

    Examples:
        >>> parse_error_message('Parser key "model.lr":\n  Expected a <class \'float\'>. Got value: nan')
        '--model.lr: expected a finite number, got nan'
        >>> parse_error_message('Parser key "data.shape":\n  Expected a tuple with 3 elements. Got value: [8, 32]')
        '--data.shape: expected 3 values, got [8, 32]'
    """  # noqa: E501
    match = re.match(r'Parser key "([^"]+)":\s*(.*)', message, re.S)
    if match is None:
        argument = re.match(r"argument (\S+): (.*)", message, re.S)
        if argument is not None:
            return _one_line(f"{argument.group(1)}: {argument.group(2)}")
        return _one_line(message)
    key, rest = match.groups()
    flag = (short or {}).get(key, f"--{key}")
    missing = re.match(r"File does not exist: '(.*)'", rest)
    if missing is not None:
        return f"{flag}: file '{_relative(missing.group(1))}' does not exist"
    given = re.search(r"(?:Got value|Given value): (.*)$", rest, re.M)
    expected = re.findall(r"Expected (?:an? )?(.+?)(?:\. Got value:.*)?$", rest, re.M)
    words = list(dict.fromkeys(_type_words(e) for e in expected))
    if words and given is not None:
        value = given.group(1).strip()
        if "a number" in words and _nonfinite(value):
            return f"{flag}: expected a finite number, got {value}"
        return _one_line(f"{flag}: expected {' or '.join(words)}, got {value}")
    return _one_line(f"{flag}: {rest}")


def _named(err: BaseException, classes: dict[str, type]) -> str:
    """The message of ``err`` with its backquoted argument names as flags ``--PREFIX.NAME``.

    The class is the outermost ``__init__`` among ``classes`` in the traceback.
    """
    prefix = None
    tb = err.__traceback__
    while tb is not None and prefix is None:
        owner = tb.tb_frame.f_locals.get("self")
        prefix = next((p for p, cls in classes.items() if isinstance(owner, cls)), None)
        tb = tb.tb_next
    message = _one_line(str(err) or type(err).__name__)
    if prefix is None:
        return message
    import inspect

    names = set(inspect.signature(classes[prefix].__init__).parameters) - {"self"}

    def swap(match: re.Match[str]) -> str:
        name = match.group(1)
        return f"--{prefix}.{name}" if name in names else match.group(0)

    return re.sub(r"`(\w+)`", swap, message)


# --------------------------------------------------------------------------------------------
# the CLI
# --------------------------------------------------------------------------------------------


class HocnetCLI(LightningCLI):
    """``LightningCLI`` with the CSV logger, up-front checks and one-line errors.

    * ``--trainer.logger`` unset or ``true`` (the default) becomes
      ``CSVLogger(default_root_dir, name="logs")`` (CSV logs, no TensorBoard needed); ``false``
      disables logging; a logger class is used as given.
    * After parsing and before the seed is set or anything is built (our addition): ``--out``
      (``--trainer.default_root_dir``) must be a folder or creatable, ``--data.n_train`` and
      ``--data.n_test`` at least 1, ``--trainer.max_epochs`` / ``max_steps`` /
      ``limit_train_batches`` not 0;
      a value refused by the system, the data module or the trainer becomes a
      :class:`ConfigError` naming the flag. The line ``Seed set to N`` is logged only once every
      class is built.
    """

    def __init__(self, *args: Any, short_used: dict[str, str] | None = None, **kwargs: Any):
        """``LightningCLI(*args, **kwargs)`` remembering the short forms typed.

        ``short_used`` maps a key typed in a short form to it (``{"trainer.max_epochs":
        "--max-epochs"}``), for the error messages.
        """
        self.short_used = dict(short_used or {})
        super().__init__(*args, **kwargs)

    def parse_arguments(self, parser: Any, args: Any) -> None:
        """Parse ``args`` (never ``sys.argv``: ``hocnet train`` passes its own arguments)."""
        self.config = parser.parse_args(args)

    def _flag(self, key: str) -> str:
        return self.short_used.get(key, f"--{key}")

    def check_config(self) -> None:
        """The up-front checks of the class docstring; raises :class:`ConfigError`."""
        get = self.config.get
        for key in ("trainer.max_epochs", "trainer.max_steps"):
            if get(key) == 0:
                raise ConfigError(
                    f"{self._flag(key)}: expected at least 1 (or -1 for no limit), got 0: "
                    "nothing would be trained"
                )
        key = "trainer.limit_train_batches"
        if get(key) == 0:
            raise ConfigError(f"--{key}: expected > 0, got {get(key)}: nothing would be trained")
        for split, why in (("train", "scenes to train on"), ("test", "held-out scenes to test on")):
            key = f"data.n_{split}"
            value = get(key)
            if isinstance(value, int) and value < 1:
                raise ConfigError(
                    f"{self._flag(key)}: expected an integer >= 1 ({why}), got {value}"
                )
        root = get("trainer.default_root_dir")
        if root is not None:
            _check_root(str(root), self._flag("trainer.default_root_dir"))

    def _set_seed(self) -> None:
        """Check the configuration, then seed silently (logged after the classes are built)."""
        self.check_config()
        seed = self.config.get("seed_everything")
        self._seed: int | None = None
        if seed is False:
            return
        self._seed = seed_everything(None if seed is True else seed, workers=True, verbose=False)
        self.config["seed_everything"] = self._seed

    def instantiate_trainer(self, **kwargs: Any) -> L.Trainer:
        """The trainer, with the CSV logger in place of ``logger=True``.

        ``--trainer.enable_progress_bar null`` (the default) shows the progress bar only when
        stderr is a terminal. A ``ModelCheckpoint(save_last=True)`` is added unless
        ``--trainer.enable_checkpointing false``, ``--trainer.fast_dev_run`` or a
        ``ModelCheckpoint`` in ``--trainer.callbacks``.
        """
        config = self._get(self.config_init, "trainer", default={})
        if config.get("logger") in (None, True):
            root = config.get("default_root_dir") or "."
            kwargs["logger"] = CSVLogger(str(root), name="logs")
        if config.get("enable_progress_bar") is None:  # progress bars only on a terminal
            kwargs["enable_progress_bar"] = _stderr_is_tty()
        callbacks = config.get("callbacks") or []
        callbacks = list(callbacks) if isinstance(callbacks, list | tuple) else [callbacks]
        wanted = config.get("enable_checkpointing") is not False and not config.get("fast_dev_run")
        if wanted and not any(isinstance(c, ModelCheckpoint) for c in callbacks):
            kwargs["callbacks"] = [*callbacks, ModelCheckpoint(save_last=True)]
        return super().instantiate_trainer(**kwargs)

    def instantiate_classes(self) -> None:
        """Instantiate; a refused value becomes :class:`ConfigError` naming the flag."""
        model_cls, data_cls = self._model_class, self._datamodule_class
        try:
            super().instantiate_classes()
        except (ValueError, TypeError, MisconfigurationException) as err:
            classes = {"model": model_cls, "data": data_cls, "trainer": L.Trainer}
            raise ConfigError(_named(err, classes)) from err

    def after_instantiate_classes(self) -> None:
        """Log ``Seed set to N`` (as Lightning does) now that the arguments are valid."""
        if self._seed is not None:
            logging.getLogger("lightning.fabric.utilities.seed").info(f"Seed set to {self._seed}")


def _check_root(root: str, flag: str) -> None:
    """``root`` must be a writable folder, or creatable (no file on its path)."""
    path = pathlib.Path(root)
    if not root.strip():
        raise ConfigError(f"{flag}: expected a folder name, got an empty string")
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag}: '{root}' is a file, expected a folder")
    if path.is_dir():
        if not os.access(path, os.W_OK | os.X_OK):
            raise ConfigError(f"{flag}: cannot write into '{root}': it is not writable")
        return
    for parent in path.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise ConfigError(
                    f"{flag}: '{_relative(str(parent))}' is a file, cannot create '{root}' in it"
                )
            if not os.access(parent, os.W_OK | os.X_OK):
                raise ConfigError(f"{flag}: cannot create '{root}': '{parent}' is not writable")
            return


class _HelpFormatter(DefaultHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """``jsonargparse``'s help layout, keeping the line breaks of the epilog (short forms)."""


def _stderr_is_tty() -> bool:
    isatty = getattr(sys.stderr, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # closed stream
        return False


def build_cli(system: str, argv: Sequence[str]) -> HocnetCLI:
    """Parse ``argv`` (``LightningCLI`` arguments) and instantiate ``system``'s classes.

    Args:
        system: ``"dpa"`` (:class:`DPATuner` on :class:`IRSceneDataModule`) or ``"hoc"``
            (:class:`LearnedHOCSystem` on :class:`BinarySceneDataModule`).
        argv: arguments after the system name (see the module docstring; short forms allowed).

    Returns:
        The CLI with ``.model``, ``.datamodule`` and ``.trainer`` (nothing run yet).

    Raises:
        SystemExit: ``--help`` or ``--print_config`` (exit code 0).
        ConfigError: a parse error or an option value the checks, the system, the data module
            or the trainer refuse (one line naming the flag, nothing written).
    """
    system = check_choice("system", system, tuple(SYSTEMS))
    model_cls, data_cls = SYSTEMS[system]
    defaults = {
        "accelerator": "cpu",
        "max_epochs": DEFAULT_EPOCHS[system],
        "default_root_dir": f"runs/{system}",
        "log_every_n_steps": 1,
        "enable_progress_bar": None,  # null: only when stderr is a terminal (instantiate_trainer)
    }
    short_used = {
        _SHORT[a].removeprefix("--"): a.split("=")[0] for a in argv if a.split("=")[0] in _SHORT
    }
    try:
        return HocnetCLI(
            model_cls,
            data_cls,
            trainer_defaults=defaults,
            seed_everything_default=0,
            save_config_kwargs={"overwrite": True},
            parser_kwargs={
                "prog": f"hocnet train {system}",
                "exit_on_error": False,
                "epilog": _SHORT_HELP,
                "formatter_class": _HelpFormatter,
            },
            args=expand_argv(argv),
            run=False,
            auto_configure_optimizers=False,
            short_used=short_used,
        )
    except argparse.ArgumentError as err:
        message = parse_error_message(str(err), short_used)
        if message.startswith("unrecognized arguments"):
            message += f" (see 'hocnet train {system} --help')"
        raise ConfigError(message) from None


_USAGE = """\
usage: hocnet train {{dpa,hoc}} [--config FILE.yaml] [--print_config] [--model.NAME V] ...

Train the DPA's parameters (dpa: b, g, p, penalty or the full matrices of [NR08]) or the HOC
network's kernels (hoc, [LA98]) on simulated scenes with Lightning, then test on held-out
scenes. `hocnet train dpa --help` (or `hocnet train hoc --help`) lists every option (model,
data, trainer) and the short forms (--out DIR, --max-epochs N, --seed N, --no-progress / -q).

systems:
  dpa   DPATuner on IRSceneDataModule
  hoc   LearnedHOCSystem on BinarySceneDataModule

configs: {configs}
"""


def _walk(root: pathlib.Path) -> set[pathlib.Path]:
    """Every file and folder under ``root`` (empty when it does not exist)."""
    found: set[pathlib.Path] = set()
    for folder, dirs, files in os.walk(root):
        found.update(pathlib.Path(folder) / name for name in (*dirs, *files))
    return found


def _remove_created(root: pathlib.Path, before: set[pathlib.Path]) -> None:
    """Remove the files and folders under ``root`` that are not in ``before``."""
    for path in sorted(_walk(root) - before, key=lambda p: len(p.parts)):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        elif path.exists() or path.is_symlink():
            path.unlink(missing_ok=True)


def _first_created(root: pathlib.Path) -> pathlib.Path | None:
    """The outermost folder of ``root``'s path that does not exist yet (None if root exists)."""
    created = None
    for folder in [root.absolute(), *root.absolute().parents]:
        if folder.exists():
            break
        created = folder
    return created


def _no_checkpoint_reason(trainer: L.Trainer) -> str:
    if trainer.fast_dev_run:
        return "fast_dev_run saves no checkpoint"
    if not isinstance(trainer.checkpoint_callback, ModelCheckpoint):
        return "checkpointing off: --trainer.enable_checkpointing false"
    return "no training step ran; see --trainer.max_time"


def train_main(argv: Sequence[str]) -> int:
    """Run ``hocnet train`` with ``argv`` (without the ``train`` word); returns the exit code.

    Fits, tests, prints ``name = value`` per test metric and ``checkpoint: PATH``. A failure
    while fitting or testing removes the files this run created under ``--out`` (the logger's
    new ``logs/version_N``, new checkpoints; earlier runs are kept) and re-raises.

    Raises:
        SystemExit: ``--help`` or ``--print_config`` (exit code 0).
        ConfigError: no or an unknown system, a parse error or an invalid option value (one
            line naming the flag; raised before anything is written).

    Examples:
        >>> train_main(["--help"])  # doctest: +ELLIPSIS
        usage: hocnet train {dpa,hoc} ...
        0
    """
    argv = list(argv)
    if argv and argv[0] in ("-h", "--help"):
        print(_USAGE.format(configs=CONFIG_DIR), end="")
        return 0
    if not argv or argv[0] not in SYSTEMS:
        got = f"got {argv[0]!r}" if argv else "got none"
        raise ConfigError(
            f"expected a system {' or '.join(SYSTEMS)} first, {got} (see 'hocnet train --help')"
        )
    cli = build_cli(argv[0], argv[1:])
    trainer, model, data = cli.trainer, cli.model, cli.datamodule
    root = pathlib.Path(str(trainer.default_root_dir))
    created = _first_created(root)
    before = _walk(root) if created is None else set()
    try:
        trainer.fit(model, data)
        results = trainer.test(model, data, verbose=False)
    except Exception:
        if created is not None:
            shutil.rmtree(created, ignore_errors=True)
        else:
            _remove_created(root, before)
        raise
    for key, value in sorted((results[0] if results else {}).items()):
        print(f"{key} = {value:.6g}")
    checkpoint = trainer.checkpoint_callback
    path = ""
    if isinstance(checkpoint, ModelCheckpoint):
        path = checkpoint.last_model_path or checkpoint.best_model_path
    print(f"checkpoint: {path or 'none (' + _no_checkpoint_reason(trainer) + ')'}")
    return 0

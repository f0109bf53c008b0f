"""``hocnet train dpa|hoc``: fit a system on simulated scenes, test it, keep the checkpoint.

A plain ``argparse`` front end over the systems (LightningCLI needs ``jsonargparse``, which is not
a dependency): every ``__init__`` argument of the system is an option ``--model.NAME`` and every
argument of its data module an option ``--data.NAME`` (``--help`` lists them with their
defaults); ``--max-epochs``, ``--out`` and ``--seed`` control the run. The run writes CSV logs
and the last checkpoint under ``OUT``, prints the test metrics and the checkpoint path (load it
with :func:`hocnet.learn.load_model`).
"""

from __future__ import annotations

import argparse
import inspect
import pathlib
from collections.abc import Sequence
from typing import Any

import lightning as L

from hocnet.learn.datamodules import BinarySceneDataModule, IRSceneDataModule
from hocnet.learn.systems import DPATuner, LearnedHOCSystem

__all__ = ["SYSTEMS", "build_parser", "train_main"]

SYSTEMS: dict[str, tuple[type[L.LightningModule], type[L.LightningDataModule]]] = {
    "dpa": (DPATuner, IRSceneDataModule),
    "hoc": (LearnedHOCSystem, BinarySceneDataModule),
}


def _number_or_none(text: str) -> float | None:
    return None if text.lower() == "none" else float(text)


def _bool(text: str) -> bool:
    if text.lower() in ("1", "true", "yes"):
        return True
    if text.lower() in ("0", "false", "no"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def _add_options(group: argparse._ArgumentGroup, prefix: str, cls: type) -> None:
    """One option ``--prefix.NAME`` per ``__init__`` argument of ``cls``, typed by its default."""
    for name, param in inspect.signature(cls.__init__).parameters.items():
        if name == "self" or param.default is inspect.Parameter.empty:
            continue
        default = param.default
        kwargs: dict[str, Any] = {"default": default, "dest": f"{prefix}.{name}"}
        if isinstance(default, bool):
            kwargs["type"] = _bool
        elif isinstance(default, (tuple, list)):
            kwargs["nargs"] = "+"
            first = default[0] if default else ""
            kwargs["type"] = type(first) if isinstance(first, (int, float)) else str
        elif default is None:
            kwargs["type"] = _number_or_none
        else:
            kwargs["type"] = type(default)
        shown = f"{default:.6g}" if isinstance(default, float) else repr(default)
        group.add_argument(f"--{prefix}.{name}", help=f"default {shown}", **kwargs)


def build_parser() -> argparse.ArgumentParser:
    """The ``hocnet train`` parser: one sub-command per system (``dpa``, ``hoc``)."""
    parser = argparse.ArgumentParser(
        prog="hocnet train",
        description="Train the DPA's parameters (dpa) or the HOC network's kernels (hoc) on "
        "simulated scenes, then test on held-out scenes.",
    )
    sub = parser.add_subparsers(dest="system", required=True)
    for key, (system, data) in SYSTEMS.items():
        p = sub.add_parser(key, help=f"{system.__name__} on {data.__name__}")
        p.add_argument("--max-epochs", type=int, default=10, help="training epochs (default 10)")
        p.add_argument("--out", default=f"runs/{key}", help="log and checkpoint folder")
        p.add_argument("--seed", type=int, default=0, help="lightning.seed_everything seed")
        p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
        _add_options(p.add_argument_group("model"), "model", system)
        _add_options(p.add_argument_group("data"), "data", data)
    return parser


def _collect(args: argparse.Namespace, prefix: str) -> dict[str, Any]:
    out = {}
    for key, value in vars(args).items():
        if key.startswith(prefix + "."):
            out[key[len(prefix) + 1 :]] = tuple(value) if isinstance(value, list) else value
    return out


def train_main(argv: Sequence[str]) -> int:
    """Run ``hocnet train`` with ``argv`` (without the ``train`` word); returns the exit code.

    Examples:
        >>> train_main(["dpa", "--help"])  # doctest: +SKIP
    """
    args = build_parser().parse_args(list(argv))
    system_cls, data_cls = SYSTEMS[args.system]
    L.seed_everything(args.seed, verbose=False)
    model_kwargs = _collect(args, "model")
    system = system_cls(**model_kwargs)
    data = data_cls(**_collect(args, "data"))
    out = pathlib.Path(args.out)
    checkpoint = L.pytorch.callbacks.ModelCheckpoint(dirpath=out / "checkpoints", save_last=True)
    trainer = L.Trainer(
        max_epochs=args.max_epochs,
        accelerator="cpu",
        default_root_dir=str(out),
        logger=L.pytorch.loggers.CSVLogger(str(out), name="logs"),
        callbacks=[checkpoint],
        enable_progress_bar=not args.no_progress,
        log_every_n_steps=1,
    )
    trainer.fit(system, data)
    results = trainer.test(system, data, verbose=False)
    for key, value in sorted((results[0] if results else {}).items()):
        print(f"{key} = {value:.6g}")
    print(f"checkpoint: {checkpoint.last_model_path or checkpoint.best_model_path}")
    return 0

"""``hocnet train``: train the DPA's parameters or the HOC network's kernels (Lightning)."""

from __future__ import annotations

import argparse
import importlib.util
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    pass
from hocnet.cli._common import (
    CLIError,
)


def _cmd_train(args: argparse.Namespace) -> int:
    """``hocnet train SYSTEM ...``: :func:`hocnet.learn.train.train_main` (needs Lightning)."""
    if importlib.util.find_spec("lightning") is None:
        raise CLIError(
            "train: needs the learn extra (Lightning, torchmetrics): "
            "pip install -e '.[learn]' (make test installs it)"
        )
    from hocnet.learn.train import train_main

    try:
        return train_main(args.rest or ["--help"])
    except SystemExit as exit_:  # --help, or argparse's own usage error (already printed)
        return exit_.code if isinstance(exit_.code, int) else 0


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``train`` on the ``hocnet`` subcommand parser."""
    train = commands.add_parser(
        "train",
        help="train the DPA's parameters or the HOC network's kernels (Lightning; the learn extra)",
        description="Train `dpa` (b, g, p, penalty of [NR08]'s DPA) or `hoc` (the HOC network's "
        "kernels) on simulated scenes: `hocnet train dpa --help` lists every option.",
        add_help=False,
    )
    train.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    train.set_defaults(func=_cmd_train)

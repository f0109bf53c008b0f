"""``hocnet train``: train the DPA's parameters or the HOC network's kernels (Lightning)."""

from __future__ import annotations

import argparse
import importlib.util
from typing import Any

from hocnet.cli._common import CLIError, _one_line, _Parser

#: Modules of the learn extra that ``hocnet train`` needs.
_NEEDS = ("lightning", "torchmetrics", "jsonargparse", "docstring_parser")


def _cmd_train(args: argparse.Namespace) -> int:
    """``hocnet train SYSTEM ...``: :func:`hocnet.learn.train.train_main` (LightningCLI)."""
    rest = list(args.rest)
    missing = [name for name in _NEEDS if importlib.util.find_spec(name) is None]
    if missing and rest[:1] not in (["-h"], ["--help"]):
        raise CLIError(
            f"train: needs the learn extra (Lightning, torchmetrics, jsonargparse[signatures]; "
            f"missing {', '.join(missing)}): pip install -e '.[learn]' (make test installs it)"
        )
    if missing:  # the usage text needs no Lightning
        print(_USAGE, end="")
        return 0
    from hocnet.learn.train import ConfigError, train_main

    try:
        return train_main(rest)
    except ConfigError as err:  # a parse error or a value the system, data or trainer refuses
        raise CLIError(_one_line(f"train: {err}")) from None
    except SystemExit as exit_:  # --help, --print_config (already printed)
        return exit_.code if isinstance(exit_.code, int) else 0


_USAGE = (
    "usage: hocnet train {dpa,hoc} [options]\n\n"
    "systems: dpa, hoc; `hocnet train dpa --help` lists the options (needs the learn extra).\n"
)


class _RestParser(_Parser):
    """The ``train`` parser: every argument after ``train`` goes to ``args.rest`` untouched.

    ``argparse.REMAINDER`` alone drops a leading option (``hocnet train --help`` was refused
    as an unrecognized argument); :func:`hocnet.learn.train.train_main` reads them all.
    """

    def parse_known_args(  # type: ignore[override]
        self, args: Any = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        namespace, _ = super().parse_known_args([], namespace)
        namespace.rest = list(args or [])
        return namespace, []


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``train`` on the ``hocnet`` subcommand parser."""
    train = commands.add_parser(
        "train",
        help="train the DPA's parameters or the HOC network's kernels (Lightning; the learn extra)",
        description="Train `dpa` (b, g, p, penalty or the full matrices of [NR08]'s DPA) or `hoc` "
        "(the HOC network's kernels) on simulated scenes through LightningCLI: `hocnet train dpa "
        "--help` lists every option, `--config FILE.yaml` reads them, `--print_config` shows them.",
        add_help=False,
    )
    train.__class__ = _RestParser  # the subparsers action builds the top-level parser's class
    train.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    train.set_defaults(func=_cmd_train)

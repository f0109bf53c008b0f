"""``hocnet train``: train the DPA's parameters or the HOC network's kernels (Lightning)."""

from __future__ import annotations

import argparse
import importlib.util

from hocnet.cli._common import CLIError, _one_line

#: Modules of the learn extra that ``hocnet train`` needs.
_NEEDS = ("lightning", "torchmetrics", "jsonargparse", "docstring_parser")


def _cmd_train(args: argparse.Namespace) -> int:
    """``hocnet train SYSTEM ...``: :func:`hocnet.learn.train.train_main` (LightningCLI)."""
    missing = [name for name in _NEEDS if importlib.util.find_spec(name) is None]
    if missing:
        raise CLIError(
            f"train: needs the learn extra (Lightning, torchmetrics, jsonargparse[signatures]; "
            f"missing {', '.join(missing)}): pip install -e '.[learn]' (make test installs it)"
        )
    from hocnet.learn.train import ConfigError, train_main

    try:
        return train_main(args.rest or ["--help"])
    except ConfigError as err:  # a value the system, data module or trainer refuses
        raise CLIError(_one_line(f"train: {err}")) from None
    except SystemExit as exit_:  # --help, --print_config, or a usage error (already printed)
        return exit_.code if isinstance(exit_.code, int) else 0


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
    train.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    train.set_defaults(func=_cmd_train)

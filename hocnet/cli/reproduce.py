"""``hocnet reproduce``: run one of the repository's experiment scripts."""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import hocnet

if TYPE_CHECKING:
    pass
from hocnet.cli._common import (
    EXPERIMENTS_ENV,
    CLIError,
    _check_int,
    _check_out_dir,
    _Formatter,
    _one_line,
    _show_progress,
)


@dataclass
class Experiment:
    """An experiment script found in the experiments folder."""

    name: str
    description: str
    path: Path
    run: Callable[..., Any]


def experiments_dir(override: str | os.PathLike | None = None) -> Path:
    """The experiments folder: ``override``, else ``$HOCNET_EXPERIMENTS_DIR``, else the repo's.

    The repository's folder is ``<repo>/experiments`` next to the ``hocnet`` package; it does not
    exist when hocnet is installed without the repository (then a :class:`CLIError` says so).
    """
    if override is not None:
        folder, source = Path(override), "--experiments-dir"
    elif os.environ.get(EXPERIMENTS_ENV):
        folder, source = Path(os.environ[EXPERIMENTS_ENV]), f"${EXPERIMENTS_ENV}"
    else:
        folder = Path(hocnet.__file__).resolve().parents[1] / "experiments"
        source = "the repository"
    if not folder.is_dir():
        hint = (
            " (hocnet seems to be installed without its repository; run from a clone, or set "
            f"{EXPERIMENTS_ENV})"
            if source == "the repository"
            else ""
        )
        raise CLIError(f"experiments folder '{folder}' from {source} does not exist{hint}")
    return folder


def _import_script(path: Path) -> ModuleType:
    """Import one script by file path (its folder is on ``sys.path`` while it is imported)."""
    module_name = f"_hocnet_experiments.{path.stem}"
    if module_name in sys.modules and getattr(sys.modules[module_name], "__file__", None) == str(
        path
    ):
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path.name}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(module_name, None)
        raise
    finally:
        with contextlib.suppress(ValueError):
            sys.path.remove(str(path.parent))
    return module


def _as_experiment(module: ModuleType, path: Path) -> Experiment | None:
    name = getattr(module, "NAME", None)
    run = getattr(module, "run", None)
    if not isinstance(name, str) or not callable(run):
        return None  # a helper module, not an experiment
    description = getattr(module, "DESCRIPTION", None) or (module.__doc__ or "").strip()
    return Experiment(name, " ".join(str(description).split()), path, run)


def find_experiments(folder: Path) -> tuple[list[Experiment], dict[str, str]]:
    """Import every ``*.py`` in ``folder`` not starting with ``_``.

    Returns:
        ``(experiments, failures)``: the scripts defining ``NAME`` and ``run``, sorted by name,
        and ``{file name: one-line error}`` for scripts that could not be imported.
    """
    found: list[Experiment] = []
    failures: dict[str, str] = {}
    for path in sorted(folder.glob("*.py")):
        if path.name.startswith("_"):
            continue
        try:
            module = _import_script(path)
        except Exception as err:  # a broken script must not hide the others
            failures[path.name] = _one_line(f"{type(err).__name__}: {err}")
            continue
        experiment = _as_experiment(module, path)
        if experiment is not None:
            found.append(experiment)
    return sorted(found, key=lambda e: e.name), failures


def _find_experiment(folder: Path, name: str) -> Experiment:
    # fast path: the script named after the experiment ("hoc-table2" -> hoc_table2.py)
    guess = folder / f"{name.replace('-', '_')}.py"
    if guess.is_file() and not guess.name.startswith("_"):
        with contextlib.suppress(Exception):
            experiment = _as_experiment(_import_script(guess), guess)
            if experiment is not None and experiment.name == name:
                return experiment
    experiments, failures = find_experiments(folder)
    for experiment in experiments:
        if name in (experiment.name, experiment.path.stem):
            return experiment
    available = ", ".join(e.name for e in experiments) or "none"
    broken = f"; could not import: {', '.join(failures)}" if failures else ""
    raise CLIError(
        f"unknown experiment {name!r}; available: {available}{broken} (see 'hocnet reproduce "
        "--list')"
    )


def _cmd_reproduce(args: argparse.Namespace) -> int:
    if args.list and args.name is not None:
        raise CLIError("give either NAME or --list, not both")
    if not args.list and args.name is None:
        raise CLIError("expected an experiment NAME or --list (see 'hocnet reproduce --help')")
    seeds = None if args.seeds is None else _check_int("--seeds", args.seeds, minimum=1)
    folder = experiments_dir(args.experiments_dir)
    if args.list:
        experiments, failures = find_experiments(folder)
        if not experiments and not failures:
            print(f"no experiments in {folder}")
        width = max((len(e.name) for e in experiments), default=0)
        for experiment in experiments:
            print(f"{experiment.name.ljust(width)}  {experiment.description}")
        for file_name, error in failures.items():
            print(f"{file_name}: could not import ({error})", file=sys.stderr)
        return 0
    experiment = _find_experiment(folder, args.name)
    if args.out is not None:
        out_dir = _check_out_dir(args.out)
    elif args.quick:
        # a quick (smoke) run never replaces the committed full results in experiments/results/:
        # it writes to a fresh temporary folder unless --out is given by hand
        import tempfile

        out_dir = Path(tempfile.mkdtemp(prefix=f"hocnet-{experiment.name}-quick-"))
    else:
        out_dir = None
    start = time.perf_counter()
    made = out_dir if args.quick and args.out is None else None
    try:
        written = experiment.run(
            quick=args.quick, seeds=seeds, out_dir=out_dir, progress=_show_progress(args)
        )
    finally:
        if made is not None and made.is_dir() and not any(made.iterdir()):
            made.rmdir()  # a run that wrote nothing leaves no empty temporary folder behind
    runtime = time.perf_counter() - start
    if written is None:
        raise CLIError(
            f"NAME: {experiment.name} did not run (its input data is absent; see the line above)"
        )
    note = " (quick run: the committed results were not touched)" if args.quick else ""
    print(f"{experiment.name}: done in {runtime:.1f} s; results in {written}{note}")
    return 0


# --------------------------------------------------------------------------------------------
# parser and entry point
# --------------------------------------------------------------------------------------------


_REPRODUCE_EPILOG = f"""\
Experiment scripts are the files experiments/*.py of the hocnet repository (not starting with
'_'); each defines NAME, DESCRIPTION and run(quick, seeds, out_dir, progress). The folder can be
changed with the environment variable {EXPERIMENTS_ENV}.
"""


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``reproduce`` on the ``hocnet`` subcommand parser."""
    reproduce = commands.add_parser(
        "reproduce",
        help="run an experiment script (a table or figure of the papers); --list shows them",
        description="Run one experiment of the repository's experiments/ folder, or list them.",
        epilog=_REPRODUCE_EPILOG,
        formatter_class=_Formatter,
    )
    reproduce.add_argument("name", nargs="?", metavar="NAME", help="experiment name")
    reproduce.add_argument("--list", action="store_true", help="list the experiments and exit")
    reproduce.add_argument(
        "--quick",
        action="store_true",
        help="small, fast smoke version (fewer scenes / seeds); writes to a new temporary folder "
        "unless --out is given, never over the committed experiments/results/",
    )
    reproduce.add_argument(
        "--seeds",
        type=int,
        default=None,
        metavar="N",
        help="number of seeds (default: the script's)",
    )
    reproduce.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="output folder (default: experiments/results/ for a full run, a new temporary "
        "folder for --quick)",
    )
    reproduce.add_argument("--experiments-dir", default=None, help=argparse.SUPPRESS)
    reproduce.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bars (also off when stderr is not a terminal)",
    )
    reproduce.set_defaults(func=_cmd_reproduce)

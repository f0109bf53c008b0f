"""The ``hocnet`` command line.

Subcommands (each has ``--help``), one line each:

* ``hocnet demo``: simulate a Table-III-like scene of [LA98] and an IR sequence of [NR08], run
  the HOC and the DPA, print true versus found tracks, write pictures.
* ``hocnet detect CUBE``: a detector on the user's data (``.npy`` / ``.npz``, or a folder or glob
  of PNG / BMP / TIFF frames): ``--method hoc`` on binary cubes (or intensity frames binarised
  with ``--threshold-pfa``), ``--method dpa`` on intensity frames; ``--weights CKPT`` uses the
  learned weights of ``hocnet train``; writes ``tracks.json``, ``detections.csv`` (per-frame
  candidate detections ``frame,x,y,score``), the method's cubes and a picture.
* ``hocnet reproduce NAME`` / ``hocnet reproduce --list``: run one of the repository's experiment
  scripts (``experiments/*.py``).
* ``hocnet train dpa|hoc``: train the DPA's parameters or the HOC network's kernels on simulated
  scenes through LightningCLI (the ``learn`` extra; YAML configs, ``--print_config``).
* ``hocnet sweep dpa|train``: DPA parameter grids and training runs over configs on Ray Tune
  (the ``sweep`` extra), resumable, results as CSV.
* ``hocnet track SEQ``: a detector's per-frame plots (``--detector hoc|dpa``) into the
  track-oriented MHT of [PD]; writes the confirmed tracks (``tracks.json``, ``tracks.png``).

Errors in the user's input (bad file, wrong shape, non-binary values, out-of-range option,
unknown experiment) are reported as one line ``hocnet: error: <message>`` on stderr with exit
code 2, and nothing is written: every command validates its input and finishes its computation
before it creates any output, then writes into a temporary directory next to the output directory
and renames it into place.

Detectors are registered in ``_METHODS`` (name -> options + runner); adding a method (such as the
DPA of [NR08]) means writing its ``_add_*_options`` and ``_run_*`` functions and one registry
entry. Options of a method that was not selected are rejected, so one method's flags cannot be
silently ignored by another.

Set ``HOCNET_DEBUG=1`` to get the full traceback instead of the one-line error.

Examples:
    >>> main(["--version"])  # doctest: +ELLIPSIS
    hocnet ...
    0
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

import hocnet
from hocnet.cli import demo, detect, reproduce, sweep, track, train

# Re-exported for tests and for users of the former single-module ``hocnet.cli``.
from hocnet.cli._common import (  # noqa: F401
    _FLAGS,
    DEBUG_ENV,
    EXPERIMENTS_ENV,
    PROG,
    CLIError,
    _fail,
    _flags_of,
    _Formatter,
    _Parser,
    _to_flags,
)
from hocnet.cli.detect import _METHODS, Detection, _bound_hoc, _Method  # noqa: F401
from hocnet.cli.reproduce import experiments_dir, find_experiments  # noqa: F401

__all__ = ["main"]


def build_parser() -> argparse.ArgumentParser:
    """The ``hocnet`` argument parser (exposed for documentation and tests)."""
    parser = _Parser(
        prog=PROG,
        description="Track-before-detect for dim multiple moving targets, and tracking after\n"
        "detection. Commands:\n"
        "  demo       simulate scenes of [LA98] and [NR08], run HOC and DPA, write PNGs\n"
        "  detect     your data -> tracks.json, detections.csv, PNG (--method hoc|dpa, below)\n"
        "  reproduce  run an experiment (a table or figure of the papers); --list names them\n"
        "  train      train the DPA's parameters or the HOC's kernels (LightningCLI, learn extra)\n"
        "  sweep      DPA parameter grids and training runs on Ray Tune (sweep extra)\n"
        "  track      a detector's per-frame plots into the MHT of [PD]: confirmed tracks\n"
        "Methods of detect (and detectors of track):\n"
        "  hoc  the modified high-order correlation (HOC) of [LA98] on BINARY multi-scan cubes\n"
        "       (outputs: tracks.json, detections.csv, cleaned.npy, support.npy, detection.png);\n"
        "  dpa  the dynamic-programming track-before-detect (DPA) of [NR08] on INTENSITY\n"
        "       frames such as infrared sequences (outputs: tracks.json, detections.csv,\n"
        "       asf.npy, shifts.csv, detection.png).\n"
        "Input (detect, track): .npy / .npz cubes, or folders, globs or files of PNG / BMP /\n"
        "TIFF frames.\n"
        "[LA98] Liou & Azimi-Sadjadi, IEEE TAES 34(2), 1998; [NR08] Nichtern & Rotman,\n"
        "EURASIP JASP 2008; [PD] Pannetier, Dezert et al., GMTI tracking with PCR5 type fusion.",
        epilog="Run 'hocnet COMMAND --help' for the options of each command.",
        formatter_class=_Formatter,
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {hocnet.__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    for module in (demo, detect, train, sweep, reproduce, track):
        module.add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``hocnet`` command line.

    Args:
        argv: the arguments after the program name; ``None`` uses ``sys.argv[1:]``.

    Returns:
        The exit code: 0 on success, 2 for a usage or input error (one line on stderr,
        ``hocnet: error: ...``), 130 when interrupted.

    Examples:
        >>> main(["reproduce"])
        2
    """
    parser = build_parser()
    args = None
    try:
        try:
            args, extra = parser.parse_known_args(argv)
            if extra:  # said by the command's parser: "see 'hocnet track --help'"
                _command_parser(parser, args.command).error(
                    f"unrecognized arguments: {' '.join(extra)}"
                )
        except SystemExit as exit_:  # --help / --version
            return exit_.code if isinstance(exit_.code, int) else 0
        code = int(args.func(args))
        sys.stdout.flush()  # a closed pipe is seen here, not at exit
        return code
    except BrokenPipeError:
        return _stdout_closed()
    except CLIError as err:
        return _fail(str(err), _flags_of(args))
    except (ValueError, TypeError, OSError, OverflowError) as err:
        if os.environ.get(DEBUG_ENV):
            raise
        from hocnet.data.io import is_disk_full

        if is_disk_full(err):
            where = f" '{err.filename}'" if getattr(err, "filename", None) else ""
            return _fail(f"no space left on device{where}: {err}", _flags_of(args))
        return _fail(str(err) or type(err).__name__, _flags_of(args))
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


def _command_parser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    """The parser of subcommand ``command`` (``parser`` itself if there is none)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return action.choices[command]
    return parser


def _stdout_closed() -> int:
    """The reader of stdout went away (``hocnet track ... | head -1``): exit 0, silently.

    The outputs are written before anything is printed, so only the rest of the report is lost,
    which the reader did not want. The standard output is pointed at the null device so that
    the interpreter's final flush does not fail again (the recipe of the Python documentation,
    "Note on SIGPIPE"); a stdout without a file descriptor (a test's capture) is left alone.
    """
    import contextlib
    import io

    with contextlib.suppress(OSError, ValueError, AttributeError, io.UnsupportedOperation):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    return 0


if __name__ == "__main__":
    sys.exit(main())

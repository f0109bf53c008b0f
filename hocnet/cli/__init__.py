"""The ``hocnet`` command line.

Subcommands (each has ``--help``):

* ``hocnet demo``: simulate a Table-III-like scene of [LA98], run the HOC detector, print true
  versus found tracks, clutter rejection, target points lost and runtime, and write pictures.
* ``hocnet detect CUBE``: run a detector on a user's data (a ``.npy`` / ``.npz`` cube, or a
  folder or glob of PNG / BMP / TIFF frames): the HOC on binary cubes (or on intensity frames
  binarised with ``--threshold-pfa``), the DPA on intensity frames after registration, temporal
  background removal and whitening; write ``tracks.json``, ``detections.csv`` (per-frame
  candidate detections ``frame,x,y,score``), the method's cubes and a picture.
* ``hocnet reproduce NAME`` / ``hocnet reproduce --list``: run one of the repository's experiment
  scripts (``experiments/*.py``).

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
from hocnet.cli import demo, detect, reproduce, track, train

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
        description="Track-before-detect for dim multiple moving targets:\n"
        "  hoc  the modified high-order correlation (HOC) of [LA98] on BINARY multi-scan cubes\n"
        "       (outputs: tracks.json, detections.csv, cleaned.npy, support.npy, detection.png);\n"
        "  dpa  the dynamic-programming track-before-detect (DPA) of [NR08] on INTENSITY\n"
        "       frames such as infrared sequences (outputs: tracks.json, detections.csv,\n"
        "       asf.npy, shifts.csv, detection.png).\n"
        "Input: .npy / .npz cubes or folders of PNG / BMP / TIFF frames.\n"
        "[LA98] Liou & Azimi-Sadjadi, IEEE TAES 34(2), 1998; [NR08] Nichtern & Rotman,\n"
        "EURASIP JASP 2008.",
        epilog="Run 'hocnet COMMAND --help' for the options of each command.",
        formatter_class=_Formatter,
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {hocnet.__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    for module in (demo, detect, train, reproduce, track):
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
            args = parser.parse_args(argv)
        except SystemExit as exit_:  # --help / --version
            return exit_.code if isinstance(exit_.code, int) else 0
        return int(args.func(args))
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


if __name__ == "__main__":
    sys.exit(main())

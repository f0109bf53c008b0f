"""Shared parts of the ``hocnet`` command line.

Errors, parsers, safe output writing, progress bars and the translation of library argument
names into the command line's flags.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import shutil
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

if TYPE_CHECKING:
    pass

PROG = "hocnet"
EXPERIMENTS_ENV = "HOCNET_EXPERIMENTS_DIR"
DEBUG_ENV = "HOCNET_DEBUG"


def _check_int(name: str, value: Any, **bounds: Any) -> int:
    """:func:`hocnet._check.check_int`, imported late so that ``--help`` does not load torch."""
    from hocnet._check import check_int

    return check_int(name, value, **bounds)


def _check_number(name: str, value: Any, **bounds: Any) -> float:
    """:func:`hocnet._check.check_number`, imported late (see :func:`_check_int`)."""
    from hocnet._check import check_number

    return check_number(name, value, **bounds)


class CLIError(Exception):
    """A user error: printed as ``hocnet: error: <message>``, exit code 2."""


class _Problems:
    """Collect the errors of independent checks and raise them together, in one line.

    A user with several bad options hears of all of them at once, not one per run.

    Examples:
        >>> problems = _Problems()
        >>> with problems.check():
        ...     _check_int("--order", 0, minimum=1)
        >>> with problems.check():
        ...     v = _check_int("--v", 2, minimum=1)
        >>> with problems.check():
        ...     raise CLIError("--delta: expected a number in (0, 180], got 400")
        >>> len(problems.messages), problems.messages[0]
        (2, '`--order`: expected an integer >= 1, got 0')
        >>> problems.raise_all()  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        hocnet.cli._common.CLIError: 2 problems: `--order`: expected ...; --delta: expected ...
    """

    def __init__(self) -> None:
        self.messages: list[str] = []

    @contextlib.contextmanager
    def check(self) -> Iterator[None]:
        """Run a check; its :class:`CLIError` / ``ValueError`` / ``TypeError`` is kept."""
        try:
            yield
        except (CLIError, ValueError, TypeError) as err:  # a raise_all's messages one by one
            self.messages.extend(getattr(err, "messages", None) or [" ".join(str(err).split())])

    def raise_all(self) -> None:
        """Raise one :class:`CLIError` with every kept message (``; ``-separated), if any."""
        if not self.messages:
            return
        text = self.messages[0]
        if len(self.messages) > 1:
            text = f"{len(self.messages)} problems: " + "; ".join(self.messages)
        err = CLIError(text)
        err.messages = list(self.messages)  # type: ignore[attr-defined]
        raise err


class _Parser(argparse.ArgumentParser):
    """Argument parser whose usage errors are one line and go through :class:`CLIError`."""

    def error(self, message: str) -> NoReturn:
        raise CLIError(f"{message} (see '{self.prog} --help')")


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Keep the layout of the (pre-wrapped) descriptions and epilogs."""


# --------------------------------------------------------------------------------------------
# output: compute everything first, then write atomically
# --------------------------------------------------------------------------------------------

Writer = Callable[[Path], None]


def _out_path(value: Any, flag: str = "--out") -> Path:
    """The ``--out`` folder as a Path; an empty string (which would mean '.') is refused."""
    if value is None:
        raise CLIError(f"{flag}: expected a folder name, got none")
    text = os.fspath(value)
    if not str(text).strip():
        raise CLIError(f"{flag}: expected a folder name, got an empty string {text!r}")
    return Path(text)


def _check_out_dir(out: Path | str) -> Path:
    """Reject an output path that can never become a directory, before any work is done."""
    out = _out_path(out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out: expected a directory, got the existing file '{out}'")
    if out.is_dir() and not os.access(out, os.W_OK | os.X_OK):
        raise CLIError(f"--out: cannot write into '{out}': it is not writable")
    for parent in out.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise CLIError(f"--out: '{parent}' is a file, cannot create '{out}' inside it")
            if not os.access(parent, os.W_OK) and not out.exists():
                raise CLIError(f"--out: cannot create '{out}': '{parent}' is not writable")
            break
    return out


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths name the same file (real paths, symlinks and hard links resolved)."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


#: The record of what hocnet wrote into an output folder: ``{name: [size, mtime_ns]}``.
MANIFEST = ".hocnet-outputs.json"

#: The hint of the refusal to replace a file hocnet did not write (see :func:`_foreign_files`).
FORCE_HINT = "use --force to replace {it}, or choose another --out"


def _file_key(path: Path) -> list[int]:
    """``[size, mtime_ns]`` of ``path`` itself (a symlink is not followed)."""
    st = os.lstat(path)
    return [int(st.st_size), int(st.st_mtime_ns)]


def _read_manifest(out: Path) -> dict[str, list[int]]:
    """The manifest of ``out`` (:data:`MANIFEST`); missing, unreadable or corrupt: empty.

    An entry that is not ``name: [size, mtime_ns]`` (two integers) is ignored, so a damaged
    manifest can only make hocnet refuse more, never replace a file it did not write.

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     _ = (Path(tmp) / MANIFEST).write_text('{"a.npy": [3, 7], "b": "x"}')
        ...     _read_manifest(Path(tmp))
        {'a.npy': [3, 7]}
    """
    path = out / MANIFEST
    if not path.is_file():  # nor a FIFO or a device, which could block or never end
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {
        name: [int(v) for v in value]
        for name, value in data.items()
        if isinstance(name, str)
        and isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
    }


def _write_manifest(out: Path, entries: dict[str, list[int]]) -> None:
    """Replace the manifest of ``out`` atomically (a temporary file, then a rename)."""
    tmp = out / f"{MANIFEST}.tmp-{uuid.uuid4().hex[:12]}"
    try:
        tmp.write_text(json.dumps(entries, indent=1, sort_keys=True) + "\n")
        os.replace(tmp, out / MANIFEST)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _record_outputs(out: Path, names: Sequence[str]) -> None:
    """Add ``names`` (files just written into ``out``) to its manifest, atomically.

    Earlier entries are kept while their files still exist. A manifest that cannot be written
    costs only a refusal at the next run into ``out`` (which then needs ``--force``): it is said
    on stderr and the command still succeeds.
    """
    entries = {n: k for n, k in _read_manifest(out).items() if (out / n).is_file()}
    try:
        for name in names:
            entries[name] = _file_key(out / name)
        _write_manifest(out, entries)
    except OSError as err:
        reason = err.strerror or _one_line(str(err))
        print(
            f"{PROG}: warning: could not record the outputs in '{out / MANIFEST}': {reason}; "
            "a rerun into this folder will need --force",
            file=sys.stderr,
        )


def _forget_outputs(out: Path, names: Sequence[str]) -> None:
    """Drop ``names`` (files removed again) from the manifest of ``out``; an empty one goes."""
    entries = _read_manifest(out)
    if not entries and not (out / MANIFEST).is_file():
        return
    entries = {n: k for n, k in entries.items() if n not in names and (out / n).is_file()}
    with contextlib.suppress(OSError):
        if entries:
            _write_manifest(out, entries)
        else:
            (out / MANIFEST).unlink()


def _foreign_files(out: Path, names: Sequence[str]) -> list[str]:
    """The ``names`` existing in ``out`` (file or symlink) that hocnet may not replace.

    A file may be replaced only when the manifest of ``out`` lists it with its current size and
    mtime_ns, i.e. hocnet wrote it and nobody changed it since.
    """
    manifest: dict[str, list[int]] | None = None
    foreign = []
    for name in names:
        dest = out / name
        if not (dest.exists() or dest.is_symlink()):
            continue
        if manifest is None:
            manifest = _read_manifest(out)
        try:
            owned = not dest.is_symlink() and manifest.get(name) == _file_key(dest)
        except OSError:
            owned = False
        if not owned:
            foreign.append(name)
    return foreign


def _refuse_foreign(out: Path, names: Sequence[str], hint: str = FORCE_HINT) -> None:
    """Raise the one-line :class:`CLIError` of :func:`_foreign_files` (all names at once)."""
    foreign = _foreign_files(out, names)
    if not foreign:
        return
    listed = ", ".join(f"'{out / name}'" for name in foreign)
    one = len(foreign) == 1
    raise CLIError(
        f"--out: {listed} {'exists' if one else 'exist'} and {'was' if one else 'were'} not "
        "written by hocnet (or "
        + ("was" if one else "were")
        + " changed since); "
        + hint.format(it="it" if one else "them")
    )


def _check_destinations(
    out: Path,
    names: Sequence[str],
    inputs: dict[str, Path] | None = None,
    *,
    force: bool = False,
) -> None:
    """Check every destination ``out/name`` before anything is written.

    Refuses a destination that is an existing directory, or that is (after resolving real paths,
    symlinks and hard links) one of the ``inputs`` (label -> path, such as ``CUBE`` or
    ``--target-free``): no output may ever replace an input file, whatever its name. Unless
    ``force``, it also refuses an existing file (or symlink) that hocnet did not write or that
    was changed since (:func:`_foreign_files`, the manifest :data:`MANIFEST` of ``out``).
    """
    out = _check_out_dir(out)
    for name in names:
        dest = out / name
        if dest.is_dir():
            raise CLIError(
                f"--out: cannot write '{dest}': a directory of that name exists; "
                "remove it or choose another --out"
            )
        for label, source in (inputs or {}).items():
            if source is not None and _same_file(dest, Path(source)):
                raise CLIError(
                    f"--out: writing '{dest}' would replace the input {label} '{source}'; "
                    "choose another --out"
                )
    if not force:
        _refuse_foreign(out, names)


def _write_error(dest: Path, staged: Path, err: BaseException) -> CLIError:
    """A one-line error about writing ``dest`` that never names the staging path."""
    from hocnet.data.io import is_disk_full

    if is_disk_full(err):
        reason = "no space left on device"
    elif isinstance(err, OSError) and err.strerror:
        reason = err.strerror
    else:
        reason = _one_line(str(err) or type(err).__name__)
        reason = reason.replace(str(staged), str(dest)).replace("`path`: ", "")
        reason = re.sub(r"'[^']*\.tmp-[0-9a-f]+[^']*'", f"'{dest}'", reason)
    return CLIError(f"--out: could not write '{dest}': {reason}")


def _write_outputs(
    out: Path,
    writers: dict[str, Writer],
    inputs: dict[str, Path] | None = None,
    *,
    force: bool = False,
) -> list[Path]:
    """Write files into ``out`` all-or-nothing, and record them in its manifest.

    Every destination is checked first (:func:`_check_destinations`: no directory in the way, no
    input replaced, the folder writable, and unless ``force`` no existing file that hocnet did
    not write or that was changed since). Then each writer is called with its path inside a
    fresh staging directory: next to ``out`` when ``out`` does not exist yet (it is then renamed
    to ``out``), inside ``out`` otherwise (the same file system, so the renames are atomic). The
    staged files are moved into ``out`` one by one; files of the same names already there are
    first moved aside and put back if any step fails. On failure the staging directory and any
    parent directories created for it are removed, and the error names the user's path. After
    success the written files are added to the manifest of ``out`` (:data:`MANIFEST`, with their
    size and mtime_ns), which lets a later run replace them (:func:`_foreign_files`).

    Returns:
        The final paths, in the order of ``writers``.
    """
    out = _check_out_dir(out)
    _check_destinations(out, list(writers), inputs, force=force)
    created: Path | None = None
    for parent in [out.absolute(), *out.absolute().parents]:
        if parent.exists():
            break
        created = parent
    existed = out.is_dir()
    tag = uuid.uuid4().hex[:12]
    tmp = out / f".hocnet.tmp-{tag}" if existed else out.parent / f".{out.name}.tmp-{tag}"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
    except OSError as err:
        if created is not None:
            shutil.rmtree(created, ignore_errors=True)
        raise _write_error(out, tmp, err) from None
    moved: list[str] = []
    aside: list[str] = []
    backup = tmp / ".previous"
    try:
        for name, write in writers.items():
            try:
                write(tmp / name)
            except (OSError, ValueError, TypeError) as err:
                raise _write_error(out / name, tmp / name, err) from None
        if existed:
            backup.mkdir()
            for name in writers:
                dest = out / name
                try:
                    if dest.exists() or dest.is_symlink():
                        os.replace(dest, backup / name)
                        aside.append(name)
                    os.replace(tmp / name, dest)
                    moved.append(name)
                except OSError as err:
                    raise _write_error(dest, tmp / name, err) from None
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            try:
                os.rename(tmp, out)
            except OSError as err:
                raise _write_error(out, tmp, err) from None
    except BaseException:
        for name in moved:  # roll back: new files out, old files back
            with contextlib.suppress(OSError):
                os.unlink(out / name)
        for name in aside:
            with contextlib.suppress(OSError):
                os.replace(backup / name, out / name)
        shutil.rmtree(tmp, ignore_errors=True)
        if created is not None:  # the parents made for the staging directory
            shutil.rmtree(created, ignore_errors=True)
        raise
    _record_outputs(out, list(writers))
    return [out / name for name in writers]


def _png_writer(fig: Any) -> Writer:
    """Render a figure to PNG bytes now; the returned writer only copies bytes to disk."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=fig.dpi)
    data = buffer.getvalue()
    return lambda path: path.write_bytes(data)


# --------------------------------------------------------------------------------------------
# detection methods
# --------------------------------------------------------------------------------------------


@contextlib.contextmanager
def _torch_threads(n: int) -> Any:
    """Run torch with ``n`` intra-op threads inside the block (restored afterwards).

    The pre-processing and the DPA are many small tensor operations per frame; on the shared
    2-core machine two threads were slower than one (``benchmarks/dpa.py``, row
    ``pipeline_real_ir``), so the command line computes with one thread.
    """
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


#: Torch threads of the ``detect`` pipeline (see :func:`_torch_threads`).
PIPELINE_THREADS = 1


@contextlib.contextmanager
def _reported_warnings(messages: list[str]) -> Any:
    """Say the warnings raised inside the block as ``hocnet: warning: <one line>`` on stderr.

    Every :class:`UserWarning` and :class:`RuntimeWarning` (e.g. a clutter density above the
    HOC's bound, a CFAR that keeps no point) is caught instead of being shown by Python with its
    source line; each distinct message is printed once when the block ends, in order, and
    appended to ``messages`` (which the commands store in their JSON ``meta``). Other warnings
    are dropped. Nothing is printed when the block raises (the error is the message then).

    Examples:
        >>> import warnings
        >>> said = []
        >>> with _reported_warnings(said):
        ...     warnings.warn("dense", RuntimeWarning)
        ...     warnings.warn("dense", RuntimeWarning)
        >>> said
        ['dense']
    """
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield messages
    new = [
        # the library's keyword, as the command line sets it (hocnet detect / track --support)
        _one_line(str(w.message)).replace("support='chain'", "--support chain")
        for w in caught
        if issubclass(w.category, (UserWarning, RuntimeWarning))
    ]
    for message in dict.fromkeys(new):
        if message in messages:
            continue
        print(f"{PROG}: warning: {message}", file=sys.stderr)
        messages.append(message)


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """Plain fixed-width table (columns left-aligned, two spaces apart)."""
    cells = [list(map(str, header)), *([str(c) for c in row] for row in rows)]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join("  " + line for line in lines)


#: Seconds a run must last before its progress bar appears ("longer than a few seconds").
PROGRESS_DELAY = 2.0


def _show_progress(args: argparse.Namespace) -> bool:
    """Progress bars on stderr unless ``--quiet`` or stderr is not a terminal."""
    if getattr(args, "quiet", False):
        return False
    isatty = getattr(sys.stderr, "isatty", None)
    return bool(isatty and isatty())


def _progress(items: Any, *, desc: str, total: int, enabled: bool) -> Any:
    """A tqdm bar on stderr (shown after :data:`PROGRESS_DELAY` seconds) when ``enabled``."""
    if not enabled:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=desc, total=total, leave=False, file=sys.stderr, delay=PROGRESS_DELAY)


class _Stages:
    """A stage-level progress bar (load, detect, pictures, write) on stderr.

    It appears only when a run lasts longer than :data:`PROGRESS_DELAY` seconds, and never when
    disabled (``--quiet``, or stderr not a terminal).
    """

    def __init__(self, names: Sequence[str], *, enabled: bool) -> None:
        self.enabled = enabled
        self._total = len(names)
        self._bar: Any = None
        self._started = False

    def __enter__(self) -> _Stages:
        if self.enabled:
            from tqdm import tqdm

            self._bar = tqdm(
                total=self._total,
                leave=False,
                file=sys.stderr,
                delay=PROGRESS_DELAY,
                bar_format="{desc}: stage {n_fmt}/{total_fmt} [{elapsed}]",
            )
        return self

    def next(self, desc: str) -> None:
        """Start the next stage."""
        if self._bar is None:
            return
        if self._started:
            self._bar.update(1)
        self._started = True
        self._bar.set_description_str(desc)

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()


# --------------------------------------------------------------------------------------------
# hocnet reproduce
# --------------------------------------------------------------------------------------------


def _one_line(message: str) -> str:
    return " ".join(str(message).split()) or "unknown error"


# API argument names -> what the user typed, per command (and method). The one place where a
# library message ("`target_free`: expected ...") becomes a command-line one ("--target-free:").
_FLAGS_COMMON = {"path": "CUBE", "cube": "CUBE", "frames": "CUBE", "x": "CUBE", "key": "--key"}
_FLAGS: dict[str, dict[str, str]] = {
    "hoc": {
        **_FLAGS_COMMON,
        "order": "--order",
        "v": "--v",
        "delta": "--delta",
        "threshold": "--threshold",
        "min_points": "--min-points",
        "min_speed": "--min-speed",
        "pfa": "--threshold-pfa",
        "background_window": "--background-window",
    },
    "dpa": {
        **_FLAGS_COMMON,
        "g": "--g",
        "b": "--b",
        "window": "--window",
        "v_max": "--v-max",
        "equal_gain": "--equal-gain",
        "max_targets": "--max-targets",
        "nms_radius": "--nms-radius",
        "threshold": "--asf-threshold",
        "target_free": "--target-free",
        "pfa": "--pfa",
        "weights": "the probability matrices of --window / --v-max",
        "background_window": "--background-window",
    },
    "demo": {"seed": "--seed", "density": "--density", "order": "--order"},
    "reproduce": {"seeds": "--seeds", "quick": "--quick", "out_dir": "--out"},
    "track": {**_FLAGS_COMMON, "path": "SEQ", "cube": "SEQ", "frames": "SEQ", "x": "SEQ"},
    "sweep": {
        "b": "--b",
        "g": "--g",
        "penalty_step": "--penalty-step",
        "s_n": "--s-n",
        "max_numbers": "--max-numbers",
        "scene": "--scene",
        "shape": "--shape",
        "scenes": "--scenes",
        "snr_db": "--snr-db",
        "speed": "--speed",
        "clouds": "--clouds",
        "window": "--window",
        "v_max": "--v-max",
        "p": "--p",
        "whiten": "--whiten",
        "pfa": "--pfa",
        "last": "--last",
        "block": "--block",
        "radius": "--radius",
        "direction_step": "--direction-step",
        "num_cpus": "--num-cpus",
        "cpus_per_trial": "--cpus-per-trial",
        "max_concurrent": "--max-concurrent",
        "max_epochs": "--max-epochs",
        "seed": "--seeds",
        "path": "--out/ray/--name",
        "grid": "--grid",
        "system": "SYSTEM",
    },
}


def _to_flags(message: str, flags: dict[str, str]) -> str:
    """Replace the backquoted API names of a library message by the command line's names.

    Examples:
        >>> _to_flags("`target_free`: expected (T, H, W), got (2, 3)", _FLAGS["dpa"])
        '--target-free: expected (T, H, W), got (2, 3)'
        >>> _to_flags("`--v`: expected an integer >= 1, got 0", {})
        '--v: expected an integer >= 1, got 0'
    """

    def swap(match: re.Match[str]) -> str:
        name = match.group(1)
        if name.startswith("--"):
            return name
        base = re.sub(r"\[.*$", "", name)  # tracks[3].id -> tracks
        return flags.get(base, match.group(0)) if base == name else match.group(0)

    return re.sub(r"`([^`\s]+)`", swap, message)


def _flags_of(args: argparse.Namespace | None) -> dict[str, str]:
    if args is None:
        return {}
    command = getattr(args, "command", None)
    if command == "detect":
        flags = dict(_FLAGS.get(getattr(args, "method", "hoc"), {}))
        for name in ("cube", "frames", "x"):  # the input named with its path
            flags[name] = f"CUBE '{args.cube}'"
        return flags
    if command == "track":  # the detector's flags, then the input's name (SEQ)
        detector = getattr(args, "detector", "hoc")
        flags = {**_FLAGS.get(detector, {}), **_FLAGS["track"]}
        if detector == "dpa":  # --window is the HOC's window here; the matrices follow --preset
            flags["window"] = "the DPA matrices of --preset"
        else:
            flags.update(window="--window", stride="--stride")
        return flags
    return _FLAGS.get(command or "", {})


def _fail(message: str, flags: dict[str, str] | None = None) -> int:
    message = _to_flags(_one_line(message), flags or {})
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2

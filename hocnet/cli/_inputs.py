"""Shared inputs of ``hocnet detect`` and ``hocnet track``: detector options and input loading.

One definition of each detector option (HOC of [LA98], DPA of [NR08], the pre-processing of
intensity frames), of its validation into parameters, and of how the input is read (a ``.npy``
/ ``.npz`` cube or a folder, glob or file of image frames), with the same one-line messages.
A command names its input (``label``: ``CUBE``, ``SEQ``) and the flag that picks the detector
(``selector``: ``--method``, ``--detector``), which appear in help texts and messages.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hocnet.cli._common import (
    PROG,
    CLIError,
    _check_int,
    _check_number,
    _one_line,
    _Problems,
)

if TYPE_CHECKING:
    import torch

#: Options of the HOC (``add_hoc_options``).
HOC_DESTS = (
    "order",
    "v",
    "delta",
    "threshold",
    "min_points",
    "min_speed",
    "threshold_pfa",
    "support",
)

#: Options of the pre-processing of intensity frames (shared by dpa and hoc --threshold-pfa).
PRE_DESTS = ("register", "background", "background_window", "whiten")

#: Options of the DPA (``add_dpa_options``).
DPA_DESTS = (
    "preset",
    "g",
    "b",
    "window",
    "v_max",
    "equal_gain",
    "max_targets",
    "nms_radius",
    "asf_threshold",
    "target_free",
    "pfa",
)

# --------------------------------------------------------------------------------------------
# detector options
# --------------------------------------------------------------------------------------------


def add_hoc_options(
    group: argparse._ArgumentGroup, *, label: str = "CUBE", selector: str = "--method"
) -> None:
    """Add the HOC options of [LA98] (:data:`HOC_DESTS`) to ``group``.

    ``label`` names the input and ``selector`` the flag that picks the detector in the help.
    """
    group.add_argument(
        "--order", type=int, default=None, metavar="K", help="HOC order k >= 1 (default: 2)"
    )
    group.add_argument(
        "--v",
        type=int,
        default=None,
        metavar="V",
        help="velocity window: largest |dx|, |dy| per scan in pixels, >= 1 (default: 4)",
    )
    group.add_argument(
        "--delta",
        type=float,
        default=None,
        metavar="DEG",
        help="largest turn between successive moves, in DEGREES, in (0, 180] (default: 45)",
    )
    group.add_argument(
        "--threshold",
        type=float,
        default=None,
        metavar="S",
        help="smallest accepted track score, eq. (8)-(9) of [LA98] (default: 2.5)",
    )
    group.add_argument(
        "--min-points",
        type=int,
        default=None,
        metavar="N",
        help="smallest accepted track length in points, >= 1 (default: 2 * order + 1)",
    )
    group.add_argument(
        "--min-speed",
        type=float,
        default=None,
        metavar="S",
        help="drop tracks whose mean speed (first to last point) is below S pixels per scan, "
        ">= 0; our addition against stationary clutter, not in [LA98] (default: 0, keep all)",
    )
    group.add_argument(
        "--support",
        choices=("mhoc", "chain"),
        default=None,
        help="the points identification starts from: 'mhoc' = the MHOC image of [LA98] "
        "(forward OR backward Y^(k); it cannot cover every scan when T < 4k, identification "
        "brings those points back), 'chain' = every point on an accepted 2k + 1-point chain "
        "(our addition; covers every scan) (default: mhoc)",
    )
    group.add_argument(
        "--threshold-pfa",
        type=float,
        default=None,
        metavar="P",
        help="take INTENSITY frames: pre-process them (see the pre-processing options), then "
        "keep in every frame the floor(P H W) highest whitened pixels (per-frame CFAR "
        "threshold, false-alarm probability P per pixel, in (0, 1); our addition, "
        f"hocnet.data.binarize) as the binary cube of the HOC (default: off, {label} is binary). "
        "Caveat: on the real IR clips of README the HOC keeps the target in its support but its "
        f"point score cannot rank it (Pd 0.00 at one false alarm per frame; {selector} dpa: 0.985)",
    )


def prepare_hoc(args: argparse.Namespace, selector: str = "--method") -> dict[str, Any]:
    """Validate the HOC options (flag names in the messages) and fill in defaults.

    With ``--threshold-pfa`` the pre-processing options too (defaults of the recommended
    preset) and ``binary`` False: intensity frames, binarised by
    :func:`hocnet.cli.detect.binarize_frames`.
    """
    problems = _Problems()  # every bad option in one message (not one per run)
    order = 2 if args.order is None else args.order
    with problems.check():
        order = _check_int("--order", order, minimum=1)
    v = 4 if args.v is None else args.v
    with problems.check():
        v = _check_int("--v", v, minimum=1)
    delta = 45.0 if args.delta is None else args.delta
    with problems.check():
        delta = _check_number("--delta", delta, low=0.0, high=180.0, low_inclusive=False)
    threshold = 2.5 if args.threshold is None else args.threshold
    with problems.check():
        threshold = _check_number("--threshold", threshold)
    min_points = args.min_points
    if min_points is None:
        min_points = 2 * order + 1 if isinstance(order, int) else 1
    with problems.check():
        min_points = _check_int("--min-points", min_points, minimum=1)
    min_speed = 0.0 if args.min_speed is None else args.min_speed
    with problems.check():
        min_speed = _check_number("--min-speed", min_speed)
        if min_speed < 0:
            raise CLIError(f"--min-speed: expected a speed >= 0 pixels per scan, got {min_speed:g}")
    params: dict[str, Any] = {
        "order": order,
        "v": v,
        "delta": delta,
        "threshold": threshold,
        "min_points": min_points,
        "min_speed": min_speed,
        "support": "mhoc" if getattr(args, "support", None) is None else args.support,
    }
    if args.threshold_pfa is None:
        for dest in PRE_DESTS:
            if getattr(args, dest, None) is not None:
                flag = "--" + dest.replace("_", "-")
                problems.messages.append(
                    f"{flag}: applies to intensity frames: {selector} dpa, or {selector} hoc with "
                    "--threshold-pfa"
                )
        problems.raise_all()
        return params
    from hocnet.dpa.presets import RECOMMENDED

    with problems.check():
        params["threshold_pfa"] = _check_number(
            "--threshold-pfa",
            args.threshold_pfa,
            low=0.0,
            high=1.0,
            low_inclusive=False,
            high_inclusive=False,
        )
    with problems.check():
        params.update(prepare_preprocess(args, RECOMMENDED))
    problems.raise_all()
    params["binary"] = False
    return params


def preset_default(field_name: str, fmt: str = "{}") -> str:
    """``recommended: X, paper: Y`` for a help text (read from :mod:`hocnet.dpa.presets`)."""
    from hocnet.dpa.presets import PAPER, RECOMMENDED

    def show(value: Any) -> str:
        if isinstance(value, bool):
            return "on" if value else "off"
        return "EMC" if value == "emc" else fmt.format(value)

    rec, pap = getattr(RECOMMENDED, field_name), getattr(PAPER, field_name)
    if rec == pap:
        return f"default: {show(rec)} in both presets"
    return f"default: {show(rec)} (--preset recommended), {show(pap)} (--preset paper)"


def add_dpa_options(
    group: argparse._ArgumentGroup,
    *,
    skip: tuple[str, ...] = (),
    helps: dict[str, str] | None = None,
) -> None:
    """Add the DPA options of [NR08] (:data:`DPA_DESTS`) to ``group``.

    ``skip``: dests left out; ``helps``: dest -> the help text of a command that uses the
    option differently.
    """

    def add(flag: str, **kwargs: Any) -> None:
        dest = flag[2:].replace("-", "_")
        if dest not in skip:
            group.add_argument(
                flag, **{**kwargs, **({"help": helps[dest]} if dest in (helps or {}) else {})}
            )

    add(
        "--preset",
        choices=("recommended", "paper"),
        default=None,
        help="the defaults of the DPA and pre-processing options: 'recommended' = the "
        "pipeline measured best on six real IR clips (registration, median background of 10 "
        "past frames, anti-mean, 5 x 5 matrices, g = 0, equal gain, memory 0.4; "
        "hocnet.dpa.presets.RECOMMENDED), 'paper' = the DPA as [NR08] builds it (7 x 7, "
        "v-max 2 + 0.5 jitter, g = 0, b = 4.67 from the EMC 0.8 of direction 9, no background "
        "removal; hocnet.dpa.presets.PAPER, the library's defaults) (default: recommended)",
    )
    add(
        "--g",
        type=float,
        default=None,
        metavar="G",
        help=f"sum/max mixing of eq. (11) of [NR08], in [0, 1]: 0 = max, 1 = sum "
        f"({preset_default('g', '{:g}')}; DPA() also defaults to 0)",
    )
    add(
        "--b",
        type=float,
        default=None,
        metavar="B",
        help="memory factor, >= 0 (default: the b of the effective-memory criterion (EMC), "
        "eq. (12)-(14) of [NR08], for g: EMC 0.4 with --preset recommended, 0.8 of "
        "direction 9 with --preset paper)",
    )
    add(
        "--window",
        type=int,
        default=None,
        metavar="K",
        help=f"probability-matrix size, odd, at most the frame size ({preset_default('window')})",
    )
    add(
        "--v-max",
        type=float,
        default=None,
        metavar="V",
        help="largest target speed in pixels per frame, without the 0.5 px jitter, > 0 "
        f"({preset_default('v_max', '{:g}')})",
    )
    add(
        "--equal-gain",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="rescale the direction matrices to one per-step gain (our addition to [NR08], "
        "for sub-pixel targets that stay in place, see hocnet.dpa.equalize_gain; "
        f"{preset_default('equal_gain')})",
    )
    add(
        "--max-targets",
        type=int,
        default=None,
        metavar="N",
        help="largest number of tracks per sequence, >= 1 (default: 5)",
    )
    add(
        "--nms-radius",
        type=int,
        default=None,
        metavar="R",
        help="non-maximum suppression radius on the last ASF, >= 0 (default: 3)",
    )
    add(
        "--asf-threshold",
        type=float,
        default=None,
        metavar="S",
        help="keep last-frame ASF peaks above S (default: no threshold, the top peaks)",
    )
    add(
        "--target-free",
        default=None,
        metavar="FRAMES",
        help="target-free frames for a CFAR (constant false-alarm rate) threshold at --pfa: "
        "the same inputs as the main one (a .npy / .npz, or a folder, glob or file of image "
        "frames) of the same frame size",
    )
    add(
        "--pfa",
        type=float,
        default=None,
        metavar="P",
        help="false-alarm probability (Pfa) per pixel of the CFAR threshold (default: 1e-3)",
    )


def add_preprocess_options(
    group: argparse._ArgumentGroup,
    *,
    selector: str = "--method",
    shifts_to: str = "shifts.csv",
) -> None:
    """Add the pre-processing options of intensity frames (:data:`PRE_DESTS`) to ``group``.

    ``selector`` as in :func:`add_hoc_options`; ``shifts_to``: where the shifts are written.
    """
    group.add_argument(
        "--register",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="estimate the camera motion between frames (phase correlation, sub-pixel) and "
        "move the past frames onto each frame before the background is taken; the shifts are "
        f"written to {shifts_to} (our addition; "
        f"{preset_default('register')}; {selector} hoc --threshold-pfa: on)",
    )
    group.add_argument(
        "--background",
        choices=("none", "mean", "median", "lowrank"),
        default=None,
        help="causal temporal background removal: per-pixel mean / median / robust low-rank "
        "background of the previous --background-window frames, subtracted before the "
        f"whitening (our addition; {preset_default('background')}; {selector} hoc "
        "--threshold-pfa: median)",
    )
    group.add_argument(
        "--background-window",
        type=int,
        default=None,
        metavar="N",
        help=f"past frames of the background, >= 1 ({preset_default('background_window')})",
    )
    group.add_argument(
        "--whiten",
        choices=("mean", "median", "none"),
        default=None,
        help="anti-mean / anti-median whitening (7 x 7 ring, 3 x 3 guard) or none "
        f"({preset_default('whitening')}; {selector} hoc --threshold-pfa: mean)",
    )


def prepare_preprocess(args: argparse.Namespace, preset: Any) -> dict[str, Any]:
    """The pre-processing options, defaults from ``preset`` (a :class:`DPAPreset`)."""
    window = preset.background_window if args.background_window is None else args.background_window
    return {
        "register": preset.register if args.register is None else bool(args.register),
        "background": args.background or preset.background,
        "background_window": _check_int("--background-window", window, minimum=1),
        "whiten": args.whiten or preset.whitening,
    }


def prepare_dpa(args: argparse.Namespace) -> dict[str, Any]:
    """Validate the DPA options (flag names in the messages) and fill in the preset's defaults."""
    from hocnet.dpa.presets import PRESETS

    preset = PRESETS[args.preset or "recommended"]
    problems = _Problems()  # every bad option in one message (not one per run)
    g = preset.g if args.g is None else args.g
    with problems.check():
        g = _check_number("--g", g, low=0.0, high=1.0)
    b = None if preset.b == "emc" else float(preset.b)
    if args.b is not None:
        with problems.check():
            b = _check_number("--b", args.b, low=0.0)
    window = preset.window if args.window is None else args.window
    with problems.check():
        window = _check_int("--window", window, minimum=1)
        if window % 2 == 0:
            raise CLIError(f"--window: expected an odd integer, got {window}")
    v_max = preset.v_max if args.v_max is None else args.v_max
    with problems.check():
        v_max = _check_number("--v-max", v_max, low=0.0, low_inclusive=False)
    max_targets = 5 if args.max_targets is None else args.max_targets
    with problems.check():
        max_targets = _check_int("--max-targets", max_targets, minimum=1)
    nms_radius = 3 if args.nms_radius is None else args.nms_radius
    with problems.check():
        nms_radius = _check_int("--nms-radius", nms_radius, minimum=0)
    threshold = args.asf_threshold
    if threshold is not None:
        with problems.check():
            threshold = _check_number("--asf-threshold", threshold)
    pfa = 1e-3 if args.pfa is None else args.pfa
    with problems.check():
        pfa = _check_number(
            "--pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
        )
    if threshold is not None and args.target_free is not None:
        problems.messages.append(
            "--asf-threshold: expected no fixed threshold together with --target-free"
        )
    preprocess: dict[str, Any] = {}
    with problems.check():
        preprocess = prepare_preprocess(args, preset)
    problems.raise_all()  # before reading --target-free
    target_free = None
    if args.target_free is not None:
        target_free = load_target_free(args.target_free)
    return {
        "preset": preset.name,
        "g": g,
        "b": b,
        "window": window,
        "v_max": v_max,
        "jitter": preset.jitter,
        "p": preset.p,
        "penalty_step": preset.penalty_step,
        "memory": preset.memory,
        "memory_direction": preset.memory_direction,
        "direction_step": preset.direction_step,
        **preprocess,
        "equal_gain": preset.equal_gain if args.equal_gain is None else bool(args.equal_gain),
        "max_targets": max_targets,
        "nms_radius": nms_radius,
        "asf_threshold": threshold,
        "pfa": pfa,
        "target_free": target_free,
    }


def load_target_free(source: str) -> torch.Tensor:
    """Load ``--target-free`` frames: the same inputs as the main one (:func:`load_input`).

    A ``.npy`` / ``.npz`` array, or a folder, glob or file of image frames (PNG, BMP, TIFF), as
    float64; every message names ``--target-free``.

    Raises:
        CLIError: one line naming ``--target-free`` (missing file, not an image, ...).
    """
    try:
        cube, _ = load_input(source, None, False, label="--target-free")
    except CLIError as err:
        message = str(err).replace("--target-free: --target-free", "--target-free")
        raise CLIError(message) from None
    return cube


def check_target_free(target_free: torch.Tensor, frame_size: tuple[int, int], label: str) -> None:
    """Refuse ``--target-free`` frames that cannot give the input's CFAR threshold.

    The threshold is an order statistic of the DPA's scores on these frames, whitened like the
    input, so they must be intensity frames (not a binary cube) of the input's frame size
    ``(H, W)``; their number of frames (and batch) may differ.

    Raises:
        CLIError: one line naming ``--target-free``.

    Examples:
        >>> import torch
        >>> check_target_free(torch.rand(4, 8, 8), (8, 8), "CUBE")
        >>> check_target_free(torch.rand(4, 6, 8), (8, 8), "CUBE")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        hocnet.cli._common.CLIError: --target-free: expected frames of the size of CUBE, ...
    """
    import torch

    height, width = target_free.shape[-2:]
    if (height, width) != tuple(frame_size):
        raise CLIError(
            f"--target-free: expected frames of the size of {label}, {frame_size[0]} x "
            f"{frame_size[1]} (H x W), got {height} x {width}"
        )
    if target_free.dtype == torch.bool or not bool(((target_free != 0) & (target_free != 1)).any()):
        raise CLIError(
            "--target-free: expected intensity frames like the input (the CFAR threshold is an "
            "order statistic of their DPA scores), got binary values (only 0 and 1)"
        )
    if target_free.numel() and bool(
        (target_free.amax(dim=(-2, -1)) == target_free.amin(dim=(-2, -1))).all()
    ):
        raise CLIError(
            "--target-free: expected intensity frames whose values vary (the CFAR threshold is "
            "an order statistic of their DPA scores), got only flat frames (zero variance)"
        )


def out_inside_input(out: Path | str, source: str, label: str = "CUBE") -> None:
    """Refuse an ``--out`` that is the input's folder of frames or inside it.

    The outputs (``tracks.json``, a ``.png``, a sub-folder) would become part of the input and
    break the next run on it ("expected only image frames ..."). A folder input refuses the
    folder and every folder inside it; a glob refuses the folders of the frames it matches (a
    picture written there could match the pattern); a ``.npy`` / ``.npz`` or one image file
    refuses nothing.

    Raises:
        CLIError: one line naming ``--out``.

    Examples:
        >>> import tempfile
        >>> clip = Path(tempfile.mkdtemp())
        >>> out_inside_input(clip / "results", str(clip), "SEQ")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        hocnet.cli._common.CLIError: --out: ... is inside the input folder of SEQ ...
    """
    import os

    if not frames_source(source):
        return
    path = Path(source)
    if path.is_dir():
        folders, inside = [path], True
    else:
        if path.is_file():  # one (multi-page) image file
            return
        from hocnet.data.frames import frame_files

        try:
            files = frame_files(source)
        except (ValueError, OSError):  # the loading names the problem
            return
        folders, inside = list(dict.fromkeys(file.parent for file in files)), False
    where = Path(os.path.realpath(out))
    for folder in folders:
        real = Path(os.path.realpath(folder))
        # the input as the user typed it; a glob also names the folder of its frames
        given = (
            f"{label} '{source}'"
            if inside
            else f"{label} '{source}' (its frames are in '{folder}')"
        )
        if where == real:
            raise CLIError(
                f"--out: '{out}' is the input folder of {given}: the outputs "
                "would become input frames of the next run; choose another --out"
            )
        if inside and real in where.parents:
            raise CLIError(
                f"--out: '{out}' is inside the input folder of {given}: the outputs "
                "would become part of the input of the next run; choose another --out"
            )


# --------------------------------------------------------------------------------------------
# the input
# --------------------------------------------------------------------------------------------


def add_input_arguments(
    parser: argparse.ArgumentParser, dest: str, label: str, *, what: str = "cube"
) -> None:
    """The positional input ``label`` (image frames or a .npy / .npz ``what``) and ``--key``."""
    parser.add_argument(
        dest,
        metavar=label,
        help=f"input: a .npy / .npz {what}, or a folder, glob ('clip/*.png') or file of image "
        "frames (PNG, BMP, TIFF; 8 or 16 bit; sorted by name, natural order)",
    )
    parser.add_argument(
        "--key", default=None, metavar="K", help="array name inside a .npz (default: its only one)"
    )


def frames_source(text: str) -> bool:
    """Whether the input names image frames (a folder, a glob or an image file), not a .npy/.npz.

    Examples:
        >>> frames_source("clip/*.png"), frames_source("no-such-cube.npy")
        (True, False)
    """
    from hocnet.data.frames import IMAGE_SUFFIXES

    path = Path(text)
    if path.is_dir():  # a folder named like a cube file is a mistaken path, not a clip
        return path.suffix.lower() not in (".npy", ".npz")
    if path.is_file():
        return path.suffix.lower() in IMAGE_SUFFIXES
    return bool(re.search(r"[*?\[]", text))


def input_paths(source: str, label: str = "CUBE") -> dict[str, Path]:
    """The files an input reads (label -> path): no output may replace any of them.

    The input itself, and for image frames every frame file (``"CUBE frame 'f.png' of"``), as
    far as they can be listed now; a source that cannot be listed gives its error on loading.
    """
    import contextlib

    paths = {label: Path(source)}
    if frames_source(source):
        from hocnet.data.frames import frame_files

        with contextlib.suppress(ValueError, OSError):
            paths.update(frame_paths(frame_files(source), label))
    return paths


def frame_paths(files: list[Path], label: str = "CUBE") -> dict[str, Path]:
    """``{"CUBE frame 'f.png' of": path}`` for image frame files (see :func:`input_paths`)."""
    return {f"{label} frame '{file.name}' of": file for file in files}


def load_input(
    source: str,
    key: str | None,
    binary: bool,
    *,
    label: str = "CUBE",
    selector: str = "--method",
) -> tuple[torch.Tensor, list[Path]]:
    """Load the input: a .npy/.npz cube, or a folder / glob / file of image frames.

    Args:
        source: the input as typed.
        key: the array of a .npz (``--key``).
        binary: require binary values (bool or 0/1) and return a bool cube.
        label: the input's name in messages (``CUBE``, ``SEQ``).
        selector: the flag that picks the detector, in the hint for non-binary values.

    Returns:
        The cube (``(T, H, W)`` or ``(B, T, H, W)``; image frames: float64 or bool) and the
        image files read (inputs that no output may replace). A colour frame converted to grey
        is reported as one ``hocnet: note:`` line on stderr.

    Raises:
        CLIError: one line naming ``label`` or ``--key`` (missing file, empty folder, a file
            that is not an image, frames of different sizes, not binary, ...).
    """
    import warnings

    import torch

    from hocnet._check import as_cube
    from hocnet.data.frames import frame_files, load_frames
    from hocnet.data.io import load_cube

    files: list[Path] | None = []
    try:
        if frames_source(source):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", UserWarning)
                cube = load_frames(source, key=key, dtype=torch.float64)
            for warning in caught:
                if issubclass(warning.category, UserWarning):
                    text = _one_line(str(warning.message)).replace("load_frames: ", "")
                    print(f"{PROG}: note: {text}", file=sys.stderr)
            files = frame_files(source)
            if binary:
                try:
                    cube, _ = as_cube("cube", cube, binary=True)
                except ValueError as err:  # as a .npy says it, naming the input
                    text = str(err).replace("`cube`: ", "")
                    raise ValueError(
                        f"{label}: the frames of '{source}' are not binary: {text}"
                    ) from None
                cube = cube[0]
        else:
            files = None
            cube = load_cube(source, key=key, binary=binary)
    except (ValueError, TypeError, OSError) as err:
        message = str(err).replace("`path`", label).replace("`source`", label)
        key_used = re.match(r"`key`: expected None for (.*), got (.*)$", message)
        if key_used:  # not "expected None": say what --key is for
            message = (
                f"--key: expected no --key for {key_used.group(1)} (--key names an array of a "
                f".npz archive), got {key_used.group(2)}"
            )
        if files is not None and "expected finite values" in message:
            message = _nonfinite_frames(source, message)
        message = message.replace("`key`", "--key").replace("`cube`: ", "")
        if message.startswith("--key") and message.endswith(", got None"):
            message = message[: -len("None")] + "no --key"  # the flag as the user left it
        if binary and "binary values" in message:
            message += (
                f"; {selector} hoc needs binary scans: give --threshold-pfa P to binarise "
                f"intensity frames, or use {selector} dpa"
            )
        raise CLIError(message) from None
    return cube, files or []


def _nonfinite_frames(source: str, message: str) -> str:
    """The NaN / inf message of image frames, naming the frame files that hold them."""
    import warnings

    from hocnet.data.frames import frame_files, load_frames

    bad = []
    try:
        for file in frame_files(source):
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    load_frames(file)
            except ValueError as err:
                if "finite" not in str(err):
                    raise
                bad.append(file.name)
    except (ValueError, TypeError, OSError):
        return message
    if not bad:
        return message
    shown = ", ".join(f"'{name}'" for name in bad[:3]) + (" ..." if len(bad) > 3 else "")
    return f"{message} in {len(bad)} frame file{'s' * (len(bad) != 1)} of '{source}': {shown}"

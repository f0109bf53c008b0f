"""Detection with learned weights: the DPA and the HOC network loaded from a training checkpoint.

:func:`load_detector` reads a :class:`~hocnet.learn.DPATuner` or
:class:`~hocnet.learn.LearnedHOCSystem` checkpoint (``torch.load(..., weights_only=True)``,
:func:`~hocnet.learn.load_model`) and checks it holds the wanted system; :func:`detect_dpa` and
:func:`detect_hoc` are the library detectors run with the learned module in place of the fixed
weights (``hocnet detect --weights CKPT`` calls them).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from typing import Any

import torch

from hocnet._check import as_cube, check_choice, restore_batch
from hocnet.dpa import DPA
from hocnet.dpa.backtrack import DPADetection
from hocnet.dpa.backtrack import detect as dpa_detect
from hocnet.hoc.identify import DEFAULT_THRESHOLD, HOCResult, identify_tracks
from hocnet.hoc.layers import MHOCImage
from hocnet.learn.systems import load_model

__all__ = ["SYSTEM_OF", "detect_dpa", "detect_hoc", "hoc_settings", "load_detector"]

#: Method name -> (module class, training system name).
SYSTEM_OF = {"dpa": (DPA, "DPATuner"), "hoc": (MHOCImage, "LearnedHOCSystem")}


def load_detector(ckpt_path: str | os.PathLike, method: str | None = None) -> DPA | MHOCImage:
    """The plain module of a training checkpoint, checked against ``method``.

    Args:
        ckpt_path: a checkpoint written by ``hocnet train`` (or any Lightning run of
            :class:`~hocnet.learn.DPATuner` / :class:`~hocnet.learn.LearnedHOCSystem`).
        method: ``"dpa"``, ``"hoc"`` or ``None`` (either).

    Returns:
        :class:`~hocnet.dpa.DPA` (hard max) or :class:`~hocnet.hoc.MHOCImage` (hard limiter
        ``c > 0.5`` of learnable layers, :func:`~hocnet.hoc.layers.learned_limiter`), in
        evaluation mode.

    Raises:
        ValueError: a checkpoint of the other system, of neither, a corrupted file, or an
            untrusted pickle (refused by ``weights_only`` loading; nothing of it is run).
        OSError: the file cannot be read (e.g. ``FileNotFoundError``).
    """
    if method is not None:
        method = check_choice("method", method, tuple(SYSTEM_OF))
    try:
        with warnings.catch_warnings():  # torch's note on a pickle's protocol: the error says it
            warnings.filterwarnings(
                "ignore", message="Detected pickle protocol", category=UserWarning
            )
            model = load_model(ckpt_path)
    except ValueError as err:
        raise ValueError(_load_message(ckpt_path, str(err))) from None
    except RuntimeError as err:  # load_state_dict: tensors that do not fit the hyper-parameters
        detail = str(err).splitlines()[0][:100]
        raise ValueError(
            f"`ckpt_path`: {os.fspath(ckpt_path)!r} does not match its hyper-parameters: {detail}"
        ) from None
    if method is not None and not isinstance(model, SYSTEM_OF[method][0]):
        other = next(k for k, (cls, _) in SYSTEM_OF.items() if isinstance(model, cls))
        raise ValueError(
            f"`ckpt_path`: expected a {SYSTEM_OF[method][1]} checkpoint for method {method!r}, "
            f"got a {SYSTEM_OF[other][1]} checkpoint (method {other!r})"
        )
    return model


#: The first bytes of what ``torch.save`` writes: a zip archive, or (legacy) a pickle.
_CHECKPOINT_MAGIC = (b"PK\x03\x04", b"\x80")


def _load_message(ckpt_path: str | os.PathLike, message: str) -> str:
    """One clean line for a checkpoint that cannot be loaded (no unpickler internals).

    A file that starts like nothing ``torch.save`` writes (e.g. a text file) is said to be no
    checkpoint at all; the detail of a failed unpickling (``pop from empty list``) is dropped.
    """
    path = os.fspath(ckpt_path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError:
        head = b""
    if head and not head.startswith(_CHECKPOINT_MAGIC):
        return (
            f"`ckpt_path`: {path!r} is not a checkpoint (torch.save writes a zip archive or a "
            "pickle); expected a .ckpt written by 'hocnet train'"
        )
    return re.sub(r" \(corrupted\?\): .*$", " (corrupted?)", message)


def detect_dpa(frames: torch.Tensor, model: DPA, **kwargs: Any) -> DPADetection:
    """:func:`hocnet.dpa.backtrack.detect` with the matrices, ``b`` and ``g`` of ``model``.

    Uses ``model.weights``, ``model.b``, ``model.g``, ``model.var_table`` and
    ``model.direction_step`` (the learned values of a checkpoint), the hard max.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` whitened frames.
        model: a :class:`~hocnet.dpa.DPA` (fixed or learned).
        **kwargs: the other options of :func:`~hocnet.dpa.backtrack.detect` (``max_targets``,
            ``nms_radius``, ``threshold``, ``target_free``, ``pfa``, ...).

    Returns:
        The :class:`~hocnet.dpa.backtrack.DPADetection`.

    Examples:
        >>> found = detect_dpa(torch.randn(4, 12, 12), DPA(window=5), max_targets=1)
        >>> found.state.asf.shape
        torch.Size([4, 12, 12])
    """
    with torch.no_grad():
        weights, b, g = model.weights.detach(), float(model.b), float(model.g)
    return dpa_detect(
        frames,
        weights,
        b,
        g,
        var_table=model.var_table,
        direction_step=model.direction_step,
        **kwargs,
    )


def hoc_settings(model: MHOCImage) -> dict[str, Any]:
    """``order``, ``v`` and ``delta`` (radians; ``None``: original HOC) of an MHOC module."""
    net = model.forward_net
    return {"order": net.order, "v": net.layers[0].v, "delta": net.delta}


def detect_hoc(
    frames: torch.Tensor,
    model: MHOCImage,
    *,
    threshold: float = DEFAULT_THRESHOLD,
    min_points: int | None = None,
    **kwargs: Any,
) -> HOCResult:
    """Track detection of [LA98] with the support of a (learned) MHOC network.

    The support is ``model(frames)`` in evaluation mode (the learned forward ``Y^(k)`` OR
    backward ``Y^(k)``, section III-B) with each layer's hard limiter: ``c > 0.5`` for learnable
    layers (:func:`~hocnet.hoc.layers.learned_limiter`, our reading, the limiter the training's
    relaxed limiter is centred on), eq. (3) ``c > 0`` for fixed ones. The tracks are identified
    in it by :func:`hocnet.hoc.identify_tracks` with the support as the roots of the five-point
    sequences (our reading: the fixed network's detector also adds the points its fixed moves
    name, which a learned kernel does not define), at the module's ``v`` and ``delta``. No
    density check (the learned network's discrimination bound is unknown).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` binary cube (bool or 0/1).
        model: an :class:`~hocnet.hoc.MHOCImage` (learned or fixed), run in evaluation mode.
        threshold: smallest accepted track score (eq. (8)-(9)).
        min_points: smallest accepted track length; default ``2 * order + 1``.
        **kwargs: other options of :func:`~hocnet.hoc.identify_tracks`.

    Returns:
        :class:`~hocnet.hoc.HOCResult` (``support``, ``tracks``, ``scores``, ``cleaned``) shaped
        like ``frames``.

    Examples:
        >>> f = torch.zeros(8, 12, 12, dtype=torch.bool)
        >>> for t in range(8):
        ...     f[t, 5, 1 + t] = True
        >>> [len(tr) for tr in detect_hoc(f, MHOCImage(order=2, v=1)).tracks]
        [8]
    """
    cube, batched = as_cube("frames", frames, binary=True)
    hp = hoc_settings(model)
    delta = math.pi if hp["delta"] is None else hp["delta"]
    min_points = 2 * hp["order"] + 1 if min_points is None else min_points
    model.eval()
    with torch.no_grad():
        support = model(cube.float()) > 0.5
    tracks, scores, cleaned = identify_tracks(
        support,
        hp["v"],
        delta,
        threshold=threshold,
        min_points=min_points,
        roots=support,
        **kwargs,
    )
    return HOCResult(
        support=restore_batch(support, batched),
        tracks=tracks,
        scores=restore_batch(scores, batched),
        cleaned=restore_batch(cleaned, batched),
    )

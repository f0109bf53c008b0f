"""Thin ``nn.Module`` wrappers of the HOC networks of [LA98].

:class:`ModifiedHOCLayer` (eq. 5-6, Fig. 2) registers its direction-masked and shift kernels and
:class:`HOCLayer` (original HOC, eq. 4) its window kernel as buffers (fixed network) or, with
``learnable=True``, as parameters initialised from the fixed kernels (or at random); their
``forward`` calls :func:`hocnet.hoc.functional.hoc_layer` /
:func:`hocnet.hoc.functional.original_hoc_layer`. :class:`HOCNet` stacks ``order`` layers;
:class:`MHOCImage` combines a forward and a backward stack into the MHOC image of section III-B.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from hocnet._check import as_cube, check_choice, check_int, check_number, restore_batch
from hocnet.hoc import functional as _fn
from hocnet.hoc.functional import Direction, hard_limiter, hoc_layer, original_hoc_layer
from hocnet.hoc.kernels import get_direction_mask_kernels, get_shift_kernels, get_window_kernel

__all__ = [
    "LEARNED_THRESHOLD",
    "HOCLayer",
    "HOCNet",
    "MHOCImage",
    "ModifiedHOCLayer",
    "learned_limiter",
    "relaxed_limiter",
    "ste_limiter",
]

#: Threshold of the hard limiter of a *learnable* layer at evaluation time (our reading):
#: ``g(c) = 1 if c > 0.5``. On the fixed network's integer counts it is eq. (3) of [LA98]
#: (``c > 0`` and ``c > 0.5`` agree on integers), and it is the centre of
#: :func:`relaxed_limiter`, so a learned layer is deployed with the limiter it was trained
#: towards (a real-valued count of 0.3 is "off" in both). Fixed layers keep eq. (3) exactly.
LEARNED_THRESHOLD = 0.5


def learned_limiter(c: torch.Tensor) -> torch.Tensor:
    """Hard limiter of learnable layers (our reading): ``1 if c > 0.5 else 0``, ``c``'s dtype.

    Identical to :func:`~hocnet.hoc.functional.hard_limiter` (eq. 3 of [LA98], ``c > 0``) on
    integer counts, and the limit of :func:`relaxed_limiter` (centred at
    :data:`LEARNED_THRESHOLD`) as its steepness grows; on real-valued learned counts in
    ``(0, 0.5]`` it is "off" where eq. (3) would be "on".

    Examples:
        >>> learned_limiter(torch.tensor([0.0, 0.3, 0.5, 0.7, 2.0])).tolist()
        [0.0, 0.0, 0.0, 1.0, 1.0]
        >>> c = torch.tensor([-1.0, 0.0, 1.0, 2.0])  # integer counts: eq. (3)
        >>> torch.equal(learned_limiter(c), hard_limiter(c))
        True
    """
    return (c > LEARNED_THRESHOLD).to(c.dtype)


def relaxed_limiter(c: torch.Tensor, steepness: float = 8.0) -> torch.Tensor:
    """Smooth surrogate of the hard limiter: ``sigmoid(steepness * (c - 0.5))``.

    Counts of the fixed network are integers, so ``c > 0`` means ``c >= 1``; the surrogate
    switches half-way between 0 and 1 and tends to :func:`learned_limiter` (``c > 0.5``) as
    ``steepness`` grows, hence to :func:`~hocnet.hoc.functional.hard_limiter` on integer inputs.

    Examples:
        >>> relaxed_limiter(torch.tensor([0.0, 1.0]), 20.0).round().tolist()
        [0.0, 1.0]
    """
    return torch.sigmoid(steepness * (c - 0.5))


def ste_limiter(c: torch.Tensor, steepness: float = 8.0) -> torch.Tensor:
    """Straight-through hard limiter: forward ``c > 0.5``, gradient of :func:`relaxed_limiter`.

    The forward is :func:`learned_limiter`, at the relaxed limiter's centre (0.5): the limiter
    a learnable layer uses at evaluation time, so training with ``relax="ste"`` sees exactly
    the deployed network's outputs.

    Examples:
        >>> ste_limiter(torch.tensor([0.2, 0.7])).tolist()
        [0.0, 1.0]
    """
    soft = relaxed_limiter(c, steepness)
    return soft + (learned_limiter(c) - soft).detach()


_RELAX = {"sigmoid": relaxed_limiter, "ste": ste_limiter}


def _check_kernel_bytes(v: int, n_bytes: float) -> None:
    """Refuse kernel banks larger than ``MEMORY_BUDGET`` before allocating them."""
    if n_bytes > _fn.MEMORY_BUDGET:
        raise ValueError(
            f"`v`: expected a velocity window whose kernels fit MEMORY_BUDGET "
            f"({_fn.MEMORY_BUDGET / 2**30:.2g} GiB), got v={v} (about {n_bytes / 2**30:.2g} GiB)"
        )


class ModifiedHOCLayer(nn.Module):
    """One modified-HOC layer (eq. 5-6 of [LA98], Fig. 2) as fixed-weight convolutions.

    Args:
        v: velocity window half-width (pixels per scan); the kernel banks hold
            ``(2v + 1)^4`` values, refused above ``MEMORY_BUDGET`` (``ValueError`` naming ``v``).
        delta: curvature limit in radians, ``(0, pi]``; ``None``: no curvature constraint (a
            three-scan correlation; the original HOC of eq. 4 is :class:`HOCLayer`).
        direction: ``"forward"`` or ``"backward"``.
        learnable: register the kernels as ``nn.Parameter`` instead of buffers.
        init: ``"fixed"`` (start from the paper's masks) or ``"random"`` (uniform in [0, 1)),
            only with ``learnable=True``.
        relax: limiter used in training mode when learnable: ``"sigmoid"`` or ``"ste"``
            (straight-through). Evaluation uses the hard limiter ``c > threshold``.
        steepness: slope of the relaxed limiter.
        seed: seed of the random initialisation.

    Attributes:
        threshold: the hard limiter's threshold outside training: ``0`` for a fixed layer
            (eq. 3 of [LA98] exactly), :data:`LEARNED_THRESHOLD` (0.5, our reading,
            :func:`learned_limiter`) for a learnable one, the centre of the relaxed limiter.
            Both give the same output on 0/1 inputs with the fixed kernels (integer counts).

    Shape:
        - Input: ``(B, T, H, W)`` float 0/1 cube ``Y^(k-1)``.
        - Output: ``(B, T, H, W)`` cube ``Y^(k)``.

    Examples:
        >>> layer = ModifiedHOCLayer(v=1)
        >>> sorted(name for name, _ in layer.named_buffers())
        ['mask_kernels', 'shift_kernels']
        >>> f = torch.zeros(1, 3, 5, 5)
        >>> f[0, 0, 2, 0] = f[0, 1, 2, 1] = f[0, 2, 1, 2] = 1.0  # a 45-degree turn
        >>> layer(f)[0, 0, 2, 0].item()
        1.0
    """

    def __init__(
        self,
        v: int = 4,
        delta: float | None = math.pi / 4,
        direction: Direction = "forward",
        *,
        learnable: bool = False,
        init: str = "fixed",
        relax: str = "sigmoid",
        steepness: float = 8.0,
        seed: int | None = None,
    ) -> None:
        super().__init__()
        self.v = check_int("v", v, minimum=1)
        self.delta = (
            None
            if delta is None
            else check_number("delta", delta, low=0.0, high=math.pi, low_inclusive=False)
        )
        self.direction = check_choice("direction", direction, ("forward", "backward"))
        self.learnable = bool(learnable)
        self.threshold = LEARNED_THRESHOLD if self.learnable else 0.0
        check_choice("init", init, ("fixed", "random"))
        self.relax = check_choice("relax", relax, tuple(_RELAX))
        self.steepness = check_number("steepness", steepness, low=0.0, low_inclusive=False)
        _check_kernel_bytes(self.v, 68.0 * (2 * self.v + 1) ** 4)
        masks = get_direction_mask_kernels(self.v, self.delta)
        shifts = get_shift_kernels(self.v)
        if self.learnable:
            if init == "random":
                gen = torch.Generator().manual_seed(0 if seed is None else int(seed))
                masks = torch.rand(masks.shape, generator=gen)
                shifts = torch.rand(shifts.shape, generator=gen)
            self.mask_kernels = nn.Parameter(masks)
            self.shift_kernels = nn.Parameter(shifts)
        else:
            if init != "fixed":
                raise ValueError("`init`: expected 'fixed' for a fixed layer, got 'random'")
            self.register_buffer("mask_kernels", masks)
            self.register_buffer("shift_kernels", shifts)

    def activation(self) -> Callable[[torch.Tensor], torch.Tensor]:
        """The limiter in use: relaxed while training a learnable layer, hard otherwise.

        Hard: :func:`learned_limiter` (``c > 0.5``) for a learnable layer,
        :func:`~hocnet.hoc.functional.hard_limiter` (eq. 3, ``c > 0``) for a fixed one.
        """
        if not self.learnable:
            return hard_limiter
        if self.training:
            relax = _RELAX[self.relax]
            return lambda c: relax(c, self.steepness)
        return learned_limiter

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        """Apply the layer to a ``(B, T, H, W)`` float cube."""
        return hoc_layer(
            y,
            self.mask_kernels,
            self.shift_kernels,
            direction=self.direction,
            activation=self.activation(),
        )

    def extra_repr(self) -> str:
        """Settings shown by ``repr``."""
        return (
            f"v={self.v}, delta={self.delta}, direction={self.direction!r}, "
            f"learnable={self.learnable}"
        )


class HOCLayer(nn.Module):
    """One original-HOC layer, eq. (4) of [LA98]: a two-scan window correlation.

    ``Y^(k)_t = Y^(k-1)_t * g(conv2d(Y^(k-1)_{t+1}, K_window))`` with the ``(2v + 1)^2``
    window kernel of ones (:func:`~hocnet.hoc.kernels.get_window_kernel`); no curvature or
    velocity-change constraint.

    Args:
        v: velocity window half-width (pixels per scan).
        direction: ``"forward"`` (scan ``t + 1``) or ``"backward"`` (scan ``t - 1``).
        learnable: register the kernel as ``nn.Parameter`` instead of a buffer.
        init: ``"fixed"`` (the paper's window) or ``"random"`` (only with ``learnable=True``).
        relax: limiter used in training mode when learnable: ``"sigmoid"`` or ``"ste"``.
            Evaluation uses the hard limiter ``c > threshold``.
        steepness: slope of the relaxed limiter.
        seed: seed of the random initialisation.

    Attributes:
        threshold: ``0`` for a fixed layer (eq. 3), :data:`LEARNED_THRESHOLD` for a learnable
            one (see :class:`ModifiedHOCLayer`).

    Shape:
        - Input: ``(B, T, H, W)`` float 0/1 cube ``Y^(k-1)``.
        - Output: ``(B, T, H, W)`` cube ``Y^(k)``.

    Examples:
        >>> layer = HOCLayer(v=2)
        >>> layer.window_kernel.shape
        torch.Size([1, 1, 5, 5])
        >>> f = torch.zeros(1, 2, 5, 5)
        >>> f[0, 0, 0, 0] = f[0, 1, 2, 2] = 1.0
        >>> layer(f)[0, :, 0, 0].tolist()
        [1.0, 0.0]
    """

    def __init__(
        self,
        v: int = 4,
        direction: Direction = "forward",
        *,
        learnable: bool = False,
        init: str = "fixed",
        relax: str = "sigmoid",
        steepness: float = 8.0,
        seed: int | None = None,
    ) -> None:
        super().__init__()
        self.v = check_int("v", v, minimum=1)
        self.direction = check_choice("direction", direction, ("forward", "backward"))
        self.learnable = bool(learnable)
        self.threshold = LEARNED_THRESHOLD if self.learnable else 0.0
        check_choice("init", init, ("fixed", "random"))
        self.relax = check_choice("relax", relax, tuple(_RELAX))
        self.steepness = check_number("steepness", steepness, low=0.0, low_inclusive=False)
        _check_kernel_bytes(self.v, 4.0 * (2 * self.v + 1) ** 2)
        window = get_window_kernel(self.v)
        if self.learnable:
            if init == "random":
                gen = torch.Generator().manual_seed(0 if seed is None else int(seed))
                window = torch.rand(window.shape, generator=gen)
            self.window_kernel = nn.Parameter(window)
        else:
            if init != "fixed":
                raise ValueError("`init`: expected 'fixed' for a fixed layer, got 'random'")
            self.register_buffer("window_kernel", window)

    activation = ModifiedHOCLayer.activation

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        """Apply the layer to a ``(B, T, H, W)`` float cube."""
        return original_hoc_layer(
            y, self.window_kernel, direction=self.direction, activation=self.activation()
        )

    def extra_repr(self) -> str:
        """Settings shown by ``repr``."""
        return f"v={self.v}, direction={self.direction!r}, learnable={self.learnable}"


class HOCNet(nn.Module):
    """The HOC network of [LA98]: ``order`` stacked layers, forward or backward in time.

    Args:
        order: number of layers ``k >= 1``; a surviving point starts (forward) or ends
            (backward) a ``(2k + 1)``-scan chain (modified) or a ``(k + 1)``-scan chain
            (original).
        v: velocity window half-width.
        delta: curvature limit in ``(0, pi]`` (:class:`ModifiedHOCLayer`, eq. 5-6), or ``None``
            for the original HOC (:class:`HOCLayer`, eq. 4).
        direction: ``"forward"`` or ``"backward"``.
        learnable: learnable kernels (see :class:`ModifiedHOCLayer`).
        **kwargs: passed to each layer (``init``, ``relax``, ``steepness``, ``seed``).

    Shape:
        - Input: ``(B, T, H, W)`` or ``(T, H, W)``, bool or 0/1 float; ``B = 0`` gives an
          empty output.
        - Output: float cube of the same shape, ``Y^(order)``.

    Examples:
        >>> net = HOCNet(order=2, v=1)
        >>> f = torch.zeros(5, 9, 9)
        >>> for t in range(5):
        ...     f[t, 4, 2 + t] = 1.0
        >>> net(f).nonzero().tolist()
        [[0, 4, 2]]
    """

    def __init__(
        self,
        order: int = 2,
        v: int = 4,
        delta: float | None = math.pi / 4,
        direction: Direction = "forward",
        *,
        learnable: bool = False,
        **kwargs,
    ) -> None:
        super().__init__()
        self.order = check_int("order", order, minimum=1)
        seed = kwargs.pop("seed", None)
        self.delta = delta
        if delta is None:
            layers = (
                HOCLayer(
                    v,
                    direction,
                    learnable=learnable,
                    seed=None if seed is None else seed + i,
                    **kwargs,
                )
                for i in range(self.order)
            )
        else:
            layers = (
                ModifiedHOCLayer(
                    v,
                    delta,
                    direction,
                    learnable=learnable,
                    seed=None if seed is None else seed + i,
                    **kwargs,
                )
                for i in range(self.order)
            )
        self.layers = nn.ModuleList(layers)

    def forward(self, frames: torch.Tensor, *, return_levels: bool = False):
        """Run the stack; with ``return_levels`` also return ``[F, Y^(1), ..., Y^(k)]``."""
        binary = not any(layer.learnable for layer in self.layers)
        cube, batched = as_cube("frames", frames, binary=binary, dtype=torch.float32)
        levels = [cube]
        for layer in self.layers:
            levels.append(layer(levels[-1]))
        out = restore_batch(levels[-1], batched)
        if return_levels:
            return out, [restore_batch(level, batched) for level in levels]
        return out


class MHOCImage(nn.Module):
    """The MHOC image of [LA98] section III-B: forward ``Y^(k)`` OR backward ``Y^(k)``.

    Two :class:`HOCNet` stacks (eq. 5 forward, eq. 10 backward) whose outputs are combined by a
    logical OR (``maximum`` of the 0/1 outputs). For ``T >= 4k`` scans every scan holds output
    (forward ``t <= T - 1 - 2k``, backward ``t >= 2k``). See
    :func:`hocnet.hoc.functional.mhoc_image`.

    Args:
        order: HOC order ``k >= 1``.
        v: velocity window half-width.
        delta: curvature limit in ``(0, pi]``, or ``None`` for the original HOC (eq. 4).
        learnable: learnable kernels (see :class:`ModifiedHOCLayer`).
        **kwargs: passed to each layer (``init``, ``relax``, ``steepness``, ``seed``).

    Shape:
        - Input: ``(B, T, H, W)`` or ``(T, H, W)``, bool or 0/1 float.
        - Output: float cube of the same shape.

    Examples:
        >>> f = torch.zeros(10, 12, 12)
        >>> for t in range(10):
        ...     f[t, 5, 1 + t] = 1.0
        >>> int(MHOCImage(order=2, v=1)(f).sum())
        10
    """

    def __init__(
        self,
        order: int = 2,
        v: int = 4,
        delta: float | None = math.pi / 4,
        *,
        learnable: bool = False,
        **kwargs,
    ) -> None:
        super().__init__()
        self.forward_net = HOCNet(order, v, delta, "forward", learnable=learnable, **kwargs)
        self.backward_net = HOCNet(order, v, delta, "backward", learnable=learnable, **kwargs)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """Forward ``Y^(k)`` OR backward ``Y^(k)`` of a ``(B, T, H, W)`` / ``(T, H, W)`` cube."""
        return torch.maximum(self.forward_net(frames), self.backward_net(frames))

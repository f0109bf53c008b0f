"""The DPA [NR08] as an ``nn.Module``: a thin wrapper of :func:`~hocnet.dpa.functional.accumulate`.

Parameters are fixed by default (the probability matrices are a buffer). Any of ``b``, ``g``,
``p`` and ``penalty`` (the penalty step ``x`` of Figure 2) can be made learnable; they are then
stored unconstrained and mapped to their valid ranges in the property accessors, and the matrices
are rebuilt differentiably from ``p`` and ``penalty_step`` (eq. 5) at every forward pass.
``"matrices"`` instead learns every entry of the ``D`` matrices (the full ``9 x k x k``
parameterisation, our addition; see :func:`full_matrices`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from hocnet._check import check_choice, check_int, check_number
from hocnet.dpa.functional import DIRECTION_STEPS, DPAState, _check_weights, accumulate
from hocnet.dpa.matrices import (
    IN_PLACE,
    N_DIRECTIONS,
    PAPER_PSF,
    PENALTY_TOP,
    _combine,
    _penalty_turns,
    _window,
    basic_matrix,
    effective_memory,
    equalize_gain,
    frame_matrix,
    probability_matrices,
)

__all__ = ["DPA", "full_matrices"]

LEARNABLE = ("b", "g", "p", "penalty", "matrices")
#: Largest penalty step ``x`` (the paper's 3: the opposite side gets ``12 - 4x = 0``).
_X_MAX = PENALTY_TOP / 4
#: Distance kept from the boundary of a constrained parameter when it is initialised on it.
_MARGIN = 1e-6


def _inverse_softplus(x: float) -> float:
    """``y`` with ``softplus(y) == x`` for ``x > 0``."""
    return x + math.log(-math.expm1(-x))


def full_matrices(init: torch.Tensor, total: torch.Tensor, raw: torch.Tensor) -> torch.Tensor:
    r"""The full learnable matrices: a softmax over each matrix's window (our addition).

    ``W(d) = S(d) softmax(log W0(d) + raw(d))`` over the ``k x k`` window of each matrix ``d``,
    computed as ``u = W0 exp(raw)``, ``W = u S / sum(u)`` with ``S = sum(W0)`` (``total``): every
    matrix stays non-negative with the sum of its initial matrix (1 for the matrices of eq. (5)
    of [NR08]), and ``raw = 0`` gives ``W0`` bit for bit (``exp(0) = 1`` and ``S / sum(u) = 1``
    exactly). Entries that are 0 in ``W0`` stay 0 (the matrices of eq. (5) have none: W_basic is
    a Gaussian over the whole window).

    Args:
        init: ``(D, k, k)`` initial matrices ``W0 >= 0``, each with a positive sum.
        total: ``(D, 1, 1)`` their sums ``S`` (``init.sum(dim=(-2, -1), keepdim=True)``).
        raw: ``(D, k, k)`` unconstrained logits (0 at initialisation).

    Returns:
        ``(D, k, k)`` matrices, differentiable in ``raw``.

    Examples:
        >>> w0 = torch.tensor([[[0.25, 0.75]]])
        >>> s = w0.sum(dim=(-2, -1), keepdim=True)
        >>> torch.equal(full_matrices(w0, s, torch.zeros(1, 1, 2)), w0)
        True
        >>> full_matrices(w0, s, torch.tensor([[[math.log(3.0), 0.0]]])).tolist()
        [[[0.5, 0.5]]]
    """
    u = init * torch.exp(raw)
    return u * (total / u.sum(dim=(-2, -1), keepdim=True))


class DPA(nn.Module):
    r"""Dynamic-programming track-before-detect [NR08]: the ASF recursion of eq. (11) as a module.

    ``forward(frames)`` is ``accumulate(frames, self.weights, self.b, self.g, var_table=...,
    smooth=...)``, see :func:`~hocnet.dpa.functional.accumulate`.

    Notes:
        The defaults are the paper's settings: ``g = 0`` (the max recursion, section 3), the
        7 x 7 matrices of eq. (5) for 0-2 px/frame plus 0.5 px jitter with ``p = 0.5`` and the
        penalty step ``x = 3`` (section 2.2.2, Figure 2), the direction step of eq. (6)-(8)
        (``direction_step="paper"``), and ``b = None``, which picks ``b`` from the effective
        memory coefficient ``memory`` (0.8) of direction ``memory_direction`` (9, as the paper
        tunes it: ``b = 4.67`` at ``g = 0``) by :func:`~hocnet.dpa.matrices.effective_memory`.
        ``directional=False`` uses the single matrix ``W(9) = W_basic`` (no direction step,
        ``D = 1``). Learnable parameters are stored unconstrained: ``g = sigmoid(g_raw)`` and
        ``p = sigmoid(p_raw)`` in ``[0, 1]``, ``b = softplus(b_raw) >= 0`` and
        ``penalty_step = 3 sigmoid(penalty_raw)`` in ``[0, 3]``; a learnable value initialised on
        its bound (``g`` or ``p`` in {0, 1}, ``b = 0``, ``penalty_step`` in {0, 3}, so the paper's
        ``x = 3``) starts ``1e-6`` inside it. ``learnable`` with ``"matrices"`` (our addition)
        learns every entry of the ``(D, k, k)`` matrices instead of ``p`` and ``x``: they start
        from ``weights`` (or the matrices of eq. (5) built from the keyword arguments), so the
        initial module equals the fixed one exactly, and stay non-negative with the initial
        sums (:func:`full_matrices`: a softmax over each window, logits ``matrices_raw``).

    Args:
        weights: ``(D, k, k)`` probability matrices (``D`` in {1, 9}); ``None`` builds them with
            :func:`~hocnet.dpa.matrices.probability_matrices` from the keyword arguments.
        b: memory factor ``>= 0``, or ``None`` for the value giving effective memory ``memory``
            in direction ``memory_direction``.
        g: sum/max mixing in ``[0, 1]`` (paper default 0).
        window: odd window size ``k`` (when ``weights`` is ``None``).
        v_max: largest target speed in pixels per frame, without the jitter (W_frame).
        jitter: half-width of the uniform per-axis jitter in pixels.
        psf: FWHM of the Gaussian target spread of W_basic in pixels.
        p: mixing weight of W_basic in eq. (5), in ``[0, 1]``.
        penalty_step: the penalty ``x`` per 45 degrees of turn (Figure 2), in ``[0, 3]``.
        directional: 9 direction-dependent matrices (``True``) or one matrix (``False``).
        learnable: subset of ``("b", "g", "p", "penalty", "matrices")`` to make
            ``nn.Parameter``\ s; ``"p"`` and ``"penalty"`` need ``weights=None`` and
            ``directional=True``; ``"matrices"`` (every matrix entry) excludes ``"p"`` and
            ``"penalty"``.
        smooth: temperature of the log-sum-exp max, or ``None`` for the hard max.
        var_table: optional ``(9, 9)`` direction-similarity table (directional only).
        memory: effective memory coefficient used when ``b`` is ``None``, ``> 0``.
        equal_gain: rescale the direction matrices to the per-step gain of direction 1 at the
            current ``g`` (:func:`~hocnet.dpa.matrices.equalize_gain`, beyond [NR08]: gives
            slow targets, which stay in place, the memory ``b`` was chosen for). Only with
            ``directional=True``; recomputed at every forward pass when ``g`` is learnable.
        direction_step: ``"paper"`` (eq. (6)-(8)) or ``"source"`` (our earlier reading), see
            :func:`~hocnet.dpa.functional.accumulate`.
        memory_direction: the direction 1..9 whose EMC sets ``b`` when ``b`` is ``None``.

    Examples:
        >>> dpa = DPA(window=5, v_max=1.0, g=0.5, learnable=("b", "g"))
        >>> state = dpa(torch.randn(2, 4, 16, 16))
        >>> state.asf.shape, sorted(name for name, _ in dpa.named_parameters())
        (torch.Size([2, 4, 16, 16]), ['b_raw', 'g_raw'])
        >>> round(dpa.g.item(), 4)
        0.5
    """

    def __init__(
        self,
        weights: torch.Tensor | None = None,
        b: float | None = None,
        g: float = 0.0,
        *,
        window: int = 7,
        v_max: float = 2.0,
        jitter: float = 0.5,
        psf: float = PAPER_PSF,
        p: float = 0.5,
        penalty_step: float = 3.0,
        directional: bool = True,
        learnable: Iterable[str] | str = (),
        smooth: float | None = None,
        var_table: torch.Tensor | None = None,
        memory: float = 0.8,
        equal_gain: bool = False,
        direction_step: str = "paper",
        memory_direction: int = 9,
    ) -> None:
        super().__init__()
        if isinstance(learnable, str):
            learnable = (learnable,)
        try:
            names = tuple(learnable)
        except TypeError:
            raise TypeError(
                f"`learnable`: expected a collection of names, got {type(learnable).__name__}"
            ) from None
        for name in names:
            check_choice("learnable", name, LEARNABLE)
        self.learnable = tuple(name for name in LEARNABLE if name in names)
        if not isinstance(equal_gain, bool):
            raise TypeError(f"`equal_gain`: expected a bool, got {type(equal_gain).__name__}")
        if equal_gain and not directional:
            raise ValueError("`equal_gain`: expected False with directional=False (one matrix)")
        self.equal_gain = equal_gain
        self.direction_step = check_choice("direction_step", direction_step, DIRECTION_STEPS)
        memory_direction = check_int("memory_direction", memory_direction, minimum=1, maximum=9)
        g = check_number("g", g, low=0.0, high=1.0)
        p = check_number("p", p, low=0.0, high=1.0)
        penalty_step = check_number("penalty_step", penalty_step, low=0.0, high=_X_MAX)
        if b is not None:
            b = check_number("b", b, low=0.0)
        memory = check_number("memory", memory, low=0.0, low_inclusive=False)
        self.smooth = (
            None if smooth is None else check_number("smooth", smooth, low=0.0, low_inclusive=False)
        )
        rebuild = "p" in self.learnable or "penalty" in self.learnable
        full = "matrices" in self.learnable
        if full and rebuild:
            raise ValueError(
                "`learnable`: expected 'matrices' (every entry) or 'p' / 'penalty' (eq. 5), not "
                f"both, got {self.learnable}"
            )
        if weights is not None:
            if rebuild:
                raise ValueError(
                    "`learnable`: expected no 'p' or 'penalty' with explicit weights (the "
                    f"matrices are rebuilt from p and penalty_step), got {self.learnable}"
                )
            weights = _check_weights(weights, 1 << 30, 1 << 30)
            if not weights.is_floating_point():
                weights = weights.to(torch.get_default_dtype())
            if directional != (weights.shape[0] == N_DIRECTIONS):
                raise ValueError(
                    f"`directional`: expected {weights.shape[0] == N_DIRECTIONS} for weights of "
                    f"shape {tuple(weights.shape)}, got {directional}"
                )
            self.register_buffer("fixed_weights", weights.detach().clone())
        elif full:
            built = probability_matrices(window, v_max, jitter, psf, p, penalty_step)
            fixed = built if directional else built[IN_PLACE : IN_PLACE + 1]
            self.register_buffer("fixed_weights", fixed.contiguous())
        elif rebuild:
            if not directional:
                raise ValueError(
                    f"`learnable`: 'p' and 'penalty' need directional=True, got {self.learnable}"
                )
            k = _window("window", window)
            dtype = torch.get_default_dtype()
            self.register_buffer("basic", basic_matrix(k, 0.0, jitter, psf, dtype=dtype))
            self.register_buffer("frame", frame_matrix(k, v_max, jitter, dtype=dtype))
            self.register_buffer("turns", _penalty_turns(k).to(dtype))
            self.register_buffer("fixed_weights", None)
        else:
            built = probability_matrices(window, v_max, jitter, psf, p, penalty_step)
            fixed = built if directional else built[IN_PLACE : IN_PLACE + 1]
            self.register_buffer("fixed_weights", fixed.contiguous())
        if full:
            init = self.fixed_weights
            total = init.sum(dim=(-2, -1), keepdim=True)
            if not bool((total > 0).all()):
                raise ValueError("`weights`: expected matrices with positive sums for 'matrices'")
            self.register_buffer("matrices_init", init)
            self.register_buffer("matrices_sum", total)
            self.register_buffer("fixed_weights", None)
            self.matrices_raw = nn.Parameter(torch.zeros_like(init))
        if var_table is not None:
            if not directional:
                raise ValueError("`var_table`: expected None with directional=False")
            self.register_buffer("var_table", torch.as_tensor(var_table).detach().clone())
        else:
            self.register_buffer("var_table", None)

        self._store("g", g, lambda x: math.log(x / (1 - x)), 0.0, 1.0)
        self._store("p", p, lambda x: math.log(x / (1 - x)), 0.0, 1.0)
        self._store("penalty", penalty_step, lambda x: math.log(x / (_X_MAX - x)), 0.0, _X_MAX)
        if b is None:
            with torch.no_grad():
                w = self.weights.double()
                b = float(effective_memory(w, g, memory, direction=memory_direction))
        self._store("b", b, _inverse_softplus, 0.0, None)

    def _store(self, name: str, value: float, inverse: Any, low: float, high: float | None) -> None:
        """Register ``name`` as a raw parameter (learnable) or a buffer holding the value."""
        dtype = torch.get_default_dtype()
        if name in self.learnable:
            value = max(value, low + _MARGIN)
            if high is not None:
                value = min(value, high - _MARGIN)
            raw = torch.tensor(inverse(value), dtype=dtype)
            self.register_parameter(f"{name}_raw", nn.Parameter(raw))
        else:
            self.register_buffer(f"{name}_value", torch.tensor(value, dtype=dtype))

    @property
    def b(self) -> torch.Tensor:
        """Memory factor ``b >= 0`` (0-dim tensor)."""
        return F.softplus(self.b_raw) if "b" in self.learnable else self.b_value

    @property
    def g(self) -> torch.Tensor:
        """Sum/max mixing ``g`` in ``[0, 1]`` (0-dim tensor)."""
        return torch.sigmoid(self.g_raw) if "g" in self.learnable else self.g_value

    @property
    def p(self) -> torch.Tensor:
        """Mixing weight ``p`` of W_basic in eq. (5), in ``[0, 1]`` (0-dim tensor)."""
        return torch.sigmoid(self.p_raw) if "p" in self.learnable else self.p_value

    @property
    def penalty_step(self) -> torch.Tensor:
        """The penalty ``x`` in ``[0, 3]`` per 45 degrees of turn, Figure 2 (0-dim tensor)."""
        if "penalty" in self.learnable:
            return _X_MAX * torch.sigmoid(self.penalty_raw)
        return self.penalty_value

    @property
    def weights(self) -> torch.Tensor:
        """The current ``(D, k, k)`` probability matrices.

        Rebuilt from ``p`` and ``penalty_step`` when those are learnable, from the learned
        logits (:func:`full_matrices`) with ``"matrices"``, and rescaled by
        :func:`~hocnet.dpa.matrices.equalize_gain` at the current ``g`` when ``equal_gain``.
        """
        if "matrices" in self.learnable:
            w = full_matrices(self.matrices_init, self.matrices_sum, self.matrices_raw)
        elif self.fixed_weights is not None:
            w = self.fixed_weights
        else:
            w = _combine(self.basic, self.frame, self.turns, self.p, self.penalty_step)
        return equalize_gain(w, self.g) if self.equal_gain else w

    def forward(self, frames: torch.Tensor) -> DPAState:
        """Run :func:`~hocnet.dpa.functional.accumulate` on ``frames``.

        Args:
            frames: ``(B, T, H, W)`` or ``(T, H, W)`` whitened frames.

        Returns:
            :class:`~hocnet.dpa.functional.DPAState` shaped like ``frames``.
        """
        return accumulate(
            frames,
            self.weights,
            self.b,
            self.g,
            var_table=self.var_table,
            smooth=self.smooth,
            direction_step=self.direction_step,
        )

    def extra_repr(self) -> str:
        """Window size, number of matrices, learnable names and the smooth temperature."""
        w = self.weights
        return (
            f"window={w.shape[-1]}, D={w.shape[0]}, learnable={self.learnable}, "
            f"smooth={self.smooth}, equal_gain={self.equal_gain}, "
            f"direction_step={self.direction_step!r}"
        )

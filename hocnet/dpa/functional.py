"""The accumulated score function (ASF) recursion of the DPA [NR08], eq. (2)-(11).

The recursion of eq. (11),

``ASF_n(p) = WF_n(p) + b * (g * sum_q term(q) + (1 - g) * max_q term(q))``, with
``term(q) = W[d_n(p)][q - p] * ASF_{n-1}(q)`` (eq. (6), the paper's direction step: the
direction ``d_n(p)`` of the pixel is estimated first, by eq. (7)-(8)) or, optionally,
``term(q) = W[d_{n-1}(q)][q - p] * ASF_{n-1}(q)`` (each source's own previous direction),

runs as a Python loop over the frames; each step is vectorised over the batch and the pixels.
The window terms are never gathered per pixel: the source-side products ``W[d(q)][o] * ASF(q)``
of every offset ``o`` are written once into a padded buffer, and a zero-copy strided view of that
buffer presents, for every pixel ``p``, its ``k x k`` window of terms. The sum is reduced over the
view with a 0 border, then the border and the impossible moves are set to ``-inf`` and the
max/argmax is reduced over the same view. Each step is one custom autograd function: the backward
pass of the sum is a correlation of the incoming gradient with the matrices (two small matrix
products per frame), that of the hard max a scatter onto the selected terms; the smooth
(log-sum-exp) max recomputes the window terms in its backward pass instead of storing them.
In the paper's direction step, the argmax of eq. (7)-(8) runs on the same source-side buffer
(with ``W_basic * Var`` in place of ``W``) and the weighted sum and max then read a strided view
of the padded ``ASF_{n-1}`` multiplied by each pixel's own matrix ``W[d_n(p)]``.

The public matrices follow the paper's index convention (:mod:`hocnet.dpa.matrices`); they are
flipped once per call to the move convention ``[h + dy, h + dx]``, ``(dx, dy) = p - q``, used
internally.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch.autograd.function import once_differentiable

from hocnet._check import as_cube, check_choice, check_finite, check_number
from hocnet.dpa.matrices import IN_PLACE, N_DIRECTIONS, _sector, b_limit
from hocnet.dpa.matrices import var_table as default_var_table

__all__ = ["DIRECTION_STEPS", "DPAState", "accumulate"]

#: The two readings of the direction step: eq. (6)-(8) of [NR08], or each source's own direction.
DIRECTION_STEPS = ("paper", "source")


@dataclass
class DPAState:
    """Result of :func:`accumulate`: the ASF, the direction map and the tracking matrix.

    The tensors keep the batching of the input frames: ``(B, T, H, W)`` for a batched input and
    ``(T, H, W)`` for an unbatched one (as every hocnet function); ``batched`` records which, and
    :meth:`as_batched` always gives the ``(B, T, H, W)`` form.

    Attributes:
        asf: accumulated score function ``(B, T, H, W)`` in the frames' float dtype.
        direction: ``(B, T, H, W)`` int64 in ``0 .. D - 1``, each pixel's direction in frame
            ``n`` (the group of Figure 4 its source pixel lies in); for ``D = 9`` index ``d - 1``
            is direction ``d`` and index 8 is direction 9 ("in place"); for ``D = 1`` all zeros.
            With ``direction_step="paper"`` it is the matrix index that weighted the pixel's
            window in frame ``n``; with ``"source"`` the one its window uses in frame ``n + 1``.
        origin: ``(B, T, H, W)`` int64 tracking matrix (eq. 8): the flat index ``y * W + x`` of
            each pixel's source pixel in the previous frame; ``-1`` in frame 0.
        batched: whether the input (and so these tensors) had a batch axis.
    """

    asf: torch.Tensor
    direction: torch.Tensor
    origin: torch.Tensor
    batched: bool = True

    def as_batched(self) -> DPAState:
        """The same state with a leading batch axis, ``(B, T, H, W)`` tensors.

        Examples:
            >>> state = accumulate(torch.zeros(3, 5, 5), torch.ones(1, 3, 3) / 9, 0.5, 0.5)
            >>> state.asf.shape, state.as_batched().asf.shape
            (torch.Size([3, 5, 5]), torch.Size([1, 3, 5, 5]))
        """
        if self.batched:
            return self
        return DPAState(
            self.asf.unsqueeze(0), self.direction.unsqueeze(0), self.origin.unsqueeze(0), True
        )


def _check_weights(weights: Any, height: int, width: int) -> torch.Tensor:
    """Validate ``weights`` ``(D, k, k)``: ``D`` in {1, 9}, ``k`` odd and ``<= min(H, W)``."""
    if not isinstance(weights, torch.Tensor):
        try:
            weights = torch.as_tensor(weights)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`weights`: expected a tensor of shape (D, k, k), got {type(weights).__name__}"
            ) from None
    if weights.is_complex() or weights.dtype == torch.bool:
        raise TypeError(f"`weights`: expected a real tensor, got dtype {weights.dtype}")
    if weights.dim() != 3 or weights.shape[0] not in (1, N_DIRECTIONS):
        raise ValueError(
            f"`weights`: expected shape (D, k, k) with D in (1, 9), got {tuple(weights.shape)}"
        )
    _, kh, kw = weights.shape
    if kh != kw or kh % 2 == 0:
        raise ValueError(
            f"`weights`: expected square windows of odd size k, got {tuple(weights.shape)}"
        )
    if kh > min(height, width):
        raise ValueError(
            f"`weights`: expected a window size k <= min(H, W) = {min(height, width)}, got k = {kh}"
        )
    check_finite("weights", weights)
    if bool((weights < 0).any()):
        raise ValueError(f"`weights`: expected non-negative values, got min {weights.min():g}")
    return weights


def _check_scalar(
    name: str, value: Any, low: float, high: float | None, dtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """Validate a scalar (float or one-element tensor, possibly requiring grad) -> 0-dim tensor."""
    check_number(name, value, low=low, high=high)
    if isinstance(value, torch.Tensor):
        return value.reshape(()).to(device=device, dtype=dtype)
    return torch.tensor(float(value), device=device, dtype=dtype)


def _combination_table(var_table: Any, device: torch.device) -> torch.Tensor:
    """Flat ``(81,)`` lookup ``[s * 9 + d_prev] -> argmax_d (V[d, s] + V[d, d_prev])``.

    Ties go to ``s`` (the direction of the last move); among other ties, to the lowest index.
    """
    if not isinstance(var_table, torch.Tensor):
        try:
            var_table = torch.as_tensor(var_table)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`var_table`: expected a (9, 9) table of numbers, got {type(var_table).__name__}"
            ) from None
    if var_table.is_complex() or var_table.dtype == torch.bool:
        raise TypeError(f"`var_table`: expected a real table, got dtype {var_table.dtype}")
    if tuple(var_table.shape) != (N_DIRECTIONS, N_DIRECTIONS):
        raise ValueError(f"`var_table`: expected shape (9, 9), got {tuple(var_table.shape)}")
    check_finite("var_table", var_table)
    v = var_table.detach().to("cpu", torch.float64)
    combo = torch.empty(N_DIRECTIONS * N_DIRECTIONS, dtype=torch.int64)
    for s in range(N_DIRECTIONS):
        for dp in range(N_DIRECTIONS):
            score = v[:, s] + v[:, dp]
            best = score.max()
            combo[s * N_DIRECTIONS + dp] = s if score[s] == best else int(torch.argmax(score))
    return combo.to(device)


class _Window:
    """Scratch buffer and lookup tables for the window terms of one :func:`accumulate` call.

    The window is cropped to the smallest centred square holding every positive weight (offsets
    outside it are never candidates of the max and add 0 to the sum). Channel
    ``c = iy * kc + ix`` (row-major) of the cropped window of pixel ``p`` is the candidate
    ``q = p + (iy - hc, ix - hc)``; the move ``p - q = (hc - ix, hc - iy)`` (as ``(dx, dy)``)
    reads ``W[.][h + hc - iy, h + hc - ix]``.

    The buffer ``(kc * kc, B, H + 2 hc, W + 2 hc)`` holds, for every channel, the source-side
    products ``W[d(q)][move] * ASF(q)`` at ``q``; the zero-copy strided view ``(kc, kc, B, H, W)``
    then presents at ``[iy, ix, b, y, x]`` the term of candidate ``q = p + (iy - hc, ix - hc)``.
    The border holds 0 (for the sum) or ``-inf`` (for the max).
    """

    def __init__(
        self, weights: torch.Tensor, batch: int, height: int, width: int, hc: int | None = None
    ) -> None:
        d, k, _ = weights.shape
        h = k // 2
        device, dtype = weights.device, weights.dtype
        w = weights.detach()
        if hc is None:
            hc = _support_radius(w)
        kc = 2 * hc + 1
        kk = kc * kc
        self.d, self.k, self.h, self.kk_full = d, k, h, k * k
        self.kc, self.hc, self.kk = kc, hc, kk
        self.shape = (batch, height, width)
        crop = w[:, h - hc : h + hc + 1, h - hc : h + hc + 1]
        self.table = crop.flip(-2, -1).reshape(d, kk).t().contiguous()  # (kk, D)
        positive = self.table > 0
        # a zero weight is an impossible move: no candidate of the max (-inf)
        self.shared = bool((positive == positive[:, :1]).all())
        self.zero_channels = torch.nonzero(~positive[:, 0]).flatten() if self.shared else None
        hp, wp = height + 2 * hc, width + 2 * hc
        plane = batch * hp * wp
        self.buf = torch.full((kk, batch, hp, wp), -math.inf, device=device, dtype=dtype)
        self.border = -math.inf
        self.interior = self.buf[:, :, hc : hc + height, hc : hc + width]
        size = (kc, kc, batch, height, width)
        self.view = self.buf.as_strided(size, (kc * plane + wp, plane + 1, hp * wp, wp, 1), 0)
        self.back_strides = ((kc * plane - wp, plane - 1, hp * wp, wp, 1), 2 * hc * wp + 2 * hc)
        iy = torch.arange(kk, device=device) // kc
        ix = torch.arange(kk, device=device) % kc
        self.shift = (iy - hc) * width + (ix - hc)  # flat index change from p to q
        self.chan_dir = _sector(hc - iy, hc - ix)  # direction of the move p - q
        self.full_index = (h + hc - iy) * k + (h + hc - ix)  # flat index of the move in W[d]
        rows = torch.arange(height, device=device).view(height, 1) * width
        self.flat = rows + torch.arange(width, device=device).view(1, width)
        self.in_place = IN_PLACE if d == N_DIRECTIONS else 0

    def _set_border(self, value: float) -> None:
        if self.border == value or self.hc == 0:
            return
        hc, (_, height, _) = self.hc, self.shape
        self.buf[:, :, :hc].fill_(value)
        self.buf[:, :, hc + height :].fill_(value)
        self.buf[:, :, hc : hc + height, :hc].fill_(value)
        self.buf[:, :, hc : hc + height, -hc:].fill_(value)
        self.border = value

    def _write(self, asf: torch.Tensor, direction: torch.Tensor) -> None:
        """Write the products ``W[d(q)][move] * ASF(q)`` of every channel (0 for zero weights)."""
        a = asf.detach()
        if self.d == 1:
            torch.mul(self.table.view(self.kk, 1, 1, 1), a.unsqueeze(0), out=self.interior)
            return
        # one non-zero term per column, so the matrix product is exactly the product W * ASF
        prod = torch.matmul(self.table, _one_hot_asf(a, direction, self.d))  # (B, kk, H * W)
        self.interior.copy_(prod.view(self.shape[0], self.kk, *self.shape[1:]).transpose(0, 1))

    def _exclude(self, direction: torch.Tensor) -> None:
        """Set the terms of impossible moves (zero weight) to ``-inf``."""
        if self.shared:
            if self.zero_channels.numel():
                self.interior.index_fill_(0, self.zero_channels, -math.inf)
            return
        indicator = _one_hot_asf(
            torch.ones_like(direction, dtype=self.table.dtype), direction, self.d
        )
        allowed = torch.matmul((self.table > 0).to(self.table.dtype), indicator)  # (B, kk, H * W)
        impossible = (allowed == 0).view(self.shape[0], self.kk, *self.shape[1:]).transpose(0, 1)
        self.interior.masked_fill_(impossible, -math.inf)

    def candidates(self, asf: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """Window terms ``(kc, kc, B, H, W)``, ``-inf`` for non-candidates (a view, no grad)."""
        self._set_border(-math.inf)
        self._write(asf, direction)
        self._exclude(direction)
        return self.view

    def sum_then_candidates(
        self, asf: torch.Tensor, direction: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The window sums ``(B, H, W)`` and then the candidate terms as in :meth:`candidates`."""
        self._set_border(0.0)
        self._write(asf, direction)
        total = self.view.sum(dim=1).sum(dim=0)
        self._set_border(-math.inf)
        self._exclude(direction)
        return total, self.view

    def argmax(self, view: torch.Tensor) -> torch.Tensor:
        """Channel of the first (row-major) maximum of each window, ``(B, H, W)`` int64."""
        kc = self.kc
        row_best = view.amax(dim=1)  # (kc, B, H, W)
        best, iy = row_best.max(dim=0)  # first row holding the maximum
        row = view.gather(0, iy.unsqueeze(0).unsqueeze(0).expand(1, kc, *self.shape))
        _, ix = row[0].max(dim=0)  # first column of that row holding it
        chan = iy * kc + ix
        empty = best == -math.inf
        if bool(empty.any()):  # no positive-weight candidate: fall back to the centre
            chan = chan.masked_fill(empty, self.kk // 2)
        return chan

    def to_sources(self, dest: torch.Tensor) -> torch.Tensor:
        """Move per-destination window values ``(kc, kc, B, H, W)`` to the candidate pixels.

        ``out[iy, ix, b, q] = dest[iy, ix, b, q - u]`` with ``u = (iy - hc, ix - hc)``, zero where
        ``q - u`` is outside the frame.
        """
        zbuf = torch.zeros_like(self.buf)
        hc, (_, height, width) = self.hc, self.shape
        zbuf[:, :, hc : hc + height, hc : hc + width] = dest.reshape(self.kk, *self.shape)
        strides, offset = self.back_strides
        return zbuf.as_strided((self.kc, self.kc, *self.shape), strides, offset)


def _support_radius(weights: torch.Tensor) -> int:
    """Half-width of the smallest centred square holding every positive weight of ``(D, k, k)``."""
    h = weights.shape[-1] // 2
    support = (weights > 0).any(dim=0)
    dy, dx = torch.nonzero(support, as_tuple=True)
    return int(torch.maximum((dy - h).abs(), (dx - h).abs()).max()) if dy.numel() else 0


class _DestWindow:
    """Windows of ``ASF_{n-1}`` weighted by each destination pixel's own matrix ``W[d_n(p)]``.

    A zero-padded copy ``(B, H + 2 hc, W + 2 hc)`` of the previous ASF and its zero-copy strided
    view ``(kc, kc, B, H, W)``, which holds at ``[iy, ix, b, y, x]`` the ASF of the candidate
    ``q = p + (iy - hc, ix - hc)`` of ``p = (y, x)``; the channel order and the tables are those
    of :class:`_Window` with the same ``hc``.
    """

    def __init__(self, window: _Window) -> None:
        bsz, height, width = window.shape
        hc, kc = window.hc, window.kc
        self.window = window
        self.shape, self.hc, self.kc, self.kk = window.shape, hc, kc, window.kk
        self.d, self.k, self.h = window.d, window.k, window.h
        hp, wp = height + 2 * hc, width + 2 * hc
        dtype, device = window.buf.dtype, window.buf.device
        self.buf = torch.zeros(bsz, hp, wp, dtype=dtype, device=device)
        self.interior = self.buf[:, hc : hc + height, hc : hc + width]
        self.view = self.buf.as_strided((kc, kc, bsz, height, width), (wp, 1, hp * wp, wp, 1), 0)
        iy = torch.arange(kc, device=device).view(kc, 1, 1, 1)
        ix = torch.arange(kc, device=device).view(1, kc, 1, 1)
        y = torch.arange(height, device=device).view(1, 1, height, 1) + iy - hc
        x = torch.arange(width, device=device).view(1, 1, 1, width) + ix - hc
        inside = (y >= 0) & (y < height) & (x >= 0) & (x < width)  # (kc, kc, H, W)
        self.outside = (~inside).unsqueeze(2)  # (kc, kc, 1, H, W)
        self.any_outside = bool(self.outside.any())

    def table(self, weights: torch.Tensor) -> torch.Tensor:
        """``(kk, D)``: column ``d`` holds ``W[d]`` at the move of each channel."""
        h, hc = self.h, self.hc
        crop = weights[:, h - hc : h + hc + 1, h - hc : h + hc + 1]
        return crop.flip(-2, -1).reshape(self.d, self.kk).t()

    def per_pixel(self, table: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """``(kc, kc, B, H, W)``: the weight of each candidate under the pixel's own matrix."""
        return table[:, direction.reshape(-1)].view(self.kc, self.kc, *self.shape)

    def terms(self, asf: torch.Tensor, wp: torch.Tensor) -> torch.Tensor:
        """``W[d(p)][move] * ASF(q)`` for every candidate (0 outside the frame), materialised."""
        self.interior.copy_(asf.detach())
        out = torch.empty(wp.shape, dtype=wp.dtype, device=wp.device)
        return torch.mul(self.view, wp, out=out)

    def exclude(self, terms: torch.Tensor, wp: torch.Tensor) -> torch.Tensor:
        """Set the terms of out-of-frame candidates and impossible moves (weight 0) to ``-inf``."""
        if self.any_outside:
            terms.masked_fill_(self.outside, -math.inf)
        terms.masked_fill_(wp <= 0, -math.inf)
        return terms

    def to_sources(self, dest: torch.Tensor) -> torch.Tensor:
        """Sum over channels of ``dest[c, q - u_c]``: per-candidate values moved to the sources."""
        return self.window.to_sources(dest).sum(dim=(0, 1))


def _one_hot_asf(asf: torch.Tensor, direction: torch.Tensor, d: int) -> torch.Tensor:
    """``(B, D, H * W)``: the ASF placed in the channel of each pixel's direction."""
    flat = asf.reshape(asf.shape[0], 1, -1)
    if d == 1:
        return flat
    out = torch.zeros(asf.shape[0], d, flat.shape[-1], device=asf.device, dtype=asf.dtype)
    return out.scatter_(1, direction.reshape(asf.shape[0], 1, -1), flat)


class _Step(torch.autograd.Function):
    """One step of eq. (11): window sum, (smooth) max and hard argmax of the terms."""

    @staticmethod
    def forward(
        ctx: Any,
        asf: torch.Tensor,
        weights: torch.Tensor,
        direction: torch.Tensor,
        window: _Window,
        tau: float | None,
        need_sum: bool,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if need_sum:
            total, view = window.sum_then_candidates(asf, direction)
        else:
            total, view = torch.zeros_like(asf), window.candidates(asf, direction)
        chan = window.argmax(view)
        if tau is None:
            src = (window.flat + window.shift[chan]).reshape(asf.shape[0], -1)
            a_src = asf.reshape(asf.shape[0], -1).gather(1, src).view_as(asf)
            w_index = window.full_index[chan]
            if window.d != 1:
                d_src = direction.reshape(asf.shape[0], -1).gather(1, src).view_as(asf)
                w_index = w_index + d_src * window.kk_full
            peak = weights.reshape(-1)[w_index] * a_src
            ctx.save_for_backward(asf, weights, direction, src, w_index, a_src)
        else:
            peak = tau * torch.logsumexp(view / tau, dim=(0, 1))
            peak = peak.masked_fill(peak == -math.inf, 0.0)  # no candidate: the centre's 0 term
            ctx.save_for_backward(asf, weights, direction, peak)
        ctx.window, ctx.tau, ctx.need_sum = window, tau, need_sum
        ctx.mark_non_differentiable(chan)
        return total, peak, chan

    @staticmethod
    @once_differentiable
    def backward(
        ctx: Any, grad_total: torch.Tensor, grad_peak: torch.Tensor, _grad_chan: Any
    ) -> tuple[Any, ...]:
        window, tau = ctx.window, ctx.tau
        asf, weights, direction = ctx.saved_tensors[:3]
        bsz = asf.shape[0]
        d, k, h = window.d, window.k, window.h
        want_asf, want_w = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        grad_asf = asf.new_zeros(asf.shape) if want_asf else None
        grad_w = weights.new_zeros(weights.shape) if want_w else None
        if ctx.need_sum and grad_total is not None:
            # windows of the incoming gradient around each source pixel: (k, k, B, H, W) at
            # [iy, ix, b, q] = grad_total[b, q + (iy - h, ix - h)], zero outside the frame
            padded = F.pad(grad_total, (h, h, h, h)).unsqueeze(0)  # (1, B, H + 2h, W + 2h)
            hp, wp = padded.shape[-2:]
            around = padded.as_strided(
                (k, k, *window.shape), (wp, 1, hp * wp, wp, 1), padded.storage_offset()
            )
            around = around.reshape(k * k, -1)  # (k * k, B * H * W)
            if want_asf:
                corr = weights.reshape(d, k * k) @ around  # (D, B * H * W), every direction
                if d != 1:
                    corr = corr.gather(0, direction.reshape(1, -1))
                grad_asf += corr.view_as(grad_asf)
            if want_w:
                onehot = _one_hot_asf(asf, direction, d).transpose(0, 1).reshape(d, -1)
                grad_w += (onehot @ around.t()).view(d, k, k)
        if grad_peak is not None and tau is None:
            src, w_index, a_src = ctx.saved_tensors[3:]
            if want_asf:
                w_sel = weights.reshape(-1)[w_index]
                grad_asf.view(bsz, -1).scatter_add_(1, src, (grad_peak * w_sel).view(bsz, -1))
            if want_w:
                grad_w.view(-1).index_add_(0, w_index.reshape(-1), (grad_peak * a_src).reshape(-1))
        elif grad_peak is not None:
            peak = ctx.saved_tensors[3]
            view = window.candidates(asf, direction)
            prob = torch.exp((view - peak) / tau)  # softmax weights, 0 for non-candidates
            at_src = window.to_sources(prob * grad_peak).reshape(window.kk, -1)  # at sources q
            if want_asf:
                corr = window.table.t() @ at_src  # (D, B * H * W)
                if d != 1:
                    corr = corr.gather(0, direction.reshape(1, -1))
                grad_asf += corr.view_as(grad_asf)
            if want_w:
                kc, hc = window.kc, window.hc
                onehot = _one_hot_asf(asf, direction, d).transpose(0, 1).reshape(d, -1)
                flipped = (onehot @ at_src.t()).view(d, kc, kc)
                grad_w[:, h - hc : h + hc + 1, h - hc : h + hc + 1] += flipped.flip(-2, -1)
        return grad_asf, grad_w, None, None, None, None


class _DestStep(torch.autograd.Function):
    """One step of eq. (11) with the pixel's own matrix ``W[d_n(p)]`` (eq. 6): sum and max."""

    @staticmethod
    def forward(
        ctx: Any,
        asf: torch.Tensor,
        weights: torch.Tensor,
        direction: torch.Tensor,
        window: _DestWindow,
        tau: float | None,
        need_sum: bool,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        table = window.table(weights.detach())
        wp = window.per_pixel(table, direction)
        terms = window.terms(asf, wp)
        total = terms.sum(dim=(0, 1)) if need_sum else torch.zeros_like(asf)
        terms = window.exclude(terms, wp).view(window.kk, *window.shape)
        if tau is None:
            peak, chan = terms.max(dim=0)
            empty = peak == -math.inf
            peak = peak.masked_fill(empty, 0.0)
            ctx.save_for_backward(asf, weights, direction, chan, empty)
        else:
            peak = tau * torch.logsumexp(terms / tau, dim=0)
            peak = peak.masked_fill(peak == -math.inf, 0.0)
            ctx.save_for_backward(asf, weights, direction, peak)
        ctx.window, ctx.tau, ctx.need_sum = window, tau, need_sum
        return total, peak

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad_total: torch.Tensor, grad_peak: torch.Tensor) -> tuple[Any, ...]:
        window, tau = ctx.window, ctx.tau
        asf, weights, direction = ctx.saved_tensors[:3]
        bsz = asf.shape[0]
        d, kk, kc, hc, h = window.d, window.kk, window.kc, window.hc, window.h
        want_asf, want_w = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        grad_asf = asf.new_zeros(asf.shape) if want_asf else None
        grad_w = weights.new_zeros(weights.shape) if want_w else None
        table = window.table(weights.detach())
        wp = window.per_pixel(table, direction)
        coef = None  # (kc, kc, B, H, W): d output / d term of each candidate
        if ctx.need_sum and grad_total is not None:
            coef = grad_total.expand(kc, kc, *window.shape)
        if grad_peak is not None and tau is not None:
            peak = ctx.saved_tensors[3]
            terms = window.exclude(window.terms(asf, wp), wp)
            prob = torch.exp((terms - peak) / tau)  # softmax weights, 0 for non-candidates
            coef = prob * grad_peak if coef is None else coef + prob * grad_peak
        if coef is not None:
            if want_asf:
                grad_asf += window.to_sources(coef * wp)
            if want_w:
                window.interior.copy_(asf.detach())
                prod = torch.empty(coef.shape, dtype=coef.dtype, device=coef.device)
                prod = torch.mul(window.view, coef, out=prod).view(kk, -1)  # (kk, B * H * W)
                onehot = torch.zeros(prod.shape[1], d, dtype=prod.dtype, device=prod.device)
                onehot.scatter_(1, direction.reshape(-1, 1), 1.0)
                per_dir = (prod @ onehot).t().reshape(d, kc, kc).flip(-2, -1)
                grad_w[:, h - hc : h + hc + 1, h - hc : h + hc + 1] += per_dir
        if grad_peak is not None and tau is None:
            chan, empty = ctx.saved_tensors[3:5]
            g_peak = grad_peak.masked_fill(empty, 0.0)
            src = (window.window.flat + window.window.shift[chan]).reshape(bsz, -1)
            w_index = window.window.full_index[chan] + direction * (window.k * window.k)
            if want_asf:
                w_sel = weights.reshape(-1)[w_index]
                grad_asf.view(bsz, -1).scatter_add_(1, src, (g_peak * w_sel).view(bsz, -1))
            if want_w:
                a_src = asf.reshape(bsz, -1).gather(1, src).view_as(asf)
                grad_w.view(-1).index_add_(0, w_index.reshape(-1), (g_peak * a_src).reshape(-1))
        return grad_asf, grad_w, None, None, None, None


def _eq7_weights(weights: torch.Tensor, var_table: torch.Tensor) -> torch.Tensor:
    """``(9, k, k)`` in the move convention: ``W_basic[move] * Var[d_source, dir(move)]`` (eq. 7).

    ``W_basic`` is ``W(9)`` (eq. 5 of [NR08]); index ``d`` of the result is the previous direction
    of the source pixel, so the source-side buffer of :class:`_Window` evaluates eq. (7).
    """
    k = weights.shape[-1]
    h = k // 2
    r = torch.arange(-h, h + 1, device=weights.device)
    dy, dx = torch.meshgrid(r, r, indexing="ij")
    move_dir = _sector(dy, dx)  # (k, k) direction of the move p - q at [h + dy, h + dx]
    v = var_table.to(device=weights.device, dtype=weights.dtype)
    basic = weights[IN_PLACE].detach()
    return basic.unsqueeze(0) * v[:, move_dir.reshape(-1)].view(N_DIRECTIONS, k, k)


def _check_var_positive(var_table: torch.Tensor) -> torch.Tensor:
    """The paper's direction step multiplies by Var (eq. 7): require positive entries."""
    if not isinstance(var_table, torch.Tensor):
        var_table = torch.as_tensor(var_table)
    v = var_table.detach().to("cpu", torch.float64)
    if bool((v <= 0).any()):
        raise ValueError(
            "`var_table`: expected positive values with direction_step='paper' (eq. (7) "
            f"multiplies the score by Var), got min {float(v.min()):g}"
        )
    return v


def _check_memory(b_t: torch.Tensor, g_t: torch.Tensor, weights: torch.Tensor) -> None:
    """``b`` within the memory range of eq. (12)-(14) (:func:`~hocnet.dpa.matrices.b_limit`)."""
    limit = b_limit(weights.detach(), float(g_t.detach()))
    b = float(b_t.detach())
    # rounding of the matrices: float32 sums of 1 can be 1 + 1.2e-7, which must not refuse b = 1
    tol = max(1e-9, 16 * torch.finfo(weights.dtype).eps)
    if b > limit * (1 + tol):
        raise ValueError(
            f"`b`: expected a value in [0, {limit:.6g}] (the memory range of eq. (12)-(14) of "
            f"[NR08] at g = {float(g_t.detach()):g}: above it the effective memory coefficient "
            f"b * (g sum W + (1 - g) max W) exceeds 1 in every direction and the recursion "
            f"grows without bound), got {b:g}"
        )


def _check_overflow(asf: torch.Tensor, n: int, b_t: torch.Tensor, g_t: torch.Tensor) -> None:
    if not bool(torch.isfinite(asf).all()):
        raise ValueError(
            f"`b`: the accumulated score overflowed to inf/NaN at frame {n} although the frames "
            f"are finite: b = {float(b_t.detach()):g} at g = {float(g_t.detach()):g} makes the "
            f"recursion grow geometrically (effective memory coefficient above 1 in some "
            f"direction, eq. (12)-(14) of [NR08]); use a smaller b, fewer frames or float64"
        )


def _check_initial(initial: Any, cube: torch.Tensor, d: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(ASF, direction)`` ``(B, H, W)`` of the last frame of ``initial``, checked on ``cube``."""
    if not isinstance(initial, DPAState):
        raise TypeError(
            "`initial`: expected a DPAState (from accumulate) or None, got "
            f"{type(initial).__name__}"
        )
    s = initial.as_batched()
    bsz, _, height, width = cube.shape
    want = (bsz, height, width)
    if s.asf.dim() != 4 or s.asf.shape[1] == 0 or (s.asf.shape[0], *s.asf.shape[2:]) != want:
        raise ValueError(
            f"`initial`: expected a state of at least one frame of {bsz} scene(s) of "
            f"{height} x {width} (the batch and frame size of `frames`), got asf of shape "
            f"{tuple(initial.asf.shape)}"
        )
    if tuple(s.direction.shape) != tuple(s.asf.shape):
        raise ValueError(
            f"`initial`: expected direction of the shape of its asf {tuple(initial.asf.shape)}, "
            f"got {tuple(initial.direction.shape)}"
        )
    direction = s.direction[:, -1].to(device=cube.device, dtype=torch.int64)
    if direction.numel() and (int(direction.min()) < 0 or int(direction.max()) >= d):
        raise ValueError(
            f"`initial`: expected directions in 0 .. {d - 1} (weights with D = {d}), got "
            f"{int(direction.min())} .. {int(direction.max())}"
        )
    asf = s.asf[:, -1].to(device=cube.device, dtype=cube.dtype)
    check_finite("initial", asf)
    return asf, direction


def accumulate(
    frames: torch.Tensor,
    weights: torch.Tensor,
    b: float | torch.Tensor,
    g: float | torch.Tensor,
    *,
    var_table: torch.Tensor | None = None,
    smooth: float | None = None,
    direction_step: str = "paper",
    initial: DPAState | None = None,
) -> DPAState:
    r"""Accumulate the score function of the DPA over the frames, eq. (2)-(11) of [NR08].

    ``ASF_0 = WF_0``; for ``n >= 1`` and every pixel ``p = (x, y)``, eq. (11) with eq. (6):

    ``ASF_n(p) = WF_n(p) + b * (g * sum_q term(q) + (1 - g) * max_q term(q))``,
    ``term(q) = w[j, i] * ASF_{n-1}(q)`` for the candidates ``q = (x + i, y + j)``

    of the ``k x k`` window centred on ``p`` that lie inside the frame (out-of-frame neighbours
    are excluded, never padded with 0, as whitened scores are often negative), with ``w`` the
    probability matrix of a direction (eq. 5):

    * ``direction_step="paper"`` (default, section 2.2.3-2.2.4): the pixel's direction is
      estimated first. Eq. (7): ``S(q) = ASF_{n-1}(q) * w_basic[j, i] * Var(q)``, with
      ``w_basic = W(9)`` (``weights[8]``) and ``Var(q) = var_table[d_{n-1}(q), dir(p - q)]``
      (the previous direction of ``q`` against the direction of the move from ``q`` to ``p``,
      the groups of Figure 4); eq. (8): the tracking matrix records ``origin_n(p) =
      argmax_q S(q)`` and ``d_n(p)`` is the direction of the move ``p - origin_n(p)``
      (direction 9 for no move); then ``w = W(d_n(p))`` weights the whole window of ``p``.
    * ``direction_step="source"`` (our earlier reading, kept as an option): each source's own
      previous direction picks its weight, ``w = W(d_{n-1}(q))``; ``origin_n(p)`` is the
      argmax of the terms and ``d_n(p)`` the direction of the move ``p - origin_n(p)``,
      combined with ``var_table`` when one is given (see Notes).

    Notes:
        Our reading of [NR08]:

        * **Index convention.** ``weights[d - 1, h + j, h + i]`` weights
          ``ASF_{n-1}(x + i, y + j)`` (eq. 6; rows ``y``, columns ``x``), as
          :func:`~hocnet.dpa.matrices.probability_matrices` builds them.
        * **Candidates of the max.** An offset whose weight is 0 (outside ``W_frame``) is an
          impossible move: it is not a candidate of the max, the argmax or the smooth max (a 0
          term would otherwise win over negative scores, like a padded zero). It adds 0 to the
          sum either way. The candidates of eq. (7) are the in-frame offsets with
          ``w_basic > 0``. If a pixel has no candidate at all (only possible with custom
          weights whose centre is 0), its max term is 0 and its origin is itself.
        * **Ties** of every argmax go to the first candidate in row-major window order (smallest
          row ``y`` of ``q``, then smallest column ``x``).
        * **Var.** ``var_table=None`` means :func:`~hocnet.dpa.matrices.var_table` (6 for the
          same direction, minus 1 per 45 degrees, 4 between direction 9 and a moving one) with
          the paper's step, and no table with ``"source"``. With ``"source"`` and a table ``V``,
          ``d_n(p) = argmax_d (V[d, s] + V[d, d_{n-1}(origin)])`` with ``s`` the move's
          direction; ties go to ``s``, then to the lowest index (with the default table the rule
          returns ``s``).
        * Frame 0: every pixel has direction 9 (index 8) for ``D = 9``, 0 for ``D = 1``.
          ``D = 1``: no direction step (both readings agree); every pixel uses ``weights[0]``
          and the origin is the argmax of the terms.
        * **Memory range.** ``b`` must lie in ``[0, b_max]`` with ``b_max`` from
          :func:`~hocnet.dpa.matrices.b_limit` (eq. (12)-(14): above it every direction's
          effective memory coefficient exceeds 1); and if the recursion still overflows (a long
          sequence with an EMC above 1 in some direction) a ``ValueError`` naming ``b`` is
          raised: the output never holds NaN/inf.
        * ``smooth = tau`` replaces the max by ``tau * logsumexp(term / tau)`` over the
          candidates (``tau -> 0`` gives the hard max); origin and direction still use the
          hard argmax.
        * An empty batch (``B = 0``) gives an empty state.
        * **Eq. (7) favours short moves.** The paper step scores each source by
          ``ASF_{n-1}(q) * w_basic * Var``; ``w_basic`` (a standing target's spread) is about
          0.17 in place, 0.10 one pixel out and 0.02 two pixels out (7 x 7), so a source 2 px
          away along an axis wins only if its ASF is 6-9 times that of the pixel itself (10-15
          times at (2, 1)). A difference from
          [NR08] (which finds the algorithm effective near 1 px/frame and better for faster
          targets, section 3.2.1(2)-(3), but sampled targets only up to about 1.5 px/frame,
          NA23 at s_n = 5): in our clear-sky scenes at 17 dB (7 x the noise;
          ``dpa-pd-snr`` speed table and its ablation rows, 20 scenes) faster targets are
          back-tracked with a lag, and the measured causes differ with ``g``. At ``g = 1`` it
          is this ``w_basic``: eq. (7) with the source's own ``W(d)`` instead (not the paper's)
          lifts the frames on the truth at 1.5 / 2 px/frame from 0.27 / 0.08 to 0.87 / 0.62.
          At ``g = 0`` it is the memory: with ``b`` = 4.67 the pixels the target left keep
          ``b max W(9)`` = 0.8 of their ASF per frame and the origins point back along that
          trail; ``b`` = 2.34 or 0 lifts 1 px/frame from 0.40 to about 0.8, whereas ``p = 0``,
          ``W(d)`` in eq. (7) or ``direction_step="source"`` (which does not use ``w_basic``)
          leave it at 0.41-0.44. At the paper's 30 and 60 x the noise the same paper DPA stays
          on the truth in >= 0.9 of the frames up to 1.5 px/frame (README, *Target speed*).
          The product is also multiplicative: with whitened (negative) ASF values a larger
          ``Var`` makes the score more negative. Both are the paper's eq. (7) as printed;
          ``direction_step="source"`` tracks faster targets better with ``g = 1`` (README, DPA
          results).

    Args:
        frames: whitened frames ``(B, T, H, W)`` or ``(T, H, W)``, finite, float (integer
            input is converted to the default float dtype).
        weights: probability matrices ``(D, k, k)``, ``D`` in {1, 9}, ``k`` odd and
            ``<= min(H, W)``, non-negative, paper index convention (see Notes).
        b: memory factor in ``[0, b_limit(weights, g)]`` (float or one-element tensor;
            gradients flow to it).
        g: sum/max mixing in ``[0, 1]`` (float or one-element tensor; gradients flow to it).
        var_table: optional ``(9, 9)`` direction-similarity table (only with ``D = 9``; positive
            entries with ``direction_step="paper"``).
        smooth: temperature ``tau > 0`` of a log-sum-exp max, or ``None`` for the hard max.
        direction_step: ``"paper"`` (eq. (6)-(8)) or ``"source"``.
        initial: the state of the frames before ``frames`` (a :class:`DPAState` returned by an
            earlier call on the same scenes, ``(B, T', H, W)`` or ``(T', H, W)``, ``T' >= 1``),
            or ``None`` (``frames[0]`` is frame 0: ``ASF_0 = WF_0``). Given, the recursion
            continues from its last frame: ``frames[0]`` is the frame after it, with
            ``ASF_{n-1}`` and ``d_{n-1}`` read from ``initial``, so calling
            ``accumulate(frames[:n])`` and then ``accumulate(frames[n:], initial=...)`` with
            the first result gives, frame by frame, the ``asf``, ``direction`` and ``origin`` of
            ``accumulate(frames)`` (streaming, one frame at a time; our addition). Only its
            last frame is read; gradients flow into its ``asf``.

    Returns:
        :class:`DPAState` with ``asf``, ``direction`` and ``origin`` shaped like ``frames``
        (``(B, T, H, W)``, or ``(T, H, W)`` for unbatched input; with ``initial``, the frames of
        this call only). ``asf`` is differentiable w.r.t. ``frames``, ``weights``, ``b`` and
        ``g`` (and ``initial.asf``).

    Raises:
        TypeError: if an argument has the wrong type.
        ValueError: on wrong shapes, out-of-range values (``b`` above the memory range),
            non-finite input, an overflow of the recursion (naming ``b``), or an ``initial``
            state of another batch size, frame size or number of directions.

    Examples:
        >>> frames = torch.zeros(4, 9, 9)
        >>> frames[:, 4, 2:6] = torch.eye(4)  # a target moving +x, one pixel per frame
        >>> weights = torch.ones(1, 3, 3) / 9
        >>> state = accumulate(frames, weights, b=1.0, g=0.0)
        >>> state.asf.shape, state.origin[3, 4, 5].item() == 4 * 9 + 4
        (torch.Size([4, 9, 9]), True)
        >>> step = accumulate(frames[:3], weights, b=1.0, g=0.0)  # frame by frame
        >>> step = accumulate(frames[3:], weights, b=1.0, g=0.0, initial=step)
        >>> torch.equal(step.asf[0], state.asf[3]), step.origin[0, 4, 5].item() == 4 * 9 + 4
        (True, True)
    """
    cube, batched = as_cube("frames", frames)
    if not cube.is_floating_point():
        cube = cube.to(torch.get_default_dtype())
    bsz, n_frames, height, width = cube.shape
    device, dtype = cube.device, cube.dtype
    weights = _check_weights(weights, height, width).to(device=device, dtype=dtype)
    b_t = _check_scalar("b", b, 0.0, None, dtype, device)
    g_t = _check_scalar("g", g, 0.0, 1.0, dtype, device)
    tau = None if smooth is None else check_number("smooth", smooth, low=0.0, low_inclusive=False)
    mode = check_choice("direction_step", direction_step, DIRECTION_STEPS)
    d = weights.shape[0]
    combo = None
    v_paper = None
    if var_table is not None:
        if d != N_DIRECTIONS:
            raise ValueError(
                "`var_table`: expected None for weights with D = 1 (no direction step), "
                f"got a table of shape {tuple(torch.as_tensor(var_table).shape)}"
            )
        combo = _combination_table(var_table, device)
    if mode == "paper" and d == N_DIRECTIONS:
        v_paper = _check_var_positive(default_var_table() if var_table is None else var_table)
    _check_memory(b_t, g_t, weights)
    start = None if initial is None else _check_initial(initial, cube, d)
    if bsz == 0:
        empty = cube.new_zeros(cube.shape)
        index = torch.zeros(cube.shape, dtype=torch.int64, device=device)
        state = DPAState(empty + 0 * b_t + 0 * g_t, index, index - 1, True)
        return state if batched else DPAState(state.asf[0], index[0], index[0] - 1, False)

    w_int = weights.flip(-2, -1)  # paper convention [h + j, h + i] -> moves [h + dy, h + dx]
    window = _Window(w_int, bsz, height, width)
    dest = eq7 = None
    if v_paper is not None:
        eq7 = _Window(_eq7_weights(w_int, v_paper), bsz, height, width, hc=window.hc)
        dest = _DestWindow(window)
    need_sum = g_t.requires_grad or float(g_t) != 0.0
    one_minus_g = 1 - g_t

    if start is None:
        asf = [cube[:, 0]]
        direction = [torch.full((bsz, height, width), window.in_place, device=device)]
        origin = [torch.full((bsz, height, width), -1, device=device, dtype=torch.int64)]
    else:  # continue from the last frame of `initial` (not part of the result)
        asf, direction = [start[0]], [start[1]]
        origin = [start[1]]  # a placeholder: skipped below
    first = 0 if start is not None else 1
    for n in range(first, n_frames):
        prev, d_prev = asf[-1], direction[-1]
        if dest is not None:
            chan = eq7.argmax(eq7.candidates(prev, d_prev))  # eq. (7)-(8)
            move = window.chan_dir[chan]
            total, peak = _DestStep.apply(prev, w_int, move, dest, tau, need_sum)
        else:
            total, peak, chan = _Step.apply(prev, w_int, d_prev, window, tau, need_sum)
            move = window.chan_dir[chan]
        mixed = one_minus_g * peak
        if need_sum:
            mixed = g_t * total + mixed
        current = cube[:, n] + b_t * mixed
        _check_overflow(current.detach(), n, b_t, g_t)
        asf.append(current)
        src = window.flat + window.shift[chan]  # (B, H, W) flat index of the origin
        origin.append(src)
        if d == 1:
            direction.append(d_prev)
            continue
        if dest is None and combo is not None:
            d_src = d_prev.reshape(bsz, -1).gather(1, src.reshape(bsz, -1)).view_as(src)
            move = combo[move * N_DIRECTIONS + d_src]
        direction.append(move)
    skip = 1 - first  # with `initial`, its last frame is not returned
    state = DPAState(
        torch.stack(asf[skip:], dim=1),
        torch.stack(direction[skip:], dim=1),
        torch.stack(origin[skip:], dim=1),
        True,
    )
    if batched:
        return state
    return DPAState(state.asf[0], state.direction[0], state.origin[0], False)

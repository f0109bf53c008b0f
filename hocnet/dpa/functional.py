"""The accumulated score function (ASF) recursion of the DPA [NR08], eq. (2)-(11).

The recursion of eq. (11),

``ASF_n(p) = WF_n(p) + b * (g * sum_q term(q) + (1 - g) * max_q term(q))``, with
``term(q) = W[d_{n-1}(q)][p - q] * ASF_{n-1}(q)``,

runs as a Python loop over the frames; each step is vectorised over the batch and the pixels.
The window terms are never gathered per pixel: the source-side products ``W[d(q)][o] * ASF(q)``
of every offset ``o`` are written once into a padded buffer, and a zero-copy strided view of that
buffer presents, for every pixel ``p``, its ``k x k`` window of terms. The sum is reduced over the
view with a 0 border, then the border and the impossible moves are set to ``-inf`` and the
max/argmax is reduced over the same view. Each step is one custom autograd function: the backward
pass of the sum is a correlation of the incoming gradient with the matrices (two small matrix
products per frame), that of the hard max a scatter onto the selected terms; the smooth
(log-sum-exp) max recomputes the window terms in its backward pass instead of storing them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch.autograd.function import once_differentiable

from hocnet._check import as_cube, check_finite, check_number
from hocnet.dpa.matrices import IN_PLACE, N_DIRECTIONS, _sector

__all__ = ["DPAState", "accumulate"]


@dataclass
class DPAState:
    """Result of :func:`accumulate`: the ASF, the direction map and the tracking matrix.

    The tensors keep the batching of the input frames: ``(B, T, H, W)`` for a batched input and
    ``(T, H, W)`` for an unbatched one (DESIGN section 2); ``batched`` records which, and
    :meth:`as_batched` always gives the ``(B, T, H, W)`` form.

    Attributes:
        asf: accumulated score function ``(B, T, H, W)`` in the frames' float dtype.
        direction: ``(B, T, H, W)`` int64 in ``0 .. D - 1``, the index into ``weights`` used by
            each pixel in the next step; for ``D = 9`` index ``d - 1`` is direction ``d`` and index
            8 is direction 9 ("in place"); for ``D = 1`` all zeros.
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

    def __init__(self, weights: torch.Tensor, batch: int, height: int, width: int) -> None:
        d, k, _ = weights.shape
        h = k // 2
        device, dtype = weights.device, weights.dtype
        w = weights.detach()
        support = (w > 0).any(dim=0)
        dy, dx = torch.nonzero(support, as_tuple=True)
        hc = int(torch.maximum((dy - h).abs(), (dx - h).abs()).max()) if dy.numel() else 0
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


def accumulate(
    frames: torch.Tensor,
    weights: torch.Tensor,
    b: float | torch.Tensor,
    g: float | torch.Tensor,
    *,
    var_table: torch.Tensor | None = None,
    smooth: float | None = None,
) -> DPAState:
    r"""Accumulate the score function of the DPA over the frames, eq. (11) of [NR08].

    ``ASF_0 = WF_0``; for ``n >= 1`` and every pixel ``p``:

    ``ASF_n(p) = WF_n(p) + b * (g * sum_q term(q) + (1 - g) * max_q term(q))``,
    ``term(q) = W[d_{n-1}(q)][p - q] * ASF_{n-1}(q)``,

    the probability-weighted score of a target at ``q`` in frame ``n - 1`` moving to ``p``. The
    candidates ``q`` are the pixels of the ``k x k`` window centred on ``p`` that lie inside the
    frame (out-of-frame neighbours are excluded, never padded with 0, as whitened scores are often
    negative). ``origin_n(p)`` (the tracking matrix, eq. 8) is the flat index ``y * W + x`` of
    the ``q`` with the largest term, and ``d_n(p)`` the direction estimated from that move.

    Notes:
        Our reading of [NR08]:

        * **Candidates of the max.** An offset whose weight is 0 (outside ``W_frame``) is an
          impossible move: it is not a candidate of the max, the argmax or the smooth max (a 0
          term would otherwise win over negative scores, like a padded zero). It adds 0 to the
          sum either way. If a pixel has no candidate at all (only possible with custom weights
          whose centre is 0), its max term is the centre's, 0, and its origin is itself.
        * **Ties** of the argmax go to the first candidate in row-major window order (smallest
          row ``y`` of ``q``, then smallest column ``x``).
        * **Direction estimation (section 2.2.3, eq. 7).** The direction of the move is the
          compass sector (8 sectors of 45 degrees centred on 0, 45, ..., 315 degrees, bearing
          ``atan2(dy, dx)``, see :mod:`hocnet.dpa.matrices` for the axes) of ``p - origin_n(p)``,
          or direction 9 ("in place") for a zero move. Without ``var_table`` that is ``d_n(p)``.
          With ``var_table`` ``V``, it is combined with the origin's previous direction:
          ``d_n(p) = argmax_d (V[d, s] + V[d, d_{n-1}(origin)])`` with ``s`` the move's
          direction; ties go to ``s``, then to the lowest index. (With the default
          :func:`~hocnet.dpa.matrices.var_table`, ``6 - distance`` is maximised on the whole
          arc between ``s`` and ``d_{n-1}``, so the rule returns ``s``: the table only matters
          for custom tables.)
        * Frame 0: every pixel has direction 9 (index 8) for ``D = 9``, 0 for ``D = 1``.
          ``D = 1``: no direction step; every pixel uses ``weights[0]``.
        * ``smooth = tau`` replaces the max by ``tau * logsumexp(term / tau)`` over the
          candidates (``tau -> 0`` gives the hard max); origin and direction still use the
          hard argmax.

    Args:
        frames: whitened frames ``(B, T, H, W)`` or ``(T, H, W)``, finite, float (integer
            input is converted to the default float dtype).
        weights: probability matrices ``(D, k, k)``, ``D`` in {1, 9}, ``k`` odd and
            ``<= min(H, W)``, non-negative, indexed ``[d, h + dy, h + dx]`` for the move
            ``(dx, dy) = p - q`` (see :func:`~hocnet.dpa.matrices.probability_matrices`).
        b: memory factor ``>= 0`` (float or one-element tensor; gradients flow to it).
        g: sum/max mixing in ``[0, 1]`` (float or one-element tensor; gradients flow to it).
        var_table: optional ``(9, 9)`` direction-similarity table (only with ``D = 9``).
        smooth: temperature ``tau > 0`` of a log-sum-exp max, or ``None`` for the hard max.

    Returns:
        :class:`DPAState` with ``asf``, ``direction`` and ``origin`` shaped like ``frames``
        (``(B, T, H, W)``, or ``(T, H, W)`` for unbatched input). ``asf`` is differentiable
        w.r.t. ``frames``, ``weights``, ``b`` and ``g``.

    Raises:
        TypeError: if an argument has the wrong type.
        ValueError: on wrong shapes, out-of-range values or non-finite input.

    Examples:
        >>> frames = torch.zeros(4, 9, 9)
        >>> frames[:, 4, 2:6] = torch.eye(4)  # a target moving +x, one pixel per frame
        >>> weights = torch.ones(1, 3, 3) / 9
        >>> state = accumulate(frames, weights, b=1.0, g=0.0)
        >>> state.asf.shape, state.origin[3, 4, 5].item() == 4 * 9 + 4
        (torch.Size([4, 9, 9]), True)
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
    d = weights.shape[0]
    combo = None
    if var_table is not None:
        if d != N_DIRECTIONS:
            raise ValueError(
                "`var_table`: expected None for weights with D = 1 (no direction step), "
                f"got a table of shape {tuple(torch.as_tensor(var_table).shape)}"
            )
        combo = _combination_table(var_table, device)

    window = _Window(weights, bsz, height, width)
    need_sum = g_t.requires_grad or float(g_t) != 0.0
    one_minus_g = 1 - g_t

    asf = [cube[:, 0]]
    direction = [torch.full((bsz, height, width), window.in_place, device=device)]
    origin = [torch.full((bsz, height, width), -1, device=device, dtype=torch.int64)]
    for n in range(1, n_frames):
        prev, d_prev = asf[-1], direction[-1]
        total, peak, chan = _Step.apply(prev, weights, d_prev, window, tau, need_sum)
        mixed = one_minus_g * peak
        if need_sum:
            mixed = g_t * total + mixed
        asf.append(cube[:, n] + b_t * mixed)
        src = window.flat + window.shift[chan]  # (B, H, W) flat index of the origin
        origin.append(src)
        if d == 1:
            direction.append(d_prev)
            continue
        move = window.chan_dir[chan]
        if combo is not None:
            d_src = d_prev.reshape(bsz, -1).gather(1, src.reshape(bsz, -1)).view_as(src)
            move = combo[move * N_DIRECTIONS + d_src]
        direction.append(move)
    state = DPAState(
        torch.stack(asf, dim=1), torch.stack(direction, dim=1), torch.stack(origin, dim=1), True
    )
    if batched:
        return state
    return DPAState(state.asf[0], state.direction[0], state.origin[0], False)

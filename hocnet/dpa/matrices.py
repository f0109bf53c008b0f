"""Probability matrices, direction table and effective memory of the DPA [NR08].

Pure kernel builders in the style of kornia's ``get_*_kernel``: every function returns a fresh
tensor on the requested ``device`` / ``dtype`` and holds no state. The matrices feed
:func:`hocnet.dpa.functional.accumulate`.

Window convention (used by every builder and by :func:`~hocnet.dpa.functional.accumulate`): a
``(k, k)`` matrix ``M`` with ``h = k // 2`` holds at ``M[h + dy, h + dx]`` the value for the
displacement ``(dx, dy)`` of a target from a pixel ``q`` of frame ``n - 1`` to a pixel ``p`` of
frame ``n``, i.e. ``(dx, dy) = p - q`` in ``(x = column, y = row)`` image coordinates. The row
index grows downwards, so **+y points down** on a displayed image. Bearings are
``atan2(dy, dx)`` (DESIGN section 2), so the directions 1..8 at 0, 45, ..., 315 degrees turn
counter-clockwise in the ``(x, y)`` frame, which is *clockwise* on screen: direction 1 is +x
(right), direction 3 (90 degrees) is +y (down), direction 5 is -x (left), direction 7 is -y (up).
Direction 9 is "in place" (no preferred direction). In tensors, direction ``d`` is stored at index
``d - 1`` (so index 8 is direction 9).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from hocnet._check import check_finite, check_int, check_number

__all__ = [
    "b_versus_g",
    "basic_matrix",
    "effective_memory",
    "equalize_gain",
    "frame_matrix",
    "memory_line",
    "penalty_matrices",
    "penalty_matrix_in_place",
    "probability_matrices",
    "var_table",
]

#: Number of direction-dependent matrices (directions 1..8 plus 9 = in place).
N_DIRECTIONS = 9
#: Index of direction 9 ("in place") in direction tensors.
IN_PLACE = 8
#: Sub-samples per pixel of the velocity-disc quadrature of :func:`basic_matrix`.
_SUBGRID = 32
#: FWHM -> standard deviation of a Gaussian.
_FWHM_TO_SIGMA = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))


def _window(name: str, window: int) -> int:
    """Validate an odd window size ``k >= 1``."""
    k = check_int(name, window, minimum=1)
    if k % 2 == 0:
        raise ValueError(f"`{name}`: expected an odd integer, got {k}")
    return k


def _dtype(dtype: torch.dtype | None) -> torch.dtype:
    return torch.get_default_dtype() if dtype is None else dtype


def _offsets(k: int, device: torch.device | str | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Integer displacement grids ``(dy, dx)`` of a ``(k, k)`` window, each ``(k, k)`` int64."""
    h = k // 2
    r = torch.arange(-h, h + 1, device=device)
    dy, dx = torch.meshgrid(r, r, indexing="ij")
    return dy, dx


def _sector(dy: torch.Tensor, dx: torch.Tensor) -> torch.Tensor:
    """Compass sector index (0..7 for directions 1..8, 8 for a zero move) of integer moves.

    The sectors are 45 degrees wide and centred on 0, 45, ..., 315 degrees. No integer move lies on
    a sector boundary (``tan(22.5 deg)`` is irrational), so rounding is unambiguous.
    """
    angle = torch.atan2(dy.to(torch.float64), dx.to(torch.float64))
    sector = torch.round(angle / (math.pi / 4)).to(torch.int64) % 8
    return torch.where((dy == 0) & (dx == 0), torch.full_like(sector, IN_PLACE), sector)


def _turn_steps(k: int, device: torch.device | str | None = None) -> torch.Tensor:
    """Turn between each offset of the window and each direction 1..8, in 45-degree steps.

    Returns:
        ``(8, k, k)`` int64 in ``0..4``; the centre (no move) gets 0 (no turn).
    """
    dy, dx = _offsets(k, device)
    sector = _sector(dy, dx)
    direction = torch.arange(8, device=device).view(8, 1, 1)
    diff = (sector.unsqueeze(0) - direction).abs() % 8
    steps = torch.minimum(diff, 8 - diff)
    h = k // 2
    steps[:, h, h] = 0
    return steps


def _step_cdf(c: torch.Tensor, sigma: float, a: float) -> torch.Tensor:
    """``P(n + u <= c)`` for ``n ~ N(0, sigma^2)`` and ``u ~ U[-a, a]`` independent (float64)."""
    if sigma > 0 and a > 0:

        def antiderivative(z: torch.Tensor) -> torch.Tensor:  # integral of Phi
            return z * torch.special.ndtr(z) + torch.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)

        return sigma / (2 * a) * (antiderivative((c + a) / sigma) - antiderivative((c - a) / sigma))
    if sigma > 0:
        return torch.special.ndtr(c / sigma)
    if a > 0:
        return ((c + a) / (2 * a)).clamp(0.0, 1.0)
    return (c > 0).to(c.dtype) + 0.5 * (c == 0).to(c.dtype)


def basic_matrix(
    window: int = 7,
    v_max: float = 1.0,
    jitter: float = 0.5,
    psf: float = 3.0,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    r"""W_basic of [NR08]: where the target's apparent displacement between frames falls.

    The displacement is ``v + n + u`` with the velocity ``v`` uniform in the disc
    ``|v| <= v_max`` (pixels per frame), ``n`` the Gaussian spread of the PSF and ``u`` the sensor
    jitter, uniform in ``[-jitter, jitter]`` on each axis. The entry at offset ``(dx, dy)`` is the
    probability that the displacement lands in the pixel cell ``[dx - 1/2, dx + 1/2] x
    [dy - 1/2, dy + 1/2]``, normalised so that the window sums to 1 (mass falling outside the
    window is dropped).

    Notes:
        Our reading of [NR08]: ``psf`` is the full width at half maximum (FWHM) of the Gaussian
        PSF in pixels, so the spread has standard deviation ``sigma = psf / (2 sqrt(2 ln 2))``
        (``psf = 3`` gives ``sigma = 1.27``; ``psf = 0`` means no blur). With this reading the
        7 x 7, 0-2.5 px/frame matrix reproduces the paper's eq. (15) constants to about 1 %
        (see :func:`memory_line`). The Gaussian and the jitter are integrated in closed form per
        axis over each pixel cell; the velocity disc is integrated numerically on a sub-grid of
        1/32 pixel (a node is inside the disc when its centre is).

    Args:
        window: odd window size ``k``.
        v_max: largest target speed in pixels per frame, ``>= 0``.
        jitter: half-width ``a`` of the uniform per-axis jitter in pixels, ``>= 0``.
        psf: FWHM of the Gaussian PSF in pixels, ``>= 0``.
        device: device of the result.
        dtype: floating dtype of the result (default: torch's default dtype).

    Returns:
        ``(k, k)`` matrix, non-negative, summing to 1, indexed ``[h + dy, h + dx]``.

    Examples:
        >>> w = basic_matrix(5, v_max=1.0, jitter=0.5, psf=3.0)
        >>> w.shape, round(float(w.sum()), 6)
        (torch.Size([5, 5]), 1.0)
        >>> bool(w[2, 2] == w.max())
        True
    """
    k = _window("window", window)
    v_max = check_number("v_max", v_max, low=0.0)
    a = check_number("jitter", jitter, low=0.0)
    psf = check_number("psf", psf, low=0.0)
    sigma = psf * _FWHM_TO_SIGMA

    reach = math.ceil(v_max * _SUBGRID)
    nodes = torch.arange(-reach, reach + 1, dtype=torch.float64) / _SUBGRID
    inside = (nodes[:, None] ** 2 + nodes[None, :] ** 2) <= v_max**2 * (1 + 1e-12)
    disc = inside.to(torch.float64)
    disc = disc / disc.sum()  # (Nv, Nv), rows vy, columns vx

    h = k // 2
    m = torch.arange(-h, h + 1, dtype=torch.float64)
    # cell[i, j] = P(axis displacement lands in cell m_i | velocity component nodes_j)
    cell = _step_cdf(m[:, None] + 0.5 - nodes[None, :], sigma, a) - _step_cdf(
        m[:, None] - 0.5 - nodes[None, :], sigma, a
    )
    prob = cell @ disc @ cell.T  # [dy, dx]
    prob = prob.clamp_min(0.0)
    prob = prob / prob.sum()
    return prob.to(device=device, dtype=_dtype(dtype))


def frame_matrix(
    window: int = 7,
    v_max: float = 1.0,
    jitter: float = 0.5,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    r"""W_frame of [NR08]: the 0/1 support of the reachable offsets.

    Notes:
        Our reading of [NR08]: an offset ``(dx, dy)`` is reachable when
        ``sqrt(dx^2 + dy^2) <= v_max + jitter * sqrt(2) + 1/2``: the largest speed, plus the
        largest jitter displacement (both axes at ``jitter``), plus half a pixel for the
        quantisation of the target position to the pixel grid. The centre is always reachable.

    Args:
        window: odd window size ``k``.
        v_max: largest target speed in pixels per frame, ``>= 0``.
        jitter: half-width of the uniform per-axis jitter in pixels, ``>= 0``.
        device: device of the result.
        dtype: dtype of the result (default: torch's default dtype).

    Returns:
        ``(k, k)`` matrix of zeros and ones.

    Examples:
        >>> frame_matrix(5, v_max=1.0, jitter=0.5).int()
        tensor([[0, 0, 1, 0, 0],
                [0, 1, 1, 1, 0],
                [1, 1, 1, 1, 1],
                [0, 1, 1, 1, 0],
                [0, 0, 1, 0, 0]], dtype=torch.int32)
    """
    k = _window("window", window)
    v_max = check_number("v_max", v_max, low=0.0)
    a = check_number("jitter", jitter, low=0.0)
    radius = v_max + a * math.sqrt(2.0) + 0.5
    dy, dx = _offsets(k)
    support = (dx * dx + dy * dy).to(torch.float64) <= radius * radius * (1 + 1e-12)
    return support.to(device=device, dtype=_dtype(dtype))


def _penalty_step_tensor(
    penalty_step: float | torch.Tensor, device: torch.device | str | None, dtype: torch.dtype
) -> torch.Tensor:
    check_number("penalty_step", penalty_step, low=1.0)
    return torch.as_tensor(penalty_step).to(device=device, dtype=dtype)


def penalty_matrices(
    window: int = 7,
    penalty_step: float | torch.Tensor = 3.0,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    r"""W_penalty of [NR08] for directions 1..8: the turn-angle penalty of each offset.

    For direction ``d`` (bearing ``(d - 1) * 45`` degrees, see the module docstring for the
    axes), the entry at offset ``(dx, dy)`` is ``penalty_step ** -s`` where ``s`` in ``0..4`` is
    the turn from the direction to the offset's bearing ``atan2(dy, dx)`` in 45-degree steps, i.e.
    the circular distance between the direction and the offset's compass sector (8 sectors of 45
    degrees centred on the directions). With ``penalty_step = 3`` a straight move weighs 1, a
    45-degree turn 1/3, 90 degrees 1/9, 135 degrees 1/27 and a reversal 1/81 (Figure 2 of
    [NR08] for direction 1).

    Notes:
        Our reading of [NR08]: the centre offset (the target stays in place) has no bearing, so
        it is no turn and is not penalised (weight 1), as a zero move is never a turn anywhere in
        hocnet (DESIGN section 2). Sub-pixel targets (0.2-0.6 px/frame in [NR08]) stay in their
        pixel in most frames; penalising the centre like a 90-degree turn (our first reading)
        made the directional matrices favour moving noise paths over such targets.
        Differentiable in ``penalty_step`` when it is a tensor.

    Args:
        window: odd window size ``k``.
        penalty_step: factor by which each further 45-degree step divides the weight, ``>= 1``
            (float or 0-dim tensor).
        device: device of the result.
        dtype: floating dtype of the result (default: torch's default dtype).

    Returns:
        ``(8, k, k)``: index ``d - 1`` holds direction ``d``.

    Examples:
        >>> w = penalty_matrices(3, 3.0)
        >>> (81 * w[0]).round().int()  # direction 1 (+x): straight ahead is the right column
        tensor([[ 3,  9, 27],
                [ 1, 81, 81],
                [ 3,  9, 27]], dtype=torch.int32)
    """
    k = _window("window", window)
    dtype = _dtype(dtype)
    step = _penalty_step_tensor(penalty_step, device, dtype)
    steps = _turn_steps(k, device).to(dtype)
    return torch.pow(step, -steps)


def penalty_matrix_in_place(
    window: int = 7,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    """W_penalty for direction 9 ("in place"): all ones.

    Notes:
        Our reading of [NR08]: a pixel whose target has not moved has no preferred direction, so
        no offset is penalised; its probability matrix is ``W_frame * W_basic`` alone.

    Args:
        window: odd window size ``k``.
        device: device of the result.
        dtype: dtype of the result (default: torch's default dtype).

    Returns:
        ``(k, k)`` ones.

    Examples:
        >>> penalty_matrix_in_place(3).sum().item()
        9.0
    """
    k = _window("window", window)
    return torch.ones(k, k, device=device, dtype=_dtype(dtype))


def _base_matrix(
    window: int,
    v_max: float,
    jitter: float,
    psf: float,
    device: torch.device | str | None,
    dtype: torch.dtype,
) -> torch.Tensor:
    """``W_frame * W_basic`` as ``(k, k)``."""
    basic = basic_matrix(window, v_max, jitter, psf, device=device, dtype=dtype)
    return frame_matrix(window, v_max, jitter, device=device, dtype=dtype) * basic


def _combine(
    base: torch.Tensor, steps: torch.Tensor, p: torch.Tensor, penalty_step: torch.Tensor
) -> torch.Tensor:
    """Eq. (5): ``normalise(base * W_penalty ** p)`` for directions 1..8, then ``normalise(base)``.

    Args:
        base: ``(k, k)`` ``W_frame * W_basic``.
        steps: ``(8, k, k)`` turn steps from :func:`_turn_steps` (in ``base``'s dtype).
        p: 0-dim exponent ``>= 0``.
        penalty_step: 0-dim step ``>= 1``.

    Returns:
        ``(9, k, k)``, each matrix summing to 1. Differentiable in ``p`` and ``penalty_step``.
    """
    penalty_p = torch.exp(-(p * torch.log(penalty_step)) * steps)  # == step ** (-p * s)
    directed = base.unsqueeze(0) * penalty_p
    stacked = torch.cat([directed, base.unsqueeze(0)], dim=0)
    return stacked / stacked.sum(dim=(-2, -1), keepdim=True)


def probability_matrices(
    window: int = 7,
    v_max: float = 1.0,
    jitter: float = 0.5,
    psf: float = 3.0,
    p: float | torch.Tensor = 0.5,
    penalty_step: float | torch.Tensor = 3.0,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    r"""The probability matrices W(direction) of eq. (5) of [NR08].

    ``W(d) = normalise(W_frame * W_basic * W_penalty(d) ** p)`` for directions ``d = 1..8`` and
    ``W(9) = normalise(W_frame * W_basic)`` for "in place" (:func:`penalty_matrix_in_place` is all
    ones), where ``normalise`` divides by the sum. Typical settings: ``window=7`` for targets of
    0-2.5 px/frame (``v_max=2.5``), ``window=5`` for 0-1 px/frame (``v_max=1``).

    Args:
        window: odd window size ``k``.
        v_max: largest target speed in pixels per frame, ``>= 0`` (:func:`basic_matrix`).
        jitter: half-width of the uniform per-axis jitter in pixels, ``>= 0``.
        psf: FWHM of the Gaussian PSF in pixels, ``>= 0`` (see :func:`basic_matrix`).
        p: exponent of the penalty, ``>= 0`` (``0``: no direction preference). Float or 0-dim
            tensor; the result is differentiable in it.
        penalty_step: turn penalty factor per 45 degrees, ``>= 1`` (:func:`penalty_matrices`).
            Float or 0-dim tensor; the result is differentiable in it.
        device: device of the result.
        dtype: floating dtype of the result (default: torch's default dtype).

    Returns:
        ``(9, k, k)``: index ``d - 1`` holds direction ``d``; each matrix sums to 1.

    Examples:
        >>> w = probability_matrices(5, v_max=1.0)
        >>> w.shape, torch.allclose(w.sum(dim=(1, 2)), torch.ones(9))
        (torch.Size([9, 5, 5]), True)
        >>> bool(w[0, 2, 3] > w[0, 2, 1])  # direction 1 prefers +x over -x
        True
    """
    k = _window("window", window)
    dtype = _dtype(dtype)
    check_number("p", p, low=0.0)
    p_t = torch.as_tensor(p).to(device=device, dtype=dtype)
    step = _penalty_step_tensor(penalty_step, device, dtype)
    base = _base_matrix(k, v_max, jitter, psf, device, dtype)
    return _combine(base, _turn_steps(k, device).to(dtype), p_t, step)


def var_table(*, device: torch.device | str | None = None) -> torch.Tensor:
    """The direction-similarity table ``Var`` of section 2.2.3 of [NR08].

    ``V[i - 1, j - 1]`` scores the similarity of directions ``i`` and ``j``: 6 for the same
    direction, minus 1 per 45 degrees between them, so 2 for opposite directions.

    Notes:
        Our reading of [NR08]: direction 9 ("in place") scores 4 against every moving direction,
        the score of a 90-degree difference, and 6 against itself.

    Args:
        device: device of the result.

    Returns:
        ``(9, 9)`` symmetric int64 table.

    Examples:
        >>> var_table()[0]
        tensor([6, 5, 4, 3, 2, 3, 4, 5, 4])
    """
    d = torch.arange(8, device=device)
    diff = (d[:, None] - d[None, :]).abs()
    table = torch.full((9, 9), 4, dtype=torch.int64, device=device)
    table[:8, :8] = 6 - torch.minimum(diff, 8 - diff)
    table[8, 8] = 6
    return table


def _memory_weights(weights: torch.Tensor | Sequence) -> torch.Tensor:
    """Validate ``weights`` for the EMC functions and return the matrix the gain is taken from."""
    if not isinstance(weights, torch.Tensor):
        try:
            weights = torch.as_tensor(weights, dtype=torch.float64)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`weights`: expected a tensor of shape (D, k, k) or (k, k), "
                f"got {type(weights).__name__}"
            ) from None
    if not weights.is_floating_point() or weights.dim() not in (2, 3) or weights.numel() == 0:
        raise ValueError(
            f"`weights`: expected a non-empty float tensor of shape (D, k, k) or (k, k), "
            f"got shape {tuple(weights.shape)} and dtype {weights.dtype}"
        )
    check_finite("weights", weights)
    return weights if weights.dim() == 2 else weights[0]


def _gain(weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return weights.sum(), weights.max()


def effective_memory(
    weights: torch.Tensor,
    g: float | torch.Tensor,
    target: float = 0.8,
) -> float | torch.Tensor:
    r"""The factor ``b`` that gives the recursion an effective memory ``target``, eq. (12)-(14).

    Feeding a constant ``ASF`` through one step of eq. (11) multiplies it by
    ``b * (g * sum(w) + (1 - g) * max(w))``; this per-step gain is the effective memory
    coefficient (EMC). ``b`` is chosen to make it equal ``target``:
    ``b = target / (g * sum(w) + (1 - g) * max(w))``.

    Notes:
        Our reading of [NR08]: the EMC is the per-step gain above (a geometric forgetting factor;
        ``target = 0.8`` weighs a frame ``m`` steps back by ``0.8 ** m``). For direction-dependent
        weights ``(9, k, k)`` the direction-1 matrix ``weights[0]`` is used (all eight directed
        matrices are rotations of it up to the pixel grid).

    Args:
        weights: ``(D, k, k)`` (``weights[0]`` is used) or ``(k, k)``.
        g: sum/max mixing factor in ``[0, 1]``, float or tensor of any shape.
        target: the wanted effective memory coefficient, ``> 0``.

    Returns:
        ``b`` as a float if ``g`` is a float, else a tensor shaped like ``g`` (differentiable in
        ``g`` and ``weights``).

    Examples:
        >>> w = probability_matrices(7, v_max=2.5)
        >>> b = effective_memory(w, 0.5)
        >>> round(b * (0.5 * float(w[0].sum()) + 0.5 * float(w[0].max())), 6)
        0.8
    """
    w = _memory_weights(weights)
    target = check_number("target", target, low=0.0, low_inclusive=False)
    total, peak = _gain(w)
    if isinstance(g, torch.Tensor):
        if not g.is_floating_point():
            g = g.to(w.dtype)
        check_finite("g", g)
        if g.numel() and not bool(((g >= 0) & (g <= 1)).all()):
            raise ValueError(
                f"`g`: expected values in [0, 1], got min {float(g.min()):g}, "
                f"max {float(g.max()):g}"
            )
        total, peak = total.to(device=g.device, dtype=g.dtype), peak.to(g.device, g.dtype)
        return target / (g * total + (1 - g) * peak)
    g = check_number("g", g, low=0.0, high=1.0)
    return target / (g * float(total) + (1 - g) * float(peak))


def equalize_gain(weights: torch.Tensor, g: float | torch.Tensor) -> torch.Tensor:
    r"""Rescale each direction's matrix so every direction has the per-step gain of direction 1.

    The per-step gain (effective memory coefficient per unit ``b``, see
    :func:`effective_memory`) of matrix ``W(d)`` is ``G_d = g * sum(W(d)) + (1 - g) * max(W(d))``.
    This returns ``W'(d) = W(d) * G_1 / G_d``, so that ``b * G_1`` is the memory of *every*
    direction, not only of direction 1.

    Notes:
        Beyond [NR08]. Eq. (5) normalises every ``W(d)`` to sum 1, which equalises the gains of
        the sum recursion (``g = 1``) but not of the max recursion: with the defaults the flat
        in-place matrix ``W(9)`` has half the maximum of the directed ones (5 x 5, ``v_max = 1``:
        0.123 against 0.249), so a target that stays in its pixel, as the paper's sub-pixel
        targets do in most frames, is accumulated with about half the memory that
        :func:`effective_memory` promises. ``hocnet reproduce dpa-pd-snr`` measures the effect.
        ``W(1)`` is unchanged, so :func:`effective_memory` and :func:`memory_line` (eq. 15) give
        the same ``b`` for the equalised matrices. Differentiable in ``weights`` and ``g``.

    Args:
        weights: ``(D, k, k)`` non-negative matrices with ``D`` in {1, 9} (``D = 1`` is returned
            as a copy) and a positive gain in every direction.
        g: sum/max mixing factor in ``[0, 1]``, float or 0-dim tensor.

    Returns:
        ``(D, k, k)`` rescaled matrices in the dtype of ``weights``.

    Raises:
        ValueError: on a wrong shape, negative or non-finite weights, a direction with zero
            gain, or ``g`` outside ``[0, 1]``.

    Examples:
        >>> w = equalize_gain(probability_matrices(5, v_max=1.0), 0.0)
        >>> peaks = w.amax(dim=(1, 2))
        >>> bool(torch.allclose(peaks, peaks[0].expand(9)))
        True
    """
    _memory_weights(weights)  # type, float dtype, finite
    w = weights if isinstance(weights, torch.Tensor) else torch.as_tensor(weights, torch.float64)
    if w.dim() != 3 or w.shape[0] not in (1, N_DIRECTIONS):
        raise ValueError(
            f"`weights`: expected shape (D, k, k) with D in (1, 9), got {tuple(w.shape)}"
        )
    if bool((w < 0).any()):
        raise ValueError(f"`weights`: expected non-negative values, got min {float(w.min()):g}")
    if isinstance(g, torch.Tensor):
        check_finite("g", g)
        if g.numel() != 1 or not 0.0 <= float(g.detach()) <= 1.0:
            raise ValueError(f"`g`: expected one value in [0, 1], got {g.detach().flatten()[:4]}")
        g = g.reshape(()).to(device=w.device, dtype=w.dtype)
    else:
        g = check_number("g", g, low=0.0, high=1.0)
    gain = g * w.sum(dim=(-2, -1)) + (1 - g) * w.amax(dim=(-2, -1))
    if bool((gain <= 0).any()):
        zero = torch.nonzero(gain <= 0).flatten().tolist()
        raise ValueError(f"`weights`: expected a positive gain in every direction, got 0 at {zero}")
    return w * (gain[0] / gain).view(-1, 1, 1)


def memory_line(weights: torch.Tensor, target: float = 0.8) -> tuple[float, float]:
    r"""Constants of eq. (15) of [NR08]: ``1 / b = slope * g + intercept``.

    From :func:`effective_memory`, ``1 / b = g * (sum(w) - max(w)) / target + max(w) / target``.
    With normalised matrices (``sum(w) = 1``) ``slope + intercept = 1 / target`` exactly.

    Notes:
        The paper's eq. (15), with ``target = 0.8``, reads ``1/b = 1.118 g + 0.131`` and
        ``1/b = 1.035 g + 0.214`` for its two matrices, i.e. ``max(w) = 0.105`` and ``0.171``.
        Our matrices (:func:`probability_matrices` defaults ``jitter=0.5, psf=3, p=0.5,
        penalty_step=3``, direction 1) give, measured:

        * 7 x 7, ``v_max = 2.5``: ``1/b = 1.1160 g + 0.1340`` (``max(w) = 0.1072``) — within
          about 2 % of the paper's ``(1.118, 0.131)``;
        * 5 x 5, ``v_max = 1``: ``1/b = 0.9388 g + 0.3112`` (``max(w) = 0.2489``) — more
          peaked than the paper's ``(1.035, 0.214)``: with ``|v| <= 1`` most of the mass stays
          within one pixel, and our ``W_frame`` keeps only the 13 offsets within 2.2 px.

    Args:
        weights: ``(D, k, k)`` (``weights[0]`` is used) or ``(k, k)``.
        target: the wanted effective memory coefficient, ``> 0``.

    Returns:
        ``(slope, intercept)`` as floats.

    Examples:
        >>> slope, intercept = memory_line(probability_matrices(7, v_max=2.5))
        >>> round(slope + intercept, 6)
        1.25
    """
    w = _memory_weights(weights)
    target = check_number("target", target, low=0.0, low_inclusive=False)
    total, peak = _gain(w.detach().to(torch.float64))
    return float(total - peak) / target, float(peak) / target


def b_versus_g(
    weights: torch.Tensor,
    gs: torch.Tensor | Sequence[float],
    target: float = 0.8,
) -> torch.Tensor:
    """The curve ``b(g)`` of :func:`effective_memory` over several values of ``g``.

    Args:
        weights: ``(D, k, k)`` (``weights[0]`` is used) or ``(k, k)``.
        gs: values of ``g`` in ``[0, 1]``, a sequence or a tensor of any shape.
        target: the wanted effective memory coefficient, ``> 0``.

    Returns:
        ``b`` for each ``g``, a tensor shaped like ``gs`` (float64 unless ``gs`` is a float
        tensor).

    Examples:
        >>> b_versus_g(torch.full((1, 3, 3), 1 / 9), [0.0, 1.0])
        tensor([7.2000, 0.8000], dtype=torch.float64)
    """
    if not isinstance(gs, torch.Tensor):
        try:
            gs = torch.as_tensor(gs, dtype=torch.float64)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`gs`: expected a sequence or tensor of numbers, got {type(gs).__name__}"
            ) from None
    if not gs.is_floating_point():
        gs = gs.to(torch.float64)
    w = _memory_weights(weights)
    result = effective_memory(w.to(gs.dtype), gs.reshape(-1), target)
    return result.reshape(gs.shape)

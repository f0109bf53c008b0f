"""Probability matrices, direction table and effective memory of the DPA [NR08], section 2.2.

Pure kernel builders in the style of kornia's ``get_*_kernel``: every function returns a fresh
tensor on the requested ``device`` / ``dtype`` and holds no state. The matrices feed
:func:`hocnet.dpa.functional.accumulate`.

Index convention (the paper's, eq. (6)): a ``(k, k)`` matrix ``w`` with ``h = k // 2`` holds at
``w[h + j, h + i]`` the weight of ``ASF_{n-1}(x + i, y + j)``, the pixel of the previous frame at
the offset ``(i, j)`` (columns ``x``, rows ``y``) from the pixel ``p = (x, y)`` being scored: rows
are ``y``, columns ``x``, as Figures 2 and 3 of [NR08] are printed, so a matrix can be compared
with them entry by entry. The row index grows downwards, so **+y points down** on a displayed
image. A target that moved by ``(dx, dy)`` from ``q`` to ``p`` came from the offset
``(i, j) = (-dx, -dy)``.

Directions (section 2.2.2 of [NR08]: directions 1-8 at 0-315 degrees in steps of 45, direction 1
the arrow -> of Figure 2, direction 9 in place; our reading: a move ``(dx, dy) = p - q`` has the
bearing ``atan2(dy, dx)``), so the directions 1..8 turn counter-clockwise in the ``(x, y)`` frame,
which is *clockwise* on screen: direction 1 is +x (right, Figure 2's arrow), direction 3
(90 degrees) is +y (down), direction 5 is -x (left), direction 7 is -y (up). Direction 9 is "in
place". In tensors, direction ``d`` is stored at index ``d - 1`` (index 8 is direction 9).
The paper does not say which way the directions turn (its Figure 4 is not legible in our copy);
the counter-clockwise-on-screen reading is equally possible. The algorithm is mirror-invariant
(the Var table and the penalties depend only on angle differences), so only the labels differ.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from hocnet._check import check_finite, check_int, check_number

__all__ = [
    "PAPER_PSF",
    "PAPER_SIGMA",
    "b_limit",
    "b_versus_g",
    "basic_matrix",
    "effective_memories",
    "effective_memory",
    "equalize_gain",
    "figure3_matrices",
    "fit_basic_sigma",
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
#: Sub-samples per pixel of the velocity-disc quadrature of :func:`basic_matrix` (``v_max > 0``).
_SUBGRID = 32
#: FWHM -> standard deviation of a Gaussian.
_FWHM_TO_SIGMA = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))
#: Standard deviation (pixels) of the Gaussian target spread of W_basic, fitted by
#: :func:`fit_basic_sigma` so that the 7 x 7 ``W(9) = W_basic`` (jitter U[-0.5, 0.5]) gives the
#: intercept 0.214 of eq. (15) for direction 9, i.e. ``max(W_basic) = 0.8 * 0.214 = 0.1712``.
PAPER_SIGMA = 0.8708160208984617
#: The same spread as a full width at half maximum (pixels), the ``psf`` argument of the builders.
PAPER_PSF = PAPER_SIGMA / _FWHM_TO_SIGMA
#: The largest penalty value, on the side the target came from (Figure 2 of [NR08]).
PENALTY_TOP = 12.0


def _window(name: str, window: int) -> int:
    """Validate an odd window size ``k >= 1``."""
    k = check_int(name, window, minimum=1)
    if k % 2 == 0:
        raise ValueError(f"`{name}`: expected an odd integer, got {k}")
    return k


def _dtype(dtype: torch.dtype | None) -> torch.dtype:
    return torch.get_default_dtype() if dtype is None else dtype


def _offsets(k: int, device: torch.device | str | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Integer offset grids ``(j, i)`` (rows ``y``, columns ``x``) of a ``(k, k)`` window."""
    h = k // 2
    r = torch.arange(-h, h + 1, device=device)
    dy, dx = torch.meshgrid(r, r, indexing="ij")
    return dy, dx


def _sector(dy: torch.Tensor, dx: torch.Tensor) -> torch.Tensor:
    """Direction index (0..7 for directions 1..8, 8 for a zero move) of integer moves ``(dx, dy)``.

    The groups of Figure 4 of [NR08]: 45-degree sectors centred on 0, 45, ..., 315 degrees of the
    bearing ``atan2(dy, dx)``. No integer move lies on a sector boundary (``tan(22.5 deg)`` is
    irrational), so rounding is unambiguous.
    """
    angle = torch.atan2(dy.to(torch.float64), dx.to(torch.float64))
    sector = torch.round(angle / (math.pi / 4)).to(torch.int64) % 8
    return torch.where((dy == 0) & (dx == 0), torch.full_like(sector, IN_PLACE), sector)


def _ring_angle(j: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
    """Position of the offset ``(i, j)`` on its square ring, in units of 45 degrees (``[0, 8)``).

    The ring of Chebyshev radius ``r`` is walked linearly along each side: the side midpoints
    and corners sit at 0, 1, ..., 7 (bearings 0, 45, ..., 315 degrees of ``atan2(j, i)``) and the
    cells between them are spaced evenly (``1 / r`` apart). The centre gets 0 (unused).
    """
    i = i.to(torch.float64)
    j = j.to(torch.float64)
    r = torch.maximum(i.abs(), j.abs()).clamp_min(1.0)
    right = i == r
    bottom = (j == r) & ~right
    left = (i == -r) & ~bottom
    a = torch.where(
        right,
        j / r,
        torch.where(bottom, 2 - i / r, torch.where(left, 4 - j / r, 6 + i / r)),
    )
    return a % 8


def _penalty_turns(k: int, device: torch.device | str | None = None) -> torch.Tensor:
    """Turn of each offset of the window from the side each direction 1..8 came from.

    Returns:
        ``(8, k, k)`` float64 in ``[0, 4]`` (units of 45 degrees), paper index convention; the
        centre gets 0 (Figure 2 prints 12 there).
    """
    j, i = _offsets(k, device)
    a = _ring_angle(j, i)
    came_from = (torch.arange(8, device=device, dtype=torch.float64) + 4).view(8, 1, 1) % 8
    diff = (a.unsqueeze(0) - came_from).abs() % 8
    turns = torch.minimum(diff, 8 - diff)
    h = k // 2
    turns[:, h, h] = 0.0
    return turns


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
    v_max: float = 0.0,
    jitter: float = 0.5,
    psf: float = PAPER_PSF,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    r"""W_basic of [NR08] (section 2.2.2): a target standing in place, spread and jittered.

    The apparent displacement of the target between two frames is ``n + u`` per axis, with ``n``
    the Gaussian target spread (standard deviation ``sigma = psf / (2 sqrt(2 ln 2))``, eq. (1))
    and ``u`` the sensor jitter, uniform in ``[-jitter, jitter]`` (the paper: U[-0.5, 0.5]). The
    entry at offset ``(i, j)`` is the probability that it lands in the pixel cell
    ``[i - 1/2, i + 1/2] x [j - 1/2, j + 1/2]``, normalised so that the window sums to 1.

    Notes:
        Our reading of [NR08]: the paper gives "a Gaussian target spread of 3 x 3" and no width.
        The default width ``PAPER_SIGMA = 0.871`` px (FWHM ``PAPER_PSF = 2.05`` px, most of the
        mass in 3 x 3 pixels) is fitted (:func:`fit_basic_sigma`) so that the 7 x 7 matrix gives
        the direction-9 intercept 0.214 of eq. (15), i.e. ``max(W_basic) = 0.1712``; the
        directions 1-8 line of eq. (15) then follows without further fitting (see
        :func:`memory_line`). The Gaussian and the jitter are integrated in closed form per axis.
        ``v_max > 0`` (our addition, not in [NR08]; 0 is the paper's standing target) also
        spreads the displacement over a velocity disc ``|v| <= v_max``, integrated on a sub-grid
        of 1/32 pixel; the offsets are then those of the source, ``-(v + n + u)``.

    Args:
        window: odd window size ``k``.
        v_max: speed of our optional velocity disc in pixels per frame, ``>= 0`` (0: paper).
        jitter: half-width ``a`` of the uniform per-axis jitter in pixels, ``>= 0``.
        psf: FWHM of the Gaussian target spread in pixels, ``>= 0`` (0: no spread).
        device: device of the result.
        dtype: floating dtype of the result (default: torch's default dtype).

    Returns:
        ``(k, k)`` matrix, non-negative, summing to 1, indexed ``[h + j, h + i]`` (paper
        convention, see the module docstring).

    Examples:
        >>> w = basic_matrix(7)
        >>> w.shape, round(float(w.sum()), 6), round(float(w.max()), 4)
        (torch.Size([7, 7]), 1.0, 0.1712)
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
    prob = cell @ disc @ cell.T  # [dy, dx] of the displacement p - q
    prob = prob.flip(-2, -1).clamp_min(0.0)  # source offsets (i, j) = -(dx, dy)
    prob = prob / prob.sum()
    return prob.to(device=device, dtype=_dtype(dtype))


def fit_basic_sigma(
    intercept: float = 0.214,
    target: float = 0.8,
    window: int = 7,
    jitter: float = 0.5,
) -> float:
    r"""The Gaussian spread ``sigma`` (pixels) whose W_basic gives eq. (15)'s direction-9 intercept.

    Solves ``max(basic_matrix(window, 0, jitter, psf(sigma))) = target * intercept`` by
    bisection (``max`` falls monotonically with ``sigma``). With the defaults (eq. (15):
    ``1/b = 1.035 g + 0.214`` for direction 9, EMC 0.8, 7 x 7, U[-0.5, 0.5]) this gives
    :data:`PAPER_SIGMA` = 0.871 px.

    Args:
        intercept: intercept of the direction-9 line ``1/b = slope g + intercept``, ``> 0``.
        target: effective memory coefficient of eq. (12), ``> 0``.
        window: odd window size ``k``.
        jitter: half-width of the uniform per-axis jitter in pixels, ``>= 0``.

    Returns:
        ``sigma`` in pixels (float).

    Raises:
        ValueError: if no ``sigma`` in ``[0, 10]`` reaches the wanted peak.

    Examples:
        >>> round(fit_basic_sigma(), 4)
        0.8708
    """
    intercept = check_number("intercept", intercept, low=0.0, low_inclusive=False)
    target = check_number("target", target, low=0.0, low_inclusive=False)
    k = _window("window", window)
    peak = intercept * target

    def top(sigma: float) -> float:
        return float(
            basic_matrix(k, 0.0, jitter, sigma / _FWHM_TO_SIGMA, dtype=torch.float64).max()
        )

    lo, hi = 1e-9, 10.0
    if not top(hi) <= peak <= top(lo):
        raise ValueError(
            f"`intercept`: expected a peak {peak:g} between {top(hi):.4g} and {top(lo):.4g} "
            f"(sigma in [0, 10]), got intercept {intercept:g}"
        )
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if top(mid) > peak else (lo, mid)
    return 0.5 * (lo + hi)


def _frame_radius(v_max: float, jitter: float) -> int:
    """Half-width of the square valid search area: ``ceil(v_max + jitter)`` pixels."""
    return max(0, math.ceil(v_max + jitter - 1e-9))


def frame_matrix(
    window: int = 7,
    v_max: float = 2.0,
    jitter: float = 0.5,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    r"""W_frame of [NR08]: 1 inside the square valid search area, 0 outside.

    The target moves up to ``v_max`` pixels per frame plus the jitter on each axis, so its source
    lies within ``r = ceil(v_max + jitter)`` pixels on each axis: ``W_frame`` is 1 on the centred
    ``(2r + 1) x (2r + 1)`` square (clipped to the window) and 0 outside. Section 2.2.1:
    0-2 px/frame plus 0.5 jitter -> 7 x 7; section 2.2.2 / Figure 3: 0-1 px/frame -> 5 x 5
    "including the assumed jitter". The paper's "0-2.5 px/frame" already includes the jitter,
    so it is ``v_max = 2, jitter = 0.5`` here, not ``v_max = 2.5``.

    Args:
        window: odd window size ``k``.
        v_max: largest target speed in pixels per frame (without the jitter), ``>= 0``.
        jitter: half-width of the uniform per-axis jitter in pixels, ``>= 0``.
        device: device of the result.
        dtype: dtype of the result (default: torch's default dtype).

    Returns:
        ``(k, k)`` matrix of zeros and ones.

    Examples:
        >>> frame_matrix(7, v_max=1.0, jitter=0.5).int()
        tensor([[0, 0, 0, 0, 0, 0, 0],
                [0, 1, 1, 1, 1, 1, 0],
                [0, 1, 1, 1, 1, 1, 0],
                [0, 1, 1, 1, 1, 1, 0],
                [0, 1, 1, 1, 1, 1, 0],
                [0, 1, 1, 1, 1, 1, 0],
                [0, 0, 0, 0, 0, 0, 0]], dtype=torch.int32)
    """
    k = _window("window", window)
    v_max = check_number("v_max", v_max, low=0.0)
    a = check_number("jitter", jitter, low=0.0)
    r = _frame_radius(v_max, a)
    dy, dx = _offsets(k)
    support = torch.maximum(dy.abs(), dx.abs()) <= r
    return support.to(device=device, dtype=_dtype(dtype))


def _penalty_step_tensor(
    penalty_step: float | torch.Tensor, device: torch.device | str | None, dtype: torch.dtype
) -> torch.Tensor:
    check_number("penalty_step", penalty_step, low=0.0, high=PENALTY_TOP / 4)
    return torch.as_tensor(penalty_step).to(device=device, dtype=dtype)


def _penalty(turns: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
    """``12 - step * turn``: the penalty values of Figure 2 (differentiable in ``step``)."""
    return PENALTY_TOP - step * turns


def penalty_matrices(
    window: int = 7,
    penalty_step: float | torch.Tensor = 3.0,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    r"""W_penalty(direction) of [NR08] for directions 1..8 (Figure 2, section 2.2.2).

    The side the target came from gets 12; every 45 degrees of turn away from it costs
    ``x = penalty_step`` ("a turn of 45 degrees leads to penalty of -x, 90 degrees to -2x"), so
    with ``x = 3`` the opposite side gets 0. The turn of an offset is measured along its square
    ring of the window, linearly along each ring side (corners and side midpoints at multiples
    of 45 degrees), and the centre gets 12 (as printed in Figure 2). ``x`` lies in ``[0, 3]``
    (our reading: 3, the paper's value, is the largest step that keeps the opposite side at
    ``12 - 4x >= 0``, a valid probability; 0 removes the direction preference).

    Notes:
        Figure 2 prints direction 1 (arrow ``->``, 0 degrees, 7 x 7, ``x = 3``) as the rows
        ``9 8 7 6 5 4 3 / 10 9 7.5 6 4.5 3 2 / 11 10 9 6 3 1.5 1 / 12 12 12 12 0 0 0`` and
        mirrored. The rule above reproduces every entry but two: at the offsets
        ``(i, j) = (-2, -1)`` and ``(-2, +1)`` (rows 3 and 5, column 2) it gives **10.5** where
        Figure 2 prints 10. We follow the rule (our reading: 10 is a misprint; the rule's
        entries of every other mirror pair ``(i, j), (-i, j)`` sum to 12 in the figure, and the
        printed 10 + 1.5 would be the only exception). Only ``x / 12`` matters after the
        normalisation of eq. (5). Differentiable in ``penalty_step`` when it is a tensor.

    Args:
        window: odd window size ``k``.
        penalty_step: the penalty ``x`` per 45 degrees of turn, in ``[0, 3]`` (float or 0-dim
            tensor); the paper takes ``x = 3``.
        device: device of the result.
        dtype: floating dtype of the result (default: torch's default dtype).

    Returns:
        ``(8, k, k)``: index ``d - 1`` holds direction ``d``, paper index convention
        ``[h + j, h + i]`` (not normalised).

    Examples:
        >>> penalty_matrices(7)[0, :4]  # Figure 2, rows 1-4 (rule: 10.5 where it prints 10)
        tensor([[ 9.0000,  8.0000,  7.0000,  6.0000,  5.0000,  4.0000,  3.0000],
                [10.0000,  9.0000,  7.5000,  6.0000,  4.5000,  3.0000,  2.0000],
                [11.0000, 10.5000,  9.0000,  6.0000,  3.0000,  1.5000,  1.0000],
                [12.0000, 12.0000, 12.0000, 12.0000,  0.0000,  0.0000,  0.0000]])
    """
    k = _window("window", window)
    dtype = _dtype(dtype)
    step = _penalty_step_tensor(penalty_step, device, dtype)
    return _penalty(_penalty_turns(k, device).to(dtype), step)


def penalty_matrix_in_place(
    window: int = 7,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    """All ones: a direction-free penalty (kept for compatibility; not used by eq. (5)).

    Notes:
        Eq. (5) of [NR08] has no penalty for direction 9: ``W(9) = W_basic`` (Figure 3, "the
        basic probability matrix (direction 9)"). This matrix is the neutral penalty of our
        first reading.

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


def _combine(
    basic: torch.Tensor,
    frame: torch.Tensor,
    turns: torch.Tensor,
    p: torch.Tensor,
    penalty_step: torch.Tensor,
) -> torch.Tensor:
    """Eq. (5): ``W(d) = p W_basic + (1 - p) P(d) W_frame / sum(P(d) W_frame)``, ``W(9) = W_basic``.

    Args:
        basic: ``(k, k)`` W_basic summing to 1.
        frame: ``(k, k)`` W_frame (0/1).
        turns: ``(8, k, k)`` turns from :func:`_penalty_turns` (in ``basic``'s dtype).
        p: 0-dim mixing weight in ``[0, 1]``.
        penalty_step: 0-dim step ``x`` in ``[0, 3]``.

    Returns:
        ``(9, k, k)``, each matrix summing to 1. Differentiable in ``p`` and ``penalty_step``.
    """
    framed = _penalty(turns, penalty_step) * frame
    framed = framed / framed.sum(dim=(-2, -1), keepdim=True)
    directed = p * basic + (1 - p) * framed
    return torch.cat([directed, basic.unsqueeze(0)], dim=0)


def probability_matrices(
    window: int = 7,
    v_max: float = 2.0,
    jitter: float = 0.5,
    psf: float = PAPER_PSF,
    p: float | torch.Tensor = 0.5,
    penalty_step: float | torch.Tensor = 3.0,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    r"""The probability matrices W(direction) of eq. (5) of [NR08].

    ``W(d) = p * W_basic + (1 - p) * W_penalty(d) W_frame / sum(W_penalty(d) W_frame)`` for the
    directions ``d = 1..8`` and ``W(9) = W_basic`` (the target standing in place), with
    :func:`basic_matrix`, :func:`penalty_matrices` and :func:`frame_matrix`. Every matrix sums to
    1, so the sum recursion (``g = 1``) has the same gain in every direction (``b = 0.8`` for an
    EMC of 0.8, eq. (13)). The defaults are the paper's: 7 x 7, 0-2 px/frame plus U[-0.5, 0.5]
    jitter (the full 7 x 7 ``W_frame``, section 2.2.1), ``p = 0.5``, ``x = 3`` (section 2.2.2);
    ``v_max = 1`` gives Figure 3's 5 x 5 valid search area (pass ``window=5`` to drop the zero
    border). The defaults give eq. (15)'s constants (see :func:`memory_line`).

    W_frame multiplies the penalty only, as eq. (5) is printed, so with ``v_max`` smaller than
    the window allows (e.g. ``window=7, v_max=1``, Figure 3) W_basic's tail stays on the border
    outside the valid search area, where the paper's Figure 3 says its border is zeroed; the
    difference and what it changes (b at g = 1 by <= 1.3 %, tracking by <= 0.01) are measured in
    :func:`figure3_matrices`. ``window=5, v_max=1`` has no such border.

    Args:
        window: odd window size ``k``.
        v_max: largest target speed in pixels per frame, without the jitter, ``>= 0``
            (:func:`frame_matrix`).
        jitter: half-width of the uniform per-axis jitter in pixels, ``>= 0``.
        psf: FWHM of the Gaussian target spread in pixels, ``>= 0`` (:func:`basic_matrix`).
        p: mixing weight of W_basic in ``[0, 1]`` (float or 0-dim tensor; differentiable).
        penalty_step: the penalty ``x`` per 45 degrees of turn, in ``[0, 3]`` (float or 0-dim
            tensor; differentiable).
        device: device of the result.
        dtype: floating dtype of the result (default: torch's default dtype).

    Returns:
        ``(9, k, k)``: index ``d - 1`` holds direction ``d``; each matrix sums to 1; paper index
        convention ``[h + j, h + i]`` for the source ``ASF_{n-1}(x + i, y + j)`` (eq. 6).

    Examples:
        >>> w = probability_matrices()
        >>> w.shape, torch.allclose(w.sum(dim=(1, 2)), torch.ones(9))
        (torch.Size([9, 7, 7]), True)
        >>> bool(w[0, 3, 1] > w[0, 3, 5])  # direction 1 (moving +x) came from -x
        True
    """
    k = _window("window", window)
    dtype = _dtype(dtype)
    check_number("p", p, low=0.0, high=1.0)
    p_t = torch.as_tensor(p).to(device=device, dtype=dtype)
    step = _penalty_step_tensor(penalty_step, device, dtype)
    basic = basic_matrix(k, 0.0, jitter, psf, device=device, dtype=dtype)
    frame = frame_matrix(k, v_max, jitter, device=device, dtype=dtype)
    return _combine(basic, frame, _penalty_turns(k, device).to(dtype), p_t, step)


def figure3_matrices(
    v_max: float = 1.0, p: float = 0.5, penalty_step: float = 3.0
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The three panels of Figure 3 of [NR08]: W_basic, the framed penalties and W(direction).

    Figure 3 shows 7 x 7 matrices for 0-1 px/frame (a 5 x 5 ``W_frame``) and ``p = 0.5``.

    Notes:
        Our reading differs from Figure 3 on the border. The paper says of Figure 3 that "the
        border pixels are zeroes accordingly using W_frame", but eq. (5) as printed multiplies
        only the penalty by W_frame, and that is what we build: ``basic`` (= W(9)) and the
        ``p * W_basic`` part of W(1..8) keep W_basic's tail on the 7 x 7 border ring, outside the
        5 x 5 valid search area (1.23 % of W(9)'s mass, 0.62 % of W(1..8)'s; the largest border
        entry is 0.75 % / 0.52 % of its matrix's maximum). Measured by ``docs/dpa_figure3.py
        --border`` (EMC 0.8): zeroing the border changes no b at g = 0 (the maxima are inside:
        6.448 for directions 1-8, 4.673 for direction 9), raises b at g = 1 from 0.800 to 0.805
        (directions 1-8) / 0.810 (direction 9) because the sums fall below 1, and lowers eq.
        (15)'s slopes from 1.095 / 1.036 to 1.087 / 1.021 (intercepts 0.155 / 0.214 unchanged).
        Zeroing and renormalising each matrix to sum 1 gives 1/b = 1.094 g + 0.156 / 1.033 g +
        0.217 (b at g = 0: 6.409 / 4.615); direction 9 is then exactly
        ``probability_matrices(5, v_max=1)``'s, directions 1-8 within 3.2e-4 (that function
        renormalises W_basic on the 5 x 5 window before mixing). In tracking it makes no
        difference that matters: on the 17 dB clear-sky speed scenes of ``dpa-pd-snr`` (20
        scenes, paper direction step) the fraction of frames on the truth at 0 / 0.5 / 1 / 1.5
        px/frame is 1.00 / 0.94 / 0.62 / 0.12 (g = 0) and 1.00 / 0.98 / 0.89 / 0.30 (g = 1) with
        our matrices and within 0.01 of that zeroed, zeroed and renormalised, or 5 x 5. For the
        paper's zeroed border use ``probability_matrices(5, v_max=1)`` (the section-3 matrices
        the experiments and ``RECOMMENDED`` use).

    Args:
        v_max: largest target speed in pixels per frame (Figure 3: 1).
        p: mixing weight (Figure 3: 0.5).
        penalty_step: the penalty ``x`` (Figure 2: 3).

    Returns:
        ``(basic, penalties, weights)``: ``(7, 7)`` W_basic, ``(8, 7, 7)`` W_penalty(d) W_frame
        (not normalised) and ``(9, 7, 7)`` W(d), float64, paper index convention.

    Examples:
        >>> basic, penalties, weights = figure3_matrices()
        >>> float(penalties[:, 0].abs().sum()), tuple(weights.shape)
        (0.0, (9, 7, 7))
    """
    basic = basic_matrix(7, dtype=torch.float64)
    frame = frame_matrix(7, v_max, 0.5, dtype=torch.float64)
    penalties = penalty_matrices(7, penalty_step, dtype=torch.float64) * frame
    weights = probability_matrices(
        7, v_max, 0.5, p=p, penalty_step=penalty_step, dtype=torch.float64
    )
    return basic, penalties, weights


def var_table(*, device: torch.device | str | None = None) -> torch.Tensor:
    """The direction-similarity table ``Var`` of section 2.2.3 of [NR08].

    ``V[i - 1, j - 1]`` scores the similarity of directions ``i`` and ``j``: 6 for the same
    direction, minus 1 per 45 degrees between them, so 2 for opposite directions.

    Notes:
        Our reading of [NR08]: direction 9 ("in place") scores 4 against every moving direction,
        the score of a 90-degree difference, and 6 against itself. The paper does not define Var
        for direction 9; this is an open choice: pass your own table as ``var_table=`` to
        :func:`~hocnet.dpa.accumulate`.

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
    """Validate ``weights`` for the EMC functions and return them as ``(D, k, k)``."""
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
    return weights if weights.dim() == 3 else weights.unsqueeze(0)


def _pick(weights: torch.Tensor, direction: int) -> torch.Tensor:
    """The ``(k, k)`` matrix of ``direction`` (1..9; the only one when ``D = 1``)."""
    check_int("direction", direction, minimum=1, maximum=N_DIRECTIONS)
    if weights.shape[0] == 1:
        return weights[0]
    if direction > weights.shape[0]:
        raise ValueError(
            f"`direction`: expected 1..{weights.shape[0]} for {weights.shape[0]} matrices, "
            f"got {direction}"
        )
    return weights[direction - 1]


def _check_g(g: float | torch.Tensor, like: torch.Tensor) -> float | torch.Tensor:
    if isinstance(g, torch.Tensor):
        if not g.is_floating_point():
            g = g.to(like.dtype)
        check_finite("g", g)
        if g.numel() and not bool(((g >= 0) & (g <= 1)).all()):
            raise ValueError(
                f"`g`: expected values in [0, 1], got min {float(g.min()):g}, "
                f"max {float(g.max()):g}"
            )
        return g
    return check_number("g", g, low=0.0, high=1.0)


def effective_memory(
    weights: torch.Tensor,
    g: float | torch.Tensor,
    target: float = 0.8,
    *,
    direction: int = 9,
) -> float | torch.Tensor:
    r"""The memory factor ``b`` of eq. (12)-(14) of [NR08] for one direction.

    Feeding a constant ``ASF`` through one step of eq. (11) with the matrix ``w = W(direction)``
    multiplies it by ``b * (g * sum(w) + (1 - g) * max(w))``, the effective memory coefficient
    (EMC). Eq. (12): ``b = target / (g * sum(w) + (1 - g) * max(w))``; eq. (14) writes it as
    ``[g / b_{g=1} + (1 - g) / b_{g=0}]^{-1}``. The result is direction dependent (eq. (13)).

    Notes:
        The paper tunes ``b`` for direction 9 (section 2.2.6: its targets stay in place most of
        the time, "``b_{g=0}`` close to 4.65"), so ``direction=9`` is the default; with the
        default matrices it gives ``b = 4.67`` at ``g = 0`` and ``0.8`` at ``g = 1``.
        :func:`effective_memories` gives every direction at once. (Before issue 8 this function
        used direction 1.)

    Args:
        weights: ``(D, k, k)`` or ``(k, k)`` (then ``D = 1``).
        g: sum/max mixing factor in ``[0, 1]``, float or tensor of any shape.
        target: the wanted effective memory coefficient, ``> 0``.
        direction: the direction 1..9 whose matrix sets ``b`` (ignored when ``D = 1``).

    Returns:
        ``b`` as a float if ``g`` is a float, else a tensor shaped like ``g`` (differentiable in
        ``g`` and ``weights``).

    Examples:
        >>> w = probability_matrices()
        >>> round(effective_memory(w, 0.0), 2), round(effective_memory(w, 1.0), 2)
        (4.67, 0.8)
        >>> round(effective_memory(w, 0.0, direction=1), 2)
        7.58
    """
    w = _pick(_memory_weights(weights), direction)
    target = check_number("target", target, low=0.0, low_inclusive=False)
    g = _check_g(g, w)
    total, peak = w.sum(), w.max()
    if isinstance(g, torch.Tensor):
        total, peak = total.to(device=g.device, dtype=g.dtype), peak.to(g.device, g.dtype)
        return target / (g * total + (1 - g) * peak)
    return target / (g * float(total) + (1 - g) * float(peak))


def effective_memories(
    weights: torch.Tensor, g: float | torch.Tensor, target: float = 0.8
) -> torch.Tensor:
    r"""``b`` of eq. (12)-(14) for every direction: ``target / (g sum W(d) + (1 - g) max W(d))``.

    Args:
        weights: ``(D, k, k)`` or ``(k, k)``.
        g: sum/max mixing factor in ``[0, 1]``, float or tensor of any shape.
        target: the wanted effective memory coefficient, ``> 0``.

    Returns:
        ``(D, *g.shape)`` tensor (``(D,)`` for a float ``g``), in the dtype of ``weights``
        (of ``g`` if it is a float tensor); entry ``d - 1`` is direction ``d``.

    Examples:
        >>> effective_memories(probability_matrices(), 0.0).round(decimals=2)
        tensor([7.5800, 7.5800, 7.5800, 7.5800, 7.5800, 7.5800, 7.5800, 7.5800, 4.6700])
    """
    w = _memory_weights(weights)
    target = check_number("target", target, low=0.0, low_inclusive=False)
    g = _check_g(g, w)
    total, peak = w.sum(dim=(-2, -1)), w.amax(dim=(-2, -1))
    if isinstance(g, torch.Tensor):
        total, peak = total.to(g.device, g.dtype), peak.to(g.device, g.dtype)
        shape = (-1,) + (1,) * g.dim()
        return target / (g * total.view(shape) + (1 - g) * peak.view(shape))
    return target / (g * total + (1 - g) * peak)


def b_limit(weights: torch.Tensor, g: float | torch.Tensor) -> float:
    r"""Largest ``b`` of the memory range of eq. (12)-(14): EMC ``<= 1`` in at least one direction.

    ``b_max = 1 / min_d (g * sum(W(d)) + (1 - g) * max(W(d)))``: above it every direction's
    effective memory coefficient exceeds 1 and the recursion grows geometrically ("explodes",
    section 2.2.6) even on a constant input. With the default matrices ``b_max = 9.47`` at
    ``g = 0`` (directions 1-8; the paper sweeps ``b`` up to 8) and exactly 1 at ``g = 1``.

    Notes:
        Our reading of [NR08]: "an appropriate range for b can be found so that 0 <= EMC <= 1";
        the paper's own sweeps (``b`` up to 8 at ``g = 0``, Figure 6 "about 0 <= b <= 8") exceed
        the direction-9 bound (5.84), so the range is bounded by the direction with the smallest
        gain. :func:`~hocnet.dpa.functional.accumulate` checks ``b`` against it.

    Args:
        weights: ``(D, k, k)`` or ``(k, k)`` non-negative matrices.
        g: sum/max mixing factor in ``[0, 1]`` (float or one-element tensor).

    Returns:
        ``b_max`` as a float (``inf`` if some direction has zero gain).

    Examples:
        >>> w = probability_matrices()
        >>> round(b_limit(w, 0.0), 2), round(b_limit(w, 1.0), 2)
        (9.47, 1.0)
    """
    w = _memory_weights(weights).detach().to(torch.float64)
    if isinstance(g, torch.Tensor):
        g = float(g.detach().reshape(-1)[0]) if g.numel() == 1 else g
    g = check_number("g", g, low=0.0, high=1.0)
    gain = g * w.sum(dim=(-2, -1)) + (1 - g) * w.amax(dim=(-2, -1))
    low = float(gain.min())
    return math.inf if low <= 0 else 1.0 / low


def equalize_gain(
    weights: torch.Tensor, g: float | torch.Tensor, *, reference: int = 1
) -> torch.Tensor:
    r"""Rescale each direction's matrix so every direction has the per-step gain of ``reference``.

    The per-step gain (effective memory coefficient per unit ``b``, see
    :func:`effective_memory`) of matrix ``W(d)`` is ``G_d = g * sum(W(d)) + (1 - g) * max(W(d))``.
    This returns ``W'(d) = W(d) * G_ref / G_d``, so that ``b * G_ref`` is the memory of *every*
    direction.

    Notes:
        Beyond [NR08] (our addition, kept as an option). Eq. (5) normalises every ``W(d)`` to
        sum 1, which equalises the gains of the sum recursion (``g = 1``) but not of the max
        recursion: with the paper's matrices the in-place ``W(9) = W_basic`` has a larger
        maximum than the directed ones (7 x 7: 0.171 against 0.106), so at ``g = 0`` a target
        that stays in place is accumulated with more memory than a moving one. ``W(reference)``
        is unchanged. Differentiable in ``weights`` and ``g``.

    Args:
        weights: ``(D, k, k)`` non-negative matrices with ``D`` in {1, 9} (``D = 1`` is returned
            as a copy) and a positive gain in every direction.
        g: sum/max mixing factor in ``[0, 1]``, float or 0-dim tensor.
        reference: the direction 1..9 whose gain every matrix gets (default 1).

    Returns:
        ``(D, k, k)`` rescaled matrices in the dtype of ``weights``.

    Raises:
        ValueError: on a wrong shape, negative or non-finite weights, a direction with zero
            gain, or ``g`` outside ``[0, 1]``.

    Examples:
        >>> w = equalize_gain(probability_matrices(), 0.0)
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
    ref = check_int("reference", reference, minimum=1, maximum=N_DIRECTIONS)
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
    ref_gain = gain[min(ref, w.shape[0]) - 1]
    return w * (ref_gain / gain).view(-1, 1, 1)


def memory_line(
    weights: torch.Tensor, target: float = 0.8, *, direction: int = 9
) -> tuple[float, float]:
    r"""Constants of eq. (15) of [NR08]: ``1 / b = slope * g + intercept`` for one direction.

    From eq. (14), ``1 / b = g * (sum(w) - max(w)) / target + max(w) / target`` with
    ``w = W(direction)``. With normalised matrices (``sum(w) = 1``) ``slope + intercept =
    1 / target`` exactly.

    Notes:
        The paper's eq. (15) (``target = 0.8``): ``1/b = 1.118 g + 0.131`` for directions 1-8
        and ``1/b = 1.035 g + 0.214`` for direction 9. The default matrices
        (:func:`probability_matrices`: 7 x 7, 0-2 px/frame + 0.5 jitter, ``p = 0.5``, ``x = 3``,
        W_basic spread fitted to direction 9's intercept) give, measured:
        directions 1-8 ``1/b = 1.1180 g + 0.1320`` (``b_{g=0} = 7.576``, paper 7.63) and
        direction 9 ``1/b = 1.0360 g + 0.2140`` (``b_{g=0} = 4.673``, paper "close to 4.65").
        Directions 1-8 are an independent check (only direction 9's intercept is fitted): both
        constants within 1 %. (The paper's pairs sum to 1.249, not 1.25: rounding.)

    Args:
        weights: ``(D, k, k)`` or ``(k, k)``.
        target: the wanted effective memory coefficient, ``> 0``.
        direction: the direction 1..9 of the line (ignored when ``D = 1``).

    Returns:
        ``(slope, intercept)`` as floats.

    Examples:
        >>> [round(c, 3) for c in memory_line(probability_matrices(), direction=1)]
        [1.118, 0.132]
        >>> [round(c, 3) for c in memory_line(probability_matrices(), direction=9)]
        [1.036, 0.214]
    """
    w = _pick(_memory_weights(weights), direction)
    target = check_number("target", target, low=0.0, low_inclusive=False)
    w = w.detach().to(torch.float64)
    total, peak = w.sum(), w.max()
    return float(total - peak) / target, float(peak) / target


def b_versus_g(
    weights: torch.Tensor,
    gs: torch.Tensor | Sequence[float],
    target: float = 0.8,
    *,
    direction: int = 9,
) -> torch.Tensor:
    """The curve ``b(g)`` of :func:`effective_memory` (Figure 6 of [NR08]) over several ``g``.

    Args:
        weights: ``(D, k, k)`` or ``(k, k)``.
        gs: values of ``g`` in ``[0, 1]``, a sequence or a tensor of any shape.
        target: the wanted effective memory coefficient, ``> 0``.
        direction: the direction 1..9 whose matrix sets ``b`` (ignored when ``D = 1``).

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
    w = _pick(_memory_weights(weights), direction)
    result = effective_memory(w.to(gs.dtype), gs.reshape(-1), target)
    return result.reshape(gs.shape)

"""Road-segment constrained constant-velocity model and constrained estimation ([PD] 24.2.3).

A road segment ``s`` is the straight line from ``p0`` to ``p1`` (m, in the local East-North
frame of [PD] section 24.2.2). Everything is batched over segments and tracks; state order is
``[x, vx, y, vy]`` (m, m/s) as in eq. 24.1-24.2.

- :func:`segment_constraint`: ``D x = L`` of eq. 24.3-24.4 (position on the line, velocity
  along it), with the line ``a x + b y + c = 0`` normalised so that ``(a, b)`` is the *unit*
  normal (the chapter leaves the scale free; the unit normal makes ``D D' = I``).
- :func:`road_noise_cov` and :func:`road_constant_velocity`: the directional process noise of
  eq. 24.5-24.6 and the model's ``(F, Q)``.
- :func:`on_segment_probability` and :func:`relaxed_road_noise_cov`: eq. 24.9-24.12.
- :func:`project_estimate`: the constrained estimate of eq. 24.14-24.16.

Our readings of the printed equations (the OCR and the chapter disagree with the standard
results in places):

- 24.6 prints ``Q = R_theta diag(sigma_d^2, sigma_n^2) R_theta'`` while the text says that
  ``sigma_n`` (the larger) is *along* the road and ``sigma_d`` across it. With ``R_theta`` the
  rotation by the road direction ``theta`` (it maps the x axis onto the road), the first
  diagonal entry is the along-road variance, so we take the arguments by name:
  ``Q_nu = R_theta diag(sigma_along^2, sigma_across^2) R_theta'``.
- 24.9 prints the relaxed entry ``q22 = sigma_n^2 P + sigma_d^2 (1 - P)``; the text says the
  across-road deviation must grow to the along-road one near the segment end (``P -> 0``), so the
  across variance is ``sigma_across^2 P + sigma_along^2 (1 - P)`` (the issue's reading too).
- 24.11-24.12: ``Q_s`` in the printed 24.11 is the projection ``Pi_s``, and ``f`` is the standard
  normal CDF (the OCR says "variance 1/2" but prints ``1/sqrt(2 pi) int exp(-t^2/2)``, which is
  the standard normal CDF). ``sigma_s^2 = u' P_pos u`` is the variance of the projection on the
  unit direction ``u`` (Ulmke and Koch 2006, the chapter's [19]; our reading). We implement 24.11
  for every position (it is already small outside ``[0, l]``); the printed 24.10 would set it to
  0 outside.
- 24.14 lacks a transpose: ``x_s = x - P D' (D P D')^-1 (D x - L)``.
- 24.16 lacks an inverse: ``W = P D' (D P D')^-1 D``; then 24.15 ``P_s = (I - W) P (I - W)'``
  equals ``P - W P`` and ``D P_s = 0``.
- ``F_{s,i}`` of 24.5 is "described in [12]" and not printed: we use the plain constant-velocity
  ``F`` and enforce the road by :func:`project_estimate`.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from hocnet._check import check_number
from hocnet.tracking.kalman import DTYPE, as_float64, constant_velocity

__all__ = [
    "on_segment_probability",
    "project_estimate",
    "relaxed_road_noise_cov",
    "road_constant_velocity",
    "road_noise_cov",
    "segment_constraint",
]


def _segments(p0: Any, p1: Any) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Validate endpoints ``(..., 2)``; return ``p0``, unit direction ``u`` and length ``l``."""
    p0 = as_float64("p0", p0, min_dim=1)
    p1 = as_float64("p1", p1, min_dim=1)
    for name, p in (("p0", p0), ("p1", p1)):
        if p.shape[-1] != 2:
            raise ValueError(
                f"`{name}`: expected points of shape (..., 2) in m, got {tuple(p.shape)}"
            )
    d = p1 - p0
    length = torch.linalg.vector_norm(d, dim=-1)
    if d.numel() and bool((length <= 0).any()):
        raise ValueError(
            f"`p1`: expected segments of non-zero length, got {int((length <= 0).sum())} "
            "with p1 == p0"
        )
    return p0, d / length.unsqueeze(-1), length


def segment_constraint(p0: Any, p1: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear constraint ``D x = L`` of a road segment, eq. 24.3-24.4.

    With the unit normal ``(a, b) = (-u_y, u_x)`` of the direction ``u`` and
    ``c = -(a x0 + b y0)``: ``D = [[a, 0, b, 0], [0, a, 0, b]]`` and ``L = [-c, 0]'``, i.e. the
    position lies on the line and the velocity is orthogonal to the normal.

    Args:
        p0: segment start points ``(..., 2)`` in m.
        p1: segment end points ``(..., 2)`` in m.

    Returns:
        ``(D, L)`` of shapes ``(..., 2, 4)`` and ``(..., 2)``, float64.

    Raises:
        TypeError, ValueError: bad shapes, NaN/inf, zero-length segments.

    Examples:
        >>> D, L = segment_constraint(torch.tensor([0.0, 5.0]), torch.tensor([10.0, 5.0]))
        >>> D.tolist(), L.tolist()
        ([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], [5.0, 0.0])
    """
    p0, u, _ = _segments(p0, p1)
    a, b = 0.0 - u[..., 1], u[..., 0]
    c = 0.0 - (a * p0[..., 0] + b * p0[..., 1])
    zero = torch.zeros_like(a)
    D = torch.stack(
        [torch.stack([a, zero, b, zero], -1), torch.stack([zero, a, zero, b], -1)], dim=-2
    )
    L = torch.stack([-c, zero], -1)
    return D, L


def road_noise_cov(p0: Any, p1: Any, sigma_along: float, sigma_across: float) -> torch.Tensor:
    """Directional acceleration covariance ``R_theta diag(s_along^2, s_across^2) R_theta'``.

    Eq. 24.6 (our reading of the diagonal's order, see the module docstring).

    Args:
        p0: segment start points ``(..., 2)`` in m.
        p1: segment end points ``(..., 2)`` in m.
        sigma_along: acceleration noise along the road, m/s^2 (``>= 0``).
        sigma_across: acceleration noise across the road, m/s^2 (``>= 0``).

    Returns:
        ``(..., 2, 2)`` float64 covariance in (m/s^2)^2, in the (x, y) frame.

    Examples:
        >>> road_noise_cov(torch.zeros(2), torch.tensor([0.0, 1.0]), 0.8, 0.4).tolist()
        [[0.16000000000000003, 0.0], [0.0, 0.6400000000000001]]
    """
    _, u, _ = _segments(p0, p1)
    sa = check_number("sigma_along", sigma_along, low=0.0)
    sc = check_number("sigma_across", sigma_across, low=0.0)
    normal = torch.stack([-u[..., 1], u[..., 0]], -1)
    return sa * sa * u.unsqueeze(-1) * u.unsqueeze(-2) + sc * sc * normal.unsqueeze(
        -1
    ) * normal.unsqueeze(-2)


def road_constant_velocity(
    dt: float, p0: Any, p1: Any, sigma_along: float, sigma_across: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(F, Q)`` of the constant-velocity model on road segments, eq. 24.5-24.8.

    ``F`` is the constant-velocity transition (see the module docstring on ``F_{s,i}``) and
    ``Q = Gamma(dt) Q_nu Gamma(dt)'`` with ``Q_nu`` from :func:`road_noise_cov`; e.g. the
    chapter's model M2 has ``sigma_along = 0.8``, ``sigma_across = 0.4`` m/s^2.

    Args:
        dt: time step in s.
        p0: segment start points ``(S, 2)`` (or ``(2,)``) in m.
        p1: segment end points, same shape.
        sigma_along: m/s^2.
        sigma_across: m/s^2.

    Returns:
        ``(F, Q)``, each ``(S, 4, 4)`` (or ``(4, 4)``) float64.

    Examples:
        >>> F, Q = road_constant_velocity(1.0, torch.zeros(3, 2), torch.ones(3, 2), 0.8, 0.4)
        >>> F.shape, Q.shape
        (torch.Size([3, 4, 4]), torch.Size([3, 4, 4]))
    """
    cov = road_noise_cov(p0, p1, sigma_along, sigma_across)
    F, Q = constant_velocity(dt, 0.0, acceleration_cov=cov)
    return F.expand(*Q.shape), Q


def on_segment_probability(x: Any, P: Any, p0: Any, p1: Any) -> torch.Tensor:
    """Probability that the predicted position projects inside the segment, eq. 24.11.

    ``P{e_s} = Phi((l - Pi_s) / sigma_s) - Phi(-Pi_s / sigma_s)`` with ``Pi_s = u'(pos - p0)``
    the along-road coordinate (m), ``sigma_s^2 = u' P_pos u`` and ``Phi`` the standard normal
    CDF (our reading of 24.11-24.12; see the module docstring).

    Args:
        x: predicted states ``(..., 4)``.
        P: predicted covariances ``(..., 4, 4)``.
        p0: segment start points ``(..., 2)`` in m (broadcast).
        p1: segment end points ``(..., 2)`` in m.

    Returns:
        ``(...)`` float64 in [0, 1].

    Raises:
        ValueError: zero variance along the road, bad shapes.

    Examples:
        >>> p = on_segment_probability(torch.tensor([50.0, 0, 0, 0]), 100 * torch.eye(4),
        ...                            torch.zeros(2), torch.tensor([100.0, 0.0]))
        >>> round(float(p), 6)
        0.999999
    """
    x = as_float64("x", x, min_dim=1)
    P = as_float64("P", P, min_dim=2, square=True)
    if x.shape[-1] != 4 or P.shape[-1] != 4:
        raise ValueError(
            f"`x`: expected states (..., 4) and covariances (..., 4, 4), got {tuple(x.shape)} "
            f"and {tuple(P.shape)}"
        )
    p0, u, length = _segments(p0, p1)
    pos = x[..., [0, 2]]
    along = ((pos - p0) * u).sum(-1)
    Ppos = P[..., [0, 2], :][..., [0, 2]]
    var = (u.unsqueeze(-2) @ Ppos @ u.unsqueeze(-1)).squeeze(-1).squeeze(-1)
    if var.numel() and bool((var <= 0).any()):
        raise ValueError("`P`: expected a positive position variance along the road, got 0")
    sd = var.sqrt()

    def phi(t: torch.Tensor) -> torch.Tensor:
        return 0.5 * torch.erfc(-t / math.sqrt(2.0))

    return (phi((length - along) / sd) - phi(-along / sd)).clamp(0.0, 1.0)


def relaxed_road_noise_cov(
    p0: Any, p1: Any, sigma_along: float, sigma_across: float, p_on: Any
) -> torch.Tensor:
    """Acceleration covariance relaxed near the segment ends, eq. 24.9 (our reading).

    ``R_theta diag(sigma_along^2, q) R_theta'`` with the across-road variance
    ``q = sigma_across^2 p_on + sigma_along^2 (1 - p_on)``: on the segment (``p_on = 1``) this is
    :func:`road_noise_cov`; at its end (``p_on -> 0``) the noise becomes isotropic.

    Args:
        p0: segment start points ``(..., 2)`` in m.
        p1: segment end points ``(..., 2)`` in m.
        sigma_along: m/s^2.
        sigma_across: m/s^2.
        p_on: on-segment probabilities ``(...)`` in [0, 1] (:func:`on_segment_probability`).

    Returns:
        ``(..., 2, 2)`` float64.

    Examples:
        >>> cov = relaxed_road_noise_cov(torch.zeros(2), torch.tensor([1.0, 0.0]), 0.8, 0.4, 0.0)
        >>> [round(v, 12) for v in cov.flatten().tolist()]
        [0.64, 0.0, 0.0, 0.64]
    """
    _, u, _ = _segments(p0, p1)
    sa = check_number("sigma_along", sigma_along, low=0.0)
    sc = check_number("sigma_across", sigma_across, low=0.0)
    p = as_float64("p_on", p_on)
    if p.numel() and bool(((p < 0) | (p > 1)).any()):
        raise ValueError("`p_on`: expected probabilities in [0, 1], got values outside")
    q = sc * sc * p + sa * sa * (1.0 - p)
    normal = torch.stack([-u[..., 1], u[..., 0]], -1)
    uu = u.unsqueeze(-1) * u.unsqueeze(-2)
    nn = normal.unsqueeze(-1) * normal.unsqueeze(-2)
    return sa * sa * uu + q.unsqueeze(-1).unsqueeze(-1) * nn


def project_estimate(x: Any, P: Any, D: Any, L: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Constrained estimate by projection, eq. 24.14-24.16 (with the transpose and inverse).

    ``x_s = x - P D' (D P D')^-1 (D x - L)`` and ``P_s = (I - W) P (I - W)'`` with
    ``W = P D' (D P D')^-1 D``: the maximiser of the Gaussian density ``N(x; x_hat, P)`` on the
    affine set ``D x = L`` (Simon and Chia 2002, the chapter's [13] cites the same result).

    Args:
        x: estimates ``(..., n)``.
        P: covariances ``(..., n, n)``.
        D: constraints ``(..., c, n)`` (e.g. :func:`segment_constraint`), broadcast.
        L: right-hand sides ``(..., c)``.

    Returns:
        ``(x_s, P_s)`` of shapes ``(..., n)`` and ``(..., n, n)``; ``D x_s = L`` and
        ``D P_s = 0`` up to rounding.

    Raises:
        ValueError: bad shapes, ``D P D'`` singular (e.g. ``P`` has no variance across the road).

    Examples:
        >>> D, L = segment_constraint(torch.zeros(2), torch.tensor([1.0, 0.0]))
        >>> xs, Ps = project_estimate(torch.tensor([3.0, 1.0, 2.0, 0.5]), torch.eye(4), D, L)
        >>> [round(v, 12) + 0.0 for v in xs.tolist()]
        [3.0, 1.0, 0.0, 0.0]
    """
    x = as_float64("x", x, min_dim=1)
    P = as_float64("P", P, min_dim=2, square=True)
    D = as_float64("D", D, min_dim=2)
    L = as_float64("L", L, min_dim=1)
    n = x.shape[-1]
    if P.shape[-1] != n or D.shape[-1] != n:
        raise ValueError(
            f"`D`: expected P (..., {n}, {n}) and D (..., c, {n}) for states of size {n}, got "
            f"{tuple(P.shape)} and {tuple(D.shape)}"
        )
    if L.shape[-1] != D.shape[-2]:
        raise ValueError(f"`L`: expected last axis {D.shape[-2]} (rows of D), got {tuple(L.shape)}")
    PDt = P @ D.transpose(-1, -2)
    M = D @ PDt
    chol, info = torch.linalg.cholesky_ex(M)
    if bool((info != 0).any()):
        raise ValueError("`P`: expected D P D' positive definite, got a singular one")
    resid = (D @ x.unsqueeze(-1)).squeeze(-1) - L
    gain = torch.cholesky_solve(PDt.transpose(-1, -2), chol).transpose(-1, -2)  # P D' M^-1
    xs = x - (gain @ resid.unsqueeze(-1)).squeeze(-1)
    W = gain @ D
    eye = torch.eye(n, dtype=DTYPE)
    A = eye - W
    Ps = A @ P @ A.transpose(-1, -2)
    return xs, 0.5 * (Ps + Ps.transpose(-1, -2))

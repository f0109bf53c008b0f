"""Out-of-sequence measurements: Bar-Shalom's one-step-lag retrodiction ("algorithm A1").

[PD] section 24.4.5 processes the delayed IMINT / UGS reports (11 s delay) as out-of-sequence
measurements (OOSM) with "the algorithm described in [3]" (Bar-Shalom and Chen's IMM version of
Bar-Shalom, "Update with out-of-sequence measurements in tracking: exact solution", IEEE TAES
38(3), 2002), "the state retrodiction step done on the road". The chapter prints no equation;
we implement algorithm A1 of the 2002 paper (exact for a linear Gaussian model when the
measurement time ``tau`` lies in the last sampling interval, ``t_{k-1} <= tau <= t_k``):

With the state ``x(k|k), P(k|k)`` after the last update at ``t_k``, its prediction covariance
``P(k|k-1)``, the last innovation ``nu(k)`` with covariance ``S(k)`` and matrix ``H(k)``, the
backward transition ``F(tau, k) = F(k, tau)^-1`` and the process-noise covariance ``Q(k, tau)``
accumulated from ``tau`` to ``t_k``:

- ``g = H(k)' S(k)^-1 nu(k)`` and ``G = H(k)' S(k)^-1 H(k)`` (stored by the filter; both 0 when
  the track was not updated at ``t_k``),
- ``P_vv = Q - Q G Q``, ``P_xv = Q - P(k|k-1) G Q``,
- retrodiction ``x(tau|k) = F(tau, k) [x(k|k) - Q g]``,
  ``P(tau|k) = F(tau, k) [P(k|k) + P_vv - P_xv - P_xv'] F(tau, k)'``,
- cross covariance ``C = cov(x(k), x(tau) | Z^k) = [P(k|k) - P_xv] F(tau, k)'``,
- ``z_hat = h(x(tau|k))``, ``S(tau) = H(tau) P(tau|k) H(tau)' + R(tau)``,
  ``P_xz = C H(tau)'``, ``x(k|tau) = x(k|k) + P_xz S(tau)^-1 (z - z_hat)`` and
  ``P(k|tau) = P(k|k) - P_xz S(tau)^-1 P_xz'``.

"On the road" (our reading of 24.4.5): the retrodicted estimate is projected on the road
segment by eq. 24.14-24.16 before the update (``x_s = x - K (D x - L)``, a linear map
``A = I - W`` of the retrodiction, so ``P_s = A P A'`` and the cross covariance becomes ``C A'``),
and the updated estimate is projected again on its current segment by the caller.

Lag rule: only the one-step lag is exact and allowed: ``tau`` must satisfy
``t_{k-1} <= tau <= t_k`` (``t_k - tau <= t_k - t_{k-1}``); an older measurement raises
``ValueError`` naming the lag (and leaves every input tensor untouched: all functions here are
pure). **Policy for older reports** (``too_old``): ``"raise"`` (default here) or ``"drop"``:
the report is not used and is counted (:func:`oosm_too_old` gives the mask;
:func:`hocnet.tracking.vsimm.vsimm_oosm` ``too_old="drop"`` returns it as ``dropped``).

**Older reports (our addition, issue 12):** the multi-step "Al1" of Bar-Shalom, Chen and Mallick
(2004) by an equivalent measurement (:func:`equivalent_memory`, :func:`oosm_al1`,
:func:`cv_discrete_lag_noise`; exact for one step, without process noise or without
measurements inside the lag interval, approximate otherwise), and an exact storage-based
alternative, the Rauch-Tung-Striebel retrodiction from stored filter output
(:func:`oosm_retrodict_rts` then :func:`oosm_apply`). The VS-IMM uses Al1 through
:func:`hocnet.tracking.vsimm.vsimm_oosm` ``lag_memory=``, which also retrodicts reports older
than a row's birth (diffuse prior). Measured in the chapter's scenario (experiments/oosm_lags.py):
the video / UGS reports arrive 11 s late but never more than one GMTI scan late for a row that
exists at their time; the reports "out of lag" were reports older than the *birth* of the row
(a track started on a later GMTI report).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import torch

from hocnet._check import check_choice, check_number
from hocnet.tracking.kalman import DTYPE, as_float64

__all__ = [
    "Retrodiction",
    "check_oosm_time",
    "cv_discrete_lag_noise",
    "cv_transition",
    "cwna_noise",
    "equivalent_memory",
    "innovation_memory",
    "oosm_a1",
    "oosm_al1",
    "oosm_apply",
    "oosm_retrodict",
    "oosm_retrodict_rts",
    "oosm_too_old",
    "project_retrodiction",
]


def cv_transition(dt: float) -> torch.Tensor:
    """Constant-velocity transition ``F(dt)`` ``(4, 4)`` for any sign of ``dt`` (s).

    ``F(-dt) = F(dt)^-1`` is the backward transition ``F(tau, k)`` of the retrodiction.

    Examples:
        >>> cv_transition(-2.0)[0].tolist()
        [1.0, -2.0, 0.0, 0.0]
    """
    dt = check_number("dt", dt)
    f = torch.eye(4, dtype=DTYPE)
    f[0, 1] = f[2, 3] = dt
    return f


def cwna_noise(dt: float, q: Any) -> torch.Tensor:
    """Process noise ``(..., 4, 4)`` of the continuous white-noise-acceleration CV model.

    Per axis ``q [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` (Bar-Shalom et al. 2001, 6.2.2); ``q`` is the
    power spectral density in m^2/s^3, a scalar or ``(..., 2, 2)`` for correlated axes (e.g. a
    road-aligned covariance). Unlike the discrete (piecewise-constant) model it splits exactly:
    ``Q(t1 + t2) = F(t2) Q(t1) F(t2)' + Q(t2)``, which makes OOSM retrodiction exact.

    Examples:
        >>> cwna_noise(3.0, 1.0)[:2, :2].tolist()
        [[9.0, 4.5], [4.5, 3.0]]
    """
    dt = check_number("dt", dt, low=0.0)
    qq = as_float64("q", q)
    if qq.dim() < 2:
        qq = qq * torch.eye(2, dtype=DTYPE)
    blk = torch.tensor([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]], dtype=DTYPE)
    out = torch.zeros(*qq.shape[:-2], 4, 4, dtype=DTYPE)
    for a in range(2):
        for b in range(2):
            out[..., 2 * a : 2 * a + 2, 2 * b : 2 * b + 2] = qq[..., a, b, None, None] * blk
    return out


def oosm_too_old(t: Any, t_prev: Any, t_last: Any) -> torch.Tensor:
    """Mask of measurement times older than the one-step lag (``t < t_{k-1}``).

    The test of :func:`check_oosm_time` (tolerance ``1e-9 (1 + |t_k|)``).

    Args:
        t: ``(...)`` times of the out-of-sequence measurements, s.
        t_prev: ``(...)`` times ``t_{k-1}`` of the previous scan, s (broadcast).
        t_last: ``(...)`` times ``t_k`` of the current estimates, s (broadcast).

    Returns:
        ``(...)`` bool.

    Examples:
        >>> oosm_too_old(torch.tensor([5.0, -1.0]), 0.0, 10.0).tolist()
        [False, True]
    """
    t = as_float64("t", t)
    tp = as_float64("t_prev", t_prev)
    tl = as_float64("t_last", t_last)
    t, tp, tl = torch.broadcast_tensors(t, tp, tl)
    return t < tp - 1e-9 * (1.0 + tl.abs())


def check_oosm_time(t: Any, t_prev: Any, t_last: Any, *, too_old: str = "raise") -> torch.Tensor:
    """Check that measurement times ``t`` are within the one-step lag, return them as float64.

    Args:
        t: ``(...)`` times of the out-of-sequence measurements, s.
        t_prev: ``(...)`` times ``t_{k-1}`` of the previous scan, s.
        t_last: ``(...)`` times ``t_k`` of the current estimates, s.
        too_old: ``"raise"`` (default) or ``"drop"``: accept times older than ``t_{k-1}`` (the
            caller drops them, see :func:`oosm_too_old`).

    Raises:
        ValueError: ``t`` older than ``t_{k-1}`` with ``too_old="raise"`` (the message gives the
            lag ``t_k - t`` and the allowed lag ``t_k - t_{k-1}``) or newer than ``t_k`` (not
            out of sequence).

    Examples:
        >>> check_oosm_time(5.0, 0.0, 10.0).item()
        5.0
    """
    t = as_float64("t", t)
    tp = as_float64("t_prev", t_prev)
    tl = as_float64("t_last", t_last)
    t, tp, tl = torch.broadcast_tensors(t, tp, tl)
    check_choice("too_old", too_old, ("raise", "drop"))
    tol = 1e-9 * (1.0 + tl.abs())
    old = t < tp - tol
    if too_old == "raise" and old.numel() and bool(old.any()):
        i = int(torch.nonzero(old.flatten())[0])
        lag, allowed = float((tl - t).flatten()[i]), float((tl - tp).flatten()[i])
        raise ValueError(
            f"`t`: expected an out-of-sequence measurement within the one-step lag (lag <= "
            f"{allowed:g} s, t >= {float(tp.flatten()[i]):g} s), got t = "
            f"{float(t.flatten()[i]):g} s with lag {lag:g} s"
        )
    new = t > tl + tol
    if new.numel() and bool(new.any()):
        i = int(torch.nonzero(new.flatten())[0])
        raise ValueError(
            f"`t`: expected a time <= the track time {float(tl.flatten()[i]):g} s (an "
            f"out-of-sequence measurement), got {float(t.flatten()[i]):g} s; use the normal update"
        )
    return t


def innovation_memory(
    nu: Any, H: Any, S: Any, detected: Any | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """``g = H' S^-1 nu`` ``(..., n)`` and ``G = H' S^-1 H`` ``(..., n, n)`` of the last update.

    These two (with ``P(k|k-1)``) are all A1 needs from the last scan, whatever the measurement
    dimension. ``detected=False`` rows get zeros (no update at ``t_k``).

    Examples:
        >>> g, G = innovation_memory(torch.ones(1), torch.ones(1, 2), 2 * torch.eye(1))
        >>> g.tolist(), G.tolist()
        ([0.5, 0.5], [[0.5, 0.5], [0.5, 0.5]])
    """
    nu = as_float64("nu", nu, min_dim=1)
    H = as_float64("H", H, min_dim=2)
    S = as_float64("S", S, min_dim=2, square=True)
    SinvH = torch.linalg.solve(
        S, H.expand(*torch.broadcast_shapes(H.shape[:-2], S.shape[:-2]), *H.shape[-2:])
    )
    Ht = H.transpose(-1, -2)
    G = Ht @ SinvH
    g = (SinvH.transpose(-1, -2) @ nu.unsqueeze(-1)).squeeze(-1)
    if detected is not None:
        d = torch.as_tensor(detected, dtype=torch.bool)
        g = torch.where(d.unsqueeze(-1), g, torch.zeros_like(g))
        G = torch.where(d.unsqueeze(-1).unsqueeze(-1), G, torch.zeros_like(G))
    return g, 0.5 * (G + G.transpose(-1, -2))


class Retrodiction(NamedTuple):
    """Retrodicted state at ``tau`` (A1).

    Attributes:
        x: ``(..., n)`` ``x(tau|k)``.
        P: ``(..., n, n)`` ``P(tau|k)``.
        C: ``(..., n, n)`` the cross covariance ``cov(x(k), x(tau) | Z^k)``.
    """

    x: torch.Tensor
    P: torch.Tensor
    C: torch.Tensor


def oosm_retrodict(
    x: Any, P: Any, P_pred: Any, g: Any, G: Any, F_back: Any, Q: Any
) -> Retrodiction:
    """A1 retrodiction from ``t_k`` back to ``tau`` (equations in the module docstring).

    Args:
        x: ``(..., n)`` ``x(k|k)``.
        P: ``(..., n, n)`` ``P(k|k)``.
        P_pred: ``(..., n, n)`` ``P(k|k-1)``.
        g: ``(..., n)`` ``H' S^-1 nu`` of the last update (:func:`innovation_memory`).
        G: ``(..., n, n)`` ``H' S^-1 H``.
        F_back: ``(n, n)`` or ``(..., n, n)`` ``F(tau, k)`` (for the CV model ``F(-(t_k - tau))``).
        Q: ``(n, n)`` or ``(..., n, n)`` ``Q(k, tau)``.

    Returns:
        :class:`Retrodiction`.

    Examples:
        >>> r = oosm_retrodict(torch.zeros(2), torch.eye(2), 2 * torch.eye(2), torch.zeros(2),
        ...                    torch.zeros(2, 2), torch.eye(2), torch.eye(2))
        >>> r.P.diagonal().tolist()
        [0.0, 0.0]
    """
    return _retrodict(*_inputs(x=x, P=P, P_pred=P_pred, g=g, G=G, F_back=F_back, Q=Q))


# rank rules of the named OOSM arguments: (min_dim, square)
_ARG_RANK = {
    "x": (1, False),
    "P": (2, True),
    "P_pred": (2, True),
    "P_prior": (2, True),
    "g": (1, False),
    "G": (2, True),
    "F_back": (2, True),
    "Q": (2, True),
    "C0": (2, True),
    "z": (1, False),
    "hx": (1, False),
    "H": (2, False),
    "R": (2, True),
}


def _inputs(**values: Any) -> list[torch.Tensor]:
    """``as_float64`` of each named argument with its rank rule (``_ARG_RANK``), in order."""
    return [
        as_float64(name, v, min_dim=_ARG_RANK[name][0], square=_ARG_RANK[name][1])
        for name, v in values.items()
    ]


def _retrodict(
    x: torch.Tensor,
    P: torch.Tensor,
    Pp: torch.Tensor,
    g: torch.Tensor,
    G: torch.Tensor,
    Fb: torch.Tensor,
    Q: torch.Tensor,
    C0: torch.Tensor | None = None,
) -> Retrodiction:
    """A1 retrodiction; ``C0 = cov(x(k), w(k, tau) | Z^{k-1})`` (default ``Q``, see below).

    A1 takes the prior cross covariance of the state and of the process noise accumulated from
    ``tau`` to ``t_k`` equal to ``Q(k, tau)``, true when that noise is independent of the noise
    before ``tau`` (continuous white acceleration). For the piecewise-constant (discrete)
    acceleration of [PD] 24.5, constant over the whole interval, ``w(k, tau) = Gamma(lag) a``
    while ``x(k)`` contains ``Gamma(dt) a``: ``C0 = Gamma(dt) Sigma Gamma(lag)'`` (our exact
    generalisation): ``P_vv = Q - C0' G C0``, ``P_xv = C0 - P(k|k-1) G C0``,
    ``x(tau|k) = F(tau, k) [x(k|k) - C0' g]``.
    """
    if C0 is None:
        C0 = Q
    GC = G @ C0
    Pvv = Q - C0.transpose(-1, -2) @ GC
    Pxv = C0 - Pp @ GC
    xr = (Fb @ (x - (C0.transpose(-1, -2) @ g.unsqueeze(-1)).squeeze(-1)).unsqueeze(-1)).squeeze(-1)
    Fbt = Fb.transpose(-1, -2)
    Pr = Fb @ (P + Pvv - Pxv - Pxv.transpose(-1, -2)) @ Fbt
    C = (P - Pxv) @ Fbt
    return Retrodiction(xr, 0.5 * (Pr + Pr.transpose(-1, -2)), C)


def project_retrodiction(r: Retrodiction, D: Any, L: Any) -> Retrodiction:
    """Retrodiction "on the road": project on ``D x = L`` (eq. 24.14-24.16), cross covariance too.

    ``K = P D' (D P D')^+ ``, ``x_s = x - K (D x - L)``, ``A = I - K D``, ``P_s = A P A'``,
    ``C_s = C A'`` (the pseudo-inverse handles a singular ``D P D'``, e.g. a stopped state).

    Args:
        r: :class:`Retrodiction` with batch ``(...)``.
        D: ``(..., c, n)`` constraint (:meth:`~hocnet.tracking.road.RoadNetwork.constraint`).
        L: ``(..., c)``.

    Returns:
        The projected :class:`Retrodiction`.

    Examples:
        >>> r = Retrodiction(torch.tensor([5.0, 1.0, 3.0, 1.0]), torch.eye(4), torch.eye(4))
        >>> D = torch.tensor([[0.0, 0, 1, 0], [0, 0, 0, 1]])  # the road y = 0
        >>> project_retrodiction(r, D, torch.zeros(2)).x.tolist()
        [5.0, 1.0, 0.0, 0.0]
    """
    r = _as_retrodiction(r)
    D = as_float64("D", D, min_dim=2)
    L = as_float64("L", L, min_dim=1)
    xs, A = _projection(r.x, r.P, D, L)
    Ps = A @ r.P @ A.transpose(-1, -2)
    return Retrodiction(xs, 0.5 * (Ps + Ps.transpose(-1, -2)), r.C @ A.transpose(-1, -2))


def _as_retrodiction(r: Any) -> Retrodiction:
    if not isinstance(r, tuple) or len(r) != 3:
        raise TypeError(f"`r`: expected a Retrodiction (x, P, C), got {type(r).__name__}")
    return Retrodiction(
        as_float64("r.x", r[0], min_dim=1),
        as_float64("r.P", r[1], min_dim=2, square=True),
        as_float64("r.C", r[2], min_dim=2, square=True),
    )


def pinv_atol(P: torch.Tensor, rel: float = 1e-9) -> torch.Tensor:
    """Absolute pseudo-inverse cut-off ``rel * max_i |P_ii|`` per matrix ``(...)`` (our choice).

    For a matrix ``D P D'`` (or ``H P H' + R``) whose rows of ``D`` have unit norm, eigenvalues
    below ``rel`` times the scale of ``P`` are round-off, whatever the largest eigenvalue of the
    product is.

    Examples:
        >>> float(pinv_atol(torch.diag(torch.tensor([4.0, 0.0], dtype=torch.float64))))
        4e-09
    """
    scale = P.diagonal(dim1=-2, dim2=-1).abs().amax(-1)
    return (rel * scale).clamp(min=torch.finfo(DTYPE).tiny)


def pinv_sym(M: torch.Tensor, atol: torch.Tensor, rtol: float = 1e-9) -> torch.Tensor:
    """Pseudo-inverse of a symmetric ``M (..., c, c)`` with an absolute cut-off per matrix.

    Eigenvalues with ``|e| <= max(atol, rtol max|e|)`` are zero; ``atol (...)`` per matrix
    (e.g. :func:`pinv_atol`).

    Examples:
        >>> M = torch.diag(torch.tensor([2.0, 1e-30], dtype=torch.float64))
        >>> pinv_sym(M, pinv_atol(torch.eye(2, dtype=torch.float64))).diagonal().tolist()
        [0.5, 0.0]
    """
    ev, V = torch.linalg.eigh(0.5 * (M + M.transpose(-1, -2)))
    big = ev.abs().amax(-1, keepdim=True) if ev.numel() else ev
    tol = torch.maximum(atol.unsqueeze(-1), rtol * big)
    keep = ev.abs() > tol
    inv = torch.where(keep, 1.0 / torch.where(keep, ev, torch.ones_like(ev)), torch.zeros_like(ev))
    return (V * inv.unsqueeze(-2)) @ V.transpose(-1, -2)


def _projection(
    x: torch.Tensor, P: torch.Tensor, D: torch.Tensor, L: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Projected mean and the linear map ``A = I - P D' (D P D')^+ D`` (no checks)."""
    PDt = P @ D.transpose(-1, -2)
    M = D @ PDt
    M = 0.5 * (M + M.transpose(-1, -2))
    # D P D' is singular for a stopped mode and for a retrodiction whose across-road position
    # and velocity are driven by one noise. Its eigenvalues below 1e-9 of the scale of P (the
    # largest variance; the rows of D have unit norm) are zero. A cut-off relative to the
    # largest eigenvalue of D P D' itself (as before) failed when the estimate already lay on
    # the road: D P D' was pure round-off (1e-30), its "largest" eigenvalue was kept and
    # inverted, and the projected variances reached 1e17 (the stop mode under a GMTI detection)
    Minv = pinv_sym(M, pinv_atol(P))
    K = PDt @ Minv
    resid = (D @ x.unsqueeze(-1)).squeeze(-1) - L
    xs = x - (K @ resid.unsqueeze(-1)).squeeze(-1)
    A = torch.eye(x.shape[-1], dtype=DTYPE) - K @ D
    return xs, A


def oosm_apply(
    x: Any, P: Any, r: Retrodiction, z: Any, hx: Any, H: Any, R: Any
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A1 update of ``x(k|k)`` with the measurement ``z`` taken at ``tau``.

    Args:
        x: ``(..., n)`` ``x(k|k)``.
        P: ``(..., n, n)`` ``P(k|k)``.
        r: the (possibly projected) :class:`Retrodiction` to ``tau``.
        z: ``(..., m)`` measurement at ``tau``.
        hx: ``(..., m)`` ``h(x(tau|k))``.
        H: ``(..., m, n)`` its (AEKF / EKF) matrix at ``tau``.
        R: ``(..., m, m)``.

    Returns:
        ``(x(k|tau), P(k|tau), log N(z - hx; 0, S(tau)))`` of shapes ``(..., n)``,
        ``(..., n, n)`` and ``(...)``.

    Examples:
        >>> r = Retrodiction(torch.zeros(1), torch.eye(1), torch.eye(1))  # x(tau) = x(k)
        >>> x, P, ll = oosm_apply(torch.zeros(1), torch.eye(1), r, torch.ones(1), torch.zeros(1),
        ...                       torch.eye(1), torch.eye(1))
        >>> round(float(x), 12), round(float(P), 12)
        (0.5, 0.5)
    """
    x, P, z, hx, H, R = _inputs(x=x, P=P, z=z, hx=hx, H=H, R=R)
    return _apply(x, P, _as_retrodiction(r), z - hx, H, R)


def _apply(
    x: torch.Tensor,
    P: torch.Tensor,
    r: Retrodiction,
    nu: torch.Tensor,
    H: torch.Tensor,
    R: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    Ht = H.transpose(-1, -2)
    S = H @ r.P @ Ht + R
    S = 0.5 * (S + S.transpose(-1, -2))
    L, info = torch.linalg.cholesky_ex(S)
    if bool((info != 0).any()):
        raise ValueError(
            "`R`: expected a positive definite OOSM innovation covariance, got one that is not"
        )
    Pxz = r.C @ Ht
    K = torch.cholesky_solve(Pxz.transpose(-1, -2), L).transpose(-1, -2)
    x_new = x + (K @ nu.unsqueeze(-1)).squeeze(-1)
    P_new = P - K @ Pxz.transpose(-1, -2)
    w = torch.linalg.solve_triangular(L, nu.unsqueeze(-1), upper=False).squeeze(-1)
    logdet = 2.0 * torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    ll = -0.5 * ((w * w).sum(-1) + logdet + nu.shape[-1] * math.log(2.0 * math.pi))
    return x_new, 0.5 * (P_new + P_new.transpose(-1, -2)), ll


def oosm_a1(
    x: Any,
    P: Any,
    P_pred: Any,
    g: Any,
    G: Any,
    F_back: Any,
    Q: Any,
    z: Any,
    H: Any,
    R: Any,
    *,
    t: Any | None = None,
    t_prev: Any | None = None,
    t_last: Any | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Algorithm A1 for a linear measurement ``z = H x(tau) + w``, batched.

    Retrodiction (:func:`oosm_retrodict`) then update (:func:`oosm_apply`) with
    ``hx = H x(tau|k)``. With ``t``, ``t_prev``, ``t_last`` given the lag is checked first
    (:func:`check_oosm_time`).

    Returns:
        ``(x(k|tau), P(k|tau), log_likelihood)``.

    Raises:
        ValueError: measurement older than the one-step lag (nothing is modified).

    Examples:
        >>> F = cv_transition(-1.0)
        >>> H = torch.tensor([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
        >>> x, P, ll = oosm_a1(torch.zeros(4), torch.eye(4), torch.eye(4), torch.zeros(4),
        ...                    torch.zeros(4, 4), F, torch.zeros(4, 4), torch.ones(2), H,
        ...                    torch.eye(2))
        >>> x.shape, P.shape
        (torch.Size([4]), torch.Size([4, 4]))
    """
    if t is not None:
        check_oosm_time(t, t_prev, t_last)
    r = oosm_retrodict(x, P, P_pred, g, G, F_back, Q)
    H = as_float64("H", H, min_dim=2)
    hx = (H @ r.x.unsqueeze(-1)).squeeze(-1)
    return oosm_apply(x, P, r, z, hx, H, R)


# ------------------------------------------------------------------------------------------
# Multi-step lag: the equivalent-measurement algorithm "Al1" (our addition to the module)
# ------------------------------------------------------------------------------------------
#
# Bar-Shalom, Chen and Mallick, "One-step solution for the multistep out-of-sequence-measurement
# problem in tracking", IEEE TAES 40(1), 2004: a measurement from ``tau`` with
# ``t_{k-l} <= tau < t_{k-l+1}`` (lag of ``l`` sampling intervals) is processed in one step,
# without reprocessing the measurements of ``(t_{k-l}, t_k]``, by replacing all of them by one
# *equivalent measurement* of the state at ``t_k`` (``H* = I``) that carries the same information:
# ``P(k|k)^-1 = P(k|k-l)^-1 + R*^-1`` and ``x(k|k) = x(k|k-l) + P(k|k-l) S*^-1 (z* - x(k|k-l))``
# with ``S* = P(k|k-l) + R*``. The interval ``[t_{k-l}, t_k]`` is then one "step" of A1 whose
# prior is ``x(k|k-l), P(k|k-l)`` (stored by the filter: the prediction over the lag interval)
# and whose memory ``g = H' S^-1 nu``, ``G = H' S^-1 H`` is that of the equivalent measurement.
# From ``P(k|k) = P(k|k-l) - P(k|k-l) S*^-1 P(k|k-l)`` it follows, without forming ``R*``
# (infinite where the interval brought no information):
#
#     G* = S*^-1 = P(k|k-l)^-1 [P(k|k-l) - P(k|k)] P(k|k-l)^-1,
#     g* = S*^-1 nu* = P(k|k-l)^-1 [x(k|k) - x(k|k-l)]
#
# (pseudo-inverses for a singular prior). Our reading of the paper's Al1 (we could not consult
# its text, only its abstract and introduction: the equations above are derived here from the
# equivalent-measurement idea it names, and are tested against the exact re-run). It is exact
# for ``l = 1`` (``G* = H' S^-1 H``, ``g* = H' S^-1 nu``: A1), without process noise, and when the
# interval ``(t_{k-l}, t_k)`` holds no measurement; otherwise approximate, because the
# equivalent measurement's noise is taken independent of the process noise after ``tau`` while
# the real measurements at ``t_{k-l+1} .. t_{k-1}`` are correlated with it.
# Storage: ``x(k|k-j), P(k|k-j)`` for ``j = 1 .. N`` (``N`` the largest lag to serve), predicted
# forward at every step. The paper's further simplified "Bl1" is not implemented (we do not
# have its equations). Measured (tests/tracking/test_oosm.py): with process noise and
# measurements inside the interval Al1 over-reacts (the equivalent measurement's noise is
# correlated with the process noise after ``tau``, Al1 takes it independent): for 2-3-step lags
# of a 10 s CV filter its estimate is farther from the exact one than the estimate without the
# report, its NEES 4.5 instead of 4.0; its MSE against the truth is about that of dropping.
# :func:`oosm_retrodict_rts` is exact at the price of storing the filtered and predicted moments;
# the VS-IMM (``hocnet.tracking.vsimm.vsimm_oosm(lag_method="rts")``, the default with a lag
# memory) uses it per mode, Al1 stays available as ``lag_method="al1"`` (issue 12 review).


def equivalent_memory(
    x: Any, P: Any, x_prior: Any, P_prior: Any, *, rtol: float = 1e-12
) -> tuple[torch.Tensor, torch.Tensor]:
    """A1 memory ``g*, G*`` of the equivalent measurement of a lag interval (Al1, our reading).

    ``G* = P_prior^+ (P_prior - P) P_prior^+`` and ``g* = P_prior^+ (x - x_prior)`` (see the
    comment above this function; Bar-Shalom, Chen and Mallick 2004). ``P_prior - P`` is
    symmetrised and its negative eigenvalues (round-off, or an estimate not conditioned on the
    prior, e.g. after IMM mixing) clipped to 0 so that ``G*`` is positive semi-definite.

    Args:
        x: ``(..., n)`` ``x(k|k)``.
        P: ``(..., n, n)`` ``P(k|k)``.
        x_prior: ``(..., n)`` ``x(k|k-l)``, the prediction over the lag interval.
        P_prior: ``(..., n, n)`` ``P(k|k-l)``.
        rtol: relative cut-off of the pseudo-inverse of ``P_prior``.

    Returns:
        ``(g*, G*)`` of shapes ``(..., n)`` and ``(..., n, n)``, float64.

    Examples:
        >>> g, G = equivalent_memory(torch.ones(1), 0.5 * torch.eye(1), torch.zeros(1),
        ...                          torch.eye(1))
        >>> g.tolist(), G.tolist()  # a measurement z = 2 with R = 1 on a prior N(0, 1)
        ([1.0], [[0.5]])
    """
    x = as_float64("x", x, min_dim=1)
    P = as_float64("P", P, min_dim=2, square=True)
    xp = as_float64("x_prior", x_prior, min_dim=1)
    Pp = as_float64("P_prior", P_prior, min_dim=2, square=True)
    check_number("rtol", rtol, low=0.0)
    Pp = 0.5 * (Pp + Pp.transpose(-1, -2))
    Pinv = torch.linalg.pinv(Pp, hermitian=True, rtol=rtol)
    dP = Pp - P
    ev, V = torch.linalg.eigh(0.5 * (dP + dP.transpose(-1, -2)))
    dP = (V * ev.clamp(min=0.0).unsqueeze(-2)) @ V.transpose(-1, -2)
    G = Pinv @ dP @ Pinv
    g = (Pinv @ (x - xp).unsqueeze(-1)).squeeze(-1)
    return g, 0.5 * (G + G.transpose(-1, -2))


def cv_discrete_lag_noise(
    tau: Any, boundaries: Any, accel_cov: Any
) -> tuple[torch.Tensor, torch.Tensor]:
    """``Q(k, tau)`` and ``C0 = cov(x(k), w(k, tau))`` of the piecewise-constant CV noise, l steps.

    With one white acceleration ``a_p ~ N(0, Sigma)`` per step ``(b_p, b_{p+1}]`` ([PD] 24.5,
    the discrete model), the state at ``t_k`` contains ``F(t_k - b_{p+1}) Gamma(D_p) a_p``
    (``D_p`` the step length) and the noise accumulated from ``tau`` to ``t_k`` contains
    ``F(t_k - b_{p+1}) Gamma(d_p) a_p`` with ``d_p`` the part of the step after ``tau``:
    ``Q = sum_p F_p Gamma(d_p) Sigma Gamma(d_p)' F_p'`` and
    ``C0 = sum_p F_p Gamma(D_p) Sigma Gamma(d_p)' F_p'`` (our derivation; for one step this is
    the ``C0`` of :func:`_retrodict`). One ``Sigma`` for all steps (the caller's choice).

    Args:
        tau: ``(...)`` measurement times, s.
        boundaries: ``(..., N + 1)`` increasing step times ``t_{k-N} .. t_k`` (steps wholly
            before ``tau`` contribute nothing).
        accel_cov: ``(..., 2, 2)`` acceleration covariance (m/s^2)^2 in x, y.

    Returns:
        ``(Q, C0)``, each ``(..., 4, 4)`` for the state ``[x, vx, y, vy]``.

    Examples:
        >>> Q, C0 = cv_discrete_lag_noise(torch.tensor(15.0), torch.tensor([10.0, 20.0]),
        ...                               torch.eye(2))
        >>> Q[0, 0].item(), C0[0, 0].item()  # (5^2/2)^2 and (10^2/2)(5^2/2)
        (156.25, 625.0)
    """
    tau = as_float64("tau", tau)
    b = as_float64("boundaries", boundaries, min_dim=1)
    S = as_float64("accel_cov", accel_cov, min_dim=2, square=True)
    tk = b[..., -1]
    shape = torch.broadcast_shapes(tau.shape, b.shape[:-1], S.shape[:-2])
    Q = torch.zeros(*shape, 4, 4, dtype=DTYPE)
    C0 = torch.zeros(*shape, 4, 4, dtype=DTYPE)
    for p in range(b.shape[-1] - 1):
        lo, hi = b[..., p], b[..., p + 1]
        D = (hi - lo).clamp(min=0.0)
        d = (hi - torch.maximum(lo, tau)).clamp(min=0.0)
        Fp = _cv_F(tk - hi)
        Gd, GD = Fp @ _cv_gamma(d), Fp @ _cv_gamma(D)
        Q = Q + Gd @ S @ Gd.transpose(-1, -2)
        C0 = C0 + GD @ S @ Gd.transpose(-1, -2)
    return 0.5 * (Q + Q.transpose(-1, -2)), C0


def _cv_F(dt: torch.Tensor) -> torch.Tensor:
    F = torch.eye(4, dtype=DTYPE).expand(*dt.shape, 4, 4).clone()
    F[..., 0, 1] = F[..., 2, 3] = dt
    return F


def _cv_gamma(dt: torch.Tensor) -> torch.Tensor:
    Gm = torch.zeros(*dt.shape, 4, 2, dtype=DTYPE)
    Gm[..., 0, 0] = Gm[..., 2, 1] = 0.5 * dt * dt
    Gm[..., 1, 0] = Gm[..., 3, 1] = dt
    return Gm


def oosm_al1(
    x: Any,
    P: Any,
    x_prior: Any,
    P_prior: Any,
    F_back: Any,
    Q: Any,
    z: Any,
    H: Any,
    R: Any,
    *,
    C0: Any | None = None,
    t: Any | None = None,
    t_first: Any | None = None,
    t_last: Any | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Multi-step-lag OOSM update "Al1" (equivalent measurement, our reading), batched.

    The A1 retrodiction and update (:func:`oosm_retrodict`, :func:`oosm_apply`) over the lag
    interval ``[t_{k-l}, t_k]`` treated as one step, with the memory of the equivalent
    measurement (:func:`equivalent_memory`): no reprocessing of the measurements of the
    interval. Exact for ``l = 1`` (equals :func:`oosm_a1`), without process noise, or without
    measurements strictly inside the interval; an approximation otherwise (Bar-Shalom, Chen and
    Mallick, IEEE TAES 40(1), 2004; see the comment above :func:`equivalent_memory`).

    Args:
        x: ``(..., n)`` ``x(k|k)``.
        P: ``(..., n, n)`` ``P(k|k)``.
        x_prior: ``(..., n)`` ``x(k|k-l)`` (prediction from ``t_{k-l}`` to ``t_k``).
        P_prior: ``(..., n, n)`` ``P(k|k-l)``.
        F_back: ``(..., n, n)`` ``F(tau, k)``.
        Q: ``(..., n, n)`` ``Q(k, tau)``, the process noise accumulated from ``tau`` to ``t_k``.
        z: ``(..., m)`` the delayed measurement, ``z = H x(tau) + w``.
        H: ``(..., m, n)``.
        R: ``(..., m, m)``.
        C0: ``(..., n, n)`` ``cov(x(k), w(k, tau) | Z^{k-l})``; default ``Q`` (continuous white
            noise; see :func:`cv_discrete_lag_noise` for the piecewise-constant model).
        t: optional ``tau`` (s); with ``t_first`` (``t_{k-l}``) and ``t_last`` (``t_k``),
            ``t_{k-l} <= tau <= t_k`` is checked first (:func:`check_oosm_time`).
        t_first: ``t_{k-l}`` (s), with ``t``.
        t_last: ``t_k`` (s), with ``t``.

    Returns:
        ``(x(k|tau), P(k|tau), log N(z - H x(tau|k); 0, S(tau)))``.

    Raises:
        ValueError: ``tau`` outside the stored lag interval (nothing is modified), a
            non-positive-definite innovation covariance.

    Examples:
        >>> H = torch.tensor([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
        >>> x, P, ll = oosm_al1(torch.zeros(4), torch.eye(4), torch.zeros(4), 2 * torch.eye(4),
        ...                     cv_transition(-15.0), cwna_noise(15.0, 0.01), torch.ones(2), H,
        ...                     torch.eye(2))
        >>> x.shape, bool(P.trace() < 4)
        (torch.Size([4]), True)
    """
    if t is not None:
        check_oosm_time(t, t_first, t_last)
    x, P = _inputs(x=x, P=P)
    g, G = equivalent_memory(x, P, x_prior, P_prior)
    Pp, Fb, Qt = _inputs(P_prior=P_prior, F_back=F_back, Q=Q)
    C = None if C0 is None else _inputs(C0=C0)[0]
    r = _retrodict(x, P, Pp, g, G, Fb, Qt, C)
    H, z, R = _inputs(H=H, z=z, R=R)
    hx = (H @ r.x.unsqueeze(-1)).squeeze(-1)
    return _apply(x, P, r, z - hx, H, R)


def oosm_retrodict_rts(
    x: Any,
    P: Any,
    xf: Any,
    Pf: Any,
    xp: Any,
    Pp: Any,
    F: Any,
    x_tau: Any,
    P_tau: Any,
    P_tau_next: Any,
    *,
    rtol: float = 1e-12,
) -> Retrodiction:
    """Exact multi-step retrodiction from stored filter output (Rauch-Tung-Striebel), batched.

    The storage-based alternative to :func:`oosm_al1` (our addition): with the filtered
    ``x(j|j), P(j|j)`` and the predictions ``x(j+1|j), P(j+1|j)`` of the ``l`` steps after
    ``t_{k-l}`` stored, the fixed-interval smoother (Rauch, Tung and Striebel 1965) runs back from
    ``x(k|k)`` without reprocessing any measurement: ``J_j = cov(x_j, x_{j+1}) P(j+1|j)^-1``,
    ``x(j|k) = x(j|j) + J_j (x(j+1|k) - x(j+1|j))``,
    ``P(j|k) = P(j|j) + J_j (P(j+1|k) - P(j+1|j)) J_j'`` and the cross covariance
    ``cov(x_k, x_j | Z^k) = cov(x_k, x_{j+1} | Z^k) J_j'``; the last step goes to ``tau`` inside
    ``(t_{k-l}, t_{k-l+1}]``, with ``J = cov(x(tau), x_{k-l+1} | Z^{k-l}) P(k-l+1|k-l)^-1``
    (valid because the states after ``t_{k-l+1}`` depend on ``x(tau)`` only through
    ``x_{k-l+1}``, for the continuous and for the piecewise-constant noise alike). Exact for a
    linear Gaussian model; the result feeds :func:`oosm_apply`. ``l = 1`` is A1.

    Args:
        x: ``(..., n)`` ``x(k|k)``.
        P: ``(..., n, n)`` ``P(k|k)``.
        xf: ``(..., l, n)`` ``x(j|j)`` for ``j = k-l .. k-1`` (oldest first).
        Pf: ``(..., l, n, n)``.
        xp: ``(..., l, n)`` ``x(j+1|j)`` for the same ``j``.
        Pp: ``(..., l, n, n)``.
        F: ``(..., l, n, n)`` ``F(j+1, j)``.
        x_tau: ``(..., n)`` ``x(tau|k-l)``, the prediction from ``t_{k-l}`` to ``tau``.
        P_tau: ``(..., n, n)`` ``P(tau|k-l)``.
        P_tau_next: ``(..., n, n)`` ``cov(x(tau), x_{k-l+1} | Z^{k-l})``: ``P(tau|k-l) F'`` (``F``
            from ``tau`` to ``t_{k-l+1}``) for continuous noise; for the piecewise-constant noise
            ``F(d) P(k-l|k-l) F(D)' + Gamma(d) Sigma Gamma(D)'`` (``d = tau - t_{k-l}``, ``D``
            the step).
        rtol: relative cut-off of the pseudo-inverses of ``P(j+1|j)``.

    Returns:
        :class:`Retrodiction` ``(x(tau|k), P(tau|k), cov(x_k, x(tau) | Z^k))``.

    Examples:
        >>> I = torch.eye(1)
        >>> r = oosm_retrodict_rts(torch.ones(1), I, torch.zeros(1, 1), I[None], torch.zeros(1, 1),
        ...                        2 * I[None], I[None], torch.zeros(1), I, I)
        >>> r.x.tolist(), r.P.tolist(), r.C.tolist()  # x(tau) = x(k-1): smoothed
        ([0.5], [[0.75]], [[0.5]])
    """
    x = as_float64("x", x, min_dim=1)
    P = as_float64("P", P, min_dim=2, square=True)
    xf = as_float64("xf", xf, min_dim=2)
    Pf = as_float64("Pf", Pf, min_dim=3, square=True)
    xp = as_float64("xp", xp, min_dim=2)
    Pp = as_float64("Pp", Pp, min_dim=3, square=True)
    F = as_float64("F", F, min_dim=3, square=True)
    xt = as_float64("x_tau", x_tau, min_dim=1)
    Pt = as_float64("P_tau", P_tau, min_dim=2, square=True)
    Ptn = as_float64("P_tau_next", P_tau_next, min_dim=2)
    n_steps = xf.shape[-2]
    if n_steps < 1 or Pf.shape[-3] != n_steps or xp.shape[-2] != n_steps:
        raise ValueError(
            f"`xf`, `Pf`, `xp`, `Pp`, `F`: expected l >= 1 stored steps each, got "
            f"{tuple(xf.shape)}, {tuple(Pf.shape)}, {tuple(xp.shape)}"
        )

    def gain(cross: torch.Tensor, Ppred: torch.Tensor) -> torch.Tensor:
        Ps = 0.5 * (Ppred + Ppred.transpose(-1, -2))
        return cross @ torch.linalg.pinv(Ps, hermitian=True, rtol=rtol)

    xs, Ps, Cr = x, P, P
    for i in range(n_steps - 1, 0, -1):
        J = gain(Pf[..., i, :, :] @ F[..., i, :, :].transpose(-1, -2), Pp[..., i, :, :])
        Jt = J.transpose(-1, -2)
        xs = xf[..., i, :] + (J @ (xs - xp[..., i, :]).unsqueeze(-1)).squeeze(-1)
        Ps = Pf[..., i, :, :] + J @ (Ps - Pp[..., i, :, :]) @ Jt
        Cr = Cr @ Jt
    J = gain(Ptn, Pp[..., 0, :, :])
    Jt = J.transpose(-1, -2)
    xr = xt + (J @ (xs - xp[..., 0, :]).unsqueeze(-1)).squeeze(-1)
    Pr = Pt + J @ (Ps - Pp[..., 0, :, :]) @ Jt
    return Retrodiction(xr, 0.5 * (Pr + Pr.transpose(-1, -2)), Cr @ Jt)

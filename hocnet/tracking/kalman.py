"""Batched linear Kalman / EKF filtering, Gaussian likelihoods and gating (float64 torch).

Every function works on a whole batch of tracks in one call: states ``x`` of shape ``(..., n)``
and covariances ``P`` of shape ``(..., n, n)``, where ``...`` is any batch shape (typically
``(N,)`` tracks, or ``(N, r)`` tracks times IMM modes). Model matrices broadcast against the
batch: ``F`` may be ``(n, n)`` (one model for all tracks) or ``(..., n, n)``. All results are
``torch.float64``; inputs of another floating or integer dtype are converted.

State convention ([PD] eq. 24.1): ``x = [x, vx, y, vy]`` with positions in m and velocities in
m/s, time steps in s. The Kalman equations themselves are the standard ones (Bar-Shalom, Li and
Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001, ch. 5); [PD] uses
them in eq. 24.7-24.8 (prediction) without printing the update.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from hocnet._check import _describe, check_finite, check_number

__all__ = [
    "constant_velocity",
    "cv_gamma",
    "ekf_update",
    "gate",
    "gaussian_log_likelihood",
    "kalman_predict",
    "kalman_update",
    "mahalanobis2",
    "normal_cdf",
    "stop_model",
]

DTYPE = torch.float64


def normal_cdf(t: Any) -> torch.Tensor:
    """Standard normal CDF ``Phi(t) = erfc(-t / sqrt 2) / 2`` (float64), one helper for tracking.

    Used by the on-segment probability (24.11-24.12, :mod:`hocnet.tracking.road`) and the GMTI
    MDV notch (:mod:`hocnet.tracking.sensors`). ``erfc`` keeps the lower tail accurate.

    Args:
        t: ``(...)`` real values (``+-inf`` allowed).

    Returns:
        ``(...)`` float64 in [0, 1].

    Examples:
        >>> normal_cdf(torch.tensor([0.0, float("inf")])).tolist()
        [0.5, 1.0]
    """
    t = torch.as_tensor(t, dtype=DTYPE)
    return 0.5 * torch.erfc(-t / math.sqrt(2.0))


def as_float64(name: str, value: Any, *, min_dim: int = 0, square: bool = False) -> torch.Tensor:
    """Convert ``value`` to a finite float64 tensor with at least ``min_dim`` axes.

    Args:
        name: argument name for error messages.
        value: tensor, array or nested sequence of real numbers.
        min_dim: smallest allowed number of axes.
        square: require the last two axes to be equal (a matrix or batch of matrices).

    Raises:
        TypeError: if ``value`` is not real numeric array-like.
        ValueError: wrong rank, non-square matrix, NaN or infinity.
    """
    if not isinstance(value, torch.Tensor):
        try:
            value_in = value
            value = torch.as_tensor(value_in)
            if value.is_floating_point() and value.dtype != DTYPE:
                # Python floats default to float32 in torch: read them again in float64 so
                # that 0.002 stays 0.002 (not 0.0020000000949).
                value = torch.as_tensor(value_in, dtype=DTYPE)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`{name}`: expected a real tensor or array, got {_describe(value)}"
            ) from None
    if value.is_complex() or value.dtype == torch.bool:
        raise TypeError(f"`{name}`: expected a real tensor, got dtype {value.dtype}")
    value = value.to(DTYPE)
    if value.dim() < min_dim:
        raise ValueError(
            f"`{name}`: expected at least {min_dim} axes, got shape {tuple(value.shape)}"
        )
    if square and value.shape[-1] != value.shape[-2]:
        raise ValueError(
            f"`{name}`: expected square matrices (..., n, n), got {tuple(value.shape)}"
        )
    check_finite(name, value)
    return value


def _check_last(name: str, value: torch.Tensor, size: int, what: str) -> None:
    if value.shape[-1] != size:
        raise ValueError(
            f"`{name}`: expected last axis of size {size} ({what}), got shape {tuple(value.shape)}"
        )


def cv_gamma(dt: float) -> torch.Tensor:
    """Noise gain ``Gamma(dt)`` of the constant-velocity model for state ``[x, vx, y, vy]``.

    ``Gamma = [[dt^2/2, 0], [dt, 0], [0, dt^2/2], [0, dt]]``: a piecewise-constant white
    acceleration ``nu`` (m/s^2) drives the state as ``Gamma @ nu`` ([PD] eq. 24.5; the chapter
    defines Gamma by reference to Bar-Shalom et al., 2001, section 6.3.3).

    Args:
        dt: time step in s (``>= 0``).

    Returns:
        ``(4, 2)`` float64 tensor.

    Raises:
        TypeError, ValueError: if ``dt`` is not a finite number ``>= 0``.

    Examples:
        >>> cv_gamma(2.0)
        tensor([[2., 0.],
                [2., 0.],
                [0., 2.],
                [0., 2.]], dtype=torch.float64)
    """
    dt = check_number("dt", dt, low=0.0)
    g = torch.zeros(4, 2, dtype=DTYPE)
    g[0, 0] = g[2, 1] = dt * dt / 2.0
    g[1, 0] = g[3, 1] = dt
    return g


def constant_velocity(
    dt: float, sigma_a: float | Any, *, acceleration_cov: Any | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Transition ``F`` and process noise ``Q`` of the 2-D constant-velocity model.

    ``F = blockdiag([[1, dt], [0, 1]], [[1, dt], [0, 1]])`` for ``[x, vx, y, vy]`` and
    ``Q = Gamma(dt) @ Sigma @ Gamma(dt)'`` with ``Sigma = sigma_a^2 I_2`` (discrete white noise
    acceleration; [PD] eq. 24.5 with an isotropic noise). The chapter's M1 (``sigma = 0.05``
    m/s^2, section 24.6) is road-constrained: its noise is the directional one of 24.6 (pass it as
    ``acceleration_cov``, see :func:`hocnet.tracking.road.road_noise_cov`); the isotropic form
    is for tracking off the road network (e.g. pixel tracks).

    Args:
        dt: time step in s (``>= 0``).
        sigma_a: standard deviation of the acceleration noise in m/s^2 (``>= 0``); ignored when
            ``acceleration_cov`` is given.
        acceleration_cov: optional ``(2, 2)`` or ``(..., 2, 2)`` covariance ``Sigma`` of the
            acceleration noise in (m/s^2)^2 in the (x, y) frame (e.g. the road-aligned covariance
            of [PD] eq. 24.6). Then ``Q`` has shape ``(..., 4, 4)``.

    Returns:
        ``(F, Q)``: ``(4, 4)`` and ``(4, 4)`` (or ``(..., 4, 4)``) float64 tensors.

    Raises:
        TypeError, ValueError: bad ``dt``, ``sigma_a`` or ``acceleration_cov``.

    Examples:
        >>> F, Q = constant_velocity(1.0, 2.0)
        >>> F[0].tolist(), Q[0].tolist()
        ([1.0, 1.0, 0.0, 0.0], [1.0, 2.0, 0.0, 0.0])
    """
    dt = check_number("dt", dt, low=0.0)
    f = torch.eye(4, dtype=DTYPE)
    f[0, 1] = f[2, 3] = dt
    g = cv_gamma(dt)
    if acceleration_cov is None:
        s = check_number("sigma_a", sigma_a, low=0.0)
        sigma = (s * s) * torch.eye(2, dtype=DTYPE)
    else:
        sigma = as_float64("acceleration_cov", acceleration_cov, min_dim=2, square=True)
        _check_last("acceleration_cov", sigma, 2, "a 2 x 2 covariance")
    q = g @ sigma @ g.T
    return f, q


def stop_model(dt: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Stop model M0 of [PD] section 24.4.2: position held, velocity set to zero.

    ``F0 = diag(1, 0, 1, 0)`` for ``[x, vx, y, vy]`` and ``Q0 = 0``: a stopped target keeps its
    position exactly and has no velocity. The chapter gives M0 no matrices; this is our reading
    of "stop model" (Kirubarajan and Bar-Shalom's stop state). ``dt`` is accepted (and checked)
    only so that all model builders share a signature.

    Returns:
        ``(F0, Q0)``, two ``(4, 4)`` float64 tensors.

    Examples:
        >>> F0, Q0 = stop_model()
        >>> F0.diagonal(), float(Q0.abs().sum())
        (tensor([1., 0., 1., 0.], dtype=torch.float64), 0.0)
    """
    check_number("dt", dt, low=0.0)
    return torch.diag(torch.tensor([1.0, 0.0, 1.0, 0.0], dtype=DTYPE)), torch.zeros(
        4, 4, dtype=DTYPE
    )


def _broadcast_state(x: torch.Tensor, P: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Expand ``x (..., n)`` and ``P (..., n, n)`` to a common batch shape."""
    try:
        shape = torch.broadcast_shapes(x.shape[:-1], P.shape[:-2])
    except RuntimeError:
        raise ValueError(
            f"`P`: expected a batch shape compatible with `x` {tuple(x.shape[:-1])}, got "
            f"{tuple(P.shape[:-2])}"
        ) from None
    n = x.shape[-1]
    return x.expand(*shape, n), P.expand(*shape, n, n)


def _symmetrize(p: torch.Tensor) -> torch.Tensor:
    return (p + p.transpose(-1, -2)).mul_(0.5)


def kalman_predict(x: Any, P: Any, F: Any, Q: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Kalman prediction ``x' = F x``, ``P' = F P F' + Q`` ([PD] eq. 24.7-24.8), batched.

    Args:
        x: states ``(..., n)``.
        P: covariances ``(..., n, n)``.
        F: transition ``(n, n)`` or ``(..., n, n)`` (broadcast against the batch).
        Q: process noise ``(n, n)`` or ``(..., n, n)``.

    Returns:
        ``(x_pred, P_pred)`` of shapes ``(..., n)`` and ``(..., n, n)``, float64.

    Raises:
        TypeError, ValueError: non-numeric input, mismatched ``n``, NaN/inf.

    Examples:
        >>> F, Q = constant_velocity(1.0, 0.0)
        >>> x, P = kalman_predict(torch.tensor([[0.0, 1.0, 0.0, 2.0]]), torch.eye(4)[None], F, Q)
        >>> x
        tensor([[1., 1., 2., 2.]], dtype=torch.float64)
    """
    x = as_float64("x", x, min_dim=1)
    n = x.shape[-1]
    P = as_float64("P", P, min_dim=2, square=True)
    F = as_float64("F", F, min_dim=2, square=True)
    Q = as_float64("Q", Q, min_dim=2, square=True)
    for name, t in (("P", P), ("F", F), ("Q", Q)):
        _check_last(name, t, n, "the state dimension of `x`")
    x, P = _broadcast_state(x, P)
    return _predict(x, P, F, Q)


def _shared_left(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """``A @ B`` where ``A (k, p, q)`` or ``(p, q)`` is shared by the leading batch of ``B``.

    One GEMM per shared matrix instead of a broadcast batched matmul of tiny matrices (much
    faster on CPU); falls back to ``matmul`` when ``A`` is not such a shared matrix.
    """
    if A.dim() == 2 and B.dim() > 2:
        return torch.einsum("ab,...bc->...ac", A, B)
    if A.dim() == 3 and B.dim() > 3 and A.shape[0] == B.shape[-3]:
        return torch.einsum("kab,...kbc->...kac", A, B)
    return A @ B


def _shared_right(B: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
    """``B @ A`` where ``A`` is shared as in :func:`_shared_left`."""
    if A.dim() == 2 and B.dim() > 2:
        return torch.einsum("...ab,bc->...ac", B, A)
    if A.dim() == 3 and B.dim() > 3 and A.shape[0] == B.shape[-3]:
        return torch.einsum("...kab,kbc->...kac", B, A)
    return B @ A


def _dot_last(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``(a * b).sum(-1)`` as a short loop over the (small) last axis.

    A torch reduction over an axis of 2-4 entries is far slower than a few element-wise products.
    """
    out = a[..., 0] * b[..., 0]
    for k in range(1, a.shape[-1]):
        out = out + a[..., k] * b[..., k]
    return out


def _predict(
    x: torch.Tensor, P: torch.Tensor, F: torch.Tensor, Q: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Kalman prediction on validated float64 tensors (no checks)."""
    x_pred = _shared_left(F, x.unsqueeze(-1)).squeeze(-1)
    P_pred = _symmetrize(_shared_right(_shared_left(F, P), F.transpose(-1, -2)) + Q)
    return x_pred, P_pred


def mahalanobis2(innovation: Any, S: Any) -> torch.Tensor:
    """Squared Mahalanobis distance ``d^2 = nu' S^-1 nu``, batched.

    Args:
        innovation: ``(..., m)`` innovations ``nu = z - h(x)`` (measurement units, e.g. m).
        S: ``(..., m, m)`` innovation covariances (symmetric positive definite; broadcast).

    Returns:
        ``(...)`` float64 tensor of squared distances (dimensionless).

    Raises:
        ValueError: shape mismatch or ``S`` not positive definite.

    Examples:
        >>> mahalanobis2(torch.tensor([2.0, 0.0]), 4.0 * torch.eye(2))
        tensor(1., dtype=torch.float64)
    """
    nu = as_float64("innovation", innovation, min_dim=1)
    S = as_float64("S", S, min_dim=2, square=True)
    _check_last("S", S, nu.shape[-1], "the measurement dimension of `innovation`")
    return _mahalanobis2_chol(nu, _cholesky("S", S))


def _mahalanobis2_chol(nu: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
    """``nu' S^-1 nu`` from the Cholesky factor ``L`` of ``S`` (no validation)."""
    shape = torch.broadcast_shapes(nu.shape[:-1], L.shape[:-2])
    nu = nu.expand(*shape, nu.shape[-1])
    L = L.expand(*shape, *L.shape[-2:])
    w = torch.linalg.solve_triangular(L, nu.unsqueeze(-1), upper=False).squeeze(-1)
    return (w * w).sum(-1)


def _gaussian_ll_chol(nu: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
    """``log N(nu; 0, S)`` from the Cholesky factor ``L`` of ``S`` (no validation)."""
    d2 = _mahalanobis2_chol(nu, L)
    logdet = 2.0 * torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    return -0.5 * (d2 + logdet + nu.shape[-1] * math.log(2.0 * math.pi))


def _cholesky(name: str, S: torch.Tensor) -> torch.Tensor:
    L, info = torch.linalg.cholesky_ex(S)
    if bool((info != 0).any()):
        raise ValueError(
            f"`{name}`: expected symmetric positive definite matrices, got "
            f"{int((info != 0).sum())} that are not"
        )
    return L


def gaussian_log_likelihood(innovation: Any, S: Any) -> torch.Tensor:
    """Log of the Gaussian density ``N(nu; 0, S)``, batched.

    ``log N = -(d^2 + log det S + m log 2 pi) / 2`` with ``d^2`` from :func:`mahalanobis2`:
    the measurement likelihood ``p{z | M_i, Z^{k-1}}`` of [PD] eq. 24.29. The value is a density
    in 1 / (measurement units)^m.

    Args:
        innovation: ``(..., m)``.
        S: ``(..., m, m)`` symmetric positive definite.

    Returns:
        ``(...)`` float64 tensor.

    Raises:
        ValueError: shape mismatch or ``S`` not positive definite.

    Examples:
        >>> round(float(gaussian_log_likelihood(torch.zeros(1), torch.eye(1))), 6)
        -0.918939
    """
    nu = as_float64("innovation", innovation, min_dim=1)
    S = as_float64("S", S, min_dim=2, square=True)
    _check_last("S", S, nu.shape[-1], "the measurement dimension of `innovation`")
    return _gaussian_ll_chol(nu, _cholesky("S", S))


def gate(innovation: Any, S: Any, threshold: float) -> torch.Tensor:
    """Ellipsoidal validation gate: ``d^2 <= threshold`` (e.g. a chi-square quantile).

    Args:
        innovation: ``(..., m)``; to gate M measurements against N tracks pass
            ``z[None, :, :] - z_pred[:, None, :]`` of shape ``(N, M, m)`` and ``S[:, None]``.
        S: ``(..., m, m)``.
        threshold: gate size ``gamma > 0`` on the squared distance (dimensionless).

    Returns:
        ``(...)`` bool tensor, ``True`` inside the gate.

    Raises:
        TypeError, ValueError: bad shapes, ``S`` not positive definite, ``threshold <= 0``.

    Examples:
        >>> gate(torch.tensor([[1.0, 0.0], [5.0, 0.0]]), torch.eye(2), 9.21)
        tensor([ True, False])
    """
    threshold = check_number("threshold", threshold, low=0.0, low_inclusive=False)
    return mahalanobis2(innovation, S) <= threshold


def ekf_update(
    x: Any, P: Any, z: Any, hx: Any, H: Any, R: Any, *, joseph: bool = True
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(Extended) Kalman update with a linearised measurement, batched.

    ``nu = z - h(x)``, ``S = H P H' + R``, ``K = P H' S^-1``, ``x+ = x + K nu`` and
    ``P+ = (I - K H) P (I - K H)' + K R K'`` (Joseph form, the default; it equals filterpy's
    ``KalmanFilter.update``) or ``P+ = P - K S K'`` (``joseph=False``). For the EKF, ``hx`` is
    ``h`` evaluated at the predicted state and ``H`` its Jacobian there (e.g. the GMTI
    range-rate measurement of [PD] eq. 24.17-24.20, whose Jacobian the caller builds).

    Args:
        x: predicted states ``(..., n)``.
        P: predicted covariances ``(..., n, n)``.
        z: measurements ``(..., m)`` (broadcast against the batch).
        hx: predicted measurements ``h(x)``, ``(..., m)``.
        H: measurement Jacobians ``(m, n)`` or ``(..., m, n)``.
        R: measurement noise ``(m, m)`` or ``(..., m, m)``.
        joseph: use the Joseph-form covariance update.

    Returns:
        ``(x_upd, P_upd, log_likelihood)`` with shapes ``(..., n)``, ``(..., n, n)`` and
        ``(...)``; ``log_likelihood`` is :func:`gaussian_log_likelihood` of the innovation.

    Raises:
        TypeError, ValueError: bad shapes, NaN/inf, ``S`` not positive definite.

    Examples:
        >>> H = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
        >>> x, P, ll = ekf_update(torch.zeros(1, 4), torch.eye(4)[None], torch.tensor([[2.0, 0.0]]),
        ...                       torch.zeros(1, 2), H, torch.eye(2))
        >>> [round(v, 9) for v in x[0].tolist()]
        [1.0, 0.0, 0.0, 0.0]
    """
    x = as_float64("x", x, min_dim=1)
    n = x.shape[-1]
    P = as_float64("P", P, min_dim=2, square=True)
    _check_last("P", P, n, "the state dimension of `x`")
    H = as_float64("H", H, min_dim=2)
    _check_last("H", H, n, "the state dimension of `x`")
    m = H.shape[-2]
    z = as_float64("z", z, min_dim=1)
    _check_last("z", z, m, "the measurement dimension of `H`")
    hx = as_float64("hx", hx, min_dim=1)
    _check_last("hx", hx, m, "the measurement dimension of `H`")
    R = as_float64("R", R, min_dim=2, square=True)
    _check_last("R", R, m, "the measurement dimension of `H`")
    x, P = _broadcast_state(x, P)
    return _update(x, P, z - hx, H, R, joseph=joseph)


def _update(
    x: torch.Tensor,
    P: torch.Tensor,
    nu: torch.Tensor,
    H: torch.Tensor,
    R: torch.Tensor,
    *,
    joseph: bool = True,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Kalman update on validated float64 tensors, innovation ``nu`` given (no input checks).

    ``S^-1`` is formed once (``inv``, as filterpy does) and reused for the gain and the
    Mahalanobis distance; the Cholesky factor of ``S`` gives the positive-definiteness check and
    ``log det S``.
    """
    n = x.shape[-1]
    Ht = H.transpose(-1, -2)
    PHt = _shared_right(P, Ht)
    S = _symmetrize(_shared_left(H, PHt) + R)
    L = _cholesky_innovation(S)
    S_inv = torch.linalg.inv_ex(S)[0]
    K = PHt @ S_inv
    x_upd = x + (K @ nu.unsqueeze(-1)).squeeze(-1)
    if joseph:
        A = torch.eye(n, dtype=DTYPE) - _shared_right(K, H)
        P_upd = A @ P @ A.transpose(-1, -2) + _shared_right(K, R) @ K.transpose(-1, -2)
    else:
        P_upd = P - K @ S @ K.transpose(-1, -2)
    P_upd = _symmetrize(P_upd)
    w = (S_inv @ nu.unsqueeze(-1)).squeeze(-1)
    d2 = _dot_last(nu, w)
    logdet = 2.0 * torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    ll = -0.5 * (d2 + logdet + nu.shape[-1] * math.log(2.0 * math.pi))
    return x_upd, P_upd, ll


def _cholesky_innovation(S: torch.Tensor) -> torch.Tensor:
    L, info = torch.linalg.cholesky_ex(S)
    if bool((info != 0).any()):
        raise ValueError(
            "`R`: expected the innovation covariance H P H' + R to be positive definite, got "
            f"{int((info != 0).sum())} that are not (is R positive definite?)"
        )
    return L


def kalman_update(
    x: Any, P: Any, z: Any, H: Any, R: Any, *, joseph: bool = True
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Linear Kalman update with ``h(x) = H x``; see :func:`ekf_update` for the equations.

    Args:
        x: predicted states ``(..., n)``.
        P: predicted covariances ``(..., n, n)``.
        z: measurements ``(..., m)``.
        H: ``(m, n)`` or ``(..., m, n)``.
        R: ``(m, m)`` or ``(..., m, m)``.
        joseph: use the Joseph-form covariance update (as filterpy does).

    Returns:
        ``(x_upd, P_upd, log_likelihood)``, shapes ``(..., n)``, ``(..., n, n)``, ``(...)``.

    Raises:
        TypeError, ValueError: as :func:`ekf_update`.

    Examples:
        >>> H = torch.tensor([[1.0, 0.0]])
        >>> x0, P0, z = torch.zeros(3, 2), torch.eye(2), torch.ones(3, 1)
        >>> x, P, ll = kalman_update(x0, P0, z, H, torch.eye(1))
        >>> x[:, 0], P[0, 0, 0]
        (tensor([0.5000, 0.5000, 0.5000], dtype=torch.float64), tensor(0.5000, dtype=torch.float64))
    """
    x = as_float64("x", x, min_dim=1)
    H = as_float64("H", H, min_dim=2)
    _check_last("H", H, x.shape[-1], "the state dimension of `x`")
    hx = (H @ x.unsqueeze(-1)).squeeze(-1)
    return ekf_update(x, P, z, hx, H, R, joseph=joseph)

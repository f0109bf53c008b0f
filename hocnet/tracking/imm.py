"""Interacting Multiple Model (IMM) estimator batched over tracks, with the stop model M0.

One call filters all ``N`` tracks and all ``r`` modes at once; shapes:

- mode probabilities ``mu``: ``(N, r)``,
- mode-matched states ``x``: ``(N, r, n)`` and covariances ``P``: ``(N, r, n, n)``,
- transition matrix ``trans``: ``(r, r)`` or ``(N, r, r)`` with ``trans[..., i, j] = p_ij =
  P(mode i at k-1 -> mode j at k)`` (rows sum to 1; the convention of Bar-Shalom et al. 2001 and
  of filterpy's ``IMMEstimator`` code, ``cbar = mu @ M``),
- model matrices ``F``, ``Q``: ``(r, n, n)`` or ``(N, r, n, n)``.

Equations ([PD] section 24.4.2, the plain IMM of Bar-Shalom, Li and Kirubarajan 2001, section
11.6.6): mixing probabilities (24.33), mixed estimates (24.34-24.35), mode-matched filtering,
PD-aware mode likelihoods with the stop model (24.29-24.31), the track likelihood (24.32), the
mode-probability update (24.36) and the combination (24.37). Road constraints (VS-IMMC, 24.4.2
with segment constraints, variable mode sets and road-section hypotheses 24.38-24.40) are in
:mod:`hocnet.tracking.vsimm`, built on this module's kernels.

**The PD-aware likelihoods 24.30-24.31 are implemented once**, in
:func:`pd_mode_log_likelihoods` (its unchecked kernel ``_pd_mode_ll``);
:mod:`~hocnet.tracking.vsimm`, :mod:`~hocnet.tracking.mht` and :mod:`~hocnet.tracking.stonesoup`
call it. Our reading of 24.31:
the stop mode's ``Lambda_0 = delta_{m_j, 0}`` rests on the GMTI clutter notch (a stopped target
is below the minimum detectable velocity, so a GMTI cannot see it). For a sensor without an MDV
(video / UGS imagery sees stopped targets) the stop mode is scored like a moving one,
``Lambda_0 = PD p(z | M0)`` if detected and ``1 - PD`` if not (``stop_detectable=True``).

Our reading of 24.34-24.35: the OCR prints ``x0_i = sum_j x_j mu_{i|j}``, which swaps the
indices of (24.33) where ``mu_{i|j} = p_ij mu_i / cbar_j`` is the probability of mode ``i`` at
``k-1`` given mode ``j`` at ``k``. We implement the standard form ``x0_j = sum_i mu_{i|j} x_i``
and ``P0_j = sum_i mu_{i|j} [P_i + (x_i - x0_j)(x_i - x0_j)']``.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import torch

from hocnet._check import check_int, check_number
from hocnet.tracking.kalman import (
    DTYPE,
    _check_last,
    _predict,
    _shared_left,
    _update,
    as_float64,
)

__all__ = [
    "IMMStep",
    "imm_combine",
    "imm_mix",
    "imm_mixing_probabilities",
    "imm_mode_probabilities",
    "imm_step",
    "imm_track_log_likelihood",
    "pd_mode_log_likelihoods",
]


def _probabilities(name: str, value: Any, *, min_dim: int) -> torch.Tensor:
    t = as_float64(name, value, min_dim=min_dim)
    if t.numel() and bool((t < 0).any()):
        raise ValueError(
            f"`{name}`: expected non-negative probabilities, got a minimum {t.min():g}"
        )
    return t


def imm_mixing_probabilities(mu: Any, trans: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Predicted mode probabilities ``cbar`` and mixing probabilities ``mu_{i|j}`` (eq. 24.33).

    ``cbar_j = sum_i p_ij mu_i`` (the predicted mode probability ``mu_j(k|k-1)`` of 24.32) and
    ``mu_{i|j} = p_ij mu_i / cbar_j``. A mode that no other mode can reach (``cbar_j = 0``) gets
    zero mixing weights.

    Args:
        mu: ``(N, r)`` mode probabilities at ``k-1`` (rows sum to 1).
        trans: ``(r, r)`` or ``(N, r, r)``, ``trans[..., i, j] = P(i -> j)`` (rows sum to 1).

    Returns:
        ``(cbar, omega)``: ``(N, r)`` and ``(N, r, r)`` with ``omega[n, i, j] = mu_{i|j}``.

    Raises:
        TypeError, ValueError: bad shapes, negative or non-finite entries, rows of ``trans``
            that do not sum to 1 (tolerance 1e-6).

    Examples:
        >>> cbar, omega = imm_mixing_probabilities(torch.tensor([[0.5, 0.5]]),
        ...                                        torch.tensor([[0.9, 0.1], [0.2, 0.8]]))
        >>> cbar
        tensor([[0.5500, 0.4500]], dtype=torch.float64)
    """
    mu = _probabilities("mu", mu, min_dim=2)
    trans = _probabilities("trans", trans, min_dim=2)
    r = mu.shape[-1]
    if trans.shape[-2:] != (r, r):
        raise ValueError(
            f"`trans`: expected shape ({r}, {r}) or (N, {r}, {r}), got {tuple(trans.shape)}"
        )
    sums = trans.sum(-1)
    if trans.numel() and bool(((sums - 1.0).abs() > 1e-6).any()):
        worst = float(sums.flatten()[(sums - 1.0).abs().flatten().argmax()])
        raise ValueError(
            "`trans`: expected rows summing to 1 (trans[i, j] = P(i -> j)), got a row sum "
            f"{worst:.9g}"
        )
    return _mixing(mu, trans)


def _mixing(mu: torch.Tensor, trans: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`imm_mixing_probabilities` on validated tensors (no checks)."""
    joint = mu.unsqueeze(-1) * trans  # (N, r, r): p_ij mu_i
    cbar = joint.sum(-2)
    safe = torch.where(cbar > 0, cbar, torch.ones_like(cbar))
    omega = torch.where(cbar.unsqueeze(-2) > 0, joint / safe.unsqueeze(-2), torch.zeros_like(joint))
    return cbar, omega


def imm_mix(x: Any, P: Any, omega: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Mixed initial conditions of the mode-matched filters (eq. 24.34-24.35, our reading).

    ``x0_j = sum_i mu_{i|j} x_i`` and ``P0_j = sum_i mu_{i|j} [P_i + (x_i - x0_j)(x_i - x0_j)']``.

    Args:
        x: ``(N, r, n)`` mode-matched states at ``k-1``.
        P: ``(N, r, n, n)`` mode-matched covariances.
        omega: ``(N, r, r)`` mixing probabilities from :func:`imm_mixing_probabilities`.

    Returns:
        ``(x0, P0)``, shapes ``(N, r, n)`` and ``(N, r, n, n)``.

    Raises:
        TypeError, ValueError: bad shapes or values.

    Examples:
        >>> x0, P0 = imm_mix(torch.tensor([[[0.0], [2.0]]]), torch.zeros(1, 2, 1, 1),
        ...                  torch.full((1, 2, 2), 0.5))
        >>> x0[0, :, 0], P0[0, :, 0, 0]
        (tensor([1., 1.], dtype=torch.float64), tensor([1., 1.], dtype=torch.float64))
    """
    x = as_float64("x", x, min_dim=3)
    P = as_float64("P", P, min_dim=4, square=True)
    omega = as_float64("omega", omega, min_dim=3)
    r, n = x.shape[-2:]
    if P.shape[-3:] != (r, n, n):
        raise ValueError(f"`P`: expected shape (N, {r}, {n}, {n}), got {tuple(P.shape)}")
    if omega.shape[-2:] != (r, r):
        raise ValueError(f"`omega`: expected shape (N, {r}, {r}), got {tuple(omega.shape)}")
    return _mix(x, P, omega)


def _mix(
    x: torch.Tensor, P: torch.Tensor, omega: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`imm_mix` on validated tensors (no checks)."""
    omega_t = omega.transpose(-1, -2)  # (..., j, i): mu_{i|j}
    x0 = omega_t @ x
    d = x.unsqueeze(-3) - x0.unsqueeze(-2)  # (..., j, i, n): x_i - x0_j
    # sum_i mu_{i|j} P_i (a short loop over the r source modes beats a batched matmul of
    # tiny matrices), plus the spread sum_i mu_{i|j} d d' as D' diag(mu_{.|j}) D.
    P0 = sum(omega[..., i, :, None, None] * P[..., i : i + 1, :, :] for i in range(P.shape[-3]))
    P0 = P0 + (omega_t.unsqueeze(-1) * d).transpose(-1, -2) @ d
    P0 = P0 + P0.transpose(-1, -2)
    return x0, P0.mul_(0.5)


def _pd_mode_ll(
    ll: torch.Tensor,
    det: torch.Tensor,
    pd: torch.Tensor,
    is_stop: torch.Tensor | None,
    stop_detectable: torch.Tensor | bool = False,
) -> torch.Tensor:
    """Kernel of 24.30-24.31 on validated tensors (the one implementation; no checks).

    ``ll (..., r)``, ``det (...)`` bool, ``pd`` broadcastable to ``(..., r)`` in [0, 1],
    ``is_stop (r,)`` bool or ``None``, ``stop_detectable`` bool or ``(...)`` bool.
    """
    d = det.unsqueeze(-1)
    moving = torch.where(d, torch.log(pd) + ll, torch.log1p(-pd))
    if is_stop is None or not bool(is_stop.any()):
        return moving
    delta = torch.where(d, -torch.inf, 0.0).to(DTYPE)  # 24.31: delta_{m_j, 0}
    sd = torch.as_tensor(stop_detectable, dtype=torch.bool)
    if sd.dim():
        sd = sd.unsqueeze(-1)
    stop = torch.where(sd, moving, delta)
    return torch.where(is_stop, stop, moving)


def pd_mode_log_likelihoods(
    log_lik: Any,
    detected: Any,
    pd: Any,
    *,
    stop_mode: int | None = None,
    stop_detectable: Any = False,
) -> torch.Tensor:
    """PD-aware mode likelihoods with the stop model, eq. 24.30-24.31, in log form.

    Moving modes ``i != stop_mode``: ``Lambda_i = PD_i p(z | M_i)`` when the track is detected
    and ``1 - PD_i`` when not (24.30). Stop mode with ``stop_detectable=False`` (the chapter's
    GMTI case): ``Lambda_0 = delta_{m_j, 0}``, i.e. 1 when the track is not detected (a stopped
    target is below the GMTI minimum detectable velocity) and 0 when it is (24.31). With
    ``stop_detectable=True`` (a sensor without MDV, e.g. video / UGS, which does see stopped
    targets; our reading, see the module docstring) the stop mode is scored as 24.30:
    ``PD_0 p(z | M0)`` or ``1 - PD_0``. ``stop_mode=None`` (default) treats all modes as moving.

    Args:
        log_lik: ``(..., r)`` Gaussian log-likelihoods ``log p(z | M_i)`` (ignored where not
            detected; any finite value).
        detected: ``(...)`` bool, whether a measurement is associated with the track.
        pd: detection probability in (0, 1], or per-mode ``PD_i`` broadcastable to
            ``(..., r)`` with values in [0, 1] (e.g. the MDV-notch expected ``PD``).
        stop_mode: index of M0 in the mode axis, or ``None``.
        stop_detectable: bool or ``(...)`` bool tensor: whether the sensor sees stopped
            targets (no MDV); default ``False`` (the printed 24.31).

    Returns:
        ``(..., r)`` float64 ``log Lambda_i`` (``-inf`` for the stop mode of detected tracks when
        ``stop_detectable`` is false).

    Raises:
        TypeError, ValueError: bad shapes, ``pd`` outside its range, ``stop_mode`` out of range.

    Examples:
        >>> det = torch.tensor([True, False])
        >>> pd_mode_log_likelihoods(torch.zeros(2, 2), det, 0.9, stop_mode=0).exp()
        tensor([[0.0000, 0.9000],
                [1.0000, 0.1000]], dtype=torch.float64)
        >>> pd_mode_log_likelihoods(torch.zeros(2, 2), det, 0.9, stop_mode=0,
        ...                         stop_detectable=True).exp()
        tensor([[0.9000, 0.9000],
                [0.1000, 0.1000]], dtype=torch.float64)
    """
    ll = as_float64("log_lik", log_lik, min_dim=1)
    det = torch.as_tensor(detected)
    if det.dtype != torch.bool:
        raise TypeError(f"`detected`: expected a bool tensor, got dtype {det.dtype}")
    if det.shape != ll.shape[:-1]:
        raise ValueError(
            f"`detected`: expected shape {tuple(ll.shape[:-1])}, got {tuple(det.shape)}"
        )
    if isinstance(pd, (int, float)):
        pd = check_number("pd", pd, low=0.0, high=1.0, low_inclusive=False)
        pdt = torch.tensor(pd, dtype=DTYPE)
    else:
        pdt = as_float64("pd", pd)
        if pdt.numel() and bool(((pdt < 0) | (pdt > 1)).any()):
            raise ValueError("`pd`: expected detection probabilities in [0, 1], got values outside")
        try:
            torch.broadcast_shapes(pdt.shape, ll.shape)
        except RuntimeError:
            raise ValueError(
                f"`pd`: expected a shape broadcastable to {tuple(ll.shape)}, got {tuple(pdt.shape)}"
            ) from None
    r = ll.shape[-1]
    is_stop = None
    if stop_mode is not None:
        stop_mode = check_int("stop_mode", stop_mode, minimum=0, maximum=r - 1)
        is_stop = torch.arange(r) == stop_mode
    sd = torch.as_tensor(stop_detectable)
    if sd.dtype != torch.bool:
        raise TypeError(f"`stop_detectable`: expected a bool or bool tensor, got {sd.dtype}")
    if sd.dim() and sd.shape != ll.shape[:-1]:
        raise ValueError(
            f"`stop_detectable`: expected shape {tuple(ll.shape[:-1])}, got {tuple(sd.shape)}"
        )
    return _pd_mode_ll(ll, det, pdt, is_stop, sd)


def imm_track_log_likelihood(mode_log_lik: Any, cbar: Any) -> torch.Tensor:
    """Track likelihood ``Lambda = sum_i Lambda_i mu_i(k|k-1)`` (eq. 24.32), in log form.

    Args:
        mode_log_lik: ``(N, r)`` ``log Lambda_i`` (``-inf`` allowed).
        cbar: ``(N, r)`` predicted mode probabilities ``mu_i(k|k-1)``.

    Returns:
        ``(N,)`` float64 ``log Lambda``.

    Examples:
        >>> lam = torch.log(torch.tensor([[0.5, 1.0]]))
        >>> imm_track_log_likelihood(lam, torch.tensor([[0.5, 0.5]])).exp()
        tensor([0.7500], dtype=torch.float64)
    """
    ll = torch.as_tensor(mode_log_lik, dtype=DTYPE)
    cbar = _probabilities("cbar", cbar, min_dim=2)
    return torch.logsumexp(ll + torch.log(cbar), dim=-1)


def imm_mode_probabilities(cbar: Any, mode_log_lik: Any) -> torch.Tensor:
    """Mode-probability update ``mu_i(k) = Lambda_i cbar_i / c`` (eq. 24.36), computed stably.

    Args:
        cbar: ``(N, r)`` predicted mode probabilities.
        mode_log_lik: ``(N, r)`` mode log-likelihoods ``log Lambda_i`` (``-inf`` allowed).

    Returns:
        ``(N, r)`` float64, rows summing to 1.

    Raises:
        ValueError: a track whose modes all have zero likelihood (``c = 0``).

    Examples:
        >>> lam = torch.log(torch.tensor([[1.0, 3.0]]))
        >>> imm_mode_probabilities(torch.tensor([[0.5, 0.5]]), lam)
        tensor([[0.2500, 0.7500]], dtype=torch.float64)
    """
    cbar = _probabilities("cbar", cbar, min_dim=2)
    ll = torch.as_tensor(mode_log_lik, dtype=DTYPE)
    if bool(torch.isnan(ll).any()) or bool((ll == torch.inf).any()):
        raise ValueError("`mode_log_lik`: expected finite values or -inf, got NaN/+inf")
    return _mode_probabilities(cbar, ll)


def _mode_probabilities(cbar: torch.Tensor, ll: torch.Tensor) -> torch.Tensor:
    """:func:`imm_mode_probabilities` after the input checks (still raises when ``c = 0``)."""
    a = ll + torch.log(cbar)
    total = torch.logsumexp(a, dim=-1, keepdim=True)
    if a.numel() and bool(torch.isinf(total).any()):
        raise ValueError(
            "`mode_log_lik`: expected at least one mode with non-zero likelihood per track, got "
            f"{int(torch.isinf(total).sum())} tracks with none"
        )
    return torch.exp(a - total)


def imm_combine(mu: Any, x: Any, P: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Combined estimate ``x = sum_i mu_i x_i`` (eq. 24.37) and its covariance.

    ``P = sum_i mu_i [P_i + (x_i - x)(x_i - x)']`` (Bar-Shalom et al. 2001, eq. 11.6.6-21; the
    chapter prints only the mean).

    Args:
        mu: ``(N, r)``.
        x: ``(N, r, n)``.
        P: ``(N, r, n, n)``.

    Returns:
        ``(x, P)`` of shapes ``(N, n)`` and ``(N, n, n)``.

    Examples:
        >>> xc, Pc = imm_combine(torch.tensor([[0.5, 0.5]]), torch.tensor([[[0.0], [2.0]]]),
        ...                      torch.zeros(1, 2, 1, 1))
        >>> xc, Pc
        (tensor([[1.]], dtype=torch.float64), tensor([[[1.]]], dtype=torch.float64))
    """
    mu = _probabilities("mu", mu, min_dim=2)
    x = as_float64("x", x, min_dim=3)
    P = as_float64("P", P, min_dim=4, square=True)
    return _combine(mu, x, P)


def _combine(
    mu: torch.Tensor, x: torch.Tensor, P: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`imm_combine` on validated tensors (no checks)."""
    xc = torch.einsum("...i,...in->...n", mu, x)
    d = x - xc.unsqueeze(-2)
    Pc = torch.einsum("...i,...iab->...ab", mu, P + d.unsqueeze(-1) * d.unsqueeze(-2))
    return xc, 0.5 * (Pc + Pc.transpose(-1, -2))


class IMMStep(NamedTuple):
    """Result of :func:`imm_step` (all float64).

    Attributes:
        mu: ``(N, r)`` updated mode probabilities (24.36).
        x: ``(N, r, n)`` mode-matched updated states.
        P: ``(N, r, n, n)`` mode-matched updated covariances.
        x_comb: ``(N, n)`` combined state (24.37).
        P_comb: ``(N, n, n)`` combined covariance.
        log_likelihood: ``(N,)`` track log-likelihood ``log Lambda`` (24.32).
        mode_log_likelihood: ``(N, r)`` ``log Lambda_i`` (24.29-24.31).
        cbar: ``(N, r)`` predicted mode probabilities ``mu_i(k|k-1)``.
        x_pred: ``(N, r, n)`` mode-matched predicted states.
        P_pred: ``(N, r, n, n)`` mode-matched predicted covariances.
    """

    mu: torch.Tensor
    x: torch.Tensor
    P: torch.Tensor
    x_comb: torch.Tensor
    P_comb: torch.Tensor
    log_likelihood: torch.Tensor
    mode_log_likelihood: torch.Tensor
    cbar: torch.Tensor
    x_pred: torch.Tensor
    P_pred: torch.Tensor


def imm_step(
    mu: Any,
    x: Any,
    P: Any,
    trans: Any,
    F: Any,
    Q: Any,
    z: Any,
    H: Any,
    R: Any,
    *,
    detected: Any | None = None,
    pd: float | None = None,
    stop_mode: int | None = None,
    stop_detectable: Any = False,
) -> IMMStep:
    """One IMM cycle for ``N`` tracks at once: mix, predict, update, combine.

    Steps 1-5 of [PD] section 24.4.2 (eq. 24.33-24.37) without road constraints. With
    ``pd=None`` (default) every track is updated with its measurement and the mode likelihoods
    are the Gaussian ``p(z | M_i)`` (24.29): the plain IMM, equal to filterpy's
    ``IMMEstimator.predict(); update(z)``. With ``pd`` given, the likelihoods are those of
    24.30-24.31 (``stop_mode`` is the index of M0, see :func:`pd_mode_log_likelihoods`), and tracks
    with ``detected=False`` keep their predictions as mode-matched estimates.

    Args:
        mu: ``(N, r)`` mode probabilities at ``k-1``.
        x: ``(N, r, n)`` mode-matched states at ``k-1`` (m, m/s).
        P: ``(N, r, n, n)`` covariances.
        trans: ``(r, r)`` or ``(N, r, r)``, ``trans[..., i, j] = P(i -> j)``.
        F: ``(r, n, n)`` or ``(N, r, n, n)`` transitions (e.g. :func:`constant_velocity`,
            :func:`stop_model` stacked).
        Q: ``(r, n, n)`` or ``(N, r, n, n)`` process noises.
        z: ``(N, m)`` measurements (m); rows of undetected tracks must be finite and are ignored.
        H: ``(m, n)``, ``(r, m, n)`` or ``(N, r, m, n)``.
        R: ``(m, m)`` or broadcastable ``(..., m, m)``.
        detected: ``(N,)`` bool; ``None`` means all detected.
        pd: detection probability for 24.30, or ``None`` for the plain IMM.
        stop_mode: index of the stop model M0 (used only with ``pd``).
        stop_detectable: whether the sensor sees stopped targets (no MDV; video / UGS), see
            :func:`pd_mode_log_likelihoods` (used only with ``pd`` and ``stop_mode``).

    Returns:
        :class:`IMMStep`.

    Raises:
        TypeError, ValueError: bad shapes or values (argument named in the message).

    Examples:
        >>> from hocnet.tracking.kalman import constant_velocity, stop_model
        >>> F1, Q1 = constant_velocity(1.0, 0.5)
        >>> F0, Q0 = stop_model()
        >>> F, Q = torch.stack([F0, F1]), torch.stack([Q0, Q1])
        >>> H = torch.tensor([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
        >>> mu, x = torch.full((3, 2), 0.5), torch.zeros(3, 2, 4)
        >>> P = torch.eye(4).repeat(3, 2, 1, 1)
        >>> trans = torch.tensor([[0.9, 0.1], [0.1, 0.9]])
        >>> out = imm_step(mu, x, P, trans, F, Q, torch.ones(3, 2), H, torch.eye(2))
        >>> out.x_comb.shape, out.mu.shape
        (torch.Size([3, 4]), torch.Size([3, 2]))
    """
    # Inputs are validated once here (same checks and messages as the public building blocks);
    # the cycle itself runs on the unchecked kernels.
    cbar, omega = imm_mixing_probabilities(mu, trans)
    x = as_float64("x", x, min_dim=3)
    P = as_float64("P", P, min_dim=4, square=True)
    r, n = x.shape[-2:]
    if P.shape[-3:] != (r, n, n):
        raise ValueError(f"`P`: expected shape (N, {r}, {n}, {n}), got {tuple(P.shape)}")
    if omega.shape[-2:] != (r, r):
        raise ValueError(f"`omega`: expected shape (N, {r}, {r}), got {tuple(omega.shape)}")
    x0, P0 = _mix(x, P, omega)
    n_tracks, r, n = x0.shape
    F = as_float64("F", F, min_dim=3, square=True)
    Q = as_float64("Q", Q, min_dim=3, square=True)
    for name, t in (("F", F), ("Q", Q)):
        if t.shape[-3:] != (r, n, n):
            raise ValueError(
                f"`{name}`: expected shape ({r}, {n}, {n}) or (N, {r}, {n}, {n}), "
                f"got {tuple(t.shape)}"
            )
    x_pred, P_pred = _predict(x0, P0, F, Q)
    z = as_float64("z", z, min_dim=2)
    if z.shape[0] != n_tracks:
        raise ValueError(
            f"`z`: expected {n_tracks} rows (one per track), got shape {tuple(z.shape)}"
        )
    if detected is None:
        det = torch.ones(n_tracks, dtype=torch.bool)
    else:
        det = torch.as_tensor(detected)
        if det.dtype != torch.bool or det.shape != (n_tracks,):
            raise ValueError(
                f"`detected`: expected a bool tensor of shape ({n_tracks},), "
                f"got {_describe_mask(det)}"
            )
    H = as_float64("H", H, min_dim=2)
    _check_last("H", H, n, "the state dimension of `x`")
    m = H.shape[-2]
    _check_last("z", z, m, "the measurement dimension of `H`")
    R = as_float64("R", R, min_dim=2, square=True)
    _check_last("R", R, m, "the measurement dimension of `H`")
    hx = _shared_left(H, x_pred.unsqueeze(-1)).squeeze(-1)
    x_upd, P_upd, ll = _update(x_pred, P_pred, z.unsqueeze(-2) - hx, H, R)
    if pd is None:
        if not bool(det.all()):
            raise ValueError(
                "`pd`: expected a detection probability when some tracks are not detected, got None"
            )
        mode_ll = ll
    else:
        mode_ll = pd_mode_log_likelihoods(
            ll, det, pd, stop_mode=stop_mode, stop_detectable=stop_detectable
        )
        keep = det.view(-1, 1, 1)
        x_upd = torch.where(keep, x_upd, x_pred)
        P_upd = torch.where(keep.unsqueeze(-1), P_upd, P_pred)
    log_cbar = torch.log(cbar)
    mu_new = _mode_probabilities(cbar, mode_ll)
    x_c, P_c = _combine(mu_new, x_upd, P_upd)
    track_ll = torch.logsumexp(mode_ll + log_cbar, dim=-1)
    return IMMStep(mu_new, x_upd, P_upd, x_c, P_c, track_ll, mode_ll, cbar, x_pred, P_pred)


def _describe_mask(t: torch.Tensor) -> str:
    return f"dtype {t.dtype} and shape {tuple(t.shape)}"

import copy
import math

import numpy as np
import pytest
import torch

from hocnet.tracking.imm import (
    imm_combine,
    imm_mix,
    imm_mixing_probabilities,
    imm_mode_probabilities,
    imm_step,
    imm_track_log_likelihood,
    pd_mode_log_likelihoods,
)
from hocnet.tracking.kalman import constant_velocity, stop_model

H_POS = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
R = np.diag([25.0, 16.0])
# trans[i, j] = P(i -> j); deliberately asymmetric so a transposed convention would fail
TRANS = np.array([[0.80, 0.15, 0.05], [0.10, 0.85, 0.05], [0.02, 0.18, 0.80]])


def models(dt: float = 10.0):
    F0, Q0 = stop_model(dt)
    F1, Q1 = constant_velocity(dt, 0.05)
    F2, Q2 = constant_velocity(dt, 0.8)
    return torch.stack([F0, F1, F2]), torch.stack([Q0, Q1, Q2])


def make_tracks(n_tracks: int, seed: int):
    rng = np.random.default_rng(seed)
    x0 = rng.normal(size=(n_tracks, 4)) * np.array([100.0, 5.0, 100.0, 5.0])
    P0 = np.stack([np.diag(rng.uniform(10, 200, size=4)) for _ in range(n_tracks)])
    mu0 = rng.dirichlet(np.ones(3), size=n_tracks)
    return x0, P0, mu0, rng


def test_plain_imm_equals_filterpy_per_track():
    from filterpy.kalman import IMMEstimator, KalmanFilter

    F, Q = models()
    n_tracks, n_steps = 4, 8
    x0, P0, mu0, rng = make_tracks(n_tracks, 0)
    imms = []
    for t in range(n_tracks):
        filters = []
        for i in range(3):
            kf = KalmanFilter(dim_x=4, dim_z=2)
            kf.F, kf.Q, kf.H, kf.R = F[i].numpy(), Q[i].numpy(), H_POS, R
            kf.x, kf.P = x0[t][:, None].copy(), P0[t].copy()
            filters.append(kf)
        imms.append(IMMEstimator(filters, mu0[t].copy(), TRANS))
    mu = torch.tensor(mu0)
    x = torch.tensor(x0)[:, None].repeat(1, 3, 1)
    P = torch.tensor(P0)[:, None].repeat(1, 3, 1, 1)
    truth = x0.copy()
    for _ in range(n_steps):
        truth = truth @ constant_velocity(10.0, 0.0)[0].numpy().T
        z = truth[:, [0, 2]] + rng.normal(size=(n_tracks, 2)) * 5
        out = imm_step(
            mu,
            x,
            P,
            torch.tensor(TRANS),
            F,
            Q,
            torch.tensor(z),
            torch.tensor(H_POS),
            torch.tensor(R),
        )
        mu, x, P = out.mu, out.x, out.P
        for t, imm in enumerate(imms):
            imm.predict()
            imm.update(z[t][:, None])
            np.testing.assert_allclose(mu[t].numpy(), imm.mu, rtol=0, atol=1e-8)
            np.testing.assert_allclose(out.x_comb[t].numpy(), imm.x[:, 0], rtol=1e-8, atol=1e-8)
            np.testing.assert_allclose(out.P_comb[t].numpy(), imm.P, rtol=1e-8, atol=1e-8)
            for i, f in enumerate(imm.filters):
                np.testing.assert_allclose(x[t, i].numpy(), f.x[:, 0], rtol=1e-8, atol=1e-8)
                np.testing.assert_allclose(P[t, i].numpy(), f.P, rtol=1e-8, atol=1e-8)
                np.testing.assert_allclose(
                    out.mode_log_likelihood[t, i].item(), f.log_likelihood, rtol=1e-9
                )
    # the runs separate the modes: not a trivially uniform mu
    assert float(mu.max() - mu.min()) > 0.1


def loop_imm_step(mu, xs, Ps, trans, F, Q, z, detected, pd, stop):
    """IMM cycle straight from eq. 24.30-24.37 (standard index order), one track, numpy."""
    r = len(mu)
    cbar = np.array([sum(trans[i, j] * mu[i] for i in range(r)) for j in range(r)])
    w = np.array([[trans[i, j] * mu[i] / cbar[j] for j in range(r)] for i in range(r)])
    lam, xo, Po = np.zeros(r), [], []
    for j in range(r):
        x0 = sum(w[i, j] * xs[i] for i in range(r))
        P0 = sum(w[i, j] * (Ps[i] + np.outer(xs[i] - x0, xs[i] - x0)) for i in range(r))
        xp, Pp = F[j] @ x0, F[j] @ P0 @ F[j].T + Q[j]
        if detected:
            S = H_POS @ Pp @ H_POS.T + R
            K = Pp @ H_POS.T @ np.linalg.inv(S)
            nu = z - H_POS @ xp
            g = np.exp(-0.5 * nu @ np.linalg.solve(S, nu)) / np.sqrt(np.linalg.det(2 * np.pi * S))
            lam[j] = 0.0 if j == stop else pd * g
            A = np.eye(4) - K @ H_POS
            xo.append(xp + K @ nu)
            Po.append(A @ Pp @ A.T + K @ R @ K.T)
        else:
            lam[j] = 1.0 if j == stop else 1.0 - pd
            xo.append(xp)
            Po.append(Pp)
    mu_new = lam * cbar / np.sum(lam * cbar)
    return mu_new, xo, Po, np.sum(lam * cbar)


def test_pd_imm_with_stop_model_matches_loop():
    F, Q = models()
    n_tracks = 5
    x0, P0, mu0, rng = make_tracks(n_tracks, 1)
    xs = np.repeat(x0[:, None], 3, axis=1) + rng.normal(size=(n_tracks, 3, 4))
    Ps = np.repeat(P0[:, None], 3, axis=1)
    detected = np.array([True, False, True, False, True])
    z = x0[:, [0, 2]] + rng.normal(size=(n_tracks, 2)) * 3
    out = imm_step(
        torch.tensor(mu0),
        torch.tensor(xs),
        torch.tensor(Ps),
        torch.tensor(TRANS),
        F,
        Q,
        torch.tensor(z),
        torch.tensor(H_POS),
        torch.tensor(R),
        detected=torch.tensor(detected),
        pd=0.9,
        stop_mode=0,
    )
    for t in range(n_tracks):
        mu_ref, x_ref, P_ref, lam_ref = loop_imm_step(
            mu0[t], xs[t], Ps[t], TRANS, F.numpy(), Q.numpy(), z[t], detected[t], 0.9, 0
        )
        np.testing.assert_allclose(out.mu[t].numpy(), mu_ref, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(out.x[t].numpy(), np.array(x_ref), rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(out.P[t].numpy(), np.array(P_ref), rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(out.log_likelihood[t].item(), np.log(lam_ref), rtol=1e-10)
        if detected[t]:
            assert out.mu[t, 0] == 0.0  # a detected target is not stopped (24.31)
        else:
            assert out.mu[t, 0] > out.cbar[t, 0]  # a missed detection favours the stop model


def test_mixing_and_combination_match_loop():
    rng = np.random.default_rng(2)
    mu = rng.dirichlet(np.ones(3), size=2)
    xs = rng.normal(size=(2, 3, 4))
    Ps = np.stack([[np.eye(4) * (i + 1) for i in range(3)]] * 2)
    cbar, w = imm_mixing_probabilities(torch.tensor(mu), torch.tensor(TRANS))
    x0, P0 = imm_mix(torch.tensor(xs), torch.tensor(Ps), w)
    for t in range(2):
        for j in range(3):
            cj = sum(TRANS[i, j] * mu[t, i] for i in range(3))
            assert np.isclose(cbar[t, j].item(), cj, rtol=1e-13)
            wij = [TRANS[i, j] * mu[t, i] / cj for i in range(3)]
            xj = sum(wij[i] * xs[t, i] for i in range(3))
            Pj = sum(wij[i] * (Ps[t, i] + np.outer(xs[t, i] - xj, xs[t, i] - xj)) for i in range(3))
            np.testing.assert_allclose(x0[t, j].numpy(), xj, rtol=1e-12)
            np.testing.assert_allclose(P0[t, j].numpy(), Pj, rtol=1e-12)
    xc, Pc = imm_combine(torch.tensor(mu), torch.tensor(xs), torch.tensor(Ps))
    ref = np.einsum("ti,tin->tn", mu, xs)
    np.testing.assert_allclose(xc.numpy(), ref, rtol=1e-12)
    assert Pc.shape == (2, 4, 4)


def test_per_track_transition_matrices_and_empty_batch():
    mu = torch.tensor([[0.5, 0.5], [0.2, 0.8]], dtype=torch.float64)
    trans = torch.tensor([[[1.0, 0.0], [0.0, 1.0]], [[0.0, 1.0], [1.0, 0.0]]], dtype=torch.float64)
    cbar, _ = imm_mixing_probabilities(mu, trans)
    assert cbar.tolist() == [[0.5, 0.5], [0.8, 0.2]]
    F, Q = models()
    out = imm_step(
        torch.zeros(0, 3),
        torch.zeros(0, 3, 4),
        torch.zeros(0, 3, 4, 4),
        torch.tensor(TRANS),
        F,
        Q,
        torch.zeros(0, 2),
        torch.tensor(H_POS),
        torch.tensor(R),
    )
    assert out.x_comb.shape == (0, 4) and out.mu.shape == (0, 3)


def test_mode_probabilities_stable_for_tiny_likelihoods():
    mu = imm_mode_probabilities(torch.tensor([[0.5, 0.5]]), torch.tensor([[-2000.0, -2001.0]]))
    np.testing.assert_allclose(mu[0].numpy(), [1 / (1 + np.exp(-1)), np.exp(-1) / (1 + np.exp(-1))])
    ll = imm_track_log_likelihood(torch.tensor([[-2000.0, -2000.0]]), torch.tensor([[0.5, 0.5]]))
    assert np.isclose(ll.item(), -2000.0)


def test_errors():
    with pytest.raises(ValueError, match="`trans`"):
        imm_mixing_probabilities(torch.tensor([[0.5, 0.5]]), torch.tensor([[0.5, 0.6], [0.5, 0.5]]))
    with pytest.raises(ValueError, match="`mu`"):
        imm_mixing_probabilities(torch.tensor([[-0.5, 1.5]]), torch.eye(2))
    with pytest.raises(ValueError, match="`pd`"):
        pd_mode_log_likelihoods(torch.zeros(1, 2), torch.tensor([True]), 1.5)
    with pytest.raises(TypeError, match="`detected`"):
        pd_mode_log_likelihoods(torch.zeros(1, 2), torch.tensor([1]), 0.5)
    with pytest.raises(ValueError, match="`stop_mode`"):
        pd_mode_log_likelihoods(torch.zeros(1, 2), torch.tensor([True]), 0.5, stop_mode=2)
    with pytest.raises(ValueError, match="`mode_log_lik`"):
        imm_mode_probabilities(torch.tensor([[0.5, 0.5]]), torch.full((1, 2), -float("inf")))
    F, Q = models()
    args = (
        torch.full((2, 3), 1 / 3),
        torch.zeros(2, 3, 4),
        torch.eye(4).repeat(2, 3, 1, 1),
        torch.tensor(TRANS),
    )
    with pytest.raises(ValueError, match="`z`"):
        imm_step(*args, F, Q, torch.zeros(3, 2), torch.tensor(H_POS), torch.tensor(R))
    with pytest.raises(ValueError, match="`F`"):
        imm_step(*args, F[:2], Q, torch.zeros(2, 2), torch.tensor(H_POS), torch.tensor(R))
    with pytest.raises(ValueError, match="`pd`"):
        imm_step(
            *args,
            F,
            Q,
            torch.zeros(2, 2),
            torch.tensor(H_POS),
            torch.tensor(R),
            detected=torch.tensor([True, False]),
        )
    # a deep copy of the inputs is left untouched
    a = copy.deepcopy(args)
    imm_step(*args, F, Q, torch.zeros(2, 2), torch.tensor(H_POS), torch.tensor(R))
    for u, v in zip(a, args):
        assert torch.equal(torch.as_tensor(u), torch.as_tensor(v))


def test_pd_mode_log_likelihoods_default_and_stop_detectable_against_loop():
    """Findings 1 and 5: default ``stop_mode=None`` (as imm_step); 24.31 only without a view
    of stopped targets; per-mode PD; checked against the equations written as loops."""
    g = torch.Generator().manual_seed(0)
    ll = torch.randn(6, 3, generator=g, dtype=torch.float64)
    det = torch.tensor([True, False, True, False, True, True])
    sd = torch.tensor([False, False, True, True, True, False])
    pd = torch.rand(6, 3, generator=g, dtype=torch.float64) * 0.9 + 0.05
    # default: every mode moving
    got = pd_mode_log_likelihoods(ll, det, 0.8)
    for n in range(6):
        for i in range(3):
            want = math.log(0.8) + float(ll[n, i]) if det[n] else math.log(0.2)
            assert float(got[n, i]) == pytest.approx(want, rel=1e-12)
    got = pd_mode_log_likelihoods(ll, det, pd, stop_mode=1, stop_detectable=sd)
    for n in range(6):
        for i in range(3):
            p = float(pd[n, i])
            moving = p * math.exp(float(ll[n, i])) if det[n] else 1 - p
            if i == 1 and not sd[n]:
                lam = 0.0 if det[n] else 1.0  # 24.31: delta_{m_j, 0}
            else:
                lam = moving  # 24.30 (and the stop mode of a sensor that sees stops)
            want = math.log(lam) if lam > 0 else -math.inf
            assert float(got[n, i]) == pytest.approx(want, rel=1e-12)
    with pytest.raises(ValueError, match="`stop_detectable`"):
        pd_mode_log_likelihoods(ll, det, 0.8, stop_mode=0, stop_detectable=torch.ones(2) > 0)
    with pytest.raises(ValueError, match="`pd`"):
        pd_mode_log_likelihoods(ll, det, torch.full((6, 3), 1.5))

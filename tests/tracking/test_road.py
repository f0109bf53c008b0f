import math

import numpy as np
import pytest
import torch
from scipy.stats import norm

from hocnet.tracking.kalman import constant_velocity, cv_gamma
from hocnet.tracking.road import (
    on_segment_probability,
    project_estimate,
    relaxed_road_noise_cov,
    road_constant_velocity,
    road_noise_cov,
    segment_constraint,
)


def random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


def random_segments(rng: np.random.Generator, k: int):
    p0 = rng.uniform(-1000, 1000, size=(k, 2))
    p1 = p0 + rng.uniform(-500, 500, size=(k, 2))
    return torch.tensor(p0), torch.tensor(p1)


def test_constraint_holds_for_states_on_the_road():
    rng = np.random.default_rng(0)
    p0, p1 = random_segments(rng, 5)
    D, L = segment_constraint(p0, p1)
    assert D.shape == (5, 2, 4) and L.shape == (5, 2)
    t = torch.tensor(rng.uniform(0, 1, size=(5, 1)))
    speed = torch.tensor(rng.normal(size=(5, 1)) * 10)
    pos = p0 + t * (p1 - p0)
    vel = speed * (p1 - p0)
    x = torch.stack([pos[:, 0], vel[:, 0], pos[:, 1], vel[:, 1]], -1)
    torch.testing.assert_close((D @ x.unsqueeze(-1)).squeeze(-1), L, rtol=0, atol=1e-9)
    # a point off the line violates the first row by its signed distance
    off = x.clone()
    normal = torch.stack([-(p1 - p0)[:, 1], (p1 - p0)[:, 0]], -1)
    normal = normal / normal.norm(dim=-1, keepdim=True)
    off[:, 0] += 7.0 * normal[:, 0]
    off[:, 2] += 7.0 * normal[:, 1]
    torch.testing.assert_close(
        (D @ off.unsqueeze(-1)).squeeze(-1)[:, 0] - L[:, 0],
        torch.full((5,), 7.0, dtype=torch.float64),
    )


def test_road_noise_along_and_across():
    rng = np.random.default_rng(1)
    p0, p1 = random_segments(rng, 4)
    cov = road_noise_cov(p0, p1, 0.8, 0.4)
    u = (p1 - p0) / (p1 - p0).norm(dim=-1, keepdim=True)
    n = torch.stack([-u[:, 1], u[:, 0]], -1)
    along = (u.unsqueeze(-2) @ cov @ u.unsqueeze(-1)).flatten()
    across = (n.unsqueeze(-2) @ cov @ n.unsqueeze(-1)).flatten()
    torch.testing.assert_close(along, torch.full((4,), 0.64, dtype=torch.float64))
    torch.testing.assert_close(across, torch.full((4,), 0.16, dtype=torch.float64))
    # the printed eq. 24.6 form R_theta diag(.,.) R_theta' with theta the road direction
    for k in range(4):
        th = math.atan2(float(u[k, 1]), float(u[k, 0]))
        R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        np.testing.assert_allclose(cov[k].numpy(), R @ np.diag([0.64, 0.16]) @ R.T, atol=1e-14)
    F, Q = road_constant_velocity(10.0, p0, p1, 0.8, 0.4)
    g = cv_gamma(10.0)
    torch.testing.assert_close(Q, g @ cov @ g.T)
    torch.testing.assert_close(F[2], constant_velocity(10.0, 0.0)[0])


def test_relaxed_noise_interpolates():
    p0, p1 = torch.zeros(3, 2), torch.tensor([[3.0, 4.0]] * 3)
    p_on = torch.tensor([1.0, 0.5, 0.0], dtype=torch.float64)
    cov = relaxed_road_noise_cov(p0, p1, 0.8, 0.4, p_on)
    torch.testing.assert_close(cov[0], road_noise_cov(p0[0], p1[0], 0.8, 0.4))
    torch.testing.assert_close(cov[2], 0.64 * torch.eye(2, dtype=torch.float64))
    n = torch.tensor([-0.8, 0.6], dtype=torch.float64)
    assert float(n @ cov[1] @ n) == pytest.approx(0.16 * 0.5 + 0.64 * 0.5)


def test_on_segment_probability_matches_scipy():
    rng = np.random.default_rng(2)
    p0, p1 = random_segments(rng, 6)
    x = np.zeros((6, 4))
    t = rng.uniform(-0.3, 1.3, size=6)
    pos = p0.numpy() + t[:, None] * (p1 - p0).numpy()
    x[:, 0], x[:, 2] = pos[:, 0], pos[:, 1]
    P = np.stack([random_spd(rng, 4) * 300 for _ in range(6)])
    p = on_segment_probability(torch.tensor(x), torch.tensor(P), p0, p1)
    for k in range(6):
        d = (p1 - p0)[k].numpy()
        length = np.linalg.norm(d)
        u = d / length
        pi = u @ (pos[k] - p0[k].numpy())
        sd = math.sqrt(u @ P[k][np.ix_([0, 2], [0, 2])] @ u)
        assert float(p[k]) == pytest.approx(
            norm.cdf((length - pi) / sd) - norm.cdf(-pi / sd), abs=1e-12
        )


def test_projection_is_the_constrained_maximiser():
    rng = np.random.default_rng(3)
    p0, p1 = random_segments(rng, 5)
    D, L = segment_constraint(p0, p1)
    x = torch.tensor(rng.normal(size=(5, 4)) * 50)
    P = torch.tensor(np.stack([random_spd(rng, 4) for _ in range(5)]))
    xs, Ps = project_estimate(x, P, D, L)
    torch.testing.assert_close((D @ xs.unsqueeze(-1)).squeeze(-1), L, rtol=0, atol=1e-8)
    torch.testing.assert_close(
        D @ Ps, torch.zeros(5, 2, 4, dtype=torch.float64), rtol=0, atol=1e-10
    )
    for k in range(5):
        Dk, Lk, Pk, xk = D[k].numpy(), L[k].numpy(), P[k].numpy(), x[k].numpy()
        # minimise (y - x)' P^-1 (y - x) on {D y = L}: y = y0 + N a, normal equations in a
        y0 = np.linalg.lstsq(Dk, Lk, rcond=None)[0]
        Nk = np.linalg.svd(Dk)[2][2:].T
        Pinv = np.linalg.inv(Pk)
        a = np.linalg.solve(Nk.T @ Pinv @ Nk, Nk.T @ Pinv @ (xk - y0))
        np.testing.assert_allclose(xs[k].numpy(), y0 + Nk @ a, rtol=1e-9, atol=1e-8)
        # eq. 24.15-24.16 with the inverse, straight
        W = Pk @ Dk.T @ np.linalg.inv(Dk @ Pk @ Dk.T) @ Dk
        np.testing.assert_allclose(
            Ps[k].numpy(), (np.eye(4) - W) @ Pk @ (np.eye(4) - W).T, rtol=1e-9, atol=1e-9
        )


def test_errors():
    with pytest.raises(ValueError, match="`p1`"):
        segment_constraint(torch.zeros(2), torch.zeros(2))
    with pytest.raises(ValueError, match="`p0`"):
        segment_constraint(torch.zeros(3), torch.ones(3))
    with pytest.raises(ValueError, match="`sigma_along`"):
        road_noise_cov(torch.zeros(2), torch.ones(2), -1.0, 0.1)
    with pytest.raises(ValueError, match="`p_on`"):
        relaxed_road_noise_cov(torch.zeros(2), torch.ones(2), 1.0, 0.1, 1.5)
    D, L = segment_constraint(torch.zeros(2), torch.ones(2))
    with pytest.raises(ValueError, match="`P`"):
        project_estimate(torch.zeros(4), torch.zeros(4, 4), D, L)
    with pytest.raises(ValueError, match="`L`"):
        project_estimate(torch.zeros(4), torch.eye(4), D, torch.zeros(3))

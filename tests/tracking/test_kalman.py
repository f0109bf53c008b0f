import math

import numpy as np
import pytest
import torch

from hocnet.tracking.kalman import (
    constant_velocity,
    cv_gamma,
    ekf_update,
    gate,
    gaussian_log_likelihood,
    kalman_predict,
    kalman_update,
    mahalanobis2,
    stop_model,
)

H_POS = torch.tensor([[1.0, 0, 0, 0], [0, 0, 1.0, 0]], dtype=torch.float64)


def random_spd(gen: torch.Generator, shape: tuple[int, ...], n: int) -> torch.Tensor:
    a = torch.randn(*shape, n, n, generator=gen, dtype=torch.float64)
    return a @ a.transpose(-1, -2) + n * torch.eye(n, dtype=torch.float64)


def loop_update(x, P, z, H, R):
    """Textbook KF update, one track at a time, numpy."""
    out_x, out_P, out_ll = [], [], []
    for xi, Pi, zi in zip(x.numpy(), P.numpy(), z.numpy()):
        S = H @ Pi @ H.T + R
        K = Pi @ H.T @ np.linalg.inv(S)
        nu = zi - H @ xi
        out_x.append(xi + K @ nu)
        A = np.eye(len(xi)) - K @ H
        out_P.append(A @ Pi @ A.T + K @ R @ K.T)
        out_ll.append(
            -0.5
            * (nu @ np.linalg.solve(S, nu) + np.log(np.linalg.det(S)) + len(zi) * np.log(2 * np.pi))
        )
    return np.array(out_x), np.array(out_P), np.array(out_ll)


class TestConstantVelocity:
    def test_matrices(self):
        dt, s = 2.5, 0.3
        F, Q = constant_velocity(dt, s)
        g1 = np.array([[dt**2 / 2], [dt]])
        q1 = s**2 * g1 @ g1.T
        expected = np.zeros((4, 4))
        expected[:2, :2] = q1
        expected[2:, 2:] = q1
        np.testing.assert_allclose(Q.numpy(), expected, rtol=1e-14)
        np.testing.assert_array_equal(F.numpy()[[0, 2], [1, 3]], [dt, dt])
        assert F.dtype == Q.dtype == torch.float64

    def test_anisotropic_cov_equals_gamma_sandwich(self):
        cov = torch.tensor([[2.0, 0.5], [0.5, 1.0]], dtype=torch.float64)
        _, Q = constant_velocity(1.5, 0.0, acceleration_cov=cov)
        g = cv_gamma(1.5)
        torch.testing.assert_close(Q, g @ cov @ g.T)

    def test_stop_model_holds_position(self):
        F0, Q0 = stop_model()
        x, P = kalman_predict(torch.tensor([[3.0, 1.0, -2.0, 4.0]]), torch.eye(4), F0, Q0)
        assert x.tolist() == [[3.0, 0.0, -2.0, 0.0]]
        assert P[0, 1, 1] == 0 and P[0, 0, 0] == 1

    @pytest.mark.parametrize("bad", [-1.0, float("nan"), "a"])
    def test_bad_dt(self, bad):
        with pytest.raises((TypeError, ValueError), match="`dt`"):
            constant_velocity(bad, 1.0)


class TestKalman:
    def test_predict_matches_loop(self):
        gen = torch.Generator().manual_seed(0)
        x = torch.randn(5, 4, generator=gen, dtype=torch.float64)
        P = random_spd(gen, (5,), 4)
        F, Q = constant_velocity(3.0, 0.7)
        xp, Pp = kalman_predict(x, P, F, Q)
        for i in range(5):
            np.testing.assert_allclose(xp[i].numpy(), F.numpy() @ x[i].numpy(), rtol=1e-13)
            np.testing.assert_allclose(
                Pp[i].numpy(), F.numpy() @ P[i].numpy() @ F.numpy().T + Q.numpy(), rtol=1e-12
            )

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_update_matches_loop(self, seed):
        gen = torch.Generator().manual_seed(seed)
        x = torch.randn(7, 4, generator=gen, dtype=torch.float64) * 10
        P = random_spd(gen, (7,), 4)
        z = torch.randn(7, 2, generator=gen, dtype=torch.float64) * 10
        R = random_spd(gen, (), 2)
        xu, Pu, ll = kalman_update(x, P, z, H_POS, R)
        ex, eP, ell = loop_update(x, P, z, H_POS.numpy(), R.numpy())
        np.testing.assert_allclose(xu.numpy(), ex, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(Pu.numpy(), eP, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(ll.numpy(), ell, rtol=1e-10)
        # the short form P - K S K' agrees with the Joseph form
        _, Pu2, _ = kalman_update(x, P, z, H_POS, R, joseph=False)
        torch.testing.assert_close(Pu2, Pu, rtol=1e-9, atol=1e-9)

    def test_matches_filterpy(self):
        from filterpy.kalman import KalmanFilter

        F, Q = constant_velocity(1.0, 0.5)
        R = np.diag([4.0, 9.0])
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.F, kf.Q, kf.H, kf.R = F.numpy(), Q.numpy(), H_POS.numpy(), R
        kf.x = np.array([[0.0], [1.0], [0.0], [-1.0]])
        kf.P = np.eye(4) * 10
        x, P = torch.tensor(kf.x[:, 0])[None], torch.tensor(kf.P)[None]
        rng = np.random.default_rng(3)
        for _ in range(5):
            z = rng.normal(size=2) * 3
            kf.predict()
            kf.update(z)
            x, P = kalman_predict(x, P, F, Q)
            x, P, ll = kalman_update(x, P, torch.tensor(z)[None], H_POS, R)
            np.testing.assert_allclose(x[0].numpy(), kf.x[:, 0], rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(P[0].numpy(), kf.P, rtol=1e-10, atol=1e-10)
            assert math.isclose(float(ll[0]), kf.log_likelihood, rel_tol=1e-10)

    def test_ekf_with_linear_h_equals_kf(self):
        gen = torch.Generator().manual_seed(4)
        x = torch.randn(3, 4, generator=gen, dtype=torch.float64)
        P = random_spd(gen, (3,), 4)
        z = torch.randn(3, 2, generator=gen, dtype=torch.float64)
        a = kalman_update(x, P, z, H_POS, torch.eye(2))
        b = ekf_update(x, P, z, x @ H_POS.T, H_POS.expand(3, 2, 4), torch.eye(2))
        for u, v in zip(a, b):
            torch.testing.assert_close(u, v, rtol=1e-12, atol=1e-12)

    def test_ekf_range_rate_matches_loop(self):
        # GMTI measurement [x, y, range-rate] (PD eq. 24.17-24.18), sensor at (xc, yc)
        xc, yc = -5000.0, -6000.0
        gen = torch.Generator().manual_seed(5)
        x = torch.randn(4, 4, generator=gen, dtype=torch.float64) * torch.tensor([100, 10, 100, 10])
        P = random_spd(gen, (4,), 4)
        R = torch.diag(torch.tensor([400.0, 400.0, 1.0], dtype=torch.float64))

        def h_and_jac(s):
            px, vx, py, vy = s
            dx, dy = px - xc, py - yc
            rho = math.hypot(dx, dy)
            rr = (dx * vx + dy * vy) / rho
            J = np.zeros((3, 4))
            J[0, 0] = J[1, 2] = 1.0
            J[2, 0] = vx / rho - dx * rr / rho**2
            J[2, 2] = vy / rho - dy * rr / rho**2
            J[2, 1], J[2, 3] = dx / rho, dy / rho
            return np.array([px, py, rr]), J

        hs, Js = zip(*(h_and_jac(s) for s in x.numpy()))
        hx, J = torch.tensor(np.array(hs)), torch.tensor(np.array(Js))
        z = hx + torch.randn(4, 3, generator=gen, dtype=torch.float64)
        xu, Pu, _ = ekf_update(x, P, z, hx, J, R)
        for i in range(4):
            S = Js[i] @ P[i].numpy() @ Js[i].T + R.numpy()
            K = P[i].numpy() @ Js[i].T @ np.linalg.inv(S)
            np.testing.assert_allclose(
                xu[i].numpy(), x[i].numpy() + K @ (z[i].numpy() - hs[i]), rtol=1e-9
            )
            A = np.eye(4) - K @ Js[i]
            np.testing.assert_allclose(
                Pu[i].numpy(), A @ P[i].numpy() @ A.T + K @ R.numpy() @ K.T, rtol=1e-9, atol=1e-9
            )

    def test_broadcast_modes_and_empty_batch(self):
        x = torch.zeros(0, 3, 4, dtype=torch.float64)
        P = torch.eye(4, dtype=torch.float64).expand(0, 3, 4, 4)
        xu, Pu, ll = kalman_update(x, P, torch.zeros(0, 1, 2), H_POS, torch.eye(2))
        assert xu.shape == (0, 3, 4) and Pu.shape == (0, 3, 4, 4) and ll.shape == (0, 3)

    def test_errors(self):
        with pytest.raises(ValueError, match="`z`"):
            kalman_update(torch.zeros(2, 4), torch.eye(4), torch.zeros(2, 3), H_POS, torch.eye(2))
        with pytest.raises(ValueError, match="`P`"):
            kalman_predict(torch.zeros(2, 4), torch.eye(3), torch.eye(4), torch.eye(4))
        with pytest.raises(ValueError, match="`x`"):
            kalman_predict(
                torch.tensor([0.0, float("nan"), 0, 0]), torch.eye(4), torch.eye(4), torch.eye(4)
            )
        with pytest.raises(TypeError, match="`x`"):
            kalman_predict("abc", torch.eye(4), torch.eye(4), torch.eye(4))
        with pytest.raises(ValueError, match="`R`"):
            kalman_update(torch.zeros(4), torch.zeros(4, 4), torch.zeros(2), H_POS, -torch.eye(2))


class TestLikelihoodAndGate:
    def test_log_likelihood_matches_scipy(self):
        from scipy.stats import multivariate_normal

        gen = torch.Generator().manual_seed(6)
        S = random_spd(gen, (6,), 3)
        nu = torch.randn(6, 3, generator=gen, dtype=torch.float64)
        ll = gaussian_log_likelihood(nu, S)
        for i in range(6):
            assert math.isclose(
                float(ll[i]),
                multivariate_normal(np.zeros(3), S[i].numpy()).logpdf(nu[i].numpy()),
                rel_tol=1e-11,
            )

    def test_gate_tracks_by_measurements(self):
        gen = torch.Generator().manual_seed(7)
        zp = torch.randn(4, 2, generator=gen, dtype=torch.float64) * 5
        S = random_spd(gen, (4,), 2)
        z = torch.randn(6, 2, generator=gen, dtype=torch.float64) * 5
        d2 = mahalanobis2(z[None] - zp[:, None], S[:, None])
        inside = gate(z[None] - zp[:, None], S[:, None], 4.0)
        assert d2.shape == inside.shape == (4, 6)
        for t in range(4):
            for j in range(6):
                nu = (z[j] - zp[t]).numpy()
                ref = nu @ np.linalg.solve(S[t].numpy(), nu)
                assert math.isclose(float(d2[t, j]), ref, rel_tol=1e-11)
                assert bool(inside[t, j]) == (ref <= 4.0)
        with pytest.raises(ValueError, match="`threshold`"):
            gate(z, torch.eye(2), 0.0)
        with pytest.raises(ValueError, match="`S`"):
            mahalanobis2(z, -torch.eye(2))


def test_as_float64_reads_python_floats_in_float64():
    """Python floats are read in float64, not through float32 (0.002 stays 0.002)."""
    from hocnet.tracking.kalman import as_float64

    assert as_float64("x", 0.002).item() == 0.002
    assert as_float64("x", [0.002, 1e-9]).tolist() == [0.002, 1e-9]
    assert as_float64("x", [[1, 2], [3, 4]]).dtype == torch.float64

import math

import numpy as np
import pytest
import torch
from scipy.stats import norm

from hocnet.tracking.sensors import (
    GMTISensor,
    VideoSensor,
    check_measurements,
    gmti_aekf_matrix,
    gmti_jacobian,
    gmti_measure,
    gmti_merge_unresolved,
    gmti_report_to_tcf,
    gmti_resolution_cells,
    gmti_resolution_groups,
    gmti_tcf_to_report,
    gmti_unresolved,
    make_sensor,
)

SENSOR = (-50000.0, -60000.0, 4000.0)  # the chapter's GMTI (24.6.1)


def random_states(rng, n):
    x = rng.uniform(-6000, 6000, size=(n, 4))
    x[:, [1, 3]] = rng.normal(size=(n, 2)) * 15
    return x


def loop_h(x, pos):
    dx, dy = x[0] - pos[0], x[2] - pos[1]
    rho = math.sqrt(dx * dx + dy * dy + pos[2] ** 2)
    return np.array([x[0], x[2], (dx * x[1] + dy * x[3]) / rho])


@pytest.mark.parametrize("pos", [SENSOR, (100.0, -200.0, 0.0)])
def test_gmti_measure_and_jacobian_against_finite_differences(pos):
    rng = np.random.default_rng(0)
    x = random_states(rng, 10)
    z = gmti_measure(torch.tensor(x), torch.tensor(pos))
    J = gmti_jacobian(torch.tensor(x), torch.tensor(pos))
    for k in range(10):
        np.testing.assert_allclose(z[k].numpy(), loop_h(x[k], pos), rtol=1e-12)
        fd = np.zeros((3, 4))
        for j in range(4):
            e = np.zeros(4)
            e[j] = 1e-3
            fd[:, j] = (loop_h(x[k] + e, pos) - loop_h(x[k] - e, pos)) / 2e-3
        np.testing.assert_allclose(J[k].numpy(), fd, rtol=1e-6, atol=1e-9)
        # the AEKF matrix (24.20): velocity partials of the EKF, no position partials, and
        # H(x) x = h(x) exactly (24.19 without noise)
        Ha = gmti_aekf_matrix(torch.tensor(x[k]), torch.tensor(pos)).numpy()
        np.testing.assert_allclose(Ha[2, [1, 3]], fd[2, [1, 3]], rtol=1e-6)
        assert Ha[2, 0] == 0.0 and Ha[2, 2] == 0.0
        np.testing.assert_allclose(Ha[:2], [[1, 0, 0, 0], [0, 0, 1, 0]])
        np.testing.assert_allclose(Ha @ x[k], loop_h(x[k], pos), rtol=1e-12)


def test_polar_report_conversion_and_covariance():
    rng = np.random.default_rng(1)
    x = random_states(rng, 6)
    pos = torch.tensor(SENSOR)
    rep = gmti_tcf_to_report(torch.tensor(x), pos)
    z, R = gmti_report_to_tcf(rep, pos, 20.0, 0.0008, 1.0)
    np.testing.assert_allclose(z.numpy(), gmti_measure(torch.tensor(x), pos).numpy(), atol=1e-6)

    def to_xy(rho, az):
        g = math.sqrt(rho * rho - SENSOR[2] ** 2)
        return np.array([SENSOR[0] + g * math.cos(az), SENSOR[1] + g * math.sin(az)])

    for k in range(6):
        rho, az = float(rep[k, 0]), float(rep[k, 1])
        J = np.column_stack(
            [
                (to_xy(rho + 1e-3, az) - to_xy(rho - 1e-3, az)) / 2e-3,
                (to_xy(rho, az + 1e-9) - to_xy(rho, az - 1e-9)) / 2e-9,
            ]
        )
        Rxy = J @ np.diag([20.0**2, 0.0008**2]) @ J.T
        np.testing.assert_allclose(R[k, :2, :2].numpy(), Rxy, rtol=1e-5)
        assert float(R[k, 2, 2]) == 1.0 and float(R[k, 0, 2]) == 0.0
    # the cross-range deviation is about ground range times the azimuth deviation (~62 m here)
    s = GMTISensor(SENSOR)
    R0 = s.covariance(torch.tensor([[0.0, 0.0, 3.0]]))[0, :2, :2].numpy()
    ev = np.sqrt(np.linalg.eigvalsh(R0))
    g = math.hypot(50000, 60000)
    assert ev[1] == pytest.approx(g * 0.0008, rel=1e-3)
    assert ev[0] == pytest.approx(20.0 * math.hypot(g, 4000) / g, rel=1e-3)


def test_gmti_linearize_and_mdv():
    s = GMTISensor(SENSOR, pd=0.9, mdv=1.0)
    x = torch.tensor([[1000.0, 10.0, 2000.0, -3.0], [0.0, 0.3, 0.0, 0.2]], dtype=torch.float64)
    z = s.measure(x) + torch.tensor([30.0, -20.0, 0.5], dtype=torch.float64)
    hx, H, R = s.linearize(x, z)
    torch.testing.assert_close(H, gmti_aekf_matrix(z[:, :2], torch.tensor(SENSOR), ground=True))
    torch.testing.assert_close(hx, (H @ x.unsqueeze(-1)).squeeze(-1))
    hx_p, _, _ = s.linearize(x, z, reference="prediction")
    torch.testing.assert_close(hx_p, s.measure(x))
    assert R.shape == (2, 3, 3)
    # hard notch
    rr = s.measure(x)[:, 2]
    assert s.detection_probability(x).tolist() == [0.9 if abs(v) >= 1 else 0.0 for v in rr]
    # expected PD against the Gaussian formula and against sampling
    rng = np.random.default_rng(2)
    P = torch.diag(torch.tensor([400.0, 1.0, 400.0, 1.0], dtype=torch.float64)).expand(2, 4, 4)
    pe = s.expected_detection_probability(x, P)
    for k in range(2):
        h3 = gmti_aekf_matrix(x[k], torch.tensor(SENSOR), ground=True)[2].numpy()
        m, sd = float(h3 @ x[k].numpy()), math.sqrt(float(h3 @ P[k].numpy() @ h3))
        ref = 0.9 * (1 - (norm.cdf((1 - m) / sd) - norm.cdf((-1 - m) / sd)))
        assert float(pe[k]) == pytest.approx(ref, abs=1e-12)
        samples = rng.multivariate_normal(x[k].numpy(), P[k].numpy(), size=20000)
        mc = float(s.detection_probability(torch.tensor(samples)).mean())
        assert float(pe[k]) == pytest.approx(mc, abs=0.02)


def test_video_and_factory_and_errors():
    v = make_sensor("video", sigma=10.0, pd=0.9)
    hx, H, R = v.linearize(torch.tensor([[1.0, 2.0, 3.0, 4.0]]), torch.tensor([[0.0, 0.0]]))
    assert hx.tolist() == [[1.0, 3.0]]
    assert H.tolist() == [[1, 0, 0, 0], [0, 0, 1, 0]]
    assert R[0].tolist() == [[100.0, 0.0], [0.0, 100.0]]
    assert isinstance(make_sensor("gmti"), GMTISensor)
    assert make_sensor("ugs").name == "ugs" and isinstance(make_sensor("ugs"), VideoSensor)
    with pytest.raises(ValueError, match="`sensor`: expected one of 'gmti', 'video', 'ugs'"):
        make_sensor("lidar")
    with pytest.raises(ValueError, match=r"`z`: expected finite measurements, got NaN/inf"):
        check_measurements("z", [[1.0, float("nan")]], 2)
    with pytest.raises(ValueError, match=r"`z`: expected finite"):
        v.linearize(torch.zeros(4), torch.tensor([float("inf"), 0.0]))
    with pytest.raises(ValueError, match=r"`z`: expected measurements of shape \(\.\.\., 3\)"):
        GMTISensor(SENSOR).linearize(torch.zeros(4), torch.zeros(2))
    with pytest.raises(ValueError, match="`report`"):
        gmti_report_to_tcf(torch.tensor([100.0, 0.0, 0.0]), torch.tensor(SENSOR), 1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="`pd`"):
        VideoSensor(pd=1.5)


def test_gmti_range_rate_geometry_matches_simulator():
    """Default ``range_rate="ground"`` is 24.18 as printed and as the scenario simulates it."""
    from hocnet.tracking.scenario import gmti_range_rate

    rng = np.random.default_rng(5)
    x = torch.tensor(random_states(rng, 8))
    pos, vel = x[:, [0, 2]].numpy(), x[:, [1, 3]].numpy()
    want = gmti_range_rate(SENSOR[:2], pos, vel)
    got = GMTISensor(SENSOR).measure(x)[:, 2].numpy()
    np.testing.assert_allclose(got, want, rtol=1e-12)
    slant = GMTISensor(SENSOR, range_rate="slant").measure(x)[:, 2].numpy()
    g = np.linalg.norm(pos - np.array(SENSOR[:2]), axis=-1)
    np.testing.assert_allclose(slant, want * g / np.sqrt(g * g + SENSOR[2] ** 2), rtol=1e-12)
    assert np.abs(slant - want).max() > 1e-4  # the two readings differ
    with pytest.raises(ValueError, match="`range_rate`"):
        GMTISensor(SENSOR, range_rate="oblique")


def test_video_coverage_and_stop_detectability():
    from hocnet.tracking.sensors import disc_coverage, rectangle_coverage, stop_detectable

    x = torch.tensor([[0.0, 1, 0, 0], [900.0, 0, 0, 0], [1500.0, 0, 0, 0]], dtype=torch.float64)
    assert VideoSensor(pd=0.9).detection_probability(x).tolist() == [0.9, 0.9, 0.9]
    ugs = VideoSensor(pd=0.8, name="ugs", coverage=disc_coverage((0.0, 0.0), 1000.0))
    assert ugs.detection_probability(x).tolist() == [0.8, 0.8, 0.0]
    assert ugs.expected_detection_probability(x, torch.eye(4).expand(3, 4, 4)).tolist() == [
        0.8,
        0.8,
        0.0,
    ]
    uav = VideoSensor(
        coverage=rectangle_coverage([[-10.0, -10.0, 10.0, 10.0], [1400, -1, 1600, 1]])
    )
    assert uav.detection_probability(x).tolist() == [0.9, 0.0, 0.9]
    uav2 = VideoSensor(coverage=lambda p: p[..., 0] > 1000)
    assert uav2.detection_probability(x).tolist() == [0.0, 0.0, 0.9]
    with pytest.raises(TypeError, match="`coverage`"):
        VideoSensor(coverage=3.0)
    assert stop_detectable(VideoSensor()) and not stop_detectable(GMTISensor(SENSOR))
    assert stop_detectable(GMTISensor(SENSOR, mdv=0.0))


# ---- GMTI resolution (our addition) ---------------------------------------------------------

CELLS = (50.0, 0.002, 2.5)


def loop_unresolved(rep, cells):
    """Straight from the hard-cell definition, one pair at a time."""
    n = len(rep)
    out = np.zeros((n, n), dtype=bool)
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            daz = (rep[i][1] - rep[j][1] + math.pi) % (2 * math.pi) - math.pi
            out[i, j] = (
                abs(rep[i][0] - rep[j][0]) < cells[0]
                and abs(daz) < cells[1]
                and abs(rep[i][2] - rep[j][2]) < cells[2]
            )
    return out


def loop_groups(rep, cells):
    """Union-find over the pairwise relation; label = smallest index of the group."""
    close = loop_unresolved(rep, cells)
    parent = list(range(len(rep)))

    def find(i):
        while parent[i] != i:
            i = parent[i]
        return i

    for i in range(len(rep)):
        for j in range(len(rep)):
            if close[i, j]:
                a, b = find(i), find(j)
                parent[max(a, b)] = min(a, b)
    return [find(i) for i in range(len(rep))]


def clustered_reports(rng, n):
    """Reports in a few clumps so that some pairs and chains are unresolved."""
    centres = rng.uniform([70000.0, -0.2, -10.0], [80000.0, 0.2, 10.0], size=(3, 3))
    rep = centres[rng.integers(3, size=n)] + rng.normal(size=(n, 3)) * (40.0, 0.0015, 2.0)
    return rep


@pytest.mark.parametrize("seed", range(5))
def test_unresolved_and_groups_against_loops(seed):
    rng = np.random.default_rng(seed)
    rep = clustered_reports(rng, 12)
    got = gmti_unresolved(torch.tensor(rep), CELLS).numpy()
    want = loop_unresolved(rep, CELLS)
    np.testing.assert_array_equal(got, want)
    assert want.any() and not want.all()  # the case is not trivial
    groups = gmti_resolution_groups(torch.tensor(rep), CELLS).tolist()
    assert groups == loop_groups(rep, CELLS)


def test_groups_transitive_batched_and_empty():
    chain = torch.tensor([[1000.0, 0.0, 5.0], [1040.0, 0.0, 5.0], [1080.0, 0.0, 5.0]])
    assert gmti_unresolved(chain, CELLS)[0, 2].item() is False  # 80 m: resolved pairwise
    assert gmti_resolution_groups(chain, CELLS).tolist() == [0, 0, 0]  # ... but chained
    batch = torch.stack([chain, chain * torch.tensor([1.0, 1.0, 0.0]) + torch.tensor([0, 0, 1.0])])
    batch[1, 1, 2] = 9.0  # range-rate 8 m/s apart: resolved by Doppler
    assert gmti_resolution_groups(batch, CELLS).tolist() == [[0, 0, 0], [0, 1, 2]]
    assert gmti_resolution_groups(torch.zeros(0, 3), CELLS).shape == (0,)
    assert gmti_resolution_groups(torch.zeros(2, 0, 3), CELLS).shape == (2, 0)
    merged, groups, dom = gmti_merge_unresolved(torch.zeros(0, 3), CELLS)
    assert merged.shape == (0, 3) and groups.shape == (0,) and dom.shape == (0,)
    # azimuth wraps at +-pi
    wrap = torch.tensor([[1000.0, math.pi - 0.0005, 5.0], [1000.0, -math.pi + 0.0005, 5.0]])
    assert gmti_resolution_groups(wrap, CELLS).tolist() == [0, 0]
    m = gmti_merge_unresolved(wrap, CELLS)[0]
    assert abs(abs(m[0, 1].item()) - math.pi) < 1e-12


@pytest.mark.parametrize("seed", range(3))
def test_merge_is_power_weighted_centroid(seed):
    rng = np.random.default_rng(10 + seed)
    rep = clustered_reports(rng, 10)
    w = rng.uniform(0.5, 3.0, size=10)
    labels = loop_groups(rep, CELLS)
    for weights in (None, w):
        merged, groups, dom = gmti_merge_unresolved(torch.tensor(rep), CELLS, weights)
        ww = np.ones(10) if weights is None else w
        firsts = sorted(set(labels))
        assert merged.shape == (len(firsts), 3)
        for gi, f in enumerate(firsts):
            members = [i for i in range(10) if labels[i] == f]
            assert [i for i in range(10) if groups[i] == gi] == members
            want = (rep[members] * ww[members, None]).sum(0) / ww[members].sum()
            np.testing.assert_allclose(merged[gi].numpy(), want, rtol=1e-12, atol=1e-12)
            assert dom[gi].item() == members[int(np.argmax(ww[members]))]


def test_zero_cells_resolve_everything_and_bad_input():
    rep = torch.tensor([[1000.0, 0.0, 5.0], [1000.0, 0.0, 5.0]])
    merged, groups, _ = gmti_merge_unresolved(rep, (0.0, 0.0, 0.0))
    assert groups.tolist() == [0, 1] and torch.equal(merged, rep.double())
    assert gmti_merge_unresolved(rep, CELLS)[1].tolist() == [0, 0]
    with pytest.raises(ValueError, match="`cells`"):
        gmti_unresolved(rep, (50.0, -1.0, 2.0))
    with pytest.raises(ValueError, match="`cells`"):
        gmti_unresolved(rep, (50.0, 1.0))
    with pytest.raises(ValueError, match="`report`"):
        gmti_unresolved(torch.tensor([1.0, 2.0, 3.0]), CELLS)
    with pytest.raises(ValueError, match="`report`"):
        gmti_unresolved(torch.tensor([[1.0, float("nan"), 3.0]]), CELLS)
    with pytest.raises(ValueError, match="`weights`"):
        gmti_merge_unresolved(rep, CELLS, [1.0, 0.0])
    with pytest.raises(ValueError, match="`weights`"):
        gmti_merge_unresolved(rep, CELLS, [1.0])
    with pytest.raises(ValueError, match="`report`"):
        gmti_merge_unresolved(rep[None], CELLS)
    with pytest.raises(ValueError, match="`sigma_range`"):
        gmti_resolution_cells(-1.0, 0.0008, 1.0)
    assert gmti_resolution_cells(20.0, 0.0008, 1.0, k=3.0) == pytest.approx((60.0, 0.0024, 3.0))


def test_sensor_resolve():
    x = torch.tensor(
        [[0.0, 10.0, 0.0, 10.0], [30.0, 10.0, 20.0, 10.0], [0.0, -10.0, 0.0, -10.0]],
        dtype=torch.float64,
    )
    off = GMTISensor(SENSOR)
    merged, groups, _ = off.resolve(x)
    assert groups.tolist() == [0, 1, 2]
    want = torch.cat([gmti_tcf_to_report(x, torch.tensor(SENSOR))[:, :2], off.measure(x)[:, 2:]], 1)
    torch.testing.assert_close(merged, want, rtol=1e-12, atol=1e-9)
    on = GMTISensor(SENSOR, resolution=gmti_resolution_cells(20.0, 0.0008, 1.0))
    assert on.resolution == (50.0, 0.002, 2.5)
    merged, groups, _ = on.resolve(x)
    assert groups.tolist() == [0, 0, 1]  # 36 m apart with one velocity; the third drives away
    torch.testing.assert_close(merged[0], want[:2].mean(0), rtol=1e-12, atol=1e-9)
    with pytest.raises(ValueError, match="`cells`"):
        GMTISensor(SENSOR, resolution=(1.0, 2.0))
    with pytest.raises(ValueError, match="`x`"):
        on.resolve(x[None])

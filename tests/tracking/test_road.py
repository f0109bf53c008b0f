import heapq
import itertools
import math

import numpy as np
import pytest
import torch
from scipy.stats import norm

from hocnet.tracking.kalman import constant_velocity, cv_gamma
from hocnet.tracking.road import (
    RoadNetwork,
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


def test_on_segment_probability_zero_variance_is_the_indicator():
    """Finding 2: one documented behaviour at zero along-road variance (it raised before; the
    VS-IMM's copy used the indicator): the limit sigma -> 0, 1 inside [0, l] and 0 outside."""
    from hocnet.tracking.road import on_segment_probability_from_moments

    p0, p1 = torch.zeros(2), torch.tensor([100.0, 0.0])
    x = torch.tensor([[50.0, 0, 0, 0], [150.0, 0, 0, 0], [-1.0, 0, 0, 0]], dtype=torch.float64)
    P = torch.diag(torch.tensor([0.0, 1.0, 4.0, 1.0], dtype=torch.float64)).expand(3, 4, 4)
    assert on_segment_probability(x, P, p0, p1).tolist() == [1.0, 0.0, 0.0]
    # continuity: a tiny variance gives the same values
    tiny = on_segment_probability(x, P + 1e-12 * torch.eye(4), p0, p1)
    np.testing.assert_allclose(tiny.numpy(), [1.0, 0.0, 0.0], atol=1e-12)
    along = torch.tensor([50.0, 150.0, -1.0], dtype=torch.float64)
    got = on_segment_probability_from_moments(along, torch.zeros(3), torch.tensor(100.0))
    assert got.tolist() == [1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="`P`: expected a non-negative position variance"):
        on_segment_probability(x, -P - torch.eye(4), p0, p1)


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


# ------------------------------------------------------------------------------------------
# RoadNetwork
# ------------------------------------------------------------------------------------------


def feature(coords, **props):
    return {
        "type": "Feature",
        "properties": props,
        "geometry": {"type": "LineString", "coordinates": coords},
    }


def sample_network_dict():
    """A highway with a bend, a byway T-junction, a chain of two features and a loop."""
    return {
        "type": "FeatureCollection",
        "features": [
            feature([[0, 0], [1000, 0], [2000, 500]], kind="highway"),  # 0
            feature([[2000, 500], [3000, 500]], kind="highway"),  # 1 joins 0 end to end
            feature([[1000, 0], [1000, 800], [1400, 1200]], kind="byway"),  # 2 T at (1000, 0)
            feature([[1400, 1200], [3000, 500]], kind="byway"),  # 3 closes a loop at (3000, 500)
            feature([[3000, 500], [3500, 500]], kind="highway"),  # 4 a stub
        ],
    }


def test_network_topology():
    net = RoadNetwork.from_geojson(sample_network_dict())
    assert net.num_segments == 7
    assert net.nodes.shape == (7, 2)
    # junctions: (1000, 0) (degree 3) and (3000, 500) (degree 3)
    junction_points = sorted(tuple(p) for p in net.nodes[net.junctions].tolist())
    assert junction_points == [(1000.0, 0.0), (3000.0, 500.0)]
    ends = sorted(tuple(p) for p in net.nodes[net.road_ends].tolist())
    assert ends == [(0.0, 0.0), (3500.0, 500.0)]
    # sections cut at junctions and ends only: features 0 (second half) and 1 form one section
    sec_of = {}
    for s in range(net.num_segments):
        key = (tuple(net.p0[s].tolist()), tuple(net.p1[s].tolist()))
        sec_of[key] = int(net.segment_section[s])
    assert sec_of[((1000.0, 0.0), (2000.0, 500.0))] == sec_of[((2000.0, 500.0), (3000.0, 500.0))]
    assert net.num_sections == 4
    for chain in net.sections:  # consecutive segments of a section share a node
        for a, b in itertools.pairwise(chain):
            assert set(net.segment_nodes[a].tolist()) & set(net.segment_nodes[b].tolist())
    # the byway features 2 and 3 meet at a degree-2 node: one section of 3 segments
    assert sorted(len(c) for c in net.sections) == [1, 1, 2, 3]
    # neighbours at the T junction
    j = int(net.junctions[0])
    assert len(net.node_segments(j)) == 3
    assert len(net.junction_sections(j)) == 3
    s0 = int(net.locate(torch.tensor([500.0, 0.0])).segment)
    assert len(net.segment_neighbours(s0)) == 2
    # section properties follow the first segment's feature
    assert {p["kind"] for p in net.section_properties} == {"highway", "byway"}


def test_network_node_merging_and_roundtrip():
    d = sample_network_dict()
    d["features"][1]["geometry"]["coordinates"][0] = [2000.0 + 1e-8, 500.0]
    net = RoadNetwork.from_geojson(d, tolerance=1e-6)
    assert net.nodes.shape[0] == 7
    back = RoadNetwork.from_geojson(net.to_geojson())
    assert back.num_segments == net.num_segments and back.num_sections == net.num_sections
    torch.testing.assert_close(back.length.sort().values, net.length.sort().values)
    # MultiLineString and a bare geometry
    multi = {"type": "MultiLineString", "coordinates": [[[0, 0], [1, 0]], [[1, 0], [1, 1]]]}
    assert RoadNetwork.from_geojson(multi).num_segments == 2
    # polylines as one array (F, K, 2)
    arr = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [1.0, 1.0]]])
    assert RoadNetwork(arr).num_segments == 2


def loop_locate(net, pos, allowed=None):
    best = None
    for s in range(net.num_segments):
        if allowed is not None and not allowed[s]:
            continue
        p0, p1 = net.p0[s].numpy(), net.p1[s].numpy()
        d = p1 - p0
        length = float(np.hypot(*d))
        u = d / length
        t = min(max(float(u @ (pos - p0)), 0.0), length)
        foot = p0 + t * u
        dist = float(np.hypot(*(pos - foot)))
        if best is None or dist < best[2] - 1e-12:
            best = (s, t, dist, foot)
    return best


def test_locate_matches_loop():
    net = RoadNetwork.from_geojson(sample_network_dict())
    rng = np.random.default_rng(4)
    pos = rng.uniform([-200, -300], [3700, 1400], size=(40, 2))
    loc = net.locate(torch.tensor(pos))
    allowed = (net.segment_section == 1).numpy()
    loc1 = net.locate(torch.tensor(pos), allowed=torch.tensor(allowed))
    for k in range(40):
        s, t, dist, foot = loop_locate(net, pos[k])
        assert int(loc.segment[k]) == s
        assert float(loc.abscissa[k]) == pytest.approx(t, abs=1e-9)
        assert float(loc.distance[k]) == pytest.approx(dist, abs=1e-9)
        np.testing.assert_allclose(loc.point[k].numpy(), foot, atol=1e-9)
        # section abscissa: walk the section's chain from its first node
        sec = int(loc.section[k])
        acc = 0.0
        for seg in net.sections[sec]:
            if seg == s:
                fwd = bool(net.section_forward[seg])
                acc += t if fwd else float(net.length[seg]) - t
                break
            acc += float(net.length[seg])
        assert float(loc.section_abscissa[k]) == pytest.approx(acc, abs=1e-9)
        s1, _, d1, _ = loop_locate(net, pos[k], allowed)
        assert int(loc1.segment[k]) == s1 and float(loc1.distance[k]) == pytest.approx(d1)
    # a state (..., 4) is accepted; batch shapes are kept
    x = torch.zeros(2, 3, 4, dtype=torch.float64)
    assert net.locate(x).segment.shape == (2, 3)


def loop_travel(net, seg, a, direction):
    """Dijkstra from the point (plain heap over nodes), then the distance to each segment.

    With a direction the own segment is removed from the graph (no U-turn back over it).
    """
    V = net.nodes.shape[0]
    adj = [[] for _ in range(V)]
    for s in range(net.num_segments):
        if direction != 0 and s == seg:
            continue
        u, v = net.segment_nodes[s].tolist()
        w = float(net.length[s])
        adj[u].append((v, w))
        adj[v].append((u, w))
    start, end = net.segment_nodes[seg].tolist()
    dist = [math.inf] * V
    heap = []
    if direction <= 0:
        heap.append((a, start))
    if direction >= 0:
        heap.append((float(net.length[seg]) - a, end))
    heapq.heapify(heap)
    while heap:
        d, v = heapq.heappop(heap)
        if d >= dist[v]:
            continue
        dist[v] = d
        for w_node, w in adj[v]:
            if d + w < dist[w_node]:
                heapq.heappush(heap, (d + w, w_node))
    out = []
    for s in range(net.num_segments):
        u, v = net.segment_nodes[s].tolist()
        out.append(0.0 if s == seg else min(dist[u], dist[v]))
    return np.array(out)


def test_travel_distance_and_reachable_match_loop():
    net = RoadNetwork.from_geojson(sample_network_dict())
    rng = np.random.default_rng(5)
    segs = rng.integers(0, net.num_segments, size=12)
    ab = rng.uniform(0, 1, size=12) * net.length[segs].numpy()
    dirs = rng.integers(-1, 2, size=12)
    d = net.travel_distance(torch.tensor(segs), torch.tensor(ab), direction=torch.tensor(dirs))
    for k in range(12):
        np.testing.assert_allclose(
            d[k].numpy(), loop_travel(net, int(segs[k]), ab[k], int(dirs[k])), rtol=1e-12
        )
    reach = net.reachable(torch.tensor(segs), torch.tensor(ab), 700.0)
    assert torch.equal(reach, net.travel_distance(torch.tensor(segs), torch.tensor(ab)) <= 700.0)
    assert bool(reach[torch.arange(12), torch.tensor(segs)].all())


def test_network_errors():
    with pytest.raises(ValueError, match="empty network"):
        RoadNetwork([])
    with pytest.raises(ValueError, match="empty network"):
        RoadNetwork.from_geojson({"type": "FeatureCollection", "features": []})
    with pytest.raises(ValueError, match="NaN/inf in feature 1 at vertex 0"):
        RoadNetwork([[[0, 0], [1, 0]], [[float("nan"), 0], [1, 0]]])
    with pytest.raises(ValueError, match="zero-length segment in feature 0 between vertices 1"):
        RoadNetwork([[[0, 0], [1, 0], [1, 0], [2, 0]]])
    with pytest.raises(ValueError, match="at least 2 vertices in feature 0"):
        RoadNetwork([[[0, 0]]])
    with pytest.raises(ValueError, match="2 disconnected parts"):
        RoadNetwork([[[0, 0], [1, 0]], [[5, 5], [6, 5]]])
    net = RoadNetwork([[[0, 0], [1, 0]], [[5, 5], [6, 5]]], require_connected=False)
    assert bool(torch.isinf(net.travel_distance(0, 0.5)[1]))
    with pytest.raises(ValueError, match="Point"):
        RoadNetwork.from_geojson(
            {"type": "Feature", "geometry": {"type": "Point", "coordinates": [0, 0]}}
        )
    with pytest.raises(ValueError, match="`segment`"):
        net.constraint(7)
    with pytest.raises(ValueError, match="`allowed`"):
        net.locate(torch.zeros(2), allowed=torch.zeros(2, dtype=torch.bool))
    with pytest.raises(ValueError, match="`travel`"):
        net.reachable(0, 0.0, -1.0)

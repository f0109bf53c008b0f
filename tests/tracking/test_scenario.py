import dataclasses
import math

import numpy as np
import pytest

from hocnet.tracking.scenario import (
    _POINTS,
    GMTI_CLASSES,
    GMTI_RESOLUTION,
    PD_INTERACTIONS,
    PD_TARGETS,
    UAV_FOOTPRINTS,
    VIDEO_CLASSES,
    VIDEO_TO_GMTI,
    GMTIConfig,
    TargetSpec,
    UGSConfig,
    VideoConfig,
    footprint_at,
    gmti_range_rate,
    network_segments,
    out_of_sequence,
    pd_ground_truth,
    pd_road_network,
    pd_scenario,
    pd_targets,
    plot_scenario,
    simulate_gmti,
    simulate_ugs,
    simulate_video,
    ugs_aspect,
)


@pytest.fixture(scope="module")
def truth():
    return pd_ground_truth()


@pytest.fixture(scope="module")
def runs():
    return [pd_scenario(seed=s) for s in range(4)]


def _at(tr, t):
    i = np.flatnonzero(np.abs(tr.times - t) < 1e-9)
    return None if not i.size else int(i[0])


def _distance(truth, a, b, t):
    ia, ib = _at(truth[a], t), _at(truth[b], t)
    return float(np.linalg.norm(truth[a].positions[ia] - truth[b].positions[ib]))


def _arc(tr):
    """Distance travelled since departure at each sample."""
    d = np.linalg.norm(np.diff(tr.positions, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(d)])


class TestNetwork:
    def test_geojson_like(self):
        net = pd_road_network()
        assert net["type"] == "FeatureCollection"
        ids = [f["properties"]["id"] for f in net["features"]]
        assert len(ids) == len(set(ids)) == 16
        for f in net["features"]:
            assert f["geometry"]["type"] == "LineString"
            assert f["properties"]["road_class"] in ("highway", "byway")
        assert sum(f["properties"]["road_class"] == "highway" for f in net["features"]) == 4

    def test_size_about_12_by_10_km(self):
        ends, _ = network_segments()
        xy = ends.reshape(-1, 2)
        assert xy[:, 0].max() - xy[:, 0].min() == pytest.approx(12_000)
        assert xy[:, 1].max() - xy[:, 1].min() == pytest.approx(10_000)

    def test_junctions_join_sections(self):
        net = pd_road_network()
        for j, n_sections in (("J1", 4), ("J2", 4), ("J3", 4), ("N1", 4), ("N2", 4), ("N3", 3)):
            touching = [f for f in net["features"] if j in f["properties"]["nodes"]]
            assert len(touching) == n_sections, j
            for f in touching:
                k = f["properties"]["nodes"].index(j)
                assert f["geometry"]["coordinates"][k] == list(_POINTS[j])

    def test_fresh_copy(self):
        a = pd_road_network()
        a["features"].clear()
        assert len(pd_road_network()["features"]) == 16

    def test_bad_network(self):
        with pytest.raises(ValueError, match="`network`"):
            network_segments({"type": "Feature"})
        bad = {"type": "FeatureCollection", "features": [{"geometry": {"type": "Point"}}]}
        with pytest.raises(ValueError, match="LineString"):
            network_segments(bad)


class TestClasses:
    def test_class_sets(self):
        assert len(GMTI_CLASSES) == 3
        assert len(VIDEO_CLASSES) == 8
        assert len(VIDEO_TO_GMTI) == 8
        # a wheeled vehicle covers six video classes ([PD] 24.6.3)
        assert sum(g == GMTI_CLASSES.index("wheeled vehicle") for g in VIDEO_TO_GMTI) == 6

    def test_target_types_of_fig_24_3(self):
        expected = {
            1: "civilian car",
            2: "military armoured car",
            3: "military armoured truck",
            4: "armoured wheeled vehicle",
            5: "civilian bus",
            6: "civilian car",
            7: "military armoured truck",
            8: "armoured wheeled vehicle",
            9: "civilian car",
            10: "civilian truck",
        }
        assert {s.target_id: VIDEO_CLASSES[s.video_class] for s in PD_TARGETS} == expected

    def test_confusion_rows(self):
        C = np.asarray(GMTIConfig().confusion)
        np.testing.assert_allclose(np.diag(C), [0.8, 0.7, 0.9])
        np.testing.assert_allclose(C.sum(1), 1.0)


class TestGroundTruth:
    def test_deterministic(self, truth):
        again = pd_ground_truth()
        for tid in truth:
            np.testing.assert_array_equal(truth[tid].positions, again[tid].positions)

    def test_one_second_grid_and_shapes(self, truth):
        for tr in truth.values():
            assert np.allclose(np.diff(tr.times), 1.0)
            n = tr.times.size
            assert tr.positions.shape == tr.velocities.shape == tr.heading.shape == (n, 2)
            assert tr.segment.shape == tr.stopped.shape == (n,)

    def test_on_road(self, truth):
        ends, _ = network_segments()
        for tr in truth.values():
            a, b = ends[tr.segment, 0], ends[tr.segment, 1]
            u = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
            rel = tr.positions - a
            across = rel[:, 0] * u[:, 1] - rel[:, 1] * u[:, 0]
            along = (rel * u).sum(1)
            seg_len = np.linalg.norm(b - a, axis=1)
            assert np.abs(across).max() < 1e-6
            assert (along > -1e-6).all() and (along < seg_len + 1e-6).all()
            # velocity along the road
            cross_v = tr.velocities[:, 0] * u[:, 1] - tr.velocities[:, 1] * u[:, 0]
            assert np.abs(cross_v).max() < 1e-9

    def test_velocity_matches_motion(self, truth):
        for tr in truth.values():
            step = np.linalg.norm(np.diff(tr.positions, axis=0), axis=1)
            mean_speed = 0.5 * (
                np.linalg.norm(tr.velocities[1:], axis=1)
                + np.linalg.norm(tr.velocities[:-1], axis=1)
            )
            # exact for a speed linear in time within a segment (also over a speed knot: the
            # knots sit on whole seconds or the speed is linear across them); at a corner the
            # chord is shorter than the distance travelled
            same = tr.segment[1:] == tr.segment[:-1]
            knot_free = np.abs(np.diff(np.linalg.norm(tr.velocities, axis=1), 2)) < 1e-9
            exact = same & np.concatenate([[True], knot_free]) & np.concatenate([knot_free, [True]])
            np.testing.assert_allclose(step[exact], mean_speed[exact], atol=1e-9)
            assert (step[~same] <= mean_speed[~same] + 1e-9).all()

    def test_stopped_means_zero_speed(self, truth):
        for tr in truth.values():
            np.testing.assert_array_equal(tr.stopped, np.linalg.norm(tr.velocities, axis=1) < 1e-9)

    def test_state_at(self, truth):
        tr = truth[3]
        s = tr.state_at(100.0)
        i = _at(tr, 100.0)
        np.testing.assert_allclose(s[[0, 2]], tr.positions[i])
        np.testing.assert_allclose(s[[1, 3]], tr.velocities[i])
        with pytest.raises(ValueError, match="`t`"):
            tr.state_at(-5.0)

    def test_bad_route(self):
        spec = TargetSpec(1, 0, ("H0", "J3"), 0.0, ((0, 10.0),))
        with pytest.raises(ValueError, match="`route`"):
            pd_ground_truth(targets=[spec])

    def test_bad_duration(self):
        with pytest.raises(ValueError, match="`duration`"):
            pd_ground_truth(duration=0.0)


class TestInteractions:
    def test_table_matches_truth(self, truth):
        """Each tabulated closest approach is the real minimum within +-30 s."""
        for it in PD_INTERACTIONS:
            if it.kind == "stop":
                continue
            window = np.arange(it.time - 30, it.time + 31)
            d = [_distance(truth, it.target, it.other, t) for t in window]
            k = int(np.argmin(d))
            assert window[k] == it.time, it
            assert d[k] == pytest.approx(it.distance, abs=0.06), it

    @pytest.mark.parametrize("it", [i for i in PD_INTERACTIONS if i.kind == "overtake"])
    def test_overtakes(self, truth, it):
        a, b = truth[it.target], truth[it.other]
        assert _distance(truth, it.target, it.other, it.time) < 5.0
        # same route from the same start: compare distances travelled
        sa, sb = _arc(a), _arc(b)
        before, after = it.time - 30, it.time + 30
        assert sa[_at(a, before)] < sb[_at(b, before)] - 50
        assert sa[_at(a, after)] > sb[_at(b, after)] + 50
        assert a.segment[_at(a, it.time)] == b.segment[_at(b, it.time)]

    @pytest.mark.parametrize("it", [i for i in PD_INTERACTIONS if i.kind == "crossing"])
    def test_crossings(self, truth, it):
        assert it.distance < 80.0
        assert _distance(truth, it.target, it.other, it.time) < 80.0
        j = np.asarray(_POINTS[it.where])
        for tid in (it.target, it.other):
            tr = truth[tid]
            assert np.linalg.norm(tr.positions[_at(tr, it.time)] - j) < 80.0
        # the crossing target comes from another road and leaves on another road
        a, b = truth[it.target], truth[it.other]
        for dt in (-60, 60):
            assert a.segment[_at(a, it.time + dt)] != b.segment[_at(b, it.time + dt)]

    def test_convoy_starts_together(self, truth):
        for tid in (2, 3, 4, 7):
            np.testing.assert_allclose(truth[tid].positions[0], _POINTS["H0"])
        starts = sorted(truth[t].times[0] for t in (2, 3, 4, 7))
        assert np.diff(starts).max() <= 10.0

    def test_target_2_ends_in_front(self, truth):
        t = 400.0
        s = {tid: _arc(truth[tid])[_at(truth[tid], t)] for tid in (2, 3, 7)}
        assert s[2] > s[3] > s[7]

    def test_target_1_passes_whole_convoy(self, truth):
        passed = {it.other for it in PD_INTERACTIONS if it.kind == "overtake" and it.target == 1}
        assert passed == {2, 3, 4, 7}

    def test_civilians_cross(self):
        crossers = {it.target for it in PD_INTERACTIONS if it.kind == "crossing"}
        crossed = {it.other for it in PD_INTERACTIONS if it.kind == "crossing"}
        assert crossers == {5, 6, 9, 10}
        assert crossed <= {1, 2, 3, 7}

    @pytest.mark.parametrize("it", [i for i in PD_INTERACTIONS if i.kind == "stop"])
    def test_stops(self, truth, it):
        tr = truth[it.target]
        i0, i1 = _at(tr, it.time), _at(tr, it.time + it.distance)
        assert tr.stopped[i0 : i1 + 1].all()
        assert np.ptp(tr.positions[i0 : i1 + 1], axis=0).max() == 0.0
        assert not tr.stopped[i0 - 1] and not tr.stopped[i1 + 1]


class TestDeterminism:
    def test_same_seed_same_reports(self):
        a, b = pd_scenario(seed=7), pd_scenario(seed=7)
        assert len(a.reports) == len(b.reports)
        for ra, rb in zip(a.reports, b.reports):
            assert (ra.time, ra.arrival, ra.sensor, ra.declared, ra.target_id) == (
                rb.time,
                rb.arrival,
                rb.sensor,
                rb.declared,
                rb.target_id,
            )
            np.testing.assert_array_equal(ra.z, rb.z)
            np.testing.assert_array_equal(ra.R, rb.R)

    def test_other_seed_other_reports(self):
        a, b = pd_scenario(seed=7), pd_scenario(seed=8)
        za = np.concatenate([r.z[:2] for r in a.reports[:50]])
        zb = np.concatenate([r.z[:2] for r in b.reports[:50]])
        assert za.shape != zb.shape or not np.array_equal(za, zb)

    def test_each_simulator_seeded(self, truth):
        for sim in (simulate_gmti, simulate_video, simulate_ugs):
            a, b = sim(truth, seed=3), sim(truth, seed=3)
            assert [r.z.tolist() for r in a] == [r.z.tolist() for r in b]

    def test_bad_seed(self):
        with pytest.raises(ValueError, match="`seed`"):
            pd_scenario(seed=-1)
        with pytest.raises(TypeError, match="`seed`"):
            pd_scenario(seed=1.5)


def _gmti_pairs(runs, cfg):
    """(detected?, |range-rate| >= MDV) for every target and scan of every run."""
    out = []
    for sc in runs:
        by_scan = {}
        for r in sc.reports:
            if r.kind == "gmti" and r.target_id is not None:
                by_scan.setdefault(r.time, set()).add(r.target_id)
        for t in np.arange(0.0, 1200.0 + 1e-9, cfg.period):
            for tid, tr in sc.truth.items():
                i = _at(tr, t)
                if i is None:
                    continue
                rr = gmti_range_rate(cfg.position[:2], tr.positions[i], tr.velocities[i])
                out.append((tid in by_scan.get(t, set()), abs(float(rr)) >= cfg.mdv, tid))
    return out


class TestGMTI:
    def test_detection_rate_is_pd(self, runs):
        pairs = _gmti_pairs(runs, GMTIConfig())
        visible = [d for d, v, _ in pairs if v]
        n = len(visible)
        rate = sum(visible) / n
        assert n > 3000
        assert abs(rate - 0.9) < 4 * math.sqrt(0.09 / n)

    def test_mdv_notch(self, runs):
        pairs = _gmti_pairs(runs, GMTIConfig())
        notched = [d for d, v, _ in pairs if not v]
        assert len(notched) > 50  # stops and departures exist
        assert not any(notched)

    def test_stopped_targets_unseen(self, runs):
        for sc in runs:
            for r in sc.reports:
                if r.kind == "gmti" and r.target_id is not None:
                    tr = sc.truth[r.target_id]
                    assert not tr.stopped[_at(tr, r.time)]

    def test_clutter_count_is_density_times_area(self, runs):
        cfg = GMTIConfig()
        x0, x1, y0, y1 = cfg.area
        n_scans = 121 * len(runs)
        expected = cfg.fa_density * (x1 - x0) * (y1 - y0) * n_scans
        fa = [r for sc in runs for r in sc.reports if r.kind == "gmti" and r.target_id is None]
        assert abs(len(fa) - expected) < 4 * math.sqrt(expected)
        z = np.array([r.z for r in fa])
        assert (z[:, 0] >= x0).all() and (z[:, 0] <= x1).all()
        assert (z[:, 1] >= y0).all() and (z[:, 1] <= y1).all()
        assert (np.abs(z[:, 2]) >= cfg.mdv).all()

    def test_no_clutter_at_zero_density(self, truth):
        reps = simulate_gmti(truth, GMTIConfig(fa_density=0.0), seed=0)
        assert all(r.target_id is not None for r in reps)

    def test_errors_match_covariance(self, runs):
        """Normalised errors: mean of e' R^-1 e is 3 (chi-square, 3 dof)."""
        cfg = GMTIConfig()
        nees = []
        for sc in runs:
            for r in sc.reports:
                if r.kind == "gmti" and r.target_id is not None:
                    tr = sc.truth[r.target_id]
                    i = _at(tr, r.time)
                    rr = gmti_range_rate(cfg.position[:2], tr.positions[i], tr.velocities[i])
                    e = r.z - np.array([*tr.positions[i], float(rr)])
                    nees.append(e @ np.linalg.solve(r.R, e))
        nees = np.array(nees)
        assert abs(nees.mean() - 3.0) < 4 * math.sqrt(6.0 / nees.size) + 0.05
        # cross-range deviation at ~75 km is about 0.0008 * 75 km = 60 m
        r0 = runs[0].reports[0]
        assert 40 < math.sqrt(np.linalg.eigvalsh(r0.R[:2, :2]).max()) < 80

    def test_type_reports_follow_confusion(self, runs):
        rep = [r for sc in runs for r in sc.reports if r.kind == "gmti" and r.target_id]
        right = np.mean([r.declared == 1 for r in rep])  # all ten are wheeled
        assert abs(right - 0.7) < 4 * math.sqrt(0.21 / len(rep))
        C = np.asarray(GMTIConfig().confusion)
        assert all(r.p_declared == C[r.declared, r.declared] for r in rep)

    def test_range_rate_formula(self):
        assert float(gmti_range_rate((0.0, 0.0), [100.0, 0.0], [0.0, 5.0])) == 0.0
        assert float(gmti_range_rate((0.0, 0.0), [100.0, 0.0], [-3.0, 5.0])) == -3.0


class TestVideo:
    def test_delay_and_footprint(self, runs):
        cfg = VideoConfig()
        for sc in runs:
            for r in (r for r in sc.reports if r.kind == "video"):
                assert r.arrival - r.time == cfg.delay
                cx, cy, w, h = footprint_at(r.time, UAV_FOOTPRINTS)
                tr = sc.truth[r.target_id]
                p = tr.positions[_at(tr, r.time)]
                assert abs(p[0] - cx) <= w / 2 and abs(p[1] - cy) <= h / 2
                area = w * h
                expected = 0.90 if area <= 1e6 else 0.75 if area <= 1e8 else 0.50
                assert r.p_declared == expected

    def test_all_three_resolutions_used(self, runs):
        assert {r.p_declared for r in runs[0].reports if r.kind == "video"} == {0.9, 0.75, 0.5}

    def test_type_rate(self, runs):
        rep = [r for sc in runs for r in sc.reports if r.kind == "video" and r.p_declared == 0.9]
        right = np.mean([r.declared == sc_class(runs, r) for r in rep])
        assert abs(right - 0.9) < 4 * math.sqrt(0.09 / len(rep))

    def test_detection_rate(self, truth):
        cfg = VideoConfig()
        reps = [simulate_video(truth, cfg, seed=s) for s in range(3)]
        inside = 0
        for t in np.arange(cfg.first_scan, 1200.0 + 1e-9, cfg.period):
            cx, cy, w, h = footprint_at(float(t), UAV_FOOTPRINTS)
            for tr in truth.values():
                i = _at(tr, t)
                if i is not None:
                    p = tr.positions[i]
                    inside += abs(p[0] - cx) <= w / 2 and abs(p[1] - cy) <= h / 2
        n_rep = sum(len(r) for r in reps)
        assert abs(n_rep / (3 * inside) - 0.9) < 4 * math.sqrt(0.09 / (3 * inside))

    def test_target_6_seen_by_gmti_only(self, runs):
        for sc in runs:
            kinds = {r.kind for r in sc.reports if r.target_id == 6}
            assert kinds == {"gmti"}


def sc_class(runs, r):
    return runs[0].truth[r.target_id].video_class


class TestUGS:
    def test_range_delay_no_clutter(self, runs):
        cfg = UGSConfig()
        for sc in runs:
            for r in (r for r in sc.reports if r.kind == "ugs"):
                assert r.target_id is not None
                assert r.arrival - r.time == cfg.delay
                tr = sc.truth[r.target_id]
                assert np.linalg.norm(tr.positions[_at(tr, r.time)] - r.sensor_position[:2]) <= 1000

    def test_one_detection_per_4_s(self, runs):
        for sc in runs:
            by_sensor = {}
            for r in sc.reports:
                if r.kind == "ugs":
                    by_sensor.setdefault(r.sensor, []).append(r.time)
            assert len(by_sensor) == 5
            for times in by_sensor.values():
                assert np.diff(sorted(times)).min() >= 4.0

    def test_aspect_probability(self, runs):
        for r in (r for r in runs[0].reports if r.kind == "ugs"):
            tr = runs[0].truth[r.target_id]
            i = _at(tr, r.time)
            alpha = ugs_aspect(tr.heading[i], r.sensor_position[:2], tr.positions[i])
            assert r.p_declared == (0.9 if math.pi / 6 <= alpha <= 5 * math.pi / 6 else 0.5)
        assert {r.p_declared for r in runs[0].reports if r.kind == "ugs"} == {0.9, 0.5}

    def test_aspect(self):
        assert ugs_aspect([1.0, 0.0], [0.0, 0.0], [0.0, 50.0]) == pytest.approx(math.pi / 2)
        assert ugs_aspect([1.0, 0.0], [0.0, 0.0], [50.0, 0.0]) == pytest.approx(0.0)
        assert ugs_aspect([1.0, 0.0], [0.0, 0.0], [-50.0, 0.0]) == pytest.approx(math.pi)

    def test_several_targets_shared(self, runs):
        """A UGS with several targets in range reports more than one of them."""
        ids = {r.target_id for r in runs[0].reports if r.sensor == "ugs-3"}
        assert len(ids) >= 3


class TestOutOfSequence:
    def test_arrival_order(self, runs):
        for sc in runs:
            arrivals = np.array([r.arrival for r in sc.reports])
            assert (np.diff(arrivals) >= 0).all()

    def test_delayed_reports_are_out_of_sequence(self, runs):
        sc = runs[0]
        oos = out_of_sequence(sc.reports)
        assert oos.sum() > 100
        kinds = {sc.reports[k].kind for k in np.flatnonzero(oos)}
        assert kinds <= {"video", "ugs"}
        # GMTI reports are never late
        assert not any(oos[k] for k, r in enumerate(sc.reports) if r.kind == "gmti")

    def test_flag(self):
        assert out_of_sequence([]).shape == (0,)


class TestReport:
    def test_bba(self, runs):
        for r in runs[0].reports[:30]:
            m = r.bba().numpy()
            n = 3 if r.frame == "gmti" else 8
            assert m.shape == (2**n,)
            assert m[1 << r.declared] == pytest.approx(r.p_declared)
            assert m[-1] == pytest.approx(1 - r.p_declared)
            assert m.sum() == pytest.approx(1.0)

    def test_measurement_shapes(self, runs):
        for r in runs[0].reports:
            d = 3 if r.kind == "gmti" else 2
            assert r.z.shape == (d,) and r.R.shape == (d, d)
            np.testing.assert_allclose(r.R, r.R.T)
            assert (np.linalg.eigvalsh(r.R) > 0).all()

    @pytest.mark.parametrize("frame", ["sar", "GMTI", "", None])
    def test_unknown_frame_is_refused(self, runs, frame):
        """Was silently read as the video frame by ``bba``."""
        r = runs[0].reports[0]
        msg = r"`frame`: expected one of 'gmti', 'video', got "
        with pytest.raises(ValueError, match=msg + repr(frame)):
            dataclasses.replace(r, frame=frame)
        for ok in ("gmti", "video"):
            assert dataclasses.replace(r, frame=ok, declared=0).frame == ok


class TestPlot:
    def test_plot(self, tmp_path, runs):
        sc = runs[0]
        path = tmp_path / "s.png"
        fig = plot_scenario(
            sc.network,
            sc.truth,
            tracks={"a": sc.truth[1].positions[::10]},
            reports=sc.reports,
            ugs=sc.ugs,
            footprints=UAV_FOOTPRINTS,
            path=path,
        )
        assert path.stat().st_size > 10_000
        assert len(fig.axes) == 1


# ---- GMTI resolution and the convoy headway (our additions) ---------------------------------


def _scan_polar(truth, cfg, t):
    """(target, true range, azimuth, range-rate) of the targets outside the notch at scan t."""
    xc, yc, h = cfg.position
    out = []
    for tid, tr in truth.items():
        i = _at(tr, t)
        if i is None:
            continue
        p = tr.positions[i]
        rr = float(gmti_range_rate((xc, yc), p, tr.velocities[i]))
        if abs(rr) >= cfg.mdv:
            r = math.sqrt((p[0] - xc) ** 2 + (p[1] - yc) ** 2 + h * h)
            out.append((tid, r, math.atan2(p[1] - yc, p[0] - xc), rr))
    return out


def _close_pairs(truth, cfg, cells):
    """Pairs closer than one cell in every coordinate at some scan: {(a, b): [times]}."""
    pairs = {}
    for t in np.arange(cfg.first_scan, 1200.0 + 1e-9, cfg.period):
        pol = _scan_polar(truth, cfg, t)
        for a in range(len(pol)):
            for b in range(a + 1, len(pol)):
                d = np.abs(np.subtract(pol[a][1:], pol[b][1:]))
                if (d < cells).all():
                    pairs.setdefault((pol[a][0], pol[b][0]), []).append(float(t))
    return pairs


class TestResolution:
    def test_cells_are_2_5_sigma_and_off_by_default(self, runs):
        from hocnet.tracking.sensors import gmti_resolution_cells

        cfg = GMTIConfig()
        cells = gmti_resolution_cells(cfg.sigma_range, cfg.sigma_azimuth, cfg.sigma_range_rate)
        assert GMTI_RESOLUTION == pytest.approx(cells, rel=1e-12)
        assert cfg.resolution is None
        assert all(r.unresolved == () for sc in runs for r in sc.reports)

    def test_default_convoy_never_within_a_cell(self, truth):
        # why the resolution is off by default: in our trajectories only the car 6 and the
        # truck 7 at the J1 crossing (t = 320 s) come within one cell; no convoy pair does
        pairs = _close_pairs(truth, GMTIConfig(), np.array(GMTI_RESOLUTION))
        assert pairs == {(6, 7): [320.0]}

    def test_close_convoy_within_a_cell(self):
        # 4 s headway: 48 m on the road, 47 m in range (< 50 m), equal range-rates
        truth4 = pd_ground_truth(targets=pd_targets(4.0))
        pairs = _close_pairs(truth4, GMTIConfig(), np.array(GMTI_RESOLUTION))
        assert set(pairs) == {(2, 4), (2, 7), (3, 7), (6, 7)}
        assert len(pairs[(3, 7)]) == 118  # every scan from 20 s to the end
        assert pairs[(2, 7)][-1] == 160.0  # until 2 accelerates away (150 s after leaving)
        # 5 s headway: 59 m in range, outside the cell: as the default scenario
        truth5 = pd_ground_truth(targets=pd_targets(5.0))
        assert set(_close_pairs(truth5, GMTIConfig(), np.array(GMTI_RESOLUTION))) == {(6, 7)}

    def test_pd_targets(self):
        assert pd_targets() == PD_TARGETS
        t4 = {s.target_id: s for s in pd_targets(4.0)}
        assert [t4[k].t_start for k in (3, 7, 2, 4)] == [0.0, 4.0, 8.0, 12.0]
        for s in PD_TARGETS:
            if s.target_id not in (2, 3, 4, 7):
                assert t4[s.target_id] == s
            assert t4[s.target_id].speed == s.speed and t4[s.target_id].route == s.route
        with pytest.raises(ValueError, match="`convoy_headway`"):
            pd_targets(-1.0)

    @pytest.mark.parametrize("headway", [10.0, 4.0])
    def test_merged_reports_and_paired_draws(self, headway):
        targets = pd_targets(headway)
        on = GMTIConfig(resolution=GMTI_RESOLUTION)
        truth4 = pd_ground_truth(targets=targets)
        a = simulate_gmti(truth4, GMTIConfig(), seed=5)
        b = simulate_gmti(truth4, on, seed=5)
        groups = {}
        for t in np.arange(0.0, 1200.0 + 1e-9, 10.0):
            pol = _scan_polar(truth4, on, t)
            labels = _loop_labels([p[1:] for p in pol], GMTI_RESOLUTION)
            for lab in set(labels):
                members = [pol[k] for k in range(len(pol)) if labels[k] == lab]
                if len(members) > 1:
                    groups[(float(t), tuple(sorted(m[0] for m in members)))] = members
        merged = [r for r in b if r.unresolved]
        assert merged or headway == 10.0
        absorbed = set()
        for r in merged:
            members = groups[(r.time, r.unresolved)]  # a group of the loop reference
            assert r.target_id == r.unresolved[0]  # equal powers: the first member carries it
            mean = np.mean([m[1:] for m in members], axis=0)
            xc, yc, h = on.position
            rng_ = math.sqrt((r.z[0] - xc) ** 2 + (r.z[1] - yc) ** 2 + h * h)
            az = math.atan2(r.z[1] - yc, r.z[0] - xc)
            assert abs(rng_ - mean[0]) < 5 * on.sigma_range
            assert abs(az - mean[1]) < 5 * on.sigma_azimuth
            assert abs(r.z[2] - mean[2]) < 5 * on.sigma_range_rate
            absorbed |= {(r.time, m) for m in r.unresolved}
        # no member of a merged group is reported on its own
        assert not any((r.time, r.target_id) in absorbed for r in b if not r.unresolved)
        # paired runs: the reports of targets outside the merged groups are unchanged
        keep_a = [r for r in a if (r.time, r.target_id) not in absorbed]
        keep_b = [r for r in b if not r.unresolved]
        in_group = {(t, m) for (t, ids) in groups for m in ids}
        keep_a = [r for r in keep_a if (r.time, r.target_id) not in in_group]
        keep_b = [r for r in keep_b if (r.time, r.target_id) not in in_group]
        assert len(keep_a) == len(keep_b) > 100
        for p, q in zip(keep_a, keep_b, strict=True):
            assert p.time == q.time and p.target_id == q.target_id and p.declared == q.declared
            np.testing.assert_array_equal(p.z, q.z)

    def test_headway_zero_merges_the_whole_convoy(self):
        sc = pd_scenario(
            seed=3, gmti=GMTIConfig(resolution=GMTI_RESOLUTION), targets=pd_targets(0.0)
        )
        first = [r for r in sc.reports if r.kind == "gmti" and r.time == 10.0 and r.target_id]
        convoy = [r for r in first if r.target_id in (2, 3, 4, 7)]
        assert len(convoy) <= 1
        assert all(r.unresolved == (2, 3, 4, 7) for r in convoy)


def _loop_labels(polar, cells):
    n = len(polar)
    close = [
        [
            i != j and all(abs(polar[i][d] - polar[j][d]) < cells[d] for d in range(3))
            for j in range(n)
        ]
        for i in range(n)
    ]
    label = list(range(n))
    changed = True
    while changed:
        changed = False
        for i in range(n):
            for j in range(n):
                if close[i][j] and label[j] < label[i]:
                    label[i] = label[j]
                    changed = True
    return label

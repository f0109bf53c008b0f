"""Tests of hocnet/tracking/pipeline.py (the glue of the [PD] 24.6 experiment)."""

import math

import numpy as np
import pytest
import torch

from hocnet.tracking.belief import pignistic
from hocnet.tracking.evaluation import assign_tracks, target_metrics
from hocnet.tracking.pipeline import (
    PDTrackerConfig,
    VSIMMRoadFilter,
    gmti_bba_on_video_frame,
    report_scans,
    run_pd_tracker,
)
from hocnet.tracking.road import RoadNetwork
from hocnet.tracking.scenario import VIDEO_TO_GMTI, pd_scenario
from hocnet.tracking.sensors import GMTISensor, VideoSensor


@pytest.fixture(scope="module")
def short():
    return pd_scenario(seed=3, duration=150.0)


def test_gmti_bba_refines_onto_the_video_frame():
    for c in range(3):
        m = gmti_bba_on_video_frame(c, 0.8)
        assert math.isclose(float(m.sum()), 1.0)
        members = [i for i, g in enumerate(VIDEO_TO_GMTI) if g == c]
        betp = pignistic(m)
        # BetP spreads 0.8 over the refined set and 0.2 over all 8 classes (24.47)
        for i in range(8):
            want = (0.8 / len(members) if i in members else 0.0) + 0.2 / 8
            assert math.isclose(float(betp[i]), want, abs_tol=1e-12)
    with pytest.raises(ValueError, match="declared"):
        gmti_bba_on_video_frame(3, 0.5)


def test_report_scans_group_every_report_once(short):
    scans = report_scans(short.reports, GMTISensor(short.gmti.position))
    flat = [r for s in scans for r in s.reports]
    assert flat == short.reports
    for s in scans:
        assert len({(r.kind, r.time, r.arrival) for r in s.reports}) == 1
        assert s.z.shape == (len(s.reports), 3) and s.bba.shape == (len(s.reports), 256)
        if s.kind != "gmti":  # padded third component: zero value, unit variance
            assert bool((s.z[:, 2] == 0).all()) and bool((s.R[:, 2, 2] == 1).all())


def _filter(net, kind, time, config=None):
    f = VSIMMRoadFilter(
        net,
        PDTrackerConfig() if config is None else config,
        GMTISensor((-50_000.0, -60_000.0, 4000.0)),
        VideoSensor(10.0, name="video"),
        VideoSensor(10.0, pd=1.0, name="ugs"),
        [(0.0, 1e9, 0.0, 0.0, 1e5, 1e5)],
    )
    f.set_scan(kind, time)
    return f


def test_video_gating_distance_is_the_2d_one():
    net = RoadNetwork([[[0.0, 0.0], [2000.0, 0.0]]])
    f = _filter(net, "video", 0.0)
    z = torch.tensor([[500.0, 0.0, 0.0]], dtype=torch.float64)
    R = torch.eye(3, dtype=torch.float64)[None].clone()
    R[0, 0, 0] = R[0, 1, 1] = 100.0
    s = f.initiate(z, R)
    f.set_scan("video", 10.0)
    pred = f.predict(s, 10.0)
    zp, hph = f.innovation(pred)
    z2 = torch.tensor([[560.0, 7.0, 0.0]], dtype=torch.float64)
    d = z2 - zp
    S = hph + R
    d2_3 = float(d[0] @ torch.linalg.solve(S[0], d[0]))
    d2_2 = float(d[0, :2] @ torch.linalg.solve(S[0, :2, :2], d[0, :2]))
    assert math.isclose(d2_3, d2_2, rel_tol=1e-12)


def test_score_increment_is_ln_lambda_over_clutter_density():
    # the filter returns ln Lambda - ln PD_mht + ln(lambda_mht / lambda_sensor), so that the
    # MHT's increment ln PD_mht + ll - ln lambda_mht is ln(Lambda / lambda_sensor) (24.42)
    net = RoadNetwork([[[0.0, 0.0], [2000.0, 0.0]]])
    cfg = PDTrackerConfig()
    f = _filter(net, "video", 0.0)
    R = torch.eye(3, dtype=torch.float64)[None].clone()
    R[0, 0, 0] = R[0, 1, 1] = 100.0
    s = f.initiate(torch.tensor([[500.0, 0.0, 0.0]], dtype=torch.float64), R)
    f.set_scan("video", 10.0)
    pred = f.predict(s, 10.0)
    _, ll = f.update(pred, torch.tensor([[520.0, 3.0, 0.0]], dtype=torch.float64), R)
    from hocnet.tracking.vsimm import vsimm_update

    _, out = vsimm_update(
        f._vs(pred),
        f._vs_pred(pred),
        torch.tensor([[520.0, 3.0]], dtype=torch.float64),
        f.sensors["video"],
        net,
        f.vcfg,
    )
    increment = math.log(cfg.pd) + float(ll[0]) - math.log(cfg.lambda_fa)
    want = float(out.log_likelihood[0]) - math.log(cfg.lambda_fa_imint)
    assert math.isclose(increment, want, rel_tol=1e-12)


def test_short_run_tracks_the_convoy_purely(short):
    out = run_pd_tracker(short, type_tracking=True)
    assert out.tracks and out.n_scans > 10
    asg = assign_tracks(out.tracks)
    m = target_metrics(short.truth, out.tracks)
    # the convoy 3, 7 (and 8 on the northern byway) are alone or 10 s apart in 150 s
    for tid in (3, 8):
        assert tid in asg.values()
        assert m[tid].track_purity >= 0.9
        assert m[tid].armse < 60.0
    for trk in out.tracks.values():
        assert bool(np.all(np.diff(trk.times) >= 0))
        assert bool(((trk.types >= -1) & (trk.types < 8)).all())


def test_without_type_tracking_no_types(short):
    out = run_pd_tracker(short, type_tracking=False)
    assert all(bool((t.types == -1).all()) for t in out.tracks.values())


def test_lag_memory_serves_reports_older_than_a_rows_birth():
    # max_lag=None: the one-step A1; a delayed report older than a row's birth (a track started
    # on a later GMTI report) is not associated with it. With a lag memory every OOSM row is
    # served (one step: A1; before the birth: the diffuse-prior retrodiction)
    sc = pd_scenario(seed=2400, duration=300.0)
    before = run_pd_tracker(sc, type_tracking=False)
    after = run_pd_tracker(sc, type_tracking=False, config=PDTrackerConfig(max_lag=2))
    assert before.out_of_lag > 0
    assert after.out_of_lag == 0
    assert after.oosm_failures == 0
    assert after.tracks
    for trk in after.tracks.values():
        assert np.isfinite(trk.positions).all()


def test_lag_memory_rows_carry_the_memory():
    net = RoadNetwork([[[0.0, 0.0], [2000.0, 0.0]]])
    cfg = PDTrackerConfig(max_lag=3)
    filt = VSIMMRoadFilter(
        net,
        cfg,
        GMTISensor((0.0, -5000.0, 3000.0)),
        VideoSensor(10.0, name="video"),
        VideoSensor(10.0, name="ugs"),
        (),
    )
    R = torch.eye(3, dtype=torch.float64).expand(1, 3, 3) * 100
    filt.set_scan("video", 10.0)
    s = filt.initiate(torch.tensor([[100.0, 0.0, 0.0]], dtype=torch.float64), R)
    assert s["lag_t"].shape == (1, 3) and bool(torch.isinf(s["lag_t"]).all())
    filt.set_scan("video", 20.0)
    s = filt.predict(s, 10.0)
    s, _ = filt.update(s, torch.tensor([[210.0, 0.0, 0.0]], dtype=torch.float64), R)
    assert s["lag_t"][0].tolist()[0] == 10.0 and s["t"].tolist() == [20.0]
    filt.set_scan("video", 5.0)  # older than the birth: served, state updated
    s2 = filt.predict(s, 0.0)
    assert bool(s2["retro"][0]) and bool(s2["lag_ok"][0])
    s3, ll = filt.update(s2, torch.tensor([[50.0, 0.0, 0.0]], dtype=torch.float64), R)
    assert torch.isfinite(ll).all() and not torch.equal(s3["x"], s["x"])
    assert torch.equal(s3["lag_t"], s["lag_t"])


def _turn_at_junction(junction_hypotheses: bool, max_lag: int | None = None, net=None):
    """A target at 15 m/s east on road A turns right (south) at the junction (1000, 0)."""
    if net is None:
        net = RoadNetwork(
            [
                [[0.0, 0.0], [1000.0, 0.0]],
                [[1000.0, 0.0], [2000.0, 0.0]],
                [[1000.0, 0.0], [1000.0, -1000.0]],
            ],
            [{"road_class": "highway"}] * 2 + [{"road_class": "byway"}],
        )
    gmti = GMTISensor((-50_000.0, -60_000.0, 4000.0))
    cfg = PDTrackerConfig(junction_hypotheses=junction_hypotheses, max_lag=max_lag)
    f = VSIMMRoadFilter(
        net, cfg, gmti, VideoSensor(10.0, name="video"), VideoSensor(10.0, name="ugs"), []
    )
    truth = [(t, torch.tensor([[600.0 + 15 * (t + 20), 15.0, 0.0, 0.0]])) for t in (-20, -10, 0)]
    truth.append((10.0, torch.tensor([[1000.0, 0.0, -50.0, -15.0]])))
    s = None
    for t, x in truth:
        z = gmti.measure(x.double())
        R = gmti.covariance(z)
        f.set_scan("gmti", float(t))
        if s is None:
            s = f.initiate(z, R)
            continue
        pred = f.predict(s, 10.0)
        zp, hph = f.innovation(pred)
        nu = z[0] - zp[0]
        d2 = float(nu @ torch.linalg.solve(hph[0] + R[0], nu))
        s, _ = f.update(pred, z, R)
    x, _ = f.mean_cov(s)
    f.last_state = s
    return d2, x[0], f


def test_junction_hypotheses_follow_a_turn():
    # issue 12: predicted straight on, the turning target's report (range-rate -11.6 m/s against
    # +9.6 m/s predicted) fell outside the 0.999 gate (chi-square 16.3 with 3 degrees of
    # freedom): the track missed it, fell into the stop model and coasted away from the target
    d2_on, x_on, f_on = _turn_at_junction(True)
    d2_off, _, _ = _turn_at_junction(False)
    gate = 16.27
    assert d2_on < gate < d2_off
    assert f_on.junction_switches == 1
    assert math.hypot(x_on[0] - 1000.0, x_on[2] + 50.0) < 15.0  # on the southern branch
    assert x_on[3] < -10.0 and abs(x_on[1]) < 1.0  # heading south


def test_lag_memory_follows_the_junction_hypothesis_taken():
    # issue 12 review (lag_junc.py): after the switch onto the southern branch the lag memory
    # still held the straight-on prediction x(k|k-1) = (1049.8, 0); now entry 0 is the branch
    # hypothesis's prediction and the older entry is carried onto the branch with it
    _, x, f = _turn_at_junction(True, max_lag=2)
    s = f.last_state
    assert f.junction_switches == 1
    for j in range(2):
        for i in (1, 2):  # the road modes
            px, py = s["lag_x"][0, j, i, 0], s["lag_x"][0, j, i, 2]
            assert abs(px - 1000.0) < 5.0 and py < -30.0, (j, i, px, py)
            assert s["lag_x"][0, j, i, 3] < -10.0  # heading south
    # the one-section 90 degree bend (pipe_bend.py): the prediction follows the road, gated
    bend = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0], [1000.0, -1000.0]]])
    d2, x, _ = _turn_at_junction(True, net=bend)
    assert d2 < 16.27 and math.hypot(x[0] - 1000.0, x[2] + 50.0) < 15.0


def test_max_coast_none_never_penalises():
    net = RoadNetwork([[[0.0, 0.0], [5000.0, 0.0]]])
    f = _filter(net, "gmti", 0.0, PDTrackerConfig(max_coast=None))
    z = f.sensors["gmti"].measure(torch.tensor([[1000.0, 15.0, 0.0, 0.0]], dtype=torch.float64))
    s = f.initiate(z, f.sensors["gmti"].covariance(z))
    for t in (10.0, 20.0, 30.0, 40.0, 50.0):
        f.set_scan("gmti", t)
        s, log_miss = f.miss(f.predict(s, 10.0), 0.9)
        assert float(log_miss[0]) > -f.cfg.coast_penalty


def test_coasting_track_is_penalised_after_max_coast():
    # issue 12: a track left behind by its target falls into the stop model (miss likelihood 1,
    # 24.31) and coasts; 30 s without any detection (three GMTI revisits) now ends it
    net = RoadNetwork([[[0.0, 0.0], [5000.0, 0.0]]])
    cfg = PDTrackerConfig()
    assert cfg.max_coast == 30.0
    f = _filter(net, "gmti", 0.0)
    z = f.sensors["gmti"].measure(torch.tensor([[1000.0, 15.0, 0.0, 0.0]], dtype=torch.float64))
    s = f.initiate(z, f.sensors["gmti"].covariance(z))
    penalties = []
    for t in (10.0, 20.0, 30.0, 40.0):
        f.set_scan("gmti", t)
        pred = f.predict(s, 10.0)
        s, log_miss = f.miss(pred, cfg.pd)
        penalties.append(float(log_miss[0]) < -cfg.coast_penalty)
    assert penalties == [False, False, False, True]

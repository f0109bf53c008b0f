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


def _shallow_fork(junction_test: str, n_after: int = 4):
    """A target at 15 m/s east takes the branch 10 degrees right of straight on at (1000, 0).

    Noise-free GMTI reports; both branches are highways (``Omega`` equal). Returns the filter
    and, after each report past the junction, ``(section, ln mu of the pending hypotheses or
    None, combined estimate, true state, (predicted dict, z, ln Lambda))``.
    """
    a = math.radians(10.0)
    c, si, L = math.cos(a), math.sin(a), 3000.0
    net = RoadNetwork(
        [
            [[0.0, 0.0], [1000.0, 0.0]],
            [[1000.0, 0.0], [1000.0 + L, 0.0]],
            [[1000.0, 0.0], [1000.0 + L * c, -L * si]],
        ],
        [{"road_class": "highway"}] * 3,
    )
    gmti = GMTISensor((-50_000.0, -60_000.0, 4000.0))
    cfg = PDTrackerConfig(junction_test=junction_test)
    f = VSIMMRoadFilter(
        net, cfg, gmti, VideoSensor(10.0, name="video"), VideoSensor(10.0, name="ugs"), []
    )
    v = 15.0
    truth = [(t, [1000.0 + v * t, v, 0.0, 0.0]) for t in (-30.0, -20.0, -10.0, 0.0)]
    for k in range(1, n_after + 1):
        d = v * 10.0 * k
        truth.append((10.0 * k, [1000 + d * c, v * c, -d * si, -v * si]))
    s, out = None, []
    for t, x in truth:
        z = gmti.measure(torch.tensor([x], dtype=torch.float64))
        R = gmti.covariance(z)
        f.set_scan("gmti", t)
        if s is None:
            s = f.initiate(z, R)
            continue
        pred = f.predict(s, 10.0)
        s, ll = f.update(pred, z, R)
        if t > 0:
            pend = s["j_lmu"][0] if "ja_valid" in s and bool(s["ja_valid"].any()) else None
            out.append((int(s["section"][0]), pend, f.mean_cov(s)[0][0], x, (pred, z, ll)))
    return f, out


def test_sprt_junction_test_accumulates_where_the_one_step_test_keeps_the_wrong_branch():
    # [PD] 24.4.3: "one measurement iteration is not sufficient to choose the right hypothesis"
    f1, one = _shallow_fork("one-step")
    fs, sprt = _shallow_fork("sprt")
    # first report past the fork: mu_branch / mu_straight below the bound 99 of 24.39
    sec, lmu = sprt[0][:2]
    assert lmu is not None and sec == 1
    assert 0.0 < float(lmu[1] - lmu[0]) < math.log(99.0)
    assert one[0][0] == 1 and f1.junction_switches == 0  # one-step: undecided -> straight on
    # the multi-scan test accepts the branch on the 2nd or 3rd report and ends
    taken = [k for k, o in enumerate(sprt) if o[0] == 2 and o[1] is None]
    assert taken and 1 <= taken[0] <= 2
    assert fs.junction_switches == 1
    assert all(o[0] == 2 for o in sprt[taken[0] :])
    # one-step keeps the wrong (straight) branch to the end
    assert all(o[0] == 1 for o in one) and f1.junction_switches == 0
    x_s, x_true = sprt[-1][2], sprt[-1][3]
    x_1 = one[-1][2]
    err_s = math.hypot(x_s[0] - x_true[0], x_s[2] - x_true[2])
    err_1 = math.hypot(x_1[0] - x_true[0], x_1[2] - x_true[2])
    assert err_s < 15.0 < 50.0 < err_1


def test_sprt_junction_test_against_a_loop_reference():
    # 24.38 as a loop over the hypotheses of the pending test, each hypothesis' IMM updated on
    # its own (vsimm_update on the stored state / prediction): ln mu_h(k) = ln Lambda_h +
    # ln mu_h(k-1) - ln c (Omega the identity past the fork), ln c the leaf's ln Lambda
    from hocnet.tracking.vsimm import VSIMMPrediction, VSIMMState, vsimm_update

    f, sprt = _shallow_fork("sprt", n_after=2)
    lmu1 = sprt[0][1]
    pred, z, ll = sprt[1][4]
    assert sprt[1][1] is not None  # still pending after two reports
    corr = -math.log(f.cfg.pd) + math.log(f.cfg.lambda_fa / f._lambda["gmti"])
    vs_keys = VSIMMState._fields
    terms = []
    for h in range(2):
        if h == 0:
            st = VSIMMState(*(pred["vs_section" if k == "section" else k] for k in vs_keys))
            pr = VSIMMPrediction(
                pred["p_cbar"], pred["p_x"], pred["p_P"], pred["p_segment"], pred["p_on"],
                pred["p_accel"], pred["p_t"],
            )  # fmt: skip
        else:
            g = "ja_"
            st = VSIMMState(
                *(pred[g + ("vs_section" if k == "section" else k)][:, 0] for k in vs_keys)
            )
            pr = VSIMMPrediction(
                pred["p_acbar"][:, 0], pred["p_ax"][:, 0], pred["p_aP"][:, 0],
                pred["p_aseg"][:, 0], pred["p_aon"][:, 0], pred["p_aacc"][:, 0], pred["p_t"],
            )  # fmt: skip
        _, u = vsimm_update(st, pr, z, f.sensors["gmti"], f.net, f.vcfg)
        terms.append(float(u.log_likelihood[0]) + float(lmu1[h]))
    ln_c = math.log(sum(math.exp(v) for v in terms))
    assert math.isclose(float(ll[0]) - corr, ln_c, rel_tol=0, abs_tol=1e-9)
    lmu2 = sprt[1][1]
    for h in range(2):
        assert math.isclose(float(lmu2[h]), terms[h] - ln_c, rel_tol=0, abs_tol=1e-9)
    assert float(lmu2[1] - lmu2[0]) > float(lmu1[1] - lmu1[0])  # the evidence accumulates


def test_junction_test_sprt_equals_the_default(short):
    a = run_pd_tracker(short, type_tracking=False)
    b = run_pd_tracker(short, type_tracking=False, config=PDTrackerConfig(junction_test="sprt"))
    assert a.tracks.keys() == b.tracks.keys() and a.junction_switches == b.junction_switches
    for k in a.tracks:
        for name in ("times", "positions", "truth_ids", "types"):
            np.testing.assert_array_equal(getattr(a.tracks[k], name), getattr(b.tracks[k], name))
    c = run_pd_tracker(short, type_tracking=False, config=PDTrackerConfig(junction_test="one-step"))
    assert c.tracks and all(np.isfinite(tr.positions).all() for tr in c.tracks.values())


def test_junction_test_bad_value():
    with pytest.raises(ValueError, match="junction_test"):
        PDTrackerConfig(junction_test="wald")
    with pytest.raises(ValueError, match="alpha"):
        PDTrackerConfig(junction_test="sprt", junction_alpha=0.0)


def _late_turn(junction_defer: float):
    """A target northbound at 17 m/s slows to 14 m/s, is 20 m before the junction (0, 0) at the
    scan of t = 0 (its constant-velocity prediction already 10 m past it) and turns west there.

    Returns the gate distances ``d2`` of the reports after t = 0, the final combined estimate and
    the filter (issue 12, seed 2408, target 6 at N1, t = 670 s, in small).
    """
    net = RoadNetwork(
        [
            [[0.0, -1000.0], [0.0, 0.0]],
            [[0.0, 0.0], [0.0, 1000.0]],
            [[0.0, 0.0], [-1000.0, 0.0]],
            [[0.0, 0.0], [1000.0, 0.0]],
        ],
        [{"road_class": "byway"}] * 4,
    )
    gmti = GMTISensor((-50_000.0, -60_000.0, 4000.0))
    cfg = PDTrackerConfig(junction_defer=junction_defer)
    f = VSIMMRoadFilter(
        net, cfg, gmti, VideoSensor(10.0, name="video"), VideoSensor(10.0, name="ugs"), []
    )
    truth = [(-30.0, [0.0, 0.0, -500.0, 17.0]), (-20.0, [0.0, 0.0, -330.0, 17.0])]
    truth += [(-10.0, [0.0, 0.0, -160.0, 17.0]), (0.0, [0.0, 0.0, -20.0, 14.0])]
    truth += [(t, [-14.0 * (t - 20 / 14), -14.0, 0.0, 0.0]) for t in (10.0, 20.0, 30.0)]
    s, d2s = None, []
    for t, x in truth:
        z = gmti.measure(torch.tensor([x], dtype=torch.float64))
        R = gmti.covariance(z)
        f.set_scan("gmti", t)
        if s is None:
            s = f.initiate(z, R)
            continue
        pred = f.predict(s, 10.0)
        zp, hph = f.innovation(pred)
        nu = z[0] - zp[0]
        d2 = float(nu @ torch.linalg.solve(hph[0] + R[0], nu))
        if t > 0:
            d2s.append(d2)
        if d2 > 16.27:  # outside the 0.999 gate: the MHT would not associate it, a miss
            s, _ = f.miss(pred, 0.9)
        else:
            s, _ = f.update(pred, z, R)
    x, _ = f.mean_cov(s)
    return d2s, x[0], f


def test_junction_defer_keeps_a_turn_decided_before_the_target_turned():
    # issue 12, seed 2408, target 6: at the scan where the prediction first passed N1 the target
    # had not turned yet; its northbound range-rate rejected the westbound branch (24.40) on that
    # one report, the westbound reports then fell outside the gate and the track coasted away
    d2_off, _, _ = _late_turn(0.0)
    d2_on, x_on, f_on = _late_turn(100.0)
    assert min(d2_off[:2]) > 16.27  # the first two westbound reports missed without the option
    assert max(d2_on) < 16.27  # every westbound report is gated with it
    assert f_on.junction_switches == 1
    truth = (-14.0 * (30.0 - 20 / 14), 0.0)
    assert math.hypot(x_on[0] - truth[0], x_on[2] - truth[1]) < 30.0
    assert x_on[1] < -10.0  # heading west


def test_junction_defer_off_by_default_leaves_the_state_unchanged():
    # the committed 24.6 results must stay valid: with the default (0) no deferral field exists
    # and no code path of the option runs; a negative distance is refused
    net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]], [[1000.0, 0.0], [2000.0, 0.0]]])
    z = torch.tensor([[500.0, 0.0, 0.0]], dtype=torch.float64)
    R = torch.diag(torch.tensor([100.0, 100.0, 1.0], dtype=torch.float64))[None]
    assert PDTrackerConfig().junction_defer == 0.0
    assert "p_adefer" not in _filter(net, "gmti", 0.0).initiate(z, R)
    on = _filter(net, "gmti", 0.0, PDTrackerConfig(junction_defer=100.0)).initiate(z, R)
    assert "p_adefer" in on and not bool(on["p_adefer"].any())
    with pytest.raises(ValueError, match="junction_defer"):
        PDTrackerConfig(junction_defer=-1.0)


def test_junction_on_crossing_opens_the_hypotheses_when_the_prediction_crossed():
    # issue 12, seed 2408, target 4 at J3 (t = 900 s): the VS-IMM prediction took the segment
    # past the junction while the best mode's constant-velocity extrapolation stopped before it;
    # without the option no section hypothesis was opened and the turn was never tested
    from hocnet.tracking.vsimm import vsimm_init, vsimm_predict

    net = RoadNetwork(
        [
            [[0.0, 0.0], [1000.0, 0.0]],
            [[1000.0, 0.0], [2000.0, 0.0]],
            [[1000.0, 0.0], [1000.0, 1000.0]],
            [[1000.0, 0.0], [1000.0, -1000.0]],
        ],
        [{"road_class": "byway"}] * 4,
    )
    out = {}
    for on in (False, True):
        f = _filter(net, "gmti", 5.0, PDTrackerConfig(junction_on_crossing=on))
        x0 = torch.tensor([[900.0, 10.0, 0.0, 0.0]], dtype=torch.float64)
        vs = vsimm_init(net, x0, torch.eye(4, dtype=torch.float64) * 25.0, f.vcfg, 0.0)
        pred = vsimm_predict(vs, net, f.vcfg, 5.0)  # CV: 950 m, 50 m before the junction
        assert int(pred.segment[0, 1]) == 0
        crossed = pred._replace(segment=torch.ones_like(pred.segment))  # as the mixing did
        out[on] = f._junction_sections(vs, crossed)[0][0]
        assert f._junction_sections(vs, pred)[0][0] == []  # not crossed: none either way
    assert out[False] == []
    assert sorted(out[True]) == [2, 3]  # north and south, not the segment it came from


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf")])
def test_section_distance_is_checked_in_the_config(bad):
    # a review finding: -1 and nan were accepted and failed only later, inside MHT()
    with pytest.raises(ValueError, match="section_distance"):
        PDTrackerConfig(section_distance=bad)
    assert PDTrackerConfig(section_distance=None).section_distance is None


def test_section_best_and_split_links_reach_the_mht(short):
    # issue 12 (target 1's ARMSE): the MHT's N-scan section exception and cluster split,
    # the former behaviour kept as "leaf" / "window" (tests/tracking/test_mht.py)
    from hocnet.tracking.pipeline import _pd_tracker

    cfg = PDTrackerConfig()
    assert (cfg.section_best, cfg.split_links) == ("leaf", "history")
    _, mht, _ = _pd_tracker(short, cfg, type_tracking=False)
    assert (mht.section_best, mht.split_links) == ("leaf", "history")
    old = PDTrackerConfig(section_best="leaf", split_links="window")
    _, mht, _ = _pd_tracker(short, old, type_tracking=False)
    assert (mht.section_best, mht.split_links) == ("leaf", "window")
    with pytest.raises(ValueError, match="section_best"):
        PDTrackerConfig(section_best="score")
    with pytest.raises(ValueError, match="split_links"):
        PDTrackerConfig(split_links="all")


def test_junction_retro_is_checked_and_reaches_the_filter():
    assert PDTrackerConfig().vsimm.junction_retro == "state"
    assert PDTrackerConfig(junction_retro="locate").vsimm.junction_retro == "locate"
    with pytest.raises(ValueError, match="`junction_retro`: expected one of 'state', 'locate'"):
        PDTrackerConfig(junction_retro="bad")

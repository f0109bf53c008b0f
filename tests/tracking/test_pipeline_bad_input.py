"""Bad input to the tracker glue of hocnet/tracking/pipeline.py (issue 12, "Speed and bad input").

A small run of the VS-IMMC SB-MHT (:func:`run_pd_tracker`'s construction, stepped by hand) gets,
after a few scans, one bad scan: non-finite measurements, time going backwards beyond the OOSM
lag, an unknown sensor kind, or reports older than the lag. Each must raise a clear error naming
what was wrong, leave the tracker exactly as it was (leaves, scores, states, hypotheses, scan
counter), and the run must then go on as if the bad scan had never been offered: its final tracks
equal those of a clean run on the same scans.
"""

import dataclasses
import math

import pytest
import torch

from hocnet.tracking.mht import MHT
from hocnet.tracking.pipeline import (
    PDTrackerConfig,
    Scan,
    _pd_tracker,
    report_scans,
    run_pd_tracker,
)
from hocnet.tracking.road import RoadNetwork
from hocnet.tracking.scenario import pd_scenario
from hocnet.tracking.sensors import GMTISensor, VideoSensor
from hocnet.tracking.vsimm import (
    VSIMMConfig,
    vsimm_init,
    vsimm_oosm,
    vsimm_predict,
    vsimm_step,
    vsimm_update,
)

N_WARM = 6  # scans before the bad input (tracks exist, some confirmed)
N_AFTER = 4  # scans after it


@pytest.fixture(scope="module")
def scenario():
    return pd_scenario(seed=2400, duration=120.0)


def _tracker(sc, cfg):
    """Filter and MHT as :func:`run_pd_tracker` builds them, and the scenario's scans."""
    return _pd_tracker(sc, cfg, type_tracking=True)


def _step(filt, mht, scan):
    t = scan.time if mht.time is None else max(mht.time, scan.time)
    filt.set_scan(scan.kind, scan.time)
    return mht.step(scan.z, time=t, R=scan.R, bba=scan.bba)


def _snapshot(filt, mht):
    """Everything a bad scan could corrupt: leaves, scores, states, hypotheses, counters."""
    leaves = [dataclasses.astuple(leaf) for leaf in mht._leaves]
    states = None if mht._states is None else {k: v.clone() for k, v in mht._states.items()}
    tracks = [
        (t.id, t.status, t.score, t.state.clone(), t.covariance.clone(), t.measurements)
        for t in mht.tracks(include_tentative=True)
    ]
    counters = (
        filt.out_of_lag,
        filt.sanitized,
        filt.oosm_failures,
        filt.junction_switches,
        filt.too_old_dropped,
        list(filt._clock),
    )
    return {
        "scan": mht.scan,
        "time": mht.time,
        "ids": (mht._next_uid, mht._next_family),
        "leaves": leaves,
        "states": states,
        "bba": None if mht._bba is None else mht._bba.clone(),
        "hyps": [list(c.hyps) for c in mht._clusters],
        "finished": sorted(mht._finished),
        "tracks": tracks,
        "counters": counters,
    }


def _assert_same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        if k == "states":
            assert (a[k] is None) == (b[k] is None)
            if a[k] is not None:
                assert a[k].keys() == b[k].keys()
                for key in a[k]:
                    torch.testing.assert_close(
                        a[k][key], b[k][key], rtol=0, atol=0, equal_nan=True, msg=key
                    )
        elif k == "tracks":
            assert len(a[k]) == len(b[k])
            for ta, tb in zip(a[k], b[k]):
                assert ta[:3] == tb[:3] and ta[5] == tb[5]
                assert torch.equal(ta[3], tb[3]) and torch.equal(ta[4], tb[4])
        elif k == "bba":
            assert (a[k] is None) == (b[k] is None)
            assert a[k] is None or torch.equal(a[k], b[k])
        else:
            assert a[k] == b[k], k


def _run(sc, bad=None, cfg=None):
    """``N_WARM`` scans, the bad input ``bad(filt, mht, next_scan)`` (must leave everything as it
    was), then the remaining scans; returns the final snapshot."""
    filt, mht, scans = _tracker(sc, PDTrackerConfig() if cfg is None else cfg)
    assert len(scans) >= N_WARM + N_AFTER
    for scan in scans[:N_WARM]:
        _step(filt, mht, scan)
    assert mht.n_leaves > 0 and mht.tracks(), "the bad input must meet live tracks"
    if bad is not None:
        before = _snapshot(filt, mht)
        bad(filt, mht, scans[N_WARM])
        _assert_same(before, _snapshot(filt, mht))
    for scan in scans[N_WARM : N_WARM + N_AFTER]:
        _step(filt, mht, scan)
    return _snapshot(filt, mht)


@pytest.fixture(scope="module")
def clean(scenario):
    return _run(scenario)


def _with(scan, **changes):
    return dataclasses.replace(scan, **changes)


@pytest.mark.parametrize("what", ["z_nan", "z_inf", "R_nan"])
def test_non_finite_measurement_raises_and_changes_nothing(scenario, clean, what):
    def bad(filt, mht, scan):
        z, R = scan.z.clone(), scan.R.clone()
        if what == "z_nan":
            z[0, 0] = math.nan
        elif what == "z_inf":
            z[-1, 2] = math.inf
        else:
            R[0, 1, 1] = math.nan
        name = what[0]
        with pytest.raises(ValueError, match=rf"`{name}`: expected .*(finite|NaN)"):
            _step(filt, mht, _with(scan, z=z, R=R))

    _assert_same(clean, _run(scenario, bad))


def test_time_going_backwards_raises_and_changes_nothing(scenario, clean):
    def bad(filt, mht, scan):
        # the MHT's own clock cannot go back ...
        filt.set_scan(scan.kind, mht.time - 100.0)
        with pytest.raises(ValueError, match=r"`time`: expected >= the previous scan time"):
            mht.step(scan.z, time=mht.time - 100.0, R=scan.R, bba=scan.bba)
        # ... and a scan 100 s late, beyond the OOSM lag of every track, is refused
        with pytest.raises(ValueError, match=r"`time`: expected a gmti scan within the OOSM lag"):
            _step(filt, mht, _with(scan, time=mht.time - 100.0))

    _assert_same(clean, _run(scenario, bad))


def test_unknown_sensor_kind_raises_and_changes_nothing(scenario, clean):
    def bad(filt, mht, scan):
        kind, time = filt.kind, filt.time
        with pytest.raises(
            ValueError, match=r"`kind`: expected one of 'gmti', 'video', 'ugs', got 'sonar'"
        ):
            filt.set_scan("sonar", scan.time)
        assert (filt.kind, filt.time) == (kind, time)
        with pytest.raises(ValueError, match=r"`time`: expected a finite number, got nan"):
            filt.set_scan("gmti", math.nan)
        assert (filt.kind, filt.time) == (kind, time)

    _assert_same(clean, _run(scenario, bad))


def _stale_video(scan, time):
    """The reports of ``scan`` as a video scan taken at ``time`` (2-D positions, 10 m noise)."""
    M = scan.z.shape[0]
    z = torch.zeros(M, 3, dtype=torch.float64)
    z[:, :2] = scan.z[:, :2]
    R = torch.eye(3, dtype=torch.float64).repeat(M, 1, 1)
    R[:, 0, 0] = R[:, 1, 1] = 100.0
    return Scan("video", time, scan.arrival, scan.reports, z, R, scan.bba)


def test_report_older_than_the_lag_raises_and_starts_no_track(scenario, clean):
    # issue 12: a video scan 100 s older than the tracker's time was accepted, counted in
    # out_of_lag and started one tentative track per report
    def bad(filt, mht, scan):
        stale = _stale_video(scan, mht.time - 100.0)
        assert filt.lag_limit() == mht.time - 10.0  # one GMTI revisit: the one-step A1
        with pytest.raises(ValueError, match=r"video scan within the OOSM lag .* 100 s older"):
            _step(filt, mht, stale)

    _assert_same(clean, _run(scenario, bad))


@pytest.mark.parametrize("max_lag", [None, 2])
def test_scans_within_the_lag_are_processed_older_ones_refused(scenario, max_lag):
    # the limit is the L-th last in-sequence scan (L = 1, or max_lag): a scan that late is
    # processed (OOSM), one older is refused, also when the tracker holds no track (initiate)
    lag = 1 if max_lag is None else max_lag
    filt, mht, scans = _tracker(scenario, PDTrackerConfig(max_lag=max_lag))
    assert filt.lag_limit() == -math.inf  # nothing processed: no limit
    for scan in scans[:N_WARM]:
        _step(filt, mht, scan)
    assert filt.lag_limit() == scans[N_WARM - 1 - lag].time
    filt.set_scan("video", filt.lag_limit() - 1.0)
    assert filt.scan_too_old()
    late = _stale_video(scans[N_WARM - 1], filt.lag_limit())
    filt.set_scan(late.kind, late.time)
    assert not filt.scan_too_old()
    _step(filt, mht, late)
    assert mht.scan == N_WARM + 1
    # an empty tracker (no leaves: MHT.step calls initiate only) refuses the stale scan too
    mht._leaves, mht._states, mht._clusters = [], None, []
    stale = _stale_video(scans[N_WARM], filt.lag_limit() - 1.0)
    with pytest.raises(ValueError, match=r"OOSM lag of the tracker"):
        _step(filt, mht, stale)
    assert mht.n_leaves == 0


def _with_stale_report(sc, delay=100.0):
    """The scenario with a GMTI report repeated ``delay`` s before its time (same arrival)."""
    i = next(k for k, r in enumerate(sc.reports) if r.time >= 90.0 and r.sensor == "gmti")
    r = sc.reports[i]
    while i + 1 < len(sc.reports) and sc.reports[i + 1].time == r.time:
        i += 1  # after the whole scan of r, so that the other scans stay as they were
    stale = dataclasses.replace(r, time=r.time - delay)
    reports = [*sc.reports[: i + 1], stale, *sc.reports[i + 1 :]]
    return dataclasses.replace(sc, reports=reports)


def test_run_pd_tracker_too_old_raise_or_drop(scenario):
    sc = _with_stale_report(scenario)
    with pytest.raises(ValueError, match=r"OOSM lag .*too_old='drop'"):
        run_pd_tracker(sc, type_tracking=False)
    dropped = run_pd_tracker(sc, type_tracking=False, config=PDTrackerConfig(too_old="drop"))
    ref = run_pd_tracker(scenario, type_tracking=False)
    assert dropped.too_old_dropped == 1 and ref.too_old_dropped == 0  # its one report
    # dropped silently but counted: the run is the clean one (no track from the stale report)
    assert dropped.n_scans == ref.n_scans and dropped.out_of_lag == ref.out_of_lag
    assert dropped.tracks.keys() == ref.tracks.keys()
    for tid, trk in ref.tracks.items():
        other = dropped.tracks[tid]
        assert list(other.times) == list(trk.times)
        assert torch.equal(torch.as_tensor(other.positions), torch.as_tensor(trk.positions))
        assert list(other.truth_ids) == list(trk.truth_ids)


def test_too_old_option_is_checked():
    with pytest.raises(ValueError, match=r"`too_old`: expected one of 'raise', 'drop', got 'warn'"):
        PDTrackerConfig(too_old="warn")


# --------------------------------------------------------------------------- vsimm arguments
def _vsimm_row():
    net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]]])
    cfg = VSIMMConfig()
    s = vsimm_init(net, torch.tensor([[0.0, 10.0, 0.0, 0.0]]), 100 * torch.eye(4), cfg)
    s, _ = vsimm_step(s, net, cfg, 10.0, torch.tensor([[100.0, 0.0]]), VideoSensor())
    return net, cfg, s


@pytest.mark.parametrize("sensor", ["sonar", "video", None, 3.0])
def test_vsimm_functions_name_a_sensor_that_is_not_a_model(sensor):
    net, cfg, s = _vsimm_row()
    z = torch.tensor([[150.0, 0.0]])
    msg = r"`sensor`: expected a sensor model such as GMTISensor or VideoSensor"
    with pytest.raises(TypeError, match=msg):
        vsimm_step(s, net, cfg, 20.0, z, sensor)
    with pytest.raises(TypeError, match=msg):
        vsimm_update(s, vsimm_predict(s, net, cfg, 20.0), z, sensor, net, cfg)
    with pytest.raises(TypeError, match=msg):
        vsimm_oosm(s, z, 5.0, sensor, net, cfg)
    if isinstance(sensor, str):
        with pytest.raises(TypeError, match=rf"got str '{sensor}' \(a name: build the model"):
            vsimm_step(s, net, cfg, 20.0, z, sensor)


# --------------------------------------------------------------------------- relabelled reports
@pytest.fixture(scope="module")
def with_video():
    """300 s: the first video reports arrive after 120 s (the runs below stop before any scan)."""
    sc = pd_scenario(seed=2400, duration=300.0)
    assert {r.kind for r in sc.reports} == {"gmti", "video"}
    return sc


def _relabelled(sc, kind, sensor):
    """``sc`` with its last ``kind`` report relabelled as ``sensor`` (kinematics unchanged)."""
    i = max(k for k, r in enumerate(sc.reports) if r.kind == kind)
    reports = list(sc.reports)
    reports[i] = dataclasses.replace(reports[i], sensor=sensor)
    return i, dataclasses.replace(sc, reports=reports)


@pytest.mark.parametrize("kind", ["gmti", "video"])
def test_report_with_unknown_sensor_is_refused_before_any_scan(with_video, kind, monkeypatch):
    """A GMTI (3-D z: was a torch RuntimeError) or video report relabelled "sonar", placed last:
    refused up front, naming the report, before the tracker steps a single scan."""
    i, sc = _relabelled(with_video, kind, "sonar")
    assert i > len(sc.reports) // 2  # late in the feed: the check does not wait for it
    stepped = []
    monkeypatch.setattr(MHT, "step", lambda self, *a, **k: stepped.append(a))
    msg = rf"`reports\[{i}\]\.sensor`: expected 'gmti', 'video' or 'ugs-N', got 'sonar'"
    with pytest.raises(ValueError, match=msg):
        run_pd_tracker(sc, type_tracking=True)
    assert stepped == []
    with pytest.raises(ValueError, match=msg):
        report_scans(sc.reports, GMTISensor(sc.gmti.position))


@pytest.mark.parametrize(
    ("kind", "sensor", "want", "got"), [("gmti", "video", 2, 3), ("video", "gmti", 3, 2)]
)
def test_report_with_a_known_sensor_and_the_wrong_z_shape_is_refused(
    with_video, kind, sensor, want, got
):
    i, sc = _relabelled(with_video, kind, sensor)
    msg = (
        rf"`reports\[{i}\]\.z`: expected shape \({want},\) for a '{sensor}' report, "
        rf"got shape \({got},\)"
    )
    with pytest.raises(ValueError, match=msg):
        run_pd_tracker(sc, type_tracking=False)


def test_clean_reports_pass_the_check(with_video):
    scans = report_scans(with_video.reports, GMTISensor(with_video.gmti.position))
    assert sum(len(s.reports) for s in scans) == len(with_video.reports)
    assert {s.kind for s in scans} >= {"gmti", "video"}

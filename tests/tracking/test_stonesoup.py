"""Stone Soup adapters (hocnet.tracking.stonesoup) against our core and Stone Soup's own parts."""

from __future__ import annotations

import math
import subprocess
import sys
from datetime import datetime, timedelta

import numpy as np
import pytest
import torch

from hocnet.tracking.sprt import sprt_thresholds

pytest.importorskip("stonesoup")

from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.tracker.simple import MultiTargetTracker
from stonesoup.types.array import StateVectors
from stonesoup.types.detection import Clutter, Detection, MissedDetection
from stonesoup.types.hypothesis import SingleHypothesis
from stonesoup.types.prediction import GaussianStatePrediction
from stonesoup.types.state import GaussianState, State
from stonesoup.types.track import Track
from stonesoup.updater.kalman import ExtendedKalmanUpdater

from hocnet.tracking.imm import imm_mix, imm_mixing_probabilities, imm_step
from hocnet.tracking.kalman import constant_velocity, ekf_update, stop_model
from hocnet.tracking.road import (
    RoadNetwork,
    on_segment_probability,
    project_estimate,
    relaxed_road_noise_cov,
    road_constant_velocity,
    segment_constraint,
)
from hocnet.tracking.sensors import GMTISensor, gmti_jacobian, gmti_measure
from hocnet.tracking.stonesoup import (
    ConstantVelocity2D,
    GMTIMeasurementModel,
    IMMHypothesiser,
    IMMInitiator,
    IMMPredictor,
    IMMState,
    IMMStatePrediction,
    IMMStateUpdate,
    IMMUpdater,
    RoadConstrainedCV,
    SPRTDeleter,
    SPRTInitiator,
    StopModel,
    gmti_detection,
    track_score,
)

T0 = datetime(2024, 1, 1)
H_POS = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])


def _assert_close(a, b, tol=1e-10):
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(torch.as_tensor(b, dtype=torch.float64).numpy())
    assert a.shape == b.shape, (a.shape, b.shape)
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol)


def _run_loop(predictor, updater, mu, x, P, zs, dets, dt):
    """Our adapters inside a Stone Soup style loop, one track."""
    state = IMMState.from_modes(mu, x, P, timestamp=T0)
    out = []
    for k, (z, det) in enumerate(zip(zs, dets), start=1):
        t = T0 + timedelta(seconds=k * dt)
        pred = predictor.predict(state, timestamp=t)
        meas = Detection(z.reshape(-1, 1), timestamp=t) if det else MissedDetection(timestamp=t)
        state = updater.update(SingleHypothesis(pred, meas))
        out.append(state)
    return out


class TestIMMAgainstImmStep:
    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_plain_imm(self, seed):
        rng = np.random.default_rng(seed)
        dt = 2.0
        models = [ConstantVelocity2D(sigma_a=0.05), ConstantVelocity2D(sigma_a=1.5)]
        trans = np.array([[0.95, 0.05], [0.2, 0.8]])
        predictor = IMMPredictor(transition_models=models, mode_transition=trans)
        R = np.diag([25.0, 9.0])
        updater = IMMUpdater(measurement_model=LinearGaussian(4, (0, 2), R))
        mu = np.array([0.3, 0.7])
        x = rng.normal(size=(2, 4)) * [10, 1, 10, 1]
        A = rng.normal(size=(2, 4, 4))
        P = A @ A.transpose(0, 2, 1) + 4 * np.eye(4)
        zs = rng.normal(size=(6, 2)) * 30
        states = _run_loop(predictor, updater, mu, x, P, zs, [True] * 6, dt)
        F = torch.stack([constant_velocity(dt, s.sigma_a)[0] for s in models])
        Q = torch.stack([constant_velocity(dt, s.sigma_a)[1] for s in models])
        m, xs, Ps = torch.tensor(mu)[None], torch.tensor(x)[None], torch.tensor(P)[None]
        for z, st in zip(zs, states):
            ref = imm_step(m, xs, Ps, trans, F, Q, torch.tensor(z)[None], H_POS, R)
            assert isinstance(st, IMMStateUpdate)
            _assert_close(st.mode_probabilities, ref.mu[0])
            _assert_close(st.mode_state_vectors, ref.x[0])
            _assert_close(st.mode_covars, ref.P[0])
            _assert_close(st.state_vector.ravel(), ref.x_comb[0])
            _assert_close(st.covar, ref.P_comb[0])
            _assert_close(st.log_likelihood, ref.log_likelihood[0])
            m, xs, Ps = ref.mu, ref.x, ref.P

    @pytest.mark.parametrize("sees_stop", [False, True])
    @pytest.mark.parametrize("seed", [0, 3])
    def test_stop_model_pd_and_missed_detections(self, seed, sees_stop):
        rng = np.random.default_rng(seed)
        dt = 1.0
        models = [StopModel(), ConstantVelocity2D(sigma_a=0.05), ConstantVelocity2D(sigma_a=0.8)]
        trans = np.array([[0.8, 0.1, 0.1], [0.05, 0.9, 0.05], [0.1, 0.1, 0.8]])
        predictor = IMMPredictor(transition_models=models, mode_transition=trans)
        R = 16.0 * np.eye(2)
        updater = IMMUpdater(  # None: the default for a position model, which sees stops
            measurement_model=LinearGaussian(4, (0, 2), R),
            pd=0.85,
            stop_mode=0,
            stop_detectable=None if sees_stop else False,
        )
        mu = np.array([0.2, 0.5, 0.3])
        x = np.tile([0.0, 3.0, 0.0, 1.0], (3, 1)) + rng.normal(size=(3, 4))
        P = np.tile(np.diag([50.0, 4.0, 50.0, 4.0]), (3, 1, 1))
        dets = [True, False, True, True, False, False, True, True]
        zs = np.stack([[3.0 * k, 1.0 * k] for k in range(1, 9)]) + rng.normal(size=(8, 2)) * 4
        states = _run_loop(predictor, updater, mu, x, P, zs, dets, dt)
        F0, Q0 = stop_model(dt)
        Fs = [F0] + [constant_velocity(dt, s.sigma_a)[0] for s in models[1:]]
        Qs = [Q0] + [constant_velocity(dt, s.sigma_a)[1] for s in models[1:]]
        F, Q = torch.stack(Fs), torch.stack(Qs)
        m, xs, Ps = torch.tensor(mu)[None], torch.tensor(x)[None], torch.tensor(P)[None]
        for z, det, st in zip(zs, dets, states):
            ref = imm_step(
                m, xs, Ps, trans, F, Q, torch.tensor(z)[None], H_POS, R,
                detected=torch.tensor([det]), pd=0.85, stop_mode=0, stop_detectable=sees_stop,
            )  # fmt: skip
            assert isinstance(st, IMMStateUpdate if det else IMMStatePrediction)
            _assert_close(st.mode_probabilities, ref.mu[0])
            _assert_close(st.mode_state_vectors, ref.x[0])
            _assert_close(st.mode_covars, ref.P[0])
            _assert_close(st.state_vector.ravel(), ref.x_comb[0])
            _assert_close(st.covar, ref.P_comb[0])
            _assert_close(st.log_likelihood, ref.log_likelihood[0])
            m, xs, Ps = ref.mu, ref.x, ref.P
        # a miss moves probability to the stop model only when the sensor cannot see stops
        if not sees_stop:
            assert states[1].mode_probabilities[0] > states[0].mode_probabilities[0]

    def test_road_models_unrelaxed_and_relaxed(self):
        p0, p1 = np.array([0.0, 0.0]), np.array([300.0, 100.0])
        dt = 5.0
        trans = np.array([[0.9, 0.1], [0.1, 0.9]])
        R = 100.0 * np.eye(2)
        mu = np.array([0.4, 0.6])
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        x = np.stack([[240.0, 8 * u[0], 80.0, 8 * u[1]], [250.0, 7 * u[0], 83.0, 7 * u[1]]])
        P = np.tile(np.diag([400.0, 4.0, 400.0, 4.0]), (2, 1, 1))
        z = np.array([290.0, 97.0])
        for relax in (False, True):
            models = [
                RoadConstrainedCV(p0=p0, p1=p1, sigma_along=0.05, sigma_across=0.05, relax=relax),
                RoadConstrainedCV(p0=p0, p1=p1, sigma_along=0.8, sigma_across=0.4, relax=relax),
            ]
            predictor = IMMPredictor(transition_models=models, mode_transition=trans)
            updater = IMMUpdater(measurement_model=LinearGaussian(4, (0, 2), R))
            (st,) = _run_loop(predictor, updater, mu, x, P, [z], [True], dt)
            # reference: the core functions written out (mix, Q per mode, imm_step)
            m, xs, Ps = torch.tensor(mu)[None], torch.tensor(x)[None], torch.tensor(P)[None]
            _, omega = imm_mixing_probabilities(m, torch.tensor(trans))
            x0, P0 = imm_mix(xs, Ps, omega)
            Fs, Qs = [], []
            for j, mod in enumerate(models):
                F, Q = road_constant_velocity(dt, p0, p1, mod.sigma_along, mod.sigma_across)
                if relax:
                    xp = F @ x0[0, j]
                    p_on = on_segment_probability(xp, F @ P0[0, j] @ F.T + Q, p0, p1)
                    cov = relaxed_road_noise_cov(p0, p1, mod.sigma_along, mod.sigma_across, p_on)
                    Q = constant_velocity(dt, 0.0, acceleration_cov=cov)[1]
                    assert 0.0 < float(p_on) < 0.999  # near the segment end: relaxation active
                Fs.append(F)
                Qs.append(Q)
            ref = imm_step(
                m, xs, Ps, trans, torch.stack(Fs)[None], torch.stack(Qs)[None],
                torch.tensor(z)[None], H_POS, R,
            )  # fmt: skip
            _assert_close(st.mode_probabilities, ref.mu[0])
            _assert_close(st.mode_state_vectors, ref.x[0])
            _assert_close(st.covar, ref.P_comb[0])

    def test_projection_on_the_road(self):
        p0, p1 = (0.0, 0.0), (1000.0, 0.0)
        models = [StopModel(p0=p0, p1=p1), RoadConstrainedCV(p0=p0, p1=p1)]
        predictor = IMMPredictor(transition_models=models, mode_transition=[[0.9, 0.1], [0.1, 0.9]])
        kw = {"measurement_model": LinearGaussian(4, (0, 2), 25 * np.eye(2)), "pd": 0.9}
        plain = IMMUpdater(stop_mode=0, **kw)
        proj = IMMUpdater(stop_mode=0, project=True, **kw)
        x = np.tile([100.0, 10.0, 3.0, 0.5], (2, 1))
        P = np.tile(np.diag([100.0, 4.0, 100.0, 4.0]), (2, 1, 1))
        state = IMMState.from_modes([0.5, 0.5], x, P, timestamp=T0)
        pred = predictor.predict(state, timestamp=T0 + timedelta(seconds=10))
        det = Detection([[201.0], [8.0]], timestamp=pred.timestamp)
        a = plain.update(SingleHypothesis(pred, det))
        b = proj.update(SingleHypothesis(pred, det))
        _assert_close(a.mode_probabilities, b.mode_probabilities, 1e-14)
        D, L = segment_constraint(torch.tensor(p0), torch.tensor(p1))
        xs, Ps = project_estimate(a.mode_state_vectors[1], a.mode_covars[1], D, L)
        _assert_close(b.mode_state_vectors[1], xs, 1e-9)
        _assert_close(b.mode_covars[1], Ps, 1e-9)
        for j in range(2):  # on the road: y = 0 and vy = 0 for both modes (stop: pinv)
            _assert_close(D.numpy() @ b.mode_state_vectors[j], L, 1e-9)

    @pytest.mark.parametrize(
        ("junction", "segments"), [("rotate", True), ("rotate", False), ("none", True)]
    )
    @pytest.mark.parametrize("sensor_name", ["gmti", "video"])
    def test_equals_vsimm_on_one_road_section(self, sensor_name, junction, segments):
        """Road models on a network + projection + MDV-aware PD == vsimm_predict / vsimm_update.

        The road has a 90 degree bend; with the default ``junction="rotate"`` both follow it
        (the moving modes' predictions are carried onto the second segment).
        """
        from hocnet.tracking.sensors import VideoSensor
        from hocnet.tracking.vsimm import VSIMMConfig, vsimm_init, vsimm_predict, vsimm_update

        net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0], [1000.0, 800.0]]])
        # stop, M1 (0.05, 0.05), M2 (0.8, 0.4), relaxed, MDV-aware PD; the default VSIMMConfig
        # (junction="rotate") or the straight CV prediction (junction="none") on both sides
        cfg = VSIMMConfig() if junction == "rotate" else VSIMMConfig(junction="none")
        if sensor_name == "gmti":
            sensor = GMTISensor((-5000.0, -6000.0, 4000.0), 20.0, 0.0008, 1.0, pd=0.9, mdv=1.0)
        else:
            sensor = VideoSensor(10.0, pd=0.9)
        kw = {} if junction == "rotate" else {"junction": "none"}  # "rotate": the default
        models = [
            StopModel(network=net),
            RoadConstrainedCV(network=net, sigma_along=0.05, sigma_across=0.05, **kw),
            RoadConstrainedCV(network=net, sigma_along=0.8, sigma_across=0.4, **kw),
        ]
        predictor = IMMPredictor(transition_models=models, mode_transition=cfg.trans)
        pd_fn = getattr(sensor, "expected_detection_probability", None)
        updater = IMMUpdater(
            pd=0.9,
            stop_mode=0,
            project=True,
            detection_probability=pd_fn if sensor_name == "gmti" else None,
        )
        ref = vsimm_init(net, torch.tensor([[700.0, 9.0, 5.0, 0.0]]), 100 * torch.eye(4), cfg)
        # without mode_segments the first prediction starts from the nearest segment (the same)
        seg0 = ref.segment[0].numpy() if segments else None
        state = IMMState.from_modes(ref.mu[0], ref.x[0], ref.P[0], timestamp=T0, mode_segments=seg0)
        rng = np.random.default_rng(7)
        rotated = []
        truth = np.array([700.0, 10.0, 0.0, 0.0])
        for k, det in enumerate([True, True, False, True, True, False, True], start=1):
            truth = truth + 10.0 * np.array([truth[1], 0, truth[3], 0])
            if truth[0] > 1000.0:  # round the bend onto the second segment
                truth = np.array([1000.0, 0.0, truth[0] - 1000.0, 10.0])
            z = sensor.measure(torch.tensor(truth)) + torch.tensor(
                rng.normal(size=sensor.dim) * [5.0, 5.0, 0.5][: sensor.dim]
            )
            pred_ref = vsimm_predict(ref, net, cfg, 10.0 * k)
            ref, _ = vsimm_update(
                ref, pred_ref, z[None], sensor, net, cfg, detected=torch.tensor([det])
            )
            t = T0 + timedelta(seconds=10 * k)
            pred = predictor.predict(state, timestamp=t)
            _assert_close(pred.mode_state_vectors, pred_ref.x[0], 1e-9)
            _assert_close(pred.mode_covars, pred_ref.P[0], 1e-9)
            _assert_close(pred.mode_segments, pred_ref.segment[0])
            eye = torch.eye(4, dtype=torch.float64)
            rotated.append(bool((pred_ref.T[0] - eye).abs().amax() > 1e-12))
            if det:
                if sensor_name == "gmti":
                    mm = GMTIMeasurementModel(
                        sensor_position=sensor.position,
                        noise_covar=sensor.covariance(z).numpy(),
                        reference=z[:2].tolist(),
                        ground=sensor.range_rate == "ground",
                    )
                else:
                    mm = LinearGaussian(4, (0, 2), sensor.covariance(z).numpy())
                meas = Detection(z.numpy().reshape(-1, 1), timestamp=t, measurement_model=mm)
            else:
                meas = MissedDetection(timestamp=t)
            state = updater.update(SingleHypothesis(pred, meas))
            _assert_close(state.mode_probabilities, ref.mu[0], 1e-9)
            _assert_close(state.mode_state_vectors, ref.x[0], 1e-9)
            _assert_close(state.mode_covars, ref.P[0], 1e-9)
            _assert_close(state.mode_segments, ref.segment[0])
        assert truth[2] > 0  # the scene did go round the bend
        # the junction rotation did act (once, at the bend) in the compared VS-IMM
        assert sum(rotated) == (1 if junction == "rotate" else 0), rotated

    @staticmethod
    def _bend_errors(junction):
        """Noise-free position reports of a target at 10 m/s round a 90 degree bend, 10 s scans."""
        net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0], [1000.0, 800.0]]])
        models = [
            StopModel(network=net),
            RoadConstrainedCV(network=net, sigma_along=0.05, sigma_across=0.05, junction=junction),
            RoadConstrainedCV(network=net, sigma_along=0.8, sigma_across=0.4, junction=junction),
        ]
        trans = [[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]
        predictor = IMMPredictor(transition_models=models, mode_transition=trans)
        mm = LinearGaussian(4, (0, 2), 25.0 * np.eye(2))
        updater = IMMUpdater(measurement_model=mm, pd=0.9, stop_mode=0, project=True)
        x = np.tile([600.0, 10.0, 0.0, 0.0], (3, 1))
        P = np.tile(np.diag([25.0, 4.0, 25.0, 4.0]), (3, 1, 1))
        state = IMMState.from_modes([0.1, 0.45, 0.45], x, P, timestamp=T0)
        errors = []
        for k in range(1, 11):
            s = 600.0 + 100.0 * k  # distance along the road
            truth = np.array([s, 0.0]) if s <= 1000.0 else np.array([1000.0, s - 1000.0])
            t = T0 + timedelta(seconds=10 * k)
            pred = predictor.predict(state, timestamp=t)
            det = Detection(truth.reshape(-1, 1), timestamp=t)
            state = updater.update(SingleHypothesis(pred, det))
            errors.append(float(np.hypot(*(state.state_vector.ravel()[[0, 2]] - truth))))
        return errors

    def test_imm_follows_a_90_degree_bend(self):
        """With the junction transition the track rounds the bend; the straight CV loses it."""
        rotate, straight = self._bend_errors("rotate"), self._bend_errors("none")
        assert max(rotate) < 1.0, rotate  # measured 0.0 m at every scan
        assert max(straight[:4]) < 1.0  # identical up to the bend (scan 4 at the node)
        # measured: 100, 200, ..., 600 m after the bend (the track stays on the first road)
        assert min(straight[4:]) > 50.0 and straight[-1] > 500.0, straight

    def test_road_model_junction_transition_is_vsimms(self):
        from hocnet.tracking.vsimm import follow_section, junction_transition

        net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])
        m = RoadConstrainedCV(network=net)
        dt = timedelta(seconds=5)
        x0 = np.array([[90.0, 80.0, 30.0], [10.0, 10.0, 2.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
        prior = State(StateVectors(x0))
        # a batch of columns: past the bend (2) or not (1)
        out = m.function(prior, time_interval=dt)
        assert isinstance(out, StateVectors) and out.shape == (4, 3)
        F = constant_velocity(5.0, 0.0)[0]
        xt = torch.tensor(x0.T)
        xp = xt @ F.T
        old = net.locate(xt).segment[:, None]
        seg = follow_section(net, old, net.locate(xp).segment[:, None], xt[:, None], xp[:, None])
        T, b = junction_transition(net, old, seg, xt[:, None], xp[:, None])
        ref = (T[:, 0] @ xp[..., None])[..., 0] + b[:, 0]
        _assert_close(out.T, ref, 1e-12)
        assert seg[:, 0].tolist() == [1, 1, 0]
        # matrix(prior=) is T F, function = T F x + b, per column
        for i in range(3):
            col = State(x0[:, i : i + 1])
            _assert_close(m.matrix(time_interval=dt, prior=col), T[i, 0] @ F, 1e-12)
            _assert_close(m.function(col, time_interval=dt).ravel(), ref[i], 1e-12)
            assert m.active_segment(col, time_interval=dt) == int(seg[i, 0])
        # the segment before the prediction decides: from segment 1 (whose node ahead at this
        # velocity is its far end) the prediction is not past a node: nearest segment, no rotation
        col = State(x0[:, :1])
        assert m.active_segment(col, time_interval=dt, segment=1) == 0
        _assert_close(m.matrix(time_interval=dt, prior=col, segment=1), F, 1e-15)
        # junction="none": the straight prediction on the nearest segment (0 for a 90 deg bend)
        straight = RoadConstrainedCV(network=net, junction="none")
        _assert_close(straight.function(col, time_interval=dt).ravel(), xp[0], 1e-12)
        assert straight.active_segment(col, time_interval=dt) == 0
        with pytest.raises(ValueError, match="`junction`"):
            RoadConstrainedCV(network=net, junction="turn")

    def test_stonesoup_own_predictors_and_road_models(self):
        """The documented limitation: Stone Soup's predictors give ``covar`` no prior."""
        from stonesoup.predictor.kalman import ExtendedKalmanPredictor

        net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])
        prior = GaussianState([[90.0], [10.0], [0.0], [0.0]], np.eye(4), timestamp=T0)
        t1 = T0 + timedelta(seconds=5)
        for cls in (KalmanPredictor, ExtendedKalmanPredictor):
            with pytest.raises(ValueError, match="`prior`"):  # never a silent straight prediction
                cls(RoadConstrainedCV(network=net)).predict(prior, timestamp=t1)
        # one segment (no junction): Stone Soup's KalmanPredictor equals ours without relaxation
        seg = RoadConstrainedCV(p0=(0.0, 0.0), p1=(100.0, 0.0), relax=False)
        ours = IMMPredictor(transition_models=[seg], mode_transition=[[1.0]]).predict(
            prior, timestamp=t1
        )
        theirs = KalmanPredictor(seg).predict(prior, timestamp=t1)
        _assert_close(ours.state_vector, theirs.state_vector, 1e-12)
        _assert_close(ours.covar, theirs.covar, 1e-12)
        assert ours.mode_segments.tolist() == [-1]  # no network segment

    def test_network_segment_follows_the_prediction(self):
        net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])
        m = RoadConstrainedCV(network=net, relax=False)
        before = GaussianState([[50.0], [0.0], [0.0], [0.0]], 100 * np.eye(4), timestamp=T0)
        after = GaussianState([[100.0], [0.0], [300.0], [0.0]], 100 * np.eye(4), timestamp=T0)
        D0, _ = m.constraint(before)
        D1, _ = m.constraint(after)
        assert D0[0].tolist() == [0.0, 0.0, 1.0, 0.0]  # y = 0 on the first segment
        assert D1[0].abs().tolist() == [1.0, 0.0, 0.0, 0.0]  # x = 100 on the second
        Q = m.covar(time_interval=timedelta(seconds=1), prior=after)
        assert Q[1, 1] < Q[3, 3]  # along-road (y) noise larger on the second segment

    def test_gaussian_prior_and_stonesoup_kalman_predictor(self):
        models = [ConstantVelocity2D(sigma_a=0.3)]
        predictor = IMMPredictor(transition_models=models, mode_transition=[[1.0]])
        prior = GaussianState([[0.0], [1.0], [5.0], [2.0]], np.eye(4), timestamp=T0)
        t1 = T0 + timedelta(seconds=3)
        ours = predictor.predict(Track([prior]), timestamp=t1)
        theirs = KalmanPredictor(models[0]).predict(prior, timestamp=t1)
        _assert_close(ours.state_vector, theirs.state_vector, 1e-12)
        _assert_close(ours.covar, theirs.covar, 1e-12)
        assert isinstance(ours, GaussianStatePrediction.__mro__[1])  # a Stone Soup Prediction
        mix = ours.to_mixture()
        assert len(mix) == 1 and float(mix[0].weight) == pytest.approx(1.0)

    def test_gaussian_mixture_prior_round_trip(self):
        models = [StopModel(), ConstantVelocity2D(sigma_a=0.5)]
        predictor = IMMPredictor(transition_models=models, mode_transition=[[0.9, 0.1], [0.2, 0.8]])
        x = np.array([[0.0, 0.0, 1.0, 0.0], [2.0, 1.0, 0.0, -1.0]])
        P = np.stack([np.eye(4), 2 * np.eye(4)])
        st = IMMState.from_modes([0.3, 0.7], x, P, timestamp=T0)
        mix = st.to_mixture()
        assert [float(c.weight) for c in mix] == pytest.approx([0.3, 0.7])
        t1 = T0 + timedelta(seconds=2)
        a, b = predictor.predict(st, timestamp=t1), predictor.predict(mix, timestamp=t1)
        _assert_close(a.mode_probabilities, b.mode_probabilities, 1e-14)
        _assert_close(a.mode_state_vectors, b.mode_state_vectors, 1e-14)
        _assert_close(a.covar, b.covar, 1e-14)

    def test_nonlinear_transition_model_equals_stonesoup_ekf_predictor(self):
        from stonesoup.models.transition.nonlinear import ConstantTurn
        from stonesoup.predictor.kalman import ExtendedKalmanPredictor

        ct = ConstantTurn(linear_noise_coeffs=np.array([0.1, 0.1]), turn_noise_coeff=0.01)
        predictor = IMMPredictor(transition_models=[ct], mode_transition=[[1.0]])
        prior = GaussianState([[0.0], [10.0], [0.0], [2.0], [0.05]], np.eye(5), timestamp=T0)
        t1 = T0 + timedelta(seconds=4)
        ours = predictor.predict(prior, timestamp=t1)
        theirs = ExtendedKalmanPredictor(ct).predict(prior, timestamp=t1)
        _assert_close(ours.state_vector, theirs.state_vector, 1e-10)
        _assert_close(ours.covar, theirs.covar, 1e-10)

    def test_bad_input(self):
        with pytest.raises(ValueError, match="`mode_transition`"):
            IMMPredictor(transition_models=[StopModel()], mode_transition=[[0.5, 0.5]])
        with pytest.raises(ValueError, match="rows summing to 1"):
            IMMPredictor(
                transition_models=[StopModel(), StopModel()],
                mode_transition=[[0.5, 0.4], [0.5, 0.5]],
            )
        predictor = IMMPredictor(transition_models=[StopModel()], mode_transition=[[1.0]])
        with pytest.raises(ValueError, match="`timestamp`"):
            predictor.predict(GaussianState([[0.0]] * 4, np.eye(4), timestamp=T0))
        upd = IMMUpdater(measurement_model=LinearGaussian(4, (0, 2), np.eye(2)))
        pred = predictor.predict(GaussianState([[0.0]] * 4, np.eye(4), timestamp=T0), timestamp=T0)
        with pytest.raises(ValueError, match="`pd`"):
            upd.update(SingleHypothesis(pred, MissedDetection(timestamp=T0)))
        with pytest.raises(TypeError, match="`hypothesis`"):
            gp = GaussianStatePrediction([[0.0]] * 4, np.eye(4), timestamp=T0)
            upd.update(SingleHypothesis(gp, Detection([[0.0], [0.0]], timestamp=T0)))
        with pytest.raises(ValueError, match="`p0`"):
            RoadConstrainedCV()

    def test_predict_measurement_moments(self):
        models = [ConstantVelocity2D(sigma_a=0.1), ConstantVelocity2D(sigma_a=1.0)]
        predictor = IMMPredictor(transition_models=models, mode_transition=[[0.9, 0.1], [0.1, 0.9]])
        R = 4 * np.eye(2)
        upd = IMMUpdater(measurement_model=LinearGaussian(4, (0, 2), R))
        x = np.array([[0.0, 1.0, 0.0, 0.0], [10.0, 0.0, 5.0, 1.0]])
        P = np.tile(np.eye(4), (2, 1, 1))
        st = IMMState.from_modes([0.25, 0.75], x, P, timestamp=T0)
        pred = predictor.predict(st, timestamp=T0 + timedelta(seconds=1))
        mp = upd.predict_measurement(pred)
        # linear H: the moments are those of H times the combined Gaussian
        _assert_close(mp.state_vector, H_POS @ pred.state_vector, 1e-12)
        _assert_close(mp.covar, H_POS @ pred.covar @ H_POS.T + R, 1e-12)
        _assert_close(mp.cross_covar, pred.covar @ H_POS.T, 1e-12)


class TestGMTI:
    POS = (-5000.0, -6000.0, 4000.0)

    def test_jacobian_against_finite_differences(self):
        rng = np.random.default_rng(0)
        model = GMTIMeasurementModel(sensor_position=self.POS, noise_covar=np.eye(3))
        for _ in range(5):
            x = rng.normal(size=4) * [2000, 10, 2000, 10]
            J = model.jacobian(State(x.reshape(-1, 1)))
            num = np.zeros((3, 4))
            for i in range(4):
                e = np.zeros(4)
                e[i] = 1e-3 * max(1.0, abs(x[i]))
                fp = model.function(State((x + e).reshape(-1, 1))).ravel()
                fm = model.function(State((x - e).reshape(-1, 1))).ravel()
                num[:, i] = (fp - fm) / (2 * e[i])
            np.testing.assert_allclose(J, num, rtol=1e-6, atol=1e-9)
            _assert_close(J, gmti_jacobian(torch.tensor(x), torch.tensor(self.POS)), 1e-14)

    @pytest.mark.parametrize("joseph", [False, True])
    def test_stonesoup_ekf_updater_equals_ekf_update(self, joseph):
        sensor = GMTISensor(self.POS, 20.0, 0.0008, 1.0)
        x = np.array([3000.0, 8.0, 2500.0, -5.0])
        P = np.diag([400.0, 9.0, 400.0, 9.0])
        z, R = sensor.from_report(sensor.measure(torch.tensor(x)).new_tensor([11700.0, 0.95, 6.5]))
        model = GMTIMeasurementModel(sensor_position=self.POS, noise_covar=R.numpy())
        updater = ExtendedKalmanUpdater(measurement_model=model, use_joseph_cov=joseph)
        pred = GaussianStatePrediction(x.reshape(-1, 1), P, timestamp=T0)
        post = updater.update(
            SingleHypothesis(pred, Detection(z.numpy().reshape(-1, 1), timestamp=T0))
        )
        xt = torch.tensor(x)
        pos = torch.tensor(self.POS)
        xr, Pr, _ = ekf_update(
            xt, torch.tensor(P), z, gmti_measure(xt, pos), gmti_jacobian(xt, pos), R, joseph=joseph
        )
        _assert_close(post.state_vector.ravel(), xr, 1e-9)
        _assert_close(post.covar, Pr, 1e-9)

    def test_aekf_detection_matches_sensor_linearize(self):
        sensor = GMTISensor(self.POS, 20.0, 0.0008, 1.0)
        det = gmti_detection(sensor, [11700.0, 0.95, 6.5], T0)
        z, R = sensor.from_report(torch.tensor([11700.0, 0.95, 6.5], dtype=torch.float64))
        _assert_close(det.state_vector.ravel(), z, 1e-12)
        _assert_close(det.measurement_model.covar(), R, 1e-12)
        x = np.array([3000.0, 8.0, 2500.0, -5.0])
        hx, H, _ = sensor.linearize(torch.tensor(x), z)
        st = State(x.reshape(-1, 1))
        _assert_close(det.measurement_model.function(st).ravel(), hx, 1e-12)
        _assert_close(det.measurement_model.jacobian(st), H, 1e-12)
        # the IMM updater uses the detection's own model
        predictor = IMMPredictor(
            transition_models=[ConstantVelocity2D(sigma_a=0.5)], mode_transition=[[1.0]]
        )
        prior = GaussianState(x.reshape(-1, 1), np.diag([400.0, 9, 400, 9]), timestamp=T0)
        pred = predictor.predict(prior, timestamp=T0)
        post = IMMUpdater().update(SingleHypothesis(pred, det))
        xr, _, _ = ekf_update(
            torch.tensor(pred.mode_state_vectors[0]), torch.tensor(pred.mode_covars[0]), z,
            hx, H, R,
        )  # fmt: skip
        _assert_close(post.state_vector.ravel(), xr, 1e-10)

    def test_noise_and_vectors(self):
        model = GMTIMeasurementModel(sensor_position=self.POS, noise_covar=np.eye(3), seed=1)
        sv = np.array([[1000.0, 2000.0], [1.0, 2.0], [500.0, 600.0], [0.0, 1.0]])
        out = model.function(StateVectors(sv))  # a batch of states, (4, N)
        assert out.shape == (3, 2)
        _assert_close(out, gmti_measure(torch.tensor(sv.T), torch.tensor(self.POS)).T, 1e-12)
        noisy = model.function(State(sv[:, :1]), noise=True)
        assert noisy.shape == (3, 1) and not np.allclose(noisy, out[:, :1])
        with pytest.raises(ValueError, match="`noise_covar`"):
            GMTIMeasurementModel(sensor_position=self.POS, noise_covar=np.eye(2))


def _scene(seed, n_scans=30, clutter_rate=3.0):
    """Two targets 60 m apart moving in parallel, then one turning away; position reports."""
    rng = np.random.default_rng(seed)
    truths = [np.array([0.0, 10.0, 0.0, 0.0]), np.array([0.0, 10.0, 60.0, 0.0])]
    F = constant_velocity(1.0, 0.0)[0].numpy()
    R = 25.0 * np.eye(2)
    model = LinearGaussian(4, (0, 2), R)
    scans, paths = [], [[], []]
    for k in range(1, n_scans + 1):
        t = T0 + timedelta(seconds=k)
        dets = set()
        for i in range(2):
            truths[i] = F @ truths[i]
            if i == 1 and k == 15:
                truths[i][3] = 4.0  # the second target turns off
            paths[i].append(truths[i].copy())
            if rng.random() < 0.9:
                z = truths[i][[0, 2]] + rng.normal(size=2) * 5.0
                dets.add(
                    Detection(
                        z.reshape(-1, 1), timestamp=t, measurement_model=model, metadata={"id": i}
                    )
                )
        for _ in range(rng.poisson(clutter_rate)):
            c = np.array([rng.uniform(-100, 450), rng.uniform(-200, 300)])
            dets.add(Clutter(c.reshape(-1, 1), timestamp=t, measurement_model=model))
        scans.append((t, dets))
    return scans, np.array(paths), model


def _tracker(model, fa, missed_pd=None):
    models = [StopModel(), ConstantVelocity2D(sigma_a=0.1), ConstantVelocity2D(sigma_a=2.0)]
    predictor = IMMPredictor(
        transition_models=models,
        mode_transition=[[0.8, 0.1, 0.1], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]],
    )
    # the printed 24.31 (a GMTI-like sensor that cannot see a stopped target)
    updater = IMMUpdater(measurement_model=model, pd=0.9, stop_mode=0, stop_detectable=False)
    hyp = IMMHypothesiser(
        predictor=predictor, updater=updater, false_alarm_density=fa, gate_threshold=13.8
    )
    assoc = GNNWith2DAssignment(hyp)
    prior = GaussianState([[0.0], [0.0], [0.0], [0.0]], np.diag([0.0, 100.0, 0.0, 100.0]))
    init = IMMInitiator(prior_state=prior, mode_probabilities=[0.1, 0.45, 0.45])
    kw = {"false_alarm_density": fa, "new_target_density": fa / 10, "missed_pd": missed_pd}
    initiator = SPRTInitiator(initiator=init, data_associator=assoc, updater=updater, **kw)
    deleter = SPRTDeleter(**kw)
    return initiator, deleter, assoc, updater


class TestMultiTargetTracker:
    @staticmethod
    def _run(seed, missed_pd):
        scans, paths, model = _scene(seed)
        fa = 3.0 / (550.0 * 500.0)  # clutter rate / surveillance area, 1/m^2
        initiator, deleter, assoc, updater = _tracker(model, fa, missed_pd)
        tracker = MultiTargetTracker(
            initiator=initiator,
            deleter=deleter,
            detector=scans,
            data_associator=assoc,
            updater=updater,
        )
        tracks, max_tentative_age = set(), 0
        for _, current in tracker:
            tracks = current
            ages = [len(tr.states) for tr in initiator.holding_tracks]
            max_tentative_age = max([max_tentative_age, *ages])
        est = [np.asarray(tr.state_vector, float).ravel() for tr in tracks]
        for truth in paths[:, -1]:
            err = [np.hypot(*(e[[0, 2]] - truth[[0, 2]])) for e in est]
            assert min(err) < 15.0, (seed, missed_pd, err)
        # one track per target, no confirmed false track alive at the end
        assert len(tracks) == 2, (seed, missed_pd, len(tracks))
        ids = []
        for tr in tracks:
            assert all(isinstance(s, IMMState) for s in tr.states)
            assert track_score(tr, fa, fa / 10, missed_pd=missed_pd) > deleter.lower
            # track purity: the detections of a track come from one target (clutter has no id)
            src = [
                s.hypothesis.measurement.metadata.get("id")
                for s in tr.states
                if hasattr(s, "hypothesis")
            ]
            best = max(set(src), key=src.count)
            assert best is not None and src.count(best) >= 0.9 * len(src), (seed, src)
            assert len(src) >= 20  # confirmed early and kept updated
            ids.append(best)
        assert sorted(ids) == [0, 1]
        return max_tentative_age

    @pytest.mark.parametrize("seed", [0, 1])
    def test_two_targets_tracked(self, seed):
        chapter = self._run(seed, None)
        single = self._run(seed, 0.9)
        # ln Lambda_miss -> 0 as the stop mode takes over, so tentative tracks born on false
        # alarms outlive those scored with ln(1 - PD) per miss (measured: 15 vs 4, 7 vs 4 scans)
        assert chapter > single
        assert single <= 6


def test_stonesoup_hypothesiser_initiator_deleter_with_our_imm():
    """Only our predictor and updater; everything else is Stone Soup's own."""
    from stonesoup.deleter.error import CovarianceBasedDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis

    scans, paths, model = _scene(4, clutter_rate=1.0)
    predictor = IMMPredictor(
        transition_models=[ConstantVelocity2D(sigma_a=0.1), ConstantVelocity2D(sigma_a=2.0)],
        mode_transition=[[0.9, 0.1], [0.1, 0.9]],
        initial_mode_probabilities=[0.5, 0.5],
    )
    updater = IMMUpdater(measurement_model=model)
    hyp = DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=4.0)
    assoc = GNNWith2DAssignment(hyp)
    deleter = CovarianceBasedDeleter(covar_trace_thresh=2000.0)
    prior = GaussianState([[0.0], [0.0], [0.0], [0.0]], np.diag([0.0, 100.0, 0.0, 100.0]))
    initiator = MultiMeasurementInitiator(
        prior_state=prior,
        measurement_model=model,
        deleter=deleter,
        data_associator=assoc,
        updater=updater,
        min_points=3,
    )
    tracker = MultiTargetTracker(
        initiator=initiator,
        deleter=deleter,
        detector=scans,
        data_associator=assoc,
        updater=updater,
    )
    tracks = set()
    for _, current in tracker:
        tracks = current
    est = [np.asarray(tr.state_vector, float).ravel() for tr in tracks]
    for truth in paths[:, -1]:
        assert min(np.hypot(*(e[[0, 2]] - truth[[0, 2]])) for e in est) < 15.0
    assert any(isinstance(s, IMMStateUpdate) for tr in tracks for s in tr.states)


class TestTrackScore:
    def test_increments(self):
        fa, nt = 1e-4, 1e-5
        s0 = IMMState.from_modes([1.0], [[0.0]], [[[1.0]]], timestamp=T0)
        upd = IMMStateUpdate.from_modes(
            [1.0], [[0.0]], [[[1.0]]], timestamp=T0, log_likelihood=-3.0, hypothesis=None
        )
        miss = IMMStatePrediction.from_modes(
            [1.0], [[0.0]], [[[1.0]]], timestamp=T0, log_likelihood=np.log(0.1)
        )
        hist = track_score(Track([s0, upd, miss]), fa, nt, history=True)
        L0 = np.log(nt / fa)
        np.testing.assert_allclose(
            hist, [L0, L0 - 3.0 - np.log(fa), L0 - 3.0 - np.log(fa) + np.log(0.1)]
        )
        printed = track_score(Track([s0]), fa, nt, initial_score="printed")
        assert printed == pytest.approx(np.log(fa / (fa + nt)))
        with pytest.raises(ValueError, match="`initial_score`"):
            track_score(Track([s0]), fa, nt, initial_score="other")

    def test_deleter(self):
        fa, nt = 1e-4, 1e-5
        d = SPRTDeleter(false_alarm_density=fa, new_target_density=nt)
        s0 = IMMState.from_modes([1.0], [[0.0]], [[[1.0]]], timestamp=T0)

        def miss(p):
            return IMMStatePrediction.from_modes(
                [1.0], [[0.0]], [[[1.0]]], timestamp=T0, log_likelihood=np.log(p)
            )

        assert not d.check_for_deletion(Track([s0, miss(0.9)]))
        # one rule with the MHT: deleted when L <= max L - drop, drop = ln(upper / lower)
        lower, upper = sprt_thresholds(1e-3, 1e-3)
        assert d.lower == lower and d.drop == pytest.approx(upper - lower)
        n = math.ceil(d.drop / -math.log(0.1))  # misses of ln 0.1 needed to fall by drop
        assert not d.check_for_deletion(Track([s0] + [miss(0.1)] * (n - 1)))
        assert d.check_for_deletion(Track([s0] + [miss(0.1)] * n))
        # the score ln lower alone no longer deletes (the MHT applies it to tentative tracks)
        assert track_score(Track([s0] + [miss(0.1)] * 2), fa, nt) <= lower + 2.31
        with pytest.raises(ValueError, match="alpha \\+ beta < 1"):
            SPRTDeleter(false_alarm_density=fa, new_target_density=nt, alpha=0.6, beta=0.5)


def test_hocnet_tracking_does_not_import_stonesoup():
    code = (
        "import sys, hocnet.tracking\n"
        "print('stonesoup' in sys.modules)\n"
        "sys.modules['stonesoup'] = None  # as if it were not installed\n"
        "try:\n"
        "    import hocnet.tracking.stonesoup\n"
        "except ImportError as e:\n"
        "    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    lines = out.stdout.strip().splitlines()
    assert lines[0] == "False"
    assert "pip install stonesoup" in lines[1]

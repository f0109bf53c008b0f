import math
from dataclasses import dataclass

import numpy as np
import pytest

from hocnet.tracking import evaluation
from hocnet.tracking.evaluation import (
    FALSE_ALARM,
    NO_MEASUREMENT,
    NO_TYPE,
    EstimatedTrack,
    assign_tracks,
    gospa,
    gospa_numpy,
    monte_carlo_metrics,
    target_metrics,
)
from hocnet.tracking.scenario import pd_ground_truth

HAVE_STONESOUP = evaluation._have_stonesoup()


@dataclass
class Truth:
    times: np.ndarray
    positions: np.ndarray
    video_class: int = 0


def line(y, n=11, video_class=0):
    t = np.arange(float(n))
    return Truth(t, np.stack([t, np.full(n, float(y))], 1), video_class)


def perfect(truth, step=1):
    return {
        f"trk{tid}": EstimatedTrack(
            tr.times[::step],
            tr.positions[::step],
            [tid] * len(tr.times[::step]),
            [tr.video_class] * len(tr.times[::step]),
        )
        for tid, tr in truth.items()
    }


class TestEstimatedTrack:
    def test_defaults(self):
        trk = EstimatedTrack([0.0, 1.0], [[0, 0], [1, 1]])
        assert trk.truth_ids.tolist() == [NO_MEASUREMENT] * 2
        assert trk.types.tolist() == [NO_TYPE] * 2
        assert trk.duration == 1.0

    def test_none_is_false_alarm(self):
        assert EstimatedTrack([0.0], [[0, 0]], [None]).truth_ids.tolist() == [FALSE_ALARM]

    def test_empty(self):
        trk = EstimatedTrack([], [])
        assert trk.positions.shape == (0, 2) and trk.duration == 0.0

    def test_bad(self):
        with pytest.raises(ValueError, match="`positions`"):
            EstimatedTrack([0.0, 1.0], [[0, 0]])
        with pytest.raises(ValueError, match="`times`"):
            EstimatedTrack([1.0, 0.0], [[0, 0], [1, 1]])
        with pytest.raises(ValueError, match="`times`"):
            EstimatedTrack([0.0, np.nan], [[0, 0], [1, 1]])
        with pytest.raises(ValueError, match="`truth_ids`"):
            EstimatedTrack([0.0, 1.0], [[0, 0], [1, 1]], [1])
        with pytest.raises(TypeError, match="`types`"):
            EstimatedTrack([0.0], [[0, 0]], [1], [0.5])


class TestAssign:
    def test_majority(self):
        tracks = {
            "a": EstimatedTrack(np.arange(5.0), np.zeros((5, 2)), [2, 2, 1, FALSE_ALARM, 2]),
            "b": EstimatedTrack(np.arange(4.0), np.zeros((4, 2)), [3, 1, 1, 3]),  # tie -> 1
            "c": EstimatedTrack(np.arange(3.0), np.zeros((3, 2)), [None, None, NO_MEASUREMENT]),
        }
        assert assign_tracks(tracks) == {"a": 2, "b": 1, "c": None}

    def test_bad(self):
        with pytest.raises(TypeError, match="`tracks`"):
            assign_tracks({"a": np.zeros((3, 2))})
        with pytest.raises(TypeError, match="`tracks`"):
            assign_tracks([1, 2])


class TestPerfectTracker:
    def test_toy(self):
        truth = {1: line(0.0), 2: line(50.0, video_class=3)}
        m = target_metrics(truth, perfect(truth))
        for tid in truth:
            assert m[tid].length_ratio == 1.0
            assert m[tid].armse == 0.0
            assert m[tid].track_purity == 1.0
            assert m[tid].type_purity == 1.0
            assert m[tid].n_tracks == 1.0

    def test_pd_scenario_every_10_s(self):
        truth = pd_ground_truth()
        m = target_metrics(truth, perfect(truth, step=10))
        for tid, tr in truth.items():
            # a track sampled every 10 s ends up to 9 s before the target
            expected = (tr.times[::10][-1] - tr.times[0]) / (tr.times[-1] - tr.times[0])
            assert m[tid].length_ratio == pytest.approx(expected)
            assert m[tid].armse == 0.0
            assert m[tid].track_purity == 1.0
            assert m[tid].type_purity == 1.0

    def test_coasting_does_not_lower_purity(self):
        truth = {1: line(0.0)}
        ids = [1, NO_MEASUREMENT] * 5 + [1]
        m = target_metrics(truth, {"a": EstimatedTrack(truth[1].times, truth[1].positions, ids)})
        assert m[1].track_purity == 1.0

    def test_no_types_is_nan(self):
        truth = {1: line(0.0)}
        trk = EstimatedTrack(truth[1].times, truth[1].positions, [1] * 11)
        assert math.isnan(target_metrics(truth, {"a": trk})[1].type_purity)


class TestSwappedIdentity:
    """Two parallel targets 10 m apart; the tracks swap at t = 7 (hand-computed values)."""

    @pytest.fixture
    def case(self):
        truth = {1: line(0.0), 2: line(10.0, video_class=2)}
        t = truth[1].times
        swap = t >= 7
        pa = np.where(swap[:, None], truth[2].positions, truth[1].positions)
        pb = np.where(swap[:, None], truth[1].positions, truth[2].positions)
        ids_a = np.where(swap, 2, 1)
        ids_b = np.where(swap, 1, 2)
        types_a = np.where(swap, 2, 0)  # declares the type of the target it follows
        tracks = {
            "a": EstimatedTrack(t, pa, ids_a, types_a),
            "b": EstimatedTrack(t, pb, ids_b, np.where(swap, 0, 2)),
        }
        return truth, tracks

    def test_assignment(self, case):
        _, tracks = case
        assert assign_tracks(tracks) == {"a": 1, "b": 2}

    def test_metrics(self, case):
        truth, tracks = case
        m = target_metrics(truth, tracks)
        for tid in (1, 2):
            assert m[tid].track_purity == pytest.approx(7 / 11)
            assert m[tid].type_purity == pytest.approx(7 / 11)
            # error 0 at 7 times, 10 m at 4 times
            assert m[tid].armse == pytest.approx(40 / 11)
            assert m[tid].length_ratio == 1.0

    def test_gospa_sees_no_error_without_labels(self, case):
        truth, tracks = case
        g = gospa(truth, tracks, backend="numpy")
        np.testing.assert_allclose(g["distance"], 0.0)


class TestMonteCarlo:
    def test_length_ratio_averages_runs(self):
        truth = {1: line(0.0)}
        m = monte_carlo_metrics(truth, [perfect(truth), {}])
        assert m[1].length_ratio == 0.5
        assert m[1].track_purity == 1.0  # only runs with a track
        assert m[1].armse == 0.0
        assert m[1].n_tracks == 0.5

    def test_armse_is_time_average_of_rms_over_runs(self):
        truth = {1: line(0.0)}
        t, p = truth[1].times, truth[1].positions
        run1 = {"a": EstimatedTrack(t, p + np.array([0.0, 3.0]), [1] * 11)}
        run2 = {"a": EstimatedTrack(t, p + np.array([0.0, 4.0]), [1] * 11)}
        m = monte_carlo_metrics(truth, [run1, run2])
        assert m[1].armse == pytest.approx(math.sqrt((9 + 16) / 2))

    def test_armse_varying_in_time(self):
        truth = {1: line(0.0, n=3)}
        t, p = truth[1].times, truth[1].positions
        trk = EstimatedTrack(t, p + np.array([[0, 1.0], [0, 2.0], [0, 6.0]]), [1, 1, 1])
        assert target_metrics(truth, {"a": trk})[1].armse == pytest.approx(3.0)

    def test_lengths(self):
        truth = {1: line(0.0)}
        t, p = truth[1].times, truth[1].positions
        tracks = {
            "a": EstimatedTrack(t[:5], p[:5], [1] * 5),  # 0..4: 4 s
            "b": EstimatedTrack(t[6:], p[6:], [1] * 5),  # 6..10: 4 s
        }
        assert target_metrics(truth, tracks)[1].length_ratio == pytest.approx(0.4)
        assert target_metrics(truth, tracks, length="max")[1].length_ratio == pytest.approx(0.4)
        assert target_metrics(truth, tracks, length="sum")[1].length_ratio == pytest.approx(0.8)
        assert target_metrics(truth, tracks)[1].n_tracks == 2

    def test_sum_length_not_clipped_for_duplicates(self):
        """Documented: two overlapping tracks over the whole life give sum = 2, mean = max = 1."""
        truth = {1: line(0.0)}
        t, p = truth[1].times, truth[1].positions
        tracks = {"a": EstimatedTrack(t, p, [1] * 11), "b": EstimatedTrack(t, p, [1] * 11)}
        assert target_metrics(truth, tracks, length="sum")[1].length_ratio == pytest.approx(2.0)
        assert target_metrics(truth, tracks)[1].length_ratio == pytest.approx(1.0)
        assert target_metrics(truth, tracks, length="max")[1].length_ratio == pytest.approx(1.0)

    def test_track_outside_lifetime_clipped(self):
        truth = {1: line(0.0)}
        t = np.arange(-5.0, 16.0)
        trk = EstimatedTrack(t, np.stack([t, np.zeros_like(t)], 1), [1] * t.size)
        m = target_metrics(truth, {"a": trk})[1]
        assert m.length_ratio == 1.0 and m.armse == 0.0

    def test_false_track_counts_for_nobody(self):
        truth = {1: line(0.0)}
        tracks = {**perfect(truth), "fa": EstimatedTrack([0.0, 1.0], [[5, 5], [6, 6]], [None] * 2)}
        m = target_metrics(truth, tracks)[1]
        assert m.n_tracks == 1 and m.track_purity == 1.0

    def test_explicit_assignment(self):
        truth = {1: line(0.0), 2: line(10.0)}
        tracks = perfect(truth)
        m = target_metrics(truth, tracks, assignment={"trk1": 2, "trk2": 1})
        assert m[1].armse == pytest.approx(10.0)
        assert m[1].track_purity == 0.0

    def test_never_tracked(self):
        m = target_metrics({1: line(0.0)}, {})[1]
        assert m.length_ratio == 0.0
        assert math.isnan(m.armse) and math.isnan(m.track_purity)

    def test_bad(self):
        truth = {1: line(0.0)}
        with pytest.raises(ValueError, match="`length`"):
            target_metrics(truth, {}, length="median")
        with pytest.raises(ValueError, match="`assignments`"):
            monte_carlo_metrics(truth, [{}], assignments=[{}, {}])
        with pytest.raises(TypeError, match="`runs"):
            monte_carlo_metrics(truth, [{"a": 1}])


class TestGospa:
    def test_hand_case(self):
        g = gospa_numpy([[0.0, 0.0]], [[3.0, 4.0], [100.0, 0.0]], c=10.0)
        assert g["localisation"] == 25.0
        assert g["missed"] == 50.0 and g["false"] == 0.0
        assert g["distance"] == pytest.approx(math.sqrt(75.0))

    def test_far_pair_is_missed_and_false(self):
        g = gospa_numpy([[0.0, 0.0]], [[50.0, 0.0]], c=10.0)
        assert g["localisation"] == 0.0 and g["missed"] == 50.0 and g["false"] == 50.0

    def test_empty(self):
        assert gospa_numpy(np.zeros((0, 2)), np.zeros((0, 2)), c=5.0)["distance"] == 0.0
        g = gospa_numpy(np.zeros((0, 2)), [[1.0, 1.0]], c=4.0, p=1.0)
        assert g["distance"] == 2.0

    @pytest.mark.parametrize("backend", ["numpy", "auto"])
    def test_identical_sets_zero(self, backend):
        truth = pd_ground_truth()
        times = np.arange(0.0, 1201.0, 50.0)
        g = gospa(truth, perfect(truth), times, backend=backend)
        np.testing.assert_allclose(g["distance"], 0.0, atol=1e-9)
        assert g["times"].shape == times.shape

    def test_missed_target(self):
        truth = {1: line(0.0), 2: line(100.0)}
        tracks = perfect({1: truth[1]})
        g = gospa(truth, tracks, [0.0, 5.0], c=20.0, backend="numpy")
        np.testing.assert_allclose(g["distance"], math.sqrt(20.0**2 / 2))
        np.testing.assert_allclose(g["missed"], 200.0)

    @pytest.mark.skipif(not HAVE_STONESOUP, reason="stonesoup not installed")
    def test_numpy_equals_stonesoup(self):
        rng = np.random.default_rng(0)
        for _ in range(20):
            m, n = rng.integers(0, 6, size=2)
            est = rng.uniform(0, 100, size=(m, 2))
            tru = rng.uniform(0, 100, size=(n, 2))
            tracks = {k: EstimatedTrack([0.0], est[k : k + 1]) for k in range(m)}
            truth = {k: Truth(np.array([0.0]), tru[k : k + 1]) for k in range(n)}
            a = gospa(truth, tracks, [0.0], c=30.0, backend="numpy")
            b = gospa(truth, tracks, [0.0], c=30.0, backend="stonesoup")
            for key in ("distance", "localisation", "missed", "false"):
                np.testing.assert_allclose(a[key], b[key], atol=1e-9, err_msg=key)

    def test_stonesoup_missing(self, monkeypatch):
        monkeypatch.setattr(evaluation, "_have_stonesoup", lambda: False)
        truth = {1: line(0.0)}
        with pytest.raises(ImportError, match="stonesoup"):
            gospa(truth, perfect(truth), [0.0], backend="stonesoup")
        g = gospa(truth, perfect(truth), [0.0])  # auto falls back to NumPy
        assert g["distance"].tolist() == [0.0]

    def test_bad(self):
        with pytest.raises(ValueError, match="`backend`"):
            gospa({}, {}, backend="torch")
        with pytest.raises(ValueError, match="`c`"):
            gospa_numpy([[0.0, 0.0]], [[0.0, 0.0]], c=0.0)


def test_truth_without_type_gives_no_type_purity():
    @dataclass
    class Bare:
        times: np.ndarray
        positions: np.ndarray

    tr = line(0.0)
    truth = {1: Bare(tr.times, tr.positions)}
    trk = EstimatedTrack(tr.times, tr.positions, [1] * 11, [NO_TYPE] * 5 + [0] * 6)
    m = target_metrics(truth, {"a": trk})[1]
    assert m.type_purity == 0.0 and m.track_purity == 1.0


class _Line:
    """A target moving along x at 1 m/s for 10 s."""

    times = np.arange(11.0)
    positions = np.stack([np.arange(11.0), np.zeros(11)], 1)
    video_class = 0


def test_armse_both_orders_and_lost_tail_counts():
    # run 0: 3 m off for 11 s; run 1: 4 m off for 6 s, then the track loses the target and
    # wanders (the tail still counts: the track is associated as a whole, 24.6.3)
    t = _Line.times
    e0 = np.full(11, 3.0)
    e1 = np.array([4.0] * 6 + [50.0, 100.0, 150.0, 200.0, 250.0])
    runs = [
        {"a": EstimatedTrack(t, _Line.positions + np.stack([0 * t, e0], 1), [1] * 11)},
        {"b": EstimatedTrack(t, _Line.positions + np.stack([0 * t, e1], 1), [1] * 6 + [-2] * 5)},
    ]
    m = monte_carlo_metrics({1: _Line}, runs)[1]
    # loop references straight from the two readings
    by_time = np.mean([np.sqrt((e0[k] ** 2 + e1[k] ** 2) / 2) for k in range(11)])
    by_run = np.mean([np.sqrt(np.mean(e0**2)), np.sqrt(np.mean(e1**2))])
    assert m.armse == pytest.approx(by_time, rel=1e-12)
    assert m.armse_run == pytest.approx(by_run, rel=1e-12)
    assert m.armse > 40.0  # the 5 lost samples dominate: they are not dropped

import math

import numpy as np
import pytest
import torch

from hocnet.hoc import Track, detect
from hocnet.metrics import (
    TrackRecall,
    clutter_rejection,
    false_tracks,
    pd_pfa,
    points_remaining,
    roc_curve,
    target_points_lost,
    track_recall,
)


def small_scene() -> tuple[torch.Tensor, torch.Tensor]:
    """A 3 x 4 x 4 cube with a 3-point target and four clutter points."""
    frames = torch.zeros(3, 4, 4, dtype=torch.bool)
    truth = torch.zeros_like(frames)
    for t in range(3):
        frames[t, t, t] = truth[t, t, t] = True
    frames[0, 3, 3] = frames[1, 3, 0] = frames[2, 0, 3] = frames[2, 3, 3] = True
    return frames, truth


def line(t0: int, n: int, y0: int, x0: int, dy: int, dx: int) -> torch.Tensor:
    return torch.tensor([[t0 + k, y0 + k * dy, x0 + k * dx] for k in range(n)])


class TestClutterRejection:
    def test_exact(self):
        frames, truth = small_scene()
        out = truth.clone()
        out[2, 3, 3] = True
        assert clutter_rejection(frames, out, truth) == 0.75
        assert clutter_rejection(frames, truth, truth) == 1.0
        assert clutter_rejection(frames, frames, truth) == 0.0

    def test_return_types(self):
        frames, truth = small_scene()
        assert isinstance(clutter_rejection(frames, truth, truth), float)
        batched = clutter_rejection(
            torch.stack([frames, frames]), torch.stack([truth, frames]), torch.stack([truth, truth])
        )
        assert batched.dtype == torch.float64 and batched.tolist() == [1.0, 0.0]

    def test_no_clutter_is_one_not_nan(self):
        _, truth = small_scene()
        assert clutter_rejection(truth, truth, truth) == 1.0
        empty = torch.zeros(2, 5, 5)
        assert clutter_rejection(empty, empty, empty) == 1.0

    def test_output_points_outside_input_ignored(self):
        frames, truth = small_scene()
        out = truth.clone()
        out[1, 0, 3] = True  # not an input point
        assert clutter_rejection(frames, out, truth) == 1.0

    def test_accepts_float_and_numpy(self):
        frames, truth = small_scene()
        out = truth.clone()
        out[0, 3, 3] = True
        value = clutter_rejection(frames.float().numpy(), out.numpy(), truth.to(torch.uint8))
        assert value == 0.75

    def test_matches_detector(self):
        g = torch.Generator().manual_seed(3)
        frames = torch.rand(8, 30, 30, generator=g) < 0.02
        truth = torch.zeros_like(frames)
        for t in range(8):
            frames[t, 3 + 2 * t, 4 + 3 * t] = truth[t, 3 + 2 * t, 4 + 3 * t] = True
        result = detect(frames, order=2)
        clutter = frames & ~truth
        expected = 1 - float((clutter & result.support).sum()) / float(clutter.sum())
        assert clutter_rejection(frames, result.support, truth) == pytest.approx(expected)

    def test_exceptions(self):
        frames, truth = small_scene()
        with pytest.raises(ValueError, match="`output`: expected shape"):
            clutter_rejection(frames, truth[:2], truth)
        with pytest.raises(ValueError, match="`target_mask`: expected shape"):
            clutter_rejection(frames, truth, truth[None])
        with pytest.raises(ValueError, match="`frames`: expected binary"):
            clutter_rejection(frames.float() * 2, truth, truth)
        with pytest.raises(ValueError, match="`frames`: expected shape"):
            clutter_rejection(frames[0], truth[0], truth[0])
        with pytest.raises(TypeError, match="`output`"):
            clutter_rejection(frames, "cube", truth)


class TestTargetPointsLost:
    def test_exact(self):
        frames, truth = small_scene()
        out = frames.clone()
        assert target_points_lost(frames, out, truth) == 0
        out[2, 2, 2] = False
        out[0, 0, 0] = False
        assert target_points_lost(frames, out, truth) == 2
        assert isinstance(target_points_lost(frames, out, truth), int)

    def test_missed_target_points_do_not_count(self):
        frames, truth = small_scene()
        frames[1, 1, 1] = False  # the target return was missed in the input
        assert target_points_lost(frames, torch.zeros_like(frames), truth) == 2

    def test_batched(self):
        frames, truth = small_scene()
        out = torch.stack([frames, torch.zeros_like(frames)])
        lost = target_points_lost(torch.stack([frames] * 2), out, torch.stack([truth] * 2))
        assert lost.dtype == torch.int64 and lost.tolist() == [0, 3]

    def test_exceptions(self):
        frames, truth = small_scene()
        with pytest.raises(ValueError, match="`output`: expected shape"):
            target_points_lost(frames, frames[:, :2], truth)
        with pytest.raises(ValueError, match="`target_mask`: expected binary"):
            target_points_lost(frames, frames, truth.float() + 0.5)


class TestPointsRemaining:
    def test_exact(self):
        frames, _ = small_scene()
        assert points_remaining(frames) == 7
        assert points_remaining(torch.zeros(2, 3, 3)) == 0

    def test_batched(self):
        frames, truth = small_scene()
        assert points_remaining(torch.stack([frames, truth])).tolist() == [7, 3]

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`output`: expected shape"):
            points_remaining(torch.zeros(3, 3))
        with pytest.raises(ValueError, match="`output`: expected binary"):
            points_remaining(torch.full((1, 2, 2), 0.5))


class TestTrackRecall:
    def test_exact(self):
        true = [line(0, 6, 5, 0, 0, 2), line(0, 3, 20, 20, 0, 0), line(0, 6, 1, 1, 1, 1)]
        found = [line(1, 5, 5, 2, 0, 2), line(0, 4, 1, 1, 1, 1)]
        r = track_recall(true, found)
        assert isinstance(r, TrackRecall)
        assert r.found == (True, None, False)
        assert r.matched == (0, None, 1)
        assert r.overlap[0] == pytest.approx(5 / 6) and r.overlap[2] == pytest.approx(4 / 6)
        assert (r.n_evaluated, r.n_found, r.recall) == (2, 1, 0.5)

    def test_min_overlap_boundary_inclusive(self):
        true = [line(0, 5, 0, 0, 1, 1)]
        found = [line(0, 4, 0, 0, 1, 1)]
        assert track_recall(true, found, min_overlap=0.8).found == (True,)
        assert track_recall(true, found, min_overlap=0.81).found == (False,)

    def test_window(self):
        true = [line(0, 16, 0, 0, 1, 1)]
        found = [line(6, 4, 6, 6, 1, 1)]
        assert track_recall(true, found, window=(6, 10), min_points=4).found == (True,)
        assert track_recall(true, found, window=(6, 10), min_points=5).found == (None,)
        assert track_recall(true, found, window=(6, 11)).found == (True,)  # 4 of 5 = 80 %
        assert track_recall(true, found, window=(6, 12)).found == (False,)  # 4 of 6

    def test_accepts_track_objects_and_lists(self):
        true = [line(0, 5, 0, 0, 1, 1).tolist()]
        track = Track(points=line(0, 5, 0, 0, 1, 1), id=1, score=3.0, point_scores=torch.ones(5))
        assert track_recall(true, [track]).found == (True,)

    def test_no_tracks(self):
        r = track_recall([], [])
        assert r.found == () and r.recall == 1.0
        r = track_recall([line(0, 5, 0, 0, 1, 1)], [])
        assert r.found == (False,) and r.matched == (None,) and r.recall == 0.0

    def test_exceptions(self):
        good = [line(0, 5, 0, 0, 1, 1)]
        with pytest.raises(TypeError, match="`true_tracks`: expected a sequence"):
            track_recall(good[0], good)
        with pytest.raises(ValueError, match=r"`found_tracks\[0\]`: expected shape \(N, 3\)"):
            track_recall(good, [torch.zeros(4, 2, dtype=torch.int64)])
        with pytest.raises(TypeError, match=r"`true_tracks\[0\]`: expected integer"):
            track_recall([good[0].float()], good)
        with pytest.raises(ValueError, match="`min_overlap`"):
            track_recall(good, good, min_overlap=0.0)
        with pytest.raises(ValueError, match="`min_points`"):
            track_recall(good, good, min_points=0)
        with pytest.raises(ValueError, match=r"`window\[1\]`"):
            track_recall(good, good, window=(5, 5))
        with pytest.raises(TypeError, match="`window`"):
            track_recall(good, good, window=3)


class TestFalseTracks:
    def mask(self) -> torch.Tensor:
        m = torch.zeros(5, 8, 8, dtype=torch.bool)
        for t in range(5):
            m[t, 1, t] = True
        return m

    def test_exact(self):
        m = self.mask()
        real = line(0, 5, 1, 0, 0, 1)
        fake = line(0, 5, 6, 7, 0, -1)
        half = torch.cat([line(0, 2, 1, 0, 0, 1), line(2, 2, 6, 2, 0, 1)])  # 2 of 4 on target
        assert false_tracks([real, fake], m) == 1
        assert false_tracks([half], m) == 0
        assert false_tracks([half], m, min_target_fraction=0.75) == 1
        assert false_tracks([], m) == 0

    def test_points_outside_cube_are_clutter(self):
        m = self.mask()
        outside = torch.tensor([[0, 1, 0], [1, -1, 9], [2, 50, 50]])
        assert false_tracks([outside], m) == 1

    def test_batched_uses_track_batch(self):
        m = torch.stack([self.mask(), torch.zeros(5, 8, 8, dtype=torch.bool)])
        pts = line(0, 5, 1, 0, 0, 1)
        tracks = [
            Track(points=pts, id=1, score=3.0, point_scores=torch.ones(5), batch=0),
            Track(points=pts, id=2, score=3.0, point_scores=torch.ones(5), batch=1),
        ]
        assert false_tracks(tracks, m).tolist() == [0, 1]

    def test_exceptions(self):
        m = torch.stack([self.mask()] * 2)
        with pytest.raises(TypeError, match=r"`found_tracks\[0\]`: expected an object with"):
            false_tracks([line(0, 5, 1, 0, 0, 1)], m)
        bad = Track(points=line(0, 5, 1, 0, 0, 1), id=1, score=3.0, point_scores=torch.ones(5))
        bad.batch = 2
        with pytest.raises(ValueError, match=r"`found_tracks\[0\].batch`"):
            false_tracks([bad], m)
        with pytest.raises(ValueError, match="`min_target_fraction`"):
            false_tracks([], self.mask(), min_target_fraction=1.5)
        with pytest.raises(ValueError, match="`target_mask`"):
            false_tracks([], torch.zeros(8, 8))


class TestPdPfa:
    def test_exact(self):
        scores = torch.tensor([[[0.9, 0.2], [0.7, float("nan")]]])
        truth = torch.tensor([[[True, False], [False, True]]])
        assert pd_pfa(scores, truth, 0.5) == (0.5, 0.5)
        assert pd_pfa(scores, truth, 0.9) == (0.5, 0.0)  # >= threshold detects
        assert pd_pfa(scores, truth, 1.0) == (0.0, 0.0)
        assert pd_pfa(scores, truth, -5.0) == (0.5, 1.0)  # NaN never detected

    def test_valid_mask(self):
        scores = torch.tensor([[[0.9, 0.2], [0.7, 0.1]]])
        truth = torch.tensor([[[True, False], [False, False]]])
        valid = torch.tensor([[[True, False], [True, False]]])
        assert pd_pfa(scores, truth, 0.5, valid=valid) == (1.0, 1.0)

    def test_degenerate_never_nan(self):
        scores = torch.ones(1, 2, 2)
        assert pd_pfa(scores, torch.zeros(1, 2, 2), 0.5) == (1.0, 1.0)
        assert pd_pfa(scores, torch.ones(1, 2, 2), 0.5) == (1.0, 0.0)

    def test_pfa_is_one_minus_rejection_on_input_points(self):
        frames, truth = small_scene()
        out = truth.clone()
        out[2, 3, 3] = True
        pd, pfa = pd_pfa(out.double(), truth, 0.5, valid=frames)
        assert pd == 1.0 and pfa == pytest.approx(1 - clutter_rejection(frames, out, truth))

    def test_exceptions(self):
        truth = torch.zeros(1, 2, 2, dtype=torch.bool)
        with pytest.raises(ValueError, match="`scores`: expected shape"):
            pd_pfa(torch.zeros(1, 2, 3), truth, 0.5)
        with pytest.raises(TypeError, match="`scores`: expected a real tensor"):
            pd_pfa(torch.zeros(1, 2, 2, dtype=torch.complex64), truth, 0.5)
        with pytest.raises(ValueError, match="`threshold`: expected a finite"):
            pd_pfa(torch.zeros(1, 2, 2), truth, math.nan)
        with pytest.raises(ValueError, match="`valid`: expected shape"):
            pd_pfa(torch.zeros(1, 2, 2), truth, 0.5, valid=torch.ones(1, 1, 2))


class TestRocCurve:
    def test_exact_default_thresholds(self):
        scores = torch.tensor([[[4.0, 1.0], [3.0, 2.0]]])
        truth = torch.tensor([[[True, False], [False, True]]])
        pfa, pd, thr = roc_curve(scores, truth)
        assert thr.tolist() == [math.inf, 4.0, 3.0, 2.0, 1.0]
        assert pd.tolist() == [0.0, 0.5, 0.5, 1.0, 1.0]
        assert pfa.tolist() == [0.0, 0.0, 0.5, 0.5, 1.0]

    def test_agrees_with_pd_pfa(self):
        g = torch.Generator().manual_seed(0)
        scores = torch.rand(2, 3, 5, 5, generator=g)
        scores[scores < 0.1] = math.nan
        truth = torch.rand(2, 3, 5, 5, generator=g) < 0.3
        thresholds = [0.05, 0.2, 0.5, 0.77, 0.99]
        pfa, pd, thr = roc_curve(scores, truth, thresholds)
        assert thr.tolist() == thresholds
        for i, t in enumerate(thresholds):
            assert (pd[i].item(), pfa[i].item()) == pytest.approx(pd_pfa(scores, truth, t))

    def test_ties_and_numpy(self):
        scores = np.array([[[1.0, 1.0, 0.0]]])
        truth = np.array([[[1, 0, 1]]])
        pfa, pd, thr = roc_curve(scores, truth)
        assert thr.tolist() == [math.inf, 1.0, 0.0]
        assert pd.tolist() == [0.0, 0.5, 1.0] and pfa.tolist() == [0.0, 1.0, 1.0]

    def test_monotone(self):
        g = torch.Generator().manual_seed(1)
        scores = torch.randn(1, 4, 8, 8, generator=g)
        truth = scores + torch.randn(1, 4, 8, 8, generator=g) > 1.0
        pfa, pd, _ = roc_curve(scores, truth)
        assert bool((pd.diff() >= 0).all()) and bool((pfa.diff() >= 0).all())
        assert pd[-1] == 1.0 and pfa[-1] == 1.0

    def test_exceptions(self):
        truth = torch.zeros(1, 2, 2, dtype=torch.bool)
        with pytest.raises(ValueError, match="`thresholds`: expected numbers, got NaN"):
            roc_curve(torch.zeros(1, 2, 2), truth, [0.5, math.nan])
        with pytest.raises(TypeError, match="`thresholds`"):
            roc_curve(torch.zeros(1, 2, 2), truth, "abc")
        with pytest.raises(ValueError, match="`truth_mask`: expected binary"):
            roc_curve(torch.zeros(1, 2, 2), torch.full((1, 2, 2), 3.0))

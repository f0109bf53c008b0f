import math
import re

import numpy as np
import pytest
import torch

from hocnet.data.infrared import IRTarget, simulate_ir
from hocnet.data.whitening import anti_mean
from hocnet.dpa.backtrack import (
    EXCLUSIVE_METHODS,
    SPREAD,
    DPADetection,
    DPATrack,
    _best_pair,
    _local_maxima,
    backtrack,
    cfar_threshold,
    detect,
)
from hocnet.dpa.functional import DPAState, accumulate
from hocnet.dpa.matrices import b_limit, effective_memory, probability_matrices
from hocnet.dpa.metrics import frame_thresholds, tracking_success


@pytest.fixture(autouse=True)
def _single_thread():
    # small tensors on a shared machine: thread wake-ups would dominate
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


W7 = probability_matrices(7, v_max=2.0)
B7 = effective_memory(W7, 0.5)
W5 = probability_matrices(5, v_max=1.0)
B5 = effective_memory(W5, 0.5)
R2 = math.sqrt(2.0)


def _random_state(seed, batch=2, t=6, h=9, w=11, directional=True, g=0.3):
    gen = torch.Generator().manual_seed(seed)
    frames = torch.randn(batch, t, h, w, generator=gen, dtype=torch.float64)
    weights = probability_matrices(5, v_max=1.0, dtype=torch.float64)
    if not directional:
        weights = weights[8:9]
    return accumulate(frames, weights, 0.9, g)


def backtrack_loop(state, start=None):
    """Slow oracle: follow the tracking matrix pixel by pixel."""
    s = state.as_batched()
    asf, origin = s.asf.detach().numpy(), s.origin.numpy()
    n_b, n_t, n_h, n_w = asf.shape
    out = np.zeros((n_b, n_t, 2), dtype=np.int64)
    for b in range(n_b):
        if start is None:
            best, x, y = -math.inf, 0, 0
            for yy in range(n_h):
                for xx in range(n_w):
                    if asf[b, -1, yy, xx] > best:  # strict: the first maximum wins
                        best, x, y = asf[b, -1, yy, xx], xx, yy
        else:
            x, y = (int(v) for v in start[b])
        out[b, n_t - 1] = (x, y)
        for t in range(n_t - 1, 0, -1):
            src = int(origin[b, t, y, x])
            y, x = src // n_w, src % n_w
            out[b, t - 1] = (x, y)
    return out if state.batched else out[0]


def _straight_scene(seed, batch=None, jitter=0.0, snr_db=30.0):
    target = IRTarget(6.3, 8.2, 1.2, 0.6, snr_db=snr_db)
    return simulate_ir(
        (12, 32, 32), [target], clouds="clear", jitter=jitter, batch=batch, seed=seed
    )


def _two_targets(seed, batch=None):
    targets = [IRTarget(5.0, 6.0, 1.0, 0.5, snr_db=20.0), IRTarget(26.0, 25.0, -1.0, -0.3, 16.0)]
    return simulate_ir((10, 32, 32), targets, clouds="clear", batch=batch, seed=seed)


class TestBacktrack:
    def test_smoke_shapes(self):
        state = _random_state(0)
        path = backtrack(state)
        assert path.shape == (2, 6, 2) and path.dtype == torch.int64
        single = accumulate(torch.randn(5, 8, 8), W5, B5, 0.5)
        assert not single.batched
        assert backtrack(single).shape == (5, 2)
        assert backtrack(single, torch.tensor([3, 4])).shape == (5, 2)

    @pytest.mark.parametrize("seed", range(6))
    @pytest.mark.parametrize("directional", [True, False])
    def test_equals_loop(self, seed, directional):
        state = _random_state(seed, batch=3, directional=directional, g=0.25 * (seed % 5))
        np.testing.assert_array_equal(backtrack(state).numpy(), backtrack_loop(state))
        gen = torch.Generator().manual_seed(100 + seed)
        start = torch.stack(
            [torch.randint(0, 11, (3,), generator=gen), torch.randint(0, 9, (3,), generator=gen)],
            dim=1,
        )
        np.testing.assert_array_equal(
            backtrack(state, start).numpy(), backtrack_loop(state, start.tolist())
        )

    def test_unbatched_equals_loop_and_batched(self):
        frames = torch.randn(7, 10, 12, generator=torch.Generator().manual_seed(3))
        state = accumulate(frames, W5, B5, 0.4)
        path = backtrack(state)
        np.testing.assert_array_equal(path.numpy(), backtrack_loop(state))
        batched = accumulate(frames.unsqueeze(0), W5, B5, 0.4)
        np.testing.assert_array_equal(backtrack(batched)[0].numpy(), path.numpy())

    def test_non_contiguous_state(self):
        state = _random_state(4, batch=2, t=5, h=12, w=12).as_batched()
        sliced = DPAState(
            state.asf.transpose(2, 3),
            state.direction.transpose(2, 3),
            state.origin.transpose(2, 3),  # garbage links but in range: the loop must agree
            True,
        )
        np.testing.assert_array_equal(backtrack(sliced).numpy(), backtrack_loop(sliced))

    def test_ties_lowest_flat_index(self):
        state = accumulate(torch.zeros(3, 6, 7), W5, B5, 0.5)
        np.testing.assert_array_equal(backtrack(state).numpy(), [[0, 0]] * 3)

    def test_single_frame(self):
        frames = torch.zeros(1, 5, 6)
        frames[0, 3, 4] = 1.0
        state = accumulate(frames, torch.ones(1, 1, 1), 1.0, 0.0)
        assert backtrack(state).tolist() == [[4, 3]]

    def test_integer_valued_float_start(self):
        state = _random_state(1)
        expected = backtrack(state, torch.tensor([[2, 4], [7, 0]]))
        got = backtrack(state, torch.tensor([[2.0, 4.0], [7.0, 0.0]]))
        np.testing.assert_array_equal(got.numpy(), expected.numpy())
        assert backtrack(state, [2, 4]).tolist() == backtrack(state, torch.tensor([2, 4])).tolist()

    @pytest.mark.parametrize("start", [[3.5, 2], [3.0, 2.2], [[2, 4], [6.5, 0.0]]])
    def test_fractional_start_raises(self, start):
        # issue 9: [3.5, 2] was silently truncated to a pixel
        with pytest.raises(ValueError, match=r"`start`: expected integer pixel coordinates"):
            backtrack(_random_state(1), start)

    def test_empty_batch(self):
        state = accumulate(torch.zeros(1, 4, 6, 6), W5, B5, 0.5)
        empty = DPAState(state.asf[:0], state.direction[:0], state.origin[:0], True)
        assert backtrack(empty).shape == (0, 4, 2)
        assert backtrack(empty, torch.tensor([1, 1])).shape == (0, 4, 2)

    @pytest.mark.parametrize("bad", [math.nan, math.inf])
    def test_non_finite_asf_names_the_overflow(self, bad):
        state = _random_state(3).as_batched()
        asf = state.asf.clone()
        asf[1, 4:, 2, 3] = bad
        with pytest.raises(
            ValueError, match=r"`state`: the accumulated score \(ASF\) overflowed.*frame 4"
        ):
            backtrack(DPAState(asf, state.direction, state.origin, True))

    def test_start_broadcast_over_batch(self):
        state = _random_state(2, batch=3)
        got = backtrack(state, torch.tensor([5, 5]))
        expected = backtrack(state, torch.tensor([[5, 5]] * 3))
        np.testing.assert_array_equal(got.numpy(), expected.numpy())
        assert (got[:, -1] == torch.tensor([5, 5])).all()

    @pytest.mark.parametrize("seed", range(3))
    def test_recovers_straight_target(self, seed):
        seq = _straight_scene(seed, batch=2)
        state = accumulate(anti_mean(seq.frames), W7, B7, 0.5)
        path = backtrack(state)
        truth = seq.positions[:, 0]  # (B, T, 2)
        dist = torch.linalg.vector_norm(path.double() - truth, dim=-1)
        assert float(dist.max()) <= 1.5, dist
        assert bool(tracking_success(path, truth, fraction=1.0).all())

    def test_recovers_jittered_target(self):
        # a 1.34 px/frame target with U[-0.5, 0.5] jitter at 20 dB through the paper's 7 x 7
        # matrices and direction step (eq. 7-8 pick the origin with W_basic, which favours short
        # moves): measured 14 of these 20 scenes tracked in >= 80 % of the frames (the
        # `"source"` step: 17 of 20 per-seed scenes); the median distance to the truth is 0.72 px
        seq = _straight_scene(0, batch=20, jitter=0.5, snr_db=20.0)
        path = backtrack(accumulate(anti_mean(seq.frames), W7, B7, 0.5))
        truth = seq.positions[:, 0]
        dist = torch.linalg.vector_norm(path.double() - truth, dim=-1)
        assert int(tracking_success(path, truth).sum()) >= 13, dist
        assert float(dist.median()) <= 1.0, dist

    def test_exceptions(self):
        state = _random_state(0)
        with pytest.raises(TypeError, match="`state`"):
            backtrack(torch.zeros(2, 3, 4, 4))
        with pytest.raises(ValueError, match="`start`: expected shape"):
            backtrack(state, torch.zeros(3, 2))
        with pytest.raises(ValueError, match="`start`: expected shape"):
            backtrack(state, torch.zeros(2, 3))
        with pytest.raises(ValueError, match=r"`start`: expected \(x, y\) inside"):
            backtrack(state, torch.tensor([11, 0]))
        with pytest.raises(ValueError, match=r"`start`: expected \(x, y\) inside"):
            backtrack(state, torch.tensor([0.0, -1.0]))
        with pytest.raises(TypeError, match="`start`"):
            backtrack(state, torch.tensor([True, False]))
        with pytest.raises(TypeError, match="`start`"):
            backtrack(state, "centre")
        with pytest.raises(ValueError, match="`start`"):
            backtrack(state, torch.tensor([math.nan, 1.0]))
        unbatched = DPAState(state.asf[0], state.direction[0], state.origin[0], False)
        with pytest.raises(ValueError, match="`start`: expected shape"):
            backtrack(unbatched, torch.zeros(1, 2))
        bad = state.origin.clone()
        bad[0, 2, 0, 0] = 99
        with pytest.raises(ValueError, match="`state`: expected `origin`"):
            backtrack(DPAState(state.asf, state.direction, bad, True))
        with pytest.raises(ValueError, match="`state`"):
            backtrack(DPAState(state.asf, state.direction, state.origin[:, 1:], True))
        with pytest.raises(TypeError, match="`state`"):
            backtrack(DPAState(state.asf, state.direction, state.origin.double(), True))


def nms_loop(image, radius):
    """Slow oracle of the NMS peak rule on a (H, W) array."""
    n_h, n_w = image.shape
    peak = np.zeros((n_h, n_w), dtype=bool)
    for y in range(n_h):
        for x in range(n_w):
            ok = True
            for yy in range(max(0, y - radius), min(n_h, y + radius + 1)):
                for xx in range(max(0, x - radius), min(n_w, x + radius + 1)):
                    v, me = image[yy, xx], image[y, x]
                    if v > me or (v == me and yy * n_w + xx < y * n_w + x):
                        ok = False
            peak[y, x] = ok
    return peak


def _frame_detect(image, **kwargs):
    """``detect`` on one frame with identity weights: the last ASF is the image itself."""
    return detect(image.unsqueeze(-3), torch.ones(1, 1, 1), 1.0, 0.0, **kwargs)


class TestDetect:
    def test_smoke(self):
        seq = _two_targets(0)
        result = detect(anti_mean(seq.frames), W7, B7, 0.5, max_targets=3)
        assert isinstance(result, DPADetection)
        assert result.threshold is None and not result.state.batched
        assert len(result.tracks) == 3
        for i, track in enumerate(result.tracks):
            assert isinstance(track, DPATrack)
            assert track.id == i + 1 and track.batch == 0
            assert track.positions.shape == (10, 2) and track.positions.dtype == torch.int64
            assert track.scores.shape == (10,) and track.scores.dtype == torch.float32
            assert track.score == float(track.scores[-1])
            assert track.points.shape == (10, 3)
        scores = [t.score for t in result.tracks]
        assert scores == sorted(scores, reverse=True)

    def test_tracks_equal_backtrack_and_asf(self):
        frames = torch.randn(2, 6, 12, 12, generator=torch.Generator().manual_seed(5))
        result = detect(frames, W5, B5, 0.5, max_targets=4, nms_radius=2, exclusive=False)
        for track in result.tracks:
            state = result.state
            path = backtrack(state, track.positions[-1].expand(2, 2))[track.batch]
            np.testing.assert_array_equal(track.positions.numpy(), path.numpy())
            x, y = track.positions[:, 0], track.positions[:, 1]
            asf = state.asf[track.batch, torch.arange(6), y, x]
            np.testing.assert_array_equal(track.scores.numpy(), asf.numpy())

    def test_finds_two_targets(self):
        # targets at 1.1 and 1.0 px/frame (20 and 16 dB, 10 frames), paper DPA with 7 x 7
        # matrices: both targets back-tracked in >= 90 % of the frames in 15 of these 20 scenes
        # (the misses lose a target's first frames)
        seq = _two_targets(0, batch=20)
        frames = anti_mean(seq.frames)
        result = detect(frames, W7, B7, 0.5, max_targets=2, nms_radius=3)
        assert [t.batch for t in result.tracks] == [b for b in range(20) for _ in range(2)]
        assert [t.id for t in result.tracks] == list(range(1, 41))
        found = 0
        for b in range(20):
            tracks = [t for t in result.tracks if t.batch == b]
            truth = seq.positions[b]  # (2, T, 2)
            matched, ok = set(), True
            for track in tracks:
                dist = torch.linalg.vector_norm(track.positions.double() - truth, dim=-1)
                n = int(dist[:, -1].argmin())
                matched.add(n)
                ok &= bool(tracking_success(track.positions, truth[n], fraction=0.9))
            found += ok and matched == {0, 1}
        assert found >= 14, found

    def test_nms_suppresses_neighbours(self):
        seq = _two_targets(3)
        frames = anti_mean(seq.frames)
        suppressed = detect(frames, W7, B7, 0.5, max_targets=5, nms_radius=3)
        ends = torch.stack([t.positions[-1] for t in suppressed.tracks]).double()
        gaps = torch.cdist(ends, ends) + torch.eye(len(ends)) * 100
        assert float(gaps.min()) > 3.0  # no two peaks within each other's neighbourhood
        raw = detect(frames, W7, B7, 0.5, max_targets=2, nms_radius=0, exclusive=False)
        a, b = (t.positions[-1].double() for t in raw.tracks)
        assert float(torch.linalg.vector_norm(a - b)) <= 1.5  # both on the brightest target
        assert raw.tracks[0].score == suppressed.tracks[0].score
        # joint back-tracking keeps one of two tracks of the same target
        joint = detect(frames, W7, B7, 0.5, max_targets=2, nms_radius=0, exclusive="joint")
        assert len(joint.tracks) == 1
        assert torch.equal(joint.tracks[0].positions, raw.tracks[0].positions)

    def test_threshold_keeps_only_strong_peaks(self):
        seq = _two_targets(1)
        frames = anti_mean(seq.frames)
        loose = detect(frames, W7, B7, 0.5, max_targets=50)
        strong = sorted((t.score for t in loose.tracks), reverse=True)
        thr = 0.5 * (strong[1] + strong[2])
        result = detect(frames, W7, B7, 0.5, max_targets=50, threshold=thr)
        assert result.threshold == thr and len(result.tracks) == 2
        assert all(t.score > thr for t in result.tracks)
        assert detect(frames, W7, B7, 0.5, threshold=1e6).tracks == []

    @pytest.mark.parametrize("radius", [0, 1, 2, 3])
    @pytest.mark.parametrize("seed", range(4))
    def test_nms_equals_loop(self, radius, seed):
        gen = torch.Generator().manual_seed(seed)
        image = torch.randint(0, 4, (2, 7, 9), generator=gen).double()  # many ties
        got = _local_maxima(image, radius)
        for b in range(2):
            np.testing.assert_array_equal(got[b].numpy(), nms_loop(image[b].numpy(), radius))

    def test_nms_hand_made(self):
        image = torch.zeros(8, 10)
        image[0, 0] = 5.0  # corner peak: out-of-frame pixels are excluded
        image[4, 3] = image[4, 4] = 7.0  # a tie: the lower flat index (x = 3) wins
        image[4, 7] = 6.0  # 3 px from the tie: suppressed at r = 3, kept at r = 2
        ends = lambda res: [t.positions[-1].tolist() for t in res.tracks]  # noqa: E731
        assert ends(_frame_detect(image, nms_radius=3, threshold=0.5)) == [[3, 4], [0, 0]]
        assert ends(_frame_detect(image, nms_radius=2, threshold=0.5)) == [[3, 4], [7, 4], [0, 0]]
        assert ends(_frame_detect(image, nms_radius=0, threshold=5.5)) == [[3, 4], [4, 4], [7, 4]]
        # the zero background has no peak: each zero pixel has a larger or an earlier equal
        # neighbour; the NMS of a constant image has exactly one, its first pixel, but detect
        # reports none: in a constant last frame no pixel stands out (issue 9)
        assert len(_frame_detect(image, nms_radius=3, max_targets=100).tracks) == 2
        assert _local_maxima(torch.ones(1, 8, 10), 1).sum() == 1
        flat = _frame_detect(torch.ones(8, 10), nms_radius=1, max_targets=100)
        assert ends(flat) == []

    def test_max_targets_and_order(self):
        image = torch.zeros(20, 20)
        for i, (x, y) in enumerate([(2, 2), (17, 2), (2, 17), (17, 17), (10, 10)]):
            image[y, x] = 1.0 + (i % 2)  # values 1, 2, 1, 2, 1: ties broken by flat index
        result = _frame_detect(image, max_targets=4, threshold=0.5)
        assert [t.positions[-1].tolist() for t in result.tracks] == [
            [17, 2],
            [17, 17],
            [2, 2],
            [10, 10],  # flat index 210 < 342 of (2, 17)
        ]
        assert [t.id for t in result.tracks] == [1, 2, 3, 4]

    def test_batched_and_unbatched_agree(self):
        frames = torch.randn(2, 5, 12, 12, generator=torch.Generator().manual_seed(9))
        both = detect(frames, W5, B5, 0.5, max_targets=3)
        assert both.state.batched
        second = detect(frames[1], W5, B5, 0.5, max_targets=3)
        mine = [t for t in both.tracks if t.batch == 1]
        assert len(mine) == len(second.tracks) == 3
        for a, b in zip(mine, second.tracks, strict=True):
            np.testing.assert_array_equal(a.positions.numpy(), b.positions.numpy())
            assert a.score == b.score

    def test_cfar_threshold_from_target_free(self):
        seq = _two_targets(2, batch=2)
        frames, free = anti_mean(seq.frames), anti_mean(seq.target_free)
        result = detect(frames, W7, B7, 0.5, target_free=free, pfa=0.01, max_targets=10)
        assert result.threshold == cfar_threshold(free, W7, B7, 0.5, pfa=0.01)
        assert all(t.score > result.threshold for t in result.tracks)
        assert len(result.tracks) >= 4  # both targets in both scenes

    def test_exceptions(self):
        frames = torch.randn(4, 10, 10)
        with pytest.raises(ValueError, match="`max_targets`"):
            detect(frames, W5, B5, 0.5, max_targets=0)
        with pytest.raises(TypeError, match="`max_targets`"):
            detect(frames, W5, B5, 0.5, max_targets=2.5)
        with pytest.raises(ValueError, match="`nms_radius`"):
            detect(frames, W5, B5, 0.5, nms_radius=-1)
        for pfa in (0.0, 1.0, -0.1):
            with pytest.raises(ValueError, match="`pfa`"):
                detect(frames, W5, B5, 0.5, pfa=pfa)
        with pytest.raises(ValueError, match="`threshold`"):
            detect(frames, W5, B5, 0.5, threshold=math.nan)
        with pytest.raises(ValueError, match="`threshold`: expected None when `target_free`"):
            detect(frames, W5, B5, 0.5, threshold=1.0, target_free=frames)
        with pytest.raises(ValueError, match="`frames`"):
            detect(torch.zeros(10, 10), W5, B5, 0.5)
        with pytest.raises(ValueError, match="`g`"):
            detect(frames, W5, B5, 1.5)
        with pytest.raises(ValueError, match="`target_free`"):
            detect(frames, W5, B5, 0.5, target_free=torch.zeros(10, 10))


class TestCfarThreshold:
    def _noise(self, seed, batch=16, t=8):
        seq = simulate_ir((t, 32, 32), clouds="clear", batch=batch, seed=seed)
        return anti_mean(seq.target_free)

    def test_exact_rate_on_its_own_data(self):
        free = self._noise(0, batch=4)
        for pfa in (0.5, 0.05, 0.01, 1 / 4096):
            thr = cfar_threshold(free, W5, B5, 0.5, pfa=pfa)
            last = accumulate(free, W5, B5, 0.5).asf[:, -1]
            assert int((last > thr).sum()) == math.floor(pfa * last.numel() * (1 + 1e-12))

    @pytest.mark.parametrize("seed", range(3))
    def test_rate_on_independent_noise(self, seed):
        pfa = 0.02
        thr = cfar_threshold(self._noise(2 * seed), W5, B5, 0.5, pfa=pfa)
        last = accumulate(self._noise(2 * seed + 1), W5, B5, 0.5).asf[:, -1]
        rate = float((last > thr).double().mean())
        # 16 * 32 * 32 = 16384 samples per side: binomial sd about 0.0011 (before correlation)
        assert abs(rate - pfa) < 0.3 * pfa, rate

    def test_peaks(self):
        free = self._noise(5, batch=8)
        thr = cfar_threshold(free, W5, B5, 0.5, pfa=0.05, samples="peaks", nms_radius=2)
        last = accumulate(free, W5, B5, 0.5).asf[:, -1]
        peaks = last[_local_maxima(last, 2)]
        assert int((peaks > thr).sum()) == math.floor(0.05 * peaks.numel())
        assert thr > cfar_threshold(free, W5, B5, 0.5, pfa=0.05)  # peaks are the high tail

    def test_unbatched_and_frame_thresholds(self):
        free = self._noise(6, batch=1)
        thr = cfar_threshold(free[0], W5, B5, 0.5, pfa=0.01)
        assert thr == cfar_threshold(free, W5, B5, 0.5, pfa=0.01)
        asf = accumulate(free, W5, B5, 0.5).asf
        assert thr == float(frame_thresholds(asf, 0.01)[-1])

    def test_too_few_samples(self):
        free = torch.randn(2, 3, 10, 10)  # 200 samples
        with pytest.raises(ValueError, match=r"`pfa`.*N = 200.*at least 1000 samples"):
            cfar_threshold(free, W5, B5, 0.5, pfa=1e-3)
        cfar_threshold(free, W5, B5, 0.5, pfa=1 / 200)  # the smallest estimable rate

    def test_exceptions(self):
        free = torch.randn(2, 3, 10, 10)
        with pytest.raises(ValueError, match="`pfa`"):
            cfar_threshold(free, W5, B5, 0.5, pfa=1.0)
        with pytest.raises(ValueError, match="`target_free`"):
            cfar_threshold(torch.zeros(10, 10), W5, B5, 0.5)
        with pytest.raises(ValueError, match="`target_free`"):
            cfar_threshold(torch.full((2, 10, 10), math.inf), W5, B5, 0.5)
        with pytest.raises(ValueError, match="`samples`"):
            cfar_threshold(free, W5, B5, 0.5, samples="all")
        with pytest.raises(ValueError, match="`nms_radius`"):
            cfar_threshold(free, W5, B5, 0.5, nms_radius=-2)
        with pytest.raises(ValueError, match="`weights`"):
            cfar_threshold(free, torch.ones(2, 3, 3), B5, 0.5)


# ----------------------------------------------------------------------------- issue 8 and 9


def _crossing_targets(speed, snr_db=18.0, low=0.0):
    """The two targets of :func:`_crossing`."""
    d = 12.0 * speed
    return [
        IRTarget(22.0 - d, 10.0, speed, speed, snr_db),
        IRTarget(22.0 + d, 10.0 + low, -speed, speed, snr_db),
    ]


def _crossing(seed, speed=1.0, snr_db=18.0, low=0.0):
    """Two targets on crossing diagonals (``speed`` px/frame per axis) meeting at frame 12 of 25.

    ``speed=1`` is the scene of issue 8. ``low > 0`` moves the second path down by ``low`` px:
    the targets then pass ``low`` px apart (a near miss).
    """
    targets = _crossing_targets(speed, snr_db, low)
    seq = simulate_ir((25, 48, 48), targets, clouds="clear", seed=seed)
    return anti_mean(seq.frames), seq.positions


def _one_track_per_target(tracks, truth):
    """Each track within 1.5 px of ONE target in >= 80 % of frames; every target has a track."""
    followed = []
    for track in tracks:
        dist = torch.linalg.vector_norm(track.positions.double() - truth, dim=-1)  # (N, T)
        rate = (dist <= 1.5).double().mean(dim=1)
        if float(rate.max()) < 0.8:
            return False
        followed.append(int(rate.argmax()))
    return sorted(followed) == list(range(truth.shape[0]))


def _joint_loop(state, weights, end_a, end_b):
    """Slow oracle of the joint back-tracking of two tracks (``detect(exclusive="joint")``).

    Written from the Notes of :func:`detect`: follow the tracking matrix while the tracks are
    more than 2 px apart (Chebyshev); in an encounter, dead-reckon each track with the mean of
    its last (at most 10) moves and pick, over every pair of candidates, the pair with the
    largest sum of ``exp(-|q - guess|^2 / (2 s^2)) * ASF_{n-1}(q)``, the two pixels more than
    1 px apart unless the guesses are within 1.5 px (or no pair is apart).
    """
    asf, origin = state.asf.detach().double().numpy(), state.origin.numpy()
    w = weights.numpy()
    n_t, n_h, n_w = asf.shape
    h = w.shape[-1] // 2
    allowed = [
        (i, j) for j in range(-h, h + 1) for i in range(-h, h + 1) if (w[:, h + j, h + i] > 0).any()
    ]
    cheb = lambda a, b: max(abs(a[0] - b[0]), abs(a[1] - b[1]))  # noqa: E731
    paths, steps, guess, vel = [[tuple(end_a)], [tuple(end_b)]], [[], []], None, None
    for n in range(n_t - 1, 0, -1):
        p = [path[-1] for path in paths]
        if guess is not None and cheb(*p) > 2 and cheb(*guess) > 2:
            guess = None
        if guess is None and cheb(*p) > 2:
            for i in range(2):
                src = int(origin[n, p[i][1], p[i][0]])
                q = (src % n_w, src // n_w)
                steps[i].append((p[i][0] - q[0], p[i][1] - q[1]))
                paths[i].append(q)
            continue
        if guess is None:
            vel = []
            for i in range(2):
                last = steps[i][-10:]
                vel.append(
                    (sum(m[0] for m in last) / len(last), sum(m[1] for m in last) / len(last))
                    if last
                    else (0.0, 0.0)
                )
            guess = [(float(x), float(y)) for x, y in p]
        guess = [(guess[i][0] - vel[i][0], guess[i][1] - vel[i][1]) for i in range(2)]
        cands = []
        for i in range(2):
            inside = [
                (p[i][0] + di, p[i][1] + dj)
                for di, dj in allowed
                if 0 <= p[i][0] + di < n_w and 0 <= p[i][1] + dj < n_h
            ]
            near = [q for q in inside if cheb(q, guess[i]) <= 1.5]
            if not near:
                dist = [(q[0] - guess[i][0]) ** 2 + (q[1] - guess[i][1]) ** 2 for q in inside]
                near = [inside[dist.index(min(dist))]]
            score = []
            for q in near:
                d2 = (q[0] - guess[i][0]) ** 2 + (q[1] - guess[i][1]) ** 2
                score.append(math.exp(-d2 / (2 * SPREAD**2)) * asf[n - 1, q[1], q[0]])
            cands.append(list(zip(near, score, strict=True)))
        share = cheb(*guess) <= 1.5
        any_apart = any(cheb(a, b) > 1 for a, _ in cands[0] for b, _ in cands[1])
        best, pick = -math.inf, None
        for a, sa in cands[0]:
            for b, sb in cands[1]:
                if not share and any_apart and cheb(a, b) <= 1:
                    continue
                if sa + sb > best:
                    best, pick = sa + sb, (a, b)
        for i in range(2):
            paths[i].append(pick[i])
    return [path[::-1] for path in paths]


def _tiny_crossing(seed):
    """Two bright targets crossing on a 16 x 16 grid (10 frames), plus white noise."""
    gen = torch.Generator().manual_seed(seed)
    frames = torch.randn(10, 16, 16, generator=gen, dtype=torch.float64)
    speed = 0.4 + 0.1 * (seed % 6)
    for t in range(10):
        for sign, peak in ((1, 6.0), (-1, 5.0 + 0.2 * (seed % 3))):
            x = 8 + sign * speed * (t - 5)
            y = 3 + speed * t
            frames[t, math.floor(y + 0.5), math.floor(x + 0.5)] += peak
    return frames


class TestCrossingTargets:
    # Two 18 dB targets on crossing diagonals meeting at frame 12 of 25 (the `speed` below is
    # per axis: 0.35, 0.5, 0.71 and 1.06 are 0.5, 0.71, 1 and 1.5 px/frame; 1.0 is issue 8's
    # scene, 1.41 px/frame), paper matrices (7 x 7, v_max = 2), b of EMC 0.8 of direction 9.
    # Measured over seeds 0..19 (experiments/dpa_crossing.py, results/dpa-crossing.md): plain
    # back-tracking gives one track per target in 0 of 20 scenes everywhere (one track follows
    # one target and then the other); re-tracking and joint back-tracking: see detect's Notes.
    # Below: seeds 0..9 (not chosen), the bound is the count measured on them minus one.
    @pytest.mark.parametrize(
        ("speed", "low", "g", "step", "exclusive", "least"),
        [
            # measured on seeds 0..9: 10, 8, 10, 7, 10, 9, 9, 9
            (0.5 / R2, 0, 1.0, "paper", "straightest", 9),
            (0.5 / R2, 0, 0.0, "paper", "straightest", 7),
            (0.71 / R2, 0, 1.0, "paper", "straightest", 9),
            (0.71 / R2, 0, 0.0, "paper", "straightest", 6),
            (0.71 / R2, 0, 1.0, "source", "straightest", 9),
            (1.0 / R2, 0, 1.0, "paper", "straightest", 8),
            (1.0, 0, 1.0, "source", "straightest", 8),
            (1.5 / R2, 0, 1.0, "source", "straightest", 8),
            # measured: 7, 10, 9
            (0.5 / R2, 0, 0.0, "paper", "joint", 6),
            (0.71 / R2, 0, 1.0, "paper", "joint", 9),
            (1.0, 0, 1.0, "source", "joint", 8),
            # measured: 5, 2, 4
            (0.71 / R2, 0, 1.0, "paper", "retrack", 4),
            (0.71 / R2, 0, 0.0, "paper", "retrack", 1),
            (1.0, 0, 1.0, "source", "retrack", 3),
            # a near miss (3 px apart), measured: 10, 5 (joint alone 2, retrack 5, plain 3 and 0)
            (0.71 / R2, 3, 1.0, "paper", "straightest", 9),
            (0.71 / R2, 3, 0.0, "paper", "straightest", 4),
        ],
    )
    def test_one_track_per_target(self, speed, low, g, step, exclusive, least):
        b = effective_memory(W7, g)
        separated = 0
        for seed in range(10):
            frames, truth = _crossing(seed, speed, low=low)
            plain = detect(frames, W7, b, g, max_targets=2, exclusive=False, direction_step=step)
            if low == 0:  # the failure of issue 8
                assert not _one_track_per_target(plain.tracks, truth), seed
            result = detect(
                frames, W7, b, g, max_targets=2, exclusive=exclusive, direction_step=step
            )
            assert len(result.tracks) == 2
            assert [t.score for t in result.tracks] == [t.score for t in plain.tracks]
            if _one_track_per_target(result.tracks, truth):
                separated += 1
                assert any(t.retracked for t in result.tracks) or low > 0
        assert separated >= least, separated

    def test_issue_scene(self):
        # issue 8's scene (1.41 px/frame, g = 1): in every one of seeds 0..9 where the DPA
        # back-tracks each target when it is alone in the scene (the same seed), joint
        # back-tracking returns one track per target; plain back-tracking never does. With the
        # paper's direction step not even a lone target is tracked at this speed (0 of 20: eq.
        # (7)-(8) favour short moves, see `accumulate`), so the scene uses the "source" step.
        b = effective_memory(W7, 1.0)
        trackable = 0
        for seed in range(10):
            frames, truth = _crossing(seed, 1.0)
            alone = True
            for n in range(2):
                seq = simulate_ir(
                    (25, 48, 48), [_crossing_targets(1.0)[n]], clouds="clear", seed=seed
                )
                one = detect(
                    anti_mean(seq.frames),
                    W7,
                    b,
                    1.0,
                    max_targets=1,
                    exclusive=False,
                    direction_step="source",
                )
                alone &= _one_track_per_target(one.tracks, seq.positions)
            if not alone:
                continue
            trackable += 1
            plain = detect(
                frames, W7, b, 1.0, max_targets=2, exclusive=False, direction_step="source"
            )
            assert not _one_track_per_target(plain.tracks, truth), seed
            result = detect(frames, W7, b, 1.0, max_targets=2, direction_step="source")
            assert _one_track_per_target(result.tracks, truth), seed
        assert trackable >= 7, trackable  # measured 8 (seeds 0 and 9 lose a lone target)

    @pytest.mark.parametrize("seed", range(12))
    def test_joint_equals_loop(self, seed):
        frames = _tiny_crossing(seed)
        g = 0.5 * (seed % 3)
        b = effective_memory(W5, g)
        result = detect(frames, W5, b, g, max_targets=2, nms_radius=2, exclusive="joint")
        plain = detect(frames, W5, b, g, max_targets=2, nms_radius=2, exclusive=False)
        ends = [t.positions[-1].tolist() for t in plain.tracks]
        expected = _joint_loop(plain.state, W5.double(), *ends)
        gap = (plain.tracks[0].positions - plain.tracks[1].positions).abs().amax(dim=1)
        if int(gap.min()) > 2:  # no encounter: the plain tracks
            expected = [[tuple(p) for p in t.positions.tolist()] for t in plain.tracks]
        shared = sum(
            max(abs(a[0] - b[0]), abs(a[1] - b[1])) <= 1 for a, b in zip(*expected, strict=True)
        ) / len(expected[0])
        if shared > 0.25:  # a duplicate: the weaker track is dropped
            expected = [[tuple(p) for p in plain.tracks[0].positions.tolist()]]
        got = [t.positions.tolist() for t in result.tracks]
        assert [[tuple(p) for p in path] for path in got] == expected

    def test_joint_loop_cases_meet(self):
        # the scenes of test_joint_equals_loop exercise the encounter (not only the plain path)
        changed = 0
        for seed in range(12):
            g = 0.5 * (seed % 3)
            b = effective_memory(W5, g)
            frames = _tiny_crossing(seed)
            result = detect(frames, W5, b, g, max_targets=2, nms_radius=2, exclusive="joint")
            changed += any(t.retracked for t in result.tracks)
        assert changed >= 6, changed  # measured 9 of 12

    @pytest.mark.parametrize("seed", range(20))
    def test_best_pair_equals_brute_force(self, seed):
        gen = torch.Generator().manual_seed(seed)
        n1, n2 = 1 + seed % 5, 1 + (seed * 7) % 6
        s1 = torch.randint(-3, 4, (n1,), generator=gen).double()  # ties on purpose
        s2 = torch.randint(-3, 4, (n2,), generator=gen).double()
        xy1 = torch.randint(0, 4, (n1, 2), generator=gen)
        xy2 = torch.randint(0, 4, (n2, 2), generator=gen)
        for share in (False, True):
            apart = lambda a, b: int((xy1[a] - xy2[b]).abs().max()) > 1  # noqa: E731
            pairs = [(a, b) for a in range(n1) for b in range(n2)]
            allowed = [ab for ab in pairs if share or apart(*ab)] or pairs
            best = max(float(s1[a] + s2[b]) for a, b in allowed)
            first = next(ab for ab in allowed if float(s1[ab[0]] + s2[ab[1]]) == best)
            assert _best_pair(s1, s2, xy1, xy2, share) == first

    @pytest.mark.parametrize("exclusive", [True, False, "joint", "retrack"])
    def test_separate_targets_unchanged(self, exclusive):
        seq = _two_targets(0)
        frames = anti_mean(seq.frames)
        a = detect(frames, W7, B7, 0.5, max_targets=2, exclusive=exclusive)
        b = detect(frames, W7, B7, 0.5, max_targets=2, exclusive=False)
        for x, y in zip(a.tracks, b.tracks, strict=True):
            assert torch.equal(x.positions, y.positions) and not x.retracked

    def test_true_means_straightest(self):
        frames, _ = _crossing(0, 0.5)
        b = effective_memory(W7, 1.0)
        a = detect(frames, W7, b, 1.0, max_targets=2)
        c = detect(frames, W7, b, 1.0, max_targets=2, exclusive="straightest")
        assert EXCLUSIVE_METHODS[0] == "straightest"
        for x, y in zip(a.tracks, c.tracks, strict=True):
            assert torch.equal(x.positions, y.positions) and x.retracked == y.retracked

    @pytest.mark.parametrize("seed", range(4))
    @pytest.mark.parametrize("g", [0.0, 1.0])
    @pytest.mark.parametrize("low", [0.0, 3.0])
    def test_straightest_picks_the_straighter_pair(self, seed, g, low):
        # the slow reference: the joint pair, and the re-tracked pair (or the plain one when
        # the plain tracks meet without sharing more than max_shared), each if its tracks
        # share at most 25 % of their frames; keep the one with the smaller sum of squared
        # residuals of straight lines fitted to (x, y)(t), the joint pair on ties
        frames, _ = _crossing(seed, 0.71 / R2, low=low)  # low = 3: a near miss
        b = effective_memory(W7, g)
        run = lambda ex: detect(frames, W7, b, g, max_targets=2, exclusive=ex).tracks  # noqa: E731
        got, joint, retrack, plain = run(True), run("joint"), run("retrack"), run(False)

        def bend(tracks):
            t = np.arange(25.0)
            return sum(
                float(np.sum((np.polyval(np.polyfit(t, xy, 1), t) - xy) ** 2))
                for tr in tracks
                for xy in tr.positions.double().numpy().T
            )

        def share(tracks):
            a, c = (tr.positions for tr in tracks)
            return float(((a - c).abs().amax(dim=1) <= 1).double().mean())

        options = [tracks for tracks in (joint,) if len(tracks) == 2 and share(tracks) <= 0.25]
        if share(plain) > 0.25:
            options += [retrack] if len(retrack) == 2 and share(retrack) <= 0.25 else []
        else:
            options.append(plain)
        best = min(options, key=bend)
        assert len(got) == len(best) == 2
        for x, y in zip(got, best, strict=True):
            assert torch.equal(x.positions, y.positions)

    def test_exceptions(self):
        frames = torch.randn(4, 10, 10)
        for bad in (1, None, 0.5, ["joint"]):
            with pytest.raises(TypeError, match="`exclusive`: expected True, False or one of"):
                detect(frames, W5, B5, 0.5, exclusive=bad)
        for bad in ("Joint", "masked", ""):
            with pytest.raises(
                ValueError, match="`exclusive`: expected one of 'straightest', 'joint', 'retrack'"
            ):
                detect(frames, W5, B5, 0.5, exclusive=bad)
        for bad in (-0.1, 1.0):
            with pytest.raises(ValueError, match="`max_shared`"):
                detect(frames, W5, B5, 0.5, max_shared=bad)


class TestDetectIssue9:
    def test_empty_batch(self):
        result = detect(np.zeros((0, 6, 16, 16), bool), W5, B5, 0.5)
        assert result.tracks == [] and result.state.asf.shape == (0, 6, 16, 16)
        result = detect(torch.zeros(0, 6, 16, 16), W5, B5, 0.5, threshold=1.0)
        assert result.tracks == [] and result.threshold == 1.0

    def test_all_zero_and_constant_input_have_no_track(self):
        for frames in (torch.zeros(6, 16, 16), torch.full((6, 16, 16), 3.0)):
            assert detect(frames, W5, B5, 0.5).tracks == []
            assert detect(frames.unsqueeze(0), W5, B5, 0.5).tracks == []
        batch = torch.stack([torch.zeros(6, 16, 16), torch.randn(6, 16, 16)])
        assert {t.batch for t in detect(batch, W5, B5, 0.5).tracks} == {1}

    def test_pure_noise_without_threshold_is_unconfirmed(self):
        noise = torch.randn(2, 8, 24, 24, generator=torch.Generator().manual_seed(0))
        result = detect(noise, W5, B5, 0.5)
        assert result.tracks and not result.confirmed
        assert all(not t.confirmed for t in result.tracks)
        assert result.note.startswith("unthresholded")

    def test_cfar_threshold_reports_only_what_passes(self):
        seq = simulate_ir((8, 24, 24), clouds="clear", batch=24, seed=1)
        free = anti_mean(seq.target_free)
        noise = anti_mean(simulate_ir((8, 24, 24), clouds="clear", batch=8, seed=2).frames)
        result = detect(noise, W5, B5, 0.5, target_free=free, pfa=1e-3, max_targets=50)
        assert result.confirmed and all(t.confirmed for t in result.tracks)
        assert all(t.score > result.threshold for t in result.tracks)
        last = result.state.asf[:, -1]
        assert len(result.tracks) <= int((last > result.threshold).sum())
        # per-pixel Pfa 1e-3 on 8 x 576 pixels: a handful of false alarms, not 5 per scene
        assert len(result.tracks) <= 12

    def test_b_above_the_memory_range_names_b(self):
        # issue 9's b = 1e30 (and b = 3 at g = 1) are now refused up front by `accumulate`
        frames = torch.randn(30, 12, 12, generator=torch.Generator().manual_seed(0))
        limit = b_limit(W5, 0.0)
        with pytest.raises(ValueError, match=r"`b`: expected a value in \[0, 7\.99.*eq\. \(12\)"):
            detect(frames, W5, 1e30, 0.0)
        with pytest.raises(ValueError, match=r"`b`: expected a value in \[0, 1\]"):
            detect(frames, W7, 3.0, 1.0)
        assert detect(frames, W5, limit, 0.0).tracks  # the end of the range is accepted

    def test_overflow_names_b(self):
        # b at the end of the memory range (EMC 1 in directions 1-8) has an EMC of 1.39 in
        # direction 9 at g = 0: on a long sequence the in-place scores grow geometrically until
        # float32 overflows (measured: frame 268 of 300), which the recursion reports
        noise = torch.randn(300, 12, 12, generator=torch.Generator().manual_seed(0))
        b = b_limit(W5, 0.0)
        with pytest.raises(ValueError, match=r"`b`: the accumulated score overflowed") as info:
            detect(noise, W5, b, 0.0)
        first = int(re.search(r"at frame (\d+)", str(info.value)).group(1))
        assert 1 <= first < 300
        # the frame named is the first one: one frame fewer is finite
        assert bool(torch.isfinite(accumulate(noise[:first], W5, b, 0.0).asf).all())
        with pytest.raises(ValueError, match=rf"`b`: .*overflowed.* at frame {first}\b"):
            accumulate(noise[: first + 1], W5, b, 0.0)


def test_cfar_threshold_overflow_names_b():
    frames = torch.randn(30, 12, 12, generator=torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match=r"`b`: expected a value in \[0, 7\.99"):
        cfar_threshold(frames, W5, 1e30, 0.0)
    noise = torch.randn(300, 12, 12, generator=torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match=r"`b`: the accumulated score overflowed"):
        cfar_threshold(noise, W5, b_limit(W5, 0.0), 0.0)


def test_cfar_threshold_leaves_out_sequences_without_usable_last_frame():
    noise = torch.randn(3, 4, 12, 12, generator=torch.Generator().manual_seed(1))
    good = cfar_threshold(noise, W5, 0.5, 0.0, pfa=0.01)
    # a sequence whose last frame is all zero (frame 0 after background removal) gives no
    # sample: the old code mixed its zeros in and lowered the threshold
    padded = torch.cat([noise, torch.zeros(3, 4, 12, 12)])
    padded[3:, :-1] = 0.0
    assert cfar_threshold(padded, W5, 0.5, 0.0, pfa=0.01) == good
    with pytest.raises(ValueError, match=r"`target_free`: expected at least one sequence"):
        cfar_threshold(torch.zeros(1, 12, 12), W5, 0.5, 0.0, pfa=0.01)
    with pytest.raises(ValueError, match=r"`target_free`: .*none usable"):
        detect(noise, W5, 0.5, 0.0, target_free=torch.zeros(2, 12, 12))


def test_detect_accepts_bool_frames_like_accumulate():
    frames = torch.zeros(4, 16, 16, dtype=torch.bool)
    for t in range(4):
        frames[t, 5, 3 + t] = True
    as_float = detect(frames.float(), W5, 0.5, 0.0, threshold=0.5)
    found = detect(frames, W5, 0.5, 0.0, threshold=0.5)
    assert len(found.tracks) == len(as_float.tracks) >= 1
    for a, b in zip(found.tracks, as_float.tracks, strict=True):
        assert torch.equal(a.positions, b.positions)
    assert detect(frames[None][:0], W5, 0.5, 0.0).tracks == []


def test_detect_target_free_of_another_size_names_target_free():
    frames = torch.randn(4, 16, 16, generator=torch.Generator().manual_seed(0))
    for size in ((20, 20), (12, 16), (16, 8)):
        free = torch.randn(4, *size, generator=torch.Generator().manual_seed(1))
        with pytest.raises(
            ValueError, match=r"`target_free`: expected frames of .*\(16, 16\), got "
        ):
            detect(frames, W5, 0.5, 0.0, target_free=free)
    free = torch.randn(4, 20, 20)
    with pytest.raises(ValueError, match=r"`target_free`"):
        detect(frames[None][:0], W5, 0.5, 0.0, target_free=free)

import math

import numpy as np
import pytest
import torch

from hocnet.data.infrared import IRTarget, simulate_ir
from hocnet.data.whitening import anti_mean
from hocnet.dpa.functional import accumulate
from hocnet.dpa.matrices import effective_memory, probability_matrices
from hocnet.dpa.metrics import (
    algorithm_score,
    block_snr,
    detection_probability,
    frame_thresholds,
    frames_to_reach,
    tracking_success,
)


@pytest.fixture(autouse=True)
def _single_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


W7 = probability_matrices(7, v_max=2.0)
B7 = effective_memory(W7, 0.5)


def block_snr_loop(image, x, y, block, max_numbers):
    """Slow oracle of eq. (16) on a (H, W) array at pixel (x, y)."""
    n_h, n_w = image.shape
    h = block // 2
    target, background = [], []
    for by in (-1, 0, 1):
        for bx in (-1, 0, 1):
            cy, cx = y + by * block, x + bx * block
            for yy in range(cy - h, cy + h + 1):
                for xx in range(cx - h, cx + h + 1):
                    if 0 <= yy < n_h and 0 <= xx < n_w:
                        (target if by == bx == 0 else background).append(float(image[yy, xx]))
    top = sorted(target, reverse=True)[:max_numbers]
    signal = sum(top) / len(top)
    mean = sum(background) / len(background)
    std = math.sqrt(sum((v - mean) ** 2 for v in background) / len(background))
    if max(background) == min(background):
        diff = signal - min(background)
        return math.inf if diff > 0 else -math.inf if diff < 0 else 0.0
    return (signal - mean) / std


class TestBlockSNR:
    def test_smoke_shapes(self):
        image = torch.randn(3, 20, 20)
        out = block_snr(image, torch.tensor([[5, 5], [10.2, 3.7], [19, 0]]))
        assert out.shape == (3,) and out.dtype == torch.float32
        assert block_snr(image[0], torch.tensor([5, 5])).shape == ()
        assert block_snr(image.double(), torch.tensor([5, 5])).dtype == torch.float64
        assert block_snr(image.long(), torch.tensor([5, 5])).dtype == torch.get_default_dtype()

    def test_hand_computation(self):
        # 11 x 11 image, block 3: background = the 8 blocks around the centre pixel (5, 5),
        # i.e. rows and columns 1..9 minus the target block 4..6
        image = torch.zeros(11, 11)
        image[4:7, 4:7] = torch.tensor([[1.0, 2.0, 0.0], [0.0, 9.0, 4.0], [0.0, 0.0, 3.0]])
        image[0, 0] = image[10, 5] = 100.0  # outside the 3 x 3 blocks: ignored
        image[3, 3] = 2.0  # in the upper-left background block
        image[7, 6] = -2.0  # in the lower-middle background block
        bg = [0.0] * 70 + [2.0, -2.0]  # 8 blocks of 9 pixels
        mean = sum(bg) / 72
        std = math.sqrt(sum((v - mean) ** 2 for v in bg) / 72)
        got = block_snr(image, torch.tensor([5, 5]), block=3)
        assert float(got) == pytest.approx((9.0 - mean) / std, rel=1e-6)
        got = block_snr(image, torch.tensor([5, 5]), block=3, max_numbers=3)
        assert float(got) == pytest.approx(((9 + 4 + 3) / 3 - mean) / std, rel=1e-6)

    def test_max_numbers(self):
        image = torch.zeros(15, 15)
        image[0::3] = 1.0
        image[6:9, 6:9] = torch.tensor([[10.0, 0, 0], [0, 8.0, 0], [0, 0, 6.0]])
        values = [float(block_snr(image, torch.tensor([7, 7]), max_numbers=m)) for m in (1, 2, 3)]
        ref = [block_snr_loop(image.numpy(), 7, 7, 5, m) for m in (1, 2, 3)]
        np.testing.assert_allclose(values, ref, rtol=1e-6)
        assert values[0] > values[1] > values[2]
        all_of_it = float(block_snr(image, torch.tensor([7, 7]), max_numbers=25))
        assert all_of_it == pytest.approx(block_snr_loop(image.numpy(), 7, 7, 5, 25), rel=1e-6)

    @pytest.mark.parametrize("seed", range(8))
    def test_equals_loop(self, seed):
        gen = torch.Generator().manual_seed(seed)
        block = (1, 3, 5, 7)[seed % 4]
        image = torch.randn(4, 13, 17, generator=gen, dtype=torch.float64)
        xy = torch.stack(
            [torch.randint(0, 17, (4,), generator=gen), torch.randint(0, 13, (4,), generator=gen)],
            dim=1,
        )
        xy[0] = torch.tensor([0, 0])  # corner: clipped blocks
        xy[1] = torch.tensor([16, 12])
        m = 1 + seed % min(3, block * block)
        got = block_snr(image, xy, block=block, max_numbers=m)
        for b in range(4):
            ref = block_snr_loop(image[b].numpy(), int(xy[b, 0]), int(xy[b, 1]), block, m)
            assert float(got[b]) == pytest.approx(ref, rel=1e-10, abs=1e-12)

    def test_clipped_target_block_with_many_numbers(self):
        image = torch.randn(10, 10, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
        # at a corner the 5 x 5 target block keeps 3 x 3 pixels: all 9 are averaged
        got = block_snr(image, torch.tensor([0, 0]), max_numbers=20)
        assert float(got) == pytest.approx(block_snr_loop(image.numpy(), 0, 0, 5, 20))

    def test_float_position_uses_containing_pixel(self):
        image = torch.randn(2, 16, 16, generator=torch.Generator().manual_seed(2))
        a = block_snr(image, torch.tensor([[7.49, 8.5], [3.0, 2.51]]))
        b = block_snr(image, torch.tensor([[7, 9], [3, 3]]))
        np.testing.assert_array_equal(a.numpy(), b.numpy())

    def test_position_broadcast(self):
        image = torch.randn(3, 16, 16, generator=torch.Generator().manual_seed(3))
        a = block_snr(image, torch.tensor([6, 9]))
        b = torch.stack([block_snr(image[i], torch.tensor([6, 9])) for i in range(3)])
        np.testing.assert_array_equal(a.numpy(), b.numpy())

    def test_constant_background(self):
        image = torch.ones(2, 15, 15)
        image[0, 7, 7] = 3.0
        image[1, 5:10, 5:10] = -3.0  # the whole target block below the background
        assert block_snr(image, torch.tensor([7, 7])).tolist() == [math.inf, -math.inf]
        assert float(block_snr(torch.full((15, 15), 0.1), torch.tensor([7, 7]))) == 0.0

    def test_exceptions(self):
        image = torch.randn(16, 16)
        pos = torch.tensor([5, 5])
        for block in (0, 4, -3):
            with pytest.raises(ValueError, match="`block`"):
                block_snr(image, pos, block=block)
        with pytest.raises(TypeError, match="`block`"):
            block_snr(image, pos, block=3.0)
        for m in (0, 10):
            with pytest.raises(ValueError, match="`max_numbers`"):
                block_snr(image, pos, block=3, max_numbers=m)
        with pytest.raises(ValueError, match="`image`"):
            block_snr(torch.randn(16), pos)
        with pytest.raises(ValueError, match="`image`"):
            block_snr(torch.full((16, 16), math.nan), pos)
        with pytest.raises(TypeError, match="`image`"):
            block_snr(torch.zeros(16, 16, dtype=torch.bool), pos)
        with pytest.raises(ValueError, match="`position`: expected shape"):
            block_snr(image, torch.tensor([[5, 5]]))
        with pytest.raises(ValueError, match="`position`: expected shape"):
            block_snr(torch.randn(2, 16, 16), torch.zeros(3, 2))
        with pytest.raises(ValueError, match=r"`position`: expected \(x, y\) inside"):
            block_snr(image, torch.tensor([16, 3]))
        with pytest.raises(ValueError, match="`position`"):
            block_snr(image, torch.tensor([math.inf, 3.0]))
        with pytest.raises(ValueError, match="`image`: expected background"):
            block_snr(torch.randn(5, 5), torch.tensor([2, 2]))


class TestAlgorithmScore:
    def test_equals_mean_block_snr(self):
        gen = torch.Generator().manual_seed(0)
        asf = torch.randn(2, 8, 16, 16, generator=gen, dtype=torch.float64)
        pos = torch.rand(2, 3, 8, 2, generator=gen, dtype=torch.float64) * 15
        got = algorithm_score(asf, pos, last=4, block=3, max_numbers=2)
        assert got.shape == (2,) and got.dtype == torch.float64
        for b in range(2):
            snrs = [
                block_snr(asf[b, t], pos[b, n, t], block=3, max_numbers=2)
                for n in range(3)
                for t in range(4, 8)
            ]
            assert float(got[b]) == pytest.approx(float(torch.stack(snrs).mean()), rel=1e-12)

    def test_shapes(self):
        asf = torch.randn(2, 7, 16, 16)
        pos = torch.full((2, 7, 2), 8.0)
        assert algorithm_score(asf, pos).shape == (2,)
        assert algorithm_score(asf, pos.unsqueeze(1)).shape == (2,)
        one = algorithm_score(asf[0], pos[0])
        assert one.shape == () and float(one) == pytest.approx(float(algorithm_score(asf, pos)[0]))
        assert algorithm_score(asf[0], pos[0].unsqueeze(0)).shape == ()
        assert float(algorithm_score(asf, pos, last=1)[1]) == pytest.approx(
            float(block_snr(asf[1, -1], pos[1, -1]))
        )

    def test_higher_with_target(self):
        target = IRTarget(8.0, 10.0, 1.0, 0.5, snr_db=12.0)
        seq = simulate_ir((12, 32, 32), [target], clouds="clear", batch=3, seed=4)
        with_target = accumulate(anti_mean(seq.frames), W7, B7, 0.5).asf
        without = accumulate(anti_mean(seq.target_free), W7, B7, 0.5).asf
        a = algorithm_score(with_target, seq.positions)
        b = algorithm_score(without, seq.positions)
        # about 3.9 against 2.2 (the target-free value is biased up by the max of the block)
        assert bool((a > b + 1.0).all()), (a, b)

    def test_exceptions(self):
        asf = torch.randn(2, 7, 16, 16)
        pos = torch.full((2, 7, 2), 8.0)
        for last in (0, 8):
            with pytest.raises(ValueError, match="`last`"):
                algorithm_score(asf, pos, last=last)
        with pytest.raises(ValueError, match="`positions`"):
            algorithm_score(asf, pos[:, :5])
        with pytest.raises(ValueError, match="`positions`"):
            algorithm_score(asf, pos[:1])
        with pytest.raises(ValueError, match="`positions`"):
            algorithm_score(asf, pos[0])
        with pytest.raises(ValueError, match="`positions`: expected at least one target"):
            algorithm_score(asf, torch.zeros(2, 0, 7, 2))
        with pytest.raises(ValueError, match=r"`positions`: expected \(x, y\) inside"):
            algorithm_score(asf, pos + 10)
        with pytest.raises(ValueError, match="`asf`"):
            algorithm_score(asf[0, 0], pos)
        with pytest.raises(ValueError, match="`block`"):
            algorithm_score(asf, pos, block=2)
        with pytest.raises(ValueError, match="`max_numbers`"):
            algorithm_score(asf, pos, max_numbers=26)


class TestTrackingSuccess:
    def test_hand_made(self):
        truth = torch.tensor([[t * 1.0, 0.5 * t] for t in range(10)])
        good = torch.round(truth).long()
        assert bool(tracking_success(good, truth, fraction=1.0))
        off = good.clone()
        off[:2] += 5  # 2 of 10 frames off: 80 % hits
        assert bool(tracking_success(off, truth))
        assert not bool(tracking_success(off, truth, fraction=0.81))
        assert bool(tracking_success(off, truth, fraction=1.0, last=8))
        assert not bool(tracking_success(off, truth, fraction=1.0, last=9))

    def test_radius_is_inclusive(self):
        truth = torch.zeros(4, 2, dtype=torch.float64)
        traj = torch.tensor([[3, 4]] * 4)  # distance exactly 5
        assert bool(tracking_success(traj, truth, radius=5.0))
        assert not bool(tracking_success(traj, truth, radius=4.99))

    def test_batched(self):
        truth = torch.zeros(3, 5, 2)
        traj = torch.zeros(3, 5, 2, dtype=torch.long)
        traj[1, :, 0] = 2
        traj[2, 0, 0] = 2
        out = tracking_success(traj, truth)
        assert out.dtype == torch.bool and out.tolist() == [True, False, True]
        assert tracking_success(traj[0], truth[0]).shape == ()

    def test_exceptions(self):
        truth = torch.zeros(5, 2)
        traj = torch.zeros(5, 2)
        with pytest.raises(ValueError, match="`truth`"):
            tracking_success(traj, truth[:4])
        with pytest.raises(ValueError, match="`trajectory`"):
            tracking_success(torch.zeros(5, 3), torch.zeros(5, 3))
        with pytest.raises(ValueError, match="`truth`"):
            tracking_success(traj, torch.full((5, 2), math.nan))
        for radius in (0.0, -1.0):
            with pytest.raises(ValueError, match="`radius`"):
                tracking_success(traj, truth, radius=radius)
        for fraction in (0.0, 1.1):
            with pytest.raises(ValueError, match="`fraction`"):
                tracking_success(traj, truth, fraction=fraction)
        for last in (0, 6):
            with pytest.raises(ValueError, match="`last`"):
                tracking_success(traj, truth, last=last)


class TestFramesToReach:
    def test_interpolation(self):
        pd = torch.tensor([0.0, 0.5, 0.8, 1.0], dtype=torch.float64)
        frames = torch.tensor([2, 4, 6, 8])
        assert frames_to_reach(pd, frames, 0.9) == pytest.approx(7.0)
        assert frames_to_reach(pd, frames, 0.25) == pytest.approx(3.0)
        assert frames_to_reach(pd, frames, 0.8) == pytest.approx(6.0)  # exactly on a point
        assert frames_to_reach(pd, frames, 0.0) == 2.0  # reached at the first point

    def test_first_crossing_and_never(self):
        pd = torch.tensor([0.2, 1.0, 0.4, 1.0], dtype=torch.float64)
        assert frames_to_reach(pd, torch.tensor([1.0, 2.0, 3.0, 4.0]), 0.6) == pytest.approx(1.5)
        assert frames_to_reach(torch.tensor([0.1, 0.5]), torch.tensor([1, 2])) == math.inf
        assert frames_to_reach(torch.tensor([0.95]), torch.tensor([10])) == 10.0

    def test_exceptions(self):
        pd, frames = torch.tensor([0.1, 0.9]), torch.tensor([1, 2])
        with pytest.raises(ValueError, match="`pd_curve`"):
            frames_to_reach(torch.tensor([0.1, 1.2]), frames)
        with pytest.raises(ValueError, match="`pd_curve`"):
            frames_to_reach(torch.zeros(2, 2), frames)
        with pytest.raises(ValueError, match="`frames`"):
            frames_to_reach(pd, torch.tensor([1, 2, 3]))
        with pytest.raises(ValueError, match="`frames`: expected strictly increasing"):
            frames_to_reach(pd, torch.tensor([2, 2]))
        with pytest.raises(ValueError, match="`level`"):
            frames_to_reach(pd, frames, 1.5)
        with pytest.raises(TypeError, match="`pd_curve`"):
            frames_to_reach("high", frames)


class TestFrameThresholds:
    def test_rate_per_frame(self):
        asf = torch.randn(4, 5, 10, 10, generator=torch.Generator().manual_seed(0))
        thr = frame_thresholds(asf, pfa=0.05)
        assert thr.shape == (5,) and thr.dtype == torch.float32
        above = (asf > thr.view(1, 5, 1, 1)).sum(dim=(0, 2, 3))
        assert above.tolist() == [20] * 5
        single = frame_thresholds(asf[0], 0.05)  # 100 pixels per frame: the 6th largest
        sixth = [
            float(torch.sort(asf[0, t].flatten(), descending=True).values[5]) for t in range(5)
        ]
        assert single.tolist() == sixth

    def test_exceptions(self):
        with pytest.raises(ValueError, match=r"`pfa`.*at least 1000 samples"):
            frame_thresholds(torch.randn(2, 3, 10, 10), 1e-3)
        with pytest.raises(ValueError, match="`asf`"):
            frame_thresholds(torch.randn(10, 10), 0.1)
        with pytest.raises(ValueError, match="`pfa`"):
            frame_thresholds(torch.randn(2, 3, 10, 10), 0.0)


class TestDetectionProbability:
    def test_hand_made(self):
        asf = torch.zeros(2, 4, 10, 10)
        asf[0, 1:, 5, 6] = 5.0  # 1.02 px from the truth (4.8, 5.2): inside the radius
        asf[1, 3, 2, 2] = 5.0  # far from the truth
        pos = torch.tensor([4.8, 5.2]).expand(2, 4, 2)
        assert detection_probability(asf, pos, 1.0).tolist() == [0.0, 0.5, 0.5, 0.5]
        assert detection_probability(asf, pos, 1.0, radius=1.0).tolist() == [0.0] * 4
        per_frame = torch.tensor([1.0, 1.0, 6.0, 1.0])
        assert detection_probability(asf, pos, per_frame).tolist() == [0.0, 0.5, 0.0, 0.5]
        assert detection_probability(asf, pos, 5.0).tolist() == [0.0] * 4  # strictly above

    def test_several_targets_and_outside(self):
        asf = torch.zeros(3, 8, 8)
        asf[:, 1, 1] = 2.0
        pos = torch.tensor([[[1.0, 1.0]] * 3, [[20.0, -9.0]] * 3])  # (N, T, 2), one far outside
        assert detection_probability(asf, pos, 1.0).tolist() == [0.5, 0.5, 0.5]
        edge = torch.tensor([[[8.3, 1.0]] * 3])  # just outside: pixel (7, 1) is 1.3 px away
        asf[:, 1, 7] = 2.0
        assert detection_probability(asf, edge, 1.0).tolist() == [1.0] * 3

    def test_pd_curve_with_cfar(self):
        target = IRTarget(8.0, 10.0, 1.0, 0.5, snr_db=9.0)
        seq = simulate_ir((10, 32, 32), [target], clouds="clear", batch=16, seed=1)
        asf = accumulate(anti_mean(seq.frames), W7, B7, 0.5).asf
        free = accumulate(anti_mean(seq.target_free), W7, B7, 0.5).asf
        thr = frame_thresholds(free, 0.01)
        pd = detection_probability(asf, seq.positions, thr)
        assert pd.shape == (10,) and pd.dtype == torch.float64
        assert float(pd[-3:].mean()) > float(pd[0]) + 0.1  # accumulation helps
        assert 1.0 <= frames_to_reach(pd, torch.arange(1, 11), 0.9) <= 10.0
        free_pd = detection_probability(free, seq.positions, thr)
        assert float(free_pd.mean()) < 0.2  # chance hits of the 1 % background near the truth

    def test_exceptions(self):
        asf = torch.zeros(3, 8, 8)
        pos = torch.zeros(3, 2)
        with pytest.raises(ValueError, match="`threshold`"):
            detection_probability(asf, pos, torch.zeros(4))
        with pytest.raises(ValueError, match="`threshold`"):
            detection_probability(asf, pos, math.nan)
        with pytest.raises(ValueError, match="`radius`"):
            detection_probability(asf, pos, 1.0, radius=-1.0)
        with pytest.raises(ValueError, match="`positions`"):
            detection_probability(asf, torch.zeros(4, 2), 1.0)

import functools
import itertools
import math

import numpy as np
import pytest
import torch

from hocnet.data.infrared import IRTarget, na23a_like, simulate_ir
from hocnet.data.whitening import anti_mean
from hocnet.dpa.functional import accumulate
from hocnet.dpa.matrices import effective_memory, probability_matrices
from hocnet.dpa.metrics import (
    algorithm_score,
    algorithm_score_terms,
    block_snr,
    block_snrs,
    detection_probability,
    frame_thresholds,
    frames_to_reach,
    highest_on_target,
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


def block_snr_c(*args, **kwargs):
    """Our earlier reading of eq. (16), kept as ``reading="centred"``."""
    return block_snr(*args, reading="centred", **kwargs)


def algorithm_score_c(*args, **kwargs):
    return algorithm_score(*args, reading="centred", **kwargs)


class TestBlockSNRCentred:
    def test_smoke_shapes(self):
        image = torch.randn(3, 20, 20)
        out = block_snr_c(image, torch.tensor([[5, 5], [10.2, 3.7], [19, 0]]))
        assert out.shape == (3,) and out.dtype == torch.float32
        assert block_snr_c(image[0], torch.tensor([5, 5])).shape == ()
        assert block_snr_c(image.double(), torch.tensor([5, 5])).dtype == torch.float64
        assert block_snr_c(image.long(), torch.tensor([5, 5])).dtype == torch.get_default_dtype()

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
        got = block_snr_c(image, torch.tensor([5, 5]), block=3)
        assert float(got) == pytest.approx((9.0 - mean) / std, rel=1e-6)
        got = block_snr_c(image, torch.tensor([5, 5]), block=3, max_numbers=3)
        assert float(got) == pytest.approx(((9 + 4 + 3) / 3 - mean) / std, rel=1e-6)

    def test_max_numbers(self):
        image = torch.zeros(15, 15)
        image[0::3] = 1.0
        image[6:9, 6:9] = torch.tensor([[10.0, 0, 0], [0, 8.0, 0], [0, 0, 6.0]])
        values = [float(block_snr_c(image, torch.tensor([7, 7]), max_numbers=m)) for m in (1, 2, 3)]
        ref = [block_snr_loop(image.numpy(), 7, 7, 5, m) for m in (1, 2, 3)]
        np.testing.assert_allclose(values, ref, rtol=1e-6)
        assert values[0] > values[1] > values[2]
        all_of_it = float(block_snr_c(image, torch.tensor([7, 7]), max_numbers=25))
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
        got = block_snr_c(image, xy, block=block, max_numbers=m)
        for b in range(4):
            ref = block_snr_loop(image[b].numpy(), int(xy[b, 0]), int(xy[b, 1]), block, m)
            assert float(got[b]) == pytest.approx(ref, rel=1e-10, abs=1e-12)

    def test_clipped_target_block_with_many_numbers(self):
        image = torch.randn(10, 10, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
        # at a corner the 5 x 5 target block keeps 3 x 3 pixels: all 9 are averaged
        got = block_snr_c(image, torch.tensor([0, 0]), max_numbers=20)
        assert float(got) == pytest.approx(block_snr_loop(image.numpy(), 0, 0, 5, 20))

    def test_float_position_uses_containing_pixel(self):
        image = torch.randn(2, 16, 16, generator=torch.Generator().manual_seed(2))
        a = block_snr_c(image, torch.tensor([[7.49, 8.5], [3.0, 2.51]]))
        b = block_snr_c(image, torch.tensor([[7, 9], [3, 3]]))
        np.testing.assert_array_equal(a.numpy(), b.numpy())

    def test_position_broadcast(self):
        image = torch.randn(3, 16, 16, generator=torch.Generator().manual_seed(3))
        a = block_snr_c(image, torch.tensor([6, 9]))
        b = torch.stack([block_snr_c(image[i], torch.tensor([6, 9])) for i in range(3)])
        np.testing.assert_array_equal(a.numpy(), b.numpy())

    def test_constant_background(self):
        image = torch.ones(2, 15, 15)
        image[0, 7, 7] = 3.0
        image[1, 5:10, 5:10] = -3.0  # the whole target block below the background
        assert block_snr_c(image, torch.tensor([7, 7])).tolist() == [math.inf, -math.inf]
        assert float(block_snr_c(torch.full((15, 15), 0.1), torch.tensor([7, 7]))) == 0.0

    def test_exceptions(self):
        image = torch.randn(16, 16)
        pos = torch.tensor([5, 5])
        for block in (0, 4, -3):
            with pytest.raises(ValueError, match="`block`"):
                block_snr_c(image, pos, block=block)
        with pytest.raises(TypeError, match="`block`"):
            block_snr_c(image, pos, block=3.0)
        for m in (0, 10):
            with pytest.raises(ValueError, match="`max_numbers`"):
                block_snr_c(image, pos, block=3, max_numbers=m)
        with pytest.raises(ValueError, match="`image`"):
            block_snr_c(torch.randn(16), pos)
        with pytest.raises(ValueError, match="`image`"):
            block_snr_c(torch.full((16, 16), math.nan), pos)
        with pytest.raises(TypeError, match="`image`"):
            block_snr_c(torch.zeros(16, 16, dtype=torch.bool), pos)
        with pytest.raises(ValueError, match="`position`: expected shape"):
            block_snr_c(image, torch.tensor([[5, 5]]))
        with pytest.raises(ValueError, match="`position`: expected shape"):
            block_snr_c(torch.randn(2, 16, 16), torch.zeros(3, 2))
        with pytest.raises(ValueError, match=r"`position`: expected \(x, y\) inside"):
            block_snr_c(image, torch.tensor([16, 3]))
        with pytest.raises(ValueError, match="`position`"):
            block_snr_c(image, torch.tensor([math.inf, 3.0]))
        with pytest.raises(ValueError, match="`image`: expected background"):
            block_snr_c(torch.randn(5, 5), torch.tensor([2, 2]))


class TestAlgorithmScoreCentred:
    def test_equals_mean_block_snr_c(self):
        gen = torch.Generator().manual_seed(0)
        asf = torch.randn(2, 8, 16, 16, generator=gen, dtype=torch.float64)
        pos = torch.rand(2, 3, 8, 2, generator=gen, dtype=torch.float64) * 15
        got = algorithm_score_c(asf, pos, last=4, block=3, max_numbers=2)
        assert got.shape == (2,) and got.dtype == torch.float64
        for b in range(2):
            snrs = [
                block_snr_c(asf[b, t], pos[b, n, t], block=3, max_numbers=2)
                for n in range(3)
                for t in range(4, 8)
            ]
            assert float(got[b]) == pytest.approx(float(torch.stack(snrs).mean()), rel=1e-12)

    def test_shapes(self):
        asf = torch.randn(2, 7, 16, 16)
        pos = torch.full((2, 7, 2), 8.0)
        assert algorithm_score_c(asf, pos).shape == (2,)
        assert algorithm_score_c(asf, pos.unsqueeze(1)).shape == (2,)
        one = algorithm_score_c(asf[0], pos[0])
        assert one.shape == () and float(one) == pytest.approx(
            float(algorithm_score_c(asf, pos)[0])
        )
        assert algorithm_score_c(asf[0], pos[0].unsqueeze(0)).shape == ()
        assert float(algorithm_score_c(asf, pos, last=1)[1]) == pytest.approx(
            float(block_snr_c(asf[1, -1], pos[1, -1]))
        )

    def test_higher_with_target(self):
        target = IRTarget(8.0, 10.0, 1.0, 0.5, snr_db=12.0)
        seq = simulate_ir((12, 32, 32), [target], clouds="clear", batch=3, seed=4)
        with_target = accumulate(anti_mean(seq.frames), W7, B7, 0.5).asf
        without = accumulate(anti_mean(seq.target_free), W7, B7, 0.5).asf
        a = algorithm_score_c(with_target, seq.positions)
        b = algorithm_score_c(without, seq.positions)
        # about 3.9 against 2.2 (the target-free value is biased up by the max of the block)
        assert bool((a > b + 1.0).all()), (a, b)

    def test_exceptions(self):
        asf = torch.randn(2, 7, 16, 16)
        pos = torch.full((2, 7, 2), 8.0)
        for last in (0, 8):
            with pytest.raises(ValueError, match="`last`"):
                algorithm_score_c(asf, pos, last=last)
        with pytest.raises(ValueError, match="`positions`"):
            algorithm_score_c(asf, pos[:, :5])
        with pytest.raises(ValueError, match="`positions`"):
            algorithm_score_c(asf, pos[:1])
        with pytest.raises(ValueError, match="`positions`"):
            algorithm_score_c(asf, pos[0])
        with pytest.raises(ValueError, match="`positions`: expected at least one target"):
            algorithm_score_c(asf, torch.zeros(2, 0, 7, 2))
        with pytest.raises(ValueError, match=r"`positions`: expected \(x, y\) inside"):
            algorithm_score_c(asf, pos + 10)
        with pytest.raises(ValueError, match="`asf`"):
            algorithm_score_c(asf[0, 0], pos)
        with pytest.raises(ValueError, match="`block`"):
            algorithm_score_c(asf, pos, block=2)
        with pytest.raises(ValueError, match="`max_numbers`"):
            algorithm_score_c(asf, pos, max_numbers=26)


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


# ----------------------------------------------------------------------------- paper reading


def paper_block_snrs_loop(image, x, y, rows, cols, max_numbers):
    """Slow oracle of eq. (16) of [NR08]: the 9 tiled blocks around the target block.

    The target block spans rows y - rows // 2 .. + rows - 1 (and the same for columns); each
    block's SNR is (mean of its max_numbers highest pixels - mean of its other pixels) / its
    population std. None for a block with at most max_numbers pixels in the frame.
    """
    n_h, n_w = image.shape
    out = []
    for r in (-1, 0, 1):
        for c in (-1, 0, 1):
            y0 = y - rows // 2 + r * rows
            x0 = x - cols // 2 + c * cols
            values = [
                float(image[yy, xx])
                for yy in range(y0, y0 + rows)
                for xx in range(x0, x0 + cols)
                if 0 <= yy < n_h and 0 <= xx < n_w
            ]
            if len(values) <= max_numbers:
                out.append(None)
                continue
            ordered = sorted(values, reverse=True)
            top, rest = ordered[:max_numbers], ordered[max_numbers:]
            mean = sum(values) / len(values)
            std = math.sqrt(sum((v - mean) ** 2 for v in values) / len(values))
            contrast = sum(top) / len(top) - sum(rest) / len(rest)
            out.append(0.0 if std == 0 else contrast / std)
    return out


def paper_score_loop(image, x, y, rows, cols, max_numbers):
    """Slow oracle of eq. (17): (SNR_TB - mean SNR_NTB) / std SNR_NTB (population std)."""
    snrs = paper_block_snrs_loop(image, x, y, rows, cols, max_numbers)
    tb = snrs[4]
    ntb = [s for i, s in enumerate(snrs) if i != 4 and s is not None]
    mean = sum(ntb) / len(ntb)
    std = math.sqrt(sum((s - mean) ** 2 for s in ntb) / len(ntb))
    return (tb - mean) / std


def peak_scene(k, seed, amp=6.0, frames=6, size=90):
    """Unit white noise with ``k`` target pixels of about ``amp`` next to the centre."""
    gen = torch.Generator().manual_seed(seed)
    asf = torch.randn(frames, size, size, generator=gen, dtype=torch.float64)
    c = size // 2
    pixels = [(c, c), (c, c + 1), (c + 1, c), (c + 1, c + 1)][:k]
    for i, (y, x) in enumerate(pixels):
        noise = 0.3 * torch.randn(frames, generator=gen, dtype=torch.float64)
        asf[:, y, x] = amp * (1 - 0.02 * i) + noise
    return asf, torch.full((frames, 2), float(c), dtype=torch.float64)


class TestBlockSNRPaper:
    def test_hand_computation(self):
        image = torch.zeros(9, 9)
        image[3:6, 3:6] = torch.tensor([[1.0, 2.0, 0.0], [0.0, 9.0, 4.0], [0.0, 0.0, 3.0]])
        image[0, 0] = 5.0  # in the upper-left block: only changes that block
        values = [1.0, 2.0, 0.0, 0.0, 9.0, 4.0, 0.0, 0.0, 3.0]
        mean = sum(values) / 9
        std = math.sqrt(sum((v - mean) ** 2 for v in values) / 9)
        got = block_snr(image, torch.tensor([4, 4]), block=3)
        assert float(got) == pytest.approx((9.0 - 10.0 / 8) / std, rel=1e-6)
        got = block_snr(image, torch.tensor([4, 4]), block=3, max_numbers=3)
        assert float(got) == pytest.approx((16.0 / 3 - 3.0 / 6) / std, rel=1e-6)
        snrs = block_snrs(image, torch.tensor([4, 4]), block=3)
        assert float(snrs[0]) == pytest.approx((5.0 - 0.0) / math.sqrt(25 / 9 - (5 / 9) ** 2))
        assert snrs[[1, 2, 3, 5, 6, 7, 8]].tolist() == [0.0] * 7

    @pytest.mark.parametrize("seed", range(6))
    def test_equals_loop(self, seed):
        gen = torch.Generator().manual_seed(seed)
        rows, cols = [(3, 3), (4, 6), (5, 2), (1, 3), (7, 7), (2, 8)][seed]
        image = torch.randn(3, 17, 23, generator=gen, dtype=torch.float64)
        xy = torch.stack(
            [torch.randint(0, 23, (3,), generator=gen), torch.randint(0, 17, (3,), generator=gen)],
            dim=1,
        )
        xy[0] = torch.tensor([0, 0])  # corner: clipped blocks
        m = 1 + seed % 2  # the clipped corner target block keeps >= 3 pixels
        got = block_snrs(image, xy, block=(rows, cols), max_numbers=m)
        for b in range(3):
            ref = paper_block_snrs_loop(
                image[b].numpy(), int(xy[b, 0]), int(xy[b, 1]), rows, cols, m
            )
            for i in range(9):
                if ref[i] is None:
                    assert math.isnan(float(got[b, i]))
                else:
                    assert float(got[b, i]) == pytest.approx(ref[i], rel=1e-10, abs=1e-12)
            if ref[4] is None:  # a clipped target block with <= m pixels
                with pytest.raises(ValueError, match="`max_numbers`"):
                    block_snr(image[b], xy[b], block=(rows, cols), max_numbers=m)
            else:
                tb = block_snr(image[b], xy[b], block=(rows, cols), max_numbers=m)
                assert float(tb) == pytest.approx(ref[4], rel=1e-10, abs=1e-12)

    def test_default_block_is_30(self):
        image = torch.randn(100, 100, generator=torch.Generator().manual_seed(5))
        got = block_snrs(image, torch.tensor([50, 47]))
        ref = paper_block_snrs_loop(image.numpy(), 50, 47, 30, 30, 1)
        np.testing.assert_allclose(got.numpy(), ref, rtol=1e-6)

    def test_exceptions(self):
        image = torch.randn(16, 16)
        pos = torch.tensor([5, 5])
        with pytest.raises(ValueError, match="`reading`"):
            block_snr(image, pos, reading="other")
        with pytest.raises(ValueError, match="`block`"):
            block_snr(image, pos, block=(3, 3, 3))
        with pytest.raises(ValueError, match="`block`"):
            block_snrs(image, pos, block=0)
        with pytest.raises(ValueError, match="`max_numbers`"):
            block_snr(image, pos, block=2, max_numbers=4)
        with pytest.raises(ValueError, match="`max_numbers`"):
            block_snrs(image, pos, max_numbers=0)
        with pytest.raises(ValueError, match="`position`"):
            block_snrs(image, torch.tensor([16, 0]))


class TestAlgorithmScorePaper:
    @pytest.mark.parametrize("seed", range(4))
    def test_equals_loop(self, seed):
        gen = torch.Generator().manual_seed(seed)
        asf = torch.randn(2, 7, 19, 26, generator=gen, dtype=torch.float64)
        pos = torch.rand(2, 2, 7, 2, generator=gen, dtype=torch.float64) * torch.tensor([25, 18])
        rows, cols = [(4, 5), (5, 5), (3, 8), (6, 4)][seed]
        m = 1 + seed % 3
        for anchor in ("first", "each"):
            got = algorithm_score(
                asf, pos, last=3, block=(rows, cols), max_numbers=m, anchor=anchor
            )
            for b in range(2):
                ref = []
                for n in range(2):
                    for t in range(4, 7):
                        at = 0 if anchor == "first" else t
                        x, y = (math.floor(float(v) + 0.5) for v in pos[b, n, at])
                        ref.append(paper_score_loop(asf[b, t].numpy(), x, y, rows, cols, m))
                assert float(got[b]) == pytest.approx(sum(ref) / len(ref), rel=1e-9)

    @pytest.mark.parametrize("k", [1, 2, 3, 4])
    def test_peaks_at_number_of_target_pixels(self, k):
        # [NR08] Table 2: Max_Numbers 3 for g = 0, 1 for g = 1 (the number of high pixels the
        # DPA leaves on the target). Under the paper's reading A_S peaks at Max_Numbers = k;
        # under the centred reading it can only fall, so its peak is 1 whatever k is.
        for seed in range(5):
            asf, pos = peak_scene(k, seed)
            paper = [float(algorithm_score(asf, pos, max_numbers=m)) for m in range(1, 8)]
            centred = [
                float(algorithm_score(asf, pos, max_numbers=m, reading="centred"))
                for m in range(1, 8)
            ]
            assert 1 + int(np.argmax(paper)) == k, (seed, paper)
            assert 1 + int(np.argmax(centred)) == 1, (seed, centred)
            assert all(a >= b - 1e-12 for a, b in itertools.pairwise(centred))

    def test_anchor_first_keeps_tiling_fixed(self):
        asf = torch.randn(5, 60, 60, generator=torch.Generator().manual_seed(9))
        pos = torch.tensor([[30.0 - 3 * t, 30.0] for t in range(5)])
        first = algorithm_score(asf, pos, last=1, block=10)
        fixed = algorithm_score(asf, pos[:1].expand(5, 2), last=1, block=10, anchor="each")
        moved = algorithm_score(asf, pos, last=1, block=10, anchor="each")
        assert float(first) == float(fixed) and float(first) != float(moved)

    def test_target_scores_above_noise(self):
        asf, pos = peak_scene(1, 0, amp=6.0)
        noise, _ = peak_scene(0, 0)
        assert float(algorithm_score(asf, pos)) > 5.0 > float(algorithm_score(noise, pos))

    def test_exceptions(self):
        asf = torch.randn(4, 40, 40)
        pos = torch.full((4, 2), 20.0)
        with pytest.raises(ValueError, match="`reading`"):
            algorithm_score(asf, pos, reading="x")
        with pytest.raises(ValueError, match="`anchor`"):
            algorithm_score(asf, pos, anchor="middle")
        with pytest.raises(ValueError, match="`asf`: expected at least 2 non-target blocks"):
            algorithm_score(asf, pos, last=2, block=(40, 40))
        with pytest.raises(ValueError, match="`max_numbers`"):
            algorithm_score(asf, pos, last=2, block=2, max_numbers=4)


def paper_terms_loop(image, x, y, rows, cols, max_numbers):
    """Slow oracle of the terms of eq. (17): (A_S, SNR_TB, mean SNR_NTB, std SNR_NTB)."""
    snrs = paper_block_snrs_loop(image, x, y, rows, cols, max_numbers)
    ntb = [s for i, s in enumerate(snrs) if i != 4 and s is not None]
    mean = sum(ntb) / len(ntb)
    std = math.sqrt(sum((s - mean) ** 2 for s in ntb) / len(ntb))
    return (snrs[4] - mean) / std, snrs[4], mean, std


class TestAlgorithmScoreTerms:
    @pytest.mark.parametrize("seed", range(3))
    def test_equals_loop_and_score(self, seed):
        gen = torch.Generator().manual_seed(seed)
        asf = torch.randn(2, 6, 20, 27, generator=gen, dtype=torch.float64)
        pos = torch.rand(2, 6, 2, generator=gen, dtype=torch.float64) * torch.tensor([26, 19])
        rows, cols = [(4, 5), (5, 5), (3, 8)][seed]
        m = 1 + seed
        for anchor in ("first", "each"):
            got = algorithm_score_terms(
                asf, pos, last=3, block=(rows, cols), max_numbers=m, anchor=anchor
            )
            score = algorithm_score(
                asf, pos, last=3, block=(rows, cols), max_numbers=m, anchor=anchor
            )
            assert torch.equal(got["score"], score)
            for b in range(2):
                ref = []
                for t in range(3, 6):
                    at = 0 if anchor == "first" else t
                    x, y = (math.floor(float(v) + 0.5) for v in pos[b, at])
                    ref.append(paper_terms_loop(asf[b, t].numpy(), x, y, rows, cols, m))
                for k, key in enumerate(("score", "snr_tb", "ntb_mean", "ntb_std")):
                    want = sum(r[k] for r in ref) / len(ref)
                    assert float(got[key][b]) == pytest.approx(want, rel=1e-9), key

    def test_unbatched_and_exceptions(self):
        asf = torch.randn(4, 40, 40, generator=torch.Generator().manual_seed(3))
        pos = torch.full((4, 2), 20.0)
        terms = algorithm_score_terms(asf, pos, last=2, block=10)
        assert all(v.shape == () for v in terms.values())
        with pytest.raises(ValueError, match="`anchor`"):
            algorithm_score_terms(asf, pos, anchor="middle")
        with pytest.raises(ValueError, match="`last`"):
            algorithm_score_terms(asf, pos, last=5)
        with pytest.raises(ValueError, match="`max_numbers`"):
            algorithm_score_terms(asf, pos, last=2, block=2, max_numbers=4)


def highest_on_target_loop(
    image, truth_first, truth_last, rows, cols, m, radius, anchor, footprint="radius"
):
    """Slow oracle: the m highest pixels of the (clipped) target block all within radius.

    ``footprint="3x3"``: all in the 3 x 3 pixels around the rounded last-frame truth.
    """
    n_h, n_w = image.shape
    ax, ay = truth_first if anchor == "first" else truth_last
    x, y = math.floor(ax + 0.5), math.floor(ay + 0.5)
    values = [
        (float(image[yy, xx]), xx, yy)
        for yy in range(y - rows // 2, y - rows // 2 + rows)
        for xx in range(x - cols // 2, x - cols // 2 + cols)
        if 0 <= yy < n_h and 0 <= xx < n_w
    ]
    top = sorted(values, reverse=True)[:m]
    if footprint == "3x3":
        tx, ty = math.floor(truth_last[0] + 0.5), math.floor(truth_last[1] + 0.5)
        return all(abs(xx - tx) <= 1 and abs(yy - ty) <= 1 for _, xx, yy in top)
    return all(math.hypot(xx - truth_last[0], yy - truth_last[1]) <= radius for _, xx, yy in top)


class TestHighestOnTarget:
    @pytest.mark.parametrize("seed", range(4))
    def test_equals_loop(self, seed):
        gen = torch.Generator().manual_seed(seed)
        asf = torch.randn(5, 4, 24, 30, generator=gen, dtype=torch.float64)
        start = torch.rand(5, 2, generator=gen, dtype=torch.float64) * torch.tensor([29, 23])
        end = (start + 3 * torch.rand(5, 2, generator=gen, dtype=torch.float64)).clamp(
            max=torch.tensor([29.0, 23.0])
        )
        pos = torch.stack([start, (start + end) / 2, (start + end) / 2, end], dim=1)
        for b in range(5):  # a bright target at the last position, sometimes a brighter trail
            x, y = (math.floor(float(v) + 0.5) for v in end[b])
            asf[b, -1, y, x] += 6.0
            if b % 2:
                asf[b, -1, max(y - 3, 0), max(x - 3, 0)] += 5.0 + b
        rows, cols = [(7, 9), (5, 5), (9, 4), (30, 30)][seed]
        m, radius = 1 + seed % 3, [1.5, 1.0, 2.5, 1.5][seed]
        for anchor, footprint in itertools.product(("first", "each"), ("radius", "3x3")):
            got = highest_on_target(
                asf,
                pos,
                block=(rows, cols),
                max_numbers=m,
                radius=radius,
                anchor=anchor,
                footprint=footprint,
            )
            ref = [
                highest_on_target_loop(
                    asf[b, -1].numpy(),
                    pos[b, 0].tolist(),
                    pos[b, -1].tolist(),
                    rows,
                    cols,
                    m,
                    radius,
                    anchor,
                    footprint,
                )
                for b in range(5)
            ]
            assert got.tolist() == ref, (anchor, footprint, got, ref)

    @pytest.mark.parametrize(
        ("xy", "footprint", "expected"),
        [
            # truth (15.5, 15.0): rounded half up to pixel (16, 15)
            ((17, 15), "radius", True),  # exactly 1.5 px: inside (<=)
            ((17, 16), "radius", False),  # 1.80 px
            ((14, 15), "radius", True),  # 1.5 px on the other side
            ((17, 16), "3x3", True),  # Chebyshev 1 from (16, 15): a footprint corner
            ((14, 15), "3x3", False),  # Chebyshev 2
            ((15, 14), "3x3", True),  # Chebyshev 1, 1.80 px
            ((18, 15), "3x3", False),  # Chebyshev 2, 2.5 px
        ],
    )
    def test_boundary(self, xy, footprint, expected):
        asf = torch.zeros(1, 2, 31, 31, dtype=torch.float64)
        truth = torch.tensor([[[15.5, 15.0], [15.5, 15.0]]], dtype=torch.float64)
        asf[0, -1, xy[1], xy[0]] = 5.0
        got = highest_on_target(asf, truth, block=9, radius=1.5, footprint=footprint)
        assert got.tolist() == [expected]
        # just beyond the radius
        if footprint == "radius" and expected:
            far = truth.clone()
            far[..., 0] += math.copysign(1e-9, 15.5 - xy[0])
            assert highest_on_target(asf, far, block=9, radius=1.5).tolist() == [False]

    def test_footprint_corner_beyond_radius(self):
        # a sub-pixel truth 0.4 px off its pixel centre: the far corner of its 3 x 3 spot is
        # 2.0 px away, a target pixel under "3x3" and not under a 1.5 px radius
        asf = torch.zeros(1, 2, 31, 31, dtype=torch.float64)
        truth = torch.tensor([[[15.4, 15.4], [15.4, 15.4]]], dtype=torch.float64)
        asf[0, -1, 14, 14] = 5.0  # Chebyshev 1 from (15, 15), hypot(1.4, 1.4) = 1.98 px
        assert highest_on_target(asf, truth, block=9, footprint="3x3").tolist() == [True]
        assert highest_on_target(asf, truth, block=9).tolist() == [False]

    def test_target_then_trail(self):
        asf = torch.zeros(1, 3, 40, 40)
        truth = torch.tensor([[[20.0, 20.0], [18.8, 20.0], [17.6, 20.0]]])
        asf[0, -1, 20, 18] = 10.0  # the target pixel, 0.4 px from the truth
        asf[0, -1, 20, 19] = 8.0  # 1.4 px: still a target pixel
        asf[0, -1, 20, 21] = 9.0  # 3.4 px behind: trail
        assert highest_on_target(asf, truth, block=9).tolist() == [True]
        assert highest_on_target(asf, truth, block=9, max_numbers=2).tolist() == [False]
        assert highest_on_target(asf, truth, block=9, max_numbers=2, radius=3.5).tolist() == [True]
        # a brighter pixel outside the target block does not count
        asf[0, -1, 2, 2] = 50.0
        assert highest_on_target(asf, truth, block=9).tolist() == [True]
        assert highest_on_target(asf[0], truth[0], block=9).shape == ()

    def test_exceptions(self):
        asf = torch.randn(2, 3, 20, 20)
        truth = torch.full((2, 3, 2), 10.0)
        with pytest.raises(ValueError, match="`anchor`"):
            highest_on_target(asf, truth, anchor="x")
        with pytest.raises(ValueError, match="`radius`"):
            highest_on_target(asf, truth, radius=0.0)
        with pytest.raises(ValueError, match="`footprint`"):
            highest_on_target(asf, truth, footprint="disc")
        with pytest.raises(ValueError, match="`positions`"):
            highest_on_target(asf, truth[:, :2])
        with pytest.raises(ValueError, match="`positions`"):
            highest_on_target(asf, torch.full((2, 3, 2), 25.0))
        with pytest.raises(ValueError, match="`max_numbers`"):
            highest_on_target(asf, truth, block=2, max_numbers=4)
        with pytest.raises(TypeError, match="`positions`"):
            highest_on_target(asf, "here")


# ----------------------------------------------------------------------------- Max_Numbers scene

MN_SEEDS = (0, 1, 2)


@functools.cache
def max_numbers_scene(psf: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Whitened frames ``(3, 25, 90, 240)`` and truth ``(3, 25, 2)`` of the NA23A s_n = 4 scene.

    The scene of [NR08] section 3.2.1(3) as far as the paper is explicit: NA23A, a single target
    in clear sky moving right to left at 0.3 px/frame, every 4th frame kept (s_n = 4, 1.2
    px/frame), 25 kept frames, anti-mean whitening (section 2.1). Our readings: white noise for
    the clear sky, Table 2's maximal peak 60 as a peak-to-noise ratio, the assumed U[-0.5, 0.5]
    jitter; our choice (``psf="pixel"``, departing from eq. (1)'s Gaussian target): the whole
    peak in one lit pixel.
    """
    seqs = [na23a_like(shape=(97, 90, 240), seed=s, psf=psf) for s in MN_SEEDS]
    frames = anti_mean(torch.stack([q.frames[::4] for q in seqs]))
    return frames, torch.stack([q.positions[0, ::4] for q in seqs])


@functools.cache
def max_numbers_curves(psf: str, g: float) -> torch.Tensor:
    """``(seeds, 7)`` A_S (eq. 16-17, mean over the last 6 frames) for Max_Numbers 1..7.

    5 x 5 matrices (0-1 px/frame, section 3), b = 4.8 for g = 0 and 0.8 for g = 1 (the paper's
    b of its Max_Numbers study), 30 x 80 blocks (section 3.2.1(2)).
    """
    frames, truth = max_numbers_scene(psf)
    asf = accumulate(frames, probability_matrices(5, v_max=1.0), {0.0: 4.8, 1.0: 0.8}[g], g).asf
    curves = [
        algorithm_score(asf, truth, last=6, block=(30, 80), max_numbers=m) for m in range(1, 8)
    ]
    return torch.stack(curves, dim=1)


class TestMaxNumbersScene:
    """A constructed-scene test and a knee test of A_S versus Max_Numbers, not Table 2 peak tests.

    [NR08] Table 2 prints Max_Numbers 3 for g = 0 and 1 for g = 1 (NA23A, s_n = 4). It finds
    g = 0's 3 from A_S versus Max_Numbers (Figure 15) and g = 1's 1 by counting the target's
    high pixels in the last frame (Figure 19); its summary 3.2.1(4) prints 1 for g = 0 too.
    These tests do not reproduce Table 2 on the paper's target:

    * ``test_g1_constructed_point_scene_peaks_at_one``: a constructed scene, the one-pixel target
      (``psf="pixel"``, our choice, departing from eq. (1)'s Gaussian target), whose g = 1 ASF
      footprint is one pixel by construction, so A_S falls from Max_Numbers = 1; with the
      presets' Gaussian target (eq. 1) the g = 1 peak moves off 1 (2-4 in these seeds).
    * ``test_g0_knee_at_three``: at g = 0 (b = 4.8) the max recursion keeps the pixels the target
      passed, and A_S rises steeply up to Max_Numbers = 3 and then stays level; the paper's 3 is
      the knee of the curve, and where the maximum falls beyond it is decided by few-% wiggles
      (we do not reproduce a peak at 3 on white noise).

    Measured (seeds 0, 1, 2; A_S for Max_Numbers 1..7, mean over the last 6 frames):

    one-pixel target, g = 1, b = 0.8 (argmax 1 in every scene):
        133.2  89.5  68.9  57.2  49.7  44.4  41.1
        139.6  92.1  69.4  57.9  49.9  44.6  40.9
        127.8  84.0  66.9  59.0  53.1  48.8  44.6
    one-pixel target, g = 0, b = 4.8 (steep rise to 3, then flat within 3 %; argmax 5, 2, 7):
         49.9  61.3  64.7  65.0  65.4  64.4  63.5
         52.5  61.0  60.4  58.9  58.1  56.5  55.5
         42.6  52.0  53.2  53.4  54.2  54.6  54.7
    0.7 px Gaussian PSF (the presets), g = 1 (argmax 3, 2, 4):
         84.7  88.2  89.1  86.7  82.3  78.8  77.5
         88.5  90.7  88.6  84.9  80.8  77.9  76.3
         82.6  86.2  87.5  89.8  89.3  88.4  86.6

    Why: A_S = (SNR_TB - mean SNR_NTB) / std SNR_NTB; std SNR_NTB falls with Max_Numbers in
    white-noise blocks, and SNR_TB falls slowly while the highest pixels are pixels the target
    lights in the ASF and fast beyond. The noise-free footprints (the highest last-ASF pixels
    relative to the highest) are measured by ``experiments/dpa_sampling.py`` (``footprints``,
    the footprint table of ``experiments/results/dpa-sampling.md``).
    """

    def test_g1_constructed_point_scene_peaks_at_one(self):
        point = max_numbers_curves("pixel", 1.0)
        assert (point.argmax(dim=1) == 0).all(), point
        # the spread of the presets' Gaussian PSF is what moves the peak off 1
        gauss = max_numbers_curves("gaussian", 1.0)
        assert (gauss.argmax(dim=1) >= 1).all(), gauss

    def test_g0_knee_at_three(self):
        mean = max_numbers_curves("pixel", 0.0).mean(dim=0)
        assert float(mean[2]) > 1.15 * float(mean[0]), mean
        assert float(mean[1]) < float(mean[2]) <= float(mean.max()) < 1.05 * float(mean[2]), mean


# ----------------------------------------------------------------------------- Max_Numbers peak

PEAK_SEEDS = tuple(range(40))
"""Seeds of :class:`TestMaxNumbersPeak` (g = 0 uses all 40, g = 1 the first 20)."""
PEAK_SNR = 12.0
"""Peak / noise std of the one-pixel target of :class:`TestMaxNumbersPeak` (21.6 dB)."""


@functools.cache
def mn_peak_scene() -> tuple[torch.Tensor, torch.Tensor]:
    """Whitened frames ``(40, 25, 90, 240)`` and truth ``(40, 25, 2)``: NA23A s_n = 4, peak 12."""
    seqs = [
        na23a_like(shape=(97, 90, 240), snr_db=20.0 * math.log10(PEAK_SNR), psf="pixel", seed=seed)
        for seed in PEAK_SEEDS
    ]
    frames = anti_mean(torch.stack([q.frames[::4] for q in seqs]))
    return frames, torch.stack([q.positions[0, ::4] for q in seqs])


@functools.cache
def mn_peak_curves(g: float) -> torch.Tensor:
    """``(n, 7)`` float64 A_S (mean of the last 6 frames), Max_Numbers 1..7, on mn_peak_scene.

    ``n`` = 40 seeds for g = 0 (b = 4.8), the first 20 for g = 1 (b = 0.8).
    """
    frames, truth = mn_peak_scene()
    n = len(PEAK_SEEDS) if g == 0.0 else 20
    frames, truth = frames[:n], truth[:n]
    asf = accumulate(frames, probability_matrices(5, v_max=1.0), {0.0: 4.8, 1.0: 0.8}[g], g).asf
    curves = [
        algorithm_score(asf, truth, last=6, block=(30, 80), max_numbers=m) for m in range(1, 8)
    ]
    return torch.stack(curves, dim=1).double()


def paired_margin(curves: torch.Tensor, best: int, other: int) -> tuple[float, float]:
    """Mean and standard error over the seeds of ``A_S(best) - A_S(other)`` (0-based columns)."""
    diff = curves[:, best] - curves[:, other]
    return float(diff.mean()), float(diff.std()) / math.sqrt(diff.numel())


class TestMaxNumbersPeak:
    """A_S peaks at Max_Numbers 3 for g = 0 and at 1 for g = 1 on one scene ([NR08] Table 2).

    The scene: NA23A as in section 3.2.1(2)-(3) of [NR08] (one target moving right to left at
    0.3 px/frame in clear sky, every 4th frame kept: s_n = 4, 1.2 px/frame, 25 frames, 30 x 80
    blocks, U[-0.5, 0.5] px jitter, anti-mean whitening, 5 x 5 matrices, b = 4.8 for g = 0 and
    0.8 for g = 1, A_S the mean of the last six frames) with two choices of ours: the one-pixel
    target (``psf="pixel"``) and a peak of 12 x the noise std, not Table 2's ~60.

    The g = 0 peak at 3 is small and set by the target's SNR, not by a 3-pixel footprint
    (``experiments/dpa_max_numbers.py``, ``experiments/results/dpa-max-numbers.md``): the last
    ASF at g = 0 holds the target, its trail (a pixel the target left keeps about
    b max(w(9)) = 0.83 of its score per frame) and its neighbours, decaying without an edge
    after 3 pixels; A_S rises with Max_Numbers while the mean of the highest target-block pixels
    falls more slowly than the spread of the non-target SNRs, so the argmax moves with the peak
    SNR (one-pixel target, experiment seeds: 4-5 at peaks 20-60, 3-4 at 15 (flat), 3 at
    10-13, 2 at 8; the presets' 0.7 px Gaussian: 4-7 at every peak). At Table 2's 60 the
    curve is flat beyond 3 (``TestMaxNumbersScene.test_g0_knee_at_three``). At 20 seeds the
    margins are about one standard error and hold on some seed sets only, hence 40 seeds here
    (the experiment: 60 seeds 8000-8059 at peak 12 give A(3) - A(2) = 0.75 ± 0.20 and
    A(3) - A(4) = 0.35 ± 0.18).

    Measured (mean ± standard error over the seeds, Max_Numbers 1..7):

    g = 0, b = 4.8, seeds 0-39 (argmax 3; 16 of the 40 seeds have their own argmax at 3):
        25.09 ± 0.68  28.03 ± 0.72  28.58 ± 0.74  27.94 ± 0.72  27.13 ± 0.70  26.38 ± 0.70
        25.79 ± 0.70
        paired margins (per seed): A(3) - A(2) = 0.55 ± 0.21, A(3) - A(4) = 0.65 ± 0.17, i.e.
        2.6 and 3.8 standard errors (asserted: > 2). They are smaller than the standard errors
        of the values themselves (~0.7): A_S moves from seed to seed by a common level, so the
        margins are taken per seed.
    g = 1, b = 0.8, seeds 0-19 (argmax 1 in every seed):
        32.00 ± 0.86  20.96 ± 0.65  16.53 ± 0.57  14.07 ± 0.47  12.40 ± 0.40  11.22 ± 0.38
        10.28 ± 0.38
        A(1) - A(2) = 11.04 ± 0.40 (asserted: > 10 standard errors).
    """

    def test_g0_peaks_at_three(self):
        curves = mn_peak_curves(0.0)
        assert int(curves.mean(dim=0).argmax()) == 2, curves.mean(dim=0)
        for other in (1, 3):
            margin, se = paired_margin(curves, 2, other)
            assert margin > 2 * se, (other + 1, margin, se)

    def test_g1_peaks_at_one(self):
        curves = mn_peak_curves(1.0)
        assert (curves.argmax(dim=1) == 0).all(), curves
        margin, se = paired_margin(curves, 0, 1)
        assert margin > 10 * se, (margin, se)

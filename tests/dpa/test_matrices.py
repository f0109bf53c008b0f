import itertools
import math
from typing import ClassVar

import pytest
import torch

from hocnet.dpa.matrices import (
    b_versus_g,
    basic_matrix,
    effective_memory,
    equalize_gain,
    frame_matrix,
    memory_line,
    penalty_matrices,
    penalty_matrix_in_place,
    probability_matrices,
    var_table,
)

F64 = torch.float64


@pytest.fixture(autouse=True)
def _single_thread():
    # tiny tensors: thread wake-ups would dominate on a busy machine
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


class TestBasicMatrix:
    def test_smoke_shape_sum(self):
        w = basic_matrix()
        assert w.shape == (7, 7)
        assert w.dtype == torch.get_default_dtype()
        assert torch.isclose(w.sum(), torch.tensor(1.0))
        assert bool((w >= 0).all())

    @pytest.mark.parametrize("window, v_max, jitter, psf", [(7, 2.5, 0.5, 3.0), (5, 1.0, 0.0, 1.0)])
    def test_symmetric_and_peaked(self, window, v_max, jitter, psf):
        w = basic_matrix(window, v_max, jitter, psf, dtype=F64)
        torch.testing.assert_close(w, w.t())
        torch.testing.assert_close(w, w.flip(0))
        torch.testing.assert_close(w, w.flip(1))
        h = window // 2
        assert w[h, h] == w.max()

    def test_point_target_without_blur_is_a_delta(self):
        w = basic_matrix(5, v_max=0.0, jitter=0.0, psf=0.0, dtype=F64)
        expected = torch.zeros(5, 5, dtype=F64)
        expected[2, 2] = 1.0
        torch.testing.assert_close(w, expected)

    def test_more_blur_spreads(self):
        centre = [basic_matrix(7, 1.0, 0.5, psf, dtype=F64)[3, 3] for psf in (0.0, 1.0, 3.0, 5.0)]
        assert all(a > b for a, b in itertools.pairwise(centre))

    def test_monte_carlo(self):
        # displacement = uniform disc velocity + Gaussian PSF spread + uniform jitter per axis
        gen = torch.Generator().manual_seed(0)
        n, v_max, a, psf = 400_000, 1.5, 0.5, 2.0
        sigma = psf / (2 * math.sqrt(2 * math.log(2)))
        radius = v_max * torch.sqrt(torch.rand(n, generator=gen, dtype=F64))
        angle = 2 * math.pi * torch.rand(n, generator=gen, dtype=F64)
        dx = radius * torch.cos(angle) + sigma * torch.randn(n, generator=gen, dtype=F64)
        dy = radius * torch.sin(angle) + sigma * torch.randn(n, generator=gen, dtype=F64)
        dx += a * (2 * torch.rand(n, generator=gen, dtype=F64) - 1)
        dy += a * (2 * torch.rand(n, generator=gen, dtype=F64) - 1)
        ix, iy = torch.round(dx).long() + 3, torch.round(dy).long() + 3
        keep = (ix >= 0) & (ix < 7) & (iy >= 0) & (iy < 7)
        hist = torch.zeros(49, dtype=F64).index_add_(
            0, (iy * 7 + ix)[keep], torch.ones(n, dtype=F64)[keep]
        )
        hist = (hist / hist.sum()).view(7, 7)
        torch.testing.assert_close(
            basic_matrix(7, v_max, a, psf, dtype=F64), hist, atol=3e-3, rtol=0
        )

    def test_device_dtype(self):
        w = basic_matrix(3, device="cpu", dtype=F64)
        assert w.dtype == F64 and w.device.type == "cpu"

    @pytest.mark.parametrize(
        "kwargs, match",
        [
            ({"window": 4}, "`window`"),
            ({"window": 0}, "`window`"),
            ({"v_max": -1.0}, "`v_max`"),
            ({"jitter": -0.1}, "`jitter`"),
            ({"psf": float("nan")}, "`psf`"),
        ],
    )
    def test_exceptions(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            basic_matrix(**kwargs)

    def test_type_error(self):
        with pytest.raises(TypeError, match="`window`"):
            basic_matrix(window=7.5)


class TestFrameMatrix:
    def test_table_5x5(self):
        expected = torch.tensor(
            [
                [0, 0, 1, 0, 0],
                [0, 1, 1, 1, 0],
                [1, 1, 1, 1, 1],
                [0, 1, 1, 1, 0],
                [0, 0, 1, 0, 0],
            ],
            dtype=torch.float32,
        )
        assert torch.equal(frame_matrix(5, 1.0, 0.5, dtype=torch.float32), expected)

    def test_7x7_fast_targets_drop_only_corners(self):
        w = frame_matrix(7, v_max=2.5, jitter=0.5)
        assert w.sum() == 45
        assert w[0, 0] == w[0, 6] == w[6, 0] == w[6, 6] == 0

    def test_centre_always_reachable(self):
        w = frame_matrix(3, v_max=0.0, jitter=0.0)
        assert w.sum() == 1 and w[1, 1] == 1

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`v_max`"):
            frame_matrix(5, v_max=-1.0)
        with pytest.raises(ValueError, match="`window`"):
            frame_matrix(6)


class TestPenaltyMatrices:
    # turn steps of direction 1 (+x), rows dy = -3..3 (top row: up), columns dx = -3..3; the
    # centre (no move) is no turn;
    # the weight is penalty_step ** -steps (Figure 2 of [NR08] for step 3)
    STEPS_DIRECTION_1 = (
        [3, 3, 2, 2, 2, 1, 1],
        [3, 3, 3, 2, 1, 1, 1],
        [4, 3, 3, 2, 1, 1, 0],
        [4, 4, 4, 0, 0, 0, 0],
        [4, 3, 3, 2, 1, 1, 0],
        [3, 3, 3, 2, 1, 1, 1],
        [3, 3, 2, 2, 2, 1, 1],
    )

    def test_direction_1_step_3_entry_by_entry(self):
        w = penalty_matrices(7, 3.0, dtype=F64)
        weight = {0: 1.0, 1: 1 / 3, 2: 1 / 9, 3: 1 / 27, 4: 1 / 81}
        for r in range(7):
            for c in range(7):
                assert w[0, r, c].item() == pytest.approx(weight[self.STEPS_DIRECTION_1[r][c]])

    def test_rotations(self):
        w = penalty_matrices(7, 2.0, dtype=F64)
        assert w.shape == (8, 7, 7)
        # +y is down: direction 3 (90 deg) is direction 1 with x and y swapped
        assert torch.equal(w[2], w[0].t())
        assert torch.equal(w[4], w[0].flip(-1))
        assert torch.equal(w[6], w[0].t().flip(0))
        assert torch.equal(w[1], w[1].t())  # direction 2 (45 deg) is symmetric about x = y

    def test_centre_is_no_turn(self):
        w = penalty_matrices(5, 3.0, dtype=F64)
        assert torch.allclose(w[:, 2, 2], torch.ones(8, dtype=F64))

    def test_differentiable_in_step(self):
        step = torch.tensor(2.5, dtype=F64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda s: penalty_matrices(3, s, dtype=F64), (step,))

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`penalty_step`"):
            penalty_matrices(5, 0.5)
        with pytest.raises(ValueError, match="`window`"):
            penalty_matrices(2)


class TestPenaltyMatrixInPlace:
    def test_ones(self):
        w = penalty_matrix_in_place(5, dtype=F64)
        assert torch.equal(w, torch.ones(5, 5, dtype=F64))

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`window`"):
            penalty_matrix_in_place(-1)


class TestProbabilityMatrices:
    @pytest.mark.parametrize("window, v_max", [(7, 2.5), (5, 1.0), (7, 1.0), (3, 0.5)])
    def test_each_sums_to_one(self, window, v_max):
        w = probability_matrices(window, v_max, dtype=F64)
        assert w.shape == (9, window, window)
        torch.testing.assert_close(w.sum(dim=(1, 2)), torch.ones(9, dtype=F64))
        assert bool((w >= 0).all())

    def test_eq5_from_the_builders(self):
        k, v, a, psf, p, step = 7, 2.5, 0.5, 3.0, 0.7, 2.0
        base = frame_matrix(k, v, a, dtype=F64) * basic_matrix(k, v, a, psf, dtype=F64)
        directed = base * penalty_matrices(k, step, dtype=F64) ** p
        expected = torch.cat([directed, (base * penalty_matrix_in_place(k, dtype=F64))[None]])
        expected = expected / expected.sum(dim=(1, 2), keepdim=True)
        got = probability_matrices(k, v, a, psf, p, step, dtype=F64)
        torch.testing.assert_close(got, expected)

    def test_zero_outside_frame(self):
        w = probability_matrices(7, v_max=1.0, dtype=F64)
        outside = frame_matrix(7, 1.0, 0.5, dtype=F64) == 0
        assert bool((w[:, outside] == 0).all())

    def test_p_zero_removes_direction_preference(self):
        w = probability_matrices(5, p=0.0, dtype=F64)
        torch.testing.assert_close(w, w[8].expand(9, 5, 5))

    def test_direction_preference(self):
        w = probability_matrices(7, v_max=2.5, dtype=F64)
        assert w[0, 3, 5] > w[0, 3, 1]  # direction 1 (+x): right over left
        assert w[2, 5, 3] > w[2, 1, 3]  # direction 3 (90 deg, +y down): below over above

    def test_gradcheck_p_and_step(self):
        p = torch.tensor(0.6, dtype=F64, requires_grad=True)
        step = torch.tensor(2.5, dtype=F64, requires_grad=True)
        fn = lambda p, s: probability_matrices(5, 1.0, p=p, penalty_step=s, dtype=F64)  # noqa: E731
        assert torch.autograd.gradcheck(fn, (p, step))

    def test_device_dtype(self):
        w = probability_matrices(3, device=torch.device("cpu"), dtype=torch.float32)
        assert w.dtype == torch.float32 and w.device.type == "cpu"

    @pytest.mark.parametrize(
        "kwargs, match",
        [
            ({"p": -0.1}, "`p`"),
            ({"penalty_step": 0.9}, "`penalty_step`"),
            ({"window": 8}, "`window`"),
            ({"psf": -1.0}, "`psf`"),
        ],
    )
    def test_exceptions(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            probability_matrices(**kwargs)


class TestVarTable:
    def test_table(self):
        v = var_table()
        assert v.shape == (9, 9) and v.dtype == torch.int64
        assert torch.equal(v, v.t())
        assert bool((v.diagonal() == 6).all())
        assert v[0].tolist() == [6, 5, 4, 3, 2, 3, 4, 5, 4]
        assert v[3].tolist() == [3, 4, 5, 6, 5, 4, 3, 2, 4]
        assert v[8].tolist() == [4, 4, 4, 4, 4, 4, 4, 4, 6]
        for i in range(8):
            assert v[i, (i + 4) % 8] == 2  # opposite directions


class TestEffectiveMemory:
    @pytest.mark.parametrize("g", [0.0, 0.3, 0.5, 1.0])
    def test_round_trip(self, g):
        w = probability_matrices(7, v_max=2.5, dtype=F64)
        b = effective_memory(w, g, target=0.8)
        assert isinstance(b, float)
        assert b * (g * w[0].sum().item() + (1 - g) * w[0].max().item()) == pytest.approx(0.8)

    def test_tensor_g(self):
        w = probability_matrices(5, v_max=1.0, dtype=F64)
        g = torch.tensor([0.0, 0.25, 1.0], dtype=F64)
        b = effective_memory(w, g, target=0.7)
        assert isinstance(b, torch.Tensor) and b.shape == (3,)
        torch.testing.assert_close(
            b * (g * w[0].sum() + (1 - g) * w[0].max()), torch.full_like(g, 0.7)
        )

    def test_uses_direction_1_and_2d_weights(self):
        w = probability_matrices(5, dtype=F64)
        assert effective_memory(w, 0.4) == effective_memory(w[0], 0.4)

    def test_gradcheck(self):
        w = probability_matrices(3, dtype=F64).requires_grad_()
        g = torch.tensor(0.4, dtype=F64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda w, g: effective_memory(w, g), (w, g))

    @pytest.mark.parametrize(
        "args, match",
        [
            ((1.5,), "`g`"),
            ((-0.1,), "`g`"),
            ((torch.tensor([0.2, 1.2]),), "`g`"),
            ((0.5, 0.0), "`target`"),
        ],
    )
    def test_exceptions(self, args, match):
        with pytest.raises(ValueError, match=match):
            effective_memory(probability_matrices(3), *args)

    def test_bad_weights(self):
        with pytest.raises(ValueError, match="`weights`"):
            effective_memory(torch.ones(2, 2, 3, 3), 0.5)


class TestEqualizeGain:
    @pytest.mark.parametrize("g", [0.0, 0.3, 1.0])
    @pytest.mark.parametrize("window, v_max", [(5, 1.0), (7, 2.5)])
    def test_every_direction_has_the_gain_of_direction_1(self, g, window, v_max):
        w = probability_matrices(window, v_max=v_max, dtype=F64)
        out = equalize_gain(w, g)
        gain = g * out.sum(dim=(1, 2)) + (1 - g) * out.amax(dim=(1, 2))
        expected = g * w[0].sum() + (1 - g) * w[0].max()
        torch.testing.assert_close(gain, expected.expand(9))
        torch.testing.assert_close(out[0], w[0])
        # a rescaling per direction: the shape of every matrix is kept
        scale = out.amax(dim=(1, 2), keepdim=True) / w.amax(dim=(1, 2), keepdim=True)
        torch.testing.assert_close(out, w * scale)

    def test_in_place_matrix_gains_at_g0_only(self):
        w = probability_matrices(5, v_max=1.0, dtype=F64)
        assert float(equalize_gain(w, 0.0)[8].max()) == pytest.approx(float(w[0].max()))
        assert float(w[8].max()) < 0.6 * float(w[0].max())  # why the rescaling matters
        torch.testing.assert_close(equalize_gain(w, 1.0), w)  # sums are already equal

    def test_effective_memory_unchanged(self):
        w = probability_matrices(7, v_max=2.5, dtype=F64)
        for g in (0.0, 0.5, 1.0):
            assert effective_memory(equalize_gain(w, g), g) == pytest.approx(effective_memory(w, g))

    def test_single_matrix_copy(self):
        w = torch.rand(1, 3, 3, dtype=F64)
        out = equalize_gain(w, 0.2)
        torch.testing.assert_close(out, w)
        assert out.data_ptr() != w.data_ptr()

    def test_gradcheck(self):
        w = (probability_matrices(3, dtype=F64) + 0.01).requires_grad_()
        g = torch.tensor(0.4, dtype=F64, requires_grad=True)
        assert torch.autograd.gradcheck(equalize_gain, (w, g))

    @pytest.mark.parametrize(
        "weights, g, match",
        [
            (torch.ones(2, 3, 3), 0.5, "`weights`: expected shape"),
            (torch.ones(3, 3), 0.5, "`weights`: expected shape"),
            (-torch.ones(9, 3, 3), 0.5, "`weights`: expected non-negative"),
            (torch.zeros(9, 3, 3), 0.5, "`weights`: expected a positive gain"),
            (torch.ones(9, 3, 3), 1.5, "`g`"),
            (torch.ones(9, 3, 3), torch.tensor([0.1, 0.2]), "`g`"),
            (torch.full((9, 3, 3), math.nan), 0.5, "`weights`"),
        ],
    )
    def test_exceptions(self, weights, g, match):
        with pytest.raises(ValueError, match=match):
            equalize_gain(weights, g)

    def test_type_error(self):
        with pytest.raises(TypeError, match="`weights`"):
            equalize_gain("matrices", 0.5)


class TestMemoryLine:
    PAPER: ClassVar = {"7x7": (1.118, 0.131), "5x5": (1.035, 0.214)}
    # our constants (documented in memory_line's docstring)
    OURS: ClassVar = {"7x7": (1.116, 0.134), "5x5": (0.9388, 0.3112)}

    @pytest.mark.parametrize("name, window, v_max", [("7x7", 7, 2.5), ("5x5", 5, 1.0)])
    def test_constants(self, name, window, v_max, record_property):
        w = probability_matrices(window, v_max, dtype=F64)
        slope, intercept = memory_line(w, target=0.8)
        assert slope + intercept == pytest.approx(1 / 0.8, abs=1e-12)  # sum(w) == 1
        assert (round(slope, 4), round(intercept, 4)) == self.OURS[name]
        paper_slope, paper_intercept = self.PAPER[name]
        # recorded, not asserted: how close max(w) comes to the paper's
        record_property(f"eq15_{name}", (slope, intercept, paper_slope, paper_intercept))
        print(
            f"eq. (15) {name}: ours 1/b = {slope:.4f} g + {intercept:.4f} "
            f"(max w = {0.8 * intercept:.4f}); paper 1/b = {paper_slope} g + {paper_intercept} "
            f"(max w = {0.8 * paper_intercept:.4f})"
        )

    def test_matches_effective_memory(self):
        w = probability_matrices(5, dtype=F64)
        slope, intercept = memory_line(w, target=0.6)
        for g in (0.0, 0.5, 1.0):
            assert 1 / effective_memory(w, g, target=0.6) == pytest.approx(slope * g + intercept)

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`target`"):
            memory_line(probability_matrices(3), target=-1.0)
        with pytest.raises(ValueError, match="`weights`"):
            memory_line(torch.ones(3))


class TestBVersusG:
    def test_curve(self):
        w = probability_matrices(7, v_max=2.5, dtype=F64)
        gs = torch.linspace(0, 1, 11, dtype=F64)
        b = b_versus_g(w, gs, target=0.8)
        assert b.shape == gs.shape
        expected = torch.tensor([effective_memory(w, float(g), 0.8) for g in gs], dtype=F64)
        torch.testing.assert_close(b, expected)
        assert bool((b[1:] < b[:-1]).all())  # more sum, more gain, smaller b

    def test_sequence_input(self):
        b = b_versus_g(torch.full((1, 3, 3), 1 / 9), [0.0, 1.0])
        torch.testing.assert_close(b, torch.tensor([7.2, 0.8], dtype=F64))

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`g`"):
            b_versus_g(probability_matrices(3), [0.5, 2.0])
        with pytest.raises(TypeError, match="`gs`"):
            b_versus_g(probability_matrices(3), object())

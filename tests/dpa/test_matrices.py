import math

import pytest
import torch

from hocnet.dpa.matrices import (
    PAPER_SIGMA,
    b_limit,
    b_versus_g,
    basic_matrix,
    effective_memories,
    effective_memory,
    equalize_gain,
    figure3_matrices,
    fit_basic_sigma,
    frame_matrix,
    memory_line,
    penalty_matrices,
    penalty_matrix_in_place,
    probability_matrices,
    var_table,
)

F64 = torch.float64
FWHM = 2 * math.sqrt(2 * math.log(2))

#: Figure 2 of [NR08]: W_penalty(direction 1, ->), 7 x 7, x = 3, rows y, columns x.
FIGURE_2 = [
    [9, 8, 7, 6, 5, 4, 3],
    [10, 9, 7.5, 6, 4.5, 3, 2],
    [11, 10, 9, 6, 3, 1.5, 1],
    [12, 12, 12, 12, 0, 0, 0],
    [11, 10, 9, 6, 3, 1.5, 1],
    [10, 9, 7.5, 6, 4.5, 3, 2],
    [9, 8, 7, 6, 5, 4, 3],
]
#: The two cells where the ring rule (documented in penalty_matrices) gives 10.5, not 10.
RULE_CELLS = {(2, 1): 10.5, (4, 1): 10.5}


@pytest.fixture(autouse=True)
def _single_thread():
    # tiny tensors: thread wake-ups would dominate on a busy machine
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _direction(i, j):
    """Direction index (0..7) of the move (dx, dy) = (i, j), 8 for no move."""
    if (i, j) == (0, 0):
        return 8
    return round(math.degrees(math.atan2(j, i)) / 45) % 8


class TestBasicMatrix:
    def test_smoke_shape_sum_peak(self):
        w = basic_matrix()
        assert w.shape == (7, 7)
        assert w.dtype == torch.get_default_dtype()
        assert torch.isclose(w.sum(), torch.tensor(1.0))
        assert bool((w >= 0).all())
        # fitted to eq. (15)'s direction-9 intercept: max(W_basic) = 0.8 * 0.214
        assert float(basic_matrix(dtype=F64).max()) == pytest.approx(0.8 * 0.214, rel=1e-6)

    @pytest.mark.parametrize("window, jitter, psf", [(7, 0.5, 3.0), (5, 0.0, 1.0), (3, 0.5, 2.0)])
    def test_standing_target_is_symmetric_and_peaked(self, window, jitter, psf):
        w = basic_matrix(window, 0.0, jitter, psf, dtype=F64)
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

    def test_monte_carlo_standing_target(self):
        # displacement = Gaussian spread (sigma fitted) + U[-0.5, 0.5] jitter per axis
        gen = torch.Generator().manual_seed(0)
        n = 400_000
        d = PAPER_SIGMA * torch.randn(2, n, generator=gen, dtype=F64)
        d += torch.rand(2, n, generator=gen, dtype=F64) - 0.5
        ix, iy = torch.round(d[0]).long() + 3, torch.round(d[1]).long() + 3
        keep = (ix >= 0) & (ix < 7) & (iy >= 0) & (iy < 7)
        hist = torch.zeros(49, dtype=F64).index_add_(
            0, (iy * 7 + ix)[keep], torch.ones(n, dtype=F64)[keep]
        )
        hist = (hist / hist.sum()).view(7, 7)
        torch.testing.assert_close(basic_matrix(dtype=F64), hist, atol=3e-3, rtol=0)

    def test_velocity_option_uses_source_offsets(self):
        # our addition v_max > 0: symmetric disc, so the flip to source offsets keeps it
        w = basic_matrix(7, 1.5, 0.5, 2.0, dtype=F64)
        torch.testing.assert_close(w, w.flip(0).flip(1))
        assert float(w[3, 3]) < float(basic_matrix(7, 0.0, 0.5, 2.0, dtype=F64)[3, 3])

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


class TestFitBasicSigma:
    def test_paper_sigma(self):
        sigma = fit_basic_sigma()
        assert sigma == pytest.approx(PAPER_SIGMA, rel=1e-9)
        w = basic_matrix(psf=sigma * FWHM, dtype=F64)
        assert float(w.max()) == pytest.approx(0.8 * 0.214, rel=1e-9)

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`intercept`"):
            fit_basic_sigma(intercept=5.0)
        with pytest.raises(ValueError, match="`intercept`"):
            fit_basic_sigma(intercept=0.0)


class TestFrameMatrix:
    @pytest.mark.parametrize(
        "v_max, jitter, radius",
        [(0.0, 0.5, 1), (0.5, 0.5, 1), (1.0, 0.5, 2), (1.5, 0.5, 2), (2.0, 0.5, 3), (2.5, 0.0, 3)],
    )
    def test_square_valid_search_area(self, v_max, jitter, radius):
        w = frame_matrix(7, v_max, jitter, dtype=F64)
        expected = torch.zeros(7, 7, dtype=F64)
        expected[3 - radius : 4 + radius, 3 - radius : 4 + radius] = 1.0
        torch.testing.assert_close(w, expected)

    def test_papers_two_windows(self):
        # section 2.2.1: 0-2 px/frame + 0.5 jitter -> the full 7 x 7 (corners and (2, 1) moves)
        assert bool((frame_matrix(7, 2.0, 0.5) == 1).all())
        # Figure 3: 0-1 px/frame -> 5 x 5 including the jitter
        assert bool((frame_matrix(5, 1.0, 0.5) == 1).all())
        assert float(frame_matrix(7, 1.0, 0.5).sum()) == 25.0

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`v_max`"):
            frame_matrix(5, -1.0)
        with pytest.raises(ValueError, match="`window`"):
            frame_matrix(6)


class TestPenaltyMatrices:
    def test_figure_2_entry_by_entry(self):
        w = penalty_matrices(7, 3.0, dtype=F64)[0]  # direction 1 (->, 0 degrees)
        for r in range(7):
            for c in range(7):
                expected = RULE_CELLS.get((r, c), FIGURE_2[r][c])
                assert float(w[r, c]) == pytest.approx(expected, abs=1e-12), (r, c)
        # exactly the two documented cells differ from the printed figure, by 0.5
        printed = torch.tensor(FIGURE_2, dtype=F64)
        differ = (w - printed).abs() > 1e-12
        assert sorted(map(tuple, torch.nonzero(differ).tolist())) == sorted(RULE_CELLS)

    def test_rule_in_x(self):
        # 12 on the side the target came from, minus x per 45 degrees along each ring
        for x in (0.0, 1.0, 2.5):
            w = penalty_matrices(7, x, dtype=F64)[0]
            got = [float(w[r, c]) for r, c in [(3, 0), (0, 0), (0, 3), (0, 6), (3, 6), (3, 3)]]
            # came from, 45, 90, 135 degrees, opposite, centre
            expected = [12, 12 - x, 12 - 2 * x, 12 - 3 * x, 12 - 4 * x, 12]
            assert got == pytest.approx(expected, abs=1e-12)

    def test_rotations_and_mirror(self):
        w = penalty_matrices(7, dtype=F64)
        h = 3
        for d in range(8):
            # a quarter turn of the (x, y) frame: direction d + 2 at (i, j) = direction d at (j, -i)
            for j in range(-h, h + 1):
                for i in range(-h, h + 1):
                    rotated = float(w[d, h - i, h + j])
                    assert float(w[(d + 2) % 8, h + j, h + i]) == pytest.approx(rotated, abs=1e-12)
        # direction 2 (45 degrees, +x and +y) came from the top-left corner
        assert float(w[1, 0, 0]) == 12 and float(w[1, 6, 6]) == pytest.approx(0, abs=1e-12)
        # direction 1 is mirror-symmetric about its axis (rows y -> -y)
        torch.testing.assert_close(w[0], w[0].flip(0))

    def test_differentiable_in_step(self):
        x = torch.tensor(2.0, dtype=F64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda x: penalty_matrices(5, x, dtype=F64), (x,))

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`penalty_step`"):
            penalty_matrices(5, -0.5)
        with pytest.raises(ValueError, match="`penalty_step`"):
            penalty_matrices(5, 3.5)
        with pytest.raises(ValueError, match="`window`"):
            penalty_matrices(4)


class TestPenaltyMatrixInPlace:
    def test_ones(self):
        assert torch.equal(penalty_matrix_in_place(5), torch.ones(5, 5))

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`window`"):
            penalty_matrix_in_place(2)


class TestProbabilityMatrices:
    @pytest.mark.parametrize("window, v_max", [(7, 2.0), (5, 1.0), (7, 1.0), (3, 0.0)])
    def test_each_sums_to_one(self, window, v_max):
        w = probability_matrices(window, v_max, dtype=F64)
        assert w.shape == (9, window, window)
        torch.testing.assert_close(w.sum(dim=(1, 2)), torch.ones(9, dtype=F64))
        assert bool((w >= 0).all())

    @pytest.mark.parametrize("p, x", [(0.5, 3.0), (0.2, 1.5), (1.0, 3.0), (0.0, 2.0)])
    def test_eq5_from_the_builders(self, p, x):
        w = probability_matrices(7, 1.0, p=p, penalty_step=x, dtype=F64)
        basic = basic_matrix(7, dtype=F64)
        framed = penalty_matrices(7, x, dtype=F64) * frame_matrix(7, 1.0, dtype=F64)
        expected = p * basic + (1 - p) * framed / framed.sum(dim=(1, 2), keepdim=True)
        torch.testing.assert_close(w[:8], expected)
        torch.testing.assert_close(w[8], basic)  # W(9) = W_basic

    def test_penalty_part_is_zero_outside_the_frame(self):
        # Figure 3: 0-1 px/frame, the 7 x 7 border holds only p * W_basic
        w = probability_matrices(7, 1.0, p=0.5, dtype=F64)
        border = torch.ones(7, 7, dtype=torch.bool)
        border[1:6, 1:6] = False
        torch.testing.assert_close(
            w[:8, border], 0.5 * basic_matrix(dtype=F64)[border].expand(8, -1)
        )

    def test_direction_preference(self):
        w = probability_matrices(dtype=F64)
        for d in range(8):
            angle = math.radians(45 * d)
            i, j = round(-2 * math.cos(angle)), round(-2 * math.sin(angle))  # came from
            assert float(w[d, 3 + j, 3 + i]) > float(w[d, 3 - j, 3 - i])

    def test_gradcheck_p_and_step(self):
        p = torch.tensor(0.4, dtype=F64, requires_grad=True)
        x = torch.tensor(2.0, dtype=F64, requires_grad=True)
        fn = lambda p, x: probability_matrices(5, p=p, penalty_step=x, dtype=F64)  # noqa: E731
        assert torch.autograd.gradcheck(fn, (p, x))

    @pytest.mark.parametrize(
        "kwargs, match",
        [
            ({"p": -0.1}, "`p`"),
            ({"p": 1.5}, "`p`"),
            ({"penalty_step": 4.0}, "`penalty_step`"),
            ({"window": 2}, "`window`"),
            ({"v_max": -1.0}, "`v_max`"),
        ],
    )
    def test_exceptions(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            probability_matrices(**kwargs)


class TestFigure3:
    def test_panels(self):
        basic, penalties, weights = figure3_matrices()
        assert basic.shape == (7, 7) and penalties.shape == (8, 7, 7) and weights.shape == (9, 7, 7)
        torch.testing.assert_close(weights[8], basic)
        assert float(penalties[:, 0].abs().sum() + penalties[:, :, 6].abs().sum()) == 0.0
        torch.testing.assert_close(
            penalties[0, 1:6, 1:6], penalty_matrices(7, dtype=F64)[0, 1:6, 1:6]
        )


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
    @pytest.mark.parametrize("direction", [1, 4, 9])
    def test_round_trip(self, g, direction):
        w = probability_matrices(dtype=F64)
        m = w[direction - 1]
        b = effective_memory(w, g, target=0.8, direction=direction)
        assert isinstance(b, float)
        assert b * (g * m.sum().item() + (1 - g) * m.max().item()) == pytest.approx(0.8)

    def test_default_is_direction_9(self):
        w = probability_matrices(dtype=F64)
        assert effective_memory(w, 0.3) == effective_memory(w, 0.3, direction=9)
        assert effective_memory(w, 0.0) == pytest.approx(4.673, abs=1e-3)  # paper: ~4.65
        assert effective_memory(w, 0.0, direction=1) == pytest.approx(7.576, abs=1e-3)
        assert effective_memory(w, 1.0) == pytest.approx(0.8)  # every direction (sum 1)

    def test_per_direction(self):
        w = probability_matrices(dtype=F64)
        b = effective_memories(w, 0.0)
        assert b.shape == (9,)
        expected = [effective_memory(w, 0.0, direction=d) for d in range(1, 10)]
        torch.testing.assert_close(b, torch.tensor(expected, dtype=F64))
        torch.testing.assert_close(effective_memories(w, 1.0), torch.full((9,), 0.8, dtype=F64))
        g = torch.tensor([0.0, 0.5], dtype=F64)
        assert effective_memories(w, g).shape == (9, 2)

    def test_tensor_g(self):
        w = probability_matrices(5, v_max=1.0, dtype=F64)
        g = torch.tensor([0.0, 0.25, 1.0], dtype=F64)
        b = effective_memory(w, g, target=0.7)
        assert isinstance(b, torch.Tensor) and b.shape == (3,)
        torch.testing.assert_close(
            b * (g * w[8].sum() + (1 - g) * w[8].max()), torch.full_like(g, 0.7)
        )

    def test_2d_weights(self):
        w = probability_matrices(5, dtype=F64)
        assert effective_memory(w, 0.4, direction=1) == effective_memory(w[0], 0.4)

    def test_gradcheck(self):
        w = probability_matrices(3, dtype=F64).requires_grad_()
        g = torch.tensor(0.4, dtype=F64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda w, g: effective_memory(w, g), (w, g))

    @pytest.mark.parametrize(
        "args, kwargs, match",
        [
            ((1.5,), {}, "`g`"),
            ((-0.1,), {}, "`g`"),
            ((torch.tensor([0.2, 1.2]),), {}, "`g`"),
            ((0.5, 0.0), {}, "`target`"),
            ((0.5,), {"direction": 10}, "`direction`"),
            ((0.5,), {"direction": 0}, "`direction`"),
        ],
    )
    def test_exceptions(self, args, kwargs, match):
        with pytest.raises(ValueError, match=match):
            effective_memory(probability_matrices(3), *args, **kwargs)

    def test_bad_weights(self):
        with pytest.raises(ValueError, match="`weights`"):
            effective_memory(torch.ones(2, 2, 3, 3), 0.5)


class TestBLimit:
    def test_values(self):
        w = probability_matrices(dtype=F64)
        assert b_limit(w, 0.0) == pytest.approx(1 / float(w[0].max()))  # directions 1-8: 9.47
        assert b_limit(w, 0.0) > 8.0  # the paper sweeps b up to 8 at g = 0
        assert b_limit(w, 1.0) == pytest.approx(1.0)
        assert b_limit(torch.zeros(1, 3, 3), 0.5) == math.inf


class TestEqualizeGain:
    @pytest.mark.parametrize("g", [0.0, 0.3, 1.0])
    @pytest.mark.parametrize("window, v_max", [(5, 1.0), (7, 2.0)])
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

    def test_in_place_matrix_changes_at_g0_only(self):
        w = probability_matrices(dtype=F64)
        assert float(equalize_gain(w, 0.0)[8].max()) == pytest.approx(float(w[0].max()))
        assert float(w[8].max()) > 1.5 * float(w[0].max())  # W(9) = W_basic is more peaked
        torch.testing.assert_close(equalize_gain(w, 1.0), w)  # sums are already equal

    def test_reference_direction(self):
        w = probability_matrices(dtype=F64)
        out = equalize_gain(w, 0.0, reference=9)
        torch.testing.assert_close(out[8], w[8])
        torch.testing.assert_close(out.amax(dim=(1, 2)), w[8].max().expand(9))

    def test_effective_memory_of_reference_unchanged(self):
        w = probability_matrices(7, v_max=2.0, dtype=F64)
        for g in (0.0, 0.5, 1.0):
            b = effective_memory(equalize_gain(w, g), g, direction=1)
            assert b == pytest.approx(effective_memory(w, g, direction=1))

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
    #: eq. (15) of [NR08]: 1/b = slope g + intercept
    PAPER = {1: (1.118, 0.131), 9: (1.035, 0.214)}  # noqa: RUF012

    @pytest.mark.parametrize("direction", [1, 2, 3, 4, 5, 6, 7, 8, 9])
    def test_eq15_within_one_percent(self, direction, record_property):
        w = probability_matrices(dtype=F64)  # 7 x 7, 0-2 px/frame + 0.5 jitter, p = 0.5, x = 3
        slope, intercept = memory_line(w, target=0.8, direction=direction)
        assert slope + intercept == pytest.approx(1 / 0.8, abs=1e-12)  # sum(w) == 1
        paper_slope, paper_intercept = self.PAPER[1 if direction < 9 else 9]
        record_property(f"eq15_direction_{direction}", (slope, intercept))
        assert slope == pytest.approx(paper_slope, rel=0.01)
        assert intercept == pytest.approx(paper_intercept, rel=0.01)

    def test_measured_constants(self):
        # the constants documented in memory_line (only direction 9's intercept is fitted)
        w = probability_matrices(dtype=F64)
        assert [round(c, 4) for c in memory_line(w, direction=1)] == [1.118, 0.132]
        assert [round(c, 4) for c in memory_line(w, direction=9)] == [1.036, 0.214]

    def test_matches_effective_memory(self):
        w = probability_matrices(5, dtype=F64)
        for direction in (1, 9):
            slope, intercept = memory_line(w, target=0.6, direction=direction)
            for g in (0.0, 0.5, 1.0):
                b = effective_memory(w, g, target=0.6, direction=direction)
                assert 1 / b == pytest.approx(slope * g + intercept)

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`target`"):
            memory_line(probability_matrices(3), target=-1.0)
        with pytest.raises(ValueError, match="`weights`"):
            memory_line(torch.ones(3))


class TestBVersusG:
    def test_curve(self):
        w = probability_matrices(dtype=F64)
        gs = torch.linspace(0, 1, 11, dtype=F64)
        for direction in (1, 9):  # Figure 6: directions 1-8 and direction 9
            b = b_versus_g(w, gs, target=0.8, direction=direction)
            assert b.shape == gs.shape
            expected = [effective_memory(w, float(g), 0.8, direction=direction) for g in gs]
            torch.testing.assert_close(b, torch.tensor(expected, dtype=F64))
        b = b_versus_g(w, gs)
        assert bool((b[1:] < b[:-1]).all())  # more sum, more gain, smaller b

    def test_sequence_input(self):
        b = b_versus_g(torch.full((1, 3, 3), 1 / 9), [0.0, 1.0])
        torch.testing.assert_close(b, torch.tensor([7.2, 0.8], dtype=F64))

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`g`"):
            b_versus_g(probability_matrices(3), [0.5, 2.0])
        with pytest.raises(TypeError, match="`gs`"):
            b_versus_g(probability_matrices(3), object())

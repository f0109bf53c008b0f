import itertools
import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hocnet.dpa.functional import DPAState, accumulate
from hocnet.dpa.matrices import b_limit, probability_matrices, var_table
from hocnet.dpa.reference import accumulate_reference

F64 = torch.float64


@pytest.fixture(autouse=True)
def _single_thread():
    # tiny tensors: thread wake-ups would dominate on a busy machine
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _weights(kind, d, k, dtype, gen):
    if kind == "probability":
        w = probability_matrices(k, v_max=1.0, dtype=dtype)  # zero corners, shared support
        return w if d == 9 else w[8:9].contiguous()
    w = torch.rand(d, k, k, generator=gen, dtype=dtype)
    w = torch.where(w < 0.25, torch.zeros_like(w), w)  # zeros differ between directions
    w[:, k // 2, k // 2] += 0.5  # every matrix has a positive gain
    return w / w.sum(dim=(1, 2), keepdim=True)  # sum 1: b up to 1 is in the memory range


def _normalised(w):
    """Leaf with every matrix summing to 1 (``b <= 1`` is then in the memory range)."""
    return (w / w.sum(dim=(-2, -1), keepdim=True)).detach().requires_grad_()


def _random_var_table(gen):
    return torch.randint(1, 7, (9, 9), generator=gen)  # positive: eq. (7) multiplies by Var


def _assert_equal_to_reference(state, expected, exact=False):
    asf, direction, origin = expected
    if exact:
        np.testing.assert_array_equal(state.asf.detach().numpy(), asf)
    elif state.asf.dtype == F64:
        np.testing.assert_allclose(state.asf.detach().numpy(), asf, rtol=1e-12, atol=1e-12)
    else:
        np.testing.assert_allclose(state.asf.detach().numpy(), asf, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(state.direction.numpy(), direction)
    np.testing.assert_array_equal(state.origin.numpy(), origin)


SIZES = [(2, 4, 5, 6, 5), (1, 5, 7, 7, 3), (2, 3, 6, 9, 5), (1, 4, 8, 5, 3)]  # B, T, H, W, k
STEPS = ("paper", "source")
CASES = [
    (i, size, d, g, step)
    for i, (size, d, g, step) in enumerate(itertools.product(SIZES, (1, 9), (0.0, 0.3, 1.0), STEPS))
]


class TestAccumulate:
    def test_smoke_shapes(self):
        frames = torch.randn(2, 4, 8, 9)
        state = accumulate(frames, probability_matrices(5), 0.8, 0.5)
        assert isinstance(state, DPAState) and state.batched
        assert state.asf.shape == state.direction.shape == state.origin.shape == frames.shape
        assert state.asf.dtype == torch.float32
        assert state.direction.dtype == state.origin.dtype == torch.int64
        torch.testing.assert_close(state.asf[:, 0], frames[:, 0])
        assert bool((state.direction[:, 0] == 8).all()) and bool((state.origin[:, 0] == -1).all())
        assert int(state.direction.min()) >= 0 and int(state.direction.max()) <= 8
        assert int(state.origin[:, 1:].min()) >= 0 and int(state.origin.max()) < 8 * 9

    def test_unbatched(self):
        frames = torch.randn(3, 6, 6, dtype=F64)
        w = probability_matrices(3, dtype=F64)
        state = accumulate(frames, w, 0.5, 0.2)
        assert not state.batched and state.asf.shape == (3, 6, 6)
        batched = accumulate(frames[None], w, 0.5, 0.2)
        torch.testing.assert_close(state.as_batched().asf, batched.asf)
        assert torch.equal(state.as_batched().origin, batched.origin)
        assert batched.as_batched() is batched

    def test_single_frame_and_integer_frames(self):
        state = accumulate(torch.ones(1, 4, 4, dtype=torch.int64), torch.ones(1, 3, 3), 1.0, 0.0)
        assert state.asf.dtype == torch.get_default_dtype()
        assert bool((state.asf == 1).all()) and bool((state.direction == 0).all())

    @pytest.mark.parametrize("i, size, d, g, step", CASES)
    def test_reference_equality(self, i, size, d, g, step):
        gen = torch.Generator().manual_seed(i)
        bsz, t, h, w, k = size
        dtype = F64 if (i // 2) % 2 == 0 else torch.float32
        kind = "probability" if (i // 6) % 2 else "random"
        b = (0.6, 0.95, 0.0)[(i // 2) % 3] if kind == "random" else 0.9
        table = _random_var_table(gen) if d == 9 and (i // 4) % 2 else None
        weights = _weights(kind, d, k, dtype, gen)
        if (i // 2) % 4 == 3:  # non-contiguous frames and weights
            frames = torch.randn(bsz, t, w, h, generator=gen, dtype=dtype).transpose(-1, -2)
            weights = weights.transpose(-1, -2)
            assert not frames.is_contiguous()
        else:
            frames = torch.randn(bsz, t, h, w, generator=gen, dtype=dtype)
        state = accumulate(frames, weights, b, g, var_table=table, direction_step=step)
        expected = accumulate_reference(frames, weights, b, g, table, direction_step=step)
        _assert_equal_to_reference(state, expected)

    @pytest.mark.parametrize("d, g, step", list(itertools.product((1, 9), (0.0, 0.5, 1.0), STEPS)))
    def test_reference_equality_with_ties(self, d, g, step):
        # integer frames and dyadic weights: many exact ties, every sum exact in float64
        gen = torch.Generator().manual_seed(7 + d)
        frames = torch.randint(-2, 3, (2, 4, 6, 5), generator=gen).to(F64)
        weights = torch.randint(0, 3, (d, 3, 3), generator=gen).to(F64) / 16
        table = var_table() + _random_var_table(gen) if d == 9 else None
        state = accumulate(frames, weights, 0.5, g, var_table=table, direction_step=step)
        expected = accumulate_reference(frames, weights, 0.5, g, table, direction_step=step)
        _assert_equal_to_reference(state, expected, exact=True)

    @pytest.mark.parametrize(
        "d, g, dtype, step",
        [
            (1, 0.3, F64, "paper"),
            (9, 0.0, F64, "paper"),
            (9, 1.0, torch.float32, "paper"),
            (9, 0.4, F64, "source"),
        ],
    )
    def test_reference_equality_smooth(self, d, g, dtype, step):
        gen = torch.Generator().manual_seed(3)
        frames = torch.randn(2, 3, 5, 6, generator=gen, dtype=dtype)
        weights = _weights("random", d, 5, dtype, gen)
        state = accumulate(frames, weights, 0.9, g, smooth=0.4, direction_step=step)
        expected = accumulate_reference(frames, weights, 0.9, g, smooth=0.4, direction_step=step)
        _assert_equal_to_reference(state, expected)

    def test_paper_direction_step_by_hand(self):
        # one bright pixel A at q0 in frame 0, zeros elsewhere: eq. (7)-(8) pick q0 as the source
        # of every pixel p of its window, d(p) = dir(p - q0), and eq. (6) gives
        # ASF_1(p) = b * W(d(p))[h + j, h + i] * A with (i, j) = q0 - p (g = 0)
        w = probability_matrices(dtype=F64)
        frames = torch.zeros(2, 9, 9, dtype=F64)
        frames[0, 4, 4] = 5.0
        state = accumulate(frames, w, 2.0, 0.0)
        for y in range(1, 8):
            for x in range(1, 8):
                i, j = 4 - x, 4 - y
                angle = math.degrees(math.atan2(-j, -i))
                d = 8 if (i, j) == (0, 0) else round(angle / 45) % 8
                assert int(state.direction[1, y, x]) == d
                assert int(state.origin[1, y, x]) == 4 * 9 + 4
                expected = 2.0 * float(w[d, 3 + j, 3 + i]) * 5.0
                assert float(state.asf[1, y, x]) == pytest.approx(expected, rel=1e-12)

    def test_paper_and_source_steps_differ(self):
        gen = torch.Generator().manual_seed(11)
        frames = torch.randn(1, 6, 12, 12, generator=gen, dtype=F64)
        w = probability_matrices(dtype=F64)
        paper = accumulate(frames, w, 4.0, 0.0)
        source = accumulate(frames, w, 4.0, 0.0, direction_step="source")
        assert not torch.allclose(paper.asf, source.asf)

    def test_smooth_tends_to_hard_max(self):
        gen = torch.Generator().manual_seed(0)
        frames = torch.randn(1, 4, 7, 7, generator=gen, dtype=F64)
        w = probability_matrices(5, dtype=F64)
        hard = accumulate(frames, w, 1.0, 0.2)
        soft = accumulate(frames, w, 1.0, 0.2, smooth=1e-4)
        torch.testing.assert_close(soft.asf, hard.asf, atol=1e-3, rtol=0)
        assert torch.equal(soft.origin, hard.origin)

    def test_out_of_frame_neighbours_are_excluded(self):
        # all scores negative: a padded 0 (or a zero-weight 0) would win the max
        frames = torch.zeros(2, 5, 6, dtype=F64)
        frames[0] = -1.0
        for weights in (torch.ones(1, 3, 3, dtype=F64), probability_matrices(5, dtype=F64)[8:]):
            state = accumulate(frames, weights, 1.0, 0.0)
            assert float(state.asf[1].max()) < 0
            _assert_equal_to_reference(state, accumulate_reference(frames, weights, 1.0, 0.0))
        state = accumulate(frames, torch.ones(1, 3, 3, dtype=F64), 1.0, 0.0)
        assert bool((state.asf[1] == -1).all())

    def test_border_pixel_max(self):
        frames = torch.zeros(2, 4, 4, dtype=F64)
        frames[0] = -torch.arange(1.0, 17.0, dtype=F64).view(4, 4)  # -1 .. -16
        state = accumulate(frames, torch.ones(1, 3, 3, dtype=F64), 1.0, 0.0)
        assert state.asf[1, 0, 0] == -1.0  # best in-frame neighbour of the corner
        assert state.asf[1, 3, 3] == -11.0  # in-frame neighbours -11, -12, -15, -16
        assert state.origin[1, 3, 3] == 10  # (y=2, x=2)
        assert state.asf[1, 1, 1] == -1.0 and state.origin[1, 1, 1] == 0

    @pytest.mark.parametrize(
        "step, direction",
        [((1, 0), 0), ((0, 1), 2), ((-1, -1), 5), ((1, -1), 7)],  # (dx, dy); +y is down
    )
    def test_track_origin_and_direction(self, step, direction):
        dx, dy = step
        t, h, w = 4, 9, 9
        frames = torch.zeros(t, h, w, dtype=F64)
        points = [(4 + n * dy, 3 + n * dx) for n in range(t)]
        for n, (y, x) in enumerate(points):
            frames[n, y, x] = 10.0
        state = accumulate(frames, probability_matrices(5, dtype=F64), 1.0, 0.0)
        for n in range(1, t):
            y, x = points[n]
            py, px = points[n - 1]
            assert state.origin[n, y, x] == py * w + px
            assert state.direction[n, y, x] == direction
        assert state.direction[0, 4, 3] == 8  # in place in frame 0

    def test_default_var_table_keeps_the_move_direction(self):
        # with 6 - distance, argmax_d V[d, s] + V[d, d_prev] always contains s
        gen = torch.Generator().manual_seed(1)
        frames = torch.randn(1, 5, 8, 8, generator=gen)
        w = probability_matrices(5)
        with_table = accumulate(frames, w, 0.9, 0.3, var_table=var_table(), direction_step="source")
        without = accumulate(frames, w, 0.9, 0.3, direction_step="source")
        assert torch.equal(with_table.direction, without.direction)
        torch.testing.assert_close(with_table.asf, without.asf)

    def test_no_candidate_falls_back_to_centre(self):
        frames = torch.randn(1, 3, 4, 5, dtype=F64)
        weights = torch.zeros(1, 1, 1, dtype=F64)
        state = accumulate(frames, weights, 1.0, 0.5)
        torch.testing.assert_close(state.asf, frames)
        assert torch.equal(state.origin[0, 1:], torch.arange(20).view(4, 5).expand(2, 4, 5))
        _assert_equal_to_reference(state, accumulate_reference(frames, weights, 1.0, 0.5))

    @pytest.mark.parametrize(
        "d, g, smooth, bsz, step",
        [
            (9, 0.3, None, 1, "paper"),
            (9, 0.3, None, 1, "source"),
            (1, 0.6, None, 2, "paper"),
            (9, 0.5, 0.3, 2, "paper"),
            (9, 0.5, 0.3, 2, "source"),
            (1, 0.2, 0.5, 1, "paper"),
        ],
    )
    def test_gradcheck(self, d, g, smooth, bsz, step):
        gen = torch.Generator().manual_seed(2)
        frames = torch.randn(bsz, 3, 6, 7, generator=gen, dtype=F64, requires_grad=True)
        weights = _normalised(torch.rand(d, 3, 3, generator=gen, dtype=F64) + 0.1)
        b = torch.tensor(0.7, dtype=F64, requires_grad=True)
        g_t = torch.tensor(g, dtype=F64, requires_grad=True)

        def fn(frames, weights, b, g):
            return accumulate(frames, weights, b, g, smooth=smooth, direction_step=step).asf

        assert torch.autograd.gradcheck(fn, (frames, weights, b, g_t), fast_mode=True)

    def test_gradcheck_full_jacobian(self):
        gen = torch.Generator().manual_seed(4)
        frames = torch.randn(1, 3, 6, 6, generator=gen, dtype=F64, requires_grad=True)
        weights = _normalised(torch.rand(9, 3, 3, generator=gen, dtype=F64) + 0.1)
        b = torch.tensor(0.8, dtype=F64, requires_grad=True)
        g = torch.tensor(0.4, dtype=F64, requires_grad=True)
        fn = lambda *args: accumulate(*args).asf  # noqa: E731
        assert torch.autograd.gradcheck(fn, (frames, weights, b, g))

    @pytest.mark.parametrize("g", [0.0, 1.0])
    def test_gradcheck_g_at_bounds_as_float(self, g):
        gen = torch.Generator().manual_seed(5)
        frames = torch.randn(1, 3, 5, 5, generator=gen, dtype=F64, requires_grad=True)
        weights = torch.nn.functional.pad(
            _normalised(torch.rand(9, 3, 3, generator=gen, dtype=F64) + 0.1).detach(), (1,) * 4
        )
        weights.requires_grad_()
        # zero-weight border of a 5x5 window: cropped for speed, gradients land in the 3x3 centre
        fn = lambda f: accumulate(f, weights.detach(), 0.9, g).asf  # noqa: E731
        assert torch.autograd.gradcheck(fn, (frames,))
        state = accumulate(frames, weights, 0.9, g)
        state.asf.sum().backward()
        assert weights.grad is not None

    def test_gradient_of_zero_weights_through_the_sum(self):
        # D = 1, g = 1: a smooth (polynomial) function of the weights, zeros included
        gen = torch.Generator().manual_seed(6)
        frames = torch.randn(1, 3, 5, 6, generator=gen, dtype=F64)
        weights = torch.zeros(1, 5, 5, dtype=F64)
        weights[0, 1:4, 1:4] = torch.rand(3, 3, generator=gen, dtype=F64) + 0.1
        weights = (weights / weights.sum()).requires_grad_()
        accumulate(frames, weights, 0.8, 1.0).asf.sum().backward()
        eps = 1e-7
        for r, c in [(0, 0), (0, 2), (4, 3), (2, 2)]:
            bumped = weights.detach().clone()
            bumped[0, r, c] += eps
            diff = (
                accumulate(frames, bumped, 0.8, 1.0).asf.sum()
                - accumulate(frames, weights.detach(), 0.8, 1.0).asf.sum()
            )
            assert float(weights.grad[0, r, c]) == pytest.approx(
                float(diff) / eps, rel=1e-4, abs=1e-6
            )

    def test_gradients_reach_every_input(self):
        frames = torch.randn(2, 4, 8, 8, requires_grad=True)
        weights = probability_matrices(5).requires_grad_()
        b = torch.tensor(0.9, requires_grad=True)
        g = torch.tensor(0.3, requires_grad=True)
        accumulate(frames, weights, b, g).asf.square().sum().backward()
        for tensor in (frames, weights, b, g):
            assert tensor.grad is not None and bool(torch.isfinite(tensor.grad).all())

    @pytest.mark.parametrize(
        "kwargs, error, match",
        [
            ({"frames": torch.zeros(4, 4)}, ValueError, "`frames`"),
            ({"frames": torch.full((2, 4, 4), float("nan"))}, ValueError, "`frames`"),
            ({"frames": "cube"}, TypeError, "`frames`"),
            ({"weights": torch.ones(2, 3, 3)}, ValueError, "`weights`"),
            ({"weights": torch.ones(1, 4, 4)}, ValueError, "`weights`"),
            ({"weights": torch.ones(1, 3, 5)}, ValueError, "`weights`"),
            ({"weights": torch.ones(1, 7, 7)}, ValueError, "`weights`"),
            ({"weights": -torch.ones(1, 3, 3)}, ValueError, "`weights`"),
            ({"weights": torch.full((1, 3, 3), float("inf"))}, ValueError, "`weights`"),
            ({"weights": torch.ones(3, 3)}, ValueError, "`weights`"),
            ({"b": -0.1}, ValueError, "`b`"),
            ({"b": torch.ones(2)}, TypeError, "`b`"),
            ({"g": 1.5}, ValueError, "`g`"),
            ({"g": "half"}, TypeError, "`g`"),
            ({"smooth": 0.0}, ValueError, "`smooth`"),
            ({"b": 1e30}, ValueError, "`b`: expected a value in \\[0, "),
            ({"direction_step": "mine"}, ValueError, "`direction_step`"),
            ({"var_table": var_table()}, ValueError, "`var_table`"),
            (
                {"weights": torch.ones(9, 3, 3) / 9, "var_table": var_table() - 2},
                ValueError,
                "`var_table`: expected positive",
            ),
            (
                {"weights": torch.ones(9, 3, 3), "var_table": torch.ones(8, 9)},
                ValueError,
                "`var_table`",
            ),
        ],
    )
    def test_exceptions(self, kwargs, error, match):
        args = {"frames": torch.zeros(2, 5, 6), "weights": torch.ones(1, 3, 3) / 9, "b": 1.0}
        args["g"] = 0.5
        args.update(kwargs)
        keys = ("smooth", "var_table", "direction_step")
        extra = {key: args.pop(key) for key in keys if key in args}
        with pytest.raises(error, match=match):
            accumulate(args["frames"], args["weights"], args["b"], args["g"], **extra)


class TestAccumulateReference:
    def test_hand_computed(self):
        frames = np.zeros((2, 3, 3))
        frames[0] = np.arange(1.0, 10.0).reshape(3, 3)
        asf, direction, origin = accumulate_reference(frames, np.ones((1, 3, 3)), 1.0, 0.5)
        assert asf[1, 0, 0] == 0.5 * (1 + 2 + 4 + 5) + 0.5 * 5
        assert asf[1, 1, 1] == 0.5 * 45 + 0.5 * 9
        assert origin[1, 0, 0] == 4 and origin[1, 1, 1] == 8 and origin[0, 1, 1] == -1
        assert (direction == 0).all()

    def test_directions(self):
        frames = np.zeros((1, 2, 3, 3))
        frames[0, 0, 1, 1] = 1.0
        _, direction, origin = accumulate_reference(frames, np.ones((9, 3, 3)), 1.0, 0.0)
        assert (direction[0, 0] == 8).all()
        # every pixel comes from the centre (y=1, x=1): the move p - centre gives the direction
        assert (origin[0, 1] == 4).all()
        assert direction[0, 1].tolist() == [[5, 6, 7], [4, 8, 0], [3, 2, 1]]

    def test_var_table_combination(self):
        frames = np.zeros((2, 3, 3))
        frames[0, 1, 1] = 1.0
        table = np.zeros((9, 9))
        table[:, 8] = table[8, :] = 0.0
        table[8, 8] = 0.0
        table[3, :] = 10.0  # direction 4 always wins
        _, direction, _ = accumulate_reference(
            frames, np.ones((9, 3, 3)), 1.0, 0.0, table, direction_step="source"
        )
        assert (direction[1] == 3).all()


class TestEmptyAndMemoryRange:
    def test_empty_batch(self):
        for step in STEPS:
            state = accumulate(
                torch.zeros(0, 6, 16, 16), probability_matrices(), 4.0, 0.0, direction_step=step
            )
            assert state.asf.shape == state.direction.shape == state.origin.shape == (0, 6, 16, 16)

    def test_b_above_the_memory_range_names_b(self):
        # issue 9: g = 1, b = 2 on 140 frames of 24 x 24 unit noise with one 5-sigma pixel
        gen = torch.Generator().manual_seed(0)
        frames = torch.randn(140, 24, 24, generator=gen)
        frames[:, 12, 12] += 5.0
        with pytest.raises(ValueError, match=r"`b`: expected a value in \[0, 1\]"):
            accumulate(frames, probability_matrices(), 2.0, 1.0)
        with pytest.raises(ValueError, match="`b`"):
            accumulate(frames, probability_matrices(), 1e30, 0.0)
        state = accumulate(frames, probability_matrices(), 1.0, 1.0)  # the bound itself is fine
        assert bool(torch.isfinite(state.asf).all())
        # float32 5 x 5 matrices: direction 1 sums to 1 + 1.2e-7, b_limit(g = 1) = 1 - 3.7e-9;
        # b = 1 (EMC 1, the end of the paper's range) must not be refused for the rounding
        w5 = probability_matrices(5, v_max=1.0)
        assert b_limit(w5, 1.0) < 1.0
        accumulate(frames[:4], w5, 1.0, 1.0)
        with pytest.raises(ValueError, match=r"`b`: expected a value in \[0, 1\]"):
            accumulate(frames[:4], w5, 1.0001, 1.0)

    @pytest.mark.parametrize("step", STEPS)
    def test_overflow_stops_with_an_error_naming_b(self, step):
        # b in the range (EMC <= 1 in directions 1-8) but EMC 1.61 in direction 9: the
        # recursion grows geometrically and would overflow float32 near frame 185
        gen = torch.Generator().manual_seed(1)
        frames = torch.randn(260, 8, 8, generator=gen)
        frames[:, 4, 4] += 5.0
        with pytest.raises(ValueError, match="`b`: the accumulated score overflowed"):
            accumulate(frames, probability_matrices(), 9.4, 0.0, direction_step=step)


class TestReferenceProperty:
    @settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(
        seed=st.integers(0, 2**31 - 1),
        bsz=st.integers(1, 2),
        t=st.integers(1, 4),
        h=st.integers(3, 7),
        w=st.integers(3, 7),
        k=st.sampled_from([1, 3, 5]),
        d=st.sampled_from([1, 9]),
        b=st.floats(0.0, 1.0),
        g=st.sampled_from([0.0, 0.25, 1.0]),
        double=st.booleans(),
        transposed=st.booleans(),
        step=st.sampled_from(STEPS),
        kind=st.sampled_from(["probability", "random"]),
    )
    def test_fast_path_equals_reference(
        self, seed, bsz, t, h, w, k, d, b, g, double, transposed, step, kind
    ):
        k = min(k, h, w) if min(k, h, w) % 2 else min(k, h, w) - 1
        gen = torch.Generator().manual_seed(seed)
        dtype = F64 if double else torch.float32
        if kind == "probability" and k > 1:
            weights = probability_matrices(k, v_max=1.0, dtype=dtype)
            weights = weights if d == 9 else weights[8:9].contiguous()
        else:
            weights = _weights("random", d, k, dtype, gen)
        table = _random_var_table(gen) if d == 9 and seed % 2 else None
        frames = torch.randn(bsz, t, w, h, generator=gen, dtype=dtype).transpose(-1, -2)
        if transposed:  # non-contiguous frames and weights
            weights = weights.transpose(-1, -2)
        else:
            frames = frames.contiguous()
        state = accumulate(frames, weights, b, g, var_table=table, direction_step=step)
        expected = accumulate_reference(frames, weights, b, g, table, direction_step=step)
        _assert_equal_to_reference(state, expected)


class TestInitial:
    """``accumulate(..., initial=state)`` continues the recursion (streaming, frame by frame)."""

    @pytest.mark.parametrize(
        ("d", "g", "step", "dtype", "table", "batched"),
        [
            (9, 0.5, "paper", torch.float32, False, False),
            (9, 0.0, "source", F64, True, True),
            (9, 1.0, "paper", F64, True, True),
            (1, 0.3, "paper", torch.float32, False, True),
        ],
    )
    def test_frame_by_frame_equals_batch(self, d, g, step, dtype, table, batched):
        gen = torch.Generator().manual_seed(3 + d)
        weights = _weights("probability", d, 5, dtype, gen)
        shape = (2, 7, 9, 8) if batched else (7, 9, 8)
        frames = torch.randn(*shape, generator=gen, dtype=dtype)
        frames[..., 3, 1:8] += 3 * torch.eye(7, dtype=dtype)[:, :7]  # some structure
        vt = _random_var_table(gen) if table else None
        kw = {"var_table": vt, "direction_step": step}
        batch = accumulate(frames, weights, 0.8, g, **kw)
        # the reference: a loop of one-frame calls, each continuing from the previous state
        state = accumulate(frames[..., :1, :, :], weights, 0.8, g, **kw)
        parts = [state]
        for n in range(1, 7):
            state = accumulate(frames[..., n : n + 1, :, :], weights, 0.8, g, initial=state, **kw)
            parts.append(state)
        for name in ("asf", "direction", "origin"):
            got = torch.cat([getattr(p, name) for p in parts], dim=-3)
            assert torch.equal(got, getattr(batch, name)), name
        assert all(p.batched == batched for p in parts)
        # and in two chunks
        first = accumulate(frames[..., :3, :, :], weights, 0.8, g, **kw)
        rest = accumulate(frames[..., 3:, :, :], weights, 0.8, g, initial=first, **kw)
        assert torch.equal(rest.asf, batch.asf[..., 3:, :, :])
        assert torch.equal(rest.origin, batch.origin[..., 3:, :, :])

    def test_gradient_flows_through_initial(self):
        gen = torch.Generator().manual_seed(0)
        weights = probability_matrices(3, v_max=1.0, dtype=F64)
        frames = torch.randn(4, 6, 6, generator=gen, dtype=F64, requires_grad=True)
        whole = accumulate(frames, weights, 0.9, 0.5).asf[-1].sum()
        (g_whole,) = torch.autograd.grad(whole, frames)
        first = accumulate(frames[:2], weights, 0.9, 0.5)
        split = accumulate(frames[2:], weights, 0.9, 0.5, initial=first).asf[-1].sum()
        (g_split,) = torch.autograd.grad(split, frames)
        torch.testing.assert_close(g_split, g_whole)

    @pytest.mark.parametrize(
        ("initial", "error", "match"),
        [
            ("not a state", TypeError, r"`initial`: expected a DPAState"),
            ("other_size", ValueError, r"`initial`: expected a state .* of 6 x 6"),
            ("other_batch", ValueError, r"`initial`: expected a state of at least one frame of 1"),
            ("bad_direction", ValueError, r"`initial`: expected directions in 0 \.\. 8"),
        ],
    )
    def test_bad_initial(self, initial, error, match):
        weights = probability_matrices(3, v_max=1.0)
        frames = torch.zeros(1, 2, 6, 6)
        if initial == "other_size":
            initial = accumulate(torch.zeros(2, 6, 7), weights, 0.5, 0.5)
        elif initial == "other_batch":
            initial = accumulate(torch.zeros(3, 2, 6, 6), weights, 0.5, 0.5)
        elif initial == "bad_direction":
            good = accumulate(frames, weights, 0.5, 0.5)
            initial = DPAState(good.asf, good.direction + 9, good.origin, True)
        with pytest.raises(error, match=match):
            accumulate(frames, weights, 0.5, 0.5, initial=initial)

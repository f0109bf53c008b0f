import math

import pytest
import torch
from torch.func import functional_call

from hocnet.dpa.functional import accumulate
from hocnet.dpa.layers import DPA
from hocnet.dpa.matrices import (
    effective_memory,
    equalize_gain,
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


class TestDPA:
    def test_smoke_fixed_by_default(self):
        dpa = DPA()
        assert list(dpa.parameters()) == []
        assert dpa.weights.shape == (9, 7, 7)
        state = dpa(torch.randn(2, 3, 10, 12))
        assert state.asf.shape == (2, 3, 10, 12)
        assert "fixed_weights" in dict(dpa.named_buffers())
        assert "window=7, D=9" in repr(dpa)

    def test_unbatched(self):
        state = DPA(window=3)(torch.randn(3, 6, 6))
        assert not state.batched and state.asf.shape == (3, 6, 6)

    def test_module_equals_function(self):
        frames = torch.randn(2, 4, 9, 8)
        dpa = DPA(g=0.3, window=5, v_max=1.0, psf=2.0, p=0.7, penalty_step=2.0)
        weights = probability_matrices(5, 1.0, 0.5, 2.0, 0.7, 2.0)
        b = effective_memory(weights, 0.3, 0.8)
        assert dpa.b.item() == pytest.approx(b)
        torch.testing.assert_close(dpa.weights, weights)
        got, expected = dpa(frames), accumulate(frames, weights, b, 0.3)
        torch.testing.assert_close(got.asf, expected.asf)
        assert torch.equal(got.origin, expected.origin)
        assert torch.equal(got.direction, expected.direction)

    def test_module_equals_function_options(self):
        frames = torch.randn(1, 4, 8, 8, dtype=F64)
        weights = probability_matrices(3, dtype=F64)
        table = var_table() * 2 - torch.eye(9, dtype=torch.int64)
        dpa = DPA(weights, b=0.9, g=0.4, smooth=0.2, var_table=table).double()
        got = dpa(frames)
        expected = accumulate(frames, weights, 0.9, 0.4, var_table=table, smooth=0.2)
        torch.testing.assert_close(got.asf, expected.asf)
        assert torch.equal(got.direction, expected.direction)

    def test_equal_gain(self):
        frames = torch.randn(2, 4, 9, 8)
        dpa = DPA(g=0.2, window=5, v_max=1.0, equal_gain=True)
        weights = equalize_gain(probability_matrices(5, 1.0), 0.2)
        torch.testing.assert_close(dpa.weights, weights)
        assert dpa.b.item() == pytest.approx(effective_memory(weights, 0.2))
        torch.testing.assert_close(dpa(frames).asf, accumulate(frames, weights, dpa.b, 0.2).asf)
        assert "equal_gain=True" in repr(dpa)

    def test_equal_gain_follows_learnable_g(self):
        dpa = DPA(window=3, g=0.3, equal_gain=True, learnable=("g", "p")).double()
        dpa(torch.randn(1, 3, 6, 6, dtype=F64)).asf.sum().backward()
        assert float(dpa.g_raw.grad.abs()) > 0
        with torch.no_grad():
            dpa.g_raw.fill_(-3.0)
        expected = equalize_gain(probability_matrices(3, p=dpa.p.item(), dtype=F64), dpa.g)
        torch.testing.assert_close(dpa.weights, expected)

    def test_non_directional(self):
        dpa = DPA(window=5, directional=False)
        torch.testing.assert_close(dpa.weights, probability_matrices(5)[8:])
        state = dpa(torch.randn(1, 3, 6, 6))
        assert bool((state.direction == 0).all())

    def test_learnable_parameters_and_constraints(self):
        dpa = DPA(
            window=5, b=0.0, g=1.0, p=0.0, penalty_step=3.0, learnable=("b", "g", "p", "penalty")
        )
        names = sorted(name for name, _ in dpa.named_parameters())
        assert names == ["b_raw", "g_raw", "p_raw", "penalty_raw"]
        # initialised just inside the bounds
        assert 0 < dpa.b.item() < 1e-5 and 1 - 1e-5 < dpa.g.item() < 1
        assert 0 < dpa.p.item() < 1e-5 and 3 - 1e-5 < dpa.penalty_step.item() < 3
        with torch.no_grad():
            for param in dpa.parameters():
                param.fill_(-50.0)
        assert dpa.b.item() >= 0 and dpa.g.item() >= 0 and dpa.p.item() >= 0
        assert dpa.penalty_step.item() >= 0
        with torch.no_grad():
            for param in dpa.parameters():
                param.fill_(50.0)
        assert dpa.g.item() <= 1 and dpa.p.item() <= 1 and dpa.penalty_step.item() <= 3

    def test_learnable_values_round_trip(self):
        dpa = DPA(
            window=5, b=0.7, g=0.3, p=0.6, penalty_step=2.5, learnable=("b", "g", "p", "penalty")
        )
        assert dpa.b.item() == pytest.approx(0.7)
        assert dpa.g.item() == pytest.approx(0.3)
        assert dpa.p.item() == pytest.approx(0.6)
        assert dpa.penalty_step.item() == pytest.approx(2.5)
        torch.testing.assert_close(dpa.weights, probability_matrices(5, p=0.6, penalty_step=2.5))

    def test_training_step_moves_parameters(self):
        dpa = DPA(window=5, g=0.5, learnable=("b", "g", "p", "penalty"), smooth=0.5)
        frames = torch.randn(2, 4, 8, 8)
        dpa(frames).asf[:, -1].mean().backward()
        for name, param in dpa.named_parameters():
            assert param.grad is not None and float(param.grad.abs()) > 0, name

    def test_gradcheck_through_module(self):
        dpa = DPA(
            window=3, b=0.8, g=0.4, p=0.7, penalty_step=2.0, learnable=("b", "g", "p", "penalty")
        )
        dpa = dpa.double()
        gen = torch.Generator().manual_seed(0)
        frames = torch.randn(1, 3, 6, 6, generator=gen, dtype=F64, requires_grad=True)
        names = [name for name, _ in dpa.named_parameters()]
        params = tuple(p.detach().clone().requires_grad_() for p in dpa.parameters())

        def fn(frames, *values):
            return functional_call(dpa, dict(zip(names, values)), (frames,)).asf

        assert torch.autograd.gradcheck(fn, (frames, *params))

    def test_gradcheck_through_module_smooth(self):
        dpa = DPA(window=3, g=0.6, learnable=("b", "g", "p", "penalty"), smooth=0.3).double()
        gen = torch.Generator().manual_seed(1)
        frames = torch.randn(2, 3, 5, 6, generator=gen, dtype=F64)
        names = [name for name, _ in dpa.named_parameters()]
        params = tuple(p.detach().clone().requires_grad_() for p in dpa.parameters())

        def fn(*values):
            return functional_call(dpa, dict(zip(names, values)), (frames,)).asf

        assert torch.autograd.gradcheck(fn, params, fast_mode=True)

    def test_state_dict_round_trip(self):
        dpa = DPA(window=5, learnable=("g", "p"))
        with torch.no_grad():
            dpa.g_raw.fill_(0.3)
        other = DPA(window=5, learnable=("g", "p"))
        other.load_state_dict(dpa.state_dict())
        assert other.g.item() == pytest.approx(dpa.g.item())

    @pytest.mark.parametrize(
        "kwargs, error, match",
        [
            ({"learnable": ("b", "speed")}, ValueError, "`learnable`"),
            ({"learnable": 3}, TypeError, "`learnable`"),
            ({"weights": torch.ones(9, 3, 3), "learnable": ("p",)}, ValueError, "`learnable`"),
            ({"directional": False, "learnable": ("penalty",)}, ValueError, "`learnable`"),
            ({"weights": torch.ones(1, 3, 3)}, ValueError, "`directional`"),
            ({"weights": torch.ones(2, 3, 3)}, ValueError, "`weights`"),
            ({"g": 2.0}, ValueError, "`g`"),
            ({"b": -1.0}, ValueError, "`b`"),
            ({"p": -1.0}, ValueError, "`p`"),
            ({"penalty_step": -0.5}, ValueError, "`penalty_step`"),
            ({"penalty_step": 3.5}, ValueError, "`penalty_step`"),
            ({"p": 1.5}, ValueError, "`p`"),
            ({"direction_step": "mine"}, ValueError, "`direction_step`"),
            ({"memory_direction": 10}, ValueError, "`memory_direction`"),
            ({"window": 4}, ValueError, "`window`"),
            ({"smooth": -1.0}, ValueError, "`smooth`"),
            ({"memory": 0.0}, ValueError, "`memory`"),
            ({"directional": False, "var_table": var_table()}, ValueError, "`var_table`"),
            ({"directional": False, "equal_gain": True}, ValueError, "`equal_gain`"),
            ({"equal_gain": 1}, TypeError, "`equal_gain`"),
        ],
    )
    def test_exceptions(self, kwargs, error, match):
        with pytest.raises(error, match=match):
            DPA(**kwargs)

    def test_forward_exceptions(self):
        with pytest.raises(ValueError, match="`weights`"):
            DPA(window=7)(torch.randn(2, 5, 5))
        with pytest.raises(ValueError, match="`frames`"):
            DPA(window=3)(torch.randn(5, 5))


class TestPaperDefaults:
    def test_defaults_are_the_papers(self):
        # g = 0 (max), 7 x 7 for 0-2 px/frame + 0.5 jitter, p = 0.5, x = 3, b = EMC 0.8 in
        # direction 9 (section 2.2.6: "b_{g=0} close to 4.65"), the paper's direction step
        dpa = DPA()
        assert dpa.g.item() == 0.0 and dpa.p.item() == 0.5 and dpa.penalty_step.item() == 3.0
        assert dpa.direction_step == "paper"
        torch.testing.assert_close(dpa.weights, probability_matrices())
        assert dpa.b.item() == pytest.approx(0.8 / float(probability_matrices()[8].max()))
        assert dpa.b.item() == pytest.approx(4.67, abs=0.005)
        assert DPA(memory_direction=1).b.item() == pytest.approx(7.576, abs=0.001)

    def test_empty_batch(self):
        state = DPA()(torch.zeros(0, 6, 16, 16))
        assert state.asf.shape == (0, 6, 16, 16)

    @pytest.mark.parametrize("smooth", [None, 0.3])
    @pytest.mark.parametrize("step", ["paper", "source"])
    def test_gradcheck_new_parameterisation(self, smooth, step):
        dpa = DPA(
            window=3,
            b=0.7,
            g=0.4,
            p=0.6,
            penalty_step=2.0,
            learnable=("b", "g", "p", "penalty"),
            smooth=smooth,
            direction_step=step,
        ).double()
        gen = torch.Generator().manual_seed(3)
        frames = torch.randn(1, 3, 5, 6, generator=gen, dtype=F64, requires_grad=True)
        names = [name for name, _ in dpa.named_parameters()]
        params = tuple(p.detach().clone().requires_grad_() for p in dpa.parameters())

        def fn(frames, *values):
            return functional_call(dpa, dict(zip(names, values, strict=True)), (frames,)).asf

        assert torch.autograd.gradcheck(fn, (frames, *params))


class TestFullMatrices:
    """learnable="matrices": every entry of the D matrices (softmax over each window)."""

    def test_initial_module_equals_fixed_exactly(self):
        frames = torch.randn(2, 4, 9, 9, generator=torch.Generator().manual_seed(0))
        for directional in (True, False):
            kw = {"window": 5, "v_max": 1.0, "g": 0.3, "directional": directional}
            fixed = DPA(**kw)
            full = DPA(**kw, learnable=("b", "matrices"))
            assert torch.equal(full.weights, fixed.weights)
            assert float(full.b.detach()) == pytest.approx(float(fixed.b), rel=1e-6)
            same_b = DPA(**kw, b=float(fixed.b), learnable="matrices")
            assert torch.equal(same_b(frames).asf, fixed(frames).asf)
        names = sorted(n for n, _ in DPA(window=5, learnable="matrices").named_parameters())
        assert names == ["matrices_raw"]

    def test_from_explicit_weights(self):
        w = probability_matrices(5, 1.0, p=0.3, penalty_step=1.5).double()
        dpa = DPA(w, b=1.0, learnable="matrices")
        assert torch.equal(dpa.weights, w)

    def test_against_loop(self):
        # W(d)[i, j] = S(d) * W0(d)[i, j] exp(r[i, j]) / sum_ij W0(d)[i, j] exp(r[i, j])
        w = probability_matrices(3, 1.0, p=0.4, penalty_step=2.0).double()
        dpa = DPA(w, b=1.0, learnable="matrices").double()
        gen = torch.Generator().manual_seed(2)
        with torch.no_grad():
            dpa.matrices_raw.copy_(torch.randn(9, 3, 3, generator=gen, dtype=F64))
        w0, raw = dpa.matrices_init, dpa.matrices_raw.detach()
        got = dpa.weights.detach()
        for d in range(9):
            s0 = sum(float(w0[d, i, j]) for i in range(3) for j in range(3))
            num = [[float(w0[d, i, j]) * math.exp(float(raw[d, i, j])) for j in range(3)]
                   for i in range(3)]  # fmt: skip
            z = sum(map(sum, num))
            for i in range(3):
                for j in range(3):
                    assert float(got[d, i, j]) == pytest.approx(s0 * num[i][j] / z, rel=1e-12)
        assert bool((got >= 0).all())
        assert torch.allclose(got.sum(dim=(-2, -1)), torch.ones(9, dtype=F64), atol=1e-12)

    @pytest.mark.parametrize("smooth", [None, 0.3])
    def test_gradcheck(self, smooth):
        dpa = DPA(window=3, b=0.7, g=0.4, learnable=("b", "g", "matrices"), smooth=smooth).double()
        gen = torch.Generator().manual_seed(4)
        with torch.no_grad():
            dpa.matrices_raw.copy_(0.3 * torch.randn(9, 3, 3, generator=gen, dtype=F64))
        frames = torch.randn(1, 3, 5, 6, generator=gen, dtype=F64, requires_grad=True)
        names = [name for name, _ in dpa.named_parameters()]
        params = tuple(p.detach().clone().requires_grad_() for p in dpa.parameters())

        def fn(frames, *values):
            return functional_call(dpa, dict(zip(names, values, strict=True)), (frames,)).asf

        assert torch.autograd.gradcheck(fn, (frames, *params), fast_mode=True)

    def test_training_moves_matrices_and_state_dict(self):
        dpa = DPA(window=3, learnable=("g", "matrices"), smooth=0.5)
        frames = torch.randn(2, 3, 6, 6, generator=torch.Generator().manual_seed(5))
        dpa(frames).asf[:, -1, 2, 3].sum().backward()
        assert float(dpa.matrices_raw.grad.abs().sum()) > 0
        with torch.no_grad():
            dpa.matrices_raw.add_(0.1 * dpa.matrices_raw.grad)
        other = DPA(window=3, learnable=("g", "matrices"))
        other.load_state_dict(dpa.state_dict())
        assert torch.equal(other.weights, dpa.weights)
        assert not torch.equal(dpa.weights, DPA(window=3).weights)

    def test_exclusive_with_p_and_penalty(self):
        with pytest.raises(ValueError, match="`learnable`"):
            DPA(window=3, learnable=("p", "matrices"))
        with pytest.raises(ValueError, match="`weights`"):
            DPA(torch.zeros(9, 3, 3), b=1.0, learnable="matrices")

import math

import pytest
import torch

from hocnet.hoc import (
    HOCLayer,
    HOCNet,
    MHOCImage,
    ModifiedHOCLayer,
    hoc_layer,
    mhoc_image,
    modified_hoc,
    original_hoc,
)
from hocnet.hoc.functional import hard_limiter
from hocnet.hoc.layers import (
    LEARNED_THRESHOLD,
    learned_limiter,
    relaxed_limiter,
    ste_limiter,
)


def random_cube(seed, shape, density):
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed)) < density


class TestModifiedHOCLayer:
    def test_buffers_not_parameters(self):
        layer = ModifiedHOCLayer(v=2)
        assert list(layer.parameters()) == []
        assert layer.mask_kernels.shape == (25, 1, 5, 5)
        assert layer.shift_kernels.shape == (1, 25, 5, 5)
        assert "mask_kernels" in layer.state_dict()

    def test_learnable_parameters(self):
        layer = ModifiedHOCLayer(v=1, learnable=True)
        names = sorted(n for n, _ in layer.named_parameters())
        assert names == ["mask_kernels", "shift_kernels"]
        fixed = ModifiedHOCLayer(v=1)
        assert torch.equal(layer.mask_kernels.data, fixed.mask_kernels)

    def test_random_init_is_seeded(self):
        a = ModifiedHOCLayer(v=1, learnable=True, init="random", seed=3)
        b = ModifiedHOCLayer(v=1, learnable=True, init="random", seed=3)
        assert torch.equal(a.mask_kernels, b.mask_kernels)

    def test_random_init_requires_learnable(self):
        with pytest.raises(ValueError, match="`init`"):
            ModifiedHOCLayer(v=1, init="random")

    def test_gradient_flows_when_training(self):
        layer = ModifiedHOCLayer(v=1, learnable=True).train()
        cube = random_cube(0, (1, 5, 6, 6), 0.4).float()
        layer(cube).sum().backward()
        assert layer.mask_kernels.grad is not None
        assert layer.mask_kernels.grad.abs().sum() > 0

    def test_eval_uses_hard_limiter(self):
        layer = ModifiedHOCLayer(v=1, learnable=True).eval()
        cube = random_cube(1, (1, 6, 7, 7), 0.4)
        out = layer(cube.float())
        assert torch.equal(out > 0, modified_hoc(cube, 1, 1)[..., :, :])
        assert set(out.unique().tolist()) <= {0.0, 1.0}

    @pytest.mark.parametrize(
        ("name", "value", "match"), [("v", 0, "`v`"), ("delta", 5.0, "`delta`")]
    )
    def test_bad_arguments(self, name, value, match):
        with pytest.raises(ValueError, match=match):
            ModifiedHOCLayer(**{name: value})


class TestHOCLayer:
    @pytest.mark.parametrize("direction", ["forward", "backward"])
    def test_is_original_hoc(self, direction):
        cube = random_cube(2, (1, 7, 9, 9), 0.1)
        out = HOCLayer(v=2, direction=direction)(cube.float())
        assert torch.equal(out > 0, original_hoc(cube, 1, 2, direction))

    def test_window_kernel_buffer(self):
        layer = HOCLayer(v=3)
        assert list(layer.parameters()) == []
        assert layer.window_kernel.shape == (1, 1, 7, 7) and bool((layer.window_kernel == 1).all())
        assert "window_kernel" in layer.state_dict()

    def test_learnable(self):
        layer = HOCLayer(v=1, learnable=True).train()
        assert [n for n, _ in layer.named_parameters()] == ["window_kernel"]
        layer(random_cube(0, (1, 5, 6, 6), 0.4).float()).sum().backward()
        assert layer.window_kernel.grad.abs().sum() > 0
        a = HOCLayer(v=1, learnable=True, init="random", seed=2)
        b = HOCLayer(v=1, learnable=True, init="random", seed=2)
        assert torch.equal(a.window_kernel, b.window_kernel)
        with pytest.raises(ValueError, match="`init`"):
            HOCLayer(v=1, init="random")

    def test_v_larger_than_frame(self):
        cube = random_cube(3, (1, 5, 4, 6), 0.2)
        out = HOCLayer(v=50)(cube.float())
        assert torch.equal(out > 0, original_hoc(cube, 1, 5))


class TestHOCNet:
    @pytest.mark.parametrize("direction", ["forward", "backward"])
    @pytest.mark.parametrize("delta", [math.pi / 4, math.pi / 2, None])
    def test_module_equals_function(self, direction, delta):
        cube = random_cube(4, (2, 9, 10, 11), 0.25)
        net = HOCNet(order=3, v=2, delta=delta, direction=direction)
        if delta is None:
            expected = original_hoc(cube, 3, 2, direction)
        else:
            expected = modified_hoc(cube, 3, 2, delta, direction)
        assert torch.equal(net(cube) > 0, expected)

    def test_unbatched_and_levels(self):
        cube = random_cube(5, (8, 9, 9), 0.3)
        out, levels = HOCNet(order=2, v=2)(cube, return_levels=True)
        assert out.shape == (8, 9, 9) and len(levels) == 3
        assert torch.equal(levels[0], cube.float())

    def test_layers_stacked(self):
        net = HOCNet(order=4, v=1)
        assert len(net.layers) == 4

    def test_rejects_non_binary_when_fixed(self):
        with pytest.raises(ValueError, match="`frames`"):
            HOCNet(order=1, v=1)(torch.full((3, 4, 4), 0.3))

    def test_bad_order(self):
        with pytest.raises(ValueError, match="`order`"):
            HOCNet(order=0)

    def test_original_stacks_hoc_layers(self):
        net = HOCNet(order=2, v=1, delta=None)
        assert all(isinstance(layer, HOCLayer) for layer in net.layers)

    @pytest.mark.parametrize("delta", [math.pi / 4, None])
    def test_empty_batch(self, delta):
        cube = torch.zeros(0, 6, 8, 8)
        assert HOCNet(order=2, v=2, delta=delta)(cube).shape == (0, 6, 8, 8)
        assert MHOCImage(order=2, v=2, delta=delta)(cube).shape == (0, 6, 8, 8)

    def test_huge_v_kernels_refused_at_once(self):
        with pytest.raises(ValueError, match="`v`"):
            ModifiedHOCLayer(v=100)
        with pytest.raises(ValueError, match="`v`"):
            HOCNet(order=2, v=1000)

    def test_v_larger_than_frame(self):
        cube = random_cube(6, (1, 6, 5, 5), 0.3)
        assert torch.equal(HOCNet(2, v=9)(cube) > 0, modified_hoc(cube, 2, 4))


class TestMHOCImage:
    @pytest.mark.parametrize("delta", [math.pi / 4, None])
    def test_module_equals_function(self, delta):
        cube = random_cube(7, (2, 10, 11, 12), 0.1)
        out = MHOCImage(order=2, v=2, delta=delta)(cube)
        assert torch.equal(out > 0, mhoc_image(cube, 2, 2, delta))

    def test_unbatched(self):
        cube = random_cube(8, (10, 9, 9), 0.1)
        assert MHOCImage(order=2, v=2)(cube).shape == (10, 9, 9)


class TestLimiters:
    def test_relaxed_tends_to_hard(self):
        c = torch.tensor([0.0, 1.0, 2.0, 5.0])
        assert torch.equal(relaxed_limiter(c, 50.0).round(), (c > 0).float())

    def test_ste_forward_hard_backward_soft(self):
        c = torch.tensor([0.0, 2.0], requires_grad=True)
        out = ste_limiter(c)
        assert out.tolist() == [0.0, 1.0]
        out.sum().backward()
        assert (c.grad > 0).all()

    def test_learned_limiter_is_eq3_on_integer_counts(self):
        c = torch.arange(-3, 30, dtype=torch.float32)
        assert torch.equal(learned_limiter(c), hard_limiter(c))
        assert torch.equal(learned_limiter(c), (c > 0).float())

    def test_learned_limiter_at_the_sigmoid_centre(self):
        c = torch.linspace(-2.0, 3.0, 501)
        off = (c - LEARNED_THRESHOLD).abs() > 1e-3  # float rounding at the sigmoid's centre
        for steepness in (1.0, 8.0, 50.0):
            soft = relaxed_limiter(c, steepness)
            assert torch.equal(learned_limiter(c)[off], (soft > 0.5).float()[off])
        assert learned_limiter(torch.tensor([0.3])).item() == 0.0
        assert hard_limiter(torch.tensor([0.3])).item() == 1.0  # eq. (3) would keep 0.3

    @pytest.mark.parametrize("steepness", [1.0, 8.0])
    def test_ste_forward_equals_learned_limiter(self, steepness):
        c = torch.linspace(-1.0, 2.0, 301)
        assert torch.equal(ste_limiter(c, steepness), learned_limiter(c))
        assert ste_limiter(torch.tensor([0.3])).item() == 0.0


def scaled(module, factor):
    with torch.no_grad():
        for p in module.parameters():
            p.mul_(factor)
    return module


class TestLearnedThreshold:
    """Learnable layers evaluate with ``c > 0.5`` (our reading), fixed ones with eq. (3)."""

    def test_thresholds(self):
        assert ModifiedHOCLayer(v=1).threshold == 0.0
        assert HOCLayer(v=1).threshold == 0.0
        assert ModifiedHOCLayer(v=1, learnable=True).threshold == LEARNED_THRESHOLD == 0.5
        assert HOCLayer(v=1, learnable=True).threshold == 0.5
        assert ModifiedHOCLayer(v=1).eval().activation() is hard_limiter
        assert ModifiedHOCLayer(v=1, learnable=True).eval().activation() is learned_limiter

    @pytest.mark.parametrize("delta", [math.pi / 4, None])
    def test_learnable_from_fixed_equals_fixed_in_eval(self, delta):
        cube = random_cube(11, (3, 10, 11, 12), 0.15)
        fixed = MHOCImage(order=2, v=2, delta=delta)(cube)
        learned = MHOCImage(order=2, v=2, delta=delta, learnable=True).eval()
        with torch.no_grad():
            out = learned(cube.float())
        assert torch.equal(out, fixed)
        assert torch.equal(out > 0, mhoc_image(cube, 2, 2, delta))
        assert fixed.sum() > 0

    @pytest.mark.parametrize("relax", ["sigmoid", "ste"])
    def test_kernels_scaled_by_0_3_are_off(self, relax):
        # a lone three-scan track: every count of the fixed network is 0 or 1
        f = torch.zeros(1, 3, 7, 7)
        f[0, 0, 3, 1] = f[0, 1, 3, 2] = f[0, 2, 3, 3] = 1.0
        fixed = ModifiedHOCLayer(v=1)(f)
        assert fixed[0, 0, 3, 1].item() == 1.0
        layer = scaled(ModifiedHOCLayer(v=1, learnable=True, relax=relax), 0.3)
        with torch.no_grad():
            assert layer.eval()(f).sum().item() == 0.0  # 0.3 < 0.5: off
            # eq. (3) (c > 0) would keep the point with these kernels
            kept = hoc_layer(f, layer.mask_kernels, layer.shift_kernels, activation=hard_limiter)
            assert kept[0, 0, 3, 1].item() == 1.0
            soft = layer.train()(f)
        assert soft[0, 0, 3, 1].item() < 0.5  # the relaxed limiter agrees: "off"

    def test_original_kernel_scaled_by_0_3_is_off(self):
        f = torch.zeros(1, 2, 5, 5)
        f[0, 0, 2, 2] = f[0, 1, 2, 3] = 1.0
        layer = scaled(HOCLayer(v=1, learnable=True), 0.3)
        with torch.no_grad():
            assert HOCLayer(v=1)(f)[0, 0, 2, 2].item() == 1.0
            assert layer.eval()(f).sum().item() == 0.0
            assert layer.train()(f)[0, 0, 2, 2].item() < 0.5

    def test_ste_training_forward_equals_eval(self):
        cube = random_cube(12, (2, 8, 9, 9), 0.2).float()
        net = scaled(MHOCImage(order=2, v=1, learnable=True, relax="ste", init="random"), 0.8)
        with torch.no_grad():
            train_out = net.train()(cube)
            eval_out = net.eval()(cube)
        assert torch.equal(train_out, eval_out)
        assert 0 < eval_out.sum() < cube.sum()

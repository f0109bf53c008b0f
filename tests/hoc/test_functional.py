import itertools
import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hocnet.hoc import chain_support, hoc_layer, hoc_levels, modified_hoc, original_hoc
from hocnet.hoc.kernels import get_direction_mask_kernels, get_shift_kernels
from hocnet.hoc.reference import chain_support_reference, hoc_reference

DELTAS = [math.pi / 8, math.pi / 4, math.pi / 2, 3 * math.pi / 4, math.pi, None]


def random_cube(seed: int, shape: tuple[int, ...], density: float) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(shape, generator=gen) < density


def as_numpy(cube: torch.Tensor) -> np.ndarray:
    return cube.cpu().numpy().astype(bool)


SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

cases = st.fixed_dictionaries(
    {
        "seed": st.integers(0, 10_000),
        "t": st.integers(3, 8),
        "h": st.integers(3, 8),
        "w": st.integers(3, 8),
        "density": st.sampled_from([0.05, 0.2, 0.45]),
        "v": st.integers(1, 4),
        "order": st.integers(1, 4),
        "delta": st.sampled_from(DELTAS),
        "direction": st.sampled_from(["forward", "backward"]),
    }
)


def _run(cube, c, method):
    if c["delta"] is None:
        return original_hoc(cube, c["order"], c["v"], c["direction"], method=method)
    return modified_hoc(cube, c["order"], c["v"], c["delta"], c["direction"], method=method)


class TestModifiedHOCReference:
    @SETTINGS
    @given(cases)
    def test_equals_reference(self, c):
        cube = random_cube(c["seed"], (c["t"], c["h"], c["w"]), c["density"])
        expected = hoc_reference(as_numpy(cube), c["order"], c["v"], c["delta"], c["direction"])
        for method in ("conv", "sparse"):
            out = _run(cube, c, method)
            assert out.dtype == torch.bool and out.shape == cube.shape
            np.testing.assert_array_equal(as_numpy(out), expected, err_msg=method)

    @pytest.mark.parametrize("seed", range(4))
    def test_backward_is_time_reversed_forward(self, seed):
        cube = random_cube(seed, (9, 12, 12), 0.15)
        fwd = modified_hoc(cube.flip(0), 2, 3)
        bwd = modified_hoc(cube, 2, 3, direction="backward")
        assert torch.equal(fwd.flip(0), bwd)

    @pytest.mark.parametrize("order", [1, 2, 3])
    def test_unevaluable_scans_are_zero(self, order):
        cube = torch.ones(8, 6, 6, dtype=torch.bool)
        fwd = modified_hoc(cube, order, 1)
        bwd = modified_hoc(cube, order, 1, direction="backward")
        t = 8
        assert fwd[: t - 2 * order].all() and not fwd[t - 2 * order :].any()
        assert bwd[2 * order :].all() and not bwd[: 2 * order].any()


class TestMethods:
    @pytest.mark.parametrize("seed", range(3))
    @pytest.mark.parametrize("density", [0.01, 0.05, 0.3])
    def test_conv_equals_sparse_batched(self, seed, density):
        cube = random_cube(seed, (2, 8, 16, 20), density)
        for direction in ("forward", "backward"):
            a = modified_hoc(cube, 3, 4, direction=direction, method="conv")
            b = modified_hoc(cube, 3, 4, direction=direction, method="sparse")
            assert torch.equal(a, b)

    def test_batch_elements_independent(self):
        cube = random_cube(5, (3, 8, 14, 14), 0.2)
        batched = modified_hoc(cube, 2, 2)
        for b in range(3):
            assert torch.equal(batched[b], modified_hoc(cube[b], 2, 2))

    def test_auto_matches(self):
        cube = random_cube(1, (8, 16, 16), 0.03)
        assert torch.equal(modified_hoc(cube, 2), modified_hoc(cube, 2, method="conv"))

    def test_input_dtypes_and_layouts(self):
        cube = random_cube(2, (8, 12, 10), 0.25)
        expected = modified_hoc(cube, 2, 2)
        for variant in (cube.float(), cube.double(), cube.to(torch.uint8), cube.numpy()):
            assert torch.equal(modified_hoc(variant, 2, 2), expected)
        wide = torch.zeros(8, 12, 20, dtype=torch.bool)
        wide[:, :, ::2] = cube
        strided = wide[:, :, ::2]
        assert not strided.is_contiguous()
        for method in ("conv", "sparse"):
            assert torch.equal(modified_hoc(strided, 2, 2, method=method), expected)

    def test_empty_scene(self):
        cube = torch.zeros(6, 10, 10, dtype=torch.bool)
        for method in ("conv", "sparse"):
            assert not modified_hoc(cube, 2, method=method).any()
            assert not chain_support(cube, 2, method=method).any()

    def test_levels(self):
        cube = random_cube(3, (1, 9, 10, 10), 0.3)
        levels = hoc_levels(cube, 3, 2)
        assert len(levels) == 4 and torch.equal(levels[0], cube)
        for lo, hi in itertools.pairwise(levels):
            assert not (hi & ~lo).any()  # each level is inside the one below


class TestHOCLayer:
    def test_single_layer_is_order_one(self):
        cube = random_cube(7, (1, 6, 9, 9), 0.3)
        k = get_direction_mask_kernels(2, math.pi / 4)
        s = get_shift_kernels(2)
        out = hoc_layer(cube.float(), k, s)
        assert torch.equal(out > 0, modified_hoc(cube, 1, 2))


class TestExceptions:
    @pytest.mark.parametrize(
        ("kwargs", "exc", "match"),
        [
            ({"order": 0}, ValueError, "`order`"),
            ({"order": 1.5}, TypeError, "`order`"),
            ({"v": 0}, ValueError, "`v`"),
            ({"delta": 0.0}, ValueError, "`delta`"),
            ({"delta": 4.0}, ValueError, "`delta`"),
            ({"direction": "sideways"}, ValueError, "`direction`"),
            ({"method": "fast"}, ValueError, "`method`"),
        ],
    )
    def test_bad_arguments(self, kwargs, exc, match):
        args = {"order": 1, "v": 2, "delta": math.pi / 4, "direction": "forward"}
        args.update(kwargs)
        method = args.pop("method", "auto")
        with pytest.raises(exc, match=match):
            modified_hoc(torch.zeros(4, 5, 5), **args, method=method)

    def test_wrong_rank(self):
        with pytest.raises(ValueError, match=r"`frames`: expected shape \(T, H, W\)"):
            modified_hoc(torch.zeros(5, 5), 1)

    def test_non_binary(self):
        with pytest.raises(ValueError, match="`frames`: expected binary"):
            modified_hoc(torch.full((3, 4, 4), 0.5), 1)

    def test_nan(self):
        cube = torch.zeros(3, 4, 4)
        cube[0, 0, 0] = float("nan")
        with pytest.raises(ValueError, match="`frames`: expected finite"):
            original_hoc(cube, 1)


class TestChainSupport:
    @settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(cases)
    def test_equals_reference(self, c):
        cube = random_cube(c["seed"], (c["t"], c["h"], c["w"]), c["density"])
        expected = chain_support_reference(as_numpy(cube), c["order"], c["v"], c["delta"])
        for method in ("conv", "sparse"):
            out = chain_support(cube, c["order"], c["v"], c["delta"], method=method)
            np.testing.assert_array_equal(as_numpy(out), expected, err_msg=method)

    def test_contains_both_directions(self):
        cube = random_cube(11, (9, 14, 14), 0.2)
        support = chain_support(cube, 2, 2)
        fwd = modified_hoc(cube, 2, 2)
        bwd = modified_hoc(cube, 2, 2, direction="backward")
        assert not ((fwd | bwd) & ~support).any()
        assert not (support & ~cube).any()

    def test_short_track_fully_kept(self):
        cube = torch.zeros(5, 9, 9, dtype=torch.bool)
        for t in range(5):
            cube[t, 1 + t, 2 + t] = True  # exactly 2k + 1 points for k = 2
        assert torch.equal(chain_support(cube, 2, 1), cube)
        assert modified_hoc(cube, 2, 1).sum() == 1  # forward alone keeps only the first point

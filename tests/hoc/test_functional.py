import itertools
import math
import time

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hocnet.hoc import (
    chain_support,
    density_bound,
    density_warning,
    effective_v,
    hoc_layer,
    hoc_levels,
    mhoc_image,
    modified_hoc,
    original_hoc,
    original_hoc_layer,
    scans_needed,
    support_from_levels,
)
from hocnet.hoc import functional as fn
from hocnet.hoc.kernels import get_direction_mask_kernels, get_shift_kernels, get_window_kernel
from hocnet.hoc.reference import (
    chain_support_reference,
    hoc_levels_reference,
    hoc_reference,
    mhoc_image_reference,
)

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


class TestOriginalHOCEq4:
    """Eq. (4): a two-scan window correlation per layer, k + 1 scans at order k."""

    def test_jagged_path_kept_curvature_free(self):
        cube = torch.zeros(3, 7, 7, dtype=torch.bool)
        cube[0, 3, 1] = cube[1, 3, 3] = cube[2, 3, 1] = True  # out and straight back
        assert original_hoc(cube, 2, v=2)[0, 3, 1]
        assert not modified_hoc(cube, 1, v=2).any()  # the modified HOC rejects the U-turn

    def test_two_scans_are_enough(self):
        cube = torch.zeros(2, 5, 5, dtype=torch.bool)
        cube[0, 0, 0] = cube[1, 2, 2] = True
        assert original_hoc(cube, 1, v=2).nonzero().tolist() == [[0, 0, 0]]
        assert not original_hoc(cube, 1, v=1).any()  # (2, 2) is outside the v = 1 window
        assert not modified_hoc(cube, 1, v=2).any()  # eq. (5) needs three scans

    @pytest.mark.parametrize("order", [1, 2, 3, 5])
    @pytest.mark.parametrize("method", ["conv", "sparse"])
    def test_valid_range(self, order, method):
        n_t = 7
        cube = torch.ones(n_t, 5, 6, dtype=torch.bool)
        fwd = original_hoc(cube, order, 1, method=method)
        bwd = original_hoc(cube, order, 1, "backward", method=method)
        last = n_t - 1 - order  # forward: t <= T - 1 - k
        assert fwd[: last + 1].all() and not fwd[last + 1 :].any()
        assert bwd[order:].all() and not bwd[:order].any()  # backward: t >= k

    @pytest.mark.parametrize("seed", range(3))
    def test_backward_is_time_reversed_forward(self, seed):
        cube = random_cube(seed, (8, 12, 12), 0.04)
        fwd = original_hoc(cube.flip(0), 3, 2)
        assert torch.equal(fwd.flip(0), original_hoc(cube, 3, 2, "backward"))

    def test_keeps_more_than_a_constant_velocity_reading(self):
        cube = random_cube(0, (10, 40, 40), 0.03)
        eq4 = original_hoc(cube, 2, 4)
        expected = hoc_reference(as_numpy(cube), 2, 4, None)
        np.testing.assert_array_equal(as_numpy(eq4), expected)
        # a constant-velocity triple is also an eq. (4) chain at order 2 (three scans), so
        # eq. (4) keeps at least as much; it keeps strictly more (issue 7: a straight-triple
        # reading, m2 = m1, returns exactly `const` and fails the second assertion)
        const = torch.zeros_like(cube)
        for t in range(10 - 2):
            for y, x in cube[t].nonzero().tolist():
                for j in range(-4, 5):
                    for i in range(-4, 5):
                        y2, x2 = y + 2 * j, x + 2 * i
                        if 0 <= y2 < 40 and 0 <= x2 < 40 and 0 <= y + j < 40 and 0 <= x + i < 40:
                            if cube[t + 1, y + j, x + i] and cube[t + 2, y2, x2]:
                                const[t, y, x] = True
        assert const.any()
        for method in ("conv", "sparse"):
            out = original_hoc(cube, 2, 4, method=method)
            assert torch.equal(out, eq4)
            assert not (const & ~out).any()
            assert int((out & ~const).sum()) > int(const.sum())

    def test_layer_equals_order_one(self):
        cube = random_cube(3, (1, 6, 9, 9), 0.2)
        out = original_hoc_layer(cube.float(), get_window_kernel(2))
        assert torch.equal(out > 0, original_hoc(cube, 1, 2))


small_cases = st.fixed_dictionaries(
    {
        "seed": st.integers(0, 10_000),
        "t": st.integers(3, 7),
        "h": st.integers(3, 7),
        "w": st.integers(3, 7),
        "density": st.sampled_from([0.1, 0.3, 0.6]),
        "v": st.integers(1, 3),
        "order": st.integers(1, 3),
        "delta": st.sampled_from([math.pi / 4, math.pi / 2, None]),
        "direction": st.sampled_from(["forward", "backward"]),
    }
)


class TestBoundedSparsePath:
    """The chunked / matrix-product sparse path (dense input) equals the loop reference."""

    @settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(small_cases)
    def test_equals_reference_with_tiny_chunks(self, c):
        cube = random_cube(c["seed"], (c["t"], c["h"], c["w"]), c["density"])
        old = fn._SPARSE_CHUNK, fn._SLOT_CHUNK
        fn._SPARSE_CHUNK, fn._SLOT_CHUNK = 20, 3  # force chunks and the matrix-product path
        try:
            out = hoc_levels(
                cube[None],
                c["order"],
                c["v"],
                c["delta"],
                direction=c["direction"],
                method="sparse",
            )
            support = chain_support(cube, c["order"], c["v"], c["delta"], method="sparse")
        finally:
            fn._SPARSE_CHUNK, fn._SLOT_CHUNK = old
        expected = hoc_levels_reference(
            as_numpy(cube), c["order"], c["v"], c["delta"], c["direction"]
        )
        for got, want in zip(out, expected, strict=True):
            np.testing.assert_array_equal(as_numpy(got[0]), want)
        np.testing.assert_array_equal(
            as_numpy(support),
            chain_support_reference(as_numpy(cube), c["order"], c["v"], c["delta"]),
        )

    def test_dense_sparse_equals_conv(self):
        cube = torch.ones(6, 9, 9, dtype=torch.bool)
        cube[2, 3:7, 3:7] = False
        for delta in (math.pi / 4, None):
            a = chain_support(cube, 2, 3, delta, method="sparse")
            b = chain_support(cube, 2, 3, delta, method="conv")
            assert torch.equal(a, b)


class TestMHOCImage:
    """Section III-B: forward Y^(k) OR backward Y^(k)."""

    @settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(small_cases)
    def test_equals_reference(self, c):
        cube = random_cube(c["seed"], (c["t"], c["h"], c["w"]), c["density"])
        expected = mhoc_image_reference(as_numpy(cube), c["order"], c["v"], c["delta"])
        for method in ("conv", "sparse"):
            out = mhoc_image(cube, c["order"], c["v"], c["delta"], method=method)
            np.testing.assert_array_equal(as_numpy(out), expected, err_msg=method)

    @settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(
        st.integers(-3, 3),
        st.integers(-3, 3),
        st.sampled_from([0.0, 0.02, 0.1, 0.3]),
        st.integers(0, 2**31 - 1),
    )
    def test_straight_ten_point_track_survives_any_clutter(self, i, j, density, seed):
        cube = random_cube(seed, (10, 32, 32), density)
        truth = torch.zeros_like(cube)
        y0, x0 = 16 - (9 * j) // 2, 16 - (9 * i) // 2
        for t in range(10):
            truth[t, y0 + t * j, x0 + t * i] = True
        for method in ("conv", "sparse"):
            image = mhoc_image(cube | truth, 2, 4, math.pi / 4, method=method)
            assert not (truth & ~image).any(), method  # all 10 points are in the image

    def test_coverage_condition(self):
        # every scan holds output iff T >= 4k (forward t <= T-1-2k, backward t >= 2k)
        for order, n_t in ((2, 8), (2, 7), (3, 12), (3, 10)):
            image = mhoc_image(torch.ones(n_t, 4, 4, dtype=torch.bool), order, 1)
            covered = image.flatten(1).any(1)
            assert bool(covered.all()) == (n_t >= 4 * order), (order, n_t)

    def test_subset_of_chain_support(self):
        cube = random_cube(2, (10, 30, 30), 0.05)
        image = mhoc_image(cube, 2)
        assert not (image & ~chain_support(cube, 2)).any()

    def test_batched(self):
        cube = random_cube(4, (2, 10, 16, 16), 0.05)
        out = mhoc_image(cube, 2, 3)
        for b in range(2):
            assert torch.equal(out[b], mhoc_image(cube[b], 2, 3))


class TestRobustness:
    """Issue 9, HOC side: empty batches, huge v, huge order, dense cubes answer boundedly."""

    @pytest.mark.parametrize("method", ["auto", "conv", "sparse"])
    def test_empty_batch(self, method):
        cube = torch.zeros(0, 6, 16, 16, dtype=torch.bool)
        for out in (
            modified_hoc(cube, 2, method=method),
            original_hoc(cube, 2, method=method),
            chain_support(cube, 2, method=method),
            chain_support(cube, 2, delta=None, method=method),
            mhoc_image(cube, 2, method=method),
        ):
            assert out.shape == (0, 6, 16, 16) and out.dtype == torch.bool
        levels = hoc_levels(cube, 2, method=method)
        assert len(levels) == 3 and all(y.shape == cube.shape for y in levels)
        assert support_from_levels(levels, method=method).shape == cube.shape

    def test_effective_v(self):
        assert effective_v(1000, 24, 16) == 23
        assert effective_v(3, 24, 16) == 3
        assert effective_v(5, 1, 1) == 1
        with pytest.raises(ValueError, match="`v`"):
            effective_v(0, 5, 5)

    @pytest.mark.parametrize("delta", [math.pi / 4, None])
    def test_v_larger_than_frame_is_clamped_exactly(self, delta):
        cube = random_cube(8, (6, 4, 5), 0.3)
        expected = hoc_reference(as_numpy(cube), 2, 7, delta)  # 7 > max(H, W) - 1
        for v in (4, 7, 1000):
            for method in ("conv", "sparse"):
                out = hoc_levels(cube[None], 2, v, delta, method=method)[-1][0]
                np.testing.assert_array_equal(as_numpy(out), expected)

    @pytest.mark.parametrize("v", [100, 1000])
    def test_huge_v_answers_within_a_second(self, v):
        small = random_cube(1, (10, 24, 24), 0.02)
        start = time.perf_counter()
        modified_hoc(small, 2, v)  # clamped to 23 (about 0.3 s idle, building the move table)
        original_hoc(small, 2, v)
        assert time.perf_counter() - start < 2.0  # slack for a loaded test machine
        big = torch.zeros(10, 512, 640, dtype=torch.bool)
        big[:, 100, 100] = True
        start = time.perf_counter()
        with pytest.raises(ValueError, match="`v`: expected a velocity window small enough"):
            modified_hoc(big, 2, v)
        with pytest.raises(ValueError, match="`v`"):
            chain_support(big, 2, v)
        assert time.perf_counter() - start < 1.0

    def test_memory_budget_names_v(self, monkeypatch):
        monkeypatch.setattr(fn, "MEMORY_BUDGET", 1000)
        with pytest.raises(ValueError, match=r"`v`.*MEMORY_BUDGET"):
            modified_hoc(random_cube(0, (5, 9, 9), 0.1), 1, 2)

    @pytest.mark.parametrize("fun", [modified_hoc, original_hoc, chain_support, mhoc_image])
    def test_order_beyond_the_scans_answers_at_once(self, fun):
        cube = torch.ones(10, 48, 48, dtype=torch.bool)
        start = time.perf_counter()
        out = fun(cube, 10_000)
        assert time.perf_counter() - start < 0.5
        assert not out.any()

    def test_levels_beyond_the_scans_are_zero(self):
        cube = torch.ones(1, 5, 4, 4, dtype=torch.bool)
        levels = hoc_levels(cube, 4, 1)
        assert [int(y.sum()) for y in levels] == [80, 48, 16, 0, 0]
        assert scans_needed(2) == 5 and scans_needed(4, "original") == 5
        assert not original_hoc(torch.ones(4, 3, 3), 4).any()  # k + 1 = 5 > 4 scans

    @pytest.mark.parametrize("fun", [chain_support, mhoc_image])
    def test_dense_cube_is_bounded(self, fun):
        cube = torch.ones(10, 48, 48, dtype=torch.bool)
        start = time.perf_counter()
        out = fun(cube, 2)
        assert time.perf_counter() - start < 10.0
        assert out.all()


class TestDensityBound:
    def test_original_bound_is_the_printed_one_over_81(self):
        # section IV-B prints "1/81 = 1.23%"
        assert round(100 * density_bound("original", 4), 2) == 1.23
        assert density_bound("original", 4) == pytest.approx(1 / 81)

    def test_modified_bound_against_the_printed_value(self):
        # section IV-B prints "(1/81) x 4 = 4.92%": the rounded 1.23 % times 4
        bound = density_bound("modified", 4, math.pi / 4)
        assert bound == pytest.approx(4 / 81)
        assert abs(100 * bound - 4.92) < 0.03
        assert round(100 * density_bound("original", 4), 2) * 4 == pytest.approx(4.92)

    def test_scaling(self):
        assert density_bound("modified", 4, math.pi / 2) == pytest.approx(2 / 81)
        assert density_bound("original", 1) == pytest.approx(1 / 9)
        assert density_bound("modified", 1, 0.01) == 1.0

    @pytest.mark.parametrize(("kwargs", "match"), [({"kind": "x"}, "`kind`"), ({"v": 0}, "`v`")])
    def test_bad_arguments(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            density_bound(**kwargs)

    def test_warning(self):
        low = random_cube(0, (10, 100, 100), 0.01)
        high = random_cube(0, (10, 100, 100), 0.03)
        assert density_warning(low) is None
        assert density_warning(high) is None  # 3 % < 4.94 %
        message = density_warning(high, "original")
        assert message is not None and "1.23 %" in message and "original" in message
        assert density_warning(torch.zeros(0, 4, 5, 5)) is None

import pytest
import torch

from hocnet.data.whitening import AntiMean, AntiMedian, anti_mean, anti_median, get_ring_kernel

SIZES = [(3, 1), (5, 1), (5, 3), (7, 3), (7, 5)]


def _reflect(k: int, n: int) -> int:
    """Index into a length-``n`` axis with reflection (no edge repeat), as numpy 'reflect'."""
    if k < 0:
        return -k
    if k >= n:
        return 2 * (n - 1) - k
    return k


def expected_fn(frames: torch.Tensor, outer: int, inner: int, mode: str) -> torch.Tensor:
    """Slow loop-level whitening: pixel minus the mean / lower median of its ring."""
    r, g = outer // 2, inner // 2
    *lead, h, w = frames.shape
    flat = frames.reshape(-1, h, w)
    out = torch.empty_like(flat)
    for f in range(flat.shape[0]):
        img = flat[f].tolist()
        for i in range(h):
            for j in range(w):
                ring = [
                    img[_reflect(i + di, h)][_reflect(j + dj, w)]
                    for di in range(-r, r + 1)
                    for dj in range(-r, r + 1)
                    if max(abs(di), abs(dj)) > g
                ]
                if mode == "mean":
                    background = sum(ring) / len(ring)
                else:
                    background = sorted(ring)[(len(ring) - 1) // 2]  # lower median
                out[f, i, j] = flat[f, i, j] - torch.tensor(background, dtype=flat.dtype)
    return out.reshape(*lead, h, w)


class TestGetRingKernel:
    @pytest.mark.parametrize(("outer", "inner"), SIZES)
    def test_ring(self, outer, inner):
        kernel = get_ring_kernel(outer, inner)
        assert kernel.shape == (outer, outer)
        count = outer * outer - inner * inner
        assert int((kernel > 0).sum()) == count
        torch.testing.assert_close(kernel[kernel > 0], torch.full((count,), 1.0 / count))
        lo = (outer - inner) // 2
        assert (kernel[lo : lo + inner, lo : lo + inner] == 0).all()
        assert kernel.sum().item() == pytest.approx(1.0)

    def test_defaults(self):
        kernel = get_ring_kernel()
        assert kernel.shape == (7, 7)
        assert int((kernel > 0).sum()) == 40

    def test_device_dtype(self):
        kernel = get_ring_kernel(5, 3, device="cpu", dtype=torch.float64)
        assert kernel.dtype == torch.float64
        assert kernel.device.type == "cpu"

    @pytest.mark.parametrize(
        ("outer", "inner", "name", "error"),
        [
            (6, 3, "outer", ValueError),
            (1, 1, "outer", ValueError),
            (7, 4, "inner", ValueError),
            (5, 5, "inner", ValueError),
            (5, 7, "inner", ValueError),
            (5, 0, "inner", ValueError),
            (5.0, 3, "outer", TypeError),
            (5, "3", "inner", TypeError),
        ],
    )
    def test_exceptions(self, outer, inner, name, error):
        with pytest.raises(error, match=f"`{name}`"):
            get_ring_kernel(outer, inner)


class _WhiteningTests:
    mode: str
    fn = None
    module = None

    def test_smoke(self):
        out = self.fn(torch.randn(3, 12, 12))
        assert torch.isfinite(out).all()

    @pytest.mark.parametrize("shape", [(4, 9, 11), (2, 3, 9, 11), (1, 1, 7, 7)])
    def test_shapes(self, shape):
        frames = torch.randn(shape)
        out = self.fn(frames)
        assert out.shape == frames.shape
        assert out.dtype == frames.dtype

    @pytest.mark.parametrize("seed", range(3))
    @pytest.mark.parametrize(("outer", "inner"), SIZES)
    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_reference(self, seed, outer, inner, dtype):
        gen = torch.Generator().manual_seed(seed)
        frames = torch.randn(2, 2, 8, 9, generator=gen, dtype=dtype) * 5.0
        got = self.fn(frames, outer, inner)
        expected = expected_fn(frames, outer, inner, self.mode)
        if self.mode == "median":
            assert torch.equal(got, expected)
        else:
            tol = 1e-5 if dtype == torch.float32 else 1e-12
            torch.testing.assert_close(got, expected, rtol=0, atol=tol)

    def test_reference_with_ties(self):
        gen = torch.Generator().manual_seed(0)
        frames = torch.randint(0, 4, (3, 7, 8), generator=gen).float()
        expected = expected_fn(frames, 5, 3, self.mode)
        torch.testing.assert_close(self.fn(frames, 5, 3), expected, rtol=0, atol=1e-5)

    def test_non_contiguous(self):
        frames = torch.randn(2, 10, 12, 9).transpose(-1, -2)[:, ::2]
        assert not frames.is_contiguous()
        torch.testing.assert_close(self.fn(frames, 5, 3), self.fn(frames.contiguous(), 5, 3))

    def test_unbatched_equals_batched(self):
        frames = torch.randn(2, 3, 10, 10)
        torch.testing.assert_close(self.fn(frames)[1], self.fn(frames[1]))

    def test_integer_input_gives_float32(self):
        frames = torch.randint(0, 10, (2, 8, 8))
        out = self.fn(frames, 5, 3)
        assert out.dtype == torch.float32
        torch.testing.assert_close(out, self.fn(frames.float(), 5, 3))

    def test_constant_whitens_to_zero(self):
        frames = torch.full((2, 3, 10, 12), 7.25)
        torch.testing.assert_close(self.fn(frames), torch.zeros_like(frames), rtol=0, atol=1e-5)

    def test_smooth_background_removed(self):
        y, x = torch.meshgrid(torch.arange(20.0), torch.arange(20.0), indexing="ij")
        plane = (3.0 + 0.5 * x - 0.25 * y).expand(4, 20, 20)
        out = self.fn(plane)
        # A linear ramp is its own ring mean / median away from the border.
        torch.testing.assert_close(out[:, 3:-3, 3:-3], torch.zeros(4, 14, 14), atol=1e-4, rtol=0)

    def test_point_target_survives(self):
        frames = torch.zeros(1, 2, 15, 15)
        frames[0, :, 7, 7] = 10.0  # target on a flat background
        frames[0, :, 7, 8] = 4.0  # PSF spill into the guard window
        out = self.fn(frames)
        assert out[0, :, 7, 7].tolist() == pytest.approx([10.0, 10.0], abs=1e-5)
        assert int(out[0, 0].flatten().argmax()) == 7 * 15 + 7

    def test_border_reflection(self):
        frames = torch.zeros(1, 7, 7)
        frames[0, 0, 1] = 40.0  # reflected onto (0, -1) for border pixels' rings
        got = self.fn(frames, 3, 1)
        torch.testing.assert_close(got, expected_fn(frames, 3, 1, self.mode))

    def test_module_equals_function(self):
        frames = torch.randn(2, 3, 11, 13)
        module = self.module(5, 3)
        assert torch.equal(module(frames), self.fn(frames, 5, 3))
        assert torch.equal(module(frames[0]), self.fn(frames[0], 5, 3))

    def test_module_buffer(self):
        module = self.module()
        assert "kernel" in dict(module.named_buffers())
        assert list(module.parameters()) == []
        assert "kernel" in module.state_dict()
        torch.testing.assert_close(module.kernel, get_ring_kernel(7, 3))
        assert "outer=7, inner=3" in repr(module)
        module = module.to(torch.float64)
        frames = torch.randn(2, 8, 8, dtype=torch.float64)
        assert module(frames).dtype == torch.float64
        assert torch.equal(module(frames), self.fn(frames))

    def test_gradcheck(self):
        gen = torch.Generator().manual_seed(0)
        frames = torch.randn(1, 1, 5, 6, generator=gen, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda f: self.fn(f, 3, 1), (frames,))

    @pytest.mark.parametrize(
        ("frames", "kwargs", "name", "error"),
        [
            (torch.full((2, 5, 5), float("nan")), {"outer": 3, "inner": 1}, "frames", ValueError),
            (torch.zeros(5, 5), {}, "frames", ValueError),
            (torch.zeros(2, 8, 6), {"outer": 7}, "outer", ValueError),
            (torch.zeros(2, 6, 8), {"outer": 7}, "outer", ValueError),
            (torch.zeros(2, 8, 8), {"outer": 4}, "outer", ValueError),
            (torch.zeros(2, 8, 8), {"inner": 7}, "inner", ValueError),
            (torch.zeros(2, 8, 8, dtype=torch.complex64), {}, "frames", TypeError),
            ("frames", {}, "frames", TypeError),
        ],
    )
    def test_exceptions(self, frames, kwargs, name, error):
        with pytest.raises(error, match=f"`{name}`"):
            self.fn(frames, **kwargs)

    def test_module_exceptions(self):
        with pytest.raises(ValueError, match="`outer`"):
            self.module(8, 3)

    @pytest.mark.parametrize(
        ("dtype", "big", "name"),
        [(torch.float32, 3e38, "float32"), (torch.float64, 1.7e308, "float64")],
    )
    def test_huge_finite_values_say_overflow(self, dtype, big, name):
        # issue 9: finite but huge frames were reported later as "got 1848 NaN/inf entries"
        frames = torch.full((2, 12, 12), -big, dtype=dtype)
        frames[:, 6, 6] = big  # pixel minus ring estimate = 2 * big
        assert torch.isfinite(frames).all()
        with pytest.raises(ValueError, match=rf"`frames`: values too large for {name} after"):
            self.fn(frames)
        with pytest.raises(ValueError, match=r"values too large"):
            self.module()(frames)
        with pytest.raises(ValueError, match="`outer`"):
            self.module(7, 3)(torch.zeros(2, 5, 5))
        with pytest.raises(ValueError, match="`frames`"):
            self.module(3, 1)(torch.full((2, 5, 5), float("inf")))


class TestAntiMean(_WhiteningTests):
    mode = "mean"
    fn = staticmethod(anti_mean)
    module = AntiMean

    def test_is_identity_minus_ring_conv(self):
        frames = torch.randn(2, 9, 9)
        ring = get_ring_kernel(5, 3)
        padded = torch.nn.functional.pad(frames[:, None], (2, 2, 2, 2), mode="reflect")
        mean = torch.nn.functional.conv2d(padded, ring[None, None])[:, 0]
        torch.testing.assert_close(anti_mean(frames, 5, 3), frames - mean)


class TestAntiMedian(_WhiteningTests):
    mode = "median"
    fn = staticmethod(anti_median)
    module = AntiMedian

    def test_lower_median_convention(self):
        # Ring of 8 values 0..7 around the centre: lower median is 3, not 3.5.
        frames = torch.zeros(1, 3, 3, dtype=torch.float64)
        frames[0] = torch.tensor([[0.0, 1.0, 2.0], [3.0, 100.0, 4.0], [5.0, 6.0, 7.0]])
        assert anti_median(frames, 3, 1)[0, 1, 1].item() == 97.0

    def test_robust_to_a_bright_ring_pixel(self):
        frames = torch.zeros(1, 11, 11)
        frames[0, 2, 5] = 1000.0  # an outlier in the ring of (5, 5)
        assert anti_median(frames)[0, 5, 5].item() == 0.0
        assert anti_mean(frames)[0, 5, 5].item() == pytest.approx(-25.0)

    def test_chunked(self, monkeypatch):
        from hocnet.data import whitening

        frames = torch.randn(3, 4, 9, 9)
        full = anti_median(frames, 5, 3)
        monkeypatch.setattr(whitening, "_MEDIAN_CHUNK", 1)
        assert torch.equal(anti_median(frames, 5, 3), full)

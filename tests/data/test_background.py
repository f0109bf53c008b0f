import math
from statistics import NormalDist

import numpy as np
import pytest
import torch
from scipy.stats import t as student

from hocnet.data.background import (
    REGISTRATION_PFA,
    BackgroundRemoval,
    Registration,
    estimate_shifts,
    register,
    registration_threshold,
    remove_background,
    shift_frames,
    shift_significance,
    temporal_background,
)
from hocnet.data.infrared import IRTarget, simulate_ir

# ----------------------------------------------------------------------------- loop references


def expected_background(frames, method, window, offsets=None):
    """Per pixel, per frame: mean / lower median of the valid past samples (integer offsets).

    With ``offsets``, the sample of past frame ``m`` at pixel ``(y, x)`` of frame ``n`` is
    ``frames[m][y - dy][x - dx]`` with ``(dx, dy) = offsets[n] - offsets[m]``, if inside.
    """
    t, h, w = frames.shape
    f = frames.tolist()
    out = [[[0.0] * w for _ in range(h)] for _ in range(t)]
    for n in range(t):
        for y in range(h):
            for x in range(w):
                samples = []
                for m in range(max(0, n - window), n):
                    dx, dy = 0, 0
                    if offsets is not None:
                        dx = int(offsets[n][0] - offsets[m][0])
                        dy = int(offsets[n][1] - offsets[m][1])
                    sy, sx = y - dy, x - dx
                    if 0 <= sy < h and 0 <= sx < w:
                        samples.append(f[m][sy][sx])
                if not samples:
                    out[n][y][x] = f[n][y][x]
                elif method == "mean":
                    out[n][y][x] = sum(samples) / len(samples)
                else:
                    out[n][y][x] = sorted(samples)[(len(samples) - 1) // 2]
    return torch.tensor(out, dtype=frames.dtype)


def expected_lowrank(frames, window, rank, iterations, clip):
    """Robust low-rank background written plainly with numpy SVD (no offsets)."""
    x = frames.numpy().astype(np.float64)
    t, h, w = x.shape
    out = x.copy()
    for n in range(1, t):
        past = x[max(0, n - window) : n].reshape(-1, h * w)
        r = min(rank, past.shape[0])
        work = past
        for _ in range(iterations + 1):
            u, s, vt = np.linalg.svd(work, full_matrices=False)
            approx = (u[:, :r] * s[:r]) @ vt[:r]
            resid = past - approx
            per_frame = [lower_median(row) for row in np.abs(resid)]
            scale = 1.4826 * lower_median(per_frame)
            work = approx + np.clip(resid, -clip * scale, clip * scale)
        out[n] = approx[-1].reshape(h, w)
    return torch.from_numpy(out).to(frames.dtype)


def lower_median(values):
    values = sorted(values)
    return values[(len(values) - 1) // 2]


def expected_shift(image, dx, dy):
    """Bilinear shift written per pixel: out(x, y) = image(x - dx, y - dy), NaN outside."""
    h, w = image.shape
    out = torch.full((h, w), math.nan, dtype=image.dtype)
    for y in range(h):
        for x in range(w):
            sx, sy = x - dx, y - dy
            if -1e-6 <= sx <= w - 1 + 1e-6 and -1e-6 <= sy <= h - 1 + 1e-6:
                sx, sy = min(max(sx, 0.0), w - 1), min(max(sy, 0.0), h - 1)
                x0, y0 = min(math.floor(sx), w - 2), min(math.floor(sy), h - 2)
                fx, fy = sx - x0, sy - y0
                out[y, x] = (
                    (1 - fx) * (1 - fy) * image[y0, x0]
                    + fx * (1 - fy) * image[y0, x0 + 1]
                    + (1 - fx) * fy * image[y0 + 1, x0]
                    + fx * fy * image[y0 + 1, x0 + 1]
                )
    return out


def smooth_texture(h, w, seed, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    spec = torch.randn(h, w, generator=g, dtype=dtype) + 1j * torch.randn(
        h, w, generator=g, dtype=dtype
    )
    ky = torch.fft.fftfreq(h, dtype=dtype).view(h, 1)
    kx = torch.fft.fftfreq(w, dtype=dtype).view(1, w)
    spec = spec * torch.exp(-((ky**2 + kx**2) / (2 * 0.08**2)))
    img = torch.fft.ifft2(spec).real
    return (img - img.mean()) / img.std()


def power_law_texture(h, w, seed):
    """Random texture with a 1/f amplitude spectrum (like natural scenes)."""
    g = torch.Generator().manual_seed(seed)
    spec = torch.randn(h, w, generator=g, dtype=torch.float64) + 1j * torch.randn(
        h, w, generator=g, dtype=torch.float64
    )
    ky = torch.fft.fftfreq(h, dtype=torch.float64).view(h, 1)
    kx = torch.fft.fftfreq(w, dtype=torch.float64).view(1, w)
    k = torch.sqrt(ky**2 + kx**2)
    k[0, 0] = 1.0
    img = torch.fft.ifft2(spec / k).real
    return (img - img.mean()) / img.std()


def expected_significance(a, b, taper=True, guard=2, train=6):
    """Local peak-to-sidelobe ratio of the phase correlation of ``b`` against ``a``, by loops.

    Written from the definition: r = IFFT(B conj(A) / |B conj(A)|) of the mean-removed
    (Hann-tapered) frames; the training cells are those within ``train`` px of the arg-max per
    axis (circularly; fewer on small frames) and outside the ``guard`` square (smaller on
    small frames); ratio = (peak - their mean) / their unbiased std.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    h, w = a.shape
    win = np.outer(np.hanning(h), np.hanning(w)) if taper else np.ones((h, w))
    fa = np.fft.fft2((a - a.mean()) * win)
    fb = np.fft.fft2((b - b.mean()) * win)
    cross = fb * np.conj(fa)
    mag = np.abs(cross)
    cross = cross / np.where(mag > 0, mag, 1.0)
    r = np.fft.ifft2(cross).real
    iy, ix = np.unravel_index(int(np.argmax(r)), r.shape)
    ry, rx = min(train, (h - 1) // 2), min(train, (w - 1) // 2)
    g = min(guard, max(ry, rx) - 1)
    cells = []
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            if abs(dy) > g or abs(dx) > g:
                cells.append(r[(iy + dy) % h, (ix + dx) % w])
    mean = sum(cells) / len(cells)
    std = math.sqrt(sum((c - mean) ** 2 for c in cells) / (len(cells) - 1))
    return (r[iy, ix] - mean) / std


def fourier_shift(img, dx, dy):
    h, w = img.shape
    ky = torch.fft.fftfreq(h, dtype=img.dtype).view(h, 1)
    kx = torch.fft.fftfreq(w, dtype=img.dtype).view(1, w)
    ramp = torch.exp(-2j * math.pi * (kx * dx + ky * dy))
    return torch.fft.ifft2(torch.fft.fft2(img) * ramp).real


# ----------------------------------------------------------------------------- background


class TestTemporalBackground:
    @pytest.mark.parametrize("method", ["mean", "median"])
    @pytest.mark.parametrize("window", [1, 3, 10])
    @pytest.mark.parametrize("seed", [0, 1])
    def test_reference(self, method, window, seed):
        frames = torch.rand(7, 5, 6, generator=torch.Generator().manual_seed(seed)).double()
        got = temporal_background(frames, method, window)
        torch.testing.assert_close(got, expected_background(frames, method, window))

    @pytest.mark.parametrize("method", ["mean", "median"])
    def test_reference_integer_offsets(self, method):
        g = torch.Generator().manual_seed(3)
        frames = torch.rand(6, 7, 8, generator=g).double()
        offsets = torch.tensor([[0, 0], [1, 0], [1, 2], [-1, 2], [0, 0], [2, -1]]).double()
        got = temporal_background(frames, method, 3, offsets=offsets)
        want = expected_background(frames, method, 3, offsets.tolist())
        torch.testing.assert_close(got, want)

    @pytest.mark.parametrize("window,rank", [(3, 1), (6, 2)])
    def test_lowrank_reference(self, window, rank):
        g = torch.Generator().manual_seed(5)
        frames = (torch.rand(8, 6, 5, generator=g) + torch.arange(8).view(8, 1, 1)).double()
        got = temporal_background(frames, "lowrank", window, rank=rank, iterations=2, clip=2.5)
        torch.testing.assert_close(got, expected_lowrank(frames, window, rank, 2, 2.5))

    def test_causal(self):
        """Changing frame n never changes the background of frames <= n."""
        g = torch.Generator().manual_seed(0)
        frames = torch.rand(8, 6, 6, generator=g)
        changed = frames.clone()
        changed[5] += 10
        for method in ("mean", "median", "lowrank"):
            a = temporal_background(frames, method, 4)
            b = temporal_background(changed, method, 4)
            torch.testing.assert_close(a[:6], b[:6])
            assert not torch.allclose(a[6:], b[6:])

    def test_registered_static_scene_removed(self):
        """A scene that slides by whole pixels is removed except where it entered the frame."""
        scene = torch.rand(20, 30, generator=torch.Generator().manual_seed(1))
        frames = torch.stack([scene[2 + 0 : 2 + 12, n : n + 16] for n in range(6)])  # moves -x
        offsets = torch.tensor([[-float(n), 0.0] for n in range(6)])
        res = remove_background(frames, "median", 3, offsets=offsets)
        assert res[1:, :, :-1].abs().max() < 1e-6  # the last column is new each frame: 0
        assert res[1:, :, -1].abs().max() == 0  # no past sample: residual 0 by convention
        assert res[1:].abs().max() < 1e-6
        unregistered = remove_background(frames, "median", 3)
        assert unregistered[1:].abs().max() > 0.1

    def test_batched_equals_unbatched(self):
        g = torch.Generator().manual_seed(2)
        frames = torch.rand(2, 6, 8, 8, generator=g)
        offsets = torch.randn(2, 6, 2, generator=g)
        out = remove_background(frames, "mean", 3, offsets=offsets)
        for i in range(2):
            torch.testing.assert_close(
                out[i], remove_background(frames[i], "mean", 3, offsets=offsets[i])
            )

    def test_frame0_zero_and_dtypes(self):
        frames = torch.randint(0, 255, (4, 8, 8), dtype=torch.uint8)
        out = remove_background(frames)
        assert out.dtype == torch.float32 and out.shape == (4, 8, 8)
        assert out[0].abs().max() == 0
        assert frames.dtype == torch.uint8  # input untouched

    def test_empty_batch(self):
        assert remove_background(torch.zeros(0, 4, 5, 5)).shape == (0, 4, 5, 5)

    def test_module_equals_function(self):
        frames = torch.rand(5, 8, 8)
        module = BackgroundRemoval("lowrank", 3, rank=1)
        torch.testing.assert_close(module(frames), remove_background(frames, "lowrank", 3))
        assert "lowrank" in repr(module)

    @pytest.mark.parametrize(
        "kwargs,match",
        [
            ({"method": "max"}, "`method`: expected one of"),
            ({"window": 0}, "`window`: expected an integer >= 1"),
            ({"clip": 0.0}, "`clip`: expected a number in"),
            ({"interpolation": "cubic"}, "`interpolation`"),
            ({"offsets": torch.zeros(3, 2)}, r"`offsets`: expected shape \(4, 2\)"),
        ],
    )
    def test_errors(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            remove_background(torch.zeros(4, 5, 5), **kwargs)

    def test_nan_input(self):
        frames = torch.zeros(3, 4, 4)
        frames[1, 1, 1] = math.nan
        with pytest.raises(ValueError, match="`frames`: expected finite values"):
            remove_background(frames)


# ----------------------------------------------------------------------------- registration


class TestShiftFrames:
    @pytest.mark.parametrize("dx,dy", [(0.0, 0.0), (1.0, -2.0), (0.3, 0.7), (-1.6, 2.25)])
    def test_bilinear_reference(self, dx, dy):
        img = torch.rand(6, 7, generator=torch.Generator().manual_seed(0)).double()
        got = shift_frames(img[None], torch.tensor([[dx, dy]]), fill=math.nan)[0]
        torch.testing.assert_close(got, expected_shift(img, dx, dy), equal_nan=True)

    def test_fourier_integer_equals_roll_inside(self):
        img = torch.rand(8, 10, dtype=torch.float64)
        got = shift_frames(img[None], torch.tensor([[2.0, 1.0]]), mode="fourier")[0]
        torch.testing.assert_close(got[1:, 2:], img[:-1, :-2])
        assert got[0].abs().max() == 0 and got[:, :2].abs().max() == 0  # fill = 0

    def test_fourier_subpixel_matches_band_limited_shift(self):
        img = smooth_texture(32, 32, 4)
        got = shift_frames(img[None], torch.tensor([[0.4, -0.3]]), mode="fourier")[0]
        want = fourier_shift(img, 0.4, -0.3)
        torch.testing.assert_close(got[:-1, 1:], want[:-1, 1:])

    def test_errors(self):
        with pytest.raises(ValueError, match=r"`shifts`: expected shape \(2, 2\)"):
            shift_frames(torch.zeros(2, 4, 4), torch.zeros(3, 2))
        with pytest.raises(ValueError, match="`mode`"):
            shift_frames(torch.zeros(2, 4, 4), torch.zeros(2, 2), mode="cubic")
        with pytest.raises(ValueError, match="`shifts`: expected finite"):
            shift_frames(torch.zeros(2, 4, 4), torch.full((2, 2), math.nan))


class TestEstimateShifts:
    @pytest.mark.parametrize("dy,dx", [(0, 0), (3, -5), (-7, 2), (10, 12)])
    def test_integer_circular(self, dy, dx):
        img = torch.rand(48, 64, generator=torch.Generator().manual_seed(1))
        frames = torch.stack([img, img.roll((dy, dx), dims=(0, 1))])
        got = estimate_shifts(frames, taper=False)
        assert got[0].tolist() == [0.0, 0.0]
        torch.testing.assert_close(got[1], torch.tensor([float(dx), float(dy)]))

    @pytest.mark.parametrize("seed", [0, 1, 2])
    @pytest.mark.parametrize("crop", [False, True])
    def test_subpixel_accuracy(self, seed, crop):
        """Sub-pixel shifts of a 1/f texture plus noise: error < 0.1 px per axis.

        ``crop``: 64 x 64 crops of a shifted 128 x 128 scene (non-circular, Hann taper);
        else circular shifts of a 64 x 64 scene without taper. Measured when written: max
        error 0.02-0.04 px.
        """
        g = torch.Generator().manual_seed(seed)
        img = power_law_texture(128 if crop else 64, 128 if crop else 64, seed)
        true = torch.rand(5, 2, generator=g, dtype=torch.float64) * 6 - 3
        pos = torch.zeros(2, dtype=torch.float64)
        frames = [img]
        for s in true:
            pos = pos + s
            frames.append(fourier_shift(img, float(pos[0]), float(pos[1])))
        cube = torch.stack(frames)
        if crop:
            cube = cube[:, 32:96, 32:96]
        cube = cube + 0.05 * torch.randn(cube.shape, generator=g, dtype=torch.float64)
        got = estimate_shifts(cube, taper=crop)
        err = (got[1:] - true).abs().max()
        assert err < 0.1, err

    def test_brute_force_integer_reference(self):
        """The integer part equals the best circular match found by trying every shift."""
        g = torch.Generator().manual_seed(7)
        a = torch.rand(12, 12, generator=g, dtype=torch.float64)
        b = a.roll((2, -3), dims=(0, 1)) + 0.05 * torch.rand(12, 12, generator=g)
        best = max(
            ((dy, dx) for dy in range(-6, 6) for dx in range(-6, 6)),
            key=lambda d: float((a.roll(d, dims=(0, 1)) * b).sum()),
        )
        got = estimate_shifts(torch.stack([a, b]), taper=False)[1].round()
        assert got.tolist() == [float(best[1]), float(best[0])]

    def test_batched_and_short(self):
        frames = torch.rand(3, 4, 16, 16)
        got = estimate_shifts(frames)
        assert got.shape == (3, 4, 2)
        torch.testing.assert_close(got[1], estimate_shifts(frames[1]))
        assert estimate_shifts(torch.rand(1, 8, 8)).tolist() == [[0.0, 0.0]]
        assert estimate_shifts(torch.zeros(0, 3, 8, 8)).shape == (0, 3, 2)


class TestPeakTest:
    """The peak test of ``estimate_shifts`` (a CFAR on the phase-correlation surface)."""

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_still_clear_sky_with_dim_target(self, seed):
        """Still camera, clear sky, 0.25 px jitter, one dim target: shifts stay within 1 px.

        The user's report: white noise + a dim target, 48 x 48; without the test the
        registration locked onto noise (shifts up to 12 px here, drift of tens of px).
        """
        target = IRTarget(10.0, 20.0, 0.5, 0.2, snr_db=6.0)
        seq = simulate_ir((40, 48, 48), [target], clouds="clear", jitter=0.25, seed=seed)
        got = estimate_shifts(seq.frames)
        assert bool(torch.isfinite(got).all())
        assert got.norm(dim=-1).max() <= 1.0
        assert got.sum(dim=0).norm() <= 1.0  # no drift
        old = estimate_shifts(seq.frames, pfa=None)  # the behaviour before the test
        assert old.norm(dim=-1).max() > 3.0  # (so this test can fail)

    def test_white_noise_rejected(self):
        """Independent white-noise frames: no pair passes at the default pfa (1e-6).

        Measured when written: 0 of 2000 pairs of 48 x 48 frames; ratios up to about 5.2
        against the threshold 6.1.
        """
        g = torch.Generator().manual_seed(11)
        frames = torch.randn(4, 51, 48, 48, generator=g)
        assert estimate_shifts(frames).abs().max() == 0
        ratio = shift_significance(frames)[:, 1:]
        assert ratio.max() < 6.13 and ratio.min() > 1.0

    @pytest.mark.parametrize("value", [0.0, 7.3, 1000.1, -3e5])
    @pytest.mark.parametrize("shape", [(48, 48), (17, 30), (1, 9), (3, 3), (1, 1)])
    def test_flat_frames_zero(self, value, shape):
        frames = torch.full((5, *shape), value)
        for pfa in (REGISTRATION_PFA, None):
            got = estimate_shifts(frames, pfa=pfa)
            assert got.tolist() == [[0.0, 0.0]] * 5
        assert not shift_significance(frames).isnan().any()
        result = register(frames)
        assert not result.frames.isnan().any() and result.offsets.abs().max() == 0

    @pytest.mark.parametrize("seed", [0, 1])
    def test_textured_pan_recovered(self, seed):
        """A textured scene panning by known sub-pixel steps (crops, noise): all accepted."""
        g = torch.Generator().manual_seed(seed)
        img = power_law_texture(128, 128, seed)
        true = torch.rand(8, 2, generator=g, dtype=torch.float64) * 8 - 4
        pos = true.cumsum(dim=0)
        cube = torch.stack([img] + [fourier_shift(img, float(x), float(y)) for x, y in pos])
        cube = cube[:, 32:96, 32:96] + 0.05 * torch.randn(9, 64, 64, generator=g)
        got = estimate_shifts(cube)
        assert (got[1:] - true).abs().max() < 0.1
        torch.testing.assert_close(got, estimate_shifts(cube, pfa=None))
        assert shift_significance(cube)[1:].min() > 20  # far above the threshold (6.2)

    def test_noise_frame_in_a_pan_keeps_zero(self):
        """A frame pair without common structure keeps a zero shift; the others are kept."""
        img = power_law_texture(96, 96, 3)
        cube = torch.stack([img.roll(n, dims=1) for n in range(5)])
        cube[3] = torch.randn(96, 96, generator=torch.Generator().manual_seed(0))
        got = estimate_shifts(cube, taper=False)
        assert got[:, 1].abs().max() < 1e-6
        assert got[:, 0].tolist() == pytest.approx([0.0, 1.0, 1.0, 0.0, 0.0], abs=1e-4)

    @pytest.mark.parametrize("taper", [True, False])
    @pytest.mark.parametrize("shape", [(12, 12), (20, 9), (5, 7), (1, 10)])
    def test_significance_reference(self, taper, shape):
        g = torch.Generator().manual_seed(4)
        frames = torch.rand(3, *shape, generator=g, dtype=torch.float64)
        frames[2] = frames[1].roll(1, dims=-1) + 0.3 * frames[2]
        got = shift_significance(frames, taper=taper)
        assert got[0] == 0
        for n in (1, 2):
            want = expected_significance(frames[n - 1], frames[n], taper=taper)
            assert float(got[n]) == pytest.approx(want, rel=1e-6, abs=1e-9)

    def test_threshold_rule(self):
        """A shift is kept iff the ratio exceeds sqrt(1 + 1/n) t_{n-1}^-1(1 - pfa / (H W)).

        32 x 32 without taper: n = 13 x 13 - 5 x 5 = 144 training cells.
        """
        g = torch.Generator().manual_seed(5)
        img = torch.randn(32, 32, generator=g)
        frames = torch.stack(
            [img]
            + [
                img.roll(2, dims=0) + s * torch.randn(32, 32, generator=g)
                for s in (0.5, 1.5, 3.0, 6.0)
            ]
        )
        ratio = shift_significance(frames, taper=False)
        free = estimate_shifts(frames, taper=False, pfa=None)
        for pfa in (1e-2, 1e-6, 1e-12):
            tau = math.sqrt(1 + 1 / 144) * student.isf(pfa / (32 * 32), 143)
            assert registration_threshold(32, 32, pfa=pfa, taper=False) == pytest.approx(tau)
            got = estimate_shifts(frames, taper=False, pfa=pfa)
            keep = (ratio > tau).unsqueeze(-1)
            torch.testing.assert_close(got, torch.where(keep, free, torch.zeros_like(free)))
        assert (ratio[1:] > 6.0).any() and (ratio[1:] < 6.0).any()  # both sides are exercised

    def test_threshold_hann_effective_cells(self):
        """With the taper the training cells count by the Hann window's (18/35)^2."""
        n = 144 * (18 / 35) ** 2
        want = math.sqrt(1 + 1 / n) * student.isf(1e-6 / (48 * 48), n - 1)
        assert registration_threshold(48, 48) == pytest.approx(want)
        # tends to the Gaussian bound of many independent cells; none fits in 1 x 1
        assert registration_threshold(48, 48) > NormalDist().inv_cdf(1 - 1e-6 / (48 * 48))
        assert registration_threshold(1, 1) == math.inf
        with pytest.raises(ValueError, match="`height`"):
            registration_threshold(0, 4)
        with pytest.raises(ValueError, match="`pfa`"):
            registration_threshold(4, 4, pfa=1.5)

    @pytest.mark.parametrize("size", [8, 12, 16])
    def test_small_noise_frames_no_shift(self, size):
        """i.i.d. Gaussian noise frames have no structure: every shift is (0, 0).

        The first version of the test (Gaussian bound Phi^-1(1 - pfa / (H W))) invented
        shifts on small frames: measured 13 % (8 x 8), 4.7 % (12 x 12), 0.6-1 % (16 x 16)
        of the pairs.
        """
        g = torch.Generator().manual_seed(21)
        frames = torch.randn(300, size, size, generator=g, dtype=torch.float64)
        assert estimate_shifts(frames).abs().max() == 0
        shifts, rejected = estimate_shifts(frames, return_rejected=True)
        assert shifts.abs().max() == 0 and rejected.shape == (300,)
        assert rejected[1:].all() and not rejected[0]  # every pair said to be unregistered
        ratio = shift_significance(frames)[1:]
        gauss = NormalDist().inv_cdf(1 - REGISTRATION_PFA / size**2)
        assert (ratio > gauss).any()  # the old bound would have kept a shift (can fail)

    @pytest.mark.parametrize("size", [24, 32, 64])
    def test_textured_shift_3_minus_2(self, size):
        """Real content shifted by (dx, dy) = (3, -2) still registers (crops of a texture)."""
        img = power_law_texture(size + 16, size + 16, 7)
        a = img[8 : 8 + size, 8 : 8 + size]
        b = img[10 : 10 + size, 5 : 5 + size]  # content at (x, y) moves to (x + 3, y - 2)
        got, rejected = estimate_shifts(torch.stack([a, b]), return_rejected=True)
        assert got[1].tolist() == pytest.approx([3.0, -2.0], abs=0.2)
        assert rejected.tolist() == [False, False]
        assert shift_significance(torch.stack([a, b]))[1] > registration_threshold(size, size)

    def test_rejected_matches_the_threshold(self):
        """``return_rejected``: the pairs whose ratio is at most the threshold, batched."""
        g = torch.Generator().manual_seed(6)
        img = power_law_texture(40, 40, 2)
        frames = torch.stack([img.roll(n, dims=1) for n in range(4)])
        frames[2] = torch.randn(40, 40, generator=g, dtype=torch.float64)
        cube = torch.stack([frames, torch.randn(4, 40, 40, generator=g, dtype=torch.float64)])
        shifts, rejected = estimate_shifts(cube, return_rejected=True)
        torch.testing.assert_close(shifts, estimate_shifts(cube))
        want = ~(shift_significance(cube) > registration_threshold(40, 40))
        want[:, 0] = False
        assert rejected.tolist() == want.tolist()
        assert rejected.tolist() == [[False, False, True, True], [False, True, True, True]]
        assert estimate_shifts(torch.zeros(0, 3, 8, 8), return_rejected=True)[1].shape == (0, 3)

    def test_batched_and_empty(self):
        frames = torch.randn(2, 4, 16, 16)
        frames[1, 2] = frames[1, 1].roll(1, dims=0)
        got = shift_significance(frames)
        assert got.shape == (2, 4)
        torch.testing.assert_close(got[1], shift_significance(frames[1]))
        assert shift_significance(torch.zeros(0, 3, 8, 8)).shape == (0, 3)
        assert shift_significance(torch.zeros(1, 8, 8)).tolist() == [0.0]

    @pytest.mark.parametrize("pfa", [0.0, 1.0, -0.1, math.nan])
    def test_pfa_errors(self, pfa):
        with pytest.raises(ValueError, match="`pfa`"):
            estimate_shifts(torch.zeros(2, 8, 8), pfa=pfa)
        with pytest.raises(ValueError, match="`pfa`"):
            Registration(pfa=pfa)

    def test_pfa_type_error(self):
        with pytest.raises(TypeError, match="`pfa`"):
            estimate_shifts(torch.zeros(2, 8, 8), pfa="small")


class TestRegister:
    def test_aligns_onto_first_frame(self):
        img = torch.rand(32, 32, generator=torch.Generator().manual_seed(0))
        frames = torch.stack([img.roll((0, n), dims=(0, 1)) for n in range(4)])
        result = register(frames, taper=False)
        assert result.offsets[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0]
        torch.testing.assert_close(result.frames[3, :, :29], img[:, :29])

    def test_module(self):
        frames = torch.rand(2, 3, 16, 16)
        out = Registration(mode="fourier")(frames)
        want = register(frames, mode="fourier")
        torch.testing.assert_close(out.frames, want.frames)
        torch.testing.assert_close(out.shifts, want.shifts)
        free = Registration(pfa=None)(frames)
        torch.testing.assert_close(free.shifts, register(frames, pfa=None).shifts)
        assert "pfa=None" in repr(Registration(pfa=None))

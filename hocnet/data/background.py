"""Temporal background removal and frame registration for real sensors (our addition).

[NR08] whitens every frame on its own and names temporal background removal as future work. Real
clutter (trees, roads, buildings) is bright, sharp and stands still on the ground, so a spatial
ring filter leaves many residuals as strong as a dim target. When the camera follows the target,
the ground slides through the image while the target stays nearly in place; registering the past
frames onto the current one and subtracting a per-pixel background from them removes the ground
and keeps what moves relative to it.

Two parts, each a functional core plus a thin ``nn.Module``:

* **Registration.** :func:`estimate_shifts` finds the global shift between consecutive frames by
  phase correlation (``torch.fft``) with an upsampled-DFT sub-pixel refinement of the correlation
  peak, accepted only when the peak stands out of the correlation surface's noise (a CFAR
  test, :func:`shift_significance`; our addition), else the frame keeps a zero shift;
  :func:`shift_frames` moves frames by sub-pixel shifts (bilinear or Fourier);
  :func:`register` aligns every frame onto the first one and reports the shifts.
* **Background.** :func:`temporal_background` estimates, for every frame ``n``, a per-pixel
  background from the previous ``window`` frames ``n - window .. n - 1`` only (causal), each
  moved onto frame ``n`` first when ``offsets`` (from :func:`register`) are given;
  :func:`remove_background` subtracts it. Methods: running ``"mean"``, running ``"median"`` and a
  robust ``"lowrank"`` background (see :func:`temporal_background`).

Conventions:

* Frames are ``(B, T, H, W)`` or ``(T, H, W)``; outputs keep the input's batching. Floating input
  keeps its dtype, integer or boolean input is converted to float32. NaN/inf input is an error.
* A shift ``(dx, dy)`` in pixels moves image content from ``(x, y)`` to ``(x + dx, y + dy)``
  (``x`` = column, ``y`` = row). ``shifts[n]`` is the shift of frame ``n`` relative to frame
  ``n - 1`` (``shifts[0] = 0``); ``offsets[n] = shifts[1] + ... + shifts[n]`` places frame ``n``
  relative to frame 0.
* Pixels without any valid background sample (frame 0, or pixels whose past samples all fall
  outside the earlier frames after registration) get the frame itself as background, so their
  residual is 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from hocnet._check import as_cube, check_choice, check_int, check_number, restore_batch

__all__ = [
    "BACKGROUND_METHODS",
    "REGISTRATION_PFA",
    "BackgroundRemoval",
    "Registered",
    "Registration",
    "estimate_shifts",
    "register",
    "registration_threshold",
    "remove_background",
    "shift_frames",
    "shift_significance",
    "temporal_background",
]

BACKGROUND_METHODS = ("mean", "median", "lowrank")
"""The background estimators of :func:`temporal_background`."""

_INTERPOLATIONS = ("bilinear", "fourier")

REGISTRATION_PFA = 1e-6
"""Default false-alarm probability per frame pair of the registration's peak test (our addition).

A shift is accepted when the peak-to-sidelobe ratio of :func:`shift_significance` exceeds
:func:`registration_threshold` (:func:`estimate_shifts`)."""

_GUARD = 2
"""Half-size of the square around the correlation peak left out of the sidelobe statistics."""

_TRAIN = 6
"""Half-size of the square around the peak whose other cells are the sidelobe (training) cells."""


def _float_cube(name: str, frames: Any) -> tuple[torch.Tensor, bool]:
    cube, batched = as_cube(name, frames)
    if not cube.is_floating_point():
        cube = cube.to(torch.float32)
    return cube, batched


def _check_shifts(name: str, shifts: Any, cube: torch.Tensor, batched: bool) -> torch.Tensor:
    """Validate ``(T, 2)`` / ``(B, T, 2)`` shifts for a ``(B, T, H, W)`` cube -> ``(B, T, 2)``."""
    b, t = cube.shape[:2]
    if not isinstance(shifts, torch.Tensor):
        try:
            shifts = torch.as_tensor(shifts)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(
                f"`{name}`: expected a tensor of shape (T, 2) or (B, T, 2), "
                f"got {type(shifts).__name__}"
            ) from None
    if shifts.is_complex() or shifts.dtype == torch.bool:
        raise TypeError(f"`{name}`: expected a real tensor, got dtype {shifts.dtype}")
    want = (b, t, 2) if batched else (t, 2)
    if tuple(shifts.shape) != want:
        raise ValueError(f"`{name}`: expected shape {want}, got {tuple(shifts.shape)}")
    shifts = shifts.to(device=cube.device, dtype=cube.dtype)
    if not bool(torch.isfinite(shifts).all()):
        raise ValueError(f"`{name}`: expected finite values, got NaN/inf entries")
    return shifts if batched else shifts.unsqueeze(0)


# ----------------------------------------------------------------------------- registration


def _hann(n: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    if n == 1:
        return torch.ones(1, device=device, dtype=dtype)
    return torch.hann_window(n, periodic=False, device=device, dtype=dtype)


def _refine(line: torch.Tensor, freq: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
    """Sub-pixel maximum of ``r(u) = Re sum_k line[k] exp(2 pi i freq[k] u)`` near ``start``.

    ``line`` ``(N, K)`` is the cross-power spectrum collapsed onto one axis at the integer peak
    of the other; ``r`` is evaluated on a grid of step 0.1 px over ``start +- 1``, then of step
    0.01 px around the best point (the upsampled DFT of M. Guizar-Sicairos, S. T. Thurman,
    J. R. Fienup, "Efficient subpixel image registration algorithms", Opt. Lett. 33(2), 2008,
    one axis at a time).
    """
    best = start
    for half, step in ((1.0, 0.1), (0.1, 0.01)):
        n = round(half / step)
        grid = torch.arange(-n, n + 1, device=line.device, dtype=freq.dtype) * step
        u = best.unsqueeze(-1) + grid  # (N, P)
        phase = 2 * math.pi * u.unsqueeze(-1) * freq  # (N, P, K)
        basis = torch.polar(torch.ones_like(phase), phase)
        values = (basis @ line.unsqueeze(-1)).squeeze(-1).real  # (N, P)
        best = u.gather(-1, values.argmax(dim=-1, keepdim=True)).squeeze(-1)
    return best


def _phase_correlation(cube: torch.Tensor, taper: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised cross-power spectra and correlation surfaces of consecutive frames.

    ``cube`` ``(B, T, H, W)`` with ``T >= 2`` -> ``cross`` (complex) and ``r`` (real), both
    ``(N, H, W)`` with ``N = B (T - 1)``; pair ``n`` is frame ``n + 1`` against frame ``n``.
    """
    h, w = cube.shape[-2:]
    x = cube - cube.mean(dim=(-2, -1), keepdim=True)
    if taper:
        x = x * (_hann(h, x.device, x.dtype)[:, None] * _hann(w, x.device, x.dtype)[None, :])
    spec = torch.fft.fft2(x)
    cross = spec[:, 1:] * spec[:, :-1].conj()
    mag = cross.abs()
    cross = (cross / torch.where(mag > 0, mag, torch.ones_like(mag))).reshape(-1, h, w)
    return cross, torch.fft.ifft2(cross).real


def _peak_to_sidelobe(r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Arg-max and local peak-to-sidelobe ratio of correlation surfaces ``r`` ``(N, H, W)``.

    Training cells: the cells of the ``(2 ry + 1) x (2 rx + 1)`` square centred on the peak
    (circularly), ``ry = min(_TRAIN, (H - 1) // 2)`` (``rx`` likewise), outside the centred
    ``(2 g + 1)`` square, ``g = min(_GUARD, max(ry, rx) - 1)``. Ratio
    ``(peak - mean) / std`` (unbiased std) of the training cells; ``inf`` when their std is 0
    and the peak is above their mean, 0 when it is not or when there is no training cell.
    """
    n, h, w = r.shape
    flat = r.reshape(n, h * w)
    peak, idx = flat.max(dim=-1)
    iy, ix = idx // w, idx % w
    ry, rx = min(_TRAIN, (h - 1) // 2), min(_TRAIN, (w - 1) // 2)
    guard = min(_GUARD, max(ry, rx) - 1)
    oy = torch.arange(-ry, ry + 1, device=r.device)
    ox = torch.arange(-rx, rx + 1, device=r.device)
    train = (oy.abs()[:, None] > guard) | (ox.abs()[None, :] > guard)
    if n == 0 or guard < 0 or not bool(train.any()):
        return idx, torch.zeros_like(peak)
    rows = ((iy[:, None] + oy) % h)[:, :, None]  # (N, 2 ry + 1, 1)
    cols = ((ix[:, None] + ox) % w)[:, None, :]  # (N, 1, 2 rx + 1)
    cells = r[torch.arange(n, device=r.device)[:, None, None], rows, cols][:, train]
    mean = cells.mean(dim=-1)
    std = cells.std(dim=-1) if cells.shape[-1] > 1 else torch.zeros_like(mean)
    excess = peak - mean
    ratio = excess / torch.where(std > 0, std, torch.ones_like(std))
    ratio = torch.where(std > 0, ratio, torch.where(excess > 0, math.inf, 0.0))
    return idx, ratio


def shift_significance(frames: torch.Tensor, *, taper: bool = True) -> torch.Tensor:
    """Peak-to-sidelobe ratio of the phase correlation of every frame with the previous one.

    Our addition (a CFAR test on the correlation surface). The surface ``r`` of
    :func:`estimate_shifts` peaks at the shift; on frames without structure (white noise, a
    flat sky) its maximum is just the largest of ``H W`` noise values. The ratio is
    ``(max r - m) / s``, with ``m`` and ``s`` the mean and standard deviation of the training
    cells: the cells within 6 px of the peak (per axis, circularly; fewer on frames smaller
    than 13 px) outside the 5 x 5 square centred on it (smaller on frames below 7 px). A local
    ring, because with the Hann taper the surface's noise is not stationary: measured on white
    noise, its standard deviation at small shifts is about 3 times that at half the frame.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` intensities.
        taper: Hann taper before the FFT, as in :func:`estimate_shifts`.

    Returns:
        ``(B, T)`` or ``(T,)`` ratios in the frames' float dtype; ``[..., 0] = 0`` (no previous
        frame). ``inf`` when the training cells are all equal and the peak is above them (an
        exact circular shift); 0 for flat frames.

    Raises:
        TypeError: non-numeric frames.
        ValueError: wrong rank, NaN/inf.

    Examples:
        >>> g = torch.Generator().manual_seed(0)
        >>> noise = torch.randn(2, 48, 48, generator=g)
        >>> bool(shift_significance(noise)[1] < 10)
        True
        >>> scene = torch.stack([noise[0], noise[0].roll(3, dims=1)])
        >>> bool(shift_significance(scene)[1] > 100)
        True
    """
    cube, batched = _float_cube("frames", frames)
    b, t = cube.shape[:2]
    out = torch.zeros(b, t, device=cube.device, dtype=cube.dtype)
    if t >= 2 and b > 0:
        _, r = _phase_correlation(cube, bool(taper))
        out[:, 1:] = _peak_to_sidelobe(r)[1].reshape(b, t - 1)
    return out if batched else out.squeeze(0)


#: Fraction of the training cells that count as independent under the Hann taper: the
#: effective sample fraction ``(sum w^2)^2 / (n sum w^4) = 18 / 35`` of a Hann window, per axis.
HANN_EFFECTIVE_FRACTION = (18 / 35) ** 2


def _training_cells(h: int, w: int) -> int:
    """Number of training cells of :func:`_peak_to_sidelobe` for ``H x W`` surfaces."""
    ry, rx = min(_TRAIN, (h - 1) // 2), min(_TRAIN, (w - 1) // 2)
    guard = min(_GUARD, max(ry, rx) - 1)
    if guard < 0:
        return 0
    return (2 * ry + 1) * (2 * rx + 1) - (2 * min(guard, ry) + 1) * (2 * min(guard, rx) + 1)


def registration_threshold(
    height: int, width: int, *, pfa: float = REGISTRATION_PFA, taper: bool = True
) -> float:
    """Threshold of the peak test of :func:`estimate_shifts` on ``H x W`` frames (our addition).

    The peak-to-sidelobe ratio of :func:`shift_significance` divides by the mean and standard
    deviation of ``n`` training cells. For a Gaussian cell ``X`` and ``n`` independent Gaussian
    training cells, ``(X - mean) / std`` is ``sqrt(1 + 1/n)`` times a Student ``t`` with
    ``n - 1`` degrees of freedom (the prediction-interval bound), so the threshold is
    ``tau = sqrt(1 + 1/n) t_{n-1}^-1(1 - pfa / (H W))``: the largest of the ``H W`` cells
    exceeds it with probability at most about ``pfa``. With the Hann taper the training cells
    are not independent: ``n`` is the number of cells times :data:`HANN_EFFECTIVE_FRACTION`
    (0.26). For large ``n`` ``tau`` tends to the Gaussian bound ``Phi^-1(1 - pfa / (H W))``.

    Measured (white Gaussian noise frames, Hann taper, ``pfa = 1e-6``; pairs with a non-zero
    shift): 0 of 4000 for 8 x 8, 3 of 4000 for 12 x 12, 1 of 4000 for 16 x 16, 0 of 2000 for
    16 x 64, 20 x 20 and 32 x 32, against 13 %, 4.7 %, 0.6-1 % and 0.2 % with the Gaussian
    bound of the first version of the test. Textured frames still pass: ratios of at least 17
    for crops of a smooth texture shifted by (3, -2) on 32 x 32 frames (threshold 8.0), and of
    at least 47 on the real infrared clips of ``experiments/real_ir.py`` (256 x 256, threshold
    9.4: no pair rejected). The cost: weakly structured frames are rejected sooner. 48 x 48
    crops of a very smooth texture (white noise blurred by a Gaussian of 1.5 px, plus noise of
    1/15 of its standard deviation) moving by (3, -2) have ratios of 7.6-10.5 and shifts off by
    up to 0.6 px; 3 of 5 pairs fall below the threshold 8.26 (the Gaussian bound, 6.1, kept all).

    Args:
        height: frame height ``H`` in pixels, >= 1.
        width: frame width ``W`` in pixels, >= 1.
        pfa: false-alarm probability per frame pair, in ``(0, 1)``.
        taper: whether the surface comes from Hann-tapered frames (as in :func:`estimate_shifts`).

    Returns:
        The threshold ``tau``; ``inf`` when the frames are too small for two independent
        training cells (no shift can be significant).

    Raises:
        TypeError: non-integer sizes or non-numeric ``pfa``.
        ValueError: sizes < 1, ``pfa`` outside ``(0, 1)``.

    Examples:
        >>> round(registration_threshold(48, 48), 2), round(registration_threshold(256, 256), 2)
        (8.26, 9.43)
        >>> round(registration_threshold(48, 48, taper=False), 2)
        6.59
    """
    from scipy.special import stdtrit  # Student t quantile (scipy.special: light import)

    height = check_int("height", height, minimum=1)
    width = check_int("width", width, minimum=1)
    pfa = check_number("pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False)
    cells = _training_cells(height, width) * (HANN_EFFECTIVE_FRACTION if taper else 1.0)
    if cells < 2:
        return math.inf
    quantile = -float(stdtrit(cells - 1, pfa / (height * width)))  # upper tail, by symmetry
    return math.sqrt(1.0 + 1.0 / cells) * quantile


def estimate_shifts(
    frames: torch.Tensor,
    *,
    taper: bool = True,
    pfa: float | None = REGISTRATION_PFA,
    return_rejected: bool = False,
) -> Any:
    """Global shift of every frame relative to the previous one, by phase correlation.

    For frames ``a = frame[n - 1]`` and ``b = frame[n]`` (each minus its mean, times a 2-D Hann
    taper unless ``taper=False``), the normalised cross-power spectrum
    ``R = B conj(A) / |B conj(A)|`` has an inverse FFT ``r`` that peaks at the shift ``(dx, dy)``
    moving ``a``'s content onto ``b`` (integer part: the arg-max, read as a signed offset in
    ``-N/2 .. N/2 - 1``). The sub-pixel part: ``r`` is interpolated by its DFT (upsampled DFT,
    one axis at a time, at the integer peak of the other axis) and maximised on a 0.1 px and
    then a 0.01 px grid within +-1 px of the integer peak. Measured accuracy (tests): < 0.05 px
    for circular shifts; < 0.2 px for crops of a smooth texture with the Hann taper.

    **Peak test (our addition).** Phase correlation whitens the spectrum, so on frames without
    structure (white noise, a clear sky with a dim target, a flat frame) ``r`` is noise and its
    arg-max lands anywhere: chained into offsets, a still camera then "drifts" by many pixels.
    A shift is therefore accepted only when the peak-to-sidelobe ratio of
    :func:`shift_significance` exceeds ``tau`` of :func:`registration_threshold` (a Student-t
    bound on the largest of ``H W`` cells, with the training cells counted as independent only
    by the Hann window's effective sample fraction): no structure, no shift. A rejected frame
    keeps a zero shift (the camera is taken as still). Very smooth frames are rejected too
    although they have structure: a texture blurred by a Gaussian of 3 px gives a
    peak-to-sidelobe ratio of about 5 against a threshold of 8.45 on 64 x 64 frames (measured by
    a new user), so such a sequence is left unregistered; :func:`shift_significance` and
    :func:`registration_threshold` tell which frames were rejected (``hocnet detect`` reports
    them). ``tau`` is 8.3 for 48 x 48 frames and 9.4 for 256 x 256 at the default
    ``pfa = 1e-6``. Measured (white Gaussian noise frames, Hann taper): non-zero shifts in 0 of
    4000 pairs of 8 x 8, 3 of 4000 of 12 x 12, 1 of 4000 of 16 x 16 and 0 of 2000 of 32 x 32
    (the first version of the test, with the Gaussian bound ``Phi^-1(1 - pfa / (H W))``: 13 %,
    4.7 %, 0.6-1 %, 0); on the six real infrared clips of ``experiments/real_ir.py`` (256 x 256,
    ground clutter) every pair has a ratio of at least 47, so none is rejected.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` intensities.
        taper: multiply by a 2-D Hann window before the FFT (reduces the wrap-around edge).
        pfa: false-alarm probability per frame pair of the peak test, in ``(0, 1)``; ``None``
            accepts every peak that rises above its sidelobes (ratio > 0; the behaviour before
            the test, except that flat frames, whose surface is all zero, keep a zero shift).
        return_rejected: also return which frames failed the peak test.

    Returns:
        ``(B, T, 2)`` or ``(T, 2)`` shifts ``(dx, dy)`` in pixels in the frames' float dtype;
        ``shifts[..., 0, :] = 0``, and ``0`` for every frame whose peak fails the test.
        Phase correlation measures shifts modulo the frame size, so shifts must be smaller than
        half the frame. With ``return_rejected``: ``(shifts, rejected)``, ``rejected`` a bool
        ``(B, T)`` or ``(T,)`` tensor, true for the frames kept at 0 by the test (no structure
        to register; ``rejected[..., 0]`` is false: frame 0 has no pair).

    Raises:
        TypeError: non-numeric frames or ``pfa``.
        ValueError: wrong rank, NaN/inf, ``pfa`` outside ``(0, 1)``.

    Examples:
        >>> frames = torch.rand(2, 32, 32)
        >>> frames[1] = frames[0].roll(shifts=(2, -3), dims=(0, 1))  # dy = 2, dx = -3
        >>> estimate_shifts(frames, taper=False)[1].tolist()
        [-3.0, 2.0]
        >>> still = torch.randn(3, 32, 32, generator=torch.Generator().manual_seed(0))
        >>> estimate_shifts(still).abs().max().item()  # white noise: no significant peak
        0.0
        >>> estimate_shifts(still, return_rejected=True)[1].tolist()
        [False, True, True]
    """
    cube, batched = _float_cube("frames", frames)
    if pfa is not None:
        pfa = check_number("pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False)
    b, t, h, w = cube.shape
    shifts = torch.zeros(b, t, 2, device=cube.device, dtype=cube.dtype)
    rejected = torch.zeros(b, t, device=cube.device, dtype=torch.bool)

    def result() -> Any:
        out = restore_batch(shifts, batched)
        return (out, restore_batch(rejected, batched)) if return_rejected else out

    if t < 2 or b == 0:
        return result()
    cross, r = _phase_correlation(cube, bool(taper))
    idx, ratio = _peak_to_sidelobe(r)
    iy, ix = idx // w, idx % w
    dy0 = torch.where(iy >= (h + 1) // 2, iy - h, iy).to(cube.dtype)
    dx0 = torch.where(ix >= (w + 1) // 2, ix - w, ix).to(cube.dtype)
    fy = torch.fft.fftfreq(h, device=cube.device, dtype=cube.dtype)
    fx = torch.fft.fftfreq(w, device=cube.device, dtype=cube.dtype)
    # collapse the spectrum onto each axis at the integer peak of the other, then refine
    at_y = torch.polar(torch.ones_like(fy), 2 * math.pi * fy * dy0.unsqueeze(-1))  # (N, H)
    at_x = torch.polar(torch.ones_like(fx), 2 * math.pi * fx * dx0.unsqueeze(-1))  # (N, W)
    line_x = (at_y.unsqueeze(1) @ cross).squeeze(1)  # (N, W)
    line_y = (cross @ at_x.unsqueeze(-1)).squeeze(-1)  # (N, H)
    dx = _refine(line_x, fx, dx0) if w >= 2 else dx0
    dy = _refine(line_y, fy, dy0) if h >= 2 else dy0
    keep = ratio > (0.0 if pfa is None else registration_threshold(h, w, pfa=pfa, taper=taper))
    dx, dy = dx.where(keep, torch.zeros_like(dx)), dy.where(keep, torch.zeros_like(dy))
    shifts[:, 1:, 0] = dx.reshape(b, t - 1)
    shifts[:, 1:, 1] = dy.reshape(b, t - 1)
    rejected[:, 1:] = ~keep.reshape(b, t - 1)
    return result()


def _bilinear(images: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """``images`` ``(N, H, W)`` moved by ``shift`` ``(N, 2)`` (dx, dy); NaN outside the source."""
    n, h, w = images.shape
    if n == 0:
        return images.clone()
    ys = torch.arange(h, device=images.device, dtype=images.dtype)
    xs = torch.arange(w, device=images.device, dtype=images.dtype)
    src_x = xs.view(1, 1, w) - shift[:, 0].view(n, 1, 1)  # (N, 1, W)
    src_y = ys.view(1, h, 1) - shift[:, 1].view(n, 1, 1)  # (N, H, 1)
    gx = (2 * src_x / max(w - 1, 1) - 1).expand(n, h, w)
    gy = (2 * src_y / max(h - 1, 1) - 1).expand(n, h, w)
    grid = torch.stack([gx, gy], dim=-1)
    out = F.grid_sample(
        images.unsqueeze(1), grid, mode="bilinear", padding_mode="border", align_corners=True
    ).squeeze(1)
    eps = 1e-4
    valid = (src_x >= -eps) & (src_x <= w - 1 + eps) & (src_y >= -eps) & (src_y <= h - 1 + eps)
    return out.masked_fill(~valid, math.nan)


def _fourier(images: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Fourier (band-limited, circular) shift; NaN where the source lies outside the frame."""
    n, h, w = images.shape
    if n == 0:
        return images.clone()
    ky = torch.fft.fftfreq(h, device=images.device, dtype=images.dtype).view(1, h, 1)
    kx = torch.fft.rfftfreq(w, device=images.device, dtype=images.dtype).view(1, 1, -1)
    phase = -2 * math.pi * (kx * shift[:, 0].view(n, 1, 1) + ky * shift[:, 1].view(n, 1, 1))
    out = torch.fft.irfft2(
        torch.fft.rfft2(images) * torch.polar(torch.ones_like(phase), phase), s=(h, w)
    )
    ys = torch.arange(h, device=images.device, dtype=images.dtype)
    xs = torch.arange(w, device=images.device, dtype=images.dtype)
    src_x = xs.view(1, 1, w) - shift[:, 0].view(n, 1, 1)
    src_y = ys.view(1, h, 1) - shift[:, 1].view(n, 1, 1)
    eps = 1e-4
    valid = (src_x >= -eps) & (src_x <= w - 1 + eps) & (src_y >= -eps) & (src_y <= h - 1 + eps)
    return out.masked_fill(~valid, math.nan)


def _move(images: torch.Tensor, shift: torch.Tensor, mode: str) -> torch.Tensor:
    return _bilinear(images, shift) if mode == "bilinear" else _fourier(images, shift)


def shift_frames(
    frames: torch.Tensor,
    shifts: torch.Tensor,
    *,
    mode: str = "bilinear",
    fill: float = 0.0,
) -> torch.Tensor:
    """Move every frame by its own sub-pixel shift: ``out(x, y) = frame(x - dx, y - dy)``.

    ``"bilinear"`` interpolates between the four nearest pixels (exact for integer shifts, a
    slight blur otherwise); ``"fourier"`` multiplies the spectrum by a phase ramp (band-limited,
    no blur, but circular). Either way, output pixels whose source ``(x - dx, y - dy)`` lies
    outside the frame get ``fill`` (``math.nan`` marks them).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)``.
        shifts: ``(B, T, 2)`` or ``(T, 2)`` shifts ``(dx, dy)`` in pixels, one per frame.
        mode: ``"bilinear"`` or ``"fourier"``.
        fill: value of the pixels shifted in from outside the frame (may be NaN).

    Returns:
        Shifted frames, same shape as ``frames`` (float).

    Raises:
        TypeError: non-numeric input.
        ValueError: wrong shapes, NaN/inf, unknown ``mode``.

    Examples:
        >>> frames = torch.arange(9.0).reshape(1, 3, 3)
        >>> shift_frames(frames, torch.tensor([[1.0, 0.0]]))[0]
        tensor([[0., 0., 1.],
                [0., 3., 4.],
                [0., 6., 7.]])
    """
    cube, batched = _float_cube("frames", frames)
    shifts = _check_shifts("shifts", shifts, cube, batched)
    mode = check_choice("mode", mode, _INTERPOLATIONS)
    if not isinstance(fill, float) or not math.isnan(fill):
        fill = check_number("fill", fill)
    b, t, h, w = cube.shape
    out = _move(cube.reshape(b * t, h, w), shifts.reshape(b * t, 2), mode)
    out = out.nan_to_num(nan=fill) if not math.isnan(fill) else out
    return restore_batch(out.reshape(b, t, h, w), batched)


@dataclass
class Registered:
    """Result of :func:`register`.

    Attributes:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` frames moved onto frame 0 (``fill`` outside).
        shifts: ``(B, T, 2)`` or ``(T, 2)`` shift ``(dx, dy)`` of each frame relative to the
            previous one, in pixels (``shifts[..., 0, :] = 0``).
        offsets: cumulative shifts: the position of each frame relative to frame 0.
    """

    frames: torch.Tensor
    shifts: torch.Tensor
    offsets: torch.Tensor


def register(
    frames: torch.Tensor,
    *,
    mode: str = "bilinear",
    fill: float = 0.0,
    taper: bool = True,
    pfa: float | None = REGISTRATION_PFA,
) -> Registered:
    """Estimate the camera motion and align every frame onto frame 0.

    Shifts from :func:`estimate_shifts`; frame ``n`` is moved by ``-offsets[n]`` with
    :func:`shift_frames`. For causal background removal in the frames' own coordinates (the
    pipeline of ``experiments/real_ir.py``) pass ``offsets`` to :func:`remove_background`
    instead of using the aligned frames: a panning camera moves the scene out of frame 0.

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` intensities.
        mode: ``"bilinear"`` or ``"fourier"`` (see :func:`shift_frames`).
        fill: value of pixels without a source in the frame.
        taper: Hann taper in :func:`estimate_shifts`.
        pfa: false-alarm probability of the peak test of :func:`estimate_shifts` (``None``:
            no test).

    Returns:
        :class:`Registered` with aligned ``frames``, ``shifts`` and ``offsets``.

    Examples:
        >>> frames = torch.rand(3, 32, 32)
        >>> frames[1] = frames[0].roll(1, dims=1)
        >>> frames[2] = frames[0].roll(2, dims=1)
        >>> register(frames, taper=False).offsets[:, 0].tolist()
        [0.0, 1.0, 2.0]
    """
    shifts = estimate_shifts(frames, taper=taper, pfa=pfa)
    offsets = shifts.cumsum(dim=-2)
    aligned = shift_frames(frames, -offsets, mode=mode, fill=fill)
    return Registered(aligned, shifts, offsets)


class Registration(nn.Module):
    """Registration as a module; ``forward`` returns a :class:`Registered` (see :func:`register`).

    Args:
        mode: ``"bilinear"`` or ``"fourier"``.
        fill: value of pixels without a source in the frame.
        taper: Hann taper before the phase correlation.
        pfa: false-alarm probability of the peak test (``None``: no test).

    Shape:
        - Input: ``(B, T, H, W)`` or ``(T, H, W)``.
        - Output: frames like the input, shifts and offsets ``(B, T, 2)`` or ``(T, 2)``.

    Examples:
        >>> Registration()(torch.rand(2, 3, 16, 16)).shifts.shape
        torch.Size([2, 3, 2])
    """

    def __init__(
        self,
        mode: str = "bilinear",
        fill: float = 0.0,
        taper: bool = True,
        pfa: float | None = REGISTRATION_PFA,
    ) -> None:
        super().__init__()
        self.mode = check_choice("mode", mode, _INTERPOLATIONS)
        self.fill = fill
        self.taper = bool(taper)
        if pfa is not None:
            pfa = check_number(
                "pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
            )
        self.pfa = pfa

    def forward(self, frames: torch.Tensor) -> Registered:
        """Register ``frames`` (see :func:`register`)."""
        return register(frames, mode=self.mode, fill=self.fill, taper=self.taper, pfa=self.pfa)

    def extra_repr(self) -> str:
        """Settings, shown in the module's repr."""
        return f"mode={self.mode!r}, fill={self.fill}, taper={self.taper}, pfa={self.pfa}"


# ----------------------------------------------------------------------------- background


def _lowrank(past: torch.Tensor, rank: int, iterations: int, clip: float) -> torch.Tensor:
    """Robust rank-``r`` reconstruction of the last row of ``past`` ``(N, L, P)`` (no NaN)."""
    x = past.to(torch.float64) if past.dtype != torch.float64 else past
    work = x
    approx = x
    for _ in range(iterations + 1):
        gram = work @ work.transpose(1, 2)  # (N, L, L)
        _, vecs = torch.linalg.eigh(gram)
        u = vecs[:, :, -rank:]  # top-r left singular vectors (N, L, r)
        approx = u @ (u.transpose(1, 2) @ work)
        resid = x - approx
        scale = (
            1.4826
            * resid.abs().median(dim=-1, keepdim=True).values.median(dim=-2, keepdim=True).values
        )
        bound = clip * scale
        work = approx + torch.maximum(torch.minimum(resid, bound), -bound)
    return approx[:, -1].to(past.dtype)


def _check_background_args(
    method: Any, window: Any, rank: Any, iterations: Any, clip: Any, interpolation: Any
) -> tuple[str, int, int, int, float, str]:
    method = check_choice("method", method, BACKGROUND_METHODS)
    window = check_int("window", window, minimum=1)
    rank = check_int("rank", rank, minimum=1)
    iterations = check_int("iterations", iterations, minimum=0)
    clip = check_number("clip", clip, low=0.0, low_inclusive=False)
    interpolation = check_choice("interpolation", interpolation, _INTERPOLATIONS)
    return method, window, rank, iterations, clip, interpolation


def temporal_background(
    frames: torch.Tensor,
    method: str = "median",
    window: int = 10,
    *,
    offsets: torch.Tensor | None = None,
    rank: int = 1,
    iterations: int = 3,
    clip: float = 3.0,
    interpolation: str = "bilinear",
) -> torch.Tensor:
    """Causal per-pixel background of every frame from the previous ``window`` frames.

    For frame ``n`` the past frames ``m = max(0, n - window) .. n - 1`` are used; with
    ``offsets`` each is first moved onto frame ``n`` by ``offsets[n] - offsets[m]``
    (:func:`shift_frames`), and samples from outside frame ``m`` are left out. Then per pixel:

    * ``"mean"``: the mean of the valid samples;
    * ``"median"``: their lower median (``torch.nanmedian``);
    * ``"lowrank"``: a robust rank-``rank`` background: the past frames as rows of an
      ``L x (H W)`` matrix ``X`` (missing samples filled with the pixel's median) are
      approximated by a truncated SVD ``A``; the residual ``X - A`` is clipped to
      ``+- clip * 1.4826 * MAD`` (MAD: the median over the frames of each frame's median
      absolute residual; lower medians, as ``torch.median``) and the SVD is redone on
      ``A + clipped residual``, ``iterations`` times. The background of frame ``n`` is the
      final approximation's row of frame ``n - 1``
      (the most recent past frame, denoised, with its outliers such as moving targets clipped).
      Our choice; it follows global brightness changes that a median over the window lags.

    Frame ``n`` itself is never used (causal), so a target that moves across the ground is not
    part of its own background; a target that stays on the same ground pixels for the whole
    window is (the price of any temporal background).

    Args:
        frames: ``(B, T, H, W)`` or ``(T, H, W)`` intensities.
        method: ``"mean"``, ``"median"`` or ``"lowrank"``.
        window: number of past frames, ``>= 1``.
        offsets: optional ``(B, T, 2)`` / ``(T, 2)`` frame positions ``(dx, dy)`` relative to
            frame 0 (``register(...).offsets``).
        rank: rank of the ``"lowrank"`` background, ``>= 1`` (use ``rank < window``).
        iterations: clipping iterations of ``"lowrank"``, ``>= 0``.
        clip: clipping bound of ``"lowrank"`` in robust standard deviations, ``> 0``.
        interpolation: ``"bilinear"`` or ``"fourier"`` shift of the past frames.

    Returns:
        Background, same shape as ``frames`` (float). Pixels without a valid past sample get
        the frame itself.

    Raises:
        TypeError: non-numeric input or wrong argument types.
        ValueError: wrong shapes, NaN/inf, out-of-range arguments.

    Examples:
        >>> frames = torch.tensor([1.0, 2.0, 4.0, 8.0]).view(4, 1, 1).expand(4, 2, 2)
        >>> temporal_background(frames, "mean", window=2)[:, 0, 0].tolist()
        [1.0, 1.0, 1.5, 3.0]
    """
    cube, batched = _float_cube("frames", frames)
    method, window, rank, iterations, clip, interpolation = _check_background_args(
        method, window, rank, iterations, clip, interpolation
    )
    offs = None if offsets is None else _check_shifts("offsets", offsets, cube, batched)
    b, t, h, w = cube.shape
    background = cube.clone()
    for n in range(1, t):
        m0 = max(0, n - window)
        past = cube[:, m0:n]  # (B, L, H, W)
        length = n - m0
        if offs is not None:
            move = offs[:, n : n + 1] - offs[:, m0:n]  # (B, L, 2)
            past = _move(past.reshape(b * length, h, w), move.reshape(b * length, 2), interpolation)
            past = past.reshape(b, length, h, w)
        if method == "mean":
            est = past.nanmean(dim=1)
        elif method == "median":
            est = past.nanmedian(dim=1).values
        else:
            flat = past.reshape(b, length, h * w)
            if offs is not None:
                fill = flat.nanmedian(dim=1, keepdim=True).values.nan_to_num(0.0)
                flat = torch.where(flat.isnan(), fill.expand_as(flat), flat)
            est = _lowrank(flat, min(rank, length), iterations, clip).reshape(b, h, w)
            if offs is not None:
                est = est.masked_fill(past.isnan().all(dim=1), math.nan)
        background[:, n] = torch.where(est.isnan(), cube[:, n], est)
    return restore_batch(background, batched)


def remove_background(
    frames: torch.Tensor,
    method: str = "median",
    window: int = 10,
    *,
    offsets: torch.Tensor | None = None,
    rank: int = 1,
    iterations: int = 3,
    clip: float = 3.0,
    interpolation: str = "bilinear",
) -> torch.Tensor:
    """Frames minus their causal temporal background (:func:`temporal_background`).

    Apply before spatial whitening (:func:`hocnet.data.whitening.anti_mean`). Arguments,
    errors and conventions as :func:`temporal_background`.

    Returns:
        Residual frames, same shape as ``frames`` (float); frame 0 is all zeros.

    Examples:
        >>> frames = torch.zeros(5, 8, 8)
        >>> frames[4, 3, 3] = 9.0  # something new in the last frame
        >>> out = remove_background(frames, "median", window=3)
        >>> float(out[4, 3, 3]), float(out[:4].abs().sum())
        (9.0, 0.0)
    """
    bg = temporal_background(
        frames,
        method,
        window,
        offsets=offsets,
        rank=rank,
        iterations=iterations,
        clip=clip,
        interpolation=interpolation,
    )
    cube = torch.as_tensor(frames)
    cube = cube.to(bg.dtype) if not cube.is_floating_point() else cube
    return cube - bg


class BackgroundRemoval(nn.Module):
    """Causal temporal background removal as a module; see :func:`remove_background`.

    Args:
        method: ``"mean"``, ``"median"`` or ``"lowrank"``.
        window: number of past frames.
        rank: rank of ``"lowrank"``.
        iterations: clipping iterations of ``"lowrank"``.
        clip: clipping bound of ``"lowrank"`` in robust standard deviations.
        interpolation: ``"bilinear"`` or ``"fourier"`` shift of the past frames.

    Shape:
        - Input: ``(B, T, H, W)`` or ``(T, H, W)``; optional ``offsets`` ``(B, T, 2)`` /
          ``(T, 2)``.
        - Output: same as the input frames.

    Examples:
        >>> BackgroundRemoval("mean", 4)(torch.rand(2, 6, 16, 16)).shape
        torch.Size([2, 6, 16, 16])
    """

    def __init__(
        self,
        method: str = "median",
        window: int = 10,
        *,
        rank: int = 1,
        iterations: int = 3,
        clip: float = 3.0,
        interpolation: str = "bilinear",
    ) -> None:
        super().__init__()
        (
            self.method,
            self.window,
            self.rank,
            self.iterations,
            self.clip,
            self.interpolation,
        ) = _check_background_args(method, window, rank, iterations, clip, interpolation)

    def forward(self, frames: torch.Tensor, offsets: torch.Tensor | None = None) -> torch.Tensor:
        """Remove the background of ``frames`` (see :func:`remove_background`)."""
        return remove_background(
            frames,
            self.method,
            self.window,
            offsets=offsets,
            rank=self.rank,
            iterations=self.iterations,
            clip=self.clip,
            interpolation=self.interpolation,
        )

    def extra_repr(self) -> str:
        """Settings, shown in the module's repr."""
        return (
            f"method={self.method!r}, window={self.window}, rank={self.rank}, "
            f"iterations={self.iterations}, clip={self.clip}, interpolation={self.interpolation!r}"
        )

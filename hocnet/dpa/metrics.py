"""Figures of merit of the DPA [NR08]: Block SNR (eq. 16), algorithm score (eq. 17), and more.

* :func:`block_snr` / :func:`block_snrs` -- eq. (16): the frame is tiled into ``M x N`` blocks
  (30 x 30 in [NR08], 30 x 80 for fast targets) around the target block; each block's SNR is
  (mean of its ``Max_Numbers`` highest pixels - mean of its other pixels) / its std;
* :func:`algorithm_score` -- ``A_S`` of eq. (17), ``(SNR_TB - mean SNR_NTB) / std SNR_NTB``,
  averaged over the last frames. ``reading="centred"`` keeps our earlier reading (5 x 5 blocks
  centred on the truth, the 8 neighbours pooled into one background), under which ``A_S`` can
  only fall as ``Max_Numbers`` grows;
* :func:`tracking_success` -- whether a back-tracked trajectory follows the truth;
* :func:`frame_thresholds` and :func:`detection_probability` -- per-frame CFAR thresholds and
  the probability of detection at a fixed false-alarm rate, frame by frame;
* :func:`frames_to_reach` -- how many frames a Pd curve needs to reach a level.

Positions are ``(x, y)`` = (column, row); a float position lies in the pixel
``(floor(x + 0.5), floor(y + 0.5))`` (pixel centres on integer coordinates, as in
:mod:`hocnet.data.infrared`).
"""

from __future__ import annotations

import math
from typing import Any

import torch

from hocnet._check import as_cube, check_choice, check_finite, check_int, check_number

__all__ = [
    "PAPER_BLOCK",
    "READINGS",
    "algorithm_score",
    "algorithm_score_terms",
    "block_snr",
    "block_snrs",
    "detection_probability",
    "frame_thresholds",
    "frames_to_reach",
    "highest_on_target",
    "tracking_success",
]


# ----------------------------------------------------------------------------- helpers


def _tensor(name: str, value: Any, what: str) -> torch.Tensor:
    """``value`` as a real (non-bool) tensor, finite."""
    if not isinstance(value, torch.Tensor):
        try:
            value = torch.as_tensor(value)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(f"`{name}`: expected {what}, got {type(value).__name__}") from None
    if value.is_complex() or value.dtype == torch.bool:
        raise TypeError(f"`{name}`: expected a real tensor, got dtype {value.dtype}")
    check_finite(name, value)
    return value


def _float(value: torch.Tensor) -> torch.Tensor:
    return value if value.is_floating_point() else value.to(torch.get_default_dtype())


def _check_block(block: Any, max_numbers: Any) -> tuple[int, int]:
    block = check_int("block", block, minimum=1)
    if block % 2 == 0:
        raise ValueError(f"`block`: expected an odd integer, got {block}")
    max_numbers = check_int("max_numbers", max_numbers, minimum=1, maximum=block * block)
    return block, max_numbers


def _pixels(name: str, xy: torch.Tensor, height: int, width: int) -> tuple[torch.Tensor, ...]:
    """Column and row of the pixels containing ``(..., 2)`` ``(x, y)``; must be in the frame."""
    if xy.is_floating_point():
        xy = torch.floor(xy + 0.5)
    xy = xy.long()
    x, y = xy[..., 0], xy[..., 1]
    outside = (x < 0) | (x >= width) | (y < 0) | (y >= height)
    if bool(outside.any()):
        bad = tuple(xy[outside][0].tolist())
        raise ValueError(
            f"`{name}`: expected (x, y) inside the W x H = {width} x {height} frame, got {bad}"
        )
    return x, y


def _patches(
    images: torch.Tensor, which: torch.Tensor, x: torch.Tensor, y: torch.Tensor, half: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(K, 2h + 1, 2h + 1)`` windows of ``images[which]`` centred on ``(x, y)`` + in-frame mask.

    Out-of-frame entries hold a copy of the nearest border pixel and are ``False`` in the mask.
    """
    _, height, width = images.shape
    off = torch.arange(-half, half + 1, device=images.device)
    rows = y.unsqueeze(1) + off  # (K, n)
    cols = x.unsqueeze(1) + off
    valid = ((rows >= 0) & (rows < height)).unsqueeze(2) & ((cols >= 0) & (cols < width)).unsqueeze(
        1
    )
    patch = images[
        which.view(-1, 1, 1),
        rows.clamp(0, height - 1).unsqueeze(2),
        cols.clamp(0, width - 1).unsqueeze(1),
    ]
    return patch, valid


def _block_snr(
    images: torch.Tensor,
    which: torch.Tensor,
    x: torch.Tensor,
    y: torch.Tensor,
    block: int,
    max_numbers: int,
) -> torch.Tensor:
    """Block SNR of eq. (16) at ``K`` targets: image ``which[i]``, pixel ``(x[i], y[i])``."""
    half = block // 2
    patch, valid = _patches(images.to(torch.float64), which, x, y, block + half)
    inner = torch.zeros(3 * block, 3 * block, dtype=torch.bool, device=images.device)
    inner[block : 2 * block, block : 2 * block] = True
    bg, bg_valid = patch[:, ~inner], valid[:, ~inner]  # (K, 8 b^2)
    n_bg = bg_valid.sum(dim=1)
    if bool((n_bg == 0).any()):
        raise ValueError(
            "`image`: expected background pixels around the target block, got an image that "
            f"the {block} x {block} target block covers entirely"
        )
    low = bg.masked_fill(~bg_valid, math.inf).amin(dim=1)
    high = bg.masked_fill(~bg_valid, -math.inf).amax(dim=1)
    constant = low == high
    mean = bg.masked_fill(~bg_valid, 0.0).sum(dim=1) / n_bg
    mean = torch.where(constant, low, mean)
    dev = (bg - mean.unsqueeze(1)).masked_fill(~bg_valid, 0.0)
    var = dev.square().sum(dim=1) / n_bg
    std = torch.where(constant, torch.zeros_like(var), var.clamp_min(0.0).sqrt())
    target, t_valid = patch[:, inner], valid[:, inner]  # (K, b^2)
    top = target.masked_fill(~t_valid, -math.inf).topk(max_numbers, dim=1).values
    count = t_valid.sum(dim=1).clamp(max=max_numbers)
    use = torch.arange(max_numbers, device=images.device).unsqueeze(0) < count.unsqueeze(1)
    signal = top.masked_fill(~use, 0.0).sum(dim=1) / count
    contrast = signal - mean
    flat_bg = torch.sign(contrast) * math.inf
    flat_bg = torch.where(contrast == 0, torch.zeros_like(contrast), flat_bg)
    safe = torch.where(constant, torch.ones_like(std), std)
    return torch.where(constant, flat_bg, contrast / safe).to(_float(images).dtype)


def _targets(
    name: str, positions: Any, bsz: int, n_t: int, batched: bool, what: str
) -> torch.Tensor:
    """Validate per-frame target positions -> ``(B, N, T, 2)``."""
    pos = _tensor(name, positions, what)
    one, many = (3, 4) if batched else (2, 3)
    if pos.dim() == one:
        pos = pos.unsqueeze(-3)
    elif pos.dim() != many:
        shapes = "(B, T, 2) or (B, N, T, 2)" if batched else "(T, 2) or (N, T, 2)"
        raise ValueError(f"`{name}`: expected shape {shapes}, got {tuple(pos.shape)}")
    if not batched:
        pos = pos.unsqueeze(0)
    if pos.shape[0] != bsz or pos.shape[2] != n_t or pos.shape[3] != 2:
        raise ValueError(
            f"`{name}`: expected B = {bsz}, T = {n_t} and (x, y) pairs in the last axis, got "
            f"shape {tuple(torch.as_tensor(positions).shape)}"
        )
    if pos.shape[1] == 0:
        raise ValueError(f"`{name}`: expected at least one target, got N = 0")
    return pos


def _upper_quantile(values: torch.Tensor, pfa: float, what: str) -> torch.Tensor:
    """``(m + 1)``-th largest of ``values`` (last axis), ``m = floor(pfa * N)``; ``(...)``."""
    n = values.shape[-1]
    m = math.floor(pfa * n * (1.0 + 1e-12))
    if m < 1:
        needed = math.ceil(1.0 / pfa - 1e-9)
        raise ValueError(
            f"`pfa`: expected a number >= 1/N = {1.0 / max(n, 1):.3g} with N = {n} {what}, got "
            f"{pfa:g}; pfa = {pfa:g} needs at least {needed} samples"
        )
    return torch.kthvalue(values, n - m, dim=-1).values


# ----------------------------------------------------------------------------- paper reading

READINGS = ("paper", "centred")
"""Readings of eq. (16)-(17): ``"paper"`` (tiled blocks, the default) and ``"centred"``."""

PAPER_BLOCK = (30, 30)
"""Block size ``(rows M, columns N)`` of [NR08] for slow targets (``(30, 80)`` for fast ones)."""


def _check_reading(reading: Any) -> str:
    return check_choice("reading", reading, READINGS)


def _check_rect(block: Any) -> tuple[int, int]:
    """``block`` of the paper reading: ``M`` (square) or ``(M, N)`` rows x columns, each >= 1."""
    if block is None:
        return PAPER_BLOCK
    if isinstance(block, tuple | list):
        if len(block) != 2:
            raise ValueError(f"`block`: expected an integer or (rows, columns), got {block!r}")
        return check_int("block", block[0], minimum=1), check_int("block", block[1], minimum=1)
    size = check_int("block", block, minimum=1)
    return size, size


def _paper_snrs(
    images: torch.Tensor,
    which: torch.Tensor,
    x: torch.Tensor,
    y: torch.Tensor,
    rows: int,
    cols: int,
    max_numbers: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Block SNR of eq. (16) of the 3 x 3 tiled blocks around ``K`` anchors: ``(K, 9)`` + valid.

    Block ``(r, c)``, ``r, c in {-1, 0, 1}`` (index ``3 (r + 1) + (c + 1)``, 4 = target block)
    covers rows ``y - rows // 2 + r rows + [0, rows)`` and the same for the columns; pixels
    outside the frame are left out. A block is valid if it keeps more than ``max_numbers``
    pixels (so that "the rest" is not empty).
    """
    img = images.to(torch.float64)
    _, height, width = img.shape
    dev = img.device
    row_idx = (y - rows // 2 - rows).unsqueeze(1) + torch.arange(3 * rows, device=dev)  # (K, 3M)
    col_idx = (x - cols // 2 - cols).unsqueeze(1) + torch.arange(3 * cols, device=dev)  # (K, 3N)
    valid = ((row_idx >= 0) & (row_idx < height)).unsqueeze(2) & (
        (col_idx >= 0) & (col_idx < width)
    ).unsqueeze(1)
    patch = img[
        which.view(-1, 1, 1),
        row_idx.clamp(0, height - 1).unsqueeze(2),
        col_idx.clamp(0, width - 1).unsqueeze(1),
    ]  # (K, 3M, 3N)
    k = patch.shape[0]

    def tiles(t: torch.Tensor) -> torch.Tensor:
        return t.reshape(k, 3, rows, 3, cols).permute(0, 1, 3, 2, 4).reshape(k, 9, rows * cols)

    vals, ok = tiles(patch), tiles(valid)
    n = ok.sum(dim=-1)  # (K, 9)
    usable = n > max_numbers
    top = vals.masked_fill(~ok, -math.inf).topk(max_numbers, dim=-1).values
    top_sum = top.masked_fill(~torch.isfinite(top), 0.0).sum(dim=-1)
    total = vals.masked_fill(~ok, 0.0).sum(dim=-1)
    count = n.clamp_min(1).to(torch.float64)
    rest = (total - top_sum) / (count - max_numbers).clamp_min(1.0)
    mean = total / count
    var = (vals - mean.unsqueeze(-1)).masked_fill(~ok, 0.0).square().sum(dim=-1) / count
    std = var.sqrt()
    flat = std == 0  # every pixel of the block equal: no contrast
    snr = (top_sum / max_numbers - rest) / torch.where(flat, torch.ones_like(std), std)
    snr = torch.where(flat, torch.zeros_like(snr), snr)
    return snr.masked_fill(~usable, math.nan), usable


def _paper_score(
    snr: torch.Tensor, usable: torch.Tensor, max_numbers: int, name: str = "asf"
) -> torch.Tensor:
    """A_S of eq. (17) from the ``(K, 9)`` block SNRs: ``(K,)`` float64."""
    return _paper_terms(snr, usable, max_numbers, name)[0]


def _paper_terms(
    snr: torch.Tensor, usable: torch.Tensor, max_numbers: int, name: str = "asf"
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A_S of eq. (17) and its terms ``(A_S, SNR_TB, mean SNR_NTB, std SNR_NTB)``, each ``(K,)``."""
    if not bool(usable[:, 4].all()):
        raise ValueError(
            "`max_numbers`: expected fewer than the pixels of the target block inside the "
            f"frame, got {max_numbers}"
        )
    ntb = torch.cat([snr[:, :4], snr[:, 5:]], dim=1)
    ok = torch.cat([usable[:, :4], usable[:, 5:]], dim=1)
    n = ok.sum(dim=1)
    if bool((n < 2).any()):
        raise ValueError(
            f"`{name}`: expected at least 2 non-target blocks with more than `max_numbers` pixels "
            f"inside the frame, got {int(n.min())} (frame too small for the blocks)"
        )
    count = n.to(torch.float64)
    mean = ntb.masked_fill(~ok, 0.0).sum(dim=1) / count
    std = ((ntb - mean.unsqueeze(1)).masked_fill(~ok, 0.0).square().sum(dim=1) / count).sqrt()
    contrast = snr[:, 4] - mean
    flat = std == 0
    inf = torch.where(contrast == 0, torch.zeros_like(contrast), torch.sign(contrast) * math.inf)
    score = torch.where(flat, inf, contrast / torch.where(flat, torch.ones_like(std), std))
    return score, snr[:, 4], mean, std


# ----------------------------------------------------------------------------- API


def block_snr(
    image: torch.Tensor,
    position: torch.Tensor,
    *,
    block: int | tuple[int, int] | None = None,
    max_numbers: int = 1,
    reading: str = "paper",
) -> torch.Tensor:
    """Block SNR of the target block, eq. (16) of [NR08].

    ``reading="paper"`` (default), as [NR08] prints it: the image is tiled into ``M x N`` blocks
    (``block``, default 30 x 30; the paper uses 30 x 80 for fast targets) placed so that the
    target block has the target pixel at its centre (row ``M // 2``, column ``N // 2``), and

    ``Block_SNR = (E[v in Max] - E[v not in Max]) / sigma_v``,

    with ``v`` the pixels of the target block, ``Max`` its ``max_numbers`` highest pixels, the
    rest the other pixels of *that* block, and ``sigma_v`` the standard deviation of all its
    pixels. :func:`block_snrs` gives the SNR of all 9 blocks.

    ``reading="centred"`` (our earlier reading, kept as an option): odd ``block x block``
    blocks (default 5) centred on the target; ``(mean of the max_numbers highest target-block
    values - mean(background)) / std(background)``, with the background the pooled pixels of
    the 8 blocks around the target block.

    Notes:
        Our reading of [NR08]: ``sigma`` is the population standard deviation (divide by
        ``n``); blocks are clipped at the image border (out-of-frame pixels are left out). A
        block whose pixels are all equal has SNR 0. Paper reading: the target block must keep
        more than ``max_numbers`` pixels. Centred reading: a constant background gives
        ``+inf`` / ``-inf`` / ``0`` for a positive / negative / zero numerator, and a clipped
        target block with fewer than ``max_numbers`` pixels averages all of them. The
        computation runs in float64; the result has the image's float dtype.

    Args:
        image: ``(B, H, W)`` or ``(H, W)`` map, e.g. an ASF frame or a whitened frame.
        position: ``(B, 2)`` (or ``(2,)``, used for every image) or ``(2,)`` ``(x, y)`` of the
            target; float allowed (the pixel containing it is used).
        block: paper: ``M`` or ``(M, N)`` (rows, columns), default ``(30, 30)``; centred: an
            odd size, default 5.
        max_numbers: number of highest pixels taken as "target" (``Max_Numbers``), ``>= 1``.
            Default 1 (our choice): eq. (16) as printed takes "the five pixels with the
            highest scores" (``max_numbers=5``, the paper's preliminary runs, Figures 9-13),
            and section 3.2.1(3) then tunes it; 1 is Table 2's value for g = 1 (3 for g = 0),
            the case of the paper's recommended b = 0.8. Pass 5 for eq. (16) as printed.
        reading: ``"paper"`` or ``"centred"``.

    Returns:
        ``(B,)`` Block SNR per image, or a 0-d tensor for an unbatched image.

    Raises:
        TypeError: non-real inputs or non-integer sizes.
        ValueError: wrong shapes, NaN/inf, out-of-range sizes, a position outside the frame, an
            unknown reading, or (centred) an image without background pixels.

    Examples:
        >>> image = torch.zeros(9, 9)
        >>> image[4, 4], image[3, 4] = 10.0, 4.0  # the target block is rows/columns 3..5
        >>> # top-1 = 10, rest = 4 / 8 = 0.5, population std of {10, 4, 0 x 7} = 3.2356
        >>> round(float(block_snr(image, torch.tensor([4, 4]), block=3)), 4)
        2.9361
        >>> image = torch.zeros(15, 15)
        >>> image[::2] = 1.0  # rows alternate 1, 0: 110 of the 200 background pixels are 1
        >>> image[7, 7] = 10.0
        >>> round(float(block_snr(image, torch.tensor([7.2, 6.9]), reading="centred")), 4)
        18.9952
        >>> round((10 - 0.55) / (0.55 * 0.45) ** 0.5, 4)
        18.9952
    """
    reading = _check_reading(reading)
    if reading == "paper":
        rows, cols = _check_rect(block)
        max_numbers = check_int("max_numbers", max_numbers, minimum=1)
    else:
        block, max_numbers = _check_block(5 if block is None else block, max_numbers)
    img = _float(_tensor("image", image, "a tensor of shape (B, H, W) or (H, W)"))
    if img.dim() not in (2, 3) or img.shape[-1] < 1 or img.shape[-2] < 1:
        raise ValueError(f"`image`: expected shape (B, H, W) or (H, W), got {tuple(img.shape)}")
    batched = img.dim() == 3
    images = img if batched else img.unsqueeze(0)
    bsz, height, width = images.shape
    pos = _tensor("position", position, "a tensor of (x, y) positions")
    shapes = [(2,), (bsz, 2)] if batched else [(2,)]
    if tuple(pos.shape) not in shapes:
        wanted = " or ".join(str(s) for s in shapes)
        raise ValueError(f"`position`: expected shape {wanted}, got {tuple(pos.shape)}")
    pos = pos.to(images.device).expand(bsz, 2)
    x, y = _pixels("position", pos, height, width)
    which = torch.arange(bsz, device=images.device)
    if reading == "paper":
        snrs, usable = _paper_snrs(images, which, x, y, rows, cols, max_numbers)
        if not bool(usable[:, 4].all()):
            raise ValueError(
                f"`max_numbers`: expected fewer than the pixels of the target block inside the "
                f"frame, got {max_numbers}"
            )
        snr = snrs[:, 4].to(images.dtype)
    else:
        snr = _block_snr(images, which, x, y, block, max_numbers)
    return snr if batched else snr[0]


def block_snrs(
    image: torch.Tensor,
    position: torch.Tensor,
    *,
    block: int | tuple[int, int] | None = None,
    max_numbers: int = 1,
) -> torch.Tensor:
    """Block SNR of eq. (16) of [NR08] for the target block and its 8 neighbours.

    The paper reading of :func:`block_snr`: ``M x N`` blocks tiled around the target block,
    which has the target pixel at its centre. Entry ``3 (r + 1) + (c + 1)`` is the block ``r``
    block-rows below and ``c`` block-columns right of the target block (entry 4 is the target
    block). Blocks are clipped at the frame border; a block keeping at most ``max_numbers``
    pixels is ``NaN``.

    Args:
        image: ``(B, H, W)`` or ``(H, W)``.
        position: ``(B, 2)`` / ``(2,)`` ``(x, y)`` of the target.
        block: ``M`` or ``(M, N)`` (rows, columns), default ``(30, 30)``.
        max_numbers: ``Max_Numbers``, ``>= 1``; default 1 (Table 2's g = 1 value, our choice;
            eq. (16) as printed uses 5, see :func:`block_snr`).

    Returns:
        float64 ``(B, 9)``, or ``(9,)`` for an unbatched image.

    Raises:
        TypeError: non-real inputs or non-integer sizes.
        ValueError: wrong shapes, NaN/inf, out-of-range sizes, a position outside the frame.

    Examples:
        >>> image = torch.zeros(9, 9)
        >>> image[4, 4] = 1.0
        >>> snr = block_snrs(image, torch.tensor([4, 4]), block=3)  # 3 x 3 blocks of 9 pixels
        >>> snr[0].item(), round(snr[4].item(), 4), round(9 / 8**0.5, 4)  # 1 / std{1, 0 x 8}
        (0.0, 3.182, 3.182)
    """
    rows, cols = _check_rect(block)
    max_numbers = check_int("max_numbers", max_numbers, minimum=1)
    img = _float(_tensor("image", image, "a tensor of shape (B, H, W) or (H, W)"))
    if img.dim() not in (2, 3) or img.shape[-1] < 1 or img.shape[-2] < 1:
        raise ValueError(f"`image`: expected shape (B, H, W) or (H, W), got {tuple(img.shape)}")
    batched = img.dim() == 3
    images = img if batched else img.unsqueeze(0)
    bsz, height, width = images.shape
    pos = _tensor("position", position, "a tensor of (x, y) positions")
    shapes = [(2,), (bsz, 2)] if batched else [(2,)]
    if tuple(pos.shape) not in shapes:
        wanted = " or ".join(str(s) for s in shapes)
        raise ValueError(f"`position`: expected shape {wanted}, got {tuple(pos.shape)}")
    x, y = _pixels("position", pos.to(images.device).expand(bsz, 2), height, width)
    which = torch.arange(bsz, device=images.device)
    snrs, _ = _paper_snrs(images, which, x, y, rows, cols, max_numbers)
    return snrs if batched else snrs[0]


def algorithm_score(
    asf: torch.Tensor,
    positions: torch.Tensor,
    *,
    last: int = 6,
    block: int | tuple[int, int] | None = None,
    max_numbers: int = 1,
    reading: str = "paper",
    anchor: str = "first",
) -> torch.Tensor:
    """Algorithm score ``A_S`` of eq. (17) of [NR08], averaged over the last frames.

    ``reading="paper"`` (default), eq. (17) as printed: per frame,

    ``A_S = (Block_SNR(TB) - E[Block_SNR(NTB)]) / sigma[Block_SNR(NTB)]``

    with the Block SNRs of :func:`block_snrs` (eq. 16) of the target block ``TB`` and of its
    8 neighbours ``NTB``; then the mean over the ``last`` final frames and over the targets.
    The tiling is fixed for the whole sequence ([NR08], Figure 8: "1st frame of TB, target at
    center") with ``anchor="first"``: the target block is centred on the target's pixel in
    frame 0 of ``asf`` (hence the paper's 30 x 80 blocks when the target moves far); with
    ``anchor="each"`` it is re-centred on the target in every frame.

    ``reading="centred"`` (our earlier reading, kept as an option): the mean over the last
    frames (and the targets) of ``block_snr(..., reading="centred")`` at the true position of
    each frame (``anchor`` is ignored). Under this reading ``A_S`` can only fall as
    ``max_numbers`` grows; under the paper's it can peak where the pixels the target lights in
    the ASF end (measured on the NA23A-like s_n = 4 scene with a one-pixel target,
    ``tests/dpa/test_metrics.py``: at 1 for g = 1 in every scene, as [NR08] Table 2; for g = 0
    it rises to 3 and then levels off within a few %, the knee at the paper's 3 but no clear
    peak, since the spread of the non-target SNRs also shrinks with ``max_numbers``).

    Notes:
        Our reading of [NR08]: population standard deviations; equal weight per frame and per
        target; non-target blocks keeping at most ``max_numbers`` pixels inside the frame are
        left out (at least 2 must remain); a zero spread of the NTB SNRs gives ``+inf`` /
        ``-inf`` / ``0`` by the sign of the numerator.

    Args:
        asf: ASF sequence ``(B, T, H, W)`` or ``(T, H, W)``.
        positions: true ``(x, y)`` target positions ``(B, T, 2)`` / ``(T, 2)``, or for several
            targets ``(B, N, T, 2)`` / ``(N, T, 2)`` (as ``IRSequence.positions``); float.
        last: number of final frames averaged, ``1 .. T``.
        block: paper: ``M`` or ``(M, N)`` rows x columns (default 30 x 30); centred: odd size
            (default 5).
        max_numbers: ``Max_Numbers``, the number of highest pixels taken as "target", ``>= 1``;
            default 1 (Table 2's g = 1 value, our choice; eq. (16) as printed uses 5, see
            :func:`block_snr`).
        reading: ``"paper"`` or ``"centred"``.
        anchor: ``"first"`` or ``"each"`` (paper reading only).

    Returns:
        ``(B,)`` float scores, or a 0-d tensor for an unbatched ``asf``.

    Raises:
        TypeError: non-real inputs or non-integer sizes.
        ValueError: wrong shapes, NaN/inf, out-of-range sizes, positions outside the frame, a
            frame too small for 2 non-target blocks.

    Examples:
        >>> asf = torch.zeros(8, 15, 15)
        >>> asf[:, ::2] = 1.0
        >>> asf[:, 7, 7] = 10.0
        >>> positions = torch.tensor([[7.0, 7.0]]).expand(8, 2)
        >>> round(float(algorithm_score(asf, positions, last=3, reading="centred")), 4)
        18.9952
        >>> asf = torch.randn(8, 45, 45, generator=torch.Generator().manual_seed(0))
        >>> asf[:, 22, 22] += 8.0
        >>> bool(algorithm_score(asf, positions + 15, block=15) > 3)
        True
    """
    reading = _check_reading(reading)
    anchor = check_choice("anchor", anchor, ("first", "each"))
    if reading == "paper":
        rows, cols = _check_rect(block)
        max_numbers = check_int("max_numbers", max_numbers, minimum=1)
    else:
        block, max_numbers = _check_block(5 if block is None else block, max_numbers)
    args, (bsz, n_targets, last, batched, dtype) = _last_frames(
        asf, positions, last, fixed=reading == "paper" and anchor == "first"
    )
    if reading == "paper":
        snrs, usable = _paper_snrs(*args, rows, cols, max_numbers)
        snr = _paper_score(snrs, usable, max_numbers).to(dtype)
    else:
        snr = _block_snr(*args, block, max_numbers)
    score = snr.view(bsz, n_targets * last).mean(dim=1)
    return score if batched else score[0]


def _last_frames(
    asf: torch.Tensor, positions: torch.Tensor, last: Any, *, fixed: bool
) -> tuple[tuple[torch.Tensor, ...], tuple[int, int, int, bool, torch.dtype]]:
    """The ``last`` final frames of ``asf`` and the target pixels in them, checked.

    Returns ``(images (B * last, H, W), which, x, y)`` (one entry per target and frame: the
    image index and the target's pixel; ``fixed``: every frame at the frame-0 position, the
    paper's tiling anchored once) and ``(B, N, last, batched, dtype)``.
    """
    cube, batched = as_cube("asf", asf)
    cube = _float(cube)
    bsz, n_t, height, width = cube.shape
    pos = _targets("positions", positions, bsz, n_t, batched, "a tensor of (x, y) positions")
    last = check_int("last", last, minimum=1, maximum=n_t)
    n_targets = pos.shape[1]
    images = cube[:, n_t - last :].reshape(bsz * last, height, width)
    pos = pos.to(cube.device)
    if fixed:
        pos = pos[:, :, :1].expand(bsz, n_targets, last, 2)
    else:
        pos = pos[:, :, n_t - last :]  # (B, N, L, 2)
    x, y = _pixels("positions", pos, height, width)
    which = torch.arange(bsz, device=cube.device).view(bsz, 1, 1) * last
    which = (which + torch.arange(last, device=cube.device).view(1, 1, last)).expand(
        bsz, n_targets, last
    )
    args = (images, which.reshape(-1), x.reshape(-1), y.reshape(-1))
    return args, (bsz, n_targets, last, batched, cube.dtype)


def algorithm_score_terms(
    asf: torch.Tensor,
    positions: torch.Tensor,
    *,
    last: int = 6,
    block: int | tuple[int, int] | None = None,
    max_numbers: int = 1,
    anchor: str = "first",
) -> dict[str, torch.Tensor]:
    """``A_S`` of eq. (17) of [NR08] (paper reading) together with the terms it is made of.

    Per frame, eq. (17) is ``A_S = (SNR_TB - mean SNR_NTB) / std SNR_NTB``; this returns the
    mean over the ``last`` final frames (and the targets) of each of ``A_S``, ``SNR_TB``,
    ``mean SNR_NTB`` and ``std SNR_NTB``, so that a change of ``A_S`` (e.g. versus ``b``) can
    be traced to the target block or to its neighbours. ``"score"`` equals
    :func:`algorithm_score` with ``reading="paper"`` and the same arguments. Our addition (a
    diagnostic; [NR08] plots the same three terms in Figures 10, 11, 14, 22 and 24).

    Args:
        asf: ASF sequence ``(B, T, H, W)`` or ``(T, H, W)``.
        positions: true ``(x, y)`` ``(B, T, 2)`` / ``(T, 2)`` or ``(B, N, T, 2)`` /
            ``(N, T, 2)``; float.
        last: number of final frames averaged, ``1 .. T``.
        block: ``M`` or ``(M, N)`` rows x columns (default 30 x 30).
        max_numbers: ``Max_Numbers``, ``>= 1``.
        anchor: ``"first"`` (tiling fixed on the frame-0 position) or ``"each"``.

    Returns:
        ``{"score", "snr_tb", "ntb_mean", "ntb_std"}``: float ``(B,)`` each (0-d unbatched).

    Raises:
        TypeError: non-real inputs or non-integer sizes.
        ValueError: as :func:`algorithm_score`.

    Examples:
        >>> asf = torch.randn(4, 45, 45, generator=torch.Generator().manual_seed(0))
        >>> asf[:, 22, 22] += 8.0
        >>> truth = torch.tensor([[22.0, 22.0]]).expand(4, 2)
        >>> terms = algorithm_score_terms(asf, truth, last=2, block=15)
        >>> sorted(terms)
        ['ntb_mean', 'ntb_std', 'score', 'snr_tb']
        >>> bool(terms["snr_tb"] > terms["ntb_mean"])
        True
    """
    anchor = check_choice("anchor", anchor, ("first", "each"))
    rows, cols = _check_rect(block)
    max_numbers = check_int("max_numbers", max_numbers, minimum=1)
    args, (bsz, n_targets, last, batched, dtype) = _last_frames(
        asf, positions, last, fixed=anchor == "first"
    )
    snrs, usable = _paper_snrs(*args, rows, cols, max_numbers)
    terms = _paper_terms(snrs, usable, max_numbers)
    out = {}
    for key, value in zip(("score", "snr_tb", "ntb_mean", "ntb_std"), terms, strict=True):
        mean = value.to(dtype).view(bsz, n_targets * last).mean(dim=1)
        out[key] = mean if batched else mean[0]
    return out


def highest_on_target(
    asf: torch.Tensor,
    positions: torch.Tensor,
    *,
    block: int | tuple[int, int] | None = None,
    max_numbers: int = 1,
    radius: float = 1.5,
    anchor: str = "first",
    footprint: str = "radius",
) -> torch.Tensor:
    """Whether the ``Max_Numbers`` highest pixels of the last target block are target pixels.

    [NR08] section 3.2.1(3) splits its b axis (Figure 16, Figures 17 and 19) by what the
    highest pixels of the last processed frame are: "(1) target pixels, (2) trail and target
    pixels and pixel of origin, and (3) pixel of origin and trail pixels", and calls a range
    good where "the highest pixels taken as 'target pixels' indeed belong to the target". Our
    reading: the target block is the one of :func:`algorithm_score` (``M x N``, centred on the
    target's pixel in frame 0 with ``anchor="first"``, on its last-frame pixel with ``"each"``),
    clipped to the frame; a pixel is a *target pixel* when (``footprint="3x3"``) it lies in the
    target's 3 x 3 footprint, Chebyshev distance ``<= 1`` from the pixel containing the true
    last-frame position (rounded half up) -- our reading: [NR08]'s target subtends about a
    pixel and is blurred by the 3 x 3 spread of ``W_basic`` (section 2.2.1), so its corner
    pixels (up to 2.1 px from a sub-pixel truth) are target pixels -- or (``footprint="radius"``,
    the default, kept for compatibility) when its centre lies within ``radius`` px (Euclidean,
    ``<=``) of the true last-frame position; the answer is ``True`` when all
    ``max_numbers`` highest pixels of the block (ties: an arbitrary choice among equal values)
    are target pixels. Our addition as a function; the rule is the paper's text.

    Args:
        asf: ASF sequence ``(B, T, H, W)`` or ``(T, H, W)`` (only its last frame is read).
        positions: true ``(x, y)`` of the studied target, ``(B, T, 2)`` or ``(T, 2)``; float.
        block: ``M`` or ``(M, N)`` rows x columns (default 30 x 30).
        max_numbers: number of highest pixels, ``>= 1``, fewer than the block's pixels in the
            frame.
        radius: target-pixel radius in pixels, ``> 0`` (read with ``footprint="radius"``).
        anchor: ``"first"`` or ``"each"``.
        footprint: ``"radius"`` (Euclidean disc of ``radius``) or ``"3x3"`` (the 3 x 3
            pixels around the rounded true position; our reading, used by ``dpa-b-sweep``).

    Returns:
        bool ``(B,)``, or a 0-d bool tensor for an unbatched ``asf``.

    Raises:
        TypeError: non-real inputs or non-integer sizes.
        ValueError: wrong shapes, NaN/inf, out-of-range sizes, positions outside the frame, a
            target block with at most ``max_numbers`` pixels inside the frame.

    Examples:
        >>> asf = torch.zeros(2, 30, 30)
        >>> asf[-1, 15, 15], asf[-1, 15, 16], asf[-1, 15, 20] = 9.0, 8.0, 7.0  # target, trail
        >>> truth = torch.tensor([[15.0, 15.0], [15.2, 15.0]])
        >>> bool(highest_on_target(asf, truth, block=9, max_numbers=2))
        True
        >>> bool(highest_on_target(asf, truth, block=9, max_numbers=3))
        False
        >>> asf[-1, 16, 16] = 8.5  # footprint corner, 1.98 px from (14.6, 14.6)
        >>> near = torch.tensor([[15.0, 15.0], [14.6, 14.6]])
        >>> bool(highest_on_target(asf, near, block=9, max_numbers=2, footprint="3x3"))
        True
        >>> bool(highest_on_target(asf, near, block=9, max_numbers=2))
        False
    """
    anchor = check_choice("anchor", anchor, ("first", "each"))
    footprint = check_choice("footprint", footprint, ("radius", "3x3"))
    rows, cols = _check_rect(block)
    max_numbers = check_int("max_numbers", max_numbers, minimum=1)
    radius = check_number("radius", radius, low=0.0, low_inclusive=False)
    cube, batched = as_cube("asf", asf)
    cube = _float(cube).detach()
    bsz, n_t, height, width = cube.shape
    pos = _tensor("positions", positions, "a tensor of (x, y) positions")
    want = (bsz, n_t, 2) if batched else (n_t, 2)
    if tuple(pos.shape) != want:
        raise ValueError(f"`positions`: expected shape {want}, got {tuple(pos.shape)}")
    pos = (pos if batched else pos.unsqueeze(0)).to(cube.device).double()
    x, y = _pixels("positions", pos[:, 0 if anchor == "first" else -1], height, width)
    dev = cube.device
    rr = torch.arange(height, device=dev).view(1, -1, 1)
    cc = torch.arange(width, device=dev).view(1, 1, -1)
    r0 = (y - rows // 2).view(-1, 1, 1)
    c0 = (x - cols // 2).view(-1, 1, 1)
    inside = (rr >= r0) & (rr < r0 + rows) & (cc >= c0) & (cc < c0 + cols)  # (B, H, W)
    count = inside.flatten(1).sum(dim=1)
    if bool((count <= max_numbers).any()):
        raise ValueError(
            "`max_numbers`: expected fewer than the pixels of the target block inside the "
            f"frame ({int(count.min())}), got {max_numbers}"
        )
    scores = cube[:, -1].masked_fill(~inside, -math.inf).flatten(1)
    top = scores.topk(max_numbers, dim=1).indices  # (B, K)
    px = (top % width).double()
    py = torch.div(top, width, rounding_mode="floor").double()
    if footprint == "3x3":
        tx, ty = _pixels("positions", pos[:, -1], height, width)
        cheb = torch.maximum((px - tx.view(-1, 1)).abs(), (py - ty.view(-1, 1)).abs())
        hit = (cheb <= 1).all(dim=1)
    else:
        dist = torch.hypot(px - pos[:, -1, 0:1], py - pos[:, -1, 1:2])
        hit = (dist <= radius).all(dim=1)
    return hit if batched else hit[0]


def tracking_success(
    trajectory: torch.Tensor,
    truth: torch.Tensor,
    *,
    radius: float = 1.5,
    fraction: float = 0.8,
    last: int | None = None,
) -> torch.Tensor:
    """Whether a back-tracked trajectory follows the true target.

    A frame is a hit when the Euclidean distance between the trajectory's pixel and the true
    position is ``<= radius``; the track is a success when the hits make up at least
    ``fraction`` of the frames (of the ``last`` final frames if given).

    Args:
        trajectory: ``(B, T, 2)`` or ``(T, 2)`` ``(x, y)`` per frame (e.g. from
            :func:`~hocnet.dpa.backtrack.backtrack`), integer or float.
        truth: true ``(x, y)`` of the same shape, float.
        radius: hit radius in pixels, ``> 0``.
        fraction: required fraction of hit frames, in ``(0, 1]``.
        last: evaluate only the ``last`` final frames, ``1 .. T``; ``None`` for all.

    Returns:
        bool ``(B,)``, or a 0-d bool tensor for ``(T, 2)`` input.

    Raises:
        TypeError: non-real inputs.
        ValueError: shape mismatch, NaN/inf, out-of-range arguments.

    Examples:
        >>> truth = torch.tensor([[0.0, 0.0], [1.0, 0.2], [2.0, 0.4], [3.0, 0.6], [4.0, 0.8]])
        >>> found = torch.tensor([[0, 0], [1, 0], [2, 0], [3, 1], [9, 9]])
        >>> bool(tracking_success(found, truth)), bool(tracking_success(found, truth, last=2))
        (True, False)
    """
    traj = _tensor("trajectory", trajectory, "a tensor of (x, y) pixels")
    if traj.dim() not in (2, 3) or traj.shape[-1] != 2 or traj.shape[-2] < 1:
        raise ValueError(
            f"`trajectory`: expected shape (B, T, 2) or (T, 2), got {tuple(traj.shape)}"
        )
    ref = _tensor("truth", truth, "a tensor of (x, y) positions")
    if ref.shape != traj.shape:
        raise ValueError(
            f"`truth`: expected the shape of `trajectory` {tuple(traj.shape)}, got "
            f"{tuple(ref.shape)}"
        )
    radius = check_number("radius", radius, low=0.0, low_inclusive=False)
    fraction = check_number("fraction", fraction, low=0.0, high=1.0, low_inclusive=False)
    n_t = traj.shape[-2]
    n_last = n_t if last is None else check_int("last", last, minimum=1, maximum=n_t)
    diff = (
        traj[..., n_t - n_last :, :].double() - ref[..., n_t - n_last :, :].to(traj.device).double()
    )
    hit = torch.linalg.vector_norm(diff, dim=-1) <= radius
    return hit.double().mean(dim=-1) >= fraction - 1e-12


def frames_to_reach(pd_curve: torch.Tensor, frames: torch.Tensor, level: float = 0.9) -> float:
    """Smallest number of frames at which a Pd curve reaches ``level``.

    The curve is interpolated linearly between its points; the answer is the first crossing:
    ``frames[0]`` if ``pd_curve[0] >= level``, else the interpolated abscissa between the last
    point below ``level`` and the first point at or above it.

    Args:
        pd_curve: ``(K,)`` values in ``[0, 1]`` (probability of detection per point).
        frames: ``(K,)`` strictly increasing numbers of frames.
        level: the level to reach, in ``[0, 1]``.

    Returns:
        The number of frames as a float, ``inf`` if the curve never reaches ``level``.

    Raises:
        TypeError: non-real inputs.
        ValueError: shapes, NaN/inf, values out of ``[0, 1]``, non-increasing ``frames``.

    Examples:
        >>> frames_to_reach(torch.tensor([0.25, 0.5, 1.0]), torch.tensor([5, 10, 15]), 0.75)
        12.5
        >>> frames_to_reach(torch.tensor([0.25, 0.5]), torch.tensor([5, 10]), 0.75)
        inf
    """
    pd = _tensor("pd_curve", pd_curve, "a 1-D tensor of probabilities").double()
    if pd.dim() != 1 or pd.numel() < 1:
        raise ValueError(f"`pd_curve`: expected a non-empty 1-D tensor, got {tuple(pd.shape)}")
    if bool(((pd < 0) | (pd > 1)).any()):
        raise ValueError(
            f"`pd_curve`: expected values in [0, 1], got min {float(pd.min()):g}, "
            f"max {float(pd.max()):g}"
        )
    fr = _tensor("frames", frames, "a 1-D tensor of frame counts").double()
    if fr.shape != pd.shape:
        raise ValueError(
            f"`frames`: expected the shape of `pd_curve` {tuple(pd.shape)}, got {tuple(fr.shape)}"
        )
    if fr.numel() > 1 and not bool((fr[1:] > fr[:-1]).all()):
        raise ValueError("`frames`: expected strictly increasing values, got a non-increasing step")
    level = check_number("level", level, low=0.0, high=1.0)
    reached = torch.nonzero(pd >= level).flatten()
    if reached.numel() == 0:
        return math.inf
    i = int(reached[0])
    if i == 0:
        return float(fr[0])
    p0, p1, f0, f1 = float(pd[i - 1]), float(pd[i]), float(fr[i - 1]), float(fr[i])
    return f0 + (level - p0) / (p1 - p0) * (f1 - f0)


def frame_thresholds(asf: torch.Tensor, pfa: float = 1e-3) -> torch.Tensor:
    """Per-frame CFAR thresholds from a target-free ASF sequence.

    For each frame ``n``, the empirical upper ``pfa``-quantile of the ``N = B * H * W`` ASF
    values of that frame, with the rule of :func:`~hocnet.dpa.backtrack.cfar_threshold`
    (the ``(m + 1)``-th largest, ``m = floor(pfa * N)``), so its last entry equals
    ``cfar_threshold(...)`` on the same data. Since ``ASF_n`` depends only on frames
    ``0 .. n``, entry ``n`` is the threshold of a detector stopped after ``n + 1`` frames.

    Args:
        asf: target-free ASF ``(B, T, H, W)`` or ``(T, H, W)``.
        pfa: per-pixel false-alarm probability in ``(0, 1)``, ``>= 1 / (B * H * W)``.

    Returns:
        ``(T,)`` thresholds in the ASF's float dtype.

    Raises:
        TypeError: non-real input.
        ValueError: bad shape, NaN/inf, ``pfa`` out of range or below ``1 / N``.

    Examples:
        >>> asf = torch.arange(2 * 3 * 10.0).reshape(2, 3, 10)  # T = 2 frames of 3 x 10
        >>> frame_thresholds(asf, pfa=0.1).tolist()  # 3 of 30 values lie above
        [26.0, 56.0]
    """
    cube, _ = as_cube("asf", asf)
    cube = _float(cube).detach()
    pfa = check_number("pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False)
    values = cube.transpose(0, 1).reshape(cube.shape[1], -1)  # (T, B * H * W)
    return _upper_quantile(values, pfa, "pixels per frame of `asf` (B * H * W)")


def detection_probability(
    asf: torch.Tensor,
    positions: torch.Tensor,
    threshold: float | torch.Tensor,
    *,
    radius: float = 1.5,
) -> torch.Tensor:
    """Probability of detection per frame at a given threshold (e.g. a CFAR one).

    A target counts as detected in frame ``n`` when some ASF pixel whose centre lies within
    ``radius`` px (Euclidean, ``<=``) of its true position exceeds the threshold (strictly,
    as in :func:`~hocnet.dpa.backtrack.detect`). ``Pd_n`` is the fraction of (scene, target)
    pairs detected in frame ``n``. With the thresholds of :func:`frame_thresholds` on
    target-free data this is the Pd-versus-frames curve at a fixed per-pixel Pfa, ready for
    :func:`frames_to_reach`.

    Notes:
        Our reading of [NR08]: detection is per pixel near the truth (no NMS, no back-tracking),
        which matches the per-pixel false-alarm rate of the thresholds. A true position whose
        neighbourhood lies outside the frame is simply not detected.

    Args:
        asf: ASF ``(B, T, H, W)`` or ``(T, H, W)``.
        positions: true ``(x, y)`` ``(B, T, 2)`` / ``(T, 2)`` or ``(B, N, T, 2)`` /
            ``(N, T, 2)``.
        threshold: one number, or ``(T,)`` per-frame thresholds.
        radius: detection radius in pixels, ``>= 0``.

    Returns:
        ``(T,)`` float64 ``Pd`` per frame.

    Raises:
        TypeError: non-real inputs.
        ValueError: wrong shapes, NaN/inf, negative radius.

    Examples:
        >>> asf = torch.zeros(3, 8, 8)
        >>> asf[1:, 4, 4] = 5.0
        >>> detection_probability(asf, torch.tensor([[4.4, 4.0]]).expand(3, 2), 1.0).tolist()
        [0.0, 1.0, 1.0]
    """
    cube, batched = as_cube("asf", asf)
    cube = _float(cube).detach()
    bsz, n_t, height, width = cube.shape
    pos = _targets("positions", positions, bsz, n_t, batched, "a tensor of (x, y) positions")
    pos = pos.to(cube.device).double()
    thr = _tensor("threshold", threshold, "a number or a (T,) tensor").to(cube.device).double()
    if thr.dim() == 0 or thr.numel() == 1:
        thr = thr.reshape(1).expand(n_t)
    elif tuple(thr.shape) != (n_t,):
        raise ValueError(
            f"`threshold`: expected a number or shape ({n_t},), got {tuple(thr.shape)}"
        )
    radius = check_number("radius", radius, low=0.0)
    n_targets = pos.shape[1]
    half = math.floor(radius) + 1
    centre = torch.floor(pos + 0.5).long()
    # clamp far-away targets so the window indices stay small; their mask is all False anyway
    cx = centre[..., 0].clamp(-half - 1, width + half)
    cy = centre[..., 1].clamp(-half - 1, height + half)
    which = (
        torch.arange(bsz * n_t, device=cube.device).view(bsz, 1, n_t).expand(bsz, n_targets, n_t)
    )
    images = cube.reshape(bsz * n_t, height, width).double()
    patch, valid = _patches(images, which.reshape(-1), cx.reshape(-1), cy.reshape(-1), half)
    off = torch.arange(-half, half + 1, device=cube.device, dtype=torch.float64)
    dx = cx.reshape(-1, 1, 1) + off.view(1, 1, -1) - pos[..., 0].reshape(-1, 1, 1)
    dy = cy.reshape(-1, 1, 1) + off.view(1, -1, 1) - pos[..., 1].reshape(-1, 1, 1)
    near = valid & (dx.square() + dy.square() <= radius * radius)
    best = patch.masked_fill(~near, -math.inf).amax(dim=(1, 2)).view(bsz, n_targets, n_t)
    hit = best > thr.view(1, 1, n_t)
    return hit.double().mean(dim=(0, 1))

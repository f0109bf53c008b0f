import math

import numpy as np
import pytest
import torch

from hocnet.data.binarize import CFARBinarize, cfar_binarize, cfar_thresholds


def loop_reference(frames: np.ndarray, pfa: float) -> np.ndarray:
    """Straight from the definition: per frame, keep the pixels above the (n+1)-th largest."""
    out = np.zeros(frames.shape, dtype=bool)
    for index in np.ndindex(frames.shape[:-2]):
        frame = frames[index]
        n = math.floor(pfa * frame.size)
        if n == 0:
            continue
        values = sorted(frame.ravel().tolist(), reverse=True)
        tau = values[n]
        for y in range(frame.shape[0]):
            for x in range(frame.shape[1]):
                out[(*index, y, x)] = frame[y, x] > tau
    return out


@pytest.mark.parametrize("shape", [(3, 9, 11), (2, 3, 8, 8)])
@pytest.mark.parametrize("pfa", [0.01, 0.05, 0.3, 0.999])
def test_matches_loop_reference(shape, pfa):
    frames = torch.randn(*shape, generator=torch.Generator().manual_seed(1))
    np.testing.assert_array_equal(
        cfar_binarize(frames, pfa).numpy(), loop_reference(frames.numpy(), pfa)
    )


def test_ties_and_integer_frames():
    frames = torch.zeros(2, 4, 4, dtype=torch.int64)
    frames[0, 1, 1] = 5
    frames[0, 2, 2] = 5  # a tie at the top: both pass with n = 2, none with n = 1
    frames[1] = 3  # constant frame: nothing stands out
    np.testing.assert_array_equal(
        cfar_binarize(frames, 2 / 16).numpy(), loop_reference(frames.numpy(), 2 / 16)
    )
    assert int(cfar_binarize(frames, 1 / 16).sum()) == 0
    assert cfar_binarize(frames, 2 / 16)[0].sum() == 2


def test_constant_false_alarm_rate():
    # whatever the clutter's level and spread, every frame keeps floor(pfa H W) pixels
    g = torch.Generator().manual_seed(0)
    frames = torch.randn(4, 64, 64, generator=g) * torch.tensor([1.0, 10.0, 0.1, 3.0]).view(
        4, 1, 1
    ) + torch.tensor([0.0, 100.0, -5.0, 7.0]).view(4, 1, 1)
    binary = cfar_binarize(frames, 1e-2)
    assert binary.dtype == torch.bool and binary.shape == frames.shape
    assert binary.sum(dim=(1, 2)).tolist() == [40] * 4


def test_target_survives():
    frames = torch.randn(5, 32, 32, generator=torch.Generator().manual_seed(3))
    frames[:, 10, 20] += 8.0
    assert bool(cfar_binarize(frames, 1e-3)[:, 10, 20].all())


def test_thresholds_and_too_small_pfa():
    frames = torch.arange(20.0).reshape(2, 2, 5)
    assert cfar_thresholds(frames, 0.1).tolist() == [8.0, 18.0]
    assert cfar_thresholds(frames, 0.01).isinf().all()  # floor(0.01 * 10) = 0: nothing passes
    assert int(cfar_binarize(frames, 0.01).sum()) == 0


def test_empty_batch_and_no_frames():
    assert cfar_binarize(torch.zeros(0, 3, 8, 8), 0.1).shape == (0, 3, 8, 8)
    assert cfar_binarize(torch.zeros(0, 8, 8), 0.1).shape == (0, 8, 8)


def test_module_matches_function():
    frames = torch.randn(2, 3, 16, 16)
    module = CFARBinarize(0.02)
    assert torch.equal(module(frames), cfar_binarize(frames, 0.02))
    assert "pfa=0.02" in repr(module)


@pytest.mark.parametrize("pfa", [0.0, 1.0, -0.1, 2.0, math.nan])
def test_bad_pfa(pfa):
    with pytest.raises(ValueError, match="`pfa`"):
        cfar_binarize(torch.zeros(2, 4, 4), pfa)
    with pytest.raises(ValueError, match="`pfa`"):
        CFARBinarize(pfa)


def test_bad_frames():
    with pytest.raises(ValueError, match="`frames`"):
        cfar_binarize(torch.zeros(4, 4), 0.1)
    with pytest.raises(ValueError, match=r"`frames`.*NaN"):
        cfar_binarize(torch.full((2, 4, 4), math.nan), 0.1)
    with pytest.raises(TypeError, match="`frames`"):
        cfar_binarize("frames", 0.1)

import numpy as np
import pytest
import torch

from hocnet._check import MAX_SEED, as_cube, check_seed
from hocnet.data.binary import simulate_binary


class TestCheckSeed:
    @pytest.mark.parametrize("seed", [0, 7, MAX_SEED])
    def test_valid(self, seed):
        assert check_seed("seed", seed) == seed
        torch.Generator().manual_seed(seed)  # the bound is torch's

    @pytest.mark.parametrize("seed", [2**64, 2**70])
    def test_too_large_names_seed(self, seed):
        with pytest.raises(
            ValueError, match=r"`seed`: expected an integer <= 18446744073709551615"
        ):
            check_seed("seed", seed)

    def test_simulate_binary_names_seed(self):
        # issue 9: simulate_binary(seed=2**70) failed inside torch without naming `seed`
        with pytest.raises(ValueError, match=r"^`seed`: "):
            simulate_binary((5, 8, 8), [], seed=2**70)


class TestAsCubeIntegers:
    @pytest.mark.parametrize("dtype", [np.uint16, np.uint32, np.uint64])
    def test_wide_unsigned_converted_exactly(self, dtype):
        top = int(np.iinfo(dtype).max) if dtype != np.uint64 else 2**63 - 1
        array = np.zeros((2, 3, 3), dtype=dtype)
        array[1, 1, 1] = top
        cube, batched = as_cube("frames", array)
        assert cube.dtype == torch.int64 and not batched
        assert int(cube[0, 1, 1, 1]) == top and int(cube.min()) == 0

    def test_uint64_above_int64_refused(self):
        # issue 9: a uint64 above 2**63 became a negative number and the DPA ran on it
        array = np.zeros((2, 3, 3), dtype=np.uint64)
        array[0, 0, 0] = 2**63 + 5
        with pytest.raises(
            ValueError, match=r"`frames`: expected integer values that fit in int64"
        ):
            as_cube("frames", array)
        with pytest.raises(ValueError, match=r"`frames`: .* 1 uint64 values above it"):
            as_cube("frames", torch.from_numpy(array))

    def test_binary_uint64(self):
        cube, _ = as_cube("cube", np.ones((2, 3, 3), dtype=np.uint64), binary=True)
        assert cube.dtype == torch.bool and bool(cube.all())


def test_min_frames_message_is_singular_for_one_frame():
    # new-user finding: "expected at least 1 frames"
    with pytest.raises(ValueError, match=r"at least 1 frame \(T\), got 0"):
        as_cube("cube", torch.zeros(0, 4, 4, dtype=torch.bool), binary=True)

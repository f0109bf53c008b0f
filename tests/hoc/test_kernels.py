import math

import pytest
import torch

from hocnet.hoc.kernels import (
    allowed_moves,
    get_direction_mask_kernels,
    get_shift_kernels,
    get_window_kernel,
    move_offsets,
    turn_angles,
)
from hocnet.hoc.reference import turn_reference


class TestMoveOffsets:
    def test_layout(self):
        moves = move_offsets(4)
        assert moves.shape == (81, 2)
        side = 9
        for m, (i, j) in enumerate(moves.tolist()):
            assert m == (j + 4) * side + (i + 4)
        assert moves[40].tolist() == [0, 0]

    @pytest.mark.parametrize("v", [0, -1])
    def test_bad_v(self, v):
        with pytest.raises(ValueError, match="`v`"):
            move_offsets(v)

    def test_type(self):
        with pytest.raises(TypeError, match="`v`"):
            move_offsets(1.5)


class TestTurnAngles:
    def test_matches_reference(self):
        moves = move_offsets(3)
        turns = turn_angles(moves[:, None], moves[None, :])
        for a, (i1, j1) in enumerate(moves.tolist()):
            for b, (i2, j2) in enumerate(moves.tolist()):
                assert turns[a, b].item() == pytest.approx(
                    turn_reference(i1, j1, i2, j2), abs=1e-12
                )

    def test_wraps(self):
        # 170 deg and -170 deg differ by 20 deg, not 340
        a = torch.tensor([-100, 17])
        b = torch.tensor([-100, -17])
        assert turn_angles(a, b).item() == pytest.approx(2 * math.atan2(17, 100))

    def test_zero_move_is_no_turn(self):
        assert turn_angles(torch.tensor([0, 0]), torch.tensor([-3, 1])).item() == 0.0


class TestAllowedMoves:
    def test_exact_45_degrees_pass(self):
        a = allowed_moves(4, math.pi / 4)
        moves = move_offsets(4).tolist()
        m1, m2 = moves.index([1, 0]), moves.index([2, 2])
        assert a[m1, m2]
        assert not a[m1, moves.index([1, 2])]  # 63.4 deg

    def test_float32_delta_still_passes_45(self):
        delta = float(torch.tensor(math.pi / 4, dtype=torch.float32))
        moves = move_offsets(2).tolist()
        assert allowed_moves(2, delta)[moves.index([1, 0]), moves.index([1, 1])]

    def test_zero_moves_always_allowed(self):
        a = allowed_moves(3, math.pi / 8)
        assert a[24].all() and a[:, 24].all()

    def test_pi_allows_everything(self):
        assert allowed_moves(2, math.pi).all()

    def test_none_is_no_curvature_constraint(self):
        assert torch.equal(allowed_moves(3, None), allowed_moves(3, math.pi))

    def test_quarter_of_window(self):
        a = allowed_moves(4, math.pi / 4)
        moving = torch.arange(81) != 40
        frac = a[moving].float().mean().item()
        assert 0.25 <= frac <= 0.3

    @pytest.mark.parametrize("delta", [0.0, -0.1, 3.2, float("nan")])
    def test_bad_delta(self, delta):
        with pytest.raises(ValueError, match="`delta`"):
            allowed_moves(2, delta)


class TestKernels:
    def test_mask_kernel_layout(self):
        k = get_direction_mask_kernels(2, math.pi / 4, dtype=torch.float64)
        a = allowed_moves(2, math.pi / 4)
        moves = move_offsets(2).tolist()
        assert k.shape == (25, 1, 5, 5) and k.dtype == torch.float64
        for m1 in range(25):
            for m2, (i2, j2) in enumerate(moves):
                assert k[m1, 0, j2 + 2, i2 + 2].item() == float(a[m1, m2])

    def test_shift_kernel_reads_ahead(self):
        s = get_shift_kernels(2)
        x = torch.zeros(1, 25, 7, 7)
        x[0, 25 - 1, 5, 5] = 1.0  # channel of move (2, 2), a point at (y, x) = (5, 5)
        out = torch.nn.functional.conv2d(x, s, padding=2)
        assert out[0, 0].nonzero().tolist() == [[3, 3]]  # read at p + (2, 2)

    def test_device_dtype(self):
        assert get_shift_kernels(1, dtype=torch.float16).dtype == torch.float16

    def test_window_kernel_sums_the_window(self):
        k = get_window_kernel(2, dtype=torch.float64)
        assert k.shape == (1, 1, 5, 5) and k.dtype == torch.float64 and bool((k == 1).all())
        x = torch.zeros(1, 1, 9, 9, dtype=torch.float64)
        x[0, 0, 4, 4] = 1.0
        out = torch.nn.functional.conv2d(x, k, padding=2)[0, 0]
        assert out.sum().item() == 25 and bool((out[2:7, 2:7] == 1).all())

    def test_window_kernel_bad_v(self):
        with pytest.raises(ValueError, match="`v`"):
            get_window_kernel(0)

import math

import pytest
import torch

from hocnet.hoc import curvature_score, movement_score, point_score


class TestTableI:
    """Table I of [LA98]: A1 = 9, alpha1 = 0.5, A2 = 2.356, alpha2 = 1.91."""

    def test_straight(self):
        assert movement_score(1, 0, 1, 0, A1=9, alpha1=0.5) == 4.5
        assert round(curvature_score(1, 0, 1, 0, A2=2.356, alpha2=1.91), 1) == 4.5

    def test_right_angle(self):
        assert movement_score(1, 0, 0, 1, A1=9, alpha1=0.5) == 3.5
        assert round(curvature_score(1, 0, 0, 1, A2=2.356, alpha2=1.91), 1) == 1.5


class TestMovementScore:
    def test_formula(self):
        assert movement_score(2, 1, 3, -1) == pytest.approx((9 - (1 + 4)) / 3)

    def test_broadcast_tensors(self):
        i2 = torch.tensor([[1], [2]])
        out = movement_score(1, 0, i2, torch.tensor([0, 1, 2]))
        assert out.shape == (2, 3)
        assert out[1, 2].item() == pytest.approx((9 - 1 - 4) / 3)

    def test_bad_constant(self):
        with pytest.raises(ValueError, match="`A1`"):
            movement_score(1, 0, 1, 0, A1=float("inf"))


class TestCurvatureScore:
    def test_zero_move_is_straight(self):
        assert curvature_score(0, 0, 3, 1) == pytest.approx(2 * 2.12)

    def test_opposite(self):
        assert curvature_score(1, 0, -1, 0) == pytest.approx(2 * (2.12 - math.pi))

    def test_bad_constant(self):
        with pytest.raises(TypeError, match="`alpha2`"):
            curvature_score(1, 0, 1, 0, alpha2="a")


class TestPointScore:
    def test_threshold_separates_gentle_from_sharp(self):
        assert point_score(3, 2, 3, 2) > 2.5
        assert point_score(1, 0, 1, 1) > 2.5
        assert point_score(1, 0, 0, 1) < 2.5
        assert point_score(3, 0, -3, 0) < 0

    def test_is_mean(self):
        m = movement_score(2, 1, 1, 2)
        c = curvature_score(2, 1, 1, 2)
        assert point_score(2, 1, 1, 2) == pytest.approx((m + c) / 2)

import math

import pytest
import torch

from hocnet.hoc import curvature_score, movement_score, point_score
from hocnet.hoc.reference import turn_reference
from hocnet.hoc.scoring import track_point_scores

TABLE_I = dict(A1=9, alpha1=0.5)
TABLE_I_C = dict(A2=2.356, alpha2=1.91)


class TestTableI:
    """Table I of [LA98] as printed: A1 = 9, alpha1 = 0.5, A2 = 2.356, alpha2 = 1.91."""

    @pytest.mark.parametrize(
        ("track", "m1", "m2", "velocity", "curvature"),
        [
            ("b", (1, 1), (1, 1), 4.5, 4.5),
            ("c", (1, -1), (1, -1), 4.5, 4.5),
            ("d", (1, 1), (1, -1), 3.5, 1.5),
            ("e", (1, -1), (1, 1), 3.5, 1.5),
        ],
    )
    def test_row(self, track, m1, m2, velocity, curvature):
        assert movement_score(*m1, *m2, **TABLE_I) == velocity, track
        # the table prints one decimal: 2.356 * 1.91 = 4.49996, (2.356 - pi/2) * 1.91 = 1.4998
        assert round(curvature_score(*m1, *m2, **TABLE_I_C), 1) == curvature, track


def movement_loop(i1, j1, i2, j2, A1=9.0, alpha1=1 / 3):
    """Eq. (8) written out."""
    return (A1 - abs(i2 - i1) - abs(j2 - j1)) * alpha1


class TestMovementScore:
    def test_is_l1_not_squared(self):
        # (2, 1) -> (3, -1): L1 change 1 + 2 = 3 (squared Euclidean would be 5)
        assert movement_score(2, 1, 3, -1) == pytest.approx((9 - 3) / 3)

    def test_against_loop_over_window(self):
        r = torch.arange(-4, 5)
        i1, j1, i2, j2 = torch.meshgrid(r, r, r, r, indexing="ij")
        fast = movement_score(i1, j1, i2, j2)
        gen = torch.Generator().manual_seed(0)
        for idx in torch.randint(0, fast.numel(), (200,), generator=gen):
            a, b, c, d = (int(x.reshape(-1)[idx]) for x in (i1, j1, i2, j2))
            assert float(fast.reshape(-1)[idx]) == pytest.approx(movement_loop(a, b, c, d))

    def test_broadcast_tensors(self):
        i2 = torch.tensor([[1], [2]])
        out = movement_score(1, 0, i2, torch.tensor([0, 1, 2]))
        assert out.shape == (2, 3)
        assert out[1, 2].item() == pytest.approx((9 - 1 - 2) / 3)

    def test_bad_constant(self):
        with pytest.raises(ValueError, match="`A1`"):
            movement_score(1, 0, 1, 0, A1=float("inf"))


class TestCurvatureScore:
    def test_zero_move_is_straight(self):
        assert curvature_score(0, 0, 3, 1) == pytest.approx(2 * 2.12)

    def test_opposite(self):
        assert curvature_score(1, 0, -1, 0) == pytest.approx(2 * (2.12 - math.pi))

    def test_against_reference_turn(self):
        for m1, m2 in [((3, 1), (2, 2)), ((-1, -3), (0, -3)), ((4, -4), (-4, -3))]:
            want = 2 * (2.12 - turn_reference(*m1, *m2))
            assert curvature_score(*m1, *m2) == pytest.approx(want)

    def test_bad_constant(self):
        with pytest.raises(TypeError, match="`alpha2`"):
            curvature_score(1, 0, 1, 0, alpha2="a")


class TestPointScore:
    def test_threshold_separates_gentle_from_sharp(self):
        assert point_score(3, 2, 3, 2) > 2.5
        assert point_score(1, 0, 1, 1) > 2.5
        assert point_score(1, 0, 0, 1) < 2.5
        assert point_score(3, 0, -3, 0) < 0

    @pytest.mark.parametrize("m1, m2", [((2, 1), (1, 2)), ((0, -3), (-1, -3)), ((1, 0), (0, 1))])
    def test_combinations(self, m1, m2):
        m = movement_score(*m1, *m2)
        c = curvature_score(*m1, *m2)
        assert point_score(*m1, *m2) == pytest.approx((m + c) / 2)
        assert point_score(*m1, *m2, combine="mean") == pytest.approx((m + c) / 2)
        assert point_score(*m1, *m2, combine="min") == pytest.approx(min(m, c))
        assert point_score(*m1, *m2, combine="sum") == pytest.approx(m + c)
        assert point_score(*m1, *m2, combine="movement") == pytest.approx(m)

    def test_min_on_tensors(self):
        i2, j2 = torch.tensor([1, 0]), torch.tensor([1, 1])
        out = point_score(torch.tensor([1, 1]), 0, i2, j2, combine="min")
        assert out.shape == (2,)
        want = min(movement_score(1, 0, 0, 1), curvature_score(1, 0, 0, 1))
        assert out[1].item() == pytest.approx(want)

    def test_bad_combine(self):
        with pytest.raises(ValueError, match="`combine`"):
            point_score(1, 0, 1, 0, combine="max")


class TestTrackPointScores:
    """``track_point_scores`` against a loop straight from its definition."""

    @staticmethod
    def _loop(points, span, combine):
        p = points.tolist()
        n = len(p)
        out = []
        for i in range(1, n - 1):
            s1, s2 = min(span, i), min(span, n - 1 - i)
            m1 = [(p[i][k] - p[i - s1][k]) / s1 for k in (1, 2)]  # (y, x)
            m2 = [(p[i + s2][k] - p[i][k]) / s2 for k in (1, 2)]
            out.append(float(point_score(m1[1], m1[0], m2[1], m2[0], combine=combine)))
        return out

    @pytest.mark.parametrize("span", [1, 2, 3])
    @pytest.mark.parametrize("combine", ["mean", "min"])
    def test_against_loop(self, span, combine):
        g = torch.Generator().manual_seed(span)
        for n in (0, 1, 2, 3, 5, 10):
            steps = torch.randint(-3, 4, (n, 2), generator=g)
            yx = torch.cumsum(steps, 0)
            pts = torch.cat([torch.arange(n)[:, None], yx], dim=1)
            got = track_point_scores(pts, span=span, combine=combine)
            assert got.shape == (max(n - 2, 0),)
            assert got.tolist() == pytest.approx(self._loop(pts, span, combine))

    def test_span_one_is_the_triple_score(self):
        pts = torch.tensor([[0, 0, 0], [1, 1, 2], [2, 1, 5], [3, 3, 7]])
        want = [point_score(2, 1, 3, 0, combine="min"), point_score(3, 0, 2, 2, combine="min")]
        assert track_point_scores(pts, combine="min").tolist() == pytest.approx(want)

    def test_alternating_moves_average_out(self):
        # velocity (1.5, 2.5): moves alternate (2, 3) / (1, 2): L1 change 2, scored 2.33
        pts = torch.tensor([[t, (5 * t + 1) // 2, (3 * t + 1) // 2] for t in range(10)])
        one = track_point_scores(pts, span=1, combine="min")
        two = track_point_scores(pts, span=2, combine="min")
        assert float(one.mean()) < 2.5 < float(two.mean())
        assert two[1:-1].tolist() == pytest.approx([3.0] * 6)

    def test_bad_input(self):
        with pytest.raises(ValueError, match="`points`"):
            track_point_scores(torch.zeros(4, 2))
        with pytest.raises(ValueError, match="`span`"):
            track_point_scores(torch.zeros(4, 3), span=0)

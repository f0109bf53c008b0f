"""Smoke and unit tests of experiments/hoc_table2_gap.py (the Table II 2.0 % gap measurements)."""

import math
import pathlib
import sys

import numpy as np
import pytest
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import load_script

from hocnet.hoc import mhoc_image
from hocnet.hoc.kernels import allowed_moves
from hocnet.hoc.reference import mhoc_image_reference


@pytest.fixture(scope="module")
def gap():
    return load_script("hoc_table2_gap.py")


def _track(n_t, h, w, start, velocity):
    f = np.zeros((n_t, h, w), dtype=bool)
    for t in range(n_t):
        f[t, (start[1] + t * velocity[1]) % h, (start[0] + t * velocity[0]) % w] = True
    return f


def _strict_loop(frames, allowed, v, length):
    """Obviously-correct reading: depth-first search over every chain of ``length`` points."""
    n_t, h, w = frames.shape
    moves = [(i, j) for j in range(-v, v + 1) for i in range(-v, v + 1)]
    out = np.zeros_like(frames)

    def extend(t, r, c, last, left, step):
        if left == 0:
            return True
        t1 = t + step
        for m, (i, j) in enumerate(moves):
            r1, c1 = r + j, c + i
            if 0 <= r1 < h and 0 <= c1 < w and frames[t1, r1, c1]:
                if (last is None or allowed[last, m]) and extend(t1, r1, c1, m, left - 1, step):
                    return True
        return False

    for step in (1, -1):
        for t, r, c in zip(*np.nonzero(frames), strict=True):
            if 0 <= t + (length - 1) * step < n_t and extend(t, r, c, None, length - 1, step):
                out[t, r, c] = True
    return out


def test_interface(gap):
    assert gap.NAME == "hoc-table2-gap"
    assert callable(gap.run) and callable(gap.main)
    assert gap.PAPER_MHOC_PCT[0.02] == 75.44


@pytest.mark.parametrize("v", [1, 2, 4])
def test_wedge_table_is_hocnets_eq6(gap, v):
    assert (gap.wedge_table(v, math.pi / 4) == allowed_moves(v, math.pi / 4).numpy()).all()


def test_wedge_readings_order(gap):
    # strict bounds and zero-with-zero shrink the window, tan^-1 literally (modulo pi) widens it
    sizes = {rule: gap.wedge_table(4, math.pi / 4, rule).sum() for rule in gap.WEDGE_RULES}
    assert sizes["exclusive"] < sizes["atan2"] < sizes["arctan"]
    assert sizes["zero-with-zero"] < sizes["atan2"]
    arctan = gap.wedge_table(1, math.pi / 4, "arctan")
    moves = gap.move_table(1).tolist()
    assert arctan[moves.index([1, 0]), moves.index([-1, 0])]  # a reversal passes modulo pi
    with pytest.raises(ValueError, match="`rule`"):
        gap.wedge_table(1, 0.5, "nope")


def test_mhoc_union_matches_loop_reference(gap):
    rng = np.random.default_rng(0)
    for _ in range(3):
        f = rng.random((6, 9, 10)) < 0.12
        ref = mhoc_image_reference(f, 2, v=1)
        assert (gap.mhoc_union(f, gap.wedge_table(1, math.pi / 4), v=1) == ref).all()


@pytest.mark.parametrize("density", [0.01, 0.04, 0.08])
def test_mhoc_union_matches_hocnet(gap, density):
    rng = np.random.default_rng(int(density * 1000))
    f = rng.random((10, 40, 50)) < density
    f |= _track(10, 40, 50, (5, 5), (3, 2))
    ours = gap.mhoc_union(f, gap.wedge_table(4, math.pi / 4))
    theirs = mhoc_image(torch.from_numpy(f), order=2, v=4, delta=math.pi / 4).numpy()
    assert (ours == theirs).all()


def test_borders(gap):
    a = gap.wedge_table(2, math.pi / 4)
    f = _track(10, 12, 20, (13, 6), (2, 0))  # leaves the frame on the right after scan 3
    assert gap.mhoc_union(f, a, v=2, border="wrap").sum() == 10  # torus: one 10-point track
    zero = gap.mhoc_union(f, a, v=2)
    # zero padding cuts it in two: 4 points (columns 13-19, fewer than five) and 6 points
    # (columns 1-11) of which forward Y^(2) keeps the first two and backward the last two
    assert not zero[:, :, 13:].any()
    assert zero.sum(axis=(1, 2)).nonzero()[0].tolist() == [4, 5, 8, 9]
    g = _track(10, 12, 20, (1, 6), (1, 0))  # starts at column 1, within v = 2 of the border
    assert gap.mhoc_union(g, a, v=2).sum() == 10
    valid = gap.mhoc_union(g, a, v=2, border="valid")
    assert valid.sum() < 10 and not valid[:, :, :2].any()


def test_threshold(gap):
    a = gap.wedge_table(1, math.pi / 4)
    f = _track(10, 8, 16, (1, 4), (1, 0))
    assert gap.mhoc_union(f, a, v=1).sum() == 10
    assert gap.mhoc_union(f, a, v=1, threshold=1).sum() == 0  # one pair per point: c = 1
    f2 = f | _track(10, 8, 16, (1, 3), (1, 0))  # a parallel neighbour: several pairs per point
    assert gap.mhoc_union(f2, a, v=1, threshold=1).sum() == 20


def test_strict_chain_matches_loop_and_is_stricter(gap):
    rng = np.random.default_rng(3)
    a = gap.wedge_table(1, math.pi / 4)
    for _ in range(3):
        f = rng.random((7, 8, 9)) < 0.2
        strict = gap.strict_chain_image(f, a, v=1)
        assert (strict == _strict_loop(f, a, 1, 5)).all()
        assert not (strict & ~gap.mhoc_union(f, a, v=1)).any()  # strict chains ⊆ eq. (5)
    line = _track(5, 6, 8, (1, 2), (1, 0))
    assert gap.strict_chain_image(line, a, v=1)[:, 2].nonzero()[0].tolist() == [0, 4]


def test_clutter_models(gap):
    rng = np.random.default_rng(1)
    shape = (3, 20, 30)
    exact = gap.clutter(rng, shape, 0.05, "exact")
    assert exact.reshape(3, -1).sum(1).tolist() == [30, 30, 30]
    assert (gap.clutter(rng, shape, 0.05, "replacement").reshape(3, -1).sum(1) <= 30).all()
    assert gap.clutter(rng, shape, 0.05).shape == shape
    with pytest.raises(ValueError, match="`model`"):
        gap.clutter(rng, shape, 0.05, "poisson")


def test_paper_arithmetic(gap):
    rows = {r["density"]: r for r in gap.paper_arithmetic()}
    # 1.1 %: 510 - 20 = 490 of 18280 - 20 = 18260 clutter points kept
    assert rows[0.011]["mhoc_recomputed"] == pytest.approx(100 * (1 - 490 / 18260))
    assert abs(rows[0.011]["mhoc_recomputed"] - 97.55) > 0.2
    for d in (0.008, 0.014, 0.017, 0.02):
        assert rows[d]["mhoc_recomputed"] == pytest.approx(gap.PAPER_MHOC_PCT[d], abs=0.006)
    assert rows[0.02]["count_density"] == pytest.approx(33060 / (10 * 320 * 520))


def test_implied_density(gap):
    curve = {0.01: [99.0, 99.0], 0.02: [80.0, 78.0], 0.03: [50.0]}
    assert gap.implied_density(curve, 79.0) == pytest.approx(0.02)
    assert gap.implied_density(curve, 64.5) == pytest.approx(0.025)
    assert math.isnan(gap.implied_density(curve, 99.5))


def test_quick_run_writes_nothing(gap, tmp_path, capsys):
    text = gap.run(quick=True, out_dir=tmp_path, progress=False)
    assert list(tmp_path.iterdir()) == []
    for section in ("## 1.", "## 2-3, 5.", "## 4.", "## 5."):
        assert section in text
    assert "`hocnet.hoc.mhoc_image` point for point on 1 of 1 scenes" in text
    assert "allowed_moves(4, pi/4)`: True" in text
    assert "| [LA98] as printed | 75.44 |" in text
    assert "| 1.1 % | 18260 |" in text
    assert "## 1." in capsys.readouterr().out


def test_main_rejects_bad_seeds(gap):
    with pytest.raises(ValueError, match="`seeds`"):
        gap.run(quick=True, seeds=0, progress=False)


@pytest.mark.slow
def test_full(gap, tmp_path):
    gap.run(out_dir=tmp_path, seeds=2, progress=False)
    assert (tmp_path / "hoc-table2-gap.md").is_file()

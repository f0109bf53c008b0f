"""Tests of hocnet.tracking.assignment: Murty's k-best against brute-force enumeration."""

from __future__ import annotations

import numpy as np
import pytest

from hocnet.tracking.assignment import (
    Assignment,
    brute_force_assignments,
    k_best_assignments,
)


def _random_cost(rng: np.random.Generator, n: int, m: int, p_forbid: float) -> np.ndarray:
    c = rng.normal(size=(n, m)).round(2)  # rounding creates ties
    c[rng.random((n, m)) < p_forbid] = np.inf
    return c


class TestKBestAssignments:
    @pytest.mark.parametrize("seed", range(40))
    def test_equals_brute_force(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        n, m = int(rng.integers(0, 5)), int(rng.integers(0, 6))
        c = _random_cost(rng, n, m, p_forbid=[0.0, 0.3, 0.6][seed % 3])
        ref = brute_force_assignments(c)
        k = int(rng.integers(1, 30))
        got = k_best_assignments(c, k)
        assert len(got) == min(k, len(ref))
        np.testing.assert_allclose([a.cost for a in got], [a.cost for a in ref[:k]], atol=1e-9)
        seen = set()
        for a in got:  # each is a valid, distinct assignment with the stated cost
            assert len(a.rows) == min(n, m)
            assert len(set(a.rows.tolist())) == len(a.rows) == len(set(a.cols.tolist()))
            vals = c[a.rows, a.cols]
            assert np.isfinite(vals).all()
            assert abs(vals.sum() - a.cost) < 1e-9
            key = tuple(zip(a.rows.tolist(), a.cols.tolist()))
            assert key not in seen
            seen.add(key)

    def test_all_solutions_enumerated(self) -> None:
        c = np.arange(12.0).reshape(3, 4)
        got = k_best_assignments(c, 1000)
        assert len(got) == 24 == len(brute_force_assignments(c))

    def test_tall_matrix_assigns_every_column(self) -> None:
        c = np.array([[1.0, 5.0], [2.0, 1.0], [0.0, 9.0]])
        best = k_best_assignments(c, 1)[0]
        assert best.cost == 1.0
        assert best.rows.tolist() == [1, 2] and best.cols.tolist() == [1, 0]

    def test_infeasible_and_empty(self) -> None:
        inf = np.inf
        assert k_best_assignments([[inf, inf], [0.0, 1.0]], 3) == []
        (empty,) = k_best_assignments(np.zeros((0, 3)), 5)
        assert isinstance(empty, Assignment) and empty.cost == 0.0 and empty.rows.size == 0

    @pytest.mark.parametrize(
        ("cost", "k", "err", "match"),
        [
            ([1.0, 2.0], 1, ValueError, "`cost`: expected a 2-D"),
            ([[np.nan]], 1, ValueError, "`cost`: expected finite"),
            ([[-np.inf]], 1, ValueError, "`cost`: expected finite"),
            ([["a"]], 1, TypeError, "`cost`"),
            ([[1.0]], 0, ValueError, "`k`"),
        ],
    )
    def test_bad_input(self, cost, k, err, match) -> None:
        with pytest.raises(err, match=match):
            k_best_assignments(cost, k)

"""Tests of hocnet.tracking.sprt: Wald's SPRT thresholds and the MHT track status they drive."""

from __future__ import annotations

import math

import pytest
import torch

from hocnet.tracking.mht import MHT, CVKalmanFilter
from hocnet.tracking.sprt import sprt_thresholds


class TestSPRT:
    def test_thresholds(self) -> None:
        ln_a, ln_b = sprt_thresholds(0.01, 0.1)
        assert ln_a == pytest.approx(math.log(0.1 / 0.99))
        assert ln_b == pytest.approx(math.log(0.9 / 0.01))
        mht = MHT(R=torch.eye(2), alpha=0.01, beta=0.1)
        assert (mht.log_a, mht.log_b) == (ln_a, ln_b)
        assert mht.drop == pytest.approx(ln_b - ln_a)

    @pytest.mark.parametrize(("alpha", "beta"), [(0.0, 0.1), (0.5, 0.5), (0.1, 1.0)])
    def test_bad_thresholds(self, alpha: float, beta: float) -> None:
        with pytest.raises(ValueError, match=r"`alpha`|`beta`"):
            sprt_thresholds(alpha, beta)

    def test_status_follows_the_score(self) -> None:
        """A perfect target: each detection adds ln(PD N / lambda_fa); confirm at ln B."""
        mht = MHT(
            CVKalmanFilter(sigma_a=0.0, velocity_std=1.0),
            R=torch.eye(2),
            pd=0.9,
            lambda_fa=1e-4,
            lambda_nt=1e-5,
            alpha=1e-6,
            beta=0.1,
        )
        statuses = []
        for k in range(6):
            mht.step(torch.tensor([[float(k), 0.0]]))
            leaf = max(mht._leaves, key=lambda lf: lf.score)  # the all-detections branch
            statuses.append((leaf.status, leaf.score))
        assert statuses[0] == ("tentative", pytest.approx(math.log(0.1)))
        scores = [s for _, s in statuses]
        assert scores == sorted(scores)
        for status, score in statuses:
            assert (status == "confirmed") == (score >= mht.log_b)
        assert statuses[-1][0] == "confirmed"
        assert [t.id for t in mht.tracks()] == [0]
        # then misses only: deleted once the score falls `drop` below its maximum
        n_miss = 0
        while mht.tracks():
            mht.step(torch.zeros(0, 2))
            n_miss += 1
        assert n_miss == math.ceil(mht.drop / -math.log(0.1))
        (ended,) = mht.all_tracks()
        assert ended.status == "deleted"

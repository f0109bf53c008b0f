"""Tests of hocnet.tracking.mht: the track-oriented SB-MHT of [PD] section 24.4.4."""

from __future__ import annotations

import math
from functools import partial

import numpy as np
import pytest
import torch

from hocnet.tracking.kalman import (
    constant_velocity,
    kalman_predict,
    kalman_update,
    mahalanobis2,
    stop_model,
)
from hocnet.tracking.mht import (
    MHT,
    CVKalmanFilter,
    IMMFilter,
    MHTTrack,
)

SIZE = 200.0  # side of the square surveillance region
H = torch.tensor([[1.0, 0, 0, 0], [0, 0, 1.0, 0]], dtype=torch.float64)


def simulate(
    starts: list[tuple[float, float, float, float]],
    n_scans: int,
    *,
    pd: float,
    clutter: float,
    sigma: float,
    seed: int,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Scans of CV targets ``(x, y, vx, vy)`` with Poisson clutter; labels -1 for clutter."""
    rng = np.random.default_rng(seed)
    scans, labels = [], []
    for k in range(n_scans):
        z, lab = [], []
        for i, (x, y, vx, vy) in enumerate(starts):
            if rng.random() < pd:
                z.append(np.array([x + vx * k, y + vy * k]) + rng.normal(0, sigma, 2))
                lab.append(i)
        n_c = rng.poisson(clutter)
        z.extend(rng.uniform(0, SIZE, (n_c, 2)))
        lab.extend([-1] * n_c)
        order = rng.permutation(len(z))
        scans.append(np.array(z, dtype=np.float64).reshape(-1, 2)[order])
        labels.append(np.array(lab, dtype=np.int64)[order])
    return scans, labels


def run(mht: MHT, scans: list[np.ndarray]) -> list[list[MHTTrack]]:
    return [mht.step(torch.from_numpy(z)) for z in scans]


def purity(track: MHTTrack, labels: list[np.ndarray]) -> tuple[int, float]:
    """Majority truth label of a track and the fraction of its detections from it."""
    lab = [int(labels[s][j]) for s, j in track.associations()]
    best = max(set(lab), key=lab.count)
    return best, lab.count(best) / len(lab)


def make_mht(**kw) -> MHT:
    defaults = dict(
        filter=CVKalmanFilter(sigma_a=0.1, velocity_std=3.0),
        R=torch.eye(2),
        pd=0.9,
        lambda_fa=10 / SIZE**2,
        lambda_nt=1 / SIZE**2,
    )
    defaults.update(kw)
    return MHT(**defaults)


class TestScenarios:
    @pytest.mark.parametrize("seed", range(4))
    def test_crossing_targets_with_clutter(self, seed: int) -> None:
        starts = [(40.0, 40.0, 4.0, 4.0), (40.0, 160.0, 4.0, -4.0)]  # cross at (100, 100), k=15
        scans, labels = simulate(starts, 30, pd=0.95, clutter=10, sigma=1.0, seed=seed)
        mht = make_mht(lambda_fa=10 / SIZE**2, pd=0.95)
        run(mht, scans)
        tracks = mht.all_tracks()
        owners: dict[int, list[float]] = {}
        for t in tracks:
            label, p = purity(t, labels)
            owners.setdefault(label, []).append(p)
        assert sorted(k for k in owners if k >= 0) == [0, 1]
        assert len(owners[0]) == len(owners[1]) == 1  # one confirmed track per truth
        assert min(owners[0] + owners[1]) >= 0.9
        assert -1 not in owners  # no confirmed clutter track
        for t in mht.tracks():  # both alive at the end, covering the whole run
            assert len(t.associations()) >= 25

    @pytest.mark.parametrize("initial_score", ["log_odds", "printed"])
    @pytest.mark.parametrize("seed", range(5))
    def test_single_target_confirmed_and_kept(self, seed: int, initial_score: str) -> None:
        scans, labels = simulate([(20, 30, 3, 2)], 40, pd=0.9, clutter=3, sigma=1.0, seed=seed)
        mht = make_mht(initial_score=initial_score)
        history = run(mht, scans)
        first = next(k for k, tr in enumerate(history) if tr)
        seen = [bool((lab == 0).any()) for lab in labels]
        run_end = next(k for k in range(2, 40) if all(seen[k - 2 : k + 1]))
        assert first <= run_end + 3  # within 3 scans of the first 3 consecutive detections
        if all(seen[:4]):
            assert first <= 3
        ids = {tuple(t.id for t in tr) for tr in history[first:]}
        assert len(ids) == 1 and len(next(iter(ids))) == 1  # the same single track to the end
        (track,) = history[-1]
        label, p = purity(track, labels)
        assert label == 0 and p == 1.0

    def test_pure_clutter_gives_no_confirmed_track(self) -> None:
        for seed in range(6):
            scans, _ = simulate([], 30, pd=0.9, clutter=10, sigma=1.0, seed=100 + seed)
            mht = make_mht()
            history = run(mht, scans)
            assert all(not tr for tr in history)
            assert mht.all_tracks() == []

    def test_imm_filter_plugs_in(self) -> None:
        starts = [(40.0, 40.0, 4.0, 4.0), (40.0, 160.0, 4.0, -4.0)]
        scans, labels = simulate(starts, 30, pd=0.95, clutter=5, sigma=1.0, seed=7)
        imm = IMMFilter(
            [stop_model, partial(constant_velocity, sigma_a=0.1)],
            [[0.9, 0.1], [0.05, 0.95]],
            initial_mu=[0.1, 0.9],
            stop_mode=0,
            velocity_std=3.0,
        )
        mht = make_mht(filter=imm, pd=0.95, lambda_fa=5 / SIZE**2)
        run(mht, scans)
        found = sorted(purity(t, labels) for t in mht.all_tracks())
        assert [lab for lab, _ in found] == [0, 1]
        assert min(p for _, p in found) >= 0.9


class TestPruning:
    def test_n_scan_pruning_bounds_the_tree(self) -> None:
        starts = [(40.0, 40.0, 4.0, 4.0), (40.0, 160.0, 4.0, -4.0), (100, 20, 0, 6)]
        scans, _ = simulate(starts, 25, pd=0.9, clutter=20, sigma=1.5, seed=3)
        sizes = {}
        for n_scan in (0, 2, 6):
            mht = make_mht(lambda_fa=20 / SIZE**2, n_scan=n_scan, merge_scans=0)
            peak = 0
            for z in scans:
                mht.step(torch.from_numpy(z))
                peak = max(peak, mht.n_leaves)
                # every cluster holds at most n_hypotheses hypotheses
                assert all(len(c.hyps) <= mht.n_hypotheses for c in mht._clusters)
                # the defining property: leaves of a family agree on scans <= k - n_scan
                cut = mht.scan - 1 - n_scan
                prefixes: dict[int, set] = {}
                for leaf in mht._leaves:
                    if leaf.birth <= cut:
                        prefixes.setdefault(leaf.family, set()).add(
                            leaf.history[: cut - leaf.birth + 1]
                        )
                assert all(len(p) == 1 for p in prefixes.values())
            sizes[n_scan] = peak
        assert sizes[0] <= sizes[2] <= sizes[6]

    def test_road_section_keeps_best_branch_per_section(self) -> None:
        """With a ``section`` state key, each section's best branch survives N-scan pruning."""

        class SectionCV(CVKalmanFilter):
            def initiate(self, z, R):
                s = super().initiate(z, R)
                s["section"] = (s["x"][:, 2] > 0).long()
                return s

            def update(self, states, z, R):
                s, ll = super().update(states, z, R)
                s["section"] = (s["x"][:, 2] > 0).long()
                return s, ll

        # a target at y = 0 seen twice per scan (y = +-0.8): two branches on two "sections"
        scans = [np.array([[float(k), 0.8], [float(k), -0.8]]) for k in range(8)]
        plain = make_mht(n_scan=1, merge_scans=0, n_hypotheses=50)
        road = make_mht(filter=SectionCV(0.1, 3.0), n_scan=1, merge_scans=0, n_hypotheses=50)
        for z in scans:
            plain.step(torch.from_numpy(z))
            road.step(torch.from_numpy(z))

        def sections_of_family(mht: MHT) -> dict[int, set]:
            out: dict[int, set] = {}
            sec = mht._states.get("section")
            for i, leaf in enumerate(mht._leaves):
                key = leaf.history[: max(0, mht.scan - 1 - 1 - leaf.birth + 1)]
                out.setdefault(leaf.family, set()).add((key, None if sec is None else int(sec[i])))
            return out

        fam_plain = sections_of_family(plain)
        fam_road = sections_of_family(road)
        assert max(len({k for k, _ in v}) for v in fam_plain.values()) == 1
        assert max(len({k for k, _ in v}) for v in fam_road.values()) >= 2

        # section_distance: the other section's branch is kept only near the family's best leaf
        # (the two branches here are about 1.6 apart)
        counts = {}
        for dist in (0.5, 100.0):
            mht = make_mht(
                filter=SectionCV(0.1, 3.0),
                n_scan=1,
                merge_scans=0,
                n_hypotheses=50,
                section_distance=dist,
            )
            for z in scans:
                mht.step(torch.from_numpy(z))
            counts[dist] = max(len({k for k, _ in v}) for v in sections_of_family(mht).values())
        assert counts == {0.5: 1, 100.0: 2}
        with pytest.raises(ValueError, match="section_distance"):
            make_mht(section_distance=-1.0)

    def test_merging_removes_duplicates(self) -> None:
        starts = [(40.0, 40.0, 4.0, 4.0)]
        scans, _ = simulate(starts, 15, pd=1.0, clutter=0, sigma=0.5, seed=0)
        a = make_mht(merge_scans=2, n_scan=10, n_hypotheses=20)
        b = make_mht(merge_scans=0, n_scan=10, n_hypotheses=20)
        run(a, scans)
        run(b, scans)
        assert a.n_leaves <= b.n_leaves
        assert [t.measurements for t in a.tracks()] == [t.measurements for t in b.tracks()]

    @pytest.mark.parametrize("seed", range(3))
    def test_merging_keeps_close_targets(self, seed: int) -> None:
        """Two targets a few sigma apart for several scans: merging must keep both tracks.

        Reproduces the bug of the cross-family merge (leaves of two target trees with the same
        recent measurements merged, every hypothesis holding both trees made inconsistent, the
        cluster emptied): with ``merge_scans=2`` both tracks must survive the close passage.
        """
        starts = [(40.0, 100.0, 4.0, 0.0), (40.0, 103.0, 4.0, 0.0)]
        scans, labels = simulate(starts, 25, pd=1.0, clutter=0, sigma=0.5, seed=seed)
        mht = make_mht(merge_scans=2, n_scan=3, n_hypotheses=10)
        history = run(mht, scans)
        assert len(history[-1]) == 2
        owners = sorted(purity(t, labels)[0] for t in mht.all_tracks())
        assert owners == [0, 1]
        assert min(len(h) for h in history[5:]) == 2  # never lost, not even for one scan


def _reference_tracks(scans, mht: MHT, sigma_a: float, v_std: float):
    """Every possible track (slow per-track loop over histories): (meas set, score)."""
    F_cache = {}
    out = []
    gamma = mht.gate_threshold
    for s0, z0 in enumerate(scans):
        for j0 in range(len(z0)):
            x = torch.tensor([z0[j0][0], 0.0, z0[j0][1], 0.0], dtype=torch.float64)
            P = torch.diag(torch.tensor([1.0, v_std**2, 1.0, v_std**2], dtype=torch.float64))
            stack = [(s0, x, P, mht.l_init, ((s0, j0),))]
            while stack:
                s, x, P, score, used = stack.pop()
                if s == len(scans) - 1:
                    out.append((frozenset(used), score))
                    continue
                if 1.0 not in F_cache:
                    F_cache[1.0] = constant_velocity(1.0, sigma_a)
                F, Q = F_cache[1.0]
                xp, Pp = kalman_predict(x, P, F, Q)
                stack.append((s + 1, xp, Pp, score + math.log(1 - mht.pd), used))
                for j, z in enumerate(scans[s + 1]):
                    z = torch.as_tensor(z, dtype=torch.float64)
                    S = H @ Pp @ H.T + torch.eye(2, dtype=torch.float64)
                    if float(mahalanobis2(z - H @ xp, S)) > gamma:
                        continue
                    xu, Pu, ll = kalman_update(xp, Pp, z, H, torch.eye(2))
                    inc = math.log(mht.pd) + float(ll) - math.log(mht.lambda_fa)
                    stack.append((s + 1, xu, Pu, score + inc, (*used, (s + 1, j))))
    return out


class TestAgainstBruteForce:
    @pytest.mark.parametrize("seed", range(3))
    def test_global_hypotheses_equal_enumeration(self, seed: int) -> None:
        """No pruning: the MHT's hypotheses are exactly all sets of compatible tracks."""
        rng = np.random.default_rng(seed)
        scans = [
            np.array([[0.0, 0.0], [3.0, 1.0]]) + rng.normal(0, 0.5, (2, 2)),
            np.array([[1.0, 0.5], [3.5, 0.0], [2.0, 4.0]]) + rng.normal(0, 0.5, (3, 2)),
            np.array([[2.0, 1.0]]) + rng.normal(0, 0.5, (1, 2)),
        ]
        sigma_a, v_std = 0.5, 1.0
        mht = MHT(
            CVKalmanFilter(sigma_a, v_std),
            R=torch.eye(2),
            pd=0.8,
            lambda_fa=0.05,
            lambda_nt=0.01,
            alpha=1e-12,
            beta=1e-12,
            gate_probability=0.99,
            n_hypotheses=100000,
            hypothesis_ratio=None,
            n_scan=100,
            merge_scans=0,
        )
        for z in scans:
            mht.step(torch.from_numpy(z))
        # joint hypotheses: product over clusters
        got = [0.0]
        for cluster in mht.hypotheses():
            got = [a + s for a in got for s, _ in cluster]
        tracks = _reference_tracks(scans, mht, sigma_a, v_std)
        ref = []
        n = len(tracks)

        # all sets of pairwise-disjoint tracks (depth-first over track indices)
        def extend(start, used, score):
            ref.append(score)
            for i in range(start, n):
                meas, s = tracks[i]
                if not (meas & used):
                    extend(i + 1, used | meas, score + s)

        extend(0, frozenset(), 0.0)
        assert len(got) == len(ref)
        np.testing.assert_allclose(sorted(got), sorted(ref), rtol=1e-9, atol=1e-9)


class TestTypeAttribute:
    def test_type_term_is_log_pignistic(self) -> None:
        from hocnet.tracking.belief import observed_bba, pcr5, pignistic

        C = torch.diag(torch.tensor([0.8, 0.7, 0.9], dtype=torch.float64))
        kw = dict(R=torch.eye(2), pd=0.9, lambda_fa=1e-2, lambda_nt=1e-3, merge_scans=0)
        with_type = MHT(CVKalmanFilter(0.0, 1.0), **kw)
        without = MHT(CVKalmanFilter(0.0, 1.0), type_term=None, **kw)
        declared = [0, 2]
        for k, c in enumerate(declared):
            bba = observed_bba(C, torch.tensor([c]))
            for m in (with_type, without):
                m.step(torch.tensor([[float(k), 0.0]]), bba=bba)

        def branch(m: MHT) -> tuple[float, torch.Tensor]:  # the track on both reports
            (i,) = [i for i, lf in enumerate(m._leaves) if lf.history == (0, 0)]
            return m._leaves[i].score, m._bba[i]

        (sa, ba), (sb, _) = branch(with_type), branch(without)
        m1 = observed_bba(C, torch.tensor([0]))
        upd = pcr5(m1, observed_bba(C, torch.tensor([2])))
        assert sa - sb == pytest.approx(math.log(float(pignistic(upd).max())))
        torch.testing.assert_close(ba, upd[0])


class TestBadInput:
    def test_messages(self) -> None:
        mht = MHT(R=torch.eye(2))
        with pytest.raises(ValueError, match="`z`"):
            mht.step(torch.tensor([[float("nan"), 0.0]]))
        with pytest.raises(ValueError, match=r"`z`: expected shape \(M, 2\)"):
            mht.step(torch.zeros(3, 3))
        with pytest.raises(ValueError, match="`R`"):
            mht.step(torch.zeros(1, 2), R=-torch.eye(2))
        with pytest.raises(ValueError, match="`bba`"):
            mht.step(torch.zeros(1, 2), bba=torch.ones(2, 4) / 4)
        mht.step(torch.zeros(1, 2), time=5.0)
        with pytest.raises(ValueError, match="`time`"):
            mht.step(torch.zeros(1, 2), time=4.0)
        with pytest.raises(ValueError, match="`R`: expected a measurement noise"):
            MHT().step(torch.zeros(1, 2))
        with pytest.raises(ValueError, match="`initial_score`"):
            MHT(initial_score="zero")
        with pytest.raises(ValueError, match="`pd`"):
            MHT(pd=0.0)

    def test_empty_scans(self) -> None:
        mht = MHT(R=torch.eye(2))
        for _ in range(3):
            assert mht.step(torch.zeros(0, 2)) == []
        assert mht.n_leaves == 0 and mht.all_tracks() == []


def test_leaf_states_are_float64_and_batched() -> None:
    mht = make_mht()
    scans, _ = simulate([(20, 30, 3, 2), (100, 100, -2, 1)], 6, pd=1.0, clutter=2, sigma=1, seed=1)
    run(mht, scans)
    assert mht._states["x"].dtype == torch.float64
    assert mht._states["x"].shape == (mht.n_leaves, 4)
    for t in mht.tracks():
        assert t.state.shape == (4,) and t.covariance.shape == (4, 4)
        assert 0.0 < t.probability <= 1.0 + 1e-12


class TestGate:
    @pytest.mark.parametrize("seed", range(5))
    def test_sorted_gate_equals_dense_gate(self, seed: int) -> None:
        """The candidate search (sorted x, box) + ellipse equals kalman.gate on every pair."""
        from hocnet.tracking.kalman import gate

        g = torch.Generator().manual_seed(seed)
        n, m = 40, 60
        zp = torch.rand(n, 2, generator=g, dtype=torch.float64) * 50
        a = torch.randn(n, 2, 2, generator=g, dtype=torch.float64)
        hph = a @ a.transpose(-1, -2) * 4 + 0.1 * torch.eye(2, dtype=torch.float64)
        z = torch.rand(m, 2, generator=g, dtype=torch.float64) * 50
        b = torch.randn(m, 2, 2, generator=g, dtype=torch.float64)
        R = b @ b.transpose(-1, -2) + 0.5 * torch.eye(2, dtype=torch.float64)
        mht = MHT(R=torch.eye(2), gate_probability=0.99)
        l_idx, j_idx = mht._gate(zp, hph, z, R)
        dense = gate(z[None] - zp[:, None], hph[:, None] + R[None], mht.gate_threshold)
        ref_l, ref_j = dense.nonzero(as_tuple=True)
        assert l_idx.tolist() == ref_l.tolist() and j_idx.tolist() == ref_j.tolist()
        assert len(l_idx) > 0


class TestFilters:
    def _imm(self, stop_mode=None):
        return IMMFilter(
            [
                stop_model,
                partial(constant_velocity, sigma_a=0.1),
                partial(constant_velocity, sigma_a=1.0),
            ],
            [[0.8, 0.15, 0.05], [0.1, 0.85, 0.05], [0.02, 0.18, 0.8]],
            initial_mu=[0.2, 0.5, 0.3],
            stop_mode=stop_mode,
            velocity_std=2.0,
        )

    def test_imm_filter_equals_imm_step(self) -> None:
        """Predict + update of IMMFilter is one plain IMM cycle of hocnet.tracking.imm_step."""
        from hocnet.tracking.imm import imm_step

        f = self._imm()
        g = torch.Generator().manual_seed(0)
        z0 = torch.rand(5, 2, generator=g, dtype=torch.float64) * 10
        R = torch.eye(2, dtype=torch.float64).repeat(5, 1, 1) * 0.7
        s = f.initiate(z0, R)
        s["mu"] = torch.softmax(torch.randn(5, 3, generator=g, dtype=torch.float64), -1)
        s["x"] = s["x"] + torch.randn(5, 3, 4, generator=g, dtype=torch.float64)
        z = z0 + torch.randn(5, 2, generator=g, dtype=torch.float64)
        dt = 2.0
        upd, ll = f.update(f.predict(s, dt), z, R)
        F = torch.stack([m(dt)[0] for m in f.models])
        Q = torch.stack([m(dt)[1] for m in f.models])
        ref = imm_step(s["mu"], s["x"], s["P"], f.trans, F, Q, z, H, R[0])
        torch.testing.assert_close(upd["mu"], ref.mu)
        torch.testing.assert_close(upd["x"], ref.x)
        torch.testing.assert_close(f.mean_cov(upd)[0], ref.x_comb)
        torch.testing.assert_close(ll, ref.log_likelihood)

    def test_stop_mode_likelihoods(self) -> None:
        """24.30-24.31: a miss has likelihood cbar_0 + (1 - cbar_0)(1 - PD); a detection none
        under the stop model."""
        f = self._imm(stop_mode=0)
        s = f.predict(f.initiate(torch.zeros(2, 2), torch.eye(2).repeat(2, 1, 1)), 1.0)
        cbar = s["mu"]
        after, log_miss = f.miss(s, 0.9)
        expected = torch.log(cbar[:, 0] + (1 - cbar[:, 0]) * 0.1)
        torch.testing.assert_close(log_miss, expected)
        torch.testing.assert_close(after["mu"][:, 0], cbar[:, 0] / expected.exp())
        upd, _ = f.update(s, torch.ones(2, 2, dtype=torch.float64), torch.eye(2).repeat(2, 1, 1))
        assert float(upd["mu"][:, 0].abs().max()) == 0.0


class TestReviewFixes:
    """Findings 1 and 4 of the tracking review (stop model, declared type, missed_pd, SPRT)."""

    @staticmethod
    def _imm(**kw) -> IMMFilter:
        return IMMFilter(
            [stop_model, partial(constant_velocity, sigma_a=0.5)],
            [[0.9, 0.1], [0.1, 0.9]],
            initial_mu=[0.98, 0.02],
            stop_mode=0,
            **kw,
        )

    def test_imm_filter_stop_mode_seen_by_imagery(self) -> None:
        R = torch.eye(2, dtype=torch.float64).expand(1, 2, 2)
        z = torch.zeros(1, 2, dtype=torch.float64)
        out = {}
        for sd in (False, True):
            f = self._imm(stop_detectable=sd)
            pred = f.predict(f.initiate(z, R), 1.0)
            new, ll = f.update(pred, z, R)
            # reference: 24.30-24.32 with PD factored out, straight from the equations
            lik = [
                math.exp(float(_gauss(pred["x"][0, i], pred["P"][0, i], z[0], R[0])))
                for i in range(2)
            ]
            cbar = pred["mu"][0].tolist()
            lam = [lik[0] if sd else 0.0, lik[1]]
            tot = sum(a * b for a, b in zip(lam, cbar))
            assert float(ll[0]) == pytest.approx(math.log(tot), rel=1e-12)
            np.testing.assert_allclose(
                new["mu"][0].numpy(), [a * b / tot for a, b in zip(lam, cbar)]
            )
            _, lm = f.miss(pred, 0.9)
            lam_miss = [0.1 if sd else 1.0, 0.1]
            assert float(lm[0]) == pytest.approx(
                math.log(sum(a * b for a, b in zip(lam_miss, cbar))), rel=1e-12
            )
            out[sd] = float(new["mu"][0, 0])
        assert out[False] == 0.0 and out[True] > 0.9  # a stopped track stays stopped on video

    def test_step_sets_stop_detectable(self) -> None:
        f = self._imm()
        mht = MHT(f, R=torch.eye(2))
        mht.step(torch.zeros(1, 2), stop_detectable=True)
        assert f.stop_detectable is True
        with pytest.raises(ValueError, match="`stop_detectable`"):
            MHT(R=torch.eye(2)).step(torch.zeros(1, 2), stop_detectable=True)

    def test_declared_type_uses_type_likelihood_with_mapping(self) -> None:
        from hocnet.tracking.belief import pcr5, pignistic, type_likelihood

        # common frame {t0, t1, t2}; a GMTI-like sensor with classes {t0, t1} -> 0, {t2} -> 1
        mapping = [0, 0, 1]
        b1 = torch.zeros(1, 8, dtype=torch.float64)
        b1[0, 0b011], b1[0, 0b111] = 0.9, 0.1  # declares GMTI class 0 = {t0, t1}
        kw = dict(R=torch.eye(2), pd=0.9, lambda_fa=1e-2, lambda_nt=1e-3, merge_scans=0)
        fixed = MHT(CVKalmanFilter(0.0, 1.0), type_term="declared", **kw)
        legacy = MHT(CVKalmanFilter(0.0, 1.0), type_term="declared", **kw)
        without = MHT(CVKalmanFilter(0.0, 1.0), type_term=None, **kw)
        for k in range(2):
            z = torch.tensor([[float(k), 0.0]])
            fixed.step(z, bba=b1, declared=torch.tensor([0]), mapping=mapping)
            legacy.step(z, bba=b1)
            without.step(z, bba=b1)

        def score(m: MHT) -> float:
            return next(lf.score for lf in m._leaves if lf.history == (0, 0))

        upd = pcr5(b1, b1)
        want = math.log(float(type_likelihood(upd, torch.tensor([0]), mapping)[0]))
        assert score(fixed) - score(without) == pytest.approx(want, rel=1e-12)
        # the former reading (argmax of the report's BetP, a single fine class) is smaller
        old = math.log(float(pignistic(upd)[0, 0]))
        assert score(legacy) - score(without) == pytest.approx(old, rel=1e-12)
        assert want > old + 0.5
        with pytest.raises(ValueError, match="`declared`"):
            fixed.step(torch.zeros(1, 2), declared=torch.tensor([0]))

    def test_missed_pd_scores_every_miss_log_one_minus_pd(self) -> None:
        kw = dict(R=torch.eye(2), pd=0.9, merge_scans=0)
        a = MHT(self._imm(), missed_pd=0.9, **kw)
        b = MHT(self._imm(), **kw)
        for m in (a, b):
            m.step(torch.zeros(1, 2), time=0.0)
            m.step(torch.zeros(0, 2), time=1.0)
        (la,), (lb,) = a._leaves, b._leaves
        assert la.score == pytest.approx(a.l_init + math.log(0.1), rel=1e-12)
        assert lb.score > la.score + 1.0  # the stop mode explains the miss
        with pytest.raises(ValueError, match="`missed_pd`"):
            MHT(missed_pd=1.0)

    def test_default_sprt_survives_one_miss_after_birth(self) -> None:
        mht = MHT(R=torch.eye(2))  # default densities, PD, alpha, beta
        assert mht.l_init > mht.log_a  # a new track starts inside the SPRT's continuation band
        mht.step(torch.zeros(1, 2), time=0.0)
        mht.step(torch.zeros(0, 2), time=1.0)
        assert mht.n_leaves == 1 and mht._leaves[0].status == "tentative"
        mht.step(torch.zeros(0, 2), time=2.0)
        assert mht.n_leaves == 0  # two misses after birth delete


def _gauss(x: torch.Tensor, P: torch.Tensor, z: torch.Tensor, R: torch.Tensor) -> float:
    nu = (z - H @ x).numpy()
    S = (H @ P @ H.T + R).numpy()
    return -0.5 * (
        nu @ np.linalg.solve(S, nu) + math.log(np.linalg.det(S)) + 2 * math.log(2 * math.pi)
    )


class _SilentCV(CVKalmanFilter):
    """CV filter whose missed detections carry no information while ``silent`` (Delta L = 0)."""

    silent = False

    def miss(self, states, pd):
        st, log_miss = super().miss(states, pd)
        return (st, torch.zeros_like(log_miss)) if self.silent else (st, log_miss)


@pytest.mark.parametrize("hold", [True, False])
def test_uninformative_scan_does_not_delete_a_tentative_track(hold: bool) -> None:
    # issue 12: in the [PD] 24.6 run a new track is born below ln lower (beta = 0.1) and the
    # next scan is often a delayed UGS / video scan that cannot see it (Delta L = 0); it used
    # to delete every such track, so a lost target was never tracked again
    f = _SilentCV()
    kw = dict(R=torch.eye(2), pd=0.9, lambda_fa=1e-3, lambda_nt=1e-5, beta=0.1, merge_scans=0)
    mht = MHT(f, hold_uninformative=hold, **kw)
    assert mht.l_init < mht.log_a
    mht.step(torch.zeros(1, 2), time=0.0)
    f.silent = True
    mht.step(torch.zeros(0, 2), time=0.0)
    assert mht.n_leaves == (1 if hold else 0)
    if hold:
        f.silent = False
        mht.step(torch.zeros(1, 2), time=1.0)  # the next detection extends it
        assert any(leaf.history == (0, -1, 0) for leaf in mht._leaves)
        mht2 = MHT(_SilentCV(), hold_uninformative=True, **kw)
        mht2.step(torch.zeros(1, 2), time=0.0)
        mht2.step(torch.zeros(0, 2), time=1.0)  # an informative miss still deletes it
        assert mht2.n_leaves == 0


class TestStoppedTrackReport:
    """Issue 12 ([PD] 24.6, seed 2424): a passing track must not keep a stopped target's report.

    Target 10 stands at the origin (its own confirmed track; a constant-velocity filter, so the
    stop model's free miss of 24.31 plays no part: the test isolates the MHT's pruning, the
    mechanism of the seed); target 1 drives past it along ``y = 2``. On scan ``K0`` the
    sensor misses target 1 and sees target 10 at ``Z``, nearer to target 10's track than to
    target 1's. The best hypothesis gives ``Z`` to target 10; target
    1's leaf that took ``Z`` scores higher than its miss leaf on its own (a track score ignores
    that the report is taken from another family). Road sections (``x > 0.15``) put target 10's
    two leaves on two sections, so that the N-scan road-section exception keeps its miss leaf,
    as at the junction J3 of the seed.
    """

    K0 = 8
    Z = (0.5, 0.6)

    class SectionCV(CVKalmanFilter):
        def _sec(self, s):
            s["section"] = (s["x"][:, 0] > 0.15).long()
            return s

        def initiate(self, z, R):
            return self._sec(super().initiate(z, R))

        def predict(self, states, dt):
            return self._sec(super().predict(states, dt))

        def update(self, states, z, R):
            s, ll = super().update(states, z, R)
            return self._sec(s), ll

    def scans(self) -> tuple[list[np.ndarray], list[list[int]]]:
        z, lab = [], []
        for k in range(self.K0 + 4):
            a = (1.0 + 4.0 * (k - self.K0), 2.0)  # target 1, at x = 1 on scan K0
            if k < self.K0:
                z.append(np.array([a, (0.0, 0.0)]))
                lab.append([1, 10])
            elif k == self.K0:  # target 1 missed; target 10 seen at Z
                z.append(np.array([self.Z]))
                lab.append([10])
            else:  # both missed (k = K0 + 1, + 2: the cluster splits), then both seen
                z.append(np.array([a, (0.0, 0.0)]) if k == self.K0 + 3 else np.zeros((0, 2)))
                lab.append([1, 10] if k == self.K0 + 3 else [])
        return z, lab

    def run(self, **kw) -> tuple[MHT, list[list[int]]]:
        mht = make_mht(
            filter=self.SectionCV(sigma_a=0.1, velocity_std=3.0),
            R=0.25 * torch.eye(2),
            lambda_fa=1e-4,
            lambda_nt=1e-5,
            n_scan=1,
            merge_scans=0,
            n_hypotheses=10,
            **kw,
        )
        z, lab = self.scans()
        for zk in z:
            mht.step(torch.from_numpy(zk))
        return mht, lab

    def owners(self, mht: MHT, lab: list[list[int]]) -> dict[int, list[tuple[int, int]]]:
        """Per reported track: the (scan, target) of its measurements, from the truth labels."""
        out = {}
        for t in mht.tracks(include_tentative=True):
            out[t.id] = [(k, lab[k][j]) for k, j in enumerate(t.measurements, t.birth) if j >= 0]
        return out

    def test_mechanism_reproduced_with_the_former_pruning(self) -> None:
        mht, lab = self.run(section_best="leaf", split_links="window")
        owners = self.owners(mht, lab)
        holders = [tid for tid, ms in owners.items() if (self.K0, 10) in ms]
        # the former behaviour: both tracks hold target 10's report of scan K0
        assert len(holders) == 2
        assert any(g == 1 for tid in holders for _, g in owners[tid])

    @pytest.mark.parametrize(
        "kw",
        [{}, {"section_best": "other", "split_links": "window"}, {"section_best": "other"}],
    )
    def test_report_stays_with_the_stopped_target(self, kw: dict) -> None:
        mht, lab = self.run(**kw)
        owners = self.owners(mht, lab)
        assert len(owners) == 2
        for ms in owners.values():  # each track holds one target's reports only (the truth)
            assert len({g for _, g in ms}) == 1
        (t10,) = [ms for ms in owners.values() if ms[0][1] == 10]
        assert (self.K0, 10) in t10
        # and no measurement is held twice
        held = [
            (k, j)
            for t in mht.tracks(include_tentative=True)
            for k, j in enumerate(t.measurements, t.birth)
            if j >= 0
        ]
        assert len(held) == len(set(held))

    def test_bad_values(self) -> None:
        with pytest.raises(ValueError, match="section_best"):
            make_mht(section_best="score")
        with pytest.raises(ValueError, match="split_links"):
            make_mht(split_links="all")

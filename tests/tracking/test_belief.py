import numpy as np
import pytest
import torch
from evidencelib import Frame

from hocnet.tracking.belief import (
    conjunctive,
    dempster,
    from_dict,
    observed_bba,
    pcr5,
    pcr5_sources,
    pignistic,
    to_dict,
    vacuous,
)

ATOMS = ["a", "b", "c"]


def random_bba(rng: np.random.Generator, n: int, n_focal: int) -> torch.Tensor:
    """A random normal bba with `n_focal` non-empty focal sets."""
    m = np.zeros(2**n)
    focal = rng.choice(np.arange(1, 2**n), size=n_focal, replace=False)
    m[focal] = rng.dirichlet(np.ones(n_focal))
    return torch.tensor(m)


def to_evidencelib(frame: Frame, m: torch.Tensor, atoms: list[str]):
    values = {}
    for mask, v in enumerate(m.tolist()):
        if v > 0:
            values[
                frame.proposition([a for i, a in enumerate(atoms) if mask >> i & 1])
                if mask
                else frame.empty
            ] = v
    return frame.mass(values)


def from_evidencelib(frame: Frame, mass, atoms: list[str]) -> np.ndarray:
    out = np.zeros(2 ** len(atoms))
    for mask in range(2 ** len(atoms)):
        key = (
            frame.proposition([a for i, a in enumerate(atoms) if mask >> i & 1])
            if mask
            else frame.empty
        )
        out[mask] = mass.mass(key)
    return out


def zadeh():
    frame = ["M", "C", "T"]
    m1 = from_dict({frozenset("M"): 0.9, frozenset("T"): 0.1}, frame)
    m2 = from_dict({frozenset("C"): 0.9, frozenset("T"): 0.1}, frame)
    return m1, m2


class TestZadeh:
    def test_dempster_gives_all_to_minority(self):
        m1, m2 = zadeh()
        assert to_dict(dempster(m1, m2), ["M", "C", "T"], tol=1e-12) == {
            frozenset("T"): pytest.approx(1.0)
        }

    def test_pcr5_values(self):
        m1, m2 = zadeh()
        out = to_dict(pcr5(m1, m2), ["M", "C", "T"], tol=1e-12)
        # the values printed in the literature (evidencelib's examples/zadeh.py): .486 / .486 / .028
        assert out.keys() == {frozenset("M"), frozenset("C"), frozenset("T")}
        assert out[frozenset("M")] == pytest.approx(0.486, abs=1e-12)
        assert out[frozenset("C")] == pytest.approx(0.486, abs=1e-12)
        assert out[frozenset("T")] == pytest.approx(0.028, abs=1e-12)
        assert pcr5_sources(m1, m2).tolist() == pytest.approx(pcr5(m1, m2).tolist(), abs=1e-15)


class TestAgainstEvidencelib:
    @pytest.mark.parametrize("n", [2, 3, 4])
    def test_two_sources_random(self, n):
        rng = np.random.default_rng(n)
        atoms = [f"t{i}" for i in range(n)]
        frame = Frame.dst(atoms)
        for _ in range(15):
            m1 = random_bba(rng, n, rng.integers(1, 2**n))
            m2 = random_bba(rng, n, rng.integers(1, 2**n))
            e1, e2 = to_evidencelib(frame, m1, atoms), to_evidencelib(frame, m2, atoms)
            np.testing.assert_allclose(
                conjunctive(m1, m2).numpy(),
                from_evidencelib(frame, e1.conjunctive(e2), atoms),
                atol=1e-12,
            )
            np.testing.assert_allclose(
                pcr5(m1, m2).numpy(), from_evidencelib(frame, e1.pcr5(e2), atoms), atol=1e-12
            )
            np.testing.assert_allclose(
                pcr5_sources(m1, m2).numpy(), pcr5(m1, m2).numpy(), atol=1e-12
            )
            if conjunctive(m1, m2)[0] < 1 - 1e-9:
                np.testing.assert_allclose(
                    dempster(m1, m2).numpy(),
                    from_evidencelib(frame, e1.dempster(e2), atoms),
                    atol=1e-10,
                )
            betp = e1.pignistic()
            np.testing.assert_allclose(pignistic(m1).numpy(), [betp[a] for a in atoms], atol=1e-12)

    @pytest.mark.parametrize("s", [3, 4])
    def test_s_sources_random(self, s):
        rng = np.random.default_rng(10 + s)
        atoms = ATOMS
        frame = Frame.dst(atoms)
        for _ in range(8):
            ms = [random_bba(rng, 3, rng.integers(1, 5)) for _ in range(s)]
            es = [to_evidencelib(frame, m, atoms) for m in ms]
            expected = from_evidencelib(frame, es[0].pcr5(*es[1:]), atoms)
            np.testing.assert_allclose(pcr5_sources(*ms).numpy(), expected, atol=1e-12)

    def test_sequential_differs_from_joint(self):
        m1 = from_dict({frozenset("a"): 0.6, frozenset("b"): 0.4}, ATOMS)
        joint = pcr5_sources(m1, m1, m1)
        seq = pcr5(pcr5(m1, m1), m1)
        assert not torch.allclose(joint, seq)

    def test_batched_equals_loop(self):
        rng = np.random.default_rng(5)
        m1 = torch.stack([random_bba(rng, 3, 4) for _ in range(6)]).reshape(2, 3, 8)
        m2 = torch.stack([random_bba(rng, 3, 3) for _ in range(3)])  # broadcast over the first axis
        for fn in (conjunctive, pcr5, pcr5_sources):
            out = fn(m1, m2)
            assert out.shape == (2, 3, 8)
            for i in range(2):
                for j in range(3):
                    torch.testing.assert_close(out[i, j], fn(m1[i, j], m2[j]), rtol=0, atol=1e-14)
        p = pignistic(m1)
        assert p.shape == (2, 3, 3)
        torch.testing.assert_close(p.sum(-1), torch.ones(2, 3, dtype=torch.float64))
        assert pcr5(torch.zeros(0, 8), m2[0]).shape == (0, 8)


class TestTargetTypeTracker:
    def test_vacuous_is_neutral_for_pcr5(self):
        rng = np.random.default_rng(7)
        m = random_bba(rng, 3, 5)
        torch.testing.assert_close(pcr5(vacuous(3), m), m, rtol=0, atol=1e-15)

    def test_observed_bba_and_tracker_decision(self):
        C = torch.diag(torch.tensor([0.8, 0.7, 0.9]))  # the chapter's GMTI confusion diagonal
        obs = observed_bba(C, torch.tensor([0, 2, 1]))
        assert obs.shape == (3, 8)
        assert to_dict(obs[1], ATOMS) == {
            frozenset("c"): pytest.approx(0.9),
            frozenset("abc"): pytest.approx(0.1),
        }
        prior = vacuous(3)
        for c in [1, 1, 0, 1]:  # steps b-e of 24.5.2
            prior = pcr5(prior, observed_bba(C, torch.tensor(c)))
        assert int(pignistic(prior).argmax()) == 1

    def test_from_to_dict_round_trip(self):
        d = {frozenset("a"): 0.2, frozenset("bc"): 0.3, frozenset("abc"): 0.5}
        out = to_dict(from_dict(d, ATOMS), ATOMS)
        assert out == pytest.approx(d)


class TestErrors:
    def test_messages(self):
        good = vacuous(3)
        with pytest.raises(ValueError, match="`m1`: expected masses summing to 1"):
            pcr5(torch.full((8,), 0.5), good)
        with pytest.raises(ValueError, match="`m2`: expected a last axis of size 2\\*\\*n"):
            pcr5(good, torch.ones(3) / 3)
        with pytest.raises(ValueError, match="same frame"):
            conjunctive(good, vacuous(2))
        with pytest.raises(ValueError, match="empty set"):
            pcr5(torch.tensor([0.5, 0.5, 0, 0]), vacuous(1).new_tensor([0, 0, 0, 1]))
        with pytest.raises(ValueError, match="total conflict"):
            dempster(torch.tensor([0.0, 1, 0, 0]), torch.tensor([0.0, 0, 1, 0]))
        with pytest.raises(ValueError, match="`masses`: expected at least 2"):
            pcr5_sources(good)
        with pytest.raises(ValueError, match="`masses`"):
            from_dict({frozenset("z"): 1.0}, ATOMS)
        with pytest.raises(ValueError, match="`declared`"):
            observed_bba(torch.eye(3), torch.tensor([3]))
        with pytest.raises(TypeError, match="`declared`"):
            observed_bba(torch.eye(3), torch.tensor([1.0]))
        with pytest.raises(ValueError, match="`m`"):
            pignistic(torch.tensor([-0.5, 1.5]))

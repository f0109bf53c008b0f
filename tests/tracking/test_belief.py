import numpy as np
import pytest
import torch
from evidencelib import Frame

from hocnet.tracking.belief import (
    TypeFusion,
    coarsen,
    conjunctive,
    dempster,
    frame_mapping,
    from_dict,
    fuse_sensors,
    observed_bba,
    pcr5,
    pcr5_sources,
    pignistic,
    pignistic_coarse,
    refine,
    report_type_likelihood,
    to_dict,
    type_likelihood,
    vacuous,
)
from hocnet.tracking.scenario import GMTI_CLASSES, VIDEO_CLASSES, VIDEO_TO_GMTI

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

    def test_against_evidencelib(self):
        """Zadeh's example through evidencelib: PCR5 (two-source and s-source forms), Dempster."""
        m1, m2 = zadeh()
        atoms = ["M", "C", "T"]
        frame = Frame.dst(atoms)
        e1, e2 = to_evidencelib(frame, m1, atoms), to_evidencelib(frame, m2, atoms)
        expected = from_evidencelib(frame, e1.pcr5(e2), atoms)
        np.testing.assert_allclose(expected[[1, 2, 4]], [0.486, 0.486, 0.028], atol=1e-12)
        np.testing.assert_allclose(pcr5(m1, m2).numpy(), expected, atol=1e-12)
        np.testing.assert_allclose(pcr5_sources(m1, m2).numpy(), expected, atol=1e-12)
        np.testing.assert_allclose(
            dempster(m1, m2).numpy(), from_evidencelib(frame, e1.dempster(e2), atoms), atol=1e-12
        )


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


# --------------------------------------------------------------------------------------------
# frames of discernment ([PD] 24.5.3): slow references on {frozenset: mass} dicts
# --------------------------------------------------------------------------------------------

#: coarse GMTI class -> set of video classes, written from VIDEO_TO_GMTI by hand-free lookup
BLOCKS = {
    g: frozenset(v for v, gi in zip(VIDEO_CLASSES, VIDEO_TO_GMTI, strict=True) if gi == i)
    for i, g in enumerate(GMTI_CLASSES)
}


def ref_refine(d: dict, blocks: dict) -> dict:
    """Omega(A) = union of the images of A's elements; masses of sets with one image add."""
    out: dict = {}
    for a, v in d.items():
        b = frozenset().union(*(blocks[w] for w in a))
        out[b] = out.get(b, 0.0) + v
    return out


def ref_coarsen(d: dict, blocks: dict, kind: str) -> dict:
    """Shafer's outer / inner reduction of every focal set, straight from the definition."""
    out: dict = {}
    for b, v in d.items():
        if kind == "outer":
            a = frozenset(w for w, img in blocks.items() if img & b)
        else:
            a = frozenset(w for w, img in blocks.items() if img <= b)
        out[a] = out.get(a, 0.0) + v
    return out


def ref_pcr5(d1: dict, d2: dict) -> dict:
    """Eq. 24.44 on dicts: conjunctive consensus plus proportional redistribution of conflicts."""
    out: dict = {}
    for x, a in d1.items():
        for y, b in d2.items():
            inter = x & y
            if inter:
                out[inter] = out.get(inter, 0.0) + a * b
            elif a + b > 0:  # the conflict a b goes to x and y in proportion to a and b
                out[x] = out.get(x, 0.0) + a * a * b / (a + b)
                out[y] = out.get(y, 0.0) + b * b * a / (a + b)
    return out


def ref_betp(d: dict, atoms) -> list[float]:
    return [sum(v / len(x) for x, v in d.items() if a in x) for a in atoms]


def dict_close(got: dict, expected: dict, atol: float = 1e-12) -> None:
    keys = {k for k, v in got.items() if v > atol} | {k for k, v in expected.items() if v > atol}
    for k in keys:
        assert got.get(k, 0.0) == pytest.approx(expected.get(k, 0.0), abs=atol), sorted(k)


def random_normal(rng, n: int, n_focal: int) -> torch.Tensor:
    return random_bba(rng, n, min(n_focal, 2**n - 1))


class TestFrameMapping:
    def test_blocks_and_labels_agree(self):
        labels = frame_mapping(VIDEO_TO_GMTI, 3, 8)
        blocks = frame_mapping([[6], [0, 1, 2, 3, 4, 5], [7]], 3, 8)
        assert labels.tolist() == blocks.tolist() == [0b01000000, 0b00111111, 0b10000000]
        as_tensor = frame_mapping(torch.tensor(VIDEO_TO_GMTI), 3, 8)
        assert as_tensor.tolist() == labels.tolist()
        assert frame_mapping(np.array([1, 0]), 2, 2).tolist() == [2, 1]

    def test_errors(self):
        with pytest.raises(ValueError, match="`mapping`: expected every coarse class to map"):
            frame_mapping([0, 0, 0], 2, 3)  # coarse class 1 has no fine class
        with pytest.raises(ValueError, match="`mapping`: expected every coarse class"):
            frame_mapping([[0, 1, 2], []], 2, 3)
        with pytest.raises(ValueError, match="fine class 1 in two coarse classes"):
            frame_mapping([[0, 1], [1, 2]], 2, 3)
        with pytest.raises(ValueError, match="fine class 2 in no coarse class"):
            frame_mapping([[0], [1]], 2, 3)
        with pytest.raises(ValueError, match="`mapping\\[1\\]`: expected indices in \\[0, 3\\)"):
            frame_mapping([[0], [3]], 2, 3)
        with pytest.raises(ValueError, match="`mapping`: expected coarse labels in \\[0, 2\\)"):
            frame_mapping([0, 1, 2], 2, 3)
        with pytest.raises(ValueError, match="expected 3 coarse labels"):
            frame_mapping([0, 1], 2, 3)
        with pytest.raises(ValueError, match="expected 2 fine-index sets"):
            frame_mapping([[0], [1], [2]], 2, 3)
        with pytest.raises(TypeError, match="`mapping\\[1\\]`: expected an iterable"):
            frame_mapping([[0, 1], 2], 2, 3)
        with pytest.raises(TypeError, match="`mapping\\[0\\]`: expected integer"):
            frame_mapping([[0.0], [1, 2]], 2, 3)
        with pytest.raises(TypeError, match="`mapping`"):
            frame_mapping(torch.tensor([0.0, 1.0]), 2, 2)
        with pytest.raises(TypeError, match="`mapping`"):
            frame_mapping("ab", 2, 2)
        with pytest.raises(ValueError, match="`n_fine`"):
            frame_mapping([[0]], 1, 0)

    def test_non_partition_allowed_on_request(self):
        # overlapping images, fine class 3 unused: a multi-valued mapping
        assert frame_mapping([[0, 1], [1, 2]], 2, 4, partition=False).tolist() == [3, 6]


class TestRefine:
    def test_against_dict_reference_random(self):
        rng = np.random.default_rng(20)
        for _ in range(20):
            m = random_normal(rng, 3, int(rng.integers(1, 8)))
            got = to_dict(refine(m, VIDEO_TO_GMTI, 8), VIDEO_CLASSES)
            dict_close(got, ref_refine(to_dict(m, GMTI_CLASSES), BLOCKS))

    def test_total_mass_and_singletons(self):
        rng = np.random.default_rng(21)
        m = torch.stack([random_normal(rng, 3, 5) for _ in range(6)])
        out = refine(m, VIDEO_TO_GMTI, 8)
        assert out.shape == (6, 256)
        torch.testing.assert_close(out.sum(-1), m.sum(-1), rtol=0, atol=1e-14)
        assert bool((out[:, 0] == 0).all())
        # each coarse singleton {omega_i} goes to the set of its video classes
        for i, g in enumerate(GMTI_CLASSES):
            e = torch.zeros(8, dtype=torch.float64)
            e[1 << i] = 1.0
            assert to_dict(refine(e, VIDEO_TO_GMTI, 8), VIDEO_CLASSES) == {BLOCKS[g]: 1.0}
        torch.testing.assert_close(refine(vacuous(3), VIDEO_TO_GMTI, 8), vacuous(8))

    def test_hand_computed(self):
        # w0 -> {t0, t2}, w1 -> {t1}; m({w0}) = .5, m({w1}) = .2, m({w0, w1}) = .3
        m = torch.tensor([0.0, 0.5, 0.2, 0.3], dtype=torch.float64)
        out = refine(m, [[0, 2], [1]], 3)
        expected = torch.zeros(8, dtype=torch.float64)
        expected[0b101], expected[0b010], expected[0b111] = 0.5, 0.2, 0.3
        torch.testing.assert_close(out, expected, rtol=0, atol=0)
        # a multi-valued (overlapping) mapping: w0 -> {t0, t1}, w1 -> {t1, t2}
        out = refine(m, [[0, 1], [1, 2]], 3, partition=False)
        expected = torch.zeros(8, dtype=torch.float64)
        expected[0b011], expected[0b110], expected[0b111] = 0.5, 0.2, 0.3
        torch.testing.assert_close(out, expected, rtol=0, atol=0)

    def test_batched_equals_loop_and_empty(self):
        rng = np.random.default_rng(22)
        m = torch.stack([random_normal(rng, 3, 4) for _ in range(6)]).reshape(2, 3, 8)
        out = refine(m, VIDEO_TO_GMTI, 8)
        for i in range(2):
            for j in range(3):
                assert torch.equal(out[i, j], refine(m[i, j], VIDEO_TO_GMTI, 8))
        assert refine(torch.zeros(0, 8), VIDEO_TO_GMTI, 8).shape == (0, 256)

    def test_errors(self):
        with pytest.raises(ValueError, match="`m`: expected masses summing to 1"):
            refine(torch.full((8,), 0.5), VIDEO_TO_GMTI, 8)
        with pytest.raises(ValueError, match="`m`: expected a last axis of size 2\\*\\*n"):
            refine(torch.ones(3) / 3, VIDEO_TO_GMTI, 8)
        with pytest.raises(ValueError, match="`mapping`"):
            refine(vacuous(3), VIDEO_TO_GMTI, 9)  # 8 labels for 9 fine classes
        with pytest.raises(ValueError, match="`mapping`: expected a partition"):
            refine(vacuous(2), [[0, 1], [1, 2]], 3)


class TestCoarsen:
    @pytest.mark.parametrize("kind", ["outer", "inner"])
    def test_refine_then_coarsen_is_identity(self, kind):
        rng = np.random.default_rng(30)
        m = torch.stack([random_normal(rng, 3, int(rng.integers(1, 8))) for _ in range(25)])
        back = coarsen(refine(m, VIDEO_TO_GMTI, 8), VIDEO_TO_GMTI, 3, kind=kind)
        torch.testing.assert_close(back, m, rtol=0, atol=1e-15)

    @pytest.mark.parametrize("kind", ["outer", "inner"])
    def test_against_dict_reference_random(self, kind):
        rng = np.random.default_rng(31)
        blocks5 = [[0, 2], [1], [3, 4]]
        atoms5 = ["f0", "f1", "f2", "f3", "f4"]
        named5 = {w: frozenset(atoms5[j] for j in b) for w, b in zip("xyz", blocks5, strict=True)}
        for _ in range(15):
            m = random_normal(rng, 5, int(rng.integers(1, 20)))
            got = to_dict(coarsen(m, blocks5, 3, kind=kind), "xyz")
            dict_close(got, ref_coarsen(to_dict(m, atoms5), named5, kind))
            m8 = random_normal(rng, 8, int(rng.integers(1, 40)))
            got = to_dict(coarsen(m8, VIDEO_TO_GMTI, 3, kind=kind), GMTI_CLASSES)
            dict_close(got, ref_coarsen(to_dict(m8, VIDEO_CLASSES), BLOCKS, kind))

    def test_hand_computed(self):
        # fine {t0, t1 | t2}: m({t0}) = .4, m({t0, t2}) = .35, m({t0, t1}) = .25
        m = torch.zeros(8, dtype=torch.float64)
        m[0b001], m[0b101], m[0b011] = 0.4, 0.35, 0.25
        outer = coarsen(m, [[0, 1], [2]], 2)
        inner = coarsen(m, [[0, 1], [2]], 2, kind="inner")
        # outer: {t0} -> {w0}, {t0, t2} -> {w0, w1}, {t0, t1} -> {w0}
        torch.testing.assert_close(outer, torch.tensor([0.0, 0.65, 0.0, 0.35]).double())
        # inner: {t0} -> empty, {t0, t2} -> {w1}, {t0, t1} -> {w0}
        torch.testing.assert_close(inner, torch.tensor([0.4, 0.25, 0.35, 0.0]).double())

    def test_errors(self):
        with pytest.raises(ValueError, match="`kind`"):
            coarsen(vacuous(3), [[0, 1], [2]], 2, kind="middle")
        with pytest.raises(ValueError, match="`mapping`: expected a partition"):
            coarsen(vacuous(3), [[0, 1], [1, 2]], 2)
        with pytest.raises(ValueError, match="`mapping`: expected a partition"):
            coarsen(vacuous(3), [[0], [1]], 2)
        assert coarsen(torch.zeros(0, 4, 8), [[0, 1], [2]], 2).shape == (0, 4, 4)


def gmti_obs(declared: int) -> torch.Tensor:
    """GMTI observed bba (step b of 24.5.2) with the chapter's confusion diagonal (24.49)."""
    return observed_bba(torch.diag(torch.tensor([0.8, 0.7, 0.9])), torch.tensor(declared))


def video_obs(declared: int, p: float = 0.75) -> torch.Tensor:
    return observed_bba(torch.eye(8) * p, torch.tensor(declared))


class TestFuseSensors:
    def test_agreeing_gmti_and_video_concentrate_on_the_true_class(self):
        bus = VIDEO_CLASSES.index("civilian bus")
        wheeled = GMTI_CLASSES.index("wheeled vehicle")
        out = fuse_sensors([gmti_obs(wheeled), video_obs(bus)], [VIDEO_TO_GMTI, None], 8)
        assert isinstance(out, TypeFusion)
        assert out.m.shape == (256,) and out.betp.shape == (8,)
        # slow reference: refine by hand, 24.44 on dicts, 24.47 on dicts
        g = ref_refine(to_dict(gmti_obs(wheeled), GMTI_CLASSES), BLOCKS)
        v = to_dict(video_obs(bus), VIDEO_CLASSES)
        expected = ref_pcr5(g, v)
        dict_close(to_dict(out.m, VIDEO_CLASSES), expected)
        np.testing.assert_allclose(out.betp.numpy(), ref_betp(expected, VIDEO_CLASSES), atol=1e-12)
        assert int(out.betp.argmax()) == bus
        assert float(out.betp[bus]) > 0.75  # measured 0.7885
        assert float(out.betp[torch.arange(8) != bus].max()) < 0.05
        # the GMTI alone cannot tell the six wheeled classes apart (24.6.3); the video can
        alone = fuse_sensors([gmti_obs(wheeled)], [VIDEO_TO_GMTI], 8).betp
        wheeled_fine = [i for i, c in enumerate(VIDEO_TO_GMTI) if c == wheeled]
        assert torch.allclose(alone[wheeled_fine], alone[wheeled_fine[0]].expand(6))
        assert float(out.betp[bus]) > 4 * float(alone[bus])

    def test_conflicting_reports_against_reference(self):
        tracked = GMTI_CLASSES.index("tracked vehicle")
        car = VIDEO_CLASSES.index("civilian car")
        rng = np.random.default_rng(40)
        prior = random_normal(rng, 8, 12)
        out = fuse_sensors(
            [gmti_obs(tracked), video_obs(car)], [VIDEO_TO_GMTI, None], 8, prior=prior
        )
        p = to_dict(prior, VIDEO_CLASSES)
        g = ref_refine(to_dict(gmti_obs(tracked), GMTI_CLASSES), BLOCKS)
        v = to_dict(video_obs(car), VIDEO_CLASSES)
        expected = ref_pcr5(ref_pcr5(p, g), v)  # sequential: prior, then the sensors in order
        dict_close(to_dict(out.m, VIDEO_CLASSES), expected)
        np.testing.assert_allclose(out.betp.numpy(), ref_betp(expected, VIDEO_CLASSES), atol=1e-12)

    def test_scans_of_agreeing_reports(self):
        truck = VIDEO_CLASSES.index("civilian truck")
        m = vacuous(8)
        for _ in range(4):  # steps b-e of the TTT with both sensors each scan
            m = fuse_sensors(
                [gmti_obs(1), video_obs(truck, 0.5)], [VIDEO_TO_GMTI, None], 8, prior=m
            ).m
        betp = pignistic(m)
        assert int(betp.argmax()) == truck and float(betp[truck]) > 0.9

    def test_vacuous_and_missing_sensors_are_neutral(self):
        rng = np.random.default_rng(41)
        g = random_normal(rng, 3, 4)
        v = random_normal(rng, 8, 10)
        prior = random_normal(rng, 8, 6)
        ref = fuse_sensors([g, v], [VIDEO_TO_GMTI, None], 8, prior=prior)
        a = fuse_sensors([g, None, v], [VIDEO_TO_GMTI, None, None], 8, prior=prior)
        b = fuse_sensors([g, vacuous(3), v], [VIDEO_TO_GMTI, VIDEO_TO_GMTI, None], 8, prior=prior)
        torch.testing.assert_close(a.m, ref.m, rtol=0, atol=1e-14)
        torch.testing.assert_close(b.m, ref.m, rtol=0, atol=1e-14)
        # "joint" (small frame: the s-source PCR5 costs (2**n)**s) drops None and vacuous sources
        g2, v2, p2 = random_normal(rng, 2, 2), random_normal(rng, 3, 4), random_normal(rng, 3, 4)
        ref2 = fuse_sensors([g2, v2], [[0, 0, 1], None], 3, prior=p2, rule="joint")
        for obs in ([g2, None, v2], [g2, vacuous(2), v2]):
            out = fuse_sensors(obs, [[0, 0, 1], [0, 1, 1], None], 3, prior=p2, rule="joint")
            torch.testing.assert_close(out.m, ref2.m, rtol=0, atol=1e-15)
        # why "joint" drops vacuous sources: the s-source PCR5 is not neutral to them
        m1, m3 = random_normal(rng, 3, 4), random_normal(rng, 3, 4)
        assert not torch.allclose(pcr5_sources(m1, vacuous(3), m3), pcr5(m1, m3))
        out = fuse_sensors([m1, vacuous(3), m3], [None] * 3, 3, rule="joint")
        torch.testing.assert_close(out.m, pcr5(m1, m3), rtol=0, atol=1e-15)
        # nothing to fuse: the vacuous prior
        out = fuse_sensors([None], [None], 3)
        assert torch.equal(out.m, vacuous(3))

    def test_joint_rule_on_a_small_frame(self):
        rng = np.random.default_rng(42)
        for _ in range(5):
            prior = random_normal(rng, 3, 4)
            g, v = random_normal(rng, 2, 2), random_normal(rng, 3, 4)
            out = fuse_sensors([g, v], [[0, 0, 1], None], 3, prior=prior, rule="joint")
            expected = pcr5_sources(prior, refine(g, [0, 0, 1], 3), v)
            torch.testing.assert_close(out.m, expected, rtol=0, atol=1e-15)
            seq = fuse_sensors([g, v], [[0, 0, 1], None], 3, prior=prior)
            assert seq.m.shape == out.m.shape

    def test_batched_equals_loop(self):
        rng = np.random.default_rng(43)
        g = torch.stack([random_normal(rng, 3, 3) for _ in range(4)])  # (4, 8)
        v = random_normal(rng, 8, 5)  # broadcast
        out = fuse_sensors([g, v], [VIDEO_TO_GMTI, None], 8)
        assert out.m.shape == (4, 256) and out.betp.shape == (4, 8)
        for i in range(4):
            one = fuse_sensors([g[i], v], [VIDEO_TO_GMTI, None], 8)
            torch.testing.assert_close(out.m[i], one.m, rtol=0, atol=1e-15)
        empty = fuse_sensors([torch.zeros(0, 8)], [VIDEO_TO_GMTI], 8)
        assert empty.m.shape == (0, 256) and empty.betp.shape == (0, 8)

    def test_errors(self):
        with pytest.raises(ValueError, match="`mappings`: expected one mapping per observation"):
            fuse_sensors([vacuous(3)], [], 8)
        with pytest.raises(ValueError, match="`observations\\[0\\]`: expected a bba on the common"):
            fuse_sensors([vacuous(3)], [None], 8)
        with pytest.raises(ValueError, match="observations\\[1\\]: `mapping`"):
            fuse_sensors([vacuous(8), vacuous(3)], [None, [0, 1, 2]], 8)
        with pytest.raises(
            ValueError, match="`observations\\[0\\]`: expected no mass on the empty"
        ):
            fuse_sensors([torch.tensor([0.5, 0.5, 0, 0])], [None], 2)
        with pytest.raises(ValueError, match="`rule`"):
            fuse_sensors([vacuous(8)], [None], 8, rule="dempster")
        with pytest.raises(ValueError, match="`prior`"):
            fuse_sensors([vacuous(8)], [None], 8, prior=vacuous(3))
        with pytest.raises(TypeError, match="`observations`"):
            fuse_sensors(vacuous(8), [None], 8)


class TestTypeLikelihood:
    def test_frame_dependence_of_the_estimate_reading(self):
        # a track seen by the GMTI only: "wheeled" three times
        coarse = vacuous(3)
        for _ in range(3):
            coarse = pcr5(coarse, gmti_obs(1))
        fine = refine(coarse, VIDEO_TO_GMTI, 8)
        on_coarse = float(type_likelihood(coarse))
        on_fine = float(type_likelihood(fine))
        betp_c, betp_f = pignistic(coarse), pignistic(fine)
        assert on_coarse == pytest.approx(float(betp_c.max()))
        assert on_fine == pytest.approx(float(betp_f.max()))
        assert on_fine < on_coarse / 5  # about 1/6: six video classes share "wheeled"
        # declared reading: BetP of the image of the declared GMTI class
        declared = float(type_likelihood(fine, torch.tensor(1), VIDEO_TO_GMTI))
        assert declared == pytest.approx(
            float(betp_f[[i for i in range(8) if VIDEO_TO_GMTI[i] == 1]].sum())
        )
        assert declared == pytest.approx(float(pignistic_coarse(fine, VIDEO_TO_GMTI, 3)[1]))

    def test_declared_against_dict_reference(self):
        rng = np.random.default_rng(50)
        m = torch.stack([random_normal(rng, 8, 9) for _ in range(5)])
        c = torch.tensor([0, 1, 2, 1, 0])
        got = type_likelihood(m, c, VIDEO_TO_GMTI)
        for i in range(5):
            d = to_dict(m[i], VIDEO_CLASSES)
            a = BLOCKS[GMTI_CLASSES[int(c[i])]]
            expected = sum(len(x & a) / len(x) * v for x, v in d.items())  # 24.47
            assert float(got[i]) == pytest.approx(expected, abs=1e-12)
        fine_c = torch.tensor([3, 7, 0, 0, 5])
        torch.testing.assert_close(
            type_likelihood(m, fine_c), pignistic(m)[torch.arange(5), fine_c]
        )

    def test_errors(self):
        with pytest.raises(ValueError, match="`declared`"):
            type_likelihood(vacuous(8), torch.tensor(3), VIDEO_TO_GMTI)
        with pytest.raises(TypeError, match="`declared`"):
            type_likelihood(vacuous(8), torch.tensor(1.0))
        with pytest.raises(ValueError, match="`mapping`"):
            type_likelihood(vacuous(8), None, VIDEO_TO_GMTI)


class TestPignisticCoarse:
    def test_against_reference_and_not_invariant(self):
        rng = np.random.default_rng(60)
        for _ in range(5):
            m = random_normal(rng, 8, 12)
            got = pignistic_coarse(m, VIDEO_TO_GMTI, 3)
            d = to_dict(m, VIDEO_CLASSES)
            expected = [
                sum(len(x & BLOCKS[g]) / len(x) * v for x, v in d.items()) for g in GMTI_CLASSES
            ]
            np.testing.assert_allclose(got.numpy(), expected, atol=1e-12)
        # BetP depends on the frame: the refined vacuous bba gives 6/8 to "wheeled", not 1/3
        refined = refine(vacuous(3), VIDEO_TO_GMTI, 8)
        torch.testing.assert_close(
            pignistic_coarse(refined, VIDEO_TO_GMTI, 3),
            torch.tensor([1 / 8, 6 / 8, 1 / 8], dtype=torch.float64),
        )
        assert not torch.allclose(
            pignistic_coarse(refined, VIDEO_TO_GMTI, 3),
            pignistic(coarsen(refined, VIDEO_TO_GMTI, 3)),
        )

    def test_equal_blocks_commute_with_refinement(self):
        rng = np.random.default_rng(61)
        blocks = [[0, 3], [1, 4], [2, 5]]
        for _ in range(5):
            m = random_normal(rng, 3, 5)
            torch.testing.assert_close(
                pignistic_coarse(refine(m, blocks, 6), blocks, 3), pignistic(m), rtol=0, atol=1e-14
            )


class TestRefinementCommutesWithPCR5:
    def test_gmti_only_track_on_the_fine_frame_is_the_refined_coarse_track(self):
        # Omega(A) & Omega(B) = Omega(A & B) for a partition, so PCR5 commutes with refinement
        rng = np.random.default_rng(70)
        for _ in range(10):
            m1, m2 = random_normal(rng, 3, 4), random_normal(rng, 3, 5)
            fine = pcr5(refine(m1, VIDEO_TO_GMTI, 8), refine(m2, VIDEO_TO_GMTI, 8))
            torch.testing.assert_close(
                fine, refine(pcr5(m1, m2), VIDEO_TO_GMTI, 8), rtol=0, atol=1e-14
            )
            torch.testing.assert_close(
                coarsen(fine, VIDEO_TO_GMTI, 3), pcr5(m1, m2), rtol=0, atol=1e-14
            )
            ms = [random_normal(rng, 2, int(rng.integers(1, 4))) for _ in range(3)]
            blocks = [[0, 2], [1]]
            torch.testing.assert_close(
                pcr5_sources(*(refine(m, blocks, 3) for m in ms)),
                refine(pcr5_sources(*ms), blocks, 3),
                rtol=0,
                atol=1e-14,
            )


class TestReportTypeLikelihood:
    def test_against_dict_reference(self):
        rng = np.random.default_rng(51)
        m = torch.stack([random_normal(rng, 8, 9) for _ in range(6)])
        declared = [1, 0, 2]  # GMTI classes, refined to the video frame
        reports = [refine(gmti_obs(c), VIDEO_TO_GMTI, 8) for c in declared]
        reports += [video_obs(3), video_obs(6, 0.5), vacuous(8)]
        rep = torch.stack(reports)
        got = report_type_likelihood(m, rep)
        for i in range(6):
            d = to_dict(m[i], VIDEO_CLASSES)
            focal = {x: v for x, v in to_dict(rep[i], VIDEO_CLASSES).items() if len(x) < 8}
            a = max(focal, key=focal.get) if focal else frozenset(VIDEO_CLASSES)
            expected = sum(len(x & a) / len(x) * v for x, v in d.items())  # 24.47
            assert float(got[i]) == pytest.approx(expected, abs=1e-12)
        # = the "declared" reading with the sensor's class and mapping
        torch.testing.assert_close(
            got[:3], type_likelihood(m[:3], torch.tensor(declared), VIDEO_TO_GMTI)
        )
        torch.testing.assert_close(got[3], pignistic(m[3])[3])
        assert float(got[5]) == pytest.approx(1.0)
        # broadcast and empty batch
        assert report_type_likelihood(m, rep[0]).shape == (6,)
        assert report_type_likelihood(m[:0], rep[:0]).shape == (0,)

    def test_errors(self):
        with pytest.raises(ValueError, match="`report`"):
            report_type_likelihood(vacuous(8), vacuous(3))
        with pytest.raises(ValueError, match="`m`"):
            report_type_likelihood(torch.tensor([0.5, 0.6, 0.0, 0.0]), vacuous(2))

    @staticmethod
    def _winner(type_term):
        """Which track takes target T's GMTI "wheeled" report (issue 12, seed 2424, t = 940 s).

        Scan 0: T (a military armoured truck, video class 4) is seen with a spread type belief
        (0.5 on its class, 0.4 on the armoured wheeled vehicle 5) and starts track 0; 1 m away
        track 1 starts on another vehicle's report, sure it is class 5 (0.95). Scan 1: T's GMTI
        report at T's position declares "wheeled" (0.7), true for both classes.
        """
        from hocnet.tracking.mht import MHT, CVKalmanFilter
        from hocnet.tracking.pipeline import gmti_bba_on_video_frame

        def two(i, p, j=None, q=0.0):
            m = torch.zeros(256, dtype=torch.float64)
            m[1 << i] += p
            if j is not None:
                m[1 << j] += q
            m[-1] += 1.0 - p - q
            return m

        kw = dict(R=torch.eye(2), pd=0.9, lambda_fa=1e-3, lambda_nt=1e-2, merge_scans=0)
        mht = MHT(CVKalmanFilter(0.0, 1.0), type_term=type_term, **kw)
        z0 = torch.tensor([[0.0, 0.0], [1.0, 0.0]])
        mht.step(z0, bba=torch.stack([two(4, 0.5, 5, 0.4), two(5, 0.95)]))
        mht.step(torch.zeros(1, 2), bba=gmti_bba_on_video_frame(1, 0.7)[None])
        best = mht.hypotheses()[0][0][1]
        (fam,) = [f for f, h in best if h[1:] == (0,)]
        return fam

    def test_declared_set_gives_the_report_to_the_right_track(self):
        # kinematics alone (no type term) pick T's own track 0, nearer the report
        assert self._winner(None) == 0
        # the chapter's max BetP rewards track 1 for being sure of a class the GMTI cannot tell
        # apart: it takes T's report (the old default's failure)
        assert self._winner("estimate") == 1
        # BetP of the updated bba on the declared set: 1 for both tracks, kinematics decide
        assert self._winner("declared_set") == 0


def test_report_type_likelihood_tie_goes_to_the_lowest_bitmask():
    # a report with m({t0}) = m({t1}) = 0.4 declares {t0} (bitmask 1 < 2): BetP({t0}) of m
    m = torch.tensor([0, 0.1, 0.6, 0, 0, 0, 0, 0.3], dtype=torch.float64)
    betp = pignistic(m)  # [0.2, 0.7, 0.1]
    rep = torch.tensor([0, 0.4, 0.4, 0, 0, 0, 0, 0.2], dtype=torch.float64)
    assert float(report_type_likelihood(m, rep)) == pytest.approx(float(betp[0]), abs=1e-12)
    # {t1} and {t2} tied: {t1} (bitmask 2 < 4)
    rep = torch.tensor([0, 0, 0.4, 0, 0.4, 0, 0, 0.2], dtype=torch.float64)
    assert float(report_type_likelihood(m, rep)) == pytest.approx(float(betp[1]), abs=1e-12)

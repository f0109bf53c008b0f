import itertools
import math
import pathlib
import sys
import time

import pytest
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import load_script, read_rows

SCRIPTS = {
    "dpa-b-sweep": "dpa_b_sweep.py",
    "dpa-sampling": "dpa_sampling.py",
    "dpa-pd-snr": "dpa_pd_snr.py",
}


def load(name: str):
    return load_script(SCRIPTS[name])


def common():
    load("dpa-b-sweep")
    return sys.modules["_expkit"]


def paper():
    load("dpa-b-sweep")
    return sys.modules["_nr08"]


def check_outputs(name: str, md: pathlib.Path, out: pathlib.Path) -> list[dict]:
    """The md/csv/png of one run exist, are well formed and show the paper's values."""
    assert md == out / f"{name}.md"
    for ext in ("md", "csv", "png"):
        path = out / f"{name}.{ext}"
        assert path.is_file() and path.stat().st_size > 0, path
    assert (out / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = md.read_text()
    assert "paper" in text and "n/a (paper text not available" not in text
    assert f"![{name}]({name}.png)" in text
    rows = read_rows(out / f"{name}.csv")
    assert rows
    return rows


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_module_interface(name):
    module = load(name)
    assert module.NAME == name
    assert isinstance(module.DESCRIPTION, str) and module.DESCRIPTION
    assert callable(module.run) and callable(module.main)


class TestCommonDPA:
    def test_b_ranges(self):
        c = common()
        assert c.b_ranges([0.0, 0.2, 0.4, 0.6], [0.5, 0.6, 0.1, 0.5]) == "0-0.2, 0.6"
        assert c.b_ranges([0.0, 1.0], [0.49, 0.0]) == "none"
        assert c.b_ranges([1.0, 2.0, 3.0], [1.0, 1.0, 1.0]) == "1-3"

    def test_dpa_scene_per_seed(self):
        c = common()
        both = c.dpa_scene("NPA-like", [3, 4], shape=(4, 24, 24), snr_db=10.0)
        one = c.dpa_scene("NPA-like", [4], shape=(4, 24, 24), snr_db=10.0)
        assert both.frames.shape == (2, 4, 24, 24)
        assert both.positions.shape == (2, 2, 4, 2)
        assert torch.equal(both.frames[1], one.frames[0])
        assert torch.equal(both.target_free[1], one.target_free[0])
        assert c.scene_speed("NA23A-like") == pytest.approx(0.3)
        assert c.scene_speed("NPA-like") == pytest.approx(0.2)

    def test_dpa_tracked(self):
        c = common()
        truth = torch.zeros(2, 2, 5, 2)
        truth[:, 1] = 10.0
        traj = torch.zeros(2, 5, 2, dtype=torch.long)
        traj[1] = 10
        traj[1, :2] = 30  # only 3 of 5 frames (60 %) on target 1
        tracked, which = c.dpa_tracked(traj, truth)
        assert tracked.tolist() == [True, False]
        assert which.tolist() == [0, -1]

    def test_blockwise_score_matches_loop(self):
        c = common()
        gen = torch.Generator().manual_seed(0)
        asf = torch.randn(2, 7, 36, 36, generator=gen)
        pos = torch.rand(2, 1, 7, 2, generator=gen) * 12 + 12
        scores = c.blockwise_score(asf, pos, [1, 3], last=4)
        for m in (1, 3):
            for b in range(2):
                values = []
                for t in range(3, 7):
                    x = math.floor(float(pos[b, 0, t, 0]) + 0.5)
                    y = math.floor(float(pos[b, 0, t, 1]) + 0.5)
                    blocks = []
                    for by in (-1, 0, 1):
                        for bx in (-1, 0, 1):
                            cy, cx = y + 5 * by, x + 5 * bx
                            blk = asf[b, t, cy - 2 : cy + 3, cx - 2 : cx + 3].reshape(-1)
                            blocks.append(blk.double().sort(descending=True).values[:m].mean())
                    target = blocks.pop(4)
                    bg = torch.stack(blocks)
                    values.append((target - bg.mean()) / bg.std(unbiased=False))
                assert float(scores[m][b]) == pytest.approx(float(sum(values) / 4), rel=1e-9)

    def test_blockwise_score_can_grow_with_max_numbers(self):
        c = common()
        asf = torch.zeros(1, 1, 30, 30)
        asf[0, 0, 14:17, 14:17] = 1.0  # a 3 x 3 blob on the target
        pos = torch.tensor([15.0, 15.0]).view(1, 1, 1, 2)
        # one bright pixel in each of the 8 background blocks, of different heights
        centres = [(y, x) for y in (10, 15, 20) for x in (10, 15, 20) if (y, x) != (15, 15)]
        for k, (y, x) in enumerate(centres):
            asf[0, 0, y, x] = 0.4 + 0.1 * k
        scores = c.blockwise_score(asf, pos, [1, 3], last=1)
        assert float(scores[3][0]) > float(scores[1][0]) > 0


class TestPaperValues:
    def test_constants_are_the_papers(self):
        p = paper()
        assert p.PAPER_B_RANGE == {
            ("NA23A", 0.0): (4.4, 6.0),
            ("NA23A", 1.0): (0.2, 0.8),
            ("NPA", 0.0): (2.0, 4.8),
            ("NPA", 1.0): (0.0, 0.8),
        }
        assert p.PAPER_MAX_NUMBERS == {0.0: 3, 1.0: 1}
        assert p.PAPER_SN_RANGE == {"NA23A": (1, 5), "NPA": (3, 5)}
        assert p.PAPER_EQ15 == {"directions 1-8": (1.118, 0.131), "direction 9": (1.035, 0.214)}
        assert p.PAPER_PEAK == {"NA23A": 60.0, "NPA": 30.0}

    def test_variant_scene(self):
        from hocnet.data.infrared import na23a_like

        p = paper()
        assert p.paper_name(p.FLUCT) == "NA23A" and p.paper_name("NPA") == "NPA"
        got = p.scene(p.FLUCT, [3], shape=(4, 30, 40))
        want = na23a_like(seed=3, shape=(4, 30, 40), fluctuation=p.FLUCTUATION)
        assert torch.equal(got.frames[0], want.frames)
        plain = p.scene("NA23A", [3], shape=(4, 30, 40))
        assert torch.equal(got.target_free, plain.target_free)  # same scene, fluctuating target
        assert not torch.equal(got.frames, plain.frames)

    def test_helpers(self):
        p = paper()
        assert p.ends_of("0.2-0.4, 0.8") == (0.2, 0.8)
        assert p.ends_of("none") is None
        assert p.gap((2.2, 4.4), (2.0, 4.8)) == "+0.2 / -0.4"
        assert p.gap(None, (2.0, 4.8)) == "no tracking"
        truth = torch.zeros(1, 5, 2)
        path = torch.tensor([[[0, 0], [1, 1], [2, 2], [0, 1], [0, 0]]])
        assert p.on_truth(path, truth).tolist() == [0.8]
        assert p.direction_option() == {"direction_step": "source"}
        # located: only the last frame counts; tracked: >= 80 % of the frames
        late = torch.tensor([[[0, 0], [0, 0], [0, 0], [0, 0], [9, 9]]])
        early = torch.tensor([[[9, 9], [9, 9], [0, 0], [0, 0], [1, 1]]])
        assert p.tracked(late, truth).tolist() == [True] and not bool(p.located(late, truth))
        assert p.located(early, truth).tolist() == [True] and not bool(p.tracked(early, truth))
        assert set(p.CRITERIA) == {"tracked", "located", "good"}

    def test_located_is_on_the_current_position(self):
        # 1.2 px per sampled frame (NA23A at s_n = 4): a detection one frame behind lies within
        # 1.5 px of the current position but nearer the previous one, and is not located
        p = paper()
        truth = torch.tensor([[[7.5, 10.0], [8.75, 10.0], [10.0, 10.0]]], dtype=torch.float64)
        truth = truth.expand(6, 3, 2)
        path = torch.zeros(6, 3, 2, dtype=torch.float64)
        path[:, -1] = torch.tensor(
            [
                [9.0, 10.0],  # 1.0 from now, 0.25 from before: one frame behind
                [10.0, 10.0],  # on the truth
                [11.0, 11.0],  # 1.41 ahead
                [11.5, 10.0],  # exactly 1.5: inside (<=)
                [11.5 + 1e-9, 10.0],  # just outside
                [9.375, 10.0],  # equidistant (0.625): not nearer the current position
            ],
            dtype=torch.float64,
        )
        assert p.located(path, truth).tolist() == [False, True, True, True, False, False]
        # the radius alone (today's tracking_success(last=1)) takes the one behind
        from hocnet.dpa import tracking_success

        assert bool(tracking_success(path[:1], truth[:1], last=1))
        # a target that did not move: the radius alone decides; T = 1 likewise
        still = torch.full((1, 2, 2), 5.0, dtype=torch.float64)
        near = torch.tensor([[[0.0, 0.0], [6.0, 6.0]]], dtype=torch.float64)
        assert p.located(near, still).tolist() == [True]
        assert p.located(near[:, 1:], still[:, 1:]).tolist() == [True]
        assert p.located(near + 1.0, still).tolist() == [False]
        assert p.located(path, truth, radius=0.5).tolist() == [False, True] + [False] * 4
        # jitter brought the previous position within 0.3 px: the target's own pixel is nearer
        # the previous position; own_pixel accepts it, a pixel behind stays rejected
        short = torch.tensor([[[9.0, 10.0], [10.1, 10.0], [10.4, 10.0]]], dtype=torch.float64)
        own = torch.tensor([[[0.0, 0.0], [0.0, 0.0], [10.0, 10.0]]], dtype=torch.float64)
        assert p.located(own, short, own_pixel=False).tolist() == [False]
        assert p.located(own, short, own_pixel=True).tolist() == [True]
        assert p.located(own - 1.0, short, own_pixel=True).tolist() == [False]
        # the detected pixel is the highest of the nine blocks around the target, not of the
        # frame: a brighter pixel outside them (another target) is ignored
        asf = torch.zeros(2, 3, 40, 60)
        asf[:, -1, 10, 40] = 9.0  # outside the 3 x 3 blocks of 10 x 10 around (15, 15)
        asf[:, -1, 2, 1] = 5.0  # inside (blocks span x, y in [0, 30))
        asf[1, -1, 29, 29] = 6.0
        truth = torch.full((2, 3, 2), 15.0)
        assert p.nine_block_start(asf, truth, 10).tolist() == [[1, 2], [29, 29]]
        # 10 x 20 blocks (rows x columns) span x in [-15, 45): (40, 10) is inside
        assert p.nine_block_start(asf, truth, (10, 20)).tolist() == [[40, 10], [40, 10]]
        flat = torch.full((3, 3), 1 / 9)
        assert p.emc_b(flat, 0.0) == pytest.approx(7.2) and p.emc_b(flat, 1.0) == pytest.approx(0.8)
        slope, intercept = p.memory_constants(flat)
        assert (slope, intercept) == pytest.approx((10 / 9, 5 / 36))  # 1/b = slope g + intercept
        assert 1 / (slope * 0.5 + intercept) == pytest.approx(p.emc_b(flat, 0.5))


class TestBSweep:
    def test_quick(self, tmp_path, capsys):
        module = load("dpa-b-sweep")
        start = time.perf_counter()
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        assert time.perf_counter() - start < 60  # loose bound; a few seconds
        rows = check_outputs("dpa-b-sweep", md, tmp_path)
        variants = {r["variant"] for r in rows}
        assert {"paper DPA", "equal gain"} <= variants
        # per scene and seed: every variant at the b values of the quick grid within the memory
        # range of eq. (12)-(14): b = 8 (g = 0, b_max 7.99) and b = 1.2 (g = 1, b_max 1) skipped;
        # the fluctuating NA23A variant is run with the paper DPA only; at g = 1 every paper DPA
        # row is also written as the equal-gain row it equals (copied_from)
        assert len(rows) == (2 * len(variants) * 4 + 4 + 2) * 2
        assert {r["scene"] for r in rows} == {"NA23A", "NPA", "NA23A fluct."}
        fluct = [r for r in rows if r["scene"] == "NA23A fluct."]
        assert {r["variant"] for r in fluct if not r.get("copied_from")} == {"paper DPA"}
        assert {float(r["b"]) for r in rows} == {0.0, 4.8, 0.8}
        text = md.read_text()
        assert "b = 8 at g = 0, b = 1.2 at g = 1: outside the memory range of eq. (12)-(14)" in text
        assert text.count("| outside the memory range of eq. (12)-(14) |") == 2 * 2 * 2 + 2
        assert "same, on the paper's 0.2 grid" in text and "Why the ranges differ" in text
        assert {r["tracked"] for r in rows} <= {"0", "1"}
        for key in ("located", "top_on_target", "good"):
            assert {r[key] for r in rows} <= {"0", "1"}, key
        # good = located and the Max_Numbers highest pixels on the target
        assert all(int(r["good"]) == int(r["located"]) * int(r["top_on_target"]) for r in rows)
        for r in rows:  # the terms of eq. (17), means over the last frames
            assert float(r["ntb_std"]) > 0 and math.isfinite(float(r["snr_tb"]))
        assert "## b range by criterion, beside Table 2 of [NR08]" in text
        assert "good range: located and MN highest on target" in text
        assert "## Why our A_S peaks early" in text and "standing pixel's gain" in text
        assert all(math.isfinite(float(r["a_s"])) for r in rows)
        # b = 0 switches the accumulation off: A_S is the single frame's for every variant
        for scene in ("NA23A", "NPA"):
            for g in (0.0, 1.0):
                zero = {
                    r["a_s"]
                    for r in rows
                    if r["scene"] == scene
                    and r["seed"] == "6000"
                    and float(r["g"]) == g
                    and float(r["b"]) == 0.0
                }
                assert len(zero) == 1, (scene, g, zero)
        # equal gain at g = 1 repeats the paper's recursion (sum-to-one matrices)
        copies = [r for r in rows if r["variant"] == "equal gain" and float(r["g"]) == 1.0]
        assert copies and all(r["copied_from"] == "paper DPA" for r in copies)
        text = md.read_text()
        for value in ("4.4-6", "2-4.8", "0.2-0.8", "0-0.8", "4.4-4.6", "1.118", "0.131", "1.035"):
            assert value in text
        assert "0.214" in text and "4.65" in text and "7.63" in text
        assert "| sequence | g | variant |" in capsys.readouterr().out

    def test_main_cli(self, tmp_path):
        module = load("dpa-b-sweep")
        md = module.main(["--quick", "--seeds", "1", "--out", str(tmp_path), "--no-progress"])
        rows = check_outputs("dpa-b-sweep", md, tmp_path)
        assert {r["seed"] for r in rows} == {str(module.SEED_BASE)}

    def test_noise_free_gain(self):
        module = load("dpa-b-sweep")
        gains = module.noise_free_gain(bs=(0.0, 2.4, 5.8), seeds=(0,), quick=True)
        # independent check of the standing pixel's gain: a single pixel standing in place,
        # run through the paper DPA at g = 0, grows as a_n = 1 + gain a_(n-1) (a loop)
        from hocnet.dpa import accumulate

        frames = torch.zeros(1, 6, 11, 11, dtype=torch.float64)
        frames[0, :, 5, 5] = 1.0
        for r in gains:
            asf = accumulate(frames, paper().weights().double(), r["b"], 0.0).asf[0, :, 5, 5]
            expected, a = [], 0.0
            for _ in range(frames.shape[1]):
                a = 1.0 + r["standing"] * a
                expected.append(a)
            assert asf.tolist() == pytest.approx(expected, rel=1e-9), r["b"]
        assert gains[0]["standing"] == 0.0 and gains[2]["standing"] > 1.0  # b = 5.8 > 5.77
        assert gains[0]["target"] == pytest.approx(1.0)  # b = 0: the single-frame value
        # memory raises the target's score, and the standing trail's faster (b max W(9) = 1
        # at b = 5.77): the best non-target pixel gains on the target as b grows
        assert gains[0]["target"] < gains[1]["target"] < gains[2]["target"]
        assert gains[0]["other"] < gains[1]["other"] < gains[2]["other"]
        assert "| 2.4 |" in module._gain_table(gains)

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("dpa-b-sweep")
        rows = check_outputs("dpa-b-sweep", module.run(out_dir=tmp_path), tmp_path)
        variants = {r["variant"] for r in rows}
        # b = 8 is skipped; the fluctuating variant with the paper DPA only (+ its g = 1 copies)
        assert len(rows) == (2 * len(variants) * (40 + 21) + 40 + 2 * 21) * module.SEEDS

    def test_b_zero_is_the_same_dpa_for_every_g(self):
        # eq. (2) at b = 0 is ASF = WF whatever g, and eq. (7)-(8) involve neither g nor b: the
        # ASF and the back-tracked track are the same for g = 0 and g = 1, so tracking at b = 0
        # cannot differ between them (Table 2's NPA: g = 1 from 0, g = 0 from 2).
        from hocnet.dpa import accumulate, backtrack

        module = load("dpa-b-sweep")
        frames, truth = module.sampled("NPA", [6000, 6001], (6, 45, 60))
        w = paper().weights()
        states = [accumulate(frames, w, 0.0, g) for g in (0.0, 1.0)]
        torch.testing.assert_close(states[0].asf, states[1].asf, rtol=0, atol=0)
        starts = [paper().nine_block_start(st.asf, truth, 15) for st in states]
        torch.testing.assert_close(starts[0], starts[1])
        tracks = [backtrack(st, s) for st, s in zip(states, starts, strict=True)]
        torch.testing.assert_close(tracks[0], tracks[1])
        # and with memory they differ
        other = [accumulate(frames, w, 0.5, g).asf for g in (0.0, 1.0)]
        assert not torch.equal(other[0], other[1])

    def test_scene_variants(self):
        module = load("dpa-b-sweep")
        table = module.variants()
        assert module.scene_variants("NA23A", table) == list(table)
        assert module.scene_variants(paper().FLUCT, table) == ["paper DPA"]
        assert module.scene_label(paper().FLUCT) == "NA23A-like, fluctuating peak"


class TestSampling:
    def test_quick(self, tmp_path):
        module = load("dpa-sampling")
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        every = check_outputs("dpa-sampling", md, tmp_path)
        rows = [r for r in every if r["table"] == "sampling"]
        # 4 scenes (NA23A, NPA, fluctuating and one-pixel NA23A) x s_n 1, 4 x g 0, 1
        # x b paper / EMC x 2 seeds
        assert len(module.SCENES) == 4
        assert len(rows) == 4 * 2 * 2 * 2 * 2
        seen = [r for r in every if r["table"] == "visibility"]  # 2 peaks x s_n 1, 4 x 2 seeds
        assert len(seen) == len(every) - len(rows) == 2 * 2 * 2
        assert {float(r["peak"]) for r in seen} == set(module.QUICK_VISIBILITY_PEAKS)
        # the preset's peak: the same scenes as the main table, so the same tracking
        for r in seen:
            if float(r["peak"]) == 30.0:
                (main,) = [
                    m
                    for m in rows
                    if (m["scene"], m["s_n"], m["seed"], m["b_choice"], float(m["g"]))
                    == ("NPA", r["s_n"], r["seed"], "paper", 0.0)
                ]
                assert main["tracked"] == r["tracked_g0"]
        assert f"## {module.VISIBILITY}" in md.read_text()
        assert {r["s_n"] for r in rows} == {"1", "4"}
        assert {r["b_choice"] for r in rows} == {"paper", "EMC"}
        for r in rows:
            speed = 0.2 if r["scene"] == "NPA" else 0.3
            assert float(r["v_eff"]) == pytest.approx(int(r["s_n"]) * speed)
            # the centred reading cannot grow with Max_Numbers
            values = [float(r[f"a_s_centred_mn{m}"]) for m in range(1, 8)]
            assert all(a >= b - 1e-9 for a, b in itertools.pairwise(values))
            assert all(math.isfinite(float(r[f"a_s_mn{m}"])) for m in range(1, 8))
        paper_b = {(float(r["g"]), float(r["b"])) for r in rows if r["b_choice"] == "paper"}
        assert paper_b == {(0.0, 4.8), (1.0, 0.8)}
        text = md.read_text()
        for value in ("0.6 ± 0.15", "0.8 ± 0.1", "1-5", "3-5", "Max_Numbers"):
            assert value in text
        # the Max_Numbers peak is read at the paper's s_n per sequence (quick grid: 1, 4)
        assert module._ref_sn("NA23A", (1, 2, 3, 4, 5)) == 4
        assert module._ref_sn("NPA", (1, 2, 3, 4, 5)) == 3
        assert module._ref_sn(paper().FLUCT, (1, 2, 3, 4, 5)) == 4
        assert module._ref_sn("NPA", (1, 4)) == 4

    def test_geometry_follows_the_paper(self):
        module = load("dpa-sampling")
        # one block size per scene at every s_n (the long blocks since some s_n needs them)
        for step in (1, 2, 3, 4, 5):
            assert module.geometry("NA23A", step, False) == ((90, 240), (30, 80))
            assert module.geometry(paper().FLUCT, step, False) == ((90, 240), (30, 80))
            assert module.geometry("NPA", step, False) == ((240, 120), (80, 30))
        # a grid that never needs them keeps 30 x 30 at every s_n
        assert module.geometry("NA23A", 1, False, (1,)) == ((90, 90), (30, 30))
        assert module.geometry("NPA", 2, False, (1, 2)) == ((90, 120), (30, 30))
        # the target may leave a 30 x 30 block: travel + 2 x jitter + PSF radius > 15 px
        assert not module.fast("NA23A", 1)  # 7.2 + 2 px
        assert module.fast("NA23A", 2)  # 14.4 + 2 px
        assert not module.fast("NPA", 2)  # 9.6 + 2 px
        assert module.fast("NPA", 3)  # 14.4 + 2 px

    def test_nine_blocks_are_full(self):
        module = load("dpa-sampling")
        for scene in ("NA23A", "NPA", paper().FLUCT, paper().POINT):
            (height, width), (rows, cols) = module.geometry(scene, 4, False)
            _, truth = module.sampled_scene(scene, [1], 3, (height, width), 1)
            x, y = (math.floor(float(v) + 0.5) for v in truth[0, 0])
            # the nine blocks around the first-frame pixel, as tiled by algorithm_score
            x0, y0 = x - cols // 2 - cols, y - rows // 2 - rows
            assert 0 <= x0 and x0 + 3 * cols <= width, scene
            assert 0 <= y0 and y0 + 3 * rows <= height, scene

    def test_footprints_are_measured(self):
        module = load("dpa-sampling")
        prints = module.footprints([7000, 7001], 8, True, (1, 4), paper().weights())
        assert set(prints) == {(s, g) for s in module.FOOTPRINT_SCENES for g in (0.0, 1.0)}
        for rel in prints.values():
            assert len(rel) == 7 and rel[0] == pytest.approx(1.0)
            assert all(a >= b - 1e-9 for a, b in itertools.pairwise(rel))
        # a one-pixel target at g = 1 lights fewer high pixels than the 0.7 px Gaussian
        assert prints[paper().POINT, 1.0][1] < prints["NA23A", 1.0][1]

    def test_sampled_scene_keeps_every_step(self):
        module = load("dpa-sampling")
        _, truth = module.sampled_scene("NA23A", [1], 5, (30, 60), 3)
        assert truth.shape == (1, 5, 2)
        steps = truth[0, 1:] - truth[0, :-1]
        # 3 frames of 0.3 px/frame between kept frames, plus the jitter of two frames (<= 1 px)
        assert torch.all(torch.linalg.vector_norm(steps, dim=-1) <= 0.9 + 2 * 2**0.5 * 0.5)

    def test_part_visibility_keeps_the_rest(self, tmp_path):
        module = load("dpa-sampling")
        with pytest.raises(FileNotFoundError, match="--part visibility"):
            module.run(quick=True, out_dir=tmp_path, progress=False, part="visibility")
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        before, rows = md.read_text(), read_rows(tmp_path / "dpa-sampling.csv")
        module.run(quick=True, out_dir=tmp_path, progress=False, part="visibility")
        after = md.read_text()
        note = "Computed alone with `--part visibility`"
        assert note in after and after.count(f"## {module.VISIBILITY}") == 1
        kept = [line for line in after.splitlines() if not line.startswith(note)]
        assert "\n".join(kept).replace("\n\n\n", "\n\n") == before.rstrip("\n")
        assert read_rows(tmp_path / "dpa-sampling.csv") == rows

    def test_single_frame_visibility(self):
        module = load("dpa-sampling")
        frames = torch.zeros(1, 2, 40, 20)
        truth = torch.tensor([[[10.0, 20.0], [10.0, 19.0]]])
        frames[0, 0, 20, 10] = 6.0  # frame 0: the target is the highest pixel, 2 x the clutter
        frames[0, 0, 5, 3] = 3.0
        frames[0, 1, 19, 10] = 2.0  # frame 1: a brighter pixel elsewhere in the target block
        frames[0, 1, 30, 15] = 4.0
        seen = module.single_frame_visibility(frames, truth, (40, 20))
        assert float(seen["on_tb"][0]) == 0.5 and float(seen["on_nine"][0]) == 0.5
        assert float(seen["ratio"][0]) == pytest.approx(0.5)  # lower median of 2.0, 0.5

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("dpa-sampling")
        rows = check_outputs("dpa-sampling", module.run(out_dir=tmp_path), tmp_path)
        rows = [r for r in rows if r["table"] == "sampling"]
        assert len(rows) == 4 * 5 * 2 * 2 * 20


class TestPdSnr:
    def test_quick(self, tmp_path):
        module = load("dpa-pd-snr")
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        rows = check_outputs("dpa-pd-snr", md, tmp_path)
        pd_rows = [r for r in rows if r["table"] == "pd"]
        assert {r["scene"] for r in pd_rows} == {"NPA-like", "clear-sky control"}
        methods = {r["method"] for r in pd_rows}
        assert {
            "single frame",
            "paper DPA, g = 0",
            "equal gain, g = 0",
            "paper DPA, g = 1",
        } <= methods
        snrs = set(module.QUICK_SNRS) | set(module.QUICK_FRAME_SNRS)
        assert len(pd_rows) == 2 * len(methods) * len(snrs)
        for r in pd_rows:
            assert 0.0 <= float(r["pd"]) <= 1.0
            assert float(r["frames_to_pd90"]) >= 1.0
        frames = [r for r in rows if r["table"] == "frames"]
        assert {int(r["frames"]) for r in frames} == set(range(1, 9))
        speed = [r for r in rows if r["table"] == "speed"]
        assert {float(r["speed"]) for r in speed} == set(module.QUICK_SPEEDS)
        assert len(speed) == len(module.QUICK_SPEEDS) * len(module.speed_options()) * 2
        assert {r["method"] for r in speed} == {label for label, *_ in module.speed_options()}
        assert all(0.0 <= float(r["on_truth"]) <= 1.0 for r in speed)
        assert "n/a: [NR08] reports no Pd" in md.read_text()
        # --part speed: part 2 alone, the part-1 rows and tables read back unchanged
        before = md.read_text()
        merged = module.run(quick=True, out_dir=tmp_path, progress=False, part="speed")
        again = read_rows(tmp_path / "dpa-pd-snr.csv")
        assert [r for r in again if r["table"] != "speed"] == [
            r for r in rows if r["table"] != "speed"
        ]
        cut = "## Tracking versus target speed"
        assert (
            merged.read_text()
            .split("## Summary")[1]
            .split(cut)[0]
            .replace("rerun alone with `--part speed`", "")
            == before.split("## Summary")[1].split(cut)[0]
        )
        assert "rerun alone with `--part speed`" in merged.read_text()

    def test_part_speed_needs_a_run(self, tmp_path):
        module = load("dpa-pd-snr")
        with pytest.raises(FileNotFoundError, match="--part speed"):
            module.run(quick=True, out_dir=tmp_path, progress=False, part="speed")
        with pytest.raises(ValueError, match="`part`"):
            module.run(quick=True, out_dir=tmp_path, progress=False, part="pd")

    def test_speed_options_are_the_presets(self):
        from hocnet.dpa.presets import PAPER, RECOMMENDED

        module = load("dpa-pd-snr")
        options = {label: (preset, flags) for label, preset, flags in module.speed_options()}
        # the paper DPA at g = 0 with the 7 x 7 matrices is --preset paper itself
        assert options["paper DPA, g = 0"] == (PAPER, "--preset paper")
        assert options["recommended (CLI default)"][0] == RECOMMENDED
        fast = options["recommended, g = 1, source direction step"][0]
        assert (fast.g, fast.direction_step, fast.window) == (1.0, "source", 5)
        for label, (preset, _) in options.items():  # the earlier options keep their settings
            if label.startswith(("paper DPA", "equal gain", "source direction step")):
                assert (preset.window, preset.v_max, preset.memory) == (7, 2.0, 0.8), label

    def test_ablation_rows_change_one_setting_of_the_paper_preset(self):
        import dataclasses

        from hocnet.dpa.presets import PAPER

        module = load("dpa-pd-snr")
        rows = module.ablation_options()
        assert rows and all(label.startswith(module.ABLATION) for label, *_ in rows)
        # the ablation rows come after every recommended / paper option
        labels = [label for label, *_ in module.speed_options()]
        assert labels[-len(rows) :] == [label for label, *_ in rows]
        for label, preset, flags in rows:
            base = PAPER.replace(g=preset.g)
            changed = {
                f.name
                for f in dataclasses.fields(PAPER)
                if getattr(preset, f.name) != getattr(base, f.name)
            }
            assert flags.startswith("--preset paper"), label
            if module.EQ7_W_OF_D in label:
                assert changed <= {"b"}, label
            else:
                assert len(changed) in (1, 2) and changed <= {"p", "b", "window", "v_max"}, label

    def test_eq7_ablation_patch_uses_w_of_d_and_is_undone(self):
        from hocnet.dpa import functional as F
        from hocnet.dpa.matrices import probability_matrices, var_table

        module = load("dpa-pd-snr")
        w = probability_matrices(7, v_max=2.0).flip(-2, -1)
        table = var_table()
        paper = F._eq7_weights(w, table)
        with module.eq7_with_w_of_d():
            patched = F._eq7_weights(w, table)
        assert F._eq7_weights(w, table).equal(paper)  # restored
        # direction 9 (index 8) of the source: W(9) = W_basic, the same score as eq. (7)
        assert torch.allclose(patched[8], paper[8])
        # direction 1 of the source: W(1) * Var in place of W_basic * Var
        ratio = patched[0] / paper[0].clamp_min(1e-30)
        expected = w[0] / w[8].clamp_min(1e-30)
        mask = paper[0] > 0
        assert torch.allclose(ratio[mask], expected[mask], rtol=1e-5)
        assert not torch.allclose(patched[0], paper[0])

    def test_fast_targets_are_sampled_from_a_longer_sequence(self):
        module = load("dpa-pd-snr")
        frames, truth = module.speed_data(2.5, [1, 2], (6, 40, 40))
        assert frames.shape == (2, 6, 40, 40) and truth.shape == (2, 6, 2)
        steps = truth[:, 1:] - truth[:, :-1]  # 2.5 px/frame at 30 degrees plus two jitters
        drift = torch.tensor([2.5 * math.cos(math.pi / 6), 2.5 * math.sin(math.pi / 6)])
        assert torch.all((steps - drift.double()).abs() <= 1.0 + 1e-9)
        slow, _ = module.speed_data(1.0, [1], (6, 40, 40))
        assert slow.shape == (1, 6, 40, 40)

    def test_frames_snr_discriminates(self):
        module = load("dpa-pd-snr")
        kind, n = module.SCENE, 5
        ones, late, never = torch.ones(n), torch.tensor([0, 0, 0.95, 1, 1.0]), torch.zeros(n)
        curves = {  # SNR -> (method a, method b)
            4.0: (never, never),  # nobody reaches 0.9: says nothing
            8.0: (late, never),  # a reaches it at frame 3, b never: discriminates
            12.0: (ones, late),
            30.0: (ones, ones),  # both from the first frame: says nothing
        }
        results = {
            (kind, m, snr): {"curve": c[i]} for snr, c in curves.items() for i, m in enumerate("ab")
        }
        assert module.frames_snr(results, kind, ["a", "b"], [4.0, 8.0, 12.0, 30.0], n) == 8.0
        assert module.frames_snr(results, kind, ["a", "b"], [12.0, 30.0], n) == 12.0
        assert module.frames_snr(results, kind, ["a", "b"], [4.0, 30.0], n) == 30.0  # none: top

    def test_scaled_scenes_equal_simulation(self):
        module = load("dpa-pd-snr")
        c, p = common(), paper()
        scenes = module.Scenes([5], (4, 30, 40))
        direct = p.scene("NPA", [5], shape=(4, 30, 40), snr_db=14.0)
        expected = c.whiten(direct.frames, "anti_mean")
        assert torch.allclose(scenes.frames(14.0), expected, atol=1e-3)
        assert torch.equal(scenes.positions, direct.positions)

    def test_control_scenes(self):
        module = load("dpa-pd-snr")
        cloudy = module.simulate(module.SCENE, [7], (4, 30, 40))
        clear = module.simulate(module.CONTROL, [7], (4, 30, 40))
        assert torch.equal(cloudy.positions, clear.positions)  # same targets and jitter
        assert bool((clear.clouds == 0).all()) and bool((cloudy.clouds > 0).any())
        noise = cloudy.target_free - cloudy.clouds
        assert torch.allclose(clear.target_free, noise, atol=1e-4)

    def test_threshold_is_cfar_threshold(self):
        from hocnet.dpa import cfar_threshold

        module = load("dpa-pd-snr")
        c, p = common(), paper()
        calib = c.whiten(p.scene("NPA", [1, 2], shape=(5, 24, 24)).target_free)
        weights = p.weights()
        det = module.Detector("x", 1.5, 0.5, weights, calib)
        assert det.threshold == pytest.approx(cfar_threshold(calib, weights, 1.5, 0.5, pfa=1e-3))
        single = module.Detector(module.SINGLE, 0.0, 0.0, weights, calib)
        assert single.threshold == pytest.approx(
            float(torch.kthvalue(calib[:, -1].reshape(-1), 2 * 24 * 24 - 1).values)
        )

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("dpa-pd-snr")
        rows = check_outputs("dpa-pd-snr", module.run(out_dir=tmp_path), tmp_path)
        pd_rows = [r for r in rows if r["table"] == "pd"]
        assert {float(r["snr_db"]) for r in pd_rows} >= set(module.SNRS)

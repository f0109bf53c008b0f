import itertools
import math
import pathlib
import sys
import time

import pytest
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import check_outputs, load_script

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


class TestBSweep:
    def test_quick(self, tmp_path, capsys):
        module = load("dpa-b-sweep")
        start = time.perf_counter()
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        assert time.perf_counter() - start < 60  # loose bound; a few seconds
        rows = check_outputs("dpa-b-sweep", md, tmp_path)
        sweep = [r for r in rows if r["table"] == "sweep"]
        # 2 scenes x 4 matrices (2 + their equal-gain variants) x (3 + 3) b values x 2 seeds
        assert len(sweep) == 2 * 4 * 6 * 2
        # eq. (5) matrices sum to 1, so at g = 1 the equal-gain variant is the same recursion
        for r in sweep:
            if r["g"] == "1" and not r["matrix"].endswith(", equal gain"):
                twin = [
                    o
                    for o in sweep
                    if o["matrix"] == r["matrix"] + ", equal gain"
                    and all(o[k] == r[k] for k in ("scene", "g", "b", "seed"))
                ]
                assert len(twin) == 1
                assert float(twin[0]["a_s"]) == pytest.approx(float(r["a_s"]), rel=1e-5)
        assert {r["tracked"] for r in sweep} <= {"0", "1"}
        assert all(math.isfinite(float(r["a_s"])) for r in sweep)
        # b = 0 switches the accumulation off: A_S is the single frame's, whatever g or matrices
        for scene in ("NA23A-like", "NPA-like"):
            for seed in ("6000", "6001"):
                zero = {
                    r["a_s"]
                    for r in sweep
                    if r["scene"] == scene and r["seed"] == seed and float(r["b"]) == 0.0
                }
                assert len(zero) == 1
        context = [r for r in rows if r["table"] == "context"]
        assert {r["whitening"] for r in context} == {"anti_mean", "anti_median"}
        text = md.read_text()
        for value in ("4.4-6", "2-4.8", "0.2-0.8", "0-0.8", "1.118", "0.214"):
            assert value in text
        assert "| sequence | g | matrices |" in capsys.readouterr().out

    def test_main_cli(self, tmp_path):
        module = load("dpa-b-sweep")
        md = module.main(["--quick", "--seeds", "1", "--out", str(tmp_path), "--no-progress"])
        rows = check_outputs("dpa-b-sweep", md, tmp_path)
        assert {r["seed"] for r in rows} == {str(module.SEED_BASE)}

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("dpa-b-sweep")
        rows = check_outputs("dpa-b-sweep", module.run(out_dir=tmp_path), tmp_path)
        sweep = [r for r in rows if r["table"] == "sweep"]
        assert len(sweep) == 2 * 2 * (41 + 21) * 20


class TestSampling:
    def test_quick(self, tmp_path):
        module = load("dpa-sampling")
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        rows = check_outputs("dpa-sampling", md, tmp_path)
        sampling = [r for r in rows if r["table"] == "sampling"]
        # 2 scenes x s_n 1, 2 x g 0, 1 x b tuned / EMC x 2 seeds
        assert len(sampling) == 2 * 2 * 2 * 2 * 2
        assert {r["s_n"] for r in sampling} == {"1", "2"}
        for r in sampling:
            assert float(r["v_eff"]) == pytest.approx(
                int(r["s_n"]) * (0.3 if r["scene"] == "NA23A-like" else 0.2)
            )
            # eq. (16) as implemented: A_S cannot grow with Max_Numbers
            values = [float(r[f"a_s_mn{m}"]) for m in range(1, 8)]
            assert all(a >= b - 1e-9 for a, b in itertools.pairwise(values))
            assert all(math.isfinite(float(r[f"a_s_blk_mn{m}"])) for m in range(1, 8))
        tuning = [r for r in rows if r["table"] == "tuning"]
        assert tuning and all(float(r["b"]) > 0 for r in tuning)
        text = md.read_text()
        assert "0.6 ± 0.15 px/frame" in text and "Max_Numbers" in text

    def test_sampled_scene_keeps_every_step(self):
        module = load("dpa-sampling")
        _, positions = module.sampled_scene("NA23A-like", [1], 5, 24, 3)
        assert positions.shape == (1, 1, 5, 2)
        steps = positions[0, 0, 1:] - positions[0, 0, :-1]
        # 3 frames of 0.3 px/frame between kept frames, plus the jitter of two frames (<= 1 px)
        assert torch.all(torch.linalg.vector_norm(steps, dim=-1) <= 0.9 + 2 * 2**0.5 * 0.5)

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("dpa-sampling")
        rows = check_outputs("dpa-sampling", module.run(out_dir=tmp_path), tmp_path)
        sampling = [r for r in rows if r["table"] == "sampling"]
        assert len(sampling) == 2 * 7 * 2 * 2 * 20


class TestPdSnr:
    def test_quick(self, tmp_path):
        module = load("dpa-pd-snr")
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        rows = check_outputs("dpa-pd-snr", md, tmp_path)
        pd_rows = [r for r in rows if r["table"] == "pd"]
        assert {r["scene"] for r in pd_rows} == {"NPA-like", "clear-sky control"}
        assert len(pd_rows) == 2 * 5 * len(set(module.QUICK_SNRS) | set(module.QUICK_FRAME_SNRS))
        methods = {r["method"] for r in pd_rows}
        assert methods == {
            "single frame",
            "DPA g = 0",
            "DPA g = 0, equal gain",
            "DPA g = 1",
            "DPA tuned",
        }
        for r in pd_rows:
            assert 0.0 <= float(r["pd"]) <= 1.0
            assert 0.0 <= float(r["pd_pixel_last"]) <= 1.0
            assert float(r["frames_to_pd90"]) >= 1.0
        frames = [r for r in rows if r["table"] == "frames"]
        assert {int(r["frames"]) for r in frames} == set(range(1, 9))
        tuned = [r for r in rows if r["table"] == "tuning"]
        assert len(tuned) == 4  # 2 g x 2 b factors
        snr_rows = [r for r in rows if r["table"] == "tuning_snr"]
        assert {float(r["snr_db"]) for r in snr_rows} == set(module.QUICK_SNRS)
        assert any(r["used_for_tuning"] == "1" for r in snr_rows)

    def test_scaled_scenes_equal_simulation(self):
        module = load("dpa-pd-snr")
        c = common()
        scenes = module.Scenes([5], (4, 24, 24))
        direct = c.dpa_scene("NPA-like", [5], shape=(4, 24, 24), snr_db=4.0)
        expected = c.whiten(direct.frames, "anti_mean")
        assert torch.allclose(scenes.frames(4.0), expected, atol=1e-4)
        assert torch.equal(scenes.positions, direct.positions)

    def test_control_scenes(self):
        module = load("dpa-pd-snr")
        cloudy = module.simulate(module.SCENE, [7], (4, 24, 24))
        clear = module.simulate(module.CONTROL, [7], (4, 24, 24))
        assert torch.equal(cloudy.positions, clear.positions)  # same targets and jitter
        assert bool((clear.clouds == 0).all()) and bool((cloudy.clouds > 0).any())
        noise = cloudy.target_free - cloudy.clouds
        assert torch.allclose(clear.target_free, noise, atol=1e-5)

    def test_threshold_is_cfar_threshold(self):
        from hocnet.dpa import cfar_threshold

        module = load("dpa-pd-snr")
        c = common()
        calib = c.whiten(c.dpa_scene("NPA-like", [1, 2], shape=(5, 24, 24)).target_free)
        weights = module._weights()
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

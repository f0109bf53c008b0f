"""Tests of hocnet.learn.apply: detection with the modules of training checkpoints."""

from __future__ import annotations

import math
import warnings

import pytest
import torch

L = pytest.importorskip("lightning")

from hocnet.data.binary import paper_scene  # noqa: E402
from hocnet.dpa import DPA  # noqa: E402
from hocnet.dpa.backtrack import detect as dpa_detect  # noqa: E402
from hocnet.hoc import identify_tracks, mhoc_image  # noqa: E402
from hocnet.hoc.functional import hoc_layer  # noqa: E402
from hocnet.hoc.layers import MHOCImage  # noqa: E402
from hocnet.learn import (  # noqa: E402
    BinarySceneDataModule,
    DPATuner,
    IRSceneDataModule,
    LearnedHOCSystem,
)
from hocnet.learn.apply import detect_dpa, detect_hoc, hoc_settings, load_detector  # noqa: E402


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """One trained DPATuner (full matrices) and one LearnedHOCSystem checkpoint."""
    root = tmp_path_factory.mktemp("ckpt")
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        runs = {
            "dpa": (
                DPATuner(window=5, matrices="full", lr=0.2),
                IRSceneDataModule(n_train=2, n_val=1, n_test=1, shape=(5, 16, 16), speed=1.0),
            ),
            "hoc": (
                LearnedHOCSystem(order=1, v=1, init="random", lr=0.1),
                BinarySceneDataModule(n_train=2, n_val=1, n_test=1, shape=(6, 16, 16), speed=1.0),
            ),
        }
        for name, (system, data) in runs.items():
            trainer = L.Trainer(
                max_epochs=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                enable_model_summary=False, default_root_dir=root / name, limit_val_batches=1,
            )  # fmt: skip
            trainer.fit(system, data)
            (out[name],) = (root / name).rglob("*.ckpt")
            out[name + "_system"] = system
    return out


class TestLoadDetector:
    def test_right_system(self, checkpoints):
        dpa = load_detector(checkpoints["dpa"], "dpa")
        assert isinstance(dpa, DPA)
        assert torch.equal(dpa.weights, checkpoints["dpa_system"].model.weights)
        hoc = load_detector(checkpoints["hoc"], "hoc")
        assert isinstance(hoc, MHOCImage) and not hoc.training
        assert hoc_settings(hoc) == {"order": 1, "v": 1, "delta": math.pi / 4}
        assert isinstance(load_detector(checkpoints["hoc"]), MHOCImage)

    def test_wrong_system(self, checkpoints):
        with pytest.raises(ValueError, match="expected a DPATuner checkpoint"):
            load_detector(checkpoints["hoc"], "dpa")
        with pytest.raises(ValueError, match="expected a LearnedHOCSystem checkpoint"):
            load_detector(checkpoints["dpa"], "hoc")
        with pytest.raises(ValueError, match="`method`"):
            load_detector(checkpoints["dpa"], "svm")

    def test_mismatched_state(self, checkpoints, tmp_path):
        ckpt = torch.load(checkpoints["dpa"], weights_only=True)
        ckpt["hyper_parameters"]["window"] = 3  # the matrices stored are 5 x 5
        path = tmp_path / "bad.ckpt"
        torch.save(ckpt, path)
        with pytest.raises(ValueError, match="does not match"):
            load_detector(path, "dpa")


class TestDetectDPA:
    def test_equals_library_call_with_the_weights(self, checkpoints):
        model = load_detector(checkpoints["dpa"], "dpa")
        frames = torch.randn(2, 5, 16, 16, generator=torch.Generator().manual_seed(0))
        got = detect_dpa(frames, model, max_targets=2)
        want = dpa_detect(
            frames,
            model.weights.detach(),
            float(model.b.detach()),
            float(model.g.detach()),
            max_targets=2,
        )
        assert torch.equal(got.state.asf, want.state.asf)
        assert [t.points.tolist() for t in got.tracks] == [t.points.tolist() for t in want.tracks]
        fixed = dpa_detect(frames, DPA(window=5).weights, float(model.b.detach()), 0.0)
        assert not torch.equal(got.state.asf, fixed.state.asf)  # the learned matrices are used


def mhoc_at(model: MHOCImage, cube: torch.Tensor, theta: float) -> torch.Tensor:
    """Reference: the MHOC image of a ``(T, H, W)`` cube with ``c > theta`` in every layer."""
    outs = []
    for net in (model.forward_net, model.backward_net):
        y = cube[None].float()
        for layer in net.layers:
            y = hoc_layer(
                y,
                layer.mask_kernels.detach(),
                layer.shift_kernels.detach(),
                direction=layer.direction,
                activation=lambda c: (c > theta).float(),
            )
        outs.append(y)
    return torch.maximum(*outs)[0] > 0


class TestDetectHOC:
    def test_learned_support_at_c_gt_half(self, checkpoints):
        cube = paper_scene("table3", 0.012, seed=5).cube
        model = load_detector(checkpoints["hoc"], "hoc")
        assert torch.equal(detect_hoc(cube, model).support, mhoc_at(model, cube, 0.5))
        scaled = MHOCImage(order=2, v=4, learnable=True)
        with torch.no_grad():
            for p in scaled.parameters():
                p.mul_(0.3)
        support = detect_hoc(cube, scaled).support
        assert torch.equal(support, mhoc_at(scaled, cube, 0.5))
        eq3 = mhoc_at(scaled, cube, 0.0)
        assert torch.equal(eq3, mhoc_image(cube, order=2, v=4))  # 0.3 x mask: eq. (3) unchanged
        assert support.sum() < eq3.sum()  # eq. (3) keeps the fixed support, c > 0.5 less

    def test_fixed_module_support_is_the_mhoc_image(self):
        scene = paper_scene("table3", 0.012, seed=5)
        cube = scene.cube
        found = detect_hoc(cube, MHOCImage(order=2, v=4))
        assert torch.equal(found.support, mhoc_image(cube, order=2, v=4))
        tracks, _, cleaned = identify_tracks(
            found.support, 4, math.pi / 4, min_points=5, roots=found.support
        )
        assert torch.equal(found.cleaned, cleaned)
        assert [t.points.tolist() for t in found.tracks] == [t.points.tolist() for t in tracks]
        assert len(found.tracks) >= len(scene.tracks)  # every true track (or more candidates)
        assert not (scene.target_mask & ~found.cleaned).any()  # no target point lost

    def test_learned_support_and_batch(self, checkpoints):
        model = load_detector(checkpoints["hoc"], "hoc")
        dm = BinarySceneDataModule(n_train=1, n_val=1, n_test=2, shape=(6, 16, 16), speed=1.0)
        dm.setup("test")
        cube = torch.stack([s["cube"] for s in dm.scenes("test")]).bool()
        found = detect_hoc(cube, model)
        with torch.no_grad():
            assert torch.equal(found.support, model(cube.float()) > 0.5)
        assert found.cleaned.shape == cube.shape
        assert all(t.batch in (0, 1) for t in found.tracks)
        one = detect_hoc(cube[1], model)
        assert torch.equal(one.support, found.support[1])
        empty = detect_hoc(cube[:0], model)
        assert empty.support.shape == (0, 6, 16, 16) and empty.tracks == []
        with pytest.raises(ValueError, match="frames"):
            detect_hoc(torch.full((6, 16, 16), 0.5), model)

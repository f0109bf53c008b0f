"""Tests of hocnet.learn.systems and .train: smoke, constraints, checkpoints, learning."""

from __future__ import annotations

import math
import warnings

import pytest
import torch

L = pytest.importorskip("lightning")

from hocnet.dpa import DPA, b_limit  # noqa: E402
from hocnet.hoc.functional import hoc_layer  # noqa: E402
from hocnet.hoc.layers import LEARNED_THRESHOLD, MHOCImage  # noqa: E402
from hocnet.learn import (  # noqa: E402
    BinarySceneDataModule,
    DPATuner,
    IRSceneDataModule,
    LearnedHOCSystem,
    dpa_loss,
    load_model,
    project_b,
)
from hocnet.metrics import clutter_rejection, target_points_lost  # noqa: E402

IR_TINY = {"n_train": 4, "n_val": 2, "n_test": 2, "shape": (5, 16, 16), "speed": (0.1, 1.0)}
BIN_TINY = {"n_train": 4, "n_val": 2, "n_test": 2, "shape": (6, 16, 16), "speed": (0.1, 1.0)}


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def mhoc_at(model: MHOCImage, cube: torch.Tensor, theta: float) -> torch.Tensor:
    """Reference: the MHOC image with the limiter ``c > theta`` written into every layer."""
    outs = []
    for net in (model.forward_net, model.backward_net):
        y = cube.float()
        for layer in net.layers:
            y = hoc_layer(
                y,
                layer.mask_kernels.detach(),
                layer.shift_kernels.detach(),
                direction=layer.direction,
                activation=lambda c: (c > theta).float(),
            )
        outs.append(y)
    return torch.maximum(*outs)


def _scale(module: torch.nn.Module, factor: float) -> None:
    with torch.no_grad():
        for p in module.parameters():
            p.mul_(factor)


def _trainer(**kwargs) -> L.Trainer:
    defaults = {
        "accelerator": "cpu",
        "logger": False,
        "enable_progress_bar": False,
        "enable_model_summary": False,
        "enable_checkpointing": False,
    }
    return L.Trainer(**{**defaults, **kwargs})


class TestDPALoss:
    def test_against_loop(self):
        gen = torch.Generator().manual_seed(0)
        asf = torch.randn(3, 5, 6, generator=gen, dtype=torch.float64)
        pixels = torch.tensor([[0, 7], [29, 3], [12, 12]])
        expected = 0.0
        for b in range(3):
            values = asf[b].flatten().tolist()
            mean = sum(values) / len(values)
            std = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
            z = [(v - mean) / std / 0.5 for v in values]
            log_norm = math.log(sum(math.exp(v) for v in z))
            expected += sum(log_norm - z[int(p)] for p in pixels[b]) / 2
        assert dpa_loss(asf, pixels, 0.5).item() == pytest.approx(expected / 3, rel=1e-10)

    def test_scale_invariant_and_empty(self):
        asf = torch.randn(2, 6, 6, dtype=torch.float64)
        pixels = torch.tensor([[3], [20]])
        assert dpa_loss(3.0 * asf + 2.0, pixels).item() == pytest.approx(
            dpa_loss(asf, pixels).item(), rel=1e-10
        )
        assert dpa_loss(asf[:0], pixels[:0]).item() == 0.0
        with pytest.raises(ValueError, match="temperature"):
            dpa_loss(asf, pixels, 0.0)


class TestDPATuner:
    def test_fast_dev_run(self):
        dm = IRSceneDataModule(**IR_TINY, batch_size=2)
        tuner = DPATuner(window=5)
        trainer = _trainer(fast_dev_run=True)
        trainer.fit(tuner, dm)
        (results,) = trainer.test(tuner, dm, verbose=False)
        for key in ("test/loss", "test/hit1", "test/auroc", "test/pd", "test/smooth_gap"):
            assert math.isfinite(results[key]), key
        assert 0.0 <= results["test/pd"] <= 1.0 and 0.0 <= results["test/auroc"] <= 1.0
        assert 0.0 <= results["test/pfa"] <= tuner.hparams["pfa"]
        assert results["test/asf_gap"] >= 0.0
        assert tuner.model.smooth is None  # test ran with the hard max

    def test_smooth_gap_against_direct_computation(self):
        dm = IRSceneDataModule(**IR_TINY, batch_size=2)
        tuner = DPATuner(window=5, tau_end=0.2)
        (results,) = _trainer().test(tuner, dm, verbose=False)
        losses, gaps = [], []
        for batch in dm.test_dataloader():
            with torch.no_grad():
                tuner.model.smooth = None
                hard = tuner.model(batch["frames"]).asf
                tuner.model.smooth = 0.2
                soft = tuner.model(batch["frames"]).asf
                tuner.model.smooth = None
            loss_h, loss_s = tuner.loss(hard, batch["pixels"]), tuner.loss(soft, batch["pixels"])
            losses.append(float(loss_s - loss_h))
            for b in range(hard.shape[0]):
                h, s = hard[b, -1].flatten(), soft[b, -1].flatten()
                gaps.append(float((s - h).abs().mean() / h.std()))
        assert results["test/smooth_gap"] == pytest.approx(sum(losses) / len(losses), rel=1e-4)
        assert results["test/asf_gap"] == pytest.approx(sum(gaps) / len(gaps), rel=1e-4)
        assert results["test/asf_gap"] > 0  # the smooth max is not the hard max

    def test_full_matrices(self):
        tuner = DPATuner(window=5, matrices="full")
        names = sorted(name for name, _ in tuner.model.named_parameters())
        assert names == ["b_raw", "g_raw", "matrices_raw"]
        assert tuner.hparams["learnable"] == ["b", "g", "matrices"]
        paper = DPATuner(window=5, learnable=("b", "g"))
        assert torch.equal(tuner.model.weights, paper.model.weights)  # starts at eq. (5)
        dm = IRSceneDataModule(**IR_TINY, batch_size=2)
        trainer = _trainer(max_epochs=1, limit_val_batches=0, num_sanity_val_steps=0)
        trainer.fit(tuner, dm)
        w = tuner.model.weights.detach()
        assert not torch.equal(w, paper.model.weights)
        assert bool((w >= 0).all())
        assert torch.allclose(w.sum(dim=(-2, -1)), torch.ones(9), atol=1e-5)
        with pytest.raises(ValueError, match="matrices"):
            DPATuner(matrices="diagonal")

    def test_constraints_after_steps(self):
        dm = IRSceneDataModule(**IR_TINY, batch_size=2)
        dm.setup("fit")
        # large steps from a start near the edge of the memory range
        tuner = DPATuner(window=5, b=9.0, g=0.1, lr=2.0, b_margin=0.95)
        opt = tuner.configure_optimizers()
        for batch in dm.train_dataloader():
            for _ in range(3):
                opt.zero_grad()
                tuner.model.smooth = 0.5
                loss = tuner.loss(tuner.model(batch["frames"]).asf, batch["pixels"])
                loss.backward()
                opt.step()
                project_b(tuner.model, 0.95)
                m = tuner.model
                assert 0.0 <= float(m.g) <= 1.0
                assert 0.0 <= float(m.p) <= 1.0
                assert 0.0 <= float(m.penalty_step) <= 3.0
                assert 0.0 <= float(m.b) <= 0.95 * b_limit(m.weights, m.g) * (1 + 1e-5)
                w = m.weights
                assert bool((w >= 0).all())

    def test_tau_annealing(self):
        import types

        tuner = DPATuner(window=5, tau_start=1.0, tau_end=0.01)
        assert tuner.tau() == 1.0  # no trainer yet
        tuner._trainer = types.SimpleNamespace(max_epochs=3, current_epoch=0)
        taus = []
        for epoch in range(3):
            tuner._trainer.current_epoch = epoch
            taus.append(tuner.tau())
        assert taus == pytest.approx([1.0, 0.1, 0.01])

    def test_track_weight(self):
        dm = IRSceneDataModule(**IR_TINY, snr_db=20.0)
        dm.setup("fit")
        batch = next(iter(dm.train_dataloader()))
        asf = DPATuner(window=5).model(batch["frames"]).asf.detach()
        last = DPATuner(window=5).loss(asf, batch["pixels"])
        both = DPATuner(window=5, track_weight=0.5).loss(asf, batch["pixels"])
        frames = [dpa_loss(asf[:, t], batch["pixels"][:, :, t]) for t in range(1, 4)]
        expected = last + 0.5 * torch.stack(frames).mean()
        assert both.item() == pytest.approx(expected.item(), rel=1e-6)

    def test_project_b(self):
        dpa = DPA(window=5, b=1.0, learnable="b")
        assert not project_b(dpa)  # inside the range: untouched
        assert float(dpa.b) == pytest.approx(1.0, rel=1e-6)
        fixed = DPA(window=5, b=1.0)
        assert not project_b(fixed)

    def test_start_inside_bounds(self):
        tuner = DPATuner(window=5, g=0.0, penalty_step=3.0, init_margin=0.02)
        assert float(tuner.model.g) == pytest.approx(0.02, rel=1e-5)
        assert float(tuner.model.penalty_step) == pytest.approx(2.94, rel=1e-5)
        with pytest.raises(ValueError, match="tau_end"):
            DPATuner(tau_end=0.0)

    def test_learning_reduces_held_out_loss(self):
        # easy setting: slow targets; a start with little memory (b = 0.3, g = 0.5)
        dm = IRSceneDataModule(
            n_train=16, n_val=12, n_test=1, shape=(8, 24, 24), snr_db=(4.0, 8.0),
            speed=(0.1, 0.5), batch_size=4,
        )  # fmt: skip
        dm.setup("fit")
        tuner = DPATuner(window=5, b=0.3, g=0.5, lr=0.1)

        def held_out() -> float:
            tuner.model.smooth = None
            with torch.no_grad():
                losses = [
                    float(tuner.loss(tuner.model(b["frames"]).asf, b["pixels"]))
                    for b in dm.val_dataloader()
                ]
            return sum(losses) / len(losses)

        before = held_out()
        trainer = _trainer(max_epochs=4, limit_val_batches=0, num_sanity_val_steps=0)
        trainer.fit(tuner, dm)  # 16 steps
        after = held_out()
        assert after < before - 0.2, (before, after)
        assert float(tuner.model.b) > 0.3


class TestLearnedHOCSystem:
    def test_fast_dev_run(self):
        dm = BinarySceneDataModule(**BIN_TINY, batch_size=2, clutter_density=0.05)
        system = LearnedHOCSystem(order=1, v=1)
        trainer = _trainer(fast_dev_run=True)
        trainer.fit(system, dm)
        (results,) = trainer.test(system, dm, verbose=False)
        for key in ("test/loss", "test/clutter_rejection", "test/target_points_lost"):
            assert math.isfinite(results[key]), key
        assert 0.0 <= results["test/pd"] <= 1.0 and 0.0 <= results["test/pfa"] <= 1.0
        assert 0.0 <= results["test/auroc"] <= 1.0

    def test_relaxed_in_training_hard_in_eval(self):
        dm = BinarySceneDataModule(**BIN_TINY, clutter_density=0.05)
        dm.setup("fit")
        cube = dm.scenes("train")[0]["cube"][None]
        system = LearnedHOCSystem(order=1, v=1)
        system.train()
        soft = system(cube)
        assert bool(((soft > 0) & (soft < 1)).any())
        system.eval()
        hard = system(cube)
        assert set(hard.unique().tolist()) <= {0.0, 1.0}
        # from the fixed masks, the hard network is the paper's fixed network
        fixed = MHOCImage(order=1, v=1)
        assert torch.equal(hard, fixed(cube))

    def test_random_init_differs(self):
        a = LearnedHOCSystem(order=1, v=1, init="random", seed=1)
        b = LearnedHOCSystem(order=1, v=1, init="fixed")
        assert not torch.equal(
            a.model.forward_net.layers[0].mask_kernels, b.model.forward_net.layers[0].mask_kernels
        )


class TestLearnedLimiter:
    """Val / test steps and load_model use the learnable layers' ``c > 0.5`` (not eq. 3's 0)."""

    def test_test_step_counts_at_c_gt_half(self):
        dm = BinarySceneDataModule(**BIN_TINY, batch_size=2, clutter_density=0.08)
        system = LearnedHOCSystem(order=1, v=1)
        _scale(system.model, 0.3)  # counts 0.3 k: "off" at 0.5 where the fixed count k is 1
        (results,) = _trainer().test(system, dm, verbose=False)
        dm.setup("test")
        cube = torch.stack([s["cube"] for s in dm.scenes("test")])
        target = torch.stack([s["target"] for s in dm.scenes("test")])
        points = cube > 0
        with torch.no_grad():
            at = {t: mhoc_at(system.model, cube, t) > 0.5 for t in (0.0, LEARNED_THRESHOLD)}
        lost = {t: int(target_points_lost(points, k, target).sum()) for t, k in at.items()}
        assert lost[0.0] != lost[0.5]  # the data tells the two limiters apart
        assert results["test/target_points_lost"] == lost[0.5]
        rejection = clutter_rejection(points, at[0.5], target)
        assert results["test/clutter_rejection"] == pytest.approx(float(rejection.mean()))

    def test_eval_from_fixed_is_the_fixed_network(self):
        dm = BinarySceneDataModule(**BIN_TINY, clutter_density=0.05)
        dm.setup("fit")
        cube = torch.stack([s["cube"] for s in dm.scenes("train")])
        system = LearnedHOCSystem(order=2, v=1).eval()
        with torch.no_grad():
            assert torch.equal(system(cube), MHOCImage(order=2, v=1)(cube))

    def test_loaded_model_limiter(self, tmp_path):
        dm = BinarySceneDataModule(**BIN_TINY, batch_size=2, clutter_density=0.05)
        system = LearnedHOCSystem(order=1, v=1, init="random", lr=0.1)
        trainer = _trainer(
            max_epochs=1, enable_checkpointing=True, default_root_dir=tmp_path, limit_val_batches=1
        )
        trainer.fit(system, dm)
        (ckpt,) = tmp_path.rglob("*.ckpt")
        model = load_model(ckpt)
        layers = [*model.forward_net.layers, *model.backward_net.layers]
        assert all(layer.threshold == LEARNED_THRESHOLD for layer in layers)
        cube = torch.stack([s["cube"] for s in dm.scenes("val")])
        with torch.no_grad():
            assert torch.equal(model(cube), mhoc_at(model, cube, LEARNED_THRESHOLD))


class _Evil:
    ran = False

    def __reduce__(self):
        return (setattr, (_Evil, "ran", True))


class TestCheckpoint:
    def test_dpa_round_trip(self, tmp_path):
        dm = IRSceneDataModule(**IR_TINY, batch_size=2)
        tuner = DPATuner(window=5, lr=0.2)
        trainer = _trainer(
            max_epochs=1, enable_checkpointing=True, default_root_dir=tmp_path, limit_val_batches=1
        )
        trainer.fit(tuner, dm)
        (ckpt,) = tmp_path.rglob("*.ckpt")
        model = load_model(ckpt)
        assert isinstance(model, DPA) and model.smooth is None and not model.training
        for name in ("b", "g", "p", "penalty_step"):
            assert float(getattr(model, name)) == float(getattr(tuner.model, name)), name
        assert float(model.g) != pytest.approx(0.02, abs=1e-4)  # trained, not the start
        frames = dm.scenes("val")[0]["frames"]
        tuner.model.smooth = None
        with torch.no_grad():
            assert torch.equal(model(frames).asf, tuner.model(frames).asf)

    def test_hoc_round_trip(self, tmp_path):
        dm = BinarySceneDataModule(**BIN_TINY, batch_size=2, clutter_density=0.05)
        system = LearnedHOCSystem(order=1, v=1, init="random", lr=0.1)
        trainer = _trainer(
            max_epochs=1, enable_checkpointing=True, default_root_dir=tmp_path, limit_val_batches=1
        )
        trainer.fit(system, dm)
        (ckpt,) = tmp_path.rglob("*.ckpt")
        model = load_model(ckpt)
        assert isinstance(model, MHOCImage) and not model.training
        cube = dm.scenes("val")[0]["cube"][None]
        system.eval()
        with torch.no_grad():
            assert torch.equal(model(cube), system.model(cube))

    def test_full_matrices_round_trip(self, tmp_path):
        dm = IRSceneDataModule(**IR_TINY, batch_size=2)
        tuner = DPATuner(window=5, matrices="full", lr=0.2)
        trainer = _trainer(
            max_epochs=1, enable_checkpointing=True, default_root_dir=tmp_path, limit_val_batches=1
        )
        trainer.fit(tuner, dm)
        (ckpt,) = tmp_path.rglob("*.ckpt")
        model = load_model(ckpt)
        assert "matrices" in model.learnable
        assert torch.equal(model.weights, tuner.model.weights)
        assert not torch.equal(model.weights, DPA(window=5).weights)

    def test_refuses_corrupted_and_untrusted(self, tmp_path):
        good = tmp_path / "good.pt"
        torch.save({"state_dict": {}}, good)
        data = good.read_bytes()
        cut = tmp_path / "cut.pt"
        cut.write_bytes(data[: len(data) // 2])
        with pytest.raises(ValueError, match="corrupted"):
            load_model(cut)
        empty = tmp_path / "empty.pt"
        empty.write_bytes(b"")
        with pytest.raises(ValueError, match="corrupted"):
            load_model(empty)
        evil = tmp_path / "evil.pt"
        torch.save({"state_dict": {}, "x": _Evil()}, evil)
        with pytest.raises(ValueError, match="untrusted pickle"):
            load_model(evil)
        assert not _Evil.ran
        with pytest.raises(FileNotFoundError):
            load_model(tmp_path / "missing.ckpt")

    def test_refuses_other_files(self, tmp_path):
        path = tmp_path / "x.pt"
        torch.save({"a": torch.zeros(1)}, path)
        with pytest.raises(ValueError, match="ckpt_path"):
            load_model(path)
        torch.save({"state_dict": {"other.w": torch.zeros(1)}}, path)
        with pytest.raises(ValueError, match="ckpt_path"):
            load_model(path)


class TestStageMetrics:
    @pytest.mark.parametrize("system", ["dpa", "hoc"])
    def test_val_pd_pfa_auroc(self, system):
        if system == "dpa":
            model, dm = DPATuner(window=5), IRSceneDataModule(**IR_TINY, batch_size=2)
        else:
            model = LearnedHOCSystem(order=1, v=1)
            dm = BinarySceneDataModule(**BIN_TINY, batch_size=2, clutter_density=0.05)
        trainer = _trainer(max_epochs=1, limit_train_batches=1, num_sanity_val_steps=0)
        trainer.fit(model, dm)
        logged = trainer.callback_metrics
        assert math.isfinite(float(logged["val/loss"]))
        for key in ("val/pd", "val/pfa", "val/auroc"):
            assert key in logged, key
            assert 0.0 <= float(logged[key]) <= 1.0, key

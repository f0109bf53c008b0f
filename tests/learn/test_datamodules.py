"""Tests of hocnet.learn.datamodules: seeds, determinism, ground truth, validation."""

from __future__ import annotations

import math

import pytest
import torch

pytest.importorskip("lightning")

from hocnet.learn.datamodules import (
    SPLIT_OFFSET,
    BinarySceneDataModule,
    IRSceneDataModule,
    split_seeds,
)

IR_SMALL = {"n_train": 3, "n_val": 2, "n_test": 2, "shape": (5, 16, 16), "speed": (0.1, 1.0)}
BIN_SMALL = {"n_train": 3, "n_val": 2, "n_test": 2, "shape": (6, 16, 16), "speed": (0.1, 1.0)}


class TestSplitSeeds:
    def test_disjoint_and_recorded(self):
        sizes = {"train": 5, "val": 3, "test": 4}
        seeds = split_seeds(11, sizes)
        sets = {k: set(range(*v)) for k, v in seeds.items()}
        assert [len(sets[k]) for k in ("train", "val", "test")] == [5, 3, 4]
        assert not sets["train"] & sets["val"]
        assert not sets["train"] & sets["test"]
        assert not sets["val"] & sets["test"]
        dm = IRSceneDataModule(seed=11, n_train=5, n_val=3, n_test=4, shape=(5, 16, 16))
        assert dm.hparams["split_seeds"] == seeds

    def test_too_many_scenes(self):
        with pytest.raises(ValueError, match="n_train"):
            split_seeds(0, {"train": SPLIT_OFFSET["val"] + 1, "val": 1, "test": 1})


@pytest.mark.parametrize(
    ("cls", "kwargs", "key"),
    [(IRSceneDataModule, IR_SMALL, "frames"), (BinarySceneDataModule, BIN_SMALL, "cube")],
)
class TestSceneModules:
    def test_setup_not_init(self, cls, kwargs, key):
        dm = cls(**kwargs)
        assert dm.datasets == {}
        dm.setup("test")
        assert set(dm.datasets) == {"test"}
        dm.setup("fit")
        assert set(dm.datasets) == {"train", "val", "test"}

    def test_deterministic(self, cls, kwargs, key):
        a, b = cls(**kwargs), cls(**kwargs)
        a.setup()
        b.setup()
        for split in ("train", "val", "test"):
            for sa, sb in zip(a.scenes(split), b.scenes(split)):
                for name in sa:
                    assert torch.equal(sa[name], sb[name])
        # the shuffled training order is seeded too
        order_a = [x[key] for x in a.train_dataloader()]
        order_b = [x[key] for x in b.train_dataloader()]
        assert all(torch.equal(x, y) for x, y in zip(order_a, order_b))

    def test_splits_and_seeds_differ(self, cls, kwargs, key):
        dm = cls(**kwargs)
        dm.setup()
        train, test = dm.scenes("train")[0][key], dm.scenes("test")[0][key]
        assert not torch.equal(train, test)
        other = cls(**{**kwargs, "seed": 1})
        other.setup("fit")
        assert not torch.equal(other.scenes("train")[0][key], train)

    def test_batches(self, cls, kwargs, key):
        dm = cls(**{**kwargs, "batch_size": 2})
        dm.setup("fit")
        batch = next(iter(dm.train_dataloader()))
        assert batch[key].shape == (2, *kwargs["shape"])
        assert sum(len(b[key]) for b in dm.val_dataloader()) == kwargs["n_val"]

    def test_bad_input(self, cls, kwargs, key):
        with pytest.raises(ValueError, match="speed"):
            cls(**{**kwargs, "speed": (0.5, 2.5)})
        with pytest.raises(TypeError, match="shape"):
            cls(**{**kwargs, "shape": (16, 16)})
        with pytest.raises(ValueError, match="shape"):
            cls(**{**kwargs, "shape": (20, 8, 8), "speed": 2.0})


class TestIRSceneDataModule:
    def test_pixels_are_the_target_peaks(self):
        # strong, jitter-free targets: the whitened target signal peaks at the nearest pixel
        dm = IRSceneDataModule(**IR_SMALL, snr_db=30.0, jitter=0.0, n_targets=1)
        dm.setup("fit")
        for sample in dm.scenes("train"):
            signal = (sample["frames"] - sample["target_free"]).flatten(1)  # (T, H * W)
            assert torch.equal(signal.argmax(1), sample["pixels"][0])
            assert sample["positions"].shape == (1, 5, 2)

    def test_tracks_stay_inside_with_margin(self):
        dm = IRSceneDataModule(**{**IR_SMALL, "n_train": 8}, jitter=0.0, margin=3.0, n_targets=2)
        dm.setup("fit")
        pos = torch.stack([s["positions"] for s in dm.scenes("train")])
        assert pos.min() >= 3.0 - 1e-4
        assert pos.max() <= 16 - 1 - 3.0 + 1e-4
        speeds = (pos[..., 1:, :] - pos[..., :-1, :]).norm(dim=-1)
        assert speeds.min() >= 0.1 - 1e-4
        assert speeds.max() <= 1.0 + 1e-4


class TestBinarySceneDataModule:
    def test_labels(self):
        dm = BinarySceneDataModule(**BIN_SMALL, n_targets=1, clutter_density=0.05)
        dm.setup("fit")
        for sample in dm.scenes("train"):
            cube, target = sample["cube"], sample["target"]
            assert cube.dtype == torch.float32 and target.dtype == torch.bool
            assert bool((cube[target] == 1).all())
            assert int(target.sum()) == 6  # one point per scan, inside the frame, no misses
            assert int((target.sum(dim=(1, 2)) == 1).sum()) == 6

    def test_clutter_density_range(self):
        dm = BinarySceneDataModule(
            **{**BIN_SMALL, "n_train": 6}, n_targets=0, clutter_density=(0.0, 0.1)
        )
        dm.setup("fit")
        densities = [float(s["cube"].mean()) for s in dm.scenes("train")]
        assert 0.0 <= min(densities) < max(densities) <= 0.15


def _angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Signed angle from vector ``a`` to ``b`` (``(..., 2)``), in ``(-pi, pi]``."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    dot = (a * b).sum(-1)
    return torch.atan2(cross, dot)


class TestManeuvers:
    def test_ir_sharp_maneuver(self):
        dm = IRSceneDataModule(
            n_train=12, n_val=1, n_test=1, shape=(8, 28, 28), speed=(0.5, 1.5), jitter=0.0,
            n_targets=2, maneuver_prob=1.0, maneuver_turn=math.pi / 3, margin=2.0,
        )  # fmt: skip
        dm.setup("fit")
        seen = set()
        for sample in dm.scenes("train"):
            pos = sample["positions"].double()  # (N, T, 2)
            assert pos.min() >= 2.0 - 1e-4 and pos.max() <= 27 - 2.0 + 1e-4
            steps = pos[:, 1:] - pos[:, :-1]  # (N, T - 1, 2): step t moves frame t -> t + 1
            for n, at in enumerate(sample["maneuver_at"].tolist()):
                assert 1 <= at <= 6
                seen.add(at)
                before, after = steps[n, :at], steps[n, at:]
                speeds = [before.norm(dim=-1), after.norm(dim=-1)]
                for s in speeds:  # constant speed on each piece, within the range
                    assert float(s.max() - s.min()) < 1e-4
                    assert 0.5 - 1e-4 <= float(s[0]) <= 1.5 + 1e-4
                assert float(_angle(before[0], before[-1]).abs()) < 1e-4  # straight before
                assert float(_angle(before[-1], after[0]).abs()) <= math.pi / 3 + 1e-4
        assert len(seen) > 2  # the maneuver frame varies

    def test_ir_gentle_turns(self):
        dm = IRSceneDataModule(
            n_train=6, n_val=1, n_test=1, shape=(8, 28, 28), speed=(0.5, 1.0), jitter=0.0,
            turn_rate=(0.1, 0.2),
        )  # fmt: skip
        dm.setup("fit")
        signs = set()
        for sample in dm.scenes("train"):
            steps = sample["positions"][0, 1:].double() - sample["positions"][0, :-1].double()
            turn = _angle(steps[:-1], steps[1:])  # per-frame heading change
            assert float(turn.abs().min()) >= 0.1 - 1e-4 and float(turn.abs().max()) <= 0.2 + 1e-4
            assert float(turn.max() - turn.min()) < 1e-4  # one rate per target
            signs.add(bool(turn[0] > 0))
            assert sample["maneuver_at"].tolist() == [-1]
        assert signs == {True, False}

    def test_binary_pieces_make_one_track(self):
        dm = BinarySceneDataModule(
            n_train=10, n_val=1, n_test=1, shape=(8, 24, 24), speed=(0.5, 2.0), n_targets=1,
            clutter_density=0.0, maneuver_prob=1.0, turn_rate=(0.0, 0.1),
        )  # fmt: skip
        dm.setup("fit")
        for sample in dm.scenes("train"):
            target = sample["target"]
            assert bool(torch.equal(target, sample["cube"].bool()))
            assert target.sum(dim=(1, 2)).tolist() == [1] * 8  # one point per scan, no gap
            pts = target.nonzero()[:, 1:].double()  # (T, 2) y, x in scan order
            assert float((pts[1:] - pts[:-1]).norm(dim=-1).max()) <= 2.0 + math.sqrt(2)
            assert 1 <= int(sample["maneuver_at"][0]) <= 6

    @pytest.mark.parametrize("cls", [IRSceneDataModule, BinarySceneDataModule])
    def test_deterministic_and_validated(self, cls):
        kw = {"n_train": 3, "n_val": 1, "n_test": 1, "shape": (6, 20, 20), "speed": (0.1, 1.0),
              "turn_rate": 0.1, "maneuver_prob": 0.5}  # fmt: skip
        a, b = cls(**kw), cls(**kw)
        a.setup("fit")
        b.setup("fit")
        for sa, sb in zip(a.scenes("train"), b.scenes("train")):
            assert all(torch.equal(sa[k], sb[k]) for k in sa)
        assert a.hparams["maneuver_prob"] == 0.5 and a.hparams["turn_rate"] == 0.1
        assert a.hparams["split_seeds"]["train"] == [0, 3]
        with pytest.raises(ValueError, match="turn_rate"):
            cls(**{**kw, "turn_rate": 1.0})
        with pytest.raises(ValueError, match="maneuver_prob"):
            cls(**{**kw, "maneuver_prob": 1.5})
        with pytest.raises(ValueError, match="maneuver_turn"):
            cls(**{**kw, "maneuver_turn": -0.1})

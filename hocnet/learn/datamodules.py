"""Seeded simulator data modules for training the DPA and the HOC network (our addition).

Scenes are generated in :meth:`setup` (never in ``__init__``), one seed per scene. The train,
validation and test seeds are disjoint ranges (``seed + SPLIT_OFFSET[split] + i``), recorded in
the hyper-parameters as ``split_seeds`` (``{split: [first, last + 1]}``), so the same module with
the same arguments yields the same scenes bit for bit.

* :class:`IRSceneDataModule`: IR sequences of :func:`hocnet.data.simulate_ir` ([NR08]) with random
  targets (peak SNR, speed 0.1-2 px/frame, heading), whitened by anti-mean or anti-median;
  each sample also holds the whitened target-free frames (same clouds, jitter and noise) for a
  per-pixel false-alarm threshold.
* :class:`BinarySceneDataModule`: binary scans of :func:`hocnet.data.simulate_binary` ([LA98]) with
  random targets and uniform clutter; each sample holds the per-point target labels.

Targets move straight by default; ``turn_rate`` (gentle turns, rad/frame) and ``maneuver_prob``
(one sharp maneuver: a heading change up to ``maneuver_turn`` and a new speed drawn from
``speed``, i.e. an acceleration or deceleration) make them maneuver (our addition; the
simulators' own ``turn_rate`` / ``turn_at`` in the IR case, two consecutive track pieces in the
binary case). Every random number comes from the scene's seed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import lightning as L
import torch
from torch.utils.data import DataLoader, Dataset

from hocnet._check import check_choice, check_int, check_number
from hocnet.data.binary import TargetSpec, simulate_binary
from hocnet.data.infrared import CLOUD_PRESETS, IRTarget, simulate_ir
from hocnet.data.whitening import anti_mean, anti_median

__all__ = ["SPLIT_OFFSET", "BinarySceneDataModule", "IRSceneDataModule", "split_seeds"]

SPLITS = ("train", "val", "test")
#: Offset of each split's seed range; a split holds at most ``SPLIT_OFFSET["val"]`` scenes.
SPLIT_OFFSET = {"train": 0, "val": 1_000_000, "test": 2_000_000}
_WHITEN = {"anti_mean": anti_mean, "anti_median": anti_median}


def split_seeds(seed: int, sizes: dict[str, int]) -> dict[str, list[int]]:
    """Disjoint seed ranges ``{split: [first, stop)}`` of the train / val / test scenes.

    Args:
        seed: base seed (``>= 0``).
        sizes: number of scenes per split, each in ``[0, 1_000_000]``.

    Returns:
        ``{split: [first, stop]}`` with ``first = seed + SPLIT_OFFSET[split]`` and
        ``stop = first + sizes[split]``.

    Examples:
        >>> split_seeds(7, {"train": 2, "val": 1, "test": 1})
        {'train': [7, 9], 'val': [1000007, 1000008], 'test': [2000007, 2000008]}
    """
    seed = check_int("seed", seed, minimum=0)
    out = {}
    for split in SPLITS:
        n = check_int(f"n_{split}", sizes[split], minimum=0, maximum=SPLIT_OFFSET["val"])
        first = seed + SPLIT_OFFSET[split]
        out[split] = [first, first + n]
    return out


def _range(name: str, value: Any, low: float, high: float) -> tuple[float, float]:
    """A pair ``low <= lo <= hi <= high``; a number or ``(x,)`` means ``(x, x)``."""
    if isinstance(value, (int, float)):
        value = (value, value)
    if isinstance(value, Sequence) and len(value) == 1:
        value = (value[0], value[0])
    if not isinstance(value, Sequence) or len(value) != 2:
        raise TypeError(f"`{name}`: expected a number or a pair (lo, hi), got {value!r}")
    lo = check_number(name, value[0], low=low, high=high)
    hi = check_number(name, value[1], low=lo, high=high)
    return (lo, hi)


def _shape(value: Any) -> tuple[int, int, int]:
    if not isinstance(value, Sequence) or len(value) != 3:
        raise TypeError(f"`shape`: expected (T, H, W), got {value!r}")
    return tuple(check_int("shape", s, minimum=1) for s in value)  # type: ignore[return-value]


def _uniform(gen: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand((), generator=gen, dtype=torch.float64))


class _Track:
    """A drawn track: start ``(x0, y0)``, first velocity, turn rate, optional maneuver."""

    def __init__(self, x0, y0, vx, vy, rate, turn_at, new_velocity) -> None:
        self.x0, self.y0, self.vx, self.vy = x0, y0, vx, vy
        self.rate, self.turn_at, self.new_velocity = rate, turn_at, new_velocity


def _relative_positions(
    n: int, vx: float, vy: float, rate: float, turn_at: int | None, new_v: Any
) -> list[tuple[float, float]]:
    """Positions of frames ``0 .. n - 1`` from ``(0, 0)`` (the stepping of ``IRTarget``).

    Step ``t -> t + 1`` moves by ``v_t``: ``v_0 = (vx, vy)``, ``v_t = R(rate) v_{t-1}``, except
    ``v_turn_at = new_v`` (then rotated on).
    """
    c, s = math.cos(rate), math.sin(rate)
    x = y = 0.0
    out = []
    for t in range(n):
        out.append((x, y))
        if t > 0 and rate != 0.0:
            vx, vy = c * vx - s * vy, s * vx + c * vy
        if t == turn_at:
            vx, vy = new_v
        x, y = x + vx, y + vy
    return out


def _maneuvering_track(
    gen: torch.Generator,
    shape: tuple[int, int, int],
    speed: tuple[float, float],
    margin: float,
    turn_rate: tuple[float, float],
    maneuver_prob: float,
    maneuver_turn: float,
) -> _Track:
    """A seeded track inside the frame (``margin`` px): straight, turning, or maneuvering.

    Draws, in this order: speed, heading; if ``turn_rate != (0, 0)``: the turn rate (magnitude
    uniform in ``turn_rate``, random sign); if ``maneuver_prob > 0``: whether the target
    maneuvers, the frame ``turn_at`` (uniform in ``1 .. T - 2``), the heading change (uniform in
    ``[-maneuver_turn, maneuver_turn]``) and the new speed (uniform in ``speed``: an
    acceleration or a deceleration); finally the start, uniform where the whole trajectory stays
    inside. Without turns and maneuvers the draws are those of a straight track.
    """
    t_len, h, w = shape
    v = _uniform(gen, *speed)
    heading = _uniform(gen, -math.pi, math.pi)
    vx, vy = v * math.cos(heading), v * math.sin(heading)
    rate = 0.0
    if turn_rate != (0.0, 0.0):
        rate = _uniform(gen, *turn_rate)
        if float(torch.rand((), generator=gen, dtype=torch.float64)) < 0.5:
            rate = -rate
    turn_at, new_v = None, None
    if maneuver_prob > 0:
        happens = float(torch.rand((), generator=gen, dtype=torch.float64)) < maneuver_prob
        at = 1 + int(torch.randint(max(1, t_len - 2), (), generator=gen))
        turn = _uniform(gen, -maneuver_turn, maneuver_turn)
        v_new = _uniform(gen, *speed)
        if happens and t_len >= 3:
            turn_at = at
            # the heading at frame `at` (before the maneuver): rotated `at - 1` times
            bearing = heading + rate * (at - 1) + turn
            new_v = (v_new * math.cos(bearing), v_new * math.sin(bearing))
    rel = _relative_positions(t_len, vx, vy, rate, turn_at, new_v)
    xs, ys = [p[0] for p in rel], [p[1] for p in rel]
    x_lo, x_hi = margin - min(xs), w - 1 - margin - max(xs)
    y_lo, y_hi = margin - min(ys), h - 1 - margin - max(ys)
    if x_lo > x_hi or y_lo > y_hi:
        raise ValueError(
            f"`shape`: expected a frame large enough for {t_len} frames at {v:.3g} px/frame "
            f"with a {margin:g} px margin, got {shape}"
        )
    return _Track(
        _uniform(gen, x_lo, x_hi), _uniform(gen, y_lo, y_hi), vx, vy, rate, turn_at, new_v
    )


def _check_fits(shape: tuple[int, int, int], speed: tuple[float, float], margin: float) -> None:
    """Refuse frames too small for the fastest axis-aligned track (``ValueError`` on ``shape``)."""
    t_len, h, w = shape
    need = speed[1] * (t_len - 1) + 2 * margin
    if need > min(h, w) - 1:
        raise ValueError(
            f"`shape`: expected H and W above {need + 1:g} px (tracks of {t_len} frames at up to "
            f"{speed[1]:g} px/frame with a {margin:g} px margin), got {shape}"
        )


class _Scenes(Dataset):
    """A list of sample dicts (tensors of equal shapes across samples)."""

    def __init__(self, samples: list[dict[str, torch.Tensor]]) -> None:
        self.samples = samples

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        return self.samples[index]


class _SceneDataModule(L.LightningDataModule):
    """Shared split / seed / loader logic; subclasses implement :meth:`make_scene`."""

    def _init_splits(self, n_train: int, n_val: int, n_test: int, seed: int) -> None:
        sizes = {"train": n_train, "val": n_val, "test": n_test}
        self.hparams["split_seeds"] = split_seeds(seed, sizes)
        self.datasets: dict[str, _Scenes] = {}

    def _init_maneuvers(self, turn_rate: Any, maneuver_prob: float, maneuver_turn: float) -> None:
        self.turn_rate = _range("turn_rate", turn_rate, 0.0, math.pi / 4)
        check_number("maneuver_prob", maneuver_prob, low=0.0, high=1.0)
        check_number("maneuver_turn", maneuver_turn, low=0.0, high=math.pi)

    def _track(self, gen: torch.Generator, margin: float) -> _Track:
        hp = self.hparams
        return _maneuvering_track(
            gen,
            self.shape,
            self.speed,
            margin,
            self.turn_rate,
            hp["maneuver_prob"],
            hp["maneuver_turn"],
        )

    def make_scene(self, seed: int) -> dict[str, torch.Tensor]:  # pragma: no cover - abstract
        raise NotImplementedError

    def scenes(self, split: str) -> _Scenes:
        """Generate (once) and return the scenes of ``split``: train, val or test."""
        split = check_choice("split", split, SPLITS)
        if split not in self.datasets:
            first, stop = self.hparams["split_seeds"][split]
            self.datasets[split] = _Scenes([self.make_scene(s) for s in range(first, stop)])
        return self.datasets[split]

    def setup(self, stage: str | None = None) -> None:
        """Generate the scenes of the splits ``stage`` needs (all of them for ``None``)."""
        needs = {
            "fit": ("train", "val"),
            "validate": ("val",),
            "test": ("test",),
            "predict": ("test",),
        }.get(stage or "", SPLITS)
        for split in needs:
            self.scenes(split)

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        gen = torch.Generator().manual_seed(self.hparams["split_seeds"][split][0])
        return DataLoader(
            self.scenes(split),
            batch_size=self.hparams["batch_size"],
            shuffle=shuffle,
            generator=gen if shuffle else None,
        )

    def train_dataloader(self) -> DataLoader:
        """Shuffled (seeded) training scenes.

        Raises:
            ValueError: ``n_train`` is 0 (a module with ``n_train=0`` serves val / test only).
        """
        first, stop = self.hparams["split_seeds"]["train"]
        if stop == first:
            raise ValueError("`n_train`: expected an integer >= 1 to train on, got 0")
        return self._loader("train", True)

    def val_dataloader(self) -> DataLoader:
        """Validation scenes in seed order."""
        return self._loader("val", False)

    def test_dataloader(self) -> DataLoader:
        """Held-out test scenes in seed order."""
        return self._loader("test", False)


class IRSceneDataModule(_SceneDataModule):
    """IR sequences of :func:`~hocnet.data.simulate_ir` [NR08] with random straight targets.

    Each scene (seed ``s``) draws, from ``torch.Generator().manual_seed(s)``, for each of the
    ``n_targets`` targets a peak SNR uniform in ``snr_db``, a speed uniform in ``speed`` and a
    uniform heading, the turn and maneuver (module docstring), and a start such that the track
    stays ``margin`` px inside the frame; the same generator then draws the noise, jitter and
    clouds. The frames and the target-free frames
    are whitened (``whiten``, 7 x 7 ring with a 3 x 3 guard).

    A sample is a dict of ``frames`` and ``target_free`` float32 ``(T, H, W)`` (whitened),
    ``positions`` float32 ``(N, T, 2)`` true ``(x, y)`` (jitter included), ``pixels`` int64
    ``(N, T)``: the flat index ``y * W + x`` of the pixel nearest to each true position (clamped
    to the frame), and ``maneuver_at`` int64 ``(N,)``: each target's maneuver frame (-1: none).
    Batches stack them to ``(B, T, H, W)``, ``(B, N, T, 2)``, ``(B, N, T)``, ``(B, N)``.

    Args:
        n_train: number of training scenes.
        n_val: number of validation scenes.
        n_test: number of held-out test scenes.
        shape: ``(T, H, W)``.
        snr_db: peak SNR in dB, a number or a range ``(lo, hi)``.
        speed: target speed in px/frame, a number or a range within ``[0, 2]``.
        n_targets: targets per scene (``>= 1``).
        turn_rate: magnitude of the gentle turn in rad/frame (random sign), a number or a range
            within ``[0, pi / 4]``; 0: straight.
        maneuver_prob: probability that a target makes one sharp maneuver (at a frame uniform in
            ``1 .. T - 2``).
        maneuver_turn: largest heading change of a maneuver in radians, in ``[0, pi]``.
        clouds: cloud preset, ``"clear"``, ``"wispy"`` or ``"bright"``.
        jitter: jitter bound in pixels.
        whiten: ``"anti_mean"`` or ``"anti_median"``.
        margin: distance in pixels kept between every track and the frame border.
        batch_size: scenes per batch.
        seed: base seed of the split seed ranges.

    Examples:
        >>> dm = IRSceneDataModule(n_train=2, n_val=1, n_test=1, shape=(4, 16, 16))
        >>> dm.setup("fit")
        >>> batch = next(iter(dm.train_dataloader()))
        >>> batch["frames"].shape, batch["pixels"].shape
        (torch.Size([2, 4, 16, 16]), torch.Size([2, 1, 4]))
        >>> dm.hparams.split_seeds["test"]
        [2000000, 2000001]
    """

    def __init__(
        self,
        n_train: int = 32,
        n_val: int = 8,
        n_test: int = 8,
        shape: tuple[int, int, int] = (8, 32, 32),
        snr_db: float | tuple[float, float] = (9.0, 15.0),
        speed: float | tuple[float, float] = (0.1, 2.0),
        n_targets: int = 1,
        turn_rate: float | tuple[float, float] = 0.0,
        maneuver_prob: float = 0.0,
        maneuver_turn: float = math.pi / 2,
        clouds: str = "clear",
        jitter: float = 0.5,
        whiten: str = "anti_mean",
        margin: float = 3.0,
        batch_size: int = 8,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.shape = _shape(shape)
        self.snr_db = _range("snr_db", snr_db, -math.inf, math.inf)
        self.speed = _range("speed", speed, 0.0, 2.0)
        check_int("n_targets", n_targets, minimum=1)
        self._init_maneuvers(turn_rate, maneuver_prob, maneuver_turn)
        check_choice("clouds", clouds, tuple(CLOUD_PRESETS))
        check_number("jitter", jitter, low=0.0)
        check_choice("whiten", whiten, tuple(_WHITEN))
        _check_fits(self.shape, self.speed, check_number("margin", margin, low=0.0))
        check_int("batch_size", batch_size, minimum=1)
        self._init_splits(n_train, n_val, n_test, seed)

    def make_scene(self, seed: int) -> dict[str, torch.Tensor]:
        """The sample of scene ``seed`` (see the class docstring)."""
        hp = self.hparams
        gen = torch.Generator().manual_seed(seed)
        targets, turns = [], []
        for _ in range(hp["n_targets"]):
            snr = _uniform(gen, *self.snr_db)
            tr = self._track(gen, hp["margin"])
            targets.append(
                IRTarget(
                    tr.x0, tr.y0, tr.vx, tr.vy, snr_db=snr, turn_rate=tr.rate,
                    turn_at=tr.turn_at, new_velocity=tr.new_velocity,
                )
            )  # fmt: skip
            turns.append(-1 if tr.turn_at is None else tr.turn_at)
        seq = simulate_ir(
            self.shape, targets, clouds=hp["clouds"], jitter=hp["jitter"], generator=gen
        )
        whiten = _WHITEN[hp["whiten"]]
        _, h, w = self.shape
        xy = seq.positions.round().long()
        x, y = xy[..., 0].clamp(0, w - 1), xy[..., 1].clamp(0, h - 1)
        return {
            "frames": whiten(seq.frames).float(),
            "target_free": whiten(seq.target_free).float(),
            "positions": seq.positions.float(),
            "pixels": y * w + x,
            "maneuver_at": torch.tensor(turns, dtype=torch.int64),
        }


class BinarySceneDataModule(_SceneDataModule):
    """Binary scans of :func:`~hocnet.data.simulate_binary` [LA98] with per-point labels.

    Each scene (seed ``s``) draws, from ``torch.Generator().manual_seed(s)``, ``n_targets``
    targets (speed uniform in ``speed`` px/scan, uniform heading, the turn and maneuver of the
    module docstring, start such that the track stays ``margin`` px inside the frame, miss
    probability ``p_miss``), then the uniform clutter of density ``clutter_density`` (a number
    or a range drawn per scene). A maneuvering target is drawn as two consecutive pieces (scans
    ``0 .. turn_at - 1`` and ``turn_at ..``, the second starting where the first course puts
    the target at ``turn_at``).

    A sample is a dict of ``cube`` float32 0/1 ``(T, H, W)`` (target points OR clutter, eq. (1)
    of [LA98]), ``target`` bool ``(T, H, W)`` (the on-pixels that are target points; the
    clutter points are ``cube & ~target``) and ``maneuver_at`` int64 ``(N,)`` (each target's
    maneuver scan, -1: none).

    Args:
        n_train: number of training scenes.
        n_val: number of validation scenes.
        n_test: number of held-out test scenes.
        shape: ``(T, H, W)``.
        clutter_density: fraction of clutter pixels per scan, a number or a range in ``[0, 1]``.
        speed: target speed in px/scan, a number or a range within ``[0, 2]``.
        n_targets: targets per scene (``>= 0``).
        turn_rate: magnitude of the gentle turn in rad/scan (random sign), a number or a range
            within ``[0, pi / 4]``; 0: straight.
        maneuver_prob: probability that a target makes one sharp maneuver (at a scan uniform in
            ``1 .. T - 2``).
        maneuver_turn: largest heading change of a maneuver in radians, in ``[0, pi]``.
        p_miss: probability that a target point is missing.
        margin: distance in pixels kept between every track and the frame border.
        batch_size: scenes per batch.
        seed: base seed of the split seed ranges.

    Examples:
        >>> dm = BinarySceneDataModule(n_train=2, n_val=1, n_test=1, shape=(6, 16, 16))
        >>> dm.setup("test")
        >>> batch = next(iter(dm.test_dataloader()))
        >>> batch["cube"].shape, batch["target"].dtype
        (torch.Size([1, 6, 16, 16]), torch.bool)
    """

    def __init__(
        self,
        n_train: int = 32,
        n_val: int = 8,
        n_test: int = 8,
        shape: tuple[int, int, int] = (8, 32, 32),
        clutter_density: float | tuple[float, float] = 0.02,
        speed: float | tuple[float, float] = (0.1, 2.0),
        n_targets: int = 2,
        turn_rate: float | tuple[float, float] = 0.0,
        maneuver_prob: float = 0.0,
        maneuver_turn: float = math.pi / 2,
        p_miss: float = 0.0,
        margin: float = 1.0,
        batch_size: int = 8,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.shape = _shape(shape)
        self.density = _range("clutter_density", clutter_density, 0.0, 1.0)
        self.speed = _range("speed", speed, 0.0, 2.0)
        check_int("n_targets", n_targets, minimum=0)
        self._init_maneuvers(turn_rate, maneuver_prob, maneuver_turn)
        check_number("p_miss", p_miss, low=0.0, high=1.0)
        _check_fits(self.shape, self.speed, check_number("margin", margin, low=0.0))
        check_int("batch_size", batch_size, minimum=1)
        self._init_splits(n_train, n_val, n_test, seed)

    def make_scene(self, seed: int) -> dict[str, torch.Tensor]:
        """The sample of scene ``seed`` (see the class docstring)."""
        hp = self.hparams
        gen = torch.Generator().manual_seed(seed)
        specs, turns = [], []
        for _ in range(hp["n_targets"]):
            tr = self._track(gen, hp["margin"])
            kw = {"turn_rate": tr.rate, "p_miss": hp["p_miss"]}
            if tr.turn_at is None:
                specs.append(TargetSpec((tr.x0, tr.y0), (tr.vx, tr.vy), **kw))
                turns.append(-1)
                continue
            rel = _relative_positions(
                tr.turn_at + 1, tr.vx, tr.vy, tr.rate, tr.turn_at, tr.new_velocity
            )
            start = (tr.x0 + rel[-1][0], tr.y0 + rel[-1][1])
            specs.append(TargetSpec((tr.x0, tr.y0), (tr.vx, tr.vy), last_scan=tr.turn_at - 1, **kw))
            specs.append(TargetSpec(start, tr.new_velocity, first_scan=tr.turn_at, **kw))
            turns.append(tr.turn_at)
        density = _uniform(gen, *self.density)
        scene = simulate_binary(self.shape, specs, clutter_density=density, generator=gen)
        return {
            "cube": scene.cube.float(),
            "target": scene.target_mask & scene.cube,
            "maneuver_at": torch.tensor(turns, dtype=torch.int64),
        }

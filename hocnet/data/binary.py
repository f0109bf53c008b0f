"""Binary multi-scan scenes with ground truth, after [LA98].

[LA98] (R.-J. Liou, M. R. Azimi-Sadjadi, IEEE Trans. AES 34(2), 1998) models each scan as a binary
image, eq. (1): ``F = S + (1 - S) N``, i.e. the cube is the logical OR of the target points ``S``
and the clutter points ``N``. This module draws such cubes together with the ground truth: which
pixel belongs to which target, and each target's drawn track.

Conventions (our reading; [LA98] section IV does not fix them):

* Cubes are ``(B, T, H, W)`` ``bool``; an unbatched call (``batch=None``) returns ``(T, H, W)``.
  ``T`` is scans, ``H`` rows (``y``), ``W`` columns (``x``).
* A target's continuous position at scan ``first_scan + k`` is
  ``start + sum_{m < k} R(m * turn_rate) @ velocity``, where ``R(a)`` rotates by ``a`` radians from
  ``+x`` towards ``+y`` (so the bearing ``atan2(vy, vx)`` grows by ``turn_rate`` each scan; with
  ``y`` pointing down the image, a positive turn is clockwise on screen). For ``turn_rate == 0``
  this is computed exactly as ``start + k * velocity``.
* The drawn pixel is the continuous position rounded with ``floor(p + 0.5)`` (round half up,
  towards ``+inf``, also for negative coordinates).
* Points falling outside the frame are simply not drawn and are not listed in the tracks; the
  target keeps moving and may come back into view.
* Each target point is missed independently with probability ``p_miss`` (per batch element).
* A splitting target (``split_at`` set) gets a second branch that leaves the target's position at
  scan ``split_at`` with ``split_velocity`` (turning at the same ``turn_rate``); both branches run
  to ``last_scan``. The branch's track begins with the point it shares with its parent at
  ``split_at`` (one physical return: it is missed or kept together with the parent's point).
* Labels: ``0`` is clutter or empty, target ``k`` (1-based, in the order given) has label ``k``
  unless its spec sets ``label``; the branch of the ``j``-th splitting target (1-based, in target
  order) has label ``n_targets + j``. Where two targets occupy the same pixel in the same scan the
  lower label wins in :attr:`BinaryScene.labels`; the tracks still list the point for both.
* Random numbers come only from a ``torch.Generator`` (made from ``seed`` if given), drawn in the
  fixed order misses, stationary clutter, clutter; the same seed gives bit-identical scenes.

Speed: the clutter is one ``torch.rand`` call over the whole batch, target drawing loops over
tracks only. 1000 scenes of ``10 x 60 x 60`` with three targets and 2 % clutter take 0.35-1 s on
a 2-core CPU (``simulate_binary((10, 60, 60), table3_targets()[:3], clutter_density=0.02,
batch=1000, seed=0)``), dominated by the ``torch.rand`` call and allocating the outputs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from hocnet._check import check_choice, check_int, check_number, check_seed

__all__ = [
    "BinaryScene",
    "TargetSpec",
    "fig5_paper_targets",
    "fig5_targets",
    "paper_scene",
    "paper_shape",
    "simulate_binary",
    "table2_targets",
    "table3_integer_targets",
    "table3_paper_targets",
    "table3_targets",
]


def _pair(name: str, value: Any) -> tuple[float, float]:
    """Validate a pair of finite numbers such as ``(x, y)`` or ``(vx, vy)``."""
    if isinstance(value, torch.Tensor):
        value = value.tolist()
    if isinstance(value, str) or not isinstance(value, Sequence) or len(value) != 2:
        shown = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
        raise TypeError(f"`{name}`: expected a pair of numbers, got {shown}")
    return (check_number(f"{name}[0]", value[0]), check_number(f"{name}[1]", value[1]))


def _round(value: float) -> int | None:
    """Round half up (``floor(value + 0.5)``); ``None`` for a non-finite value."""
    return math.floor(value + 0.5) if math.isfinite(value) else None


@dataclass(frozen=True)
class TargetSpec:
    """One target of a binary scene: where it starts, how it moves, when it is visible.

    All values are validated on construction (``TypeError`` / ``ValueError`` naming the field).
    Checks that depend on the cube (``first_scan``, ``last_scan``, ``split_at`` against ``T``)
    happen in :func:`simulate_binary`.

    Args:
        start: ``(x0, y0)`` continuous position in pixels at scan ``first_scan`` (``x`` column,
            ``y`` row).
        velocity: ``(vx, vy)`` in pixels per scan (finite).
        turn_rate: rotation of the velocity vector per scan in radians, in ``[-pi, pi]``; positive
            turns from ``+x`` towards ``+y``. ``0`` gives a straight track.
        first_scan: first scan on which the target exists (``>= 0``).
        last_scan: last scan on which it exists (inclusive); ``None`` means the cube's last scan.
        p_miss: probability that each of its points is missed, in ``[0, 1]``.
        split_at: scan from which a second branch leaves the target, or ``None``. Must satisfy
            ``first_scan <= split_at < last_scan``.
        split_velocity: ``(vx, vy)`` of the branch; required exactly when ``split_at`` is set.
        label: label of the target in :attr:`BinaryScene.labels` (``>= 1``); ``None`` uses its
            1-based position in the target list.

    Examples:
        >>> spec = TargetSpec(start=(2, 3), velocity=(1, 0.5), last_scan=4)
        >>> spec.start, spec.velocity
        ((2.0, 3.0), (1.0, 0.5))
        >>> TargetSpec(start=(0, 0), velocity=(float("nan"), 0))
        Traceback (most recent call last):
        ...
        ValueError: `velocity[0]`: expected a finite number, got nan
    """

    start: tuple[float, float]
    velocity: tuple[float, float]
    turn_rate: float = 0.0
    first_scan: int = 0
    last_scan: int | None = None
    p_miss: float = 0.0
    split_at: int | None = None
    split_velocity: tuple[float, float] | None = None
    label: int | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "start", _pair("start", self.start))
        set_(self, "velocity", _pair("velocity", self.velocity))
        set_(
            self, "turn_rate", check_number("turn_rate", self.turn_rate, low=-math.pi, high=math.pi)
        )
        set_(self, "first_scan", check_int("first_scan", self.first_scan, minimum=0))
        if self.last_scan is not None:
            set_(self, "last_scan", check_int("last_scan", self.last_scan, minimum=self.first_scan))
        set_(self, "p_miss", check_number("p_miss", self.p_miss, low=0.0, high=1.0))
        if self.split_at is None:
            if self.split_velocity is not None:
                raise ValueError(
                    "`split_velocity`: expected None when `split_at` is None, "
                    f"got {self.split_velocity!r}"
                )
        else:
            maximum = None if self.last_scan is None else self.last_scan - 1
            set_(
                self,
                "split_at",
                check_int("split_at", self.split_at, minimum=self.first_scan, maximum=maximum),
            )
            if self.split_velocity is None:
                raise ValueError(
                    "`split_velocity`: expected a pair (vx, vy) when `split_at` is set"
                )
            set_(self, "split_velocity", _pair("split_velocity", self.split_velocity))
        if self.label is not None:
            set_(self, "label", check_int("label", self.label, minimum=1))

    def _positions(
        self, velocity: tuple[float, float], origin: tuple[float, float], n: int
    ) -> list[tuple[float, float]]:
        """Continuous positions of ``n`` scans starting at ``origin`` with ``velocity``."""
        x0, y0 = origin
        vx, vy = velocity
        if self.turn_rate == 0.0:
            return [(x0 + k * vx, y0 + k * vy) for k in range(n)]
        out = [(x0, y0)]
        x, y = x0, y0
        for m in range(n - 1):
            c, s = math.cos(m * self.turn_rate), math.sin(m * self.turn_rate)
            x, y = x + c * vx - s * vy, y + s * vx + c * vy
            out.append((x, y))
        return out


@dataclass(frozen=True, eq=False)
class BinaryScene:
    """A simulated binary scene and its ground truth.

    Attributes:
        cube: ``(B, T, H, W)`` (or ``(T, H, W)`` if unbatched) ``bool``: target points OR clutter,
            eq. (1) of [LA98].
        labels: ``int64`` of the same shape: ``0`` for clutter or empty pixels, the target's label
            on its drawn points (the lower label where two targets share a pixel).
        tracks: the drawn points of each target and branch, ordered by label, as ``int64``
            tensors of shape ``(N, 3)`` with rows ``(t, y, x)`` sorted by ``t`` (after misses,
            clipped to the frame). Unbatched: a flat list; batched: one such list per batch
            element.
        track_labels: the label of each entry of a track list (ascending).
        split_parents: maps each split branch's label to its parent's label.
        specs: the target specs the scene was drawn from.

    Examples:
        >>> scene = simulate_binary((5, 8, 8), [TargetSpec((1, 1), (1, 1))], seed=0)
        >>> scene.cube.shape, scene.labels.dtype, scene.tracks[0].shape
        (torch.Size([5, 8, 8]), torch.int64, torch.Size([5, 3]))
        >>> int(scene.n_target_points), int(scene.n_clutter_points)
        (5, 0)
    """

    cube: torch.Tensor
    labels: torch.Tensor
    tracks: list[torch.Tensor] | list[list[torch.Tensor]]
    track_labels: tuple[int, ...]
    split_parents: dict[int, int]
    specs: tuple[TargetSpec, ...]

    @property
    def batched(self) -> bool:
        """Whether the scene has a leading batch axis."""
        return self.cube.dim() == 4

    @property
    def target_mask(self) -> torch.Tensor:
        """``bool`` mask of target points (``labels > 0``), shaped like :attr:`cube`."""
        return self.labels > 0

    @property
    def clutter_mask(self) -> torch.Tensor:
        """``bool`` mask of clutter points (cube points that are not target points)."""
        return self.cube & ~self.target_mask

    @property
    def n_target_points(self) -> torch.Tensor:
        """Number of target pixels per scene: ``(B,)`` ``int64``, or a 0-d tensor if unbatched.

        A pixel shared by two targets counts once.
        """
        return self.target_mask.sum(dim=(-3, -2, -1))

    @property
    def n_clutter_points(self) -> torch.Tensor:
        """Number of clutter pixels per scene: ``(B,)`` ``int64``, or a 0-d tensor if unbatched."""
        return self.clutter_mask.sum(dim=(-3, -2, -1))

    def select(self, index: int) -> BinaryScene:
        """Return batch element ``index`` of a batched scene as an unbatched scene.

        Examples:
            >>> scene = simulate_binary((4, 6, 6), [], batch=3, seed=1)
            >>> scene.select(2).cube.shape
            torch.Size([4, 6, 6])
        """
        if not self.batched:
            raise ValueError("`self`: expected a batched scene, got an unbatched one")
        n = self.cube.shape[0]
        index = check_int("index", index, minimum=-n, maximum=n - 1)
        return BinaryScene(
            cube=self.cube[index],
            labels=self.labels[index],
            tracks=list(self.tracks[index]),
            track_labels=self.track_labels,
            split_parents=dict(self.split_parents),
            specs=self.specs,
        )


@dataclass
class _Track:
    """Internal: one drawn branch before misses (in-frame points and their miss columns)."""

    label: int
    points: torch.Tensor  # (N, 3) int64 (t, y, x)
    columns: torch.Tensor  # (N,) int64 index into the miss draws
    p_miss: float


def _check_shape(shape: Any) -> tuple[int, int, int]:
    if isinstance(shape, torch.Size):
        shape = tuple(shape)
    if isinstance(shape, str) or not isinstance(shape, Sequence) or len(shape) != 3:
        raise TypeError(f"`shape`: expected a triple (T, H, W) of positive integers, got {shape!r}")
    names = ("shape[0] (T)", "shape[1] (H)", "shape[2] (W)")
    t, h, w = (check_int(n, v, minimum=1) for n, v in zip(names, shape))
    return t, h, w


def _check_targets(targets: Any, n_scans: int) -> tuple[TargetSpec, ...]:
    if isinstance(targets, TargetSpec):
        targets = [targets]
    if isinstance(targets, str) or not isinstance(targets, Sequence):
        raise TypeError(
            f"`targets`: expected a sequence of TargetSpec, got {type(targets).__name__}"
        )
    last = n_scans - 1
    for i, spec in enumerate(targets):
        if not isinstance(spec, TargetSpec):
            raise TypeError(f"`targets[{i}]`: expected a TargetSpec, got {type(spec).__name__}")
        check_int(f"targets[{i}].first_scan", spec.first_scan, maximum=last)
        if spec.last_scan is not None:
            check_int(f"targets[{i}].last_scan", spec.last_scan, maximum=last)
        if spec.split_at is not None:
            check_int(f"targets[{i}].split_at", spec.split_at, maximum=last - 1)
    return tuple(targets)


def _make_generator(seed: Any, generator: Any) -> torch.Generator:
    seed = check_seed("seed", seed)
    if generator is not None:
        if seed is not None:
            raise ValueError("`generator`: expected None when `seed` is given, got a Generator")
        if not isinstance(generator, torch.Generator):
            raise TypeError(
                f"`generator`: expected a torch.Generator or None, got {type(generator).__name__}"
            )
        if generator.device.type != "cpu":
            raise ValueError(
                f"`generator`: expected a CPU generator, got device {generator.device}"
            )
        return generator
    gen = torch.Generator()
    if seed is None:
        gen.seed()  # non-deterministic, but never the global state
    else:
        gen.manual_seed(seed)
    return gen


def _layout(
    specs: tuple[TargetSpec, ...], shape: tuple[int, int, int]
) -> tuple[list[_Track], dict[int, int], int]:
    """Draw the ideal (miss-free) tracks of all targets; return them, split parents, #columns."""
    n_scans, height, width = shape
    n_targets = len(specs)
    tracks: list[_Track] = []
    parents: dict[int, int] = {}
    owners: dict[int, str] = {}
    n_columns = 0
    n_splits = 0

    def claim(label: int, owner: str) -> None:
        if label in owners:
            raise ValueError(
                f"`targets`: expected distinct labels, got label {label} for both "
                f"{owners[label]} and {owner}"
            )
        owners[label] = owner

    def draw(
        first: int, positions: list[tuple[float, float]], shared: tuple[int, int] | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """In-frame (t, y, x) rows and miss columns; ``shared`` = (scan, column) of a split."""
        nonlocal n_columns
        rows, cols = [], []
        for k, (x, y) in enumerate(positions):
            t, xi, yi = first + k, _round(x), _round(y)
            if xi is None or yi is None or not (0 <= xi < width and 0 <= yi < height):
                continue
            rows.append((t, yi, xi))
            if shared is not None and t == shared[0]:
                cols.append(shared[1])
            else:
                cols.append(n_columns)
                n_columns += 1
        points = torch.tensor(rows, dtype=torch.int64).reshape(-1, 3)
        return points, torch.tensor(cols, dtype=torch.int64)

    for i, spec in enumerate(specs):
        label = spec.label if spec.label is not None else i + 1
        claim(label, f"targets[{i}]")
        last = n_scans - 1 if spec.last_scan is None else spec.last_scan
        positions = spec._positions(spec.velocity, spec.start, last - spec.first_scan + 1)
        points, columns = draw(spec.first_scan, positions, None)
        tracks.append(_Track(label, points, columns, spec.p_miss))
        if spec.split_at is None:
            continue
        n_splits += 1
        branch_label = n_targets + n_splits
        claim(branch_label, f"the split branch of targets[{i}]")
        parents[branch_label] = label
        origin = positions[spec.split_at - spec.first_scan]
        hit = (points[:, 0] == spec.split_at).nonzero()
        shared = (spec.split_at, int(columns[hit[0, 0]])) if len(hit) else None
        branch = spec._positions(spec.split_velocity, origin, last - spec.split_at + 1)
        b_points, b_columns = draw(spec.split_at, branch, shared)
        tracks.append(_Track(branch_label, b_points, b_columns, spec.p_miss))
    tracks.sort(key=lambda tr: tr.label)
    return tracks, parents, n_columns


def simulate_binary(
    shape: Sequence[int],
    targets: Sequence[TargetSpec] = (),
    *,
    clutter_density: float = 0.0,
    stationary_clutter: float = 0.0,
    batch: int | None = None,
    seed: int | None = None,
    generator: torch.Generator | None = None,
) -> BinaryScene:
    """Simulate binary multi-scan scenes ``F = S + (1 - S) N`` of [LA98], eq. (1).

    See the module docstring for the conventions (rounding, off-frame points, labels, splits).

    Args:
        shape: ``(T, H, W)``: scans, rows, columns.
        targets: the target specs (may be empty); the same specs are used for every batch
            element.
        clutter_density: fraction of pixels per scan turned on by uniform random clutter, in
            ``[0, 1]``, independent per scan and batch element.
        stationary_clutter: fraction of pixels in ``[0, 1]`` that are on in every scan (fixed
            clutter points, independent per batch element).
        batch: ``None`` for one unbatched scene, or the number ``B >= 1`` of independent scenes
            (independent clutter and misses).
        seed: seed of a fresh ``torch.Generator``; ``None`` for a non-deterministic one.
        generator: a CPU ``torch.Generator`` to draw from instead (not together with ``seed``).

    Returns:
        A :class:`BinaryScene` with ``cube`` ``(B, T, H, W)`` ``bool`` and ``labels``
        ``(B, T, H, W)`` ``int64`` (``(T, H, W)`` each if ``batch`` is ``None``) and the tracks.

    Raises:
        TypeError: for arguments of the wrong type.
        ValueError: for out-of-range values, specs that do not fit in ``T`` scans, or duplicate
            labels.

    Examples:
        >>> spec = TargetSpec(start=(1, 2), velocity=(2, 1))
        >>> scene = simulate_binary((4, 10, 10), [spec], seed=0)
        >>> scene.tracks[0].tolist()
        [[0, 2, 1], [1, 3, 3], [2, 4, 5], [3, 5, 7]]
        >>> noisy = simulate_binary((4, 10, 10), [spec], clutter_density=0.1, batch=2, seed=0)
        >>> noisy.cube.shape, len(noisy.tracks), bool(noisy.cube[:, 3, 5, 7].all())
        (torch.Size([2, 4, 10, 10]), 2, True)
    """
    n_scans, height, width = _check_shape(shape)
    specs = _check_targets(targets, n_scans)
    density = check_number("clutter_density", clutter_density, low=0.0, high=1.0)
    stationary = check_number("stationary_clutter", stationary_clutter, low=0.0, high=1.0)
    n_batch = 1 if batch is None else check_int("batch", batch, minimum=1)
    gen = _make_generator(seed, generator)

    tracks, parents, n_columns = _layout(specs, (n_scans, height, width))

    # 1. misses: one uniform per physical target point and batch element.
    if any(tr.p_miss > 0 for tr in tracks) and n_columns:
        p_col = torch.zeros(n_columns, dtype=torch.float32)
        for tr in tracks:
            p_col[tr.columns] = tr.p_miss
        keep = torch.rand((n_batch, n_columns), generator=gen) >= p_col
    else:
        keep = torch.ones((n_batch, n_columns), dtype=torch.bool)

    # 2. clutter N: stationary points (same pixel every scan), then per-scan uniform clutter.
    cube = torch.zeros((n_batch, n_scans, height, width), dtype=torch.bool)
    if stationary > 0:
        fixed = torch.rand((n_batch, 1, height, width), generator=gen) < stationary
        cube |= fixed
    if density > 0:
        cube |= torch.rand((n_batch, n_scans, height, width), generator=gen) < density

    # 3. targets S: paint in descending label order so that the lower label wins a shared pixel.
    labels = torch.zeros((n_batch, n_scans, height, width), dtype=torch.int64)
    kept = [keep[:, tr.columns] for tr in tracks]  # each (B, N)
    for tr, k in sorted(zip(tracks, kept), key=lambda pair: -pair[0].label):
        b_idx, p_idx = k.nonzero(as_tuple=True)
        pts = tr.points[p_idx]
        labels[b_idx, pts[:, 0], pts[:, 1], pts[:, 2]] = tr.label
        cube[b_idx, pts[:, 0], pts[:, 1], pts[:, 2]] = True

    per_scene = [[tr.points[k[b]] for tr, k in zip(tracks, kept)] for b in range(n_batch)]
    batched = batch is not None
    return BinaryScene(
        cube=cube if batched else cube[0],
        labels=labels if batched else labels[0],
        tracks=per_scene if batched else per_scene[0],
        track_labels=tuple(tr.label for tr in tracks),
        split_parents=parents,
        specs=specs,
    )


# --------------------------------------------------------------------------------------------
# Scenario presets of the [LA98] experiments
# --------------------------------------------------------------------------------------------

_SHAPES: dict[str, tuple[int, int, int]] = {
    "table2": (10, 320, 520),
    "table3": (10, 60, 60),
    "fig5": (16, 60, 60),
    "table3-paper": (10, 60, 60),
    "fig5-paper": (16, 520, 520),
    "table3-int": (10, 60, 60),
}


def table2_targets() -> tuple[TargetSpec, ...]:
    """Targets of the Table II experiment of [LA98]: two straight 10-point tracks.

    For the ``(T, H, W) = (10, 320, 520)`` cube (``W = 520`` columns, ``H = 320`` rows). The size
    is our inference, not printed: 13310 clutter points / 10 scans / 0.8 % is about 166,400
    pixels per scan. [LA98] section IV-C places the targets "around (104, 312) and (468, 156)";
    ours start elsewhere (our choice, away from the border; the clutter is uniform, so the place
    does not change the rejection). Integer starts and velocities, so every move is exactly the
    velocity:

    1. start ``(100, 80)``, velocity ``(3, 1)``: scans 0-9, ends at ``(127, 89)``.
    2. start ``(380, 240)``, velocity ``(-2, -2)``: scans 0-9, ends at ``(362, 222)``.

    Returns:
        The two :class:`TargetSpec` (labels 1 and 2).

    Examples:
        >>> [spec.velocity for spec in table2_targets()]
        [(3.0, 1.0), (-2.0, -2.0)]
    """
    return (
        TargetSpec(start=(100, 80), velocity=(3, 1)),
        TargetSpec(start=(380, 240), velocity=(-2, -2)),
    )


def table3_targets() -> tuple[TargetSpec, ...]:
    """Targets of the Table III experiment of [LA98]: crossing, splitting and close-parallel.

    For the ``(10, 60, 60)`` cube; all moves have ``|dx|, |dy| <= 3`` (within ``v = 4``) and every
    turn, including the one into the split branch, is below 45 degrees:

    1. start ``(15, 20)``, velocity ``(3, 2)``, scans 0-9.
    2. start ``(15, 40)``, velocity ``(3, -2)``, scans 0-9: crosses target 1, both at pixel
       ``(x, y) = (30, 30)`` at scan 5.
    3. start ``(5, 50)``, velocity ``(3, 0)``, scans 0-9, splits at scan 3 (pixel ``(14, 50)``);
       the branch (label 5) moves ``(3, -2)`` (a 33.7 degree turn) and ends at ``(32, 38)``.
    4. start ``(5, 52)``, velocity ``(3, 0)``, scans 0-9: parallel to target 3, 2 pixels below.

    Returns:
        The four :class:`TargetSpec` (labels 1-4; the split branch gets label 5).

    Examples:
        >>> len(table3_targets())
        4
    """
    return (
        TargetSpec(start=(15, 20), velocity=(3, 2)),
        TargetSpec(start=(15, 40), velocity=(3, -2)),
        TargetSpec(start=(5, 50), velocity=(3, 0), split_at=3, split_velocity=(3, -2)),
        TargetSpec(start=(5, 52), velocity=(3, 0)),
    )


def fig5_targets() -> tuple[TargetSpec, ...]:
    """Targets of the Fig. 5 experiment of [LA98]: six tracks over 16 scans, two splitting.

    For the ``(16, 60, 60)`` cube. Tracks start and end at different scans, each has at least 7
    points (each split branch at least 6, counting the shared split point); all moves are within
    ``v = 4`` and all turns below 45 degrees:

    1. start ``(4, 6)``, velocity ``(3, 1)``, scans 0-9.
    2. start ``(56, 10)``, velocity ``(-3, 2)``, scans 2-15; splits at scan 8 (pixel ``(38, 22)``)
       into a branch (label 7) moving ``(-3, 0)``.
    3. start ``(8, 56)``, velocity ``(3, -1)``, scans 4-13.
    4. start ``(45, 50)``, velocity ``(0, -3)``, scans 1-8.
    5. start ``(50, 56)``, velocity ``(-1, -3)``, scans 6-14; splits at scan 9 (pixel
       ``(47, 47)``) into a branch (label 8) moving ``(1, -3)``.
    6. start ``(10, 30)``, velocity ``(3, 0)`` turning by 0.1 rad per scan (towards ``+y``),
       scans 3-12: a gently turning track.

    Returns:
        The six :class:`TargetSpec` (labels 1-6; branches 7 and 8).

    Examples:
        >>> [(s.first_scan, s.last_scan) for s in fig5_targets()][:3]
        [(0, 9), (2, 15), (4, 13)]
    """
    return (
        TargetSpec(start=(4, 6), velocity=(3, 1), first_scan=0, last_scan=9),
        TargetSpec(
            start=(56, 10),
            velocity=(-3, 2),
            first_scan=2,
            last_scan=15,
            split_at=8,
            split_velocity=(-3, 0),
        ),
        TargetSpec(start=(8, 56), velocity=(3, -1), first_scan=4, last_scan=13),
        TargetSpec(start=(45, 50), velocity=(0, -3), first_scan=1, last_scan=8),
        TargetSpec(
            start=(50, 56),
            velocity=(-1, -3),
            first_scan=6,
            last_scan=14,
            split_at=9,
            split_velocity=(1, -3),
        ),
        TargetSpec(start=(10, 30), velocity=(3, 0), turn_rate=0.1, first_scan=3, last_scan=12),
    )


TABLE3_CONFIGURATIONS = ("close", "crossing", "splitting")
"""Relative configurations of the three Table III tracks ([LA98] section IV-C)."""


def table3_paper_targets(
    generator: torch.Generator | None = None, configuration: str | None = None
) -> tuple[TargetSpec, ...]:
    """Three 10-scan tracks of the Table III experiment of [LA98], placed at random.

    [LA98] section IV-C: "three target tracks ... in 60 x 60 size images ... positioned and
    initialized randomly ... by random translation and rotation operations to generate closely
    spaced, crossing or splitting tracks"; 3 x 10 = 30 target points per image. Our reading: a
    configuration is drawn (or given), built around the image centre, rotated by a uniform random
    angle and translated by up to +-4 pixels; speeds are 2-3 pixels per scan, straight:

    - ``"close"``: three parallel tracks 3 pixels apart, abreast (the same speed, all from
      scan 0 at the same along-track position);
    - ``"crossing"``: tracks 1 and 2 cross at the centre at scan 5 at 50-90 degrees; track 3
      runs 3 pixels beside track 1;
    - ``"splitting"``: tracks 1 and 2 leave the same neighbourhood (1 pixel apart at scan 0) and
      diverge by 20-40 degrees; track 3 crosses them.

    Args:
        generator: CPU ``torch.Generator`` to draw from (``None``: a fresh unseeded one).
        configuration: one of :data:`TABLE3_CONFIGURATIONS`, or ``None`` to draw one.

    Returns:
        Three :class:`TargetSpec` for the ``(10, 60, 60)`` cube, all inside the frame.

    Examples:
        >>> specs = table3_paper_targets(torch.Generator().manual_seed(0), "crossing")
        >>> len(specs), all(s.first_scan == 0 and s.last_scan is None for s in specs)
        (3, True)
    """
    gen = _make_generator(None, generator) if generator is not None else torch.Generator()
    if generator is None:
        gen.seed()

    def u(a: float, b: float) -> float:
        return a + (b - a) * float(torch.rand((), generator=gen))

    if configuration is None:
        configuration = TABLE3_CONFIGURATIONS[int(torch.randint(0, 3, (), generator=gen))]
    configuration = check_choice("configuration", configuration, TABLE3_CONFIGURATIONS)
    for _ in range(1000):
        speeds = [u(2.0, 3.0) for _ in range(3)]
        if configuration == "close":
            local = [((-4.5 * speeds[0], 0.0), (speeds[0], 0.0))]
            local.append(((-4.5 * speeds[0], 3.0), (speeds[0], 0.0)))
            local.append(((-4.5 * speeds[0], -3.0), (speeds[0], 0.0)))
        elif configuration == "crossing":
            ang = math.radians(u(50, 90)) * (1 if u(0, 1) < 0.5 else -1)
            v2 = (speeds[1] * math.cos(ang), speeds[1] * math.sin(ang))
            local = [((-5 * speeds[0], 0.0), (speeds[0], 0.0))]
            local.append(((-5 * v2[0], -5 * v2[1]), v2))
            local.append(((-5 * speeds[0], 3.0), (speeds[0], 0.0)))
        else:
            ang = math.radians(u(20, 40))
            v2 = (speeds[1] * math.cos(ang), speeds[1] * math.sin(ang))
            x0 = -4.5 * speeds[0]
            local = [((x0, 0.0), (speeds[0], 0.0)), ((x0, 1.0), v2)]
            a3 = math.radians(u(60, 120))
            v3 = (speeds[2] * math.cos(a3), speeds[2] * math.sin(a3))
            local.append(((-4.5 * v3[0] + 5.0, -4.5 * v3[1]), v3))
        rot = u(-math.pi, math.pi)
        c, s_ = math.cos(rot), math.sin(rot)
        dx, dy = u(-4, 4), u(-4, 4)
        specs = []
        inside = True
        for (x, y), (vx, vy) in local:
            sx, sy = 30 + c * x - s_ * y + dx, 30 + s_ * x + c * y + dy
            vx2, vy2 = c * vx - s_ * vy, s_ * vx + c * vy
            for k in (0, 9):
                px, py = _round(sx + k * vx2), _round(sy + k * vy2)
                inside &= 0 <= px < 60 and 0 <= py < 60
            specs.append(TargetSpec(start=(sx, sy), velocity=(vx2, vy2)))
        if inside:
            return tuple(specs)
    raise RuntimeError("table3_paper_targets: no placement inside the frame")  # pragma: no cover


TABLE3_INTEGER_MOVES = tuple(
    (a, b)
    for a in range(-3, 4)
    for b in range(-3, 4)
    if 2.0 <= math.hypot(a, b) <= math.sqrt(10) + 1e-9
)
"""Velocities of :func:`table3_integer_targets`: integer, 2 - 3.16 px/scan, ``|dx|, |dy| <= 3``."""


def table3_integer_targets(
    generator: torch.Generator | None = None, configuration: str | None = None
) -> tuple[TargetSpec, ...]:
    """The Table III configurations of :func:`table3_paper_targets` with integer velocities.

    Our addition: the same three configurations (close, crossing, splitting) but every velocity
    is one of :data:`TABLE3_INTEGER_MOVES` (``(2, 0), (2, 1), (2, 2), (3, 0), (3, 1)`` and their
    images under the grid's rotations by multiples of 90 degrees and reflections: directions in
    steps of 45 degrees plus the knight-like ``(2, 1)`` / ``(3, 1)`` families), so every move of
    a track is exactly its velocity and no move alternates (the rotations of
    :func:`table3_paper_targets` are arbitrary, so their integer moves alternate between
    neighbouring moves). Angles as there where the integer directions allow: crossing tracks at
    45-90 degrees, splitting tracks 18-40 degrees apart, the third splitting-scene track
    crossing at 60-120 degrees; a close track runs 3 pixels beside track 1 (starts rounded
    alike, so the gap is 2-3 pixels); translation by up to +-4 pixels.

    Args:
        generator: CPU ``torch.Generator`` to draw from (``None``: a fresh unseeded one).
        configuration: one of :data:`TABLE3_CONFIGURATIONS`, or ``None`` to draw one.

    Returns:
        Three :class:`TargetSpec` for the ``(10, 60, 60)`` cube, integer velocities, inside the
        frame.

    Examples:
        >>> specs = table3_integer_targets(torch.Generator().manual_seed(0), "crossing")
        >>> all(float(v).is_integer() for s in specs for v in s.velocity)
        True
    """
    gen = _make_generator(None, generator) if generator is not None else torch.Generator()
    if generator is None:
        gen.seed()

    def u(a: float, b: float) -> float:
        return a + (b - a) * float(torch.rand((), generator=gen))

    def pick(ref: tuple[int, int] | None = None, lo: float = 0.0, hi: float = 180.0):
        ok = [
            m
            for m in TABLE3_INTEGER_MOVES
            if ref is None or lo - 1e-9 <= _angle(ref, m) <= hi + 1e-9
        ]
        return ok[int(torch.randint(0, len(ok), (), generator=gen))]

    if configuration is None:
        configuration = TABLE3_CONFIGURATIONS[int(torch.randint(0, 3, (), generator=gen))]
    configuration = check_choice("configuration", configuration, TABLE3_CONFIGURATIONS)
    for _ in range(1000):
        v1 = pick()
        n1 = math.hypot(*v1)
        side = (-v1[1] / n1, v1[0] / n1)  # unit normal of track 1
        if configuration == "close":
            local = [((-4.5 * v1[0], -4.5 * v1[1]), v1)]
            for off in (3.0, -3.0):
                local.append(((-4.5 * v1[0] + off * side[0], -4.5 * v1[1] + off * side[1]), v1))
        elif configuration == "crossing":
            v2 = pick(v1, 45, 90)
            local = [((-5 * v1[0], -5 * v1[1]), v1), ((-5 * v2[0], -5 * v2[1]), v2)]
            local.append(((-5 * v1[0] + 3 * side[0], -5 * v1[1] + 3 * side[1]), v1))
        else:
            v2 = pick(v1, 18, 40)
            v3 = pick(v1, 60, 120)
            x0, y0 = -4.5 * v1[0], -4.5 * v1[1]
            local = [((x0, y0), v1), ((x0 + side[0], y0 + side[1]), v2)]
            local.append(((-4.5 * v3[0] + 5 * side[0], -4.5 * v3[1] + 5 * side[1]), v3))
        dx, dy = u(-4, 4), u(-4, 4)
        specs = []
        inside = True
        for (x, y), (vx, vy) in local:
            sx, sy = 30 + x + dx, 30 + y + dy
            for k in (0, 9):
                px, py = _round(sx + k * vx), _round(sy + k * vy)
                inside &= 0 <= px < 60 and 0 <= py < 60
            specs.append(TargetSpec(start=(sx, sy), velocity=(vx, vy)))
        if inside:
            return tuple(specs)
    raise RuntimeError("table3_integer_targets: no placement inside the frame")  # pragma: no cover


def _angle(a: tuple[int, int], b: tuple[int, int]) -> float:
    """Angle between two vectors in degrees, ``[0, 180]``."""
    d = math.degrees(abs(math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1])))
    return d


def fig5_paper_targets() -> tuple[TargetSpec, ...]:
    """Targets of the Fig. 5 experiment of [LA98]: six tracks in a large image over 16 scans.

    [LA98] section IV-A: six tracks "approximately located around (100,300), (200,120),
    (260,270), (310,415), (410,325), and (420,350)"; "the first four tracks initiate at different
    scans within the first interval while the last two initiate within the second interval. All
    tracks are isolated except the last two which are splitting ones." Our reading, for a
    ``(16, 520, 520)`` cube (``(x, y)`` as printed; scans 0-based):

    1. near ``(100, 300)``, velocity ``(3, 1)``, scans 0-12;
    2. near ``(200, 120)``, velocity ``(-2, 3)``, scans 1-15;
    3. near ``(260, 270)``, velocity ``(2, -2)``, scans 2-13;
    4. near ``(310, 415)``, velocity ``(-3, 0)``, scans 3-14;
    5. from ``(400, 318)``, velocity ``(2, 3)``, scans 6-15, splitting at scan 8 into
    6. its branch (label 6), velocity ``(3, 1)`` (a 38-degree turn), scans 8-15.

    Returns:
        The five :class:`TargetSpec` (the split branch gets label 6).

    Examples:
        >>> [(s.first_scan, s.last_scan) for s in fig5_paper_targets()][:2]
        [(0, 12), (1, 15)]
    """
    return (
        TargetSpec(start=(82, 294), velocity=(3, 1), first_scan=0, last_scan=12),
        TargetSpec(start=(214, 99), velocity=(-2, 3), first_scan=1, last_scan=15),
        TargetSpec(start=(248, 282), velocity=(2, -2), first_scan=2, last_scan=13),
        TargetSpec(start=(328, 415), velocity=(-3, 0), first_scan=3, last_scan=14),
        TargetSpec(
            start=(400, 318),
            velocity=(2, 3),
            first_scan=6,
            last_scan=15,
            split_at=8,
            split_velocity=(3, 1),
        ),
    )


FIG5_STATIONARY = 0.02
"""Density of the stationary clutter in the lower-left quarter of the Fig. 5 scene (our choice)."""


def _stationary_patch(scene: BinaryScene, gen: torch.Generator, density: float) -> BinaryScene:
    """Add stationary clutter (same pixels in every scan) to the lower-left quarter."""
    cube = scene.cube if scene.batched else scene.cube[None]
    b, _, h, w = cube.shape
    patch = torch.zeros((b, 1, h, w), dtype=torch.bool)
    patch[:, :, 3 * h // 4 :, : w // 4] = (
        torch.rand((b, 1, h - 3 * h // 4, w // 4), generator=gen) < density
    )
    new = cube | patch
    return BinaryScene(
        cube=new if scene.batched else new[0],
        labels=scene.labels,
        tracks=scene.tracks,
        track_labels=scene.track_labels,
        split_parents=scene.split_parents,
        specs=scene.specs,
    )


def _table3_paper_scene(
    density: float, batch: int | None, gen: torch.Generator, name: str = "table3-paper"
) -> BinaryScene:
    """Each batch element gets its own random placement (drawn before its clutter)."""
    scenes = []
    for _ in range(1 if batch is None else check_int("batch", batch, minimum=1)):
        specs = _PRESETS[name](gen)
        scenes.append(simulate_binary(_SHAPES[name], specs, clutter_density=density, generator=gen))
    if batch is None:
        return scenes[0]
    return BinaryScene(
        cube=torch.stack([sc.cube for sc in scenes]),
        labels=torch.stack([sc.labels for sc in scenes]),
        tracks=[list(sc.tracks) for sc in scenes],
        track_labels=scenes[0].track_labels,
        split_parents={},
        specs=scenes[0].specs,
    )


_PRESETS = {
    "table2": table2_targets,
    "table3": table3_targets,
    "fig5": fig5_targets,
    "table3-paper": table3_paper_targets,
    "fig5-paper": fig5_paper_targets,
    "table3-int": table3_integer_targets,
}


def paper_shape(name: str) -> tuple[int, int, int]:
    """Cube shape ``(T, H, W)`` of a paper scenario.

    Args:
        name: ``"table2"``, ``"table3"`` or ``"fig5"``.

    Returns:
        ``(10, 320, 520)``, ``(10, 60, 60)`` or ``(16, 60, 60)``.

    Examples:
        >>> paper_shape("table2")
        (10, 320, 520)
    """
    return _SHAPES[check_choice("name", name, tuple(_PRESETS))]


def paper_scene(
    name: str,
    density: float,
    *,
    seed: int | None = None,
    batch: int | None = None,
    generator: torch.Generator | None = None,
) -> BinaryScene:
    """Simulate one of the [LA98] scenarios with uniform clutter of the given density.

    Args:
        name: the paper's scenes ``"table2"`` (:func:`table2_targets` in ``(10, 320, 520)``),
            ``"table3-paper"`` (three randomly placed 10-scan tracks,
            :func:`table3_paper_targets`, in ``(10, 60, 60)``; every batch element draws its own
            placement) and ``"fig5-paper"`` (:func:`fig5_paper_targets` in ``(16, 520, 520)``
            plus stationary clutter in the lower-left quarter), ``"table3-int"`` (our addition:
            the same configurations with integer velocities, :func:`table3_integer_targets`),
            or our harder scenes
            ``"table3"`` (:func:`table3_targets`: four tracks and a split branch in
            ``(10, 60, 60)``) and ``"fig5"`` (:func:`fig5_targets` in ``(16, 60, 60)``).
        density: clutter density in ``[0, 1]`` (fraction of pixels per scan).
        seed: seed of the generator (``None``: non-deterministic).
        batch: ``None`` for one ``(T, H, W)`` scene, or ``B`` for ``(B, T, H, W)``.
        generator: a ``torch.Generator`` instead of ``seed``.

    Returns:
        The :class:`BinaryScene`.

    Examples:
        >>> scene = paper_scene("table3", 0.02, seed=0)
        >>> scene.cube.shape, scene.track_labels
        (torch.Size([10, 60, 60]), (1, 2, 3, 4, 5))
    """
    name = check_choice("name", name, tuple(_PRESETS))
    if name in ("table3-paper", "table3-int"):
        return _table3_paper_scene(density, batch, _make_generator(seed, generator), name)
    if name == "fig5-paper":
        gen = _make_generator(seed, generator)
        scene = simulate_binary(
            _SHAPES[name], _PRESETS[name](), clutter_density=density, batch=batch, generator=gen
        )
        return _stationary_patch(scene, gen, FIG5_STATIONARY)
    return simulate_binary(
        _SHAPES[name],
        _PRESETS[name](),
        clutter_density=density,
        batch=batch,
        seed=seed,
        generator=generator,
    )

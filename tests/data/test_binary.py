import dataclasses
import itertools
import math

import pytest
import torch

from hocnet.data.binary import (
    BinaryScene,
    TargetSpec,
    fig5_paper_targets,
    fig5_targets,
    paper_scene,
    paper_shape,
    simulate_binary,
    table2_targets,
    table3_paper_targets,
    table3_targets,
)

# Speed note (not a timed test): on a 2-core CPU,
#   simulate_binary((10, 60, 60), table3_targets()[:3], clutter_density=0.02, batch=1000, seed=0)
# takes 0.35-1 s (measured 0.33-0.50 s on an idle machine).


def rows(track: torch.Tensor) -> list[tuple[int, int, int]]:
    return [tuple(r) for r in track.tolist()]


def moves(points: list[tuple[int, int, int]]) -> list[tuple[int, int]]:
    return [(b[2] - a[2], b[1] - a[1]) for a, b in itertools.pairwise(points)]


def turn(m1: tuple[int, int], m2: tuple[int, int]) -> float:
    if m1 == (0, 0) or m2 == (0, 0):
        return 0.0
    d = abs(math.atan2(m2[1], m2[0]) - math.atan2(m1[1], m1[0])) % (2 * math.pi)
    return min(d, 2 * math.pi - d)


def full_path(scene: BinaryScene, label: int) -> list[tuple[int, int, int]]:
    """Points of a track; for a split branch, preceded by its parent's points before the split."""
    track = rows(scene.tracks[scene.track_labels.index(label)])
    parent = scene.split_parents.get(label)
    if parent is None:
        return track
    before = [p for p in rows(scene.tracks[scene.track_labels.index(parent)]) if p[0] < track[0][0]]
    return before + track


class TestTargetSpec:
    def test_smoke(self):
        spec = TargetSpec(start=(1, 2), velocity=(0.5, -1))
        assert spec.start == (1.0, 2.0)
        assert spec.velocity == (0.5, -1.0)
        assert spec.turn_rate == 0.0 and spec.first_scan == 0 and spec.last_scan is None
        assert spec.p_miss == 0.0 and spec.split_at is None and spec.label is None

    def test_accepts_tensor_pairs(self):
        spec = TargetSpec(start=torch.tensor([1.0, 2.0]), velocity=torch.tensor([3, 4]))
        assert spec.start == (1.0, 2.0) and spec.velocity == (3.0, 4.0)

    def test_frozen(self):
        spec = TargetSpec(start=(0, 0), velocity=(1, 0))
        with pytest.raises(dataclasses.FrozenInstanceError):
            spec.p_miss = 0.5

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"velocity": (float("nan"), 0)}, ValueError, r"`velocity\[0\]`"),
            ({"velocity": (0, float("inf"))}, ValueError, r"`velocity\[1\]`"),
            ({"velocity": (1, 2, 3)}, TypeError, "`velocity`"),
            ({"start": "ab"}, TypeError, "`start`"),
            ({"start": (0, float("-inf"))}, ValueError, r"`start\[1\]`"),
            ({"turn_rate": 4.0}, ValueError, "`turn_rate`"),
            ({"turn_rate": float("nan")}, ValueError, "`turn_rate`"),
            ({"first_scan": -1}, ValueError, "`first_scan`"),
            ({"first_scan": 1.5}, TypeError, "`first_scan`"),
            ({"first_scan": 3, "last_scan": 2}, ValueError, "`last_scan`"),
            ({"p_miss": 1.5}, ValueError, "`p_miss`"),
            ({"p_miss": -0.1}, ValueError, "`p_miss`"),
            ({"split_at": 2}, ValueError, "`split_velocity`"),
            ({"split_velocity": (1, 1)}, ValueError, "`split_velocity`"),
            ({"split_at": 1, "first_scan": 2, "split_velocity": (1, 1)}, ValueError, "`split_at`"),
            ({"split_at": 5, "last_scan": 5, "split_velocity": (1, 1)}, ValueError, "`split_at`"),
            ({"split_at": 1, "split_velocity": (1, float("nan"))}, ValueError, "`split_velocity"),
            ({"label": 0}, ValueError, "`label`"),
            ({"label": True}, TypeError, "`label`"),
        ],
    )
    def test_exceptions(self, kwargs, error, match):
        args = {"start": (0, 0), "velocity": (1, 0)} | kwargs
        with pytest.raises(error, match=match):
            TargetSpec(**args)


class TestSimulateBinary:
    def test_smoke_unbatched(self):
        scene = simulate_binary((5, 8, 9), [TargetSpec((1, 1), (1, 1))], seed=0)
        assert isinstance(scene, BinaryScene)
        assert scene.cube.shape == (5, 8, 9) and scene.cube.dtype == torch.bool
        assert scene.labels.shape == (5, 8, 9) and scene.labels.dtype == torch.int64
        assert not scene.batched
        assert len(scene.tracks) == 1 and scene.tracks[0].dtype == torch.int64
        assert scene.tracks[0].shape == (5, 3)
        assert scene.track_labels == (1,)
        assert scene.n_target_points.shape == () and int(scene.n_target_points) == 5

    def test_shapes_batched(self):
        specs = [TargetSpec((1, 1), (1, 1)), TargetSpec((6, 1), (0, 1))]
        scene = simulate_binary((5, 8, 9), specs, clutter_density=0.1, batch=3, seed=0)
        assert scene.batched
        assert scene.cube.shape == scene.labels.shape == (3, 5, 8, 9)
        assert len(scene.tracks) == 3 and all(len(t) == 2 for t in scene.tracks)
        assert scene.n_target_points.shape == scene.n_clutter_points.shape == (3,)
        assert scene.target_mask.shape == scene.clutter_mask.shape == (3, 5, 8, 9)

    def test_batch_one_keeps_axis(self):
        scene = simulate_binary((2, 3, 3), [], batch=1, seed=0)
        assert scene.cube.shape == (1, 2, 3, 3) and scene.tracks == [[]]

    def test_empty_scene(self):
        scene = simulate_binary((3, 4, 4), seed=0)
        assert not scene.cube.any() and not scene.labels.any()
        assert scene.tracks == [] and scene.track_labels == () and scene.split_parents == {}
        assert int(scene.n_target_points) == 0 and int(scene.n_clutter_points) == 0

    def test_unseeded_runs(self):
        scene = simulate_binary((3, 10, 10), clutter_density=0.5)
        assert scene.cube.any()

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"shape": (5, 8)}, TypeError, "`shape`"),
            ({"shape": (0, 8, 8)}, ValueError, r"`shape\[0\] \(T\)`"),
            ({"shape": (5, 8, 2.5)}, TypeError, r"`shape\[2\] \(W\)`"),
            ({"targets": [(0, 0)]}, TypeError, r"`targets\[0\]`"),
            ({"targets": 3}, TypeError, "`targets`"),
            ({"targets": [TargetSpec((0, 0), (1, 0), first_scan=5)]}, ValueError, "first_scan"),
            ({"targets": [TargetSpec((0, 0), (1, 0), last_scan=5)]}, ValueError, "last_scan"),
            (
                {"targets": [TargetSpec((0, 0), (1, 0), split_at=4, split_velocity=(0, 1))]},
                ValueError,
                r"`targets\[0\]\.split_at`",
            ),
            ({"clutter_density": 1.5}, ValueError, "`clutter_density`"),
            ({"clutter_density": float("nan")}, ValueError, "`clutter_density`"),
            ({"stationary_clutter": -0.1}, ValueError, "`stationary_clutter`"),
            ({"batch": 0}, ValueError, "`batch`"),
            ({"batch": 2.0}, TypeError, "`batch`"),
            ({"seed": -1}, ValueError, "`seed`"),
            ({"seed": 1, "generator": torch.Generator()}, ValueError, "`generator`"),
            ({"generator": 3}, TypeError, "`generator`"),
            (
                {"targets": [TargetSpec((0, 0), (1, 0)), TargetSpec((0, 0), (1, 0), label=1)]},
                ValueError,
                "`targets`: expected distinct labels",
            ),
            (
                {
                    "targets": [
                        TargetSpec((0, 0), (1, 0), split_at=1, split_velocity=(1, 1)),
                        TargetSpec((0, 0), (1, 0), label=3),
                    ]
                },
                ValueError,
                "split branch",
            ),
        ],
    )
    def test_exceptions(self, kwargs, error, match):
        args = {"shape": (5, 8, 8), "targets": ()} | kwargs
        shape, targets = args.pop("shape"), args.pop("targets")
        with pytest.raises(error, match=match):
            simulate_binary(shape, targets, **args)

    def test_same_seed_identical(self):
        specs = [TargetSpec((1, 1), (1, 1), p_miss=0.3), TargetSpec((9, 2), (0, 1), p_miss=0.3)]
        kwargs = {"clutter_density": 0.1, "stationary_clutter": 0.02, "batch": 4}
        a = simulate_binary((6, 12, 12), specs, seed=7, **kwargs)
        b = simulate_binary((6, 12, 12), specs, seed=7, **kwargs)
        assert torch.equal(a.cube, b.cube) and torch.equal(a.labels, b.labels)
        for ta, tb in zip(a.tracks, b.tracks):
            assert all(torch.equal(x, y) for x, y in zip(ta, tb))

    def test_different_seed_differs(self):
        a = simulate_binary((6, 12, 12), clutter_density=0.2, seed=1)
        b = simulate_binary((6, 12, 12), clutter_density=0.2, seed=2)
        assert not torch.equal(a.cube, b.cube)

    def test_generator_matches_seed_and_advances(self):
        gen = torch.Generator().manual_seed(5)
        first = simulate_binary((4, 10, 10), clutter_density=0.3, generator=gen)
        second = simulate_binary((4, 10, 10), clutter_density=0.3, generator=gen)
        seeded = simulate_binary((4, 10, 10), clutter_density=0.3, seed=5)
        assert torch.equal(first.cube, seeded.cube)
        assert not torch.equal(first.cube, second.cube)

    def test_global_state_untouched(self):
        torch.manual_seed(0)
        expected = torch.rand(3)
        torch.manual_seed(0)
        simulate_binary((3, 8, 8), [TargetSpec((1, 1), (1, 0), p_miss=0.5)], clutter_density=0.3)
        assert torch.equal(torch.rand(3), expected)

    def test_clutter_density(self):
        p, shape = 0.05, (20, 100, 100)
        scene = simulate_binary(shape, clutter_density=p, batch=2, seed=0)
        n = scene.cube.numel()
        se = math.sqrt(p * (1 - p) / n)
        assert abs(scene.cube.float().mean().item() - p) < 5 * se
        # independent per scan and per batch element
        assert not torch.equal(scene.cube[0, 0], scene.cube[0, 1])
        assert not torch.equal(scene.cube[0], scene.cube[1])

    @pytest.mark.parametrize("p", [0.0, 1.0])
    def test_clutter_extremes(self, p):
        scene = simulate_binary((3, 5, 5), clutter_density=p, seed=0)
        assert bool((scene.cube == bool(p)).all())

    def test_stationary_clutter(self):
        p = 0.1
        scene = simulate_binary((6, 100, 100), stationary_clutter=p, batch=2, seed=3)
        cube = scene.cube
        assert bool((cube == cube[:, :1]).all())  # same points in every scan
        assert not torch.equal(cube[0], cube[1])  # independent per batch element
        n = cube[:, 0].numel()
        assert abs(cube[:, 0].float().mean().item() - p) < 5 * math.sqrt(p * (1 - p) / n)
        assert int(scene.n_clutter_points.sum()) == int(cube.sum())

    def test_stationary_plus_moving_clutter(self):
        scene = simulate_binary((5, 40, 40), clutter_density=0.05, stationary_clutter=0.05, seed=1)
        fixed = scene.cube.all(dim=0)
        assert fixed.float().mean() > 0.04  # the stationary points stay on whatever the clutter

    def test_points_where_spec_says(self):
        # x: 2.5, 4.0, 5.5, 7.0 -> 3, 4, 6, 7 ; y: 1.4, 1.9, 2.4, 2.9 -> 1, 2, 2, 3 (floor(p + .5))
        spec = TargetSpec(start=(2.5, 1.4), velocity=(1.5, 0.5))
        scene = simulate_binary((4, 10, 10), [spec], seed=0)
        expected = [(0, 1, 3), (1, 2, 4), (2, 2, 6), (3, 3, 7)]
        assert rows(scene.tracks[0]) == expected
        assert scene.cube.nonzero().tolist() == [list(p) for p in expected]
        assert scene.labels.sum().item() == 4

    def test_rounding_half_up_negative(self):
        # floor(p + 0.5): -0.5 -> 0 (drawn), -1.5 -> -1 (off frame), 0.5 -> 1
        spec = TargetSpec(start=(-1.5, 0.5), velocity=(1.0, 0.0))
        scene = simulate_binary((3, 4, 4), [spec], seed=0)
        assert rows(scene.tracks[0]) == [(1, 1, 0), (2, 1, 1)]

    def test_off_frame_points_not_drawn(self):
        spec = TargetSpec(start=(-2, 1), velocity=(2, 0))  # x = -2, 0, 2, 4, 6
        scene = simulate_binary((5, 3, 5), [spec], seed=0)
        assert rows(scene.tracks[0]) == [(1, 1, 0), (2, 1, 2), (3, 1, 4)]
        assert int(scene.n_target_points) == 3

    def test_turning_track(self):
        spec = TargetSpec(start=(5, 5), velocity=(2, 0), turn_rate=math.pi / 2)
        scene = simulate_binary((5, 12, 12), [spec], seed=0)
        # moves (2,0), (0,2), (-2,0), (0,-2): a square, bearing growing by 90 degrees per scan
        assert rows(scene.tracks[0]) == [(0, 5, 5), (1, 5, 7), (2, 7, 7), (3, 7, 5), (4, 5, 5)]

    def test_first_last_scan(self):
        spec = TargetSpec(start=(1, 1), velocity=(1, 0), first_scan=2, last_scan=5)
        scene = simulate_binary((8, 6, 10), [spec], seed=0)
        assert rows(scene.tracks[0]) == [(2, 1, 1), (3, 1, 2), (4, 1, 3), (5, 1, 4)]
        assert not scene.cube[:2].any() and not scene.cube[6:].any()

    def test_p_miss_one_removes_all_target_points(self):
        specs = [TargetSpec((1, 1), (1, 1), p_miss=1.0, split_at=1, split_velocity=(1, 0))]
        scene = simulate_binary((5, 8, 8), specs, batch=3, seed=0)
        assert not scene.cube.any() and not scene.labels.any()
        assert all(t.shape == (0, 3) for per in scene.tracks for t in per)
        assert scene.n_target_points.tolist() == [0, 0, 0]

    def test_p_miss_fraction_and_independence(self):
        spec = TargetSpec((0, 0), (1, 0), p_miss=0.5)
        scene = simulate_binary((50, 1, 60), [spec], batch=40, seed=0)
        kept = scene.n_target_points.sum().item() / (50 * 40)
        assert abs(kept - 0.5) < 5 * math.sqrt(0.25 / 2000)
        assert not torch.equal(scene.tracks[0][0], scene.tracks[1][0])
        for per, labels in zip(scene.tracks, scene.labels):  # kept points are drawn
            t, y, x = per[0].unbind(1)
            assert bool((labels[t, y, x] == 1).all()) and int((labels > 0).sum()) == len(per[0])

    def test_misses_do_not_depend_on_clutter(self):
        spec = TargetSpec((0, 0), (1, 1), p_miss=0.4)
        a = simulate_binary((8, 8, 8), [spec], batch=3, seed=4)
        b = simulate_binary((8, 8, 8), [spec], clutter_density=0.3, batch=3, seed=4)
        for ta, tb in zip(a.tracks, b.tracks):
            assert torch.equal(ta[0], tb[0])

    def test_split_branch(self):
        spec = TargetSpec((1, 5), (2, 0), split_at=2, split_velocity=(2, 1))
        other = TargetSpec((1, 1), (1, 0))
        scene = simulate_binary((5, 10, 12), [spec, other], seed=0)
        assert scene.track_labels == (1, 2, 3)
        assert scene.split_parents == {3: 1}
        assert rows(scene.tracks[0]) == [(0, 5, 1), (1, 5, 3), (2, 5, 5), (3, 5, 7), (4, 5, 9)]
        assert rows(scene.tracks[2]) == [(2, 5, 5), (3, 6, 7), (4, 7, 9)]
        assert scene.labels[2, 5, 5] == 1  # shared split point: the lower label wins
        assert scene.labels[4, 7, 9] == 3

    def test_split_point_missed_together(self):
        spec = TargetSpec((0, 2), (1, 0), split_at=1, split_velocity=(1, 1), p_miss=0.5)
        scene = simulate_binary((4, 8, 8), [spec], batch=200, seed=0)
        for main, branch in scene.tracks:
            in_main = any(r[0] == 1 for r in rows(main))
            in_branch = any(r[0] == 1 for r in rows(branch))
            assert in_main == in_branch

    def test_two_splits_labels(self):
        specs = [
            TargetSpec((0, 0), (1, 0), split_at=1, split_velocity=(1, 1)),
            TargetSpec((0, 9), (1, 0)),
            TargetSpec((0, 5), (1, 0), split_at=2, split_velocity=(1, -1)),
        ]
        scene = simulate_binary((5, 12, 12), specs, seed=0)
        assert scene.track_labels == (1, 2, 3, 4, 5)
        assert scene.split_parents == {4: 1, 5: 3}
        assert rows(scene.tracks[4])[0] == (2, 5, 2)

    def test_label_override(self):
        specs = [TargetSpec((0, 0), (1, 0), label=9), TargetSpec((0, 3), (1, 0))]
        scene = simulate_binary((3, 5, 5), specs, seed=0)
        assert scene.track_labels == (2, 9)
        assert rows(scene.tracks[1])[0] == (0, 0, 0)
        assert set(scene.labels.unique().tolist()) == {0, 2, 9}

    def test_crossing_tracks_share_pixel(self):
        specs = [TargetSpec((0, 0), (1, 1)), TargetSpec((0, 4), (1, -1))]
        scene = simulate_binary((5, 5, 5), specs, seed=0)
        assert (2, 2, 2) in rows(scene.tracks[0]) and (2, 2, 2) in rows(scene.tracks[1])
        assert scene.labels[2, 2, 2] == 1
        assert int(scene.n_target_points) == 9

    def test_labels_consistent_with_cube(self):
        scene = paper_scene("table3", 0.1, batch=3, seed=0)
        assert torch.equal(scene.cube, scene.clutter_mask | scene.target_mask)
        assert torch.equal(scene.n_clutter_points, scene.clutter_mask.sum(dim=(1, 2, 3)))
        for b, per in enumerate(scene.tracks):
            drawn = torch.zeros_like(scene.target_mask[b])
            for label, track in zip(scene.track_labels, per):
                t, y, x = track.unbind(1)
                got = scene.labels[b, t, y, x]
                assert bool((got > 0).all()) and bool((got <= label).all())
                drawn[t, y, x] = True
            assert torch.equal(drawn, scene.target_mask[b])

    def test_select(self):
        scene = simulate_binary((3, 6, 6), [TargetSpec((0, 0), (1, 1))], batch=2, seed=0)
        one = scene.select(1)
        assert not one.batched and torch.equal(one.cube, scene.cube[1])
        assert torch.equal(one.tracks[0], scene.tracks[1][0])
        with pytest.raises(ValueError, match="`index`"):
            scene.select(2)
        with pytest.raises(ValueError, match="batched"):
            one.select(0)


PRESETS = {"table2": table2_targets, "table3": table3_targets, "fig5": fig5_targets}


class TestPresets:
    @pytest.mark.parametrize(
        ("name", "shape"),
        [("table2", (10, 320, 520)), ("table3", (10, 60, 60)), ("fig5", (16, 60, 60))],
    )
    def test_shapes(self, name, shape):
        assert paper_shape(name) == shape
        scene = paper_scene(name, 0.01, seed=0)
        assert scene.cube.shape == shape
        batched = paper_scene(name, 0.0, seed=0, batch=2)
        assert batched.cube.shape == (2, *shape)

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`name`"):
            paper_scene("table4", 0.01)
        with pytest.raises(ValueError, match="`name`"):
            paper_shape("fig6")
        with pytest.raises(ValueError, match="`clutter_density`"):
            paper_scene("table3", 2.0)

    @pytest.mark.parametrize("name", list(PRESETS))
    def test_deterministic(self, name):
        assert PRESETS[name]() == PRESETS[name]()
        a, b = paper_scene(name, 0.02, seed=3), paper_scene(name, 0.02, seed=3)
        assert torch.equal(a.cube, b.cube)

    @pytest.mark.parametrize("name", list(PRESETS))
    def test_moves_and_turns_within_window(self, name):
        scene = paper_scene(name, 0.0, seed=0)
        for spec, track in zip(scene.specs, scene.tracks):  # no point falls off the frame
            last = scene.cube.shape[0] - 1 if spec.last_scan is None else spec.last_scan
            assert len(track) == last - spec.first_scan + 1
        for label in scene.track_labels:
            path = full_path(scene, label)
            assert [b[0] - a[0] for a, b in itertools.pairwise(path)] == [1] * (len(path) - 1)
            ms = moves(path)
            assert all(max(abs(i), abs(j)) <= 4 and math.hypot(i, j) <= 4 for i, j in ms)
            assert all(turn(a, b) <= math.pi / 4 + 1e-9 for a, b in itertools.pairwise(ms))

    def test_table2(self):
        scene = paper_scene("table2", 0.0, seed=0)
        assert len(scene.tracks) == 2 and all(len(t) == 10 for t in scene.tracks)
        for label in scene.track_labels:
            ms = set(moves(full_path(scene, label)))
            assert len(ms) == 1 and 2 <= max(abs(c) for c in next(iter(ms))) <= 3
        a, b = (t.float() for t in scene.tracks)
        assert (a - b)[:, 1:].norm(dim=1).min() > 100  # well separated

    def test_table3(self):
        scene = paper_scene("table3", 0.0, seed=0)
        tracks = {label: rows(t) for label, t in zip(scene.track_labels, scene.tracks)}
        assert set(tracks[1]) & set(tracks[2]) == {(5, 30, 30)}  # crossing
        assert scene.split_parents == {5: 3} and len(tracks[5]) >= 5  # splitting
        assert tracks[5][0] in tracks[3] and tracks[5][-1] not in tracks[3]
        parallel = [(b[1] - a[1], b[2] - a[2]) for a, b in zip(tracks[3], tracks[4])]
        assert set(parallel) == {(2, 0)}  # close parallel, 2 px apart

    def test_fig5(self):
        specs = fig5_targets()
        scene = paper_scene("fig5", 0.0, seed=0)
        assert scene.cube.shape[0] == 16 and len(specs) == 6
        assert len(scene.split_parents) == 2
        assert all(len(t) >= 5 for t in scene.tracks)
        assert len({s.first_scan for s in specs}) == 6 and len({s.last_scan for s in specs}) == 6
        # no two targets collide: every drawn pixel belongs to exactly one track
        assert int(scene.n_target_points) == sum(len(t) for t in scene.tracks) - 2


class TestPaperScenes:
    """The scenes as [LA98] describes them (Table III: three random tracks; Fig. 5: 520 x 520)."""

    @pytest.mark.parametrize("configuration", ["close", "crossing", "splitting"])
    def test_table3_configurations(self, configuration):
        for seed in range(5):
            gen = torch.Generator().manual_seed(seed)
            specs = table3_paper_targets(gen, configuration)
            scene = simulate_binary((10, 60, 60), specs, seed=seed)
            assert len(scene.tracks) == 3
            assert all(len(t) == 10 for t in scene.tracks)  # every point inside the frame
            pts = [t.float() for t in scene.tracks]
            gaps = [
                (pts[a][:, 1:] - pts[b][:, 1:]).norm(dim=1).min().item()
                for a, b in itertools.combinations(range(3), 2)
            ]
            assert min(gaps) <= 4  # close, crossing or splitting: two tracks within 4 px

    def test_table3_paper_scene(self):
        scene = paper_scene("table3-paper", 0.014, seed=0)
        assert scene.cube.shape == (10, 60, 60)
        assert 29 <= int(scene.n_target_points) <= 30  # 30 unless two tracks share a pixel
        batched = paper_scene("table3-paper", 0.0, seed=0, batch=3)
        assert batched.cube.shape == (3, 10, 60, 60)
        assert not torch.equal(batched.cube[0], batched.cube[1])  # own placement per scene
        again = paper_scene("table3-paper", 0.014, seed=0)
        assert torch.equal(scene.cube, again.cube)

    def test_bad_configuration(self):
        with pytest.raises(ValueError, match="`configuration`"):
            table3_paper_targets(torch.Generator().manual_seed(0), "parallel")

    def test_fig5_paper(self):
        specs = fig5_paper_targets()
        assert len(specs) == 5 and sum(s.split_at is not None for s in specs) == 1
        assert [s.first_scan for s in specs[:4]] == [0, 1, 2, 3]  # first interval
        assert specs[4].first_scan >= 2  # the splitting pair starts later
        scene = paper_scene("fig5-paper", 0.0, seed=0)
        assert scene.cube.shape == (16, 520, 520)
        assert len(scene.tracks) == 6
        clutter = scene.clutter_mask
        assert torch.equal(clutter[0], clutter[15])  # stationary clutter only
        h, w = 520, 520
        assert not clutter[:, : 3 * h // 4].any() and not clutter[:, :, w // 4 :].any()
        assert clutter.any()

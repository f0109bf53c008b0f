import itertools
import math
import os
import random
import subprocess
import sys
import time
import tracemalloc
import typing
import warnings

import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hocnet.data.binary import paper_scene
from hocnet.hoc import chain_support, detect, identify_tracks, reject_slow_tracks
from hocnet.hoc import identify as identify_module
from hocnet.hoc.functional import _allowed_cached, _sparse_triples, density_bound
from hocnet.hoc.identify import (
    _is_near_duplicate,
    _sequences,
    _short_track_sequences,
    _whole_sequence_rows,
    _whole_sequences,
    mhoc_candidates,
)
from hocnet.hoc.kernels import allowed_moves, move_offsets
from hocnet.hoc.reference import turn_reference
from hocnet.hoc.scoring import track_point_scores


@st.composite
def gentle_track_scene(draw):
    """A straight or gently turning track of >= 2k + 1 points plus arbitrary clutter."""
    order = draw(st.integers(1, 3))
    v = draw(st.integers(1, 4))
    delta = draw(st.sampled_from([math.pi / 4, math.pi / 3, math.pi / 2]))
    n_t = draw(st.integers(2 * order + 1, 10))
    length = draw(st.integers(2 * order + 1, n_t))
    first = draw(st.integers(0, n_t - length))
    moves = move_offsets(v).tolist()
    allowed = allowed_moves(v, delta)
    m = draw(st.integers(0, len(moves) - 1))
    path = [m]
    for _ in range(length - 2):
        options = allowed[path[-1]].nonzero().squeeze(1).tolist()
        path.append(options[draw(st.integers(0, len(options) - 1))])
    xs, ys = [0], [0]
    for idx in path:
        xs.append(xs[-1] + moves[idx][0])
        ys.append(ys[-1] + moves[idx][1])
    h = max(ys) - min(ys) + 1 + 2 * draw(st.integers(0, 4))
    w = max(xs) - min(xs) + 1 + 2 * draw(st.integers(0, 4))
    density = draw(st.sampled_from([0.0, 0.05, 0.2, 0.35]))
    seed = draw(st.integers(0, 2**31 - 1))
    cube = torch.rand(n_t, h, w, generator=torch.Generator().manual_seed(seed)) < density
    truth = torch.zeros_like(cube)
    for k, (x, y) in enumerate(zip(xs, ys)):
        truth[first + k, y - min(ys), x - min(xs)] = True
    return cube | truth, truth, order, v, delta


class TestProposition1:
    @settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(gentle_track_scene())
    def test_track_survives_any_clutter(self, scene):
        cube, truth, order, v, delta = scene
        methods = ("conv", "sparse") if cube.numel() <= 1500 else ("sparse",)
        for method in methods:
            support = chain_support(cube, order, v, delta, method=method)
            assert not (truth & ~support).any(), method
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # dense draws are above the density bound
            result = detect(cube, order=order, v=v, delta=delta, support="chain")
        if not result.saturated:  # above the density bound the support is the MHOC image
            assert not (truth & ~result.support).any()


def _straight_track(x0, y0, speed, angle, n_t=10):
    vx, vy = speed * math.cos(angle), speed * math.sin(angle)
    return [(t, math.floor(y0 + t * vy + 0.5), math.floor(x0 + t * vx + 0.5)) for t in range(n_t)]


@st.composite
def hard_case(draw):
    """Three straight tracks at 1-3 px/scan in any direction passing near the centre at t ~ 4.5.

    Silently drops the tracks eq. (6) itself rejects (the ``assume`` on the turns): near
    1 px/scan the rounded integer moves of a straight track can turn by 90 degrees, e.g.
    (1, 0) then (0, 1). Measured on 20 000 uniform draws (speed, angle, offsets; all inside
    the frame): 423 (2.1 %) dropped, speeds 1.00-1.33 px/scan, so about 6 % of three-track
    scenes are redrawn; alone and without clutter, ``detect`` loses 579 of the 2000 points
    (29 %) of the first 200 dropped tracks. The property below says nothing about such tracks.
    """
    tracks = []
    for _ in range(3):
        speed = draw(st.floats(1.0, 3.0))
        angle = draw(st.floats(-math.pi, math.pi))
        ox, oy = draw(st.floats(-3, 3)), draw(st.floats(-3, 3))
        x0 = 30 + ox - 4.5 * speed * math.cos(angle)
        y0 = 30 + oy - 4.5 * speed * math.sin(angle)
        pts = _straight_track(x0, y0, speed, angle)
        assume(all(0 <= y < 60 and 0 <= x < 60 for _, y, x in pts))
        moves = [(b[2] - a[2], b[1] - a[1]) for a, b in itertools.pairwise(pts)]
        # integer moves alternate; the track must meet the detector's own criterion (eq. 6)
        assume(
            all(
                turn_reference(*m1, *m2) <= math.pi / 4 + 1e-9
                for m1, m2 in itertools.pairwise(moves)
            )
        )
        tracks.append(pts)
    seed = draw(st.integers(0, 2**31 - 1))
    return tracks, seed


def _hard_scene(tracks, seed, density=0.014):
    """The hard-case cube: ``tracks`` of ``(y, x)`` per scan 0-9 plus uniform clutter."""
    cube = torch.rand(10, 60, 60, generator=torch.Generator().manual_seed(seed)) < density
    truth = torch.zeros_like(cube)
    for pts in tracks:
        for t, (y, x) in enumerate(pts):
            truth[t, y, x] = True
    return cube | truth, truth


HARD_SCENES = {
    # clutter seed: the three tracks, (y, x) at scans 0-9 (scenes 91, 112, 115 and 555 of 600
    # drawn like ``hard_case`` with random.Random(7), the clutter seed the scene number)
    # 14: seed 14 of ``random.Random(seed)`` drawn like ``hard_case`` (review finding 2: a
    # kept track sharing only two far points near-duplicated the true track at scan 1)
    14: [
        [
            (27, 29),
            (29, 30),
            (30, 30),
            (31, 30),
            (32, 31),
            (33, 31),
            (34, 31),
            (36, 32),
            (37, 32),
            (38, 33),
        ],
        [
            (38, 31),
            (36, 31),
            (35, 31),
            (33, 31),
            (32, 31),
            (30, 31),
            (29, 31),
            (27, 32),
            (26, 32),
            (24, 32),
        ],
        [
            (25, 26),
            (27, 27),
            (28, 28),
            (29, 28),
            (31, 29),
            (32, 30),
            (34, 30),
            (35, 31),
            (37, 32),
            (38, 32),
        ],
    ],
    91: [
        [
            (28, 23),
            (29, 24),
            (30, 25),
            (31, 26),
            (32, 27),
            (33, 28),
            (34, 29),
            (35, 30),
            (36, 31),
            (37, 32),
        ],
        [
            (34, 33),
            (33, 32),
            (33, 31),
            (33, 30),
            (33, 28),
            (32, 27),
            (32, 26),
            (32, 24),
            (32, 23),
            (32, 22),
        ],
        [
            (33, 32),
            (32, 31),
            (31, 30),
            (29, 29),
            (28, 28),
            (27, 27),
            (25, 26),
            (24, 25),
            (23, 23),
            (21, 22),
        ],
    ],
    112: [
        [
            (41, 28),
            (38, 28),
            (35, 29),
            (33, 29),
            (30, 29),
            (27, 29),
            (24, 30),
            (22, 30),
            (19, 30),
            (16, 31),
        ],
        [
            (39, 30),
            (37, 30),
            (36, 29),
            (34, 28),
            (32, 27),
            (30, 27),
            (29, 26),
            (27, 25),
            (25, 24),
            (24, 24),
        ],
        [
            (37, 29),
            (35, 29),
            (34, 29),
            (32, 29),
            (31, 29),
            (29, 29),
            (28, 29),
            (26, 29),
            (24, 29),
            (23, 29),
        ],
    ],
    115: [
        [
            (20, 31),
            (23, 31),
            (26, 30),
            (28, 29),
            (31, 28),
            (34, 28),
            (36, 27),
            (39, 26),
            (42, 25),
            (45, 25),
        ],
        [
            (23, 33),
            (25, 33),
            (27, 32),
            (29, 32),
            (31, 31),
            (33, 31),
            (36, 30),
            (38, 30),
            (40, 29),
            (42, 29),
        ],
        [
            (21, 34),
            (24, 33),
            (26, 32),
            (28, 30),
            (30, 29),
            (32, 28),
            (34, 26),
            (37, 25),
            (39, 23),
            (41, 22),
        ],
    ],
    555: [
        [
            (37, 38),
            (36, 37),
            (34, 36),
            (32, 34),
            (30, 33),
            (29, 32),
            (27, 31),
            (25, 29),
            (24, 28),
            (22, 27),
        ],
        [
            (33, 25),
            (32, 26),
            (31, 28),
            (31, 29),
            (30, 30),
            (29, 31),
            (28, 32),
            (28, 33),
            (27, 35),
            (26, 36),
        ],
        [
            (30, 35),
            (30, 34),
            (29, 33),
            (29, 33),
            (28, 32),
            (28, 31),
            (27, 30),
            (26, 29),
            (26, 28),
            (25, 27),
        ],
    ],
}


class TestHardCase:
    """Issue 7: straight tracks at non-integer velocities passing close to each other.

    Measured on 40 such scenes (1.4 % clutter): eq. (8)-(9) on one-scan moves with
    ``combine="min"`` loses 55 points, because alternating integer moves such as (-2, 0) /
    (-3, 1) change by 2 pixels (L1) at every point and eq. (8) scores them (9 - 2) / 3 = 2.33 <
    2.5. With one five-point sequence per image point (``shared_points=False``) the whole-
    sequence score still lost 7 points in 3 of 120 scenes and 20 in 600: where two tracks swap
    pixels at a crossing, the crossing points' best sequences switch tracks, so no kept
    sequence holds the true triple there and the true track is never a candidate (scenes 91,
    112, 115). With ``shared_points=True`` (every short track through an image point keeps its
    best Case-1 sequence) and the half-pixel residual margin of ``dedupe``
    (``RESIDUAL_MARGIN``; scene 555, a track running beside another), the default loses none
    of 600 scenes; ``test_regression_scenes`` holds the four scenes that failed, and scene 14
    of the review's 183 (a kept track sharing only far points near-duplicated a true one;
    fixed by the shared-neighbour rule, ``_next_to_shared``). Out of sample, 600 fresh scenes
    (tracks from ``random.Random(20000 + s)``, clutter seed ``70000 + s``) lose one point with
    the earlier ``residual="two-point"``, scene 76 (:class:`TestHardCaseScene76`, its measured
    cause); the default ``"two-point+straight"`` loses none of 1800 such scenes.
    """

    @settings(
        max_examples=12,
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    )
    @given(hard_case())
    def test_no_target_point_lost(self, case):
        tracks, seed = case
        cube = torch.rand(10, 60, 60, generator=torch.Generator().manual_seed(seed)) < 0.014
        truth = torch.zeros_like(cube)
        for pts in tracks:
            for p in pts:
                truth[p] = True
        cube |= truth
        result = detect(cube, order=2)  # the defaults: min, span 2, shared points
        assert not (truth & ~result.cleaned).any(), int((truth & ~result.cleaned).sum())

    @pytest.mark.parametrize("seed", sorted(HARD_SCENES))
    def test_regression_scenes(self, seed):
        cube, truth = _hard_scene(HARD_SCENES[seed], seed)
        result = detect(cube, order=2)
        assert not (truth & ~result.cleaned).any()

    @pytest.mark.parametrize(("seed", "lost"), [(91, 4), (112, 2), (115, 1)])
    def test_one_sequence_per_point_loses_crossing_points(self, seed, lost):
        # the previous rule, kept as an option: measured losses of these scenes
        cube, truth = _hard_scene(HARD_SCENES[seed], seed)
        result = detect(cube, order=2, shared_points=False)
        assert int((truth & ~result.cleaned).sum()) == lost

    def test_residual_margin(self, monkeypatch):
        # scene 555: two near-parallel tracks 1 pixel apart at scan 6. Without the rule that a
        # kept track must meet the candidate next to each differing point (``_next_to_shared``)
        # and without the half-pixel margin, the other track's point won by 0.28 px and the
        # true track was dropped as its near-duplicate; either rule alone keeps it, and so does
        # the guard for mixed candidates (``GUARD_MIXED``: the candidate mixes kept tracks)
        cube, truth = _hard_scene(HARD_SCENES[555], 555)
        monkeypatch.setattr(identify_module, "RESIDUAL_MARGIN", 1e-9)
        monkeypatch.setattr(identify_module, "_next_to_shared", lambda *args: True)
        monkeypatch.setattr(identify_module, "GUARD_MIXED", False)
        result = detect(cube, order=2)
        assert int((truth & ~result.cleaned).sum()) == 1
        monkeypatch.setattr(identify_module, "GUARD_MIXED", True)
        assert not (truth & ~detect(cube, order=2).cleaned).any()
        monkeypatch.undo()
        monkeypatch.setattr(identify_module, "RESIDUAL_MARGIN", 1e-9)
        assert not (truth & ~detect(cube, order=2).cleaned).any()
        monkeypatch.undo()
        assert not (truth & ~detect(cube, order=2).cleaned).any()

    def test_far_kept_track_does_not_near_duplicate(self, monkeypatch):
        # scene 14 (review finding 2): with ``explained``, the true track differs from an
        # unrelated kept track at scan 1 only (its other points lie on other kept tracks); the
        # residual extrapolated from that track's two points at scans 8-9 dropped (1, 29, 30),
        # whatever the margin. A kept track must share a point next to each differing one.
        cube, truth = _hard_scene(HARD_SCENES[14], 14)
        monkeypatch.setattr(identify_module, "_next_to_shared", lambda *args: True)
        for margin in (0.5, math.sqrt(2) / 2 + 1e-9, 1.0):
            monkeypatch.setattr(identify_module, "RESIDUAL_MARGIN", margin)
            lost = (truth & ~detect(cube, order=2).cleaned).nonzero().tolist()
            assert lost == [[1, 29, 30]]
        monkeypatch.undo()
        assert not (truth & ~detect(cube, order=2).cleaned).any()

    def test_whole_sequence_beats_better_triple(self):
        # a clutter point offering a straighter triple at one scan must not cut the true track
        cube = torch.zeros(10, 40, 60, dtype=torch.bool)
        pts = _straight_track(5, 30, 2.6, -0.35)
        for p in pts:
            cube[p] = True
        t, y, x = pts[5]
        cube[t, y + 1, x] = True  # a detour candidate beside the true point
        result = detect(cube, order=2)
        truth = torch.zeros_like(cube)
        for p in pts:
            truth[p] = True
        assert not (truth & ~result.cleaned).any()
        assert any(len(tr) == 10 for tr in result.tracks)


class TestDedupe:
    """Near-duplicate tracks (``dedupe``, our addition): a clutter detour at one scan."""

    def _detour_scene(self, scan=4):
        cube = torch.zeros(10, 30, 40, dtype=torch.bool)
        truth = torch.zeros_like(cube)
        for t in range(10):
            truth[t, 10 + t, 4 + 3 * t] = True
        cube |= truth
        cube[scan, 11 + scan, 4 + 3 * scan] = True  # clutter beside the true point
        return cube, truth

    @pytest.mark.parametrize("scan", [4, 5])
    def test_detour_duplicate_is_dropped(self, scan):
        cube, truth = self._detour_scene(scan)
        plain = detect(cube, order=2, dedupe=False)
        assert len(plain.tracks) == 2  # the true track and its detour copy
        result = detect(cube, order=2)  # dedupe=True is the default
        assert len(result.tracks) == 1
        assert torch.equal(result.cleaned, truth)
        assert len(result.tracks[0]) == 10

    def test_near_duplicate_rule(self):
        # points 0-4 on a line (t, y, x) = (t, t, 2t); point 5 is off it at scan 2
        xy = [[t, t, 2 * t] for t in range(5)] + [[2, 4, 4]]
        on_line, detour = [0, 1, 2, 3, 4], [0, 1, 5, 3, 4]
        scan_of = [p[0] for p in xy]

        def kept(pts):
            return [(pts, {scan_of[q]: i for i, q in enumerate(pts)})]

        image = [True] * 6
        assert _is_near_duplicate(detour, kept(on_line), scan_of, image, xy)
        # the kept track's point predicts worse: both are kept (no point dropped)
        assert not _is_near_duplicate(on_line, kept(detour), scan_of, image, xy)
        # Case 1 first: the candidate's point is in the MHOC image, the kept one's is not
        image_c = [True, True, False, True, True, True]
        assert not _is_near_duplicate(detour, kept(on_line), scan_of, image_c, xy)
        # ... and Case 1 wins over the prediction: the kept point in the image, the other not
        assert _is_near_duplicate(on_line, kept(detour), scan_of, image_c, xy)
        # differing at two scans is not a near-duplicate (dedupe=True)
        xy2 = [*xy, [3, 5, 7]]
        scan_of2 = [p[0] for p in xy2]
        two = [0, 1, 5, 6, 4]
        k2 = [(on_line, {scan_of2[q]: i for i, q in enumerate(on_line)})]
        assert not _is_near_duplicate(two, k2, scan_of2, [True] * 7, xy2)
        # ... but is with max_diff=2 (dedupe=2), both detour points 2 pixels off the line
        assert _is_near_duplicate(two, k2, scan_of2, [True] * 7, xy2, 2)
        # unless a differing image point is on no kept track and next to the kept point (a
        # crossing track's own point): point 7 is 1 pixel beside point 3
        xy3 = [*xy, [3, 3, 7]]
        scan_of3 = [p[0] for p in xy3]
        k3 = [(on_line, {scan_of3[q]: i for i, q in enumerate(on_line)})]
        near = [0, 1, 5, 6, 4]
        assert not _is_near_duplicate(near, k3, scan_of3, [True] * 7, xy3, 2, {0, 1, 2, 3, 4})
        assert _is_near_duplicate(near, k3, scan_of3, [True] * 7, xy3, 2, {0, 1, 2, 3, 4, 6})

    @pytest.mark.parametrize("dedupe", [True, 2, 3])
    @pytest.mark.parametrize("name", ["table3", "table3-paper"])
    def test_no_target_point_lost_against_plain_rule(self, name, dedupe):
        for seed in range(3):
            scene = paper_scene(name, 0.014, seed=seed)
            truth = scene.labels > 0
            plain = detect(scene.cube, order=2, dedupe=False)
            result = detect(scene.cube, order=2, dedupe=dedupe)
            assert not (truth & plain.cleaned & ~result.cleaned).any()
            assert not (result.cleaned & ~plain.cleaned).any()
            assert len(result.tracks) <= len(plain.tracks)


class TestDetect:
    def test_clean_paper_scene_recovers_every_track(self):
        scene = paper_scene("table3", 0.0, seed=0)
        result = detect(scene.cube, order=2)
        assert torch.equal(result.cleaned, scene.cube)
        assert len(result.tracks) == len(scene.tracks)
        found = {tuple(map(tuple, tr.points[-6:].tolist())) for tr in result.tracks}
        for true in scene.tracks:
            assert tuple(map(tuple, true[-6:].tolist())) in found

    @pytest.mark.parametrize("identify", ["paper", "greedy", "assignment"])
    def test_crossing_tracks_share_a_point(self, identify):
        cube = torch.zeros(9, 20, 20, dtype=torch.bool)
        for t in range(9):
            cube[t, 10, 2 + 2 * t] = True  # moving +x
            cube[t, 2 + 2 * t, 10] = True  # moving +y, both at (10, 10) at t = 4
        result = detect(cube, order=2, v=3, identify=identify)
        assert len(result.tracks) == 2
        assert all(len(tr) == 9 for tr in result.tracks)

    def test_splitting_tracks(self):
        cube = torch.zeros(10, 40, 40, dtype=torch.bool)
        for t in range(10):
            cube[t, 20, 2 + 3 * t] = True
            if t >= 3:  # a branch leaving the track at scan 3 with a 34-degree turn
                cube[t, 20 + 2 * (t - 3), 11 + 3 * (t - 3)] = True
        result = detect(cube, order=2)
        assert torch.equal(result.cleaned, cube)
        assert sorted(len(tr) for tr in result.tracks) == [10, 10]

    @pytest.mark.parametrize("seed", range(3))
    def test_paper_scene_with_clutter_loses_no_target_point(self, seed):
        scene = paper_scene("table3", 0.014, seed=seed)
        result = detect(scene.cube, order=2)
        assert not (scene.target_mask & ~result.support).any()
        assert result.cleaned.sum() < result.support.sum()

    def test_batched_tracks_carry_batch_index(self):
        scene = paper_scene("table3", 0.01, seed=1, batch=2)
        result = detect(scene.cube, order=2)
        assert result.support.shape == scene.cube.shape
        assert {tr.batch for tr in result.tracks} == {0, 1}
        assert [tr.id for tr in result.tracks] == list(range(1, len(result.tracks) + 1))
        single = detect(scene.cube[1], order=2)
        assert [tr.points.tolist() for tr in result.tracks if tr.batch == 1] == [
            tr.points.tolist() for tr in single.tracks
        ]

    def test_scores_cube(self):
        scene = paper_scene("table3", 0.0, seed=0)
        result = detect(scene.cube, order=2)
        assert result.scores.dtype == torch.float64
        assert torch.isnan(result.scores[~scene.cube]).all()
        on = result.scores[scene.cube]
        assert (on > 2.5).all()  # every point of these tracks has a good triple
        for tr in result.tracks:
            assert tr.score == pytest.approx(float(tr.point_scores[1:-1].mean()))
            assert tr.score >= 2.5

    def test_threshold_rejects(self):
        scene = paper_scene("table3", 0.0, seed=0)
        assert detect(scene.cube, order=2, threshold=10.0).tracks == []

    def test_empty(self):
        result = detect(torch.zeros(6, 8, 8), order=2)
        assert result.tracks == [] and not result.support.any() and not result.cleaned.any()
        assert not result.saturated and result.warnings == []

    def test_batch_of_zero_scenes(self):
        result = detect(torch.zeros(0, 6, 16, 16, dtype=torch.bool), order=2)
        assert result.tracks == []
        assert result.support.shape == (0, 6, 16, 16) and result.cleaned.shape == (0, 6, 16, 16)
        assert result.scores.shape == (0, 6, 16, 16)

    @pytest.mark.parametrize("size", [48, 64])
    def test_dense_cube_is_bounded_and_flagged(self, size):
        cube = torch.ones(10, size, size, dtype=torch.bool)
        tracemalloc.start()
        start = time.perf_counter()
        with pytest.warns(RuntimeWarning, match="discrimination bound"):
            result = detect(cube, order=2)
        seconds = time.perf_counter() - start
        tracemalloc.stop()
        assert seconds < 15
        assert result.saturated and "4.94 %" in result.warnings[0]
        assert result.tracks == [] and not result.cleaned.any()

    def test_density_bound(self):
        assert density_bound("original", 4) == pytest.approx(1 / 81)
        assert density_bound("modified", 4, math.pi / 4) == pytest.approx(4 / 81)

    @pytest.mark.parametrize("support", ["mhoc", "chain"])
    def test_clean_table3_scenes_keep_every_point(self, support):
        # the default whole-sequence score (min, span 2): measured 0 lost on seeds 0-29, where
        # span 1 loses points in 9 scenes with min and 1 scene (seed 4) with mean
        for seed in range(30):
            scene = paper_scene("table3-paper", 0.0, seed=seed)
            result = detect(scene.cube, order=2, support=support)
            assert torch.equal(result.cleaned, scene.cube), seed

    @pytest.mark.parametrize("name", ["table3-int", "table3-paper"])
    def test_clean_scene_span1(self, name):
        # the paper as printed (one-scan moves): min keeps integer-velocity tracks whole but
        # drops seed 17's three tracks, whose moves alternate (eq. 8 scores them 2.33)
        lost = []
        for seed in (0, 1, 2, 3, 17):
            scene = paper_scene(name, 0.0, seed=seed)
            result = detect(scene.cube, order=2, combine="min", score_span=1)
            lost.append(int((scene.cube & ~result.cleaned).sum()))
        if name == "table3-int":
            assert lost == [0, 0, 0, 0, 0]
        else:
            assert lost[-1] == 30 and lost[2] > 0

    def test_span_two_keeps_alternating_moves(self):
        scene = paper_scene("table3-paper", 0.0, seed=17)
        result = detect(scene.cube, order=2, combine="min", score_span=2)
        assert torch.equal(result.cleaned, scene.cube)
        # the accepted track scores are the whole-track span-2 scores
        for tr in result.tracks:
            want = track_point_scores(tr.points, span=2, combine="min").mean()
            assert tr.score == pytest.approx(float(want))

    def test_track_combine_and_span_validated(self):
        with pytest.raises(ValueError, match="`score_span`"):
            detect(torch.zeros(6, 8, 8), score_span=0)
        with pytest.raises(ValueError, match="`track_combine`"):
            detect(torch.zeros(6, 8, 8), track_combine="max")

    def test_bad_choices(self):
        with pytest.raises(ValueError, match="`support`"):
            detect(torch.zeros(6, 8, 8), support="all")
        with pytest.raises(ValueError, match="`identify`"):
            detect(torch.zeros(6, 8, 8), identify="best")
        with pytest.raises(ValueError, match="`combine`"):
            detect(torch.zeros(6, 8, 8), combine="max")


_PATCH_SCRIPT = """
import resource, sys, warnings
import torch
torch.set_num_threads(1)
from hocnet.hoc import detect
n = int(sys.argv[1])
g = torch.Generator().manual_seed(0)
cube = torch.rand(10, 128, 128, generator=g) < 0.005
cube[:, 60 : 60 + n, 60 : 60 + n] = True
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    r = detect(cube, order=2)
try:  # this process's own peak: ru_maxrss survives exec, so it can be the parent's (pytest's)
    with open("/proc/self/status") as f:
        rss = next(int(l.split()[1]) for l in f if l.startswith("VmHWM:")) // 1024
except (OSError, StopIteration):
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
kept = int(r.cleaned[:, 56:76, 56:76].sum())
print(rss, int(r.saturated), kept, sum("windows" in w for w in r.warnings))
"""


class TestLocalSaturation:
    """Review finding 1: a local saturated patch passes the global density check."""

    @pytest.mark.parametrize("n", [8, 12])
    def test_patch_is_bounded_and_warned(self, n):
        # before: 8 x 8 needed more than 6 GB (killed), 12 x 12 reached 18 GB; measured after:
        # 294 MB / 0.1 s and 468 MB / 0.4 s peak RSS for the whole process
        out = subprocess.run(
            [sys.executable, "-c", _PATCH_SCRIPT, str(n)],
            capture_output=True,
            text=True,
            timeout=120,
            env={**os.environ, "OMP_NUM_THREADS": "1"},
        )
        assert out.returncode == 0, out.stderr[-2000:]
        rss_mb, saturated, kept, notes = map(int, out.stdout.split())
        assert rss_mb < 2048
        assert saturated == 1 and notes == 1
        assert kept == 0  # the patch is left out of identification

    def test_windows_against_loop(self):
        gen = torch.Generator().manual_seed(3)
        cube = torch.rand(2, 3, 20, 24, generator=gen) < 0.2
        cube[0, 1, 5:10, 6:11] = True
        v = 2
        got = identify_module._local_saturation(cube, v)
        side = 2 * v + 1
        want = torch.zeros_like(cube)
        for b, t, y, x in itertools.product(range(2), range(3), range(20), range(24)):
            win = cube[b, t, max(0, y - v) : y + v + 1, max(0, x - v) : x + v + 1]
            if int(win.sum()) > identify_module.LOCAL_SATURATION * side * side:
                want[b, t, max(0, y - v) : y + v + 1, max(0, x - v) : x + v + 1] = True
        assert want.any() and not want.all()
        assert torch.equal(got, want)

    @pytest.mark.parametrize("seed", range(3))
    def test_uniform_clutter_at_the_bound_is_not_local(self, seed):
        gen = torch.Generator().manual_seed(seed)
        cube = torch.rand(1, 10, 128, 128, generator=gen) < density_bound(
            "modified", 4, math.pi / 4
        )
        assert not identify_module._local_saturation(cube, 4).any()


class TestIdentifyTracks:
    def test_turning_track_scores_lower(self):
        s = torch.zeros(7, 20, 20, dtype=torch.bool)
        straight = [(t, 2, 2 + 2 * t) for t in range(7)]
        turning = [
            (0, 12, 2),
            (1, 12, 4),
            (2, 12, 6),
            (3, 13, 8),
            (4, 15, 9),
            (5, 17, 10),
            (6, 19, 11),
        ]
        for p in straight + turning:
            s[p] = True
        tracks, _, cleaned = identify_tracks(s, v=3)
        assert len(tracks) == 2 and torch.equal(cleaned, s)
        by_row = {int(tr.points[0, 1]): tr.score for tr in tracks}
        assert by_row[2] > by_row[12] > 2.5

    def test_min_points(self):
        s = torch.zeros(4, 8, 8, dtype=torch.bool)
        for t in range(4):
            s[t, 3, t] = True
        assert identify_tracks(s, min_points=5)[0] == []
        assert len(identify_tracks(s, min_points=4)[0]) == 1

    @pytest.mark.parametrize(
        ("kw", "match"), [({"v": 0}, "`v`"), ({"min_points": 0}, "`min_points`")]
    )
    def test_bad_arguments(self, kw, match):
        with pytest.raises(ValueError, match=match):
            identify_tracks(torch.zeros(3, 4, 4, dtype=torch.bool), **kw)


class TestBatchRecipe:
    def test_detect_equals_candidates_plus_identify(self):
        """What a streaming caller must run to equal batch ``detect`` (support="mhoc")."""
        scene = paper_scene("table3-paper", 0.014, seed=2)
        result = detect(scene.cube, order=2)
        image, cand = mhoc_candidates(scene.cube, order=2)
        tracks, scores, cleaned = identify_tracks(cand, 4, math.pi / 4, roots=image, min_points=5)
        assert torch.equal(result.support, image)
        assert torch.equal(result.cleaned, cleaned)
        assert torch.equal(result.scores.isnan(), scores.isnan())
        assert [t.points.tolist() for t in result.tracks] == [t.points.tolist() for t in tracks]


class TestRejectSlowTracks:
    def _scene(self):
        f = torch.zeros(8, 20, 20, dtype=torch.bool)
        for t in range(8):
            f[t, 3, 3] = True  # stationary clutter chain
            f[t, 4 + t, 10 + t // 2] = True  # target moving (0.5, 1) px/scan
        return f

    def test_drops_only_the_stationary_chain(self):
        found = detect(self._scene(), order=2)
        assert len(found.tracks) == 2
        moving = reject_slow_tracks(found, 0.5)
        assert len(moving.tracks) == 1
        assert int(moving.tracks[0].points[:, 1].min()) == 4
        assert not moving.cleaned[:, 3, 3].any() and int(moving.cleaned.sum()) == 8
        assert torch.equal(moving.support, found.support)
        assert len(found.tracks) == 2  # input untouched

    def test_threshold_is_the_mean_speed(self):
        found = detect(self._scene(), order=2)
        speed = (1 + 0.25) ** 0.5 * 7 / 7  # (dx, dy) = (3.5, 7) over 7 scans -> 1.118 px/scan
        assert len(reject_slow_tracks(found, speed - 0.2).tracks) == 1
        assert len(reject_slow_tracks(found, speed + 0.2).tracks) == 0
        assert len(reject_slow_tracks(found, 0.0).tracks) == 2

    def test_batched(self):
        cube = torch.stack([self._scene(), self._scene()])
        moving = reject_slow_tracks(detect(cube, order=2), 0.5)
        assert [tr.batch for tr in moving.tracks] == [0, 1]
        assert moving.cleaned.shape == cube.shape and int(moving.cleaned.sum()) == 16

    def test_bad_input(self):
        found = detect(self._scene(), order=2)
        with pytest.raises(ValueError, match="`min_speed`"):
            reject_slow_tracks(found, -1.0)
        with pytest.raises(TypeError, match="`result`"):
            reject_slow_tracks(object(), 1.0)


class TestWholeSequences:
    """The vectorised five-point sequence search against a loop over every left/right pair."""

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_against_loop(self, seed):
        g = torch.Generator().manual_seed(seed)
        cube = torch.rand(7, 16, 16, generator=g) < 0.06
        allowed = _allowed_cached(4, math.pi / 4, "cpu")
        flat, p0, p1, p2 = _sparse_triples(cube[None], allowed, 4, 1)
        assert p0.numel() > 20
        h, w = 16, 16
        coords = torch.stack([flat // (h * w), (flat // w) % h, flat % w], dim=1)
        n = flat.numel()
        s = torch.zeros(p0.numel(), dtype=torch.float64)
        a_in, a_out, *_ = _sequences(n, p0, p1, p2, s)
        kw = {"A1": 9.0, "alpha1": 1 / 3, "A2": 2.12, "alpha2": 2.0, "combine": "min"}
        left, right, key = _whole_sequences(a_in, a_out, p0, p1, p2, coords, {**kw, "span": 2})
        trip = list(zip(p0.tolist(), p1.tolist(), p2.tolist()))
        for c, (a, b, d) in enumerate(trip):
            lefts = [k for k, t in enumerate(trip) if (t[1], t[2]) == (a, b)] or [-1]
            rights = [k for k, t in enumerate(trip) if (t[0], t[1]) == (b, d)] or [-1]
            best = -math.inf
            for lk in lefts:
                for rk in rights:
                    pts = ([trip[lk][0]] if lk >= 0 else []) + [a, b, d]
                    pts += [trip[rk][2]] if rk >= 0 else []
                    sc = track_point_scores(coords[torch.tensor(pts)], span=2, **kw)
                    best = max(best, 100.0 * (len(pts) - 2) + float(sc.mean()))
            assert float(key[c]) == pytest.approx(best), c
            chosen = ([trip[int(left[c])][0]] if left[c] >= 0 else []) + [a, b, d]
            chosen += [trip[int(right[c])][2]] if right[c] >= 0 else []
            got = track_point_scores(coords[torch.tensor(chosen)], span=2, **kw).mean()
            assert 100.0 * (len(chosen) - 2) + float(got) == pytest.approx(best)


class TestSharedPoints:
    """``shared_points``: several five-point sequences per image point (section III-B)."""

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_short_track_sequences_against_loop(self, seed):
        g = torch.Generator().manual_seed(seed)
        cube = torch.rand(7, 16, 16, generator=g) < 0.06
        allowed = _allowed_cached(4, math.pi / 4, "cpu")
        flat, p0, p1, p2 = _sparse_triples(cube[None], allowed, 4, 1)
        h, w = 16, 16
        coords = torch.stack([flat // (h * w), (flat // w) % h, flat % w], dim=1)
        n = flat.numel()
        root = torch.rand(n, generator=g) < 0.7  # some points outside the "image"
        a_in, a_out, *_ = _sequences(n, p0, p1, p2, torch.zeros(p0.numel(), dtype=torch.float64))
        kw = {"A1": 9.0, "alpha1": 1 / 3, "A2": 2.12, "alpha2": 2.0, "combine": "min", "span": 2}
        rows = _whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, kw)
        got = set(_short_track_sequences(rows, p0, p1, p2, root).nonzero().squeeze(1).tolist())
        # loop reference: every (left, centre, right) sequence with all its points in the image
        # (Case 1); each triple, as the left or the right half of such sequences, keeps a
        # best-keyed one (ties: any of them)
        trip = list(zip(p0.tolist(), p1.tolist(), p2.tolist()))
        rt = root.tolist()
        best: dict[tuple[str, int], tuple[float, list[set[int]]]] = {}
        for c, (a, b, d) in enumerate(trip):
            lefts = [k for k, t in enumerate(trip) if (t[1], t[2]) == (a, b)] or [-1]
            rights = [k for k, t in enumerate(trip) if (t[0], t[1]) == (b, d)] or [-1]
            for lk in lefts:
                for rk in rights:
                    pts = ([trip[lk][0]] if lk >= 0 else []) + [a, b, d]
                    pts += [trip[rk][2]] if rk >= 0 else []
                    if not all(rt[q] for q in pts):
                        continue
                    sc = track_point_scores(coords[torch.tensor(pts)], **kw).mean()
                    key = 100.0 * (len(pts) - 2) + float(sc)
                    seq = {k for k in (lk, c, rk) if k >= 0}
                    for half in (("L", lk), ("R", rk)):
                        if half[1] < 0:
                            continue
                        old = best.get(half, (-math.inf, []))
                        if key > old[0] + 1e-9:
                            best[half] = (key, [seq])
                        elif key > old[0] - 1e-9:
                            old[1].append(seq)
        assert len(best) > 5  # the draw has Case-1 sequences
        allowed_union = set().union(*(seq for _, seqs in best.values() for seq in seqs))
        assert got <= allowed_union
        for _, seqs in best.values():  # each half's best sequence is kept whole
            assert any(seq <= got for seq in seqs)

    def test_swapping_crossing_found_only_with_shared_points(self):
        # two tracks that swap pixels at scans 4-5 (scene 91 of the hard case, no clutter):
        # each crossing point's single best sequence switches tracks
        cube, truth = _hard_scene(HARD_SCENES[91][:2], 91, density=0.0)
        one = detect(cube, order=2, shared_points=False)
        both = detect(cube, order=2)
        assert torch.equal(both.cleaned, truth)
        true_tracks = {tuple(map(tuple, pts)) for pts in HARD_SCENES[91][:2]}
        found = {tuple((y, x) for _, y, x in tr.points.tolist()) for tr in both.tracks}
        assert true_tracks <= found
        assert not true_tracks <= {
            tuple((y, x) for _, y, x in tr.points.tolist()) for tr in one.tracks
        }

    def test_explained_points_do_not_count_as_differences(self):
        # K1: (t, t, 2t) for t = 0-4; K2 shares nothing with K1 but scan 1's point (2 px off)
        xy = [[t, t, 2 * t] for t in range(5)] + [[1, 3, 2], [2, 4, 4]]
        scan_of = [p[0] for p in xy]
        k1 = [0, 1, 2, 3, 4]
        kept = [(k1, {scan_of[q]: i for i, q in enumerate(k1)})]
        cand = [0, 5, 6, 3, 4]  # K1 with two points of another kept track (5) and a detour (6)
        image = [True] * 7
        covered = {0, 1, 2, 3, 4, 5}  # point 5 lies on another kept track
        assert not _is_near_duplicate(cand, kept, scan_of, image, xy, 1, covered)
        assert _is_near_duplicate(cand, kept, scan_of, image, xy, 1, covered, explained=True)


def _partial_scene(seed, n_t=10, size=60, density=0.014, eligible=False):
    """Three straight tracks at 1-3 px/scan, each starting at a random scan 0-4, plus clutter.

    The scene of the review scripts (``scene(seed, partial=True)``): tracks from
    ``random.Random(seed)``, clutter from ``torch.Generator().manual_seed(seed)``. With
    ``eligible``, also the mask of the points of the tracks the detector's criterion admits
    (:func:`_turn_ok`).
    """
    gen = torch.Generator().manual_seed(seed)
    cube = torch.rand(n_t, size, size, generator=gen) < density
    truth = torch.zeros_like(cube)
    admitted = torch.zeros_like(cube)
    rng = random.Random(seed)
    for _ in range(3):
        speed = rng.uniform(1, 3)
        angle = rng.uniform(-math.pi, math.pi)
        t0 = rng.randint(0, 4)
        x0 = 30 - 4.5 * speed * math.cos(angle) + rng.uniform(-3, 3)
        y0 = 30 - 4.5 * speed * math.sin(angle) + rng.uniform(-3, 3)
        pts = []
        for t in range(t0, n_t):
            y = round(y0 + t * speed * math.sin(angle))
            x = round(x0 + t * speed * math.cos(angle))
            if 0 <= y < size and 0 <= x < size:
                truth[t, y, x] = True
                pts.append((t, y, x))
        if _turn_ok(pts):
            for p in pts:
                admitted[p] = True
    if eligible:
        return cube | truth, truth, admitted
    return cube | truth, truth


class TestTrackEnds:
    """Step 5 of the module notes (the track-ends step, ``track_ends``)."""

    def test_track_of_its_own_is_kept(self, monkeypatch):
        # review finding 1: a track starting at scan 3 whose maximal chain clutter extends
        # backwards scores 2.48 as a chain; its best sub-track (2.83) shares no point with an
        # accepted track and was dropped: all 7 of its points lost
        cube, truth = _partial_scene(6)
        monkeypatch.setattr(identify_module, "RESCUE_ALONE", False)
        assert int((truth & ~detect(cube).cleaned).sum()) == 7
        monkeypatch.undo()
        assert not (truth & ~detect(cube).cleaned).any()

    def test_track_ends_off(self):
        # ``track_ends=False`` skips the step: the track above is lost again, and the literal
        # configuration runs (no addition of ours)
        cube, truth = _partial_scene(6)
        assert int((truth & ~detect(cube, track_ends=False).cleaned).sum()) == 7
        literal = {"score_span": 1, "shared_points": False, "dedupe": False, "track_ends": False}
        result = detect(cube, **literal)  # its own sequences: this track survives (measured)
        assert not (truth & ~result.cleaned).any()
        _, _, cleaned = identify_tracks(result.support, roots=result.support, **literal)
        assert torch.equal(cleaned, result.cleaned)


class TestSplitBranchFig5:
    """The splitting branch of the paper's Fig. 5 scene in window 5-14 (measured by hoc-fig5).

    The cause was the candidate cap, not the shared points themselves: with shared points the
    window has 830 556 maximal chains (2 501 with one sequence per point), 763 169 of them in
    the ten largest clusters of stationary clutter, whose zero-move chains score best; the
    depth-first enumeration spent the cap (20 000) on them before it reached the branch's small
    cluster, so the branch's chain (parent track, then the branch's own point after the split)
    was never a candidate and a mixed candidate starting on the parent's next point was kept
    instead (11 points in 10 of 20 seeds at 1 % clutter, window 5-14). The cap is now spent on
    the clusters with the fewest chains first (``identify._enumerate_paths``).
    """

    def _window(self):
        scene = paper_scene("fig5-paper", 0.01, seed=5001)
        return scene.cube[4:14], scene.target_mask[4:14]

    def test_one_sequence_per_point_keeps_the_branch(self):
        cube, truth = self._window()
        result = detect(cube, order=2, shared_points=False)
        assert not (truth & ~result.cleaned).any()

    def test_default_keeps_the_branch(self):
        cube, truth = self._window()
        with pytest.warns(RuntimeWarning, match="candidate tracks"):
            result = detect(cube, order=2)
        assert result.saturated  # the cap is hit: the clustered enumeration decides
        assert not (truth & ~result.cleaned).any()


def _chains_reference(accepted, a_in, a_out):
    """Every maximal chain of accepted triples (depth first, no cap) and its cluster.

    Clusters by union-find over the edges each accepted triple joins (a loop reading of
    ``identify._chain_clusters``), numbered by their first triple.
    """
    idx = accepted.nonzero().squeeze(1).tolist()
    ain, aout = a_in.tolist(), a_out.tolist()
    parent: dict[int, int] = {}

    def find(e):
        while parent.setdefault(e, e) != e:
            e = parent[e]
        return e

    for k in idx:
        parent[find(ain[k])] = find(aout[k])
    label: dict[int, int] = {}
    for k in idx:
        label.setdefault(find(ain[k]), len(label))
    ends = {aout[k] for k in idx}
    chains = []
    stack = [[k] for k in idx if ain[k] not in ends]
    while stack:
        path = stack.pop()
        nxt = [k for k in idx if ain[k] == aout[path[-1]]]
        if not nxt:
            chains.append(path)
        stack.extend([*path, k] for k in nxt)
    return [(label[find(ain[path[0]])], path) for path in chains]


class TestCandidateCap:
    """``max_candidates``: at the cap the clusters with the fewest chains are enumerated whole."""

    @staticmethod
    def _dag(seed):
        gen = torch.Generator().manual_seed(seed)
        k = int(torch.randint(10, 70, (1,), generator=gen))
        a_in = torch.randint(0, 40, (k,), generator=gen)
        a_out = a_in + torch.randint(1, 4, (k,), generator=gen)  # edge ids grow: a DAG
        s = torch.randint(0, 4, (k,), generator=gen).double() / 2
        accepted = torch.rand(k, generator=gen) < 0.8
        return accepted, a_in, a_out, s

    @pytest.mark.parametrize("seed", range(20))
    def test_chain_clusters_against_loop(self, seed):
        accepted, a_in, a_out, _ = self._dag(seed)
        cluster, count = identify_module._chain_clusters(accepted, a_in, a_out)
        ref = _chains_reference(accepted, a_in, a_out)
        idx = accepted.nonzero().squeeze(1).tolist()
        for label, path in ref:
            assert all(int(cluster[idx.index(k)]) == label for k in path)
        want = [0.0] * count.numel()
        for label, _ in ref:
            want[label] += 1
        assert count.tolist() == want

    @staticmethod
    def _check_capped(accepted, a_in, a_out, s, cap, cluster_of, n_starts):
        """The claims of ``_enumerate_paths``' docstring at the cap, against the uncapped loop.

        ``cluster_of``: per accepted triple index, its cluster label (any numbering).
        """
        ref = identify_module._enumerate_paths_loop(accepted, a_in, a_out, s, 10**9)[0]
        assert len(ref) >= cap  # really at the cap
        got, capped = identify_module._enumerate_paths(accepted, a_in, a_out, s, cap)
        assert capped
        count: dict[int, int] = {}
        for path in ref:
            count[cluster_of[path[0]]] = count.get(cluster_of[path[0]], 0) + 1
        budget, whole = 0, set()
        for c in sorted(
            count, key=lambda c: (count[c], min(k for k in cluster_of if cluster_of[k] == c))
        ):
            if budget + count[c] >= cap:
                break
            budget += count[c]
            whole.add(c)
        every = {tuple(path) for path in ref}
        assert all(tuple(path) in every for path in got)  # maximal chains only
        assert len({tuple(path) for path in got}) == len(got)  # each chain once
        # the whole clusters' chains first, all of them, in the order of the uncapped
        # enumeration; then the other clusters' only
        head = [path for path in ref if cluster_of[path[0]] in whole]
        assert got[:budget] == head
        assert all(cluster_of[path[0]] not in whole for path in got[budget:])
        # bounded: fewer than ``cap`` chains of whole clusters, at most the rest of the budget
        # ``b`` in full from the loop, plus one best continuation per open chain of the loop
        # (at most ``max(starts, b + largest fan-out)``)
        idx = accepted.nonzero().squeeze(1)
        fan = int(torch.bincount(a_in[idx]).max())
        rest = max(1, cap - budget)
        assert len(got) <= budget + rest + max(n_starts, rest + fan)
        return whole, count

    @staticmethod
    def _starts(accepted, a_in, a_out):
        idx = accepted.nonzero().squeeze(1)
        return int((~torch.isin(a_in[idx], a_out[idx])).sum())

    @pytest.mark.parametrize("cap", [2, 10, 40])
    def test_small_clusters_are_enumerated_whole(self, cap):
        # only seeds whose DAG really has ``cap`` chains or more (the uncapped form otherwise)
        hit = split = 0
        for seed in range(200):
            accepted, a_in, a_out, s = self._dag(seed)
            ref = _chains_reference(accepted, a_in, a_out)
            if len(ref) < cap:
                continue
            cluster, _ = identify_module._chain_clusters(accepted, a_in, a_out)
            idx = accepted.nonzero().squeeze(1).tolist()
            cluster_of = dict(zip(idx, cluster.tolist(), strict=True))
            starts = self._starts(accepted, a_in, a_out)
            whole, count = self._check_capped(accepted, a_in, a_out, s, cap, cluster_of, starts)
            split += bool(whole) and len(whole) < len(count)  # whole clusters and the loop's
            hit += 1
            if hit == 15:
                break
        assert hit == 15 and split >= 10  # measured: 13 / 14 / 14 of 15 (cap 2 / 10 / 40)

    def test_giant_plus_many_small_clusters(self):
        # the review's case (dag.py "smallmany", smaller): 60 clusters of 32 chains each and
        # one giant cluster of 120 * 4^5 = 122 880 chains; at a cap of 2 000 every small
        # cluster is enumerated whole (1 920 chains), the giant follows best continuations
        gen = torch.Generator().manual_seed(0)
        ins, outs, labels = [], [], []

        def layered(n_layers, width, fan, base, label):
            for layer in range(n_layers - 1):
                src = torch.arange(width).repeat_interleave(fan)
                dst = (src + torch.arange(fan).repeat(width) + 1) % width  # distinct successors
                ins.append(base + layer * width + src)
                outs.append(base + (layer + 1) * width + dst)
                labels.append(torch.full((width * fan,), label))

        for c in range(60):
            layered(5, 2, 2, base=c * 10, label=c)
        layered(7, 30, 4, base=1000, label=60)
        a_in, a_out, label = torch.cat(ins), torch.cat(outs), torch.cat(labels)
        s = torch.rand(a_in.numel(), generator=gen).double()
        accepted = torch.ones(a_in.numel(), dtype=torch.bool)
        cluster_of = dict(enumerate(label.tolist()))
        starts = self._starts(accepted, a_in, a_out)
        t0 = time.perf_counter()
        whole, count = self._check_capped(accepted, a_in, a_out, s, 2000, cluster_of, starts)
        assert whole == set(range(60)) and count[60] == 120 * 4**5
        assert time.perf_counter() - t0 < 60


def _turn_ok(pts, v=4, delta=math.pi / 4):
    """Whether a track meets the detector's criterion: one point per scan, moves within ``v``,
    turns within ``delta`` (eq. 6), at least five points."""
    moves = [(b[2] - a[2], b[1] - a[1]) for a, b in itertools.pairwise(pts)]
    return (
        len(pts) >= 5
        and all(b[0] - a[0] == 1 for a, b in itertools.pairwise(pts))
        and all(max(abs(i), abs(j)) <= v for i, j in moves)
        and all(turn_reference(*m1, *m2) <= delta + 1e-9 for m1, m2 in itertools.pairwise(moves))
    )


def partial_track_scene(seed, ends=True, n_t=10, size=60, density=0.014):
    """Three straight tracks at 1-3 px/scan in any direction, each from a random scan 0-4 to a
    random scan at least four later (``ends``; else to the last scan), passing near the
    centre, plus uniform clutter (the measurements of ``RESCUE_SHORT``).

    Returns ``(cube, truth, eligible)``: ``eligible`` holds the points of the tracks that meet
    the detector's own criterion (:func:`_turn_ok`: >= 5 points, moves within ``v``, turns
    within ``delta``; integer positions of a slow track can turn by 90 degrees).
    """
    gen = torch.Generator().manual_seed(seed)
    cube = torch.rand(n_t, size, size, generator=gen) < density
    truth = torch.zeros_like(cube)
    eligible = torch.zeros_like(cube)
    rng = random.Random(seed)
    for _ in range(3):
        speed = rng.uniform(1, 3)
        angle = rng.uniform(-math.pi, math.pi)
        t0 = rng.randint(0, 4)
        t1 = rng.randint(t0 + 4, n_t - 1) if ends else n_t - 1
        x0 = 30 - 4.5 * speed * math.cos(angle) + rng.uniform(-3, 3)
        y0 = 30 - 4.5 * speed * math.sin(angle) + rng.uniform(-3, 3)
        pts = [
            p
            for p in _straight_track(x0, y0, speed, angle, n_t)[t0 : t1 + 1]
            if 0 <= p[1] < size and 0 <= p[2] < size
        ]
        for p in pts:
            truth[p] = True
            if _turn_ok(pts):
                eligible[p] = True
    return cube | truth, truth, eligible


class TestPartialTracks:
    """Issue 7: tracks that start late (or end early), passing close to each other.

    The wanted property (``_partial_scene``, tracks starting at scans 0-4): no point of a track
    the detector's criterion admits (>= 5 points, moves within ``v``, turns within ``delta``)
    is lost after identification with the defaults. It held on the review's 60 scenes (seeds
    0-59), but ``GUARD_MIXED`` and ``RESCUE_BRANCH`` were built on those seeds (before them 3
    points in scenes 9 and 49 were lost): 9 and 49 stay as regression tests, and fresh seeds
    are counted against the measured bound (``test_fresh_seeds_lost_points``): the property
    does not hold out of sample yet (issue 7).
    Not yet a property of every such scene (measured, module notes of ``hocnet.hoc.identify``,
    ``RESCUE_SHORT``): on 200 fresh scenes of the same kind (``partial_track_scene(seed,
    ends=False)``, seeds 0-199) 8 points in 6 scenes are still lost (20 in 12, then 15 in 8
    before ``RESCUE_END`` and ``ALONE_EXTEND``), and with early ends too (``ends=True``) 182 in
    45 (217 in 57, then 209 in 55), 100 of them on tracks of exactly 2k + 1 = 5 points
    (:class:`TestFig5ExactPieces`).
    """

    @pytest.mark.parametrize("seed", [9, 49])
    def test_no_eligible_point_lost(self, seed):
        # regression: the two scenes ``GUARD_MIXED`` and ``RESCUE_BRANCH`` were built on
        cube, _, eligible = _partial_scene(seed, eligible=True)
        result = detect(cube)
        assert not (eligible & ~result.cleaned).any(), (eligible & ~result.cleaned).nonzero()

    def test_fresh_seeds_lost_points(self):
        # NOT the property (issue 7, open): on 40 fresh seeds (2000-2039, not used to build
        # any rule) the defaults lose eligible points; measured 2 points in 2 scenes (2017: 1,
        # 2026: 1; 5 in 3 before ``RESCUE_END``, which keeps scene 2008's 3). The bound
        # catches a regression; lower it when a fix lands.
        lost = []
        for seed in range(2000, 2040):
            cube, _, eligible = _partial_scene(seed, eligible=True)
            lost.append(int((eligible & ~detect(cube).cleaned).sum()))
        assert sum(lost) <= 2, lost
        assert sum(n > 0 for n in lost) <= 2, lost

    def test_branch_rules(self):
        root = [True] * 6
        assert identify_module._is_branch([0, 1, 2, 3, 4], [3, 4], root)  # leaves at the end
        assert identify_module._is_branch([0, 1, 2, 3, 4], [0, 1], root)  # joins at the start
        assert not identify_module._is_branch([0, 1, 2, 3, 4], [2, 3], root)  # a detour
        assert not identify_module._is_branch([0, 1, 2, 3, 4], [4], root)  # one new point
        root[4] = False
        assert not identify_module._is_branch([0, 1, 2, 3, 4], [3, 4], root)  # not an image point
        on = {1: [0], 2: [0, 1], 3: [1]}  # point -> accepted tracks through it
        assert identify_module._one_track_holds([1, 2, 9], on)
        assert not identify_module._one_track_holds([1, 3, 9], on)  # on two different tracks
        assert not identify_module._one_track_holds([9], on)

    def test_short_track_rescue(self, monkeypatch):
        # ``RESCUE_SHORT`` (off by default): a 5-point track at scans 1-5 crossing two others,
        # only its end points in the image; its best whole track (2.56 on one-scan scores)
        # shares no point with an accepted track and is kept only with the option
        cube, _, eligible = partial_track_scene(16)
        lost = [[1, 40, 28], [2, 38, 28], [3, 35, 29], [4, 33, 29], [5, 31, 29]]
        assert (eligible & ~detect(cube).cleaned).nonzero().tolist() == lost
        monkeypatch.setattr(identify_module, "RESCUE_SHORT", True)
        assert not (eligible & ~detect(cube).cleaned).any()

    def test_mixed_candidate_guard(self, monkeypatch):
        # review scene(9, partial=True): two tracks one pixel apart at scans 5-6; the true
        # track (its start on kept mixed tracks) differed from a kept mixed track at scan 6 only
        # and lost there by 0.68 px: dropped as its near-duplicate, (6, 30, 30) lost
        cube, truth = _partial_scene(9)
        monkeypatch.setattr(identify_module, "GUARD_MIXED", False)
        assert (truth & ~detect(cube).cleaned).nonzero().tolist() == [[6, 30, 30]]
        monkeypatch.undo()
        assert not (truth & ~detect(cube).cleaned)[6, 30, 30]

    def test_branch_end_is_kept(self, monkeypatch):
        # review scene(49, partial=True): a 6-point track from scan 4 whose first four points
        # lie on kept tracks (mixed with its neighbours); its last two points were lost
        cube, truth = _partial_scene(49)
        lost = [[8, 29, 37], [9, 30, 39]]
        monkeypatch.setattr(identify_module, "RESCUE_BRANCH", False)
        got = (truth & ~detect(cube).cleaned).nonzero().tolist()
        assert all(p in got for p in lost)
        monkeypatch.undo()
        got = (truth & ~detect(cube).cleaned).nonzero().tolist()
        assert not any(p in got for p in lost)


class TestUncoveredScans:
    """Issue 7 audit: the MHOC image of T scans at order k covers every scan iff T >= 4k."""

    @pytest.mark.parametrize("order", [1, 2, 3, 4])
    def test_condition_against_the_image(self, order):
        # a clean straight track through every scan: the scans the MHOC image marks
        for n_t in range(2 * order + 1, 4 * order + 3):
            f = torch.zeros(n_t, 8, 4 * n_t + 4, dtype=torch.bool)
            for t in range(n_t):
                f[t, 4, 2 + 3 * t] = True
            image, _ = mhoc_candidates(f, order=order)
            marked = set(image.flatten(1).any(dim=1).nonzero().squeeze(1).tolist())
            missing = sorted(set(range(n_t)) - marked)
            assert missing == identify_module._uncovered_scans(n_t, order), (order, n_t)
            assert (not missing) == (n_t >= 4 * order)

    def test_detect_warns_and_names_the_chain_support(self):
        cube = torch.zeros(10, 20, 20, dtype=torch.bool)
        with pytest.warns(UserWarning, match=r"T < 4k.*scans 4-5.*support='chain'"):
            detect(cube, order=3)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            detect(cube, order=2)  # 10 >= 4 * 2: covered
            detect(cube, order=3, support="chain")  # the remedy: no warning
        # no chain fits at all: not the uncovered-scan warning, the order one
        with pytest.warns(UserWarning, match=r"`order`") as said:
            detect(cube[:4], order=2)
        assert not any("cannot cover" in str(w.message) for w in said)

    def test_order_three_loses_the_gap_only_with_the_image(self):
        # a lone straight track over 10 scans: order 3's MHOC image misses scans 4-5 (0-based)
        cube = torch.zeros(10, 12, 40, dtype=torch.bool)
        for t in range(10):
            cube[t, 5, 3 + 3 * t] = True
        with pytest.warns(UserWarning):
            image = detect(cube, order=3).support
        assert (cube & ~image).nonzero()[:, 0].unique().tolist() == [4, 5]
        assert not (cube & ~detect(cube, order=3, support="chain").support).any()


HARD_SCENE_76 = [
    # scene 76 of 600 fresh scenes drawn like ``hard_case`` (issue 7 audit: tracks from
    # random.Random(20000 + s), clutter seed 70000 + s): (y, x) at scans 0-9
    [
        (36, 38),
        (35, 36),
        (34, 34),
        (32, 32),
        (31, 31),
        (30, 29),
        (29, 27),
        (28, 25),
        (27, 24),
        (25, 22),
    ],
    [
        (31, 23),
        (30, 25),
        (30, 26),
        (30, 28),
        (29, 29),
        (29, 31),
        (28, 32),
        (28, 34),
        (28, 36),
        (27, 37),
    ],
    [
        (35, 36),
        (34, 35),
        (33, 34),
        (32, 33),
        (31, 32),
        (30, 31),
        (29, 30),
        (29, 28),
        (28, 27),
        (27, 26),
    ],
]


class TestHardCaseScene76:
    """The one point lost in 600 fresh hard-case scenes (issue 7 audit) by the earlier default.

    Measured cause: the true track's first point (0, 31, 23) and a clutter point (0, 30, 24)
    one pixel away are both MHOC image points, so ``dedupe`` compares the true track with the
    better-scoring track that starts at the clutter point and shares all other points. At a
    track end ``residual="two-point"`` (the earlier default) extrapolates from the two nearest
    shared points (scans 1-2, whose one-scan move (0, 1) is one phase of the alternating moves
    of a track moving (-0.44, 1.56) px/scan in (y, x)): it predicts (30, 24) exactly, residual
    0 against 1.41 px for the true point, so the true track is dropped as the clutter track's
    near-duplicate. ``dedupe=False`` loses nothing. The default ``"two-point+straight"`` drops a
    candidate only when the kept point also wins with the mean move of the straight run of
    shared points (scans 1-9 here: 0.62 against 0.80 px, within the half-pixel margin), so
    both tracks are kept. ``"lsq"`` (the least-squares line through all shared points on that
    side) keeps it too, but loses target points two-point keeps on partial-track scenes
    (:meth:`test_lsq_loses_partial_scene_18`); ``"straight"`` alone loses some too
    (:meth:`test_straight_alone_loses_partial_track_scene_89`, shown with ``RESCUE_END`` off,
    which now re-adds that point; :meth:`test_straight_alone_loses_a_track_partial_scene_94`
    with every rule on; module notes of ``hocnet.hoc.identify``, step 4).
    """

    def test_no_target_point_lost(self):
        cube, truth = _hard_scene(HARD_SCENE_76, 70076)
        assert not (truth & ~detect(cube, order=2).cleaned).any()

    @pytest.mark.parametrize("residual", ["two-point+straight", "straight", "lsq", "both"])
    def test_no_target_point_lost_with(self, residual):
        # regression: every end prediction over more than one move keeps the true track (alone,
        # or required to agree with the two-point one before a track is dropped)
        cube, truth = _hard_scene(HARD_SCENE_76, 70076)
        assert not (truth & ~detect(cube, order=2, residual=residual).cleaned).any()

    def test_two_point_loses_it(self):
        # the earlier default, kept as an option: its measured failure
        cube, truth = _hard_scene(HARD_SCENE_76, 70076)
        lost = (truth & ~detect(cube, order=2, residual="two-point").cleaned).nonzero().tolist()
        assert lost == [[0, 31, 23]]
        assert not (truth & ~detect(cube, order=2, dedupe=False).cleaned).any()

    def test_cause(self):
        cube, truth = _hard_scene(HARD_SCENE_76, 70076)
        image, _ = mhoc_candidates(cube, order=2)
        assert image[0, 31, 23] and image[0, 30, 24] and not truth[0, 30, 24]
        true_track = [(t, *yx) for t, yx in enumerate(HARD_SCENE_76[1])]
        xy = {i: p for i, p in enumerate(true_track)}
        xy[10] = (0, 30, 24)  # the clutter start
        true_ids, kept_ids = list(range(10)), [10, *range(1, 10)]
        residual = identify_module._residual
        assert residual(kept_ids, 0, set(true_ids), xy) == 0.0
        assert residual(true_ids, 0, set(kept_ids), xy) == pytest.approx(math.sqrt(2))
        assert identify_module.RESIDUAL_MARGIN < math.sqrt(2)
        # least squares, or the mean move of the straight run (scans 1-9: every one-scan move
        # is (0, 1), (0, 2) or (-1, 1)), over the shared scans: the clutter point no longer
        # wins by the margin
        run = identify_module._straight_run(true_ids, list(range(1, 10)), xy)
        assert run == list(range(1, 10))
        for mode in ("lsq", "straight"):
            kept = residual(kept_ids, 0, set(true_ids), xy, mode)
            true = residual(true_ids, 0, set(kept_ids), xy, mode)
            assert not kept < true - identify_module.RESIDUAL_MARGIN
        assert residual(kept_ids, 0, set(true_ids), xy, "straight") == pytest.approx(0.625)
        assert residual(true_ids, 0, set(kept_ids), xy, "straight") == pytest.approx(
            math.hypot(0.625, 0.5)
        )

    def test_lsq_loses_partial_scene_18(self):
        # why "lsq" is not the default: review ``scene(18, partial=True)``, a 5-point candidate
        # whose first two points are clutter before a track starting at scan 2 and whose last
        # point (4, 32, 28) is another track's; fitted to all four shared points (two of them
        # clutter), the line predicts (4, 32, 28) better than the kept track's (4, 31, 30)
        # (0.71 against 2.55 px; two-point 2.24 against 1.41), the candidate is kept, and the
        # track starting at scan 2 through (4, 32, 28) loses three points. The straight run
        # stops at the clutter point (moves (1, 0) then (3, -2)), so ``"straight"`` is the
        # two-point prediction here and keeps them, alone and in the default
        cube, _, eligible = _partial_scene(18, eligible=True)
        for residual in ("two-point", "straight", "two-point+straight"):
            assert not (eligible & ~detect(cube, residual=residual).cleaned).any()
        assert not (eligible & ~detect(cube).cleaned).any()
        for residual in ("lsq", "both"):
            lost = (eligible & ~detect(cube, residual=residual).cleaned).nonzero().tolist()
            assert lost == [[2, 30, 27], [3, 31, 27], [5, 33, 29]]

    def test_straight_alone_loses_partial_track_scene_89(self, monkeypatch):
        # why the default asks two-point too: in ``partial_track_scene(89, ends=False)`` a
        # candidate starts with a track's first point (3, 31, 26) and continues on another
        # track; the straight run predicts the kept track's (3, 32, 27) better (0.45 against
        # 1.00 px; two-point 1.0 against 1.0, a tie), so ``"straight"`` (and ``"lsq"``) drop it
        # as a near-duplicate (``dedupe=False`` keeps it), and with it the only kept track
        # through (3, 31, 26). Shown with ``RESCUE_END`` (step 5) off: since that rule, the
        # true track from (3, 31, 26) (score 2.80) is re-added in the track-ends step as a
        # track whose own start point scores above the accepted tracks it shares points with,
        # so no setting loses the point any more
        cube, _, eligible = partial_track_scene(89, ends=False)
        monkeypatch.setattr(identify_module, "RESCUE_END", False)
        for residual in ("straight", "lsq"):
            assert _lost(cube, eligible, residual=residual) == [[3, 31, 26]]
            assert _lost(cube, eligible, residual=residual, dedupe=False) == []
        for residual in ("two-point", "two-point+straight", "both"):
            assert _lost(cube, eligible, residual=residual) == []
        monkeypatch.undo()
        for residual in identify_module.RESIDUAL:
            assert _lost(cube, eligible, residual=residual) == []
        tracks = detect(cube, residual="straight").tracks
        tracks = [t for t in tracks if [3, 31, 26] in t.points.tolist()]
        assert [t.points.tolist() for t in tracks] == [
            [
                [3, 31, 26],
                [4, 32, 27],
                [5, 32, 28],
                [6, 33, 29],
                [7, 34, 30],
                [8, 35, 31],
                [9, 35, 32],
            ]
        ]
        assert tracks[0].score == pytest.approx(2.8)

    def test_straight_alone_loses_a_track_partial_scene_94(self):
        # the same tie under the merged rules (``RESCUE_END`` and ``ALONE_EXTEND`` on, measured
        # by task h7combo): in ``partial_track_scene(94, ends=True)`` a candidate starts with
        # the first point (3, 30, 34) of a 6-point track and continues on another track; the
        # kept track starts at (3, 32, 35). Two-point: 1.00 against 1.41 px, within the margin,
        # both kept; the straight run: 0.60 against 1.72 px, the candidate is dropped, and the
        # whole 6-point track is lost with ``"straight"`` (and ``"lsq"``); ``dedupe=False``
        # and every setting that asks two-point keep it
        cube, _, eligible = partial_track_scene(94, ends=True)
        track = [[3, 30, 34], [4, 30, 33], [5, 30, 32], [6, 30, 31], [7, 30, 30], [8, 29, 29]]
        for residual in ("straight", "lsq"):
            assert _lost(cube, eligible, residual=residual) == track
        assert _lost(cube, eligible, residual="straight", dedupe=False) == []
        for residual in ("two-point", "two-point+straight", "both"):
            assert _lost(cube, eligible, residual=residual) == []


class TestResidual:
    """``_residual`` (the position prediction of ``dedupe``) against plain references."""

    @pytest.mark.parametrize("seed", range(20))
    def test_lsq_against_polyfit(self, seed):
        np = pytest.importorskip("numpy")
        rng = random.Random(seed)
        n = rng.randrange(4, 10)
        xy = [[t, rng.randrange(60), rng.randrange(60)] for t in range(n)]
        pts = list(range(n))
        end = rng.choice([0, n - 1])
        shared = {q for q in pts if q != end and rng.random() < 0.8}
        got = identify_module._residual(pts, end, shared, xy, "lsq")
        if len(shared) < 2:
            assert got == math.inf
            return
        t = np.array([xy[q][0] for q in sorted(shared)], dtype=float)
        want = [
            np.polyval(np.polyfit(t, [xy[q][k] for q in sorted(shared)], 1), xy[end][0])
            for k in (1, 2)
        ]
        assert got == pytest.approx(
            math.hypot(xy[end][1] - want[0], xy[end][2] - want[1]), abs=1e-9
        )

    def test_interpolation_is_the_same_for_both(self):
        rng = random.Random(1)
        for _ in range(50):
            xy = [[t, rng.randrange(60), rng.randrange(60)] for t in range(8)]
            i = rng.randrange(1, 7)
            shared = {rng.randrange(0, i), rng.randrange(i + 1, 8), rng.randrange(8)} - {i}
            a = identify_module._residual(list(range(8)), i, shared, xy)
            for mode in ("lsq", "straight"):
                assert identify_module._residual(list(range(8)), i, shared, xy, mode) == a

    def test_two_shared_points_give_the_same_line(self):
        xy = [[t, 3 * t, 40 - 2 * t] for t in range(6)] + [[5, 14, 31]]
        pts = [0, 1, 2, 3, 4, 6]
        for mode in ("two-point", "lsq", "straight"):
            assert identify_module._residual(pts, 5, {3, 4}, xy, mode) == pytest.approx(
                math.hypot(1, 1)
            )

    @pytest.mark.parametrize("seed", range(30))
    def test_straight_against_reference(self, seed):
        # plain reference: the longest run of shared points on consecutive scans from the
        # nearest one (any two nearest at least) whose one-scan moves stay within 1 px of each
        # other per coordinate; the end predicted from the nearest point plus the mean of the
        # run's one-scan moves times the scans to the end
        rng = random.Random(seed)
        n = rng.randrange(3, 10)
        vy, vx = rng.uniform(-3, 3), rng.uniform(-3, 3)
        xy = [
            [
                t,
                round(30 + vy * t + (rng.choice([-2, -1, 1, 2]) if rng.random() < 0.25 else 0)),
                round(30 + vx * t),
            ]
            for t in range(n)
        ]
        pts = list(range(n))
        end = rng.choice([0, n - 1])
        shared = {q for q in pts if q != end and rng.random() < 0.85}
        got = identify_module._residual(pts, end, shared, xy, "straight")
        side = sorted(shared, key=lambda q: abs(q - end))
        if len(side) < 2:
            assert got == math.inf
            return
        best = 2
        for m in range(3, len(side) + 1):
            run = side[:m]
            consecutive = all(abs(a - b) == 1 for a, b in itertools.pairwise(run))
            moves = [(xy[b][1] - xy[a][1], xy[b][2] - xy[a][2]) for a, b in itertools.pairwise(run)]
            spread = max(max(mv[k] for mv in moves) - min(mv[k] for mv in moves) for k in (0, 1))
            if consecutive and spread <= 1:
                best = m
            else:
                break
        run = side[:best]
        steps = [xy[b][0] - xy[a][0] for a, b in itertools.pairwise(run)]
        mean_y = sum(xy[b][1] - xy[a][1] for a, b in itertools.pairwise(run)) / sum(steps)
        mean_x = sum(xy[b][2] - xy[a][2] for a, b in itertools.pairwise(run)) / sum(steps)
        dt = xy[run[0]][0] - xy[end][0]  # scans from the end to the nearest shared point
        want_y, want_x = xy[run[0]][1] - mean_y * dt, xy[run[0]][2] - mean_x * dt
        assert got == pytest.approx(math.hypot(xy[end][1] - want_y, xy[end][2] - want_x))

    def test_straight_run_stops_at_a_gap_or_a_bend(self):
        xy = [[t, 2 * t, t + t // 2] for t in range(6)]  # moves (2, 1) / (2, 2) alternate
        run = identify_module._straight_run
        assert run(list(range(6)), [1, 2, 3, 4, 5], xy) == [1, 2, 3, 4, 5]
        assert run(list(range(6)), [1, 2, 4, 5], xy) == [1, 2]  # scan 3 not shared
        assert run(list(range(6)), [1, 3, 4, 5], xy) == [1, 3]  # the two nearest, not adjacent
        xy[4] = [4, 11, 6]  # a bend: the move 3 -> 4 is (5, 2)
        assert run(list(range(6)), [1, 2, 3, 4, 5], xy) == [1, 2, 3]

    @pytest.mark.parametrize("seed", range(10))
    def test_combined_choices_need_every_mode(self, seed):
        # ``"both"`` / ``"two-point+straight"``: the kept point must win under each mode
        rng = random.Random(seed)
        wins = identify_module._kept_point_wins
        for _ in range(40):
            n = rng.randrange(4, 9)
            xy = {q: [q, rng.randrange(6), rng.randrange(6)] for q in range(n)}
            xy[n] = [n - 1, rng.randrange(6), rng.randrange(6)]  # K's own end point
            pts, k_pts = list(range(n)), [*range(n - 1), n]
            args = (pts, n - 1, k_pts, {t: t for t in range(n)}, set(k_pts), set(pts))
            rest = ([xy[q][0] for q in range(n + 1)], [True] * (n + 1), xy)
            for combined, modes in (
                ("both", ("two-point", "lsq")),
                ("two-point+straight", ("two-point", "straight")),
            ):
                want = all(wins(*args, *rest, mode) for mode in modes)
                assert wins(*args, *rest, combined) == want

    def test_bad_choice(self):
        cube = torch.zeros(6, 8, 8, dtype=torch.bool)
        with pytest.raises(ValueError, match="residual"):
            detect(cube, residual="cubic")
        with pytest.raises(ValueError, match="residual"):
            identify_tracks(cube, residual="cubic")


class TestTable3GapReadings:
    """Opt-in readings of section III-B measured by ``experiments/hoc_table3_gap.py``.

    ``own_points``, ``near_duplicate``, ``dedupe_rescued``, ``case1`` and ``score_points``: each
    off by default (the results bit-identical to before), each checked here against a plain
    reading of what it promises.
    """

    OFF: typing.ClassVar[dict] = {
        "own_points": 1,
        "near_duplicate": "support",
        "dedupe_rescued": False,
        "case1": False,
        "score_points": "interior",
    }

    @staticmethod
    def _same(a, b):
        assert torch.equal(a.cleaned, b.cleaned)
        assert [tr.points.tolist() for tr in a.tracks] == [tr.points.tolist() for tr in b.tracks]
        assert [tr.score for tr in a.tracks] == [tr.score for tr in b.tracks]

    @pytest.mark.parametrize("seed", [3000, 3004])
    def test_defaults_are_the_former_rule(self, seed):
        scene = paper_scene("table3-paper", 0.02, seed=seed)
        self._same(detect(scene.cube), detect(scene.cube, **self.OFF))

    @pytest.mark.parametrize("own", [2, 3, 5])
    def test_own_points_against_loop(self, own):
        # main stage only (``track_ends=False``): in score order, every accepted track has at
        # least ``own`` points on no better accepted track (the loop reading of the option)
        for seed in (3000, 3001, 3002):
            scene = paper_scene("table3-paper", 0.014, seed=seed)
            result = detect(scene.cube, own_points=own, track_ends=False)
            order = sorted(result.tracks, key=lambda tr: (-tr.score, -len(tr)))
            seen: set = set()
            for tr in order:
                pts = {tuple(p) for p in tr.points.tolist()}
                assert len(pts - seen) >= own
                seen |= pts

    def test_near_duplicate_by_score(self):
        # the kept (better scoring) track's point predicts worse: the evidence rule keeps both,
        # the score rule drops the candidate (the better whole sequence wins)
        xy = [[t, t, 2 * t] for t in range(5)] + [[2, 4, 4]]
        on_line, detour = [0, 1, 2, 3, 4], [0, 1, 5, 3, 4]
        scan_of = [p[0] for p in xy]
        kept = [(detour, {scan_of[q]: i for i, q in enumerate(detour)})]
        image = [True] * 6
        assert not _is_near_duplicate(on_line, kept, scan_of, image, xy)
        assert _is_near_duplicate(on_line, kept, scan_of, image, xy, by_score=True)

    def test_dedupe_rescued(self):
        # Table III seed 3000 at 0.8 %: with the score rule the clutter end point (0, 39, 21)
        # of true track 1 is dropped as a near-duplicate, but the track-ends step re-adds it
        # (an alternative end point); with ``dedupe_rescued`` it stays dropped
        scene = paper_scene("table3-paper", 0.008, seed=3000)
        score = detect(scene.cube, near_duplicate="score")
        both = detect(scene.cube, near_duplicate="score", dedupe_rescued=True)
        assert bool(score.cleaned[0, 39, 21]) and not bool(both.cleaned[0, 39, 21])
        truth = scene.target_mask
        assert not (truth & ~both.cleaned).any()

    def test_case1_against_loop(self):
        for seed in (3000, 3001):
            scene = paper_scene("table3-paper", 0.02, seed=seed)
            result = detect(scene.cube, case1=True)
            for tr in result.tracks:
                inside = [bool(result.support[tuple(p)]) for p in tr.points.tolist()]
                assert 2 * sum(inside) > len(inside)

    def test_score_points_all(self):
        for seed in (3000, 3001):
            scene = paper_scene("table3-paper", 0.02, seed=seed)
            result = detect(scene.cube, score_points="all")
            for tr in result.tracks:  # the mean over all points, ends repeating neighbours
                assert tr.score == pytest.approx(float(tr.point_scores.mean()), abs=1e-12)
                assert tr.score >= 2.5

    @pytest.mark.parametrize(
        ("kw", "match"),
        [
            ({"own_points": 0}, "own_points"),
            ({"near_duplicate": "best"}, "near_duplicate"),
            ({"score_points": "ends"}, "score_points"),
        ],
    )
    def test_bad_options(self, kw, match):
        cube = torch.zeros(6, 8, 8, dtype=torch.bool)
        with pytest.raises(ValueError, match=match):
            detect(cube, **kw)
        with pytest.raises(ValueError, match=match):
            identify_tracks(cube, **kw)

    def test_near_duplicate_by_score_at_ends_only(self):
        # ``score-ends``: the score decides where the candidate differs only at its first or
        # last scans (an alternative end point); a detour (inner scan) keeps the evidence rule
        xy = [[t, t, 2 * t] for t in range(5)] + [[0, 1, 1], [2, 4, 4]]
        scan_of = [p[0] for p in xy]
        image = [True] * 7
        line = [0, 1, 2, 3, 4]
        end_variant, detour = [5, 1, 2, 3, 4], [0, 1, 6, 3, 4]
        kept = [(end_variant, {scan_of[q]: i for i, q in enumerate(end_variant)})]
        # the evidence rule: the candidate's end point lies on the line, it wins
        assert not _is_near_duplicate(line, kept, scan_of, image, xy)
        assert _is_near_duplicate(line, kept, scan_of, image, xy, by_score="ends")
        inner = [(detour, {scan_of[q]: i for i, q in enumerate(detour)})]
        assert not _is_near_duplicate(line, inner, scan_of, image, xy, by_score="ends")
        assert _is_near_duplicate(line, inner, scan_of, image, xy, by_score=True)

    @pytest.mark.parametrize("seed", sorted(HARD_SCENES))
    def test_score_ends_regression_scenes(self, seed):
        cube, truth = _hard_scene(HARD_SCENES[seed], seed)
        result = detect(cube, near_duplicate="score-ends")
        assert not (truth & ~result.cleaned).any()

    @pytest.mark.parametrize("seed", [6, 9, 49])
    def test_score_ends_partial_scenes(self, seed):
        cube, _, eligible = _partial_scene(seed, eligible=True)
        result = detect(cube, near_duplicate="score-ends")
        assert not (eligible & ~result.cleaned).any()


def test_detect_warns_when_no_chain_of_the_order_fits():
    cube = torch.zeros(4, 16, 16, dtype=torch.bool)
    for t in range(4):
        cube[t, 4, 3 + t] = True
    with pytest.warns(UserWarning, match=r"`order`: order 2 needs .* = 5 scans.*got T = 4"):
        result = detect(cube, order=2)
    assert result.tracks == []
    with pytest.warns(UserWarning, match=r"`order`: .*= 3 scans.*got T = 2"):
        detect(cube[:2], order=1)
    with warnings.catch_warnings():  # T = 2k + 1: a chain fits, no such warning
        warnings.simplefilter("error", UserWarning)
        warnings.filterwarnings("ignore", message=".*cannot cover every scan")
        detect(cube[:3], order=1)


def _fig5_window(seed, start):
    """Scans ``start .. start + 9`` of ``paper_scene("fig5", 0.01, seed)`` (as ``hoc-fig5``).

    Returns ``(frames, evaluated, image)``: the points of the true tracks with at least 2k + 1
    = 5 points in the window (the experiment's evaluated tracks), and the order-2 MHOC image.
    """
    scene = paper_scene("fig5", 0.01, seed=seed)
    frames = scene.cube[start : start + 10]
    evaluated = torch.zeros_like(frames)
    for tr in scene.tracks:
        q = tr[(tr[:, 0] >= start) & (tr[:, 0] < start + 10)]
        if q.shape[0] >= 5:
            evaluated[q[:, 0] - start, q[:, 1], q[:, 2]] = True
    image, _ = mhoc_candidates(frames, order=2)
    return frames, evaluated, image


def _lost(cube, eligible, **kw):
    return (eligible & ~detect(cube, **kw).cleaned).nonzero().tolist()


class TestOwnEnds:
    """Step 5, ``RESCUE_END`` (issue 7, task h7part): a track's own end point, replaced on the
    accepted tracks by a clutter point (or another track's), is kept when the proposed track
    through it scores higher than every accepted track it shares points with."""

    @pytest.mark.parametrize(("start", "point"), [(0, [3, 30, 10]), (2, [1, 30, 10])])
    def test_fig5_turning_track_keeps_its_first_point(self, monkeypatch, start, point):
        # ``fig5`` seed 5002, windows 1-10 and 3-12: the turning track T6 starts at scan 3
        # (absolute) at (30, 10); both accepted copies of it start on clutter instead, (29, 9)
        # at that scan (one after (26, 6) the scan before, so the scan is inside the accepted
        # tracks' scans and the extension rule rejected the true track). These were 2 of the 52
        # points hoc-fig5 lost on evaluated tracks; the other 50 are TestFig5ExactPieces'
        frames, evaluated, _ = _fig5_window(5002, start)
        monkeypatch.setattr(identify_module, "RESCUE_END", False)
        assert _lost(frames, evaluated) == [point]
        monkeypatch.undo()
        assert _lost(frames, evaluated) == []

    @pytest.mark.parametrize(
        ("seed", "points"),
        [(5019, [[3, 31, 33]]), (5079, [[3, 28, 25], [4, 28, 27]]), (5151, [[1, 28, 36]])],
    )
    def test_partial_scenes_keep_their_start(self, monkeypatch, seed, points):
        # ``partial_track_scene(seed, ends=False)``: measured with the rule off, these start
        # points (a run of one or two) were the scene's only eligible points lost
        cube, _, eligible = partial_track_scene(seed, ends=False)
        monkeypatch.setattr(identify_module, "RESCUE_END", False)
        assert _lost(cube, eligible) == points
        monkeypatch.undo()
        assert _lost(cube, eligible) == []

    def test_cut_before_the_new_point(self, monkeypatch):
        # ``partial_track_scene(67, ends=False)``: the best whole track through the lost start
        # (3, 31, 30) begins one scan earlier on another track's point (2, 31, 30), so its new
        # point is not at an end; cut before it, it is the true track, scoring above the
        # accepted copy that starts on clutter (3, 30, 33)
        cube, _, eligible = partial_track_scene(67, ends=False)
        monkeypatch.setattr(identify_module, "RESCUE_END", False)
        assert _lost(cube, eligible) == [[3, 31, 30]]
        monkeypatch.undo()
        assert _lost(cube, eligible) == []

    def test_own_ends(self):
        own = identify_module._own_ends
        root = [True] * 10
        assert own([0, 1, 2, 3, 4, 5], [0, 1], root, 5) == [range(6)]  # new start run
        assert own([0, 1, 2, 3, 4, 5], [5], root, 5) == [range(6)]  # new last point
        # a new point inside: cut before it (6 points left) or after it (2: too short)
        assert own([0, 1, 2, 3, 4, 5, 6, 7], [2], root, 5) == [range(2, 8)]
        assert own(list(range(10)), [4], root, 5) == [range(4, 10), range(5)]  # both
        assert own([0, 1, 2, 3, 4, 5], [1, 3], root, 5) == []  # not one run
        assert own([0, 1, 2, 3, 4, 5], list(range(6)), root, 5) == []  # no accepted point
        assert own([0, 1, 2, 3, 4, 5], [], root, 5) == []
        root[0] = False
        assert own([0, 1, 2, 3, 4, 5], [0, 1], root, 5) == []  # not an image point

    def test_beats_is_the_track_score(self):
        # ``_beats`` compares the score ``_select_tracks`` gives the track (span 2, min)
        cube, _ = _partial_scene(6)
        flat, p0, p1, p2 = _sparse_triples(cube[None], _allowed_cached(4, math.pi / 4, "cpu"), 4, 1)
        h, w = cube.shape[1:]
        coords = torch.stack([flat // (h * w), (flat // w) % h, flat % w], dim=1)
        kw = identify_module._score_kwargs(9.0, 0.5, 2.356, 1.91, "min")
        s = identify_module._triple_scores(coords, p0, p1, p2, kw)
        track_kw = identify_module._track_kwargs(kw, 2, None)
        path = [0]
        (score, _, _), *_ = identify_module._score_paths([path], p0, p1, p2, s, coords, 0, track_kw)
        beats = identify_module._beats
        assert beats(path, [score - 1e-9], p0, p1, p2, s, coords, track_kw)
        assert not beats(path, [score], p0, p1, p2, s, coords, track_kw)


class TestLoneExtension:
    """Step 5, ``ALONE_EXTEND`` (issue 7, task h7part): a 6-point track of its own whose
    maximal chain another point extends below the threshold, and whose best whole tracks on
    one-scan scores are its two 5-point pieces (too short for ``RESCUE_ALONE`` alone)."""

    @pytest.mark.parametrize("seed", [176, 5050])
    def test_six_point_track_is_kept(self, monkeypatch, seed):
        cube, _, eligible = partial_track_scene(seed, ends=False)
        monkeypatch.setattr(identify_module, "ALONE_EXTEND", False)
        lost = _lost(cube, eligible)
        assert len(lost) == 6 and {t for t, _, _ in lost} == set(range(4, 10))
        monkeypatch.undo()
        assert _lost(cube, eligible) == []

    def test_extend_alone(self):
        # triples k: points (k, k + 1, k + 2), edges e(k, k + 1) = k
        a0, a2 = [0, 1, 2, 3], [2, 3, 4, 5]
        a_in, a_out = [0, 1, 2, 3], [1, 2, 3, 4]
        root = [True] * 6
        links = identify_module._accepted_links(a_in, a_out, [True] * 4)
        extend = identify_module._extend_alone
        assert extend([1], links, a0, a2, root, {}) == [0, 1, 2, 3]
        assert extend([1], links, a0, a2, root, {5: [0]}) == [0, 1, 2]  # 5 on a track
        assert extend([1], links, a0, a2, [False] + [True] * 5, {}) == [1, 2, 3]  # 0 not image
        links = identify_module._accepted_links(a_in, a_out, [True, True, True, False])
        assert extend([1], links, a0, a2, root, {}) == [0, 1, 2]  # triple 3 not accepted
        # a second accepted triple (3, 4, 6) on the out-edge of triple 2: ambiguous, not followed
        links = identify_module._accepted_links([*a_in, 3], [*a_out, 5], [True] * 5)
        assert extend([1], links, [*a0, 3], [*a2, 6], [*root, True], {}) == [0, 1, 2]


class TestFig5ExactPieces:
    """The other 50 of the 52 points ``hoc-fig5`` lost on ``fig5`` (issue 7, task h7part).

    All 50: T4 (scans 1-8) in window 5-14, where it has exactly 2k + 1 = 5 points (window
    scans 0-4), in the 10 of 20 seeds (5000-5019) where no clutter point extends it. The
    order-2 forward image marks a point only with four scans after it and the backward image
    only with four before, so just its first and last point are MHOC image points: Case 1 of
    section III-B holds at none of its scans, and the paper's retention statement (section III,
    after Proposition 1) is for tracks over *more than* 2k + 1 scans. Their sequences (the
    forward triple at scan 0, the backward triple at scan 4) meet at one point, which no
    association step of ours links. ``RESCUE_JOINED`` (off) keeps them, at a measured cost of
    up to 0.48 points of clutter rejection on Table III.
    """

    T4: typing.ClassVar = [[0, 41, 45], [1, 38, 45], [2, 35, 45], [3, 32, 45], [4, 29, 45]]

    def test_only_the_ends_are_image_points(self):
        frames, evaluated, image = _fig5_window(5003, 4)
        assert [bool(image[tuple(p)]) for p in self.T4] == [True, False, False, False, True]
        assert _lost(frames, evaluated) == self.T4

    def test_joined_option_keeps_them(self, monkeypatch):
        frames, evaluated, _ = _fig5_window(5003, 4)
        monkeypatch.setattr(identify_module, "RESCUE_JOINED", True)
        assert _lost(frames, evaluated) == []

    def test_kept_when_clutter_extends_it(self):
        # seed 5000: a clutter point extends the piece, (1, 38, 45) is an image point too
        frames, evaluated, image = _fig5_window(5000, 4)
        assert bool(image[1, 38, 45])
        assert _lost(frames, evaluated) == []


@pytest.mark.slow
def test_partial_track_scenes_bound():
    # issue 7, open: the eligible points ``partial_track_scene(seed, ends=False)`` seeds 0-199
    # lose with the defaults (measured 8 in 6 scenes; 15 in 8 before ``RESCUE_END`` and
    # ``ALONE_EXTEND``); the bound catches a regression
    lost = []
    for seed in range(200):
        cube, _, eligible = partial_track_scene(seed, ends=False)
        lost.append(len(_lost(cube, eligible)))
    assert sum(lost) <= 8 and sum(n > 0 for n in lost) <= 6, lost

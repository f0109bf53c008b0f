import math
import tracemalloc

import numpy as np
import pytest
import torch

import hocnet.hoc.stream as stream
from hocnet.data.binary import paper_scene
from hocnet.hoc import (
    StreamingDetector,
    detect,
    hoc_levels,
    identify_tracks,
    modified_hoc,
    support_from_levels,
)
from hocnet.hoc.kernels import allowed_moves

DELTA = math.pi / 4


def _assert_same(a, b):
    """Two HOCResults are equal: cubes bit for bit, tracks point for point."""
    assert torch.equal(a.support, b.support)
    assert torch.equal(a.cleaned, b.cleaned)
    assert torch.equal(a.scores.isnan(), b.scores.isnan())
    assert torch.equal(a.scores.nan_to_num(), b.scores.nan_to_num())
    assert [t.points.tolist() for t in a.tracks] == [t.points.tolist() for t in b.tracks]
    assert [t.score for t in a.tracks] == [t.score for t in b.tracks]
    for ta, tb in zip(a.tracks, b.tracks, strict=True):
        assert torch.equal(ta.point_scores, tb.point_scores)


def _stream(det, cube):
    return [out for t in range(cube.shape[0]) if (out := det.push(cube[t])) is not None]


class TestStreamingEqualsBatch:
    @pytest.mark.parametrize("seed", range(3))
    @pytest.mark.parametrize("order", [1, 2, 3])
    @pytest.mark.parametrize("stride", [1, 2])
    def test_every_window_equals_detect(self, seed, order, stride):
        scene = paper_scene("fig5", 0.015, seed=seed)  # (16, 60, 60), tracks start and stop
        for window in (2 * order + 2, 10):
            det = StreamingDetector(window=window, stride=stride, order=order)
            outs = _stream(det, scene.cube)
            assert len(outs) == (16 - window) // stride + 1
            for out in outs:
                assert out.stop - out.start == window
                _assert_same(out.result, detect(scene.cube[out.start : out.stop], order=order))

    def test_chain_support_equals_detect(self):
        scene = paper_scene("fig5", 0.015, seed=1)
        det = StreamingDetector(window=10, stride=2, order=2, support="chain", identify="greedy")
        for out in _stream(det, scene.cube):
            want = detect(scene.cube[out.start : out.stop], support="chain", identify="greedy")
            _assert_same(out.result, want)

    def test_saturated_window_equals_detect(self):
        gen = torch.Generator().manual_seed(4)
        cube = torch.rand(8, 30, 30, generator=gen) < 0.06  # above the 4.94 % bound
        det = StreamingDetector(window=6, stride=1, order=1)
        with pytest.warns(RuntimeWarning, match="discrimination bound"):
            outs = _stream(det, cube)
        for out in outs:
            with pytest.warns(RuntimeWarning):
                want = detect(cube[out.start : out.stop], order=1)
            _assert_same(out.result, want)
            assert out.result.saturated and want.saturated
            assert out.result.warnings == want.warnings

    @pytest.mark.parametrize("patch", [8, 12])
    def test_locally_saturated_patch_equals_detect(self, patch):
        # a patch on in every scan under a low global density: detect leaves it out of track
        # identification (LOCAL_SATURATION; unbounded memory before, 18 GB at 12 x 12); the
        # stream must do the same, window by window
        gen = torch.Generator().manual_seed(patch)
        cube = torch.rand(12, 64, 64, generator=gen) < 0.005
        cube[:, 20 : 20 + patch, 30 : 30 + patch] = True
        cube[4:, 50, 5:13] = True  # a stationary line elsewhere: not saturated
        det = StreamingDetector(window=10, stride=1, order=2)
        with pytest.warns(RuntimeWarning, match="windows of scans"):
            outs = _stream(det, cube)
        assert len(outs) == 3
        for out in outs:
            with pytest.warns(RuntimeWarning, match="windows of scans"):
                want = detect(cube[out.start : out.stop], order=2)
            _assert_same(out.result, want)
            assert out.result.saturated and out.result.warnings == want.warnings
            assert not out.result.cleaned[:, 20 : 20 + patch, 30 : 30 + patch].any()

    @pytest.mark.parametrize("seed", range(2))
    def test_dense_clutter_and_options(self, seed):
        gen = torch.Generator().manual_seed(seed)
        cube = torch.rand(14, 40, 48, generator=gen) < 0.04
        kw = {"v": 3, "delta": math.pi / 3, "threshold": 2.0, "min_points": 4}
        det = StreamingDetector(window=8, stride=1, order=2, **kw)
        for out in _stream(det, cube):
            _assert_same(out.result, detect(cube[out.start : out.stop], order=2, **kw))

    @pytest.mark.parametrize(
        "kw",
        [
            # the paper's section III-B read literally (no additions)
            {"score_span": 1, "shared_points": False, "dedupe": False, "track_ends": False},
            {"track_combine": "mean"},
            {"track_ends": False},
        ],
    )
    def test_literal_and_track_options_equal_detect(self, kw):
        scene = paper_scene("fig5", 0.02, seed=3)
        det = StreamingDetector(window=10, stride=2, order=2, **kw)
        outs = _stream(det, scene.cube)
        assert outs
        for out in outs:
            _assert_same(out.result, detect(scene.cube[out.start : out.stop], order=2, **kw))

    def test_conv_method_equals_detect(self):
        scene = paper_scene("fig5", 0.02, seed=5)
        cube = scene.cube[:12, 10:40, 5:45]
        det = StreamingDetector(window=7, stride=1, order=2, method="conv")
        outs = _stream(det, cube)
        assert len(outs) == 6
        for out in outs:
            _assert_same(out.result, detect(cube[out.start : out.stop], order=2))

    @pytest.mark.parametrize(
        ("order", "method"), [(1, "auto"), (2, "auto"), (3, "auto"), (2, "conv")]
    )
    def test_mhoc_support_is_forward_or_backward_top_level(self, order, method):
        scene = paper_scene("fig5", 0.015, seed=7)
        cube = scene.cube if method == "auto" else scene.cube[:12, 10:40, 5:45]
        det = StreamingDetector(window=10, stride=1, order=order, support="mhoc", method=method)
        outs = _stream(det, cube)
        assert len(outs) == cube.shape[0] - 9
        for out in outs:
            w = cube[out.start : out.stop]
            image = modified_hoc(w, order, direction="forward") | modified_hoc(
                w, order, direction="backward"
            )
            assert torch.equal(out.result.support, image)
            # candidates: the image plus the members of its top-layer triples, both directions
            named = torch.zeros_like(w)
            for direction in ("forward", "backward"):
                levels = hoc_levels(w[None], order, 4, DELTA, direction=direction)
                named |= support_from_levels(levels[-2:], 4, DELTA, direction=direction)[0]
            assert torch.equal(out.candidates, named)
            assert bool((image <= named).all())
            # identification on the candidates, rooted at the image ([LA98] section III-B)
            tracks, _, cleaned = identify_tracks(named, roots=image, min_points=2 * order + 1)
            assert torch.equal(out.result.cleaned, cleaned)
            assert [t.points.tolist() for t in out.result.tracks] == [
                t.points.tolist() for t in tracks
            ]

    def test_chain_mode_has_no_candidates(self):
        det = StreamingDetector(window=5, stride=1, order=2, support="chain")
        outs = _stream(det, torch.zeros(5, 8, 8, dtype=torch.bool))
        assert outs[0].candidates is None

    @pytest.mark.parametrize("order", [1, 3])
    def test_cached_levels_equal_hoc_levels_of_the_window(self, order):
        gen = torch.Generator().manual_seed(3)
        cube = torch.rand(15, 30, 30, generator=gen) < 0.05
        window = 2 * order + 3
        det = StreamingDetector(window=window, stride=1, order=order, v=2)
        for t in range(15):
            if det.push(cube[t]) is None:
                continue
            start = t + 1 - window
            w = cube[start : t + 1][None]
            for cache, direction in zip(det._dirs, ("forward", "backward"), strict=True):
                batch = hoc_levels(w, order, 2, DELTA, direction=direction)
                for level in range(order + 1):
                    mine = torch.zeros(window, 30 * 30, dtype=torch.bool)
                    for u, pts in cache.levels[level].items():
                        lo = start + 2 * level if direction == "backward" else start
                        if u >= lo:  # the batch run cannot evaluate earlier backward entries
                            mine[u - start, pts] = True
                    assert torch.equal(mine.reshape(window, 30, 30), batch[level][0])


def _turn(i1, j1, i2, j2):
    if (i1, j1) == (0, 0) or (i2, j2) == (0, 0):
        return 0.0
    d = abs(math.atan2(j2, i2) - math.atan2(j1, i1)) % (2 * math.pi)
    return min(d, 2 * math.pi - d)


def _triples_loop(a, b, c, v, delta):
    """Accepted triples of one layer, straight from eq. (5)-(6): loops over pixels."""
    out = set()
    for y0, x0 in zip(*np.nonzero(a), strict=True):
        for y1, x1 in zip(*np.nonzero(b), strict=True):
            i1, j1 = x1 - x0, y1 - y0
            if max(abs(i1), abs(j1)) > v:
                continue
            for y2, x2 in zip(*np.nonzero(c), strict=True):
                i2, j2 = x2 - x1, y2 - y1
                if max(abs(i2), abs(j2)) <= v and _turn(i1, j1, i2, j2) <= delta + 1e-9:
                    out.add(((y0, x0), (y1, x1), (y2, x2)))
    return out


class TestSparseHelpers:
    @pytest.mark.parametrize("seed", range(4))
    @pytest.mark.parametrize("v", [1, 2])
    def test_links_and_join_against_loop(self, seed, v):
        h, w = 9, 11
        gen = torch.Generator().manual_seed(seed)
        scans = torch.rand(3, h, w, generator=gen) < 0.3
        grid = stream._Grid(h, w, v)
        pts = [s.reshape(-1).nonzero().squeeze(1) for s in scans]
        allowed = allowed_moves(v, DELTA)
        fwd = grid.join(grid.edges(pts[0], pts[1]), grid.edges(pts[1], pts[2]), allowed)
        # backward: the same links read the other way round
        bwd = grid.join(
            grid.reverse(grid.edges(pts[1], pts[2])),
            grid.reverse(grid.edges(pts[0], pts[1])),
            allowed,
        )

        def as_set(triples):
            rows = torch.stack(triples, 1).tolist()
            assert len(rows) == len({tuple(r) for r in rows})  # no triple twice
            assert torch.equal(triples[0], triples[0].sort().values)  # sorted by root
            return {tuple((p // w, p % w) for p in r) for r in rows}

        arr = scans.numpy()
        assert as_set(fwd) == _triples_loop(arr[0], arr[1], arr[2], v, DELTA)
        assert as_set(bwd) == _triples_loop(arr[2], arr[1], arr[0], v, DELTA)
        # scratch images cleared
        assert (grid.image == -1).all() and (grid.slots == -1).all() and not grid.flags.any()

    def test_no_wrap_at_the_border(self):
        grid = stream._Grid(4, 5, 1)
        src, dst, _ = grid.edges(torch.tensor([4]), torch.tensor([5]))  # (0, 4) -> (1, 0)
        assert src.numel() == 0 and dst.numel() == 0


class TestIncremental:
    def _count(self, monkeypatch, window, order):
        calls = {"edges": [], "join": 0, "tree": 0}
        edges, join, tree = stream._Grid.edges, stream._Grid.join, StreamingDetector._tree_sparse

        def count_edges(self, a, b):
            calls["edges"].append((a.numel(), b.numel()))
            return edges(self, a, b)

        def count_join(self, *args):
            calls["join"] += 1
            return join(self, *args)

        def count_tree(self, *args):
            calls["tree"] += 1
            return tree(self, *args)

        monkeypatch.setattr(stream._Grid, "edges", count_edges)
        monkeypatch.setattr(stream._Grid, "join", count_join)
        monkeypatch.setattr(StreamingDetector, "_tree_sparse", count_tree)
        gen = torch.Generator().manual_seed(0)
        cube = torch.rand(3 * window, 24, 24, generator=gen) < 0.05
        det = StreamingDetector(window=window, stride=1000, order=order)  # layers only
        for t in range(2 * window):
            det.push(cube[t])
        per_push = []
        for t in range(2 * window, 3 * window):
            for key in ("join", "tree"):
                calls[key] = 0
            calls["edges"] = []
            det.push(cube[t])
            new = int(cube[t].sum())
            per_push.append((len(calls["edges"]), calls["join"], calls["tree"]))
            assert calls["edges"] == [(int(cube[t - 1].sum()), new)]  # scans n - 1 and n only
        return per_push

    @pytest.mark.parametrize("order", [1, 2, 3])
    def test_push_work_does_not_depend_on_the_window(self, monkeypatch, order):
        for window in (2 * order + 1, 12, 20):
            per_push = self._count(monkeypatch, window, order)
            # one look-up of the new scan, 2k new layer entries, one new tree per direction
            assert set(per_push) == {(1, 2 * order, 2)}

    @pytest.mark.parametrize("seed", range(6))
    @pytest.mark.parametrize("v", [1, 2, 4])
    def test_local_points_against_a_window_loop(self, seed, v):
        """Block-count pre-check + frame pass = every window counted one by one."""
        from hocnet.hoc.identify import LOCAL_SATURATION

        gen = torch.Generator().manual_seed(seed)
        h, w = 23 + seed, 31 - seed  # not multiples of the block side
        scan = torch.rand(h, w, generator=gen) < 0.04
        side = 2 * v + 1
        if seed % 3:  # a dense patch, at the border for some seeds
            y, x = (0, w - side) if seed % 3 == 1 else (h // 2, w // 3)
            scan[y : y + side, x : x + side] = torch.rand(side, side, generator=gen) < 0.6
        want = torch.zeros(h, w, dtype=torch.bool)
        limit = LOCAL_SATURATION * side * side
        for cy in range(h):
            for cx in range(w):  # the window centred on (cy, cx), zero padded
                count = int(scan[max(cy - v, 0) : cy + v + 1, max(cx - v, 0) : cx + v + 1].sum())
                if count > limit:
                    want[max(cy - v, 0) : cy + v + 1, max(cx - v, 0) : cx + v + 1] = True
        det = StreamingDetector(window=5, order=1, v=v)
        det.push(scan)
        got = det._local_points(scan.flatten().nonzero().squeeze(1))
        assert got.tolist() == want.flatten().nonzero().squeeze(1).tolist()
        if seed % 3:
            assert got.numel() > 0  # the patch is saturated: the frame pass ran

    def test_memory_stays_flat(self):
        det = StreamingDetector(window=10, stride=100, order=2, v=2)
        gen = torch.Generator().manual_seed(0)
        scans = torch.rand(64, 16, 16, generator=gen) < 0.02

        def run(n):
            for i in range(n):
                det.push(scans[i % 64])

        run(500)
        tracemalloc.start()
        run(500)
        first, _ = tracemalloc.get_traced_memory()
        run(4000)
        second, _ = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert det.pushed == 5000
        assert sorted(det._scans) == list(range(4990, 5000))
        for cache in det._dirs:
            for d in (*cache.levels, *cache.triples, cache.links, cache.trees):
                assert all(4990 <= t < 5000 for t in d)
        assert second - first < 64 * 1024  # no growth with the number of pushed scans


class TestStreamingDetector:
    def test_paper_windows(self):
        scene = paper_scene("fig5", 0.0, seed=0)
        det = StreamingDetector(window=10, stride=2, order=2)
        spans = [(out.start + 1, out.stop) for out in _stream(det, scene.cube)]
        assert spans == [(1, 10), (3, 12), (5, 14), (7, 16)]  # 1-based, [LA98] section IV-A

    def test_ids_persist_across_windows(self):
        cube = torch.zeros(14, 16, 40, dtype=torch.bool)
        for t in range(14):
            cube[t, 8, 2 + 2 * t] = True
            cube[t, 2, 37 - 2 * t] = True
        det = StreamingDetector(window=8, stride=2, order=2)
        outs = _stream(det, cube)
        assert len(outs) == 4
        for out in outs:
            by_row = {int(tr.points[0, 1]): tr.id for tr in out.tracks}
            assert by_row == {2: 1, 8: 2}

    def test_new_track_gets_a_new_id(self):
        cube = torch.zeros(12, 16, 40, dtype=torch.bool)
        for t in range(12):
            cube[t, 8, 2 + 2 * t] = True
        for t in range(6, 12):
            cube[t, 2, 2 + 3 * (t - 6)] = True
        det = StreamingDetector(window=6, stride=3, order=2)
        outs = _stream(det, cube)
        assert [[tr.id for tr in out.tracks] for out in outs[:2]] == [[1], [1]]
        assert sorted((int(tr.points[0, 1]), tr.id) for tr in outs[2].tracks) == [(2, 2), (8, 1)]

    @pytest.mark.parametrize(("seed", "stride"), [(0, 1), (1, 2), (2, 3)])
    def test_ids_against_a_loop_reference(self, seed, stride):
        scene = paper_scene("fig5", 0.03, seed=seed)  # many short clutter tracks
        outs = _stream(StreamingDetector(window=6, stride=stride, order=1), scene.cube)
        previous, next_id, n_tracks, inherited = [], 1, 0, 0
        for out in outs:
            current, taken = [], set()
            for tr in out.tracks:  # in order: the previous track with most common points
                pts = {tuple(p) for p in tr.points.tolist()}
                best, most = None, 0
                for pid, ppts in previous:
                    if pid not in taken and len(pts & ppts) > most:
                        best, most = pid, len(pts & ppts)
                if best is None:
                    best, next_id = next_id, next_id + 1
                else:
                    inherited += 1
                taken.add(best)
                current.append((best, pts))
                assert tr.id == best
            previous = current
            n_tracks += len(current)
        assert n_tracks > 3 * len(outs) and 0 < inherited < n_tracks

    @pytest.mark.parametrize("seed", range(30))
    def test_associate_against_a_loop_reference(self, seed):
        """Crafted overlaps, some tracks wanting the same previous track first (both paths)."""
        from hocnet.hoc.identify import Track

        gen = torch.Generator().manual_seed(seed)
        det = StreamingDetector(window=5, order=1)
        det.push(torch.zeros(4, 40, dtype=torch.bool))

        def tracks(n, pool):  # n tracks of 3-5 points drawn from a small pool of pixels
            out = []
            for _ in range(n):
                size = int(torch.randint(3, 6, (1,), generator=gen))
                xs = torch.randperm(pool, generator=gen)[:size].sort().values
                pts = torch.stack([torch.arange(size), torch.zeros(size).long(), xs], 1)
                out.append(Track(points=pts, id=0, score=3.0, point_scores=torch.ones(size)))
            return out

        previous, next_id, conflicts = [], 1, 0
        for _ in range(4):  # start 0 each time: the windows overlap completely
            current = tracks(int(torch.randint(0, 7, (1,), generator=gen)), 12)
            det._associate(current, 0)
            taken, firsts = set(), []
            for tr in current:  # in order: the not yet taken previous track with most points
                pts = {tuple(p) for p in tr.points.tolist()}
                overlap = [len(pts & pp) for _, pp in previous]
                if overlap and max(overlap) > 0:
                    firsts.append(previous[overlap.index(max(overlap))][0])
                best, most = None, 0
                for (pid, _), n in zip(previous, overlap, strict=True):
                    if pid not in taken and n > most:
                        best, most = pid, n
                if best is None:
                    best, next_id = next_id, next_id + 1
                taken.add(best)
                assert tr.id == best
            conflicts += len(firsts) > len(set(firsts))
            previous = [(tr.id, {tuple(p) for p in tr.points.tolist()}) for tr in current]
        if seed == 0:
            assert conflicts > 0  # the loop path ran

    def test_absolute_scan_numbers(self):
        cube = torch.zeros(10, 8, 30, dtype=torch.bool)
        for t in range(10):
            cube[t, 4, 1 + 2 * t] = True
        det = StreamingDetector(window=6, stride=4, order=2)
        outs = _stream(det, cube)
        assert outs[-1].start == 4
        assert outs[-1].tracks[0].points[0, 0].item() == 4
        assert outs[-1].result.tracks[0].points[0, 0].item() == 0

    def test_numpy_and_float_scans(self):
        cube = torch.zeros(6, 10, 20, dtype=torch.bool)
        for t in range(6):
            cube[t, 5, 2 + t] = True
        det = StreamingDetector(window=6, order=2)
        outs = [det.push(cube[t].numpy().astype(np.float32)) for t in range(6)]
        assert len(outs[-1].tracks) == 1

    def test_reset(self):
        det = StreamingDetector(window=5, order=2)
        det.push(torch.zeros(6, 6))
        det.reset()
        det.push(torch.zeros(7, 6))  # a new stream may have a new size
        assert det.pushed == 1


class TestErrors:
    @pytest.mark.parametrize(
        ("kwargs", "error", "name"),
        [
            ({"window": 4, "order": 2}, ValueError, "window"),
            ({"window": 2.5}, TypeError, "window"),
            ({"stride": 0}, ValueError, "stride"),
            ({"stride": "2"}, TypeError, "stride"),
            ({"order": 0}, ValueError, "order"),
            ({"v": 0}, ValueError, "v"),
            ({"delta": 0.0}, ValueError, "delta"),
            ({"delta": 4.0}, ValueError, "delta"),
            ({"delta": None}, TypeError, "delta"),
            ({"threshold": math.nan}, ValueError, "threshold"),
            ({"min_points": -5}, ValueError, "min_points"),
            ({"min_points": 0}, ValueError, "min_points"),
            ({"min_points": 2.0}, TypeError, "min_points"),
            ({"max_tracks_per_point": 0}, ValueError, "max_tracks_per_point"),
            ({"method": "fast"}, ValueError, "method"),
            ({"support": "all"}, ValueError, "support"),
            ({"A1": "nine"}, TypeError, "A1"),
            ({"alpha1": math.inf}, ValueError, "alpha1"),
            ({"A2": None}, TypeError, "A2"),
            ({"alpha2": math.nan}, ValueError, "alpha2"),
            ({"track_combine": "max"}, ValueError, "track_combine"),
        ],
    )
    def test_bad_constructor_argument_raises_at_construction(self, kwargs, error, name):
        with pytest.raises(error, match=f"^`{name}`: expected"):
            StreamingDetector(**kwargs)

    @pytest.mark.parametrize(
        ("scan", "error", "message"),
        [
            (torch.zeros(3, 8, 8), ValueError, r"\(H, W\), got shape \(3, 8, 8\)"),
            (torch.zeros(1, 8, 8), ValueError, r"\(H, W\), got shape \(1, 8, 8\)"),
            (torch.zeros(8), ValueError, r"one scan of shape \(H, W\), got shape \(8,\)"),
            (torch.zeros(0, 8), ValueError, "non-empty"),
            (torch.full((8, 8), 0.5), ValueError, "binary"),
            (torch.full((8, 8), math.nan), ValueError, "finite"),
            (torch.zeros(8, 8, dtype=torch.complex64), TypeError, "dtype"),
            ("scan", TypeError, "str"),
        ],
    )
    def test_bad_scan(self, scan, error, message):
        det = StreamingDetector(window=5, order=2)
        det.push(torch.zeros(8, 8))
        with pytest.raises(error, match=f"^`scan`: expected .*{message}"):
            det.push(scan)
        assert det.pushed == 1  # a refused scan changes nothing
        assert det.push(torch.zeros(8, 8)) is None and det.pushed == 2

    def test_frame_size_change(self):
        det = StreamingDetector(window=5, order=2)
        det.push(torch.zeros(6, 6))
        with pytest.raises(ValueError, match=r"`scan`: expected shape \(6, 6\) .* got \(7, 6\)"):
            det.push(torch.zeros(7, 6))
        with pytest.raises(ValueError, match="`scan`: expected shape"):
            det.push(torch.zeros(6, 7))
        assert det.pushed == 1


# ----------------------------------------------------------------------------- latency work


def _clutter_with_targets(n_t, h, w, density, seed):
    """Uniform clutter plus three straight targets at non-integer speeds (1-3 px/scan)."""
    gen = torch.Generator().manual_seed(seed)
    cube = torch.rand(n_t, h, w, generator=gen) < density
    for _ in range(3):
        y0, x0 = (torch.rand(2, generator=gen) * torch.tensor([h, w])).tolist()
        angle = float(torch.rand(1, generator=gen)) * 2 * math.pi
        speed = 1.0 + 2.0 * float(torch.rand(1, generator=gen))
        for t in range(n_t):
            y = math.floor(y0 + t * speed * math.sin(angle) + 0.5) % h
            x = math.floor(x0 + t * speed * math.cos(angle) + 0.5) % w
            cube[t, y, x] = True
    return cube


class TestLatencyPathsEqualBatch:
    """The streaming fast paths (window triples from cached links, vectorised identification
    helpers) against batch ``detect`` and against the loops they replace."""

    @pytest.mark.parametrize("density", [0.005, 0.015, 0.03])
    @pytest.mark.parametrize("order", [2, 3])
    @pytest.mark.parametrize("stride", [1, 2])
    @pytest.mark.parametrize("support", ["mhoc", "chain"])
    def test_random_scenes_every_window(self, density, order, stride, support):
        seed = int(1000 * density) + 10 * order + stride
        cube = _clutter_with_targets(13, 40, 56, density, seed)
        det = StreamingDetector(window=10, stride=stride, order=order, support=support)
        outs = _stream(det, cube)
        assert len(outs) == 3 // stride + 1
        for out in outs:
            want = detect(cube[out.start : out.stop], order=order, support=support)
            _assert_same(out.result, want)

    @pytest.mark.parametrize("order", [2, 3])
    def test_two_percent_stride_one_every_window(self, order):
        """The benchmark's hard row in small: 2 % clutter, stride 1, every window == detect
        (a larger frame than above: more clutter tracks per window)."""
        cube = _clutter_with_targets(14, 96, 128, 0.02, 20 + order)
        det = StreamingDetector(window=10, stride=1, order=order)
        outs = _stream(det, cube)
        assert len(outs) == 5
        for out in outs:
            _assert_same(out.result, detect(cube[out.start : out.stop], order=order))
        assert sum(len(out.result.tracks) for out in outs) > 0

    @pytest.mark.parametrize("identify", ["assignment", "greedy"])
    def test_other_identifications(self, identify):
        cube = _clutter_with_targets(12, 40, 48, 0.015, 7)
        det = StreamingDetector(window=9, stride=1, order=2, identify=identify, score_span=1)
        for out in _stream(det, cube):
            want = detect(cube[out.start : out.stop], identify=identify, score_span=1)
            _assert_same(out.result, want)

    @pytest.mark.parametrize("support", ["mhoc", "chain"])
    def test_window_triples_equal_sparse_triples(self, support):
        from hocnet.hoc.functional import _sparse_triples

        cube = _clutter_with_targets(12, 36, 40, 0.03, 3)
        det = StreamingDetector(window=8, stride=1, order=2, support=support)
        checked = 0
        for t in range(cube.shape[0]):
            if det.push(cube[t]) is None:
                continue
            start = det.pushed - det.window
            points = det._window_points(start, trees=True)
            got = det._window_triples(start, points)
            want = _sparse_triples(det._cube(points)[None], allowed_moves(4, DELTA), 4, 1)
            for g, w in zip(got, want, strict=True):
                assert torch.equal(g, w)
            checked += int(got[1].numel() > 0)
        assert checked > 0

    @pytest.mark.parametrize("order", [1, 2, 3])
    def test_window_triples_cached_equal_joined_links(self, order):
        """The cached first-layer triples, filtered == the restricted links, joined."""
        cube = _clutter_with_targets(12, 36, 40, 0.03, 5)
        det = StreamingDetector(window=2 * order + 3, stride=1, order=order)
        checked = 0
        for t in range(cube.shape[0]):
            if det.push(cube[t]) is None:
                continue
            start = det.pushed - det.window
            points = det._window_points(start, trees=True)
            got = det._window_triples(start, points)
            cached = det._dirs[0].triples[1]
            det._dirs[0].triples[1] = {}  # not cached: the links are joined
            try:
                want = det._window_triples(start, points)
            finally:
                det._dirs[0].triples[1] = cached
            for g, w in zip(got, want, strict=True):
                assert torch.equal(g, w)
            checked += int(got[1].numel() > 0)
        assert checked > 0

    @pytest.mark.parametrize("seed", range(40))
    def test_enumerate_paths_vectorised_equals_loop(self, seed):
        from hocnet.hoc._incremental import enumerate_paths_vectorised
        from hocnet.hoc.identify import _enumerate_paths, _enumerate_paths_loop

        gen = torch.Generator().manual_seed(seed)
        k = int(torch.randint(0, 150, (1,), generator=gen))
        a_in = torch.randint(0, 30, (k,), generator=gen)
        a_out = a_in + torch.randint(1, 5, (k,), generator=gen)  # edge ids grow: a DAG
        s = torch.randint(0, 4, (k,), generator=gen).double() / 2  # many ties
        accepted = torch.rand(k, generator=gen) < 0.8
        for cap in (3, 40, 20000):
            want, capped = _enumerate_paths_loop(accepted, a_in, a_out, s, cap)
            fast = enumerate_paths_vectorised(accepted, a_in, a_out, s, cap)
            if fast is None:  # at least `cap` chains: the loop's cap decides
                assert capped
            else:
                assert not capped
                assert fast == want
            got = _enumerate_paths(accepted, a_in, a_out, s, cap)
            if not capped:  # at the cap the clusters decide (test_identify.py::TestCandidateCap)
                assert got == (want, capped)
            else:
                assert got[1]

    @pytest.mark.parametrize("seed", range(20))
    def test_enumerate_paths_vectorised_at_the_exact_cap(self, seed):
        """``None`` exactly when the loop caps: caps just below, at and above the chain count."""
        from hocnet.hoc._incremental import enumerate_paths_vectorised
        from hocnet.hoc.identify import _enumerate_paths_loop

        gen = torch.Generator().manual_seed(100 + seed)
        k = int(torch.randint(1, 40, (1,), generator=gen))  # small: a few hundred chains
        a_in = torch.randint(0, 30, (k,), generator=gen)
        a_out = a_in + torch.randint(1, 4, (k,), generator=gen)
        s = torch.randint(0, 3, (k,), generator=gen).double()
        accepted = torch.rand(k, generator=gen) < 0.9
        every, capped = _enumerate_paths_loop(accepted, a_in, a_out, s, 10**5)
        assert not capped
        total = len(every)
        for cap in {max(1, total - 1), max(1, total), total + 1}:
            want, capped = _enumerate_paths_loop(accepted, a_in, a_out, s, cap)
            fast = enumerate_paths_vectorised(accepted, a_in, a_out, s, cap)
            assert (fast is None) == capped == (total >= cap)
            if fast is not None:
                assert fast == want

    @pytest.mark.parametrize("seed", range(20))
    def test_chain_counts_against_recursion(self, seed):
        """Chains from each triple, capped: against a memoised recursion over the continuations."""
        from functools import cache

        from hocnet.hoc._incremental import _chain_counts

        gen = torch.Generator().manual_seed(seed)
        k = int(torch.randint(1, 200, (1,), generator=gen))
        a_in = torch.randint(0, 40, (k,), generator=gen).numpy()
        a_out = a_in + torch.randint(1, 3, (k,), generator=gen).numpy()
        n_e = int(max(a_in.max(), a_out.max())) + 1
        fan = np.bincount(a_in, minlength=n_e)[a_out]

        @cache
        def chains(j: int) -> int:
            nxt = [i for i in range(k) if a_in[i] == a_out[j]]
            return sum(chains(i) for i in nxt) if nxt else 1

        want = [chains(j) for j in range(k)]
        for cap in (1, 3, 50, 10**12):
            got = _chain_counts(a_in, a_out, fan, n_e, cap).tolist()
            assert got == [min(w, cap) for w in want]

    @pytest.mark.parametrize("seed", range(20))
    def test_chain_clusters_equals_identify(self, seed):
        """The same clusters as ``_chain_clusters``; the counts equal below the cap, else >= it."""
        from hocnet.hoc._incremental import chain_clusters
        from hocnet.hoc.identify import _chain_clusters

        gen = torch.Generator().manual_seed(300 + seed)
        k = int(torch.randint(0, 300, (1,), generator=gen))
        a_in = torch.randint(0, 60, (k,), generator=gen)
        a_out = a_in + torch.randint(1, 4, (k,), generator=gen)
        accepted = torch.rand(k, generator=gen) < 0.7
        want_c, want_n = _chain_clusters(accepted, a_in, a_out)
        capped_once = False
        for cap in (1, 5, 40, 10**9):
            got_c, got_n = chain_clusters(accepted, a_in, a_out, cap)
            assert got_c.dtype == torch.long and got_n.dtype == torch.float64
            assert torch.equal(got_c, want_c)
            exact = want_n < cap
            assert torch.equal(got_n[exact], want_n[exact])
            assert bool((got_n[~exact] >= cap).all())
            capped_once |= bool((~exact).any())
        assert k == 0 or capped_once

    @pytest.mark.parametrize("distinct", [1, 9, 70000])
    def test_stable_argsort_values_equals_numpy(self, distinct):
        from hocnet.hoc._incremental import _stable_argsort_values

        gen = torch.Generator().manual_seed(distinct)
        x = (torch.randint(0, distinct, (90000,), generator=gen).double() - 4) / 2
        x[::7] = -0.0  # -0.0 and 0.0 tie in both sorts
        x[::11] = 0.0
        x[::13] = math.nan
        x = x.numpy()
        assert np.array_equal(_stable_argsort_values(x), np.argsort(x, kind="stable"))

    @pytest.mark.parametrize("span", [1, 2, 3])
    @pytest.mark.parametrize("combine", ["min", "mean"])
    def test_score_paths_equals_per_path_scores(self, span, combine):
        from hocnet.hoc.identify import _score_paths
        from hocnet.hoc.scoring import track_point_scores

        gen = torch.Generator().manual_seed(span)
        n = 60
        coords = torch.stack(
            [
                torch.randint(0, 10, (n,), generator=gen),
                torch.randint(0, 30, (n,), generator=gen),
                torch.randint(0, 30, (n,), generator=gen),
            ],
            dim=1,
        )
        k = 80
        p0, p1, p2 = (torch.randint(0, n, (k,), generator=gen) for _ in range(3))
        s = torch.rand(k, generator=gen, dtype=torch.float64) * 4
        paths = [
            torch.randint(0, k, (int(torch.randint(1, 9, (1,), generator=gen)),), generator=gen)
            for _ in range(50)
        ]
        paths = [p.tolist() for p in paths]
        kw = {"A1": 9.0, "alpha1": 1 / 3, "A2": 2.12, "alpha2": 2.0, "combine": combine}
        for track_kw in (None, {**kw, "span": span}):
            got = _score_paths(paths, p0, p1, p2, s, coords, 4, track_kw)
            want = []
            for path in paths:
                pts = [int(p0[path[0]]), int(p1[path[0]])] + [int(p2[j]) for j in path]
                if len(pts) < 4:
                    continue
                if track_kw is None:
                    ps = [float(s[j]) for j in path]
                else:
                    ps = track_point_scores(coords[torch.tensor(pts)], **track_kw).tolist()
                want.append((float(torch.tensor(ps, dtype=torch.float64).mean()), pts, ps))
            assert got == want  # the same bits

    def test_point_score_same_bits_batched_or_alone(self):
        """Scoring many moves in one call equals scoring them a few at a time, bit for bit.

        The moves of ``score_span <= 2`` with ``v = 4``: components ``k / 2``, ``|k| <= 8``
        (every pair of such moves); what lets :func:`_score_paths` batch the paths.
        """
        from hocnet.hoc.scoring import point_score

        vals = torch.arange(-8, 9, dtype=torch.float64) / 2
        g = torch.cartesian_prod(vals, vals, vals, vals)
        for combine in ("min", "mean"):
            batched = point_score(g[:, 0], g[:, 1], g[:, 2], g[:, 3], combine=combine)
            alone = torch.cat(
                [
                    point_score(c[:, 0], c[:, 1], c[:, 2], c[:, 3], combine=combine)
                    for c in g.split(7)
                ]
            )
            assert torch.equal(batched, alone)

    def test_push_restores_the_garbage_collector(self):
        import gc

        det = StreamingDetector(window=5, stride=1, order=2)
        scan = torch.zeros(8, 8, dtype=torch.bool)
        assert gc.isenabled()
        det.push(scan)
        assert gc.isenabled()
        gc.disable()
        try:
            det.push(scan)
            assert not gc.isenabled()
        finally:
            gc.enable()
        with pytest.raises(ValueError, match="scan"):
            det.push(torch.zeros(9, 9, dtype=torch.bool))
        assert gc.isenabled()


def test_stride_larger_than_window_warns():
    with pytest.warns(UserWarning, match=r"`stride`: 20 is larger than `window` = 10: the 10 "):
        StreamingDetector(window=10, stride=20)
    import warnings as _warnings

    with _warnings.catch_warnings():
        _warnings.simplefilter("error", UserWarning)
        StreamingDetector(window=10, stride=10)  # adjacent windows: every scan in one


def test_push_of_an_empty_scan_reports_the_shape_given():
    # new-user finding: (0, 60) was reported as the (1, 0, 60) the validation built
    det = StreamingDetector(window=5, order=1)
    with pytest.raises(ValueError, match=r"`scan`: expected a non-empty scan, got shape \(0, 60\)"):
        det.push(torch.zeros(0, 60, dtype=torch.bool))

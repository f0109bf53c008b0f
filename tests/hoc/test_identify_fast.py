"""The helpers of hocnet.hoc._identify_fast against the identify.py code they stand for."""

import math
import random
import warnings
from types import SimpleNamespace

import pytest
import torch

from hocnet.hoc import _identify_fast as fast
from hocnet.hoc import identify as ident
from hocnet.hoc.functional import _allowed_cached, _sparse_triples

DELTA = math.pi / 4


def _scene(seed, n_t=8, size=24, density=0.05, v=3):
    """Triples of a random cube with a few straight tracks (so that chains pass)."""
    gen = torch.Generator().manual_seed(seed)
    cube = torch.rand(n_t, size, size, generator=gen) < density
    for _ in range(3):
        y, x = (int(c) for c in torch.randint(2, size - 2, (2,), generator=gen))
        dy, dx = (int(c) for c in torch.randint(-1, 2, (2,), generator=gen))
        for t in range(n_t):
            cube[t, (y + dy * t) % size, (x + dx * t) % size] = True
    flat, p0, p1, p2 = _sparse_triples(cube[None], _allowed_cached(v, DELTA, "cpu"), v, 1)
    h = w = size
    coords = torch.stack([flat // (h * w), (flat // w) % h, flat % w], dim=1)
    kw = ident._score_kwargs(9.0, 1 / 3, 2.12, 2.0, "min")
    s = ident._triple_scores(coords, p0, p1, p2, kw)
    a_in, a_out, *_ = ident._sequences(flat.numel(), p0, p1, p2, s)
    return flat, p0, p1, p2, s, a_in, a_out, coords, kw, gen


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("span", [2, 3])
def test_whole_sequences_from_rows(seed, span):
    _, p0, p1, p2, _, a_in, a_out, coords, kw, _ = _scene(seed)
    assert p0.numel() > 0
    track_kw = ident._track_kwargs(kw, span, None)
    want = ident._whole_sequences(a_in, a_out, p0, p1, p2, coords, track_kw)
    rows = ident._whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, track_kw)
    got = fast.whole_sequences_from_rows(rows, p0.numel())
    for g, w in zip(got, want, strict=True):
        assert torch.equal(g, w)


@pytest.mark.parametrize("seed", range(12))
def test_best_paths_equals_identify(seed):
    flat, p0, p1, p2, s, a_in, a_out, _, _, gen = _scene(seed, density=0.04 + 0.01 * seed)
    n = flat.numel()
    found = 0
    for threshold, min_points, n_t in ((2.5, 5, 8), (2.0, 4, 8), (2.8, 7, 8), (2.5, 5, 3)):
        for frac in (1.0, 0.3):
            points = torch.rand(n, generator=gen) < frac
            args = (n, p0, p1, p2, s, a_in, a_out, n_t, threshold, min_points, points)
            want = ident._best_paths(*args)
            assert fast.best_paths(*args) == want
            found += len(want)
    assert found > 0  # chains were found: the comparison is not vacuous


def test_best_paths_ties():
    """Many equal sums (integer scores): the first maximum in (lb, lf) order is kept."""
    for seed in range(6):
        flat, p0, p1, p2, s, a_in, a_out, *_ = _scene(seed, density=0.08)
        s = torch.full_like(s, 3.0)
        n = flat.numel()
        points = torch.ones(n, dtype=torch.bool)
        args = (n, p0, p1, p2, s, a_in, a_out, 8, 2.5, 5, points)
        want = ident._best_paths(*args)
        assert want
        assert fast.best_paths(*args) == want


def _random_tracks(rng, n_scans, per_scan):
    """A random track: one point per scan over a run of consecutive scans."""
    first = rng.randrange(0, n_scans - 2)
    last = rng.randrange(first + 2, n_scans)
    return [t * per_scan + rng.randrange(per_scan) for t in range(first, last + 1)]


@pytest.mark.parametrize("seed", range(30))
def test_near_duplicate_asks_only_tracks_sharing_a_point(seed):
    """`_is_near_duplicate` over every kept track == over those sharing a point."""
    rng = random.Random(seed)
    n_scans, per_scan = 8, 3
    n_pts = n_scans * per_scan
    scan_of = [q // per_scan for q in range(n_pts)]
    xy = [[q // per_scan, rng.randrange(6), rng.randrange(6)] for q in range(n_pts)]
    image = [rng.random() < 0.7 for _ in range(n_pts)]
    kept_pts = [_random_tracks(rng, n_scans, per_scan) for _ in range(rng.randrange(1, 6))]
    kept = [(pts, {scan_of[q]: i for i, q in enumerate(pts)}) for pts in kept_pts]
    kept_at: dict[int, list[int]] = {}
    for i, pts in enumerate(kept_pts):
        for q in pts:
            kept_at.setdefault(q, []).append(i)
    covered = {q for pts in kept_pts for q in pts} | {q for q in range(n_pts) if rng.random() < 0.1}
    answers = []
    for _ in range(60):
        if rng.random() < 0.7:  # a kept track with a few points changed: near-duplicates
            cand = list(rng.choice(kept_pts))
            for _ in range(rng.randrange(1, 3)):
                i = rng.randrange(len(cand))
                cand[i] = scan_of[cand[i]] * per_scan + rng.randrange(per_scan)
        else:
            cand = _random_tracks(rng, n_scans, per_scan)
        near = [kept[i] for i in fast.kept_sharing_a_point(cand, kept_at)]
        for max_diff in (1, 2, 3):
            for explained in (False, True):
                for residual in ident.RESIDUAL:
                    args = (scan_of, image, xy, max_diff, covered, explained, False, residual)
                    want = ident._is_near_duplicate(cand, kept, *args)
                    assert ident._is_near_duplicate(cand, near, *args) == want
                    answers.append(want)
    assert any(answers) and not all(answers)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("span", [None, 1, 2, 3])
def test_score_paths_passing(seed, span):
    _, p0, p1, p2, s, a_in, a_out, coords, kw, gen = _scene(seed, density=0.06)
    accepted = torch.rand(p0.numel(), generator=gen) < 0.7
    paths, _ = ident._enumerate_paths(accepted, a_in, a_out, s, 20000)
    track_kw = None if span is None else {**kw, "span": span}
    for threshold, min_points in ((2.5, 5), (2.0, 4), (-math.inf, 3)):
        every = ident._score_paths(paths, p0, p1, p2, s, coords, min_points, track_kw)
        want = [item for item in every if not item[0] < threshold]
        got = fast.score_paths_passing(
            paths, p0, p1, p2, s, coords, min_points, track_kw, threshold
        )
        assert got == want
        assert threshold > -math.inf or len(want) == len(every) > 0


def test_score_paths_passing_no_paths():
    empty = torch.zeros(0, dtype=torch.long)
    got = fast.score_paths_passing(
        [], empty, empty, empty, empty.double(), empty.reshape(0, 3), 5, None, 2.5
    )
    assert got == []


@pytest.mark.parametrize("seed", range(5))
def test_make_tracks_equals_make_track(seed):
    rng = random.Random(seed)
    coords = torch.randint(0, 50, (40, 3), generator=torch.Generator().manual_seed(seed))
    kept = []
    for _ in range(rng.randrange(0, 8)):
        pts = [rng.randrange(40) for _ in range(rng.randrange(3, 9))]
        pscores = [rng.uniform(-1, 4) for _ in range(len(pts) - 2)]
        kept.append((rng.uniform(2, 4), pts, pscores))
    got = fast.make_tracks(kept, coords, batch=seed)
    assert len(got) == len(kept)
    for tr, (score, pts, pscores) in zip(got, kept, strict=True):
        want, _ = ident._make_track(pts, pscores, coords, seed)
        want.score = score
        assert torch.equal(tr.points, want.points)
        assert torch.equal(tr.point_scores, want.point_scores)
        assert (tr.id, tr.score, tr.batch) == (want.id, want.score, want.batch)
        assert tr.points.dtype == want.points.dtype


def _unwired() -> SimpleNamespace:
    """The helpers replaced by the identify.py code they stand for (the loop references)."""

    def score_paths_passing(paths, p0, p1, p2, s, coords, min_points, track_kw, threshold):
        every = ident._score_paths(paths, p0, p1, p2, s, coords, min_points, track_kw)
        return [item for item in every if not item[0] < threshold]

    def kept_sharing_a_point(pts, kept_at):  # every kept track (each has points in kept_at)
        return sorted({i for tracks in kept_at.values() for i in tracks})

    def make_tracks(kept, coords, batch):
        out = []
        for score, pts, pscores in kept:
            track, _ = ident._make_track(pts, pscores, coords, batch)
            track.score = score
            out.append(track)
        return out

    def whole_sequences_from_rows(rows, k):
        c_idx, left_t, right_t, key_rows = rows
        best = ident._group_best_sorted(c_idx, key_rows, k)
        return left_t[best], right_t[best], key_rows[best]

    def unique_links(a_in, a_out, accepted):
        acc = [True] * a_in.numel() if accepted is None else accepted.tolist()
        return ident._accepted_links(a_in.tolist(), a_out.tolist(), acc)

    def beats_scorer(p0, p1, p2, s, coords, track_kw):
        return lambda path, scores: ident._beats(path, scores, p0, p1, p2, s, coords, track_kw)

    def path_points(paths, p0, p1, p2):
        a0, a1, a2 = p0.tolist(), p1.tolist(), p2.tolist()
        return [[a0[path[0]], a1[path[0]]] + [a2[k] for k in path] for path in paths]

    def mark_cleaned(cleaned, flat, point_lists):
        if point_lists:
            kept = torch.tensor([q for pts in point_lists for q in pts])
            cleaned[flat[kept]] = True

    return SimpleNamespace(
        mark_cleaned=mark_cleaned,
        path_points=path_points,
        unique_links=unique_links,
        extend_alone=ident._extend_alone,
        beats_scorer=beats_scorer,
        score_paths_passing=score_paths_passing,
        kept_sharing_a_point=kept_sharing_a_point,
        make_tracks=make_tracks,
        best_paths=ident._best_paths,
        pairs=ident._pairs,
        whole_sequences_from_rows=whole_sequences_from_rows,
        whole_sequence_rows=ident._whole_sequence_rows,
        fill_scores=ident._fill_scores,
        group_best=ident._group_best_sorted,
        short_track_sequences=ident._short_track_sequences,
    )


def _same_result(a: ident.HOCResult, b: ident.HOCResult) -> None:
    assert torch.equal(a.support, b.support) and torch.equal(a.cleaned, b.cleaned)
    assert torch.equal(a.scores.view(torch.int64), b.scores.view(torch.int64))  # the same bits
    assert (a.saturated, a.warnings) == (b.saturated, b.warnings)
    assert len(a.tracks) == len(b.tracks)
    for s, t in zip(a.tracks, b.tracks, strict=True):
        assert torch.equal(s.points, t.points) and s.points.dtype == t.points.dtype
        assert torch.equal(s.point_scores.view(torch.int64), t.point_scores.view(torch.int64))
        assert (s.score, s.id, s.batch) == (t.score, t.id, t.batch)


DETECT_SETTINGS = [
    {},
    {"support": "chain"},
    {"identify": "assignment"},
    {"score_span": 1, "shared_points": False, "dedupe": False, "track_ends": False},
    {"dedupe": 1},
    {"max_candidates": 40},
    {"residual": "two-point"},
    {"residual": "lsq"},
    {"residual": "both"},
]


@pytest.mark.parametrize("seed", range(4))
def test_detect_wired_equals_unwired(seed, monkeypatch):
    """`detect` with the helpers wired == with the identify.py code they replace."""
    from hocnet.data.binary import paper_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # density warnings, alike on both sides
        cube = paper_scene("table3-paper", 0.02 + 0.005 * seed, seed=seed).cube
        order = 2 + seed % 2
        wired = [ident.detect(cube, order=order, **kw) for kw in DETECT_SETTINGS]
        monkeypatch.setattr(ident, "_fast", _unwired())
        loop = [ident.detect(cube, order=order, **kw) for kw in DETECT_SETTINGS]
    for a, b in zip(wired, loop, strict=True):
        _same_result(a, b)
    assert sum(len(r.tracks) for r in wired) > 0  # tracks were found: not vacuous


@pytest.mark.parametrize("seed", range(8))
def test_pairs_equals_identify(seed):
    gen = torch.Generator().manual_seed(seed)
    for m, q, ids in ((50, 40, 10), (200, 300, 500), (0, 5, 3), (5, 0, 3), (0, 0, 1)):
        keys = torch.randint(0, ids, (m,), generator=gen)
        queries = torch.randint(0, ids, (q,), generator=gen)
        want = ident._pairs(keys, queries)
        got = fast.pairs(keys, queries)
        for g, w in zip(got, want, strict=True):
            assert torch.equal(g, w)
    *_, a_in, a_out, _, _, _ = _scene(seed)
    for keys, queries in ((a_out, a_in), (a_in, a_out)):
        want = ident._pairs(keys, queries)
        assert want[0].numel() > 0
        for g, w in zip(fast.pairs(keys, queries), want, strict=True):
            assert torch.equal(g, w)


KW_VARIANTS = [
    {"A1": 9.0, "alpha1": 1 / 3, "A2": 2.12, "alpha2": 2.0, "combine": "min"},
    {"A1": 9.0, "alpha1": 0.5, "A2": 2.356, "alpha2": 1.91, "combine": "mean"},
    {"A1": 7.0, "alpha1": 1 / 3, "A2": 2.12, "alpha2": 2.0, "combine": "sum"},
    {"A1": 9.0, "alpha1": 1 / 3, "A2": 2.12, "alpha2": 2.0, "combine": "movement"},
]


def _same_bits(a: torch.Tensor, b: torch.Tensor) -> bool:
    return a.dtype == b.dtype and torch.equal(a.view(torch.int64), b.view(torch.int64))


@pytest.mark.parametrize("kw", KW_VARIANTS)
def test_score_table_equals_point_score(kw):
    """Every half-pixel move pair read from the table == `point_score` called on it, bit for bit."""
    from hocnet.hoc.scoring import point_score

    gen = torch.Generator().manual_seed(0)
    h1 = torch.randint(-8, 9, (3000, 2), generator=gen)
    h2 = torch.randint(-8, 9, (3000, 2), generator=gen)
    got = fast.half_move_scores(h1.numpy(), h2.numpy(), kw)
    m1, m2 = h1.double() / 2, h2.double() / 2  # columns (y, x)
    want = point_score(m1[:, 1], m1[:, 0], m2[:, 1], m2[:, 0], **kw)
    assert _same_bits(torch.from_numpy(got), want)
    # one by one (no batch at all) as well
    for i in range(0, 3000, 150):
        one = point_score(m1[i, 1], m1[i, 0], m2[i, 1], m2[i, 0], **kw)
        assert float(one) == float(got[i])
    too_far = h1.numpy().copy()
    too_far[0, 0] = fast.TABLE_REACH + 1
    assert fast.half_move_scores(too_far, h2.numpy(), kw) is None  # the caller scores directly


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("v", [3, 9])  # v = 9: moves beyond the table, the reference runs
def test_whole_sequence_rows_equal_identify(seed, v):
    _, p0, p1, p2, _, a_in, a_out, coords, _, _ = _scene(seed, density=0.05, v=v, size=30)
    assert p0.numel() > 0
    for kw in KW_VARIANTS:
        for span in (1, 2, 3):
            track_kw = {**kw, "span": span}
            want = ident._whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, track_kw)
            got = fast.whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, track_kw)
            for g, w in zip(got[:3], want[:3], strict=True):
                assert torch.equal(g, w) and g.dtype == w.dtype
            assert _same_bits(got[3], want[3])


@pytest.mark.parametrize("seed", range(6))
def test_fill_scores_equals_identify(seed):
    flat, p0, p1, p2, s, *_ = _scene(seed, density=0.06)
    size = 8 * 24 * 24
    holes = s.clone()
    holes[::3] = math.nan  # NaN maxima are skipped: the next pass writes
    for values in (s, torch.full_like(s, 3.0), holes):  # ties too
        want = torch.full((size,), math.nan, dtype=torch.float64)
        got = want.clone()
        want[flat[:5]] = 1.5  # points already holding a score keep it
        got[flat[:5]] = 1.5
        ident._fill_scores(want, flat, p0, p1, p2, values)
        fast.fill_scores(got, flat, p0, p1, p2, values)
        assert _same_bits(got, want)


@pytest.mark.parametrize("seed", range(10))
def test_group_best_equals_identify(seed):
    gen = torch.Generator().manual_seed(seed)
    n = int(torch.randint(1, 60, (1,), generator=gen))
    groups = torch.randint(0, 40, (n,), generator=gen)
    for key in (
        torch.randint(0, 4, (n,), generator=gen).double(),  # many ties
        torch.rand(n, generator=gen, dtype=torch.float64),
        torch.where(torch.rand(n, generator=gen) < 0.3, -math.inf, 1.0).double(),
    ):
        want = ident._group_best_sorted(groups, key, 45)
        assert torch.equal(fast.group_best(groups, key, 45), want)
        assert torch.equal(ident._group_best(groups, key, 45), want)
    nan_key = torch.tensor([1.0, math.nan] * (n // 2) + [0.5] * (n % 2), dtype=torch.float64)
    assert torch.equal(fast.group_best(groups, nan_key, 45), ident._group_best(groups, nan_key, 45))
    empty = torch.zeros(0, dtype=torch.long)
    assert torch.equal(fast.group_best(empty, empty.double(), 3), torch.full((3,), -1))


@pytest.mark.parametrize("seed", range(6))
def test_short_track_sequences_equals_identify(seed):
    flat, p0, p1, p2, _, a_in, a_out, coords, kw, gen = _scene(seed, density=0.06)
    rows = ident._whole_sequence_rows(a_in, a_out, p0, p1, p2, coords, {**kw, "span": 2})
    for frac in (1.0, 0.7, 0.4):
        is_root = torch.rand(flat.numel(), generator=gen) < frac
        want = ident._short_track_sequences(rows, p0, p1, p2, is_root)
        got = fast.short_track_sequences(rows, p0, p1, p2, is_root)
        assert torch.equal(got, want)
    assert bool(want.any())


@pytest.mark.parametrize("seed", range(4))
def test_path_list_groups_hold_the_chains(seed):
    """`PathList.groups` are the chains of the list, per length, in list order."""
    _, p0, p1, p2, s, a_in, a_out, coords, _, gen = _scene(seed, density=0.06)
    accepted = torch.rand(p0.numel(), generator=gen) < 0.8
    paths, capped = ident._enumerate_paths(accepted, a_in, a_out, s, 20000)
    assert not capped and isinstance(paths, fast.PathList) and paths
    seen = {}
    for index, tri in paths.groups:
        assert list(index) == sorted(index)
        for i, row in zip(index.tolist(), tri.tolist(), strict=True):
            seen[i] = row
    assert [seen[i] for i in range(len(paths))] == list(paths)
    # the same scores from the plain list (groups rebuilt from the lists)
    for span in (None, 2, 3):
        kw = None if span is None else {**KW_VARIANTS[0], "span": span}
        args = (p0, p1, p2, s, coords, 4, kw, 2.0)
        got = fast.score_paths_passing(paths, *args)
        assert got == fast.score_paths_passing(list(paths), *args)
        assert got  # paths pass: the comparison is not vacuous


def test_best_paths_non_finite_scores_use_the_reference():
    flat, p0, p1, p2, s, a_in, a_out, *_ = _scene(1, density=0.08)
    n = flat.numel()
    points = torch.ones(n, dtype=torch.bool)
    for bad in (math.nan, math.inf):
        s2 = s.clone()
        s2[::7] = bad
        args = (n, p0, p1, p2, s2, a_in, a_out, 8, 2.5, 5, points)
        assert fast.best_paths(*args) == ident._best_paths(*args)


@pytest.mark.parametrize("seed", range(8))
def test_extend_alone_equals_identify(seed):
    """`extend_alone` on `unique_links` == `_extend_alone` on `_accepted_links`, every triple."""
    _, p0, _, p2, _, a_in, a_out, _, _, gen = _scene(seed, density=0.03 + 0.01 * (seed % 4))
    k = p0.numel()
    n = int(torch.maximum(p0.max(), p2.max())) + 1
    a0, a2 = p0.tolist(), p2.tolist()
    grown = 0
    for frac in (1.0, 0.6, 0.3):
        accepted = None if frac == 1.0 else torch.rand(k, generator=gen) < frac
        acc = [True] * k if accepted is None else accepted.tolist()
        ref_links = ident._accepted_links(a_in.tolist(), a_out.tolist(), acc)
        links = fast.unique_links(a_in, a_out, accepted)
        root = (torch.rand(n, generator=gen) < 0.8).tolist()
        on_tracks = torch.randperm(n, generator=gen)[: n // 10].tolist()
        point_tracks = {q: [0] for q in on_tracks}
        for j in range(k):
            want = ident._extend_alone([j], ref_links, a0, a2, root, point_tracks)
            assert fast.extend_alone([j], links, a0, a2, root, point_tracks) == want
            grown += len(want) > 1
    assert grown > 0  # tracks were extended: not vacuous


def test_unique_links_empty_and_none():
    empty = torch.zeros(0, dtype=torch.long)
    assert [x.tolist() for x in fast.unique_links(empty, empty, None)] == [[], []]
    a_in, a_out = torch.tensor([0, 1, 1]), torch.tensor([1, 2, 3])
    none = torch.zeros(3, dtype=torch.bool)
    assert [x.tolist() for x in fast.unique_links(a_in, a_out, none)] == [[-1] * 3] * 2


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("span", [None, 1, 2, 3])
def test_beats_scorer_equals_identify(seed, span):
    """The same answers as `_beats`, at the path's own score (the same bits) and around it."""
    _, p0, p1, p2, s, a_in, a_out, coords, kw, gen = _scene(seed, density=0.06)
    accepted = torch.rand(p0.numel(), generator=gen) < 0.7
    paths, _ = ident._enumerate_paths(accepted, a_in, a_out, s, 20000)
    track_kw = None if span is None else {**kw, "span": span}
    beats = fast.beats_scorer(p0, p1, p2, s, coords, track_kw)
    answers = []
    for path in list(paths)[:200]:
        [(score, _, _)] = ident._score_paths([path], p0, p1, p2, s, coords, 0, track_kw)
        below = math.nextafter(score, -math.inf)
        for rivals in ([], [score], [below], [below, score], [score - 1.0, below]):
            want = ident._beats(path, rivals, p0, p1, p2, s, coords, track_kw)
            assert beats(path, rivals) == want
            answers.append(want)
    assert any(answers) and not all(answers)


@pytest.mark.parametrize("seed", range(3))
def test_path_list_is_lazy_and_adds_as_a_list(seed):
    """A PathList equals its plain list before and after `+`, and `+` keeps the groups."""
    _, p0, p1, p2, s, a_in, a_out, coords, _, gen = _scene(seed, density=0.06)
    accepted = torch.rand(p0.numel(), generator=gen) < 0.8
    paths, _ = ident._enumerate_paths(accepted, a_in, a_out, s, 20000)
    assert isinstance(paths, fast.PathList) and paths._rows is None  # nothing built yet
    plain = ident._enumerate_paths_loop(accepted, a_in, a_out, s, 20000)[0]
    assert len(paths) == len(plain) > 2
    tail, nothing = plain[:2], []
    for other in (tail, fast.PathList(tail, fast._path_groups(tail)), []):
        joined = paths + other
        assert isinstance(joined, fast.PathList) and joined == plain + list(other)
        assert nothing + joined == plain + list(other) and list(joined) == plain + list(other)
        args = (p0, p1, p2, s, coords, 4, None, 2.0)
        got = fast.score_paths_passing(joined, *args)
        assert got == fast.score_paths_passing(plain + list(other), *args) and got
    assert paths == plain and paths[0] == plain[0] and paths != plain[1:]


@pytest.mark.parametrize("seed", range(4))
def test_path_points_equals_the_loop(seed):
    _, p0, p1, p2, s, a_in, a_out, _, _, gen = _scene(seed, density=0.06)
    accepted = torch.rand(p0.numel(), generator=gen) < 0.8
    paths = list(ident._enumerate_paths(accepted, a_in, a_out, s, 20000)[0])
    assert len(paths) > 1
    a0, a1, a2 = p0.tolist(), p1.tolist(), p2.tolist()
    want = [[a0[c[0]], a1[c[0]]] + [a2[k] for k in c] for c in paths]
    got = fast.path_points(paths, p0, p1, p2)
    assert got == want and all(type(q) is int for q in got[0])
    assert fast.path_points([], p0, p1, p2) == []


def test_mark_cleaned_equals_indexing():
    gen = torch.Generator().manual_seed(0)
    flat = torch.randperm(500, generator=gen)[:120].sort().values
    lists = [torch.randint(0, 120, (int(n),), generator=gen).tolist() for n in (5, 7, 0, 3)]
    want = torch.zeros(500, dtype=torch.bool)
    want[flat[torch.tensor([q for pts in lists for q in pts])]] = True
    got = torch.zeros(500, dtype=torch.bool)
    fast.mark_cleaned(got, flat, lists)
    assert torch.equal(got, want) and bool(want.any())
    strided = torch.zeros(1000, dtype=torch.bool)[::2]  # a view: the torch indexing path
    fast.mark_cleaned(strided, flat, lists)
    assert torch.equal(strided, want)
    fast.mark_cleaned(got, flat, [[], []])  # nothing to mark
    assert torch.equal(got, want)

import tracemalloc

import pytest
import torch

from hocnet.data.binary import paper_scene
from hocnet.hoc import StreamingDetector, detect


def _same(a, b):
    return (
        torch.equal(a.support, b.support)
        and torch.equal(a.cleaned, b.cleaned)
        and [t.points.tolist() for t in a.tracks] == [t.points.tolist() for t in b.tracks]
        and [t.score for t in a.tracks] == pytest.approx([t.score for t in b.tracks])
    )


class TestStreamingDetector:
    @pytest.mark.parametrize("seed", range(3))
    @pytest.mark.parametrize(("window", "stride", "order"), [(10, 2, 2), (7, 1, 3), (9, 3, 1)])
    def test_equals_batch_on_every_window(self, seed, window, stride, order):
        scene = paper_scene("fig5", 0.012, seed=seed)
        det = StreamingDetector(window=window, stride=stride, order=order)
        windows = 0
        for t in range(scene.cube.shape[0]):
            out = det.push(scene.cube[t])
            if out is None:
                continue
            windows += 1
            assert out.stop - out.start == window
            batch = detect(scene.cube[out.start : out.stop], order=order)
            assert _same(out.result, batch)
        assert windows == (16 - window) // stride + 1

    def test_paper_windows(self):
        scene = paper_scene("fig5", 0.0, seed=0)
        det = StreamingDetector(window=10, stride=2, order=2)
        spans = []
        for t in range(16):
            out = det.push(scene.cube[t])
            if out is not None:
                spans.append((out.start + 1, out.stop))  # 1-based as in the paper
        assert spans == [(1, 10), (3, 12), (5, 14), (7, 16)]

    def test_ids_persist_across_windows(self):
        cube = torch.zeros(14, 16, 40, dtype=torch.bool)
        for t in range(14):
            cube[t, 8, 2 + 2 * t] = True
        det = StreamingDetector(window=8, stride=2, order=2)
        ids = [out.tracks[0].id for t in range(14) if (out := det.push(cube[t])) is not None]
        assert len(ids) == 4 and set(ids) == {1}

    def test_absolute_scan_numbers(self):
        cube = torch.zeros(10, 8, 30, dtype=torch.bool)
        for t in range(10):
            cube[t, 4, 1 + 2 * t] = True
        det = StreamingDetector(window=6, stride=4, order=2)
        outs = [o for t in range(10) if (o := det.push(cube[t])) is not None]
        assert outs[-1].start == 4
        assert outs[-1].tracks[0].points[0, 0].item() == 4
        assert outs[-1].result.tracks[0].points[0, 0].item() == 0

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
        run(9000)
        second, _ = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert det.pushed == 10_000
        assert len(det._fwd[0]) == 10
        assert second - first < 64 * 1024  # no growth with the number of pushed scans

    def test_errors(self):
        with pytest.raises(ValueError, match="`window`"):
            StreamingDetector(window=4, order=2)
        with pytest.raises(ValueError, match="`stride`"):
            StreamingDetector(stride=0)
        det = StreamingDetector(window=5, order=2)
        det.push(torch.zeros(6, 6))
        with pytest.raises(ValueError, match="`scan`: expected shape"):
            det.push(torch.zeros(7, 6))
        with pytest.raises(ValueError, match="`scan`"):
            det.push(torch.full((6, 6), 0.5))

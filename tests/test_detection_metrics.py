import math

import pytest
import torch

from hocnet.detection_metrics import (
    detect_peaks,
    pd_at_fa,
    read_detections,
    roc_auc,
    roc_curve,
    write_detections,
)

# ----------------------------------------------------------------------------- loop references


def expected_peaks(scores, radius, max_per_frame, threshold=None):
    """Plain loops: window maximum with the lower-row-major tie rule, then the top scores."""
    t, h, w = scores.shape
    out = []
    for f in range(t):
        cands = []
        for y in range(h):
            for x in range(w):
                v = float(scores[f, y, x])
                if threshold is not None and not v > threshold:
                    continue
                ok = True
                for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                    for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                        u = float(scores[f, yy, xx])
                        if u > v or (u == v and yy * w + xx < y * w + x):
                            ok = False
                if ok:
                    cands.append((-v, y * w + x, [f, x, y, v]))
        cands.sort(key=lambda c: (c[0], c[1]))
        out.extend(c[2] for c in cands[:max_per_frame])
    return torch.tensor(out, dtype=torch.float64).reshape(-1, 4)


def expected_roc(det, truth, frames, radius):
    """Threshold by threshold: count detected frames and false alarms directly."""
    det = [d for d in det.tolist() if int(d[0]) in frames]
    thresholds = [math.inf, *sorted({d[3] for d in det}, reverse=True)]
    targets = [f for f in frames if not math.isnan(truth[f][0])]
    pds, fas = [], []
    for tau in thresholds:
        detected = set()
        fa = 0
        for f, x, y, s in det:
            if s < tau:
                continue
            tx, ty = truth[int(f)]
            if not math.isnan(tx) and math.hypot(x - tx, y - ty) <= radius:
                detected.add(int(f))
            else:
                fa += 1
        pds.append(len(detected) / len(targets))
        fas.append(fa / len(frames))
    return thresholds, pds, fas


# ----------------------------------------------------------------------------- detect_peaks


class TestDetectPeaks:
    def test_hand_case(self):
        s = torch.zeros(1, 5, 6)
        s[0, 1, 1] = 5.0  # peak
        s[0, 1, 2] = 4.0  # suppressed by (1, 1)
        s[0, 4, 5] = 3.0  # corner peak
        s[0, 3, 4] = 3.0  # ties with (4, 5) at distance 1: lower row-major index wins
        got = detect_peaks(s, radius=1, max_per_frame=10, threshold=0.0)
        assert got.shape == (2, 4)
        assert got[0].tolist() == [0.0, 1.0, 1.0, 5.0]
        assert got[1].tolist() == [0.0, 4.0, 3.0, 3.0]  # x = column 4, y = row 3
        assert [0.0, 5.0, 4.0, 3.0] not in got.tolist()

    @pytest.mark.parametrize("radius", [0, 1, 2, 3])
    @pytest.mark.parametrize("seed", [0, 1])
    def test_reference(self, radius, seed):
        g = torch.Generator().manual_seed(seed)
        s = torch.randint(0, 6, (3, 7, 8), generator=g).double()  # many ties
        got = detect_peaks(s, radius=radius, max_per_frame=5)
        torch.testing.assert_close(got, expected_peaks(s, radius, 5))

    def test_threshold_and_cap(self):
        s = torch.rand(2, 9, 9, generator=torch.Generator().manual_seed(3))
        got = detect_peaks(s, radius=1, max_per_frame=2, threshold=0.5)
        torch.testing.assert_close(got, expected_peaks(s, 1, 2, 0.5))
        assert (got[:, 3] > 0.5).all()

    def test_batched(self):
        s = torch.rand(2, 3, 6, 6)
        got = detect_peaks(s)
        assert isinstance(got, list) and len(got) == 2
        torch.testing.assert_close(got[1], detect_peaks(s[1]))

    def test_empty(self):
        assert detect_peaks(torch.zeros(0, 4, 4)).shape == (0, 4)
        assert detect_peaks(torch.zeros(3, 4, 4), threshold=1.0).shape == (0, 4)

    def test_errors(self):
        with pytest.raises(ValueError, match="`max_per_frame`: expected an integer >= 1"):
            detect_peaks(torch.zeros(1, 4, 4), max_per_frame=0)
        with pytest.raises(ValueError, match="`scores`: expected shape"):
            detect_peaks(torch.zeros(4, 4))


# ----------------------------------------------------------------------------- ROC


class TestRoc:
    def test_hand_case(self):
        # frame 0: a hit (score 3) and a false alarm (2); frame 1: a false alarm (4), a hit (1);
        # frame 2: no target (NaN truth): its detection (5) is a false alarm.
        det = torch.tensor(
            [[0, 5, 5, 3.0], [0, 1, 1, 2.0], [1, 9, 9, 4.0], [1, 7, 6, 1.0], [2, 5, 5, 5.0]]
        )
        truth = torch.tensor([[5.0, 5.0], [5.0, 5.0], [math.nan, math.nan]])
        roc = roc_curve(det, truth, frame_shape=(10, 10))
        assert roc.thresholds.tolist() == [math.inf, 5.0, 4.0, 3.0, 2.0, 1.0]
        assert roc.pd.tolist() == [0.0, 0.0, 0.0, 0.5, 0.5, 1.0]  # (7, 6) is 2.24 px away
        assert roc.fa_per_frame.tolist() == [0.0, 1 / 3, 2 / 3, 2 / 3, 1.0, 1.0]
        torch.testing.assert_close(roc.fa_per_pixel, roc.fa_per_frame / 100)
        assert (roc.n_frames, roc.n_target_frames) == (3, 2)
        assert pd_at_fa(roc, 1.0) == 1.0
        assert pd_at_fa(roc, 0.9) == 0.5
        assert pd_at_fa(roc, 0.5) == 0.0
        # Pd(x) = 0 on [0, 2/3), 0.5 on [2/3, 1), 1 at 1: area 0.5 / 3
        assert roc_auc(roc, 1.0) == pytest.approx(0.5 / 3)
        assert roc_auc(roc, 2.0) == pytest.approx((0.5 / 3 + 1.0) / 2)

    def test_hit_radius_and_frames(self):
        det = torch.tensor([[0, 8, 5, 1.0], [1, 0, 0, 1.0], [2, 5, 5, 1.0]])
        truth = torch.tensor([[5.0, 5.0]] * 3)
        assert pd_at_fa(roc_curve(det, truth, hit_radius=3.0), 10) == pytest.approx(2 / 3)
        assert pd_at_fa(roc_curve(det, truth, hit_radius=2.9), 10) == pytest.approx(1 / 3)
        roc = roc_curve(det, truth, frames=[1, 2])
        assert roc.n_frames == 2 and roc.fa_per_frame[-1] == 0.5 and roc.pd[-1] == 0.5

    def test_duplicate_hits_not_false_alarms(self):
        det = torch.tensor([[0, 5, 5, 2.0], [0, 6, 5, 1.0]])
        roc = roc_curve(det, torch.tensor([[5.0, 5.0]]))
        assert roc.fa_per_frame.max() == 0 and roc.pd[-1] == 1.0

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_reference(self, seed):
        g = torch.Generator().manual_seed(seed)
        scores = torch.rand(6, 12, 12, generator=g)
        truth = torch.randint(0, 12, (6, 2), generator=g).double()
        truth[4] = math.nan
        det = detect_peaks(scores, radius=1, max_per_frame=6)
        frames = [1, 2, 3, 4, 5]
        roc = roc_curve(det, truth, frames=frames, hit_radius=2.0)
        thresholds, pds, fas = expected_roc(det, truth.tolist(), frames, 2.0)
        assert roc.thresholds.tolist() == thresholds
        torch.testing.assert_close(roc.pd, torch.tensor(pds, dtype=torch.float64))
        torch.testing.assert_close(roc.fa_per_frame, torch.tensor(fas, dtype=torch.float64))

    def test_no_detections(self):
        roc = roc_curve(torch.zeros(0, 4), torch.tensor([[1.0, 1.0]]))
        assert roc.pd.tolist() == [0.0] and pd_at_fa(roc) == 0.0 and roc_auc(roc) == 0.0

    def test_errors(self):
        truth = torch.zeros(2, 2)
        with pytest.raises(ValueError, match=r"`detections`: expected shape \(N, 4\)"):
            roc_curve(torch.zeros(3, 3), truth)
        with pytest.raises(ValueError, match="`truth_xy`: expected shape"):
            roc_curve(torch.zeros(1, 4), torch.zeros(2, 3))
        with pytest.raises(ValueError, match=r"`frames`: expected frame indices in 0 \.\. 1"):
            roc_curve(torch.zeros(1, 4), truth, frames=[0, 2])
        with pytest.raises(ValueError, match="`hit_radius`"):
            roc_curve(torch.zeros(1, 4), truth, hit_radius=-1)
        with pytest.raises(ValueError, match="integer frame"):
            roc_curve(torch.tensor([[0.5, 0, 0, 1]]), truth)


# ----------------------------------------------------------------------------- files


class TestDetectionsCsv:
    def test_round_trip(self, tmp_path):
        det = torch.tensor([[0, 3, 1, 2.5], [1, 0, 7, -0.1], [1, 2, 2, 1 / 3]], dtype=torch.float64)
        path = write_detections(tmp_path / "detections.csv", det)
        lines = path.read_text().splitlines()
        assert lines[0] == "frame,x,y,score" and lines[1] == "0,3,1,2.5"
        torch.testing.assert_close(read_detections(path), det, rtol=0, atol=0)
        assert [p.name for p in tmp_path.iterdir()] == ["detections.csv"]  # no temp file left

    def test_never_overwrites_unless_asked(self, tmp_path):
        path = tmp_path / "detections.csv"
        path.write_text("input\n")
        with pytest.raises(FileExistsError, match="existing"):
            write_detections(path, torch.zeros(0, 4))
        assert path.read_text() == "input\n"
        write_detections(path, torch.zeros(0, 4), overwrite=True)
        assert read_detections(path).shape == (0, 4)

    def test_file_mode_follows_the_umask(self, tmp_path):
        # new-user finding: a tempfile.mkstemp file kept mode 0600 after the rename
        import os

        old = os.umask(0o022)
        try:
            path = write_detections(tmp_path / "detections.csv", torch.zeros(0, 4))
        finally:
            os.umask(old)
        assert path.stat().st_mode & 0o777 == 0o644

    def test_read_errors(self, tmp_path):
        bad_header = tmp_path / "a.csv"
        bad_header.write_text("frame,x,y\n0,1,2\n")
        with pytest.raises(ValueError, match="header"):
            read_detections(bad_header)
        bad_value = tmp_path / "b.csv"
        bad_value.write_text("frame,x,y,score\n0,1,2,abc\n")
        with pytest.raises(ValueError, match=r"line 2 of .*b\.csv"):
            read_detections(bad_value)


# ----------------------------------------------------------------------------- issue 10 additions


class TestMask:
    @pytest.mark.parametrize("seed", [0, 1])
    def test_reference(self, seed):
        g = torch.Generator().manual_seed(seed)
        scores = torch.randn(3, 9, 10, generator=g, dtype=torch.float64)
        mask = torch.rand(3, 9, 10, generator=g) < 0.3
        # NaN outside the mask is allowed: those pixels are ignored
        got = detect_peaks(scores.masked_fill(~mask, math.nan), radius=1, mask=mask)
        # loop reference: the masked-out pixels take no part (as -inf), then only mask pixels
        ref = expected_peaks(scores.masked_fill(~mask, -math.inf), 1, 50)
        ref = ref[torch.isfinite(ref[:, 3])]
        assert got.tolist() == ref.tolist()
        for f, x, y, _ in got.tolist():
            assert mask[int(f), int(y), int(x)]

    def test_batched_and_errors(self):
        scores = torch.zeros(2, 2, 4, 4)
        mask = torch.zeros(2, 2, 4, 4, dtype=torch.bool)
        mask[1, 0, 2, 3] = True
        scores[1, 0, 2, 3] = 5.0
        out = detect_peaks(scores, mask=mask)
        assert [d.tolist() for d in out] == [[], [[0.0, 3.0, 2.0, 5.0]]]
        with pytest.raises(ValueError, match="`mask`: expected the shape"):
            detect_peaks(scores, mask=mask[0])
        with pytest.raises(TypeError, match="`mask`"):
            detect_peaks(scores, mask=mask.float())


class TestPerPixel:
    def test_pd_at_fa_per_pixel(self):
        det = torch.tensor([[0, 5, 5, 3.0], [0, 1, 1, 2.0], [1, 9, 9, 4.0], [1, 6, 5, 1.0]])
        truth = torch.tensor([[5.0, 5.0], [5.0, 5.0]])
        roc = roc_curve(det, truth, frame_shape=(10, 10))
        # 1 false alarm per frame = 0.01 per pixel on 10 x 10 frames
        for fa in (0.0, 0.5, 1.0):
            assert pd_at_fa(roc, fa / 100, per="pixel") == pd_at_fa(roc, fa)
        with pytest.raises(ValueError, match="`per`"):
            pd_at_fa(roc, 1.0, per="scan")
        with pytest.raises(ValueError, match="frame_shape"):
            pd_at_fa(roc_curve(det, truth), 0.01, per="pixel")


def test_hocnet_metrics_reexports():
    import hocnet.detection_metrics as dm
    import hocnet.metrics as m

    assert m.detect_peaks is dm.detect_peaks and m.pd_at_fa is dm.pd_at_fa
    assert m.roc_auc is dm.roc_auc and m.detection_roc_curve is dm.roc_curve
    assert m.DetectionROC is dm.ROC
    assert m.write_detections is dm.write_detections and m.read_detections is dm.read_detections
    # the default hit radius is 3 pixels
    det = torch.tensor([[0, 3, 0, 1.0], [1, 4, 0, 1.0]], dtype=torch.float64)
    roc = m.detection_roc_curve(det, torch.zeros(2, 2))
    assert m.pd_at_fa(roc, 0.5) == 0.5

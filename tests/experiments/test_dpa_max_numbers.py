"""Smoke and unit tests of experiments/dpa_max_numbers.py (A_S versus Max_Numbers, issue 8)."""

import math
import pathlib
import shutil
import sys

import pytest
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import load_script, quick_run_watched, read_rows, results_snapshot


@pytest.fixture(scope="module")
def mn():
    return load_script("dpa_max_numbers.py")


@pytest.fixture(scope="module")
def quick_run(mn, tmp_path_factory):
    """One ``--quick`` run into a temporary ``--out``, with the results folder watched."""
    return quick_run_watched(mn, tmp_path_factory.mktemp("dpa-max-numbers"))


def test_interface(mn):
    assert mn.NAME == "dpa-max-numbers"
    assert isinstance(mn.DESCRIPTION, str) and mn.DESCRIPTION
    assert callable(mn.run) and callable(mn.main)
    assert mn.B == {0.0: 4.8, 1.0: 0.8} and mn.BLOCK == (30, 80) and mn.STEP == 4


def test_scene_is_the_na23a_s4_geometry(mn):
    frames, truth = mn.scene(mn.Setting("pixel", 13.0, 0.0, jitter=0.0), 0)
    assert tuple(frames.shape) == (25, 90, 240)
    steps = truth[1:] - truth[:-1]  # 1.2 px/frame right to left, no jitter
    assert torch.allclose(steps, torch.tensor([-1.2, 0.0], dtype=torch.float64).expand_as(steps))
    assert truth[0].tolist() == [120.0, 45.0]


def _summary_loop(curves):
    """Obviously-correct summary: means, standard errors, argmax, paired margins."""
    n = len(curves)
    cols = list(zip(*curves, strict=True))
    mean = [sum(c) / n for c in cols]

    def se(values):
        m = sum(values) / n
        return math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1) / n)

    d32 = [c[2] - c[1] for c in curves]
    d34 = [c[2] - c[3] for c in curves]
    return {
        "mean": mean,
        "se": [se(c) for c in cols],
        "argmax": mean.index(max(mean)) + 1,
        "d32": sum(d32) / n,
        "se_d32": se(d32),
        "d34": sum(d34) / n,
        "se_d34": se(d34),
        "seeds_at_3": sum(c.index(max(c)) == 2 for c in curves),
    }


def test_summarise_matches_loop(mn):
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        curves = torch.rand(6, 7, generator=gen, dtype=torch.float64) * 10
        got, ref = mn.summarise(curves), _summary_loop(curves.tolist())
        assert got["argmax"] == ref["argmax"] and got["seeds_at_3"] == ref["seeds_at_3"]
        for key in ("d32", "se_d32", "d34", "se_d34"):
            assert got[key] == pytest.approx(ref[key], rel=1e-12), key
        assert got["mean"] == pytest.approx(ref["mean"], rel=1e-12)
        assert got["se"] == pytest.approx(ref["se"], rel=1e-12)
        want = ref["argmax"] == 3 and ref["d32"] > ref["se_d32"] and ref["d34"] > ref["se_d34"]
        assert mn.peaks_at_three(got) == want


def test_above_ntb_counts_pixels_over_the_other_blocks(mn):
    truth = torch.tensor([[120.0, 45.0], [119.0, 45.0]], dtype=torch.float64)
    asf = torch.zeros(2, 90, 240)
    asf[:, 70, 10] = 5.0  # the highest pixel outside the target block (rows 30-59, cols 80-159)
    asf[-1, 45, 119], asf[-1, 45, 120], asf[-1, 44, 119] = 9.0, 6.0, 5.0  # 5 is not above
    assert mn.above_ntb(asf, truth, last=1) == 2.0
    assert mn.above_ntb(asf, truth, last=2) == 1.0  # frame 0: nothing above 5


def test_quick_run_writes_md_and_csv_only_into_out(mn, quick_run):
    md, out, before, after = quick_run
    assert md == out / "dpa-max-numbers.md"
    assert sorted(p.name for p in out.iterdir()) == ["dpa-max-numbers.csv", "dpa-max-numbers.md"]
    assert before == after  # nothing written into experiments/results
    rows = read_rows(out / "dpa-max-numbers.csv")
    assert [(r["signature"], float(r["snr"]), float(r["g"])) for r in rows] == [
        (s.signature, s.snr, s.g) for s in mn.settings(quick=True)
    ]
    text = md.read_text()
    assert "quick (smoke) run, 2 seeded scenes" in text
    for row in rows:
        means = [float(row[f"a_s_mn{m}"]) for m in mn.MAX_NUMBERS]
        assert int(row["argmax"]) == means.index(max(means)) + 1
        assert f"**{means[int(row['argmax']) - 1]:.2f} ± " in text
        assert len(row["argmax_per_frame"].split()) == mn.LAST
    assert "## Noise-free footprint" in text and "| 4 | 1.2 | 4.8 | 1.00 |" in text


def test_quick_without_out_uses_a_temporary_folder(mn, monkeypatch):
    results = sys.modules["_expkit"].RESULTS_DIR
    before = results_snapshot(results)
    monkeypatch.setattr(mn, "settings", lambda quick: [mn.Setting("pixel", 13.0, 1.0)])
    md = mn.main(["--quick", "--no-progress", "--seeds", "1"])
    try:
        assert results not in md.parents and md.is_file()
        assert results_snapshot(results) == before
        assert len(read_rows(md.with_suffix(".csv"))) == 1
    finally:
        shutil.rmtree(md.parent)

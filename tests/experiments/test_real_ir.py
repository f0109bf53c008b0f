import pathlib
import sys

import pytest
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import load_script, read_rows

real_ir = load_script("real_ir.py")


def test_skipped_without_data(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(real_ir, "DATA_DIR", tmp_path / "absent")
    assert real_ir.run(quick=True, out_dir=tmp_path / "out", progress=False) is None
    assert "skipped" in capsys.readouterr().out
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not real_ir.DATA_DIR.is_dir(), reason="real-ir data folder absent")
def test_quick_run(tmp_path):
    md = real_ir.run(quick=True, out_dir=tmp_path, progress=False)
    assert md == tmp_path / "real-ir.md"
    for name in ("real-ir.csv", "real-ir.png", "real-ir-clips.png"):
        assert (tmp_path / name).stat().st_size > 0
    rows = read_rows(tmp_path / "real-ir.csv")
    assert {r["method"] for r in rows} == set(real_ir.METHODS)
    assert {r["clip"] for r in rows} == set(real_ir.QUICK_CLIPS)
    assert all(0.0 <= float(r["pd_at_1fa"]) <= 1.0 for r in rows)
    text = md.read_text()
    assert "Science Data Bank" in text
    for name in ("DPA (paper)", "DPA (ours)", "HOC", "HOC support + intensity"):
        assert f"| {name} " in text or f"| {name} |" in text, name
    assert "share the clip's top HOC point score" in text


@pytest.mark.skipif(not real_ir.DATA_DIR.is_dir(), reason="real-ir data folder absent")
def test_quick_never_writes_results(monkeypatch, tmp_path):
    monkeypatch.setattr(real_ir.C, "RESULTS_DIR", tmp_path / "results")
    monkeypatch.setattr(real_ir, "CLIPS", ("seq01",))
    monkeypatch.setattr(real_ir, "QUICK_CLIPS", ("seq01",))
    monkeypatch.setattr(real_ir, "QUICK_FRAMES", 12)
    md = real_ir.run(quick=True, progress=False, methods={"single-frame": real_ir.single_frame})
    assert md is not None and md.is_file()
    assert not (tmp_path / "results").exists()


def _synthetic_clip(n: int = 16, size: int = 40):
    """Still textured ground, noise and a bright target moving 0.5 px/frame; truth (x, y)."""
    g = torch.Generator().manual_seed(0)
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    ground = 20 * torch.sin(xx / 3.0) * torch.cos(yy / 4.0)
    ground = ground + 15 * (torch.rand(size, size, generator=g) > 0.9)  # broadband, still
    frames = 60.0 + ground + 2.0 * torch.randn(n, size, size, generator=g)
    truth = torch.zeros(n, 2, dtype=torch.float64)
    for t in range(n):
        x = 10 + t // 2
        frames[t, 20, x] += 40.0
        truth[t] = torch.tensor([x, 20.0])
    return frames, truth


def test_methods_on_a_synthetic_clip(monkeypatch):
    # every method maps (T, H, W) frames to scores (or scores + mask) that evaluate_clip scores
    monkeypatch.setattr(real_ir, "FIRST_FRAME", 4)
    frames, truth = _synthetic_clip()
    results = real_ir.evaluate_clip(frames, truth, real_ir.METHODS)
    assert set(results) == set(real_ir.METHODS)
    for name in ("pre-processed", "DPA (ours)", "HOC support + intensity"):
        assert results[name]["pd"] == 1.0, name
    # only support points can be HOC detections
    scores, mask = real_ir.hoc_pipeline(frames)
    for f, x, y, s in results["HOC"]["detections"].tolist():
        assert mask[int(f), int(y), int(x)] and s == pytest.approx(
            float(scores[int(f), int(y), int(x)])
        )


def test_dpa_methods_are_the_presets():
    from hocnet.dpa.presets import PAPER, RECOMMENDED, run_preset

    frames, _ = _synthetic_clip(n=6)
    assert torch.equal(real_ir.dpa_paper(frames), run_preset(frames, PAPER).asf)
    assert torch.equal(real_ir.dpa_ours(frames), run_preset(frames, RECOMMENDED).asf)

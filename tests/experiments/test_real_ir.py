import pathlib
import sys

import pytest

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
    assert "Science Data Bank" in md.read_text()


@pytest.mark.skipif(not real_ir.DATA_DIR.is_dir(), reason="real-ir data folder absent")
def test_quick_never_writes_results(monkeypatch, tmp_path):
    monkeypatch.setattr(real_ir.C, "RESULTS_DIR", tmp_path / "results")
    monkeypatch.setattr(real_ir, "CLIPS", ("seq01",))
    monkeypatch.setattr(real_ir, "QUICK_CLIPS", ("seq01",))
    monkeypatch.setattr(real_ir, "QUICK_FRAMES", 12)
    md = real_ir.run(quick=True, progress=False, methods={"single-frame": real_ir.single_frame})
    assert md is not None and md.is_file()
    assert not (tmp_path / "results").exists()

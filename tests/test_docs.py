"""The scripts under docs/ run: docs/dpa_figure3.py draws Figure 3 of [NR08] (to a tmp path)."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
FIGURE3 = ROOT / "docs" / "dpa_figure3.py"
COMMITTED = ROOT / "docs" / "images" / "dpa_figure3.png"


def load_figure3():
    spec = importlib.util.spec_from_file_location("dpa_figure3", FIGURE3)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_figure3_script_draws_to_the_given_path(tmp_path):
    before = COMMITTED.read_bytes() if COMMITTED.exists() else None
    out = tmp_path / "sub" / "figure3.png"
    done = subprocess.run(
        [sys.executable, str(FIGURE3), str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000
    if before is not None:  # the committed picture is left alone
        assert COMMITTED.read_bytes() == before


def test_border_effect_follows_the_matrices():
    module = load_figure3()
    variants = module.border_variants()
    ours, zeroed = variants["ours"], variants["zeroed"]
    ring = torch.ones(7, 7, dtype=torch.bool)
    ring[1:-1, 1:-1] = False
    # eq. (5) as printed: the border keeps W_basic's tail (p W_basic in directions 1-8)
    assert bool((ours[:, ring] > 0).all()) and bool((zeroed[:, ring] == 0).all())
    assert torch.allclose(ours[:8, ring], 0.5 * ours[8, ring].expand(8, -1))
    effect = module.border_effect()
    mass9 = effect["ours"]["border mass, dir 9"]
    assert mass9 == pytest.approx(float(ours[8, ring].sum()))
    assert effect["ours"]["border mass, dir 1"] == pytest.approx(0.5 * mass9)
    # the maxima are inside the 5 x 5 area: b at g = 0 does not move; at g = 1 b = 0.8 / sum
    for d in ("dir 1", "dir 9"):
        assert effect["zeroed"][f"b g=0, {d}"] == pytest.approx(effect["ours"][f"b g=0, {d}"])
        assert effect["ours"][f"b g=1, {d}"] == pytest.approx(0.8)
    assert effect["zeroed"]["b g=1, dir 9"] == pytest.approx(0.8 / (1 - mass9))
    # zeroed and renormalised, direction 9 is the 5 x 5 function's W_basic
    renorm, five = variants["zeroed, renormalised"], variants["5 x 5"]
    assert torch.allclose(renorm[8], five[8], atol=1e-12)
    assert torch.allclose(renorm, five, atol=1e-3)
    assert "our reading" in module.caption()

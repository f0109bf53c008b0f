"""Smoke tests of experiments/pd_scenario.py ([PD] 24.6, issue 12)."""

import math
import pathlib
import sys
import time

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import check_outputs, load_script

NAME = "pd-scenario"


def load():
    return load_script("pd_scenario.py")


def test_module_interface():
    module = load()
    assert module.NAME == NAME
    assert isinstance(module.DESCRIPTION, str) and module.DESCRIPTION
    assert callable(module.run) and callable(module.main)
    assert len(module.PAPER_ARMSE["with PCR5"]) == 10 == len(module.PAPER_TYPE_PURITY)


def test_quick_short(tmp_path, capsys):
    module = load()
    start = time.perf_counter()
    md = module.run(quick=True, seeds=1, duration=150.0, out_dir=tmp_path, progress=False)
    assert time.perf_counter() - start < 60  # loose bound; typically ~10 s
    rows = check_outputs(NAME, md, tmp_path)
    assert len(rows) == 2 * 10
    assert {r["config"] for r in rows} == {"without PCR5", "with PCR5"}
    text = md.read_text()
    # the chapter's printed values stand beside ours
    assert "14.82" in text and "0.94" in text and "| [PD] 24.2 |" in text
    assert "Monte-Carlo runs: 1" in text
    for r in rows:
        for key in ("length_ratio", "track_purity"):
            v = float(r[key])
            assert math.isnan(v) or 0.0 <= v <= 1.0
        if r["config"] == "without PCR5":
            assert r["type_purity"] in ("", "nan")
    # in 150 s the convoy (3, 7, 2, 4) and target 8 exist and are seen by the GMTI: tracked
    tracked = {int(r["target"]) for r in rows if r["armse"] not in ("", "nan")}
    assert {3, 7, 8} <= tracked
    assert "| target |" in capsys.readouterr().out


def test_main_cli(tmp_path):
    module = load()
    md = module.main(["--quick", "--seeds", "1", "--out", str(tmp_path), "--no-progress"])
    rows = check_outputs(NAME, md, tmp_path)
    assert {r["runs"] for r in rows} == {"1"}


@pytest.mark.slow
def test_full(tmp_path):
    module = load()
    md = module.run(out_dir=tmp_path, progress=False)
    rows = check_outputs(NAME, md, tmp_path)
    assert {r["runs"] for r in rows} == {str(module.FULL_RUNS)}

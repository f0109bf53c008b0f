"""Smoke tests of the issue-12 diagnostic scripts built on experiments/pd_scenario.py.

experiments/oosm_lags.py, experiments/oosm_compare.py and experiments/pd_resolution_crosstalk.py
print their measurements (their full-run numbers are hand-written notes in experiments/results);
each test runs the script's ``main`` with ``--quick`` (a 400 s scenario, 1 seed) and ``--out``
in ``tmp_path`` and checks the printed / written sections and that no file of
experiments/results was created, changed or touched.
"""

import hashlib
import json
import pathlib
import re
import sys

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import EXPERIMENTS, load_script

from hocnet.tracking.scenario import pd_scenario

RESULTS = EXPERIMENTS / "results"
SCRIPTS = ("oosm_lags.py", "oosm_compare.py", "pd_resolution_crosstalk.py")


def results_snapshot() -> dict[str, tuple[int, int, str]]:
    """``{name: (size, mtime_ns, sha256)}`` of every file under experiments/results."""
    return {
        str(p.relative_to(RESULTS)): (
            p.stat().st_size,
            p.stat().st_mtime_ns,
            hashlib.sha256(p.read_bytes()).hexdigest(),
        )
        for p in sorted(RESULTS.rglob("*"))
        if p.is_file()
    }


def run_main(module, argv):
    """``module.main(argv)`` (speed is measured in benchmarks/, not asserted here)."""
    return module.main(argv)


@pytest.mark.parametrize("script", SCRIPTS)
def test_interface(script):
    module = load_script(script)
    assert callable(module.main)
    assert module.QUICK_SEEDS == 1 and module.QUICK_DURATION < 1200.0
    doc = module.__doc__
    # says what it measures, the full-run command and where the numbers go
    assert f"python experiments/{script}" in doc and "experiments/results/" in doc
    assert "--quick" in doc and "--out" in doc


@pytest.mark.parametrize("script", SCRIPTS)
def test_quick_refuses_results_dir(script, capsys):
    module = load_script(script)
    before = results_snapshot()
    with pytest.raises(SystemExit) as exc:
        module.main(["--quick", "--out", str(RESULTS)])
    assert exc.value.code == 2
    assert "does not write into" in capsys.readouterr().err
    assert results_snapshot() == before


def test_oosm_lags_quick(tmp_path, capsys):
    module = load_script("oosm_lags.py")
    before = results_snapshot()
    text = run_main(module, ["--quick", "--max-lag", "2", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert printed == text == (tmp_path / "oosm-lags.txt").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["oosm-lags.txt"]
    lines = text.splitlines()
    seed = module.SEED_BASE
    n_reports = len(pd_scenario(seed=seed, duration=module.QUICK_DURATION).reports)
    assert lines[0] == f"seed {seed}: {n_reports} reports"
    # the quick scenario has both delayed IMINT kinds (video from 245 s, UGS from 388 s)
    for kind in ("ugs", "video"):
        (line,) = [x for x in lines if x.startswith(f"  {kind}: ")]
        assert re.match(rf"  {kind}: \d+ reports; lag behind the last GMTI scan ", line)
        assert "GMTI scans after tau: {" in line
    assert any(x.startswith("  tracker: ") and "out-of-lag rows" in x for x in lines)
    assert any(x.startswith("  last step length (t - t_prev)") for x in lines)
    assert any(x.startswith("  OOSM rows by lag (memory of 2 steps): ") for x in lines)
    assert len(lines) == 6
    assert results_snapshot() == before


def test_oosm_compare_quick(tmp_path, capsys):
    module = load_script("oosm_compare.py")
    before = results_snapshot()
    text = run_main(module, ["--quick", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert printed == text == (tmp_path / "oosm-compare.txt").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["oosm-compare.json", "oosm-compare.txt"]
    labels = ("before (max_lag=None)", "after (max_lag=2)")
    for label in labels:
        assert f"== {label}: seeds [2400]" in text
    for name in ("without PCR5", "with PCR5"):
        assert text.count(f"  {name} diagnostics: n_scans ") == 2
        assert text.count(f"  {name}: target purity / ARMSE / type purity / length") == 2
    assert text.count("  goals: purity_without ") == 2
    # ten target rows per configuration and setting
    assert len(re.findall(r"^    ( \d|\d\d): ", text, flags=re.M)) == 2 * 2 * 10
    summary = json.loads((tmp_path / "oosm-compare.json").read_text())
    assert list(summary) == list(labels)
    for s in summary.values():
        assert s["seeds"] == [2400]
        assert set(s["targets"]["with PCR5"]) == {str(t) for t in range(1, 11)}
        assert {"out_of_lag", "oosm_failures"} <= set(s["diag"]["without PCR5"])
    # the lag memory takes every delayed report (experiments/results/oosm-lags.md: 0 / 0)
    assert summary["after (max_lag=2)"]["diag"]["with PCR5"]["out_of_lag"] == 0
    assert results_snapshot() == before


def test_pd_resolution_crosstalk_quick(tmp_path, capsys):
    module = load_script("pd_resolution_crosstalk.py")
    before = results_snapshot()
    counts = run_main(module, ["off", "10", "--quick", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert json.loads(printed) == counts
    written = tmp_path / "pd-resolution-crosstalk-off-10.json"
    assert [p.name for p in tmp_path.iterdir()] == [written.name]
    assert json.loads(written.read_text()) == counts
    assert list(counts) == ["without", "with"]
    for c in counts.values():
        assert set(c) == {"t1_in_convoy", "convoy_in_t1", "t1_samples", "convoy_samples"}
        # target 1 (from 250 s) and the convoy are tracked within the quick scenario
        assert c["t1_samples"] > 0 and c["convoy_samples"] > 0
        assert 0 <= c["convoy_in_t1"] <= c["t1_samples"]
        assert 0 <= c["t1_in_convoy"] <= c["convoy_samples"]
    assert results_snapshot() == before

"""Smoke test of benchmarks/tracking.py (issue 12, "Speed and bad input").

Runs the IMM table and the MHT tables at tiny sizes with ``--out`` in ``tmp_path`` and checks the
written Markdown (columns, agreement with filterpy, the one-thread goal) and that no committed file
of benchmarks/results was created, changed or touched. Speed is measured by the full run
(``OMP_NUM_THREADS=1 .venv/bin/python benchmarks/tracking.py [--mht]``), not asserted here.
"""

import hashlib
import importlib.util
import pathlib
import sys

import pytest
import torch

BENCHMARKS = pathlib.Path(__file__).resolve().parents[2] / "benchmarks"
RESULTS = BENCHMARKS / "results"


def load_benchmark():
    """Import benchmarks/tracking.py by path (it imports ``_common`` from its own folder)."""
    name = "_test_benchmark_tracking"
    if name not in sys.modules:
        if str(BENCHMARKS) not in sys.path:
            sys.path.insert(0, str(BENCHMARKS))
        spec = importlib.util.spec_from_file_location(name, BENCHMARKS / "tracking.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def results_snapshot():
    """``{name: (size, mtime_ns, sha256)}`` of every file under benchmarks/results."""
    return {
        str(p.relative_to(RESULTS)): (
            p.stat().st_size,
            p.stat().st_mtime_ns,
            hashlib.sha256(p.read_bytes()).hexdigest(),
        )
        for p in sorted(RESULTS.rglob("*"))
        if p.is_file()
    }


@pytest.fixture
def bench():
    threads = torch.get_num_threads()
    yield load_benchmark()
    torch.set_num_threads(threads)  # the script sets 1 / 2 threads


def test_imm_table_tiny(bench, tmp_path):
    before = results_snapshot()
    out = tmp_path / "imm"
    assert bench.main(["--quick", "--tracks", "3", "--scans", "2", "--out", str(out)]) == 0
    text = out.with_suffix(".md").read_text()
    assert "| 3 | 2 |" in text and "| yes |" in text and "| NO |" not in text
    assert "for one torch thread" in text  # the goal's thread count is stated in the header
    assert "56.7x on one thread and 45.4x on two" in text
    assert "Goal (issue 12: >= 50x filterpy at 1000 tracks, one torch thread): not run." in text
    assert results_snapshot() == before


def test_mht_tables_tiny(bench, tmp_path):
    before = results_snapshot()
    out = tmp_path / "mht"
    argv = ["--mht", "--quick", "--tracks", "3", "--densities", "0,1e-9", "--out", str(out)]
    assert bench.main(argv) == 0
    text = out.with_suffix(".md").read_text()
    assert "## MHT with the CV Kalman filter" in text
    assert "## MHT with the IMM, and the filter part against filterpy" in text
    imm = text.split("## MHT with the IMM")[1]
    rows = [line for line in imm.splitlines() if line.startswith("| 3 |")]
    assert len(rows) == 2  # one IMM row per clutter density
    for line in rows:
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[11] == "yes"  # the filterpy replay agrees to 1e-8
        assert float(cells[6]) > 0 and float(cells[7]) > 0  # both filter parts were timed
    assert results_snapshot() == before


def test_filterpy_replay_detects_a_difference(bench):
    # the agreement column can fail: a perturbed recorded output is reported
    from hocnet.tracking.mht import MHT

    scans = bench.mht_data(3, 4, 1e-9, 0)
    filt = bench.TimedFilter(bench.mht_imm_filter())
    mht = MHT(filt, R=torch.tensor(bench.R), pd=bench.MHT_PD, lambda_fa=1e-9, lambda_nt=1e-10)
    mht.step(scans[0], time=0.0)
    filt.calls = []
    for k in (1, 2, 3):
        mht.step(scans[k], time=bench.DT * k)
    _, diff = bench.filterpy_replay(filt.calls)
    assert diff <= 1.0
    name, args, (new, ll) = next(c for c in filt.calls if c[0] == "update")
    i = filt.calls.index((name, args, (new, ll)))
    bad = {**new, "x": new["x"] + 1e-5}
    filt.calls[i] = (name, args, (bad, ll))
    assert bench.filterpy_replay(filt.calls)[1] > 1.0

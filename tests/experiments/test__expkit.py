"""Tests of experiments/_expkit.py (the experiment scripts' shared helpers)."""

import importlib.util
import pathlib
import sys

import pytest

PATH = pathlib.Path(__file__).resolve().parents[2] / "experiments" / "_expkit.py"


@pytest.fixture(scope="module")
def C():
    spec = importlib.util.spec_from_file_location("_test_expkit", PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules["_test_expkit"] = module
    spec.loader.exec_module(module)
    return module


def test_one_seed_has_no_spread(C):
    # issue 9: `--seeds 1` tables printed "± 0.00"
    assert C.mean_std([0.25], digits=2) == "0.25 (n = 1)"
    assert "±" not in C.mean_std([3.0], digits=2, scale=100)
    assert C.mean_std([1.0, 3.0], digits=2) == "2.00 ± 1.41"


def test_quick_run_never_writes_the_committed_results(C):
    # issue 9: a quick run overwrote experiments/results/ with smoke numbers
    def run(*, quick=False, seeds=None, out_dir=None, progress=True):  # as the scripts do
        return C.out_dir_of(out_dir)

    assert run(quick=False) == C.RESULTS_DIR
    quick = run(quick=True)
    assert quick != C.RESULTS_DIR and C.RESULTS_DIR not in quick.parents and quick.is_dir()
    assert C.out_dir_of(None, quick=True) != C.RESULTS_DIR
    assert run(quick=True, out_dir=C.RESULTS_DIR) == C.RESULTS_DIR  # asked explicitly


def test_main_for_quick_uses_a_temporary_folder(C, tmp_path):
    seen = {}

    def run(*, quick, seeds, out_dir, progress):
        seen.update(quick=quick, out_dir=out_dir)
        return tmp_path

    C.main_for("x", "a test", run, ["--quick", "--no-progress"])
    assert seen["quick"] and seen["out_dir"] is not None
    assert pathlib.Path(seen["out_dir"]) != C.RESULTS_DIR
    C.main_for("x", "a test", run, ["--quick", "--out", str(tmp_path)])
    assert str(seen["out_dir"]) == str(tmp_path)
    with pytest.raises(SystemExit):
        C.main_for("x", "a test", run, ["--out", ""])


def test_every_script_picks_its_folder_through_out_dir_of():
    # the scripts must not build experiments/results themselves (out_dir_of guards quick runs)
    for script in sorted(PATH.parent.glob("[!_]*.py")):
        text = script.read_text()
        assert "C.out_dir_of(out_dir)" in text or "out_dir_of(" in text, script.name
        assert "RESULTS_DIR" not in text, script.name

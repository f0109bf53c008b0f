"""Helpers shared by the experiment smoke tests (imported by path: tests are not a package)."""

import csv
import importlib.util
import pathlib
import sys

EXPERIMENTS = pathlib.Path(__file__).resolve().parents[2] / "experiments"


def load_script(filename: str):
    """Import an experiment script by file path, as `hocnet reproduce` does."""
    path = EXPERIMENTS / filename
    module_name = f"_test_experiment_{path.stem}"
    if module_name not in sys.modules:
        spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module
        spec.loader.exec_module(module)
    return sys.modules[module_name]


def read_rows(path: pathlib.Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def check_outputs(name: str, md: pathlib.Path, out: pathlib.Path) -> list[dict]:
    """The md/csv/png of one run exist, are well formed and say what the paper gives."""
    assert md == out / f"{name}.md"
    for ext in ("md", "csv", "png"):
        path = out / f"{name}.{ext}"
        assert path.is_file() and path.stat().st_size > 0, path
    assert (out / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = md.read_text()
    assert f"![{name}]({name}.png)" in text
    rows = read_rows(out / f"{name}.csv")
    assert rows
    return rows


def results_snapshot(folder: pathlib.Path) -> dict[str, tuple[int, int]]:
    """``{file name: (mtime_ns, size)}`` of ``folder``: equal before and after = nothing written."""
    return {p.name: (p.stat().st_mtime_ns, p.stat().st_size) for p in folder.iterdir()}


def quick_run_watched(script, out: pathlib.Path) -> tuple:
    """``script.main(--quick --out out)`` with the committed results folder watched.

    Returns ``(md, out, before, after)``: the run's markdown text, ``out`` and the snapshots
    (:func:`results_snapshot`) of ``experiments/results`` before and after the run.
    """
    results = sys.modules["_expkit"].RESULTS_DIR
    before = results_snapshot(results)
    md = script.main(["--quick", "--no-progress", "--out", str(out)])
    return md, out, before, results_snapshot(results)

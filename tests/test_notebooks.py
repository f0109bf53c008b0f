"""The notebooks in ``notebooks/`` run top to bottom (small sizes) and are kept without outputs."""

import importlib.util
import re
import time
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
NEEDS = {"03_tuning_the_dpa.ipynb": "lightning", "04_fixed_vs_learned.ipynb": "lightning"}

nbformat = pytest.importorskip("nbformat")


def test_one_notebook_per_capability():
    names = [p.name for p in NOTEBOOKS]
    assert names == [
        "01_hoc_detection.ipynb",
        "02_dpa_ir_sequence.ipynb",
        "03_tuning_the_dpa.ipynb",
        "04_fixed_vs_learned.ipynb",
    ]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_stripped_and_cites_the_paper(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    first = nb.cells[0]
    assert first.cell_type == "markdown" and "What it shows" in first.source
    assert "[LA98]" in first.source or "[NR08]" in first.source
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, path.name
            imports = re.findall(
                r"^from hocnet\S* import \(?([^)]*?)\)?$", cell.source, re.M | re.S
            )
            names = [n.strip() for text in imports for n in text.replace("\n", ",").split(",")]
            assert not [n for n in names if n.startswith("_")], "public API only"
            assert "hocnet._" not in cell.source and "._" not in cell.source, "public API only"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_runs(path, tmp_path):
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    if path.name in NEEDS and importlib.util.find_spec(NEEDS[path.name]) is None:
        pytest.skip(f"needs {NEEDS[path.name]}")
    nb = nbformat.read(path, as_version=4)
    start = time.perf_counter()
    nbclient.NotebookClient(
        nb, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    ).execute()
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    assert time.perf_counter() - start < 60, "keep the notebooks small"

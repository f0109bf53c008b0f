import pathlib
import sys
import time

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import load_script, read_rows


def check_outputs(name, md, out):
    """The md/csv/png of one run exist and are well formed (the HOC files quote the paper)."""
    assert md == out / f"{name}.md"
    for ext in ("md", "csv", "png"):
        path = out / f"{name}.{ext}"
        assert path.is_file() and path.stat().st_size > 0, path
    assert f"![{name}]({name}.png)" in md.read_text()
    rows = read_rows(out / f"{name}.csv")
    assert rows
    return rows


SCRIPTS = {
    "hoc-table2": "hoc_table2.py",
    "hoc-table3": "hoc_table3.py",
    "hoc-fig6": "hoc_fig6.py",
    "hoc-fig5": "hoc_fig5.py",
}


def load(name: str):
    return load_script(SCRIPTS[name])


def rejection_columns(rows: list[dict]) -> list[float]:
    values = []
    for row in rows:
        for key, value in row.items():
            if "rejection" in key or key.endswith("_hoc") or key.endswith("_id"):
                if value not in ("", None):
                    values.append(float(value))
    return values


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_module_interface(name):
    module = load(name)
    assert module.NAME == name
    assert isinstance(module.DESCRIPTION, str) and module.DESCRIPTION
    assert callable(module.run) and callable(module.main)


class TestTable2:
    def test_quick(self, tmp_path, capsys):
        module = load("hoc-table2")
        start = time.perf_counter()
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        assert time.perf_counter() - start < 60  # loose bound; typically a few seconds
        rows = check_outputs("hoc-table2", md, tmp_path)
        # 2 seeds x (configs at k = 2 + the MHOC image and the chain support at k = 3)
        assert len(rows) == 2 * (len(module.CONFIGS) + len(module.ORDER3_CONFIGS))
        assert {"combine=sum, span 2", "combine=movement (eq. 8 alone), span 2"} <= {
            r["config"] for r in rows
        }
        assert {r["order"] for r in rows} == {"2", "3"}
        text = md.read_text()
        assert "[LA98] as printed | 99.56 | 99.91" in text
        assert all(int(r["input_target"]) == 20 for r in rows)
        values = rejection_columns(rows)
        assert values and all(0.0 <= v <= 1.0 for v in values)
        assert all(int(r["id_target_lost"]) == 0 for r in rows if r["config"] == "paper")
        # order 3: the MHOC image leaves scans 5-6 uncovered, the chain support covers them
        k3 = {r["config"]: r for r in rows if r["order"] == "3" and r["seed"] == "2000"}
        assert int(k3["paper"]["hoc_target_lost"]) == 4
        assert int(k3["chain + paper"]["hoc_target_lost"]) == 0
        assert "scene-to-scene spread" in text and "Where the paper disagrees" in text
        assert "| density |" in capsys.readouterr().out

    def test_main_cli(self, tmp_path):
        module = load("hoc-table2")
        md = module.main(["--quick", "--seeds", "1", "--out", str(tmp_path), "--no-progress"])
        rows = check_outputs("hoc-table2", md, tmp_path)
        assert {r["seed"] for r in rows} == {str(module.SEED_BASE)}

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("hoc-table2")
        rows = check_outputs("hoc-table2", module.run(out_dir=tmp_path), tmp_path)
        assert len(rows) == 20 * 5 * (len(module.CONFIGS) + len(module.ORDER3_CONFIGS))
        assert all(int(r["hoc_target_lost"]) == 0 for r in rows if r["order"] == "2")


class TestTable3:
    def test_quick(self, tmp_path):
        module = load("hoc-table3")
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        rows = check_outputs("hoc-table3", md, tmp_path)
        configs = len(module.CONFIGS) + len(module.ORDER3_CONFIGS)
        assert len(rows) == len(module.SCENES) * 2 * configs
        assert {r["scene"] for r in rows} == {"table3-paper", "table3-int", "table3"}
        # the default (whole-sequence score) loses no target point on either variant
        assert all(
            int(r["id_target_lost"]) == 0
            for r in rows
            if r["config"] == "paper" and r["order"] == "2"
        )
        values = rejection_columns(rows)
        assert values and all(0.0 <= v <= 1.0 for v in values)
        for row in rows:  # every true track of the row's scene evaluated (>= 2k + 1 points)
            labels = module.TRACK_NAMES[row["scene"]]
            assert all(row[f"found_T{label}"] in ("0", "1") for label in labels)
            others = [row.get(f"found_T{i}", "") for i in range(1, 6) if i not in labels]
            assert all(flag == "" for flag in others)
        # the harder scene's extra rows: four tracks plus the branch, all found at k = 2
        harder = [r for r in rows if r["scene"] == "table3" and r["order"] == "2"]
        assert harder and all(int(r["input_target"]) == 45 for r in harder)
        assert all(int(r["true_found"]) == 5 for r in harder if r["config"] == "paper")
        text = md.read_text()
        assert "[LA98] as printed | 78.67 | 97.46" in text
        assert "chain support (`support='chain'`" in text and "scene-to-scene spread" in text
        assert "## `table3`, order k = 2" in text and "true tracks found (of 5)" in text
        assert "- Command: `OMP_NUM_THREADS=1 python experiments/hoc_table3.py --quick`" in text

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("hoc-table3")
        rows = check_outputs("hoc-table3", module.run(out_dir=tmp_path), tmp_path)
        configs = len(module.CONFIGS) + len(module.ORDER3_CONFIGS)
        assert len(rows) == len(module.SCENES) * 20 * 3 * configs
        k2 = [r for r in rows if r["order"] == "2" and r["config"] == "paper"]
        assert all(int(r["hoc_target_lost"]) == 0 and int(r["id_target_lost"]) == 0 for r in k2)


class TestFig6:
    def test_quick(self, tmp_path):
        module = load("hoc-fig6")
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        rows = check_outputs("hoc-fig6", md, tmp_path)
        assert len(rows) == 2 * 2  # 2 densities x 2 seeds
        values = rejection_columns(rows)
        assert values and all(0.0 <= v <= 1.0 for v in values)
        assert all(int(r["targets_lost_hoc"]) == 0 for r in rows)
        text = md.read_text()
        assert "Breakdown densities" in text and "1.23 %" in text and "4.92 %" in text

    def test_breakdown(self):
        module = load("hoc-fig6")
        assert module.breakdown([0.01, 0.04], [1.0, 0.98]) == "2.00 %"
        assert module.breakdown([0.01, 0.04], [0.9, 0.5]).startswith("<")
        assert module.breakdown([0.01, 0.04], [1.0, 0.995]).startswith(">")

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("hoc-fig6")
        rows = check_outputs("hoc-fig6", module.run(out_dir=tmp_path), tmp_path)
        assert len(rows) == 20 * 12


class TestFig5:
    def test_quick(self, tmp_path):
        module = load("hoc-fig5")
        md = module.run(quick=True, out_dir=tmp_path, progress=False)
        rows = check_outputs("hoc-fig5", md, tmp_path)
        assert len(rows) == 2 * 2 * 4  # 2 scenes x 2 seeds x windows 1-10, 3-12, 5-14, 7-16
        assert [r["scene"] for r in rows[:: 2 * 4]] == ["fig5-paper", "fig5"]
        assert [r["scans"] for r in rows[:4]] == ["1-10", "3-12", "5-14", "7-16"]
        assert all(r["stream_equals_batch"] == "1" for r in rows)
        assert all(int(r["hoc_eligible_lost"]) == 0 for r in rows)
        values = rejection_columns(rows)
        assert values and all(0.0 <= v <= 1.0 for v in values)

    @pytest.mark.slow
    def test_full(self, tmp_path):
        module = load("hoc-fig5")
        rows = check_outputs("hoc-fig5", module.run(out_dir=tmp_path), tmp_path)
        assert len(rows) == 2 * 20 * 4
        assert all(r["stream_equals_batch"] == "1" for r in rows)


# ----------------------------------------------------------------------------- printed values


def paper_columns(name: str, seeds: list[int]) -> dict[float, tuple[float, float]]:
    """Our MHOC and identification clutter rejection (%) per density, mean over ``seeds``.

    The experiment's headline configuration: its scene (Table II: ``table2``; Table III:
    ``table3-paper``, the paper's random rotation), its densities, ``detect`` at order 2 with
    ``CONFIGS["paper"]`` (the detector's defaults) and v = 4, delta = pi/4.
    """
    import math

    from hocnet import metrics
    from hocnet.data.binary import paper_scene
    from hocnet.hoc import detect

    module = load(name)
    scene_name = "table2" if name == "hoc-table2" else "table3-paper"
    out = {}
    for density in module.DENSITIES:
        hoc, ident = [], []
        for seed in seeds:
            scene = paper_scene(scene_name, density, seed=seed)
            result = detect(scene.cube, order=2, v=4, delta=math.pi / 4, **module.CONFIGS["paper"])
            truth = scene.target_mask
            hoc.append(metrics.clutter_rejection(scene.cube, result.support, truth))
            ident.append(metrics.clutter_rejection(scene.cube, result.cleaned, truth))
            assert metrics.target_points_lost(scene.cube, result.cleaned, truth) == 0
        out[density] = (100 * sum(hoc) / len(hoc), 100 * sum(ident) / len(ident))
    return out


CLAIMED = {
    # (experiment, column): the densities where our mean over 20 scenes is within 1 point of
    # the printed value (full runs, experiments/results/hoc-table2.md / hoc-table3.md). Not
    # claimed: Table II MHOC at 2.0 % (ours 79.41 %, printed 75.44 %; its own counts give
    # 75.44 %), measured to lie outside the paper's stated set-up
    # (experiments/results/hoc-table2-gap.md: our eq. (5)-(6) needs 2.13 % clutter to reach
    # 75.44 %, and none of 200 random 2.0 % scenes does, minimum 77.80 %), reported in the
    # results files only.
    ("hoc-table2", "hoc"): (0.008, 0.011, 0.014, 0.017),
    ("hoc-table2", "id"): (0.008, 0.011, 0.014, 0.017, 0.020),
    ("hoc-table3", "hoc"): (0.008, 0.014, 0.020),
    ("hoc-table3", "id"): (0.008, 0.014, 0.020),
}

FULL_STD = {
    # scene-to-scene standard deviation (points) of each column in the full runs (20 scenes;
    # experiments/results/hoc-table2.md, hoc-table3.md, headline k = 2 rows)
    ("hoc-table2", "hoc"): {0.008: 0.13, 0.011: 0.25, 0.014: 0.41, 0.017: 0.53, 0.020: 0.71},
    ("hoc-table2", "id"): {0.008: 0.03, 0.011: 0.05, 0.014: 0.07, 0.017: 0.12, 0.020: 0.22},
    ("hoc-table3", "hoc"): {0.008: 1.57, 0.014: 2.44, 0.020: 4.53},
    ("hoc-table3", "id"): {0.008: 0.85, 0.014: 0.94, 0.020: 1.78},
}

RESULTS = pathlib.Path(__file__).resolve().parents[2] / "experiments" / "results"


def test_full_std_is_the_committed_runs_std():
    # FULL_STD sets the tolerance of the fast Table II test below (Table III runs its full 20
    # seeds in the default suite; its rows here check that the committed run has not drifted):
    # it must be the scene-to-scene std of the committed full runs (rerun an experiment ->
    # update FULL_STD; issue 7 audit: the Table III identification row had drifted, 0.74 /
    # 0.86 / 1.71 against 0.85 / 0.94 / 1.77)
    import statistics

    for (name, column), per_density in FULL_STD.items():
        rows = read_rows(RESULTS / f"{name}.csv")
        for density, want in per_density.items():
            values = [
                100 * float(r[f"{column}_rejection"])
                for r in rows
                if float(r["density"]) == density
                and r["order"] == "2"
                and r["config"] == "paper"
                and r.get("scene", "table3-paper") == "table3-paper"
            ]
            assert len(values) == 20, (name, density)
            assert round(statistics.stdev(values), 2) == want, (name, column, density)


FAST_SEEDS = {"hoc-table2": 2}
"""Scenes per density of the fast Table II test (the first seeds of the full run). Table III
has no reduced test: its full 20 seeds take about a second, and a 4-seed test would allow
1 + 3 * 4.53 / sqrt(4) = 7.8 points at 2.0 % MHOC."""


def check_claims(name: str, ours: dict, tolerance) -> None:
    module = load(name)
    for column, printed in (("hoc", module.PAPER_HOC), ("id", module.PAPER_ID)):
        for density in CLAIMED[(name, column)]:
            value = ours[density][0 if column == "hoc" else 1]
            tol = tolerance(name, column, density)
            assert abs(value - printed[density]) <= tol, (column, density, value, tol)


class TestPrintedValues:
    """Tables II and III of [LA98]: our columns against the printed ones ("within a point")."""

    @pytest.mark.parametrize("name", ["hoc-table2"])
    def test_reduced_seeds(self, name):
        # the mean of n scenes scatters around the 20-scene mean by std / sqrt(n): allow the
        # claimed 1 point plus 3 standard errors (std measured in the full run)
        n = FAST_SEEDS[name]
        module = load(name)
        ours = paper_columns(name, [module.SEED_BASE + i for i in range(n)])

        def tolerance(name, column, density):
            return 1.0 + 3 * FULL_STD[(name, column)][density] / n**0.5

        check_claims(name, ours, tolerance)

    @pytest.mark.parametrize(
        "name",
        [pytest.param("hoc-table2", marks=pytest.mark.slow), "hoc-table3"],  # Table III: ~1 s
    )
    def test_full_configuration(self, name):
        module = load(name)
        ours = paper_columns(name, [module.SEED_BASE + i for i in range(20)])
        check_claims(name, ours, lambda *_: 1.0)

import csv
import importlib.util
import json
import math
import os
import re
import socket
import sys
import time
import uuid
from pathlib import Path

import pytest

from hocnet.cli import main
from hocnet.data import anti_mean, simulate_ir
from hocnet.data.infrared import IRTarget
from hocnet.dpa import (
    accumulate,
    algorithm_score,
    b_limit,
    detection_probability,
    frame_thresholds,
    probability_matrices,
)
from hocnet.sweep import (
    DPASweepSettings,
    check_dpa_axes,
    evaluate_dpa,
    write_rows_csv,
)

HAS_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(not HAS_RAY, reason="ray[tune] not installed (the sweep extra)")

TINY = DPASweepSettings(scene="ir", shape=(5, 24, 24), scenes=2, snr_db=15.0, last=3)
TINY_FLAGS = ["--scene", "ir", "--shape", "5", "24", "24", "--snr-db", "15", "--last", "3"]


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


# --------------------------------------------------------------------------------------------
# without Ray
# --------------------------------------------------------------------------------------------


class TestWithoutRay:
    def test_cli_says_how_to_install(self, monkeypatch, capsys, tmp_path):
        monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now fails
        code = main(["sweep", "dpa", "--out", str(tmp_path / "s")])
        err = capsys.readouterr().err.strip()
        assert code == 2
        assert len(err.splitlines()) == 1
        assert err.startswith("hocnet: error: sweep:") and "pip install 'hocnet[sweep]'" in err
        assert not (tmp_path / "s").exists()

    def test_help_needs_no_ray(self, monkeypatch, capsys):
        monkeypatch.setitem(sys.modules, "ray", None)
        assert main(["sweep", "dpa", "--help"]) == 0
        assert "--penalty-step" in capsys.readouterr().out


class TestEvaluateDPA:
    def test_against_a_direct_computation(self):
        config = {"b": 0.6, "g": 0.5, "penalty_step": 1.5, "s_n": 2, "max_numbers": 2, "seed": 3}
        got = evaluate_dpa(config, TINY)
        # the same scenes and metrics, written out step by step
        speed, t_sim = 0.5, 1 + (5 - 1) * 2
        target = IRTarget(12.0 + 0.5 * speed * (t_sim - 1), 12.0, -speed, 0.0, snr_db=15.0)
        seq = simulate_ir((t_sim, 24, 24), [target], clouds="wispy", batch=2, seed=3)
        frames = anti_mean(seq.frames[:, ::2].contiguous())
        free = anti_mean(seq.target_free[:, ::2].contiguous())
        pos = seq.positions[:, :, ::2]
        w = probability_matrices(5, v_max=1.0, p=0.5, penalty_step=1.5)
        asf = accumulate(frames, w, 0.6, 0.5).asf
        a_s = algorithm_score(asf, pos[:, 0], last=3, block=(8, 8), max_numbers=2).double()
        thr = frame_thresholds(accumulate(free, w, 0.6, 0.5).asf, 1e-3)
        pd = detection_probability(asf, pos, thr, radius=1.5)
        assert got["valid"] == 1.0
        assert got["a_s"] == pytest.approx(float(a_s.mean()), rel=1e-6)
        assert got["a_s_std"] == pytest.approx(float(a_s.std(unbiased=False)), rel=1e-6)
        assert got["pd"] == pytest.approx(float(pd[-1]))
        assert 0.0 <= got["tracked"] <= 1.0

    def test_b_outside_the_memory_range_is_marked_not_run(self):
        w = probability_matrices(5, v_max=1.0)
        got = evaluate_dpa({"b": b_limit(w, 0.0) * 1.01, "g": 0.0}, TINY)
        assert got["valid"] == 0.0 and math.isnan(got["a_s"]) and math.isnan(got["pd"])

    def test_seed_changes_the_scenes(self):
        a = evaluate_dpa({"b": 0.8, "g": 1.0, "seed": 0}, TINY)["a_s"]
        b = evaluate_dpa({"b": 0.8, "g": 1.0, "seed": 1}, TINY)["a_s"]
        assert a != b

    @pytest.mark.parametrize(
        ("axes", "match"),
        [
            ({"q": [1]}, "`axes`: expected names among"),
            ({"b": []}, "`b`: expected at least one value"),
            ({"g": [1.5]}, "`g`"),
            ({"penalty_step": [4.0]}, "`penalty_step`"),
            ({"s_n": [0]}, "`s_n`"),
        ],
    )
    def test_bad_axes(self, axes, match):
        with pytest.raises(ValueError, match=match):
            check_dpa_axes(axes)

    @pytest.mark.parametrize(
        ("kwargs", "match"),
        [
            ({"scene": "mars"}, "`scene`"),
            ({"scene": "npa", "clouds": "clear"}, "`clouds`: expected None for scene 'npa'"),
            ({"shape": (5, 24, 24), "scenes": 1, "pfa": 1e-4}, "`pfa`"),
            ({"window": 4}, "`window`: expected an odd size"),
            ({"shape": (5, 24, 24), "block": 9}, "`block`: expected 3 x 3 blocks"),
        ],
    )
    def test_bad_settings(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            DPASweepSettings(**kwargs)

    def test_cli_names_the_flag(self, capsys, tmp_path):
        if not HAS_RAY:
            pytest.skip("the ray check comes first")
        code = main(["sweep", "dpa", "--g", "2", "--out", str(tmp_path / "s"), *TINY_FLAGS])
        assert code == 2
        assert "hocnet: error: --g: expected" in capsys.readouterr().err
        assert not (tmp_path / "s").exists()


def _closed_port() -> int:
    """A local TCP port where nothing listens (bound, then released)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@needs_ray
@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--num-cpus", "0"], r"--num-cpus: expected an integer >= 1, got 0"),
        (["--cpus-per-trial", "0"], r"--cpus-per-trial: expected a number in \(0, inf\)"),
        (["--max-concurrent", "0"], r"--max-concurrent: expected an integer >= 1, got 0"),
        (["--address", "nohost"], r"--address: expected 'auto', HOST:PORT or ray://HOST:PORT"),
        (["--address", "PORT"], r"--address: no Ray cluster reachable at 127\.0\.0\.1:\d+"),
        (["--address", "ray://PORT"], r"--address: no Ray cluster reachable at ray://"),
    ],
)
def test_bad_run_options_create_nothing(args, match, capsys, tmp_path):
    """Every argument is checked (and --address probed) before --out is created."""
    port = f"127.0.0.1:{_closed_port()}"
    args = [a.replace("PORT", port) for a in args]
    out = tmp_path / "a" / "sw6"
    start = time.perf_counter()
    code = main(["sweep", "dpa", *args, "--shape", "8", "45", "45", "--out", str(out)])
    assert time.perf_counter() - start < 30  # not Ray's minutes of retries
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert re.search(match, err), err
    assert list(tmp_path.iterdir()) == []


@needs_ray
@pytest.mark.parametrize("existing", [False, True])
def test_failed_start_removes_what_it_made(existing, capsys, tmp_path, monkeypatch):
    """Ray failing before the experiment exists: the folders made are removed, or in an
    existing folder the sweep.json and the manifest written, and nothing else is touched."""
    import hocnet.sweep
    from hocnet.cli._common import MANIFEST

    def no_cluster(*args, **kwargs):
        assert (out / "sweep.json").is_file() and (out / MANIFEST).is_file()
        raise ConnectionError("could not connect to the cluster")

    monkeypatch.setattr(hocnet.sweep, "run_sweep", no_cluster)
    out = tmp_path / "a" / "sw"
    if existing:
        out.mkdir(parents=True)
        (out / "notes.txt").write_text("MINE")
    code = main(["sweep", "dpa", *TINY_FLAGS, "--quiet", "--out", str(out)])
    assert code == 2 and "could not connect" in capsys.readouterr().err
    if existing:
        assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    else:
        assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not HAS_RAY, reason="the ray check comes first")
@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--grid", "model.lrx=0.01,0.05"], "--grid: expected model.NAME with NAME an argument"),
        (["--grid", "lr=0.01"], "--grid: expected keys 'model.NAME' or 'data.NAME'"),
        (["--grid", "model.lr"], "--grid: expected KEY=VALUES"),
        ([], "--grid: expected at least one KEY=V1,V2 axis"),
    ],
)
def test_train_sweep_checks_the_configs_before_ray_starts(args, match, capsys, tmp_path):
    pytest.importorskip("lightning")
    assert main(["sweep", "train", "dpa", *args, "--out", str(tmp_path / "t")]) == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "t").exists()


def test_set_values_are_typed():
    from hocnet.cli.sweep import _assignments

    got = _assignments(
        ["data.shape=8,32,32", "model.g=0.5", "data.clouds=wispy"], "--set", many=False
    )
    assert got == {"data.shape": (8, 32, 32), "model.g": 0.5, "data.clouds": "wispy"}
    grid = _assignments(["model.lr=0.01,1e-3", "model.learnable=b"], "--grid", many=True)
    assert grid == {"model.lr": [0.01, 0.001], "model.learnable": ["b"]}


def test_write_rows_csv(tmp_path):
    out = write_rows_csv([{"b": 0.8, "a_s": math.nan}, {"b": 1.0, "x": "y"}], tmp_path / "r.csv")
    assert _rows(out) == [{"b": "0.8", "a_s": "nan", "x": ""}, {"b": "1", "a_s": "", "x": "y"}]


def test_train_metrics_fast_dev_run():
    pytest.importorskip("lightning")
    from hocnet.learn.sweep import TrainSweepSettings, train_metrics

    settings = TrainSweepSettings(
        "dpa",
        fixed={
            "data.n_train": 2,
            "data.n_val": 1,
            "data.n_test": 2,
            "data.shape": (4, 16, 16),
            "data.batch_size": 2,
            "model.learnable": ("b",),
        },
        fast_dev_run=True,
    )
    got = train_metrics({"model.lr": 0.01}, settings)
    assert "test/loss" in got and math.isfinite(got["test/loss"])


# --------------------------------------------------------------------------------------------
# on Ray (one shared local instance: ray start-up is the slow part)
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ray_instance():
    if not HAS_RAY:
        pytest.skip("ray[tune] not installed (the sweep extra)")
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    yield ray
    ray.shutdown()


@needs_ray
def test_2x2_grid_interrupted_then_resumed_on_the_cli(ray_instance, tmp_path, capsys, monkeypatch):
    """One 2 x 2 DPA grid end to end on the command line, one trial killed on its first attempt
    (a lost worker), then ``--resume``: only that trial runs again (both runs < 60 s here)."""
    import hocnet.sweep

    calls = tmp_path / "calls"
    calls.mkdir()
    marker = tmp_path / "killed-once"

    def flaky(config, settings):  # a closure: Ray pickles it by value
        from ray import tune

        Path(calls, f"{config['b']}_{config['g']}_{uuid.uuid4().hex}").touch()
        if config["b"] == 0.8 and config["g"] == 1.0 and not marker.exists():
            marker.touch()
            raise RuntimeError("worker lost (simulated interruption)")
        tune.report(evaluate_dpa(config, settings))

    monkeypatch.setattr(hocnet.sweep, "dpa_trial", flaky)
    out = tmp_path / "sweep"
    argv = ["sweep", "dpa", "--b", "0.4", "0.8", "--g", "0", "1", "--quiet", "--out", str(out)]
    assert main([*argv, *TINY_FLAGS]) == 1  # one trial did not finish
    assert "1 of 4 trials did not finish; rerun with --resume" in capsys.readouterr().out
    first = _rows(out / "results.csv")
    grid = {("0.4", "0"), ("0.4", "1"), ("0.8", "0"), ("0.8", "1")}
    assert {(r["b"], r["g"]) for r in first} == grid
    assert sorted(r["status"] for r in first) == ["done", "done", "done", "error"]
    failed = next(r for r in first if r["status"] == "error")
    assert (failed["b"], failed["g"]) == ("0.8", "1") and "simulated interruption" in failed[
        "error"
    ]
    assert len(list(calls.iterdir())) == 4
    assert (out / "sweep.json").is_file() and (out / "ray" / "dpa").is_dir()

    # a new sweep into the same folder is refused without --force; nothing is touched
    before = (out / "results.csv").read_bytes()
    assert main([*argv, *TINY_FLAGS]) == 2
    err = capsys.readouterr().err
    assert "exists: pass --resume" in err and "--force" in err
    assert (out / "results.csv").read_bytes() == before
    # the library refuses the same, and a resume of nothing
    from hocnet.sweep import run_sweep

    with pytest.raises(ValueError, match="expected a new experiment folder"):
        run_sweep(flaky, {}, out / "ray" / "dpa", settings=TINY, quiet=True)
    with pytest.raises(ValueError, match="expected an experiment folder to resume"):
        run_sweep(flaky, None, tmp_path / "none", settings=TINY, resume=True, quiet=True)

    # resume rewrites results.csv only if hocnet wrote it and nobody changed it since
    from hocnet.cli._common import MANIFEST

    assert sorted(json.loads((out / MANIFEST).read_text())) == ["results.csv", "sweep.json"]
    stat = (out / "results.csv").stat()
    (out / "results.csv").write_bytes(before + b"my notes\n")
    assert main(["sweep", "dpa", "--resume", "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "results.csv' exists and was not written by hocnet" in err and "--resume" in err
    assert (out / "results.csv").read_bytes() == before + b"my notes\n"
    assert len(list(calls.iterdir())) == 4  # refused before Ray ran anything
    (out / "results.csv").write_bytes(before)
    os.utime(out / "results.csv", ns=(stat.st_atime_ns, stat.st_mtime_ns))  # as hocnet left it

    # resume (grid and scenes from sweep.json): only the interrupted trial runs again
    assert main(["sweep", "dpa", "--resume", "--quiet", "--out", str(out)]) == 0
    rows = _rows(out / "results.csv")
    assert len(rows) == 4 and all(r["status"] == "done" for r in rows)
    names = sorted(p.name.rsplit("_", 1)[0] for p in calls.iterdir())
    assert len(names) == 5
    assert names.count("0.8_1.0") == 2 and names.count("0.4_0.0") == 1
    key = ("trial_id", "b", "g", "a_s", "pd", "seconds")
    kept = {tuple(r[k] for k in key) for r in first if r["status"] == "done"}
    assert kept <= {tuple(r[k] for k in key) for r in rows}  # finished trials untouched
    # every metric is what evaluate_dpa gives at that grid point
    for r in rows:
        want = evaluate_dpa({"b": float(r["b"]), "g": float(r["g"])}, TINY)
        assert float(r["a_s"]) == pytest.approx(want["a_s"], rel=1e-5)
        assert float(r["pd"]) == pytest.approx(want["pd"], abs=1e-5)


# --------------------------------------------------------------------------------------------
# experiments/dpa_b_sweep.py --engine ray
# --------------------------------------------------------------------------------------------

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


def _b_sweep():
    name = "_test_sweep_dpa_b_sweep"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / "dpa_b_sweep.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


B_SWEEP_TINY = {
    "scenes": ("NA23A",),
    "grid": {0.0: [0.0, 4.8, 9.0], 1.0: [0.8]},
    "seeds": [6000, 6001],
    "shapes": {"NA23A": (4, 45, 60)},
    "block": {"NA23A": 15},
}


def _b_sweep_evaluate(engine, **ray):
    m = _b_sweep()
    t = B_SWEEP_TINY
    table = m.variants()
    return m.evaluate(
        t["scenes"],
        table,
        t["grid"],
        t["seeds"],
        t["shapes"],
        t["block"],
        False,
        engine=engine,
        **ray,
    )


def test_b_sweep_ray_job_gives_the_loop_rows():
    """The function each Ray trial runs gives the loop engine's rows, job by job."""
    m = _b_sweep()
    t = B_SWEEP_TINY
    loop = _b_sweep_evaluate("loop")
    jobs = m._jobs(t["scenes"], m.variants(), t["grid"])
    assert 9.0 not in {j["b"] for j in jobs}  # outside the memory range: skipped
    rows = [r for job in jobs for r in m.ray_job(job, t["seeds"], t["shapes"], t["block"])]
    assert rows == loop and len(rows) == len(jobs) * 2


def test_b_sweep_rejects_an_unknown_engine():
    with pytest.raises(ValueError, match="`engine`: expected 'loop' or 'ray'"):
        _b_sweep_evaluate("spark")


@pytest.mark.slow
@needs_ray
def test_b_sweep_ray_engine_gives_the_loop_rows(ray_instance, tmp_path):
    loop = _b_sweep_evaluate("loop")
    ray_rows = _b_sweep_evaluate("ray", ray={"path": tmp_path / "exp"})
    assert ray_rows == loop


# --------------------------------------------------------------------------------------------
# experiments/dpa_sampling.py and dpa_pd_snr.py --engine ray
# --------------------------------------------------------------------------------------------


def _script(stem):
    name = f"_test_sweep_{stem}"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{stem}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


@pytest.mark.parametrize("stem", ["dpa_sampling", "dpa_pd_snr"])
def test_rejects_an_unknown_engine(stem, tmp_path):
    with pytest.raises(ValueError, match="`engine`: expected 'loop' or 'ray'"):
        _script(stem).run(quick=True, out_dir=tmp_path, progress=False, engine="spark")


@pytest.mark.parametrize("stem", ["dpa_b_sweep", "dpa_sampling", "dpa_pd_snr"])
def test_engine_flags_need_engine_ray(stem, capsys):
    m = _script(stem)
    with pytest.raises(SystemExit):
        m.main(["--quick", "--resume"])
    assert "need --engine ray" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        m.main(["--quick", "--engine", "ray", "--resume"])
    assert "--resume needs --ray-dir" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        m.main(["--help"])
    assert "Engine options" in " ".join(capsys.readouterr().out.split())  # argparse wraps lines


@needs_ray
@pytest.mark.parametrize("stem", ["dpa_sampling", "dpa_pd_snr"])
def test_quick_run_gives_the_same_csv_on_either_engine(stem, ray_instance, tmp_path):
    """A --quick run with --engine ray writes the loop engine's CSV byte for byte."""
    m = _script(stem)
    loop = m.run(quick=True, out_dir=tmp_path / "loop", progress=False)
    ray = m.run(
        quick=True,
        out_dir=tmp_path / "ray",
        progress=False,
        engine="ray",
        ray={"path": tmp_path / "exp"},
    )
    csv_name = f"{m.NAME}.csv"
    assert (tmp_path / "ray" / csv_name).read_bytes() == (tmp_path / "loop" / csv_name).read_bytes()
    assert len(_rows(tmp_path / "ray" / csv_name)) > 0
    # the reports differ only in their runtime line
    strip = [line for line in loop.read_text().splitlines() if not line.startswith("- Runtime")]
    assert strip == [
        line for line in ray.read_text().splitlines() if not line.startswith("- Runtime")
    ]
    assert any((tmp_path / "exp").glob("experiment_state*.json"))  # Ray Tune ran the trials


@pytest.mark.slow
@needs_ray
def test_train_sweep_on_ray(ray_instance, tmp_path):
    pytest.importorskip("lightning")
    out = tmp_path / "t"
    argv = ["sweep", "train", "dpa", "--grid", "model.lr=0.01,0.05", "--fast-dev-run", "--quiet"]
    sets = ["data.n_train=2", "data.n_val=1", "data.n_test=2", "data.shape=4,16,16"]
    argv += [x for s in sets for x in ("--set", s)] + ["--set", "data.batch_size=2"]
    assert main([*argv, "--out", str(out)]) == 0
    rows = _rows(out / "results.csv")
    assert [r["model.lr"] for r in rows] == ["0.01", "0.05"]
    assert all(r["status"] == "done" and math.isfinite(float(r["test/loss"])) for r in rows)


@needs_ray
def test_force_replaces_and_resume_rewrites_results(capsys, tmp_path, monkeypatch):
    """--force replaces a sweep folder's files (even the user's own), the manifest then lets
    --resume rewrite results.csv; Ray itself is replaced by a stub here."""
    import hocnet.sweep
    from hocnet.cli._common import MANIFEST
    from hocnet.sweep import SweepResult

    runs = []

    def stub(trainable, space, path, *, resume=False, **kwargs):
        runs.append(resume)
        Path(path).mkdir(parents=True, exist_ok=True)
        (Path(path) / "experiment_state-0.json").write_text("{}")
        row = {"b": 0.8, "a_s": float(len(runs)), "trial_id": "t1", "status": "done"}
        return SweepResult(rows=[row], path=Path(path), seconds=0.0)

    monkeypatch.setattr(hocnet.sweep, "run_sweep", stub)
    out = tmp_path / "sw"
    out.mkdir()
    for name in ("sweep.json", "results.csv"):
        (out / name).write_text("MINE")
    argv = ["sweep", "dpa", *TINY_FLAGS, "--quiet", "--out", str(out)]
    assert main(argv) == 2 and "pass --resume" in capsys.readouterr().err
    assert (out / "results.csv").read_text() == "MINE"
    assert main([*argv, "--force"]) == 0
    assert _rows(out / "results.csv")[0]["a_s"] == "1"
    assert json.loads((out / "sweep.json").read_text())["kind"] == "dpa"
    assert sorted(json.loads((out / MANIFEST).read_text())) == ["results.csv", "sweep.json"]
    printed = capsys.readouterr().out
    assert MANIFEST not in printed and ".tmp" not in printed
    assert main(["sweep", "dpa", "--resume", "--quiet", "--out", str(out)]) == 0
    assert _rows(out / "results.csv")[0]["a_s"] == "2" and runs == [False, True]

import io
import json
import math
import os
import pickle
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import hocnet.cli as cli
from hocnet.cli import main
from hocnet.cli._common import MANIFEST
from hocnet.data.binary import TargetSpec, paper_scene, simulate_binary
from hocnet.data.io import load_tracks_json, save_cube
from hocnet.hoc import HOCResult, detect

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def assert_png(path: Path) -> None:
    assert path.is_file() and path.stat().st_size > 1000
    assert path.read_bytes()[:8] == PNG_MAGIC


def assert_one_line_error(capsys, code: int, match: str | None = None) -> str:
    out, err = capsys.readouterr()
    assert code == 2
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("hocnet: error: "), err
    assert "Traceback" not in err
    if match is not None:
        assert re.search(match, lines[0]), lines[0]
    return lines[0]


def written(folder: Path) -> list[str]:
    """The files hocnet wrote into ``folder``: its listing but the manifest, which lists them."""
    names = sorted(p.name for p in folder.iterdir() if p.name != MANIFEST)
    assert sorted(json.loads((folder / MANIFEST).read_text())) == names
    return names


def no_leftovers(folder: Path) -> list[str]:
    """Names of temporary output folders left behind (must be none)."""
    return [p.name for p in folder.rglob(".*.tmp-*")]


@pytest.fixture(scope="module")
def scene():
    return paper_scene("table3", 0.012, seed=5)


@pytest.fixture
def cube_file(tmp_path, scene):
    path = tmp_path / "scene.npy"
    save_cube(path, scene.cube)
    return path


# --------------------------------------------------------------------------------------------
# demo
# --------------------------------------------------------------------------------------------


class TestDemo:
    def test_writes_pictures_and_prints_table(self, tmp_path, capsys):
        out = tmp_path / "demo"
        assert main(["demo", "--out", str(out)]) == 0
        stdout = capsys.readouterr().out
        assert written(out) == [
            "demo_3d.png",
            "demo_before_after.png",
            "demo_dpa.png",
        ]
        assert "DPA ([NR08])" in stdout and "Back-tracked track" in stdout
        for name in ("demo_3d.png", "demo_before_after.png", "demo_dpa.png"):
            assert_png(out / name)
        assert no_leftovers(tmp_path) == []

        # the table agrees with detect() on the same scene
        scene = paper_scene("table3", 0.014, seed=0)
        result = detect(scene.cube, order=2)
        assert "True tracks" in stdout and "Found tracks" in stdout
        rows = re.findall(
            r"^\s+(\d+)(?: \(branch of \d+\))?\s+(\d+)\s+(\d+-\d+)\s+(\S+)\s", stdout, re.M
        )
        true_rows = rows[: len(scene.tracks)]
        assert [int(r[0]) for r in true_rows] == list(scene.track_labels)
        assert [int(r[1]) for r in true_rows] == [len(t) for t in scene.tracks]
        assert "5 (branch of 3)" in stdout
        assert f"Found tracks: {len(result.tracks)} (" in stdout
        clutter = scene.clutter_mask
        left = int((clutter & result.support).sum())
        assert f"({left} of {int(clutter.sum())} clutter points left)" in stdout
        assert f"Target points lost: 0 of {int(scene.target_mask.sum())}" in stdout
        assert re.search(r"Runtime: \d+\.\d\d s", stdout)
        assert f"wrote {out / 'demo_before_after.png'}" in stdout

    def test_options(self, tmp_path, capsys):
        out = tmp_path / "nested" / "demo"
        args = ["demo", "--out", str(out), "--seed", "3", "--density", "0", "--order", "1"]
        assert main([*args, "--no-plot"]) == 0
        stdout = capsys.readouterr().out
        assert "clutter density 0, seed 3" in stdout
        assert "HOC, order 1" in stdout and "Found tracks: " in stdout
        assert "100.0 % (0 of 0 clutter points left)" in stdout  # nothing to reject
        assert not (tmp_path / "nested").exists()  # --no-plot: nothing to write

    @pytest.mark.parametrize(
        ("args", "match"),
        [
            (["--density", "1.5"], r"--density: expected a number in \[0, 1\]"),
            (["--density", "nan"], "--density: expected a finite number"),
            (["--seed", "-1"], "--seed: expected an integer >= 0"),
            (["--order", "0"], "--order: expected an integer >= 1"),
            (["--order", "two"], "argument --order: invalid int value"),
        ],
    )
    def test_bad_options(self, tmp_path, capsys, args, match):
        out = tmp_path / "demo"
        assert_one_line_error(capsys, main(["demo", "--out", str(out), *args]), match)
        assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# detect
# --------------------------------------------------------------------------------------------


class TestDetect:
    def test_matches_api(self, tmp_path, cube_file, scene, capsys):
        out = tmp_path / "out"
        assert main(["detect", str(cube_file), "--method", "hoc", "--out", str(out)]) == 0
        stdout = capsys.readouterr().out
        expected = detect(scene.cube)
        assert written(out) == [
            "cleaned.npy",
            "detection.png",
            "detections.csv",
            "support.npy",
            "tracks.json",
        ]
        tracks, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert [t["id"] for t in tracks] == [t.id for t in expected.tracks]
        assert [t["score"] for t in tracks] == pytest.approx([t.score for t in expected.tracks])
        for got, want in zip(tracks, expected.tracks):
            assert torch.equal(got["points"], want.points)
        assert meta["method"] == "hoc"
        assert (meta["order"], meta["v"], meta["delta"], meta["threshold"]) == (2, 4, 45.0, 2.5)
        assert meta["min_points"] == 5
        assert meta["input_shape"] == [10, 60, 60]
        assert meta["points_in"] == int(scene.cube.sum())
        assert meta["points_out"] == int(expected.cleaned.sum())
        assert meta["points_support"] == int(expected.support.sum())
        cleaned = np.load(out / "cleaned.npy")
        support = np.load(out / "support.npy")
        assert cleaned.dtype == np.bool_ and support.dtype == np.bool_
        assert np.array_equal(cleaned, expected.cleaned.numpy())
        assert np.array_equal(support, expected.support.numpy())
        assert_png(out / "detection.png")
        assert f"{len(expected.tracks)} tracks" in stdout
        assert f"points in: {meta['points_in']}" in stdout
        assert f"kept on tracks: {meta['points_out']}" in stdout

    def test_options_are_passed(self, tmp_path, cube_file, scene):
        out = tmp_path / "out"
        args = ["detect", str(cube_file), "--out", str(out), "--no-plot"]
        args += [
            "--order",
            "1",
            "--v",
            "3",
            "--delta",
            "30",
            "--threshold",
            "2",
            "--min-points",
            "4",
        ]
        assert main(args) == 0
        expected = detect(scene.cube, 1, 3, math.radians(30), threshold=2.0, min_points=4)
        tracks, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert [t["points"].tolist() for t in tracks] == [
            t.points.tolist() for t in expected.tracks
        ]
        assert (meta["order"], meta["v"], meta["delta"], meta["min_points"]) == (1, 3, 30.0, 4)
        assert not (out / "detection.png").exists()

    def test_batched_npz(self, tmp_path, capsys):
        targets = [TargetSpec((2, 3), (2, 1)), TargetSpec((20, 18), (-2, -1))]
        scenes = simulate_binary((8, 24, 24), targets, clutter_density=0.02, batch=2, seed=2)
        path = tmp_path / "scenes.npz"
        save_cube(path, scenes.cube.to(torch.uint8), key="scans")
        out = tmp_path / "out"
        assert main(["detect", str(path), "--key", "scans", "--out", str(out)]) == 0
        expected = detect(scenes.cube)
        tracks, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["input_shape"] == [2, 8, 24, 24] and meta["key"] == "scans"
        assert meta["track_batch"] == [t.batch for t in expected.tracks]
        assert set(meta["track_batch"]) == {0, 1}
        assert [t["id"] for t in tracks] == list(range(1, len(tracks) + 1))
        assert np.load(out / "cleaned.npy").shape == (2, 8, 24, 24)
        assert np.array_equal(np.load(out / "support.npy"), expected.support.numpy())
        for name in ("detection_000.png", "detection_001.png"):
            assert_png(out / name)
        assert "2 x 8 x 24 x 24" in capsys.readouterr().out

    def test_large_batch_scene_by_scene(self, tmp_path, capsys):
        """From 8 scenes on, detection runs scene by scene (progress bar); same result."""
        targets = [TargetSpec((1, 2), (2, 1)), TargetSpec((14, 12), (-2, 0))]
        scenes = simulate_binary((6, 16, 16), targets, clutter_density=0.03, batch=8, seed=4)
        path = tmp_path / "many.npy"
        save_cube(path, scenes.cube)
        out = tmp_path / "out"
        assert main(["detect", str(path), "--out", str(out), "--no-plot"]) == 0
        expected = detect(scenes.cube)
        tracks, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert [(t["id"], t["points"].tolist()) for t in tracks] == [
            (t.id, t.points.tolist()) for t in expected.tracks
        ]
        assert meta["track_batch"] == [t.batch for t in expected.tracks]
        assert np.array_equal(np.load(out / "cleaned.npy"), expected.cleaned.numpy())
        assert np.array_equal(np.load(out / "support.npy"), expected.support.numpy())

    def test_existing_output_dir(self, tmp_path, cube_file):
        out = tmp_path / "out"
        out.mkdir()
        (out / "notes.txt").write_text("keep me")
        (out / "tracks.json").write_text("old")  # the user's own: replaced with --force only
        argv = ["detect", str(cube_file), "--out", str(out), "--no-plot"]
        assert main([*argv, "--force"]) == 0
        assert (out / "notes.txt").read_text() == "keep me"
        assert load_tracks_json(out / "tracks.json")  # replaced by the new result
        assert no_leftovers(tmp_path) == []

    @pytest.mark.parametrize(
        ("case", "extra", "match"),
        [
            ("rank", [], r"CUBE: .* expected shape \(T, H, W\) or \(B, T, H, W\), got \(60, 60\)"),
            ("nonbinary", [], r"expected binary values"),
            ("missing", [], r"CUBE: no such file"),
            ("garbage", [], r"CUBE: .*garbage\.npy' is not a valid \.npy file"),
            ("extension", [], r"CUBE: expected a \.npy or \.npz file"),
            ("ok", ["--v", "0"], r"^hocnet: error: --v: expected an integer >= 1, got 0$"),
            ("ok", ["--order", "0"], r"--order: expected an integer >= 1, got 0"),
            ("ok", ["--delta", "0"], r"--delta: expected a number in \(0, 180\], got 0"),
            ("ok", ["--delta", "180.5"], r"--delta: expected a number in \(0, 180\]"),
            ("ok", ["--delta", "-45"], r"--delta: expected a number in \(0, 180\]"),
            ("ok", ["--delta", "inf"], r"--delta: expected a finite number"),
            ("ok", ["--min-points", "0"], r"--min-points: expected an integer >= 1"),
            ("ok", ["--threshold", "nan"], r"--threshold: expected a finite number"),
            ("ok", ["--v", "2.5"], r"argument --v: invalid int value: '2.5'"),
            ("ok", ["--method", "nope"], r"argument --method: invalid choice: 'nope'"),
            ("ok", ["--key", "cube"], r"--key: expected no --key for the \.npy file"),
            ("ok", ["--bogus"], r"unrecognized arguments: --bogus"),
            ("npz", ["--key", "nope"], r"--key: expected one of 'a', 'b'"),
            ("npz", [], r"--key: expected one of 'a', 'b' .* got no --key"),
        ],
    )
    def test_bad_input(self, tmp_path, capsys, scene, case, extra, match):
        inputs = tmp_path / "inputs"
        inputs.mkdir()
        files = {
            "ok": "ok.npy",
            "rank": "rank.npy",
            "nonbinary": "nonbinary.npy",
            "missing": "missing.npy",
            "garbage": "garbage.npy",
            "extension": "cube.txt",
            "npz": "two.npz",
        }
        path = inputs / files[case]
        if case in ("ok", "extension"):
            np.save(inputs / "ok.npy", scene.cube.numpy())
            if case == "extension":
                path.write_bytes((inputs / "ok.npy").read_bytes())
        elif case == "rank":
            np.save(path, scene.cube[0].numpy())
        elif case == "nonbinary":
            np.save(path, scene.cube.numpy() * 2.0)
        elif case == "garbage":
            path.write_bytes(b"this is not numpy")
        elif case == "npz":
            np.savez(path, a=scene.cube.numpy(), b=scene.cube.numpy())
        before = sorted(p.name for p in inputs.iterdir())
        out = tmp_path / "a" / "b" / "out"
        code = main(["detect", str(path), "--out", str(out), *extra])
        assert_one_line_error(capsys, code, match)
        assert not (tmp_path / "a").exists()  # nothing written, not even parents
        assert sorted(p.name for p in inputs.iterdir()) == before
        assert no_leftovers(tmp_path) == []

    def test_out_is_a_file(self, tmp_path, capsys, cube_file):
        target = tmp_path / "taken"
        target.write_text("x")
        code = main(["detect", str(cube_file), "--out", str(target)])
        assert_one_line_error(capsys, code, r"--out: expected a directory, got the existing file")
        assert target.read_text() == "x"

    def test_failed_write_leaves_nothing(self, tmp_path, capsys, cube_file, monkeypatch):
        def broken(path, cube, **kwargs):
            raise OSError("disk full")

        monkeypatch.setattr("hocnet.data.io.save_cube", broken)
        out = tmp_path / "new" / "out"
        code = main(["detect", str(cube_file), "--out", str(out), "--no-plot"])
        assert_one_line_error(capsys, code, "disk full")
        assert not (tmp_path / "new").exists()
        assert no_leftovers(tmp_path) == []

    def test_new_method_plugs_in(self, tmp_path, capsys, cube_file, monkeypatch):
        """A second method (as DPA will be) only needs a registry entry."""

        def add_options(group):
            group.add_argument("--gain", type=float, default=None)

        def prepare(args):
            return {"gain": 1.0 if args.gain is None else args.gain}

        def run(cube, params):
            empty = torch.zeros_like(cube)
            result = HOCResult(support=cube, tracks=[], scores=empty.double(), cleaned=empty)
            return cli.Detection(result=result, params=params)

        fake = cli._Method("fake", "a test method", add_options, ("gain",), prepare, run)
        monkeypatch.setitem(cli._METHODS, "fake", fake)
        out = tmp_path / "out"
        code = main(
            ["detect", str(cube_file), "--method", "fake", "--gain", "3", "--out", str(out)]
        )
        assert code == 0
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["method"] == "fake" and meta["gain"] == 3.0 and meta["points_out"] == 0
        capsys.readouterr()
        # an option of another method is rejected, not silently ignored
        code = main(["detect", str(cube_file), "--method", "fake", "--order", "3"])
        assert_one_line_error(capsys, code, r"--order: applies to --method hoc, not fake")
        code = main(["detect", str(cube_file), "--gain", "3", "--out", str(tmp_path / "x")])
        assert_one_line_error(capsys, code, r"--gain: applies to --method fake, not hoc")
        assert not (tmp_path / "x").exists()


# --------------------------------------------------------------------------------------------
# reproduce
# --------------------------------------------------------------------------------------------

EXPERIMENT = '''\
"""A fake experiment."""
import io
import json
from pathlib import Path

from _shared import UNIT

NAME = "{name}"
DESCRIPTION = "{description}"


def run(*, quick=False, seeds=None, out_dir=None, progress=True):
    out_dir = Path(out_dir) if out_dir is not None else Path(__file__).parent / "results"
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / (NAME + ".md")
    args = {{"quick": quick, "seeds": seeds, "out_dir": str(out_dir), "progress": progress}}
    target.write_text(json.dumps(args) + UNIT)
    return target
'''


@pytest.fixture
def experiments(tmp_path):
    folder = tmp_path / "experiments"
    folder.mkdir()
    (folder / "_shared.py").write_text('UNIT = "\\n"\n')  # helper: skipped, but importable
    for stem, name, description in [
        ("hoc_table2", "hoc-table2", "Table II of [LA98]: two straight tracks"),
        ("hoc_table3", "hoc-table3", "Table III of [LA98]: crossing, splitting, parallel"),
    ]:
        text = EXPERIMENT.format(name=name, description=description)
        (folder / f"{stem}.py").write_text(text)
    (folder / "notes.py").write_text("X = 1\n")  # no NAME: not an experiment
    return folder


@pytest.fixture(scope="module")
def ir_sequence():
    from hocnet.data.infrared import IRTarget, simulate_ir

    target = IRTarget(6.0, 8.0, 0.8, 0.3, snr_db=15.0)
    return simulate_ir((12, 24, 28), [target], clouds="clear", jitter=0.0, seed=3)


@pytest.fixture
def frames_file(tmp_path, ir_sequence):
    path = tmp_path / "frames.npy"
    save_cube(path, ir_sequence.frames)
    return path


class TestDetectDPA:
    def test_outputs_match_the_library(self, tmp_path, frames_file, ir_sequence, capsys):
        from hocnet.data.whitening import anti_mean
        from hocnet.dpa import detect as dpa_detect
        from hocnet.dpa import effective_memory, probability_matrices

        out = tmp_path / "out"
        args = ["detect", str(frames_file), "--method", "dpa", "--preset", "paper", "--g", "0"]
        code = main([*args, "--out", str(out)])
        assert code == 0
        assert "dpa: " in capsys.readouterr().out
        assert written(out) == [
            "asf.npy",
            "detection.png",
            "detections.csv",
            "tracks.json",
        ]
        assert_png(out / "detection.png")
        tracks, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        # the paper's DPA: the library's defaults (7 x 7, v_max 2 + 0.5 jitter, EMC 0.8 of
        # direction 9, the paper's direction step), anti-mean whitening, no background removal
        weights = probability_matrices()
        b = float(effective_memory(weights, 0.0))
        assert b == pytest.approx(4.67, abs=0.01)
        expected = dpa_detect(anti_mean(ir_sequence.frames), weights, b, 0.0)
        assert meta["confirmed"] is False and "unthresholded" in meta["note"]
        assert meta["method"] == "dpa" and meta["b"] == pytest.approx(b)
        assert [t["points"].tolist() for t in tracks] == [
            t.points.tolist() for t in expected.tracks
        ]
        asf = np.load(out / "asf.npy")
        np.testing.assert_allclose(asf, expected.state.asf.numpy(), rtol=1e-6, atol=1e-6)
        # the strongest track ends on the target
        first = tracks[0]["points"]
        truth = ir_sequence.positions[0]
        err = (first[:, [2, 1]].double() - truth).norm(dim=-1)
        assert err[-1] <= 1.5

    @pytest.mark.parametrize("preset", ["paper", "recommended"])
    def test_strongest_track_ends_on_the_target(self, tmp_path, frames_file, ir_sequence, preset):
        # The strongest track ends on the target with either preset. Its back-tracked path lags
        # behind this PSF-spread 15 dB target moving 0.85 px/frame over 12 frames (on the truth
        # in 3 of 12 frames): eq. (7) of [NR08] scores the sources with W_basic, which favours
        # "in place" (a limitation of the paper's direction step, see accumulate's Notes).
        out = tmp_path / "out"
        args = ["detect", str(frames_file), "--method", "dpa", "--preset", preset]
        assert main([*args, "--out", str(out)]) == 0
        tracks = load_tracks_json(out / "tracks.json")
        err = (tracks[0]["points"][:, [2, 1]].double() - ir_sequence.positions[0]).norm(dim=-1)
        assert err[-1] <= 1.5

    def test_equal_gain(self, tmp_path, frames_file, ir_sequence):
        from hocnet.data.whitening import anti_mean
        from hocnet.dpa import detect as dpa_detect
        from hocnet.dpa import effective_memory, equalize_gain, probability_matrices

        out = tmp_path / "out"
        args = ["detect", str(frames_file), "--method", "dpa", "--preset", "paper", "--g", "0"]
        assert main([*args, "--equal-gain", "--out", str(out)]) == 0
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        weights = equalize_gain(probability_matrices(), 0.0)
        b = float(effective_memory(weights, 0.0))
        expected = dpa_detect(anti_mean(ir_sequence.frames), weights, b, 0.0)
        assert meta["equal_gain"] is True and meta["b"] == pytest.approx(b)
        np.testing.assert_allclose(
            np.load(out / "asf.npy"), expected.state.asf.numpy(), rtol=1e-6, atol=1e-6
        )

    @pytest.mark.parametrize("preset", [None, "recommended", "paper"])
    def test_defaults_come_from_the_preset(self, tmp_path, frames_file, ir_sequence, preset):
        # issue 9: --g defaulted to 1 in the CLI and 0.5 in DPA(), --v-max to 2.5 and 1.0
        from hocnet.data.background import estimate_shifts, remove_background
        from hocnet.data.whitening import anti_mean
        from hocnet.dpa import detect as dpa_detect
        from hocnet.dpa import effective_memory, equalize_gain, probability_matrices
        from hocnet.dpa.presets import PRESETS

        chosen = PRESETS[preset or "recommended"]
        out = tmp_path / "out"
        extra = [] if preset is None else ["--preset", preset]
        assert main(["detect", str(frames_file), "--method", "dpa", *extra, "--out", str(out)]) == 0
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["preset"] == chosen.name
        assert (meta["window"], meta["v_max"], meta["g"]) == (chosen.window, chosen.v_max, chosen.g)
        assert meta["equal_gain"] is chosen.equal_gain and meta["whiten"] == chosen.whitening
        assert (meta["register"], meta["background"]) == (chosen.register, chosen.background)
        weights = probability_matrices(window=chosen.window, v_max=chosen.v_max)
        if chosen.equal_gain:
            weights = equalize_gain(weights, chosen.g)
        b = float(effective_memory(weights, chosen.g, chosen.memory))
        x = ir_sequence.frames.float()
        if chosen.background != "none":
            offsets = estimate_shifts(x).cumsum(dim=0) if chosen.register else None
            x = remove_background(x, chosen.background, chosen.background_window, offsets=offsets)
        expected = dpa_detect(anti_mean(x), weights, b, chosen.g)
        assert meta["b"] == pytest.approx(b)
        np.testing.assert_allclose(
            np.load(out / "asf.npy"), expected.state.asf.numpy(), rtol=1e-6, atol=1e-6
        )

    def test_recommended_differs_from_paper_and_help_says_which(self, capsys):
        from hocnet.dpa.presets import PAPER, RECOMMENDED

        assert RECOMMENDED != PAPER
        assert (RECOMMENDED.window, RECOMMENDED.v_max, RECOMMENDED.g) == (5, 1.0, 0.0)
        assert RECOMMENDED.equal_gain and RECOMMENDED.whitening == "mean"
        assert main(["detect", "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        assert "--preset" in text and "hocnet.dpa.presets.RECOMMENDED" in text
        assert "default: 5 (--preset recommended), 7 (--preset paper)" in text
        assert "default: on (--preset recommended), off (--preset paper)" in text  # --register
        assert "default: median (--preset recommended), none (--preset paper)" in text
        assert "tuned on those six clips" in text and "0.985" in text

    def test_no_equal_gain(self, tmp_path, frames_file):
        out = tmp_path / "out"
        args = ["detect", str(frames_file), "--method", "dpa", "--no-equal-gain"]
        assert main([*args, "--out", str(out)]) == 0
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["equal_gain"] is False

    def test_equal_gain_is_a_dpa_option(self, tmp_path, capsys):
        cube = tmp_path / "cube.npy"
        np.save(cube, np.zeros((6, 8, 8), dtype=bool))
        out = tmp_path / "out"
        code = main(["detect", str(cube), "--method", "hoc", "--equal-gain", "--out", str(out)])
        assert_one_line_error(capsys, code, r"--equal-gain: applies to --method dpa")
        assert not out.exists()

    def test_cfar_threshold_from_target_free_frames(self, tmp_path, frames_file, ir_sequence):
        free = tmp_path / "free.npy"
        save_cube(free, ir_sequence.target_free)
        out = tmp_path / "out"
        args = ["detect", str(frames_file), "--method", "dpa", "--target-free", str(free)]
        assert main([*args, "--pfa", "0.01", "--out", str(out)]) == 0
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["cfar"] is True and meta["threshold_used"] is not None

    @pytest.mark.parametrize(
        ("extra", "match"),
        [
            (["--g", "1.5"], r"--g: expected a number in \[0, 1\]"),
            (["--b", "-1"], r"--b: expected a number in \[0, inf\)"),
            (["--window", "99"], r"--window: expected at most the frame size"),
            (["--window", "4"], r"--window: expected an odd integer"),
            (["--order", "3"], r"--order: applies to --method hoc"),
            (["--pfa", "0"], r"--pfa"),
        ],
    )
    def test_bad_options(self, tmp_path, frames_file, capsys, extra, match):
        out = tmp_path / "out"
        code = main(["detect", str(frames_file), "--method", "dpa", *extra, "--out", str(out)])
        assert_one_line_error(capsys, code, match)
        assert not out.exists() and no_leftovers(tmp_path) == []

    @pytest.mark.parametrize(
        ("mutate", "match"),
        [
            (lambda a: np.where(np.arange(a.size).reshape(a.shape) == 7, np.nan, a), "finite"),
            (lambda a: a[0], r"shape \(T, H, W\)"),
        ],
    )
    def test_bad_frames(self, tmp_path, ir_sequence, capsys, mutate, match):
        path = tmp_path / "bad.npy"
        np.save(path, mutate(ir_sequence.frames.numpy()))
        out = tmp_path / "out"
        code = main(["detect", str(path), "--method", "dpa", "--out", str(out)])
        assert_one_line_error(capsys, code, match)
        assert not out.exists()


class TestReproduce:
    def test_list(self, experiments, capsys):
        code = main(["reproduce", "--list", "--experiments-dir", str(experiments)])
        out, err = capsys.readouterr()
        assert code == 0 and err == ""
        assert out.splitlines() == [
            "hoc-table2  Table II of [LA98]: two straight tracks",
            "hoc-table3  Table III of [LA98]: crossing, splitting, parallel",
        ]

    def test_list_from_environment_with_broken_script(self, experiments, capsys, monkeypatch):
        (experiments / "broken.py").write_text("import no_such_module_hocnet\n")
        monkeypatch.setenv(cli.EXPERIMENTS_ENV, str(experiments))
        assert main(["reproduce", "--list"]) == 0
        out, err = capsys.readouterr()
        assert "hoc-table2" in out and "hoc-table3" in out
        assert "broken.py: could not import (ModuleNotFoundError" in err

    @pytest.mark.parametrize("name", ["hoc-table3", "hoc_table3"])
    def test_run(self, experiments, tmp_path, capsys, name):
        out = tmp_path / "results"
        args = ["reproduce", name, "--quick", "--seeds", "3", "--out", str(out)]
        assert main([*args, "--experiments-dir", str(experiments)]) == 0
        written = out / "hoc-table3.md"
        assert json.loads(written.read_text()) == {
            "quick": True,
            "seeds": 3,
            "out_dir": str(out),
            "progress": False,  # stderr is not a terminal under pytest
        }
        assert "hoc-table3: done in" in capsys.readouterr().out

    def test_run_defaults(self, experiments, capsys):
        assert main(["reproduce", "hoc-table2", "--experiments-dir", str(experiments)]) == 0
        written = experiments / "results" / "hoc-table2.md"
        args = json.loads(written.read_text())
        assert (args["quick"], args["seeds"]) == (False, None)
        assert str(written) in capsys.readouterr().out

    @pytest.mark.parametrize(
        ("args", "match"),
        [
            (["nope"], r"unknown experiment 'nope'; available: hoc-table2, hoc-table3"),
            ([], r"expected an experiment NAME or --list"),
            (["hoc-table2", "--list"], r"either NAME or --list"),
            (["hoc-table2", "--seeds", "0"], r"--seeds: expected an integer >= 1"),
        ],
    )
    def test_bad_input(self, experiments, capsys, args, match):
        code = main(["reproduce", *args, "--experiments-dir", str(experiments)])
        assert_one_line_error(capsys, code, match)
        assert not (experiments / "results").exists()

    def test_missing_folder(self, tmp_path, capsys, monkeypatch):
        monkeypatch.setenv(cli.EXPERIMENTS_ENV, str(tmp_path / "nowhere"))
        code = main(["reproduce", "--list"])
        assert_one_line_error(capsys, code, r"experiments folder '.*nowhere' .* does not exist")

    def test_default_folder_is_the_repository(self, monkeypatch):
        monkeypatch.delenv(cli.EXPERIMENTS_ENV, raising=False)
        repo = Path(cli.__file__).resolve().parents[2]
        if (repo / "experiments").is_dir():
            assert cli.experiments_dir() == repo / "experiments"
        else:
            with pytest.raises(cli.CLIError, match="installed without its repository"):
                cli.experiments_dir()


# --------------------------------------------------------------------------------------------
# help and the installed script
# --------------------------------------------------------------------------------------------


class TestHelp:
    @pytest.mark.parametrize(
        ("command", "words"),
        [
            ([], ["demo", "detect", "reproduce"]),
            (["demo"], ["--out", "--seed", "--density", "--order", "demo-output"]),
            (["detect"], ["--method", "--delta", "DEGREES", "--min-points", "(B, T, H, W)"]),
            (["reproduce"], ["--list", "--quick", "--seeds", cli.EXPERIMENTS_ENV]),
        ],
    )
    def test_help(self, capsys, command, words):
        assert main([*command, "--help"]) == 0
        out = capsys.readouterr().out
        assert out.startswith("usage: hocnet")
        for word in words:
            assert word in out
        assert "--experiments-dir" not in out

    def test_help_describes_both_methods_and_their_outputs(self, capsys):
        # issue 9: `hocnet --help` described only HOC, `detect --help` only HOC's outputs
        assert main(["--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        for word in ("(HOC) of [LA98]", "BINARY", "(DPA) of [NR08]", "INTENSITY", "asf.npy"):
            assert word in text, word
        assert main(["detect", "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        for word in (
            "outputs of --method hoc",
            "outputs of --method dpa",
            "cleaned.npy",
            "support.npy",
            "asf.npy",
            "each track with its score",
            "[LA98] R.-J. Liou",
            "[NR08] O. Nichtern",
            "hocnet.data.save_cube",
        ):
            assert word in text, word
        assert "DESIGN" not in text

    def test_no_command(self, capsys):
        assert_one_line_error(capsys, main([]), "required: COMMAND")

    def test_console_script(self):
        script = Path(sys.executable).parent / ("hocnet.exe" if os.name == "nt" else "hocnet")
        assert script.is_file(), "run `pip install -e . --no-deps` to install the console script"
        done = subprocess.run(
            [str(script), "--help"], capture_output=True, text=True, timeout=120, check=False
        )
        assert done.returncode == 0, done.stderr
        assert "usage: hocnet" in done.stdout and "reproduce" in done.stdout


# --------------------------------------------------------------------------------------------
# issue 9: a user's data is never lost, every bad input gets a clear answer
# --------------------------------------------------------------------------------------------


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes); symlinks by their target."""
    out = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
        if path.is_symlink():
            out[key] = b"-> " + os.readlink(path).encode()
        elif path.is_file():
            out[key] = path.read_bytes()
        else:
            out[key] = b"<dir>"
    return out


class TestNoDataLoss:
    @pytest.mark.parametrize("name", ["cleaned.npy", "support.npy"])
    def test_output_never_replaces_the_input(self, tmp_path, capsys, scene, name):
        # issue 9: `hocnet detect own/cleaned.npy --out own` overwrote the input
        own = tmp_path / "own"
        own.mkdir()
        save_cube(own / name, scene.cube)
        before = snapshot(tmp_path)
        code = main(["detect", str(own / name), "--out", str(own)])
        line = assert_one_line_error(capsys, code, rf"--out: writing '.*{name}' would replace")
        assert "input CUBE" in line
        assert snapshot(tmp_path) == before

    def test_output_never_replaces_the_input_through_a_symlink(self, tmp_path, capsys, scene):
        data = tmp_path / "data"
        data.mkdir()
        save_cube(data / "scene.npy", scene.cube)
        out = tmp_path / "out"
        out.mkdir()
        (out / "cleaned.npy").symlink_to(data / "scene.npy")
        before = snapshot(tmp_path)
        # the input given through another symlinked folder, too
        (tmp_path / "alias").symlink_to(data)
        before["alias"] = b"-> " + str(data).encode()
        code = main(["detect", str(tmp_path / "alias" / "scene.npy"), "--out", str(out)])
        assert_one_line_error(capsys, code, r"would replace the input CUBE")
        assert snapshot(tmp_path) == before

    def test_output_never_replaces_the_target_free_input(
        self, tmp_path, capsys, frames_file, ir_sequence
    ):
        out = tmp_path / "out"
        out.mkdir()
        save_cube(out / "asf.npy", ir_sequence.target_free)
        before = snapshot(tmp_path)
        args = ["detect", str(frames_file), "--method", "dpa", "--target-free"]
        code = main([*args, str(out / "asf.npy"), "--out", str(out)])
        assert_one_line_error(capsys, code, r"would replace the input --target-free")
        assert snapshot(tmp_path) == before

    def test_all_or_nothing_when_a_destination_is_a_directory(self, tmp_path, capsys, cube_file):
        # issue 9: tracks.json was overwritten and cleaned/support written before exit 2,
        # and the message named an internal temporary path
        part = tmp_path / "part"
        (part / "detection.png").mkdir(parents=True)
        (part / "tracks.json").write_text("old")
        before = snapshot(tmp_path)
        code = main(["detect", str(cube_file), "--out", str(part)])
        line = assert_one_line_error(capsys, code, r"--out: cannot write '.*detection\.png'")
        assert ".tmp" not in line and "a directory of that name exists" in line
        assert snapshot(tmp_path) == before

    def test_failed_move_rolls_back(self, tmp_path, capsys, cube_file, monkeypatch):
        out = tmp_path / "out"
        # the files of an earlier run (hocnet's, so a rerun may replace them)
        assert main(["detect", str(cube_file), "--out", str(out), "--no-plot", "--v", "3"]) == 0
        capsys.readouterr()
        before = snapshot(tmp_path)
        real_replace = os.replace
        calls = []

        def flaky_replace(src, dst):
            calls.append((src, dst))
            if (
                Path(dst).name == "support.npy"
                and ".tmp-" in str(src)
                and ".previous" not in str(dst)
            ):
                raise OSError(5, "Input/output error")
            return real_replace(src, dst)

        monkeypatch.setattr(cli.os, "replace", flaky_replace)
        code = main(["detect", str(cube_file), "--out", str(out), "--no-plot"])
        monkeypatch.undo()
        line = assert_one_line_error(capsys, code, r"--out: could not write '.*support\.npy'")
        assert ".tmp" not in line
        assert snapshot(tmp_path) == before

    @pytest.mark.parametrize(
        "error",
        [OSError(28, "No space left on device"), OSError("163840 requested and 159616 written")],
    )
    def test_disk_full(self, tmp_path, capsys, cube_file, monkeypatch, error):
        def full(handle, array, allow_pickle=False):
            handle.write(b"\x93NUMPY")
            raise error

        monkeypatch.setattr("hocnet.data.io.np.save", full)
        out = tmp_path / "out"
        code = main(["detect", str(cube_file), "--out", str(out), "--no-plot"])
        line = assert_one_line_error(capsys, code, r"no space left on device")
        assert f"'{out / 'cleaned.npy'}'" in line and ".tmp" not in line
        assert not out.exists() and no_leftovers(tmp_path) == []

    @pytest.mark.parametrize("command", ["detect", "demo", "reproduce"])
    def test_empty_out_is_refused(
        self, tmp_path, capsys, cube_file, experiments, command, monkeypatch
    ):
        monkeypatch.chdir(tmp_path)
        before = snapshot(tmp_path)
        argv = {
            "detect": ["detect", str(cube_file)],
            "demo": ["demo", "--no-dpa"],
            "reproduce": ["reproduce", "hoc-table2", "--experiments-dir", str(experiments)],
        }[command]
        code = main([*argv, "--out", ""])
        assert_one_line_error(capsys, code, r"--out: expected a folder name, got an empty string")
        assert snapshot(tmp_path) == before

    def test_quick_reproduce_never_touches_the_results(self, experiments, capsys):
        # issue 9: `hocnet reproduce NAME --quick` overwrote experiments/results/ with smoke numbers
        results = experiments / "results"
        results.mkdir()
        (results / "hoc-table2.md").write_text("full run")
        code = main(["reproduce", "hoc-table2", "--quick", "--experiments-dir", str(experiments)])
        assert code == 0
        assert (results / "hoc-table2.md").read_text() == "full run"
        printed = capsys.readouterr().out
        written = Path(re.search(r"results in (\S+\.md)", printed).group(1))
        assert written.is_file() and results not in written.parents
        assert json.loads(written.read_text())["quick"] is True
        # asked explicitly: then it does write there
        args = ["reproduce", "hoc-table2", "--quick", "--out", str(results)]
        assert main([*args, "--experiments-dir", str(experiments)]) == 0
        assert json.loads((results / "hoc-table2.md").read_text())["quick"] is True


class TestOwnFiles:
    """A user's own files in --out are never replaced without --force (the manifest)."""

    REFUSED = r"--out: .* not written by hocnet \(or (was|were) changed since\); use --force"

    @staticmethod
    def argv(kind, cube_file, frames_file, out):
        return {
            "hoc": ["detect", str(cube_file), "--no-plot"],
            "dpa": ["detect", str(frames_file), "--method", "dpa", "--no-plot"],
            "demo": ["demo", "--no-dpa", "--density", "0.005"],
        }[kind] + ["--out", str(out)]

    @pytest.mark.parametrize(
        ("kind", "own"),
        [
            ("hoc", ["tracks.json"]),
            ("hoc", ["cleaned.npy", "detections.csv"]),
            ("dpa", ["tracks.json", "detections.csv", "asf.npy"]),  # the new user's report
            ("demo", ["demo_3d.png"]),
        ],
    )
    def test_own_file_is_refused_and_nothing_is_written(
        self, tmp_path, capsys, cube_file, frames_file, kind, own
    ):
        out = tmp_path / "own"
        out.mkdir()
        (out / "notes.txt").write_text("MINE")
        for name in own:
            (out / name).write_text("MINE\n")
        before = snapshot(tmp_path)
        code = main(self.argv(kind, cube_file, frames_file, out))
        line = assert_one_line_error(capsys, code, self.REFUSED)
        listed = re.findall(r"'([^']+)'", line.split(" not written")[0])
        assert sorted(Path(p).name for p in listed) == sorted(own)  # every one, in one message
        assert ("exists and was" in line) == (len(own) == 1)
        assert snapshot(tmp_path) == before  # byte-identical, no manifest, no staging folder
        # --force replaces them (and keeps the user's other files)
        assert main([*self.argv(kind, cube_file, frames_file, out), "--force"]) == 0
        printed = capsys.readouterr().out
        assert MANIFEST not in printed and ".tmp" not in printed
        assert all((out / name).read_bytes() != b"MINE\n" for name in own)
        assert (out / "notes.txt").read_text() == "MINE"
        assert set(own) <= set(json.loads((out / MANIFEST).read_text()))

    @pytest.mark.parametrize("kind", ["hoc", "dpa", "demo"])
    def test_rerun_into_the_same_folder(self, tmp_path, capsys, cube_file, frames_file, kind):
        out = tmp_path / "out"
        argv = self.argv(kind, cube_file, frames_file, out)
        assert main(argv) == 0
        first = written(out)
        manifest = json.loads((out / MANIFEST).read_text())
        assert manifest == {n: [(out / n).stat().st_size, (out / n).stat().st_mtime_ns]
                            for n in first}  # fmt: skip
        assert main(argv) == 0  # hocnet's own files: replaced
        assert written(out) == first
        printed = capsys.readouterr().out
        assert MANIFEST not in printed and ".tmp" not in printed
        assert no_leftovers(tmp_path) == []

    def test_manifest_merges_runs_and_keeps_other_files(self, tmp_path, cube_file, frames_file):
        out = tmp_path / "out"
        assert main(self.argv("hoc", cube_file, frames_file, out)) == 0
        assert main(self.argv("dpa", cube_file, frames_file, out)) == 0  # tracks.json again
        assert written(out) == [
            "asf.npy", "cleaned.npy", "detections.csv", "shifts.csv", "support.npy", "tracks.json"
        ]  # fmt: skip
        assert main(self.argv("hoc", cube_file, frames_file, out)) == 0

    @pytest.mark.parametrize("edit", ["append", "touch", "symlink"])
    def test_output_changed_by_the_user_is_refused(
        self, tmp_path, capsys, cube_file, frames_file, edit
    ):
        out = tmp_path / "out"
        argv = self.argv("hoc", cube_file, frames_file, out)
        assert main(argv) == 0
        capsys.readouterr()
        path = out / "detections.csv"
        if edit == "append":  # the same mtime would not do: the size differs
            with open(path, "a") as handle:
                handle.write("# my notes\n")
        elif edit == "touch":  # same size, another modification time
            st = path.stat()
            os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
        else:
            (tmp_path / "mine.csv").write_text("MINE")
            path.unlink()
            path.symlink_to(tmp_path / "mine.csv")
        before = snapshot(tmp_path)
        line = assert_one_line_error(capsys, main(argv), self.REFUSED)
        assert f"'{path}' exists and was not written by hocnet" in line
        assert snapshot(tmp_path) == before
        assert main([*argv, "--force"]) == 0
        if edit == "symlink":
            assert not path.is_symlink() and (tmp_path / "mine.csv").read_text() == "MINE"

    @pytest.mark.parametrize(
        "manifest", ["{not json", "[1, 2]", '{"tracks.json": "x"}', '{"tracks.json": [1]}', ""]
    )
    def test_corrupt_manifest_is_empty(self, tmp_path, capsys, cube_file, frames_file, manifest):
        out = tmp_path / "out"
        argv = self.argv("hoc", cube_file, frames_file, out)
        assert main(argv) == 0
        capsys.readouterr()
        (out / MANIFEST).write_text(manifest)
        before = snapshot(tmp_path)
        line = assert_one_line_error(capsys, main(argv), self.REFUSED)  # refused, no crash
        assert "tracks.json" in line and "support.npy" in line
        assert snapshot(tmp_path) == before
        assert main([*argv, "--force"]) == 0  # --force writes a good manifest again
        assert written(out) and main(argv) == 0

    def test_manifest_that_cannot_be_written(self, tmp_path, capsys, cube_file, frames_file):
        out = tmp_path / "out"
        (out / MANIFEST).mkdir(parents=True)  # in the way: the outputs are still written
        assert main(self.argv("hoc", cube_file, frames_file, out)) == 0
        out_text, err = capsys.readouterr()
        assert "warning: could not record the outputs" in err and "--force" in err
        assert (out / "tracks.json").is_file() and MANIFEST not in out_text
        code = main(self.argv("hoc", cube_file, frames_file, out))
        assert_one_line_error(capsys, code, self.REFUSED)


class TestClearMessages:
    def run_dpa(self, tmp_path, array, *extra):
        path = tmp_path / "in.npy"
        np.save(path, array)
        return main(["detect", str(path), "--method", "dpa", "--out", str(tmp_path / "o"), *extra])

    @pytest.mark.parametrize(
        ("dtype", "big", "match"),
        [
            (np.float32, 3e38, r"CUBE '.*in\.npy': values too large for float32 after anti-mean"),
            (np.float64, 1e300, r"CUBE '.*in\.npy': values too large for float32, in which"),
        ],
    )
    @pytest.mark.parametrize("preset", ["paper", "recommended"])
    def test_huge_finite_frames(self, tmp_path, capsys, dtype, big, match, preset):
        array = np.full((6, 16, 16), -big, dtype=dtype)
        # a bright pixel in the last frame only: a pixel constant in time would be removed
        # exactly by the temporal background (0 everywhere, nothing overflows)
        array[-1, 8, 8] = big
        if preset == "recommended":  # the background removal overflows first
            match = match.replace("after anti-mean", "in the background removal")
        code = self.run_dpa(tmp_path, array, "--preset", preset)
        line = assert_one_line_error(capsys, code, match)
        assert "NaN/inf" not in line
        assert not (tmp_path / "o").exists()

    def test_text_file_named_npy(self, tmp_path, capsys):
        (tmp_path / "t.npy").write_text("1 2 3\n")
        code = main(["detect", str(tmp_path / "t.npy"), "--out", str(tmp_path / "o")])
        line = assert_one_line_error(capsys, code, r"CUBE: '.*t\.npy' is not a valid \.npy file")
        assert "pickle" not in line.lower()

    def test_uint64_above_int64(self, tmp_path, capsys):
        array = np.zeros((6, 16, 16), dtype=np.uint64)
        array[2, 3, 4] = 2**63 + 1
        code = self.run_dpa(tmp_path, array)
        assert_one_line_error(
            capsys, code, r"CUBE: .* holds uint64 values up to 9223372036854775809"
        )

    def test_api_names_become_flags(self, tmp_path, capsys, frames_file):
        # the library says `pfa` and `target_free`; the command line says --pfa, --target-free
        free = tmp_path / "free.npy"
        # frames of the input's size (24 x 28), two of them (the fewest the median background
        # allows): too few pixels for --pfa 1e-3
        np.save(free, np.random.default_rng(0).normal(size=(2, 24, 28)).astype(np.float32))
        args = ["detect", str(frames_file), "--method", "dpa", "--target-free", str(free)]
        code = main([*args, "--window", "5", "--out", str(tmp_path / "o")])
        line = assert_one_line_error(capsys, code, r"^hocnet: error: --pfa: ")
        assert "--target-free" in line and "`" not in line

    def test_translation_table(self):
        assert cli._to_flags("`target_free`: bad; `pfa`: bad", cli._FLAGS["dpa"]) == (
            "--target-free: bad; --pfa: bad"
        )
        assert cli._to_flags("`threshold`: x", cli._FLAGS["dpa"]) == "--asf-threshold: x"
        assert cli._to_flags("`threshold`: x", cli._FLAGS["hoc"]) == "--threshold: x"
        assert cli._to_flags("`cube`: x", cli._FLAGS["hoc"]) == "CUBE: x"
        assert cli._to_flags("`unknown`: x", cli._FLAGS["hoc"]) == "`unknown`: x"


class TestUpFrontBounds:
    @pytest.mark.parametrize(
        ("extra", "match"),
        [
            (["--v", "1000"], r"--v: expected at most max\(H, W\) - 1 = 23 for frames of 24 x 24"),
            (["--v", "50"], r"--v: expected at most max\(H, W\) - 1 = 23"),
            (["--order", "5"], r"--order: expected at most \(T - 1\) // 2 = 4 .* T = 10 scans"),
        ],
    )
    def test_hoc(self, tmp_path, capsys, extra, match):
        import time

        path = tmp_path / "c.npy"
        np.save(path, np.zeros((10, 24, 24), dtype=bool))
        start = time.perf_counter()
        code = main(["detect", str(path), "--out", str(tmp_path / "o"), *extra])
        assert time.perf_counter() - start < 5
        assert_one_line_error(capsys, code, match)

    def test_v_bounded_by_memory(self):
        params = {"order": 1, "v": 100}
        with pytest.raises(cli.CLIError, match=r"--v: expected at most 63 .* GiB\), got 100"):
            cli._bound_hoc(torch.zeros(3, 512, 512, dtype=torch.bool), params)

    def test_empty_batch(self, tmp_path, capsys):
        path = tmp_path / "z.npy"
        np.save(path, np.zeros((0, 6, 16, 16), dtype=bool))
        code = main(["detect", str(path), "--out", str(tmp_path / "o")])
        assert_one_line_error(capsys, code, r"CUBE: .* holds a batch of 0 scenes")
        assert not (tmp_path / "o").exists()


class _TTY(io.StringIO):
    def isatty(self):
        return True


class TestProgress:
    def test_bar_on_a_terminal(self, tmp_path, cube_file, monkeypatch):
        monkeypatch.setattr("hocnet.cli._common.PROGRESS_DELAY", 0.0)
        fake = _TTY()
        monkeypatch.setattr(sys, "stderr", fake)
        assert main(["detect", str(cube_file), "--out", str(tmp_path / "o"), "--no-plot"]) == 0
        text = fake.getvalue()
        assert "stage" in text and "load" in text and "hoc" in text and "write" in text

    def test_quiet(self, tmp_path, cube_file, monkeypatch):
        monkeypatch.setattr("hocnet.cli._common.PROGRESS_DELAY", 0.0)
        fake = _TTY()
        monkeypatch.setattr(sys, "stderr", fake)
        args = ["detect", str(cube_file), "--out", str(tmp_path / "o"), "--no-plot", "--quiet"]
        assert main(args) == 0
        assert fake.getvalue() == ""

    def test_not_a_terminal(self, tmp_path, cube_file, monkeypatch):
        monkeypatch.setattr("hocnet.cli._common.PROGRESS_DELAY", 0.0)
        fake = io.StringIO()
        monkeypatch.setattr(sys, "stderr", fake)
        assert main(["detect", str(cube_file), "--out", str(tmp_path / "o"), "--no-plot"]) == 0
        assert fake.getvalue() == ""

    @pytest.mark.parametrize("command", ["demo", "detect", "reproduce"])
    def test_every_command_has_quiet(self, capsys, command):
        assert main([command, "--help"]) == 0
        assert "--quiet" in capsys.readouterr().out


# --------------------------------------------------------------------------------------------
# real frames (issue 10): image folders, pre-processing, detections.csv
# --------------------------------------------------------------------------------------------


def _clip_arrays(n: int = 14, size: int = 32, seed: int = 0) -> np.ndarray:
    """8-bit frames: a fixed textured ground, noise, a bright 2 x 2 target moving right.

    The target moves 0.5 px/frame over the still ground (the registration locks on the ground).
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    ground = 20 * np.sin(xx / 3.0) * np.cos(yy / 4.0) + 15 * (rng.random((size, size)) > 0.9)
    frames = 60.0 + ground + rng.normal(0.0, 3.0, (n, size, size))
    for t in range(n):
        x = 8 + t // 2
        frames[t, 12:14, x : x + 2] += 45.0
    return np.clip(frames, 0, 255).astype(np.uint8)


@pytest.fixture
def png_clip(tmp_path):
    from PIL import Image

    folder = tmp_path / "clip"
    folder.mkdir()
    arrays = _clip_arrays()
    for t, a in enumerate(arrays):
        Image.fromarray(a).save(folder / f"f{t:02d}.png")
    return folder, arrays


def _read_csv(path: Path) -> list[dict[str, str]]:
    import csv

    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _digests(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.name != MANIFEST}


class TestRealFrames:
    def test_png_folder_dpa(self, tmp_path, png_clip, capsys):
        from hocnet.detection_metrics import read_detections

        folder, arrays = png_clip
        out = tmp_path / "out"
        assert main(["detect", str(folder), "--method", "dpa", "--out", str(out)]) == 0
        stdout = capsys.readouterr().out
        assert "registration:" in stdout and "shifts.csv" in stdout
        assert written(out) == [
            "asf.npy",
            "detection.png",
            "detections.csv",
            "shifts.csv",
            "tracks.json",
        ]
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["input_frames"] == [f"f{t:02d}.png" for t in range(len(arrays))]
        assert meta["input_shape"] == list(arrays.shape) and meta["max_per_frame"] == 50
        # the CLI's input is exactly the library's load_frames of the folder
        from hocnet.dpa.presets import RECOMMENDED, run_preset

        asf = np.load(out / "asf.npy")
        expected = run_preset(torch.from_numpy(arrays.astype(np.float64)), RECOMMENDED).asf
        np.testing.assert_allclose(asf, expected.numpy(), rtol=1e-5, atol=1e-5)
        # detections.csv: header, per-frame NMS peaks of the ASF, highest first, x col / y row
        assert (out / "detections.csv").read_text().splitlines()[0] == "frame,x,y,score"
        det = read_detections(out / "detections.csv")
        assert det.numel()
        assert 0 not in det[:, 0].tolist()  # frame 0 is all zero after background removal
        for f in det[:, 0].unique().tolist():
            rows = det[det[:, 0] == f]
            assert len(rows) <= 50
            assert rows[:, 3].tolist() == sorted(rows[:, 3].tolist(), reverse=True)
            for _, x, y, s in rows.tolist():
                assert s == pytest.approx(float(asf[int(f), int(y), int(x)]), rel=1e-6)
                window = asf[
                    int(f), max(0, int(y) - 2) : int(y) + 3, max(0, int(x) - 2) : int(x) + 3
                ]
                assert s >= window.max() - 1e-6
        # the target (rows 12-13, columns 8 + t // 2 ...) is the top detection in late frames
        for t in range(6, len(arrays)):
            top = det[det[:, 0] == t][0]
            assert abs(top[1] - (8.5 + t // 2)) <= 1.5 and abs(top[2] - 12.5) <= 1.5
        shifts = _read_csv(out / "shifts.csv")
        assert list(shifts[0]) == ["frame", "dx", "dy", "offset_x", "offset_y"]
        assert len(shifts) == len(arrays) and float(shifts[0]["dx"]) == 0.0

    def test_max_per_frame_and_glob(self, tmp_path, png_clip):
        from hocnet.detection_metrics import read_detections

        folder, _ = png_clip
        out = tmp_path / "out"
        args = ["detect", str(folder / "f0*.png"), "--method", "dpa", "--max-per-frame", "3"]
        assert main([*args, "--out", str(out)]) == 0
        det = read_detections(out / "detections.csv")
        counts = torch.bincount(det[:, 0].long())
        assert int(counts.max()) == 3 and int(det[:, 0].max()) == 9  # f00 .. f09

    def test_detections_are_causal(self, tmp_path, png_clip):
        # frame n of detections.csv uses frames 0..n only: a run on the first 10 frames gives
        # the same detections for those frames as a run on all 14
        from hocnet.detection_metrics import read_detections

        folder, _ = png_clip
        for name, source in (("all", str(folder)), ("part", str(folder / "f0*.png"))):
            args = ["detect", source, "--method", "dpa", "--out", str(tmp_path / name)]
            assert main(args) == 0
        full = read_detections(tmp_path / "all" / "detections.csv")
        part = read_detections(tmp_path / "part" / "detections.csv")
        head = full[full[:, 0] < 10]
        assert head.shape == part.shape
        torch.testing.assert_close(head, part, rtol=1e-5, atol=1e-5)
        assert int(full[:, 0].max()) == 13

    def test_paper_preset_and_no_register(self, tmp_path, png_clip):
        folder, _ = png_clip
        for extra in (["--preset", "paper"], ["--no-register"]):
            out = tmp_path / extra[-1].strip("-")
            assert main(["detect", str(folder), "--method", "dpa", *extra, "--out", str(out)]) == 0
            assert not (out / "shifts.csv").exists() and (out / "detections.csv").is_file()
            _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
            assert meta["register"] is False

    @pytest.mark.parametrize("background", ["none", "mean", "median", "lowrank"])
    def test_background_options(self, tmp_path, png_clip, background):
        from hocnet.data.background import estimate_shifts, remove_background
        from hocnet.data.whitening import anti_mean

        folder, arrays = png_clip
        out = tmp_path / "out"
        args = ["detect", str(folder), "--method", "dpa", "--background", background]
        assert main([*args, "--background-window", "4", "--out", str(out)]) == 0
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert (meta["background"], meta["background_window"]) == (background, 4)
        # the whitened frames the DPA saw: check through the ASF of frame 0 (= whitened frame 0)
        x = torch.from_numpy(arrays).float()
        if background != "none":
            offsets = estimate_shifts(x).cumsum(dim=0)
            x = remove_background(x, background, 4, offsets=offsets)
        np.testing.assert_allclose(
            np.load(out / "asf.npy")[0], anti_mean(x)[0].numpy(), rtol=1e-5, atol=1e-4
        )

    def test_npz_key(self, tmp_path):
        path = tmp_path / "clip.npz"
        np.savez(path, frames=_clip_arrays(), other=np.zeros(3))
        out = tmp_path / "out"
        args = ["detect", str(path), "--key", "frames", "--method", "dpa", "--out", str(out)]
        assert main(args) == 0
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["key"] == "frames"

    def test_npz_wrong_key(self, tmp_path, capsys):
        path = tmp_path / "clip.npz"
        np.savez(path, frames=_clip_arrays(), other=np.zeros(3))
        code = main(["detect", str(path), "--key", "nope", "--method", "dpa", "--out", "o"])
        assert_one_line_error(capsys, code, r"--key: expected one of")

    def test_colour_frames_note(self, tmp_path, capsys):
        from PIL import Image

        folder = tmp_path / "rgb"
        folder.mkdir()
        for t, a in enumerate(_clip_arrays(n=6)):
            Image.fromarray(np.stack([a, a, a], axis=-1)).save(folder / f"c{t}.png")
        out = tmp_path / "out"
        assert main(["detect", str(folder), "--method", "dpa", "--out", str(out)]) == 0
        err = capsys.readouterr().err
        notes = [line for line in err.splitlines() if line.startswith("hocnet: note:")]
        assert len(notes) == 1 and "converted to grey" in notes[0] and "6 colour" in notes[0]
        assert (out / "detections.csv").is_file()

    def test_out_is_the_input_folder(self, png_clip, capsys):
        # refused (the outputs there broke the next run on the folder: "expected only image
        # frames ... got tracks.json"), and so is a folder inside it; nothing is written
        folder, _ = png_clip
        before = _digests(folder)
        for out in (folder, folder / "results"):
            code = main(["detect", str(folder), "--method", "dpa", "--out", str(out)])
            assert_one_line_error(capsys, code, r"^hocnet: error: --out: .* input folder of CUBE")
        assert _digests(folder) == before and no_leftovers(folder) == []

    def test_never_overwrites_an_image_frame(self, tmp_path, capsys):
        from PIL import Image

        folder = tmp_path / "clip"
        folder.mkdir()
        for t, a in enumerate(_clip_arrays(n=6)):
            name = "detection.png" if t == 3 else f"f{t}.png"  # a frame named like an output
            Image.fromarray(a).save(folder / name)
        before = _digests(folder)
        code = main(["detect", str(folder), "--method", "dpa", "--out", str(folder)])
        # the input folder is never an --out (test_out_is_the_input_folder)
        assert_one_line_error(capsys, code, r"--out: '.*clip' is the input folder of CUBE")
        assert _digests(folder) == before and no_leftovers(folder) == []

    def test_never_overwrites_a_symlinked_input(self, tmp_path, capsys):
        arrays = _clip_arrays(n=6)
        real = tmp_path / "real.npy"
        np.save(real, arrays)
        out = tmp_path / "out"
        out.mkdir()
        (out / "asf.npy").symlink_to(real)
        code = main(["detect", str(real), "--method", "dpa", "--out", str(out)])
        assert_one_line_error(capsys, code, r"would replace the input CUBE")
        np.testing.assert_array_equal(np.load(real), arrays)
        assert sorted(p.name for p in out.iterdir()) == ["asf.npy"]

    def test_hoc_threshold_pfa(self, tmp_path, png_clip, capsys):
        from hocnet.data.binarize import cfar_binarize
        from hocnet.detection_metrics import read_detections
        from hocnet.dpa.presets import RECOMMENDED, preprocess
        from hocnet.hoc import detect as hoc_detect

        folder, arrays = png_clip
        out = tmp_path / "out"
        args = ["detect", str(folder), "--method", "hoc", "--threshold-pfa", "0.005"]
        assert main([*args, "--out", str(out)]) == 0
        stdout = capsys.readouterr().out
        assert "binarised:" in stdout and "registration:" in stdout
        assert written(out) == [
            "binary.npy",
            "cleaned.npy",
            "detection.png",
            "detections.csv",
            "shifts.csv",
            "support.npy",
            "tracks.json",
        ]
        white, _ = preprocess(torch.from_numpy(arrays), RECOMMENDED)
        binary = cfar_binarize(white, 0.005)
        np.testing.assert_array_equal(np.load(out / "binary.npy"), binary.numpy())
        assert int(binary.sum(dim=(1, 2)).max()) <= 5  # floor(0.005 * 32 * 32)
        expected = hoc_detect(binary)
        np.testing.assert_array_equal(np.load(out / "support.npy"), expected.support.numpy())
        det = read_detections(out / "detections.csv")
        assert det.numel()
        for f, x, y, s in det.tolist():
            assert expected.support[int(f), int(y), int(x)]
            assert s == pytest.approx(float(expected.scores[int(f), int(y), int(x)]))
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["threshold_pfa"] == 0.005 and "point score" in meta["detection_score"]

    def test_hoc_binary_cube_detections(self, tmp_path, cube_file, scene):
        from hocnet.detection_metrics import read_detections

        out = tmp_path / "out"
        assert main(["detect", str(cube_file), "--out", str(out)]) == 0
        det = read_detections(out / "detections.csv")
        expected = detect(scene.cube)
        assert det.numel()
        for f, x, y, s in det.tolist():
            assert expected.support[int(f), int(y), int(x)]
            assert s == pytest.approx(float(expected.scores[int(f), int(y), int(x)]))

    def test_batched_detections(self, tmp_path):
        path = tmp_path / "batch.npy"
        np.save(path, np.stack([_clip_arrays(n=8, seed=s) for s in (0, 1)]).astype(np.float32))
        out = tmp_path / "out"
        assert main(["detect", str(path), "--method", "dpa", "--no-plot", "--out", str(out)]) == 0
        names = written(out)
        assert "detections_000.csv" in names and "detections_001.csv" in names
        assert "detections.csv" not in names

    @pytest.mark.parametrize(
        ("setup", "extra", "match"),
        [
            ("text", [], r"CUBE: expected only image frames .* got the file notes\.txt"),
            ("empty", [], r"CUBE: expected a folder with image frames, got an empty folder"),
            ("sizes", [], r"CUBE: expected frames of one size"),
            ("noglob", [], r"CUBE: expected a pattern matching image files"),
            ("ok", ["--method", "hoc"], r"binary values.*--threshold-pfa"),
            ("ok", ["--method", "hoc", "--threshold-pfa", "0"], r"--threshold-pfa: expected"),
            ("ok", ["--method", "hoc", "--threshold-pfa", "1"], r"--threshold-pfa: expected"),
            ("ok", ["--method", "hoc", "--background", "mean"], r"--background: applies to"),
            ("ok", ["--method", "hoc", "--no-register"], r"--register: applies to"),
            ("ok", ["--method", "dpa", "--background-window", "0"], r"--background-window: "),
            ("ok", ["--method", "dpa", "--max-per-frame", "0"], r"--max-per-frame: expected"),
            ("ok", ["--method", "dpa", "--background", "max"], r"--background: invalid choice"),
            (
                "ok",
                ["--method", "dpa", "--key", "frames"],
                r"--key: expected no --key for a folder",
            ),
        ],
    )
    def test_bad_inputs(self, tmp_path, capsys, setup, extra, match):
        from PIL import Image

        folder = tmp_path / "clip"
        folder.mkdir()
        arrays = _clip_arrays(n=6)
        if setup != "empty":
            for t, a in enumerate(arrays):
                Image.fromarray(a).save(folder / f"f{t}.png")
        if setup == "text":
            (folder / "notes.txt").write_text("hello")
        if setup == "sizes":
            Image.fromarray(arrays[0][:20]).save(folder / "f9.png")
        source = str(folder / "g*.png") if setup == "noglob" else str(folder)
        before = _digests(folder)
        out = tmp_path / "out"
        code = main(["detect", source, *extra, "--out", str(out)])
        assert_one_line_error(capsys, code, match)
        assert not out.exists() and _digests(folder) == before

    def test_help_names_inputs_and_outputs(self, capsys):
        assert main(["detect", "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        for word in (
            "PNG, BMP, TIFF",
            "detections.csv",
            "frame,x,y,score",
            "shifts.csv",
            "--threshold-pfa",
            "--background-window",
            "--max-per-frame",
            "causal",
            "hocnet.dpa.presets.PAPER",
        ):
            assert word in text, word


class TestTrain:
    @pytest.mark.parametrize("flag", ["--help", "-h"])
    def test_help_lists_the_systems(self, flag, capsys):
        assert main(["train", flag]) == 0
        out, err = capsys.readouterr()
        assert "dpa" in out and "hoc" in out and "hocnet train dpa --help" in out and err == ""

    @pytest.mark.parametrize("argv", [[], ["--model.lr", "1"], ["svm"]])
    def test_missing_system_is_one_line(self, argv, capsys):
        line = assert_one_line_error(capsys, main(["train", *argv]))
        assert "train: expected a system dpa or hoc first" in line

    @pytest.mark.parametrize(
        ("argv", "message"),
        [
            (["--config", "nope.yaml"], "--config: file 'nope.yaml' does not exist"),
            (["--model.lr", "nan"], "--model.lr: expected a finite number, got nan"),
            (["--data.shape", "[8,32]"], "--data.shape: expected 3 values, got [8, 32]"),
            (["--data.n_train", "0"], "--data.n_train: expected an integer >= 1"),
            (["--max-epochs", "0"], "--max-epochs: expected at least 1"),
            (["--out", "notes.txt"], "--out: 'notes.txt' is a file, expected a folder"),
        ],
    )
    def test_errors_are_one_line(self, argv, message, tmp_path, monkeypatch, capsys):
        pytest.importorskip("lightning")
        monkeypatch.chdir(tmp_path)
        (tmp_path / "notes.txt").write_text("mine")
        line = assert_one_line_error(capsys, main(["train", "dpa", *argv]))
        assert line.startswith(f"hocnet: error: train: {message}"), line
        assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]

    def test_tiny_dpa_run_writes_a_checkpoint(self, tmp_path, capsys):
        pytest.importorskip("lightning")
        out = tmp_path / "run"
        argv = ["train", "dpa", "--max-epochs", "1", "--out", str(out), "--no-progress"]
        argv += ["--data.n_train", "2", "--data.n_val", "2", "--data.n_test", "2"]
        argv += ["--data.shape", "6", "24", "24", "--model.window", "5", "--model.v_max", "1"]
        assert main(argv) == 0
        assert "checkpoint:" in capsys.readouterr().out
        assert list(out.rglob("*.ckpt"))


class TestMinSpeed:
    def _cube(self, tmp_path):
        f = np.zeros((8, 20, 20), dtype=bool)
        for t in range(8):
            f[t, 3, 3] = True  # stationary clutter
            f[t, 4 + t, 10 + t // 2] = True  # a moving target
        path = tmp_path / "c.npy"
        np.save(path, f)
        return path

    def test_drops_the_stationary_chain(self, tmp_path):
        path = self._cube(tmp_path)
        assert main(["detect", str(path), "--out", str(tmp_path / "all"), "-q", "--no-plot"]) == 0
        argv = ["detect", str(path), "--out", str(tmp_path / "fast"), "-q", "--no-plot"]
        assert main([*argv, "--min-speed", "0.5"]) == 0
        assert len(load_tracks_json(tmp_path / "all" / "tracks.json")) == 2
        moving = load_tracks_json(tmp_path / "fast" / "tracks.json")
        assert len(moving) == 1 and int(moving[0]["points"][:, 1].min()) == 4
        rows = (tmp_path / "fast" / "detections.csv").read_text().splitlines()[1:]
        assert rows and all(row.split(",")[1:3] != ["3", "3"] for row in rows)

    def test_negative_is_an_error(self, tmp_path, capsys):
        path = self._cube(tmp_path)
        assert main(["detect", str(path), "--out", str(tmp_path / "o"), "--min-speed", "-1"]) == 2
        assert "--min-speed" in capsys.readouterr().err
        assert not (tmp_path / "o").exists()


class TestWeights:
    """`hocnet detect --weights CKPT`: the learned module of a `hocnet train` checkpoint."""

    @pytest.fixture(scope="class")
    @classmethod
    def ckpts(cls, tmp_path_factory):
        pytest.importorskip("lightning")
        pytest.importorskip("jsonargparse")
        root = tmp_path_factory.mktemp("train")
        tiny = ["--max-epochs", "1", "--no-progress", "--trainer.limit_train_batches", "1",
                "--trainer.limit_val_batches", "1", "--data.n_train", "2", "--data.n_val", "1",
                "--data.n_test", "1", "--data.speed", "0.5", "1.0"]  # fmt: skip
        runs = {
            "dpa": ["--data.shape", "5", "16", "16", "--model.window", "5", "--model.lr", "0.3",
                    "--model.matrices", "full"],
            "hoc": ["--data.shape", "6", "16", "16", "--model.order", "1", "--model.v", "1",
                    "--model.init", "random"],
        }  # fmt: skip
        out = {}
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for name, extra in runs.items():
                assert main(["train", name, "--out", str(root / name), *tiny, *extra]) == 0
                (out[name],) = (root / name).rglob("last.ckpt")
        return out

    def test_dpa_uses_the_learned_parameters(self, ckpts, tmp_path):
        from hocnet.cli.detect import _preprocess
        from hocnet.dpa import DPA
        from hocnet.dpa.presets import PAPER
        from hocnet.learn import load_model
        from hocnet.learn.apply import detect_dpa

        model = load_model(ckpts["dpa"])
        assert isinstance(model, DPA)
        assert not torch.equal(model.weights, DPA(window=5).weights)  # learned, not eq. (5)
        frames = torch.randn(5, 16, 16, generator=torch.Generator().manual_seed(1))
        frames[:, 8, 8] += 6.0
        path = tmp_path / "f.npy"
        np.save(path, frames.numpy())
        out = tmp_path / "o"
        argv = ["detect", str(path), "--method", "dpa", "--preset", "paper", "--no-plot", "-q"]
        assert main([*argv, "--weights", str(ckpts["dpa"]), "--out", str(out)]) == 0
        tracks, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        with torch.no_grad():
            assert meta["g"] == float(model.g) and meta["b"] == float(model.b)
        assert meta["window"] == 5 and meta["weights"] == str(ckpts["dpa"].resolve())
        # the library call with the same weights
        pre = {"register": PAPER.register, "background": PAPER.background,
               "background_window": PAPER.background_window, "whiten": PAPER.whitening}  # fmt: skip
        white, _ = _preprocess(frames, pre)
        found = detect_dpa(white, model, max_targets=5, nms_radius=3, pfa=1e-3)
        assert torch.equal(torch.from_numpy(np.load(out / "asf.npy")), found.state.asf)
        assert [t["points"].tolist() for t in tracks] == [t.points.tolist() for t in found.tracks]
        # and not the fixed weights
        assert main([*argv, "--out", str(tmp_path / "fixed")]) == 0
        fixed = np.load(tmp_path / "fixed" / "asf.npy")
        assert not np.array_equal(fixed, np.load(out / "asf.npy"))

    def test_hoc_uses_the_learned_kernels(self, ckpts, tmp_path):
        from hocnet.hoc.layers import MHOCImage
        from hocnet.learn import load_model
        from hocnet.learn.apply import detect_hoc

        model = load_model(ckpts["hoc"])
        assert isinstance(model, MHOCImage)
        fixed = MHOCImage(order=1, v=1)
        learned = model.forward_net.layers[0].mask_kernels
        assert not torch.equal(learned, fixed.forward_net.layers[0].mask_kernels)
        scene = simulate_binary(
            (6, 16, 16), [TargetSpec((2, 3), (1, 1))], clutter_density=0.03,
            generator=torch.Generator().manual_seed(2),
        )  # fmt: skip
        path = tmp_path / "c.npy"
        save_cube(path, scene.cube)
        out = tmp_path / "o"
        assert main(["detect", str(path), "--weights", str(ckpts["hoc"]), "--out", str(out),
                     "--no-plot", "-q"]) == 0  # fmt: skip
        tracks, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert (meta["order"], meta["v"], meta["delta"]) == (1, 1, 45.0)
        found = detect_hoc(scene.cube, model)
        assert np.array_equal(np.load(out / "support.npy"), found.support.numpy())
        assert np.array_equal(np.load(out / "cleaned.npy"), found.cleaned.numpy())
        assert [t["points"].tolist() for t in tracks] == [t.points.tolist() for t in found.tracks]

    def test_errors_are_one_line(self, ckpts, tmp_path, capsys):
        frames = tmp_path / "f.npy"
        np.save(frames, np.random.default_rng(0).normal(size=(5, 16, 16)))
        cube = tmp_path / "c.npy"
        np.save(cube, np.zeros((6, 16, 16), dtype=bool))
        cut = tmp_path / "cut.ckpt"
        cut.write_bytes(ckpts["dpa"].read_bytes()[:1000])

        class Evil:
            def __reduce__(self):
                return (os.system, ("echo pwned",))

        evil = tmp_path / "evil.ckpt"
        torch.save({"state_dict": {}, "x": Evil()}, evil)
        text = tmp_path / "fake.ckpt"
        text.write_text("not a checkpoint\n")
        pickled = tmp_path / "tuner.pkl"  # pickle protocol 4: torch warns about it
        pickled.write_bytes(pickle.dumps(Evil(), protocol=4))
        cases = [
            (
                frames,
                "dpa",
                text,
                [],
                r"--weights: '.*fake\.ckpt' is not a checkpoint \(torch\.save",
            ),
            (frames, "dpa", pickled, [], r"--weights: refused .*tuner\.pkl.*untrusted pickle"),
            (frames, "dpa", tmp_path / "missing.ckpt", [], r"--weights: cannot read"),
            (cube, "hoc", ckpts["dpa"], [], r"--weights: expected a LearnedHOCSystem"),
            (frames, "dpa", ckpts["hoc"], [], r"--weights: expected a DPATuner"),
            (frames, "dpa", cut, [], r"--weights: .*corrupted\?\)$"),  # no unpickler detail
            (frames, "dpa", evil, [], r"--weights: refused .*untrusted pickle"),
            (frames, "dpa", ckpts["dpa"], ["--g", "0.5"], r"--g: set by the checkpoint"),
            (cube, "hoc", ckpts["hoc"], ["--order", "2"], r"--order: set by the checkpoint"),
        ]
        for i, (data, method, weights, extra, match) in enumerate(cases):
            out = tmp_path / f"out{i}"
            argv = ["detect", str(data), "--method", method, "--weights", str(weights)]
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                code = main([*argv, *extra, "--out", str(out), "-q"])
            assert [str(w.message) for w in caught] == []  # nothing leaks before the error
            assert_one_line_error(capsys, code, match)
            assert not out.exists()


# --------------------------------------------------------------------------------------------
# a fresh clone: six small problems of new users (registration on noise, glob names, --order
# range, --target-free frames, threshold precision, flat frames)
# --------------------------------------------------------------------------------------------


def _save_png_frames(folder: Path, arrays: np.ndarray) -> Path:
    from PIL import Image

    folder.mkdir()
    for t, a in enumerate(arrays):
        Image.fromarray(a).save(folder / f"f{t:02d}.png")
    return folder


class TestFreshClone:
    def test_noise_frames_register_no_shift_and_say_so(self, tmp_path, capsys):
        # item 1: pure noise has no structure to register: every shift 0, and the user is told
        noise = np.random.default_rng(4).normal(100.0, 5.0, (12, 32, 32))
        path = tmp_path / "noise.npy"
        np.save(path, noise)
        out = tmp_path / "out"
        assert main(["detect", str(path), "--method", "dpa", "--out", str(out), "-q"]) == 0
        stdout = capsys.readouterr().out
        assert "registration: no reliable registration peak in 11 of 11 frame pairs" in stdout
        assert "shifts kept at 0" in stdout
        rows = _read_csv(out / "shifts.csv")
        assert {(r["dx"], r["dy"]) for r in rows} == {("0.0000", "0.0000")}
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["unregistered_pairs"] == 11

    def test_textured_shift_3_minus_2_registers(self, tmp_path, capsys):
        # item 1, the other side: real content moving by (dx, dy) = (3, -2) still registers
        from scipy.ndimage import gaussian_filter

        rng = np.random.default_rng(2)
        ground = gaussian_filter(rng.normal(size=(96, 96)), 0.7) * 40 + 100
        # frame t shows ground pixel (x - 3 t, y + 2 t) at (x, y): content moves by (3, -2)
        frames = np.stack(
            [ground[20 + 2 * t : 68 + 2 * t, 30 - 3 * t : 78 - 3 * t] for t in range(6)]
        )
        path = tmp_path / "pan.npy"
        np.save(path, frames + rng.normal(0.0, 0.5, frames.shape))
        out = tmp_path / "out"
        assert main(["detect", str(path), "--method", "dpa", "--out", str(out), "-q"]) == 0
        assert "no structure" not in capsys.readouterr().out
        rows = _read_csv(out / "shifts.csv")[1:]
        assert [float(r["dx"]) for r in rows] == pytest.approx([3.0] * 5, abs=0.2)
        assert [float(r["dy"]) for r in rows] == pytest.approx([-2.0] * 5, abs=0.2)

    def test_textured_clip_registers_without_note(self, tmp_path, png_clip, capsys):
        folder, _ = png_clip  # a textured ground: every pair has structure
        out = tmp_path / "out"
        assert main(["detect", str(folder), "--method", "dpa", "--out", str(out), "-q"]) == 0
        stdout = capsys.readouterr().out
        assert "registration: mean shift" in stdout and "no structure" not in stdout
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["unregistered_pairs"] == 0

    def test_glob_out_error_names_the_pattern(self, tmp_path, png_clip, capsys):
        # item 2: the message named the folder 'clip', not the pattern the user typed
        folder, _ = png_clip
        pattern = str(folder / "f0*.png")
        code = main(["detect", pattern, "--method", "dpa", "--out", str(folder)])
        line = assert_one_line_error(capsys, code, r"--out: .* is the input folder of CUBE")
        assert f"CUBE '{pattern}'" in line
        assert f"its frames are in '{folder}'" in line
        # a folder input is named as typed too (with its trailing slash)
        typed = str(folder) + os.sep
        code = main(["detect", typed, "--method", "dpa", "--out", str(folder / "sub")])
        line = assert_one_line_error(capsys, code, r"--out: .* is inside the input folder")
        assert f"CUBE '{typed}'" in line

    def test_order_99_refused_at_once_with_its_range(self, tmp_path, capsys, monkeypatch):
        # item 3: every bad option in one message, the shape's bounds before any pre-processing
        cube = tmp_path / "c.npy"
        np.save(cube, np.zeros((10, 24, 24), dtype=bool))
        out = str(tmp_path / "o")
        code = main(["detect", str(cube), "--order", "99", "--v", "500", "--out", out])
        line = assert_one_line_error(capsys, code, r"^hocnet: error: 2 problems: --order: ")
        assert "--order: expected at most (T - 1) // 2 = 4 for a cube of T = 10" in line
        assert "--v: expected at most max(H, W) - 1 = 23" in line
        argv = ["detect", str(cube), "--order", "0", "--v", "0", "--delta", "400"]
        code = main([*argv, "--max-per-frame", "0", "--out", out])
        line = assert_one_line_error(capsys, code, r"^hocnet: error: 4 problems: ")
        for flag in ("--order", "--v", "--delta", "--max-per-frame"):
            assert f"{flag}: expected" in line
        code = main(["detect", str(cube), "--method", "dpa", "--g", "5", "--window", "4"])
        assert_one_line_error(capsys, code, r"2 problems: --g: .*; --window: expected an odd")
        code = main(["detect", str(cube), "--g", "0.5", "--order", "0", "--out", out])
        assert_one_line_error(
            capsys, code, r"2 problems: --g: applies to --method dpa, not hoc; --order: expected"
        )
        # intensity frames: --order is checked before the registration runs

        def no_registration(*args, **kwargs):
            raise AssertionError("registration ran before --order was checked")

        monkeypatch.setattr("hocnet.data.background.estimate_shifts", no_registration)
        frames = tmp_path / "f.npy"
        np.save(frames, np.random.default_rng(0).normal(size=(10, 24, 24)))
        code = main(["detect", str(frames), "--threshold-pfa", "0.01", "--order", "99"])
        assert_one_line_error(capsys, code, r"--order: expected at most \(T - 1\) // 2 = 4")
        assert not Path(out).exists()

    def test_target_free_png_folder(self, tmp_path, ir_sequence, capsys):
        # item 4: --target-free took .npy / .npz only; it takes what the input takes
        to8 = lambda x: np.clip(x.numpy() * 20 + 100, 0, 255).astype(np.uint8)  # noqa: E731
        clip = _save_png_frames(tmp_path / "clip", to8(ir_sequence.frames))
        free = _save_png_frames(tmp_path / "free", to8(ir_sequence.target_free))
        np.save(tmp_path / "free.npy", to8(ir_sequence.target_free).astype(np.float64))
        thresholds = []
        for name, source in (
            ("npy", tmp_path / "free.npy"),
            ("folder", free),
            ("glob", free / "f*.png"),
        ):
            out = tmp_path / f"out_{name}"
            argv = ["detect", str(clip), "--method", "dpa", "--target-free", str(source)]
            assert main([*argv, "--pfa", "0.01", "--out", str(out), "-q"]) == 0
            _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
            assert meta["cfar"] is True
            thresholds.append(meta["threshold_used"])
        assert thresholds[0] == thresholds[1] == thresholds[2]
        capsys.readouterr()
        # its frames are inputs: no output inside that folder, none replaces a frame
        argv = ["detect", str(clip), "--method", "dpa", "--target-free", str(free)]
        code = main([*argv, "--pfa", "0.01", "--out", str(free)])
        assert_one_line_error(capsys, code, rf"--out: .* input folder of --target-free '{free}'")
        code = main([*argv[:-1], str(tmp_path / "nothing" / "*.png"), "--out", str(tmp_path)])
        assert_one_line_error(capsys, code, r"^hocnet: error: --target-free: ")

    def test_threshold_printed_with_4_digits_and_units(self, tmp_path, frames_file, capsys):
        # item 5: "threshold = 3.1415926535"
        out = tmp_path / "out"
        argv = ["detect", str(frames_file), "--method", "dpa", "--out", str(out), "-q"]
        assert main([*argv, "--asf-threshold", "3.1415926535"]) == 0
        stdout = capsys.readouterr().out
        assert "threshold = 3.142 (ASF, input intensity units; --asf-threshold)" in stdout
        assert "3.1415" not in stdout
        free = tmp_path / "free.npy"
        np.save(free, np.random.default_rng(1).normal(size=(20, 24, 28)))
        assert main([*argv, "--target-free", str(free), "--pfa", "0.01", "--force"]) == 0
        stdout = capsys.readouterr().out
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        shown = re.search(r"threshold = (\S+) \(ASF, input intensity units; CFAR at", stdout)
        assert shown is not None, stdout
        assert shown.group(1) == f"{meta['threshold_used']:.4g}"
        assert len(shown.group(1).replace(".", "").replace("-", "").lstrip("0")) <= 4
        assert "--pfa 0.01 on --target-free" in stdout

    def test_flat_frames_dpa_refused_or_warned(self, tmp_path, capsys):
        # item 6: constant frames ran silently, with tracks on rounding noise
        flat = _save_png_frames(tmp_path / "flat", np.full((8, 24, 24), 100, np.uint8))
        for cmd, selector in (("detect", "--method"), ("track", "--detector")):
            out = tmp_path / f"out_{cmd}"
            code = main([cmd, str(flat), selector, "dpa", "--out", str(out), "-q"])
            label = "CUBE" if cmd == "detect" else "SEQ"
            assert_one_line_error(
                capsys,
                code,
                rf"^hocnet: error: {label}: all 8 frames are flat \('f00\.png' \.\.\. 'f07\.png'\) "
                r"\(the constant value 100, zero variance\): nothing can be detected",
            )
            assert not out.exists()
        # some flat frames: the run goes on, and the frames are named
        part = np.random.default_rng(0).normal(100.0, 5.0, (8, 24, 24))
        part[2], part[5] = 7.0, 7.0
        path = tmp_path / "part.npy"
        np.save(path, part)
        out = tmp_path / "out_part"
        assert main(["detect", str(path), "--method", "dpa", "--out", str(out), "-q"]) == 0
        err = capsys.readouterr().err
        assert "hocnet: warning: CUBE: 2 of 8 frames are flat" in err
        assert "frames 2, 5 (0-based)" in err
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert any("2 of 8 frames are flat" in w for w in meta["warnings"])
        # flat --target-free frames cannot give a CFAR threshold
        free = tmp_path / "free.npy"
        np.save(free, np.full((4, 24, 24), 3.0))
        argv = ["detect", str(path), "--method", "dpa", "--target-free", str(free)]
        code = main([*argv, "--out", str(tmp_path / "o2")])
        assert_one_line_error(capsys, code, r"--target-free: expected intensity frames whose")


def test_detect_direction_step_reaches_the_dpa(tmp_path, capsys, monkeypatch):
    import importlib

    backtrack_module = importlib.import_module("hocnet.dpa.backtrack")  # not the function
    frames = tmp_path / "frames.npy"
    np.save(frames, np.random.default_rng(3).normal(size=(6, 20, 20)).astype(np.float32))
    real, seen = backtrack_module.detect, []

    def spy(*args, **kwargs):
        seen.append(kwargs["direction_step"])
        return real(*args, **kwargs)

    monkeypatch.setattr(backtrack_module, "detect", spy)
    asf = {}
    for step in (None, "source", "paper"):
        out = tmp_path / f"out_{step}"
        flags = [] if step is None else ["--direction-step", step]
        argv = ["detect", str(frames), "--method", "dpa", "--g", "1", *flags]
        assert main([*argv, "--out", str(out), "--no-plot", "-q"]) == 0
        _, meta = load_tracks_json(out / "tracks.json", return_meta=True)
        assert meta["direction_step"] == (step or "paper")  # the presets' default: paper
        asf[step] = np.load(out / "asf.npy")
    capsys.readouterr()
    assert seen == ["paper", "source", "paper"]
    assert np.array_equal(asf[None], asf["paper"]) and not np.array_equal(asf[None], asf["source"])
    # a DPA option: refused with --method hoc, and a choice
    cube = tmp_path / "c.npy"
    np.save(cube, np.zeros((6, 16, 16), dtype=bool))
    code = main(["detect", str(cube), "--direction-step", "source", "--out", str(tmp_path / "h")])
    assert_one_line_error(capsys, code, r"--direction-step: applies to --method dpa, not hoc")
    code = main(["detect", str(frames), "--method", "dpa", "--direction-step", "x", "-q"])
    assert code == 2 and "--direction-step" in capsys.readouterr().err

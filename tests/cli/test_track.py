"""Tests of ``hocnet track``: detector plots into the MHT, on simulated crossing targets."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from hocnet.cli import main
from hocnet.data.binary import TargetSpec, simulate_binary
from hocnet.data.infrared import IRTarget, simulate_ir

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def one_line_error(capsys, code: int, match: str) -> str:
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hocnet: error: "), err
    assert re.search(match, lines[0]), lines[0]
    return lines[0]


def purities(tracks: list[dict], label_of) -> dict[int, list[float]]:
    """Majority truth label of each track -> the purities of the tracks it owns."""
    owners: dict[int, list[float]] = {}
    for tr in tracks:
        labels = [label_of(f, x, y) for f, x, y, _ in tr["points"]]
        best = max(set(labels), key=labels.count)
        owners.setdefault(best, []).append(labels.count(best) / len(labels))
    return owners


@pytest.fixture(scope="module")
def binary_scene():
    specs = [
        TargetSpec(start=(5, 5), velocity=(1.2, 1.2), p_miss=0.05),
        TargetSpec(start=(5, 55), velocity=(1.2, -1.2), p_miss=0.05),
    ]
    return simulate_binary((40, 64, 64), specs, clutter_density=0.003, seed=0)


@pytest.fixture(scope="module")
def ir_scene():
    targets = [IRTarget(8, 8, 1.2, 1.2, snr_db=14.0), IRTarget(8, 56, 1.2, -1.2, snr_db=14.0)]
    return simulate_ir((40, 64, 64), targets, clouds="clear", jitter=0.0, seed=0)


class TestTrack:
    def test_hoc_crossing_targets(self, tmp_path, binary_scene, capsys):
        seq = tmp_path / "scene.npy"
        np.save(seq, binary_scene.cube.numpy())
        out = tmp_path / "out"
        assert main(["track", str(seq), "--detector", "hoc", "--out", str(out)]) == 0
        printed = capsys.readouterr().out
        assert "confirmed track" in printed and "vx, vy" in printed
        data = json.loads((out / "tracks.json").read_text())
        assert data["meta"]["detector"] == "hoc"
        labels = binary_scene.labels.numpy()  # (T, H, W), 0 = clutter

        def label_of(f, x, y):
            return int(labels[f, round(y), round(x)])

        owners = purities(data["tracks"], label_of)
        assert sorted(k for k in owners if k > 0) == [1, 2]  # no target left untracked
        assert 0 not in owners  # no clutter track
        assert min(p for ps in owners.values() for p in ps) >= 0.9
        assert (out / "tracks.png").read_bytes()[:8] == PNG_MAGIC

    def test_dpa_crossing_targets(self, tmp_path, ir_scene, capsys):
        seq = tmp_path / "ir.npy"
        np.save(seq, ir_scene.frames.numpy())
        out = tmp_path / "out"
        assert main(["track", str(seq), "--detector", "dpa", "--out", str(out), "--no-plot"]) == 0
        capsys.readouterr()
        data = json.loads((out / "tracks.json").read_text())
        pos = ir_scene.positions.numpy()  # (N, T, 2) x, y

        def label_of(f, x, y):
            d = np.hypot(pos[:, f, 0] - x, pos[:, f, 1] - y)
            return int(d.argmin()) if d.min() <= 2.5 else -1

        owners = purities(data["tracks"], label_of)
        assert sorted(k for k in owners if k >= 0) == [0, 1]
        assert -1 not in owners
        assert min(p for ps in owners.values() for p in ps) >= 0.9
        for tr in data["tracks"]:  # each track follows its target over most of the sequence
            assert len(tr["points"]) >= 25
        assert not (out / "tracks.png").exists()

    @pytest.mark.parametrize(
        ("array", "detector", "match"),
        [
            (np.full((6, 8, 8), np.nan), "dpa", r"SEQ: .*(finite|NaN)"),
            (np.where(np.eye(8)[None] > 0, np.inf, 0.0).repeat(6, 0), "hoc", r"SEQ: .*finite"),
            (np.zeros((8, 8)), "dpa", r"SEQ: .*shape"),
            (np.zeros((2, 6, 8, 8)), "hoc", r"SEQ: expected one sequence of shape \(T, H, W\)"),
            (np.full((6, 8, 8), 0.5), "hoc", r"binary"),
            (np.zeros((3, 8, 8), dtype=bool), "hoc", r"SEQ: expected at least .* = 5 frames"),
            (np.zeros((6, 4, 9)), "dpa", r"SEQ: expected frames of at least 5 x 5 .* got 4 x 9"),
        ],
    )
    def test_bad_input(self, tmp_path, capsys, array, detector, match):
        seq = tmp_path / "bad.npy"
        np.save(seq, array)
        out = tmp_path / "out"
        code = main(["track", str(seq), "--detector", detector, "--out", str(out)])
        one_line_error(capsys, code, match)
        assert not out.exists()
        assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npy"]

    @pytest.mark.parametrize(
        ("extra", "match"),
        [
            (["--detector", "sonar"], r"--detector.*invalid choice"),
            (["--detector", "dpa", "--stride", "5"], r"--stride: does not apply"),
            (["--pd", "1.5"], r"--pd"),
            (["--alpha", "0.6", "--beta", "0.6"], r"--beta"),
        ],
    )
    def test_bad_options(self, tmp_path, capsys, extra, match):
        seq = tmp_path / "ok.npy"
        cube = np.zeros((6, 12, 12), dtype=bool)
        for t in range(6):
            cube[t, 2 + t, 3 + t] = True
        np.save(seq, cube)
        out = tmp_path / "out"
        code = main(["track", str(seq), "--out", str(out), *extra])
        one_line_error(capsys, code, match)
        assert not out.exists()

    def test_help(self, capsys):
        assert main(["track", "--help"]) == 0
        assert "--detector" in capsys.readouterr().out

    def test_empty_scene_gives_no_track(self, tmp_path, capsys):
        seq = tmp_path / "empty.npy"
        np.save(seq, np.zeros((8, 16, 16), dtype=bool))
        out = tmp_path / "out"
        assert main(["track", str(seq), "--out", str(out), "--no-plot"]) == 0
        assert "0 confirmed tracks" in capsys.readouterr().out
        assert json.loads((out / "tracks.json").read_text())["tracks"] == []


class TestOwnFiles:
    """`hocnet track` never replaces a user's own file in --out without --force."""

    def test_own_file_refused_rerun_and_force(self, tmp_path, capsys):
        from hocnet.cli._common import MANIFEST

        seq = tmp_path / "scans.npy"
        np.save(seq, np.zeros((8, 16, 16), dtype=bool))
        out = tmp_path / "own"
        out.mkdir()
        (out / "tracks.json").write_text("MINE\n")
        argv = ["track", str(seq), "--out", str(out)]
        before = {p.name: p.read_bytes() for p in out.iterdir()}
        code = main(argv)
        one_line_error(
            capsys,
            code,
            r"^hocnet: error: --out: '.*own/tracks\.json' exists and was not written by hocnet "
            r"\(or was changed since\); use --force to replace it, or choose another --out$",
        )
        assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing written
        assert main([*argv, "--force"]) == 0
        printed = capsys.readouterr().out
        assert MANIFEST not in printed and ".tmp" not in printed
        assert json.loads((out / "tracks.json").read_text())["tracks"] == []
        names = sorted(p.name for p in out.iterdir())
        assert names == sorted([MANIFEST, "tracks.json", "tracks.png"])
        assert main(argv) == 0  # a rerun replaces hocnet's own files
        (out / "tracks.png").write_bytes(b"edited by the user")
        code = main([*argv, "--no-plot"])  # tracks.png is not written: not in the way
        assert code == 0
        capsys.readouterr()
        one_line_error(capsys, main(argv), r"'.*tracks\.png' exists and was not written")
        assert (out / "tracks.png").read_bytes() == b"edited by the user"


def save_frames(folder, frames, fmt="frame_{:03d}.png") -> list:
    """Write a (T, H, W) array as one image file per frame (Pillow; bool -> mode 1)."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for t, frame in enumerate(frames):
        path = folder / fmt.format(t)
        Image.fromarray(frame).save(path)
        paths.append(path)
    return paths


def tracks_of(out) -> list[dict]:
    return json.loads((out / "tracks.json").read_text())["tracks"]


def snapshot(root) -> dict:
    """Every file below ``root`` with its bytes (to check that nothing was written or changed)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


class TestImageFrames:
    """`hocnet track FOLDER` reads image frames as `hocnet detect` does (issue 12, issue 9)."""

    def test_hoc_folder_gives_the_tracks_of_the_npy(self, tmp_path, binary_scene, capsys):
        cube = binary_scene.cube.numpy()
        np.save(tmp_path / "scene.npy", cube)
        files = save_frames(tmp_path / "frames", cube)  # mode "1": values 0 / 1
        runs = {}
        for name, seq in (("npy", tmp_path / "scene.npy"), ("png", tmp_path / "frames")):
            out = tmp_path / f"out-{name}"
            assert main(["track", str(seq), "--out", str(out), "--no-plot"]) == 0
            runs[name] = json.loads((out / "tracks.json").read_text())
        capsys.readouterr()
        assert len(runs["npy"]["tracks"]) >= 2  # both targets (test_hoc_crossing_targets)
        assert runs["png"]["tracks"] == runs["npy"]["tracks"]
        meta = runs["png"]["meta"]
        assert meta["input_frames"] == [p.name for p in files]
        assert meta["plots_per_frame"] == runs["npy"]["meta"]["plots_per_frame"]

    def test_dpa_folder_of_16_bit_pngs_gives_the_tracks_of_the_npy(
        self, tmp_path, ir_scene, capsys
    ):
        frames = np.round((ir_scene.frames.numpy() + 10.0) * 1000.0).astype(np.uint16)
        np.save(tmp_path / "ir.npy", frames)
        save_frames(tmp_path / "clip", frames, fmt="f{}.png")  # natural order: f2 before f10
        runs = {}
        for name, seq in (("npy", tmp_path / "ir.npy"), ("png", tmp_path / "clip")):
            out = tmp_path / f"out-{name}"
            argv = ["track", str(seq), "--detector", "dpa", "--out", str(out), "--no-plot"]
            assert main(argv) == 0
            runs[name] = tracks_of(out)
        capsys.readouterr()
        assert len(runs["npy"]) >= 2
        assert runs["png"] == runs["npy"]

    def test_hoc_threshold_pfa_on_intensity_frames(self, tmp_path, ir_scene, capsys):
        # the binarisation of `hocnet detect --threshold-pfa`: the same binary cube (binary.npy)
        frames = np.round((ir_scene.frames.numpy()[:16, :32, :32] + 10.0) * 1000.0)
        save_frames(tmp_path / "clip", frames.astype(np.uint16))
        argv = ["--threshold-pfa", "0.003", "--no-plot"]
        assert main(["detect", str(tmp_path / "clip"), "--out", str(tmp_path / "d"), *argv]) == 0
        out = tmp_path / "t"
        assert main(["track", str(tmp_path / "clip"), "--out", str(out), *argv]) == 0
        printed = capsys.readouterr().out
        assert "binarised:" in printed and "registration:" in printed
        data = json.loads((out / "tracks.json").read_text())
        binary = np.load(tmp_path / "d" / "binary.npy")
        assert data["meta"]["detector_params"]["threshold_pfa"] == 0.003
        assert len(data["meta"]["shifts"]) == 16
        for tr in data["tracks"]:  # every plot is an on-point of the binarised cube
            for f, x, y, _ in tr["points"]:
                assert binary[f, int(y), int(x)]

    @pytest.mark.parametrize(
        ("make", "match"),
        [
            ("empty", r"^hocnet: error: SEQ: expected a folder with image frames, got an empty"),
            ("mixed_sizes", r"^hocnet: error: SEQ: expected frames of one size .* frame_999\.png"),
            ("not_an_image", r"^hocnet: error: SEQ: expected only image frames .* notes\.txt"),
            ("unreadable", r"^hocnet: error: SEQ: .*f1\.png"),
            ("non_binary_hoc", r"^hocnet: error: .*--detector hoc needs binary scans.*"),
        ],
    )
    def test_bad_folder(self, tmp_path, capsys, make, match):
        folder = tmp_path / "clip"
        folder.mkdir()
        frame = np.zeros((12, 12), dtype=np.uint8)
        if make == "mixed_sizes":
            save_frames(folder, [frame] * 6)
            save_frames(folder, [np.zeros((10, 12), dtype=np.uint8)], fmt="frame_999.png")
        elif make == "not_an_image":
            save_frames(folder, [frame] * 6)
            (folder / "notes.txt").write_text("my notes\n")
        elif make == "unreadable":
            save_frames(folder, [frame] * 6, fmt="f{}.png")
            (folder / "f1.png").write_bytes(b"not a png")
        elif make == "non_binary_hoc":
            save_frames(folder, [frame + 7] * 6)
        before = snapshot(tmp_path)
        for detector in ("hoc", "dpa") if make != "non_binary_hoc" else ("hoc",):
            out = tmp_path / "out"
            code = main(["track", str(folder), "--detector", detector, "--out", str(out)])
            one_line_error(capsys, code, match)
            assert not out.exists()
            assert snapshot(tmp_path) == before  # nothing written, nothing changed

    def test_missing_input_names_seq(self, tmp_path, capsys):
        code = main(["track", str(tmp_path / "nope"), "--out", str(tmp_path / "out")])
        one_line_error(capsys, code, r"^hocnet: error: SEQ: ")
        assert list(tmp_path.iterdir()) == []


class TestInputsNeverReplaced:
    """No output of `hocnet track` replaces an input, even with --force (issue 9)."""

    def test_frame_named_like_an_output(self, tmp_path, capsys):
        folder = tmp_path / "clip"
        cube = np.zeros((6, 12, 12), dtype=bool)
        files = save_frames(folder, cube, fmt="frame{}.png")
        files[-1].rename(folder / "tracks.png")  # sorted after frame4: still the last frame
        before = snapshot(tmp_path)
        code = main(["track", str(folder), "--out", str(folder), "--force"])
        # refused before: the input folder itself is never an --out (item 3 of the new user)
        one_line_error(capsys, code, r"--out: '.*clip' is the input folder of SEQ")
        assert snapshot(tmp_path) == before

    @pytest.mark.parametrize("link", ["symlink", "hardlink"])
    def test_output_linked_to_the_input(self, tmp_path, capsys, link):
        seq = tmp_path / "scans.npy"
        np.save(seq, np.zeros((6, 12, 12), dtype=bool))
        out = tmp_path / "out"
        out.mkdir()
        if link == "symlink":
            (out / "tracks.json").symlink_to(seq)
        else:
            (out / "tracks.json").hardlink_to(seq)
        before = seq.read_bytes()
        code = main(["track", str(seq), "--out", str(out), "--force"])
        one_line_error(capsys, code, r"would replace the input SEQ '.*scans\.npy'")
        assert seq.read_bytes() == before
        assert sorted(p.name for p in out.iterdir()) == ["tracks.json"]

    def test_target_free_is_an_input(self, tmp_path, capsys):
        seq = tmp_path / "ir.npy"
        np.save(seq, np.random.default_rng(0).normal(size=(6, 12, 12)))
        free = tmp_path / "free.npy"
        np.save(free, np.zeros((6, 12, 12)))
        out = tmp_path / "out"
        out.mkdir()
        (out / "tracks.json").symlink_to(free)
        before = snapshot(tmp_path)
        argv = ["track", str(seq), "--detector", "dpa", "--target-free", str(free)]
        code = main([*argv, "--out", str(out), "--force"])
        one_line_error(capsys, code, r"would replace the input --target-free '.*free\.npy'")
        assert snapshot(tmp_path) == before


class TestSharedOptions:
    """`detect` and `track` share the detector options: same texts, same messages."""

    @pytest.mark.parametrize(
        ("extra", "method"),
        [
            (["--v", "0"], "hoc"),
            (["--delta", "200"], "hoc"),
            (["--order", "0"], "hoc"),
            (["--threshold-pfa", "1.5"], "hoc"),
            (["--min-speed", "-1"], "hoc"),
            (["--g", "2"], "dpa"),
            (["--v-max", "0"], "dpa"),
            (["--pfa", "0"], "dpa"),
            (["--background-window", "0"], "dpa"),
            (["--asf-threshold", "1", "--target-free", "x.npy"], "dpa"),
        ],
    )
    def test_same_validation(self, tmp_path, capsys, extra, method):
        seq = tmp_path / "ok.npy"
        np.save(seq, np.zeros((6, 12, 12), dtype=bool))
        messages = []
        for cmd, selector in (("detect", "--method"), ("track", "--detector")):
            out = tmp_path / f"out-{cmd}"
            code = main([cmd, str(seq), selector, method, "--out", str(out), *extra])
            messages.append(one_line_error(capsys, code, re.escape(extra[0])))
            assert not out.exists()
        assert messages[0] == messages[1]

    def test_preprocessing_needs_intensity_frames(self, tmp_path, capsys):
        seq = tmp_path / "ok.npy"
        np.save(seq, np.zeros((6, 12, 12), dtype=bool))
        code = main(["track", str(seq), "--register", "--out", str(tmp_path / "out")])
        one_line_error(
            capsys,
            code,
            r"--register: applies to intensity frames: --detector dpa, or --detector hoc with "
            r"--threshold-pfa$",
        )

    def test_help_texts_are_detects(self, capsys):
        def options(cmd: str) -> dict[str, str]:
            assert main([cmd, "--help"]) == 0
            entries: dict[str, str] = {}
            flag = None
            text = capsys.readouterr().out
            text = text.split("\nmethods:\n")[0].split("\ntarget speed")[0]  # options, no epilog
            for line in text.splitlines():
                if line.startswith("  --"):
                    flag = line.split()[0].rstrip(",")
                    entries[flag] = ""
                elif not line.startswith(" " * 10):
                    flag = None
                if flag is not None:  # the entry without white space (wrapped differently)
                    entries[flag] += "".join(line.split())
            return entries

        detect, track = options("detect"), options("track")
        shared = ("--order", "--v", "--min-points", "--preset", "--g", "--b", "--pfa", "--whiten")
        for flag in shared:
            assert track[flag] == detect[flag].replace("--method", "--detector"), flag
        assert "--nms-radius" not in track and "--max-targets" not in track


def _ir_frames(shape=(12, 32, 32)) -> np.ndarray:
    """A small simulated IR sequence as 16-bit intensities (two targets, clear sky)."""
    targets = [IRTarget(6, 6, 1.0, 1.0, snr_db=14.0), IRTarget(6, 26, 1.0, -1.0, snr_db=14.0)]
    seq = simulate_ir(shape, targets, clouds="clear", jitter=0.0, seed=0)
    return np.round((seq.frames.numpy() + 10.0) * 1000.0).astype(np.uint16)


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("hocnet: warning: ")]


COMMANDS = [("detect", "--method"), ("track", "--detector")]


class TestNewUser:
    """What a new user met running `hocnet track` / `detect` from a fresh clone."""

    def test_saturated_cube_is_not_streamed(self, tmp_path, capsys, monkeypatch):
        # item 1: a cube of ones ran > 500 s (40 x 64 x 64) in the streaming HOC, which did all
        # the layer work before its density check; like `detect`, dense windows are skipped
        from hocnet.hoc.stream import StreamingDetector

        def push(self, scan):
            raise AssertionError("a window above the density bound was streamed")

        monkeypatch.setattr(StreamingDetector, "push", push)
        seq = tmp_path / "const.npy"
        np.save(seq, np.ones((20, 32, 32), dtype=bool))
        out = tmp_path / "out"
        assert main(["track", str(seq), "--detector", "hoc", "--out", str(out), "-q"]) == 0
        printed = capsys.readouterr().out
        assert "0 plots, 0 confirmed tracks" in printed
        meta = json.loads((out / "tracks.json").read_text())["meta"]
        assert meta["plots_per_frame"] == [0] * 20
        assert "discrimination bound" in meta["warnings"][0]

    @pytest.mark.parametrize(("window", "stride"), [(10, 1), (10, 2), (10, 3), (8, 11), (7, 4)])
    def test_dense_windows_skipped_plots_equal_detect_per_window(self, window, stride):
        # the reference: the union over the windows of `hocnet.hoc.detect` on each window (the
        # stream's documented equality), dense windows included (detect skips them itself)
        import warnings

        import torch

        from hocnet.cli.detect import hoc_kwargs
        from hocnet.cli.track import _hoc_plots, _window_starts
        from hocnet.hoc import density_bound, detect

        specs = [
            TargetSpec(start=(5, 5), velocity=(1.2, 1.2), p_miss=0.05),
            TargetSpec(start=(5, 40), velocity=(1.0, -0.8), p_miss=0.05),
        ]
        cube = simulate_binary((33, 48, 48), specs, clutter_density=0.01, seed=1).cube.clone()
        gen = torch.Generator().manual_seed(0)
        cube[12:20] |= torch.rand(8, 48, 48, generator=gen) < 0.12  # dense in the middle
        p = {"order": 2, "v": 4, "delta": 45.0, "threshold": 2.5, "min_points": 5}
        p.update(min_speed=0.0, window=window, stride=stride)
        starts = _window_starts(33, window, stride)
        bound = density_bound("modified", 4, math.radians(45.0))
        dense = [s for s in starts if cube[s : s + window].float().mean() > bound]
        assert dense and len(dense) < len(starts)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            stream = list(_hoc_plots(cube, p))
            kept = torch.zeros_like(cube)
            for s in starts:
                kept[s : s + window] |= detect(cube[s : s + window], **hoc_kwargs(p)).cleaned
        assert [t for t, _ in stream] == list(range(33))
        plots = [z for _, z in stream]
        expected = [kept[t].nonzero().double()[:, [1, 0]] for t in range(33)]
        assert sum(len(e) for e in expected) > 30  # measured: 35 to more than 50
        for got, want in zip(plots, expected, strict=True):
            assert torch.equal(got, want)

    def test_density_warning_is_a_hocnet_warning(self, tmp_path, capsys):
        # item 2: the same mechanism as `detect` (not Python's RuntimeWarning with its source)
        seq = tmp_path / "const.npy"
        np.save(seq, np.ones((12, 16, 16), dtype=bool))
        for cmd, _ in COMMANDS:
            assert main([cmd, str(seq), "--out", str(tmp_path / cmd), "--no-plot", "-q"]) == 0
            err = capsys.readouterr().err
            lines = _warnings(err)
            assert len(lines) == 1 and "discrimination bound 4.94 %" in lines[0], err
            assert "RuntimeWarning" not in err and ".py:" not in err

    def test_local_saturation_is_said_once_with_frame_numbers(self, tmp_path, capsys):
        # a second new-user trial: a saturated patch in frames 25-30 gave one warning per
        # window, each with the window's own scan numbers
        rng = np.random.default_rng(0)
        cube = rng.random((40, 64, 64)) < 0.005
        cube[25:31, 20:32, 30:42] = True
        seq = tmp_path / "patch.npy"
        np.save(seq, cube)
        code = main(["track", str(seq), "--detector", "hoc", "--out", str(tmp_path / "o"), "-q"])
        assert code == 0
        lines = [ln for ln in _warnings(capsys.readouterr().err) if "9 x 9 windows" in ln]
        assert len(lines) == 1 and "of frames [25, 26, 27, 28, 29, 30]" in lines[0], lines

    @pytest.mark.parametrize("where", ["same", "inside", "glob"])
    @pytest.mark.parametrize(("cmd", "selector"), COMMANDS)
    def test_out_in_the_input_folder_is_refused(self, tmp_path, capsys, where, cmd, selector):
        # item 3: the outputs would break the next run on the folder
        folder = tmp_path / "clip"
        save_frames(folder, _ir_frames((6, 16, 16)))
        seq = str(folder / "*.png") if where == "glob" else str(folder)
        out = folder / "results" if where == "inside" else folder
        before = snapshot(tmp_path)
        code = main([cmd, seq, selector, "dpa", "--out", str(out)])
        line = one_line_error(capsys, code, r"^hocnet: error: --out: '.*clip(/results)?' is ")
        assert "input folder" in line
        assert snapshot(tmp_path) == before

    def test_shifts_are_in_tracks_json(self, tmp_path, capsys):
        # item 4: `track` writes no shifts.csv: it says where the shifts are
        seq = tmp_path / "ir.npy"
        np.save(seq, _ir_frames())
        out = tmp_path / "out"
        assert main(["track", str(seq), "--detector", "dpa", "--out", str(out), "--no-plot"]) == 0
        printed = capsys.readouterr().out
        assert "see tracks.json (meta.shifts)" in printed and "shifts.csv" not in printed
        assert len(json.loads((out / "tracks.json").read_text())["meta"]["shifts"]) == 12
        assert not (out / "shifts.csv").exists()

    def test_closed_stdout_exits_0(self, tmp_path, capsys, monkeypatch):
        # item 5: `hocnet track ... | head -1` said "[Errno 32] Broken pipe" and exit 2
        import sys

        class Closed:
            def write(self, text):
                raise BrokenPipeError(32, "Broken pipe")

            def flush(self):
                raise BrokenPipeError(32, "Broken pipe")

        seq = tmp_path / "ir.npy"
        np.save(seq, _ir_frames())
        for cmd, selector in COMMANDS:
            out = tmp_path / cmd
            monkeypatch.setattr(sys, "stdout", Closed())
            code = main([cmd, str(seq), selector, "dpa", "--out", str(out), "--no-plot"])
            monkeypatch.undo()
            assert code == 0
            assert capsys.readouterr().err == ""
            assert (out / "tracks.json").is_file()

    def test_closed_pipe_in_a_process(self, tmp_path):
        import os
        import subprocess
        import sys

        seq = tmp_path / "scans.npy"
        np.save(seq, np.zeros((6, 12, 12), dtype=bool))
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        argv = [sys.executable, "-m", "hocnet.cli", "track", str(seq), "--out", str(tmp_path / "o")]
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        proc.stdout.close()  # the reader is gone before anything is printed
        err = proc.stderr.read().decode()
        assert proc.wait(timeout=120) == 0, err
        assert err == ""
        assert (tmp_path / "o" / "tracks.json").is_file()

    def test_deleted_tracks_are_counted_and_documented(self, tmp_path, capsys):
        # item 6: "1 confirmed track" whose status is "deleted": say it
        cube = np.zeros((24, 32, 32), dtype=bool)
        for t in range(12):  # a target for 12 scans, then gone
            cube[t, 3 + 2 * t, 4 + t] = True
        seq = tmp_path / "scans.npy"
        np.save(seq, cube)
        out = tmp_path / "out"
        assert main(["track", str(seq), "--out", str(out), "--no-plot"]) == 0
        printed = capsys.readouterr().out
        data = json.loads((out / "tracks.json").read_text())
        assert [tr["status"] for tr in data["tracks"]] == ["deleted"]
        assert "1 confirmed track (deleted by the end)" in printed
        assert set(data["meta"]["status"]) == {"confirmed", "deleted"}
        assert main(["track", "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        assert "confirmed still held at the last frame" in text
        assert "deleted ended before the last frame" in text

    @pytest.mark.parametrize(
        ("free", "match"),
        [
            (np.random.default_rng(0).random((10, 60, 60)) < 0.5, r"size of (SEQ|CUBE), 32 x 32"),
            (np.random.default_rng(0).normal(size=(10, 32, 40)), r"got 32 x 40"),
            ((np.random.default_rng(0).random((10, 32, 32)) < 0.5) * 1.0, r"binary values"),
        ],
    )
    @pytest.mark.parametrize(("cmd", "selector"), COMMANDS)
    def test_target_free_must_fit(self, tmp_path, capsys, free, match, cmd, selector):
        # item 7: a binary 10 x 60 x 60 cube was a CFAR reference for 64 x 64 IR frames
        seq, tf = tmp_path / "ir.npy", tmp_path / "free.npy"
        np.save(seq, _ir_frames())
        np.save(tf, free)
        out = tmp_path / "out"
        code = main([cmd, str(seq), selector, "dpa", "--target-free", str(tf), "--out", str(out)])
        one_line_error(capsys, code, r"^hocnet: error: --target-free: .*" + match)
        assert not out.exists()

    @pytest.mark.parametrize(("cmd", "selector"), COMMANDS)
    def test_threshold_pfa_keeping_no_point_is_said(self, tmp_path, capsys, cmd, selector):
        # item 8: Pfa H W < 1 keeps 0 points per frame
        seq = tmp_path / "ir.npy"
        np.save(seq, _ir_frames())
        argv = [cmd, str(seq), "--threshold-pfa", "1e-9", "--out", str(tmp_path / "o"), "-q"]
        assert main([*argv, "--no-plot"]) == 0
        lines = _warnings(capsys.readouterr().err)
        assert len(lines) == 1 and lines[0].startswith("hocnet: warning: --threshold-pfa: 1e-09")
        assert "(< 1)" in lines[0] and "0.000977" in lines[0]  # 1 / (32 x 32)

    def test_order_too_large_for_the_window_names_order(self, tmp_path, capsys):
        # item 9: "--window: expected an integer >= 199, got 10" for --order 99
        seq = tmp_path / "scans.npy"
        np.save(seq, np.zeros((6, 12, 12), dtype=bool))
        code = main(["track", str(seq), "--window", "3", "--out", str(tmp_path / "o")])
        one_line_error(capsys, code, r"^hocnet: error: --window: expected an integer >= 5, got 3")
        code = main(["track", str(seq), "--order", "3", "--window", "5", "--out", str(tmp_path)])
        one_line_error(
            capsys, code, r"^hocnet: error: --order: expected at most \(--window - 1\) // 2 = 2 "
        )

    @pytest.mark.parametrize("window", [None, "300"])
    def test_order_99_one_round_trip(self, tmp_path, capsys, window):
        """`--order 99` was refused twice (first: the default --window 10 cannot hold it; with
        --window 300: SEQ has too few frames). Now one error, with the range that works."""
        seq = tmp_path / "scans.npy"
        np.save(seq, np.zeros((10, 12, 12), dtype=bool))
        extra = [] if window is None else ["--window", window]
        argv = ["track", str(seq), "--order", "99", *extra, "--out", str(tmp_path / "o"), "-q"]
        one_line_error(
            capsys,
            main(argv),
            r"^hocnet: error: --order: expected at most \(T - 1\) // 2 = 4 for SEQ of T = 10 "
            r"frames \(order k needs 2k \+ 1 frames\), got 99$",
        )
        argv[argv.index("99")] = "4"  # the range given works at once
        assert main([*argv, "--no-plot"]) == 0

    def test_bad_options_said_together(self, tmp_path, capsys):
        seq = tmp_path / "scans.npy"
        np.save(seq, np.zeros((10, 12, 12), dtype=bool))
        argv = ["track", str(seq), "--order", "0", "--v", "0", "--delta", "400", "--stride", "0"]
        line = one_line_error(capsys, main([*argv, "--out", str(tmp_path / "o")]), "4 problems")
        for flag in ("--order", "--v", "--delta", "--stride"):
            assert f"{flag}: expected" in line
        assert not (tmp_path / "o").exists()

    def test_messages_name_the_flags_as_typed(self, tmp_path, capsys):
        # item 10
        from PIL import Image

        seq = tmp_path / "ir.npy"
        np.save(seq, _ir_frames())
        clip = tmp_path / "clip"
        save_frames(clip, _ir_frames((6, 16, 16)))
        nan = tmp_path / "nan"
        nan.mkdir()
        for t in range(6):
            frame = np.zeros((8, 8), dtype=np.float32)
            frame[2, 2] = np.nan if t == 4 else 1.0
            Image.fromarray(frame).save(nan / f"f{t}.tif")
        out = str(tmp_path / "o")
        cases = [
            (["track", str(seq), "--detector", "dpa", "--b", "1e9"], r"^hocnet: error: --b: "),
            (["track", str(clip)], r"^hocnet: error: SEQ: the frames of .*clip' are not binary"),
            (["detect", str(clip)], r"^hocnet: error: CUBE: the frames of .*clip' are not binary"),
            (["track", str(seq), "--bogus"], r"--bogus \(see 'hocnet track --help'\)$"),
            (["detect", str(seq), "--bogus"], r"--bogus \(see 'hocnet detect --help'\)$"),
            (["track", str(seq), "--key", "frames"], r"--key: expected no --key for the \.npy"),
            (
                ["track", str(nan), "--detector", "dpa"],
                r"SEQ: expected finite values, got 1 NaN/inf entries in 1 frame file .*'f4\.tif'",
            ),
        ]
        for argv, match in cases:
            one_line_error(capsys, main([*argv, "--out", out]), match)
        assert not (tmp_path / "o").exists()

    @pytest.mark.parametrize(
        ("cmd", "selector", "method", "match"),
        [
            ("track", "--detector", "dpa", r"SEQ: expected at least 3 frames for --detector dpa"),
            ("detect", "--method", "dpa", r"CUBE: expected at least 2 frames for the DPA"),
            ("track", "--detector", "hoc", r"SEQ: expected at least 2 \* order \+ 1 = 5 frames"),
            ("detect", "--method", "hoc", r"CUBE: expected at least 3 scans for the HOC"),
        ],
    )
    def test_one_frame_folder(self, tmp_path, capsys, cmd, selector, method, match):
        # item 11: dpa wrote empty results, hoc refused; both name their minimum now
        frame = _ir_frames((1, 16, 16)) if method == "dpa" else np.zeros((1, 16, 16), bool)
        save_frames(tmp_path / "one", frame)
        out = tmp_path / "out"
        code = main([cmd, str(tmp_path / "one"), selector, method, "--out", str(out)])
        one_line_error(capsys, code, match)
        assert not out.exists()

    def test_top_level_help_and_track_ids(self, capsys):
        # item 12
        import torch

        from hocnet.cli.track import LABEL_COLOUR, _figure

        assert main(["--help"]) == 0
        assert "Input (detect, track):" in capsys.readouterr().out
        cube = torch.ones(4, 8, 8, dtype=torch.bool)
        plots = [torch.tensor([[1.0, 2.0]])] * 4
        track = {"id": 7, "points": [[t, 1.0, 2.0, 0] for t in range(4)]}
        fig = _figure(cube, plots, [track], "t")
        (label,) = fig.axes[0].texts
        assert label.get_text() == "7" and label.get_color() == LABEL_COLOUR == "navy"
        assert label.get_path_effects()  # the white outline


def _batch_mht(plots, p):
    """A copy of the batch path before streaming: every frame's plots first, then the MHT."""
    from functools import partial

    import torch

    from hocnet.tracking.kalman import constant_velocity
    from hocnet.tracking.mht import MHT, CVKalmanFilter, IMMFilter

    if p["filter"] == "imm":
        filt = IMMFilter(
            [
                partial(constant_velocity, sigma_a=p["sigma_a"]),
                partial(constant_velocity, sigma_a=10 * p["sigma_a"]),
            ],
            [[0.95, 0.05], [0.05, 0.95]],
            initial_mu=[0.5, 0.5],
            velocity_std=p["velocity_std"],
        )
    else:
        filt = CVKalmanFilter(p["sigma_a"], p["velocity_std"])
    mht = MHT(
        filt,
        R=(p["meas_std"] ** 2) * torch.eye(2, dtype=torch.float64),
        pd=p["pd"],
        lambda_fa=p["lambda_fa"],
        lambda_nt=p["lambda_nt"],
        alpha=p["alpha"],
        beta=p["beta"],
        n_hypotheses=p["n_hypotheses"],
        n_scan=p["n_scan"],
    )
    for t, z in enumerate(plots):
        mht.step(z, time=float(t))
    return mht.all_tracks()


def _batch_hoc_plots(cube, p):
    """The HOC's plots in batch: the union over the windows of `hocnet.hoc.detect` on each."""
    import warnings

    import torch

    from hocnet.cli.detect import hoc_kwargs
    from hocnet.cli.track import _window_starts
    from hocnet.hoc import detect

    kept = torch.zeros_like(cube)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for s in _window_starts(cube.shape[0], p["window"], p["stride"]):
            kept[s : s + p["window"]] |= detect(cube[s : s + p["window"]], **hoc_kwargs(p)).cleaned
    return [kept[t].nonzero().double()[:, [1, 0]] for t in range(cube.shape[0])]


def _batch_dpa_plots(cube, params):
    """The DPA's plots as the batch path computed them: `hocnet detect`'s DPA on the whole
    sequence (:func:`hocnet.cli.detect._run_dpa`: pre-processing and one `accumulate` call),
    then the local maxima of every frame's ASF."""
    from hocnet.cli.detect import DETECTION_NMS_RADIUS, _run_dpa
    from hocnet.detection_metrics import detect_peaks

    detection = _run_dpa(cube, {**params, "label": "SEQ"})
    asf = detection.result.state.asf.double()
    found = detect_peaks(
        asf,
        radius=DETECTION_NMS_RADIUS,
        max_per_frame=params["max_per_frame"],
        threshold=detection.params.get("threshold_used"),
    )
    plots = []
    for t in range(cube.shape[0]):
        rows = found[found[:, 0] == t]
        if bool(asf[t].max() == asf[t].min()):
            rows = rows[:0]
        plots.append(rows[:, 1:3])
    return plots, detection.result.shifts


class TestOnline:
    """The streaming path gives the batch path's plots and, with --lambda-fa, its tracks."""

    @staticmethod
    def _run(tmp_path, array, argv):
        from hocnet.cli import build_parser
        from hocnet.cli.track import _prepare

        tmp_path.mkdir(parents=True, exist_ok=True)
        seq = tmp_path / "seq.npy"
        np.save(seq, array)
        out = tmp_path / "out"
        full = ["track", str(seq), "--out", str(out), "--no-plot", "-q", *argv]
        assert main(full) == 0
        args = build_parser().parse_args(full)
        return json.loads((out / "tracks.json").read_text()), _prepare(args)

    @pytest.mark.parametrize("stride", [2, 3])
    def test_hoc_streaming_equals_batch(self, tmp_path, binary_scene, capsys, stride):
        import torch

        from hocnet.cli.track import _hoc_plots, _track_dicts

        cube = binary_scene.cube
        argv = ["--detector", "hoc", "--stride", str(stride), "--lambda-fa", "3e-4"]
        data, params = self._run(tmp_path, cube.numpy(), argv)
        capsys.readouterr()
        want = _batch_hoc_plots(cube, params)
        got = list(_hoc_plots(cube, params))
        assert [t for t, _ in got] == list(range(40))
        for (_, z), ref in zip(got, want, strict=True):
            assert torch.equal(z, ref)
        assert data["meta"]["plots_per_frame"] == [len(z) for z in want]
        mht = data["meta"]["mht_params"]
        assert mht["lambda_fa"] == 3e-4 and mht["lambda_fa_source"] == "--lambda-fa"
        reference = _track_dicts(_batch_mht(want, mht), want)
        assert len(reference) >= 2
        assert data["tracks"] == json.loads(json.dumps(reference))

    @pytest.mark.parametrize(
        ("scene", "extra"),
        [
            ("clear", []),
            ("clear", ["--no-register", "--background", "mean"]),
            ("bright", ["--background", "lowrank", "--background-window", "6"]),
        ],
    )
    def test_dpa_streaming_equals_batch(
        self, tmp_path, ir_scene, capsys, monkeypatch, scene, extra
    ):
        import torch

        import hocnet.data.background as background
        from hocnet.cli.track import _dpa_plots, _track_dicts

        frames = ir_scene.frames
        if scene == "bright":  # clouds and a shaking camera: registration with non-zero shifts
            targets = [IRTarget(8, 8, 1.2, 1.2, snr_db=16.0), IRTarget(8, 56, 1.2, -1.2, snr_db=16)]
            frames = simulate_ir((24, 64, 64), targets, clouds="bright", jitter=1.0, seed=1).frames
        argv = ["--detector", "dpa", "--lambda-fa", "2e-4", *extra]
        data, params = self._run(tmp_path, frames.numpy(), argv)
        capsys.readouterr()
        stream, info = _dpa_plots(frames.double(), dict(params))
        got = list(stream)
        _, batch_shifts = _batch_dpa_plots(frames.double(), dict(params))
        if batch_shifts is not None:
            # the pairs registered one at a time: the FFTs of a pair and of the whole sequence
            # round differently in float32 (measured: 1 of 23 pairs moved by one 0.01 px step
            # of the sub-pixel search); the rest of the batch path is then run with the
            # stream's shifts, so the comparison below is exact
            ours = info["shifts"]
            assert (ours - batch_shifts).abs().max() <= 0.0101
            assert int(((ours - batch_shifts).abs().sum(1) > 0).sum()) <= 2
            assert int((batch_shifts.abs().sum(1) > 0).sum()) >= (10 if scene == "bright" else 0)
            pairs = torch.zeros_like(ours[:, 0], dtype=torch.bool)

            def estimate(x, **kw):  # the stream's shifts, no peak rejected
                return (ours.to(x.dtype), pairs) if kw.get("return_rejected") else ours

            monkeypatch.setattr(background, "estimate_shifts", estimate)
        want, shifts = _batch_dpa_plots(frames.double(), dict(params))
        for (_, z), ref in zip(got, want, strict=True):
            assert torch.equal(z, ref)
        assert sum(len(z) for z in want) > 100
        if shifts is None:
            assert info["shifts"] is None and "shifts" not in data["meta"]
        else:
            assert data["meta"]["shifts"] == info["shifts"].tolist()
        reference = _track_dicts(_batch_mht(want, data["meta"]["mht_params"]), want)
        assert len(reference) >= (2 if scene == "clear" else 1)
        assert data["tracks"] == json.loads(json.dumps(reference))

    def test_dpa_plots_are_causal(self, ir_scene):
        # the plots of frame t from the first t + 1 frames only equal those of the whole run
        import torch

        from hocnet.cli import build_parser
        from hocnet.cli.track import _dpa_plots, _prepare

        frames = ir_scene.frames.double()[:16]
        args = build_parser().parse_args(["track", "x.npy", "--detector", "dpa"])
        params = _prepare(args)
        whole = [z for _, z in _dpa_plots(frames, dict(params))[0]]
        for t in (4, 9, 15):
            short = [z for _, z in _dpa_plots(frames[: t + 1], dict(params))[0]]
            assert torch.equal(short[t], whole[t])

    def test_hoc_frame_is_yielded_once_its_windows_are_done(self, binary_scene):
        # frame t is out after frame s + window - 1 is read (s: the last window start <= t)
        from hocnet.cli.track import _hoc_plots, _window_starts

        cube = binary_scene.cube[:23]
        read: list[int] = []

        def frames():
            for n in range(23):
                read.append(n)
                yield cube[n]

        p = {"order": 2, "v": 4, "delta": 45.0, "threshold": 2.5, "min_points": 5}
        p.update(min_speed=0.0, window=10, stride=3)
        starts = _window_starts(23, 10, 3)
        assert starts == [0, 3, 6, 9, 12, 13]
        for t, _ in _hoc_plots(frames(), p, shape=tuple(cube.shape)):
            s = max(s for s in starts if s <= t)
            assert len(read) == s + 10, (t, len(read))

    def test_default_lambda_fa_is_causal(self):
        # the default density from the first K frames only: later frames do not change it
        import torch

        from hocnet.cli import build_parser
        from hocnet.cli.track import _run_mht

        gen = torch.Generator().manual_seed(0)
        counts = [1] * 5 + [12] * 15  # clutter from frame 5 on
        plots = [torch.rand(c, 2, generator=gen, dtype=torch.float64) * 32 for c in counts]
        pulled: list[int] = []

        def stream():
            for t, z in enumerate(plots):
                pulled.append(t)
                yield t, z

        params = {}
        for k in ("5", "20"):
            args = build_parser().parse_args(["track", "x.npy", "--lambda-fa-frames", k])
            pulled.clear()
            _, got, params[k] = _run_mht(stream(), args, 20, 1024.0)
            assert pulled == list(range(20)) and len(got) == 20
        assert params["5"]["lambda_fa"] == 1 / 1024  # frames 0-4 only
        assert params["20"]["lambda_fa"] == pytest.approx(sum(counts) / 20 / 1024)
        assert "over the first 5 frames (5 plots" in params["5"]["lambda_fa_source"]
        assert params["5"]["lambda_nt"] == params["5"]["lambda_fa"] / 10
        empty = [(t, plots[0][:0]) for t in range(3)]  # fewer frames than K, and no plots
        args = build_parser().parse_args(["track", "x.npy"])
        _, _, p = _run_mht(iter(empty), args, 3, 1024.0)
        assert p["lambda_fa"] == 0.1 / 1024 and "first 3 frames" in p["lambda_fa_source"]

    def test_lambda_fa_frames_options(self, tmp_path, capsys):
        seq = tmp_path / "s.npy"
        np.save(seq, np.zeros((8, 12, 12), dtype=bool))
        for extra, match in (
            (["--lambda-fa-frames", "0"], r"--lambda-fa-frames: expected an integer >= 1"),
            (["--lambda-fa", "1e-3", "--lambda-fa-frames", "3"], r"--lambda-fa-frames: .*both"),
        ):
            code = main(["track", str(seq), "--out", str(tmp_path / "o"), *extra])
            one_line_error(capsys, code, match)
        assert main(["track", "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        assert "--lambda-fa-frames K" in text and "online" in text

    def test_threshold_pfa_binarised_frame_by_frame_equals_batch(self, ir_scene):
        import warnings

        import torch

        from hocnet.cli import build_parser
        from hocnet.cli.detect import binarize_frames
        from hocnet.cli.track import _hoc_input, _prepare

        args = build_parser().parse_args(["track", "x.npy", "--threshold-pfa", "0.003"])
        params = _prepare(args)
        params.pop("binary", None)
        frames = ir_scene.frames.double()[:16]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            want, shifts, note = binarize_frames(frames, dict(params))
            stream, info = _hoc_input(frames, dict(params))
            got = torch.stack(list(stream))
        assert want.sum() > 16 and torch.equal(got, want)
        assert shifts is not None and torch.equal(info["shifts"], shifts)
        assert info["notes"][-1] == note

    def test_mht_built_once_the_first_k_frames_are_known(self, monkeypatch):
        import torch

        from hocnet.cli import build_parser
        from hocnet.cli import track as track_module

        pulled: list[int] = []
        built: list[int] = []
        real = track_module._build_mht

        def build(p):
            built.append(len(pulled))
            return real(p)

        monkeypatch.setattr(track_module, "_build_mht", build)

        def stream():
            for t in range(8):
                pulled.append(t)
                yield t, torch.zeros(0, 2, dtype=torch.float64)

        for argv, frames in (([], 5), (["--lambda-fa-frames", "3"], 3), (["--lambda-fa", "1"], 1)):
            pulled.clear()
            built.clear()
            args = build_parser().parse_args(["track", "x.npy", *argv])
            track_module._run_mht(stream(), args, 8, 100.0)
            assert built == [frames]

    @pytest.mark.parametrize(
        ("tty", "quiet", "shown"), [(True, False, True), (True, True, False), (False, False, False)]
    )
    def test_progress_bar_on_a_terminal_only(
        self, tmp_path, capsys, monkeypatch, tty, quiet, shown
    ):
        # the shared tqdm bar of the CLI (`_common._progress`), over the frames as they are done
        import sys

        from hocnet.cli import track as track_module

        calls = []
        real = track_module._progress

        def progress(items, *, desc, total, enabled):
            calls.append((desc, total, enabled))
            return real(items, desc=desc, total=total, enabled=False)

        monkeypatch.setattr(track_module, "_progress", progress)
        monkeypatch.setattr(sys.stderr, "isatty", lambda: tty, raising=False)
        seq = tmp_path / "s.npy"
        np.save(seq, np.zeros((7, 12, 12), dtype=bool))
        argv = ["track", str(seq), "--out", str(tmp_path / "o"), "--no-plot", *["-q"] * quiet]
        assert main(argv) == 0
        capsys.readouterr()
        assert calls == [("track", 7, shown)]

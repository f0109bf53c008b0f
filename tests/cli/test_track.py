"""Tests of ``hocnet track``: detector plots into the MHT, on simulated crossing targets."""

from __future__ import annotations

import json
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
            (["--detector", "dpa", "--window", "5"], r"--window: does not apply"),
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
        one_line_error(
            capsys, code, r"--out: writing '.*tracks\.png' would replace the input SEQ frame"
        )
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
            for line in capsys.readouterr().out.splitlines():
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

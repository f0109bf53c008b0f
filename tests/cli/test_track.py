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

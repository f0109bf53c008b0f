"""Command-line problems a new user met (second round): each test fails on the old code."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from hocnet.cli import main


def one_line_error(capsys, code: int, match: str) -> str:
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hocnet: error: "), err
    assert re.search(match, lines[0]), lines[0]
    return lines[0]


def noise(path, shape, seed=0):
    rng = np.random.default_rng(seed)
    np.save(path, rng.normal(100.0, 5.0, shape).astype(np.float32))
    return str(path)


class TestTargetFreeTooShort:
    def test_one_frame_with_background_removal_refused(self, tmp_path, capsys):
        x = noise(tmp_path / "x.npy", (8, 24, 24))
        one = noise(tmp_path / "one.npy", (1, 24, 24), seed=1)
        out = tmp_path / "o"
        code = main(["detect", x, "--method", "dpa", "--target-free", one, "--out", str(out)])
        one_line_error(capsys, code, r"--target-free: expected at least 2 frames .*got 1")
        assert not out.exists()

    def test_two_frames_give_a_positive_threshold(self, tmp_path, capsys):
        x = noise(tmp_path / "x.npy", (8, 40, 40))
        two = noise(tmp_path / "two.npy", (2, 40, 40), seed=1)
        out = tmp_path / "o"
        args = ["detect", x, "--method", "dpa", "--target-free", two, "--out", str(out)]
        assert main([*args, "--no-register"]) == 0
        meta = json.loads((out / "tracks.json").read_text())["meta"]
        assert meta["threshold_used"] > 0

    def test_track_refuses_too(self, tmp_path, capsys):
        x = noise(tmp_path / "x.npy", (8, 24, 24))
        one = noise(tmp_path / "one.npy", (1, 24, 24), seed=1)
        out = tmp_path / "o"
        code = main(["track", x, "--detector", "dpa", "--target-free", one, "--out", str(out)])
        one_line_error(capsys, code, r"--target-free: expected at least 2 frames .*got 1")


@pytest.mark.parametrize("background", ["none"])
def test_target_free_one_frame_without_background_accepted(tmp_path, background):
    x = noise(tmp_path / "x.npy", (8, 40, 40))
    one = noise(tmp_path / "one.npy", (1, 40, 40), seed=1)
    out = tmp_path / "o"
    args = ["detect", x, "--method", "dpa", "--target-free", one, "--out", str(out)]
    assert main([*args, "--background", background, "--no-register"]) == 0

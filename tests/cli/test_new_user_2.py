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


@pytest.fixture(scope="module")
def one_target(tmp_path_factory):
    from hocnet.data.infrared import IRTarget, simulate_ir

    scene = simulate_ir(
        (20, 48, 48), [IRTarget(8, 8, 1.0, 0.8, snr_db=14.0)], clouds="clear", jitter=0.0, seed=0
    )
    path = tmp_path_factory.mktemp("one_target") / "seq.npy"
    np.save(path, scene.frames.numpy())
    return path


class TestLambdaFaCountsOnlyFramesWithPlots:
    def test_one_frame_estimate_skips_frame_0(self, tmp_path, one_target, capsys):
        # measured on the old code: frame 0 (all zero after background removal) was the only
        # counted frame, the estimate fell to its floor and 4 tracks were confirmed
        out = tmp_path / "o"
        args = ["track", str(one_target), "--detector", "dpa", "--no-plot", "--out", str(out)]
        assert main([*args, "--lambda-fa-frames", "1"]) == 0
        capsys.readouterr()
        data = json.loads((out / "tracks.json").read_text())
        mht = data["meta"]["mht_params"]
        assert mht["lambda_fa_frames_counted"] == [1]
        assert mht["lambda_fa_frames_skipped"] == [0]
        assert "not counted: frame 0" in mht["lambda_fa_source"]
        assert mht["lambda_fa"] > 0.1 / (48 * 48)
        assert len(data["tracks"]) == 1

    def test_flat_frames_skipped(self, tmp_path, one_target, capsys):
        seq = np.load(one_target)
        seq[2] = seq[3] = 7.0
        path = tmp_path / "flat.npy"
        np.save(path, seq)
        out = tmp_path / "o"
        args = ["track", str(path), "--detector", "dpa", "--no-plot", "--out", str(out)]
        assert main([*args, "--lambda-fa-frames", "3", "--no-register"]) == 0
        capsys.readouterr()
        mht = json.loads((out / "tracks.json").read_text())["meta"]["mht_params"]
        assert mht["lambda_fa_frames_counted"] == [1, 4, 5]
        assert mht["lambda_fa_frames_skipped"] == [0, 2, 3]

    def test_floor_warned(self):
        import warnings

        import torch

        from hocnet.cli import build_parser
        from hocnet.cli.track import _run_mht

        def stream(counts):
            for t, c in enumerate(counts):
                yield t, torch.rand(c, 2, dtype=torch.float64) * 32

        args = build_parser().parse_args(["track", "x.npy", "--detector", "dpa"])
        # frames 0-4 without plots, then 3 per frame: the estimate is at its floor, warned
        with pytest.warns(RuntimeWarning, match=r"--lambda-fa: .* at its floor") as said:
            _, _, p = _run_mht(stream([0] * 5 + [3] * 15), args, 20, 1024.0)
        assert len(said) == 1 and p["lambda_fa_at_floor"] and p["lambda_fa"] == 0.1 / 1024
        # no plots anywhere: nothing to be misled by, no warning
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            _, _, p = _run_mht(stream([0] * 20), args, 20, 1024.0)
            assert p["lambda_fa_at_floor"]
            _, _, p = _run_mht(stream([2] * 20), args, 20, 1024.0)
            assert not p["lambda_fa_at_floor"]
        # frames that cannot have plots are not what puts it at its floor
        _, _, p = _run_mht(stream([0] + [3] * 19), args, 20, 1024.0, uncounted=[0])
        assert not p["lambda_fa_at_floor"] and p["lambda_fa"] == 3 / 1024

    def test_floor_warned_once_on_the_command_line(self, tmp_path, one_target, capsys):
        out = tmp_path / "o"
        args = ["track", str(one_target), "--detector", "dpa", "--no-plot", "--out", str(out)]
        # measured: the ASF maximum of frame 1 (the one counted) is 4.48, of later frames up
        # to 8.54: no plot counted, plots later
        assert main([*args, "--lambda-fa-frames", "1", "--asf-threshold", "6.5"]) == 0
        err = capsys.readouterr().err
        lines = [x for x in err.splitlines() if "--lambda-fa" in x]
        assert len(lines) == 1 and lines[0].startswith("hocnet: warning: --lambda-fa: ")


@pytest.fixture(scope="module")
def ten_scans(tmp_path_factory):
    from hocnet.data.binary import TargetSpec, simulate_binary

    spec = TargetSpec(start=(5, 5), velocity=(1.5, 1.2), p_miss=0.0)
    scene = simulate_binary((10, 48, 48), [spec], clutter_density=0.002, seed=0)
    path = tmp_path_factory.mktemp("ten") / "bin.npy"
    np.save(path, scene.cube.numpy())
    return path


class TestSupportOption:
    def test_support_reaches_the_detector(self, tmp_path, ten_scans, capsys, monkeypatch):
        import hocnet.hoc

        seen = []
        real = hocnet.hoc.detect

        def spy(*a, **kw):
            seen.append(kw.get("support"))
            return real(*a, **kw)

        monkeypatch.setattr(hocnet.hoc, "detect", spy)
        for support in ("mhoc", "chain"):
            out = tmp_path / support
            args = ["detect", str(ten_scans), "--method", "hoc", "--order", "3"]
            assert main([*args, "--support", support, "--out", str(out)]) == 0
            meta = json.loads((out / "tracks.json").read_text())["meta"]
            assert meta["support"] == support
        assert seen == ["mhoc", "chain"]
        out, err = capsys.readouterr()
        # the uncovered-scan warning (mhoc only) names the command-line option
        assert "--support chain covers every scan" in err and "support='chain'" not in err

    def test_summary_names_the_image_and_why_more_points_are_kept(self, tmp_path, ten_scans):
        out = tmp_path / "o"
        args = ["detect", str(ten_scans), "--method", "hoc", "--order", "3", "--out", str(out)]
        import contextlib
        import io

        buf = io.StringIO()
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
            assert main(args) == 0
        meta = json.loads((out / "tracks.json").read_text())["meta"]
        line = buf.getvalue().splitlines()[0]
        assert f"in the MHOC image: {meta['points_support']}" in line
        assert f"kept on tracks: {meta['points_out']}" in line
        assert meta["points_out"] > meta["points_support"]  # measured: 10 > 8
        assert "identification brings back points the MHOC image misses" in line
        assert "in the support:" not in line

    def test_track_takes_support(self, tmp_path, ten_scans, capsys):
        out = tmp_path / "o"
        args = ["track", str(ten_scans), "--detector", "hoc", "--order", "3", "--no-plot"]
        assert main([*args, "--support", "chain", "--out", str(out)]) == 0
        meta = json.loads((out / "tracks.json").read_text())["meta"]
        assert meta["detector_params"]["support"] == "chain"


def test_registration_note_on_a_smooth_texture(tmp_path, capsys):
    # a Gaussian-blurred texture (sigma 3 px): there is structure, but the phase-correlation
    # peak is below the test's threshold; the note must not say "no structure"
    import torch

    from hocnet.cli.detect import _shifts_summary

    line = _shifts_summary(torch.zeros(30, 2), unregistered=29)
    assert line.startswith("registration: no reliable registration peak in 29 of 29 frame pairs")
    assert "noise, flat or very smooth frames; shifts kept at 0" in line
    assert "no structure" not in line
    part = _shifts_summary(torch.ones(30, 2), unregistered=3)
    assert "no reliable registration peak in 3 of 29 frame pairs" in part
    rng = np.random.default_rng(0)
    base = torch.from_numpy(rng.normal(0, 1, (1, 1, 96, 96))).float()
    k = torch.exp(-0.5 * (torch.arange(-9, 10, dtype=torch.float32) / 3.0) ** 2)
    k = k / k.sum()
    smooth = torch.nn.functional.conv2d(base, k.view(1, 1, 1, -1), padding=(0, 9))
    smooth = torch.nn.functional.conv2d(smooth, k.view(1, 1, -1, 1), padding=(9, 0))[0, 0]
    frames = torch.stack([smooth[10:50, 10 + t : 50 + t] for t in range(6)]) * 50 + 100
    frames = frames + torch.from_numpy(rng.normal(0, 0.5, frames.shape)).float()
    path = tmp_path / "tex.npy"
    np.save(path, frames.numpy())
    assert main(["detect", str(path), "--method", "dpa", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "registration:" in out and "no structure" not in out


class TestTrackDPAOptions:
    def test_direction_step_and_window_reach_the_dpa(self, tmp_path, one_target, monkeypatch):
        import hocnet.dpa

        seen = []
        real = hocnet.dpa.accumulate

        def spy(frames, weights, *a, **kw):
            seen.append((tuple(weights.shape[-2:]), kw.get("direction_step")))
            return real(frames, weights, *a, **kw)

        monkeypatch.setattr(hocnet.dpa, "accumulate", spy)
        out = tmp_path / "o"
        args = ["track", str(one_target), "--detector", "dpa", "--no-plot", "--out", str(out)]
        assert main([*args, "--direction-step", "source", "--window", "3", "--g", "1"]) == 0
        assert seen and set(seen) == {((3, 3), "source")}
        meta = json.loads((out / "tracks.json").read_text())["meta"]["detector_params"]
        assert meta["window"] == 3 and meta["direction_step"] == "source"

    def test_bad_window_and_hoc_only_flags(self, tmp_path, one_target, capsys):
        args = ["track", str(one_target), "--detector", "dpa", "--out", str(tmp_path / "o")]
        one_line_error(capsys, main([*args, "--window", "4"]), r"--window: expected an odd")
        one_line_error(
            capsys,
            main([*args, "--window", "49"]),
            r"SEQ: expected frames of at least 49 x 49 .*--window",
        )
        one_line_error(
            capsys,
            main(["track", str(one_target), "--direction-step", "source"]),
            r"--direction-step: does not apply to --detector hoc",
        )


def test_track_refuses_a_stride_larger_than_the_window(tmp_path, ten_scans, capsys):
    args = ["track", str(ten_scans), "--detector", "hoc", "--out", str(tmp_path / "o")]
    one_line_error(
        capsys,
        main([*args, "--window", "5", "--stride", "7"]),
        r"--stride: expected at most --window = 5 \(.*the 2 frames between two windows.*got 7",
    )
    assert main([*args, "--window", "5", "--stride", "5", "--no-plot"]) == 0

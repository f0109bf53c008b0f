"""Smoke and unit tests of experiments/dpa_crossing.py (crossing targets in the DPA)."""

import pathlib
import shutil
import sys

import pytest
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _helpers import load_script, quick_run_watched, read_rows, results_snapshot


@pytest.fixture(scope="module")
def crossing():
    return load_script("dpa_crossing.py")


@pytest.fixture(scope="module")
def quick_run(crossing, tmp_path_factory):
    """One ``--quick`` run into a temporary ``--out``, with the results folder watched."""
    return quick_run_watched(crossing, tmp_path_factory.mktemp("dpa-crossing"))


def test_interface(crossing):
    assert crossing.NAME == "dpa-crossing"
    assert isinstance(crossing.DESCRIPTION, str) and crossing.DESCRIPTION
    assert callable(crossing.run) and callable(crossing.main)
    assert list(crossing.METHODS.values()) == [False, "retrack", "joint", "straightest"]


def test_targets_meet_around_frame_12(crossing):
    for scene in ("0.5", "0.71", "1", "1.41", "1.5"):
        a, b = (t.trajectory(25) for t in crossing.targets(scene))
        gap = torch.linalg.vector_norm(a - b, dim=-1)
        assert int(gap.argmin()) == 12 and float(gap[12]) < 1e-9, scene
        assert crossing.speed_label(scene) == scene
    a, b = (t.trajectory(25) for t in crossing.targets("near-miss"))
    assert float(torch.linalg.vector_norm(a - b, dim=-1).min()) == pytest.approx(3.0)
    a, b = (t.trajectory(25) for t in crossing.targets("overtake"))
    gap = torch.linalg.vector_norm(a - b, dim=-1)  # level at t = 12.5: 2 px apart
    assert int(gap.argmin()) in (12, 13) and 2.0 < float(gap.min()) < 2.05


def _followed_loop(positions, truth):
    """Obviously-correct reading of the criterion, frame by frame."""
    n_targets, n_frames = truth.shape[0], truth.shape[1]
    owners = []
    for pos in positions:
        rates = []
        for k in range(n_targets):
            near = 0
            for t in range(n_frames):
                dx = float(pos[t, 0]) - float(truth[k, t, 0])
                dy = float(pos[t, 1]) - float(truth[k, t, 1])
                near += (dx * dx + dy * dy) ** 0.5 <= 1.5
            rates.append(near / n_frames)
        best = max(rates)
        if best < 0.8:
            return False
        owners.append(rates.index(best))
    return sorted(owners) == list(range(n_targets))


def test_followed_matches_loop(crossing):
    gen = torch.Generator().manual_seed(0)
    truth = torch.stack([t.trajectory(10) for t in crossing.targets("0.71")])
    for _ in range(30):
        positions = [
            truth[i]
            + torch.randint(-2, 3, (10, 2), generator=gen).double()
            * (torch.rand(10, 1, generator=gen) < 0.15)
            for i in torch.randint(0, 2, (int(torch.randint(1, 3, (1,), generator=gen)),))
        ]
        assert crossing.followed(positions, truth) == _followed_loop(positions, truth)
    assert crossing.followed([truth[0], truth[1]], truth)
    assert not crossing.followed([truth[0]], truth)  # a target without a track
    assert not crossing.followed([truth[0], truth[0]], truth)  # one target twice


def test_quick_run_writes_md_and_csv_only_into_out(crossing, quick_run):
    md, out, before, after = quick_run
    assert md == out / "dpa-crossing.md"
    assert sorted(p.name for p in out.iterdir()) == ["dpa-crossing.csv", "dpa-crossing.md"]
    assert before == after  # nothing written into experiments/results
    rows = read_rows(out / "dpa-crossing.csv")
    settings = [
        (s, g, step) for s in crossing.QUICK_SCENES for g in crossing.GS for step in crossing.STEPS
    ]
    assert [(r["scene"], float(r["g"]), r["direction_step"]) for r in rows] == settings
    text = md.read_text()
    assert "quick (smoke) run, 2 seeded scenes" in text
    header = (
        "| scene | speed (px/frame) | g | direction step | each target alone | plain | retrack "
        "| joint | straightest |"
    )
    assert header in text
    lines = text[text.index(header) :].splitlines()[2:]
    table = [line for line in lines if line.startswith("| ")]
    assert len(table) == len(rows)
    for line, row in zip(table, rows, strict=True):
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[0] == row["scene"] and cells[3] == row["direction_step"]
        counts = [row[k] for k in ("single", "plain", "retrack", "joint", "straightest")]
        assert cells[4:] == [f"{c}/2" for c in counts]
        assert all(0 <= int(c) <= 2 for c in counts)


def test_quick_without_out_uses_a_temporary_folder(crossing, monkeypatch):
    results = sys.modules["_expkit"].RESULTS_DIR
    before = results_snapshot(results)
    monkeypatch.setattr(crossing, "QUICK_SCENES", ("overtake",))
    monkeypatch.setattr(crossing, "GS", (1.0,))
    md = crossing.main(["--quick", "--no-progress", "--seeds", "1"])
    try:
        assert results not in md.parents and md.is_file()
        assert results_snapshot(results) == before
        assert len(read_rows(md.with_suffix(".csv"))) == len(crossing.STEPS)
    finally:
        shutil.rmtree(md.parent)

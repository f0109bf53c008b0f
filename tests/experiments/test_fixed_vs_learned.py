"""Smoke test of experiments/fixed_vs_learned.py (--quick sizes)."""

import csv
import pathlib
import sys
import warnings

import pytest
import torch

pytest.importorskip("lightning")

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "experiments"))  # _expkit
from _helpers import load_script


def test_quick_run_writes_table(tmp_path, capsys):
    script = load_script("fixed_vs_learned.py")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        text = script.main(["--quick", "--out", str(tmp_path)])
    assert text in capsys.readouterr().out
    with open(tmp_path / "fixed-vs-learned.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    methods = [(r["detector"], r["method"].split(" (")[0]) for r in rows]
    assert methods == [
        ("dpa", "paper g=0"),
        ("dpa", "paper g=1, b=0.8"),
        ("dpa", "learned"),
        ("hoc", "fixed [LA98]"),
        ("hoc", "learned from fixed"),
        ("hoc", "learned from random"),
    ]
    for r in rows[:3]:
        for key in ("pd@0.01", "pd@0.001", "auroc", "hit1"):
            assert 0.0 <= float(r[key]) <= 1.0
    for r in rows[3:]:
        assert 0.0 <= float(r["clutter_rejection"]) <= 1.0
        assert int(r["target_points_lost"]) >= 0


def test_auroc_against_pairs():
    script = load_script("fixed_vs_learned.py")
    pos = torch.tensor([0.5, 2.0, 1.0])
    neg = torch.tensor([0.0, 1.0, 3.0, 1.0])
    pairs = [(1.0 if p > n else 0.5 if p == n else 0.0) for p in pos for n in neg]
    assert script._auroc(pos, neg) == pytest.approx(sum(pairs) / len(pairs))

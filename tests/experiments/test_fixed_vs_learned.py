"""Tests of experiments/fixed_vs_learned.py: helpers against loops, and a --quick smoke run."""

import math
import pathlib
import sys
import warnings

import pytest
import torch

pytest.importorskip("lightning")

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "experiments"))  # _expkit
from _helpers import load_script, read_rows

from hocnet.hoc.layers import MHOCImage


@pytest.fixture(scope="module")
def script():
    return load_script("fixed_vs_learned.py")


@pytest.fixture(scope="module")
def quick_out(script, tmp_path_factory):
    out = tmp_path_factory.mktemp("fvl")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        md = script.run(quick=True, out_dir=out, show=False, cache=out / "cache.pt")
    return md, out


def test_quick_run_writes_tables_and_plots(script, quick_out):
    md, out = quick_out
    text = md.read_text()
    assert "quick (smoke)" in text
    for suffix in ("-roc.png", "-pd-snr.png", "-kernels.png", ".csv", "-hoc.csv", "-summary.csv"):
        assert (out / f"{script.NAME}{suffix}").stat().st_size > 0
    rows = read_rows(out / f"{script.NAME}.csv")
    methods = {r["method"] for r in rows}
    assert {"paper g=0", "paper g=1, b=0.8", "grid best (in-domain)", "learned (in-domain)"} <= (
        methods
    )
    assert {r["setting"] for r in rows} == set(script.SETTINGS)
    for r in rows:
        for key in ("pd@0.001", "pd@0.0001", "auc", "track_success"):
            assert 0.0 <= float(r[key]) <= 1.0
        assert float(r["snr_db"]) in script.SNRS
    hoc = read_rows(out / f"{script.NAME}-hoc.csv")
    expected = {"fixed [LA98]", "learned from fixed", "learned from random"}
    assert {r["method"] for r in hoc} >= expected
    for r in hoc:
        assert 0.0 <= float(r["rejection"]) <= 1.0
        assert 0 <= int(r["lost"]) <= int(r["target_points"])


def test_render_from_cache_reproduces_the_report(script, quick_out, tmp_path):
    md, out = quick_out
    again = script.main(["--render-from", str(out / "cache.pt"), "--out", str(tmp_path)])
    assert again.read_text() == md.read_text()


def test_auroc_against_pairs(script):
    pos = torch.tensor([0.5, 2.0, 1.0])
    neg = torch.tensor([0.0, 1.0, 3.0, 1.0])
    pairs = [(1.0 if p > n else 0.5 if p == n else 0.0) for p in pos for n in neg]
    assert script._auroc(pos, neg) == pytest.approx(sum(pairs) / len(pairs))


@pytest.mark.parametrize("pfa", [1e-3, 0.01, 0.1, 0.5])
def test_threshold_at_keeps_the_false_alarm_rate(script, pfa):
    neg = torch.randn(5000, generator=torch.Generator().manual_seed(1))
    t = script.threshold_at(neg, pfa)
    exceed = sum(1 for x in neg.tolist() if x > t)
    assert exceed <= pfa * neg.numel()
    assert exceed == math.floor(pfa * neg.numel())  # distinct values: exactly floor(pfa * n)


def test_snr_at_interpolates(script):
    snrs = (2.0, 4.0, 6.0)
    assert script.snr_at([0.5, 0.8, 1.0], snrs) == pytest.approx(5.0)
    assert script.snr_at([0.95, 1.0, 1.0], snrs) == 2.0
    assert math.isinf(script.snr_at([0.1, 0.2, 0.3], snrs))


def test_near_max_against_loop(script):
    gen = torch.Generator().manual_seed(0)
    last = torch.randn(3, 6, 7, generator=gen)
    pixels = torch.tensor([[0], [20], [41]])
    got = script._near_max(last, pixels)
    for b in range(3):
        y, x = divmod(int(pixels[b, 0]), 7)
        ref = max(
            float(last[b, yy, xx])
            for yy in range(max(0, y - 1), min(6, y + 2))
            for xx in range(max(0, x - 1), min(7, x + 2))
        )
        assert float(got[b, 0]) == ref


@pytest.mark.parametrize("init", ["fixed", "random"])
def test_mhoc_at_the_layer_threshold_is_the_eval_network(script, init):
    cube = (torch.rand(2, 6, 12, 12, generator=torch.Generator().manual_seed(3)) < 0.1).float()
    learnable = init == "random"
    model = MHOCImage(order=1, v=1, learnable=learnable, init=init, seed=0).eval()
    theta = model.forward_net.layers[0].threshold
    assert theta == (script.LEARNED_THRESHOLD if learnable else 0.0)
    with torch.no_grad():
        assert torch.equal(script.mhoc_at(model, cube, theta), model(cube))
    # a larger theta keeps a subset of the points
    assert bool((script.mhoc_at(model, cube, 0.5) <= script.mhoc_at(model, cube, 0.0)).all())
    if not learnable:  # integer counts: eq. (3) and c > 0.5 agree
        assert torch.equal(script.mhoc_at(model, cube, 0.5), script.mhoc_at(model, cube, 0.0))


def _hoc_row(method, rule, theta, sp, d, lost, kept):
    return {
        "method": method,
        "rule": rule,
        "theta": theta,
        "speed": sp,
        "density": d,
        "lost": lost,
        "kept_clutter": kept,
        "rejection": 1.0 - kept / 100,
        "target_points": 10,
    }


def test_hoc_duplicates_and_verdict_at_the_deployed_limiter(script):
    rows = []
    for sp in ("slow", "fast"):
        for d in script.DENSITIES:
            rows += [
                _hoc_row("fixed [LA98]", script.EQ3, 0.0, sp, d, 0, 20),
                _hoc_row("fixed [LA98]", script.DEPLOYED, 0.5, sp, d, 0, 20),
                _hoc_row("fixed [LA98]", script.STAR, 1.5, sp, d, 3, 5),
                _hoc_row("learned", script.EQ3, 0.0, sp, d, 0, 30),
                _hoc_row("learned", script.DEPLOYED, 0.5, sp, d, 0, 10),
                _hoc_row("learned", script.STAR, 0.5, sp, d, 0, 10),
                _hoc_row("same", script.EQ3, 0.0, sp, d, 0, 10),
                _hoc_row("same", script.DEPLOYED, 0.5, sp, d, 0, 10),
            ]
    same = script.hoc_duplicates(rows)
    assert same == {
        ("fixed [LA98]", script.DEPLOYED): script.EQ3,
        ("learned", script.STAR): script.DEPLOYED,
    }
    assert script.hoc_keys(rows) == [
        ("fixed [LA98]", script.EQ3),
        ("fixed [LA98]", script.STAR),
        ("learned", script.EQ3),
        ("learned", script.DEPLOYED),
        ("same", script.EQ3),
        ("same", script.DEPLOYED),  # a learned network's deployed row is always its own
    ]
    lines = [x for x in script.hoc_verdict(rows) if x.startswith("- HOC slow targets, learned")]
    assert [script.DEPLOYED in x for x in lines] == [True, False]  # deployed first, no theta*
    assert script.EQ3 in lines[1].split(" (theta")[0]
    # learned keeps 10 clutter points of 100 at 0.5 (30 at 0), the fixed network 20
    assert "0.8 %: +10.00 pts, lost 0 (fixed 0)" in lines[0] and "is met." in lines[0]
    assert "0.8 %: -10.00 pts" in lines[1]
    head = script.hoc_headline(rows)
    assert len(head) == 4 and "deployed limiter" in head[0]
    assert "fixed [LA98]: 0 / 40 lost, mean rejection 80.00 %" in head[0]
    assert "learned: 0 / 40 lost, mean rejection 90.00 %" in head[0]
    assert "learned: 0 / 40 lost, mean rejection 70.00 %" in head[1]


def test_npa_scenes_are_paired_across_snr(script):
    cfg = script.QUICK
    low = script.stack(script.ir_module("npa-slow", 2.0, cfg, 0, n_test=2), "test")
    high = script.stack(script.ir_module("npa-slow", 15.0, cfg, 0, n_test=2), "test")
    clear = script.stack(script.ir_module("clear-slow", 2.0, cfg, 0, n_test=2), "test")
    assert torch.equal(low["target_free"], high["target_free"])
    assert torch.equal(low["positions"], high["positions"])
    assert not torch.equal(low["frames"], high["frames"])
    assert not torch.equal(low["target_free"], clear["target_free"])  # the clouds are there


def test_merge_joins_the_two_parts(script):
    dpa = {"quick": True, "rows": [1], "seconds": {"dpa": 2.0}}
    hoc = {"quick": True, "hoc_rows": [2], "seconds": {"hoc": 3.0}}
    res = script.merge(dpa, hoc)
    assert res["seconds"] == {"dpa": 2.0, "hoc": 3.0} and res["merged"]
    assert (res["quick"], res["rows"], res["hoc_rows"]) == (True, [1], [2])

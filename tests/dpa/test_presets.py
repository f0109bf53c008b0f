import pytest
import torch

from hocnet.data.background import estimate_shifts, remove_background
from hocnet.data.whitening import anti_mean
from hocnet.dpa import accumulate, effective_memory, equalize_gain, probability_matrices
from hocnet.dpa.presets import PAPER, PRESETS, RECOMMENDED, preprocess, run_preset, weights_and_b


def test_paper_is_the_library_defaults():
    # the paper's DPA: the defaults of probability_matrices / effective_memory / accumulate
    assert (PAPER.window, PAPER.v_max, PAPER.jitter, PAPER.p, PAPER.penalty_step) == (
        7,
        2.0,
        0.5,
        0.5,
        3.0,
    )
    assert (PAPER.g, PAPER.b, PAPER.memory, PAPER.memory_direction) == (0.0, "emc", 0.8, 9)
    assert PAPER.direction_step == "paper" and not PAPER.equal_gain
    assert not PAPER.register and PAPER.background == "none" and PAPER.whitening == "mean"
    weights, b = weights_and_b(PAPER)
    assert torch.equal(weights, probability_matrices())
    assert b == pytest.approx(float(effective_memory(probability_matrices(), 0.0)))
    assert b == pytest.approx(4.67, abs=0.01)


def test_recommended_fields():
    assert (RECOMMENDED.window, RECOMMENDED.v_max, RECOMMENDED.g) == (5, 1.0, 0.0)
    assert RECOMMENDED.equal_gain and RECOMMENDED.memory == 0.4
    assert RECOMMENDED.register and RECOMMENDED.background == "median"
    assert RECOMMENDED.background_window == 10
    assert PRESETS == {"paper": PAPER, "recommended": RECOMMENDED}


def test_run_preset_matches_the_building_blocks():
    g = torch.Generator().manual_seed(0)
    frames = torch.rand(8, 20, 24, generator=g) * 50
    frames[:, 7, 9] += 40
    x = frames.clone()
    offsets = estimate_shifts(x).cumsum(dim=0)
    white = anti_mean(remove_background(x, "median", 10, offsets=offsets))
    weights = equalize_gain(probability_matrices(window=5, v_max=1.0), 0.0)
    b = float(effective_memory(weights, 0.0, 0.4))
    expected = accumulate(white, weights, b, 0.0)
    got = run_preset(frames, RECOMMENDED)
    torch.testing.assert_close(got.asf, expected.asf)
    got_white, shifts = preprocess(frames, RECOMMENDED)
    torch.testing.assert_close(got_white, white)
    assert shifts.shape == (8, 2)
    paper = run_preset(frames, PAPER)
    w = probability_matrices()
    torch.testing.assert_close(
        paper.asf, accumulate(anti_mean(frames), w, float(effective_memory(w, 0.0)), 0.0).asf
    )


def test_run_preset_is_causal():
    frames = torch.rand(12, 20, 20, generator=torch.Generator().manual_seed(1)) * 10
    full = run_preset(frames, RECOMMENDED).asf
    part = run_preset(frames[:7], RECOMMENDED).asf
    torch.testing.assert_close(full[:7], part)


def test_fixed_b_and_replace():
    weights, b = weights_and_b(PAPER.replace(b=2.0))
    assert b == 2.0 and weights.shape == (9, 7, 7)

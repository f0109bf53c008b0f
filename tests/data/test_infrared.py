import math
from dataclasses import replace

import pytest
import torch

from hocnet.data.infrared import (
    CLOUD_PRESETS,
    NPA_CLOUDS,
    CloudSpec,
    IRSequence,
    IRTarget,
    markov_field,
    na23a_like,
    npa_like,
    simulate_ir,
)


def _centroid(img: torch.Tensor) -> torch.Tensor:
    """Intensity-weighted (x, y) centroid of the last two axes, float64."""
    img = img.double()
    h, w = img.shape[-2:]
    total = img.sum(dim=(-2, -1))
    cx = (img * torch.arange(w, dtype=torch.float64)).sum(dim=(-2, -1)) / total
    cy = (img * torch.arange(h, dtype=torch.float64)[:, None]).sum(dim=(-2, -1)) / total
    return torch.stack((cx, cy), dim=-1)


def _assert_same(a: IRSequence, b: IRSequence) -> None:
    for name in ("frames", "positions", "target_free", "clouds", "jitter"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


class TestIRTarget:
    def test_smoke(self):
        target = IRTarget(3.0, 4.0, 0.5, -0.5, snr_db=6.0)
        assert target.sigma == (0.7, 0.7)
        assert target.trajectory(4).shape == (4, 2)
        assert target.trajectory(4).dtype == torch.float64

    def test_scalar_sigma(self):
        assert IRTarget(0, 0, 0, 0, 0.0, sigma=1.2).sigma == (1.2, 1.2)

    def test_amplitude_is_peak_snr_against_noise(self):
        target = IRTarget(0, 0, 0, 0, snr_db=10.0)
        assert target.amplitude(2.0) == pytest.approx(2.0 * 10**0.5)
        assert IRTarget(0, 0, 0, 0, snr_db=0.0).amplitude(3.0) == pytest.approx(3.0)

    def test_constant_velocity(self):
        traj = IRTarget(1.5, 2.5, 0.3, -0.2, 6.0).trajectory(10)
        steps = traj.diff(dim=0)
        torch.testing.assert_close(steps, torch.tensor([[0.3, -0.2]] * 9, dtype=torch.float64))
        torch.testing.assert_close(traj[0], torch.tensor([1.5, 2.5], dtype=torch.float64))

    def test_gentle_turn(self):
        rate = 0.1
        traj = IRTarget(0.0, 0.0, 1.0, 0.0, 6.0, turn_rate=rate).trajectory(12)
        steps = traj.diff(dim=0)
        speed = steps.norm(dim=1)
        torch.testing.assert_close(speed, torch.ones(11, dtype=torch.float64))
        bearing = torch.atan2(steps[:, 1], steps[:, 0])
        torch.testing.assert_close(bearing, rate * torch.arange(11, dtype=torch.float64))

    def test_sharp_turn(self):
        target = IRTarget(5.0, 5.0, 1.0, 0.0, 6.0, turn_at=3, new_velocity=(0.0, -1.5))
        steps = target.trajectory(6).diff(dim=0)
        expected = [[1.0, 0.0]] * 3 + [[0.0, -1.5]] * 2
        torch.testing.assert_close(steps, torch.tensor(expected, dtype=torch.float64))

    @pytest.mark.parametrize(
        ("kwargs", "name", "error"),
        [
            ({"vx": 2.0, "vy": 1.0}, "vx, vy", ValueError),
            ({"vx": float("nan")}, "vx", ValueError),
            ({"sigma": 0.0}, "sigma", ValueError),
            ({"sigma": (1.0, 2.0, 3.0)}, "sigma", TypeError),
            ({"snr_db": "high"}, "snr_db", TypeError),
            ({"turn_at": 2}, "new_velocity", ValueError),
            ({"new_velocity": (1.0, 0.0)}, "turn_at", ValueError),
            ({"turn_at": 0, "new_velocity": (1.0, 0.0)}, "turn_at", ValueError),
            ({"turn_at": 2, "new_velocity": (3.0, 0.0)}, "new_velocity", ValueError),
        ],
    )
    def test_exceptions(self, kwargs, name, error):
        args = {"x0": 0.0, "y0": 0.0, "vx": 0.5, "vy": 0.0, "snr_db": 6.0} | kwargs
        with pytest.raises(error, match=f"`{name}`"):
            IRTarget(**args)


class TestCloudSpec:
    def test_presets(self):
        assert CLOUD_PRESETS["clear"] is None
        wispy, bright = CLOUD_PRESETS["wispy"], CLOUD_PRESETS["bright"]
        assert wispy.amplitude < bright.amplitude
        assert wispy.coverage < bright.coverage
        assert bright.edge < wispy.edge  # bright clouds have the sharper edges

    def test_threshold(self):
        assert CloudSpec(1.0, 0.5, 0.9, 1.0).threshold == pytest.approx(0.0, abs=1e-12)
        assert CloudSpec(1.0, 0.1587, 0.9, 1.0).threshold == pytest.approx(1.0, abs=1e-3)

    @pytest.mark.parametrize(
        ("kwargs", "name"),
        [
            ({"amplitude": -1.0}, "amplitude"),
            ({"coverage": 0.0}, "coverage"),
            ({"coverage": 1.0}, "coverage"),
            ({"rho": 1.0}, "rho"),
            ({"edge": 0.0}, "edge"),
            ({"drift": (0.1, float("inf"))}, "drift"),
            ({"anchors": ((1.0, 2.0, -3.0),)}, r"anchors\[0\]"),
            ({"holes": ((1.0, 2.0, 0.0),)}, r"holes\[0\]"),
        ],
    )
    def test_exceptions(self, kwargs, name):
        args = {"amplitude": 1.0, "coverage": 0.3, "rho": 0.9, "edge": 1.0} | kwargs
        with pytest.raises(ValueError, match=f"`{name}`"):
            CloudSpec(**args)

    def test_holes_clear_the_sky(self):
        # bright, wide clouds with a clear disc of radius 8 at (30, 20): nothing inside it in any
        # frame (the disc drifts with the clouds: 0.1 px/frame here), clouds elsewhere
        spec = CloudSpec(20.0, 0.7, 0.95, 0.25, drift=(0.1, 0.0), holes=((30.0, 20.0, 8.0),))
        seq = simulate_ir((5, 40, 60), clouds=spec, jitter=0.0, batch=3, seed=1)
        ys = torch.arange(40.0)[:, None]
        xs = torch.arange(60.0)[None, :]
        for t in range(5):
            inside = (xs - 30.0 - 0.1 * t) ** 2 + (ys - 20.0) ** 2 < 7.0**2
            assert float(seq.clouds[:, t][:, inside].abs().max()) == 0.0
        assert float(seq.clouds.amax()) == pytest.approx(20.0)
        # without the hole the same seed has clouds in that disc
        plain = simulate_ir(
            (5, 40, 60), clouds=replace(spec, holes=()), jitter=0.0, batch=3, seed=1
        )
        inside = (xs - 30.0) ** 2 + (ys - 20.0) ** 2 < 7.0**2
        assert float(plain.clouds[:, 0][:, inside].max()) > 0.0
        assert torch.allclose(
            plain.target_free - plain.clouds, seq.target_free - seq.clouds, atol=1e-4
        )


class TestMarkovField:
    def test_shapes(self):
        assert markov_field((5, 7), 0.5, seed=0).shape == (5, 7)
        assert markov_field((5, 7), 0.5, batch=3, seed=0).shape == (3, 5, 7)
        assert markov_field((5, 7), 0.5, seed=0).dtype == torch.float32

    def test_seeding(self):
        assert torch.equal(markov_field((9, 9), 0.8, seed=4), markov_field((9, 9), 0.8, seed=4))
        assert not torch.equal(markov_field((9, 9), 0.8, seed=4), markov_field((9, 9), 0.8, seed=5))

    @pytest.mark.parametrize("rho", [0.0, 0.5, 0.9, 0.96])
    def test_correlation(self, rho):
        field = markov_field((64, 64), rho, batch=64, seed=1).double()
        var = field.pow(2).mean()
        assert var == pytest.approx(1.0, abs=0.05 + 0.3 * rho**8)
        lag_x = (field[:, :, 1:] * field[:, :, :-1]).mean() / var
        lag_y = (field[:, 1:, :] * field[:, :-1, :]).mean() / var
        lag_2 = (field[:, :, 2:] * field[:, :, :-2]).mean() / var
        assert lag_x == pytest.approx(rho, abs=0.03)
        assert lag_y == pytest.approx(rho, abs=0.03)
        assert lag_2 == pytest.approx(rho * rho, abs=0.04)

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`rho`"):
            markov_field((4, 4), 1.0)
        with pytest.raises(ValueError, match="`shape`"):
            markov_field((0, 4), 0.5)
        with pytest.raises(TypeError, match="`shape`"):
            markov_field((4, 4, 4), 0.5)
        with pytest.raises(ValueError, match="`batch`"):
            markov_field((4, 4), 0.5, batch=0)


class TestSimulateIR:
    def test_fluctuation(self):
        # a point target (tiny PSF) on a pixel centre: its pixel holds noise + A min(1, m E)
        target = IRTarget(5.0, 6.0, 0.0, 0.0, snr_db=20.0, sigma=0.05)
        args = ((400, 12, 12), [target])
        kw = {"clouds": "clear", "jitter": 0.0, "batch": 2, "seed": 4}
        flat = simulate_ir(*args, **kw)
        seq = simulate_ir(*args, fluctuation=0.4, **kw)
        # drawn last: the scene without the target is the same, the positions too
        assert torch.equal(seq.target_free, flat.target_free)
        assert torch.equal(seq.positions, flat.positions)
        peak = (seq.frames - seq.target_free)[:, :, 6, 5] / target.amplitude()  # (B, T)
        assert float(peak.max()) == pytest.approx(1.0)  # clipped at the (maximal) peak
        assert float(peak.min()) >= 0.0
        # E[min(1, m E)] = m (1 - exp(-1 / m)) for E ~ Exp(1)
        assert float(peak.mean()) == pytest.approx(0.4 * (1 - math.exp(-2.5)), abs=0.03)
        assert float((peak == 1.0).double().mean()) == pytest.approx(math.exp(-2.5), abs=0.02)
        # the two sequences of the batch fluctuate independently
        assert not torch.equal(peak[0], peak[1])
        for bad in (0.0, 1.5, -1.0):
            with pytest.raises(ValueError, match="`fluctuation`"):
                simulate_ir((2, 8, 8), [target], fluctuation=bad)

    def test_smoke(self):
        seq = simulate_ir((4, 12, 10), [IRTarget(3.0, 4.0, 0.5, 0.5, 10.0)], seed=0)
        assert isinstance(seq, IRSequence)
        assert len(seq.targets) == 1
        assert torch.isfinite(seq.frames).all()

    @pytest.mark.parametrize("batch", [None, 1, 3])
    @pytest.mark.parametrize("clouds", ["clear", "wispy", "bright"])
    def test_shapes(self, batch, clouds):
        targets = [IRTarget(3.0, 4.0, 0.5, 0.5, 10.0), IRTarget(8.0, 2.0, 0.0, 0.5, 10.0)]
        seq = simulate_ir((5, 12, 10), targets, clouds=clouds, batch=batch, seed=0)
        lead = () if batch is None else (batch,)
        for name in ("frames", "target_free", "clouds"):
            tensor = getattr(seq, name)
            assert tensor.shape == (*lead, 5, 12, 10), name
            assert tensor.dtype == torch.float32
        assert seq.positions.shape == (*lead, 2, 5, 2)
        assert seq.positions.dtype == torch.float64
        assert seq.jitter.shape == (*lead, 5, 2)

    def test_no_targets(self):
        seq = simulate_ir((3, 8, 8), [], batch=2, seed=0)
        assert seq.positions.shape == (2, 0, 3, 2)
        assert torch.equal(seq.frames, seq.target_free)

    def test_single_pixel_and_single_frame(self):
        seq = simulate_ir((1, 1, 1), [IRTarget(0, 0, 0, 0, 0.0)], clouds="bright", seed=0)
        assert seq.frames.shape == (1, 1, 1)

    def test_seeding(self):
        targets = [IRTarget(10.2, 20.7, 0.3, 0.1, 6.0)]
        a = simulate_ir((6, 32, 32), targets, clouds="bright", batch=2, seed=11)
        b = simulate_ir((6, 32, 32), targets, clouds="bright", batch=2, seed=11)
        _assert_same(a, b)
        c = simulate_ir((6, 32, 32), targets, clouds="bright", batch=2, seed=12)
        assert not torch.equal(a.frames, c.frames)
        g = torch.Generator().manual_seed(11)
        d = simulate_ir((6, 32, 32), targets, clouds="bright", batch=2, generator=g)
        _assert_same(a, d)

    def test_global_rng_untouched(self):
        state = torch.random.get_rng_state()
        simulate_ir((3, 16, 16), [IRTarget(5, 5, 0.5, 0, 6.0)], clouds="wispy", seed=None)
        assert torch.equal(state, torch.random.get_rng_state())

    def test_unseeded_runs_differ(self):
        a = simulate_ir((2, 8, 8), clouds="clear")
        b = simulate_ir((2, 8, 8), clouds="clear")
        assert not torch.equal(a.frames, b.frames)

    def test_components_add_up(self):
        seq = simulate_ir(
            (5, 24, 24), [IRTarget(8.3, 9.6, 0.4, 0.2, 20.0)], clouds="bright", batch=2, seed=3
        )
        noise = seq.target_free - seq.clouds
        assert noise.std().item() == pytest.approx(1.0, abs=0.05)
        signal = seq.frames - seq.target_free
        assert signal.min() > -1e-4  # target signal is non-negative
        # The same seed gives the same noise and jitter whatever the clutter.
        clear = simulate_ir(
            (5, 24, 24), [IRTarget(8.3, 9.6, 0.4, 0.2, 20.0)], clouds="clear", batch=2, seed=3
        )
        torch.testing.assert_close(clear.target_free, noise, rtol=0, atol=1e-4)
        assert torch.equal(clear.jitter, seq.jitter)
        assert torch.equal(clear.clouds, torch.zeros_like(clear.clouds))

    @pytest.mark.parametrize("seed", range(4))
    def test_peak_at_truth(self, seed):
        gen = torch.Generator().manual_seed(100 + seed)
        x0, y0 = (8 + 16 * torch.rand(2, generator=gen, dtype=torch.float64)).tolist()
        target = IRTarget(x0, y0, 0.37, -0.23, snr_db=40.0, sigma=(0.7, 0.9))
        seq = simulate_ir((10, 32, 32), [target], clouds="bright", jitter=0.5, seed=seed)
        signal = seq.frames - seq.target_free  # noiseless high-SNR frames
        for t in range(10):
            flat = int(signal[t].argmax())
            row, col = divmod(flat, 32)
            x, y = seq.positions[0, t].tolist()
            assert abs(col - x) <= 0.5 + 1e-6 and abs(row - y) <= 0.5 + 1e-6
        # Sub-pixel: the centroid of the rendered PSF is the true position.
        torch.testing.assert_close(_centroid(signal), seq.positions[0], rtol=0, atol=1e-3)

    def test_peak_in_noisy_frames(self):
        target = IRTarget(12.0, 20.0, 0.5, 0.25, snr_db=30.0)
        seq = simulate_ir((8, 32, 32), [target], clouds="clear", jitter=0.0, seed=5)
        for t in range(8):
            row, col = divmod(int(seq.frames[t].argmax()), 32)
            x, y = seq.positions[0, t].tolist()
            assert abs(col - x) <= 1.0 and abs(row - y) <= 1.0

    def test_snr_definition(self):
        target = IRTarget(10.0, 7.0, 0.0, 0.0, snr_db=10.0)
        seq = simulate_ir(
            (3, 16, 20), [target], clouds="clear", noise_sigma=2.0, jitter=0.0, batch=4, seed=0
        )
        signal = seq.frames - seq.target_free
        amplitude = 2.0 * 10 ** (10.0 / 20.0)
        torch.testing.assert_close(
            signal[..., 7, 10], torch.full((4, 3), amplitude), rtol=1e-5, atol=1e-4
        )
        assert signal.amax().item() == pytest.approx(amplitude, rel=1e-5)
        # PSF at one pixel off in x: exp(-1 / (2 * 0.7^2)).
        torch.testing.assert_close(
            signal[..., 7, 11],
            torch.full((4, 3), amplitude * math.exp(-1 / 0.98)),
            rtol=1e-5,
            atol=1e-4,
        )
        assert seq.target_free.std().item() == pytest.approx(2.0, rel=0.03)

    def test_positions_follow_trajectory(self):
        targets = [
            IRTarget(5.0, 5.0, 1.2, 0.4, 10.0, turn_rate=0.05),
            IRTarget(20.0, 6.0, 0.0, 1.0, 10.0, turn_at=4, new_velocity=(-1.0, 0.0)),
        ]
        seq = simulate_ir((9, 32, 32), targets, jitter=0.0, batch=2, seed=0)
        for k, target in enumerate(targets):
            assert torch.equal(seq.positions[0, k], target.trajectory(9))
            assert torch.equal(seq.positions[1, k], target.trajectory(9))
        assert torch.equal(seq.jitter, torch.zeros(2, 9, 2, dtype=torch.float64))

    def test_jitter_shifts_targets_and_is_bounded(self):
        target = IRTarget(16.0, 16.0, 0.2, 0.1, 30.0)
        seq = simulate_ir((25, 32, 32), [target], clouds="clear", jitter=0.7, batch=8, seed=2)
        torch.testing.assert_close(
            seq.positions[:, 0] - target.trajectory(25), seq.jitter, rtol=0, atol=1e-12
        )
        assert seq.jitter.abs().max() <= 0.7
        assert seq.jitter.abs().max() > 0.6  # U[-a, a]: the bound is nearly reached
        assert seq.jitter.mean().abs() < 0.1
        signal = seq.frames - seq.target_free
        torch.testing.assert_close(_centroid(signal), seq.positions[:, 0], rtol=0, atol=1e-3)

    @pytest.mark.parametrize("seed", range(3))
    def test_jitter_and_drift_shift_clouds(self, seed):
        # One smooth cloud disc held at a known place by an anchor (and a sky too clear for
        # other clouds): its centroid must move with the drift and the jitter, like targets.
        spec = CloudSpec(
            amplitude=10.0, coverage=1e-5, rho=0.95, edge=2.0, drift=(0.3, -0.2),
            anchors=((20.0, 24.0, 4.0),),
        )  # fmt: skip
        seq = simulate_ir((12, 48, 48), [], clouds=spec, jitter=0.8, batch=3, seed=seed)
        centroid = _centroid(seq.clouds)  # (B, T, 2)
        steps = torch.arange(12, dtype=torch.float64)[:, None]
        drift = torch.tensor([0.3, -0.2], dtype=torch.float64)
        torch.testing.assert_close(
            centroid, steps * drift + seq.jitter + torch.tensor([20.0, 24.0]).double(),
            rtol=0, atol=0.02,
        )  # fmt: skip

    def test_anchor_guarantees_cloud(self):
        spec = CloudSpec(amplitude=5.0, coverage=0.01, rho=0.9, edge=0.5, anchors=((8, 9, 3),))
        seq = simulate_ir((3, 20, 20), [], clouds=spec, jitter=0.0, batch=16, seed=0)
        torch.testing.assert_close(
            seq.clouds[..., 9, 5:12], torch.full((16, 3, 7), 5.0), rtol=0, atol=1e-5
        )

    def test_jitter_zero_still_same_noise(self):
        a = simulate_ir((4, 16, 16), clouds="clear", jitter=0.0, seed=9)
        b = simulate_ir((4, 16, 16), clouds="clear", jitter=1.0, seed=9)
        assert torch.equal(a.frames, b.frames)  # clear sky: jitter moves nothing but targets

    def test_cloud_presets_ordered(self):
        level = {}
        for name in ("clear", "wispy", "bright"):
            seq = simulate_ir((5, 48, 48), clouds=name, batch=8, seed=1)
            level[name] = seq.clouds.abs().mean().item()
            assert seq.clouds.min() >= 0
        assert level["clear"] == 0.0
        assert level["clear"] < level["wispy"] < level["bright"]

    @pytest.mark.parametrize("name", ["wispy", "bright"])
    def test_cloud_coverage_and_plateau(self, name):
        spec = CLOUD_PRESETS[name]
        seq = simulate_ir((2, 64, 64), clouds=name, noise_sigma=2.0, batch=64, seed=3)
        covered = (seq.clouds > 0).double().mean().item()
        assert covered == pytest.approx(spec.coverage, abs=0.06)
        assert seq.clouds.max().item() == pytest.approx(2.0 * spec.amplitude, rel=1e-5)

    def test_bright_clouds_have_sharp_edges(self):
        seq = simulate_ir((1, 64, 64), clouds="bright", batch=16, seed=0)
        step = (seq.clouds[..., 1:] - seq.clouds[..., :-1]).abs()
        # A sizeable share of the cloud boundary jumps by more than a third of the plateau
        # from one pixel to the next.
        assert (step > 10.0).double().mean() > 0.01

    @pytest.mark.parametrize(
        ("kwargs", "name", "error"),
        [
            ({"shape": (4, 8)}, "shape", TypeError),
            ({"shape": (0, 8, 8)}, "shape", ValueError),
            ({"targets": IRTarget(0, 0, 0, 0, 0.0)}, "targets", TypeError),
            ({"targets": [(1, 2)]}, r"targets\[0\]", TypeError),
            (
                {"targets": [IRTarget(0, 0, 0, 0, 0.0, turn_at=4, new_velocity=(0, 1))]},
                r"targets\[0\]\.turn_at",
                ValueError,
            ),
            ({"clouds": "stormy"}, "clouds", ValueError),
            ({"noise_sigma": 0.0}, "noise_sigma", ValueError),
            ({"jitter": -0.1}, "jitter", ValueError),
            ({"batch": 0}, "batch", ValueError),
            ({"seed": -1}, "seed", ValueError),
            ({"generator": 5}, "generator", TypeError),
            ({"seed": 1, "generator": torch.Generator()}, "generator", ValueError),
        ],
    )
    def test_exceptions(self, kwargs, name, error):
        args = {"shape": (4, 8, 8)} | kwargs
        with pytest.raises(error, match=f"`{name}`"):
            simulate_ir(**args)


class TestNa23aLike:
    def test_scene(self):
        # [NR08] section 3: one target in clear sky, right to left at ~0.3 px/frame
        seq = na23a_like(batch=2, seed=0)
        assert seq.frames.shape == (2, 25, 90, 90)
        assert seq.positions.shape == (2, 1, 25, 2)
        step = seq.targets[0].trajectory(25).diff(dim=0)
        torch.testing.assert_close(step, torch.tensor([[-0.3, 0.0]] * 24, dtype=torch.float64))
        assert float(seq.clouds.abs().max()) == 0.0  # clear sky
        assert seq.targets[0].amplitude() == pytest.approx(60.0)  # Table 2: peak ~60
        torch.testing.assert_close(
            seq.targets[0].trajectory(1)[0], torch.tensor([45.0, 45.0], dtype=torch.float64)
        )
        inside = (seq.positions >= 0) & (seq.positions <= 89)
        assert inside.all()

    def test_bright_cloud_variant(self):
        # Table 1 of [NR08] says "bright clouds": kept as an option
        seq = na23a_like(shape=(6, 40, 40), clouds="bright", seed=1)
        bright = CLOUD_PRESETS["bright"]
        assert seq.clouds.max().item() == pytest.approx(bright.amplitude, rel=1e-5)

    def test_seeding_and_options(self):
        a = na23a_like(shape=(10, 32, 40), snr_db=3.0, seed=4)
        _assert_same(a, na23a_like(shape=(10, 32, 40), snr_db=3.0, seed=4))
        assert a.frames.shape == (10, 32, 40)
        assert a.targets[0].snr_db == 3.0
        assert not torch.equal(a.frames, na23a_like(shape=(10, 32, 40), snr_db=3.0, seed=5).frames)

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`speed`"):
            na23a_like(speed=3.0)
        with pytest.raises(TypeError, match="`shape`"):
            na23a_like(shape=(64, 64))
        with pytest.raises(ValueError, match="`clouds`"):
            na23a_like(clouds="dark")


class TestPresetFluctuation:
    def test_passed_through(self):
        for make in (na23a_like, npa_like):
            plain = make(seed=2, shape=(6, 40, 60))
            seq = make(seed=2, shape=(6, 40, 60), fluctuation=0.3)
            assert torch.equal(seq.target_free, plain.target_free)
            assert not torch.equal(seq.frames, plain.frames)
            # the target signal only shrinks (factor <= 1)
            signal, full = seq.frames - seq.target_free, plain.frames - plain.target_free
            assert bool((signal <= full + 1e-4).all())


class TestNpaLike:
    def test_scene(self):
        seq = npa_like(batch=4, seed=0)
        assert seq.frames.shape == (4, 25, 90, 120)
        assert seq.positions.shape == (4, 2, 25, 2)
        for target in seq.targets:  # bottom to top at ~0.2 px/frame
            step = target.trajectory(25).diff(dim=0)
            torch.testing.assert_close(step, torch.tensor([[0.0, -0.2]] * 24, dtype=torch.float64))
            assert target.amplitude() == pytest.approx(30.0)  # Table 2: peak ~30
        # the studied target 0 is under the full cloud plateau in every frame and sequence
        pos = seq.positions[:, 0].round().long()
        b = torch.arange(4)[:, None]
        t = torch.arange(25)[None, :]
        under = seq.clouds[b, t, pos[..., 1], pos[..., 0]]
        plateau = torch.full((4, 25), NPA_CLOUDS.amplitude)
        torch.testing.assert_close(under, plateau, rtol=0, atol=1e-4)
        # target 1 lies to the lower right, outside the 3 x 3 blocks of 30 x 30 around target 0
        gap = seq.positions[:, 1, 0] - seq.positions[:, 0, 0]
        assert bool((gap[:, 0] > 45).all()) and bool((gap[:, 1] > 0).all())
        # cloud edges around the studied target: the clouds are not a flat sheet
        assert float((seq.clouds == 0).double().mean()) > 0.2

    def test_seeding(self):
        _assert_same(npa_like(seed=3), npa_like(seed=3))

    def test_exceptions(self):
        with pytest.raises(ValueError, match="`speed`"):
            npa_like(speed=-0.1)
        with pytest.raises(ValueError, match="`noise_sigma`"):
            npa_like(noise_sigma=-1.0)
        with pytest.raises(TypeError, match="`shape`"):
            npa_like(shape=(40, 90))
        with pytest.raises(TypeError, match="`clouds`"):
            npa_like(clouds="wispy")


class TestPixelPSF:
    def test_one_lit_pixel_at_the_jittered_position(self):
        seq = na23a_like(shape=(6, 30, 40), seed=3, psf="pixel")
        gauss = na23a_like(shape=(6, 30, 40), seed=3)
        assert torch.equal(seq.target_free, gauss.target_free)
        assert torch.equal(seq.positions, gauss.positions)
        signal = seq.frames - seq.target_free
        for t in range(6):
            x, y = (math.floor(float(v) + 0.5) for v in seq.positions[0, t])
            expected = torch.zeros(30, 40)
            expected[y, x] = 60.0
            torch.testing.assert_close(signal[t], expected, atol=1e-4, rtol=0)

    def test_mixed_targets_and_validation(self):
        point = IRTarget(5.0, 5.0, 0.0, 0.0, 20.0, psf="pixel")
        blob = IRTarget(14.3, 5.0, 0.0, 0.0, 20.0)
        both = simulate_ir((1, 10, 20), [point, blob], clouds="clear", jitter=0.0, seed=0)
        alone = simulate_ir((1, 10, 20), [blob], clouds="clear", jitter=0.0, seed=0)
        diff = both.frames - alone.frames
        assert float(diff[0, 5, 5]) == pytest.approx(10.0, rel=1e-5)
        assert int((diff.abs() > 1e-4).sum()) == 1
        with pytest.raises(ValueError, match="`psf`"):
            IRTarget(0.0, 0.0, 0.0, 0.0, 20.0, psf="disc")

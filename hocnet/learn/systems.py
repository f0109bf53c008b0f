r"""Lightning systems that learn the hand-set weights of the DPA and the HOC network (our addition).

The models stay plain ``nn.Module``\\ s (:class:`hocnet.dpa.DPA`, :class:`hocnet.hoc.MHOCImage`);
the systems hold the training logic only, and :func:`load_model` turns a checkpoint back into the
plain module (``torch.load(..., weights_only=True)``).

* :class:`DPATuner` tunes ``b``, ``g``, ``p`` and the penalty step ``x`` of [NR08] (or ``b``,
  ``g`` and every entry of the 9 matrices, ``matrices="full"``) through the smooth
  (log-sum-exp) max, its temperature annealed geometrically towards the hard max.
* :class:`LearnedHOCSystem` learns the direction-masked and shift kernels of the MHOC network of
  [LA98] (forward OR backward stacks) with a relaxed hard limiter, scored per input point.
"""

from __future__ import annotations

import math
import os
import pickle
from collections.abc import Sequence
from typing import Any

import lightning as L
import torch
import torch.nn.functional as F
from torch import nn
from torchmetrics import CatMetric, MeanMetric, SumMetric
from torchmetrics.classification import BinaryAUROC

from hocnet._check import check_choice, check_int, check_number
from hocnet.dpa import DPA, b_limit
from hocnet.hoc.layers import MHOCImage
from hocnet.metrics import clutter_rejection, target_points_lost

__all__ = ["DPATuner", "LearnedHOCSystem", "dpa_loss", "load_model", "project_b"]

STAGES = ("train", "val", "test")


def _softplus_inverse(x: float) -> float:
    return x + math.log(-math.expm1(-x))


def dpa_loss(asf: torch.Tensor, pixels: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """Softmax cross-entropy of a standardised ASF against the true target pixels (our choice).

    Each scene's ASF ``(H, W)`` is standardised over its pixels (``(asf - mean) / std``, so the
    loss cannot be lowered by scaling the ASF up, e.g. by a larger ``b``: it rewards the contrast
    of the target against the background, what a per-pixel threshold sees), divided by
    ``temperature`` and flattened into ``H * W`` logits; the loss is ``-log softmax`` at each
    target's pixel, averaged over targets and scenes.

    Args:
        asf: ``(B, H, W)`` accumulated score function of one frame.
        pixels: ``(B, N)`` int64 flat indices ``y * W + x`` of the ``N`` targets.
        temperature: softmax temperature ``> 0`` (in background standard deviations).

    Returns:
        0-dim tensor (0 for an empty batch).

    Examples:
        >>> asf = torch.zeros(1, 4, 4)
        >>> asf[0, 1, 2] = 10.0
        >>> bool(dpa_loss(asf, torch.tensor([[6]])) < dpa_loss(asf, torch.tensor([[0]])))
        True
    """
    temperature = check_number("temperature", temperature, low=0.0, low_inclusive=False)
    if asf.shape[0] == 0:
        return asf.sum()
    flat = asf.flatten(1)
    z = (flat - flat.mean(1, keepdim=True)) / flat.std(1, keepdim=True).clamp_min(1e-12)
    logp = torch.log_softmax(z / temperature, dim=1)
    return -logp.gather(1, pixels).mean()


def _near(pixels: torch.Tensor, width: int, height: int, radius: int) -> torch.Tensor:
    """``(B, H * W)`` bool: pixels within ``radius`` (Chebyshev) of a target pixel."""
    bsz = pixels.shape[0]
    mask = torch.zeros(bsz, height, width, dtype=torch.bool, device=pixels.device)
    ys, xs = pixels // width, pixels % width
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            y, x = (ys + dy).clamp(0, height - 1), (xs + dx).clamp(0, width - 1)
            b = torch.arange(bsz, device=pixels.device)[:, None].expand_as(y)
            mask[b, y, x] = True
    return mask.flatten(1)


class DPATuner(L.LightningModule):
    r"""Tune the DPA's ``b``, ``g``, ``p`` and penalty step by gradient [NR08] (our addition).

    The model is ``DPA(window=window, v_max=v_max, b=b, g=g, p=p, penalty_step=penalty_step,
    learnable=learnable, smooth=tau_start)``: with ``matrices="paper"`` the paper's
    parameterisation (eq. (5): ``p`` and one penalty step ``x``), with ``matrices="full"`` (our
    addition) every entry of the ``9 x k x k`` matrices is learned instead of ``p`` and ``x``
    (``"p"`` and ``"penalty"`` in ``learnable`` are replaced by ``"matrices"``; the matrices
    start from eq. (5) at ``p`` and ``penalty_step`` and stay non-negative with sum 1, a softmax
    over each window: :func:`hocnet.dpa.layers.full_matrices`). Constraints are those of the
    DPA's parameterisation (``g``, ``p`` in ``[0, 1]``, ``x`` in ``[0, 3]``, ``b >= 0``) plus a
    projection after every optimiser step that keeps ``b <= b_margin * b_limit(weights, g)``,
    inside the memory range of eq. (12)-(14) (an initial ``b`` above it is moved there too).

    Loss (our choice): :func:`dpa_loss` of the last ASF against the true last-frame target
    pixel, plus ``track_weight`` times the mean :func:`dpa_loss` of the ASFs of frames
    ``1 .. T - 2`` against their true pixels (frame 0's ASF is the frame itself): a
    differentiable stand-in for the back-tracked trajectory, which follows the ASF peaks of
    eq. (8). Training uses the smooth max with
    temperature ``tau`` annealed geometrically from ``tau_start`` (epoch 0) to ``tau_end`` (last
    epoch); validation and test use the hard max, and the test also logs the loss with the
    smooth max at ``tau_end`` and the gap ``test/smooth_gap = loss_smooth - loss_hard``, and
    ``test/asf_gap``, the mean ``|ASF_smooth - ASF_hard|`` of the last frame in units of each
    scene's hard-ASF standard deviation (what training optimised versus what is deployed).

    Metrics per stage (hard max in val / test): ``{stage}/loss``; ``{stage}/hit1``, the fraction
    of scenes whose last-ASF argmax is within ``radius`` px (Chebyshev) of a target;
    ``{stage}/auroc``, target pixels (within ``radius``: the max over that neighbourhood) versus
    every pixel of the target-free frames' last ASF; ``{stage}/pd``, the fraction of targets
    above the per-pixel threshold for false-alarm probability ``pfa`` estimated over the stage's
    target-free last ASFs (an epoch-level quantile: with ``n`` target-free pixels it is
    meaningful for ``pfa >> 1 / n``), and ``{stage}/pfa``, the fraction of target-free pixels
    above that threshold (the realised false-alarm rate, at most ``pfa``).

    Args:
        window: odd window size of the probability matrices.
        v_max: largest target speed (px/frame) of W_frame.
        b: initial memory factor, ``None`` for the EMC-0.8 value of direction 9 (the paper's).
        g: initial sum/max mixing (paper: 0).
        p: initial W_basic mixing weight of eq. (5) (paper: 0.5).
        penalty_step: initial penalty step ``x`` (paper: 3).
        learnable: names among ``("b", "g", "p", "penalty", "matrices")``.
        matrices: ``"paper"`` (eq. (5): ``p`` and ``x``) or ``"full"`` (every matrix entry).
        init_margin: learnable ``g`` / ``p`` start at least this far inside ``[0, 1]`` and ``x``
            ``3 * init_margin`` inside ``[0, 3]`` (our choice: on the bound, the sigmoid's
            gradient is about ``1e-6`` and the parameter could not move).
        lr: Adam learning rate on the unconstrained parameters.
        temperature: softmax temperature of :func:`dpa_loss`.
        track_weight: weight of the per-frame term (0: last frame only).
        tau_start: smooth-max temperature at the first epoch.
        tau_end: smooth-max temperature at the last epoch.
        b_margin: ``b`` is kept below ``b_margin * b_limit``, in ``(0, 1]``.
        pfa: per-pixel false-alarm probability of ``{stage}/pd``.
        radius: hit radius in pixels.
        seed: passed to ``lightning.seed_everything`` at construction.

    Examples:
        >>> tuner = DPATuner(window=5, learnable=("b", "g"))
        >>> sorted(name for name, _ in tuner.model.named_parameters())
        ['b_raw', 'g_raw']
    """

    def __init__(
        self,
        window: int = 5,
        v_max: float = 2.0,
        b: float | None = None,
        g: float = 0.0,
        p: float = 0.5,
        penalty_step: float = 3.0,
        learnable: Sequence[str] = ("b", "g", "p", "penalty"),
        matrices: str = "paper",
        init_margin: float = 0.02,
        lr: float = 0.05,
        temperature: float = 1.0,
        track_weight: float = 0.0,
        tau_start: float = 1.0,
        tau_end: float = 0.05,
        b_margin: float = 0.98,
        pfa: float = 1e-2,
        radius: int = 1,
        seed: int = 0,
    ) -> None:
        super().__init__()
        learnable = (learnable,) if isinstance(learnable, str) else tuple(learnable)
        self.save_hyperparameters()
        if check_choice("matrices", matrices, ("paper", "full")) == "full":
            kept = (n for n in learnable if n not in ("p", "penalty", "matrices"))
            learnable = (*kept, "matrices")
        self.hparams["learnable"] = list(learnable)
        L.seed_everything(check_int("seed", seed, minimum=0), verbose=False)
        margin = check_number("init_margin", init_margin, low=0.0, high=0.5)
        check_number("lr", lr, low=0.0, low_inclusive=False)
        check_number("temperature", temperature, low=0.0, low_inclusive=False)
        check_number("track_weight", track_weight, low=0.0)
        self.tau_start = check_number("tau_start", tau_start, low=0.0, low_inclusive=False)
        self.tau_end = check_number("tau_end", tau_end, low=0.0, low_inclusive=False)
        check_number("b_margin", b_margin, low=0.0, high=1.0, low_inclusive=False)
        check_number("pfa", pfa, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False)
        check_int("radius", radius, minimum=0)
        if "g" in learnable:
            g = min(max(g, margin), 1.0 - margin)
        if "p" in learnable:
            p = min(max(p, margin), 1.0 - margin)
        if "penalty" in learnable:
            penalty_step = min(max(penalty_step, 3 * margin), 3.0 - 3 * margin)
        self.model = _build_dpa(
            {**self.hparams, "g": g, "p": p, "penalty_step": penalty_step}, smooth=tau_start
        )
        project_b(self.model, b_margin)
        self.metrics = nn.ModuleDict()
        for stage in STAGES:
            self.metrics[f"{stage}_auroc"] = BinaryAUROC()
            self.metrics[f"{stage}_hit1"] = MeanMetric()
            self.metrics[f"{stage}_pos"] = CatMetric()
            self.metrics[f"{stage}_neg"] = CatMetric()

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """The ASF ``(B, T, H, W)`` of whitened frames ``(B, T, H, W)`` (current max)."""
        return self.model(frames).asf

    def tau(self) -> float:
        """Smooth-max temperature of the current epoch (geometric from tau_start to tau_end)."""
        trainer = self._trainer
        if trainer is None or not trainer.max_epochs or trainer.max_epochs <= 1:
            return self.tau_end if trainer is not None else self.tau_start
        frac = min(1.0, self.current_epoch / (trainer.max_epochs - 1))
        return self.tau_start * (self.tau_end / self.tau_start) ** frac

    def loss(self, asf: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
        """The documented loss of ``asf`` ``(B, T, H, W)`` and ``pixels`` ``(B, N, T)``."""
        hp = self.hparams
        loss = dpa_loss(asf[:, -1], pixels[:, :, -1], hp["temperature"])
        t_len = asf.shape[1]
        if hp["track_weight"] > 0 and t_len > 1:
            per_frame = [
                dpa_loss(asf[:, t], pixels[:, :, t], hp["temperature"]) for t in range(1, t_len - 1)
            ]
            if per_frame:
                loss = loss + hp["track_weight"] * torch.stack(per_frame).mean()
        return loss

    def _step(self, batch: dict[str, torch.Tensor], stage: str) -> torch.Tensor:
        frames, pixels = batch["frames"], batch["pixels"]
        self.model.smooth = self.tau() if stage == "train" else None
        asf = self.model(frames).asf
        loss = self.loss(asf, pixels)
        bsz = frames.shape[0]
        self.log(f"{stage}/loss", loss, prog_bar=stage != "train", batch_size=bsz)
        with torch.no_grad():
            h, w = frames.shape[-2:]
            last = asf[:, -1].detach().flatten(1)
            near = _near(pixels[:, :, -1], w, h, self.hparams["radius"])
            hit = near.gather(1, last.argmax(1, keepdim=True)).squeeze(1).float()
            self.metrics[f"{stage}_hit1"].update(hit)
            self.log(f"{stage}/hit1", self.metrics[f"{stage}_hit1"], batch_size=bsz)
            if stage != "train":
                neg = self.model(batch["target_free"]).asf[:, -1].flatten(1)
                pos = torch.stack(
                    [
                        last.masked_fill(
                            ~_near(pixels[:, n : n + 1, -1], w, h, self.hparams["radius"]),
                            -math.inf,
                        ).amax(1)
                        for n in range(pixels.shape[1])
                    ],
                    1,
                ).flatten()
                self.metrics[f"{stage}_pos"].update(pos)
                self.metrics[f"{stage}_neg"].update(neg.flatten())
                scores = torch.cat([pos, neg.flatten()])
                labels = torch.cat([torch.ones_like(pos), torch.zeros_like(neg.flatten())]).long()
                self.metrics[f"{stage}_auroc"].update(scores, labels)
                self.log(f"{stage}/auroc", self.metrics[f"{stage}_auroc"], batch_size=bsz)
        if stage == "test":
            self.model.smooth = self.tau_end
            soft = self.model(frames).asf
            smooth = self.loss(soft, pixels)
            self.model.smooth = None
            self.log("test/loss_smooth", smooth, batch_size=bsz)
            self.log("test/smooth_gap", smooth - loss, batch_size=bsz)
            hard_last = asf[:, -1].detach().flatten(1)
            scale = hard_last.std(1).clamp_min(1e-12) if hard_last.shape[1] > 1 else 1.0
            diff = (soft[:, -1].detach().flatten(1) - hard_last).abs().mean(1) / scale
            self.log("test/asf_gap", diff.mean(), batch_size=bsz)
        return loss

    def _epoch_pd(self, stage: str) -> None:
        pos_m, neg_m = self.metrics[f"{stage}_pos"], self.metrics[f"{stage}_neg"]
        if not pos_m.update_called:
            return
        pos, neg = pos_m.compute().flatten(), neg_m.compute().flatten()
        k = max(1, math.floor(self.hparams["pfa"] * neg.numel()))
        threshold = neg.topk(k).values[-1]
        self.log(f"{stage}/pd", (pos > threshold).double().mean().float(), prog_bar=True)
        self.log(f"{stage}/pfa", (neg > threshold).double().mean().float())
        self.log(f"{stage}/threshold", threshold.float())
        pos_m.reset()
        neg_m.reset()

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        """Smooth-max training step."""
        return self._step(batch, "train")

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        """Hard-max validation step."""
        self._step(batch, "val")

    def test_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        """Hard-max test step, with the smooth-max gap."""
        self._step(batch, "test")

    def on_train_epoch_start(self) -> None:
        """Log the current parameters and smooth-max temperature."""
        self.log("train/tau", self.tau())
        for name in ("b", "g", "p", "penalty_step"):
            self.log(f"param/{name}", getattr(self.model, name).detach().float())

    def on_validation_epoch_end(self) -> None:
        """Epoch-level ``val/pd``."""
        self._epoch_pd("val")

    def on_test_epoch_end(self) -> None:
        """Epoch-level ``test/pd``."""
        self._epoch_pd("test")

    def on_train_batch_end(self, outputs: Any, batch: Any, batch_idx: int) -> None:
        """Project ``b`` back below ``b_margin * b_limit(weights, g)``."""
        project_b(self.model, self.hparams["b_margin"])

    def configure_optimizers(self) -> torch.optim.Optimizer:
        """Adam on the unconstrained DPA parameters."""
        return torch.optim.Adam(self.model.parameters(), lr=self.hparams["lr"])


def project_b(model: DPA, margin: float = 0.98) -> bool:
    """Clamp a learnable ``b`` of ``model`` to ``margin * b_limit(weights, g)`` in place.

    Returns:
        ``True`` if ``b`` was changed.

    Examples:
        >>> dpa = DPA(window=5, b=9.0, learnable="b")
        >>> project_b(dpa, 0.5), round(dpa.b.item(), 3) == round(0.5 * b_limit(dpa.weights, 0.0), 3)
        (True, True)
    """
    if "b" not in model.learnable:
        return False
    with torch.no_grad():
        limit = margin * b_limit(model.weights, model.g)
        if math.isfinite(limit) and float(model.b) > limit:
            model.b_raw.fill_(_softplus_inverse(limit))
            return True
    return False


def _build_dpa(hp: dict[str, Any], smooth: float | None = None) -> DPA:
    return DPA(
        window=hp["window"],
        v_max=hp["v_max"],
        b=hp["b"],
        g=hp["g"],
        p=hp["p"],
        penalty_step=hp["penalty_step"],
        learnable=tuple(hp["learnable"]),
        smooth=smooth,
    )


class LearnedHOCSystem(L.LightningModule):
    """The MHOC network of [LA98] with learnable kernels, trained per input point (our addition).

    The model is :class:`~hocnet.hoc.MHOCImage` (forward ``Y^(k)`` OR backward ``Y^(k)``, section
    III-B) with ``learnable=True``: every layer's direction-masked and shift kernels are
    parameters initialised from the fixed masks (``init="fixed"``) or uniformly at random
    (``init="random"``). Training uses the relaxed limiter (``relax="sigmoid"``: steep sigmoid
    centred at 0.5, or ``"ste"``: straight-through, forward ``c > 0.5``); evaluation (val / test)
    uses the learnable layers' hard limiter ``c > 0.5``
    (:func:`~hocnet.hoc.layers.learned_limiter`, our reading: eq. (3) of [LA98], ``c > 0``, on
    the fixed network's integer counts, and the relaxed limiter's centre, so a count the
    training pushed below 0.5 is "off" when deployed), i.e. exactly the network that
    :func:`load_model` returns. From the fixed masks, before training, that is the paper's
    fixed network.

    Loss: binary cross-entropy of the output at every on-pixel of the input cube against its
    label (1 target point, 0 clutter point), the target points weighted by ``target_weight``
    (losing a target point is what [LA98] never allows). Metrics per stage:
    ``{stage}/clutter_rejection`` (mean over scenes, :func:`hocnet.metrics.clutter_rejection`),
    ``{stage}/target_points_lost`` (sum, :func:`hocnet.metrics.target_points_lost`), ``{stage}/pd``
    (kept target points / target points), ``{stage}/pfa`` (kept clutter points / clutter
    points; a point is kept where the output is ``> 0.5``: in training the relaxed output, in
    val / test the 0/1 output of the hard limiter) and ``{stage}/auroc`` (the output as the
    score of each on-pixel, target versus clutter; with the hard limiter a two-level score).

    Args:
        order: HOC order ``k``.
        v: velocity window half-width (pixels per scan).
        delta: curvature limit in radians.
        init: ``"fixed"`` or ``"random"``.
        relax: ``"sigmoid"`` or ``"ste"``.
        steepness: slope of the relaxed limiter.
        target_weight: weight of the target points in the loss.
        lr: Adam learning rate.
        seed: ``lightning.seed_everything`` seed and the random initialisation's seed.

    Examples:
        >>> system = LearnedHOCSystem(order=1, v=1)
        >>> sum(p.numel() for p in system.model.parameters())
        324
    """

    def __init__(
        self,
        order: int = 2,
        v: int = 2,
        delta: float = math.pi / 4,
        init: str = "fixed",
        relax: str = "sigmoid",
        steepness: float = 8.0,
        target_weight: float = 5.0,
        lr: float = 1e-2,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        L.seed_everything(check_int("seed", seed, minimum=0), verbose=False)
        check_choice("init", init, ("fixed", "random"))
        check_number("target_weight", target_weight, low=0.0)
        check_number("lr", lr, low=0.0, low_inclusive=False)
        self.model = _build_hoc(self.hparams)
        self.metrics = nn.ModuleDict()
        for stage in STAGES:
            self.metrics[f"{stage}_rejection"] = MeanMetric()
            self.metrics[f"{stage}_auroc"] = BinaryAUROC()
            self.metrics[f"{stage}_lost"] = SumMetric()
            for name in ("tp", "t", "fp", "c"):
                self.metrics[f"{stage}_{name}"] = SumMetric()

    def forward(self, cube: torch.Tensor) -> torch.Tensor:
        """The network output ``(B, T, H, W)`` of a 0/1 cube ``(B, T, H, W)``."""
        return self.model(cube)

    def _step(self, batch: dict[str, torch.Tensor], stage: str) -> torch.Tensor:
        cube, target = batch["cube"], batch["target"]
        out = self.model(cube)
        points = cube > 0
        weight = torch.where(target, self.hparams["target_weight"], 1.0)[points]
        prob = out[points].clamp(1e-6, 1 - 1e-6)
        if prob.numel():
            loss = F.binary_cross_entropy(prob, target[points].float(), weight=weight)
        else:
            loss = out.sum() * 0.0
        bsz = cube.shape[0]
        self.log(f"{stage}/loss", loss, prog_bar=stage != "train", batch_size=bsz)
        with torch.no_grad():
            kept = out.detach() > 0.5
            if prob.numel():
                self.metrics[f"{stage}_auroc"].update(out.detach()[points], target[points].long())
            self.metrics[f"{stage}_rejection"].update(clutter_rejection(points, kept, target))
            self.metrics[f"{stage}_lost"].update(target_points_lost(points, kept, target))
            clutter = points & ~target
            self.metrics[f"{stage}_tp"].update((kept & target).sum())
            self.metrics[f"{stage}_t"].update(target.sum())
            self.metrics[f"{stage}_fp"].update((kept & clutter).sum())
            self.metrics[f"{stage}_c"].update(clutter.sum())
            kw = {"batch_size": bsz, "on_step": False, "on_epoch": True}
            self.log(f"{stage}/clutter_rejection", self.metrics[f"{stage}_rejection"], **kw)
            self.log(f"{stage}/target_points_lost", self.metrics[f"{stage}_lost"], **kw)
            if prob.numel():
                self.log(f"{stage}/auroc", self.metrics[f"{stage}_auroc"], **kw)
        return loss

    def _epoch_rates(self, stage: str) -> None:
        m = self.metrics
        if not m[f"{stage}_t"].update_called:
            return
        t, c = m[f"{stage}_t"].compute(), m[f"{stage}_c"].compute()
        pd = m[f"{stage}_tp"].compute() / t.clamp_min(1)
        pfa = m[f"{stage}_fp"].compute() / c.clamp_min(1)
        self.log(f"{stage}/pd", pd.float(), prog_bar=stage != "train")
        self.log(f"{stage}/pfa", pfa.float(), prog_bar=stage != "train")
        for name in ("tp", "t", "fp", "c"):
            m[f"{stage}_{name}"].reset()

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        """Relaxed-limiter training step."""
        return self._step(batch, "train")

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        """Hard-limiter (``c > 0.5``) validation step."""
        self._step(batch, "val")

    def test_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        """Hard-limiter (``c > 0.5``) test step."""
        self._step(batch, "test")

    def on_train_epoch_end(self) -> None:
        """Epoch-level ``train/pd`` and ``train/pfa``."""
        self._epoch_rates("train")

    def on_validation_epoch_end(self) -> None:
        """Epoch-level ``val/pd`` and ``val/pfa``."""
        self._epoch_rates("val")

    def on_test_epoch_end(self) -> None:
        """Epoch-level ``test/pd`` and ``test/pfa``."""
        self._epoch_rates("test")

    def configure_optimizers(self) -> torch.optim.Optimizer:
        """Adam on the kernels."""
        return torch.optim.Adam(self.model.parameters(), lr=self.hparams["lr"])


def _build_hoc(hp: dict[str, Any]) -> MHOCImage:
    return MHOCImage(
        hp["order"],
        hp["v"],
        hp["delta"],
        learnable=True,
        init=hp["init"],
        relax=hp["relax"],
        steepness=hp["steepness"],
        seed=hp["seed"],
    )


def load_model(ckpt_path: str | os.PathLike) -> nn.Module:
    """Load a :class:`DPATuner` or :class:`LearnedHOCSystem` checkpoint as the plain model.

    The checkpoint is read with ``torch.load(..., weights_only=True)`` (no pickled code); the
    model is rebuilt from the checkpoint's hyper-parameters and gets the ``model.*`` entries of
    its state dict. The result is in evaluation mode: a :class:`~hocnet.dpa.DPA` with the hard
    max (``smooth=None``) or an :class:`~hocnet.hoc.MHOCImage` with the learnable layers' hard
    limiter ``c > 0.5`` (:func:`~hocnet.hoc.layers.learned_limiter`, the limiter of the
    system's val / test steps).

    Args:
        ckpt_path: path of a Lightning checkpoint written by either system.

    Returns:
        The ``nn.Module``.

    Raises:
        ValueError: the checkpoint holds neither system, is corrupted, or holds pickled
            objects that ``weights_only`` loading refuses (an untrusted pickle: nothing of it is
            run).
        OSError: the file cannot be read (e.g. ``FileNotFoundError``).
    """
    path = os.fspath(ckpt_path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        if "weights only" in str(err).lower():
            raise ValueError(
                f"`ckpt_path`: refused {path!r}: it holds pickled objects other than tensors and "
                "plain containers (an untrusted pickle; only weights_only=True loading is done)"
            ) from None
        message = f"`ckpt_path`: {path!r} is not a readable checkpoint (corrupted?)"
        raise ValueError(message) from None
    except (RuntimeError, EOFError, KeyError, IndexError, ValueError, TypeError) as err:
        detail = str(err).splitlines()[0][:80] if str(err) else type(err).__name__
        raise ValueError(
            f"`ckpt_path`: {path!r} is not a readable checkpoint (corrupted?): {detail}"
        ) from None
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        raise ValueError(f"`ckpt_path`: expected a Lightning checkpoint, got {ckpt_path!r}")
    hp = dict(ckpt.get("hyper_parameters", {}))
    state = {k[len("model.") :]: v for k, v in ckpt["state_dict"].items() if k.startswith("model.")}
    if any("mask_kernels" in k or "window_kernel" in k for k in state):
        model: nn.Module = _build_hoc(hp)
    elif any(k.endswith(("b_raw", "b_value")) for k in state):
        model = _build_dpa(hp, smooth=None)
    else:
        raise ValueError(
            f"`ckpt_path`: expected a DPATuner or LearnedHOCSystem checkpoint, got {ckpt_path!r}"
        )
    model.load_state_dict(state)
    return model.eval()

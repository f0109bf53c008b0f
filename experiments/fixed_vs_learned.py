"""Fixed versus learned, first measurement (beyond [NR08] and [LA98]; a small first increment).

On the same held-out simulated scenes (the test split of the data modules, seeds disjoint from
training and validation):

* **DPA** (``IRSceneDataModule``): the paper's defaults -- ``g = 0`` with ``b`` from the
  effective memory 0.8 of direction 9, and ``g = 1, b = 0.8`` -- against the DPA whose ``b``,
  ``g``, ``p`` and penalty step ``x`` were tuned by :class:`hocnet.learn.DPATuner` from the
  ``g = 0`` defaults. All with the hard max. Metrics: Pd at a per-pixel Pfa (threshold from the
  last ASF of the *validation* scenes' target-free frames: calibration and test scenes are
  disjoint), the per-pixel AUROC (target versus target-free pixels), and the top-1 hit rate (the
  last-ASF argmax within 1 px of a target).
* **HOC** (``BinarySceneDataModule``): the fixed MHOC network of [LA98] against the network with
  kernels learned from the fixed masks and from random kernels (:class:`hocnet.learn.
  LearnedHOCSystem`), hard limiter. Metrics: clutter rejection and target points lost.

This is not yet the issue's comparison (>= 200 scenes per setting, SNR sweeps, grid search): the
default sizes are small enough for a 2-core CPU in a few minutes.

Run: ``python experiments/fixed_vs_learned.py [--quick] [--out DIR]`` (prints a table; with
``--out`` also writes ``fixed-vs-learned.csv`` and ``.md`` there).
"""

from __future__ import annotations

import argparse
import csv
import math
import pathlib
import warnings
from collections.abc import Sequence
from typing import Any

import _expkit as C
import lightning as L
import torch

from hocnet.dpa import DPA
from hocnet.hoc.layers import MHOCImage
from hocnet.learn import (
    BinarySceneDataModule,
    DPATuner,
    IRSceneDataModule,
    LearnedHOCSystem,
)
from hocnet.metrics import clutter_rejection, target_points_lost

NAME = "fixed-vs-learned"
PFAS = (1e-2, 1e-3)
FULL = {
    "ir": {"n_train": 32, "n_val": 16, "n_test": 32, "shape": (8, 32, 32), "batch_size": 8},
    "bin": {"n_train": 32, "n_val": 8, "n_test": 32, "shape": (8, 32, 32), "batch_size": 8},
    "epochs": 8,
    "hoc": {"order": 2, "v": 2},
    "bin_speed": (0.1, 2.0),
}
QUICK = {
    "ir": {"n_train": 4, "n_val": 2, "n_test": 2, "shape": (5, 16, 16), "batch_size": 2},
    "bin": {"n_train": 4, "n_val": 2, "n_test": 2, "shape": (6, 16, 16), "batch_size": 2},
    "epochs": 1,
    "hoc": {"order": 1, "v": 1},
    "bin_speed": (0.1, 1.0),
}


def _fit(system: L.LightningModule, data: L.LightningDataModule, epochs: int) -> None:
    trainer = L.Trainer(
        max_epochs=epochs,
        accelerator="cpu",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        enable_checkpointing=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
    )
    trainer.fit(system, data)


def _near_max(last: torch.Tensor, pixels: torch.Tensor, radius: int = 1) -> torch.Tensor:
    """``(B, N)``: the max of ``last`` ``(B, H, W)`` within ``radius`` px of each target pixel."""
    _, h, w = last.shape
    ys, xs = pixels // w, pixels % w
    out = torch.full(pixels.shape, -math.inf, dtype=last.dtype)
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            y, x = (ys + dy).clamp(0, h - 1), (xs + dx).clamp(0, w - 1)
            b = torch.arange(last.shape[0])[:, None].expand_as(y)
            out = torch.maximum(out, last[b, y, x])
    return out


def _auroc(pos: torch.Tensor, neg: torch.Tensor) -> float:
    """Probability that a target score beats a target-free pixel score (ties count half)."""
    neg = neg.sort().values
    below = torch.searchsorted(neg, pos, right=False).double()
    upto = torch.searchsorted(neg, pos, right=True).double()
    return float(((below + upto) / 2).mean() / neg.numel())


@torch.no_grad()
def evaluate_dpa(model: DPA, data: IRSceneDataModule) -> dict[str, float]:
    """Pd at each of ``PFAS``, AUROC and top-1 hit rate of ``model`` (hard max), test split."""
    model.smooth = None
    calib = torch.stack([s["target_free"] for s in data.scenes("val")])
    neg = model(calib).asf[:, -1].flatten()
    pos, neg_test, hits = [], [], []
    for batch in data.test_dataloader():
        last = model(batch["frames"]).asf[:, -1]
        pixels = batch["pixels"][:, :, -1]
        scores = _near_max(last, pixels)
        pos.append(scores.flatten())
        hits.append((scores.amax(1) >= last.flatten(1).amax(1)).double())
        neg_test.append(model(batch["target_free"]).asf[:, -1].flatten())
    pos_t = torch.cat(pos)
    row: dict[str, float] = {}
    for pfa in PFAS:
        k = max(1, math.floor(pfa * neg.numel()))
        threshold = neg.topk(k).values[-1]
        row[f"pd@{pfa:g}"] = float((pos_t > threshold).double().mean())
    row["auroc"] = _auroc(pos_t, torch.cat(neg_test))
    row["hit1"] = float(torch.cat(hits).mean())
    return row


@torch.no_grad()
def evaluate_hoc(model: MHOCImage, data: BinarySceneDataModule) -> dict[str, float]:
    """Mean clutter rejection and total target points lost of ``model`` (hard limiter)."""
    model.eval()
    rejection, lost = [], 0
    for batch in data.test_dataloader():
        cube, target = batch["cube"] > 0, batch["target"]
        out = model(batch["cube"]) > 0.5
        rejection.append(clutter_rejection(cube, out, target))
        lost += int(target_points_lost(cube, out, target).sum())
    return {"clutter_rejection": float(torch.cat(rejection).mean()), "target_points_lost": lost}


def run(quick: bool = False, seed: int = 0) -> list[dict[str, Any]]:
    """Train and evaluate every method; one row per (detector, method)."""
    cfg = QUICK if quick else FULL
    rows: list[dict[str, Any]] = []
    ir = IRSceneDataModule(**cfg["ir"], snr_db=(6.0, 12.0), speed=(0.1, 2.0), seed=seed)
    ir.setup()
    window = 5 if quick else 7
    paper = {
        "paper g=0 (EMC 0.8, dir 9)": DPA(window=window, g=0.0),
        "paper g=1, b=0.8": DPA(window=window, g=1.0, b=0.8),
    }
    for label, model in paper.items():
        rows.append({"detector": "dpa", "method": label, **evaluate_dpa(model, ir)})
    tuner = DPATuner(window=window, seed=seed)
    _fit(tuner, ir, cfg["epochs"])
    m = tuner.model
    label = (
        f"learned (b={float(m.b):.3g}, g={float(m.g):.3g}, p={float(m.p):.3g}, "
        f"x={float(m.penalty_step):.3g})"
    )
    rows.append({"detector": "dpa", "method": label, **evaluate_dpa(m, ir)})

    binary = BinarySceneDataModule(
        **cfg["bin"], clutter_density=(0.008, 0.05), speed=cfg["bin_speed"], seed=seed
    )
    binary.setup()
    hoc = cfg["hoc"]
    rows.append(
        {"detector": "hoc", "method": "fixed [LA98]", **evaluate_hoc(MHOCImage(**hoc), binary)}
    )
    for init in ("fixed", "random"):
        system = LearnedHOCSystem(**hoc, init=init, seed=seed)
        _fit(system, binary, cfg["epochs"])
        rows.append(
            {
                "detector": "hoc",
                "method": f"learned from {init}",
                **evaluate_hoc(system.model, binary),
            }
        )
    return rows


def table(rows: Sequence[dict[str, Any]]) -> str:
    """A markdown table of ``rows`` (missing values blank)."""
    keys = ["detector", "method"] + [
        k for k in dict.fromkeys(k for r in rows for k in r) if k not in ("detector", "method")
    ]
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        cells = [f"{r[k]:.3f}" if isinstance(r.get(k), float) else str(r.get(k, "")) for k in keys]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> str:
    """Command line: run, print the table, optionally write csv and md to ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny smoke-test sizes")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the data splits")
    parser.add_argument("--out", default=None, help="folder for the csv and md (optional)")
    args = parser.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows = run(quick=args.quick, seed=args.seed)
    text = table(rows)
    print(text)
    if args.out:  # written only where asked (never into experiments/results by itself)
        out = C.out_dir_of(pathlib.Path(args.out), quick=args.quick)
        out.mkdir(parents=True, exist_ok=True)
        keys = list(dict.fromkeys(k for r in rows for k in r))
        with open(out / f"{NAME}.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=keys)
            writer.writeheader()
            writer.writerows(rows)
        (out / f"{NAME}.md").write_text(f"# {NAME}\n\n{text}\n")
    return text


if __name__ == "__main__":
    main()

"""Learning the hand-set weights of the DPA [NR08] and the HOC network [LA98] (our addition).

Lightning data modules over the simulators and Lightning systems around the plain models;
:func:`load_model` turns a checkpoint back into the plain ``nn.Module``; :func:`detect_dpa` /
:func:`detect_hoc` detect with it (``hocnet detect --weights``); ``hocnet train`` is
:mod:`hocnet.learn.train` (``LightningCLI``). Needs the optional ``learn`` extra (``lightning``,
``torchmetrics``, ``jsonargparse[signatures]``).
"""

from hocnet.learn.apply import detect_dpa, detect_hoc, load_detector
from hocnet.learn.datamodules import BinarySceneDataModule, IRSceneDataModule, split_seeds
from hocnet.learn.systems import DPATuner, LearnedHOCSystem, dpa_loss, load_model, project_b

__all__ = [
    "BinarySceneDataModule",
    "DPATuner",
    "IRSceneDataModule",
    "LearnedHOCSystem",
    "detect_dpa",
    "detect_hoc",
    "dpa_loss",
    "load_detector",
    "load_model",
    "project_b",
    "split_seeds",
]

"""Learning the hand-set weights of the DPA [NR08] and the HOC network [LA98] (our addition).

Lightning data modules over the simulators and Lightning systems around the plain models;
:func:`load_model` turns a checkpoint back into the plain ``nn.Module``. Needs the optional
``lightning`` and ``torchmetrics`` packages.
"""

from hocnet.learn.datamodules import BinarySceneDataModule, IRSceneDataModule, split_seeds
from hocnet.learn.systems import DPATuner, LearnedHOCSystem, dpa_loss, load_model, project_b

__all__ = [
    "BinarySceneDataModule",
    "DPATuner",
    "IRSceneDataModule",
    "LearnedHOCSystem",
    "dpa_loss",
    "load_model",
    "project_b",
    "split_seeds",
]

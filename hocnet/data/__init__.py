"""Simulators, real frames, pre-processing and files.

Binary scenes [LA98], IR sequences [NR08], whitening, registration, background removal, CFAR
binarisation, loading frames and cubes.
"""

from hocnet.data.background import (
    BackgroundRemoval,
    Registration,
    estimate_shifts,
    register,
    remove_background,
)
from hocnet.data.binarize import CFARBinarize, cfar_binarize
from hocnet.data.binary import BinaryScene, TargetSpec, paper_scene, simulate_binary
from hocnet.data.infrared import IRSequence, IRTarget, na23a_like, npa_like, simulate_ir
from hocnet.data.io import load_cube, load_frames, load_tracks_json, save_cube, save_tracks_json
from hocnet.data.whitening import AntiMean, AntiMedian, anti_mean, anti_median

__all__ = [
    "AntiMean",
    "AntiMedian",
    "BackgroundRemoval",
    "BinaryScene",
    "CFARBinarize",
    "IRSequence",
    "IRTarget",
    "Registration",
    "TargetSpec",
    "anti_mean",
    "anti_median",
    "cfar_binarize",
    "estimate_shifts",
    "load_cube",
    "load_frames",
    "load_tracks_json",
    "na23a_like",
    "npa_like",
    "paper_scene",
    "register",
    "remove_background",
    "save_cube",
    "save_tracks_json",
    "simulate_binary",
    "simulate_ir",
]

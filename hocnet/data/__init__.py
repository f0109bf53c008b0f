"""Simulators and I/O: binary multi-scan scenes [LA98], IR sequences [NR08], whitening, files."""

from hocnet.data.binary import BinaryScene, TargetSpec, paper_scene, simulate_binary
from hocnet.data.infrared import IRSequence, IRTarget, na23a_like, npa_like, simulate_ir
from hocnet.data.io import load_cube, load_tracks_json, save_cube, save_tracks_json
from hocnet.data.whitening import AntiMean, AntiMedian, anti_mean, anti_median

__all__ = [
    "AntiMean",
    "AntiMedian",
    "BinaryScene",
    "IRSequence",
    "IRTarget",
    "TargetSpec",
    "anti_mean",
    "anti_median",
    "load_cube",
    "load_tracks_json",
    "na23a_like",
    "npa_like",
    "paper_scene",
    "save_cube",
    "save_tracks_json",
    "simulate_binary",
    "simulate_ir",
]

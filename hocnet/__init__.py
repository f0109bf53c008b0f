"""hocnet: track-before-detect for dim multiple moving targets, as PyTorch modules.

Subpackages: :mod:`hocnet.hoc` (modified high-order correlation, [LA98]), :mod:`hocnet.dpa`
(dynamic-programming TBD, [NR08]), :mod:`hocnet.data` (simulators, real frames, registration,
background removal, whitening, CFAR binarisation, files), :mod:`hocnet.metrics` (including the
small-target detection measures) and :mod:`hocnet.plot`.
"""

from hocnet import data, hoc
from hocnet.data import load_frames, paper_scene, simulate_binary, simulate_ir
from hocnet.hoc import (
    HOCLayer,
    HOCNet,
    HOCResult,
    ModifiedHOCLayer,
    StreamingDetector,
    Track,
    chain_support,
    density_bound,
    density_warning,
    mhoc_candidates,
    mhoc_image,
    modified_hoc,
    original_hoc,
)

__version__ = "0.1.0"

__all__ = [
    "HOCLayer",
    "HOCNet",
    "HOCResult",
    "ModifiedHOCLayer",
    "StreamingDetector",
    "Track",
    "__version__",
    "chain_support",
    "data",
    "density_bound",
    "density_warning",
    "hoc",
    "load_frames",
    "mhoc_candidates",
    "mhoc_image",
    "modified_hoc",
    "original_hoc",
    "paper_scene",
    "simulate_binary",
    "simulate_ir",
]

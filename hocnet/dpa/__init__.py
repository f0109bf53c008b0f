"""Dynamic-programming track-before-detect (DPA), [NR08].

O. Nichtern, S. R. Rotman, "Parameter adjustment for a dynamic programming track-before-detect-based
target detection algorithm", EURASIP J. Adv. Signal Process., 2008.
"""

from hocnet.dpa.backtrack import DPADetection, DPATrack, backtrack, cfar_threshold, detect
from hocnet.dpa.functional import DIRECTION_STEPS, DPAState, accumulate
from hocnet.dpa.layers import DPA
from hocnet.dpa.matrices import (
    PAPER_PSF,
    PAPER_SIGMA,
    b_limit,
    b_versus_g,
    basic_matrix,
    effective_memories,
    effective_memory,
    equalize_gain,
    figure3_matrices,
    fit_basic_sigma,
    frame_matrix,
    memory_line,
    penalty_matrices,
    penalty_matrix_in_place,
    probability_matrices,
    var_table,
)
from hocnet.dpa.metrics import (
    algorithm_score,
    block_snr,
    block_snrs,
    detection_probability,
    frame_thresholds,
    frames_to_reach,
    tracking_success,
)

__all__ = [
    "DIRECTION_STEPS",
    "DPA",
    "PAPER_PSF",
    "PAPER_SIGMA",
    "DPADetection",
    "DPAState",
    "DPATrack",
    "accumulate",
    "algorithm_score",
    "b_limit",
    "b_versus_g",
    "backtrack",
    "basic_matrix",
    "block_snr",
    "block_snrs",
    "cfar_threshold",
    "detect",
    "detection_probability",
    "effective_memories",
    "effective_memory",
    "equalize_gain",
    "figure3_matrices",
    "fit_basic_sigma",
    "frame_matrix",
    "frame_thresholds",
    "frames_to_reach",
    "memory_line",
    "penalty_matrices",
    "penalty_matrix_in_place",
    "probability_matrices",
    "tracking_success",
    "var_table",
]

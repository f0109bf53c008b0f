"""Dynamic-programming track-before-detect (DPA), [NR08].

O. Nichtern, S. R. Rotman, "Parameter adjustment for a dynamic programming track-before-detect-based
target detection algorithm", EURASIP J. Adv. Signal Process., 2008.
"""

from hocnet.dpa.functional import DPAState, accumulate
from hocnet.dpa.layers import DPA
from hocnet.dpa.matrices import (
    b_versus_g,
    basic_matrix,
    effective_memory,
    frame_matrix,
    memory_line,
    penalty_matrices,
    penalty_matrix_in_place,
    probability_matrices,
    var_table,
)

__all__ = [
    "DPA",
    "DPAState",
    "accumulate",
    "b_versus_g",
    "basic_matrix",
    "effective_memory",
    "frame_matrix",
    "memory_line",
    "penalty_matrices",
    "penalty_matrix_in_place",
    "probability_matrices",
    "var_table",
]

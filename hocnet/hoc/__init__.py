"""Modified high-order correlation (HOC) multi-target detection, [LA98].

R.-J. Liou, M. R. Azimi-Sadjadi, "Multiple target detection using modified high order
correlations", IEEE Trans. AES 34(2), 1998.
"""

from hocnet.hoc.functional import (
    chain_support,
    density_bound,
    density_warning,
    effective_v,
    hard_limiter,
    hoc_layer,
    hoc_levels,
    hoc_mark,
    mhoc_image,
    modified_hoc,
    original_hoc,
    original_hoc_layer,
    original_hoc_mark,
    scans_needed,
    support_from_levels,
)
from hocnet.hoc.identify import (
    HOCResult,
    Track,
    detect,
    identify_tracks,
    mhoc_candidates,
    reject_slow_tracks,
)
from hocnet.hoc.kernels import (
    allowed_moves,
    get_direction_mask_kernels,
    get_shift_kernels,
    get_window_kernel,
    move_offsets,
    turn_angles,
)
from hocnet.hoc.layers import (
    HOCLayer,
    HOCNet,
    MHOCImage,
    ModifiedHOCLayer,
    relaxed_limiter,
    ste_limiter,
)
from hocnet.hoc.scoring import DEFAULT_THRESHOLD, curvature_score, movement_score, point_score
from hocnet.hoc.stream import StreamingDetector, StreamResult

__all__ = [
    "DEFAULT_THRESHOLD",
    "HOCLayer",
    "HOCNet",
    "HOCResult",
    "MHOCImage",
    "ModifiedHOCLayer",
    "StreamResult",
    "StreamingDetector",
    "Track",
    "allowed_moves",
    "chain_support",
    "curvature_score",
    "density_bound",
    "density_warning",
    "detect",
    "effective_v",
    "get_direction_mask_kernels",
    "get_shift_kernels",
    "get_window_kernel",
    "hard_limiter",
    "hoc_layer",
    "hoc_levels",
    "hoc_mark",
    "identify_tracks",
    "mhoc_candidates",
    "mhoc_image",
    "modified_hoc",
    "move_offsets",
    "movement_score",
    "original_hoc",
    "original_hoc_layer",
    "original_hoc_mark",
    "point_score",
    "reject_slow_tracks",
    "relaxed_limiter",
    "scans_needed",
    "ste_limiter",
    "support_from_levels",
    "turn_angles",
]

"""Tracking after detection ([PD], Pannetier, Dezert et al.): batched numeric core.

First increment: batched Kalman / EKF filtering and gating (:mod:`hocnet.tracking.kalman`), the
IMM with a stop model (:mod:`hocnet.tracking.imm`) and belief functions with PCR5 and the
pignistic transformation (:mod:`hocnet.tracking.belief`), and the road-segment model with the
constrained estimate by projection (:mod:`hocnet.tracking.road`). Data association: Murty's
k-best assignment (:mod:`hocnet.tracking.assignment`) and the track-oriented structured-branching
MHT with LLR track scores and SPRT track status (:mod:`hocnet.tracking.mht`).
"""

from hocnet.tracking.assignment import Assignment, brute_force_assignments, k_best_assignments
from hocnet.tracking.belief import (
    conjunctive,
    dempster,
    from_dict,
    observed_bba,
    pcr5,
    pcr5_sources,
    pignistic,
    to_dict,
    vacuous,
)
from hocnet.tracking.imm import (
    IMMStep,
    imm_combine,
    imm_mix,
    imm_mixing_probabilities,
    imm_mode_probabilities,
    imm_step,
    imm_track_log_likelihood,
    pd_mode_log_likelihoods,
)
from hocnet.tracking.kalman import (
    constant_velocity,
    cv_gamma,
    ekf_update,
    gate,
    gaussian_log_likelihood,
    kalman_predict,
    kalman_update,
    mahalanobis2,
    stop_model,
)
from hocnet.tracking.mht import (
    MHT,
    CVKalmanFilter,
    IMMFilter,
    MHTTrack,
    MotionFilter,
    sprt_thresholds,
)
from hocnet.tracking.road import (
    on_segment_probability,
    project_estimate,
    relaxed_road_noise_cov,
    road_constant_velocity,
    road_noise_cov,
    segment_constraint,
)

__all__ = [
    "MHT",
    "Assignment",
    "CVKalmanFilter",
    "IMMFilter",
    "IMMStep",
    "MHTTrack",
    "MotionFilter",
    "brute_force_assignments",
    "conjunctive",
    "constant_velocity",
    "cv_gamma",
    "dempster",
    "ekf_update",
    "from_dict",
    "gate",
    "gaussian_log_likelihood",
    "imm_combine",
    "imm_mix",
    "imm_mixing_probabilities",
    "imm_mode_probabilities",
    "imm_step",
    "imm_track_log_likelihood",
    "k_best_assignments",
    "kalman_predict",
    "kalman_update",
    "mahalanobis2",
    "observed_bba",
    "on_segment_probability",
    "pcr5",
    "pcr5_sources",
    "pd_mode_log_likelihoods",
    "pignistic",
    "project_estimate",
    "relaxed_road_noise_cov",
    "road_constant_velocity",
    "road_noise_cov",
    "segment_constraint",
    "sprt_thresholds",
    "stop_model",
    "to_dict",
    "vacuous",
]

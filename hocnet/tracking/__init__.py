"""Tracking after detection ([PD], Pannetier, Dezert et al.): batched numeric core.

First increment: batched Kalman / EKF filtering and gating (:mod:`hocnet.tracking.kalman`), the
IMM with a stop model (:mod:`hocnet.tracking.imm`) and belief functions with PCR5 and the
pignistic transformation (:mod:`hocnet.tracking.belief`), and the road-segment model with the
constrained estimate by projection (:mod:`hocnet.tracking.road`).

The experiment of [PD] section 24.6: the scenario simulator (road network, ten targets, GMTI /
UAV video / UGS reports; :mod:`hocnet.tracking.scenario`) and the per-target metrics with GOSPA
(:mod:`hocnet.tracking.evaluation`).
"""

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
from hocnet.tracking.evaluation import (
    EstimatedTrack,
    TargetMetrics,
    assign_tracks,
    gospa,
    monte_carlo_metrics,
    target_metrics,
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
from hocnet.tracking.road import (
    on_segment_probability,
    project_estimate,
    relaxed_road_noise_cov,
    road_constant_velocity,
    road_noise_cov,
    segment_constraint,
)
from hocnet.tracking.scenario import (
    GMTI_CLASSES,
    VIDEO_CLASSES,
    GMTIConfig,
    PDScenario,
    Report,
    TargetTruth,
    UGSConfig,
    VideoConfig,
    pd_ground_truth,
    pd_road_network,
    pd_scenario,
    plot_scenario,
)

__all__ = [
    "GMTI_CLASSES",
    "VIDEO_CLASSES",
    "EstimatedTrack",
    "GMTIConfig",
    "IMMStep",
    "PDScenario",
    "Report",
    "TargetMetrics",
    "TargetTruth",
    "UGSConfig",
    "VideoConfig",
    "assign_tracks",
    "conjunctive",
    "constant_velocity",
    "cv_gamma",
    "dempster",
    "ekf_update",
    "from_dict",
    "gate",
    "gaussian_log_likelihood",
    "gospa",
    "imm_combine",
    "imm_mix",
    "imm_mixing_probabilities",
    "imm_mode_probabilities",
    "imm_step",
    "imm_track_log_likelihood",
    "kalman_predict",
    "kalman_update",
    "mahalanobis2",
    "monte_carlo_metrics",
    "observed_bba",
    "on_segment_probability",
    "pcr5",
    "pcr5_sources",
    "pd_ground_truth",
    "pd_mode_log_likelihoods",
    "pd_road_network",
    "pd_scenario",
    "pignistic",
    "plot_scenario",
    "project_estimate",
    "relaxed_road_noise_cov",
    "road_constant_velocity",
    "road_noise_cov",
    "segment_constraint",
    "stop_model",
    "target_metrics",
    "to_dict",
    "vacuous",
]

"""Tracking after detection ([PD], Pannetier, Dezert et al.): the VS-IMMC SB-MHT with PCR5.

Modules (numerics batched over tracks, float64 torch):

- :mod:`hocnet.tracking.kalman`: Kalman / EKF predict and update, Gaussian likelihoods,
  gating, the constant-velocity and stop models, the shared normal CDF.
- :mod:`hocnet.tracking.imm`: the IMM with the stop model M0 (24.29-24.37), and the one
  implementation of the PD-aware likelihoods 24.30-24.31.
- :mod:`hocnet.tracking.road`: road segments, directional and relaxed process noise
  (24.2-24.12), projection on the road (24.14-24.16), the road network (segments, sections,
  junctions, GeoJSON).
- :mod:`hocnet.tracking.sensors`: the GMTI model with range-rate, AEKF linearisation and MDV
  notch (24.17-24.20), video / UGS position reports (24.23-24.24) with optional coverage.
- :mod:`hocnet.tracking.vsimm`: the variable-structure IMM on the road network (VS-IMMC) with
  road-section hypotheses at junctions decided by the SPRT (24.38-24.40).
- :mod:`hocnet.tracking.oosm`: out-of-sequence measurements by Bar-Shalom's one-step-lag
  retrodiction, done on the road (24.4.5), with a drop policy for older reports.
- :mod:`hocnet.tracking.sprt`: Wald's SPRT bounds, shared by the track status and the
  road-section test.
- :mod:`hocnet.tracking.assignment`: Murty's k-best assignment.
- :mod:`hocnet.tracking.mht`: the track-oriented structured-branching MHT with LLR track scores
  (24.41-24.43), SPRT track status, clustering, N-best hypotheses, N-scan pruning per road
  section, merging, and the type term of 24.48.
- :mod:`hocnet.tracking.belief`: belief functions on bitmask tensors: PCR5 (24.44), the
  pignistic transformation (24.47), frame refinement (24.5.3), the target-type tracker.
- :mod:`hocnet.tracking.scenario`: the simulator of the chapter's experiment (section 24.6).
- :mod:`hocnet.tracking.evaluation`: per-target metrics (24.52, ARMSE, track and type
  purity) and GOSPA.
- :mod:`hocnet.tracking.stonesoup` (optional, needs Stone Soup; not imported here): adapters
  of the IMM, road models, GMTI model and SPRT track logic as Stone Soup parts.
"""

from hocnet.tracking.assignment import Assignment, brute_force_assignments, k_best_assignments
from hocnet.tracking.belief import (
    TypeFusion,
    coarsen,
    conjunctive,
    dempster,
    frame_mapping,
    from_dict,
    fuse_sensors,
    observed_bba,
    pcr5,
    pcr5_sources,
    pignistic,
    pignistic_coarse,
    refine,
    to_dict,
    type_likelihood,
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
    normal_cdf,
    stop_model,
)
from hocnet.tracking.mht import (
    MHT,
    CVKalmanFilter,
    IMMFilter,
    MHTTrack,
    MotionFilter,
)
from hocnet.tracking.oosm import (
    Retrodiction,
    check_oosm_time,
    cv_transition,
    cwna_noise,
    innovation_memory,
    oosm_a1,
    oosm_apply,
    oosm_retrodict,
    oosm_too_old,
    project_retrodiction,
)
from hocnet.tracking.road import (
    RoadLocation,
    RoadNetwork,
    on_segment_probability,
    on_segment_probability_from_moments,
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
from hocnet.tracking.sensors import (
    SENSOR_NAMES,
    GMTISensor,
    VideoSensor,
    check_measurements,
    disc_coverage,
    gmti_aekf_matrix,
    gmti_jacobian,
    gmti_measure,
    gmti_report_to_tcf,
    gmti_tcf_to_report,
    make_sensor,
    rectangle_coverage,
    stop_detectable,
)
from hocnet.tracking.sprt import sprt_thresholds
from hocnet.tracking.vsimm import (
    VSIMMAssociation,
    VSIMMConfig,
    VSIMMOOSMUpdate,
    VSIMMPrediction,
    VSIMMState,
    VSIMMUpdate,
    section_probabilities,
    section_transition,
    sprt_decide,
    vsimm_association_log_likelihood,
    vsimm_expand_sections,
    vsimm_init,
    vsimm_oosm,
    vsimm_predict,
    vsimm_section_sprt,
    vsimm_step,
    vsimm_update,
)

__all__ = [
    "GMTI_CLASSES",
    "MHT",
    "SENSOR_NAMES",
    "VIDEO_CLASSES",
    "Assignment",
    "CVKalmanFilter",
    "EstimatedTrack",
    "GMTIConfig",
    "GMTISensor",
    "IMMFilter",
    "IMMStep",
    "MHTTrack",
    "MotionFilter",
    "PDScenario",
    "Report",
    "Retrodiction",
    "RoadLocation",
    "RoadNetwork",
    "TargetMetrics",
    "TargetTruth",
    "TypeFusion",
    "UGSConfig",
    "VSIMMAssociation",
    "VSIMMConfig",
    "VSIMMOOSMUpdate",
    "VSIMMPrediction",
    "VSIMMState",
    "VSIMMUpdate",
    "VideoConfig",
    "VideoSensor",
    "assign_tracks",
    "brute_force_assignments",
    "check_measurements",
    "check_oosm_time",
    "coarsen",
    "conjunctive",
    "constant_velocity",
    "cv_gamma",
    "cv_transition",
    "cwna_noise",
    "dempster",
    "disc_coverage",
    "ekf_update",
    "frame_mapping",
    "from_dict",
    "fuse_sensors",
    "gate",
    "gaussian_log_likelihood",
    "gmti_aekf_matrix",
    "gmti_jacobian",
    "gmti_measure",
    "gmti_report_to_tcf",
    "gmti_tcf_to_report",
    "gospa",
    "imm_combine",
    "imm_mix",
    "imm_mixing_probabilities",
    "imm_mode_probabilities",
    "imm_step",
    "imm_track_log_likelihood",
    "innovation_memory",
    "k_best_assignments",
    "kalman_predict",
    "kalman_update",
    "mahalanobis2",
    "make_sensor",
    "monte_carlo_metrics",
    "normal_cdf",
    "observed_bba",
    "on_segment_probability",
    "on_segment_probability_from_moments",
    "oosm_a1",
    "oosm_apply",
    "oosm_retrodict",
    "oosm_too_old",
    "pcr5",
    "pcr5_sources",
    "pd_ground_truth",
    "pd_mode_log_likelihoods",
    "pd_road_network",
    "pd_scenario",
    "pignistic",
    "pignistic_coarse",
    "plot_scenario",
    "project_estimate",
    "project_retrodiction",
    "rectangle_coverage",
    "refine",
    "relaxed_road_noise_cov",
    "road_constant_velocity",
    "road_noise_cov",
    "section_probabilities",
    "section_transition",
    "segment_constraint",
    "sprt_decide",
    "sprt_thresholds",
    "stop_detectable",
    "stop_model",
    "target_metrics",
    "to_dict",
    "type_likelihood",
    "vacuous",
    "vsimm_association_log_likelihood",
    "vsimm_expand_sections",
    "vsimm_init",
    "vsimm_oosm",
    "vsimm_predict",
    "vsimm_section_sprt",
    "vsimm_step",
    "vsimm_update",
]

"""Tracking after detection ([PD], Pannetier, Dezert et al.): batched numeric core.

First increment: batched Kalman / EKF filtering and gating (:mod:`hocnet.tracking.kalman`), the
IMM with a stop model (:mod:`hocnet.tracking.imm`) and belief functions with PCR5 and the
pignistic transformation (:mod:`hocnet.tracking.belief`).
"""

from hocnet.tracking.kalman import (
    constant_velocity,
    cv_gamma,
    ekf_update,
    gaussian_log_likelihood,
    gate,
    kalman_predict,
    kalman_update,
    mahalanobis2,
    stop_model,
)

__all__ = [
    "constant_velocity",
    "cv_gamma",
    "ekf_update",
    "gaussian_log_likelihood",
    "gate",
    "kalman_predict",
    "kalman_update",
    "mahalanobis2",
    "stop_model",
]

"""Stone Soup adapters: our IMM, road models, GMTI model and SPRT track logic as Stone Soup parts.

Stone Soup (https://stonesoup.readthedocs.io) composes a tracker from roles: a predictor
(``predict(prior, timestamp)``), an updater (``predict_measurement``, ``update(hypothesis)``), a
hypothesiser (``hypothesise(track, detections, timestamp)``), a data associator, an initiator
and a deleter. Stone Soup 1.9 has no Gaussian IMM; this module supplies one built on the batched
numeric core of :mod:`hocnet.tracking` (float64 torch), with Stone Soup types in and out, so that
a Stone Soup user can drop our models into their own tracker:

- **State types**: :class:`IMMState` is a :class:`~stonesoup.types.state.GaussianState` whose
  ``state_vector`` / ``covar`` are the combined IMM estimate (24.37) and which carries the
  mode-matched estimates ``mode_state_vectors`` ``(r, n)``, ``mode_covars`` ``(r, n, n)`` and the
  mode probabilities ``mode_probabilities`` ``(r,)``; :class:`IMMStatePrediction` (mode
  probabilities = the predicted ``mu_j(k|k-1)``) and :class:`IMMStateUpdate`. Every other Stone
  Soup part that reads a Gaussian state (gaters, metrics, plotters) sees the combined estimate;
  :meth:`IMMState.to_mixture` gives the modes as a
  :class:`~stonesoup.types.mixture.GaussianMixture` (weights = mode probabilities).
- **Transition models** (state ``[x, vx, y, vy]``, m and m/s; Stone Soup's ``time_interval`` is
  a :class:`datetime.timedelta`): :class:`StopModel` (M0), :class:`ConstantVelocity2D` (our
  discrete white-noise acceleration CV, [PD] 24.5 isotropic; Stone Soup's own
  ``ConstantVelocity`` uses continuous white noise, a different ``Q``) and
  :class:`RoadConstrainedCV` (24.2-24.8 with the relaxed noise of 24.9-24.12 and the constraint
  ``D x = L`` of 24.3-24.4, on one segment or on the nearest segment of a
  :class:`~hocnet.tracking.road.RoadNetwork`, following bends and junctions as
  :func:`~hocnet.tracking.vsimm.vsimm_predict` does). All are ``LinearGaussianTransitionModel``
  s, so Stone Soup's own ``KalmanPredictor`` accepts them too (without the relaxation, which
  needs the prior: see :meth:`RoadConstrainedCV.covar`; a road model on a ``network`` needs
  :class:`IMMPredictor`).
- **IMM**: :class:`IMMPredictor` (mixing 24.33-24.35 and the mode-matched predictions, with
  :func:`~hocnet.tracking.imm.imm_mixing_probabilities`, :func:`~hocnet.tracking.imm.imm_mix`,
  :func:`~hocnet.tracking.kalman.kalman_predict`) and :class:`IMMUpdater` (mode-matched (E)KF
  updates by :func:`~hocnet.tracking.kalman.ekf_update`, PD-aware likelihoods with the stop model
  24.29-24.31, 24.32, 24.36, 24.37, and optionally the projection of every road mode on its
  segment, 24.14-24.16). A predict + update cycle equals :func:`~hocnet.tracking.imm.imm_step`.
- **GMTI**: :class:`GMTIMeasurementModel`, the range-rate measurement of 24.17-24.18 as a Stone
  Soup non-linear Gaussian measurement model with its Jacobian (so Stone Soup's
  ``ExtendedKalmanUpdater`` works with it), or, with a ``reference`` position, the linear AEKF
  form 24.19-24.20; :func:`gmti_detection` turns a polar report of a
  :class:`~hocnet.tracking.sensors.GMTISensor` into a Stone Soup ``Detection`` with its ``R``.
- **Track logic**: :class:`IMMHypothesiser` (gating by :func:`~hocnet.tracking.kalman.gate` on
  the mode-matched innovations, hypothesis weights = likelihood ratios of the PD-aware IMM
  likelihood to the clutter density, i.e. ``exp`` of the score increments 24.42, usable with
  Stone Soup's ``GNNWith2DAssignment``), :func:`track_score` (the LLR of 24.41-24.43),
  :class:`IMMInitiator`, :class:`SPRTInitiator` (tentative tracks confirmed or dropped by Wald's
  SPRT on the score) and :class:`SPRTDeleter`.

Readings (the same as :mod:`hocnet.tracking.vsimm`; see there): 24.34-24.35 with the standard
mixing indices; 24.42 for a missed detection ``Delta L = ln Lambda_miss`` with
``Lambda_miss = sum_i mu_i(k|k-1) Lambda_i`` from 24.30-24.31 (``ln(1 - PD)`` without a stop
model); 24.43 ``L(0) = ln(lambda_nt / lambda_fa)`` by default (Blackman and Popoli 1999, section
6.2; ``initial_score="printed"`` keeps the chapter's ``ln(lambda_fa / (lambda_fa + lambda_nt))``);
Wald's bounds (:func:`~hocnet.tracking.sprt.sprt_thresholds`) ``ln lower = ln(beta / (1 -
alpha))`` and ``ln upper = ln((1 - beta) / alpha)`` with the deletion rule of
:mod:`hocnet.tracking.mht` (one rule for both): a tentative track is confirmed at ``L >= ln
upper`` and dropped at ``L <= ln lower``; a confirmed track is deleted at ``L <= max L - drop``
(our reading, Blackman and Popoli 1999 section 6.4; ``ln lower`` is not applied to it); defaults
``alpha = beta = 1e-3`` as the MHT (the reason is given there). The stop mode follows the
printed 24.31 (``Lambda_0 = delta``) only for a sensor with an MDV (a
:class:`GMTIMeasurementModel`); with another measurement model (video / UGS positions) it is
scored ``PD p(z | M0)`` (:func:`hocnet.tracking.imm.pd_mode_log_likelihoods`, our reading;
``IMMUpdater(stop_detectable=...)`` overrides).

Stone Soup is an optional dependency: importing :mod:`hocnet.tracking` never imports it; importing
this module without it raises :class:`ImportError` ("pip install stonesoup").

Examples:
    Our IMM with a stop model inside Stone Soup's own predict / update loop:

    >>> from datetime import datetime, timedelta
    >>> import numpy as np
    >>> from stonesoup.models.measurement.linear import LinearGaussian
    >>> from stonesoup.types.detection import Detection
    >>> from stonesoup.types.hypothesis import SingleHypothesis
    >>> from stonesoup.types.state import GaussianState
    >>> predictor = IMMPredictor(
    ...     transition_models=[StopModel(), ConstantVelocity2D(sigma_a=0.5)],
    ...     mode_transition=[[0.9, 0.1], [0.1, 0.9]],
    ... )
    >>> updater = IMMUpdater(  # positions from a GMTI: the MDV hides a stopped target (24.31)
    ...     measurement_model=LinearGaussian(4, (0, 2), np.eye(2)), pd=0.9, stop_mode=0,
    ...     stop_detectable=False,
    ... )
    >>> t0 = datetime(2024, 1, 1)
    >>> state = GaussianState([[0.0], [1.0], [0.0], [0.0]], np.eye(4), timestamp=t0)
    >>> for k in range(1, 4):
    ...     prediction = predictor.predict(state, timestamp=t0 + timedelta(seconds=k))
    ...     detection = Detection([[float(k)], [0.0]], timestamp=prediction.timestamp)
    ...     state = updater.update(SingleHypothesis(prediction, detection))
    >>> type(state).__name__, state.mode_probabilities.round(3).tolist()
    ('IMMStateUpdate', [0.0, 1.0])
"""

from __future__ import annotations

import datetime
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import torch

try:
    from stonesoup.base import Property
    from stonesoup.deleter.base import Deleter
    from stonesoup.hypothesiser.base import Hypothesiser
    from stonesoup.initiator.base import Initiator
    from stonesoup.models.base import GaussianModel, LinearModel, TimeVariantModel
    from stonesoup.models.measurement.base import MeasurementModel
    from stonesoup.models.transition.base import TransitionModel
    from stonesoup.models.transition.linear import LinearGaussianTransitionModel
    from stonesoup.predictor.base import Predictor
    from stonesoup.types.array import CovarianceMatrix, StateVector, StateVectors
    from stonesoup.types.detection import Detection, MissedDetection
    from stonesoup.types.hypothesis import SingleHypothesis, SingleProbabilityHypothesis
    from stonesoup.types.mixture import GaussianMixture
    from stonesoup.types.multihypothesis import MultipleHypothesis
    from stonesoup.types.numeric import Probability
    from stonesoup.types.prediction import GaussianMeasurementPrediction, Prediction
    from stonesoup.types.state import GaussianState, State, StateMutableSequence
    from stonesoup.types.track import Track
    from stonesoup.types.update import Update
    from stonesoup.updater.base import Updater
except ImportError as exc:  # pragma: no cover - exercised only without the optional dependency
    raise ImportError(
        "hocnet.tracking.stonesoup needs Stone Soup (an optional dependency): pip install stonesoup"
    ) from exc

from hocnet._check import check_choice, check_number
from hocnet.tracking.imm import (
    _pd_mode_ll,
    imm_combine,
    imm_mix,
    imm_mixing_probabilities,
    imm_mode_probabilities,
    imm_track_log_likelihood,
)
from hocnet.tracking.kalman import DTYPE, constant_velocity, ekf_update, gate, kalman_predict
from hocnet.tracking.oosm import _projection
from hocnet.tracking.road import (
    RoadNetwork,
    on_segment_probability,
    relaxed_road_noise_cov,
    road_constant_velocity,
    segment_constraint,
)
from hocnet.tracking.sensors import (
    GMTISensor,
    gmti_aekf_matrix,
    gmti_jacobian,
    gmti_measure,
)
from hocnet.tracking.sprt import sprt_thresholds
from hocnet.tracking.vsimm import follow_section, junction_transition

__all__ = [
    "ConstantVelocity2D",
    "GMTIMeasurementModel",
    "IMMHypothesiser",
    "IMMInitiator",
    "IMMPredictor",
    "IMMState",
    "IMMStatePrediction",
    "IMMStateUpdate",
    "IMMUpdater",
    "RoadConstrainedCV",
    "SPRTDeleter",
    "SPRTInitiator",
    "StopModel",
    "gmti_detection",
    "track_score",
]


# ------------------------------------------------------------------------------------------
# numpy (Stone Soup) <-> torch (our core)
# ------------------------------------------------------------------------------------------


def _torch(a: Any) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=DTYPE)


def _numpy(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float64, copy=True)


def _seconds(time_interval: Any) -> float:
    """Stone Soup's ``time_interval`` (timedelta, or a number of s) in s."""
    if time_interval is None:
        raise ValueError(
            "`time_interval`: expected a datetime.timedelta (states need timestamps), got None"
        )
    if isinstance(time_interval, datetime.timedelta):
        return time_interval.total_seconds()
    return check_number("time_interval", time_interval)


# ------------------------------------------------------------------------------------------
# Transition models
# ------------------------------------------------------------------------------------------


class StopModel(LinearGaussianTransitionModel, TimeVariantModel):
    """Stop model M0 ([PD] 24.4.2): ``F0 = diag(1, 0, 1, 0)``, ``Q0 = 0``, state ``[x, vx, y, vy]``.

    Our reading of "stop model" (see :func:`hocnet.tracking.kalman.stop_model`). With ``p0`` /
    ``p1`` (or ``network``) the stopped target is on a road and :class:`IMMUpdater` with
    ``project=True`` projects it on the segment like the road modes.

    Examples:
        >>> StopModel().matrix().diagonal().tolist()
        [1.0, 0.0, 1.0, 0.0]
    """

    p0: Sequence[float] = Property(default=None, doc="Road segment start (x, y), m, or None.")
    p1: Sequence[float] = Property(default=None, doc="Road segment end (x, y), m, or None.")
    network: RoadNetwork = Property(
        default=None, doc="Road network: the segment nearest to the state is used."
    )

    @property
    def ndim_state(self) -> int:
        """4."""
        return 4

    def matrix(self, time_interval: Any = None, **kwargs: Any) -> np.ndarray:
        """``F0 (4, 4)``."""
        return np.diag([1.0, 0.0, 1.0, 0.0])

    def covar(self, time_interval: Any = None, **kwargs: Any) -> CovarianceMatrix:
        """``Q0 = 0 (4, 4)``."""
        return CovarianceMatrix(np.zeros((4, 4)))

    def constraint(
        self, state: Any, segment: int | None = None
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(D, L)`` of the road segment at ``state`` (24.3-24.4), or ``None`` off-road.

        With ``network``: the network segment ``segment`` (the mode's active segment of the
        prediction, :attr:`IMMState.mode_segments`) or, if ``None`` / ``-1``, the nearest one.
        """
        return _segment_constraint(self, state, segment)

    def active_segment(
        self, prior: Any, time_interval: Any = None, segment: int | None = None, **kwargs: Any
    ) -> int:
        """Network segment of the stopped target: the nearest to ``prior``, or ``-1``."""
        if self.network is None:
            return -1
        x = _torch(prior.state_vector).reshape(-1)
        return int(self.network.locate(x[[0, 2]]).segment)


class ConstantVelocity2D(LinearGaussianTransitionModel, TimeVariantModel):
    """2-D constant velocity with discrete white-noise acceleration (:func:`constant_velocity`).

    ``F = blockdiag([[1, dt], [0, 1]] x 2)``, ``Q = sigma_a^2 Gamma Gamma'`` for
    ``[x, vx, y, vy]`` ([PD] 24.5 with an isotropic noise; the chapter's M1 off-road). Stone
    Soup's ``ConstantVelocity`` pair models continuous white noise instead (another ``Q``).

    Examples:
        >>> from datetime import timedelta
        >>> Q = ConstantVelocity2D(sigma_a=2.0).covar(time_interval=timedelta(seconds=1))
        >>> Q[0, :2].tolist()
        [1.0, 2.0]
    """

    sigma_a: float = Property(doc="Acceleration noise standard deviation, m/s^2.")

    @property
    def ndim_state(self) -> int:
        """4."""
        return 4

    def matrix(self, time_interval: Any = None, **kwargs: Any) -> np.ndarray:
        """``F (4, 4)`` over ``time_interval``."""
        return _numpy(constant_velocity(_seconds(time_interval), self.sigma_a)[0])

    def covar(self, time_interval: Any = None, **kwargs: Any) -> CovarianceMatrix:
        """``Q (4, 4)`` over ``time_interval``."""
        return CovarianceMatrix(_numpy(constant_velocity(_seconds(time_interval), self.sigma_a)[1]))


def _segment_of(
    model: Any, state: Any, segment: int | None = None
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Endpoints ``(p0, p1)`` of the model's segment (``p0`` / ``p1``, or a network segment).

    The network segment is ``segment`` (``>= 0``) or the one nearest to ``state``.
    """
    if model.network is not None:
        if segment is None or segment < 0:
            x = _torch(state.state_vector).reshape(-1)
            segment = model.network.locate(x[[0, 2]]).segment
        return model.network.p0[segment], model.network.p1[segment]
    if model.p0 is None or model.p1 is None:
        return None
    return _torch(model.p0).reshape(2), _torch(model.p1).reshape(2)


def _segment_constraint(
    model: Any, state: Any, segment: int | None = None
) -> tuple[torch.Tensor, torch.Tensor] | None:
    seg = _segment_of(model, state, segment)
    return None if seg is None else segment_constraint(*seg)


class RoadConstrainedCV(LinearGaussianTransitionModel, TimeVariantModel):
    """Constant velocity on a road segment, [PD] eq. 24.2-24.8, relaxed near its ends (24.9-24.12).

    ``F`` is the constant-velocity transition and ``Q = Gamma R_theta diag(s_along^2, q)
    R_theta' Gamma'`` (:func:`~hocnet.tracking.road.road_constant_velocity`). Without a prior
    (Stone Soup's ``KalmanPredictor`` passes none to ``covar``) or with ``relax=False``,
    ``q = s_across^2``; given ``prior=`` (as :class:`IMMPredictor` does), ``q = s_across^2 P{e_s}
    + s_along^2 (1 - P{e_s})`` with the on-segment probability ``P{e_s}`` (24.11) of the
    prediction ``F x`` with covariance ``F P F' + Q_unrelaxed`` (the relaxation of
    :mod:`hocnet.tracking.vsimm`). The road is the segment ``p0 -> p1`` or, with ``network``, the
    segment nearest to the predicted position (the variable structure of 24.4.3 without the
    junction hypotheses). :meth:`constraint` gives ``D x = L`` (24.3-24.4) for the projection.

    **Bends and junctions** (``network`` with ``junction="rotate"``, the default; the same as
    ``VSIMMConfig(junction="rotate")``, our reading of ``F_{s,i}`` of 24.5): the active segment
    is :func:`~hocnet.tracking.vsimm.follow_section` of the segment before the prediction and the
    nearest one (so a bend of 90 degrees or more inside one road section is followed too), and a
    prediction past the node ahead is carried onto the new segment by
    :func:`~hocnet.tracking.vsimm.junction_transition`, an affine map ``x -> T x + b``: the
    prediction is ``T F x + b`` (:meth:`function`), its matrix ``T F`` (:meth:`matrix` with
    ``prior=``) and ``P{e_s}`` is evaluated at the carried prediction with ``T F P F' T' +
    Q_unrelaxed``, exactly as :func:`~hocnet.tracking.vsimm.vsimm_predict`. The model has no
    memory: the segment before the prediction is the keyword ``segment=`` of :meth:`function`,
    :meth:`matrix`, :meth:`covar` and :meth:`active_segment` (:class:`IMMPredictor` passes the
    mode's entry of :attr:`IMMState.mode_segments` and stores the new one in its prediction) or,
    without it, the segment nearest to the prior. The road is the whole network (no section
    hypotheses, unlike the VS-IMM rows). ``junction="none"``: the straight CV prediction on the
    nearest segment (the behaviour before the junction transition; ``VSIMMConfig(junction=
    "none")``).

    Limitation (Stone Soup's design): ``b`` is not a matrix, and Stone Soup's own
    ``KalmanPredictor`` computes the mean as ``matrix(time_interval) @ x`` without the prior
    and calls ``covar`` without it; its ``ExtendedKalmanPredictor`` uses :meth:`function` for
    the mean but ``matrix`` / ``covar`` without the prior too. A ``network`` model therefore
    needs :class:`IMMPredictor` (``covar`` without ``prior`` raises ``ValueError``, so a
    wrong prediction is never returned silently); a ``p0 -> p1`` model has one segment, no
    junction, and works with Stone Soup's predictors as before (``matrix`` = ``F``).

    Examples:
        >>> from datetime import timedelta
        >>> m = RoadConstrainedCV(p0=(0.0, 0.0), p1=(100.0, 0.0), sigma_along=0.8, sigma_across=0.4)
        >>> Q = m.covar(time_interval=timedelta(seconds=1))
        >>> float(Q[1, 1]), round(float(Q[3, 3]), 12)  # along (x) and across (y) velocity noise
        (0.6400000000000001, 0.16)

        Round a 90 degree bend: 40 m past the node the prediction is on the second segment.

        >>> from stonesoup.types.state import State
        >>> net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])
        >>> m = RoadConstrainedCV(network=net)
        >>> x = State([[90.0], [10.0], [0.0], [0.0]])
        >>> m.function(x, time_interval=timedelta(seconds=5)).ravel().round(9).tolist()
        [100.0, 0.0, 40.0, 10.0]
        >>> m.active_segment(x, time_interval=timedelta(seconds=5))
        1
    """

    p0: Sequence[float] = Property(default=None, doc="Segment start (x, y), m.")
    p1: Sequence[float] = Property(default=None, doc="Segment end (x, y), m.")
    sigma_along: float = Property(default=0.8, doc="Acceleration noise along the road, m/s^2.")
    sigma_across: float = Property(default=0.4, doc="Acceleration noise across the road, m/s^2.")
    relax: bool = Property(default=True, doc="Relax the across noise near the ends (24.9).")
    network: RoadNetwork = Property(
        default=None, doc="Road network (nearest segment); replaces p0 / p1."
    )
    junction: str = Property(
        default="rotate",
        doc="'rotate': follow bends and junctions (VSIMMConfig.junction); 'none': straight CV.",
    )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.network is None and (self.p0 is None or self.p1 is None):
            raise ValueError("`p0`: expected a road segment (p0, p1) or a network, got neither")
        check_number("sigma_along", self.sigma_along, low=0.0)
        check_number("sigma_across", self.sigma_across, low=0.0)
        check_choice("junction", self.junction, ("rotate", "none"))

    @property
    def ndim_state(self) -> int:
        """4."""
        return 4

    def _transition(
        self, x: torch.Tensor, dt: float, segment: int | None
    ) -> tuple[torch.Tensor | None, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Segments ``(N,)``, ``T (N, 4, 4)``, ``b (N, 4)``, ``F (4, 4)`` of a prediction.

        From states ``x (N, 4)`` over ``dt`` s and ``segment`` (the segment before the
        prediction; ``None`` / ``-1``: the nearest); the segments are ``None`` without a network.
        """
        F = constant_velocity(dt, 0.0)[0]
        N = x.shape[0]
        T = torch.eye(4, dtype=DTYPE).expand(N, 4, 4)
        b = torch.zeros(N, 4, dtype=DTYPE)
        if self.network is None:
            return None, T, b, F
        net = self.network
        x_pred = x @ F.T
        new = net.locate(x_pred).segment.reshape(N)
        if self.junction == "none":
            return new, T, b, F
        if segment is None or int(segment) < 0:
            old = net.locate(x).segment.reshape(N)
        else:
            old = torch.full((N,), int(segment), dtype=torch.int64)
        args = (x[:, None], x_pred[:, None])
        seg = follow_section(net, old[:, None], new[:, None], *args)
        T, b = junction_transition(net, old[:, None], seg, *args)
        return seg[:, 0], T[:, 0], b[:, 0], F

    def _prior_transition(
        self, prior: Any, time_interval: Any, segment: int | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int | None]:
        """``(x (4,), T F (4, 4), b (4,), segment)`` for one prior state."""
        x = _torch(prior.state_vector).reshape(1, 4)
        seg, T, b, F = self._transition(x, _seconds(time_interval), segment)
        return x[0], T[0] @ F, b[0], None if seg is None else int(seg[0])

    def active_segment(
        self, prior: Any, time_interval: Any = None, segment: int | None = None, **kwargs: Any
    ) -> int:
        """Network segment of the prediction from ``prior`` (``-1`` without a network).

        Args:
            prior: Gaussian state (the IMM's mixed estimate).
            time_interval: :class:`datetime.timedelta`.
            segment: the segment before the prediction, or ``None`` (the nearest to ``prior``).
            **kwargs: ignored.
        """
        seg = self._prior_transition(prior, time_interval, segment)[3]
        return -1 if seg is None else seg

    def matrix(
        self,
        time_interval: Any = None,
        prior: Any = None,
        segment: int | None = None,
        **kwargs: Any,
    ) -> np.ndarray:
        """``F (4, 4)``; with ``prior`` (and a network) ``T F``, ``T`` the junction rotation."""
        if prior is None or self.network is None:
            return _numpy(constant_velocity(_seconds(time_interval), 0.0)[0])
        return _numpy(self._prior_transition(prior, time_interval, segment)[1])

    def function(self, state: Any, noise: Any = False, **kwargs: Any) -> Any:
        """``T F x + b`` for each column of ``state.state_vector`` (``F x`` without a network).

        Args:
            state: Stone Soup state, ``state_vector`` ``(4, 1)`` or ``StateVectors (4, N)``.
            noise: as Stone Soup (``True``: a sample of :meth:`covar`, which with a network
                needs ``prior=`` in ``kwargs``).
            **kwargs: ``time_interval`` (:class:`datetime.timedelta`), optional ``segment``.
        """
        if self.network is None or self.junction == "none":
            kw = {k: v for k, v in kwargs.items() if k != "segment"}
            return super().function(state, noise=noise, **kw)
        sv = state.state_vector
        x = _torch(sv).reshape(4, -1).T
        _, T, b, F = self._transition(
            x, _seconds(kwargs.get("time_interval")), kwargs.get("segment")
        )
        mean = (T @ (F @ x.unsqueeze(-1))).squeeze(-1) + b
        out = (StateVectors if isinstance(sv, StateVectors) else StateVector)(_numpy(mean.T))
        if isinstance(noise, bool) or noise is None:
            noise = self.rvs(num_samples=x.shape[0], **kwargs) if noise else 0
        return out + noise

    def covar(
        self,
        time_interval: Any = None,
        prior: Any = None,
        segment: int | None = None,
        **kwargs: Any,
    ) -> CovarianceMatrix:
        """``Q (4, 4)`` over ``time_interval``, relaxed (24.9-24.12) when ``prior`` is given.

        Args:
            time_interval: :class:`datetime.timedelta`.
            prior: optional Gaussian state (the IMM's mixed estimate) the model predicts from;
                it selects the network segment and gives ``P{e_s}`` (at the prediction carried
                past a junction, ``T F x + b``, with ``T F P F' T' + Q_unrelaxed``).
            segment: network segment before the prediction, or ``None`` (the nearest to
                ``prior``).
            **kwargs: ignored (Stone Soup passes its own keywords).

        Raises:
            ValueError: a ``network`` model without ``prior``.
        """
        dt = _seconds(time_interval)
        if prior is None:
            if self.network is not None:
                raise ValueError("`prior`: expected the prior state to choose the network segment")
            p0, p1 = _torch(self.p0).reshape(2), _torch(self.p1).reshape(2)
            return CovarianceMatrix(_numpy(self._q(dt, p0, p1, None)))
        x, F, b, seg = self._prior_transition(prior, time_interval, segment)
        x_pred = F @ x + b
        p0, p1 = _segment_of(self, State(StateVector(_numpy(x_pred))), seg)
        if not self.relax:
            return CovarianceMatrix(_numpy(self._q(dt, p0, p1, None)))
        P = _torch(prior.covar)
        P_tmp = F @ P @ F.T + self._q(dt, p0, p1, None)
        p_on = on_segment_probability(x_pred, P_tmp, p0, p1)
        return CovarianceMatrix(_numpy(self._q(dt, p0, p1, p_on)))

    def _q(
        self, dt: float, p0: torch.Tensor, p1: torch.Tensor, p_on: torch.Tensor | None
    ) -> torch.Tensor:
        if p_on is None:
            return road_constant_velocity(dt, p0, p1, self.sigma_along, self.sigma_across)[1]
        cov = relaxed_road_noise_cov(p0, p1, self.sigma_along, self.sigma_across, p_on)
        return constant_velocity(dt, 0.0, acceleration_cov=cov)[1]

    def constraint(
        self, state: Any, segment: int | None = None
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(D (2, 4), L (2,))`` of the segment at ``state`` (eq. 24.3-24.4).

        With ``network``: segment ``segment`` (the mode's active segment of the prediction,
        :attr:`IMMState.mode_segments`) or, if ``None`` / ``-1``, the nearest one.
        """
        return _segment_constraint(self, state, segment)


# ------------------------------------------------------------------------------------------
# State types
# ------------------------------------------------------------------------------------------


class IMMState(GaussianState):
    """Gaussian state of an IMM: the combined estimate plus the ``r`` mode-matched estimates.

    ``state_vector (n, 1)`` and ``covar (n, n)`` are the combination (24.37 and its covariance)
    of ``mode_state_vectors (r, n)``, ``mode_covars (r, n, n)`` with ``mode_probabilities (r,)``.
    ``mode_segments (r,)`` (int64, optional) is the active road-network segment of each mode
    (``-1``: none; set by :class:`IMMPredictor` from the models' ``active_segment``, kept by
    :class:`IMMUpdater`; the ``segment`` of :class:`~hocnet.tracking.vsimm.VSIMMState`): the
    segment a road mode's next prediction starts from (:class:`RoadConstrainedCV`) and the one
    its update is projected on. Build it with :meth:`from_modes`.
    """

    mode_state_vectors: np.ndarray = Property(default=None, doc="(r, n) mode-matched means.")
    mode_covars: np.ndarray = Property(default=None, doc="(r, n, n) mode-matched covariances.")
    mode_probabilities: np.ndarray = Property(default=None, doc="(r,) mode probabilities.")
    mode_segments: np.ndarray = Property(
        default=None, doc="(r,) int64 active network segment of each mode (-1: none), or None."
    )
    log_likelihood: float = Property(
        default=None,
        doc="ln Lambda (24.32) of the update (or missed detection) that produced the state.",
    )

    @classmethod
    def from_modes(
        cls, mu: Any, x: Any, P: Any, timestamp: datetime.datetime | None = None, **kwargs: Any
    ) -> IMMState:
        """State from mode probabilities ``(r,)``, means ``(r, n)`` and covariances ``(r, n, n)``.

        Examples:
            >>> s = IMMState.from_modes([0.5, 0.5], [[0.0], [2.0]], [[[0.0]], [[0.0]]])
            >>> float(s.state_vector[0, 0]), float(s.covar[0, 0])
            (1.0, 1.0)
        """
        mu_t, x_t, P_t = _torch(mu), _torch(x), _torch(P)
        if kwargs.get("mode_segments") is not None:
            seg = np.asarray(kwargs["mode_segments"], dtype=np.int64).reshape(-1)
            if seg.shape != tuple(mu_t.shape):
                raise ValueError(
                    f"`mode_segments`: expected shape {tuple(mu_t.shape)}, got {seg.shape}"
                )
            kwargs["mode_segments"] = seg
        xc, Pc = imm_combine(mu_t[None], x_t[None], P_t[None])
        return cls(
            state_vector=StateVector(_numpy(xc[0])),
            covar=CovarianceMatrix(_numpy(Pc[0])),
            timestamp=timestamp,
            mode_state_vectors=_numpy(x_t),
            mode_covars=_numpy(P_t),
            mode_probabilities=_numpy(mu_t),
            **kwargs,
        )

    @property
    def num_modes(self) -> int:
        """``r``."""
        return len(self.mode_probabilities)

    def to_mixture(self) -> Any:
        """The modes as a Stone Soup ``GaussianMixture`` (weights = mode probabilities)."""
        from stonesoup.types.state import WeightedGaussianState

        return GaussianMixture(
            [
                WeightedGaussianState(
                    StateVector(self.mode_state_vectors[i]),
                    CovarianceMatrix(self.mode_covars[i]),
                    timestamp=self.timestamp,
                    weight=Probability(float(self.mode_probabilities[i])),
                )
                for i in range(self.num_modes)
            ]
        )


class IMMStatePrediction(Prediction, IMMState):
    """Predicted IMM state: modes ``x_j(k|k-1)``, ``P_j(k|k-1)`` and ``mu_j(k|k-1)`` (24.33).

    A missed-detection state (``log_likelihood`` set; mode probabilities updated by 24.30-24.31,
    means and covariances the predictions) has this type too.
    """

    transition_models: Sequence[Any] = Property(
        default=None, doc="The mode transition models used (for the road projection)."
    )


class IMMStateUpdate(Update, IMMState):
    """Updated IMM state (24.36-24.37), with ``log_likelihood`` = ``ln Lambda`` (24.32)."""


def _as_imm(state: Any, mu0: np.ndarray | None) -> IMMState:
    if isinstance(state, StateMutableSequence):
        state = state.state
    if isinstance(state, IMMState) and state.mode_probabilities is not None:
        return state
    if isinstance(state, GaussianMixture):
        # one component per mode, weights = mode probabilities (the form of to_mixture)
        if len(state) == 0:
            raise ValueError("`prior`: expected a GaussianMixture with one component per mode")
        w = np.array([float(c.weight) for c in state.components])
        if not np.all(np.isfinite(w)) or w.sum() <= 0 or (w < 0).any():
            raise ValueError(f"`prior`: expected non-negative mixture weights, got {w.tolist()}")
        x = np.stack([np.asarray(c.state_vector, float).ravel() for c in state.components])
        P = np.stack([np.asarray(c.covar, float) for c in state.components])
        return IMMState.from_modes(w / w.sum(), x, P, timestamp=state.timestamp)
    if not isinstance(state, GaussianState):
        raise TypeError(
            f"`prior`: expected an IMMState or a GaussianState, got {type(state).__name__}"
        )
    if mu0 is None:
        raise ValueError(
            "`initial_mode_probabilities`: expected mode probabilities to start an IMM from a "
            "GaussianState, got None"
        )
    r = len(mu0)
    x = np.repeat(np.asarray(state.state_vector, float).reshape(1, -1), r, 0)
    P = np.repeat(np.asarray(state.covar, float)[None], r, 0)
    return IMMState.from_modes(mu0, x, P, timestamp=state.timestamp)


# ------------------------------------------------------------------------------------------
# Predictor and updater
# ------------------------------------------------------------------------------------------


class IMMPredictor(Predictor):
    """IMM prediction (mixing 24.33-24.35, mode-matched Kalman prediction), a Stone Soup predictor.

    ``predict(prior, timestamp)`` takes an :class:`IMMState` (or a ``Track`` of them; a
    ``GaussianMixture`` with one component per mode, weights = mode probabilities; or a plain
    ``GaussianState``, which starts every mode with ``initial_mode_probabilities``) and
    returns an :class:`IMMStatePrediction`. Mode ``j`` is predicted with
    ``transition_models[j]``: ``F = matrix(time_interval=dt, prior=mixed_j)`` (a linear model;
    otherwise its ``jacobian`` and ``function``), ``Q = covar(time_interval=dt, prior=mixed_j)``.
    A road model (one with ``active_segment``: :class:`RoadConstrainedCV`, :class:`StopModel`)
    also gets ``segment=`` the mode's entry of the prior's ``mode_segments`` (``None`` if
    absent), its mean is ``function(mixed_j, ...)`` (``T F x + b`` past a junction) and its
    ``active_segment`` goes to the prediction's ``mode_segments`` (``-1`` for other models).
    With :class:`StopModel` / :class:`RoadConstrainedCV` on a network this is
    :func:`~hocnet.tracking.vsimm.vsimm_predict` (its default ``junction="rotate"`` included).

    Args (Stone Soup properties, pass by keyword):
        transition_models: ``r`` transition models (Stone Soup ``TransitionModel`` s, e.g.
            :class:`StopModel`, :class:`ConstantVelocity2D`, :class:`RoadConstrainedCV`).
        mode_transition: ``(r, r)`` ``P(i -> j)``, rows summing to 1 (our convention,
            :mod:`hocnet.tracking.imm`).
        initial_mode_probabilities: ``(r,)`` for Gaussian priors (default uniform).

    Raises:
        ValueError: mismatched sizes, states without timestamps.
    """

    transition_model: TransitionModel = Property(default=None, doc="Unused (see models).")
    transition_models: Sequence[TransitionModel] = Property(doc="The r mode transition models.")
    mode_transition: np.ndarray = Property(doc="(r, r) mode transition matrix, P(i -> j).")
    initial_mode_probabilities: np.ndarray = Property(
        default=None, doc="(r,) mode probabilities for a GaussianState prior (default uniform)."
    )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        r = len(self.transition_models)
        if r == 0:
            raise ValueError("`transition_models`: expected at least one model, got none")
        self.mode_transition = np.asarray(self.mode_transition, dtype=np.float64)
        if self.mode_transition.shape != (r, r):
            raise ValueError(
                f"`mode_transition`: expected shape ({r}, {r}) for {r} models, got "
                f"{self.mode_transition.shape}"
            )
        imm_mixing_probabilities(torch.full((1, r), 1.0 / r, dtype=DTYPE), self.mode_transition)
        if self.initial_mode_probabilities is None:
            self.initial_mode_probabilities = np.full(r, 1.0 / r)
        self.initial_mode_probabilities = np.asarray(self.initial_mode_probabilities, float)
        if self.initial_mode_probabilities.shape != (r,):
            raise ValueError(
                f"`initial_mode_probabilities`: expected shape ({r},), got "
                f"{self.initial_mode_probabilities.shape}"
            )

    def predict(self, prior: Any, timestamp: Any = None, **kwargs: Any) -> IMMStatePrediction:
        """Predict ``prior`` to ``timestamp`` (a :class:`datetime.datetime`).

        Returns:
            :class:`IMMStatePrediction` with ``r`` predicted modes and ``mu_j(k|k-1)``.
        """
        state = _as_imm(prior, self.initial_mode_probabilities)
        r = len(self.transition_models)
        if state.num_modes != r:
            raise ValueError(
                f"`prior`: expected {r} modes (one per transition model), got {state.num_modes}"
            )
        if timestamp is None or state.timestamp is None:
            raise ValueError(
                "`timestamp`: expected datetimes on the prior and the prediction, got None"
            )
        interval = timestamp - state.timestamp
        cbar, omega = imm_mixing_probabilities(
            _torch(state.mode_probabilities)[None], self.mode_transition
        )
        x0, P0 = imm_mix(
            _torch(state.mode_state_vectors)[None], _torch(state.mode_covars)[None], omega
        )
        Fs, Qs, fx, segs = [], [], {}, []
        old = state.mode_segments
        for j, model in enumerate(self.transition_models):
            mixed = GaussianState(
                StateVector(_numpy(x0[0, j])), CovarianceMatrix(_numpy(P0[0, j])), state.timestamp
            )
            road = hasattr(model, "active_segment")
            kw = {"segment": None if old is None else int(old[j])} if road else {}
            if isinstance(model, LinearModel):
                F = model.matrix(time_interval=interval, prior=mixed, **kw)
            else:
                F = model.jacobian(mixed, time_interval=interval, **kw)
            if road or not isinstance(model, LinearModel):
                fx[j] = np.asarray(
                    model.function(mixed, time_interval=interval, **kw), float
                ).ravel()
            segs.append(model.active_segment(mixed, time_interval=interval, **kw) if road else -1)
            Fs.append(np.asarray(F, float))
            Qs.append(np.asarray(model.covar(time_interval=interval, prior=mixed, **kw), float))
        x_pred, P_pred = kalman_predict(x0, P0, _torch(np.stack(Fs)), _torch(np.stack(Qs)))
        for j, v in fx.items():
            x_pred[0, j] = _torch(v)
        return IMMStatePrediction.from_modes(
            cbar[0],
            x_pred[0],
            P_pred[0],
            timestamp=timestamp,
            prior=prior,
            transition_models=self.transition_models,
            mode_segments=segs,
        )


class IMMUpdater(Updater):
    """IMM update as a Stone Soup updater: mode-matched (E)KF updates, PD-aware likelihoods.

    ``update(hypothesis)`` with a detection: every mode ``j`` is updated by
    :func:`~hocnet.tracking.kalman.ekf_update` with ``H_j`` the measurement model's ``matrix()``
    (linear) or ``jacobian`` at ``x_j(k|k-1)`` and ``h(x_j)`` its ``function``; the mode
    likelihoods are Gaussian (24.29; ``pd=None``) or PD-aware with the stop model (24.30-24.31);
    then 24.36 and 24.37. With a missed detection (``MissedDetection``, needs ``pd``) the means
    and covariances stay the predictions and the mode probabilities follow 24.30-24.31 (the stop
    mode explains a miss); the result is then an :class:`IMMStatePrediction`. With
    ``project=True`` every mode whose transition model has a road (``constraint``) is projected
    on it after the update (24.14-24.16; a pseudo-inverse for a singular ``D P D'``, e.g. the
    stop mode, as in :mod:`hocnet.tracking.vsimm`): on the prediction's ``mode_segments`` entry
    when set (the active segment, as :func:`~hocnet.tracking.vsimm.vsimm_update`), else on the
    segment nearest to the mode's prediction. The result keeps the prediction's
    ``mode_segments``.

    Args (Stone Soup properties, pass by keyword):
        measurement_model: default measurement model (a detection's own model wins).
        pd: detection probability, or ``None`` for the plain IMM (24.29).
        stop_mode: index of M0 among the modes (with ``pd``), or ``None``.
        project: project road modes on their segments.
        use_joseph_cov: Joseph-form covariance update (the default, as ``imm_step``).
        stop_detectable: whether the sensor sees stopped targets (the stop mode is then scored
            as 24.30 instead of 24.31); ``None`` (default): ``False`` for a
            :class:`GMTIMeasurementModel` (MDV clutter notch), ``True`` for any other model.
        detection_probability: optional per-mode ``PD_i`` from the predicted modes, a callable
            ``(x (r, n), P (r, n, n)) -> (r,)``, e.g.
            :meth:`~hocnet.tracking.sensors.GMTISensor.expected_detection_probability` (the MDV
            clutter notch; our reading, as ``use_mdv`` of :mod:`hocnet.tracking.vsimm`), floored
            at 1e-12; it replaces ``pd`` in 24.30.
    """

    measurement_model: MeasurementModel = Property(default=None, doc="Measurement model.")
    pd: float = Property(default=None, doc="Detection probability (24.30), or None.")
    stop_mode: int = Property(default=None, doc="Index of the stop model M0, or None.")
    project: bool = Property(default=False, doc="Project road modes on their segments.")
    use_joseph_cov: bool = Property(default=True, doc="Joseph-form covariance update.")
    detection_probability: Any = Property(
        default=None,
        doc="Per-mode PD: callable (x (r, n), P (r, n, n)) -> (r,); overrides pd.",
    )
    stop_detectable: bool = Property(
        default=None, doc="Sensor sees stopped targets; None: not for a GMTI model, else yes."
    )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.pd is not None:
            check_number("pd", self.pd, low=0.0, high=1.0, low_inclusive=False)

    @property
    def has_pd(self) -> bool:
        """Whether missed detections can be scored (``pd`` or ``detection_probability`` set)."""
        return self.pd is not None or self.detection_probability is not None

    def _sees_stop(self, model: Any) -> bool:
        if self.stop_detectable is not None:
            return bool(self.stop_detectable)
        model = self.measurement_model if model is None else model
        return not isinstance(model, GMTIMeasurementModel)

    def _mode_log_likelihoods(
        self,
        ll: torch.Tensor,
        detected: bool,
        x: torch.Tensor,
        P: torch.Tensor,
        model: Any = None,
    ) -> torch.Tensor:
        """``log Lambda_i`` ``(1, r)``: 24.29 (no PD), or 24.30-24.31 (scalar or per-mode PD)."""
        det = torch.full((1,), detected, dtype=torch.bool)
        if self.detection_probability is None:
            if self.pd is None:
                return ll
            pd = torch.tensor(float(self.pd), dtype=DTYPE)
        else:
            pd = torch.as_tensor(self.detection_probability(x, P), dtype=DTYPE).reshape(1, -1)
            if pd.shape != ll.shape:
                raise ValueError(
                    f"`detection_probability`: expected {ll.shape[-1]} mode values, "
                    f"got {pd.shape[-1]}"
                )
            pd = pd.clamp(1e-12, 1.0)
        is_stop = None if self.stop_mode is None else torch.arange(ll.shape[-1]) == self.stop_mode
        return _pd_mode_ll(ll, det, pd, is_stop, self._sees_stop(model))

    def _linearise(
        self, pred: IMMState, model: Any, measurement: Any | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Per-mode ``h(x_j) (r, m)``, ``H`` (``(m, n)`` or ``(r, m, n)``), ``R (m, m)``, ``nu``."""
        r = pred.num_modes
        hx, Hs, nus = [], [], []
        linear = isinstance(model, LinearModel)
        for j in range(r):
            sj = State(StateVector(pred.mode_state_vectors[j]), timestamp=pred.timestamp)
            h = model.function(sj)
            hx.append(np.asarray(h, float).ravel())
            Hs.append(np.asarray(model.matrix() if linear else model.jacobian(sj), float))
            if measurement is not None:
                # innovation in Stone Soup's types (wraps angles for bearing models)
                nus.append(np.asarray(measurement.state_vector - h, float).ravel())
        H = _torch(Hs[0]) if linear else _torch(np.stack(Hs))
        R = _torch(model.covar())
        nu = _torch(np.stack(nus)) if nus else None
        return _torch(np.stack(hx)), H, R, nu

    def predict_measurement(
        self,
        predicted_state: Any,
        measurement_model: Any = None,
        measurement_noise: bool = True,
        **kwargs: Any,
    ) -> GaussianMeasurementPrediction:
        """Moment-matched measurement prediction of the IMM prediction.

        ``z = sum_j mu_j h(x_j)``, ``S = sum_j mu_j [H_j P_j H_j' (+ R) + (z_j - z)(z_j - z)']``
        and the cross covariance ``sum_j mu_j [P_j H_j' + (x_j - x)(z_j - z)']`` with
        ``mu_j = mu_j(k|k-1)``. A plain ``GaussianState`` is treated as one mode.
        """
        model = self._check_measurement_model(measurement_model)
        pred = predicted_state
        if not (isinstance(pred, IMMState) and pred.mode_probabilities is not None):
            pred = _as_imm(pred, np.ones(1))
        hx, H, R, _ = self._linearise(pred, model, None)
        mu = _torch(pred.mode_probabilities)
        x = _torch(pred.mode_state_vectors)
        P = _torch(pred.mode_covars)
        Hr = H.expand(len(mu), *H.shape[-2:])
        S = Hr @ P @ Hr.transpose(-1, -2)
        if measurement_noise:
            S = S + R
        zc = mu @ hx
        dz = hx - zc
        xc = mu @ x
        dx = x - xc
        Sc = torch.einsum("j,jab->ab", mu, S + dz[:, :, None] * dz[:, None, :])
        C = torch.einsum(
            "j,jab->ab", mu, P @ Hr.transpose(-1, -2) + dx[:, :, None] * dz[:, None, :]
        )
        return GaussianMeasurementPrediction(
            StateVector(_numpy(zc)),
            CovarianceMatrix(_numpy(0.5 * (Sc + Sc.T))),
            timestamp=pred.timestamp,
            cross_covar=_numpy(C),
        )

    def update(self, hypothesis: Any, **kwargs: Any) -> IMMStateUpdate | IMMStatePrediction:
        """Update the hypothesis' :class:`IMMStatePrediction` with its detection (or a miss).

        Returns:
            :class:`IMMStateUpdate` (detection) or :class:`IMMStatePrediction` (missed
            detection), with ``log_likelihood`` = ``ln Lambda`` (24.32).

        Raises:
            TypeError: the prediction is not an IMM prediction.
            ValueError: a missed detection without ``pd``; all modes with zero likelihood.
        """
        pred = hypothesis.prediction
        if not isinstance(pred, IMMState) or pred.mode_probabilities is None:
            raise TypeError(
                "`hypothesis`: expected an IMMStatePrediction (from IMMPredictor), got "
                f"{type(pred).__name__}"
            )
        cbar = _torch(pred.mode_probabilities)[None]
        x_pred = _torch(pred.mode_state_vectors)[None]
        P_pred = _torch(pred.mode_covars)[None]
        r = pred.num_modes
        if not hypothesis:
            if self.pd is None and self.detection_probability is None:
                raise ValueError(
                    "`pd`: expected a detection probability to process a missed detection, got None"
                )
            mode_ll = self._mode_log_likelihoods(
                torch.zeros(1, r, dtype=DTYPE), False, x_pred[0], P_pred[0]
            )
            return self._result(pred, cbar, mode_ll, x_pred, P_pred, None, hypothesis)
        measurement = hypothesis.measurement
        model = self._check_measurement_model(measurement.measurement_model)
        _, H, R, nu = self._linearise(pred, model, measurement)
        x_upd, P_upd, ll = ekf_update(
            x_pred, P_pred, nu[None], torch.zeros_like(nu)[None], H, R, joseph=self.use_joseph_cov
        )
        mode_ll = self._mode_log_likelihoods(ll, True, x_pred[0], P_pred[0], model)
        return self._result(pred, cbar, mode_ll, x_upd, P_upd, measurement, hypothesis)

    def _result(
        self,
        pred: IMMState,
        cbar: torch.Tensor,
        mode_ll: torch.Tensor,
        x: torch.Tensor,
        P: torch.Tensor,
        measurement: Any | None,
        hypothesis: Any,
    ) -> IMMStateUpdate | IMMStatePrediction:
        mu = imm_mode_probabilities(cbar, mode_ll)
        track_ll = float(imm_track_log_likelihood(mode_ll, cbar)[0])
        if self.project:
            x, P = self._project(pred, x, P)
        if measurement is None:
            return IMMStatePrediction.from_modes(
                mu[0],
                x[0],
                P[0],
                timestamp=pred.timestamp,
                log_likelihood=track_ll,
                prior=getattr(pred, "prior", None),
                transition_models=getattr(pred, "transition_models", None),
                mode_segments=pred.mode_segments,
            )
        return IMMStateUpdate.from_modes(
            mu[0],
            x[0],
            P[0],
            timestamp=measurement.timestamp,
            log_likelihood=track_ll,
            hypothesis=hypothesis,
            mode_segments=pred.mode_segments,
        )

    @staticmethod
    def _project(
        pred: IMMState, x: torch.Tensor, P: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        models = getattr(pred, "transition_models", None)
        if models is None:
            raise ValueError(
                "`project`: expected the prediction to carry its transition models (use "
                "IMMPredictor), got none"
            )
        x, P = x.clone(), P.clone()
        for j, model in enumerate(models):
            if not hasattr(model, "constraint"):
                continue
            mode_pred = State(StateVector(pred.mode_state_vectors[j]))
            segs = pred.mode_segments
            con = model.constraint(mode_pred, *(() if segs is None else (int(segs[j]),)))
            if con is None:
                continue
            D, L = con
            xs, A = _projection(x[0, j], P[0, j], D, L)
            Ps = A @ P[0, j] @ A.T
            x[0, j], P[0, j] = xs, 0.5 * (Ps + Ps.T)
        return x, P


# ------------------------------------------------------------------------------------------
# GMTI measurement model
# ------------------------------------------------------------------------------------------


class GMTIMeasurementModel(MeasurementModel, GaussianModel):
    """GMTI position + range-rate measurement (24.17-24.18) as a Stone Soup measurement model.

    ``h(x) = [x, y, rho_dot]`` with ``rho_dot = ((x - xc) vx + (y - yc) vy) / rho`` and the slant
    range ``rho`` (:func:`~hocnet.tracking.sensors.gmti_measure`); :meth:`jacobian` is the full
    EKF Jacobian (:func:`~hocnet.tracking.sensors.gmti_jacobian`), so Stone Soup's
    ``ExtendedKalmanUpdater`` works with it. With ``reference`` (a position, m) the model is the
    chapter's AEKF form (24.19-24.20): ``h(x) = H_mti x`` with the line of sight evaluated at
    ``reference`` (the reported position in the chapter; :func:`gmti_detection` sets it) and
    ``jacobian = H_mti``.

    Args (Stone Soup properties, pass by keyword):
        sensor_position: ``(xc, yc, zc)`` or ``(xc, yc)`` in m.
        noise_covar: ``R (3, 3)`` (m^2, m^2, (m/s)^2), e.g. from
            :meth:`~hocnet.tracking.sensors.GMTISensor.from_report`.
        reference: ``(x, y)`` of the AEKF linearisation, or ``None`` (EKF).
        ground: range-rate divided by the ground range (24.18 as printed, the default of
            :class:`~hocnet.tracking.sensors.GMTISensor` and of the scenario simulator) instead
            of the slant range (``False``, default here, backward compatible).
        ndim_state: 4; mapping: ``(0, 2)`` (the measured position components).

    Examples:
        >>> m = GMTIMeasurementModel(sensor_position=(0.0, 0.0, 0.0), noise_covar=np.eye(3))
        >>> from stonesoup.types.state import State
        >>> m.function(State([[3.0], [1.0], [4.0], [0.0]])).ravel().tolist()
        [3.0, 4.0, 0.6]
    """

    ndim_state: int = Property(default=4, doc="4: [x, vx, y, vy].")
    mapping: Sequence[int] = Property(default=(0, 2), doc="State indices of x and y.")
    sensor_position: Sequence[float] = Property(doc="(xc, yc, zc) in m.")
    noise_covar: CovarianceMatrix = Property(doc="R (3, 3).")
    reference: Sequence[float] = Property(default=None, doc="AEKF reference position, or None.")
    ground: bool = Property(
        default=False, doc="Range-rate over the ground range (24.18 as printed), not the slant one."
    )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.noise_covar = CovarianceMatrix(np.asarray(self.noise_covar, dtype=np.float64))
        if self.noise_covar.shape != (3, 3):
            raise ValueError(f"`noise_covar`: expected shape (3, 3), got {self.noise_covar.shape}")
        if self.ndim_state != 4:
            raise ValueError(f"`ndim_state`: expected 4 ([x, vx, y, vy]), got {self.ndim_state}")

    @property
    def ndim_meas(self) -> int:
        """3."""
        return 3

    def _states(self, state: Any) -> torch.Tensor:
        """``(N, 4)`` states from a State (vector ``(4, 1)`` or vectors ``(4, N)``)."""
        sv = state.state_vector if hasattr(state, "state_vector") else state
        return _torch(sv).reshape(4, -1).T

    def function(self, state: Any, noise: Any = False, **kwargs: Any) -> StateVector:
        """``h(x)`` ``(3, 1)`` (or ``(3, N)`` for ``StateVectors``), plus optional noise."""
        x = self._states(state)
        pos = _torch(self.sensor_position)
        if self.reference is None:
            z = gmti_measure(x, pos, ground=self.ground)
        else:
            H = gmti_aekf_matrix(_torch(self.reference).reshape(2), pos, ground=self.ground)
            z = x @ H.T
        out = _numpy(z.T)
        if isinstance(noise, bool) or noise is None:
            noise = self.rvs(num_samples=out.shape[1], **kwargs) if noise else 0
        out = out + noise
        return StateVector(out) if out.shape[1] == 1 else StateVectors(out)

    def jacobian(self, state: Any, **kwargs: Any) -> np.ndarray:
        """``(3, 4)`` Jacobian at ``state`` (full EKF), or the AEKF ``H_mti`` (24.20)."""
        x = self._states(state)[0]
        pos = _torch(self.sensor_position)
        if self.reference is None:
            return _numpy(gmti_jacobian(x, pos, ground=self.ground))
        return _numpy(gmti_aekf_matrix(_torch(self.reference).reshape(2), pos, ground=self.ground))

    def covar(self, **kwargs: Any) -> CovarianceMatrix:
        """``R (3, 3)``."""
        return self.noise_covar


def gmti_detection(
    sensor: GMTISensor,
    report: Any,
    timestamp: datetime.datetime,
    *,
    aekf: bool = True,
    metadata: dict | None = None,
) -> Any:
    """A Stone Soup ``Detection`` from a polar GMTI report ``(rho, azimuth, rho_dot)``.

    The measurement is ``z = [x, y, rho_dot]`` in the TCF with its ``R``
    (:meth:`~hocnet.tracking.sensors.GMTISensor.from_report`); the detection carries a
    :class:`GMTIMeasurementModel` (AEKF at the reported position when ``aekf``, our reading of
    24.20; the EKF otherwise).

    Args:
        sensor: the GMTI sensor.
        report: ``(3,)`` slant range (m), azimuth (rad), range-rate (m/s).
        timestamp: report time.
        aekf: linearise at the reported position (24.20) instead of the prediction.
        metadata: optional detection metadata.

    Examples:
        >>> from datetime import datetime
        >>> s = GMTISensor((0.0, 0.0, 0.0), 20.0, 0.0008, 1.0)
        >>> d = gmti_detection(s, [5000.0, 0.0, 3.0], datetime(2024, 1, 1))
        >>> d.state_vector.ravel().tolist()
        [5000.0, 0.0, 3.0]
    """
    z, R = sensor.from_report(report)
    if z.shape != (3,):
        raise ValueError(f"`report`: expected one report of shape (3,), got {tuple(z.shape)}")
    model = GMTIMeasurementModel(
        sensor_position=sensor.position,
        noise_covar=_numpy(R),
        reference=_numpy(z[:2]).tolist() if aekf else None,
        ground=getattr(sensor, "range_rate", "slant") == "ground",
    )
    return Detection(
        StateVector(_numpy(z)),
        timestamp=timestamp,
        measurement_model=model,
        metadata=metadata or {},
    )


# ------------------------------------------------------------------------------------------
# Hypothesiser, track score, initiators, deleter
# ------------------------------------------------------------------------------------------


class IMMHypothesiser(Hypothesiser):
    """Gated IMM hypotheses weighted by likelihood ratios (for Stone Soup's data associators).

    For a track: one :class:`IMMPredictor` prediction; the missed-detection hypothesis carries
    the missed-detection state (PD-aware mode probabilities, 24.30-24.31) as its ``prediction``,
    so that Stone Soup's ``MultiTargetTracker`` appends it, and has weight ``Lambda_miss``; a
    detection is gated in when its innovation passes :func:`~hocnet.tracking.kalman.gate`
    (``d^2 <= gate_threshold``) for at least one mode (gating convention: any mode, unlike the
    MHT's single test on the combined innovation), and has weight
    ``Lambda / lambda_fa`` (``exp`` of the score increment 24.42). The hypotheses are
    ``SingleProbabilityHypothesis`` (un-normalised), so ``GNNWith2DAssignment`` picks the
    assignment of highest summed score increments.

    Args (Stone Soup properties, pass by keyword):
        predictor: :class:`IMMPredictor`.
        updater: :class:`IMMUpdater` with ``pd`` set.
        false_alarm_density: ``lambda_fa`` per unit measurement volume (e.g. 1 / m^2).
        gate_threshold: gate on the squared Mahalanobis distance (e.g. a chi-square quantile).
    """

    predictor: IMMPredictor = Property(doc="IMM predictor.")
    updater: IMMUpdater = Property(doc="IMM updater (with pd).")
    false_alarm_density: float = Property(doc="Clutter density lambda_fa.")
    gate_threshold: float = Property(default=16.0, doc="Gate on the squared distance.")

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        check_number("false_alarm_density", self.false_alarm_density, low=0.0, low_inclusive=False)
        check_number("gate_threshold", self.gate_threshold, low=0.0, low_inclusive=False)
        if not self.updater.has_pd:
            raise ValueError("`updater`: expected an IMMUpdater with a detection probability pd")

    def hypothesise(
        self, track: Any, detections: Iterable[Any], timestamp: Any, **kwargs: Any
    ) -> MultipleHypothesis:
        """Missed-detection hypothesis plus one per gated detection (see the class docstring)."""
        prediction = self.predictor.predict(track, timestamp=timestamp)
        missed = self.updater.update(
            SingleHypothesis(prediction, MissedDetection(timestamp=timestamp))
        )
        hyps = [
            SingleProbabilityHypothesis(
                missed,
                MissedDetection(timestamp=timestamp),
                probability=Probability(missed.log_likelihood, log_value=True),
            )
        ]
        log_fa = math.log(self.false_alarm_density)
        x = _torch(prediction.mode_state_vectors)
        P = _torch(prediction.mode_covars)
        for detection in detections:
            model = self.updater._check_measurement_model(detection.measurement_model)
            _, H, R, nu = self.updater._linearise(prediction, model, detection)
            Hr = H.expand(len(x), *H.shape[-2:])
            S = Hr @ P @ Hr.transpose(-1, -2) + R
            if not bool(gate(nu, S, self.gate_threshold).any()):
                continue
            hyp = SingleHypothesis(prediction, detection)
            upd = self.updater.update(hyp)
            hyps.append(
                SingleProbabilityHypothesis(
                    prediction,
                    detection,
                    probability=Probability(upd.log_likelihood - log_fa, log_value=True),
                )
            )
        return MultipleHypothesis(hyps)


def _score_increments(
    track: Any, false_alarm_density: float, missed_pd: float | None
) -> list[float]:
    log_fa = math.log(false_alarm_density)
    log_miss = None if missed_pd is None else math.log1p(-missed_pd)
    out = []
    for state in list(track.states)[1:]:
        ll = getattr(state, "log_likelihood", None)
        if ll is None:
            out.append(0.0)
        elif isinstance(state, Update):
            out.append(ll - log_fa)
        else:
            out.append(ll if log_miss is None else log_miss)
    return out


def _initial_score(fa: float, nt: float, initial_score: str) -> float:
    check_choice("initial_score", initial_score, ("log_odds", "printed"))
    if initial_score == "log_odds":
        return math.log(nt / fa)
    return math.log(fa / (fa + nt))


def track_score(
    track: Any,
    false_alarm_density: float,
    new_target_density: float,
    *,
    initial_score: str = "log_odds",
    missed_pd: float | None = None,
    history: bool = False,
) -> float | list[float]:
    """LLR track score of a Stone Soup track of IMM states, [PD] eq. 24.41-24.43 (our reading).

    ``L(0)`` (24.43; ``"log_odds"``: ``ln(lambda_nt / lambda_fa)``, ``"printed"``:
    ``ln(lambda_fa / (lambda_fa + lambda_nt))``) for the first state, then per later state
    ``Delta L = ln Lambda - ln lambda_fa`` for an update (24.42) and ``ln Lambda_miss`` for a
    missed-detection state (24.30-24.32); states without ``log_likelihood`` add 0. With the stop
    model, ``Lambda_miss -> 1`` as the stop mode takes over, so misses stop lowering the score
    (a track born on a false alarm then lingers just above the deletion bound; measured in the
    tests); ``missed_pd`` scores every miss ``ln(1 - PD)`` instead (Blackman and Popoli's
    single-model increment; our option).

    Args:
        track: Stone Soup ``Track`` (states from :class:`IMMUpdater` / :class:`IMMHypothesiser`).
        false_alarm_density: ``lambda_fa > 0``.
        new_target_density: ``lambda_nt > 0``.
        initial_score: ``"log_odds"`` (default) or ``"printed"``.
        missed_pd: ``PD`` for the ``ln(1 - PD)`` miss increment, or ``None`` (``ln Lambda_miss``).
        history: return the score after every state instead of the last one.

    Examples:
        >>> from stonesoup.types.track import Track
        >>> track = Track([IMMState.from_modes([1.0], [[0.0]], [[[1.0]]])])
        >>> round(track_score(track, 1e-4, 1e-5), 6)
        -2.302585
    """
    fa = check_number("false_alarm_density", false_alarm_density, low=0.0, low_inclusive=False)
    nt = check_number("new_target_density", new_target_density, low=0.0, low_inclusive=False)
    if missed_pd is not None:
        check_number("missed_pd", missed_pd, low=0.0, high=1.0, high_inclusive=False)
    scores = [_initial_score(fa, nt, initial_score)]
    for d in _score_increments(track, fa, missed_pd):
        scores.append(scores[-1] + d)
    return scores if history else scores[-1]


class IMMInitiator(Initiator):
    """One-point initiation of IMM tracks from detections.

    The measured state components (the measurement model's ``mapping``, e.g. ``(0, 2)`` for
    positions; the first ``len(mapping)`` measurement entries) are set from the detection with
    their block of ``R``; the others keep ``prior_state``'s mean and covariance. Every mode
    starts at that state with ``mode_probabilities``.

    Args (Stone Soup properties, pass by keyword):
        prior_state: ``GaussianState (n,)`` (e.g. zero velocity with a large variance).
        mode_probabilities: ``(r,)``.
        measurement_model: default model (a detection's own model wins).
    """

    prior_state: GaussianState = Property(doc="Prior for the unmeasured components.")
    mode_probabilities: np.ndarray = Property(doc="(r,) initial mode probabilities.")
    measurement_model: MeasurementModel = Property(default=None, doc="Measurement model.")

    def initiate(self, detections: Iterable[Any], timestamp: Any, **kwargs: Any) -> set:
        """One new :class:`~stonesoup.types.track.Track` per detection."""
        tracks = set()
        mu = np.asarray(self.mode_probabilities, float)
        for det in detections:
            model = det.measurement_model or self.measurement_model
            if model is None:
                raise ValueError("`measurement_model`: expected a model on the detection or here")
            idx = list(model.mapping)
            z = np.asarray(det.state_vector, float).ravel()[: len(idx)]
            R = np.asarray(model.covar(), float)[: len(idx), : len(idx)]
            x = np.asarray(self.prior_state.state_vector, float).ravel().copy()
            P = np.asarray(self.prior_state.covar, float).copy()
            x[idx] = z
            P[idx, :] = 0.0
            P[:, idx] = 0.0
            P[np.ix_(idx, idx)] = R
            r = len(mu)
            state = IMMState.from_modes(
                mu, np.repeat(x[None], r, 0), np.repeat(P[None], r, 0), timestamp=det.timestamp
            )
            tracks.add(Track([state]))
        return tracks


class SPRTInitiator(Initiator):
    """Tentative tracks confirmed or dropped by Wald's SPRT on the LLR score (24.41-24.43).

    Each scan the tentative tracks are associated with the detections (``data_associator``,
    e.g. Stone Soup's ``GNNWith2DAssignment`` over an :class:`IMMHypothesiser`) and updated;
    a tentative track is released to the tracker when its score reaches ``ln upper =
    ln((1 - beta) / alpha)`` and dropped when it falls to ``ln lower = ln(beta / (1 - alpha))``
    (the deletion rule of :mod:`hocnet.tracking.mht`);
    every detection left over starts a tentative track (``initiator``, e.g.
    :class:`IMMInitiator`). The birth scan is not tested (one plot cannot be; our reading).

    Args (Stone Soup properties, pass by keyword):
        initiator: one-point initiator.
        data_associator: associator for the tentative tracks.
        updater: :class:`IMMUpdater`.
        false_alarm_density, new_target_density: ``lambda_fa``, ``lambda_nt``.
        alpha: probability of confirming a false track; beta: of dropping a true one.
        initial_score, missed_pd: see :func:`track_score`.
    """

    initiator: Initiator = Property(doc="One-point initiator (e.g. IMMInitiator).")
    data_associator: Any = Property(doc="Data associator for the tentative tracks.")
    updater: IMMUpdater = Property(doc="IMM updater.")
    false_alarm_density: float = Property(doc="lambda_fa.")
    new_target_density: float = Property(doc="lambda_nt.")
    alpha: float = Property(default=1e-3, doc="P(confirm a false track).")
    beta: float = Property(default=1e-3, doc="P(drop a true track).")
    initial_score: str = Property(default="log_odds", doc="'log_odds' or 'printed'.")
    missed_pd: float = Property(default=None, doc="Score misses ln(1 - PD) (see track_score).")

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.lower, self.upper = sprt_thresholds(self.alpha, self.beta)
        _initial_score(self.false_alarm_density, self.new_target_density, self.initial_score)
        self.holding_tracks: set = set()

    def _score(self, track: Any) -> float:
        return track_score(
            track,
            self.false_alarm_density,
            self.new_target_density,
            initial_score=self.initial_score,
            missed_pd=self.missed_pd,
        )

    def initiate(self, detections: Iterable[Any], timestamp: Any, **kwargs: Any) -> set:
        """Confirmed tracks of this scan (the others stay tentative or are dropped)."""
        detections = set(detections)
        confirmed, used = set(), set()
        if self.holding_tracks:
            assoc = self.data_associator.associate(self.holding_tracks, detections, timestamp)
            for track, hyp in assoc.items():
                if hyp:
                    track.append(self.updater.update(hyp))
                    used.add(hyp.measurement)
                else:
                    track.append(hyp.prediction)
                score = self._score(track)
                if score >= self.upper:
                    confirmed.add(track)
                elif score <= self.lower:
                    self.holding_tracks.discard(track)
            self.holding_tracks -= confirmed
        self.holding_tracks |= self.initiator.initiate(detections - used, timestamp)
        return confirmed


class SPRTDeleter(Deleter):
    """Delete confirmed tracks by their LLR score (24.41-24.43): ``drop`` below its maximum.

    The deletion rule of :mod:`hocnet.tracking.mht` for confirmed tracks: delete when ``L <=
    max L - drop``; ``drop`` defaults to ``ln(upper / lower)`` (Wald's bounds of
    :func:`~hocnet.tracking.sprt.sprt_thresholds`; our reading, Blackman and Popoli 1999
    section 6.4), so a track confirmed at ``ln upper`` goes at the latest at ``ln lower``.
    Before this rule was unified, ``L <= ln lower`` also deleted and the drop test was strict.

    Args (Stone Soup properties, pass by keyword):
        false_alarm_density, new_target_density, alpha, beta, initial_score, missed_pd: as
            :class:`SPRTInitiator`.
        drop: allowed fall of the score below its running maximum, or ``None``.

    Examples:
        >>> from stonesoup.types.track import Track
        >>> d = SPRTDeleter(false_alarm_density=1e-4, new_target_density=1e-5)
        >>> d.check_for_deletion(Track([IMMState.from_modes([1.0], [[0.0]], [[[1.0]]])]))
        False
    """

    false_alarm_density: float = Property(doc="lambda_fa.")
    new_target_density: float = Property(doc="lambda_nt.")
    alpha: float = Property(default=1e-3, doc="P(confirm a false track).")
    beta: float = Property(default=1e-3, doc="P(drop a true track).")
    drop: float = Property(default=None, doc="Allowed fall below the maximum score.")
    initial_score: str = Property(default="log_odds", doc="'log_odds' or 'printed'.")
    missed_pd: float = Property(default=None, doc="Score misses ln(1 - PD) (see track_score).")

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.lower, self.upper = sprt_thresholds(self.alpha, self.beta)
        if self.drop is None:
            self.drop = self.upper - self.lower
        check_number("drop", self.drop, low=0.0)

    def check_for_deletion(self, track: Any, **kwargs: Any) -> bool:
        """``True`` when the track's score history says delete."""
        scores = track_score(
            track,
            self.false_alarm_density,
            self.new_target_density,
            initial_score=self.initial_score,
            missed_pd=self.missed_pd,
            history=True,
        )
        if len(scores) == 1:
            return False
        return scores[-1] <= max(scores) - self.drop

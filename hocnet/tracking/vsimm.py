"""Variable-structure IMM on a road network (VS-IMMC, [PD] section 24.4), batched over rows.

A *row* is one (track, road-section hypothesis) pair; every function works on all rows of a scan
at once (``B`` rows, ``r`` modes, state ``[x, vx, y, vy]`` in m and m/s, float64):

- mode probabilities ``mu`` ``(B, r)``, mode-matched states ``x`` ``(B, r, 4)``, covariances
  ``P`` ``(B, r, 4, 4)``, the active segment of each mode ``segment`` ``(B, r)`` (``-1`` for an
  off-road mode), the section hypothesis ``section`` ``(B,)`` (``-1``: the whole network), the
  track id ``track`` ``(B,)`` and the section probability ``mu_section`` ``(B,)`` (24.38); the
  segment of each mode before its last step and the junction node it crossed then
  (``segment_prev``, ``junction_node`` ``(B, r)``, for the OOSM retrodiction across a junction).

**Mode set** (:class:`VSIMMConfig`): the stop model M0 (24.31; ``F0 = diag(1, 0, 1, 0)``,
``Q0 = 0``), ``r'`` road-constrained constant-velocity models ``M_i^s`` with along / across
acceleration deviations (24.5-24.8; the chapter's M1 0.05 / 0.05 and M2 0.8 / 0.4 m/s^2) and,
optionally, an unconstrained off-road constant-velocity model (our addition, "on-off road model"
of the abstract).

**Variable structure** (24.4.3, our reading): the chapter builds ``r + 1`` graphs whose nodes are
the constrained models ``M_s^i`` of the segments and activates, for each model, the node of the
segment where its *predicted* state lies. So in :func:`vsimm_predict` the mixed estimate of mode
``i`` is predicted with the constant-velocity ``F``, located on the segments of the row's section
(:meth:`~hocnet.tracking.road.RoadNetwork.locate`), and that segment ``s`` gives the directional
noise (24.6) relaxed near its ends (24.9-24.12 with the predicted ``P{e_s}``), the constraint of
the update, and the projection (24.14-24.16) of the updated mode estimate. Near a junction the
segments reachable within the predicted travel (:meth:`~hocnet.tracking.road.RoadNetwork.reachable`)
belong to several sections: :func:`vsimm_expand_sections` adds one row per new section (one IMM
per hypothesis ``h``), and :func:`vsimm_section_sprt` updates the section probabilities (24.38)
and runs Wald's SPRT (24.39-24.40) to keep one.

**Likelihoods** (24.29-24.32, by the one kernel of
:func:`hocnet.tracking.imm.pd_mode_log_likelihoods`): mode ``i`` moving: ``PD_i p(z | M_i)`` if
detected, ``1 - PD_i`` if not; stop: ``delta_{m_j, 0}`` for a sensor with an MDV (GMTI, the
printed 24.31), and like a moving mode for a sensor that sees stopped targets (video / UGS,
``stop_detectable``; our reading). ``PD_i`` is the sensor's ``PD`` (coverage-aware for video /
UGS) or, with the GMTI minimum detectable velocity (``use_mdv``), the expected ``PD`` of the
mode's predicted state (:meth:`~hocnet.tracking.sensors.GMTISensor.expected_detection_probability`;
our reading of the MDV), floored at 1e-12. The IMM equations are those of
:mod:`hocnet.tracking.imm` (mixing
24.33-24.35 with the standard indices, 24.36, 24.37).

**24.38** prints the sum over ``h_bar in {1, ..., N_k - 1}``; we read the subscript ``k - 1``
flattened by the OCR: the sum runs over the ``N_{k-1}`` hypotheses alive at ``k - 1`` (a newly
spawned hypothesis has ``mu = 0`` at ``k - 1``, so summing over the ``N_k`` current ones is the
same). ``Omega[h_bar, h]`` is the probability of moving from the road of ``h_bar`` to that of
``h`` (:func:`section_transition`, our choice of values).

**SPRT thresholds** (24.39-24.40; "given in [5, 20]"): Wald's (1947) bounds for the error
probabilities ``alpha`` (accepting a wrong section) and ``beta`` (rejecting the true one): the
upper bound ``(1 - beta) / alpha`` and the lower bound ``beta / (1 - alpha)`` (Wald names the
upper one ``A`` and the lower one ``B``; the chapter's 24.39 accepts ``h`` when
``mu_h / mu_h' >= B`` and 24.40 rejects when ``<= A``, letters swapped with respect to Wald's).
We write "upper" and "lower" everywhere: accept above the upper bound, reject below the lower
bound (:func:`hocnet.tracking.sprt.sprt_thresholds` returns ``(ln lower, ln upper)``). With
three or more hypotheses the printed 24.40 can stall; :func:`sprt_decide` ``reject="best"`` is
our option.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import torch

from hocnet._check import check_choice, check_number
from hocnet.tracking.imm import _combine, _mix, _mixing, _pd_mode_ll, imm_mixing_probabilities
from hocnet.tracking.kalman import DTYPE, _update, as_float64
from hocnet.tracking.oosm import (
    Retrodiction,
    _apply,
    _projection,
    _retrodict,
    check_oosm_time,
    oosm_too_old,
    pinv_atol,
    pinv_sym,
)
from hocnet.tracking.road import RoadNetwork, on_segment_probability_from_moments
from hocnet.tracking.sensors import check_measurements, stop_detectable
from hocnet.tracking.sprt import sprt_thresholds

__all__ = [
    "VSIMMAssociation",
    "VSIMMConfig",
    "VSIMMLagMemory",
    "VSIMMOOSMUpdate",
    "VSIMMPrediction",
    "VSIMMState",
    "VSIMMUpdate",
    "crossed_node",
    "follow_section",
    "junction_transition",
    "node_ahead",
    "section_probabilities",
    "section_transition",
    "sprt_decide",
    "vsimm_association_log_likelihood",
    "vsimm_expand_sections",
    "vsimm_init",
    "vsimm_lag_memory",
    "vsimm_lag_memory_step",
    "vsimm_oosm",
    "vsimm_predict",
    "vsimm_section_sprt",
    "vsimm_step",
    "vsimm_update",
]

_PD_FLOOR = 1e-12


def _mode_pd(sensor: Any, config: VSIMMConfig, x: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """``PD_i`` ``(B, r)`` of 24.30, floored at ``_PD_FLOOR``.

    The MDV-notch expected PD of a GMTI (``use_mdv``), the coverage-aware PD of another sensor,
    else the constant ``pd``.
    """
    B, r = x.shape[:2]
    if hasattr(sensor, "mdv") and not config.use_mdv:
        pd = torch.full((B, r), float(sensor.pd), dtype=DTYPE)
    elif hasattr(sensor, "expected_detection_probability"):
        pd = torch.as_tensor(sensor.expected_detection_probability(x, P), dtype=DTYPE)
    else:
        pd = torch.full((B, r), float(sensor.pd), dtype=DTYPE)
    return pd.clamp(_PD_FLOOR, 1.0)


def _stop_mask(config: VSIMMConfig) -> torch.Tensor:
    return torch.tensor([k == "stop" for k in config.kinds])


def _default_trans(r: int, stay: float = 0.9) -> tuple[tuple[float, ...], ...]:
    if r == 1:
        return ((1.0,),)
    off = (1.0 - stay) / (r - 1)
    return tuple(tuple(stay if i == j else off for j in range(r)) for i in range(r))


@dataclass(frozen=True)
class VSIMMConfig:
    """Mode set and options of the VS-IMM.

    Args:
        road_sigmas: ``((sigma_along, sigma_across), ...)`` of the road-constrained CV models in
            m/s^2 (the chapter: M1 ``(0.05, 0.05)``, M2 ``(0.8, 0.4)``).
        stop: include the stop model M0 as mode 0.
        off_road_sigma: acceleration deviation (m/s^2) of an unconstrained CV mode appended last,
            or ``None`` (no off-road mode).
        trans: ``(r, r)`` mode transition matrix, ``trans[i, j] = P(i -> j)`` (rows sum to 1);
            ``None`` gives 0.9 on the diagonal and the rest spread evenly (our choice; the
            chapter takes its matrix from its reference [14]).
        relax: relax the across-road noise near segment ends (24.9-24.12).
        use_mdv: mode-dependent ``PD`` from the sensor's MDV notch (GMTI).
        noise: ``"discrete"`` (default): piecewise-constant white acceleration,
            ``Q = Gamma(dt) Sigma Gamma(dt)'`` as in 24.5 with ``Gamma`` of [1]; ``"continuous"``
            (our addition): continuous white acceleration of power spectral density ``Sigma``
            (per axis ``[[dt^3/3, dt^2/2], [dt^2/2, dt]]``), whose ``Q`` splits exactly over
            sub-intervals, so that the OOSM retrodiction is exact for a linear model.
        junction: how a road mode's prediction enters a new segment (:func:`junction_transition`).
            ``"rotate"`` (default, our reading of ``F_{s,i}`` of 24.5, "the state transition
            matrix projects the mixed estimate on the road section", 24.4.2 step 2): when the
            constant-velocity prediction of a moving mode has passed the end of its segment and
            lies on an adjacent segment, the part of the motion beyond the shared node and the
            velocity are rotated onto the new segment (the target follows the road; speed and
            travelled distance kept), the covariance with them. ``"none"``: the plain CV
            prediction, left to the projection 24.14-24.16 after the update (the previous
            behaviour: at a turn the velocity mismatch, read as an estimation error, moved the
            position along the new road through the position-velocity correlation, 120 m at an
            11 degree turn in the [PD] 24.6 scenario, seed 2402, target 1, t = 810 s).
        junction_retro: how a one-step OOSM retrodiction (A1, a straight back-extrapolation
            along the mode's current segment) is carried back across the junction the mode
            passed in its last step (:func:`_retro_junction`; with ``junction="rotate"`` only;
            our addition). ``"state"`` (default): from the state, the segment of each mode
            before its last step (``VSIMMState.segment_prev``) and the node it crossed
            (``VSIMMState.junction_node``): the inverse of the rotation of
            :func:`junction_transition` about that node, for the modes whose retrodiction lies
            behind it; also for the one-step rows of a lag memory. ``"locate"`` (the former
            behaviour, kept for side-by-side measurement): the old segment *guessed* as the
            segment nearest to the straight back-extrapolation (wrong at 4-way crossroads, at
            T junctions from the stem and at some bends of 90 degrees or more), not for the
            lag memory's one-step rows. ``"off"``: no correction. Measured in the [PD] 24.6
            scenario (``experiments/_pd_armse_diag.py``, without PCR5), "state" against
            "locate": the step ran on 4 and 6 of 1984 and 3722 OOSM road-mode rows (seeds
            2408, 2400), every time 5 m or more from the guess. With the pipeline's
            ``split_links="history"`` (the default) the two agree on every target of the seeds
            2400-2429 within 0.1 m of ARMSE (target 4 41.4 / 41.5 m, target 10 15.4 / 15.5 m)
            and GOSPA 84.1 / 84.2 m (``_pd_armse_diag.py --seeds 2400-2429 --jobs 1 --set
            junction_retro=state`` and ``=locate``). Before ``split_links="history"``, seed 2408
            target 9 went 13 -> 321 m with "state": a video report from 5 s before the junction
            at (3000, 0) no longer penalised (through the wrong guess) the leaf of the branch
            the target did not take, the two branch leaves tied (scores 490.0 / 490.6) and the
            MHT kept the wrong one for 150 s; with ``"history"`` it is 13.1 m with both.

    Examples:
        >>> VSIMMConfig().kinds
        ('stop', 'road', 'road')
    """

    road_sigmas: tuple[tuple[float, float], ...] = ((0.05, 0.05), (0.8, 0.4))
    stop: bool = True
    off_road_sigma: float | None = None
    trans: Any = None
    relax: bool = True
    use_mdv: bool = True
    noise: str = "discrete"
    junction: str = "rotate"
    junction_retro: str = "state"
    kinds: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        check_choice("noise", self.noise, ("discrete", "continuous"))
        check_choice("junction", self.junction, ("rotate", "none"))
        check_choice("junction_retro", self.junction_retro, ("state", "locate", "off"))
        for i, pair in enumerate(self.road_sigmas):
            if len(pair) != 2:
                raise ValueError(
                    "`road_sigmas`: expected (sigma_along, sigma_across) pairs, got "
                    f"{pair!r} at {i}"
                )
            check_number("sigma_along", pair[0], low=0.0)
            check_number("sigma_across", pair[1], low=0.0)
        if self.off_road_sigma is not None:
            check_number("off_road_sigma", self.off_road_sigma, low=0.0)
        kinds = ("stop",) * self.stop + ("road",) * len(self.road_sigmas)
        kinds += ("off",) * (self.off_road_sigma is not None)
        if not kinds:
            raise ValueError("`road_sigmas`: expected at least one mode, got none")
        object.__setattr__(self, "kinds", kinds)
        trans = self.trans if self.trans is not None else _default_trans(len(kinds))
        t = as_float64("trans", trans, min_dim=2)
        r = len(kinds)
        if t.shape != (r, r):
            raise ValueError(
                f"`trans`: expected shape ({r}, {r}) for modes {kinds}, got {tuple(t.shape)}"
            )
        imm_mixing_probabilities(torch.full((1, r), 1.0 / r, dtype=DTYPE), t)  # row-sum checks
        object.__setattr__(self, "trans", tuple(tuple(row) for row in t.tolist()))

    @property
    def num_modes(self) -> int:
        """``r``."""
        return len(self.kinds)

    def trans_tensor(self) -> torch.Tensor:
        """``(r, r)`` float64 transition matrix."""
        return torch.tensor(self.trans, dtype=DTYPE)

    def sigma_tensors(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per-mode ``sigma_along``, ``sigma_across`` ``(r,)`` (m/s^2) and the road-mode mask."""
        sa, sc, road = [], [], []
        it = iter(self.road_sigmas)
        for k in self.kinds:
            if k == "road":
                a, c = next(it)
            elif k == "off":
                a = c = float(self.off_road_sigma)
            else:
                a = c = 0.0
            sa.append(a)
            sc.append(c)
            road.append(k != "off")
        return (
            torch.tensor(sa, dtype=DTYPE),
            torch.tensor(sc, dtype=DTYPE),
            torch.tensor(road, dtype=torch.bool),
        )


class VSIMMState(NamedTuple):
    """State of ``B`` rows (track x section hypothesis), all float64 unless said.

    Attributes:
        mu: ``(B, r)`` mode probabilities.
        x: ``(B, r, 4)`` mode-matched estimates (m, m/s), projected on their segments.
        P: ``(B, r, 4, 4)``.
        segment: ``(B, r)`` int64 active segment per mode (``-1`` off-road).
        section: ``(B,)`` int64 section hypothesis (``-1``: whole network).
        track: ``(B,)`` int64 track id.
        mu_section: ``(B,)`` section probability ``mu_h`` (24.38), sums to 1 per track.
        t: ``(B,)`` time of the estimate, s.
        t_prev: ``(B,)`` time of the previous scan, s (the OOSM lag limit).
        P_pred: ``(B, r, 4, 4)`` ``P(k|k-1)`` of the last step (OOSM memory).
        g: ``(B, r, 4)`` ``H' S^-1 nu`` of the last update, the road projection included as a
            perfect pseudo-measurement (see ``_oosm_memory``).
        G: ``(B, r, 4, 4)`` ``H' S^-1 H`` of the last update, likewise.
        accel_cov: ``(B, r, 2, 2)`` acceleration covariance (m/s^2)^2 used in the last step.
        segment_prev: ``(B, r)`` int64 active segment of each mode before its last step (at
            ``t_prev``; ``-1`` off-road), or ``None`` (a state built without it: the OOSM
            junction step of ``VSIMMConfig(junction_retro="state")`` is then skipped).
        junction_node: ``(B, r)`` int64 the node shared by ``segment_prev`` and ``segment``
            (:func:`crossed_node`), recorded whenever the segment changed across a shared node,
            whether or not the forward map :func:`junction_transition` rotated the prediction
            (it does not with ``junction="none"`` or for a mixed prediction short of the
            node); ``-1``: the segment did not change, a mode is off-road or the two segments
            do not touch; ``None`` as ``segment_prev``. The OOSM retrodiction
            (:func:`_retro_junction`) rotates back about it the modes whose retrodiction lies
            behind it.
    """

    mu: torch.Tensor
    x: torch.Tensor
    P: torch.Tensor
    segment: torch.Tensor
    section: torch.Tensor
    track: torch.Tensor
    mu_section: torch.Tensor
    t: torch.Tensor
    t_prev: torch.Tensor
    P_pred: torch.Tensor
    g: torch.Tensor
    G: torch.Tensor
    accel_cov: torch.Tensor
    segment_prev: torch.Tensor | None = None
    junction_node: torch.Tensor | None = None

    def combined(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Combined estimate (24.37) and covariance: ``(B, 4)``, ``(B, 4, 4)``."""
        return _combine(self.mu, self.x, self.P)

    def select(self, rows: Any) -> VSIMMState:
        """The rows ``rows`` (index or bool mask) of every field."""
        return VSIMMState(*(None if f is None else f[rows] for f in self))


class VSIMMPrediction(NamedTuple):
    """Result of :func:`vsimm_predict`.

    Attributes:
        cbar: ``(B, r)`` predicted mode probabilities ``mu_i(k|k-1)``.
        x: ``(B, r, 4)`` mode-matched predictions.
        P: ``(B, r, 4, 4)``.
        segment: ``(B, r)`` int64 active segments (``-1`` off-road).
        p_on: ``(B, r)`` on-segment probabilities ``P{e_s(k) | Z^{k-1}}`` (24.11; 1 off-road).
        accel_cov: ``(B, r, 2, 2)`` acceleration covariances (24.9).
        t: ``(B,)`` prediction time, s.
        T: ``(B, r, 4, 4)`` the junction rotation applied to each mode's prediction
            (:func:`junction_transition`; identity elsewhere), or ``None`` (a prediction
            rebuilt without it: :func:`vsimm_lag_memory_step` then needs ``net``).
    """

    cbar: torch.Tensor
    x: torch.Tensor
    P: torch.Tensor
    segment: torch.Tensor
    p_on: torch.Tensor
    accel_cov: torch.Tensor
    t: torch.Tensor
    T: torch.Tensor | None = None


def _cv_matrices(dt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """CV ``F (..., 4, 4)`` and ``Gamma (..., 4, 2)`` for time steps ``dt (...)`` (any sign)."""
    F = torch.eye(4, dtype=DTYPE).expand(*dt.shape, 4, 4).clone()
    F[..., 0, 1] = dt
    F[..., 2, 3] = dt
    Gm = torch.zeros(*dt.shape, 4, 2, dtype=DTYPE)
    Gm[..., 0, 0] = Gm[..., 2, 1] = 0.5 * dt * dt
    Gm[..., 1, 0] = Gm[..., 3, 1] = dt
    return F, Gm


def _mode_F(kinds: tuple[str, ...], dt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-row, per-mode ``F (B, r, 4, 4)`` and ``Gamma (B, r, 4, 2)``; the stop mode has F0."""
    F, Gm = _cv_matrices(dt)
    r = len(kinds)
    F = F.unsqueeze(1).repeat(1, r, 1, 1)
    Gm = Gm.unsqueeze(1).repeat(1, r, 1, 1)
    for i, k in enumerate(kinds):
        if k == "stop":
            F[:, i] = torch.diag(torch.tensor([1.0, 0.0, 1.0, 0.0], dtype=DTYPE))
            Gm[:, i] = 0.0
    return F, Gm


def _process_noise(
    kinds: tuple[str, ...], noise: str, dt: torch.Tensor, Gm: torch.Tensor, cov: torch.Tensor
) -> torch.Tensor:
    """``Q (B, r, 4, 4)`` from acceleration covariances ``cov (B, r, 2, 2)`` over ``dt (B,)``."""
    if noise == "discrete":
        return Gm @ cov @ Gm.transpose(-1, -2)
    d = dt.abs().view(-1, 1, 1, 1)
    blk = torch.cat(
        [torch.cat([d**3 / 3.0, d**2 / 2.0], -1), torch.cat([d**2 / 2.0, d], -1)], -2
    )  # (B, 1, 2, 2)
    T = cov[..., :, None, :, None] * blk[..., None, :, None, :]
    Q = T.reshape(*cov.shape[:-2], 4, 4)
    stop = torch.tensor([k == "stop" for k in kinds]).view(1, -1, 1, 1)
    return torch.where(stop, torch.zeros_like(Q), Q)


def _accel_cov(
    net: RoadNetwork,
    seg: torch.Tensor,
    x_pred: torch.Tensor,
    P_tmp_fn: Any,
    sa: torch.Tensor,
    sc: torch.Tensor,
    road: torch.Tensor,
    relax: bool,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Acceleration covariances 24.6 / 24.9 ``(B, r, 2, 2)`` and ``p_on`` ``(B, r)``."""
    s = seg.clamp(min=0)
    u = net.direction[s]  # (B, r, 2)
    nrm = torch.stack([-u[..., 1], u[..., 0]], -1)
    uu = u.unsqueeze(-1) * u.unsqueeze(-2)
    nn = nrm.unsqueeze(-1) * nrm.unsqueeze(-2)
    sa2 = (sa * sa).view(1, -1, 1, 1)
    sc2 = (sc * sc).view(1, -1, 1, 1)
    iso = torch.eye(2, dtype=DTYPE)
    base = torch.where(road.view(1, -1, 1, 1), sa2 * uu + sc2 * nn, sa2 * iso)
    p_on = torch.ones(seg.shape, dtype=DTYPE)
    if relax:
        P_tmp = P_tmp_fn(base)
        along = ((x_pred[..., [0, 2]] - net.p0[s]) * u).sum(-1)
        Ppos = P_tmp[..., [0, 2], :][..., [0, 2]]
        var = (u.unsqueeze(-2) @ Ppos @ u.unsqueeze(-1)).squeeze(-1).squeeze(-1)
        p = on_segment_probability_from_moments(along, var, net.length[s])
        p_on = torch.where(road.view(1, -1) & (seg >= 0), p, p_on)
        q = sc2.squeeze(-1).squeeze(-1) * p_on + sa2.squeeze(-1).squeeze(-1) * (1.0 - p_on)
        relaxed = sa2 * uu + q.unsqueeze(-1).unsqueeze(-1) * nn
        base = torch.where(
            (road.view(1, -1) & (seg >= 0)).unsqueeze(-1).unsqueeze(-1), relaxed, base
        )
    return base, p_on


def _times(name: str, t: Any, B: int) -> torch.Tensor:
    tt = as_float64(name, t)
    if tt.dim() == 0:
        tt = tt.expand(B)
    if tt.shape != (B,):
        raise ValueError(f"`{name}`: expected a scalar or shape ({B},) in s, got {tuple(tt.shape)}")
    return tt


def vsimm_init(
    net: RoadNetwork,
    x0: Any,
    P0: Any,
    config: VSIMMConfig,
    t0: Any = 0.0,
    *,
    section: Any | None = None,
    track: Any | None = None,
    mu0: Any | None = None,
) -> VSIMMState:
    """Initial VS-IMM rows: every mode starts at ``(x0, P0)`` projected on the nearest segment.

    Args:
        net: the road network.
        x0: ``(N, 4)`` initial states (m, m/s).
        P0: ``(N, 4, 4)`` or ``(4, 4)``.
        config: :class:`VSIMMConfig`.
        t0: scalar or ``(N,)`` s.
        section: ``(N,)`` section hypotheses, default the section of the nearest segment
            (``-1`` for the whole network).
        track: ``(N,)`` track ids (default ``0..N-1``).
        mu0: ``(N, r)`` or ``(r,)`` initial mode probabilities (default uniform).

    Returns:
        :class:`VSIMMState` with ``N`` rows.

    Examples:
        >>> net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]]])
        >>> s = vsimm_init(net, torch.tensor([[10.0, 5.0, 3.0, 1.0]]), 100 * torch.eye(4),
        ...                VSIMMConfig())
        >>> s.x[0].tolist()  # stop, M1, M2 on the road y = 0 (the stop mode has no velocity)
        [[10.0, 0.0, 0.0, 0.0], [10.0, 5.0, 0.0, 0.0], [10.0, 5.0, 0.0, 0.0]]
    """
    x0 = as_float64("x0", x0, min_dim=2)
    N = x0.shape[0]
    if x0.shape != (N, 4):
        raise ValueError(f"`x0`: expected shape (N, 4), got {tuple(x0.shape)}")
    P0 = as_float64("P0", P0, min_dim=2, square=True).expand(N, 4, 4)
    r = config.num_modes
    if section is None:
        loc = net.locate(x0)
        sec = loc.section
    else:
        sec = torch.as_tensor(section, dtype=torch.int64).expand(N)
    loc = net.locate(x0, allowed=net.section_mask(sec))
    _, _, road = config.sigma_tensors()
    seg = torch.where(road, loc.segment.unsqueeze(-1), torch.full((N, r), -1, dtype=torch.int64))
    x = x0.unsqueeze(1).repeat(1, r, 1)
    P = P0.unsqueeze(1).repeat(1, r, 1, 1)
    for i, k in enumerate(config.kinds):
        if k == "stop":
            x[:, i, [1, 3]] = 0.0
            P[:, i, [1, 3], :] = 0.0
            P[:, i, :, [1, 3]] = 0.0
    D, L = net.constraint(seg.clamp(min=0))
    xs, A = _projection(x, P, D, L)
    Ps = A @ P @ A.transpose(-1, -2)
    rm = (seg >= 0).unsqueeze(-1)
    x = torch.where(rm, xs, x)
    P = torch.where(rm.unsqueeze(-1), 0.5 * (Ps + Ps.transpose(-1, -2)), P)
    mu = (
        torch.full((N, r), 1.0 / r, dtype=DTYPE)
        if mu0 is None
        else as_float64("mu0", mu0).expand(N, r).clone()
    )
    t = _times("t0", t0, N)
    trk = torch.arange(N) if track is None else torch.as_tensor(track, dtype=torch.int64).expand(N)
    z4 = torch.zeros(N, r, 4, dtype=DTYPE)
    return VSIMMState(
        mu,
        x,
        P,
        seg,
        sec.clone(),
        trk.clone(),
        torch.ones(N, dtype=DTYPE),
        t,
        t.clone(),
        P.clone(),
        z4,
        torch.zeros(N, r, 4, 4, dtype=DTYPE),
        torch.zeros(N, r, 2, 2, dtype=DTYPE),
        seg.clone(),
        torch.full((N, r), -1, dtype=torch.int64),
    )


def vsimm_predict(
    state: VSIMMState, net: RoadNetwork, config: VSIMMConfig, t: Any
) -> VSIMMPrediction:
    """Mixing (24.33-24.35) and the road-constrained prediction of every mode (24.5-24.12).

    For each row and mode: mixed estimate ``(x0, P0)``; ``x_pred = F x0``; active segment ``s``
    = the segment of the row's section nearest to ``x_pred`` (the variable structure); the
    acceleration covariance ``R_theta_s diag(s_along^2, q) R_theta_s'`` with
    ``q = s_across^2 P{e_s} + s_along^2 (1 - P{e_s})`` (24.9 as read in
    :mod:`hocnet.tracking.road`), ``P{e_s}`` from 24.11 at ``x_pred`` and
    ``F P0 F' + Gamma Q_s Gamma'`` (the un-relaxed prediction); ``P_pred = F P0 F' +
    Gamma Q~ Gamma'``. The stop mode has ``F0``, ``Q0 = 0``; the off-road mode isotropic noise.

    Args:
        state: :class:`VSIMMState` (``B`` rows).
        net: road network.
        config: :class:`VSIMMConfig` (``r`` modes).
        t: scalar or ``(B,)`` prediction time, s (``>= state.t``).

    Returns:
        :class:`VSIMMPrediction`.

    Raises:
        ValueError: ``t`` before the track time (use :func:`vsimm_oosm`), bad shapes.

    Examples:
        >>> net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])
        >>> cfg = VSIMMConfig(stop=False)
        >>> s = vsimm_init(net, torch.tensor([[90.0, 10.0, 0.0, 0.0]]), 100 * torch.eye(4), cfg)
        >>> pred = vsimm_predict(s, net, cfg, 5.0)
        >>> pred.segment.tolist(), pred.x[0, 0].tolist()  # 40 m past the 90 degree bend
        ([[1, 1]], [100.0, 0.0, 40.0, 10.0])
    """
    B, r = state.mu.shape
    if r != config.num_modes:
        raise ValueError(f"`state`: expected {config.num_modes} modes for {config.kinds}, got {r}")
    tt = _times("t", t, B)
    dt = tt - state.t
    if dt.numel() and bool((dt < 0).any()):
        raise ValueError(
            f"`t`: expected a time >= the track time (scan order), got dt = {float(dt.min()):g} s; "
            "process delayed measurements with vsimm_oosm"
        )
    cbar, omega = _mixing(state.mu, config.trans_tensor())
    x0, P0 = _mix(state.x, state.P, omega)
    F, Gm = _mode_F(config.kinds, dt)
    x_pred = (F @ x0.unsqueeze(-1)).squeeze(-1)
    FPF = F @ P0 @ F.transpose(-1, -2)
    sa, sc, road = config.sigma_tensors()
    allowed = net.section_mask(state.section).unsqueeze(1)
    loc = net.locate(x_pred, allowed=allowed)
    seg = torch.where(road.view(1, -1), loc.segment, torch.full_like(loc.segment, -1))
    T = torch.eye(4, dtype=DTYPE).expand(B, r, 4, 4)
    if config.junction == "rotate":
        moving = torch.tensor([k == "road" for k in config.kinds]).view(1, -1)
        seg = follow_section(net, state.segment, seg, x0, x_pred, moving)
        T, b = junction_transition(net, state.segment, seg, x0, x_pred, moving)
        x_pred = (T @ x_pred.unsqueeze(-1)).squeeze(-1) + b
        FPF = T @ FPF @ T.transpose(-1, -2)

    def p_tmp(cov: torch.Tensor) -> torch.Tensor:
        return FPF + _process_noise(config.kinds, config.noise, dt, Gm, cov)

    cov, p_on = _accel_cov(net, seg, x_pred, p_tmp, sa, sc, road, config.relax)
    P_pred = p_tmp(cov)
    return VSIMMPrediction(
        cbar, x_pred, 0.5 * (P_pred + P_pred.transpose(-1, -2)), seg, p_on, cov, tt, T
    )


def junction_transition(
    net: RoadNetwork,
    old: torch.Tensor,
    new: torch.Tensor,
    x0: torch.Tensor,
    x_pred: torch.Tensor,
    moving: Any = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Affine map ``x -> T x + b`` taking a CV prediction past a junction onto the new segment.

    Our reading of the segment transition ``F_{s,i}`` of [PD] 24.5 ("the state transition matrix
    projects the mixed estimate on the road section", 24.4.2 step 2; the chapter leaves its form
    to its reference [12]). A row / mode moves from ``old`` to an adjacent ``new`` segment when
    its constant-velocity prediction has passed the node ``J`` they share: ``J`` is the end of
    ``old`` ahead of the mixed velocity (``x0``) and the prediction is beyond it
    (``(p_pred - J) . w > 0`` with ``w`` the direction of travel on ``old``). Then ``T`` rotates
    positions about ``J`` and velocities by the angle from ``w`` to the direction leaving ``J``
    along ``new``: the distance travelled past ``J`` and the speed are kept, the target follows
    the road. Elsewhere (same segment, stop / off-road modes, segments without a common node, a
    prediction not past ``J``) ``T = I`` and ``b = 0``. Covariances transform as ``T P T'``.

    Args:
        net: road network.
        old: ``(B, r)`` int64 segment of each mode before the prediction (``-1`` off-road).
        new: ``(B, r)`` int64 active segment located at the prediction.
        x0: ``(B, r, 4)`` mixed estimates ``[x, vx, y, vy]``.
        x_pred: ``(B, r, 4)`` CV predictions ``F x0``.
        moving: ``(r,)`` or ``(B, r)`` bool, the modes to transform (default all).

    Returns:
        ``T`` ``(B, r, 4, 4)`` and ``b`` ``(B, r, 4)``, float64.

    Examples:
        >>> net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])
        >>> x0 = torch.tensor([[[90.0, 10.0, 0.0, 0.0]]])
        >>> xp = torch.tensor([[[140.0, 10.0, 0.0, 0.0]]], dtype=torch.float64)  # past (100, 0)
        >>> T, b = junction_transition(net, torch.tensor([[0]]), torch.tensor([[1]]), x0, xp)
        >>> [round(v, 6) + 0.0 for v in ((T @ xp[..., None])[..., 0] + b)[0, 0].tolist()]
        [100.0, 0.0, 40.0, 10.0]
    """
    old, new, x0, x_pred, mov = _check_transition(net, old, new, x0, x_pred, moving)
    B, r = old.shape
    T = torch.eye(4, dtype=DTYPE).expand(B, r, 4, 4).clone()
    b = torch.zeros(B, r, 4, dtype=DTYPE)
    if not B:
        return T, b
    cand = mov & (old >= 0) & (new >= 0) & (old != new)
    if not bool(cand.any()):
        return T, b
    sn = new.clamp(min=0)
    ahead, w = node_ahead(net, old, x0[..., [1, 3]])
    n0, n1 = net.segment_nodes[sn, 0], net.segment_nodes[sn, 1]
    shared = (ahead == n0) | (ahead == n1)
    u = torch.where((ahead == n0).unsqueeze(-1), net.direction[sn], -net.direction[sn])
    J = net.nodes[ahead]
    p = x_pred[..., [0, 2]]
    past = ((p - J) * w).sum(-1) > 0
    ok = cand & shared & past
    if not bool(ok.any()):
        return T, b
    c = (w * u).sum(-1)
    s = w[..., 0] * u[..., 1] - w[..., 1] * u[..., 0]
    R = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)  # (B, r, 2, 2)
    T, b = _rotate_about(R, J, ok, T, b)
    return T, b


def _rotate_about(
    R: torch.Tensor, J: torch.Tensor, ok: torch.Tensor, T: torch.Tensor, b: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Affine map ``x -> T x + b`` rotating positions about the node ``J`` and velocities by ``R``.

    ``R``: ``(B, r, 2, 2)`` rotations, ``J``: ``(B, r, 2)`` nodes (m), ``ok``: ``(B, r)`` bool;
    state order ``[x, vx, y, vy]``. Rows where ``ok`` is false keep the given ``T`` ``(B, r, 4, 4)``
    and ``b`` ``(B, r, 4)``. Shared by :func:`junction_transition` and its inverse.
    """
    B, r = ok.shape
    Tr = torch.zeros(B, r, 4, 4, dtype=DTYPE)
    pos, vel = [0, 2], [1, 3]
    for a in range(2):
        for k in range(2):
            Tr[..., pos[a], pos[k]] = R[..., a, k]
            Tr[..., vel[a], vel[k]] = R[..., a, k]
    br = torch.zeros(B, r, 4, dtype=DTYPE)
    br[..., pos] = J - (R @ J.unsqueeze(-1)).squeeze(-1)
    return torch.where(ok[..., None, None], Tr, T), torch.where(ok[..., None], br, b)


def node_ahead(
    net: RoadNetwork, segment: torch.Tensor, velocity: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The end node of each segment ahead of a velocity, and the direction of travel on it.

    The node ahead is the segment's end (``segment_nodes[s, 1]``) when ``velocity`` points along
    its direction (``v . d_s >= 0``), its start otherwise; ``w = +-d_s`` accordingly (the
    one place this is computed: :func:`junction_transition`, :func:`follow_section` and the
    pipeline's junction hypotheses).

    Args:
        net: road network.
        segment: ``(...)`` int64 segments (``-1`` is read as segment 0: mask such rows).
        velocity: ``(..., 2)`` velocities ``[vx, vy]`` (m/s).

    Returns:
        ``ahead`` ``(...)`` int64 node indices and ``w`` ``(..., 2)`` float64 unit vectors.

    Examples:
        >>> net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])
        >>> node, w = node_ahead(net, torch.tensor([0, 0]), torch.tensor([[5.0, 0.0], [-5.0, 0.0]]))
        >>> node.tolist(), w.tolist()
        ([1, 0], [[1.0, 0.0], [-1.0, -0.0]])
    """
    so = torch.as_tensor(segment).to(torch.int64).clamp(min=0)
    d = net.direction[so]
    v = torch.as_tensor(velocity, dtype=DTYPE)
    fwd = (v * d).sum(-1) >= 0
    w = torch.where(fwd.unsqueeze(-1), d, -d)
    ahead = torch.where(fwd, net.segment_nodes[so, 1], net.segment_nodes[so, 0])
    return ahead, w


def crossed_node(
    net: RoadNetwork, old: torch.Tensor, new: torch.Tensor, velocity: torch.Tensor
) -> torch.Tensor:
    """The node shared by each mode's segment before and after a step (the junction crossed).

    ``-1`` where the segment did not change, a mode is off-road (``-1``) or the two segments
    share no node; where they share both ends (two segments between the same nodes) the node
    ahead of ``velocity`` on ``old`` (:func:`node_ahead`; :func:`vsimm_update` passes the mixed
    velocity of the step, as :func:`junction_transition` uses it). Recorded whenever the segment
    changed across a shared node, whether or not :func:`junction_transition` rotated the
    prediction. Stored in :attr:`VSIMMState.junction_node` by :func:`vsimm_update` (our
    addition, for the OOSM retrodiction across the junction, :func:`_retro_junction`).

    Args:
        net: road network.
        old: ``(...)`` int64 segments before the step (``-1`` off-road).
        new: ``(...)`` int64 segments after the step, same shape.
        velocity: ``(..., 2)`` velocities ``[vx, vy]`` (m/s) before the step.

    Returns:
        ``(...)`` int64 node indices, ``-1`` for none.

    Raises:
        ValueError: ``old`` / ``new`` not integer, of different shapes or with an index outside
            ``[-1, num_segments - 1]``; ``velocity`` not of shape ``old.shape + (2,)`` or not
            finite.
        TypeError: ``old`` / ``new`` / ``velocity`` not array-like, ``velocity`` not real.

    Examples:
        >>> net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])
        >>> crossed_node(net, torch.tensor([0, 0, 1]), torch.tensor([1, 0, 0]),
        ...              torch.tensor([[5.0, 0.0], [5.0, 0.0], [0.0, -5.0]])).tolist()
        [1, -1, 1]
    """
    old = _check_segments(net, "old", old)
    new = _check_segments(net, "new", new)
    if new.shape != old.shape:
        raise ValueError(f"`new`: expected shape {tuple(old.shape)}, got {tuple(new.shape)}")
    velocity = as_float64("velocity", velocity)
    if tuple(velocity.shape) != (*old.shape, 2):
        raise ValueError(
            f"`velocity`: expected shape {(*old.shape, 2)}, got {tuple(velocity.shape)}"
        )
    so, sn = old.clamp(min=0), new.clamp(min=0)
    a0, a1 = net.segment_nodes[so, 0], net.segment_nodes[so, 1]
    b0, b1 = net.segment_nodes[sn, 0], net.segment_nodes[sn, 1]
    sh0 = (a0 == b0) | (a0 == b1)
    sh1 = (a1 == b0) | (a1 == b1)
    ahead, _ = node_ahead(net, old, velocity)
    none = torch.full_like(old, -1)
    node = torch.where(sh0 & sh1, ahead, torch.where(sh0, a0, torch.where(sh1, a1, none)))
    return torch.where((old >= 0) & (new >= 0) & (old != new), node, none)


_NEXT_CACHE: dict[int, tuple[RoadNetwork, torch.Tensor]] = {}


def _section_next(net: RoadNetwork) -> torch.Tensor:
    """``(S, 2)`` int64: the segment of the same section at each end node of a segment (-1)."""
    hit = _NEXT_CACHE.get(id(net))
    if hit is not None and hit[0] is net:
        return hit[1]
    S = net.num_segments
    nxt = torch.full((S, 2), -1, dtype=torch.int64)
    sec = net.segment_section.tolist()
    ends = net.segment_nodes.tolist()
    for s in range(S):
        for e in range(2):
            same = [t for t in net.node_segments(ends[s][e]) if t != s and sec[t] == sec[s]]
            if same:
                nxt[s, e] = same[0]
    if len(_NEXT_CACHE) > 64:
        _NEXT_CACHE.clear()
    _NEXT_CACHE[id(net)] = (net, nxt)
    return nxt


def follow_section(
    net: RoadNetwork,
    old: torch.Tensor,
    new: torch.Tensor,
    x0: torch.Tensor,
    x_pred: torch.Tensor,
    moving: Any = True,
) -> torch.Tensor:
    """Active segments after a prediction, following the section's topology past a node.

    :meth:`~hocnet.tracking.road.RoadNetwork.locate` takes the segment nearest to the straight
    CV prediction. Past a bend of 90 degrees or more inside one road section the nearest
    segment is still the old one (the next segment is at least as far: its nearest point is the
    shared node), the rotation of :func:`junction_transition` never runs and the track is lost
    (issue 12 review: a 90 degree bend gave errors of 80, 200, 320 m on noise-free data). So
    where a moving mode's prediction is past the node ahead of its old segment
    (:func:`node_ahead` with the mixed velocity of ``x0``) and ``locate`` kept the old segment,
    the mode continues on the segment of the same section linked at that node (the topology,
    not the nearest segment); a road end keeps the old segment. Below 90 degrees ``locate``
    already gives that segment (a point ``d`` past the node is ``d sin(angle) < d`` from it),
    so the result is unchanged there. One segment per prediction: a prediction past the far end
    of the next segment too is not followed further.

    Args:
        net: road network.
        old: ``(B, r)`` int64 segment of each mode before the prediction (``-1`` off-road).
        new: ``(B, r)`` int64 segment located at the prediction.
        x0: ``(B, r, 4)`` mixed estimates ``[x, vx, y, vy]``.
        x_pred: ``(B, r, 4)`` CV predictions ``F x0``.
        moving: ``(r,)`` or ``(B, r)`` bool, the modes concerned (default all).

    Returns:
        ``(B, r)`` int64 active segments.

    Examples:
        >>> net = RoadNetwork([[[0.0, 0.0], [100.0, 0.0], [100.0, 500.0]]])  # 90 deg bend
        >>> x0 = torch.tensor([[[90.0, 10.0, 0.0, 0.0]]])
        >>> xp = torch.tensor([[[140.0, 10.0, 0.0, 0.0]]])  # straight on, past (100, 0)
        >>> net.locate(xp).segment.tolist(), follow_section(
        ...     net, torch.tensor([[0]]), torch.tensor([[0]]), x0, xp
        ... ).tolist()
        ([[0]], [[1]])
    """
    old, new, x0, x_pred, mov = _check_transition(net, old, new, x0, x_pred, moving)
    cand = mov & (old >= 0) & (new == old)
    if not bool(cand.any()):
        return new
    ahead, w = node_ahead(net, old, x0[..., [1, 3]])
    past = ((x_pred[..., [0, 2]] - net.nodes[ahead]) * w).sum(-1) > 0
    so = old.clamp(min=0)
    end = (net.segment_nodes[so, 1] == ahead).to(torch.int64)
    nxt = _section_next(net)[so, end]
    return torch.where(cand & past & (nxt >= 0), nxt, new)


def _check_transition(
    net: RoadNetwork, old: Any, new: Any, x0: Any, x_pred: Any, moving: Any
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Validated inputs of :func:`junction_transition` / :func:`follow_section`."""
    old, new = _check_segments(net, "old", old, 2), _check_segments(net, "new", new, 2)
    if new.shape != old.shape:
        raise ValueError(f"`new`: expected shape {tuple(old.shape)}, got {tuple(new.shape)}")
    B, r = old.shape
    out = []
    for name, v in (("x0", x0), ("x_pred", x_pred)):
        v = as_float64(name, v)
        if tuple(v.shape) != (B, r, 4):
            raise ValueError(f"`{name}`: expected shape ({B}, {r}, 4), got {tuple(v.shape)}")
        out.append(v)
    try:
        mov = torch.as_tensor(moving, dtype=torch.bool).expand(B, r)
    except RuntimeError:
        raise ValueError(
            f"`moving`: expected a bool of shape ({r},) or ({B}, {r}), got "
            f"{tuple(torch.as_tensor(moving).shape)}"
        ) from None
    return old, new, out[0], out[1], mov


def _check_segments(
    net: RoadNetwork, name: str, value: Any, dim: int | None = None
) -> torch.Tensor:
    """``value`` as int64 segment indices in ``[-1, S - 1]`` (``dim`` axes if given)."""
    shape = "(B, r)" if dim == 2 else "(...)"
    try:
        v = torch.as_tensor(value)
    except (TypeError, ValueError, RuntimeError):
        raise TypeError(
            f"`{name}`: expected a {shape} integer tensor, got {type(value).__name__}"
        ) from None
    integer = not (v.is_floating_point() or v.is_complex() or v.dtype == torch.bool)
    if (dim is not None and v.dim() != dim) or not integer:
        raise ValueError(
            f"`{name}`: expected a {shape} integer tensor, got {tuple(v.shape)} {v.dtype}"
        )
    if v.numel() and bool(((v < -1) | (v >= net.num_segments)).any()):
        raise ValueError(
            f"`{name}`: expected segment indices in [-1, {net.num_segments - 1}], got "
            f"{int(v.min())}..{int(v.max())}"
        )
    return v.to(torch.int64)


class VSIMMUpdate(NamedTuple):
    """Likelihoods of :func:`vsimm_update` and :func:`vsimm_oosm`.

    Attributes:
        log_likelihood: ``(B,)`` ``log Lambda`` (24.32).
        mode_log_likelihood: ``(B, r)`` ``log Lambda_i`` (24.30-24.31).
    """

    log_likelihood: torch.Tensor
    mode_log_likelihood: torch.Tensor


def _oosm_memory(
    pred: VSIMMPrediction,
    H: torch.Tensor,
    nu: torch.Tensor,
    R: torch.Tensor,
    det: torch.Tensor,
    D: torch.Tensor,
    L: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """A1 memory ``g = Ht' St^+ nut``, ``G = Ht' St^+ Ht`` of the whole update at ``t_k``.

    The update of a road mode is the measurement followed by the projection on ``D x = L``, i.e.
    the conditioning on a perfect pseudo-measurement; both are stacked (``Ht = [H; D]``,
    ``nut = [nu; L - D x_pred]``, ``Rt = blockdiag(R, 0)``, zero rows where a part is absent:
    undetected rows, off-road modes) so that ``P(k|k) = P(k|k-1) - P(k|k-1) G P(k|k-1)`` holds as
    A1 assumes (our addition; with the measurement alone the retrodicted covariance can become
    indefinite). ``St^+`` is the pseudo-inverse (a stopped mode has no velocity variance).
    """
    B, r, m, _ = H.shape
    d = det.view(B, 1, 1)
    on = (pred.segment >= 0).unsqueeze(-1)
    Hz = torch.where(d.unsqueeze(-1), H, torch.zeros_like(H))
    Dz = torch.where(on.unsqueeze(-1), D, torch.zeros_like(D))
    Ht = torch.cat([Hz, Dz], -2)
    resid = L - (D @ pred.x.unsqueeze(-1)).squeeze(-1)
    nut = torch.cat(
        [torch.where(d, nu, torch.zeros_like(nu)), torch.where(on, resid, torch.zeros_like(resid))],
        -1,
    )
    c = D.shape[-2]
    Rt = torch.zeros(B, r, m + c, m + c, dtype=DTYPE)
    Rt[..., :m, :m] = torch.where(d.unsqueeze(-1), R, torch.zeros_like(R))
    St = Ht @ pred.P @ Ht.transpose(-1, -2) + Rt
    St = 0.5 * (St + St.transpose(-1, -2))
    # cut-off on the scale of P(k|k-1) (see hocnet.tracking.oosm._projection): without a
    # detection St = D P D' can be pure round-off for a mode already on its road
    Sp = pinv_sym(St, pinv_atol(pred.P))
    HtS = Ht.transpose(-1, -2) @ Sp
    G = HtS @ Ht
    g = (HtS @ nut.unsqueeze(-1)).squeeze(-1)
    return g, 0.5 * (G + G.transpose(-1, -2))


def vsimm_update(
    state: VSIMMState,
    pred: VSIMMPrediction,
    z: Any,
    sensor: Any,
    net: RoadNetwork,
    config: VSIMMConfig,
    *,
    detected: Any | None = None,
) -> tuple[VSIMMState, VSIMMUpdate]:
    """Mode-matched update, PD-aware likelihoods, projection on the road, combination.

    Steps 3-5 of [PD] 24.4.2: the (AEKF / linear) update of every mode with the row's
    measurement, ``log Lambda_i`` of 24.30-24.31, the mode probabilities 24.36, the projection of
    every road mode on its active segment (24.14-24.16, pseudo-inverse for a singular
    ``D P D'``), and the OOSM memory (``g``, ``G``, ``P(k|k-1)``).

    Args:
        state: the rows before the step.
        pred: :func:`vsimm_predict` output.
        z: ``(B, m)`` one measurement per row (rows with ``detected=False`` are ignored and may
            be NaN); ``m`` = ``sensor.dim``.
        sensor: :class:`~hocnet.tracking.sensors.GMTISensor` or
            :class:`~hocnet.tracking.sensors.VideoSensor`.
        net: road network.
        config: :class:`VSIMMConfig`.
        detected: ``(B,)`` bool (default all).

    Returns:
        ``(new_state, VSIMMUpdate)``.

    Raises:
        ValueError: non-finite measurement in a detected row, bad shapes.
        TypeError: ``sensor`` is not a sensor model (e.g. a name such as ``"sonar"``).

    Examples:
        >>> from hocnet.tracking.sensors import GMTISensor
        >>> net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]]])
        >>> cfg = VSIMMConfig()
        >>> s = vsimm_init(net, torch.tensor([[0.0, 10.0, 0.0, 0.0]]), 100 * torch.eye(4), cfg)
        >>> pred = vsimm_predict(s, net, cfg, 10.0)
        >>> z = torch.tensor([[float("nan"), 0.0, 0.0]])
        >>> new, out = vsimm_update(s, pred, z, GMTISensor((0.0, -5000.0, 0.0)), net, cfg,
        ...                         detected=torch.tensor([False]))
        >>> new.mu[0, 0] > s.mu[0, 0]  # a GMTI miss favours the stop model (24.31)
        tensor(True)
    """
    _check_sensor(sensor)
    B, r = pred.cbar.shape
    if detected is None:
        det = torch.ones(B, dtype=torch.bool)
    else:
        det = torch.as_tensor(detected)
        if det.dtype != torch.bool or det.shape != (B,):
            raise ValueError(
                f"`detected`: expected a bool tensor of shape ({B},), got dtype {det.dtype} and "
                f"shape {tuple(det.shape)}"
            )
    zt = _measurement(z, sensor, det)
    m = sensor.dim
    xc_pred = _combine(pred.cbar, pred.x, pred.P)[0]
    zt = torch.where(det.unsqueeze(-1), zt, sensor.measure(xc_pred))
    hx, H, R = sensor.linearize(pred.x, zt.unsqueeze(1))
    H = H.expand(B, r, m, 4)
    R = R.expand(B, r, m, m)
    nu = zt.unsqueeze(1) - hx
    x_upd, P_upd, ll = _update(pred.x, pred.P, nu, H, R)
    pd = _mode_pd(sensor, config, pred.x, pred.P)
    d = det.unsqueeze(-1)
    mode_ll = _pd_mode_ll(ll, det, pd, _stop_mask(config), stop_detectable(sensor))
    x_upd = torch.where(d.unsqueeze(-1), x_upd, pred.x)
    P_upd = torch.where(d.unsqueeze(-1).unsqueeze(-1), P_upd, pred.P)
    # projection on the active segments (road and stop modes)
    D, L = net.constraint(pred.segment.clamp(min=0))
    xs, A = _projection(x_upd, P_upd, D, L)
    Ps = A @ P_upd @ A.transpose(-1, -2)
    on = (pred.segment >= 0).unsqueeze(-1)
    x_new = torch.where(on, xs, x_upd)
    P_new = torch.where(on.unsqueeze(-1), 0.5 * (Ps + Ps.transpose(-1, -2)), P_upd)
    a = mode_ll + torch.log(pred.cbar)
    total = torch.logsumexp(a, dim=-1, keepdim=True)
    if a.numel() and bool(torch.isinf(total).any()):
        raise ValueError(
            "`z`: expected at least one mode with non-zero likelihood per row, got "
            f"{int(torch.isinf(total).sum())} rows with none"
        )
    mu = torch.exp(a - total)
    g, G = _oosm_memory(pred, H, nu, R, det, D, L)
    new = VSIMMState(
        mu,
        x_new,
        P_new,
        pred.segment,
        state.section,
        state.track,
        state.mu_section,
        pred.t,
        state.t,
        pred.P,
        g,
        G,
        pred.accel_cov,
        state.segment,
        crossed_node(net, state.segment, pred.segment, _mixed_velocity(state, config)),
    )
    return new, VSIMMUpdate(total.squeeze(-1), mode_ll)


def _mixed_velocity(state: VSIMMState, config: VSIMMConfig) -> torch.Tensor:
    """``(B, r, 2)`` velocities of the mixed estimates ``x0`` of :func:`vsimm_predict` (24.34)."""
    _, omega = _mixing(state.mu, config.trans_tensor())
    return (omega.transpose(-1, -2) @ state.x)[..., [1, 3]]


class VSIMMOOSMUpdate(NamedTuple):
    """Result of :func:`vsimm_oosm` with ``too_old="drop"``.

    Attributes:
        log_likelihood: ``(B,)`` ``log Lambda`` (0 for undetected and dropped rows).
        mode_log_likelihood: ``(B, r)`` ``log Lambda_i``.
        dropped: ``(B,)`` bool, the rows whose measurement was older than the one-step lag and
            was not used (``int(dropped.sum())`` is the count).
    """

    log_likelihood: torch.Tensor
    mode_log_likelihood: torch.Tensor
    dropped: torch.Tensor


class VSIMMAssociation(NamedTuple):
    """Result of :func:`vsimm_association_log_likelihood`.

    Attributes:
        log_likelihood: ``(B, M)`` ``log Lambda`` (24.32) of row ``b`` updated with measurement
            ``j`` (PD-aware, 24.30-24.31 with ``m_j != 0``).
        missed_log_likelihood: ``(B,)`` ``log Lambda`` of a missed detection (``m_j = 0``).
        d2: ``(B, M, r)`` squared Mahalanobis distances of every mode's innovation (for gating).

    Gating convention: no gate is applied here; the caller gates on ``d2`` (per mode: "any mode
    inside" is the Stone Soup hypothesiser's rule, while :class:`~hocnet.tracking.mht.MHT`
    gates on its filter's combined innovation).
    """

    log_likelihood: torch.Tensor
    missed_log_likelihood: torch.Tensor
    d2: torch.Tensor


def vsimm_association_log_likelihood(
    pred: VSIMMPrediction, z: Any, sensor: Any, config: VSIMMConfig
) -> VSIMMAssociation:
    """Likelihoods of every (row, measurement) pair of a scan, for gating and track scores.

    The same mode likelihoods as :func:`vsimm_update` (24.29-24.32), for all ``B x M`` pairs at
    once, without updating: the ``Lambda`` of the LLR increment 24.42 of each association
    hypothesis, and the missed-detection ``Lambda`` (``sum_i (1 - PD_i) mu_i(k|k-1)`` over the
    moving modes plus the stop mode's ``mu_0(k|k-1)``).

    Args:
        pred: :func:`vsimm_predict` output (``B`` rows, ``r`` modes).
        z: ``(M, m)`` measurements of the scan (finite).
        sensor: the sensor of the scan.
        config: :class:`VSIMMConfig`.

    Returns:
        :class:`VSIMMAssociation`.

    Raises:
        ValueError: non-finite measurements, wrong measurement size.

    Examples:
        >>> from hocnet.tracking.sensors import VideoSensor
        >>> net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]]])
        >>> cfg = VSIMMConfig()
        >>> s = vsimm_init(net, torch.tensor([[0.0, 10.0, 0.0, 0.0]]), 100 * torch.eye(4), cfg)
        >>> a = vsimm_association_log_likelihood(vsimm_predict(s, net, cfg, 10.0),
        ...     torch.tensor([[100.0, 0.0], [400.0, 0.0]]), VideoSensor(), cfg)
        >>> bool(a.log_likelihood[0, 0] > a.log_likelihood[0, 1]), a.d2.shape
        (True, torch.Size([1, 2, 3]))
    """
    B, r = pred.cbar.shape
    m = sensor.dim
    zz = check_measurements("z", z, m)
    if zz.dim() != 2:
        raise ValueError(f"`z`: expected shape (M, {m}), got {tuple(zz.shape)}")
    M = zz.shape[0]
    xb = pred.x.unsqueeze(1)  # (B, 1, r, 4)
    Pb = pred.P.unsqueeze(1)
    zb = zz.view(1, M, 1, m)
    hx, H, R = sensor.linearize(xb, zb)
    shape = (B, M, r)
    H = H.expand(*shape, m, 4)
    R = R.expand(*shape, m, m)
    nu = zb - hx
    S = H @ Pb @ H.transpose(-1, -2) + R
    S = 0.5 * (S + S.transpose(-1, -2))
    L, info = torch.linalg.cholesky_ex(S)
    if bool((info != 0).any()):
        raise ValueError(
            "`z`: expected positive definite innovation covariances, got some that are not"
        )
    w = torch.linalg.solve_triangular(L, nu.unsqueeze(-1), upper=False).squeeze(-1)
    d2 = (w * w).sum(-1)
    logdet = 2.0 * torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    ll = -0.5 * (d2 + logdet + m * math.log(2.0 * math.pi))
    pd = _mode_pd(sensor, config, pred.x, pred.P)
    is_stop = _stop_mask(config)
    sees_stop = stop_detectable(sensor)
    log_cbar = torch.log(pred.cbar)
    det = _pd_mode_ll(ll, torch.ones((B, M), dtype=torch.bool), pd.unsqueeze(1), is_stop, sees_stop)
    miss = _pd_mode_ll(
        torch.zeros_like(pd), torch.zeros(B, dtype=torch.bool), pd, is_stop, sees_stop
    )
    return VSIMMAssociation(
        torch.logsumexp(det + log_cbar.unsqueeze(1), -1),
        torch.logsumexp(miss + log_cbar, -1),
        d2,
    )


def vsimm_step(
    state: VSIMMState,
    net: RoadNetwork,
    config: VSIMMConfig,
    t: Any,
    z: Any,
    sensor: Any,
    *,
    detected: Any | None = None,
) -> tuple[VSIMMState, VSIMMUpdate]:
    """:func:`vsimm_predict` then :func:`vsimm_update` (one scan for all rows).

    Raises:
        TypeError: ``sensor`` is not a sensor model (checked before the prediction).
        ValueError: as :func:`vsimm_predict` and :func:`vsimm_update`.

    Examples:
        >>> from hocnet.tracking.sensors import VideoSensor
        >>> net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]]])
        >>> cfg = VSIMMConfig()
        >>> s = vsimm_init(net, torch.tensor([[0.0, 10.0, 0.0, 0.0]]),
        ...                torch.diag(torch.tensor([100.0, 4.0, 100.0, 4.0])), cfg)
        >>> s, out = vsimm_step(s, net, cfg, 10.0, torch.tensor([[101.0, 2.0]]), VideoSensor())
        >>> s.combined()[0][0, 2].abs().item() < 1e-9  # on the road y = 0
        True
    """
    _check_sensor(sensor)
    pred = vsimm_predict(state, net, config, t)
    return vsimm_update(state, pred, z, sensor, net, config, detected=detected)


# ------------------------------------------------------------------------------------------
# Road-section hypotheses at junctions: 24.38-24.40
# ------------------------------------------------------------------------------------------


def section_probabilities(
    mu_prev: Any, log_lambda: Any, omega: Any, valid: Any | None = None
) -> torch.Tensor:
    """Section-hypothesis probabilities, eq. 24.38 (our reading of the sum limit), batched.

    ``mu_h(k) = Lambda_h(k) sum_{h_bar} Omega[h_bar, h] mu_h_bar(k-1) / c`` over the hypotheses
    of each track (padded to ``H``; ``valid`` masks the real ones).

    Args:
        mu_prev: ``(T, H)`` probabilities at ``k-1`` (0 for newly spawned hypotheses).
        log_lambda: ``(T, H)`` ``log Lambda_h`` (24.32 of each hypothesis' IMM).
        omega: ``(H, H)`` or ``(T, H, H)``, ``omega[..., h_bar, h] = P(h_bar -> h)``.
        valid: ``(T, H)`` bool, default all.

    Returns:
        ``(T, H)`` float64, rows summing to 1 over valid entries (0 elsewhere).

    Examples:
        >>> section_probabilities(torch.tensor([[0.5, 0.5]]), torch.log(torch.tensor([[1.0, 3.0]])),
        ...                       torch.eye(2))
        tensor([[0.2500, 0.7500]], dtype=torch.float64)
    """
    mu = as_float64("mu_prev", mu_prev, min_dim=2)
    ll = torch.as_tensor(log_lambda, dtype=DTYPE)
    if ll.shape != mu.shape:
        raise ValueError(f"`log_lambda`: expected shape {tuple(mu.shape)}, got {tuple(ll.shape)}")
    om = as_float64("omega", omega, min_dim=2)
    Hn = mu.shape[-1]
    if om.shape[-2:] != (Hn, Hn):
        raise ValueError(
            f"`omega`: expected shape ({Hn}, {Hn}) or (T, {Hn}, {Hn}), got {tuple(om.shape)}"
        )
    val = (
        torch.ones_like(mu, dtype=torch.bool)
        if valid is None
        else torch.as_tensor(valid, dtype=torch.bool)
    )
    mu = torch.where(val, mu, torch.zeros_like(mu))
    prior = (mu.unsqueeze(-1) * om).sum(-2)  # sum over valid hbar of mu_hbar Omega[hbar, h]
    a = torch.where(
        val & (prior > 0), ll + torch.log(prior.clamp(min=1e-300)), torch.full_like(ll, -torch.inf)
    )
    total = torch.logsumexp(a, -1, keepdim=True)
    out = torch.exp(a - total)
    return torch.where(torch.isfinite(total), out, torch.zeros_like(out))


def sprt_decide(
    mu: Any, upper: float, lower: float, valid: Any | None = None, *, reject: str = "all"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Wald's SPRT on hypothesis probabilities, eq. 24.39-24.40, batched over tracks.

    Accept ``h`` when ``mu_h / mu_h' >= upper`` for all valid ``h' != h``; reject ``h`` when
    ``mu_h / mu_h' <= lower`` for all valid ``h' != h`` (``reject="all"``, as printed, the
    default); otherwise wait for the next scan. A track with a single valid hypothesis accepts it.

    With three or more hypotheses the printed 24.40 never rejects a hypothesis dominated by the
    best one but not by a weaker third (``mu = [.98, .019, .001]``, bounds 99 and 1/99: the
    second is not rejected since ``.019 / .001 > 1/99``, and nothing is accepted since
    ``.98 / .019 < 99``). ``reject="best"`` (our option, Armitage's multi-hypothesis SPRT form
    of pairwise tests against the leader, Armitage 1950) rejects ``h`` when
    ``mu_h / max_{h' != h} mu_h' <= lower``, i.e. when the best other hypothesis dominates it.

    Args:
        mu: ``(T, H)`` probabilities.
        upper: acceptance bound (the upper bound ``(1 - beta) / alpha``).
        lower: rejection bound (the lower bound ``beta / (1 - alpha)``).
        valid: ``(T, H)`` bool.
        reject: ``"all"`` (24.40 as printed) or ``"best"`` (dominated by the best other one).

    Returns:
        ``(accepted, rejected)``: two ``(T, H)`` bool tensors.

    Examples:
        >>> acc, rej = sprt_decide(torch.tensor([[0.995, 0.005]]), 99.0, 0.0101)
        >>> acc.tolist(), rej.tolist()
        ([[True, False]], [[False, True]])
    """
    mu = as_float64("mu", mu, min_dim=2)
    val = (
        torch.ones_like(mu, dtype=torch.bool)
        if valid is None
        else torch.as_tensor(valid, dtype=torch.bool)
    )
    num = mu.unsqueeze(-1)
    den = mu.unsqueeze(-2)
    ratio = torch.where(den > 0, num / den.clamp(min=1e-300), torch.where(num > 0, torch.inf, 1.0))
    others = val.unsqueeze(-2) & ~torch.eye(mu.shape[-1], dtype=torch.bool)
    acc = torch.where(others, ratio >= upper, torch.ones_like(others)).all(-1) & val
    check_choice("reject", reject, ("all", "best"))
    if reject == "all":
        rej = torch.where(others, ratio <= lower, torch.ones_like(others)).all(-1) & val
    else:
        rej = torch.where(others, ratio <= lower, torch.zeros_like(others)).any(-1) & val
    rej = rej & others.any(-1)  # a lone hypothesis is never rejected
    return acc, rej


def section_transition(
    net: RoadNetwork,
    sections: Any,
    *,
    same_kind: float = 1.0,
    other_kind: float = 0.2,
    key: str = "kind",
) -> torch.Tensor:
    """``Omega`` of 24.38 between the roads of hypotheses, ``(..., H, H)`` (our choice of values).

    ``Omega[h_bar, h]`` proportional to ``same_kind`` when the two sections have the same
    ``properties[key]`` (e.g. highway -> highway) and to ``other_kind`` otherwise (highway ->
    byway: "the transition probability is small"), rows normalised to 1.

    Args:
        net: road network.
        sections: ``(..., H)`` int section indices.
        same_kind: weight of a transition between sections of the same kind.
        other_kind: weight between different kinds.
        key: the properties key holding the kind.

    Examples:
        >>> net = RoadNetwork([[[0, 0], [1, 0]], [[1, 0], [2, 0]], [[1, 0], [1, 1]]],
        ...                   [{"kind": "highway"}, {"kind": "highway"}, {"kind": "byway"}])
        >>> section_transition(net, torch.tensor([1, 2]))
        tensor([[0.8333, 0.1667],
                [0.1667, 0.8333]], dtype=torch.float64)
    """
    same = check_number("same_kind", same_kind, low=0.0)
    other = check_number("other_kind", other_kind, low=0.0)
    secs = torch.as_tensor(sections, dtype=torch.int64)
    kinds = [p.get(key) for p in net.section_properties]
    codes = {k: i for i, k in enumerate(dict.fromkeys(map(repr, kinds)))}
    kind_id = torch.tensor([codes[repr(k)] for k in kinds], dtype=torch.int64)
    kid = kind_id[secs.clamp(min=0)]
    w = torch.where(kid.unsqueeze(-1) == kid.unsqueeze(-2), same, other).to(DTYPE)
    return w / w.sum(-1, keepdim=True)


def _groups(track: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rows grouped by track: ``index (T, H)`` of rows (``-1`` padding), ``valid``, track ids."""
    ids, inv = torch.unique(track, return_inverse=True)
    T = ids.numel()
    counts = torch.bincount(inv, minlength=T)
    Hn = int(counts.max()) if T else 0
    order = torch.argsort(inv, stable=True)
    starts = torch.cumsum(counts, 0) - counts
    pos = torch.arange(track.numel()) - starts[inv[order]]
    index = torch.full((T, Hn), -1, dtype=torch.int64)
    index[inv[order], pos] = order
    return index, index >= 0, ids


def vsimm_section_sprt(
    state: VSIMMState,
    log_lambda: Any,
    net: RoadNetwork,
    *,
    alpha: float = 0.01,
    beta: float = 0.01,
    omega: Any | None = None,
    reject: str = "all",
) -> tuple[VSIMMState, torch.Tensor]:
    """Update ``mu_section`` by 24.38 and keep the rows the SPRT (24.39-24.40) does not reject.

    Rows are grouped by ``state.track``; when a hypothesis is accepted the other rows of its
    track are dropped; rejected rows are dropped; survivors' ``mu_section`` are renormalised.

    Args:
        state: rows after :func:`vsimm_update`.
        log_lambda: ``(B,)`` ``log Lambda`` of each row (``VSIMMUpdate.log_likelihood``).
        net: road network (for :func:`section_transition` when ``omega`` is None).
        alpha: SPRT probability of accepting a wrong section (:func:`sprt_thresholds`).
        beta: SPRT probability of rejecting the true section.
        omega: optional callable ``sections (T, H) -> (T, H, H)`` or a fixed ``(H, H)`` tensor.
        reject: the rejection rule of :func:`sprt_decide` (``"all"``, 24.40 as printed, or
            ``"best"``).

    The defaults ``alpha = beta = 0.01`` differ from the track-status SPRT of the MHT
    (``1e-3``): this test chooses among road-section hypotheses that must be settled within a
    few scans after a junction (symmetric errors, ratio bounds 99 and 1/99), while the track
    status weighs a false confirmation against a lost target over a whole track life.

    Returns:
        ``(kept_state, kept_rows)`` with ``kept_rows`` the ``(B',)`` indices into ``state``.

    Examples:
        >>> net = RoadNetwork([[[0, 0], [1, 0]], [[1, 0], [2, 0]], [[1, 0], [1, 1]]])
        >>> s = vsimm_init(net, torch.zeros(2, 4), torch.eye(4), VSIMMConfig(),
        ...                section=torch.tensor([1, 2]), track=torch.tensor([0, 0]))
        >>> s = s._replace(mu_section=torch.tensor([0.5, 0.5], dtype=torch.float64))
        >>> kept, rows = vsimm_section_sprt(s, torch.tensor([0.0, -8.0]), net)
        >>> rows.tolist(), kept.mu_section.tolist()
        ([0], [1.0])
    """
    B = state.mu.shape[0]
    ll = torch.as_tensor(log_lambda, dtype=DTYPE)
    if ll.shape != (B,):
        raise ValueError(f"`log_lambda`: expected shape ({B},), got {tuple(ll.shape)}")
    ln_lower, ln_upper = sprt_thresholds(alpha, beta)
    upper, lower = math.exp(ln_upper), math.exp(ln_lower)
    index, valid, _ = _groups(state.track)
    safe = index.clamp(min=0)
    secs = state.section[safe]
    if omega is None:
        om = section_transition(net, secs)
    elif callable(omega):
        om = omega(secs)
    else:
        om = as_float64("omega", omega, min_dim=2)
    mu_prev = torch.where(valid, state.mu_section[safe], torch.zeros_like(secs, dtype=DTYPE))
    mu = section_probabilities(mu_prev, ll[safe], om, valid)
    acc, rej = sprt_decide(mu, upper, lower, valid, reject=reject)
    keep = valid & ~rej
    has_acc = acc.any(-1, keepdim=True)
    keep = torch.where(has_acc, acc, keep)
    mu_k = torch.where(keep, mu, torch.zeros_like(mu))
    mu_k = mu_k / mu_k.sum(-1, keepdim=True).clamp(min=1e-300)
    rows = index[keep]
    rows = torch.sort(rows).values
    new_mu = torch.zeros(B, dtype=DTYPE)
    new_mu[index[keep]] = mu_k[keep]
    out = state._replace(mu_section=new_mu).select(rows)
    return out, rows


def vsimm_expand_sections(
    state: VSIMMState,
    net: RoadNetwork,
    dt: float,
    *,
    n_sigma: float = 3.0,
) -> VSIMMState:
    """Add one row per road section reachable within the next scan (junction hypotheses, 24.4.3).

    For each row with a section hypothesis: its combined estimate is located on the row's
    section, the travel ``|v| dt + n_sigma sqrt(trace P_pos)`` (m) gives the reachable segments
    (:meth:`~hocnet.tracking.road.RoadNetwork.reachable`; only ahead when the along-road speed
    exceeds ``n_sigma`` of its standard deviation, both ways otherwise), and every section among
    them that the track does not have yet becomes a new row (a copy of the row, with
    ``mu_section = 0``: 24.38 gives it probability through ``Omega`` at the next update).

    Returns:
        The rows of ``state`` followed by the new rows (``state`` itself when nothing is added).

    Examples:
        >>> net = RoadNetwork([[[0, 0], [100, 0]], [[100, 0], [200, 0]], [[100, 0], [100, 90]]])
        >>> s = vsimm_init(net, torch.tensor([[90.0, 10.0, 0.0, 0.0]]), torch.eye(4),
        ...                VSIMMConfig(), mu0=torch.tensor([0.0, 0.5, 0.5]))
        >>> vsimm_expand_sections(s, net, 10.0).section.tolist()
        [0, 1, 2]
    """
    dt = check_number("dt", dt, low=0.0)
    B = state.mu.shape[0]
    if B == 0:
        return state
    xc, Pc = state.combined()
    sec_rows = state.section >= 0
    loc = net.locate(xc, allowed=net.section_mask(state.section))
    speed = torch.linalg.vector_norm(xc[:, [1, 3]], dim=-1)
    spread = torch.sqrt(Pc[:, 0, 0] + Pc[:, 2, 2]).clamp(min=0.0)
    travel = speed * dt + n_sigma * spread
    # travel direction along the segment when the along-road speed is significant
    u = net.direction[loc.segment]
    v_along = (u * xc[:, [1, 3]]).sum(-1)
    Pv = Pc[:, [1, 3]][:, :, [1, 3]]
    sd_v = (u.unsqueeze(-2) @ Pv @ u.unsqueeze(-1)).flatten().clamp(min=0.0).sqrt()
    direction = torch.where(v_along.abs() > n_sigma * sd_v, torch.sign(v_along), 0.0)
    reach = net.reachable(loc.segment, loc.abscissa, travel, direction=direction)
    # sections reached by each row, (B, n_sections), restricted to rows with a hypothesis
    onehot = torch.nn.functional.one_hot(net.segment_section, net.num_sections).to(DTYPE)
    reached = ((reach.to(DTYPE) @ onehot) > 0) & sec_rows.unsqueeze(-1)
    ids, inv = torch.unique(state.track, return_inverse=True)
    have = torch.zeros(ids.numel(), net.num_sections, dtype=torch.bool)
    have[inv[sec_rows], state.section[sec_rows]] = True
    cand = reached & ~have[inv]
    # one new row per (track, section): a copy of the first row of the track that reaches it
    T, n_sec = ids.numel(), net.num_sections
    rows_of = torch.arange(B).unsqueeze(-1).expand(B, n_sec)
    flat = (inv.unsqueeze(-1) * n_sec + torch.arange(n_sec))[cand]
    first = torch.full((T * n_sec,), B, dtype=torch.int64)
    first = first.scatter_reduce(0, flat, rows_of[cand], "amin").view(T, n_sec)
    new_tr, sec = torch.nonzero(first < B, as_tuple=True)
    if not sec.numel():
        return state
    idx = first[new_tr, sec]
    add = state.select(idx)
    add = add._replace(section=sec, mu_section=torch.zeros(sec.numel(), dtype=DTYPE))
    return VSIMMState(
        *(None if a is None else torch.cat([a, b_]) for a, b_ in zip(state, add, strict=True))
    )


# ------------------------------------------------------------------------------------------
# Out-of-sequence measurements on the road (24.4.5)
# ------------------------------------------------------------------------------------------


def _refresh_memory(
    P_pred: torch.Tensor,
    x: torch.Tensor,
    P: torch.Tensor,
    g: torch.Tensor,
    G: torch.Tensor,
    x_new: torch.Tensor,
    P_new: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """A1 memory after an OOSM update, so that a further OOSM of the interval stays consistent.

    A1 retrodicts from ``x(k|k) = x(k|k-1) + P(k|k-1) g`` and
    ``P(k|k) = P(k|k-1) - P(k|k-1) G P(k|k-1)``. An OOSM update changes ``x(k|k), P(k|k)`` but
    not ``g, G``: a second OOSM of the same interval then retrodicted with a stale memory, and
    its covariance was indefinite (seen down to -1e17 relative in the 24.6 experiment). Our
    fix: the memory is rewritten so that both identities hold for the updated estimate,
    ``g' = g + P(k|k-1)^+ (x' - x)`` and ``G' = G + P(k|k-1)^+ (P - P') P(k|k-1)^+``, i.e. the
    information of the delayed measurement is kept as information on ``x(k)`` (its part on the
    process noise of the interval is dropped: approximate, as any sequence of A1 updates in one
    interval, but ``0 <= G' <= P(k|k-1)^+`` on the range of ``P(k|k-1)`` since
    ``0 <= P' <= P(k|k-1)``, so the next retrodiction is a valid conditioning: positive
    semi-definite). Unchanged rows (``P' = P``) keep their memory.
    """
    Pp = 0.5 * (P_pred + P_pred.transpose(-1, -2))
    Pinv = torch.linalg.pinv(Pp, hermitian=True, rtol=1e-12)
    dP = P - P_new
    dP = 0.5 * (dP + dP.transpose(-1, -2))
    g_new = g + (Pinv @ (x_new - x).unsqueeze(-1)).squeeze(-1)
    G_new = G + Pinv @ dP @ Pinv
    return g_new, 0.5 * (G_new + G_new.transpose(-1, -2))


def vsimm_oosm(
    state: VSIMMState,
    z: Any,
    t: Any,
    sensor: Any,
    net: RoadNetwork,
    config: VSIMMConfig,
    *,
    detected: Any | None = None,
    too_old: str = "raise",
    lag_memory: VSIMMLagMemory | None = None,
    lag_method: str = "rts",
) -> tuple[VSIMMState, VSIMMUpdate | VSIMMOOSMUpdate]:
    """Update all rows with measurements taken at ``t <= state.t`` (A1 per mode, on the road).

    For every mode: ``F(tau, k)`` (CV with ``-(t_k - tau)``; the stop mode keeps its position),
    ``Q(k, tau)`` over ``t_k - tau`` (``config.noise``) with the mode's last acceleration
    covariance, the A1 retrodiction (:mod:`hocnet.tracking.oosm`), the retrodiction projected on
    the segment of the section nearest to the retrodicted position (24.14-24.16, "retrodiction
    done on the road"; a retrodiction behind the junction the mode passed after ``tau`` is first
    carried back onto the segment it came from, by the inverse of the junction map of the last
    step kept in the state, ``config.junction_retro``, :func:`_retro_junction`), the A1 update of
    ``x(k|k)``, the projection of the result on the mode's
    current segment, and the mode probabilities ``mu_i ∝ mu_i Lambda_i(tau)`` with the
    PD-aware likelihoods of 24.30-24.31 (the IMM-OOSM of Bar-Shalom and Chen, the chapter's [3],
    in its simplest form: mode probabilities at ``t_k`` re-weighted; our reading). With the
    chapter's piecewise-constant acceleration (``config.noise="discrete"``) the cross
    covariance of the state and the noise after ``tau`` is ``Gamma(dt) Sigma Gamma(lag)'``, not
    A1's ``Q(k, tau)`` (which made even a first retrodiction indefinite); see
    :func:`hocnet.tracking.oosm._retrodict`. After the update the A1 memory ``g, G`` is
    rewritten for the updated estimate (``_refresh_memory``), so several OOSMs in one interval
    keep positive semi-definite covariances (approximate beyond the first, our addition).

    Args:
        state: rows at time ``t_k``.
        z: ``(B, m)`` delayed measurements (NaN allowed where ``detected`` is False).
        t: scalar or ``(B,)`` measurement times, s, with ``t_{k-1} <= t <= t_k``.
        sensor: the sensor of the delayed measurements.
        net: road network.
        config: :class:`VSIMMConfig`.
        detected: ``(B,)`` bool (default all).
        too_old: policy for a measurement older than the one-step lag (``t < t_{k-1}``; only
            the one-step A1 is implemented, see :mod:`hocnet.tracking.oosm`): ``"raise"``
            (default, backward compatible) or ``"drop"``: the row is left unchanged as if not
            detected, and the result is a :class:`VSIMMOOSMUpdate` whose ``dropped`` mask
            counts them (the policy a pipeline should use).
        lag_memory: optional :class:`VSIMMLagMemory` of depth ``N`` (our addition): rows
            whose ``t`` is older than the one-step lag use the multi-step Al1 (``t >= t_{k-N}``)
            or, before the row's birth, a diffuse-prior retrodiction (``_vsimm_oosm_lag``);
            ``too_old`` then applies to ``t < t_{k-N}``. ``None``: the one-step A1 only.
        lag_method: the retrodiction of a report ``1 < l <= N`` steps old: ``"rts"`` (default)
            the exact storage-based Rauch-Tung-Striebel retrodiction per mode from the memory's
            per-step fields (``_lag_rts``; falls back to Al1 for a memory without them),
            ``"al1"`` the equivalent-measurement Al1 (approximate: measured further from the
            in-order answer than dropping the report in the issue 12 review).

    Returns:
        ``(new_state, VSIMMUpdate)`` (``VSIMMOOSMUpdate`` with ``too_old="drop"``); undetected
        and dropped rows are unchanged.

    Raises:
        ValueError: with ``too_old="raise"``, a measurement older than the one-step lag
            (message names the lag; ``state`` is not modified); non-finite measurements, bad
            shapes.
        TypeError: ``sensor`` is not a sensor model.

    Examples:
        >>> from hocnet.tracking.sensors import VideoSensor
        >>> net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]]])
        >>> cfg, video = VSIMMConfig(), VideoSensor(10.0)
        >>> s = vsimm_init(net, torch.tensor([[0.0, 10.0, 0.0, 0.0]]), 100 * torch.eye(4), cfg)
        >>> s, _ = vsimm_step(s, net, cfg, 10.0, torch.tensor([[100.0, 0.0]]), video)
        >>> s, _ = vsimm_step(s, net, cfg, 20.0, torch.tensor([[200.0, 0.0]]), video)
        >>> s2, out = vsimm_oosm(s, torch.tensor([[150.0, 0.0]]), 15.0, video, net, cfg)
        >>> vsimm_oosm(s, torch.tensor([[50.0, 0.0]]), 5.0, video, net, cfg)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: `t`: expected an out-of-sequence measurement within the one-step lag ... 15 s
    """
    _check_sensor(sensor)
    if lag_memory is not None:
        return _vsimm_oosm_lag(
            state,
            lag_memory,
            z,
            t,
            sensor,
            net,
            config,
            detected=detected,
            too_old=too_old,
            method=lag_method,
        )
    B = state.mu.shape[0]
    tau = _times("t", t, B)
    check_oosm_time(tau, state.t_prev, state.t, too_old=too_old)
    det = _detected_mask(detected, B)
    dropped = oosm_too_old(tau, state.t_prev, state.t) & det
    if bool(dropped.any()):
        det = det & ~dropped
        tau = torch.where(dropped, state.t_prev.expand(B), tau)  # any in-lag time: unused
    zt = _measurement(z, sensor, det)
    r0 = _a1_retrodiction(state, tau, config)
    new, ll_out, mode_ll = _oosm_finish(
        state, r0, zt, det, sensor, net, config, back_across_junction=True
    )
    return _oosm_result(new, ll_out, mode_ll, dropped, too_old)


def _a1_retrodiction(state: VSIMMState, tau: torch.Tensor, config: VSIMMConfig) -> Retrodiction:
    """One-step A1 retrodiction of every mode to ``tau (B,)`` (:func:`vsimm_oosm`), off-road.

    ``F(tau, k)``, ``Q(k, tau)`` with the mode's last acceleration covariance and, for
    ``config.noise="discrete"``, the cross covariance ``Gamma(dt) S Gamma(lag)'`` of one
    acceleration over the whole interval (:func:`hocnet.tracking.oosm._retrodict`).
    """
    B = state.mu.shape[0]
    lag = state.t - tau
    Fb, _ = _mode_F(config.kinds, -lag)
    _, Gm = _mode_F(config.kinds, lag)
    Q = _process_noise(config.kinds, config.noise, lag, Gm, state.accel_cov)
    C0 = None
    if config.noise == "discrete":
        # one acceleration over the whole interval: cov(x(k), w(k, tau)) = Gamma(dt) S Gamma(lag)'
        _, Gd = _mode_F(config.kinds, (state.t - state.t_prev).expand(B))
        C0 = Gd @ state.accel_cov @ Gm.transpose(-1, -2)
    return _retrodict(state.x, state.P, state.P_pred, state.g, state.G, Fb, Q, C0)


#: Attributes the VS-IMM uses on a sensor model (``GMTISensor``, ``VideoSensor`` have them).
_SENSOR_ATTRS = ("dim", "pd", "measure", "linearize")


def _check_sensor(sensor: Any) -> Any:
    """Raise ``TypeError`` naming ``sensor`` unless it is a sensor model (issue 12, bad input).

    A sensor name such as ``"gmti"`` is not a model: make one with
    :func:`~hocnet.tracking.sensors.make_sensor`.
    """
    missing = [a for a in _SENSOR_ATTRS if not hasattr(sensor, a)]
    if missing:
        hint = (
            " (a name: build the model with make_sensor(name))" if isinstance(sensor, str) else ""
        )
        raise TypeError(
            "`sensor`: expected a sensor model such as GMTISensor or VideoSensor (with "
            f"{', '.join(_SENSOR_ATTRS)}), got {type(sensor).__name__} {sensor!r:.60}{hint}"
        )
    return sensor


def _detected_mask(detected: Any | None, B: int) -> torch.Tensor:
    """``(B,)`` bool ``detected`` of the OOSM updates (all ``True`` for ``None``), checked."""
    det = (
        torch.ones(B, dtype=torch.bool)
        if detected is None
        else torch.as_tensor(detected, dtype=torch.bool)
    )
    if det.shape != (B,):
        raise ValueError(f"`detected`: expected shape ({B},), got {tuple(det.shape)}")
    return det


def _measurement(z: Any, sensor: Any, det: torch.Tensor) -> torch.Tensor:
    """``(B, m)`` float64 ``z`` of an update, checked (finite where ``det``)."""
    B, m = det.shape[0], sensor.dim
    zt = torch.as_tensor(z, dtype=DTYPE)
    if zt.shape != (B, m):
        raise ValueError(
            f"`z`: expected shape ({B}, {m}) for sensor {sensor.name!r}, got {tuple(zt.shape)}"
        )
    check_measurements("z", zt[det], m)
    return zt


def _oosm_result(
    new: VSIMMState,
    ll_out: torch.Tensor,
    mode_ll: torch.Tensor,
    dropped: torch.Tensor,
    too_old: str,
) -> tuple[VSIMMState, VSIMMUpdate | VSIMMOOSMUpdate]:
    """The return value of :func:`vsimm_oosm` (with ``dropped`` for ``too_old="drop"``)."""
    if too_old == "drop":
        return new, VSIMMOOSMUpdate(ll_out, mode_ll, dropped)
    return new, VSIMMUpdate(ll_out, mode_ll)


def _retro_junction(
    state: VSIMMState,
    r0: Retrodiction,
    seg_tau: torch.Tensor,
    net: RoadNetwork,
    config: VSIMMConfig,
    rows: torch.Tensor | None = None,
) -> tuple[Retrodiction, torch.Tensor]:
    """Carry a retrodiction back across the junction the mode passed after ``tau`` (ours).

    The A1 retrodiction extrapolates ``x(k|k)`` backwards with the constant velocity of the
    mode's current segment. When the target crossed a junction between ``tau`` and ``t_k`` the
    back-extrapolated position lies on the straight extension of the current segment behind the
    node, and its covariance (constrained to the current segment) has no across-road spread:
    the projection on the segment located at ``tau`` (24.14-24.16) then moves it *along the
    current segment* to the node, with zero variance, and the report's likelihood collapses
    (issue 12: a UGS report 9 m from the target got ``ln Lambda = -32`` against ``-11`` for the
    stop mode 35 m away; every moving mode lost its probability and the track stopped at the
    junction, seed 2405, target 2, t = 563 s). The backward counterpart of
    :func:`junction_transition`: positions rotate about the shared node and velocities by the
    angle between the two segments (the distance travelled and the speed are kept), covariance
    ``T P T'`` and cross covariance ``C T'``; rows / modes not behind a node shared by the two
    segments are unchanged.

    ``config.junction_retro`` (only with ``config.junction == "rotate"``):

    - ``"state"`` (default): the inverse of the last step's junction map, kept in the state:
      for a moving road mode whose segment changed in its last step
      (``state.segment_prev != state.segment``, crossed node ``J = state.junction_node``) and
      whose retrodicted position lies behind ``J`` on the current segment's line
      (``(p - J) . u < 0``, ``u`` the direction leaving ``J`` along the current segment), the
      rotation about ``J`` taking ``u`` to the direction of travel on ``segment_prev`` into
      ``J``; that mode's segment at ``tau`` is ``segment_prev``. The old segment is known, not
      guessed, at any junction shape (crossroads, T junctions from the stem or along the bar,
      bends of 90 degrees or more) and whatever the row's section hypothesis. A retrodiction
      ahead of ``J`` (the target had crossed it by ``tau``) is unchanged.
    - ``"locate"`` (the former behaviour, for side-by-side measurement): the segment at ``tau``
      is *guessed* with ``net.locate`` of the straight back-extrapolation (``seg_tau``),
      nearest segment of the row's section, ties to the lowest index. Right for shallow bends;
      at a 4-way crossroad or a T junction approached from the stem the extension lies on the
      collinear arm, so the rotation is the identity and the stop-mode collapse stays; at bends
      of 90 degrees or more a tie can pick the current segment (no change) or, at a T junction
      approached along the bar, the wrong arm (a review measured 60 m error against 20 m
      without this step); a leaf whose pending section hypothesis masks the old section is not
      corrected.
    - ``"off"``: no correction.

    Limits (both): one node is undone (as :func:`junction_transition` passes one per step).

    Args:
        state: rows at ``t_k``.
        r0: the A1 retrodiction ``(B, r, ...)``.
        seg_tau: ``(B, r)`` int64 segments located at ``r0.x`` (``"locate"``).
        net: road network.
        config: :class:`VSIMMConfig`.
        rows: ``(B,)`` bool, the rows to correct (default all).

    Returns:
        The retrodiction and ``(B, r)`` the segment of each mode at ``tau`` (``seg_tau``, or
        ``segment_prev`` where the state's junction map was inverted).
    """
    mode = config.junction_retro if config.junction == "rotate" else "off"
    B = state.mu.shape[0]
    if mode == "off" or not state.mu.numel():
        return r0, seg_tau
    moving = torch.tensor([k == "road" for k in config.kinds]).view(1, -1)
    if rows is not None:
        moving = moving & rows.view(B, 1)
    seg_k = state.segment
    if mode == "locate":
        cand = moving & (seg_k >= 0) & (seg_tau >= 0) & (seg_k != seg_tau)
        if not bool(cand.any()):
            return r0, seg_tau
        flip = torch.tensor([1.0, -1.0, 1.0, -1.0], dtype=DTYPE)
        new = torch.where(cand, seg_tau, seg_k)
        T, b = junction_transition(net, seg_k, new, state.x * flip, r0.x * flip, moving)
    else:
        if state.segment_prev is None or state.junction_node is None:
            return r0, seg_tau
        T, b, ok = _junction_inverse(
            net, seg_k, state.segment_prev, state.junction_node, r0.x, moving
        )
        if not bool(ok.any()):
            return r0, seg_tau
        seg_tau = torch.where(ok, state.segment_prev, seg_tau)
    x = (T @ r0.x.unsqueeze(-1)).squeeze(-1) + b
    Tt = T.transpose(-1, -2)
    P = T @ r0.P @ Tt
    return Retrodiction(x, 0.5 * (P + P.transpose(-1, -2)), r0.C @ Tt), seg_tau


def _junction_inverse(
    net: RoadNetwork,
    seg: torch.Tensor,
    seg_prev: torch.Tensor,
    node: torch.Tensor,
    x: torch.Tensor,
    moving: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Inverse junction map ``x -> T x + b`` from ``seg`` back onto ``seg_prev`` about ``node``.

    ``u``: the direction leaving ``J = nodes[node]`` along ``seg``; ``w``: along ``seg_prev``.
    The forward map (:func:`junction_transition`) rotated the direction of travel into ``J``
    on ``seg_prev`` (``-w``) onto ``u``; ``T`` rotates ``u`` onto ``-w`` (positions about ``J``,
    velocities about the origin). Applied (``ok``) to moving modes with ``seg != seg_prev``,
    a valid ``node`` that ends both segments, and ``x`` behind ``J`` (``(p - J) . u < 0``);
    ``T = I``, ``b = 0`` elsewhere. Shapes ``(B, r)``, ``x (B, r, 4)``; returns
    ``T (B, r, 4, 4)``, ``b (B, r, 4)``, ``ok (B, r)`` bool.
    """
    B, r = seg.shape
    T = torch.eye(4, dtype=DTYPE).expand(B, r, 4, 4).clone()
    b = torch.zeros(B, r, 4, dtype=DTYPE)
    sk, sp, nd = seg.clamp(min=0), seg_prev.clamp(min=0), node.clamp(min=0)
    ends_k, ends_p = net.segment_nodes[sk], net.segment_nodes[sp]
    touch = (ends_k == nd.unsqueeze(-1)).any(-1) & (ends_p == nd.unsqueeze(-1)).any(-1)
    u = torch.where((ends_k[..., 0] == nd).unsqueeze(-1), net.direction[sk], -net.direction[sk])
    w = torch.where((ends_p[..., 0] == nd).unsqueeze(-1), net.direction[sp], -net.direction[sp])
    J = net.nodes[nd]
    behind = ((x[..., [0, 2]] - J) * u).sum(-1) < 0
    ok = moving & (seg >= 0) & (seg_prev >= 0) & (seg != seg_prev) & (node >= 0) & touch & behind
    if not bool(ok.any()):
        return T, b, ok
    c = -(u * w).sum(-1)  # rotation taking u to -w
    s = -(u[..., 0] * w[..., 1] - u[..., 1] * w[..., 0])
    R = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    T, b = _rotate_about(R, J, ok, T, b)
    return T, b, ok


def _road_retrodiction(
    state: VSIMMState,
    r0: Retrodiction,
    net: RoadNetwork,
    config: VSIMMConfig,
    back_across_junction: bool | torch.Tensor = False,
) -> Retrodiction:
    """The retrodiction ``r0`` carried across the last junction and projected on the road.

    ``back_across_junction`` (bool or ``(B,)`` bool): the rows whose ``r0`` is a one-step A1
    retrodiction (:func:`_retro_junction`). The projection is on the segment of each mode at
    ``tau``: the state's ``segment_prev`` where :func:`_retro_junction` inverted the junction
    map, else the segment of the section nearest to the retrodiction (24.14-24.16,
    "retrodiction done on the road"); road and stop modes only.
    """
    B = state.mu.shape[0]
    allowed = net.section_mask(state.section).unsqueeze(1)
    seg_tau = net.locate(r0.x, allowed=allowed).segment
    back = torch.as_tensor(back_across_junction, dtype=torch.bool).expand(B)
    if bool(back.any()):
        r0, seg_tau = _retro_junction(state, r0, seg_tau, net, config, back)
    on = state.segment >= 0
    D, L = net.constraint(seg_tau)
    xs, A = _projection(r0.x, r0.P, D, L)
    At = A.transpose(-1, -2)
    onx = on.unsqueeze(-1)
    return Retrodiction(
        torch.where(onx, xs, r0.x),
        torch.where(onx.unsqueeze(-1), A @ r0.P @ At, r0.P),
        torch.where(onx.unsqueeze(-1), r0.C @ At, r0.C),
    )


def _oosm_finish(
    state: VSIMMState,
    r0: Retrodiction,
    zt: torch.Tensor,
    det: torch.Tensor,
    sensor: Any,
    net: RoadNetwork,
    config: VSIMMConfig,
    back_across_junction: bool | torch.Tensor = False,
) -> tuple[VSIMMState, torch.Tensor, torch.Tensor]:
    """The common end of :func:`vsimm_oosm` and ``_vsimm_oosm_lag`` after the retrodiction.

    ``back_across_junction`` (bool or ``(B,)`` bool): first carry a one-step A1 retrodiction
    (a straight back-extrapolation along the current segment) back across a junction passed
    after ``tau`` (:func:`_retro_junction`); not for the lag memory's RTS, which undoes the
    junction rotation through its stored steps already.

    The retrodiction ``r0`` projected on the road (:func:`_road_retrodiction`, 24.14-24.16,
    "retrodiction done on the road"), the OOSM update of ``x(k|k)`` (:func:`_apply`), its
    projection on the mode's current segment, the mode probabilities re-weighted by the
    PD-aware likelihoods (24.30-24.31) and the A1 memory refreshed (:func:`_refresh_memory`).
    Returns ``(new_state, ln Lambda (B,), mode log-likelihoods (B, r))``; rows not ``det`` or
    with a non-finite likelihood are unchanged.
    """
    B, r = state.mu.shape
    m = sensor.dim
    r1 = _road_retrodiction(state, r0, net, config, back_across_junction)
    onx = (state.segment >= 0).unsqueeze(-1)
    xc = _combine(state.mu, r1.x, r1.P)[0]
    zt = torch.where(det.unsqueeze(-1), zt, sensor.measure(xc))
    hx, H, R = sensor.linearize(r1.x, zt.unsqueeze(1))
    H = H.expand(B, r, m, 4)
    R = R.expand(B, r, m, m)
    x_upd, P_upd, ll = _apply(state.x, state.P, r1, zt.unsqueeze(1) - hx, H, R)
    pd = _mode_pd(sensor, config, r1.x, r1.P)
    mode_ll = _pd_mode_ll(ll, det, pd, _stop_mask(config), stop_detectable(sensor))
    Dk, Lk = net.constraint(state.segment.clamp(min=0))
    xk, Ak = _projection(x_upd, P_upd, Dk, Lk)
    Pk = Ak @ P_upd @ Ak.transpose(-1, -2)
    x_upd = torch.where(onx, xk, x_upd)
    P_upd = torch.where(onx.unsqueeze(-1), 0.5 * (Pk + Pk.transpose(-1, -2)), P_upd)
    a = mode_ll + torch.log(state.mu)
    total = torch.logsumexp(a, -1, keepdim=True)
    ok = torch.isfinite(total).squeeze(-1) & det
    mu = torch.where(ok.unsqueeze(-1), torch.exp(a - total), state.mu)
    x_new = torch.where(ok.view(B, 1, 1), x_upd, state.x)
    P_new = torch.where(ok.view(B, 1, 1, 1), P_upd, state.P)
    g_new, G_new = _refresh_memory(state.P_pred, state.x, state.P, state.g, state.G, x_new, P_new)
    new = state._replace(mu=mu, x=x_new, P=P_new, g=g_new, G=G_new)
    ll_out = torch.where(det, total.squeeze(-1), torch.zeros(B, dtype=DTYPE))
    return new, ll_out, mode_ll


# ------------------------------------------------------------------------------------------
# Multi-step-lag OOSM on the road (our addition; see hocnet.tracking.oosm.oosm_al1)
# ------------------------------------------------------------------------------------------


class VSIMMLagMemory(NamedTuple):
    """Lag memory of ``B`` rows for the multi-step OOSM (Al1, see ``oosm.oosm_al1``).

    Entry ``j - 1`` (``j = 1 .. N``) holds the time ``t_{k-j}`` of the ``j``-th step back and the
    mode-matched prediction over the ``j`` last steps, ``x(k|k-j)`` and ``P(k|k-j)`` (entry 0 is
    the last prediction, after mixing; older entries are predicted step by step with each mode's
    own ``F`` and ``Q``, without mixing: our approximation). ``t = -inf`` marks steps before the
    row's birth (a delayed report older than the birth is retrodicted with a diffuse prior).

    For the exact storage-based retrodiction (``lag_method="rts"``, our addition) entry ``j - 1``
    also holds the step from ``t_{k-j}`` to ``t_{k-j+1}`` of each mode: the mixed estimate the
    mode's filter started from (``xf, Pf``: 24.34-24.35), its prediction (``xp, Pp``: the
    ``x(k-j+1|k-j)`` of the mode filter), the junction map ``T`` of the step
    (:func:`junction_transition`; identity elsewhere) and the acceleration covariance ``acc``.
    These fields are ``None`` in a memory built without them (then only Al1 is possible).

    Attributes:
        t: ``(B, N)`` float64 step times ``t_{k-1}, ..., t_{k-N}`` (s), ``-inf`` before birth.
        x: ``(B, N, r, 4)`` ``x(k|k-j)``.
        P: ``(B, N, r, 4, 4)`` ``P(k|k-j)``.
        xf: ``(B, N, r, 4)`` mixed estimate at ``t_{k-j}`` (or ``None``).
        Pf: ``(B, N, r, 4, 4)`` its covariance.
        xp: ``(B, N, r, 4)`` the mode prediction at ``t_{k-j+1}``.
        Pp: ``(B, N, r, 4, 4)`` its covariance.
        T: ``(B, N, r, 4, 4)`` the step's junction rotation (the prediction is
            ``xp = T F xf + b``).
        acc: ``(B, N, r, 2, 2)`` the step's acceleration covariance (m^2/s^4).
    """

    t: torch.Tensor
    x: torch.Tensor
    P: torch.Tensor
    xf: torch.Tensor | None = None
    Pf: torch.Tensor | None = None
    xp: torch.Tensor | None = None
    Pp: torch.Tensor | None = None
    T: torch.Tensor | None = None
    acc: torch.Tensor | None = None


def vsimm_lag_memory(state: VSIMMState, depth: int, *, rts: bool = True) -> VSIMMLagMemory:
    """Empty lag memory of depth ``N = depth`` for new rows (every entry before the birth).

    ``rts``: also allocate the per-step fields of the exact retrodiction (``xf .. acc``).

    Examples:
        >>> net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]]])
        >>> s = vsimm_init(net, torch.zeros(1, 4), 100 * torch.eye(4), VSIMMConfig())
        >>> vsimm_lag_memory(s, 3).t.tolist()
        [[-inf, -inf, -inf]]
    """
    if not isinstance(depth, int) or isinstance(depth, bool) or depth < 1:
        raise ValueError(f"`depth`: expected an int >= 1, got {depth!r}")
    B, r = state.mu.shape
    x = state.x.unsqueeze(1).repeat(1, depth, 1, 1)
    P = state.P.unsqueeze(1).repeat(1, depth, 1, 1, 1)
    if not rts:
        return VSIMMLagMemory(torch.full((B, depth), -math.inf, dtype=DTYPE), x, P)
    eye = torch.eye(4, dtype=DTYPE).expand(B, depth, r, 4, 4).clone()
    return VSIMMLagMemory(
        torch.full((B, depth), -math.inf, dtype=DTYPE),
        x,
        P,
        x.clone(),
        P.clone(),
        x.clone(),
        P.clone(),
        eye,
        torch.zeros(B, depth, r, 2, 2, dtype=DTYPE),
    )


def vsimm_lag_memory_step(
    memory: VSIMMLagMemory,
    state: VSIMMState,
    pred: VSIMMPrediction,
    config: VSIMMConfig,
    *,
    net: RoadNetwork | None = None,
) -> VSIMMLagMemory:
    """Lag memory after the in-sequence step ``state`` -> ``pred`` (update or miss).

    New entry 0: ``(state.t, pred.x, pred.P)``; entry ``j`` <- entry ``j - 1`` predicted over
    ``pred.t - state.t`` with each mode's ``F`` and ``Q`` (``pred.accel_cov``); the oldest entry
    is forgotten. With ``net`` (and ``config.junction == "rotate"``), an older entry whose road
    mode changes segment in this step (``state.segment`` -> ``pred.segment``, e.g. a junction
    hypothesis taken by the pipeline) is carried onto the new segment by the same
    :func:`junction_transition` as the prediction (``T x + b``, ``T P T'``), so that the memory
    stays consistent with ``pred`` (issue 12 review: after a junction switch the memory held the
    straight-on prediction 50 m off the road taken). ``pred`` must then be the prediction that
    the state was updated with. The RTS fields take the step's rotation from ``pred.T``
    (:func:`vsimm_predict` sets it), else recompute it with ``net``; with neither, a step
    through a junction is stored unrotated and its RTS retrodiction is inconsistent: pass
    ``net`` for a prediction rebuilt without ``T``.

    Examples:
        >>> net = RoadNetwork([[[0.0, 0.0], [1000.0, 0.0]]])
        >>> cfg = VSIMMConfig()
        >>> s = vsimm_init(net, torch.zeros(1, 4), 100 * torch.eye(4), cfg)
        >>> m = vsimm_lag_memory_step(vsimm_lag_memory(s, 2), s, vsimm_predict(s, net, cfg, 10.0),
        ...                           cfg)
        >>> m.t.tolist()
        [[0.0, -inf]]
    """
    B = state.mu.shape[0]
    dt = pred.t - state.t
    F, Gm = _mode_F(config.kinds, dt)
    Q = _process_noise(config.kinds, config.noise, dt, Gm, pred.accel_cov)
    ox = (F.unsqueeze(1) @ memory.x[:, :-1].unsqueeze(-1)).squeeze(-1)
    oP = F.unsqueeze(1) @ memory.P[:, :-1] @ F.transpose(-1, -2).unsqueeze(1)
    n_old = ox.shape[1]
    rts = memory.xf is not None
    r = state.mu.shape[1]
    if rts:
        _, omega = _mixing(state.mu, config.trans_tensor())
        x0, P0 = _mix(state.x, state.P, omega)
        T0 = torch.eye(4, dtype=DTYPE).expand(B, r, 4, 4)
        if pred.T is not None:
            T0 = pred.T
        elif net is not None and config.junction == "rotate" and B:
            moving = torch.tensor([k == "road" for k in config.kinds]).view(1, r)
            xs = (F @ x0.unsqueeze(-1)).squeeze(-1)
            T0, _ = junction_transition(net, state.segment, pred.segment, x0, xs, moving)
        step = (x0, P0, pred.x, pred.P, T0, pred.accel_cov)
        old_f = (memory.xf, memory.Pf, memory.xp, memory.Pp, memory.T, memory.acc)
        extra = tuple(
            torch.cat([a.unsqueeze(1), m[:, :-1]], 1) for a, m in zip(step, old_f, strict=True)
        )
    if net is not None and config.junction == "rotate" and n_old and B:
        r = state.mu.shape[1]
        moving = torch.tensor([k == "road" for k in config.kinds]).view(1, r)
        rep = (B * n_old, r)
        T, b = junction_transition(
            net,
            state.segment.unsqueeze(1).expand(B, n_old, r).reshape(rep),
            pred.segment.unsqueeze(1).expand(B, n_old, r).reshape(rep),
            memory.x[:, :-1].reshape(*rep, 4),
            ox.reshape(*rep, 4),
            moving,
        )
        T, b = T.view(B, n_old, r, 4, 4), b.view(B, n_old, r, 4)
        ox = (T @ ox.unsqueeze(-1)).squeeze(-1) + b
        oP = T @ oP @ T.transpose(-1, -2)  # the noise is added in the new frame, as the prediction
    oP = oP + Q.unsqueeze(1)
    return VSIMMLagMemory(
        torch.cat([state.t.view(B, 1), memory.t[:, :-1]], 1),
        torch.cat([pred.x.unsqueeze(1), ox], 1),
        torch.cat([pred.P.unsqueeze(1), 0.5 * (oP + oP.transpose(-1, -2))], 1),
        *(extra if rts else ()),
    )


def _vsimm_oosm_lag(
    state: VSIMMState,
    memory: VSIMMLagMemory,
    z: Any,
    t: Any,
    sensor: Any,
    net: RoadNetwork,
    config: VSIMMConfig,
    *,
    detected: Any | None,
    too_old: str,
    method: str = "rts",
) -> tuple[VSIMMState, VSIMMUpdate | VSIMMOOSMUpdate]:
    """:func:`vsimm_oosm` with a lag memory: A1 (one step), RTS or Al1 (``l <= N``), diffuse.

    ``method="rts"`` (with a memory holding the per-step fields): rows with ``1 < l <= N`` are
    retrodicted by :func:`_lag_rts` (exact per mode, given the stored mixed estimates, issue 12
    review); ``"al1"`` as below.

    Per row the lag ``l = 1 + #{j : t_{k-j} > tau}``. ``l = 1``: the A1 of :func:`vsimm_oosm`
    (memory ``g, G, P(k|k-1)`` of the state, road pseudo-measurement included). ``1 < l <= N``:
    Al1, the A1 retrodiction over ``[t_{k-l}, t_k]`` with the equivalent-measurement memory
    (:func:`hocnet.tracking.oosm.equivalent_memory` of ``x(k|k), P(k|k)`` and the stored
    ``x(k|k-l), P(k|k-l)``) and, for ``config.noise="discrete"``, the cross covariance of the
    per-step accelerations (:func:`hocnet.tracking.oosm.cv_discrete_lag_noise`, with the last
    step's acceleration covariance for every step: our approximation). ``tau`` before the row's
    birth: the limit of Al1 for a diffuse prior at ``t_{k-l}`` (``P(k|k-l) -> inf``:
    ``P_xv -> 0``, ``P_vv -> Q``): ``x(tau|k) = F(tau, k) x(k|k)``,
    ``P(tau|k) = F (P(k|k) + Q) F'``, ``C = P(k|k) F'`` (our derivation; for a new row's zero
    acceleration covariance, ``Q`` uses each mode's un-relaxed road noise of 24.6). Older
    than ``t_{k-N}``: ``too_old``. The rest (projection on the road, update, mode
    probabilities, memory refresh) as :func:`vsimm_oosm`.
    """
    from hocnet.tracking.oosm import cv_discrete_lag_noise, equivalent_memory

    B, r = state.mu.shape
    tau = _times("t", t, B)
    check_choice("too_old", too_old, ("raise", "drop"))
    check_choice("lag_method", method, ("rts", "al1"))
    mt = torch.as_tensor(memory[0], dtype=DTYPE)  # -inf allowed (before the birth)
    mx = as_float64("lag_memory.x", memory[1])
    mP = as_float64("lag_memory.P", memory[2])
    N = mt.shape[-1] if mt.dim() == 2 else -1
    if mt.shape != (B, N) or N < 1 or mx.shape != (B, N, r, 4) or mP.shape != (B, N, r, 4, 4):
        raise ValueError(
            f"`lag_memory`: expected t (B, N), x (B, N, r, 4), P (B, N, r, 4, 4) with B = {B}, "
            f"r = {r}, got {tuple(mt.shape)}, {tuple(mx.shape)} and {tuple(mP.shape)}"
        )
    check_oosm_time(tau, tau, state.t)  # only a time newer than t_k is an error here
    tol = 1e-9 * (1.0 + state.t.abs())
    n_new = (mt > (tau + tol).unsqueeze(-1)).sum(-1)
    old = n_new >= N
    det = _detected_mask(detected, B)
    if too_old == "raise" and bool((old & det).any()):
        i = int(torch.nonzero(old & det)[0])
        raise ValueError(
            f"`t`: expected an out-of-sequence measurement within the {N}-step lag memory "
            f"(t >= {float(mt[i, -1]):g} s), got t = {float(tau[i]):g} s with lag "
            f"{float(state.t[i] - tau[i]):g} s"
        )
    dropped = old & det
    det = det & ~dropped
    tau = torch.where(dropped, state.t, tau)
    n_new = torch.where(dropped, torch.zeros_like(n_new), n_new)
    idx = n_new.clamp(max=N - 1)
    rows = torch.arange(B)
    t_first = mt[rows, idx]
    birth = torch.isinf(t_first) & ~dropped
    one = (n_new == 0) & ~birth
    zt = _measurement(z, sensor, det)
    g_eq, G_eq = equivalent_memory(state.x, state.P, mx[rows, idx], mP[rows, idx])
    o1 = one.view(B, 1, 1)
    Pp = torch.where(o1.unsqueeze(-1), state.P_pred, mP[rows, idx])
    g = torch.where(o1, state.g, g_eq)
    G = torch.where(o1.unsqueeze(-1), state.G, G_eq)
    lag = state.t - tau
    Fb, _ = _mode_F(config.kinds, -lag)
    _, Gm = _mode_F(config.kinds, lag)
    sa, sc, road = config.sigma_tensors()
    u = net.direction[state.segment.clamp(min=0)]  # (B, r, 2)
    nrm = torch.stack([-u[..., 1], u[..., 0]], -1)
    uu = u.unsqueeze(-1) * u.unsqueeze(-2)
    nn = nrm.unsqueeze(-1) * nrm.unsqueeze(-2)
    sa2, sc2 = (sa * sa).view(1, r, 1, 1), (sc * sc).view(1, r, 1, 1)
    on_road = (road.view(1, r) & (state.segment >= 0)).view(B, r, 1, 1)
    base = torch.where(on_road, sa2 * uu + sc2 * nn, sa2 * torch.eye(2, dtype=DTYPE))
    empty = state.accel_cov.abs().sum((-1, -2), keepdim=True) == 0
    accel = torch.where(birth.view(B, 1, 1, 1) & empty, base, state.accel_cov)
    if config.noise == "discrete":
        bnd = torch.cat([mt.flip(-1), state.t.view(B, 1)], -1)
        bnd = torch.where(torch.isinf(bnd), tau.view(B, 1), bnd)
        Q, C0 = cv_discrete_lag_noise(tau.view(B, 1), bnd.unsqueeze(1), accel)
        stop = _stop_mask(config).view(1, r, 1, 1)
        Q = torch.where(stop, torch.zeros_like(Q), Q)
        C0 = torch.where(stop, torch.zeros_like(C0), C0)
    else:
        Q = _process_noise(config.kinds, config.noise, lag, Gm, accel)
        C0 = Q
    C0 = torch.where(birth.view(B, 1, 1, 1), torch.zeros_like(C0), C0)
    r0 = _retrodict(state.x, state.P, Pp, g, G, Fb, Q, C0)
    multi = ~one & ~birth & ~dropped
    if method == "rts" and memory.xf is not None and bool(multi.any()):
        rr = _lag_rts(state, memory, tau, idx, multi, config)
        use = multi.view(B, 1, 1)
        r0 = Retrodiction(
            torch.where(use, rr.x, r0.x),
            torch.where(use.unsqueeze(-1), rr.P, r0.P),
            torch.where(use.unsqueeze(-1), rr.C, r0.C),
        )
    # the one-step rows are A1 retrodictions as in vsimm_oosm: carried back across the junction
    # of the last step from the state ("state"; the former "locate" did not do it here)
    back = one & ~dropped if config.junction_retro == "state" else False
    new, ll_out, mode_ll = _oosm_finish(state, r0, zt, det, sensor, net, config, back)
    return _oosm_result(new, ll_out, mode_ll, dropped, too_old)


def _lag_rts(
    state: VSIMMState,
    memory: VSIMMLagMemory,
    tau: torch.Tensor,
    idx: torch.Tensor,
    use: torch.Tensor,
    config: VSIMMConfig,
) -> Retrodiction:
    """Exact retrodiction of each mode to ``tau`` from the lag memory (RTS; our addition).

    :func:`hocnet.tracking.oosm.oosm_retrodict_rts` per mode, batched over rows with
    different lags: from ``x(k|k), P(k|k)`` back through the stored steps ``0 .. idx - 1``
    (newest first; step ``e`` went from ``xf_e`` to ``xp_e = T_e F_e xf_e + b_e``, so the
    smoother gain is ``J = Pf_e (T_e F_e)' Pp_e^+``, which also undoes a junction rotation),
    then into step ``idx`` at ``tau``: ``x(tau|.) = F(d) xf``, ``P = F(d) Pf F(d)' + Q(d)``,
    ``cov(x(tau), x_next) = P(tau|.) F(D - d)' T'`` (continuous noise) or
    ``F(d) Pf F(D)' T' + Gamma(d) S Gamma(D)'`` (piecewise-constant, ``d = tau - t``, ``D`` the
    step; the step's noise is drawn in the new segment's frame, as in :func:`vsimm_predict`).
    Exact for one linear Gaussian mode filter started from its stored mixed estimate (the
    mode probabilities and mixing are not retrodicted, and an OOSM update earlier in the stored
    interval is not propagated into the stored steps: approximate there, as A1 and Al1).

    Args:
        state: ``B`` rows at ``t_k``.
        memory: lag memory with the per-step fields.
        tau: ``(B,)`` report times.
        idx: ``(B,)`` int64 the memory entry whose step contains ``tau``.
        use: ``(B,)`` bool rows to compute (others get ``x(k|k)``).
        config: :class:`VSIMMConfig`.

    Returns:
        :class:`Retrodiction` ``(x(tau|k), P(tau|k), cov(x_k, x(tau)|k))``, ``(B, r, ...)``.
    """
    B = state.mu.shape[0]
    N = memory.t.shape[1]
    kinds = config.kinds
    xs, Ps, Cr = state.x, state.P, state.P
    out_x, out_P, out_C = state.x.clone(), state.P.clone(), state.P.clone()
    t_end = torch.cat([state.t.view(B, 1).expand(B, 1), memory.t[:, :-1]], 1)

    def pinv(M: torch.Tensor) -> torch.Tensor:
        return torch.linalg.pinv(0.5 * (M + M.transpose(-1, -2)), hermitian=True, rtol=1e-12)

    last_e = int(idx[use].max()) if bool(use.any()) else -1
    for e in range(min(last_e, N - 1) + 1):
        t0 = torch.where(use, memory.t[:, e], state.t)  # -inf never reaches here for used rows
        D = torch.where(use, t_end[:, e] - t0, torch.zeros_like(t0))
        xf, Pf = memory.xf[:, e], memory.Pf[:, e]
        xp, Pp, T = memory.xp[:, e], memory.Pp[:, e], memory.T[:, e]
        FD, GD = _mode_F(kinds, D)
        Tt = T.transpose(-1, -2)
        full = (use & (e < idx)).view(B, 1, 1)
        if bool(full.any()):
            J = Pf @ FD.transpose(-1, -2) @ Tt @ pinv(Pp)
            Jt = J.transpose(-1, -2)
            xs_n = xf + (J @ (xs - xp).unsqueeze(-1)).squeeze(-1)
            Ps_n = Pf + J @ (Ps - Pp) @ Jt
            xs = torch.where(full, xs_n, xs)
            Ps = torch.where(full.unsqueeze(-1), Ps_n, Ps)
            Cr = torch.where(full.unsqueeze(-1), Cr @ Jt, Cr)
        here = (use & (e == idx)).view(B, 1, 1)
        if bool(here.any()):
            d = torch.where(use, tau - t0, torch.zeros_like(t0)).clamp(min=0.0)
            Fd, Gd = _mode_F(kinds, d)
            acc = memory.acc[:, e]
            Pt = Fd @ Pf @ Fd.transpose(-1, -2) + _process_noise(kinds, config.noise, d, Gd, acc)
            xt = (Fd @ xf.unsqueeze(-1)).squeeze(-1)
            if config.noise == "discrete":
                # the step's acceleration is drawn in the frame of the new segment (not rotated)
                cross = Fd @ Pf @ FD.transpose(-1, -2) @ Tt + Gd @ acc @ GD.transpose(-1, -2)
            else:
                Frest, _ = _mode_F(kinds, D - d)
                cross = Pt @ Frest.transpose(-1, -2) @ Tt
            J = cross @ pinv(Pp)
            Jt = J.transpose(-1, -2)
            xr = xt + (J @ (xs - xp).unsqueeze(-1)).squeeze(-1)
            Pr = Pt + J @ (Ps - Pp) @ Jt
            out_x = torch.where(here, xr, out_x)
            out_P = torch.where(here.unsqueeze(-1), 0.5 * (Pr + Pr.transpose(-1, -2)), out_P)
            out_C = torch.where(here.unsqueeze(-1), Cr @ Jt, out_C)
    return Retrodiction(out_x, out_P, out_C)

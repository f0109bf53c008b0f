"""Track-oriented structured-branching MHT (SB-MHT) of [PD] section 24.4.4, batched numerics.

One :meth:`MHT.step` per scan runs the six blocks of the chapter's figure 24.2:

1. **Gating and track maintenance.** All leaf tracks are predicted in one filter call; every
   (track, measurement) pair is gated with the chi-square gate of
   :func:`hocnet.tracking.kalman.gate`; each track branches into a missed-detection child and
   one child per gated measurement (all updates in one filter call); each measurement also
   starts a new track (a new *family*, i.e. a new target tree). Gating convention: one test per
   pair on the filter's combined innovation (:meth:`MotionFilter.innovation`, for an IMM the
   moment-matched mixture of the modes), unlike the Stone Soup hypothesiser (any mode).
2. **Track score** (eq. 24.41-24.43, log-likelihood ratio against the false-alarm hypothesis)
   and **track status by Wald's SPRT** (tentative / confirmed / deleted).
3. **Clustering**: families linked by a shared measurement (in this scan or in the last
   ``n_scan`` scans of their histories) form a cluster; hypotheses are kept per cluster.
4. **Global hypotheses**: a global hypothesis of a cluster is a set of leaf tracks, at most one
   per family and no two sharing a measurement; its score is the sum of its tracks' scores
   (families not in it are false alarms, LLR 0). The children of each parent hypothesis are
   the ``n_hypotheses`` best assignments of the scan's measurements to its tracks or to "new
   track" / "false alarm" dummy columns (Murty, :func:`~hocnet.tracking.assignment.
   k_best_assignments`); only the ``n_hypotheses`` best are kept, and tracks in none of them
   are deleted.
5. **N-scan pruning** (the chapter's modified form): every hypothesis must agree with the best
   one on all decisions older than ``n_scan`` scans, except that, when tracks carry a road
   section id (filter state key ``"section"``), the best branch of each road section is kept
   too (``section_best``). Clusters whose kept hypotheses no longer share a measurement are
   split (``split_links``).
6. **Merging**: leaves of one family (target tree) with the same measurements over the last
   ``merge_scans`` scans are merged into the best-scoring one (never across families).

Readings of the equations (the OCR damaged 24.42-24.43; the chapter refers to Blackman and
Popoli, *Design and Analysis of Modern Tracking Systems*, 1999, ch. 6 and 16, its ref. [5]):

* 24.41: ``L(k) = L(k-1) + Delta L(k)``.
* 24.42, detection: ``Delta L = ln(Lambda / lambda_fa)`` with ``Lambda = PD p(z | track)``, the
  PD-aware likelihood of 24.30-24.32 (for an IMM with a stop model, the stop mode contributes 0
  to a detection). Missed detection (our reading, as the issue says): ``Delta L = ln(1 - PD)``,
  or ``ln Lambda_miss = ln(sum_i mu_i(k|k-1) Lambda_i)`` with 24.30-24.31 for an IMM with a stop
  model (the stop mode explains a miss with likelihood 1).
* 24.43, initial score of a track started on one measurement: ``initial_score="log_odds"``
  (default, Blackman and Popoli 1999 section 6.2) ``L = ln(lambda_nt / lambda_fa)``, the prior
  log-odds new target against false alarm; ``initial_score="printed"`` keeps the chapter's
  printed ``L(0) = ln(lambda_fa / (lambda_fa + lambda_nt))``. The SPRT is not applied on the
  birth scan (one plot cannot be tested; our reading), nor, with ``hold_uninformative=True``
  (default), on a scan that leaves a tentative track's score unchanged (``Delta L = 0``: a scan
  of a sensor that cannot see the track, e.g. a UGS silence or a video frame whose footprint
  does not contain it; such a scan is no sample of the sequential test; our reading). Without it
  (``hold_uninformative=False``, the former behaviour) a track born below ``ln lower`` was
  deleted by the next scan of any sensor that did not detect it: in the [PD] 24.6 experiment,
  where delayed video / UGS scans come between the GMTI scans, no new track could start on a
  target after its first track was lost (seed 2400: target 6, 200 s untracked).
* SPRT ([PD] section 24.4.3, Wald 1947): the lower bound ``beta / (1 - alpha)`` and the upper
  bound ``(1 - beta) / alpha`` (:func:`~hocnet.tracking.sprt.sprt_thresholds`) with ``alpha``
  the probability of confirming a false track and ``beta`` of deleting a true one. **The
  deletion rule** (the same in :class:`~hocnet.tracking.stonesoup.SPRTInitiator` /
  :class:`~hocnet.tracking.stonesoup.SPRTDeleter`): a tentative track is confirmed when
  ``L >= ln upper`` and deleted when ``L <= ln lower`` (Wald's test stops on reaching a bound);
  a confirmed track is deleted when ``L <= max L - drop`` (Blackman and Popoli 1999, section
  6.4; our reading, default ``drop = ln(upper / lower)``, so a confirmed track, whose maximum is
  at least ``ln upper``, is deleted at the latest when it falls to ``ln lower``); ``ln lower``
  is not applied to confirmed tracks. Defaults ``alpha = beta = 1e-3`` (also those of the Stone
  Soup adapters): with the default densities (``ln(lambda_nt / lambda_fa) = -2.30``) and
  ``PD = 0.9`` (a miss scores ``ln 0.1 = -2.30``), the former default ``beta = 0.1`` put
  ``L(0)`` below ``ln lower = -2.3016`` (a new track survived only because the birth scan is
  not tested, and any miss at its second scan deleted it); ``beta = 1e-3`` gives ``ln lower =
  -6.91``: one miss after birth does not delete, two consecutive misses do. The road-section
  SPRT of :func:`~hocnet.tracking.vsimm.vsimm_section_sprt` is a different test (a choice among
  hypotheses that must end within a few scans at a junction) and keeps ``0.01 / 0.01``.
* ``missed_pd`` (as :func:`~hocnet.tracking.stonesoup.track_score`): score every miss
  ``ln(1 - missed_pd)`` (Blackman and Popoli's single-model increment) instead of the filter's
  ``ln Lambda_miss``; default ``None`` (the filter's), as the Stone Soup adapters.
* 24.48 (type attribute): when a measurement carries a type bba, the track's bba is revised by
  PCR5 (:func:`~hocnet.tracking.belief.pcr5`) and ``ln P{dtype(k) | dtype(k-1)}`` is added to the
  detection increment, with ``P`` the pignistic probability (24.47) of the updated bba on the
  estimated type (``type_term="estimate"``, the chapter's text: ``max BetP``) or on the type the
  report declares (``type_term="declared"``, our alternative:
  :func:`~hocnet.tracking.belief.type_likelihood` with the declared class index on the sensor's
  frame and the sensor's ``mapping`` into the common frame, both passed to :meth:`MHT.step`;
  without ``declared`` the argmax of the report's BetP is used, which is only right for a report
  made on the common frame), or on the set the report's own bba declares
  (``type_term="declared_set"``, our addition, issue 12:
  :func:`~hocnet.tracking.belief.report_type_likelihood`, the same as ``"declared"`` with the
  sensor's mapping for observed bbas ``m(A) = P{c}``, ``m(Theta) = 1 - P{c}``, but read off the
  report's bba, so reports of several sensors on the common frame need no ``declared``). Why:
  ``max BetP`` rewards a track for being *sure* of its type, not for *agreeing* with the report;
  on a GMTI "wheeled" report a track sure of a wrong wheeled class scores ``ln 1 = 0`` and the
  right track with its mass spread over two classes ``ln 0.57`` (seed 2424 of the chapter's
  scenario, t = 940 s: target 4's track left behind at a junction beside target 3's track).
  Measured on seeds 2400-2409 and 2420-2429 (``experiments/results/pd-pcr5-diag.md``): no
  better than ``"estimate"`` overall, which stays the default of the experiment.

Numbers are float64 torch tensors; the tree (histories, families, hypotheses) is Python
bookkeeping. The motion model is pluggable (:class:`MotionFilter`): :class:`CVKalmanFilter`
(default) and :class:`IMMFilter` (built on :mod:`hocnet.tracking.imm`) are provided.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import torch

from hocnet._check import check_choice, check_int, check_number
from hocnet.tracking.assignment import k_best_assignments
from hocnet.tracking.imm import _combine, _mix, _mixing, _mode_probabilities, _pd_mode_ll
from hocnet.tracking.kalman import (
    DTYPE,
    _predict,
    _shared_left,
    _update,
    as_float64,
    constant_velocity,
    gate,
)
from hocnet.tracking.sprt import sprt_thresholds

__all__ = [
    "MHT",
    "CVKalmanFilter",
    "IMMFilter",
    "MHTTrack",
    "MotionFilter",
    "sprt_thresholds",
]

States = dict[str, torch.Tensor]
"""Batched filter states: every value has the leading axis ``K`` (one entry per track)."""

_H_POS = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]], dtype=DTYPE)


def _take(states: States, index: Any) -> States:
    return {k: v[index] for k, v in states.items()}


def _cat(parts: Sequence[States]) -> States:
    keys = parts[0].keys()
    return {k: torch.cat([p[k] for p in parts]) for k in keys}


class MotionFilter(Protocol):
    """The filter interface the MHT calls (every method batched over ``K`` tracks, float64).

    ``states`` is a dict of tensors with a leading axis ``K``; an optional key ``"section"``
    (``(K,)`` int64 road-section ids) enables the road-section exception of the N-scan pruning.
    """

    meas_dim: int

    def initiate(self, z: torch.Tensor, R: torch.Tensor) -> States:
        """States of tracks started on measurements ``z (K, m)`` with noises ``R (K, m, m)``."""
        ...

    def predict(self, states: States, dt: float) -> States:
        """Predict every state by ``dt`` (time units of the scans)."""
        ...

    def innovation(self, states: States) -> tuple[torch.Tensor, torch.Tensor]:
        """Predicted measurements ``(K, m)`` and ``H P H'`` ``(K, m, m)`` (``S`` without ``R``)."""
        ...

    def update(
        self, states: States, z: torch.Tensor, R: torch.Tensor
    ) -> tuple[States, torch.Tensor]:
        """Update with ``z (K, m)``; returns states and ``log p(z | track)`` ``(K,)`` (no PD)."""
        ...

    def miss(self, states: States, pd: float) -> tuple[States, torch.Tensor]:
        """States after a missed detection and ``log Lambda_miss`` ``(K,)``."""
        ...

    def mean_cov(self, states: States) -> tuple[torch.Tensor, torch.Tensor]:
        """Combined estimate ``(K, n)`` and covariance ``(K, n, n)``."""
        ...


class CVKalmanFilter:
    """2-D constant-velocity Kalman filter, state ``[x, vx, y, vy]``, position measurements.

    Args:
        sigma_a: acceleration noise standard deviation (units / time^2), as in
            :func:`~hocnet.tracking.kalman.constant_velocity`.
        velocity_std: velocity standard deviation of a track started on one measurement
            (one-point initiation with zero velocity).

    Examples:
        >>> f = CVKalmanFilter(sigma_a=0.1, velocity_std=2.0)
        >>> s = f.initiate(torch.tensor([[1.0, 2.0]]), torch.eye(2)[None])
        >>> f.mean_cov(f.predict(s, 1.0))[0]
        tensor([[1., 0., 2., 0.]], dtype=torch.float64)
    """

    meas_dim = 2

    def __init__(self, sigma_a: float = 1.0, velocity_std: float = 1.0) -> None:
        self.sigma_a = check_number("sigma_a", sigma_a, low=0.0)
        self.velocity_std = check_number("velocity_std", velocity_std, low=0.0)

    def initiate(self, z: torch.Tensor, R: torch.Tensor) -> States:
        """See :meth:`MotionFilter.initiate`."""
        z, R = torch.as_tensor(z, dtype=DTYPE), torch.as_tensor(R, dtype=DTYPE)
        k = z.shape[0]
        x = torch.zeros(k, 4, dtype=DTYPE)
        x[:, 0], x[:, 2] = z[:, 0], z[:, 1]
        P = torch.zeros(k, 4, 4, dtype=DTYPE)
        idx = torch.tensor([0, 2])
        P[:, idx[:, None], idx[None, :]] = R
        P[:, 1, 1] = P[:, 3, 3] = self.velocity_std**2
        return {"x": x, "P": P}

    def predict(self, states: States, dt: float) -> States:
        """See :meth:`MotionFilter.predict`."""
        F, Q = constant_velocity(dt, self.sigma_a)
        x, P = _predict(states["x"], states["P"], F, Q)
        return {**states, "x": x, "P": P}

    def innovation(self, states: States) -> tuple[torch.Tensor, torch.Tensor]:
        """See :meth:`MotionFilter.innovation`."""
        x, P = states["x"], states["P"]
        zp = x[:, [0, 2]]
        return zp, P[:, [0, 2]][:, :, [0, 2]]

    def update(
        self, states: States, z: torch.Tensor, R: torch.Tensor
    ) -> tuple[States, torch.Tensor]:
        """See :meth:`MotionFilter.update`."""
        x, P = states["x"], states["P"]
        z, R = torch.as_tensor(z, dtype=DTYPE), torch.as_tensor(R, dtype=DTYPE)
        nu = z - x[:, [0, 2]]
        x, P, ll = _update(x, P, nu, _H_POS, R)
        return {**states, "x": x, "P": P}, ll

    def miss(self, states: States, pd: float) -> tuple[States, torch.Tensor]:
        """See :meth:`MotionFilter.miss`."""
        k = states["x"].shape[0]
        return states, torch.full((k,), math.log1p(-pd) if pd < 1 else -math.inf, dtype=DTYPE)

    def mean_cov(self, states: States) -> tuple[torch.Tensor, torch.Tensor]:
        """See :meth:`MotionFilter.mean_cov`."""
        return states["x"], states["P"]


class IMMFilter:
    """IMM over ``r`` linear models (:mod:`hocnet.tracking.imm`), optionally with a stop model.

    Between :meth:`predict` and :meth:`update` the state key ``"mu"`` holds the predicted mode
    probabilities ``mu_i(k|k-1)`` (24.32); after an update or a miss it holds ``mu_i(k)``
    (24.36). With ``stop_mode`` given, the mode likelihoods are those of 24.30-24.31 by the one
    kernel :func:`hocnet.tracking.imm.pd_mode_log_likelihoods`: for a sensor with an MDV (GMTI;
    ``stop_detectable=False``, default) a detection has zero likelihood under the stop model and
    a miss has likelihood 1 under it; for a sensor that sees stopped targets
    (``stop_detectable=True``, video / UGS / a detector that sees static objects) the stop model
    is scored like the moving ones. ``PD`` is factored out of :meth:`update` (the MHT adds
    ``ln PD``). :meth:`MHT.step` can set ``stop_detectable`` per scan.

    Args:
        models: ``r`` callables ``dt -> (F (4, 4), Q (4, 4))`` such as
            ``functools.partial(constant_velocity, sigma_a=0.05)`` or
            :func:`~hocnet.tracking.kalman.stop_model`.
        trans: ``(r, r)`` mode transition matrix, ``trans[i, j] = P(i -> j)``.
        initial_mu: ``(r,)`` mode probabilities of a new track (default uniform).
        stop_mode: index of the stop model M0, or ``None``.
        velocity_std: velocity standard deviation of a new track.
        stop_detectable: whether the sensor sees stopped targets (see above).

    Examples:
        >>> from functools import partial
        >>> f = IMMFilter([partial(constant_velocity, sigma_a=0.1),
        ...                partial(constant_velocity, sigma_a=2.0)], [[0.9, 0.1], [0.1, 0.9]])
        >>> s = f.predict(f.initiate(torch.zeros(3, 2), torch.eye(2).repeat(3, 1, 1)), 1.0)
        >>> s, ll = f.update(s, torch.ones(3, 2), torch.eye(2).repeat(3, 1, 1))
        >>> s["mu"].shape, ll.shape
        (torch.Size([3, 2]), torch.Size([3]))
    """

    meas_dim = 2

    def __init__(
        self,
        models: Sequence[Callable[[float], tuple[Any, Any]]],
        trans: Any,
        *,
        initial_mu: Any | None = None,
        stop_mode: int | None = None,
        velocity_std: float = 1.0,
        stop_detectable: bool = False,
    ) -> None:
        self.models = list(models)
        self.stop_detectable = bool(stop_detectable)
        r = len(self.models)
        if r < 1:
            raise ValueError("`models`: expected at least one model, got none")
        self.trans = as_float64("trans", trans, min_dim=2)
        if self.trans.shape != (r, r):
            raise ValueError(f"`trans`: expected shape ({r}, {r}), got {tuple(self.trans.shape)}")
        if bool(((self.trans.sum(-1) - 1).abs() > 1e-6).any()) or bool((self.trans < 0).any()):
            raise ValueError("`trans`: expected non-negative rows summing to 1")
        mu = torch.full((r,), 1.0 / r, dtype=DTYPE) if initial_mu is None else initial_mu
        self.initial_mu = as_float64("initial_mu", mu, min_dim=1)
        if self.initial_mu.shape != (r,):
            raise ValueError(
                f"`initial_mu`: expected shape ({r},), got {tuple(self.initial_mu.shape)}"
            )
        self.stop_mode = (
            None
            if stop_mode is None
            else check_int("stop_mode", stop_mode, minimum=0, maximum=r - 1)
        )
        self.velocity_std = check_number("velocity_std", velocity_std, low=0.0)

    def initiate(self, z: torch.Tensor, R: torch.Tensor) -> States:
        """See :meth:`MotionFilter.initiate`."""
        base = CVKalmanFilter(velocity_std=self.velocity_std).initiate(z, R)
        r = len(self.models)
        k = z.shape[0]
        return {
            "mu": self.initial_mu.expand(k, r).clone(),
            "x": base["x"][:, None].expand(k, r, 4).clone(),
            "P": base["P"][:, None].expand(k, r, 4, 4).clone(),
        }

    def predict(self, states: States, dt: float) -> States:
        """See :meth:`MotionFilter.predict`."""
        cbar, omega = _mixing(states["mu"], self.trans)
        x0, P0 = _mix(states["x"], states["P"], omega)
        FQ = [m(dt) for m in self.models]
        F = torch.stack([torch.as_tensor(f, dtype=DTYPE) for f, _ in FQ])
        Q = torch.stack([torch.as_tensor(q, dtype=DTYPE) for _, q in FQ])
        x, P = _predict(x0, P0, F, Q)
        return {**states, "mu": cbar, "x": x, "P": P}

    def innovation(self, states: States) -> tuple[torch.Tensor, torch.Tensor]:
        """See :meth:`MotionFilter.innovation`."""
        x, P = _combine(states["mu"], states["x"], states["P"])
        return x[:, [0, 2]], P[:, [0, 2]][:, :, [0, 2]]

    def _is_stop(self, r: int) -> torch.Tensor | None:
        return None if self.stop_mode is None else torch.arange(r) == self.stop_mode

    def update(
        self, states: States, z: torch.Tensor, R: torch.Tensor
    ) -> tuple[States, torch.Tensor]:
        """See :meth:`MotionFilter.update`."""
        x, P, cbar = states["x"], states["P"], states["mu"]
        r = x.shape[1]
        hx = _shared_left(_H_POS, x.unsqueeze(-1)).squeeze(-1)
        z, R = torch.as_tensor(z, dtype=DTYPE), torch.as_tensor(R, dtype=DTYPE)
        x_upd, P_upd, ll = _update(x, P, z.unsqueeze(1) - hx, _H_POS, R.unsqueeze(1))
        det = torch.ones(ll.shape[:-1], dtype=torch.bool)
        one = torch.tensor(1.0, dtype=DTYPE)  # PD is factored out (the MHT adds ln PD)
        mode_ll = _pd_mode_ll(ll, det, one, self._is_stop(r), self.stop_detectable)
        a = mode_ll + torch.log(cbar)
        track_ll = torch.logsumexp(a, dim=-1)
        ok = torch.isfinite(track_ll)
        mu = torch.where(ok[:, None], torch.exp(a - track_ll[:, None].where(ok[:, None], 0)), cbar)
        return {**states, "mu": mu, "x": x_upd, "P": P_upd}, track_ll

    def miss(self, states: States, pd: float) -> tuple[States, torch.Tensor]:
        """See :meth:`MotionFilter.miss`."""
        cbar = states["mu"]
        k, r = cbar.shape
        if self.stop_mode is None:
            return states, torch.full((k,), math.log1p(-pd) if pd < 1 else -math.inf, dtype=DTYPE)
        det = torch.zeros(k, dtype=torch.bool)
        pdt = torch.tensor(pd, dtype=DTYPE)
        is_stop = self._is_stop(r)
        mode_ll = _pd_mode_ll(cbar.new_zeros(k, r), det, pdt, is_stop, self.stop_detectable)
        total = torch.logsumexp(mode_ll + torch.log(cbar), dim=-1)
        if not bool(torch.isfinite(total).all()):  # PD = 1 and no mode explains a miss
            return states, total
        return {**states, "mu": _mode_probabilities(cbar, mode_ll)}, total

    def mean_cov(self, states: States) -> tuple[torch.Tensor, torch.Tensor]:
        """See :meth:`MotionFilter.mean_cov`."""
        return _combine(states["mu"], states["x"], states["P"])


@dataclass
class MHTTrack:
    """A track reported by :class:`MHT`.

    Attributes:
        id: track id (the family, i.e. target tree, it belongs to; stable over scans).
        state: ``(n,)`` float64 combined state (e.g. ``[x, vx, y, vy]``).
        covariance: ``(n, n)`` float64.
        score: log-likelihood ratio ``L(k)`` (24.41).
        status: ``"tentative"``, ``"confirmed"`` or ``"deleted"`` (ended by the SPRT).
        birth: scan index of its first measurement.
        measurements: per scan from ``birth``, the index of the associated measurement in that
            scan's list, ``-1`` for a missed detection.
        probability: posterior probability of the track in its cluster (sum of the normalised
            probabilities ``exp(score) / sum exp(score)`` of the kept hypotheses containing it).
        type_bba: the track's type bba ``(2**n,)`` when type reports were given, else ``None``.
    """

    id: int
    state: torch.Tensor
    covariance: torch.Tensor
    score: float
    status: str
    birth: int
    measurements: list[int]
    probability: float = 1.0
    type_bba: torch.Tensor | None = None

    def associations(self) -> list[tuple[int, int]]:
        """``(scan, measurement index)`` pairs of the detections of the track."""
        return [(self.birth + i, j) for i, j in enumerate(self.measurements) if j >= 0]


@dataclass
class _Leaf:
    uid: int
    family: int
    birth: int
    history: tuple[int, ...]
    score: float
    max_score: float
    status: str


@dataclass
class _Cluster:
    families: set[int]
    hyps: list[tuple[float, frozenset[int]]] = field(default_factory=list)


class _UnionFind:
    def __init__(self) -> None:
        self.parent: dict[Any, Any] = {}

    def find(self, a: Any) -> Any:
        self.parent.setdefault(a, a)
        root = a
        while self.parent[root] != root:
            root = self.parent[root]
        while self.parent[a] != root:
            self.parent[a], a = root, self.parent[a]
        return root

    def union(self, a: Any, b: Any) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[rb] = ra


def _top_product(
    a: list[tuple[float, frozenset[int]]], b: list[tuple[float, frozenset[int]]], n: int
) -> list[tuple[float, frozenset[int]]]:
    prod = [(sa + sb, ha | hb) for sa, ha in a for sb, hb in b]
    prod.sort(key=lambda t: -t[0])
    return prod[:n]


class MHT:
    """Track-oriented structured-branching MHT ([PD] section 24.4.4); see the module docstring.

    Args:
        filter: the motion model / filter (:class:`MotionFilter`); default
            :class:`CVKalmanFilter` with unit acceleration noise.
        R: ``(m, m)`` measurement noise covariance (measurement units squared), used when
            :meth:`step` gets none.
        pd: detection probability in (0, 1].
        lambda_fa: false-alarm density per unit of surveillance volume (area), ``> 0``.
        lambda_nt: new-target density per unit volume, ``> 0``.
        gate_probability: probability mass of the chi-square gate (threshold
            ``chi2.ppf(gate_probability, m)``), in (0, 1).
        alpha, beta: SPRT error probabilities (:func:`sprt_thresholds`; defaults ``1e-3``, see
            the module docstring).
        drop: score drop from its maximum that deletes a confirmed track (default
            ``ln(upper / lower)``).
        n_hypotheses: global hypotheses kept per cluster (``NHypo`` of the chapter), ``>= 1``.
        hypothesis_ratio: also drop the hypotheses whose probability is below this fraction of
            the best one's in their cluster (score below ``best + ln(ratio)``; ratio pruning of
            Blackman and Popoli 1999, ch. 16; ``None`` keeps the ``n_hypotheses`` best).
        n_scan: depth of the N-scan pruning (``>= 0``; 0 decides every scan).
        merge_scans: leaves with the same measurements over this many last scans are merged
            (``0`` disables merging).
        initial_score: ``"log_odds"`` or ``"printed"`` (module docstring, reading of 24.43).
        type_term: ``"estimate"``, ``"declared"`` or ``"declared_set"`` (reading of 24.48,
            module docstring), or ``None`` to ignore type reports in the score (they still
            update the tracks' bbas).
        missed_pd: score misses ``ln(1 - missed_pd)`` instead of the filter's miss likelihood
            (``None``, default).
        hold_uninformative: do not apply the SPRT deletion to a tentative track in a scan that
            left its score unchanged (module docstring; default ``True``). It never acts when
            ``missed_pd`` is set: every miss then scores ``ln(1 - missed_pd) < 0`` (the score
            always changes), so a tentative track is tested on every scan, seen or not.
        section_distance: the road-section exception of the N-scan pruning keeps the best leaf
            of another section only within this distance (m, position ``[x, ., y, .]`` of
            :meth:`MotionFilter.mean_cov`) of the family's leaf in the best hypothesis (our
            reading of "the Nk best tracks on each of the Nk road sections" of a junction,
            24.4.4 step 5); ``None`` (default, the former behaviour): any distance, so a family
            could keep leaves on two targets km apart for the whole run and its reported track
            jumped between them (issue 12, seed 2408: 3.2 km, 200 s).
        section_best: which leaves the road-section exception of the N-scan pruning keeps
            (24.4.4 step 5, "the best track on each road section"; our reading, issue 12):
            ``"leaf"`` (default, the former behaviour): per family, the best-scoring leaf of
            every road section, the section of its leaf in the best hypothesis included;
            ``"other"`` (our addition, opt-in): only on the sections *other* than that one (on
            it the best hypothesis's leaf is the best track). A track score ignores the
            measurements a leaf takes from other families: with ``"leaf"`` a leaf that took
            another target's report survives on the best leaf's own section although every
            hypothesis holding it scores lower (issue 12, seed 2424 of [PD] 24.6, see
            ``split_links``). ``"other"`` is not the default: it also drops the second-best
            leaf of a family on its own section, which lost a turning target's track in seed
            2437 (target 3 ARMSE 10.0 -> 24.3 m), and ``split_links="history"`` alone fixes
            seed 2424.
        split_links: which shared measurements keep families in one cluster when clusters are
            split after pruning (our reading, issue 12): ``"history"`` (default): any
            measurement of the leaves' histories (looked at only when the last
            ``max(n_scan, merge_scans) + 1`` scans would split the cluster); ``"window"`` (the
            former behaviour): only those of the last ``max(n_scan, merge_scans) + 1`` scans.
            Each part of a split cluster takes its best projected hypothesis on its own, so the
            parts must not share a measurement in any kept hypothesis. With ``"window"`` two
            families whose leaves held one older measurement in different hypotheses (kept by
            the road-section exception) were split apart and each reported the leaf holding
            it, an inconsistent pair of tracks: seed 2424, t = 730 s, target 1's track took
            the first report of target 10 leaving its stop at J3 although the hypothesis giving
            it to target 10's track scored 2.1 higher, and followed target 10 for 110 s.
            Without the road-section exception all kept hypotheses agree on the older scans
            and the two settings give the same clusters.

    Raises:
        TypeError, ValueError: bad parameters.

    Examples:
        >>> mht = MHT(R=0.25 * torch.eye(2), pd=0.9, lambda_fa=1e-3, lambda_nt=1e-4)
        >>> for k in range(6):  # two targets (rows 0, 1) and a wandering false alarm (row 2)
        ...     z = [[10.0 + k, 20.0], [50.0 - k, 5.0 + k], [3.0 * k * k % 40, 7.0 * k % 30]]
        ...     _ = mht.step(torch.tensor(z))
        >>> [(t.id, t.status, t.measurements) for t in mht.tracks()]
        [(0, 'confirmed', [0, 0, 0, 0, 0, 0]), (1, 'confirmed', [1, 1, 1, 1, 1, 1])]
    """

    def __init__(
        self,
        filter: MotionFilter | None = None,
        *,
        R: Any = None,
        pd: float = 0.9,
        lambda_fa: float = 1e-4,
        lambda_nt: float = 1e-5,
        gate_probability: float = 0.999,
        alpha: float = 1e-3,
        beta: float = 1e-3,
        drop: float | None = None,
        n_hypotheses: int = 10,
        hypothesis_ratio: float | None = 1e-6,
        n_scan: int = 3,
        merge_scans: int = 3,
        initial_score: str = "log_odds",
        type_term: str | None = "estimate",
        missed_pd: float | None = None,
        hold_uninformative: bool = True,
        section_distance: float | None = None,
        section_best: str = "leaf",
        split_links: str = "history",
    ) -> None:
        from scipy.stats import chi2

        self.filter = CVKalmanFilter() if filter is None else filter
        m = int(self.filter.meas_dim)
        self.R = None if R is None else self._check_R(R, None, m)
        self.pd = check_number("pd", pd, low=0.0, high=1.0, low_inclusive=False)
        self.lambda_fa = check_number("lambda_fa", lambda_fa, low=0.0, low_inclusive=False)
        self.lambda_nt = check_number("lambda_nt", lambda_nt, low=0.0, low_inclusive=False)
        gp = check_number(
            "gate_probability",
            gate_probability,
            low=0.0,
            high=1.0,
            low_inclusive=False,
            high_inclusive=False,
        )
        self.gate_threshold = float(chi2.ppf(gp, m))
        self.log_a, self.log_b = sprt_thresholds(alpha, beta)
        self.drop = (
            self.log_b - self.log_a
            if drop is None
            else check_number("drop", drop, low=0.0, low_inclusive=False)
        )
        self.n_hypotheses = check_int("n_hypotheses", n_hypotheses, minimum=1)
        self.log_ratio = (
            None
            if hypothesis_ratio is None
            else math.log(
                check_number(
                    "hypothesis_ratio", hypothesis_ratio, low=0.0, high=1.0, low_inclusive=False
                )
            )
        )
        self.n_scan = check_int("n_scan", n_scan, minimum=0)
        self.merge_scans = check_int("merge_scans", merge_scans, minimum=0)
        self.initial_score = check_choice("initial_score", initial_score, ("log_odds", "printed"))
        if type_term is not None:
            check_choice("type_term", type_term, ("estimate", "declared", "declared_set"))
        self.type_term = type_term
        self.missed_pd = (
            None
            if missed_pd is None
            else check_number("missed_pd", missed_pd, low=0.0, high=1.0, high_inclusive=False)
        )
        self.hold_uninformative = bool(hold_uninformative)
        self.section_distance = (
            None
            if section_distance is None
            else check_number("section_distance", section_distance, low=0.0)
        )
        self.section_best = check_choice("section_best", section_best, ("other", "leaf"))
        self.split_links = check_choice("split_links", split_links, ("history", "window"))
        if self.initial_score == "log_odds":
            self.l_init = math.log(self.lambda_nt / self.lambda_fa)
        else:
            self.l_init = math.log(self.lambda_fa / (self.lambda_fa + self.lambda_nt))
        self.scan = 0
        self.time: float | None = None
        self._leaves: list[_Leaf] = []
        self._states: States | None = None
        self._bba: torch.Tensor | None = None
        self._clusters: list[_Cluster] = []
        self._next_uid = 0
        self._next_family = 0
        self._finished: dict[int, MHTTrack] = {}
        self._declared: torch.Tensor | None = None
        self._mapping: Any = None

    # ---------------------------------------------------------------- input checks
    @staticmethod
    def _check_R(R: Any, n_meas: int | None, m: int) -> torch.Tensor:
        R = as_float64("R", R, min_dim=2, square=True)
        if R.shape[-1] != m or R.dim() > 3 or (R.dim() == 3 and R.shape[0] != n_meas):
            want = f"({m}, {m})" + ("" if n_meas is None else f" or ({n_meas}, {m}, {m})")
            raise ValueError(f"`R`: expected shape {want}, got {tuple(R.shape)}")
        if bool((torch.linalg.eigvalsh(R) <= 0).any()):
            raise ValueError("`R`: expected positive definite covariances, got one that is not")
        return R

    # ---------------------------------------------------------------- public API
    @property
    def n_leaves(self) -> int:
        """Number of leaf tracks (all branches of all target trees) currently held."""
        return len(self._leaves)

    @property
    def n_hypotheses_held(self) -> int:
        """Total number of global hypotheses over all clusters."""
        return sum(len(c.hyps) for c in self._clusters)

    def hypotheses(self) -> list[list[tuple[float, list[tuple[int, tuple[int, ...]]]]]]:
        """Per cluster, its hypotheses best first: ``(score, [(family, history), ...])``."""
        by_uid = {leaf.uid: leaf for leaf in self._leaves}
        out = []
        for c in self._clusters:
            out.append(
                [(s, sorted((by_uid[u].family, by_uid[u].history) for u in h)) for s, h in c.hyps]
            )
        return out

    def step(
        self,
        z: Any,
        *,
        time: float | None = None,
        R: Any = None,
        bba: Any = None,
        declared: Any = None,
        mapping: Any = None,
        stop_detectable: bool | None = None,
    ) -> list[MHTTrack]:
        """Process one scan of measurements and return the confirmed tracks.

        Args:
            z: ``(M, m)`` measurements of the scan (``M = 0`` allowed), in the units of ``R``.
            time: scan time; default: the previous time plus 1 (first scan: 0).
            R: ``(m, m)`` or ``(M, m, m)`` measurement noise; default the constructor's ``R``.
            bba: optional ``(M, 2**n)`` type bbas of the reports (24.48).
            declared: optional ``(M,)`` integer class each report declares, on its sensor's
                frame (for ``type_term="declared"``).
            mapping: the sensor's refinement into the common frame of ``bba``
                (:func:`~hocnet.tracking.belief.frame_mapping`), ``None`` for the common frame.
            stop_detectable: for this scan, whether the sensor sees stopped targets (sets the
                filter's ``stop_detectable``, e.g. :class:`IMMFilter`; ``None`` keeps it).

        Returns:
            The confirmed tracks of the best hypothesis of every cluster (:meth:`tracks`).

        Raises:
            TypeError, ValueError: non-finite or mis-shaped input, time going backwards.
        """
        m = int(self.filter.meas_dim)
        z = as_float64("z", z, min_dim=1)
        if z.numel() == 0:
            z = z.reshape(0, m)
        if z.dim() != 2 or z.shape[1] != m:
            raise ValueError(f"`z`: expected shape (M, {m}), got {tuple(z.shape)}")
        n_meas = z.shape[0]
        if R is None:
            if self.R is None:
                raise ValueError(
                    "`R`: expected a measurement noise here or in MHT(R=...), got None"
                )
            R = self.R
        else:
            R = self._check_R(R, n_meas, m)
        R = R.expand(n_meas, m, m) if R.dim() == 2 else R
        if bba is not None:
            from hocnet.tracking.belief import _masses

            bba = _masses("bba", bba)
            if bba.dim() != 2 or bba.shape[0] != n_meas:
                raise ValueError(f"`bba`: expected shape ({n_meas}, 2**n), got {tuple(bba.shape)}")
            if self._bba is not None and self._bba.shape[-1] != bba.shape[-1]:
                raise ValueError(
                    f"`bba`: expected the frame size {self._bba.shape[-1]} of earlier scans, "
                    f"got {bba.shape[-1]}"
                )
        if time is None:
            time = 0.0 if self.time is None else self.time + 1.0
        time = check_number("time", time)
        if self.time is not None and time < self.time:
            raise ValueError(
                f"`time`: expected >= the previous scan time {self.time:g}, got {time:g}"
            )
        dt = 0.0 if self.time is None else time - self.time
        if declared is not None:
            if bba is None:
                raise ValueError("`declared`: expected together with `bba`, got no bba")
            declared = torch.as_tensor(declared)
            if declared.dtype.is_floating_point or declared.shape != (n_meas,):
                raise ValueError(
                    f"`declared`: expected ({n_meas},) integer class indices, got dtype "
                    f"{declared.dtype} and shape {tuple(declared.shape)}"
                )
        self._declared, self._mapping = declared, mapping
        if stop_detectable is not None:
            if not hasattr(self.filter, "stop_detectable"):
                raise ValueError(
                    "`stop_detectable`: expected a filter with a `stop_detectable` attribute, "
                    f"got {type(self.filter).__name__}"
                )
            self.filter.stop_detectable = bool(stop_detectable)
        self._step(z, R, bba, dt)
        self.time = time
        self.scan += 1
        return self.tracks()

    # ---------------------------------------------------------------- one scan
    def _step(self, z: torch.Tensor, R: torch.Tensor, bba: torch.Tensor | None, dt: float) -> None:
        k = self.scan
        f = self.filter
        n_meas = z.shape[0]
        n_old = len(self._leaves)
        if bba is not None and self._bba is None:
            from hocnet.tracking.belief import vacuous

            n_types = bba.shape[-1].bit_length() - 1
            self._bba = vacuous(n_types, (n_old,))
        leaves = self._leaves
        scores = torch.tensor([leaf.score for leaf in leaves], dtype=DTYPE)

        # 1. predict, gate, branch (one filter call each)
        pairs_l = torch.zeros(0, dtype=torch.long)
        pairs_j = torch.zeros(0, dtype=torch.long)
        if n_old:
            pred = f.predict(self._states, dt)
            if n_meas:
                zp, hph = f.innovation(pred)
                pairs_l, pairs_j = self._gate(zp, hph, z, R)
            miss_states, log_miss = f.miss(pred, self.pd)
            if self.missed_pd is not None:
                log_miss = torch.full_like(scores, math.log1p(-self.missed_pd))
            miss_scores = scores + log_miss
        else:
            pred = None
        if len(pairs_l):
            det_states, ll = f.update(_take(pred, pairs_l), z[pairs_j], R[pairs_j])
            det_scores = scores[pairs_l] + math.log(self.pd) + ll - math.log(self.lambda_fa)
        else:
            det_states, det_scores = None, torch.zeros(0, dtype=DTYPE)
        new_states = f.initiate(z, R) if n_meas else None
        new_scores = torch.full((n_meas,), self.l_init, dtype=DTYPE)

        # type attribute (24.48)
        miss_bba = det_bba = new_bba = None
        if self._bba is not None:
            from hocnet.tracking.belief import pcr5, pignistic, vacuous

            n_types = self._bba.shape[-1].bit_length() - 1
            miss_bba = self._bba
            new_bba = bba if bba is not None else vacuous(n_types, (n_meas,))
            if bba is not None and len(pairs_l):
                det_bba = pcr5(self._bba[pairs_l], bba[pairs_j])
                if self.type_term is not None:
                    betp = pignistic(det_bba)
                    if self.type_term == "estimate":
                        p = betp.max(-1).values
                    elif self.type_term == "declared_set":
                        from hocnet.tracking.belief import report_type_likelihood

                        p = report_type_likelihood(det_bba, bba[pairs_j])
                    elif self._declared is not None:
                        from hocnet.tracking.belief import type_likelihood

                        p = type_likelihood(det_bba, self._declared[pairs_j], self._mapping)
                    else:  # backward compatible: the report's BetP argmax (common frame only)
                        declared = pignistic(bba[pairs_j]).argmax(-1)
                        p = betp.gather(-1, declared[:, None])[:, 0]
                    det_scores = det_scores + torch.log(p)
            elif len(pairs_l):
                det_bba = self._bba[pairs_l]

        # candidate children: index space [miss (n_old) | det (n_pairs) | new (n_meas)]
        n_pairs = len(pairs_l)
        child_scores = torch.cat(
            [miss_scores if n_old else torch.zeros(0, dtype=DTYPE), det_scores, new_scores]
        ).tolist()
        parent_of = list(range(n_old)) + pairs_l.tolist() + [-1] * n_meas
        meas_of = [-1] * n_old + pairs_j.tolist() + list(range(n_meas))
        children: list[_Leaf | None] = []
        for s, p, j in zip(child_scores, parent_of, meas_of):
            if p >= 0:
                par = leaves[p]
                status, max_score = self._sprt(par.status, s, max(par.max_score, s), par.score)
                if status == "deleted":
                    children.append(None)
                    continue
                leaf = _Leaf(-1, par.family, par.birth, (*par.history, j), s, max_score, status)
            else:
                leaf = _Leaf(-1, -1, k, (j,), s, s, "tentative")
            children.append(leaf)
        miss_child = children[:n_old]
        det_child = {
            (int(l_), int(j_)): n_old + i for i, (l_, j_) in enumerate(zip(pairs_l, pairs_j))
        }

        # 3-4. clusters of this scan and hypothesis expansion
        fam_cluster: dict[int, int] = {}
        for ci, c in enumerate(self._clusters):
            for fam in c.families:
                fam_cluster[fam] = ci
        leaf_pos = {leaf.uid: i for i, leaf in enumerate(leaves)}
        uf = _UnionFind()
        for ci in range(len(self._clusters)):
            uf.find(("c", ci))
        for j in range(n_meas):
            uf.find(("m", j))
        for (l_, j_), c in det_child.items():
            if children[c] is not None:
                uf.union(("c", fam_cluster[leaves[l_].family]), ("m", j_))
        groups: dict[Any, list[Any]] = {}
        for node in list(uf.parent):
            groups.setdefault(uf.find(node), []).append(node)

        new_clusters: list[_Cluster] = []
        used: set[int] = set()  # candidate-child indices referenced by some kept hypothesis
        hyp_children: list[list[tuple[float, tuple[int, ...]]]] = []
        for members in groups.values():
            old = sorted(n[1] for n in members if n[0] == "c")
            meas = sorted(n[1] for n in members if n[0] == "m")
            parents: list[tuple[float, frozenset[int]]] = [(0.0, frozenset())]
            for ci in old:
                parents = _top_product(parents, self._clusters[ci].hyps, self.n_hypotheses)
            cands: dict[tuple[int, ...], float] = {}
            for _, h in parents:
                tracks = sorted(leaf_pos[u] for u in h)
                for sc, kids in self._expand(
                    tracks, meas, miss_child, det_child, children, n_old, n_pairs
                ):
                    if kids not in cands or cands[kids] < sc:
                        cands[kids] = sc
            best = sorted(cands.items(), key=lambda t: -t[1])[: self.n_hypotheses]
            if self.log_ratio is not None:
                floor = best[0][1] + self.log_ratio
                best = [b for b in best if b[1] >= floor]
            hyp_children.append([(s, kids) for kids, s in best])
            for kids, _ in best:
                used.update(kids)
            new_clusters.append(_Cluster(set()))

        # 6. new leaves: the candidate children used by a kept hypothesis
        keep = sorted(used)
        uid_of: dict[int, int] = {}
        new_leaves: list[_Leaf] = []
        for c in keep:
            leaf = children[c]
            leaf.uid = self._next_uid
            self._next_uid += 1
            if leaf.family < 0:
                leaf.family = self._next_family
                self._next_family += 1
            uid_of[c] = leaf.uid
            new_leaves.append(leaf)
        keep_t = torch.tensor(keep, dtype=torch.long)
        parts: list[States] = []
        bparts: list[torch.Tensor] = []
        idx_miss = keep_t[keep_t < n_old]
        idx_det = keep_t[(keep_t >= n_old) & (keep_t < n_old + n_pairs)] - n_old
        idx_new = keep_t[keep_t >= n_old + n_pairs] - n_old - n_pairs
        if len(idx_miss):
            parts.append(_take(miss_states, idx_miss))
        if len(idx_det):
            parts.append(_take(det_states, idx_det))
        if len(idx_new):
            parts.append(_take(new_states, idx_new))
        if self._bba is not None:
            for src, idx in ((miss_bba, idx_miss), (det_bba, idx_det), (new_bba, idx_new)):
                if len(idx):
                    bparts.append(src[idx])
        for cl, hyps in zip(new_clusters, hyp_children):
            cl.hyps = [(s, frozenset(uid_of[c] for c in kids)) for s, kids in hyps]
        # record confirmed tracks that ended (terminated by the SPRT) in a best hypothesis
        self._record_terminations(miss_child, det_child, children)

        self._leaves = new_leaves
        if parts:
            self._states = _cat(parts)
        else:
            self._states = None
        if self._bba is not None:
            n_types = self._bba.shape[-1].bit_length() - 1
            from hocnet.tracking.belief import vacuous

            self._bba = torch.cat(bparts) if bparts else vacuous(n_types, (0,))
        self._clusters = new_clusters
        self._prune_and_split()

    def _gate(
        self, zp: torch.Tensor, hph: torch.Tensor, z: torch.Tensor, R: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Gated (track, measurement) pairs, as :func:`~hocnet.tracking.kalman.gate` would give.

        Candidates first: measurements sorted by ``x``; each track looks only at the ``x``
        interval its gate can reach (``|dx| <= sqrt(gamma S_xx)``, a necessary condition of the
        ellipse), then the same box test in ``y``; the ellipse test of
        :func:`~hocnet.tracking.kalman.gate` decides on the candidates.
        """
        gamma = self.gate_threshold
        order = torch.argsort(z[:, 0])
        zx = z[order, 0].contiguous()
        r_diag = R.diagonal(dim1=-2, dim2=-1)
        half = torch.sqrt(gamma * (hph[:, 0, 0] + r_diag[:, 0].max()))
        lo = torch.searchsorted(zx, zp[:, 0] - half, side="left")
        hi = torch.searchsorted(zx, zp[:, 0] + half, side="right")
        counts = hi - lo
        total = int(counts.sum())
        if total == 0:
            empty = torch.zeros(0, dtype=torch.long)
            return empty, empty
        l_idx = torch.repeat_interleave(torch.arange(len(zp)), counts)
        start = torch.cumsum(counts, 0) - counts
        offset = torch.arange(total) - torch.repeat_interleave(start, counts)
        j_idx = order[torch.repeat_interleave(lo, counts) + offset]
        d = z[j_idx] - zp[l_idx]
        box = ((d * d) <= gamma * (hph[l_idx].diagonal(dim1=-2, dim2=-1) + r_diag[j_idx])).all(-1)
        l_idx, j_idx, d = l_idx[box], j_idx[box], d[box]
        if len(l_idx) == 0:
            return l_idx, j_idx
        inside = gate(d, hph[l_idx] + R[j_idx], gamma)
        l_idx, j_idx = l_idx[inside], j_idx[inside]
        key = torch.argsort(l_idx * len(z) + j_idx)  # track-major order, as a dense scan gives
        return l_idx[key], j_idx[key]

    def _sprt(
        self,
        parent_status: str,
        score: float,
        max_score: float,
        parent_score: float | None = None,
    ) -> tuple[str, float]:
        """Status of a child track by the SPRT (the deletion rule of the module docstring)."""
        if parent_status == "confirmed":
            return ("deleted" if score <= max_score - self.drop else "confirmed"), max_score
        if score >= self.log_b:
            return "confirmed", score
        held = self.hold_uninformative and parent_score is not None and score == parent_score
        if score <= self.log_a and not held:
            return "deleted", max_score
        return "tentative", max_score

    def _expand(
        self,
        tracks: list[int],
        meas: list[int],
        miss_child: list[Any],
        det_child: dict[tuple[int, int], int],
        children: list[_Leaf | None],
        n_old: int,
        n_pairs: int,
    ) -> list[tuple[float, tuple[int, ...]]]:
        """Children of one parent hypothesis: the k best assignments (Murty)."""
        n_t, n_m = len(tracks), len(meas)
        base = []
        for t in tracks:
            mc = miss_child[t]
            base.append(mc.score if mc is not None else 0.0)
        new_index = [n_old + n_pairs + j for j in meas]
        if n_m == 0:
            kids = tuple(
                sorted(n for t in tracks if (n := self._miss_index(t, miss_child)) is not None)
            )
            return [(sum(children[c].score for c in kids), kids)]
        inf = math.inf
        cost = [[inf] * (n_t + 2 * n_m) for _ in range(n_m)]
        for r, j in enumerate(meas):
            for ti, t in enumerate(tracks):
                c = det_child.get((t, j))
                if c is not None and children[c] is not None:
                    cost[r][ti] = -(children[c].score - base[ti])
            cost[r][n_t + r] = -children[new_index[r]].score
            cost[r][n_t + n_m + r] = 0.0
        out = []
        for a in k_best_assignments(cost, self.n_hypotheses):
            kids = []
            assigned = set()
            for r, col in zip(a.rows.tolist(), a.cols.tolist()):
                if col < n_t:
                    kids.append(det_child[(tracks[col], meas[r])])
                    assigned.add(col)
                elif col < n_t + n_m:
                    kids.append(new_index[r])
            for ti, t in enumerate(tracks):
                if ti not in assigned and (n := self._miss_index(t, miss_child)) is not None:
                    kids.append(n)
            kids_t = tuple(sorted(kids))
            out.append((sum(children[c].score for c in kids_t), kids_t))
        return out

    @staticmethod
    def _miss_index(t: int, miss_child: list[Any]) -> int | None:
        return t if miss_child[t] is not None else None

    def _record_terminations(
        self, miss_child: list[Any], det_child: dict[tuple[int, int], int], children: list[Any]
    ) -> None:
        """Keep confirmed tracks of the previous best hypotheses whose every branch ended."""
        if not self._leaves:
            return
        alive = set()
        for i, mc in enumerate(miss_child):
            if mc is not None:
                alive.add(i)
        for (l_, _), c in det_child.items():
            if children[c] is not None:
                alive.add(l_)
        pos = {leaf.uid: i for i, leaf in enumerate(self._leaves)}
        for c in self._clusters:
            if not c.hyps:
                continue
            for u in c.hyps[0][1]:
                i = pos[u]
                leaf = self._leaves[i]
                if i not in alive and leaf.status == "confirmed":
                    (self._finished[leaf.family],) = self._reports([i], [1.0], status="deleted")

    # ---------------------------------------------------------------- pruning
    def _prune_and_split(self) -> None:
        k = self.scan
        leaves = self._leaves
        by_uid = {leaf.uid: leaf for leaf in leaves}
        sections = None
        if self._states is not None and "section" in self._states:
            sections = self._states["section"].tolist()
        sec_of = {leaf.uid: sections[i] for i, leaf in enumerate(leaves)} if sections else {}
        cut = k - self.n_scan  # decisions at scans <= cut are committed
        for cl in self._clusters:
            if not cl.hyps:
                continue
            # 5. N-scan pruning against the best hypothesis
            if cut >= 0:
                best = cl.hyps[0][1]
                fams = {by_uid[u].family for _, h in cl.hyps for u in h}

                def signature(h: frozenset[int], cut: int = cut) -> dict[int, tuple[int, ...]]:
                    sig = {}
                    for u in h:
                        leaf = by_uid[u]
                        if leaf.birth <= cut:
                            sig[leaf.family] = leaf.history[: cut - leaf.birth + 1]
                    return sig

                best_sig = signature(best)
                allowed: dict[int, set[Any]] = {fam: {best_sig.get(fam)} for fam in fams}
                if sec_of:
                    best_by_sec: dict[tuple[int, Any], _Leaf] = {}
                    if self.section_best == "other":  # best's own leaf stands for its section
                        own = {(by_uid[u].family, sec_of[u]) for u in best}
                    else:
                        own = set()
                    for _, h in cl.hyps:
                        for u in h:
                            leaf = by_uid[u]
                            key = (leaf.family, sec_of[u])
                            if (
                                leaf.birth <= cut
                                and key not in own
                                and (key not in best_by_sec or best_by_sec[key].score < leaf.score)
                            ):
                                best_by_sec[key] = leaf
                    near = self._near_best(best, best_by_sec, by_uid)
                    for (fam, _), leaf in best_by_sec.items():
                        if near is None or near(leaf):
                            allowed[fam].add(leaf.history[: cut - leaf.birth + 1])
                kept = []
                for s, h in cl.hyps:
                    sig = signature(h)
                    if all(sig.get(fam) in allowed[fam] for fam in fams):
                        kept.append((s, h))
                cl.hyps = kept
        # merging of duplicate leaves
        if self.merge_scans:
            self._merge(by_uid)
        # drop leaves in no hypothesis
        used = {u for cl in self._clusters for _, h in cl.hyps for u in h}
        keep = [i for i, leaf in enumerate(leaves) if leaf.uid in used]
        if len(keep) != len(leaves):
            idx = torch.tensor(keep, dtype=torch.long)
            self._leaves = [leaves[i] for i in keep]
            self._states = _take(self._states, idx) if keep else None
            if self._bba is not None:
                self._bba = self._bba[idx]
        self._split()

    def _near_best(
        self, best: frozenset[int], cand: dict[tuple[int, Any], _Leaf], by_uid: dict[int, _Leaf]
    ) -> Callable[[_Leaf], bool] | None:
        """Predicate "leaf within ``section_distance`` of its family's best leaf" (or ``None``).

        A family absent from the best hypothesis keeps the exception without a distance limit.
        """
        if self.section_distance is None or self._states is None:
            return None
        index = {leaf.uid: i for i, leaf in enumerate(self._leaves)}
        uids = sorted({u for u in best} | {leaf.uid for leaf in cand.values()})
        if not uids:
            return None
        rows = torch.tensor([index[u] for u in uids], dtype=torch.long)
        x, _ = self.filter.mean_cov(_take(self._states, rows))
        pos = {u: x[n, [0, 2]] for n, u in enumerate(uids)}
        ref = {by_uid[u].family: pos[u] for u in best}
        limit = self.section_distance

        def near(leaf: _Leaf) -> bool:
            r = ref.get(leaf.family)
            return r is None or float(torch.linalg.vector_norm(pos[leaf.uid] - r)) <= limit

        return near

    def _merge(self, by_uid: dict[int, _Leaf]) -> None:
        """Merge leaves of one family with identical measurements over the last ``merge_scans``.

        Merging is done **within a target tree** (our reading of [PD] 24.4.4 step 6, "selection
        of the most probable tracks which have common measurements"; Blackman and Popoli 1999,
        16.3): leaves of the same family whose last ``merge_scans`` measurements coincide are
        duplicates of one track and are replaced by the best-scoring one. Leaves of different
        families are never merged: two targets close together for a few scans share no
        measurement in a consistent hypothesis, but a leaf of one tree can carry the same
        recent measurements as a leaf of another; replacing it made every hypothesis that held
        both trees inconsistent, and a whole cluster (the convoy during an overtaking) lost all
        its tracks at once. A hypothesis whose merged form is inconsistent (the kept leaf
        conflicts with another track of the hypothesis in an older scan) is kept unmerged.
        """
        k = self.scan
        depth = self.merge_scans
        for cl in self._clusters:
            uids = {u for _, h in cl.hyps for u in h}
            groups: dict[tuple[int, tuple[int, ...]], list[_Leaf]] = {}
            for u in sorted(uids):
                leaf = by_uid[u]
                if k - leaf.birth + 1 < depth:
                    continue
                tail = leaf.history[-depth:]
                if all(j < 0 for j in tail):
                    continue
                groups.setdefault((leaf.family, tail), []).append(leaf)
            repl: dict[int, int] = {}
            for group in groups.values():
                if len(group) > 1:
                    group.sort(key=lambda lf: (-lf.score, lf.uid))
                    for other in group[1:]:
                        repl[other.uid] = group[0].uid
            if not repl:
                continue
            hyps: dict[frozenset[int], float] = {}
            for _, h in cl.hyps:
                h2 = frozenset(repl.get(u, u) for u in h)
                if h2 != h and not self._consistent(h2, by_uid):
                    h2 = h
                s = sum(by_uid[u].score for u in h2)
                if h2 not in hyps or hyps[h2] < s:
                    hyps[h2] = s
            cl.hyps = sorted(((s, h) for h, s in hyps.items()), key=lambda t: -t[0])

    @staticmethod
    def _consistent(h: frozenset[int], by_uid: dict[int, _Leaf]) -> bool:
        fams: set[int] = set()
        seen: set[tuple[int, int]] = set()
        for u in h:
            leaf = by_uid[u]
            if leaf.family in fams:
                return False
            fams.add(leaf.family)
            for i, j in enumerate(leaf.history):
                if j >= 0:
                    key = (leaf.birth + i, j)
                    if key in seen:
                        return False
                    seen.add(key)
        return True

    @staticmethod
    def _components(
        uids: set[int], by_uid: dict[int, _Leaf], after: int | None
    ) -> dict[int, set[int]]:
        """Families of the leaves ``uids`` linked by a shared measurement at a scan ``> after``.

        ``after=None``: at any scan of the leaves' histories.
        """
        uf = _UnionFind()
        owner: dict[tuple[int, int], int] = {}
        for u in uids:
            leaf = by_uid[u]
            uf.find(leaf.family)
            first = 0 if after is None else max(0, after + 1 - leaf.birth)
            for i in range(first, len(leaf.history)):
                j = leaf.history[i]
                if j >= 0:
                    key = (leaf.birth + i, j)
                    if key in owner:
                        uf.union(owner[key], leaf.family)
                    else:
                        owner[key] = leaf.family
        comps: dict[int, set[int]] = {}
        for u in uids:
            fam = by_uid[u].family
            comps.setdefault(uf.find(fam), set()).add(fam)
        return comps

    def _split(self) -> None:
        """Split clusters into independent components and project their hypotheses."""
        k = self.scan
        window = max(self.n_scan, self.merge_scans) + 1
        by_uid = {leaf.uid: leaf for leaf in self._leaves}
        out: list[_Cluster] = []
        for cl in self._clusters:
            if not cl.hyps:
                continue
            uids = {u for _, h in cl.hyps for u in h}
            comps = self._components(uids, by_uid, k - window)
            if len(comps) > 1 and self.split_links == "history":
                comps = self._components(uids, by_uid, None)
            if len(comps) == 1:
                cl.families = next(iter(comps.values()))
                out.append(cl)
                continue
            for fams in comps.values():
                proj: dict[frozenset[int], float] = {}
                for _, h in cl.hyps:
                    hp = frozenset(u for u in h if by_uid[u].family in fams)
                    s = sum(by_uid[u].score for u in hp)
                    proj[hp] = s
                hyps = sorted(((s, h) for h, s in proj.items()), key=lambda t: -t[0])
                out.append(_Cluster(fams, hyps[: self.n_hypotheses]))
        self._clusters = out

    # ---------------------------------------------------------------- output
    def _reports(
        self, index: list[int], probability: list[float], status: str | None = None
    ) -> list[MHTTrack]:
        """Reports of the leaves ``index`` (one batched ``mean_cov`` call)."""
        if not index:
            return []
        x, P = self.filter.mean_cov(_take(self._states, torch.tensor(index, dtype=torch.long)))
        out = []
        for n, (i, p) in enumerate(zip(index, probability)):
            leaf = self._leaves[i]
            out.append(
                MHTTrack(
                    id=leaf.family,
                    state=x[n].clone(),
                    covariance=P[n].clone(),
                    score=leaf.score,
                    status=status or leaf.status,
                    birth=leaf.birth,
                    measurements=list(leaf.history),
                    probability=p,
                    type_bba=None if self._bba is None else self._bba[i].clone(),
                )
            )
        return out

    def tracks(self, *, include_tentative: bool = False) -> list[MHTTrack]:
        """Tracks of the best hypothesis of every cluster (confirmed ones by default), by id."""
        pos = {leaf.uid: i for i, leaf in enumerate(self._leaves)}
        index: list[int] = []
        probability: list[float] = []
        for cl in self._clusters:
            if not cl.hyps:
                continue
            scores = torch.tensor([s for s, _ in cl.hyps], dtype=DTYPE)
            prob = torch.softmax(scores, 0).tolist()
            marginal: dict[int, float] = {}
            for p, (_, h) in zip(prob, cl.hyps):
                for u in h:
                    marginal[u] = marginal.get(u, 0.0) + p
            for u in cl.hyps[0][1]:
                i = pos[u]
                if include_tentative or self._leaves[i].status == "confirmed":
                    index.append(i)
                    probability.append(marginal[u])
        out = self._reports(index, probability)
        out.sort(key=lambda t: t.id)
        return out

    def all_tracks(self) -> list[MHTTrack]:
        """Confirmed tracks of the run: the current ones and those ended by the SPRT, by id."""
        current = {t.id: t for t in self.tracks()}
        ended = {fid: t for fid, t in self._finished.items() if fid not in current}
        return sorted([*current.values(), *ended.values()], key=lambda t: t.id)

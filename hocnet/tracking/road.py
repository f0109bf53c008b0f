"""Road-segment constrained constant-velocity model and constrained estimation ([PD] 24.2.3).

A road segment ``s`` is the straight line from ``p0`` to ``p1`` (m, in the local East-North
frame of [PD] section 24.2.2). Everything is batched over segments and tracks; state order is
``[x, vx, y, vy]`` (m, m/s) as in eq. 24.1-24.2.

- :func:`segment_constraint`: ``D x = L`` of eq. 24.3-24.4 (position on the line, velocity
  along it), with the line ``a x + b y + c = 0`` normalised so that ``(a, b)`` is the *unit*
  normal (the chapter leaves the scale free; the unit normal makes ``D D' = I``).
- :func:`road_noise_cov` and :func:`road_constant_velocity`: the directional process noise of
  eq. 24.5-24.6 and the model's ``(F, Q)``.
- :func:`on_segment_probability` and :func:`relaxed_road_noise_cov`: eq. 24.9-24.12.
- :func:`project_estimate`: the constrained estimate of eq. 24.14-24.16.
- :class:`RoadNetwork`: the GIS road network of 24.2.2 (nodes, segments, sections, junctions)
  from GeoJSON-like polylines in metres, validated (empty, NaN, zero-length segments,
  disconnected -> ``ValueError`` naming the feature / vertex / part), with
  :meth:`~RoadNetwork.locate` (nearest segment, along-road abscissa on the segment and on its
  section), :meth:`~RoadNetwork.reachable` (segments within a travel distance, for the
  variable-structure model set of 24.4.3) and the neighbours at junctions. The WGS84 to TCF
  conversion of 24.2.2 is left to the caller (coordinates are already local East-North metres).

Our readings of the printed equations (the OCR and the chapter disagree with the standard
results in places):

- 24.6 prints ``Q = R_theta diag(sigma_d^2, sigma_n^2) R_theta'`` while the text says that
  ``sigma_n`` (the larger) is *along* the road and ``sigma_d`` across it. With ``R_theta`` the
  rotation by the road direction ``theta`` (it maps the x axis onto the road), the first
  diagonal entry is the along-road variance, so we take the arguments by name:
  ``Q_nu = R_theta diag(sigma_along^2, sigma_across^2) R_theta'``.
- 24.9 prints the relaxed entry ``q22 = sigma_n^2 P + sigma_d^2 (1 - P)``; the text says the
  across-road deviation must grow to the along-road one near the segment end (``P -> 0``), so the
  across variance is ``sigma_across^2 P + sigma_along^2 (1 - P)`` (the issue's reading too).
- 24.11-24.12: ``Q_s`` in the printed 24.11 is the projection ``Pi_s``, and ``f`` is the standard
  normal CDF (the OCR says "variance 1/2" but prints ``1/sqrt(2 pi) int exp(-t^2/2)``, which is
  the standard normal CDF). ``sigma_s^2 = u' P_pos u`` is the variance of the projection on the
  unit direction ``u`` (Ulmke and Koch 2006, the chapter's [19]; our reading). We implement 24.11
  for every position (it is already small outside ``[0, l]``); the printed 24.10 would set it to
  0 outside.
- 24.14 lacks a transpose: ``x_s = x - P D' (D P D')^-1 (D x - L)``. (The text before it says
  the estimate maximises "pdf (24.3)": the density is 24.13, 24.3 is the constraint.)
- 24.16 lacks an inverse: ``W = P D' (D P D')^-1 D``; then 24.15 ``P_s = (I - W) P (I - W)'``
  equals ``P - W P`` and ``D P_s = 0``.
- ``F_{s,i}`` of 24.5 is "described in [12]" and not printed: we use the plain constant-velocity
  ``F`` and enforce the road by :func:`project_estimate`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch

from hocnet._check import _describe, check_int, check_number
from hocnet.tracking.kalman import DTYPE, as_float64, constant_velocity, normal_cdf

__all__ = [
    "RoadLocation",
    "RoadNetwork",
    "on_segment_probability",
    "on_segment_probability_from_moments",
    "project_estimate",
    "relaxed_road_noise_cov",
    "road_constant_velocity",
    "road_noise_cov",
    "segment_constraint",
]


def _segments(p0: Any, p1: Any) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Validate endpoints ``(..., 2)``; return ``p0``, unit direction ``u`` and length ``l``."""
    p0 = as_float64("p0", p0, min_dim=1)
    p1 = as_float64("p1", p1, min_dim=1)
    for name, p in (("p0", p0), ("p1", p1)):
        if p.shape[-1] != 2:
            raise ValueError(
                f"`{name}`: expected points of shape (..., 2) in m, got {tuple(p.shape)}"
            )
    d = p1 - p0
    length = torch.linalg.vector_norm(d, dim=-1)
    if d.numel() and bool((length <= 0).any()):
        raise ValueError(
            f"`p1`: expected segments of non-zero length, got {int((length <= 0).sum())} "
            "with p1 == p0"
        )
    return p0, d / length.unsqueeze(-1), length


def segment_constraint(p0: Any, p1: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear constraint ``D x = L`` of a road segment, eq. 24.3-24.4.

    With the unit normal ``(a, b) = (-u_y, u_x)`` of the direction ``u`` and
    ``c = -(a x0 + b y0)``: ``D = [[a, 0, b, 0], [0, a, 0, b]]`` and ``L = [-c, 0]'``, i.e. the
    position lies on the line and the velocity is orthogonal to the normal.

    Args:
        p0: segment start points ``(..., 2)`` in m.
        p1: segment end points ``(..., 2)`` in m.

    Returns:
        ``(D, L)`` of shapes ``(..., 2, 4)`` and ``(..., 2)``, float64.

    Raises:
        TypeError, ValueError: bad shapes, NaN/inf, zero-length segments.

    Examples:
        >>> D, L = segment_constraint(torch.tensor([0.0, 5.0]), torch.tensor([10.0, 5.0]))
        >>> D.tolist(), L.tolist()
        ([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], [5.0, 0.0])
    """
    p0, u, _ = _segments(p0, p1)
    a, b = 0.0 - u[..., 1], u[..., 0]
    c = 0.0 - (a * p0[..., 0] + b * p0[..., 1])
    zero = torch.zeros_like(a)
    D = torch.stack(
        [torch.stack([a, zero, b, zero], -1), torch.stack([zero, a, zero, b], -1)], dim=-2
    )
    L = torch.stack([-c, zero], -1)
    return D, L


def road_noise_cov(p0: Any, p1: Any, sigma_along: float, sigma_across: float) -> torch.Tensor:
    """Directional acceleration covariance ``R_theta diag(s_along^2, s_across^2) R_theta'``.

    Eq. 24.6 (our reading of the diagonal's order, see the module docstring).

    Args:
        p0: segment start points ``(..., 2)`` in m.
        p1: segment end points ``(..., 2)`` in m.
        sigma_along: acceleration noise along the road, m/s^2 (``>= 0``).
        sigma_across: acceleration noise across the road, m/s^2 (``>= 0``).

    Returns:
        ``(..., 2, 2)`` float64 covariance in (m/s^2)^2, in the (x, y) frame.

    Examples:
        >>> road_noise_cov(torch.zeros(2), torch.tensor([0.0, 1.0]), 0.8, 0.4).tolist()
        [[0.16000000000000003, 0.0], [0.0, 0.6400000000000001]]
    """
    _, u, _ = _segments(p0, p1)
    sa = check_number("sigma_along", sigma_along, low=0.0)
    sc = check_number("sigma_across", sigma_across, low=0.0)
    normal = torch.stack([-u[..., 1], u[..., 0]], -1)
    return sa * sa * u.unsqueeze(-1) * u.unsqueeze(-2) + sc * sc * normal.unsqueeze(
        -1
    ) * normal.unsqueeze(-2)


def road_constant_velocity(
    dt: float, p0: Any, p1: Any, sigma_along: float, sigma_across: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(F, Q)`` of the constant-velocity model on road segments, eq. 24.5-24.8.

    ``F`` is the constant-velocity transition (see the module docstring on ``F_{s,i}``) and
    ``Q = Gamma(dt) Q_nu Gamma(dt)'`` with ``Q_nu`` from :func:`road_noise_cov`; e.g. the
    chapter's model M2 has ``sigma_along = 0.8``, ``sigma_across = 0.4`` m/s^2.

    Args:
        dt: time step in s.
        p0: segment start points ``(S, 2)`` (or ``(2,)``) in m.
        p1: segment end points, same shape.
        sigma_along: m/s^2.
        sigma_across: m/s^2.

    Returns:
        ``(F, Q)``, each ``(S, 4, 4)`` (or ``(4, 4)``) float64.

    Examples:
        >>> F, Q = road_constant_velocity(1.0, torch.zeros(3, 2), torch.ones(3, 2), 0.8, 0.4)
        >>> F.shape, Q.shape
        (torch.Size([3, 4, 4]), torch.Size([3, 4, 4]))
    """
    cov = road_noise_cov(p0, p1, sigma_along, sigma_across)
    F, Q = constant_velocity(dt, 0.0, acceleration_cov=cov)
    return F.expand(*Q.shape), Q


def on_segment_probability(x: Any, P: Any, p0: Any, p1: Any) -> torch.Tensor:
    """Probability that the predicted position projects inside the segment, eq. 24.11.

    ``P{e_s} = Phi((l - Pi_s) / sigma_s) - Phi(-Pi_s / sigma_s)`` with ``Pi_s = u'(pos - p0)``
    the along-road coordinate (m), ``sigma_s^2 = u' P_pos u`` and ``Phi`` the standard normal
    CDF (our reading of 24.11-24.12; see the module docstring). With zero variance along the road
    (a known position) this is the limit ``sigma_s -> 0``: the indicator ``0 <= Pi_s <= l``
    (:func:`on_segment_probability_from_moments`, also used by :mod:`hocnet.tracking.vsimm`).

    Args:
        x: predicted states ``(..., 4)``.
        P: predicted covariances ``(..., 4, 4)``.
        p0: segment start points ``(..., 2)`` in m (broadcast).
        p1: segment end points ``(..., 2)`` in m.

    Returns:
        ``(...)`` float64 in [0, 1].

    Raises:
        ValueError: negative variance along the road (``P`` not PSD), bad shapes.

    Examples:
        >>> p = on_segment_probability(torch.tensor([50.0, 0, 0, 0]), 100 * torch.eye(4),
        ...                            torch.zeros(2), torch.tensor([100.0, 0.0]))
        >>> round(float(p), 6)
        0.999999
    """
    x = as_float64("x", x, min_dim=1)
    P = as_float64("P", P, min_dim=2, square=True)
    if x.shape[-1] != 4 or P.shape[-1] != 4:
        raise ValueError(
            f"`x`: expected states (..., 4) and covariances (..., 4, 4), got {tuple(x.shape)} "
            f"and {tuple(P.shape)}"
        )
    p0, u, length = _segments(p0, p1)
    pos = x[..., [0, 2]]
    along = ((pos - p0) * u).sum(-1)
    Ppos = P[..., [0, 2], :][..., [0, 2]]
    var = (u.unsqueeze(-2) @ Ppos @ u.unsqueeze(-1)).squeeze(-1).squeeze(-1)
    if var.numel() and bool((var < 0).any()):
        raise ValueError(
            "`P`: expected a non-negative position variance along the road, got a negative one"
        )
    return on_segment_probability_from_moments(along, var, length)


def on_segment_probability_from_moments(along: Any, var: Any, length: Any) -> torch.Tensor:
    """``P{e_s}`` of eq. 24.11 from the along-road mean, variance and segment length (no checks).

    ``Phi((l - Pi_s) / sigma_s) - Phi(-Pi_s / sigma_s)`` with ``Phi`` =
    :func:`~hocnet.tracking.kalman.normal_cdf`; where ``sigma_s^2 <= 0`` (a known position, or a
    round-off negative) the limit ``sigma_s -> 0``: 1 if ``0 <= Pi_s <= l``, else 0. The one
    implementation of the 24.9-24.12 relaxation's probability (:func:`on_segment_probability`
    and :mod:`hocnet.tracking.vsimm` call it).

    Args:
        along: ``(...)`` along-road coordinate ``Pi_s`` of the predicted position (m).
        var: ``(...)`` its variance ``sigma_s^2`` (m^2).
        length: ``(...)`` segment length ``l`` (m), broadcast.

    Returns:
        ``(...)`` float64 in [0, 1].

    Examples:
        >>> on_segment_probability_from_moments(torch.tensor([5.0, 15.0]), torch.zeros(2),
        ...                                     torch.tensor(10.0)).tolist()
        [1.0, 0.0]
    """
    along = torch.as_tensor(along, dtype=DTYPE)
    var = torch.as_tensor(var, dtype=DTYPE)
    length = torch.as_tensor(length, dtype=DTYPE)
    sd = var.clamp(min=0.0).sqrt()
    safe = torch.where(sd > 0, sd, torch.ones_like(sd))
    p = normal_cdf((length - along) / safe) - normal_cdf(-along / safe)
    inside = ((along >= 0) & (along <= length)).to(DTYPE)
    return torch.where(sd > 0, p, inside).clamp(0.0, 1.0)


def relaxed_road_noise_cov(
    p0: Any, p1: Any, sigma_along: float, sigma_across: float, p_on: Any
) -> torch.Tensor:
    """Acceleration covariance relaxed near the segment ends, eq. 24.9 (our reading).

    ``R_theta diag(sigma_along^2, q) R_theta'`` with the across-road variance
    ``q = sigma_across^2 p_on + sigma_along^2 (1 - p_on)``: on the segment (``p_on = 1``) this is
    :func:`road_noise_cov`; at its end (``p_on -> 0``) the noise becomes isotropic.

    Args:
        p0: segment start points ``(..., 2)`` in m.
        p1: segment end points ``(..., 2)`` in m.
        sigma_along: m/s^2.
        sigma_across: m/s^2.
        p_on: on-segment probabilities ``(...)`` in [0, 1] (:func:`on_segment_probability`).

    Returns:
        ``(..., 2, 2)`` float64.

    Examples:
        >>> cov = relaxed_road_noise_cov(torch.zeros(2), torch.tensor([1.0, 0.0]), 0.8, 0.4, 0.0)
        >>> [round(v, 12) for v in cov.flatten().tolist()]
        [0.64, 0.0, 0.0, 0.64]
    """
    _, u, _ = _segments(p0, p1)
    sa = check_number("sigma_along", sigma_along, low=0.0)
    sc = check_number("sigma_across", sigma_across, low=0.0)
    p = as_float64("p_on", p_on)
    if p.numel() and bool(((p < 0) | (p > 1)).any()):
        raise ValueError("`p_on`: expected probabilities in [0, 1], got values outside")
    q = sc * sc * p + sa * sa * (1.0 - p)
    normal = torch.stack([-u[..., 1], u[..., 0]], -1)
    uu = u.unsqueeze(-1) * u.unsqueeze(-2)
    nn = normal.unsqueeze(-1) * normal.unsqueeze(-2)
    return sa * sa * uu + q.unsqueeze(-1).unsqueeze(-1) * nn


def project_estimate(x: Any, P: Any, D: Any, L: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Constrained estimate by projection, eq. 24.14-24.16 (with the transpose and inverse).

    ``x_s = x - P D' (D P D')^-1 (D x - L)`` and ``P_s = (I - W) P (I - W)'`` with
    ``W = P D' (D P D')^-1 D``: the maximiser of the Gaussian density ``N(x; x_hat, P)`` on the
    affine set ``D x = L`` (Simon and Chia 2002, the chapter's [13] cites the same result).

    Args:
        x: estimates ``(..., n)``.
        P: covariances ``(..., n, n)``.
        D: constraints ``(..., c, n)`` (e.g. :func:`segment_constraint`), broadcast.
        L: right-hand sides ``(..., c)``.

    Returns:
        ``(x_s, P_s)`` of shapes ``(..., n)`` and ``(..., n, n)``; ``D x_s = L`` and
        ``D P_s = 0`` up to rounding.

    Raises:
        ValueError: bad shapes, ``D P D'`` singular (e.g. ``P`` has no variance across the road).

    Examples:
        >>> D, L = segment_constraint(torch.zeros(2), torch.tensor([1.0, 0.0]))
        >>> xs, Ps = project_estimate(torch.tensor([3.0, 1.0, 2.0, 0.5]), torch.eye(4), D, L)
        >>> [round(v, 12) + 0.0 for v in xs.tolist()]
        [3.0, 1.0, 0.0, 0.0]
    """
    x = as_float64("x", x, min_dim=1)
    P = as_float64("P", P, min_dim=2, square=True)
    D = as_float64("D", D, min_dim=2)
    L = as_float64("L", L, min_dim=1)
    n = x.shape[-1]
    if P.shape[-1] != n or D.shape[-1] != n:
        raise ValueError(
            f"`D`: expected P (..., {n}, {n}) and D (..., c, {n}) for states of size {n}, got "
            f"{tuple(P.shape)} and {tuple(D.shape)}"
        )
    if L.shape[-1] != D.shape[-2]:
        raise ValueError(f"`L`: expected last axis {D.shape[-2]} (rows of D), got {tuple(L.shape)}")
    PDt = P @ D.transpose(-1, -2)
    M = D @ PDt
    chol, info = torch.linalg.cholesky_ex(M)
    if bool((info != 0).any()):
        raise ValueError("`P`: expected D P D' positive definite, got a singular one")
    resid = (D @ x.unsqueeze(-1)).squeeze(-1) - L
    gain = torch.cholesky_solve(PDt.transpose(-1, -2), chol).transpose(-1, -2)  # P D' M^-1
    xs = x - (gain @ resid.unsqueeze(-1)).squeeze(-1)
    W = gain @ D
    eye = torch.eye(n, dtype=DTYPE)
    A = eye - W
    Ps = A @ P @ A.transpose(-1, -2)
    return xs, 0.5 * (Ps + Ps.transpose(-1, -2))


# --------------------------------------------------------------------------------------------
# Road network ([PD] section 24.2.2): nodes, segments, sections, junctions.
# --------------------------------------------------------------------------------------------


def _graph(seg_nodes: np.ndarray, length: np.ndarray, V: int) -> Any:
    """Symmetric CSR adjacency of segment lengths (parallel edges: the shorter one)."""
    from scipy.sparse import coo_matrix

    rows = np.concatenate([seg_nodes[:, 0], seg_nodes[:, 1]])
    cols = np.concatenate([seg_nodes[:, 1], seg_nodes[:, 0]])
    data = np.concatenate([length, length])
    # coo -> csr sums duplicates; keep the minimum instead
    order = np.lexsort((data, cols, rows))
    rows, cols, data = rows[order], cols[order], data[order]
    first = np.ones(len(rows), dtype=bool)
    first[1:] = (rows[1:] != rows[:-1]) | (cols[1:] != cols[:-1])
    return coo_matrix((data[first], (rows[first], cols[first])), shape=(V, V)).tocsr()


class RoadLocation(NamedTuple):
    """Result of :meth:`RoadNetwork.locate` (all shapes ``(...)`` = the batch of positions).

    Attributes:
        segment: ``(...)`` int64 index of the nearest segment.
        abscissa: ``(...)`` float64 along-road coordinate on that segment, m from its ``p0``,
            in ``[0, length]``.
        distance: ``(...)`` float64 distance from the position to the segment, m.
        point: ``(..., 2)`` float64 nearest point of the segment, m.
        section: ``(...)`` int64 index of the segment's road section.
        section_abscissa: ``(...)`` float64 along-road coordinate on the section, m from the
            section's first node (sections are walked from a road end or junction).
    """

    segment: torch.Tensor
    abscissa: torch.Tensor
    distance: torch.Tensor
    point: torch.Tensor
    section: torch.Tensor
    section_abscissa: torch.Tensor


def _find(parent: list[int], i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


class RoadNetwork:
    """A road network: nodes, straight segments, sections and junctions ([PD] section 24.2.2).

    The chapter's GIS gives road *segments* (straight pieces) indexed by the road *section* they
    belong to; a section ``Ro(p) = {s0, s1, ...}`` is "a connected road segments set delimited by
    a road end or a junction", and "the road network is connected". Here a network is built from
    polylines in metres (the local East-North frame, TCF, of 24.2.2; no WGS84 conversion):

    - *nodes* ``(V, 2)``: the polyline vertices, vertices closer than ``tolerance`` merged (so
      polylines that share an end or a vertex are connected there);
    - *segments* ``(S,)``: consecutive vertices of a polyline, ``p0 -> p1`` (the direction only
      fixes the sign of the along-road abscissa; roads are two-way);
    - *sections*: maximal chains of segments through nodes of degree 2, cut at junctions (degree
      >= 3) and road ends (degree 1), computed from the topology and not from the input features
      (a polyline crossing a junction is split there; two polylines joined end to end form one
      section);
    - *junctions*: nodes of degree >= 3.

    Attributes (all torch, float64 or int64):
        nodes: ``(V, 2)`` m.
        segment_nodes: ``(S, 2)`` node indices ``(start, end)``.
        p0, p1: ``(S, 2)`` segment end points, m.
        length: ``(S,)`` m.
        direction: ``(S, 2)`` unit vectors ``(p1 - p0) / length``.
        segment_section: ``(S,)`` section index of every segment.
        segment_feature: ``(S,)`` index of the input polyline (feature) of every segment.
        section_offset: ``(S,)`` m, along-section abscissa of the segment's entry node.
        section_forward: ``(S,)`` bool, the section is walked from ``p0`` to ``p1``.
        node_degree: ``(V,)`` number of segment ends at each node.
        junctions: ``(J,)`` node indices of degree >= 3.
        road_ends: ``(E,)`` node indices of degree 1.
        node_distance: ``(V, V)`` m, shortest road distance between nodes (Dijkstra; ``inf``
            between disconnected parts).
        sections: tuple of tuples of segment indices, in walking order.
        section_properties: tuple of dicts, the ``properties`` of the feature of each section's
            first segment (e.g. ``{"kind": "highway"}``).

    Raises (constructors):
        ValueError: empty network, NaN/inf coordinates, fewer than 2 vertices in a polyline,
            zero-length segments (after merging), a disconnected network (unless
            ``require_connected=False``); the message names the feature and vertex.

    Examples:
        >>> net = RoadNetwork.from_geojson({"type": "FeatureCollection", "features": [
        ...     {"type": "Feature", "properties": {"kind": "highway"},
        ...      "geometry": {"type": "LineString", "coordinates": [[0, 0], [100, 0], [200, 0]]}},
        ...     {"type": "Feature", "properties": {"kind": "byway"},
        ...      "geometry": {"type": "LineString", "coordinates": [[100, 0], [100, 50]]}}]})
        >>> net.num_segments, len(net.sections), net.junctions.tolist()
        (3, 3, [1])
        >>> loc = net.locate(torch.tensor([150.0, 3.0]))
        >>> int(loc.segment), float(loc.abscissa), float(loc.distance)
        (1, 50.0, 3.0)
    """

    def __init__(
        self,
        polylines: Sequence[Any],
        properties: Sequence[dict] | None = None,
        *,
        tolerance: float = 1e-6,
        require_connected: bool = True,
    ) -> None:
        tolerance = check_number("tolerance", tolerance, low=0.0)
        if isinstance(polylines, np.ndarray | torch.Tensor):
            polylines = list(polylines)
        if not isinstance(polylines, Sequence) or isinstance(polylines, str | bytes):
            raise TypeError(
                f"`polylines`: expected a sequence of (K, 2) coordinate lists in m, got "
                f"{type(polylines).__name__}"
            )
        if len(polylines) == 0:
            raise ValueError("`network`: expected at least one road polyline, got an empty network")
        if properties is None:
            properties = [{} for _ in polylines]
        if len(properties) != len(polylines):
            raise ValueError(
                f"`properties`: expected one dict per polyline ({len(polylines)}), got "
                f"{len(properties)}"
            )
        coords: list[np.ndarray] = []
        for f, line in enumerate(polylines):
            try:
                arr = np.asarray(line, dtype=np.float64)
            except (TypeError, ValueError):
                raise TypeError(
                    f"`network`: expected numeric coordinates in feature {f}, got {_describe(line)}"
                ) from None
            if arr.ndim != 2 or arr.shape[1] != 2:
                raise ValueError(
                    f"`network`: expected coordinates of shape (K, 2) in m in feature {f}, got "
                    f"shape {arr.shape}"
                )
            if arr.shape[0] < 2:
                raise ValueError(
                    f"`network`: expected at least 2 vertices in feature {f}, got {arr.shape[0]}"
                )
            bad = ~np.isfinite(arr).all(axis=1)
            if bad.any():
                raise ValueError(
                    f"`network`: expected finite coordinates, got NaN/inf in feature {f} at "
                    f"vertex {int(np.flatnonzero(bad)[0])}"
                )
            coords.append(arr)
        # merge vertices closer than `tolerance` (union-find over k-d tree pairs)
        allv = np.concatenate(coords)
        starts = np.cumsum([0] + [len(c) for c in coords])
        parent = list(range(len(allv)))
        from scipy.spatial import cKDTree

        for i, j in cKDTree(allv).query_pairs(max(tolerance, 0.0) + 1e-12):
            ri, rj = _find(parent, i), _find(parent, j)
            if ri != rj:
                parent[max(ri, rj)] = min(ri, rj)
        roots = np.array([_find(parent, i) for i in range(len(allv))])
        uniq, node_of = np.unique(roots, return_inverse=True)
        nodes = allv[uniq]
        seg_nodes, seg_feature = [], []
        for f, c in enumerate(coords):
            ids = node_of[starts[f] : starts[f + 1]]
            for v in range(len(c) - 1):
                if ids[v] == ids[v + 1]:
                    raise ValueError(
                        f"`network`: expected segments of non-zero length, got a zero-length "
                        f"segment in feature {f} between vertices {v} and {v + 1}"
                    )
                seg_nodes.append((int(ids[v]), int(ids[v + 1])))
                seg_feature.append(f)
        self._build(
            nodes,
            np.asarray(seg_nodes, dtype=np.int64),
            np.asarray(seg_feature, dtype=np.int64),
            [dict(p) if p is not None else {} for p in properties],
            require_connected,
        )

    @classmethod
    def from_geojson(
        cls, data: dict, *, tolerance: float = 1e-6, require_connected: bool = True
    ) -> RoadNetwork:
        """Build a network from a GeoJSON-like ``FeatureCollection`` of ``LineString`` features.

        Coordinates are ``[x, y]`` in metres in the local frame (a third coordinate, the
        altitude, is ignored); ``MultiLineString`` features contribute one polyline per part.
        Each feature's ``properties`` dict is kept (e.g. ``{"kind": "highway"}`` for the
        section-transition probabilities of :func:`hocnet.tracking.vsimm.section_transition`).

        Args:
            data: ``{"type": "FeatureCollection", "features": [...]}`` (a single ``Feature`` or
                a bare geometry is accepted too).
            tolerance: vertices closer than this (m) are the same node.
            require_connected: raise when the network has several connected components.

        Returns:
            :class:`RoadNetwork`.

        Raises:
            TypeError, ValueError: not a FeatureCollection, a geometry that is not a line,
                empty network, NaN, zero-length segments, disconnected network.
        """
        if not isinstance(data, dict):
            raise TypeError(f"`data`: expected a GeoJSON-like dict, got {type(data).__name__}")
        kind = data.get("type")
        if kind == "FeatureCollection":
            features = data.get("features")
            if not isinstance(features, list):
                raise ValueError("`data`: expected a list under 'features', got none")
        elif kind == "Feature":
            features = [data]
        elif kind in ("LineString", "MultiLineString"):
            features = [{"type": "Feature", "geometry": data, "properties": {}}]
        else:
            raise ValueError(
                "`data`: expected type 'FeatureCollection', 'Feature' or 'LineString', got "
                f"{kind!r}"
            )
        lines, props = [], []
        for f, feat in enumerate(features):
            geom = feat.get("geometry") if isinstance(feat, dict) else None
            if not isinstance(geom, dict):
                raise ValueError(f"`data`: expected a geometry in feature {f}, got none")
            gtype = geom.get("type")
            coords = geom.get("coordinates")
            parts = (
                [coords]
                if gtype == "LineString"
                else coords
                if gtype == "MultiLineString"
                else None
            )
            if parts is None:
                raise ValueError(
                    f"`data`: expected LineString or MultiLineString geometries, got {gtype!r} in "
                    f"feature {f}"
                )
            for part in parts:
                arr = np.asarray(part, dtype=np.float64)
                if arr.ndim == 2 and arr.shape[1] == 3:
                    arr = arr[:, :2]
                lines.append(arr)
                props.append(feat.get("properties") or {})
        return cls(lines, props, tolerance=tolerance, require_connected=require_connected)

    def to_geojson(self) -> dict:
        """The network as a FeatureCollection, one ``LineString`` per section (m).

        Each feature's properties hold the section's input properties plus ``"section"`` (its
        index). ``RoadNetwork.from_geojson(net.to_geojson())`` rebuilds the same segments.
        """
        feats = []
        nodes = self.nodes.tolist()
        for p, segs in enumerate(self.sections):
            chain = []
            for s in segs:
                a, b = self.segment_nodes[s].tolist()
                if not bool(self.section_forward[s]):
                    a, b = b, a
                if not chain:
                    chain.append(nodes[a])
                chain.append(nodes[b])
            props = dict(self.section_properties[p])
            props["section"] = p
            feats.append(
                {
                    "type": "Feature",
                    "properties": props,
                    "geometry": {"type": "LineString", "coordinates": chain},
                }
            )
        return {"type": "FeatureCollection", "features": feats}

    def _build(
        self,
        nodes: np.ndarray,
        seg_nodes: np.ndarray,
        seg_feature: np.ndarray,
        properties: list[dict],
        require_connected: bool,
    ) -> None:
        from scipy.sparse.csgraph import connected_components, dijkstra

        V, S = len(nodes), len(seg_nodes)
        p0, p1 = nodes[seg_nodes[:, 0]], nodes[seg_nodes[:, 1]]
        length = np.linalg.norm(p1 - p0, axis=1)
        degree = np.bincount(seg_nodes.ravel(), minlength=V)
        incident: list[list[int]] = [[] for _ in range(V)]
        for s, (a, b) in enumerate(seg_nodes):
            incident[a].append(s)
            incident[b].append(s)
        graph = _graph(seg_nodes, length, V)
        n_comp, labels = connected_components(graph, directed=False)
        if require_connected and n_comp > 1:
            sizes = np.bincount(labels)
            small = int(np.argmin(sizes))
            example = int(np.flatnonzero(labels == small)[0])
            raise ValueError(
                f"`network`: expected a connected road network ([PD] 24.2.2), got {n_comp} "
                f"disconnected parts (e.g. the node at {nodes[example].tolist()} m is in a part "
                f"of {int(sizes[small])} nodes); pass require_connected=False to allow it"
            )
        node_distance = dijkstra(graph, directed=False)
        # sections: chains through degree-2 nodes
        seg_section = np.full(S, -1, dtype=np.int64)
        forward = np.zeros(S, dtype=bool)
        offset = np.zeros(S)
        sections: list[tuple[int, ...]] = []

        def walk(start_node: int, first_seg: int) -> None:
            p = len(sections)
            chain, node, seg, acc = [], start_node, first_seg, 0.0
            while seg >= 0 and seg_section[seg] < 0:
                seg_section[seg] = p
                a, b = seg_nodes[seg]
                forward[seg] = a == node
                offset[seg] = acc
                acc += length[seg]
                chain.append(int(seg))
                node = int(b if a == node else a)
                if degree[node] != 2:
                    break
                nxt = [t for t in incident[node] if t != seg]
                seg = nxt[0] if nxt else -1
            sections.append(tuple(chain))

        for v in range(V):
            if degree[v] != 2:
                for s in incident[v]:
                    if seg_section[s] < 0:
                        walk(v, s)
        for s in range(S):  # closed loops of degree-2 nodes
            if seg_section[s] < 0:
                walk(int(seg_nodes[s, 0]), s)
        t = torch.as_tensor
        self.nodes = t(nodes, dtype=DTYPE)
        self.segment_nodes = t(seg_nodes, dtype=torch.int64)
        self.p0 = t(p0, dtype=DTYPE)
        self.p1 = t(p1, dtype=DTYPE)
        self.length = t(length, dtype=DTYPE)
        self.direction = (self.p1 - self.p0) / self.length.unsqueeze(-1)
        self.segment_section = t(seg_section, dtype=torch.int64)
        self.segment_feature = t(seg_feature, dtype=torch.int64)
        self.section_offset = t(offset, dtype=DTYPE)
        self.section_forward = t(forward, dtype=torch.bool)
        self.node_degree = t(degree, dtype=torch.int64)
        self.junctions = t(np.flatnonzero(degree >= 3), dtype=torch.int64)
        self.road_ends = t(np.flatnonzero(degree == 1), dtype=torch.int64)
        self.node_distance = t(node_distance, dtype=DTYPE)
        self.components = t(labels, dtype=torch.int64)
        self.sections = tuple(sections)
        self.section_properties = tuple(
            properties[int(seg_feature[chain[0]])] for chain in sections
        )
        self._incident = tuple(tuple(i) for i in incident)
        self._seg_np = (seg_nodes, length, V)
        self._without_cache: dict[int, torch.Tensor] = {}

    def _distances_without(self, segment: int) -> torch.Tensor:
        """``(2, V)`` distances from the ends of ``segment`` in the network without it (cached).

        Routes that do not turn back over the segment, for the directed travel distance.
        """
        out = self._without_cache.get(segment)
        if out is None:
            from scipy.sparse.csgraph import dijkstra

            seg_nodes, length, V = self._seg_np
            keep = np.arange(len(seg_nodes)) != segment
            g = _graph(seg_nodes[keep], length[keep], V)
            out = torch.as_tensor(
                dijkstra(g, directed=False, indices=seg_nodes[segment].tolist()), dtype=DTYPE
            )
            self._without_cache[segment] = out
        return out

    @property
    def num_segments(self) -> int:
        """Number of segments ``S``."""
        return int(self.segment_nodes.shape[0])

    @property
    def num_sections(self) -> int:
        """Number of sections."""
        return len(self.sections)

    def __repr__(self) -> str:
        return (
            f"RoadNetwork({self.nodes.shape[0]} nodes, {self.num_segments} segments, "
            f"{self.num_sections} sections, {self.junctions.numel()} junctions)"
        )

    def _segment_index(self, name: str, segment: Any) -> torch.Tensor:
        s = torch.as_tensor(segment)
        if s.is_floating_point() or s.dtype == torch.bool or s.is_complex():
            raise TypeError(f"`{name}`: expected integer segment indices, got dtype {s.dtype}")
        s = s.to(torch.int64)
        if s.numel() and bool(((s < 0) | (s >= self.num_segments)).any()):
            raise ValueError(
                f"`{name}`: expected segment indices in [0, {self.num_segments - 1}], got "
                f"{int(s.min())}..{int(s.max())}"
            )
        return s

    def constraint(self, segment: Any) -> tuple[torch.Tensor, torch.Tensor]:
        """``(D, L)`` of eq. 24.3-24.4 for segment indices ``(...)``.

        Returns ``D`` ``(..., 2, 4)`` and ``L`` ``(..., 2)`` (:func:`segment_constraint`).
        """
        s = self._segment_index("segment", segment)
        return segment_constraint(self.p0[s], self.p1[s])

    def locate(self, positions: Any, *, allowed: Any | None = None) -> RoadLocation:
        """Nearest segment, along-road abscissa and distance for a batch of positions.

        For every segment the orthogonal projection ``t = clamp(u'(p - p0), 0, l)`` and the
        distance ``|p - p0 - t u|``; the nearest segment wins (lowest index on ties).

        Args:
            positions: ``(..., 2)`` m (or states ``(..., 4)`` ``[x, vx, y, vy]``).
            allowed: optional bool mask ``(..., S)`` (broadcast) of the segments to consider,
                e.g. the segments of one road section; each position needs at least one.

        Returns:
            :class:`RoadLocation` with batch shape ``(...)``.

        Raises:
            TypeError, ValueError: bad shapes, NaN, a position with no allowed segment.
        """
        pos = as_float64("positions", positions, min_dim=1)
        if pos.shape[-1] == 4:
            pos = pos[..., [0, 2]]
        if pos.shape[-1] != 2:
            raise ValueError(
                f"`positions`: expected (..., 2) positions or (..., 4) states, got "
                f"{tuple(pos.shape)}"
            )
        # component-wise (..., S) arithmetic: much faster than (..., S, 2) reductions
        ux, uy = self.direction[:, 0], self.direction[:, 1]
        rx = pos[..., 0:1] - self.p0[:, 0]
        ry = pos[..., 1:2] - self.p0[:, 1]
        t = torch.minimum((rx * ux + ry * uy).clamp_(min=0.0), self.length)
        ex, ey = rx - t * ux, ry - t * uy
        dist = ex * ex + ey * ey  # squared distance, for the argmin
        if allowed is not None:
            mask = torch.as_tensor(allowed)
            if mask.dtype != torch.bool:
                raise TypeError(f"`allowed`: expected a bool mask, got dtype {mask.dtype}")
            if mask.shape[-1] != self.num_segments:
                raise ValueError(
                    f"`allowed`: expected last axis {self.num_segments} (segments), got "
                    f"{tuple(mask.shape)}"
                )
            mask = mask.expand_as(dist)
            if dist.numel() and bool((~mask.any(-1)).any()):
                raise ValueError("`allowed`: expected at least one allowed segment per position")
            dist = torch.where(mask, dist, torch.full_like(dist, torch.inf))
        seg = dist.argmin(-1)
        idx = seg.unsqueeze(-1)
        a = t.gather(-1, idx).squeeze(-1)
        d = dist.gather(-1, idx).squeeze(-1).sqrt()
        point = self.p0[seg] + a.unsqueeze(-1) * self.direction[seg]
        fwd = self.section_forward[seg]
        sec_a = self.section_offset[seg] + torch.where(fwd, a, self.length[seg] - a)
        return RoadLocation(seg, a, d, point, self.segment_section[seg], sec_a)

    def travel_distance(self, segment: Any, abscissa: Any, *, direction: Any = 0) -> torch.Tensor:
        """Road distance from points on the network to every segment, m.

        From the point at ``abscissa`` on ``segment`` the distance to segment ``t`` is 0 for
        ``t = segment`` and otherwise ``min over v in ends(segment), e in ends(t)`` of
        ``d(point, v) + node_distance[v, e]`` with ``d(point, start) = abscissa`` and
        ``d(point, end) = length - abscissa``. With a direction only the end ahead is used and
        the road distances from it are taken in the network without ``segment`` (no U-turn back
        over the own segment; our choice).

        Args:
            segment: ``(...)`` int segment indices.
            abscissa: ``(...)`` m along the segment from its ``p0``.
            direction: ``(...)`` or scalar: ``+1`` travel only towards ``p1``, ``-1`` only towards
                ``p0``, ``0`` both ways (default).

        Returns:
            ``(..., S)`` float64 m (``inf`` for unreachable segments).

        Examples:
            >>> net = RoadNetwork([[[0, 0], [100, 0], [100, 100]], [[100, 0], [300, 0]]])
            >>> net.travel_distance(0, 30.0).tolist()
            [0.0, 70.0, 70.0]
            >>> net.travel_distance(0, 30.0, direction=-1).tolist()  # towards the road end
            [0.0, inf, inf]
        """
        s = self._segment_index("segment", segment)
        a = as_float64("abscissa", abscissa)
        direc = torch.as_tensor(direction).to(DTYPE)
        s, a, direc = torch.broadcast_tensors(s, a, direc)
        start, end = self.segment_nodes[s, 0], self.segment_nodes[s, 1]
        inf = torch.tensor(torch.inf, dtype=DTYPE)
        d_start = torch.where(direc > 0, inf, a)
        d_end = torch.where(direc < 0, inf, self.length[s] - a)
        ends = self.segment_nodes  # (S, 2)
        nd_s = self.node_distance[start]  # (..., V)
        nd_e = self.node_distance[end]
        directed = direc != 0
        if bool(directed.any()):
            uniq, inv = torch.unique(s[directed], return_inverse=True)
            table = torch.stack([self._distances_without(int(u)) for u in uniq.tolist()])
            nd_s = nd_s.clone()
            nd_e = nd_e.clone()
            nd_s[directed] = table[inv, 0]
            nd_e[directed] = table[inv, 1]
        nd_s = nd_s[..., ends]  # (..., S, 2)
        nd_e = nd_e[..., ends]
        via_s = d_start.unsqueeze(-1) + nd_s.min(-1).values
        via_e = d_end.unsqueeze(-1) + nd_e.min(-1).values
        out = torch.minimum(via_s, via_e)
        own = torch.nn.functional.one_hot(s, self.num_segments).bool()
        return torch.where(own, torch.zeros_like(out), out)

    def reachable(
        self, segment: Any, abscissa: Any, travel: Any, *, direction: Any = 0
    ) -> torch.Tensor:
        """Segments reachable within a travel distance (the VS-IMM active set), bool ``(..., S)``.

        ``travel_distance(segment, abscissa, direction) <= travel``; e.g. ``travel = |v| dt +
        k sigma`` for the predicted travel of a track in one scan.

        Args:
            segment: ``(...)`` int.
            abscissa: ``(...)`` m.
            travel: ``(...)`` or scalar, m (``>= 0``).
            direction: as in :meth:`travel_distance`.

        Returns:
            ``(..., S)`` bool (the own segment always included).

        Examples:
            >>> net = RoadNetwork([[[0, 0], [100, 0], [100, 100]], [[100, 0], [300, 0]]])
            >>> net.reachable(torch.tensor([0, 0]), torch.tensor([30.0, 90.0]), 50.0).tolist()
            [[True, False, False], [True, True, True]]
        """
        d = self.travel_distance(segment, abscissa, direction=direction)
        trav = as_float64("travel", travel)
        if trav.numel() and bool((trav < 0).any()):
            raise ValueError(f"`travel`: expected distances >= 0 m, got {float(trav.min()):g}")
        return d <= trav.unsqueeze(-1)

    def segment_neighbours(self, segment: int) -> tuple[int, ...]:
        """Segments sharing a node with ``segment`` (sorted, excluding itself)."""
        s = int(self._segment_index("segment", segment))
        a, b = self.segment_nodes[s].tolist()
        return tuple(sorted({t for v in (a, b) for t in self._incident[v]} - {s}))

    def node_segments(self, node: int) -> tuple[int, ...]:
        """Segments incident to ``node`` (a junction has >= 3)."""
        v = check_int("node", node, minimum=0, maximum=int(self.nodes.shape[0]) - 1)
        return self._incident[v]

    def junction_sections(self, node: int) -> tuple[int, ...]:
        """Road sections meeting at ``node`` (sorted): the hypotheses of [PD] 24.4.3 there.

        Examples:
            >>> net = RoadNetwork([[[0, 0], [100, 0], [100, 100]], [[100, 0], [300, 0]]])
            >>> net.junction_sections(int(net.junctions[0]))
            (0, 1, 2)
        """
        return tuple(sorted({int(self.segment_section[s]) for s in self.node_segments(node)}))

    def section_mask(self, section: Any) -> torch.Tensor:
        """Bool mask ``(..., S)`` of the segments of road sections ``(...)`` (``-1``: all)."""
        p = torch.as_tensor(section).to(torch.int64)
        if p.numel() and bool(((p < -1) | (p >= self.num_sections)).any()):
            raise ValueError(
                f"`section`: expected indices in [-1, {self.num_sections - 1}], got "
                f"{int(p.min())}..{int(p.max())}"
            )
        return (self.segment_section == p.unsqueeze(-1)) | (p.unsqueeze(-1) < 0)

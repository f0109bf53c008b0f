"""Measurement models of [PD] section 24.3: GMTI reports with range-rate, video / IMINT positions.

State convention ``x = [x, vx, y, vy]`` (m, m/s) in the local East-North frame (TCF, 24.2.2);
everything is batched over a leading shape ``(...)`` and float64.

**GMTI** (24.17-24.20). A report is the TCF position and the range-rate,
``z_mti = [x, y, rho_dot]'`` (24.17), with (24.18)

    rho_dot = ((x - xc) vx + (y - yc) vy) / rho,

``rho`` the distance from the sensor at ``(xc, yc, zc)`` to the target. The chapter prints
``rho = sqrt((x - xc)^2 + (y - yc)^2)`` (a sensor in the ground plane); with the sensor's altitude
``zc`` (the chapter's GMTI flies at 4000 m) we use the slant range
``rho = sqrt((x - xc)^2 + (y - yc)^2 + zc^2)`` for a target on the ground (our addition; it equals
24.18 for ``zc = 0``). The sensor is taken as stationary or its own motion as compensated (the
usual MTI report convention; the chapter does not discuss it).

The range-rate is correlated with the position, so the chapter uses Bizup and Brown's
*alternative* EKF linearisation (AEKF, the chapter's [4]) and writes the measurement as linear,
``z = H_mti x + nu`` (24.19) with (24.20)

    H_mti = [[1, 0, 0, 0], [0, 0, 1, 0], [0, d rho_dot / d vx, 0, d rho_dot / d vy]]
          = [[1, 0, 0, 0], [0, 0, 1, 0], [0, ux, 0, uy]],   u = (x - xc, y - yc) / rho,

i.e. the range-rate row keeps only its velocity partials (the line of sight ``u``), so that
``H_mti(x) x = h(x)`` exactly; the full EKF Jacobian (:func:`gmti_jacobian`) has in addition the
position partials ``d rho_dot / dx = (vx - rho_dot ux) / rho`` (and likewise for ``y``). Our
reading of "the explicit expression of 24.20 is given in [4]": ``u`` is evaluated at the *reported*
position (the measurement, which makes the filter invariant to translations of the frame, as the
chapter says), :meth:`GMTISensor.linearize` ``reference="measurement"``; ``"prediction"`` uses the
predicted position instead.

Noise: the chapter gives the standard deviations in range (20 m), cross-range (0.0008 rad, i.e.
an azimuth angle) and range-rate (1 m/s). :func:`gmti_report_to_tcf` converts a polar report
``(rho, azimuth, rho_dot)`` into ``z`` and its covariance ``R`` by the Jacobian of the
polar-to-Cartesian map (azimuth measured from the East axis counter-clockwise, rad; ground range
``g = sqrt(rho^2 - zc^2)``): ``R_xy = J diag(s_rho^2, s_az^2) J'`` with
``J = [[rho/g cos az, -g sin az], [rho/g sin az, g cos az]]``, and ``R = blockdiag(R_xy,
s_rr^2)``.

**Minimum detectable velocity** (MDV, 1 m/s in the chapter). The equations around 24.21-24.22 are
lost in the OCR (24.21 is the MTI class set); the chapter only states the MDV. Our reading, the
usual clutter notch (Koch and Klemm): a target whose radial speed is below the MDV is in the
clutter notch and is not detected, ``PD(x) = PD`` if ``|rho_dot(x)| >= MDV`` else 0
(:meth:`GMTISensor.detection_probability`); for a Gaussian predicted state the expected value
``PD (1 - P{|rho_dot| < MDV})`` (:meth:`GMTISensor.expected_detection_probability`, our addition).

**Video / IMINT** (24.23-24.24): ``z_video = H_video x + w``, ``H_video = [[1, 0, 0, 0],
[0, 0, 1, 0]]``, ``R_video`` given by the ground station (10 m standard deviation in x and y in
the chapter's scenario). The UGS reports use the same model (24.3.2: "video information given
by both sensor types").

**Resolution** (our addition; :func:`gmti_unresolved`, :func:`gmti_resolution_groups`,
:func:`gmti_merge_unresolved`, :attr:`GMTISensor.resolution`). The chapter blames the convoy's
association ambiguity on "the close formation between targets with the GMTI sensor resolution"
(24.6.3) but gives only *accuracies* (20 m, 0.0008 rad, 1 m/s), no resolution cells. Our
reading, the usual hard-cell model of radar resolution: two targets are *unresolved* when they
are closer than one cell in range **and** in azimuth (cross-range) **and** in range-rate; the
relation is closed transitively (a chain of pairwise unresolved targets is one group), and each
group gives ONE report, at the power-weighted centroid of its members' true ``(rho, azimuth,
rho_dot)`` (equal powers: the mean; the chapter gives no radar cross-sections), with the
measurement noise of one target. Cell widths: :func:`gmti_resolution_cells`, ``k`` times the
accuracies with ``k = 2.5`` by default (:data:`GMTI_RESOLUTION_SIGMAS`; at high SNR a
measurement is a few times finer than its resolution cell, so a cell of 2-3 sigma is the usual
order): 50 m, 0.002 rad (about 150 m of cross-range at the chapter's 75 km) and 2.5 m/s. Off
(``resolution=None``, every target resolved) unless asked for.

Sensors are created by name with :func:`make_sensor` (``"gmti"``, ``"video"``, ``"ugs"``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from hocnet._check import _describe, check_choice, check_number
from hocnet.tracking.kalman import DTYPE, as_float64, normal_cdf

__all__ = [
    "GMTI_RESOLUTION_SIGMAS",
    "SENSOR_NAMES",
    "GMTISensor",
    "VideoSensor",
    "check_measurements",
    "disc_coverage",
    "gmti_aekf_matrix",
    "gmti_jacobian",
    "gmti_measure",
    "gmti_merge_unresolved",
    "gmti_report_to_tcf",
    "gmti_resolution_cells",
    "gmti_resolution_groups",
    "gmti_tcf_to_report",
    "gmti_unresolved",
    "make_sensor",
    "rectangle_coverage",
    "stop_detectable",
]

H_POSITION = ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0))


def check_measurements(name: str, z: Any, dim: int) -> torch.Tensor:
    """Validate measurements ``(..., dim)``: real, finite, float64.

    Raises:
        TypeError: not real numeric.
        ValueError: wrong last axis, or NaN / inf (the message gives the first bad row).

    Examples:
        >>> check_measurements("z", [[1.0, 2.0]], 2).dtype
        torch.float64
    """
    if not isinstance(z, torch.Tensor):
        try:
            z = torch.as_tensor(z, dtype=DTYPE)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(f"`{name}`: expected real measurements, got {_describe(z)}") from None
    if z.is_complex() or z.dtype == torch.bool:
        raise TypeError(f"`{name}`: expected real measurements, got dtype {z.dtype}")
    z = z.to(DTYPE)
    if z.dim() < 1 or z.shape[-1] != dim:
        raise ValueError(
            f"`{name}`: expected measurements of shape (..., {dim}), got {tuple(z.shape)}"
        )
    bad = ~torch.isfinite(z).all(-1)
    if bool(bad.any()):
        first = torch.nonzero(bad)[0].tolist()
        raise ValueError(
            f"`{name}`: expected finite measurements, got NaN/inf at index {first} "
            f"({int(bad.sum())} bad rows)"
        )
    return z


def _sensor_position(position: Any) -> torch.Tensor:
    pos = as_float64("position", position, min_dim=1)
    if pos.shape[-1] == 2:
        pos = torch.cat([pos, torch.zeros_like(pos[..., :1])], -1)
    if pos.shape[-1] != 3:
        raise ValueError(
            f"`position`: expected the sensor position (xc, yc) or (xc, yc, zc) in m, got shape "
            f"{tuple(pos.shape)}"
        )
    return pos


def _state(x: Any) -> torch.Tensor:
    x = as_float64("x", x, min_dim=1)
    if x.shape[-1] != 4:
        raise ValueError(f"`x`: expected states (..., 4) [x, vx, y, vy], got {tuple(x.shape)}")
    return x


def _los(
    x: torch.Tensor, pos: torch.Tensor, ground: bool = False
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Horizontal offsets ``dx, dy`` and slant (or, ``ground=True``, ground) range ``rho``."""
    dx = x[..., 0] - pos[..., 0]
    dy = x[..., 2] - pos[..., 1]
    h2 = 0.0 if ground else pos[..., 2] * pos[..., 2]
    rho = torch.sqrt(dx * dx + dy * dy + h2)
    if rho.numel() and bool((rho <= 0).any()):
        raise ValueError("`x`: expected targets away from the sensor position, got range 0")
    return dx, dy, rho


def gmti_measure(x: Any, position: Any, *, ground: bool = False) -> torch.Tensor:
    """Noise-free GMTI measurement ``h(x) = [x, y, rho_dot]`` (eq. 24.17-24.18).

    Args:
        x: states ``(..., 4)`` (m, m/s).
        position: sensor position ``(3,)`` ``(xc, yc, zc)`` or ``(2,)`` (m), broadcast.
        ground: divide by the ground range (24.18 as printed, ``zc`` ignored) instead of the
            slant range including the altitude ``zc`` (default, backward compatible).

    Returns:
        ``(..., 3)`` float64: m, m, m/s.

    Examples:
        >>> gmti_measure(torch.tensor([3.0, 1.0, 4.0, 0.0]), torch.zeros(2)).tolist()
        [3.0, 4.0, 0.6]
    """
    x = _state(x)
    pos = _sensor_position(position)
    dx, dy, rho = _los(x, pos, ground)
    rr = (dx * x[..., 1] + dy * x[..., 3]) / rho
    return torch.stack([x[..., 0], x[..., 2], rr], -1)


def gmti_jacobian(x: Any, position: Any, *, ground: bool = False) -> torch.Tensor:
    """Full EKF Jacobian ``d h / d x`` of :func:`gmti_measure`, ``(..., 3, 4)``.

    ``d rho_dot / dx = (vx - rho_dot dx / rho) / rho``, ``d rho_dot / dvx = dx / rho`` (and
    likewise in ``y``): the standard EKF linearisation, which the chapter replaces by 24.20.
    ``ground`` as :func:`gmti_measure`.

    Examples:
        >>> gmti_jacobian(torch.tensor([3.0, 0.0, 4.0, 0.0]), torch.zeros(2))[2].tolist()
        [0.0, 0.6, 0.0, 0.8]
    """
    x = _state(x)
    pos = _sensor_position(position)
    dx, dy, rho = _los(x, pos, ground)
    rr = (dx * x[..., 1] + dy * x[..., 3]) / rho
    zero, one = torch.zeros_like(rho), torch.ones_like(rho)
    row3 = [
        (x[..., 1] - rr * dx / rho) / rho,
        dx / rho,
        (x[..., 3] - rr * dy / rho) / rho,
        dy / rho,
    ]
    return torch.stack(
        [
            torch.stack([one, zero, zero, zero], -1),
            torch.stack([zero, zero, one, zero], -1),
            torch.stack(row3, -1),
        ],
        -2,
    )


def gmti_aekf_matrix(reference: Any, position: Any, *, ground: bool = False) -> torch.Tensor:
    """AEKF measurement matrix ``H_mti`` of eq. 24.20 (Bizup and Brown), ``(..., 3, 4)``.

    ``[[1, 0, 0, 0], [0, 0, 1, 0], [0, ux, 0, uy]]`` with the line of sight
    ``u = (x - xc, y - yc) / rho`` evaluated at ``reference``: the velocity partials of the
    range-rate (the position partials are dropped). For any state ``x`` with the same position
    as ``reference``, ``H_mti x = h(x)`` exactly (24.19 without noise).

    Args:
        reference: ``(..., 2)`` positions or ``(..., 4)`` states (m) where ``u`` is evaluated
            (the reported position in the AEKF).
        position: sensor position ``(3,)`` or ``(2,)`` (m).
        ground: line of sight normalised by the ground range (as :func:`gmti_measure`).

    Examples:
        >>> gmti_aekf_matrix(torch.tensor([3.0, 4.0]), torch.zeros(2))[2].tolist()
        [0.0, 0.6, 0.0, 0.8]
    """
    ref = as_float64("reference", reference, min_dim=1)
    if ref.shape[-1] == 2:
        ref = torch.stack(
            [
                ref[..., 0],
                torch.zeros_like(ref[..., 0]),
                ref[..., 1],
                torch.zeros_like(ref[..., 0]),
            ],
            -1,
        )
    ref = _state(ref)
    pos = _sensor_position(position)
    dx, dy, rho = _los(ref, pos, ground)
    zero, one = torch.zeros_like(rho), torch.ones_like(rho)
    return torch.stack(
        [
            torch.stack([one, zero, zero, zero], -1),
            torch.stack([zero, zero, one, zero], -1),
            torch.stack([zero, dx / rho, zero, dy / rho], -1),
        ],
        -2,
    )


def gmti_report_to_tcf(
    report: Any,
    position: Any,
    sigma_range: float,
    sigma_azimuth: float,
    sigma_range_rate: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Polar GMTI report ``(rho, azimuth, rho_dot)`` to the TCF measurement ``z`` and its ``R``.

    ``g = sqrt(rho^2 - zc^2)``, ``x = xc + g cos az``, ``y = yc + g sin az`` (target on the
    ground), ``z = [x, y, rho_dot]`` (24.17) and ``R`` as in the module docstring (first-order
    propagation of ``diag(s_rho^2, s_az^2)``; the range-rate noise independent).

    Args:
        report: ``(..., 3)`` slant range (m), azimuth (rad, from East counter-clockwise),
            range-rate (m/s).
        position: sensor position ``(3,)`` or ``(2,)`` (m).
        sigma_range: m (the chapter: 20).
        sigma_azimuth: rad (the chapter's "cross-range" 0.0008).
        sigma_range_rate: m/s (the chapter: 1).

    Returns:
        ``(z, R)``: ``(..., 3)`` and ``(..., 3, 3)`` float64.

    Raises:
        ValueError: non-finite report, slant range below the sensor altitude, bad sigmas.

    Examples:
        >>> z, R = gmti_report_to_tcf(torch.tensor([5.0, 0.0, 1.0]), torch.zeros(2), 1.0, 0.1, 1.0)
        >>> z.tolist(), [round(v, 12) for v in R.diagonal().tolist()]
        ([5.0, 0.0, 1.0], [1.0, 0.25, 1.0])
    """
    rep = check_measurements("report", report, 3)
    pos = _sensor_position(position)
    sr = check_number("sigma_range", sigma_range, low=0.0)
    sa = check_number("sigma_azimuth", sigma_azimuth, low=0.0)
    srr = check_number("sigma_range_rate", sigma_range_rate, low=0.0)
    rho, az, rr = rep[..., 0], rep[..., 1], rep[..., 2]
    g2 = rho * rho - pos[..., 2] * pos[..., 2]
    if g2.numel() and bool((g2 <= 0).any()):
        raise ValueError(
            "`report`: expected slant ranges larger than the sensor altitude, got one that is not"
        )
    g = torch.sqrt(g2)
    c, s = torch.cos(az), torch.sin(az)
    z = torch.stack([pos[..., 0] + g * c, pos[..., 1] + g * s, rr], -1)
    J = torch.stack(
        [torch.stack([rho / g * c, -g * s], -1), torch.stack([rho / g * s, g * c], -1)], -2
    )
    Rxy = J @ torch.diag(torch.tensor([sr * sr, sa * sa], dtype=DTYPE)) @ J.transpose(-1, -2)
    R = torch.zeros(*z.shape[:-1], 3, 3, dtype=DTYPE)
    R[..., :2, :2] = Rxy
    R[..., 2, 2] = srr * srr
    return z, R


def gmti_tcf_to_report(x: Any, position: Any) -> torch.Tensor:
    """Polar report ``(rho, azimuth, rho_dot)`` of states (the inverse of the conversion above).

    Args:
        x: states ``(..., 4)`` (m, m/s), targets on the ground.
        position: sensor position ``(3,)`` or ``(2,)`` (m).

    Returns:
        ``(..., 3)``: m, rad, m/s (for simulating noisy reports in the sensor frame).

    Examples:
        >>> [round(v, 6) for v in gmti_tcf_to_report(torch.tensor([0.0, 0, 4.0, 1]),
        ...                                           torch.tensor([0.0, 0, 3])).tolist()]
        [5.0, 1.570796, 0.8]
    """
    x = _state(x)
    pos = _sensor_position(position)
    dx, dy, rho = _los(x, pos)
    rr = (dx * x[..., 1] + dy * x[..., 3]) / rho
    return torch.stack([rho, torch.atan2(dy, dx), rr], -1)


#: Width of a GMTI resolution cell in accuracies (standard deviations), our choice (module doc).
GMTI_RESOLUTION_SIGMAS = 2.5


def gmti_resolution_cells(
    sigma_range: float,
    sigma_azimuth: float,
    sigma_range_rate: float,
    k: float = GMTI_RESOLUTION_SIGMAS,
) -> tuple[float, float, float]:
    """Resolution cells ``(range m, azimuth rad, range-rate m/s)`` of ``k`` accuracies each.

    Our reading (the chapter gives accuracies, not cells): see the module docstring.

    Examples:
        >>> gmti_resolution_cells(20.0, 0.0008, 1.0)
        (50.0, 0.002, 2.5)
    """
    k = check_number("k", k, low=0.0)
    vals = [
        check_number(n, v, low=0.0)
        for n, v in (
            ("sigma_range", sigma_range),
            ("sigma_azimuth", sigma_azimuth),
            ("sigma_range_rate", sigma_range_rate),
        )
    ]
    return (k * vals[0], k * vals[1], k * vals[2])


def _cells(cells: Any) -> torch.Tensor:
    c = as_float64("cells", cells, min_dim=1)
    if c.shape != (3,) or bool((c < 0).any()):
        raise ValueError(
            "`cells`: expected 3 non-negative widths (range m, azimuth rad, range-rate m/s), got "
            f"{c.tolist() if c.numel() <= 6 else tuple(c.shape)}"
        )
    return c


def _polar_reports(report: Any) -> torch.Tensor:
    rep = check_measurements("report", report, 3)
    if rep.dim() < 2:
        raise ValueError(f"`report`: expected reports of shape (..., N, 3), got {tuple(rep.shape)}")
    return rep


def _wrap(a: torch.Tensor) -> torch.Tensor:
    return torch.remainder(a + torch.pi, 2 * torch.pi) - torch.pi


def gmti_unresolved(report: Any, cells: Any) -> torch.Tensor:
    """Pairwise "unresolved" relation of noise-free polar reports (our addition, hard cells).

    Targets ``i != j`` are unresolved when ``|rho_i - rho_j| < cells[0]``, ``|az_i - az_j| <
    cells[1]`` (wrapped to ``[-pi, pi)``) and ``|rho_dot_i - rho_dot_j| < cells[2]``: closer than
    one cell in every coordinate. A zero width resolves everything in that coordinate.

    Args:
        report: ``(..., N, 3)`` true ``(rho m, azimuth rad, rho_dot m/s)`` of the targets of one
            scan (:func:`gmti_tcf_to_report`).
        cells: ``(3,)`` cell widths (:func:`gmti_resolution_cells`).

    Returns:
        ``(..., N, N)`` bool, symmetric, ``False`` on the diagonal.

    Raises:
        ValueError: bad shapes, non-finite reports, negative widths.

    Examples:
        >>> rep = torch.tensor([[1000.0, 0.0, 5.0], [1030.0, 0.001, 6.0], [1200.0, 0.0, 5.0]])
        >>> gmti_unresolved(rep, (50.0, 0.002, 2.5)).int().tolist()
        [[0, 1, 0], [1, 0, 0], [0, 0, 0]]
    """
    rep = _polar_reports(report)
    c = _cells(cells)
    d = rep.unsqueeze(-2) - rep.unsqueeze(-3)  # (..., N, N, 3)
    d = torch.stack([d[..., 0], _wrap(d[..., 1]), d[..., 2]], -1).abs()
    close = (d < c).all(-1)
    n = rep.shape[-2]
    return close & ~torch.eye(n, dtype=torch.bool)


def gmti_resolution_groups(report: Any, cells: Any) -> torch.Tensor:
    """Groups of mutually unresolved targets: the transitive closure of :func:`gmti_unresolved`.

    Computed by repeated squaring of the reachability matrix (``ceil(log2 N)`` boolean matrix
    products), batched over the leading axes.

    Args:
        report: ``(..., N, 3)`` true polar reports of one scan.
        cells: ``(3,)`` cell widths.

    Returns:
        ``(..., N)`` int64: the group label of each target, the smallest index in its group (a
        resolved target is its own group).

    Examples:
        >>> rep = torch.tensor([[1000.0, 0, 5], [1040.0, 0, 5], [1080.0, 0, 5], [2000.0, 0, 5]])
        >>> gmti_resolution_groups(rep, (50.0, 0.002, 2.5)).tolist()
        [0, 0, 0, 3]
    """
    rep = _polar_reports(report)
    n = rep.shape[-2]
    if n == 0:
        return torch.zeros(rep.shape[:-1], dtype=torch.int64)
    reach = gmti_unresolved(rep, cells) | torch.eye(n, dtype=torch.bool)
    for _ in range(max(1, math.ceil(math.log2(n)))):
        reach = (reach.to(DTYPE) @ reach.to(DTYPE)) > 0
    return reach.to(torch.int64).argmax(-1)  # first True of each row: smallest index


def gmti_merge_unresolved(
    report: Any, cells: Any, weights: Any = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One report per group of unresolved targets, at the power-weighted centroid (our reading).

    Args:
        report: ``(N, 3)`` true polar reports ``(rho, azimuth, rho_dot)`` of one scan.
        cells: ``(3,)`` cell widths (:func:`gmti_resolution_cells`).
        weights: ``(N,)`` positive echo powers (default: equal, then the centroid is the mean).

    Returns:
        ``(merged, groups, dominant)``: ``merged`` ``(G, 3)`` the centroid of each group in the
        order of the groups' first members, ``groups`` ``(N,)`` int64 the row of ``merged`` of
        each target, ``dominant`` ``(G,)`` int64 the member with the largest power (the first on
        ties), whose type the report carries in our model.

    Raises:
        ValueError: bad shapes, non-finite values, non-positive weights.

    Examples:
        >>> rep = torch.tensor([[1000.0, 0.0, 5.0], [1040.0, 0.0, 6.0], [3000.0, 0.0, 5.0]])
        >>> merged, groups, dom = gmti_merge_unresolved(rep, (50.0, 0.002, 2.5))
        >>> merged.tolist(), groups.tolist(), dom.tolist()
        ([[1020.0, 0.0, 5.5], [3000.0, 0.0, 5.0]], [0, 0, 1], [0, 2])
    """
    rep = _polar_reports(report)
    if rep.dim() != 2:
        raise ValueError(f"`report`: expected one scan of shape (N, 3), got {tuple(rep.shape)}")
    n = rep.shape[0]
    if weights is None:
        w = torch.ones(n, dtype=DTYPE)
    else:
        w = as_float64("weights", weights, min_dim=1)
        if w.shape != (n,) or not bool(torch.isfinite(w).all()) or bool((w <= 0).any()):
            raise ValueError(
                f"`weights`: expected {n} finite positive echo powers, got shape {tuple(w.shape)}"
            )
    labels = gmti_resolution_groups(rep, cells)
    firsts, groups = torch.unique(labels, return_inverse=True)  # sorted: order of first members
    g = firsts.shape[0]
    # azimuths relative to the group's first member, so that the mean does not wrap
    rel = rep.clone()
    rel[:, 1] = rep[firsts[groups], 1] + _wrap(rep[:, 1] - rep[firsts[groups], 1])
    wsum = torch.zeros(g, dtype=DTYPE).index_add_(0, groups, w)
    merged = torch.zeros(g, 3, dtype=DTYPE).index_add_(0, groups, rel * w[:, None]) / wsum[:, None]
    merged[:, 1] = _wrap(merged[:, 1])
    best = torch.full((g,), -1.0, dtype=DTYPE).scatter_reduce(0, groups, w, reduce="amax")
    is_best = w == best[groups]
    idx = torch.arange(n)
    dominant = torch.full((g,), n, dtype=torch.int64).scatter_reduce(
        0, groups, torch.where(is_best, idx, torch.full_like(idx, n)), reduce="amin"
    )
    return merged, groups, dominant


@dataclass(frozen=True)
class GMTISensor:
    """A GMTI radar: TCF position + range-rate reports, AEKF linearisation, MDV notch.

    Args:
        position: ``(xc, yc, zc)`` in m (the chapter: ``(-50000, -60000, 4000)``).
        sigma_range: m (20).
        sigma_azimuth: rad (0.0008, the chapter's "cross-range").
        sigma_range_rate: m/s (1).
        pd: detection probability outside the clutter notch (0.9).
        mdv: minimum detectable velocity, m/s (1); 0 disables the notch (and then the sensor is
            taken to see stopped targets, ``stop_detectable``).
        name: ``"gmti"``.
        range_rate: ``"ground"`` (default): eq. 24.18 as printed, the range-rate along the
            ground line of sight ``(p - p_c) . v / |p - p_c|``, as the scenario simulator
            (:func:`hocnet.tracking.scenario.gmti_range_rate`) generates it; ``"slant"``: divided
            by the slant range including the altitude ``zc`` (a factor ``g / rho``, 0.9987 at
            78 km ground range and 4 km altitude). Before this option the model used ``"slant"``.
        resolution: resolution cells ``(range m, azimuth rad, range-rate m/s)`` used by
            :meth:`resolve` (our addition, module docstring), e.g.
            ``gmti_resolution_cells(20.0, 0.0008, 1.0)``; ``None`` (default): every target
            resolved. The tracker's filters do not use it (no unresolved-measurement
            hypotheses in the MHT).

    Attributes:
        stop_detectable: ``False`` when ``mdv > 0``: a stopped target is inside the clutter
            notch, so the stop mode follows the printed 24.31 (``Lambda_0 = delta``; see
            :func:`hocnet.tracking.imm.pd_mode_log_likelihoods`).

    Examples:
        >>> s = GMTISensor((0.0, 0.0, 0.0), 20.0, 0.0008, 1.0, pd=0.9, mdv=1.0)
        >>> s.detection_probability(torch.tensor([[100.0, 0.5, 0, 0], [100.0, 5.0, 0, 0]])).tolist()
        [0.0, 0.9]
    """

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sigma_range: float = 20.0
    sigma_azimuth: float = 0.0008
    sigma_range_rate: float = 1.0
    pd: float = 0.9
    mdv: float = 1.0
    name: str = "gmti"
    range_rate: str = "ground"
    resolution: tuple[float, float, float] | None = None

    dim = 3

    def __post_init__(self) -> None:
        pos = _sensor_position(self.position)
        if pos.shape != (3,):
            raise ValueError(f"`position`: expected one sensor position, got {tuple(pos.shape)}")
        object.__setattr__(self, "position", tuple(pos.tolist()))
        for n in ("sigma_range", "sigma_azimuth", "sigma_range_rate", "mdv"):
            check_number(n, getattr(self, n), low=0.0)
        check_number("pd", self.pd, low=0.0, high=1.0)
        check_choice("range_rate", self.range_rate, ("ground", "slant"))
        if self.resolution is not None:
            object.__setattr__(self, "resolution", tuple(_cells(self.resolution).tolist()))

    @property
    def stop_detectable(self) -> bool:
        """Whether a stopped target can be detected (only without an MDV notch)."""
        return self.mdv <= 0.0

    @property
    def _ground(self) -> bool:
        return self.range_rate == "ground"

    @property
    def _pos(self) -> torch.Tensor:
        return torch.tensor(self.position, dtype=DTYPE)

    def measure(self, x: Any) -> torch.Tensor:
        """Noise-free ``h(x)`` ``(..., 3)`` (24.17-24.18)."""
        return gmti_measure(x, self._pos, ground=self._ground)

    def jacobian(self, x: Any) -> torch.Tensor:
        """Full EKF Jacobian ``(..., 3, 4)``."""
        return gmti_jacobian(x, self._pos, ground=self._ground)

    def covariance(self, z: Any) -> torch.Tensor:
        """``R`` ``(..., 3, 3)`` of TCF measurements ``z`` ``(..., 3)`` (at their positions)."""
        z = check_measurements("z", z, 3)
        x = torch.stack([z[..., 0], torch.zeros_like(z[..., 0]), z[..., 1], z[..., 2]], -1)
        report = gmti_tcf_to_report(x, self._pos)
        report = torch.stack([report[..., 0], report[..., 1], z[..., 2]], -1)
        return gmti_report_to_tcf(
            report, self._pos, self.sigma_range, self.sigma_azimuth, self.sigma_range_rate
        )[1]

    def from_report(self, report: Any) -> tuple[torch.Tensor, torch.Tensor]:
        """Polar report ``(..., 3)`` -> ``(z, R)`` (:func:`gmti_report_to_tcf`)."""
        return gmti_report_to_tcf(
            report, self._pos, self.sigma_range, self.sigma_azimuth, self.sigma_range_rate
        )

    def linearize(
        self, x_pred: Any, z: Any, *, reference: str = "measurement"
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """AEKF linearisation (24.19-24.20) for an update of ``x_pred`` with ``z``.

        Args:
            x_pred: predicted states ``(..., 4)``.
            z: measurements ``(..., 3)`` (broadcast against ``x_pred``'s batch).
            reference: where the line of sight is evaluated, ``"measurement"`` (AEKF, our
                reading of [4]) or ``"prediction"``.

        Returns:
            ``(hx, H, R)``: ``H x_pred`` ``(..., 3)``, ``H`` ``(..., 3, 4)``, ``R`` ``(..., 3, 3)``.
        """
        check_choice("reference", reference, ("measurement", "prediction"))
        x = _state(x_pred)
        z = check_measurements("z", z, 3)
        ref = z[..., :2] if reference == "measurement" else x
        H = gmti_aekf_matrix(ref, self._pos, ground=self._ground)
        if reference == "measurement":
            H = H.expand(*torch.broadcast_shapes(H.shape[:-2], x.shape[:-1]), 3, 4)
        hx = (H @ x.unsqueeze(-1)).squeeze(-1)
        return hx, H, self.covariance(z)

    def resolve(
        self, x: Any, weights: Any = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Noise-free reports of the targets ``x`` ``(N, 4)`` of one scan after resolution.

        The true polar reports (:func:`gmti_tcf_to_report`, slant range) merged by
        :func:`gmti_merge_unresolved` with :attr:`resolution` (``None``: one report per target).

        Returns:
            ``(reports (G, 3), groups (N,), dominant (G,))`` as :func:`gmti_merge_unresolved`.

        Examples:
            >>> s = GMTISensor((0.0, 0.0, 0.0), resolution=(50.0, 0.002, 2.5))
            >>> x = torch.tensor([[1000.0, 5.0, 0, 0], [1030.0, 6.0, 0, 0], [900.0, 5.0, 0, 0]])
            >>> s.resolve(x)[1].tolist()
            [0, 0, 1]
        """
        x = _state(x)
        if x.dim() != 2:
            raise ValueError(f"`x`: expected the states (N, 4) of one scan, got {tuple(x.shape)}")
        rep = gmti_tcf_to_report(x, self._pos)
        if self._ground:
            rep = torch.stack([rep[..., 0], rep[..., 1], self.measure(x)[..., 2]], -1)
        cells = (0.0, 0.0, 0.0) if self.resolution is None else self.resolution
        return gmti_merge_unresolved(rep, cells, weights)

    def detection_probability(self, x: Any) -> torch.Tensor:
        """``PD`` outside the MDV clutter notch, 0 inside (our reading), ``(...)``."""
        rr = self.measure(x)[..., 2]
        return torch.where(rr.abs() >= self.mdv, torch.full_like(rr, self.pd), torch.zeros_like(rr))

    def expected_detection_probability(self, x: Any, P: Any) -> torch.Tensor:
        """``PD (1 - P{|rho_dot| < MDV})`` ``(...)`` for Gaussian states ``N(x, P)`` (our addition).

        ``rho_dot ~ N(h3(x), H3 P H3')`` with the AEKF row ``H3`` at the state's position.
        """
        x = _state(x)
        P = as_float64("P", P, min_dim=2, square=True)
        H3 = gmti_aekf_matrix(x, self._pos, ground=self._ground)[..., 2, :]
        m = (H3 * x).sum(-1)
        var = (H3.unsqueeze(-2) @ P @ H3.unsqueeze(-1)).squeeze(-1).squeeze(-1)
        sd = var.clamp(min=0.0).sqrt()
        safe = torch.where(sd > 0, sd, torch.ones_like(sd))
        inside = normal_cdf((self.mdv - m) / safe) - normal_cdf((-self.mdv - m) / safe)
        hard = (m.abs() < self.mdv).to(DTYPE)
        inside = torch.where(sd > 0, inside, hard)
        return self.pd * (1.0 - inside)


@dataclass(frozen=True)
class VideoSensor:
    """Video EO/IR (UAV) or UGS position reports, eq. 24.23-24.24.

    Imagery has no clutter notch: a stopped target is seen like a moving one
    (``stop_detectable = True``; the stop mode is then scored ``PD p(z | M0)``, not by the
    printed 24.31, see :func:`hocnet.tracking.imm.pd_mode_log_likelihoods`).

    Args:
        sigma: position standard deviation in x and y, m (the chapter: 10 for the UAV).
        pd: detection probability (0.9) inside the coverage.
        name: ``"video"`` or ``"ugs"``.
        coverage: where the sensor sees (our addition; the chapter's UAV footprint and the UGS
            1000 m range): ``None`` (everywhere, the former behaviour), a callable
            ``positions (..., 2) -> bool (...)``, or :func:`disc_coverage` /
            :func:`rectangle_coverage`. ``PD = 0`` outside. The expected ``PD`` of a Gaussian
            state uses the coverage at its mean (our simplification).

    Examples:
        >>> hx, H, R = VideoSensor(10.0).linearize(torch.zeros(4), torch.ones(2))
        >>> H.tolist(), R.diagonal().tolist()
        ([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]], [100.0, 100.0])
    """

    sigma: float = 10.0
    pd: float = 0.9
    name: str = "video"
    coverage: Any = None

    dim = 2
    stop_detectable = True

    def __post_init__(self) -> None:
        check_number("sigma", self.sigma, low=0.0, low_inclusive=False)
        check_number("pd", self.pd, low=0.0, high=1.0)
        if self.coverage is not None and not callable(self.coverage):
            raise TypeError(
                "`coverage`: expected None or a callable positions -> bool, got "
                f"{_describe(self.coverage)}"
            )

    def measure(self, x: Any) -> torch.Tensor:
        """``H_video x`` ``(..., 2)`` (24.23 without noise)."""
        x = _state(x)
        return x[..., [0, 2]]

    def jacobian(self, x: Any) -> torch.Tensor:
        """``H_video`` (24.24) broadcast to ``(..., 2, 4)``."""
        x = _state(x)
        return torch.tensor(H_POSITION, dtype=DTYPE).expand(*x.shape[:-1], 2, 4)

    def covariance(self, z: Any) -> torch.Tensor:
        """``R_video = sigma^2 I`` ``(..., 2, 2)``."""
        z = check_measurements("z", z, 2)
        return (self.sigma**2 * torch.eye(2, dtype=DTYPE)).expand(*z.shape[:-1], 2, 2)

    def linearize(
        self, x_pred: Any, z: Any, **_: Any
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(H x_pred, H, R)`` for a linear update (the model is linear)."""
        x = _state(x_pred)
        z = check_measurements("z", z, 2)
        H = torch.tensor(H_POSITION, dtype=DTYPE)
        return x[..., [0, 2]], H, self.covariance(z)

    def detection_probability(self, x: Any) -> torch.Tensor:
        """``PD`` inside the coverage, 0 outside, ``(...)`` (no clutter notch for imagery)."""
        x = _state(x)
        pd = torch.full(x.shape[:-1], self.pd, dtype=DTYPE)
        if self.coverage is None:
            return pd
        inside = torch.as_tensor(self.coverage(x[..., [0, 2]]), dtype=torch.bool)
        return torch.where(inside, pd, torch.zeros_like(pd))

    def expected_detection_probability(self, x: Any, P: Any) -> torch.Tensor:
        """:meth:`detection_probability` at the mean ``(...)`` (``P`` unused)."""
        return self.detection_probability(x)


def disc_coverage(center: Any, radius: float) -> Any:
    """Coverage of a sensor with range ``radius`` (m) around ``center`` ``(2,)`` (e.g. a UGS).

    Returns:
        A callable ``positions (..., 2) -> bool (...)`` (inside or on the circle).

    Examples:
        >>> cov = disc_coverage((0.0, 0.0), 1000.0)
        >>> cov(torch.tensor([[500.0, 0.0], [0.0, 1500.0]])).tolist()
        [True, False]
    """
    c = as_float64("center", center, min_dim=1)
    if c.shape != (2,):
        raise ValueError(f"`center`: expected shape (2,), got {tuple(c.shape)}")
    r = check_number("radius", radius, low=0.0)

    def inside(pos: Any) -> torch.Tensor:
        p = torch.as_tensor(pos, dtype=DTYPE)
        return ((p - c) ** 2).sum(-1) <= r * r

    return inside


def rectangle_coverage(rectangles: Any) -> Any:
    """Coverage by axis-aligned rectangles ``(K, 4)`` ``[xmin, ymin, xmax, ymax]`` (m).

    E.g. a UAV footprint.

    Returns:
        A callable ``positions (..., 2) -> bool (...)`` (inside any rectangle, borders included).

    Examples:
        >>> cov = rectangle_coverage([[0.0, 0.0, 10.0, 5.0]])
        >>> cov(torch.tensor([[5.0, 5.0], [11.0, 1.0]])).tolist()
        [True, False]
    """
    b = as_float64("rectangles", rectangles, min_dim=1)
    b = b.reshape(-1, 4) if b.numel() else b.reshape(0, 4)
    if b.shape[-1] != 4 or bool((b[:, 2] < b[:, 0]).any() or (b[:, 3] < b[:, 1]).any()):
        raise ValueError("`rectangles`: expected rows [xmin, ymin, xmax, ymax] with min <= max")

    def inside(pos: Any) -> torch.Tensor:
        p = torch.as_tensor(pos, dtype=DTYPE).unsqueeze(-2)  # (..., 1, 2)
        ok = (p[..., 0] >= b[:, 0]) & (p[..., 0] <= b[:, 2])
        ok = ok & (p[..., 1] >= b[:, 1]) & (p[..., 1] <= b[:, 3])
        return ok.any(-1)

    return inside


def stop_detectable(sensor: Any) -> bool:
    """Whether ``sensor`` sees stopped targets (no MDV clutter notch).

    Its ``stop_detectable`` attribute, else ``False`` for a sensor with an ``mdv`` (a GMTI) and
    ``True`` otherwise.

    Examples:
        >>> stop_detectable(GMTISensor()), stop_detectable(VideoSensor())
        (False, True)
    """
    if hasattr(sensor, "stop_detectable"):
        return bool(sensor.stop_detectable)
    return not hasattr(sensor, "mdv")


_SENSORS = {"gmti": GMTISensor, "video": VideoSensor, "ugs": VideoSensor}
#: Names accepted by :func:`make_sensor`.
SENSOR_NAMES = tuple(_SENSORS)


def make_sensor(name: str, **params: Any) -> GMTISensor | VideoSensor:
    """Create a sensor model by name: ``"gmti"``, ``"video"`` or ``"ugs"``.

    Args:
        name: sensor name.
        **params: the dataclass fields of :class:`GMTISensor` / :class:`VideoSensor`.

    Raises:
        ValueError: unknown name (the message lists the known ones) or bad parameters.

    Examples:
        >>> make_sensor("ugs", sigma=5.0).name
        'ugs'
    """
    check_choice("sensor", name, SENSOR_NAMES)
    return _SENSORS[name](name=name, **params)

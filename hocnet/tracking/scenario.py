"""The simulated experiment of [PD] 24.6: road network, ten targets, GMTI / UAV / UGS reports.

Everything is in the local East-North frame of [PD] 24.2.2 (the TCF): x East, y North, in m,
velocities in m/s, times in s. The chapter runs its scenario on a *real* road network that it
shows only as a picture (Fig. 24.3-24.7); we build a synthetic network of the same size (12 x 10
km: x in [-6000, 6000], y in [-6000, 4000]) with one highway and byways, and the ten targets with
the interactions the text describes (our design, see :data:`PD_INTERACTIONS`):

- the convoy 3, 7, 2, 4 (military) leaves the highway's west end together, 10 s apart;
- 2 overtakes 7 and then 3 and drives in front of the convoy;
- the civilian car 1 comes from behind on the highway and passes 4, 2, 7 and 3;
- the civilians 5 (bus), 6 (car), 9 (car) and 10 (truck) cross the highway at its junctions as
  convoy vehicles or target 1 go through (6 at the west junction J1, where no image sensor looks:
  the chapter's target 6 is seen by the GMTI only);
- stops: 4 stops 60 s after turning north at J3, the bus 5 stops 30 s at a bus stop, 8 stops
  120 s on the northern byway, 10 waits 20 s before crossing J3.

Sensors (parameters of [PD] 24.6.1 unless said otherwise; every random draw takes a ``seed``):

- GMTI at (-50 km, -60 km, 4000 m), 10 s revisit, sigma 20 m in range, 0.0008 rad in cross-range
  and 1 m/s in range-rate, PD 0.9, MDV 1 m/s (a target whose range-rate is below the MDV in
  magnitude is never detected), Poisson false alarms of density 1e-8 per m^2 over the surveillance
  area, type reports drawn from the confusion matrix diag(0.8, 0.7, 0.9) of eq. 24.49.
- A UAV video sensor: reports every 10 s with sigma 10 m in x and y, PD 0.9, delay 11 s, no false
  alarm, type probability 0.90 / 0.75 / 0.50 by footprint area (eq. 24.50).
- 5 UGS: a target within 1000 m, a report every 1 s but one target per 4 s, delay 11 s, no false
  alarm, type probability 0.9 / 0.5 by aspect (eq. 24.51).

Our readings and choices where the chapter is silent or the OCR lost the text:

- The class sets of eq. 24.21 and 24.25 are lost in the OCR. :data:`GMTI_CLASSES` follows the
  STANAG 4607 target-classification order (tracked vehicle, wheeled vehicle, rotary-wing
  aircraft), which gives the three-class confusion matrix of eq. 24.49 a meaning;
  :data:`VIDEO_CLASSES` are the six types of Fig. 24.3 plus a tracked armoured vehicle and a
  helicopter (8 classes, as the text says). :data:`VIDEO_TO_GMTI` maps each video class to its
  GMTI class; a wheeled vehicle covers six video classes, as the chapter says of its GMTI class
  in 24.6.3 (where it writes "tracked"; all ten targets are wheeled vehicles). Consequence, not
  measured side by side: every target's GMTI declaration is right with the wheeled-vehicle
  diagonal 0.7 of eq. 24.49, not the 0.8 of the tracked class the chapter names there.
- Off-diagonal terms of the GMTI confusion matrix: the error mass ``1 - C[i, i]`` is spread
  uniformly over the other classes, which is the chapter's simulation procedure (a uniform ``u``;
  if ``u > P`` a *wrong* type is declared) with the wrong type drawn uniformly. A report carries
  the declared class ``c`` and ``P{c} = C[c, c]`` (eq. 24.22); video and UGS reports likewise with
  ``P{c}`` the probability of the current footprint or aspect.
- 24.51 prints ``5 pi / 6 <= alpha <= pi / 6``, an empty interval: we read ``pi / 6 <= alpha <=
  5 pi / 6`` with ``alpha`` in ``[0, pi]`` the angle between the target's heading and the UGS
  line of sight (near-orthogonal views give 0.9, as the text says). A stopped target keeps the
  heading of its road segment.
- GMTI geometry: a flat Earth at altitude 0; the range is the slant range from the sensor; the
  cross-range error is ``r * 0.0008`` (about 60 m here); a report is the ground position
  ``(x, y)`` recovered from the noisy (range, azimuth) and the range-rate of eq. 24.18 (ground
  plane, as the chapter) plus noise; its covariance is the first-order transform of
  ``diag(20^2, (0.0008 r)^2)`` to ``(x, y)`` and ``1`` for the range-rate. The sensor does not
  move (the chapter's Fig. 24.4 shows a trajectory that the text does not give). All targets
  of a scan share the scan time. GMTI reports arrive without delay.
- The false-alarm range-rate is uniform on ``[-30, -MDV] U [MDV, 30]`` m/s and its declared type
  uniform over the GMTI classes; the surveillance area is the network's box (1.2e8 m^2, so 1.2
  false alarms per scan on average).
- UAV: the chapter places it at (-100 m, -100 m, 1200 m). We model its ground footprint as a
  square whose centre and side follow the schedule :data:`UAV_FOOTPRINTS` (the operator zooms
  and steers the camera; sides 800 m, 5000 m and 10.5 km, one per row of eq. 24.50).
- UGS: the chapter gives no position noise and no PD: we take sigma 10 m (like the video) and
  PD 1 within range. When several targets are in range the UGS reports the one it has reported
  least recently (ties: the nearest), then stays busy 4 s.
- Overtaking vehicles share the road's centre line (no lanes): their positions coincide at the
  overtaking instant.
- GMTI resolution (our addition, off by default: ``GMTIConfig(resolution=GMTI_RESOLUTION)``
  turns it on): the chapter blames its convoy ambiguity on "the close formation between targets
  with the GMTI sensor resolution" (24.6.3) but prints no resolution. Targets closer than one
  cell (:data:`GMTI_RESOLUTION`: 50 m in range, 0.002 rad in azimuth, 2.5 m/s in range-rate,
  2.5 times the chapter's accuracies) in all three coordinates, transitively, give one report
  at their mean true (range, azimuth, range-rate) plus the noise of one target (equal echo
  powers: the chapter gives no radar cross-sections), detected with PD once; see
  :mod:`hocnet.tracking.sensors`. Its declared type is drawn from the confusion row of the
  strongest echo, with equal powers the group's first member in target order (the lowest
  number), which is also its ``target_id`` (a stable label, so that a track following the
  unresolved group is scored as following that member and the other is untracked meanwhile);
  ``Report.unresolved`` lists all members. The type report is thus never a mixed one (all ten
  targets are "wheeled vehicle" in the GMTI frame anyway). Off by default because, measured on
  our trajectories (tests), no two convoy vehicles are ever within one cell at a GMTI scan: the
  convoy drives 10 s (120 m) apart on a highway nearly radial to the sensor (its segments are
  12 to 31 degrees off the line of sight), i.e. 102 to 120 m apart in range with equal
  range-rates, and
  at the overtakes (2 past 7 and 3, 1 past the convoy) the range-rates differ by 3.7 m/s or
  more. The only unresolved pair is the car 6 with the truck 7 at the J1 crossing, at one scan
  (t = 320 s). :func:`pd_targets` with a shorter ``convoy_headway`` (4 s: 48 m on the road, 47
  m in range) puts the convoy inside one range cell, the chapter's "close formation"; 5 s (59
  m) does not.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hocnet._check import check_choice, check_number, check_seed

__all__ = [
    "GMTI_CLASSES",
    "GMTI_CONFUSION",
    "GMTI_RESOLUTION",
    "PD_DURATION",
    "PD_INTERACTIONS",
    "PD_TARGETS",
    "SURVEILLANCE_AREA",
    "UAV_FOOTPRINTS",
    "UGS_POSITIONS",
    "VIDEO_CLASSES",
    "VIDEO_TO_GMTI",
    "GMTIConfig",
    "Interaction",
    "PDScenario",
    "Report",
    "TargetSpec",
    "TargetTruth",
    "UGSConfig",
    "VideoConfig",
    "footprint_at",
    "gmti_range_rate",
    "network_segments",
    "out_of_sequence",
    "pd_ground_truth",
    "pd_road_network",
    "pd_scenario",
    "pd_targets",
    "plot_scenario",
    "simulate_gmti",
    "simulate_ugs",
    "simulate_video",
]

# --------------------------------------------------------------------------------------------
# classes (eq. 24.21 and 24.25 are lost in the OCR: our reading, see the module docstring)
# --------------------------------------------------------------------------------------------

#: GMTI (STANAG 4607-like) classes of eq. 24.21, in the order of the confusion matrix 24.49.
GMTI_CLASSES: tuple[str, ...] = ("tracked vehicle", "wheeled vehicle", "rotary wing aircraft")

#: The 8 video / IMINT classes of eq. 24.25 (our reading from the target types of Fig. 24.3).
VIDEO_CLASSES: tuple[str, ...] = (
    "civilian car",
    "civilian bus",
    "civilian truck",
    "military armoured car",
    "military armoured truck",
    "armoured wheeled vehicle",
    "tracked armoured vehicle",
    "helicopter",
)

#: GMTI class index of each video class (the refinement of [PD] 24.5.3, ours).
VIDEO_TO_GMTI: tuple[int, ...] = (1, 1, 1, 1, 1, 1, 0, 2)

#: GMTI confusion matrix ``C[i, j] = P(declare j | true i)``: diagonal of eq. 24.49, the rest of
#: each row spread uniformly over the other classes (our choice).
GMTI_CONFUSION: np.ndarray = np.array(
    [[0.8, 0.1, 0.1], [0.15, 0.7, 0.15], [0.05, 0.05, 0.9]], dtype=np.float64
)

# --------------------------------------------------------------------------------------------
# road network
# --------------------------------------------------------------------------------------------

#: Named points of the synthetic network (m). J1-J3 are the highway junctions, N1-N3 those of the
#: northern byway.
_POINTS: dict[str, tuple[float, float]] = {
    "H0": (-6000.0, -5000.0),
    "Ha": (-4500.0, -3800.0),
    "J1": (-3000.0, -3000.0),
    "Hb": (-1500.0, -2000.0),
    "J2": (0.0, -1500.0),
    "Hc": (1500.0, -500.0),
    "J3": (3000.0, 0.0),
    "Hd": (4500.0, 1000.0),
    "H4": (6000.0, 2500.0),
    "S1": (-2500.0, -6000.0),
    "B1": (-3300.0, -200.0),
    "N1": (-3000.0, 2000.0),
    "S2": (500.0, -6000.0),
    "B2": (-300.0, 500.0),
    "N2": (0.0, 2000.0),
    "S3": (4000.0, -6000.0),
    "B3": (3300.0, 1000.0),
    "N3": (3000.0, 2000.0),
    "W": (-6000.0, 2500.0),
    "Nw": (-4500.0, 2300.0),
    "Nm": (-1500.0, 2600.0),
    "Ne": (1500.0, 1700.0),
    "E": (6000.0, 3000.0),
    "Nx": (4500.0, 2600.0),
    "T1": (-3000.0, 4000.0),
    "T2": (0.0, 4000.0),
}

#: Road sections (id, road class, point names): each runs between two junctions or road ends.
_SECTIONS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("H-1", "highway", ("H0", "Ha", "J1")),
    ("H-2", "highway", ("J1", "Hb", "J2")),
    ("H-3", "highway", ("J2", "Hc", "J3")),
    ("H-4", "highway", ("J3", "Hd", "H4")),
    ("B1-s", "byway", ("S1", "J1")),
    ("B1-n", "byway", ("J1", "B1", "N1")),
    ("B2-s", "byway", ("S2", "J2")),
    ("B2-n", "byway", ("J2", "B2", "N2")),
    ("B3-s", "byway", ("S3", "J3")),
    ("B3-n", "byway", ("J3", "B3", "N3")),
    ("N-1", "byway", ("W", "Nw", "N1")),
    ("N-2", "byway", ("N1", "Nm", "N2")),
    ("N-3", "byway", ("N2", "Ne", "N3")),
    ("N-4", "byway", ("N3", "Nx", "E")),
    ("T-1", "byway", ("N1", "T1")),
    ("T-2", "byway", ("N2", "T2")),
)

#: Surveillance area (x_min, x_max, y_min, y_max), m: the network's box.
SURVEILLANCE_AREA: tuple[float, float, float, float] = (-6000.0, 6000.0, -6000.0, 4000.0)


def pd_road_network() -> dict[str, Any]:
    """The synthetic road network of our [PD] 24.6 scenario as a GeoJSON-like dict.

    A ``FeatureCollection`` of ``LineString`` features, one per road section (a chain of segments
    between two junctions or road ends, [PD] 24.2.2), coordinates ``[x, y]`` in m in the local
    East-North frame (not WGS84). Properties: ``id`` (section id such as ``"H-2"``),
    ``road_class`` (``"highway"`` or ``"byway"``), ``nodes`` (the names of the section's points;
    sections meeting at a junction share its name and coordinates). One highway (west-south-west
    to east-north-east) with junctions J1, J2, J3, three north-south byways through them, a
    northern byway with junctions N1, N2, N3 and two dead ends: 16 sections, 27 segments, about
    12 x 10 km.

    Returns:
        A new dict (safe to modify).

    Examples:
        >>> net = pd_road_network()
        >>> net["type"], len(net["features"]), net["features"][0]["properties"]["id"]
        ('FeatureCollection', 16, 'H-1')
    """
    features = []
    for sid, road_class, names in _SECTIONS:
        features.append(
            {
                "type": "Feature",
                "geometry": {
                    "type": "LineString",
                    "coordinates": [list(_POINTS[n]) for n in names],
                },
                "properties": {"id": sid, "road_class": road_class, "nodes": list(names)},
            }
        )
    return {"type": "FeatureCollection", "features": features}


def network_segments(network: Mapping[str, Any] | None = None) -> tuple[np.ndarray, list[str]]:
    """Flatten a GeoJSON-like network into its straight segments.

    Segment ``k`` is the ``k``-th pair of consecutive coordinates, features in order.

    Args:
        network: a ``FeatureCollection`` of ``LineString`` features (default:
            :func:`pd_road_network`).

    Returns:
        ``(ends, section_ids)``: ``ends`` of shape ``(S, 2, 2)`` (segment, endpoint, xy) float64
        in m, and the section id of each segment.

    Raises:
        ValueError: not a FeatureCollection of LineStrings with at least two points each.

    Examples:
        >>> ends, sections = network_segments()
        >>> ends.shape, sections[:3]
        ((27, 2, 2), ['H-1', 'H-1', 'H-2'])
    """
    network = pd_road_network() if network is None else network
    if not isinstance(network, Mapping) or network.get("type") != "FeatureCollection":
        raise ValueError(
            f"`network`: expected a GeoJSON-like FeatureCollection dict, got {type(network)}"
        )
    ends: list[np.ndarray] = []
    sections: list[str] = []
    for i, feat in enumerate(network.get("features", [])):
        geom = feat.get("geometry", {})
        coords = np.asarray(geom.get("coordinates", []), dtype=np.float64)
        if geom.get("type") != "LineString" or coords.ndim != 2 or coords.shape[0] < 2:
            raise ValueError(
                f"`network`: expected LineString features with >= 2 points, got feature {i} "
                f"of type {geom.get('type')!r} and shape {coords.shape}"
            )
        sid = str(feat.get("properties", {}).get("id", i))
        for k in range(coords.shape[0] - 1):
            ends.append(coords[k : k + 2, :2])
            sections.append(sid)
    return (np.stack(ends) if ends else np.zeros((0, 2, 2))), sections


def _segment_index() -> dict[frozenset[str], int]:
    index: dict[frozenset[str], int] = {}
    k = 0
    for _, _, names in _SECTIONS:
        for a, b in itertools.pairwise(names):
            index[frozenset((a, b))] = k
            k += 1
    return index


# --------------------------------------------------------------------------------------------
# targets and ground truth
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TargetSpec:
    """One scripted target: a route on the network and a speed profile.

    Attributes:
        target_id: 1..10 as in [PD] Fig. 24.3.
        video_class: index into :data:`VIDEO_CLASSES` (the true type).
        route: point names of :func:`pd_road_network`; consecutive names must be the two ends of
            one segment.
        t_start: departure time (s); the target exists from then until it reaches the route's end.
        speed: knots ``(t, v)`` (s after ``t_start``, m/s), speed linear between knots and held
            after the last; ``v = 0`` spans are stops.
    """

    target_id: int
    video_class: int
    route: tuple[str, ...]
    t_start: float
    speed: tuple[tuple[float, float], ...]

    @property
    def gmti_class(self) -> int:
        """Index into :data:`GMTI_CLASSES`."""
        return VIDEO_TO_GMTI[self.video_class]


_HIGHWAY = ("H0", "Ha", "J1", "Hb", "J2", "Hc", "J3", "Hd", "H4")

#: The ten targets (our design of the chapter's scenario; types of Fig. 24.3).
PD_TARGETS: tuple[TargetSpec, ...] = (
    # civilian car, fast on the highway: passes 4, 2, 7 and 3
    TargetSpec(1, 0, _HIGHWAY, 250.0, ((0, 0.0), (11, 22.0))),
    # military armoured car: leaves third, overtakes 7 then 3, then leads the convoy
    TargetSpec(
        2,
        3,
        _HIGHWAY,
        20.0,
        ((0, 0.0), (10, 12.0), (150, 12.0), (155, 16.0), (270, 16.0), (275, 12.0)),
    ),
    # military armoured truck: leads the convoy out
    TargetSpec(3, 4, _HIGHWAY, 0.0, ((0, 0.0), (10, 12.0))),
    # armoured wheeled vehicle: last of the convoy, turns north at J3 and stops 60 s
    TargetSpec(
        4,
        5,
        (*_HIGHWAY[:7], "B3", "N3", "Nx", "E"),
        30.0,
        ((0, 0.0), (10, 12.0), (920, 12.0), (930, 0.0), (990, 0.0), (1000, 10.0)),
    ),
    # civilian bus: south to north through J2 (crosses the convoy), stops 30 s at a bus stop
    TargetSpec(
        5,
        1,
        ("S2", "J2", "B2", "N2", "T2"),
        136.0,
        ((0, 0.0), (10, 10.0), (536, 10.0), (540, 0.0), (570, 0.0), (580, 10.0)),
    ),
    # civilian car: south to north through J1 (crosses the convoy), west on the northern byway
    TargetSpec(6, 0, ("S1", "J1", "B1", "N1", "Nw", "W"), 91.0, ((0, 0.0), (8, 14.0))),
    # military armoured truck: second of the convoy
    TargetSpec(7, 4, _HIGHWAY, 10.0, ((0, 0.0), (10, 12.0))),
    # armoured wheeled vehicle: northern byway west to east, stops 120 s
    TargetSpec(
        8,
        5,
        ("W", "Nw", "N1", "Nm", "N2", "Ne", "N3", "Nx", "E"),
        0.0,
        ((0, 0.0), (10, 11.0), (400, 11.0), (405, 0.0), (525, 0.0), (535, 11.0)),
    ),
    # civilian car: north to south through J3 (crosses the convoy)
    TargetSpec(9, 0, ("N2", "Ne", "N3", "B3", "J3", "S3"), 529.0, ((0, 0.0), (8, 15.0))),
    # civilian truck: south to north through J3, waits 20 s before crossing (target 1 passes)
    TargetSpec(
        10,
        2,
        ("S3", "J3", "B3", "N3", "Nx", "E"),
        91.0,
        ((0, 0.0), (10, 10.0), (608.3, 10.0), (612.3, 0.0), (632.3, 0.0), (642.3, 10.0)),
    ),
)

#: Departure order of the convoy (3 leads out, then 7, 2 and 4), one ``convoy_headway`` apart.
_CONVOY_ORDER: tuple[int, ...] = (3, 7, 2, 4)


def pd_targets(convoy_headway: float = 10.0) -> tuple[TargetSpec, ...]:
    """The ten targets with the convoy 3, 7, 2, 4 leaving ``convoy_headway`` s apart.

    ``convoy_headway = 10`` (default) gives :data:`PD_TARGETS` (120 m apart at 12 m/s, about
    117 m in GMTI range). Shorter headways give the chapter's "close formation" (our variant;
    e.g. 4 s: 48 m on the road, 47 m in range, inside a 50 m range cell of
    :data:`GMTI_RESOLUTION`). Only the departure times of 7, 2 and 4 change (``k *
    convoy_headway`` for the ``k``-th vehicle); speed profiles are relative to the departure,
    so 2 still overtakes 7 and 3, but the other interactions' times and distances move away
    from :data:`PD_INTERACTIONS` (measured for the default).

    Raises:
        ValueError: negative or non-finite ``convoy_headway``.

    Examples:
        >>> [s.t_start for s in pd_targets(4.0) if s.target_id in (3, 7, 2, 4)]
        [8.0, 0.0, 12.0, 4.0]
    """
    h = check_number("convoy_headway", convoy_headway, low=0.0)
    rank = {tid: k for k, tid in enumerate(_CONVOY_ORDER)}
    return tuple(
        dataclasses.replace(s, t_start=rank[s.target_id] * h) if s.target_id in rank else s
        for s in PD_TARGETS
    )


@dataclass(frozen=True)
class TargetTruth:
    """Ground truth of one target sampled on a regular time grid.

    Attributes:
        target_id: the target's number.
        video_class: index into :data:`VIDEO_CLASSES`.
        gmti_class: index into :data:`GMTI_CLASSES`.
        times: ``(T,)`` float64 sample times (s), only those at which the target exists.
        positions: ``(T, 2)`` float64 ``(x, y)`` in m.
        velocities: ``(T, 2)`` float64 ``(vx, vy)`` in m/s.
        segment: ``(T,)`` int64 index of the network segment the target is on (see
            :func:`network_segments`).
        stopped: ``(T,)`` bool, the target's speed is 0.
        heading: ``(T, 2)`` float64 unit direction of travel of the current segment (defined
            also while stopped).
    """

    target_id: int
    video_class: int
    gmti_class: int
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    segment: np.ndarray
    stopped: np.ndarray
    heading: np.ndarray

    def state_at(self, t: float) -> np.ndarray:
        """State ``[x, vx, y, vy]`` ([PD] eq. 24.1) at time ``t`` by linear interpolation.

        Raises:
            ValueError: ``t`` outside the target's lifetime.
        """
        if not self.times.size or not self.times[0] - 1e-9 <= t <= self.times[-1] + 1e-9:
            raise ValueError(f"`t`: expected a time in the target's lifetime, got {t}")
        x = np.interp(t, self.times, self.positions[:, 0])
        y = np.interp(t, self.times, self.positions[:, 1])
        vx = np.interp(t, self.times, self.velocities[:, 0])
        vy = np.interp(t, self.times, self.velocities[:, 1])
        return np.array([x, vx, y, vy])


def _speed_integral(knots: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed ``v(tau)`` (linear between knots, held after) and distance ``s(tau) = int_0^tau v``."""
    kt, kv = knots[:, 0], knots[:, 1]
    area = np.concatenate([[0.0], np.cumsum(np.diff(kt) * (kv[1:] + kv[:-1]) / 2)])
    v = np.interp(tau, kt, kv)
    i = np.clip(np.searchsorted(kt, tau, side="right") - 1, 0, len(kt) - 1)
    s = area[i] + (tau - kt[i]) * (kv[i] + v) / 2
    return v, s


def _route_polyline(spec: TargetSpec) -> tuple[np.ndarray, np.ndarray]:
    index = _segment_index()
    seg = []
    for a, b in itertools.pairwise(spec.route):
        key = frozenset((a, b))
        if key not in index:
            raise ValueError(
                f"`route`: expected consecutive points joined by a road segment, got {a}-{b} "
                f"in target {spec.target_id}"
            )
        seg.append(index[key])
    pts = np.array([_POINTS[n] for n in spec.route], dtype=np.float64)
    return pts, np.array(seg, dtype=np.int64)


def _truth_of(spec: TargetSpec, duration: float, dt: float) -> TargetTruth:
    pts, seg_ids = _route_polyline(spec)
    d = np.diff(pts, axis=0)
    seg_len = np.linalg.norm(d, axis=1)
    unit = d / seg_len[:, None]
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    knots = np.asarray(spec.speed, dtype=np.float64)
    n = math.floor(duration / dt + 1e-9) + 1
    grid = np.arange(n) * dt
    tau = grid - spec.t_start
    keep = tau >= -1e-9
    v, s = _speed_integral(knots, np.maximum(tau, 0.0))
    keep &= s <= cum[-1] + 1e-9
    grid, v, s = grid[keep], v[keep], s[keep]
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg_len) - 1)
    pos = pts[k] + unit[k] * (s - cum[k])[:, None]
    return TargetTruth(
        target_id=spec.target_id,
        video_class=spec.video_class,
        gmti_class=spec.gmti_class,
        times=grid,
        positions=pos,
        velocities=unit[k] * v[:, None],
        segment=seg_ids[k],
        stopped=np.abs(v) < 1e-9,
        heading=unit[k],
    )


#: Length of the scenario (s).
PD_DURATION = 1200.0


def pd_ground_truth(
    duration: float = PD_DURATION,
    dt: float = 1.0,
    targets: Sequence[TargetSpec] = PD_TARGETS,
) -> dict[int, TargetTruth]:
    """Ground truth of the ten targets of our [PD] 24.6 scenario (deterministic).

    Args:
        duration: scenario length (s); samples at ``0, dt, ..., <= duration``.
        dt: sampling period (s), 1 s by default.
        targets: the scripted targets (default :data:`PD_TARGETS`).

    Returns:
        ``{target_id: TargetTruth}`` in the order of ``targets``.

    Raises:
        ValueError: non-positive ``duration`` or ``dt``, a route that leaves the network.

    Examples:
        >>> truth = pd_ground_truth()
        >>> sorted(truth), truth[3].positions[0].tolist(), bool(truth[4].stopped.any())
        ([1, 2, 3, 4, 5, 6, 7, 8, 9, 10], [-6000.0, -5000.0], True)
    """
    duration = check_number("duration", duration, low=0.0, low_inclusive=False)
    dt = check_number("dt", dt, low=0.0, low_inclusive=False)
    return {spec.target_id: _truth_of(spec, duration, dt) for spec in targets}


# --------------------------------------------------------------------------------------------
# interactions (measured from the ground truth above; tests check each)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Interaction:
    """A scripted interaction between two targets (or a stop, then ``other`` is ``None``).

    Attributes:
        kind: ``"overtake"`` (``target`` passes ``other`` on the same road), ``"crossing"``
            (both go through ``where`` at about the same time) or ``"stop"``.
        target: the overtaking / crossing / stopping target.
        other: the other target, ``None`` for a stop.
        time: time of closest approach (s); for a stop, its start.
        distance: closest distance on the 1 s grid (m); for a stop, its duration (s).
        where: junction name, or ``""``.
    """

    kind: str
    target: int
    other: int | None
    time: float
    distance: float
    where: str = ""


#: The interactions of our scenario, measured on its 1 s ground truth (time, closest distance).
PD_INTERACTIONS: tuple[Interaction, ...] = (
    Interaction("overtake", 2, 7, 203.0, 2.0),
    Interaction("overtake", 2, 3, 232.0, 2.0),
    Interaction("crossing", 6, 3, 310.0, 59.3, "J1"),
    Interaction("crossing", 6, 7, 314.0, 47.9, "J1"),
    Interaction("overtake", 1, 4, 520.0, 1.0),
    Interaction("overtake", 1, 7, 544.0, 1.0),
    Interaction("overtake", 1, 3, 556.0, 1.0),
    Interaction("overtake", 1, 2, 580.0, 1.0),
    Interaction("crossing", 5, 3, 590.0, 46.6, "J2"),
    Interaction("crossing", 5, 7, 597.0, 41.4, "J2"),
    Interaction("crossing", 10, 1, 728.0, 22.0, "J3"),
    Interaction("crossing", 9, 3, 874.0, 25.1, "J3"),
    Interaction("crossing", 9, 7, 878.0, 39.4, "J3"),
    Interaction("stop", 8, None, 405.0, 120.0),
    Interaction("stop", 5, None, 676.0, 30.0),
    Interaction("stop", 10, None, 704.0, 19.0),
    Interaction("stop", 4, None, 960.0, 60.0),
)

# --------------------------------------------------------------------------------------------
# sensors and reports
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Report:
    """One sensor report ([PD] eq. 24.22 and 24.26: kinematic part and class declaration).

    Attributes:
        time: measurement time (s).
        arrival: time the report reaches the tracker (s); ``arrival > time`` for delayed sensors,
            which makes the report out of sequence.
        sensor: ``"gmti"``, ``"video"`` or ``"ugs-1"`` ... ``"ugs-5"``.
        z: measurement, float64: ``(3,)`` ``[x, y, range_rate]`` (m, m, m/s) for the GMTI
            (eq. 24.17), ``(2,)`` ``[x, y]`` (m) for video and UGS (eq. 24.23).
        R: measurement covariance ``(3, 3)`` or ``(2, 2)``.
        sensor_position: ``(3,)`` sensor position ``(x, y, z)`` in m at ``time``.
        frame: class frame of the declaration, ``"gmti"`` (:data:`GMTI_CLASSES`) or ``"video"``
            (:data:`VIDEO_CLASSES`, also used by the UGS); any other value raises ``ValueError``
            at construction.
        declared: declared class index in that frame.
        p_declared: ``P{c}``, the probability that the declaration is right (eq. 24.22).
        target_id: the originating target, ``None`` for a false alarm (for evaluation only);
            for an unresolved GMTI report, the member whose type it carries.
        unresolved: the targets merged in this report by the GMTI resolution, sorted (``()``
            for a report of one target or a false alarm; for evaluation only).
    """

    time: float
    arrival: float
    sensor: str
    z: np.ndarray
    R: np.ndarray
    sensor_position: np.ndarray
    frame: str
    declared: int
    p_declared: float
    target_id: int | None
    unresolved: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        """Check ``frame``: any other value would be read as the video frame by :meth:`bba`.

        Raises:
            ValueError: ``frame`` is not ``"gmti"`` or ``"video"``.
        """
        check_choice("frame", self.frame, ("gmti", "video"))

    @property
    def kind(self) -> str:
        """``"gmti"``, ``"video"`` or ``"ugs"``."""
        return self.sensor.split("-")[0]

    def bba(self) -> Any:
        """Observed bba of the declaration on the report's frame (step b of [PD] 24.5.2).

        ``m({c}) = P{c}`` and ``m(Theta) = 1 - P{c}``, as a ``(2**n,)`` float64 torch tensor
        indexed by subset bitmask (:mod:`hocnet.tracking.belief`).

        Examples:
            >>> r = pd_scenario(seed=0).reports[0]
            >>> float(r.bba().sum())
            1.0
        """
        import torch

        n = len(GMTI_CLASSES if self.frame == "gmti" else VIDEO_CLASSES)
        m = torch.zeros(1 << n, dtype=torch.float64)
        m[1 << self.declared] = self.p_declared
        m[-1] += 1.0 - self.p_declared
        return m


@dataclass(frozen=True)
class GMTIConfig:
    """GMTI sensor of [PD] 24.6.1 (defaults are the chapter's values, except where noted).

    Attributes:
        position: sensor position (m).
        period: revisit time (s).
        first_scan: time of the first scan (s).
        sigma_range: slant-range standard deviation (m).
        sigma_azimuth: cross-range (azimuth) standard deviation (rad).
        sigma_range_rate: range-rate standard deviation (m/s).
        pd: detection probability.
        mdv: minimum detectable velocity (m/s): no detection if ``|range_rate| < mdv``.
        fa_density: false-alarm density (per m^2 per scan).
        fa_max_range_rate: largest false-alarm range-rate magnitude (m/s, ours).
        area: surveillance area ``(x_min, x_max, y_min, y_max)`` (m).
        confusion: ``(3, 3)`` confusion matrix on :data:`GMTI_CLASSES`.
        resolution: resolution cells ``(range m, azimuth rad, range-rate m/s)`` (our addition,
            module docstring), e.g. :data:`GMTI_RESOLUTION`; ``None`` (default): every target
            resolved.
    """

    position: tuple[float, float, float] = (-50_000.0, -60_000.0, 4000.0)
    period: float = 10.0
    first_scan: float = 0.0
    sigma_range: float = 20.0
    sigma_azimuth: float = 0.0008
    sigma_range_rate: float = 1.0
    pd: float = 0.9
    mdv: float = 1.0
    fa_density: float = 1e-8
    fa_max_range_rate: float = 30.0
    area: tuple[float, float, float, float] = SURVEILLANCE_AREA
    confusion: tuple[tuple[float, ...], ...] = tuple(map(tuple, GMTI_CONFUSION.tolist()))
    resolution: tuple[float, float, float] | None = None


#: GMTI resolution cells (range m, azimuth rad, range-rate m/s): 2.5 times the chapter's accuracies
#: 20 m, 0.0008 rad and 1 m/s (our choice,
#: :func:`hocnet.tracking.sensors.gmti_resolution_cells`; the chapter prints no resolution).
GMTI_RESOLUTION: tuple[float, float, float] = (50.0, 0.002, 2.5)

#: UAV footprints ``(t_start, t_end, centre_x, centre_y, width, height)`` in s and m (ours): the
#: camera looks at the junctions as the convoy reaches them and never at target 6.
UAV_FOOTPRINTS: tuple[tuple[float, float, float, float, float, float], ...] = (
    (0.0, 300.0, 5500.0, -1000.0, 14000.0, 7200.0),  # wide, 1.008e8 m^2: P 0.50
    (300.0, 500.0, -200.0, -1800.0, 5000.0, 5000.0),  # medium, 2.5e7 m^2: P 0.75
    (500.0, 650.0, 0.0, -1500.0, 800.0, 800.0),  # narrow on J2, 6.4e5 m^2: P 0.90
    (650.0, 800.0, 2500.0, -500.0, 5000.0, 5000.0),  # medium around J3
    (800.0, 950.0, 3000.0, 0.0, 800.0, 800.0),  # narrow on J3
    (950.0, 1e9, 3500.0, 1500.0, 5000.0, 5000.0),  # medium, north of J3
)


@dataclass(frozen=True)
class VideoConfig:
    """UAV video (EO/IR) sensor of [PD] 24.6.1.

    Attributes:
        position: UAV position (m), as printed in the chapter (used only as the report's sensor
            position: the footprint schedule decides what is seen).
        period: report period (s).
        first_scan: time of the first frame (s; ours, 5 s so that GMTI and video alternate).
        sigma: position standard deviation in x and y (m).
        pd: detection probability in the footprint.
        delay: constant delay of the reports (s).
        footprints: footprint schedule (see :data:`UAV_FOOTPRINTS`).
        area_thresholds: footprint areas (m^2) of eq. 24.50.
        type_probabilities: ``P{c}`` below, between and above the thresholds (eq. 24.50).
    """

    position: tuple[float, float, float] = (-100.0, -100.0, 1200.0)
    period: float = 10.0
    first_scan: float = 5.0
    sigma: float = 10.0
    pd: float = 0.9
    delay: float = 11.0
    footprints: tuple[tuple[float, float, float, float, float, float], ...] = UAV_FOOTPRINTS
    area_thresholds: tuple[float, float] = (1e6, 1e8)
    type_probabilities: tuple[float, float, float] = (0.90, 0.75, 0.50)


#: Positions of the 5 UGS (m, ours): near J2, the bus stop, J3, the highway east of J3 and
#: where target 1 passes target 4; none within 1 km of target 6's route.
UGS_POSITIONS: tuple[tuple[float, float], ...] = (
    (300.0, -1200.0),
    (-400.0, 300.0),
    (3300.0, -300.0),
    (4800.0, 1500.0),
    (-1000.0, -2200.0),
)


@dataclass(frozen=True)
class UGSConfig:
    """Unattended ground sensors of [PD] 24.6.1.

    Attributes:
        positions: ground positions of the sensors (m).
        max_range: minimal range of detection (MRD): a target is seen within this range (m).
        period: report period (s).
        dead_time: after a detection the UGS reports no target for this long (s).
        delay: constant delay (s).
        sigma: position standard deviation (m; ours, the chapter gives none).
        pd: detection probability within range (ours, the chapter gives none).
        aspect_probabilities: ``P{c}`` for near-orthogonal and other aspects (eq. 24.51).
    """

    positions: tuple[tuple[float, float], ...] = UGS_POSITIONS
    max_range: float = 1000.0
    period: float = 1.0
    dead_time: float = 4.0
    delay: float = 11.0
    sigma: float = 10.0
    pd: float = 1.0
    aspect_probabilities: tuple[float, float] = (0.9, 0.5)


def _rng(seed: int | None) -> np.random.Generator:
    return np.random.default_rng(check_seed("seed", seed))


def _grid_times(start: float, period: float, duration: float) -> np.ndarray:
    n = math.floor((duration - start) / period + 1e-9) + 1
    return start + period * np.arange(max(n, 0))


def _states_at(truth: Mapping[int, TargetTruth], t: float) -> list[tuple[int, TargetTruth, int]]:
    out = []
    for tid, tr in truth.items():
        if tr.times.size and tr.times[0] - 1e-9 <= t <= tr.times[-1] + 1e-9:
            i = int(np.argmin(np.abs(tr.times - t)))
            if abs(tr.times[i] - t) < 1e-6:
                out.append((tid, tr, i))
    return out


def _wrong_class(rng: np.random.Generator, true: int, n: int) -> int:
    c = int(rng.integers(n - 1))
    return c + (c >= true)


def _gmti_cov(cfg: GMTIConfig, xy: np.ndarray) -> np.ndarray:
    xc, yc, h = cfg.position
    dx, dy = xy[0] - xc, xy[1] - yc
    g = math.hypot(dx, dy)
    r = math.sqrt(g * g + h * h)
    c, s = dx / g, dy / g
    J = np.array([[r / g * c, -g * s], [r / g * s, g * c]])
    R = np.zeros((3, 3))
    R[:2, :2] = J @ np.diag([cfg.sigma_range**2, cfg.sigma_azimuth**2]) @ J.T
    R[2, 2] = cfg.sigma_range_rate**2
    return R


def gmti_range_rate(sensor_xy: Sequence[float], position: Any, velocity: Any) -> np.ndarray:
    """Range-rate of eq. 24.18 (ground plane): ``(p - p_c) . v / |p - p_c|``.

    Args:
        sensor_xy: sensor ground position ``(x_c, y_c)`` (m).
        position: ``(..., 2)`` target positions (m).
        velocity: ``(..., 2)`` target velocities (m/s).

    Returns:
        ``(...)`` float64 range-rates (m/s).

    Examples:
        >>> float(gmti_range_rate((0.0, 0.0), [3.0, 4.0], [3.0, 4.0]))
        5.0
    """
    p = np.asarray(position, dtype=np.float64) - np.asarray(sensor_xy, dtype=np.float64)[:2]
    v = np.asarray(velocity, dtype=np.float64)
    return (p * v).sum(-1) / np.linalg.norm(p, axis=-1)


def _resolution_groups(
    cfg: GMTIConfig, polar: Sequence[np.ndarray]
) -> tuple[list[int], np.ndarray, list[int]]:
    """Group of each target of one scan, centroid and dominant member of each group."""
    n = len(polar)
    if cfg.resolution is None or n < 2:
        return list(range(n)), np.asarray(polar, dtype=np.float64).reshape(n, 3), list(range(n))
    import torch

    from hocnet.tracking.sensors import gmti_merge_unresolved

    merged, groups, dominant = gmti_merge_unresolved(
        torch.as_tensor(np.stack(polar), dtype=torch.float64), cfg.resolution
    )
    return groups.tolist(), merged.numpy(), dominant.tolist()


def simulate_gmti(
    truth: Mapping[int, TargetTruth],
    config: GMTIConfig | None = None,
    *,
    duration: float = PD_DURATION,
    seed: int | None = None,
) -> list[Report]:
    """GMTI reports of [PD] 24.6.1: detections with PD and MDV, Poisson clutter, class reports.

    Each scan ``t_k`` (every ``period`` s) sees every target present at ``t_k`` whose
    range-rate (eq. 24.18) is at least ``mdv`` in magnitude with probability ``pd``; it measures
    slant range and azimuth with Gaussian errors, converts them to the ground ``(x, y)`` and adds
    a noisy range-rate. With ``config.resolution`` (our addition, module docstring), targets
    outside the notch that are unresolved give one report per group, at the group's mean true
    (range, azimuth, range-rate), detected and measured with the draws of its first member in
    the scan (the others' draws are made and discarded, so that the clutter and every later
    scan are those of the run without resolution: paired runs).
    The number of false alarms per scan is Poisson with mean
    ``fa_density * area``, uniform over the area. Declared classes follow the confusion matrix
    rows (false alarms: uniform). Reports arrive at once (``arrival == time``); within a scan
    their order is random.

    Args:
        truth: ground truth from :func:`pd_ground_truth` (sampled at the scan times).
        config: sensor parameters (default :class:`GMTIConfig`).
        duration: last scan time bound (s).
        seed: seed of the random draws (``None``: fresh entropy).

    Returns:
        Reports sorted by time.

    Examples:
        >>> reports = simulate_gmti(pd_ground_truth(), seed=0)
        >>> reports[0].sensor, reports[0].z.shape, reports[0].R.shape
        ('gmti', (3,), (3, 3))
    """
    cfg = GMTIConfig() if config is None else config
    check_number("config.pd", cfg.pd, low=0.0, high=1.0)
    check_number("config.fa_density", cfg.fa_density, low=0.0)
    check_number("config.period", cfg.period, low=0.0, low_inclusive=False)
    rng = _rng(seed)
    C = np.asarray(cfg.confusion, dtype=np.float64)
    xc, yc, h = cfg.position
    x0, x1, y0, y1 = cfg.area
    area = (x1 - x0) * (y1 - y0)
    sensor_pos = np.array(cfg.position, dtype=np.float64)
    reports: list[Report] = []
    for t in _grid_times(cfg.first_scan, cfg.period, duration):
        scan: list[Report | None] = []
        # true (range, azimuth, range-rate) of the targets outside the clutter notch
        seen: list[tuple[int, TargetTruth, np.ndarray]] = []
        for tid, tr, i in _states_at(truth, t):
            p, v = tr.positions[i], tr.velocities[i]
            rr = float(gmti_range_rate((xc, yc), p, v))
            if abs(rr) < cfg.mdv:
                continue
            dx, dy = p[0] - xc, p[1] - yc
            seen.append(
                (tid, tr, np.array([math.sqrt(dx * dx + dy * dy + h * h), math.atan2(dy, dx), rr]))
            )
        groups, centroid, dominant = _resolution_groups(cfg, [s[2] for s in seen])
        for k, (tid, tr, polar) in enumerate(seen):
            # every target consumes the draws it would without resolution (detection, noise,
            # class), so that a merge leaves the rest of the run's draws unchanged (paired runs)
            if rng.random() >= cfg.pd:
                continue
            noise = rng.standard_normal(3) * (
                cfg.sigma_range,
                cfg.sigma_azimuth,
                cfg.sigma_range_rate,
            )
            members = [m for m in range(len(seen)) if groups[m] == groups[k]]
            ids: tuple[int, ...] = ()
            if len(members) > 1:
                if members[0] != k:
                    # merged into its group's report, drawn at its first member
                    rng.choice(C.shape[0], p=C[tr.gmti_class] / C[tr.gmti_class].sum())
                    scan.append(None)  # keeps the scan's shuffle the same
                    continue
                polar = centroid[groups[k]]
                ids = tuple(sorted(seen[m][0] for m in members))
                tid, tr = seen[dominant[groups[k]]][:2]  # equal powers: the first member
            r = polar[0] + noise[0]
            az = polar[1] + noise[1]
            g = math.sqrt(max(r * r - h * h, 0.0))
            xy = np.array([xc + g * math.cos(az), yc + g * math.sin(az)])
            z = np.array([xy[0], xy[1], polar[2] + noise[2]])
            c = int(rng.choice(C.shape[0], p=C[tr.gmti_class] / C[tr.gmti_class].sum()))
            scan.append(
                Report(
                    float(t),
                    float(t),
                    "gmti",
                    z,
                    _gmti_cov(cfg, xy),
                    sensor_pos,
                    "gmti",
                    c,
                    float(C[c, c]),
                    tid,
                    ids,
                )
            )
        for _ in range(int(rng.poisson(cfg.fa_density * area))):
            xy = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])
            mag = rng.uniform(cfg.mdv, cfg.fa_max_range_rate)
            rr = mag if rng.random() < 0.5 else -mag
            c = int(rng.integers(C.shape[0]))
            scan.append(
                Report(
                    float(t),
                    float(t),
                    "gmti",
                    np.array([xy[0], xy[1], rr]),
                    _gmti_cov(cfg, xy),
                    sensor_pos,
                    "gmti",
                    c,
                    float(C[c, c]),
                    None,
                )
            )
        shuffled = (scan[k] for k in rng.permutation(len(scan)))
        reports.extend(r for r in shuffled if r is not None)
    return reports


def footprint_at(
    t: float, footprints: Sequence[tuple[float, float, float, float, float, float]]
) -> tuple[float, float, float, float] | None:
    """UAV footprint ``(centre_x, centre_y, width, height)`` at time ``t``, or ``None``.

    Examples:
        >>> footprint_at(600.0, UAV_FOOTPRINTS)
        (0.0, -1500.0, 800.0, 800.0)
    """
    for t0, t1, cx, cy, w, hgt in footprints:
        if t0 <= t < t1:
            return (cx, cy, w, hgt)
    return None


def simulate_video(
    truth: Mapping[int, TargetTruth],
    config: VideoConfig | None = None,
    *,
    duration: float = PD_DURATION,
    seed: int | None = None,
) -> list[Report]:
    """UAV video reports of [PD] 24.6.1: targets in the footprint, PD, delay, eq. 24.50 types.

    Every ``period`` s, each target inside the current footprint (:data:`UAV_FOOTPRINTS`) is
    reported with probability ``pd`` at its position plus ``N(0, sigma^2 I)``; the operator's
    declared type is right with probability ``P{c}`` of eq. 24.50 (footprint area), otherwise
    uniform over the other 7 classes; no false alarm. ``arrival = time + delay``.

    Args:
        truth: ground truth from :func:`pd_ground_truth`.
        config: sensor parameters (default :class:`VideoConfig`).
        duration: last frame time bound (s).
        seed: seed of the random draws.

    Returns:
        Reports sorted by measurement time.

    Examples:
        >>> reports = simulate_video(pd_ground_truth(), seed=0)
        >>> reports[0].arrival - reports[0].time, reports[0].frame
        (11.0, 'video')
    """
    cfg = VideoConfig() if config is None else config
    check_number("config.pd", cfg.pd, low=0.0, high=1.0)
    check_number("config.period", cfg.period, low=0.0, low_inclusive=False)
    rng = _rng(seed)
    pos = np.array(cfg.position, dtype=np.float64)
    R = np.eye(2) * cfg.sigma**2
    n_cls = len(VIDEO_CLASSES)
    reports: list[Report] = []
    for t in _grid_times(cfg.first_scan, cfg.period, duration):
        fp = footprint_at(float(t), cfg.footprints)
        if fp is None:
            continue
        cx, cy, w, hgt = fp
        area = w * hgt
        lo, hi = cfg.area_thresholds
        p_c = cfg.type_probabilities[0 if area <= lo else 1 if area <= hi else 2]
        for tid, tr, i in _states_at(truth, t):
            p = tr.positions[i]
            if abs(p[0] - cx) > w / 2 or abs(p[1] - cy) > hgt / 2 or rng.random() >= cfg.pd:
                continue
            z = p + cfg.sigma * rng.standard_normal(2)
            c = tr.video_class if rng.random() < p_c else _wrong_class(rng, tr.video_class, n_cls)
            reports.append(
                Report(float(t), float(t) + cfg.delay, "video", z, R, pos, "video", c, p_c, tid)
            )
    return reports


def ugs_aspect(heading: Any, sensor_xy: Any, position: Any) -> float:
    """Aspect ``alpha`` in ``[0, pi]``: angle between the heading and the UGS line of sight.

    Examples:
        >>> round(ugs_aspect([1.0, 0.0], [0.0, 0.0], [0.0, 100.0]), 4)  # broadside
        1.5708
    """
    los = np.asarray(position, dtype=np.float64) - np.asarray(sensor_xy, dtype=np.float64)
    h = np.asarray(heading, dtype=np.float64)
    c = float(los @ h / (np.linalg.norm(los) * np.linalg.norm(h) + 1e-300))
    return math.acos(min(1.0, max(-1.0, c)))


def simulate_ugs(
    truth: Mapping[int, TargetTruth],
    config: UGSConfig | None = None,
    *,
    duration: float = PD_DURATION,
    seed: int | None = None,
) -> list[Report]:
    """UGS reports of [PD] 24.6.1: one target per 4 s within 1000 m, delay 11 s, eq. 24.51 types.

    Every ``period`` s each idle UGS picks, among the targets within ``max_range``, the one it has
    reported least recently (ties: the nearest), reports it with probability ``pd`` at its position
    plus ``N(0, sigma^2 I)`` and stays busy ``dead_time`` s. The declared type is right with
    probability 0.9 if ``pi/6 <= alpha <= 5 pi/6`` (our reading of the printed, empty interval of
    eq. 24.51), else 0.5; wrong types are uniform over the other classes; no false alarm.

    Args:
        truth: ground truth from :func:`pd_ground_truth`.
        config: sensor parameters (default :class:`UGSConfig`).
        duration: last time bound (s).
        seed: seed of the random draws.

    Returns:
        Reports sorted by measurement time (sensors ``"ugs-1"`` ... in order within a time).

    Examples:
        >>> reports = simulate_ugs(pd_ground_truth(), seed=0)
        >>> reports[0].sensor.startswith("ugs-"), reports[0].arrival - reports[0].time
        (True, 11.0)
    """
    cfg = UGSConfig() if config is None else config
    check_number("config.pd", cfg.pd, low=0.0, high=1.0)
    check_number("config.period", cfg.period, low=0.0, low_inclusive=False)
    rng = _rng(seed)
    sensors = np.asarray(cfg.positions, dtype=np.float64).reshape(-1, 2)
    busy = np.full(len(sensors), -np.inf)
    last: list[dict[int, float]] = [{} for _ in sensors]
    R = np.eye(2) * cfg.sigma**2
    n_cls = len(VIDEO_CLASSES)
    reports: list[Report] = []
    for t in _grid_times(0.0, cfg.period, duration):
        present = _states_at(truth, t)
        for s, xy in enumerate(sensors):
            if t < busy[s] - 1e-9:
                continue
            cands = []
            for tid, tr, i in present:
                d = float(np.linalg.norm(tr.positions[i] - xy))
                if d <= cfg.max_range:
                    cands.append((last[s].get(tid, -np.inf), d, tid, tr, i))
            if not cands:
                continue
            _, _, tid, tr, i = min(cands, key=lambda c: (c[0], c[1]))
            if rng.random() >= cfg.pd:
                continue
            alpha = ugs_aspect(tr.heading[i], xy, tr.positions[i])
            good = math.pi / 6 <= alpha <= 5 * math.pi / 6
            p_c = cfg.aspect_probabilities[0 if good else 1]
            c = tr.video_class if rng.random() < p_c else _wrong_class(rng, tr.video_class, n_cls)
            z = tr.positions[i] + cfg.sigma * rng.standard_normal(2)
            sensor_pos = np.array([xy[0], xy[1], 0.0])
            reports.append(
                Report(
                    float(t),
                    float(t) + cfg.delay,
                    f"ugs-{s + 1}",
                    z,
                    R,
                    sensor_pos,
                    "video",
                    c,
                    p_c,
                    tid,
                )
            )
            busy[s] = t + cfg.dead_time
            last[s][tid] = float(t)
    return reports


def out_of_sequence(reports: Sequence[Report]) -> np.ndarray:
    """Flag the reports that arrive after a report with a later measurement time.

    Args:
        reports: reports in arrival order.

    Returns:
        ``(N,)`` bool: ``time`` smaller than the largest ``time`` of the reports before it.

    Examples:
        >>> out_of_sequence(pd_scenario(seed=0).reports).any()
        np.True_
    """
    times = np.array([r.time for r in reports], dtype=np.float64)
    if not times.size:
        return np.zeros(0, dtype=bool)
    latest = np.maximum.accumulate(np.concatenate([[-np.inf], times[:-1]]))
    return times < latest - 1e-9


@dataclass(frozen=True)
class PDScenario:
    """One run of our [PD] 24.6 scenario.

    Attributes:
        network: the GeoJSON-like road network (:func:`pd_road_network`).
        truth: ``{target_id: TargetTruth}``.
        reports: all reports in arrival order (ties: measurement time, then GMTI, video, UGS).
        interactions: the scripted interactions (:data:`PD_INTERACTIONS`).
        gmti, video, ugs: the sensor parameters used.
        seed: the seed of the run.
    """

    network: dict[str, Any]
    truth: dict[int, TargetTruth]
    reports: list[Report]
    interactions: tuple[Interaction, ...] = PD_INTERACTIONS
    gmti: GMTIConfig = field(default_factory=GMTIConfig)
    video: VideoConfig = field(default_factory=VideoConfig)
    ugs: UGSConfig = field(default_factory=UGSConfig)
    seed: int | None = None


_KIND_ORDER = {"gmti": 0, "video": 1, "ugs": 2}


def pd_scenario(
    seed: int | None = 0,
    *,
    duration: float = PD_DURATION,
    gmti: GMTIConfig | None = None,
    video: VideoConfig | None = None,
    ugs: UGSConfig | None = None,
    targets: Sequence[TargetSpec] = PD_TARGETS,
) -> PDScenario:
    """Ground truth and all sensor reports of one run of our [PD] 24.6 scenario.

    The three sensors draw from independent streams derived from ``seed``
    (``numpy.random.SeedSequence(seed).spawn(3)``); the ground truth is deterministic.

    Args:
        seed: seed of the run (``None``: fresh entropy). Same seed, same reports.
        duration: scenario length (s).
        gmti: GMTI parameters (default :class:`GMTIConfig`, the chapter's).
        video: UAV video parameters (default :class:`VideoConfig`).
        ugs: UGS parameters (default :class:`UGSConfig`).
        targets: the scripted targets (default :data:`PD_TARGETS`; :func:`pd_targets` for a
            closer convoy).

    Returns:
        A :class:`PDScenario` whose ``reports`` are in arrival order.

    Examples:
        >>> sc = pd_scenario(seed=1)
        >>> len(sc.truth), sorted({r.kind for r in sc.reports})
        (10, ['gmti', 'ugs', 'video'])
    """
    seed = check_seed("seed", seed)
    gmti = GMTIConfig() if gmti is None else gmti
    video = VideoConfig() if video is None else video
    ugs = UGSConfig() if ugs is None else ugs
    truth = pd_ground_truth(duration, targets=targets)
    subs = [int(s.generate_state(1, np.uint64)[0]) for s in np.random.SeedSequence(seed).spawn(3)]
    reports = (
        simulate_gmti(truth, gmti, duration=duration, seed=subs[0])
        + simulate_video(truth, video, duration=duration, seed=subs[1])
        + simulate_ugs(truth, ugs, duration=duration, seed=subs[2])
    )
    order = sorted(
        range(len(reports)),
        key=lambda k: (reports[k].arrival, reports[k].time, _KIND_ORDER[reports[k].kind], k),
    )
    return PDScenario(
        network=pd_road_network(),
        truth=truth,
        reports=[reports[k] for k in order],
        gmti=gmti,
        video=video,
        ugs=ugs,
        seed=seed,
    )


# --------------------------------------------------------------------------------------------
# picture
# --------------------------------------------------------------------------------------------


def plot_scenario(
    network: Mapping[str, Any] | None = None,
    truth: Mapping[int, TargetTruth] | None = None,
    *,
    tracks: Mapping[Any, Any] | None = None,
    reports: Sequence[Report] | None = None,
    ugs: UGSConfig | None = None,
    footprints: Sequence[tuple[float, float, float, float, float, float]] | None = None,
    ax: Any = None,
    path: Any = None,
) -> Any:
    """Draw the road network, the ground truth and optionally sensors, reports and tracks.

    Roads grey (the highway thicker), each target's trajectory in its colour with its number and
    type at the start and squares where it stops, UGS ranges as circles, UAV footprints as dashed
    rectangles, GMTI reports as small dots (false alarms grey), tracks as dashed black lines.
    Builds a :class:`matplotlib.figure.Figure` without ``pyplot`` (see :mod:`hocnet.plot`).

    Args:
        network: GeoJSON-like network (default :func:`pd_road_network`).
        truth: ``{target_id: TargetTruth}`` or ``None``.
        tracks: ``{track_id: obj}`` where ``obj`` has ``positions`` ``(N, 2)`` (e.g.
            :class:`hocnet.tracking.evaluation.EstimatedTrack`) or is an ``(N, 2)`` array.
        reports: reports to draw (only GMTI reports are drawn, as dots).
        ugs: UGS parameters whose positions and range are drawn.
        footprints: UAV footprint schedule to draw.
        ax: matplotlib axes to draw into (default: a new figure).
        path: save the figure there when set (format from the extension).

    Returns:
        The figure.

    Examples:
        >>> fig = plot_scenario(truth=pd_ground_truth())
        >>> len(fig.axes)
        1
    """
    import matplotlib as mpl
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Rectangle

    network = pd_road_network() if network is None else network
    if ax is None:
        fig = Figure(figsize=(9.0, 7.5), layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
    fig = ax.figure
    for feat in network["features"]:
        xy = np.asarray(feat["geometry"]["coordinates"], dtype=np.float64)
        hw = feat.get("properties", {}).get("road_class") == "highway"
        ax.plot(xy[:, 0], xy[:, 1], color="0.55" if hw else "0.75", lw=4 if hw else 1.8, zorder=1)
    if reports:
        g = [r for r in reports if r.kind == "gmti"]
        if g:
            z = np.array([r.z[:2] for r in g])
            fa = np.array([r.target_id is None for r in g])
            ax.scatter(z[~fa, 0], z[~fa, 1], s=2, color="tab:blue", alpha=0.25, zorder=2)
            ax.scatter(z[fa, 0], z[fa, 1], s=4, color="0.4", marker="x", zorder=2)
    if ugs is not None:
        for k, (x, y) in enumerate(ugs.positions):
            ax.add_patch(
                Circle((x, y), ugs.max_range, fill=False, ls=":", color="tab:green", zorder=2)
            )
            ax.plot(x, y, marker="^", color="tab:green", zorder=3)
            ax.annotate(f"UGS {k + 1}", (x, y), fontsize=7, color="tab:green")
    for t0, t1, cx, cy, w, h in footprints or ():
        ax.add_patch(
            Rectangle(
                (cx - w / 2, cy - h / 2), w, h, fill=False, ls="--", lw=0.8, color="tab:purple"
            )
        )
        ax.annotate(
            f"{t0:g}-{min(t1, PD_DURATION):g} s",
            (cx - w / 2, cy + h / 2),
            fontsize=6,
            color="tab:purple",
        )
    colours = list(mpl.colormaps["tab10"].colors)
    labelled: dict[tuple[float, float], int] = {}  # labels stacked at a shared start
    for n, (tid, tr) in enumerate((truth or {}).items()):
        c = colours[n % len(colours)]
        ax.plot(tr.positions[:, 0], tr.positions[:, 1], color=c, lw=1.4, zorder=4)
        if tr.times.size:
            x, y = tr.positions[0]
            ax.plot(x, y, "o", color=c, ms=4, zorder=5)
            key = (round(float(x)), round(float(y)))
            labelled[key] = labelled.get(key, -1) + 1
            ax.annotate(
                f"{tid}: {VIDEO_CLASSES[tr.video_class]}",
                (x, y),
                xytext=(4, 4 + 8 * labelled[key]),
                textcoords="offset points",
                fontsize=7,
                color=c,
            )
            st = tr.stopped.copy()
            st[0] = False
            if st.any():
                p = tr.positions[st]
                ax.plot(p[:, 0], p[:, 1], "s", color=c, ms=6, mfc="none", zorder=5)
    for tid, trk in (tracks or {}).items():
        p = np.asarray(getattr(trk, "positions", trk), dtype=np.float64).reshape(-1, 2)
        ax.plot(p[:, 0], p[:, 1], "--", color="k", lw=0.8, zorder=6)
        if p.size:
            ax.annotate(str(tid), p[-1], fontsize=6)
    x0, x1, y0, y1 = SURVEILLANCE_AREA
    ax.set_xlim(x0 - 300, x1 + 300)
    ax.set_ylim(y0 - 300, y1 + 300)
    ax.set_aspect("equal")
    ax.set_xlabel("East (m)")
    ax.set_ylabel("North (m)")
    if path is not None:
        fig.savefig(path)
    return fig

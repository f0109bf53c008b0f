"""Scene-to-scene spread of the identification column of [LA98] Tables II and III.

Shared by ``hoc_table2.py`` and ``hoc_table3.py``. The paper prints one value per density:
Table II from one scene per density, Table III the average of six scenes (section IV-C). Our
columns are means over 20 seeded scenes; these helpers put the paper's value into our
per-scene distribution (and, for Table III, into the distribution of six-scene means).
"""

from __future__ import annotations

import itertools
import random
import statistics
from collections.abc import Callable, Sequence

import _expkit as C

SUBSETS = 2000
"""Random six-scene subsets drawn for the distribution of six-scene means (Table III)."""

SUBSET_SEED = 0

RARE = 0.05
"""Share of six-scene means below which the paper's value counts as out of their reach."""
"""Seed of the ``random.Random`` that draws the subsets (fixed: the file is reproducible)."""


def _at_or_above(value: float, printed: float) -> bool:
    """Our value (percent) at or above the printed one, compared at its two decimals."""
    return round(value, 2) >= printed


def _where(printed: float, low: float, high: float) -> str:
    if round(high, 2) < printed:
        return "above our best"
    if round(low, 2) > printed:
        return "below our worst"
    return "inside"


def spread_table(
    select: Callable[[float, str], list[dict]],
    densities: Sequence[float],
    configs: Sequence[str],
    paper_id: dict[float, float],
    paper_kept: dict[float, float],
    *,
    group: int = 1,
) -> tuple[str, list[str]]:
    """Markdown table of our per-scene identification results beside the paper's value.

    Args:
        select: ``select(density, config)`` gives the per-scene result rows (each with
            ``id_rejection``, a fraction, and ``id_clutter_remaining``).
        densities: the table's densities.
        configs: configuration names (rows per density).
        paper_id: printed clutter rejection after identification (%) per density.
        paper_kept: clutter points the paper kept after identification (its printed
            "points remained" minus the target points) per density.
        group: scenes behind each printed value (1 for Table II; 6 for Table III, whose
            values are six-scene averages): for ``group > 1`` the table adds the 5th-95th
            percentile of the mean of ``group`` of our scenes (:data:`SUBSETS` random subsets)
            and the share of those means at or above the printed value.

    Returns:
        ``(table, findings)``: the markdown table and one sentence per configuration saying
        where the printed values lie in our spread.
    """
    headers = [
        "density",
        "configuration (k = 2)",
        "paper: clutter kept",
        "ours: clutter kept per scene (min / median / max)",
        "paper (%)",
        "ours per scene (%): min / median / max",
        "scenes at or above the paper",
        "paper's value in our per-scene range",
    ]
    if group > 1:
        headers += [
            f"ours, mean of {group} scenes: 5th-95th percentile (%)",
            f"{group}-scene means at or above the paper",
        ]
    rng = random.Random(SUBSET_SEED)
    body = []
    places: dict[str, list[tuple[float, str, int, int]]] = {c: [] for c in configs}
    shares: dict[str, list[str]] = {c: [] for c in configs}
    rare: dict[str, list[str]] = {c: [] for c in configs}
    usual: dict[str, list[str]] = {c: [] for c in configs}
    for d in densities:
        for config in configs:
            sel = select(d, config)
            rej = [100 * float(r["id_rejection"]) for r in sel]
            kept = [int(r["id_clutter_remaining"]) for r in sel]
            printed = paper_id[d]
            above = sum(_at_or_above(x, printed) for x in rej)
            where = _where(printed, min(rej), max(rej))
            places[config].append((d, where, above, len(rej)))
            row = [
                C.pct(d, 1),
                config,
                f"{paper_kept[d]:g}",
                f"{min(kept)} / {statistics.median(kept):g} / {max(kept)}",
                f"{printed:.2f}",
                f"{min(rej):.2f} / {statistics.median(rej):.2f} / {max(rej):.2f}",
                f"{above}/{len(rej)}",
                where,
            ]
            if group > 1 and len(rej) < group:
                row += [f"n/a (fewer than {group} scenes)", "n/a"]
            elif group > 1:
                means = sorted(statistics.fmean(rng.sample(rej, group)) for _ in range(SUBSETS))
                lo, hi = means[int(0.05 * SUBSETS)], means[int(0.95 * SUBSETS) - 1]
                share = sum(_at_or_above(m, printed) for m in means) / SUBSETS
                row += [f"{lo:.2f} - {hi:.2f}", f"{100 * share:.1f} %"]
                shares[config].append(f"{C.pct(d, 1)}: {100 * share:.1f} %")
                (rare if share < RARE else usual)[config].append(C.pct(d, 1))
            body.append(row)
    findings = []
    for config, rows in places.items():
        inside = [C.pct(d, 1) for d, w, _, _ in rows if w == "inside"]
        out = [f"{C.pct(d, 1)} ({w})" for d, w, _, _ in rows if w != "inside"]
        share = ", ".join(f"{C.pct(d, 1)}: {a}/{n}" for d, _, a, n in rows)
        text = f"`{config}`: the paper's value lies inside our scene-to-scene range at "
        text += ", ".join(inside) if inside else "no density"
        if out:
            text += "; outside it at " + ", ".join(out)
        text += f". Our scenes at or above the paper's value: {share}."
        if shares[config]:
            text += (
                f" Our {group}-scene means at or above it (the paper averages {group} scenes): "
                + ", ".join(shares[config])
                + "."
            )
        reached = [C.pct(d, 1) for d, w, a, n in rows if 0 < a < n]
        beyond = [C.pct(d, 1) for d, w, a, n in rows if a == n]
        never = [C.pct(d, 1) for d, w, a, n in rows if a == 0]
        if group == 1 and reached:
            text += (
                " Reading: some of our scenes, each one scene like the paper's, reach its value "
                "and some do not at "
                + ", ".join(reached)
                + ": there the difference between our mean and the printed value is within the "
                "scatter of a single scene."
            )
        if group == 1 and beyond:
            text += " Every scene of ours is at or above it at " + ", ".join(beyond) + "."
        if group == 1 and never:
            text += " No scene of ours reaches it at " + ", ".join(never) + "."
        if group > 1 and rare[config]:
            text += (
                f" Reading: fewer than {100 * RARE:.0f} % of our {group}-scene means reach the "
                "paper's value at "
                + ", ".join(rare[config])
                + f": there the gap is larger than the scatter of a {group}-scene average"
            )
            if usual[config]:
                text += f" (not at {', '.join(usual[config])})"
            text += "."
        findings.append(text)
    return C.md_table(headers, body), findings


def monotonic(values: Sequence[float]) -> bool:
    """Whether ``values`` never decrease."""
    return all(b >= a for a, b in itertools.pairwise(values))

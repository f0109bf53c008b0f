"""Wald's sequential probability ratio test (SPRT) thresholds.

Shared by the MHT track status ([PD] 24.41-24.43) and the road-section hypotheses of the VS-IMM
([PD] 24.39-24.40).
"""

from __future__ import annotations

import math

from hocnet._check import check_number

__all__ = ["sprt_thresholds"]


def sprt_thresholds(alpha: float, beta: float) -> tuple[float, float]:
    """Wald's SPRT bounds on the log-likelihood ratio: ``(ln lower, ln upper)``.

    ``lower = beta / (1 - alpha)`` (reject / delete at or below) and ``upper = (1 - beta) /
    alpha`` (accept / confirm at or above) ([PD] section 24.4.3; A. Wald, *Sequential Analysis*,
    1947, where the upper bound is called ``A`` and the lower ``B``; the chapter swaps the
    letters, so this code says "lower" and "upper" only).

    Args:
        alpha: probability of confirming a false track (accepting a wrong hypothesis), in (0, 1).
        beta: probability of deleting a true track (rejecting the true hypothesis), in (0, 1),
            with ``alpha + beta < 1``.

    Returns:
        ``(ln lower, ln upper)``.

    Raises:
        ValueError: out-of-range ``alpha`` or ``beta``, or ``alpha + beta >= 1``.

    Examples:
        >>> [round(v, 4) for v in sprt_thresholds(0.01, 0.1)]
        [-2.2925, 4.4998]
    """
    alpha = check_number(
        "alpha", alpha, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
    )
    beta = check_number("beta", beta, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False)
    if alpha + beta >= 1.0:
        raise ValueError(f"`beta`: expected alpha + beta < 1, got {alpha:g} + {beta:g}")
    return math.log(beta / (1.0 - alpha)), math.log((1.0 - beta) / alpha)

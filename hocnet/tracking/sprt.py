"""Wald's sequential probability ratio test (SPRT) thresholds.

Shared by the MHT track status ([PD] 24.41-24.43) and the road-section hypotheses of the VS-IMM
([PD] 24.39-24.40).
"""

from __future__ import annotations

import math

from hocnet._check import check_number

__all__ = ["sprt_thresholds"]


def sprt_thresholds(alpha: float, beta: float) -> tuple[float, float]:
    """Wald's SPRT thresholds on the log-likelihood ratio: ``(ln A, ln B)``.

    ``A = beta / (1 - alpha)`` (delete at or below) and ``B = (1 - beta) / alpha`` (confirm at or
    above) ([PD] section 24.4.3; A. Wald, *Sequential Analysis*, 1947).

    Args:
        alpha: probability of confirming a false track, in (0, 1).
        beta: probability of deleting a true track, in (0, 1), with ``alpha + beta < 1``.

    Returns:
        ``(ln A, ln B)``.

    Raises:
        ValueError: out-of-range ``alpha`` or ``beta``.

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

"""Named DPA settings: the paper's (:data:`PAPER`) and the best measured (:data:`RECOMMENDED`).

The rule (issue 9): the library's building blocks (:func:`hocnet.dpa.probability_matrices`,
:func:`hocnet.dpa.accumulate`, :class:`hocnet.dpa.DPA`) default to the settings of [NR08]
(O. Nichtern, S. R. Rotman, *Parameter adjustment for a dynamic programming track-before-detect
based target detection algorithm*, EURASIP JASP 2008); the ``hocnet detect --method dpa``
command line defaults to :data:`RECOMMENDED` and takes ``--preset paper`` for :data:`PAPER`.

Fields (one :class:`DPAPreset` each):

* ``window`` / ``v_max``: size of the probability matrices and largest target speed in pixels per
  frame (:func:`~hocnet.dpa.probability_matrices`).
* ``g``: sum/max mixing of eq. (11) of [NR08] (0 = max, 1 = sum).
* ``b``: memory factor, or ``"emc"`` for the b of the effective-memory criterion (EMC) of
  eq. (12)-(14) (:func:`~hocnet.dpa.effective_memory`).
* ``equal_gain``: rescale the direction matrices to one per-step gain (our addition,
  :func:`~hocnet.dpa.equalize_gain`).
* ``whitening``: ``"mean"`` (anti-mean), ``"median"`` (anti-median) or ``"none"``; 7 x 7 ring,
  3 x 3 guard (:mod:`hocnet.data.whitening`).
* ``p`` / ``penalty_step``: the direction-matrix parameters of
  :func:`~hocnet.dpa.probability_matrices`.

:data:`PAPER` is the defaults of those building blocks (``DPA()`` mixes with ``g = 0.5``;
[NR08] studies g = 0 and g = 1, so PAPER takes g = 0, the max recursion its Table 2 gives first).
:data:`RECOMMENDED` is what README's [NR08] results measured best for sub-pixel targets
(``dpa-pd-snr``: Pd >= 0.9 at 12 dB on NPA-like scenes and 6 dB in clear sky, against 15 dB and
12 dB with the paper's matrices): 5 x 5 matrices with ``v_max = 1``, g = 0, EMC b, equal gain,
anti-mean whitening.

Examples:
    >>> RECOMMENDED.window, RECOMMENDED.v_max, RECOMMENDED.g, RECOMMENDED.equal_gain
    (5, 1.0, 0.0, True)
    >>> PRESETS["paper"] is PAPER
    True
    >>> PAPER.replace(g=1.0).g
    1.0
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

__all__ = ["PAPER", "PRESETS", "RECOMMENDED", "DPAPreset"]


@dataclass(frozen=True)
class DPAPreset:
    """One named set of DPA settings (see the module docstring for the fields).

    Attributes:
        name: ``"paper"`` or ``"recommended"`` (or a user's own name).
        window: odd probability-matrix size.
        v_max: largest target speed, pixels per frame.
        g: sum/max mixing of eq. (11) of [NR08], in [0, 1].
        b: memory factor >= 0, or ``"emc"`` (eq. (12)-(14) of [NR08]).
        equal_gain: one per-step gain for every direction matrix (our addition).
        whitening: ``"mean"``, ``"median"`` or ``"none"``.
        p: direction-matrix parameter ``p`` of :func:`~hocnet.dpa.probability_matrices`.
        penalty_step: direction-matrix ``penalty_step`` of the same function.
    """

    name: str
    window: int = 7
    v_max: float = 1.0
    g: float = 0.0
    b: float | Literal["emc"] = "emc"
    equal_gain: bool = False
    whitening: Literal["mean", "median", "none"] = "mean"
    p: float = 0.5
    penalty_step: float = 3.0

    def replace(self, **changes: Any) -> DPAPreset:
        """A copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, Any]:
        """The fields as a plain dict (JSON-friendly)."""
        return dataclasses.asdict(self)


PAPER = DPAPreset(name="paper")
"""[NR08]'s settings: the defaults of ``probability_matrices`` (7 x 7, ``v_max`` 1, ``p`` 0.5,
``penalty_step`` 3), g = 0, the EMC b, no gain equalisation, anti-mean whitening."""

RECOMMENDED = DPAPreset(name="recommended", window=5, v_max=1.0, g=0.0, b="emc", equal_gain=True)
"""The pipeline the ``dpa-pd-snr`` experiment measured best for sub-pixel targets (README):
5 x 5 matrices, ``v_max`` 1, g = 0, EMC b, equal gain, anti-mean whitening."""

PRESETS: dict[str, DPAPreset] = {"paper": PAPER, "recommended": RECOMMENDED}
"""The named presets, by name (``hocnet detect --preset NAME``)."""

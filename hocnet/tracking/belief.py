"""Belief functions on Shafer's model, batched: conjunctive, Dempster, PCR5, pignistic (BetP).

A basic belief assignment (bba) on a frame ``Theta = {theta_0, ..., theta_{n-1}}`` is a float64
tensor of shape ``(..., 2**n)`` indexed by subset bitmask: bit ``i`` set means ``theta_i`` is in
the subset, index 0 is the empty set and index ``2**n - 1`` is ``Theta`` (total ignorance).
Leading axes are batch axes (e.g. one bba per track); two sources broadcast against each other.
Masses are non-negative and sum to 1 (tolerance 1e-6).

Source: [PD] section 24.5 (Pannetier, Dezert et al.): PCR5 for two sources on Shafer's model
(eq. 24.44), the target-type tracker (vacuous prior, observed bba from the classifier's confusion
matrix, eq. 24.45-24.46) and the pignistic transformation (eq. 24.47). The s-source PCR5 is the
general rule of Smarandache and Dezert (*Advances and Applications of DSmT for Information
Fusion*, vol. 2, 2006, ch. 1) in its focal-element form (Dezert, Dezert and Smarandache, JAIF
16(1), 2021, eq. 14, as cited by ``evidencelib``; we compared numbers with ``evidencelib``, not
the formula with the paper's text): every conflicting product ``m_1(X_1) ... m_s(X_s)``
(``X_1 & ... & X_s`` empty) is shared among the *distinct* sets among ``X_1, ..., X_s``
proportionally to the product of the masses the sources put on each distinct set.

Several frames ([PD] 24.5.3): the GMTI frame (3 classes, eq. 24.21) is refined to the video
frame (8 classes, eq. 24.25) by a "human refinement" ``Omega`` (each coarse class to a set of
fine classes, :func:`frame_mapping`); a coarse bba is carried to the fine frame by sending each
focal set to the union of its elements' images (:func:`refine`), and back by Shafer's outer or
inner reduction (:func:`coarsen`). Reports of several sensors are fused on the fine frame by
PCR5 (:func:`fuse_sensors`); the type factor of eq. 24.48 on that frame is
:func:`type_likelihood`.
"""

from __future__ import annotations

import itertools
from collections.abc import Hashable, Iterable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import torch

from hocnet._check import _describe, check_choice, check_int, check_number
from hocnet.tracking.kalman import DTYPE, as_float64

__all__ = [
    "TypeFusion",
    "coarsen",
    "conjunctive",
    "dempster",
    "frame_mapping",
    "from_dict",
    "fuse_sensors",
    "observed_bba",
    "pcr5",
    "pcr5_sources",
    "pignistic",
    "pignistic_coarse",
    "refine",
    "report_type_likelihood",
    "to_dict",
    "type_likelihood",
    "vacuous",
]

_TOL = 1e-6


def _n_atoms(name: str, size: int) -> int:
    n = size.bit_length() - 1
    if size < 2 or (1 << n) != size:
        raise ValueError(f"`{name}`: expected a last axis of size 2**n with n >= 1, got {size}")
    return n


def _masses(name: str, m: Any, *, normal: bool = False) -> torch.Tensor:
    m = as_float64(name, m, min_dim=1)
    _n_atoms(name, m.shape[-1])
    if m.numel():
        if bool((m < -1e-12).any()):
            raise ValueError(f"`{name}`: expected non-negative masses, got a minimum {m.min():g}")
        sums = m.sum(-1)
        bad = (sums - 1.0).abs() > _TOL
        if bool(bad.any()):
            raise ValueError(
                f"`{name}`: expected masses summing to 1, got a sum {float(sums[bad][0]):.9g}"
            )
        if normal and bool((m[..., 0] > 1e-12).any()):
            raise ValueError(
                f"`{name}`: expected no mass on the empty set (Shafer's model), got "
                f"{float(m[..., 0].max()):g}"
            )
    return m.clamp_min(0.0)


def _same_frame(*pairs: tuple[str, torch.Tensor]) -> int:
    sizes = {t.shape[-1] for _, t in pairs}
    if len(sizes) != 1:
        names = ", ".join(f"`{n}` {t.shape[-1]}" for n, t in pairs)
        raise ValueError(
            f"`{pairs[-1][0]}`: expected the same frame size 2**n for all sources, got {names}"
        )
    return sizes.pop()


def vacuous(n: int, batch_shape: Sequence[int] = ()) -> torch.Tensor:
    """Vacuous bba ``m(Theta) = 1``: the target-type tracker's prior (step a of 24.5.2).

    Args:
        n: number of atoms (classes) of the frame, ``1 <= n <= 20``.
        batch_shape: leading batch shape.

    Returns:
        ``(*batch_shape, 2**n)`` float64.

    Examples:
        >>> vacuous(2)
        tensor([0., 0., 0., 1.], dtype=torch.float64)
    """
    n = check_int("n", n, minimum=1, maximum=20)
    m = torch.zeros(*batch_shape, 1 << n, dtype=DTYPE)
    m[..., -1] = 1.0
    return m


def from_dict(masses: Mapping[frozenset, float], frame: Sequence[Hashable]) -> torch.Tensor:
    """Build a bba tensor ``(2**n,)`` from ``{frozenset of atoms: mass}``.

    Args:
        masses: mapping from subsets of ``frame`` (any iterable of atoms is accepted) to masses.
        frame: the ``n`` atoms in bit order (atom ``frame[i]`` is bit ``i``).

    Returns:
        ``(2**n,)`` float64 tensor.

    Raises:
        ValueError: unknown atom, duplicate atoms in ``frame``, masses not summing to 1.

    Examples:
        >>> from_dict({frozenset("a"): 0.6, frozenset("ab"): 0.4}, ["a", "b"])
        tensor([0.0000, 0.6000, 0.0000, 0.4000], dtype=torch.float64)
    """
    atoms = list(frame)
    if len(set(atoms)) != len(atoms) or not atoms:
        raise ValueError(f"`frame`: expected distinct atoms, got {atoms!r}")
    index = {a: i for i, a in enumerate(atoms)}
    m = torch.zeros(1 << len(atoms), dtype=DTYPE)
    for subset, value in masses.items():
        mask = 0
        for atom in subset:
            if atom not in index:
                raise ValueError(
                    f"`masses`: expected subsets of the frame {atoms!r}, got atom {atom!r}"
                )
            mask |= 1 << index[atom]
        m[mask] += check_number("masses", value, low=0.0)
    return _masses("masses", m)


def to_dict(m: Any, frame: Sequence[Hashable], *, tol: float = 0.0) -> dict[frozenset, float]:
    """Convert one bba ``(2**n,)`` to ``{frozenset of atoms: mass}`` (masses ``> tol`` only).

    Examples:
        >>> d = to_dict(torch.tensor([0.0, 0.6, 0.0, 0.4], dtype=torch.float64), ["a", "b"])
        >>> sorted((sorted(k), v) for k, v in d.items())
        [(['a'], 0.6), (['a', 'b'], 0.4)]
    """
    m = _masses("m", m)
    atoms = list(frame)
    if m.dim() != 1 or m.shape[0] != 1 << len(atoms):
        raise ValueError(
            f"`m`: expected shape ({1 << len(atoms)},) for a frame of {len(atoms)} atoms, "
            f"got {tuple(m.shape)}"
        )
    return {
        frozenset(a for i, a in enumerate(atoms) if mask >> i & 1): float(v)
        for mask, v in enumerate(m.tolist())
        if v > tol
    }


def _intersection_table(size: int) -> torch.Tensor:
    idx = torch.arange(size)
    return idx[:, None] & idx[None, :]


def conjunctive(m1: Any, m2: Any) -> torch.Tensor:
    """Unnormalised conjunctive rule ``m12(A) = sum_{B & C = A} m1(B) m2(C)`` (conflict on index 0).

    ``m12`` is the "conjunctive consensus" of [PD] eq. 24.44.

    Args:
        m1: first bba ``(..., 2**n)``.
        m2: second bba ``(..., 2**n)`` (broadcast against ``m1``).

    Returns:
        ``(..., 2**n)`` float64; ``[..., 0]`` is the conflict mass.

    Raises:
        TypeError, ValueError: not bbas, different frames.

    Examples:
        >>> conjunctive(torch.tensor([0, 0.5, 0, 0.5]), torch.tensor([0, 0, 1.0, 0]))
        tensor([0.5000, 0.0000, 0.5000, 0.0000], dtype=torch.float64)
    """
    m1, m2 = _masses("m1", m1), _masses("m2", m2)
    size = _same_frame(("m1", m1), ("m2", m2))
    return _conjunctive(m1, m2, size)


def _conjunctive(m1: torch.Tensor, m2: torch.Tensor, size: int) -> torch.Tensor:
    shape = torch.broadcast_shapes(m1.shape[:-1], m2.shape[:-1])
    prod = (
        (m1.unsqueeze(-1) * m2.unsqueeze(-2))
        .expand(*shape, size, size)
        .reshape(*shape, size * size)
    )
    out = torch.zeros(*shape, size, dtype=DTYPE)
    index = _intersection_table(size).reshape(-1).expand(*shape, size * size)
    return out.scatter_add_(-1, index, prod)


def dempster(m1: Any, m2: Any) -> torch.Tensor:
    """Dempster's rule: the conjunctive rule normalised by ``1 - K`` (``K`` the conflict).

    Args:
        m1: first bba ``(..., 2**n)``.
        m2: second bba ``(..., 2**n)`` (broadcast against ``m1``).

    Returns:
        ``(..., 2**n)`` float64 with ``m(empty) = 0``.

    Raises:
        ValueError: total conflict (``K = 1``), for which Dempster's rule is undefined.

    Examples:
        >>> m1 = torch.tensor([0, 0.9, 0, 0, 0.1, 0, 0, 0], dtype=torch.float64)  # Zadeh (M, C, T)
        >>> m2 = torch.tensor([0, 0, 0.9, 0, 0.1, 0, 0, 0], dtype=torch.float64)
        >>> [round(v, 9) for v in dempster(m1, m2).tolist()]  # all on the minority T
        [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    """
    m = conjunctive(m1, m2)
    rest = 1.0 - m[..., :1]
    if m.numel() and bool((rest <= 1e-15).any()):
        raise ValueError(
            "`m2`: expected sources not in total conflict with `m1` (Dempster's rule is "
            "undefined), got K = 1"
        )
    out = m / rest
    out[..., 0] = 0.0
    return out


def pcr5(m1: Any, m2: Any) -> torch.Tensor:
    """PCR5 for two sources on Shafer's model, eq. 24.44 of [PD].

    ``m(X) = m12(X) + sum_{Y : X & Y = empty} [m1(X)^2 m2(Y) / (m1(X) + m2(Y)) +
    m2(X)^2 m1(Y) / (m2(X) + m1(Y))]`` for ``X`` non-empty and ``m(empty) = 0``; fractions
    with a zero denominator are discarded (their numerators are zero too). ``m12`` is
    :func:`conjunctive`. The chapter prints the sum over ``Y in 2^Theta minus {X}``; the condition
    ``X & Y = empty`` already excludes ``Y = X`` for non-empty ``X``.

    Args:
        m1: first bba ``(..., 2**n)`` with no mass on the empty set (e.g. the prior ``m-``).
        m2: second bba ``(..., 2**n)``, broadcast against ``m1`` (e.g. the observed ``m_obs``).

    Returns:
        ``(..., 2**n)`` float64 summing to 1, ``m(empty) = 0``.

    Raises:
        TypeError, ValueError: not bbas, different frames, mass on the empty set.

    Examples:
        >>> m1 = torch.tensor([0, 0.9, 0, 0, 0.1, 0, 0, 0])  # Zadeh: m1(M) = 0.9, m1(T) = 0.1
        >>> m2 = torch.tensor([0, 0, 0.9, 0, 0.1, 0, 0, 0])  # m2(C) = 0.9, m2(T) = 0.1
        >>> [round(v, 6) for v in pcr5(m1, m2).tolist()]
        [0.0, 0.486, 0.486, 0.0, 0.028, 0.0, 0.0, 0.0]
    """
    m1, m2 = _masses("m1", m1, normal=True), _masses("m2", m2, normal=True)
    size = _same_frame(("m1", m1), ("m2", m2))
    m12 = _conjunctive(m1, m2, size)
    disjoint = (_intersection_table(size) == 0).to(DTYPE)  # (X, Y)
    a = m1.unsqueeze(-1)  # m1(X)
    b = m2.unsqueeze(-2)  # m2(Y)
    c = m2.unsqueeze(-1)  # m2(X)
    d = m1.unsqueeze(-2)  # m1(Y)
    t1 = _safe_ratio(a * a * b, a + b)
    t2 = _safe_ratio(c * c * d, c + d)
    extra = ((t1 + t2) * disjoint).sum(-1)
    out = m12 + extra
    out[..., 0] = 0.0
    return out


def _safe_ratio(num: torch.Tensor, den: torch.Tensor) -> torch.Tensor:
    return torch.where(
        den > 0, num / torch.where(den > 0, den, torch.ones_like(den)), torch.zeros_like(num)
    )


def pcr5_sources(*masses: Any) -> torch.Tensor:
    """PCR5 for ``s >= 2`` sources combined jointly (the general rule, see the module docstring).

    Every tuple ``(X_1, ..., X_s)`` (one focal set per source) with a non-empty intersection
    gives ``prod_i m_i(X_i)`` to that intersection (conjunctive consensus); with an empty
    intersection the product is shared among the distinct sets ``Y`` of the tuple in proportion to
    ``prod_{i : X_i = Y} m_i(X_i)``. For ``s = 2`` this is eq. 24.44 (:func:`pcr5`). PCR5 is
    not associative: ``pcr5(pcr5(m1, m2), m3)`` (the sequential fusion the chapter's target-type
    tracker uses, one new bba per scan) is **not** ``pcr5_sources(m1, m2, m3)``.

    Cost: ``(2**n)**s`` tuples per batch element; meant for small frames (``n <= 4`` with
    ``s = 3``).

    Args:
        *masses: ``s >= 2`` bbas ``(..., 2**n)`` without mass on the empty set (broadcast).

    Returns:
        ``(..., 2**n)`` float64 summing to 1, ``m(empty) = 0``.

    Raises:
        TypeError, ValueError: fewer than 2 sources, not bbas, different frames, empty-set mass,
            more than ``2**24`` tuples.

    Examples:
        >>> m = torch.tensor([0, 0.6, 0.4, 0], dtype=torch.float64)  # not idempotent:
        >>> [round(v, 6) for v in pcr5_sources(m, m, m).tolist()]
        [0.0, 0.648, 0.352, 0.0]
    """
    if len(masses) < 2:
        raise ValueError(f"`masses`: expected at least 2 sources, got {len(masses)}")
    ms = [_masses(f"masses[{i}]", m, normal=True) for i, m in enumerate(masses)]
    size = _same_frame(*((f"masses[{i}]", m) for i, m in enumerate(ms)))
    s = len(ms)
    if size**s > 2**24:
        raise ValueError(f"`masses`: expected (2**n)**s <= 2**24 tuples, got {size}**{s}")
    shape = torch.broadcast_shapes(*(m.shape[:-1] for m in ms))
    stack = torch.stack([m.expand(*shape, size) for m in ms], dim=-2)  # (..., s, K)
    out = torch.zeros(*shape, size, dtype=DTYPE)
    # conjunctive consensus, sequentially (the conjunctive rule is associative)
    conj = ms[0].expand(*shape, size)
    for m in ms[1:]:
        conj = _conjunctive(conj, m, size)
    out += conj
    out[..., 0] = 0.0
    # conflicting tuples: (C, s) indices with an empty intersection, sets of non-zero size only
    grid = torch.tensor(list(itertools.product(range(1, size), repeat=s)), dtype=torch.long)
    inter = grid[:, 0]
    for j in range(1, s):
        inter = inter & grid[:, j]
    grid = grid[inter == 0]
    if grid.numel() == 0:
        return out
    vals = torch.stack([stack[..., j, :][..., grid[:, j]] for j in range(s)], dim=-1)  # (..., C, s)
    amount = vals.prod(-1)  # (..., C)
    same = grid.unsqueeze(-1) == grid.unsqueeze(-2)  # (C, s, s): X_j == X_t
    w = torch.where(same, vals.unsqueeze(-2), torch.ones_like(vals).unsqueeze(-2)).prod(
        -1
    )  # (..., C, s)
    earlier = torch.tril(torch.ones(s, s, dtype=torch.bool), diagonal=-1)  # t < j
    first = ~(same & earlier).any(-1)  # (C, s): first occurrence of its set in the tuple
    w = w * first
    den = w.sum(-1, keepdim=True)
    share = _safe_ratio(amount.unsqueeze(-1) * w, den)  # (..., C, s)
    index = grid.expand(*shape, *grid.shape).reshape(*shape, -1)
    return out.scatter_add_(-1, index, share.reshape(*shape, -1))


def pignistic(m: Any) -> torch.Tensor:
    """Pignistic probabilities of the singletons, eq. 24.47 of [PD] with ``A = {theta_i}``.

    ``BetP(theta_i) = sum_{X ∋ theta_i} m(X) / |X|``, divided by ``1 - m(empty)`` when the bba
    carries conflict (Smets' convention, as ``evidencelib``'s default; PCR5 and Dempster outputs
    have none). For a set ``A``, ``BetP(A) = sum_{X} |X & A| / |X| m(X)`` is the sum of the
    singleton values over ``A``. The type decision of 24.45 is ``pignistic(m).argmax(-1)``.

    Args:
        m: bbas ``(..., 2**n)``.

    Returns:
        ``(..., n)`` float64, summing to 1.

    Raises:
        TypeError, ValueError: not a bba; total conflict (``m(empty) = 1``).

    Examples:
        >>> pignistic(torch.tensor([0, 0.5, 0, 0.5]))
        tensor([0.7500, 0.2500], dtype=torch.float64)
    """
    m = _masses("m", m)
    size = m.shape[-1]
    n = _n_atoms("m", size)
    idx = torch.arange(size)
    member = ((idx.unsqueeze(-1) >> torch.arange(n)) & 1).to(DTYPE)  # (K, n)
    card = member.sum(-1)
    weight = member / torch.where(card > 0, card, torch.ones_like(card)).unsqueeze(-1)
    rest = 1.0 - m[..., :1]
    if m.numel() and bool((rest <= 1e-15).any()):
        raise ValueError("`m`: expected a bba with some mass off the empty set, got m(empty) = 1")
    return (m @ weight) / rest


def observed_bba(confusion: Any, declared: Any) -> torch.Tensor:
    """Observed bba of a classifier declaration (step b of [PD] section 24.5.2).

    ``m_obs({theta_c}) = C[c, c]`` and ``m_obs(Theta) = 1 - C[c, c]`` where ``c`` is the declared
    class and ``C`` the classifier's confusion matrix (only its diagonal is used, as in the
    chapter; ``C[i, j] = P(declare j | true i)``).

    Args:
        confusion: ``(n, n)`` confusion matrix with entries in [0, 1].
        declared: integer tensor of declared class indices, shape ``(...)``, values in ``[0, n)``.

    Returns:
        ``(..., 2**n)`` float64 bbas.

    Raises:
        TypeError, ValueError: non-square or out-of-range confusion matrix, non-integer or
            out-of-range declarations.

    Examples:
        >>> observed_bba(torch.diag(torch.tensor([0.8, 0.7])), torch.tensor([1]))
        tensor([[0.0000, 0.0000, 0.7000, 0.3000]], dtype=torch.float64)
    """
    C = as_float64("confusion", confusion, min_dim=2, square=True)
    if C.dim() != 2:
        raise ValueError(f"`confusion`: expected an (n, n) matrix, got shape {tuple(C.shape)}")
    if bool(((C < 0) | (C > 1)).any()):
        raise ValueError("`confusion`: expected probabilities in [0, 1], got values outside")
    n = check_int("confusion.shape[0]", C.shape[0], minimum=1, maximum=20)
    c = torch.as_tensor(declared)
    if c.is_floating_point() or c.is_complex() or c.dtype == torch.bool:
        raise TypeError(f"`declared`: expected integer class indices, got dtype {c.dtype}")
    c = c.long()
    if c.numel() and bool(((c < 0) | (c >= n)).any()):
        raise ValueError(
            f"`declared`: expected class indices in [0, {n}), got {c.min()}..{c.max()}"
        )
    p = C.diagonal()[c]
    m = torch.zeros(*c.shape, 1 << n, dtype=DTYPE)
    m.scatter_(-1, (1 << c).unsqueeze(-1), p.unsqueeze(-1))
    m[..., -1] += 1.0 - p
    return m


# --------------------------------------------------------------------------------------------
# frames of discernment: refinement, coarsening, multi-sensor fusion ([PD] 24.5.3)
# --------------------------------------------------------------------------------------------


class TypeFusion(NamedTuple):
    """Result of :func:`fuse_sensors`: the fused bba and its pignistic probabilities.

    Attributes:
        m: ``(..., 2**n_fine)`` float64 fused bba on the common (fine) frame.
        betp: ``(..., n_fine)`` float64 pignistic probabilities of the fine classes (eq. 24.47).
    """

    m: torch.Tensor
    betp: torch.Tensor


def _is_index(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | np.integer)


def frame_mapping(
    mapping: Any, n_coarse: int, n_fine: int, *, partition: bool = True
) -> torch.Tensor:
    """Validate a refinement ``Omega`` of a coarse frame into a fine one ([PD] 24.5.3).

    Two forms are accepted:

    - *blocks*: a sequence of ``n_coarse`` iterables, ``mapping[i]`` the fine-class indices of
      coarse class ``i`` (``Omega({omega_i})``);
    - *labels*: a sequence (or 1-D integer tensor / array) of ``n_fine`` coarse-class indices,
      ``mapping[j]`` the coarse class of fine class ``j`` (e.g.
      :data:`~hocnet.tracking.scenario.VIDEO_TO_GMTI`); always a partition.

    The chapter asks that "each element of C_MTI can be associated at least to one element of
    C_video": every image must be non-empty. With ``partition=True`` (Shafer's refining, 1976
    ch. 6) the images must also be disjoint and cover the fine frame; ``partition=False`` accepts
    any non-empty images (a multi-valued mapping, our addition; coarsening does not invert it).

    Args:
        mapping: blocks or labels, see above.
        n_coarse: number of coarse classes, ``1 <= n_coarse <= 20``.
        n_fine: number of fine classes, ``1 <= n_fine <= 20``.
        partition: require disjoint images covering the fine frame.

    Returns:
        ``(n_coarse,)`` int64 tensor: the fine bitmask of each coarse class's image.

    Raises:
        TypeError: mixed or non-integer entries.
        ValueError: wrong length, index out of range, empty image, not a partition.

    Examples:
        >>> frame_mapping([(0, 1), (2,)], 2, 3).tolist()
        [3, 4]
        >>> frame_mapping([0, 0, 1], 2, 3).tolist()  # the same refinement as labels
        [3, 4]
    """
    n_coarse = check_int("n_coarse", n_coarse, minimum=1, maximum=20)
    n_fine = check_int("n_fine", n_fine, minimum=1, maximum=20)
    if isinstance(mapping, torch.Tensor | np.ndarray):
        arr = torch.as_tensor(mapping)
        if arr.dim() != 1 or arr.is_floating_point() or arr.is_complex() or arr.dtype == torch.bool:
            raise TypeError(
                f"`mapping`: expected a 1-D integer tensor of coarse labels, got "
                f"{_describe(mapping)}"
            )
        mapping = arr.tolist()
    if isinstance(mapping, str | bytes) or not isinstance(mapping, Sequence):
        raise TypeError(
            f"`mapping`: expected a sequence of fine-index sets or coarse labels, got "
            f"{_describe(mapping)}"
        )
    items = list(mapping)
    if items and all(_is_index(v) for v in items):  # labels: fine -> coarse
        if len(items) != n_fine:
            raise ValueError(
                f"`mapping`: expected {n_fine} coarse labels (one per fine class), got {len(items)}"
            )
        bad = [int(v) for v in items if not 0 <= int(v) < n_coarse]
        if bad:
            raise ValueError(f"`mapping`: expected coarse labels in [0, {n_coarse}), got {bad[0]}")
        blocks = [[j for j, v in enumerate(items) if int(v) == i] for i in range(n_coarse)]
    else:
        if len(items) != n_coarse:
            raise ValueError(
                f"`mapping`: expected {n_coarse} fine-index sets (one per coarse class), got "
                f"{len(items)}"
            )
        blocks = []
        for i, block in enumerate(items):
            if isinstance(block, str | bytes) or not isinstance(block, Iterable):
                raise TypeError(
                    f"`mapping[{i}]`: expected an iterable of fine-class indices, got "
                    f"{_describe(block)}"
                )
            block = list(block.tolist() if isinstance(block, torch.Tensor) else block)
            if not all(_is_index(v) for v in block):
                raise TypeError(
                    f"`mapping[{i}]`: expected integer fine-class indices, got {_describe(block)}"
                )
            bad = [int(v) for v in block if not 0 <= int(v) < n_fine]
            if bad:
                raise ValueError(f"`mapping[{i}]`: expected indices in [0, {n_fine}), got {bad[0]}")
            blocks.append([int(v) for v in block])
    masks = []
    for i, block in enumerate(blocks):
        if not block:
            raise ValueError(
                f"`mapping`: expected every coarse class to map to at least one fine class, got "
                f"an empty image for coarse class {i}"
            )
        masks.append(sum(1 << j for j in set(block)))
    if partition:
        seen = 0
        for i, mask in enumerate(masks):
            if seen & mask:
                j = (seen & mask).bit_length() - 1
                raise ValueError(
                    f"`mapping`: expected a partition of the fine frame, got fine class {j} in "
                    f"two coarse classes (the second is {i})"
                )
            seen |= mask
        if seen != (1 << n_fine) - 1:
            j = next(j for j in range(n_fine) if not seen >> j & 1)
            raise ValueError(
                f"`mapping`: expected a partition of the fine frame, got fine class {j} in no "
                f"coarse class"
            )
    return torch.tensor(masks, dtype=torch.long)


def _subset_bits(n: int) -> torch.Tensor:
    return ((torch.arange(1 << n).unsqueeze(-1) >> torch.arange(n)) & 1).bool()  # (2**n, n)


def _refine_table(images: torch.Tensor, n_coarse: int) -> torch.Tensor:
    bits = _subset_bits(n_coarse)  # (2**nc, nc)
    table = torch.zeros(1 << n_coarse, dtype=torch.long)
    for i in range(n_coarse):
        table |= torch.where(bits[:, i], images[i], 0)
    return table


def _scatter(m: torch.Tensor, table: torch.Tensor, size: int) -> torch.Tensor:
    out = torch.zeros(*m.shape[:-1], size, dtype=DTYPE)
    return out.scatter_add_(-1, table.expand(*m.shape[:-1], table.shape[0]), m)


def refine(m: Any, mapping: Any, n_fine: int, *, partition: bool = True) -> torch.Tensor:
    """Refine bbas from a coarse frame to a fine one ([PD] 24.5.3, "human refinement").

    ``m_fine(B) = sum_{A : Omega(A) = B} m(A)`` with ``Omega(A) = U_{omega in A} Omega({omega})``
    (Shafer 1976 ch. 6: the refined bba is the *vacuous extension* of ``m``; every focal set
    ``A`` goes to the union of the images of its elements; ``Omega(empty) = empty``). This is how
    the chapter "adapts the frame C_MTI to C_video": a GMTI report is combined with video reports
    and the track's prior on the video frame. Total mass and the empty-set mass are preserved;
    ``m_fine`` is normal when ``m`` is.
    For a partition ``Omega(A) & Omega(B) = Omega(A & B)``, so the conjunctive rule, :func:`pcr5`
    and :func:`pcr5_sources` commute with refinement: a track fed only GMTI reports and fused on
    the video frame carries exactly the refinement of its GMTI-frame bba (tested).

    Args:
        m: coarse bbas ``(..., 2**n_coarse)``.
        mapping: the refinement, ``n_coarse`` fine-index sets or ``n_fine`` coarse labels (see
            :func:`frame_mapping`).
        n_fine: number of fine classes.
        partition: require a partition (Shafer's refining); see :func:`frame_mapping`.

    Returns:
        ``(..., 2**n_fine)`` float64.

    Raises:
        TypeError, ValueError: ``m`` not a bba, bad ``mapping`` or ``n_fine``.

    Examples:
        >>> m = torch.tensor([0, 0.7, 0, 0.3], dtype=torch.float64)  # m({w0}) = .7, m(Theta) = .3
        >>> out = refine(m, [(0, 1), (2,)], 3)  # w0 -> {t0, t1}, w1 -> {t2}
        >>> [(i, round(v, 6)) for i, v in enumerate(out.tolist()) if v]
        [(3, 0.7), (7, 0.3)]
    """
    m = _masses("m", m)
    n_coarse = _n_atoms("m", m.shape[-1])
    n_fine = check_int("n_fine", n_fine, minimum=1, maximum=20)
    images = frame_mapping(mapping, n_coarse, n_fine, partition=partition)
    return _scatter(m, _refine_table(images, n_coarse), 1 << n_fine)


def coarsen(m: Any, mapping: Any, n_coarse: int, *, kind: str = "outer") -> torch.Tensor:
    """Coarsen bbas from a fine frame to a coarse one by the outer or inner reduction.

    With ``Omega`` a refinement (a partition of the fine frame into ``n_coarse`` blocks),
    Shafer (1976, ch. 6) defines for a fine set ``B``:

    - outer reduction ``B_bar = {omega : Omega({omega}) & B != empty}``;
    - inner reduction ``B_under = {omega : Omega({omega}) <= B}``;

    and ``m_coarse(A) = sum_{B : reduction(B) = A} m(B)``. Both are left inverses of
    :func:`refine` (``coarsen(refine(m)) = m``). The outer reduction keeps a normal bba normal
    (the coarse bba is the least committed one whose refinement contains the fine evidence);
    the inner one sends a set containing no whole block to the empty set (and a normal bba may
    get mass on it).

    Our reading: the chapter (24.5.3) only refines, "C_MTI to C_video", and fuses on the fine
    frame; it never coarsens. ``kind="outer"`` is our default because it is the reduction that
    preserves normality (Shafer's model, needed by :func:`pcr5`); ``"inner"`` is given for
    completeness.

    Args:
        m: fine bbas ``(..., 2**n_fine)``.
        mapping: the refinement, a partition (see :func:`frame_mapping`).
        n_coarse: number of coarse classes.
        kind: ``"outer"`` or ``"inner"``.

    Returns:
        ``(..., 2**n_coarse)`` float64.

    Raises:
        TypeError, ValueError: ``m`` not a bba, ``mapping`` not a partition, bad ``kind``.

    Examples:
        >>> m = torch.zeros(8, dtype=torch.float64)
        >>> m[1], m[7] = 0.6, 0.4  # m({t0}) = .6, m(Theta) = .4
        >>> coarsen(m, [(0, 1), (2,)], 2).tolist()  # {t0} -> {w0}
        [0.0, 0.6, 0.0, 0.4]
        >>> coarsen(m, [(0, 1), (2,)], 2, kind="inner").tolist()  # {t0} holds no whole block
        [0.6, 0.0, 0.0, 0.4]
    """
    m = _masses("m", m)
    n_fine = _n_atoms("m", m.shape[-1])
    n_coarse = check_int("n_coarse", n_coarse, minimum=1, maximum=20)
    kind = check_choice("kind", kind, ("outer", "inner"))
    images = frame_mapping(mapping, n_coarse, n_fine, partition=True)
    sets = torch.arange(1 << n_fine).unsqueeze(-1)  # (2**nf, 1)
    inter = sets & images  # (2**nf, nc)
    hit = inter != 0 if kind == "outer" else inter == images
    table = (hit.long() << torch.arange(n_coarse)).sum(-1)
    return _scatter(m, table, 1 << n_coarse)


def _to_common(
    name: str, m: Any, mapping: Any, n_fine: int, partition: bool
) -> torch.Tensor | None:
    if m is None:
        return None
    m = _masses(name, m, normal=True)
    if mapping is None:
        if m.shape[-1] != 1 << n_fine:
            raise ValueError(
                f"`{name}`: expected a bba on the common frame (last axis {1 << n_fine}) when its "
                f"mapping is None, got {m.shape[-1]}"
            )
        return m
    try:
        return refine(m, mapping, n_fine, partition=partition)
    except (TypeError, ValueError) as err:
        raise type(err)(f"{name}: {err}") from None


def fuse_sensors(
    observations: Sequence[Any],
    mappings: Sequence[Any],
    n_fine: int,
    *,
    prior: Any = None,
    rule: str = "sequential",
    partition: bool = True,
) -> TypeFusion:
    """Fuse type bbas of sensors with different frames on a common (fine) frame ([PD] 24.5.3).

    Each observed bba is refined to the common frame (:func:`refine`), then combined with the
    track's prior ``m-`` by PCR5 and the pignistic probabilities (24.47) are taken:

    - ``rule="sequential"`` (default): ``m = (((m- (+) m_1) (+) m_2) ...)`` with the two-source
      PCR5 of eq. 24.44, the observations in the given order. Our reading of "we extend the
      principle of TTT to combine multiple bba's ... with prior target ID bba m-": the TTT
      (24.5.2) fuses two sources at a time, and 24.44 is printed as "useful for sequential
      fusion". PCR5 is not associative, so the order matters (prior first, then sensors).
    - ``rule="joint"``: the s-source PCR5 (:func:`pcr5_sources`) of ``m-`` and all
      observations at once ("the PCR5 formula for s >= 2 sources is given in [16]"). Cost
      ``(2**n_fine)**s`` tuples: with the 8 video classes only ``s = 2`` is practical.

    Vacuous sources. The chapter takes a sensor without information as the vacuous bba "because
    this doesn't change the result of the fusion rule". That holds for the two-source PCR5
    (``pcr5(m, vacuous) = m``) and hence for ``"sequential"``, but **not** for the s-source
    PCR5, which gives ``Theta`` a share of every conflict involving a vacuous source (we measured
    ``pcr5_sources(m1, vacuous, m3) != pcr5(m1, m3)``). So ``None`` observations, and sources
    that are vacuous for the whole batch (including the default vacuous prior), are *dropped*
    rather than combined (our reading: the property the chapter asks for, for both rules).

    Args:
        observations: ``s`` bbas, ``observations[i]`` of shape ``(..., 2**n_i)`` on sensor
            ``i``'s frame (no mass on the empty set), or ``None`` (no report). Batch axes
            broadcast.
        mappings: ``s`` refinements of the sensors' frames into the common frame (see
            :func:`frame_mapping`), ``None`` for a sensor already on the common frame.
        n_fine: number of classes of the common frame.
        prior: the track's prior ``m-`` ``(..., 2**n_fine)``; ``None`` is the vacuous prior of
            step a) of 24.5.2.
        rule: ``"sequential"`` or ``"joint"``.
        partition: require every mapping to be a partition (:func:`frame_mapping`).

    Returns:
        :class:`TypeFusion` ``(m, betp)``: ``(..., 2**n_fine)`` and ``(..., n_fine)`` float64.

    Raises:
        TypeError, ValueError: lengths differ, bad bba or mapping (named by index), bad ``rule``.

    Examples:
        >>> gmti = torch.tensor([0, 0, 0.7, 0.3])  # 2 coarse classes, "wheeled" (1) with P = .7
        >>> video = torch.zeros(8)
        >>> video[2], video[7] = 0.75, 0.25  # video class 1 of 3 with P = .75
        >>> out = fuse_sensors([gmti, video], [[0, 1, 1], None], 3)  # fine 1, 2 are "wheeled"
        >>> [round(v, 4) for v in out.betp.tolist()]
        [0.025, 0.8625, 0.1125]
    """
    n_fine = check_int("n_fine", n_fine, minimum=1, maximum=20)
    rule = check_choice("rule", rule, ("sequential", "joint"))
    if isinstance(observations, str | bytes) or not isinstance(observations, Sequence):
        raise TypeError(
            f"`observations`: expected a sequence of bbas, got {_describe(observations)}"
        )
    if isinstance(mappings, str | bytes) or not isinstance(mappings, Sequence):
        raise TypeError(f"`mappings`: expected a sequence of mappings, got {_describe(mappings)}")
    if len(mappings) != len(observations):
        raise ValueError(
            f"`mappings`: expected one mapping per observation ({len(observations)}), got "
            f"{len(mappings)}"
        )
    sources = []
    if prior is not None:
        sources.append(_to_common("prior", prior, None, n_fine, partition))
    for i, (obs, mp) in enumerate(zip(observations, mappings, strict=True)):
        m = _to_common(f"observations[{i}]", obs, mp, n_fine, partition)
        if m is not None:
            sources.append(m)
    size = 1 << n_fine
    present = [m for m in sources if not bool((m[..., -1] == 1.0).all())]
    shape = torch.broadcast_shapes(*(m.shape[:-1] for m in sources)) if sources else ()
    if not present:
        fused = vacuous(n_fine, shape)
    elif len(present) == 1:
        fused = present[0]
    elif rule == "joint":
        fused = pcr5_sources(*present)
    else:
        fused = present[0]
        for m in present[1:]:
            fused = pcr5(fused, m)
    fused = fused.expand(*shape, size).clone()
    return TypeFusion(fused, pignistic(fused))


def pignistic_coarse(m: Any, mapping: Any, n_coarse: int) -> torch.Tensor:
    """Pignistic probabilities of the coarse classes' images, ``BetP{Omega({omega_i})}``.

    Eq. 24.47 with ``A = Omega({omega_i})`` on the fine frame, i.e. the sum of the fine
    ``BetP`` over each block. Our addition for the decision on the coarse frame: the chapter
    notes (24.6.3) that a track with GMTI reports only has equal fine ``BetP`` over the six
    video classes of its GMTI class, so the fine argmax is arbitrary; the coarse one is not.
    Note that ``BetP`` is not invariant to refinement: this is in general **not**
    ``pignistic(coarsen(m, mapping, n_coarse))`` (blocks of different sizes weigh differently).

    Args:
        m: fine bbas ``(..., 2**n_fine)``.
        mapping: the refinement (a partition, see :func:`frame_mapping`).
        n_coarse: number of coarse classes.

    Returns:
        ``(..., n_coarse)`` float64, summing to 1.

    Examples:
        >>> m = torch.tensor([0, 0, 0, 0, 0, 0, 0, 1.0])  # vacuous on 3 fine classes
        >>> [round(v, 4) for v in pignistic_coarse(m, [0, 0, 1], 2).tolist()]
        [0.6667, 0.3333]
    """
    m = _masses("m", m)
    n_fine = _n_atoms("m", m.shape[-1])
    n_coarse = check_int("n_coarse", n_coarse, minimum=1, maximum=20)
    images = frame_mapping(mapping, n_coarse, n_fine, partition=True)
    member = ((images.unsqueeze(-1) >> torch.arange(n_fine)) & 1).to(DTYPE)  # (nc, nf)
    return pignistic(m) @ member.T


def type_likelihood(m: Any, declared: Any = None, mapping: Any = None) -> torch.Tensor:
    """The type factor ``P{dtype(k) | dtype(k-1)}`` of eq. 24.48 on the common frame.

    ``Lambda_N(k) = Lambda(k) P{dtype(k) | dtype(k-1)}`` with ``P`` "the pignistic probability
    value on the declared target type dtype(k) derived from the updated mass of belief m".

    - ``declared=None``: ``max_i BetP{theta_i}`` on the frame of ``m``, ``dtype(k)`` being the
      TTT's estimate of 24.45 (the chapter's text; :class:`~hocnet.tracking.mht.MHT`'s
      ``type_term="estimate"``). This **depends on the frame**: on the 8-class video frame a
      track seen by the GMTI only spreads its wheeled-vehicle mass over six classes, so the
      factor is about six times smaller than on the GMTI frame (the chapter's 24.6.3 remark).
    - ``declared`` given: ``BetP{Omega(c)}`` (24.47 for the set ``A = Omega(c)``), ``c`` the
      class the report declares on its sensor's frame and ``Omega(c)`` its image in the frame
      of ``m`` (our addition; a singleton for a report already on the common frame, the block
      of the GMTI class for a GMTI report). This is the probability the fused belief gives to
      what the report says, whatever frame the report was made in.

    Args:
        m: updated bbas ``(..., 2**n)`` on the common frame.
        declared: ``None`` or integer class indices ``(...)`` on the sensor's frame (broadcast
            against the batch of ``m``).
        mapping: the sensor's refinement into the common frame (blocks or labels, see
            :func:`frame_mapping`, partition or not); ``None`` when the sensor reports on the
            common frame. Needs ``declared``.

    Returns:
        ``(...)`` float64 in ``[0, 1]``.

    Raises:
        TypeError, ValueError: bad bba, non-integer or out-of-range ``declared``, bad mapping.

    Examples:
        >>> m = torch.tensor([0, 0, 0, 0.7, 0, 0, 0, 0.3])  # GMTI "wheeled" = {t0, t1}, refined
        >>> round(float(type_likelihood(m)), 4)  # max fine BetP
        0.45
        >>> round(float(type_likelihood(m, torch.tensor(0), [0, 0, 1])), 4)  # BetP{t0, t1}
        0.9
    """
    m = _masses("m", m)
    n = _n_atoms("m", m.shape[-1])
    betp = pignistic(m)
    if declared is None:
        if mapping is not None:
            raise ValueError("`mapping`: expected None when `declared` is None, got a mapping")
        return betp.max(-1).values
    c = torch.as_tensor(declared)
    if c.is_floating_point() or c.is_complex() or c.dtype == torch.bool:
        raise TypeError(f"`declared`: expected integer class indices, got dtype {c.dtype}")
    c = c.long()
    if mapping is None:
        images = 1 << torch.arange(n)
    else:
        n_sensor = _n_sensor_classes(mapping, n)
        images = frame_mapping(mapping, n_sensor, n, partition=False)
    if c.numel() and bool(((c < 0) | (c >= images.shape[0])).any()):
        raise ValueError(
            f"`declared`: expected class indices in [0, {images.shape[0]}), got "
            f"{int(c.min())}..{int(c.max())}"
        )
    member = ((images[c].unsqueeze(-1) >> torch.arange(n)) & 1).to(DTYPE)  # (..., n)
    return (betp * member).sum(-1)


def _n_sensor_classes(mapping: Any, n_fine: int) -> int:
    """Number of coarse classes implied by blocks (their count) or labels (max + 1)."""
    if isinstance(mapping, torch.Tensor | np.ndarray):
        arr = torch.as_tensor(mapping)
        return int(arr.max()) + 1 if arr.numel() else 0
    items = list(mapping) if isinstance(mapping, Sequence) else []
    if items and all(_is_index(v) for v in items):
        return max(int(v) for v in items) + 1
    return len(items)


def report_type_likelihood(m: Any, report: Any) -> torch.Tensor:
    """``BetP`` of the updated bba on the set the report declares (24.48, our reading).

    The report's declared set ``A`` is its focal element of largest mass other than the whole
    frame (for an observed bba ``m_obs(A) = P{c}``, ``m_obs(Theta) = 1 - P{c}`` of 24.5.2 step b,
    refined to the common frame as in 24.5.3: a singleton for a video report, the block of the
    GMTI class for a GMTI report); the factor is ``BetP_m(A) = sum_{X} |X & A| / |X| m(X)``
    (24.47) of the *updated* bba ``m``. A report with no mass off ``Theta`` (vacuous) declares
    ``Theta`` and gives 1. Ties between focal elements of equal largest mass go to the lowest
    bitmask (``torch.argmax`` returns the first maximum; our choice: an observed bba of 24.5.2
    has a single focal element besides ``Theta``, so ties arise only in hand-made reports, e.g.
    ``m({t0}) = m({t1})`` declares ``{t0}``). This is :func:`type_likelihood` with the declared
    class and the sensor's mapping read off the report's bba, so it works on reports of mixed
    sensors already on the common frame.

    Why (issue 12, ours): ``max BetP`` of the updated bba (``type_likelihood(m)``, the chapter's
    text) measures how *certain* the track's type is, not whether the report *agrees* with it: a
    track whose bba is concentrated on a wrong class scores higher on a GMTI "wheeled" report
    than the right track whose bba is spread over two wheeled classes (seed 2424 of the
    chapter's scenario, t = 940 s: target 4's track, left behind at a junction beside target 3's
    track, 1.00 against 0.57). Measured (``experiments/results/pd-pcr5-diag.md``): not better
    than ``max BetP`` on the scenario's runs, so the MHT's default stays the chapter's reading.

    Args:
        m: updated bbas ``(..., 2**n)`` (e.g. ``pcr5(track, report)``).
        report: the reports' observed bbas ``(..., 2**n)`` on the same frame (broadcast).

    Returns:
        ``(...)`` float64 in ``[0, 1]``.

    Raises:
        TypeError, ValueError: bad bbas, different frames.

    Examples:
        >>> rep = torch.tensor([0, 0, 0, 0.7, 0, 0, 0, 0.3])  # declares {t0, t1}
        >>> round(float(report_type_likelihood(pcr5(vacuous(3), rep), rep)), 4)  # 0.7 + 0.3 * 2/3
        0.9
        >>> track = torch.tensor([0, 0, 0, 0, 0.9, 0, 0, 0.1])  # sure it is t2
        >>> round(float(report_type_likelihood(pcr5(track, rep), rep)), 4)
        0.3656
    """
    m = _masses("m", m)
    report = _masses("report", report)
    size = _same_frame(("m", m), ("report", report))
    n = _n_atoms("m", size)
    off = report.clone()
    off[..., size - 1] = -1.0  # never pick Theta unless nothing else has mass
    off[..., 0] = -1.0
    best = off.argmax(-1)
    has = off.gather(-1, best.unsqueeze(-1)).squeeze(-1) > 0
    mask = torch.where(has, best, torch.full_like(best, size - 1))
    member = ((mask.unsqueeze(-1) >> torch.arange(n)) & 1).to(DTYPE)  # (..., n)
    betp = pignistic(m)
    betp, member = torch.broadcast_tensors(betp, member)
    return (betp * member).sum(-1)

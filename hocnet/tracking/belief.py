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
"""

from __future__ import annotations

import itertools
from collections.abc import Hashable, Mapping, Sequence
from typing import Any

import torch

from hocnet._check import check_int, check_number
from hocnet.tracking.kalman import DTYPE, as_float64

__all__ = [
    "conjunctive",
    "dempster",
    "from_dict",
    "observed_bba",
    "pcr5",
    "pcr5_sources",
    "pignistic",
    "to_dict",
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

"""The information matrix of a calibration: rank, pseudo-inverse, degree, pruning.

One routine and one tolerance for everything that asks whether the data
determine the parameters: the solvers, the Cramér-Rao bound, the
observability analysis and the selection.

* :func:`pseudo_inverse`: rank, null space, undetermined parameters and the
  pseudo-inverse of an information matrix, after Jacobi scaling, with
  :data:`RANK_TOLERANCE`.
* :func:`observability`: rank and observability degree of an information
  matrix (paper 001 eq. 11, after Jacobi scaling).
* :func:`degree` and :func:`greedy_prune_information`: paper 001 eq. 11-12.
* :func:`solve_normal_equations`: the (weighted) least-squares solution
  ``(H^T W H)^-1 H^T W z`` (paper 001 eq. 10, paper 003 eq. 19 corrected), with
  the rank exposed and rank-deficient directions left at zero.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graphcal.data.calibration import Observability

#: Relative eigenvalue threshold (of the Jacobi-scaled information matrix) below
#: which a direction counts as unobservable.
RANK_TOLERANCE = 1e-9
#: A parameter whose component in the null space exceeds this is undetermined.
NULL_SPACE_WEIGHT = 1e-6
#: Observability degree below which a warning names the weakly determined parameters.
#: Paper 001's path-2 geometry, where WLS fails, has Deg ~ 1e-5; path 1 ~ 2e-3.
WEAK_DEGREE = 1e-4


def jacobi_scale(information: NDArray[np.float64]) -> NDArray[np.float64]:
    """``1/sqrt(diag(A))`` (1 where the diagonal is zero), for unit-free scaling."""
    d = np.diag(information).copy()
    d[d <= 0] = 1.0
    return 1.0 / np.sqrt(d)


@dataclass(frozen=True)
class PseudoInverse:
    """Pseudo-inverse of an information matrix and what the data leave undetermined.

    Attributes
    ----------
    covariance : ndarray (p, p)
        ``A^+`` through the Jacobi scaling ``S``: ``S (S A S)^+ S``, the
        directions below :data:`RANK_TOLERANCE` left out.
    rank : int
        Numerical rank of ``S A S``.
    null_space : ndarray (p, p - rank)
        Orthonormal basis of the unresolved directions (scaled basis).
    undetermined : ndarray of bool (p,)
        Parameters that an unresolved direction touches, or with no information.
    """

    covariance: NDArray[np.float64]
    rank: int
    null_space: NDArray[np.float64]
    undetermined: NDArray[np.bool_]


def pseudo_inverse(information: NDArray[np.float64]) -> PseudoInverse:
    """Rank, null space and pseudo-inverse of an information matrix (Jacobi-scaled).

    Parameters
    ----------
    information : ndarray (p, p)
        Symmetric positive semi-definite information matrix, any units.
    """
    p = information.shape[0]
    if p == 0:
        return PseudoInverse(np.zeros((0, 0)), 0, np.zeros((0, 0)), np.zeros(0, dtype=bool))
    s = jacobi_scale(information)
    scaled = information * np.outer(s, s)
    w, v = np.linalg.eigh(0.5 * (scaled + scaled.T))
    top = max(float(w[-1]), 0.0)
    good = w > RANK_TOLERANCE * top if top > 0 else np.zeros(p, dtype=bool)
    covariance = ((v[:, good] / w[good]) @ v[:, good].T) * np.outer(s, s)
    null_space = v[:, ~good]
    weight = np.sqrt(np.sum(null_space**2, axis=1)) if null_space.size else np.zeros(p)
    undetermined = (weight > NULL_SPACE_WEIGHT) | (np.diag(information) <= 0)
    return PseudoInverse(covariance, int(good.sum()), null_space, undetermined)


def observability(
    information: NDArray[np.float64], scale: NDArray[np.float64] | None = None
) -> Observability:
    """Rank and observability degree of an information matrix ``A``.

    ``Deg = lambda_min / lambda_max`` of ``S A S`` with ``S = diag(scale)``
    (paper 001 eq. 11; ``scale`` defaults to the Jacobi scaling of ``A``).
    """
    n = information.shape[0]
    if n == 0:
        return Observability(degree=0.0, rank=0, n_parameters=0)
    s = jacobi_scale(information) if scale is None else scale
    scaled = information * np.outer(s, s)
    eigenvalues, vectors = np.linalg.eigh(scaled)
    top = max(eigenvalues[-1], 0.0)
    rank = int(np.sum(eigenvalues > RANK_TOLERANCE * top)) if top > 0 else 0
    degree = float(max(eigenvalues[0], 0.0) / top) if top > 0 else 0.0
    return Observability(
        degree=degree,
        rank=rank,
        n_parameters=n,
        eigenvalues=eigenvalues,
        weakest_direction=vectors[:, 0],
    )


@dataclass
class LinearSolution:
    """Solution of the normal equations with its covariance and figures."""

    estimate: NDArray[np.float64]
    covariance: NDArray[np.float64]
    observability: Observability
    singular_values: NDArray[np.float64]


def solve_normal_equations(
    information: NDArray[np.float64],
    rhs: NDArray[np.float64],
    middle: NDArray[np.float64] | None = None,
) -> LinearSolution:
    """Solve ``A x = b`` by a rank-revealing eigen-decomposition of the scaled ``A``.

    Parameters
    ----------
    information : ndarray (p, p)
        ``A = H^T W H``.
    rhs : ndarray (p,)
        ``b = H^T W z``.
    middle : ndarray (p, p), optional
        ``H^T W Sigma W H`` for a sandwich covariance ``A^-1 M A^-1`` when the
        weights ``W`` are not the inverse noise covariance ``Sigma^-1`` (e.g. the
        unweighted LS of paper 003).  Without it the covariance is ``A^-1``.

    Returns
    -------
    LinearSolution
        Unobservable directions (eigenvalue below :data:`RANK_TOLERANCE`) get
        zero estimate and infinite variance.
    """
    s = jacobi_scale(information)
    scaled = information * np.outer(s, s)
    eigenvalues, vectors = np.linalg.eigh(scaled)
    top = max(eigenvalues[-1], 0.0) if len(eigenvalues) else 0.0
    good = eigenvalues > RANK_TOLERANCE * top if top > 0 else np.zeros_like(eigenvalues, bool)
    inv_scaled = (vectors[:, good] / eigenvalues[good]) @ vectors[:, good].T
    a_inv = inv_scaled * np.outer(s, s)
    estimate = a_inv @ rhs
    covariance = a_inv if middle is None else a_inv @ middle @ a_inv
    covariance = 0.5 * (covariance + covariance.T)
    if not np.all(good):
        # Give unobservable directions infinite variance on the parameters they touch.
        touched = np.any(np.abs(vectors[:, ~good]) > 1e-6, axis=1)
        covariance[touched, :] = np.nan
        covariance[:, touched] = np.nan
        covariance[touched, touched] = np.inf
    return LinearSolution(
        estimate=estimate,
        covariance=covariance,
        observability=observability(information, s),
        singular_values=np.sqrt(np.clip(eigenvalues, 0.0, None)),
    )


def describe_weak_directions(
    labels: list[tuple[str, str]], obs: Observability, threshold: float = WEAK_DEGREE
) -> list[str]:
    """Plain-language warnings for directions the data hardly determine."""
    warnings = []
    if obs.rank < obs.n_parameters:
        warnings.append(
            f"the data determine only {obs.rank} of {obs.n_parameters} parameters "
            "(rank-deficient information matrix)"
        )
    if obs.n_parameters and obs.degree < threshold:
        v = obs.weakest_direction
        involved = [
            f"{rid} {name.replace('_', ' ')}"
            for (rid, name), c in zip(labels, v, strict=True)
            if abs(c) > 0.3
        ]
        warnings.append(
            "weakly observable combination (observability degree "
            f"{obs.degree:.2g}): " + ", ".join(involved) + " cannot be told apart with this traffic"
        )
    return warnings


def degree(information: NDArray[np.float64]) -> float:
    """``Deg = lambda_min / lambda_max`` of an (already scaled) information matrix."""
    w = np.linalg.eigvalsh(information)
    return float(max(w[0], 0.0) / w[-1]) if w[-1] > 0 else 0.0


def greedy_prune_information(
    information: NDArray[np.float64], progress: Callable[[int, int], None] | None = None
) -> tuple[NDArray[np.bool_], list[float]]:
    """Paper 001 eq. 12 on units given by their (scaled) information, in the given order.

    Unit ``k`` is removed when ``Deg(A - A_k) > Deg(A)``; ``A`` is downdated
    by ``A_k`` (the sum of the unit's rank-one terms), not recomputed.

    Parameters
    ----------
    information : ndarray (u, p, p)
        Each unit's information, already scaled (e.g. Jacobi-scaled by the full set).
    progress : callable, optional
        ``progress(done, total)``.

    Returns
    -------
    keep : ndarray of bool (u,)
    degree_trace : list of float
        ``Deg`` after each visit.
    """
    a = information.sum(axis=0)
    current = degree(a)
    keep = np.ones(len(information), dtype=bool)
    trace = []
    total = len(information)
    for k in range(total):
        candidate = a - information[k]
        deg = degree(candidate)
        if deg > current:  # eq. 12: Deg(k) < Deg(k - 1) -> remove observation k
            a, current = candidate, deg
            keep[k] = False
        trace.append(current)
        if progress is not None and (k % 500 == 0 or k == total - 1):
            progress(k + 1, total)
    return keep, trace

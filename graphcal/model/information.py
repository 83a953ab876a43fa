"""Shared linear-algebra pieces of the closed-form estimators.

* :class:`ParameterLayout`: which bias of which radar sits in which column.
* :func:`observability`: rank and observability degree of an information
  matrix (paper 001 eq. 11, after Jacobi scaling).
* :func:`solve_normal_equations`: the (weighted) least-squares solution
  ``(H^T W H)^-1 H^T W z`` (paper 001 eq. 10, paper 003 eq. 19 corrected), with
  the rank exposed and rank-deficient directions left at zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graphcal.data.bias import PARAMETER_NAMES
from graphcal.data.calibration import Observability
from graphcal.data.dataset import Site

#: Relative eigenvalue threshold (of the Jacobi-scaled information matrix) below
#: which a direction counts as unobservable.
RANK_TOLERANCE = 1e-10
#: Observability degree below which a warning names the weakly determined parameters.
#: Paper 001's path-2 geometry, where WLS fails, has Deg ~ 1e-5; path 1 ~ 2e-3.
WEAK_DEGREE = 1e-4


@dataclass(frozen=True)
class ParameterLayout:
    """Columns of the joint state vector: one block per radar, its estimated biases."""

    labels: tuple[tuple[str, str], ...]

    @classmethod
    def for_sites(cls, sites: list[Site], allowed: tuple[str, ...] = PARAMETER_NAMES):
        """Layout for ``sites``, keeping each site's ``estimate`` list within ``allowed``."""
        labels = []
        for site in sites:
            for name in PARAMETER_NAMES:
                if name in site.estimate and name in allowed:
                    if name == "elevation_bias" and not site.is_3d:
                        continue
                    labels.append((site.id, name))
        return cls(tuple(labels))

    def __len__(self) -> int:
        return len(self.labels)

    def columns(self, radar_id: str) -> tuple[list[int], list[int]]:
        """``(state columns, bias-vector positions)`` of one radar.

        Bias-vector positions index :data:`graphcal.data.bias.PARAMETER_NAMES`.
        """
        cols, positions = [], []
        for i, (rid, name) in enumerate(self.labels):
            if rid == radar_id:
                cols.append(i)
                positions.append(PARAMETER_NAMES.index(name))
        return cols, positions


def jacobi_scale(information: NDArray[np.float64]) -> NDArray[np.float64]:
    """``1/sqrt(diag(A))`` (1 where the diagonal is zero), for unit-free scaling."""
    d = np.diag(information).copy()
    d[d <= 0] = 1.0
    return 1.0 / np.sqrt(d)


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

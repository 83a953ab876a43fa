"""Greedy data pruning of paper 001 eq. 12 and the observability degree eq. 11."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.model.information import jacobi_scale, observability, solve_normal_equations
from graphcal.solvers.wls import greedy_prune


def _degree(h: np.ndarray, scale: np.ndarray) -> float:
    """Deg of sum h^T h, recomputed from scratch (the second implementation)."""
    a = np.einsum("mip,miq->pq", h, h) * np.outer(scale, scale)
    ev = np.linalg.eigvalsh(a)
    return ev[0] / ev[-1]


def test_greedy_pruning_follows_eq12_against_a_recomputing_implementation() -> None:
    """Downdated Deg equals Deg recomputed from the kept set; the rule is applied in order."""
    rng = np.random.default_rng(0)
    m, p = 120, 4
    h = rng.normal(size=(m, 3, p))
    h[:80, :, 0] *= 5.0  # crowded observations dominating one direction
    keep, trace = greedy_prune(h)
    scale = jacobi_scale(np.einsum("mip,miq->pq", h, h))
    # Reference: the same greedy loop with full recomputation.
    ref_keep = np.ones(m, dtype=bool)
    current = _degree(h, scale)
    for k in range(m):
        trial = ref_keep.copy()
        trial[k] = False
        deg = _degree(h[trial], scale)
        if deg > current:
            ref_keep, current = trial, deg
    assert np.array_equal(keep, ref_keep)
    assert trace[-1] == pytest.approx(current, rel=1e-9)
    assert trace[-1] >= _degree(h, scale)
    assert (~keep).sum() > 0


def test_observability_degree_is_unit_free_and_rank_is_exposed() -> None:
    """Deg after Jacobi scaling does not change when a parameter changes units."""
    rng = np.random.default_rng(1)
    h = rng.normal(size=(50, 3))
    a = h.T @ h
    units = np.diag([1.0, 1e-3, 1e3])
    a_units = units @ a @ units
    assert observability(a).degree == pytest.approx(observability(a_units).degree, rel=1e-9)
    assert observability(a).rank == 3
    singular = a.copy()
    singular[2, :] = singular[1, :]
    singular[:, 2] = singular[:, 1]
    assert observability(singular).rank == 2


def test_rank_deficient_solution_marks_undetermined_parameters() -> None:
    """Two columns that cannot be told apart get infinite variance, not a number."""
    rng = np.random.default_rng(2)
    h = rng.normal(size=(40, 3))
    h[:, 2] = 2.0 * h[:, 1]
    z = h @ np.array([1.0, 0.5, 0.25]) + rng.normal(0, 0.01, 40)
    sol = solve_normal_equations(h.T @ h, h.T @ z)
    assert sol.observability.rank == 2
    assert np.isinf(sol.covariance[1, 1]) and np.isinf(sol.covariance[2, 2])
    assert np.isfinite(sol.covariance[0, 0])
    assert sol.estimate[0] == pytest.approx(1.0, abs=0.01)

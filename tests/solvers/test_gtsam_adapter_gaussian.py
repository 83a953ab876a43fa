"""FactorGraph.add_gaussian: a dense Gaussian summary over several keys, assembled from
GTSAM's at-most-three-key HessianFactors, gives the numpy solution and covariance."""

from __future__ import annotations

import numpy as np

from graphcal.solvers.gtsam_adapter import FactorGraph, symbol


def test_a_gaussian_over_four_keys_solves_like_numpy() -> None:
    rng = np.random.default_rng(0)
    sizes = [2, 3, 1, 2]
    n = sum(sizes)
    jac = rng.normal(size=(30, n))
    information = jac.T @ jac
    vector = jac.T @ rng.normal(size=30)
    point = rng.normal(size=n)
    edges = np.cumsum([0, *sizes])
    keys = [symbol("t", i) for i in range(4)]
    fg = FactorGraph()
    for i, key in enumerate(keys):
        fg.add_variable(key, np.zeros(sizes[i]))
    fg.add_gaussian(keys, information, vector,
                    [point[edges[i]:edges[i + 1]] for i in range(4)])
    result = fg.solve_linear()
    solved = np.concatenate([result.vector(k) for k in keys])
    np.testing.assert_allclose(solved, point + np.linalg.solve(information, vector),
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(fg.joint_covariance(result.values, keys),
                               np.linalg.inv(information), rtol=1e-7, atol=1e-12)

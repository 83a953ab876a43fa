""":func:`graphcal.data.calibration.covariance_problem`: valid covariances pass, broken ones
are named.  Expectations by construction: ``V diag(lambda) V^T`` has the signs of ``lambda``
as eigenvalue signs, and so (Sylvester's law of inertia) has its correlation matrix."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.data.calibration import covariance_problem

LABELS = ["A.range_offset_m", "A.range_gain", "B.range_offset_m", "B.azimuth_bias_mrad"]


def _with_eigenvalues(values: list[float], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(len(values), len(values))))
    scale = np.diag([10.0, 1e-4, 3.0, 0.05])  # contract units differ by orders of magnitude
    return scale @ (q @ np.diag(values) @ q.T) @ scale


@pytest.mark.parametrize("seed", range(5))
def test_positive_definite_and_singular_pass(seed: int) -> None:
    assert covariance_problem(_with_eigenvalues([5.0, 4.0, 3.0, 0.5], seed), LABELS) is None
    singular = _with_eigenvalues([5.0, 4.0, 3.0, 0.0], seed)
    assert covariance_problem(singular, LABELS) is None


@pytest.mark.parametrize("seed", range(5))
def test_a_negative_eigenvalue_is_refused(seed: int) -> None:
    matrix = _with_eigenvalues([5.0, 4.0, 3.0, -0.5], seed)
    if np.any(np.diag(matrix) <= 0):
        pytest.skip("this draw has a negative variance: another check")
    assert "not positive semi-definite" in covariance_problem(matrix, LABELS)


def test_negative_variance_asymmetry_and_undetermined_rows() -> None:
    matrix = _with_eigenvalues([5.0, 4.0, 3.0, 0.5], 0)
    negative = matrix.copy()
    negative[2, 2] = -1.0
    assert covariance_problem(negative, LABELS) == "negative variance -1 of B.range_offset_m"
    asymmetric = matrix.copy()
    asymmetric[0, 3] += 1e-3 * np.sqrt(matrix[0, 0] * matrix[3, 3])
    assert "not symmetric" in covariance_problem(asymmetric, LABELS)
    assert "A.range_offset_m" in covariance_problem(asymmetric, LABELS)
    undetermined = matrix.copy()
    undetermined[1, :] = undetermined[:, 1] = np.nan  # null in the JSON: infinite variance
    assert covariance_problem(undetermined, LABELS) is None
    rounded = matrix * (1.0 + 1e-9)  # what printing 9 digits would do
    assert covariance_problem(rounded, LABELS) is None

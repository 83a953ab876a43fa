"""Robust kernels applied per measurement inside the vectorised factors.

A vectorised factor holds many measurements (a whole radar's plots); GTSAM's
own robust noise models act on a factor's whole error, so the kernel is applied
here, to each measurement's whitened residual ``r_i`` (2 or 3 components) of
norm ``s_i = ||r_i||``, the way GTSAM's ``noiseModel.Robust`` does for one
factor:

* the cost is ``sum_i rho(s_i)``: the error returned for cost evaluation is
  ``r_i sqrt(2 rho(s_i)) / s_i`` so that ``0.5 ||e||^2 = sum rho``;
* linearisation is iteratively re-weighted: error and Jacobian rows scaled
  by ``sqrt(w(s_i))`` with ``w = rho'(s) / s`` (Zhang's M-estimator tutorial;
  GTSAM ``mEstimator``).

At convergence this is the M-estimate, and the marginal covariance from the
re-weighted information is the usual asymptotic one.

Kernels, with threshold ``k`` in units of sigma:

=========  ===================================  ========================================
name       rho(s)                                 w(s)
=========  ===================================  ========================================
none       s^2 / 2                               1
huber      s^2 / 2 (s <= k), k s - k^2 / 2       1 (s <= k), k / s
cauchy     k^2 / 2 log(1 + s^2 / k^2)           1 / (1 + s^2 / k^2)
=========  ===================================  ========================================

The default threshold is the 95 % point of the chi distribution of a
measurement's dimension (2.45 for range-azimuth, 2.80 for 3-D), so that
clean data are hardly down-weighted.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from graphcal.core import frames

FloatArray = NDArray[np.float64]

#: Kernel names accepted by :class:`RobustKernel`.
KERNELS: tuple[str, ...] = ("huber", "cauchy", "none")
#: A measurement whose final weight is below this counts as down-weighted.
DOWNWEIGHT_THRESHOLD = 0.5


@lru_cache(maxsize=8)
def default_threshold(dimension: int) -> float:
    """95 % point of the chi distribution with ``dimension`` degrees of freedom
    (``scipy.special.chdtri``: the chi-square quantile, without scipy.stats' import)."""
    from scipy import special

    return float(np.sqrt(special.chdtri(dimension, 0.05)))


@dataclass(frozen=True)
class RobustKernel:
    """A robust kernel: ``name`` in :data:`KERNELS`, ``scale`` multiplies the default threshold."""

    name: str = "huber"
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.name not in KERNELS:
            raise ValueError(
                f"unknown robust kernel '{self.name}'; use one of: {', '.join(KERNELS)}"
            )
        if not self.scale > 0:
            raise ValueError(f"robust kernel scale must be positive, got {self.scale}")

    def threshold(self, dimension: int) -> float:
        """Threshold ``k`` [sigma] for measurements of ``dimension`` components."""
        return self.scale * default_threshold(dimension)

    def weight(self, s: FloatArray, dimension: int) -> FloatArray:
        """IRLS weight ``w(s) = rho'(s) / s``."""
        s = np.asarray(s, dtype=float)
        k = self.threshold(dimension)
        if self.name == "huber":
            return np.where(s <= k, 1.0, k / np.maximum(s, 1e-300))
        if self.name == "cauchy":
            return 1.0 / (1.0 + (s / k) ** 2)
        return np.ones_like(s)

    def loss(self, s: FloatArray, dimension: int) -> FloatArray:
        """``rho(s)``; ``s^2 / 2`` near zero for every kernel."""
        s = np.asarray(s, dtype=float)
        k = self.threshold(dimension)
        if self.name == "huber":
            return np.where(s <= k, 0.5 * s**2, k * s - 0.5 * k**2)
        if self.name == "cauchy":
            return 0.5 * k**2 * np.log1p((s / k) ** 2)
        return 0.5 * s**2

    def apply(
        self, residual: FloatArray, jacobians: list[FloatArray] | None, *,
        in_place: bool = False,
    ) -> tuple[FloatArray, list[FloatArray] | None]:
        """Robustify whitened residuals ``(n, m)`` and their Jacobians ``(n, m, p)``.

        Without Jacobians (cost evaluation) returns ``r sqrt(2 rho(s)) / s``;
        with them (linearisation) returns ``sqrt(w) r`` and ``sqrt(w) J``.
        ``in_place``: scale the given arrays themselves (the caller's own, fresh ones),
        sparing the memory of a copy.
        """
        if self.name == "none":
            return residual, jacobians
        m = residual.shape[1]
        s = frames.row_norm(residual)
        if jacobians is None:
            scale = np.sqrt(2.0 * self.loss(s, m)) / np.where(s > 0, s, 1.0)
            scale = np.where(s > 0, scale, 1.0)
            return residual * scale[:, None], None
        root_w = np.sqrt(self.weight(s, m))
        if in_place:
            residual *= root_w[:, None]
            for j in jacobians:
                j *= root_w[:, None, None]
            return residual, jacobians
        return residual * root_w[:, None], [j * root_w[:, None, None] for j in jacobians]

    def downweighted(self, residual: FloatArray) -> NDArray[np.bool_]:
        """Measurements (rows of whitened ``residual``) whose weight is below 0.5."""
        if self.name == "none" or len(residual) == 0:
            return np.zeros(len(residual), dtype=bool)
        s = frames.row_norm(residual)
        return self.weight(s, residual.shape[1]) < DOWNWEIGHT_THRESHOLD

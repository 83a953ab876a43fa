"""The one place graphcal talks to GTSAM.

GTSAM's Python API is camelCase and works with keys, ``Values`` and factor
objects; the rest of graphcal works with numpy arrays and snake_case.  This
module wraps the few pieces the graph calibrator needs:

* vector-valued variables (a radar's biases, a target state),
* :class:`gtsam.CustomFactor` with a numpy error function (the vectorised
  factors of :mod:`graphcal.model.factors`),
* linear factors (constant-velocity motion, random walks) and Gaussian summaries
  (a time window's data reduced to its bias variables) as a
  :class:`gtsam.LinearContainerFactor` so they cost no Python call per iteration,
* Gaussian priors, Levenberg-Marquardt, and joint marginal covariances.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from graphcal.core.errors import EstimationError

FloatArray = NDArray[np.float64]

#: An error function: ``f(values_by_key, want_jacobians) -> (error, jacobians or None)``,
#: with ``values_by_key`` the current value of each of the factor's keys in order.
ErrorFunction = Callable[[list[FloatArray], bool], tuple[FloatArray, list[FloatArray] | None]]


class FactorGraph:
    """A nonlinear factor graph over vector-valued variables, with its initial values."""

    def __init__(self) -> None:
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()

    # ------------------------------------------------------------ variables
    def add_variable(self, key: int, initial: FloatArray) -> None:
        """Add a vector variable ``key`` with its initial value."""
        self._values.insert(int(key), np.asarray(initial, dtype=float))

    def has_variable(self, key: int) -> bool:
        """Whether ``key`` is a variable of the graph."""
        return bool(self._values.exists(int(key)))

    def set_initial(self, key: int, value: FloatArray) -> None:
        """Replace the initial value of variable ``key``."""
        self._values.update(int(key), np.asarray(value, dtype=float))

    # -------------------------------------------------------------- factors
    def add_custom(self, keys: Sequence[int], dimension: int, error: ErrorFunction) -> None:
        """Add a factor whose whitened error is computed in Python.

        The error function returns errors that are already whitened (unit
        noise), so the factor's noise model is the identity of ``dimension``.
        GTSAM asks for Jacobians only when it linearises.
        """
        keys = [int(k) for k in keys]

        def gtsam_error(
            this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list | None
        ) -> FloatArray:
            current = [values.atVector(k) for k in keys]
            e, jac = error(current, jacobians is not None)
            if jacobians is not None:
                assert jac is not None
                for i, block in enumerate(jac):
                    jacobians[i] = block
            return e

        noise = gtsam.noiseModel.Unit.Create(int(dimension))
        self._graph.add(gtsam.CustomFactor(noise, keys, gtsam_error))

    def add_linear(
        self, keys: Sequence[int], blocks: Sequence[FloatArray], rhs: FloatArray
    ) -> None:
        """Add the whitened linear factor ``sum_i blocks[i] x_i - rhs`` (unit noise).

        The factor is exact for vector variables: it is linearised at zero and
        GTSAM evaluates it at ``x - 0``.
        """
        rhs = np.asarray(rhs, dtype=float)
        noise = gtsam.noiseModel.Unit.Create(len(rhs))
        args: list = []
        point = gtsam.Values()
        for key, block in zip(keys, blocks, strict=True):
            args.extend([int(key), np.asarray(block, dtype=float)])
            point.insert(int(key), np.zeros(block.shape[1]))
        if not 1 <= len(keys) <= 3:
            raise ValueError("linear factors on one to three variables only")
        factor = gtsam.JacobianFactor(*args, rhs, noise)
        self._graph.add(gtsam.LinearContainerFactor(factor, point))

    def add_gaussian(
        self,
        keys: Sequence[int],
        information: FloatArray,
        vector: FloatArray,
        point: Sequence[FloatArray],
    ) -> None:
        """Add a Gaussian summary ``1/2 d^T L d - d^T eta`` on ``keys``, ``d = x - point``.

        ``information`` (``L``) and ``vector`` (``eta``) stack the keys' blocks in
        order, each as long as its ``point``.  GTSAM's ``HessianFactor`` takes at
        most three keys at once, so the summary is assembled from one factor per
        diagonal block and one per pair of keys (their sum is ``L``), merged into
        a single ``HessianFactor``, and held at ``point`` by a
        :class:`gtsam.LinearContainerFactor`.
        """
        keys = [int(k) for k in keys]
        sizes = [len(np.atleast_1d(p)) for p in point]
        edges = np.concatenate([[0], np.cumsum(sizes)])
        information = np.asarray(information, dtype=float)
        vector = np.asarray(vector, dtype=float)
        pieces = gtsam.GaussianFactorGraph()
        linearisation = gtsam.Values()
        for i, key in enumerate(keys):
            a = slice(edges[i], edges[i + 1])
            pieces.push_back(gtsam.HessianFactor(key, information[a, a], vector[a], 0.0))
            linearisation.insert(key, np.asarray(point[i], dtype=float))
            for j in range(i + 1, len(keys)):
                b = slice(edges[j], edges[j + 1])
                pieces.push_back(gtsam.HessianFactor(
                    key, keys[j], np.zeros((sizes[i], sizes[i])), information[a, b],
                    np.zeros(sizes[i]), np.zeros((sizes[j], sizes[j])), np.zeros(sizes[j]), 0.0))
        self._graph.add(gtsam.LinearContainerFactor(gtsam.HessianFactor(pieces), linearisation))

    def add_prior(self, key: int, mean: FloatArray, sigmas: FloatArray) -> None:
        """Add an independent Gaussian prior ``N(mean, diag(sigmas^2))`` on ``key``."""
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float))
        self._graph.add(gtsam.PriorFactorVector(int(key), np.asarray(mean, dtype=float), noise))

    def __len__(self) -> int:
        return int(self._graph.size())

    # ------------------------------------------------------------ solving
    def error(self, values: gtsam.Values | None = None) -> float:
        """Total error ``0.5 * sum ||whitened error||^2`` at ``values`` (default: initial)."""
        return float(self._graph.error(self._values if values is None else values))

    def optimize(
        self,
        max_iterations: int = 100,
        relative_tolerance: float = 1e-7,
        absolute_tolerance: float = 1e-9,
    ) -> OptimizationResult:
        """Levenberg-Marquardt from the initial values."""
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(int(max_iterations))
        params.setRelativeErrorTol(float(relative_tolerance))
        params.setAbsoluteErrorTol(float(absolute_tolerance))
        # Damping proportional to the Hessian diagonal: variables in metres and
        # radians differ by orders of magnitude.
        params.setDiagonalDamping(True)
        initial_error = self.error()
        optimizer = gtsam.LevenbergMarquardtOptimizer(self._graph, self._values, params)
        values = optimizer.optimize()
        iterations = int(optimizer.iterations())
        return OptimizationResult(
            values=values,
            iterations=iterations,
            initial_error=initial_error,
            final_error=float(optimizer.error()),
            converged=iterations < max_iterations,
        )

    def solve_linear(self) -> OptimizationResult:
        """One Gauss-Newton step from the initial values: exact when every factor is
        linear (random walks, Gaussian summaries, priors), with no stopping tolerance."""
        initial_error = self.error()
        delta = self._graph.linearize(self._values).optimize()
        values = self._values.retract(delta)
        return OptimizationResult(values=values, iterations=1, initial_error=initial_error,
                                  final_error=float(self._graph.error(values)), converged=True)

    def joint_covariance(self, values: gtsam.Values, keys: Sequence[int]) -> FloatArray:
        """Joint marginal covariance of ``keys`` at ``values`` (GTSAM ``Marginals``).

        Raises
        ------
        IndeterminateSystemError
            When GTSAM finds the linear system indeterminate (or too poorly
            conditioned to factorise) near one of the variables.
        """
        marginals = _marginals(self._graph, values)
        key_vector = gtsam.KeyVector()
        for k in keys:
            key_vector.append(int(k))
        joint = marginals.jointMarginalCovariance(key_vector)
        return np.block([[joint.at(int(a), int(b)) for b in keys] for a in keys])

    def marginal_covariances(self, values: gtsam.Values, keys: Sequence[int]
                             ) -> list[FloatArray]:
        """Each key's own marginal covariance, from one factorisation (GTSAM ``Marginals``)."""
        marginals = _marginals(self._graph, values)
        return [np.asarray(marginals.marginalCovariance(int(k)), dtype=float) for k in keys]


class IndeterminateSystemError(EstimationError):
    """GTSAM's ``IndeterminateSystemException``: the linear system at the solution is
    singular, or too poorly conditioned to factorise, near the variable ``key``."""

    def __init__(self, message: str, key: int | None) -> None:
        super().__init__(message)
        self.key = key


def _marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Marginals:
    """``gtsam.Marginals``, its indeterminate-system error as :class:`IndeterminateSystemError`."""
    try:
        return gtsam.Marginals(graph, values)
    except RuntimeError as exc:
        text = str(exc)
        if "Indeterminate" not in text:
            raise
        found = re.search(r"variable\s+(\d+)", text)
        key = int(found.group(1)) if found else None
        raise IndeterminateSystemError(
            "the linear system is indeterminate (or too poorly conditioned to factorise) at "
            "the solution", key) from None


class IncrementalGraph(FactorGraph):
    """A factor graph solved incrementally with GTSAM's ``ISAM2``.

    Variables and factors are added with the :class:`FactorGraph` methods; they wait
    until :meth:`update`, which hands them to ISAM2 and updates the estimate (only the
    part of the Bayes tree they touch is re-factored).  Suited to linear factors
    (random walks, Gaussian summaries, priors): one update gives the exact solution.
    """

    def __init__(self) -> None:
        super().__init__()
        self._isam = gtsam.ISAM2(gtsam.ISAM2Params())
        self._known: set[int] = set()

    def has_variable(self, key: int) -> bool:
        """Whether ``key`` is a variable (added, or waiting for :meth:`update`)."""
        return int(key) in self._known or super().has_variable(key)

    def update(self) -> None:
        """Hand the waiting variables and factors to ISAM2 and update the estimate."""
        self._isam.update(self._graph, self._values)
        self._known.update(int(k) for k in self._values.keys())
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()

    def vector(self, key: int) -> FloatArray:
        """The current estimate of variable ``key``."""
        return np.asarray(self._isam.calculateEstimateVector(int(key)), dtype=float)

    def covariance(self, key: int) -> FloatArray:
        """The marginal covariance of ``key`` given everything added so far."""
        return np.asarray(self._isam.marginalCovariance(int(key)), dtype=float)

    def joint_covariance_of(self, keys: Sequence[int]) -> FloatArray:
        """The joint marginal covariance of ``keys``."""
        key_vector = gtsam.KeyVector()
        for k in keys:
            key_vector.append(int(k))
        joint = self._isam.jointMarginalCovariance(key_vector)
        return np.block([[joint.at(int(a), int(b)) for b in keys] for a in keys])


@dataclass
class OptimizationResult:
    """Outcome of a Levenberg-Marquardt run."""

    values: gtsam.Values
    iterations: int
    initial_error: float
    final_error: float
    converged: bool

    def vector(self, key: int) -> FloatArray:
        """The optimised value of variable ``key``."""
        return np.asarray(self.values.atVector(int(key)), dtype=float)


def symbol(letter: str, index: int) -> int:
    """A GTSAM key made of a letter and an index (``b0`` for radar 0's biases, ...)."""
    return int(gtsam.symbol(letter, int(index)))

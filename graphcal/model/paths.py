"""Aircraft paths as cubic B-splines, and their exact elimination from the normal equations.

Every aircraft's path ``x(t)`` (three Cartesian coordinates in one local frame of
the network, metres) is a uniform cubic B-spline with knots every
``spacing_s`` seconds::

    x(t) = sum_j B_j(u) c_{k + j},    j = 0..3,   k = floor((t - t0) / spacing),
    u = (t - t0) / spacing - k,

with the uniform cubic basis ``B_0 = (1 - u)^3 / 6``, ``B_1 = (3u^3 - 6u^2 + 4) / 6``,
``B_2 = (-3u^3 + 3u^2 + 3u + 1) / 6``, ``B_3 = u^3 / 6``.  Its motion prior is the
nearly-constant-velocity model, white acceleration of spectral density ``q``
[m^2/s^3] per axis, whose negative log density is ``(1 / 2q) int |x''(t)|^2 dt``
(the cubic smoothing spline is the MAP path of that model): a quadratic form
``c^T Omega c / (2q)`` in the coefficients, exact for the spline.  ``q`` may change
from one flight phase to the next (:class:`PathLayout` ``phase``).

Unknowns are ordered path by path, coefficient by coefficient, axis by axis
(``3 * coefficient + axis``).  A measurement at time ``t`` touches the 12 unknowns
``3k .. 3k + 11`` and the prior couples coefficients at most three apart, so the
normal matrix of all paths together is one symmetric band matrix of half-bandwidth
:data:`HALF_BANDWIDTH` (paths do not couple: it is block diagonal in the band).
LAPACK's banded Cholesky (``scipy.linalg.cholesky_banded``) factorises it in
``O(n)``, and its banded triangular solve (``dtbtrs``) eliminates the paths from
the bias columns: the Schur complement of bundle adjustment's reduced camera
system, with no Python loop over aircraft or plots.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.linalg
import scipy.sparse
from numpy.typing import NDArray
from scipy.linalg import lapack

from graphcal.model import path_kernels

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Unknowns touched by one measurement: four coefficients of three axes.
LOCAL = 12
#: Half-bandwidth of the paths' normal matrix.
HALF_BANDWIDTH = LOCAL - 1

# Lower-triangle pairs (a >= c) of the 12 local unknowns.
_PAIR_A, _PAIR_C = np.tril_indices(LOCAL)
_COEF_A, _AXIS_A = np.divmod(_PAIR_A, 3)
_COEF_C, _AXIS_C = np.divmod(_PAIR_C, 3)


# The distinct entries ``M[a, b]``, ``a <= b``, of a symmetric 3x3 (axes) matrix.
_SYM3_A, _SYM3_B = np.triu_indices(3)


def basis(u: FloatArray) -> FloatArray:
    """Uniform cubic B-spline weights ``(n, 4)`` at the interval fractions ``u`` in [0, 1]
    (in one compiled pass when the compiled loops are used: the same values to rounding)."""
    u = np.asarray(u, dtype=float)
    if path_kernels.enabled() and u.ndim == 1:
        return path_kernels.compiled().basis(np.ascontiguousarray(u))
    u2, u3 = u * u, u * u * u
    return np.stack([(1.0 - u) ** 3, 3.0 * u3 - 6.0 * u2 + 4.0,
                     -3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0, u3], axis=-1) / 6.0


def basis_derivative(u: FloatArray) -> FloatArray:
    """``d B_j / d u`` ``(n, 4)`` (divide by the knot spacing for ``d / dt``)."""
    u = np.asarray(u, dtype=float)
    u2 = u * u
    return np.stack([-(1.0 - u) ** 2, 3.0 * u2 - 4.0 * u,
                     -3.0 * u2 + 2.0 * u + 1.0, u2], axis=-1) / 2.0


def _second_derivative_gram() -> FloatArray:
    """``G_ab = int_0^1 B_a''(u) B_b''(u) du`` (4, 4): the ``B''`` are linear in ``u``,
    so two-point Gauss-Legendre quadrature is exact."""
    nodes = 0.5 + np.array([-0.5, 0.5]) / np.sqrt(3.0)
    gram = np.zeros((4, 4))
    for u in nodes:
        second = np.array([1.0 - u, 3.0 * u - 2.0, 1.0 - 3.0 * u, u])
        gram += 0.5 * np.outer(second, second)
    return gram


#: ``int B_a'' B_b'' du`` over one knot interval (per unit spacing).
SECOND_DERIVATIVE_GRAM = _second_derivative_gram()


@dataclass(frozen=True)
class PathLayout:
    """Where every path's coefficients sit among the unknowns.

    Attributes
    ----------
    spacing_s : float
        Knot spacing [s].
    t0_s : ndarray (n_paths,)
        Time of each path's first knot [s].
    n_intervals : ndarray (n_paths,) of int
        Knot intervals of each path (coefficients: ``n_intervals + 3``).
    first_coefficient : ndarray (n_paths + 1,) of int
        Path ``p``'s coefficients are ``first_coefficient[p] : first_coefficient[p + 1]``.
    phase : ndarray (n_intervals_total,) of int
        The flight phase (a run of intervals of one path sharing one process noise)
        of each interval, intervals ordered path by path.
    n_phases : int
    vertical_phase : ndarray (n_intervals_total,) of int
        The same for the vertical axis's own process noise (shorter runs: an aircraft
        levels off in seconds).
    n_vertical_phases : int
    """

    spacing_s: float
    t0_s: FloatArray
    n_intervals: IntArray
    first_coefficient: IntArray
    phase: IntArray
    n_phases: int
    vertical_phase: IntArray
    n_vertical_phases: int

    @classmethod
    def build(cls, start_s: FloatArray, end_s: FloatArray, spacing_s: float,
              phase_s: float, vertical_phase_s: float | None = None) -> PathLayout:
        """Paths spanning ``[start_s, end_s]`` each, flight phases of ``phase_s`` seconds
        (the vertical axis's of ``vertical_phase_s``, by default the same)."""
        start_s = np.asarray(start_s, dtype=float)
        end_s = np.asarray(end_s, dtype=float)
        n_intervals = np.maximum(np.ceil((end_s - start_s) / spacing_s).astype(np.int64), 1)
        first = np.concatenate([[0], np.cumsum(n_intervals + 3)]).astype(np.int64)
        phase, n_phases = _phase_runs(n_intervals, phase_s / spacing_s)
        vertical, n_vertical = (phase, n_phases) if vertical_phase_s is None else _phase_runs(
            n_intervals, vertical_phase_s / spacing_s)
        return cls(float(spacing_s), start_s, n_intervals, first, phase, n_phases,
                   vertical, n_vertical)

    @property
    def n_paths(self) -> int:
        return len(self.t0_s)

    @property
    def n_coefficients(self) -> int:
        return int(self.first_coefficient[-1])

    @property
    def n_unknowns(self) -> int:
        return 3 * self.n_coefficients

    def locate(self, path: IntArray, time_s: FloatArray) -> tuple[IntArray, FloatArray]:
        """The first coefficient (global) and the fraction ``u`` of each time on its path.

        Times outside a path's knots are clamped to its first or last interval
        (``u`` then leaves [0, 1]: the cubic is extrapolated).
        """
        position = (time_s - self.t0_s[path]) / self.spacing_s
        interval = np.clip(np.floor(position), 0, self.n_intervals[path] - 1).astype(np.int64)
        return self.first_coefficient[path] + interval, position - interval

    def unknown_path(self) -> IntArray:
        """The path of every unknown ``(n_unknowns,)``."""
        per_path = 3 * np.diff(self.first_coefficient)
        return np.repeat(np.arange(self.n_paths), per_path)

    def interval_path(self) -> IntArray:
        """The path of every knot interval."""
        return np.repeat(np.arange(self.n_paths), self.n_intervals)

    @cached_property
    def interval_first(self) -> IntArray:
        """:meth:`interval_first_coefficient`, computed once."""
        return self.interval_first_coefficient()

    def interval_first_coefficient(self) -> IntArray:
        """The first coefficient of every knot interval (global)."""
        path = self.interval_path()
        local = np.arange(len(path)) - np.repeat(
            np.concatenate([[0], np.cumsum(self.n_intervals)[:-1]]), self.n_intervals)
        return self.first_coefficient[path] + local

    def unknown_phase(self, vertical: bool = False) -> IntArray:
        """The flight phase of every unknown: coefficient ``j`` of a path counts with its
        interval ``clip(j - 2, 0, n_intervals - 1)`` (the middle of its support); with
        ``vertical``, its vertical phase."""
        n_coef = np.diff(self.first_coefficient)
        path = np.repeat(np.arange(self.n_paths), n_coef)
        local = np.arange(self.n_coefficients) - self.first_coefficient[path]
        interval_offset = np.concatenate([[0], np.cumsum(self.n_intervals)[:-1]])
        interval = interval_offset[path] + np.clip(local - 2, 0, self.n_intervals[path] - 1)
        phase = self.vertical_phase if vertical else self.phase
        return np.repeat(phase[interval], 3)


    def evaluate(self, coefficients: FloatArray, first: IntArray, u: FloatArray,
                 derivative: bool = False) -> FloatArray:
        """Positions (or velocities [m/s] with ``derivative``) ``(n, 3)`` of the paths.

        ``coefficients``: ``(n_coefficients, 3)``; ``first`` and ``u`` from :meth:`locate`.
        """
        weights = (basis_derivative(u) / self.spacing_s) if derivative else basis(u)
        out = np.zeros((len(first), 3))
        for j in range(4):
            out += weights[:, j, None] * coefficients[first + j]
        return out


def _phase_runs(n_intervals: IntArray, intervals_per_phase: float) -> tuple[IntArray, int]:
    """Each interval's phase (runs of ``intervals_per_phase`` intervals within a path; the
    last run of a path may be up to twice as long rather than very short) and their
    number."""
    per_phase = max(int(round(intervals_per_phase)), 1)
    path_of_interval = np.repeat(np.arange(len(n_intervals)), n_intervals)
    interval_in_path = np.arange(int(n_intervals.sum())) - np.repeat(
        np.concatenate([[0], np.cumsum(n_intervals)[:-1]]), n_intervals)
    phases_per_path = np.maximum(n_intervals // per_phase, 1)
    local_phase = np.minimum(interval_in_path // per_phase,
                             phases_per_path[path_of_interval] - 1)
    first_phase = np.concatenate([[0], np.cumsum(phases_per_path)[:-1]])
    phase = first_phase[path_of_interval] + local_phase
    return phase.astype(np.int64), int(phases_per_path.sum())


# --------------------------------------------------------------------------- band assembly
def band_zeros(n_unknowns: int) -> FloatArray:
    """An empty lower band ``(HALF_BANDWIDTH + 1, n)``: ``band[d, i] = A[i + d, i]``.

    In Fortran order, as LAPACK takes it (no copy for the factorisation), each unknown's
    column of the band contiguous (the compiled sums touch one column at a time)."""
    return np.zeros((HALF_BANDWIDTH + 1, n_unknowns), order="F")


def band_to_dense(band: FloatArray) -> FloatArray:
    """The symmetric ``(n, n)`` matrix of a lower band (:func:`band_zeros`'s convention;
    for checks on small problems)."""
    n = band.shape[1]
    dense = np.zeros((n, n))
    for d in range(band.shape[0]):
        idx = np.arange(n - d)
        dense[idx + d, idx] = band[d, : n - d]
        dense[idx, idx + d] = band[d, : n - d]
    return dense


def spread_matrix(first: IntArray, weights: FloatArray, n_coefficients: int,
                  offset: int | None = None) -> scipy.sparse.csc_matrix:
    """The sparse ``P`` ``(n_coefficients, n)`` that spreads measurements over coefficients.

    Without ``offset``, ``P[first_i + j, i] = B_ij`` (``j = 0 .. 3``): ``P @ V`` sums each
    measurement's row ``V_i`` into its four coefficients, weighted by ``B_ij``.  With
    ``offset`` ``d``, ``P[first_i + j, i] = B_ij B_i(j + d)`` (``j = 0 .. 3 - d``): the
    products that the band's blocks ``d`` coefficients apart are made of.  One sparse
    product sums every measurement of a coefficient at once.  Every column of ``P`` has
    the same number of entries, so ``P`` is built column by column (compressed sparse
    columns) with no sorting.
    """
    j = np.arange(4 - (offset or 0))
    values = weights[:, j] if offset is None else weights[:, j] * weights[:, j + offset]
    rows = (np.asarray(first, dtype=np.int64)[:, None] + j).ravel()
    pointers = np.arange(0, len(rows) + 1, len(j), dtype=np.int64)
    return scipy.sparse.csc_matrix((values.ravel(), rows, pointers),
                                   shape=(n_coefficients, len(first)))


def add_measurement_blocks(band: FloatArray, first: IntArray, weights: FloatArray,
                           info: FloatArray) -> None:
    """Add ``sum_i (B_i B_i^T) kron M_i`` to the band, in place.

    ``first`` (n,) the first coefficient of each measurement, ``weights`` (n, 4) its
    B-spline weights, ``info`` (n, 3, 3) its information on the position
    (``H^T W H``, robust weight included).  For each distance ``d`` between two
    coefficients one sparse product (:func:`spread_matrix`) sums ``B_ij B_i(j+d)``
    times the six distinct entries of every ``M_i`` into the coefficients.
    """
    if len(first) == 0:
        return
    if path_kernels.enabled():
        path_kernels.compiled().add_blocks(band, _int64(first), _contiguous(weights),
                                           _contiguous(info))
        return
    n_coefficients = band.shape[1] // 3
    six = info[:, _SYM3_A, _SYM3_B]  # (n, 6): M[a, b] for a <= b
    for d in range(4):
        summed = spread_matrix(first, weights, n_coefficients, d) @ six  # (n_coef, 6)
        for k, (a, b) in enumerate(zip(_SYM3_A, _SYM3_B, strict=True)):
            # A[3(c + d) + b, 3c + a] and, off the diagonal blocks, its mirror.
            band[3 * d + b - a, a::3] += summed[:, k]
            if d > 0 and a != b:
                band[3 * d + a - b, b::3] += summed[:, k]


def add_motion_prior(band: FloatArray, layout: PathLayout, phase_scale: FloatArray,
                     vertical_scale: FloatArray | None = None) -> None:
    """Add ``Omega / q`` (the white-acceleration prior) to the band, in place.

    ``phase_scale`` (n_phases,): ``1 / q`` of every flight phase [s^3/m^2];
    ``vertical_scale`` (n_vertical_phases,): the vertical axis's (the network frame's up)
    by vertical phase, by default that of ``phase_scale``.
    """
    first = layout.interval_first
    horizontal = np.asarray(phase_scale, dtype=float)[layout.phase]
    vertical = horizontal if vertical_scale is None else np.asarray(
        vertical_scale, dtype=float)[layout.vertical_phase]
    scale = np.column_stack([horizontal, horizontal, vertical]) / layout.spacing_s**3
    if path_kernels.enabled():
        path_kernels.compiled().motion_prior(band, _int64(first), _contiguous(scale),
                                             SECOND_DERIVATIVE_GRAM)
        return
    same_axis = np.flatnonzero(_AXIS_A == _AXIS_C)
    gram = SECOND_DERIVATIVE_GRAM[_COEF_A[same_axis], _COEF_C[same_axis]]
    base = 3 * first
    for k, g in zip(same_axis, gram, strict=True):
        band[_PAIR_A[k] - _PAIR_C[k], base + _PAIR_C[k]] += scale[:, _AXIS_A[k]] * g


def motion_prior_energy(coefficients: FloatArray, layout: PathLayout,
                        per_axis: bool = False) -> FloatArray:
    """``int |x''|^2 dt`` of every interval ``(n_intervals_total,)`` [m^2/s^3]; with
    ``per_axis``, of every interval and axis ``(n_intervals_total, 3)``."""
    first = layout.interval_first
    c = np.stack([coefficients[first + j] for j in range(4)], axis=1)  # (k, 4, 3)
    energy = np.sum(c * (SECOND_DERIVATIVE_GRAM @ c), axis=1) / layout.spacing_s**3  # (k, 3)
    return energy if per_axis else energy.sum(axis=1)


def scatter_vectors(first: IntArray, weights: FloatArray, vectors: FloatArray,
                    n_unknowns: int) -> FloatArray:
    """``sum_i B_i kron v_i`` as a length-``n_unknowns`` vector (``vectors`` (n, 3))."""
    if len(first) == 0:
        return np.zeros(n_unknowns)
    if path_kernels.enabled():
        out = np.zeros(n_unknowns)
        path_kernels.compiled().scatter_vectors(out, _int64(first), _contiguous(weights),
                                                _contiguous(vectors))
        return out
    return np.asarray(spread_matrix(first, weights, n_unknowns // 3) @ vectors).ravel()


def scatter_columns(first: IntArray, weights: FloatArray, blocks: FloatArray,
                    columns: IntArray, out: FloatArray) -> None:
    """Add ``sum_i B_i kron K_i`` into the columns ``columns`` of ``out`` (n_unknowns, P).

    ``blocks`` (n, 3, k): each measurement's position-by-bias block (``H_x^T W H_b``).
    One sparse product (:func:`spread_matrix`) sums them into the coefficients; the
    coefficient-major, axis-minor rows are the unknowns' order.
    """
    if len(first) == 0 or blocks.shape[2] == 0:
        return
    n, k = len(first), blocks.shape[2]
    summed = spread_matrix(first, weights, out.shape[0] // 3) @ blocks.reshape(n, 3 * k)
    out[:, columns] += np.asarray(summed).reshape(out.shape[0], k)


def evaluate_paths(coefficients: FloatArray, first: IntArray, weights: FloatArray) -> FloatArray:
    """``sum_j weights_ij c_(first_i + j)`` ``(n, 3)``: the paths (or their rates, with the
    basis' derivatives as ``weights``) at the measurements."""
    if path_kernels.enabled():
        return path_kernels.compiled().evaluate(_contiguous(coefficients), _int64(first),
                                                _contiguous(weights))
    out = weights[:, 0, None] * coefficients[first]
    for j in range(1, 4):
        out += weights[:, j, None] * coefficients[first + j]
    return out


def weighted_squares(coefficients: FloatArray, first: IntArray, weights: FloatArray,
                     position: FloatArray, information: FloatArray) -> FloatArray:
    """``r_i^T M_i r_i`` ``(n,)`` of the paths' residuals at measured positions,
    ``r_i`` = :func:`evaluate_paths` ``- position_i`` (``information`` (n, 3, 3) the
    ``M_i``): each measurement's chi-square on the paths."""
    if path_kernels.enabled():
        return path_kernels.compiled().weighted_squares(
            _contiguous(coefficients), _int64(first), _contiguous(weights),
            _contiguous(position), _contiguous(information))
    residual = evaluate_paths(coefficients, first, weights) - position
    return np.einsum("ni,nij,nj->n", residual, information, residual)


def _contiguous(array: FloatArray) -> FloatArray:
    """``array`` as C-contiguous float64 (the type the compiled loops are made for)."""
    return np.ascontiguousarray(array, dtype=np.float64)


def _int64(array: IntArray) -> IntArray:
    return np.ascontiguousarray(array, dtype=np.int64)


def band_matvec(band: FloatArray, x: FloatArray) -> FloatArray:
    """``A x`` for the symmetric matrix whose lower band is ``band`` (x: (n,) or (n, k));
    for a vector in one compiled pass when the compiled loops are used."""
    if path_kernels.enabled() and x.ndim == 1:
        return path_kernels.compiled().band_matvec(np.asfortranarray(band, dtype=np.float64),
                                                   _contiguous(x))
    y = band[0].reshape((-1,) + (1,) * (x.ndim - 1)) * x
    for d in range(1, band.shape[0]):
        diagonal = band[d, :-d].reshape((-1,) + (1,) * (x.ndim - 1))
        y[d:] += diagonal * x[:-d]
        y[:-d] += diagonal * x[d:]
    return y


def check_factorised(info: int) -> None:
    """Raise :class:`numpy.linalg.LinAlgError` for a banded Cholesky's ``info`` other
    than 0 (the order of the first leading minor that is not positive, as LAPACK's and
    :func:`scipy.linalg.cholesky_banded`'s message says)."""
    if info != 0:
        raise np.linalg.LinAlgError(f"{info}-th leading minor not positive definite")


@dataclass
class BandFactor:
    """The banded Cholesky factor ``L`` (lower) of a path normal matrix."""

    lower: FloatArray
    _c: FloatArray | None = field(default=None, repr=False)

    @classmethod
    def of(cls, band: FloatArray, overwrite: bool = False) -> BandFactor:
        """Factorise (in ``band``'s memory with ``overwrite``);
        :class:`numpy.linalg.LinAlgError` when not positive definite.  With the
        compiled loops (:mod:`~graphcal.model.path_kernels`) by their banded Cholesky,
        else by LAPACK's (``dpbtrf``): the same factor, to rounding."""
        if not path_kernels.enabled():
            return cls(scipy.linalg.cholesky_banded(band, overwrite_ab=overwrite, lower=True,
                                                    check_finite=False))
        in_place = overwrite and band.flags.f_contiguous and band.dtype == np.float64
        lower = band if in_place else np.array(band, dtype=np.float64, order="F")
        check_factorised(path_kernels.compiled().band_cholesky(lower))
        return cls(lower, lower)

    def forward(self, rhs: FloatArray, overwrite: bool = False) -> FloatArray:
        """``L^-1 rhs`` (rhs (n,) or (n, k); in ``rhs``'s memory where it can with
        ``overwrite``)."""
        matrix = rhs.reshape(len(rhs), -1)
        if path_kernels.enabled() and matrix.shape[1] > 1:
            in_place = overwrite and matrix.flags.c_contiguous and matrix.dtype == np.float64
            out = matrix if in_place else np.array(matrix, dtype=np.float64, order="C")
            path_kernels.compiled().band_forward(self._lower_c(), out)
            return out.reshape(rhs.shape)
        out, info = lapack.dtbtrs(self.lower, np.asfortranarray(matrix), uplo="L")
        if info != 0:
            raise np.linalg.LinAlgError(f"banded triangular solve failed (info {info})")
        return out.reshape(rhs.shape)

    def _lower_c(self) -> FloatArray:
        """The factor as LAPACK gives it (Fortran order), for the compiled loops."""
        if self._c is None:
            self._c = np.asfortranarray(self.lower)
        return self._c

    def backward(self, rhs: FloatArray) -> FloatArray:
        """``L^-T rhs``: after :meth:`forward`, ``A^-1`` of the original right-hand side."""
        matrix = rhs.reshape(len(rhs), -1)
        out, info = lapack.dtbtrs(self.lower, np.asfortranarray(matrix), uplo="L", trans="T")
        if info != 0:
            raise np.linalg.LinAlgError(f"banded triangular solve failed (info {info})")
        return out.reshape(rhs.shape)

    def solve(self, rhs: FloatArray) -> FloatArray:
        """``A^-1 rhs``."""
        return scipy.linalg.cho_solve_banded((self.lower, True), rhs, check_finite=False)

    def log_diagonal(self) -> FloatArray:
        """``log L_ii`` of every unknown (``log det A = 2 sum``)."""
        return np.log(self.lower[0])

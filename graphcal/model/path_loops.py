"""The compiled loops of :mod:`graphcal.model.path_kernels`.

Importing this module loads Numba and compiles the loops, or loads them from its
cache: :mod:`graphcal.model.path_kernels` imports it only when the loops are used.
Each loop is the sum its name says, measurement by measurement; the conventions
(lower band ``band[d, i] = A[i + d, i]``, unknown ``3 k + axis``) are those of
:mod:`graphcal.model.paths`.
"""

from __future__ import annotations

import numba
import numpy as np

from graphcal.core.frames import WGS84_A_M as _A
from graphcal.core.frames import WGS84_B_M as _B
from graphcal.core.frames import WGS84_E2 as _E2
from graphcal.model.kernel_codes import TERM_ADDITIVE, TERM_RANGE_GAIN

_jit = numba.njit(cache=True, nogil=True)


@_jit
def add_block(band, base, weights, info):  # pragma: no cover - compiled
    """``band += (B B^T) kron M`` for one measurement whose first coefficient's first
    unknown is ``base`` (``weights`` its four ``B``, ``info`` the 3 x 3 ``M``)."""
    for a in range(4):
        wa = weights[a]
        column = base + 3 * a
        # The diagonal block: its lower triangle.
        waa = wa * wa
        for x in range(3):
            for y in range(x, 3):
                band[y - x, column + x] += waa * info[y, x]
        # The blocks below it, whole.
        for c in range(a + 1, 4):
            ww = wa * weights[c]
            offset = 3 * (c - a)
            for x in range(3):
                for y in range(3):
                    band[offset + y - x, column + x] += ww * info[y, x]


@_jit
def add_blocks(band, first, weights, info):  # pragma: no cover - compiled
    """``band += sum_i (B_i B_i^T) kron M_i`` (``info`` (n, 3, 3) the ``M_i``)."""
    for i in range(first.shape[0]):
        add_block(band, 3 * first[i], weights[i], info[i])


@_jit
def scatter_vectors(out, first, weights, vectors):  # pragma: no cover - compiled
    """``out += sum_i B_i kron v_i`` (``vectors`` (n, 3) the ``v_i``)."""
    for i in range(first.shape[0]):
        base = 3 * first[i]
        for a in range(4):
            wa = weights[i, a]
            for x in range(3):
                out[base + 3 * a + x] += wa * vectors[i, x]


@_jit
def evaluate(coefficients, first, weights):  # pragma: no cover - compiled
    """``sum_j weights_ij c_(first_i + j)`` ``(n, 3)``."""
    n = first.shape[0]
    out = np.zeros((n, 3))
    for i in range(n):
        for j in range(4):
            wj = weights[i, j]
            row = first[i] + j
            for x in range(3):
                out[i, x] += wj * coefficients[row, x]
    return out


@_jit
def accumulate(band, gradient, cross, bias_information, bias_gradient, first, weights,
               hx, hb, e, w, columns):  # pragma: no cover - compiled
    """One group of whitened linearised measurements ``e + Hx dx + Hb db`` with robust
    weights ``w`` into the normal equations: ``(B B^T) kron (Hx^T w Hx)`` into ``band``,
    ``B kron (Hx^T w e)`` into ``gradient``, ``B kron (Hx^T w Hb)`` into the bias
    ``columns`` of ``cross``, and ``Hb^T w Hb``, ``Hb^T w e`` into the bias information and
    gradient.  ``hx`` (n, m, 3), ``hb`` (n, m, k), ``e`` (n, m), ``w`` (n,).  A measurement's
    sums over its ``m`` rows are kept in scalars, and the zero entries of ``Hb`` (a bias
    term moves one coordinate) are skipped: the same sums."""
    n, m = e.shape[0], e.shape[1]
    k = columns.shape[0]
    info = np.zeros((3, 3))
    kx = np.zeros((3, k))
    bias_info = np.zeros((k, k))
    bias_grad = np.zeros(k)
    for i in range(n):
        wi = w[i]
        if wi == 0.0:
            continue
        i00 = i01 = i02 = i11 = i12 = i22 = 0.0
        g0 = g1 = g2 = 0.0
        for x in range(3):
            for b in range(k):
                kx[x, b] = 0.0
        for r in range(m):
            h0, h1, h2 = hx[i, r, 0], hx[i, r, 1], hx[i, r, 2]
            er = wi * e[i, r]
            g0 += h0 * er
            g1 += h1 * er
            g2 += h2 * er
            w0, w1, w2 = wi * h0, wi * h1, wi * h2
            i00 += w0 * h0
            i01 += w0 * h1
            i02 += w0 * h2
            i11 += w1 * h1
            i12 += w1 * h2
            i22 += w2 * h2
            for b in range(k):
                hrb = hb[i, r, b]
                if hrb == 0.0:
                    continue
                kx[0, b] += w0 * hrb
                kx[1, b] += w1 * hrb
                kx[2, b] += w2 * hrb
                whrb = wi * hrb
                bias_grad[b] += hrb * er
                for b2 in range(b, k):
                    bias_info[b, b2] += whrb * hb[i, r, b2]
        info[0, 0], info[1, 1], info[2, 2] = i00, i11, i22
        info[1, 0] = info[0, 1] = i01
        info[2, 0] = info[0, 2] = i02
        info[2, 1] = info[1, 2] = i12
        base = 3 * first[i]
        add_block(band, base, weights[i], info)
        for a in range(4):
            wa = weights[i, a]
            row = base + 3 * a
            gradient[row] += wa * g0
            gradient[row + 1] += wa * g1
            gradient[row + 2] += wa * g2
            for x in range(3):
                for b in range(k):
                    cross[row + x, columns[b]] += wa * kx[x, b]
    for b in range(k):
        bias_gradient[columns[b]] += bias_grad[b]
        for b2 in range(b, k):
            bias_information[columns[b], columns[b2]] += bias_info[b, b2]
            if b2 != b:
                bias_information[columns[b2], columns[b]] += bias_info[b, b2]


@_jit
def weighted_squares(coefficients, first, weights, position, information
                     ):  # pragma: no cover - compiled
    """``r_i^T M_i r_i`` ``(n,)`` of the residuals ``r_i = sum_j weights_ij
    c_(first_i + j) - position_i`` (``information`` (n, 3, 3) the ``M_i``)."""
    n = first.shape[0]
    out = np.empty(n)
    r = np.empty(3)
    for i in range(n):
        for x in range(3):
            r[x] = -position[i, x]
        for j in range(4):
            wj = weights[i, j]
            row = first[i] + j
            for x in range(3):
                r[x] += wj * coefficients[row, x]
        total = 0.0
        for x in range(3):
            mr = 0.0
            for y in range(3):
                mr += information[i, x, y] * r[y]
            total += r[x] * mr
        out[i] = total
    return out


@numba.njit(inline="always")
def _cholesky_column(band, j, width):  # pragma: no cover - compiled
    """Column ``j`` of the banded Cholesky factor, in place: scale the ``width``
    entries below the diagonal by its root and take their outer product from the
    next ``width`` columns.  ``False`` when the pivot is not positive."""
    pivot = band[0, j]
    if not pivot > 0.0:
        return False
    root = np.sqrt(pivot)
    band[0, j] = root
    inverse = 1.0 / root
    for d in range(1, width + 1):
        band[d, j] *= inverse
    for dq in range(1, width + 1):
        below = band[dq, j]
        column = j + dq
        for dp in range(dq, width + 1):
            band[dp - dq, column] -= band[dp, j] * below
    return True


@_jit
def band_cholesky(band):  # pragma: no cover - compiled
    """``band <- L`` in place, the lower Cholesky factor of the symmetric band matrix
    ``band[d, i] = A[i + d, i]`` (LAPACK's ``dpbtrf`` storage, Fortran order).

    Returns 0, or ``j + 1`` when the leading minor of order ``j + 1`` is not positive
    (as LAPACK's ``info``).  The half-bandwidths of the paths' bands (11; 3 for the
    heights alone) are unrolled as constants, two to three times faster than LAPACK's
    unblocked loop of level-2 calls for so narrow a band."""
    width = band.shape[0] - 1
    n = band.shape[1]
    body = max(n - width, 0)  # the columns with a full band below them
    if width == 11:
        for j in range(body):
            if not _cholesky_column(band, j, 11):
                return j + 1
    elif width == 3:
        for j in range(body):
            if not _cholesky_column(band, j, 3):
                return j + 1
    else:
        for j in range(body):
            if not _cholesky_column(band, j, width):
                return j + 1
    for j in range(body, n):
        if not _cholesky_column(band, j, n - 1 - j):
            return j + 1
    return 0


@_jit
def noise_likelihood_terms(data_band, unit_prior, scale, data_gradient, unit_gradient,
                           ridge, unknown_phase, n_phases, work):  # pragma: no cover
    """One process noise's terms of the paths' Laplace likelihood, by phase: the band
    ``A = data_band + scale unit_prior`` (its diagonal raised by ``ridge`` times its
    largest entry, at least 1) factorised as ``L L^T`` in ``work`` (Fortran order, the
    band's shape), ``z = L^-1 (data_gradient + scale unit_gradient)``, and per phase
    ``sum z^2 / 2`` and ``sum log L_ii`` over its unknowns (``unknown_phase``).

    Returns ``(info, reduction, log_det)``, ``info`` as :func:`band_cholesky`'s."""
    width1, n = data_band.shape
    largest = 1.0
    for j in range(n):
        for d in range(width1):
            work[d, j] = data_band[d, j] + scale * unit_prior[d, j]
        if work[0, j] > largest:
            largest = work[0, j]
    shift = ridge * largest
    for j in range(n):
        work[0, j] += shift
    reduction = np.zeros(n_phases)
    log_det = np.zeros(n_phases)
    info = band_cholesky(work)
    if info != 0:
        return info, reduction, log_det
    z = np.empty(n)
    for j in range(n):
        z[j] = data_gradient[j] + scale * unit_gradient[j]
    width = width1 - 1
    for j in range(n):
        z[j] /= work[0, j]
        for d in range(1, min(width, n - 1 - j) + 1):
            z[j + d] -= work[d, j] * z[j]
    for j in range(n):
        phase = unknown_phase[j]
        reduction[phase] += 0.5 * z[j] * z[j]
        log_det[phase] += np.log(work[0, j])
    return 0, reduction, log_det


@_jit
def band_forward(lower, rhs):  # pragma: no cover - compiled
    """``rhs <- L^-1 rhs`` in place (``rhs`` (n, k), C order), ``L`` lower triangular in band
    storage ``lower[d, i] = L[i + d, i]``: forward substitution, row by row, all the
    columns of a row at once."""
    n, k = rhs.shape[0], rhs.shape[1]
    width = lower.shape[0]
    for i in range(n):
        for d in range(1, min(i, width - 1) + 1):
            factor = lower[d, i - d]
            if factor != 0.0:
                for j in range(k):
                    rhs[i, j] -= factor * rhs[i - d, j]
        pivot = lower[0, i]
        for j in range(k):
            rhs[i, j] /= pivot


@_jit
def adsb_reports(ecef, sigma, origin, rotation, vertical_ratio, axes2):  # pragma: no cover
    """ADS-B reports in the network frame: positions ``R (x - origin)`` (n, 3) and
    information matrices (n, 3, 3), ``1 / sigma^2`` horizontally and
    ``1 / (vertical_ratio sigma)^2`` along the report's vertical (the ellipsoid's normal,
    the gradient of ``sum x_i^2 / axes2_i``, rotated into the frame)."""
    n = ecef.shape[0]
    position = np.zeros((n, 3))
    information = np.zeros((n, 3, 3))
    normal = np.zeros(3)
    up = np.zeros(3)
    for i in range(n):
        norm = 0.0
        for x in range(3):
            normal[x] = ecef[i, x] / axes2[x]
            norm += normal[x] * normal[x]
        norm = np.sqrt(norm)
        for x in range(3):
            p = 0.0
            u = 0.0
            for y in range(3):
                p += rotation[x, y] * (ecef[i, y] - origin[y])
                u += rotation[x, y] * normal[y]
            position[i, x] = p
            up[x] = u / norm
        horizontal = 1.0 / (sigma[i] * sigma[i])
        vertical = 1.0 / ((vertical_ratio * sigma[i]) * (vertical_ratio * sigma[i]))
        for x in range(3):
            for y in range(3):
                value = (vertical - horizontal) * up[x] * up[y]
                if x == y:
                    value += horizontal
                information[i, x, y] = value
    return position, information


@_jit
def adsb_sums(band, rhs, first, weights, position, information):  # pragma: no cover
    """The reports' share of the paths' normal equations: ``(B B^T) kron M`` into ``band``,
    ``B kron (M z)`` into ``rhs``; returns ``sum z^T M z / 2``."""
    constant = 0.0
    mz = np.zeros(3)
    for i in range(first.shape[0]):
        for x in range(3):
            v = 0.0
            for y in range(3):
                v += information[i, x, y] * position[i, y]
            mz[x] = v
            constant += 0.5 * position[i, x] * v
        base = 3 * first[i]
        add_block(band, base, weights[i], information[i])
        for a in range(4):
            for x in range(3):
                rhs[base + 3 * a + x] += weights[i, a] * mz[x]
    return constant


@_jit
def motion_prior(band, first, scale, gram):  # pragma: no cover - compiled
    """``band += sum_k G kron diag(scale_k)`` at interval ``k``'s four coefficients
    (``first`` its first coefficient, ``scale`` (k, 3) per axis, ``gram`` the 4 x 4
    ``int B'' B''``)."""
    for k in range(first.shape[0]):
        base = 3 * first[k]
        for low in range(4):
            for high in range(low, 4):
                g = gram[high, low]
                for x in range(3):
                    band[3 * (high - low), base + 3 * low + x] += scale[k, x] * g


_TWO_PI = 2.0 * np.pi


@numba.njit(inline="always")
def _wrap_to_2pi(angle):  # pragma: no cover - compiled
    """:func:`graphcal.core.frames.wrap_to_2pi` of one angle [rad]."""
    wrapped = angle - _TWO_PI * np.floor(angle / _TWO_PI)
    if wrapped < 0.0 or wrapped >= _TWO_PI:
        return 0.0
    return wrapped


@_jit
def plot_linearisation(coefficients, first, weights, rates, map_a, map_c, measured, ndim,
                       bias, whiten, term_row, term_kind):  # pragma: no cover - compiled
    """One radar's plots linearised on the paths, without refraction or eccentricity:
    what :meth:`graphcal.model.trajectory.TrajectoryBlock._radar_groups` forms with
    NumPy (the path's position ``p``, the radar's ENU ``A p + c``, the polar coordinates
    and their Jacobian, the bias model
    :func:`graphcal.model.measurement.biased_polar`), plot by plot.

    ``bias``: range offset [m], range gain, azimuth and elevation biases [rad];
    ``whiten`` (ndim,) the inverse sigmas; per free term ``k`` its column's kind
    (:data:`~graphcal.model.kernel_codes.TERM_ADDITIVE` on row ``term_row[k]``,
    ``TERM_RANGE_GAIN``, or ``TERM_TIME_OFFSET``: ``-(d h / d p) v``, ``v`` the path's
    velocity from the basis ``rates`` (n, 4), given when the time offset is free).

    Returns the whitened ``e`` (n, ndim), ``hx`` (n, ndim, 3) and ``hb`` (n, ndim, k),
    the positions (n, 3), the velocities (n, 3; zero without ``rates``) and the number
    of plots at the zenith (zero ground range, where the azimuth's Jacobian is
    undefined: their rows are left NaN).
    """
    n = first.shape[0]
    k = term_kind.shape[0]
    e = np.empty((n, ndim))
    hx = np.empty((n, ndim, 3))
    hb = np.zeros((n, ndim, k))
    position = evaluate(coefficients, first, weights)
    velocity = (evaluate(coefficients, first, rates) if rates.shape[0] == n
                else np.zeros((n, 3)))
    offset, gain, az_bias, el_bias = bias[0], bias[1], bias[2], bias[3]
    enu = np.empty(3)
    jac = np.empty((3, 3))
    residual = np.empty(3)
    zenith = 0
    for i in range(n):
        for x in range(3):
            enu[x] = (position[i, 0] * map_a[x, 0] + position[i, 1] * map_a[x, 1]
                      + position[i, 2] * map_a[x, 2]) + map_c[x]
        east, north, up = enu[0], enu[1], enu[2]
        g2 = east * east + north * north
        if g2 == 0.0:
            zenith += 1
            for r in range(ndim):
                e[i, r] = np.nan
                for x in range(3):
                    hx[i, r, x] = np.nan
            continue
        ground = np.hypot(east, north)
        range_m = np.sqrt(ground * ground + up * up)
        azimuth = _wrap_to_2pi(np.arctan2(east, north))
        elevation = np.arctan2(up, ground)
        g = np.sqrt(g2)
        r2 = g2 + up * up
        r = np.sqrt(r2)
        slope0 = 1.0 + gain
        jac[0, 0] = slope0 * (east / r)
        jac[0, 1] = slope0 * (north / r)
        jac[0, 2] = slope0 * (up / r)
        jac[1, 0] = north / g2
        jac[1, 1] = -east / g2
        jac[1, 2] = 0.0
        jac[2, 0] = -east * up / (r2 * g)
        jac[2, 1] = -north * up / (r2 * g)
        jac[2, 2] = g / r2
        residual[0] = (range_m * slope0 + offset) - measured[i, 0]
        residual[1] = _wrap_to_2pi((azimuth + az_bias) - measured[i, 1] + np.pi) - np.pi
        residual[2] = (elevation + el_bias) - measured[i, 2]
        for row in range(ndim):
            for x in range(3):
                hx[i, row, x] = (jac[row, 0] * map_a[0, x] + jac[row, 1] * map_a[1, x]
                                 + jac[row, 2] * map_a[2, x])
        for b in range(k):
            kind = term_kind[b]
            if kind == TERM_ADDITIVE:
                if term_row[b] < ndim:
                    hb[i, term_row[b], b] = 1.0
            elif kind == TERM_RANGE_GAIN:
                hb[i, 0, b] = range_m
            else:
                for row in range(ndim):
                    hb[i, row, b] = -(hx[i, row, 0] * velocity[i, 0]
                                      + hx[i, row, 1] * velocity[i, 1]
                                      + hx[i, row, 2] * velocity[i, 2])
        for row in range(ndim):
            scale = whiten[row]
            e[i, row] = residual[row] * scale
            for x in range(3):
                hx[i, row, x] *= scale
            for b in range(k):
                hb[i, row, b] *= scale
    return e, hx, hb, position, velocity, zenith


@_jit
def heights_and_up(enu, rotation, origin):  # pragma: no cover - compiled
    """Ellipsoidal heights [m] (n,) and local verticals (n, 3) of points ``enu`` (n, 3) of a
    frame whose ECEF is ``rotation^T p + origin``: :func:`graphcal.core.frames.
    ecef_to_height_and_normal` (Bowring's latitude in one step), the normal rotated into
    the frame, point by point."""
    n = enu.shape[0]
    height = np.empty(n)
    up = np.empty((n, 3))
    ep2 = _E2 / (1.0 - _E2)
    for i in range(n):
        x = enu[i, 0] * rotation[0, 0] + enu[i, 1] * rotation[1, 0] + enu[i, 2] * rotation[2, 0]
        y = enu[i, 0] * rotation[0, 1] + enu[i, 1] * rotation[1, 1] + enu[i, 2] * rotation[2, 1]
        z = enu[i, 0] * rotation[0, 2] + enu[i, 1] * rotation[1, 2] + enu[i, 2] * rotation[2, 2]
        x += origin[0]
        y += origin[1]
        z += origin[2]
        p = np.hypot(x, y)
        za, pb = z * _A, p * _B
        radius = np.hypot(za, pb)
        sin_t, cos_t = za / radius, pb / radius
        north = z + ep2 * _B * (sin_t * sin_t * sin_t)
        out = p - _E2 * _A * (cos_t * cos_t * cos_t)
        length = np.hypot(north, out)
        sin_lat, cos_lat = north / length, out / length
        radius_n = _A / np.sqrt(1.0 - _E2 * sin_lat * sin_lat)
        height[i] = p * cos_lat + z * sin_lat - _A * _A / radius_n
        n0, n1, n2 = cos_lat * x / p, cos_lat * y / p, sin_lat
        for a in range(3):
            up[i, a] = n0 * rotation[a, 0] + n1 * rotation[a, 1] + n2 * rotation[a, 2]
    return height, up


@_jit
def band_matvec(band, x):  # pragma: no cover - compiled
    """``A x`` for the symmetric matrix whose lower band is ``band`` (``band[d, i] =
    A[i + d, i]``), ``x`` (n,)."""
    width1, n = band.shape
    y = np.zeros(n)
    for i in range(n):
        xi = x[i]
        yi = band[0, i] * xi
        for d in range(1, min(width1, n - i)):
            a = band[d, i]
            yi += a * x[i + d]
            y[i + d] += a * xi
        y[i] += yi
    return y


@_jit
def add_plot_positions(band, rhs, first, weights, range_m, azimuth, elevation, weight, map_a,
                       map_c):  # pragma: no cover - compiled
    """The first fit's plots into its normal equations: each plot's position (its polar
    coordinates to the radar's ENU, then to the frame of the paths, ``p = A^T (enu - c)``)
    with the isotropic information ``weight`` [1/m^2]: ``(B B^T) kron (weight I)`` into
    ``band`` (only the blocks' diagonals), ``B kron (weight p)`` into ``rhs``.  Plots of zero
    weight are skipped."""
    for i in range(first.shape[0]):
        wi = weight[i]
        if wi == 0.0:
            continue
        ground = range_m[i] * np.cos(elevation[i])
        e0 = ground * np.sin(azimuth[i]) - map_c[0]
        e1 = ground * np.cos(azimuth[i]) - map_c[1]
        e2 = range_m[i] * np.sin(elevation[i]) - map_c[2]
        base = 3 * first[i]
        for x in range(3):
            local = e0 * map_a[0, x] + e1 * map_a[1, x] + e2 * map_a[2, x]
            scaled = wi * local
            for a in range(4):
                wa = weights[i, a]
                rhs[base + 3 * a + x] += wa * scaled
                for c in range(a, 4):
                    band[3 * (c - a), base + 3 * a + x] += (wa * weights[i, c]) * wi


@_jit
def basis(u):  # pragma: no cover - compiled
    """:func:`graphcal.model.paths.basis`, value by value: the uniform cubic B-spline
    weights ``(n, 4)`` at the interval fractions ``u``."""
    n = u.shape[0]
    out = np.empty((n, 4))
    for i in range(n):
        x = u[i]
        x2 = x * x
        x3 = x2 * x
        v = 1.0 - x
        out[i, 0] = (v * v * v) / 6.0
        out[i, 1] = (3.0 * x3 - 6.0 * x2 + 4.0) / 6.0
        out[i, 2] = (-3.0 * x3 + 3.0 * x2 + 3.0 * x + 1.0) / 6.0
        out[i, 3] = x3 / 6.0
    return out


__all__ = ["accumulate", "add_block", "add_blocks", "add_plot_positions", "adsb_reports",
           "adsb_sums", "band_forward", "band_matvec", "basis", "evaluate", "heights_and_up",
           "motion_prior", "plot_linearisation", "scatter_vectors"]

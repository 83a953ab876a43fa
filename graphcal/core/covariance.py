"""Conversion of measurement covariances between frames (paper 002).

Units: metres and radians; covariances in m^2, rad^2 and m rad.  Every
function is vectorised over leading dimensions: covariances are ``(..., n, n)``,
Jacobians ``(..., m, n)``, Hessians ``(..., m, n, n)`` and polar coordinates
broadcast with them.  Azimuth is clockwise from true north, so
``enu = (r cos(el) sin(az), r cos(el) cos(az), r sin(el))``; paper 002 measures
azimuth from the x axis, so its matrices differ from these by the swap of the
sine and cosine of the azimuth.

Unified rule (paper 002 eq. 2, 4, 12)
-------------------------------------
A measurement ``x`` with covariance ``R`` mapped by ``y = f(x)`` has, to first
order about the evaluation point, ``cov(y) = J R J^T`` with ``J = df/dx``
(:func:`convert_covariance`).  For a linear map (ENU <-> ECEF, eq. 3-6) ``J``
is the constant rotation and the rule is exact; for polar -> ENU (eq. 7-13,
17-19, 23-25) ``J`` is :func:`graphcal.core.frames.polar_to_enu_jacobian`.  In
the paper's Monte Carlo (and in practice) the Jacobian is evaluated at the
measured point, since the truth is unknown.

Chains are products of Jacobians, so conversions compose::

    polar (radar A) -> ENU A            polar_to_enu_covariance
    ENU A -> ECEF                       enu_to_ecef_covariance(lat_A, lon_A)
    ECEF -> ENU of radar B              ecef_to_enu_covariance(lat_B, lon_B)
    ENU A -> ENU B in one step          enu_to_enu_covariance
    ECEF -> polar of radar B            ecef_to_polar_covariance (first order)

:func:`polar_to_ecef_covariance` is the first two steps (paper 002 eq. 19).

Second order, derived anew
--------------------------
Write the conversion error as ``e = J d + 1/2 d^T H d + O(d^3)`` with
``d ~ N(0, R)`` and ``H_i`` the Hessian of component ``i``.  The odd moments of
``d`` vanish, and for a Gaussian ``E[d^T A d d^T B d] = tr(A R) tr(B R) +
2 tr(A R B R)``, so

* mean shift (bias):        ``b_i = 1/2 tr(H_i R)``
* covariance:               ``J R J^T + 1/2 tr(H_i R H_j R)``
* mean square about truth:  covariance ``+ b b^T``.

Printed eq. 26 of paper 002 keeps only squared halves of the diagonal Hessian
entries, i.e. a partial ``b_i^2`` without its cross products; its eq. 29
``sigma^2 / (4 + sigma^2)`` (``sigma_r = 0``, ``sigma_a = sigma_e = sigma``)
is therefore not the size of the second-order covariance term.  With the
complete term the ratio is ``sigma^2 (2 + sin^2 el) / (2 (2 - sin^2 el) +
sigma^2 (2 + sin^2 el))``: ``sigma^2 / (2 + sigma^2)`` at zero elevation, twice
the printed value, and still about 1.5e-4 for 1 degree
(:func:`second_order_relative_size`).  Nor does the share fall as ``sigma_r``
grows, as eq. 28 suggests: the range-angle Hessian entries add
``sigma_r^2 sigma_a^2`` and ``sigma_r^2 sigma_e^2`` terms (at 10 km, 60 deg,
60 deg with 1 deg angle errors the share is 3.35e-4 at ``sigma_r = 0`` and
3.75e-4 at 500 m).

The second-order term is not uniformly an improvement.  Keeping ``H`` but not
the third derivatives ``T`` drops the cross term ``E[(J d)(T d d d)^T] / 6``
(and its transpose), which is of the same order ``sigma^4`` as
``1/2 tr(H_i R H_j R)``.  Example: azimuth noise ``s`` only, zero elevation,
trace over east and north.  Exactly, ``r^2 (1 - exp(-s^2)) =
r^2 (s^2 - s^4/2 + ...)``; first order gives ``r^2 s^2`` (error ``+s^4/2``),
first plus Hessian term ``r^2 (s^2 + s^4/2)`` (error ``+s^4``, twice as large);
the third-derivative cross term ``-r^2 s^4`` restores ``-s^4/2``.  For the
mean square about the truth (what paper 002 eq. 30 measures) the errors are
``+s^4/4`` (first order) and ``+s^4`` (with Hessian term and ``b b^T``).
Where a component's first-order row vanishes (e.g. up with elevation noise
at 90 deg elevation: ``var = r^2 (1 - exp(-s^2))^2 / 2``), the cross term
vanishes too and the Hessian term is the exact leading ``r^2 s^4 / 2``.
These statements are checked numerically in ``tests/test_covariance.py``.

Exact polar -> ENU
------------------
For uncorrelated Gaussian range, azimuth and elevation errors the moments
of the converted point are closed-form (unbiased converted measurements,
Mo et al. 1998; Lerro and Bar-Shalom 1993): with ``mu = exp(-s^2)``,
``E[cos a'] = sqrt(mu) cos a``, ``E[sin a'] = sqrt(mu) sin a``,
``var(sin a') = (1 - mu)(1 + mu cos 2a) / 2``,
``var(cos a') = (1 - mu)(1 - mu cos 2a) / 2`` and
``cov(sin a', cos a') = -mu (1 - mu) sin(2a) / 2``.  Each ENU component is a
product ``r' Y(el') Z(az')`` of independent factors, and
``cov(X Y1 Z1, X Y2 Z2) = v_X (m_Y + c_Y)(m_Z + c_Z) + mu_X^2 (c_Y m_Z + m_Y c_Z
+ c_Y c_Z)`` (``m`` products of means, ``c`` covariances), which has no
cancellation at small sigmas.  ``order="exact"`` returns this covariance about
the mean; :func:`polar_to_enu_mean_shift` gives the bias for the mean square
about the truth.  It is exact at the evaluation point; evaluated at a noisy
measurement it is, like every order, an approximation.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from graphcal.core import frames

Array = NDArray[np.float64]
Order = Literal[1, 2, "exact"]

__all__ = [
    "convert_covariance",
    "ecef_to_enu_covariance",
    "ecef_to_polar_covariance",
    "enu_to_ecef_covariance",
    "enu_to_enu_covariance",
    "mean_square_error",
    "polar_covariance",
    "polar_to_ecef_covariance",
    "polar_to_enu_covariance",
    "polar_to_enu_hessian",
    "polar_to_enu_mean_shift",
    "second_order_covariance_term",
    "second_order_mean",
    "second_order_relative_size",
]


# --------------------------------------------------------------------------- checks


def _as_matrix_stack(value: ArrayLike, name: str, rows: int | None = None) -> Array:
    arr = np.asarray(value, dtype=float)
    if arr.ndim < 2:
        raise ValueError(f"{name} must have shape (..., m, n), got shape {arr.shape}")
    if rows is not None and arr.shape[-2:] != (rows, rows):
        raise ValueError(f"{name} must have shape (..., {rows}, {rows}), got shape {arr.shape}")
    return arr


def _as_covariance(cov: ArrayLike, name: str, size: int | None = None) -> Array:
    arr = _as_matrix_stack(cov, name)
    if arr.shape[-1] != arr.shape[-2]:
        raise ValueError(f"{name} must be square in its last two axes, got shape {arr.shape}")
    if size is not None and arr.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}, {size}), got shape {arr.shape}")
    if np.any(np.diagonal(arr, axis1=-2, axis2=-1) < 0.0):
        raise ValueError(f"{name} has a negative variance on its diagonal")
    return arr


def _check_order(order: object) -> None:
    if order not in (1, 2, "exact") or isinstance(order, bool):
        raise ValueError(f"order must be 1, 2 or 'exact', got {order!r}")


def _polar_point(
    range_m: ArrayLike, azimuth_rad: ArrayLike, elevation_rad: ArrayLike
) -> tuple[Array, Array, Array]:
    r = np.asarray(range_m, dtype=float)
    if np.any(r < 0.0):
        raise ValueError("range must be non-negative")
    az = np.asarray(azimuth_rad, dtype=float)
    el = np.asarray(elevation_rad, dtype=float)
    return np.broadcast_arrays(r, az, el)


# --------------------------------------------------------------------------- general rule


def convert_covariance(cov: ArrayLike, jacobian: ArrayLike) -> Array:
    """First-order covariance conversion ``J R J^T`` (paper 002 eq. 2, 4, 12).

    Parameters
    ----------
    cov : array_like, shape (..., n, n)
        Covariance ``R`` in the source frame (units of the source squared).
    jacobian : array_like, shape (..., m, n)
        Jacobian ``J = d(target)/d(source)`` at the evaluation point; for a
        linear map the transformation matrix itself (eq. 4).

    Returns
    -------
    ndarray, shape (..., m, m)
        Converted covariance; leading dimensions broadcast.

    Raises
    ------
    ValueError
        If ``cov`` is not square, ``jacobian`` has not ``n`` columns, or a
        variance is negative.
    """
    r = _as_covariance(cov, "cov")
    j = _as_matrix_stack(jacobian, "jacobian")
    if j.shape[-1] != r.shape[-1]:
        raise ValueError(
            f"jacobian has {j.shape[-1]} columns but cov is {r.shape[-1]}x{r.shape[-1]}"
        )
    return j @ r @ np.swapaxes(j, -1, -2)


def mean_square_error(cov: ArrayLike, mean_shift: ArrayLike) -> Array:
    """Mean square error about the truth, ``cov + b b^T`` [units^2].

    Parameters
    ----------
    cov : array_like, shape (..., m, m)
        Covariance about the mean of the converted measurement.
    mean_shift : array_like, shape (..., m)
        Bias ``b = E[y] - f(x)`` (:func:`second_order_mean`,
        :func:`polar_to_enu_mean_shift`).
    """
    c = _as_covariance(cov, "cov")
    b = np.asarray(mean_shift, dtype=float)
    if b.ndim < 1 or b.shape[-1] != c.shape[-1]:
        raise ValueError(f"mean_shift must have shape (..., {c.shape[-1]}), got {b.shape}")
    return c + b[..., :, None] * b[..., None, :]


# --------------------------------------------------------------------------- linear


def enu_to_ecef_covariance(cov_enu: ArrayLike, lat_rad: ArrayLike, lon_rad: ArrayLike) -> Array:
    """ENU covariance of the site at ``(lat, lon)`` to ECEF [m^2] (paper 002 eq. 5-6).

    Exact: ``R_ecef = T R_enu T^T`` with ``T = d(ecef)/d(enu)``, the transpose
    of :func:`graphcal.core.frames.ecef_to_enu_rotation`.

    Parameters
    ----------
    cov_enu : array_like, shape (..., 3, 3)
        Covariance in the local ENU frame [m^2].
    lat_rad, lon_rad : array_like
        Geodetic latitude and longitude of the ENU origin [rad]; broadcast with
        the leading dimensions of ``cov_enu``.
    """
    cov = _as_covariance(cov_enu, "cov_enu", 3)
    rot = frames.ecef_to_enu_rotation(lat_rad, lon_rad)
    return convert_covariance(cov, np.swapaxes(rot, -1, -2))


def ecef_to_enu_covariance(cov_ecef: ArrayLike, lat_rad: ArrayLike, lon_rad: ArrayLike) -> Array:
    """ECEF covariance to the ENU frame of the site at ``(lat, lon)`` [m^2] (eq. 4-6).

    Exact: ``R_enu = T^T R_ecef T``.  With another radar's latitude and
    longitude this is the ECEF -> that radar's ENU step of a chain.

    Parameters
    ----------
    cov_ecef : array_like, shape (..., 3, 3)
        Covariance in ECEF [m^2].
    lat_rad, lon_rad : array_like
        Geodetic latitude and longitude of the ENU origin [rad].
    """
    cov = _as_covariance(cov_ecef, "cov_ecef", 3)
    return convert_covariance(cov, frames.ecef_to_enu_rotation(lat_rad, lon_rad))


def enu_to_enu_covariance(
    cov_enu: ArrayLike,
    lat_from_rad: ArrayLike,
    lon_from_rad: ArrayLike,
    lat_to_rad: ArrayLike,
    lon_to_rad: ArrayLike,
) -> Array:
    """ENU covariance of one site to the ENU frame of another [m^2] (eq. 4 twice).

    Exact: ``R_B = (T_B T_A^T) R_A (T_B T_A^T)^T`` with ``T`` the
    ECEF -> ENU rotations; the sites' heights do not matter.
    """
    cov = _as_covariance(cov_enu, "cov_enu", 3)
    rot_a = frames.ecef_to_enu_rotation(lat_from_rad, lon_from_rad)
    rot_b = frames.ecef_to_enu_rotation(lat_to_rad, lon_to_rad)
    return convert_covariance(cov, rot_b @ np.swapaxes(rot_a, -1, -2))


# --------------------------------------------------------------------------- polar


def polar_covariance(
    sigma_range_m: ArrayLike,
    sigma_azimuth_rad: ArrayLike,
    sigma_elevation_rad: ArrayLike | None = None,
) -> Array:
    """Diagonal polar measurement covariance (paper 002 eq. 23), shape ``(..., 3, 3)``.

    Parameters
    ----------
    sigma_range_m : array_like
        1-sigma range error [m].
    sigma_azimuth_rad : array_like
        1-sigma azimuth error [rad].
    sigma_elevation_rad : array_like, optional
        1-sigma elevation error [rad]; ``None`` for a 2-D radar (zero
        elevation variance).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        ``diag(sigma_r^2, sigma_a^2, sigma_e^2)`` in [m^2, rad^2, rad^2].

    Raises
    ------
    ValueError
        If a sigma is negative.
    """
    sr = np.asarray(sigma_range_m, dtype=float)
    sa = np.asarray(sigma_azimuth_rad, dtype=float)
    se = np.zeros(()) if sigma_elevation_rad is None else np.asarray(sigma_elevation_rad, float)
    named = (("sigma_range_m", sr), ("sigma_azimuth_rad", sa), ("sigma_elevation_rad", se))
    for name, value in named:
        if np.any(value < 0.0):
            raise ValueError(f"{name} must be non-negative")
    sr, sa, se = np.broadcast_arrays(sr, sa, se)
    cov = np.zeros((*sr.shape, 3, 3))
    cov[..., 0, 0] = sr**2
    cov[..., 1, 1] = sa**2
    cov[..., 2, 2] = se**2
    return cov


def polar_to_enu_hessian(
    range_m: ArrayLike, azimuth_rad: ArrayLike, elevation_rad: ArrayLike
) -> Array:
    """Hessians of east, north, up w.r.t. (range, azimuth, elevation) (eq. 20-22).

    Returns
    -------
    ndarray, shape (..., 3, 3, 3)
        ``H[..., i, j, k] = d^2 enu_i / (d p_j d p_k)`` with ``p = (r, az, el)``;
        units m/rad^2 (angle-angle), 1/rad (range-angle), 0 (range-range)::

            east  [[0,         ce ca,     -se sa   ],
                   [ce ca,    -r ce sa,   -r se ca ],
                   [-se sa,   -r se ca,   -r ce sa ]]
            north [[0,        -ce sa,     -se ca   ],
                   [-ce sa,   -r ce ca,    r se sa ],
                   [-se ca,    r se sa,   -r ce ca ]]
            up    [[0,         0,          ce      ],
                   [0,         0,          0       ],
                   [ce,        0,         -r se    ]]

        with ``sa, ca = sin, cos(az)`` and ``se, ce = sin, cos(el)``.
    """
    r, az, el = _polar_point(range_m, azimuth_rad, elevation_rad)
    sa, ca = np.sin(az), np.cos(az)
    se, ce = np.sin(el), np.cos(el)
    z = np.zeros_like(r)
    east = [
        [z, ce * ca, -se * sa],
        [ce * ca, -r * ce * sa, -r * se * ca],
        [-se * sa, -r * se * ca, -r * ce * sa],
    ]
    north = [
        [z, -ce * sa, -se * ca],
        [-ce * sa, -r * ce * ca, r * se * sa],
        [-se * ca, r * se * sa, -r * ce * ca],
    ]
    up = [[z, z, ce], [z, z, z], [ce, z, -r * se]]
    return np.stack(
        [np.stack([np.stack(row, axis=-1) for row in comp], axis=-2) for comp in (east, north, up)],
        axis=-3,
    )


def second_order_covariance_term(hessian: ArrayLike, cov: ArrayLike) -> Array:
    """Second-order covariance term ``1/2 tr(H_i R H_j R)`` (eq. 20-22, completed).

    Parameters
    ----------
    hessian : array_like, shape (..., m, n, n)
        Hessian of each output component w.r.t. the inputs.
    cov : array_like, shape (..., n, n)
        Input covariance ``R`` (Gaussian errors assumed).

    Returns
    -------
    ndarray, shape (..., m, m)
        Term to add to ``J R J^T``; positive semi-definite.
    """
    h = np.asarray(hessian, dtype=float)
    r = _as_covariance(cov, "cov")
    n = r.shape[-1]
    if h.ndim < 3 or h.shape[-2:] != (n, n):
        raise ValueError(f"hessian must have shape (..., m, {n}, {n}), got shape {h.shape}")
    hr = h @ r[..., None, :, :]  # (..., m, n, n): H_i R
    return 0.5 * np.einsum("...iab,...jba->...ij", hr, hr)


def second_order_mean(hessian: ArrayLike, cov: ArrayLike) -> Array:
    """Second-order mean shift (bias) ``b_i = 1/2 tr(H_i R)``, shape ``(..., m)``.

    ``E[f(x + d)] - f(x)`` to second order for ``d ~ N(0, R)``; paper 002
    eq. 26 squares the halved diagonal terms of this (without cross products).
    """
    h = np.asarray(hessian, dtype=float)
    r = _as_covariance(cov, "cov")
    n = r.shape[-1]
    if h.ndim < 3 or h.shape[-2:] != (n, n):
        raise ValueError(f"hessian must have shape (..., m, {n}, {n}), got shape {h.shape}")
    return 0.5 * np.einsum("...iab,...ba->...i", h, r)


def second_order_relative_size(
    jacobian: ArrayLike, hessian: ArrayLike, cov: ArrayLike, *, include_bias: bool = False
) -> Array:
    """Share of the second-order term in the converted covariance (cf. eq. 28-29).

    ``tr(S) / (tr(J R J^T) + tr(S))`` with ``S`` from
    :func:`second_order_covariance_term`.  With ``include_bias`` the squared
    mean shift ``|b|^2`` is added to numerator and denominator (share in the
    mean square error about the truth, what eq. 30 measures).  Traces are
    rotation invariant, so ENU and ECEF give the same value.

    Parameters
    ----------
    jacobian : array_like, shape (..., m, n)
    hessian : array_like, shape (..., m, n, n)
    cov : array_like, shape (..., n, n)

    Returns
    -------
    ndarray, shape (...)
        Dimensionless ratio in ``[0, 1]``.
    """
    first = convert_covariance(cov, jacobian)
    second = second_order_covariance_term(hessian, cov)
    num = np.trace(second, axis1=-2, axis2=-1)
    den = np.trace(first, axis1=-2, axis2=-1) + num
    if include_bias:
        b2 = np.sum(second_order_mean(hessian, cov) ** 2, axis=-1)
        num = num + b2
        den = den + b2
    return num / den


def _exact_moments(
    r: Array, az: Array, el: Array, cov_polar: Array
) -> tuple[Array, Array]:
    """Exact covariance ``(..., 3, 3)`` and mean shift ``(..., 3)`` of polar -> ENU."""
    off = cov_polar - np.diagonal(cov_polar, axis1=-2, axis2=-1)[..., :, None] * np.eye(3)
    if np.any(off != 0.0):
        raise ValueError(
            "order='exact' needs uncorrelated range, azimuth and elevation errors "
            "(diagonal cov_polar)"
        )
    v_r = cov_polar[..., 0, 0]
    v_a = cov_polar[..., 1, 1]
    v_e = cov_polar[..., 2, 2]
    # Characteristic function of N(0, s^2): E[exp(i k d)] = exp(-k^2 s^2 / 2).
    mu_a = np.exp(-v_a)
    mu_e = np.exp(-v_e)
    one_a = -np.expm1(-v_a)  # 1 - mu, without cancellation
    one_e = -np.expm1(-v_e)
    sa, ca, s2a, c2a = np.sin(az), np.cos(az), np.sin(2 * az), np.cos(2 * az)
    se, ce, s2e, c2e = np.sin(el), np.cos(el), np.sin(2 * el), np.cos(2 * el)
    lam_a = np.sqrt(mu_a)
    lam_e = np.sqrt(mu_e)
    # Factors Y(el') = (cos, cos, sin) and Z(az') = (sin, cos, 1) of east, north, up.
    ones = np.ones_like(lam_a * sa)
    zeros = np.zeros_like(ones)
    mean_y = np.stack(np.broadcast_arrays(lam_e * ce, lam_e * ce, lam_e * se), axis=-1)
    mean_z = np.stack(np.broadcast_arrays(lam_a * sa, lam_a * ca, ones), axis=-1)
    var_cos_e = one_e * (1.0 - mu_e * c2e) / 2.0
    var_sin_e = one_e * (1.0 + mu_e * c2e) / 2.0
    cov_sc_e = -mu_e * one_e * s2e / 2.0
    var_sin_a = one_a * (1.0 + mu_a * c2a) / 2.0
    var_cos_a = one_a * (1.0 - mu_a * c2a) / 2.0
    cov_sc_a = -mu_a * one_a * s2a / 2.0
    c_y = np.stack(
        [
            np.stack(np.broadcast_arrays(var_cos_e, var_cos_e, cov_sc_e), axis=-1),
            np.stack(np.broadcast_arrays(var_cos_e, var_cos_e, cov_sc_e), axis=-1),
            np.stack(np.broadcast_arrays(cov_sc_e, cov_sc_e, var_sin_e), axis=-1),
        ],
        axis=-2,
    )
    c_z = np.stack(
        [
            np.stack(np.broadcast_arrays(var_sin_a, cov_sc_a, zeros), axis=-1),
            np.stack(np.broadcast_arrays(cov_sc_a, var_cos_a, zeros), axis=-1),
            np.stack(np.broadcast_arrays(zeros, zeros, zeros), axis=-1),
        ],
        axis=-2,
    )
    m_y = mean_y[..., :, None] * mean_y[..., None, :]
    m_z = mean_z[..., :, None] * mean_z[..., None, :]
    r2 = (r**2)[..., None, None]
    cov = v_r[..., None, None] * (m_y + c_y) * (m_z + c_z) + r2 * (
        c_y * m_z + m_y * c_z + c_y * c_z
    )
    # Mean shift E[enu'] - enu, with expm1 so that it is accurate at small sigmas.
    shift = np.stack(
        np.broadcast_arrays(
            r * ce * sa * np.expm1(-(v_a + v_e) / 2.0),
            r * ce * ca * np.expm1(-(v_a + v_e) / 2.0),
            r * se * np.expm1(-v_e / 2.0),
        ),
        axis=-1,
    )
    return cov, shift


def polar_to_enu_covariance(
    range_m: ArrayLike,
    azimuth_rad: ArrayLike,
    elevation_rad: ArrayLike,
    cov_polar: ArrayLike,
    *,
    order: Order = 1,
) -> Array:
    """Polar measurement covariance to radar ENU [m^2] (paper 002 eq. 17-19, 23-25).

    Parameters
    ----------
    range_m, azimuth_rad, elevation_rad : array_like
        Evaluation point [m, rad, rad] (the measured point in practice).
    cov_polar : array_like, shape (..., 3, 3)
        Covariance of (range, azimuth, elevation) [m^2, m rad, rad^2]
        (e.g. :func:`polar_covariance`).
    order : {1, 2, "exact"}
        ``1``: ``J R J^T`` (eq. 12, 23); ``2``: plus ``1/2 tr(H_i R H_j R)``
        (module docstring; not uniformly better); ``"exact"``: closed-form
        covariance for Gaussian, uncorrelated polar errors.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Covariance about the mean of the converted point; add
        ``b b^T`` (:func:`polar_to_enu_mean_shift`, :func:`mean_square_error`)
        for the mean square about the truth.

    Raises
    ------
    ValueError
        For a negative range, a malformed ``cov_polar``, an unknown
        ``order``, or correlated errors with ``order="exact"``.
    """
    _check_order(order)
    r, az, el = _polar_point(range_m, azimuth_rad, elevation_rad)
    cov = _as_covariance(cov_polar, "cov_polar", 3)
    if order == "exact":
        return _exact_moments(r, az, el, cov)[0]
    out = convert_covariance(cov, frames.polar_to_enu_jacobian(r, az, el))
    if order == 2:
        out = out + second_order_covariance_term(polar_to_enu_hessian(r, az, el), cov)
    return out


def polar_to_enu_mean_shift(
    range_m: ArrayLike,
    azimuth_rad: ArrayLike,
    elevation_rad: ArrayLike,
    cov_polar: ArrayLike,
    *,
    order: Order = 2,
) -> Array:
    """Bias ``E[enu(p + d)] - enu(p)`` of the converted point [m], shape ``(..., 3)``.

    ``order=1``: zero; ``order=2``: ``1/2 tr(H_i R)``
    (:func:`second_order_mean`); ``order="exact"``: closed form, e.g. up
    ``r sin(el) (exp(-s_e^2/2) - 1)`` (Mo et al. 1998).
    """
    _check_order(order)
    r, az, el = _polar_point(range_m, azimuth_rad, elevation_rad)
    cov = _as_covariance(cov_polar, "cov_polar", 3)
    if order == "exact":
        return _exact_moments(r, az, el, cov)[1]
    hessian = polar_to_enu_hessian(r, az, el)
    if order == 1:
        return np.zeros(np.broadcast_shapes(hessian.shape[:-2], cov.shape[:-2] + (3,)))
    return second_order_mean(hessian, cov)


def polar_to_ecef_covariance(
    range_m: ArrayLike,
    azimuth_rad: ArrayLike,
    elevation_rad: ArrayLike,
    cov_polar: ArrayLike,
    lat_rad: ArrayLike,
    lon_rad: ArrayLike,
    *,
    order: Order = 1,
) -> Array:
    """Polar measurement covariance of the radar at ``(lat, lon)`` to ECEF [m^2] (eq. 19).

    The chain polar -> ENU (:func:`polar_to_enu_covariance`, nonlinear, with
    ``order``) -> ECEF (:func:`enu_to_ecef_covariance`, exact).  The radar's
    height does not enter.
    """
    cov_enu = polar_to_enu_covariance(
        range_m, azimuth_rad, elevation_rad, cov_polar, order=order
    )
    return enu_to_ecef_covariance(cov_enu, lat_rad, lon_rad)


def ecef_to_polar_covariance(
    cov_ecef: ArrayLike,
    target_ecef_m: ArrayLike,
    lat_rad: float,
    lon_rad: float,
    alt_m: float,
) -> Array:
    """ECEF covariance to the polar frame of the radar at ``(lat, lon, alt)`` (eq. 12-13).

    First order: ``J = d(r, az, el)/d(enu) @ T`` at the target's position
    (:func:`graphcal.core.frames.enu_to_polar_jacobian`).  Rows are range [m],
    azimuth and elevation [rad].

    Raises
    ------
    ValueError
        At the radar's zenith, where azimuth is undefined.
    """
    cov = _as_covariance(cov_ecef, "cov_ecef", 3)
    enu = frames.ecef_to_enu(target_ecef_m, lat_rad, lon_rad, alt_m)
    rot = frames.ecef_to_enu_rotation(lat_rad, lon_rad)
    return convert_covariance(cov, frames.enu_to_polar_jacobian(enu) @ rot)

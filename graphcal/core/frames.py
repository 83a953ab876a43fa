"""Coordinate frames: WGS-84 geodetic, ECEF, radar-local ENU and radar polar.

Units are stated once: angles in radians, lengths in metres.  Every function is
vectorised over leading array dimensions; 3-vectors live in the last axis.

Radar polar coordinates follow the contract: slant range, azimuth clockwise from
true north in ``[0, 2*pi)``, elevation above the local horizontal plane at the
antenna, straight line of sight (no refraction).

* geodetic -> ECEF: paper 003 eq. 3 (corrected: the z component is
  ``(N (1 - e^2) + h) sin(lat)``).
* ECEF -> ENU: paper 003 eq. 1-2, paper 002 eq. 5 (its transpose).
* ENU -> polar: paper 003 eq. 4 (with ``atan2`` so that the quadrant is kept).
* polar -> ENU: paper 001 eq. 5/7, paper 000 eq. 1.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: WGS-84 semi-major axis [m].
WGS84_A_M = 6378137.0
#: WGS-84 flattening.
WGS84_F = 1.0 / 298.257223563
#: WGS-84 semi-minor axis [m].
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
#: WGS-84 first eccentricity squared.
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

TWO_PI = 2.0 * np.pi

Array = NDArray[np.float64]


def wrap_to_2pi(angle_rad: ArrayLike) -> Array:
    """Wrap angles to ``[0, 2*pi)`` [rad].

    ``a - 2 pi floor(a / 2 pi)``: the same values as ``np.mod(a, 2 pi)`` to the bit
    for ``|a| < 4 pi`` (the subtraction is then exact), within a few ulp of ``a``
    beyond, at a fifth of the cost.  NaN and infinities give NaN.
    """
    angle = np.asarray(angle_rad, dtype=float)
    wrapped = angle - TWO_PI * np.floor(angle / TWO_PI)
    # Rounding can leave a tiny negative value or exactly 2*pi: both are 0 on the circle.
    return np.where((wrapped < 0.0) | (wrapped >= TWO_PI), 0.0, wrapped)


def wrap_to_pi(angle_rad: ArrayLike) -> Array:
    """Wrap angles to ``[-pi, pi)`` [rad]; used for angle differences."""
    # Through wrap_to_2pi so that np.mod returning exactly 2*pi cannot give +pi.
    return wrap_to_2pi(np.asarray(angle_rad, dtype=float) + np.pi) - np.pi


def _check_latitude(lat_rad: Array) -> None:
    if np.any(np.abs(lat_rad) > np.pi / 2 + 1e-12):
        raise ValueError("latitude must be within [-pi/2, pi/2] rad")


def geodetic_to_ecef(lat_rad: ArrayLike, lon_rad: ArrayLike, alt_m: ArrayLike) -> Array:
    """Geodetic WGS-84 coordinates to ECEF [m], shape ``(..., 3)``.

    ``x = (N + h) cos(lat) cos(lon)``, ``y = (N + h) cos(lat) sin(lon)``,
    ``z = (N (1 - e^2) + h) sin(lat)``, ``N = a / sqrt(1 - e^2 sin^2(lat))``
    (paper 003 eq. 3, corrected).  The inputs broadcast against each other; the
    components are written straight into the (C-contiguous) result.
    """
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    alt = np.asarray(alt_m, dtype=float)
    _check_latitude(lat)
    sin_lat = np.sin(lat)
    cos_lat = np.cos(lat)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    ecef = np.empty(np.broadcast_shapes(lat.shape, lon.shape, alt.shape) + (3,))
    horizontal = (n + alt) * cos_lat  # distance from the polar axis [m]
    np.multiply(horizontal, np.cos(lon), out=ecef[..., 0])
    np.multiply(horizontal, np.sin(lon), out=ecef[..., 1])
    np.multiply(n * (1.0 - WGS84_E2) + alt, sin_lat, out=ecef[..., 2])
    return ecef


def ecef_to_geodetic(ecef_m: ArrayLike) -> tuple[Array, Array, Array]:
    """ECEF [m] to geodetic WGS-84 ``(lat_rad, lon_rad, alt_m)``.

    Bowring's initial guess refined by Newton-like iterations on the latitude;
    accurate to well below a millimetre for heights from -1e4 m to 1e7 m.
    Points on the polar axis return longitude 0.
    """
    p_ecef = np.asarray(ecef_m, dtype=float)
    x, y, z = p_ecef[..., 0], p_ecef[..., 1], p_ecef[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    ep2 = WGS84_E2 / (1.0 - WGS84_E2)
    theta = np.arctan2(z * WGS84_A_M, p * WGS84_B_M)
    lat = np.arctan2(
        z + ep2 * WGS84_B_M * np.sin(theta) ** 3,
        p - WGS84_E2 * WGS84_A_M * np.cos(theta) ** 3,
    )
    for _ in range(3):
        sin_lat = np.sin(lat)
        n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
        lat = np.arctan2(z + WGS84_E2 * n * sin_lat, p)
    sin_lat = np.sin(lat)
    cos_lat = np.cos(lat)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    # Height formula that stays well conditioned at the equator and the poles.
    alt = p * cos_lat + z * sin_lat - WGS84_A_M**2 / n
    return lat, lon, alt


def ecef_to_height_and_normal(ecef_m: ArrayLike) -> tuple[Array, Array]:
    """ECEF [m] to the WGS-84 ellipsoidal height [m] and the ellipsoid normal (unit, ECEF).

    Bowring's latitude in one step, without trigonometric functions: ``tan(theta) =
    z a / (p b)``, ``tan(lat) = (z + e'^2 b sin^3 theta) / (p - e^2 a cos^3 theta)``
    (the first step of :func:`ecef_to_geodetic`); the height is then
    ``p cos(lat) + z sin(lat) - a^2 / N``, whose error is second order in the latitude's.
    For points from -10 km to 100 km above the ellipsoid the height agrees with
    :func:`ecef_to_geodetic` to 1e-8 m and the normal to 1e-12 rad.  The normal is
    ``(cos(lat) cos(lon), cos(lat) sin(lon), sin(lat))``, the local vertical.  Not for
    points on the polar axis.
    """
    p_ecef = np.asarray(ecef_m, dtype=float)
    x, y, z = p_ecef[..., 0], p_ecef[..., 1], p_ecef[..., 2]
    p = np.hypot(x, y)
    ep2 = WGS84_E2 / (1.0 - WGS84_E2)
    za, pb = z * WGS84_A_M, p * WGS84_B_M
    radius = np.hypot(za, pb)
    sin_t, cos_t = za / radius, pb / radius
    north = z + ep2 * WGS84_B_M * sin_t**3
    out = p - WGS84_E2 * WGS84_A_M * cos_t**3
    length = np.hypot(north, out)
    sin_lat, cos_lat = north / length, out / length
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    height = p * cos_lat + z * sin_lat - WGS84_A_M**2 / n
    normal = _vectors([cos_lat * x / p, cos_lat * y / p, sin_lat])
    return height, normal


def ecef_to_enu_rotation(lat_rad: ArrayLike, lon_rad: ArrayLike) -> Array:
    """Rotation matrix ``R`` with ``enu = R @ (ecef - ecef_site)``, shape ``(..., 3, 3)``.

    Rows are the east, north and up unit vectors in ECEF (paper 003 eq. 2).
    It is also the (constant) Jacobian d(enu)/d(ecef); its transpose is
    d(ecef)/d(enu) (paper 002 eq. 5).
    """
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    _check_latitude(lat)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl * so)
    rows = [
        [-so + zero, co + zero, zero],
        [-sl * co, -sl * so, cl + zero],
        [cl * co, cl * so, sl + zero],
    ]
    return _matrices(rows)


def _matrices(rows: list[list[ArrayLike]]) -> Array:
    """The matrices whose entry ``(i, j)`` is ``rows[i][j]`` (arrays broadcast against
    each other), shape ``(..., len(rows), len(rows[0]))``: each entry written once into
    the result, as ``np.stack`` of the rows' stacks gives it without their copies."""
    shape = np.broadcast_shapes(*(np.shape(x) for row in rows for x in row))
    out = np.empty(shape + (len(rows), len(rows[0])))
    for i, row in enumerate(rows):
        for j, x in enumerate(row):
            out[..., i, j] = x
    return out


def _vectors(components: list[ArrayLike]) -> Array:
    """The vectors of these components (broadcast against each other) in the last
    axis, as ``np.stack(np.broadcast_arrays(*components), axis=-1)``, written once."""
    return _matrices([components])[..., 0, :]


def rotate(vectors: ArrayLike, matrix: ArrayLike) -> Array:
    """``vectors @ matrix.T`` for 3-vectors in the last axis, element by element.

    The same arithmetic as the matrix product, without handing ``(n, 3) @ (3, 3)`` to
    BLAS, whose threads split the ``n`` rows and then wait for one another: on a
    busy machine that costs a hundred times the arithmetic.
    """
    v = np.asarray(vectors, dtype=float)
    m = np.asarray(matrix, dtype=float)
    if v.shape[-1:] != (3,) or m.shape != (3, 3):
        return v @ m.T
    return v[..., 0, None] * m[:, 0] + v[..., 1, None] * m[:, 1] + v[..., 2, None] * m[:, 2]


def row_norm(vectors: ArrayLike) -> Array:
    """Euclidean norm over the last axis, as ``numpy.linalg.norm(vectors, axis=-1)``.

    The squares are summed in order, the same arithmetic (the same bits) as
    ``numpy.linalg.norm``, at a fraction of its cost for short rows.
    """
    v = np.asarray(vectors, dtype=float)
    if v.shape[-1] == 0:
        return np.zeros(v.shape[:-1])
    total = v[..., 0] * v[..., 0]
    for k in range(1, v.shape[-1]):
        total = total + v[..., k] * v[..., k]
    return np.sqrt(total)


def ecef_to_enu(ecef_m: ArrayLike, lat_rad: float, lon_rad: float, alt_m: float) -> Array:
    """ECEF points [m] to the ENU frame [m] of the site at ``(lat, lon, alt)``."""
    origin = geodetic_to_ecef(lat_rad, lon_rad, alt_m)
    rotation = ecef_to_enu_rotation(lat_rad, lon_rad)
    delta = np.asarray(ecef_m, dtype=float) - origin
    return delta @ rotation.T


def enu_to_ecef(enu_m: ArrayLike, lat_rad: float, lon_rad: float, alt_m: float) -> Array:
    """ENU points [m] of the site at ``(lat, lon, alt)`` to ECEF [m]."""
    origin = geodetic_to_ecef(lat_rad, lon_rad, alt_m)
    rotation = ecef_to_enu_rotation(lat_rad, lon_rad)
    return np.asarray(enu_m, dtype=float) @ rotation + origin


def enu_to_polar(enu_m: ArrayLike) -> tuple[Array, Array, Array]:
    """ENU [m] to radar polar ``(range_m, azimuth_rad, elevation_rad)``.

    ``range = |enu|``, ``azimuth = atan2(east, north)`` wrapped to ``[0, 2*pi)``,
    ``elevation = atan2(up, hypot(east, north))``.  At the zenith the azimuth is
    undefined and returned as 0; at the origin all angles are 0.
    """
    enu = np.asarray(enu_m, dtype=float)
    east, north, up = enu[..., 0], enu[..., 1], enu[..., 2]
    ground = np.hypot(east, north)
    range_m = np.sqrt(ground**2 + up**2)
    # Zero ground range (zenith, nadir, origin): azimuth 0 even for signed zeros,
    # where arctan2(+-0.0, -0.0) would give +-pi.
    azimuth = np.where(ground == 0.0, 0.0, wrap_to_2pi(np.arctan2(east, north)))
    elevation = np.arctan2(up, ground)
    return range_m, azimuth, elevation


def polar_to_enu(range_m: ArrayLike, azimuth_rad: ArrayLike, elevation_rad: ArrayLike) -> Array:
    """Radar polar to ENU [m]: ``r cos(el) sin(az), r cos(el) cos(az), r sin(el)``.

    Raises
    ------
    ValueError
        If any range is negative.
    """
    r = np.asarray(range_m, dtype=float)
    if np.any(r < 0):
        raise ValueError("range must be non-negative")
    az = np.asarray(azimuth_rad, dtype=float)
    el = np.asarray(elevation_rad, dtype=float)
    ground = r * np.cos(el)
    return _vectors([ground * np.sin(az), ground * np.cos(az), r * np.sin(el)])


def polar_to_enu_and_jacobian(
    range_m: ArrayLike, azimuth_rad: ArrayLike, elevation_rad: ArrayLike
) -> tuple[Array, Array]:
    """:func:`polar_to_enu` and :func:`polar_to_enu_jacobian` at once, from one set of sines
    and cosines (the same values as the two functions give)."""
    r = np.asarray(range_m, dtype=float)
    if np.any(r < 0):
        raise ValueError("range must be non-negative")
    r, az, el = np.broadcast_arrays(r, np.asarray(azimuth_rad, dtype=float),
                                    np.asarray(elevation_rad, dtype=float))
    sa, ca = np.sin(az), np.cos(az)
    se, ce = np.sin(el), np.cos(el)
    ground = r * ce
    enu = _vectors([ground * sa, ground * ca, r * se])
    zero = np.zeros_like(r)
    rows = [
        [ce * sa, ground * ca, -r * se * sa],
        [ce * ca, -r * ce * sa, -r * se * ca],
        [se, zero, ground],
    ]
    return enu, _matrices(rows)


def polar_to_enu_jacobian(
    range_m: ArrayLike, azimuth_rad: ArrayLike, elevation_rad: ArrayLike
) -> Array:
    """Jacobian d(east, north, up)/d(range, azimuth, elevation), shape ``(..., 3, 3)``.

    Paper 002 eq. 18-19 and paper 000 eq. 1 (written here for azimuth from north)::

        [[cos(el) sin(az),  r cos(el) cos(az), -r sin(el) sin(az)],
         [cos(el) cos(az), -r cos(el) sin(az), -r sin(el) cos(az)],
         [sin(el),          0,                  r cos(el)        ]]
    """
    r = np.asarray(range_m, dtype=float)
    az = np.asarray(azimuth_rad, dtype=float)
    el = np.asarray(elevation_rad, dtype=float)
    r, az, el = np.broadcast_arrays(r, az, el)
    sa, ca = np.sin(az), np.cos(az)
    se, ce = np.sin(el), np.cos(el)
    zero = np.zeros_like(r)
    rows = [
        [ce * sa, r * ce * ca, -r * se * sa],
        [ce * ca, -r * ce * sa, -r * se * ca],
        [se, zero, r * ce],
    ]
    return _matrices(rows)


def enu_to_polar_jacobian(enu_m: ArrayLike) -> Array:
    """Jacobian d(range, azimuth, elevation)/d(east, north, up), shape ``(..., 3, 3)``.

    With ``g = hypot(e, n)`` and ``r = |enu|``::

        [[ e/r,          n/r,          u/r  ],
         [ n/g^2,       -e/g^2,        0    ],
         [-e u/(r^2 g), -n u/(r^2 g),  g/r^2]]

    Raises
    ------
    ValueError
        At the zenith or the origin (``g == 0``), where azimuth is undefined.
    """
    enu = np.asarray(enu_m, dtype=float)
    e, n, u = enu[..., 0], enu[..., 1], enu[..., 2]
    g2 = e**2 + n**2
    if np.any(g2 == 0.0):
        raise ValueError("azimuth Jacobian is undefined at the zenith (zero ground range)")
    g = np.sqrt(g2)
    r2 = g2 + u**2
    r = np.sqrt(r2)
    zero = np.zeros_like(e)
    rows = [
        [e / r, n / r, u / r],
        [n / g2, -e / g2, zero],
        [-e * u / (r2 * g), -n * u / (r2 * g), g / r2],
    ]
    return _matrices(rows)


def ecef_to_polar(
    ecef_m: ArrayLike, lat_rad: float, lon_rad: float, alt_m: float
) -> tuple[Array, Array, Array]:
    """ECEF [m] to the polar coordinates of the radar at ``(lat, lon, alt)``."""
    return enu_to_polar(ecef_to_enu(ecef_m, lat_rad, lon_rad, alt_m))


def polar_to_ecef(
    range_m: ArrayLike,
    azimuth_rad: ArrayLike,
    elevation_rad: ArrayLike,
    lat_rad: float,
    lon_rad: float,
    alt_m: float,
) -> Array:
    """Polar coordinates of the radar at ``(lat, lon, alt)`` to ECEF [m]."""
    return enu_to_ecef(polar_to_enu(range_m, azimuth_rad, elevation_rad), lat_rad, lon_rad, alt_m)


def gaussian_radius_m(lat_rad: ArrayLike) -> Array:
    """Gaussian (mean) radius of curvature of the WGS-84 ellipsoid at a latitude [m].

    ``R = sqrt(M N) = a sqrt(1 - e^2) / (1 - e^2 sin^2(lat))``, the geometric mean
    of the meridional (``M``) and prime-vertical (``N``) radii: the radius of the
    sphere that best fits the ellipsoid around a point in every direction.  It is
    the local earth sphere of :func:`elevation_from_height` and of the refraction
    model (:mod:`graphcal.core.refraction`).
    """
    sin_lat2 = np.sin(np.asarray(lat_rad, dtype=float)) ** 2
    return WGS84_A_M * np.sqrt(1.0 - WGS84_E2) / (1.0 - WGS84_E2 * sin_lat2)


def elevation_from_height(
    range_m: ArrayLike, target_alt_m: ArrayLike, lat_rad: float, alt_m: float
) -> Array:
    """Elevation [rad] of a target at slant range ``range_m`` and ellipsoidal height.

    Used for 2-D radars, which do not measure elevation: the target's height
    (from Mode C or ADS-B) fixes it.  Solved on a sphere of the local Gaussian
    radius of curvature; the ellipsoid's curvature varies with azimuth, so the
    error grows with range: measured at 48.7 deg N about 1 urad at 10 km,
    12 urad at 100 km and 40 urad at 300 km (up to 80 urad at the equator),
    i.e. under 12 m of height at 300 km::

        (R + h_t)^2 = (R + h_r)^2 + r^2 + 2 r (R + h_r) sin(el)
    """
    r = np.asarray(range_m, dtype=float)
    radius = gaussian_radius_m(lat_rad)
    rt = radius + np.asarray(target_alt_m, dtype=float)
    rr = radius + alt_m
    with np.errstate(invalid="ignore", divide="ignore"):
        sin_el = (rt**2 - rr**2 - r**2) / (2.0 * r * rr)
    return np.arcsin(np.clip(sin_el, -1.0, 1.0))

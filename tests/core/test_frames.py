"""Tests of graphcal.core.frames: WGS-84 geodetic, ECEF, radar ENU and radar polar.

Reference: pymap3d (an independent implementation) plus hand-derived values at
singular and reference points.  Angles are radians unless a name says ``_deg``.
All randomness goes through ``numpy.random.default_rng`` with a fixed seed.
"""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest

from graphcal.core import frames
from graphcal.core.frames import (
    TWO_PI,
    WGS84_A_M,
    WGS84_B_M,
    WGS84_E2,
    ecef_to_enu,
    ecef_to_enu_rotation,
    ecef_to_geodetic,
    ecef_to_polar,
    elevation_from_height,
    enu_to_ecef,
    enu_to_polar,
    enu_to_polar_jacobian,
    gaussian_radius_m,
    geodetic_to_ecef,
    polar_to_ecef,
    polar_to_enu,
    polar_to_enu_jacobian,
    wrap_to_2pi,
    wrap_to_pi,
)

# Radar sites (lat_rad, lon_rad, alt_m) used by the ENU tests: mid-latitude, equator on
# the antimeridian, southern hemisphere below the ellipsoid, near the pole.
SITES = [
    (np.deg2rad(48.7), np.deg2rad(9.2), 420.0),
    (0.0, np.pi, 0.0),
    (np.deg2rad(-33.9), np.deg2rad(-70.7), -35.0),
    (np.deg2rad(89.5), np.deg2rad(-120.0), 2800.0),
]
SITE_IDS = ["48.7N", "equator-antimeridian", "33.9S-below-ellipsoid", "89.5N"]


def random_geodetic(rng: np.random.Generator, n: int, h_min: float, h_max: float):
    """Points uniform on the ellipsoid's parameter sphere, heights uniform in [h_min, h_max]."""
    lat = np.arcsin(rng.uniform(-1.0, 1.0, n))
    lon = rng.uniform(-np.pi, np.pi, n)
    alt = rng.uniform(h_min, h_max, n)
    return lat, lon, alt


def random_enu(rng: np.random.Generator, n: int) -> np.ndarray:
    """Radar-coverage ENU points: +-400 km horizontally, -10..+20 km vertically, every
    component at least 1 m from zero (pymap3d.enu2aer snaps components below 1 mm to 0)."""
    enu = np.column_stack(
        [
            rng.uniform(-4e5, 4e5, n),
            rng.uniform(-4e5, 4e5, n),
            rng.uniform(-1e4, 2e4, n),
        ]
    )
    enu[np.abs(enu) < 1.0] = 1.0
    return enu


def angle_diff(a, b):
    """Wrapped angle difference a - b in [-pi, pi), so that 2*pi - eps vs 0 is eps."""
    return wrap_to_pi(np.asarray(a) - np.asarray(b))


# --------------------------------------------------------------------------------------
# Cross-checks against pymap3d
# --------------------------------------------------------------------------------------


def test_geodetic_to_ecef_matches_pymap3d():
    """geodetic_to_ecef agrees with pymap3d.geodetic2ecef from -1 km to geostationary height.

    Tolerance 1e-6 m: both evaluate the same closed form, so they differ only by rounding;
    at |ECEF| <= 4.3e7 m one ulp is 7.5e-9 m, the observed difference a few 1e-9 m.
    """
    rng = np.random.default_rng(20240601)
    lat, lon, alt = random_geodetic(rng, 2000, -1000.0, 3.6e7)
    ours = geodetic_to_ecef(lat, lon, alt)
    x, y, z = pymap3d.geodetic2ecef(lat, lon, alt, deg=False)
    np.testing.assert_allclose(ours, np.column_stack([x, y, z]), rtol=0, atol=1e-6)
    # pymap3d's default is degrees: the same points in degrees give the same ECEF.
    x_deg, y_deg, z_deg = pymap3d.geodetic2ecef(np.rad2deg(lat), np.rad2deg(lon), alt)
    np.testing.assert_allclose(ours, np.column_stack([x_deg, y_deg, z_deg]), rtol=0, atol=1e-6)


def test_ecef_to_geodetic_matches_pymap3d():
    """ecef_to_geodetic agrees with pymap3d.ecef2geodetic for heights -1 km .. 100 km.

    Tolerances 1e-10 rad (0.6 mm on the ground) and 1e-6 m: below 100 km height pymap3d's
    non-iterative You (2000) method is good to ~2e-13 rad / 3e-9 m.  Above that it degrades
    (~2e-6 rad at 3.6e7 m), so high orbits are checked by the exact round trip instead.
    """
    rng = np.random.default_rng(11)
    lat, lon, alt = random_geodetic(rng, 2000, -1000.0, 1e5)
    ecef = geodetic_to_ecef(lat, lon, alt)
    our_lat, our_lon, our_alt = ecef_to_geodetic(ecef)
    ref_lat, ref_lon, ref_alt = pymap3d.ecef2geodetic(ecef[:, 0], ecef[:, 1], ecef[:, 2], deg=False)
    np.testing.assert_allclose(our_lat, ref_lat, rtol=0, atol=1e-10)
    np.testing.assert_allclose(angle_diff(our_lon, ref_lon), 0.0, rtol=0, atol=1e-10)
    np.testing.assert_allclose(our_alt, ref_alt, rtol=0, atol=1e-6)
    # And both recover the generating coordinates.
    np.testing.assert_allclose(our_lat, lat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(our_alt, alt, rtol=0, atol=1e-6)


def test_ecef_to_height_and_normal_matches_pymap3d():
    """The trig-free height and normal agree with pymap3d.ecef2geodetic from -10 km to
    100 km: heights to 1e-6 m, the normal to 1e-11 rad, and the normal is the local
    vertical (the third row of pymap3d's ENU rotation at that latitude and longitude)."""
    rng = np.random.default_rng(12)
    lat, lon, alt = random_geodetic(rng, 2000, -1e4, 1e5)
    ecef = geodetic_to_ecef(lat, lon, alt)
    height, normal = frames.ecef_to_height_and_normal(ecef)
    ref_lat, ref_lon, ref_alt = pymap3d.ecef2geodetic(ecef[:, 0], ecef[:, 1], ecef[:, 2], deg=False)
    np.testing.assert_allclose(height, ref_alt, rtol=0, atol=1e-6)
    np.testing.assert_allclose(height, alt, rtol=0, atol=1e-6)
    up = np.column_stack(pymap3d.enu2ecef(0.0, 0.0, 1.0, ref_lat, ref_lon, 0.0, deg=False)) \
        - np.column_stack(pymap3d.enu2ecef(0.0, 0.0, 0.0, ref_lat, ref_lon, 0.0, deg=False))
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(normal, up, rtol=0, atol=1e-9)
    expected = np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    np.testing.assert_allclose(normal, expected, rtol=0, atol=1e-11)


@pytest.mark.parametrize(("lat0", "lon0", "h0"), SITES, ids=SITE_IDS)
def test_ecef_enu_match_pymap3d(lat0, lon0, h0):
    """ecef_to_enu / enu_to_ecef agree with pymap3d.ecef2enu / enu2ecef.

    Tolerance 1e-6 m: ECEF coordinates are ~6.4e6 m (ulp 9.3e-10 m) and the two codes
    order the rotation arithmetic differently; observed differences are ~2e-9 m.
    """
    rng = np.random.default_rng(7)
    enu = random_enu(rng, 1000)
    ecef = enu_to_ecef(enu, lat0, lon0, h0)
    ref_ecef = np.column_stack(pymap3d.enu2ecef(*enu.T.copy(), lat0, lon0, h0, deg=False))
    np.testing.assert_allclose(ecef, ref_ecef, rtol=0, atol=1e-6)
    back = ecef_to_enu(ecef, lat0, lon0, h0)
    ref_back = np.column_stack(pymap3d.ecef2enu(*ecef.T.copy(), lat0, lon0, h0, deg=False))
    np.testing.assert_allclose(back, ref_back, rtol=0, atol=1e-6)


def test_enu_to_polar_matches_pymap3d_enu2aer():
    """enu_to_polar agrees with pymap3d.enu2aer (which returns az, el, range; degrees by default).

    Tolerances 1e-6 m and 1e-12 rad: both are atan2/hypot of the same numbers (observed
    ~1e-10 m, 0 rad).  Azimuth is compared after wrapping the difference.
    """
    rng = np.random.default_rng(3)
    enu = random_enu(rng, 2000)
    rng_m, az, el = enu_to_polar(enu)
    # enu2aer overwrites tiny input components in place: pass copies.
    ref_az, ref_el, ref_r = pymap3d.enu2aer(*enu.T.copy(), deg=False)
    np.testing.assert_allclose(rng_m, ref_r, rtol=0, atol=1e-6)
    np.testing.assert_allclose(angle_diff(az, ref_az), 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(el, ref_el, rtol=0, atol=1e-12)
    ref_az_deg, ref_el_deg, _ = pymap3d.enu2aer(*enu.T.copy())
    np.testing.assert_allclose(np.rad2deg(el), ref_el_deg, rtol=0, atol=1e-9)
    assert np.all((az >= 0.0) & (az < TWO_PI))
    assert np.all((ref_az_deg >= 0.0) & (ref_az_deg < 360.0))
    np.testing.assert_allclose(
        np.rad2deg(angle_diff(az, np.deg2rad(ref_az_deg))), 0.0, rtol=0, atol=1e-9
    )


# --------------------------------------------------------------------------------------
# Singular and reference points
# --------------------------------------------------------------------------------------

GEODETIC_REFERENCE = [
    # (lat_deg, lon_deg, alt_m, expected ECEF) -- hand-derived from the ellipsoid axes.
    pytest.param(0.0, 0.0, 0.0, (WGS84_A_M, 0.0, 0.0), id="equator-prime-meridian"),
    pytest.param(0.0, 90.0, 0.0, (0.0, WGS84_A_M, 0.0), id="equator-90E"),
    pytest.param(0.0, -90.0, 0.0, (0.0, -WGS84_A_M, 0.0), id="equator-90W"),
    pytest.param(0.0, 180.0, 0.0, (-WGS84_A_M, 0.0, 0.0), id="equator-lon180"),
    pytest.param(0.0, -180.0, 0.0, (-WGS84_A_M, 0.0, 0.0), id="equator-lon-180"),
    pytest.param(0.0, 0.0, -1000.0, (WGS84_A_M - 1000.0, 0.0, 0.0), id="equator-h-1000"),
    pytest.param(0.0, 0.0, 1e5, (WGS84_A_M + 1e5, 0.0, 0.0), id="equator-h1e5"),
    pytest.param(0.0, 0.0, 3.6e7, (WGS84_A_M + 3.6e7, 0.0, 0.0), id="equator-h3.6e7"),
    pytest.param(90.0, 0.0, 0.0, (0.0, 0.0, WGS84_B_M), id="north-pole-lon0"),
    pytest.param(90.0, 123.0, 0.0, (0.0, 0.0, WGS84_B_M), id="north-pole-lon123"),
    pytest.param(90.0, -180.0, 1e5, (0.0, 0.0, WGS84_B_M + 1e5), id="north-pole-h1e5"),
    pytest.param(-90.0, 0.0, 0.0, (0.0, 0.0, -WGS84_B_M), id="south-pole-lon0"),
    pytest.param(-90.0, 45.0, -1000.0, (0.0, 0.0, -WGS84_B_M + 1000.0), id="south-pole-h-1000"),
    pytest.param(-90.0, 77.0, 3.6e7, (0.0, 0.0, -WGS84_B_M - 3.6e7), id="south-pole-h3.6e7"),
]


@pytest.mark.parametrize(("lat_deg", "lon_deg", "alt_m", "expected"), GEODETIC_REFERENCE)
def test_geodetic_to_ecef_reference_points(lat_deg, lon_deg, alt_m, expected):
    """geodetic_to_ecef at the poles, the equator and lon +-180 gives the axis points.

    Tolerance 1e-6 m: the only error is cos(pi/2) = 6e-17 and sin(pi) = 1.2e-16 times
    |ECEF| <= 4.3e7 m, i.e. a few nm.
    """
    ecef = geodetic_to_ecef(np.deg2rad(lat_deg), np.deg2rad(lon_deg), alt_m)
    assert ecef.shape == (3,)
    np.testing.assert_allclose(ecef, expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize(("lat_deg", "lon_deg", "alt_m", "expected"), GEODETIC_REFERENCE)
def test_ecef_to_geodetic_reference_points(lat_deg, lon_deg, alt_m, expected):
    """ecef_to_geodetic of the exact axis points recovers latitude and height.

    On the polar axis (x = y = 0) the longitude is documented as 0; at lon +-180 the
    returned longitude is +-pi (either sign is the same meridian).  Tolerances 1e-12 rad and
    1e-6 m (exact geometry, rounding only).
    """
    lat, lon, alt = ecef_to_geodetic(np.array(expected))
    np.testing.assert_allclose(lat, np.deg2rad(lat_deg), rtol=0, atol=1e-12)
    np.testing.assert_allclose(alt, alt_m, rtol=0, atol=1e-6)
    if abs(lat_deg) == 90.0:
        assert lon == 0.0
    else:
        np.testing.assert_allclose(angle_diff(lon, np.deg2rad(lon_deg)), 0.0, rtol=0, atol=1e-12)
    assert -np.pi <= lon <= np.pi


@pytest.mark.parametrize(
    "z_m",
    [WGS84_B_M, -WGS84_B_M, WGS84_B_M - 1000.0, -(WGS84_B_M + 1e5), WGS84_B_M + 3.6e7],
    ids=["north-surface", "south-surface", "north-h-1000", "south-h1e5", "north-h3.6e7"],
)
def test_ecef_to_geodetic_on_polar_axis(z_m):
    """Points on the polar axis: lat = sign(z) * pi/2, lon = 0, height = |z| - b (exactly)."""
    lat, lon, alt = ecef_to_geodetic(np.array([0.0, 0.0, z_m]))
    assert lat == np.sign(z_m) * np.pi / 2
    assert lon == 0.0
    np.testing.assert_allclose(alt, abs(z_m) - WGS84_B_M, rtol=0, atol=1e-6)


def test_lon_plus_minus_180_same_point():
    """lon = +180 and -180 deg are the same meridian: same ECEF, and geodetic returns |lon| = pi."""
    lat = np.deg2rad(37.0)
    east = geodetic_to_ecef(lat, np.pi, 5000.0)
    west = geodetic_to_ecef(lat, -np.pi, 5000.0)
    np.testing.assert_allclose(east, west, rtol=0, atol=1e-6)
    _, lon, _ = ecef_to_geodetic(east)
    np.testing.assert_allclose(abs(lon), np.pi, rtol=0, atol=1e-12)


# (enu, expected (range, azimuth, elevation)).  Each row is a hand-computed point.
POLAR_REFERENCE = [
    pytest.param((0.0, 1000.0, 0.0), (1000.0, 0.0, 0.0), id="north-az0"),
    pytest.param((1000.0, 0.0, 0.0), (1000.0, np.pi / 2, 0.0), id="east-az90"),
    pytest.param((0.0, -1000.0, 0.0), (1000.0, np.pi, 0.0), id="south-az180"),
    pytest.param((-1000.0, 0.0, 0.0), (1000.0, 1.5 * np.pi, 0.0), id="west-az270"),
    pytest.param((-0.0, 1000.0, 0.0), (1000.0, 0.0, 0.0), id="north-negative-zero-east"),
    pytest.param((1000.0, 1000.0, 0.0), (np.sqrt(2e6), np.pi / 4, 0.0), id="northeast-az45"),
    pytest.param((3.0, 0.0, 4.0), (5.0, np.pi / 2, np.arctan2(4.0, 3.0)), id="3-4-5"),
    pytest.param((0.0, 0.0, 5000.0), (5000.0, 0.0, np.pi / 2), id="zenith"),
    pytest.param((-0.0, -0.0, 5000.0), (5000.0, 0.0, np.pi / 2), id="zenith-signed-zeros"),
    pytest.param((0.0, -0.0, 5000.0), (5000.0, 0.0, np.pi / 2), id="zenith-negative-north"),
    pytest.param((0.0, 0.0, -5000.0), (5000.0, 0.0, -np.pi / 2), id="nadir"),
    pytest.param((-0.0, -0.0, -5000.0), (5000.0, 0.0, -np.pi / 2), id="nadir-signed-zeros"),
    pytest.param((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), id="origin"),
]


@pytest.mark.parametrize(("enu", "expected"), POLAR_REFERENCE)
def test_enu_to_polar_reference_points(enu, expected):
    """enu_to_polar at the cardinal directions, zenith, nadir and origin.

    Azimuth is clockwise from north in [0, 2*pi); at zero ground range it is 0 (as the
    docstring promises, also for signed zeros).  Tolerance 1e-12 (exact up to rounding).
    """
    rng_m, az, el = enu_to_polar(np.array(enu))
    np.testing.assert_allclose([rng_m, az, el], expected, rtol=1e-15, atol=1e-12)
    assert 0.0 <= az < TWO_PI


@pytest.mark.parametrize(("enu", "expected"), POLAR_REFERENCE[:4] + POLAR_REFERENCE[5:8])
def test_polar_to_enu_reference_points(enu, expected):
    """polar_to_enu inverts the reference table: north is +y, east is +x, up is +z.

    Tolerance 1e-9 m: sin/cos of pi/2, pi, 3pi/2 are off by ~1e-16, times 5000 m.
    """
    np.testing.assert_allclose(polar_to_enu(*expected), enu, rtol=0, atol=1e-9)


def test_azimuth_just_west_of_north():
    """A target a hair west of north has azimuth just below 2*pi (359.99999... deg), not 360.

    Exact: atan2(-1e-9, 1) = -1e-9 and 2*pi - 1e-9 is representable to ~1e-15 rad.
    """
    _, az, _ = enu_to_polar(np.array([-1e-6, 1000.0, 0.0]))
    assert az < TWO_PI
    np.testing.assert_allclose(az, TWO_PI - 1e-9, rtol=0, atol=1e-15)
    assert 359.9999 < np.rad2deg(az) < 360.0
    # The smallest representable westward offset still stays below 2*pi.
    _, az_tiny, _ = enu_to_polar(np.array([-1e-300, 1000.0, 0.0]))
    assert 0.0 <= az_tiny < TWO_PI


@pytest.mark.parametrize(
    ("angle", "expected"),
    [
        pytest.param(-1e-15, TWO_PI - 1e-15, id="minus-1e-15"),
        pytest.param(-1e-17, 0.0, id="minus-1e-17-rounds-to-0"),
        pytest.param(-1e-300, 0.0, id="minus-1e-300"),
        pytest.param(-0.0, 0.0, id="negative-zero"),
        pytest.param(TWO_PI, 0.0, id="2pi"),
        pytest.param(-TWO_PI, 0.0, id="minus-2pi"),
        pytest.param(3 * np.pi, np.pi, id="3pi"),
        pytest.param(-np.pi / 2, 1.5 * np.pi, id="minus-pi/2"),
        pytest.param(np.nextafter(TWO_PI, 0.0), np.nextafter(TWO_PI, 0.0), id="below-2pi"),
    ],
)
def test_wrap_to_2pi(angle, expected):
    """wrap_to_2pi lands in [0, 2*pi) even where np.mod would round to exactly 2*pi.

    Tolerance 1e-14 rad: np.mod of a few-pi argument is exact to a few ulp.
    """
    wrapped = wrap_to_2pi(angle)
    assert 0.0 <= wrapped < TWO_PI
    np.testing.assert_allclose(wrapped, expected, rtol=0, atol=1e-14)


@pytest.mark.parametrize(
    ("angle", "expected"),
    [
        pytest.param(np.pi, -np.pi, id="pi-to-minus-pi"),
        pytest.param(-np.pi, -np.pi, id="minus-pi"),
        pytest.param(np.nextafter(-np.pi, -np.inf), -np.pi, id="just-below-minus-pi"),
        pytest.param(TWO_PI - 1e-3, -1e-3, id="2pi-minus-small"),
        pytest.param(0.0, 0.0, id="zero"),
        pytest.param(-1e-17, -1e-17, id="tiny-negative"),
    ],
)
def test_wrap_to_pi(angle, expected):
    """wrap_to_pi lands in [-pi, pi) for every input, including one ulp below -pi
    (where np.mod(x + pi, 2 pi) rounds to 2 pi and would return +pi; -pi is the same
    direction to 4e-16 rad).  Tolerance 1e-14 rad (a few ulp of pi)."""
    wrapped = wrap_to_pi(angle)
    assert -np.pi <= wrapped < np.pi
    np.testing.assert_allclose(wrapped, expected, rtol=0, atol=1e-14)


def test_wrap_to_2pi_equals_numpy_mod_within_two_turns():
    """Against np.mod (the second implementation): the same bits for |a| < 4 pi, where
    every use in the package lies (azimuths from arctan2, differences of angles), apart
    from np.mod's exact 2 pi, which wraps to 0; NaN and infinities give NaN."""
    rng = np.random.default_rng(7)
    edges = TWO_PI * np.arange(-1, 2)
    x = np.concatenate([rng.uniform(-4 * np.pi, 4 * np.pi, 100_000), edges,
                        np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf),
                        [np.nextafter(4 * np.pi, 0.0), np.nextafter(-4 * np.pi, 0.0)]])
    expected = np.mod(x, TWO_PI)
    expected[expected >= TWO_PI] = 0.0
    np.testing.assert_array_equal(wrap_to_2pi(x), expected)
    with np.errstate(invalid="ignore"):
        assert np.isnan(wrap_to_2pi(np.array([np.nan, np.inf, -np.inf]))).all()


def test_wrap_to_pi_random_range():
    """Random angles over +-1e3 rad: wrap_to_pi in [-pi, pi) and differs by a multiple of 2 pi
    (tolerance 1e-9 rad: |x| <= 1e3 has ulp 1.1e-13, the mod adds a few)."""
    rng = np.random.default_rng(99)
    x = rng.uniform(-1e3, 1e3, 5000)
    w = wrap_to_pi(x)
    assert np.all((w >= -np.pi) & (w < np.pi))
    turns = (x - w) / TWO_PI
    np.testing.assert_allclose(turns, np.round(turns), rtol=0, atol=1e-9)


# --------------------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "enu",
    [
        pytest.param([0.0, 0.0, 1000.0], id="zenith"),
        pytest.param([0.0, 0.0, -1000.0], id="nadir"),
        pytest.param([0.0, 0.0, 0.0], id="origin"),
        pytest.param([[1.0, 2.0, 3.0], [0.0, 0.0, 7.0]], id="one-zenith-in-batch"),
    ],
)
def test_enu_to_polar_jacobian_raises_at_zenith(enu):
    """The azimuth row is undefined at zero ground range: ValueError, also inside a batch."""
    with pytest.raises(ValueError, match="zenith"):
        enu_to_polar_jacobian(np.array(enu))


@pytest.mark.parametrize(
    ("r", "az", "el"),
    [
        pytest.param(-1.0, 0.0, 0.0, id="scalar"),
        pytest.param(-1e-300, 1.0, 0.2, id="tiny-negative"),
        pytest.param([10.0, -5.0, 3.0], [0.0, 1.0, 2.0], [0.0, 0.1, 0.2], id="in-batch"),
    ],
)
def test_polar_to_enu_raises_on_negative_range(r, az, el):
    """A negative slant range is rejected with ValueError."""
    with pytest.raises(ValueError, match="range"):
        polar_to_enu(r, az, el)


def test_polar_to_enu_accepts_zero_range():
    """Zero range is allowed (the origin), so the check is r < 0, not r <= 0."""
    np.testing.assert_array_equal(polar_to_enu(0.0, 1.0, 0.5), [0.0, 0.0, 0.0])


@pytest.mark.parametrize(
    "lat_deg",
    [
        pytest.param(90.001, id="90.001"),
        pytest.param(-90.001, id="-90.001"),
        pytest.param(180.0, id="180"),
        pytest.param([10.0, 91.0], id="in-batch"),
    ],
)
def test_latitude_out_of_range_raises(lat_deg):
    """Latitudes beyond +-90 deg are rejected by every function that takes a site latitude."""
    lat = np.deg2rad(lat_deg)
    with pytest.raises(ValueError, match="latitude"):
        geodetic_to_ecef(lat, 0.0, 0.0)
    with pytest.raises(ValueError, match="latitude"):
        ecef_to_enu_rotation(lat, 0.0)
    scalar_lat = float(np.max(np.abs(lat)))
    with pytest.raises(ValueError, match="latitude"):
        ecef_to_enu(np.zeros(3), scalar_lat, 0.0, 0.0)
    with pytest.raises(ValueError, match="latitude"):
        enu_to_ecef(np.zeros(3), scalar_lat, 0.0, 0.0)


@pytest.mark.parametrize("lat", [np.pi / 2, -np.pi / 2, np.deg2rad(90.0), np.deg2rad(-90.0)])
def test_latitude_exactly_at_pole_is_accepted(lat):
    """Exactly +-90 deg (in radians via pi/2 or deg2rad) is valid."""
    assert geodetic_to_ecef(lat, 0.0, 0.0).shape == (3,)
    assert ecef_to_enu_rotation(lat, 0.0).shape == (3, 3)


# --------------------------------------------------------------------------------------
# Round trips and batching
# --------------------------------------------------------------------------------------


def test_geodetic_ecef_round_trip_up_to_geostationary():
    """geodetic -> ECEF -> geodetic recovers the input from -1 km to 3.6e7 m height.

    Tolerances: 1e-12 rad in latitude/longitude (observed 2e-16) and 1e-7 m in height
    (about 13 ulp of the 4.2e7 m ECEF coordinates; observed 1.5e-8 m).
    """
    rng = np.random.default_rng(5)
    lat, lon, alt = random_geodetic(rng, 4000, -1000.0, 3.6e7)
    back_lat, back_lon, back_alt = ecef_to_geodetic(geodetic_to_ecef(lat, lon, alt))
    np.testing.assert_allclose(back_lat, lat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(angle_diff(back_lon, lon), 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back_alt, alt, rtol=0, atol=1e-7)


def test_geodetic_ecef_batched_shapes_and_elementwise():
    """A (2, 5) batch gives (2, 5, 3) ECEF, identical (to 1e-9 m / 1e-15 rad, rounding of
    vectorised vs scalar libm) to converting each point on its own, and round-trips."""
    rng = np.random.default_rng(6)
    lat, lon, alt = (a.reshape(2, 5) for a in random_geodetic(rng, 10, -1000.0, 1e5))
    ecef = geodetic_to_ecef(lat, lon, alt)
    assert ecef.shape == (2, 5, 3)
    back = ecef_to_geodetic(ecef)
    for idx in np.ndindex(2, 5):
        single = geodetic_to_ecef(lat[idx], lon[idx], alt[idx])
        np.testing.assert_allclose(ecef[idx], single, rtol=0, atol=1e-9)
        single_back = ecef_to_geodetic(single)
        for batched, one in zip(back, single_back, strict=True):
            assert batched.shape == (2, 5)
            np.testing.assert_allclose(batched[idx], one, rtol=1e-15, atol=1e-9)
    np.testing.assert_allclose(back[0], lat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back[2], alt, rtol=0, atol=1e-6)


@pytest.mark.parametrize(("lat0", "lon0", "h0"), SITES, ids=SITE_IDS)
def test_enu_ecef_round_trip(lat0, lon0, h0):
    """ENU -> ECEF -> ENU and ECEF -> ENU -> ECEF for an (N, 3) and a (2, 5, 3) batch.

    Tolerance 1e-6 m (observed ~1e-9 m: rounding of 6.4e6 m ECEF coordinates).  The batched
    result equals the point-by-point one to 1e-9 m.
    """
    rng = np.random.default_rng(8)
    enu = random_enu(rng, 500)
    np.testing.assert_allclose(
        ecef_to_enu(enu_to_ecef(enu, lat0, lon0, h0), lat0, lon0, h0), enu, rtol=0, atol=1e-6
    )
    ecef = geodetic_to_ecef(*random_geodetic(rng, 500, -1000.0, 1e5))
    np.testing.assert_allclose(
        enu_to_ecef(ecef_to_enu(ecef, lat0, lon0, h0), lat0, lon0, h0), ecef, rtol=0, atol=1e-6
    )
    batch = enu[:10].reshape(2, 5, 3)
    ecef_batch = enu_to_ecef(batch, lat0, lon0, h0)
    assert ecef_batch.shape == (2, 5, 3)
    enu_back = ecef_to_enu(ecef_batch, lat0, lon0, h0)
    assert enu_back.shape == (2, 5, 3)
    np.testing.assert_allclose(enu_back, batch, rtol=0, atol=1e-6)
    for idx in np.ndindex(2, 5):
        np.testing.assert_allclose(
            ecef_batch[idx], enu_to_ecef(batch[idx], lat0, lon0, h0), rtol=0, atol=1e-9
        )


@pytest.mark.parametrize(("lat0", "lon0", "h0"), SITES, ids=SITE_IDS)
def test_site_and_local_vertical(lat0, lon0, h0):
    """The site is the ENU origin, and a point 1 km higher along the ellipsoid normal is
    (0, 0, 1000): ENU 'up' is the geodetic vertical.  Tolerance 1e-6 m (rounding)."""
    np.testing.assert_allclose(
        ecef_to_enu(geodetic_to_ecef(lat0, lon0, h0), lat0, lon0, h0), 0.0, rtol=0, atol=1e-6
    )
    above = geodetic_to_ecef(lat0, lon0, h0 + 1000.0)
    np.testing.assert_allclose(
        ecef_to_enu(above, lat0, lon0, h0), [0.0, 0.0, 1000.0], rtol=0, atol=1e-6
    )


def test_polar_enu_round_trip_batched():
    """polar -> ENU -> polar and ENU -> polar -> ENU over (N, 3) and (2, 5, 3) batches.

    Tolerances: 1e-12 relative in range, 1e-12 rad in angles (float64 rounding of
    trigonometric functions; elevations kept within +-1.5 rad so azimuth is well defined),
    1e-9 m in ENU.  Azimuths include values a hair from 0 and 2*pi.
    """
    rng = np.random.default_rng(12)
    n = 1000
    r = rng.uniform(1.0, 4e5, n)
    az = rng.uniform(0.0, TWO_PI, n)
    az[:4] = [0.0, 1e-12, TWO_PI - 1e-12, np.nextafter(TWO_PI, 0.0)]
    el = rng.uniform(-1.5, 1.5, n)
    back_r, back_az, back_el = enu_to_polar(polar_to_enu(r, az, el))
    np.testing.assert_allclose(back_r, r, rtol=1e-12)
    np.testing.assert_allclose(angle_diff(back_az, az), 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back_el, el, rtol=0, atol=1e-12)
    assert np.all((back_az >= 0.0) & (back_az < TWO_PI))

    enu = random_enu(rng, n)
    np.testing.assert_allclose(polar_to_enu(*enu_to_polar(enu)), enu, rtol=0, atol=1e-9)

    batch = enu[:10].reshape(2, 5, 3)
    polar_batch = enu_to_polar(batch)
    for comp in polar_batch:
        assert comp.shape == (2, 5)
    enu_batch = polar_to_enu(*polar_batch)
    assert enu_batch.shape == (2, 5, 3)
    np.testing.assert_allclose(enu_batch, batch, rtol=0, atol=1e-9)
    for idx in np.ndindex(2, 5):
        single = enu_to_polar(batch[idx])
        for batched, one in zip(polar_batch, single, strict=True):
            np.testing.assert_allclose(batched[idx], one, rtol=1e-15, atol=1e-15)
        np.testing.assert_allclose(enu_batch[idx], polar_to_enu(*single), rtol=0, atol=1e-9)


@pytest.mark.parametrize(("lat0", "lon0", "h0"), SITES, ids=SITE_IDS)
def test_polar_ecef_round_trip(lat0, lon0, h0):
    """polar_to_ecef and ecef_to_polar are inverse and agree with the composed steps
    (tolerances 1e-9 relative range, 1e-11 rad angles: ECEF rounding ~1e-9 m over >= 1 km)."""
    rng = np.random.default_rng(13)
    r = rng.uniform(1e3, 4e5, 200)
    az = rng.uniform(0.0, TWO_PI, 200)
    el = rng.uniform(-0.2, 1.4, 200)
    ecef = polar_to_ecef(r, az, el, lat0, lon0, h0)
    np.testing.assert_allclose(ecef, enu_to_ecef(polar_to_enu(r, az, el), lat0, lon0, h0))
    back_r, back_az, back_el = ecef_to_polar(ecef, lat0, lon0, h0)
    np.testing.assert_allclose(back_r, r, rtol=1e-9)
    np.testing.assert_allclose(angle_diff(back_az, az), 0.0, rtol=0, atol=1e-11)
    np.testing.assert_allclose(back_el, el, rtol=0, atol=1e-11)


# --------------------------------------------------------------------------------------
# Jacobians
# --------------------------------------------------------------------------------------


def _polar_samples(rng: np.random.Generator, n: int):
    r = rng.uniform(1e3, 4e5, n)
    az = rng.uniform(0.0, TWO_PI, n)
    az[:2] = [1e-9, TWO_PI - 1e-9]  # finite differences must cross the 0/2pi seam
    el = rng.uniform(-1.3, 1.3, n)
    return r, az, el


def test_polar_to_enu_jacobian_finite_differences():
    """polar_to_enu_jacobian equals central differences of polar_to_enu.

    Steps: 1e-6 relative in range, 1e-6 rad in angles.  Columns are scaled to O(1) (the
    angle columns by 1/r); the truncation error is ~step^2 = 1e-12 and the rounding error
    ~eps * r / step / r ~ 2e-10, so atol 1e-7 on the scaled entries has ample margin while
    a wrong sign or a swapped sin/cos is an O(1) error.
    """
    rng = np.random.default_rng(21)
    r, az, el = _polar_samples(rng, 300)
    jac = polar_to_enu_jacobian(r, az, el)
    assert jac.shape == (300, 3, 3)
    fd = np.empty_like(jac)
    steps = [1e-6 * r, np.full_like(r, 1e-6), np.full_like(r, 1e-6)]
    for k, step in enumerate(steps):
        plus = [r.copy(), az.copy(), el.copy()]
        minus = [r.copy(), az.copy(), el.copy()]
        plus[k] += step
        minus[k] -= step
        fd[..., k] = (polar_to_enu(*plus) - polar_to_enu(*minus)) / (2 * step[:, None])
    scale = np.stack([np.ones_like(r), r, r], axis=-1)[:, None, :]
    np.testing.assert_allclose(jac / scale, fd / scale, rtol=0, atol=1e-7)


def test_enu_to_polar_jacobian_finite_differences():
    """enu_to_polar_jacobian equals central differences of enu_to_polar (azimuth
    differences wrapped, so the seam at north is handled).

    Step 1e-6 * range in each ENU component.  Angle rows are scaled by r to O(1); the
    truncation error is ~(step / ground)^2 < 1e-10 (ground >= 0.27 r) and the rounding error
    ~eps * pi * r / step ~ 1e-9, so atol 1e-7 has margin.
    """
    rng = np.random.default_rng(22)
    r, az, el = _polar_samples(rng, 300)
    enu = polar_to_enu(r, az, el)
    jac = enu_to_polar_jacobian(enu)
    assert jac.shape == (300, 3, 3)
    fd = np.empty_like(jac)
    for k in range(3):
        step = 1e-6 * r
        plus, minus = enu.copy(), enu.copy()
        plus[:, k] += step
        minus[:, k] -= step
        p_r, p_az, p_el = enu_to_polar(plus)
        m_r, m_az, m_el = enu_to_polar(minus)
        fd[:, 0, k] = (p_r - m_r) / (2 * step)
        fd[:, 1, k] = angle_diff(p_az, m_az) / (2 * step)
        fd[:, 2, k] = (p_el - m_el) / (2 * step)
    scale = np.stack([np.ones_like(r), r, r], axis=-1)[:, :, None]
    np.testing.assert_allclose(jac * scale, fd * scale, rtol=0, atol=1e-7)


def test_jacobians_are_inverse():
    """d(enu)/d(polar) @ d(polar)/d(enu) = I and vice versa, for a (2, 5) batch.

    The polar-side product has entries in m and 1/m, so it is compared as
    S^-1 (J_inv J_fwd) S with S = diag(1, 1/r, 1/r) (dimensionless).  Tolerance 1e-12:
    only rounding (~1e-16 relative) remains.
    """
    rng = np.random.default_rng(23)
    r, az, el = _polar_samples(rng, 10)
    r, az, el = (a.reshape(2, 5) for a in (r, az, el))
    enu = polar_to_enu(r, az, el)
    forward = polar_to_enu_jacobian(r, az, el)
    inverse = enu_to_polar_jacobian(enu)
    assert forward.shape == inverse.shape == (2, 5, 3, 3)
    eye = np.broadcast_to(np.eye(3), forward.shape)
    np.testing.assert_allclose(forward @ inverse, eye, rtol=0, atol=1e-12)
    scale = np.stack([np.ones_like(r), r, r], axis=-1)  # polar units relative to metres
    polar_side = scale[..., :, None] * (inverse @ forward) / scale[..., None, :]
    np.testing.assert_allclose(polar_side, eye, rtol=0, atol=1e-12)


def test_rotation_is_orthonormal_proper():
    """ecef_to_enu_rotation is orthonormal with det +1 (a rotation, not a reflection) for a
    batch of sites including both poles and lon +-180.  Tolerance 1e-14 (a few ulp of 1)."""
    rng = np.random.default_rng(24)
    lat, lon, _ = random_geodetic(rng, 200, 0.0, 0.0)
    lat = np.concatenate([lat, [np.pi / 2, -np.pi / 2, 0.0, 0.0]])
    lon = np.concatenate([lon, [0.3, -2.0, np.pi, -np.pi]])
    rot = ecef_to_enu_rotation(lat, lon)
    assert rot.shape == (204, 3, 3)
    eye = np.broadcast_to(np.eye(3), rot.shape)
    np.testing.assert_allclose(rot @ np.swapaxes(rot, -1, -2), eye, rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, rtol=0, atol=1e-14)


@pytest.mark.parametrize(("lat0", "lon0", "h0"), SITES, ids=SITE_IDS)
def test_rotation_rows_are_geodetic_directions(lat0, lon0, h0):
    """Rows of the rotation are the unit vectors d(ECEF)/d(lon), d(ECEF)/d(lat), d(ECEF)/d(h),
    an independent definition of east, north and up (central differences, steps 1e-7 rad and
    1 m; tolerance 1e-6: truncation ~step^2, rounding ~eps * 6.4e6 m / 0.6 m ~ 2e-9)."""
    rot = ecef_to_enu_rotation(lat0, lon0)
    if abs(lat0) < np.deg2rad(89.0):  # d/dlon vanishes at the pole
        d_lon = geodetic_to_ecef(lat0, lon0 + 1e-7, h0) - geodetic_to_ecef(lat0, lon0 - 1e-7, h0)
        np.testing.assert_allclose(rot[0], d_lon / np.linalg.norm(d_lon), rtol=0, atol=1e-6)
    d_lat = geodetic_to_ecef(lat0 + 1e-7, lon0, h0) - geodetic_to_ecef(lat0 - 1e-7, lon0, h0)
    np.testing.assert_allclose(rot[1], d_lat / np.linalg.norm(d_lat), rtol=0, atol=1e-6)
    d_h = geodetic_to_ecef(lat0, lon0, h0 + 1.0) - geodetic_to_ecef(lat0, lon0, h0 - 1.0)
    np.testing.assert_allclose(rot[2], d_h / 2.0, rtol=0, atol=1e-6)


@pytest.mark.parametrize(("lat0", "lon0", "h0"), SITES, ids=SITE_IDS)
def test_rotation_is_jacobian_of_ecef_to_enu(lat0, lon0, h0):
    """The rotation equals the finite-difference Jacobian d(enu)/d(ecef) of ecef_to_enu.

    ecef_to_enu is affine, so central differences have no truncation error; with 10 m steps
    the rounding error is ~eps * 6.4e6 m / 10 m ~ 1.4e-10, hence atol 1e-8.
    """
    rng = np.random.default_rng(25)
    ecef = enu_to_ecef(random_enu(rng, 5), lat0, lon0, h0)
    rot = ecef_to_enu_rotation(lat0, lon0)
    for point in ecef:
        fd = np.empty((3, 3))
        for k in range(3):
            step = np.zeros(3)
            step[k] = 10.0
            fd[:, k] = (
                ecef_to_enu(point + step, lat0, lon0, h0)
                - ecef_to_enu(point - step, lat0, lon0, h0)
            ) / 20.0
        np.testing.assert_allclose(rot, fd, rtol=0, atol=1e-8)


# --------------------------------------------------------------------------------------
# Elevation of a 2-D radar plot from the target height
# --------------------------------------------------------------------------------------


def test_elevation_from_height_matches_exact_geometry():
    """elevation_from_height vs the exact elevation (geodetic_to_ecef -> ecef_to_enu ->
    enu_to_polar) for targets 10-300 km away at 0-12 km height, radar at 48.7 N, 420 m.

    The function solves on a sphere of the Gaussian radius sqrt(M N); the true curvature
    radius along the line of sight varies with azimuth between M (north) and N (east), so
    the elevation is off by about (r / 2) |1/R_az - 1/sqrt(M N)| (measured: 1.2 urad at
    10 km, 12 urad at 100 km, 38 urad at 300 km).  The tolerance is that bound, evaluated
    at the worst azimuth, times 1.3 plus 0.5 urad; a wrong radius (e.g. N instead of
    sqrt(M N)) roughly doubles the error and fails.
    """
    lat0, lon0, h0 = np.deg2rad(48.7), np.deg2rad(9.2), 420.0
    rng = np.random.default_rng(31)
    n = 3000
    bearing = rng.uniform(0.0, TWO_PI, n)
    ground = rng.uniform(10e3, 299e3, n)
    height = rng.uniform(0.0, 12e3, n)
    w = 1.0 - WGS84_E2 * np.sin(lat0) ** 2
    m_rad = WGS84_A_M * (1.0 - WGS84_E2) / w**1.5
    n_rad = WGS84_A_M / np.sqrt(w)
    lat_t = lat0 + ground * np.cos(bearing) / m_rad
    lon_t = lon0 + ground * np.sin(bearing) / (n_rad * np.cos(lat0))
    target_enu = ecef_to_enu(geodetic_to_ecef(lat_t, lon_t, height), lat0, lon0, h0)
    slant, _, exact_el = enu_to_polar(target_enu)
    keep = (slant >= 10e3) & (slant <= 300e3)
    assert keep.sum() > 0.9 * n
    slant, exact_el, height = slant[keep], exact_el[keep], height[keep]

    approx_el = elevation_from_height(slant, height, lat0, h0)
    assert approx_el.shape == slant.shape

    gauss = np.sqrt(m_rad * n_rad)
    worst_curvature = max(abs(1.0 / m_rad - 1.0 / gauss), abs(1.0 / n_rad - 1.0 / gauss))
    tolerance = 1.3 * 0.5 * slant * worst_curvature + 0.5e-6
    error = np.abs(approx_el - exact_el)
    assert np.all(error <= tolerance), f"worst excess {np.max(error - tolerance):.3e} rad"
    # Absolute statement for the docs: below 50 urad out to 300 km at this latitude.
    assert error.max() < 50e-6
    # And it is not trivially satisfied: the error is a real, range-growing effect.
    assert error[slant > 250e3].max() > 10e-6


def test_gaussian_radius_is_the_mean_of_the_principal_radii():
    """sqrt(M N) from the meridional radius M = a (1 - e2) / w^1.5 and the prime-vertical
    radius N = a / sqrt(w), w = 1 - e2 sin^2(lat): a at the equator's N times sqrt(1 - e2),
    a^2 / b at the poles (rtol 1e-15, rounding only); vectorised."""
    lat = np.deg2rad(np.array([-90.0, -45.0, 0.0, 30.0, 48.7, 89.5, 90.0]))
    w = 1.0 - WGS84_E2 * np.sin(lat) ** 2
    m_rad = WGS84_A_M * (1.0 - WGS84_E2) / w**1.5
    n_rad = WGS84_A_M / np.sqrt(w)
    np.testing.assert_allclose(gaussian_radius_m(lat), np.sqrt(m_rad * n_rad), rtol=1e-15)
    np.testing.assert_allclose(gaussian_radius_m(0.0), WGS84_B_M, rtol=1e-15)
    np.testing.assert_allclose(gaussian_radius_m(np.pi / 2), WGS84_A_M**2 / WGS84_B_M,
                               rtol=1e-15)


def test_elevation_from_height_simple_cases():
    """Hand-checkable cases: a target straight up (range = height difference) is at
    pi/2 (to 1e-6 rad: arcsin near 1 turns 1e-16 rounding into ~1.5e-8 rad); a target at
    the radar's own height is below the horizontal by the Earth's curvature,
    sin(el) = -r / (2 (R + h_r)) with R the Gaussian radius (rtol 1e-12, rounding only);
    NaN range stays NaN."""
    lat0, h0 = np.deg2rad(48.7), 420.0
    np.testing.assert_allclose(
        elevation_from_height(5000.0, h0 + 5000.0, lat0, h0), np.pi / 2, rtol=0, atol=1e-6
    )
    w = 1.0 - WGS84_E2 * np.sin(lat0) ** 2
    gauss = WGS84_A_M * np.sqrt(1.0 - WGS84_E2) / w
    r = 100e3
    np.testing.assert_allclose(
        elevation_from_height(r, h0, lat0, h0), np.arcsin(-r / (2 * (gauss + h0))), rtol=1e-12
    )
    assert np.isnan(elevation_from_height(np.nan, 1000.0, lat0, h0))


def test_rotate_and_row_norm_are_the_matrix_product_and_numpys_norm() -> None:
    """frames.rotate is ``v @ M.T`` and row_norm is numpy's norm, bit for bit."""
    rng = np.random.default_rng(7)
    v = rng.normal(size=(1000, 3)) * 1e6
    m = frames.ecef_to_enu_rotation(0.8, 0.04)
    np.testing.assert_allclose(frames.rotate(v, m), v @ m.T, rtol=0, atol=1e-9)
    np.testing.assert_allclose(frames.rotate(v[0], m), m @ v[0], rtol=0, atol=1e-9)
    for width in (2, 3):
        assert np.array_equal(frames.row_norm(v[:, :width]), np.linalg.norm(v[:, :width], axis=1))

"""Tests of graphcal.core.refraction: rays through an exponential atmosphere.

References, independent of the module's Snell-invariant quadrature:

* a numerical ray trace: the ray equation ``d(n t)/ds = grad n`` integrated in the
  radar's ENU frame with ``scipy.integrate.solve_ivp`` (DOP853, relative tolerance
  1e-12) from the antenna at the solved apparent elevation, until the accumulated
  ``∫ n ds`` equals the solved electrical length: it must end at the target;
* the straight line of sight (``graphcal.core.frames`` and pymap3d's ``enu2aer``)
  when there is no atmosphere;
* closed forms and published orders of magnitude: the zenith delay
  ``1e-6 N_s H (exp(-h_r/H) - exp(-h_t/H))``, a few milliradians of bending at
  0-1 deg elevation and 100-300 km, below the astronomical refraction
  ``(n0 - 1) cot(e)`` at high elevation;
* central differences for every Jacobian, round trips for every inverse.

The local earth sphere (the Gaussian radius of curvature) is recomputed here from
the WGS-84 constants as ``sqrt(M N)``.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from scipy.integrate import solve_ivp

from graphcal.core import frames
from graphcal.core.refraction import (
    DEFAULT_N_S,
    DEFAULT_SCALE_HEIGHT_M,
    NO_REFRACTION,
    Atmosphere,
    apparent_elevation_from_height,
    apparent_elevation_from_height_jacobian,
    refracted_polar,
    refracted_polar_jacobian,
    refracted_ray,
    target_from_refracted,
    target_from_refracted_jacobian,
)

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563


def sphere_radius(lat_rad: float) -> float:
    """``sqrt(M N)``: the geometric mean of the meridional and prime-vertical radii."""
    e2 = WGS84_F * (2.0 - WGS84_F)
    w2 = 1.0 - e2 * math.sin(lat_rad) ** 2
    return math.sqrt(WGS84_A * (1.0 - e2) / w2**1.5 * WGS84_A / math.sqrt(w2))


def target_enu(lat_rad: float, alt_m: float, ground_m: float, height_m: float,
               azimuth_rad: float = 0.7) -> np.ndarray:
    """ENU of a point ``ground_m`` along the local sphere and ``height_m`` above it."""
    radius = sphere_radius(lat_rad)
    theta = ground_m / radius
    r = radius + height_m
    return np.array([r * math.sin(theta) * math.sin(azimuth_rad),
                     r * math.sin(theta) * math.cos(azimuth_rad),
                     r * math.cos(theta) - (radius + alt_m)])


def trace(atmosphere: Atmosphere, lat_rad: float, alt_m: float, azimuth_rad: float,
          elevation_rad: float, length_m: float) -> tuple[np.ndarray, float]:
    """Shoot a ray from the antenna; return where ``∫ n ds`` reaches ``length_m`` and
    the lowest height on the way.

    State ``(p, P = n t, ∫ n ds)`` in the radar's ENU frame; ``dp/ds = P / n``,
    ``dP/ds = grad n``.  The lowest point is where the ray is horizontal
    (``P . (p - centre) = 0``), found by an event.
    """
    radius = sphere_radius(lat_rad)
    centre = np.array([0.0, 0.0, -(radius + alt_m)])
    k, inv_h = 1e-6 * atmosphere.n_s, 1.0 / atmosphere.scale_height_m

    def index(p: np.ndarray) -> tuple[float, np.ndarray, float]:
        q = p - centre
        rq = float(np.linalg.norm(q))
        nu = k * math.exp(-(rq - radius) * inv_h)
        return 1.0 + nu, -nu * inv_h * q / rq, rq - radius

    def rhs(_s: float, y: np.ndarray) -> np.ndarray:
        n, grad, _ = index(y[:3])
        return np.concatenate([y[3:6] / n, grad, [n]])

    def arrive(_s: float, y: np.ndarray) -> float:
        return y[6] - length_m

    def horizontal(_s: float, y: np.ndarray) -> float:
        return float(np.dot(y[3:6], y[:3] - centre))

    arrive.terminal = True
    n0 = index(np.zeros(3))[0]
    tangent = np.array([math.cos(elevation_rad) * math.sin(azimuth_rad),
                        math.cos(elevation_rad) * math.cos(azimuth_rad),
                        math.sin(elevation_rad)])
    sol = solve_ivp(rhs, (0.0, 2.0 * length_m + 10.0),
                    np.concatenate([np.zeros(3), n0 * tangent, [0.0]]),
                    method="DOP853", rtol=1e-12, atol=1e-10, events=[arrive, horizontal])
    assert sol.status == 1, sol.message
    end = sol.y_events[0][0][:3]
    heights = [alt_m, index(end)[2]] + [index(y[:3])[2] for y in sol.y_events[1]]
    return end, min(heights)


PARIS = (math.radians(48.85), 140.0)
MOUNTAIN = (math.radians(46.5), 2800.0)

# (name, (lat, alt), atmosphere, ground distance [m], target height [m])
RAYS = [
    ("low-long", PARIS, Atmosphere(320.0), 300e3, 3000.0),
    ("grazing", PARIS, Atmosphere(313.0), 150e3, 1900.0),
    ("steep", PARIS, Atmosphere(320.0), 5e3, 10e3),
    ("high-far", PARIS, Atmosphere(320.0), 250e3, 30e3),
    ("dips-and-rises", MOUNTAIN, Atmosphere(320.0), 250e3, 1500.0),
    ("descends", MOUNTAIN, Atmosphere(320.0), 40e3, 500.0),
    ("arrives-horizontal", (math.radians(47.48), 866.0), Atmosphere(313.0), 106e3, 200.0),
    ("strong-gradient", PARIS, Atmosphere(450.0, 6000.0), 280e3, 2000.0),
    ("below-ellipsoid-south", (math.radians(-33.9), -35.0), Atmosphere(350.0), 200e3, 8000.0),
    ("equator", (0.0, 0.0), Atmosphere(380.0, 7500.0), 350e3, 11e3),
]
RAY_IDS = [case[0] for case in RAYS]


@pytest.mark.parametrize(("name", "site", "atmosphere", "ground", "height"), RAYS, ids=RAY_IDS)
def test_traced_ray_reaches_the_target(name, site, atmosphere, ground, height):
    lat, alt = site
    p = target_enu(lat, alt, ground, height)
    ray = refracted_ray(atmosphere, lat, alt, p)
    end, lowest = trace(atmosphere, lat, alt, ray.azimuth_rad[0], ray.elevation_rad[0],
                        ray.range_m[0])
    # 0.1 mm at up to 350 km: the elevation to better than 1e-9 rad, the length to 0.1 mm.
    assert np.linalg.norm(end - p) < 1e-4
    assert ray.lowest_height_m[0] == pytest.approx(lowest, abs=1e-3)
    assert ray.target_height_m[0] == pytest.approx(height, abs=1e-6)
    assert ray.central_angle_rad[0] == pytest.approx(ground / sphere_radius(lat), rel=1e-12)


def test_the_rays_cover_every_kind():
    """The cases above include rays up, down, dipping and rising, and arriving level."""
    kinds = {}
    for name, (lat, alt), atmosphere, ground, height in RAYS:
        kinds[name] = refracted_ray(atmosphere, lat, alt, target_enu(lat, alt, ground, height))
    dips = kinds["dips-and-rises"]
    assert dips.elevation_rad[0] < 0 < dips.arrival_elevation_rad[0]
    assert dips.lowest_height_m[0] < min(1500.0, MOUNTAIN[1]) - 100.0
    assert kinds["descends"].arrival_elevation_rad[0] < 0
    assert abs(kinds["arrives-horizontal"].arrival_elevation_rad[0]) < 2e-3
    assert kinds["steep"].elevation_rad[0] > 1.0


def test_straight_lines_without_atmosphere():
    rng = np.random.default_rng(7)
    enu = np.column_stack([rng.uniform(-3e5, 3e5, 200), rng.uniform(-3e5, 3e5, 200),
                           rng.uniform(-5e3, 2e4, 200)])
    lat, alt = math.radians(48.7), 420.0
    expected = frames.enu_to_polar(enu)
    for atmosphere in (None, NO_REFRACTION, Atmosphere(n_s=0.0, scale_height_m=8000.0)):
        got = refracted_polar(atmosphere, lat, alt, enu)
        for a, b in zip(got, expected, strict=True):
            assert np.array_equal(a, b)
    aer = pymap3d.enu2aer(enu[:, 0], enu[:, 1], enu[:, 2], deg=False)
    np.testing.assert_allclose(expected[0], aer[2], rtol=1e-14)
    np.testing.assert_allclose(expected[1], aer[0], atol=1e-12)
    np.testing.assert_allclose(expected[2], aer[1], atol=1e-12)
    polar, jac = refracted_polar_jacobian(None, lat, alt, enu)
    assert np.array_equal(jac, frames.enu_to_polar_jacobian(enu))
    assert np.array_equal(target_from_refracted(None, lat, alt, *polar.T),
                          frames.polar_to_enu(*polar.T))
    heights = refracted_ray(None, lat, alt, enu).target_height_m
    assert np.array_equal(apparent_elevation_from_height(None, lat, alt, polar[:, 0], heights),
                          frames.elevation_from_height(polar[:, 0], heights, lat, alt))


def test_faint_atmosphere_is_the_straight_line():
    """The general solver with N_s = 1e-9 agrees with the straight line."""
    rng = np.random.default_rng(8)
    enu = np.column_stack([rng.uniform(-3e5, 3e5, 100), rng.uniform(-3e5, 3e5, 100),
                           rng.uniform(0.0, 2e4, 100)])
    lat, alt = math.radians(-20.0), 50.0
    faint = Atmosphere(n_s=1e-9)
    rng_m, az, el = refracted_polar(faint, lat, alt, enu)
    r0, az0, el0 = frames.enu_to_polar(enu)
    np.testing.assert_allclose(rng_m, r0, rtol=0, atol=1e-6)
    np.testing.assert_allclose(az, az0, rtol=0, atol=0)
    np.testing.assert_allclose(el, el0, rtol=0, atol=1e-11)
    back = target_from_refracted(faint, lat, alt, r0, az0, el0)
    np.testing.assert_allclose(back, enu, rtol=0, atol=1e-6)
    height = refracted_ray(None, lat, alt, enu).target_height_m
    e2d = apparent_elevation_from_height(faint, lat, alt, r0, height)
    np.testing.assert_allclose(e2d, frames.elevation_from_height(r0, height, lat, alt),
                               rtol=0, atol=1e-11)


@pytest.mark.parametrize("n_s", [313.0, 320.0])
@pytest.mark.parametrize("alt_m", [0.0, 500.0])
def test_zenith_delay_is_the_closed_form(n_s, alt_m):
    atmosphere = Atmosphere(n_s)
    h = DEFAULT_SCALE_HEIGHT_M
    for top in (10e3, 30e3, 100e3, 300e3):
        rng_m, _, el = refracted_polar(atmosphere, math.radians(45.0), alt_m, [0.0, 0.0, top])
        closed = 1e-6 * n_s * h * (math.exp(-alt_m / h) - math.exp(-(alt_m + top) / h))
        assert rng_m[0] - top == pytest.approx(closed, abs=1e-7)
        assert el[0] == pytest.approx(math.pi / 2, abs=1e-12)
    if alt_m == 0.0:
        # Above the atmosphere: N_s H 1e-6, 2.19 m (313) to 2.24 m (320).
        assert 2.15 < rng_m[0] - top < 2.25


def test_bending_at_low_elevation():
    """A few milliradians at 0-1 deg elevation and 100-300 km, less at higher elevation."""
    lat, alt = PARIS
    atmosphere = Atmosphere(313.0)
    bending = np.zeros((3, 3))
    for i, el_deg in enumerate((0.0, 0.5, 1.0)):
        for j, rng_m in enumerate((100e3, 200e3, 300e3)):
            el = math.radians(el_deg)
            p = [0.0, rng_m * math.cos(el), rng_m * math.sin(el)]
            bending[i, j] = refracted_polar(atmosphere, lat, alt, p)[2][0] - el
    assert np.all((bending > 1e-3) & (bending < 10e-3))
    assert np.all(np.diff(bending, axis=0) < 0)  # less at higher elevation
    assert np.all(np.diff(bending, axis=1) > 0)  # more at longer range


@pytest.mark.parametrize("el_deg", [10.0, 30.0, 60.0])
def test_bending_below_astronomical_refraction(el_deg):
    """A target at finite distance is displaced less than a star: ``(n0 - 1) cot(e)``."""
    lat, alt = PARIS
    atmosphere = Atmosphere(320.0)
    el = math.radians(el_deg)
    n0 = float(atmosphere.refractive_index(alt))
    for rng_m in (30e3, 100e3, 300e3, 1000e3):
        p = [0.0, rng_m * math.cos(el), rng_m * math.sin(el)]
        bending = refracted_polar(atmosphere, lat, alt, p)[2][0] - el
        assert 0.0 < bending < (n0 - 1.0) / math.tan(el)
    # Far above the atmosphere they agree to within 10 % (the Earth's curvature, the
    # finite distance).
    assert bending == pytest.approx((n0 - 1.0) / math.tan(el), rel=0.1)


def random_targets(rng: np.random.Generator, lat: float, alt: float, n: int,
                   max_ground: float = 3e5, max_height: float = 1.2e4) -> np.ndarray:
    return np.array([target_enu(lat, alt, g, h, a) for g, h, a in zip(
        rng.uniform(2e3, max_ground, n), rng.uniform(0.0, max_height, n),
        rng.uniform(0.0, 2 * math.pi, n), strict=True)])


def numeric_jacobian(f, x: np.ndarray, steps: np.ndarray, wrap_row: int | None = None
                     ) -> np.ndarray:
    """Central differences of a vectorised ``f: (n, 3) -> (n, 3)`` at ``x``."""
    jac = np.zeros((len(x), 3, 3))
    for k in range(3):
        dx = np.zeros(3)
        dx[k] = steps[k]
        diff = f(x + dx) - f(x - dx)
        if wrap_row is not None:
            diff[:, wrap_row] = frames.wrap_to_pi(diff[:, wrap_row])
        jac[:, :, k] = diff / (2.0 * steps[k])
    return jac


def test_polar_jacobian_against_central_differences():
    rng = np.random.default_rng(11)
    lat, alt = math.radians(47.0), 900.0
    atmosphere = Atmosphere(320.0)
    enu = np.vstack([random_targets(rng, lat, alt, 60),
                     [target_enu(lat, alt, 250e3, 1500.0)],   # dips and rises
                     [target_enu(lat, alt, 110e3, 200.0)]])   # arrives about level
    polar, jac = refracted_polar_jacobian(atmosphere, lat, alt, enu)
    np.testing.assert_array_equal(polar, np.stack(refracted_polar(atmosphere, lat, alt, enu), -1))

    def f(p):
        return np.stack(refracted_polar(atmosphere, lat, alt, p), -1)

    numeric = numeric_jacobian(f, enu, np.full(3, 0.5), wrap_row=1)
    scale = np.linalg.norm(numeric, axis=2, keepdims=True)
    assert np.max(np.abs(jac - numeric) / scale) < 1e-6
    # Eikonal: |grad L| is the refractive index at the target.
    heights = refracted_ray(atmosphere, lat, alt, enu).target_height_m
    np.testing.assert_allclose(np.linalg.norm(jac[:, 0], axis=1),
                               atmosphere.refractive_index(heights), rtol=1e-12)


def test_polar_jacobian_undefined_at_zenith():
    with pytest.raises(ValueError, match="zenith"):
        refracted_polar_jacobian(Atmosphere(), 0.5, 0.0, [[0.0, 0.0, 1e4]])


def test_inverse_round_trip_and_jacobian():
    rng = np.random.default_rng(12)
    lat, alt = math.radians(-10.0), 60.0
    atmosphere = Atmosphere(360.0, 7500.0)
    enu = np.vstack([random_targets(rng, lat, alt, 200, max_height=2e4),
                     [target_enu(lat, alt, 300e3, 500.0)]])
    polar, jac = refracted_polar_jacobian(atmosphere, lat, alt, enu)
    back, inv = target_from_refracted_jacobian(atmosphere, lat, alt, *polar.T)
    np.testing.assert_allclose(back, enu, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(back, target_from_refracted(atmosphere, lat, alt, *polar.T))

    def f(x):
        return target_from_refracted(atmosphere, lat, alt, *x.T)

    numeric = numeric_jacobian(f, polar, np.array([0.5, 1e-6, 1e-6]))
    col = np.linalg.norm(numeric, axis=1, keepdims=True)
    assert np.max(np.abs(inv - numeric) / col) < 1e-6
    # The inverse's Jacobian inverts the forward one.
    identity = np.linalg.inv(jac) @ np.linalg.inv(inv)
    np.testing.assert_allclose(identity, np.broadcast_to(np.eye(3), identity.shape), atol=1e-6)


def test_height_inverse_round_trip_and_derivatives():
    rng = np.random.default_rng(13)
    lat, alt = math.radians(52.0), 35.0
    atmosphere = Atmosphere(330.0)
    enu = random_targets(rng, lat, alt, 200, max_height=1.5e4)
    ray = refracted_ray(atmosphere, lat, alt, enu)
    e0, d_range, d_height = apparent_elevation_from_height_jacobian(
        atmosphere, lat, alt, ray.range_m, ray.target_height_m)
    np.testing.assert_allclose(e0, ray.elevation_rad, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(
        e0, apparent_elevation_from_height(atmosphere, lat, alt, ray.range_m,
                                           ray.target_height_m))
    step = 0.05

    def e(rng_m, h):
        return apparent_elevation_from_height(atmosphere, lat, alt, rng_m, h)

    numeric_range = (e(ray.range_m + step, ray.target_height_m)
                     - e(ray.range_m - step, ray.target_height_m)) / (2 * step)
    numeric_height = (e(ray.range_m, ray.target_height_m + step)
                      - e(ray.range_m, ray.target_height_m - step)) / (2 * step)
    np.testing.assert_allclose(d_range, numeric_range, rtol=1e-5)
    np.testing.assert_allclose(d_height, numeric_height, rtol=1e-5)


def test_height_inverse_straight_derivatives():
    """Without atmosphere: the derivatives of (R + h)^2 = r0^2 + L^2 + 2 L r0 sin(e)."""
    lat, alt = math.radians(40.0), 300.0
    rng_m = np.array([20e3, 150e3, 300e3])
    height = np.array([9000.0, 6000.0, 11000.0])
    e0, d_range, d_height = apparent_elevation_from_height_jacobian(None, lat, alt, rng_m, height)
    step = 0.01
    np.testing.assert_allclose(
        d_range, (frames.elevation_from_height(rng_m + step, height, lat, alt)
                  - frames.elevation_from_height(rng_m - step, height, lat, alt)) / (2 * step),
        rtol=1e-6)
    np.testing.assert_allclose(
        d_height, (frames.elevation_from_height(rng_m, height + step, lat, alt)
                   - frames.elevation_from_height(rng_m, height - step, lat, alt)) / (2 * step),
        rtol=1e-6)


def test_batched_equals_one_at_a_time():
    rng = np.random.default_rng(14)
    lat, alt = MOUNTAIN
    atmosphere = Atmosphere(320.0)
    enu = np.vstack([random_targets(rng, lat, alt, 20), [target_enu(lat, alt, 250e3, 1500.0)]])
    batch = np.stack(refracted_polar(atmosphere, lat, alt, enu), -1)
    single = np.array([np.stack(refracted_polar(atmosphere, lat, alt, p), -1)[0] for p in enu])
    np.testing.assert_allclose(batch, single, rtol=1e-13, atol=1e-9)
    back = target_from_refracted(atmosphere, lat, alt, *batch.T)
    back_single = np.array([target_from_refracted(atmosphere, lat, alt, *x)[0] for x in batch])
    np.testing.assert_allclose(back, back_single, rtol=0, atol=1e-8)
    heights = refracted_ray(atmosphere, lat, alt, enu).target_height_m
    e_batch = apparent_elevation_from_height(atmosphere, lat, alt, batch[:, 0], heights)
    e_single = [apparent_elevation_from_height(atmosphere, lat, alt, r, h)[0]
                for r, h in zip(batch[:, 0], heights, strict=True)]
    np.testing.assert_allclose(e_batch, e_single, rtol=0, atol=1e-13)


def test_special_points():
    lat, alt = PARIS
    atmosphere = Atmosphere()
    ray = refracted_ray(atmosphere, lat, alt, [[0.0, 0.0, 0.0], [0.0, 0.0, -100.0]])
    # At the antenna: nothing; straight down: a vertical ray, 100 m plus its delay.
    assert ray.range_m[0] == 0.0 and ray.elevation_rad[0] == 0.0
    assert ray.elevation_rad[1] == pytest.approx(-math.pi / 2, abs=1e-12)
    closed = 1e-6 * DEFAULT_N_S * DEFAULT_SCALE_HEIGHT_M * (
        math.exp(-(alt - 100.0) / DEFAULT_SCALE_HEIGHT_M) - math.exp(-alt / DEFAULT_SCALE_HEIGHT_M))
    assert ray.range_m[1] - 100.0 == pytest.approx(closed, abs=1e-7)
    assert np.array_equal(target_from_refracted(atmosphere, lat, alt, 0.0, 1.0, 0.3),
                          np.zeros((1, 3)))
    with pytest.raises(ValueError, match="non-negative"):
        target_from_refracted(atmosphere, lat, alt, -1.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="shape"):
        refracted_polar(atmosphere, lat, alt, [1.0, 2.0])


def test_blocked_and_unreachable():
    lat, alt = PARIS
    atmosphere = Atmosphere(320.0)
    # Just beyond the radio horizon of a 1 km target the ray grazes below the ground;
    # 900 km away at 1 km the ray would pass 9 km underground: not solved.
    beyond = refracted_ray(atmosphere, lat, alt, [target_enu(lat, alt, 200e3, 1000.0),
                                                  target_enu(lat, alt, 900e3, 1000.0)])
    assert -1000.0 < beyond.lowest_height_m[0] < 0.0
    assert np.isnan(beyond.range_m[1]) and np.isnan(beyond.elevation_rad[1])
    # No ray of 1 km reaches 5 km higher.
    assert np.isnan(apparent_elevation_from_height(atmosphere, lat, alt, 1000.0, alt + 5000.0))


def test_refraction_sees_beyond_the_straight_horizon():
    """Below the straight line's horizon but above the refracted one (4/3-earth effect)."""
    lat, alt = PARIS
    p = target_enu(lat, alt, 165e3, 1000.0)
    assert refracted_ray(None, lat, alt, p).lowest_height_m[0] < 0.0
    assert refracted_ray(Atmosphere(313.0), lat, alt, p).lowest_height_m[0] > 0.0


def test_atmosphere():
    atmosphere = Atmosphere(320.0, 7000.0)
    assert atmosphere.refracts and not NO_REFRACTION.refracts
    np.testing.assert_allclose(atmosphere.refractive_index([0.0, 7000.0]),
                               [1.00032, 1.0 + 320e-6 / math.e], rtol=0, atol=1e-15)
    assert Atmosphere() == Atmosphere(DEFAULT_N_S, DEFAULT_SCALE_HEIGHT_M)
    for bad in [dict(n_s=-1.0), dict(n_s=math.nan), dict(scale_height_m=0.0),
                dict(scale_height_m=-7000.0), dict(n_s=500.0, scale_height_m=5000.0)]:
        with pytest.raises(ValueError):
            Atmosphere(**bad)

"""Tests of graphcal.data.bias: the bias model and its sign convention ("measured minus true").

Contract: range_measured = (1 + gain) * range_true + offset, azimuth_measured =
azimuth_true + azimuth_bias (wrapped to [0, 2 pi)), elevation_measured = elevation_true +
elevation_bias, time_reported = time_true + time_offset.  Angles in radians inside the code.
All randomness goes through ``numpy.random.default_rng`` with a fixed seed.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from graphcal.core.frames import TWO_PI, wrap_to_pi
from graphcal.data.bias import (
    CONTRACT_KEYS,
    NAME_FROM_KEY,
    PARAMETER_NAMES,
    RadarBias,
    apply_bias,
    compose_bias,
    correct_bias,
    correct_time,
    from_contract_units,
    measurement_bias_jacobian,
    to_contract_units,
)
from tests.jacobians import numerical_jacobian


def random_bias(rng: np.random.Generator) -> RadarBias:
    """A realistic random bias: +-500 m, +-1 % gain, +-10 mrad angles, +-2 s time."""
    return RadarBias(
        range_offset_m=rng.uniform(-500.0, 500.0),
        range_gain=rng.uniform(-0.01, 0.01),
        azimuth_bias_rad=rng.uniform(-0.01, 0.01),
        elevation_bias_rad=rng.uniform(-0.01, 0.01),
        time_offset_s=rng.uniform(-2.0, 2.0),
    )


# --------------------------------------------------------------------------------------
# Sign convention with hand-computed numbers
# --------------------------------------------------------------------------------------


def test_range_sign_convention_hand_computed():
    """True 100 km, gain 0.005, offset 50 m -> measured 1.005 * 100000 + 50 = 100550 m,
    and back.  Tolerance 1e-9 m (three float operations on 1e5 m, ulp 1.5e-11 m)."""
    bias = RadarBias(range_offset_m=50.0, range_gain=0.005)
    r_meas, az_meas, el_meas = apply_bias(100e3, 1.0, 0.1, bias)
    np.testing.assert_allclose(r_meas, 100550.0, rtol=0, atol=1e-9)
    assert az_meas == 1.0 and el_meas == 0.1  # no angle bias: angles untouched
    r_true, _, _ = correct_bias(100550.0, 1.0, 0.1, bias)
    np.testing.assert_allclose(r_true, 100e3, rtol=0, atol=1e-9)


def test_negative_range_bias_hand_computed():
    """Gain -0.002, offset -120 m: 250 km measures 0.998 * 250000 - 120 = 249380 m."""
    bias = RadarBias(range_offset_m=-120.0, range_gain=-0.002)
    r_meas, _, _ = apply_bias(250e3, 0.0, 0.0, bias)
    np.testing.assert_allclose(r_meas, 249380.0, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("az_true_deg", "bias_deg", "az_meas_deg"),
    [
        pytest.param(359.9, 0.2, 0.1, id="359.9+0.2->0.1"),
        pytest.param(0.1, -0.2, 359.9, id="0.1-0.2->359.9"),
        pytest.param(90.0, 0.5, 90.5, id="90+0.5"),
        pytest.param(180.0, -1.0, 179.0, id="180-1"),
        pytest.param(359.0, 1.0, 0.0, id="359+1->0-not-360"),
        pytest.param(0.0, 0.0, 0.0, id="zero"),
    ],
)
def test_azimuth_sign_convention_and_wrap(az_true_deg, bias_deg, az_meas_deg):
    """azimuth_measured = azimuth_true + bias, wrapped to [0, 2 pi) (never 2 pi itself).

    Tolerance 1e-12 rad: degree/radian conversion and one addition, compared on the circle
    (so 0 and 2*pi - 1e-16 count as equal), plus a strict range check.
    """
    bias = RadarBias(azimuth_bias_rad=np.deg2rad(bias_deg))
    _, az_meas, _ = apply_bias(1e4, np.deg2rad(az_true_deg), 0.0, bias)
    assert 0.0 <= az_meas < TWO_PI
    np.testing.assert_allclose(
        wrap_to_pi(az_meas - np.deg2rad(az_meas_deg)), 0.0, rtol=0, atol=1e-12
    )
    _, az_back, _ = correct_bias(1e4, az_meas, 0.0, bias)
    assert 0.0 <= az_back < TWO_PI
    np.testing.assert_allclose(
        wrap_to_pi(az_back - np.deg2rad(az_true_deg)), 0.0, rtol=0, atol=1e-12
    )


def test_azimuth_359_9_plus_0_2_in_degrees():
    """The contract example read as degrees: 359.9 deg + 0.2 deg bias reports 0.1 deg (not
    360.1).  Tolerance 1e-9 deg (rounding of the degree/radian conversion)."""
    bias = RadarBias(azimuth_bias_rad=np.deg2rad(0.2))
    _, az_meas, _ = apply_bias(1e4, np.deg2rad(359.9), 0.0, bias)
    np.testing.assert_allclose(np.rad2deg(az_meas), 0.1, rtol=0, atol=1e-9)


def test_elevation_sign_convention():
    """elevation_measured = elevation_true + bias, not wrapped: 2 deg + 0.5 mrad, and a
    negative elevation stays negative.  Tolerance 1e-15 rad (one addition)."""
    bias = RadarBias(elevation_bias_rad=0.5e-3)
    _, _, el = apply_bias([1e4, 1e4], [0.0, 0.0], [np.deg2rad(2.0), -0.01], bias)
    np.testing.assert_allclose(el, [np.deg2rad(2.0) + 0.5e-3, -0.0095], rtol=0, atol=1e-15)


def test_correct_time_sign_convention():
    """time_reported = time_true + offset, so a plot reported at 100 s by a radar whose clock
    is 0.25 s late happened at 99.75 s.  Tolerance 1e-12 s."""
    bias = RadarBias(time_offset_s=0.25)
    np.testing.assert_allclose(correct_time(100.0, bias), 99.75, rtol=0, atol=1e-12)
    rng = np.random.default_rng(41)
    t_true = rng.uniform(0.0, 86400.0, (2, 5))
    bias = random_bias(rng)
    t_back = correct_time(t_true + bias.time_offset_s, bias)
    assert t_back.shape == (2, 5)
    # 86400 s has ulp 1.5e-11 s.
    np.testing.assert_allclose(t_back, t_true, rtol=0, atol=1e-9)


def test_correct_time_only_uses_time_offset():
    """The spatial biases do not touch the time stamp."""
    bias = RadarBias(range_offset_m=100.0, range_gain=0.01, azimuth_bias_rad=0.1)
    np.testing.assert_array_equal(correct_time([1.0, 2.0], bias), [1.0, 2.0])


def test_zero_bias_is_identity():
    """The default RadarBias is all zeros and leaves plots unchanged (exactly)."""
    bias = RadarBias()
    np.testing.assert_array_equal(bias.as_vector(), np.zeros(4))
    assert bias.time_offset_s == 0.0
    r, az, el = apply_bias([1e4, 2e5], [0.5, 6.0], [0.01, np.nan], bias)
    np.testing.assert_array_equal(r, [1e4, 2e5])
    np.testing.assert_array_equal(az, [0.5, 6.0])
    np.testing.assert_array_equal(el, [0.01, np.nan])


# --------------------------------------------------------------------------------------
# Round trips
# --------------------------------------------------------------------------------------


def test_apply_then_correct_round_trip():
    """correct_bias(apply_bias(x, b), b) == x for random biases, with azimuths crowded near
    the 0 / 2 pi seam, over an (N,) and a (2, 5) batch.

    Tolerances: 1e-12 relative in range (a divide by 1 + gain), 1e-12 rad in angles
    (two additions and two wraps; azimuth compared on the circle).
    """
    rng = np.random.default_rng(42)
    n = 2000
    r = rng.uniform(1e3, 4e5, n)
    az = np.concatenate(
        [rng.uniform(0.0, 0.02, n // 4), rng.uniform(TWO_PI - 0.02, TWO_PI, n // 4)]
        + [rng.uniform(0.0, TWO_PI, n - 2 * (n // 4))]
    )
    el = rng.uniform(-0.05, 1.2, n)
    for _ in range(20):
        bias = random_bias(rng)
        r_m, az_m, el_m = apply_bias(r, az, el, bias)
        assert np.all((az_m >= 0.0) & (az_m < TWO_PI))
        r_c, az_c, el_c = correct_bias(r_m, az_m, el_m, bias)
        assert np.all((az_c >= 0.0) & (az_c < TWO_PI))
        np.testing.assert_allclose(r_c, r, rtol=1e-12)
        np.testing.assert_allclose(wrap_to_pi(az_c - az), 0.0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(el_c, el, rtol=0, atol=1e-12)
        # The bias really moved the plot (so the round trip is not vacuous).
        assert np.all(np.abs(r_m - r) > 0.0)

    bias = random_bias(rng)
    batch = [a[:10].reshape(2, 5) for a in (r, az, el)]
    measured = apply_bias(*batch, bias)
    for comp in measured:
        assert comp.shape == (2, 5)
    corrected = correct_bias(*measured, bias)
    np.testing.assert_allclose(corrected[0], batch[0], rtol=1e-12)
    np.testing.assert_allclose(wrap_to_pi(corrected[1] - batch[1]), 0.0, rtol=0, atol=1e-12)
    for idx in np.ndindex(2, 5):
        single = apply_bias(batch[0][idx], batch[1][idx], batch[2][idx], bias)
        for batched, one in zip(measured, single, strict=True):
            np.testing.assert_allclose(batched[idx], one, rtol=1e-15, atol=0)


def test_correct_then_apply_round_trip():
    """apply_bias(correct_bias(m, b), b) == m too (the maps are mutual inverses).
    Tolerances as for the forward round trip."""
    rng = np.random.default_rng(43)
    r = rng.uniform(1e3, 4e5, 500)
    az = rng.uniform(0.0, TWO_PI, 500)
    el = rng.uniform(-0.05, 1.2, 500)
    bias = random_bias(rng)
    r2, az2, el2 = apply_bias(*correct_bias(r, az, el, bias), bias)
    np.testing.assert_allclose(r2, r, rtol=1e-12)
    np.testing.assert_allclose(wrap_to_pi(az2 - az), 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(el2, el, rtol=0, atol=1e-12)


def test_nan_elevation_stays_nan():
    """2-D radars have NaN elevation: it stays NaN through apply and correct, while range
    and azimuth of the same plots are still biased / corrected normally."""
    bias = RadarBias(
        range_offset_m=50.0, range_gain=0.005, azimuth_bias_rad=1e-3, elevation_bias_rad=2e-3
    )
    el = np.array([np.nan, 0.1, np.nan])
    r_m, az_m, el_m = apply_bias([1e5, 1e5, 2e5], [0.0, 1.0, 2.0], el, bias)
    assert np.isnan(el_m[0]) and np.isnan(el_m[2])
    np.testing.assert_allclose(el_m[1], 0.102, rtol=0, atol=1e-15)
    np.testing.assert_allclose(r_m, [100550.0, 100550.0, 201050.0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(az_m, [1e-3, 1.001, 2.001], rtol=0, atol=1e-15)
    r_c, az_c, el_c = correct_bias(r_m, az_m, el_m, bias)
    assert np.isnan(el_c[0]) and np.isnan(el_c[2])
    np.testing.assert_allclose(r_c, [1e5, 1e5, 2e5], rtol=1e-14)
    np.testing.assert_allclose(el_c[1], 0.1, rtol=0, atol=1e-15)
    # Scalar NaN too.
    assert np.isnan(apply_bias(1e4, 0.0, np.nan, bias)[2])


def test_compose_bias_equals_successive_application():
    """compose_bias(first, inc) is the single bias equal to applying ``inc`` and then
    ``first``: correcting with ``first`` leaves exactly ``inc`` in the plots.

    Tolerances 1e-12 relative in range and 1e-12 rad in angles (a few roundings).
    """
    rng = np.random.default_rng(44)
    r = rng.uniform(1e3, 4e5, 300)
    az = rng.uniform(0.0, TWO_PI, 300)
    el = rng.uniform(-0.05, 1.2, 300)
    first, inc = random_bias(rng), random_bias(rng)
    total = compose_bias(first, inc)
    twice = apply_bias(*apply_bias(r, az, el, inc), first)
    once = apply_bias(r, az, el, total)
    np.testing.assert_allclose(once[0], twice[0], rtol=1e-12)
    np.testing.assert_allclose(wrap_to_pi(once[1] - twice[1]), 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(once[2], twice[2], rtol=0, atol=1e-12)
    left = correct_bias(*once, first)
    direct = apply_bias(r, az, el, inc)
    np.testing.assert_allclose(left[0], direct[0], rtol=1e-12)
    np.testing.assert_allclose(total.time_offset_s, first.time_offset_s + inc.time_offset_s)
    # Composing with zero is the identity (to 1e-15: (1 + g) * 1 - 1 rounds the gain).
    np.testing.assert_allclose(
        compose_bias(first, RadarBias()).as_vector(), first.as_vector(), rtol=0, atol=1e-15
    )
    np.testing.assert_allclose(
        compose_bias(RadarBias(), inc).as_vector(), inc.as_vector(), rtol=0, atol=1e-15
    )


# --------------------------------------------------------------------------------------
# Jacobian
# --------------------------------------------------------------------------------------


def test_measurement_bias_jacobian_finite_differences():
    """measurement_bias_jacobian equals central differences of apply_bias with respect to
    (offset, gain, azimuth bias, elevation bias).

    apply_bias is affine in the biases, so central differences have no truncation error.
    Steps 1 m, 1e-6, 1e-6 rad, 1e-6 rad; rounding error ~eps * 4e5 m / 1e-6 ~ 1e-4 m per
    unit gain on a derivative of ~1e5 m, hence rtol 1e-8 plus atol 1e-8 for the zeros.
    Azimuths straddle the 0/2 pi seam; azimuth differences are wrapped.
    """
    rng = np.random.default_rng(45)
    n = 200
    r = rng.uniform(1e3, 4e5, n)
    az = rng.uniform(0.0, TWO_PI, n)
    az[:2] = [1e-9, TWO_PI - 1e-9]
    el = rng.uniform(-0.05, 1.2, n)
    base = random_bias(rng).as_vector()
    steps = np.array([1.0, 1e-6, 1e-6, 1e-6])

    def measured(vector: np.ndarray) -> np.ndarray:
        return np.stack(apply_bias(r, az, el, RadarBias.from_vector(vector)), axis=-1)

    def wrapped(plus: np.ndarray, minus: np.ndarray) -> np.ndarray:
        delta = plus - minus
        delta[:, 1] = wrap_to_pi(delta[:, 1])
        return delta

    fd = numerical_jacobian(measured, base, steps, difference=wrapped)
    jac = measurement_bias_jacobian(r)
    assert jac.shape == (n, 3, 4)
    np.testing.assert_allclose(jac, fd, rtol=1e-8, atol=1e-8)


def test_measurement_bias_jacobian_layout_and_batch():
    """Exact layout [[1, r, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]] for a scalar and a (2, 5)
    batch (columns in PARAMETER_NAMES order)."""
    np.testing.assert_array_equal(
        measurement_bias_jacobian(1234.5),
        [[1.0, 1234.5, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
    )
    r = np.arange(10.0).reshape(2, 5) * 1e4
    jac = measurement_bias_jacobian(r)
    assert jac.shape == (2, 5, 3, 4)
    for idx in np.ndindex(2, 5):
        np.testing.assert_array_equal(jac[idx], measurement_bias_jacobian(r[idx]))
    assert PARAMETER_NAMES == ("range_offset", "range_gain", "azimuth_bias", "elevation_bias")


# --------------------------------------------------------------------------------------
# Units and the parameter vector
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "value_si", "key", "value_contract"),
    [
        pytest.param("range_offset", -93.7, "range_offset_m", -93.7, id="range_offset_m"),
        pytest.param("range_gain", 0.000694, "range_gain", 0.000694, id="range_gain"),
        pytest.param("azimuth_bias", -3.10e-3, "azimuth_bias_mrad", -3.10, id="azimuth_mrad"),
        pytest.param("elevation_bias", 2e-3, "elevation_bias_mrad", 2.0, id="elevation_mrad"),
        pytest.param("time_offset", 0.25, "time_offset_s", 0.25, id="time_offset_s"),
    ],
)
def test_contract_units(name, value_si, key, value_contract):
    """SI <-> contract units: angles in mrad (1 mrad = 1e-3 rad), the rest unchanged; the
    keys are the contract's JSON keys.  Tolerance 1e-12 relative (one multiply/divide)."""
    assert CONTRACT_KEYS[name][0] == key
    assert NAME_FROM_KEY[key] == name
    np.testing.assert_allclose(to_contract_units(name, value_si), value_contract, rtol=1e-12)
    np.testing.assert_allclose(from_contract_units(name, value_contract), value_si, rtol=1e-12)


def test_contract_units_round_trip_and_keys():
    """Random values survive SI -> contract -> SI for every parameter (rtol 1e-15), every
    estimated parameter has a contract key, and NAME_FROM_KEY inverts CONTRACT_KEYS."""
    rng = np.random.default_rng(46)
    assert set(PARAMETER_NAMES) <= set(CONTRACT_KEYS)
    assert {key for key, _ in CONTRACT_KEYS.values()} == {
        "range_offset_m",
        "range_gain",
        "azimuth_bias_mrad",
        "elevation_bias_mrad",
        "time_offset_s",
        "azimuth_sin_mrad",
        "azimuth_cos_mrad",
    }
    for name, (key, _) in CONTRACT_KEYS.items():
        assert NAME_FROM_KEY[key] == name
        for value in rng.normal(0.0, 10.0, 20):
            back = from_contract_units(name, to_contract_units(name, value))
            np.testing.assert_allclose(back, value, rtol=1e-15)


def test_radar_bias_vector_round_trip():
    """as_vector uses PARAMETER_NAMES order and from_vector inverts it exactly (time offset
    passed separately); an unset time offset defaults to 0."""
    rng = np.random.default_rng(47)
    for _ in range(10):
        bias = random_bias(rng)
        vec = bias.as_vector()
        assert vec.shape == (4,)
        np.testing.assert_array_equal(
            vec,
            [bias.range_offset_m, bias.range_gain, bias.azimuth_bias_rad, bias.elevation_bias_rad],
        )
        assert RadarBias.from_vector(vec, bias.time_offset_s) == bias
        assert RadarBias.from_vector(vec).time_offset_s == 0.0
    ordered = RadarBias.from_vector([1.0, 2.0, 3.0, 4.0], 5.0)
    assert ordered == RadarBias(1.0, 2.0, 3.0, 4.0, 5.0)
    assert ordered.range_offset_m == 1.0 and ordered.range_gain == 2.0
    assert ordered.azimuth_bias_rad == 3.0 and ordered.elevation_bias_rad == 4.0
    # from_vector stores plain floats, not numpy scalars or arrays.
    assert all(type(getattr(ordered, f.name)) is float for f in dataclasses.fields(ordered))


def test_radar_bias_is_frozen():
    """RadarBias is immutable (it is shared between estimators and results)."""
    bias = RadarBias(range_offset_m=1.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        bias.range_offset_m = 2.0  # type: ignore[misc]


def test_eccentricity_follows_the_contract_and_inverts() -> None:
    """Contract v2: az_m = az + b + s sin(az) + c cos(az); correcting inverts it (Newton) to
    1e-12 rad for eccentricities up to 20 mrad, across the 0 / 2 pi seam."""
    rng = np.random.default_rng(47)
    az = rng.uniform(0.0, TWO_PI, 500)
    az[:2] = [1e-9, TWO_PI - 1e-9]
    r = rng.uniform(1e3, 3e5, 500)
    el = rng.uniform(0.0, 0.5, 500)
    for s, c in [(2e-3, -1e-3), (-0.02, 0.015), (0.0, 5e-3)]:
        bias = RadarBias(10.0, 1e-4, 3e-3, 1e-3, azimuth_sin_rad=s, azimuth_cos_rad=c)
        _, az_m, _ = apply_bias(r, az, el, bias)
        expected = np.mod(az + 3e-3 + s * np.sin(az) + c * np.cos(az), TWO_PI)
        np.testing.assert_allclose(wrap_to_pi(az_m - expected), 0.0, atol=1e-13)
        _, az_back, _ = correct_bias(*apply_bias(r, az, el, bias), bias)
        np.testing.assert_allclose(wrap_to_pi(az_back - az), 0.0, atol=1e-12)
    assert RadarBias(azimuth_sin_rad=1e-3).value("azimuth_sin") == 1e-3
    assert not RadarBias(1.0, 0.1, 0.1, 0.1, 1.0).has_eccentricity

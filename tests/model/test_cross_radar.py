"""Plots placed along refracted rays by the linearised ray excess
(:class:`graphcal.model.cross_radar.RayExcess`) against the rays traced exactly."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from graphcal.data.align import plot_arrays
from graphcal.model.cross_radar import (
    RAY_EXCESS_ELEVATION_TOLERANCE_RAD,
    RAY_EXCESS_RANGE_TOLERANCE_M,
    corrected_ecef,
    ray_excess,
    ray_excess_near,
)
from graphcal.model.measurement import biased_polar, corrected_polar
from graphcal.model.parameters import TERM_NAMES
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.jacobians import numerical_jacobian
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def dataset():
    scenario = load_scenario(SCENARIOS / "demo_refraction.toml")
    return simulate(scenario, np.random.default_rng(3)).dataset


# OUEST3D: a 3-D radar; APP: a 2-D radar placing its plots at their reported heights.
@pytest.mark.parametrize("radar", ["OUEST3D", "APP"])
def test_placement_at_the_centre_is_the_traced_ray(dataset, radar: str) -> None:
    """Where the excess was traced, positions and Jacobians equal the exact ray tracing."""
    site, plots = dataset.sites[radar], plot_arrays(dataset, radar)
    bias = np.array([30.0, 1e-4, 1e-3, 1e-3 if site.is_3d else 0.0])
    excess = ray_excess_near(None, site, plots, bias)
    exact, exact_jac, exact_ok = corrected_ecef(site, plots, bias)
    fast, fast_jac, fast_ok = corrected_ecef(site, plots, bias, refraction=excess)
    np.testing.assert_array_equal(fast_ok, exact_ok)
    assert np.abs(fast[exact_ok] - exact[exact_ok]).max() < 1e-6
    scale = np.abs(exact_jac[exact_ok]).max(axis=(0, 1))
    assert np.all(np.abs(fast_jac[exact_ok] - exact_jac[exact_ok]).max(axis=(0, 1))
                  <= 1e-9 * np.maximum(scale, 1.0))


@pytest.mark.parametrize("radar", ["OUEST3D", "APP"])
def test_placement_within_the_tolerance_stays_within_millimetres(dataset, radar: str) -> None:
    """Corrections up to the re-tracing tolerance from the centre: under 5 mm from the exact
    ray (the error grows as the square of the step; 0.1 mrad, 25 m here)."""
    site, plots = dataset.sites[radar], plot_arrays(dataset, radar)
    excess = ray_excess(site, plots)
    bias = np.array([RAY_EXCESS_RANGE_TOLERANCE_M, 0.0, 2e-3,
                     RAY_EXCESS_ELEVATION_TOLERANCE_RAD if site.is_3d else 0.0])
    exact, _, ok = corrected_ecef(site, plots, bias)
    fast, _, _ = corrected_ecef(site, plots, bias, refraction=excess)
    error = np.linalg.norm(fast[ok] - exact[ok], axis=1)
    assert error.max() < 5e-3
    # Five times further in elevation: the linearisation alone is no longer enough.
    if site.is_3d:
        far = bias + np.array([0.0, 0.0, 0.0, 4 * RAY_EXCESS_ELEVATION_TOLERANCE_RAD])
        exact, _, ok = corrected_ecef(site, plots, far)
        fast, _, _ = corrected_ecef(site, plots, far, refraction=excess)
        assert np.linalg.norm(fast[ok] - exact[ok], axis=1).max() > 1e-2


def test_the_excess_is_traced_again_only_beyond_its_tolerance(dataset) -> None:
    site, plots = dataset.sites["OUEST3D"], plot_arrays(dataset, "OUEST3D")
    excess = ray_excess(site, plots)
    near = np.array([0.5 * RAY_EXCESS_RANGE_TOLERANCE_M, 0.0, 5e-3,
                     0.5 * RAY_EXCESS_ELEVATION_TOLERANCE_RAD])
    assert ray_excess_near(excess, site, plots, near) is excess
    for far in ([2 * RAY_EXCESS_RANGE_TOLERANCE_M, 0, 0, 0],
                [0, 0, 0, 2 * RAY_EXCESS_ELEVATION_TOLERANCE_RAD]):
        again = ray_excess_near(excess, site, plots, np.array(far, dtype=float))
        assert again is not excess
        np.testing.assert_allclose(again.range_m, np.nan_to_num(plots.range_m) - far[0])


def test_no_atmosphere_no_excess(dataset) -> None:
    site = replace(dataset.sites["NORD"], refraction="none")
    plots = plot_arrays(dataset, "NORD")
    assert ray_excess(site, plots) is None
    assert ray_excess_near(None, site, plots, np.zeros(4)) is None


def test_plot_covariances_look_up_labels_in_any_order() -> None:
    """Parts with a label in common: one entry per label; lookups in any order; an unknown
    label is an error, not a neighbour's covariance."""
    from graphcal.model.cross_radar import PlotCovariances

    eye = np.eye(3)
    table = PlotCovariances.collect([np.array([7, 3]), np.array([3, 11])],
                                    [np.stack([7 * eye, 3 * eye]), np.stack([3 * eye, 11 * eye])])
    assert table.labels.tolist() == [3, 7, 11]
    assert table.of(np.array([11, 3, 7, 3]))[:, 0, 0].tolist() == [11.0, 3.0, 7.0, 3.0]
    with pytest.raises(KeyError):
        table.of(np.array([5]))


def test_the_middle_of_column_blocks_equals_the_dense_middle() -> None:
    """Three blocks on overlapping column subsets of 9, sharing plots, with zero
    coefficients here and there: the block-wise middle equals gradient_noise_middle of
    the same observations written out over all 9 columns."""
    from graphcal.model.cross_radar import (
        PlotCovariances,
        gradient_noise_middle,
        gradient_noise_middle_of_blocks,
    )

    rng = np.random.default_rng(8)
    p, plots = 9, np.arange(100, 160)
    a = rng.normal(size=(len(plots), 3, 3))
    table = PlotCovariances.collect([plots], [a @ np.swapaxes(a, 1, 2)])
    blocks, dense_q, dense_rows, dense_c = [], [], [], []
    for cols, width in (([0, 1, 2, 6], 1), ([0, 1, 3, 4], 3), ([3, 4, 5, 6, 7, 8], 2)):
        m = 40
        ht_q = rng.normal(size=(m, len(cols), 3))
        rows = rng.choice(plots, size=(m, width))
        coef = rng.normal(size=(m, width)) * (rng.random((m, width)) > 0.2)
        blocks.append((cols, ht_q, rows, coef))
        full = np.zeros((m, p, 3))
        full[:, cols, :] = ht_q
        dense_q.append(full)
        dense_rows.append(np.pad(rows, ((0, 0), (0, 3 - width)), mode="edge"))
        dense_c.append(np.pad(coef, ((0, 0), (0, 3 - width))))
    expected = gradient_noise_middle(np.concatenate(dense_q), np.concatenate(dense_rows),
                                     np.concatenate(dense_c), table)
    actual = gradient_noise_middle_of_blocks(blocks, table, p)
    np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-9 * np.abs(expected).max())


# --------------------------------------------------------------------------- the inverse bias model
#: Terms of TERM_NAMES with a non-zero eccentricity (the time offset moves no plot).
ECCENTRIC_TERMS = np.array([40.0, 1.5e-3, 2e-3, -1e-3, 0.0, 1.2e-3, -0.8e-3])
TERM_STEPS = np.array([1.0, 1e-6, 1e-6, 1e-6, 1e-3, 1e-6, 1e-6])


def _wrapped_rows(plus: np.ndarray, minus: np.ndarray) -> np.ndarray:
    """plus - minus of (3, n) polar coordinates, the azimuth row wrapped to [-pi, pi)."""
    delta = plus - minus
    delta[1] = np.mod(delta[1] + np.pi, 2 * np.pi) - np.pi
    return delta


@pytest.mark.parametrize("terms", [ECCENTRIC_TERMS, ECCENTRIC_TERMS * [1, 1, 1, 1, 1, 0, 0]])
def test_corrected_polar_is_the_inverse_with_the_implicit_jacobian(terms: np.ndarray) -> None:
    """corrected_polar inverts biased_polar, and its Jacobian in the terms equals both
    central differences of the inverse and -slope^-1 d_terms of the forward model at the
    corrected point (the implicit function theorem)."""
    rng = np.random.default_rng(21)
    n = 40
    measured = np.column_stack([rng.uniform(5e3, 250e3, n), rng.uniform(0.0, 2 * np.pi, n),
                                rng.uniform(-0.01, 0.3, n)])
    measured[:3, 1] = [0.0, 1e-4, 2 * np.pi - 1e-4]  # at the 0 / 2 pi seam
    true, d_true = corrected_polar(measured, terms, TERM_NAMES)
    again, slope, d_terms = biased_polar(true, terms, TERM_NAMES)
    np.testing.assert_allclose(again[:, [0, 2]], measured[:, [0, 2]], rtol=1e-14, atol=1e-9)
    assert np.abs(np.mod(again[:, 1] - measured[:, 1] + np.pi, 2 * np.pi) - np.pi).max() < 1e-14
    numeric = numerical_jacobian(lambda t: corrected_polar(measured, t)[0].T, terms, TERM_STEPS,
                                 difference=_wrapped_rows)
    np.testing.assert_allclose(d_true, np.moveaxis(numeric, 1, 0), rtol=1e-7, atol=1e-9)
    implicit = -np.linalg.solve(np.einsum("ni,ij->nij", slope, np.eye(3)), d_terms)
    np.testing.assert_allclose(d_true, implicit, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("radar", ["OUEST3D", "APP"])
@pytest.mark.parametrize("refracted", [False, True])
def test_corrected_ecef_jacobian_matches_numerical(dataset, radar: str, refracted: bool) -> None:
    """d ecef / d (biases, s, c) of the corrected plots against central differences:
    straight rays, and refracted ones through the linearised ray excess; a 2-D radar's
    plots placed at their reported heights (its elevation-bias column is 0)."""
    site, plots = dataset.sites[radar], plot_arrays(dataset, radar)
    plots = plots.subset(np.arange(0, len(plots.range_m), 25))
    if not refracted:
        site = replace(site, refraction="none")
    bias = np.array([30.0, 2e-4, 1.5e-3, 1e-3 if site.is_3d else 0.0])
    eccentricity = (1.2e-3, -0.8e-3)
    rays = ray_excess(site, plots) if refracted else None
    _, jac, ok = corrected_ecef(site, plots, bias, eccentricity, refraction=rays)
    assert ok.sum() > 50

    def ecef(v: np.ndarray) -> np.ndarray:
        return corrected_ecef(site, plots, v[:4], (v[4], v[5]), refraction=rays)[0]

    numeric = numerical_jacobian(ecef, np.r_[bias, eccentricity], TERM_STEPS[[0, 1, 2, 3, 5, 6]])
    scale = np.abs(numeric[ok]).max(axis=(0, 1))
    assert np.all(np.abs(jac[ok] - numeric[ok]).max(axis=(0, 1)) <= 1e-6 * np.maximum(scale, 1.0))
    if not site.is_3d:
        assert not np.any(jac[:, :, 3])

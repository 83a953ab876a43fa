"""The Cramér-Rao bound with pressure altitudes: the height model as an unknown."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from graphcal.analysis.crlb import crlb
from graphcal.data.height import height_jacobian
from graphcal.model.height import HEIGHT_PRIOR_SIGMA, adsb_height_segments
from tests.model.test_height import TRUE_HEIGHT, pressure_network


@pytest.fixture(scope="module")
def pressure():
    """Three radars (2-D A and C, 3-D B), two aircraft; plots with pressure altitudes."""
    dataset = pressure_network(noise=True, seed=5)
    adsb = dataset.adsb.copy()
    adsb["baro_alt_m"] = TRUE_HEIGHT.pressure(adsb["alt_m"].to_numpy())
    return dataclasses.replace(dataset, adsb=adsb)


def _known_heights(dataset):
    """The same plots with the true heights (the height model known)."""
    plots = dataset.plots.copy()
    plots["altitude_m"] = TRUE_HEIGHT.geometric(plots["altitude_m"].to_numpy())
    return dataclasses.replace(dataset, plots=plots, plot_altitude="geometric")


def test_an_unknown_height_model_widens_the_cross_radar_bound(pressure) -> None:
    """Eliminating (d, k) can only lose information: every radar term's bound is at least
    the bound with known heights, and the 2-D radars' range terms lose visibly."""
    unknown = crlb(pressure, use_adsb=False, height_model=TRUE_HEIGHT)
    known = crlb(_known_heights(pressure), use_adsb=False)
    assert unknown.labels == known.labels and known.atmosphere_sigma is None
    ratio = np.sqrt(np.diag(unknown.covariance) / np.diag(known.covariance))
    assert np.all(ratio >= 1.0 - 1e-9)
    worst = {label: r for label, r in zip(unknown.labels, ratio, strict=True)}
    assert max(worst[("A", "range_offset")], worst[("C", "range_offset")]) > 1.05
    # 3-D radar B's elevation and the 2-D plots' heights tie (d, k): a finite bound.
    assert np.isfinite(unknown.atmosphere_sigma["height_offset_m"])
    assert unknown.atmosphere_sigma["height_offset_m"] < 1000.0


def test_adsb_height_segments_give_the_height_model_bound(pressure) -> None:
    """With ADS-B every plot is matched (no cross-radar event): the height model's bound is
    the inverse of its segments' information plus the prior, computed here directly."""
    bound = crlb(pressure, priors="graph", height_model=TRUE_HEIGHT)
    seg = adsb_height_segments(pressure.adsb)
    jac = height_jacobian(seg.pressure_m) / seg.sigma_m[:, None]
    information = jac.T @ jac + np.diag(np.array(HEIGHT_PRIOR_SIGMA) ** -2.0)
    expected = np.sqrt(np.diag(np.linalg.inv(information)))
    assert bound.info["n_events"] == 0 and bound.info["n_adsb_height_segments"] == len(seg)
    assert bound.atmosphere_sigma["height_offset_m"] == pytest.approx(expected[0], rel=1e-9)
    assert bound.atmosphere_sigma["height_scale"] == pytest.approx(expected[1], rel=1e-9)


def test_nothing_observes_the_height_model(pressure) -> None:
    no_baro = dataclasses.replace(pressure, adsb=pressure.adsb.drop(columns="baro_alt_m"))
    bound = crlb(no_baro)
    assert bound.atmosphere_sigma == {"height_offset_m": np.inf, "height_scale": np.inf}
    # The radar terms are bounded as if the heights were known: no plot uses one.
    known = crlb(_known_heights(no_baro))
    np.testing.assert_allclose(bound.covariance, known.covariance, rtol=1e-9)

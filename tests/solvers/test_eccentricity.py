"""Azimuth eccentricity (contract v2): simulated truth recovered by the graph, reported in
the result JSON, with and without ADS-B."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphcal.io.folder import load_dataset, write_dataset
from graphcal.pipeline.calibrate import calibrate
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.paths import SCENARIOS

ECCENTRIC_RADARS = ("NORD", "EST3D")


@pytest.fixture(scope="module")
def runs():
    scenario = load_scenario(SCENARIOS / "demo_eccentricity.toml")
    return [simulate(scenario, np.random.default_rng(seed)) for seed in (21, 22)]


def _z(cal, biases) -> dict[tuple[str, str], float]:
    sd = np.sqrt(np.diag(cal.covariance))
    return {(rid, name): (cal.estimate[i] - biases[rid].value(name)) / sd[i]
            for i, (rid, name) in enumerate(cal.labels)}


@pytest.mark.parametrize("use_adsb", [True, False])
def test_every_parameter_within_3_sigma_and_efficient(runs, use_adsb: bool) -> None:
    z_all = []
    for run in runs:
        cal = calibrate(run.dataset, use_adsb=use_adsb)
        for rid in ECCENTRIC_RADARS:
            assert (rid, "azimuth_sin") in cal.labels and (rid, "azimuth_cos") in cal.labels
        assert not any(name.startswith("azimuth_sin") for rid, name in cal.labels
                       if rid not in ECCENTRIC_RADARS)
        z = _z(cal, run.biases)
        assert max(abs(v) for v in z.values()) < 3.0, z
        z_all.extend(z.values())
        for rid in ECCENTRIC_RADARS:
            for key in ("azimuth_sin_mrad", "azimuth_cos_mrad"):
                assert 0.85 < cal.info["efficiency"][f"{rid}.{key}"] < 1.35
    assert 0.3 < np.mean(np.square(z_all)) < 2.0


def test_ignoring_the_eccentricity_is_visible(runs) -> None:
    """The same data calibrated without the eccentricity terms: NORD's (2-D radar) ADS-B
    residuals no longer fit their noise (chi2/dof well above its scatter about 1)."""
    run = runs[0]
    sites = {rid: site for rid, site in run.dataset.sites.items()}
    from dataclasses import replace

    from graphcal.data.dataset import Dataset

    plain = {rid: replace(s, estimate=tuple(n for n in s.estimate
                                            if n != "azimuth_eccentricity"))
             for rid, s in sites.items()}
    ds = Dataset(plain, run.dataset.plots, run.dataset.adsb)
    with_terms = calibrate(run.dataset, time_offset="off")
    without = calibrate(ds, time_offset="off")
    fit, misfit = with_terms.residuals["NORD"], without.residuals["NORD"]
    # chi2/dof of 2 n measurements scatters by sqrt(2 / 2n) about 1 when the model fits.
    spread = np.sqrt(2.0 / (2 * fit.n))
    assert abs(fit.chi2_per_dof - 1.0) < 4 * spread
    assert misfit.chi2_per_dof - fit.chi2_per_dof > 8 * spread


def test_result_json_and_sites_round_trip(runs, tmp_path) -> None:
    run = runs[0]
    folder = write_dataset(run.dataset, tmp_path / "ds")
    assert "azimuth_eccentricity" in (folder / "sites.toml").read_text()
    loaded = load_dataset(folder)
    assert loaded.sites["NORD"].estimate == run.dataset.sites["NORD"].estimate
    cal = calibrate(loaded, "graph", time_offset="off")
    data = json.loads(cal.to_json())
    assert data["radars"]["NORD"]["azimuth_sin_mrad"] == pytest.approx(
        cal.value("NORD", "azimuth_sin_mrad"))
    assert "azimuth_cos_mrad" in data["radars"]["NORD"]["sigma"]
    assert data["radars"]["SUD"]["azimuth_sin_mrad"] is None
    assert "NORD.azimuth_cos_mrad" in data["covariance"]["labels"]
    again = type(cal).from_dict(data)
    assert again.bias("NORD").azimuth_sin_rad == pytest.approx(cal.bias("NORD").azimuth_sin_rad)


def test_version_1_results_keep_version_1_keys(runs) -> None:
    from dataclasses import replace

    from graphcal.data.dataset import Dataset

    run = runs[0]
    plain = {rid: replace(s, estimate=tuple(n for n in s.estimate
                                            if n != "azimuth_eccentricity"))
             for rid, s in run.dataset.sites.items()}
    cal = calibrate(Dataset(plain, run.dataset.plots, run.dataset.adsb), "fl-ls")
    assert "azimuth_sin_mrad" not in json.loads(cal.to_json())["radars"]["NORD"]


def test_target_state_mode_refuses_eccentricity(runs) -> None:
    with pytest.raises(ValueError, match="eccentricity"):
        calibrate(runs[0].dataset, cross="target-state")

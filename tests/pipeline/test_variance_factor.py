"""Residuals beyond their sigmas widen ``graph``'s sigmas (docs/model-checks.md,
"When the residuals exceed their sigmas").

The demo network (seed 1) with its stated noise too small: the ADS-B ``sigma_m``
divided by 20 (NORD and SUD's range residuals chi2/dof 1.95 and 1.92; before, exit 0
without a word and sigmas 30 % too small), or NORD's ``sigma_range_m`` 3 m instead of
30 m (1.94).  Clean data are left alone.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import graphcal
from graphcal.analysis.fit_verdict import (
    WIDEN_FLOOR,
    CoordinateFit,
    FitVerdict,
    RadarFit,
    pooled_verdict,
    sigma_inflation,
    widen_limit,
)
from graphcal.cli.app import app
from graphcal.data.calibration import Calibration
from graphcal.solvers.registry import calibrate as estimate
from graphcal.solvers.window_fit import WindowFit

runner = CliRunner()
WIDENED = "its residuals exceed their sigmas beyond chance"




@pytest.fixture(scope="module")
def clean_result(demo_dir, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("clean") / "result.json"
    result = runner.invoke(app, ["calibrate", str(demo_dir), "--out", str(out)])
    assert result.exit_code == 0, result.output
    return json.loads(out.read_text())


def _adsb_too_confident(demo_dir: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "adsb20"
    folder.mkdir()
    for item in demo_dir.iterdir():
        (folder / item.name).write_bytes(item.read_bytes())
    adsb = pd.read_csv(folder / "adsb.csv", dtype={"target_id": str})
    adsb["sigma_m"] = adsb["sigma_m"] / 20.0
    adsb["nacp"] = 11
    adsb.to_csv(folder / "adsb.csv", index=False)
    return folder


def _consistent(path: Path) -> Calibration:
    """The result reads back, and its sigmas are its covariance's diagonal."""
    cal = Calibration.read_json(path)
    cov = cal.covariance_contract
    for i, label in enumerate(cal.contract_labels()):
        rid, key = label.split(".", 1)
        assert cal.sigma(rid, key) == pytest.approx(math.sqrt(cov[i, i]), rel=1e-9)
    assert np.linalg.eigvalsh(cal.covariance_si / np.sqrt(np.outer(
        np.diag(cal.covariance_si), np.diag(cal.covariance_si)))).min() > -1e-9
    return cal


def test_adsb_sigma_too_small_widens_nord_and_sud(demo_dir, clean_result, tmp_path) -> None:
    """ADS-B sigma_m / 20: NORD's and SUD's sigmas widened (range terms by the range
    residuals' chi2/dof ~1.9), a warning naming the radar, coordinate, ratio and causes;
    the widened sigmas are back at least to the clean data's."""
    folder = _adsb_too_confident(demo_dir, tmp_path)
    out = tmp_path / "result.json"
    result = runner.invoke(app, ["calibrate", str(folder), "--out", str(out)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    for rid in ("NORD", "SUD"):
        assert f"radar {rid}: {WIDENED} (range chi2/dof 1.9" in text
    assert "sigma_range_m" in text and "ADS-B sigma_m/NACp" in text
    assert "carry both errors" in text
    data = json.loads(out.read_text())
    inflation = data["info"]["sigma_inflation"]
    assert {"NORD", "SUD"} <= set(inflation)
    assert not {"EST3D", "OUEST3D"} & set(inflation)
    for rid in ("NORD", "SUD"):
        entry = inflation[rid]
        assert 1.7 < entry["factor"] < 2.2
        assert entry["parameters"]["range_offset_m"] == entry["coordinates"]["range"][
            "chi2_per_dof"]
        assert entry["parameters"]["time_offset_s"] == entry["factor"]
        clean = clean_result["radars"][rid]["sigma"]["range_offset_m"]
        widened = data["radars"][rid]["sigma"]["range_offset_m"]
        # Back to at least the clean data's sigma (more with the trajectory formulation:
        # its paths follow the too-trusted ADS-B noise, which the widening then covers).
        assert 0.9 * clean < widened < 2.0 * clean
        # sigma over the bound scaled alike
        assert data["info"]["efficiency"][f"{rid}.range_offset_m"] > 1.3
    cal = _consistent(out)
    assert cal.info["sigma_inflation"] == inflation


def test_clean_data_not_widened(clean_result) -> None:
    assert "sigma_inflation" not in clean_result["info"]
    assert not any(WIDENED in w for w in clean_result["warnings"])


def test_radar_sigma_too_small_widens_that_radar_only(demo, tmp_path) -> None:
    """NORD's sigma_range_m 3 m instead of 30: NORD's range terms and time offset widened
    by its range chi2/dof, its azimuth bias not (azimuth chi2/dof 1.0); nothing else."""
    sites = dict(demo.sites)
    sites["NORD"] = dataclasses.replace(sites["NORD"], sigma_range_m=3.0)
    misstated = dataclasses.replace(demo, sites=sites)
    cal = graphcal.calibrate(misstated)
    base = estimate(misstated, "graph")  # the estimator alone: formal sigmas
    inflation = cal.info["sigma_inflation"]
    assert set(inflation) == {"NORD"}
    f = inflation["NORD"]["factor"]
    assert 1.7 < f < 2.2 and set(inflation["NORD"]["coordinates"]) == {"range"}
    for key, factor in (("range_offset_m", f), ("range_gain", f), ("time_offset_s", f),
                        ("azimuth_bias_mrad", 1.0)):
        assert cal.sigma("NORD", key) == pytest.approx(
            base.sigma("NORD", key) * math.sqrt(factor), rel=1e-6)
    assert cal.sigma("SUD", "range_offset_m") == pytest.approx(
        base.sigma("SUD", "range_offset_m"), rel=1e-9)
    warning = next(w for w in cal.warnings if WIDENED in w)
    assert warning.startswith("radar NORD:") and "range chi2/dof 1.9" in warning
    path = tmp_path / "nord.json"
    cal.write_json(path)
    _consistent(path)


def test_without_adsb_a_radar_sigma_too_small_widens_that_radar_on_the_paths(demo) -> None:
    """Without ADS-B: NORD's sigma_azimuth stated 0.6 times its noise.  On the aircraft's
    paths its azimuth residuals have ``chi2/dof`` 1 / 0.6^2 = 2.78 (the paths' share of
    the degrees of freedom counted); only NORD's azimuth terms are widened."""
    sites = dict(demo.sites)
    sites["NORD"] = dataclasses.replace(sites["NORD"],
                                        sigma_azimuth_rad=0.6 * sites["NORD"].sigma_azimuth_rad)
    cal = graphcal.calibrate(dataclasses.replace(demo, sites=sites, adsb=None),
                             model_checks=False)
    inflation = cal.info["sigma_inflation"]
    assert set(inflation) == {"NORD"} and inflation["NORD"]["reference"] == "paths"
    assert set(inflation["NORD"]["coordinates"]) == {"azimuth"}
    assert inflation["NORD"]["factor"] == pytest.approx(1.0 / 0.6**2, abs=0.15)
    assert inflation["NORD"]["parameters"]["range_offset_m"] == 1.0
    warning = next(w for w in cal.warnings if WIDENED in w)
    assert "residuals are against the aircraft's paths" in warning


def test_window_widens_from_pooled_residuals(demo) -> None:
    """--window: the residuals pooled over the windows widen every window's summary."""
    adsb = demo.adsb.assign(sigma_m=demo.adsb["sigma_m"] / 20.0, nacp=11)
    cal = graphcal.calibrate(dataclasses.replace(demo, adsb=adsb), window=600.0)
    assert {"NORD", "SUD"} <= set(cal.info["sigma_inflation"])
    assert any(w.startswith("radar NORD:") and "pooled over the windows" in w
               for w in cal.warnings)
    clean = graphcal.calibrate(demo, window=600.0)
    assert "sigma_inflation" not in clean.info


def _verdict(ratio: float, dof: float) -> FitVerdict:
    fit = RadarFit("R", [CoordinateFit("range", ratio * dof, dof, 4.0),
                         CoordinateFit("azimuth", dof, dof, 4.0)])
    return FitVerdict("adsb", {"R": fit})


def test_limit_and_rule() -> None:
    assert widen_limit(7000) == WIDEN_FLOOR == 1.15
    assert widen_limit(100) == pytest.approx(1.494, abs=1e-3)  # chi2_isf(1e-3, 100) / 100
    assert sigma_inflation(_verdict(1.14, 7000)) == {}
    assert sigma_inflation(_verdict(1.3, 100)) == {}
    widened = sigma_inflation(_verdict(1.6, 7000))["R"]
    assert widened.factor == 1.6
    assert widened.parameter_factor("range_gain") == 1.6
    assert widened.parameter_factor("azimuth_bias") == 1.0
    assert widened.parameter_factor("time_offset") == 1.6
    assert "sigma_range_m" in widened.message()


def test_pooled_verdict_sums_windows() -> None:
    fits = [WindowFit("adsb", sums={"R": {"range": (1.6 * 600, 602)}}, n_terms={"R": 2})
            for _ in range(3)]
    verdict = pooled_verdict(fits)
    (coordinate,) = verdict.radars["R"].coordinates
    assert coordinate.dof == 1800 and coordinate.ratio == pytest.approx(1.6)
    assert sigma_inflation(verdict)["R"].factor == pytest.approx(1.6)

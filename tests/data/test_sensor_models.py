"""Tests of graphcal.data.sensor_models: radar model files and the ADS-B NACp table."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.core.errors import SensorModelError
from graphcal.data.bias import CONTRACT_KEYS, PARAMETER_NAMES
from graphcal.data.sensor_models import (
    MODELS_DIR_ENV,
    SensorModel,
    adsb_sigma_from_nacp,
    list_sensor_models,
    load_sensor_model,
    models_dir,
)
from tests.paths import MODELS

#: DO-260B NACp -> EPU bound [m] (95 % horizontal containment radius).
EPU_M = {
    11: 3.0, 10: 10.0, 9: 30.0, 8: 92.6, 7: 185.2, 6: 555.6, 5: 926.0,
    4: 1852.0, 3: 3704.0, 2: 7408.0, 1: 18520.0,
}

RADAR_MODEL = """\
kind = "radar"
description = "test radar"
dimensions = 2
sigma_range_m = 40.0
sigma_azimuth_mrad = 1.5
scan_period_s = 5.0
detection_probability = 0.95
max_range_m = 200000.0
min_elevation_deg = 0.0
estimate = ["range_offset", "azimuth_bias"]

[typical_bias]
range_offset_m = 20.0
"""


@pytest.fixture
def custom_models(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A models folder of our own (with the real NACp table) selected by the env variable."""
    folder = tmp_path / "models"
    folder.mkdir()
    real = MODELS / "adsb-nacp.toml"
    (folder / "adsb-nacp.toml").write_text(real.read_text())
    (folder / "test-radar.toml").write_text(RADAR_MODEL)
    monkeypatch.setenv(MODELS_DIR_ENV, str(folder))
    return folder


def test_bundled_models_are_listed_without_the_nacp_table() -> None:
    names = list_sensor_models()
    assert {"ssr-mode-s", "air-defence-3d", "psr-approach"} <= set(names)
    assert "adsb-nacp" not in names
    assert names == sorted(names)


def test_models_dir_is_the_repository_models_folder(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(MODELS_DIR_ENV, raising=False)
    assert models_dir() == MODELS


@pytest.mark.parametrize("name", ["ssr-mode-s", "air-defence-3d", "psr-approach"])
def test_every_bundled_model_is_consistent(name: str) -> None:
    model = load_sensor_model(name)
    assert isinstance(model, SensorModel)
    assert model.name == name and model.kind == "radar" and model.description
    assert set(model.estimate) <= set(PARAMETER_NAMES)
    assert ("elevation_bias" in model.estimate) == model.is_3d
    assert (model.sigma_elevation_rad is not None) == (model.dimensions == 3)
    assert 0.0 < model.detection_probability <= 1.0
    assert model.sigma_range_m > 0 and model.sigma_azimuth_rad > 0 and model.scan_period_s > 0
    contract_keys = {key for key, _ in CONTRACT_KEYS.values()}
    assert model.typical_bias and set(model.typical_bias) <= contract_keys


def test_ssr_mode_s_values_in_si_units() -> None:
    model = load_sensor_model("ssr-mode-s")
    assert model.dimensions == 2
    assert model.sigma_range_m == 30.0
    assert model.sigma_azimuth_rad == pytest.approx(1.2e-3)
    assert model.sigma_elevation_rad is None
    assert model.scan_period_s == 4.0
    assert model.detection_probability == 0.98
    assert model.max_range_m == 470e3
    assert model.estimate == ("range_offset", "range_gain", "azimuth_bias")


def test_air_defence_3d_values_in_si_units() -> None:
    model = load_sensor_model("air-defence-3d")
    assert model.dimensions == 3
    assert model.sigma_range_m == 100.0
    assert model.sigma_azimuth_rad == pytest.approx(2e-3)
    assert model.sigma_elevation_rad == pytest.approx(3e-3)
    assert model.scan_period_s == 10.0
    assert model.max_range_m == 450e3
    assert model.min_elevation_rad == pytest.approx(math.radians(-1.0))
    assert model.estimate == PARAMETER_NAMES


def test_psr_approach_does_not_estimate_the_range_gain() -> None:
    model = load_sensor_model("psr-approach")
    assert model.estimate == ("range_offset", "azimuth_bias")
    assert model.sigma_azimuth_rad == pytest.approx(2.6e-3)
    assert model.max_range_m == 110e3


def test_unknown_model_lists_the_available_ones() -> None:
    with pytest.raises(SensorModelError) as info:
        load_sensor_model("no-such-radar")
    message = str(info.value)
    assert "no-such-radar" in message
    for name in ("ssr-mode-s", "air-defence-3d", "psr-approach"):
        assert name in message


def test_the_nacp_table_is_not_a_radar_model() -> None:
    with pytest.raises(SensorModelError, match="not a radar sensor model"):
        load_sensor_model("adsb-nacp")


def test_env_variable_selects_another_models_folder(custom_models: Path) -> None:
    assert list_sensor_models() == ["test-radar"]
    model = load_sensor_model("test-radar")
    assert model.sigma_range_m == 40.0
    assert model.typical_bias == {"range_offset_m": 20.0}
    with pytest.raises(SensorModelError, match="test-radar"):
        load_sensor_model("ssr-mode-s")


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("sigma_range_m = 40.0\n", "", "sigma_range_m"),
        ("dimensions = 2\n", "dimensions = 2\nbeamwidth_deg = 1.0\n", "beamwidth_deg"),
        ("dimensions = 2\n", "dimensions = 2\nsigma_elevation_mrad = 2.0\n",
         "sigma_elevation_mrad"),
        ("dimensions = 2\n", "dimensions = 4\n", "dimensions"),
        ('"azimuth_bias"]', '"elevation_bias"]', "estimate"),
        ('"azimuth_bias"]', '"north_bias"]', "estimate"),
        ("detection_probability = 0.95", "detection_probability = 1.5", "detection_probability"),
        ("sigma_azimuth_mrad = 1.5", "sigma_azimuth_mrad = 0.0", "sigma_azimuth_mrad"),
        ("range_offset_m = 20.0", "range_bias_m = 20.0", "typical_bias.range_bias_m"),
    ],
)
def test_invalid_model_file_names_the_field(
    custom_models: Path, old: str, new: str, field: str
) -> None:
    assert old in RADAR_MODEL
    (custom_models / "test-radar.toml").write_text(RADAR_MODEL.replace(old, new))
    with pytest.raises(SensorModelError) as info:
        load_sensor_model("test-radar")
    assert info.value.field == field
    assert "test-radar.toml" in str(info.value)


def test_broken_toml_is_a_sensor_model_error(custom_models: Path) -> None:
    (custom_models / "test-radar.toml").write_text("kind = [unclosed\n")
    with pytest.raises(SensorModelError, match="cannot read TOML"):
        load_sensor_model("test-radar")


def test_95_percent_radius_factor() -> None:
    # P(r <= R) = 1 - exp(-R^2 / (2 sigma^2)) = 0.95 for a circular 2-D Gaussian.
    assert math.sqrt(-2.0 * math.log(0.05)) == pytest.approx(2.4477, abs=1e-4)


def test_nacp_9_gives_30_m_over_2_4477() -> None:
    assert float(adsb_sigma_from_nacp(9)) == pytest.approx(30.0 / 2.4477, rel=1e-12)


def test_every_nacp_category_follows_do_260b() -> None:
    categories = np.array(sorted(EPU_M))
    expected = np.array([EPU_M[int(n)] for n in categories]) / 2.4477
    np.testing.assert_allclose(adsb_sigma_from_nacp(categories), expected, rtol=1e-12)
    assert np.all(np.diff(adsb_sigma_from_nacp(categories)) < 0)  # better category, smaller


def test_nacp_0_gets_a_large_value_and_unknowns_nan() -> None:
    sigma = adsb_sigma_from_nacp([0, 12, -1, 2.5, np.nan, None])
    assert sigma[0] == pytest.approx(18520.0 / 2.4477)
    assert np.all(np.isnan(sigma[1:]))


def test_nacp_is_vectorised_and_keeps_the_shape() -> None:
    nacp = np.array([[9, 10], [11, 8]])
    sigma = adsb_sigma_from_nacp(nacp)
    assert sigma.shape == (2, 2)
    assert sigma[1, 0] == pytest.approx(3.0 / 2.4477)


def test_nacp_accepts_nullable_pandas_integers() -> None:
    sigma = adsb_sigma_from_nacp(pd.Series([9, None, 7], dtype="Int64"))
    assert sigma[0] == pytest.approx(30.0 / 2.4477)
    assert np.isnan(sigma[1])
    assert sigma[2] == pytest.approx(185.2 / 2.4477)

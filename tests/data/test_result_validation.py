"""Results are validated when read, corrected plots before they are written (case 2),
and the covariance API names its units (case 8)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import graphcal
from graphcal.cli.app import app
from graphcal.core.errors import ResultError
from graphcal.data.bias import RadarBias
from graphcal.data.calibration import Calibration, read_biases
from graphcal.data.correct import correct_dataset
from graphcal.io.folder import write_dataset
from tests.paths import SCENARIOS

runner = CliRunner()


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """The demo network (seed 1) on disk and its ls result as a document."""
    folder = tmp_path_factory.mktemp("ds") / "demo"
    dataset = graphcal.simulate(SCENARIOS / "demo_network.toml", seed=1).dataset
    write_dataset(dataset, folder)
    cal = graphcal.calibrate(dataset, "ls", model_checks=False)
    return folder, dataset, cal, cal.to_dict()


def _write(tmp_path: Path, doc: dict) -> Path:
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    return path


def test_correct_refuses_a_gain_of_minus_one(case, tmp_path) -> None:
    """Before: 'wrote' and inf for every range.  Now exit 2 naming the field, no folder."""
    folder, _, _, doc = case
    bad = copy.deepcopy(doc)
    bad["radars"]["NORD"]["range_gain"] = -1.0
    out = tmp_path / "out"
    result = runner.invoke(app, ["correct", str(folder), str(_write(tmp_path, bad)),
                                 "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert "field 'radars.NORD.range_gain'" in result.output
    assert "wrote" not in result.output and not out.exists()


@pytest.mark.parametrize(("edit", "field", "message"), [
    (lambda d: d["radars"]["NORD"].__setitem__("range_gain", 0.2), "radars.NORD.range_gain",
     "beyond"),
    (lambda d: d["radars"]["NORD"]["sigma"].__setitem__("range_offset_m", -1.0),
     "radars.NORD.sigma.range_offset_m", ">= 0"),
    (lambda d: d["radars"]["NORD"]["sigma"].__setitem__("range_offset_m", 99.0),
     "radars.NORD.sigma.range_offset_m", "disagrees with the covariance"),
    (lambda d: d["radars"]["NORD"].__setitem__("azimuth_bias_mrad", 5000.0),
     "radars.NORD.azimuth_bias_mrad", "beyond"),
    (lambda d: d["radars"]["NORD"].__setitem__("range_offset_m", None),
     "radars.NORD.range_offset_m", "null"),
    (lambda d: d["covariance"]["matrix"][0].__setitem__(1, 1e9), "covariance.matrix",
     "not symmetric"),
    (lambda d: d["covariance"]["matrix"].pop(), "covariance.matrix", "list of rows"),
    (lambda d: d["covariance"]["labels"].reverse(), "radars", ""),
])
def test_result_checks(case, tmp_path, edit, field, message) -> None:
    _, _, _, doc = case
    bad = copy.deepcopy(doc)
    edit(bad)
    path = _write(tmp_path, bad)
    with pytest.raises(ResultError) as info:
        Calibration.read_json(path)
    if field != "radars":
        assert field in str(info.value) and message in str(info.value)
    with pytest.raises(ResultError):
        read_biases(path)


def test_valid_result_and_truth_pass(case, tmp_path) -> None:
    _, _, cal, doc = case
    back = Calibration.read_json(_write(tmp_path, doc))
    assert back.sigma("NORD", "range_offset_m") == pytest.approx(cal.sigma("NORD",
                                                                           "range_offset_m"))
    assert set(read_biases(_write(tmp_path, doc))) == set(cal.radar_ids)
    truth = {"radars": {rid: {"range_gain": 0.0002} for rid in cal.radar_ids}}
    assert set(read_biases(_write(tmp_path, truth))) == set(cal.radar_ids)


def test_corrected_values_checked_before_writing(case) -> None:
    _, dataset, _, _ = case
    with pytest.raises(ResultError, match="non-finite or negative range_m"):
        correct_dataset(dataset, {"NORD": RadarBias(range_gain=-1.0)})
    with pytest.raises(ResultError, match="NORD"):
        correct_dataset(dataset, {"NORD": RadarBias(range_offset_m=1e7)})


def test_covariance_units_are_named(case) -> None:
    """covariance[i, j] is SI, covariance(radar) and sigma are contract units: the
    explicit names say which."""
    _, _, cal, doc = case
    i = cal.labels.index(("NORD", "azimuth_bias"))
    sigma = cal.sigma("NORD", "azimuth_bias_mrad")
    assert np.sqrt(cal.covariance_contract[i, i]) == pytest.approx(sigma)
    assert np.sqrt(cal.covariance_si[i, i]) * 1e3 == pytest.approx(sigma)
    assert cal.covariance_si[i, i] == cal.covariance[i, i]
    block = cal.marginal("NORD")
    k = cal.marginal_labels("NORD").index("azimuth_bias_mrad")
    assert np.sqrt(block[k, k]) == pytest.approx(sigma)
    assert np.allclose(cal.covariance_contract, doc["covariance"]["matrix"])
    assert type(cal.covariance_si) is np.ndarray

"""The API around a result: to_frame, a short repr, load_truth and compare_to_truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import graphcal
from graphcal.core.errors import ResultError
from graphcal.data.bias import CONTRACT_KEYS, to_contract_units
from graphcal.data.truth import COMPARISON_COLUMNS
from graphcal.simulation.simulate import write_simulation
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    sim = graphcal.simulate(SCENARIOS / "demo_network.toml", seed=7)
    folder = tmp_path_factory.mktemp("truth") / "demo"
    write_simulation(sim, folder)
    cal = graphcal.calibrate(sim.dataset, "graph", fixed={"APP.azimuth_bias_mrad": 0.6})
    return sim, folder, cal


def test_to_frame_one_row_per_radar_and_term(run) -> None:
    _, _, cal = run
    frame = cal.to_frame()
    assert list(frame.columns) == ["radar", "parameter", "value", "sigma", "unit", "fixed"]
    estimated = frame[~frame["fixed"]]
    assert list(zip(estimated["radar"], estimated["parameter"], strict=True)) == [
        tuple(label.split(".")) for label in cal.contract_labels()]
    # values and sigmas are those of the result JSON, sigma the covariance's diagonal
    doc = cal.to_dict()
    for row in estimated.itertuples(index=False):
        assert row.value == doc["radars"][row.radar][row.parameter]
    np.testing.assert_allclose(estimated["sigma"], np.sqrt(np.diag(cal.contract_covariance())))
    units = dict(zip(frame["parameter"], frame["unit"], strict=False))
    assert units["range_offset_m"] == "m" and units["range_gain"] == "fraction"
    assert units["azimuth_bias_mrad"] == "mrad" and units["time_offset_s"] == "s"
    [fixed] = frame[frame["fixed"]].itertuples(index=False)
    assert (fixed.radar, fixed.parameter, fixed.value) == ("APP", "azimuth_bias_mrad", 0.6)
    assert np.isnan(fixed.sigma)


def test_repr_is_one_line_per_radar(run) -> None:
    _, _, cal = run
    lines = repr(cal).splitlines()
    assert lines[0].startswith("Calibration(method='graph', 5 radars, ")
    assert len(lines) == 1 + len(cal.radar_ids)
    assert lines[1].startswith("  NORD: range_offset_m ") and " ± " in lines[1]
    assert "azimuth_bias_mrad 0.6 (fixed)" in lines[-1]
    assert len(repr(cal)) < 2000


def test_load_truth_and_compare(run) -> None:
    sim, folder, cal = run
    truth = graphcal.load_truth(folder / "truth.json")
    assert truth.scenario == "demo_network"
    table = graphcal.compare_to_truth(cal, truth)
    assert list(table.columns) == list(COMPARISON_COLUMNS)
    assert len(table) == len(cal.labels)
    for row in table.itertuples(index=False):
        name = next(n for n, (k, _) in CONTRACT_KEYS.items() if k == row.parameter)
        expected = to_contract_units(name, sim.biases[row.radar].value(name))
        assert row.truth == pytest.approx(expected, abs=1e-12)
        assert row.error == pytest.approx(row.estimate - row.truth)
        assert row.z == pytest.approx(row.error / row.sigma)
    # an honest estimate: z about standard normal over the 20 terms
    assert np.all(np.abs(table["z"]) < 4.5)
    assert 0.3 < np.sqrt(np.mean(table["z"] ** 2)) < 2.0
    # a path works as well as a loaded truth
    assert graphcal.compare_to_truth(cal, folder / "truth.json").equals(table)


@pytest.mark.parametrize(("text", "field"), [
    ("{", None), ('{"radars": 3}', "radars"), ('{"radars": {"A": 1}}', "radars.A"),
    ('{"radars": {"A": {"range_offset_m": "x"}}}', "radars.A.range_offset_m"),
])
def test_bad_truth_is_one_error_naming_the_field(tmp_path: Path, text: str, field) -> None:
    path = tmp_path / "truth.json"
    path.write_text(text)
    with pytest.raises(ResultError) as info:
        graphcal.load_truth(path)
    assert info.value.field == field and str(path) in str(info.value)
    with pytest.raises(ResultError, match="no such file"):
        graphcal.load_truth(tmp_path / "missing.json")


def test_null_truth_is_zero(tmp_path: Path) -> None:
    path = tmp_path / "truth.json"
    path.write_text(json.dumps({"radars": {"A": {"range_offset_m": 5, "elevation_bias_mrad":
                                                 None}}}))
    truth = graphcal.load_truth(path)
    assert truth.value("A", "elevation_bias_mrad") == 0.0
    assert truth.value("A", "range_gain") == 0.0
    assert np.isnan(truth.value("B", "range_gain"))

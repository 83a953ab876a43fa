"""Bias correction of datasets (graphcal.data.correct) and the ``correct`` command."""

from __future__ import annotations

import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from graphcal.cli.correct import correct_command
from graphcal.data.bias import RadarBias, apply_bias, correct_bias
from graphcal.data.correct import correct_dataset
from graphcal.io.folder import load_dataset, write_dataset
from tests.synthetic import Track, make_dataset, site_at

BIASES = {
    "A": RadarBias(range_offset_m=120.0, range_gain=2e-4, azimuth_bias_rad=3e-3,
                   time_offset_s=0.7),
    "B": RadarBias(range_offset_m=-80.0, range_gain=-1e-4, azimuth_bias_rad=-2e-3,
                   elevation_bias_rad=1.5e-3),
}
TRACKS = [
    Track("abc001", (-60e3, 10e3, 9000.0), (220.0, 10.0, 0.0), 0.0, 500.0),
    Track("abc002", (20e3, -50e3, 7000.0), (-30.0, 200.0, 0.0), 0.0, 500.0),
    # Crosses north of radar A: azimuth near 0 / 360 deg.
    Track("abc003", (-25e3, 40e3, 5000.0), (180.0, 0.0, 0.0), 0.0, 300.0),
]


def _sites():
    return [site_at("A", -20e3, 0.0), site_at("B", 30e3, 5e3, sigma_elevation_mrad=2.0)]


def _dataset(biases):
    sites = _sites()
    radars = [(s, biases.get(s.id, RadarBias())) for s in sites]
    return make_dataset(np.random.default_rng(4), radars, TRACKS, noise=False)


def _sorted(plots):
    return plots.sort_values(["radar_id", "target_id", "time_s"], ignore_index=True)


def test_correcting_with_the_true_biases_restores_the_unbiased_plots() -> None:
    measured = _dataset(BIASES)
    corrected = _sorted(correct_dataset(measured, BIASES).plots)
    truth = _sorted(_dataset({}).plots)  # independent expectation: simulated with zero bias
    assert len(corrected) == len(truth)
    assert (corrected["radar_id"] == truth["radar_id"]).all()
    np.testing.assert_allclose(corrected["time_s"], truth["time_s"], atol=1e-9)
    np.testing.assert_allclose(corrected["range_m"], truth["range_m"], atol=1e-6)
    daz = (corrected["azimuth_deg"] - truth["azimuth_deg"] + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(daz, 0.0, atol=1e-9)
    assert corrected["azimuth_deg"].between(0.0, 360.0, inclusive="left").all()
    b = corrected["radar_id"] == "B"
    np.testing.assert_allclose(corrected.loc[b, "elevation_deg"], truth.loc[b, "elevation_deg"],
                               atol=1e-9)
    assert corrected.loc[~b, "elevation_deg"].isna().all()  # 2-D radar: stays empty
    np.testing.assert_allclose(corrected["altitude_m"], truth["altitude_m"])
    assert (corrected["target_id"] == truth["target_id"]).all()
    # The measured dataset is not modified.
    assert not np.allclose(_sorted(measured.plots)["range_m"], truth["range_m"])


def test_apply_then_correct_round_trip() -> None:
    rng = np.random.default_rng(1)
    r = rng.uniform(1e3, 3e5, 200)
    az = rng.uniform(0.0, 2 * np.pi, 200)
    el = rng.uniform(-0.01, 0.3, 200)
    bias = RadarBias(250.0, 0.004, -0.01, 0.002, 1.0)
    r2, az2, el2 = correct_bias(*apply_bias(r, az, el, bias), bias)
    np.testing.assert_allclose(r2, r, rtol=1e-12)
    np.testing.assert_allclose(np.angle(np.exp(1j * (az2 - az))), 0.0, atol=1e-12)
    np.testing.assert_allclose(el2, el, atol=1e-12)


def test_radars_not_covered_are_left_alone() -> None:
    measured = _dataset(BIASES)
    corrected = correct_dataset(measured, {"B": BIASES["B"], "ZZ": RadarBias(5.0)})
    a = measured.plots["radar_id"] == "A"
    assert corrected.plots.loc[a].equals(measured.plots.loc[a])


def _truth_json(path, biases):
    radars = {
        rid: {"range_offset_m": b.range_offset_m, "range_gain": b.range_gain,
              "azimuth_bias_mrad": b.azimuth_bias_rad * 1e3,
              "elevation_bias_mrad": b.elevation_bias_rad * 1e3 if rid == "B" else None,
              "time_offset_s": b.time_offset_s}
        for rid, b in biases.items()
    }
    path.write_text(json.dumps({"method": "truth", "radars": radars}))


@pytest.fixture()
def runner_app():
    app = typer.Typer()
    app.command(name="correct")(correct_command)
    app.command(name="noop")(lambda: None)  # keeps 'correct' a named sub-command
    return app


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_correct_command_writes_a_loadable_corrected_dataset(tmp_path, runner_app) -> None:
    src = tmp_path / "in"
    write_dataset(_dataset(BIASES), src)
    _truth_json(src / "truth.json", BIASES)
    before = _snapshot(src)
    out = tmp_path / "out"
    result = CliRunner().invoke(
        runner_app, ["correct", str(src), str(src / "truth.json"), "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert _snapshot(src) == before  # DIR untouched
    corrected = load_dataset(out)
    assert sorted(p.name for p in out.iterdir()) == ["adsb.csv", "plots.csv", "sites.toml"]
    truth = _sorted(_dataset({}).plots)
    got = _sorted(corrected.plots)
    np.testing.assert_allclose(got["range_m"], truth["range_m"], atol=1e-5)
    np.testing.assert_allclose(got["time_s"], truth["time_s"], atol=1e-6)
    assert corrected.adsb is not None and len(corrected.adsb) == len(load_dataset(src).adsb)
    # A second run needs --overwrite.
    again = CliRunner().invoke(
        runner_app, ["correct", str(src), str(src / "truth.json"), "--out", str(out)]
    )
    assert again.exit_code == 2
    forced = CliRunner().invoke(
        runner_app,
        ["correct", str(src), str(src / "truth.json"), "--out", str(out), "--overwrite"],
    )
    assert forced.exit_code == 0, forced.output


@pytest.mark.parametrize("content", [None, "not json", '{"radars": 3}'])
def test_correct_command_bad_result_exits_2(tmp_path, runner_app, content) -> None:
    src = tmp_path / "in"
    write_dataset(_dataset(BIASES), src)
    bad = tmp_path / "bad.json"
    if content is not None:
        bad.write_text(content)
    out = tmp_path / "out"
    result = CliRunner().invoke(runner_app, ["correct", str(src), str(bad), "--out", str(out)])
    assert result.exit_code == 2
    assert not out.exists()


def test_correct_command_refuses_to_overwrite_its_input(tmp_path, runner_app) -> None:
    src = tmp_path / "in"
    write_dataset(_dataset(BIASES), src)
    _truth_json(src / "truth.json", BIASES)
    before = _snapshot(src)
    result = CliRunner().invoke(
        runner_app,
        ["correct", str(src), str(src / "truth.json"), "--out", str(src), "--overwrite"],
    )
    assert result.exit_code == 2
    assert _snapshot(src) == before

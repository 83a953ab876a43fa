"""The time-stamping bias in the graph: recovered, harmless when absent, dropped when weak."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from graphcal.analysis.crlb import crlb
from graphcal.pipeline.calibrate import calibrate
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.graph import graph
from tests.paths import SCENARIOS

#: True time offsets [s] (CONTRACT.md: time_reported = time_true + time_offset_s).
OFFSETS_S = {"NORD": 1.5, "SUD": -0.5, "EST3D": 2.0, "OUEST3D": -1.0, "APP": 0.8}


def _with_offsets(offsets: dict[str, float]):
    scenario = load_scenario(SCENARIOS / "demo_network.toml")
    radars = tuple(
        dataclasses.replace(
            r, bias=dataclasses.replace(r.bias, time_offset_s=offsets.get(r.id, 0.0))
        )
        for r in scenario.radars
    )
    return dataclasses.replace(scenario, radars=radars)


@pytest.fixture(scope="module")
def runs():
    """The demo network (aircraft at 130-250 m/s) with and without time offsets, same noise."""
    seed = 21
    shifted = simulate(_with_offsets(OFFSETS_S), np.random.default_rng(seed))
    plain = simulate(_with_offsets({}), np.random.default_rng(seed))
    return shifted, plain


def _z(cal, biases) -> dict[tuple[str, str], float]:
    sd = np.sqrt(np.diag(cal.covariance))
    return {
        label: (cal.estimate[i] - biases[label[0]].value(label[1])) / sd[i]
        for i, label in enumerate(cal.labels)
    }


def test_offsets_of_half_a_second_to_two_seconds_are_recovered(runs) -> None:
    shifted, _ = runs
    cal = graph(shifted.dataset)
    assert cal.info["time_offset"]["estimated"] == list(OFFSETS_S)
    # The paths are evaluated at each plot's own corrected time: nothing to realign.
    assert cal.info["time_offset"]["realignments"] == 0
    z = _z(cal, shifted.biases)
    assert max(abs(v) for v in z.values()) < 3.0, z
    for rid, offset in OFFSETS_S.items():
        assert cal.value(rid, "time_offset_s") == pytest.approx(offset, abs=0.05)
        assert 0.0 < cal.sigma(rid, "time_offset_s") < 0.05
    # The contract's result JSON carries it.
    assert cal.to_dict()["radars"]["NORD"]["time_offset_s"] == pytest.approx(1.5, abs=0.05)


def test_other_biases_unchanged_by_the_offsets(runs) -> None:
    """Same noise with and without the offsets: the other estimates agree within 0.2 sigma."""
    shifted, plain = runs
    with_offsets = graph(shifted.dataset)
    without_offsets = graph(plain.dataset)
    sd = np.sqrt(np.diag(with_offsets.covariance))
    for i, (rid, name) in enumerate(with_offsets.labels):
        if name == "time_offset":
            assert abs(without_offsets.value(rid, "time_offset_s")) < 3 * sd[i]
            continue
        j = without_offsets.labels.index((rid, name))
        assert abs(with_offsets.estimate[i] - without_offsets.estimate[j]) < 0.2 * sd[i], (
            rid, name)


def test_ignoring_the_offsets_gives_confidently_wrong_biases(runs) -> None:
    shifted, _ = runs
    cal = graph(shifted.dataset, time_offset=False)
    assert all(name != "time_offset" for _, name in cal.labels)
    assert max(abs(v) for v in _z(cal, shifted.biases).values()) > 10.0


def test_bound_includes_the_time_offsets(runs) -> None:
    shifted, _ = runs
    cal = calibrate(shifted.dataset)
    for key, ratio in cal.info["efficiency"].items():
        assert 0.9 < ratio < 1.3, key
    res = crlb(shifted.dataset, time_offset=True)
    assert ("EST3D", "time_offset") in res.labels


def test_one_straight_flight_cannot_separate_a_time_offset() -> None:
    """Paper 003's single straight flight: a time offset looks like a range offset and an
    azimuth bias, so auto mode keeps it at 0 and says so; asking for it anyway works."""
    run = simulate(load_scenario(SCENARIOS / "paper003_adsb_2d.toml"), np.random.default_rng(0))
    cal = graph(run.dataset)
    assert [name for _, name in cal.labels] == ["range_offset", "azimuth_bias"]
    assert any("R2D time offset not estimated" in w for w in cal.warnings)
    forced = graph(run.dataset, time_offset=True)
    assert forced.sigma("R2D", "time_offset_s") > 0.3
    assert forced.sigma("R2D", "azimuth_bias_mrad") > 1.5 * cal.sigma("R2D", "azimuth_bias_mrad")


def test_time_offsets_need_adsb() -> None:
    run = simulate(load_scenario(SCENARIOS / "paper003_adsb_2d.toml"), np.random.default_rng(0))
    with pytest.raises(ValueError, match="need ADS-B"):
        graph(run.dataset, use_adsb=False, time_offset=True)


def test_cli_time_offset_option(tmp_path: Path) -> None:
    import json

    from typer.testing import CliRunner

    from graphcal.cli.app import app
    from graphcal.simulation.simulate import write_simulation

    run = simulate(_with_offsets({"NORD": 1.0}), np.random.default_rng(4))
    data = tmp_path / "ds"
    write_simulation(run, data)
    runner = CliRunner()
    out_on, out_off = tmp_path / "on.json", tmp_path / "off.json"
    on = runner.invoke(app, ["calibrate", str(data), "--time-offset", "on", "--out", str(out_on)])
    assert on.exit_code == 0, on.output
    result = json.loads(out_on.read_text())["radars"]["NORD"]
    assert abs(result["time_offset_s"] - 1.0) < 3 * result["sigma"]["time_offset_s"]
    off = runner.invoke(app, ["calibrate", str(data), "--time-offset", "off", "--out",
                              str(out_off)])
    # NORD's 1-s offset left out of the model: its range residuals (1 s x ~200 m/s) are
    # far beyond their sigmas, and the fit verdict refuses the result (exit 3).
    assert off.exit_code == 3, off.output
    assert "NORD: range chi2/dof" in " ".join(off.output.split()) and not out_off.exists()
    from graphcal.pipeline.calibrate import calibrate

    cal = calibrate(run.dataset, time_offset="off", check_fit=False, model_checks=False)
    assert "time_offset_s" not in cal.to_dict()["radars"]["NORD"]
    assert cal.info["fit_verdict"]["failed"] == ["NORD"]
    bad = runner.invoke(app, ["calibrate", str(data), "--time-offset", "maybe"])
    assert bad.exit_code == 2 and "auto, on or off" in bad.output

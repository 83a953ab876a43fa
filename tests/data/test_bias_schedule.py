"""Biases over time (graphcal.data.bias_schedule): values and window means against direct
evaluation and numerical integration."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.data.bias import RadarBias
from graphcal.data.bias_schedule import BiasSchedule, BiasStep

HOUR = 3600.0
SCHEDULE = BiasSchedule(
    initial=RadarBias(range_offset_m=50.0, azimuth_bias_rad=1e-3, time_offset_s=0.02),
    drift_per_s=RadarBias(azimuth_bias_rad=0.2e-3 / HOUR, range_gain=1e-5 / HOUR),
    steps=(BiasStep(5000.0, RadarBias(range_offset_m=60.0)),
           BiasStep(9000.0, RadarBias(range_offset_m=-10.0, elevation_bias_rad=5e-4))),
    reference_time_s=1000.0,
)


def test_values_follow_the_drift_and_the_steps() -> None:
    t = np.array([1000.0, 4999.0, 5000.0, 9000.0 + HOUR])
    v = SCHEDULE.at(t)
    np.testing.assert_allclose(v["range_offset_m"], [50.0, 50.0, 110.0, 100.0])
    np.testing.assert_allclose(v["azimuth_bias_rad"], 1e-3 + 0.2e-3 * (t - 1000.0) / HOUR)
    np.testing.assert_allclose(v["range_gain"], 1e-5 * (t - 1000.0) / HOUR)
    np.testing.assert_allclose(v["elevation_bias_rad"], [0.0, 0.0, 0.0, 5e-4])
    np.testing.assert_allclose(v["time_offset_s"], 0.02)  # never drifts
    assert SCHEDULE.bias_at(5000.0).range_offset_m == 110.0
    assert not SCHEDULE.constant and BiasSchedule(RadarBias(1.0)).constant


@pytest.mark.parametrize("window", [(0.0, 1800.0), (4000.0, 7600.0), (4500.0, 9500.0)])
def test_window_means_equal_the_integral(window) -> None:
    start, end = window
    t = np.linspace(start, end, 200_001)[:-1] + 0.5 * (end - start) / 200_000
    values = SCHEDULE.at(t)
    mean = SCHEDULE.mean(start, end)
    for name, v in values.items():
        # A step lands between samples: the sampled mean is good to a sample spacing.
        assert getattr(mean, name) == pytest.approx(np.mean(v), rel=1e-5, abs=1e-12), name


def test_bad_schedules_are_refused() -> None:
    with pytest.raises(ValueError, match="time-stamping"):
        BiasSchedule(RadarBias(), drift_per_s=RadarBias(time_offset_s=1e-4))
    with pytest.raises(ValueError, match="time order"):
        BiasSchedule(RadarBias(), steps=(BiasStep(10.0, RadarBias(1.0)),
                                         BiasStep(5.0, RadarBias(1.0))))
    with pytest.raises(ValueError, match="empty window"):
        SCHEDULE.mean(10.0, 10.0)


def test_truth_json_gives_back_the_simulated_schedules() -> None:
    """A simulation's truth.json (biases at time 0 plus the drift block) read back with
    schedules_from_truth: the same window means as the scenario's own schedules."""
    import json
    import tomllib

    from graphcal.data.bias_schedule import schedules_from_truth, truth_over_windows
    from graphcal.simulation.scenario import parse_scenario
    from graphcal.simulation.simulate import simulate, truth_document
    from tests.paths import SCENARIOS

    with open(SCENARIOS / "demo_drift.toml", "rb") as f:
        doc = tomllib.load(f)
    doc["scenario"]["duration_s"] = 600.0
    doc["traffic"]["n_aircraft"] = 3
    doc["traffic"]["start_time_s"] = [0.0, 10.0]
    doc["radar"][1]["step"][0]["time_s"] = 300.0
    scenario = parse_scenario(doc)
    truth = json.loads(json.dumps(truth_document(simulate(scenario, np.random.default_rng(0)))))
    schedules = schedules_from_truth(truth)
    for radar in scenario.radars:
        for span in [(0.0, 200.0), (250.0, 400.0), (3600.0, 5400.0)]:
            mine, theirs = schedules[radar.id].mean(*span), radar.schedule.mean(*span)
            for name in ("range_offset", "range_gain", "azimuth_bias", "elevation_bias"):
                assert mine.value(name) == pytest.approx(theirs.value(name), abs=1e-12)
    over = truth_over_windows(truth, {"SUD": (0.0, 600.0)})
    # SUD steps +60 m at 300 s: half the window after it.
    assert over["radars"]["SUD"]["range_offset_m"] == pytest.approx(
        truth["radars"]["SUD"]["range_offset_m"] + 30.0)
    assert over["radars"]["NORD"] == truth["radars"]["NORD"]

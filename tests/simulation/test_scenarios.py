"""Tests of the scenario format, the shipped scenarios and the OpenSky replay."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.core import frames
from graphcal.core.errors import ScenarioError
from graphcal.core.refraction import Atmosphere
from graphcal.simulation.scenario import load_scenario, parse_scenario
from graphcal.simulation.simulate import simulate
from graphcal.simulation.trajectories import OpenSkySpec, replay_opensky
from tests.paths import SCENARIOS

SHIPPED = sorted(p.stem for p in SCENARIOS.glob("*.toml"))


def _needs_missing_file(scenario) -> bool:
    return scenario.opensky is not None and not scenario.opensky.file.is_file()


def _run(name: str, seed: int = 2024):
    scenario = load_scenario(SCENARIOS / f"{name}.toml")
    if _needs_missing_file(scenario):
        pytest.skip(f"shared OpenSky table not present: {scenario.opensky.file}")
    return simulate(scenario, np.random.default_rng(seed))


# --------------------------------------------------------------------------- shipped files


def test_all_expected_scenarios_are_shipped():
    assert {
        "paper001_path1",
        "paper001_path2",
        "paper002_three_radars",
        "paper003_adsb_2d",
        "demo_network",
        "demo_refraction",
        "paris_opensky",
    } <= set(SHIPPED)
    assert (SCENARIOS / "README.md").is_file()


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenario_parses_and_simulates(name):
    result = _run(name)
    counts = result.n_plots()
    assert all(n > 0 for n in counts.values()), counts
    plots = result.dataset.plots
    assert np.all(np.diff(plots["time_s"].to_numpy()) >= 0)
    assert plots["azimuth_deg"].between(0.0, 360.0, inclusive="left").all()


@pytest.mark.parametrize("name", ["paper001_path1", "paper001_path2"])
def test_paper001_counts_and_settings(name):
    result = _run(name)
    assert result.dataset.adsb is None
    for radar_id, n in result.n_plots().items():
        assert 798 <= n <= 802, (radar_id, n)
        site = result.dataset.sites[radar_id]
        assert site.estimate == ("range_offset", "range_gain", "azimuth_bias")
        assert site.scan_period_s == 2.0 and site.is_3d
    assert result.biases["R1"].range_gain == 0.005
    assert result.biases["R2"].azimuth_bias_rad == pytest.approx(14e-3)
    heights = result.plot_truth["height_true_m"]
    assert heights.between(5999.0, 6001.0).all()


def _crowding(result) -> float:
    """Fraction of plots within 20 km of the median plot position."""
    xyz = result.plot_truth[["x_m", "y_m", "z_m"]].to_numpy()
    centre = np.median(xyz, axis=0)
    return float(np.mean(np.linalg.norm(xyz - centre, axis=1) < 20_000.0))


def test_paper001_path2_is_crowded_and_path1_is_spread():
    path1 = _run("paper001_path1")
    path2 = _run("paper001_path2")
    assert _crowding(path2) > 0.7
    assert _crowding(path1) < 0.15
    r1 = path1.plot_truth["range_true_m"][path1.dataset.plots["radar_id"] == "R1"]
    assert r1.max() - r1.min() > 150_000.0


def test_paper002_radars_see_the_target():
    result = _run("paper002_three_radars")
    counts = result.n_plots()
    assert set(counts) == {"I", "II", "III"}
    for n in counts.values():
        assert 99 <= n <= 101
    assert 99 <= len(result.dataset.adsb) <= 101
    truth = result.plot_truth
    assert truth["range_true_m"].min() > 200_000.0
    assert truth["range_true_m"].max() < 1_200_000.0
    site = result.dataset.sites["I"]
    assert site.ecef_m == pytest.approx([-3610169.0, 4471655.0, 2757575.0], abs=1e-3)
    assert all(b.as_vector().tolist() == [0.0, 0.0, 0.0, 0.0] for b in result.biases.values())


def test_paper003_counts():
    for seed in (1, 2, 3):
        result = _run("paper003_adsb_2d", seed)
        assert abs(result.n_plots()["R2D"] - 27) <= 3
        assert abs(len(result.dataset.adsb) - 105) <= 5
    site = result.dataset.sites["R2D"]
    assert not site.is_3d
    assert site.estimate == ("range_offset", "azimuth_bias")
    assert result.biases["R2D"].range_offset_m == 297.0
    assert result.biases["R2D"].azimuth_bias_rad == pytest.approx(0.1617)
    ranges = result.plot_truth["range_true_m"]
    assert ranges.between(60_000.0, 100_000.0).all()


def test_demo_network_counts():
    result = _run("demo_network")
    counts = result.n_plots()
    assert len(counts) == 5
    assert 20_000 <= sum(counts.values()) <= 40_000
    assert 45_000 <= len(result.dataset.adsb) <= 75_000
    assert len(result.trajectories) == 40
    sites = result.dataset.sites
    assert sum(s.is_3d for s in sites.values()) == 2
    assert {s.model for s in sites.values()} == {"ssr-mode-s", "air-defence-3d", "psr-approach"}


def test_demo_refraction_is_the_demo_with_refraction():
    demo = load_scenario(SCENARIOS / "demo_network.toml")
    refracted = load_scenario(SCENARIOS / "demo_refraction.toml")
    assert all(r.refraction == "none" for r in demo.radars)
    assert all(r.atmosphere == Atmosphere(320.0, 7000.0) for r in refracted.radars)
    straight = refracted.with_radars(refraction="none", refractivity_n_s=313.0)
    assert straight.radars == demo.radars
    assert (straight.traffic, straight.adsb, straight.origin, straight.duration_s) == (
        demo.traffic, demo.adsb, demo.origin, demo.duration_s)
    result = _run("demo_refraction")
    assert all(s.refraction == "exponential" for s in result.dataset.sites.values())
    assert 20_000 <= sum(result.n_plots().values()) <= 40_000


def test_benchmark_network_scenario_parses():
    path = SCENARIOS.parent / "benchmarks" / "scenarios" / "network_10radars_1h.toml"
    scenario = load_scenario(path)
    models = [r.model for r in scenario.radars]
    assert len(models) == 10 and len({r.id for r in scenario.radars}) == 10
    assert models.count("ssr-mode-s") == 5
    assert models.count("air-defence-3d") == 3
    assert models.count("psr-approach") == 2
    assert len({(r.bias.range_offset_m, r.bias.azimuth_bias_rad) for r in scenario.radars}) == 10
    assert scenario.duration_s == 3600.0 and scenario.traffic.n_aircraft == 200
    assert scenario.adsb.enabled and scenario.adsb.period_s == 1.0 and scenario.adsb.nacp == 8
    assert scenario.adsb.equipped_fraction == 0.7


# --------------------------------------------------------------------------- OpenSky replay


def test_paris_opensky_replay():
    scenario = load_scenario(SCENARIOS / "paris_opensky.toml")
    if _needs_missing_file(scenario):
        pytest.skip(f"shared OpenSky table not present: {scenario.opensky.file}")
    result = simulate(scenario, np.random.default_rng(1))
    stats = result.replay_stats
    assert stats is not None
    assert 0.1 < stats.stale_dropped / stats.rows_in_window < 0.3
    assert 10 <= stats.aircraft_used <= 60
    per_radar = result.dataset.plots.groupby("radar_id")["target_id"].nunique()
    assert (per_radar >= 5).all()
    assert 10_000 <= len(result.dataset.plots) <= 30_000


def _synthetic_table(path: Path) -> None:
    """Two aircraft at 1 s with stale repeats, NaN heights, a glitch and a 40 s gap."""
    rows = []
    start = pd.Timestamp("2021-10-07T13:00:00Z").timestamp()
    for craft, lat0, lon0 in (("4ca123", 48.9, 2.0), ("3c6abc", 48.6, 2.8)):
        for k in range(300):
            if craft == "3c6abc" and 100 <= k < 140:
                continue  # 40 s gap
            lat = lat0 + 0.0015 * k
            lon = lon0 + 0.0020 * k
            alt_ft = 30000.0
            if k % 5 == 4:  # stale: OpenSky repeats the previous position
                lat = lat0 + 0.0015 * (k - 1)
                lon = lon0 + 0.0020 * (k - 1)
            if k == 50:
                alt_ft = 90000.0  # glitch
            if k == 70:
                alt_ft = np.nan
            rows.append((start + k, craft.upper(), lat, lon, alt_ft, False))
    frame = pd.DataFrame(
        rows, columns=["timestamp", "icao24", "latitude", "longitude", "altitude", "onground"]
    )
    frame.to_csv(path, index=False)


def test_replay_cleans_a_synthetic_table(tmp_path):
    path = tmp_path / "states.csv"
    _synthetic_table(path)
    spec = OpenSkySpec(
        file=path,
        start=pd.Timestamp("2021-10-07T13:00:00Z"),
        duration_s=300.0,
        min_points=30,
    )
    flights, stats = replay_opensky(spec)
    assert stats.rows_in_window == 560
    assert stats.stale_dropped == 112
    assert stats.nan_dropped == 2
    assert stats.glitch_dropped == 2
    by_id = {f.target_id: f for f in flights}
    assert set(by_id) == {"4ca123", "3c6abc"}
    assert len(by_id["3c6abc"].segments()) == 2
    assert np.isnan(by_id["3c6abc"].position_ecef(np.array([120.0]))).all()
    _, _, h = frames.ecef_to_geodetic(by_id["4ca123"].position_ecef(np.linspace(0, 298, 50)))
    np.testing.assert_allclose(h, 30000.0 * 0.3048, atol=1.0)


def test_scenario_with_synthetic_replay(tmp_path):
    _synthetic_table(tmp_path / "states.csv")
    text = """
[scenario]
duration_s = 300.0
[[radar]]
id = "X"
lat_deg = 49.0
lon_deg = 2.3
alt_m = 50.0
model = "ssr-mode-s"
[opensky]
file = "states.csv"
start = 2021-10-07T13:00:00Z
min_points = 30
[adsb]
nacp = 8
"""
    (tmp_path / "replay.toml").write_text(text)
    scenario = load_scenario(tmp_path / "replay.toml")
    assert scenario.opensky.file == (tmp_path / "states.csv").resolve()
    result = simulate(scenario, np.random.default_rng(0))
    assert set(result.dataset.plots["target_id"]) == {"4ca123", "3c6abc"}
    assert set(result.dataset.adsb["target_id"]) == {"4ca123", "3c6abc"}
    assert math.isclose(result.dataset.adsb["time_s"].max(), 298.0, abs_tol=1.0)


# --------------------------------------------------------------------------- bad input

GOOD = """
[scenario]
name = "bad"
duration_s = 100.0
origin = {{ lat_deg = 48.0, lon_deg = 2.0 }}

[[radar]]
id = "R"
{site}
sigma_range_m = 50.0
sigma_azimuth_mrad = 1.0
scan_period_s = {scan}

[[aircraft]]
east_m = 1000.0
north_m = 30000.0
alt_m = 5000.0
speed_mps = {speed}
{extra}
"""


def _bad(tmp_path, **fields) -> tuple[Path, str]:
    values = {
        "site": "lat_deg = 48.0\nlon_deg = 2.0\nalt_m = 10.0",
        "scan": "4.0",
        "speed": "200.0",
        "extra": "",
    }
    values.update(fields)
    path = tmp_path / "bad.toml"
    path.write_text(GOOD.format(**values))
    return path, str(path)


def test_good_template_parses(tmp_path):
    path, _ = _bad(tmp_path)
    scenario = load_scenario(path)
    assert scenario.radars[0].id == "R"
    assert scenario.aircraft[0].target_id == "f00001"


@pytest.mark.parametrize(
    ("fields", "field_name", "words"),
    [
        ({"scan": '"fast"'}, "radar[0].scan_period_s", "must be a number"),
        ({"scan": "-4.0"}, "radar[0].scan_period_s", "positive"),
        ({"site": ""}, "radar[0].lat_deg", "missing radar site"),
        ({"site": "lat_deg = 48.0\nlon_deg = 2.0"}, "radar[0].alt_m", "missing"),
        ({"speed": "true"}, "aircraft[0].speed_mps", "must be a number"),
        ({"extra": "colour = 3"}, "aircraft[0].colour", "unknown field"),
        ({"extra": 'id = "ABC123"'}, "aircraft[0].id", "hex"),
        (
            {"extra": "[[aircraft.leg]]\nduration_s = 10.0\nacceleration_mps2 = -30.0"},
            "aircraft[0].leg",
            "negative",
        ),
        (
            {"site": "ecef_m = [1.0, 2.0]"},
            "radar[0].ecef_m",
            "3 numbers",
        ),
    ],
)
def test_bad_input_names_file_and_field(tmp_path, fields, field_name, words):
    path, text = _bad(tmp_path, **fields)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert info.value.field == field_name
    assert info.value.path == path
    message = str(info.value)
    assert text in message and field_name in message and words in message


def test_bad_radar_sections(tmp_path):
    cases = [
        ("[radar.bias]\nelevation_bias_mrad = 1.0", "radar[0].bias.elevation_bias_mrad"),
        ('model = "no-such-radar"', "radar[0].model"),
        ('estimate = ["range_offset", "elevation_bias"]', "radar[0].estimate"),
        ("detection_probability = 1.5", "radar[0].detection_probability"),
        ('refraction = "standard"', "radar[0].refraction"),
        ("refraction = true", "radar[0].refraction"),
        ("refractivity_n_s = 501", "radar[0].refractivity_n_s"),
        ("refractivity_n_s = -5", "radar[0].refractivity_n_s"),
        ("refractivity_scale_height_m = 0", "radar[0].refractivity_scale_height_m"),
        ('refraction = "exponential"\nrefractivity_n_s = 400\n'
         "refractivity_scale_height_m = 4000", "radar[0].refractivity_scale_height_m"),
    ]
    for extra, field_name in cases:
        path = tmp_path / "radar.toml"
        path.write_text(
            '[scenario]\nduration_s = 10.0\n[[radar]]\nid = "R"\nlat_deg = 1.0\n'
            "lon_deg = 2.0\nalt_m = 0.0\nsigma_range_m = 1.0\nsigma_azimuth_mrad = 1.0\n"
            "scan_period_s = 1.0\n"
            f"{extra}\n"
            "[[aircraft]]\nlat_deg = 1.1\nlon_deg = 2.0\nalt_m = 100.0\nspeed_mps = 10.0\n"
        )
        with pytest.raises(ScenarioError) as info:
            load_scenario(path)
        assert info.value.field == field_name, extra
        assert info.value.path == path


def test_missing_file_and_missing_sections(tmp_path):
    with pytest.raises(ScenarioError, match="file not found"):
        load_scenario(tmp_path / "nope.toml")
    with pytest.raises(ScenarioError) as info:
        parse_scenario({"scenario": {"duration_s": 5.0}}, tmp_path / "x.toml")
    assert info.value.field == "radar"
    (tmp_path / "broken.toml").write_text("[scenario\n")
    with pytest.raises(ScenarioError, match="cannot read TOML"):
        load_scenario(tmp_path / "broken.toml")


def test_missing_opensky_table_is_a_scenario_error(tmp_path):
    path = tmp_path / "replay.toml"
    path.write_text(
        '[scenario]\nduration_s = 60.0\n[[radar]]\nid = "X"\nlat_deg = 49.0\nlon_deg = 2.3\n'
        'alt_m = 50.0\nmodel = "ssr-mode-s"\n[opensky]\nfile = "absent.parquet"\n'
        'start = "2021-10-07T13:00:00"\n'
    )
    scenario = load_scenario(path)
    assert scenario.opensky.start == pd.Timestamp("2021-10-07T13:00:00Z")
    with pytest.raises(ScenarioError) as info:
        simulate(scenario, np.random.default_rng(0))
    assert info.value.field == "opensky.file"

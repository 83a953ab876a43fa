"""Tests of the simulator and the trajectories it flies."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from graphcal.core import frames
from graphcal.core.errors import ScenarioError
from graphcal.core.refraction import Atmosphere, refracted_polar
from graphcal.data.bias import CONTRACT_KEYS, RadarBias, correct_bias, correct_time
from graphcal.io.folder import load_dataset
from graphcal.simulation.scenario import load_scenario, parse_scenario
from graphcal.simulation.simulate import (
    beam_crossings,
    earth_blocks,
    simulate,
    truth_document,
    write_simulation,
)
from graphcal.simulation.trajectories import (
    EcefTrajectory,
    Leg,
    LegTrajectory,
    LocalPlane,
    TrafficSpec,
    generate_traffic,
)
from tests.paths import SCENARIOS

ORIGIN = {"lat_deg": 48.85, "lon_deg": 2.35, "alt_m": 0.0}


def _radar(radar_id: str, lat: float, lon: float, *, three_d: bool = True, **extra) -> dict:
    entry = {
        "id": radar_id,
        "lat_deg": lat,
        "lon_deg": lon,
        "alt_m": 100.0,
        "sigma_range_m": 50.0,
        "sigma_azimuth_mrad": 1.5,
        "scan_period_s": 4.0,
        "max_range_m": 400_000.0,
        "min_elevation_deg": -1.0,
    }
    if three_d:
        entry["sigma_elevation_mrad"] = 2.0
    entry.update(extra)
    return entry


def _document(**changes) -> dict:
    """A small scenario: one 3-D and one 2-D radar, a turning climbing aircraft."""
    doc = {
        "scenario": {"name": "unit", "duration_s": 600.0, "origin": dict(ORIGIN)},
        "radar": [
            _radar(
                "A3D",
                48.70,
                2.10,
                bias={
                    "range_offset_m": 120.0,
                    "range_gain": 4e-4,
                    "azimuth_bias_mrad": 2.5,
                    "elevation_bias_mrad": -1.5,
                    "time_offset_s": 0.3,
                },
            ),
            _radar(
                "B2D",
                49.10,
                2.70,
                three_d=False,
                scan_period_s=5.0,
                bias={"range_offset_m": -60.0, "range_gain": -2e-4, "azimuth_bias_mrad": -1.0},
            ),
        ],
        "aircraft": [
            {
                "id": "abc123",
                "east_m": -40_000.0,
                "north_m": 10_000.0,
                "alt_m": 7000.0,
                "speed_mps": 220.0,
                "heading_deg": 80.0,
                "leg": [
                    {"duration_s": 150.0},
                    {"duration_s": 120.0, "turn_rate_deg_s": 2.0, "vertical_rate_mps": 8.0},
                    {"duration_s": 200.0, "acceleration_mps2": 0.3},
                    {"duration_s": 130.0, "turn_rate_deg_s": -1.5, "vertical_rate_mps": -5.0},
                ],
            },
            {
                "id": "def456",
                "east_m": 30_000.0,
                "north_m": -20_000.0,
                "alt_m": 9000.0,
                "speed_mps": 240.0,
                "heading_deg": 330.0,
            },
        ],
    }
    for key, value in changes.items():
        doc[key] = value
    return doc


def _noise_free(scenario):
    return scenario.with_radars(sigma_range_m=0.0, sigma_azimuth_rad=0.0, sigma_elevation_rad=0.0)


# --------------------------------------------------------------------------- geometry


def test_noise_free_plots_invert_to_true_positions():
    scenario = _noise_free(parse_scenario(_document()))
    result = simulate(scenario, np.random.default_rng(3))
    plots = result.dataset.plots
    flights = {f.target_id: f for f in result.trajectories}
    assert set(plots["radar_id"]) == {"A3D", "B2D"}
    for radar in scenario.radars:
        sel = (plots["radar_id"] == radar.id).to_numpy()
        rows = plots[sel]
        assert len(rows) > 50
        t_true = correct_time(rows["time_s"].to_numpy(), radar.bias)
        true = np.concatenate(
            [
                flights[tid].position_ecef(np.array([t]))
                for tid, t in zip(rows["target_id"], t_true, strict=True)
            ]
        )
        site = radar.site()
        r, az, el = correct_bias(
            rows["range_m"].to_numpy(),
            np.radians(rows["azimuth_deg"].to_numpy()),
            np.radians(rows["elevation_deg"].to_numpy()),
            radar.bias,
        )
        if radar.is_3d:
            measured = site.ecef_from_polar(r, az, el)
            assert np.max(np.linalg.norm(measured - true, axis=1)) < 1e-3
        else:
            assert rows["elevation_deg"].isna().all()
            r_true, az_true, _ = site.polar_from_ecef(true)
            assert np.max(np.abs(r - r_true)) < 1e-3
            assert np.max(np.abs(frames.wrap_to_pi(az - az_true)) * r_true) < 1e-3


def test_plot_truth_rows_match_plots():
    scenario = _noise_free(parse_scenario(_document()))
    result = simulate(scenario, np.random.default_rng(4))
    plots, truth = result.dataset.plots, result.plot_truth
    assert len(plots) == len(truth)
    offset = plots["radar_id"].map({r.id: r.bias.time_offset_s for r in scenario.radars})
    np.testing.assert_allclose(plots["time_s"] - offset, truth["time_true_s"], atol=1e-9)
    assert np.all(np.diff(plots["time_s"].to_numpy()) >= 0)


def test_stationary_target_follows_the_sweep():
    doc = _document(
        aircraft=[
            {
                "id": "a1b2c3",
                "east_m": 20_000.0,
                "north_m": 35_000.0,
                "alt_m": 5000.0,
                "speed_mps": 0.0,
            }
        ]
    )
    doc["radar"][0]["antenna_phase_deg"] = 123.0
    scenario = parse_scenario(doc)
    result = simulate(scenario, np.random.default_rng(5))
    for radar in scenario.radars:
        sel = (result.dataset.plots["radar_id"] == radar.id).to_numpy()
        truth = result.plot_truth[sel]
        t = truth["time_true_s"].to_numpy()
        assert t.size == pytest.approx(scenario.duration_s / radar.scan_period_s, abs=1)
        np.testing.assert_allclose(np.diff(t), radar.scan_period_s, atol=1e-9)
        phase = result.antenna_phase_rad[radar.id]
        beam = phase + 2 * np.pi * t / radar.scan_period_s
        target = np.radians(truth["azimuth_true_deg"].to_numpy())
        assert np.max(np.abs(frames.wrap_to_pi(beam - target))) < 1e-9
    assert result.antenna_phase_rad["A3D"] == pytest.approx(math.radians(123.0))


def test_moving_target_is_hit_when_the_beam_passes_it():
    scenario = parse_scenario(_document())
    result = simulate(scenario, np.random.default_rng(6))
    plots, truth = result.dataset.plots, result.plot_truth
    for radar in scenario.radars:
        sel = (plots["radar_id"] == radar.id).to_numpy()
        t = truth["time_true_s"].to_numpy()[sel]
        beam = result.antenna_phase_rad[radar.id] + 2 * np.pi * t / radar.scan_period_s
        target = np.radians(truth["azimuth_true_deg"].to_numpy()[sel])
        assert np.max(np.abs(frames.wrap_to_pi(beam - target))) < 1e-8
        # Not a shared clock: per target, intervals differ from the period.
        for tid in ("abc123", "def456"):
            ti = t[(plots["target_id"].to_numpy()[sel] == tid)]
            gaps = np.diff(ti)
            assert np.all(np.abs(gaps - radar.scan_period_s) < 0.1 * radar.scan_period_s)
            assert np.max(np.abs(gaps - radar.scan_period_s)) > 1e-4


def test_beam_crossings_close_to_the_radar():
    """A fast target passing 2 km from a radar that turns once a second."""
    plane = LocalPlane(math.radians(48.0), math.radians(2.0), 0.0)
    flight = LegTrajectory(
        "0abcde", plane, 0.0, -20_000.0, 2000.0, 3000.0, 300.0, math.radians(90.0), [Leg(130.0)]
    )
    radar_ecef = frames.geodetic_to_ecef(plane.lat_rad, plane.lon_rad, 0.0)
    rotation = frames.ecef_to_enu_rotation(plane.lat_rad, plane.lon_rad)
    t = beam_crossings(flight, radar_ecef, rotation, 1.0, 0.4, 0.0, 130.0)
    enu = (flight.position_ecef(t) - radar_ecef) @ rotation.T
    alpha = np.arctan2(enu[:, 0], enu[:, 1])
    assert np.max(np.abs(frames.wrap_to_pi(0.4 + 2 * np.pi * t - alpha))) < 1e-8
    assert t.size == pytest.approx(130, abs=2)
    assert np.all(np.diff(t) > 0.5)


# --------------------------------------------------------------------------- coverage


def test_detection_probability_fraction():
    p = 0.7
    doc = _document()
    doc["scenario"]["duration_s"] = 3600.0
    doc["aircraft"][1]["speed_mps"] = 150.0
    for radar in doc["radar"]:
        radar["detection_probability"] = p
        radar["scan_period_s"] = 2.0
    scenario = parse_scenario(doc)
    result = simulate(scenario, np.random.default_rng(7))
    for radar_id, n in result.n_candidates.items():
        k = result.n_plots()[radar_id]
        assert n > 1000
        half_width = 4.0 * math.sqrt(n * p * (1 - p))
        assert abs(k - n * p) < half_width


def test_max_range_and_min_elevation_respected():
    doc = _document()
    doc["radar"][0]["max_range_m"] = 60_000.0
    doc["radar"][1]["min_elevation_deg"] = 5.0
    scenario = parse_scenario(doc)
    full = simulate(parse_scenario(_document()), np.random.default_rng(8))
    result = simulate(scenario, np.random.default_rng(8))
    plots, truth = result.dataset.plots, result.plot_truth
    a = (plots["radar_id"] == "A3D").to_numpy()
    b = ~a
    assert 0 < a.sum() < (full.dataset.plots["radar_id"] == "A3D").sum()
    assert truth["range_true_m"][a].max() <= 60_000.0
    assert truth["elevation_true_deg"][b].min() >= 5.0
    # Those left out really were outside: the full run has plots beyond the limits.
    full_a = (full.dataset.plots["radar_id"] == "A3D").to_numpy()
    assert full.plot_truth["range_true_m"][full_a].max() > 60_000.0


def test_earth_blocks_beyond_the_radio_horizon():
    lat = math.radians(45.0)
    plane = LocalPlane(lat, 0.0, 0.0)
    radar_ecef = frames.geodetic_to_ecef(lat, 0.0, 0.0)
    rotation = frames.ecef_to_enu_rotation(lat, 0.0)
    # Geometric horizon of a 10 km high target seen from the ground: sqrt(2 R h) = 357 km.
    east = np.array([50e3, 300e3, 340e3, 380e3, 420e3])
    enu = (plane.to_ecef(east, np.zeros(5), np.full(5, 10_000.0)) - radar_ecef) @ rotation.T
    blocked = earth_blocks(enu, lat, 0.0)
    assert blocked.tolist() == [False, False, False, True, True]
    assert not earth_blocks(np.array([[0.0, 0.0, 0.0], [1e5, 0.0, 1.0]]), lat, 0.0).any()


def test_horizon_check_removes_hidden_targets():
    doc = _document(
        aircraft=[
            {
                "id": "00a001",
                "east_m": 0.0,
                "north_m": 330_000.0,
                "alt_m": 2000.0,
                "speed_mps": 0.0,
            },
        ]
    )
    doc["radar"][0]["min_elevation_deg"] = -5.0
    doc["radar"][1]["min_elevation_deg"] = -5.0
    hidden = simulate(parse_scenario(doc), np.random.default_rng(1))
    assert len(hidden.dataset.plots) == 0
    for radar in doc["radar"]:
        radar["horizon_check"] = False
    seen = simulate(parse_scenario(doc), np.random.default_rng(1))
    assert len(seen.dataset.plots) > 100
    assert seen.plot_truth["elevation_true_deg"].max() < 0.0


# --------------------------------------------------------------------------- noise


def _chi2_ok(residual: np.ndarray, sigma: float, alpha: float = 1e-5) -> bool:
    n = residual.size
    statistic = np.sum(residual**2) / sigma**2  # zero-mean noise: n degrees of freedom
    return stats.chi2.ppf(alpha, n) < statistic < stats.chi2.ppf(1 - alpha, n)


def test_noise_has_configured_sigmas():
    doc = _document()
    doc["scenario"]["duration_s"] = 2400.0
    for radar in doc["radar"]:
        radar["scan_period_s"] = 1.0
    scenario = parse_scenario(doc)
    result = simulate(scenario, np.random.default_rng(9))
    plots, truth = result.dataset.plots, result.plot_truth
    for radar in scenario.radars:
        sel = (plots["radar_id"] == radar.id).to_numpy()
        rows, tr = plots[sel], truth[sel]
        assert len(rows) > 1500
        r_b, az_b, el_b = (
            (1 + radar.bias.range_gain) * tr["range_true_m"].to_numpy() + radar.bias.range_offset_m,
            np.radians(tr["azimuth_true_deg"].to_numpy()) + radar.bias.azimuth_bias_rad,
            np.radians(tr["elevation_true_deg"].to_numpy()) + radar.bias.elevation_bias_rad,
        )
        assert _chi2_ok(rows["range_m"].to_numpy() - r_b, radar.sigma_range_m)
        d_az = frames.wrap_to_pi(np.radians(rows["azimuth_deg"].to_numpy()) - az_b)
        assert _chi2_ok(d_az, radar.sigma_azimuth_rad)
        assert not _chi2_ok(d_az, 1.2 * radar.sigma_azimuth_rad)
        if radar.is_3d:
            d_el = np.radians(rows["elevation_deg"].to_numpy()) - el_b
            assert _chi2_ok(d_el, radar.sigma_elevation_rad)
        alt_err = rows["altitude_m"].to_numpy() - tr["height_true_m"].to_numpy()
        assert np.std(alt_err) == pytest.approx(math.hypot(10.0, 7.62 / math.sqrt(12)), rel=0.1)
        assert np.allclose(np.round(rows["altitude_m"] / 7.62) * 7.62, rows["altitude_m"])


def test_adsb_noise_outliers_and_dropouts():
    doc = _document(
        adsb={
            "sigma_m": 20.0,
            "sigma_vertical_m": 30.0,
            "nacp": 8,
            "outlier_fraction": 0.05,
            "outlier_distance_m": 5000.0,
            "dropout_probability": 0.1,
        }
    )
    doc["scenario"]["duration_s"] = 1800.0
    scenario = parse_scenario(doc)
    result = simulate(scenario, np.random.default_rng(10))
    adsb, truth = result.dataset.adsb, result.adsb_truth
    assert list(adsb.columns) == [
        "time_s",
        "target_id",
        "lat_deg",
        "lon_deg",
        "alt_m",
        "sigma_m",
        "nacp",
    ]
    assert (adsb["nacp"] == 8).all() and (adsb["sigma_m"] == 20.0).all()
    expected = (600 + 1800) * 0.9  # flights of 600 s and 1800 s, 1 s period, 10 % lost
    assert abs(len(adsb) - expected) < 4 * math.sqrt(2400 * 0.09)
    truth_xyz = truth[["x_m", "y_m", "z_m"]].to_numpy()
    lat, lon, h = frames.ecef_to_geodetic(truth_xyz)
    reported = frames.geodetic_to_ecef(
        np.radians(adsb["lat_deg"].to_numpy()),
        np.radians(adsb["lon_deg"].to_numpy()),
        adsb["alt_m"].to_numpy(),
    )
    rot = frames.ecef_to_enu_rotation(lat, lon)
    enu = np.einsum("nij,nj->ni", rot, reported - truth_xyz)
    out = truth["outlier"].to_numpy()
    assert abs(out.mean() - 0.05) < 4 * math.sqrt(0.05 * 0.95 / out.size)
    horiz = np.hypot(enu[:, 0], enu[:, 1])
    assert np.all(np.abs(horiz[out] - 5000.0) < 200.0)
    assert _chi2_ok(enu[~out, 0], 20.0) and _chi2_ok(enu[~out, 1], 20.0)
    assert _chi2_ok(enu[~out, 2], 30.0)
    per_target = adsb.groupby("target_id")["time_s"].apply(lambda s: np.diff(np.sort(s)).min())
    assert (per_target >= 1.0 - 1e-9).all()


def _equipage_document(fraction: float | None, n_aircraft: int = 40) -> dict:
    adsb = {"nacp": 9}
    if fraction is not None:
        adsb["equipped_fraction"] = fraction
    doc = _document(adsb=adsb, traffic={"n_aircraft": n_aircraft, "radius_m": 60_000.0})
    doc["scenario"]["duration_s"] = 120.0
    return doc


def test_adsb_equipped_fraction_selects_that_many_aircraft():
    result = simulate(parse_scenario(_equipage_document(0.5)), np.random.default_rng(21))
    flights = [f.target_id for f in result.trajectories]
    assert len(flights) == 42  # two explicit aircraft and 40 random ones
    equipped = result.adsb_equipped
    assert len(equipped) == 21 and len(set(equipped)) == 21
    assert set(equipped) <= set(flights)
    assert list(equipped) == [f for f in flights if f in set(equipped)]  # flight order
    # Every equipped aircraft reports (all fly through the 120 s), no other does.
    assert set(result.dataset.adsb["target_id"]) == set(equipped)
    # Radar plots come before the ADS-B draws: unaffected by the equipage.
    full = simulate(parse_scenario(_equipage_document(None)), np.random.default_rng(21))
    pd.testing.assert_frame_equal(result.dataset.plots, full.dataset.plots)
    assert len(full.adsb_equipped) == 42
    per_aircraft = full.dataset.adsb.groupby("target_id").size()
    assert len(result.dataset.adsb) == per_aircraft[list(equipped)].sum()


def test_adsb_equipped_fraction_is_roughly_the_share_of_reporting_aircraft():
    result = simulate(parse_scenario(_equipage_document(0.7, 200)), np.random.default_rng(22))
    share = result.dataset.adsb["target_id"].nunique() / len(result.trajectories)
    assert share == pytest.approx(0.7, abs=0.01)


def test_adsb_equipped_fraction_zero_gives_no_adsb_table(tmp_path):
    result = simulate(parse_scenario(_equipage_document(0.0)), np.random.default_rng(23))
    assert result.adsb_equipped == ()
    assert result.dataset.adsb is None and result.adsb_truth is None
    assert len(result.dataset.plots) > 0
    folder = write_simulation(result, tmp_path / "out")
    assert not (folder / "adsb.csv").exists()
    assert load_dataset(folder).adsb is None


def test_adsb_equipped_fraction_one_keeps_the_random_stream():
    default = simulate(parse_scenario(_equipage_document(None)), np.random.default_rng(24))
    explicit = simulate(parse_scenario(_equipage_document(1.0)), np.random.default_rng(24))
    pd.testing.assert_frame_equal(default.dataset.adsb, explicit.dataset.adsb)
    pd.testing.assert_frame_equal(default.dataset.plots, explicit.dataset.plots)
    assert default.adsb_equipped == explicit.adsb_equipped
    assert len(default.adsb_equipped) == len(default.trajectories)


def test_adsb_equipped_fraction_is_reproducible_with_a_seed():
    scenario = parse_scenario(_equipage_document(0.5))
    first = simulate(scenario, np.random.default_rng(25))
    second = simulate(scenario, np.random.default_rng(25))
    assert first.adsb_equipped == second.adsb_equipped
    pd.testing.assert_frame_equal(first.dataset.adsb, second.dataset.adsb)
    others = {simulate(scenario, np.random.default_rng(s)).adsb_equipped for s in (26, 27)}
    assert any(set(o) != set(first.adsb_equipped) for o in others)


@pytest.mark.parametrize(
    ("value", "words"),
    [(1.5, "within [0, 1]"), (-0.1, "within [0, 1]"), ("x", "must be a number")],
)
def test_bad_adsb_equipped_fraction_names_file_and_field(tmp_path, value, words):
    doc = _equipage_document(None)
    doc["adsb"]["equipped_fraction"] = value
    path = tmp_path / "equipage.toml"
    with pytest.raises(ScenarioError) as info:
        parse_scenario(doc, path)
    assert info.value.field == "adsb.equipped_fraction"
    assert info.value.path == path
    message = str(info.value)
    assert str(path) in message and "adsb.equipped_fraction" in message and words in message


# --------------------------------------------------------------------------- reproducibility


def _files(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_same_seed_same_files_different_seed_different(tmp_path):
    doc = _document(adsb={"nacp": 9}, traffic={"n_aircraft": 3, "radius_m": 50_000.0})
    scenario = parse_scenario(doc)
    outs = []
    for name, seed in (("a", 11), ("b", 11), ("c", 12)):
        outs.append(
            write_simulation(simulate(scenario, np.random.default_rng(seed)), tmp_path / name)
        )
    first, second, third = (_files(folder) for folder in outs)
    assert set(first) == {"sites.toml", "plots.csv", "adsb.csv", "truth.json"}
    assert first == second
    assert first["plots.csv"] != third["plots.csv"]
    assert first["adsb.csv"] != third["adsb.csv"]


def test_written_dataset_loads_back(tmp_path):
    scenario = parse_scenario(_document(adsb={"nacp": 9}))
    result = simulate(scenario, np.random.default_rng(13))
    folder = write_simulation(result, tmp_path / "out", fmt="parquet")
    loaded = load_dataset(folder)
    assert list(loaded.sites) == ["A3D", "B2D"]
    assert loaded.sites["A3D"].is_3d and not loaded.sites["B2D"].is_3d
    assert len(loaded.plots) == len(result.dataset.plots)
    assert len(loaded.adsb) == len(result.dataset.adsb)
    np.testing.assert_allclose(loaded.plots["range_m"], result.dataset.plots["range_m"])


def test_truth_json_has_contract_keys(tmp_path):
    scenario = parse_scenario(_document())
    result = simulate(scenario, np.random.default_rng(14))
    folder = write_simulation(result, tmp_path / "out")
    doc = json.loads((folder / "truth.json").read_text())
    assert doc["method"] == "truth"
    assert doc == truth_document(result)
    keys = [
        CONTRACT_KEYS[n][0]
        for n in ("range_offset", "range_gain", "azimuth_bias", "elevation_bias")
    ]
    a, b = doc["radars"]["A3D"], doc["radars"]["B2D"]
    for entry in (a, b):
        assert set(keys) <= set(entry)
        assert entry["sigma"] == {}
    assert a["range_offset_m"] == 120.0 and a["range_gain"] == 4e-4
    assert a["azimuth_bias_mrad"] == pytest.approx(2.5)
    assert a["elevation_bias_mrad"] == pytest.approx(-1.5)
    assert a["time_offset_s"] == 0.3
    assert b["elevation_bias_mrad"] is None and "time_offset_s" not in b
    assert a["n_plots"] == result.n_plots()["A3D"] > 0


def test_progress_callback_reports_every_step():
    calls = []
    scenario = parse_scenario(_document())
    simulate(scenario, np.random.default_rng(15), progress=lambda *a: calls.append(a))
    assert [c[1] for c in calls] == [1, 2, 3, 4]
    assert all(c[2] == 4 for c in calls)


# --------------------------------------------------------------------------- trajectories


def test_leg_closed_form_matches_numerical_integration():
    plane = LocalPlane(math.radians(45.0), math.radians(5.0), 0.0)
    legs = [
        Leg(100.0),
        Leg(90.0, math.radians(3.0), 10.0, 0.5),
        Leg(60.0, math.radians(-2.0), -4.0, -1.0),
    ]
    flight = LegTrajectory("123abc", plane, 10.0, 1000.0, -2000.0, 5000.0, 200.0, 0.3, legs)
    t = np.linspace(10.0, 260.0, 250_001)
    state = flight.local_state(t)
    dt = t[1] - t[0]
    v, psi = state[:, 3], state[:, 4]
    east = 1000.0 + np.concatenate(
        [[0.0], np.cumsum(0.5 * dt * (v[1:] * np.sin(psi[1:]) + v[:-1] * np.sin(psi[:-1])))]
    )
    north = -2000.0 + np.concatenate(
        [[0.0], np.cumsum(0.5 * dt * (v[1:] * np.cos(psi[1:]) + v[:-1] * np.cos(psi[:-1])))]
    )
    assert np.max(np.abs(east - state[:, 0])) < 1e-3
    assert np.max(np.abs(north - state[:, 1])) < 1e-3
    assert state[-1, 2] == pytest.approx(5000.0 + 900.0 - 240.0)
    assert state[-1, 3] == pytest.approx(200.0 + 45.0 - 60.0)
    assert np.isnan(flight.position_ecef(np.array([9.0, 261.0]))).all()


def test_level_flight_keeps_its_height_far_from_the_origin():
    plane = LocalPlane(math.radians(48.0), math.radians(2.0), 0.0)
    flight = LegTrajectory(
        "0000aa", plane, 0.0, 0.0, 0.0, 9000.0, 250.0, math.radians(60.0), [Leg(1000.0)]
    )
    _, _, h = frames.ecef_to_geodetic(flight.position_ecef(np.array([0.0, 500.0, 1000.0])))
    np.testing.assert_allclose(h, 9000.0, atol=1e-6)
    lat, lon = math.radians(49.1), math.radians(3.3)
    east, north = plane.from_geodetic(lat, lon)
    back = frames.ecef_to_geodetic(plane.to_ecef(east, north, 100.0))
    assert back[0] == pytest.approx(lat, abs=1e-12) and back[1] == pytest.approx(lon, abs=1e-12)


def test_ecef_trajectory_is_linear():
    flight = EcefTrajectory("00beef", [4e6, 1e5, 4.9e6], [100.0, -50.0, 20.0], 5.0, 10.0)
    p = flight.position_ecef(np.array([5.0, 15.0, 16.0]))
    np.testing.assert_allclose(p[1] - p[0], [1000.0, -500.0, 200.0])
    assert np.isnan(p[2]).all()


def test_generated_traffic_stays_near_the_disc_and_is_reproducible():
    plane = LocalPlane(math.radians(48.85), math.radians(2.35), 0.0)
    spec = TrafficSpec(n_aircraft=20, radius_m=100_000.0, start_time_s=(0.0, 100.0))
    a = generate_traffic(spec, plane, 1800.0, np.random.default_rng(1))
    b = generate_traffic(spec, plane, 1800.0, np.random.default_rng(1))
    assert [f.target_id for f in a] == [f.target_id for f in b]
    assert len({f.target_id for f in a}) == 20
    for fa, fb in zip(a, b, strict=True):
        t = np.linspace(fa.start_s, fa.end_s, 200)
        np.testing.assert_array_equal(fa.position_ecef(t), fb.position_ecef(t))
        state = fa.local_state(t)
        assert np.all(np.hypot(state[:, 0], state[:, 1]) < 100_000.0 + 15_000.0)
        assert np.all((state[:, 2] >= 3000.0 - 1e-6) & (state[:, 2] <= 11000.0 + 1e-6))
        assert fa.end_s <= 1800.0 + 1e-9


def test_radar_bias_of_result_is_scenario_truth():
    scenario = parse_scenario(_document())
    result = simulate(scenario, np.random.default_rng(16))
    assert result.biases["A3D"] == RadarBias(120.0, 4e-4, 2.5e-3, -1.5e-3, 0.3)
    sites = result.dataset.sites
    assert sites["A3D"].sigma_elevation_rad == pytest.approx(2e-3)
    assert sites["B2D"].sigma_elevation_rad is None
    assert isinstance(result.dataset.plots, pd.DataFrame)


# --------------------------------------------------------------------------- refraction


def _plots_digest(plots: pd.DataFrame) -> str:
    """SHA-256 of the plots' numbers (exact bits) and identities."""
    digest = hashlib.sha256()
    for column in ("time_s", "range_m", "azimuth_deg", "elevation_deg", "altitude_m"):
        digest.update(np.ascontiguousarray(plots[column].to_numpy(dtype=float)).tobytes())
    digest.update("\n".join(plots["radar_id"] + "/" + plots["target_id"]).encode())
    return digest.hexdigest()


#: The demo network's plots with seed 1, as simulated before refraction existed.
DEMO_SEED_1_PLOTS_SHA256 = "119d5fdb9b29292e73d66825d49559a6b710d635fd6000d23dd126f69e980065"


def test_demo_network_plots_unchanged_without_refraction():
    """Version-1 scenarios give bit-identical plots; refraction = "none" changes nothing."""
    scenario = load_scenario(SCENARIOS / "demo_network.toml")
    result = simulate(scenario, np.random.default_rng(1))
    assert len(result.dataset.plots) == 33920
    assert _plots_digest(result.dataset.plots) == DEMO_SEED_1_PLOTS_SHA256
    explicit = scenario.with_radars(refraction="none", refractivity_n_s=400.0)
    again = simulate(explicit, np.random.default_rng(1))
    pd.testing.assert_frame_equal(again.dataset.plots, result.dataset.plots, check_exact=True)


def _refracted_document(**changes) -> dict:
    doc = _document(**changes)
    for radar in doc["radar"]:
        radar.update(refraction="exponential", refractivity_n_s=320.0,
                     refractivity_scale_height_m=7000.0, altitude_sigma_m=0.0,
                     altitude_quantum_ft=0.0)
    return doc


def test_refracted_plots_measure_the_ray():
    """Noise-free plots minus the biases are the refracted polar coordinates of the truth."""
    scenario = _noise_free(parse_scenario(_refracted_document()))
    result = simulate(scenario, np.random.default_rng(3))
    plots, truth = result.dataset.plots, result.plot_truth
    atmosphere = Atmosphere(320.0, 7000.0)
    for radar in scenario.radars:
        assert radar.atmosphere == atmosphere
        sel = (plots["radar_id"] == radar.id).to_numpy()
        rows, tr = plots[sel], truth[sel]
        assert len(rows) > 50
        site = radar.site()
        enu = site.enu_from_ecef(tr[["x_m", "y_m", "z_m"]].to_numpy())
        rng_m, az, el = refracted_polar(atmosphere, site.lat_rad, site.alt_m, enu)
        straight, _, straight_el = frames.enu_to_polar(enu)
        b = radar.bias
        np.testing.assert_allclose(rows["range_m"], (1 + b.range_gain) * rng_m + b.range_offset_m,
                                   rtol=0, atol=1e-6)
        np.testing.assert_allclose(np.radians(rows["azimuth_deg"]),
                                   frames.wrap_to_2pi(az + b.azimuth_bias_rad), rtol=0, atol=1e-12)
        np.testing.assert_allclose(tr["range_true_m"], rng_m, rtol=0, atol=1e-9)
        # Refraction lengthens the range by metres and raises the elevation.
        assert np.all(rng_m - straight > 1.0)
        assert np.all(el > straight_el)
        if radar.is_3d:
            np.testing.assert_allclose(np.radians(rows["elevation_deg"]),
                                       el + b.elevation_bias_rad, rtol=0, atol=1e-12)
        else:
            assert rows["elevation_deg"].isna().all()
        # The reported altitude stays the geometric height (noise and quantum off here).
        np.testing.assert_array_equal(rows["altitude_m"], tr["height_true_m"])


def test_refraction_sees_beyond_the_straight_horizon():
    """A target 210 km north of radar A3D (100 m) at 2 km is behind its straight horizon
    (195 km) but not behind the refracted one (about 4/3 farther)."""
    lat = 48.70 + math.degrees(210e3 / frames.gaussian_radius_m(math.radians(48.70)))
    doc = _refracted_document(aircraft=[
        {"id": "00a001", "lat_deg": lat, "lon_deg": 2.10, "alt_m": 2000.0, "speed_mps": 0.0},
    ])
    doc["radar"][0]["min_elevation_deg"] = -5.0

    def a3d_plots(document: dict) -> int:
        plots = simulate(parse_scenario(document), np.random.default_rng(1)).dataset.plots
        return int((plots["radar_id"] == "A3D").sum())

    assert a3d_plots(doc) > 100
    doc["radar"][0]["refraction"] = "none"
    assert a3d_plots(doc) == 0


def test_refraction_is_written_to_sites(tmp_path):
    result = simulate(parse_scenario(_refracted_document()), np.random.default_rng(4))
    folder = write_simulation(result, tmp_path / "out")
    loaded = load_dataset(folder)
    assert loaded.sites == result.dataset.sites
    assert all(s.atmosphere == Atmosphere(320.0, 7000.0) for s in loaded.sites.values())


# --------------------------------------------------------------------------- biases over time
DRIFT = {"azimuth_bias_mrad_per_h": 3.0, "range_gain_per_h": 2e-4,
         "elevation_bias_mrad_per_h": -1.2}
STEP = {"time_s": 300.0, "range_offset_m": 60.0, "azimuth_bias_mrad": -0.5}


def _drifting(**radar_changes) -> dict:
    doc = _document()
    doc["radar"][0]["drift"] = dict(DRIFT)
    doc["radar"][0]["step"] = [dict(STEP)]
    doc["radar"][0].update(radar_changes)
    return doc


def test_noise_free_plots_carry_the_bias_of_their_time() -> None:
    """Removing each plot's bias at its own true time gives the true position back, and the
    bias at t = 0 alone does not."""
    scenario = _noise_free(parse_scenario(_drifting()))
    radar = scenario.radars[0]
    assert not radar.schedule.constant and scenario.radars[1].schedule.constant
    result = simulate(scenario, np.random.default_rng(3))
    plots, truth = result.dataset.plots, result.plot_truth
    rows = (plots["radar_id"] == radar.id).to_numpy()
    t_true = correct_time(plots.loc[rows, "time_s"].to_numpy(), radar.bias)
    assert t_true.min() < 300.0 < t_true.max()
    measured = (plots.loc[rows, "range_m"].to_numpy(),
                np.radians(plots.loc[rows, "azimuth_deg"].to_numpy()),
                np.radians(plots.loc[rows, "elevation_deg"].to_numpy()))
    r, az, el = correct_bias(*measured, RadarBias(**radar.schedule.at(t_true)))
    np.testing.assert_allclose(r, truth.loc[rows, "range_true_m"], atol=1e-6)
    np.testing.assert_allclose(np.degrees(az), truth.loc[rows, "azimuth_true_deg"], atol=1e-9)
    np.testing.assert_allclose(np.degrees(el), truth.loc[rows, "elevation_true_deg"], atol=1e-9)
    r0, _, _ = correct_bias(*measured, radar.bias)
    late = t_true > 300.0
    assert np.min(r0[late] - truth.loc[rows, "range_true_m"].to_numpy()[late]) > 55.0


def test_truth_json_describes_the_drift() -> None:
    scenario = parse_scenario(_drifting())
    doc = truth_document(simulate(scenario, np.random.default_rng(1)))
    drift = doc["drift"]
    assert set(drift) == {"A3D"}
    per_h = drift["A3D"]["per_h"]
    assert per_h["azimuth_bias_mrad"] == pytest.approx(3.0)
    assert per_h["range_gain"] == pytest.approx(2e-4)
    assert per_h["elevation_bias_mrad"] == pytest.approx(-1.2)
    assert drift["A3D"]["steps"] == [
        {"time_s": 300.0, "range_offset_m": pytest.approx(60.0),
         "azimuth_bias_mrad": pytest.approx(-0.5)}]
    # radars holds the biases at t = 0, as before.
    assert doc["radars"]["A3D"]["range_offset_m"] == pytest.approx(120.0)


@pytest.mark.parametrize(("change", "field"), [
    ({"drift": {"time_offset_s_per_h": 0.1}}, "radar[0].drift.time_offset_s_per_h"),
    ({"step": [{"time_s": 900.0, "range_offset_m": 1.0}]}, "radar[0].step[0].time_s"),
    ({"drift": {"azimuth_bias_mrad": 1.0}}, "radar[0].drift.azimuth_bias_mrad"),
])
def test_bad_drift_is_refused_naming_the_field(change, field) -> None:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(_drifting(**change))
    assert field in str(info.value)


def test_elevation_drift_needs_a_3d_radar() -> None:
    doc = _document()
    doc["radar"][1]["drift"] = {"elevation_bias_mrad_per_h": 1.0}
    with pytest.raises(ScenarioError, match="2-D radar has no elevation bias"):
        parse_scenario(doc)

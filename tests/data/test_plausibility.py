"""Unit and frame heuristics: silent on every scenario, firing on each mistake made on one."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import graphcal
from graphcal.core.errors import DatasetError, ImplausibleDataError
from graphcal.data.plausibility import check_tables, check_time_overlap, ground_distance_m
from graphcal.io.folder import load_dataset, write_dataset
from graphcal.io.window_reader import iter_windows
from tests.paths import SCENARIOS

#: demo_drift is demo_network's geometry and traffic over 4 h (13 s to simulate).
SCENARIO_FILES = sorted(p for p in SCENARIOS.glob("*.toml") if p.stem != "demo_drift")


def _simulated(path: Path, seed: int) -> graphcal.Dataset:
    """The scenario's dataset; skipped when it replays the shared OpenSky table and that
    table is absent (a checkout without ../shared/data)."""
    from graphcal.simulation.scenario import load_scenario

    scenario = load_scenario(path)
    if scenario.opensky is not None and not scenario.opensky.file.is_file():
        pytest.skip(f"shared OpenSky table not present: {scenario.opensky.file}")
    return graphcal.simulate(path, seed=seed).dataset


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=lambda p: p.stem)
def test_no_finding_on_any_scenario(path: Path) -> None:
    ds = _simulated(path, 3)
    assert check_tables(ds.sites, ds.plots, ds.adsb) == []


@pytest.fixture(scope="module")
def demo() -> graphcal.Dataset:
    return graphcal.simulate(SCENARIOS / "demo_network.toml", seed=1).dataset


@pytest.fixture(scope="module")
def paris() -> graphcal.Dataset:
    """Replayed OpenSky trajectories: mostly low traffic (median height 2.8 km)."""
    return _simulated(SCENARIOS / "paris_opensky.toml", 1)


def _plots(ds, radar: str, column: str, scale: float):
    plots = ds.plots.copy()
    rows = plots["radar_id"] == radar
    plots.loc[rows, column] = plots.loc[rows, column] * scale
    return replace(ds, plots=plots)


def _adsb(ds, **columns):
    adsb = ds.adsb.copy()
    for name, value in columns.items():
        adsb[name] = value(adsb)
    return replace(ds, adsb=adsb)


def _site(ds, radar: str, **values):
    return replace(ds, sites={**ds.sites, radar: replace(ds.sites[radar], **values)})


def _fields(ds) -> list[tuple[str, str, tuple[str, ...]]]:
    return [(f.table, f.field, f.radars) for f in check_tables(ds.sites, ds.plots, ds.adsb)]


def test_azimuth_in_radians(demo) -> None:
    assert _fields(_plots(demo, "NORD", "azimuth_deg", math.pi / 180)) == [
        ("plots", "azimuth_deg", ("NORD",))]


def test_range_in_km_and_in_nautical_miles(demo) -> None:
    assert _fields(_plots(demo, "SUD", "range_m", 1e-3)) == [("plots", "range_m", ("SUD",))]
    assert _fields(_plots(demo, "APP", "range_m", 1 / 1852)) == [("plots", "range_m", ("APP",))]


def test_adsb_heights_in_feet_above_15_km(demo) -> None:
    broken = _adsb(demo, alt_m=lambda a: a["alt_m"] / 0.3048)
    [finding] = check_tables(broken.sites, broken.plots, broken.adsb)
    assert (finding.table, finding.field) == ("adsb", "alt_m")
    assert "feet" in finding.message


def test_adsb_heights_in_feet_of_low_traffic_against_the_plots(paris) -> None:
    broken = _adsb(paris, alt_m=lambda a: a["alt_m"] / 0.3048)
    # Low traffic: under half of the heights in feet exceed 15 km ...
    assert np.mean(broken.adsb["alt_m"] > 15e3) < 0.5
    # ... but the same aircraft are 1/0.3048 = 3.28 times higher than in the plots.
    [finding] = check_tables(broken.sites, broken.plots, broken.adsb)
    assert (finding.table, finding.field) == ("adsb", "alt_m")
    ratio = float(finding.message.split(" times")[0].split()[-1])
    assert abs(ratio - 1 / 0.3048) < 0.1


def test_plot_altitudes_in_feet(paris) -> None:
    broken = replace(paris, plots=paris.plots.assign(altitude_m=paris.plots["altitude_m"] / 0.3048))
    assert _fields(broken) == [("plots", "altitude_m", ())]


def test_adsb_latitude_and_longitude_swapped(demo, paris) -> None:
    for ds in (demo, paris):
        broken = _adsb(ds, lat_deg=lambda a: a["lon_deg"], lon_deg=lambda a: a["lat_deg"])
        assert _fields(broken) == [("adsb", "lat_deg", ())]


def test_adsb_swapped_without_shared_aircraft_names(demo) -> None:
    broken = _adsb(demo, lat_deg=lambda a: a["lon_deg"], lon_deg=lambda a: a["lat_deg"],
                   target_id=lambda a: "x" + a["target_id"])
    assert _fields(broken) == [("adsb", "lat_deg", ())]
    # The same renaming alone is fine (an ADS-B export may cover a wider area).
    assert _fields(_adsb(demo, target_id=lambda a: "x" + a["target_id"])) == []


def test_one_radar_site_swapped(paris) -> None:
    site = paris.sites["NORD"]
    broken = _site(paris, "NORD", lat_rad=site.lon_rad, lon_rad=site.lat_rad)
    assert _fields(broken) == [("sites", "lat_deg", ("NORD",))]


def test_antenna_height_out_of_bounds(demo) -> None:
    broken = _site(demo, "EST3D", alt_m=demo.sites["EST3D"].alt_m + 140e3)
    assert _fields(broken) == [("sites", "alt_m", ("EST3D",))]
    assert _fields(_site(demo, "EST3D", alt_m=-600.0)) == [("sites", "alt_m", ("EST3D",))]


def test_antenna_height_beyond_geometric_reach(demo) -> None:
    # APP's close-in traffic on a 3-degree approach (600 m at under 10 km) and APP said
    # to stand at 8.5 km: the aircraft are farther below the antenna than their slant
    # range, which no geometry allows (a chord is never shorter than the difference of
    # its ends' heights).
    near = demo.plots[(demo.plots["radar_id"] == "APP") & (demo.plots["range_m"] < 10e3)]
    near = near.assign(altitude_m=600.0)
    assert len(near) >= 50
    plots = pd.concat([demo.plots[demo.plots["radar_id"] != "APP"], near], ignore_index=True)
    broken = replace(_site(demo, "APP", alt_m=8500.0), plots=plots)
    assert _fields(broken) == [("sites", "alt_m", ("APP",))]
    assert _fields(replace(demo, plots=plots)) == []


@pytest.mark.parametrize(("shift_s", "hint"), [(1.7e9, "UNIX time"), (7200.0, "+2 h")])
def test_adsb_on_another_time_base(demo, shift_s: float, hint: str) -> None:
    broken = _adsb(demo, time_s=lambda a: a["time_s"] + shift_s)
    [finding] = check_tables(broken.sites, broken.plots, broken.adsb)
    assert (finding.table, finding.field) == ("adsb", "time_s")
    assert hint in finding.message


def test_time_overlap_tolerates_a_minute() -> None:
    assert check_time_overlap((0.0, 100.0), (150.0, 900.0)) is None
    assert check_time_overlap((0.0, 100.0), (161.0, 900.0)) is not None
    assert check_time_overlap((0.0, 100.0), None) is None


def test_ground_distance_against_a_known_arc() -> None:
    # One degree of latitude along a meridian: R * pi / 180.
    d = ground_distance_m(np.array([46.0]), np.array([7.0]), math.radians(45.0), math.radians(7.0))
    assert d[0] == pytest.approx(6_371_008.8 * math.pi / 180, rel=1e-12)


# ------------------------------------------------------------------ folders and readers
@pytest.fixture(scope="module")
def broken_folder(tmp_path_factory, demo) -> Path:
    folder = tmp_path_factory.mktemp("plaus") / "az_rad"
    write_dataset(_plots(demo, "NORD", "azimuth_deg", math.pi / 180), folder)
    return folder


def test_load_dataset_names_file_and_field_and_force_proceeds(broken_folder: Path) -> None:
    with pytest.raises(ImplausibleDataError) as info:
        load_dataset(broken_folder)
    text = str(info.value)
    assert text.startswith(f"{broken_folder / 'plots.csv'}, field 'azimuth_deg': ")
    assert "radians" in text and "--force" in text
    assert isinstance(info.value, DatasetError)
    assert len(load_dataset(broken_folder, force=True).plots) == len(
        pd.read_csv(broken_folder / "plots.csv"))


def test_window_reader_checks_each_window(broken_folder: Path) -> None:
    with pytest.raises(ImplausibleDataError, match="azimuth_deg"):
        next(iter_windows(broken_folder, 600.0))
    assert len(list(iter_windows(broken_folder, 600.0, force=True))) == 3


def test_window_reader_checks_time_bases_before_the_first_window(tmp_path, demo) -> None:
    folder = tmp_path / "timebase"
    write_dataset(_adsb(demo, time_s=lambda a: a["time_s"] + 1.7e9), folder, fmt="parquet")
    for order in ("auto", "sorted"):
        with pytest.raises(ImplausibleDataError, match="time_s"):
            next(iter_windows(folder, 600.0, order=order))
    assert len(list(iter_windows(folder, 600.0, force=True))) == 3

"""The plausibility checks name the real cause: two aircraft's addresses swapped are not
an antenna height, barometric ADS-B heights are not every antenna's survey, flight levels
are not metres."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import graphcal
from graphcal.data.plausibility import check_tables
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def pressure() -> graphcal.Dataset:
    return graphcal.simulate(SCENARIOS / "demo_pressure.toml", seed=3).dataset


def _fields(ds) -> list[tuple[str, str]]:
    return [(f.table, f.field) for f in check_tables(ds.sites, ds.plots, ds.adsb)]


def test_the_clean_datasets_raise_nothing(demo, pressure) -> None:
    assert _fields(demo) == [] and _fields(pressure) == []


def test_two_swapped_addresses_are_not_an_antenna_height(demo) -> None:
    adsb = demo.adsb.copy()
    first, second = adsb["target_id"].drop_duplicates().to_numpy()[:2]
    swap = {first: second, second: first}
    adsb["target_id"] = adsb["target_id"].map(lambda x: swap.get(x, x))
    assert _fields(replace(demo, adsb=adsb)) == []  # left to the cleaning, which names them


def test_barometric_adsb_heights_are_named_not_the_antennas(pressure) -> None:
    adsb = pressure.adsb.copy()
    adsb["alt_m"] = adsb["baro_alt_m"]
    (finding,) = check_tables(pressure.sites, pressure.plots, adsb)
    assert (finding.table, finding.field) == ("adsb", "alt_m")
    assert "baroaltitude" in finding.message and "every radar" in finding.message
    assert set(finding.radars) == set(pressure.sites)


def test_flight_levels_as_altitudes(demo) -> None:
    plots = demo.plots.copy()
    plots["altitude_m"] = np.round(plots["altitude_m"] / 0.3048 / 100.0)
    findings = check_tables(demo.sites, plots, demo.adsb)
    assert [(f.table, f.field) for f in findings] == [("plots", "altitude_m")]
    assert "flight levels" in findings[0].message

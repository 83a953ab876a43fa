"""More unit heuristics: elevations in radians, times in milliseconds, quantised times,
times of the day wrapping at midnight, UNIX time against seconds of the day."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.data.cleaning import clean_dataset, time_stamp_warnings
from graphcal.data.plausibility import (
    adsb_geometry,
    check_tables,
    elevation_radians,
    midnight_wrap,
)
from graphcal.io.folder import write_dataset

ALL = ("NORD", "SUD", "EST3D", "OUEST3D", "APP")



def _elevation_in_radians(ds, radar: str = "EST3D", altitude: bool = True):
    plots = ds.plots.copy()
    rows = plots["radar_id"] == radar
    plots.loc[rows, "elevation_deg"] = np.radians(plots.loc[rows, "elevation_deg"])
    if not altitude:
        plots.loc[rows, "altitude_m"] = np.nan
    return replace(ds, plots=plots)


def _times(ds, plots=None, adsb=None):
    p, a = ds.plots.copy(), ds.adsb.copy()
    if plots is not None:
        p["time_s"] = plots(p["time_s"])
    if adsb is not None:
        a["time_s"] = adsb(a["time_s"])
    return replace(ds, plots=p, adsb=a)


def _findings(ds):
    return check_tables(ds.sites, ds.plots, ds.adsb)


def _fields(ds):
    return [(f.table, f.field, f.radars) for f in _findings(ds)]


# --------------------------------------------------------------------------- 1. elevation
@pytest.mark.parametrize("adsb", [True, False], ids=["adsb", "no-adsb"])
@pytest.mark.parametrize("altitude", [True, False], ids=["altitude", "no-altitude"])
def test_elevation_in_radians_is_named_instead_of_the_antenna_height(demo, adsb, altitude):
    # Before: "the antenna height (alt_m) of EST3D looks wrong by about 2,451 m".
    ds = _elevation_in_radians(demo, altitude=altitude)
    if not adsb:
        ds = replace(ds, adsb=None)
    findings = _findings(ds)
    assert [(f.table, f.field, f.radars) for f in findings] == [
        ("plots", "elevation_deg", ("EST3D",))]
    assert "radians instead of degrees" in findings[0].message
    assert "antenna" not in findings[0].message


def test_elevation_in_radians_seen_against_the_adsb(demo):
    ds = _elevation_in_radians(demo, altitude=False)
    with np.errstate(all="ignore"):
        fits = adsb_geometry(ds.sites, ds.plots, ds.adsb)
    assert math.isclose(fits["EST3D"].elevation_ratio, math.pi / 180, rel_tol=0.1)
    assert math.isclose(fits["OUEST3D"].elevation_ratio, 1.0, rel_tol=0.1)
    finding = elevation_radians(ds.sites, ds.plots, fits)
    assert finding is not None and finding.radars == ("EST3D",)
    assert "ADS-B" in finding.message


def test_elevation_in_radians_exits_2_on_the_command_line(demo, tmp_path: Path):
    folder = write_dataset(_elevation_in_radians(demo), tmp_path / "elrad")
    result = CliRunner().invoke(app, ["calibrate", str(folder)])
    assert result.exit_code == 2, result.output
    line = " ".join(result.output.split())
    assert "field 'elevation_deg'" in line and "EST3D" in line and "radians" in line
    assert "antenna height" not in line and "--force" in line


# --------------------------------------------------------------------------- 2. milliseconds
def test_times_in_milliseconds(demo):
    # Before: exit 3 "nothing to calibrate: no plot matched ADS-B ...", no hint.
    both = _findings(_times(demo, lambda t: t * 1000, lambda t: t * 1000))
    assert [(f.table, f.field, f.radars) for f in both] == [
        ("plots", "time_s", tuple(sorted(ALL))), ("adsb", "time_s", ())]
    assert all("milliseconds" in f.message for f in both)
    assert "about 1,001 times its scan period apart (median; APP 4,002 s (scan 4 s), " \
           "EST3D 10,008 s (scan 10 s)" in both[0].message
    assert _fields(_times(demo, plots=lambda t: t * 1000)) == [
        ("plots", "time_s", tuple(sorted(ALL)))]
    assert _fields(_times(demo, adsb=lambda t: t * 1000)) == [("adsb", "time_s", ())]


def test_one_radar_in_milliseconds(demo):
    plots = demo.plots.copy()
    rows = plots["radar_id"] == "SUD"
    plots.loc[rows, "time_s"] *= 1000
    assert ("plots", "time_s", ("SUD",)) in _fields(replace(demo, plots=plots))


# --------------------------------------------------------------------------- 3. quantised
def test_whole_seconds_warn_but_do_not_refuse(demo):
    # Before: exit 0, SUD's range offset 5.4 sigma off, warnings naming other causes.
    ds = _times(demo, lambda t: t.round(), lambda t: t.round())
    assert _findings(ds) == []
    warnings = clean_dataset(ds)[1].warnings
    assert warnings[0].startswith("the plots' time_s are whole seconds: quantised time "
                                  "stamps add up to 0.29 s (1/sqrt(12) s) of timing noise, "
                                  "about 72 m along track at 250 m/s")
    assert warnings[1].startswith("the ADS-B reports' time_s are whole seconds")
    assert "off by several sigma" in warnings[0]
    assert time_stamp_warnings(demo.plots, demo.adsb) == []


def test_one_radar_quantised_to_half_seconds(demo):
    plots = demo.plots.copy()
    rows = plots["radar_id"] == "APP"
    plots.loc[rows, "time_s"] = (plots.loc[rows, "time_s"] * 2).round() / 2
    (warning,) = time_stamp_warnings(plots, demo.adsb)
    assert warning.startswith("radar APP's plots' time_s are multiples of 0.5 s")


# --------------------------------------------------------------------------- 4. time bases
def test_unix_time_against_seconds_of_the_day(demo):
    (finding,) = _findings(_times(demo, adsb=lambda t: t + 1.7e9))
    assert (finding.table, finding.field) == ("adsb", "time_s")
    assert "UNIX time against seconds of the day" in finding.message


def _wrap(t):
    return (t + 86400.0 - 900.0) % 86400.0


def test_midnight_wrap_in_both_tables_warns(demo):
    ds = _times(demo, _wrap, _wrap)
    assert _findings(ds) == []
    assert midnight_wrap(ds.plots["time_s"].to_numpy()) is not None
    assert midnight_wrap(demo.plots["time_s"].to_numpy()) is None
    (warning,) = time_stamp_warnings(ds.plots, ds.adsb)
    assert warning.startswith("time_s wrap at midnight (plots 85,521.9..86,399.9 s, then "
                              "0.0..899.9 s)")
    assert "add 86,400 s to the times after midnight" in warning


def test_midnight_wrap_in_one_table_only_is_refused(demo):
    ds = _times(demo, _wrap, lambda t: t + 86400.0 - 900.0)
    (finding,) = _findings(ds)
    assert (finding.table, finding.field) == ("plots", "time_s")
    assert "the plots' time_s wrap at midnight" in finding.message
    assert "the ADS-B's do not (85,520.7..87,300.0 s)" in finding.message

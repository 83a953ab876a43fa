"""Guard rails: a confidently wrong answer is refused or named, one test per case.

Each case takes the demo network (seed 1: 5 radars, ADS-B), makes one mistake in a copy
of its tables and checks that graphcal refuses it (exit 2, ``--force`` to proceed) or
says what is wrong, instead of a silent exit 0 with sigmas the data do not justify.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import graphcal
from graphcal.analysis.fit_verdict import shared_time_offset_warning
from graphcal.cli.app import app
from graphcal.data.cleaning import clean_dataset
from graphcal.data.plausibility import adsb_geometry, check_tables
from graphcal.pipeline.compare import row_status

runner = CliRunner()




def _copy(demo_dir: Path, tmp_path: Path) -> Path:
    out = tmp_path / "copy"
    out.mkdir()
    for item in demo_dir.iterdir():
        (out / item.name).write_bytes(item.read_bytes())
    return out


# ------------------------------------------------------------------ 1. ADS-B clock
def test_adsb_on_another_clock_is_refused_then_named(demo, demo_dir, tmp_path) -> None:
    """+30 s on the ADS-B times: before, every radar got time_offset_s -30.00 +- 0.003 and
    exit 0; the ±60 s overlap check could not see it.  Now the ADS-B geometry fit finds
    the shared offset and refuses (exit 2); with --force the result warns."""
    folder = _copy(demo_dir, tmp_path)
    adsb = pd.read_csv(folder / "adsb.csv", dtype={"target_id": str})
    adsb["time_s"] += 30.0
    adsb.to_csv(folder / "adsb.csv", index=False)
    result = runner.invoke(app, ["calibrate", str(folder)])
    assert result.exit_code == 2, result.output
    assert "adsb.csv, field 'time_s'" in result.output
    assert "-30.00 s" in result.output and "another clock" in result.output
    # The fit itself: every radar within 0.1 s of -30 s.
    shifted = dataclasses.replace(demo, adsb=demo.adsb.assign(time_s=demo.adsb["time_s"] + 30))
    fits = adsb_geometry(shifted.sites, shifted.plots, shifted.adsb)
    assert len(fits) == 5
    assert all(abs(f.time_offset_s + 30.0) < 0.1 for f in fits.values())
    # Second line of defence, after the estimate (--force).
    cal = graphcal.calibrate(shifted, "graph", model_checks=False)
    warning = shared_time_offset_warning(cal, shifted.sites)
    assert warning is not None and "ADS-B time_s is likely on another clock" in warning
    assert warning in cal.warnings


# ------------------------------------------------------------- 3. numeric options
@pytest.mark.parametrize("value", ["-3", "nan", "0", "inf"])
def test_max_gap_must_be_positive(demo_dir, value) -> None:
    """--max-gap-s -3 silently turned ADS-B off (exit 0); now exit 2."""
    result = runner.invoke(app, ["calibrate", str(demo_dir), "--max-gap-s", value])
    assert result.exit_code == 2, result.output
    assert "--max-gap-s must be a positive number of seconds" in result.output


@pytest.mark.parametrize(("args", "expected"), [
    (["--robust-scale", "inf"], "--robust-scale must be a positive, finite factor"),
    (["--fix", "NORD.range_gain=nan"], "the value must be a finite number"),
    (["--window", "10min", "--break", "NORD@nan"], "the time must be a finite number"),
])
def test_other_numeric_options_refused(demo_dir, args, expected) -> None:
    result = runner.invoke(app, ["calibrate", str(demo_dir), *args])
    assert result.exit_code == 2, result.output
    assert expected in result.output


def test_python_api_refuses_bad_gap(demo) -> None:
    with pytest.raises(ValueError, match="max_gap_s must be a positive"):
        graphcal.calibrate(demo, "ls", max_gap_s=-3.0)


# --------------------------------------------------------------- 4. range 1e300
def test_range_beyond_reach_is_named(demo, demo_dir, tmp_path) -> None:
    """range_m = 1e300: before, 30 lines of numpy overflow warnings and a wrong radar
    blamed; now the row is named (exit 2), and cleaning in memory drops it with a
    warning, without numpy warnings."""
    folder = _copy(demo_dir, tmp_path)
    plots = pd.read_csv(folder / "plots.csv", dtype={"target_id": str})
    plots.loc[100, "range_m"] = 1e300
    plots.to_csv(folder / "plots.csv", index=False)
    result = runner.invoke(app, ["calibrate", str(folder)])
    assert result.exit_code == 2, result.output
    assert "row 101, field 'range_m'" in result.output
    assert "beyond any radar's reach" in result.output
    assert "RuntimeWarning" not in result.output
    broken = demo.plots.copy()
    broken.loc[100, "range_m"] = 1e300
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cleaned, report = clean_dataset(dataclasses.replace(demo, plots=broken, cleaning=None))
    assert report.counts["plots_out_of_range"] == 1
    assert len(cleaned.plots) == len(demo.plots) - 1
    assert any("row 100" in w and "1e+300" in w for w in report.warnings)


# ------------------------------------------------------- 5. antenna height in feet
@pytest.mark.parametrize(("radar", "factor"), [("EST3D", 3.0), ("NORD", 3.2808)])
def test_antenna_height_in_feet_is_refused(demo, demo_dir, tmp_path, radar, factor) -> None:
    """alt_m 3x too high: before, exit 0 with the elevation bias ~100 sigma and range
    offsets 50 sigma off, blamed on refraction.  Now the antenna height is named."""
    folder = _copy(demo_dir, tmp_path)
    true_alt = demo.sites[radar].alt_m
    text = (folder / "sites.toml").read_text()
    assert f"alt_m = {true_alt}" in text
    wrong = round(true_alt * factor, 1)
    (folder / "sites.toml").write_text(text.replace(f"alt_m = {true_alt}", f"alt_m = {wrong}"))
    result = runner.invoke(app, ["calibrate", str(folder)])
    assert result.exit_code == 2, result.output
    out = " ".join(result.output.split())
    assert f"the antenna height (alt_m) of {radar} looks wrong by about" in out
    assert "feet instead of metres?" in out
    fits = adsb_geometry({**demo.sites, radar: dataclasses.replace(demo.sites[radar],
                                                                   alt_m=wrong)},
                         demo.plots, demo.adsb)
    assert abs(fits[radar].antenna_dh_m + (wrong - true_alt)) < 0.1 * (wrong - true_alt)


def test_no_geometry_finding_on_the_demo(demo) -> None:
    fits = adsb_geometry(demo.sites, demo.plots, demo.adsb)
    assert all(abs(f.time_offset_s) < 0.1 for f in fits.values())
    assert all(abs(f.antenna_dh_m) < 60.0 for f in fits.values())
    assert check_tables(demo.sites, demo.plots, demo.adsb) == []


# -------------------------------------------------------------- 6. compare status
def test_compare_status_names_dishonest_sigmas() -> None:
    """A row with sigma-hat/std 0.15 over 24 runs was 'ok'."""
    assert row_status("ok", 24, 45.0, 20.0, 45.0, 0.15) == "sigma too small (σ̂/std 0.15)"
    assert row_status("ok", 24, 45.0, 20.0, 45.0, 1.6).startswith("sigma too large")
    assert row_status("ok", 24, 45.0, 20.0, 45.0, 1.0) == "ok"
    assert row_status("ok", 24, 1337.0, 14.6, 297.0, 0.94).startswith("biased")
    assert row_status("ok", 12, 45.0, 2.0, 45.0, 1.47) == "ok"  # chance at 12 runs
    assert row_status("ok", 5, 45.0, 2.0, 45.0, 0.2) == "ok"  # too few runs to judge
    assert row_status("failed in 2 of 24 runs", 22, 45.0, 2.0, 45.0, 0.2).startswith(
        "failed in 2 of 24 runs; sigma too small")


def test_ls_sigmas_widen_with_an_unmodelled_time_offset(demo) -> None:
    """A 0.5 s time-stamping bias ls does not model: its formal sigmas were 5-7 times too
    small (compare: sigma-hat/std 0.14-0.17 over 24 runs); the per-aircraft spread of
    the residuals now widens them, and says so."""
    plots = demo.plots.copy()
    plots["time_s"] += 0.5  # time_reported = time_true + 0.5 s on every radar
    late = dataclasses.replace(demo, plots=plots, cleaning=None)
    honest = graphcal.calibrate(demo, "ls", model_checks=False, check_fit=False)
    cal = graphcal.calibrate(late, "ls", model_checks=False, check_fit=False)
    assert "formal" in cal.info["sigma"]
    inflations = {rid: d.get("sigma_inflation", 1.0) for rid, d in cal.info["per_radar"].items()}
    assert max(inflations.values()) > 4.0
    assert any("sigmas widened" in w for w in cal.warnings)
    ratio = cal.sigma("NORD", "range_offset_m") / honest.sigma("NORD", "range_offset_m")
    assert ratio > 2.0
    assert not any("sigmas widened" in w for w in honest.warnings)


# ----------------------------------------------------- 7. observability parameters
def test_observability_says_time_offsets_are_left_out(demo_dir) -> None:
    result = runner.invoke(app, ["observability", str(demo_dir)])
    assert result.exit_code == 0, result.output
    out = " ".join(result.output.split())
    assert "rank 16 of 16" in out
    assert "16 parameters: time offsets (time_offset_s) are not included" in out
    assert "up to 5 more parameters" in out


def test_shared_warning_silent_on_honest_offsets(demo) -> None:
    cal = graphcal.calibrate(demo, "graph", model_checks=False)
    assert shared_time_offset_warning(cal, demo.sites) is None
    assert math.isfinite(cal.value("NORD", "time_offset_s"))
    assert np.all(np.isfinite(cal.covariance_si))

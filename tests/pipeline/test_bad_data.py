"""Bad data never gives a confident wrong calibration.

Each defect of real recordings is injected into a small synthetic dataset (3 radars,
12 aircraft, 15 min; :mod:`synthetic`) whose true biases are known.  After cleaning
(:mod:`graphcal.data.cleaning`, run by :func:`graphcal.io.folder.load_dataset`) the estimate
must be within 3 sigma of the truth, or a specific warning or error must say what
cannot be calibrated.  Where a defect matters, the uncleaned data are shown to give a
wrong answer, so that the checks can fail.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d
import pytest

from graphcal.core.errors import DatasetError, EstimationError
from graphcal.data.bias import RadarBias
from graphcal.data.calibration import Calibration
from graphcal.data.cleaning import check_identities, clean_dataset, ensure_clean, traffic_groups
from graphcal.data.dataset import Dataset
from graphcal.io.folder import load_dataset, write_dataset
from graphcal.solvers.adsb_reference import fl_ls
from graphcal.solvers.graph import graph
from graphcal.solvers.wls import wls
from tests.synthetic import ORIGIN, Track, make_dataset, site_at

BIASES = {
    "A": RadarBias(80.0, 0.0008, 0.004),
    "B": RadarBias(-60.0, -0.0005, -0.003, 0.002),
    "C": RadarBias(40.0, 0.0003, 0.002),
}


def _sites() -> dict:
    return {
        "A": site_at("A", -50e3, 0.0),
        "B": site_at("B", 50e3, 20e3, sigma_elevation_mrad=2.0),
        "C": site_at("C", 0.0, -60e3, sigma_range_m=50.0),
    }


def _tracks(rng: np.random.Generator, n: int = 12, duration_s: float = 900.0,
            prefix: str = "4ca", east_m: float = 0.0) -> list[Track]:
    tracks = []
    for i in range(n):
        start = (east_m + rng.uniform(-90e3, 90e3), rng.uniform(-90e3, 90e3),
                 rng.uniform(4e3, 11e3))
        heading, speed = rng.uniform(0.0, 2 * np.pi), rng.uniform(150.0, 250.0)
        velocity = (speed * np.sin(heading), speed * np.cos(heading), 0.0)
        tracks.append(Track(f"{prefix}{i:03x}", start, velocity, 0.0, duration_s))
    return tracks


def _dataset(seed: int = 1, biases: dict[str, RadarBias] = BIASES) -> Dataset:
    rng = np.random.default_rng(seed)
    sites = _sites()
    return make_dataset(rng, [(sites[rid], biases[rid]) for rid in biases], _tracks(rng))


def _z(cal: Calibration, biases: dict[str, RadarBias]) -> np.ndarray:
    sigma = np.sqrt(np.diag(cal.covariance))
    return np.array([(cal.estimate[i] - biases[rid].value(name)) / sigma[i]
                     for i, (rid, name) in enumerate(cal.labels)])


def _z_clean(dirty: Calibration, clean: Calibration,
             biases: dict[str, RadarBias] = BIASES) -> np.ndarray:
    """Errors of ``dirty`` in the sigmas of the same method on the clean data: how far a
    defect moves the estimate, whatever sigmas the method reports on the dirty data (the
    paper methods widen theirs when their residuals show the defect)."""
    sigma = np.sqrt(np.diag(clean.covariance))
    return np.array([(dirty.estimate[i] - biases[rid].value(name)) / sigma[i]
                     for i, (rid, name) in enumerate(dirty.labels)])


def _assert_within_3_sigma(cal: Calibration, biases: dict[str, RadarBias] = BIASES) -> None:
    z = _z(cal, biases)
    assert np.max(np.abs(z)) < 3.0, dict(zip(cal.contract_labels(), np.round(z, 1), strict=True))


def _graph(dataset: Dataset, **options) -> Calibration:
    return graph(dataset, **options)


def _replace(dataset: Dataset, **tables) -> Dataset:
    return Dataset(tables.get("sites", dataset.sites), tables.get("plots", dataset.plots),
                   tables.get("adsb", dataset.adsb))


# --------------------------------------------------------------------------- corruptions
def _duplicated(dataset: Dataset, fraction: float = 0.3) -> tuple[Dataset, int, int]:
    plots = dataset.plots.sample(frac=fraction, random_state=1)
    adsb = dataset.adsb.sample(frac=fraction, random_state=2)
    out = _replace(dataset, plots=pd.concat([dataset.plots, plots], ignore_index=True),
                   adsb=pd.concat([dataset.adsb, adsb], ignore_index=True))
    return out, len(plots), len(adsb)


def _shuffled(dataset: Dataset) -> Dataset:
    return _replace(dataset,
                    plots=dataset.plots.sample(frac=1.0, random_state=3).reset_index(drop=True),
                    adsb=dataset.adsb.sample(frac=1.0, random_state=4).reset_index(drop=True))


def _stale(dataset: Dataset, rng: np.random.Generator, fraction: float = 0.2
           ) -> tuple[Dataset, int]:
    """About ``fraction`` of the reports repeat the aircraft's previous position."""
    adsb = dataset.adsb.sort_values(["target_id", "time_s"], ignore_index=True)
    same = adsb["target_id"].eq(adsb["target_id"].shift()).to_numpy()
    pick = np.flatnonzero(same & (rng.random(len(adsb)) < fraction))
    values = adsb[["lat_deg", "lon_deg", "alt_m"]].to_numpy().copy()
    for i in pick:  # in order, so runs of stale reports repeat the last fresh one
        values[i] = values[i - 1]
    adsb[["lat_deg", "lon_deg", "alt_m"]] = values
    return _replace(dataset, adsb=adsb), len(pick)


def _shift_enu(adsb: pd.DataFrame, rows: np.ndarray, east_m, north_m) -> None:
    lat, lon, alt = (adsb.loc[rows, c].to_numpy() for c in ("lat_deg", "lon_deg", "alt_m"))
    e, n, u = pymap3d.geodetic2enu(lat, lon, alt, *ORIGIN)
    lat, lon, _ = pymap3d.enu2geodetic(e + east_m, n + north_m, u, *ORIGIN)
    adsb.loc[rows, "lat_deg"], adsb.loc[rows, "lon_deg"] = lat, lon


def _spoofed(dataset: Dataset, target: str = "4ca003", start_s: float = 200.0,
             end_s: float = 500.0, offset_m: float = 6000.0) -> Dataset:
    """A stretch of one aircraft's reports offset by ``offset_m`` (east) and half that north."""
    adsb = dataset.adsb.copy()
    rows = adsb.index[(adsb["target_id"] == target) & adsb["time_s"].between(start_s, end_s)]
    _shift_enu(adsb, rows.to_numpy(), offset_m, 0.5 * offset_m)
    return _replace(dataset, adsb=adsb)


def _wild(dataset: Dataset, rng: np.random.Generator, n: int = 30, distance_m: float = 30e3
          ) -> tuple[Dataset, int]:
    """``n`` single reports thrown ``distance_m`` away (not the first or last of a track)."""
    adsb = dataset.adsb.copy()
    inner = adsb.groupby("target_id")["time_s"].transform(
        lambda t: (t > t.min()) & (t < t.max())).to_numpy(dtype=bool)
    rows = rng.choice(np.flatnonzero(inner), n, replace=False)
    angle = rng.uniform(0.0, 2 * np.pi, n)
    _shift_enu(adsb, rows, distance_m * np.cos(angle), distance_m * np.sin(angle))
    return _replace(dataset, adsb=adsb), n


def _mislabelled(dataset: Dataset, radar: str = "A", aircraft: str = "4ca001",
                 address: str = "4ca002") -> Dataset:
    """Radar ``radar`` reports aircraft ``aircraft`` under ``address`` (wrong address or a
    second transponder) and does not see the real ``address`` aircraft."""
    plots = dataset.plots.copy()
    on_radar = plots["radar_id"] == radar
    plots = plots[~(on_radar & (plots["target_id"] == address))].copy()
    plots.loc[on_radar & (plots["target_id"] == aircraft), "target_id"] = address
    return _replace(dataset, plots=plots.reset_index(drop=True))


# --------------------------------------------------------------------------- each case
def test_duplicates_are_dropped_and_do_not_shrink_the_sigmas() -> None:
    clean = _dataset()
    reference = _graph(clean)
    dirty, n_plots, n_adsb = _duplicated(clean)
    # Counted twice, the duplicates make the sigmas too small by about 1 / sqrt(1.3).
    ratio = np.sqrt(np.diag(_graph(dirty).covariance) / np.diag(reference.covariance))
    assert np.all(ratio < 0.93)
    cleaned, report = clean_dataset(dirty)
    assert report.counts["plots_duplicate"] == n_plots
    assert report.counts["adsb_duplicate"] == n_adsb
    assert len(cleaned.plots) == len(clean.plots) and len(cleaned.adsb) == len(clean.adsb)
    cal = _graph(cleaned)
    np.testing.assert_allclose(np.diag(cal.covariance), np.diag(reference.covariance), rtol=1e-6)
    _assert_within_3_sigma(cal)


def test_out_of_order_rows_give_the_same_calibration() -> None:
    ordered = _dataset()
    shuffled, report = clean_dataset(_shuffled(ordered))
    assert report.n_changed == 0
    assert not shuffled.plots["time_s"].is_monotonic_increasing
    a, b = _graph(ordered), _graph(shuffled)
    np.testing.assert_allclose(a.estimate, b.estimate, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(fl_ls(ordered).estimate, fl_ls(shuffled).estimate, rtol=1e-9)
    _assert_within_3_sigma(b)


def test_stale_adsb_reports_are_dropped() -> None:
    dirty, n_stale = _stale(_dataset(), np.random.default_rng(5))
    # The lagging positions do matter to the pairwise formulation's interpolated ADS-B;
    # the trajectory formulation's gate leaves them out of its paths.
    assert np.max(np.abs(_z(_graph(dirty, cross="pairwise"), BIASES))) > 5.0
    _assert_within_3_sigma(_graph(dirty))
    cleaned, report = clean_dataset(dirty)
    assert report.counts["adsb_stale"] == n_stale
    assert report.counts["adsb_jumping_aircraft"] == 0 and not report.warnings
    _assert_within_3_sigma(_graph(cleaned))
    _assert_within_3_sigma(fl_ls(cleaned))


def test_spoofed_stretch_drops_the_aircraft_with_a_warning() -> None:
    dirty = _spoofed(_dataset())
    assert np.max(np.abs(_z_clean(fl_ls(dirty), fl_ls(_dataset())))) > 10.0
    assert np.max(np.abs(_z(_graph(dirty), BIASES))) > 3.0
    cleaned, report = clean_dataset(dirty)
    assert report.jumping_aircraft == ["4ca003"]
    assert report.counts["adsb_jumping_aircraft"] == 900
    (warning,) = report.warnings
    assert "4ca003" in warning and "t = 199.0 s" in warning and "t = 501.0 s" in warning
    assert "4ca003" not in set(cleaned.adsb["target_id"])
    assert "4ca003" in set(cleaned.plots["target_id"])  # its plots still pair between radars
    _assert_within_3_sigma(_graph(cleaned))
    _assert_within_3_sigma(fl_ls(cleaned))


def test_isolated_wild_adsb_reports_are_dropped() -> None:
    dirty, n_wild = _wild(_dataset(), np.random.default_rng(6))
    assert np.max(np.abs(_z_clean(fl_ls(dirty), fl_ls(_dataset())))) > 10.0
    cleaned, report = clean_dataset(dirty)
    # A wild report next to the start or end of a track can take a true neighbour along.
    assert n_wild <= report.counts["adsb_wild"] <= n_wild + 4
    assert report.counts["adsb_jumping_aircraft"] == 0 and not report.warnings
    _assert_within_3_sigma(_graph(cleaned))
    _assert_within_3_sigma(fl_ls(cleaned))


def test_wrong_address_clears_the_plot_ids_with_a_warning() -> None:
    dirty = _mislabelled(_dataset())
    assert np.max(np.abs(_z(_graph(dirty), BIASES))) > 5.0
    cleaned, report = clean_dataset(dirty)
    assert [(r, t) for r, t, _ in report.mislabelled] == [("A", "4ca002")]
    assert report.mislabelled[0][2] > 10e3
    (warning,) = report.warnings
    assert warning.startswith("radar A: the plots labelled 4ca002 are") and " km " in warning
    moved = (dirty.plots["radar_id"] == "A") & (dirty.plots["target_id"] == "4ca002")
    assert report.counts["plots_identity_cleared"] == int(moved.sum())
    assert "4ca002" not in set(cleaned.plots.loc[cleaned.plots["radar_id"] == "A", "target_id"])
    _assert_within_3_sigma(_graph(cleaned))
    _assert_within_3_sigma(fl_ls(cleaned))


def test_identity_check_is_robust_to_large_true_biases() -> None:
    """160 mrad of azimuth bias at ~100 km is 16 km, common to all aircraft of the radar."""
    large = {
        "A": RadarBias(2000.0, 0.01, 0.160),
        "B": RadarBias(-1500.0, -0.008, -0.120, 0.01),
        "C": RadarBias(500.0, 0.005, 0.080),
    }
    honest = _dataset(seed=2, biases=large)
    _, report = check_identities(honest.plots, honest.adsb, honest.sites)
    assert report.mislabelled == [] and report.counts["plots_identity_cleared"] == 0
    dirty = _mislabelled(honest, radar="B", aircraft="4ca005", address="4ca007")
    _, report = check_identities(dirty.plots, dirty.adsb, dirty.sites)
    assert [(r, t) for r, t, _ in report.mislabelled] == [("B", "4ca007")]


def test_radar_without_plots_is_warned_and_the_others_calibrated() -> None:
    dataset = _dataset()
    sites = {**dataset.sites, "D": site_at("D", 0.0, 80e3)}
    for use_adsb in (True, False):
        cleaned, report = clean_dataset(_replace(dataset, sites=sites,
                                                 adsb=dataset.adsb if use_adsb else None))
        assert "radar D has no plots; not calibrated" in report.warnings
        cal = _graph(cleaned)
        assert cal.radar_ids == ["A", "B", "C"]
        assert "radar D has no usable observations; not calibrated" in cal.warnings
        _assert_within_3_sigma(cal)
    # wls (cross-radar only) leaves D out with a warning instead of failing.
    cal = wls(_replace(dataset, sites=sites, adsb=None))
    assert cal.radar_ids == ["A", "B", "C"]
    assert any("radar D" in w for w in cal.warnings)
    assert cal.observability.n_parameters == len(cal.labels)
    _assert_within_3_sigma(cal)


def test_a_single_radar_without_adsb_is_a_clear_error() -> None:
    dataset = _dataset()
    lonely = _replace(dataset, plots=dataset.plots[dataset.plots["radar_id"] == "A"], adsb=None)
    cleaned, report = clean_dataset(lonely)
    assert "radar B has no plots; not calibrated" in report.warnings
    with pytest.raises(EstimationError, match="nothing to calibrate"):
        _graph(cleaned)


def test_radar_groups_without_common_traffic_are_named() -> None:
    """Without ADS-B: radars A-B see one area, C-D another 450 km away, E a third alone."""
    rng = np.random.default_rng(3)
    sites = {"A": site_at("A", -50e3, 0.0), "B": site_at("B", 50e3, 0.0),
             "C": site_at("C", 400e3, 0.0), "D": site_at("D", 500e3, 0.0),
             "E": site_at("E", 0.0, 600e3)}
    biases = {"A": RadarBias(80.0, 0.0008, 0.004), "B": RadarBias(-60.0, -0.0005, -0.003),
              "C": RadarBias(40.0, 0.0003, 0.002), "D": RadarBias(-30.0, 0.0002, -0.001),
              "E": RadarBias(10.0, 0.0, 0.001)}
    parts = [
        make_dataset(rng, [(sites["A"], biases["A"]), (sites["B"], biases["B"])],
                     _tracks(rng, 8), adsb=False),
        make_dataset(rng, [(sites["C"], biases["C"]), (sites["D"], biases["D"])],
                     _tracks(rng, 8, prefix="5b0", east_m=450e3), adsb=False),
        make_dataset(rng, [(sites["E"], biases["E"])],
                     [Track("6c0001", (20e3, 640e3, 9e3), (200.0, 0.0, 0.0), 0.0, 600.0)],
                     adsb=False),
    ]
    plots = pd.concat([p.plots for p in parts], ignore_index=True)
    dataset, report = clean_dataset(Dataset(sites, plots, None))
    assert traffic_groups(plots, list(sites)) == [["A", "B"], ["C", "D"], ["E"]]
    assert any("radars {A, B} and {C, D} and {E} have no aircraft in common" in w
               for w in report.warnings)
    assert any(w.startswith("radar E shares no aircraft") for w in report.warnings)
    cal = _graph(dataset)
    assert "radar E has no usable observations; not calibrated" in cal.warnings
    assert "E" not in cal.radar_ids
    # Each pair is determined by its own geometry; whatever is not must be flagged.
    z = _z(cal, biases)
    undetermined = set(cal.info["undetermined"])
    for label, value in zip(cal.contract_labels(), z, strict=True):
        assert abs(value) < 3.0 or label in undetermined, (label, value)


def test_2d_radar_without_altitude() -> None:
    dataset = _dataset()
    plots = dataset.plots.copy()
    plots["altitude_m"] = np.nan
    with_adsb, report = clean_dataset(_replace(dataset, plots=plots))
    assert not report.warnings
    _assert_within_3_sigma(_graph(with_adsb))  # heights from ADS-B
    _assert_within_3_sigma(fl_ls(with_adsb))
    without_adsb, report = clean_dataset(_replace(dataset, plots=plots, adsb=None))
    for rid in ("A", "C"):
        assert any(w.startswith(f"radar {rid} is 2-D and none of its plots carries an altitude")
                   for w in report.warnings)
    with pytest.raises(EstimationError, match="nothing to calibrate"):
        _graph(without_adsb, cross="pairwise")
    # The trajectory formulation places the 2-D plots on paths whose heights the 3-D
    # radar measures: every radar calibrated.
    _assert_within_3_sigma(_graph(without_adsb))


def test_non_finite_values(tmp_path: Path) -> None:
    dataset = _dataset()
    plots, adsb = dataset.plots.copy(), dataset.adsb.copy()
    plots.loc[5, "range_m"] = np.inf
    plots.loc[9, "azimuth_deg"] = np.nan
    plots.loc[12, "altitude_m"] = -np.inf
    adsb.loc[7, "lat_deg"] = np.nan
    adsb.loc[8, "alt_m"] = np.inf
    dirty = _replace(dataset, plots=plots, adsb=adsb)
    # In a file: a clear error naming file, row and field.
    write_dataset(dirty, tmp_path / "ds")
    with pytest.raises(DatasetError, match=r"plots\.csv, row 6, field 'range_m'"):
        load_dataset(tmp_path / "ds")
    # In memory (a dataset built by a program): the rows are dropped and counted.
    # Uncleaned, the solver fails on NaN (numpy's warnings on the way are expected).
    with pytest.raises(Exception), np.errstate(invalid="ignore"):  # noqa: B017
        _graph(dirty)
    cleaned, report = clean_dataset(dirty)
    assert report.counts["plots_non_finite"] == 2 and report.counts["adsb_non_finite"] == 2
    assert np.isnan(cleaned.plots["altitude_m"]).sum() == 1
    _assert_within_3_sigma(_graph(cleaned))
    assert ensure_clean(dirty).cleaning.counts == report.counts
    assert ensure_clean(cleaned) is cleaned


def test_load_dataset_cleans_in_memory_and_leaves_the_files_alone(tmp_path: Path) -> None:
    dirty, n_plots, n_adsb = _duplicated(_dataset())
    write_dataset(dirty, tmp_path / "ds")
    before = {p.name: p.read_bytes() for p in (tmp_path / "ds").iterdir()}
    loaded = load_dataset(tmp_path / "ds")
    assert loaded.cleaning is not None
    assert loaded.cleaning.counts["plots_duplicate"] == n_plots
    assert len(loaded.plots) == len(dirty.plots) - n_plots
    raw = load_dataset(tmp_path / "ds", clean=False)
    assert raw.cleaning is None and len(raw.plots) == len(dirty.plots)
    assert len(raw.adsb) == len(dirty.adsb)
    assert {p.name: p.read_bytes() for p in (tmp_path / "ds").iterdir()} == before


# --------------------------------------------------------------------------- all together
def test_all_defects_together(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    dataset = _dataset(seed=5)
    dirty = _mislabelled(dataset, radar="C", aircraft="4ca004", address="4ca006")
    dirty = _spoofed(dirty, target="4ca008", start_s=300.0, end_s=700.0, offset_m=4000.0)
    dirty, n_wild = _wild(dirty, rng, n=20)
    dirty, n_stale = _stale(dirty, rng)
    dirty, n_dup_plots, n_dup_adsb = _duplicated(dirty, 0.2)
    dirty = _shuffled(dirty)
    plots = dirty.plots.copy()
    plots.loc[plots["radar_id"] == "A", "altitude_m"] = np.nan  # 2-D radar without altitude
    sites = {**dirty.sites, "D": site_at("D", 0.0, 80e3)}  # a radar that sees nothing
    write_dataset(_replace(dirty, sites=sites, plots=plots), tmp_path / "ds")

    loaded = load_dataset(tmp_path / "ds")
    report = loaded.cleaning
    assert report is not None
    assert report.counts["plots_duplicate"] == n_dup_plots
    assert report.counts["adsb_duplicate"] == n_dup_adsb
    assert report.counts["adsb_stale"] >= 0.9 * n_stale
    # Some wild reports are repeated by a stale report, or belong to the spoofed aircraft.
    assert n_wild // 2 <= report.counts["adsb_wild"] <= n_wild + 4
    assert report.jumping_aircraft == ["4ca008"]
    assert [(r, t) for r, t, _ in report.mislabelled] == [("C", "4ca006")]
    assert "radar D has no plots; not calibrated" in report.warnings
    assert len(report.warnings) == 3

    raw = load_dataset(tmp_path / "ds", clean=False)
    assert np.max(np.abs(_z_clean(fl_ls(raw), fl_ls(dataset)))) > 10.0
    cal = _graph(loaded)
    assert cal.radar_ids == ["A", "B", "C"]
    _assert_within_3_sigma(cal)
    _assert_within_3_sigma(fl_ls(loaded))


def test_duplicate_records_are_those_pandas_finds() -> None:
    """The sorting duplicate search drops exactly DataFrame.duplicated's rows (the first
    kept), with NaN equal to NaN, -0.0 to 0.0, missing identities equal, and records that
    share the time but not the position kept."""
    from graphcal.data.cleaning import drop_duplicate_adsb, drop_duplicate_plots

    rng = np.random.default_rng(11)
    for _ in range(200):
        n = int(rng.integers(2, 40))
        adsb = pd.DataFrame({
            "time_s": rng.choice([0.0, 1.0, 2.0, np.nan], n),
            "target_id": pd.Series(rng.choice(["a1", "b2", "", None], n), dtype="str"),
            "lat_deg": rng.choice([0.0, -0.0, 1.5, np.nan], n),
            "lon_deg": rng.choice([3.0, 4.0], n),
            "alt_m": rng.choice([10.0, 11.0], n),
        })
        kept, report = drop_duplicate_adsb(adsb)
        expected = adsb.duplicated(keep="first").to_numpy()
        assert report.counts["adsb_duplicate"] == expected.sum()
        pd.testing.assert_frame_equal(kept, adsb[~expected].reset_index(drop=True))
        plots = pd.DataFrame({
            "radar_id": pd.Series(rng.choice(["A", "B"], n), dtype="str"),
            "time_s": rng.choice([5.0, 6.0], n), "range_m": rng.choice([1e4, 2e4], n),
            "azimuth_deg": rng.choice([10.0, 20.0], n), "elevation_deg": np.nan,
            "target_id": pd.Series(rng.choice(["a1", ""], n), dtype="str"),
        })
        kept, report = drop_duplicate_plots(plots)
        expected = plots.duplicated(keep="first").to_numpy()
        pd.testing.assert_frame_equal(kept, plots[~expected].reset_index(drop=True))


@pytest.mark.parametrize("row_order", ["shuffled", "by time"])
def test_clean_dataset_is_its_steps_one_after_the_other(row_order: str) -> None:
    """clean_dataset finds the ADS-B track order once and carries it through the stale
    reports, the gate and the identity check; running the public steps one by one (each
    finding the order afresh) must give the same tables, counts and warnings, in order,
    also when an aircraft's first row in the table is one that is dropped."""
    from graphcal.data.cleaning import (
        coverage_warnings,
        drop_duplicate_adsb,
        drop_duplicate_plots,
        drop_non_finite_adsb,
        drop_non_finite_plots,
        drop_stale_adsb,
        gate_adsb_kinematics,
    )

    rng = np.random.default_rng(8)
    dirty = _mislabelled(_dataset(seed=6), radar="C", aircraft="4ca004", address="4ca006")
    dirty = _spoofed(dirty, target="4ca008", start_s=300.0, end_s=700.0, offset_m=4000.0)
    dirty = _spoofed(dirty, target="4ca002", start_s=100.0, end_s=400.0, offset_m=5000.0)
    dirty, _ = _wild(dirty, rng, n=20)
    dirty, _ = _stale(dirty, rng, fraction=0.3)
    dirty, _, _ = _duplicated(dirty, 0.2)
    dirty = _shuffled(dirty)
    if row_order == "by time":
        dirty = _replace(dirty, adsb=dirty.adsb.sort_values("time_s", kind="stable",
                                                            ignore_index=True))
    cleaned, report = clean_dataset(dirty)

    plots, _ = drop_non_finite_plots(dirty.plots, dirty.sites)
    plots, _ = drop_duplicate_plots(plots)
    adsb = dirty.adsb
    steps = []
    for step in (drop_non_finite_adsb, drop_duplicate_adsb, drop_stale_adsb,
                 gate_adsb_kinematics):
        adsb, found = step(adsb)
        steps.append(found)
    plots, identity = check_identities(plots, adsb, dirty.sites)
    steps.append(identity)

    pd.testing.assert_frame_equal(cleaned.adsb, adsb)
    pd.testing.assert_frame_equal(cleaned.plots, plots)
    assert report.jumping_aircraft == steps[3].jumping_aircraft
    assert sorted(report.jumping_aircraft) == ["4ca002", "4ca008"]
    assert report.mislabelled == identity.mislabelled
    assert [(r, t) for r, t, _ in report.mislabelled] == [("C", "4ca006")]
    for name in ("adsb_stale", "adsb_wild", "adsb_jumping_aircraft"):
        assert report.counts[name] == sum(s.counts.get(name, 0) for s in steps)
    assert report.counts["adsb_stale"] > 0 and report.counts["adsb_wild"] > 0
    expected_warnings = [w for s in steps for w in s.warnings]
    expected_warnings += coverage_warnings(plots, dirty.sites, True)
    assert report.warnings == expected_warnings


def test_clean_dataset_names_jumping_aircraft_in_table_order_after_a_stale_first_row(
        ) -> None:
    """The jumping aircraft are named in the order they first appear in the table that is
    gated, as gate_adsb_kinematics names them: also when the table's first row, a stale
    report of the later aircraft, is dropped before the gate."""
    from graphcal.data.cleaning import gate_adsb_kinematics

    dirty = _spoofed(_dataset(seed=6), target="4ca008", start_s=300.0, end_s=700.0,
                     offset_m=4000.0)
    dirty = _spoofed(dirty, target="4ca002", start_s=100.0, end_s=400.0, offset_m=5000.0)
    adsb = dirty.adsb.sort_values("time_s", kind="stable", ignore_index=True)
    first_seen = [t for t in pd.unique(adsb["target_id"]) if t in ("4ca002", "4ca008")]
    later = first_seen[1]
    mine = adsb[adsb["target_id"] == later]
    repeat = mine.iloc[[0]].copy()  # its first position again, half a second later: stale
    repeat["time_s"] += 0.5
    adsb = pd.concat([repeat, adsb], ignore_index=True)
    cleaned, report = clean_dataset(_replace(dirty, adsb=adsb))

    assert report.counts["adsb_stale"] == 1
    _, gate = gate_adsb_kinematics(adsb.iloc[1:].reset_index(drop=True))
    assert gate.jumping_aircraft == first_seen
    assert report.jumping_aircraft == first_seen

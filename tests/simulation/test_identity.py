"""Tests of the contract v3 simulation: plot identity, Mode 3/A codes, track numbers, clutter
and the plots' truth."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from graphcal.core.errors import ScenarioError
from graphcal.data.dataset import PLOT_COLUMNS
from graphcal.simulation.chunks import TimeSpan
from graphcal.simulation.scenario import load_scenario, parse_scenario
from graphcal.simulation.simulate import (
    CLUTTER,
    CLUTTER_MAX_ELEVATION_DEG,
    SPECIAL_CODES,
    TRACK_COAST_SCANS,
    TrackNumbers,
    clutter_plots,
    simulate,
    truth_document,
    write_simulation,
)
from graphcal.simulation.stream import simulate_to_folder
from tests.paths import SCENARIOS

ORIGIN = {"lat_deg": 48.85, "lon_deg": 2.35, "alt_m": 0.0}
OCTAL_CODE = r"^[0-7]{4}$"


def _radar(radar_id: str, lat: float, lon: float, *, three_d: bool = False, **extra) -> dict:
    entry = {"id": radar_id, "lat_deg": lat, "lon_deg": lon, "alt_m": 100.0,
             "sigma_range_m": 50.0, "sigma_azimuth_mrad": 1.5, "scan_period_s": 4.0,
             "max_range_m": 300_000.0, "min_elevation_deg": -1.0}
    if three_d:
        entry["sigma_elevation_mrad"] = 2.0
    entry.update(extra)
    return entry


def _document(radars: list[dict], *, n_aircraft: int = 8, duration_s: float = 600.0,
              **tables) -> dict:
    """Random traffic near Paris seen by ``radars``, with ADS-B, and further top-level tables."""
    doc = {
        "scenario": {"name": "identity", "duration_s": duration_s, "origin": dict(ORIGIN)},
        "radar": radars,
        "traffic": {"n_aircraft": n_aircraft, "radius_m": 60_000.0},
        "adsb": {"nacp": 9},
    }
    doc.update(tables)
    return doc


def _three_radars(**changes) -> list[dict]:
    """A Mode S, a Mode A/C and a 3-D primary radar; ``changes`` per radar id."""
    radars = [
        _radar("S", 48.70, 2.10, identity="mode_s"),
        _radar("AC", 49.10, 2.70, identity="mode_ac", scan_period_s=5.0),
        _radar("P3", 48.60, 2.80, three_d=True, identity="psr", scan_period_s=6.0),
    ]
    for radar in radars:
        radar.update(changes.get(radar["id"], {}))
    return radars


@pytest.fixture(scope="module")
def mixed():
    """The three radars with Mode 3/A codes, simulated with seed 31."""
    doc = _document(_three_radars(), **{"mode_3a": {"vfr_fraction": 0.25, "code_changes": 0.5}})
    return simulate(parse_scenario(doc), np.random.default_rng(31))


# --------------------------------------------------------------------------- parsing


def test_defaults_are_version_2():
    scenario = parse_scenario(_document([_radar("R", 48.7, 2.1)]))
    radar = scenario.radars[0]
    assert (radar.identity, radar.track_numbers, radar.clutter_per_scan) == ("mode_s", False, 0.0)
    assert radar.detection_probability == 1.0
    assert scenario.mode_3a is None and scenario.codes is None
    assert scenario.addressed and not scenario.track_numbers


def test_a_mode_ac_radar_brings_codes_with_the_defaults():
    scenario = parse_scenario(_document([_radar("R", 48.7, 2.1, identity="mode_ac")]))
    assert scenario.mode_3a is None
    assert scenario.codes is not None and scenario.codes.vfr_fraction == 0.0
    assert not scenario.addressed


@pytest.mark.parametrize(
    ("where", "key", "value", "words"),
    [
        ("radar", "identity", "mode_c", 'must be one of "mode_s", "mode_ac", "psr"'),
        ("radar", "identity", 3, "must be a string"),
        ("radar", "track_numbers", "yes", "must be true or false"),
        ("radar", "clutter_per_scan", -1.0, "within [0, 100000]"),
        ("mode_3a", "vfr_fraction", 1.5, "within [0, 1]"),
        ("mode_3a", "code_changes", -0.1, "within [0, 1]"),
        ("mode_3a", "vfr_code", "7080", "4 octal digits"),
        ("mode_3a", "vfr_code", "700", "4 octal digits"),
        ("mode_3a", "squawk", 1, "unknown field"),
    ],
)
def test_bad_identity_keys_name_the_file_and_the_field(tmp_path, where, key, value, words):
    doc = _document([_radar("R", 48.7, 2.1)], mode_3a={})
    table = doc["radar"][0] if where == "radar" else doc["mode_3a"]
    table[key] = value
    path = tmp_path / "bad.toml"
    with pytest.raises(ScenarioError) as info:
        parse_scenario(doc, path)
    field = f"radar[0].{key}" if where == "radar" else f"mode_3a.{key}"
    assert info.value.field == field and info.value.path == path
    assert str(path) in str(info.value) and field in str(info.value) and words in str(info.value)


def test_clutter_needs_a_finite_range(tmp_path):
    radar = _radar("R", 48.7, 2.1, clutter_per_scan=2.0)
    del radar["max_range_m"]
    with pytest.raises(ScenarioError) as info:
        parse_scenario(_document([radar]), tmp_path / "c.toml")
    assert info.value.field == "radar[0].clutter_per_scan"
    assert "finite max_range_m" in str(info.value)


# --------------------------------------------------------------------------- identity


def test_identity_sets_the_columns_of_each_radar(mixed):
    plots, truth = mixed.dataset.plots, mixed.plot_truth
    assert list(plots.columns) == [*PLOT_COLUMNS, "altitude_m", "mode_3a"]
    assert (truth["truth_target_id"] != CLUTTER).all()
    codes = mixed.mode_3a.at(truth["truth_target_id"], truth["time_true_s"])
    by = plots["radar_id"].to_numpy()

    s = by == "S"
    assert (plots["target_id"][s] == truth["truth_target_id"][s]).all()
    assert (plots["mode_3a"][s] == codes[s]).all()
    assert np.isfinite(plots["altitude_m"][s]).all() and plots["elevation_deg"][s].isna().all()

    ac = by == "AC"
    assert (plots["target_id"][ac] == "").all()
    assert (plots["mode_3a"][ac] == codes[ac]).all()
    assert plots["mode_3a"][ac].str.match(OCTAL_CODE).all()
    assert np.isfinite(plots["altitude_m"][ac]).all()

    p3 = by == "P3"
    assert (plots["target_id"][p3] == "").all() and (plots["mode_3a"][p3] == "").all()
    assert plots["altitude_m"][p3].isna().all()
    assert np.isfinite(plots["elevation_deg"][p3]).all()  # a 3-D primary radar
    assert min(s.sum(), ac.sum(), p3.sum()) > 100


def test_identity_changes_no_draw(mixed):
    """As Mode S radars, the same plots with addresses: the identity only hides columns."""
    doc = _document(_three_radars(AC={"identity": "mode_s"}, P3={"identity": "mode_s"}),
                    **{"mode_3a": {"vfr_fraction": 0.25, "code_changes": 0.5}})
    plain = simulate(parse_scenario(doc), np.random.default_rng(31))
    numbers = ["time_s", "range_m", "azimuth_deg", "elevation_deg"]
    pd.testing.assert_frame_equal(plain.dataset.plots[numbers], mixed.dataset.plots[numbers])
    pd.testing.assert_frame_equal(plain.plot_truth, mixed.plot_truth)
    assert (plain.dataset.plots["target_id"] == mixed.plot_truth["truth_target_id"]).all()
    secondary = mixed.dataset.plots["radar_id"] != "P3"
    pd.testing.assert_series_equal(plain.dataset.plots["altitude_m"][secondary],
                                   mixed.dataset.plots["altitude_m"][secondary])
    pd.testing.assert_frame_equal(plain.dataset.adsb, mixed.dataset.adsb)


def test_without_codes_or_track_numbers_the_columns_are_version_2():
    doc = _document([_radar("P", 48.7, 2.1, identity="psr")])
    result = simulate(parse_scenario(doc), np.random.default_rng(32))
    assert list(result.dataset.plots.columns) == [*PLOT_COLUMNS, "altitude_m"]
    assert "mode_3a" not in result.dataset.adsb
    assert (result.dataset.plots["target_id"] == "").all()


def test_adsb_carries_the_code_at_its_time(mixed):
    adsb = mixed.dataset.adsb
    expected = mixed.mode_3a.at(adsb["target_id"], adsb["time_s"])
    assert (adsb["mode_3a"].to_numpy(dtype=object) == expected).all()
    assert adsb["mode_3a"].str.match(OCTAL_CODE).all()


# --------------------------------------------------------------------------- codes


def _codes_run(seed: int, n_aircraft: int = 200, **mode_3a):
    doc = _document([_radar("AC", 48.7, 2.1, identity="mode_ac", scan_period_s=8.0)],
                    n_aircraft=n_aircraft, duration_s=300.0, mode_3a=mode_3a)
    return simulate(parse_scenario(doc), np.random.default_rng(seed))


def test_vfr_share_and_distinct_discrete_codes():
    result = _codes_run(41, vfr_fraction=0.1, vfr_code="1200")
    codes = result.mode_3a
    assert codes.target_ids == tuple(f.target_id for f in result.trajectories)
    assert codes.vfr.sum() == 20  # round(0.1 x 200)
    assert (codes.first_code[codes.vfr] == 0o1200).all()
    discrete = codes.first_code[~codes.vfr]
    assert len(set(discrete)) == discrete.size  # distinct while the codes last
    assert not set(discrete) & {*SPECIAL_CODES, 0o1200}
    assert np.isnan(codes.change_time_s).all()
    # The plots carry them: 20 aircraft squawk 1200 on the radar and in ADS-B.
    truth, plots = result.plot_truth, result.dataset.plots
    vfr_ids = {t for t, v in zip(codes.target_ids, codes.vfr, strict=True) if v}
    on_vfr = truth["truth_target_id"].isin(vfr_ids)
    assert (plots["mode_3a"][on_vfr] == "1200").all()
    assert (plots["mode_3a"][~on_vfr] != "1200").all()
    assert set(result.dataset.adsb.loc[result.dataset.adsb["mode_3a"] == "1200", "target_id"]) \
        == vfr_ids & set(result.dataset.adsb["target_id"])


def test_code_changes_once_in_flight():
    result = _codes_run(42, code_changes=0.05)
    codes = result.mode_3a
    changes = np.isfinite(codes.change_time_s)
    assert changes.sum() == 10  # round(0.05 x 200)
    flights = {f.target_id: f for f in result.trajectories}
    plots, truth = result.dataset.plots, result.plot_truth
    seen_both = 0
    for i in np.flatnonzero(changes):
        target, when = codes.target_ids[i], codes.change_time_s[i]
        flight = flights[target]
        assert max(flight.start_s, 0.0) <= when <= min(flight.end_s, 300.0)
        mine = (truth["truth_target_id"] == target).to_numpy()
        before = mine & (truth["time_true_s"] < when).to_numpy()
        after = mine & (truth["time_true_s"] >= when).to_numpy()
        first, second = f"{codes.first_code[i]:04o}", f"{codes.second_code[i]:04o}"
        assert first != second
        assert (plots["mode_3a"][before] == first).all()
        assert (plots["mode_3a"][after] == second).all()
        seen_both += bool(before.any() and after.any())
    assert seen_both >= 5
    # The others keep one code all along.
    steady = set(np.array(codes.target_ids)[~changes])
    per_aircraft = plots.assign(truth=truth["truth_target_id"]).groupby("truth")["mode_3a"]
    assert (per_aircraft.nunique()[list(steady & set(truth["truth_target_id"]))] == 1).all()


def test_codes_come_from_the_seed():
    first, second = _codes_run(43, 50, vfr_fraction=0.2), _codes_run(43, 50, vfr_fraction=0.2)
    np.testing.assert_array_equal(first.mode_3a.first_code, second.mode_3a.first_code)
    other = _codes_run(44, 50, vfr_fraction=0.2)
    assert not np.array_equal(first.mode_3a.first_code, other.mode_3a.first_code)


# --------------------------------------------------------------------------- track numbers


def _assert_track_rule(plots: pd.DataFrame, truth: pd.DataFrame, radar_id: str,
                       scan_period_s: float) -> int:
    """Each aircraft's number changes exactly after a gap of more than the coast; returns
    the number of tracks."""
    mine = (plots["radar_id"] == radar_id).to_numpy()
    frame = pd.DataFrame({"target": truth["truth_target_id"][mine].to_numpy(),
                          "time": truth["time_true_s"][mine].to_numpy(),
                          "number": plots["track_number"][mine].to_numpy(dtype=np.int64)})
    limit = (TRACK_COAST_SCANS + 1.5) * scan_period_s
    n_tracks = 0
    for _, track in frame.sort_values("time").groupby("target"):
        gap = np.diff(track["time"].to_numpy())
        changed = np.diff(track["number"].to_numpy()) != 0
        np.testing.assert_array_equal(changed, gap > limit)
        n_tracks += 1 + int(changed.sum())
    # A number is never given to two tracks (fewer than 4096 tracks here).
    assert frame.groupby("number")["target"].nunique().max() == 1
    starts = frame.sort_values("time").drop_duplicates("number")
    assert sorted(starts["number"]) == list(range(n_tracks))
    assert (np.diff(starts["number"].to_numpy()) == 1).all()  # in the order of their start
    return n_tracks


@pytest.mark.parametrize("chunk_s", [None, 170.0])
def test_track_numbers_last_while_seen_and_change_after_a_gap(chunk_s):
    radars = [_radar("T", 48.7, 2.1, track_numbers=True, detection_probability=0.5),
              _radar("U", 49.1, 2.7)]
    doc = _document(radars, n_aircraft=6)
    result = simulate(parse_scenario(doc), np.random.default_rng(51), chunk_s=chunk_s)
    plots, truth = result.dataset.plots, result.plot_truth
    assert plots["track_number"].dtype == "Int64"
    assert plots["track_number"][plots["radar_id"] == "U"].isna().all()
    n_tracks = _assert_track_rule(plots, truth, "T", 4.0)
    assert n_tracks > 2 * 8  # Pd 0.5: gaps of 4 scans or more are common


def test_track_numbers_are_constant_without_gaps():
    doc = _document([_radar("T", 48.7, 2.1, track_numbers=True)], n_aircraft=5)
    doc["traffic"]["start_time_s"] = [0.0, 0.0]
    result = simulate(parse_scenario(doc), np.random.default_rng(52))
    plots, truth = result.dataset.plots, result.plot_truth
    per_aircraft = plots.groupby(truth["truth_target_id"])["track_number"]
    assert (per_aircraft.nunique() == 1).all()
    assert sorted(per_aircraft.first()) == list(range(per_aircraft.ngroups))
    _assert_track_rule(plots, truth, "T", 4.0)


def test_track_numbers_wrap_at_4096():
    numbers = TrackNumbers(scan_period_s=4.0)
    numbers.next_number = 4094
    first = numbers.number(["a", "b", "c"], [0.0, 1.0, 2.0])
    assert list(first) == [4094, 4095, 0]
    # a continues, c comes back after more than the coast, d is new.
    again = numbers.number(["a", "c", "d"], [4.0, 2.0 + 4.0 * 4.6, 30.0])
    assert list(again) == [4094, 1, 2]


# --------------------------------------------------------------------------- clutter


def test_clutter_count_per_scan_is_poisson():
    """1000 scans at 8 false plots per scan.  Tolerances: the total within 4.5 sigma of
    8000 (sigma = sqrt(8000) = 89); the per-scan counts' dispersion index within the
    chi-square bounds at p = 1e-5 each side; positions uniform (KS test, p > 1e-5)."""
    radar = _radar("C", 48.7, 2.1, three_d=True, clutter_per_scan=8.0, min_elevation_deg=0.5)
    doc = _document([radar], n_aircraft=1, duration_s=4000.0)
    result = simulate(parse_scenario(doc), np.random.default_rng(61))
    plots, truth = result.dataset.plots, result.plot_truth
    false = (truth["truth_target_id"] == CLUTTER).to_numpy()
    n_scans, rate = 1000, 8.0
    assert result.n_clutter == {"C": false.sum()}
    assert abs(false.sum() - rate * n_scans) < 4.5 * math.sqrt(rate * n_scans)
    scan = np.floor(truth["time_true_s"][false].to_numpy() / 4.0).astype(int)
    counts = np.bincount(scan, minlength=n_scans)[:n_scans]
    assert abs(counts.mean() - rate) < 4.5 * math.sqrt(rate / n_scans)
    dispersion = (n_scans - 1) * counts.var(ddof=1) / counts.mean()
    assert stats.chi2.ppf(1e-5, n_scans - 1) < dispersion < stats.chi2.ppf(1 - 1e-5, n_scans - 1)
    clutter = plots[false]
    assert stats.kstest(clutter["range_m"], stats.uniform(0.0, 300_000.0).cdf).pvalue > 1e-5
    assert stats.kstest(clutter["azimuth_deg"], stats.uniform(0.0, 360.0).cdf).pvalue > 1e-5
    span = CLUTTER_MAX_ELEVATION_DEG - 0.5
    assert stats.kstest(clutter["elevation_deg"], stats.uniform(0.5, span).cdf).pvalue > 1e-5
    assert (clutter["target_id"] == "").all() and clutter["altitude_m"].isna().all()
    assert truth[false].drop(columns=["time_true_s", "truth_target_id"]).isna().all().all()
    assert np.all(np.diff(plots["time_s"].to_numpy()) >= 0)


def test_clutter_follows_the_beam_and_the_clock():
    radar = parse_scenario(_document([_radar(
        "C", 48.7, 2.1, clutter_per_scan=5.0, bias={"time_offset_s": 0.5})])).radars[0]
    plots, truth = clutter_plots(radar, 1.0, TimeSpan(100.0, 500.0, False),
                                 np.random.default_rng(62))
    t = truth["time_true_s"].to_numpy()
    assert ((t >= 100.0) & (t < 500.0)).all()
    np.testing.assert_allclose(plots["time_s"], t + 0.5)
    beam = np.degrees(np.mod(1.0 + 2.0 * np.pi / 4.0 * t, 2.0 * np.pi))
    np.testing.assert_allclose(plots["azimuth_deg"], beam, atol=1e-9)
    assert plots["elevation_deg"].isna().all()  # 2-D
    assert (plots["mode_3a"] == "").all() and plots["track_number"].isna().all()
    assert plots["track_number"].dtype == "Int64"


def test_clutter_comes_after_every_other_draw():
    """Clutter and track numbers on a radar leave the aircraft plots and ADS-B as they were."""
    base = _document(_three_radars(), **{"mode_3a": {}})
    noisy = _document(_three_radars(S={"clutter_per_scan": 3.0, "track_numbers": True}),
                      **{"mode_3a": {}})
    plain = simulate(parse_scenario(base), np.random.default_rng(63))
    more = simulate(parse_scenario(noisy), np.random.default_rng(63))
    real = (more.plot_truth["truth_target_id"] != CLUTTER).to_numpy()
    assert (~real).sum() == more.n_clutter["S"] > 0
    pd.testing.assert_frame_equal(more.dataset.plots[real].drop(columns="track_number")
                                  .reset_index(drop=True), plain.dataset.plots)
    pd.testing.assert_frame_equal(more.dataset.adsb, plain.dataset.adsb)


# --------------------------------------------------------------------------- truth


def test_truth_json_scores_every_plot_and_the_table_does_not_carry_it(tmp_path):
    radars = _three_radars(P3={"clutter_per_scan": 2.0, "track_numbers": True})
    result = simulate(parse_scenario(_document(radars)), np.random.default_rng(71))
    folder = write_simulation(result, tmp_path / "out")
    header = (folder / "plots.csv").read_text().splitlines()[0].split(",")
    assert header == [*PLOT_COLUMNS, "altitude_m", "mode_3a", "track_number"]
    document = json.loads((folder / "truth.json").read_text())
    assert document == truth_document(result)
    block = document["plot_truth"]
    assert block["truth_target_id"] == result.plot_truth["truth_target_id"].tolist()
    assert len(block["truth_target_id"]) == len(result.dataset.plots)
    assert block["radars"]["P3"] == {"identity": "psr", "track_numbers": True,
                                     "detection_probability": 1.0, "clutter_per_scan": 2.0,
                                     "n_clutter": result.n_clutter["P3"]}
    assert result.n_clutter["P3"] == block["truth_target_id"].count(CLUTTER) > 0
    addressed = result.dataset.plots["target_id"] != ""
    assert (result.dataset.plots["target_id"][addressed]
            == result.plot_truth["truth_target_id"][addressed]).all()


def test_streamed_folder_has_the_same_truth(tmp_path):
    radars = _three_radars(P3={"clutter_per_scan": 2.0, "track_numbers": True})
    scenario = parse_scenario(_document(radars, **{"mode_3a": {"code_changes": 0.5}}))
    whole = simulate(scenario, np.random.default_rng(72), chunk_s=200.0)
    write_simulation(whole, tmp_path / "whole")
    streamed = simulate_to_folder(scenario, np.random.default_rng(72), tmp_path / "streamed",
                                  fmt="csv", chunk_s=200.0)
    for name in ("plots.csv", "adsb.csv", "truth.json"):
        assert (tmp_path / "whole" / name).read_bytes() == \
            (tmp_path / "streamed" / name).read_bytes(), name
    assert streamed.n_clutter == whole.n_clutter


# --------------------------------------------------------------------------- defaults


def _frame_digest(frame: pd.DataFrame) -> str:
    """SHA-256 of a frame's columns, types, index and values (exact bits)."""
    digest = hashlib.sha256()
    digest.update(repr(list(frame.columns)).encode())
    digest.update(repr([str(t) for t in frame.dtypes]).encode())
    digest.update(pd.util.hash_pandas_object(frame, index=True).to_numpy().tobytes())
    return digest.hexdigest()


#: demo_network with seed 1, simulated before contract v3 existed: the plots, the ADS-B,
#: truth.json (sorted keys), and the generator's next number after the simulation; in one
#: piece and in chunks of 600 s.
DEMO_SEED_1 = {
    None: ("a02b9bc7921af8b59e996c824d18a61e89f3672b7d9280e3e8bd128a41572e85",
           "0f2ed07a595d2d739b52eafe70a31103d6492892f8a1acc9a8daa5689907fcef",
           "515c7d4fd64ee93ce3b63bc5d1bed9847ed00ac12ae0d3cd73bae43a103efa63",
           0.8633737217490103),
    600.0: ("493d29ec43b9e8a3012503206f008ef009630bb34d779ed5e94ef1bff30145c4",
            "206e9cf3fac853267fb6896484c30e2226488023111da22b419ed718b4087279",
            "4b1dcd76de8ec7724386d142e71278df390d76a7af895a8661ca968b49cd39e5",
            0.4120311056595689),
}


@pytest.mark.parametrize("chunk_s", [None, 600.0])
def test_defaults_reproduce_the_version_2_simulation(chunk_s):
    scenario = load_scenario(SCENARIOS / "demo_network.toml")
    rng = np.random.default_rng(1)
    result = simulate(scenario, rng, chunk_s=chunk_s)
    plots_sha, adsb_sha, truth_sha, next_draw = DEMO_SEED_1[chunk_s]
    assert _frame_digest(result.dataset.plots) == plots_sha
    assert _frame_digest(result.dataset.adsb) == adsb_sha
    document = truth_document(result)
    assert "plot_truth" not in document
    assert hashlib.sha256(json.dumps(document, sort_keys=True).encode()).hexdigest() == truth_sha
    assert rng.random() == next_draw  # not one draw more or less
    assert result.mode_3a is None and set(result.n_clutter.values()) == {0}
    assert (result.plot_truth["truth_target_id"] == result.dataset.plots["target_id"]).all()


def test_explicit_defaults_change_nothing():
    scenario = load_scenario(SCENARIOS / "paper003_adsb_2d.toml")
    explicit = scenario.with_radars(identity="mode_s", track_numbers=False,
                                    clutter_per_scan=0.0)
    a = simulate(scenario, np.random.default_rng(2))
    b = simulate(explicit, np.random.default_rng(2))
    pd.testing.assert_frame_equal(a.dataset.plots, b.dataset.plots, check_exact=True)
    pd.testing.assert_frame_equal(a.dataset.adsb, b.dataset.adsb, check_exact=True)


# --------------------------------------------------------------------------- demo_identity


def test_demo_identity_is_demo_network_seen_by_contract_v3():
    scenario = load_scenario(SCENARIOS / "demo_identity.toml")
    result = simulate(scenario, np.random.default_rng(1))
    plots, truth = result.dataset.plots, result.plot_truth
    identity = {r.id: r.identity for r in scenario.radars}
    assert identity == {"NORD": "mode_s", "SUD": "mode_ac", "EST3D": "psr",
                        "OUEST3D": "psr", "APP": "mode_s"}
    named = plots.groupby("radar_id")["target_id"].apply(lambda s: (s != "").mean())
    assert named.to_dict() == {"APP": 1.0, "EST3D": 0.0, "NORD": 1.0, "OUEST3D": 0.0, "SUD": 0.0}
    est = (plots["radar_id"] == "EST3D").to_numpy()
    real = (truth["truth_target_id"] != CLUTTER).to_numpy()
    assert plots["track_number"][est & real].notna().all()
    assert plots["track_number"][~est | ~real].isna().all()
    expected = 8.0 * 1800.0 / 10.0
    assert abs(result.n_clutter["EST3D"] - expected) < 4.5 * math.sqrt(expected)
    assert result.dataset.adsb["target_id"].nunique() == 32  # 0.8 x 40
    assert result.mode_3a.vfr.sum() == 4 and np.isfinite(result.mode_3a.change_time_s).sum() == 2
    # The aircraft plots are demo_network's, the same seed.
    demo = simulate(load_scenario(SCENARIOS / "demo_network.toml"), np.random.default_rng(1))
    numbers = ["radar_id", "time_s", "range_m", "azimuth_deg", "elevation_deg"]
    pd.testing.assert_frame_equal(plots[real][numbers].reset_index(drop=True),
                                  demo.dataset.plots[numbers])
    assert (truth["truth_target_id"][real].to_numpy() == demo.dataset.plots["target_id"]).all()

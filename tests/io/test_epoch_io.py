"""``[dataset] epoch_utc`` (contract v1.6) in dataset folders, scenarios and imports: read,
refused when not a UTC time (naming sites.toml and the key), written by the writers that
know it, absent from simulations unless the scenario gives it."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.core.errors import DatasetError, ScenarioError
from graphcal.data.bias import RadarBias
from graphcal.data.correct import correct_dataset
from graphcal.io.folder import (
    load_dataset,
    load_epoch_utc,
    load_plot_altitude,
    load_sites,
    write_dataset,
    write_sites,
)
from graphcal.io.window_reader import iter_windows
from graphcal.simulation.scenario import load_scenario, parse_scenario
from tests.io.test_asterix_read import (
    CAT034,
    CAT048,
    MIDNIGHT,
    block,
    capture,
    plot_record,
    site_record,
)
from tests.io.test_dataset import SITES, make_dataset
from tests.paths import SCENARIOS

runner = CliRunner()
EPOCH = datetime(2021, 10, 7, 6, 30, tzinfo=UTC)
EPOCH_SITES = '[dataset]\nepoch_utc = "2021-10-07T06:30:00Z"\n\n' + SITES


def test_the_epoch_is_read_and_absent_means_none(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "ds", sites=EPOCH_SITES))
    assert dataset.epoch_utc == EPOCH and dataset.plot_altitude == "geometric"
    assert load_dataset(make_dataset(tmp_path / "v1")).epoch_utc is None
    both = '[dataset]\nplot_altitude = "pressure"\nepoch_utc = 2021-10-07T06:30:00Z\n\n' + SITES
    dataset = load_dataset(make_dataset(tmp_path / "both", sites=both))  # a TOML date-time
    assert dataset.epoch_utc == EPOCH and dataset.plot_altitude == "pressure"


@pytest.mark.parametrize(("value", "words"), [
    ('"2021-10-07T06:30:00"', "has no UTC designator"),
    ('"2021-10-07T08:30:00+02:00"', "is not in UTC"),
    ('"2021-10-07"', "is a date without a time"),
    ("2021-10-07", "is a date without a time"),
    ('"07/10/2021 06:30"', "is not an ISO 8601 date and time"),
])
def test_a_bad_epoch_names_the_file_and_the_key(tmp_path: Path, value: str, words: str) -> None:
    folder = make_dataset(tmp_path / "ds", sites=f"[dataset]\nepoch_utc = {value}\n\n{SITES}")
    with pytest.raises(DatasetError) as info:
        load_dataset(folder)
    assert info.value.field == "dataset.epoch_utc"
    assert str(folder / "sites.toml") in str(info.value) and words in str(info.value)
    with pytest.raises(DatasetError):  # read window by window: checked too
        next(iter(iter_windows(folder, 600.0)))
    with pytest.raises(DatasetError):
        load_plot_altitude(folder / "sites.toml")
    result = runner.invoke(app, ["calibrate", str(folder)])
    assert result.exit_code == 2 and result.output.count("\n") == 1
    assert "epoch_utc" in result.output and "sites.toml" in result.output


def test_writers_keep_the_epoch(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "ds", sites=EPOCH_SITES))
    out = write_dataset(dataset, tmp_path / "out")
    assert 'epoch_utc = "2021-10-07T06:30:00Z"' in (out / "sites.toml").read_text()
    assert load_dataset(out).epoch_utc == EPOCH
    sites = load_sites(out / "sites.toml")
    write_sites(sites, tmp_path / "s.toml", plot_altitude="pressure", epoch_utc=EPOCH)
    assert load_epoch_utc(tmp_path / "s.toml") == EPOCH
    assert load_plot_altitude(tmp_path / "s.toml") == "pressure"
    write_sites(sites, tmp_path / "v1.toml")
    assert "[dataset]" not in (tmp_path / "v1.toml").read_text()  # version 1 unchanged
    with pytest.raises(ValueError, match="UTC designator"):
        write_sites(sites, tmp_path / "bad.toml", epoch_utc=datetime(2021, 10, 7))
    # corrected plots: the same time base
    assert correct_dataset(dataset, {"A": RadarBias(range_offset_m=10.0)}).epoch_utc == EPOCH


def test_noise_write_sites_keeps_the_dataset_table(tmp_path: Path) -> None:
    from graphcal.simulation.simulate import simulate

    doc = _demo_document()
    doc["dataset"] = {"plot_altitude": "pressure", "epoch_utc": "2021-10-07T00:00:00Z"}
    sim = simulate(parse_scenario(doc), np.random.default_rng(1))
    folder = write_dataset(sim.dataset, tmp_path / "ds")
    out = tmp_path / "sites.toml"
    result = runner.invoke(app, ["noise", str(folder), "--write-sites", str(out)])
    assert result.exit_code == 0, result.output
    assert load_plot_altitude(out) == "pressure"
    assert load_epoch_utc(out) == datetime(2021, 10, 7, tzinfo=UTC)


# --------------------------------------------------------------------------- simulation
def _demo_document() -> dict:
    import tomllib

    with open(SCENARIOS / "demo_network.toml", "rb") as f:
        doc = tomllib.load(f)
    doc["scenario"]["duration_s"] = 120.0
    return doc


def test_simulations_have_no_epoch_unless_the_scenario_gives_one(tmp_path: Path) -> None:
    assert load_scenario(SCENARIOS / "demo_network.toml").epoch_utc is None
    result = runner.invoke(app, ["simulate", str(SCENARIOS / "demo_network.toml"), "--out",
                                 str(tmp_path / "demo"), "--seed", "1"])
    assert result.exit_code == 0, result.output
    assert "epoch_utc" not in (tmp_path / "demo" / "sites.toml").read_text()
    doc = _demo_document()
    doc["dataset"] = {"epoch_utc": "2021-10-07T06:30:00Z"}
    assert parse_scenario(doc).epoch_utc == EPOCH
    from graphcal.simulation.stream import simulate_to_folder

    simulate_to_folder(parse_scenario(doc), np.random.default_rng(1), tmp_path / "streamed")
    assert load_epoch_utc(tmp_path / "streamed" / "sites.toml") == EPOCH
    doc["dataset"] = {"epoch_utc": "2021-10-07T06:30:00"}
    with pytest.raises(ScenarioError, match="dataset.epoch_utc.*no UTC designator"):
        parse_scenario(doc)


def test_an_opensky_replay_starts_at_its_epoch() -> None:
    doc = _demo_document()
    doc.pop("traffic", None)
    doc["opensky"] = {"file": "states.csv", "start": "2022-06-01T12:00:00"}
    assert parse_scenario(doc).epoch_utc == datetime(2022, 6, 1, 12, tzinfo=UTC)
    doc["dataset"] = {"epoch_utc": "2022-06-01T00:00:00Z"}  # the scenario's own wins
    assert parse_scenario(doc).epoch_utc == datetime(2022, 6, 1, tzinfo=UTC)


# --------------------------------------------------------------------------- import-asterix
def _recording() -> bytes:
    """Radar SAC 25 SIC 2 (its CAT034 position), three plots at 100-102 s of the day."""
    return (block(CAT048, [plot_record(100.0 + i, sic=2) for i in range(3)])
            + block(CAT034, [site_record(sic=2, lat=47.5, lon=8.25, height=500.0)]))


def test_import_asterix_date_is_the_recordings_midnight(tmp_path: Path) -> None:
    raw = tmp_path / "rec.ast"
    raw.write_bytes(_recording())
    unknown = runner.invoke(app, ["import-asterix", str(raw), "--out", str(tmp_path / "a")])
    assert unknown.exit_code == 0, unknown.output
    assert load_epoch_utc(tmp_path / "a" / "sites.toml") is None
    assert "date unknown: give it with --date" in " ".join(unknown.output.split())
    dated = runner.invoke(app, ["import-asterix", str(raw), "--out", str(tmp_path / "b"),
                                "--date", "2021-10-07"])
    assert dated.exit_code == 0, dated.output
    assert "00:00 UTC of 2021-10-07" in dated.output
    back = load_dataset(tmp_path / "b")
    assert back.epoch_utc == datetime(2021, 10, 7, tzinfo=UTC)
    assert back.plots["time_s"].tolist() == pytest.approx([100.0, 101.0, 102.0], abs=0.01)
    bad = runner.invoke(app, ["import-asterix", str(raw), "--out", str(tmp_path / "c"),
                              "--date", "07/10/2021"])
    assert bad.exit_code == 2 and bad.output.startswith("error: --date 07/10/2021: not a date")
    assert not (tmp_path / "c").exists()


def test_import_asterix_writes_the_capture_day_and_checks_date(tmp_path: Path) -> None:
    pcap = tmp_path / "rec.pcap"
    pcap.write_bytes(capture([(MIDNIGHT + 101.0, _recording())]))
    result = runner.invoke(app, ["import-asterix", str(pcap), "--out", str(tmp_path / "a")])
    assert result.exit_code == 0, result.output
    assert (load_epoch_utc(tmp_path / "a" / "sites.toml")
            == datetime.fromtimestamp(MIDNIGHT, UTC))
    same = runner.invoke(app, ["import-asterix", str(pcap), "--out", str(tmp_path / "b"),
                               "--date", "2021-10-07"])
    assert same.exit_code == 0, same.output
    other = runner.invoke(app, ["import-asterix", str(pcap), "--out", str(tmp_path / "c"),
                                "--date", "2021-10-08"])
    assert other.exit_code == 2
    assert other.output.startswith("error: --date 2021-10-08: the recording's capture times "
                                   "begin on 2021-10-07 UTC")
    assert not (tmp_path / "c").exists()

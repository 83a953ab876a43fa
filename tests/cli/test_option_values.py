"""Numeric options of every command other than calibrate (tests/cli/test_options.py): a
negative, zero, NaN or infinite value where it makes no sense is refused with one line
``error: --OPTION must be a positive ..., not X`` and exit status 2, before any data is
read (the dataset folders here do not exist)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.cli.common import check_count, check_positive
from tests.paths import SCENARIOS

runner = CliRunner()
SCENARIO = SCENARIOS / "paper003_adsb_2d.toml"


def _refused(argv: list[str], *expected: str) -> str:
    result = runner.invoke(app, argv)
    assert result.exit_code == 2, result.output
    assert result.output.startswith("error: ") and result.output.count("\n") == 1, \
        result.output
    assert "Traceback" not in result.output
    for text in expected:
        assert text in result.output, result.output
    return result.output


@pytest.mark.parametrize("value", ["-1", "0"])
def test_observability_random_draws(tmp_path: Path, value: str) -> None:
    _refused(["observability", str(tmp_path / "none"), "--budget", "100", "--random-draws",
              value], f"--random-draws must be a positive number of draws, not {value}")


@pytest.mark.parametrize("value", ["-5", "0"])
def test_observability_budget(tmp_path: Path, value: str) -> None:
    _refused(["observability", str(tmp_path / "none"), "--budget", value],
             f"--budget must be a positive number of observations, not {value}")


@pytest.mark.parametrize("value", ["-60", "0", "nan", "inf"])
def test_observability_segment_s(tmp_path: Path, value: str) -> None:
    _refused(["observability", str(tmp_path / "none"), "--budget", "100", "--segment-s",
              value], "--segment-s must be a positive number of seconds, not ")


def test_observability_seed(tmp_path: Path) -> None:
    _refused(["observability", str(tmp_path / "none"), "--budget", "100", "--seed", "-1"],
             "--seed -1: the seed must be a non-negative integer")


@pytest.mark.parametrize("value", ["-1", "0", "nan", "inf"])
def test_fuse_grid_s(tmp_path: Path, value: str) -> None:
    text = _refused(["fuse", str(tmp_path / "none"), "--grid-s", value],
                    "--grid-s must be a positive number of seconds, not ")
    assert text.strip().endswith(str(float(value)))


@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_fuse_q(tmp_path: Path, value: str) -> None:
    _refused(["fuse", str(tmp_path / "none"), "--q-m2-s3", value],
             "--q-m2-s3 must be a finite number >= 0 [m^2/s^3], not ")


@pytest.mark.parametrize("value", ["-50", "0", "nan", "inf"])
def test_noise_range_bin_km(tmp_path: Path, value: str) -> None:
    _refused(["noise", str(tmp_path / "none"), "--range-bin-km", value],
             "--range-bin-km must be a positive number of kilometres, not ")


@pytest.mark.parametrize("value", ["-45", "0", "nan", "inf", "400"])
def test_noise_azimuth_bin_deg(tmp_path: Path, value: str) -> None:
    _refused(["noise", str(tmp_path / "none"), "--azimuth-bin-deg", value],
             "--azimuth-bin-deg must be a positive number of degrees up to 360, not ")


@pytest.mark.parametrize("value", ["-5", "0", "nan", "inf"])
def test_history_tolerance(tmp_path: Path, value: str) -> None:
    _refused(["history", str(tmp_path / "none.db"), "--tolerance", f"range_offset_m={value}"],
             f"--tolerance range_offset_m={value}: expected KEY=VALUE with a positive number",
             f"not {value}")


@pytest.mark.parametrize("value", ["-1", "0"])
def test_compare_runs(tmp_path: Path, value: str) -> None:
    _refused(["compare", str(SCENARIO), "--runs", value],
             f"--runs must be a positive number of runs, not {value}")


@pytest.mark.parametrize("value", ["-1", "0"])
def test_compare_jobs(tmp_path: Path, value: str) -> None:
    _refused(["compare", str(SCENARIO), "--jobs", value],
             f"--jobs must be a positive number of processes, not {value}")


def test_compare_seed() -> None:
    _refused(["compare", str(SCENARIO), "--seed", "-3"],
             "--seed -3: the seed must be a non-negative integer")


@pytest.mark.parametrize(("value", "why"), [
    ("0", "a duration must be positive"),
    ("-1h", "--chunk must be a positive duration (e.g. 1h), not -1h"),
    ("nan", "not a duration"), ("inf", "not a duration"),
    ("1e400s", "a duration must be positive"),
    ("0.001s", "--chunk must be a duration of at least 1 s, not 0.001s"),
])
def test_simulate_chunk(tmp_path: Path, value: str, why: str) -> None:
    _refused(["simulate", str(SCENARIO), "--out", str(tmp_path / "out"), f"--chunk={value}"],
             "--chunk", why)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("value", ["-0.1", "1", "nan", "inf"])
def test_marginals_min_rho(tmp_path: Path, value: str) -> None:
    _refused(["marginals", str(tmp_path / "r.json"), "--correlation", "--min-rho", value],
             "--min-rho must be in [0, 1), not ")


def test_helpers_pass_good_values() -> None:
    check_positive(None, "--x")
    check_positive(0.5, "--x")
    check_count(None, "--n")
    check_count(1, "--n")

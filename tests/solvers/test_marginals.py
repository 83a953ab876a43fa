"""Marginal covariance queries, Calibration.from_dict and ``graphcal marginals``.

The reference values are built by hand here: a known SI covariance over known
labels, converted to contract units with the unit factors written out
(m and fraction: 1, rad -> mrad: 1e3, s: 1), independent of graphcal.data.bias.
"""

from __future__ import annotations

import copy
import json
import pickle
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.core.errors import GraphcalInputError, ResultError
from graphcal.data.bias import RadarBias
from graphcal.data.calibration import Calibration, JointCovariance, Observability, ResidualStats
from graphcal.solvers.registry import calibrate
from tests.synthetic import Track, make_dataset, site_at

runner = CliRunner()

#: (radar, internal name, contract key, SI -> contract factor, SI value, SI sigma)
PARAMS = [
    ("LAEG", "range_offset", "range_offset_m", 1.0, -93.7, 0.9),
    ("LAEG", "range_gain", "range_gain", 1.0, 6.94e-4, 7.5e-6),
    ("LAEG", "azimuth_bias", "azimuth_bias_mrad", 1e3, -3.10e-3, 2e-5),
    ("DOLE", "range_offset", "range_offset_m", 1.0, 41.2, 1.7),
    ("DOLE", "azimuth_bias", "azimuth_bias_mrad", 1e3, 1.25e-3, 3e-5),
    ("DOLE", "elevation_bias", "elevation_bias_mrad", 1e3, -0.8e-3, 6e-5),
    ("DOLE", "time_offset", "time_offset_s", 1.0, 0.35, 0.02),
    ("HOLB", "azimuth_bias", "azimuth_bias_mrad", 1e3, 0.4e-3, 4e-5),
]
LAEG, DOLE, HOLB = [0, 1, 2], [3, 4, 5, 6], [7]
#: Correlations set by hand: offset/gain of LAEG, and LAEG/DOLE range offsets.
RHO = {(0, 1): -0.7, (0, 3): 0.6, (2, 4): 0.3, (5, 6): -0.2, (4, 7): 0.1}


def _correlation() -> np.ndarray:
    r = np.eye(len(PARAMS))
    for (i, j), v in RHO.items():
        r[i, j] = r[j, i] = v
    assert np.all(np.linalg.eigvalsh(r) > 0)
    return r


def _si_covariance() -> np.ndarray:
    sd = np.array([p[5] for p in PARAMS])
    return _correlation() * np.outer(sd, sd)


def _factors(idx: list[int]) -> np.ndarray:
    return np.array([PARAMS[i][3] for i in idx])


def _expected_block(rows: list[int], cols: list[int]) -> np.ndarray:
    """Contract-unit block, converted by hand."""
    return _si_covariance()[np.ix_(rows, cols)] * np.outer(_factors(rows), _factors(cols))


def _cal() -> Calibration:
    return Calibration(
        method="wls",
        radar_ids=["LAEG", "DOLE", "HOLB"],
        is_3d={"LAEG": False, "DOLE": True, "HOLB": False},
        labels=[(p[0], p[1]) for p in PARAMS],
        estimate=np.array([p[4] for p in PARAMS]),
        covariance=_si_covariance(),
        n_plots={"LAEG": 12914, "DOLE": 8000, "HOLB": 311},
        observability=Observability(0.0012, 8, 8, np.linspace(0.01, 1.0, 8)),
        residuals={"LAEG": ResidualStats(
            100, {"range_m": {"mean": 90.0, "mean_abs": 90.0, "rms": 95.0}},
            {"range_m": {"mean": 0.1, "mean_abs": 30.0, "rms": 38.0}}, 1.02,
        )},
        warnings=["weak observability: HOLB.azimuth_bias"],
        info={"iterations": 1},
    )


# ---------------------------------------------------------------- blocks
@pytest.mark.parametrize(("radar", "idx"), [("LAEG", LAEG), ("DOLE", DOLE), ("HOLB", HOLB)])
def test_marginal_block_is_the_hand_converted_slice(radar: str, idx: list[int]) -> None:
    cal = _cal()
    expected = _expected_block(idx, idx)
    np.testing.assert_allclose(cal.marginal(radar), expected, rtol=1e-13)
    np.testing.assert_allclose(cal.marginal(radar), expected, rtol=1e-13)
    np.testing.assert_allclose(cal.covariance_block(radar), expected, rtol=1e-13)
    assert cal.marginal_labels(radar) == [PARAMS[i][2] for i in idx]
    # and a slice of the contract JSON's matrix
    data = cal.to_dict()
    rows = [data["covariance"]["labels"].index(f"{radar}.{PARAMS[i][2]}") for i in idx]
    matrix = np.array(data["covariance"]["matrix"])
    np.testing.assert_allclose(cal.marginal(radar), matrix[np.ix_(rows, rows)], rtol=1e-13)


def test_marginal_units_by_hand() -> None:
    """LAEG azimuth variance: (2e-5 rad)^2 -> (0.02 mrad)^2; offset-azimuth cross in m*mrad."""
    block = _cal().marginal("LAEG")
    assert block[2, 2] == pytest.approx(0.02**2)
    assert block[0, 0] == pytest.approx(0.9**2)
    assert block[0, 1] == pytest.approx(-0.7 * 0.9 * 7.5e-6)
    cross = _cal().marginal("LAEG", "DOLE")
    assert cross.shape == (3, 4)
    assert cross[0, 0] == pytest.approx(0.6 * 0.9 * 1.7)  # m * m
    assert cross[2, 1] == pytest.approx(0.3 * 0.02 * 0.03)  # mrad * mrad


def test_cross_block_and_its_transpose() -> None:
    cal = _cal()
    np.testing.assert_allclose(cal.marginal("LAEG", "DOLE"), _expected_block(LAEG, DOLE))
    np.testing.assert_allclose(cal.marginal("DOLE", "HOLB"), _expected_block(DOLE, HOLB))
    np.testing.assert_array_equal(cal.marginal("DOLE", "LAEG"), cal.marginal("LAEG", "DOLE").T)
    np.testing.assert_array_equal(cal.marginal("HOLB", "DOLE"), cal.marginal("DOLE", "HOLB").T)
    assert cal.marginal("LAEG", "LAEG").shape == (3, 3)


def test_calling_covariance_is_deprecated_and_gives_contract_units() -> None:
    cal = _cal()
    with pytest.warns(DeprecationWarning, match="marginal"):
        block = cal.covariance("LAEG")
    np.testing.assert_array_equal(block, cal.marginal("LAEG"))
    # the array itself is SI: the LAEG azimuth variance in rad^2
    assert cal.covariance[LAEG[2], LAEG[2]] == pytest.approx(2e-5**2)
    np.testing.assert_array_equal(cal.covariance_si, np.asarray(cal.covariance))


def test_unknown_radar_raises_key_error() -> None:
    cal = _cal()
    with pytest.raises(KeyError, match="XXXX"):
        cal.marginal("XXXX")
    with pytest.raises(KeyError, match="XXXX"):
        cal.marginal("LAEG", "XXXX")
    with pytest.raises(KeyError, match="XXXX"):
        cal.correlation("XXXX")


# ------------------------------------------------- covariance stays an array
def test_covariance_attribute_is_still_the_si_array() -> None:
    si = _si_covariance()
    cal = _cal()
    assert isinstance(cal.covariance, np.ndarray)
    assert isinstance(cal.covariance, JointCovariance)
    assert cal.covariance.shape == (8, 8)
    assert cal.covariance[2, 2] == si[2, 2]
    np.testing.assert_array_equal(np.diag(cal.covariance), np.diag(si))
    np.testing.assert_array_equal(cal.covariance, si)
    # derived arrays are plain ndarrays
    assert type(cal.covariance[:3, :3]) is np.ndarray
    assert type(cal.covariance * 2.0) is np.ndarray
    assert type(np.sqrt(np.diag(cal.covariance))) is np.ndarray
    assert type(np.linalg.inv(cal.covariance)) is np.ndarray
    with pytest.raises(TypeError, match="derived"), pytest.warns(DeprecationWarning):
        cal.covariance.T("LAEG")


def test_covariance_assignment_and_in_place_writes() -> None:
    cal = _cal()
    si = _si_covariance()
    cal.covariance = 4.0 * si  # reassignment, as the WLS estimator does when it drops radars
    np.testing.assert_allclose(cal.marginal("LAEG"), 4.0 * _expected_block(LAEG, LAEG))
    assert cal.sigma("LAEG", "azimuth_bias_mrad") == pytest.approx(2 * 0.02)
    cal.covariance[7, 7] = 9e-10  # element write goes to the calibration's matrix
    assert cal.sigma("HOLB", "azimuth_bias_mrad") == pytest.approx(3e-5 * 1e3)
    cal.covariance *= 0.25
    np.testing.assert_allclose(cal.marginal("DOLE"), _expected_block(DOLE, DOLE))
    # pruning labels and covariance together keeps the queries consistent
    keep = LAEG + HOLB
    cal.radar_ids = ["LAEG", "HOLB"]
    cal.labels = [cal.labels[i] for i in keep]
    cal.estimate = cal.estimate[keep]
    cal.covariance = cal.covariance[np.ix_(keep, keep)]
    np.testing.assert_allclose(cal.marginal("LAEG", "HOLB"), _expected_block(LAEG, HOLB))


def test_pickle_and_deepcopy_keep_the_queries() -> None:
    cal = _cal()
    for other in (pickle.loads(pickle.dumps(cal)), copy.deepcopy(cal)):
        np.testing.assert_allclose(other.marginal("DOLE"), _expected_block(DOLE, DOLE))


# ------------------------------------------------------------------ sigma
@pytest.mark.parametrize("index", range(len(PARAMS)))
def test_sigma_for_every_contract_key(index: int) -> None:
    radar, _, key, factor, value, sd = PARAMS[index]
    cal = _cal()
    assert cal.sigma(radar, key) == pytest.approx(sd * factor, rel=1e-12)
    assert cal.value(radar, key) == pytest.approx(value * factor, rel=1e-12)
    assert cal.sigma(radar, key) == pytest.approx(np.sqrt(cal.marginal(radar).diagonal()[
        cal.marginal_labels(radar).index(key)]))


def test_sigma_of_parameters_not_estimated_and_unknown_keys() -> None:
    cal = _cal()
    assert cal.sigma("LAEG", "time_offset_s") is None
    assert cal.sigma("LAEG", "elevation_bias_mrad") is None
    assert cal.sigma("DOLE", "time_offset_s") == pytest.approx(0.02)
    assert cal.value("HOLB", "range_offset_m") is None
    with pytest.raises(KeyError, match="azimuth_bias_mrad"):  # the message lists the keys
        cal.sigma("LAEG", "azimuth_bias")


# ------------------------------------------------------------ correlation
def test_correlation_full_and_blocks() -> None:
    cal = _cal()
    r = _correlation()
    np.testing.assert_allclose(cal.correlation(), r, atol=1e-14)
    np.testing.assert_allclose(cal.correlation("LAEG"), r[np.ix_(LAEG, LAEG)], atol=1e-14)
    np.testing.assert_allclose(cal.correlation("LAEG", "DOLE"), r[np.ix_(LAEG, DOLE)], atol=1e-14)
    assert cal.correlation("LAEG")[0, 1] == pytest.approx(-0.7)
    assert cal.correlation("LAEG", "DOLE")[0, 0] == pytest.approx(0.6)
    assert cal.correlation("DOLE", "HOLB")[1, 0] == pytest.approx(0.1)
    np.testing.assert_allclose(np.diag(cal.correlation("DOLE")), 1.0)
    np.testing.assert_allclose(cal.correlation("DOLE", "LAEG"), cal.correlation("LAEG", "DOLE").T)
    with pytest.raises(TypeError):
        cal.correlation(radar_b="LAEG")


# -------------------------------------------------------------- from_dict
def _assert_same(a: Calibration, b: Calibration) -> None:
    assert a.method == b.method and a.radar_ids == b.radar_ids and a.labels == b.labels
    np.testing.assert_allclose(a.estimate, b.estimate, rtol=1e-14)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-14)
    for radar, _, key, *_ in PARAMS:
        assert a.value(radar, key) == pytest.approx(b.value(radar, key), rel=1e-14)
        assert a.sigma(radar, key) == pytest.approx(b.sigma(radar, key), rel=1e-14)
    for radar in a.radar_ids:
        np.testing.assert_allclose(a.marginal(radar), b.marginal(radar), rtol=1e-14)
    np.testing.assert_allclose(a.correlation(), b.correlation(), rtol=1e-12, atol=1e-15)
    assert a.n_plots == b.n_plots and a.is_3d == b.is_3d and a.warnings == b.warnings
    assert a.observability.degree == pytest.approx(b.observability.degree)
    assert a.observability.rank == b.observability.rank


def test_from_dict_round_trip() -> None:
    cal = _cal()
    data = json.loads(cal.to_json())
    back = Calibration.from_dict(data)
    _assert_same(cal, back)
    assert back.residuals["LAEG"].to_dict() == cal.residuals["LAEG"].to_dict()
    assert back.info == cal.info
    again = back.to_dict()
    assert again["covariance"]["labels"] == data["covariance"]["labels"]
    np.testing.assert_allclose(again["covariance"]["matrix"], data["covariance"]["matrix"])
    for radar in cal.radar_ids:
        assert again["radars"][radar]["sigma"] == pytest.approx(data["radars"][radar]["sigma"])


def test_read_json_round_trip(tmp_path: Path) -> None:
    cal = _cal()
    cal.write_json(tmp_path / "result.json")
    _assert_same(cal, Calibration.read_json(tmp_path / "result.json"))


def test_from_dict_reads_null_as_nan() -> None:
    data = _cal().to_dict()
    data["covariance"]["matrix"][7][7] = None  # what to_dict writes for an infinite variance
    data["radars"]["HOLB"]["azimuth_bias_mrad"] = None
    back = Calibration.from_dict(data)
    assert np.isnan(back.sigma("HOLB", "azimuth_bias_mrad"))
    assert np.isnan(back.value("HOLB", "azimuth_bias_mrad"))
    assert back.sigma("LAEG", "range_offset_m") == pytest.approx(0.9)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda d: d.pop("covariance"), "covariance"),
        (lambda d: d.pop("radars"), "radars"),
        (lambda d: d["covariance"].pop("labels"), "covariance.labels"),
        (lambda d: d["covariance"]["labels"].__setitem__(0, "LAEG.range_offset"),
         "covariance.labels"),
        (lambda d: d["covariance"]["labels"].__setitem__(0, "NOPE.range_offset_m"),
         "covariance.labels"),
        (lambda d: d["covariance"]["matrix"].pop(), "covariance.matrix"),
        (lambda d: d["covariance"]["matrix"][0].__setitem__(1, "x"), "covariance.matrix"),
        (lambda d: d["radars"]["DOLE"].__setitem__("range_offset_m", "41"),
         "radars.DOLE.range_offset_m"),
        (lambda d: d["radars"].__setitem__("HOLB", 3), "radars.HOLB"),
    ],
)
def test_from_dict_names_the_bad_field(change, field: str) -> None:
    data = _cal().to_dict()
    change(data)
    with pytest.raises(ResultError, match=f"result.json, field '{field}'") as info:
        Calibration.from_dict(data, source="result.json")
    assert isinstance(info.value, GraphcalInputError) and info.value.field == field


def test_from_dict_on_an_estimator_result() -> None:
    """A real WLS result (its covariance reassigned when radars are dropped) round-trips."""
    rng = np.random.default_rng(3)
    sites = [
        (site_at("A", 0.0, 0.0), RadarBias(50.0, 1e-4, 1e-3)),
        (site_at("B", 100e3, 10e3, sigma_elevation_mrad=2.0), RadarBias(-30.0, 0.0, -1e-3, 5e-4)),
    ]
    tracks = []
    for i in range(6):
        start = (rng.uniform(-50e3, 150e3), rng.uniform(-80e3, 80e3), rng.uniform(7e3, 11e3))
        heading = rng.uniform(0, 2 * np.pi)
        tracks.append(Track(f"b{i:05x}", start,
                            (200 * np.sin(heading), 200 * np.cos(heading), 0.0), 0.0, 600.0))
    cal = calibrate(make_dataset(rng, sites, tracks, adsb=False), "wls")
    data = cal.to_dict()
    matrix = np.array(data["covariance"]["matrix"])
    for radar in cal.radar_ids:
        rows = [i for i, label in enumerate(data["covariance"]["labels"])
                if label.startswith(f"{radar}.")]
        np.testing.assert_allclose(cal.marginal(radar), matrix[np.ix_(rows, rows)])
    back = Calibration.from_dict(json.loads(json.dumps(data)))
    np.testing.assert_allclose(back.marginal("A", "B"), cal.marginal("A", "B"), rtol=1e-12)


# ------------------------------------------------------------------- CLI
def _write(tmp_path: Path) -> Path:
    path = tmp_path / "result.json"
    _cal().write_json(path)
    return path


def test_cli_prints_blocks_values_and_sigmas(tmp_path: Path) -> None:
    result = runner.invoke(app, ["marginals", str(_write(tmp_path))])
    assert result.exit_code == 0, result.output
    out = result.output
    for radar in ("LAEG", "DOLE", "HOLB"):
        assert f"{radar}: marginal covariance" in out
    assert "-3.100 ± 0.020" in out  # LAEG azimuth, mrad
    assert "-93.70 ± 0.90" in out  # LAEG range offset, m
    assert "0.350 ± 0.020" in out  # DOLE time offset, s
    assert "6.940e-04 ± 7.500e-06" in out  # LAEG range gain
    assert f"{0.9**2:.4g}" in out  # LAEG offset variance, m^2
    assert f"{-0.7 * 0.9 * 7.5e-6:.4g}" in out  # LAEG offset x gain
    assert f"{0.03**2:.4g}" in out  # DOLE azimuth variance, mrad^2
    assert "correlation" not in out


def test_cli_one_radar_with_correlation(tmp_path: Path) -> None:
    result = runner.invoke(app, ["marginals", str(_write(tmp_path)), "--radar", "LAEG",
                                 "--correlation"])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "LAEG: marginal covariance" in out and "DOLE: marginal" not in out
    assert "LAEG: correlation" in out
    assert "-0.700" in out  # offset/gain inside LAEG
    assert "LAEG.range_offset_m" in out and "DOLE.range_offset_m" in out and "+0.600" in out
    assert "LAEG.azimuth_bias_mrad" not in out  # rho 0.3 with DOLE: below the 0.5 threshold
    lowered = runner.invoke(app, ["marginals", str(_write(tmp_path)), "--radar", "LAEG",
                                  "--correlation", "--min-rho", "0.25"])
    assert "LAEG.azimuth_bias_mrad" in lowered.output and "+0.300" in lowered.output


def test_cli_full_correlation_matrix(tmp_path: Path) -> None:
    result = runner.invoke(app, ["marginals", str(_write(tmp_path)), "--correlation"])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "[8] HOLB.azimuth_bias_mrad" in out
    assert "-0.70" in out and "+0.60" in out and "+0.10" in out
    assert "|ρ| > 0.5" in out


def _bad_inputs(tmp_path: Path) -> dict[str, tuple[list[str], str]]:
    good = _write(tmp_path)
    (tmp_path / "text.json").write_text("{not json")
    data = _cal().to_dict()
    data.pop("covariance")
    (tmp_path / "nocov.json").write_text(json.dumps(data))
    return {
        "missing file": ([str(tmp_path / "absent.json")], "absent.json"),
        "not JSON": ([str(tmp_path / "text.json")], "text.json"),
        "no covariance": ([str(tmp_path / "nocov.json")], "field 'covariance'"),
        "unknown radar": ([str(good), "--radar", "XXXX"], "XXXX"),
        "folder": ([str(tmp_path)], str(tmp_path)),
        "bad threshold": ([str(good), "--min-rho", "1.5"], "--min-rho"),
    }


@pytest.mark.parametrize(
    "case", ["missing file", "not JSON", "no covariance", "unknown radar", "folder",
             "bad threshold"]
)
def test_cli_bad_input_exits_2_with_one_line(tmp_path: Path, case: str) -> None:
    args, expected = _bad_inputs(tmp_path)[case]
    result = runner.invoke(app, ["marginals", *args])
    assert result.exit_code == 2, result.output
    message = result.output.strip()
    assert len(message.splitlines()) == 1
    assert message.startswith("error: ") and expected in message


def test_help_lists_marginals() -> None:
    result = runner.invoke(app, ["--help"])
    assert "marginals" in result.output

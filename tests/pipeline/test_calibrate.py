"""The calibration pipeline and the public API: one run, options checked, the bound once."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import graphcal
from graphcal.analysis.crlb import crlb
from graphcal.data.bias import CONTRACT_KEYS, RadarBias
from graphcal.pipeline.calibrate import calibrate, parse_fixed
from graphcal.solvers.graph import graph
from tests.synthetic import Track, make_dataset, site_at

TRUTH = {"A": RadarBias(60.0, 3e-4, 1.5e-3), "B": RadarBias(-40.0, -2e-4, -1e-3, 2e-3)}


@pytest.fixture(scope="module")
def network():
    rng = np.random.default_rng(3)
    a = site_at("A", 0.0, 0.0)
    b = site_at("B", 90e3, 30e3, sigma_elevation_mrad=2.0)
    tracks = []
    for i in range(8):
        heading = rng.uniform(0, 2 * np.pi)
        start = (rng.uniform(-60e3, 150e3), rng.uniform(-90e3, 90e3), rng.uniform(6e3, 11e3))
        tracks.append(Track(f"c{i:05x}", start, (200 * np.sin(heading), 200 * np.cos(heading),
                                                  0.0), 0.0, 600.0))
    return make_dataset(rng, [(a, TRUTH["A"]), (b, TRUTH["B"])], tracks)


def test_graph_estimate_is_the_solvers_and_the_bound_is_its_models(network) -> None:
    """The pipeline's graph result equals the solver's own, and the bound it reports is
    the one the trajectory formulation computed of its own model."""
    cal = calibrate(network, time_offset="off")
    alone = graph(network, time_offset=False, bound=True)
    np.testing.assert_array_equal(cal.estimate, alone.estimate)
    assert "crlb_sigma" in cal.info and "crlb_sigma" not in alone.info
    assert graph(network, time_offset=False).bound is None  # only when asked
    assert cal.info["crlb_model"].startswith("trajectory model")
    bound_sigma = np.sqrt(np.diag(alone.bound["covariance"]))
    for i, (rid, name) in enumerate(alone.labels):
        key = f"{rid}.{_key(name)}"
        scale = CONTRACT_KEYS[name][1]
        assert cal.info["crlb_sigma"][key] == pytest.approx(bound_sigma[i] * scale, rel=1e-9)
        assert 0.99 < cal.info["efficiency"][key] < 1.3


def test_pairwise_estimate_is_the_solvers_and_the_bound_is_computed_once(network) -> None:
    """Pairwise: the pipeline's graph result equals the solver's own; the bound it adds
    equals the Cramér-Rao bound computed separately with the graph's labels and priors."""
    cal = calibrate(network, time_offset="off", cross="pairwise")
    alone = graph(network, time_offset=False, cross="pairwise")
    np.testing.assert_array_equal(cal.estimate, alone.estimate)
    assert "crlb_sigma" in cal.info and "crlb_sigma" not in alone.info
    priors = {(rid, name): float(s) for rid, entries in alone.info["priors"].items()
              for name, s in _si(entries).items()}
    bound = crlb(network, labels=alone.labels, priors=priors)
    for rid, name in alone.labels:
        key = f"{rid}.{_key(name)}"
        assert cal.info["crlb_sigma"][key] == pytest.approx(bound.sigma(rid, _key(name)),
                                                           rel=1e-9)
        # An efficient estimator: reported sigma close to the bound.
        assert 0.9 < cal.info["efficiency"][key] < 1.3


def _key(name: str) -> str:
    from graphcal.data.bias import CONTRACT_KEYS

    return CONTRACT_KEYS[name][0]


def _si(entries: dict[str, float]) -> dict[str, float]:
    from graphcal.data.bias import NAME_FROM_KEY, from_contract_units

    return {NAME_FROM_KEY[k]: from_contract_units(NAME_FROM_KEY[k], v) for k, v in entries.items()}


def test_estimates_within_3_sigma_of_the_truth(network) -> None:
    cal = calibrate(network, time_offset="off")
    sd = np.sqrt(np.diag(cal.covariance))
    for i, (rid, name) in enumerate(cal.labels):
        assert abs(cal.estimate[i] - TRUTH[rid].value(name)) < 3 * sd[i], (rid, name)


def test_a_closed_form_method_gets_no_bound_unless_asked(network) -> None:
    assert "crlb_sigma" not in calibrate(network, "fl-ls").info
    assert "crlb_sigma" in calibrate(network, "fl-ls", bound=True).info


def test_fixed_takes_contract_keys_and_units(network) -> None:
    cal = calibrate(network, fixed={"B.azimuth_bias_mrad": -1.0}, time_offset="off")
    assert ("B", "azimuth_bias") not in cal.labels
    assert cal.value("B", "azimuth_bias_mrad") == pytest.approx(-1.0)
    assert parse_fixed({"A.range_gain": 0.001}, network.sites) == {("A", "range_gain"): 0.001}


@pytest.mark.parametrize("options, message", [
    ({"method": "ls", "cross": "none"}, "cross applies to graph"),
    ({"method": "graph", "iterations": 3}, "iterations applies to wls"),
    ({"method": "fl", "use_adsb": False}, "use_adsb applies to graph"),
    ({"budget": 100}, "give select as well"),
    ({"fixed": {"A.bogus_m": 1.0}}, "unknown key 'bogus_m'"),
    ({"fixed": {"Z.range_gain": 0.0}}, "unknown radar 'Z'"),
    ({"time_offset": "sometimes"}, "auto, on or off"),
    ({"method": "nope"}, "unknown method 'nope'"),
])
def test_options_that_do_not_apply_are_refused(network, options, message) -> None:
    with pytest.raises(ValueError, match=message):
        calibrate(network, **options)


def test_a_folder_path_is_loaded(network, tmp_path) -> None:
    folder = graphcal.write_dataset(network, tmp_path / "ds")
    from_path = graphcal.calibrate(folder, "ls")
    np.testing.assert_allclose(from_path.estimate, calibrate(network, "ls").estimate,
                               rtol=1e-9)


def test_public_names_resolve_and_are_listed() -> None:
    for name in graphcal.__all__:
        assert getattr(graphcal, name) is not None, name
    assert graphcal.calibrate is calibrate
    with pytest.raises(AttributeError):
        graphcal.not_a_name  # noqa: B018


def test_simulate_takes_a_seed_or_a_generator() -> None:
    from tests.paths import SCENARIOS

    path = SCENARIOS / "paper003_adsb_2d.toml"
    one = graphcal.simulate(path, seed=4)
    two = graphcal.simulate(path, np.random.default_rng(4))
    assert one.dataset.plots.equals(two.dataset.plots)
    assert one.truth == one.biases
    with pytest.raises(ValueError, match="exactly one"):
        graphcal.simulate(path)


def test_importing_graphcal_loads_no_solver() -> None:
    code = ("import sys, graphcal; "
            "print(sorted(m for m in ('gtsam', 'scipy', 'cvxpy', 'matplotlib', 'pandas') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"


# --------------------------------------------------------------------------- model checks
def _eccentric(dataset, radar: str, amplitude_mrad: float):
    """``dataset`` with ``amplitude sin(azimuth)`` added to ``radar``'s azimuths."""
    plots = dataset.plots.copy()
    rows = plots["radar_id"] == radar
    az = np.deg2rad(plots.loc[rows, "azimuth_deg"].to_numpy())
    plots.loc[rows, "azimuth_deg"] = np.mod(
        np.rad2deg(az + amplitude_mrad * 1e-3 * np.sin(az)), 360.0)
    return graphcal.Dataset(dataset.sites, plots, dataset.adsb)


@pytest.mark.parametrize("method", ["graph", "ls", "wls"])
def test_model_checks_run_after_every_calibration(network, method) -> None:
    cal = calibrate(network, method)
    checks = cal.info["model_checks"]
    assert checks["reference"] == "adsb"
    assert set(checks["radars"]) == set(cal.radar_ids)
    assert all(r["n_tests"] >= 8 for r in checks["radars"].values())
    assert checks["warnings"] == [w for w in cal.warnings if "unmodelled" in w] == []
    assert cal.info["timing_s"]["model_checks_s"] == checks["seconds"] > 0
    # Recorded in the result JSON and read back.
    back = graphcal.Calibration.from_dict(json.loads(cal.to_json()))
    assert back.info["model_checks"]["radars"].keys() == checks["radars"].keys()


def test_a_structure_beyond_chance_becomes_a_warning(network) -> None:
    dataset = _eccentric(network, "A", 2.0)
    cal = calibrate(dataset, "ls")
    found = [w for w in cal.warnings if "unmodelled" in w]
    assert len(found) == 1
    assert found[0].startswith("A: unmodelled azimuth residual sinusoidal in azimuth")
    assert cal.info["model_checks"]["warnings"] == found
    assert cal.info["model_checks"]["radars"]["A"]["fired"][0] == "azimuth vs azimuth"


def test_model_checks_can_be_turned_off(network) -> None:
    cal = calibrate(_eccentric(network, "A", 2.0), "ls", model_checks=False)
    assert "model_checks" not in cal.info
    assert not any("unmodelled" in w for w in cal.warnings)


def test_without_adsb_the_checks_use_the_pairs(network) -> None:
    cal = calibrate(network, use_adsb=False)
    checks = cal.info["model_checks"]
    assert checks["reference"] == "cross"
    assert checks["radars"]["A"]["partners"] == ["B"]

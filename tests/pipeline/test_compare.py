"""Monte-Carlo comparison (graphcal.pipeline.compare) and the ``compare`` command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import typer
from typer.testing import CliRunner

from graphcal.cli.compare import compare_command
from graphcal.pipeline.compare import TABLE_COLUMNS, compare
from graphcal.simulation.scenario import load_scenario
from tests.paths import ROOT

PATH1 = ROOT / "scenarios" / "paper001_path1.toml"
PAPER003 = ROOT / "scenarios" / "paper003_adsb_2d.toml"

runner = CliRunner()


def _app() -> typer.Typer:
    app = typer.Typer()
    app.command(name="compare")(compare_command)
    # A second command keeps typer from collapsing the app into its only command.
    app.command(name="noop")(lambda: None)
    return app


@pytest.fixture(scope="module")
def path1_result():
    return compare(PATH1, ["wls", "graph"], 4, seed=3,
                   method_options={"graph": {"use_adsb": False}})


def _no_adsb_path1(tmp_path: Path) -> Path:
    """Paper 001 path 1, shortened to 400 s; its [adsb] is already disabled."""
    text = PATH1.read_text().replace("duration_s = 1600.0", "duration_s = 400.0")
    assert "[adsb]\nenabled = false" in text
    path = tmp_path / "no_adsb.toml"
    path.write_text(text)
    return path


def test_table_layout(path1_result):
    table = path1_result.table
    assert list(table.columns) == list(TABLE_COLUMNS)
    # 2 methods x 2 radars x 3 estimated parameters
    assert len(table) == 12
    assert set(table["method"]) == {"wls", "graph"}
    assert list(table["parameter"].iloc[:3]) == ["range_offset_m", "range_gain",
                                                 "azimuth_bias_mrad"]
    truth = table.set_index(["method", "radar", "parameter"])["truth"]
    assert truth[("wls", "R1", "range_offset_m")] == pytest.approx(1000.0)
    assert truth[("wls", "R2", "azimuth_bias_mrad")] == pytest.approx(14.0)
    assert (table["failures"] == 0).all() and (table["n"] == 4).all()
    assert list(path1_result.timing["method"]) == ["wls", "graph"]
    assert (path1_result.timing["mean_s"] > 0).all()


def test_summary_matches_hand_computation(path1_result):
    est = path1_result.estimates
    table = path1_result.table.set_index(["method", "radar", "parameter"])
    for (method, rid, key), row in table.iterrows():
        sel = est[(est.method == method) & (est.radar == rid) & (est.parameter == key)]
        values = sel.sort_values("run")["value"].to_numpy()
        assert len(values) == 4
        assert row["mean"] == pytest.approx(np.mean(values), rel=1e-12)
        assert row["std"] == pytest.approx(np.std(values, ddof=1), rel=1e-12)
        assert row["rmse"] == pytest.approx(
            np.sqrt(np.mean((values - row["truth"]) ** 2)), rel=1e-12)
        sigmas = sel["sigma"].to_numpy()
        assert row["mean_sigma"] == pytest.approx(np.mean(sigmas), rel=1e-12)
        assert row["consistency"] == pytest.approx(np.mean(sigmas) / np.std(values, ddof=1))


def test_runs_are_independent_simulations(path1_result):
    est = path1_result.estimates
    sel = est[(est.method == "wls") & (est.radar == "R1") & (est.parameter == "range_offset_m")]
    assert sel["value"].nunique() == 4


def test_same_results_for_any_jobs():
    kwargs = dict(seed=11, method_options={"graph": {"use_adsb": False}})
    calls: list[tuple[int, int]] = []
    one = compare(PATH1, ["wls-pruned", "graph"], 3, jobs=1, **kwargs)
    two = compare(PATH1, ["wls-pruned", "graph"], 3, jobs=2,
                  progress=lambda d, t: calls.append((d, t)), **kwargs)
    pd.testing.assert_frame_equal(one.table, two.table)
    pd.testing.assert_frame_equal(one.estimates, two.estimates)
    assert calls == [(1, 3), (2, 3), (3, 3)]
    # and a different seed gives different runs
    other = compare(PATH1, ["wls-pruned"], 3, seed=12)
    assert not np.allclose(other.table["mean"], one.table["mean"].iloc[: len(other.table)])


def test_seed_sequence_matches_spawned_children():
    """Run i simulates with default_rng(SeedSequence(seed).spawn(runs)[i])."""
    from graphcal.simulation.simulate import simulate
    from graphcal.solvers.registry import get_estimator

    scenario = load_scenario(PAPER003)
    result = compare(scenario, ["fl"], 2, seed=5, crlb=False)
    child = np.random.SeedSequence(5).spawn(2)[1]
    cal = get_estimator("fl")(simulate(scenario, np.random.default_rng(child)).dataset)
    est = result.estimates
    value = est[(est.run == 1) & (est.parameter == "range_offset_m")]["value"].item()
    assert value == cal.value("R2D", "range_offset_m")


def test_failures_are_counted(tmp_path):
    path = _no_adsb_path1(tmp_path)
    result = compare(path, ["ls", "wls"], 2, seed=1)
    failures = result.failures.set_index("method")
    assert failures.loc["ls", "failures"] == 2
    assert "EstimationError" in failures.loc["ls", "first_error"]
    assert failures.loc["wls", "failures"] == 0
    # The failed method stays in the table: one row with its status, no figures.
    table = result.table
    assert set(table["method"]) == {"ls", "wls"}
    [ls_row] = table[table["method"] == "ls"].itertuples(index=False)
    assert ls_row.status.startswith("failed: EstimationError") and ls_row.failures == 2
    assert ls_row.n == 0 and ls_row.radar == "" and np.isnan(ls_row.mean)
    wls = table[table["method"] == "wls"]
    assert (wls["failures"] == 0).all() and (wls["status"] == "ok").all()
    assert "| ls |  |  |" in result.to_markdown()


def test_unknown_method_and_bad_counts():
    with pytest.raises(ValueError, match="use one of"):
        compare(PATH1, ["nope"], 1)
    with pytest.raises(ValueError, match="runs"):
        compare(PATH1, ["wls"], 0)
    with pytest.raises(ValueError, match="jobs"):
        compare(PATH1, ["wls"], 1, jobs=0)


def test_crlb_column_is_nan_or_positive(path1_result):
    col = path1_result.table["rmse_over_crlb"]
    assert col.isna().all() or (col.dropna() > 0).all()


def test_writers(tmp_path, path1_result):
    md, csv, js = tmp_path / "r.md", tmp_path / "r.csv", tmp_path / "r.json"
    for path in (md, csv, js):
        path1_result.write(path)
    frame = pd.read_csv(csv)
    assert list(frame.columns) == list(TABLE_COLUMNS)
    np.testing.assert_allclose(frame["rmse"], path1_result.table["rmse"])
    data = json.loads(js.read_text())
    assert data["runs"] == 4 and data["methods"] == ["wls", "graph"]
    assert len(data["table"]) == 12 and data["table"][0]["parameter"] == "range_offset_m"
    assert {r["method"] for r in data["timing"]} == {"wls", "graph"}
    # markdown: a pipe table with one row per table row, same number of cells in every row
    rows = [ln for ln in md.read_text().splitlines() if ln.startswith("| ")]
    header = rows[0].count("|")
    body = [r for r in rows if r.count("|") == header]
    assert len(body) >= 1 + 12
    assert "| wls | R1 | range_offset_m | 1000 |" in md.read_text()
    assert not list(tmp_path.glob(".*"))  # no temporary files left
    with pytest.raises(ValueError, match="suffix"):
        path1_result.write(tmp_path / "r.txt")


def test_cli_prints_and_writes(tmp_path):
    out = tmp_path / "cmp.json"
    res = runner.invoke(_app(), ["compare", str(PAPER003), "--methods", "fl,fl-ls",
                                 "--runs", "2", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "fl-ls" in res.output and "range_offset_m" in res.output
    assert json.loads(out.read_text())["runs"] == 2


def test_cli_method_that_cannot_run_is_a_failure(tmp_path):
    path = _no_adsb_path1(tmp_path)
    res = runner.invoke(_app(), ["compare", str(path), "--methods", "ls,wls", "--runs", "1"])
    assert res.exit_code == 0, res.output
    assert "1 of 1 runs failed" in res.output


@pytest.mark.parametrize(
    "args, message",
    [
        (["--methods", "wls,bogus"], "use one of: ls, fl, fl-ls, wls, wls-pruned, graph"),
        (["--runs", "0"], "--runs"),
        (["--jobs", "0"], "--jobs"),
        (["--out", "x.txt"], "suffix"),
    ],
)
def test_cli_bad_input_exits_2(args, message):
    res = runner.invoke(_app(), ["compare", str(PATH1), *args])
    assert res.exit_code == 2
    assert message in res.output


def test_cli_missing_scenario_exits_2(tmp_path):
    res = runner.invoke(_app(), ["compare", str(tmp_path / "none.toml"), "--runs", "1"])
    assert res.exit_code == 2
    assert "error" in res.output

"""Every command's output at 80 columns, piped: no line wider than 80 characters, no cell
cut with an ellipsis, and the numbers printed are those of the command's JSON output; with
the demo's short radar ids and with realistic long ones (20 and 43 characters)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from graphcal.data.calibration import Calibration
from graphcal.reporting.tables import format_value
from tests.paths import SCENARIOS

ROOT = Path(__file__).resolve().parents[2]
WIDTH = 80


def _graphcal(*argv: str, cwd: Path = ROOT) -> str:
    """Standard output of ``graphcal ARGV`` into a pipe with ``COLUMNS=80``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": str(WIDTH), "NO_COLOR": "1",
           "TERM": "dumb"}
    done = subprocess.run([sys.executable, "-m", "graphcal", *argv], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout


def _fits(text: str) -> None:
    """No line beyond 80 characters (warnings and notes included: they wrap at spaces with
    a hanging indent), nothing cut."""
    assert text.strip()
    widest = max(text.splitlines(), key=len)
    assert len(widest) <= WIDTH, widest
    assert "…" not in text and "..." not in text, text


def _tokens(text: str) -> set[str]:
    return set(text.split())


def _scenario(tmp: Path, source: str, duration_s: float, n_aircraft: int) -> Path:
    """A copy of a bundled scenario, shorter and with fewer aircraft (a faster test)."""
    text = (SCENARIOS / source).read_text()
    text = re.sub(r"(?m)^duration_s = .*$", f"duration_s = {duration_s}", text, count=1)
    text = re.sub(r"(?m)^n_aircraft = .*$", f"n_aircraft = {n_aircraft}", text, count=1)
    path = tmp / source
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The demo network (5 radars, 3-D ones with five parameters), 10 min, calibrated."""
    tmp = tmp_path_factory.mktemp("columns80")
    folder = tmp / "demo"
    _graphcal("simulate", str(_scenario(tmp, "demo_network.toml", 600.0, 25)), "--out",
              str(folder), "--seed", "1")
    result = tmp / "r.json"
    _graphcal("calibrate", str(folder), "--out", str(result))
    return folder, result


@pytest.fixture(scope="module")
def eccentric(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A result with seven parameters for one radar (eccentricity terms, time offset)."""
    tmp = tmp_path_factory.mktemp("columns80ecc")
    folder = tmp / "ecc"
    _graphcal("simulate", str(_scenario(tmp, "demo_eccentricity.toml", 600.0, 25)), "--out",
              str(folder), "--seed", "1")
    result = tmp / "r.json"
    _graphcal("calibrate", str(folder), "--out", str(result))
    return result


def test_calibrate(demo: tuple[Path, Path]) -> None:
    folder, result = demo
    text = _graphcal("calibrate", str(folder))
    _fits(text)
    doc = json.loads(result.read_text())
    for rid, entry in doc["radars"].items():
        assert re.search(rf"(^|\s){rid}\b", text, re.MULTILINE), rid
        for key, sigma in entry["sigma"].items():
            assert format_value(key, entry[key], sigma) in text, (rid, key)


def test_calibrate_window(tmp_path: Path) -> None:
    folder = tmp_path / "drift"
    _graphcal("simulate", str(_scenario(tmp_path, "demo_drift.toml", 4800.0, 15)), "--out",
              str(folder), "--seed", "1")
    result = tmp_path / "r.json"
    # The formatting of windows is the matter here: the quicker pairwise formulation.
    _graphcal("calibrate", str(folder), "--window", "30min", "--cross", "pairwise",
              "--out", str(result),
              "--history", str(tmp_path / "calib.db"))
    text = _graphcal("calibrate", str(folder), "--window", "30min", "--cross", "pairwise")
    _fits(text)
    doc = json.loads(result.read_text())
    for rid, entry in doc["radars"].items():  # the last window
        for key, sigma in entry["sigma"].items():
            assert format_value(key, entry[key], sigma) in text, (rid, key)

    # Relative to the folder: the header names the file as given, and a long temporary
    # path alone would pass 80 columns.
    shown = _graphcal("history", "calib.db", cwd=tmp_path)
    _fits(shown)
    for rid, windows in doc["series"]["radars"].items():
        assert f"{rid} (" in shown
        for window in windows:
            for key, sigma in window["sigma"].items():
                assert format_value(key, window[key], 2.0 * sigma) in shown, (rid, key)


@pytest.mark.parametrize("radar", [None, "EST3D"])
def test_marginals(demo: tuple[Path, Path], radar: str | None) -> None:
    """Every value ± 1σ and every covariance entry printed whole (the wide rows of 3-D
    radars split over two tables)."""
    _, result = demo
    argv = ["marginals", str(result), "--correlation"]
    if radar is not None:
        argv += ["--radar", radar]
    text = _graphcal(*argv)
    _fits(text)
    cal = Calibration.read_json(result)
    tokens = _tokens(text)
    for rid in [radar] if radar else cal.radar_ids:
        for key, row in zip(cal.marginal_labels(rid), cal.marginal(rid), strict=True):
            assert format_value(key, cal.value(rid, key), cal.sigma(rid, key)) in text
            assert key in tokens
            for entry in row:
                assert f"{entry:.4g}" in tokens, (rid, key, entry)
    if radar is not None:
        rho = cal.correlation(radar)
        assert {f"{r:+.3f}" for r in np.ravel(rho)} <= tokens


def test_marginals_seven_parameters(eccentric: Path) -> None:
    text = _graphcal("marginals", str(eccentric), "--correlation", "--radar", "NORD")
    _fits(text)
    cal = Calibration.read_json(eccentric)
    assert len(cal.marginal_labels("NORD")) >= 6
    tokens = _tokens(text)
    for row in cal.marginal("NORD"):
        assert {f"{entry:.4g}" for entry in row} <= tokens


def test_compare(tmp_path: Path) -> None:
    out = tmp_path / "c.json"
    text = _graphcal("compare", str(SCENARIOS / "paper003_adsb_2d.toml"), "--runs", "2",
                     "--methods", "ls,fl,wls,graph", "--out", str(out))
    _fits(text)
    doc = json.loads(out.read_text())
    tokens = _tokens(text)
    for method in doc["methods"]:
        assert method in tokens
    for row in doc["table"]:
        if row["parameter"]:
            assert f"{row['radar']} {row['parameter']}" in text
            assert f"{row['mean']:.4g} ± {row['std']:.3g}" in text, row
            assert f"{row['rmse']:.3g}" in tokens
            assert f"{row['rmse_over_crlb']:.3g}" in tokens


def test_observability_budget(demo: tuple[Path, Path], tmp_path: Path) -> None:
    folder, _ = demo
    out = tmp_path / "o.json"
    text = _graphcal("observability", str(folder), "--budget", "800", "--random-draws", "5",
                     "--out", str(out))
    _fits(text)
    doc = json.loads(out.read_text())
    tokens = _tokens(text)
    for row in doc["selection"]:
        for word in str(row["method"]).split():
            assert word in tokens
        for key in ("degree_full_scaling", "lambda_min", "mean_sigma_ratio"):
            if row.get(key) is not None:
                assert f"{row[key]:.3g}" in tokens, (row["method"], key)
        assert str(int(row["observations"])) in tokens


def test_noise(demo: tuple[Path, Path], tmp_path: Path) -> None:
    folder, _ = demo
    text = _graphcal("noise", str(folder), "--write-sites", str(tmp_path / "sites.toml"))
    _fits(text)
    for rid in ("NORD", "SUD", "EST3D", "OUEST3D", "APP"):
        assert re.search(rf"^\S*\s*{rid}\s", text, re.MULTILINE), rid
    # every estimate whole: "value ± se" with both numbers on one line
    assert len(re.findall(r"\d+\.\d+ ± \d+\.\d+", text)) >= 12


def test_fuse(demo: tuple[Path, Path]) -> None:
    folder, result = demo
    text = _graphcal("fuse", str(folder), "--calibration", str(result))
    _fits(text)
    for name in ("NORD", "SUD", "EST3D", "OUEST3D", "APP", "fused, covariance weights",
                 "fused, equal weights"):
        assert re.search(rf"{re.escape(name)}\s+[│ ]*\d+\.\d", text), name


def test_methods() -> None:
    from graphcal.solvers.registry import METHODS

    text = _graphcal("methods")
    _fits(text)
    for name in METHODS:
        assert re.search(rf"^{re.escape(name)}\s", text, re.MULTILINE)


def test_correct(demo: tuple[Path, Path], tmp_path: Path) -> None:
    folder, result = demo
    done = subprocess.run(
        [sys.executable, "-m", "graphcal", "correct", str(folder), str(result), "--out",
         str(tmp_path / "corrected")], cwd=ROOT, capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": str(WIDTH)})
    assert done.returncode == 0, done.stderr
    _fits(done.stdout + done.stderr)


@pytest.fixture(scope="module")
def imported(demo: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> str:
    """import-asterix's output on the demo's first 40 plots per radar, encoded."""
    from graphcal.io.asterix.encode import encode_dataset
    from graphcal.io.folder import load_dataset, write_sites

    tmp = tmp_path_factory.mktemp("asterix80")
    ds = load_dataset(demo[0])
    ds.plots = ds.plots.groupby("radar_id").head(40).reset_index(drop=True)
    ds.adsb = ds.adsb.iloc[::50].reset_index(drop=True)
    codes = {rid: (25, 10 + k) for k, rid in enumerate(ds.sites)}
    rec = tmp / "rec.ast"
    rec.write_bytes(encode_dataset(ds, codes))
    sites = tmp / "sites.toml"
    write_sites(ds.sites, sites)
    text = sites.read_text()
    for rid, (sac, sic) in codes.items():
        text = text.replace(f'id = "{rid}"', f'id = "{rid}"\nsac = {sac}\nsic = {sic}')
    sites.write_text(text)
    return _graphcal("import-asterix", str(rec), "--sites", str(sites), "--out",
                     str(tmp / "ds"))


def test_import_asterix_table(imported: str) -> None:
    """The table of radars fits and names every radar whole."""
    table = imported.split("\ntime base:")[0]
    _fits(table)
    for rid in ("NORD", "SUD", "EST3D", "OUEST3D", "APP"):
        assert re.search(rf"│ {rid}\s+│\s+25 │", table), rid


def test_import_asterix_summary_lines(imported: str) -> None:
    """The summary lines (a time-base line of 130 characters) wrap at spaces, every
    number whole."""
    _fits(imported)
    summary = "time base:" + imported.split("\ntime base:")[1]
    assert re.search(r"^time base: seconds since 00:00 UTC", summary, re.MULTILINE)
    assert all(line.startswith("  ") for line in summary.splitlines()
               if not re.match(r"^(time base|ADS-B|blocks|CAT021 editions|skipped|rejected|"
                               r"reports skipped|OpenSky|warning):", line))


# ------------------------------------------------------------------ long radar ids
#: Realistic radar ids: 20 characters, and 43 (about half the terminal).
LONG_IDS = ["LFPG_NORD_SSR_MODE_S", "LFPG_NORD_SSR_MODE_S_CHARLES_DE_GAULLE_NRTH"]


def _renamed(tmp: Path, source: str, old: str, new: str, duration_s: float | None = None,
             n_aircraft: int | None = None) -> Path:
    """A copy of a bundled scenario with radar ``old`` renamed ``new`` (shorter and with
    fewer aircraft when given)."""
    text = (SCENARIOS / source).read_text()
    assert f'id = "{old}"' in text
    text = text.replace(f'id = "{old}"', f'id = "{new}"')
    if duration_s is not None:
        text = re.sub(r"(?m)^duration_s = .*$", f"duration_s = {duration_s}", text, count=1)
    if n_aircraft is not None:
        text = re.sub(r"(?m)^n_aircraft = .*$", f"n_aircraft = {n_aircraft}", text, count=1)
    path = tmp / source
    path.write_text(text)
    return path


def _line_with(text: str, rid: str) -> None:
    """``rid`` printed whole, on one line."""
    assert rid in text.splitlines() or re.search(rf"(^|[\s│]){re.escape(rid)}([\s:.│]|$)",
                                                 text, re.MULTILINE), rid


@pytest.fixture(scope="module", params=LONG_IDS, ids=["id20", "id43"])
def long_demo(request: pytest.FixtureRequest,
              tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, str]:
    """The demo network with radar NORD renamed to a long id, 10 min, calibrated."""
    rid = request.param
    tmp = tmp_path_factory.mktemp("columns80long")
    folder = tmp / "demo"
    _graphcal("simulate", str(_renamed(tmp, "demo_network.toml", "NORD", rid, 600.0, 25)),
              "--out", str(folder), "--seed", "1")
    result = tmp / "r.json"
    _graphcal("calibrate", str(folder), "--out", str(result))
    return folder, result, rid


def test_long_id_calibrate(long_demo: tuple[Path, Path, str]) -> None:
    folder, result, rid = long_demo
    text = _graphcal("calibrate", str(folder))
    _fits(text)
    _line_with(text, rid)
    doc = json.loads(result.read_text())
    assert rid in doc["radars"]
    for name, entry in doc["radars"].items():
        for key, sigma in entry["sigma"].items():
            assert format_value(key, entry[key], sigma) in text, (name, key)


@pytest.mark.parametrize("one", [False, True], ids=["all", "radar"])
def test_long_id_marginals(long_demo: tuple[Path, Path, str], one: bool) -> None:
    """Every value ± 1σ, covariance entry and correlation whole; the pairs' labels too."""
    from graphcal.reporting.tables import strong_correlations

    _, result, rid = long_demo
    argv = ["marginals", str(result), "--correlation"] + (["--radar", rid] if one else [])
    text = _graphcal(*argv)
    _fits(text)
    _line_with(text, rid)
    cal = Calibration.read_json(result)
    tokens = _tokens(text)
    for name in [rid] if one else cal.radar_ids:
        for key, row in zip(cal.marginal_labels(name), cal.marginal(name), strict=True):
            assert format_value(key, cal.value(name, key), cal.sigma(name, key)) in text
            assert {f"{entry:.4g}" for entry in row} <= tokens, (name, key)
    if one:
        assert {f"{r:+.3f}" for r in np.ravel(cal.correlation(rid))} <= tokens
        pairs = strong_correlations(cal, 0.5, rid)
    else:
        rho = cal.correlation()
        assert {f"{r:+.2f}" for r in np.ravel(rho) if abs(r) < 0.999} <= tokens
        pairs = strong_correlations(cal, 0.5)
        assert any(rid in line for line in text.splitlines() if "range_offset_m" in line)
        assert pairs  # range offset and gain of each radar
    for a, b, r in pairs:
        assert f"{r:+.3f}" in tokens
        for label in (a, b):
            name, _, key = label.rpartition(".")
            assert label in text or re.search(rf"{re.escape(name)}\.\s+{key}\b", text), label


def test_long_id_noise(long_demo: tuple[Path, Path, str], tmp_path: Path) -> None:
    """Every estimate whole (``value ± se`` on one line) and equal to the sites written."""
    import tomllib

    folder, _, rid = long_demo
    sites = tmp_path / "sites.toml"
    text = _graphcal("noise", str(folder), "--write-sites", str(sites))
    _fits(text)
    _line_with(text, rid)
    assert len(re.findall(r"\d+\.\d+ ± \d+\.\d+", text)) >= 12
    written = tomllib.loads(sites.read_text())
    radars = written["radar"]
    assert any(site["id"] == rid for site in radars)
    for site in radars:
        assert f"{site['sigma_range_m']:.1f} ± " in text, site["id"]
        assert f"{site['sigma_azimuth_mrad']:.3f} ± " in text, site["id"]


def test_long_id_observability(long_demo: tuple[Path, Path, str], tmp_path: Path) -> None:
    folder, _, rid = long_demo
    out = tmp_path / "o.json"
    text = _graphcal("observability", str(folder), "--out", str(out))
    _fits(text)
    _line_with(text, rid)
    tokens = _tokens(text)
    parameters = json.loads(out.read_text())["parameters"]
    assert any(label.startswith(f"{rid}.") for label in parameters)
    for label, entry in parameters.items():
        assert f"{entry['sigma_alone']:.4g}" in tokens, label
        if entry.get("sigma_joint") is not None:
            assert f"{entry['sigma_joint']:.4g}" in tokens, label


def test_long_id_fuse(long_demo: tuple[Path, Path, str]) -> None:
    """Every track named whole, its numbers on one line: RMSE before and after, the
    improvement and the points."""
    folder, result, rid = long_demo
    text = _graphcal("fuse", str(folder), "--calibration", str(result))
    _fits(text)
    _line_with(text, rid)
    for name in ("fused, covariance weights", "fused, equal weights"):
        assert name in text
    rows = re.findall(r"\d+\.\d\s+\d+\.\d\s+[+-]\d+\.\d %\s+\d+\s*$", text, re.MULTILINE)
    assert len(rows) == 7, text


def test_long_id_fuse_raw(long_demo: tuple[Path, Path, str]) -> None:
    folder, _, rid = long_demo
    text = _graphcal("fuse", str(folder))
    _fits(text)
    _line_with(text, rid)
    assert len(re.findall(r"\d+\.\d\s+[│ ]*\d+\s+[│ ]*\d+\s*[│ ]*$", text, re.MULTILINE)) == 7


@pytest.mark.parametrize("rid", LONG_IDS, ids=["id20", "id43"])
def test_long_id_calibrate_window_and_history(tmp_path: Path, rid: str) -> None:
    folder = tmp_path / "drift"
    _graphcal("simulate", str(_renamed(tmp_path, "demo_drift.toml", "NORD", rid, 4800.0, 15)),
              "--out", str(folder), "--seed", "1")
    result = tmp_path / "r.json"
    # The formatting of windows is the matter here: the quicker pairwise formulation.
    _graphcal("calibrate", str(folder), "--window", "30min", "--cross", "pairwise",
              "--out", str(result),
              "--history", str(tmp_path / "calib.db"))
    text = _graphcal("calibrate", str(folder), "--window", "30min", "--cross", "pairwise")
    _fits(text)
    _line_with(text, rid)
    doc = json.loads(result.read_text())
    for name, entry in doc["radars"].items():
        for key, sigma in entry["sigma"].items():
            assert format_value(key, entry[key], sigma) in text, (name, key)
    # Relative to the folder: the header names the file as given, and a long temporary
    # path alone would pass 80 columns.
    shown = _graphcal("history", "calib.db", cwd=tmp_path)
    _fits(shown)
    assert f"{rid} (" in shown
    for name, windows in doc["series"]["radars"].items():
        for window in windows:
            for key, sigma in window["sigma"].items():
                assert format_value(key, window[key], 2.0 * sigma) in shown, (name, key)


@pytest.mark.parametrize("rid", LONG_IDS, ids=["id20", "id43"])
def test_long_id_compare(tmp_path: Path, rid: str) -> None:
    out = tmp_path / "c.json"
    scenario = _renamed(tmp_path, "paper003_adsb_2d.toml", "R2D", rid)
    text = _graphcal("compare", str(scenario), "--runs", "2", "--methods", "ls,fl,wls,graph",
                     "--out", str(out))
    _fits(text)
    _line_with(text, rid)
    tokens = _tokens(text)
    for row in json.loads(out.read_text())["table"]:
        if row["parameter"]:
            assert re.search(rf"{re.escape(row['radar'])}\s+{row['parameter']}\b", text), row
            assert f"{row['mean']:.4g} ± {row['std']:.3g}" in text, row
            assert f"{row['rmse']:.3g}" in tokens
            assert f"{row['rmse_over_crlb']:.3g}" in tokens


@pytest.mark.parametrize("width", [40, 60, 80])
def test_terminal_tables_never_cut(width: int) -> None:
    """The central guarantee on a made-up table: whatever the width, every cell whole (an
    id longer than a line may fold), no line wider than the width."""
    import io

    from rich.console import Console
    from rich.table import Table

    from graphcal.reporting.tables import terminal_tables

    table = Table(title="a table of long ids")
    for header in ("radar", "parameter", "estimate ± 1σ", "truth", "error/σ"):
        table.add_column(header, justify="right" if header != "radar" else "left",
                         no_wrap=True)
    rows = [(LONG_IDS[1], "range_offset_m", "44.89 ± 1.23", "45.00", "-0.1"),
            ("", "range_gain", "1.975e-04 ± 1.081e-05", "2.000e-04", "-0.2"),
            (LONG_IDS[0], "azimuth_bias_mrad", "1.184 ± 0.015", "1.200", "-1.0")]
    for row in rows:
        table.add_row(*row)
    console = Console(file=io.StringIO(), width=width, color_system=None)
    for item in terminal_tables(table, width):
        console.print(item)
    text = console.file.getvalue()
    assert max(len(line) for line in text.splitlines()) <= width
    assert "…" not in text
    for row in rows:
        for cell in row[1:]:
            assert cell in text, (width, cell)
    if width >= len(LONG_IDS[1]) + 1:
        _line_with(text, LONG_IDS[1])


def test_every_command_table_goes_through_the_guarantee() -> None:
    """A command module that builds a rich table prints it through ``print_tables`` or
    ``terminal_tables`` (graphcal.reporting.tables), which never cut a cell."""
    exempt = {"import_asterix.py"}  # its own layout; test_import_asterix_table checks it
    for path in sorted((ROOT / "graphcal" / "cli").glob("*.py")):
        text = path.read_text()
        if path.name in exempt or not re.search(r"\bTable\(", text):
            continue
        assert "print_tables" in text or "terminal_tables" in text, path.name

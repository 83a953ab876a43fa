"""User and environment errors: one line ``error: <path>: <cause>``, exit status 2, no
traceback, no partial output; outputs never replace a file that appeared meanwhile."""

from __future__ import annotations

import errno
import os
import resource
import signal
import sqlite3
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from tests.paths import SCENARIOS

runner = CliRunner()
SCENARIO = SCENARIOS / "paper002_three_radars.toml"
LONG_SCENARIO = SCENARIOS / "demo_network.toml"


def _one_line_error(result, *words: str, status: int = 2) -> str:
    """The command failed with ``status`` and one ``error:`` line holding ``words``, no
    traceback."""
    assert result.exit_code == status, result.output
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    lines = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, result.output
    assert "Traceback" not in result.output
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def _hidden(folder: Path) -> list[str]:
    """Temporary files or folders left behind (their names start with a dot)."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("env") / "ds"
    result = runner.invoke(app, ["simulate", str(SCENARIO), "--out", str(out), "--seed", "1"])
    assert result.exit_code == 0, result.output
    return out


# ----------------------------------------------------------------- 1. negative seeds


@pytest.mark.parametrize("command", ["simulate", "compare"])
def test_a_negative_seed_is_refused(tmp_path: Path, command: str) -> None:
    args = [command, str(SCENARIO), "--seed=-1"]
    args += ["--out", str(tmp_path / "out")] if command == "simulate" else ["--runs", "1"]
    result = runner.invoke(app, args)
    _one_line_error(result, "--seed -1", "non-negative integer")
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------- 2. --out . and d/..


@pytest.mark.parametrize("name", [".", "d/.."])
@pytest.mark.parametrize("overwrite", [False, True])
def test_simulate_refuses_the_current_folder(tmp_path: Path, monkeypatch, name: str,
                                             overwrite: bool) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "d").mkdir()
    (tmp_path / "keep.txt").write_text("mine")
    args = ["simulate", str(SCENARIO), "--out", name] + (["--overwrite"] if overwrite else [])
    result = runner.invoke(app, args)
    _one_line_error(result, f"--out {name}")
    assert (tmp_path / "keep.txt").read_text() == "mine"
    assert _hidden(tmp_path) == []


# ----------------------------------------------------------------- 3. full disk, file size


def _enospc(monkeypatch) -> None:
    def fsync(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", fsync)


def test_a_full_disk_while_calibrate_writes_its_result(dataset: Path, tmp_path: Path,
                                                       monkeypatch) -> None:
    _enospc(monkeypatch)
    out = tmp_path / "result.json"
    result = runner.invoke(app, ["calibrate", str(dataset), "--out", str(out)])
    line = _one_line_error(result, "disk full")
    assert line == f"error: {out}: disk full"
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_calibrate_writes_its_report(dataset: Path, tmp_path: Path,
                                                       monkeypatch) -> None:
    import graphcal.reporting.html as html

    monkeypatch.setattr(html, "build_report", lambda *a, **k: "<html></html>\n")
    _enospc(monkeypatch)
    report = tmp_path / "report.html"
    result = runner.invoke(app, ["calibrate", str(dataset), "--report", str(report)])
    assert _one_line_error(result) == f"error: {report}: disk full"
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_simulating(tmp_path: Path, monkeypatch) -> None:
    _enospc(monkeypatch)
    out = tmp_path / "sim"
    result = runner.invoke(app, ["simulate", str(SCENARIO), "--out", str(out)])
    _one_line_error(result, str(out), "disk full")
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_correcting(dataset: Path, tmp_path: Path, monkeypatch) -> None:
    def write(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    import pandas as pd

    monkeypatch.setattr(pd.DataFrame, "to_csv", write)
    out = tmp_path / "corrected"
    result = runner.invoke(app, ["correct", str(dataset), str(dataset / "truth.json"),
                                 "--out", str(out)])
    _one_line_error(result, f"{out}/plots.csv: disk full")
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_fusing(dataset: Path, tmp_path: Path, monkeypatch) -> None:
    _enospc(monkeypatch)
    out = tmp_path / "tracks.csv"
    result = runner.invoke(app, ["fuse", str(dataset), "--out", str(out)])
    assert _one_line_error(result) == f"error: {out}: disk full"
    assert list(tmp_path.iterdir()) == []


def _limited(limit: int, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``python -m graphcal ARGS`` with a file-size limit (SIGXFSZ ignored: EFBIG)."""
    def limit_size() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run([sys.executable, "-m", "graphcal", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300, check=False,
                          preexec_fn=limit_size)


@pytest.mark.parametrize(("limit", "args", "named"), [
    (2000, ["simulate", str(SCENARIO), "--out", "sim"], "sim/plots.csv"),
    (5000, ["simulate", str(SCENARIO), "--out", "sim", "--format", "parquet"],
     "sim/plots.parquet"),
    (3000, ["calibrate", "DS", "--out", "result.json"], "result.json"),
])
def test_a_file_size_limit(dataset: Path, tmp_path: Path, limit: int, args: list[str],
                           named: str) -> None:
    args = [str(dataset) if a == "DS" else a for a in args]
    result = _limited(limit, *args, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines()[-1] == f"error: {named}: file too large"
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("code", "cause"), [
    (errno.ENOSPC, "disk full"), (errno.EFBIG, "file too large"),
    (errno.EROFS, "read-only file system"), (errno.EACCES, "permission denied"),
    (errno.EISDIR, "is a folder"), (errno.ENOTDIR, "not a folder")])
def test_os_errors_in_words(dataset: Path, tmp_path: Path, monkeypatch, code: int,
                            cause: str) -> None:
    import graphcal.core.atomic as atomic

    def mkstemp(*args, **kwargs):
        raise OSError(code, os.strerror(code), str(tmp_path / ".result.json.x.tmp"))

    monkeypatch.setattr(atomic.tempfile, "mkstemp", mkstemp)
    out = tmp_path / "result.json"
    result = runner.invoke(app, ["calibrate", str(dataset), "--out", str(out)])
    assert _one_line_error(result).startswith(f"error: {out}: {cause}")


# ----------------------------------------------------------------- 4. no silent replacing


def _appears_meanwhile(monkeypatch, path: Path, text: str = "written by the other") -> None:
    """The output appears (another process writes it) while this one writes its own."""
    fsync = os.fsync

    def racing(fd: int) -> None:
        fsync(fd)
        if not path.exists():
            path.write_text(text)

    monkeypatch.setattr(os, "fsync", racing)


def test_calibrate_does_not_replace_a_result_written_meanwhile(dataset: Path, tmp_path: Path,
                                                               monkeypatch) -> None:
    out = tmp_path / "same.json"
    _appears_meanwhile(monkeypatch, out)
    result = runner.invoke(app, ["calibrate", str(dataset), "--out", str(out)])
    assert _one_line_error(result) == (
        f"error: {out}: exists (written by another process meanwhile); pass --overwrite")
    assert out.read_text() == "written by the other"
    assert _hidden(tmp_path) == []


def test_overwrite_replaces_a_result_written_meanwhile(dataset: Path, tmp_path: Path,
                                                       monkeypatch) -> None:
    out = tmp_path / "same.json"
    _appears_meanwhile(monkeypatch, out)
    result = runner.invoke(app, ["calibrate", str(dataset), "--out", str(out), "--overwrite"])
    assert result.exit_code == 0, result.output
    assert out.read_text().startswith("{")


def test_simulate_does_not_replace_a_folder_written_meanwhile(tmp_path: Path,
                                                              monkeypatch) -> None:
    import graphcal.io.folder as folder

    out = tmp_path / "sim"
    move = folder._move_into_place

    def racing(staging: Path, target: Path, overwrite: bool) -> None:
        target.mkdir()
        (target / "sites.toml").write_text("# the other's\n")
        move(staging, target, overwrite)

    monkeypatch.setattr(folder, "_move_into_place", racing)
    result = runner.invoke(app, ["simulate", str(SCENARIO), "--out", str(out)])
    _one_line_error(result, f"{out}: exists (written by another process meanwhile)")
    assert [p.name for p in out.iterdir()] == ["sites.toml"]
    assert _hidden(tmp_path) == []


def test_two_calibrations_to_one_file_at_once(dataset: Path, tmp_path: Path) -> None:
    """Started together: one writes, the other says the file appeared meanwhile."""
    command = [sys.executable, "-m", "graphcal", "calibrate", str(dataset), "--out", "same.json"]
    runs = [subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outputs = [run.communicate(timeout=300) for run in runs]
    statuses = sorted(run.returncode for run in runs)
    if statuses == [2, 2]:  # the second started after the first had written: refused early
        pytest.skip("the runs did not overlap")
    assert statuses == [0, 2], outputs
    errors = [err for run, (_, err) in zip(runs, outputs, strict=True) if run.returncode == 2]
    assert "same.json: exists" in errors[0]
    assert _hidden(tmp_path) == []


# ----------------------------------------------------------------- 5. history database


_WRITER = """
import sys
from graphcal.pipeline.history import append_run
entry = {"range_offset_m": 1.0, "range_gain": 0.0, "azimuth_bias_mrad": 0.1,
         "elevation_bias_mrad": None, "n_plots": 10,
         "sigma": {"range_offset_m": 0.1, "range_gain": 1e-6, "azimuth_bias_mrad": 0.01}}
result = {"method": "graph", "radars": {f"R{i}": entry for i in range(50)}}
append_run(sys.argv[1], result, provenance={"dataset": "x", "t_start_s": 0.0, "t_end_s": 9.0})
print("ready", flush=True)
while True:
    append_run(sys.argv[1], result, provenance={"dataset": "x", "t_start_s": 0.0,
                                                "t_end_s": 9.0})
"""


def test_a_history_killed_while_writing_still_reads(tmp_path: Path) -> None:
    """SIGKILL at moments in a run of appends: the history reads, with whole runs."""
    for trial, delay in enumerate((0.05, 0.11, 0.17, 0.23, 0.31, 0.37)):
        db = tmp_path / f"h{trial}.db"
        writer = subprocess.Popen([sys.executable, "-c", _WRITER, str(db)],
                                  stdout=subprocess.PIPE, text=True)
        assert writer.stdout.readline().strip() == "ready"
        time.sleep(delay)
        writer.kill()
        writer.communicate()
        result = runner.invoke(app, ["history", str(db), "--csv"])
        assert result.exit_code == 0, (trial, result.output)
        assert "not an SQLite file" not in result.output


def test_a_full_disk_while_appending_to_the_history(tmp_path: Path, monkeypatch) -> None:
    import graphcal.pipeline.history as history

    db = tmp_path / "calib.db"
    entry = {"range_offset_m": 1.0, "range_gain": 0.0, "azimuth_bias_mrad": 0.1,
             "elevation_bias_mrad": None, "n_plots": 10,
             "sigma": {"range_offset_m": 0.1, "range_gain": 1e-6, "azimuth_bias_mrad": 0.01}}
    doc = {"method": "graph", "radars": {f"R{i}": entry for i in range(30)}}
    provenance = {"dataset": "x", "t_start_s": 0.0, "t_end_s": 9.0}
    history.append_run(db, doc, provenance=provenance)
    pages = db.stat().st_size // 4096
    connect = sqlite3.connect

    def small_disk(*args, **kwargs):
        con = connect(*args, **kwargs)
        con.execute(f"PRAGMA max_page_count = {pages}")  # the disk is full at this size
        return con

    monkeypatch.setattr(history.sqlite3, "connect", small_disk)
    with pytest.raises(history.HistoryError) as caught:
        for _ in range(20):
            history.append_run(db, doc, provenance=provenance)
    assert str(caught.value) == f"{db}: disk full"
    monkeypatch.undo()
    assert len(history.read_runs(db)) >= 1  # what was written before stays readable


# ----------------------------------------------------------------- 6., 7. tables


def _copy(dataset: Path, target: Path) -> Path:
    target.mkdir()
    for entry in dataset.iterdir():
        (target / entry.name).write_bytes(entry.read_bytes())
    return target


def test_a_byte_that_is_not_utf8_is_named_by_row_and_field(dataset: Path,
                                                           tmp_path: Path) -> None:
    folder = _copy(dataset, tmp_path / "ds")
    lines = (folder / "plots.csv").read_bytes().split(b"\n")
    header = lines[0].decode().split(",")
    cells = lines[5].split(b",")
    cells[2] = b"\xff" + cells[2]
    lines[5] = b",".join(cells)
    (folder / "plots.csv").write_bytes(b"\n".join(lines))
    result = runner.invoke(app, ["calibrate", str(folder)])
    line = _one_line_error(result, "row 5", f"field '{header[2]}'", "not UTF-8", "line 6")
    assert "position" not in line


@pytest.mark.parametrize(("name", "message"), [
    ("plots.csv", "plots.csv: is a folder, not a table file"),
    ("adsb.csv", "adsb.csv: is a folder, not a table file"),
    ("sites.toml", "sites.toml: is a folder, not a TOML file")])
def test_a_folder_where_a_file_is_wanted(dataset: Path, tmp_path: Path, name: str,
                                         message: str) -> None:
    folder = _copy(dataset, tmp_path / "ds")
    (folder / name).unlink()
    (folder / name).mkdir()
    result = runner.invoke(app, ["calibrate", str(folder)])
    _one_line_error(result, message)


def test_a_binary_sites_file(dataset: Path, tmp_path: Path) -> None:
    folder = _copy(dataset, tmp_path / "ds")
    (folder / "sites.toml").write_bytes(bytes(range(256)))
    result = runner.invoke(app, ["calibrate", str(folder)])
    _one_line_error(result, "sites.toml", "not UTF-8")


# ----------------------------------------------------------------- 8. SIGTERM


def test_sigterm_during_a_chunked_simulation_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "sim"
    run = subprocess.Popen([sys.executable, "-m", "graphcal", "simulate", str(LONG_SCENARIO),
                            "--out", str(out), "--chunk", "60s"], cwd=tmp_path,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not _hidden(tmp_path) and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert _hidden(tmp_path), "the chunked simulation never started writing"
    time.sleep(0.3)
    run.send_signal(signal.SIGTERM)
    _, err = run.communicate(timeout=60)
    assert run.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------- 9. --overwrite


def test_overwrite_never_deletes_a_folder_that_is_not_a_dataset(tmp_path: Path) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    (out / "sites.toml").write_text("# looks like a dataset, but holds more\n")
    result = runner.invoke(app, ["simulate", str(SCENARIO), "--out", str(out), "--overwrite"])
    _one_line_error(result, "not a graphcal dataset", "thesis.tex")
    assert (out / "thesis.tex").read_text() == "years of work"
    (out / "sites.toml").unlink()
    result = runner.invoke(app, ["simulate", str(SCENARIO), "--out", str(out), "--overwrite"])
    _one_line_error(result, "not a graphcal dataset")
    assert (out / "thesis.tex").read_text() == "years of work"


def test_overwrite_replaces_a_dataset(dataset: Path, tmp_path: Path) -> None:
    out = _copy(dataset, tmp_path / "ds")
    result = runner.invoke(app, ["simulate", str(SCENARIO), "--out", str(out), "--overwrite",
                                 "--seed", "2"])
    assert result.exit_code == 0, result.output
    assert "(seed 2)" in result.output


# ----------------------------------------------------------------- 10. warnings


def test_no_raw_numpy_warnings_reach_the_user(dataset: Path, tmp_path: Path) -> None:
    """A dataset of three plots per radar: numpy divides by zero variances inside; the
    user sees graphcal's own warnings only."""
    folder = _copy(dataset, tmp_path / "tiny")
    lines = (folder / "plots.csv").read_text().splitlines()
    (folder / "plots.csv").write_text("\n".join([lines[0], *lines[1:4], *lines[101:104],
                                                 *lines[201:204]]) + "\n")
    adsb = (folder / "adsb.csv").read_text().splitlines()
    (folder / "adsb.csv").write_text("\n".join(adsb[:5]) + "\n")
    result = subprocess.run([sys.executable, "-m", "graphcal", "observability", str(folder)],
                            capture_output=True, text=True, timeout=300, check=False)
    assert "RuntimeWarning" not in result.stderr, result.stderr
    assert "encountered in" not in result.stderr


def test_dask_large_graph_warning_is_silenced() -> None:
    from graphcal.pipeline.schedulers import quiet_large_graphs

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        quiet_large_graphs()
        warnings.warn("Sending large graph of size 12.50 MiB.\nThis may cause some slowdown.",
                      UserWarning, stacklevel=1)
        warnings.warn("another warning", UserWarning, stacklevel=1)
    assert [str(w.message) for w in caught] == ["another warning"]

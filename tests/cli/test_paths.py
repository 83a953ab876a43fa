"""Every command with bad paths: exit status 2, one ``error:`` line, no traceback, nothing
written, and the inputs untouched.

The cases: a missing input; an output in a missing folder; an output onto a folder (or,
for a dataset folder, onto a file or a non-empty folder); an output inside an input
dataset folder (or a dataset folder holding an input); an output file that exists, without
``--overwrite``.  Every check runs before any work,
so the cases take no time.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli import common
from graphcal.cli.app import app
from graphcal.data.bias import RadarBias
from graphcal.io.folder import write_dataset
from tests.paths import SCENARIOS
from tests.synthetic import Track, make_dataset, site_at

runner = CliRunner()

SCENARIO = SCENARIOS / "paper003_adsb_2d.toml"


@dataclass
class Files:
    """The inputs the commands read (a dataset, a result, a scenario, ...) and a scratch
    folder, with the dataset's listing and bytes before the run."""

    root: Path
    ds: Path
    result: Path
    scenario_dir: Path
    scenario: Path
    recording: Path
    db: Path
    plain_file: Path

    def snapshot(self) -> dict[str, bytes]:
        return {str(p.relative_to(self.root)): p.read_bytes()
                for p in sorted(self.root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> Files:
    root = tmp_path_factory.mktemp("paths")
    rng = np.random.default_rng(3)
    tracks = [Track(f"4ca{i:03x}", (rng.uniform(-50e3, 50e3), rng.uniform(-50e3, 50e3), 9e3),
                    (200.0, 50.0, 0.0), 0.0, 300.0) for i in range(3)]
    ds = make_dataset(rng, [(site_at("RA", 0.0, 0.0), RadarBias(50.0, 1e-4, 1e-3)),
                            (site_at("RB", 80e3, 0.0), RadarBias(-30.0, 0.0, -1e-3))], tracks)
    folder = write_dataset(ds, root / "ds")
    result = root / "result.json"
    result.write_text(json.dumps({
        "method": "ls",
        "radars": {"RA": {"range_offset_m": 50.0, "range_gain": None,
                          "azimuth_bias_mrad": None, "elevation_bias_mrad": None,
                          "sigma": {"range_offset_m": 1.0}, "n_plots": 10}},
        "covariance": {"labels": ["RA.range_offset_m"], "matrix": [[1.0]]},
    }))
    scenario_dir = root / "scenarios"
    scenario_dir.mkdir()
    scenario = scenario_dir / SCENARIO.name
    scenario.write_text(SCENARIO.read_text())
    recordings = root / "recordings"
    recordings.mkdir()
    recording = recordings / "rec.ast"
    recording.write_bytes(b"\x30\x00\x03")
    db = root / "calib.db"
    db.write_bytes(b"not a database")
    plain_file = root / "plain.txt"
    plain_file.write_text("a file, not a folder\n")
    (root / "dir.json").mkdir()  # a folder named like each output file
    for suffix in ("csv", "png", "html", "md", "toml"):
        (root / f"dir.{suffix}").mkdir()
    for suffix in ("json", "csv", "png", "html", "md", "toml"):
        (root / f"old.{suffix}").write_text("an earlier output\n")
    return Files(root, folder, result, scenario_dir, scenario, recording, db, plain_file)


def _missing_input(f: Files) -> list[list[str]]:
    nope = str(f.root / "nope")
    out = str(f.root / "new.json")
    return [
        ["simulate", nope + ".toml", "--out", str(f.root / "new-ds")],
        ["calibrate", nope, "--out", out],
        ["calibrate", str(f.ds), "--truth", nope + ".json"],
        ["noise", nope],
        ["fuse", nope],
        ["fuse", str(f.ds), "--calibration", nope + ".json"],
        ["marginals", nope + ".json"],
        ["compare", nope + ".toml", "--runs", "1", "--methods", "ls"],
        ["import-asterix", nope + ".ast", "--out", str(f.root / "new-ds")],
        ["observability", nope],
        ["report", nope + ".json", str(f.ds), "--out", str(f.root / "new.html")],
        ["report", str(f.result), nope, "--out", str(f.root / "new.html")],
        ["report", str(f.result), str(f.ds), "--truth", nope + ".json",
         "--out", str(f.root / "new.html")],
        ["correct", nope, str(f.result), "--out", str(f.root / "new-ds")],
        ["correct", str(f.ds), nope + ".json", "--out", str(f.root / "new-ds")],
        ["history", nope + ".db"],
    ]


def _outputs(f: Files, place) -> list[list[str]]:
    """Every output option of every command, its path given by ``place(suffix)``."""
    ds, res = str(f.ds), str(f.result)
    return [
        ["calibrate", ds, "--out", place(".json")],
        ["calibrate", ds, "--report", place(".html")],
        ["calibrate", ds, "--cat063", place(".json")],
        ["calibrate", ds, "--history", place(".db")],
        ["noise", ds, "--write-sites", place(".toml")],
        ["noise", ds, "--table", place(".csv")],
        ["fuse", ds, "--out", place(".csv")],
        ["observability", ds, "--out", place(".json")],
        ["observability", ds, "--plot", place(".png")],
        ["report", res, ds, "--out", place(".html")],
        ["compare", str(f.scenario), "--runs", "1", "--methods", "ls", "--out", place(".md")],
        ["history", str(f.db), "--plot", place(".png")],
    ]


def _folder_outputs(f: Files, target: Path, *extra: str) -> list[list[str]]:
    """The commands that write a dataset folder, into ``target``."""
    return [
        ["simulate", str(f.scenario), "--out", str(target), *extra],
        ["correct", str(f.ds), str(f.result), "--out", str(target), *extra],
        ["import-asterix", str(f.recording), "--out", str(target), *extra],
    ]


def _cases(f: Files) -> list[tuple[str, list[str]]]:
    missing = f.root / "no-such-folder"
    cases = [("missing input", argv) for argv in _missing_input(f)]
    cases += [("output in a missing folder", argv)
              for argv in _outputs(f, lambda s: str(missing / f"x{s}"))]
    cases += [("output onto a folder", argv)
              for argv in _outputs(f, lambda s: str(f.root / f"dir{s}"))
              if not argv[-1].endswith(".db")]
    cases += [("output inside the input", argv)  # compare reads a file, not a dataset
              for argv in _outputs(f, lambda s: str(f.ds / f"plots{s}"))
              if argv[0] != "compare"]
    cases += [("existing output without --overwrite", argv)  # a history is appended to
              for argv in _outputs(f, lambda s: str(f.root / f"old{s}"))
              if not argv[-1].endswith(".db")]
    # dataset folders: parents are created, but not below a file
    cases += [("output in a missing folder", argv)
              for argv in _folder_outputs(f, f.plain_file / "sub" / "ds")]
    cases += [("output onto a file", argv) for argv in _folder_outputs(f, f.plain_file)]
    cases += [("output onto a non-empty folder", argv)
              for argv in _folder_outputs(f, f.scenario_dir)]
    cases += [("output inside the input", argv)  # simulate reads a file, not a dataset
              for argv in _folder_outputs(f, f.ds / "sub", "--overwrite")
              if argv[0] != "simulate"]
    cases += [("output holding the input", argv)
              for argv in _folder_outputs(f, f.root, "--overwrite")]
    return cases


def test_every_command_is_covered(inputs: Files) -> None:
    """Each command that reads or writes a path appears among the cases."""
    from tests.cli.test_help import COMMANDS

    covered = {argv[0] for _, argv in _cases(inputs)}
    assert covered == set(COMMANDS) - {"methods"}


def test_bad_paths_exit_2_with_one_line_and_write_nothing(inputs: Files) -> None:
    before = inputs.snapshot()
    failures = []
    for what, argv in _cases(inputs):
        result = runner.invoke(app, argv)
        lines = [line for line in result.output.splitlines() if line.strip()]
        ok = (result.exit_code == 2 and "Traceback" not in result.output
              and isinstance(result.exception, SystemExit | None)
              and len(lines) == 1 and lines[0].startswith("error: "))
        if not ok:
            failures.append(f"{what}: graphcal {' '.join(argv)} -> {result.exit_code}: "
                            f"{result.output!r} {result.exception!r}")
    assert not failures, "\n".join(failures)
    assert inputs.snapshot() == before  # no input touched, no output written
    assert not (inputs.root / "no-such-folder").exists()


@pytest.mark.parametrize(("place", "message"), [
    ("dir.json", "is a folder"),
    ("no-such-folder/x.json", "folder"),
    ("ds/plots.csv", "inside the input folder"),
    ("ds", "is a folder"),
])
def test_calibrate_out_messages(inputs: Files, place: str, message: str) -> None:
    result = runner.invoke(app, ["calibrate", str(inputs.ds), "--out",
                                 str(inputs.root / place)])
    assert result.exit_code == 2
    assert message in result.output
    assert f"--out {inputs.root / place}" in result.output


def test_calibrate_out_needs_overwrite(inputs: Files, tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    out.write_text("old\n")
    result = runner.invoke(app, ["calibrate", str(inputs.ds), "--method", "ls",
                                 "--out", str(out)])
    assert result.exit_code == 2
    assert "pass --overwrite" in result.output
    assert out.read_text() == "old\n"
    result = runner.invoke(app, ["calibrate", str(inputs.ds), "--method", "ls",
                                 "--out", str(out), "--overwrite"])
    assert result.exit_code == 0, result.output
    assert set(json.loads(out.read_text())["radars"]) == {"RA", "RB"}


@pytest.mark.parametrize(("command", "option", "suffix"), [
    ("report", "--out", ".html"),
    ("fuse", "--out", ".csv"),
    ("observability", "--out", ".json"),
    ("observability", "--plot", ".png"),
    ("history", "--plot", ".png"),
])
def test_outputs_need_overwrite(inputs: Files, tmp_path: Path, command: str, option: str,
                                suffix: str) -> None:
    """An existing output file: refused (exit 2, one line, untouched), replaced with
    ``--overwrite``, as ``calibrate --out``."""
    if command == "history":
        db = tmp_path / "calib.db"
        made = runner.invoke(app, ["calibrate", str(inputs.ds), "--method", "ls",
                                   "--history", str(db)])
        assert made.exit_code == 0, made.output
        argv = ["history", str(db)]
    else:
        argv = {"report": ["report", str(inputs.result), str(inputs.ds)],
                "fuse": ["fuse", str(inputs.ds)],
                "observability": ["observability", str(inputs.ds)]}[command]
    out = tmp_path / f"old{suffix}"
    out.write_text("an earlier output\n")
    refused = runner.invoke(app, [*argv, option, str(out)])
    assert refused.exit_code == 2, refused.output
    assert refused.output == f"error: {option} {out}: exists; pass --overwrite to replace it\n"
    assert out.read_text() == "an earlier output\n"
    replaced = runner.invoke(app, [*argv, option, str(out), "--overwrite"])
    assert replaced.exit_code == 0, replaced.output
    assert out.read_bytes() != b"an earlier output\n" and out.stat().st_size > 100


def test_two_outputs_on_one_file_are_refused(inputs: Files, tmp_path: Path) -> None:
    same = str(tmp_path / "x.json")
    result = runner.invoke(app, ["calibrate", str(inputs.ds), "--out", same,
                                 "--cat063", same])
    assert result.exit_code == 2
    assert "writes the same file" in result.output


def test_unwritable_folder_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Permission is asked of the OS (``os.access``); as root every folder is writable, so
    the answer is replaced for one folder."""
    locked = tmp_path / "locked"
    locked.mkdir()
    real = os.access
    monkeypatch.setattr(common.os, "access",
                        lambda path, mode: False if Path(path) == locked else real(path, mode))
    result = runner.invoke(app, ["fuse", str(tmp_path), "--out", str(locked / "f.csv")])
    assert result.exit_code == 2
    assert "cannot write in folder" in result.output
    result = runner.invoke(app, ["simulate", str(SCENARIO), "--out", str(locked / "a" / "b")])
    assert result.exit_code == 2
    assert "cannot write in folder" in result.output


@pytest.mark.parametrize(("text", "field"), [
    ('{"radars": 5}', "radars"),
    ('{"radars": {"RA": {"range_offset_m": "fifty"}}}', "radars.RA.range_offset_m"),
    ('{"radars": {"RA": {"range_offset_m": NaN}}}', "radars.RA.range_offset_m"),
    ("not json", None),
])
def test_bad_truth_is_one_line(inputs: Files, tmp_path: Path, text: str,
                               field: str | None) -> None:
    truth = tmp_path / "truth.json"
    truth.write_text(text)
    result = runner.invoke(app, ["calibrate", str(inputs.ds), "--method", "ls",
                                 "--truth", str(truth)])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert result.output.startswith(f"error: {truth}")
    if field is not None:
        assert f"field '{field}'" in result.output


def test_wls_iterations_zero_is_one_line(inputs: Files) -> None:
    result = runner.invoke(app, ["calibrate", str(inputs.ds), "--method", "wls",
                                 "--iterations", "0"])
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and "iterations" in result.output

"""The ``report`` and ``correct`` commands (registered on the app in :mod:`graphcal.cli.app`).

Names from :mod:`graphcal.cli.app` are imported inside the functions so that this
module can be imported by ``cli.py`` itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def report_command(
    result: Annotated[Path, typer.Argument(metavar="RESULT.json", help="Result JSON.")],
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    out: Annotated[Path, typer.Option("--out", help="HTML file to write.")] = Path("report.html"),
    truth: Annotated[
        Path | None,
        typer.Option(help="Truth JSON to compare with (default: DIR/truth.json if present)."),
    ] = None,
) -> None:
    """Write a self-contained HTML report (estimates, residuals, map, correlations)."""
    from graphcal.cli.app import EXIT_BAD_INPUT, _errors_to_exit, _fail, err_console
    from graphcal.data.calibration import Calibration
    from graphcal.io.folder import load_dataset
    from graphcal.reporting.html import write_report_for

    if out.suffix.lower() not in (".html", ".htm"):
        _fail(f"--out {out}: the report is HTML; use a .html suffix", EXIT_BAD_INPUT)
    if out.parent and not out.parent.exists():
        _fail(f"--out {out}: folder {out.parent} does not exist", EXIT_BAD_INPUT)
    with _errors_to_exit():
        cal = Calibration.read_json(result)
        dataset = load_dataset(dataset_dir)
        if truth is not None and not truth.exists():
            _fail(f"{truth}: no such file", EXIT_BAD_INPUT)
        unknown = [rid for rid in cal.radar_ids if rid not in dataset.sites]
        if unknown and len(unknown) == len(cal.radar_ids):
            _fail(f"{result}: none of its radars ({', '.join(unknown)}) is in {dataset_dir}",
                  EXIT_BAD_INPUT)
        write_report_for(cal, dataset, out, truth_path=truth)
    err_console.print(f"wrote {out}", highlight=False)


def correct_command(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder to correct.")],
    result: Annotated[
        Path, typer.Argument(metavar="RESULT.json", help="Result JSON or truth.json.")
    ],
    out: Annotated[Path, typer.Option("--out", help="Corrected dataset folder to write.")],
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output folder.")] = False,
) -> None:
    """Remove the biases of RESULT.json from DIR's plots; write the dataset to --out."""
    from graphcal.cli.app import _errors_to_exit, console
    from graphcal.pipeline.correct import correct_folder

    with _errors_to_exit():
        corrected = correct_folder(dataset_dir, result, out, overwrite=overwrite)
    console.print(
        f"wrote {out}: {len(corrected.plots)} corrected plots of {len(corrected.sites)} radars",
        highlight=False,
    )

"""``graphcal report``: a self-contained HTML report of a result on its dataset."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    FORCE_HELP,
    check_input_path,
    check_output_file,
    command_line,
    err_console,
    errors_to_exit,
    fail,
    print_wrapped,
    progress_bar,
)


def report_command(
    result: Annotated[Path, typer.Argument(metavar="RESULT.json", help="Result JSON.")],
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    out: Annotated[Path, typer.Option("--out", help="HTML file to write.")] = Path("report.html"),
    truth: Annotated[
        Path | None,
        typer.Option(help="Truth JSON to compare with (default: DIR/truth.json if present)."),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --out file.")] = False,
    force: Annotated[bool, typer.Option("--force", help=FORCE_HELP)] = False,
) -> None:
    """Write a self-contained HTML report (estimates, residuals, map, correlations)."""
    from graphcal.data.calibration import Calibration
    from graphcal.io.folder import load_dataset
    from graphcal.reporting.html import write_report_for

    if out.suffix.lower() not in (".html", ".htm"):
        fail(f"--out {out}: the report is HTML; use a .html suffix", EXIT_BAD_INPUT)
    check_input_path(truth, "--truth")
    check_output_file(out, "--out", overwrite=overwrite, inputs=[result, dataset_dir, truth])
    with errors_to_exit():
        cal = Calibration.read_json(result)
        with progress_bar("loading"):
            dataset = load_dataset(dataset_dir, force=force)
        if truth is not None and not truth.exists():
            fail(f"{truth}: no such file", EXIT_BAD_INPUT)
        unknown = [rid for rid in cal.radar_ids if rid not in dataset.sites]
        if unknown and len(unknown) == len(cal.radar_ids):
            fail(f"{result}: none of its radars ({', '.join(unknown)}) is in {dataset_dir}",
                 EXIT_BAD_INPUT)
        with progress_bar("writing the report"):
            write_report_for(cal, dataset, out, truth_path=truth, command=command_line())
    print_wrapped(str(out), err_console, label="wrote")


__all__ = ["report_command"]

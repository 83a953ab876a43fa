"""``graphcal correct``: a dataset folder with a result's biases removed from its plots."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    FORCE_HELP,
    check_input_path,
    check_output_folder,
    console,
    err_console,
    errors_to_exit,
    print_wrapped,
    progress_bar,
)


def correct_command(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder to correct.")],
    result: Annotated[
        Path, typer.Argument(metavar="RESULT.json", help="Result JSON or truth.json.")
    ],
    out: Annotated[Path, typer.Option("--out", help="Corrected dataset folder to write.")],
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output folder.")] = False,
    force: Annotated[bool, typer.Option("--force", help=FORCE_HELP)] = False,
) -> None:
    """Remove the biases of RESULT.json from DIR's plots; write the dataset to --out.

    The plots and ADS-B reports that cleaning drops (duplicates, non-finite values, ...)
    are not written; their counts are printed.
    """
    from graphcal.data.calibration import read_biases
    from graphcal.pipeline.correct import correct_folder

    check_input_path(result, "")
    check_output_folder(out, "--out", overwrite=overwrite, inputs=[dataset_dir, result])
    with errors_to_exit(), progress_bar("correcting"):
        corrected = correct_folder(dataset_dir, result, out, overwrite=overwrite,
                                   force=force)
    if corrected.cleaning is not None:
        for line in corrected.cleaning.summary():
            print_wrapped(f"{line} (not written)", err_console, label="cleaning:")
    print_wrapped(f"{out}: {len(corrected.plots)} corrected plots of "
                  f"{len(corrected.sites)} radars", label="wrote", out=console)
    with errors_to_exit():
        missing = sorted(set(corrected.sites) - set(read_biases(result)))
    if missing:
        print_wrapped(f"{result} has no biases for {', '.join(missing)}: their plots are "
                      "written uncorrected", label="warning:", style="yellow", out=console)


__all__ = ["correct_command"]

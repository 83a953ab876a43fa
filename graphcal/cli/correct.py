"""``graphcal correct``: a dataset folder with a result's biases removed from its plots."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import FORCE_HELP, console, errors_to_exit


def correct_command(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder to correct.")],
    result: Annotated[
        Path, typer.Argument(metavar="RESULT.json", help="Result JSON or truth.json.")
    ],
    out: Annotated[Path, typer.Option("--out", help="Corrected dataset folder to write.")],
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output folder.")] = False,
    force: Annotated[bool, typer.Option("--force", help=FORCE_HELP)] = False,
) -> None:
    """Remove the biases of RESULT.json from DIR's plots; write the dataset to --out."""
    from graphcal.pipeline.correct import correct_folder

    with errors_to_exit():
        corrected = correct_folder(dataset_dir, result, out, overwrite=overwrite,
                                   force=force)
    console.print(
        f"wrote {out}: {len(corrected.plots)} corrected plots of {len(corrected.sites)} radars",
        highlight=False,
    )


__all__ = ["correct_command"]

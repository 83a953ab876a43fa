"""``graphcal fuse``: track, fuse and score the aircraft, with or without a calibration."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    FORCE_HELP,
    check_input_path,
    check_output_file,
    check_positive,
    console,
    err_console,
    errors_to_exit,
    fail,
    print_wrapped,
    progress_bar,
)


def fuse_command(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    calibration: Annotated[
        Path | None,
        typer.Option(metavar="RESULT.json",
                     help="Correct the plots with these biases (a calibrate --out result or a "
                     "truth.json) and compare with the raw plots."),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Write the fused tracks (.csv or .parquet); corrected "
                     "ones when --calibration is given."),
    ] = None,
    q_m2_s3: Annotated[
        float | None,
        typer.Option("--q-m2-s3", help="Tracker acceleration noise density [m^2/s^3] "
                     "(default 100: manoeuvring civil traffic)."),
    ] = None,
    grid_s: Annotated[float, typer.Option(help="Fusion time step [s].")] = 1.0,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --out file.")] = False,
    force: Annotated[bool, typer.Option("--force", help=FORCE_HELP)] = False,
) -> None:
    """Track every aircraft with every radar, fuse the tracks, score them against ADS-B."""
    from graphcal.core.atomic import atomic_write_table
    from graphcal.io.folder import load_dataset
    from graphcal.reporting.tables import fusion_layouts, print_tables
    from graphcal.tracking.fusion import DEFAULT_Q_M2_S3, fuse_dataset, fusion_comparison

    q = DEFAULT_Q_M2_S3 if q_m2_s3 is None else q_m2_s3
    if not (math.isfinite(q) and q >= 0.0):
        fail(f"--q-m2-s3 must be a finite number >= 0 [m^2/s^3], not {q}", EXIT_BAD_INPUT)
    check_positive(grid_s, "--grid-s", "a positive number of seconds")
    if out is not None and out.suffix not in (".csv", ".parquet"):
        fail(f"--out {out}: the suffix must be .csv or .parquet", EXIT_BAD_INPUT)
    check_input_path(calibration, "--calibration")
    check_output_file(out, "--out", overwrite=overwrite, inputs=[dataset_dir, calibration])
    with errors_to_exit():
        with progress_bar("loading"):
            dataset = load_dataset(dataset_dir, force=force)
        with progress_bar("fusing raw plots") as callback:
            raw = fuse_dataset(dataset, None, q_m2_s3=q, grid_s=grid_s, progress=callback)
        corrected = None
        if calibration is not None:
            with progress_bar("fusing corrected plots") as callback:
                corrected = fuse_dataset(dataset, calibration, q_m2_s3=q, grid_s=grid_s,
                                         progress=callback)
    counts = raw.counts
    print_wrapped(
        f"{dataset_dir}: {counts.get('targets', 0)} aircraft, "
        f"{counts.get('grid_points', 0)} fused points every {grid_s:g} s "
        f"({counts.get('grid_points_multi', 0)} from two radars or more); tracker q {q:g} m²/s³",
        console)
    if dataset.adsb is None:
        print_wrapped("no ADS-B table: the tracks cannot be scored", out=console)
    elif corrected is None:
        print_tables(console, fusion_layouts(raw.summary))
    else:
        print_tables(console, fusion_layouts(raw.summary, fusion_comparison(raw, corrected)))
        missing = sorted(set(dataset.sites) - set(corrected.calibrated_radars))
        if missing:
            print_wrapped(f"{calibration} has no biases for {', '.join(missing)}: their "
                          "plots stay raw", label="warning:", style="yellow", out=console)
    if out is not None:
        with errors_to_exit():
            atomic_write_table((corrected or raw).tracks, out)
        print_wrapped(str(out), err_console, label="wrote")


__all__ = ["fuse_command"]

"""``graphcal noise``: every radar's random-error sigmas from its data."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    FORCE_HELP,
    check_distinct_outputs,
    check_output_file,
    console,
    err_console,
    errors_to_exit,
    fail,
    progress_bar,
)


def noise_command(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    method: Annotated[
        str, typer.Option(metavar="auto|adsb|line-fit",
                          help="auto (ADS-B where a radar has enough, else line fits), "
                          "adsb, or line-fit (paper 000's straight legs; no ADS-B needed).")
    ] = "auto",
    sites_out: Annotated[
        Path | None,
        typer.Option("--write-sites", metavar="SITES.toml",
                     help="Write the sites with the estimated sigmas."),
    ] = None,
    only_missing: Annotated[
        bool, typer.Option("--only-missing/--all",
                           help="--write-sites: fill only the sigmas sites.toml lacks, or "
                           "replace all of them (default).")
    ] = False,
    table: Annotated[
        Path | None,
        typer.Option(metavar="TABLE.csv|.parquet",
                     help="Write paper 000's variance lookup table (range x azimuth bins)."),
    ] = None,
    range_bin_km: Annotated[float, typer.Option(help="--table: range bin [km].")] = 50.0,
    azimuth_bin_deg: Annotated[float, typer.Option(help="--table: azimuth bin [deg].")] = 45.0,
    overwrite: Annotated[
        bool, typer.Option(help="Replace existing --write-sites / --table files.")
    ] = False,
    force: Annotated[bool, typer.Option("--force", help=FORCE_HELP)] = False,
) -> None:
    """Estimate every radar's random-error sigmas (range, azimuth, elevation) from its data."""
    import pandas as pd

    from graphcal.core.atomic import atomic_write_table
    from graphcal.io.folder import load_dataset, write_sites
    from graphcal.noise import estimate_noise, sites_with_estimated_sigmas, variance_table
    from graphcal.reporting.tables import noise_table

    modes = {"auto": "auto", "adsb": True, "line-fit": False}
    if method not in modes:
        fail(f"--method must be auto, adsb or line-fit, not '{method}'", EXIT_BAD_INPUT)
    if table is not None and table.suffix not in (".csv", ".parquet"):
        fail(f"--table {table}: the suffix must be .csv or .parquet", EXIT_BAD_INPUT)
    check_output_file(sites_out, "--write-sites", overwrite=overwrite, inputs=[dataset_dir])
    check_output_file(table, "--table", overwrite=overwrite, inputs=[dataset_dir])
    check_distinct_outputs(("--write-sites", sites_out), ("--table", table))
    if not (range_bin_km > 0 and 0 < azimuth_bin_deg <= 360):
        fail("--range-bin-km must be > 0 and --azimuth-bin-deg in (0, 360]", EXIT_BAD_INPUT)
    with errors_to_exit():
        with progress_bar("loading"):
            dataset = load_dataset(dataset_dir, force=force)
        try:
            with progress_bar("estimating the noise") as callback:
                estimates = estimate_noise(dataset, use_adsb=modes[method], progress=callback)
        except ValueError as exc:
            fail(f"{dataset_dir}: {exc}", EXIT_BAD_INPUT)
    console.print(noise_table(dataset.sites, estimates))
    for est in estimates.values():
        if not est.estimated:
            console.print(f"[yellow]warning:[/yellow] {est.radar_id}: not estimated: {est.reason}")
    if sites_out is not None:
        rounded = {rid: _rounded_sigmas(est) for rid, est in estimates.items()}
        sites = sites_with_estimated_sigmas(dataset.sites, rounded, only_missing=only_missing)
        still = [f"{rid} ({', '.join(site.missing_sigmas)})"
                 for rid, site in sites.items() if site.missing_sigmas]
        write_sites(sites, sites_out, plot_altitude=dataset.plot_altitude,
                    epoch_utc=dataset.epoch_utc)  # the [dataset] table kept
        err_console.print(f"wrote {sites_out}", highlight=False)
        if still:
            console.print(f"[yellow]warning:[/yellow] still missing in {sites_out}: "
                          f"{', '.join(still)}")
    if table is not None:
        frames = []
        for rid in dataset.sites:
            try:
                frames.append(variance_table(dataset, rid, range_bin_m=range_bin_km * 1e3,
                                             azimuth_bin_deg=azimuth_bin_deg))
            except ValueError as exc:
                console.print(f"[yellow]warning:[/yellow] {rid}: no lookup table: {exc}")
        if frames:
            atomic_write_table(pd.concat(frames, ignore_index=True), table)
            err_console.print(f"wrote {table}", highlight=False)


def _rounded_sigmas(est):
    """A noise estimate with sigmas rounded for a sites file (0.1 m, 0.001 mrad)."""
    from dataclasses import replace

    el = est.sigma_elevation_mrad
    return replace(est, sigma_range_m=round(est.sigma_range_m, 1),
                   sigma_azimuth_mrad=round(est.sigma_azimuth_mrad, 3),
                   sigma_elevation_mrad=None if el is None else round(el, 3))


__all__ = ["noise_command"]

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
    check_positive,
    console,
    err_console,
    errors_to_exit,
    fail,
    outputs_published_together,
    print_wrapped,
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
    from graphcal.reporting.tables import noise_layouts, print_tables

    modes = {"auto": "auto", "adsb": True, "line-fit": False}
    if method not in modes:
        fail(f"--method must be auto, adsb or line-fit, not '{method}'", EXIT_BAD_INPUT)
    if table is not None and table.suffix not in (".csv", ".parquet"):
        fail(f"--table {table}: the suffix must be .csv or .parquet", EXIT_BAD_INPUT)
    check_output_file(sites_out, "--write-sites", overwrite=overwrite, inputs=[dataset_dir])
    check_output_file(table, "--table", overwrite=overwrite, inputs=[dataset_dir])
    check_distinct_outputs(("--write-sites", sites_out), ("--table", table))
    check_positive(range_bin_km, "--range-bin-km", "a positive number of kilometres")
    if not 0 < azimuth_bin_deg <= 360:  # NaN and infinity too
        fail(f"--azimuth-bin-deg must be a positive number of degrees up to 360, not "
             f"{azimuth_bin_deg}", EXIT_BAD_INPUT)
    with errors_to_exit():
        with progress_bar("loading"):
            dataset = load_dataset(dataset_dir, force=force)
        try:
            with progress_bar("estimating the noise") as callback:
                estimates = estimate_noise(dataset, use_adsb=modes[method], progress=callback)
        except ValueError as exc:
            fail(f"{dataset_dir}: {exc}", EXIT_BAD_INPUT)
    print_tables(console, noise_layouts(dataset.sites, estimates))
    for est in estimates.values():
        if not est.estimated:
            print_wrapped(f"{est.radar_id}: not estimated: {est.reason}", label="warning:",
                          style="yellow", out=console)
        elif "time_offset_s" in est.details:
            tau, sigma = est.details["time_offset_s"], est.details["time_offset_sigma_s"]
            print_wrapped(f"{est.radar_id}: its plots run {tau:+.3f} ± {sigma:.3f} s off the "
                          "ADS-B clock (a time-stamping bias, or the ADS-B's): removed before "
                          "the sigmas were estimated; calibrate estimates it as time_offset_s",
                          label="note:", out=console)
    frames = []
    if table is not None:  # built before any output is written
        for rid in dataset.sites:
            try:
                frames.append(variance_table(dataset, rid, range_bin_m=range_bin_km * 1e3,
                                             azimuth_bin_deg=azimuth_bin_deg))
            except ValueError as exc:
                print_wrapped(f"{rid}: no lookup table: {exc}", label="warning:",
                              style="yellow", out=console)
    still: list[str] = []
    with outputs_published_together():  # both outputs or neither, whatever the signals
        if sites_out is not None:
            rounded = {rid: _rounded_sigmas(est) for rid, est in estimates.items()}
            sites = sites_with_estimated_sigmas(dataset.sites, rounded,
                                                only_missing=only_missing)
            still = [f"{rid} ({', '.join(site.missing_sigmas)})"
                     for rid, site in sites.items() if site.missing_sigmas]
            write_sites(sites, sites_out, plot_altitude=dataset.plot_altitude,
                        epoch_utc=dataset.epoch_utc)  # the [dataset] table kept
            print_wrapped(str(sites_out), err_console, label="wrote")
        if table is not None and frames:
            atomic_write_table(pd.concat(frames, ignore_index=True), table)
            print_wrapped(str(table), err_console, label="wrote")
    if still:
        print_wrapped(f"still missing in {sites_out}: {', '.join(still)}",
                      label="warning:", style="yellow", out=console)


def _rounded_sigmas(est):
    """A noise estimate with sigmas rounded for a sites file (0.1 m, 0.001 mrad)."""
    from dataclasses import replace

    el = est.sigma_elevation_mrad
    return replace(est, sigma_range_m=round(est.sigma_range_m, 1),
                   sigma_azimuth_mrad=round(est.sigma_azimuth_mrad, 3),
                   sigma_elevation_mrad=None if el is None else round(el, 3))


__all__ = ["noise_command"]

"""The ``graphcal`` command line.

Bad input prints one line ``error: <file>, row N, field 'x': what is wrong``
and exits with status 2.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from graphcal.cli.compare import compare_command
from graphcal.cli.import_asterix import import_asterix_command
from graphcal.cli.observability import observability_command
from graphcal.cli.report import correct_command, report_command
from graphcal.core.errors import EstimationError, GraphcalInputError
from graphcal.data.calibration import load_result

app = typer.Typer(
    help="Joint bias calibration of air-surveillance radar networks.",
    no_args_is_help=True,
    add_completion=False,
)
#: Width used when the output is not a terminal (pipes, logs, ``make demo``).
PLAIN_WIDTH = 120
console = Console(width=None if sys.stdout.isatty() else PLAIN_WIDTH)
err_console = Console(stderr=True)

#: Exit status for bad input.
EXIT_BAD_INPUT = 2
#: Exit status when the data do not allow an estimate.
EXIT_ESTIMATION_FAILED = 3


def _fail(message: str, status: int) -> None:
    err_console.print(f"error: {message}", highlight=False, soft_wrap=True, markup=False)
    raise typer.Exit(status)


@contextmanager
def _errors_to_exit():
    """Turn input and estimation errors into one-line messages and exit codes."""
    try:
        yield
    except GraphcalInputError as exc:
        _fail(str(exc), EXIT_BAD_INPUT)
    except EstimationError as exc:
        _fail(str(exc), EXIT_ESTIMATION_FAILED)


@contextmanager
def progress_bar(description: str):
    """A rich progress bar yielding ``callback([stage,] done, total)``; silent off a terminal."""
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=True,
        disable=not err_console.is_terminal,
    )
    with progress:
        task = progress.add_task(description, total=None)

        def callback(*args: object) -> None:
            if len(args) == 3:
                stage, done, total = args
                progress.update(task, description=f"{description}: {stage}")
            else:
                done, total = args
            progress.update(task, completed=done, total=total)

        yield callback


@app.command()
def simulate(
    scenario: Annotated[Path, typer.Argument(help="Scenario TOML file.")],
    out: Annotated[Path, typer.Option("--out", help="Dataset folder to write.")],
    seed: Annotated[int, typer.Option(help="Seed of the random generator.")] = 0,
    fmt: Annotated[str, typer.Option("--format", help="Table format: csv or parquet.")] = "csv",
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output folder.")] = False,
) -> None:
    """Simulate a scenario into a dataset folder plus truth.json."""
    from graphcal.simulation.scenario import load_scenario
    from graphcal.simulation.simulate import simulate as run_simulation
    from graphcal.simulation.simulate import write_simulation

    if fmt not in ("csv", "parquet"):
        _fail(f"--format must be csv or parquet, not '{fmt}'", EXIT_BAD_INPUT)
    with _errors_to_exit():
        spec = load_scenario(scenario)
        rng = np.random.default_rng(seed)
        with progress_bar("simulating") as callback:
            result = run_simulation(spec, rng, progress=callback)
        write_simulation(result, out, fmt=fmt, overwrite=overwrite)
    n_adsb = 0 if result.dataset.adsb is None else len(result.dataset.adsb)
    console.print(
        f"wrote {out}: {len(result.dataset.sites)} radars, {len(result.dataset.plots)} plots, "
        f"{n_adsb} ADS-B reports (seed {seed})"
    )


@app.command()
def calibrate(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    method: Annotated[
        str | None,
        typer.Option(
            help="Estimator: graph (default), ls, fl, fl-ls, wls, wls-pruned "
            "(see 'graphcal methods')."
        ),
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write the result JSON here.")] = None,
    truth: Annotated[
        Path | None,
        typer.Option(help="Truth JSON to compare with (default: DIR/truth.json if present)."),
    ] = None,
    iterations: Annotated[
        int, typer.Option(help="wls/wls-pruned: re-linearisations (1 = the paper's method).")
    ] = 1,
    max_gap_s: Annotated[
        float | None, typer.Option(help="Longest time gap bridged by interpolation [s].")
    ] = None,
    cross: Annotated[
        str, typer.Option(help="graph: cross-radar factors: pairwise, target-state or none.")
    ] = "pairwise",
    robust: Annotated[
        str, typer.Option(help="graph: robust kernel on every measurement: huber, cauchy, none.")
    ] = "huber",
    robust_scale: Annotated[
        float, typer.Option(help="graph: multiplies the kernel's default threshold.")
    ] = 1.0,
    adsb: Annotated[
        bool, typer.Option("--adsb/--no-adsb", help="graph: use the ADS-B table if present.")
    ] = True,
    init: Annotated[
        str, typer.Option(help="graph: initial values: auto, zero, or a closed-form method.")
    ] = "auto",
    fix: Annotated[
        list[str] | None,
        typer.Option(
            metavar="RADAR.KEY=VALUE",
            help="graph: hold a bias at a known value, contract units "
            "(e.g. NORD.range_gain=0, SUD.azimuth_bias_mrad=1.5); repeatable.",
        ),
    ] = None,
    max_iterations: Annotated[
        int, typer.Option(help="graph: Levenberg-Marquardt iteration limit.")
    ] = 100,
    time_offset: Annotated[
        str,
        typer.Option(
            help="graph: estimate each radar's time-stamping bias: auto (with ADS-B, where "
            "the traffic determines it), on, off."
        ),
    ] = "auto",
    report: Annotated[
        Path | None,
        typer.Option("--report", metavar="REPORT.html", help="Also write an HTML report here."),
    ] = None,
    clean: Annotated[
        bool,
        typer.Option(
            "--clean/--no-clean",
            help="Drop duplicate, non-finite, stale and jumping ADS-B records and clear "
            "mislabelled aircraft before estimating (the files are not changed).",
        ),
    ] = True,
    select: Annotated[
        str | None,
        typer.Option(
            "--select", metavar="greedy|e-optimal|d-optimal|random",
            help="Estimate on a selected part of the data: paper 001's greedy pruning, the "
            "E-optimal (largest smallest eigenvalue) or D-optimal (largest log det) subset "
            "of --budget observations, or a random one (see 'graphcal observability "
            "--budget').",
        ),
    ] = None,
    budget: Annotated[
        int | None,
        typer.Option(help="--select: observations to keep (greedy: optional cap)."),
    ] = None,
    select_unit: Annotated[
        str,
        typer.Option(help="--select: choose whole segments of one aircraft's track "
                     "(every radar), whole tracks, or single observations."),
    ] = "segment",
    segment_s: Annotated[
        float, typer.Option(help="--select: segment length [s].")
    ] = 60.0,
    select_seed: Annotated[
        int, typer.Option(help="--select random: seed of the draw.")
    ] = 0,
    linearise: Annotated[
        str,
        typer.Option(
            help="wls/wls-pruned: evaluate the Jacobians at the plots (the paper) or at "
            "each plot's track neighbours (removes the errors-in-variables bias)."
        ),
    ] = "plots",
    cat063: Annotated[
        Path | None,
        typer.Option(
            "--cat063", metavar="FILE",
            help="Also export the biases in ASTERIX CAT063 terms: .json, .csv, or a binary "
            "CAT063 block (.ast/.bin). Radars are identified by SAC/SIC (ids like "
            "SAC025_SIC201, or sac/sic keys in sites.toml).",
        ),
    ] = None,
) -> None:
    """Estimate every radar's biases from a dataset folder."""
    from graphcal.io.folder import load_dataset
    from graphcal.pipeline.calibrate import calibrate as run_calibration
    from graphcal.reporting.tables import calibration_table

    with _errors_to_exit():
        dataset = load_dataset(dataset_dir, clean=clean)
        if dataset.cleaning is not None:
            for line in dataset.cleaning.summary():
                err_console.print(f"cleaning: {line}", highlight=False)
        if method is None:
            method = "graph"
        try:
            fixed = _parse_fix_options(fix or [])
            with progress_bar(_progress_label(method, select)) as callback:
                cal = run_calibration(
                    dataset, method, max_gap_s=max_gap_s, cross=cross, robust=robust,
                    robust_scale=robust_scale, use_adsb=adsb, init=init, fixed=fixed,
                    max_iterations=max_iterations, time_offset=time_offset,
                    iterations=iterations, linearise=linearise, select=select, budget=budget,
                    select_unit=select_unit, segment_s=segment_s, select_seed=select_seed,
                    progress=callback,
                )
        except ValueError as exc:
            _fail(str(exc), EXIT_BAD_INPUT)
        if "selection" in cal.info:
            _print_selection(cal.info["selection"])
        if cat063 is not None:
            from graphcal.io.asterix.cat063 import radar_kinds_from_sites, write_cat063

            try:
                write_cat063(cat063, cal, _radar_codes(dataset.sites),
                             radar_kinds_from_sites(dataset.sites))
            except ValueError as exc:
                _fail(f"--cat063 {cat063}: {exc}", EXIT_BAD_INPUT)
            err_console.print(f"wrote {cat063}", highlight=False)
        if report is not None:
            from graphcal.reporting.html import write_report_for

            if report.suffix != ".html":
                _fail(f"--report {report}: the file must end in .html", EXIT_BAD_INPUT)
            write_report_for(cal, dataset, report, truth_path=truth)
            err_console.print(f"wrote {report}", highlight=False)
        if out is not None:
            cal.write_json(out)
            err_console.print(f"wrote {out}", highlight=False)
            return
        truth_path = truth if truth is not None else dataset_dir / "truth.json"
        truth_data = load_result(truth_path) if truth_path.exists() else None
        console.print(calibration_table(cal, truth_data))
        obs = cal.observability
        console.print(
            f"observability degree {obs.degree:.3g}, rank {obs.rank} of {obs.n_parameters}",
            highlight=False,
        )
        warnings = list(cal.warnings)
        if dataset.cleaning is not None and method != "graph":
            warnings = [w for w in dataset.cleaning.warnings if w not in warnings] + warnings
        for warning in warnings:
            console.print(f"[yellow]warning:[/yellow] {warning}", highlight=False)


def _progress_label(method: str, select: str | None) -> str:
    if select is not None:
        return f"selecting ({select}), {method}"
    return "pruning" if method == "wls-pruned" else method


def _print_selection(summary: dict) -> None:
    """The one-line account of ``calibrate --select``."""
    err_console.print(
        f"selection {summary['method']}: kept {summary['observations_kept']} of "
        f"{summary['observations_total']} observations ({summary['units_kept']} of "
        f"{summary['units_total']} {summary['unit']}s), Deg {summary['degree']:.3g} (all: "
        f"{summary['degree_all']:.3g}), {summary['seconds']:.1f} s", highlight=False,
    )
    for note in summary.get("notes", []):
        err_console.print(f"selection: {note}", highlight=False)


def _radar_codes(sites) -> dict[str, tuple[int, int]]:
    """SAC/SIC per radar from its ``sac``/``sic`` site keys, when given."""
    return {
        rid: (int(site.sac), int(site.sic)) for rid, site in sites.items()
        if getattr(site, "sac", None) is not None and getattr(site, "sic", None) is not None
    }


def _parse_fix_options(items: list[str]) -> dict[str, float]:
    """``--fix RADAR.KEY=VALUE`` (contract units) -> ``{"RADAR.KEY": value}``."""
    fixed = {}
    for item in items:
        target, sep, text = item.partition("=")
        if not sep or "." not in target:
            raise ValueError(f"--fix {item!r}: expected RADAR.KEY=VALUE, e.g. NORD.range_gain=0")
        try:
            fixed[target] = float(text)
        except ValueError:
            raise ValueError(f"--fix {item!r}: value '{text}' is not a number") from None
    return fixed


@app.command()
def noise(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    method: Annotated[
        str, typer.Option(help="auto (ADS-B where a radar has enough, else line fits), "
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
) -> None:
    """Estimate every radar's random-error sigmas (range, azimuth, elevation) from its data."""
    import pandas as pd

    from graphcal.core.atomic import atomic_write_table
    from graphcal.io.folder import load_dataset, write_sites
    from graphcal.noise import estimate_noise, sites_with_estimated_sigmas, variance_table
    from graphcal.reporting.tables import noise_table

    modes = {"auto": "auto", "adsb": True, "line-fit": False}
    if method not in modes:
        _fail(f"--method must be auto, adsb or line-fit, not '{method}'", EXIT_BAD_INPUT)
    for path in (sites_out, table):
        if path is not None and path.exists() and not overwrite:
            _fail(f"{path} exists; pass --overwrite to replace it", EXIT_BAD_INPUT)
    if table is not None and table.suffix not in (".csv", ".parquet"):
        _fail(f"--table {table}: the suffix must be .csv or .parquet", EXIT_BAD_INPUT)
    if not (range_bin_km > 0 and 0 < azimuth_bin_deg <= 360):
        _fail("--range-bin-km must be > 0 and --azimuth-bin-deg in (0, 360]", EXIT_BAD_INPUT)
    with _errors_to_exit():
        dataset = load_dataset(dataset_dir)
        try:
            estimates = estimate_noise(dataset, use_adsb=modes[method])
        except ValueError as exc:
            _fail(f"{dataset_dir}: {exc}", EXIT_BAD_INPUT)
    console.print(noise_table(dataset.sites, estimates))
    for est in estimates.values():
        if not est.estimated:
            console.print(f"[yellow]warning:[/yellow] {est.radar_id}: not estimated: {est.reason}")
    if sites_out is not None:
        rounded = {rid: _rounded_sigmas(est) for rid, est in estimates.items()}
        sites = sites_with_estimated_sigmas(dataset.sites, rounded, only_missing=only_missing)
        still = [f"{rid} ({', '.join(site.missing_sigmas)})"
                 for rid, site in sites.items() if site.missing_sigmas]
        write_sites(sites, sites_out)
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


@app.command()
def fuse(
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
) -> None:
    """Track every aircraft with every radar, fuse the tracks, score them against ADS-B."""
    from graphcal.core.atomic import atomic_write_table
    from graphcal.io.folder import load_dataset
    from graphcal.reporting.tables import fusion_table
    from graphcal.tracking.fusion import DEFAULT_Q_M2_S3, fuse_dataset, fusion_comparison

    q = DEFAULT_Q_M2_S3 if q_m2_s3 is None else q_m2_s3
    if not (q >= 0.0 and grid_s > 0.0):
        _fail("--q-m2-s3 must be >= 0 and --grid-s > 0", EXIT_BAD_INPUT)
    if out is not None and out.suffix not in (".csv", ".parquet"):
        _fail(f"--out {out}: the suffix must be .csv or .parquet", EXIT_BAD_INPUT)
    with _errors_to_exit():
        dataset = load_dataset(dataset_dir)
        with progress_bar("fusing raw plots") as callback:
            raw = fuse_dataset(dataset, None, q_m2_s3=q, grid_s=grid_s, progress=callback)
        corrected = None
        if calibration is not None:
            with progress_bar("fusing corrected plots") as callback:
                corrected = fuse_dataset(dataset, calibration, q_m2_s3=q, grid_s=grid_s,
                                         progress=callback)
    counts = raw.counts
    console.print(
        f"{dataset_dir}: {counts.get('targets', 0)} aircraft, "
        f"{counts.get('grid_points', 0)} fused points every {grid_s:g} s "
        f"({counts.get('grid_points_multi', 0)} from two radars or more); tracker q {q:g} m²/s³",
        highlight=False,
    )
    if dataset.adsb is None:
        console.print("no ADS-B table: the tracks cannot be scored", highlight=False)
    elif corrected is None:
        console.print(fusion_table(raw.summary))
    else:
        console.print(fusion_table(raw.summary, fusion_comparison(raw, corrected)))
        missing = sorted(set(dataset.sites) - set(corrected.calibrated_radars))
        if missing:
            console.print(f"[yellow]warning:[/yellow] {calibration} has no biases for "
                          f"{', '.join(missing)}: their plots stay raw")
    if out is not None:
        atomic_write_table((corrected or raw).tracks, out)
        err_console.print(f"wrote {out}", highlight=False)


@app.command()
def methods() -> None:
    """List the available estimators."""
    from graphcal.solvers.registry import METHODS

    for name, function in METHODS.items():
        summary = (function.__doc__ or "").strip().splitlines()[0]
        console.print(f"{name:12s} {summary}", highlight=False)


@app.command()
def marginals(
    result: Annotated[Path, typer.Argument(metavar="RESULT.json", help="Result JSON.")],
    radar: Annotated[
        str | None, typer.Option("--radar", metavar="ID", help="Only this radar.")
    ] = None,
    correlation: Annotated[
        bool, typer.Option("--correlation", help="Also print correlation coefficients.")
    ] = False,
    min_rho: Annotated[
        float, typer.Option(help="--correlation: list the pairs with |rho| above this.")
    ] = 0.5,
) -> None:
    """Marginal covariance blocks, value ± sigma and correlations from a result JSON."""
    from graphcal.data.calibration import Calibration
    from graphcal.reporting.tables import (
        correlation_block_table,
        correlation_matrix_tables,
        marginal_table,
        strong_correlations,
        strong_correlations_table,
    )

    if not 0.0 <= min_rho < 1.0:
        _fail(f"--min-rho must be in [0, 1), not {min_rho}", EXIT_BAD_INPUT)
    with _errors_to_exit():
        cal = Calibration.read_json(result)
    if radar is not None and radar not in cal.radar_ids:
        _fail(
            f"{result}, field 'radars': no radar '{radar}'; known: {', '.join(cal.radar_ids)}",
            EXIT_BAD_INPUT,
        )
    radar_ids = cal.radar_ids if radar is None else [radar]
    console.print(
        f"{result}: method {cal.method or '?'}, {len(cal.radar_ids)} radars, "
        f"{len(cal.labels)} estimated parameters; units m, fraction, mrad, s",
        highlight=False,
    )
    for rid in radar_ids:
        if not cal.marginal_labels(rid):
            console.print(f"{rid}: no estimated parameters", highlight=False)
            continue
        console.print(marginal_table(cal, rid))
        if correlation and radar is not None:
            console.print(correlation_block_table(cal, rid))
    if not correlation:
        return
    if radar is None:
        for table in correlation_matrix_tables(cal, console.width):
            console.print(table)
        pairs = strong_correlations(cal, min_rho)
        what = "between parameters"
    else:
        pairs = strong_correlations(cal, min_rho, radar)
        what = f"of {radar} with other radars' parameters"
    if pairs:
        console.print(strong_correlations_table(pairs, f"correlations {what}, |ρ| > {min_rho:g}"))
    else:
        console.print(f"no correlations {what} with |ρ| > {min_rho:g}", highlight=False)


app.command(name="compare")(compare_command)
app.command(name="import-asterix")(import_asterix_command)
app.command(name="observability")(observability_command)
app.command(name="report")(report_command)
app.command(name="correct")(correct_command)


def main() -> None:  # pragma: no cover - console entry point
    """Entry point for ``python -m graphcal``."""
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

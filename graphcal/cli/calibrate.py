"""``graphcal calibrate``: every radar's biases from a dataset folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    console,
    err_console,
    errors_to_exit,
    fail,
    progress_bar,
)


def calibrate_command(
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
        float | None, typer.Option(help="Longest time gap bridged by interpolation \\[s].")
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
        float, typer.Option(help="--select: segment length \\[s].")
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
    model_checks: Annotated[
        bool,
        typer.Option(
            "--model-checks/--no-model-checks",
            help="After the estimate, bin each radar's residuals against range \\[km], "
            "elevation \\[deg] or height \\[km], azimuth \\[deg] and time \\[s] and warn "
            "('unmodelled ...') when their structure is beyond chance (false alarms on "
            "under 1 % of radars): refraction, pressure altitudes, antenna eccentricity, a "
            "drifting bias. --no-model-checks skips them.",
        ),
    ] = True,
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
    import time

    from graphcal.data.calibration import load_result
    from graphcal.io.folder import load_dataset
    from graphcal.pipeline.calibrate import calibrate as run_calibration
    from graphcal.reporting.tables import calibration_table

    with errors_to_exit():
        start = time.perf_counter()
        with progress_bar("loading"):
            dataset = load_dataset(dataset_dir, clean=clean)
        load_s = time.perf_counter() - start
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
                    model_checks=model_checks, progress=callback,
                )
        except ValueError as exc:
            fail(str(exc), EXIT_BAD_INPUT)
        cal.info.setdefault("timing_s", {})["load_s"] = load_s
        if "selection" in cal.info:
            _print_selection(cal.info["selection"])
        if cat063 is not None:
            from graphcal.io.asterix.cat063 import radar_kinds_from_sites, write_cat063

            try:
                write_cat063(cat063, cal, _radar_codes(dataset.sites),
                             radar_kinds_from_sites(dataset.sites))
            except ValueError as exc:
                fail(f"--cat063 {cat063}: {exc}", EXIT_BAD_INPUT)
            err_console.print(f"wrote {cat063}", highlight=False)
        if report is not None:
            from graphcal.reporting.html import write_report_for

            if report.suffix != ".html":
                fail(f"--report {report}: the file must end in .html", EXIT_BAD_INPUT)
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


__all__ = ["calibrate_command"]

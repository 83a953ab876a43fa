"""``graphcal calibrate``: every radar's biases from a dataset folder."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.calibrate_options import check_calibrate_options
from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    FORCE_HELP,
    cat063_codes,
    check_distinct_outputs,
    check_input_path,
    check_output_file,
    console,
    err_console,
    errors_to_exit,
    fail,
    outputs_published_together,
    print_wrapped,
    progress_bar,
)

#: ``--cat063`` formats, by suffix.
CAT063_SUFFIXES = (".json", ".csv", ".ast", ".bin")


def calibrate_command(
    ctx: typer.Context,
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    method: Annotated[
        str | None,
        typer.Option(
            metavar="graph|ls|fl|fl-ls|wls|wls-pruned",
            help="Estimator: graph (default), ls, fl, fl-ls, wls, wls-pruned "
            "(see 'graphcal methods')."
        ),
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write the result JSON here.")] = None,
    overwrite: Annotated[
        bool, typer.Option(help="Replace existing --out, --report and --cat063 files.")
    ] = False,
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
        str, typer.Option(metavar="trajectory|pairwise|target-state|none",
                          help="graph: how radars are tied together: trajectory (every "
                          "aircraft's path, the default), pairwise (paper 001's pairs), "
                          "target-state or none.")
    ] = "trajectory",
    robust: Annotated[
        str, typer.Option(metavar="huber|cauchy|none",
                          help="graph: robust kernel on every measurement: huber, cauchy, "
                          "none.")
    ] = "huber",
    robust_scale: Annotated[
        float, typer.Option(help="graph: multiplies the kernel's default threshold.")
    ] = 1.0,
    adsb: Annotated[
        bool, typer.Option("--adsb/--no-adsb", help="graph: use the ADS-B table if present.")
    ] = True,
    init: Annotated[
        str, typer.Option(metavar="auto|zero|ls|fl|fl-ls|wls|wls-pruned",
                          help="graph: initial values: auto, zero, or a closed-form method.")
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
            metavar="auto|on|off",
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
        typer.Option(metavar="segment|track|observation",
                     help="--select: choose whole segments of one aircraft's track "
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
            metavar="plots|neighbours",
            help="wls/wls-pruned: evaluate the Jacobians at the plots (the paper) or at "
            "each plot's track neighbours (removes the errors-in-variables bias)."
        ),
    ] = "plots",
    model_checks: Annotated[
        bool,
        typer.Option(
            "--model-checks/--no-model-checks",
            help="After the estimate, bin each radar's residuals against range [km], "
            "elevation [deg] or height [km], azimuth [deg] and time [s] and warn "
            "('unmodelled ...') when their structure is beyond chance (false alarms on "
            "under 1 % of radars): refraction, pressure altitudes, antenna eccentricity, a "
            "drifting bias. --no-model-checks skips them.",
        ),
    ] = True,
    window: Annotated[
        str | None,
        typer.Option(
            "--window", metavar="DURATION",
            help="Biases over time: calibrate each window (e.g. 15min, 1h, 900s; aligned on "
            "multiples of it) and chain the windows by random walks. The result's radars "
            "are the last window's; it adds series and events (steps found).",
        ),
    ] = None,
    drift: Annotated[
        list[str] | None,
        typer.Option(
            "--drift", metavar="KEY=RATE",
            help="--window: random-walk rate of a bias, contract units per square root of "
            "an hour (e.g. azimuth_bias_mrad=0.5, range_offset_m=2), for every radar; "
            "repeatable. Rates not given are estimated from the data.",
        ),
    ] = None,
    breaks: Annotated[
        list[str] | None,
        typer.Option(
            "--break", metavar="RADAR@TIME",
            help="--window: a known change (maintenance) of a radar at TIME [s, dataset "
            "time base]: its chain is cut there; repeatable.",
        ),
    ] = None,
    steps: Annotated[
        bool,
        typer.Option(
            "--steps/--no-steps",
            help="--window: search for steps beyond the random walk (false alarms: 0.1 % "
            "per radar and recording).",
        ),
    ] = True,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler", metavar="auto|synchronous|forked|threads|processes|ADDRESS",
            help="--window: where windows are calibrated: auto (default: forked for a "
            "large folder on two cores or more, else synchronous), in this process "
            "(synchronous), in this process and a forked copy taking turns (forked), "
            "threads, one process per core (Dask LocalCluster), or the address of a Dask "
            "scheduler (tcp://host:8786).",
        ),
    ] = None,
    history: Annotated[
        Path | None,
        typer.Option(
            "--history", metavar="DB",
            help="Also append this run (provenance and estimates, every window with "
            "--window) to a calibration history database (SQLite; created when missing); "
            "see 'graphcal history'.",
        ),
    ] = None,
    cat063: Annotated[
        Path | None,
        typer.Option(
            "--cat063", metavar="FILE",
            help="Also export the biases in ASTERIX CAT063 terms: .json, .csv, or a binary "
            "CAT063 block (.ast/.bin). Radars are identified by SAC/SIC: --sac-sic, sac/sic "
            "keys in sites.toml, or ids like SAC025_SIC201 (checked before the estimation).",
        ),
    ] = None,
    sac_sic: Annotated[
        list[str] | None,
        typer.Option("--sac-sic", metavar="RADAR=SAC/SIC",
                     help="--cat063: a radar's SAC/SIC (e.g. NORD=25/201); repeatable."),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help=FORCE_HELP)] = False,
) -> None:
    """Estimate every radar's biases from a dataset folder.

    Exit status 3 when the data cannot support the answer, among others when a radar's
    residuals are far beyond their sigmas (the fit verdict, docs/model-checks.md).
    """
    import time

    check_calibrate_options(ctx)
    _check_paths(dataset_dir, truth, out, report, cat063, history, overwrite)
    if window is not None and method in (None, "graph"):
        # A head start: a large folder's first windows are read by a child process
        # while the solvers are imported (pipeline.window_feed).
        from graphcal.pipeline.window_feed import start_reading

        start_reading(dataset_dir, window, clean=clean, force=force)
    from graphcal.pipeline.calibrate import CONSTANT_BATCH_WINDOW_S, is_long_recording

    # A long recording without --window: constant biases from its windows, read one at a
    # time by the pipeline (bounded memory); a report needs the data loaded whole.  Its
    # windows get the same head start.
    constant_windows = (window is None and method in (None, "graph") and select is None
                        and report is None and is_long_recording(dataset_dir))
    if constant_windows:
        from graphcal.pipeline.window_feed import start_reading

        start_reading(dataset_dir, CONSTANT_BATCH_WINDOW_S, clean=clean, force=force)
    from graphcal.io.folder import SITES_FILE, load_dataset, load_epoch_utc, load_sites
    from graphcal.pipeline.calibrate import calibrate as run_calibration

    with errors_to_exit():
        truth_path = truth if truth is not None else dataset_dir / "truth.json"
        truth_data = None
        if out is None and truth_path.exists():  # read (and checked) before the estimation
            truth_data = _read_truth(truth_path)
        start = time.perf_counter()
        if window is not None or constant_windows:
            # Read window by window (bounded memory) by the pipeline: the sites only here.
            dataset = None
            sites = load_sites(dataset_dir / SITES_FILE)
            epoch_utc = load_epoch_utc(dataset_dir / SITES_FILE)  # checked before the work
        else:
            with progress_bar("loading"):
                dataset = load_dataset(dataset_dir, clean=clean, force=force)
            sites = dataset.sites
            epoch_utc = dataset.epoch_utc
        load_s = time.perf_counter() - start
        codes = cat063_codes(cat063, sac_sic, sites, sites if dataset is None
                             else dataset.plots["radar_id"].astype(str).unique())
        if dataset is not None and dataset.cleaning is not None:
            for line in dataset.cleaning.summary():
                print_wrapped(line, err_console, label="cleaning:")
        if method is None:
            method = "graph"
        try:
            fixed = _parse_fix_options(fix or [])
            windowed: dict = {}
            if window is not None:
                windowed = {"window": window, "scheduler": scheduler,
                            "drift": _parse_drift_options(drift or []),
                            "breaks": _parse_break_options(breaks or []),
                            "detect_steps": steps}
            elif drift or breaks or scheduler is not None or not steps:
                given = "--drift" if drift else "--break" if breaks else (
                    "--scheduler" if scheduler is not None else "--no-steps")
                raise ValueError(f"{given} applies to calibrations over time: give --window")
            with progress_bar(_progress_label(method, select)) as callback:
                cal = run_calibration(
                    dataset_dir if dataset is None else dataset, method, max_gap_s=max_gap_s,
                    cross=cross, robust=robust,
                    robust_scale=robust_scale, use_adsb=adsb, init=init, fixed=fixed,
                    max_iterations=max_iterations, time_offset=time_offset,
                    iterations=iterations, linearise=linearise, select=select, budget=budget,
                    select_unit=select_unit, segment_s=segment_s, select_seed=select_seed,
                    model_checks=model_checks and window is None, progress=callback,
                    force=force, **windowed,
                )
        except ValueError as exc:
            fail(str(exc), EXIT_BAD_INPUT)
        cal.info.setdefault("timing_s", {})["load_s"] = load_s
        if "selection" in cal.info:
            _print_selection(cal.info["selection"])
        report_text = None
        if report is not None:  # built first (the slow part), published with the rest
            from graphcal.cli.common import command_line
            from graphcal.reporting.html import build_report_for

            if report.suffix != ".html":
                fail(f"--report {report}: the file must end in .html", EXIT_BAD_INPUT)
            report_text = build_report_for(cal, dataset, truth_path=truth,
                                           command=command_line())
        # Every output at once: a SIGTERM or Ctrl-C meanwhile waits for the last one, so
        # an interruption never leaves some outputs (or a history run) without the others.
        with outputs_published_together():
            if cat063 is not None:
                from graphcal.io.asterix.cat063 import radar_kinds_from_sites, write_cat063

                try:
                    write_cat063(cat063, cal, codes, radar_kinds_from_sites(sites))
                except ValueError as exc:
                    fail(f"--cat063 {cat063}: {exc}", EXIT_BAD_INPUT)
                print_wrapped(str(cat063), err_console, label="wrote")
            if report is not None and report_text is not None:
                from graphcal.core.atomic import atomic_write_text

                atomic_write_text(report, report_text)
                print_wrapped(str(report), err_console, label="wrote")
            if out is not None:
                cal.write_json(out)
                print_wrapped(str(out), err_console, label="wrote")
            if history is not None:  # last: a run in the history means every file is there
                _append_history(history, cal, sites, dataset, dataset_dir, epoch_utc, {
                    "method": method, "window": window, "cross": cross, "robust": robust,
                    "adsb": adsb, "fix": fix or [], "drift": drift or [], "break": breaks or [],
                    "steps": steps, "clean": clean})
        if out is not None:
            obs = cal.observability
            # The table is left out with --out: say so, and where to find it.
            print_wrapped(f"{out}: method {cal.method}, {len(cal.radar_ids)} radars, "
                          f"{len(cal.labels)} estimated parameters, observability degree "
                          f"{obs.degree:.3g}, rank {obs.rank} of {obs.n_parameters}; the "
                          f"table: graphcal marginals {out} (or calibrate without --out)",
                          console)
            _print_warnings(cal, dataset, method)
            return
        if truth_data is not None and cal.series is not None:
            from graphcal.data.bias_schedule import truth_over_windows

            spans = {rid: (entries[-1]["t_start_s"], entries[-1]["t_end_s"])
                     for rid, entries in cal.series["radars"].items()}
            truth_data = truth_over_windows(truth_data, spans)
        if cal.series is not None:
            _print_windows(cal)
        # Imported here: a run with --out prints no table.
        from graphcal.reporting.tables import calibration_tables, sigma_footnote

        for table in calibration_tables(cal, truth_data, console.width):
            console.print(table)
        footnote = sigma_footnote(cal)
        if footnote is not None:  # what the sigmas are (the paper methods)
            print_wrapped(footnote, out=console)
        obs = cal.observability
        print_wrapped(f"observability degree {obs.degree:.3g}, rank {obs.rank} of "
                      f"{obs.n_parameters}", console)
        association = (cal.info or {}).get("association")
        if association:
            print_wrapped(association_line(association["radars"]), console)
        _print_warnings(cal, dataset, method)


def association_line(radars: dict) -> str:
    """One line on the plots without an address: per radar, how many were associated (and
    of them on paths of their own) and the false plots a scan left out
    (``info.association``, docs/association.md)."""
    parts = []
    for rid, f in radars.items():
        part = f"{rid} {f['associated']} of {f['plots']}"
        notes = []
        if f.get("own_paths"):
            notes.append(f"{f['own_paths']} on paths of their own")
        if f.get("false_plots_per_scan") is not None:
            notes.append(f"{f['false_plots_per_scan']:.1f} left out a scan")
        if notes:
            part += f" ({', '.join(notes)})"
        parts.append(part)
    return "plots without an address associated: " + ", ".join(parts)


def _check_paths(dataset_dir: Path, truth: Path | None, out: Path | None,
                 report: Path | None, cat063: Path | None, history: Path | None,
                 overwrite: bool) -> None:
    """Every input and output path, before any work (exit 2 with one line)."""
    check_input_path(truth, "--truth")
    inputs = [dataset_dir, truth]
    check_output_file(out, "--out", overwrite=overwrite, inputs=inputs)
    check_output_file(report, "--report", overwrite=overwrite, inputs=inputs,
                      suffixes=(".html",))
    check_output_file(cat063, "--cat063", overwrite=overwrite, inputs=inputs,
                      suffixes=CAT063_SUFFIXES)
    check_output_file(history, "--history", inputs=inputs)  # appended to, not replaced
    check_distinct_outputs(("--out", out), ("--report", report), ("--cat063", cat063),
                           ("--history", history))


def _read_truth(path: Path) -> dict:
    """A truth JSON for the table, checked (a bad one: exit 2 naming file and field)."""
    from graphcal.data.calibration import load_result, read_biases

    read_biases(path)  # JSON, a radars object, numbers where the contract keys are
    return load_result(path)


def _print_warnings(cal, dataset, method: str) -> None:
    """The estimator's warnings (and the cleaning's for the closed-form methods)."""
    warnings = list(cal.warnings)
    if dataset is not None and dataset.cleaning is not None and method != "graph":
        warnings = [w for w in dataset.cleaning.warnings if w not in warnings] + warnings
    for warning in warnings:
        print_wrapped(warning, label="warning:", style="yellow", out=console)


def _append_history(path: Path, cal, sites, dataset, dataset_dir: Path, epoch_utc,
                    options: dict) -> None:
    """``--history``: the run appended to the calibration history database, with the
    dataset's ``epoch_utc`` (``[dataset] epoch_utc`` of its ``sites.toml``) when known."""
    from graphcal.pipeline.history import append_run

    span = {}
    if cal.series is None:  # with windows the span is that of the series
        times = dataset.plots["time_s"]
        span = {"t_start_s": float(times.min()), "t_end_s": float(times.max())}
    epoch = {} if epoch_utc is None else {"epoch_utc": epoch_utc}
    run_id = append_run(path, cal.to_dict(), provenance={
        "dataset": str(dataset_dir.resolve()),
        "options": options,
        **span,
        **epoch,
        "sensor_models": {rid: site.model for rid, site in sites.items()
                          if getattr(site, "model", None)},
    })
    print_wrapped(f"run {run_id} to {path}", err_console, label="appended")


def _print_windows(cal) -> None:
    """One line on the windows: how many, their span, and that the table is the last."""
    from graphcal.core.durations import format_duration

    series = cal.series
    entries = [e for windows in series["radars"].values() for e in windows]
    first = min(e["t_start_s"] for e in entries)
    last = max(e["t_end_s"] for e in entries)
    last_start = max(e["t_start_s"] for e in entries)
    print_wrapped(
        f"{cal.info['windows']['n_windows']} windows of {format_duration(series['window_s'])}, "
        f"{first:.0f}-{last:.0f} s. Below: the last window ({last_start:.0f}-{last:.0f} s); "
        "every window and the steps: --out JSON.", out=console)


def _progress_label(method: str, select: str | None) -> str:
    if select is not None:
        return f"selecting ({select}), {method}"
    return "pruning" if method == "wls-pruned" else method


def _print_selection(summary: dict) -> None:
    """The one-line account of ``calibrate --select``."""
    print_wrapped(
        f"selection {summary['method']}: kept {summary['observations_kept']} of "
        f"{summary['observations_total']} observations ({summary['units_kept']} of "
        f"{summary['units_total']} {summary['unit']}s), Deg {summary['degree']:.3g} (all: "
        f"{summary['degree_all']:.3g}), {summary['seconds']:.1f} s", err_console)
    for note in summary.get("notes", []):
        print_wrapped(note, err_console, label="selection:")


def _parse_drift_options(items: list[str]) -> dict[str, float]:
    """``--drift KEY=RATE`` -> ``{key: rate}`` (contract units per sqrt(hour))."""
    rates = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep:
            raise ValueError(f"--drift {item!r}: expected KEY=RATE, e.g. azimuth_bias_mrad=0.5")
        try:
            rates[key.strip()] = float(text)
        except ValueError:
            raise ValueError(f"--drift {item!r}: rate '{text}' is not a number") from None
    return rates


def _parse_break_options(items: list[str]) -> dict[str, list[float]]:
    """``--break RADAR@TIME`` -> ``{radar: [time_s, ...]}``."""
    breaks: dict[str, list[float]] = {}
    for item in items:
        rid, sep, text = item.rpartition("@")
        if not sep or not rid:
            raise ValueError(f"--break {item!r}: expected RADAR@TIME, e.g. NORD@43200")
        try:
            time_s = float(text)
        except ValueError:
            raise ValueError(f"--break {item!r}: time '{text}' is not a number of "
                             "seconds") from None
        if not math.isfinite(time_s):
            raise ValueError(f"--break {item!r}: the time must be a finite number of seconds")
        breaks.setdefault(rid, []).append(time_s)
    return breaks


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
        if not math.isfinite(fixed[target]):
            raise ValueError(f"--fix {item!r}: the value must be a finite number")
    return fixed


__all__ = ["calibrate_command"]

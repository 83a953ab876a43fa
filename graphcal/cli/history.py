"""``graphcal history``: each bias over time from a calibration history database.

The database is written by ``calibrate --history`` (:mod:`graphcal.pipeline.history`).
The command prints one table per radar (every window of every run, ``value ± 2σ`` in
contract units, the tolerance and a flag), the detected events, and optionally the
drift plot (:mod:`graphcal.reporting.history_plot`) or the same rows as CSV.
"""

from __future__ import annotations

import math
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    check_output_file,
    console,
    err_console,
    errors_to_exit,
    fail,
    print_wrapped,
)

if TYPE_CHECKING:
    import pandas as pd
    from rich.table import Table

#: Table flag of each tolerance status (``possibly``: the estimate beyond, not its band).
FLAGS: dict[str, str] = {"outside": "OUT", "possibly": "out?"}
#: Columns of ``--csv``.
CSV_COLUMNS: tuple[str, ...] = (
    "run_id", "radar_id", "sensor_model", "t_start_s", "t_end_s", "t_start_utc", "t_end_utc",
    "n_plots", "key", "value", "sigma", "tolerance", "tolerance_source", "status",
)


def parse_since(text: str) -> float | datetime:
    """``--since``: seconds on the dataset time base, or an ISO 8601 time (UTC if naive).

    Raises
    ------
    ValueError
        Neither a finite number nor an ISO 8601 time.
    """
    try:
        seconds = float(text)
    except ValueError:
        pass
    else:
        if math.isfinite(seconds):
            return seconds
        raise ValueError(f"--since {text}: not a finite number of seconds")
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise ValueError(f"--since {text}: expected seconds on the dataset's time base "
                         "(e.g. 32400) or an ISO 8601 UTC time (e.g. 2024-05-01T09:00Z)") from None
    return when if when.tzinfo is not None else when.replace(tzinfo=UTC)


def parse_tolerances(items: list[str] | None) -> dict[str, float]:
    """``--tolerance KEY=VALUE`` options: key -> positive tolerance in the key's unit.

    Raises
    ------
    ValueError
        An item that is not ``KEY=VALUE`` with a positive finite number.
    """
    out: dict[str, float] = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        try:
            value = float(text)
        except ValueError:
            value = None
        if not sep or not key.strip() or value is None:
            raise ValueError(f"--tolerance {item}: expected KEY=VALUE with a positive number "
                             "in the key's unit, e.g. range_offset_m=50")
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"--tolerance {item}: expected KEY=VALUE with a positive number "
                             f"in the key's unit (e.g. range_offset_m=50), not {text.strip()}")
        out[key.strip()] = value
    return out


def _format_time(seconds: float, utc: pd.Timestamp | None) -> str:
    """A window start: UTC ``YYYY-MM-DD HH:MM:SS`` when known, else seconds."""
    if utc is not None:
        return utc.strftime("%Y-%m-%d %H:%M:%S")
    return f"{seconds:.0f}" if seconds == round(seconds) else f"{seconds:.1f}"


def _utc_or_none(value: object) -> pd.Timestamp | None:
    import pandas as pd

    return None if pd.isna(value) else value  # type: ignore[return-value]


def _radar_table(radar: str, rows: pd.DataFrame, utc: bool) -> Table:
    """One radar's windows: run, start, key, value ± 2σ, tolerance, flag."""
    from rich import box
    from rich.table import Table

    from graphcal.reporting.tables import format_value

    models = [m for m in dict.fromkeys(rows["sensor_model"].tolist()) if isinstance(m, str)]
    title = f"{radar} ({', '.join(models)})" if models else radar
    table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, show_edge=False,
                  padding=(0, 0), pad_edge=False)
    table.add_column("from (UTC)" if utc else "from \\[s]", no_wrap=True)
    table.add_column("run", justify="right", no_wrap=True)
    table.add_column("parameter", no_wrap=True)
    table.add_column("value ± 2σ", justify="right", no_wrap=True)
    table.add_column("tol.", justify="right", no_wrap=True)
    table.add_column("flag", no_wrap=True)
    previous = None
    for row in rows.itertuples(index=False):
        window = (row.run_id, row.t_start_s)
        first = window != previous
        previous = window
        sigma = None if math.isnan(row.sigma) else 2.0 * row.sigma
        start = _format_time(row.t_start_s, _utc_or_none(row.t_start_utc) if utc else None)
        table.add_row(
            start if first else "",
            str(row.run_id) if first else "",
            row.key,
            format_value(row.key, row.value, sigma),
            "" if math.isnan(row.tolerance) else f"{row.tolerance:.3g}",
            FLAGS.get(row.status, ""),
        )
    return table


def _event_lines(events: pd.DataFrame, utc: bool) -> list[str]:
    """One line per event: when, run, kind and each parameter's step ± 2σ."""
    from graphcal.pipeline.history import key_unit
    from graphcal.reporting.tables import format_value

    lines = []
    for (_, run_id, time_s, kind), group in events.groupby(
            ["event_id", "run_id", "time_s", "kind"], sort=False):
        when = _format_time(time_s, _utc_or_none(group["time_utc"].iloc[0]) if utc else None)
        parts = []
        for row in group.itertuples(index=False):
            if not isinstance(row.key, str):  # an event without parameters
                continue
            sigma = None if math.isnan(row.sigma) else 2.0 * row.sigma
            size = "?" if math.isnan(row.size) else format_value(row.key, row.size, sigma)
            parts.append(f"{row.key} {size} {key_unit(row.key)}".rstrip())
        detail = f": {'; '.join(parts)}" if parts else ""
        lines.append(f"  {kind} at {when}{'' if utc else ' s'} (run {run_id}){detail}")
    return lines


def _runs_table(runs: pd.DataFrame) -> Table:
    """One row per run: when it ran, method, time span, window, version, dataset."""
    from rich import box
    from rich.table import Table

    table = Table(box=box.SIMPLE_HEAD, show_edge=False, padding=(0, 0), pad_edge=False)
    table.add_column("run", justify="right", no_wrap=True)
    table.add_column("ran (UTC)", no_wrap=True)
    table.add_column("method", no_wrap=True)
    table.add_column("span \\[s]", no_wrap=True)
    table.add_column("window", justify="right", no_wrap=True)
    table.add_column("graphcal", no_wrap=True)
    table.add_column("dataset", overflow="fold")
    for run in runs.itertuples(index=False):
        table.add_row(
            str(run.run_id), run.run_time_utc.strftime("%Y-%m-%d %H:%M"), run.method or "?",
            f"{run.t_start_s:g}-{run.t_end_s:g}",
            "all" if math.isnan(run.window_s) else f"{run.window_s:g} s",
            run.graphcal_version, run.dataset,
        )
    return table


def _print_runs(db: Path, runs: pd.DataFrame, n_radars: int) -> None:
    print_wrapped(f"{db}: {len(runs)} run{'s' if len(runs) != 1 else ''}, {n_radars} "
                  f"radar{'s' if n_radars != 1 else ''}; values ± 2σ in contract units "
                  "(m, fraction, mrad, s)", out=console)
    from graphcal.reporting.tables import print_tables

    print_tables(console, _runs_table(runs))


def _print_tables(db: Path, runs: pd.DataFrame, flagged: pd.DataFrame,
                  events: pd.DataFrame) -> None:
    """The runs, one table per radar with its events, and the flags' meaning."""
    from graphcal.reporting.tables import print_tables

    shown = runs[runs["run_id"].isin(flagged["run_id"])]
    radars = list(dict.fromkeys(flagged["radar_id"]))
    _print_runs(db, shown, len(radars))
    for radar in radars:
        rows = flagged[flagged["radar_id"] == radar]
        utc = bool(rows["t_start_utc"].notna().all())  # UTC when all its runs have an epoch
        radar_events = events[events["radar_id"] == radar]
        console.print()
        print_tables(console, _radar_table(radar, rows, utc))
        lines = _event_lines(radar_events, utc and bool(radar_events["time_utc"].notna().all()))
        if lines:
            console.print("events:", highlight=False)
            for line in lines:
                print_wrapped(line, indent=4, out=console)
    counts = flagged["status"].value_counts()
    console.print()
    print_wrapped(
        f"{counts.get('outside', 0)} OUT (|value| - 2σ > tolerance), "
        f"{counts.get('possibly', 0)} out? (|value| > tolerance, within 2σ of it). "
        "Tolerances: --tolerance, else twice the sensor model's typical bias.", out=console)


def _print_csv(flagged: pd.DataFrame) -> None:
    frame = flagged.loc[:, list(CSV_COLUMNS)].copy()
    for column in ("t_start_utc", "t_end_utc"):
        frame[column] = frame[column].map(
            lambda t: "" if t is None or t != t else t.strftime("%Y-%m-%dT%H:%M:%S.%fZ"))
    sys.stdout.write(frame.to_csv(index=False, na_rep=""))


def _check_plot_path(plot: Path | None, db: Path, overwrite: bool) -> None:
    from graphcal.reporting.history_plot import PLOT_FORMATS

    if plot is None:
        return
    if plot.suffix.lower() not in PLOT_FORMATS:
        fail(f"--plot {plot}: use a {', '.join(PLOT_FORMATS)} suffix", EXIT_BAD_INPUT)
    check_output_file(plot, "--plot", overwrite=overwrite, inputs=[db])


def _check_tolerance_keys(tolerances: dict[str, float], series: pd.DataFrame) -> None:
    from graphcal.pipeline.history import KEY_ORDER

    known = list(dict.fromkeys([*KEY_ORDER, *series["key"]]))
    for key in tolerances:
        if key not in known:
            fail(f"--tolerance {key}: unknown key; known: {', '.join(known)}", EXIT_BAD_INPUT)


def history_command(
    db: Annotated[Path, typer.Argument(metavar="DB", help="History database (calibrate "
                                       "--history).")],
    radar: Annotated[
        str | None, typer.Option("--radar", metavar="ID", help="Only this radar.")
    ] = None,
    since: Annotated[
        str | None,
        typer.Option("--since", metavar="T", help="Only windows ending after T: seconds on "
                     "the dataset time base, or an ISO 8601 UTC time (runs with an epoch)."),
    ] = None,
    plot: Annotated[
        Path | None,
        typer.Option("--plot", metavar="FILE.png", help="Also draw the drift plot (.png, "
                     ".pdf or .svg)."),
    ] = None,
    csv: Annotated[
        bool, typer.Option("--csv", help="Print the windows as CSV instead of tables.")
    ] = False,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --plot file.")] = False,
    tolerance: Annotated[
        list[str] | None,
        typer.Option("--tolerance", metavar="KEY=VALUE", help="Tolerance of a bias in "
                     "its contract unit, e.g. range_offset_m=50 (repeatable; default: "
                     "twice the sensor model's typical bias)."),
    ] = None,
) -> None:
    """Each radar's biases over time with their 2σ band, the events, and the flags."""
    from graphcal.pipeline.history import (
        flag_tolerances,
        read_events,
        read_runs,
        read_series,
    )

    try:
        tolerances = parse_tolerances(tolerance)
        when = None if since is None else parse_since(since)
    except ValueError as exc:
        fail(str(exc), EXIT_BAD_INPUT)
    _check_plot_path(plot, db, overwrite)
    with errors_to_exit():
        runs = read_runs(db)
        series = read_series(db, radar=radar, since=when)
        events = read_events(db, radar=radar, since=when)
        _check_tolerance_keys(tolerances, series)
        flagged = flag_tolerances(series, tolerances)
    if isinstance(when, datetime) and runs["epoch_utc"].isna().any():
        left_out = ", ".join(str(r) for r in runs.loc[runs["epoch_utc"].isna(), "run_id"])
        print_wrapped(f"--since {since} leaves out the runs without a UTC epoch "
                      f"({left_out})", err_console, label="note:")
    if csv:
        _print_csv(flagged)
    elif flagged.empty:
        print_wrapped(f"{db}: no windows{'' if radar is None else f' of {radar}'}"
                      f"{'' if since is None else f' after {since}'}", out=console)
    else:
        _print_tables(db, runs, flagged, events)
    if plot is not None:
        _write_plot(db, flagged, events, plot)


def _write_plot(db: Path, flagged: pd.DataFrame, events: pd.DataFrame, plot: Path) -> None:
    from graphcal.reporting.history_plot import plot_history

    if flagged.empty:
        fail(f"--plot {plot}: no windows to draw", EXIT_BAD_INPUT)
    with errors_to_exit():
        plot_history(flagged, plot, events=events, title=f"{db.name}: biases over time, ± 2σ")
    print_wrapped(str(plot), err_console, label="wrote")


__all__ = ["CSV_COLUMNS", "FLAGS", "history_command", "parse_since", "parse_tolerances"]

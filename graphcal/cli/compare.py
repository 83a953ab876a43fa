"""``graphcal compare``: Monte-Carlo comparison of estimators on a scenario."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    check_count,
    check_output_file,
    check_seed,
    console,
    err_console,
    errors_to_exit,
    fail,
    print_wrapped,
    progress_bar,
)

DEFAULT_METHODS = "ls,fl,fl-ls,wls,wls-pruned,graph"
OUT_SUFFIXES = (".md", ".csv", ".json")


def compare_command(
    scenario: Annotated[Path, typer.Argument(help="Scenario TOML file.")],
    methods: Annotated[
        str, typer.Option(metavar="METHOD,...",
                          help="Comma-separated estimators (see 'graphcal methods').")
    ] = DEFAULT_METHODS,
    runs: Annotated[int, typer.Option(help="Monte-Carlo runs.")] = 20,
    jobs: Annotated[
        int, typer.Option(help="Worker processes (the results do not depend on it).")
    ] = 1,
    seed: Annotated[int, typer.Option(help="Root seed; every run gets its own child seed.")] = 0,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Also write the summary: .md, .csv or .json by the suffix."),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --out file.")] = False,
) -> None:
    """Monte-Carlo comparison: simulate a scenario RUNS times, run every method on each."""
    from graphcal.pipeline.compare import compare
    from graphcal.reporting.tables import print_tables
    from graphcal.simulation.scenario import load_scenario
    from graphcal.solvers.registry import METHODS

    names = [m.strip() for m in methods.split(",") if m.strip()]
    unknown = [m for m in names if m not in METHODS]
    if not names or unknown:
        what = f"unknown method '{unknown[0]}'" if unknown else "no method given"
        fail(f"--methods: {what}; use one of: {', '.join(METHODS)}", EXIT_BAD_INPUT)
    if len(set(names)) != len(names):
        fail(f"--methods: a method is repeated in '{methods}'", EXIT_BAD_INPUT)
    check_count(runs, "--runs", "a positive number of runs")
    check_count(jobs, "--jobs", "a positive number of processes")
    check_seed(seed)
    if out is not None and out.suffix.lower() not in OUT_SUFFIXES:
        fail(f"--out {out}: the format comes from the suffix: .md, .csv or .json",
              EXIT_BAD_INPUT)
    check_output_file(out, "--out", overwrite=overwrite, inputs=[scenario])

    with errors_to_exit():
        spec = load_scenario(scenario)
        with progress_bar(f"compare {spec.name}") as callback:
            result = compare(spec, names, runs, seed=seed, jobs=jobs, progress=callback)
        for table in render_tables(result, console.width):
            print_tables(console, table)
        print_tables(console, render_timing(result))
        print_wrapped(sigma_note(result), out=console)
        for row in result.failures.itertuples(index=False):
            if row.first_error:
                print_wrapped(f"{row.failures} of {row.runs} runs failed; first: "
                              f"{row.first_error}", console, label=f"{row.method}:",
                              style="yellow")
        if out is not None:
            result.write(out)
            print_wrapped(str(out), err_console, label="wrote")


def _num(value: float, digits: int = 4) -> str:
    import numpy as np

    return f"{value:.{digits}g}" if value is not None and np.isfinite(value) else "–"


def render_table(result):
    """A rich table: per method, radar and parameter, the Monte-Carlo summary."""
    from rich.table import Table

    table = Table(
        title=f"{result.scenario}: {result.runs} runs, seed {result.seed} "
        "(units m, fraction, mrad, s)",
        show_lines=False,
    )
    for name, justify in (
        ("method", "left"), ("radar", "left"), ("parameter", "left"), ("truth", "right"),
        ("mean ± std", "right"), ("RMSE", "right"), ("RMSE/√CRLB", "right"),
        ("σ̂/std", "right"), ("failures", "right"), ("status", "left"),
    ):
        table.add_column(name, justify=justify)
    previous = None
    for row in result.table.itertuples(index=False):
        if previous is not None and row.method != previous:
            table.add_section()
        if not row.parameter:  # a method that never gave an estimate
            table.add_row(row.method, "–", "no estimate", "", "", "", "", "",
                          f"{row.failures}/{result.runs}", "failed")
        else:
            table.add_row(
                row.method if row.method != previous else "", row.radar, row.parameter,
                _num(row.truth), f"{_num(row.mean)} ± {_num(row.std, 3)}", _num(row.rmse, 3),
                _num(row.rmse_over_crlb, 3), _num(row.consistency, 3),
                f"{row.failures}/{result.runs}",
                _status_cell(row.status, row.failures, result.runs),
            )
        previous = row.method
    return table


#: Methods whose sigmas are their papers' formal ones.
PAPER_METHODS = ("ls", "fl", "fl-ls", "wls", "wls-pruned")


def sigma_note(result) -> str:
    """The line under the tables: what σ̂/std and the status judge, and which sigmas
    are the papers' formal ones."""
    from graphcal.pipeline.compare import CONSISTENCY_RANGE, MIN_RUNS_JUDGED

    low, high = CONSISTENCY_RANGE
    formal = [m for m in result.methods if m in PAPER_METHODS]
    text = (f"status: σ̂/std outside {low:g}-{high:g} (and its chance spread) is 'sigma too "
            f"small/large', a mean off the truth beyond its spread 'biased' (judged from "
            f"{MIN_RUNS_JUDGED} runs)")
    if formal:
        text += (f"; {', '.join(formal)} report the papers' formal sigmas (ls and fl-ls "
                 "widened by the residuals' per-aircraft spread)")
    return text


def _status_cell(status: str, failures: int, runs: int) -> str:
    """The status column: ``ok``, what the figures show (``sigma too small (σ̂/std
    0.18)``, ``biased (+3.1 std)``), with ``failed K/N`` first when runs failed."""
    prefix = f"failed in {failures} of {runs} runs"
    if status.startswith(prefix):
        rest = status[len(prefix):].lstrip("; ")
        return f"failed {failures}/{runs}" + (f"; {rest}" if rest else "")
    return status


#: Headers of the narrow layout that may break across two lines.
_NARROW_HEADERS = {"RMSE/√CRLB": "RMSE/\n√CRLB"}


def render_tables(result, width: int = 120) -> list:
    """:func:`render_table` laid out for a terminal ``width`` characters wide.

    The one table when it fits; otherwise one compact table per radar and parameter (its
    truth in the title) with a row per method, and one line per method without any
    estimate.  The cells are those of :func:`render_table`: no id or number is cut.
    """
    from rich import box
    from rich.table import Table
    from rich.text import Text

    from graphcal.reporting.tables import table_width

    wide = render_table(result)
    if table_width(wide) <= width:
        return [wide]
    headers = [str(column.header) for column in wide.columns]
    columns = [[str(cell) for cell in column.cells] for column in wide.columns]
    rows = [list(row) for row in zip(*columns, strict=True)]
    method, radar, parameter, truth = (headers.index(name) for name in
                                       ("method", "radar", "parameter", "truth"))
    rest = [i for i in range(len(headers)) if i not in (method, radar, parameter, truth)]
    groups: dict[tuple[str, str], list[list[str]]] = {}
    failed: list[str] = []
    current = ""
    for row in rows:
        current = row[method] or current
        row[method] = current
        if row[radar] in ("", "–"):  # a method that never gave an estimate
            cells = " ".join(row[i] for i in rest if row[i])
            failed.append(f"{row[method]}: {row[parameter] or 'no estimate'} ({cells})")
            continue
        groups.setdefault((row[radar], row[parameter]), []).append(row)
    out: list = []
    for (rid, key), group in groups.items():
        truths = {row[truth] for row in group if row[truth]}
        title = f"{rid} {key}" + (f", truth {truths.pop()}" if len(truths) == 1 else "")
        table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, show_edge=False,
                      pad_edge=False, collapse_padding=True)
        table.add_column("method", no_wrap=True, overflow="fold")
        for i in rest:
            numeric = wide.columns[i].justify == "right"
            table.add_column(_NARROW_HEADERS.get(headers[i], headers[i]),
                             justify=wide.columns[i].justify, no_wrap=numeric,
                             overflow="fold")
        for row in group:
            table.add_row(row[method], *(row[i] for i in rest))
        out.append(table)
    title = wide.title if isinstance(wide.title, str) else ""
    if title:
        out.insert(0, Text(title, overflow="fold"))
    out += [Text(line, overflow="fold") for line in failed]
    return out


def render_timing(result):
    """A rich table of the estimators' mean run time."""
    from rich.table import Table

    table = Table(title=f"run time per method (simulation {result.simulation_s:.3g} s per run)")
    for name in ("method", "mean (s)", "median (s)", "total (s)", "failures"):
        table.add_column(name, justify="left" if name == "method" else "right")
    failures = dict(zip(result.failures["method"], result.failures["failures"], strict=True))
    for row in result.timing.itertuples(index=False):
        table.add_row(row.method, f"{row.mean_s:.3g}", f"{row.median_s:.3g}",
                      f"{row.total_s:.3g}", f"{failures[row.method]}/{row.runs}")
    return table


__all__ = ["compare_command", "render_table", "render_tables", "render_timing"]

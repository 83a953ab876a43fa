"""``graphcal compare``: Monte-Carlo comparison of estimators on a scenario."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    check_output_file,
    console,
    err_console,
    errors_to_exit,
    fail,
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
    from graphcal.simulation.scenario import load_scenario
    from graphcal.solvers.registry import METHODS

    names = [m.strip() for m in methods.split(",") if m.strip()]
    unknown = [m for m in names if m not in METHODS]
    if not names or unknown:
        what = f"unknown method '{unknown[0]}'" if unknown else "no method given"
        fail(f"--methods: {what}; use one of: {', '.join(METHODS)}", EXIT_BAD_INPUT)
    if len(set(names)) != len(names):
        fail(f"--methods: a method is repeated in '{methods}'", EXIT_BAD_INPUT)
    if runs < 1:
        fail(f"--runs must be at least 1, not {runs}", EXIT_BAD_INPUT)
    if jobs < 1:
        fail(f"--jobs must be at least 1, not {jobs}", EXIT_BAD_INPUT)
    if out is not None and out.suffix.lower() not in OUT_SUFFIXES:
        fail(f"--out {out}: the format comes from the suffix: .md, .csv or .json",
              EXIT_BAD_INPUT)
    check_output_file(out, "--out", overwrite=overwrite, inputs=[scenario])

    with errors_to_exit():
        spec = load_scenario(scenario)
        with progress_bar(f"compare {spec.name}") as callback:
            result = compare(spec, names, runs, seed=seed, jobs=jobs, progress=callback)
        console.print(render_table(result))
        console.print(render_timing(result))
        for row in result.failures.itertuples(index=False):
            if row.first_error:
                console.print(
                    f"[yellow]{row.method}[/yellow]: {row.failures} of {row.runs} runs failed; "
                    f"first: {row.first_error}", highlight=False, soft_wrap=True,
                )
        if out is not None:
            result.write(out)
            err_console.print(f"wrote {out}", highlight=False)


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
                "ok" if row.status == "ok" else f"failed {row.failures}/{result.runs}",
            )
        previous = row.method
    return table


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


__all__ = ["compare_command", "render_table", "render_timing"]

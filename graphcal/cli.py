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

from graphcal.calibration import load_result
from graphcal.errors import EstimationError, GraphcalInputError

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
    err_console.print(f"error: {message}", highlight=False, soft_wrap=True)
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
    from graphcal.scenario import load_scenario
    from graphcal.simulate import simulate as run_simulation
    from graphcal.simulate import write_simulation

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


def _default_method(has_adsb: bool) -> str:
    """The method used when none is given."""
    from graphcal.estimators import METHODS

    if "graph" in METHODS:
        return "graph"
    return "fl-ls" if has_adsb else "wls"


@app.command()
def calibrate(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    method: Annotated[
        str | None,
        typer.Option(help="Estimator: ls, fl, fl-ls, wls, wls-pruned (see 'graphcal methods')."),
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
) -> None:
    """Estimate every radar's biases from a dataset folder."""
    from graphcal.dataset import load_dataset
    from graphcal.estimators import get_estimator
    from graphcal.report_table import calibration_table

    with _errors_to_exit():
        dataset = load_dataset(dataset_dir)
        if method is None:
            method = _default_method(dataset.adsb is not None)
            err_console.print(f"method: {method} (default)", highlight=False)
        try:
            estimator = get_estimator(method)
        except ValueError as exc:
            _fail(str(exc), EXIT_BAD_INPUT)
        options: dict = {}
        if max_gap_s is not None:
            options["max_gap_s"] = max_gap_s
        if method.startswith("wls"):
            options["iterations"] = iterations
            with progress_bar("pruning" if method == "wls-pruned" else method) as callback:
                cal = estimator(dataset, progress=callback, **options)
        else:
            cal = estimator(dataset, **options)
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
        for warning in cal.warnings:
            console.print(f"[yellow]warning:[/yellow] {warning}")


@app.command()
def methods() -> None:
    """List the available estimators."""
    from graphcal.estimators import METHODS

    for name, function in METHODS.items():
        summary = (function.__doc__ or "").strip().splitlines()[0]
        console.print(f"{name:12s} {summary}", highlight=False)


def main() -> None:  # pragma: no cover - console entry point
    """Entry point for ``python -m graphcal``."""
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

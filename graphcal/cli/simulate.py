"""``graphcal simulate``: a scenario TOML file to a dataset folder plus truth.json."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    check_input_path,
    check_output_folder,
    check_seed,
    console,
    errors_to_exit,
    fail,
    print_wrapped,
    progress_bar,
)

#: Shortest ``--chunk`` [s]: a radar sweeps once in a few seconds; a shorter chunk only
#: multiplies the files' row groups.
MIN_CHUNK_S = 1.0


def simulate_command(
    scenario: Annotated[Path, typer.Argument(help="Scenario TOML file.")],
    out: Annotated[Path, typer.Option("--out", help="Dataset folder to write.")],
    seed: Annotated[int, typer.Option(help="Seed of the random generator.")] = 0,
    fmt: Annotated[str, typer.Option("--format", metavar="csv|parquet",
                                     help="Table format: csv or parquet.")] = "csv",
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output folder.")] = False,
    chunk: Annotated[str | None, typer.Option(
        "--chunk", metavar="DURATION",
        help="Simulate and write in chunks of this much time (e.g. 1h), holding "
             "one chunk in memory: for long scenarios.")] = None,
) -> None:
    """Simulate a scenario into a dataset folder plus truth.json."""
    import numpy as np

    from graphcal.core.durations import parse_duration
    from graphcal.simulation.scenario import load_scenario
    from graphcal.simulation.simulate import simulate as run_simulation
    from graphcal.simulation.simulate import write_simulation
    from graphcal.simulation.stream import simulate_to_folder

    if fmt not in ("csv", "parquet"):
        fail(f"--format must be csv or parquet, not '{fmt}'", EXIT_BAD_INPUT)
    check_seed(seed)
    check_input_path(scenario, "")
    check_output_folder(out, "--out", overwrite=overwrite, inputs=[scenario])
    chunk_s = None
    if chunk is not None:
        if chunk.strip().startswith("-"):
            fail(f"--chunk must be a positive duration (e.g. 1h), not {chunk}", EXIT_BAD_INPUT)
        try:
            chunk_s = parse_duration(chunk)
        except ValueError as exc:
            fail(f"--chunk: {exc}", EXIT_BAD_INPUT)
        if chunk_s < MIN_CHUNK_S:  # a chunk per sweep or less: millions of chunks
            fail(f"--chunk must be a duration of at least {MIN_CHUNK_S:g} s, not {chunk}",
                 EXIT_BAD_INPUT)
    with errors_to_exit():
        spec = load_scenario(scenario)
        rng = np.random.default_rng(seed)
        with progress_bar("simulating") as callback:
            if chunk_s is None:
                result = run_simulation(spec, rng, progress=callback)
            else:
                streamed = simulate_to_folder(spec, rng, out, fmt=fmt, chunk_s=chunk_s,
                                              overwrite=overwrite, progress=callback)
        if chunk_s is None:
            write_simulation(result, out, fmt=fmt, overwrite=overwrite)
            n_radars, n_plots = len(result.dataset.sites), len(result.dataset.plots)
            n_adsb = 0 if result.dataset.adsb is None else len(result.dataset.adsb)
        else:
            n_radars, n_plots, n_adsb = len(streamed.n_plots), streamed.total_plots, \
                streamed.n_adsb
    print_wrapped(f"{out}: {n_radars} radars, {n_plots} plots, {n_adsb} ADS-B reports "
                  f"(seed {seed})", label="wrote", out=console)


__all__ = ["simulate_command"]

"""``graphcal marginals``: marginal covariances and correlations of a result JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import EXIT_BAD_INPUT, console, errors_to_exit, fail, print_wrapped


def marginals_command(
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
        correlation_block_tables,
        correlation_matrix_tables,
        marginal_tables,
        print_tables,
        strong_correlations,
        strong_correlations_layouts,
    )

    if not 0.0 <= min_rho < 1.0:
        fail(f"--min-rho must be in [0, 1), not {min_rho}", EXIT_BAD_INPUT)
    with errors_to_exit():
        cal = Calibration.read_json(result)
    if radar is not None and radar not in cal.radar_ids:
        fail(
            f"{result}, field 'radars': no radar '{radar}'; known: {', '.join(cal.radar_ids)}",
            EXIT_BAD_INPUT,
        )
    radar_ids = cal.radar_ids if radar is None else [radar]
    heading = (f"{result}: method {cal.method or '?'}, {len(cal.radar_ids)} radars, "
               f"{len(cal.labels)} estimated parameters")
    units = "units m, fraction, mrad, s"
    if len(heading) + 2 + len(units) <= console.width:
        heading, units = f"{heading}; {units}", ""
    print_wrapped(heading, out=console)
    if units:
        print_wrapped(units, out=console)
    for rid in radar_ids:
        if not cal.marginal_labels(rid):
            print_wrapped(f"{rid}: no estimated parameters", out=console)
            continue
        for table in marginal_tables(cal, rid, console.width):
            console.print(table)
        if correlation and radar is not None:
            for table in correlation_block_tables(cal, rid, console.width):
                console.print(table)
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
        print_tables(console, strong_correlations_layouts(
            pairs, f"correlations {what}, |ρ| > {min_rho:g}"))
    else:
        print_wrapped(f"no correlations {what} with |ρ| > {min_rho:g}", out=console)


__all__ = ["marginals_command"]

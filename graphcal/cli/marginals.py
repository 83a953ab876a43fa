"""``graphcal marginals``: marginal covariances and correlations of a result JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import EXIT_BAD_INPUT, console, errors_to_exit, fail


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
        correlation_block_table,
        correlation_matrix_tables,
        marginal_table,
        strong_correlations,
        strong_correlations_table,
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


__all__ = ["marginals_command"]

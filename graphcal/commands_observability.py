"""The ``observability`` command (registered on the app in :mod:`graphcal.cli`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer


def observability_command(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    method: Annotated[
        str, typer.Option(help="Whose observations: graph (ADS-B and pairs) or wls (pairs).")
    ] = "graph",
    adsb: Annotated[
        bool, typer.Option("--adsb/--no-adsb", help="graph: use the ADS-B table if present.")
    ] = True,
    plot: Annotated[
        Path | None,
        typer.Option("--plot", metavar="FILE.png",
                     help="Plot Deg against the number of observations, in time order."),
    ] = None,
    out: Annotated[
        Path | None, typer.Option("--out", metavar="FILE.json", help="Write the figures as JSON.")
    ] = None,
) -> None:
    """How well the traffic determines each bias: rank, condition, Deg, weak directions."""
    import json

    from rich.table import Table

    from graphcal.bias import CONTRACT_KEYS
    from graphcal.cli import (
        EXIT_BAD_INPUT,
        _errors_to_exit,
        _fail,
        console,
        err_console,
    )
    from graphcal.dataset import atomic_write_text, load_dataset
    from graphcal.noise import sites_with_estimated_sigmas
    from graphcal.observability import analyse, degree_curve, observation_blocks

    for path, suffix in ((plot, ".png"), (out, ".json")):
        if path is not None and path.suffix.lower() != suffix:
            _fail(f"{path}: the file must end in {suffix}", EXIT_BAD_INPUT)
    with _errors_to_exit():
        dataset = load_dataset(dataset_dir)
        if any(site.missing_sigmas for site in dataset.sites.values()):
            dataset = sites_with_estimated_sigmas(dataset)
        try:
            blocks = observation_blocks(dataset, method, use_adsb=adsb)
            report = analyse(blocks)
        except ValueError as exc:
            _fail(str(exc), EXIT_BAD_INPUT)
    table = Table(title=f"observability of {dataset_dir} ({method}, {report.n_observations} "
                        "observations)")
    for column in ("radar", "parameter", "σ if the others were known", "σ jointly",
                   "inflation ×"):
        table.add_column(column, justify="left" if column in ("radar", "parameter") else "right")
    previous = None
    for i, (rid, name) in enumerate(report.labels):
        key, scale = CONTRACT_KEYS[name]
        alone, joint = report.sigma_alone[i] * scale, report.sigma_joint[i] * scale
        inflation = np.sqrt(report.inflation[i])
        table.add_row(rid if rid != previous else "", key, f"{alone:.4g}",
                      f"{joint:.4g}" if np.isfinite(joint) else "not determined",
                      f"{inflation:.1f}" if np.isfinite(inflation) else "inf")
        previous = rid
    console.print(table)
    console.print(
        f"rank {report.rank} of {len(report.labels)}, condition {report.condition:.3g}, "
        f"observability degree Deg = {report.degree:.3g} (paper 001 eq. 11)", highlight=False,
    )
    for line in report.weak_directions() + report.confounded():
        console.print(f"[yellow]warning:[/yellow] {line}", highlight=False)
    if out is not None:
        atomic_write_text(out, json.dumps(report.to_dict(), indent=2) + "\n")
        err_console.print(f"wrote {out}", highlight=False)
    if plot is not None:
        _plot_degree(plot, *degree_curve(blocks), title=f"{dataset_dir.name} ({method})")
        err_console.print(f"wrote {plot}", highlight=False)


def _plot_degree(path: Path, time_s, n_obs, degree, title: str) -> None:
    """Deg against the number of observations (log scale), written atomically."""
    import matplotlib

    from graphcal.dataset import atomic_write_stream

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.semilogy(n_obs, np.maximum(degree, 1e-16), marker=".")
    ax.set_xlabel("observations (in time order)")
    ax.set_ylabel("observability degree Deg")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    try:
        atomic_write_stream(path, lambda stream: fig.savefig(stream, format="png", dpi=100,
                                                             bbox_inches="tight"))
    finally:
        plt.close(fig)

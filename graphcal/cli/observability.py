"""``graphcal observability``: how well the traffic determines each bias."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    FORCE_HELP,
    check_choice,
    check_distinct_outputs,
    check_output_file,
    console,
    err_console,
    errors_to_exit,
    fail,
    progress_bar,
)


def observability_command(
    dataset_dir: Annotated[Path, typer.Argument(metavar="DIR", help="Dataset folder.")],
    method: Annotated[
        str, typer.Option(metavar="graph|wls",
                          help="Whose observations: graph (ADS-B and pairs) or wls (pairs).")
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
    budget: Annotated[
        int | None,
        typer.Option(help="Compare the selections of this many observations: greedy (paper "
                     "001 eq. 12), E-optimal, D-optimal and random subsets."),
    ] = None,
    unit: Annotated[
        str, typer.Option(metavar="observation|segment|track",
                          help="--budget: select single observations, segments of one "
                          "aircraft's track, or whole tracks.")
    ] = "segment",
    segment_s: Annotated[float, typer.Option(help="--budget: segment length [s].")] = 60.0,
    random_draws: Annotated[
        int, typer.Option(help="--budget: random subsets drawn for the baseline.")
    ] = 20,
    seed: Annotated[int, typer.Option(help="--budget: seed of the random subsets.")] = 0,
    overwrite: Annotated[
        bool, typer.Option(help="Replace existing --out and --plot files.")
    ] = False,
    force: Annotated[bool, typer.Option("--force", help=FORCE_HELP)] = False,
) -> None:
    """How well the traffic determines each bias: rank, condition, Deg, weak directions."""
    import json

    import numpy as np
    from rich.table import Table

    from graphcal.analysis.observability import analyse, degree_curve, observation_blocks
    from graphcal.core.atomic import atomic_write_text
    from graphcal.data.bias import CONTRACT_KEYS
    from graphcal.io.folder import load_dataset
    from graphcal.noise import fill_missing_sigmas

    for path, suffix in ((plot, ".png"), (out, ".json")):
        if path is not None and path.suffix.lower() != suffix:
            fail(f"{path}: the file must end in {suffix}", EXIT_BAD_INPUT)
    check_choice(method, "--method", ("graph", "wls"), "method")
    check_choice(unit, "--unit", ("observation", "segment", "track"), "selection unit")
    if method == "wls" and not adsb:
        fail("--no-adsb: the wls observations are the radars' common ones; it never uses "
             "ADS-B", EXIT_BAD_INPUT)
    check_output_file(out, "--out", overwrite=overwrite, inputs=[dataset_dir])
    check_output_file(plot, "--plot", overwrite=overwrite, inputs=[dataset_dir])
    check_distinct_outputs(("--out", out), ("--plot", plot))
    with errors_to_exit():
        with progress_bar("loading"):
            dataset = load_dataset(dataset_dir, force=force)
        dataset, _ = fill_missing_sigmas(dataset)
        try:
            with progress_bar("observations"):
                blocks = observation_blocks(dataset, method, use_adsb=adsb)
                report = analyse(blocks)
        except ValueError as exc:
            fail(str(exc), EXIT_BAD_INPUT)
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
    document = report.to_dict()
    if budget is not None:
        with errors_to_exit():
            try:
                with progress_bar(f"selections of {budget} observations") as callback:
                    comparison = _compare(dataset, method, adsb, budget, unit, segment_s,
                                          random_draws, seed, callback)
            except ValueError as exc:
                fail(str(exc), EXIT_BAD_INPUT)
        console.print(_comparison_table(comparison, budget))
        document["selection"] = [
            {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
             for k, v in row.items() if not (isinstance(v, float) and np.isnan(v))}
            for row in comparison.to_dict("records")
        ]
    if out is not None:
        atomic_write_text(out, json.dumps(document, indent=2) + "\n")
        err_console.print(f"wrote {out}", highlight=False)
    if plot is not None:
        _plot_degree(plot, *degree_curve(blocks), title=f"{dataset_dir.name} ({method})")
        err_console.print(f"wrote {plot}", highlight=False)


def _compare(dataset, method: str, adsb: bool, budget: int, unit: str, segment_s: float,
             draws: int, seed: int, progress=None):
    """The selection comparison table (:func:`graphcal.analysis.selection.compare_selections`)."""
    import numpy as np

    from graphcal.analysis.observability import observation_blocks
    from graphcal.analysis.selection import MAX_CONVEX_UNITS, compare_selections, selection_units

    if progress is not None:
        progress("observations", 0, 1)
    blocks = observation_blocks(dataset, method, use_adsb=adsb, linearise="neighbours")
    units = selection_units(blocks, unit, segment_s, MAX_CONVEX_UNITS)
    return compare_selections(units, budget, np.random.default_rng(seed), n_random=draws,
                              progress=progress)


def _comparison_table(comparison, budget: int):
    import numpy as np
    from rich.table import Table

    table = Table(title=f"selections of {budget} observations")
    columns = [("method", "method"), ("units", "units"), ("observations", "observations"),
               ("degree_full_scaling", "Deg"), ("degree", "Deg, own scaling"),
               ("lambda_min", "λmin"),
               ("mean_sigma_ratio", "σ / σ(all), mean"), ("seconds", "time (s)")]
    for _, title in columns:
        table.add_column(title, justify="left" if title == "method" else "right")
    for row in comparison.to_dict("records"):
        cells = []
        for key, _ in columns:
            value = row.get(key)
            if key == "method":
                cells.append(str(value))
            elif value is None or (isinstance(value, float) and np.isnan(value)):
                cells.append("")
            elif key in ("units", "observations"):
                cells.append(f"{int(value)}")
            elif key == "degree" and np.isfinite(row.get("degree_min", np.nan)):
                cells.append(f"{value:.3g} ({row['degree_min']:.2g}-{row['degree_max']:.2g})")
            else:
                cells.append(f"{value:.3g}")
        table.add_row(*cells)
    return table


def _plot_degree(path: Path, time_s, n_obs, degree, title: str) -> None:
    """Deg against the number of observations (log scale), written atomically."""
    import matplotlib
    import numpy as np

    from graphcal.core.atomic import atomic_write_stream

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

"""``graphcal observability``: how well the traffic determines each bias."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    FORCE_HELP,
    check_choice,
    check_count,
    check_distinct_outputs,
    check_output_file,
    check_positive,
    check_seed,
    console,
    err_console,
    errors_to_exit,
    fail,
    print_wrapped,
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

    from graphcal.analysis.observability import (
        analyse,
        degree_curve,
        excluded_parameters_note,
        observation_blocks,
    )
    from graphcal.core.atomic import atomic_write_text
    from graphcal.io.folder import load_dataset
    from graphcal.noise import fill_missing_sigmas
    from graphcal.reporting.tables import print_tables

    for path, suffix in ((plot, ".png"), (out, ".json")):
        if path is not None and path.suffix.lower() != suffix:
            fail(f"{path}: the file must end in {suffix}", EXIT_BAD_INPUT)
    check_choice(method, "--method", ("graph", "wls"), "method")
    check_choice(unit, "--unit", ("observation", "segment", "track"), "selection unit")
    check_count(budget, "--budget", "a positive number of observations")
    check_positive(segment_s, "--segment-s", "a positive number of seconds")
    check_count(random_draws, "--random-draws", "a positive number of draws")
    check_seed(seed)
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
    print_tables(console, _sigma_layouts(
        report, f"observability of {dataset_dir} ({method}, {report.n_observations} "
        "observations)"))
    print_wrapped(
        f"rank {report.rank} of {len(report.labels)}, condition {report.condition:.3g}, "
        f"observability degree Deg = {report.degree:.3g} (paper 001 eq. 11)", out=console)
    note = excluded_parameters_note(dataset, method, use_adsb=adsb)
    if note is not None:
        print_wrapped(f"{len(report.labels)} parameters: {note}", out=console)
    for line in report.weak_directions() + report.confounded():
        print_wrapped(line, label="warning:", style="yellow", out=console)
    document = report.to_dict()
    if note is not None:
        document["excluded"] = note
    if budget is not None:
        with errors_to_exit():
            try:
                with progress_bar(f"selections of {budget} observations") as callback:
                    comparison = _compare(dataset, method, adsb, budget, unit, segment_s,
                                          random_draws, seed, callback)
            except ValueError as exc:
                fail(str(exc), EXIT_BAD_INPUT)
        print_tables(console, _comparison_table(comparison, budget))
        document["selection"] = [
            {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
             for k, v in row.items() if not (isinstance(v, float) and np.isnan(v))}
            for row in comparison.to_dict("records")
        ]
    if out is not None:
        atomic_write_text(out, json.dumps(document, indent=2) + "\n")
        print_wrapped(str(out), err_console, label="wrote")
    if plot is not None:
        _plot_degree(plot, *degree_curve(blocks), title=f"{dataset_dir.name} ({method})")
        print_wrapped(str(plot), err_console, label="wrote")


def _sigma_layouts(report, title: str) -> list:
    """The table of sigmas per radar and parameter, in two layouts for
    :func:`graphcal.reporting.tables.terminal_tables` (headers on one line; on two or three);
    every number on one line."""
    import numpy as np
    from rich.table import Table

    from graphcal.data.bias import CONTRACT_KEYS

    layouts = []
    for headers in (("σ if the others were known", "σ jointly", "inflation ×"),
                    ("σ if the others\nwere known", "σ\njointly", "inflation\n×")):
        table = Table(title=title)
        table.add_column("radar", no_wrap=True)
        table.add_column("parameter", no_wrap=True)
        for header in headers:
            table.add_column(header, justify="right", no_wrap=True)
        previous = None
        for i, (rid, name) in enumerate(report.labels):
            key, scale = CONTRACT_KEYS[name]
            alone, joint = report.sigma_alone[i] * scale, report.sigma_joint[i] * scale
            inflation = np.sqrt(report.inflation[i])
            table.add_row(rid if rid != previous else "", key, f"{alone:.4g}",
                          f"{joint:.4g}" if np.isfinite(joint) else "not determined",
                          f"{inflation:.1f}" if np.isfinite(inflation) else "inf")
            previous = rid
        layouts.append(table)
    return layouts


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

    table = Table(title=f"selections of {budget} observations (obs.: observations kept)")
    columns = [("method", "method"), ("units", "units"), ("observations", "obs."),
               ("degree_full_scaling", "Deg"), ("degree", "Deg,\nown\nscaling"),
               ("lambda_min", "λmin"),
               ("mean_sigma_ratio", "σ/σ(all),\nmean"), ("seconds", "time\n\\[s]")]
    records = comparison.to_dict("records")
    longest_word = max((len(word) for row in records for word in str(row.get("method")).split()),
                       default=6)
    for key, title in columns:
        # numbers whole on one line; the method and a range "(a-b)" may wrap at a space
        table.add_column(title, justify="left" if key == "method" else "right",
                         no_wrap=key not in ("method", "degree"),
                         min_width=longest_word if key == "method" else None)
    for row in records:
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

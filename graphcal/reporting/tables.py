"""Readable tables of calibration results (``value ± sigma``) for the terminal."""

from __future__ import annotations

from typing import Any

from rich.table import Table
from rich.text import Text

from graphcal.data.bias import CONTRACT_KEYS, ECCENTRICITY_NAMES, PARAMETER_NAMES
from graphcal.data.calibration import Calibration

#: Display precision per contract key.
_FORMATS = {
    "range_offset_m": "{:.2f}",
    "range_gain": "{:.3e}",
    "azimuth_bias_mrad": "{:.3f}",
    "elevation_bias_mrad": "{:.3f}",
    "time_offset_s": "{:.3f}",
    "azimuth_sin_mrad": "{:.3f}",
    "azimuth_cos_mrad": "{:.3f}",
    "height_offset_m": "{:.1f}",
    "height_scale": "{:.5f}",
}


def format_value(key: str, value: float | None, sigma: float | None = None) -> str:
    """``value ± sigma`` in the key's precision; '-' when not estimated."""
    if value is None:
        return "-"
    fmt = _FORMATS.get(key, "{:.4g}")
    text = fmt.format(value)
    if sigma is None:
        return text
    if sigma != sigma or sigma == float("inf"):
        return f"{text} ± undetermined"
    return f"{text} ± {fmt.format(sigma)}"


#: Parameters shown only for the radars that estimate them.
OPTIONAL_ROWS: tuple[str, ...] = ("time_offset", *ECCENTRICITY_NAMES)


def _value_row(cal: Calibration, label: str, key: str, value: float, sigma: float | None,
               efficiency: dict[str, Any], truth: bool, true: float | None) -> list[str]:
    """One parameter's row: key, estimate ± 1 sigma (or "not determined"), [σ/CRLB],
    [truth, error/σ].

    ``label`` names the parameter in ``info`` (``"NORD.range_offset_m"``,
    ``"atmosphere.height_scale"``); ``truth``: whether the truth columns are shown,
    ``true`` the true value (``None``: unknown).  error/σ is left empty without a
    finite, non-zero sigma.
    """
    shown = format_value(key, value, sigma)
    if label in cal.info.get("undetermined", []):
        shown = f"not determined (prior ± {_FORMATS.get(key, '{:.4g}').format(sigma)})"
    row = [key, shown]
    if efficiency:
        ratio = efficiency.get(label)
        row.append("" if ratio is None else f"{ratio:.2f}")
    if truth:
        row.append(format_value(key, true))
        finite = sigma is not None and sigma == sigma and sigma not in (0.0, float("inf"))
        row.append(f"{(value - true) / sigma:+.1f}" if true is not None and finite else "")
    return row


def _radar_rows(cal: Calibration, rid: str, efficiency: dict[str, Any],
                truth: dict[str, Any] | None) -> list[list[str]]:
    """One radar's rows: parameter, estimate ± 1 sigma, [σ/CRLB], [truth, error/σ]."""
    rows = []
    true_radars = (truth or {}).get("radars", {})
    for name in (*PARAMETER_NAMES, *ECCENTRICITY_NAMES, "time_offset"):
        key = CONTRACT_KEYS[name][0]
        value, sigma = cal.value(rid, key), cal.sigma(rid, key)
        if value is None or (name in OPTIONAL_ROWS and not sigma):
            continue
        true = true_radars.get(rid, {}).get(key)
        if true is None and name in OPTIONAL_ROWS and rid in true_radars:
            true = 0.0  # truth.json leaves out a zero time offset or eccentricity
        rows.append(_value_row(cal, f"{rid}.{key}", key, value, sigma, efficiency,
                               truth is not None, true))
    return rows


def _value_columns(table: Table, efficiency: bool, truth: bool) -> None:
    """The columns after the radar: parameter, estimate, [σ/CRLB], [truth, error/σ]."""
    table.add_column("parameter", no_wrap=True)
    table.add_column("estimate ± 1σ", justify="right", overflow="fold")
    if efficiency:
        table.add_column("σ/CRLB", justify="right", overflow="fold")
    if truth:
        table.add_column("truth", justify="right", overflow="fold")
        table.add_column("error/σ", justify="right", overflow="fold")


def calibration_table(cal: Calibration, truth: dict[str, Any] | None = None) -> Table:
    """A table: one row per radar and parameter, estimate ± 1 sigma, truth if given."""
    table = Table(title=f"graphcal calibration, method {cal.method}")
    table.add_column("radar", overflow="fold")
    efficiency = cal.info.get("efficiency") or {}
    _value_columns(table, bool(efficiency), truth is not None)
    table.add_column("plots", justify="right", overflow="fold")
    for rid in cal.radar_ids:
        for i, row in enumerate(_radar_rows(cal, rid, efficiency, truth)):
            first = i == 0
            table.add_row(rid if first else "", *row,
                          str(cal.n_plots.get(rid, "")) if first else "")
    if cal.atmosphere is not None:
        _atmosphere_rows(table, cal, efficiency, truth)
    return table


def calibration_tables(cal: Calibration, truth: dict[str, Any] | None = None,
                       width: int = 120) -> list[Table | Text]:
    """The calibration table laid out for a terminal ``width`` characters wide.

    :func:`calibration_table` when it fits; otherwise one compact table per radar
    (its id and plot count in the title, no radar and plots columns) and one for the
    atmosphere; and when even those do not fit, a list: per radar its title, then per
    parameter its key and one line per field (``value ± sigma``, ``σ/CRLB r``,
    ``truth t``, ``error/σ z``).  No id or number is ever cut.
    """
    from rich import box
    from rich.console import Console
    from rich.measure import Measurement

    console = Console(width=100_000)  # to measure a table's natural width

    def fits(table: Table) -> bool:
        return Measurement.get(console, console.options, table).maximum <= width

    wide = calibration_table(cal, truth)
    if fits(wide):
        return [wide]
    efficiency = cal.info.get("efficiency") or {}
    groups = [(f"{rid}: {cal.n_plots.get(rid, 0)} plots, method {cal.method}",
               _radar_rows(cal, rid, efficiency, truth)) for rid in cal.radar_ids]
    if cal.atmosphere is not None:
        groups.append(("atmosphere (height model of pressure altitudes)",
                       _atmosphere_value_rows(cal, efficiency, truth)))
    tables = []
    for title, rows in groups:
        table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD,
                      show_edge=False, pad_edge=False)
        _value_columns(table, bool(efficiency), truth is not None)
        for row in rows:
            table.add_row(*row)
        tables.append(table)
    if all(fits(table) for table in tables):
        return tables
    names = ["", "σ/CRLB"] if efficiency else [""]
    if truth is not None:
        names += ["truth", "error/σ"]
    blocks = []
    for title, rows in groups:
        lines = [title]
        for key, *values in rows:
            fields = [f"{name} {value}".strip() for name, value in zip(names, values,
                                                                         strict=True) if value]
            lines += [f"  {key}", *(f"    {field}" for field in fields)]
        blocks.append(Text("\n".join(lines), overflow="fold"))
    return blocks


def _atmosphere_rows(
    table: Table, cal: Calibration, efficiency: dict[str, Any], truth: dict[str, Any] | None
) -> None:
    """The height model of pressure altitudes, under the radars (``atmosphere`` rows)."""
    for i, row in enumerate(_atmosphere_value_rows(cal, efficiency, truth)):
        table.add_row("atmosphere" if i == 0 else "", *row, "")


def _atmosphere_value_rows(cal: Calibration, efficiency: dict[str, Any],
                           truth: dict[str, Any] | None) -> list[list[str]]:
    """The height model's rows: key, estimate ± 1 sigma, [σ/CRLB], [truth, error/σ]."""
    atmosphere = cal.atmosphere
    assert atmosphere is not None
    true_block = (truth or {}).get("atmosphere") or {}
    return [_value_row(cal, f"atmosphere.{key}", key, getattr(atmosphere, key),
                       atmosphere.sigma[key], efficiency, truth is not None, true_block.get(key))
            for key in ("height_offset_m", "height_scale")]


# ------------------------------------------------------------------ marginals
def _stacked(key: str) -> str:
    """A contract key as a two-line column header: ``azimuth\\nbias_mrad``."""
    head, _, tail = key.partition("_")
    return f"{head}\n{tail}" if tail else key


def _number(value: float, fmt: str = "{:.4g}") -> str:
    """A matrix entry; NaN/inf spelt out."""
    if value != value:
        return "nan"
    if value in (float("inf"), float("-inf")):
        return "inf" if value > 0 else "-inf"
    return fmt.format(value)


def marginal_table(cal: Calibration, radar_id: str) -> Table:
    """One radar: each parameter's ``value ± 1σ`` and its marginal covariance block.

    Covariance entries are in the products of the contract units of the row
    and column keys (m, fraction, mrad, s), e.g. mrad² or m·mrad.
    """
    keys = cal.marginal_labels(radar_id)
    block = cal.marginal(radar_id)
    table = Table(title=f"{radar_id}: marginal covariance (contract units)")
    table.add_column("parameter", no_wrap=True)
    table.add_column("estimate ± 1σ", justify="right", no_wrap=True)
    for key in keys:
        table.add_column(_stacked(key), justify="right", no_wrap=True)
    for i, key in enumerate(keys):
        value, sigma = cal.value(radar_id, key), cal.sigma(radar_id, key)
        table.add_row(key, format_value(key, value, sigma), *(_number(v) for v in block[i]))
    return table


def correlation_block_table(cal: Calibration, radar_id: str) -> Table:
    """Correlation coefficients among one radar's parameters."""
    keys = cal.marginal_labels(radar_id)
    rho = cal.correlation(radar_id)
    table = Table(title=f"{radar_id}: correlation")
    table.add_column("parameter", no_wrap=True)
    for key in keys:
        table.add_column(_stacked(key), justify="right", no_wrap=True)
    for i, key in enumerate(keys):
        table.add_row(key, *(_number(v, "{:+.3f}") for v in rho[i]))
    return table


def correlation_matrix_tables(cal: Calibration, width: int = 120) -> list[Table]:
    """The full correlation matrix, numbered columns, split to fit ``width`` characters.

    Rows are ``[k] RADAR.key``; column ``k`` is the parameter of row ``k``.
    """
    labels = cal.contract_labels()
    rho = cal.correlation()
    n = len(labels)
    row_names = [f"[{k + 1}] {label}" for k, label in enumerate(labels)]
    first = max((len(name) for name in row_names), default=10) + 4
    per_table = max(1, (width - first) // 8)
    tables = []
    for start in range(0, n, per_table):
        cols = range(start, min(start + per_table, n))
        title = "correlation" if n <= per_table else (
            f"correlation, columns {cols[0] + 1}-{cols[-1] + 1} of {n}"
        )
        table = Table(title=title)
        table.add_column("parameter", no_wrap=True)
        for j in cols:
            table.add_column(f"[{j + 1}]", justify="right", no_wrap=True)
        for i in range(n):
            cells = ["1" if i == j else _number(rho[i, j], "{:+.2f}") for j in cols]
            table.add_row(row_names[i], *cells)
        tables.append(table)
    return tables


def strong_correlations(
    cal: Calibration, min_rho: float = 0.5, radar_id: str | None = None
) -> list[tuple[str, str, float]]:
    """Parameter pairs with ``|rho| > min_rho``, strongest first.

    Parameters
    ----------
    cal : Calibration
    min_rho : float
        Threshold on the absolute correlation coefficient.
    radar_id : str, optional
        Only pairs of this radar's parameters with other radars' parameters.
        Without it: every pair.

    Returns
    -------
    list of (label_a, label_b, rho)
        ``RADAR.key`` labels; ``label_a`` belongs to ``radar_id`` when given.
    """
    labels = cal.contract_labels()
    rho = cal.correlation()
    pairs = []
    for i, (rid_i, _) in enumerate(cal.labels):
        for j, (rid_j, _) in enumerate(cal.labels):
            if radar_id is None:
                wanted = j > i
            else:
                wanted = rid_i == radar_id and rid_j != radar_id
            if wanted and abs(rho[i, j]) > min_rho:
                pairs.append((labels[i], labels[j], float(rho[i, j])))
    return sorted(pairs, key=lambda pair: -abs(pair[2]))


def strong_correlations_table(pairs: list[tuple[str, str, float]], title: str) -> Table:
    """A table of :func:`strong_correlations` pairs."""
    table = Table(title=title)
    table.add_column("parameter", no_wrap=True)
    table.add_column("with", no_wrap=True)
    table.add_column("ρ", justify="right", no_wrap=True)
    for a, b, r in pairs:
        table.add_row(a, b, f"{r:+.3f}")
    return table


def fusion_table(summary: Any, comparison: Any | None = None) -> Table:
    """Track and fused RMSE against the reference, optionally before and after calibration.

    Parameters
    ----------
    summary : pandas.DataFrame
        :attr:`graphcal.tracking.fusion.FusionResult.summary` (without calibration).
    comparison : pandas.DataFrame, optional
        :func:`graphcal.tracking.fusion.fusion_comparison` of the runs before and after.
    """
    from graphcal.tracking.fusion import FUSED_COV, FUSED_EQUAL

    names = {FUSED_COV: "fused, covariance weights", FUSED_EQUAL: "fused, equal weights"}
    table = Table(title="track accuracy against ADS-B" if comparison is None
                  else "track accuracy against ADS-B, before and after calibration")
    table.add_column("track")
    if comparison is None:
        table.add_column("RMSE \\[m]", justify="right")
        table.add_column("points", justify="right")
        table.add_column("aircraft", justify="right")
        for label, row in summary.iterrows():
            table.add_row(names.get(label, str(label)), _number(row["rmse_m"], "{:.1f}"),
                          str(int(row["n_points"])), str(int(row["n_targets"])))
        return table
    for column in ("RMSE before \\[m]", "RMSE after \\[m]", "improvement", "points"):
        table.add_column(column, justify="right")
    for label, row in comparison.iterrows():
        table.add_row(names.get(label, str(label)), _number(row["rmse_before_m"], "{:.1f}"),
                      _number(row["rmse_after_m"], "{:.1f}"),
                      _number(row["improvement_pct"], "{:+.1f} %"), str(int(row["n_points"])))
    return table


def noise_table(sites: Any, estimates: Any) -> Table:
    """Estimated random-error sigmas ``value ± standard error`` beside the site file's.

    Parameters
    ----------
    sites : mapping of str to Site
    estimates : mapping of str to graphcal.noise.NoiseEstimate
    """
    table = Table(title="random-error sigmas: estimated ± standard error (sites.toml)")
    for column in ("radar", "method", "plots", "range \\[m]", "azimuth \\[mrad]",
                   "elevation \\[mrad]"):
        table.add_column(column, justify="left" if column in ("radar", "method") else "right")

    def cell(value: float | None, se: float | None, given: float | None, scale: float,
             fmt: str) -> str:
        if value is None:
            return "-"
        text = "not estimated" if value != value else (
            f"{fmt.format(value)} ± {fmt.format(se)}" if se == se and se is not None
            else fmt.format(value))
        if given is not None and given == given:
            text += f" ({fmt.format(given * scale)})"
        return text

    for rid, est in estimates.items():
        site = sites[rid]
        table.add_row(
            rid, est.method, str(est.n_plots_used),
            cell(est.sigma_range_m, est.se_range_m, site.sigma_range_m, 1.0, "{:.1f}"),
            cell(est.sigma_azimuth_mrad, est.se_azimuth_mrad, site.sigma_azimuth_rad, 1e3,
                 "{:.3f}"),
            cell(est.sigma_elevation_mrad, est.se_elevation_mrad, site.sigma_elevation_rad, 1e3,
                 "{:.3f}"),
        )
    return table

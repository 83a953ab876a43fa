"""Readable tables of calibration results (``value ± sigma``) for the terminal."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rich.console import RenderableType
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
                       width: int = 120) -> list[RenderableType]:
    """The calibration table laid out for a terminal ``width`` characters wide.

    :func:`calibration_table` when it fits; otherwise one compact table per radar
    (its id and plot count in the title, no radar and plots columns) and one for the
    atmosphere; and when even those do not fit, a list: per radar its title, then per
    parameter its key and one line per field (``value ± sigma``, ``σ/CRLB r``,
    ``truth t``, ``error/σ z``).  No id or number is ever cut.
    """
    return terminal_all(_calibration_layouts(cal, truth, width), width)


def _calibration_layouts(cal: Calibration, truth: dict[str, Any] | None,
                         width: int) -> list[Table | Text]:
    """:func:`calibration_tables` before :func:`terminal_all`."""
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


def sigma_footnote(cal: Calibration) -> str | None:
    """The footnote under the calibration table saying what the sigmas are, from
    ``info["sigma"]`` (the paper methods record it: ``"formal (paper 003 eq. 19 ...)"``),
    e.g. ``"σ: formal (paper 001: the weighted LS covariance ...)"``; None when the
    method records nothing (graph: its sigmas are the factor graph's marginals)."""
    note = cal.info.get("sigma")
    if not isinstance(note, str) or not note.strip():
        return None
    return f"σ: {' '.join(note.split())}"


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


def table_width(table: Table) -> int:
    """The natural width of ``table`` in characters (what it takes with no limit)."""
    from rich.console import Console
    from rich.measure import Measurement

    console = Console(width=100_000)
    return Measurement.get(console, console.options, table).maximum


def _plain(content: Any) -> str:
    """The text of a header or cell as printed (rich markup resolved, ``\\[`` unescaped)."""
    if isinstance(content, Text):
        return content.plain
    if content is None:
        return ""
    from rich.errors import MarkupError

    try:
        return Text.from_markup(str(content)).plain
    except MarkupError:  # not markup: printed as it is
        return str(content)


def _copy(table: Table, **columns: Any) -> Table:
    """A shallow copy of ``table`` whose columns have the attributes ``columns``."""
    import copy
    from dataclasses import replace

    new = copy.copy(table)
    new.columns = [replace(column, **columns) for column in table.columns]
    return new


def _rendered(table: Table | Text, width: int) -> list[str]:
    """The lines of ``table`` printed ``width`` characters wide, not cropped."""
    import io

    from rich.console import Console

    console = Console(file=io.StringIO(), width=width, color_system=None, legacy_windows=False,
                      force_terminal=False)
    console.print(table, crop=False)
    return console.file.getvalue().splitlines()  # type: ignore[attr-defined]


def overflows(table: Table, width: int) -> bool:
    """Whether rich, printing ``table`` in ``width`` characters, would cut a cell or a header
    (with an ellipsis, or silently: a cell that does not wrap cropped to its column) or print
    a line wider than ``width``.  Wrapping at spaces is no cut."""
    from rich.cells import cell_len

    probe = _copy(table, overflow="ellipsis")  # every cut shows as an ellipsis
    lines = _rendered(probe, width)
    if any(cell_len(line.rstrip()) > width for line in lines):
        return True
    shown = sum(line.count("…") for line in lines)
    natural = sum(line.count("…") for line in _rendered(probe, 100_000))
    return shown > natural


def cuts(table: Table, width: int) -> bool:
    """Whether rich, to fit ``table`` in ``width`` characters, would cut a cell (see
    :func:`overflows`)."""
    return overflows(table, width)


def compact(table: Table) -> Table:
    """A copy of ``table`` in the compact style: a rule under the header, no edges, two
    spaces between columns, the title on the left."""
    from rich import box

    new = _copy(table)
    new.box = box.SIMPLE_HEAD
    new.show_edge = False
    new.pad_edge = False
    new.collapse_padding = True
    new.title_justify = "left"
    return new


def fit_table(table: Table, width: int) -> Table:
    """``table`` as it is when it fits ``width`` characters, else in the compact style
    (:func:`compact`).  :func:`terminal_tables` goes further: it never cuts."""
    return table if not overflows(table, width) else compact(table)


def _folding(table: Table) -> Table:
    """``table`` with every column folding what does not fit instead of an ellipsis (a
    safeguard: the layouts chosen by :func:`terminal_tables` fit already)."""
    for column in table.columns:
        column.overflow = "fold"
    return table


def _cells(table: Table) -> list[list[str]]:
    """The rows of ``table`` as plain text."""
    columns = [[_plain(cell) for cell in column.cells] for column in table.columns]
    return [list(row) for row in zip(*columns, strict=True)]


def _groups(table: Table) -> list[tuple[str, list[list[str]]]]:
    """The rows of ``table`` grouped by their first cell (a row with an empty first cell
    belongs to the group above): ``[(first cell, [other cells of each row])]``."""
    groups: list[tuple[str, list[list[str]]]] = []
    for first, *rest in _cells(table):
        if first or not groups:
            groups.append((first, []))
        groups[-1][1].append(rest)
    return groups


def grouped_layout(table: Table, width: int) -> list[RenderableType] | None:
    """``table`` without its first column: that column's cell (a radar id) on a heading
    line of its own (``LFPG_NORD_SSR_MODE_S:``) above its rows, the other columns aligned
    over all groups.  None when even that does not fit ``width`` whole."""
    from rich import box
    from rich.cells import cell_len

    if len(table.columns) < 2:
        return None
    groups = _groups(table)
    rest = table.columns[1:]
    natural = []
    for k, column in enumerate(rest):
        texts = [_plain(column.header), *(row[k] for _, rows in groups for row in rows)]
        natural.append(max((cell_len(line) for text in texts for line in text.split("\n")),
                           default=1))

    def part(rows: list[list[str]], header: bool) -> Table:
        part = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False,
                     collapse_padding=True, show_header=header)
        for column, size in zip(rest, natural, strict=True):
            part.add_column(column.header, justify=column.justify, no_wrap=column.no_wrap,
                            width=size, overflow="fold")
        for row in rows:
            part.add_row(*(Text(cell) for cell in row))  # plain text, not markup
        return part

    if overflows(part([row for _, rows in groups for row in rows], True), width):
        return None
    out: list[RenderableType] = []
    if _plain(table.title):
        out.append(Text(_plain(table.title), overflow="fold"))
    out.append(part([], True))
    for first, rows in groups:
        if first:
            out.append(Text(f"{first}:", overflow="fold"))
        out.append(part(rows, False))
    return out


def _pack(fields: list[str], indent: int, width: int) -> list[str]:
    """``fields`` on lines of ``width`` characters, indented, two spaces apart; a field is
    never broken (one longer than a line gets a line of its own, folded when printed)."""
    from rich.cells import cell_len

    lines: list[str] = []
    line = ""
    for field in fields:
        if line and cell_len(line) + 2 + cell_len(field) > width - indent:
            lines.append(line)
            line = ""
        line = f"{line}  {field}" if line else field
    if line:
        lines.append(line)
    return [" " * indent + line for line in lines]


def stacked_layout(table: Table, width: int) -> list[RenderableType]:
    """``table`` as a list, the last resort of :func:`terminal_tables` for any width: its
    title; per group (the first column's cell) a heading line; per row its label and one
    ``header value`` field per cell, packed on lines without breaking a field."""
    headers = [" ".join(_plain(column.header).split()) for column in table.columns]
    grouped = any(not row[0] for row in _cells(table)) and len(headers) > 2
    lines = [_plain(table.title)] if _plain(table.title) else []
    for first, rows in _groups(table):
        lines.append(f"{first}:" if first else "")
        for row in rows:
            names = headers[2:] if grouped else headers[1:]
            cells = row[1:] if grouped else row
            fields = [f"{name} {' '.join(cell.split())}".strip()
                      for name, cell in zip(names, cells, strict=True) if cell.strip()]
            if grouped:
                lines.append(f"  {row[0]}" if row[0] else "  -")
            lines += _pack(fields, 4 if grouped else 2, width)
    return [Text("\n".join(lines), overflow="fold")]


def terminal_tables(table: Table | Sequence[Table], width: int) -> list[RenderableType]:
    """What to print for ``table`` in a terminal ``width`` characters wide: every header,
    id and number whole, no line wider than ``width``.  Every table of the commands goes
    through here (or :func:`print_tables`).

    ``table`` is a table or a sequence of layouts of the same content, the preferred
    first.  The first layout that fits whole, as it is or in the compact style
    (:func:`compact`); else the first that fits with its first column (the radar) on
    heading lines (:func:`grouped_layout`); else the first as a list
    (:func:`stacked_layout`), which fits any width (an id longer than a line folds).
    """
    layouts = [table] if isinstance(table, Table) else list(table)
    for layout in layouts:
        for style in (layout, compact(layout)):
            if not overflows(style, width):
                return [_folding(style)]
    for layout in layouts:
        grouped = grouped_layout(compact(layout), width)
        if grouped is not None:
            return grouped
    return stacked_layout(layouts[0], width)


def terminal_all(items: Sequence[Table | Text], width: int) -> list[RenderableType]:
    """Each table of ``items`` through :func:`terminal_tables`; text as it is."""
    out: list[RenderableType] = []
    for item in items:
        out += terminal_tables(item, width) if isinstance(item, Table) else [item]
    return out


def print_tables(out: Any, *items: RenderableType | Sequence[Table],
                 width: int | None = None) -> None:
    """Print ``items`` on the console ``out``: each table (or sequence of layouts of one
    table) through :func:`terminal_tables`, anything else as it is."""
    width = out.width if width is None else width
    for item in items:
        if isinstance(item, Table) or (isinstance(item, (list, tuple)) and item
                                       and all(isinstance(t, Table) for t in item)):
            for shown in terminal_tables(item, width):  # type: ignore[arg-type]
                out.print(shown)
        else:
            out.print(item)


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


def marginal_tables(cal: Calibration, radar_id: str,
                    width: int = 120) -> list[RenderableType]:
    """:func:`marginal_table` laid out for a terminal ``width`` characters wide.

    The one table when it fits; otherwise a table of ``value ± 1σ`` and the
    covariance block with its columns split over as many tables as needed (each
    repeating the parameter column).  No key or number is ever cut.
    """
    from rich import box

    wide = marginal_table(cal, radar_id)
    if table_width(wide) <= width:
        return terminal_all([wide], width)
    keys = cal.marginal_labels(radar_id)
    block = cal.marginal(radar_id)
    compact = {"box": box.SIMPLE_HEAD, "show_edge": False, "pad_edge": False,
               "title_justify": "left"}
    values = Table(title=f"{radar_id}: value ± 1σ (contract units)", **compact)
    values.add_column("parameter", no_wrap=True)
    values.add_column("estimate ± 1σ", justify="right", no_wrap=True)
    for key in keys:
        values.add_row(key, format_value(key, cal.value(radar_id, key),
                                         cal.sigma(radar_id, key)))
    cells = [[_number(v) for v in row] for row in block]

    def cov_table(cols: list[int]) -> Table:
        title = (f"{radar_id}: marginal covariance" if len(cols) == len(keys) else
                 f"{radar_id}: covariance, columns {cols[0] + 1}-{cols[-1] + 1} of {len(keys)}")
        table = Table(title=title, **compact)
        table.add_column("parameter", no_wrap=True)
        for j in cols:
            table.add_column(_stacked(keys[j]), justify="right", no_wrap=True)
        for i, key in enumerate(keys):
            table.add_row(key, *(cells[i][j] for j in cols))
        return table

    return terminal_all([values, *split_columns(cov_table, len(keys), width)], width)


def split_columns(make_table: Callable[[list[int]], Table], n: int,
                  width: int) -> list[Table]:
    """Tables of columns ``0 .. n-1`` made by ``make_table(columns)``, as many columns in
    each as fit ``width`` characters (at least one)."""
    tables = []
    start = 0
    while start < n:
        stop = start + 1
        while stop < n and table_width(make_table(list(range(start, stop + 1)))) <= width:
            stop += 1
        tables.append(make_table(list(range(start, stop))))
        start = stop
    per = -(-n // len(tables))  # the same count in every table (5 as 3 + 2, not 4 + 1)
    even = [make_table(list(range(a, min(a + per, n)))) for a in range(0, n, per)]
    if len(even) == len(tables) and all(table_width(t) <= width for t in even):
        return even
    return tables


def correlation_block_table(cal: Calibration, radar_id: str) -> Table:
    """Correlation coefficients among one radar's parameters."""
    table = correlation_block_tables(cal, radar_id, 100_000)[0]
    assert isinstance(table, Table)
    return table


def correlation_block_tables(cal: Calibration, radar_id: str,
                             width: int = 120) -> list[RenderableType]:
    """Correlation coefficients among one radar's parameters, split to fit ``width``."""
    keys = cal.marginal_labels(radar_id)
    rho = cal.correlation(radar_id)

    def make(cols: list[int]) -> Table:
        span = "" if len(cols) == len(keys) else (
            f", columns {cols[0] + 1}-{cols[-1] + 1} of {len(keys)}")
        table = Table(title=f"{radar_id}: correlation{span}")
        table.add_column("parameter", no_wrap=True)
        for j in cols:
            table.add_column(_stacked(keys[j]), justify="right", no_wrap=True)
        for i, key in enumerate(keys):
            table.add_row(key, *(_number(rho[i, j], "{:+.3f}") for j in cols))
        return table

    return terminal_all(split_columns(make, len(keys), width), width)


def correlation_matrix_tables(cal: Calibration, width: int = 120) -> list[RenderableType]:
    """The full correlation matrix, numbered columns, split to fit ``width`` characters.

    Rows are ``[k] RADAR.key``; column ``k`` is the parameter of row ``k``.  When these
    labels would take more than half the width (long radar ids), the rows are ``[k]``
    only, under a legend listing ``[k] RADAR.key``.
    """
    labels = cal.contract_labels()
    rho = cal.correlation()
    n = len(labels)
    row_names = [f"[{k + 1}] {label}" for k, label in enumerate(labels)]
    tables: list[Table | Text] = []
    if max((len(name) for name in row_names), default=0) + 4 > width // 2:
        tables.append(Text("\n".join(["correlation matrix, parameters:",
                                       *(f"  {name}" for name in row_names)]),
                           overflow="fold"))
        row_names = [f"[{k + 1}]" for k in range(n)]
    first = max(len("parameter"), *(len(name) for name in row_names)) + 4
    per_table = max(1, (width - first) // 8)
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
    return terminal_all(tables, width)


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
    return strong_correlations_layouts(pairs, title)[0]


def strong_correlations_layouts(pairs: list[tuple[str, str, float]],
                                title: str) -> list[Table]:
    """Layouts of the :func:`strong_correlations` pairs for :func:`terminal_tables`: one
    line per pair; the ``RADAR.key`` labels on two lines (``RADAR.`` then ``key``); the
    pair in one column (``RADAR.key`` then ``with RADAR.key``)."""

    def two_lines(label: str) -> str:
        radar, dot, key = label.rpartition(".")
        return f"{radar}{dot}\n  {key}" if dot else label

    wide = Table(title=title)
    split = Table(title=title)
    one = Table(title=title)
    for table in (wide, split):
        table.add_column("parameter", no_wrap=True)
        table.add_column("with", no_wrap=True)
        table.add_column("ρ", justify="right", no_wrap=True)
    one.add_column("parameter, with", no_wrap=True)
    one.add_column("ρ", justify="right", no_wrap=True)
    for a, b, r in pairs:
        wide.add_row(a, b, f"{r:+.3f}")
        split.add_row(two_lines(a), two_lines(b), f"{r:+.3f}")
        one.add_row(f"{a}\n  with {b}", f"{r:+.3f}")
    split.show_lines = one.show_lines = len(pairs) > 1
    return [wide, split, one]


def fusion_table(summary: Any, comparison: Any | None = None, width: int = 120) -> Table:
    """The preferred layout of :func:`fusion_layouts` at ``width`` (the first if it fits,
    else the second in the compact style); :func:`terminal_tables` of the layouts never
    cuts."""
    layouts = fusion_layouts(summary, comparison)
    return layouts[0] if table_width(layouts[0]) <= width else fit_table(layouts[1], width)


def fusion_layouts(summary: Any, comparison: Any | None = None) -> list[Table]:
    """Track and fused RMSE against the reference, optionally before and after calibration.

    Parameters
    ----------
    summary : pandas.DataFrame
        :attr:`graphcal.tracking.fusion.FusionResult.summary` (without calibration).
    comparison : pandas.DataFrame, optional
        :func:`graphcal.tracking.fusion.fusion_comparison` of the runs before and after.

    Returns
    -------
    list of Table
        Layouts for :func:`terminal_tables`: one-line headers; two-line headers; short
        headers of up to three lines.
    """
    from graphcal.tracking.fusion import FUSED_COV, FUSED_EQUAL

    names = {FUSED_COV: "fused, covariance weights", FUSED_EQUAL: "fused, equal weights"}

    short = {"RMSE \\[m]": "RMSE\n\\[m]", "aircraft": "air-\ncraft",
             "RMSE before \\[m]": "RMSE\nbefore\n\\[m]",
             "RMSE after \\[m]": "RMSE\nafter\n\\[m]", "improvement": "improve-\nment"}

    def build(stacked: bool, shortest: bool = False) -> Table:
        table = Table(title="track accuracy against ADS-B" if comparison is None
                      else "track accuracy against ADS-B, before and after calibration")
        table.add_column("track", no_wrap=True)
        if comparison is None:
            for column in ("RMSE \\[m]", "points", "aircraft"):
                table.add_column(short.get(column, column) if shortest else column,
                                 justify="right", no_wrap=True)
            for label, row in summary.iterrows():
                table.add_row(names.get(label, str(label)), _number(row["rmse_m"], "{:.1f}"),
                              str(int(row["n_points"])), str(int(row["n_targets"])))
            return table
        for column in ("RMSE before \\[m]", "RMSE after \\[m]", "improvement", "points"):
            if shortest:
                column = short.get(column, column)
            elif stacked:
                column = column.replace("RMSE ", "RMSE\n").replace("improvement", "improve-\nment")
            table.add_column(column, justify="right", no_wrap=True)
        for label, row in comparison.iterrows():
            table.add_row(names.get(label, str(label)), _number(row["rmse_before_m"], "{:.1f}"),
                          _number(row["rmse_after_m"], "{:.1f}"),
                          _number(row["improvement_pct"], "{:+.1f} %"),
                          str(int(row["n_points"])))
        return table

    return [build(False), build(True), build(True, True)]


def noise_table(sites: Any, estimates: Any, width: int = 120) -> Table:
    """The preferred layout of :func:`noise_layouts` at ``width`` (one line per radar if it
    fits, else the site file's values on second lines, compact); :func:`terminal_tables` of
    the layouts never cuts."""
    layouts = noise_layouts(sites, estimates)
    return layouts[0] if table_width(layouts[0]) <= width else fit_table(layouts[1], width)


def noise_layouts(sites: Any, estimates: Any) -> list[Table]:
    """Estimated random-error sigmas ``value ± standard error`` beside the site file's.

    Parameters
    ----------
    sites : mapping of str to Site
    estimates : mapping of str to graphcal.noise.NoiseEstimate

    Returns
    -------
    list of Table
        Layouts for :func:`terminal_tables`: one line per radar; the site file's value on a
        second line of its cell; and the headers on two lines too.
    """

    def cell(value: float | None, se: float | None, given: float | None, scale: float,
             fmt: str, sep: str) -> str:
        if value is None:
            return "-"
        text = "not estimated" if value != value else (
            f"{fmt.format(value)} ± {fmt.format(se)}" if se == se and se is not None
            else fmt.format(value))
        if given is not None and given == given:
            text += f"{sep}({fmt.format(given * scale)})"
        return text

    def build(sep: str, stacked: bool = False) -> Table:
        table = Table(title="random-error sigmas: estimated ± standard error (sites.toml)")
        for column in ("radar", "method", "plots", "range \\[m]", "azimuth \\[mrad]",
                       "elevation \\[mrad]"):
            table.add_column(column.replace(" ", "\n") if stacked else column,
                             justify="left" if column in ("radar", "method") else "right",
                             no_wrap=True)
        for rid, est in estimates.items():
            site = sites[rid]
            table.add_row(
                rid, est.method, str(est.n_plots_used),
                cell(est.sigma_range_m, est.se_range_m, site.sigma_range_m, 1.0, "{:.1f}",
                     sep),
                cell(est.sigma_azimuth_mrad, est.se_azimuth_mrad, site.sigma_azimuth_rad, 1e3,
                     "{:.3f}", sep),
                cell(est.sigma_elevation_mrad, est.se_elevation_mrad, site.sigma_elevation_rad,
                     1e3, "{:.3f}", sep),
            )
        return table

    return [build(" "), build("\n"), build("\n", True)]

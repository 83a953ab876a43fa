"""A self-contained HTML report of a calibration.

:func:`build_report` returns one HTML page (inline CSS, figures embedded as
base64 PNG made with matplotlib's Agg backend, no external assets).  It opens
with a header (``<header id="header">``: graphcal version, when the report was
written in UTC, the command line, the dataset, the recording's time span in UTC,
with its date when the dataset has an epoch, ``[dataset] epoch_utc``, else as
times of day from 00:00 UTC of its first day, the counts of plots and ADS-B
reports) followed by these sections, each an ``<h2>`` with a stable ``id``:

``estimates``      per radar and parameter, value ± sigma in display units (range
                   offset m, gain ppm, azimuth and elevation mrad, time offset
                   ms; :mod:`graphcal.reporting.display`), the truth, error and
                   z = error / sigma when given (|z| > 3 flagged), the CRLB sigma
                   and sigma / CRLB sigma;
``correlation``    the correlation matrix as a coloured table (two decimals);
``residuals``      per radar, residuals against range before and after
                   correction in separate panels with robust limits, and a
                   table of their means and standard deviations;
``binned``         per radar, the corrected residuals binned against range,
                   azimuth, elevation and time (mean ± 1 sd bands);
``pairs``          radar versus radar (without ADS-B): per pair, the difference
                   of the two radars' positions before and after correction;
``histograms``     corrected residuals with the expected N(0, sigma);
``map``            east/north in km around the network centre, equal aspect,
                   range rings, coverage, tracks before and after correction;
``model-checks``   the model checks' binned means and tests
                   (:mod:`graphcal.analysis.model_checks`, read from
                   ``info["model_checks"]``);
``observability``  degree, rank, undetermined parameters, warnings and the
                   robust kernel's down-weighted measurements;
``association``    only when the result has ``info["association"]`` (radars without
                   addresses): per radar the plots associated, ambiguous and left out,
                   detection probability, false plots per scan, Mode 3/A consistency
                   and the tail fraction (flagged above 1 %), with the rounds or
                   windows of the association;
``data``           plots per radar, ADS-B reports, time spans.

Residuals (:mod:`graphcal.reporting.report_residuals`) are against ADS-B when
the dataset has it, else against the other radars' plots of the same aircraft.
Figures: :mod:`graphcal.reporting.report_figures`.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from graphcal.data.bias import CONTRACT_KEYS, ECCENTRICITY_NAMES, PARAMETER_NAMES, RadarBias
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset
from graphcal.data.epoch import format_epoch_utc
from graphcal.reporting.display import (
    Z_FLAG,
    decimals_for,
    display_unit,
    duration_text,
    span_text,
    value_text,
)
from graphcal.reporting.report_figures import (
    MAX_MAP_POINTS,
    MAX_SCATTER,
    before_after_figure,
    binned_figure,
    correlation_figure,
    histograms_figure,
    map_figure,
    model_checks_figure,
    p_value_text,
    pyplot,
)
from graphcal.reporting.report_residuals import (
    COORDINATES,
    ROBUST_PERCENTILES,
    ResidualView,
    pair_summaries,
    residual_views,
)
from graphcal.reporting.tables import sigma_footnote
from graphcal.tracking.association import TAIL_PROBABILITY, TAIL_WARNING_FACTOR

#: Section ids, in page order.
SECTIONS: tuple[tuple[str, str], ...] = (
    ("estimates", "Estimates"),
    ("correlation", "Correlation of the estimates"),
    ("residuals", "Residuals before and after correction"),
    ("binned", "Binned residuals after correction"),
    ("pairs", "Radar versus radar"),
    ("histograms", "Residual histograms after correction"),
    ("map", "Map"),
    ("model-checks", "Model checks: structure left in the residuals"),
    ("observability", "Observability and warnings"),
    ("data", "Data"),
)
#: The association section: only for a result with ``info["association"]``, before ``data``.
ASSOCIATION_SECTION: tuple[str, str] = ("association", "Association")
#: Tail fraction above which a radar's association is flagged (10 times the expected 0.1 %).
TAIL_FLAG = TAIL_WARNING_FACTOR * (1.0 - TAIL_PROBABILITY)
#: Figure resolution [dots per inch].
DPI = 96
#: Seed of the subsampling (the report is reproducible).
SEED = 0
#: Largest number of parameters shown as a table of numbers (beyond: an image).
MAX_TABLE_PARAMETERS = 40

_KEYS: tuple[str, ...] = tuple(
    CONTRACT_KEYS[n][0] for n in (*PARAMETER_NAMES, *ECCENTRICITY_NAMES, "time_offset")
)

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em;
color:#222;max-width:1200px}
h1{font-size:1.6em;margin-bottom:.3em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;
margin-top:1.6em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ddd;padding:3px 8px;
text-align:right;font-variant-numeric:tabular-nums}th{background:#f4f4f4}
td.l,th.l{text-align:left}img{max-width:100%;height:auto;display:block}
.note{color:#555;font-size:.9em}.warn{color:#a15c00}nav a{margin-right:1em}
header table td{text-align:left;border:none;padding:1px 10px 1px 0}
header table td:first-child{color:#555;white-space:nowrap}
header code{white-space:pre-wrap;word-break:break-all}
tr.flag td{background:#fde2e1}.zflag{font-weight:bold;color:#b00020}
tr.first td{border-top:2px solid #999}
table.corr td,table.corr th{padding:2px 4px;font-size:.8em;min-width:2.6em}
table.corr th{font-weight:normal}table.corr th.l{white-space:nowrap}
.ok{color:#1a7f37}.wide{overflow-x:auto}
table.corr tr.first td,table.corr tr.first th{border-top:2px solid #888}
"""


# --------------------------------------------------------------------- helpers
def _esc(value: Any) -> str:
    return html.escape(str(value))


def _fmt(value: float | None, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–" if value is None else str(value)
    return f"{value:.{digits}g}"


def _img(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{_esc(alt)}">'


def _table(header: list[str], rows: list[list[str]], left: int = 1,
           row_classes: list[str] | None = None, css: str = "",
           groups: list[tuple[str, int]] | None = None) -> str:
    """An HTML table; the first ``left`` columns are left-aligned; cells already escaped.

    ``groups`` adds a header row above ``header``: (label, number of columns spanned).
    """
    def cells(values: list[str], tag: str) -> str:
        return "".join(
            f'<{tag} class="l">{v}</{tag}>' if i < left else f"<{tag}>{v}</{tag}>"
            for i, v in enumerate(values)
        )

    classes = row_classes or [""] * len(rows)
    body = "".join((f'<tr class="{c}">' if c else "<tr>") + f"{cells(r, 'td')}</tr>"
                   for r, c in zip(rows, classes, strict=True))
    attribute = f' class="{css}"' if css else ""
    top = ""
    if groups:
        top = "<tr>" + "".join(f'<th colspan="{n}">{label}</th>' if n > 1 else
                               f"<th>{label}</th>" for label, n in groups) + "</tr>"
    return f"<table{attribute}>{top}<tr>{cells(header, 'th')}</tr>{body}</table>"


# ---------------------------------------------------------------------- header
def _header(cal: Calibration, dataset: Dataset, command: str | None, title: str) -> str:
    import graphcal

    plots = dataset.plots
    rows = [
        ("graphcal", _esc(graphcal.__version__)),
        ("written", datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S UTC")),
        ("command", f"<code>{_esc(command)}</code>" if command
         else "not recorded (Python API)"),
        ("dataset", _esc(Path(dataset.path).resolve()) if dataset.path is not None
         else "in memory (no folder)"),
        ("method", _esc(cal.method or "?")),
    ]
    if len(plots):
        t0, t1 = float(plots["time_s"].min()), float(plots["time_s"].max())
        epoch = dataset.epoch_utc
        origin = ("00:00 UTC of the recording's first day" if epoch is None
                  else f"epoch_utc {format_epoch_utc(epoch)}")
        rows.append(("recording", f"{span_text(t0, t1, epoch)} UTC "
                     f"({duration_text(t1 - t0)}; time_s {t0:.1f} – {t1:.1f}, counted from "
                     f"{origin})"))
    counts = f"{len(plots):,} plots of {plots['radar_id'].nunique()} radars"
    if dataset.adsb is not None and len(dataset.adsb):
        counts += (f"; {len(dataset.adsb):,} ADS-B reports of "
                   f"{dataset.adsb['target_id'].nunique()} aircraft")
    else:
        counts += "; no ADS-B"
    rows.append(("data", counts))
    body = "".join(f"<tr><td>{k}</td><td>{v}</td></tr>" for k, v in rows)
    return f'<header id="header"><h1>{_esc(title)}</h1><table>{body}</table></header>'


# ----------------------------------------------------------------- estimates
def _estimate_row(name: str, key: str, value: float | None, sigma: float | None,
                  truth: float | None, truth_columns: bool, crlb_columns: bool,
                  crlb_sigma: float | None, shown: str | None = None) -> tuple[list[str], bool]:
    """One row of the estimates table in display units, and whether |z| > :data:`Z_FLAG`."""
    unit = display_unit(key)
    f = unit.factor
    d_sigma = None if sigma is None else sigma * f
    digits = decimals_for(d_sigma)
    d_value = None if value is None else value * f
    row = [name, _esc(unit.name), _esc(unit.unit),
           shown if shown is not None else value_text(d_value, digits),
           "fixed" if sigma is None else value_text(d_sigma, max(digits, 0))]
    flagged = False
    if truth_columns:
        if truth is None or value is None:
            row += ["–", "–", "–"]
        else:
            error = (value - truth) * f
            z = (value - truth) / sigma if sigma else math.nan
            flagged = math.isfinite(z) and abs(z) > Z_FLAG
            z_text = f"{z:+.1f}" if math.isfinite(z) else "–"
            row += [value_text(truth * f, digits), value_text(error, digits),
                    f'<span class="zflag" title="|z| > {Z_FLAG:g}">⚠ {z_text}</span>' if flagged
                    else z_text]
    if crlb_columns:
        eff = sigma / crlb_sigma if crlb_sigma and sigma is not None else None
        row += [value_text(None if crlb_sigma is None else crlb_sigma * f, digits + 1),
                value_text(eff, 2)]
    return row, flagged


def _estimates_section(cal: Calibration, truth: Mapping[str, RadarBias] | None,
                       crlb: Any, truth_atmosphere: Mapping[str, Any] | None = None) -> str:
    header = ["radar", "parameter", "unit", "estimate", "± 1σ"]
    if truth is not None:
        header += ["truth", "error", "z = error / σ"]
    if crlb is not None:
        header += ["CRLB σ", "σ / CRLB σ"]
    rows: list[list[str]] = []
    classes: list[str] = []
    n_flagged = n_compared = 0
    for rid in cal.radar_ids:
        first = True
        for key in _KEYS:
            value = cal.value(rid, key)
            if value is None:
                continue
            sigma = cal.sigma(rid, key)
            true = None
            if truth is not None and truth.get(rid) is not None:
                name = key_name(key)
                true = truth[rid].value(name) * CONTRACT_KEYS[name][1]
            cs = _crlb_sigma(crlb, rid, key) if crlb is not None else None
            row, flagged = _estimate_row(_esc(rid) if first else "", key, value, sigma, true,
                                         truth is not None, crlb is not None, cs)
            n_compared += true is not None and sigma is not None
            n_flagged += flagged
            rows.append(row)
            classes.append(" ".join(c for c in ("first" if first else "",
                                                 "flag" if flagged else "") if c))
            first = False
    extra, extra_flags = _atmosphere_rows(cal, truth_atmosphere, truth is not None,
                                          crlb is not None)
    rows += extra
    classes += ["flag" if f else "" for f in extra_flags]
    n_flagged += sum(extra_flags)
    parts = []
    if truth is not None:
        if n_flagged:
            parts.append(f'<p class="warn"><b>{n_flagged} of {n_compared + len(extra_flags)} '
                         f"estimates are more than {Z_FLAG:g} σ from the truth</b> "
                         "(rows in red).</p>")
        else:
            parts.append(f'<p class="ok">Every estimate is within {Z_FLAG:g} σ of the '
                         "truth.</p>")
    parts.append(_table(header, rows, left=3, row_classes=classes))
    parts.append('<p class="note">Display units: range offset m, range gain ppm (10⁻⁶), '
                 "azimuth and elevation bias mrad, time offset ms; the result JSON keeps the "
                 "contract units (m, fraction, mrad, s). Decimals follow σ (two significant "
                 f"digits). Method: {_esc(cal.method or '?')}.</p>")
    footnote = sigma_footnote(cal)
    if footnote is not None:  # what the sigmas are (the paper methods)
        parts.append(f'<p class="note sigma">{_esc(footnote)}.</p>')
    if cal.atmosphere is not None:
        parts.append('<p class="note">Height model of pressure altitudes: height above the '
                     "ellipsoid = (1 + height scale) × pressure altitude + height offset.</p>")
    return "".join(parts)


def _atmosphere_rows(cal: Calibration, truth: Mapping[str, Any] | None, truth_columns: bool,
                     crlb_columns: bool) -> tuple[list[list[str]], list[bool]]:
    """Rows of the estimates table for the height model (``atmosphere`` block), if any."""
    atmosphere = cal.atmosphere
    if atmosphere is None:
        return [], []
    rows, flags = [], []
    recorded = cal.info.get("crlb_sigma") or {}
    for i, key in enumerate(("height_offset_m", "height_scale")):
        value, sigma = getattr(atmosphere, key), atmosphere.sigma.get(key)
        shown = None
        if not atmosphere.determined or f"atmosphere.{key}" in cal.info.get("undetermined", []):
            shown = "not determined"
        row, flagged = _estimate_row("atmosphere" if i == 0 else "", key, value, sigma,
                                     (truth or {}).get(key), truth_columns, crlb_columns,
                                     recorded.get(f"atmosphere.{key}"), shown)
        rows.append(row)
        flags.append(flagged)
    return rows, flags


def key_name(key: str) -> str:
    """Internal parameter name of a contract key."""
    from graphcal.data.bias import NAME_FROM_KEY

    return NAME_FROM_KEY[key]


# -------------------------------------------------------------- correlation
def _corr_colour(rho: float) -> str:
    """Background of a correlation cell: white to red (positive) or blue (negative)."""
    if not math.isfinite(rho):
        return "#eee"
    end = (178, 24, 43) if rho > 0 else (33, 102, 172)
    a = min(abs(rho), 1.0)
    r, g, b = (round(255 + (e - 255) * a) for e in end)
    return f"#{r:02x}{g:02x}{b:02x}"


def correlation_table(cal: Calibration) -> str:
    """The correlation matrix as a coloured HTML table: the lower triangle, two decimals,
    blank where |rho| < 0.005, labelled radar / short parameter name, a heavier line
    between radars."""
    rho = np.asarray(cal.correlation(), dtype=float)
    labels = [(rid, display_unit(CONTRACT_KEYS[name][0]).short) for rid, name in cal.labels]
    starts = {i for i, (rid, _) in enumerate(labels) if i == 0 or labels[i - 1][0] != rid}

    def edge(j: int) -> str:
        return "border-left:2px solid #888;" if j in starts and j > 0 else ""

    head = "".join(f'<th style="{edge(j)}">{_esc(r)}<br>{_esc(p)}</th>'
                   for j, (r, p) in enumerate(labels))
    body = []
    for i, (rid, short) in enumerate(labels):
        cells = []
        for j in range(len(labels)):
            value = rho[i, j]
            style = edge(j)
            if j > i:
                cells.append(f'<td style="{style}border-color:transparent"></td>')
            elif i == j:
                cells.append(f'<td style="{style}background:#ddd">1</td>')
            elif not math.isfinite(value):
                cells.append(f'<td style="{style}background:#eee">–</td>')
            elif abs(value) < 0.005:
                cells.append(f'<td style="{style}"></td>')
            else:
                ink = "#fff" if abs(value) > 0.6 else "#222"
                cells.append(f'<td style="{style}background:{_corr_colour(value)};color:{ink}">'
                             f"{value_text(float(value), 2)}</td>")
        top = ' class="first"' if i in starts and i > 0 else ""
        body.append(f'<tr{top}><th class="l">{_esc(rid)} {_esc(short)}</th>{"".join(cells)}'
                    "</tr>")
    return (f'<div class="wide"><table class="corr"><tr><th></th>{head}</tr>{"".join(body)}'
            "</table></div>"
            '<p class="note">Correlation coefficients of the estimated parameters, lower '
            "triangle (red positive, blue negative, blank below 0.005 in magnitude). Δr = "
            "range offset, gain = range gain, az / el = azimuth / elevation bias, Δt = time "
            "offset.</p>")


# ---------------------------------------------------------------- residuals
def _ordinal(value: float) -> str:
    """``1`` -> ``"1st"``, ``99`` -> ``"99th"``."""
    n = round(value)
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{value:g}{suffix}"


def _residual_rows(views: Mapping[str, ResidualView]) -> tuple[list[list[str]], list[str]]:
    rows, classes = [], []
    for rid, view in views.items():
        for k, c in enumerate(view.coordinates):
            name, unit, _ = COORDINATES[c]
            after = view.after.residuals[c]
            after = after[np.isfinite(after)]
            if after.size == 0:
                continue
            before = (view.before.residuals[c] if view.before is not None
                      and c in view.before.residuals else np.empty(0))
            before = before[np.isfinite(before)]
            sig = view.after.sigmas[c]
            expected = float(np.sqrt(np.nanmean(sig**2))) if np.any(np.isfinite(sig)) else None
            digits = decimals_for(expected) if expected else 2
            # A mean is known to sigma / sqrt(n): one decimal more than the spreads.
            stat = [value_text(float(np.mean(before)), digits + 1) if before.size else "–",
                    value_text(float(np.std(before)), digits) if before.size else "–",
                    value_text(float(np.mean(after)), digits + 1),
                    value_text(float(np.std(after)), digits),
                    value_text(expected, digits)]
            rows.append([_esc(rid) if k == 0 else "", _esc(name), unit, str(after.size), *stat,
                         str(view.after.n_outliers) if k == 0 else ""])
            classes.append("first" if k == 0 else "")
    return rows, classes


def _residuals_section(views: Mapping[str, ResidualView], emit, rng) -> str:
    if not views:
        return ("<p>No residuals: the dataset has no ADS-B (or no plot aligned with it), and "
                "no two calibrated radars have usable plots of the same aircraft (within 2.5 "
                "scans of each other; a 2-D radar's plots need a Mode C altitude).</p>")
    reference = next(iter(views.values())).reference
    what = ("ADS-B (the aircraft's reported position interpolated to the plot time)"
            if reference == "adsb" else "the other radars' corrected plots of the same aircraft "
            "(no ADS-B: radar versus radar, in this radar's polar frame)")
    lo, hi = ROBUST_PERCENTILES
    rows, classes = _residual_rows(views)
    parts = [
        f"<p>Residual = plot minus {what}. Left: as measured (every bias zero); right: "
        "corrected with the estimate.</p>",
        _table(["radar", "residual", "unit", "n", "mean before", "sd before", "mean after",
                "sd after", "expected σ", "outliers left out"], rows, left=3,
               row_classes=classes),
        f'<p class="note">Each panel\'s vertical axis spans the {lo:g}th–{hi:g}th percentile '
        "of its residuals (padded by 10 %); points beyond are not drawn and counted above the "
        f"panel. Scatter panels show at most {MAX_SCATTER} randomly chosen points per radar "
        "and stage; statistics use every residual. Dashed: the expected ± 1σ (radar noise "
        "plus the reference's, from sites.toml and the ADS-B accuracy). Outliers: residuals "
        "beyond 8 robust σ, left out everywhere.</p>",
    ]
    for rid, view in views.items():
        parts.append(f"<h3>{_esc(rid)}</h3>"
                     + emit("residuals", before_after_figure(view, rng), f"{rid} residuals"))
    return "".join(parts)


def _binned_section(views: Mapping[str, ResidualView], emit,
                    epoch_utc: datetime | None = None) -> str:
    if not views:
        return "<p>No residuals to bin.</p>"
    parts = ['<p>Corrected residuals in bins of equal counts (azimuth: 30° bins): the line is '
             "the bin mean, the band ± 1 standard deviation of the residuals in the bin, the "
             "dashed lines the expected ± 1σ. A calibrated radar's mean stays near zero and "
             "its band near the dashed lines everywhere; a trend left against a variable is "
             "an error the bias model does not describe (see the model checks). A 2-D "
             "radar's elevation is that of its plot's height at its range.</p>"]
    for rid, view in views.items():
        parts.append(f"<h3>{_esc(rid)}</h3>"
                     + emit("binned", binned_figure(view, epoch_utc),
                            f"{rid} binned residuals"))
    return "".join(parts)


def _pairs_section(views: Mapping[str, ResidualView]) -> str:
    summaries = pair_summaries(views)
    if not summaries:
        if views and next(iter(views.values())).reference == "adsb":
            return ("<p>The dataset has ADS-B: the residuals above are against it. Radar "
                    "versus radar residuals are shown when there is no ADS-B.</p>")
        return ("<p>No pair of calibrated radars with usable plots of the same aircraft "
                "(see above).</p>")
    rows, classes = [], []
    previous = None
    for s in summaries:
        row = [_esc(s.radar_id) if s.radar_id != previous else "", _esc(s.partner),
               str(s.n_after)]
        for c in ("range", "azimuth"):
            expected = s.sigma.get(c)
            digits = decimals_for(expected) if expected else 2
            for stage in ("before", "after"):
                mean, sd = s.mean.get((stage, c)), s.sd.get((stage, c))
                row += [value_text(mean, digits + 1), value_text(sd, digits)]
            row.append(value_text(expected, digits))
        rows.append(row)
        classes.append("first" if s.radar_id != previous else "")
        previous = s.radar_id
    stats = ["mean before", "sd before", "mean after", "sd after", "expected σ"]
    header = ["radar", "minus partner", "pairs", *stats, *stats]
    groups = [("", 3), ("range difference [m]", 5), ("azimuth difference [mrad]", 5)]
    return ("<p>Pairs of radars that saw the same aircraft: each plot of a radar against the "
            "partner's track interpolated to its time, the difference of the two positions "
            "expressed in the first radar's range and azimuth, before correction (every bias "
            "zero) and after (both radars corrected). After a good calibration the means are "
            "near zero and the sd near the expected σ (both radars' noise).</p>"
            + _table(header, rows, left=2, row_classes=classes, groups=groups))


def _histograms_section(views: Mapping[str, ResidualView], emit) -> str:
    if not views:
        return "<p>No residuals.</p>"
    parts = ['<p class="note">Expected curve: N(0, σ) with σ² the mean over the residuals of '
             "their expected variance (radar noise plus the reference's).</p>"]
    for rid, view in views.items():
        parts.append(emit("histograms", histograms_figure(view), f"{rid} histograms"))
    return "".join(parts)


# --------------------------------------------------------------- model checks
def _model_checks_section(cal: Calibration, emit, epoch_utc: datetime | None = None) -> str:
    """The model-checks section from ``info["model_checks"]`` (a note when absent)."""
    checks = cal.info.get("model_checks")
    if not isinstance(checks, Mapping):
        return ('<p>No model checks recorded: the calibration ran with '
                "<code>--no-model-checks</code> (or the result predates them).</p>")
    radars = checks.get("radars") or {}
    if not radars:
        notes = "; ".join(map(str, checks.get("notes") or [])) or "no reference to compare with"
        return f"<p>No radar was checked: {_esc(notes)}.</p>"
    reference = {"adsb": "ADS-B", "cross": "the other radars' plots (no ADS-B)"}.get(
        checks.get("reference"), _esc(checks.get("reference")))
    parts = [
        f"<p>Residuals of the corrected plots against {reference}, binned in bins of equal "
        "counts; a test fires when the chi-square of the bin means, after the model's own "
        "terms are fitted out, has a p-value below the radar's threshold (family-wise "
        f"false-alarm rate {100 * float(checks.get('family_false_alarm', 0.01)):.3g} % "
        "per radar, Bonferroni over its tests; track segments of "
        f"{float(checks.get('segment_s', 60)):.0f} s as independent units).</p>"]
    warnings = checks.get("warnings") or []
    if warnings:
        items = "".join(f'<li class="warn">{_esc(w)}</li>' for w in warnings)
        parts.append(f"<ul>{items}</ul>")
    else:
        parts.append("<p>No structure beyond chance.</p>")
    rows = []
    for rid, entry in radars.items():
        for t in entry.get("tests") or []:
            rows.append([
                _esc(rid), _esc(t["residual"]), _esc(t["against"]), str(t["n_bins"]),
                _fmt(t["chi2"], 3), _fmt(t["dof"], 3), p_value_text(t),
                _fmt(entry.get("threshold_p"), 2),
                '<span class="warn">fired</span>' if t.get("fired") else "",
                _esc(f"{t.get('pattern', '')} ({t.get('magnitude', '')})") if t.get("fired")
                else "",
            ])
    for rid, entry in radars.items():
        if not entry.get("tests"):  # a small dataset: nothing to draw
            parts.append(f"<h3>{_esc(rid)}</h3><p>No test: too few residuals to bin "
                         f"({_esc(entry.get('n_plots', 0))} plots checked).</p>")
            continue
        parts.append(f"<h3>{_esc(rid)}</h3>"
                     + emit("model-checks", model_checks_figure(rid, entry, epoch_utc),
                            f"{rid} model checks"))
    parts.append("<details><summary>Every test</summary>" + _table(
        ["radar", "residual", "against", "bins", "χ²", "dof", "p", "threshold", "", "pattern"],
        rows, left=3) + "</details>")
    notes = checks.get("notes") or []
    if notes:
        parts.append('<p class="note">' + _esc("; ".join(map(str, notes))) + "</p>")
    return "".join(parts)


# --------------------------------------------------------------------- CRLB
def _compute_crlb(dataset: Dataset) -> tuple[Any, str | None]:
    """``(CrlbResult, None)`` from :mod:`graphcal.analysis.crlb`, or ``(None, why not)``."""
    try:
        from graphcal.analysis.crlb import crlb as compute
    except ImportError:
        return None, "graphcal.analysis.crlb is not available"
    try:
        return compute(dataset, use_adsb=True, cross=True), None
    except Exception as exc:  # noqa: BLE001 - the report must still be written
        return None, f"CRLB not computed: {exc}"


class _RecordedCrlb:
    """The CRLB sigmas an estimator recorded in ``info["crlb_sigma"]`` (``RADAR.key``)."""

    def __init__(self, sigmas: Mapping[str, float]) -> None:
        self._sigmas = sigmas

    def sigma(self, radar_id: str, key: str) -> float | None:
        return self._sigmas.get(f"{radar_id}.{key}")


def _crlb_sigma(crlb: Any, rid: str, key: str) -> float | None:
    try:
        value = crlb.sigma(rid, key)
    except (KeyError, ValueError, IndexError, TypeError):
        return None
    return None if value is None else float(value)



# -------------------------------------------------------------- other sections
def _observability_section(cal: Calibration) -> str:
    obs = cal.observability
    parts = [_table(["", "value"], [
        ["observability degree (λ<sub>min</sub>/λ<sub>max</sub>)", _fmt(obs.degree, 3)],
        ["rank", f"{obs.rank} of {obs.n_parameters}"],
    ])]
    undetermined = cal.info.get("undetermined") or []
    parts.append("<p>Undetermined parameters: "
                 + (_esc(", ".join(map(str, undetermined))) if undetermined else "none") + "</p>")
    if cal.warnings:
        items = "".join(f'<li class="warn">{_esc(w)}</li>' for w in cal.warnings)
        parts.append(f"<p>Warnings ({len(cal.warnings)}):</p><ul>{items}</ul>")
    else:
        parts.append("<p>No warnings.</p>")
    down = cal.info.get("downweighted")
    if isinstance(down, Mapping) and down:
        kinds = sorted({k for counts in down.values() if isinstance(counts, Mapping)
                        for k in counts})
        rows = [[_esc(rid)] + [_esc((counts or {}).get(k, 0)) for k in kinds]
                for rid, counts in down.items()]
        parts.append("<p>Down-weighted measurements (outliers: final robust weight below 0.5), "
                     "per radar:</p>" + _table(["radar", *map(_esc, kinds)], rows))
    else:
        parts.append('<p class="note">No down-weighting record from this estimator.</p>')
    return "".join(parts)


def _count_text(value: Any) -> str:
    """A count with thousands separators; an en dash when missing."""
    return "–" if value is None else f"{int(value):,}"


def _percent_text(fraction: float | None, decimals: int = 1) -> str:
    """A fraction as a percentage (``0.898`` -> ``"89.8 %"``); an en dash when missing."""
    return "–" if fraction is None else f"{value_text(100.0 * fraction, decimals)} %"


def _association_row(rid: str, figures: Mapping[str, Any]) -> tuple[list[str], bool]:
    """One radar's row of the association table, and whether its tail fraction is flagged."""
    tail = figures.get("tail_fraction")
    flagged = tail is not None and math.isfinite(tail) and tail > TAIL_FLAG
    tail_text = _percent_text(tail, 2)
    if flagged:
        tail_text = (f'<span class="zflag" title="above {100 * TAIL_FLAG:g} %">⚠ '
                     f"{tail_text}</span>")
    false_rate = figures.get("false_plots_per_scan")
    row = [_esc(rid), *(_count_text(figures.get(k)) for k in
                        ("plots", "associated", "own_paths", "ambiguous", "left_out", "scans")),
           _percent_text(figures.get("detection_probability")),
           value_text(None if false_rate is None else float(false_rate), 2),
           _percent_text(figures.get("mode_3a_consistency")), tail_text]
    return row, flagged


def _association_runs(association: Mapping[str, Any]) -> str:
    """How the association ran (its rounds or windows, and its time) as a sentence."""
    rounds, windows = association.get("rounds"), association.get("windows")
    seconds = association.get("seconds")
    parts = []
    if rounds is not None:
        parts.append(f"associated and calibrated in turn: {int(rounds)} "
                     f"round{'s' if int(rounds) != 1 else ''}")
    if windows is not None:
        parts.append(f"associated window by window: {int(windows)} "
                     f"window{'s' if int(windows) != 1 else ''} (the figures above are summed "
                     "over them)")
    if not parts and seconds is None:
        return ""
    text = "; ".join(parts) or "associated"
    if seconds is not None:
        text += f", {float(seconds):.1f} s"
    return f"<p>{_esc(text[0].upper() + text[1:])}.</p>"


def _association_section(cal: Calibration) -> str | None:
    """The association section from ``info["association"]``; ``None`` without it.

    Parameters
    ----------
    cal : Calibration
        The result; its ``info["association"]`` holds, per radar without addresses,
        the figures of :meth:`graphcal.tracking.association.RadarAssociation.to_dict`
        (summed over the windows by :func:`graphcal.pipeline.associate.merged_figures`
        with ``--window``), and ``rounds``, ``windows`` and ``seconds`` when recorded.

    Returns
    -------
    str or None
        The section's HTML, or ``None`` when the result has no association.
    """
    association = cal.info.get("association")
    if not isinstance(association, Mapping):
        return None
    radars = association.get("radars")
    radars = radars if isinstance(radars, Mapping) else {}
    parts = [
        "<p>Plots that carry no aircraft address (primary radars, Mode A/C radars) are "
        "given to a known aircraft, one that ADS-B or a Mode S radar sees, when they fall "
        "inside its gate; an aircraft no reference sees but two such radars do gets a path "
        "of its own, from the tracks their plots form. Only associated plots enter the "
        "calibration. "
        "<b>Left out</b>: plots not associated with any known aircraft (false plots, and "
        "plots of aircraft that neither a reference nor a second such radar sees); "
        "<b>ambiguous</b>: plots that fit two aircraft "
        "almost equally well, also left out of the fit.</p>"]
    rows, classes, flagged = [], [], []
    for rid, figures in radars.items():
        if not isinstance(figures, Mapping):
            continue
        row, flag = _association_row(str(rid), figures)
        rows.append(row)
        classes.append("flag" if flag else "")
        if flag:
            flagged.append(f"{rid} ({_percent_text(figures['tail_fraction'], 1)})")
    if not rows:
        parts.append("<p>No radar was associated.</p>")
    else:
        expected = 100 * (1.0 - TAIL_PROBABILITY)
        if flagged:
            parts.append(
                f'<p class="warn"><b>Tail fraction above {100 * TAIL_FLAG:g} %: '
                f"{_esc(', '.join(flagged))}</b> (rows in red; {expected:g} % expected): "
                "plots given to the wrong aircraft, or a bias the model lacks.</p>")
        parts.append(_table(
            ["radar", "plots", "associated", "of them on<br>own paths", "ambiguous",
             "left out", "scans",
             "detection<br>probability", "false plots<br>per scan", "Mode 3/A<br>consistency",
             "tail<br>fraction"], rows, row_classes=classes))
        parts.append(
            '<p class="note">Plots: those without an address. Own paths: plots associated '
            "with an aircraft no reference sees. Detection probability: plots associated "
            "over the scans each associated aircraft spans. False plots per scan: "
            "plots left out per antenna turn (an upper bound: it counts plots of aircraft no "
            "reference sees). Mode 3/A consistency: of the associated plots with a Mode 3/A "
            "code, the share whose code matches one the aircraft reported (– when there is "
            "no code to compare, e.g. a primary radar). Tail fraction: share of the "
            "associated plots that fit their aircraft "
            f"worse than the chi-square's {100 * TAIL_PROBABILITY:g} % point; near "
            f"{expected:g} % when the gates are right, flagged above {100 * TAIL_FLAG:g} "
            "%.</p>")
    parts.append(_association_runs(association))
    return "".join(parts)


def _span_text(times, epoch_utc: datetime | None = None) -> str:
    if len(times) == 0:
        return "–"
    t0, t1 = float(times.min()), float(times.max())
    return f"{span_text(t0, t1, epoch_utc)} ({duration_text(t1 - t0)})"


def _data_section(cal: Calibration, dataset: Dataset, views: Mapping[str, ResidualView]
                  ) -> str:
    plots = dataset.plots
    counts = plots.groupby("radar_id").size()
    reference = next(iter(views.values())).reference if views else "adsb"
    rows = []
    for rid, site in dataset.sites.items():
        sel = plots[plots["radar_id"] == rid]
        rows.append([
            _esc(rid), "3-D" if site.is_3d else "2-D", f"{int(counts.get(rid, 0)):,}",
            f"{cal.n_plots[rid]:,}" if rid in cal.radar_ids and rid in cal.n_plots
            else ("–" if rid in cal.radar_ids else "not calibrated"),
            f"{len(views[rid].after):,}" if rid in views else "–",
            str(sel["target_id"].nunique()), _span_text(sel["time_s"], dataset.epoch_utc),
        ])
    compared = "aligned with ADS-B" if reference == "adsb" else "cross-radar residuals"
    table = _table(["radar", "type", "plots", "plots used", compared, "aircraft",
                    "time span (UTC)"], rows, left=2)
    lines = [f"<p>{len(plots):,} plots from {len(dataset.sites)} radars, "
             f"{_span_text(plots['time_s'], dataset.epoch_utc)} UTC.</p>" if len(plots)
             else "<p>No plots.</p>"]
    if dataset.adsb is None:
        lines.append("<p>No ADS-B table.</p>")
    else:
        a = dataset.adsb
        lines.append(f"<p>{len(a):,} ADS-B reports of {a['target_id'].nunique()} aircraft"
                     + (f", {_span_text(a['time_s'], dataset.epoch_utc)} UTC" if len(a) else "")
                     + ".</p>")
    return "".join(lines) + table


# -------------------------------------------------------------------- build
def page_sections(association: bool = False) -> tuple[tuple[str, str], ...]:
    """The page's sections in order: :data:`SECTIONS`, with :data:`ASSOCIATION_SECTION`
    before ``data`` when ``association``.

    Parameters
    ----------
    association : bool
        Whether the result has ``info["association"]``.

    Returns
    -------
    tuple of (str, str)
        ``(id, heading)`` per section.
    """
    if not association:
        return SECTIONS
    at = [sid for sid, _ in SECTIONS].index("data")
    return (*SECTIONS[:at], ASSOCIATION_SECTION, *SECTIONS[at:])


def _as_truth(truth: Any) -> dict[str, RadarBias] | None:
    if truth is None:
        return None
    if isinstance(truth, str | Path):
        from graphcal.data.calibration import read_biases

        return read_biases(truth)
    if isinstance(truth, Calibration):
        return {rid: truth.bias(rid) for rid in truth.radar_ids}
    return {str(k): v for k, v in truth.items()}


def _truth_atmosphere(truth: Any) -> dict[str, Any] | None:
    """The true height model of a truth file or Calibration, when it has one."""
    from graphcal.data.calibration import read_height_model

    pair = read_height_model(truth)
    return None if pair is None else dict(zip(("height_offset_m", "height_scale"), pair,
                                              strict=True))


def build_report(
    calibration: Calibration,
    dataset: Dataset,
    *,
    truth: Mapping[str, RadarBias] | str | Path | None = None,
    crlb: Any = None,
    title: str | None = None,
    figures: dict[str, list[Any]] | None = None,
    command: str | None = None,
) -> str:
    """The HTML report of a calibration on its dataset (see the module doc).

    Parameters
    ----------
    calibration : Calibration
        The estimate (from an estimator or :meth:`Calibration.read_json`).
    dataset : Dataset
        The measured dataset it was computed from.
    truth : mapping of radar id to RadarBias, or path, optional
        True biases (e.g. ``read_biases("truth.json")``): adds truth, error and
        z-score columns, |z| > 3 flagged.
    crlb : CrlbResult, False or None
        A result of :func:`graphcal.analysis.crlb.crlb` (``.sigma(radar_id, key)``);
        ``None`` uses the sigmas the estimator recorded, else computes them;
        ``False`` skips them.
    title : str, optional
        Page title.
    figures : dict, optional
        When given, each matplotlib figure is also kept (open) in
        ``figures[section id]`` instead of being closed, e.g. for a PDF.
    command : str, optional
        The command line that made the report, shown in the header.

    Returns
    -------
    str
        One self-contained HTML page.
    """
    from graphcal.data.correct import correct_dataset

    plt = pyplot()  # select the Agg backend before any figure
    truth_biases = _as_truth(truth)
    crlb_note = None
    if crlb is None and calibration.info.get("crlb_sigma"):
        crlb = _RecordedCrlb(calibration.info["crlb_sigma"])
    elif crlb is None:
        crlb, crlb_note = _compute_crlb(dataset)
    elif crlb is False:
        crlb, crlb_note = None, None
    radar_ids = [rid for rid in calibration.radar_ids if rid in dataset.sites]
    corrected = correct_dataset(
        dataset, {rid: calibration.bias(rid) for rid in radar_ids})
    views = residual_views(dataset, calibration)
    rng = np.random.default_rng(SEED)

    def emit(section: str, fig, alt: str) -> str:
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=DPI)
        if figures is not None:
            figures.setdefault(section, []).append(fig)
        else:
            plt.close(fig)
        return _img(buffer.getvalue(), alt)

    body: dict[str, str] = {}
    est = _estimates_section(calibration, truth_biases, crlb, _truth_atmosphere(truth))
    if crlb_note:
        est += f'<p class="note">CRLB column omitted: {_esc(crlb_note)}.</p>'
    body["estimates"] = est
    if not calibration.labels:
        body["correlation"] = "<p>No estimated parameters.</p>"
    elif len(calibration.labels) <= MAX_TABLE_PARAMETERS:
        body["correlation"] = correlation_table(calibration)
        if figures is not None:  # the PDF has no tables: the matrix as a figure
            figures.setdefault("correlation", []).append(correlation_figure(calibration))
    else:
        body["correlation"] = emit("correlation", correlation_figure(calibration),
                                   "correlation matrix")
    body["residuals"] = _residuals_section(views, emit, rng)
    body["binned"] = _binned_section(views, emit, dataset.epoch_utc)
    body["pairs"] = _pairs_section(views)
    body["histograms"] = _histograms_section(views, emit)
    body["map"] = emit("map", map_figure(dataset, corrected, radar_ids, rng), "map") + (
        f'<p class="note">East and north [km] from the network centre (the mean of the sites), '
        "equal scales. Rings: ground distance from each radar in round steps out to its "
        f"farthest plot. Coverage: at most {MAX_MAP_POINTS} corrected plots per radar; 2-D "
        "plots are placed at the elevation of their Mode C altitude (0 when unknown). Black "
        "lines: ADS-B tracks of the aircraft seen by the most radars; right, the first of "
        "them with each radar's plots before and after correction.</p>")
    body["model-checks"] = _model_checks_section(calibration, emit, dataset.epoch_utc)
    body["observability"] = _observability_section(calibration)
    association = _association_section(calibration)
    if association is not None:
        body[ASSOCIATION_SECTION[0]] = association
    body["data"] = _data_section(calibration, dataset, views)

    title = title or f"graphcal calibration report ({calibration.method or 'result'})"
    shown = page_sections(association is not None)
    nav = "".join(f'<a href="#{sid}">{_esc(name)}</a>' for sid, name in shown)
    sections = "".join(
        f'<section><h2 id="{sid}">{_esc(name)}</h2>{body[sid]}</section>' for sid, name in shown
    )
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{_esc(title)}</title><style>{_CSS}</style></head><body>"
        f"{_header(calibration, dataset, command, title)}<nav>{nav}</nav>{sections}"
        "</body></html>\n"
    )


def write_report(path: str | Path, calibration: Calibration, dataset: Dataset, *,
                 truth: Mapping[str, RadarBias] | str | Path | None = None,
                 crlb: Any = None, pdf: str | Path | None = None,
                 command: str | None = None) -> Path:
    """Write :func:`build_report` to ``path`` atomically; optionally the figures as a PDF.

    With ``pdf``, the same figures are also written, one per page, with
    matplotlib's ``PdfPages`` (tables are only in the HTML).
    """
    from graphcal.core.atomic import atomic_write_text

    path = Path(path)
    figures: dict[str, list[Any]] | None = {} if pdf is not None else None
    text = build_report(calibration, dataset, truth=truth, crlb=crlb, figures=figures,
                        command=command)
    atomic_write_text(path, text)
    if pdf is not None and figures is not None:
        _write_pdf(Path(pdf), figures)
    return path


def _write_pdf(path: Path, figures: dict[str, list[Any]]) -> None:
    """The figures, one per page, into a PDF (written to a temporary file, then renamed)."""
    import os
    import tempfile

    from matplotlib.backends.backend_pdf import PdfPages

    plt = pyplot()
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".pdf", dir=path.parent)
    os.close(handle)
    try:
        with PdfPages(temporary) as pdf:
            for sid, _ in SECTIONS:
                for fig in figures.get(sid, []):
                    pdf.savefig(fig)
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise
    finally:
        for figs in figures.values():
            for fig in figs:
                plt.close(fig)


def build_report_for(cal: Calibration, dataset: Dataset,
                     truth_path: str | Path | None = None, *,
                     command: str | None = None) -> str:
    """The report text :func:`write_report_for` writes, built without writing anything
    (the slow part: a command builds it first, then publishes all its outputs at once)."""
    if truth_path is None and dataset.path is not None:
        candidate = Path(dataset.path) / "truth.json"
        truth_path = candidate if candidate.exists() else None
    return build_report(cal, dataset, truth=truth_path, command=command)


def write_report_for(cal: Calibration, dataset: Dataset, path: str | Path,
                     truth_path: str | Path | None = None, *,
                     command: str | None = None) -> Path:
    """Write the report of ``cal`` (e.g. from ``calibrate --report``) to ``path``.

    ``truth_path`` is a ``truth.json`` (or any result JSON) read with
    :func:`graphcal.data.calibration.read_biases`; ``None`` uses
    ``dataset.path / "truth.json"`` when that file exists.  A ``.pdf`` suffix
    is not supported: the report is HTML.  ``command`` is the command line shown in
    the header.
    """
    if truth_path is None and dataset.path is not None:
        candidate = Path(dataset.path) / "truth.json"
        truth_path = candidate if candidate.exists() else None
    return write_report(path, cal, dataset, truth=truth_path, command=command)

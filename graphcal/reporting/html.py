"""A self-contained HTML report of a calibration.

:func:`build_report` returns one HTML page (inline CSS, figures embedded as
base64 PNG made with matplotlib's Agg backend, no external assets) with these
sections, each an ``<h2>`` with a stable ``id``:

``estimates``      value ± sigma per radar and parameter (contract units), the
                   truth and z-score when given, the CRLB sigma and sigma / CRLB sigma
                   when :mod:`graphcal.analysis.crlb` is available;
``residuals``      range and azimuth residuals against ADS-B versus range and
                   azimuth, before and after correction, per radar;
``histograms``     residuals after correction with the expected N(0, sigma);
``map``            radar sites, coverage (the plot cloud), tracks before and
                   after correction, lon/lat axes;
``correlation``    the correlation matrix of the estimated parameters;
``model-checks``   per radar, the binned means (± 1 sigma) of the corrected residuals
                   against range, elevation or height, azimuth and time that the model
                   checks tested (:mod:`graphcal.analysis.model_checks`, read from
                   ``info["model_checks"]``), with the part the model's own terms
                   absorb, and the tests that fired marked;
``observability``  degree, rank, undetermined parameters, every warning and the
                   robust kernel's down-weighted measurements per radar;
``data``           plots per radar, ADS-B reports, time span.

Residuals are recomputed here: each radar's plots are aligned with ADS-B
(:func:`graphcal.data.align.align_adsb`) once as measured and once after
:func:`graphcal.data.correct.correct_dataset` (so a time offset is corrected too).
Scatter plots show a random subsample of at most :data:`MAX_SCATTER` points per
radar (stated under each figure); histograms and statistics use every point.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.data.bias import CONTRACT_KEYS, ECCENTRICITY_NAMES, PARAMETER_NAMES, RadarBias
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset

#: Section ids, in page order.
SECTIONS: tuple[tuple[str, str], ...] = (
    ("estimates", "Estimates"),
    ("residuals", "Residuals against ADS-B"),
    ("histograms", "Residual histograms after correction"),
    ("map", "Map"),
    ("correlation", "Correlation of the estimates"),
    ("model-checks", "Model checks: structure left in the residuals"),
    ("observability", "Observability and warnings"),
    ("data", "Data"),
)
#: Most points per radar drawn in a scatter plot (a random subsample beyond).
MAX_SCATTER = 2000
#: Most plots per radar drawn in the map's coverage cloud.
MAX_MAP_POINTS = 1500
#: Tracks drawn before/after correction on the map.
N_MAP_TRACKS = 3
#: Half-width [s] of the time window of the zoomed track on the map.
ZOOM_S = 40.0
#: Figure resolution.
DPI = 80
#: Seed of the subsampling (the report is reproducible).
SEED = 0

_KEYS: tuple[str, ...] = tuple(
    CONTRACT_KEYS[n][0] for n in (*PARAMETER_NAMES, *ECCENTRICITY_NAMES, "time_offset")
)

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em;
color:#222;max-width:1200px}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ddd;padding:3px 8px;
text-align:right;font-variant-numeric:tabular-nums}th{background:#f4f4f4}
td.l,th.l{text-align:left}img{max-width:100%;height:auto}.note{color:#555;font-size:.9em}
.warn{color:#a15c00}nav a{margin-right:1em}
"""


# --------------------------------------------------------------------- helpers
def _esc(value: Any) -> str:
    return html.escape(str(value))


def _fmt(value: float | None, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–" if value is None else str(value)
    return f"{value:.{digits}g}"


def _figure_png(fig) -> bytes:
    """PNG bytes of a matplotlib figure (then closed)."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    plt.close(fig)
    return buffer.getvalue()


def _img(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{_esc(alt)}">'


def _subsample(n: int, k: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """Sorted random indices of at most ``k`` of ``n`` items."""
    if n <= k:
        return np.arange(n)
    return np.sort(rng.choice(n, size=k, replace=False))


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _table(header: list[str], rows: list[list[str]], left: int = 1) -> str:
    """An HTML table; the first ``left`` columns are left-aligned; cells already escaped."""
    def cells(values: list[str], tag: str) -> str:
        return "".join(
            f'<{tag} class="l">{v}</{tag}>' if i < left else f"<{tag}>{v}</{tag}>"
            for i, v in enumerate(values)
        )

    body = "".join(f"<tr>{cells(r, 'td')}</tr>" for r in rows)
    return f"<table><tr>{cells(header, 'th')}</tr>{body}</table>"


# ------------------------------------------------------------------- residuals
@dataclass
class RadarResiduals:
    """Residuals of one radar's plots against ADS-B (measured minus ADS-B).

    Attributes are per aligned plot: reference range [m] and azimuth [deg],
    range residual [m] and azimuth residual [mrad] before and after correction,
    and the expected 1-sigma of the residual after correction (radar noise and
    interpolated ADS-B error), range [m] and azimuth [mrad]; NaN where the
    radar's sigma is unknown.
    """

    radar_id: str
    range_km: NDArray[np.float64]
    azimuth_deg: NDArray[np.float64]
    range_before_m: NDArray[np.float64]
    azimuth_before_mrad: NDArray[np.float64]
    range_after_m: NDArray[np.float64]
    azimuth_after_mrad: NDArray[np.float64]
    range_range_km_after: NDArray[np.float64]
    azimuth_deg_after: NDArray[np.float64]
    sigma_range_m: NDArray[np.float64]
    sigma_azimuth_mrad: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.range_after_m)


def _polar_residuals(al) -> tuple[NDArray, NDArray]:
    measured_r = al.plots.range_m
    measured_az = al.plots.azimuth_rad
    ref = al.reference_polar
    return measured_r - ref[:, 0], frames.wrap_to_pi(measured_az - ref[:, 1]) * 1e3


def _expected_sigmas(site, al) -> tuple[NDArray, NDArray]:
    """1-sigma of the corrected residual: radar noise plus projected ADS-B error."""
    ref = al.reference_polar
    cov = al.reference_enu_cov_m2
    az, el = ref[:, 1], ref[:, 2]
    ce, se = np.cos(el), np.sin(el)
    # d range / d enu = (sin az cos el, cos az cos el, sin el); d az / d enu = (cos az,
    # -sin az, 0) / (r cos el).
    var_r_ref = (cov[:, 0, 0] * (np.sin(az) * ce) ** 2 + cov[:, 1, 1] * (np.cos(az) * ce) ** 2
                 + cov[:, 2, 2] * se**2)
    rho = np.maximum(ref[:, 0] * ce, 1.0)
    var_az_ref = (cov[:, 0, 0] * np.cos(az) ** 2 + cov[:, 1, 1] * np.sin(az) ** 2) / rho**2
    sig_r = np.sqrt(site.sigma_range_m**2 + var_r_ref)
    sig_az = np.sqrt(site.sigma_azimuth_rad**2 + var_az_ref) * 1e3
    return sig_r, sig_az


def adsb_residuals(dataset: Dataset, corrected: Dataset, radar_ids: list[str]
                   ) -> dict[str, RadarResiduals]:
    """Residuals against ADS-B before (``dataset``) and after (``corrected``) correction.

    Radars without any plot aligned with ADS-B are left out; empty without ADS-B.
    """
    from graphcal.data.align import align_adsb

    out: dict[str, RadarResiduals] = {}
    if dataset.adsb is None or len(dataset.adsb) == 0:
        return out
    for rid in radar_ids:
        if rid not in dataset.sites:
            continue
        before = align_adsb(dataset, rid)
        after = align_adsb(corrected, rid)
        if len(before) == 0 or len(after) == 0:
            continue
        rb, ab = _polar_residuals(before)
        ra, aa = _polar_residuals(after)
        sr, sa = _expected_sigmas(dataset.sites[rid], after)
        out[rid] = RadarResiduals(
            rid,
            before.reference_polar[:, 0] / 1e3, np.rad2deg(before.reference_polar[:, 1]),
            rb, ab, ra, aa,
            after.reference_polar[:, 0] / 1e3, np.rad2deg(after.reference_polar[:, 1]),
            sr, sa,
        )
    return out


def residuals_figure(res: RadarResiduals, rng: np.random.Generator | None = None):
    """The 2 x 2 residual panel of one radar: range / azimuth residual vs range / azimuth."""
    plt = _pyplot()
    rng = np.random.default_rng(SEED) if rng is None else rng
    ib = _subsample(len(res.range_before_m), MAX_SCATTER, rng)
    ia = _subsample(len(res.range_after_m), MAX_SCATTER, rng)
    fig, axes = plt.subplots(2, 2, figsize=(10, 5.6), sharey="row")
    panels = [
        (0, 0, res.range_km, res.range_range_km_after, res.range_before_m, res.range_after_m,
         "range [km]", "range residual [m]"),
        (0, 1, res.azimuth_deg, res.azimuth_deg_after, res.range_before_m, res.range_after_m,
         "azimuth [deg]", None),
        (1, 0, res.range_km, res.range_range_km_after, res.azimuth_before_mrad,
         res.azimuth_after_mrad, "range [km]", "azimuth residual [mrad]"),
        (1, 1, res.azimuth_deg, res.azimuth_deg_after, res.azimuth_before_mrad,
         res.azimuth_after_mrad, "azimuth [deg]", None),
    ]
    for row, col, xb, xa, yb, ya, xlabel, ylabel in panels:
        ax = axes[row, col]
        ax.scatter(xb[ib], yb[ib], s=3, c="tab:red", alpha=0.35, lw=0, label="before")
        ax.scatter(xa[ia], ya[ia], s=3, c="tab:blue", alpha=0.35, lw=0, label="after")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_xlabel(xlabel)
        if ylabel:
            ax.set_ylabel(ylabel)
        if col == 1:
            ax.set_xlim(0, 360)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", markerscale=4, fontsize=8)
    fig.suptitle(f"{res.radar_id}: residuals against ADS-B before and after correction")
    # Fixed margins: tight_layout would cost a full extra draw per figure.
    fig.subplots_adjust(left=0.08, right=0.985, bottom=0.09, top=0.92, hspace=0.28, wspace=0.04)
    return fig


def _gauss(x: NDArray, sigma: float) -> NDArray:
    return np.exp(-0.5 * (x / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))


def histograms_figure(res: RadarResiduals):
    """Histograms of the corrected range and azimuth residuals with the expected N(0, sigma)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 2.8))
    for ax, values, sig, unit, name in (
        (axes[0], res.range_after_m, res.sigma_range_m, "m", "range"),
        (axes[1], res.azimuth_after_mrad, res.sigma_azimuth_mrad, "mrad", "azimuth"),
    ):
        values = values[np.isfinite(values)]
        sigma = float(np.sqrt(np.mean(sig**2))) if np.all(np.isfinite(sig)) else math.nan
        width = 5.0 * (sigma if math.isfinite(sigma) else float(np.std(values)) or 1.0)
        ax.hist(values, bins=60, range=(-width, width), density=True, color="tab:blue",
                alpha=0.6, label=f"after correction (n={len(values)})")
        if math.isfinite(sigma):
            x = np.linspace(-width, width, 300)
            ax.plot(x, _gauss(x, sigma), "k", lw=1.5, label=f"N(0, {sigma:.3g} {unit})")
        ax.set_xlabel(f"{name} residual [{unit}]")
        mean, sd = float(np.mean(values)), float(np.std(values))
        ax.set_title(f"{res.radar_id} {name}: mean {mean:.3g}, sd {sd:.3g} {unit}", fontsize=10)
        ax.legend(fontsize=8)
    fig.subplots_adjust(left=0.06, right=0.985, bottom=0.17, top=0.88, wspace=0.15)
    return fig


# ------------------------------------------------------------------------ map
def _plots_lonlat(dataset: Dataset, rid: str, rows: NDArray | None = None
                  ) -> tuple[NDArray, NDArray]:
    """Longitude and latitude [deg] of one radar's plots (altitude from Mode C or 0 el)."""
    plots = dataset.plots_of(rid)
    if rows is not None:
        plots = plots.iloc[rows]
    site = dataset.sites[rid]
    r = plots["range_m"].to_numpy(float)
    az = np.deg2rad(plots["azimuth_deg"].to_numpy(float))
    el = np.deg2rad(plots["elevation_deg"].to_numpy(float))
    if not site.is_3d or not np.all(np.isfinite(el)):
        el = np.where(np.isfinite(el) & site.is_3d, el, 0.0)
        if "altitude_m" in plots:
            alt = plots["altitude_m"].to_numpy(float)
        else:
            alt = np.full(len(r), np.nan)
        known = np.isfinite(alt)
        if known.any():
            el_alt = frames.elevation_from_height(r[known], alt[known], site.lat_rad, site.alt_m)
            el[known] = np.where(np.isfinite(el_alt), el_alt, 0.0)
    ecef = site.ecef_from_polar(r, az, el)
    lat, lon, _ = frames.ecef_to_geodetic(ecef)
    return np.rad2deg(lon), np.rad2deg(lat)


def map_figure(dataset: Dataset, corrected: Dataset, radar_ids: list[str],
               rng: np.random.Generator | None = None):
    """Sites, coverage (plot cloud), and a few tracks before / after correction with ADS-B."""
    plt = _pyplot()
    rng = np.random.default_rng(SEED) if rng is None else rng
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 5.5))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    color = {rid: colors[i % len(colors)] for i, rid in enumerate(dataset.radar_ids)}
    for rid in radar_ids:
        if rid not in dataset.sites:
            continue
        n = int((dataset.plots["radar_id"] == rid).sum())
        rows = _subsample(n, MAX_MAP_POINTS, rng)
        lon, lat = _plots_lonlat(corrected, rid, rows)
        ax0.scatter(lon, lat, s=2, color=color[rid], alpha=0.3, lw=0)
    for rid, site in dataset.sites.items():
        lon, lat = math.degrees(site.lon_rad), math.degrees(site.lat_rad)
        ax0.plot(lon, lat, "^", color=color[rid], mec="k", ms=10)
        ax0.annotate(rid, (lon, lat), xytext=(5, 5), textcoords="offset points", fontsize=9,
                     weight="bold")
    ax0.set_title("sites and coverage (corrected plots, subsampled)", fontsize=10)
    # Tracks: the targets seen by the most radars (then with the most plots).
    plots = dataset.plots[dataset.plots["target_id"] != ""]
    counts = plots.groupby("target_id")["radar_id"].agg(["nunique", "size"])
    targets = list(counts.sort_values(["nunique", "size"], ascending=False).index[:N_MAP_TRACKS])
    for k, target in enumerate(targets):
        # The zoom (right panel): +- ZOOM_S around the middle of the first target's plots.
        t_mid = float(np.median(plots.loc[plots["target_id"] == target, "time_s"]))
        if dataset.adsb is not None:
            adsb = dataset.adsb[dataset.adsb["target_id"] == target].sort_values("time_s")
            ax0.plot(adsb["lon_deg"], adsb["lat_deg"], "k-", lw=0.8)
            if k == 0:
                near = adsb[(adsb["time_s"] - t_mid).abs() <= ZOOM_S]
                ax1.plot(near["lon_deg"], near["lat_deg"], "k-", lw=1.5, label="ADS-B")
        if k > 0:
            continue
        for rid in radar_ids:
            if rid not in dataset.sites:
                continue
            own = dataset.plots_of(rid)
            rows = np.flatnonzero((own["target_id"].to_numpy() == target)
                                  & (np.abs(own["time_s"].to_numpy(float) - t_mid) <= ZOOM_S))
            if rows.size == 0:
                continue
            lon_b, lat_b = _plots_lonlat(dataset, rid, rows)
            lon_a, lat_a = _plots_lonlat(corrected, rid, rows)
            ax1.plot(lon_b, lat_b, "x", ms=3, color=color[rid], alpha=0.6,
                     label=f"{rid} before")
            ax1.plot(lon_a, lat_a, ".-", ms=3, lw=0.6, color=color[rid],
                     label=f"{rid} after")
    if targets:
        ax1.set_title(f"target {targets[0]}, {2 * ZOOM_S:.0f} s: plots before (x) and after (.) "
                      "correction",
                      fontsize=10)
        ax1.legend(fontsize=7, ncol=2)
    for ax in (ax0, ax1):
        ax.set_xlabel("longitude [deg]")
        ax.set_ylabel("latitude [deg]")
        ax.grid(alpha=0.3)
        lat0 = float(np.mean([s.lat_rad for s in dataset.sites.values()]))
        ax.set_aspect(1.0 / max(math.cos(lat0), 0.1), adjustable="datalim")
    fig.tight_layout()
    return fig


# ----------------------------------------------------------------- correlation
def correlation_figure(cal: Calibration):
    """The correlation matrix of the estimated parameters, labelled."""
    plt = _pyplot()
    rho = np.asarray(cal.correlation(), dtype=float)
    labels = cal.contract_labels()
    n = len(labels)
    size = min(max(4.0, 0.42 * n + 2.5), 14.0)
    fig, ax = plt.subplots(figsize=(size + 1.2, size))
    image = ax.imshow(np.ma.masked_invalid(rho), cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_xticks(range(n), labels, rotation=90, fontsize=7)
    ax.set_yticks(range(n), labels, fontsize=7)
    if n <= 20:
        for i in range(n):
            for j in range(n):
                if np.isfinite(rho[i, j]):
                    ax.text(j, i, f"{rho[i, j]:.2f}", ha="center", va="center", fontsize=6,
                            color="w" if abs(rho[i, j]) > 0.6 else "k")
    fig.colorbar(image, ax=ax, fraction=0.046, label="correlation")
    fig.tight_layout()
    return fig


# ----------------------------------------------------------------- model checks
def _split_unit(key: str) -> tuple[str, str]:
    """``"range_m"`` -> ``("range", "m")``."""
    name, _, unit = key.rpartition("_")
    return name, unit


def model_checks_figure(radar_id: str, entry: Mapping[str, Any]):
    """One radar's binned residual means, a panel per test (rows: residuals; columns: variables).

    ``entry`` is one radar of ``info["model_checks"]["radars"]``.  Each panel:
    bin means ± 1 sigma against the bin centres (the bins' ranges as horizontal
    bars), the part the model's own terms absorb (dashed), zero; a test that
    fired has a red frame and title.
    """
    plt = _pyplot()
    tests = list(entry.get("tests") or [])
    rows = list(dict.fromkeys(t["residual"] for t in tests))
    cols = list(dict.fromkeys(t["against"] for t in tests))
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(3.5 * len(cols) + 0.6,
                                                             2.4 * len(rows) + 0.6),
                             squeeze=False, sharey="row")
    for ax in axes.flat:
        ax.set_visible(False)
    for t in tests:
        i, j = rows.index(t["residual"]), cols.index(t["against"])
        ax = axes[i, j]
        ax.set_visible(True)
        coord, unit = _split_unit(t["residual"])
        var, vunit = _split_unit(t["against"])
        b = t["bins"]
        x = np.asarray(b[f"centre_{vunit}"], dtype=float)
        lo = x - np.asarray(b[f"lower_{vunit}"], dtype=float)
        hi = np.asarray(b[f"upper_{vunit}"], dtype=float) - x
        mean = np.asarray(b[f"mean_{unit}"], dtype=float)
        sigma = np.asarray(b[f"sigma_{unit}"], dtype=float)
        fired = bool(t.get("fired"))
        color = "tab:red" if fired else "tab:blue"
        ax.axhline(0.0, color="k", lw=0.6)
        ax.errorbar(x, mean, yerr=sigma, xerr=[lo, hi], fmt="o", ms=3, lw=1, color=color,
                    elinewidth=1, capsize=2)
        ax.plot(x, np.asarray(b[f"absorbed_{unit}"], dtype=float), "--", color="0.4", lw=1)
        ax.set_title(("FIRED  " if fired else "")
                     + f"χ² {t['chi2']:.3g} over {t['dof']:.3g} dof, p {_p_text(t)}",
                     fontsize=8, color="tab:red" if fired else "k")
        if fired:
            for spine in ax.spines.values():
                spine.set_edgecolor("tab:red")
                spine.set_linewidth(2)
        ax.set_xlabel(f"{var} [{vunit}]", fontsize=8, labelpad=1)
        first = min(cols.index(u["against"]) for u in tests if u["residual"] == t["residual"])
        if j == first:
            ax.set_ylabel(f"{coord} [{unit}]", fontsize=8)
        ax.yaxis.set_tick_params(labelleft=True)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{radar_id}: binned residual means ± 1σ after correction "
                 f"(dashed: absorbed by the model's own terms)", fontsize=10)
    top = 1.0 - 0.7 / fig.get_figheight()
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.45 / fig.get_figheight(), top=top,
                        hspace=0.6, wspace=0.16)
    return fig


def _p_text(test: Mapping[str, Any]) -> str:
    """A test's p-value, as a power of ten where it underflows to 0."""
    p = test.get("p_value")
    if p:
        return f"{p:.2g}"
    log10_p = test.get("log10_p")
    return f"1e{log10_p:.0f}" if log10_p is not None else "–"


def _model_checks_section(cal: Calibration, emit) -> str:
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
                _fmt(t["chi2"], 3), _fmt(t["dof"], 3), _p_text(t),
                _fmt(entry.get("threshold_p"), 2),
                '<span class="warn">fired</span>' if t.get("fired") else "",
                _esc(f"{t.get('pattern', '')} ({t.get('magnitude', '')})") if t.get("fired")
                else "",
            ])
    for rid, entry in radars.items():
        parts.append(f"<h3>{_esc(rid)}</h3>"
                     + emit("model-checks", model_checks_figure(rid, entry),
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


# ----------------------------------------------------------------- sections
def _estimates_section(cal: Calibration, truth: Mapping[str, RadarBias] | None,
                       crlb: Any, truth_atmosphere: Mapping[str, Any] | None = None) -> str:
    header = ["radar", "parameter", "estimate", "± 1σ"]
    if truth is not None:
        header += ["truth", "error / σ"]
    if crlb is not None:
        header += ["CRLB σ", "σ / CRLB σ"]
    rows = []
    for rid in cal.radar_ids:
        for key in _KEYS:
            value = cal.value(rid, key)
            if value is None:
                continue
            sigma = cal.sigma(rid, key)
            row = [_esc(rid), _esc(key), _fmt(value), "fixed" if sigma is None else _fmt(sigma, 3)]
            if truth is not None:
                tb = truth.get(rid)
                if tb is None:
                    row += ["–", "–"]
                else:
                    name = key_name(key)
                    t = tb.value(name) * CONTRACT_KEYS[name][1]
                    z = (value - t) / sigma if sigma else math.nan
                    row += [_fmt(t), _fmt(z, 2)]
            if crlb is not None:
                cs = _crlb_sigma(crlb, rid, key)
                eff = sigma / cs if cs and sigma is not None else None
                row += [_fmt(cs, 3), _fmt(eff, 3)]
            rows.append(row)
    rows += _atmosphere_rows(cal, truth_atmosphere, truth is not None, crlb is not None)
    units = ('<p class="note">Units: range_offset_m m, range_gain fraction, *_mrad mrad, '
             f"time_offset_s s. Method: {_esc(cal.method or '?')}.</p>")
    if cal.atmosphere is not None:
        units += ('<p class="note">atmosphere: the height model of pressure altitudes, '
                  "height above the ellipsoid = (1 + height_scale) × pressure altitude + "
                  "height_offset_m (contract v2).</p>")
    return _table(header, rows, left=2) + units


def _atmosphere_rows(cal: Calibration, truth: Mapping[str, Any] | None, truth_columns: bool,
                     crlb_columns: bool) -> list[list[str]]:
    """Rows of the estimates table for the height model (``atmosphere`` block), if any."""
    atmosphere = cal.atmosphere
    if atmosphere is None:
        return []
    rows = []
    recorded = cal.info.get("crlb_sigma") or {}
    for i, key in enumerate(("height_offset_m", "height_scale")):
        value, sigma = getattr(atmosphere, key), atmosphere.sigma.get(key)
        shown = _fmt(value)
        if not atmosphere.determined or f"atmosphere.{key}" in cal.info.get("undetermined", []):
            shown = "not determined"
        row = ["atmosphere" if i == 0 else "", _esc(key), shown,
               "–" if sigma is None else _fmt(sigma, 3)]
        if truth_columns:
            true = (truth or {}).get(key)
            row += (["–", "–"] if true is None else
                    [_fmt(true), _fmt((value - true) / sigma if sigma else math.nan, 2)])
        if crlb_columns:
            cs = recorded.get(f"atmosphere.{key}")
            row += [_fmt(cs, 3), _fmt(sigma / cs if cs and sigma else None, 3)]
        rows.append(row)
    return rows


def key_name(key: str) -> str:
    """Internal parameter name of a contract key."""
    from graphcal.data.bias import NAME_FROM_KEY

    return NAME_FROM_KEY[key]


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


def _data_section(cal: Calibration, dataset: Dataset, residuals: Mapping[str, RadarResiduals]
                  ) -> str:
    plots = dataset.plots
    counts = plots.groupby("radar_id").size()
    rows = []
    for rid, site in dataset.sites.items():
        sel = plots[plots["radar_id"] == rid]
        span = (f"{sel['time_s'].min():.1f} – {sel['time_s'].max():.1f}" if len(sel) else "–")
        rows.append([
            _esc(rid), "3-D" if site.is_3d else "2-D", str(int(counts.get(rid, 0))),
            str(cal.n_plots.get(rid, "–")) if rid in cal.radar_ids else "not calibrated",
            str(len(residuals[rid])) if rid in residuals else "–",
            str(sel["target_id"].nunique()), span,
        ])
    table = _table(["radar", "type", "plots", "plots used", "aligned with ADS-B", "targets",
                    "time span [s]"], rows)
    t = plots["time_s"]
    lines = [f"<p>{len(plots)} plots from {len(dataset.sites)} radars, "
             f"time {t.min():.1f} – {t.max():.1f} s ({t.max() - t.min():.0f} s).</p>"
             if len(plots) else "<p>No plots.</p>"]
    if dataset.adsb is None:
        lines.append("<p>No ADS-B table.</p>")
    else:
        a = dataset.adsb
        lines.append(f"<p>{len(a)} ADS-B reports of {a['target_id'].nunique()} aircraft"
                     + (f", time {a['time_s'].min():.1f} – {a['time_s'].max():.1f} s"
                        if len(a) else "") + ".</p>")
    if dataset.path is not None:
        lines.append(f'<p class="note">Dataset: {_esc(dataset.path)}</p>')
    return "".join(lines) + table


# -------------------------------------------------------------------- build
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
) -> str:
    """The HTML report of a calibration on its dataset (see the module doc).

    Parameters
    ----------
    calibration : Calibration
        The estimate (from an estimator or :meth:`Calibration.read_json`).
    dataset : Dataset
        The measured dataset it was computed from.
    truth : mapping of radar id to RadarBias, or path, optional
        True biases (e.g. ``read_biases("truth.json")``): adds truth and z-score columns.
    crlb : CrlbResult, False or None
        A result of :func:`graphcal.analysis.crlb.crlb` (``.sigma(radar_id, key)``);
        ``None`` computes it when :mod:`graphcal.analysis.crlb` exists; ``False`` skips it.
    title : str, optional
        Page title.
    figures : dict, optional
        When given, each matplotlib figure is also kept (open) in
        ``figures[section id]`` instead of being closed, e.g. for a PDF.

    Returns
    -------
    str
        One self-contained HTML page.
    """
    from graphcal.data.correct import correct_dataset

    _pyplot()  # select the Agg backend before any figure
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
    residuals = adsb_residuals(dataset, corrected, radar_ids)
    rng = np.random.default_rng(SEED)

    def emit(section: str, fig, alt: str) -> str:
        if figures is not None:
            figures.setdefault(section, []).append(fig)
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=DPI)
            return _img(buffer.getvalue(), alt)
        return _img(_figure_png(fig), alt)

    body: dict[str, str] = {}
    est = _estimates_section(calibration, truth_biases, crlb, _truth_atmosphere(truth))
    if crlb_note:
        est += f'<p class="note">CRLB column omitted: {_esc(crlb_note)}.</p>'
    body["estimates"] = est

    sub_note = (f'<p class="note">Scatter plots show at most {MAX_SCATTER} randomly chosen '
                "points per radar and stage; statistics and histograms use every aligned plot. "
                "Residual = plot minus the ADS-B position interpolated to the plot time, in the "
                "radar's polar coordinates (azimuth wrapped to ±π).</p>")
    if not residuals:
        missing = ('<p>No residuals against ADS-B: the dataset has no ADS-B table or no plot '
                   "could be aligned with it.</p>")
        body["residuals"] = missing
        body["histograms"] = missing
    else:
        res_parts, hist_parts, stat_rows = [sub_note], [], []
        for rid, res in residuals.items():
            res_parts.append(f"<h3>{_esc(rid)}</h3>"
                             + emit("residuals", residuals_figure(res, rng), f"{rid} residuals"))
            hist_parts.append(emit("histograms", histograms_figure(res), f"{rid} histograms"))
            stat_rows.append([
                _esc(rid), str(len(res)),
                _fmt(float(np.mean(res.range_before_m)), 3),
                _fmt(float(np.sqrt(np.mean(res.range_before_m**2))), 3),
                _fmt(float(np.mean(res.range_after_m)), 3),
                _fmt(float(np.sqrt(np.mean(res.range_after_m**2))), 3),
                _fmt(float(np.mean(res.azimuth_before_mrad)), 3),
                _fmt(float(np.sqrt(np.mean(res.azimuth_before_mrad**2))), 3),
                _fmt(float(np.mean(res.azimuth_after_mrad)), 3),
                _fmt(float(np.sqrt(np.mean(res.azimuth_after_mrad**2))), 3),
            ])
        res_parts.insert(1, _table(
            ["radar", "n", "range mean before [m]", "rms before", "mean after", "rms after",
             "azimuth mean before [mrad]", "rms before", "mean after", "rms after"], stat_rows))
        body["residuals"] = "".join(res_parts)
        body["histograms"] = (
            '<p class="note">Expected curve: N(0, σ) with σ² the mean over the plots of the '
            "radar's noise variance plus the interpolated ADS-B error projected on range / "
            "azimuth (sites.toml sigmas).</p>" + "".join(hist_parts))

    body["map"] = emit("map", map_figure(dataset, corrected, radar_ids, rng), "map") + (
        f'<p class="note">Coverage: at most {MAX_MAP_POINTS} corrected plots per radar; '
        "2-D plots are placed at the elevation of their Mode C altitude (0 when unknown). "
        "Black lines: ADS-B tracks of the targets seen by the most radars.</p>")
    if calibration.labels:
        body["correlation"] = emit("correlation", correlation_figure(calibration),
                                   "correlation matrix")
    else:
        body["correlation"] = "<p>No estimated parameters.</p>"
    body["model-checks"] = _model_checks_section(calibration, emit)
    body["observability"] = _observability_section(calibration)
    body["data"] = _data_section(calibration, dataset, residuals)

    title = title or f"graphcal calibration report ({calibration.method or 'result'})"
    nav = "".join(f'<a href="#{sid}">{_esc(name)}</a>' for sid, name in SECTIONS)
    sections = "".join(
        f'<section><h2 id="{sid}">{_esc(name)}</h2>{body[sid]}</section>' for sid, name in SECTIONS
    )
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{_esc(title)}</title><style>{_CSS}</style></head><body>"
        f"<h1>{_esc(title)}</h1><nav>{nav}</nav>{sections}</body></html>\n"
    )


def write_report(path: str | Path, calibration: Calibration, dataset: Dataset, *,
                 truth: Mapping[str, RadarBias] | str | Path | None = None,
                 crlb: Any = None, pdf: str | Path | None = None) -> Path:
    """Write :func:`build_report` to ``path`` atomically; optionally the figures as a PDF.

    With ``pdf``, the same figures are also written, one per page, with
    matplotlib's ``PdfPages`` (tables are only in the HTML).
    """
    from graphcal.core.atomic import atomic_write_text

    path = Path(path)
    figures: dict[str, list[Any]] | None = {} if pdf is not None else None
    text = build_report(calibration, dataset, truth=truth, crlb=crlb, figures=figures)
    atomic_write_text(path, text)
    if pdf is not None and figures is not None:
        _write_pdf(Path(pdf), figures)
    return path


def _write_pdf(path: Path, figures: dict[str, list[Any]]) -> None:
    """The figures, one per page, into a PDF (written to a temporary file, then renamed)."""
    import os
    import tempfile

    from matplotlib.backends.backend_pdf import PdfPages

    plt = _pyplot()
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


def write_report_for(cal: Calibration, dataset: Dataset, path: str | Path,
                     truth_path: str | Path | None = None) -> Path:
    """Write the report of ``cal`` (e.g. from ``calibrate --report``) to ``path``.

    ``truth_path`` is a ``truth.json`` (or any result JSON) read with
    :func:`graphcal.data.calibration.read_biases`; ``None`` uses
    ``dataset.path / "truth.json"`` when that file exists.  A ``.pdf`` suffix
    is not supported: the report is HTML.
    """
    if truth_path is None and dataset.path is not None:
        candidate = Path(dataset.path) / "truth.json"
        truth_path = candidate if candidate.exists() else None
    return write_report(path, cal, dataset, truth=truth_path)

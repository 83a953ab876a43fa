"""The figures of the HTML report (matplotlib, Agg backend).

* :func:`before_after_figure`: one radar's residuals against range, measured
  (left) and corrected (right) in separate panels, each with its own robust
  limits (:func:`graphcal.reporting.report_residuals.robust_limits`) and the
  count of points beyond them written above the panel.
* :func:`binned_figure`: one radar's corrected residuals binned against range,
  azimuth, elevation and time: mean with a band of ± 1 standard deviation per
  bin, and the expected ± 1 sigma dashed.
* :func:`histograms_figure`: corrected residuals with the expected N(0, sigma).
* :func:`map_figure`: local east/north in km around the network centre, equal
  aspect, range rings around each radar, the corrected plot cloud, ADS-B tracks,
  and one track before and after correction.
* :func:`correlation_figure`: the correlation matrix as an image (for networks
  too large for the report's table, and for the PDF).
* :func:`model_checks_figure`: the model checks' binned means.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset
from graphcal.reporting.display import clock_text
from graphcal.reporting.report_residuals import (
    COORDINATES,
    VARIABLES,
    ResidualView,
    Side,
    binned,
    robust_limits,
)

#: Most points per radar and stage drawn in a scatter panel (a random subsample beyond).
MAX_SCATTER = 2000
#: Most plots per radar drawn in the map's coverage cloud.
MAX_MAP_POINTS = 1500
#: Tracks drawn on the map.
N_MAP_TRACKS = 3
#: Half-width [s] of the time window of the zoomed track on the map.
ZOOM_S = 40.0
#: Residual coordinates drawn (a 2-D radar's Mode C altitude is summarised in tables only).
DRAWN = ("range", "azimuth", "elevation")
#: Colours of the two stages.
BEFORE_COLOUR, AFTER_COLOUR = "tab:red", "tab:blue"


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def subsample(n: int, k: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """Sorted random indices of at most ``k`` of ``n`` items."""
    if n <= k:
        return np.arange(n)
    return np.sort(rng.choice(n, size=k, replace=False))


def _coordinate_label(c: str) -> str:
    name, unit, _ = COORDINATES[c]
    return f"{name} residual [{unit}]"


def _drawn(view: ResidualView) -> list[str]:
    return [c for c in view.coordinates if c in DRAWN]


def _reference_text(view: ResidualView) -> str:
    return "ADS-B" if view.reference == "adsb" else "the other radars' plots"


# ------------------------------------------------------------- before / after
def before_after_figure(view: ResidualView, rng: np.random.Generator):
    """Residuals against range: measured (left column) and corrected (right column).

    One row per residual coordinate; each panel has its own y limits (1st-99th
    percentile, padded); points beyond are not drawn and their count is written
    above the panel, with the mean and sd.  The corrected panels show the expected
    ± 1 sigma (dashed).
    """
    plt = pyplot()
    coords = _drawn(view)
    fig, axes = plt.subplots(len(coords), 2, figsize=(10.5, 2.45 * len(coords) + 0.9),
                             squeeze=False, sharex=True)
    stages = (("measured (before correction)", view.before, BEFORE_COLOUR),
              ("corrected (after correction)", view.after, AFTER_COLOUR))
    for col, (title, side, colour) in enumerate(stages):
        # the stage above its column, clear of the panel's own note (its left title)
        axes[0, col].annotate(title, (0.5, 1.0), xycoords="axes fraction", xytext=(0, 13),
                              textcoords="offset points", ha="center", va="bottom",
                              fontsize=10, color=colour)
        for row, c in enumerate(coords):
            ax = axes[row, col]
            ax.axhline(0.0, color="k", lw=0.6)
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=8)
            if col == 0:
                ax.set_ylabel(_coordinate_label(c), fontsize=8)
            if row == len(coords) - 1:
                ax.set_xlabel("range [km]", fontsize=8)
            if side is None or c not in side.residuals:
                ax.text(0.5, 0.5, "no residuals", transform=ax.transAxes, ha="center")
                continue
            _scatter_panel(ax, side, c, colour, rng, expected=col == 1)
    fig.suptitle(f"{view.radar_id}: residuals against {_reference_text(view)} versus range",
                 fontsize=11)
    height = fig.get_figheight()
    fig.subplots_adjust(left=0.085, right=0.99, bottom=0.5 / height, top=1 - 0.8 / height,
                        hspace=0.25, wspace=0.16)
    return fig


def _scatter_panel(ax, side: Side, c: str, colour: str, rng: np.random.Generator,
                   expected: bool) -> None:
    x, y = side.variables["range"], side.residuals[c]
    finite = np.isfinite(x) & np.isfinite(y)
    x, y = x[finite], y[finite]
    lo, hi, outside = robust_limits(y)
    rows = subsample(len(y), MAX_SCATTER, rng)
    inside = (y[rows] >= lo) & (y[rows] <= hi)
    ax.scatter(x[rows][inside], y[rows][inside], s=3, c=colour, alpha=0.35, lw=0,
               rasterized=True)
    ax.set_ylim(lo, hi)
    if expected:
        sigma = side.sigmas[c][finite]
        s = float(np.sqrt(np.nanmean(sigma**2))) if np.any(np.isfinite(sigma)) else math.nan
        if math.isfinite(s):
            for sign in (-1, 1):
                ax.axhline(sign * s, color="k", lw=0.8, ls="--")
    mean, sd = float(np.mean(y)), float(np.std(y))
    unit = COORDINATES[c][1]
    note = f"mean {mean:.3g}, sd {sd:.3g} {unit}; n {len(y)}"
    if outside:
        note += f"; {outside} ({100 * outside / len(y):.1f} %) beyond the axis"
    ax.set_title(note, loc="left", fontsize=7, pad=2)  # above the panel: over no point


# ------------------------------------------------------------------- binned
def binned_figure(view: ResidualView, epoch_utc: datetime | None = None):
    """Corrected residuals binned against range, azimuth, elevation and time (module doc).

    ``epoch_utc``: the dataset's epoch (``Dataset.epoch_utc``), for the time axis in UTC.
    """
    plt = pyplot()

    coords = _drawn(view)
    variables = list(VARIABLES)
    fig, axes = plt.subplots(len(coords), len(variables),
                             figsize=(12, 1.95 * len(coords) + 0.8), squeeze=False,
                             sharey="row")
    side = view.after
    for row, c in enumerate(coords):
        for col, var in enumerate(variables):
            ax = axes[row, col]
            ax.axhline(0.0, color="k", lw=0.6)
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
            options: dict[str, Any] = {}
            if var == "azimuth":
                options = {"width": 30.0, "span": (0.0, 360.0)}
            b = binned(side.variables[var], side.residuals[c], side.sigmas[c], **options)
            if len(b.centre):
                ax.fill_between(b.centre, b.mean - b.sd, b.mean + b.sd, color=AFTER_COLOUR,
                                alpha=0.25, lw=0, label="mean ± 1 sd")
                ax.plot(b.centre, b.mean, "o-", color=AFTER_COLOUR, ms=3, lw=1.2,
                        label="bin mean")
                if np.any(np.isfinite(b.expected)):
                    ax.plot(b.centre, b.expected, "--", color="k", lw=0.8,
                            label="expected ± 1σ")
                    ax.plot(b.centre, -b.expected, "--", color="k", lw=0.8)
            else:
                ax.text(0.5, 0.5, "too few residuals", transform=ax.transAxes, ha="center",
                        fontsize=8)
            name, unit, _ = VARIABLES[var]
            if var == "time":
                clock_axis(ax, side.variables[var], epoch_utc)
            else:
                ax.set_xlabel(f"{name} [{unit}]", fontsize=8)
            if var == "azimuth":
                ax.set_xlim(0.0, 360.0)
                ax.set_xticks(range(0, 361, 90))
            if col == 0:
                ax.set_ylabel(_coordinate_label(c), fontsize=8)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, fontsize=7, loc="upper right", ncol=3, frameon=False)
    fig.suptitle(f"{view.radar_id}: corrected residuals against {_reference_text(view)}, "
                 "binned (equal counts; azimuth 30° bins)", fontsize=11, x=0.07, ha="left")
    height = fig.get_figheight()
    fig.subplots_adjust(left=0.07, right=0.975, bottom=0.55 / height, top=1 - 0.5 / height,
                        hspace=0.55, wspace=0.08)
    return fig


def clock_axis(ax, time_s: NDArray, epoch_utc: datetime | None = None,
               fontsize: float = 8) -> None:
    """An x axis of dataset times [s] labelled as UTC clock times ``HH:MM``, at most five
    ticks on round clock times; ``epoch_utc`` (the UTC time of 0 s) gives the clock and
    the date, else 0 s is read as 00:00 UTC (:func:`graphcal.reporting.display.clock_text`)."""
    from matplotlib.ticker import FuncFormatter, MultipleLocator

    step = _time_step_s(np.asarray(time_s, dtype=float))
    midnight = 0.0 if epoch_utc is None else (
        epoch_utc.hour * 3600.0 + epoch_utc.minute * 60.0 + epoch_utc.second
        + epoch_utc.microsecond / 1e6)
    ax.xaxis.set_major_locator(MultipleLocator(step, offset=(-midnight) % step))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda t, _: clock_text(t, epoch_utc)[:5]))
    day = "" if epoch_utc is None else f", {epoch_utc.strftime('%Y-%m-%d')}"
    ax.set_xlabel(f"time [HH:MM UTC{day}]", fontsize=fontsize)


def _time_step_s(time_s: NDArray) -> float:
    """A round clock step [s] giving at most five time ticks over ``time_s``."""
    finite = time_s[np.isfinite(time_s)]
    span = float(finite.max() - finite.min()) if finite.size else 0.0
    for step in (60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200):
        if span / step <= 5:
            return float(step)
    return 86400.0


# --------------------------------------------------------------- histograms
def _gauss(x: NDArray, sigma: float) -> NDArray:
    return np.exp(-0.5 * (x / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))


def histograms_figure(view: ResidualView):
    """Histograms of the corrected residuals with the expected N(0, sigma), one per coordinate."""
    plt = pyplot()
    coords = _drawn(view)
    fig, axes = plt.subplots(1, len(coords), figsize=(3.6 * len(coords) + 0.4, 2.8),
                             squeeze=False)
    for ax, c in zip(axes[0], coords, strict=True):
        values = view.after.residuals[c]
        finite = np.isfinite(values)
        values = values[finite]
        sig = view.after.sigmas[c][finite]
        sigma = float(np.sqrt(np.nanmean(sig**2))) if np.any(np.isfinite(sig)) else math.nan
        width = 5.0 * (sigma if math.isfinite(sigma) else float(np.std(values)) or 1.0)
        unit = COORDINATES[c][1]
        ax.hist(values, bins=60, range=(-width, width), density=True, color=AFTER_COLOUR,
                alpha=0.6, label=f"corrected (n={len(values)})")
        if math.isfinite(sigma):
            x = np.linspace(-width, width, 300)
            ax.plot(x, _gauss(x, sigma), "k", lw=1.5, label=f"N(0, {sigma:.3g} {unit})")
        ax.set_xlabel(_coordinate_label(c), fontsize=8)
        ax.set_ylabel(f"density [1/{unit}]", fontsize=8)
        ax.tick_params(labelsize=7)
        mean, sd = (float(np.mean(values)), float(np.std(values))) if len(values) else (0, 0)
        ax.set_title(f"{view.radar_id} {c}: mean {mean:.3g}, sd {sd:.3g} {unit}", fontsize=9)
        ax.set_ylim(0.0, ax.get_ylim()[1] * 1.3)  # headroom: the legend above the bars
        ax.legend(fontsize=7, loc="upper right")
    width = fig.get_figwidth()  # room in inches for the tick labels and the density label
    fig.subplots_adjust(left=0.75 / width, right=1 - 0.1 / width, bottom=0.17, top=0.88,
                        wspace=0.3)
    return fig


# ------------------------------------------------------------------------ map
def network_centre(dataset: Dataset) -> tuple[float, float]:
    """Latitude and longitude [rad] of the mean of the sites' ECEF positions."""
    centre = np.mean([site.ecef_m for site in dataset.sites.values()], axis=0)
    lat, lon, _ = frames.ecef_to_geodetic(centre[None, :])
    return float(lat[0]), float(lon[0])


def plots_ecef(dataset: Dataset, rid: str, rows: NDArray | None = None) -> NDArray:
    """ECEF [m] of one radar's plots (2-D: at the elevation of their Mode C altitude, else 0)."""
    plots = dataset.plots_of(rid)
    if rows is not None:
        plots = plots.iloc[rows]
    site = dataset.sites[rid]
    r = plots["range_m"].to_numpy(float)
    az = np.deg2rad(plots["azimuth_deg"].to_numpy(float))
    el = np.deg2rad(plots["elevation_deg"].to_numpy(float))
    if not site.is_3d or not np.all(np.isfinite(el)):
        el = np.where(np.isfinite(el) & site.is_3d, el, 0.0)
        alt = (plots["altitude_m"].to_numpy(float) if "altitude_m" in plots
               else np.full(len(r), np.nan))
        known = np.isfinite(alt)
        if known.any():
            el_alt = frames.elevation_from_height(r[known], alt[known], site.lat_rad, site.alt_m)
            el[known] = np.where(np.isfinite(el_alt), el_alt, 0.0)
    return site.ecef_from_polar(r, az, el)


def _ring_step_km(max_range_km: float) -> float:
    """A round ring spacing giving about three rings out to ``max_range_km``."""
    for step in (10.0, 20.0, 25.0, 50.0, 100.0, 150.0, 200.0):
        if max_range_km / step <= 4.0:
            return step
    return 250.0


def map_figure(dataset: Dataset, corrected: Dataset, radar_ids: list[str],
               rng: np.random.Generator):
    """Sites, range rings and coverage, tracks, and one track before / after (module doc)."""
    plt = pyplot()
    from matplotlib.patches import Circle

    lat0, lon0 = network_centre(dataset)

    def enu_km(ecef: NDArray) -> NDArray:
        return frames.ecef_to_enu(ecef, lat0, lon0, 0.0)[:, :2] / 1e3

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12.5, 7.0), width_ratios=(1.25, 1.0))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    color = {rid: colors[i % len(colors)] for i, rid in enumerate(dataset.radar_ids)}
    cloud = []
    for rid in radar_ids:
        n = int((dataset.plots["radar_id"] == rid).sum())
        if n == 0:
            continue
        xy = enu_km(plots_ecef(corrected, rid, subsample(n, MAX_MAP_POINTS, rng)))
        cloud.append(xy)
        ax0.scatter(xy[:, 0], xy[:, 1], s=3, color=color[rid], alpha=0.35, lw=0,
                    rasterized=True)
    handles = []
    sites: list[tuple[str, float, float]] = []
    for rid, site in dataset.sites.items():
        x, y = enu_km(site.ecef_m[None, :])[0]
        plots = dataset.plots_of(rid)
        max_km = float(plots["range_m"].max()) / 1e3 if len(plots) else 0.0
        cloud.append(np.array([[x - max_km, y - max_km], [x + max_km, y + max_km]]))
        if max_km > 0:
            step = _ring_step_km(max_km)
            for k in range(1, int(max_km // step) + 1):
                ax0.add_patch(Circle((x, y), k * step, fill=False, color=color[rid], lw=0.8,
                                     ls=":"))
            ax0.add_patch(Circle((x, y), max_km, fill=False, color=color[rid], lw=1.0,
                                 ls="-", alpha=0.6))
            handles.append(plt.Line2D([], [], color=color[rid], ls=":", lw=1.2,
                                      label=f"{rid}: every {step:.0f} km, farthest plot "
                                            f"{max_km:.0f} km"))
        ax0.plot(x, y, "^", color=color[rid], mec="k", ms=10, zorder=5)
        sites.append((rid, x, y))
    if handles:  # under the map, where it covers no ring or plot
        ax0.legend(handles=handles, fontsize=7, loc="upper center", title="range rings",
                   title_fontsize=7, bbox_to_anchor=(0.5, -0.1), ncol=2, frameon=False)
    extent = np.concatenate(cloud) if cloud else np.zeros((1, 2))
    lo, hi = extent.min(axis=0), extent.max(axis=0)
    pad = 0.03 * float(max(hi - lo)) + 2.0
    ax0.set_xlim(lo[0] - pad, hi[0] + pad)
    ax0.set_ylim(lo[1] - pad, hi[1] + pad)
    ax0.set_title("sites, range rings, corrected plots (subsampled), ADS-B tracks", fontsize=10)
    targets = _map_targets(dataset)
    for k, target in enumerate(targets):
        if dataset.adsb is not None:
            adsb = dataset.adsb[dataset.adsb["target_id"] == target].sort_values("time_s")
            if len(adsb):
                xy = enu_km(_adsb_ecef(adsb))
                ax0.plot(xy[:, 0], xy[:, 1], "k-", lw=0.8)
        if k == 0:
            _zoom_panel(ax1, dataset, corrected, radar_ids, target, color, enu_km)
    for ax in (ax0, ax1):
        ax.set_xlabel("east [km]")
        ax.set_ylabel("north [km]")
        ax.grid(alpha=0.3)
    ax0.set_aspect("equal", adjustable="box")
    ax1.set_aspect("equal", adjustable="datalim")
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.2, top=0.94, wspace=0.2)
    place_site_labels(ax0, sites)
    return fig


#: Offsets [points] tried for a site's label, nearest first: (dx, dy, ha, va).
_LABEL_OFFSETS = tuple(
    (sx * r, sy * r, "left" if sx > 0 else "right" if sx < 0 else "center",
     "bottom" if sy > 0 else "top" if sy < 0 else "center")
    for r in (7.0, 14.0, 24.0, 36.0)
    for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1), (0, 1.2), (0, -1.2), (1.2, 0),
                   (-1.2, 0))
)
#: Half-size [points] of a site's marker kept free of labels.
_MARKER_HALF_PT = 6.0


def place_site_labels(ax, sites: list[tuple[str, float, float]], fontsize: float = 9):
    """Label each site ``(id, x, y)`` where the label covers no other label, no site's
    marker and not the legend: the first free offset of :data:`_LABEL_OFFSETS` in the Agg
    renderer's text boxes (greedy, in the order given), with a thin leader line when it is
    not one of the nearest; the nearest when none is free.  Returns the labels.
    """
    from matplotlib.transforms import Bbox

    fig = ax.figure
    ax.apply_aspect()
    renderer = fig.canvas.get_renderer()
    points = fig.dpi / 72.0  # pixels per point
    taken: list[Any] = []
    for _, x, y in sites:
        px, py = ax.transData.transform((x, y))
        half = _MARKER_HALF_PT * points
        taken.append(Bbox([[px - half, py - half], [px + half, py + half]]))
    legend = ax.get_legend()
    if legend is not None:
        taken.append(legend.get_window_extent(renderer))
    axes_box = ax.get_window_extent(renderer)
    labels = []
    for rid, x, y in sites:
        chosen = None
        for k, (dx, dy, ha, va) in enumerate(_LABEL_OFFSETS):
            label = ax.annotate(rid, (x, y), xytext=(dx, dy), textcoords="offset points",
                                fontsize=fontsize, weight="bold", zorder=6, ha=ha, va=va,
                                annotation_clip=False)
            box = label.get_window_extent(renderer).expanded(1.05, 1.1)
            inside = (axes_box.x0 <= box.x0 and box.x1 <= axes_box.x1
                      and axes_box.y0 <= box.y0 and box.y1 <= axes_box.y1)
            if inside and not any(box.overlaps(other) for other in taken):
                chosen = (label, box, k)
                break
            label.remove()
        if chosen is None:  # nowhere free: the nearest place
            dx, dy, ha, va = _LABEL_OFFSETS[0]
            label = ax.annotate(rid, (x, y), xytext=(dx, dy), textcoords="offset points",
                                fontsize=fontsize, weight="bold", zorder=6, ha=ha, va=va)
            chosen = (label, label.get_window_extent(renderer), 0)
        label, box, k = chosen
        if k >= 8:  # away from its marker: a leader line
            label.remove()
            dx, dy, ha, va = _LABEL_OFFSETS[k]
            label = ax.annotate(rid, (x, y), xytext=(dx, dy), textcoords="offset points",
                                fontsize=fontsize, weight="bold", zorder=6, ha=ha, va=va,
                                arrowprops={"arrowstyle": "-", "lw": 0.6, "color": "0.3",
                                            "shrinkA": 0, "shrinkB": 5})
        taken.append(box)
        labels.append(label)
    return labels


def _map_targets(dataset: Dataset) -> list[str]:
    """The targets seen by the most radars (then with the most plots)."""
    plots = dataset.plots[dataset.plots["target_id"] != ""]
    if len(plots) == 0:
        return []
    counts = plots.groupby("target_id")["radar_id"].agg(["nunique", "size"])
    return list(counts.sort_values(["nunique", "size"], ascending=False).index[:N_MAP_TRACKS])


def _adsb_ecef(adsb) -> NDArray:
    return frames.geodetic_to_ecef(np.deg2rad(adsb["lat_deg"].to_numpy(float)),
                                   np.deg2rad(adsb["lon_deg"].to_numpy(float)),
                                   adsb["alt_m"].to_numpy(float))


def _zoom_panel(ax, dataset: Dataset, corrected: Dataset, radar_ids: list[str], target: str,
                color: Mapping[str, str], enu_km) -> None:
    """± :data:`ZOOM_S` of one target: each radar's plots before (x) and after (.) correction."""
    plots = dataset.plots
    t_mid = float(np.median(plots.loc[plots["target_id"] == target, "time_s"]))
    if dataset.adsb is not None:
        adsb = dataset.adsb[(dataset.adsb["target_id"] == target)
                            & ((dataset.adsb["time_s"] - t_mid).abs() <= ZOOM_S)]
        if len(adsb):
            xy = enu_km(_adsb_ecef(adsb.sort_values("time_s")))
            ax.plot(xy[:, 0], xy[:, 1], "k-", lw=1.5, label="ADS-B")
    for rid in radar_ids:
        own = dataset.plots_of(rid)
        rows = np.flatnonzero((own["target_id"].to_numpy() == target)
                              & (np.abs(own["time_s"].to_numpy(float) - t_mid) <= ZOOM_S))
        if rows.size == 0:
            continue
        before = enu_km(plots_ecef(dataset, rid, rows))
        after = enu_km(plots_ecef(corrected, rid, rows))
        ax.plot(before[:, 0], before[:, 1], "x", ms=4, color=color[rid], alpha=0.7,
                label=f"{rid} before")
        ax.plot(after[:, 0], after[:, 1], ".-", ms=4, lw=0.6, color=color[rid],
                label=f"{rid} after")
    ax.set_title(f"aircraft {target}, {2 * ZOOM_S:.0f} s around "
                 f"{clock_text(t_mid, dataset.epoch_utc)} UTC: "
                 "plots before (x) and after (•)", fontsize=9)
    ax.legend(fontsize=7, ncol=2)


# ----------------------------------------------------------------- correlation
def correlation_figure(cal: Calibration):
    """The correlation matrix of the estimated parameters as an image, labelled."""
    plt = pyplot()
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


def p_value_text(test: Mapping[str, Any]) -> str:
    """A model-check test's p-value, as a power of ten where it underflows to 0."""
    p = test.get("p_value")
    if p:
        return f"{p:.2g}"
    log10_p = test.get("log10_p")
    return f"1e{log10_p:.0f}" if log10_p is not None else "–"


def model_checks_figure(radar_id: str, entry: Mapping[str, Any],
                        epoch_utc: datetime | None = None):
    """One radar's binned residual means, a panel per test (rows: residuals; columns: variables).

    ``entry`` is one radar of ``info["model_checks"]["radars"]``; ``epoch_utc`` (the
    dataset's epoch) labels a time axis in UTC.  Each panel:
    bin means ± 1 sigma against the bin centres (the bins' ranges as horizontal
    bars), the part the model's own terms absorb (dashed), zero; a test that
    fired has a red frame and title.
    """
    plt = pyplot()
    tests = list(entry.get("tests") or [])
    rows = list(dict.fromkeys(t["residual"] for t in tests))
    cols = list(dict.fromkeys(t["against"] for t in tests))
    if not tests:  # too few residuals for any test: a figure that says so
        fig, ax = plt.subplots(figsize=(4.0, 1.2))
        ax.set_axis_off()
        ax.text(0.5, 0.5, f"{radar_id}: no model-check test (too few residuals)",
                ha="center", va="center", fontsize=9)
        return fig
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
        colour = "tab:red" if fired else "tab:blue"
        ax.axhline(0.0, color="k", lw=0.6)
        ax.errorbar(x, mean, yerr=sigma, xerr=[lo, hi], fmt="o", ms=3, lw=1, color=colour,
                    elinewidth=1, capsize=2)
        ax.plot(x, np.asarray(b[f"absorbed_{unit}"], dtype=float), "--", color="0.4", lw=1)
        ax.set_title(("FIRED  " if fired else "")
                     + f"χ² {t['chi2']:.3g} over {t['dof']:.3g} dof, p {p_value_text(t)}",
                     fontsize=8, color="tab:red" if fired else "k")
        if fired:
            for spine in ax.spines.values():
                spine.set_edgecolor("tab:red")
                spine.set_linewidth(2)
        if var == "time" and vunit == "s" and x.size:
            clock_axis(ax, np.concatenate([x - lo, x + hi]), epoch_utc)
        else:
            ax.set_xlabel(f"{var} [{vunit}]", fontsize=8, labelpad=1)
        first = min(cols.index(u["against"]) for u in tests if u["residual"] == t["residual"])
        if j == first:
            ax.set_ylabel(f"{coord} [{unit}]", fontsize=8)
        ax.yaxis.set_tick_params(labelleft=True)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{radar_id}: binned residual means ± 1σ of the mean after correction "
                 f"(dashed: absorbed by the model's own terms)", fontsize=10)
    top = 1.0 - 0.7 / fig.get_figheight()
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.45 / fig.get_figheight(), top=top,
                        hspace=0.6, wspace=0.16)
    return fig


__all__ = ["MAX_MAP_POINTS", "MAX_SCATTER", "N_MAP_TRACKS", "ZOOM_S", "before_after_figure",
           "binned_figure", "clock_axis", "correlation_figure", "histograms_figure", "map_figure",
           "model_checks_figure", "network_centre", "p_value_text", "place_site_labels",
           "plots_ecef", "pyplot", "subsample"]

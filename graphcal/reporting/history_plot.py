"""The drift plot of a calibration history: each bias over time with its 2-sigma band.

One panel per radar (rows) and bias key (columns).  Each window of a run is drawn as
its estimate, a horizontal segment over the window, inside its shaded ``± 2 sigma``
band; consecutive windows of a run are joined at their middles.  Dashed lines mark
the tolerance ``± tol`` when it falls inside the panel's range (otherwise a note above
the panel, right of its title, gives it), crosses and circles the windows flagged
``outside`` and ``possibly`` (:func:`graphcal.pipeline.history.flag_tolerances`), and
dotted vertical lines the detected events with their size, labelled in a strip kept free
above the data.  Range gains are drawn in ppm.  Times are UTC when every run has an epoch, else
hours on the datasets' time base.  matplotlib's Agg backend; written atomically.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from graphcal.core.atomic import atomic_write_stream
from graphcal.pipeline.history import key_rank, key_unit

#: File formats by suffix.
PLOT_FORMATS: dict[str, str] = {".png": "png", ".pdf": "pdf", ".svg": "svg"}
#: Panel size [inches] and resolution [dots per inch].
PANEL_WIDTH_IN, PANEL_HEIGHT_IN, DPI = 3.8, 2.6, 100
#: Colour of the tolerance lines and of the ``outside`` / ``possibly`` marks.
TOLERANCE_COLOUR, OUTSIDE_COLOUR, POSSIBLY_COLOUR = "crimson", "crimson", "darkorange"


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _time_axis(series: pd.DataFrame) -> tuple[bool, str]:
    """Whether to plot UTC times, and the time axis label."""
    utc = "t_start_utc" in series and len(series) > 0 and bool(series["t_start_utc"].notna().all())
    return utc, "time (UTC)" if utc else "time [h] (dataset time base)"


def _x(values: pd.Series, utc_values: pd.Series | None, utc: bool) -> np.ndarray:
    """Plot abscissae: naive UTC datetimes, or hours."""
    if utc and utc_values is not None:
        return utc_values.dt.tz_convert("UTC").dt.tz_localize(None).to_numpy()
    return values.to_numpy(dtype=float) / 3600.0


def _draw_run(ax: Any, rows: pd.DataFrame, colour: Any, utc: bool) -> None:
    """One run's windows in one panel: segments, 2-sigma bands, joins and flags."""
    rows = rows.sort_values("t_start_s")
    x0 = _x(rows["t_start_s"], rows.get("t_start_utc"), utc)
    x1 = _x(rows["t_end_s"], rows.get("t_end_utc"), utc)
    value = rows["value"].to_numpy(dtype=float)
    band = 2.0 * rows["sigma"].to_numpy(dtype=float)
    for a, b, v, s in zip(x0, x1, value, band, strict=True):
        if math.isfinite(s):
            ax.fill_between([a, b], [v - s] * 2, [v + s] * 2, color=colour, alpha=0.25,
                            linewidth=0)
    ax.hlines(value, x0, x1, color=colour, linewidth=1.8)
    middle = x0 + (x1 - x0) / 2
    if len(rows) > 1:
        ax.plot(middle, value, color=colour, linewidth=0.8, alpha=0.6)
    status = rows["status"].to_numpy() if "status" in rows else np.array([""] * len(rows))
    for flag, marker, colour_flag in (("outside", "x", OUTSIDE_COLOUR),
                                      ("possibly", "o", POSSIBLY_COLOUR)):
        hit = status == flag
        if hit.any():
            ax.scatter(middle[hit], value[hit], marker=marker, s=36, zorder=5,
                       color=colour_flag, facecolors="none" if marker == "o" else colour_flag)


def _draw_reference_lines(ax: Any, rows: pd.DataFrame, unit: str) -> None:
    """Zero and ``± tol`` lines inside the panel's data range; a note for a tolerance beyond.

    Drawn after the data, keeping the data's range: a far tolerance would squash the
    windows into a line.  The note goes above the panel, right of its title, where it
    cannot cover a window.
    """
    low, high = ax.get_ylim()
    if low <= 0.0 <= high:
        ax.axhline(0.0, color="0.6", linewidth=0.6)
    tolerances = rows["tolerance"].dropna() if "tolerance" in rows else pd.Series([])
    notes = []
    for tol in sorted(set(tolerances.tolist())):
        if any(low <= y <= high for y in (tol, -tol)):
            ax.axhline(tol, color=TOLERANCE_COLOUR, linestyle="--", linewidth=1)
            ax.axhline(-tol, color=TOLERANCE_COLOUR, linestyle="--", linewidth=1)
        else:
            notes.append(f"±{tol:.3g}{f' {unit}' if unit else ''}")
    if notes:
        ax.set_title(f"tolerance {', '.join(notes)} off scale", loc="right", fontsize=7,
                     color=TOLERANCE_COLOUR)
    ax.set_ylim(low, high)


#: Share of a panel's height kept free above the data for the events' labels.
EVENT_HEADROOM = 0.18


def _draw_events(ax: Any, events: pd.DataFrame, key: str, unit: str, utc: bool,
                 scale: float = 1.0) -> None:
    """Dotted vertical lines at the radar's events that concern ``key``, with their size.

    The labels sit in a strip added above the data (:data:`EVENT_HEADROOM`), left of their
    line in the right half of the panel and right of it in the left half, so that they
    cover no window.
    """
    mine = events[(events["key"] == key) | events["key"].isna()]
    if mine.empty:
        return
    low, high = ax.get_ylim()
    ax.set_ylim(low, high + (high - low) * EVENT_HEADROOM / (1.0 - EVENT_HEADROOM))
    left, right = ax.get_xlim()
    for _, event in mine.iterrows():
        utc_value = pd.Series([event["time_utc"]]) if utc else None
        x = _x(pd.Series([event["time_s"]]), utc_value, utc)[0]
        ax.axvline(x, color="black", linestyle=":", linewidth=1.2)
        size = event["size"]
        label = (event["kind"] if pd.isna(size)
                 else f"{event['kind']} {size * scale:+.3g}{f' {unit}' if unit else ''}")
        position = _axis_number(x)
        before = position > _axis_number(left) + 0.5 * (_axis_number(right) - _axis_number(left))
        ax.annotate(label, (x, 1.0), xycoords=("data", "axes fraction"), fontsize=7,
                    ha="right" if before else "left", va="top",
                    xytext=(-3 if before else 3, -2), textcoords="offset points")


def _axis_number(x: Any) -> float:
    """An abscissa as a number (matplotlib's date numbers for datetimes)."""
    if isinstance(x, (np.datetime64, pd.Timestamp)):
        from matplotlib.dates import date2num

        return float(date2num(pd.Timestamp(x).to_pydatetime()))
    return float(x)


def _concise_dates(ax: Any) -> None:
    """Date ticks that name the day once and the hours beside it."""
    from matplotlib.dates import AutoDateLocator, ConciseDateFormatter

    locator = AutoDateLocator()
    ax.xaxis.set_major_locator(locator)
    ax.xaxis.set_major_formatter(ConciseDateFormatter(locator))


def _legend_handles(run_ids: Sequence[int], colours: dict[int, Any]) -> list[Any]:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Any] = [Line2D([], [], color=colours[r], linewidth=1.8, label=f"run {r}")
                          for r in run_ids]
    handles += [
        Patch(color="grey", alpha=0.3, label="± 2σ band"),
        Line2D([], [], color=TOLERANCE_COLOUR, linestyle="--", label="± tolerance"),
        Line2D([], [], color="black", linestyle=":", label="event"),
        Line2D([], [], color=OUTSIDE_COLOUR, marker="x", linestyle="", label="outside"),
        Line2D([], [], color=POSSIBLY_COLOUR, marker="o", markerfacecolor="none",
               linestyle="", label="possibly outside"),
    ]
    return handles


def plot_history(
    series: pd.DataFrame,
    path: str | os.PathLike[str],
    *,
    events: pd.DataFrame | None = None,
    title: str | None = None,
) -> Path:
    """Draw each radar's biases over time and write the figure atomically.

    Parameters
    ----------
    series : DataFrame
        Rows of :func:`graphcal.pipeline.history.read_series`, optionally with
        the ``tolerance`` and ``status`` columns of
        :func:`graphcal.pipeline.history.flag_tolerances` (then the tolerance
        lines and flags are drawn).  Values in contract units.
    path : str or path
        Output file; ``.png``, ``.pdf`` or ``.svg``.  Its folder must exist.
    events : DataFrame, optional
        Rows of :func:`graphcal.pipeline.history.read_events`.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        An unknown suffix, or no rows to draw.
    """
    path = Path(path)
    fmt = PLOT_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(f"{path}: the plot format comes from the suffix: "
                         f"{', '.join(PLOT_FORMATS)}")
    if series.empty:
        raise ValueError("no windows to plot")
    plt = _pyplot()
    radars = sorted(series["radar_id"].unique())
    keys = sorted(series["key"].unique(), key=key_rank)
    run_ids = sorted(int(r) for r in series["run_id"].unique())
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colours = {r: cycle[i % len(cycle)] for i, r in enumerate(run_ids)}
    utc, time_label = _time_axis(series)
    height = PANEL_HEIGHT_IN * len(radars) + 0.9
    fig, axes = plt.subplots(len(radars), len(keys), squeeze=False, sharex=True,
                             figsize=(PANEL_WIDTH_IN * len(keys), height))
    try:
        for i, radar in enumerate(radars):
            radar_rows = series[series["radar_id"] == radar]
            radar_events = (events[events["radar_id"] == radar] if events is not None
                            else None)
            for j, key in enumerate(keys):
                _panel(axes[i][j], radar_rows[radar_rows["key"] == key], radar_events,
                       radar, key, colours, utc)
        for ax in axes[-1]:
            ax.set_xlabel(time_label)
            if utc:
                _concise_dates(ax)
        top = 0.1 / height  # [figure fraction] from the top: title, legend, panels
        if title:
            fig.suptitle(title, y=1.0 - top, va="top", fontsize=10)
            top += 0.3 / height
        fig.legend(handles=_legend_handles(run_ids, colours), loc="upper center",
                   bbox_to_anchor=(0.5, 1.0 - top), ncol=min(len(run_ids) + 5, 8),
                   frameon=False, fontsize=8)
        fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - top - 0.25 / height))
        atomic_write_stream(path, lambda stream: fig.savefig(stream, format=fmt, dpi=DPI))
    finally:
        plt.close(fig)
    return path


def _panel(ax: Any, rows: pd.DataFrame, events: pd.DataFrame | None, radar: str, key: str,
           colours: dict[int, Any], utc: bool) -> None:
    """One radar's bias ``key``: every run's windows, the tolerance and the events."""
    unit = key_unit(key)
    scale = 1.0
    if unit == "fraction":  # a range gain reads in ppm: -148 ppm, not -0.000148
        scale, unit = 1e6, "ppm"
        rows = rows.copy()
        for column in ("value", "sigma", "tolerance"):
            if column in rows:
                rows[column] = rows[column] * scale
    model = None if rows.empty else rows["sensor_model"].iloc[0]
    ax.set_title(radar if model is None or pd.isna(model) else f"{radar} ({model})",
                 loc="left", fontsize=9)
    name = key.removesuffix(f"_{key_unit(key)}")
    ax.set_ylabel(f"{name} [{unit}]" if unit else key, fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, alpha=0.3)
    if rows.empty:
        ax.text(0.5, 0.5, "not estimated", transform=ax.transAxes, ha="center",
                va="center", color="grey")
        return
    for run_id, run_rows in rows.groupby("run_id"):
        _draw_run(ax, run_rows, colours[int(run_id)], utc)
    _draw_reference_lines(ax, rows, unit)
    if events is not None and not events.empty:
        _draw_events(ax, events, key, unit, utc, scale)


__all__ = ["DPI", "PLOT_FORMATS", "plot_history"]

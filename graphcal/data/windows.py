"""Time windows of a dataset, for biases that change over time (contract v2 ``--window``).

A recording is cut into consecutive windows ``[t_k, t_k + window_s)`` aligned on
multiples of ``window_s`` (so that a window means the same span on every day and
in every run, ``09:00-09:30`` rather than "30 minutes after the first plot").  Each
window's plots are those with ``t_k <= time_s < t_k + window_s``; its ADS-B reports
reach ``margin_s`` beyond both ends, so that a plot near a window's edge still has
ADS-B on both sides to be interpolated between.  Windows without plots are left out.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from graphcal.data.dataset import Dataset

#: ADS-B beyond a window's ends [s] kept with it (the default ADS-B gap limit is 10 s).
DEFAULT_ADSB_MARGIN_S = 30.0


@dataclass(frozen=True)
class Window:
    """One time window of a dataset.

    Attributes
    ----------
    index : int
        ``floor(t_start_s / window_s)``: the same window has the same index in every
        run over the same time base.
    t_start_s, t_end_s : float
        Its span ``[t_start_s, t_end_s)`` [s].
    dataset : Dataset
        The plots inside it and the ADS-B reports up to the margin beyond it.
    """

    index: int
    t_start_s: float
    t_end_s: float
    dataset: Dataset

    @property
    def n_plots(self) -> int:
        """Plots in the window."""
        return len(self.dataset.plots)

    @property
    def middle_s(self) -> float:
        """Middle of the span [s]."""
        return 0.5 * (self.t_start_s + self.t_end_s)


def window_index(time_s: np.ndarray, window_s: float) -> np.ndarray:
    """Window number of each time: ``floor(t / window_s)``."""
    if not (math.isfinite(window_s) and window_s > 0):
        raise ValueError(f"the window must be a positive duration, not {window_s} s")
    return np.floor(np.asarray(time_s, dtype=float) / window_s).astype(np.int64)


def split_windows(dataset: Dataset, window_s: float,
                  adsb_margin_s: float = DEFAULT_ADSB_MARGIN_S) -> Iterator[Window]:
    """The dataset's windows in time order (module docstring); empty ones are skipped.

    The tables are not copied more than the windows need: each window holds its
    rows only, so a consumer that drops a window frees its memory.
    """
    plots = dataset.plots
    index = window_index(plots["time_s"].to_numpy(dtype=float), window_s)
    order = np.argsort(index, kind="stable")
    sorted_index = index[order]
    cuts = np.flatnonzero(np.diff(sorted_index)) + 1
    adsb = dataset.adsb
    adsb_time = None if adsb is None else adsb["time_s"].to_numpy(dtype=float)
    for rows in np.split(order, cuts):
        if len(rows) == 0:
            continue
        k = int(index[rows[0]])
        start, end = k * window_s, (k + 1) * window_s
        window_adsb = None
        if adsb is not None and adsb_time is not None:
            near = (adsb_time >= start - adsb_margin_s) & (adsb_time < end + adsb_margin_s)
            window_adsb = adsb.loc[near]
        part = replace(dataset, plots=plots.iloc[np.sort(rows)], adsb=window_adsb,
                       cleaning=None)
        yield Window(k, float(start), float(end), part)


def split_window(window: Window, times_s: list[float] | tuple[float, ...],
                 adsb_margin_s: float = DEFAULT_ADSB_MARGIN_S) -> list[Window]:
    """A window cut at the given times into consecutive parts (same ``index``).

    Used where a bias steps inside a window: each part then has one bias.  Times
    outside the window are ignored; a part without plots is left out.
    """
    edges = [window.t_start_s, *sorted(t for t in set(times_s)
                                       if window.t_start_s < t < window.t_end_s),
             window.t_end_s]
    plots = window.dataset.plots
    time_s = plots["time_s"].to_numpy(dtype=float)
    adsb = window.dataset.adsb
    adsb_time = None if adsb is None else adsb["time_s"].to_numpy(dtype=float)
    parts = []
    for start, end in zip(edges, edges[1:], strict=False):
        inside = (time_s >= start) & (time_s < end)
        if not inside.any():
            continue
        part_adsb = None
        if adsb is not None and adsb_time is not None:
            part_adsb = adsb.loc[(adsb_time >= start - adsb_margin_s)
                                 & (adsb_time < end + adsb_margin_s)]
        parts.append(Window(window.index, float(start), float(end),
                            replace(window.dataset, plots=plots.loc[inside], adsb=part_adsb)))
    return parts


__all__ = ["DEFAULT_ADSB_MARGIN_S", "Window", "split_window", "split_windows", "window_index"]

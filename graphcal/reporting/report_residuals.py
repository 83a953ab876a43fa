"""The residuals the HTML report draws, in display units, and their summaries.

Each radar's plots are compared with a reference twice: as measured (every bias
zero) and corrected by the calibration (every bias, the time offset and the
height model included).  The reference is ADS-B when the dataset has it
(:func:`graphcal.analysis.check_residuals.adsb_radar_residuals`), else the other
radars' corrected plots of the same aircraft
(:func:`graphcal.analysis.check_residuals.cross_radar_residuals`: the difference
of the two radars' positions in this radar's polar frame).  Gross outliers
(beyond :data:`graphcal.analysis.check_residuals.OUTLIER_SIGMAS` robust sigmas)
are left out and counted.

Display units: residuals in m (range, altitude) and mrad (azimuth, elevation);
the variables they are drawn against in km (range), deg (azimuth, elevation) and
s (time).  A 2-D radar's elevation is that of its plot's height (Mode C or
ADS-B) at its range (:func:`graphcal.core.frames.elevation_from_height`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graphcal.analysis.check_residuals import (
    RadarResiduals,
    adsb_radar_residuals,
    cross_radar_residuals,
)
from graphcal.core import frames
from graphcal.data.bias import RadarBias
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset, Site

FloatArray = NDArray[np.float64]

#: Residual coordinates: name -> (label, display unit, factor from SI).
COORDINATES: dict[str, tuple[str, str, float]] = {
    "range": ("range", "m", 1.0),
    "azimuth": ("azimuth", "mrad", 1e3),
    "elevation": ("elevation", "mrad", 1e3),
    "altitude": ("altitude (Mode C)", "m", 1.0),
}
#: Variables residuals are drawn against: name -> (label, display unit, factor from SI).
VARIABLES: dict[str, tuple[str, str, float]] = {
    "range": ("range", "km", 1e-3),
    "azimuth": ("azimuth", "deg", 180.0 / math.pi),
    "elevation": ("elevation", "deg", 180.0 / math.pi),
    "time": ("time", "UTC", 1.0),
}
#: Percentiles that bound a scatter panel's axis (points beyond are counted, not drawn).
ROBUST_PERCENTILES = (1.0, 99.0)
#: Fewest residuals in a bin of a binned curve.
MIN_PER_BIN = 10


@dataclass
class Side:
    """One radar's residuals at one stage (measured or corrected), display units.

    Attributes
    ----------
    variables : dict of str to ndarray (n,)
        ``range`` [km], ``azimuth`` [deg, 0-360], ``elevation`` [deg] (NaN where
        unknown), ``time`` [s] of each residual.
    residuals : dict of str to ndarray (n,)
        Per coordinate of :data:`COORDINATES` the radar has: plot minus
        reference, m or mrad.
    sigmas : dict of str to ndarray (n,)
        Their expected 1-sigma (radar noise plus the reference's), same units.
    partner : ndarray (n,) of str or None
        Cross-radar reference: the other radar of each residual.
    n_outliers : int
        Residuals left out as gross outliers.
    """

    variables: dict[str, FloatArray]
    residuals: dict[str, FloatArray]
    sigmas: dict[str, FloatArray]
    partner: NDArray[np.str_] | None
    n_outliers: int

    def __len__(self) -> int:
        return len(self.variables["time"])


@dataclass
class ResidualView:
    """One radar's residuals before (``None`` if none) and after correction."""

    radar_id: str
    reference: str
    before: Side | None
    after: Side

    @property
    def coordinates(self) -> list[str]:
        """The residual coordinates of this radar, in :data:`COORDINATES` order."""
        return [c for c in COORDINATES if c in self.after.residuals]


def _side(res: RadarResiduals, site: Site) -> Side:
    """:class:`Side` of check residuals (SI) in display units."""
    v = res.variables
    rng = v["range"]
    if "elevation" in v:
        elevation = v["elevation"]
    else:
        elevation = frames.elevation_from_height(rng, v.get("height", np.full(len(rng), np.nan)),
                                                 site.lat_rad, site.alt_m)
    variables = {
        "range": rng * VARIABLES["range"][2],
        "azimuth": np.mod(np.rad2deg(v["azimuth"]), 360.0),
        "elevation": np.rad2deg(elevation),
        "time": np.asarray(v["time"], dtype=float),
    }
    residuals, sigmas = {}, {}
    for name, (_, _, factor) in COORDINATES.items():
        if name in res.residuals:
            residuals[name] = res.residuals[name] * factor
            sigmas[name] = np.sqrt(np.abs(res.variances[name])) * factor
    partner = None
    if res.partner is not None and res.partners:
        partner = np.asarray(res.partners, dtype=str)[res.partner]
    return Side(variables, residuals, sigmas, partner, res.n_outliers)


def _biases(cal: Calibration, dataset: Dataset) -> dict[str, RadarBias]:
    return {rid: cal.bias(rid) for rid in cal.radar_ids if rid in dataset.sites}


def residual_views(dataset: Dataset, cal: Calibration) -> dict[str, ResidualView]:
    """Every calibrated radar's residuals before and after correction (module doc).

    Radars with nothing to compare with (no plot aligned with ADS-B, no
    cross-radar pair) are left out.
    """
    biases = _biases(cal, dataset)
    height_model = cal.atmosphere.model if cal.atmosphere is not None else None
    views: dict[str, ResidualView] = {}
    if dataset.adsb is not None and len(dataset.adsb) > 0:
        for rid, bias in biases.items():
            after = adsb_radar_residuals(dataset, rid, bias, height_model=height_model)
            if after is None:
                continue
            before = adsb_radar_residuals(dataset, rid, RadarBias())
            site = dataset.sites[rid]
            views[rid] = ResidualView(rid, "adsb", None if before is None else
                                      _side(before, site), _side(after, site))
        return views
    after_all = cross_radar_residuals(dataset, biases, height_model)
    before_all = cross_radar_residuals(dataset, {rid: RadarBias() for rid in biases})
    for rid, after in after_all.items():
        site = dataset.sites[rid]
        before = before_all.get(rid)
        views[rid] = ResidualView(rid, "cross", None if before is None else _side(before, site),
                                  _side(after, site))
    return views


@dataclass
class PairSummary:
    """Radar versus radar: one radar's residuals against one partner, display units.

    ``mean`` and ``sd`` map ``(stage, coordinate)`` (stage ``"before"`` or
    ``"after"``) to the mean and standard deviation of the differences (this
    radar's plot minus the partner's, in this radar's polar frame).
    """

    radar_id: str
    partner: str
    n_after: int
    mean: dict[tuple[str, str], float]
    sd: dict[tuple[str, str], float]
    sigma: dict[str, float]


def pair_summaries(views: dict[str, ResidualView]) -> list[PairSummary]:
    """Per radar and partner, the statistics of the cross-radar differences."""
    out = []
    for rid, view in views.items():
        if view.reference != "cross" or view.after.partner is None:
            continue
        for partner in sorted(set(view.after.partner.tolist())):
            mean: dict[tuple[str, str], float] = {}
            sd: dict[tuple[str, str], float] = {}
            sigma: dict[str, float] = {}
            n_after = 0
            for stage, side in (("before", view.before), ("after", view.after)):
                if side is None or side.partner is None:
                    continue
                rows = side.partner == partner
                if stage == "after":
                    n_after = int(rows.sum())
                for c in ("range", "azimuth"):
                    values = side.residuals[c][rows]
                    values = values[np.isfinite(values)]
                    if values.size:
                        mean[(stage, c)] = float(np.mean(values))
                        sd[(stage, c)] = float(np.std(values))
                    if stage == "after" and values.size:
                        s = side.sigmas[c][rows]
                        sigma[c] = float(np.sqrt(np.nanmean(s**2)))
            out.append(PairSummary(rid, partner, n_after, mean, sd, sigma))
    return out


@dataclass
class Bins:
    """Binned residuals: per bin the centre, count, mean, standard deviation and the
    expected 1-sigma (root mean square of the residuals' sigmas)."""

    centre: FloatArray
    count: NDArray[np.int64]
    mean: FloatArray
    sd: FloatArray
    expected: FloatArray


def binned(x: FloatArray, y: FloatArray, sigma: FloatArray | None = None, *,
           n_bins: int = 12, width: float | None = None, span: tuple[float, float] | None = None
           ) -> Bins:
    """Mean and standard deviation of ``y`` in bins of ``x``.

    Bins hold equal counts (quantiles of ``x``), or, with ``width`` and ``span``,
    equal widths over ``span`` (e.g. 30 deg of azimuth over 0-360).  Bins with
    fewer than :data:`MIN_PER_BIN` finite values are dropped; the centre is the
    mean ``x`` of a bin.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    s = np.full(len(y), np.nan) if sigma is None else np.asarray(sigma, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y, s = x[ok], y[ok], s[ok]
    n_bins = max(1, min(n_bins, len(x) // MIN_PER_BIN))
    if width is not None and span is not None:
        edges = np.arange(span[0], span[1] + 0.5 * width, width)
    elif len(x):
        edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, n_bins + 1)))
    else:
        edges = np.array([0.0, 1.0])
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, max(len(edges) - 2, 0))
    rows = []
    for k in range(max(len(edges) - 1, 0)):
        inside = which == k
        n = int(inside.sum())
        if n < MIN_PER_BIN:
            continue
        ys, ss = y[inside], s[inside]
        expected = float(np.sqrt(np.nanmean(ss**2))) if np.any(np.isfinite(ss)) else math.nan
        rows.append((float(np.mean(x[inside])), n, float(np.mean(ys)), float(np.std(ys)),
                     expected))
    if not rows:
        empty = np.empty(0)
        return Bins(empty, np.empty(0, dtype=np.int64), empty, empty, empty)
    c, n, m, sd, e = (np.array(col) for col in zip(*rows, strict=True))
    return Bins(c, n.astype(np.int64), m, sd, e)


def robust_limits(values: FloatArray, percentiles: tuple[float, float] = ROBUST_PERCENTILES,
                  pad: float = 0.1) -> tuple[float, float, int]:
    """Axis limits from the ``percentiles`` of ``values`` (padded by ``pad`` of their span),
    and how many finite values lie outside them."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return -1.0, 1.0, 0
    lo, hi = (float(v) for v in np.percentile(finite, percentiles))
    span = hi - lo
    if span <= 0.0:
        span = max(abs(lo), 1.0) * 0.1
    lo, hi = lo - pad * span, hi + pad * span
    outside = int(np.count_nonzero((finite < lo) | (finite > hi)))
    return lo, hi, outside


__all__ = ["COORDINATES", "MIN_PER_BIN", "ROBUST_PERCENTILES", "VARIABLES", "Bins",
           "PairSummary", "ResidualView", "Side", "binned", "pair_summaries", "residual_views",
           "robust_limits"]

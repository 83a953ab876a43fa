"""The height model's observations: ADS-B reports with both heights (contract v2).

With pressure altitudes (``sites.toml`` ``[dataset] plot_altitude = "pressure"``)
the calibration carries one more variable, the height model ``x = (d, k)`` of
:mod:`graphcal.data.height`::

    h = (1 + k) p + d        (h above the ellipsoid, p the pressure altitude [m])

It enters the pairwise factors through the heights at which 2-D plots are
placed (:func:`graphcal.model.cross_radar.corrected_ecef`) and, here, through
the ADS-B reports that carry both the geometric ``alt_m`` and the barometric
``baro_alt_m``: each is a direct measurement of the model,

    e = alt_m - ((1 + k) baro_alt_m + d),     d e / d (d, k) = -(1, baro_alt_m).

Consecutive reports of one aircraft are not independent: a GNSS vertical error
and the local departure of the atmosphere from one linear model persist for
minutes, and a level aircraft's 25 ft quantisation error is the same in every
report.  A report-by-report factor with the white report noise would therefore
be far too confident.  :func:`adsb_height_segments` groups each aircraft's
reports into segments and keeps one measurement per segment, the segment means
(the model is linear, so the mean residual is the residual of the means):

- *level*: all the reports of one aircraft at one reported pressure altitude,
  when there are at least :data:`MIN_LEVEL_REPORTS` of them, however long the
  aircraft stays there (they share one quantisation error);
- *climbing or descending*: the other reports, cut into pieces of
  :data:`SEGMENT_S` seconds,

with the variance

    sigma^2 = mean(sigma_v^2) / n + q^2 / 12 + sigma_c^2,

the white GNSS noise averaged over the ``n`` reports (``sigma_v`` =
:data:`graphcal.data.align.ADSB_VERTICAL_SIGMA_RATIO` times the report's
horizontal sigma), the quantisation ``q`` (:data:`BARO_QUANTUM_M`) that a level
segment does not average, and a correlated floor ``sigma_c``
(:data:`CORRELATED_SIGMA_M`) that no averaging removes.  :class:`AdsbHeightFactor`
holds all the segments in one vectorised factor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.data.align import ADSB_VERTICAL_SIGMA_RATIO, PlotArrays
from graphcal.data.dataset import Site
from graphcal.data.height import FOOT_M, height_jacobian
from graphcal.model.cross_radar import MAX_2D_ELEVATION_RAD
from graphcal.model.robust import RobustKernel

FloatArray = NDArray[np.float64]

#: Weak prior 1-sigma of the height model ``(height_offset_m [m], height_scale)``.
HEIGHT_PRIOR_SIGMA: tuple[float, float] = (1000.0, 0.1)
#: Length [s] of the ADS-B segments that each give one height-model measurement.
SEGMENT_S = 60.0
#: Quantum [m] of a reported pressure altitude (25 ft).
BARO_QUANTUM_M = 25.0 * FOOT_M
#: Fewest reports of one aircraft at one reported pressure altitude that form a level segment.
MIN_LEVEL_REPORTS = 3
#: Correlated 1-sigma [m] of a segment mean that averaging does not remove (GNSS vertical
#: errors and the atmosphere's local departure from one linear model).
CORRELATED_SIGMA_M = 3.0


@dataclass
class HeightSegments:
    """One row per ADS-B aircraft segment: mean heights and the sigma of their difference.

    Attributes
    ----------
    target_id : ndarray (n,) of str
    time_s : ndarray (n,)
        Mean report time [s].
    geometric_m : ndarray (n,)
        Mean reported height above the ellipsoid ``alt_m`` [m].
    pressure_m : ndarray (n,)
        Mean reported pressure altitude ``baro_alt_m`` [m].
    sigma_m : ndarray (n,)
        1-sigma of ``geometric_m - model(pressure_m)`` [m] (module docstring).
    n_reports : ndarray (n,) of int
    """

    target_id: NDArray[np.object_]
    time_s: FloatArray
    geometric_m: FloatArray
    pressure_m: FloatArray
    sigma_m: FloatArray
    n_reports: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.time_s)


def adsb_height_segments(
    adsb: pd.DataFrame | None,
    segment_s: float = SEGMENT_S,
    correlated_sigma_m: float = CORRELATED_SIGMA_M,
) -> HeightSegments:
    """The segment means of the ADS-B reports that carry both heights (module docstring).

    Parameters
    ----------
    adsb : DataFrame or None
        The dataset's ADS-B table (``time_s``, ``target_id``, ``alt_m``, ``sigma_m``
        and, for any segment at all, ``baro_alt_m``).
    segment_s : float
        Length [s] of the climbing or descending segments; an aircraft's start at
        its first such report.  Level segments are whole (module docstring).
    correlated_sigma_m : float
        The floor ``sigma_c`` [m].

    Returns
    -------
    HeightSegments
        Empty without a ``baro_alt_m`` column or reports with both heights.
    """
    empty = HeightSegments(np.zeros(0, dtype=object), np.zeros(0), np.zeros(0), np.zeros(0),
                           np.zeros(0), np.zeros(0, dtype=np.int64))
    if adsb is None or "baro_alt_m" not in adsb or len(adsb) == 0:
        return empty
    geometric = adsb["alt_m"].to_numpy(dtype=float)
    pressure = pd.to_numeric(adsb["baro_alt_m"], errors="coerce").to_numpy(
        dtype=float, na_value=np.nan)
    keep = np.isfinite(geometric) & np.isfinite(pressure)
    if not np.any(keep):
        return empty
    table = pd.DataFrame({
        "target": adsb["target_id"].astype(str).to_numpy()[keep],
        "time": adsb["time_s"].to_numpy(dtype=float)[keep],
        "h": geometric[keep],
        "p": pressure[keep],
        "var_v": (ADSB_VERTICAL_SIGMA_RATIO * adsb["sigma_m"].to_numpy(dtype=float)[keep]) ** 2,
    })
    at_level = table.groupby(["target", "p"], sort=False)["time"].transform("size")
    level = (at_level >= MIN_LEVEL_REPORTS).to_numpy()
    moving = table[~level]
    start = moving.groupby("target", sort=False)["time"].transform("min")
    pieces = np.floor((moving["time"] - start) / segment_s).astype(np.int64)
    # Level segments: one per (aircraft, pressure altitude), numbered apart from the pieces.
    levels = pd.factorize(pd.MultiIndex.from_frame(table.loc[level, ["target", "p"]]))[0]
    segment = np.empty(len(table), dtype=np.int64)
    segment[~level] = pieces.to_numpy()
    segment[level] = -1 - levels
    table["segment"] = segment
    means = table.groupby(["target", "segment"], sort=True).agg(
        time=("time", "mean"), h=("h", "mean"), p=("p", "mean"), var_v=("var_v", "mean"),
        n=("time", "size"),
    )
    n = means["n"].to_numpy(dtype=np.int64)
    variance = (means["var_v"].to_numpy() / n + BARO_QUANTUM_M**2 / 12.0
                + correlated_sigma_m**2)
    return HeightSegments(
        target_id=means.index.get_level_values("target").to_numpy(dtype=object),
        time_s=means["time"].to_numpy(),
        geometric_m=means["h"].to_numpy(),
        pressure_m=means["p"].to_numpy(),
        sigma_m=np.sqrt(variance),
        n_reports=n,
    )


@dataclass
class AdsbHeightFactor:
    """The ADS-B height-model measurements, one per aircraft segment, in one factor.

    Residual of segment ``i`` (whitened by its ``sigma_i``, then robustified as
    every measurement of the graph)::

        e_i = (h_i - ((1 + k) p_i + d)) / sigma_i

    Attributes
    ----------
    key : int
        GTSAM key of the height-model variable ``(d, k)``.
    segments : HeightSegments
    kernel : RobustKernel
    """

    key: int
    segments: HeightSegments
    kernel: RobustKernel

    @property
    def keys(self) -> list[int]:
        return [self.key]

    @property
    def dimension(self) -> int:
        return len(self.segments)

    def __len__(self) -> int:
        return len(self.segments)

    def residual(self, height_model: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Unwhitened residual ``(n, 1)`` [m] and its Jacobian ``(n, 1, 2)``."""
        offset, scale = (float(v) for v in height_model)
        seg = self.segments
        res = seg.geometric_m - ((1.0 + scale) * seg.pressure_m + offset)
        return res[:, None], -height_jacobian(seg.pressure_m)[:, None, :]

    def whitened(self, values: list[FloatArray]) -> tuple[FloatArray, list[FloatArray]]:
        """Whitened residual ``(n, 1)`` and Jacobian ``(n, 1, 2)`` before the robust kernel."""
        res, jac = self.residual(values[0])
        w = 1.0 / self.segments.sigma_m
        return res * w[:, None], [jac * w[:, None, None]]

    def error(
        self, values: list[FloatArray], want_jacobians: bool
    ) -> tuple[FloatArray, list[FloatArray] | None]:
        e, jac = self.whitened(values)
        e, jac = self.kernel.apply(e, jac if want_jacobians else None)
        flat = e.reshape(-1)
        if jac is None:
            return flat, None
        return flat, [j.reshape(flat.size, j.shape[-1]) for j in jac]


def adsb_height_factor(
    adsb: pd.DataFrame | None, key: int, kernel: RobustKernel
) -> AdsbHeightFactor | None:
    """The ADS-B height factor of a dataset's ADS-B table; ``None`` without both heights."""
    segments = adsb_height_segments(adsb)
    if len(segments) == 0:
        return None
    return AdsbHeightFactor(key, segments, kernel)


def placeable_over_prior(site: Site, plots: PlotArrays) -> NDArray[np.bool_]:
    """2-D plots that stay placeable for any height model within the prior's 1 sigma.

    A 2-D plot is placed at the elevation of its height
    (:func:`graphcal.core.frames.elevation_from_height`); near the radar's zenith
    that elevation leaves :data:`graphcal.model.cross_radar.MAX_2D_ELEVATION_RAD`
    (or the slant range cannot reach the height), and the plot cannot be used.
    With pressure altitudes the height moves with the estimated model, so a plot
    is paired only if it is placeable at both ends of the heights
    ``(1 +- k) p +- d`` (``d``, ``k``: :data:`HEIGHT_PRIOR_SIGMA`): elevation is
    monotonic in height at a fixed range.  Every plot of a 3-D radar is placeable.
    """
    n = len(plots)
    if site.is_3d:
        return np.ones(n, dtype=bool)
    offset, scale = HEIGHT_PRIOR_SIGMA
    p = plots.altitude_m
    ends = [(1.0 + sign_k * scale) * p + sign_d * offset
            for sign_k in (1.0, -1.0) for sign_d in (1.0, -1.0)]
    ok = np.isfinite(p)
    for height in (np.min(ends, axis=0), np.max(ends, axis=0)):
        el = frames.elevation_from_height(plots.range_m, height, site.lat_rad, site.alt_m)
        with np.errstate(invalid="ignore"):
            ok &= np.isfinite(el) & (np.abs(el) < MAX_2D_ELEVATION_RAD)
    return ok

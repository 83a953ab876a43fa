"""One calibration problem: the hand-off from the data to every solver and analysis.

:func:`build_problem` takes a dataset and the estimators' options
(:class:`~graphcal.core.solve_options.SolveOptions`) and returns a :class:`Problem`: the
dataset, the options and what every stage derives from them, each computed once, on
first use, by the problem itself:

- every radar's plots as SI arrays in time order (:meth:`Problem.plots`);
- the ADS-B reports grouped by aircraft (:attr:`Problem.adsb_tracks`);
- every radar's plots aligned with ADS-B at zero time offset
  (:meth:`Problem.alignment`; at another time offset computed afresh);
- one measurement model per radar, with the Jacobian of every bias term
  (:meth:`Problem.measurement_model`,
  :meth:`~graphcal.model.measurement.RadarMeasurementModel.measure`).

The solvers (``solve(problem)``, :func:`graphcal.solvers.registry.solve`) and the
analyses (the bound, the model checks, the fit verdict) all take the problem, so the
initial values, the factors, the bound and the checks of one calibration share these
arrays by holding the same problem, not through a cache keyed by object identity.

A problem is immutable: its dataset, options and derived arrays do not change once
built, and a derived array handed out is read-only.  The problem does not copy the
dataset's tables: do not modify them while the problem is in use.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from graphcal.core.solve_options import SolveOptions
from graphcal.data.align import (
    AdsbAlignment,
    AdsbTrackTable,
    PlotArrays,
    PlotTable,
    adsb_track_table,
    align_adsb,
    align_adsb_thinned,
    plot_arrays,
    plot_table,
)
from graphcal.data.dataset import Dataset, Site
from graphcal.model.measurement import RadarMeasurementModel, measurement_model

T = TypeVar("T")


@dataclass(frozen=True, eq=False)
class Problem:
    """A dataset and the estimators' options, with the arrays every stage derives from them.

    Build it with :func:`build_problem`.  Attributes are read-only; the derived arrays
    are computed on first use and kept (:meth:`plots`, :meth:`alignment`, ...).
    """

    dataset: Dataset
    options: SolveOptions = field(default_factory=SolveOptions)
    _derived: dict[tuple, Any] = field(default_factory=dict, init=False, repr=False)

    # ------------------------------------------------------------ the data
    @property
    def sites(self) -> dict[str, Site]:
        return self.dataset.sites

    @property
    def radar_ids(self) -> list[str]:
        return list(self.dataset.radar_ids)

    @property
    def has_adsb(self) -> bool:
        """ADS-B is used: the options allow it and the dataset has reports."""
        adsb = self.dataset.adsb
        return bool(self.options.use_adsb and adsb is not None and len(adsb) > 0)

    def _once(self, key: tuple, compute: Callable[[], T]) -> T:
        if key not in self._derived:
            self._derived[key] = compute()
        return self._derived[key]

    # ------------------------------------------------------------ derived arrays
    @property
    def plot_table(self) -> PlotTable:
        """The plots table as SI arrays, grouped by radar
        (:func:`~graphcal.data.align.plot_table`)."""
        return self._once(("plot_table",), lambda: plot_table(self.dataset.plots))

    def plots(self, radar_id: str) -> PlotArrays:
        """``radar_id``'s plots in time order, as SI arrays (read-only)."""
        return self._once(("plots", radar_id),
                          lambda: plot_arrays(self.dataset, radar_id, self.plot_table))

    @property
    def all_plots(self) -> dict[str, PlotArrays]:
        """Every radar's :meth:`plots`."""
        return {rid: self.plots(rid) for rid in self.radar_ids}

    @property
    def adsb_tracks(self) -> AdsbTrackTable:
        """The ADS-B reports grouped by aircraft, in time order."""
        if self.dataset.adsb is None:
            raise ValueError("the dataset has no ADS-B table")
        return self._once(("adsb_tracks",), lambda: adsb_track_table(self.dataset.adsb))

    def alignment(self, radar_id: str, max_gap_s: float | None = None,
                  time_offset_s: float = 0.0) -> AdsbAlignment:
        """``radar_id``'s plots aligned with ADS-B (:func:`~graphcal.data.align.align_adsb`).

        ``max_gap_s`` defaults to the options' ADS-B gap.  At zero time offset the
        alignment is computed once and shared by every stage (read-only); at another
        time offset it is computed afresh.
        """
        gap = self.options.adsb_max_gap_s if max_gap_s is None else float(max_gap_s)

        def compute() -> AdsbAlignment:
            return align_adsb(self.dataset, radar_id, gap, time_offset_s,
                              plots=self.plots(radar_id), tracks=self.adsb_tracks)

        if time_offset_s != 0.0:
            return compute()
        return self._once(("alignment", radar_id, gap), compute)

    def measurement_model(self, radar_id: str) -> RadarMeasurementModel:
        """``radar_id``'s measurement model (the Jacobian of every bias term)."""
        return self._once(("model", radar_id), lambda: measurement_model(self.sites[radar_id]))

    # ------------------------------------------------------------ other problems
    def with_options(self, **changes: Any) -> Problem:
        """The same data with other options; the derived arrays that do not depend on
        the options (plots, ADS-B tracks, alignments by gap) are shared."""
        other = Problem(self.dataset, self.options.replace(**changes))
        other._derived.update(self._derived)
        return other

    def with_dataset(self, dataset: Dataset) -> Problem:
        """Another dataset with the same options (nothing derived is shared)."""
        return Problem(dataset, self.options)

    def thinned(self, keep: NDArray[np.bool_]) -> Problem:
        """The problem of the plot rows ``keep`` only (rows renumbered from 0, the same
        ADS-B and sites), its zero-offset alignments cut from this problem's
        (:func:`~graphcal.data.align.align_adsb_thinned`: the same arrays, without
        aligning again)."""
        keep = np.asarray(keep, dtype=bool)
        plots = self.dataset.plots[keep].reset_index(drop=True)
        thinned = Problem(dataclasses.replace(self.dataset, plots=plots), self.options)
        if self.dataset.adsb is not None:
            thinned._derived[("adsb_tracks",)] = self.adsb_tracks
        for key, value in list(self._derived.items()):
            if key[0] == "alignment":
                rid = key[1]
                thinned._derived[key] = align_adsb_thinned(
                    value, self.dataset, keep, self.plots(rid))
        return thinned


def build_problem(dataset: Dataset, options: SolveOptions | None = None, **changes: Any
                  ) -> Problem:
    """The :class:`Problem` of ``dataset`` with ``options`` (default: the command line's),
    changed by ``changes`` (fields of :class:`~graphcal.core.solve_options.SolveOptions`).

    Nothing is computed yet: each derived array is computed when a stage first asks for
    it, and kept.
    """
    options = SolveOptions() if options is None else options
    if changes:
        options = options.replace(**changes)
    return Problem(dataset, options)


def as_problem(data: Dataset | Problem, options: SolveOptions | None = None) -> Problem:
    """``data`` as a :class:`Problem`: a problem as it is, a dataset as a new problem
    with ``options`` (the estimators' own keyword arguments still choose how they solve
    it)."""
    if isinstance(data, Problem):
        return data
    return build_problem(data, options)


__all__ = ["Problem", "as_problem", "build_problem"]

"""Plots without an address associated with known aircraft by gating (contract v3).

Primary radars report no identity, Mode A/C radars a code that is not unique; their plots'
``target_id`` is empty.  This module gives such a plot the address of the aircraft it is a
measurement of, or leaves it out, so that the calibration can use it as it uses an
addressed plot, and clutter never enters the fit.

The aircraft are those with a reference trajectory (:mod:`graphcal.tracking.gating`:
ADS-B, and the Mode S radars' plots corrected with their current biases).  For one radar,
with its current bias estimate and its covariance:

1. **Gates.**  Every (plot, aircraft) pair inside the chi-square gate in the radar's own
   coordinates, Mode 3/A and Mode C as evidence (:func:`~graphcal.tracking.gating.gated_pairs`).
2. **One plot per aircraft per antenna turn.**  Within each scan (plots binned by the
   radar's scan period), plots and aircraft are assigned by minimum total chi-square
   (:func:`scipy.optimize.linear_sum_assignment`).
3. **Ambiguity.**  A plot whose second-best aircraft fits within
   :data:`AMBIGUITY_CHI2_MARGIN` of its best is left out: it could be either.
4. **Track numbers.**  A radar's track number keeps its plots together: the plots of one
   number take the aircraft most of its associated plots have, where that aircraft is in
   their gate; those assigned elsewhere and not in its gate are left out.
5. **Paths of their own.**  The plots left out that form tracks, seen by two of these
   radars, become aircraft of their own (:mod:`graphcal.tracking.own_paths`).

The pipeline starts from :func:`~graphcal.tracking.gating.coarse_bias` and then associates
and calibrates in turn until the associations stop changing.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.special import chdtri

from graphcal.data.align import plot_arrays
from graphcal.data.bias import RadarBias
from graphcal.data.dataset import Dataset, Site
from graphcal.tracking.gating import (
    Pairs,
    References,
    coarse_bias,
    gated_pairs,
    reference_tracks,
    scan_period,
)
from graphcal.tracking.own_paths import Leftover
from graphcal.tracking.own_paths import own_paths as find_own_paths

FloatArray = NDArray[np.float64]

#: A plot whose second-best aircraft's chi-square is within this of its best is ambiguous.
AMBIGUITY_CHI2_MARGIN = 4.0
#: The associated plots' fit: the chi-square point whose tail is counted, the multiple of
#: its expected share that is warned about, and the fewest associated plots judged.
TAIL_PROBABILITY = 0.999
TAIL_WARNING_FACTOR = 10.0
MIN_TAIL_PLOTS = 200
#: Status of each unaddressed plot.
ASSOCIATED, AMBIGUOUS, LEFT_OUT = 0, 1, 2


# --------------------------------------------------------------------------- association
@dataclass
class RadarAssociation:
    """One radar's association figures (contract v3 ``info.association``)."""

    radar_id: str
    n_plots: int  # plots without an address
    n_associated: int
    n_ambiguous: int
    n_left_out: int
    n_scans: int
    detection_probability: float | None
    false_plots_per_scan: float | None
    mode_3a_consistency: float | None
    #: Associated plots that fit their aircraft worse than the chi-square's
    #: :data:`TAIL_PROBABILITY` point, as a fraction (``1 - TAIL_PROBABILITY`` expected).
    tail_fraction: float | None = None
    #: Associated plots on paths of their own (aircraft no reference covers).
    n_own_paths: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"plots": self.n_plots, "associated": self.n_associated,
                "ambiguous": self.n_ambiguous, "left_out": self.n_left_out,
                "scans": self.n_scans, "detection_probability": self.detection_probability,
                "false_plots_per_scan": self.false_plots_per_scan,
                "mode_3a_consistency": self.mode_3a_consistency,
                "tail_fraction": self.tail_fraction, "own_paths": self.n_own_paths}

    def warning(self) -> str | None:
        """A warning when the associated plots' fit shows association errors: more than
        :data:`TAIL_WARNING_FACTOR` times the expected share beyond the tail point."""
        expected = 1.0 - TAIL_PROBABILITY
        if (self.tail_fraction is None or self.n_associated < MIN_TAIL_PLOTS
                or self.tail_fraction <= TAIL_WARNING_FACTOR * expected):
            return None
        return (f"{self.radar_id}: {100 * self.tail_fraction:.1f} % of its associated plots fit "
                f"their aircraft worse than the {100 * TAIL_PROBABILITY:g} % point "
                f"({100 * expected:g} % expected): association errors, or a bias the model "
                "lacks?")


@dataclass
class Association:
    """Addresses given to plots without one: ``target_id`` by plot row label ("" where left
    out), each such plot's status, and the per-radar figures."""

    target_id: pd.Series
    status: pd.Series
    radars: dict[str, RadarAssociation] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {rid: r.to_dict() for rid, r in self.radars.items()}

    def applied(self, dataset: Dataset) -> Dataset:
        """``dataset`` with the associated plots addressed and the other plots without an
        address left out (they never enter the fit)."""
        plots = dataset.plots
        unaddressed = plots.index.isin(self.status.index)
        keep = ~unaddressed | plots.index.isin(self.status.index[self.status == ASSOCIATED])
        out = plots.loc[keep].copy()
        assigned = self.target_id[self.status == ASSOCIATED]
        out.loc[out.index.isin(assigned.index), "target_id"] = assigned.reindex(
            out.index[out.index.isin(assigned.index)]).to_numpy()
        return replace(dataset, plots=out)


#: A radar most of whose plots carry no address (at least this fraction) is a radar without
#: identity: its biases are first found by the coarse search.  A radar with fewer such plots
#: (a Mode S radar's plots that lost their address) is started from its addressed plots.
UNADDRESSED_FRACTION = 0.5


def unaddressed_share(dataset: Dataset) -> dict[str, float]:
    """Per radar with plots, the fraction of its plots without an address."""
    target = dataset.plots["target_id"]
    empty = target.isna() | (target.astype(str).str.strip().isin(["", "nan"]))
    share = empty.groupby(dataset.plots["radar_id"], sort=False).mean()
    return {str(r): float(f) for r, f in share.items()}


def unaddressed_radars(dataset: Dataset, min_fraction: float = 0.0) -> list[str]:
    """Radars with plots without an address: more than ``min_fraction`` of them (default:
    any)."""
    return [r for r, f in unaddressed_share(dataset).items() if f > min_fraction]


def associate(dataset: Dataset, biases: Mapping[str, RadarBias],
              covariances: Mapping[str, FloatArray] | None = None, *,
              use_adsb: bool = True, radars: list[str] | None = None,
              own_paths: bool = True) -> Association:
    """Associate every plot without an address (module docstring).

    Parameters
    ----------
    dataset : Dataset
    biases : mapping of radar id to RadarBias
        The current estimate of every radar (missing: zero).
    covariances : mapping of radar id to ndarray (4, 4), optional
        The estimate's covariance over (range offset m, range gain, azimuth bias rad,
        elevation bias rad), widening the gate; missing: none.
    use_adsb : bool
        Use the ADS-B reports as references.
    radars : list of str, optional
        The radars to associate (default :func:`unaddressed_radars`).
    own_paths : bool
        Give the aircraft no reference covers, seen by two of these radars, paths of their
        own (:func:`graphcal.tracking.own_paths.own_paths`).
    """
    refs = reference_tracks(dataset, biases, use_adsb=use_adsb)
    radars = unaddressed_radars(dataset) if radars is None else radars
    names = np.asarray(refs.tracks.targets, dtype=object)
    done: dict[str, tuple[Any, NDArray[np.object_], NDArray[np.int64], Any, float | None]] = {}
    leftovers: dict[str, Leftover] = {}
    for rid in radars:
        site = dataset.sites[rid]
        all_plots = plot_arrays(dataset, rid)
        target = all_plots.target_id.astype(str)
        rows = np.flatnonzero((target == "") | (target == "nan"))
        plots = all_plots.subset(rows)
        frame = dataset.plots.loc[plots.index]
        codes = (frame["mode_3a"].astype("string").fillna("").to_numpy(object)
                 if "mode_3a" in frame else None)
        numbers = frame["track_number"].to_numpy() if "track_number" in frame else None
        bias = biases.get(rid, RadarBias())
        cov = None if covariances is None else covariances.get(rid)
        pairs = gated_pairs(site, refs, plots, bias, cov, None, codes)
        assigned, status = _assign(site, plots, pairs)
        if numbers is not None:
            _by_track(numbers, pairs, assigned, status)
        ids = np.full(len(assigned), "", dtype=object)
        ids[assigned >= 0] = names[assigned[assigned >= 0]]
        tail = _tail_fraction(site, pairs, assigned, len(names))
        done[rid] = (plots, ids, status, codes, tail)
        left = np.flatnonzero(status == LEFT_OUT)
        leftovers[rid] = Leftover(
            plots.subset(left), left, None if codes is None else codes[left],
            None if numbers is None else numbers[left], bias, cov)
    own: dict[str, NDArray[np.object_]] = {}
    if own_paths and len(leftovers) >= 2:
        own = find_own_paths(dataset.sites, leftovers)
    target_parts, status_parts, figures = [], [], {}
    for rid, (plots, ids, status, codes, tail) in done.items():
        on_own = np.zeros(len(ids), dtype=bool)
        if rid in own:
            found = own[rid] != ""
            rows = leftovers[rid].rows[found]
            ids[rows] = own[rid][found]
            status[rows] = ASSOCIATED
            on_own[rows] = True
        target_parts.append(pd.Series(ids, index=plots.index, dtype=object))
        status_parts.append(pd.Series(status, index=plots.index))
        figures[rid] = _figures(rid, dataset.sites[rid], plots, ids, status, refs, codes)
        figures[rid].tail_fraction = tail
        figures[rid].n_own_paths = int(on_own.sum())
    target_id = (pd.concat(target_parts) if target_parts else pd.Series(dtype=object))
    status_all = pd.concat(status_parts) if status_parts else pd.Series(dtype=np.int64)
    return Association(target_id, status_all, figures)


def _assign(site: Site, plots: Any, pairs: Pairs
            ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """One plot per aircraft per scan, ambiguous plots left out."""
    from scipy.optimize import linear_sum_assignment  # only when plots lack an address

    n = len(plots)
    assigned = np.full(n, -1, dtype=np.int64)
    status = np.full(n, LEFT_OUT, dtype=np.int64)
    if len(pairs.plot) == 0:
        return assigned, status
    # Ambiguity: a plot whose second-best aircraft fits almost as well.
    order = np.lexsort((pairs.chi2, pairs.plot))
    p, c = pairs.plot[order], pairs.chi2[order]
    first = np.r_[True, p[1:] != p[:-1]]
    best = np.full(n, np.inf)
    second = np.full(n, np.inf)
    best[p[first]] = c[first]
    is_second = np.r_[False, ~first[1:] & first[:-1]]
    second[p[is_second]] = c[is_second]
    ambiguous = np.zeros(n, dtype=bool)
    both = np.isfinite(second)
    ambiguous[both] = second[both] - best[both] < AMBIGUITY_CHI2_MARGIN
    # Scans: the plots' times binned by the scan period.
    scan = np.floor(plots.time_s / scan_period(site)).astype(np.int64)
    keep = ~ambiguous[pairs.plot]
    pp, aa, cc = pairs.plot[keep], pairs.aircraft[keep], pairs.chi2[keep]
    pair_scan = scan[pp]
    order = np.argsort(pair_scan, kind="stable")
    pp, aa, cc, pair_scan = pp[order], aa[order], cc[order], pair_scan[order]
    bounds = np.flatnonzero(np.r_[True, pair_scan[1:] != pair_scan[:-1], True])
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        bp, ba, bc = pp[lo:hi], aa[lo:hi], cc[lo:hi]
        up, ip = np.unique(bp, return_inverse=True)
        ua, ia = np.unique(ba, return_inverse=True)
        if len(up) == 1 or len(ua) == 1:
            k = int(np.argmin(bc))
            assigned[bp[k]] = ba[k]
            continue
        cost = np.full((len(up), len(ua)), 1e9)
        cost[ip, ia] = bc
        r, a = linear_sum_assignment(cost)
        good = cost[r, a] < 1e9
        assigned[up[r[good]]] = ua[a[good]]
    status[assigned >= 0] = ASSOCIATED
    status[ambiguous & (assigned < 0)] = AMBIGUOUS
    return assigned, status


def _by_track(track_number: NDArray, pairs: Pairs, assigned: NDArray[np.int64],
              status: NDArray[np.int64]) -> None:
    """Track numbers keep their plots together (module docstring), in place."""
    numbers = pd.array(track_number, dtype="Int64")
    have = ~pd.isna(numbers)
    if not have.any():
        return
    gated = set(zip(pairs.plot.tolist(), pairs.aircraft.tolist(), strict=True))
    numbers = np.asarray(numbers.to_numpy(dtype=np.int64, na_value=-1))
    for number in np.unique(numbers[have]):
        rows = np.flatnonzero(numbers == number)
        mine = assigned[rows]
        known = mine[mine >= 0]
        if len(known) == 0:
            continue
        values, counts = np.unique(known, return_counts=True)
        major = int(values[np.argmax(counts)])
        if counts.max() < 0.5 * len(known):
            continue
        for row in rows:
            if (int(row), major) in gated:
                assigned[row] = major
                status[row] = ASSOCIATED
            elif assigned[row] >= 0:
                assigned[row] = -1
                status[row] = LEFT_OUT


def _tail_fraction(site: Site, pairs: Pairs, assigned: NDArray[np.int64], n_aircraft: int
                   ) -> float | None:
    """The share of associated plots beyond the chi-square's :data:`TAIL_PROBABILITY` point."""
    rows = np.flatnonzero(assigned >= 0)
    if len(rows) == 0:
        return None
    keys = pd.Index(pairs.plot * max(n_aircraft, 1) + pairs.aircraft)
    at = keys.get_indexer(rows * max(n_aircraft, 1) + assigned[rows])
    chi2 = pairs.chi2[at[at >= 0]]
    m = 3 if site.is_3d else 2
    return float(np.mean(chi2 > chdtri(m, 1.0 - TAIL_PROBABILITY))) if len(chi2) else None


def _figures(rid: str, site: Site, plots: Any, ids: NDArray[np.object_],
             status: NDArray[np.int64], refs: References,
             codes: NDArray[np.object_] | None = None) -> RadarAssociation:
    """Detection probability, false plots per scan and code consistency of one radar;
    ``ids``: each plot's aircraft ("" where none)."""
    period = scan_period(site)
    n_scans = 0
    if len(plots):
        n_scans = int(np.floor((plots.time_s.max() - plots.time_s.min()) / period)) + 1
    detection = None
    seen = status == ASSOCIATED
    if seen.any():
        frame = pd.DataFrame({"a": ids[seen], "t": plots.time_s[seen]})
        span = frame.groupby("a")["t"].agg(["min", "max", "size"])
        expected = np.floor((span["max"] - span["min"]) / period) + 1
        detection = float(min(1.0, span["size"].sum() / expected.sum()))
    left = int(np.sum(status == LEFT_OUT))
    false_rate = left / n_scans if n_scans else None
    consistency = None
    if codes is not None and seen.any():
        have = np.array([bool(c) for c in np.asarray(codes, dtype=object)]) & seen
        known = [(c, n) for c, n in zip(np.asarray(codes, dtype=object)[have], ids[have],
                                        strict=True) if refs.codes.get(n)]
        if known:
            consistency = float(np.mean([c in refs.codes[n] for c, n in known]))
    return RadarAssociation(rid, len(plots), int(seen.sum()), int(np.sum(status == AMBIGUOUS)),
                            left, n_scans, detection, false_rate, consistency)


__all__ = ["AMBIGUITY_CHI2_MARGIN", "ASSOCIATED", "AMBIGUOUS", "Association", "LEFT_OUT",
           "RadarAssociation", "associate", "coarse_bias", "reference_tracks",
           "UNADDRESSED_FRACTION", "unaddressed_radars", "unaddressed_share"]

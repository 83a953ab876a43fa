"""The fit verdict: are a calibration's residuals within their sigmas, radar by radar?

An estimator always returns numbers, and its covariance assumes the model is
right.  When it is not (azimuths in radians, ADS-B heights in feet, an antenna
140 km off), the biases come out with tiny sigmas and mean nothing.  The
residuals say so: corrected against ADS-B (or, without it, against the other
radars' plots; :func:`graphcal.analysis.model_checks.calibrated_residuals`), each
radar's residuals in range, azimuth and (3-D) elevation, normalised by their
expected variance (the radar's sigmas, given in ``sites.toml`` or estimated from
the data, plus the reference's), have a mean square ``chi2 / dof`` near 1.

Verdict
    A coordinate of a radar *fails* when its ``chi2 / dof`` exceeds

    ``limit(dof) = max(FLOOR, chi2_isf(P, dof) / dof)``

    * ``chi2_isf(P, dof) / dof``: the value a correct model with the stated noise
      exceeds with probability :data:`P` (1e-6) given the residuals' degrees of
      freedom (their count less the radar's estimated terms).  It matters for
      few residuals (4.7 at 10 dof, 2.3 at 50); for the thousands a
      calibration has it approaches 1 (1.1 at 10,000 dof), where the floor rules.
    * :data:`FLOOR` = 4: room for an imperfect noise model.  Stated sigmas are
      nominal and real noise is not exactly Gaussian; residuals up to twice
      their sigma on average (chi2/dof 4) pass.  Unmodelled effects the model
      checks report (refraction, pressure altitudes: chi2/dof 1-2 on the
      scenarios) stay below it; a unit or frame mistake gives 10^2 to 10^8.

    ``altitude`` residuals (a 2-D radar's Mode C height against ADS-B) are not
    judged: pressure altitudes taken for geometric heights give chi2/dof of 35
    without any bias being wrong, and no bias term acts on them.

    A radar also fails when its estimate corrects some of its plots to a negative
    range, and when its estimated ``range_gain`` is beyond
    :data:`MAX_RANGE_GAIN` (1 %, i.e. 2.5 km at 250 km; real gains are of the
    order of 1e-4): ranges in km or NM are *exactly* a range gain of -0.999,
    which the residuals cannot reveal.

Without ADS-B residuals the trajectory formulation (the default) judges each radar's
plots on the aircraft's paths it estimated (``reference`` ``"paths"``;
``info["target_state"]["fit"]``): the whitened residuals of the plots on the paths, in
their own coordinates and through the same measurement model (refraction, eccentricity,
time offsets) as the estimate, with ``dof`` their count less the share of the paths'
unknowns they take (:meth:`graphcal.model.trajectory.TrajectoryBlock.residual_fit`) and
less the radar's terms.  On correct data these read 1.002 +- 0.019 (the demo network,
12 seeds) and at most 1.13 (``demo_v2``, 40 seeds), where the pairwise comparison of
two radars' plots (``"cross"``: interpolated partner, converted plots; without the model
checks' outlier screening) gave up to 2.6 for ``demo_v2``'s 3-D radars' elevations.
Otherwise, without ADS-B, each residual compares two radars (``"cross"``).  Either way
one radar's misfit also shows in the others': the radars are listed worst first.

Widening (:func:`sigma_inflation`)
    Between 1 and the limit the fit passes, yet the sigmas, computed from the stated
    noise, are too small when the residuals are larger than it says.  A coordinate
    whose ``chi2 / dof`` exceeds

    ``widen_limit(dof) = max(WIDEN_FLOOR, chi2_isf(WIDEN_P, dof) / dof)``

    (:data:`WIDEN_P` 1e-3, :data:`WIDEN_FLOOR` 1.15: on data the model fits, the
    demo scenarios' coordinates stay within 0.95-1.05 at 5,000-9,000 dof; see
    ``benchmarks/variance_factor_study.py``) gives the parameters it measures a
    variance factor ``f`` = its ``chi2 / dof`` (range: range offset and gain; azimuth:
    azimuth bias and eccentricity; elevation: elevation bias); the time offset, which
    every coordinate measures through the along-track motion, takes the radar's
    largest.  The pipeline (``graphcal calibrate``, method ``graph``) multiplies each
    such parameter's row and column of the joint covariance by ``sqrt(f)``, which
    keeps it positive semi-definite, records ``info["sigma_inflation"]`` and warns.
    Residuals against ADS-B carry the ADS-B error as well as the radar's, and without
    ADS-B the partner's: the factor says the stated noise is too small, not whose.
    Over windows the windows' residuals are pooled per radar (:func:`pooled_verdict`).

Over time windows (``calibrate --window``) each window's own fit is judged so, from
the numbers its summary carries (:class:`graphcal.solvers.window_fit.WindowFit`:
residuals against ADS-B only; a window without them is judged on its range gains
and negative ranges alone), and a radar fails the run when it fails in any window
(:func:`windows_verdict`); the verdict names those windows.

:func:`fit_verdict` computes it (from the model checks when they ran, else from
the residuals); :class:`FitVerdict` holds it, and ``graphcal calibrate`` turns a
failed verdict into exit status 3 (:class:`ModelMisfitError`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from scipy import special

from graphcal.analysis.model_checks import ModelChecks, calibrated_residuals, normalised_sums
from graphcal.core.errors import EstimationError
from graphcal.data.bias import CONTRACT_KEYS, count_non_positive_ranges
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset
from graphcal.model.problem import Problem, as_problem
from graphcal.solvers.window_fit import WindowFit, sums_on_paths

#: Chance that a correct model with the stated noise exceeds the limit (given its dof).
P = 1e-6
#: Smallest limit of chi2/dof: residuals twice their sigma on average (noise-model error).
FLOOR = 4.0
#: Largest plausible |range_gain| (fraction); beyond: ranges in another unit.
MAX_RANGE_GAIN = 0.01
#: The coordinates judged (their bias terms are estimated; altitude is not judged).
JUDGED: tuple[str, ...] = ("range", "azimuth", "elevation")
#: At most this many windows are named per radar in the message (all in the JSON).
MESSAGE_WINDOWS = 4
#: Chance that a correct model with the stated noise has its sigmas widened (given its dof).
WIDEN_P = 1e-3
#: Smallest ``chi2/dof`` that widens the sigmas: room for the noise model (module docstring).
WIDEN_FLOOR = 1.15
#: The coordinate that measures each bias term (the time offset: every coordinate).
MEASURED_BY: dict[str, str] = {"range_offset": "range", "range_gain": "range",
                               "azimuth_bias": "azimuth", "azimuth_sin": "azimuth",
                               "azimuth_cos": "azimuth", "elevation_bias": "elevation"}
#: The sites.toml key of each judged coordinate's stated sigma.
SIGMA_KEYS: dict[str, str] = {"range": "sigma_range_m", "azimuth": "sigma_azimuth_mrad",
                              "elevation": "sigma_elevation_mrad"}


def chi2_limit(dof: float, p: float = P, floor: float = FLOOR) -> float:
    """Largest passing ``chi2 / dof`` at ``dof`` degrees of freedom (module docstring)."""
    dof = max(float(dof), 1.0)
    return max(floor, float(special.chdtri(dof, p)) / dof)


@dataclass(frozen=True)
class CoordinateFit:
    """One radar's residuals in one coordinate: chi-square, degrees of freedom, limit."""

    coordinate: str
    chi2: float
    dof: float
    limit: float

    @property
    def ratio(self) -> float:
        """``chi2 / dof``."""
        return self.chi2 / self.dof

    @property
    def failed(self) -> bool:
        """``chi2 / dof`` above the limit."""
        return self.ratio > self.limit


@dataclass
class RadarFit:
    """The verdict on one radar: its coordinates and a range gain beyond reason."""

    radar_id: str
    coordinates: list[CoordinateFit] = field(default_factory=list)
    range_gain: float | None = None
    negative_ranges: int = 0

    @property
    def gain_implausible(self) -> bool:
        """``|range_gain|`` above :data:`MAX_RANGE_GAIN`."""
        return self.range_gain is not None and abs(self.range_gain) > MAX_RANGE_GAIN

    @property
    def failed(self) -> bool:
        """A coordinate failed, the range gain is implausible, or ranges corrected negative."""
        return (self.gain_implausible or self.negative_ranges > 0
                or any(c.failed for c in self.coordinates))

    @property
    def worst(self) -> float:
        """The largest ``chi2 / dof`` over the coordinates (0 without any)."""
        return max((c.ratio for c in self.coordinates), default=0.0)

    def describe(self) -> str:
        """``NORD: azimuth chi2/dof 893,425, range 80.4`` (what failed), plain words."""
        parts = [f"{c.coordinate} chi2/dof {_fmt(c.ratio)}"
                 for c in sorted(self.coordinates, key=lambda c: -c.ratio) if c.failed]
        if self.negative_ranges:
            parts.append(f"{self.negative_ranges} plots corrected to a negative range")
        if self.gain_implausible:
            parts.append(f"range gain {self.range_gain:.4g} (beyond ±{MAX_RANGE_GAIN:g})")
        return f"{self.radar_id}: " + ", ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: per coordinate chi2, dof, chi2/dof, limit and whether it failed."""
        return {
            "failed": self.failed,
            "coordinates": {c.coordinate: {"chi2": c.chi2, "dof": c.dof, "chi2_per_dof": c.ratio,
                                           "limit": c.limit, "failed": c.failed}
                            for c in self.coordinates},
            "range_gain": self.range_gain,
            "range_gain_implausible": self.gain_implausible,
            "negative_ranges": self.negative_ranges,
        }


def _fmt(value: float) -> str:
    return f"{value:,.0f}" if abs(value) >= 100 else f"{value:.3g}"


@dataclass(frozen=True)
class WindowJudgement:
    """The verdict on one time window's own fit (``calibrate --window``)."""

    t_start_s: float
    t_end_s: float
    verdict: FitVerdict

    @property
    def span(self) -> str:
        """``0-3600 s``."""
        return f"{self.t_start_s:.0f}-{self.t_end_s:.0f} s"


@dataclass
class FitVerdict:
    """The fit verdict of a calibration (module docstring).

    Attributes
    ----------
    reference : {"adsb", "paths", "cross", "none"}
        What the residuals were measured against: ADS-B, the aircraft's paths (the
        trajectory formulation without ADS-B residuals), the other radars' plots
        (pairwise), or nothing (over windows: ``"adsb"`` when any window's were against
        ADS-B, else ``"paths"`` when any were on the paths).
    radars : dict of str to RadarFit
        Over windows: each radar's fit in its worst window (a failing one when it
        failed anywhere).
    p, floor : float
        The limit's probability and floor.
    windows : list of WindowJudgement, optional
        Over windows: every window's own verdict, in time order.
    associated : dict of str to str
        The radars whose plots were associated by gating (contract v3), each with a
        phrase on how well they fit their aircraft: a failed one's message names wrong
        associations as a cause.
    """

    reference: str
    radars: dict[str, RadarFit]
    p: float = P
    floor: float = FLOOR
    windows: list[WindowJudgement] | None = None
    associated: dict[str, str] = field(default_factory=dict)

    @property
    def failed(self) -> list[str]:
        """The radars that failed, worst first."""
        bad = [r for r in self.radars.values() if r.failed]
        return [r.radar_id for r in sorted(bad, key=_badness)]

    @property
    def passed(self) -> bool:
        """No radar failed."""
        return not self.failed

    def failed_windows(self, radar_id: str) -> list[WindowJudgement]:
        """Over windows: those in which ``radar_id`` failed, in time order."""
        return [w for w in self.windows or ()
                if radar_id in w.verdict.radars and w.verdict.radars[radar_id].failed]

    def message(self) -> str:
        """One line: the radars that failed, what, and the likely causes."""
        if self.passed:
            return "the residuals are within their sigmas"
        text = ("the residuals are far beyond their sigmas (limit chi2/dof "
                f"{self.floor:g}, or the 1e-6 quantile for few residuals): "
                + "; ".join(self._describe(rid) for rid in self.failed)
                + ". The biases would be meaningless: check the data's units and frames "
                "(azimuth in degrees, range and heights in metres, ADS-B latitude and "
                "longitude, the sites' positions and heights; a range gain of -0.999 is "
                "ranges in km) and the sigmas in sites.toml")
        if self.reference == "paths":
            text += (" (without ADS-B each radar's plots are judged on the aircraft's paths, "
                     "which every radar's plots shape, so one radar's misfit bends the paths "
                     "and shows in the others' too; the worst is named first), and each "
                     "radar's clock: a time-stamping bias of a second or more moves its "
                     "plots along track, and without ADS-B it is not estimated (calibrate "
                     "with ADS-B to estimate time_offset_s)")
        if self.reference == "cross":
            text += (" (without ADS-B each residual compares two radars, so one radar's "
                     "misfit shows in its partners' too; the worst is named first), and "
                     "each radar's clock: a time-stamping bias of a second or more moves "
                     "its plots along track, and without ADS-B it is not estimated "
                     "(calibrate with ADS-B to estimate time_offset_s)")
        for rid in self.failed:
            if rid in self.associated:
                text += (f". {rid}'s plots carry no address and were associated by gating "
                         f"({self.associated[rid]}): wrong associations (another aircraft, "
                         "false plots) show as such a misfit")
        return text

    def _describe(self, radar_id: str) -> str:
        """One failed radar in words; over windows, with the windows it failed in."""
        fit = self.radars[radar_id]
        if self.windows is None:
            return fit.describe()
        bad = self.failed_windows(radar_id)
        judged = sum(1 for w in self.windows if radar_id in w.verdict.radars)
        spans = ", ".join(w.span for w in bad[:MESSAGE_WINDOWS])
        if len(bad) > MESSAGE_WINDOWS:
            spans += f" and {len(bad) - MESSAGE_WINDOWS} more"
        worst = fit.describe().partition(": ")[2]
        return (f"{radar_id}: in {len(bad)} of {judged} windows ({spans}); "
                f"worst: {worst}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``Calibration.info["fit_verdict"]``).

        Over windows, each radar's entry is its worst window's, with that window
        (``window``: ``[t_start_s, t_end_s]``) and ``failed_windows``; ``windows``
        lists every window's span, reference and failed radars.
        """
        out = {
            "reference": self.reference,
            "passed": self.passed,
            "failed": self.failed,
            "p": self.p,
            "floor": self.floor,
            "max_range_gain": MAX_RANGE_GAIN,
            "radars": {rid: r.to_dict() for rid, r in self.radars.items()},
        }
        if self.associated:
            out["associated"] = dict(self.associated)
        if self.windows is not None:
            for rid, entry in out["radars"].items():
                worst = _worst_window(self.windows, rid)
                entry["window"] = None if worst is None else [worst.t_start_s, worst.t_end_s]
                entry["failed_windows"] = [[w.t_start_s, w.t_end_s]
                                           for w in self.failed_windows(rid)]
            out["windows"] = [{"t_start_s": w.t_start_s, "t_end_s": w.t_end_s,
                               "reference": w.verdict.reference, "failed": w.verdict.failed}
                              for w in self.windows]
        return out


def _badness(fit: RadarFit) -> tuple[bool, bool, float]:
    """Sort key, worst first: failed, then an implausible gain, then the largest chi2/dof."""
    return (not fit.failed, not fit.gain_implausible, -fit.worst)


def _worst_window(windows: list[WindowJudgement], radar_id: str) -> WindowJudgement | None:
    judged = [w for w in windows if radar_id in w.verdict.radars]
    return min(judged, key=lambda w: _badness(w.verdict.radars[radar_id]), default=None)


class ModelMisfitError(EstimationError):
    """A calibration whose residuals are far beyond their sigmas (exit status 3).

    ``calibration`` holds the result (its ``info["fit_verdict"]`` the verdict), for
    inspection; ``verdict`` the :class:`FitVerdict`.
    """

    def __init__(self, verdict: FitVerdict, calibration: Calibration) -> None:
        super().__init__(verdict.message())
        self.verdict = verdict
        self.calibration = calibration


def _n_terms(cal: Calibration, radar_id: str) -> int:
    return sum(1 for rid, _ in cal.labels if rid == radar_id)


def negative_ranges(dataset: Dataset, cal: Calibration) -> dict[str, int]:
    """Per radar of ``cal``: its plots whose corrected range ``(r - offset) / (1 + gain)``
    is not positive (an estimate no geometry allows; the residuals cannot be formed)."""
    out = {}
    for rid in cal.radar_ids:
        if rid not in dataset.sites:
            continue
        r = dataset.plots_of(rid)["range_m"].to_numpy(dtype=float)
        out[rid] = count_non_positive_ranges(r, cal.bias(rid))
    return out


def radar_fit(radar_id: str, sums: Mapping[str, tuple[float, float]], n_terms: int,
              range_gain: float | None, negative: int = 0, *, p: float = P,
              floor: float = FLOOR) -> RadarFit:
    """One radar's :class:`RadarFit` from its ``{coordinate: (sum e^2/v, count)}``.

    ``dof`` = count less ``n_terms`` (the radar's estimated terms; at least 1);
    coordinates other than :data:`JUDGED`, empty or non-finite are left out.
    """
    fit = RadarFit(radar_id, range_gain=range_gain, negative_ranges=negative)
    for coordinate, (chi2, n) in sums.items():
        if coordinate not in JUDGED or n <= 0 or not math.isfinite(chi2):
            continue
        dof = max(n - n_terms, 1)
        fit.coordinates.append(CoordinateFit(coordinate, float(chi2), float(dof),
                                             chi2_limit(dof, p, floor)))
    return fit


def verdict_from_sums(cal: Calibration, reference: str,
                      sums: Mapping[str, Mapping[str, tuple[float, float]]], *,
                      p: float = P, floor: float = FLOOR,
                      negative: Mapping[str, int] | None = None) -> FitVerdict:
    """The verdict from each radar's ``{coordinate: (sum e^2/v, count)}``.

    ``dof`` = count less the radar's estimated terms (at least 1).  ``negative``:
    per radar, the plots corrected to a non-positive range (:func:`negative_ranges`).
    """
    radars = {rid: radar_fit(rid, sums.get(rid) or {}, _n_terms(cal, rid),
                             cal.value(rid, "range_gain"), (negative or {}).get(rid, 0),
                             p=p, floor=floor)
              for rid in cal.radar_ids}
    return FitVerdict(reference, radars, p, floor)


def window_verdict(fit: WindowFit, *, p: float = P, floor: float = FLOOR) -> FitVerdict:
    """The verdict on one window's own fit, from the numbers its summary carries."""
    radars = {rid: radar_fit(rid, fit.sums.get(rid) or {}, n_terms,
                             fit.range_gain.get(rid), fit.negative_ranges.get(rid, 0),
                             p=p, floor=floor)
              for rid, n_terms in fit.n_terms.items()}
    return FitVerdict(fit.reference, radars, p, floor)


def windows_verdict(windows: Iterable[tuple[float, float, WindowFit]], *, p: float = P,
                    floor: float = FLOOR) -> FitVerdict:
    """The verdict of a calibration over time windows (module docstring).

    Parameters
    ----------
    windows : iterable of (t_start_s, t_end_s, WindowFit)
        Each window's span [s] and fit numbers
        (:attr:`graphcal.solvers.windows.WindowSummary.fit`).
    p, floor : float
        The limit's probability and floor (:func:`chi2_limit`).

    Returns
    -------
    FitVerdict
        With ``windows``; each radar's entry is its fit in its worst window, so
        that it fails exactly when it failed in some window.  ``reference`` is
        ``"adsb"`` when any window's residuals were against ADS-B, else ``"paths"`` when
        any were on the paths, else ``"none"``.
    """
    judged = sorted((WindowJudgement(float(t0), float(t1), window_verdict(fit, p=p, floor=floor))
                     for t0, t1, fit in windows), key=lambda w: (w.t_start_s, w.t_end_s))
    radars: dict[str, RadarFit] = {}
    for rid in dict.fromkeys(rid for w in judged for rid in w.verdict.radars):
        worst = _worst_window(judged, rid)
        if worst is not None:
            radars[rid] = worst.verdict.radars[rid]
    reference = _pooled_reference(w.verdict.reference for w in judged)
    return FitVerdict(reference, radars, p, floor, judged)


def fit_verdict(
    data: Dataset | Problem,
    cal: Calibration,
    *,
    checks: ModelChecks | None = None,
    use_adsb: bool = True,
    adsb_max_gap_s: float | None = None,
    p: float = P,
    floor: float = FLOOR,
) -> FitVerdict:
    """Judge a calibration's residuals (module docstring).

    Parameters
    ----------
    data : Dataset or Problem
        The data the calibration used (sigmas filled in), or its calibration problem.
    cal : Calibration
        The estimate.
    checks : ModelChecks, optional
        The model checks of ``cal`` on ``dataset``, when they ran: their residuals'
        sums are reused.  Without them the residuals are computed here.
    use_adsb, adsb_max_gap_s
        As for :func:`graphcal.analysis.model_checks.model_checks`.
    p, floor : float
        The limit's probability and floor (:func:`chi2_limit`).

    Returns
    -------
    FitVerdict
        A radar whose estimate corrects plots to a negative range fails on that
        alone, and its residuals are not formed (nor are pairs with it).
    """
    problem = as_problem(data)
    dataset = problem.dataset
    negative = negative_ranges(dataset, cal)
    on_paths = sums_on_paths(cal.info)  # the trajectory formulation's, without ADS-B
    if checks is not None and checks.reference == "adsb":
        on_paths = None
    if on_paths is not None:
        return verdict_from_sums(cal, "paths", on_paths, p=p, floor=floor, negative=negative)
    if checks is not None:
        sums = {rid: {c: (r.chi2_per_dof[c] * r.n_residuals[c], r.n_residuals[c])
                      for c in r.chi2_per_dof if c in r.n_residuals}
                for rid, r in checks.radars.items()}
        return verdict_from_sums(cal, checks.reference, sums, p=p, floor=floor,
                                 negative=negative)
    biases = {rid: cal.bias(rid) for rid in cal.radar_ids
              if rid in dataset.sites and not negative.get(rid)}
    reference, residuals, _ = calibrated_residuals(problem, biases, use_adsb=use_adsb,
                                                   adsb_max_gap_s=adsb_max_gap_s)
    sums = {rid: normalised_sums(res) for rid, res in residuals.items()}
    return verdict_from_sums(cal, reference, sums, p=p, floor=floor, negative=negative)


def widen_limit(dof: float, p: float = WIDEN_P, floor: float = WIDEN_FLOOR) -> float:
    """Largest ``chi2 / dof`` that leaves the sigmas as they are (module docstring)."""
    return chi2_limit(dof, p, floor)


@dataclass(frozen=True)
class SigmaInflation:
    """One radar's sigmas widened: the coordinates whose ``chi2 / dof`` exceeds
    :func:`widen_limit`, with their ratio and limit, and what the residuals were
    measured against."""

    radar_id: str
    coordinates: dict[str, tuple[float, float]]  # coordinate -> (chi2/dof, limit)
    reference: str

    @property
    def factor(self) -> float:
        """The largest variance factor: the largest ``chi2 / dof`` that exceeded."""
        return max(ratio for ratio, _ in self.coordinates.values())

    def parameter_factor(self, name: str) -> float:
        """The variance factor of the bias term ``name`` (internal name): its coordinate's
        ``chi2 / dof`` when that exceeded, else 1; the radar's largest for the time offset
        (and any term no single coordinate measures)."""
        coordinate = MEASURED_BY.get(name)
        if coordinate is None:
            return self.factor
        return self.coordinates.get(coordinate, (1.0, 0.0))[0]

    def to_dict(self, names: Iterable[str] = ()) -> dict[str, Any]:
        """JSON-ready (``info["sigma_inflation"][radar]``): the largest factor, the
        coordinates that exceeded, and per contract key of ``names`` (the radar's
        estimated terms) its variance factor."""
        return {"factor": self.factor, "reference": self.reference,
                "coordinates": {c: {"chi2_per_dof": r, "limit": lim}
                                for c, (r, lim) in self.coordinates.items()},
                "parameters": {CONTRACT_KEYS[n][0]: self.parameter_factor(n) for n in names}}

    def message(self) -> str:
        """The warning: the radar, the coordinates and ratios, the likely causes."""
        worst = sorted(self.coordinates.items(), key=lambda item: -item[1][0])
        found = ", ".join(f"{c} chi2/dof {r:.2f} > {lim:.2f}" for c, (r, lim) in worst)
        keys = " or ".join(SIGMA_KEYS[c] for c, _ in worst if c in SIGMA_KEYS)
        if self.reference == "adsb":
            cause = (f"the sigmas in sites.toml ({keys}) or the ADS-B sigma_m/NACp are "
                     "smaller than the data's scatter (residuals against ADS-B carry both "
                     "errors: ADS-B sigmas too small widen every radar, most those with the "
                     "smallest sigmas)")
        elif self.reference == "paths":
            cause = (f"the sigmas in sites.toml ({keys}) are smaller than the data's scatter "
                     "(without ADS-B the residuals are against the aircraft's paths, fitted "
                     "to every radar's plots)")
        else:
            cause = (f"the sigmas in sites.toml ({keys}) are smaller than the data's scatter "
                     "(without ADS-B each residual carries the partner radar's error too, "
                     "so a partner's misstated sigma widens this radar as well, and this "
                     "radar's own shows diluted)")
        return (f"radar {self.radar_id}: its residuals exceed their sigmas beyond chance "
                f"({found}): sigmas widened by up to {math.sqrt(self.factor):.2f} times "
                f"(variance factor {self.factor:.2f}, info.sigma_inflation); {cause}, or an "
                "effect the model leaves out (see the model checks)")


def sigma_inflation(verdict: FitVerdict, *, p: float = WIDEN_P,
                    floor: float = WIDEN_FLOOR) -> dict[str, SigmaInflation]:
    """The radars whose sigmas are too small by their residuals (module docstring).

    Returns
    -------
    dict of str to SigmaInflation
        Per radar with a judged coordinate above :func:`widen_limit`, in the
        verdict's order; radars within their sigmas are absent.
    """
    out = {}
    for rid, fit in verdict.radars.items():
        beyond = {}
        for c in fit.coordinates:
            limit = widen_limit(c.dof, p, floor)
            if math.isfinite(c.ratio) and c.ratio > limit:
                beyond[c.coordinate] = (c.ratio, limit)
        if beyond:
            out[rid] = SigmaInflation(rid, beyond, verdict.reference)
    return out


def _pooled_reference(references: Iterable[str]) -> str:
    """The windows' reference: ``"adsb"`` when any window's residuals were against ADS-B,
    else ``"paths"`` when any were on the paths, else ``"none"``."""
    found = set(references)
    return next((r for r in ("adsb", "paths") if r in found), "none")


def pooled_verdict(fits: Iterable[WindowFit]) -> FitVerdict:
    """One verdict from every window's residuals pooled, radar by radar: per coordinate
    the windows' chi-squares and counts summed, less every window's estimated terms
    (``calibrate --window``: a noise stated too small is too small in every window, and
    the pooled ``dof`` are the batch's; :func:`sigma_inflation` reads it)."""
    sums: dict[str, dict[str, tuple[float, float]]] = {}
    terms: dict[str, int] = {}
    fits = list(fits)
    reference = _pooled_reference(fit.reference for fit in fits)
    for fit in fits:
        for rid, by in fit.sums.items():
            pooled = sums.setdefault(rid, {})
            for coordinate, (chi2, n) in by.items():
                if n > 0 and math.isfinite(chi2):
                    c0, n0 = pooled.get(coordinate, (0.0, 0.0))
                    pooled[coordinate] = (c0 + float(chi2), n0 + float(n))
            terms[rid] = terms.get(rid, 0) + int(fit.n_terms.get(rid, 0))
    radars = {rid: radar_fit(rid, by, terms.get(rid, 0), None) for rid, by in sums.items()}
    return FitVerdict(reference, radars)


#: Time-stamping bias [s] assumed typical when a radar names no sensor model.
DEFAULT_TYPICAL_TIME_OFFSET_S = 0.1
#: Radars sharing a time offset beyond this multiple of their typical one: the ADS-B clock.
#: Independent radar clocks do not agree on an offset 3 times their typical size; ADS-B
#: stamped at reception instead of applicability runs 0.3-1 s late on every radar alike.
SHARED_TIME_OFFSET_MULTIPLE = 3.0


def shared_time_offset_warning(cal: Calibration, sites: Mapping[str, Any]) -> str | None:
    """A warning when every radar's estimated time offset is the same, and far too large.

    Radars' clocks are independent: when two or more radars all come out with one
    time offset, beyond :data:`SHARED_TIME_OFFSET_MULTIPLE` times their sensor models'
    typical time-stamping bias (``typical_bias.time_offset_s``, else
    :data:`DEFAULT_TYPICAL_TIME_OFFSET_S`) and each beyond 5 of its sigmas, while
    they agree with each other, what is off is the common reference: the ADS-B
    time base.  The radars' offsets then put their plots on the ADS-B's clock.

    Returns
    -------
    str or None
        The warning, naming the offset, its multiple of the typical value and the
        ADS-B clock; ``None`` when the offsets do not look shared.
    """
    from graphcal.data.sensor_models import load_sensor_model

    offsets: dict[str, tuple[float, float]] = {}
    typical = 0.0
    for rid in cal.radar_ids:
        value, sigma = cal.value(rid, "time_offset_s"), cal.sigma(rid, "time_offset_s")
        if value is None or sigma is None or not (math.isfinite(value)
                                                  and math.isfinite(sigma)):
            continue
        offsets[rid] = (value, sigma)
        site = sites.get(rid)
        radar_typical = DEFAULT_TYPICAL_TIME_OFFSET_S
        model = getattr(site, "model", None)
        if model:
            try:
                radar_typical = load_sensor_model(model).typical_bias.get(
                    "time_offset_s", radar_typical)
            except (OSError, ValueError):
                pass
        typical = max(typical, radar_typical)
    if len(offsets) < 2 or typical <= 0:
        return None
    values = [v for v, _ in offsets.values()]
    sigmas = [s for _, s in offsets.values()]
    mean = sum(values) / len(values)
    limit = SHARED_TIME_OFFSET_MULTIPLE * typical
    if not all(abs(v) > limit and abs(v) > 5.0 * s and (v > 0) == (mean > 0)
               for v, s in offsets.values()):
        return None
    if max(values) - min(values) > 0.2 * abs(mean) + 5.0 * max(sigmas):
        return None
    detail = ", ".join(f"{rid} {v:+.3f} ± {s:.3f}" for rid, (v, s) in offsets.items())
    return (f"every radar has the same time offset, {mean:+.2f} s ({detail} s), "
            f"{abs(mean) / typical:,.0f} times the sensor models' typical "
            f"{typical:g} s: the ADS-B time_s is likely on another clock, "
            f"{-mean:+.2f} s off the radars' (a time base, leap-second or GPS-UTC offset; "
            "the time of reception instead of the time of applicability, which runs 0.3-1 s "
            "late?), not every radar's; the time offsets put the plots on "
            "the ADS-B's clock. Check the ADS-B times before using them")


__all__ = ["DEFAULT_TYPICAL_TIME_OFFSET_S", "FLOOR", "JUDGED", "MAX_RANGE_GAIN",
           "MEASURED_BY", "MESSAGE_WINDOWS", "P", "SHARED_TIME_OFFSET_MULTIPLE", "SIGMA_KEYS",
           "WIDEN_FLOOR",
           "WIDEN_P", "CoordinateFit", "FitVerdict", "ModelMisfitError", "RadarFit",
           "SigmaInflation", "WindowJudgement", "chi2_limit", "fit_verdict",
           "negative_ranges", "pooled_verdict", "radar_fit", "shared_time_offset_warning",
           "sigma_inflation", "verdict_from_sums", "widen_limit", "window_verdict",
           "windows_verdict"]

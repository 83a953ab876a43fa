"""Model checks: structure left in each radar's residuals after a calibration.

graphcal's model is idealised: straight rays, geometric heights, constant
biases, an azimuth bias that does not depend on the azimuth.  When the data
carry what it leaves out (refraction, pressure altitudes, antenna eccentricity,
a bias that drifts or steps), the estimate absorbs what it can and leaves the
rest in the residuals as *structure*: residual means that vary with range,
elevation, azimuth or time.  :func:`model_checks` looks for it, per radar:

1. **Residuals** (:mod:`graphcal.analysis.check_residuals`): each corrected plot
   against ADS-B, or without ADS-B against the other radars' plots of the same
   aircraft, in the radar's polar frame, with their expected variances.
2. **Tests** (:mod:`graphcal.analysis.binned_test`): per measured coordinate
   (range, azimuth, elevation for a 3-D radar, the reported altitude of a 2-D
   one), the model's own terms (a constant, the range gain's ``r``, with ADS-B
   the time offset's rate, without it the partners' bias terms) are fitted out
   once; the residuals are then binned against
   range, elevation (3-D) or height (2-D), azimuth and time in
   :data:`~graphcal.analysis.binned_test.N_BINS` bins of equal counts, and the
   bin means tested with a chi-square against their scatter, one aircraft's
   :data:`~graphcal.analysis.check_residuals.SEGMENT_S`-second track segment
   counting as the independent unit.
3. **Beyond chance**: a test fires when its p-value is below
   ``family_false_alarm / n_tests`` (Bonferroni over the radar's tests, default
   :data:`FAMILY_FALSE_ALARM`), so that on data the model fits under 1 % of
   radars show a warning (``benchmarks/model_checks_study.py`` measures it).
4. **Words** (:mod:`graphcal.analysis.check_patterns`): a radar with a test that
   fired gets one warning line containing "unmodelled", naming the pattern
   (e.g. "growing towards the horizon", "sinusoidal in azimuth", "stepping near
   t = 900 s"), its size and its likely cause.

Without ADS-B a radar's residuals also carry its partners' errors.  A radar
whose structure goes below the threshold when the pairs with one partner are
left out is not warned about: when that partner's own checks fired, the
partner's warning mentions it (:attr:`RadarChecks.seen_via`); when they did not,
a note says that the structure could be attributed to neither.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graphcal.analysis.binned_test import BinnedMeans, TermsFit, binned_test, fit_terms, plot_bins
from graphcal.analysis.check_patterns import describe
from graphcal.analysis.check_residuals import (
    SEGMENT_S,
    RadarResiduals,
    adsb_radar_residuals,
    cross_radar_residuals,
)
from graphcal.data.align import DEFAULT_ADSB_MAX_GAP_S
from graphcal.data.bias import RadarBias
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset, Site
from graphcal.model.problem import Problem, as_problem

#: Family-wise false-alarm rate per radar (Bonferroni over its tests).  Nominally 0.2 %:
#: the tests are somewhat liberal without ADS-B (``benchmarks/model_checks_study.py``),
#: and at this rate under 1 % of radars are warned about on data the model fits.
FAMILY_FALSE_ALARM = 0.002

#: Residual coordinates: unit and factor from SI.
COORDINATES: dict[str, tuple[str, float]] = {
    "range": ("m", 1.0),
    "azimuth": ("mrad", 1e3),
    "elevation": ("mrad", 1e3),
    "altitude": ("m", 1.0),
}
#: Variables the residuals are binned against: unit and factor from SI.
VARIABLES: dict[str, tuple[str, float]] = {
    "range": ("km", 1e-3),
    "elevation": ("deg", 180.0 / math.pi),
    "height": ("km", 1e-3),
    "azimuth": ("deg", 180.0 / math.pi),
    "time": ("s", 1.0),
}


# --------------------------------------------------------------------------- results
@dataclass
class CheckTest:
    """One radar's residuals of one coordinate binned against one variable, and the verdict.

    Attributes
    ----------
    coordinate : str
        ``range``, ``azimuth``, ``elevation`` or ``altitude`` (unit in :data:`COORDINATES`).
    variable : str
        ``range``, ``elevation``, ``height``, ``azimuth`` or ``time`` (unit in
        :data:`VARIABLES`).
    bins : BinnedMeans
        Bin centres in the variable's unit, means and sigmas in the coordinate's.
    fired : bool
        p-value below the radar's threshold.
    pattern : str
        Plain-words shape of the structure (e.g. "sinusoidal in azimuth").
    magnitude : str
        Its size and where (e.g. "+2.1 mrad at 1 deg").
    cause : str
        Its likely cause.
    """

    coordinate: str
    variable: str
    bins: BinnedMeans
    fired: bool = False
    pattern: str = ""
    magnitude: str = ""
    cause: str = ""

    @property
    def unit(self) -> str:
        """Unit of the residual."""
        return COORDINATES[self.coordinate][0]

    @property
    def variable_unit(self) -> str:
        """Unit of the variable."""
        return VARIABLES[self.variable][0]

    @property
    def name(self) -> str:
        """``"<coordinate> vs <variable>"``."""
        return f"{self.coordinate} vs {self.variable}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: figures with units in the key names."""
        u, vu = self.unit, self.variable_unit
        b = self.bins
        return {
            "residual": f"{self.coordinate}_{u}",
            "against": f"{self.variable}_{vu}",
            "n_bins": len(b),
            "chi2": b.chi2,
            "dof": b.dof,
            "p_value": b.p_value,
            "log10_p": b.log10_p,
            "rho": b.rho,
            "fired": self.fired,
            "pattern": self.pattern,
            "magnitude": self.magnitude,
            "cause": self.cause,
            "bins": {
                f"centre_{vu}": b.centre.tolist(),
                f"lower_{vu}": b.lower.tolist(),
                f"upper_{vu}": b.upper.tolist(),
                "n_plots": b.n_plots.tolist(),
                "n_segments": b.n_segments.tolist(),
                f"mean_{u}": b.mean.tolist(),
                f"sigma_{u}": b.sigma.tolist(),
                f"absorbed_{u}": b.absorbed.tolist(),
            },
        }


@dataclass
class RadarChecks:
    """The model checks of one radar.

    Attributes
    ----------
    radar_id : str
    reference : {"adsb", "cross"}
    n_plots : int
        Residuals checked (plots against ADS-B, or pair differences).
    n_outliers : int
        Left out as gross outliers.
    threshold_p : float
        A test fires below this p-value (``family_false_alarm / len(tests)``).
    chi2_per_dof : dict of str to float
        Per coordinate, the mean squared normalised residual (near 1 when the
        sites.toml sigmas are right, above 1 when they are too small).
    tests : list of CheckTest
    n_residuals : dict of str to int
        Per coordinate, the finite residuals ``chi2_per_dof`` averages over (the
        fit verdict's degrees of freedom, :mod:`graphcal.analysis.fit_verdict`).
    partners : tuple of str
        ``cross``: the radars its residuals are measured against.
    explained_by : str or None
        ``cross``: the partner without whose pairs no test fires any more.
    seen_via : list of str
        ``cross``: radars whose structure this radar's explains.
    """

    radar_id: str
    reference: str
    n_plots: int
    n_outliers: int
    threshold_p: float
    chi2_per_dof: dict[str, float]
    tests: list[CheckTest] = field(default_factory=list)
    partners: tuple[str, ...] = ()
    explained_by: str | None = None
    seen_via: list[str] = field(default_factory=list)
    n_residuals: dict[str, int] = field(default_factory=dict)

    @property
    def fired(self) -> list[CheckTest]:
        """The tests that fired, the one the warning describes first.

        Most significant first; a reported-altitude structure is described
        against height (a pressure altitude differs from the geometric height by
        a function of the height, which shows less directly against azimuth and
        time).
        """
        fired = sorted((t for t in self.tests if t.fired), key=lambda t: t.bins.log10_p)
        if fired and fired[0].coordinate == "altitude":
            fired.sort(key=lambda t: (t.name != "altitude vs height", t.bins.log10_p))
        return fired

    def warning(self) -> str | None:
        """One plain line naming the pattern and its likely cause, or None."""
        fired = self.fired
        if not fired:
            return None
        t = fired[0]
        text = (f"{self.radar_id}: unmodelled {t.coordinate} residual {t.pattern} "
                f"({t.magnitude}, chi2 = {t.bins.chi2:.0f} over {len(t.bins)} bins): {t.cause}?")
        if len(fired) > 1:
            text += " (also beyond chance: " + ", ".join(o.name for o in fired[1:]) + ")"
        if self.reference == "cross":
            text += " (No ADS-B: measured against the other radars, whose errors it can carry.)"
        if self.seen_via:
            text += (" It also shows in the residuals of " + ", ".join(self.seen_via)
                     + " against it.")
        return text

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "reference": self.reference,
            "n_plots": self.n_plots,
            "n_outliers": self.n_outliers,
            "n_tests": len(self.tests),
            "threshold_p": self.threshold_p,
            "fired": [t.name for t in self.fired],
            "chi2_per_dof": {f"{k}_{COORDINATES[k][0]}": v for k, v in self.chi2_per_dof.items()},
            "n_residuals": {f"{k}_{COORDINATES[k][0]}": v for k, v in self.n_residuals.items()},
            "partners": list(self.partners),
            "explained_by": self.explained_by,
            "seen_via": list(self.seen_via),
            "tests": [t.to_dict() for t in self.tests],
        }


@dataclass
class ModelChecks:
    """The model checks of a calibration (see the module doc).

    Attributes
    ----------
    reference : {"adsb", "cross", "none"}
    radars : dict of str to RadarChecks
    family_false_alarm : float
        Per-radar family-wise false-alarm rate.
    segment_s : float
        Track segment length [s] of the independent units.
    seconds : float
        Time the checks took [s].
    notes : list of str
        Radars not checked and why.
    """

    reference: str
    radars: dict[str, RadarChecks]
    family_false_alarm: float = FAMILY_FALSE_ALARM
    segment_s: float = SEGMENT_S
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)

    def warnings(self) -> list[str]:
        """One line per radar with a structure beyond chance that is its own.

        Without ADS-B, a radar whose structure is explained by one partner
        (:attr:`RadarChecks.explained_by`) gets no line of its own: the partner's
        line mentions it when the partner's checks fired too, and a note records
        it when they did not (it cannot then be attributed to either radar).
        """
        return [w for r in self.radars.values()
                if r.explained_by is None and (w := r.warning()) is not None]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the form kept in ``Calibration.info["model_checks"]``)."""
        return {
            "reference": self.reference,
            "family_false_alarm": self.family_false_alarm,
            "segment_s": self.segment_s,
            "seconds": self.seconds,
            "notes": list(self.notes),
            "warnings": self.warnings(),
            "radars": {rid: r.to_dict() for rid, r in self.radars.items()},
        }


# --------------------------------------------------------------------------- the checks
def _test(res: RadarResiduals, coordinate: str, variable: str, terms: TermsFit | None = None,
          shared_bins: dict[str, tuple[NDArray[np.bool_], NDArray[np.int64] | None]] | None
          = None) -> BinnedMeans | None:
    """One binned test of ``res`` in display units (the terms fitted when not given).

    ``shared_bins``: the plots' bins by variable, with the rows they were made for,
    kept across the coordinates of one radar (the coordinates' residuals are
    usually finite on the same plots, and then share the bins).
    """
    scale = COORDINATES[coordinate][1]
    e = res.residuals[coordinate] * scale
    v = res.variances[coordinate] * scale**2
    if terms is None:
        terms = fit_terms(e, v, res.regressors[coordinate])
    x = res.variables[variable] * VARIABLES[variable][1]
    if shared_bins is None:
        return binned_test(x, e, v, res.segment, terms)
    kept = shared_bins.get(variable)
    if kept is None or not np.array_equal(kept[0], terms.rows):
        kept = shared_bins[variable] = (terms.rows, plot_bins(x, terms.rows))
    if kept[1] is None:
        return None
    return binned_test(x, e, v, res.segment, terms, bins=kept[1])


def radar_checks(res: RadarResiduals, site: Site,
                 family_false_alarm: float = FAMILY_FALSE_ALARM,
                 pressure: bool = False) -> RadarChecks:
    """Every binned test of one radar's residuals, with the Bonferroni verdict.

    ``pressure``: the plots' altitudes are declared pressure altitudes (for the words).
    """
    tests: list[CheckTest] = []
    chi2_per_dof: dict[str, float] = {}
    n_residuals: dict[str, int] = {}
    for coordinate, (chi2, n) in normalised_sums(res).items():
        chi2_per_dof[coordinate], n_residuals[coordinate] = chi2 / n, n
    shared_bins: dict[str, tuple[NDArray[np.bool_], NDArray[np.int64] | None]] = {}
    for coordinate, e in res.residuals.items():
        v = res.variances[coordinate]
        scale = COORDINATES[coordinate][1]
        terms = fit_terms(e * scale, v * scale**2, res.regressors[coordinate])
        for variable in res.variables:
            if coordinate == "altitude" and variable == "range":
                continue  # a pressure altitude is a function of height: see altitude vs height
            bins = _test(res, coordinate, variable, terms, shared_bins)
            if bins is not None:
                tests.append(CheckTest(coordinate, variable, bins))
    threshold = family_false_alarm / max(len(tests), 1)
    for t in tests:
        t.fired = bool(t.bins.p_value < threshold)
        words = describe(t.coordinate, t.variable, t.bins, t.unit, t.variable_unit,
                         is_3d=site.is_3d, reference=res.reference,
                         gain_modelled="range_gain" in site.estimate, pressure=pressure)
        t.pattern, t.magnitude, t.cause = words.pattern, words.magnitude, words.cause
    return RadarChecks(res.radar_id, res.reference, len(res), res.n_outliers, threshold,
                       chi2_per_dof, tests, res.partners, n_residuals=n_residuals)


def normalised_sums(res: RadarResiduals) -> dict[str, tuple[float, int]]:
    """Per coordinate with a finite residual: ``(sum e^2 / v, count)`` over the finite ones."""
    out: dict[str, tuple[float, int]] = {}
    for coordinate, e in res.residuals.items():
        v = res.variances[coordinate]
        finite = np.isfinite(e) & np.isfinite(v) & (v > 0)
        if finite.any():
            out[coordinate] = (float(np.sum(e[finite] ** 2 / v[finite])), int(finite.sum()))
    return out


def _explaining_partner(res: RadarResiduals, checks: RadarChecks) -> str | None:
    """The partner without whose pairs none of the radar's fired tests stays beyond chance.

    When several would do, the one whose removal leaves the least structure
    (largest smallest p-value).
    """
    if res.partner is None or len(res.partners) < 2 or not checks.fired:
        return None
    best, best_p = None, -1.0
    for j, partner in enumerate(res.partners):
        rest = res.subset(res.partner != j)
        p_values = []
        for t in checks.fired:
            bins = _test(rest, t.coordinate, t.variable)
            p_values.append(1.0 if bins is None else bins.p_value)
        if min(p_values) >= checks.threshold_p and min(p_values) > best_p:
            best, best_p = partner, min(p_values)
    return best


def calibrated_residuals(
    data: Dataset | Problem,
    calibration: Calibration | Mapping[str, RadarBias],
    *,
    use_adsb: bool = True,
    adsb_max_gap_s: float | None = None,
) -> tuple[str, dict[str, RadarResiduals], list[str]]:
    """Each calibrated radar's corrected residuals: ``(reference, residuals, notes)``.

    Against ADS-B when ``use_adsb`` and the dataset has it (and some plot aligns with
    it), else against the other radars' plots
    (:mod:`graphcal.analysis.check_residuals`); ``reference`` is ``"none"`` when no
    radar has any.  ``notes``: the radars without residuals.
    Parameters as for :func:`model_checks`.
    """
    problem = as_problem(data)
    dataset = problem.dataset
    height_model = None
    if isinstance(calibration, Calibration):
        biases = {rid: calibration.bias(rid) for rid in calibration.radar_ids
                  if rid in dataset.sites}
        if calibration.atmosphere is not None:
            height_model = calibration.atmosphere.model
    else:
        biases = {rid: b for rid, b in calibration.items() if rid in dataset.sites}
    notes: list[str] = []
    residuals: dict[str, RadarResiduals] = {}
    reference = "none"
    if use_adsb and dataset.adsb is not None and len(dataset.adsb) > 0:
        reference = "adsb"
        gap = DEFAULT_ADSB_MAX_GAP_S if adsb_max_gap_s is None else adsb_max_gap_s
        for rid, bias in biases.items():
            res = adsb_radar_residuals(problem, rid, bias, gap, height_model)
            if res is None:
                notes.append(f"{rid}: no plot aligned with ADS-B; not checked")
            else:
                residuals[rid] = res
    if reference != "adsb" or not residuals:
        if reference == "adsb":  # ADS-B on another time base or place: nothing aligned
            notes = ["no plot aligned with ADS-B: checked against the other radars"]
        reference = "cross"
        residuals = cross_radar_residuals(problem, biases, height_model)
        notes += [f"{rid}: no cross-radar pair; not checked" for rid in biases
                  if rid not in residuals]
    if not residuals:
        reference = "none"
    return reference, residuals, notes


def model_checks(
    data: Dataset | Problem,
    calibration: Calibration | Mapping[str, RadarBias],
    *,
    use_adsb: bool = True,
    adsb_max_gap_s: float | None = None,
    family_false_alarm: float = FAMILY_FALSE_ALARM,
) -> ModelChecks:
    """Check each calibrated radar's corrected residuals for structure (module doc).

    Parameters
    ----------
    data : Dataset or Problem
        The data the calibration used (sigmas filled in), or its calibration problem
        (:func:`graphcal.model.problem.build_problem`), whose alignments with ADS-B
        the checks then reuse.
    calibration : Calibration or mapping of radar id to RadarBias
        The estimate: its radars are checked, corrected with every bias
        (fixed ones and the time offset included).
    use_adsb : bool
        Use ADS-B as the reference when the dataset has it; else cross-radar pairs.
    adsb_max_gap_s : float, optional
        Longest gap between ADS-B reports bridged by interpolation [s] (default
        :data:`graphcal.data.align.DEFAULT_ADSB_MAX_GAP_S`); cross-radar pairs
        bridge 2.5 scans (:func:`graphcal.data.align.pair_max_gap_s`).
    family_false_alarm : float
        Per-radar family-wise false-alarm rate (Bonferroni over its tests).

    Returns
    -------
    ModelChecks
        ``reference`` "none" and no radars when there is nothing to compare with.
    """
    start = time.perf_counter()
    problem = as_problem(data)
    dataset = problem.dataset
    reference, residuals, notes = calibrated_residuals(
        problem, calibration, use_adsb=use_adsb, adsb_max_gap_s=adsb_max_gap_s)
    radars = {rid: radar_checks(res, dataset.sites[rid], family_false_alarm,
                                dataset.pressure_altitudes)
              for rid, res in residuals.items()}
    if reference == "cross":
        for rid, res in residuals.items():
            radars[rid].explained_by = _explaining_partner(res, radars[rid])
        for rid, checks in radars.items():
            if checks.explained_by is None:
                continue
            owner = radars.get(checks.explained_by)
            if owner is not None and owner.fired and owner.explained_by is None:
                owner.seen_via.append(rid)
            else:
                notes.append(
                    f"{rid}: {', '.join(t.name for t in checks.fired)} beyond chance only "
                    f"against {checks.explained_by}'s plots, and {checks.explained_by} shows "
                    "no structure of its own: attributed to neither")
    return ModelChecks(reference, radars, family_false_alarm, SEGMENT_S,
                       time.perf_counter() - start, notes)


__all__ = ["COORDINATES", "FAMILY_FALSE_ALARM", "VARIABLES", "CheckTest", "ModelChecks",
           "RadarChecks", "calibrated_residuals", "model_checks", "normalised_sums", "radar_checks"]

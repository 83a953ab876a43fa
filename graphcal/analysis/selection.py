"""Choosing the observations that determine the biases.

Paper 001 shows that more data is not always more observability: a calibration
on a crowded observation set can be worse than one on a well-spread part of it.
This module selects *units* - single observations, time segments of one
aircraft's track (every radar's observations of it in the window), or whole
aircraft tracks - from the observations of :mod:`graphcal.analysis.observability`, so
that any estimator can be run on the informative part of the data:

``greedy``
    Paper 001 eq. 12: visiting the units in the order they arrive, unit ``k``
    is removed when ``Deg`` of ``A - A_k`` is larger than ``Deg`` of ``A``
    (a downdate of ``A`` by the unit's rank-``m`` contribution, never a
    recomputation).  The paper's rule decides the size itself; with a budget,
    backward elimination (remove the units whose removal leaves the largest
    ``Deg``, ranked to first order) continues until the budget is met.
``e-optimal``
    ``max lambda_min(sum_i w_i A_i)`` over ``0 <= w_i <= 1``,
    ``sum_i c_i w_i = N`` (``c_i`` the unit's observation count, ``N`` the
    budget), a semidefinite programme solved with Clarabel (an interior-point
    solver; SCS held to a tight tolerance if Clarabel fails) through cvxpy, then
    rounded: units by decreasing weight while they fit the budget.
``d-optimal``
    The same with ``max log det(sum_i w_i A_i)``.
``random``
    Units in random order while they fit the budget (the baseline).

Every criterion works on the Jacobi-scaled information (scaled by the full
set's diagonal), so that parameters in metres, fractions and radians weigh
alike.  The convex problems take at most :data:`MAX_CONVEX_UNITS` units;
beyond that, consecutive observations of one aircraft in one group are merged
into chunks first (and a note says so).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.analysis.observability import (
    Label,
    ObservabilityReport,
    ObservationBlocks,
    report_from_information,
)
from graphcal.data.dataset import Dataset
from graphcal.model.information import degree, greedy_prune_information, jacobi_scale

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int], None]

#: Selection methods.
SELECTION_METHODS: tuple[str, ...] = ("greedy", "e-optimal", "d-optimal", "random")
#: Selection units.
SELECTION_UNITS: tuple[str, ...] = ("observation", "segment", "track")
#: Largest number of units handed to the convex solver.
MAX_CONVEX_UNITS = 2000
#: Default segment length [s].
DEFAULT_SEGMENT_S = 60.0


@dataclass
class SelectionUnits:
    """Candidate units with their information.

    Attributes
    ----------
    labels : list of (radar_id, parameter name)
    information : ndarray (u, p, p)
        Each unit's information ``A_i = sum J^T J`` [SI].
    cost : ndarray (u,) of int
        Observations in each unit.
    start_s : ndarray (u,)
        Time of each unit's first observation [s] (the arrival order).
    target_id : ndarray (u,) of str
        The aircraft of each unit.
    unit : str
        ``"observation"``, ``"segment"`` or ``"track"``.
    unit_of : list of ndarray of int
        Per observation block, the unit of each observation.
    blocks : ObservationBlocks
        The observations the units group.
    notes : list of str
        What was done to the candidates (e.g. merged for the solver).
    """

    labels: list[Label]
    information: FloatArray
    cost: NDArray[np.int64]
    start_s: FloatArray
    target_id: NDArray[np.object_]
    unit: str
    unit_of: list[NDArray[np.int64]]
    blocks: ObservationBlocks
    notes: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.cost)

    @property
    def scale(self) -> FloatArray:
        """Jacobi scaling ``1/sqrt(diag A)`` of the full set."""
        return jacobi_scale(self.information.sum(axis=0))

    def scaled_information(self) -> FloatArray:
        """``S A_i S`` per unit, ``S`` the full set's Jacobi scaling."""
        s = self.scale
        return self.information * np.outer(s, s)


def selection_units(
    blocks: ObservationBlocks,
    unit: str = "observation",
    segment_s: float = DEFAULT_SEGMENT_S,
    max_units: int | None = None,
) -> SelectionUnits:
    """Group the observations of ``blocks`` into selection units.

    Parameters
    ----------
    blocks : ObservationBlocks
        From :func:`graphcal.analysis.observability.observation_blocks`.
    unit : {"observation", "segment", "track"}
        One observation; every observation of one aircraft within a window of
        ``segment_s`` (all radars); or every observation of one aircraft.
    segment_s : float
        Segment length [s] (``unit="segment"``).
    max_units : int, optional
        When there are more units, consecutive observations of one aircraft in
        one block (``"observation"``) or consecutive segments of one aircraft
        (``"segment"``) are merged until there are at most this many.

    Returns
    -------
    SelectionUnits
    """
    if unit not in SELECTION_UNITS:
        raise ValueError(f"unknown selection unit '{unit}'; use one of: "
                         f"{', '.join(SELECTION_UNITS)}")
    if not segment_s > 0:
        raise ValueError(f"segment length must be positive, not {segment_s} s")
    if len(blocks) == 0:
        raise ValueError("no observations to select from: no plot is matched to ADS-B "
                         "or seen by two radars")
    frame = pd.DataFrame({
        "block": np.concatenate([np.full(len(b), i) for i, b in enumerate(blocks.blocks)]),
        "obs": np.concatenate([np.arange(len(b)) for b in blocks.blocks]),
        "time_s": np.concatenate([b.time_s for b in blocks.blocks]),
        "target": np.concatenate([b.target_id for b in blocks.blocks]).astype(str),
    })
    t0 = float(frame["time_s"].min())
    notes = []
    if unit == "observation":
        frame = frame.sort_values(["block", "target", "time_s"], kind="stable")
        group = np.arange(len(frame))
        if max_units is not None and len(frame) > max_units:
            run = (frame["block"].astype(str) + "\0" + frame["target"]).to_numpy()
            starts = np.r_[True, run[1:] != run[:-1]]
            run_id = np.cumsum(starts) - 1
            lengths = np.bincount(run_id)
            if len(lengths) > max_units:
                raise ValueError(
                    f"{len(lengths)} aircraft-and-radar groups are too many for {max_units} "
                    "units of single observations; select segments or tracks instead"
                )
            size = int(np.ceil(len(frame) / max_units))
            while np.sum(np.ceil(lengths / size)) > max_units:
                size = int(np.ceil(size * 1.25))
            position = np.arange(len(frame)) - np.flatnonzero(starts)[run_id]
            group = pd.factorize(pd.Series(run_id * 10**9 + position // size))[0]
            notes.append(f"{len(frame)} observations merged into {group.max() + 1} chunks of "
                         f"up to {size} consecutive observations of one aircraft")
        frame["key"] = group
    elif unit == "segment":
        window = np.floor((frame["time_s"].to_numpy() - t0) / segment_s).astype(np.int64)
        def count(w: NDArray[np.int64]) -> int:
            return len(pd.unique(pd.Series(frame["target"] + "\0" + w.astype(str))))

        n_segments = count(window)
        if max_units is not None and n_segments > max_units:
            factor = int(np.ceil(n_segments / max_units))
            while count(window // factor) > max_units:
                if factor > window.max():
                    raise ValueError(f"more than {max_units} aircraft: too many for the "
                                     "convex solver even with one unit per aircraft")
                factor = int(np.ceil(factor * 1.25))
            window //= factor
            notes.append(f"{n_segments} segments of {segment_s:g} s merged into segments of "
                         f"{factor * segment_s:g} s")
        frame["key"] = frame["target"] + "\0" + window.astype(str)
    else:
        frame["key"] = frame["target"]
    codes, _ = pd.factorize(frame["key"], sort=False)
    frame["unit"] = codes
    n_units = int(codes.max()) + 1
    p = len(blocks.labels)
    information = np.zeros((n_units, p, p))
    unit_of = []
    for i, block in enumerate(blocks.blocks):
        rows = frame[frame["block"] == i].sort_values("obs")
        owner = rows["unit"].to_numpy(np.int64)
        unit_of.append(owner)
        per_obs = np.einsum("nip,niq->npq", block.jacobian, block.jacobian)
        local = np.zeros((n_units, len(block.columns), len(block.columns)))
        np.add.at(local, owner, per_obs)
        information[np.ix_(np.arange(n_units), block.columns, block.columns)] += local
    by_unit = frame.groupby("unit", sort=True)
    return SelectionUnits(
        labels=list(blocks.labels),
        information=information,
        cost=by_unit.size().to_numpy(np.int64),
        start_s=by_unit["time_s"].min().to_numpy(float),
        target_id=by_unit["target"].first().to_numpy(object),
        unit=unit,
        unit_of=unit_of,
        blocks=blocks,
        notes=notes,
    )


# --------------------------------------------------------------------------- criteria
def _eliminate_to_budget(
    scaled: FloatArray, cost: NDArray[np.int64], keep: NDArray[np.bool_], budget: int
) -> NDArray[np.bool_]:
    """Backward elimination: drop the kept units whose removal leaves the largest Deg.

    The units are ranked by the first-order change of Deg on removal
    (``lambda_min - v_min^T A_i v_min`` over ``lambda_max - v_max^T A_i v_max``, ``v``
    the extreme eigenvectors of the kept information), and removed in batches of
    about a tenth of the excess, after which ``A`` and its eigenvectors are updated.
    """
    keep = keep.copy()
    a = scaled[keep].sum(axis=0)
    while cost[keep].sum() > budget:
        kept = np.flatnonzero(keep)
        excess = cost[keep].sum() - budget
        w, v = np.linalg.eigh(a)
        low = w[0] - np.einsum("p,upq,q->u", v[:, 0], scaled[kept], v[:, 0])
        high = w[-1] - np.einsum("p,upq,q->u", v[:, -1], scaled[kept], v[:, -1])
        after = np.where(high > 0, low / np.where(high > 0, high, 1.0), -np.inf)
        order = kept[np.argsort(-after, kind="stable")]
        batch = max(1, int(np.ceil(excess / np.mean(cost[kept]) / 10)))
        for i in order[:batch]:
            if cost[keep].sum() <= budget:
                break
            keep[i] = False
            a = a - scaled[i]
    return keep


def relaxed_weights(
    scaled: FloatArray,
    cost: NDArray[np.int64],
    budget: int,
    criterion: str,
    solver: str = "CLARABEL",
) -> tuple[FloatArray, str]:
    """Solve the relaxed E- or D-optimal design.

    ``max lambda_min(sum w_i A_i)`` (``criterion="e"``) or
    ``max log det(sum w_i A_i)`` (``"d"``) subject to ``0 <= w_i <= 1`` and
    ``sum c_i w_i = budget``.

    Parameters
    ----------
    scaled : ndarray (u, p, p)
        Scaled unit information.
    cost : ndarray (u,)
        Observations per unit.
    budget : int
        Observations to select.
    criterion : {"e", "d"}
    solver : str
        A cvxpy conic solver that handles semidefinite (and, for D, exponential)
        cones: ``"CLARABEL"`` (default; SCS with a tight tolerance is tried when it
        fails) or ``"SCS"``.  The weak directions' eigenvalues are often 1e-5 of the
        largest, below a first-order solver's default accuracy.

    Returns
    -------
    weights : ndarray (u,)
    status : str
        The solver's status.
    """
    import cvxpy as cp

    u, p = scaled.shape[:2]
    # Normalise so the budget's uniform share has a unit diagonal (solver conditioning).
    scaled = scaled * (cost.sum() / budget)
    if criterion == "d":
        # log det changes by a constant under a change of basis: solve it in the full
        # set's whitened basis (where the full information is the identity), which is
        # well conditioned however weak the weakest direction.
        ev, vec = np.linalg.eigh(scaled.sum(axis=0))
        good = ev > 1e-12 * ev[-1]
        basis = vec[:, good] / np.sqrt(ev[good])
        scaled = np.einsum("pi,upq,qj->uij", basis, scaled, basis) * (budget / cost.sum())
        p = int(good.sum())
    upper = np.triu_indices(p)
    coefficients = scaled[:, upper[0], upper[1]].T
    w = cp.Variable(u)
    a = cp.Variable((p, p), symmetric=True)
    constraints = [a[upper] == coefficients @ w, w >= 0, w <= 1,
                   cost.astype(float) @ w == float(budget)]
    if criterion == "e":
        t = cp.Variable()
        problem = cp.Problem(cp.Maximize(t), constraints + [a - t * np.eye(p) >> 0])
    elif criterion == "d":
        problem = cp.Problem(cp.Maximize(cp.log_det(a)), constraints)
    else:
        raise ValueError(f"criterion must be 'e' or 'd', not '{criterion}'")
    attempts = [(solver, {})]
    if solver != "SCS":  # first-order fallback, held to a tight tolerance
        attempts.append(("SCS", {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iters": 100_000}))
    failures = []
    for name, settings in attempts:
        try:
            with warnings.catch_warnings():  # an inaccurate solution shows in the status
                warnings.simplefilter("ignore", UserWarning)
                problem.solve(solver=name, **settings)
        except cp.error.SolverError as exc:
            failures.append(f"{name}: {exc}")
            continue
        if w.value is not None and problem.status in ("optimal", "optimal_inaccurate"):
            break
        failures.append(f"{name}: {problem.status}")
    else:
        raise RuntimeError("the selection problem could not be solved (" + "; ".join(failures)
                           + ")")
    return np.clip(np.asarray(w.value, dtype=float), 0.0, 1.0), str(problem.status)


def round_weights(
    weights: FloatArray,
    cost: NDArray[np.int64],
    budget: int,
    scaled: FloatArray | None = None,
    criterion: str | None = None,
) -> NDArray[np.bool_]:
    """Round relaxed weights to a subset within the budget.

    Units with a weight of (nearly) 1 are taken first.  With ``scaled`` and
    ``criterion`` (``"e"`` or ``"d"``), the fractional units are then added one
    at a time, each time the one that improves the criterion most (ties to the
    larger weight): the relaxation often spreads equal weights over units that
    are worth only as a mix.  The rest of the budget is filled by decreasing
    weight.
    """
    keep = np.zeros(len(weights), dtype=bool)
    used = 0

    def take(i: int) -> None:
        nonlocal used
        keep[i] = True
        used += int(cost[i])

    order = np.argsort(-weights, kind="stable")
    for i in order[weights[order] >= 1.0 - 1e-3]:
        if used + cost[i] <= budget:
            take(i)
    if scaled is not None and criterion is not None:
        a = scaled[keep].sum(axis=0)
        floor = 1e-12 * max(float(np.trace(scaled.sum(axis=0))), 1e-300)
        candidates = [i for i in order if not keep[i] and 1e-3 < weights[i]]
        while candidates:
            fits = [i for i in candidates if used + cost[i] <= budget]
            if not fits:
                break
            ev = np.linalg.eigvalsh(a[None] + scaled[fits])
            gain = ev[:, 0] if criterion == "e" else np.sum(np.log(np.clip(ev, floor, None)),
                                                            axis=1)
            best = fits[int(np.argmax(gain))]  # first of equals: the largest weight
            take(best)
            a = a + scaled[best]
            candidates = [i for i in fits if i != best]
    for i in order:
        if not keep[i] and used + cost[i] <= budget:
            take(i)
    return keep


# --------------------------------------------------------------------------- selections
@dataclass
class Selection:
    """The units a selection method kept.

    Attributes
    ----------
    method : str
    units : SelectionUnits
    keep : ndarray of bool (u,)
    weights : ndarray (u,) or None
        The relaxed weights of the convex methods.
    budget : int or None
        Observations asked for.
    seconds : float
        Time the selection took [s].
    status : str
        Solver status (convex methods), else ``"done"``.
    """

    method: str
    units: SelectionUnits
    keep: NDArray[np.bool_]
    weights: FloatArray | None = None
    budget: int | None = None
    seconds: float = 0.0
    status: str = "done"

    @property
    def n_units(self) -> int:
        return int(self.keep.sum())

    @property
    def n_observations(self) -> int:
        return int(self.units.cost[self.keep].sum())

    def information(self) -> FloatArray:
        """``A`` of the kept units [SI]."""
        return self.units.information[self.keep].sum(axis=0)

    def report(self) -> ObservabilityReport:
        """Observability figures of the kept units (Deg with their own Jacobi scaling)."""
        return report_from_information(self.units.labels, self.information(),
                                       self.n_observations)

    def scaled_figures(self) -> dict[str, float]:
        """Deg, lambda_min and log det under the full set's Jacobi scaling."""
        s = self.units.scale
        w = np.linalg.eigvalsh(self.information() * np.outer(s, s))
        return {
            "degree_full_scaling": float(max(w[0], 0.0) / w[-1]) if w[-1] > 0 else 0.0,
            "lambda_min": float(max(w[0], 0.0)),
            "log_det": float(np.sum(np.log(w))) if w[0] > 0 else -np.inf,
        }

    def observation_masks(self) -> list[NDArray[np.bool_]]:
        """Per observation block, the observations kept."""
        return [self.keep[owner] for owner in self.units.unit_of]

    def plot_rows(self) -> NDArray[np.int64]:
        """Row labels in ``dataset.plots`` of the plots behind the kept observations."""
        rows = [b.plot_rows[m].ravel()
                for b, m in zip(self.units.blocks.blocks, self.observation_masks(), strict=True)]
        return np.unique(np.concatenate(rows)) if rows else np.zeros(0, np.int64)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        report = self.report()
        out = {
            "method": self.method,
            "unit": self.units.unit,
            "budget": self.budget,
            "units_kept": self.n_units,
            "units_total": len(self.units),
            "observations_kept": self.n_observations,
            "observations_total": int(self.units.cost.sum()),
            "degree": report.degree,
            "seconds": self.seconds,
            "status": self.status,
        }
        out.update({k: (v if np.isfinite(v) else None)
                    for k, v in self.scaled_figures().items()})
        if self.units.notes:
            out["notes"] = list(self.units.notes)
        return out


def select(
    units: SelectionUnits,
    method: str,
    budget: int | None = None,
    *,
    rng: np.random.Generator | None = None,
    solver: str = "CLARABEL",
    progress: Progress | None = None,
) -> Selection:
    """Select units by ``method`` (module docstring).

    Parameters
    ----------
    units : SelectionUnits
    method : {"greedy", "e-optimal", "d-optimal", "random"}
    budget : int, optional
        Observations to keep (required except for ``greedy``).  Units are
        whole, so the selection may keep a few fewer.
    rng : numpy.random.Generator, optional
        Required for ``random``.
    solver : str
        cvxpy solver of the convex methods.
    progress : callable, optional
        ``progress(done, total)`` of the greedy pass.

    Returns
    -------
    Selection
    """
    if method not in SELECTION_METHODS:
        raise ValueError(f"unknown selection method '{method}'; use one of: "
                         f"{', '.join(SELECTION_METHODS)}")
    total = int(units.cost.sum())
    if budget is not None:
        if budget < 1:
            raise ValueError(f"the budget must be at least 1 observation, not {budget}")
        if budget > total:
            budget = total
        smallest = int(units.cost.min())
        if budget < smallest:
            raise ValueError(f"the budget of {budget} observations is smaller than the "
                             f"smallest {units.unit} ({smallest} observations)")
    elif method != "greedy":
        raise ValueError(f"selection '{method}' needs a budget (the number of observations "
                         "to keep)")
    start = time.perf_counter()
    scaled = units.scaled_information()
    weights = None
    status = "done"
    if method == "greedy":
        order = np.argsort(units.start_s, kind="stable")
        kept_in_order, _ = greedy_prune_information(scaled[order], progress)
        keep = np.zeros(len(units), dtype=bool)
        keep[order] = kept_in_order
        if budget is not None and units.cost[keep].sum() > budget:
            keep = _eliminate_to_budget(scaled, units.cost, keep, budget)
    elif method == "random":
        if rng is None:
            raise ValueError("random selection needs a numpy.random.Generator")
        keep = round_weights(rng.random(len(units)), units.cost, budget)
    else:
        if len(units) > MAX_CONVEX_UNITS:
            raise ValueError(
                f"{len(units)} units are too many for the convex solver (at most "
                f"{MAX_CONVEX_UNITS}); build the units with max_units={MAX_CONVEX_UNITS}"
            )
        if budget >= total:
            weights, keep = np.ones(len(units)), np.ones(len(units), dtype=bool)
        else:
            weights, status = relaxed_weights(scaled, units.cost, budget, method[0], solver)
            keep = round_weights(weights, units.cost, budget, scaled, method[0])
    return Selection(method, units, keep, weights, budget, time.perf_counter() - start, status)


def select_dataset(dataset: Dataset, selection: Selection) -> Dataset:
    """A copy of ``dataset`` with only the plots behind the kept observations.

    The ADS-B table and the sites are kept whole (an estimator uses ADS-B only
    through the plots it matches).  The estimator forms its own observations
    from the kept plots again, so it sees the selected observations (and
    occasionally a few more, where kept plots of two radars pair up anew).
    """
    rows = selection.plot_rows()
    plots = dataset.plots.loc[dataset.plots.index.isin(rows)]
    return Dataset(dataset.sites, plots, dataset.adsb, dataset.path, dataset.cleaning,
                   dataset.plot_altitude, dataset.epoch_utc)


def select_for_calibration(
    dataset: Dataset,
    estimator: str,
    method: str,
    budget: int | None,
    *,
    unit: str = "segment",
    segment_s: float = DEFAULT_SEGMENT_S,
    use_adsb: bool = True,
    rng: np.random.Generator | None = None,
    progress: Progress | None = None,
) -> tuple[Dataset, Selection]:
    """Select the informative part of ``dataset`` for the estimator ``estimator``.

    The observations are those of ``wls`` for the ``wls`` methods and of
    ``graph`` otherwise (:func:`graphcal.analysis.observability.observation_blocks`);
    missing site sigmas are estimated for the selection only.

    Returns
    -------
    subset : Dataset
        :func:`select_dataset` of the selection (the user's sigmas untouched).
    selection : Selection
    """
    from graphcal.analysis.observability import observation_blocks
    from graphcal.noise import fill_missing_sigmas

    filled, _ = fill_missing_sigmas(dataset)
    blocks = observation_blocks(filled, "wls" if estimator.startswith("wls") else "graph",
                                use_adsb=use_adsb, linearise="neighbours")
    convex = method in ("e-optimal", "d-optimal")
    units = selection_units(blocks, unit, segment_s, MAX_CONVEX_UNITS if convex else None)
    selection = select(units, method, budget, rng=rng, progress=progress)
    return select_dataset(dataset, selection), selection


def compare_selections(
    units: SelectionUnits,
    budget: int,
    rng: np.random.Generator,
    *,
    n_random: int = 20,
    methods: tuple[str, ...] = ("greedy", "e-optimal", "d-optimal"),
    solver: str = "CLARABEL",
    progress: Callable[[str, int, int], None] | None = None,
) -> pd.DataFrame:
    """Every method at one budget, with ``n_random`` random subsets as the baseline.

    ``progress(stage, done, total)``, when given, is called before each method and
    each random draw (``total``: the methods plus the draws).

    Returns
    -------
    pandas.DataFrame
        One row per method (random: the median draw, with the min and max Deg),
        columns ``method, units, observations, degree, degree_full_scaling,
        lambda_min, log_det, seconds`` plus ``degree_min``/``degree_max`` for
        random and ``mean_sigma_ratio`` (the mean over parameters of the subset's
        joint sigma divided by the full set's).
    """
    full = report_from_information(units.labels, units.information.sum(axis=0))
    rows = []

    def row(sel: Selection, name: str) -> dict[str, Any]:
        rep = sel.report()
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = float(np.mean(rep.sigma_joint / full.sigma_joint))
        return {"method": name, "units": sel.n_units, "observations": sel.n_observations,
                "degree": rep.degree, **sel.scaled_figures(), "mean_sigma_ratio": ratio,
                "seconds": sel.seconds}

    total = len(methods) + n_random

    def step(stage: str, done: int) -> None:
        if progress is not None:
            progress(stage, done, total)

    for i, method in enumerate(methods):
        step(method, i)
        rows.append(row(select(units, method, budget, solver=solver), method))
    draws = []
    for i in range(n_random):
        step("random", len(methods) + i)
        draws.append(row(select(units, "random", budget, rng=rng), "random"))
    step("done", total)
    if draws:
        degrees = np.array([d["degree"] for d in draws])
        median = draws[int(np.argsort(degrees)[len(degrees) // 2])]
        median.update(method=f"random (median of {n_random})", degree_min=float(degrees.min()),
                      degree_max=float(degrees.max()))
        rows.append(median)
    all_rows = {"method": "all observations", "units": len(units),
                "observations": int(units.cost.sum()), "degree": full.degree,
                "mean_sigma_ratio": 1.0, "seconds": 0.0}
    rows.append(all_rows)
    return pd.DataFrame(rows)


__all__ = [
    "SELECTION_METHODS", "SELECTION_UNITS", "MAX_CONVEX_UNITS", "SelectionUnits",
    "Selection", "selection_units", "select", "select_dataset", "compare_selections",
    "greedy_prune_information", "relaxed_weights", "select_for_calibration", "round_weights",
    "degree",
]

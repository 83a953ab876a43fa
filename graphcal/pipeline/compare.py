"""Monte-Carlo comparison of estimators on a scenario: :func:`compare`.

Each run simulates the scenario once, with its own seed spawned from ``seed``
(:class:`numpy.random.SeedSequence`), and runs every method on that same
dataset.  Over the runs, per method, radar and parameter (contract units):

=================  =============================================================
``truth``          the scenario's true bias
``mean``, ``std``  mean and standard deviation (``ddof=1``) of the estimates
``rmse``           root mean square of ``estimate - truth``
``mean_sigma``     mean of the estimator's own 1-sigma
``consistency``    ``mean_sigma / std``: 1 for an honest covariance, < 1 overconfident
``crlb_sigma``     square root of the mean (over runs) Cramér-Rao bound variance
``rmse_over_crlb`` ``rmse / crlb_sigma``: 1 for an efficient unbiased estimator
``n``              runs that gave a finite value for this parameter
``failures``       runs in which the method failed (an error, a non-finite estimate)
``status``         ``ok``, ``failed in K of N runs``, or for a method that never
                   gave an estimate ``failed: <first error>`` (its one row has no
                   radar or parameter and NaN figures: failed methods stay in the
                   table); with :data:`MIN_RUNS_JUDGED` runs or more, a row whose
                   ``consistency`` is outside :data:`CONSISTENCY_RANGE` (0.7-1.4),
                   and beyond the chance spread of a std from its runs (3 x
                   ``1/sqrt(2 (n - 1))``: the range is 0.61-1.64 at 12 runs),
                   says ``sigma too small`` or ``sigma too large`` instead of
                   ``ok``, and one whose mean is off the truth by more than
                   :data:`BIAS_STANDARD_ERRORS` standard errors (and half a std)
                   says ``biased``
=================  =============================================================

The sigmas of ``ls``, ``fl``, ``fl-ls``, ``wls`` and ``wls-pruned`` are the papers'
formal ones (from the stated noise, scaled by no fit statistic): the table shows
whether they are honest on the scenario.

The results do not depend on ``jobs``: every run's randomness comes from its
own seed and the runs are put back in order.  Only the run times vary.

Example::

    result = compare("scenarios/paper001_path1.toml", ["wls", "wls-pruned"], 100, jobs=2)
    print(result.table)
    result.write("paper001.md")
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from graphcal.core.atomic import atomic_write_table, atomic_write_text
from graphcal.core.errors import EstimationError
from graphcal.data.bias import (
    CONTRACT_KEYS,
    ECCENTRICITY_NAMES,
    PARAMETER_NAMES,
    to_contract_units,
)

#: Contract key -> internal parameter name, in table order.
_KEY_ORDER: dict[str, str] = {
    CONTRACT_KEYS[name][0]: name
    for name in (*PARAMETER_NAMES, "time_offset", *ECCENTRICITY_NAMES)
}
#: ``consistency`` (mean reported sigma / actual std) outside this range: the sigmas are
#: not honest.  A std from 24 runs is itself uncertain by about 15 %.
CONSISTENCY_RANGE: tuple[float, float] = (0.7, 1.4)
#: ... and beyond this many of the chance spreads of a std from the runs.
CONSISTENCY_CHANCE_SIGMAS = 3.0
#: Fewest runs behind a row for its sigmas and mean to be judged.
MIN_RUNS_JUDGED = 10
#: A mean this many standard errors (std / sqrt(n)) off the truth, and more than
#: :data:`BIAS_STD_FRACTION` of a std, is a bias.
BIAS_STANDARD_ERRORS = 4.0
BIAS_STD_FRACTION = 0.5

#: Columns of :attr:`ComparisonResult.table`, in order.
TABLE_COLUMNS: tuple[str, ...] = (
    "method", "radar", "parameter", "truth", "n", "mean", "std", "rmse", "mean_sigma",
    "consistency", "crlb_sigma", "rmse_over_crlb", "failures", "status",
)

#: Columns of :attr:`ComparisonResult.estimates` (one row per run, method, radar, parameter).
ESTIMATE_COLUMNS: tuple[str, ...] = ("run", "method", "radar", "parameter", "value", "sigma")

Progress = Callable[[int, int], None]

#: What counts as a method failing on a run (recorded, not raised): the data do not
#: allow its estimate (:class:`~graphcal.core.errors.EstimationError`), or its numerics
#: break down on them (GTSAM's indeterminate system is a ``RuntimeError``).
FAILURES: tuple[type[BaseException], ...] = (
    EstimationError, RuntimeError, ValueError, ArithmeticError, np.linalg.LinAlgError,
)


@dataclass
class ComparisonResult:
    """What :func:`compare` returns.

    Attributes
    ----------
    scenario : str
        Scenario name.
    methods : list of str
        Methods compared, in the order given.
    runs : int
        Monte-Carlo runs.
    seed : int
        Root seed of the runs.
    table : pandas.DataFrame
        Tidy summary, one row per method x radar x parameter (:data:`TABLE_COLUMNS`).
    timing : pandas.DataFrame
        One row per method: ``method, runs, mean_s, median_s, total_s`` (wall-clock
        seconds of the estimator alone; the simulation is not counted).
    failures : pandas.DataFrame
        One row per method: ``method, runs, failures, first_error``.
    estimates : pandas.DataFrame
        Every estimate (:data:`ESTIMATE_COLUMNS`), to recompute anything from.
    extra : pandas.DataFrame
        Per run, method and radar: the residual statistics the calibration reports
        (``range_before_m, range_after_m, azimuth_before_mrad, azimuth_after_mrad``:
        mean absolute residual against the reference before and after correction),
        NaN where an estimator gives none.
    simulation_s : float
        Mean wall-clock seconds to simulate one run.
    """

    scenario: str
    methods: list[str]
    runs: int
    seed: int
    table: pd.DataFrame
    timing: pd.DataFrame
    failures: pd.DataFrame
    estimates: pd.DataFrame
    extra: pd.DataFrame = field(default_factory=pd.DataFrame)
    simulation_s: float = float("nan")

    # ----------------------------------------------------------------- writers
    def to_markdown(self) -> str:
        """A readable markdown report: the summary per method, then run times and failures."""
        lines = [
            f"# Monte-Carlo comparison: {self.scenario}",
            "",
            f"{self.runs} runs, seed {self.seed}, methods: {', '.join(self.methods)}.",
            "Units: m, fraction (gain), mrad, s. std with ddof=1; consistency = mean "
            "reported sigma / std; RMSE/sqrt(CRLB) needs graphcal.analysis.crlb.",
            "",
            "| method | radar | parameter | truth | mean | std | RMSE | mean σ̂ | σ̂/std "
            "| RMSE/√CRLB | n | failures | status |",
            "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
        ]
        for row in self.table.itertuples(index=False):
            lines.append(
                f"| {row.method} | {row.radar} | {row.parameter} | {_fmt(row.truth)} "
                f"| {_fmt(row.mean)} | {_fmt(row.std)} | {_fmt(row.rmse)} "
                f"| {_fmt(row.mean_sigma)} | {_fmt(row.consistency, 3)} "
                f"| {_fmt(row.rmse_over_crlb, 3)} | {row.n} | {row.failures} "
                f"| {row.status.replace('|', '/')} |"
            )
        lines += [
            "",
            "| method | runs | failures | mean time (s) | median time (s) |",
            "|---|---:|---:|---:|---:|",
        ]
        merged = self.timing.merge(self.failures[["method", "failures"]], on="method")
        for row in merged.itertuples(index=False):
            lines.append(
                f"| {row.method} | {row.runs} | {row.failures} | {row.mean_s:.4g} "
                f"| {row.median_s:.4g} |"
            )
        lines += ["", f"Simulation: {self.simulation_s:.4g} s per run."]
        errors = [r for r in self.failures.itertuples(index=False) if r.first_error]
        if errors:
            lines += [""] + [f"- `{r.method}` first error: {r.first_error}" for r in errors]
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict[str, Any]:
        """Plain-dict form for JSON (NaN becomes ``null``)."""
        return {
            "scenario": self.scenario,
            "methods": list(self.methods),
            "runs": self.runs,
            "seed": self.seed,
            "simulation_s": _json_number(self.simulation_s),
            "table": _records(self.table),
            "timing": _records(self.timing),
            "failures": _records(self.failures),
        }

    def write(self, path: str | Path) -> None:
        """Write the summary by suffix: ``.md`` (report), ``.csv`` (table) or ``.json``.

        The write is atomic (temporary file, then ``os.replace``).

        Raises
        ------
        ValueError
            For another suffix.
        """
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".md":
            atomic_write_text(path, self.to_markdown())
        elif suffix == ".csv":
            atomic_write_table(self.table, path)
        elif suffix == ".json":
            atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")
        else:
            raise ValueError(f"{path}: the output format comes from the suffix: .md, .csv or .json")


def _fmt(value: float, digits: int = 4) -> str:
    if value is None or not np.isfinite(value):
        return "–"
    return f"{value:.{digits}g}"


def _json_number(value: Any) -> Any:
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _records(frame: pd.DataFrame) -> list[dict[str, Any]]:
    return [
        {k: _json_number(v) for k, v in row.items()} for row in frame.to_dict(orient="records")
    ]


# ----------------------------------------------------------------------- one run
def _crlb_variances(dataset: Any, options: Mapping[str, Any]) -> dict[tuple[str, str], float]:
    """CRLB variance per (radar, contract key) of one dataset; empty if unavailable."""
    try:
        from graphcal.analysis.crlb import crlb as compute_crlb  # written in parallel; optional
    except ImportError:
        return {}
    try:
        bound = compute_crlb(dataset, **options)
    except Exception:  # noqa: BLE001 - a bound that cannot be computed is just missing
        return {}
    out = {}
    for rid in dataset.sites:
        for key in _KEY_ORDER:
            try:
                sigma = bound.sigma(rid, key)
            except Exception:  # noqa: BLE001 - key not estimated for this radar
                continue
            if sigma is not None and np.isfinite(sigma):
                out[(rid, key)] = float(sigma) ** 2
    return out


def _residual_stats(cal: Any, rid: str) -> dict[str, float]:
    stats = {
        "range_before_m": math.nan, "range_after_m": math.nan,
        "azimuth_before_mrad": math.nan, "azimuth_after_mrad": math.nan,
    }
    res = getattr(cal, "residuals", {}).get(rid)
    if res is None:
        return stats
    for name, measurement in (("range", "range_m"), ("azimuth", "azimuth_mrad")):
        unit = "m" if name == "range" else "mrad"
        for when in ("before", "after"):
            entry = getattr(res, when).get(measurement)
            if entry is not None and entry.get("mean_abs") is not None:
                stats[f"{name}_{when}_{unit}"] = float(entry["mean_abs"])
    return stats


def _one_run(
    scenario: Any,
    methods: Sequence[str],
    run: int,
    seed_sequence: np.random.SeedSequence,
    method_options: Mapping[str, Mapping[str, Any]],
    crlb_options: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """Simulate once and run every method; plain data back (picklable)."""
    from graphcal.simulation.simulate import simulate
    from graphcal.solvers.registry import get_estimator

    start = time.perf_counter()
    sim = simulate(scenario, np.random.default_rng(seed_sequence))
    simulation_s = time.perf_counter() - start
    dataset = sim.dataset
    truth = {
        (rid, CONTRACT_KEYS[name][0]): to_contract_units(name, bias.value(name))
        for rid, bias in sim.biases.items()
        for name in (*PARAMETER_NAMES, "time_offset")
    }
    crlb_var = {} if crlb_options is None else _crlb_variances(dataset, crlb_options)
    rows, extra, outcome = [], [], {}
    for method in methods:
        estimator = get_estimator(method)
        start = time.perf_counter()
        try:
            cal = estimator(dataset, **dict(method_options.get(method, {})))
            elapsed = time.perf_counter() - start
        except FAILURES as exc:
            outcome[method] = (time.perf_counter() - start, f"{type(exc).__name__}: {exc}")
            continue
        method_rows = []
        for rid, name in cal.labels:
            key = CONTRACT_KEYS[name][0]
            value = cal.value(rid, key)
            sigma = cal.sigma(rid, key)
            method_rows.append((run, method, rid, key, value, math.nan if sigma is None else sigma))
        if not method_rows or not all(np.isfinite(r[4]) for r in method_rows):
            what = "no estimate" if not method_rows else "non-finite estimate"
            outcome[method] = (elapsed, what)
            continue
        outcome[method] = (elapsed, None)
        rows.extend(method_rows)
        for rid in cal.radar_ids:
            extra.append({"run": run, "method": method, "radar": rid,
                          **_residual_stats(cal, rid)})
    return {
        "run": run, "rows": rows, "extra": extra, "outcome": outcome, "truth": truth,
        "crlb": crlb_var, "simulation_s": simulation_s,
    }


# ----------------------------------------------------------------------- compare
def compare(
    scenario: Any,
    methods: Sequence[str],
    runs: int,
    *,
    seed: int = 0,
    jobs: int = 1,
    progress: Progress | None = None,
    method_options: Mapping[str, Mapping[str, Any]] | None = None,
    crlb: bool | Mapping[str, Any] | None = None,
) -> ComparisonResult:
    """Monte-Carlo comparison of estimators on one scenario.

    Parameters
    ----------
    scenario : Scenario or str or Path
        A loaded scenario or its TOML file.
    methods : sequence of str
        Estimator names (:data:`graphcal.solvers.registry.METHODS`).
    runs : int
        Number of Monte-Carlo runs (>= 1).
    seed : int, optional
        Root seed; run ``i`` uses the ``i``-th child of ``SeedSequence(seed)``.
    jobs : int, optional
        Worker processes (1: in this process).  The results do not depend on it.
    progress : callable, optional
        ``progress(done, total)`` after each finished run.
    method_options : mapping, optional
        Keyword arguments per method, e.g. ``{"graph": {"use_adsb": False}}``.
    crlb : bool or mapping, optional
        Compute the Cramér-Rao bound per run with :func:`graphcal.analysis.crlb.crlb` (keyword
        arguments if a mapping); ``None`` or ``True``: with its defaults, ``False``: not
        at all.  Silently NaN when :mod:`graphcal.analysis.crlb` is not available.

    Returns
    -------
    ComparisonResult

    Raises
    ------
    ValueError
        For an unknown method, ``runs < 1`` or ``jobs < 1``.
    """
    from graphcal.simulation.scenario import load_scenario
    from graphcal.solvers.registry import get_estimator

    methods = list(methods)
    if not methods:
        raise ValueError("no method to compare")
    for method in methods:
        get_estimator(method)  # ValueError naming the valid ones
    if len(set(methods)) != len(methods):
        raise ValueError(f"methods repeated: {', '.join(methods)}")
    if runs < 1:
        raise ValueError(f"runs must be at least 1, not {runs}")
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, not {jobs}")
    if isinstance(scenario, (str, Path)):
        scenario = load_scenario(scenario)
    options = {m: dict(o) for m, o in (method_options or {}).items()}
    unknown = sorted(set(options) - set(methods))
    if unknown:
        raise ValueError(f"method_options for methods not compared: {', '.join(unknown)}")
    crlb_options: dict[str, Any] | None
    if crlb is False:
        crlb_options = None
    elif crlb is None or crlb is True:
        crlb_options = {}
    else:
        crlb_options = dict(crlb)

    children = np.random.SeedSequence(seed).spawn(runs)
    results: list[dict[str, Any] | None] = [None] * runs
    done = 0
    if jobs == 1:
        for i, child in enumerate(children):
            results[i] = _one_run(scenario, methods, i, child, options, crlb_options)
            done += 1
            if progress is not None:
                progress(done, runs)
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {
                pool.submit(_one_run, scenario, methods, i, child, options, crlb_options): i
                for i, child in enumerate(children)
            }
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                done += 1
                if progress is not None:
                    progress(done, runs)
    return _summarise(
        getattr(scenario, "name", str(scenario)), methods, runs, seed,
        [r for r in results if r is not None],
    )


def row_status(base: str, n: int, mean: float, std: float, truth: float,
               consistency: float) -> str:
    """A row's status: the method's (``ok``, ``failed in K of N runs``) with what its
    figures show (module docstring): ``sigma too small (σ̂/std 0.18)``, ``sigma too
    large``, ``biased (+3.1 std)``; ``ok`` only when nothing is found."""
    notes = []
    if n >= MIN_RUNS_JUDGED:
        # Outside CONSISTENCY_RANGE and beyond the chance spread of a std from n runs
        # (3 x 1/sqrt(2 (n - 1))): 0.69-1.44 at 24 runs, 0.61-1.64 at 12.
        chance = CONSISTENCY_CHANCE_SIGMAS / math.sqrt(2.0 * (n - 1))
        low = min(CONSISTENCY_RANGE[0], 1.0 / (1.0 + chance))
        high = max(CONSISTENCY_RANGE[1], 1.0 + chance)
        if math.isfinite(consistency) and consistency < low:
            notes.append(f"sigma too small (σ̂/std {consistency:.2f})")
        elif math.isfinite(consistency) and consistency > high:
            notes.append(f"sigma too large (σ̂/std {consistency:.2f})")
        if math.isfinite(std) and math.isfinite(truth) and std > 0:
            off = mean - truth
            if (abs(off) > BIAS_STANDARD_ERRORS * std / math.sqrt(n)
                    and abs(off) > BIAS_STD_FRACTION * std):
                notes.append(f"biased ({off / std:+.1f} std)")
    if not notes:
        return base
    return "; ".join(notes if base == "ok" else [base, *notes])


def _summarise(
    name: str, methods: list[str], runs: int, seed: int, results: list[dict[str, Any]]
) -> ComparisonResult:
    estimates = pd.DataFrame(
        [row for r in results for row in r["rows"]], columns=list(ESTIMATE_COLUMNS)
    )
    truth = results[0]["truth"]
    # CRLB: mean variance over runs, per (radar, key).
    crlb_sum: dict[tuple[str, str], list[float]] = {}
    for r in results:
        for k, v in r["crlb"].items():
            crlb_sum.setdefault(k, []).append(v)
    crlb_sigma = {k: math.sqrt(float(np.mean(v))) for k, v in crlb_sum.items()}

    fail_rows, time_rows = [], []
    n_failed: dict[str, int] = {}
    for method in methods:
        outcomes = [r["outcome"][method] for r in results if method in r["outcome"]]
        errors = [e for _, e in outcomes if e is not None]
        n_failed[method] = len(errors)
        fail_rows.append({"method": method, "runs": runs, "failures": len(errors),
                          "first_error": errors[0] if errors else ""})
        times = np.array([t for t, _ in outcomes], dtype=float)
        time_rows.append({"method": method, "runs": runs, "mean_s": float(times.mean()),
                          "median_s": float(np.median(times)), "total_s": float(times.sum())})

    status = {}
    for row in fail_rows:
        k = row["failures"]
        status[row["method"]] = "ok" if k == 0 else f"failed in {k} of {runs} runs"
    table_rows = []
    radar_order = {rid: i for i, rid in enumerate(dict.fromkeys(r for r, _ in truth))}
    key_order = {k: i for i, k in enumerate(_KEY_ORDER)}
    for method in methods:
        sub = estimates[estimates["method"] == method]
        groups = sorted(
            sub.groupby(["radar", "parameter"], sort=False),
            key=lambda g: (radar_order.get(g[0][0], 1 << 30), key_order[g[0][1]]),
        )
        for (rid, key), group in groups:
            values = group["value"].to_numpy(float)
            sigmas = group["sigma"].to_numpy(float)
            true = float(truth.get((rid, key), math.nan))
            n = len(values)
            mean = float(values.mean())
            std = float(values.std(ddof=1)) if n > 1 else math.nan
            rmse = float(np.sqrt(np.mean((values - true) ** 2)))
            finite_sigmas = sigmas[np.isfinite(sigmas)]
            mean_sigma = float(finite_sigmas.mean()) if finite_sigmas.size else math.nan
            bound = crlb_sigma.get((rid, key), math.nan)
            consistency = mean_sigma / std if std and np.isfinite(std) else math.nan
            table_rows.append({
                "method": method, "radar": rid, "parameter": key, "truth": true, "n": n,
                "mean": mean, "std": std, "rmse": rmse, "mean_sigma": mean_sigma,
                "consistency": consistency,
                "crlb_sigma": bound,
                "rmse_over_crlb": rmse / bound if bound > 0 else math.nan,
                "failures": n_failed[method],
                "status": row_status(status[method], n, mean, std, true, consistency),
            })
        if not groups:  # never an estimate: one row saying so, not silence
            first = next(r["first_error"] for r in fail_rows if r["method"] == method)
            table_rows.append({
                "method": method, "radar": "", "parameter": "", "truth": math.nan, "n": 0,
                "mean": math.nan, "std": math.nan, "rmse": math.nan, "mean_sigma": math.nan,
                "consistency": math.nan, "crlb_sigma": math.nan, "rmse_over_crlb": math.nan,
                "failures": n_failed[method],
                "status": f"failed: {first}" if first else "failed",
            })
    table = pd.DataFrame(table_rows, columns=list(TABLE_COLUMNS))
    table["n"] = table["n"].astype(int)
    table["failures"] = table["failures"].astype(int)
    extra = pd.DataFrame([row for r in results for row in r["extra"]])
    return ComparisonResult(
        scenario=name, methods=methods, runs=runs, seed=seed, table=table,
        timing=pd.DataFrame(time_rows), failures=pd.DataFrame(fail_rows),
        estimates=estimates, extra=extra,
        simulation_s=float(np.mean([r["simulation_s"] for r in results])),
    )


__all__ = ["BIAS_STANDARD_ERRORS", "CONSISTENCY_RANGE", "MIN_RUNS_JUDGED", "ComparisonResult",
           "ESTIMATE_COLUMNS", "TABLE_COLUMNS", "compare", "row_status"]

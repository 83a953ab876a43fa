"""Benchmark of the ``graph`` calibrator.

Run from the repository root::

    .venv/bin/python -m benchmarks.bench_graph            # full benchmark
    .venv/bin/python -m benchmarks.bench_graph --quick    # 40k plots only, no network part
    .venv/bin/python -m benchmarks.bench_graph --profile  # full, plus a cProfile of part 2

Part 1 - solver overhead.  The ADS-B model of the ``graph`` calibrator is
solved two ways on the same data: with GTSAM (one variable per radar, the
weak priors of :func:`graphcal.model.parameters.prior_sigmas`, the vectorised
ADS-B factors, Levenberg-Marquardt, then the joint marginal covariance) and
with :func:`scipy.optimize.least_squares` on exactly the same stacked whitened
residuals (:meth:`graphcal.model.factors.AdsbFactor.whitened` of every
radar plus the prior residuals ``x / sigma``) and the same analytic Jacobian,
assembled into a dense matrix, with the covariance ``(J^T J)^-1`` at the
solution.  Both start from zero and use no robust kernel, so they minimise the
same cost and must reach the same solution.  Datasets of about 40k and 400k
ADS-B-matched plots come from the benchmark scenario with every aircraft
equipped and the number of aircraft scaled.  Reading the ratio: ``trf``
factors the whole tall Jacobian (rows x 31) by SVD at every iteration and
``lm`` by QR, while GTSAM forms only the 31 x 31 normal equations of each
factor, so scipy's cost grows faster with the data.

Part 2 - the network.  The benchmark scenario as is (1 h, 10 radars, 200
aircraft, ADS-B on 70 % of them): simulation time, then the end-to-end
``graph(dataset)`` with its defaults (ADS-B factors plus pairwise cross-radar
factors, Huber kernel), its timing breakdown and its accuracy against the
simulated truth, ``z = (estimate - truth) / sigma`` per parameter.

Part 3 - refraction.  The same network with every radar looking through the
exponential atmosphere of contract v2 (``N_s = 320``, ``H = 7 km``): the same
seed simulates the same traffic along refracted rays, and ``graph(dataset)``
runs end to end with the refraction declared.  Its time over part 2's (same
run) is the cost of refraction; the target is under
``TARGET_REFRACTION_RATIO``.  ``--network-only`` runs parts 2 and 3 alone.

The figures are printed as tables and written to
``benchmarks/results/bench_graph.json`` (``--quick`` overwrites it too, with
``"quick": true``).  Every simulation is seeded with an
explicit ``numpy.random.default_rng(seed)``.  The exit status is 1 when the
GTSAM and scipy solutions disagree by ``AGREEMENT_TOLERANCE_SIGMA`` or more;
the timing targets are reported as PASS/FAIL but do not change it.
"""

from __future__ import annotations

import argparse
import cProfile
import importlib.metadata
import io
import json
import os
import platform
import pstats
import resource
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import scipy
import scipy.linalg
import scipy.optimize
from numpy.typing import NDArray

from benchmarks import RESULTS
from graphcal.data.align import DEFAULT_ADSB_MAX_GAP_S
from graphcal.data.bias import CONTRACT_KEYS
from graphcal.data.dataset import Dataset
from graphcal.model.factor_set import FactorSet, build_factors
from graphcal.model.parameters import prior_sigmas, radar_terms
from graphcal.model.robust import RobustKernel
from graphcal.simulation.scenario import Scenario, load_scenario
from graphcal.simulation.simulate import SimulationResult, simulate
from graphcal.solvers.graph import add_factor, graph
from graphcal.solvers.gtsam_adapter import FactorGraph, OptimizationResult, symbol

FloatArray = NDArray[np.float64]
T = TypeVar("T")

HERE = Path(__file__).resolve().parent
SCENARIO_PATH = HERE / "scenarios" / "network_10radars_1h.toml"
RESULTS_PATH = RESULTS / "bench_graph.json"

#: Repeats of every timed solve in part 1; the median is reported.
REPEATS = 3
#: Part 1 sizes: label, aircraft in the 1-hour scenario (all ADS-B equipped), seed.
#: About 1300 ADS-B-matched plots per aircraft; these counts and seeds give 40,144 and
#: 401,733 (the number of aircraft changes every random draw, so the size is not linear).
SIZES: tuple[tuple[str, int, int], ...] = (("40k", 32, 11), ("400k", 308, 12))
#: Seed of the part 2 simulation.
NETWORK_SEED = 1
#: Method "lm" is skipped when its dense Jacobian would exceed this size [bytes].
LM_MAX_JACOBIAN_BYTES = 2 * 1024**3
#: The GTSAM and scipy solutions must agree to this fraction of the graph's sigma.
AGREEMENT_TOLERANCE_SIGMA = 0.01
#: Targets: graph solve time at most this multiple of scipy "trf"'s ...
TARGET_RATIO = 1.5
#: ... and the end-to-end network calibration under this many seconds.
TARGET_NETWORK_S = 60.0
#: Part 3 target: the network's graph(dataset) time with refraction over without.
TARGET_REFRACTION_RATIO = 1.3


# --------------------------------------------------------------------------- helpers
def peak_rss_mib() -> float:
    """Peak resident memory of this process so far [MiB] (``ru_maxrss``, KiB on Linux)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    scale = 1024.0**2 if sys.platform == "darwin" else 1024.0  # macOS reports bytes
    return rss / scale


def timed(function: Callable[..., T], *args: Any, **kwargs: Any) -> tuple[T, float]:
    """Call ``function(*args, **kwargs)``; return its result and wall time [s]."""
    start = time.perf_counter()
    out = function(*args, **kwargs)
    return out, time.perf_counter() - start


def scaled_scenario(base: Scenario, n_aircraft: int) -> Scenario:
    """``base`` with ``n_aircraft`` random aircraft, all of them ADS-B equipped.

    Parameters
    ----------
    base : Scenario
        A scenario with a ``[traffic]`` table.
    n_aircraft : int
        Number of random aircraft.

    Returns
    -------
    Scenario
        The copy; duration, radars and ADS-B settings other than equipage unchanged.
    """
    if base.traffic is None:
        raise ValueError(f"scenario {base.name} has no [traffic] table to scale")
    return replace(
        base,
        name=f"{base.name}_{n_aircraft}ac_adsb100",
        traffic=replace(base.traffic, n_aircraft=n_aircraft),
        adsb=replace(base.adsb, enabled=True, equipped_fraction=1.0),
    )


def write_json_atomic(path: Path, document: dict[str, Any]) -> None:
    """Write ``document`` to ``path`` through a temporary file and :func:`os.replace`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o644)  # mkstemp creates the file private (0600)
        with os.fdopen(fd, "w", encoding="utf-8") as stream:
            json.dump(document, stream, indent=2)
            stream.write("\n")
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def print_table(title: str, header: list[str], rows: list[list[str]]) -> None:
    """Print a plain text table: first column left-aligned, the others right-aligned."""
    widths = [max(len(str(row[i])) for row in [header, *rows]) for i in range(len(header))]

    def line(cells: list[str]) -> str:
        return "  ".join(
            str(c).ljust(w) if i == 0 else str(c).rjust(w)
            for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        )

    print(f"\n{title}")
    print(line(header))
    print("  ".join("-" * w for w in widths))
    for row in rows:
        print(line(row))


# --------------------------------------------------------------------------- part 1
@dataclass
class AdsbModel:
    """The ADS-B factors of a dataset, their variables and priors.

    Attributes
    ----------
    blocks : FactorSet
        Built by the graph calibrator's own ``build_factors`` (no robust
        kernel, no cross-radar factors).
    radars : list of str
        Radars with a variable, in dataset order.
    priors : dict of str to ndarray
        Prior 1-sigma of each radar's free terms [SI].
    labels : list of (str, str)
        ``(radar_id, parameter name)`` of every parameter, in solution order.
    """

    blocks: FactorSet
    radars: list[str]
    priors: dict[str, FloatArray]
    labels: list[tuple[str, str]]

    @property
    def n_plots(self) -> int:
        """ADS-B-matched plots."""
        return int(sum(len(f.measured) for f in self.blocks.adsb.values()))

    @property
    def n_residuals(self) -> int:
        """Stacked residual length: measurement rows plus one prior row per parameter."""
        return int(sum(f.dimension for f in self.blocks.adsb.values())) + len(self.labels)


def build_adsb_model(dataset: Dataset) -> AdsbModel:
    """Build the ADS-B factors once, as ``graph(dataset, cross="none", robust="none")`` does.

    Parameters
    ----------
    dataset : Dataset
        A dataset with an ADS-B table.

    Returns
    -------
    AdsbModel
        Factors from the graph calibrator's ``build_factors`` (no robust
        kernel, default ADS-B gap), no terms fixed.
    """
    terms = {rid: radar_terms(dataset.sites[rid], {}) for rid in dataset.radar_ids}
    keys = {rid: symbol("b", i) for i, rid in enumerate(dataset.radar_ids)}
    blocks = FactorSet(terms, keys)
    build_factors(
        dataset, blocks, True, "none", RobustKernel("none"), DEFAULT_ADSB_MAX_GAP_S, None, None
    )
    radars = blocks.variable_radars()
    priors = {rid: prior_sigmas(dataset.sites[rid], terms[rid]) for rid in radars}
    labels = [(rid, name) for rid in radars for name in terms[rid].free]
    return AdsbModel(blocks, radars, priors, labels)


def graph_solve(model: AdsbModel) -> tuple[FactorGraph, OptimizationResult, FloatArray]:
    """Build the factor graph (zero start, weak priors, ADS-B factors) and optimise it.

    Parameters
    ----------
    model : AdsbModel

    Returns
    -------
    FactorGraph, OptimizationResult, ndarray
        The graph, GTSAM's result and the stacked solution in ``model.labels`` order.
    """
    blocks = model.blocks
    fg = FactorGraph()
    for rid in model.radars:
        k = len(blocks.terms[rid].free)
        fg.add_variable(blocks.keys[rid], np.zeros(k))
        fg.add_prior(blocks.keys[rid], np.zeros(k), model.priors[rid])
    variable = set(model.radars)
    for factor in blocks.adsb.values():
        add_factor(fg, factor, variable)
    result = fg.optimize()
    x = np.concatenate([result.vector(blocks.keys[rid]) for rid in model.radars])
    return fg, result, x


def graph_covariance(model: AdsbModel, fg: FactorGraph, result: OptimizationResult) -> FloatArray:
    """Joint marginal covariance of every radar's biases (GTSAM ``Marginals``)."""
    return fg.joint_covariance(result.values, [model.blocks.keys[rid] for rid in model.radars])


class StackedResiduals:
    """The ADS-B model as one residual vector and dense Jacobian for scipy.

    Rows: every radar's whitened ADS-B residuals (``AdsbFactor.whitened``,
    raveled), then the prior residuals ``x / sigma``.  The residuals and
    Jacobian of the last ``x`` are cached, so that scipy's ``jac(x)`` after
    ``fun(x)`` at the same point costs no second evaluation.
    """

    def __init__(self, model: AdsbModel) -> None:
        self.model = model
        self.factors = [model.blocks.adsb[rid] for rid in model.radars]
        self.columns: list[slice] = []
        self.rows: list[slice] = []
        col = row = 0
        for rid, factor in zip(model.radars, self.factors, strict=True):
            k = len(model.blocks.terms[rid].free)
            self.columns.append(slice(col, col + k))
            self.rows.append(slice(row, row + factor.dimension))
            col += k
            row += factor.dimension
        self.n_parameters = col
        self.prior_rows = slice(row, row + col)
        self.n_rows = row + col
        self.inverse_prior = 1.0 / np.concatenate([model.priors[rid] for rid in model.radars])
        self._cache: tuple[bytes, FloatArray, list[FloatArray]] | None = None

    def _evaluate(self, x: FloatArray) -> tuple[FloatArray, list[FloatArray]]:
        tag = np.asarray(x, dtype=float).tobytes()
        if self._cache is None or self._cache[0] != tag:
            residuals = np.empty(self.n_rows)
            blocks = []
            for factor, rows, cols in zip(self.factors, self.rows, self.columns, strict=True):
                e, (jac,) = factor.whitened([x[cols]])
                residuals[rows] = e.ravel()
                blocks.append(jac.reshape(-1, jac.shape[-1]))
            residuals[self.prior_rows] = x * self.inverse_prior
            self._cache = (tag, residuals, blocks)
        return self._cache[1], self._cache[2]

    def residuals(self, x: FloatArray) -> FloatArray:
        """Stacked whitened residuals at ``x``."""
        return self._evaluate(x)[0].copy()

    def jacobian(self, x: FloatArray) -> FloatArray:
        """Dense Jacobian ``(n_rows, n_parameters)`` of :meth:`residuals` at ``x``."""
        _, blocks = self._evaluate(x)
        jac = np.zeros((self.n_rows, self.n_parameters))
        for block, rows, cols in zip(blocks, self.rows, self.columns, strict=True):
            jac[rows, cols] = block
        jac[self.prior_rows, np.arange(self.n_parameters)] = self.inverse_prior
        return jac

    @property
    def jacobian_bytes(self) -> int:
        """Size of the dense Jacobian [bytes]."""
        return self.n_rows * self.n_parameters * 8


def scipy_solve(model: AdsbModel, method: str) -> scipy.optimize.OptimizeResult:
    """``least_squares`` on the stacked residuals from zero.

    Analytic dense Jacobian, ``x_scale="jac"``, default tolerances.
    """
    stacked = StackedResiduals(model)
    return scipy.optimize.least_squares(
        stacked.residuals,
        np.zeros(stacked.n_parameters),
        jac=stacked.jacobian,
        method=method,
        x_scale="jac",
    )


def scipy_covariance(model: AdsbModel, x: FloatArray) -> FloatArray:
    """``(J^T J)^-1`` with the Jacobian evaluated afresh at ``x`` (as GTSAM's marginals do)."""
    jac = StackedResiduals(model).jacobian(x)
    information = jac.T @ jac
    return scipy.linalg.cho_solve(scipy.linalg.cho_factor(information), np.eye(len(x)))


def median_times(times: list[float]) -> dict[str, Any]:
    """Median and all repeats of a list of wall times [s]."""
    return {"median": statistics.median(times), "repeats": times}


def bench_size(label: str, n_aircraft: int, seed: int, base: Scenario) -> dict[str, Any]:
    """Part 1 at one size: simulate, build the factors once, time graph and scipy.

    Parameters
    ----------
    label : str
        Size label for the tables.
    n_aircraft : int
        Aircraft in the scaled scenario (:func:`scaled_scenario`).
    seed : int
        Seed of the simulation's ``numpy.random.default_rng``.
    base : Scenario
        The benchmark scenario.

    Returns
    -------
    dict
        Sizes, wall times (median and repeats), ratios, iteration counts,
        agreement between the solutions, target verdict and peak memory.
    """
    print(f"\n[part 1, {label}] simulating {n_aircraft} aircraft (seed {seed}) ...", flush=True)
    sim, t_sim = timed(simulate, scaled_scenario(base, n_aircraft), np.random.default_rng(seed))
    dataset = sim.dataset
    model, t_build = timed(build_adsb_model, dataset)
    stacked = StackedResiduals(model)
    run_lm = stacked.jacobian_bytes <= LM_MAX_JACOBIAN_BYTES
    print(f"  {len(dataset.plots)} plots, {model.n_plots} ADS-B-matched, "
          f"{len(model.labels)} parameters; simulation {t_sim:.1f} s, factors {t_build:.1f} s",
          flush=True)

    times: dict[str, list[float]] = {
        "graph_solve": [], "graph_covariance": [], "scipy_trf": [], "scipy_lm": [],
        "scipy_covariance": [], "graph_end_to_end": [],
    }
    for repeat in range(REPEATS):
        print(f"  repeat {repeat + 1}/{REPEATS} ...", flush=True)
        (fg, g_result, x_graph), t = timed(graph_solve, model)
        times["graph_solve"].append(t)
        cov_graph, t = timed(graph_covariance, model, fg, g_result)
        times["graph_covariance"].append(t)
        trf, t = timed(scipy_solve, model, "trf")
        times["scipy_trf"].append(t)
        cov_scipy, t = timed(scipy_covariance, model, trf.x)
        times["scipy_covariance"].append(t)
        lm = None
        if run_lm:
            lm, t = timed(scipy_solve, model, "lm")
            times["scipy_lm"].append(t)
        cal, t = timed(graph, dataset, cross="none", robust="none", init="zero",
                       time_offset=False)  # the same 31 parameters as the ADS-B model
        times["graph_end_to_end"].append(t)
    iterations = {
        "graph_lm": g_result.iterations,
        "scipy_trf_nfev": int(trf.nfev), "scipy_trf_njev": int(trf.njev or 0),
        "scipy_lm_nfev": int(lm.nfev) if lm is not None else None,
        "graph_end_to_end": int(cal.info["iterations"]),
    }

    sigma_graph = np.sqrt(np.diag(cov_graph))
    agreement = {
        "trf_max_abs_dx_sigma": float(np.max(np.abs(trf.x - x_graph) / sigma_graph)),
        "lm_max_abs_dx_sigma": (float(np.max(np.abs(lm.x - x_graph) / sigma_graph))
                                if lm is not None else None),
        "end_to_end_max_abs_dx_sigma": float(np.max(np.abs(cal.estimate - x_graph)
                                                    / sigma_graph)),
        "sigma_max_rel_diff": float(np.max(np.abs(np.sqrt(np.diag(cov_scipy)) / sigma_graph
                                                  - 1.0))),
        "covariance_max_abs_diff_corr": float(np.max(
            np.abs(cov_scipy - cov_graph) / np.outer(sigma_graph, sigma_graph))),
        "tolerance_sigma": AGREEMENT_TOLERANCE_SIGMA,
    }
    checked = [agreement["trf_max_abs_dx_sigma"], agreement["end_to_end_max_abs_dx_sigma"]]
    if lm is not None:
        checked.append(agreement["lm_max_abs_dx_sigma"])
    agreement["max_abs_dx_sigma"] = max(checked)
    agreement["ok"] = bool(agreement["max_abs_dx_sigma"] < AGREEMENT_TOLERANCE_SIGMA)

    medians = {name: statistics.median(t) for name, t in times.items() if t}
    ratio = medians["graph_solve"] / medians["scipy_trf"]
    return {
        "label": label,
        "n_aircraft": n_aircraft,
        "seed": seed,
        "n_plots_total": len(dataset.plots),
        "n_adsb_plots": model.n_plots,
        "n_residuals": stacked.n_rows,
        "n_parameters": len(model.labels),
        "dense_jacobian_mib": stacked.jacobian_bytes / 1024**2,
        "lm_run": run_lm,
        "simulation_s": t_sim,
        "factor_build_s": t_build,
        "times_s": {name: median_times(t) for name, t in times.items() if t},
        "ratio_graph_over_scipy_trf": ratio,
        "ratio_graph_over_scipy_lm": (medians["graph_solve"] / medians["scipy_lm"]
                                      if run_lm else None),
        "ratio_with_covariance": ((medians["graph_solve"] + medians["graph_covariance"])
                                  / (medians["scipy_trf"] + medians["scipy_covariance"])),
        "iterations": iterations,
        "agreement": agreement,
        "target_ratio": TARGET_RATIO,
        "target_pass": bool(ratio <= TARGET_RATIO),
        "peak_rss_mib": peak_rss_mib(),
    }


def print_part1(results: list[dict[str, Any]]) -> None:
    """Print the part 1 tables."""
    def med(r: dict[str, Any], name: str) -> str:
        t = r["times_s"].get(name)
        return f"{t['median']:.3f}" if t else "skipped"

    header = ["", *[r["label"] for r in results]]
    rows = [
        ["ADS-B-matched plots", *[f"{r['n_adsb_plots']:,}" for r in results]],
        ["all plots in dataset", *[f"{r['n_plots_total']:,}" for r in results]],
        ["aircraft (all ADS-B), seed",
         *[f"{r['n_aircraft']}, {r['seed']}" for r in results]],
        ["residual rows", *[f"{r['n_residuals']:,}" for r in results]],
        ["parameters", *[str(r["n_parameters"]) for r in results]],
        ["dense Jacobian [MiB]", *[f"{r['dense_jacobian_mib']:.0f}" for r in results]],
        ["graph: build + LM solve [s]", *[med(r, "graph_solve") for r in results]],
        ["graph: joint_covariance [s]", *[med(r, "graph_covariance") for r in results]],
        ["scipy trf solve [s]", *[med(r, "scipy_trf") for r in results]],
        ["scipy lm solve [s]", *[med(r, "scipy_lm") for r in results]],
        ["scipy (J^T J)^-1 [s]", *[med(r, "scipy_covariance") for r in results]],
        ["graph() end-to-end [s]", *[med(r, "graph_end_to_end") for r in results]],
        ["ratio graph / scipy trf", *[f"{r['ratio_graph_over_scipy_trf']:.2f}" for r in results]],
        ["ratio graph / scipy lm",
         *[f"{r['ratio_graph_over_scipy_lm']:.2f}" if r["ratio_graph_over_scipy_lm"] else "-"
           for r in results]],
        ["ratio incl. covariance (trf)",
         *[f"{r['ratio_with_covariance']:.2f}" for r in results]],
        ["iterations graph LM / trf nfev / lm nfev",
         *[f"{r['iterations']['graph_lm']} / {r['iterations']['scipy_trf_nfev']} / "
           f"{r['iterations']['scipy_lm_nfev'] if r['iterations']['scipy_lm_nfev'] else '-'}"
           for r in results]],
        ["max |x_scipy - x_graph| [sigma]",
         *[f"{r['agreement']['max_abs_dx_sigma']:.1e}" for r in results]],
        ["max |sigma_scipy / sigma_graph - 1|",
         *[f"{r['agreement']['sigma_max_rel_diff']:.1e}" for r in results]],
        ["peak RSS so far [MiB]", *[f"{r['peak_rss_mib']:.0f}" for r in results]],
    ]
    print_table(f"PART 1: GTSAM graph vs scipy least_squares, same ADS-B model "
                f"(wall times: median of {REPEATS})", header, rows)
    print("  (graph solve = FactorGraph build + optimize(); end-to-end = "
          "graph(dataset, cross='none', robust='none', init='zero'), ADS-B association "
          "included; max |dx| over trf, lm and end-to-end)")
    for r in results:
        a = r["agreement"]
        verdict = "OK" if a["ok"] else "FAILED"
        print(f"  [{r['label']}] solutions agree: max |dx| = {a['max_abs_dx_sigma']:.1e} sigma "
              f"< {AGREEMENT_TOLERANCE_SIGMA} sigma: {verdict}")


# --------------------------------------------------------------------------- part 2
def accuracy(cal: Any, sim: SimulationResult) -> list[dict[str, Any]]:
    """``(estimate - truth) / sigma`` for every estimated parameter.

    Parameters
    ----------
    cal : Calibration
        The graph calibration (SI estimate and joint covariance).
    sim : SimulationResult
        The simulation with the true biases.

    Returns
    -------
    list of dict
        Per parameter: radar, names, estimate, truth and sigma in contract
        units, and ``z``.
    """
    covariance = np.asarray(cal.covariance)
    rows = []
    for i, (rid, name) in enumerate(cal.labels):
        truth = sim.biases[rid].value(name)
        sigma = float(np.sqrt(covariance[i, i]))
        key, unit = CONTRACT_KEYS[name]
        rows.append({
            "radar": rid, "parameter": name, "contract_key": key,
            "estimate": float(cal.estimate[i]) * unit, "truth": truth * unit,
            "sigma": sigma * unit, "z": (float(cal.estimate[i]) - truth) / sigma,
        })
    return rows


def profile_graph(dataset: Dataset, top: int = 15) -> str:
    """cProfile of ``graph(dataset)``: the ``top`` entries by cumulative time."""
    profiler = cProfile.Profile()
    profiler.enable()
    graph(dataset)
    profiler.disable()
    out = io.StringIO()
    pstats.Stats(profiler, stream=out).sort_stats("cumulative").print_stats(top)
    return out.getvalue()


def bench_network(base: Scenario, profile: bool) -> dict[str, Any]:
    """Part 2: the scenario as is, simulated then calibrated with ``graph`` defaults.

    Parameters
    ----------
    base : Scenario
        The benchmark scenario, unchanged.
    profile : bool
        Also profile ``graph(dataset)`` in a second, untimed run.

    Returns
    -------
    dict
        Simulation and calibration times, the calibrator's timing breakdown
        and counts, accuracy against the truth, target verdict and peak memory.
    """
    print(f"\n[part 2] simulating {base.name} (seed {NETWORK_SEED}) ...", flush=True)
    sim, t_sim = timed(simulate, base, np.random.default_rng(NETWORK_SEED))
    print(f"  {len(sim.dataset.plots)} plots in {t_sim:.1f} s; calibrating ...", flush=True)
    cal, t_graph = timed(graph, sim.dataset)
    z_rows = accuracy(cal, sim)
    z = np.array([r["z"] for r in z_rows])
    worst = int(np.argmax(np.abs(z)))
    out: dict[str, Any] = {
        "scenario": str(SCENARIO_PATH.relative_to(HERE.parent)),
        "seed": NETWORK_SEED,
        "n_radars": len(sim.dataset.sites),
        "n_aircraft": base.traffic.n_aircraft if base.traffic else None,
        "adsb_equipped_fraction": base.adsb.equipped_fraction,
        "n_plots": len(sim.dataset.plots),
        "n_adsb_reports": 0 if sim.dataset.adsb is None else len(sim.dataset.adsb),
        "simulation_s": t_sim,
        "graph_s": t_graph,
        "timing_s": dict(cal.info["timing_s"]),
        "iterations": int(cal.info["iterations"]),
        "converged": bool(cal.info["converged"]),
        "initialisation": cal.info["initialisation"],
        "n_parameters": len(cal.labels),
        "n_adsb_plots": int(cal.info["n_adsb_plots"]),
        "n_pairs": int(cal.info["n_pairs"]),
        "n_factors": int(cal.info["n_factors"]),
        "chi2_per_dof": float(cal.info["chi2_per_dof"]),
        "max_abs_z": float(np.abs(z[worst])),
        "max_abs_z_parameter": f"{z_rows[worst]['radar']}.{z_rows[worst]['contract_key']}",
        "mean_z2": float(np.mean(z**2)),
        "accuracy": z_rows,
        "target_s": TARGET_NETWORK_S,
        "target_pass": bool(t_graph < TARGET_NETWORK_S),
        "peak_rss_mib": peak_rss_mib(),
    }
    if profile:
        print("  profiling graph(dataset) (separate, untimed run) ...", flush=True)
        out["profile_top15_cumulative"] = profile_graph(sim.dataset)
    return out


def refracted(base: Scenario) -> Scenario:
    """The scenario with every radar's rays refracted (contract v2, ``N_s = 320``, 7 km)."""
    radars = tuple(replace(r, refraction="exponential", refractivity_n_s=320.0,
                           refractivity_scale_height_m=7000.0) for r in base.radars)
    return replace(base, radars=radars)


def bench_refraction(base: Scenario, straight_s: float) -> dict[str, Any]:
    """Part 3: part 2's network with refraction on, simulated then calibrated the same way.

    Parameters
    ----------
    base : Scenario
        The benchmark scenario, unchanged (refraction is switched on here).
    straight_s : float
        Part 2's ``graph(dataset)`` time, same run [s].
    """
    print(f"\n[part 3] simulating {base.name} with refraction (seed {NETWORK_SEED}) ...",
          flush=True)
    sim, t_sim = timed(simulate, refracted(base), np.random.default_rng(NETWORK_SEED))
    print(f"  {len(sim.dataset.plots)} plots in {t_sim:.1f} s; calibrating ...", flush=True)
    cal, t_graph = timed(graph, sim.dataset)
    z = np.array([r["z"] for r in accuracy(cal, sim)])
    ratio = t_graph / straight_s
    return {
        "n_plots": len(sim.dataset.plots), "simulation_s": t_sim, "graph_s": t_graph,
        "straight_graph_s": straight_s, "ratio": ratio,
        "timing_s": dict(cal.info["timing_s"]), "iterations": int(cal.info["iterations"]),
        "max_abs_z": float(np.max(np.abs(z))), "mean_z2": float(np.mean(z**2)),
        "target_ratio": TARGET_REFRACTION_RATIO,
        "target_pass": bool(ratio < TARGET_REFRACTION_RATIO),
    }


def print_part3(r: dict[str, Any]) -> None:
    """Print the part 3 table."""
    t = r["timing_s"]
    rows = [
        ["plots", f"{r['n_plots']:,}"],
        ["graph(dataset) straight (part 2) [s]", f"{r['straight_graph_s']:.2f}"],
        ["graph(dataset) refracted [s]", f"{r['graph_s']:.2f}"],
        ["  factors / initialisation", f"{t.get('factors_s', 0.0):.2f} / "
                                       f"{t.get('initialisation_s', 0.0):.2f}"],
        ["  optimisation / marginals", f"{t.get('optimisation_s', 0.0):.2f} / "
                                       f"{t.get('marginals_s', 0.0):.2f}"],
        ["refracted / straight", f"{r['ratio']:.2f}"],
        ["max |z|, mean z^2", f"{r['max_abs_z']:.2f}, {r['mean_z2']:.2f}"],
    ]
    print_table("PART 3: the network with refraction (N_s = 320, H = 7 km)", ["", "value"], rows)


def print_part2(r: dict[str, Any]) -> None:
    """Print the part 2 tables."""
    t = r["timing_s"]
    stages = ("factors_s", "initialisation_s", "optimisation_s", "marginals_s")
    rest = t["total_s"] - sum(t.get(k, 0.0) for k in stages)
    rows = [
        ["radars / aircraft / ADS-B equipped",
         f"{r['n_radars']} / {r['n_aircraft']} / {r['adsb_equipped_fraction']:.0%}"],
        ["plots / ADS-B reports", f"{r['n_plots']:,} / {r['n_adsb_reports']:,}"],
        ["simulation [s]", f"{r['simulation_s']:.2f}"],
        ["graph(dataset) end-to-end [s]", f"{r['graph_s']:.2f}"],
        ["  factors (ADS-B association, pairing)", f"{t.get('factors_s', 0.0):.2f}"],
        ["  initialisation (closed form)", f"{t.get('initialisation_s', 0.0):.2f}"],
        ["  optimisation (LM)", f"{t.get('optimisation_s', 0.0):.2f}"],
        ["  marginals (+ pairwise sandwich)", f"{t.get('marginals_s', 0.0):.2f}"],
        ["  rest (report, residual stats)", f"{rest:.2f}"],
        ["LM iterations (init)", f"{r['iterations']} ({r['initialisation']})"],
        ["parameters / factors", f"{r['n_parameters']} / {r['n_factors']}"],
        ["ADS-B plots / cross-radar pairs", f"{r['n_adsb_plots']:,} / {r['n_pairs']:,}"],
        ["chi2 per dof", f"{r['chi2_per_dof']:.3f}"],
        ["max |z| (parameter)", f"{r['max_abs_z']:.2f} ({r['max_abs_z_parameter']})"],
        ["mean z^2 (1 expected)", f"{r['mean_z2']:.2f}"],
        ["peak RSS so far [MiB]", f"{r['peak_rss_mib']:.0f}"],
    ]
    print_table("PART 2: network, graph(dataset) with defaults (pairwise cross factors, Huber)",
                ["", "value"], rows)
    by_radar: dict[str, list[str]] = {}
    for a in r["accuracy"]:
        by_radar.setdefault(a["radar"], []).append(f"{a['contract_key']} {a['z']:+.2f}")
    print_table("  z = (estimate - truth) / sigma", ["radar", "z per parameter"],
                [[rid, ",  ".join(items)] for rid, items in by_radar.items()])
    if "profile_top15_cumulative" in r:
        print("\ncProfile of graph(dataset), top 15 by cumulative time:")
        print(r["profile_top15_cumulative"])


# --------------------------------------------------------------------------- main
def environment() -> dict[str, Any]:
    """Versions, machine, BLAS thread settings and load (the timings depend on all four)."""
    return {
        "load_average_1_5_15min": list(os.getloadavg()),
        "thread_env": {name: os.environ.get(name) for name in
                       ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")},
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "gtsam": importlib.metadata.version("gtsam"),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print the tables and write the JSON.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 1 if the GTSAM and scipy solutions disagree, else 0.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="only the 40k size of part 1, no part 2")
    parser.add_argument("--network-only", action="store_true",
                        help="only parts 2 and 3 (the network, straight and refracted)")
    parser.add_argument("--profile", action="store_true",
                        help="also print a cProfile of part 2's graph(dataset) (extra run)")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    env = environment()
    print(f"load average at start: {env['load_average_1_5_15min'][0]:.2f} "
          f"on {env['cpu_count']} CPUs (timings are wall times: other load inflates them)")
    base = load_scenario(SCENARIO_PATH)
    sizes = [] if args.network_only else SIZES[:1] if args.quick else SIZES
    part1 = [bench_size(label, n, seed, base) for label, n, seed in sizes]
    part2 = None if args.quick else bench_network(base, args.profile)
    part3 = None if part2 is None else bench_refraction(base, part2["graph_s"])

    if part1:
        print_part1(part1)
    if part2 is not None:
        print_part2(part2)
    if part3 is not None:
        print_part3(part3)
    print("\nTARGETS")
    for r in part1:
        verdict = "PASS" if r["target_pass"] else "FAIL"
        print(f"  {verdict}  [{r['label']}] graph solve / scipy trf = "
              f"{r['ratio_graph_over_scipy_trf']:.2f} <= {TARGET_RATIO}")
    if part2 is not None:
        verdict = "PASS" if part2["target_pass"] else "FAIL"
        print(f"  {verdict}  network graph(dataset) = {part2['graph_s']:.1f} s "
              f"< {TARGET_NETWORK_S:.0f} s (simulation {part2['simulation_s']:.1f} s "
              "not included)")
    if part3 is not None:
        verdict = "PASS" if part3["target_pass"] else "FAIL"
        print(f"  {verdict}  network with refraction / without = {part3['ratio']:.2f} "
              f"< {TARGET_REFRACTION_RATIO}")
    peak = peak_rss_mib()
    print(f"\npeak memory (ru_maxrss): {peak:.0f} MiB; wall time "
          f"{time.perf_counter() - start:.0f} s")

    document = {
        "benchmark": "bench_graph",
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "quick": args.quick,
        "environment": env,
        "part1": part1 if part1 or not RESULTS_PATH.exists() else json.loads(
            RESULTS_PATH.read_text()).get("part1", []),  # --network-only keeps part 1's
        "part2": part2,
        "part3": part3,
        "peak_rss_mib": peak,
        "wall_time_s": time.perf_counter() - start,
    }
    write_json_atomic(RESULTS_PATH, document)
    print(f"figures written to {RESULTS_PATH}")

    if not all(r["agreement"]["ok"] for r in part1):
        print("ERROR: the GTSAM and scipy solutions differ by "
              f">= {AGREEMENT_TOLERANCE_SIGMA} sigma", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

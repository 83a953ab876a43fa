"""Trajectory study: are ``graph``'s sigmas right with ``cross="trajectory"``, and is it order-free?

Run from the repository root::

    .venv/bin/python -m benchmarks.trajectory_study [--seeds N] [--cases a,b] [--json out.json]

``graphcal.solvers.graph.graph`` estimates, by default (``cross="trajectory"``,
:mod:`graphcal.model.trajectory`), every aircraft's path jointly with the radar biases;
``cross="pairwise"`` is the older formulation, run on the same datasets for comparison.
Every dataset is simulated with an explicit seed (``1 .. N``), cleaned as
``graphcal calibrate`` cleans a folder (:func:`graphcal.data.cleaning.clean_dataset`),
then calibrated by ``graph(...)`` directly (no variance-factor widening).  Cases:

* ``adsb-5s``, ``adsb-10s``: ``scenarios/paris_opensky.toml`` (real OpenSky traffic,
  needs ``../shared/data/opensky_paris_2021-10-07.parquet``, skipped with a message
  when it is missing) with the ADS-B report
  period set to 5 s and 10 s; ADS-B used, time offsets automatic (``time_offset=None``:
  estimated where the traffic determines them; the true offsets are 0).  6 seeds.
* ``noisy-7mrad``: ``scenarios/demo_network.toml`` reduced to NORD, SUD, EST3D and
  OUEST3D (APP dropped), every radar's azimuth noise 7 mrad and the 3-D radars'
  elevation noise 6 mrad (``Scenario.with_radars``; the stated sigmas in
  ``sites.toml`` are the simulated ones), ADS-B neither simulated nor used
  (``use_adsb=False``).  12 seeds.
* ``demo-no-adsb``: ``scenarios/demo_network.toml`` as it is (1 mrad radars),
  calibrated without ADS-B (``use_adsb=False``): the cross-radar observations alone.
  8 seeds.
* ``order``: ``scenarios/demo_network.toml``, with and without ADS-B: the cleaned
  dataset and the same dataset with its radars in reversed order (``Dataset.sites``
  order is ``Dataset.radar_ids``), calibrated each; the largest
  ``|estimate - estimate_reversed| / sigma`` over every parameter (sigma of the file
  order's calibration).  3 seeds.

One ``graph`` call takes 1-3 s with ``cross="trajectory"`` and 0.1-2 s with
``cross="pairwise"`` on a 2-core machine; the defaults take about 1.5 minutes in all
(88 s measured), ``--seeds 30 --cases adsb-5s,adsb-10s,noisy-7mrad`` 3-5 minutes.

For the calibration cases the table gives, per case and formulation, the runs, the
mean time of one ``graph`` call, and per parameter kind (``range_offset``,
``range_gain``, ``azimuth_bias``, ``elevation_bias``, ``time_offset``, and all kinds
together) the statistics of ``z = (estimate - truth) / sigma`` over the seeds and
radars: mean z / var z (mean z², the normalised error variance) / max |z| and
(count of |z| > 3 of n).  Parameters of one run are correlated, and the OpenSky cases
replay the same traffic for every seed (only the noise, antenna phases and ADS-B
phases change), so the effective sample is smaller than ``n``.  A second table gives
the order case.  Runs that raised are counted in the ``errors`` column and printed.

Prints the tables; writes JSON (summaries and every run's estimates, sigmas and
truths) only to the path given with ``--json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.study_runs import timed_run
from graphcal.data.cleaning import clean_dataset
from graphcal.data.dataset import Dataset
from graphcal.simulation.scenario import Scenario, load_scenario
from graphcal.simulation.simulate import SimulationResult, simulate
from graphcal.solvers.graph import graph

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"

#: Parameter kinds reported, in table order.
KINDS: tuple[str, ...] = ("range_offset", "range_gain", "azimuth_bias", "elevation_bias",
                          "time_offset")
#: Formulations compared: the default first.
FORMULATIONS: tuple[str, ...] = ("trajectory", "pairwise")
#: Case -> default number of seeds.
CASES: dict[str, int] = {"adsb-5s": 6, "adsb-10s": 6, "noisy-7mrad": 12, "demo-no-adsb": 8,
                         "order": 3}
#: Radars kept in the noisy case, and their noise [rad].
NOISY_RADARS: tuple[str, ...] = ("NORD", "SUD", "EST3D", "OUEST3D")
NOISY_AZIMUTH_RAD = 7e-3
NOISY_ELEVATION_RAD = 6e-3


#: The cases flown by the shared OpenSky table's real trajectories.
OPENSKY_CASES = ("adsb-5s", "adsb-10s")


def opensky_table() -> Path:
    """The OpenSky table the real-traffic cases replay (``scenarios/paris_opensky.toml``'s)."""
    return load_scenario(SCENARIOS / "paris_opensky.toml").opensky.file


def scenario_of(case: str) -> tuple[Scenario, bool]:
    """The scenario of a case and whether ADS-B is used (module docstring)."""
    if case in ("adsb-5s", "adsb-10s"):
        scenario = load_scenario(SCENARIOS / "paris_opensky.toml")
        period = 5.0 if case == "adsb-5s" else 10.0
        return dataclasses.replace(scenario, adsb=dataclasses.replace(scenario.adsb,
                                                                      period_s=period)), True
    if case == "noisy-7mrad":
        scenario = load_scenario(SCENARIOS / "demo_network.toml")
        scenario = dataclasses.replace(
            scenario,
            radars=tuple(r for r in scenario.radars if r.id in NOISY_RADARS),
            adsb=dataclasses.replace(scenario.adsb, enabled=False))
        scenario = scenario.with_radars(sigma_azimuth_rad=NOISY_AZIMUTH_RAD,
                                        sigma_elevation_rad=NOISY_ELEVATION_RAD)
        return scenario, False
    if case == "demo-no-adsb":  # the demo network (1 mrad radars), cross-radar only
        return load_scenario(SCENARIOS / "demo_network.toml"), False
    raise ValueError(case)


def simulated(scenario: Scenario, seed: int) -> tuple[SimulationResult, Dataset]:
    """The simulation of one seed and its cleaned dataset."""
    res = simulate(scenario, np.random.default_rng(seed))
    dataset, _ = clean_dataset(res.dataset)
    return res, dataset


def calibrate(dataset: Dataset, cross: str, use_adsb: bool) -> tuple[object | None, dict]:
    """``graph`` on the dataset: the Calibration (None if it raised) and the run record."""
    return timed_run(lambda: graph(dataset, cross=cross, use_adsb=use_adsb, bound=True))


def run(case: str, seed: int) -> dict:
    """One seed of a calibration case, both formulations: z of every parameter."""
    scenario, use_adsb = scenario_of(case)
    res, dataset = simulated(scenario, seed)
    out: dict = {"case": case, "seed": seed, "plots": len(dataset.plots),
                 "adsb": 0 if dataset.adsb is None else len(dataset.adsb)}
    for cross in FORMULATIONS:
        cal, record = calibrate(dataset, cross, use_adsb)
        if cal is not None:
            cov = np.asarray(cal.covariance_si)
            bound = None if cal.bound is None else np.asarray(cal.bound["covariance"])
            params = []
            for i, (rid, name) in enumerate(cal.labels):
                sigma = float(np.sqrt(cov[i, i]))
                truth = float(res.biases[rid].value(name))
                estimate = float(cal.estimate[i])
                params.append({"radar": rid, "name": name, "estimate": estimate,
                               "sigma": sigma, "truth": truth,
                               "z": (estimate - truth) / sigma,
                               "bound_sigma": None if bound is None
                               else float(np.sqrt(bound[i, i]))})
            record["parameters"] = params
        out[cross] = record
    return out


def run_order(seed: int) -> dict:
    """One seed of the order case: file order against reversed radars, per formulation."""
    scenario = load_scenario(SCENARIOS / "demo_network.toml")
    _, dataset = simulated(scenario, seed)
    reversed_ = dataclasses.replace(dataset, sites=dict(reversed(list(dataset.sites.items()))))
    assert reversed_.radar_ids == dataset.radar_ids[::-1]
    out: dict = {"case": "order", "seed": seed}
    for use_adsb in (True, False):
        for cross in FORMULATIONS:
            a, rec_a = calibrate(dataset, cross, use_adsb)
            b, rec_b = calibrate(reversed_, cross, use_adsb)
            record: dict = {"seconds": (rec_a["seconds"] + rec_b["seconds"]) / 2,
                            "error": rec_a["error"] or rec_b["error"]}
            if a is not None and b is not None:
                index_b = {label: i for i, label in enumerate(b.labels)}
                cov = np.asarray(a.covariance_si)
                worst, where = 0.0, None
                for i, label in enumerate(a.labels):
                    if label not in index_b:
                        record["error"] = f"label {label} missing in the reversed calibration"
                        continue
                    d = abs(float(a.estimate[i] - b.estimate[index_b[label]])) / float(
                        np.sqrt(cov[i, i]))
                    if d >= worst:
                        worst, where = d, f"{label[0]} {label[1]}"
                record.update(max_diff_sigma=worst, at=where,
                              same_labels=set(a.labels) == set(b.labels))
            out[f"{cross} {'adsb' if use_adsb else 'no-adsb'}"] = record
    return out


def z_stats(z: list[float]) -> dict:
    a = np.asarray(z, dtype=float)
    if not len(a):
        return {"n": 0}
    return {"n": len(a), "mean": float(a.mean()), "var": float(np.mean(a**2)),
            "max_abs": float(np.max(np.abs(a))), "beyond_3": int(np.sum(np.abs(a) > 3))}


def summarise(runs: list[dict]) -> dict:
    """Per formulation: runs, errors, mean seconds and z statistics per kind."""
    summary = {}
    for cross in FORMULATIONS:
        records = [r[cross] for r in runs]
        good = [r for r in records if r["error"] is None]
        params = [p for r in good for p in r["parameters"]]
        kinds = {kind: z_stats([p["z"] for p in params if p["name"] == kind])
                 for kind in KINDS}
        other = sorted({p["name"] for p in params} - set(KINDS))
        for kind in other:
            kinds[kind] = z_stats([p["z"] for p in params if p["name"] == kind])
        kinds["all"] = z_stats([p["z"] for p in params])
        # RMSE / sqrt(CRLB) per parameter over the seeds (the bound the estimator computes
        # of its own model, where it does), the largest per kind.
        efficiency: dict[str, float] = {}
        squares: dict[str, list[float]] = {}
        by_label: dict[tuple[str, str], list[dict]] = {}
        for p in params:
            if p.get("bound_sigma"):
                by_label.setdefault((p["radar"], p["name"]), []).append(p)
        for (_, name), ps in by_label.items():
            rmse = np.sqrt(np.mean([(p["estimate"] - p["truth"]) ** 2 for p in ps]))
            bound = np.sqrt(np.mean([p["bound_sigma"] ** 2 for p in ps]))
            efficiency[name] = max(efficiency.get(name, 0.0), float(rmse / bound))
            squares.setdefault(name, []).append(float(rmse / bound) ** 2)
        summary[cross] = {
            "rmse_over_crlb_max": efficiency,
            "rmse_over_crlb_kind": {k: float(np.sqrt(np.mean(v))) for k, v in squares.items()},
            "runs": len(good), "errors": len(records) - len(good),
            "seconds": float(np.mean([r["seconds"] for r in records])) if records else 0.0,
            "kinds": kinds,
            "runs_warned": sum(1 for r in good if r["warnings"]),
        }
    return summary


def summarise_order(runs: list[dict]) -> dict:
    keys = [f"{cross} {a}" for a in ("adsb", "no-adsb") for cross in FORMULATIONS]
    summary = {}
    for key in keys:
        records = [r[key] for r in runs]
        good = [r for r in records if "max_diff_sigma" in r]
        worst = max(good, key=lambda r: r["max_diff_sigma"], default=None)
        summary[key] = {
            "runs": len(good), "errors": sum(1 for r in records if r["error"]),
            "seconds": float(np.mean([r["seconds"] for r in records])) if records else 0.0,
            "max_diff_sigma": None if worst is None else worst["max_diff_sigma"],
            "at": None if worst is None else worst["at"],
            "per_seed": [r.get("max_diff_sigma") for r in records],
        }
    return summary


def _fmt(stats: dict) -> str:
    if not stats.get("n"):
        return "-"
    return (f"{stats['mean']:+.2f} / {stats['var']:.2f} / {stats['max_abs']:.1f}"
            f" ({stats['beyond_3']}/{stats['n']})")


def table(summary: dict[str, dict]) -> str:
    extra = sorted({k for s in summary.values() for f in s.values() for k in f["kinds"]}
                   - set(KINDS) - {"all"})
    columns = [*KINDS, *extra, "all"]
    lines = ["z = (estimate - truth) / sigma: mean z / var z / max |z| (count |z| > 3 / n)",
             "",
             "| case | formulation | runs | errors | s/run | " + " | ".join(columns) + " |",
             "|---|---|---|---|---|" + "---|" * len(columns)]
    for case, per in summary.items():
        for cross, s in per.items():
            cells = " | ".join(_fmt(s["kinds"].get(k, {})) for k in columns)
            lines.append(f"| {case} | {cross} | {s['runs']} | {s['errors']} | "
                         f"{s['seconds']:.1f} | {cells} |")
    lines += ["", "RMSE / sqrt(CRLB) over the seeds (the trajectory model's own bound), per "
              "kind: over its parameters (root mean square) / the largest parameter", ""]
    for case, per in summary.items():
        for cross, s in per.items():
            ratios = s.get("rmse_over_crlb_max") or {}
            kinds = s.get("rmse_over_crlb_kind") or {}
            if ratios:
                lines.append(f"- {case}, {cross}: " + ", ".join(
                    f"{k} {kinds[k]:.2f} / {v:.2f}" for k, v in ratios.items()))
    return "\n".join(lines)


def order_table(summary: dict) -> str:
    lines = ["order: demo_network, radars in file order vs reversed; largest "
             "|estimate difference| / sigma over every parameter",
             "",
             "| ADS-B | formulation | runs | errors | s/run | max abs diff / sigma | at "
             "| per seed |",
             "|---|---|---|---|---|---|---|---|"]
    for key, s in summary.items():
        cross, adsb = key.split(" ")
        value = "-" if s["max_diff_sigma"] is None else f"{s['max_diff_sigma']:.2g}"
        seeds = ", ".join("-" if v is None else f"{v:.2g}" for v in s["per_seed"])
        lines.append(f"| {'yes' if adsb == 'adsb' else 'no'} | {cross} | {s['runs']} | "
                     f"{s['errors']} | {s['seconds']:.1f} | {value} | {s['at'] or '-'} | "
                     f"{seeds} |")
    return "\n".join(lines)


def _cases(text: str) -> list[str]:
    cases = [c.strip() for c in text.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        raise argparse.ArgumentTypeError(
            f"unknown case(s) {', '.join(unknown)}; choose from {', '.join(CASES)}")
    return cases


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=None,
                        help="seeds of every case (default: " + ", ".join(
                            f"{c} {n}" for c, n in CASES.items()) + ")")
    parser.add_argument("--cases", type=_cases, default=list(CASES),
                        help="comma-separated cases (default: all): " + ", ".join(CASES))
    parser.add_argument("--json", type=Path, help="write the runs and summaries here")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    runs: dict[str, list[dict]] = {}
    table = opensky_table()
    if not table.exists():
        skipped = [c for c in args.cases if c in OPENSKY_CASES]
        if skipped:
            print(f"OpenSky table not found ({table}): {', '.join(skipped)} skipped")
        args.cases = [c for c in args.cases if c not in OPENSKY_CASES]
    for case in args.cases:
        runs[case] = []
        for seed in range(1, (args.seeds or CASES[case]) + 1):
            if case == "order":
                result = run_order(seed)
                note = ", ".join(f"{k} {v.get('max_diff_sigma', float('nan')):.2g}"
                                 for k, v in result.items() if isinstance(v, dict))
            else:
                result = run(case, seed)
                note = ", ".join(
                    f"{cross} {result[cross]['seconds']:.1f} s"
                    + (f" ERROR {result[cross]['error']}" if result[cross]["error"] else "")
                    + (f" ({len(result[cross]['warnings'])} warnings)"
                       if result[cross].get("warnings") else "")
                    for cross in FORMULATIONS)
            runs[case].append(result)
            print(f"{case} seed {seed}: {note}", flush=True)
    summary = {case: summarise(r) for case, r in runs.items() if case != "order"}
    if summary:
        print()
        print(table(summary))
    errors = [(case, r["seed"], cross, r[cross]["error"]) for case, rs in runs.items()
              if case != "order" for r in rs for cross in FORMULATIONS if r[cross]["error"]]
    for case, seed, cross, error in errors:
        print(f"error: {case} seed {seed} {cross}: {error}")
    order = summarise_order(runs["order"]) if "order" in runs else None
    if order is not None:
        print()
        print(order_table(order))
    print(f"\ntotal {time.perf_counter() - start:.0f} s")
    if args.json is not None:
        args.json.write_text(json.dumps({"summary": summary, "order": order, "runs": runs},
                                        indent=1) + "\n")


if __name__ == "__main__":
    main()

"""Model checks study: false alarms on data the model fits, detections on data it does not.

Run from the repository root::

    .venv/bin/python -m benchmarks.model_checks_study [--seeds 100] [--cross-seeds 40]
        [--detect-seeds 10] [--jobs 2]

Part 1 - false alarms.  Data simulated with graphcal's own model (straight rays,
geometric heights, constant biases), calibrated, then checked
(:func:`graphcal.analysis.model_checks.model_checks`); every warning is a false
alarm.  Cases: ``scenarios/demo_network.toml`` (five radars) by ``graph`` with
ADS-B (``--seeds``) and without (``--cross-seeds``); paper 001 paths 1 and 2
(two 3-D radars, no ADS-B) and the crowded synthetic network of
``tests/synthetic.py`` (no ADS-B) by ``graph``; paper 003 (one 2-D radar, ADS-B)
by ``fl-ls``.  Reported: radars checked, radars with a warning (the false-alarm
rate, with a 95 % Clopper-Pearson interval), tests made, and the share of
tests with p below 0.05, 0.01 and 0.001 (a calibrated test gives those shares).

Part 2 - detections.  The demo network (``--detect-seeds`` seeds) with one
unmodelled effect added to one radar's plots, from the simulation's true
geometry, then calibrated by ``graph`` with ADS-B:

* ``eccentricity``: NORD azimuth ``+ 1.0 sin(az) + 0.5 cos(az)`` mrad;
* ``refraction-elevation``: EST3D elevation ``+ 2 exp(-el / 2 deg)`` mrad;
* ``refraction-range``: OUEST3D range ``+ 40 (r / 100 km)^2`` m;
* ``step``: SUD range ``+ 60`` m after t = 900 s;
* ``pressure-altitude``: APP's reported altitude ``0.97 h - 60`` m (Mode C, 25 ft).

Reported per case: the share of seeds where that radar's warning names the
right cause, and the warnings on the other radars.  Also
``scenarios/demo_v2.toml`` (refraction at every radar, pressure altitudes,
NORD's eccentric antenna): declared as the scenario does, among the false-alarm
cases; read as version 1 (straight rays, geometric altitudes, no eccentricity
term), the radars whose warning names refraction (3-D) or pressure altitudes
(2-D).

Part 3 - time: the checks' share of ``graphcal.calibrate`` on the demo network
(seed 1), with and without ADS-B.

Outputs: tables on stdout, ``benchmarks/results/model_checks_study.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from graphcal.analysis.model_checks import model_checks
from graphcal.core.atomic import atomic_write_text
from graphcal.data.dataset import Dataset
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.registry import calibrate
from tests.synthetic import crowded_network

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SCENARIOS = ROOT / "scenarios"

#: Injected effect -> (radar, word the warning must contain).
DETECTIONS: dict[str, tuple[str, str]] = {
    "eccentricity": ("NORD", "eccentricity"),
    "refraction-elevation": ("EST3D", "refraction"),
    "refraction-range": ("OUEST3D", "refraction"),
    "step": ("SUD", "drifting or stepping"),
    "pressure-altitude": ("APP", "pressure altitude"),
}


#: Each injected effect in words.
EFFECTS: dict[str, str] = {
    "eccentricity": "eccentricity: azimuth + 1.0 sin(az) + 0.5 cos(az) mrad",
    "refraction-elevation": "refraction: elevation + 2 exp(-el / 2 deg) mrad",
    "refraction-range": "refraction: range + 40 (r / 100 km)² m",
    "step": "range offset + 60 m after t = 900 s",
    "pressure-altitude": "Mode C altitude 0.97 h - 60 m",
}


#: Family false-alarm rates at which the radars' warning rate is also reported.
FAMILY_RATES: tuple[float, ...] = (0.01, 0.005, 0.002, 0.001)


# --------------------------------------------------------------------------- one run
def _summary(checks) -> dict:
    """Per radar: fired or not, the warning; per test: its p-value."""
    warnings = checks.warnings()
    return {
        "radars": {rid: {"fired": bool(r.fired) and r.explained_by is None,
                         "warning": next((w for w in warnings if w.startswith(f"{rid}:")), None),
                         "adjusted_p": _adjusted_p(r)}
                   for rid, r in checks.radars.items()},
        "p_values": [t.bins.p_value for r in checks.radars.values() for t in r.tests],
        "seconds": checks.seconds,
    }


def _adjusted_p(radar) -> float:
    """The radar's smallest p-value times its number of tests (Bonferroni): its checks
    fire at a family false-alarm rate above this (partner attribution aside)."""
    p = [t.bins.p_value for t in radar.tests]
    return min(1.0, min(p) * len(p)) if p else 1.0


def _scenario_run(name: str, seed: int, method: str, use_adsb: bool) -> dict:
    res = simulate(load_scenario(SCENARIOS / f"{name}.toml"), np.random.default_rng(seed))
    options = {"use_adsb": False} if method == "graph" and not use_adsb else {}
    cal = calibrate(res.dataset, method, **options)
    return _summary(model_checks(res.dataset, cal, use_adsb=use_adsb))


def _crowded_run(seed: int) -> dict:
    dataset, _ = crowded_network(np.random.default_rng(seed))
    return _summary(model_checks(dataset, calibrate(dataset, "graph"), use_adsb=False))


def inject(case: str, res) -> Dataset:
    """The simulated dataset with one unmodelled effect added (module doc), from the truth."""
    plots, truth = res.dataset.plots.copy(), res.plot_truth
    radar, _ = DETECTIONS[case]
    rows = (plots["radar_id"] == radar).to_numpy()
    az = np.deg2rad(truth["azimuth_true_deg"].to_numpy()[rows])
    el = np.deg2rad(truth["elevation_true_deg"].to_numpy()[rows])
    r = truth["range_true_m"].to_numpy()[rows]
    h = truth["height_true_m"].to_numpy()[rows]
    index = plots.index[rows]
    if case == "eccentricity":
        error = 1.0e-3 * np.sin(az) + 0.5e-3 * np.cos(az)
        plots.loc[index, "azimuth_deg"] = np.mod(plots.loc[index, "azimuth_deg"]
                                                 + np.rad2deg(error), 360.0)
    elif case == "refraction-elevation":
        plots.loc[index, "elevation_deg"] += np.rad2deg(2e-3 * np.exp(-el / np.deg2rad(2.0)))
    elif case == "refraction-range":
        plots.loc[index, "range_m"] += 40.0 * (r / 1e5) ** 2
    elif case == "step":
        late = plots.loc[index, "time_s"].to_numpy() > 900.0
        plots.loc[index[late], "range_m"] += 60.0
    elif case == "pressure-altitude":
        foot = 0.3048
        plots.loc[index, "altitude_m"] = np.round((0.97 * h - 60.0) / (25 * foot)) * 25 * foot
    return Dataset(res.dataset.sites, plots, res.dataset.adsb, None)


def _v2_run(seed: int, use_adsb: bool, declared: bool) -> dict:
    import dataclasses

    res = simulate(load_scenario(SCENARIOS / "demo_v2.toml"), np.random.default_rng(seed))
    dataset = res.dataset
    if not declared:
        sites = {rid: dataclasses.replace(
            site, refraction="none",
            estimate=tuple(e for e in site.estimate if e != "azimuth_eccentricity"))
            for rid, site in dataset.sites.items()}
        dataset = Dataset(sites, dataset.plots, dataset.adsb, None, plot_altitude="geometric")
    cal = calibrate(dataset, "graph", use_adsb=use_adsb)
    return _summary(model_checks(dataset, cal, use_adsb=use_adsb))


#: demo_v2 read as version 1: each radar and the word its warning should hold.
V2_CAUSES: dict[str, str] = {"NORD": "pressure altitude", "SUD": "pressure altitude",
                             "EST3D": "refraction", "OUEST3D": "refraction",
                             "APP": "pressure altitude"}


def v2_detections(runs: list[dict]) -> dict:
    named = {rid: int(sum(word in (run["radars"].get(rid, {}).get("warning") or "")
                          for run in runs)) for rid, word in V2_CAUSES.items()}
    return {"runs": len(runs), "named": named}


def _detection_run(case: str, seed: int) -> dict:
    res = simulate(load_scenario(SCENARIOS / "demo_network.toml"), np.random.default_rng(seed))
    dataset = inject(case, res)
    return _summary(model_checks(dataset, calibrate(dataset, "graph")))


def _timing() -> dict:
    import graphcal

    res = simulate(load_scenario(SCENARIOS / "demo_network.toml"), np.random.default_rng(1))
    out = {"n_plots": len(res.dataset.plots)}
    for adsb in (True, False):
        key = "adsb" if adsb else "cross"
        runs = []
        for _ in range(3):
            cal = graphcal.calibrate(res.dataset, use_adsb=adsb)
            runs.append((cal.info["timing_s"]["model_checks_s"], cal.info["timing_s"]["total_s"]))
        checks_s, total_s = np.median(np.array(runs), axis=0)
        out[key] = {"checks_s": float(checks_s), "calibrate_s": float(total_s)}
    return out


# --------------------------------------------------------------------------- summaries
def _interval(k: int, n: int) -> tuple[float, float]:
    """95 % Clopper-Pearson interval of a proportion ``k / n``."""
    from scipy import stats

    low = 0.0 if k == 0 else float(stats.beta.ppf(0.025, k, n - k + 1))
    high = 1.0 if k == n else float(stats.beta.ppf(0.975, k + 1, n - k))
    return low, high


def false_alarms(runs: list[dict]) -> dict:
    """Radars checked and warned about, and the test p-values' tail shares."""
    radars = [r for run in runs for r in run["radars"].values()]
    fired = sum(r["fired"] for r in radars)
    p = np.array([v for run in runs for v in run["p_values"]])
    low, high = _interval(fired, len(radars)) if radars else (0.0, 1.0)
    return {
        "runs": len(runs), "radars": len(radars), "radars_warned": int(fired),
        "rate": fired / len(radars) if radars else None, "rate_95": [low, high],
        "tests": int(p.size),
        "p_below": {str(a): float(np.mean(p < a)) if p.size else None
                    for a in (0.05, 0.01, 0.001)},
        "warnings": [r["warning"] for r in radars if r["fired"]],
        "rate_at": {str(a): float(np.mean([r["adjusted_p"] < a for r in radars]))
                    if radars else None for a in FAMILY_RATES},
        "seconds_median": float(np.median([run["seconds"] for run in runs])),
    }


def detections(case: str, runs: list[dict]) -> dict:
    radar, word = DETECTIONS[case]
    named = [word in (run["radars"].get(radar, {}).get("warning") or "") for run in runs]
    others = [r["warning"] for run in runs for rid, r in run["radars"].items()
              if rid != radar and r["fired"]]
    example = next((run["radars"][radar]["warning"] for run in runs
                    if run["radars"].get(radar, {}).get("warning")), None)
    weakest = max(run["radars"][radar]["adjusted_p"] for run in runs)
    return {"radar": radar, "word": word, "runs": len(runs), "named": int(sum(named)),
            "weakest_adjusted_p": weakest,
            "other_warnings": others, "example": example}


def markdown(result: dict, args) -> str:
    lines = ["# Model checks: false alarms and detections", "",
             f"`python -m benchmarks.model_checks_study --seeds {args.seeds} --cross-seeds "
             f"{args.cross_seeds} --detect-seeds {args.detect_seeds}`", "",
             "## False alarms on data the model fits", "",
             "<!-- --8<-- [start:false] -->",
             "| case | runs | radars | with a warning | rate (95 % interval) | tests | "
             "p < 0.05 | p < 0.01 | p < 0.001 |",
             "|---|---:|---:|---:|---|---:|---:|---:|---:|"]
    for name, fa in result["false_alarms"].items():
        rate = "–" if fa["rate"] is None else (
            f"{100 * fa['rate']:.2f} % ({100 * fa['rate_95'][0]:.2f}–"
            f"{100 * fa['rate_95'][1]:.2f} %)")
        shares = " | ".join("–" if v is None else f"{100 * v:.2f} %"
                            for v in fa["p_below"].values())
        lines.append(f"| {name} | {fa['runs']} | {fa['radars']} | {fa['radars_warned']} | "
                     f"{rate} | {fa['tests']} | {shares} |")
    total = result["total"]
    lines += ["", f"All cases: {total['radars_warned']} of {total['radars']} radars "
              f"({100 * total['rate']:.2f} %, 95 % interval {100 * total['rate_95'][0]:.2f}–"
              f"{100 * total['rate_95'][1]:.2f} %).", "",
              "Radars warned about at other family false-alarm rates (all cases; partner "
              "attribution without ADS-B ignored, so an upper bound): " + ", ".join(
                  f"{a}: {100 * v:.2f} %" for a, v in total.get("rate_at", {}).items()) + ".",
              "<!-- --8<-- [end:false] -->", "",
              "Warnings given:", ""]
    lines += [f"- {w}" for fa in result["false_alarms"].values() for w in fa["warnings"]]
    lines += ["", "## Detections (demo network, graph with ADS-B)", "",
              "<!-- --8<-- [start:detect] -->",
              "| effect added | radar | right cause named | warnings on other radars | "
              "weakest seed's adjusted p |",
              "|---|---|---:|---:|---:|"]
    for case, d in result["detections"].items():
        lines.append(f"| {EFFECTS[case]} | {d['radar']} | {d['named']} of {d['runs']} | "
                     f"{len(d['other_warnings'])} | "
                     f"{d.get('weakest_adjusted_p', float('nan')):.1e} |")
    v2 = result.get("v2_detections")
    if v2:
        lines += ["", f"demo_v2 read as version 1 ({v2['runs']} seeds), warnings naming the "
                  "right cause: " + ", ".join(
                      f"{rid} {v2['named'][rid]} ({V2_CAUSES[rid]})" for rid in V2_CAUSES) + "."]
    lines.append("<!-- --8<-- [end:detect] -->")
    lines += ["", "Examples (first seed):", ""]
    lines += [f"- {d['example']}" for d in result["detections"].values() if d["example"]]
    t = result["timing"]
    lines += ["", f"## Time (demo network, {t['n_plots']} plots, median of 3)", "",
              "| reference | checks [s] | whole calibrate [s] |", "|---|---:|---:|"]
    for key in ("adsb", "cross"):
        lines.append(f"| {key} | {t[key]['checks_s']:.2f} | {t[key]['calibrate_s']:.2f} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100,
                        help="demo network seeds with ADS-B (5 radars each)")
    parser.add_argument("--cross-seeds", type=int, default=40,
                        help="demo network seeds without ADS-B")
    parser.add_argument("--detect-seeds", type=int, default=10,
                        help="seeds per injected effect")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--markdown-only", action="store_true",
                        help="rewrite the .md from the existing .json, without running")
    args = parser.parse_args()
    start = time.perf_counter()
    if args.markdown_only:
        result = json.loads((RESULTS / "model_checks_study.json").read_text())
        for key, value in result.pop("arguments").items():
            setattr(args, key, value)
        atomic_write_text(RESULTS / "model_checks_study.md", markdown(result, args))
        print(f"wrote {RESULTS / 'model_checks_study.md'}")
        return 0
    jobs: dict[str, list] = {
        "demo network, graph, ADS-B": [
            (_scenario_run, "demo_network", s, "graph", True) for s in range(args.seeds)],
        "demo network, graph, no ADS-B": [
            (_scenario_run, "demo_network", s, "graph", False) for s in range(args.cross_seeds)],
        "paper 001 path 1, graph, no ADS-B": [
            (_scenario_run, "paper001_path1", s, "graph", False) for s in range(20)],
        "paper 001 path 2, graph, no ADS-B": [
            (_scenario_run, "paper001_path2", s, "graph", False) for s in range(20)],
        "paper 003, fl-ls, ADS-B": [
            (_scenario_run, "paper003_adsb_2d", s, "fl-ls", True) for s in range(20)],
        "crowded synthetic network, graph, no ADS-B": [
            (_crowded_run, s) for s in range(20)],
        "demo v2 declared, graph, ADS-B": [(_v2_run, s, True, True) for s in range(20)],
        "demo v2 declared, graph, no ADS-B": [(_v2_run, s, False, True) for s in range(10)],
    }
    for case in DETECTIONS:
        jobs[f"detect {case}"] = [(_detection_run, case, s) for s in range(args.detect_seeds)]
    jobs["detect v2"] = [(_v2_run, s, True, False) for s in range(args.detect_seeds)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = {name: [pool.submit(*job) for job in todo] for name, todo in jobs.items()}
        runs = {name: [f.result() for f in fs] for name, fs in futures.items()}
        timing = pool.submit(_timing).result()
    result = {
        "false_alarms": {name: false_alarms(r) for name, r in runs.items()
                         if not name.startswith("detect ")},
        "detections": {case: detections(case, runs[f"detect {case}"]) for case in DETECTIONS},
        "v2_detections": v2_detections(runs["detect v2"]),
        "timing": timing,
    }
    all_runs = [run for name, r in runs.items() if not name.startswith("detect ") for run in r]
    result["total"] = false_alarms(all_runs)
    text = markdown(result, args)
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    atomic_write_text(RESULTS / "model_checks_study.md", text)
    atomic_write_text(RESULTS / "model_checks_study.json", json.dumps(
        {"arguments": vars(args), **result}, indent=2) + "\n")
    print(f"wrote {RESULTS / 'model_checks_study.md'} in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

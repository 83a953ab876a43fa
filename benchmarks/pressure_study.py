"""Pressure altitudes: how well ``graph`` recovers the biases and the height model.

Usage: ``.venv/bin/python -m benchmarks.pressure_study [--seeds N] [--first S]``.

``scenarios/demo_pressure.toml`` (the demo network on a warm high-pressure day:
``h = 1.02 p + 185 m``) is simulated with seeds ``S .. S+N-1`` and calibrated by
``graph`` in five ways:

* ``adsb``: with ADS-B (every aircraft, ``alt_m`` and ``baro_alt_m``);
* ``half-adsb``: half the aircraft equipped (the others' 2-D plots are paired, so
  both the ADS-B height factor and the pairwise factors inform the height model);
* ``no-adsb``: cross-radar observations only;
* ``no-adsb, declared geometric``: the same data with ``plot_altitude`` declared
  ``"geometric"`` (the pressure altitudes taken as heights): the wrong model;
* ``adsb, no baro_alt_m``: ADS-B without its pressure altitudes: every plot is
  matched to ADS-B, nothing observes the height model, which must be reported as
  not determined.

Printed per case: the normalised error variance (mean ``z^2``, ``z`` = error /
reported sigma) over all radar terms and over the height model, the largest
``|z|``, the height model's mean estimate and sigma, and the run time; for the
first seed also sigma / CRLB.  The table is also written to
``benchmarks/results/pressure_study.md``.  The unit tests
(``tests/solvers/test_pressure.py``) check a few seeds of the same cases.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from graphcal.data.bias import CONTRACT_KEYS
from graphcal.pipeline.calibrate import calibrate
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "demo_pressure.toml"
RESULTS = ROOT / "benchmarks" / "results" / "pressure_study.md"
CASES = ("adsb", "half-adsb", "no-adsb", "no-adsb, declared geometric", "adsb, no baro_alt_m")


def _z_scores(cal, biases, height) -> tuple[list[float], list[float]]:
    """Errors over reported sigmas: radar terms, then the height model (when estimated)."""
    radar = [
        (cal.estimate[i] - biases[rid].value(name)) * CONTRACT_KEYS[name][1]
        / cal.sigma(rid, CONTRACT_KEYS[name][0])
        for i, (rid, name) in enumerate(cal.labels)
    ]
    atmosphere = []
    if cal.atmosphere is not None and cal.atmosphere.determined:
        sigma = cal.atmosphere.sigma
        atmosphere = [(cal.atmosphere.height_offset_m - height.height_offset_m)
                      / sigma["height_offset_m"],
                      (cal.atmosphere.height_scale - height.height_scale) / sigma["height_scale"]]
    return radar, atmosphere


def _case(name: str, run, half_run):
    """Dataset and calibrate options of a case."""
    ds = run.dataset
    if name == "adsb":
        return ds, {}
    if name == "half-adsb":
        return half_run.dataset, {}
    if name == "no-adsb":
        return ds, {"use_adsb": False}
    if name == "no-adsb, declared geometric":
        return dataclasses.replace(ds, plot_altitude="geometric"), {"use_adsb": False}
    return dataclasses.replace(ds, adsb=ds.adsb.drop(columns="baro_alt_m")), {}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--first", type=int, default=1)
    args = parser.parse_args()
    scenario = load_scenario(SCENARIO)
    half = dataclasses.replace(scenario,
                               adsb=dataclasses.replace(scenario.adsb, equipped_fraction=0.5))
    height = scenario.height_model
    stats = {case: {"radar": [], "atmosphere": [], "offset": [], "scale": [], "sigma": [],
                    "seconds": [], "determined": 0, "efficiency": None} for case in CASES}
    for seed in range(args.first, args.first + args.seeds):
        run = simulate(scenario, np.random.default_rng(seed))
        half_run = simulate(half, np.random.default_rng(seed))
        for case in CASES:
            dataset, options = _case(case, run, half_run)
            t0 = time.perf_counter()
            cal = calibrate(dataset, bound=seed == args.first, **options)
            entry = stats[case]
            entry["seconds"].append(time.perf_counter() - t0)
            radar, atmosphere = _z_scores(cal, run.biases, height)
            entry["radar"] += radar
            entry["atmosphere"] += atmosphere
            if cal.atmosphere is not None:
                entry["determined"] += int(cal.atmosphere.determined)
                entry["offset"].append(cal.atmosphere.height_offset_m)
                entry["scale"].append(cal.atmosphere.height_scale)
                entry["sigma"].append((cal.atmosphere.sigma["height_offset_m"],
                                       cal.atmosphere.sigma["height_scale"]))
            if seed == args.first:
                entry["efficiency"] = {k: v for k, v in cal.info.get("efficiency", {}).items()
                                       if v is not None}
        print(f"seed {seed} done", flush=True)
    lines = [
        f"demo_pressure, true height model: offset {height.height_offset_m:g} m, "
        f"scale {height.height_scale:g}; seeds {args.first}-{args.first + args.seeds - 1}",
        "",
        "| case | NEV radar terms | max \\|z\\| | NEV height model | determined | "
        "height_offset_m (mean ± σ) | height_scale (mean ± σ) | σ/CRLB (first seed) | s/run |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for case in CASES:
        entry = stats[case]
        radar = np.asarray(entry["radar"])
        atmosphere = np.asarray(entry["atmosphere"])
        nev_h = f"{np.mean(atmosphere**2):.2f}" if atmosphere.size else "-"
        if entry["offset"]:
            sigma = np.mean(entry["sigma"], axis=0)
            offset = f"{np.mean(entry['offset']):.1f} ± {sigma[0]:.2f}"
            scale = f"{np.mean(entry['scale']):.5f} ± {sigma[1]:.5f}"
        else:
            offset = scale = "-"
        eff = entry["efficiency"] or {}
        low, high = (min(eff, key=eff.get), max(eff, key=eff.get)) if eff else (None, None)
        efficiency = (f"{eff[low]:.2f} ({low}) - {eff[high]:.2f} ({high})" if eff else "-")
        determined = f"{entry['determined']}/{args.seeds}" if entry["offset"] else "-"
        lines.append(
            f"| {case} | {np.mean(radar**2):.2f} | {np.max(np.abs(radar)):.1f} | {nev_h} | "
            f"{determined} | {offset} | {scale} | {efficiency} | "
            f"{np.mean(entry['seconds']):.1f} |")
    text = "\n".join(lines) + "\n"
    print("\n" + text)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)


if __name__ == "__main__":
    main()

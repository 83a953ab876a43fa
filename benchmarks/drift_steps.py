"""Biases over time: drifting and stepping radars calibrated in 30-minute windows.

The demo network flown for several hours with continuous traffic: NORD's azimuth and
range offset drift linearly, EST3D's elevation drifts, SUD's range offset steps by
60 m at a random time (one per seed); OUEST3D and APP are constant.  Each seed is
calibrated with ``calibrate(..., window="30min")`` (the graph per window, chained,
rates estimated, steps searched for) and judged against the simulation's truth:

* every window estimate against the truth averaged over that window (z = error /
  sigma): the share within 3 sigma (target at least 95 %) and the mean z^2;
* the step: found, and placed within one window of its true time;
* no event on the constant radars (and none on the drifting ones).

Run ``python -m benchmarks.drift_steps [--seeds N] [--hours H] [--no-adsb]``; it
prints one line per seed and the totals, and writes ``benchmarks/results/
drift_steps.json``.
"""

from __future__ import annotations

import argparse
import json
import time
import tomllib
from pathlib import Path

import numpy as np

from benchmarks import RESULTS
from graphcal.data.bias import CONTRACT_KEYS, NAME_FROM_KEY
from graphcal.pipeline.calibrate import calibrate
from graphcal.simulation.scenario import parse_scenario
from graphcal.simulation.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]

#: The step's size [m] and the drifts per hour.
STEP_M = 60.0
DRIFTS = {"NORD": {"azimuth_bias_mrad_per_h": 0.5, "range_offset_m_per_h": 10.0},
          "EST3D": {"elevation_bias_mrad_per_h": 0.3}}
CONSTANT = ("OUEST3D", "APP")


def scenario(hours: float, rng: np.random.Generator):
    """The demo network for ``hours`` with drifts and one step at a random time."""
    with open(ROOT / "scenarios" / "demo_network.toml", "rb") as f:
        doc = tomllib.load(f)
    duration = hours * 3600.0
    doc["scenario"]["duration_s"] = duration
    # About 40 aircraft airborne at any time, all through the recording.
    doc["traffic"]["n_aircraft"] = int(40 * hours / 0.6)
    doc["traffic"]["start_time_s"] = [0.0, duration - 1800.0]
    step_time = float(rng.uniform(0.25, 0.75) * duration)
    for radar in doc["radar"]:
        if radar["id"] in DRIFTS:
            radar["drift"] = dict(DRIFTS[radar["id"]])
        if radar["id"] == "SUD":
            radar["step"] = [{"time_s": step_time, "range_offset_m": STEP_M}]
    return parse_scenario(doc), step_time


def judge(sc, cal, step_time: float, window_s: float) -> dict:
    """z of every window estimate, the step's placement, events elsewhere."""
    z, outliers = [], []
    for radar in sc.radars:
        for entry in cal.series["radars"].get(radar.id, []):
            truth = radar.schedule.mean(entry["t_start_s"], entry["t_end_s"])
            for key, sigma in entry["sigma"].items():
                name = NAME_FROM_KEY[key]
                value = entry[key]
                z.append((value - truth.value(name) * CONTRACT_KEYS[name][1]) / sigma)
                if abs(z[-1]) > 4.0:
                    outliers.append(f"{radar.id} {entry['t_start_s']:.0f} s {key} "
                                    f"z {z[-1]:+.1f}")
    z = np.array(z)
    sud = [e for e in cal.events if e["radar_id"] == "SUD"]
    found = [e for e in sud if abs(e["time_s"] - step_time) <= window_s]
    others = [e for e in cal.events if e["radar_id"] != "SUD"]
    return {
        "n_estimates": len(z),
        "within_3_sigma": float(np.mean(np.abs(z) < 3.0)),
        "mean_z2": float(np.mean(z**2)),
        "max_abs_z": float(np.max(np.abs(z))),
        "step_found": bool(found),
        "step_time_error_s": float(found[0]["time_s"] - step_time) if found else None,
        "step_size_m": found[0]["size"].get("range_offset_m") if found else None,
        "step_sigma_m": found[0]["sigma"].get("range_offset_m") if found else None,
        "extra_sud_events": len(sud) - len(found),
        "events_on_constant": sum(e["radar_id"] in CONSTANT for e in others),
        "events_on_drifting": sum(e["radar_id"] in DRIFTS for e in others),
        "beyond_4_sigma": outliers,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--hours", type=float, default=6.0)
    parser.add_argument("--window", default="30min")
    parser.add_argument("--no-adsb", action="store_true")
    args = parser.parse_args(argv)
    window_s = {"30min": 1800.0}.get(args.window)
    if window_s is None:
        from graphcal.core.durations import parse_duration
        window_s = parse_duration(args.window)
    rows = []
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        sc, step_time = scenario(args.hours, rng)
        sim = simulate(sc, rng)
        t0 = time.perf_counter()
        cal = calibrate(sim.dataset, window=args.window, use_adsb=not args.no_adsb)
        row = {"seed": seed, "plots": len(sim.dataset.plots), "step_time_s": step_time,
               "seconds": time.perf_counter() - t0, **judge(sc, cal, step_time, window_s)}
        rows.append(row)
        print(f"seed {seed}: {row['plots']} plots, {row['seconds']:.1f} s; "
              f"{100 * row['within_3_sigma']:.1f} % within 3 sigma (mean z^2 "
              f"{row['mean_z2']:.2f}, max |z| {row['max_abs_z']:.1f}); step at "
              f"{step_time:.0f} s {'found' if row['step_found'] else 'MISSED'}"
              + (f" ({row['step_time_error_s']:+.0f} s, {row['step_size_m']:.1f} ± "
                 f"{row['step_sigma_m']:.1f} m)" if row["step_found"] else "")
              + f"; events on constant radars {row['events_on_constant']}, on drifting "
              f"{row['events_on_drifting']}, extra on SUD {row['extra_sud_events']}"
              + "".join(f"\n    beyond 4 sigma: {o}" for o in row["beyond_4_sigma"]),
              flush=True)
    n = sum(r["n_estimates"] for r in rows)
    within = sum(r["within_3_sigma"] * r["n_estimates"] for r in rows) / n
    summary = {
        "seeds": args.seeds, "hours": args.hours, "window": args.window,
        "adsb": not args.no_adsb,
        "within_3_sigma": within,
        "mean_z2": sum(r["mean_z2"] * r["n_estimates"] for r in rows) / n,
        "steps_found": sum(r["step_found"] for r in rows),
        "events_on_constant": sum(r["events_on_constant"] for r in rows),
        "events_on_drifting": sum(r["events_on_drifting"] for r in rows),
        "extra_sud_events": sum(r["extra_sud_events"] for r in rows),
        "rows": rows,
    }
    print(f"\n{args.seeds} seeds, {args.hours:g} h, {args.window} windows, "
          f"{'with' if summary['adsb'] else 'without'} ADS-B: {100 * within:.1f} % of {n} "
          f"window estimates within 3 sigma (target >= 95 %), mean z^2 "
          f"{summary['mean_z2']:.2f}; step found within one window in "
          f"{summary['steps_found']}/{args.seeds}; events on constant radars "
          f"{summary['events_on_constant']}, on drifting {summary['events_on_drifting']}, "
          f"extra on SUD {summary['extra_sud_events']}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    suffix = "" if summary["adsb"] else "_no_adsb"
    (RESULTS / f"drift_steps{suffix}.json").write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()

"""Association study: calibrating radars whose plots carry no address, against the truth.

Run from the repository root::

    .venv/bin/python -m benchmarks.association_study [--seeds N] [--json out.json]

``scenarios/demo_identity.toml`` is the demonstration network with two primary 3-D
radars (EST3D, with 8 false plots per scan and its own track numbers, and OUEST3D), a
Mode A/C SSR (SUD) and two Mode S radars (NORD, APP); 80 % of the aircraft broadcast
ADS-B.  The plots of EST3D, OUEST3D and SUD have an empty ``target_id``, so
:func:`graphcal.calibrate` associates them with the known aircraft
(:mod:`graphcal.pipeline.associate`) before and between its calibrations.

For every seed ``1 .. N`` and for ``use_adsb`` True and False, the simulated dataset is
calibrated twice with ``graphcal.calibrate(ds, use_adsb=..., model_checks=False,
check_fit=False, bound=False)`` (the whole call timed with ``time.perf_counter``):

* **associated**: the dataset as simulated (plots without address, clutter included);
* **addressed**: the same plots with ``target_id`` restored from the simulation's plot
  truth (``plot_truth["truth_target_id"]``) and the clutter dropped: what the
  calibration would get with a perfect association.

**Association score.**  The association is re-run at the associated calibration's final
biases and their covariance (:func:`graphcal.tracking.association.associate`, the gates
widened as the pipeline widens them) and compared plot by plot with the truth: per radar,
``correct`` (associated with the aircraft that made the plot), ``wrong`` (with another
aircraft), ``clutter in`` (a false plot associated), ``left out`` (a real plot not
associated) and ``ambiguous`` (a real plot left out as ambiguous; included in
``left out``); ``clutter ambiguous`` counts the false plots found ambiguous.

**Parameters.**  For every estimated ``range_offset_m``, ``range_gain``,
``azimuth_bias_mrad``, ``elevation_bias_mrad`` and ``time_offset_s`` of every radar,
``z = (estimate - truth) / sigma`` in both runs, and the sigma ratio associated /
addressed (the price of not knowing which aircraft made a plot; the primary radars'
ratio is reported, and the Mode A/C radar's).  A radar counts as calibrated when it is in
the result with estimated terms and no "not calibrated" warning.

The table gives per ``use_adsb``: the association counts summed over seeds and radars,
mean z / var z (mean z², the normalised error variance) per parameter kind over every
radar and seed for both runs, the largest |z| (with its seed and radar) and the count of
|z| > 3, the sigma ratios (mean, max), whether every radar was calibrated in every run,
and the median time ratio associated / addressed.  One seed takes about 10-15 s on a
2-core machine (four calibrations and one association).

Prints the table; writes JSON (summaries and every run's counts, estimates, sigmas and
truths) only to the path given with ``--json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import traceback
from pathlib import Path

import numpy as np
import pandas as pd

import graphcal
from graphcal.data.dataset import Dataset
from graphcal.pipeline.associate import gate_covariances
from graphcal.simulation.simulate import CLUTTER, SimulationResult
from graphcal.tracking.association import AMBIGUOUS, ASSOCIATED, associate

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "demo_identity.toml"

#: Contract keys reported, in table order, and the truth's value of each in its unit.
KEYS: tuple[str, ...] = ("range_offset_m", "range_gain", "azimuth_bias_mrad",
                         "elevation_bias_mrad", "time_offset_s")
TRUTH = {
    "range_offset_m": lambda b: b.range_offset_m,
    "range_gain": lambda b: b.range_gain,
    "azimuth_bias_mrad": lambda b: b.azimuth_bias_rad * 1e3,
    "elevation_bias_mrad": lambda b: b.elevation_bias_rad * 1e3,
    "time_offset_s": lambda b: b.time_offset_s,
}
#: The two calibrations of one dataset.
RUNS: tuple[str, ...] = ("associated", "addressed")
#: Association counts, in table order.
COUNTS: tuple[str, ...] = ("correct", "wrong", "clutter_in", "left_out", "ambiguous",
                           "clutter_ambiguous")


def addressed(sim: SimulationResult) -> Dataset:
    """The simulated plots with ``target_id`` from the truth, the clutter dropped."""
    truth = sim.plot_truth["truth_target_id"].astype(str).to_numpy()
    plots = sim.dataset.plots.copy()
    plots["target_id"] = truth
    plots = plots.loc[truth != CLUTTER].reset_index(drop=True)
    return dataclasses.replace(sim.dataset, plots=plots)


def calibrate(dataset: Dataset, use_adsb: bool) -> tuple[object | None, dict]:
    """``graphcal.calibrate`` on the dataset, timed: the Calibration (None if it raised)
    and the run record."""
    t0 = time.perf_counter()
    try:
        cal = graphcal.calibrate(dataset, use_adsb=use_adsb, model_checks=False,
                                 check_fit=False, bound=False)
    except Exception as exc:  # noqa: BLE001 - a study reports errors, it does not stop
        return None, {"seconds": time.perf_counter() - t0,
                      "error": f"{type(exc).__name__}: {exc}",
                      "traceback": traceback.format_exc()}
    return cal, {"seconds": time.perf_counter() - t0, "error": None,
                 "warnings": list(cal.warnings)}


def calibrated(cal, radar_ids: list[str]) -> dict[str, bool]:
    """Per radar: in the result with estimated terms and no "not calibrated" warning."""
    out = {}
    for rid in radar_ids:
        ok = cal is not None and rid in cal.radar_ids and any(
            r == rid for r, _ in cal.labels)
        if ok and any(w.startswith(f"{rid}:") and "not calibrated" in w
                      for w in cal.warnings):
            ok = False
        out[rid] = bool(ok)
    return out


def parameters(cal, sim: SimulationResult) -> list[dict]:
    """Estimate, sigma, truth and z of every reported key of every radar."""
    params = []
    for rid in cal.radar_ids:
        for key in KEYS:
            sigma = cal.sigma(rid, key)
            if sigma is None:  # not estimated
                continue
            estimate = float(cal.value(rid, key))
            truth = float(TRUTH[key](sim.truth[rid]))
            z = (estimate - truth) / sigma if sigma > 0 and np.isfinite(sigma) else float("nan")
            params.append({"radar": rid, "key": key, "estimate": estimate, "sigma": sigma,
                           "truth": truth, "z": z})
    return params


def score(sim: SimulationResult, cal, use_adsb: bool) -> dict[str, dict[str, int]]:
    """Re-associate at the calibration's biases and count per radar against the truth."""
    dataset = sim.dataset
    biases = {rid: cal.bias(rid) for rid in cal.radar_ids}
    association = associate(dataset, biases, gate_covariances(cal), use_adsb=use_adsb)
    truth = sim.plot_truth["truth_target_id"].astype(str)
    truth.index = dataset.plots.index  # row-aligned with the plots
    radar = dataset.plots["radar_id"].astype(str)
    out: dict[str, dict[str, int]] = {}
    index = association.status.index
    status = association.status.to_numpy()
    given = association.target_id.reindex(index).astype(str).to_numpy()
    true = truth.reindex(index).to_numpy()
    rids = radar.reindex(index).to_numpy()
    for rid in association.radars:
        sel = rids == rid
        st, gv, tr = status[sel], given[sel], true[sel]
        real = tr != CLUTTER
        assoc = st == ASSOCIATED
        out[rid] = {
            "plots": int(sel.sum()),
            "correct": int(np.sum(assoc & real & (gv == tr))),
            "wrong": int(np.sum(assoc & real & (gv != tr))),
            "clutter_in": int(np.sum(assoc & ~real)),
            "left_out": int(np.sum(~assoc & real)),
            "ambiguous": int(np.sum((st == AMBIGUOUS) & real)),
            "clutter_ambiguous": int(np.sum((st == AMBIGUOUS) & ~real)),
            "clutter": int(np.sum(~real)),
        }
    return out


def run(seed: int, scenario) -> dict:
    """One seed: both ADS-B settings, the two calibrations each, the score and z."""
    sim = graphcal.simulate(scenario, seed=seed)
    full = addressed(sim)
    radar_ids = list(sim.dataset.sites)
    out: dict = {"seed": seed, "plots": len(sim.dataset.plots),
                 "clutter": int((sim.plot_truth["truth_target_id"] == CLUTTER).sum())}
    for use_adsb in (True, False):
        record: dict = {}
        for name, dataset in (("associated", sim.dataset), ("addressed", full)):
            cal, rec = calibrate(dataset, use_adsb)
            rec["calibrated"] = calibrated(cal, radar_ids)
            if cal is not None:
                rec["parameters"] = parameters(cal, sim)
                if name == "associated":
                    rec["association_info"] = cal.info.get("association")
                    rec["score"] = score(sim, cal, use_adsb)
            record[name] = rec
        out["adsb" if use_adsb else "no-adsb"] = record
    return out


def _z_stats(z: list[float]) -> dict:
    a = np.asarray([v for v in z if np.isfinite(v)], dtype=float)
    if not len(a):
        return {"n": 0}
    return {"n": int(len(a)), "mean": float(a.mean()), "var": float(np.mean(a**2)),
            "max_abs": float(np.max(np.abs(a))), "beyond_3": int(np.sum(np.abs(a) > 3))}


def summarise(runs: list[dict], setting: str, identities: dict[str, str]) -> dict:
    """One ADS-B setting over the seeds (module docstring)."""
    counts = dict.fromkeys(COUNTS, 0)
    per_radar: dict[str, dict[str, int]] = {}
    for r in runs:
        for rid, c in r[setting]["associated"].get("score", {}).items():
            for k in COUNTS:
                counts[k] += c[k]
            acc = per_radar.setdefault(rid, dict.fromkeys((*COUNTS, "plots", "clutter"), 0))
            for k in acc:
                acc[k] += c[k]
    out: dict = {"counts": counts, "counts_per_radar": per_radar}
    for name in RUNS:
        records = [r[setting][name] for r in runs]
        params = [(r["seed"], p) for r in runs for p in r[setting][name].get("parameters", [])]
        kinds = {key: _z_stats([p["z"] for _, p in params if p["key"] == key]) for key in KEYS}
        kinds["all"] = _z_stats([p["z"] for _, p in params])
        worst = max(params, key=lambda sp: abs(sp[1]["z"]) if np.isfinite(sp[1]["z"]) else -1,
                    default=None)
        out[name] = {
            "errors": sum(1 for rec in records if rec["error"]),
            "seconds_mean": float(np.mean([rec["seconds"] for rec in records])),
            "kinds": kinds,
            "max_abs_z_at": None if worst is None else {
                "seed": worst[0], "radar": worst[1]["radar"], "key": worst[1]["key"],
                "z": worst[1]["z"]},
            "beyond_3": [{"seed": s, "radar": p["radar"], "key": p["key"], "z": p["z"]}
                         for s, p in params if abs(p["z"]) > 3],
            "not_calibrated": [{"seed": r["seed"], "radar": rid}
                               for r in runs for rid, ok in r[setting][name]["calibrated"].items()
                               if not ok],
        }
    ratios: dict[str, list[float]] = {}
    for r in runs:
        a = {(p["radar"], p["key"]): p["sigma"]
             for p in r[setting]["associated"].get("parameters", [])}
        b = {(p["radar"], p["key"]): p["sigma"]
             for p in r[setting]["addressed"].get("parameters", [])}
        for label in a.keys() & b.keys():
            ratios.setdefault(identities[label[0]], []).append(a[label] / b[label])
    out["sigma_ratio"] = {ident: {"mean": float(np.mean(v)), "max": float(np.max(v)),
                                  "min": float(np.min(v)), "n": len(v)}
                          for ident, v in ratios.items()}
    times = [r[setting]["associated"]["seconds"] / r[setting]["addressed"]["seconds"]
             for r in runs]
    out["time_ratio_median"] = float(np.median(times))
    out["time_ratio"] = times
    out["all_calibrated"] = not out["associated"]["not_calibrated"] and not out[
        "addressed"]["not_calibrated"]
    return out


def _fmt(stats: dict) -> str:
    if not stats.get("n"):
        return "-"
    return f"{stats['mean']:+.2f} / {stats['var']:.2f}"


def table(summary: dict[str, dict], seeds: int) -> str:
    lines = [f"demo_identity, seeds 1-{seeds}", "",
             "Association at the final biases, summed over seeds and radars "
             "(ambiguous: real plots, included in left out)", "",
             "| ADS-B | correct | wrong | clutter in | left out | ambiguous | "
             "clutter ambiguous |",
             "|---|---|---|---|---|---|---|"]
    for setting, s in summary.items():
        c = s["counts"]
        lines.append(f"| {'yes' if setting == 'adsb' else 'no'} | " + " | ".join(
            f"{c[k]:,}" for k in COUNTS) + " |")
    columns = [*KEYS, "all"]
    lines += ["", "z = (estimate - truth) / sigma: mean z / var z (mean z²), over every "
              "radar and seed", "",
              "| ADS-B | run | " + " | ".join(columns) + " | max abs z | abs z > 3 | "
              "errors | s/run |",
              "|---|---|" + "---|" * len(columns) + "---|---|---|---|"]
    for setting, s in summary.items():
        for name in RUNS:
            r = s[name]
            cells = " | ".join(_fmt(r["kinds"].get(k, {})) for k in columns)
            at = r["max_abs_z_at"]
            worst = "-" if at is None else (f"{abs(at['z']):.2f} (seed {at['seed']}, "
                                           f"{at['radar']} {at['key']})")
            lines.append(f"| {'yes' if setting == 'adsb' else 'no'} | {name} | {cells} | "
                         f"{worst} | {r['kinds']['all'].get('beyond_3', 0)}/"
                         f"{r['kinds']['all'].get('n', 0)} | {r['errors']} | "
                         f"{r['seconds_mean']:.1f} |")
    lines += ["", "| ADS-B | sigma ratio primary (mean, max) | sigma ratio Mode A/C "
              "(mean, max) | every radar calibrated | median time ratio |",
              "|---|---|---|---|---|"]
    for setting, s in summary.items():
        def ratio(ident: str, s: dict = s) -> str:
            r = s["sigma_ratio"].get(ident)
            return "-" if r is None else f"{r['mean']:.3f}, {r['max']:.3f}"
        lines.append(f"| {'yes' if setting == 'adsb' else 'no'} | {ratio('psr')} | "
                     f"{ratio('mode_ac')} | {'yes' if s['all_calibrated'] else 'no'} | "
                     f"{s['time_ratio_median']:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="seeds 1 .. N (default 5)")
    parser.add_argument("--json", type=Path, help="write the runs and summaries here")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    scenario = graphcal.load_scenario(SCENARIO)
    identities = {r.id: r.identity for r in scenario.radars}
    runs = []
    for seed in range(1, args.seeds + 1):
        result = run(seed, scenario)
        runs.append(result)
        note = "; ".join(
            f"{setting} " + ", ".join(
                f"{name} {result[setting][name]['seconds']:.1f} s"
                + (f" ERROR {result[setting][name]['error']}"
                   if result[setting][name]["error"] else "")
                for name in RUNS)
            for setting in ("adsb", "no-adsb"))
        print(f"seed {seed}: {note}", flush=True)
    summary = {setting: summarise(runs, setting, identities)
               for setting in ("adsb", "no-adsb")}
    print()
    print(table(summary, args.seeds))
    for setting, s in summary.items():
        for name in RUNS:
            for item in s[name]["not_calibrated"]:
                print(f"not calibrated: {setting} {name} seed {item['seed']} {item['radar']}")
            for item in s[name]["beyond_3"]:
                print(f"|z| > 3: {setting} {name} seed {item['seed']} {item['radar']} "
                      f"{item['key']} z = {item['z']:+.2f}")
    errors = [(r["seed"], setting, name, r[setting][name]["error"]) for r in runs
              for setting in ("adsb", "no-adsb") for name in RUNS
              if r[setting][name]["error"]]
    for seed, setting, name, error in errors:
        print(f"error: seed {seed} {setting} {name}: {error}")
    print(f"\ntotal {time.perf_counter() - start:.0f} s")
    if args.json is not None:
        args.json.write_text(json.dumps({"scenario": "scenarios/demo_identity.toml",
                                         "seeds": args.seeds, "summary": summary,
                                         "runs": runs}, indent=1, default=_plain) + "\n")


def _plain(value: object) -> object:
    """numpy and pandas scalars in the JSON."""
    if isinstance(value, np.generic):
        return value.item()
    if value is pd.NA or value is None:
        return None
    raise TypeError(type(value).__name__)


if __name__ == "__main__":
    main()

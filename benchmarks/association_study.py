"""Association study: calibrating radars whose plots carry no address, against the truth.

Run from the repository root::

    .venv/bin/python -m benchmarks.association_study [--seeds N] [--network NAME] [--json out.json]

``--network`` is ``demo_identity`` (the default), ``uncovered``, ``opensky_identity``,
``both`` (``demo_identity`` and ``uncovered``) or ``all`` (the three).

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

**Real traffic** (``--network opensky_identity``) is the same study on
``scenarios/opensky_identity.toml``: the four-radar network (EST3D primary 3-D with 8 false
plots per scan, OUEST3D primary 3-D with its own track numbers, SUD Mode A/C, NORD Mode S;
80 % ADS-B equipage, Mode 3/A codes) on the real trajectories of the shared OpenSky table
(``../shared/data`` from the repository root, as the scenario says).  The seeds draw
different noise, ADS-B equipage, codes and clutter, but the trajectories are the same in
every seed.  One seed takes about 5 s on a 2-core machine.

**The uncovered network** (``--network uncovered``) is the network of
``tests/tracking/test_own_paths.py``: for seed ``s`` the same simulation without the two
Mode S radars (NORD and APP dropped from the sites and the plots) and with the ADS-B
reports of 40 % of the aircraft that broadcast it kept (8 to 18 of the 40 aircraft in seeds
1-10), chosen with ``np.random.default_rng(s + 2)`` (seed 1 is the test's network).  The
other aircraft are seen only by SUD, EST3D and OUEST3D: no reference covers them, and those
that two of these radars see get paths of their own (:mod:`graphcal.tracking.own_paths`).
Per seed, with ADS-B only, three calibrations: **associated** (as is), **addressed**
(``target_id`` from the truth, clutter dropped) and **no own paths**: associated with paths
of their own turned off, by replacing ``graphcal.tracking.association.find_own_paths`` with
``lambda sites, leftovers: {}`` for that calibration and its score only (the study's own
switch; the function is restored after).  The scores are those above, with the plots on
paths of their own (names starting with
:data:`~graphcal.tracking.own_paths.OWN_PATH_PREFIX`) counted apart from ``correct`` and
``wrong``: ``on own paths`` (``clutter in`` includes the false ones), of them ``of the
majority`` (the path's most frequent aircraft over all its radars: purity), ``clutter on
own`` and ``ADS-B aircraft on own`` (plots of an aircraft the ADS-B covers), and the
uncovered aircraft's real plots (``uncovered``) and how many of them were left out.  The
sigma ratios are against the addressed run, for both associated runs.  One seed takes about
5 s on a 2-core machine (three calibrations of three radars and two associations).

Prints the table; writes JSON (summaries and every run's counts, estimates, sigmas and
truths) only to the path given with ``--json`` (with ``--network both`` one object per
network; with ``--network all`` likewise).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd

import graphcal
import graphcal.tracking.association as association_module
from benchmarks.study_runs import timed_run
from graphcal.data.dataset import Dataset
from graphcal.pipeline.associate import gate_covariances
from graphcal.simulation.simulate import CLUTTER, SimulationResult
from graphcal.tracking.association import AMBIGUOUS, ASSOCIATED, associate
from graphcal.tracking.own_paths import OWN_PATH_PREFIX

ROOT = Path(__file__).resolve().parents[1]
NETWORKS: tuple[str, ...] = ("demo_identity", "uncovered", "opensky_identity")
#: The scenario of each network (relative to the repository root).
SCENARIOS: dict[str, str] = {"demo_identity": "scenarios/demo_identity.toml",
                             "uncovered": "scenarios/demo_identity.toml",
                             "opensky_identity": "scenarios/opensky_identity.toml"}
#: The networks of ``--network both`` and ``--network all``.
GROUPS: dict[str, tuple[str, ...]] = {"both": ("demo_identity", "uncovered"),
                                      "all": NETWORKS}

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
#: The uncovered network's three calibrations, in table order.
UNCOVERED_RUNS: tuple[str, ...] = ("associated", "no_own_paths", "addressed")
#: Association counts, in table order.
COUNTS: tuple[str, ...] = ("correct", "wrong", "clutter_in", "left_out", "ambiguous",
                           "clutter_ambiguous")
#: Counts of the plots on paths of their own and of the aircraft no reference covers.
OWN_COUNTS: tuple[str, ...] = ("own", "own_majority", "own_clutter", "own_covered",
                               "uncovered", "uncovered_left_out")

#: The uncovered network: these radars (the two that report addresses) are dropped ...
DROPPED_RADARS: tuple[str, ...] = ("NORD", "APP")
#: ... and the ADS-B reports of this fraction of the aircraft kept,
ADSB_KEPT = 0.4
#: chosen with ``np.random.default_rng(seed + ADSB_RNG_OFFSET)``.
ADSB_RNG_OFFSET = 2


def with_truth(dataset: Dataset, truth: pd.Series) -> Dataset:
    """The plots with ``target_id`` from the truth (row-aligned), the clutter dropped."""
    true = truth.astype(str).to_numpy()
    plots = dataset.plots.copy()
    plots["target_id"] = true
    plots = plots.loc[true != CLUTTER].reset_index(drop=True)
    return dataclasses.replace(dataset, plots=plots)


def addressed(sim: SimulationResult) -> Dataset:
    """The simulated plots with ``target_id`` from the truth, the clutter dropped."""
    return with_truth(sim.dataset, plot_truth(sim))


def plot_truth(sim: SimulationResult) -> pd.Series:
    """Each plot's true aircraft (or CLUTTER), indexed like the dataset's plots."""
    return pd.Series(sim.plot_truth["truth_target_id"].astype(str).to_numpy(),
                     index=sim.dataset.plots.index)


def uncovered_network(sim: SimulationResult, seed: int
                      ) -> tuple[Dataset, pd.Series, set[str]]:
    """The uncovered network of one seed (module docstring): the dataset, each plot's true
    aircraft and the aircraft whose ADS-B is kept."""
    ds = sim.dataset
    keep = ~ds.plots["radar_id"].astype(str).isin(DROPPED_RADARS).to_numpy()
    aircraft = np.array(sorted(pd.unique(ds.adsb["target_id"].astype(str))))
    rng = np.random.default_rng(seed + ADSB_RNG_OFFSET)
    with_adsb = {str(a) for a in aircraft[rng.random(len(aircraft)) < ADSB_KEPT]}
    adsb = ds.adsb[ds.adsb["target_id"].astype(str).isin(with_adsb)]
    sites = {rid: site for rid, site in ds.sites.items() if rid not in DROPPED_RADARS}
    network = dataclasses.replace(ds, sites=sites, plots=ds.plots.loc[keep], adsb=adsb)
    return network, plot_truth(sim).loc[keep], with_adsb


@contextlib.contextmanager
def no_own_paths() -> Iterator[None]:
    """Paths of their own turned off: ``find_own_paths`` of
    :mod:`graphcal.tracking.association` finds none until the block ends."""
    saved = association_module.find_own_paths
    association_module.find_own_paths = lambda sites, leftovers: {}
    try:
        yield
    finally:
        association_module.find_own_paths = saved


def calibrate(dataset: Dataset, use_adsb: bool) -> tuple[object | None, dict]:
    """``graphcal.calibrate`` on the dataset, timed: the Calibration (None if it raised)
    and the run record."""
    return timed_run(lambda: graphcal.calibrate(dataset, use_adsb=use_adsb, model_checks=False,
                                                check_fit=False, bound=False))


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


def covered_aircraft(dataset: Dataset, use_adsb: bool) -> set[str]:
    """The aircraft a reference covers: ADS-B (when used) and the addressed plots."""
    covered = set()
    if use_adsb and dataset.adsb is not None:
        covered |= set(dataset.adsb["target_id"].astype(str))
    target = dataset.plots["target_id"].astype(str)
    covered |= set(target[~target.isin(["", "nan", "<NA>"])])
    return covered


def score(dataset: Dataset, truth: pd.Series, cal, use_adsb: bool
          ) -> tuple[dict[str, dict[str, int]], list[dict]]:
    """Re-associate at the calibration's biases and count per radar against the truth
    (``truth``: each plot's true aircraft, indexed like the plots); also each path of its
    own: its plots, its majority aircraft and their plots, its radars."""
    biases = {rid: cal.bias(rid) for rid in cal.radar_ids}
    association = associate(dataset, biases, gate_covariances(cal), use_adsb=use_adsb)
    covered = covered_aircraft(dataset, use_adsb)
    index = association.status.index
    status = association.status.to_numpy()
    given = association.target_id.reindex(index).astype(str).to_numpy()
    true = truth.reindex(index).astype(str).to_numpy()
    rids = dataset.plots["radar_id"].astype(str).reindex(index).to_numpy()
    real_all = true != CLUTTER
    own_all = (status == ASSOCIATED) & np.array(
        [g.startswith(OWN_PATH_PREFIX) for g in given], dtype=bool)
    # Each path's majority aircraft, over all its radars.
    frame = pd.DataFrame({"path": given[own_all], "truth": true[own_all],
                          "radar": rids[own_all]})
    paths = []
    majority: dict[str, str] = {}
    for name, group in frame.groupby("path", sort=True):
        real = group.loc[group["truth"] != CLUTTER, "truth"].value_counts()
        major = str(real.index[0]) if len(real) else CLUTTER
        majority[str(name)] = major
        paths.append({"path": str(name), "plots": len(group),
                      "majority": major, "majority_plots": int(real.iloc[0]) if len(real) else 0,
                      "clutter": int((group["truth"] == CLUTTER).sum()),
                      "aircraft": {str(k): int(v) for k, v in real.items()},
                      "radars": sorted(set(group["radar"]))})
    major_of = np.array([majority.get(g, "") for g in given], dtype=object)
    uncovered_all = real_all & ~np.isin(true, list(covered))
    out: dict[str, dict[str, int]] = {}
    for rid in association.radars:
        sel = rids == rid
        st, gv, tr = status[sel], given[sel], true[sel]
        own, real, uncovered = own_all[sel], real_all[sel], uncovered_all[sel]
        assoc = st == ASSOCIATED
        ref = assoc & ~own
        out[rid] = {
            "plots": int(sel.sum()),
            "correct": int(np.sum(ref & real & (gv == tr))),
            "wrong": int(np.sum(ref & real & (gv != tr))),
            "clutter_in": int(np.sum(assoc & ~real)),
            "left_out": int(np.sum(~assoc & real)),
            "ambiguous": int(np.sum((st == AMBIGUOUS) & real)),
            "clutter_ambiguous": int(np.sum((st == AMBIGUOUS) & ~real)),
            "clutter": int(np.sum(~real)),
            "own": int(own.sum()),
            "own_majority": int(np.sum(own & real & (tr == major_of[sel]))),
            "own_clutter": int(np.sum(own & ~real)),
            "own_covered": int(np.sum(own & real & ~uncovered)),
            "uncovered": int(uncovered.sum()),
            "uncovered_left_out": int(np.sum(uncovered & ~assoc)),
        }
    return out, paths


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
                    rec["score"], rec["own_paths"] = score(
                        sim.dataset, plot_truth(sim), cal, use_adsb)
            record[name] = rec
        out["adsb" if use_adsb else "no-adsb"] = record
    return out


def run_uncovered(seed: int, scenario) -> dict:
    """One seed of the uncovered network: the three calibrations with ADS-B, the scores of
    the two associated ones and z."""
    sim = graphcal.simulate(scenario, seed=seed)
    network, truth, with_adsb = uncovered_network(sim, seed)
    datasets = {"associated": network, "no_own_paths": network,
                "addressed": with_truth(network, truth)}
    radar_ids = list(network.sites)
    out: dict = {"seed": seed, "plots": len(network.plots),
                 "clutter": int((truth == CLUTTER).sum()),
                 "aircraft_with_adsb": sorted(with_adsb)}
    record: dict = {}
    for name in UNCOVERED_RUNS:
        switch = no_own_paths() if name == "no_own_paths" else contextlib.nullcontext()
        with switch:
            cal, rec = calibrate(datasets[name], True)
            rec["calibrated"] = calibrated(cal, radar_ids)
            if cal is not None:
                rec["parameters"] = parameters(cal, sim)
                if name != "addressed":
                    rec["association_info"] = cal.info.get("association")
                    rec["score"], rec["own_paths"] = score(network, truth, cal, True)
        record[name] = rec
    out["adsb"] = record
    return out


def _z_stats(z: list[float]) -> dict:
    a = np.asarray([v for v in z if np.isfinite(v)], dtype=float)
    if not len(a):
        return {"n": 0}
    return {"n": int(len(a)), "mean": float(a.mean()), "var": float(np.mean(a**2)),
            "max_abs": float(np.max(np.abs(a))), "beyond_3": int(np.sum(np.abs(a) > 3))}


def _sigma_ratios(runs: list[dict], setting: str, name: str, identities: dict[str, str]
                  ) -> dict[str, dict]:
    """Sigma of run ``name`` / sigma of the addressed run, per radar identity."""
    ratios: dict[str, list[float]] = {}
    for r in runs:
        a = {(p["radar"], p["key"]): p["sigma"]
             for p in r[setting][name].get("parameters", [])}
        b = {(p["radar"], p["key"]): p["sigma"]
             for p in r[setting]["addressed"].get("parameters", [])}
        for label in a.keys() & b.keys():
            ratios.setdefault(identities[label[0]], []).append(a[label] / b[label])
    return {ident: {"mean": float(np.mean(v)), "max": float(np.max(v)),
                    "min": float(np.min(v)), "n": len(v)}
            for ident, v in ratios.items()}


def summarise(runs: list[dict], setting: str, identities: dict[str, str],
              names: tuple[str, ...] = RUNS) -> dict:
    """One ADS-B setting over the seeds (module docstring).  ``names``: the runs; every
    one but ``addressed`` is scored and compared with ``addressed``; the ``associated``
    run's figures are under ``counts``, ``sigma_ratio`` and ``time_ratio``, another run's
    under the same names suffixed with ``_`` and its name."""
    out: dict = {}
    for name in names:
        if name == "addressed":
            continue
        suffix = "" if name == "associated" else f"_{name}"
        counts = dict.fromkeys((*COUNTS, *OWN_COUNTS), 0)
        per_radar: dict[str, dict[str, int]] = {}
        for r in runs:
            for rid, c in r[setting][name].get("score", {}).items():
                for k in counts:
                    counts[k] += c[k]
                acc = per_radar.setdefault(
                    rid, dict.fromkeys((*COUNTS, *OWN_COUNTS, "plots", "clutter"), 0))
                for k in acc:
                    acc[k] += c[k]
        paths = [(r["seed"], p) for r in runs for p in r[setting][name].get("own_paths", [])]
        out["counts" + suffix] = counts
        out["counts_per_radar" + suffix] = per_radar
        out["own_paths" + suffix] = {
            "paths": len(paths),
            "impure": [{"seed": s, **p} for s, p in paths
                       if p["majority_plots"] < p["plots"]]}
        out["sigma_ratio" + suffix] = _sigma_ratios(runs, setting, name, identities)
        times = [r[setting][name]["seconds"] / r[setting]["addressed"]["seconds"]
                 for r in runs]
        out["time_ratio_median" + suffix] = float(np.median(times))
        out["time_ratio" + suffix] = times
        out["rounds" + suffix] = [(r[setting][name].get("association_info") or {}).get("rounds")
                                  for r in runs]
    for name in names:
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
    out["all_calibrated"] = not any(out[name]["not_calibrated"] for name in names)
    return out


def _fmt(stats: dict) -> str:
    if not stats.get("n"):
        return "-"
    return f"{stats['mean']:+.2f} / {stats['var']:.2f}"


def _z_rows(label: str, s: dict, names: tuple[str, ...]) -> list[str]:
    """The z table's rows of one setting, ``label`` its first cells."""
    lines = []
    for name in names:
        r = s[name]
        cells = " | ".join(_fmt(r["kinds"].get(k, {})) for k in (*KEYS, "all"))
        at = r["max_abs_z_at"]
        worst = "-" if at is None else (f"{abs(at['z']):.2f} (seed {at['seed']}, "
                                       f"{at['radar']} {at['key']})")
        lines.append(f"| {label}{name.replace('_', ' ')} | {cells} | "
                     f"{worst} | {r['kinds']['all'].get('beyond_3', 0)}/"
                     f"{r['kinds']['all'].get('n', 0)} | {r['errors']} | "
                     f"{r['seconds_mean']:.1f} |")
    return lines


def _ratio(s: dict, ident: str, suffix: str = "") -> str:
    r = s["sigma_ratio" + suffix].get(ident)
    return "-" if r is None else f"{r['mean']:.3f}, {r['max']:.3f}"


def table(summary: dict[str, dict], seeds: int, network: str = "demo_identity") -> str:
    lines = [f"{network}, seeds 1-{seeds}", "",
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
        lines += _z_rows(f"{'yes' if setting == 'adsb' else 'no'} | ", s, RUNS)
    lines += ["", "| ADS-B | sigma ratio primary (mean, max) | sigma ratio Mode A/C "
              "(mean, max) | every radar calibrated | median time ratio |",
              "|---|---|---|---|---|"]
    for setting, s in summary.items():
        lines.append(f"| {'yes' if setting == 'adsb' else 'no'} | {_ratio(s, 'psr')} | "
                     f"{_ratio(s, 'mode_ac')} | {'yes' if s['all_calibrated'] else 'no'} | "
                     f"{s['time_ratio_median']:.2f} |")
    return "\n".join(lines)


def _percent(part: int, whole: int, digits: int = 1) -> str:
    return f"{part:,} ({100.0 * part / whole:.{digits}f} %)" if whole else f"{part:,}"


def table_uncovered(s: dict, seeds: int) -> str:
    """The uncovered network's table (one setting: with ADS-B)."""
    scored = {"own paths": "", "no own paths": "_no_own_paths"}
    lines = [f"uncovered: demo_identity without {' and '.join(DROPPED_RADARS)}, ADS-B kept for "
             f"{ADSB_KEPT * 100:.0f} % of its aircraft, seeds 1-{seeds}, with ADS-B", "",
             "Association at the final biases, summed over seeds and radars (correct and "
             "wrong: known aircraft only; clutter in includes clutter on own paths)", "",
             "| run | correct | wrong | clutter in | left out | ambiguous | "
             "clutter ambiguous |",
             "|---|---|---|---|---|---|---|"]
    for label, suffix in scored.items():
        c = s["counts" + suffix]
        lines.append(f"| {label} | " + " | ".join(f"{c[k]:,}" for k in COUNTS) + " |")
    lines += ["", "Paths of their own, summed over seeds and radars (uncovered: real plots of "
              "the aircraft no reference covers)", "",
              "| run | paths (impure) | on own paths | of the majority aircraft | "
              "clutter on own | ADS-B aircraft on own | uncovered | uncovered left out |",
              "|---|---|---|---|---|---|---|---|"]
    for label, suffix in scored.items():
        c, p = s["counts" + suffix], s["own_paths" + suffix]
        lines.append(f"| {label} | {p['paths']} ({len(p['impure'])}) | {c['own']:,} | "
                     f"{_percent(c['own_majority'], c['own'], 2)} | {c['own_clutter']:,} | "
                     f"{c['own_covered']:,} | {c['uncovered']:,} | "
                     f"{_percent(c['uncovered_left_out'], c['uncovered'])} |")
    columns = [*KEYS, "all"]
    lines += ["", "z = (estimate - truth) / sigma: mean z / var z (mean z²), over every "
              "radar and seed", "",
              "| run | " + " | ".join(columns) + " | max abs z | abs z > 3 | errors | s/run |",
              "|---|" + "---|" * len(columns) + "---|---|---|---|"]
    lines += _z_rows("", s, UNCOVERED_RUNS)
    lines += ["", "| run | sigma ratio primary (mean, max) | sigma ratio Mode A/C (mean, max) "
              "| every radar calibrated | median time ratio | rounds |",
              "|---|---|---|---|---|---|"]
    for (label, suffix), name in zip(scored.items(), ("associated", "no_own_paths"),
                                     strict=True):
        ok = not s[name]["not_calibrated"] and not s["addressed"]["not_calibrated"]
        rounds = [r for r in s["rounds" + suffix] if r is not None]
        lines.append(f"| {label} | {_ratio(s, 'psr', suffix)} | "
                     f"{_ratio(s, 'mode_ac', suffix)} | {'yes' if ok else 'no'} | "
                     f"{s['time_ratio_median' + suffix]:.2f} | "
                     f"{min(rounds, default=0)}-{max(rounds, default=0)} |")
    return "\n".join(lines)


def _report(summary: dict[str, dict], runs: list[dict], names: tuple[str, ...],
            network: str) -> None:
    """The runs not calibrated, the |z| > 3, the impure paths and the errors."""
    for setting, s in summary.items():
        for name in names:
            for item in s[name]["not_calibrated"]:
                print(f"not calibrated: {network} {setting} {name} seed {item['seed']} "
                      f"{item['radar']}")
            for item in s[name]["beyond_3"]:
                print(f"|z| > 3: {network} {setting} {name} seed {item['seed']} "
                      f"{item['radar']} {item['key']} z = {item['z']:+.2f}")
        if network == "uncovered":
            for key in ("own_paths", "own_paths_no_own_paths"):
                for p in s[key]["impure"]:
                    print(f"impure path: {network} seed {p['seed']} {p['path']} "
                          f"({', '.join(p['radars'])}): {p['plots']} plots, "
                          f"{p['majority_plots']} of {p['majority']}, aircraft {p['aircraft']}, "
                          f"clutter {p['clutter']}")
    errors = [(r["seed"], setting, name, r[setting][name]["error"]) for r in runs
              for setting in summary for name in names if r[setting][name]["error"]]
    for seed, setting, name, error in errors:
        print(f"error: {network} seed {seed} {setting} {name}: {error}")


def study(network: str, seeds: int) -> dict:
    """One network over the seeds, on its scenario (:data:`SCENARIOS`): prints its
    progress, table and notes; returns the JSON object."""
    scenario = graphcal.load_scenario(ROOT / SCENARIOS[network])
    identities = {r.id: r.identity for r in scenario.radars}
    uncovered = network == "uncovered"
    settings = ("adsb",) if uncovered else ("adsb", "no-adsb")
    names = UNCOVERED_RUNS if uncovered else RUNS
    runs = []
    for seed in range(1, seeds + 1):
        result = run_uncovered(seed, scenario) if uncovered else run(seed, scenario)
        runs.append(result)
        note = "; ".join(
            f"{setting} " + ", ".join(
                f"{name} {result[setting][name]['seconds']:.1f} s"
                + (f" ERROR {result[setting][name]['error']}"
                   if result[setting][name]["error"] else "")
                for name in names)
            for setting in settings)
        print(f"{network} seed {seed}: {note}", flush=True)
    summary = {setting: summarise(runs, setting, identities, names) for setting in settings}
    print()
    print(table_uncovered(summary["adsb"], seeds) if uncovered
          else table(summary, seeds, network))
    _report(summary, runs, names, network)
    print()
    out = {"scenario": SCENARIOS[network], "seeds": seeds, "summary": summary,
           "runs": runs}
    if uncovered:
        out = {"network": "uncovered", "dropped_radars": list(DROPPED_RADARS),
               "adsb_kept": ADSB_KEPT, "adsb_rng": f"seed + {ADSB_RNG_OFFSET}", **out}
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="seeds 1 .. N (default 5)")
    parser.add_argument("--network", choices=(*NETWORKS, *GROUPS), default="demo_identity",
                        help="demo_identity (default), uncovered (no Mode S radar, ADS-B "
                             "kept for 40 %% of its aircraft), opensky_identity (the "
                             "four-radar network on real traffic), both (demo_identity and "
                             "uncovered) or all")
    parser.add_argument("--json", type=Path, help="write the runs and summaries here")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    networks = GROUPS.get(args.network, (args.network,))
    results = {network: study(network, args.seeds) for network in networks}
    print(f"total {time.perf_counter() - start:.0f} s")
    if args.json is not None:
        out = results if len(results) > 1 else next(iter(results.values()))
        args.json.write_text(json.dumps(out, indent=1, default=_plain) + "\n")


def _plain(value: object) -> object:
    """numpy and pandas scalars in the JSON."""
    if isinstance(value, np.generic):
        return value.item()
    if value is pd.NA or value is None:
        return None
    raise TypeError(type(value).__name__)


if __name__ == "__main__":
    main()

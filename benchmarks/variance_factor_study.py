"""Variance-factor study: when do ``graph``'s sigmas get widened, and does it help?

Run from the repository root::

    .venv/bin/python -m benchmarks.variance_factor_study [--seeds 12] [--misstated-seeds 8]
        [--cross-seeds 8] [--v2-seeds 8] [--json out.json]

``graphcal.calibrate`` (method ``graph``) widens a radar's sigmas when its residuals'
``chi2/dof`` exceeds 1 by more than chance (``graphcal.analysis.fit_verdict``,
"When the residuals exceed their sigmas").  Every dataset is simulated, then cleaned
as ``graphcal calibrate`` cleans a folder (:func:`graphcal.data.cleaning.clean_dataset`),
then calibrated:

* ``clean``: ``scenarios/demo_network.toml`` with ADS-B (``--seeds``): the widening
  should not fire;
* ``clean --no-adsb``: the same without ADS-B (``--cross-seeds``);
* ``demo_v2``: ``scenarios/demo_v2.toml`` (refraction, pressure altitudes and NORD's
  eccentric antenna, all declared) with ADS-B (``--v2-seeds``);
* ``adsb sigma_m/20``: demo_network with every ADS-B ``sigma_m`` divided by 20 and
  ``nacp`` 11 (``--misstated-seeds``);
* ``NORD sigma_range_m/10``: demo_network with NORD's ``sigma_range_m`` 3 m instead of
  30 m (``--misstated-seeds``);
* ``clean --window 10min`` (``--v2-seeds``) and ``adsb sigma_m/20 --window 10min``
  (``--misstated-seeds``): the same over 10-minute windows (the residuals pooled over
  the windows; the chi2/dof column is then the worst window's), z of the last window;
* ``NORD sigma_range_m/10 --no-adsb`` (``--cross-seeds``): residuals against the other
  radars, which carry the partner's error;
* ``demo_v2 undeclared`` (``--v2-seeds``): demo_v2 read as version 1 (straight rays,
  geometric altitudes, no eccentricity term): residuals beyond their sigmas from an
  unmodelled effect, not a misstated sigma.

Reported per case: runs, radars, radars whose sigmas were widened (and the coordinates
that fired), the largest ``chi2/dof`` of a coordinate on the radars not widened, and the
z statistics ``z = (estimate - truth) / sigma`` over every estimated parameter, before
the widening (the sigmas divided back by the factor recorded in
``info.sigma_inflation``) and after: mean z, ``var z`` (mean z², the normalised error
variance), the largest ``|z|`` and the share beyond 3.  Also for the widened radars alone.

Prints a table; writes JSON only to the path given with ``--json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

import graphcal
from graphcal.data.bias import CONTRACT_KEYS
from graphcal.data.cleaning import clean_dataset
from graphcal.data.dataset import Dataset
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"

#: Case -> (scenario, misstatement, use_adsb, window [s] or None).
CASES: dict[str, tuple[str, str | None, bool, float | None]] = {
    "clean": ("demo_network", None, True, None),
    "clean --no-adsb": ("demo_network", None, False, None),
    "clean --window 10min": ("demo_network", None, True, 600.0),
    "demo_v2": ("demo_v2", None, True, None),
    "adsb sigma_m/20": ("demo_network", "adsb20", True, None),
    "NORD sigma_range_m/10": ("demo_network", "range10", True, None),
    "adsb sigma_m/20 --window 10min": ("demo_network", "adsb20", True, 600.0),
    "NORD sigma_range_m/10 --no-adsb": ("demo_network", "range10", False, None),
    "demo_v2 undeclared": ("demo_v2", "undeclared", True, None),
}
#: Which seed count (command-line option) each case takes.
SEED_OPTION: dict[str, str] = {
    "clean": "seeds", "clean --no-adsb": "cross_seeds", "clean --window 10min": "v2_seeds",
    "demo_v2": "v2_seeds", "adsb sigma_m/20": "misstated_seeds",
    "NORD sigma_range_m/10": "misstated_seeds",
    "adsb sigma_m/20 --window 10min": "misstated_seeds",
    "NORD sigma_range_m/10 --no-adsb": "cross_seeds", "demo_v2 undeclared": "v2_seeds",
}


def misstate(dataset: Dataset, how: str | None) -> Dataset:
    """The dataset with its stated noise made too small (module docstring)."""
    if how is None:
        return dataset
    if how == "adsb20":
        adsb = dataset.adsb.copy()
        adsb["sigma_m"] = adsb["sigma_m"] / 20.0
        if "nacp" in adsb:
            adsb["nacp"] = 11
        return dataclasses.replace(dataset, adsb=adsb)
    if how == "range10":
        sites = dict(dataset.sites)
        sites["NORD"] = dataclasses.replace(sites["NORD"],
                                            sigma_range_m=sites["NORD"].sigma_range_m / 10.0)
        return dataclasses.replace(dataset, sites=sites)
    if how == "undeclared":  # demo_v2 read as version 1 (model_checks_study's _v2_run)
        sites = {rid: dataclasses.replace(
            site, refraction="none",
            estimate=tuple(e for e in site.estimate if e != "azimuth_eccentricity"))
            for rid, site in dataset.sites.items()}
        return dataclasses.replace(dataset, sites=sites, plot_altitude="geometric")
    raise ValueError(how)


def run(case: str, seed: int) -> dict:
    """One calibration: per radar, its coordinates' chi2/dof, factor and z before/after."""
    scenario, how, use_adsb, window = CASES[case]
    res = simulate(load_scenario(SCENARIOS / f"{scenario}.toml"), np.random.default_rng(seed))
    dataset = misstate(res.dataset, how)
    dataset, _ = clean_dataset(dataset)
    t0 = time.perf_counter()
    options = ({"bound": False} if window is None else {"window": window})
    cal = graphcal.calibrate(dataset, use_adsb=use_adsb, check_fit=False, **options)
    seconds = time.perf_counter() - t0
    # Over windows: the worst window's residuals (the widening pools them; its
    # coordinates are in info.sigma_inflation).
    verdict = (cal.info.get("fit_verdict") or {}).get("radars") or {}
    inflation = cal.info.get("sigma_inflation") or {}
    radars = {}
    for rid in cal.radar_ids:
        entry = inflation.get(rid) or {}
        z_after, z_before, keys = [], [], []
        for i, (r, name) in enumerate(cal.labels):
            if r != rid:
                continue
            key = CONTRACT_KEYS[name][0]
            sigma = float(np.sqrt(cal.covariance_si[i, i]))
            error = float(cal.estimate[i] - res.biases[rid].value(name))
            factor = float((entry.get("parameters") or {}).get(key, 1.0))
            keys.append(key)
            z_after.append(error / sigma)
            z_before.append(error / (sigma / np.sqrt(factor)))
        radars[rid] = {
            "coordinates": {c: {"chi2_per_dof": v["chi2_per_dof"], "dof": v["dof"]}
                            for c, v in (verdict.get(rid) or {}).get("coordinates",
                                                                     {}).items()},
            "factor": float(entry.get("factor", 1.0)),
            "widened": [c for c in entry.get("coordinates", {})],
            "keys": keys,
            "z_before": z_before,
            "z_after": z_after,
        }
    warned = [w for w in cal.warnings if "sigmas widened" in w]
    return {"case": case, "seed": seed, "seconds": seconds, "radars": radars,
            "warnings": warned}


def z_stats(z: list[float]) -> dict:
    a = np.asarray(z, dtype=float)
    if not len(a):
        return {"n": 0}
    return {"n": len(a), "mean": float(a.mean()), "var": float(np.mean(a**2)),
            "max_abs": float(np.max(np.abs(a))), "beyond_3": int(np.sum(np.abs(a) > 3))}


def summarise(runs: list[dict]) -> dict:
    radars = [(run, rid, r) for run in runs for rid, r in run["radars"].items()]
    widened = [(run, rid, r) for run, rid, r in radars if r["factor"] > 1.0]
    quiet = [r for _, _, r in radars if r["factor"] == 1.0]
    fired_by: dict[str, int] = {}
    for _, rid, _r in widened:
        fired_by[rid] = fired_by.get(rid, 0) + 1
    worst_quiet = max((c["chi2_per_dof"] for r in quiet for c in r["coordinates"].values()),
                      default=float("nan"))
    ratios = np.array([c["chi2_per_dof"] for _, _, r in radars
                       for c in r["coordinates"].values()])
    every = lambda key, rows: [z for r in rows for z in r[key]]  # noqa: E731
    rows = [r for _, _, r in radars]
    wide = [r for _, _, r in widened]
    return {
        "runs": len(runs),
        "radars": len(radars),
        "widened": len(widened),
        "widened_by_radar": fired_by,
        "factors": {rid: [round(r["factor"], 3) for run, i, r in widened if i == rid]
                    for rid in fired_by},
        "runs_warned": sum(1 for run in runs if run["warnings"]),
        "worst_quiet_chi2_per_dof": worst_quiet,
        "chi2_per_dof": ({"n": len(ratios), "mean": float(ratios.mean()),
                          "sd": float(ratios.std()), "max": float(ratios.max())}
                         if len(ratios) else {"n": 0}),
        "z_before": z_stats(every("z_before", rows)),
        "z_after": z_stats(every("z_after", rows)),
        "z_before_widened": z_stats(every("z_before", wide)),
        "z_after_widened": z_stats(every("z_after", wide)),
        "seconds": float(np.mean([run["seconds"] for run in runs])) if runs else 0.0,
    }


def _fmt(stats: dict) -> str:
    if not stats.get("n"):
        return "-"
    return (f"{stats['mean']:+.2f} / {stats['var']:.2f} / {stats['max_abs']:.1f}"
            f" ({stats['beyond_3']} of {stats['n']} > 3)")


def table(summary: dict[str, dict]) -> str:
    lines = ["| case | runs | radars widened | chi2/dof: mean ± sd (max) | not widened: "
             "worst | z before: mean / var / max | z after | widened radars' z before "
             "| after |",
             "|---|---|---|---|---|---|---|---|---|"]
    for case, s in summary.items():
        by = ", ".join(f"{rid} {n}" for rid, n in s["widened_by_radar"].items())
        ratio = s["chi2_per_dof"]
        spread = (f"{ratio['mean']:.3f} ± {ratio['sd']:.3f} ({ratio['max']:.3f})"
                  if ratio["n"] else "-")
        lines.append(
            f"| {case} | {s['runs']} | {s['widened']} of {s['radars']}"
            f"{f' ({by})' if by else ''} | {spread} | {s['worst_quiet_chi2_per_dof']:.3f} | "
            f"{_fmt(s['z_before'])} | {_fmt(s['z_after'])} | "
            f"{_fmt(s['z_before_widened'])} | {_fmt(s['z_after_widened'])} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12, help="clean demo seeds, ADS-B")
    parser.add_argument("--cross-seeds", type=int, default=8,
                        help="clean and NORD sigma_range_m/10, --no-adsb")
    parser.add_argument("--v2-seeds", type=int, default=8,
                        help="demo_v2 (declared, undeclared) and clean --window")
    parser.add_argument("--misstated-seeds", type=int, default=8,
                        help="each misstated case")
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--json", type=Path, help="write the runs and summary here")
    args = parser.parse_args(argv)
    counts = {case: getattr(args, option) for case, option in SEED_OPTION.items()}
    runs: dict[str, list[dict]] = {}
    for case in args.cases:
        runs[case] = []
        for seed in range(1, counts[case] + 1):
            result = run(case, seed)
            runs[case].append(result)
            fired = {rid: round(r["factor"], 3) for rid, r in result["radars"].items()
                     if r["factor"] > 1.0}
            print(f"{case} seed {seed}: {result['seconds']:.1f} s, widened {fired or 'none'}",
                  flush=True)
    summary = {case: summarise(r) for case, r in runs.items()}
    print(table(summary))
    if args.json is not None:
        args.json.write_text(json.dumps({"summary": summary, "runs": runs}, indent=1) + "\n")


if __name__ == "__main__":
    main()

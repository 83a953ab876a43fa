"""Benchmark of the random-error estimators of :mod:`graphcal.noise` (paper 000).

Run from the repository root::

    .venv/bin/python -m benchmarks.noise_estimation               # 5 seeds + timing
    .venv/bin/python -m benchmarks.noise_estimation --seeds 10
    .venv/bin/python -m benchmarks.noise_estimation --no-timing

Part 1 - accuracy.  ``scenarios/demo_network.toml`` (two 2-D Mode S SSRs, two
3-D air-defence radars, one 2-D approach radar; random traffic with turns and
climbs; ADS-B NACp 8) is simulated with seeds 1..N.  For each radar the
estimated sigmas of both methods (straight-leg line fits without ADS-B, and
ADS-B residuals) are divided by the simulated sigmas; the table shows the mean
ratio over the seeds, its spread (standard deviation over seeds) and the
mean reported standard error (as a ratio), which should be about the spread.

Part 2 - timing.  The same scenario with the number of aircraft scaled to give
about 300k plots; wall time of ``estimate_noise`` for each method.
"""

from __future__ import annotations

import argparse
import time
import tomllib
from pathlib import Path

import numpy as np

from graphcal.noise import estimate_noise
from graphcal.simulation.scenario import load_scenario, parse_scenario
from graphcal.simulation.simulate import simulate

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "demo_network.toml"


def accuracy(n_seeds: int) -> None:
    """Estimated / simulated sigma per radar, component and method over seeds."""
    scenario = load_scenario(SCENARIO)
    ratios: dict[tuple[str, str, str], list[tuple[float, float]]] = {}
    for seed in range(1, n_seeds + 1):
        dataset = simulate(scenario, np.random.default_rng(seed)).dataset
        for method, use_adsb in (("line-fit", False), ("adsb", True)):
            for rid, est in estimate_noise(dataset, use_adsb=use_adsb).items():
                site = dataset.sites[rid]
                comps = [
                    ("range", est.sigma_range_m, est.se_range_m, site.sigma_range_m),
                    ("azimuth", est.sigma_azimuth_rad, est.se_azimuth_mrad * 1e-3,
                     site.sigma_azimuth_rad),
                ]
                if site.is_3d:
                    comps.append(("elevation", est.sigma_elevation_rad,
                                  est.se_elevation_mrad * 1e-3, site.sigma_elevation_rad))
                for comp, value, se, true in comps:
                    ratios.setdefault((rid, comp, method), []).append((value / true, se / true))
    print(f"estimated / simulated sigma, {n_seeds} seeds of {SCENARIO.name}")
    print(f"{'radar':8s} {'component':10s} {'method':9s} {'mean':>7s} {'spread':>7s} "
          f"{'mean se':>7s} {'worst':>7s}")
    for (rid, comp, method), values in ratios.items():
        r = np.array([v[0] for v in values])
        se = np.array([v[1] for v in values])
        worst = r[np.argmax(np.abs(r - 1.0))]
        spread = r.std(ddof=1) if r.size > 1 else float("nan")
        print(f"{rid:8s} {comp:10s} {method:9s} {r.mean():7.3f} {spread:7.3f} "
              f"{se.mean():7.3f} {worst:7.3f}")


def timing(target_plots: int = 300_000) -> None:
    """Wall time of both methods on about ``target_plots`` plots."""
    with SCENARIO.open("rb") as handle:
        document = tomllib.load(handle)
    base = document["traffic"]["n_aircraft"]
    document["traffic"]["n_aircraft"] = int(base * target_plots / 34_000)
    scenario = parse_scenario(document, SCENARIO)
    t0 = time.perf_counter()
    dataset = simulate(scenario, np.random.default_rng(1)).dataset
    t1 = time.perf_counter()
    print(f"\ntiming: {len(dataset.plots)} plots, {len(dataset.sites)} radars "
          f"(simulation {t1 - t0:.1f} s)")
    for method, use_adsb in (("line-fit", False), ("adsb", True)):
        t0 = time.perf_counter()
        est = estimate_noise(dataset, use_adsb=use_adsb)
        elapsed = time.perf_counter() - t0
        used = sum(e.n_plots_used for e in est.values())
        print(f"  {method:9s} {elapsed:6.2f} s  ({used} plots used)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--no-timing", action="store_true")
    args = parser.parse_args()
    accuracy(args.seeds)
    if not args.no_timing:
        timing()


if __name__ == "__main__":
    main()

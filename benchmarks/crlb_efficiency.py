"""CRLB timing and the graph calibrator's efficiency on a simulated scenario.

Usage: ``.venv/bin/python -m benchmarks.crlb_efficiency [SCENARIO.toml] [--seed N]``
(default ``scenarios/demo_network.toml``).  Prints the CRLB time, and per
parameter the CRLB sigma, graph's reported sigma, their ratio and the error
in CRLB sigmas, with and without ADS-B.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from graphcal.analysis.crlb import crlb
from graphcal.data.bias import CONTRACT_KEYS
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.graph import graph

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("scenario", nargs="?", default=str(ROOT / "scenarios/demo_network.toml"))
    parser.add_argument("--seed", type=int, default=11)
    args = parser.parse_args()
    run = simulate(load_scenario(args.scenario), np.random.default_rng(args.seed))
    ds = run.dataset
    print(f"{len(ds.plots)} plots, {len(ds.sites)} radars")
    for use_adsb in (True, False):
        t0 = time.perf_counter()
        bound = crlb(ds, use_adsb=use_adsb, priors="graph")
        t_crlb = time.perf_counter() - t0
        cal = graph(ds, use_adsb=use_adsb)
        eff = bound.efficiency(cal)
        print(f"\nuse_adsb={use_adsb}: CRLB {t_crlb:.3f} s, rank {bound.rank}/{len(bound.labels)},"
              f" {bound.info.get('n_events', 0)} events")
        print(f"{'parameter':32s} {'CRLB sigma':>12s} {'graph sigma':>12s} {'ratio':>6s}"
              f" {'err/CRLB':>8s}")
        for i, (rid, name) in enumerate(cal.labels):
            key = CONTRACT_KEYS[name][0]
            s_b = bound.sigma(rid, key)
            err = (cal.estimate[i] - run.biases[rid].value(name)) * CONTRACT_KEYS[name][1]
            print(f"{rid + '.' + key:32s} {s_b:12.4g} {cal.sigma(rid, key):12.4g}"
                  f" {eff[(rid, key)]:6.3f} {err / s_b:8.2f}")


if __name__ == "__main__":
    main()

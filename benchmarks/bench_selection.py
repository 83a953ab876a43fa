"""Benchmark of observation selection on 100k observations.

Run from the repository root::

    .venv/bin/python -m benchmarks.bench_selection [--observations 100000] [--seed 0]

The demo network (``scenarios/demo_network.toml``, 5 radars, ADS-B) is simulated
once; the observations ``graph`` sees (ADS-B-matched plots and cross-radar pairs,
:func:`graphcal.analysis.observability.observation_blocks`, linearised at the
neighbours) are repeated with renamed aircraft and shifted times until there are
at least ``--observations`` of them: real Jacobians, a realistic mix.  Then, for
units of 60-s track segments and of single observations (merged into at most
2,000 chunks for the convex solver), it times building the units and every
selection method at a budget of a tenth of the observations, and prints Deg and
lambda_min of each subset.  Target: every selection (units + method) under 30 s.

Outputs: the table on stdout and ``benchmarks/results/bench_selection.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import RESULTS
from graphcal.analysis.observability import ObservationBlocks, observation_blocks
from graphcal.analysis.selection import MAX_CONVEX_UNITS, select, selection_units
from graphcal.core.atomic import atomic_write_text
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 30.0


def repeated_blocks(blocks: ObservationBlocks, at_least: int) -> ObservationBlocks:
    """``blocks`` repeated with renamed aircraft and shifted times to ``at_least`` observations."""
    copies = int(np.ceil(at_least / len(blocks)))
    span = max(float(b.time_s.max()) for b in blocks.blocks) + 1.0
    out = ObservationBlocks(list(blocks.labels))
    for k in range(copies):
        for b in blocks.blocks:
            out.blocks.append(dataclasses.replace(
                b, time_s=b.time_s + k * span,
                target_id=np.array([f"{t}#{k}" for t in b.target_id], dtype=object),
            ))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--observations", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    t0 = time.perf_counter()
    result = simulate(load_scenario(ROOT / "scenarios" / "demo_network.toml"),
                      np.random.default_rng(args.seed))
    t_sim = time.perf_counter() - t0
    t0 = time.perf_counter()
    base = observation_blocks(result.dataset, "graph", linearise="neighbours")
    t_blocks = time.perf_counter() - t0
    blocks = repeated_blocks(base, args.observations)
    n = len(blocks)
    budget = n // 10
    print(f"demo network simulated in {t_sim:.1f} s; {len(base)} observations built in "
          f"{t_blocks:.1f} s, repeated to {n}; {len(blocks.labels)} parameters; budget {budget}")
    rows = []
    cases = [("segment", "greedy"), ("segment", "e-optimal"), ("segment", "d-optimal"),
             ("segment", "random"), ("observation", "e-optimal"), ("observation", "d-optimal"),
             ("observation", "greedy")]
    for unit, method in cases:
        convex = method in ("e-optimal", "d-optimal")
        start = time.perf_counter()
        units = selection_units(blocks, unit, 60.0, MAX_CONVEX_UNITS if convex else None)
        t_units = time.perf_counter() - start
        sel = select(units, method, budget, rng=np.random.default_rng(args.seed))
        total = time.perf_counter() - start
        figures = sel.scaled_figures()
        rows.append({
            "unit": unit, "method": method, "units": len(units), "kept_units": sel.n_units,
            "observations": sel.n_observations, "units_s": t_units, "select_s": sel.seconds,
            "total_s": total, "degree": figures["degree_full_scaling"],
            "lambda_min": figures["lambda_min"], "status": sel.status,
            "pass": total < TARGET_S,
        })
        r = rows[-1]
        print(f"{unit:12s} {method:10s} units {r['units']:6d} kept {r['kept_units']:6d} "
              f"({r['observations']:6d} obs)  units {t_units:6.2f} s  select "
              f"{sel.seconds:6.2f} s  total {total:6.2f} s  Deg {r['degree']:.3g}  "
              f"lambda_min {r['lambda_min']:.3g}  {'PASS' if r['pass'] else 'FAIL'} "
              f"(< {TARGET_S:g} s)", flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    atomic_write_text(RESULTS / "bench_selection.json", json.dumps({
        "observations": n, "parameters": len(blocks.labels), "budget": budget,
        "seed": args.seed, "simulate_s": t_sim, "blocks_s": t_blocks, "rows": rows,
    }, indent=2) + "\n")
    print(f"wrote {RESULTS / 'bench_selection.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Monte-Carlo study of observation selection (greedy, E-optimal, D-optimal, random).

Run from the repository root::

    .venv/bin/python -m benchmarks.selection_study [--seeds 30]

Part 1 - paper 001 path 2 (``scenarios/paper001_path2.toml``, no ADS-B).  Per
seed: WLS on all observations with the Jacobians at the plots (the paper) and at
the plots' neighbours; then the greedy pruning of eq. 12 and, at its size, the
E-optimal, D-optimal and a random subset (selected on observations linearised at
the neighbours), each estimated by WLS both ways.  Reported: the share of seeds
with every parameter within 3 sigma, the median of the largest |z|, and how the
subsets' smallest eigenvalue and Deg (full set's scaling) compare.

Part 2 - a crowded network (two radars; twelve parallel flights far north, two
crossing flights; as in ``tests/test_selection.py``).  Per seed: 400 of about
1040 observations in 30-s segments by every method, and all of them; WLS at the
neighbours.  Reported: RMSE per parameter in units of the full set's sigma, and
its mean.

Part 3 - the figure ``docs/selection_path2.png``: Deg of path 2 (seed 0) against
the number of observations in time order, with each subset's Deg at its size.

Outputs: tables on stdout, ``benchmarks/results/selection_study.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from graphcal.analysis.observability import degree_curve, observation_blocks
from graphcal.analysis.selection import select, select_dataset, selection_units
from graphcal.core.atomic import atomic_write_stream, atomic_write_text
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.registry import calibrate
from tests.synthetic import crowded_network

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "benchmarks" / "results"
FIGURE = ROOT / "docs" / "selection_path2.png"
METHODS = ("greedy", "e-optimal", "d-optimal", "random")


def _max_z(cal, biases) -> float:
    z = [(cal.estimate[i] - biases[rid].value(name)) / np.sqrt(cal.covariance[i, i])
         for i, (rid, name) in enumerate(cal.labels)]
    return float(np.max(np.abs(z)))


def path2(seeds: int) -> dict:
    spec = load_scenario(ROOT / "scenarios" / "paper001_path2.toml")
    rows = []
    for seed in range(seeds):
        res = simulate(spec, np.random.default_rng(seed))
        ds = res.dataset
        units = selection_units(observation_blocks(ds, "wls", linearise="neighbours"),
                                "observation")
        row = {"seed": seed}
        for lin in ("plots", "neighbours"):
            row[f"all/{lin}"] = _max_z(calibrate(ds, "wls", linearise=lin), res.biases)
        greedy = select(units, "greedy")
        row["size"] = greedy.n_observations
        for method in METHODS:
            sel = greedy if method == "greedy" else select(
                units, method, greedy.n_observations, rng=np.random.default_rng(seed))
            figures = sel.scaled_figures()
            row[f"{method}/degree"] = figures["degree_full_scaling"]
            row[f"{method}/lambda_min"] = figures["lambda_min"]
            subset = select_dataset(ds, sel)
            for lin in ("plots", "neighbours"):
                row[f"{method}/{lin}"] = _max_z(calibrate(subset, "wls", linearise=lin),
                                                res.biases)
        rows.append(row)
        print(f"path 2 seed {seed}: kept {row['size']}, max|z| all {row['all/plots']:.1f} "
              f"-> {row['all/neighbours']:.1f}, e-optimal {row['e-optimal/neighbours']:.1f}",
              flush=True)
    return {"rows": rows}


def crowded(seeds: int, budget: int = 400) -> dict:
    methods = (*METHODS, "all")
    errors: dict[str, list] = {m: [] for m in methods}
    labels = None
    n_total = 0
    for seed in range(seeds):
        ds, biases = crowded_network(np.random.default_rng(seed))
        units = selection_units(observation_blocks(ds, "wls", linearise="neighbours"),
                                "segment", segment_s=30.0)
        n_total = int(units.cost.sum())
        full_sigma = np.sqrt(np.diag(np.linalg.pinv(units.information.sum(axis=0))))
        for method in methods:
            subset = ds if method == "all" else select_dataset(
                ds, select(units, method, budget, rng=np.random.default_rng(seed)))
            cal = calibrate(subset, "wls", linearise="neighbours")
            labels = cal.labels
            truth = np.array([biases[r].value(n) for r, n in cal.labels])
            errors[method].append(((cal.estimate - truth) / full_sigma).tolist())
    rmse = {m: np.sqrt(np.mean(np.square(v), axis=0)).tolist() for m, v in errors.items()}
    return {"budget": budget, "observations": n_total, "labels": labels, "rmse": rmse}


def figure(path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = simulate(load_scenario(ROOT / "scenarios" / "paper001_path2.toml"),
                   np.random.default_rng(0))
    blocks = observation_blocks(res.dataset, "wls", linearise="neighbours")
    _, n_obs, degree = degree_curve(blocks, points=80)
    units = selection_units(blocks, "observation")
    greedy = select(units, "greedy")
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.semilogy(n_obs, np.maximum(degree, 1e-16), color="0.3",
                label="all observations, in time order")
    markers = {"greedy": "o", "e-optimal": "s", "d-optimal": "^", "random": "x"}
    for method, marker in markers.items():
        sel = greedy if method == "greedy" else select(units, method, greedy.n_observations,
                                                       rng=np.random.default_rng(0))
        ax.semilogy([sel.n_observations], [sel.report().degree], marker=marker, ls="none",
                    markersize=9, label=f"{method} subset")
    ax.set_xlabel("observations")
    ax.set_ylabel("observability degree Deg")
    ax.set_title("paper 001 path 2: Deg of the data and of selected subsets")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    try:
        atomic_write_stream(path, lambda stream: fig.savefig(stream, format="png", dpi=100,
                                                             bbox_inches="tight"))
    finally:
        plt.close(fig)


def _share(values: list[float]) -> str:
    return f"{100 * np.mean(np.array(values) < 3.0):.0f} %"


def markdown(p2: dict, net: dict, seeds: int) -> str:
    rows = p2["rows"]
    lines = [
        "# Observation selection: Monte-Carlo study", "",
        f"`benchmarks/selection_study.py --seeds {seeds}`.", "",
        "## Paper 001 path 2 (WLS; subsets of the greedy pruning's size, "
        f"median {int(np.median([r['size'] for r in rows]))} of ~800 observations)", "",
        "| data | Jacobians at | every parameter within 3σ | median max abs(z) |",
        "|---|---|---:|---:|",
    ]
    for name in ("all", *METHODS):
        for lin in ("plots", "neighbours"):
            values = [r[f"{name}/{lin}"] for r in rows]
            lines.append(f"| {name} | {lin} | {_share(values)} | {np.median(values):.2f} |")
    lines += ["", "| comparison | seeds |", "|---|---:|"]
    for a, b, key in (("e-optimal", "greedy", "lambda_min"), ("e-optimal", "greedy", "degree"),
                      ("e-optimal", "random", "degree"), ("d-optimal", "random", "degree")):
        share = np.mean([r[f"{a}/{key}"] >= r[f"{b}/{key}"] for r in rows])
        name = "λmin" if key == "lambda_min" else "Deg (full set's scaling)"
        lines.append(f"| {a} {name} ≥ {b}'s | {100 * share:.0f} % |")
    lines += ["", f"## Crowded network ({net['budget']} of {net['observations']} observations, "
              "30-s segments, WLS at the neighbours)", "",
              "RMSE in units of the full set's σ, per parameter and mean:", "",
              "| subset | " + " | ".join(f"{r} {n}" for r, n in net["labels"]) + " | mean |",
              "|---|" + "---:|" * (len(net["labels"]) + 1)]
    for method, values in net["rmse"].items():
        lines.append(f"| {method} | " + " | ".join(f"{v:.2f}" for v in values)
                     + f" | {np.mean(values):.2f} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    args = parser.parse_args()
    warnings.filterwarnings("ignore", category=UserWarning)
    start = time.perf_counter()
    p2 = path2(args.seeds)
    net = crowded(args.seeds)
    figure(FIGURE)
    text = markdown(p2, net, args.seeds)
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    atomic_write_text(RESULTS / "selection_study.md", text)
    atomic_write_text(RESULTS / "selection_study.json",
                      json.dumps({"seeds": args.seeds, "path2": p2, "crowded": net}, indent=2)
                      + "\n")
    print(f"wrote {RESULTS / 'selection_study.md'}, {FIGURE} in "
          f"{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

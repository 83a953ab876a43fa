"""Speed of the whole ``graphcal calibrate`` process against a plain scipy fit.

Run from the repository root::

    .venv/bin/python -m benchmarks.bench_speed                    # 40k and 1M plots
    .venv/bin/python -m benchmarks.bench_speed --sizes 40k        # one size
    .venv/bin/python -m benchmarks.bench_speed --compare-root OLD # also time another tree

For every size a seeded dataset folder is simulated (and kept in ``--data-dir`` for
the next run): the four-radar network of ``benchmarks/scenarios/speed_opensky.toml``
flown by the real trajectories of the shared OpenSky table, or, where that table is
missing (or with ``--traffic synthetic``), by the random traffic of
``speed_synthetic.toml``.  A scenario is a 3-hour tile; the tile is simulated again
with the next seed, shifted by 3 hours and given new aircraft addresses until the
dataset has the plots asked for, and the dataset is then cut at the time of its
``N``-th plot.

Then three commands are timed end to end, as subprocesses, alternately and
``--repeats`` times each:

* ``graphcal calibrate DIR --out result.json`` with its defaults (ADS-B, every
  aircraft's path in the problem (``--cross trajectory``), Huber kernel, time offsets,
  Cramér-Rao bound and model checks);
* :mod:`benchmarks.scipy_adsb`, a plain scipy least-squares fit of the ADS-B model
  alone (range offset, gain, azimuth and elevation biases per radar, ADS-B
  interpolated to the plot times);
* the *import floor*: a Python process that only imports the outside libraries
  ``graphcal calibrate`` cannot run without (:data:`FLOOR_IMPORTS`: pandas with
  numpy and pyarrow, GTSAM, SciPy's special functions, typer) and exits.  No
  implementation on these libraries can be faster than this; its ratio to the
  script shows how much of the script's time is left for the work itself.

The table gives, per size, the median wall times, their ratio (and that of the CPU
times, less sensitive to other load on the machine), the child's peak memory and
graphcal's own stage timings (``info["timing_s"]`` of the result): loading, ADS-B
association, initial values, factors, optimisation, marginals (with the time-offset
check's), Cramér-Rao bound, model checks, and "other", the rest of the calibration
(residual statistics, down-weighting counts, observability); "start-up, output" is
the rest of the wall time (interpreter and imports, the command line, the JSON
written, exit).  The agreement of the two estimates, in graphcal's sigmas, is
printed as a sanity check: they fit different models (graphcal adds the time
offsets, the cross-radar observations and a robust kernel), so a few sigma is usual.

The ``graphcal`` package of each tree and these benchmarks are byte-compiled first,
as an installed package is (:func:`byte_compile`).

With ``--compare-root DIR`` the graphcal command is also run from the package tree
in ``DIR`` (e.g. an older checkout, with its ``models/``), labelled ``compared``, in
the same alternation, so that a before/after ratio is measured under the same load.
With ``--pairwise`` the same command with ``--cross pairwise`` (paper 001's pairs, the
baseline formulation) is run too, labelled ``pairwise``, and the default's ratio to it
printed: the default should take at most 1.5 times as long.  ``--no-adsb`` adds
``--no-adsb`` to every graphcal command (the cross-radar observations alone; the
scipy script, an ADS-B fit, is still run as the yardstick of the machine's speed).
The figures go to ``benchmarks/results/bench_speed.json`` (``--json``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from benchmarks import RESULTS

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS_PATH = RESULTS / "bench_speed.json"
OPENSKY_SCENARIO = HERE / "scenarios" / "speed_opensky.toml"
SYNTHETIC_SCENARIO = HERE / "scenarios" / "speed_synthetic.toml"
#: Sizes run by default.
DEFAULT_SIZES = "40k,1M"
#: Above this many plots one repeat is the default, below it three.
LARGE_PLOTS = 200_000
#: Changes whenever the datasets this script writes would change; part of the cache name.
DATASET_VERSION = 1
#: ``info["timing_s"]`` entries shown as stages, in order, with their labels.
STAGES: tuple[tuple[str, str], ...] = (
    ("load_s", "load"),
    ("association_s", "assoc"),
    ("initialisation_s", "init"),
    ("factors_s", "factors"),
    ("optimisation_s", "optimise"),
    ("marginals_s", "marginals"),
    ("crlb_s", "CRLB"),
    ("model_checks_s", "checks"),
)


# --------------------------------------------------------------------------- datasets
def parse_size(text: str) -> int:
    """``"40k"`` -> 40000, ``"1M"`` -> 1000000, ``"2500"`` -> 2500."""
    text = text.strip()
    factor = {"k": 1_000, "K": 1_000, "m": 1_000_000, "M": 1_000_000}.get(text[-1:], 1)
    number = text[:-1] if factor != 1 else text
    return int(round(float(number) * factor))


def choose_traffic(traffic: str, opensky: Path | None) -> tuple[str, Any]:
    """The traffic kind and its scenario: OpenSky when the table exists, else synthetic."""
    from graphcal.simulation.scenario import load_scenario

    if traffic in ("auto", "opensky"):
        scenario = load_scenario(OPENSKY_SCENARIO)
        if opensky is not None:
            scenario = replace(scenario, opensky=replace(scenario.opensky, file=opensky))
        if scenario.opensky.file.exists():
            return "opensky", scenario
        if traffic == "opensky":
            raise SystemExit(f"OpenSky table not found: {scenario.opensky.file}")
        print(f"OpenSky table not found ({scenario.opensky.file}): synthetic traffic")
    return "synthetic", load_scenario(SYNTHETIC_SCENARIO)


def make_dataset(n_plots: int, traffic: str, scenario: Any, seed: int, fmt: str,
                 data_dir: Path) -> Path:
    """Simulate (or find from an earlier run) a dataset folder of ``n_plots`` plots.

    Parameters
    ----------
    n_plots : int
        Plots wanted; the dataset is cut at the time of the ``n_plots``-th plot.
    traffic : str
        ``"opensky"`` or ``"synthetic"`` (part of the folder name).
    scenario : Scenario
        The 3-hour tile.
    seed : int
        Seed of the first tile; tile ``k`` uses ``seed + k``.
    fmt : {"csv", "parquet"}
        Table format of the folder.
    data_dir : Path
        Where the folders are kept.

    Returns
    -------
    Path
        The dataset folder (with ``truth.json``).
    """
    from graphcal.data.dataset import Dataset
    from graphcal.simulation.simulate import simulate, write_simulation

    folder = data_dir / f"v{DATASET_VERSION}-{traffic}-{n_plots}-seed{seed}-{fmt}"
    if (folder / "truth.json").exists():
        return folder
    duration = scenario.duration_s
    plots, adsb = [], []
    total, tile, first = 0, 0, None
    start = time.perf_counter()
    while total < n_plots:
        sim = simulate(scenario, np.random.default_rng(seed + tile))
        first = first or sim
        if tile >= 16:
            raise ValueError("more than 16 tiles: addresses would repeat")
        p, a = sim.dataset.plots.copy(), sim.dataset.adsb.copy()
        codes, names = pd.factorize(pd.concat([p["target_id"], a["target_id"]]), sort=True)
        # New 24-bit addresses: the tile in the top 4 bits, unique within the tile.
        address = np.array([f"{(tile << 20) + i:06x}" for i in range(len(names))], dtype=object)
        address = np.where(names == "", "", address)
        p["target_id"] = address[codes[: len(p)]]
        a["target_id"] = address[codes[len(p):]]
        p["time_s"] += tile * duration
        a["time_s"] += tile * duration
        plots.append(p)
        adsb.append(a)
        total += len(p)
        tile += 1
        print(f"  tile {tile}: {total:,} plots ({time.perf_counter() - start:.0f} s)", flush=True)
    all_plots = pd.concat(plots, ignore_index=True).sort_values("time_s", kind="stable")
    cut = float(all_plots["time_s"].iloc[n_plots - 1])
    all_plots = all_plots.iloc[:n_plots].reset_index(drop=True)
    all_adsb = pd.concat(adsb, ignore_index=True)
    all_adsb = all_adsb[all_adsb["time_s"] <= cut].sort_values("time_s", kind="stable")
    dataset = Dataset(first.dataset.sites, all_plots, all_adsb.reset_index(drop=True))
    write_simulation(replace(first, dataset=dataset), folder, fmt=fmt, overwrite=True)
    return folder


# --------------------------------------------------------------------------- timing
def _tree_pss_mib(pid: int) -> float | None:
    """Proportional set size [MiB] of process ``pid`` and its descendants (Linux), or None.

    Proportional: a page shared by a forked reader and its parent counts once in total,
    half in each, so the sum is the memory the command really holds.
    """
    total_kib, pending, found = 0, [pid], False
    while pending:
        current = pending.pop()
        try:
            text = Path(f"/proc/{current}/smaps_rollup").read_text()
            for task in Path(f"/proc/{current}/task").iterdir():
                children = (task / "children").read_text().split()
                pending.extend(int(c) for c in children)
        except OSError:
            continue
        for line in text.splitlines():
            if line.startswith("Pss:"):
                total_kib += int(line.split()[1])
                found = True
    return total_kib / 1024.0 if found else None


def run_timed(command: list[str], env: dict[str, str], cwd: Path) -> tuple[float, float, float]:
    """Run ``command`` in ``cwd``: its wall time [s], CPU time (user + system, with the
    processes it started) [s] and peak memory [MiB].

    The memory is the peak of the process tree's proportional set size, sampled every
    50 ms (Linux; ``graphcal calibrate --window`` reads in a forked child, whose memory
    the process's own ``ru_maxrss`` would leave out), or ``ru_maxrss`` where that is not
    available.

    Raises
    ------
    RuntimeError
        If the command fails (its standard error is included).
    """
    import threading

    log = cwd / "stderr.txt"
    peak = [0.0]
    with open(log, "w") as stderr:
        start = time.perf_counter()
        child = subprocess.Popen(command, env=env, cwd=cwd, stdout=subprocess.DEVNULL,
                                 stderr=stderr)
        done = threading.Event()

        def sample() -> None:
            while not done.wait(0.05):
                now = _tree_pss_mib(child.pid)
                if now is not None:
                    peak[0] = max(peak[0], now)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - start
        done.set()
        sampler.join()
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({child.returncode}):\n"
                           f"{log.read_text()}")
    scale = 1024.0**2 if sys.platform == "darwin" else 1024.0
    memory = peak[0] if peak[0] > 0.0 else usage.ru_maxrss / scale
    return wall, usage.ru_utime + usage.ru_stime, memory


def byte_compile(roots: list[Path]) -> None:
    """Byte-compile the ``graphcal`` package of each tree, and these benchmarks.

    An installed package comes compiled (``pip install`` compiles it); a source tree
    run where ``PYTHONDONTWRITEBYTECODE`` is set would otherwise compile every module
    at every run (about 0.2 s of each command), which a user's installation never does.
    """
    import compileall

    for folder in [*(root / "graphcal" for root in roots), ROOT / "benchmarks"]:
        if not compileall.compile_dir(folder, quiet=1):
            raise RuntimeError(f"cannot byte-compile {folder}")


def environment_for(root: Path) -> dict[str, str]:
    """The environment that makes ``python -m graphcal`` import the package under ``root``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(root), str(ROOT)])
    return env


def agreement(graph: dict[str, Any], plain: dict[str, Any]) -> float:
    """Largest ``|graphcal - scipy| / graphcal sigma`` over the terms both estimate."""
    worst = 0.0
    for rid, entry in plain["radars"].items():
        mine = graph["radars"].get(rid, {})
        for key, value in entry.items():
            sigma = (mine.get("sigma") or {}).get(key)
            if key == "sigma" or value is None or mine.get(key) is None or not sigma:
                continue
            worst = max(worst, abs(mine[key] - value) / sigma)
    return worst


#: The outside libraries every ``graphcal calibrate`` run imports (the import floor).
FLOOR_IMPORTS = ("pandas", "gtsam", "scipy.special", "typer")


def bench_size(label: str, folder: Path, repeats: int, roots: dict[str, Path],
               work: Path, window: str | None = None,
               extra_args: dict[str, list[str]] | None = None,
               warmup: int = 0) -> dict[str, Any]:
    """Time graphcal (each root) and the scipy script on one dataset, alternately, after
    ``warmup`` uncounted runs of each.

    ``roots``: each graphcal run's package tree by label; ``extra_args``: more options
    of a run's ``graphcal calibrate`` by label (``--cross pairwise``, ``--no-adsb``).

    Returns
    -------
    dict
        Wall times and peak memory per command (all repeats and medians), the
        stage timings of graphcal's last run per root, the ratios and the agreement.
    """
    commands = {
        name: ([sys.executable, "-m", "graphcal", "calibrate", str(folder), "--out",
                str(work / f"{name}.json"), *(["--window", window] if window else []),
                *(extra_args or {}).get(name, [])],
               environment_for(root))
        for name, root in roots.items()
    }
    commands["scipy"] = ([sys.executable, "-m", "benchmarks.scipy_adsb", str(folder), "--out",
                          str(work / "scipy.json")], environment_for(ROOT))
    commands["floor"] = ([sys.executable, "-c", f"import {', '.join(FLOOR_IMPORTS)}"],
                         environment_for(ROOT))
    walls: dict[str, list[float]] = {name: [] for name in commands}
    cpu: dict[str, list[float]] = {name: [] for name in commands}
    memory: dict[str, list[float]] = {name: [] for name in commands}
    stages: dict[str, list[dict[str, float]]] = {name: [] for name in roots}
    for _ in range(warmup):  # not counted: the first run after a write reads cold files
        for name, (command, env) in commands.items():
            (work / f"{name}.json").unlink(missing_ok=True)
            run_timed(command, env, work)
        print(f"  [{label}] warm-up run of every command done", flush=True)
    for repeat in range(repeats):
        for name, (command, env) in commands.items():
            if name in roots:  # calibrate refuses to replace its --out (it has --overwrite)
                (work / f"{name}.json").unlink(missing_ok=True)
            wall, seconds, rss = run_timed(command, env, work)  # not the root: it would come first
            walls[name].append(wall)
            cpu[name].append(seconds)
            memory[name].append(rss)
            if name in roots:
                stages[name].append(json.loads((work / f"{name}.json").read_text())
                                    ["info"].get("timing_s", {}))
            print(f"  [{label}] repeat {repeat + 1}/{repeats} {name}: {wall:.2f} s "
                  f"(CPU {seconds:.2f} s), {rss:.0f} MiB", flush=True)
    plain = json.loads((work / "scipy.json").read_text())
    truth = json.loads((folder / "truth.json").read_text())
    out: dict[str, Any] = {
        "label": label, "dataset": folder.name, "repeats": repeats, "warmup": warmup,
        "window": window,
        "floor_imports": list(FLOOR_IMPORTS),
        "n_plots": int(sum(e["n_plots"] for e in truth["radars"].values())),
        "wall_s": {name: {"median": statistics.median(t), "all": t} for name, t in walls.items()},
        "cpu_s": {name: {"median": statistics.median(t), "all": t} for name, t in cpu.items()},
        "peak_rss_mib": {name: max(m) for name, m in memory.items()},
        "stages_s": {}, "ratio_to_scipy": {}, "cpu_ratio_to_scipy": {}, "agreement_sigma": {},
    }
    out["ratio_to_scipy"]["floor"] = (statistics.median(walls["floor"])
                                      / statistics.median(walls["scipy"]))
    for name in roots:
        median_wall = statistics.median(walls[name])
        timing = {key: statistics.median(s.get(key, 0.0) for s in stages[name])
                  for key in {k for s in stages[name] for k in s}}
        timing["other_s"] = timing.get("total_s", 0.0) - sum(
            timing.get(key, 0.0) for key, _ in STAGES if key != "load_s")
        timing["startup_output_s"] = median_wall - timing.get("load_s", 0.0) - timing.get(
            "total_s", 0.0)
        out["stages_s"][name] = timing
        out["ratio_to_scipy"][name] = median_wall / statistics.median(walls["scipy"])
        out["cpu_ratio_to_scipy"][name] = (statistics.median(cpu[name])
                                           / statistics.median(cpu["scipy"]))
        graph = json.loads((work / f"{name}.json").read_text())
        out["agreement_sigma"][name] = agreement(graph, plain)
    return out


def print_table(results: list[dict[str, Any]], names: list[str]) -> None:
    """Print the size / graphcal / scipy / ratio / stages table."""
    header = ["size", "plots", "run", "wall s", "scipy s", "ratio", "CPU ratio", "MiB",
              *[label for _, label in STAGES], "other", "start-up, output"]
    rows = []
    for r in results:
        for name in names:
            timing = r["stages_s"][name]
            rows.append([
                r["label"], f"{r['n_plots']:,}", name, f"{r['wall_s'][name]['median']:.2f}",
                f"{r['wall_s']['scipy']['median']:.2f}", f"{r['ratio_to_scipy'][name]:.2f}",
                f"{r['cpu_ratio_to_scipy'][name]:.2f}",
                f"{r['peak_rss_mib'][name]:.0f}",
                *[f"{timing.get(key, 0.0):.2f}" for key, _ in STAGES],
                f"{timing['other_s']:.2f}",
                f"{timing['startup_output_s']:.2f}",
            ])
    widths = [max(len(str(row[i])) for row in [header, *rows]) for i in range(len(header))]
    print()
    for row in [header, ["-" * w for w in widths], *rows]:
        print("  ".join(str(c).rjust(w) for c, w in zip(row, widths, strict=True)))
    print("\n(wall: median end to end of `graphcal calibrate DIR --out x.json`; ratio: over the "
          "scipy script's; CPU ratio: the same for user + system CPU time, less sensitive to "
          "other load; stages: graphcal's info['timing_s'], medians)")
    for r in results:
        if len(names) > 1:
            base, base_cpu = r["wall_s"][names[-1]]["median"], r["cpu_s"][names[-1]]["median"]
            print(f"  [{r['label']}] " + ", ".join(
                f"{n} / {names[-1]} = {r['wall_s'][n]['median'] / base:.2f} "
                f"(CPU {r['cpu_s'][n]['median'] / base_cpu:.2f})" for n in names[:-1]))
        floor = r["wall_s"].get("floor")
        if floor is not None:
            print(f"  [{r['label']}] import floor ({', '.join(r['floor_imports'])}): "
                  f"{floor['median']:.2f} s, {r['ratio_to_scipy']['floor']:.2f} of the scipy "
                  "script's wall time")
        for name in names:
            print(f"  [{r['label']}] {name}: scipy peak {r['peak_rss_mib']['scipy']:.0f} MiB; "
                  f"max |graphcal - scipy| = {r['agreement_sigma'][name]:.1f} sigma")


def main(argv: list[str] | None = None) -> int:
    """Build the datasets, time both commands, print the table and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default=DEFAULT_SIZES,
                        help=f"comma-separated plot counts, e.g. 40k,1M (default {DEFAULT_SIZES})")
    parser.add_argument("--repeats", type=int, default=None,
                        help=f"runs of each command per size (default 3; 1 above "
                             f"{LARGE_PLOTS:,} plots)")
    parser.add_argument("--traffic", choices=("auto", "opensky", "synthetic"), default="auto",
                        help="OpenSky trajectories if the table exists (auto), or random ones")
    parser.add_argument("--opensky", type=Path, default=None,
                        help="the OpenSky table (default: the scenario's)")
    parser.add_argument("--format", dest="fmt", choices=("csv", "parquet"), default="csv",
                        help="table format of the dataset folders (default csv)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the first tile")
    parser.add_argument("--data-dir", type=Path,
                        default=Path(tempfile.gettempdir()) / "graphcal-bench-speed",
                        help="where the simulated datasets are kept between runs")
    parser.add_argument("--json", type=Path, default=RESULTS_PATH,
                        help="where to write the figures (default: RESULTS/bench_speed.json)")
    parser.add_argument("--window", default=None,
                        help="run graphcal with --window DURATION (e.g. 1h): biases over time, "
                        "read window by window")
    parser.add_argument("--compare-root", type=Path, default=None,
                        help="also time `graphcal calibrate` from the package tree in this "
                             "folder (labelled 'compared'), alternating with this one")
    parser.add_argument("--pairwise", action="store_true",
                        help="also time `graphcal calibrate --cross pairwise` (labelled "
                             "'pairwise'), alternating, and print the default's ratio to it")
    parser.add_argument("--warmup", type=int, default=None,
                        help=f"uncounted runs of each command first (default 1; 0 above "
                             f"{LARGE_PLOTS:,} plots)")
    parser.add_argument("--no-adsb", action="store_true",
                        help="give every graphcal command --no-adsb")
    args = parser.parse_args(argv)

    traffic, scenario = choose_traffic(args.traffic, args.opensky)
    roots = {"graphcal": ROOT}
    if args.compare_root is not None:
        roots["compared"] = args.compare_root.resolve()
    extra_args = {name: ["--no-adsb"] if args.no_adsb else [] for name in roots}
    if args.pairwise:
        roots["pairwise"] = ROOT
        extra_args["pairwise"] = ["--cross", "pairwise", *extra_args["graphcal"]]
    byte_compile(sorted(set(roots.values())))
    load = os.getloadavg()[0]
    print(f"traffic: {traffic}; load average {load:.2f} on {os.cpu_count()} CPUs "
          "(wall times: other load inflates them)")
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-speed-") as tmp:
        for label in args.sizes.split(","):
            n = parse_size(label)
            print(f"\n[{label}] dataset of {n:,} plots ({traffic}, seed {args.seed}) ...",
                  flush=True)
            folder = make_dataset(n, traffic, scenario, args.seed, args.fmt, args.data_dir)
            repeats = args.repeats or (1 if n > LARGE_PLOTS else 3)
            warmup = args.warmup if args.warmup is not None else (0 if n > LARGE_PLOTS else 1)
            results.append(bench_size(label, folder, repeats, roots, Path(tmp), args.window,
                                      extra_args, warmup))
    print_table(results, list(roots))
    document = {
        "benchmark": "bench_speed",
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "traffic": traffic, "format": args.fmt, "seed": args.seed,
        "runs": list(roots), "window": args.window, "no_adsb": args.no_adsb,
        "options": extra_args,
        "environment": {"load_average_1min": load, "cpu_count": os.cpu_count(),
                        "python": platform.python_version(), "machine": platform.machine()},
        "results": results,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(document, indent=2) + "\n")
    print(f"\nfigures written to {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

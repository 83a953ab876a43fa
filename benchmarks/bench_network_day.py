"""Benchmark of a day of a large network (20 radars, 1,000 aircraft): simulated, read in windows.

Run from the repository root::

    .venv/bin/python -m benchmarks.bench_network_day [--hours 24] [--window 3600]
        [--function benchmarks.bench_memory:read_windows] [--keep DIR] [--seed 1]
        [--folder DIR]

Stage 1 simulates ``benchmarks/scenarios/network_20radars_24h.toml`` chunk by chunk
(one hour at a time, :func:`graphcal.simulation.stream.simulate_to_folder`) into a
Parquet dataset folder, in a fresh Python process whose time and peak memory are
measured.  ``--hours H`` simulates only the first H hours (the same traffic cut
there) and extrapolates the time and the counts to the whole day by the aircraft's
flight time inside the span, which is what the simulation's cost follows; the
figures say so.  Stage 2 runs the measured function (``--function MODULE:NAME``,
``NAME(folder, window_s) -> dict``, as in :mod:`benchmarks.bench_memory`; default: read
every window) on the folder, again in a fresh process, for its time, throughput and
peak memory.  ``--no-read`` skips stage 2; ``--folder DIR`` skips stage 1 and measures
stage 2 on a folder simulated before (``--keep DIR``).

Outputs: a table on stdout and ``benchmarks/results/bench_network_day.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.bench_memory import (
    DEFAULT_FUNCTION,
    measure_in_subprocess,
    peak_rss_mb,
    rss_mb,
)
from graphcal.core.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SCENARIO = ROOT / "benchmarks" / "scenarios" / "network_20radars_24h.toml"


def flight_hours(hours: float, seed: int) -> float:
    """Hours flown inside ``[0, hours]`` by the scenario's aircraft (seeded traffic)."""
    from graphcal.simulation.scenario import load_scenario
    from graphcal.simulation.simulate import build_trajectories

    scenario = dataclasses.replace(load_scenario(SCENARIO), duration_s=hours * 3600.0)
    flights, _ = build_trajectories(scenario, np.random.default_rng(seed))
    return sum(max(0.0, min(f.end_s, hours * 3600.0) - max(f.start_s, 0.0))
               for f in flights) / 3600.0


def simulate(folder: Path, hours: float, seed: int) -> dict:
    """Simulate the first ``hours`` into ``folder`` here; counts, time and peak memory."""
    from graphcal.simulation.scenario import load_scenario
    from graphcal.simulation.stream import simulate_to_folder

    scenario = dataclasses.replace(load_scenario(SCENARIO), duration_s=hours * 3600.0)
    baseline = rss_mb()
    start = time.perf_counter()
    written = simulate_to_folder(scenario, np.random.default_rng(seed), folder,
                                 chunk_s=3600.0)
    return {"hours": hours, "seconds": time.perf_counter() - start,
            "plots": written.total_plots, "adsb": written.n_adsb,
            "peak_rss_mb": peak_rss_mb(), "baseline_rss_mb": baseline,
            "bytes_on_disk": sum(p.stat().st_size for p in folder.iterdir())}


def simulate_in_subprocess(folder: Path, hours: float, seed: int) -> dict:
    """:func:`simulate` in a fresh Python process (its own peak memory)."""
    command = [sys.executable, "-m", "benchmarks.bench_network_day", "--simulate-into",
               str(folder), "--hours", str(hours), "--seed", str(seed)]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def count_rows(folder: Path, table: str) -> int:
    """Rows of a dataset folder's table (Parquet footers, else CSV lines less headers)."""
    import pyarrow.parquet as pq

    files = sorted(folder.glob(f"{table}.parquet")) + sorted((folder / table).glob("*.parquet"))
    if files:
        return sum(pq.ParquetFile(f).metadata.num_rows for f in files)
    files = sorted(folder.glob(f"{table}.csv")) + sorted((folder / table).glob("*.csv"))
    return sum(sum(1 for _ in open(f, "rb")) - 1 for f in files)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0,
                        help="simulate the first HOURS hours and extrapolate to 24 h")
    parser.add_argument("--window", type=float, default=3600.0, help="window [s]")
    parser.add_argument("--function", default=DEFAULT_FUNCTION, help="MODULE:NAME measured")
    parser.add_argument("--no-read", action="store_true", help="only simulate")
    parser.add_argument("--keep", type=Path, help="simulate into this folder and keep it")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--folder", type=Path,
                        help="measure stage 2 on this dataset folder, simulated before "
                             "(e.g. with --keep), instead of simulating again")
    parser.add_argument("--simulate-into", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.simulate_into is not None:
        print(json.dumps(simulate(args.simulate_into, args.hours, args.seed)))
        return 0
    document: dict = {"scenario": SCENARIO.name, "seed": args.seed, "hours": args.hours,
                      "machine": platform.platform(), "python": platform.python_version()}
    with tempfile.TemporaryDirectory(prefix="bench-day-") as scratch:
        folder = args.keep if args.keep is not None else Path(scratch) / "day"
        scale = 1.0
        if args.folder is not None:
            folder = args.folder
            sim = {"folder": str(folder), "plots": count_rows(folder, "plots"),
                   "adsb": count_rows(folder, "adsb")}
            print(f"reused {folder}: {sim['plots']:,} plots, {sim['adsb']:,} ADS-B")
        else:
            sim = simulate_in_subprocess(folder, args.hours, args.seed)
            if args.hours < 24.0:
                scale = flight_hours(24.0, args.seed) / flight_hours(args.hours, args.seed)
            print(f"simulated {args.hours:g} h: {sim['plots']:,} plots, {sim['adsb']:,} ADS-B "
                  f"in {sim['seconds']:.1f} s ({sim['plots'] / sim['seconds']:,.0f} plots/s), "
                  f"peak {sim['peak_rss_mb']:.0f} MB, {sim['bytes_on_disk'] / 1e6:.0f} MB of "
                  "Parquet")
        sim["scale_to_day"] = scale
        document["simulate"] = sim
        if scale != 1.0:
            print(f"extrapolated to 24 h by flight time (x{scale:.2f}): about "
                  f"{sim['plots'] * scale / 1e6:.1f} M plots, {sim['adsb'] * scale / 1e6:.1f} M "
                  f"ADS-B, {sim['seconds'] * scale / 60:.0f} min; the peak memory is that of "
                  "one chunk")
        if not args.no_read:
            read = measure_in_subprocess(folder, args.window, args.function)
            document["read"] = {"function": args.function, "window_s": args.window, **read}
            print(f"{args.function} in {args.window:g} s windows: {read['seconds']:.1f} s "
                  f"({sim['plots'] / read['seconds']:,.0f} plots/s), peak "
                  f"{read['peak_rss_mb']:.0f} MB; {read['summary']}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    atomic_write_text(RESULTS / "bench_network_day.json", json.dumps(document, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

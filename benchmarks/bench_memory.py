"""Benchmark of memory bounded by a window: a 17-hour recording read window by window vs 2 hours.

Run from the repository root::

    .venv/bin/python -m benchmarks.bench_memory [--hours 2 17] [--window 1800]
        [--function benchmarks.bench_memory:read_windows] [--format parquet] [--seed 1]

For each duration the scenario ``benchmarks/scenarios/network_4radars_17h.toml`` (four
radars, steady traffic) is cut to that many hours and simulated (seeded) chunk by chunk
into a temporary dataset folder (:func:`graphcal.simulation.stream.simulate_to_folder`).
Then the *measured function* runs on each folder in a fresh Python process, and that
process's peak resident memory is read (:func:`peak_rss_mb`): in total, and above what
the process held just before the call (the interpreter and the libraries).  The target:
the peak for 17 hours at most 1.5 times the peak for 2 hours, the same window.
``--function benchmarks.bench_memory:calibrate_windows`` measures the whole windowed
calibration (``calibrate --window``) instead of the reading alone, and
``--function benchmarks.bench_memory:calibrate_batch`` the constant-bias calibration
(``calibrate`` without ``--window``: loaded whole up to 2 hours, from 1-hour windows
beyond).

The measured function is a parameter, ``--function MODULE:NAME``: any function
``NAME(folder: Path, window_s: float) -> dict`` (a summary, printed); the default,
:func:`read_windows`, reads every window with :func:`graphcal.io.window_reader.iter_windows`
(validation and cleaning included) and counts its rows.  A windowed calibration can be
measured the same way.

Outputs: a table on stdout and ``benchmarks/results/bench_memory.json`` (``--json``).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import platform
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks import RESULTS
from graphcal.core.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "benchmarks" / "scenarios" / "network_4radars_17h.toml"
DEFAULT_FUNCTION = "benchmarks.bench_memory:read_windows"
TARGET_RATIO = 1.5


def read_windows(folder: Path, window_s: float) -> dict:
    """Read every window of ``folder`` (validated and cleaned) and count what it holds."""
    from graphcal.io.window_reader import iter_windows

    windows = plots = adsb = largest = 0
    for window in iter_windows(folder, window_s):
        n_adsb = 0 if window.dataset.adsb is None else len(window.dataset.adsb)
        windows += 1
        plots += window.n_plots
        adsb += n_adsb
        largest = max(largest, window.n_plots + n_adsb)
    return {"windows": windows, "plots": plots, "adsb_in_windows": adsb,
            "largest_window_rows": largest}


def calibrate_windows(folder: Path, window_s: float) -> dict:
    """The whole windowed calibration of the folder (``calibrate --window``), streamed."""
    from graphcal.pipeline.calibrate import calibrate

    cal = calibrate(folder, window=window_s)
    events = [f"{e['radar_id']}@{e['time_s']:.0f}s" for e in cal.events or []]
    return {"windows": cal.info["windows"]["n_windows"], "events": events,
            "radars": len(cal.radar_ids),
            "summaries_s": round(cal.info["timing_s"].get("summaries_s", 0.0), 1)}


def calibrate_batch(folder: Path, window_s: float) -> dict:
    """The constant-bias calibration of the folder (``calibrate`` without ``--window``):
    loaded whole up to 2 hours, beyond that solved from 1-hour windows read one at a
    time.  ``window_s`` is not used."""
    from graphcal.pipeline.calibrate import calibrate

    del window_s
    cal = calibrate(folder)
    windows = cal.info.get("windows") or {}
    return {"windows": windows.get("n_windows", 1), "constant": bool(windows.get("constant")),
            "radars": len(cal.radar_ids), "plots": int(sum(cal.n_plots.values()))}


def load_function(spec: str) -> Callable[[Path, float], dict]:
    """The function named ``MODULE:NAME``."""
    module, _, name = spec.partition(":")
    if not name:
        raise SystemExit(f"--function must be MODULE:NAME, not {spec!r}")
    return getattr(importlib.import_module(module), name)


def _status_mb(key: str) -> float | None:
    """A ``/proc/self/status`` memory figure [MB] (Linux), ``None`` elsewhere."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith(f"{key}:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far [MB].

    Linux's ``VmHWM`` when there is one: unlike ``ru_maxrss``, which a process
    started by ``fork`` and ``exec`` inherits from its parent, it counts this
    program only.  Elsewhere ``ru_maxrss`` (KiB on Linux, bytes on macOS).
    """
    high_water = _status_mb("VmHWM")
    if high_water is not None:
        return high_water
    scale = 1024.0 * 1024.0 if sys.platform == "darwin" else 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / scale


def rss_mb() -> float:
    """Resident memory of this process now [MB] (its peak where that is unknown)."""
    current = _status_mb("VmRSS")
    return peak_rss_mb() if current is None else current


def measure(folder: Path, window_s: float, spec: str) -> dict:
    """Run the measured function here; its time and this process's peak memory."""
    function = load_function(spec)
    importlib.import_module("graphcal.io.window_reader")
    baseline = rss_mb()
    start = time.perf_counter()
    summary = function(folder, window_s)
    return {"seconds": time.perf_counter() - start, "peak_rss_mb": peak_rss_mb(),
            "baseline_rss_mb": baseline, "summary": summary}


def measure_in_subprocess(folder: Path, window_s: float, spec: str) -> dict:
    """:func:`measure` in a fresh Python process (its own peak memory)."""
    command = [sys.executable, "-m", "benchmarks.bench_memory", "--measure", str(folder),
               "--window", str(window_s), "--function", spec]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def simulate_hours(hours: float, folder: Path, seed: int, fmt: str) -> dict:
    """The benchmark scenario cut to ``hours``, simulated into ``folder``; counts and time."""
    from graphcal.simulation.scenario import load_scenario
    from graphcal.simulation.stream import simulate_to_folder

    scenario = dataclasses.replace(load_scenario(SCENARIO), duration_s=hours * 3600.0)
    start = time.perf_counter()
    written = simulate_to_folder(scenario, np.random.default_rng(seed), folder, fmt=fmt,
                                 chunk_s=3600.0)
    return {"hours": hours, "plots": written.total_plots, "adsb": written.n_adsb,
            "simulate_s": time.perf_counter() - start}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, nargs=2, default=[2.0, 17.0],
                        metavar=("SHORT", "LONG"))
    parser.add_argument("--window", type=float, default=1800.0, help="window [s]")
    parser.add_argument("--function", default=DEFAULT_FUNCTION, help="MODULE:NAME measured")
    parser.add_argument("--format", choices=["parquet", "csv"], default="parquet")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None,
                        help="where to write the figures (default: RESULTS/bench_memory.json)")
    parser.add_argument("--measure", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure is not None:
        print(json.dumps(measure(args.measure, args.window, args.function)))
        return 0
    cases = []
    with tempfile.TemporaryDirectory(prefix="bench-memory-") as scratch:
        for hours in args.hours:
            folder = Path(scratch) / f"{hours:g}h"
            case = simulate_hours(hours, folder, args.seed, args.format)
            case.update(measure_in_subprocess(folder, args.window, args.function))
            case["above_baseline_mb"] = case["peak_rss_mb"] - case["baseline_rss_mb"]
            cases.append(case)
            print(f"{hours:5g} h: {case['plots']:>9,} plots {case['adsb']:>9,} ADS-B "
                  f"(simulated in {case['simulate_s']:.1f} s); {args.function} in "
                  f"{case['seconds']:.1f} s, peak {case['peak_rss_mb']:.0f} MB "
                  f"({case['above_baseline_mb']:.0f} MB above the "
                  f"{case['baseline_rss_mb']:.0f} MB before the call); {case['summary']}",
                  flush=True)
    short, long = cases
    ratio = long["peak_rss_mb"] / short["peak_rss_mb"]
    ratio_above = long["above_baseline_mb"] / max(short["above_baseline_mb"], 1e-9)
    data_ratio = long["plots"] / max(short["plots"], 1)
    verdict = "meets" if ratio <= TARGET_RATIO else "misses"
    print(f"data {data_ratio:.1f}x; peak memory {ratio:.2f}x ({ratio_above:.2f}x above the "
          f"baseline): {verdict} the target of at most {TARGET_RATIO}x")
    document = {"function": args.function, "window_s": args.window, "format": args.format,
                "seed": args.seed, "cases": cases, "peak_ratio": ratio,
                "peak_ratio_above_baseline": ratio_above, "data_ratio": data_ratio,
                "target_ratio": TARGET_RATIO, "machine": platform.platform(),
                "python": platform.python_version()}
    target = args.json if args.json is not None else RESULTS / "bench_memory.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(target, json.dumps(document, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

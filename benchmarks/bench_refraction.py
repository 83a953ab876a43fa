"""Benchmark of the refraction model (:mod:`graphcal.core.refraction`): cost per plot.

Run from the repository root::

    .venv/bin/python -m benchmarks.bench_refraction [--plots 100000] [--seed 0]

``--plots`` targets are drawn around a radar at 48.85 N, 140 m (seeded
``numpy.random.default_rng``): ground distance 2-300 km, height 0-12 km
(aircraft), azimuth uniform; the atmosphere is ``N_s = 320``, ``H = 7 km``.
Each function of the module's public API is timed on all of them at once (best
of ``--repeat`` runs), beside its straight-line counterpart in
:mod:`graphcal.core.frames`, and its round trip is checked: the inverse of
the forward result must give the targets back.  Target: well under 10 us per
plot for the forward model.

Outputs: a table on stdout and ``benchmarks/results/bench_refraction.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from graphcal.core import frames
from graphcal.core.atomic import atomic_write_text
from graphcal.core.refraction import (
    Atmosphere,
    apparent_elevation_from_height,
    apparent_elevation_from_height_jacobian,
    refracted_polar,
    refracted_polar_jacobian,
    refracted_ray,
    target_from_refracted,
    target_from_refracted_jacobian,
)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
TARGET_US = 10.0
LAT_RAD, ALT_M = math.radians(48.85), 140.0
ATMOSPHERE = Atmosphere(320.0, 7000.0)


def targets(n: int, rng: np.random.Generator) -> np.ndarray:
    """ENU targets at random ground distance, height and azimuth over the local sphere."""
    radius = float(frames.gaussian_radius_m(LAT_RAD))
    ground = rng.uniform(2e3, 3e5, n)
    height = rng.uniform(0.0, 1.2e4, n)
    azimuth = rng.uniform(0.0, 2.0 * math.pi, n)
    theta = ground / radius
    r = radius + height
    return np.column_stack([r * np.sin(theta) * np.sin(azimuth),
                            r * np.sin(theta) * np.cos(azimuth),
                            r * np.cos(theta) - (radius + ALT_M)])


def best_time(call: Callable[[], object], repeat: int) -> float:
    """Best wall time [s] of ``repeat`` calls."""
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plots", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    enu = targets(args.plots, np.random.default_rng(args.seed))
    ray = refracted_ray(ATMOSPHERE, LAT_RAD, ALT_M, enu)
    polar = np.column_stack([ray.range_m, ray.azimuth_rad, ray.elevation_rad])
    height = ray.target_height_m
    straight = np.column_stack(frames.enu_to_polar(enu))
    cases: list[tuple[str, Callable[[], object], Callable[[], object]]] = [
        ("refracted_polar",
         lambda: refracted_polar(ATMOSPHERE, LAT_RAD, ALT_M, enu),
         lambda: frames.enu_to_polar(enu)),
        ("refracted_polar_jacobian",
         lambda: refracted_polar_jacobian(ATMOSPHERE, LAT_RAD, ALT_M, enu),
         lambda: frames.enu_to_polar_jacobian(enu)),
        ("target_from_refracted",
         lambda: target_from_refracted(ATMOSPHERE, LAT_RAD, ALT_M, *polar.T),
         lambda: frames.polar_to_enu(*straight.T)),
        ("target_from_refracted_jacobian",
         lambda: target_from_refracted_jacobian(ATMOSPHERE, LAT_RAD, ALT_M, *polar.T),
         lambda: frames.polar_to_enu_jacobian(*straight.T)),
        ("apparent_elevation_from_height",
         lambda: apparent_elevation_from_height(ATMOSPHERE, LAT_RAD, ALT_M, polar[:, 0], height),
         lambda: frames.elevation_from_height(straight[:, 0], height, LAT_RAD, ALT_M)),
        ("apparent_elevation_from_height_jacobian",
         lambda: apparent_elevation_from_height_jacobian(ATMOSPHERE, LAT_RAD, ALT_M,
                                                         polar[:, 0], height),
         lambda: frames.elevation_from_height(straight[:, 0], height, LAT_RAD, ALT_M)),
    ]
    print(f"{args.plots} plots, N_s = {ATMOSPHERE.n_s:g}, H = {ATMOSPHERE.scale_height_m:g} m, "
          f"ground 2-300 km, height 0-12 km")
    print(f"{'function':42s} {'us/plot':>8s} {'straight us/plot':>17s}")
    timings = {}
    for name, refracted, line in cases:
        us = best_time(refracted, args.repeat) / args.plots * 1e6
        us_line = best_time(line, args.repeat) / args.plots * 1e6
        timings[name] = {"us_per_plot": us, "straight_us_per_plot": us_line}
        print(f"{name:42s} {us:8.2f} {us_line:17.3f}")
    back = target_from_refracted(ATMOSPHERE, LAT_RAD, ALT_M, *polar.T)
    e0 = apparent_elevation_from_height(ATMOSPHERE, LAT_RAD, ALT_M, polar[:, 0], height)
    round_trip_m = float(np.max(np.linalg.norm(back - enu, axis=1)))
    round_trip_rad = float(np.max(np.abs(e0 - polar[:, 2])))
    excess = ray.range_m - straight[:, 0]
    bending = ray.elevation_rad - straight[:, 2]
    print(f"round trips: position {round_trip_m:.1e} m, elevation from height "
          f"{round_trip_rad:.1e} rad")
    print(f"range excess {excess.min():.2f} to {excess.max():.2f} m, "
          f"bending {bending.min() * 1e3:.3f} to {bending.max() * 1e3:.3f} mrad")
    forward = timings["refracted_polar"]["us_per_plot"]
    verdict = "PASS" if forward < TARGET_US else "FAIL"
    print(f"forward model {forward:.2f} us/plot, target < {TARGET_US:g}: {verdict}")
    atomic_write_text(RESULTS / "bench_refraction.json", json.dumps({
        "plots": args.plots, "seed": args.seed, "repeat": args.repeat,
        "atmosphere": {"n_s": ATMOSPHERE.n_s, "scale_height_m": ATMOSPHERE.scale_height_m},
        "machine": platform.machine(), "python": platform.python_version(),
        "timings": timings,
        "round_trip": {"position_m": round_trip_m, "elevation_rad": round_trip_rad},
        "range_excess_m": [float(excess.min()), float(excess.max())],
        "bending_mrad": [float(bending.min() * 1e3), float(bending.max() * 1e3)],
    }, indent=2) + "\n")
    print(f"wrote {RESULTS / 'bench_refraction.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

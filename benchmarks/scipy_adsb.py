"""A plain scipy least-squares fit of the ADS-B model alone: the reference of ``bench_speed``.

Run from the repository root::

    .venv/bin/python -m benchmarks.scipy_adsb DIR --out result.json

This is what a short script without graphcal does with a dataset folder (contract
format, CSV or Parquet): read ``sites.toml``, the plots and the ADS-B reports with
pandas; interpolate each aircraft's ADS-B positions (ECEF, linearly in time, no gap
longer than ``--max-gap-s``) to the times of its plots; convert them to each radar's
range, azimuth and elevation; and fit, radar by radar, the model

    range_m       = (1 + range_gain) * range_adsb + range_offset_m
    azimuth_rad   = azimuth_adsb + azimuth_bias_rad
    elevation_rad = elevation_adsb + elevation_bias_rad      (3-D radars)

with :func:`scipy.optimize.least_squares` (``trf``, the analytic Jacobian,
``x_scale="jac"``, from zero, as ``bench_graph`` part 1 calls it) on the residuals
whitened by the radar's sigmas.  The 1-sigma of each term comes from ``(J^T J)^-1`` at
the solution.  The ADS-B model alone separates by radar, so each radar is its own fit.
It knows nothing of time-stamping biases, cross-radar observations, robust kernels,
refraction or pressure altitudes, and writes a small JSON with the same keys and units
as graphcal's result (``radars.ID.KEY`` and ``radars.ID.sigma.KEY``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

#: WGS-84 semi-major axis [m] and first eccentricity squared.
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3


def read_table(folder: Path, name: str) -> pd.DataFrame:
    """``name.parquet`` or ``name.csv`` of a dataset folder."""
    parquet = folder / f"{name}.parquet"
    if parquet.exists():
        return pd.read_parquet(parquet)
    return pd.read_csv(folder / f"{name}.csv", dtype={"target_id": str, "radar_id": str})


def ecef(lat_rad: np.ndarray, lon_rad: np.ndarray, alt_m: np.ndarray) -> np.ndarray:
    """Geodetic WGS-84 coordinates to ECEF ``(n, 3)`` [m]."""
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat_rad) ** 2)
    return np.stack([
        (n + alt_m) * np.cos(lat_rad) * np.cos(lon_rad),
        (n + alt_m) * np.cos(lat_rad) * np.sin(lon_rad),
        (n * (1.0 - WGS84_E2) + alt_m) * np.sin(lat_rad),
    ], axis=-1)


def polar(site: dict, points_ecef: np.ndarray) -> np.ndarray:
    """ECEF points to the radar's ``(range m, azimuth rad, elevation rad)``, ``(n, 3)``."""
    lat, lon = np.deg2rad(site["lat_deg"]), np.deg2rad(site["lon_deg"])
    origin = ecef(np.array(lat), np.array(lon), np.array(site["alt_m"]))
    rotation = np.array([
        [-np.sin(lon), np.cos(lon), 0.0],
        [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
        [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)],
    ])
    east, north, up = ((points_ecef - origin) @ rotation.T).T
    horizontal = np.hypot(east, north)
    return np.stack([np.sqrt(horizontal**2 + up**2), np.mod(np.arctan2(east, north), 2 * np.pi),
                     np.arctan2(up, horizontal)], axis=-1)


def interpolate_adsb(plots: pd.DataFrame, adsb: pd.DataFrame, max_gap_s: float) -> np.ndarray:
    """Each plot's ADS-B position (ECEF ``(n, 3)``, NaN where not bracketed within the gap)."""
    adsb = adsb.sort_values(["target_id", "time_s"], kind="stable")
    points = ecef(np.deg2rad(adsb["lat_deg"].to_numpy()), np.deg2rad(adsb["lon_deg"].to_numpy()),
                  adsb["alt_m"].to_numpy())
    times = adsb["time_s"].to_numpy()
    reference = np.full((len(plots), 3), np.nan)
    plot_time = plots["time_s"].to_numpy()
    plot_rows = plots.groupby("target_id", sort=False).indices
    for target, rows in adsb.groupby("target_id", sort=False).indices.items():
        mine = plot_rows.get(target)
        if mine is None or len(rows) < 2:
            continue
        t, xyz = times[rows], points[rows]
        query = plot_time[mine]
        j = np.clip(np.searchsorted(t, query, side="right") - 1, 0, len(t) - 2)
        w = (query - t[j]) / (t[j + 1] - t[j])
        ok = (w >= 0.0) & (w <= 1.0) & (t[j + 1] - t[j] <= max_gap_s)
        reference[mine[ok]] = (1.0 - w[ok, None]) * xyz[j[ok]] + w[ok, None] * xyz[j[ok] + 1]
    return reference


def fit_radar(site: dict, measured: np.ndarray, reference: np.ndarray) -> dict:
    """Least-squares biases of one radar against its plots' ADS-B reference positions.

    Parameters
    ----------
    site : dict
        The radar's ``[[radar]]`` table of ``sites.toml``.
    measured : ndarray (n, 3)
        The plots' range [m], azimuth and elevation [rad] (elevation NaN for 2-D).
    reference : ndarray (n, 3)
        The ADS-B positions in the radar's polar coordinates.

    Returns
    -------
    dict
        The radar's entry of the result: values and sigmas in contract units.
    """
    is_3d = "sigma_elevation_mrad" in site
    sigma = np.array([site["sigma_range_m"], site["sigma_azimuth_mrad"] * 1e-3,
                      site.get("sigma_elevation_mrad", np.nan) * 1e-3])
    rows = 3 if is_3d else 2
    difference = measured[:, :rows] - reference[:, :rows]
    difference[:, 1] = np.mod(difference[:, 1] + np.pi, 2 * np.pi) - np.pi
    n = len(difference)
    # Columns: range offset, range gain, azimuth bias, elevation bias; those not in the
    # radar's ``estimate`` list are dropped (held at zero).
    full = np.zeros((n, rows, 4))
    full[:, 0, 0] = -1.0 / sigma[0]
    full[:, 0, 1] = -reference[:, 0] / sigma[0]
    full[:, 1, 2] = -1.0 / sigma[1]
    if is_3d:
        full[:, 2, 3] = -1.0 / sigma[2]
    names = ["range_offset", "range_gain", "azimuth_bias", "elevation_bias"][: rows + 1]
    free = [i for i, name in enumerate(names) if name in site.get("estimate", names)]
    jacobian = full[:, :, free].reshape(n * rows, len(free))
    whitened = (difference / sigma[:rows]).ravel()

    def residuals(x: np.ndarray) -> np.ndarray:
        return whitened + jacobian @ x

    fit = least_squares(residuals, np.zeros(len(free)), jac=lambda x: jacobian, method="trf",
                        x_scale="jac")
    covariance = np.linalg.inv(fit.jac.T @ fit.jac)
    scale = np.array([1.0, 1.0, 1e3, 1e3])[free]  # to contract units (m, -, mrad)
    keys = ["range_offset_m", "range_gain", "azimuth_bias_mrad", "elevation_bias_mrad"]
    entry: dict = dict.fromkeys(keys)
    entry["sigma"] = {}
    for i, value, variance, unit in zip(free, fit.x, np.diag(covariance), scale, strict=True):
        entry[keys[i]] = float(value * unit)
        entry["sigma"][keys[i]] = float(np.sqrt(variance) * unit)
    entry["n_plots"] = n
    entry["nfev"] = int(fit.nfev)
    return entry


def main(argv: list[str] | None = None) -> int:
    """Fit every radar of a dataset folder and write the JSON result."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="dataset folder")
    parser.add_argument("--out", type=Path, required=True, help="result JSON to write")
    parser.add_argument("--max-gap-s", type=float, default=10.0,
                        help="longest ADS-B gap bridged by interpolation [s]")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    with open(args.folder / "sites.toml", "rb") as stream:
        sites = {site["id"]: site for site in tomllib.load(stream)["radar"]}
    plots = read_table(args.folder, "plots")
    adsb = read_table(args.folder, "adsb")
    reference = interpolate_adsb(plots, adsb, args.max_gap_s)
    measured = np.stack([plots["range_m"].to_numpy(), np.deg2rad(plots["azimuth_deg"]),
                         np.deg2rad(plots["elevation_deg"])], axis=-1)
    matched = np.isfinite(reference[:, 0])
    radars = {}
    for radar_id, rows in plots.groupby("radar_id", sort=False).indices.items():
        rows = rows[matched[rows]]
        site = sites[radar_id]
        radars[radar_id] = fit_radar(site, measured[rows], polar(site, reference[rows]))
    result = {"method": "scipy least_squares, ADS-B model", "radars": radars,
              "seconds": time.perf_counter() - start}
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Small synthetic datasets for estimator tests, built independently of the simulator.

Geometry goes through pymap3d (an outside library), not graphcal.core.frames, so the
estimator tests do not share conversion code with the estimators they check.
Plots are taken at regular times (no antenna sweep) - enough for estimators.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import pymap3d

from graphcal.data.bias import RadarBias
from graphcal.data.dataset import Dataset, Site

ORIGIN = (48.8, 2.4, 0.0)  # lat deg, lon deg, alt m


@dataclass
class Track:
    """Constant-velocity aircraft in the ENU frame of :data:`ORIGIN`."""

    target_id: str
    start_enu_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    t0_s: float
    duration_s: float

    def enu(self, t: np.ndarray) -> np.ndarray:
        dt = (t - self.t0_s)[:, None]
        return np.asarray(self.start_enu_m) + dt * np.asarray(self.velocity_mps)


def site_at(
    radar_id: str,
    east_m: float,
    north_m: float,
    *,
    sigma_range_m: float = 30.0,
    sigma_azimuth_mrad: float = 1.0,
    sigma_elevation_mrad: float | None = None,
    scan_period_s: float = 4.0,
    estimate: tuple[str, ...] = (),
) -> Site:
    lat, lon, alt = pymap3d.enu2geodetic(east_m, north_m, 50.0, *ORIGIN)
    return Site(
        id=radar_id,
        lat_rad=np.deg2rad(lat),
        lon_rad=np.deg2rad(lon),
        alt_m=float(alt),
        sigma_range_m=sigma_range_m,
        sigma_azimuth_rad=sigma_azimuth_mrad * 1e-3,
        sigma_elevation_rad=None if sigma_elevation_mrad is None else sigma_elevation_mrad * 1e-3,
        scan_period_s=scan_period_s,
        estimate=estimate,
    )


def make_dataset(
    rng: np.random.Generator,
    radars: list[tuple[Site, RadarBias]],
    tracks: list[Track],
    *,
    adsb: bool = True,
    adsb_sigma_m: float = 10.0,
    noise: bool = True,
) -> Dataset:
    """Plots of every radar for every track at its scan times, plus 1 Hz ADS-B."""
    rows = []
    for site, bias in radars:
        phase = rng.uniform(0, site.scan_period_s)
        for track in tracks:
            t = np.arange(track.t0_s + phase, track.t0_s + track.duration_s, site.scan_period_s)
            e, n, u = track.enu(t).T
            lat, lon, alt = pymap3d.enu2geodetic(e, n, u, *ORIGIN)
            az, el, rng_m = pymap3d.geodetic2aer(
                lat, lon, alt, np.rad2deg(site.lat_rad), np.rad2deg(site.lon_rad), site.alt_m
            )
            az_rad, el_rad = np.deg2rad(az), np.deg2rad(el)
            k = len(t)
            nr = rng.normal(0, site.sigma_range_m, k) if noise else 0.0
            na = rng.normal(0, site.sigma_azimuth_rad, k) if noise else 0.0
            r_meas = (1 + bias.range_gain) * rng_m + bias.range_offset_m + nr
            eccentricity = (bias.azimuth_sin_rad * np.sin(az_rad)
                            + bias.azimuth_cos_rad * np.cos(az_rad))
            az_meas = np.mod(az_rad + bias.azimuth_bias_rad + eccentricity + na, 2 * np.pi)
            if site.is_3d:
                ne = rng.normal(0, site.sigma_elevation_rad, k) if noise else 0.0
                el_meas = np.rad2deg(el_rad + bias.elevation_bias_rad + ne)
            else:
                el_meas = np.full(k, np.nan)
            rows.append(
                pd.DataFrame(
                    {
                        "radar_id": site.id,
                        "time_s": t + bias.time_offset_s,
                        "range_m": r_meas,
                        "azimuth_deg": np.rad2deg(az_meas),
                        "elevation_deg": el_meas,
                        "target_id": track.target_id,
                        "altitude_m": alt,
                    }
                )
            )
    plots = pd.concat(rows, ignore_index=True).sort_values("time_s", ignore_index=True)
    adsb_table = None
    if adsb:
        reports = []
        for track in tracks:
            t = np.arange(track.t0_s, track.t0_s + track.duration_s, 1.0)
            enu = track.enu(t)
            if noise:
                enu = enu + rng.normal(0, adsb_sigma_m, enu.shape) * [1, 1, 1.5]
            lat, lon, alt = pymap3d.enu2geodetic(*enu.T, *ORIGIN)
            reports.append(
                pd.DataFrame(
                    {
                        "time_s": t,
                        "target_id": track.target_id,
                        "lat_deg": lat,
                        "lon_deg": lon,
                        "alt_m": alt,
                        "sigma_m": adsb_sigma_m,
                    }
                )
            )
        adsb_table = pd.concat(reports, ignore_index=True)
    return Dataset({s.id: s for s, _ in radars}, plots, adsb_table)


def crowded_network(rng: np.random.Generator) -> tuple[Dataset, dict[str, RadarBias]]:
    """Two radars; twelve parallel flights crowded far north, two crossing flights; no
    ADS-B.  Returns the dataset and the true biases (the selection test and study)."""
    radars = [
        (site_at("A", -40e3, 0.0, sigma_range_m=50.0, sigma_azimuth_mrad=2.0),
         RadarBias(150.0, 0.002, 0.004)),
        (site_at("B", 40e3, 0.0, sigma_range_m=50.0, sigma_azimuth_mrad=2.0),
         RadarBias(-100.0, -0.001, -0.003)),
    ]
    tracks = [Track(f"c{i}", (-20e3 + 3e3 * i, 150e3, 9000.0), (0.0, 220.0, 0.0), 0.0, 300.0)
              for i in range(12)]
    tracks += [Track("x1", (-80e3, -60e3, 8000.0), (250.0, 150.0, 0.0), 0.0, 300.0),
               Track("x2", (60e3, -70e3, 7000.0), (-150.0, 220.0, 0.0), 0.0, 300.0)]
    return make_dataset(rng, radars, tracks, adsb=False), {s.id: b for s, b in radars}

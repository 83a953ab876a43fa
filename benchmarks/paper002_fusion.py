"""Paper 002 (Wu et al.), section 3.3: Tables 2 and 3 by Monte-Carlo simulation.

Run from the repository root::

    .venv/bin/python -m benchmarks.paper002_fusion [--runs 50] [--seed 0] [--q 1.0]

Scenario ``scenarios/paper002_three_radars.toml``: three radars in ECEF, one
target at ``v = (-300, -300, 300)`` m/s for 100 s, ``sigma_r = 100`` m,
``sigma_a = sigma_e = 0.1`` deg, 1 s scans, no biases.  Each run is
:func:`graphcal.simulation.simulate.simulate` with its own seeded Generator
(``numpy.random.SeedSequence(seed).spawn(runs)``); plots are converted to ECEF
with their converted covariance (paper eq. 19) and filtered by the CV Kalman
filter of :mod:`graphcal.tracking.kalman` (two-point start).

Table 2, filtering RMSE: eq. 32 with its misprint corrected (the sum over the
``m`` runs is *divided* by ``m``)::

    RMSE_i(k) = sqrt( (1/m) sum_j |x_hat_i(k, j) - x(k)|^2 )

at each plot ``k`` of radar ``i`` (from the second plot on, the first estimate
of a two-point start; truth = the simulator's true position at the plot), then
the mean over ``k``; per radar and the mean of the three.  Measurement noise
``R1 = diag(1e4)`` m^2 (eq. 31, ``fixed``) versus ``R2`` = the first plot's
converted covariance, held (``converted-first``, the paper's wording), plus every
plot's own converted covariance (``converted``).

Table 3, fusion RMSE: every track (``converted-first`` R, as the paper)
predicted to the common 1 s grid, fused with equal weights (the radars' polar
accuracies are equal) or covariance weights (information form), RMSE at each
grid time against the true CV position, mean over time.

Process noise: the paper gives none.  The target flies exactly at constant
velocity, so any ``q > 0`` only costs smoothing; we take ``q = 1 m^2/s^3``, a
"nearly constant velocity" model whose velocity random walk is 1 m/s per 1 s
scan (about 0.3 % of the 520 m/s speed), small enough that the filter averages
over tens of scans, and print the sensitivity over ``q``.

Outputs: tables on stdout, ``benchmarks/results/paper002_fusion.json``
(atomically) and ``benchmarks/results/paper002_fusion.png`` (fused RMSE versus
time for both weightings, like the paper's Fig. 7).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks import RESULTS  # noqa: E402
from graphcal.data.align import plot_arrays  # noqa: E402
from graphcal.model.cross_radar import convert_plots  # noqa: E402
from graphcal.simulation.scenario import load_scenario  # noqa: E402
from graphcal.simulation.simulate import simulate  # noqa: E402
from graphcal.tracking.fusion import fuse_covariance_weighted, fuse_equal_weights  # noqa: E402
from graphcal.tracking.kalman import (
    NOISE_MODES,
    kalman_filter,
    measurement_noise,
    pad_tracks,
    predict_to,
)

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "paper002_three_radars.toml"
RADARS = ("I", "II", "III")
#: Paper 002 Table 2 (fixed R1, converted R2) and Table 3 (equal, covariance weights) [m].
PAPER_TABLE2_M = {"fixed": 1569.25, "converted-first": 1463.62}
PAPER_TABLE3_M = {"equal": 631.73, "covariance": 299.93}
DEFAULT_Q_M2_S3 = 1.0
SENSITIVITY_Q_M2_S3 = (0.1, 1.0, 10.0, 100.0)


@dataclass
class RadarRuns:
    """One radar's plots over all runs, padded: (runs, n, ...)."""

    time_s: np.ndarray
    z_m: np.ndarray
    cov_m2: np.ndarray
    truth_m: np.ndarray
    mask: np.ndarray


def simulate_runs(runs: int, seed: int) -> tuple[dict[str, RadarRuns], list]:
    """Simulate ``runs`` Monte-Carlo runs; per radar the padded plots and truth."""
    scenario = load_scenario(SCENARIO)
    children = np.random.SeedSequence(seed).spawn(runs)
    results = [simulate(scenario, np.random.default_rng(c)) for c in children]
    data = {}
    for rid in RADARS:
        t, z, cov, truth = [], [], [], []
        for res in results:
            plots = plot_arrays(res.dataset, rid)
            conv = convert_plots(res.dataset.sites[rid], plots)
            if not conv.usable.all():
                raise RuntimeError(f"radar {rid}: unusable plots in a 3-D scenario")
            t.append(plots.time_s)
            z.append(conv.ecef_m)
            cov.append(conv.cov_m2)
            truth.append(res.plot_truth.loc[plots.index, ["x_m", "y_m", "z_m"]].to_numpy())
        tp, mask = pad_tracks(t)
        zp, _ = pad_tracks(z)
        cp, _ = pad_tracks(cov)
        cp[~mask] = np.eye(3)
        trp, _ = pad_tracks(truth, fill=np.nan)
        data[rid] = RadarRuns(tp, zp, cp, trp, mask)
    return data, results


def rmse_over_runs(err_m: np.ndarray) -> np.ndarray:
    """Eq. 32 (corrected): sqrt of the mean over runs (axis 0) of the squared 3-D error."""
    return np.sqrt(np.mean(np.sum(err_m**2, axis=-1), axis=0))


def filter_runs(radar: RadarRuns, mode: str, q: float):
    r = measurement_noise(mode, radar.cov_m2)
    r[~radar.mask] = np.eye(3)
    return kalman_filter(radar.time_s, radar.z_m, r, q_m2_s3=q, mask=radar.mask)


def table2(data: dict[str, RadarRuns], q: float) -> dict[str, dict[str, float]]:
    """Filtering RMSE per mode: per radar and the mean of the three [m]."""
    n_common = min(int(d.mask.sum(axis=1).min()) for d in data.values())
    out = {}
    for mode in NOISE_MODES:
        per = {}
        for rid, radar in data.items():
            est = filter_runs(radar, mode, q)
            err = est.position_m[:, 1:n_common] - radar.truth_m[:, 1:n_common]
            per[rid] = float(np.mean(rmse_over_runs(err)))
        per["mean"] = float(np.mean([per[rid] for rid in RADARS]))
        out[mode] = per
    return out


def fusion_grid(data: dict[str, RadarRuns]) -> np.ndarray:
    """Integer seconds inside every radar's track span in every run."""
    first = max(float(d.time_s[:, 1].max()) for d in data.values())
    last_idx = {rid: d.mask.sum(axis=1) - 1 for rid, d in data.items()}
    last = min(
        float(np.take_along_axis(d.time_s, last_idx[rid][:, None], axis=1).min())
        for rid, d in data.items()
    )
    return np.arange(np.ceil(first), np.floor(last) + 1.0)


def table3(
    data: dict[str, RadarRuns], truth_grid_m: np.ndarray, grid_s: np.ndarray, q: float,
    mode: str = "converted-first",
) -> dict[str, object]:
    """Fusion RMSE (mean over the grid) and RMSE versus time for both weightings [m]."""
    xs, ps = [], []
    for radar in data.values():
        est = filter_runs(radar, mode, q)
        x, p, ok = predict_to(est, grid_s)
        if not ok.all():
            raise RuntimeError("a track does not cover the fusion grid")
        xs.append(x)
        ps.append(p)
    x_all, p_all = np.stack(xs), np.stack(ps)  # (radars, runs, grid, 6[, 6])
    x_cov, _, _ = fuse_covariance_weighted(x_all, p_all)
    x_eq, _, _ = fuse_equal_weights(x_all, p_all)
    rmse_cov = rmse_over_runs(x_cov[..., :3] - truth_grid_m)
    rmse_eq = rmse_over_runs(x_eq[..., :3] - truth_grid_m)
    return {
        "equal": float(rmse_eq.mean()),
        "covariance": float(rmse_cov.mean()),
        "ratio": float(rmse_eq.mean() / rmse_cov.mean()),
        "rmse_equal_vs_time_m": rmse_eq.tolist(),
        "rmse_covariance_vs_time_m": rmse_cov.tolist(),
    }


def write_json_atomic(path: Path, document: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            json.dump(document, handle, indent=2)
            handle.write("\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def plot_figure(path: Path, grid_s: np.ndarray, t3: dict, q: float, runs: int) -> None:
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(grid_s, t3["rmse_equal_vs_time_m"], label=f"equal weights (mean {t3['equal']:.0f} m)")
    ax.plot(grid_s, t3["rmse_covariance_vs_time_m"],
            label=f"converted-covariance weights (mean {t3['covariance']:.0f} m)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("fused position RMSE [m]")
    ax.set_title(f"Paper 002 Fig. 7: fusion RMSE, {runs} runs, q = {q:g} m$^2$/s$^3$")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".png")
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=120)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50, help="Monte-Carlo runs (paper: 50)")
    parser.add_argument("--seed", type=int, default=0, help="root seed")
    parser.add_argument("--q", type=float, default=DEFAULT_Q_M2_S3,
                        help="process noise q [m^2/s^3] of the main tables")
    parser.add_argument("--out", type=Path, default=RESULTS / "paper002_fusion.json")
    args = parser.parse_args(argv)
    if args.runs < 2:
        parser.error("--runs must be at least 2")
    if not args.q >= 0:
        parser.error("--q must be >= 0")
    start = time.perf_counter()
    data, results = simulate_runs(args.runs, args.seed)
    t_sim = time.perf_counter() - start
    grid = fusion_grid(data)
    truth_grid = results[0].trajectories[0].position_ecef(grid)  # same CV truth in every run

    qs = sorted(set(SENSITIVITY_Q_M2_S3) | {args.q})
    sens = {}
    for q in qs:
        t2 = table2(data, q)
        t3 = table3(data, truth_grid, grid, q)
        t3_conv = table3(data, truth_grid, grid, q, mode="converted")
        sens[q] = (t2, t3, t3_conv)
    t2, t3, t3_conv = sens[args.q]
    elapsed = time.perf_counter() - start

    paper_r2 = PAPER_TABLE2_M["fixed"] / PAPER_TABLE2_M["converted-first"]
    paper_r3 = PAPER_TABLE3_M["equal"] / PAPER_TABLE3_M["covariance"]
    print(f"Paper 002, section 3.3: {args.runs} Monte-Carlo runs, seed {args.seed}, "
          f"q = {args.q:g} m^2/s^3, fusion grid {grid[0]:g}..{grid[-1]:g} s")
    print("\nTable 2 - filtering RMSE [m] (eq. 32, mean over time)")
    print(f"{'R':<26}{'I':>9}{'II':>9}{'III':>9}{'mean':>9}{'paper':>10}")
    labels = {"fixed": "fixed R1 = diag(1e4)", "converted-first": "converted R2 (first plot)",
              "converted": "converted (every plot)"}
    for mode in NOISE_MODES:
        row = t2[mode]
        paper = PAPER_TABLE2_M.get(mode)
        paper_txt = f"{paper:10.2f}" if paper else f"{'-':>10}"
        print(f"{labels[mode]:<26}" + "".join(f"{row[k]:9.1f}" for k in (*RADARS, "mean"))
              + paper_txt)
    r2 = t2["fixed"]["mean"] / t2["converted-first"]["mean"]
    r2c = t2["fixed"]["mean"] / t2["converted"]["mean"]
    print(f"ratio fixed / converted-first: ours {r2:.3f} (every plot: {r2c:.3f}), "
          f"paper {paper_r2:.3f}")
    print("\nTable 3 - fusion RMSE [m] (filters with converted R2, mean over the grid)")
    print(f"{'weights':<26}{'ours':>9}{'every plot R':>14}{'paper':>10}")
    print(f"{'equal':<26}{t3['equal']:9.1f}{t3_conv['equal']:14.1f}{PAPER_TABLE3_M['equal']:10.2f}")
    print(f"{'converted covariance':<26}{t3['covariance']:9.1f}{t3_conv['covariance']:14.1f}"
          f"{PAPER_TABLE3_M['covariance']:10.2f}")
    print(f"ratio equal / covariance: ours {t3['ratio']:.3f} (every plot: {t3_conv['ratio']:.3f}),"
          f" paper {paper_r3:.3f}")
    print("\nSensitivity to the process noise q (mean of the three radars for Table 2)")
    print(f"{'q [m^2/s^3]':>12}{'T2 fixed':>10}{'T2 R2':>9}{'T2 every':>10}{'ratio':>7}"
          f"{'T3 equal':>10}{'T3 cov':>9}{'ratio':>7}")
    for q in qs:
        a, b, _ = sens[q]
        print(f"{q:12g}{a['fixed']['mean']:10.1f}{a['converted-first']['mean']:9.1f}"
              f"{a['converted']['mean']:10.1f}"
              f"{a['fixed']['mean'] / a['converted-first']['mean']:7.3f}"
              f"{b['equal']:10.1f}{b['covariance']:9.1f}{b['ratio']:7.3f}")
    print(f"\n{elapsed:.1f} s (simulation {t_sim:.1f} s)")

    document = {
        "benchmark": "paper002_fusion",
        "scenario": str(SCENARIO.relative_to(ROOT)),
        "runs": args.runs,
        "seed": args.seed,
        "q_m2_s3": args.q,
        "grid_s": [float(grid[0]), float(grid[-1])],
        "paper": {"table2_m": PAPER_TABLE2_M, "table3_m": PAPER_TABLE3_M,
                  "table2_ratio": paper_r2, "table3_ratio": paper_r3},
        "table2_m": t2,
        "table2_ratio": {"converted-first": r2, "converted": r2c},
        "table3_m": {k: v for k, v in t3.items() if not k.endswith("vs_time_m")},
        "table3_every_plot_r_m": {k: v for k, v in t3_conv.items()
                                  if not k.endswith("vs_time_m")},
        "fig7": {"time_s": grid.tolist(), "rmse_equal_m": t3["rmse_equal_vs_time_m"],
                 "rmse_covariance_m": t3["rmse_covariance_vs_time_m"]},
        "sensitivity": [
            {"q_m2_s3": q,
             "table2_mean_m": {m: sens[q][0][m]["mean"] for m in NOISE_MODES},
             "table3_m": {k: sens[q][1][k] for k in ("equal", "covariance", "ratio")},
             "table3_every_plot_r_m": {k: sens[q][2][k] for k in ("equal", "covariance", "ratio")}}
            for q in qs
        ],
        "elapsed_s": elapsed,
    }
    write_json_atomic(args.out, document)
    png = args.out.with_suffix(".png")
    plot_figure(png, grid, t3, args.q, args.runs)
    print(f"wrote {args.out} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

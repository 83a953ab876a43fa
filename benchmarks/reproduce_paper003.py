"""Paper 003 (Yuan et al.), Tables 1-3: FL, LS and FL-LS against ADS-B, one 2-D radar.

Run from the repository root::

    .venv/bin/python -m benchmarks.reproduce_paper003 [--runs 1000] [--jobs 2] [--seed 0]

Scenario ``scenarios/paper003_adsb_2d.toml`` (one 2-D radar, one straight flight,
ADS-B at 1 s; the paper uses one real recording of 27 plots, we simulate it with
assumed geometry and noise).  Methods ``fl``, ``ls``, ``fl-ls`` and, for context,
``graph``.  Per run (:func:`graphcal.pipeline.compare.compare`): the estimates, and each
calibration's mean absolute range and azimuth residual against the interpolated
ADS-B before and after correction (the paper's Table 2 "mean error"); Table 3's
improvement ``eta = (before - after) / before`` is computed from the means over runs.

Outputs: stdout, ``benchmarks/results/reproduce_paper003.md`` and
``benchmarks/results/reproduce_paper003.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from graphcal.core.atomic import atomic_write_text
from graphcal.pipeline.compare import compare

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
METHODS = ["fl", "ls", "fl-ls", "graph"]

#: Paper 003 Table 1 (estimates), Table 2 (mean error after), Table 3 (improvement %).
PAPER_T1 = {"fl": (296.8, 160.3), "ls": (382.9, 161.8), "fl-ls": (297.4, 9.7)}
PAPER_T2_BEFORE = (296.8, 170.8)
PAPER_T2 = {"fl": (296.1, 115.2), "ls": (107.3, 114.5), "fl-ls": (84.1, 80.8)}
PAPER_T3 = {"fl": (0.2, 32.6), "ls": (63.8, 33.0), "fl-ls": (71.7, 52.7)}


def report(result, runs: int) -> str:
    t = result.table.set_index(["method", "parameter"])
    extra = result.extra.groupby("method")[
        ["range_before_m", "range_after_m", "azimuth_before_mrad", "azimuth_after_mrad"]
    ].mean()
    fails = result.failures.set_index("method")["failures"]
    lines = [
        "# Paper 003, Tables 1-3",
        "",
        f"Ours: {runs} simulated runs (truth 297 m, 161.7 mrad); paper: one real recording.",
        "",
        "Table 1, estimates (ours: mean ± std over runs; RMSE/√CRLB in brackets):",
        "",
        "| method | range offset (m), ours | paper | azimuth bias (mrad), ours | paper "
        "| failures |",
        "|---|---|---|---|---|---|",
    ]
    for m in METHODS:
        cells = []
        for key, k in (("range_offset_m", 0), ("azimuth_bias_mrad", 1)):
            row = t.loc[(m, key)]
            ours = f"{row['mean']:.1f} ± {row['std']:.2g} [{row['rmse_over_crlb']:.2f}]"
            paper = f"{PAPER_T1[m][k]:g}" if m in PAPER_T1 else "–"
            cells += [ours, paper]
        lines.append(f"| `{m}` | " + " | ".join(cells) + f" | {fails[m]}/{runs} |")
    before_r = extra["range_before_m"].mean()
    before_a = extra["azimuth_before_mrad"].mean()
    lines += [
        "",
        "Tables 2 and 3, mean absolute error of the radar plots against ADS-B after "
        "correction, and the improvement eta = (before - after) / before:",
        "",
        "| method | range error (m), ours | paper | azimuth error (mrad), ours | paper "
        "| eta_r ours | paper | eta_theta ours | paper |",
        "|---|---|---|---|---|---|---|---|---|",
        f"| uncorrected | {before_r:.1f} | {PAPER_T2_BEFORE[0]:g} | {before_a:.1f} "
        f"| {PAPER_T2_BEFORE[1]:g} | | | | |",
    ]
    for m in METHODS:
        if m not in extra.index:
            continue
        after_r, after_a = extra.loc[m, "range_after_m"], extra.loc[m, "azimuth_after_mrad"]
        eta_r = 100 * (extra.loc[m, "range_before_m"] - after_r) / extra.loc[m, "range_before_m"]
        eta_a = 100 * (extra.loc[m, "azimuth_before_mrad"] - after_a) / extra.loc[
            m, "azimuth_before_mrad"]
        p2 = PAPER_T2.get(m, ("–", "–"))
        p3 = PAPER_T3.get(m, ("–", "–"))
        lines.append(
            f"| `{m}` | {after_r:.1f} | {p2[0]} | {after_a:.2f} | {p2[1]} "
            f"| {eta_r:.1f} % | {p3[0]} | {eta_a:.1f} % | {p3[1]} |"
        )
    timing = result.timing.set_index("method")["mean_s"]
    lines += ["", "Mean run time per method: " + ", ".join(
        f"`{m}` {timing[m] * 1e3:.2f} ms" for m in METHODS) + "."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)

    def progress(done: int, total: int) -> None:
        if done % max(1, total // 10) == 0 or done == total:
            print(f"{done}/{total}", file=sys.stderr, flush=True)

    start = time.perf_counter()
    result = compare(ROOT / "scenarios" / "paper003_adsb_2d.toml", METHODS, args.runs,
                     seed=args.seed, jobs=args.jobs, progress=progress)
    elapsed = time.perf_counter() - start
    print(f"{args.runs} runs in {elapsed:.1f} s ({elapsed / args.runs:.4f} s per run with "
          f"{args.jobs} jobs)", flush=True)
    result.write(RESULTS / "reproduce_paper003.json")
    text = report(result, args.runs)
    atomic_write_text(RESULTS / "reproduce_paper003.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Paper 001 (Yang et al.), Table 1: Monte-Carlo bias estimates on paths 1 and 2.

Run from the repository root::

    .venv/bin/python -m benchmarks.reproduce_paper001 [--runs 1000] [--jobs 2] [--seed 0]

Scenarios ``scenarios/paper001_path1.toml`` and ``paper001_path2.toml`` (two 3-D
radars, no ADS-B: the paper has none).  Methods: ``wls`` (the paper's full
observation set, eq. 8-11), ``wls-pruned`` (its greedy pruning, eq. 12) and
``graph`` (cross-radar factors only, ``use_adsb=False``).  Every run simulates
the scenario with its own seed (:func:`graphcal.pipeline.compare.compare`) and runs all
three methods on the same data.

Outputs: the tables on stdout, ``benchmarks/results/reproduce_paper001_path{1,2}.md``
and ``.json`` (the full :class:`~graphcal.pipeline.compare.ComparisonResult` summary) and
``benchmarks/results/reproduce_paper001.md`` (the Table 1 layout beside the paper).
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
METHODS = ["wls", "wls-pruned", "graph"]
KEYS = ["range_offset_m", "range_gain", "azimuth_bias_mrad"]

#: Paper 001 Table 1: (mean, std) for R1 offset m, gain %, azimuth mrad, R2 the same.
PAPER = {
    ("path1", "wls"): [(989, 18), (0.52, 0.014), (5.1, 0.78),
                       (1004, 18), (0.42, 0.016), (10, 0.84)],
    ("path1", "wls-pruned"): [(995, 25), (0.51, 0.03), (8.4, 1.0),
                              (995, 22), (0.42, 0.022), (13.7, 0.9)],
    ("path2", "wls"): [(942, 57), (0.65, 0.14), (5.5, 0.9),
                       (964, 48), (0.55, 0.14), (10.3, 0.996)],
    ("path2", "wls-pruned"): [(989, 42), (0.52, 0.079), (8.5, 1.0),
                              (993, 30), (0.429, 0.069), (13.5, 1.067)],
}
TRUTH = "| truth | 1000 | 0.5 | 8.7 | 1000 | 0.4 | 14 | | |"


def _cell(mean: float, std: float, key: str) -> str:
    if key == "range_gain":  # show in percent, as the paper
        return f"{100 * mean:.3g} ± {100 * std:.2g}"
    if key == "range_offset_m":
        return f"{mean:.0f} ± {std:.0f}"
    return f"{mean:.3g} ± {std:.2g}"


def table1(results: dict[str, object], runs: int) -> str:
    lines = [
        f"Ours: {runs} Monte-Carlo runs per path (mean ± std over runs); paper: 1000 runs.",
        "",
        "| path, method | R1 offset (m) | R1 gain (%) | R1 azimuth (mrad) | R2 offset (m) "
        "| R2 gain (%) | R2 azimuth (mrad) | RMSE/√CRLB (R1 az, R2 az) | failures |",
        "|---|---|---|---|---|---|---|---|---|",
        TRUTH,
    ]
    for path, result in results.items():
        t = result.table.set_index(["method", "radar", "parameter"])
        fails = result.failures.set_index("method")["failures"]
        for method in METHODS:
            cells = []
            for rid in ("R1", "R2"):
                for key in KEYS:
                    row = t.loc[(method, rid, key)] if (method, rid, key) in t.index else None
                    cells.append("–" if row is None else _cell(row["mean"], row["std"], key))
            ratio = []
            for rid in ("R1", "R2"):
                idx = (method, rid, "azimuth_bias_mrad")
                ratio.append(f"{t.loc[idx, 'rmse_over_crlb']:.2f}" if idx in t.index else "–")
            lines.append(f"| {path[-1]}, `{method}` (ours) | " + " | ".join(cells)
                         + f" | {', '.join(ratio)} | {fails[method]}/{runs} |")
            if (path, method) in PAPER:
                paper = PAPER[(path, method)]
                cells = [f"{m:g} ± {s:g}" for m, s in paper]
                lines.append(f"| {path[-1]}, {method} (paper) | " + " | ".join(cells) + " | | |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    results = {}
    for path in ("path1", "path2"):
        start = time.perf_counter()

        def progress(done: int, total: int, path: str = path) -> None:
            if done % max(1, total // 10) == 0 or done == total:
                print(f"{path}: {done}/{total}", file=sys.stderr, flush=True)

        result = compare(
            ROOT / "scenarios" / f"paper001_{path}.toml", METHODS, args.runs, seed=args.seed,
            jobs=args.jobs, progress=progress, method_options={"graph": {"use_adsb": False}},
        )
        elapsed = time.perf_counter() - start
        print(f"{path}: {args.runs} runs in {elapsed:.1f} s "
              f"({elapsed / args.runs:.3f} s per run with {args.jobs} jobs)", flush=True)
        result.write(RESULTS / f"reproduce_paper001_{path}.md")
        result.write(RESULTS / f"reproduce_paper001_{path}.json")
        print(result.to_markdown())
        results[path] = result
    text = "# Paper 001, Table 1\n\n" + table1(results, args.runs)
    atomic_write_text(RESULTS / "reproduce_paper001.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

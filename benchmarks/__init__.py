"""Benchmarks and studies; run each from the repository root as ``python -m benchmarks.NAME``.

The scripts of ``make bench`` and ``make papers`` write their figures to :data:`RESULTS`:
``benchmarks/results/`` (tracked: the figures the manual quotes), or the folder named by the
environment variable ``GRAPHCAL_BENCH_RESULTS``. The Makefile sets it to
``benchmarks/results/latest/`` (ignored by git) unless told ``BENCH_RESULTS=benchmarks/results``.
"""

import os
from pathlib import Path

#: Where the benchmarks write their figures (see the module docstring).
RESULTS = Path(
    os.environ.get("GRAPHCAL_BENCH_RESULTS") or Path(__file__).parent / "results"
).resolve()

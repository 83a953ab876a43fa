"""ASTERIX decoding speed: CAT048 and CAT021 records per second, on one core.

Run from the repository root::

    .venv/bin/python -m benchmarks.bench_asterix
    .venv/bin/python -m benchmarks.bench_asterix --records 1000000 --reference-records 0

A simulated network (``scenarios/demo_network.toml``: five radars, two of them 3-D, and
ADS-B) is written as ASTERIX with :mod:`graphcal.io.asterix.encode`: 5,000 plots as CAT048
(I010, I140, I020, I040, I090, I110 for the 3-D radars, I220) and 5,000 ADS-B reports as
CAT021 ed. 2.7 (I010, I040, I161, I071, I131, I080, I140, I090).  Each recording is repeated
to ``--records`` records and decoded by :func:`graphcal.io.asterix.decode.decode_bytes`
(the column decoder), then by :mod:`graphcal.io.asterix.reference` (libasterix item by
item, the decoder graphcal had before) on ``--reference-records`` of them; the tables are
then built (:func:`graphcal.io.asterix.tables.build_tables`).  Prints records per second of
each, the speed-up, and checks that both decoders give the same reports.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from graphcal.data.dataset import Dataset
from graphcal.io.asterix import reference
from graphcal.io.asterix.decode import DecodeStats, decode_bytes, split_blocks
from graphcal.io.asterix.encode import encode_dataset
from graphcal.io.asterix.tables import build_tables
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.paths import SCENARIOS

#: Where the figures are written.
RESULTS = Path(__file__).resolve().parent / "results" / "bench_asterix.json"
#: Records encoded per category (libasterix encodes about 2,000 a second); then repeated.
SOURCE_RECORDS = 5000


def recordings() -> tuple[bytes, bytes, int, int]:
    """Raw CAT048 (with the CAT034 positions) and CAT021 recordings, and their record counts."""
    run = simulate(load_scenario(SCENARIOS / "demo_network.toml"), np.random.default_rng(7))
    ds = run.dataset
    codes = {rid: (25, 10 + k) for k, rid in enumerate(ds.sites)}
    plots = ds.plots[ds.plots["range_m"] < 250.0 * 1852.0]
    step = max(1, len(plots) // SOURCE_RECORDS)
    plots = plots.iloc[::step].head(SOURCE_RECORDS).reset_index(drop=True)
    cat048 = encode_dataset(Dataset(ds.sites, plots, None), codes)
    adsb = ds.adsb.head(SOURCE_RECORDS).reset_index(drop=True)
    both = encode_dataset(Dataset(ds.sites, plots.head(1), adsb), codes)
    cat021 = b"".join(both[begin:stop] for category, begin, stop
                      in split_blocks(both, DecodeStats()) if category == 21)
    return cat048, cat021, len(plots), len(adsb)


def repeat(data: bytes, n_source: int, n_records: int) -> tuple[bytes, int]:
    """``data`` repeated to about ``n_records`` records; the bytes and the record count."""
    times = max(1, round(n_records / n_source))
    return data * times, n_source * times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=200_000,
                        help="records per category decoded by the column decoder")
    parser.add_argument("--reference-records", type=int, default=5000,
                        help="records per category decoded by the libasterix reference "
                        "(0: skip it)")
    args = parser.parse_args()
    cat048, cat021, n048, n021 = recordings()
    figures: dict[str, dict[str, float]] = {}
    for name, data, n_source in (("CAT048", cat048, n048), ("CAT021", cat021, n021)):
        big, n = repeat(data, n_source, args.records)
        start = time.perf_counter()
        decoded = decode_bytes(big)
        fast_s = time.perf_counter() - start
        assert len(decoded.order) >= n, (len(decoded.order), n)
        figures[name] = {"records": n, "records_per_s": n / fast_s}
        line = (f"{name}: {n:,} records ({len(big) / 1e6:.1f} MB): column decoder "
                f"{fast_s:.2f} s, {n / fast_s:,.0f} records/s")
        if args.reference_records:
            small, n_small = repeat(data, n_source, args.reference_records)
            start = time.perf_counter()
            reports, _ = reference.decode_payload(small)
            reference_s = time.perf_counter() - start
            assert decode_bytes(small).sequence == reports, "the decoders differ"
            figures[name]["reference_records_per_s"] = n_small / reference_s
            line += (f"; libasterix reference {n_small / reference_s:,.0f} records/s "
                     f"({n_small:,} records); x{(n / fast_s) / (n_small / reference_s):.0f}")
        if name == "CAT048":
            start = time.perf_counter()
            tables = build_tables(decoded)
            line += (f"; tables {time.perf_counter() - start:.2f} s "
                     f"({len(tables.dataset.plots):,} plots)")
        print(line, flush=True)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(figures, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()

"""Fuzz the ASTERIX reader, and time it on a large synthetic recording.

Run from the repository root::

    .venv/bin/python -m benchmarks.fuzz_asterix --n 10000
    .venv/bin/python -m benchmarks.fuzz_asterix --n 0 --speed 100000

Fuzzing: ``--n`` inputs, half random bytes and half mutations of valid data
blocks (CAT048, CAT021, CAT034, several per input; bit flips, truncation,
changed ``LEN``, inserted and deleted bytes), a quarter of the mutated ones
wrapped in a pcap capture.  Each input goes through the block splitter, the
decoder and the table builder.  Only :class:`graphcal.core.errors.GraphcalInputError`
may come out; anything else is a crash.  Prints the counts (inputs, blocks
accepted, rejected by reason, crashes, slowest input) and exits with status 1
on any crash.

Speed: ``--speed N`` writes a raw file of N CAT048 target reports (typical Mode S
content: I010, I140, I020, I040, I070, I090, I220, I240, I161, I200, I170) and
times :func:`graphcal.io.asterix.decode.decode_file` and the table builder on it.
"""

from __future__ import annotations

import argparse
import io
import random
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

import asterix.generated as gen
import dpkt

from graphcal.core.errors import GraphcalInputError
from graphcal.io.asterix.decode import decode_bytes, decode_file
from graphcal.io.asterix.tables import build_tables, load_user_sites

CAT048 = gen.Cat_048_1_32
CAT021 = gen.Cat_021_2_6
CAT034 = gen.Cat_034_1_29


def plot(tod: float, rho: float, theta: float, address: int, sic: int = 201):
    return CAT048.cv_record.create({
        "010": (("SAC", 25), ("SIC", sic)),
        "140": (tod, "s"),
        "020": ((("TYP", 5), 0, 0, 0, 0, None),),
        "040": (("RHO", (rho, "NM")), ("THETA", (theta, "°"))),
        "070": (0, 0, 0, 0, ("MODE3A", "1000")),
        "090": (0, 0, ("FL", (330.0, "FL"))),
        "220": address,
        "240": "DLH65A",
        "161": (0, ("TRN", 3563)),
        "200": (("GSP", (0.12, "NM/s")), ("HDG", (124.0, "°"))),
        "170": ((0, 0, 2, 0, 0, 0, 0, 0, None),),
    })


def valid_blocks(rng: random.Random) -> list[bytes]:
    """A few valid data blocks of each decoded category."""
    blocks = []
    for _ in range(3):
        tod = rng.uniform(0.0, 86399.0)
        blocks.append(CAT048.create([
            plot(tod, rng.uniform(1, 250), rng.uniform(0, 359.9), rng.randrange(1 << 24))
            for _ in range(rng.randint(1, 4))]).unparse().to_bytes())
        blocks.append(CAT021.create([CAT021.cv_record.create({
            "010": (("SAC", 1), ("SIC", 2)), "071": (tod, "s"),
            "080": rng.randrange(1 << 24),
            "131": (("LAT", (rng.uniform(-80, 80), "°")), ("LON", (rng.uniform(-170, 170), "°"))),
            "140": (rng.uniform(0, 40000), "ft"),
            "090": ((0, 7, None), (0, 0, rng.randint(0, 11), None)),
        })]).unparse().to_bytes())
        blocks.append(CAT034.create([CAT034.cv_record.create({
            "000": 2, "010": (("SAC", 25), ("SIC", 201)), "030": (tod, "s"),
            "120": (("HGT", (100.0, "m")), ("LAT", (48.0, "°")), ("LON", (2.0, "°"))),
        })]).unparse().to_bytes())
    return blocks


def mutate(rng: random.Random, data: bytes) -> bytes:
    out = bytearray(data)
    for _ in range(rng.randint(1, 6)):
        if not out:
            break
        kind = rng.choice(("flip", "flip", "truncate", "length", "insert", "delete"))
        pos = rng.randrange(len(out))
        if kind == "flip":
            out[pos] ^= 1 << rng.randrange(8)
        elif kind == "truncate":
            del out[pos:]
        elif kind == "length":
            starts = [0]
            while starts[-1] + 3 <= len(out):
                step = int.from_bytes(out[starts[-1] + 1:starts[-1] + 3], "big")
                if step < 3:
                    break
                starts.append(starts[-1] + step)
            at = rng.choice([s for s in starts if s + 3 <= len(out)] or [0])
            if at + 3 <= len(out):
                out[at + 1:at + 3] = rng.choice(
                    (rng.randrange(1 << 16), rng.randrange(3), len(out) + rng.randint(1, 9),
                     max(3, int.from_bytes(out[at + 1:at + 3], "big") + rng.randint(-5, 5)))
                ).to_bytes(2, "big")
        elif kind == "insert":
            out[pos:pos] = rng.randbytes(rng.randint(1, 8))
        else:
            del out[pos:pos + rng.randint(1, 8)]
    return bytes(out)


def pcap(payload: bytes) -> bytes:
    udp = dpkt.udp.UDP(sport=1, dport=2, data=payload)
    udp.ulen = len(udp)
    ip = dpkt.ip.IP(src=b"\x0a\0\0\1", dst=b"\x0a\0\0\2", p=dpkt.ip.IP_PROTO_UDP, data=udp)
    ip.len = len(ip)
    frame = dpkt.ethernet.Ethernet(type=dpkt.ethernet.ETH_TYPE_IP, data=ip)
    stream = io.BytesIO()
    writer = dpkt.pcap.Writer(stream)
    writer.writepkt(bytes(frame), ts=1633564800.0)
    return stream.getvalue()


def fuzz(n: int, seed: int) -> int:
    rng = random.Random(seed)
    pool = valid_blocks(rng)
    counts: Counter[str] = Counter()
    rejected: Counter[str] = Counter()
    crashes = 0
    slowest = 0.0
    started = time.perf_counter()
    for i in range(n):
        if i % 2 == 0:
            data = rng.randbytes(rng.randint(0, 400))
            kind = "random"
        else:
            data = mutate(rng, b"".join(rng.choice(pool) for _ in range(rng.randint(1, 5))))
            kind = "mutated"
            if rng.random() < 0.25:
                data = mutate(rng, pcap(data)) if rng.random() < 0.5 else pcap(data)
                kind = "mutated pcap"
        counts[kind] += 1
        t0 = time.perf_counter()
        try:
            decoded = decode_bytes(data)
            counts["blocks accepted"] += decoded.stats.blocks_decoded
            counts["records"] += sum(decoded.stats.records.values())
            rejected.update(decoded.stats.rejected)
            build_tables(decoded)
            counts["tables built"] += 1
        except GraphcalInputError:
            counts["clear errors"] += 1
        except Exception:  # noqa: BLE001 - the point is to find these
            crashes += 1
            if crashes <= 5:
                print(f"CRASH on input {i} ({kind}): {data.hex()}", file=sys.stderr)
                traceback.print_exc()
        slowest = max(slowest, time.perf_counter() - t0)
    total = time.perf_counter() - started
    print(f"inputs: {n} ({counts['random']} random, {counts['mutated']} mutated, "
          f"{counts['mutated pcap']} mutated in pcap); seed {seed}")
    print(f"blocks accepted: {counts['blocks accepted']}; records: {counts['records']}; "
          f"tables built: {counts['tables built']}; clear errors: {counts['clear errors']}")
    print("rejected by reason: " + ", ".join(f"{k} {v}" for k, v in sorted(rejected.items())))
    print(f"crashes: {crashes}")
    print(f"time: {total:.1f} s total, max {slowest * 1e3:.1f} ms per input")
    return crashes


def speed(n_records: int) -> None:
    rng = random.Random(1)
    per_block = 20
    template = [plot(0.0, rng.uniform(1, 250), rng.uniform(0, 359.9), rng.randrange(1 << 24))
                for _ in range(per_block)]
    parts = []
    for b in range(n_records // per_block):
        tod = 1000.0 + b * 0.25
        records = [rec.set_item("140", (tod, "s")) for rec in template]
        parts.append(CAT048.create(records).unparse().to_bytes())
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "synthetic.raw"
        path.write_bytes(b"".join(parts))
        sites = Path(folder) / "sites.toml"
        sites.write_text('[[radar]]\nid = "R"\nsac = 25\nsic = 201\n'
                         "lat_deg = 48.0\nlon_deg = 2.0\nalt_m = 100.0\n")
        size = path.stat().st_size
        t0 = time.perf_counter()
        decoded = decode_file(path)
        t1 = time.perf_counter()
        tables = build_tables(decoded, user_sites=load_user_sites(sites))
        t2 = time.perf_counter()
    n = len(decoded.cat048)
    print(f"speed: {n} CAT048 records ({size / 1e6:.1f} MB raw): decode {t1 - t0:.1f} s "
          f"({n / (t1 - t0):,.0f} records/s), tables {t2 - t1:.2f} s, "
          f"{len(tables.dataset.plots)} plots")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=10000, help="fuzz inputs (0: no fuzzing)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--speed", type=int, default=0,
                        help="also time a synthetic raw file of this many CAT048 records")
    args = parser.parse_args()
    crashes = fuzz(args.n, args.seed) if args.n else 0
    if args.speed:
        speed(args.speed)
    sys.exit(1 if crashes else 0)


if __name__ == "__main__":
    main()

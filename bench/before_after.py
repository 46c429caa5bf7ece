#!/usr/bin/env python3
"""Before/after table of nmat profiles on the same materials: PSNR and BPPC per material from a
baseline CSV and a new results CSV (both in bench/quality.sh's format), Markdown.

Usage: bench/before_after.py BASELINE.csv NEW.csv [CODEC ...]   (default: nmat-ntc-0.2 nmat-ntc-1.0)
"""
import csv
import sys


def load(path):
    rows = {}
    for r in csv.DictReader(open(path)):
        rows[(r["material"], r["codec"])] = (float(r["bppc"]), float(r["psnr_db"]))
    return rows


before, after = load(sys.argv[1]), load(sys.argv[2])
codecs = sys.argv[3:] or ["nmat-ntc-0.2", "nmat-ntc-1.0"]
for codec in codecs:
    materials = sorted({m for (m, c) in after if c == codec and (m, c) in before})
    print(f"\n{codec}, {len(materials)} materials:\n")
    print("| material | BPPC before | BPPC after | PSNR before (dB) | PSNR after (dB) | Δ dB |")
    print("|---|---:|---:|---:|---:|---:|")
    deltas, rates = [], []
    for m in materials:
        (b0, p0), (b1, p1) = before[(m, codec)], after[(m, codec)]
        deltas.append(p1 - p0)
        rates.append((b0, b1))
        print(f"| {m} | {b0:.3f} | {b1:.3f} | {p0:.2f} | {p1:.2f} | {p1 - p0:+.2f} |")
    if materials:
        n = len(materials)
        print(
            f"| **mean** | {sum(r[0] for r in rates) / n:.3f} | {sum(r[1] for r in rates) / n:.3f} "
            f"| | | **{sum(deltas) / n:+.2f}** ({sum(d > 0 for d in deltas)} of {n} better) |"
        )

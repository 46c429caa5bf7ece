#!/usr/bin/env python3
"""Before/after table of nmat profiles on the same materials: PSNR and BPPC per material from a
baseline CSV and a new results CSV (both in bench/quality.sh's format), Markdown. Where the new CSV
also holds JPEG XL and AVIF points bisected to the profile's rate (`jpegxl@P`, `avif@P`), they are
columns of their own, in bold where they beat the new nmat value.

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
    profile = codec.removeprefix("nmat-")
    anchors = [(name, f"{key}@{profile}") for name, key in (("JPEG XL", "jpegxl"), ("AVIF", "avif"))]
    anchors = [(name, key) for name, key in anchors if any(c == key for (_, c) in after)]
    materials = sorted({m for (m, c) in after if c == codec and (m, c) in before})
    print(f"\n{codec}, {len(materials)} materials:\n")
    print(
        "| material | BPPC before | BPPC after | PSNR before (dB) | PSNR after (dB) | Δ dB |"
        + "".join(f" {name} (BPPC) |" for name, _ in anchors)
    )
    print("|---|---:|---:|---:|---:|---:|" + "---:|" * len(anchors))
    deltas, rates = [], []
    for m in materials:
        (b0, p0), (b1, p1) = before[(m, codec)], after[(m, codec)]
        deltas.append(p1 - p0)
        rates.append((b0, b1))
        cells = []
        for _, key in anchors:
            if (m, key) in after:
                rate, psnr = after[(m, key)]
                value = f"**{psnr:.2f}**" if psnr > p1 else f"{psnr:.2f}"
                cells.append(f" {value} ({rate:.3f}) |")
            else:
                cells.append(" – |")
        print(f"| {m} | {b0:.3f} | {b1:.3f} | {p0:.2f} | {p1:.2f} | {p1 - p0:+.2f} |" + "".join(cells))
    if materials:
        n = len(materials)
        print(
            f"| **mean** | {sum(r[0] for r in rates) / n:.3f} | {sum(r[1] for r in rates) / n:.3f} "
            f"| {sum(before[(m, codec)][1] for m in materials) / n:.2f} "
            f"| {sum(after[(m, codec)][1] for m in materials) / n:.2f} "
            f"| **{sum(deltas) / n:+.2f}** ({sum(d > 0 for d in deltas)} of {n} better) |"
            + " |" * len(anchors)
        )

#!/usr/bin/env python3
"""Summaries of bench/quality.sh rows, as Markdown:
1. per codec: materials, mean BPPC, mean whole-chain PSNR, mean seconds;
2. head to head on the materials both sides have, over all materials and per development set
   (`nexuiz`, `stk-*`, `ufo-*`): every nmat profile against the JPEG XL, AVIF and nmat-JPEG points
   bisected to its rate (`jpegxl@P`, `avif@P`, `jpeg@P`) and the better of AVIF and JPEG XL on each
   material (`best@P`, what issue targets are stated against), nmat at ≈1 BPPC
   against BC1/BC4 and ASTC 8×8, nmat-JPEG against AVIF and JPEG XL at the same rate and against BC1/BC4 at
   BC1/BC4's rate (`jpeg@bc1`) (mean Δ dB, wins);
3. encode seconds per profile for the materials named in --big (e.g. the 1024² ones).

Usage: summarize.py results.csv [--big m1,m2,...]"""
import csv
import sys
from collections import defaultdict

path = sys.argv[1]
big = []
if "--big" in sys.argv:
    big = sys.argv[sys.argv.index("--big") + 1].split(",")
rows = list(csv.DictReader(open(path)))
by = defaultdict(dict)  # codec -> material -> row
for r in rows:
    by[r["codec"]][r["material"]] = r
# The better of AVIF and JPEG XL at each nmat profile's rate, per material (JPEG XL alone cannot
# reach some low rates: then AVIF's point).
for c in [c for c in by if c.startswith("avif@")]:
    p = c.split("@")[1]
    for m, avif in by[c].items():
        jxl = by.get("jpegxl@" + p, {}).get(m)
        best = max([avif] + ([jxl] if jxl else []), key=lambda r: float(r["psnr_db"]))
        by["best@" + p][m] = best


def set_of(material):
    """The development set a material belongs to (bench/dev-materials.sh)."""
    for prefix, name in (("stk-", "stk"), ("ufo-", "ufo")):
        if material.startswith(prefix):
            return name
    return "nexuiz"

print("| codec | materials | mean BPPC | mean PSNR (dB, whole chain) | mean seconds |")
print("|---|---:|---:|---:|---:|")
for codec in sorted(by, key=lambda c: sum(float(r["bppc"]) for r in by[c].values()) / len(by[c])):
    g = list(by[codec].values())
    mean = lambda k: sum(float(r[k]) for r in g) / len(g)
    print(f"| {codec} | {len(g)} | {mean('bppc'):.3f} | {mean('psnr_db'):.2f} | {mean('seconds'):.1f} |")

# Matched anchors first (by nmat profile, then codec), then the fixed-rate codecs.
matched = sorted((c for c in by if "@" in c), key=lambda c: (c.split("@")[1], c))
pairs = [("nmat-" + c.split("@")[1], c) for c in matched] + [
    ("nmat-ntc-1.0", "bc1/bc4"), ("nmat-ntc-1.0", "astc8x8"),
    ("nmat-ntc-0.5", "astc12x12"), ("nmat-ntc-2.25", "bc1/bc4"),
] + [
    (c, other + "@" + c.split("@")[1])
    for c in matched if c.startswith("jpeg@")
    for other in ("avif", "jpegxl")
] + [
    ("jpeg@bc1", "bc1/bc4"),
]
print()
print("| nmat | against | set | common materials | mean BPPC (nmat / other) | mean Δ PSNR dB (nmat − other) | nmat wins | worst Δ |")
print("|---|---|---|---:|---:|---:|---:|---:|")
sets = sorted({set_of(m) for r in by.values() for m in r})
for a, b in pairs:
    both = sorted(set(by.get(a, {})) & set(by.get(b, {})))
    for group in ["all"] + (sets if len(sets) > 1 else []):
        common = [m for m in both if group == "all" or set_of(m) == group]
        if not common:
            continue
        d = [float(by[a][m]["psnr_db"]) - float(by[b][m]["psnr_db"]) for m in common]
        ra = sum(float(by[a][m]["bppc"]) for m in common) / len(common)
        rb = sum(float(by[b][m]["bppc"]) for m in common) / len(common)
        wins = sum(1 for x in d if x > 0)
        worst = min(zip(d, common))
        print(f"| {a} | {b} | {group} | {len(common)} | {ra:.3f} / {rb:.3f} | {sum(d) / len(d):+.2f} | {wins} of {len(common)} | {worst[0]:+.2f} ({worst[1]}) |")

if big:
    print()
    print("| profile | " + " | ".join(big) + " | mean |")
    print("|---|" + "---:|" * (len(big) + 1))
    for codec in sorted(c for c in by if c.startswith("nmat-")):
        cells = [by[codec].get(m) for m in big]
        secs = [float(c["seconds"]) for c in cells if c]
        mean = f"{sum(secs) / len(secs):.0f}" if secs else "–"
        print(f"| {codec} | " + " | ".join(f"{float(c['seconds']):.0f}" if c else "–" for c in cells) + f" | {mean} |")

#!/usr/bin/env python3
"""Averages bench/quality.sh rows per codec: mean BPPC, mean whole-chain PSNR, mean seconds,
and the count of materials, as a Markdown table."""
import csv
import sys
from collections import defaultdict

rows = list(csv.DictReader(open(sys.argv[1])))
groups = defaultdict(list)
for r in rows:
    groups[r["codec"]].append(r)
print("| codec | materials | mean BPPC | mean PSNR (dB, whole chain) | mean seconds |")
print("|---|---:|---:|---:|---:|")
for codec in sorted(groups, key=lambda c: sum(float(r["bppc"]) for r in groups[c]) / len(groups[c])):
    g = groups[codec]
    n = len(g)
    mean = lambda k: sum(float(r[k]) for r in g) / n
    print(f"| {codec} | {n} | {mean('bppc'):.3f} | {mean('psnr_db'):.2f} | {mean('seconds'):.1f} |")

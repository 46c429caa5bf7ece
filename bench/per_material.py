#!/usr/bin/env python3
"""Per-material table of bench/quality.sh rows: PSNR (BPPC) per codec, Markdown."""
import csv
import sys
from collections import defaultdict

rows = list(csv.DictReader(open(sys.argv[1])))
codecs = []
table = defaultdict(dict)
for r in rows:
    if r["codec"] not in codecs:
        codecs.append(r["codec"])
    table[r["material"]][r["codec"]] = f"{float(r['psnr_db']):.2f} ({float(r['bppc']):.3f})"
print("| material | " + " | ".join(codecs) + " |")
print("|---|" + "---:|" * len(codecs))
for m, cells in table.items():
    print(f"| {m} | " + " | ".join(cells.get(c, "–") for c in codecs) + " |")

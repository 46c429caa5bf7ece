#!/usr/bin/env python3
"""Turns the output of `nmat bench FILE... --ref DIR` into the Markdown tables of
docs/PERFORMANCE.md: one table per material file, plus the machine lines.

Usage: python3 bench/perf_table.py OUTPUT.txt [OUTPUT.txt ...]
"""
import re
import sys

ROW = re.compile(r"^  (.+?)\s{2,}(\d+\.\d)\s+(\d+)\s+(\d+\.\d)%\s+(\S+)\s+(\S+)\s+(\d+)$")
REF = re.compile(r"^  (reference: .+?)\s{2,}(\d+\.\d)\s+(\d+)\s+\((.+)\)$")
NOTE = re.compile(r"^  (random access ÷ region .+)$")

def main(paths):
    seen_machine = False
    notes = []

    def flush():
        # Notes printed under a material's table (after its last row).
        if notes:
            print()
            for note in notes:
                print(note + "  ")
            notes.clear()

    for path in paths:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
        for line in lines:
            if not seen_machine and (line.startswith("machine:") or "peak multiply-add" in line or "roofline =" in line):
                print(line.strip() + "  ")
                continue
            if line.endswith(".nmat") or ".nmat:" in line:
                seen_machine = True
                flush()
                print()
                print(f"**{line.split(': ', 1)[0].split('/')[-1]}** — {line.split(': ', 1)[1]}")
                print()
                print("| mode | ns/texel | texels/s | % roofline | PSNR dB (region) | max \\|Δ\\| vs float | bytes |")
                print("|---|---:|---:|---:|---:|---:|---:|")
                continue
            m = ROW.match(line)
            if m:
                mode, ns, tps, roof, psnr, delta, size = m.groups()
                print(f"| {mode} | {ns} | {int(tps):,} | {roof} | {psnr} | {delta} | {int(size):,} |")
                continue
            m = REF.match(line)
            if m:
                mode, ns, tps, note = m.groups()
                print(f"| {mode} ({note}) | {ns} | {int(tps):,} | | | | |")
                continue
            m = NOTE.match(line)
            if m:
                notes.append(m.group(1))
    flush()

if __name__ == "__main__":
    main(sys.argv[1:])

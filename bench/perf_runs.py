#!/usr/bin/env python3
"""Summarizes repeated `nmat bench` runs of the same files (a shared machine's speed drifts from
run to run, so one run is not enough to judge a target): for every material, the median and the
range over the runs of the one-thread region decode (ns/texel and % of the roofline) and of
random access, and their ratio (timed in alternation within each run when the output has that
line, else the ratio of the two rows).

Usage: python3 bench/perf_runs.py OUTPUT.txt [OUTPUT.txt ...]   (any order, any number of files
per material; rows are matched by material file name)
"""
import re
import statistics
import sys

ROW = re.compile(r"^  (.+?)\s{2,}(\d+\.\d)\s+(\d+)\s+(\d+\.\d)%\s+(\S+)\s+(\S+)\s+(\d+)$")
HEAD = re.compile(r"^(\S+\.nmat): ")
REGION = re.compile(r"^integer (\S+) region, all \d+ ch, 1 thread$")
RANDOM = re.compile(r"^integer (\S+) random access per texel, all \d+ ch$")
ALTERNATED = re.compile(r"^  random access ÷ region per texel, \S+, runs alternated: (\d+\.\d+)×")


def parse(path):
    """{material: {"region": (ns, roof), "random": (ns, roof)}} for the best kernel's rows."""
    runs, material, kernel = {}, None, None
    with open(path, encoding="utf-8") as f:
        for line in f.read().splitlines():
            m = HEAD.match(line)
            if m:
                material, kernel = m.group(1).split("/")[-1], None
                runs[material] = {}
                continue
            alternated = ALTERNATED.match(line)
            if alternated and material:
                runs[material]["alternated"] = float(alternated.group(1))
                continue
            m = ROW.match(line)
            if not (m and material):
                continue
            mode, ns, roof = m.group(1), float(m.group(2)), float(m.group(4))
            region = REGION.match(mode)
            if region and kernel is None:  # the first region row is the fastest kernel's
                kernel = region.group(1)
                runs[material]["region"] = (ns, roof)
            elif RANDOM.match(mode):
                runs[material]["random"] = (ns, roof)
    return runs


def span(values, fmt):
    return f"{fmt.format(statistics.median(values))} ({fmt.format(min(values))}–{fmt.format(max(values))})"


def main(paths):
    by_material = {}
    for path in paths:
        for material, rows in parse(path).items():
            if "region" in rows and "random" in rows:
                by_material.setdefault(material, []).append(rows)
    print("| material | runs | region ns/texel | region % roofline | random access ns/texel | random ÷ region (runs alternated) |")
    print("|---|---:|---:|---:|---:|---:|")
    for material, runs in sorted(by_material.items()):
        region_ns = [r["region"][0] for r in runs]
        roof = [r["region"][1] for r in runs]
        random_ns = [r["random"][0] for r in runs]
        # The alternated measurement when the output has it, else the ratio of the two rows.
        ratio = [r.get("alternated", r["random"][0] / r["region"][0]) for r in runs]
        print(
            f"| {material} | {len(runs)} | {span(region_ns, '{:.0f}')} | {span(roof, '{:.1f}')} "
            f"| {span(random_ns, '{:.0f}')} | {span(ratio, '{:.2f}')} |"
        )


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])

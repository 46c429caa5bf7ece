#!/usr/bin/env python3
"""How compressible a neural material's network is: per file, the MLP section's size, its share of
the file, and the order-0 entropy of its int8 weights (bits per weight, of 8 stored), per layer and
over all layers; what an entropy coder of the weights alone could save at best with a static
per-file table (scales and biases left as they are). Reads fixed-rate and packed files alike (the
MLP section, docs/FORMAT.md §5.3, is stored as it is in both).

With --columns, also where the first layer's int8 range goes: per input feature (column) the mean
|weight code| over the rows, and how many rows have their largest |code| on each feature (a row
whose range one feature takes leaves the others few bits: docs/FORMAT.md §6.5).

Usage: bench/mlp_entropy.py [--columns] FILE.nmat...
"""
import collections
import math
import struct
import sys

MLP = 3


def entropy(values):
    counts = collections.Counter(values)
    n = len(values)
    return -sum(c / n * math.log2(c / n) for c in counts.values())


def mlp_section(data, path):
    if data[:4] != b"NMAT":
        sys.exit(f"{path}: not an .nmat file")
    (count,) = struct.unpack_from("<I", data, 16)
    for i in range(count):
        kind, _flags, offset, length = struct.unpack_from("<IIII", data, 32 + 16 * i)
        if kind == MLP:
            return data[offset : offset + length]
    sys.exit(f"{path}: no MLP section (a JPEG material?)")


def columns(mlp):
    inputs, outputs = struct.unpack_from("<HH", mlp, 8)
    w = struct.unpack_from(f"<{inputs * outputs}b", mlp, 8 + 8 * mlp[0])
    rows = [w[o * inputs : (o + 1) * inputs] for o in range(outputs)]
    means = [sum(abs(r[i]) for r in rows) / outputs for i in range(inputs)]
    tops = collections.Counter(max(range(inputs), key=lambda i: abs(r[i])) for r in rows)
    print(f"  layer 0, {inputs} inputs x {outputs} rows; mean |code| per input: "
          + " ".join(f"{m:.0f}" for m in means))
    print("  rows whose largest |code| is on input i (i: rows): "
          + ", ".join(f"{i}: {n}" for i, n in sorted(tops.items())))


show_columns = "--columns" in sys.argv[1:]
for path in [a for a in sys.argv[1:] if a != "--columns"]:
    data = open(path, "rb").read()
    mlp = mlp_section(data, path)
    layers = mlp[0]
    at = 8 + 8 * layers
    weights, parts = [], []
    for k in range(layers):
        inputs, outputs = struct.unpack_from("<HH", mlp, 8 + 8 * k)
        n = inputs * outputs
        w = struct.unpack_from(f"<{n}b", mlp, at)
        at += (n + 3) // 4 * 4 + 8 * outputs
        weights += w
        parts.append(f"{inputs}x{outputs} {entropy(w):.2f}")
    bits = entropy(weights)
    saved = len(weights) * (8 - bits) / 8
    print(
        f"{path}: MLP {len(mlp)} bytes ({100 * len(mlp) / len(data):.1f} % of {len(data)}), "
        f"{len(weights)} int8 weights at {bits:.2f} bits each (layers: {', '.join(parts)}); "
        f"coded: at most {saved:.0f} bytes saved ({100 * saved / len(data):.1f} % of the file)"
    )
    if show_columns:
        columns(mlp)

// The requantization of the tiled and matrix kernels (tiled.wgsl, matrix.wgsl), from a layer's
// row table (tiled.rs: `row_table`; layout in tiled.wgsl).

// A row table (layout.rs: `NmatRequantRow`), read once for all the accumulators of the row.
struct NmatRequantRow {
    bias: i32,
    m: u32,
    s: u32,
    u: u32,
    mp: i32,
    c: f32,
    lo: i32,
    hi: i32,
}

fn nmat_requant_table(rb: u32) -> NmatRequantRow {
    return NmatRequantRow(
        bitcast<i32>(nmat_desc[rb + NMAT_REQUANT_BIAS]),
        nmat_desc[rb + NMAT_REQUANT_M],
        nmat_desc[rb + NMAT_REQUANT_S],
        nmat_desc[rb + NMAT_REQUANT_U],
        bitcast<i32>(nmat_desc[rb + NMAT_REQUANT_MP]),
        bitcast<f32>(nmat_desc[rb + NMAT_REQUANT_C]),
        bitcast<i32>(nmat_desc[rb + NMAT_REQUANT_LO]),
        bitcast<i32>(nmat_desc[rb + NMAT_REQUANT_HI]),
    );
}

// nmat_requant_with(acc, row) is sat16((acc · m + 2^(s−1)) >> s) exactly, with acc first clamped to the row's saturation range
// [lo, hi] (outside it the result saturates anyway, inside it fits an i32).
//
// 32-bit path (u ≠ 0; tiled.rs sets it where m' < 2^24, |acc| ≤ 2^24 on [lo, hi], u ≤ 31 and
// |acc · m' / 2^u| ≤ 2^20): the result is r = floor((acc · m' + 2^(u−1)) / 2^u). The f32
// estimate q = floor(acc · (m' / 2^u) + 0.5) is within 1 of r (acc and m' / 2^u are exact f32
// values; the two roundings err by at most 2^−3 in all). Then e = acc · m' − q · 2^u lies in
// (−(1/2 + 2^−3) · 2^u, (1/2 + 2^−3) · 2^u) ⊂ (−2^31, 2^31), so wrapping i32 arithmetic gives it
// exactly, and r = q − 1 if e < −2^(u−1), q + 1 if e ≥ 2^(u−1), else q.
//
// 64-bit path: |acc| · m as a 64-bit (hi, lo) pair; floor(x / 2^s) of x = acc · m + 2^(s−1) is
// (|acc| · m + 2^(s−1)) >> s for acc ≥ 0 and −((|acc| · m + 2^(s−1) − 1) >> s) for acc < 0
// (floor(−y) = −ceil(y)); the clamp keeps the quotient below 2^31.
fn nmat_requant_with(acc_in: i32, row: NmatRequantRow) -> i32 {
    let acc = clamp(acc_in, row.lo, row.hi);
    let u = row.u;
    if (u != 0u) {
        var q = i32(floor(f32(acc) * row.c + 0.5));
        let e = acc * row.mp - (q << u);
        let half = 1 << (u - 1u);
        q += select(0, -1, e < -half) + select(0, 1, e >= half);
        return nmat_sat16(q);
    }
    let s = row.s;
    let negative = acc < 0;
    let magnitude = select(bitcast<u32>(acc), 0u - bitcast<u32>(acc), negative);
    let p = nmat_umul64(magnitude, row.m);
    let minus = select(0u, 1u, negative);
    var add = vec2<u32>(0u, (1u << (s - 1u)) - minus);
    if (s > 32u) {
        add = vec2<u32>((1u << (s - 33u)) - minus, 0u - minus);
    }
    let lo = p.y + add.y;
    let hi = p.x + add.x + select(0u, 1u, lo < p.y);
    var r = u32();
    if (s < 32u) {
        r = (lo >> s) | (hi << (32u - s));
    } else {
        r = hi >> (s - 32u);
    }
    return nmat_sat16(select(bitcast<i32>(r), -bitcast<i32>(r), negative));
}

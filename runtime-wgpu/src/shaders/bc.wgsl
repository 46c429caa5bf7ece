// BC1, BC4 and BC5 block encoders, byte-identical with nmat-core's `bc::encode_bc1`, `encode_bc4`
// and `encode_bc5` (core-nostd/src/bc/bc1.rs, bc4.rs): the same candidates in the same order, the
// same integer arithmetic, the same rules on ties. The one 64-bit step (BC1's power iteration) is
// computed exactly in 32-bit pieces. `BC1_SINGLE` (the endpoints of single-colour blocks, taken
// from the core) is prepended to this file by context.rs.
//
// Entry points (bindings and `Params` of decode.wgsl, which comes first):
//   `encode_codes`: params.count blocks of a region whose texels the material's kernel decoded
//     into `requests` first (Context::record_transcode), one invocation per block.
//   `encode_pixels`: params.count blocks of RGBA8 pixels from `requests` (17 words per block: 16
//     pixels, R in the low byte, then the valid mask), one invocation per block.
// Blocks are written to `out_codes` from word params.out_offset, block row r at
// r · params.row_words, params.format = 1 (BC1), 4 (BC4) or 5 (BC5). bc7.wgsl follows with BC7's
// encoder and entry points.

var<private> px: array<u32, 16>; // the block being encoded: RGBA8 per pixel, row-major
var<private> vals: array<u32, 16>; // one channel of it (BC4)

fn counts(valid: u32, i: u32) -> bool {
    return ((valid >> i) & 1u) != 0u;
}

fn rgb(p: u32) -> vec3<i32> {
    return vec3<i32>(i32(p & 255u), i32((p >> 8u) & 255u), i32((p >> 16u) & 255u));
}

// ---- signed 64-bit values as (hi, lo), for the power iteration ----

fn neg64(v: vec2<u32>) -> vec2<u32> {
    let lo = ~v.y + 1u;
    return vec2<u32>(~v.x + select(0u, 1u, lo == 0u), lo);
}

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.y + b.y;
    return vec2<u32>(a.x + b.x + select(0u, 1u, lo < a.y), lo);
}

fn imul64(a: i32, b: i32) -> vec2<u32> {
    let ma = select(bitcast<u32>(a), 0u - bitcast<u32>(a), a < 0);
    let mb = select(bitcast<u32>(b), 0u - bitcast<u32>(b), b < 0);
    let p = nmat_umul64(ma, mb);
    return select(p, neg64(p), (a < 0) != (b < 0));
}

fn wide(a: i32) -> vec2<u32> {
    return vec2<u32>(select(0u, 0xFFFFFFFFu, a < 0), bitcast<u32>(a));
}

// Bits of |v| (0 for v = 0).
fn bit_length64(v: vec2<u32>) -> u32 {
    let m = select(v, neg64(v), bitcast<i32>(v.x) < 0);
    if (m.x != 0u) {
        return 64u - countLeadingZeros(m.x);
    }
    return 32u - countLeadingZeros(m.y);
}

// v >> shift (arithmetic), for results that fit an i32.
fn shr64(v: vec2<u32>, shift: u32) -> i32 {
    if (shift == 0u) {
        return bitcast<i32>(v.y);
    }
    if (shift < 32u) {
        return bitcast<i32>((v.y >> shift) | (v.x << (32u - shift)));
    }
    return bitcast<i32>(v.x) >> (shift - 32u);
}

// ---- BC1 ----

fn expand5(v: u32) -> u32 {
    return (v * 510u + 31u) / 62u;
}

fn expand6(v: u32) -> u32 {
    return (v * 510u + 63u) / 126u;
}

fn third(a: u32, b: u32, m: u32) -> u32 {
    return ((2u * a + b) * 510u + 3u * m) / (6u * m);
}

fn midpoint(a: u32, b: u32, m: u32) -> u32 {
    return ((a + b) * 510u + 2u * m) / (4u * m);
}

struct Palette1 {
    p: array<vec3<u32>, 4>,
    usable: u32,
}

fn palette1(c0: u32, c1: u32) -> Palette1 {
    let a = vec3<u32>((c0 >> 11u) & 31u, (c0 >> 5u) & 63u, c0 & 31u);
    let b = vec3<u32>((c1 >> 11u) & 31u, (c1 >> 5u) & 63u, c1 & 31u);
    var r = Palette1();
    r.p[0] = vec3<u32>(expand5(a.x), expand6(a.y), expand5(a.z));
    r.p[1] = vec3<u32>(expand5(b.x), expand6(b.y), expand5(b.z));
    if (c0 > c1) {
        r.p[2] = vec3<u32>(third(a.x, b.x, 31u), third(a.y, b.y, 63u), third(a.z, b.z, 31u));
        r.p[3] = vec3<u32>(third(b.x, a.x, 31u), third(b.y, a.y, 63u), third(b.z, a.z, 31u));
        r.usable = 4u;
    } else {
        r.p[2] = vec3<u32>(midpoint(a.x, b.x, 31u), midpoint(a.y, b.y, 63u), midpoint(a.z, b.z, 31u));
        r.p[3] = vec3<u32>(0u);
        r.usable = 3u;
    }
    return r;
}

fn distance1(a: vec3<i32>, b: vec3<u32>) -> u32 {
    let d = a - vec3<i32>(b);
    return u32(d.x * d.x + d.y * d.y + d.z * d.z);
}

// (error, indices): the nearest usable entry of each valid pixel, the lowest on a tie. With
// `uniform`, every pixel is `colour` instead of the block's own.
fn fit1(valid: u32, c0: u32, c1: u32, uniform: bool, colour: vec3<i32>) -> vec2<u32> {
    let pal = palette1(c0, c1);
    var error = 0u;
    var indices = 0u;
    for (var i = 0u; i < 16u; i++) {
        if (!counts(valid, i)) {
            continue;
        }
        let c = select(rgb(px[i]), colour, uniform);
        var best_k = 0u;
        var best_e = 0xFFFFFFFFu;
        for (var k = 0u; k < pal.usable; k++) {
            let e = distance1(c, pal.p[k]);
            if (e < best_e) {
                best_k = k;
                best_e = e;
            }
        }
        error += best_e;
        indices |= best_k << (2u * i);
    }
    return vec2<u32>(error, indices);
}

fn bits565(c: vec3<u32>) -> u32 {
    return (c.x << 11u) | (c.y << 5u) | c.z;
}

fn nearest565(c: vec3<i32>) -> u32 {
    let v = vec3<u32>(clamp(c, vec3<i32>(0), vec3<i32>(255)));
    let m = vec3<u32>(31u, 63u, 31u);
    return bits565(min((v * m + 127u) / 255u, m));
}

struct Ends {
    ok: bool,
    lo: u32,
    hi: u32,
}

// The valid pixels at the low and the high end of the principal axis (`principal_ends` of the
// core with 3 coordinates): the first wins a tie at the low end, the last at the high end.
fn principal_ends3(valid: u32) -> Ends {
    var missing = Ends();
    missing.ok = false;
    var n = 0;
    var sum = vec3<i32>(0);
    for (var i = 0u; i < 16u; i++) {
        if (counts(valid, i)) {
            n++;
            sum += rgb(px[i]);
        }
    }
    // |deviation| ≤ 15·255 and |covariance| ≤ 16 · (15·255)² < 2^28: both fit an i32.
    var cov = array<vec3<i32>, 3>();
    for (var i = 0u; i < 16u; i++) {
        if (counts(valid, i)) {
            let d = n * rgb(px[i]) - sum;
            cov[0] += d.x * d;
            cov[1] += d.y * d;
            cov[2] += d.z * d;
        }
    }
    var widest = 0u;
    for (var c = 1u; c < 3u; c++) {
        if (cov[c][c] >= cov[widest][widest]) {
            widest = c;
        }
    }
    var v = array<vec2<u32>, 3>(wide(cov[widest].x), wide(cov[widest].y), wide(cov[widest].z));
    var s = vec3<i32>(0);
    for (var iteration = 0u; iteration <= 8u; iteration++) {
        // s = v scaled down below 2^16.
        let scale = max(bit_length64(v[0]), max(bit_length64(v[1]), bit_length64(v[2])));
        if (scale == 0u) {
            return missing;
        }
        let shift = select(0u, scale - 16u, scale > 16u);
        s = vec3<i32>(shr64(v[0], shift), shr64(v[1], shift), shr64(v[2], shift));
        if (iteration == 8u) {
            break;
        }
        for (var r = 0u; r < 3u; r++) {
            v[r] = add64(add64(imul64(cov[r].x, s.x), imul64(cov[r].y, s.y)), imul64(cov[r].z, s.z));
        }
    }
    // |projection| ≤ 3 · 15·255 · 2^16 < 2^31.
    var r = Ends();
    r.ok = true;
    var lo_p = 0;
    var hi_p = 0;
    var seen = false;
    for (var i = 0u; i < 16u; i++) {
        if (!counts(valid, i)) {
            continue;
        }
        let d = n * rgb(px[i]) - sum;
        let p = d.x * s.x + d.y * s.y + d.z * s.z;
        if (!seen || p < lo_p) {
            lo_p = p;
            r.lo = i;
        }
        if (!seen || p >= hi_p) {
            hi_p = p;
            r.hi = i;
        }
        seen = true;
    }
    return r;
}

// Least-squares 8-bit endpoints for 4-colour indices; ok = false if every pixel has one weight.
struct Refined {
    ok: bool,
    e0: vec3<i32>,
    e1: vec3<i32>,
}

fn refine1(valid: u32, indices: u32) -> Refined {
    var aa = 0;
    var bb = 0;
    var ab = 0;
    var x = vec3<i32>(0);
    var y = vec3<i32>(0);
    for (var i = 0u; i < 16u; i++) {
        if (!counts(valid, i)) {
            continue;
        }
        let k = (indices >> (2u * i)) & 3u;
        let alpha = select(select(select(1, 2, k == 2u), 0, k == 1u), 3, k == 0u);
        let beta = 3 - alpha;
        aa += alpha * alpha;
        bb += beta * beta;
        ab += alpha * beta;
        x += alpha * rgb(px[i]);
        y += beta * rgb(px[i]);
    }
    var r = Refined();
    let det = aa * bb - ab * ab;
    r.ok = det != 0;
    if (!r.ok) {
        return r;
    }
    for (var c = 0u; c < 3u; c++) {
        r.e0[c] = clamp(nmat_floor_div(2 * 3 * (bb * x[c] - ab * y[c]) + det, 2 * det), 0, 255);
        r.e1[c] = clamp(nmat_floor_div(2 * 3 * (aa * y[c] - ab * x[c]) + det, 2 * det), 0, 255);
    }
    return r;
}

fn encode_bc1(valid: u32) -> vec4<u32> {
    if (valid == 0u) {
        return vec4<u32>(0u);
    }
    let first = rgb(px[firstTrailingBit(valid)]);
    let ends = principal_ends3(valid);
    var c0 = u32();
    var c1 = u32();
    var indices = u32();
    if (!ends.ok || all(rgb(px[ends.lo]) == rgb(px[ends.hi]))) {
        // One colour: per channel the core's single-colour endpoints, in the better order.
        let t = vec3<u32>(BC1_SINGLE[first.x], BC1_SINGLE[first.y], BC1_SINGLE[first.z]);
        let a = bits565(vec3<u32>(t.x & 255u, (t.y >> 16u) & 255u, t.z & 255u));
        let b = bits565(vec3<u32>((t.x >> 8u) & 255u, t.y >> 24u, (t.z >> 8u) & 255u));
        let f1 = fit1(valid, a, b, true, first);
        let f2 = fit1(valid, b, a, true, first);
        if (f2.x < f1.x) {
            c0 = b;
            c1 = a;
            indices = f2.y;
        } else {
            c0 = a;
            c1 = b;
            indices = f1.y;
        }
    } else {
        var e0 = rgb(px[ends.hi]);
        var e1 = rgb(px[ends.lo]);
        var best_e = 0u;
        var have = false;
        for (var iteration = 0u; iteration < 3u; iteration++) {
            let a = nearest565(e0);
            let b = nearest565(e1);
            var last = 0u;
            var has_last = false;
            for (var order = 0u; order < 2u; order++) {
                let p = select(a, b, order == 1u);
                let q = select(b, a, order == 1u);
                let f = fit1(valid, p, q, false, vec3<i32>(0));
                if (!have || f.x < best_e) {
                    have = true;
                    best_e = f.x;
                    c0 = p;
                    c1 = q;
                    indices = f.y;
                }
                if (p > q) {
                    last = f.y;
                    has_last = true;
                }
            }
            if (!has_last || iteration >= 2u) {
                break;
            }
            let next = refine1(valid, last);
            if (!next.ok) {
                break;
            }
            e0 = next.e0;
            e1 = next.e1;
        }
    }
    return vec4<u32>(c0 | (c1 << 16u), indices, 0u, 0u);
}

// ---- BC4, BC5 ----

fn palette4(a0: u32, a1: u32) -> array<u32, 8> {
    var p = array<u32, 8>(a0, a1, 0u, 0u, 0u, 0u, 0u, 255u);
    if (a0 > a1) {
        for (var k = 1u; k <= 6u; k++) {
            p[k + 1u] = ((7u - k) * a0 + k * a1 + 3u) / 7u;
        }
    } else {
        for (var k = 1u; k <= 4u; k++) {
            p[k + 1u] = ((5u - k) * a0 + k * a1 + 2u) / 5u;
        }
    }
    return p;
}

// Squared error of endpoints (a0, a1) over the valid pixels of `vals`, each at its nearest entry.
fn error4(valid: u32, a0: u32, a1: u32) -> u32 {
    let p = palette4(a0, a1);
    var total = 0u;
    for (var i = 0u; i < 16u; i++) {
        if (!counts(valid, i)) {
            continue;
        }
        var best = 0xFFFFu;
        for (var k = 0u; k < 8u; k++) {
            let d = i32(vals[i]) - i32(p[k]);
            best = min(best, u32(d * d));
        }
        total += best;
    }
    return total;
}

const ASCENDING_EIGHT = array<u32, 8>(1u, 7u, 6u, 5u, 4u, 3u, 2u, 0u);
const ASCENDING_SIX = array<u32, 8>(6u, 0u, 2u, 3u, 4u, 5u, 1u, 7u);

var<private> index4: array<u32, 16>;

// The nearest entry of each valid pixel (the smaller value on a tie; 0 for the others), into
// `index4`.
fn indices4(valid: u32, a0: u32, a1: u32) {
    let p = palette4(a0, a1);
    var order = ASCENDING_SIX;
    if (a0 > a1) {
        order = ASCENDING_EIGHT;
    }
    var sorted = array<u32, 8>();
    for (var j = 0u; j < 8u; j++) {
        sorted[j] = p[order[j]];
    }
    for (var i = 0u; i < 16u; i++) {
        var at = 0u;
        for (var j = 0u; j < 7u; j++) {
            at += select(0u, 1u, 2u * vals[i] > sorted[j] + sorted[j + 1u]);
        }
        index4[i] = select(0u, order[at], counts(valid, i));
    }
}

struct Pair {
    ok: bool,
    a0: u32,
    a1: u32,
}

fn refine4(valid: u32, eight: bool) -> Pair {
    let d = select(5, 7, eight);
    var aa = 0;
    var bb = 0;
    var ab = 0;
    var x = 0;
    var y = 0;
    for (var i = 0u; i < 16u; i++) {
        let k = i32(index4[i]);
        if (!counts(valid, i) || (!eight && k >= 6)) {
            continue;
        }
        let alpha = select(select(d + 1 - k, 0, k == 1), d, k == 0);
        let beta = d - alpha;
        aa += alpha * alpha;
        bb += beta * beta;
        ab += alpha * beta;
        x += alpha * i32(vals[i]);
        y += beta * i32(vals[i]);
    }
    var r = Pair();
    let det = aa * bb - ab * ab;
    r.ok = det != 0;
    if (r.ok) {
        r.a0 = u32(clamp(nmat_floor_div(2 * d * (bb * x - ab * y) + det, 2 * det), 0, 255));
        r.a1 = u32(clamp(nmat_floor_div(2 * d * (aa * y - ab * x) + det, 2 * det), 0, 255));
    }
    return r;
}

var<private> best4: vec3<u32>; // (error, a0, a1)
var<private> have4: bool;

fn consider4(valid: u32, a0: u32, a1: u32) {
    let e = error4(valid, a0, a1);
    if (!have4 || e < best4.x) {
        have4 = true;
        best4 = vec3<u32>(e, a0, a1);
    }
}

// BC4 of `vals` as two words.
fn encode_bc4(valid: u32) -> vec2<u32> {
    if (valid == 0u) {
        return vec2<u32>(0u);
    }
    var lo = 255u;
    var hi = 0u;
    var inner_lo = 255u;
    var inner_hi = 0u;
    var inner = false;
    for (var i = 0u; i < 16u; i++) {
        if (counts(valid, i)) {
            let v = vals[i];
            lo = min(lo, v);
            hi = max(hi, v);
            if (v != 0u && v != 255u) {
                inner = true;
                inner_lo = min(inner_lo, v);
                inner_hi = max(inner_hi, v);
            }
        }
    }
    have4 = false;
    consider4(valid, hi, lo);
    if (lo != hi) {
        for (var i = 0; i < 8; i++) {
            for (var j = i + 1; j < 8; j++) {
                let l = i32(lo);
                let h = i32(hi);
                let n = j - i;
                let q0 = nmat_floor_div(2 * (l * n + (7 - i) * (h - l)) + n, 2 * n);
                let q1 = nmat_floor_div(2 * (l * n - i * (h - l)) + n, 2 * n);
                let a0 = u32(clamp(q0, 0, 255));
                let a1 = u32(clamp(q1, 0, 255));
                if (a0 > a1) {
                    consider4(valid, a0, a1);
                }
            }
        }
        if (inner) {
            for (var a0 = max(inner_lo, 1u) - 1u; a0 <= min(inner_lo + 1u, 255u); a0++) {
                for (var a1 = max(inner_hi, 1u) - 1u; a1 <= min(inner_hi + 1u, 255u); a1++) {
                    if (a0 <= a1) {
                        consider4(valid, a0, a1);
                    }
                }
            }
        } else {
            consider4(valid, 0u, 0u);
        }
    }
    for (var iteration = 0u; iteration < 3u; iteration++) {
        indices4(valid, best4.y, best4.z);
        let e = refine4(valid, best4.y > best4.z);
        if (!e.ok) {
            break;
        }
        for (var a0 = max(e.a0, 1u) - 1u; a0 <= min(e.a0 + 1u, 255u); a0++) {
            for (var a1 = max(e.a1, 1u) - 1u; a1 <= min(e.a1 + 1u, 255u); a1++) {
                if ((a0 > a1) == (e.a0 > e.a1)) {
                    consider4(valid, a0, a1);
                }
            }
        }
    }
    indices4(valid, best4.y, best4.z);
    // 16 indices of 3 bits from bit 16 of the block: pixel i at bit 16 + 3i.
    var lo_bits = best4.y | (best4.z << 8u);
    var hi_bits = 0u;
    for (var i = 0u; i < 16u; i++) {
        let at = 16u + 3u * i;
        if (at < 32u) {
            lo_bits |= index4[i] << at;
            if (at > 29u) {
                hi_bits |= index4[i] >> (32u - at);
            }
        } else {
            hi_bits |= index4[i] << (at - 32u);
        }
    }
    return vec2<u32>(lo_bits, hi_bits);
}

fn channel_into_vals(c: u32) {
    for (var i = 0u; i < 16u; i++) {
        vals[i] = (px[i] >> (8u * c)) & 255u;
    }
}

// The block in `px` in params.format, as up to 4 words (2 for BC1 and BC4).
fn encode_block(valid: u32) -> vec4<u32> {
    if (params.format == 1u) {
        return encode_bc1(valid);
    }
    channel_into_vals(0u);
    let r = encode_bc4(valid);
    if (params.format == 4u) {
        return vec4<u32>(r, 0u, 0u);
    }
    channel_into_vals(1u);
    let g = encode_bc4(valid);
    return vec4<u32>(r, g);
}

// Words per block: 2 for BC1 and BC4, 4 for BC5 and BC7 (bc7.wgsl: params.format 7 and 8).
fn block_words() -> u32 {
    return select(4u, 2u, params.format == 1u || params.format == 4u);
}

fn write_block(block: u32, words: vec4<u32>) {
    let at = params.out_offset + (block / params.width) * params.row_words
        + (block % params.width) * block_words();
    for (var k = 0u; k < block_words(); k++) {
        out_codes[at + k] = words[k];
    }
}

// BC blocks of texels decoded first (`Context::record_transcode`: the region's texels decoded by
// the material's kernel into `requests`, codes four per word, `params.out_channels` per texel in
// channel order, row-major over the `params.x0` × `params.y0` texels of the region that lie in
// the mip): one invocation per block of the region (`params.width` blocks a row, `params.count`
// in all). Component k is the code at slot (params.components >> 8k) & 15 of its texel, or the
// constant (params.constants, params.constant_mask); texels outside the mip are 0 and not valid,
// as the CPU's `transcode_blocks` has them.
@compute @workgroup_size(64)
fn encode_codes(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let block = gid.x + gid.y * groups.x * 64u;
    if (block >= params.count) {
        return;
    }
    write_block(block, encode_block(gather_codes(block)));
}

// The pixels of `block` of the decoded region (above) into `px`; returns the valid mask.
fn gather_codes(block: u32) -> u32 {
    let bx = block % params.width;
    let by = block / params.width;
    var valid = 0u;
    for (var i = 0u; i < 16u; i++) {
        let x = 4u * bx + i % 4u;
        let y = 4u * by + i / 4u;
        var pixel = 0u;
        if (x < params.x0 && y < params.y0) {
            valid |= 1u << i;
            let first = (y * params.x0 + x) * params.out_channels;
            for (var k = 0u; k < 4u; k++) {
                var code = (params.constants >> (8u * k)) & 255u;
                if (((params.constant_mask >> k) & 1u) == 0u) {
                    let at = first + ((params.components >> (8u * k)) & 15u);
                    code = (bitcast<u32>(requests[at / 4u]) >> (8u * (at % 4u))) & 255u;
                }
                pixel |= code << (8u * k);
            }
        }
        px[i] = pixel;
    }
    return valid;
}

@compute @workgroup_size(64)
fn encode_pixels(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let block = gid.x + gid.y * groups.x * 64u;
    if (block >= params.count) {
        return;
    }
    write_block(block, encode_block(gather_pixels(block)));
}

// The pixels of `block` given by the caller (17 words a block) into `px`; returns the valid mask.
fn gather_pixels(block: u32) -> u32 {
    for (var i = 0u; i < 16u; i++) {
        px[i] = bitcast<u32>(requests[17u * block + i]);
    }
    return bitcast<u32>(requests[17u * block + 16u]) & 0xFFFFu;
}

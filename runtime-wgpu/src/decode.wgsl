// The integer decoder of docs/FORMAT.md §6 in WGSL, bit-exact with nmat-core's `decode_texel_u8`.
// Only 32-bit integer arithmetic (WGSL has no i64): the 64-bit requantization product, the
// footprint numerator and the fusion-chain sum are computed in pieces, exactly.
//
// `desc` layout (written by `upload` in lib.rs, all u32):
//   [0] width  [1] height  [2] mip_count  [3] channel_count  [4] address_mode (0 wrap, 1 clamp)
//   [5] input_frac_bits  [6] pe_frequencies  [7] lod_input  [8] layer_count  [9] level_count
//   [10] grid_count  [11] grids_at  [12] levels_at  [13] layers_at  [14..30) mip_to_level[16]
//   grid g at grids_at + 8g: width, height, channels, bits, word offset in `latents`, word count,
//        quant_at (offset into desc: channels × (offset, step) as i32 bit patterns), 0
//   level l at levels_at + 1 + ... : see `level_base`: levels_at + l * (1 + 4 * 10):
//        term_count, then 4 terms × [mode, chain_len, grid ids × 8]
//   layer k at layers_at + 8k: inputs, outputs, out_frac_bits, activation, weights_at (i32 per
//        weight, in `desc`), rows_at (per row: bias, multiplier, shift, in `desc`)

struct Params {
    // 0: decode `count` requests from `requests`; 1: decode the rectangle (x0, y0, width, height)
    // of `mip` in row-major order.
    mode: u32,
    count: u32,
    mip: u32,
    x0: u32,
    y0: u32,
    width: u32,
    channel_mask: u32,
    out_channels: u32,
    // BC transcoding (bc.wgsl): 1 (BC1), 4 (BC4) or 5 (BC5); the material channel of each
    // component (byte k = component k); the code of each constant component (byte k) and which
    // are constant (bit k); the output row pitch. Every entry point: the output offset in words.
    format: u32,
    components: u32,
    constants: u32,
    constant_mask: u32,
    row_words: u32,
    out_offset: u32,
    // Decoding requests: the word where they start in `requests`.
    in_offset: u32,
    pad1: u32,
}

// Four storage buffers: the most downlevel limits allow per stage. The int8 weights (widened to
// i32) and the per-row constants live in `desc` after the descriptors.
@group(0) @binding(0) var<storage, read> desc: array<u32>;
@group(0) @binding(1) var<storage, read> latents: array<u32>;
@group(0) @binding(2) var<storage, read> requests: array<i32>;
@group(0) @binding(3) var<storage, read_write> out_codes: array<u32>;
@group(0) @binding(4) var<uniform> params: Params;

fn weight(i: u32) -> i32 {
    return bitcast<i32>(desc[i]);
}

const MAX_WIDTH: u32 = 128u;
const TERM_WORDS: u32 = 10u;
const LEVEL_WORDS: u32 = 41u;

fn address(i: i32, size: u32, clamp_mode: bool) -> u32 {
    let s = i32(max(size, 1u));
    if (clamp_mode) {
        return u32(clamp(i, 0, s - 1));
    }
    return u32(((i % s) + s) % s);
}

// floor(x / 2^k) position of a texel centre on a grid, in 1/256 cell (§6.2), without 64 bits:
// floor(q·128 / m) with q = (2x+1)·g < 2^29 is 128·(q / m) + (128·(q % m)) / m.
fn grid_pos(x: u32, mip_size: u32, grid_size: u32) -> i32 {
    let q = (2u * x + 1u) * grid_size;
    let m = max(mip_size, 1u);
    let p = 128u * (q / m) + (128u * (q % m)) / m;
    return i32(p) - 128;
}

fn grid_code(g: u32, x: u32, y: u32, c: u32) -> u32 {
    let gb = desc[11] + 8u * g;
    let w = desc[gb];
    let ch = desc[gb + 2u];
    let bits = desc[gb + 3u];
    let base = desc[gb + 4u];
    let words = desc[gb + 5u];
    let bit = ((y * w + x) * ch + c) * bits;
    let word = bit / 32u;
    let shift = bit % 32u;
    let lo = latents[base + word];
    var v = lo >> shift;
    if (shift + bits > 32u && word + 1u < words) {
        v = v | (latents[base + word + 1u] << (32u - shift));
    }
    return v & ((1u << bits) - 1u);
}

fn grid_value(g: u32, x: u32, y: u32, c: u32) -> i32 {
    let qa = desc[desc[11] + 8u * g + 6u] + 2u * c;
    return bitcast<i32>(desc[qa]) + i32(grid_code(g, x, y, c)) * bitcast<i32>(desc[qa + 1u]);
}

struct Footprint {
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
    fx: i32,
    fy: i32,
}

fn footprint(g: u32, x: u32, y: u32, mw: u32, mh: u32) -> Footprint {
    let gb = desc[11] + 8u * g;
    let gw = desc[gb];
    let gh = desc[gb + 1u];
    let clamp_mode = desc[4] == 1u;
    let px = grid_pos(x, mw, gw);
    let py = grid_pos(y, mh, gh);
    let ix = px >> 8u;
    let iy = py >> 8u;
    var f: Footprint;
    f.x0 = address(ix, gw, clamp_mode);
    f.x1 = address(ix + 1, gw, clamp_mode);
    f.y0 = address(iy, gh, clamp_mode);
    f.y1 = address(iy + 1, gh, clamp_mode);
    f.fx = px & 255;
    f.fy = py & 255;
    return f;
}

// Σ w·v of one grid's 4 cells: within [−2^31, 2^31) (§6.3), so an i32 holds it.
fn bilinear(g: u32, f: Footprint, c: u32) -> i32 {
    let gx = 256 - f.fx;
    let gy = 256 - f.fy;
    return gx * gy * grid_value(g, f.x0, f.y0, c) + f.fx * gy * grid_value(g, f.x1, f.y0, c)
        + gx * f.fy * grid_value(g, f.x0, f.y1, c) + f.fx * f.fy * grid_value(g, f.x1, f.y1, c);
}

fn triangle(t: u32, k: u32, phase: u32, frac_bits: u32) -> i32 {
    let period = 1u << (k + 2u);
    let a = (2u * t + 1u + phase * (period / 2u)) % (2u * period);
    let mag = select(2u * period - 2u * a, 2u * a - 2u * period, 2u * a >= 2u * period);
    return i32(mag << (frac_bits - k - 3u));
}

fn sat16(v: i32) -> i32 {
    return clamp(v, -32768, 32767);
}

// 32×32 → 64-bit unsigned product as (hi, lo).
fn umul64(a: u32, b: u32) -> vec2<u32> {
    let a0 = a & 0xFFFFu;
    let a1 = a >> 16u;
    let b0 = b & 0xFFFFu;
    let b1 = b >> 16u;
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    let mid = (p00 >> 16u) + (p01 & 0xFFFFu) + (p10 & 0xFFFFu);
    let lo = (p00 & 0xFFFFu) | (mid << 16u);
    let hi = p11 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u);
    return vec2<u32>(hi, lo);
}

// sat16((acc · mult + 2^(shift−1)) >> shift), shift in 1..=62, |acc · mult| < 2^62 (§6.6).
fn requantize(acc: i32, mult: u32, shift: u32) -> i32 {
    let negative = acc < 0;
    let magnitude = select(u32(acc), u32(0) - bitcast<u32>(acc), negative);
    var p = umul64(magnitude, mult);
    if (negative) {
        // Two's complement negation of (hi, lo).
        let lo = ~p.y + 1u;
        let hi = ~p.x + select(0u, 1u, lo == 0u);
        p = vec2<u32>(hi, lo);
    }
    // + 2^(shift − 1)
    if (shift - 1u < 32u) {
        let add = 1u << (shift - 1u);
        let lo = p.y + add;
        p = vec2<u32>(p.x + select(0u, 1u, lo < p.y), lo);
    } else {
        p = vec2<u32>(p.x + (1u << (shift - 33u)), p.y);
    }
    // Arithmetic shift right of the signed 64-bit value.
    var hi: i32;
    var lo: u32;
    let shi = bitcast<i32>(p.x);
    if (shift < 32u) {
        lo = (p.y >> shift) | (p.x << (32u - shift));
        hi = shi >> shift;
    } else {
        lo = bitcast<u32>(shi >> (shift - 32u));
        hi = select(0, -1, shi < 0);
    }
    if (hi > 0 || (hi == 0 && lo > 32767u)) {
        return 32767;
    }
    if (hi < -1 || (hi == -1 && lo < 0xFFFF8000u)) {
        return -32768;
    }
    return bitcast<i32>(lo);
}

fn floor_div(n: i32, d: i32) -> i32 {
    let q = n / d;
    return select(q, q - 1, (n % d != 0) && (n < 0));
}

fn hard_gelu(z: i32, f: u32) -> i32 {
    let t = 3 << (f - 1u);
    if (z >= t) {
        return z;
    }
    if (z <= -t) {
        return 0;
    }
    return floor_div(z * (z + t) + t, 3 << f);
}

var<private> act_a: array<i32, 128>;
var<private> act_b: array<i32, 128>;
// The codes `decode` wrote, by channel (channels outside params.channel_mask are not written).
var<private> codes: array<u32, 16>;

// The input features of texel (xi, yi) of `mip_in` (addressed and clamped to the chain as on
// the CPU) in act_a[0..input width): latents, positional encoding, LOD (§6.2–6.4).
fn features(xi: i32, yi: i32, mip_in: u32) {
    let mip = min(mip_in, desc[2] - 1u);
    let mw = max(desc[0] >> mip, 1u);
    let mh = max(desc[1] >> mip, 1u);
    let clamp_mode = desc[4] == 1u;
    let x = address(xi, mw, clamp_mode);
    let y = address(yi, mh, clamp_mode);
    let f_in = desc[5];
    let level = desc[14u + mip];
    let lb = desc[12] + level * LEVEL_WORDS;
    var n = 0u;
    let terms = desc[lb];
    for (var t = 0u; t < terms; t++) {
        let tb = lb + 1u + t * TERM_WORDS;
        let chain = desc[tb + 1u];
        let g0 = desc[tb + 2u];
        let channels = desc[desc[11] + 8u * g0 + 2u];
        if (desc[tb] == 0u) {
            let f = footprint(g0, x, y, mw, mh);
            for (var k = 0u; k < 4u; k++) {
                let cx = select(f.x0, f.x1, (k & 1u) == 1u);
                let cy = select(f.y0, f.y1, k >= 2u);
                for (var c = 0u; c < channels; c++) {
                    act_a[n] = grid_value(g0, cx, cy, c);
                    n++;
                }
            }
        } else {
            for (var c = 0u; c < channels; c++) {
                // Σ over the chain of (s >> 16) and (s & 0xFFFF) kept apart: the exact sum
                // rounded half up is hi + (lo + 2^15) >> 16, and no part overflows.
                var hi = 0;
                var lo = 0u;
                for (var k = 0u; k < chain; k++) {
                    let g = desc[tb + 2u + k];
                    let s = bilinear(g, footprint(g, x, y, mw, mh), c);
                    hi += s >> 16u;
                    lo += bitcast<u32>(s) & 0xFFFFu;
                }
                act_a[n] = sat16(hi + i32((lo + 32768u) >> 16u));
                n++;
            }
        }
    }
    for (var k = 0u; k < desc[6]; k++) {
        act_a[n] = triangle(x, k, 0u, f_in);
        act_a[n + 1u] = triangle(x, k, 1u, f_in);
        act_a[n + 2u] = triangle(y, k, 0u, f_in);
        act_a[n + 3u] = triangle(y, k, 1u, f_in);
        n += 4u;
    }
    if (desc[7] == 1u) {
        act_a[n] = i32(mip << (f_in - 4u));
        n++;
    }
}

fn decode(xi: i32, yi: i32, mip_in: u32) {
    features(xi, yi, mip_in);
    let layer_count = desc[8];
    var out_frac = 1u;
    for (var l = 0u; l < layer_count; l++) {
        let lb2 = desc[13] + 8u * l;
        let inputs = desc[lb2];
        let outputs = desc[lb2 + 1u];
        out_frac = desc[lb2 + 2u];
        let gelu = desc[lb2 + 3u] == 1u;
        let wa = desc[lb2 + 4u];
        let ra = desc[lb2 + 5u];
        let last = l + 1u == layer_count;
        for (var o = 0u; o < outputs; o++) {
            if (last && (o >= 16u || (params.channel_mask & (1u << o)) == 0u)) {
                act_b[o] = 0;
                continue;
            }
            var acc = weight(ra + 3u * o);
            for (var i = 0u; i < inputs; i++) {
                acc += weight(wa + o * inputs + i) * act_a[i];
            }
            var v = requantize(acc, desc[ra + 3u * o + 1u], desc[ra + 3u * o + 2u]);
            if (gelu) {
                v = hard_gelu(v, out_frac);
            }
            act_b[o] = v;
        }
        for (var o = 0u; o < outputs; o++) {
            act_a[o] = act_b[o];
        }
    }
    for (var c = 0u; c < desc[3]; c++) {
        if ((params.channel_mask & (1u << c)) != 0u) {
            codes[c] = u32(clamp((act_a[c] * 255 + (1 << (out_frac - 1u))) >> out_frac, 0, 255));
        }
    }
}

// One workgroup's codes, one per u32, in output order (texel, then channel), before packing.
var<workgroup> staged: array<u32, 1024>;

// Decodes `params.count` texels (requests from word `params.in_offset` of `requests`, or a
// rectangle), 64 per workgroup, and writes their codes packed four per u32 (code i in byte
// i % 4 of word i / 4, so the buffer's bytes are the codes in order) from word
// `params.out_offset` of `out_codes`. A workgroup's codes start on a word boundary (64 texels
// hold a multiple of 4 codes); the last word of the last workgroup is padded with zeros.
@compute @workgroup_size(64)
fn main(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let group = wg.x + wg.y * groups.x;
    let index = group * 64u + lid;
    let n = params.out_channels;
    if (index < params.count) {
        if (params.mode == 0u) {
            let r = params.in_offset + 3u * index;
            decode(requests[r], requests[r + 1u], bitcast<u32>(requests[r + 2u]));
        } else {
            let x = params.x0 + index % params.width;
            let y = params.y0 + index / params.width;
            decode(i32(x), i32(y), params.mip);
        }
        var slot = lid * n;
        for (var c = 0u; c < desc[3]; c++) {
            if ((params.channel_mask & (1u << c)) != 0u) {
                staged[slot] = codes[c];
                slot++;
            }
        }
    }
    workgroupBarrier();
    let first = group * 64u;
    let texels = select(0u, min(params.count - first, 64u), first < params.count);
    let count = texels * n;
    for (var w = lid; 4u * w < count; w += 64u) {
        var word = 0u;
        for (var k = 0u; k < 4u; k++) {
            if (4u * w + k < count) {
                word |= staged[4u * w + k] << (8u * k);
            }
        }
        out_codes[params.out_offset + first / 4u * n + w] = word;
    }
}

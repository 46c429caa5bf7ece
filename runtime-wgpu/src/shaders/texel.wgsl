// The integer decoder of docs/FORMAT.md §6 in WGSL, bit-exact with nmat-core's `decode_texel_u8`:
// `nmat_decode` decodes one texel. Only 32-bit integer arithmetic (WGSL has no i64): the 64-bit
// requantization product, the footprint numerator and the fusion-chain sum are computed in
// pieces, exactly. Every module-scope name starts with `nmat_`, `Nmat` or `NMAT_`: this file is
// also part of the module engines include in their own shaders (sample.wgsl); whoever includes
// it declares the two material bindings, `nmat_desc` and `nmat_latents`.
//
// `nmat_desc` (written by `network_words` in upload.rs) is read through the constants that
// nmat-wgpu's layout.rs generates and prepends to this file, one per field of its records:
// NMAT_DESC_* (the header: sizes, network, where the records start, the level of each mip),
// NMAT_RANGE_*, NMAT_GRID_* and NMAT_QUANT_* (grids and their dequantization), NMAT_LEVEL_* and
// NMAT_TERM_* (how a level's features are made), NMAT_LAYER_* and NMAT_ROW_* (layers, their i32
// weights and per-row constants), NMAT_REQUANT_* (the tiled and matrix kernels' row tables), and
// *_WORDS for each record's size.
//
// `nmat_decode` takes a texel's features from `nmat_texel_features` and its codes from
// `nmat_texel_network`, which the includer appends (features.rs, unrolled.rs): `nmat_features`
// and `nmat_layers` below for any material, or code generated for one material's latent layout
// and network, which gives the same features and codes.

fn nmat_weight(i: u32) -> i32 {
    return bitcast<i32>(nmat_desc[i]);
}

// Index i of an axis of `size` cells, wrapped or clamped (§6.2). A GPU divides in many
// instructions, so the wrap takes one add or subtract over [−size, 2 · size), which holds every
// cell a footprint reads (nmat_footprint: −1 … size) and the texels of a region; the remainder
// only further out (sizes are at most 16 384, so 2 · size is an i32), of unsigned operands
// (nmat_wrap).
fn nmat_address(i: i32, size: u32, clamp_mode: bool) -> u32 {
    let s = i32(max(size, 1u));
    if (clamp_mode) {
        return u32(clamp(i, 0, s - 1));
    }
    if (i >= -s && i < 2 * s) {
        return u32(select(select(i, i - s, i >= s), i + s, i < 0));
    }
    return nmat_wrap(i, u32(s));
}

// i modulo s (in [0, s), s ≥ 1) with a remainder of unsigned integers only: GLSL leaves `%` of
// a negative operand undefined and naga writes WGSL's `%` into it unchanged, so on wgpu's
// OpenGL backend a signed remainder differs from WGSL's (docs/GPU.md, "Known problems"). For
// i < 0 it is s − 1 − (−(i + 1)) mod s, and −(i + 1) is an i32 for every i.
fn nmat_wrap(i: i32, s: u32) -> u32 {
    if (i < 0) {
        return s - 1u - u32(-(i + 1)) % s;
    }
    return u32(i) % s;
}

// floor(x / 2^k) position of a texel centre on a grid, in 1/256 cell (§6.2), without 64 bits:
// floor(q·128 / m) with q = (2x+1)·g < 2^29 is 128·(q / m) + (128·(q % m)) / m; for x in the
// mip, −128 … 256 · g − 129 (so a footprint's cells lie in −1 … g). Where the mip's side m is a
// power of two (most textures' mips) the same quotients are shifts.
fn nmat_grid_pos(x: u32, mip_size: u32, grid_size: u32) -> i32 {
    let q = (2u * x + 1u) * grid_size;
    let m = max(mip_size, 1u);
    var p = u32();
    if ((m & (m - 1u)) == 0u) {
        let k = countTrailingZeros(m);
        p = 128u * (q >> k) + ((128u * (q & (m - 1u))) >> k);
    } else {
        p = 128u * (q / m) + (128u * (q % m)) / m;
    }
    return i32(p) - 128;
}

// One latent grid's record, read once for all the codes a texel takes from it (`NmatGrid` and
// `nmat_grid_record` are generated from layout.rs's `GridRecord`).
fn nmat_grid(g: u32) -> NmatGrid {
    return nmat_grid_record(nmat_desc[NMAT_DESC_GRIDS_AT] + NMAT_GRID_WORDS * g);
}

fn nmat_grid_code(r: NmatGrid, x: u32, y: u32, c: u32) -> u32 {
    let bit = ((y * r.width + x) * r.channels + c) * r.bits;
    let word = bit / 32u;
    let shift = bit % 32u;
    var v = nmat_latents[r.latents_at + word] >> shift;
    if (shift + r.bits > 32u && word + 1u < r.latent_words) {
        v = v | (nmat_latents[r.latents_at + word + 1u] << (32u - shift));
    }
    return v & ((1u << r.bits) - 1u);
}

// Channel c's dequantization, offset + code · step (§4): (offset, step).
fn nmat_grid_quant(r: NmatGrid, c: u32) -> vec2<i32> {
    let qa = r.quant_at + NMAT_QUANT_WORDS * c;
    return vec2<i32>(bitcast<i32>(nmat_desc[qa + NMAT_QUANT_OFFSET]), bitcast<i32>(nmat_desc[qa + NMAT_QUANT_STEP]));
}

fn nmat_grid_value(r: NmatGrid, q: vec2<i32>, x: u32, y: u32, c: u32) -> i32 {
    return q.x + i32(nmat_grid_code(r, x, y, c)) * q.y;
}

struct NmatFootprint {
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
    fx: i32,
    fy: i32,
}

fn nmat_footprint(r: NmatGrid, x: u32, y: u32, mw: u32, mh: u32, clamp_mode: bool) -> NmatFootprint {
    let px = nmat_grid_pos(x, mw, r.width);
    let py = nmat_grid_pos(y, mh, r.height);
    let ix = px >> 8u;
    let iy = py >> 8u;
    var f = NmatFootprint();
    f.x0 = nmat_address(ix, r.width, clamp_mode);
    f.x1 = nmat_address(ix + 1, r.width, clamp_mode);
    f.y0 = nmat_address(iy, r.height, clamp_mode);
    f.y1 = nmat_address(iy + 1, r.height, clamp_mode);
    f.fx = px & 255;
    f.fy = py & 255;
    return f;
}

// Σ w·v of one grid's 4 cells, channel c: within [−2^31, 2^31) (§6.3), so an i32 holds it.
fn nmat_bilinear(r: NmatGrid, f: NmatFootprint, c: u32) -> i32 {
    let q = nmat_grid_quant(r, c);
    let w = nmat_bilinear_weights(f);
    return w.x * nmat_grid_value(r, q, f.x0, f.y0, c) + w.y * nmat_grid_value(r, q, f.x1, f.y0, c)
        + w.z * nmat_grid_value(r, q, f.x0, f.y1, c) + w.w * nmat_grid_value(r, q, f.x1, f.y1, c);
}

// A footprint's four bilinear weights (in 1/65 536) in cell order: (x0, y0), (x1, y0), (x0, y1),
// (x1, y1).
fn nmat_bilinear_weights(f: NmatFootprint) -> vec4<i32> {
    let gx = 256 - f.fx;
    let gy = 256 - f.fy;
    return vec4<i32>(gx * gy, f.fx * gy, gx * f.fy, f.fx * f.fy);
}

// A sum of Σ w·v terms kept as (Σ (s >> 16), Σ (s & 0xFFFF)), rounded half up to the input grid
// and saturated (§6.3): hi + (lo + 2^15) >> 16, where s + 2^15 itself could overflow an i32.
fn nmat_round_split(hi: i32, lo: u32) -> i32 {
    return nmat_sat16(hi + i32((lo + 32768u) >> 16u));
}

fn nmat_triangle(t: u32, k: u32, phase: u32, frac_bits: u32) -> i32 {
    let period = 1u << (k + 2u);
    let a = (2u * t + 1u + phase * (period / 2u)) % (2u * period);
    let mag = select(2u * period - 2u * a, 2u * a - 2u * period, 2u * a >= 2u * period);
    return i32(mag << (frac_bits - k - 3u));
}

fn nmat_sat16(v: i32) -> i32 {
    return clamp(v, -32768, 32767);
}

// 32×32 → 64-bit unsigned product as (hi, lo).
fn nmat_umul64(a: u32, b: u32) -> vec2<u32> {
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
fn nmat_requantize(acc: i32, mult: u32, shift: u32) -> i32 {
    let negative = acc < 0;
    let magnitude = select(u32(acc), u32(0) - bitcast<u32>(acc), negative);
    var p = nmat_umul64(magnitude, mult);
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
    var hi = i32();
    var lo = u32();
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

// floor(n / d), d ≠ 0: the quotient truncated toward zero, one less where it was rounded up (n
// not a multiple of d, operands of opposite signs). No `%` (see nmat_wrap); q · d cannot
// overflow, its magnitude being at most |n|.
fn nmat_floor_div(n: i32, d: i32) -> i32 {
    let q = n / d;
    return select(q, q - 1, q * d != n && (n < 0) != (d < 0));
}

fn nmat_hard_gelu(z: i32, f: u32) -> i32 {
    let t = 3 << (f - 1u);
    if (z >= t) {
        return z;
    }
    if (z <= -t) {
        return 0;
    }
    return nmat_floor_div(z * (z + t) + t, 3 << f);
}

var<private> nmat_act_a: array<i32, 128>;
var<private> nmat_act_b: array<i32, 128>;
// The codes `nmat_decode` wrote, by channel (channels outside its mask are not written).
var<private> nmat_codes: array<u32, 16>;

// The input features of texel (xi, yi) of `mip_in` (addressed and clamped to the chain as on
// the CPU) in nmat_act_a[0..input width): latents, positional encoding, LOD (§6.2–6.4).
fn nmat_features(xi: i32, yi: i32, mip_in: u32) {
    let mip = min(mip_in, nmat_desc[NMAT_DESC_MIP_COUNT] - 1u);
    let mw = max(nmat_desc[NMAT_DESC_WIDTH] >> mip, 1u);
    let mh = max(nmat_desc[NMAT_DESC_HEIGHT] >> mip, 1u);
    let clamp_mode = nmat_desc[NMAT_DESC_ADDRESS_MODE] == 1u;
    let x = nmat_address(xi, mw, clamp_mode);
    let y = nmat_address(yi, mh, clamp_mode);
    let f_in = nmat_desc[NMAT_DESC_INPUT_FRAC_BITS];
    let level = nmat_desc[NMAT_DESC_LEVEL_OF_MIP + mip];
    let lb = nmat_desc[NMAT_DESC_LEVELS_AT] + level * NMAT_LEVEL_WORDS;
    var n = 0u;
    let terms = nmat_desc[lb + NMAT_LEVEL_TERM_COUNT];
    // Each grid's record and footprint are read and computed once, and each channel's
    // dequantization once per grid (not once per code).
    for (var t = 0u; t < terms; t++) {
        let tb = lb + NMAT_LEVEL_TERMS + t * NMAT_TERM_WORDS;
        let chain = nmat_desc[tb + NMAT_TERM_CHAIN_LEN];
        let r0 = nmat_grid(nmat_desc[tb + NMAT_TERM_GRIDS]);
        let channels = r0.channels;
        if (nmat_desc[tb + NMAT_TERM_BILINEAR] == 0u) {
            // The 4 cells' codes in cell order, channels within a cell: feature k·channels + c.
            let f = nmat_footprint(r0, x, y, mw, mh, clamp_mode);
            for (var c = 0u; c < channels; c++) {
                let q = nmat_grid_quant(r0, c);
                nmat_act_a[n + c] = nmat_grid_value(r0, q, f.x0, f.y0, c);
                nmat_act_a[n + channels + c] = nmat_grid_value(r0, q, f.x1, f.y0, c);
                nmat_act_a[n + 2u * channels + c] = nmat_grid_value(r0, q, f.x0, f.y1, c);
                nmat_act_a[n + 3u * channels + c] = nmat_grid_value(r0, q, f.x1, f.y1, c);
            }
            n += 4u * channels;
        } else if (chain == 1u) {
            let f = nmat_footprint(r0, x, y, mw, mh, clamp_mode);
            for (var c = 0u; c < channels; c++) {
                let s = nmat_bilinear(r0, f, c);
                nmat_act_a[n + c] = nmat_round_split(s >> 16u, bitcast<u32>(s) & 0xFFFFu);
            }
            n += channels;
        } else {
            // Σ over the chain of (s >> 16) and (s & 0xFFFF) kept apart, per channel in
            // nmat_act_a and nmat_act_b (free until the first layer): the exact sum rounded half
            // up is hi + (lo + 2^15) >> 16, and no part overflows.
            for (var c = 0u; c < channels; c++) {
                nmat_act_a[n + c] = 0;
                nmat_act_b[n + c] = 0;
            }
            for (var k = 0u; k < chain; k++) {
                let r = nmat_grid(nmat_desc[tb + NMAT_TERM_GRIDS + k]);
                let f = nmat_footprint(r, x, y, mw, mh, clamp_mode);
                for (var c = 0u; c < channels; c++) {
                    let s = nmat_bilinear(r, f, c);
                    nmat_act_a[n + c] += s >> 16u;
                    nmat_act_b[n + c] += bitcast<i32>(bitcast<u32>(s) & 0xFFFFu);
                }
            }
            for (var c = 0u; c < channels; c++) {
                nmat_act_a[n + c] = nmat_round_split(nmat_act_a[n + c], bitcast<u32>(nmat_act_b[n + c]));
            }
            n += channels;
        }
    }
    for (var k = 0u; k < nmat_desc[NMAT_DESC_PE_FREQUENCIES]; k++) {
        nmat_act_a[n] = nmat_triangle(x, k, 0u, f_in);
        nmat_act_a[n + 1u] = nmat_triangle(x, k, 1u, f_in);
        nmat_act_a[n + 2u] = nmat_triangle(y, k, 0u, f_in);
        nmat_act_a[n + 3u] = nmat_triangle(y, k, 1u, f_in);
        n += 4u;
    }
    // The LOD feature, mip · 2^(code − 5) (code 1: mip / 16); f_in ≥ 4 and code ≥ 1.
    let lod_code = nmat_desc[NMAT_DESC_LOD_INPUT];
    if (lod_code != 0u) {
        nmat_act_a[n] = i32(mip << (f_in + lod_code - 5u));
        n++;
    }
}

// Decodes texel (xi, yi) of `mip_in` into nmat_codes, the channels in `mask` (bit c: channel c):
// its input features (`nmat_texel_features`), then the network (`nmat_texel_network`), each
// defined by the source that includes this file — the generic `nmat_features` and
// `nmat_layers`, or code generated for the material (features.rs, unrolled.rs).
fn nmat_decode(xi: i32, yi: i32, mip_in: u32, mask: u32) {
    nmat_texel_features(xi, yi, mip_in);
    nmat_texel_network(mask);
}

// The network on the input features in nmat_act_a, the codes of the channels in `mask` into
// nmat_codes, every width, weight and row constant read through the descriptor (any material).
fn nmat_layers(mask: u32) {
    let layer_count = nmat_desc[NMAT_DESC_LAYER_COUNT];
    var out_frac = 1u;
    for (var l = 0u; l < layer_count; l++) {
        let lb2 = nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_WORDS * l;
        let inputs = nmat_desc[lb2 + NMAT_LAYER_INPUTS];
        let outputs = nmat_desc[lb2 + NMAT_LAYER_OUTPUTS];
        out_frac = nmat_desc[lb2 + NMAT_LAYER_OUT_FRAC_BITS];
        let gelu = nmat_desc[lb2 + NMAT_LAYER_HARD_GELU] == 1u;
        let wa = nmat_desc[lb2 + NMAT_LAYER_WEIGHTS_AT];
        let ra = nmat_desc[lb2 + NMAT_LAYER_ROWS_AT];
        let last = l + 1u == layer_count;
        for (var o = 0u; o < outputs; o++) {
            if (last && (o >= 16u || (mask & (1u << o)) == 0u)) {
                nmat_act_b[o] = 0;
                continue;
            }
            let rc = ra + NMAT_ROW_WORDS * o;
            var acc = nmat_weight(rc + NMAT_ROW_BIAS);
            // Four inputs per iteration (i32 sums wrap, so the order does not change them):
            // lavapipe caps the loop iterations of a shader invocation, all loops together, at
            // 65 535 (docs/GPU.md, "Known problems"); this keeps a decode far below it.
            let row = wa + o * inputs;
            var i = 0u;
            for (; i + 4u <= inputs; i += 4u) {
                acc += nmat_weight(row + i) * nmat_act_a[i]
                    + nmat_weight(row + i + 1u) * nmat_act_a[i + 1u]
                    + nmat_weight(row + i + 2u) * nmat_act_a[i + 2u]
                    + nmat_weight(row + i + 3u) * nmat_act_a[i + 3u];
            }
            for (; i < inputs; i++) {
                acc += nmat_weight(row + i) * nmat_act_a[i];
            }
            var v = nmat_requantize(acc, nmat_desc[rc + NMAT_ROW_MULTIPLIER], nmat_desc[rc + NMAT_ROW_SHIFT]);
            if (gelu) {
                v = nmat_hard_gelu(v, out_frac);
            }
            nmat_act_b[o] = v;
        }
        for (var o = 0u; o < outputs; o++) {
            nmat_act_a[o] = nmat_act_b[o];
        }
    }
    for (var c = 0u; c < nmat_desc[NMAT_DESC_CHANNEL_COUNT]; c++) {
        if ((mask & (1u << c)) != 0u) {
            nmat_codes[c] = u32(clamp((nmat_act_a[c] * 255 + (1 << (out_frac - 1u))) >> out_frac, 0, 255));
        }
    }
}


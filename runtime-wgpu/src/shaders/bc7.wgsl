// The BC7 block encoder, byte-identical with nmat-core's `bc::encode_bc7`
// (core-nostd/src/bc/bc7.rs): modes 6, 1, 3, 2, 0, 5 and 4 for opaque blocks, 6 and 5 for blocks
// with alpha; the same partitions ranked the same way, the same endpoint fits (principal axis,
// every p-bit choice, least squares twice), the same palettes, rules on ties and packing.
// Integer arithmetic only; the least-squares step's 41-bit numerators and 33-bit divisors are
// computed exactly in 32-bit pieces. It follows bc.wgsl (its `px`, `counts` and 64-bit helpers)
// and has entry points of its own, so the pipelines of the other formats do not carry it:
// `encode_codes_bc7` and `encode_pixels_bc7`, as bc.wgsl's `encode_codes` and `encode_pixels`
// with params.format = 7 (RGB) or 8 (RGBA).

// Two-subset partitions (bit i: pixel i in subset 1), three-subset ones (bits 2i, 2i + 1), and
// the anchors of subset 1 (two subsets) and of subsets 1 and 2 (three): the format's tables P2,
// P3, A2, A3a and A3b.
const BC7_P2 = array<u32, 64>(
    0xCCCCu, 0x8888u, 0xEEEEu, 0xECC8u, 0xC880u, 0xFEECu, 0xFEC8u, 0xEC80u,
    0xC800u, 0xFFECu, 0xFE80u, 0xE800u, 0xFFE8u, 0xFF00u, 0xFFF0u, 0xF000u,
    0xF710u, 0x008Eu, 0x7100u, 0x08CEu, 0x008Cu, 0x7310u, 0x3100u, 0x8CCEu,
    0x088Cu, 0x3110u, 0x6666u, 0x366Cu, 0x17E8u, 0x0FF0u, 0x718Eu, 0x399Cu,
    0xAAAAu, 0xF0F0u, 0x5A5Au, 0x33CCu, 0x3C3Cu, 0x55AAu, 0x9696u, 0xA55Au,
    0x73CEu, 0x13C8u, 0x324Cu, 0x3BDCu, 0x6996u, 0xC33Cu, 0x9966u, 0x0660u,
    0x0272u, 0x04E4u, 0x4E40u, 0x2720u, 0xC936u, 0x936Cu, 0x39C6u, 0x639Cu,
    0x9336u, 0x9CC6u, 0x817Eu, 0xE718u, 0xCCF0u, 0x0FCCu, 0x7744u, 0xEE22u,
);
const BC7_P3 = array<u32, 64>(
    0xAA685050u, 0x6A5A5040u, 0x5A5A4200u, 0x5450A0A8u, 0xA5A50000u, 0xA0A05050u,
    0x5555A0A0u, 0x5A5A5050u, 0xAA550000u, 0xAA555500u, 0xAAAA5500u, 0x90909090u,
    0x94949494u, 0xA4A4A4A4u, 0xA9A59450u, 0x2A0A4250u, 0xA5945040u, 0x0A425054u,
    0xA5A5A500u, 0x55A0A0A0u, 0xA8A85454u, 0x6A6A4040u, 0xA4A45000u, 0x1A1A0500u,
    0x0050A4A4u, 0xAAA59090u, 0x14696914u, 0x69691400u, 0xA08585A0u, 0xAA821414u,
    0x50A4A450u, 0x6A5A0200u, 0xA9A58000u, 0x5090A0A8u, 0xA8A09050u, 0x24242424u,
    0x00AA5500u, 0x24924924u, 0x24499224u, 0x50A50A50u, 0x500AA550u, 0xAAAA4444u,
    0x66660000u, 0xA5A0A5A0u, 0x50A050A0u, 0x69286928u, 0x44AAAA44u, 0x66666600u,
    0xAA444444u, 0x54A854A8u, 0x95809580u, 0x96969600u, 0xA85454A8u, 0x80959580u,
    0xAA141414u, 0x96960000u, 0xAAAA1414u, 0xA05050A0u, 0xA0A5A5A0u, 0x96000000u,
    0x40804080u, 0xA9A8A9A8u, 0xAAAAAA44u, 0x2A4A5254u,
);
const BC7_A2 = array<u32, 64>(
    15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u,
    15u, 2u, 8u, 2u, 2u, 8u, 8u, 15u, 2u, 8u, 2u, 2u, 8u, 8u, 2u, 2u,
    15u, 15u, 6u, 8u, 2u, 8u, 15u, 15u, 2u, 8u, 2u, 2u, 2u, 15u, 15u, 6u,
    6u, 2u, 6u, 8u, 15u, 15u, 2u, 2u, 15u, 15u, 15u, 15u, 15u, 2u, 2u, 15u,
);
const BC7_A3A = array<u32, 64>(
    3u, 3u, 15u, 15u, 8u, 3u, 15u, 15u, 8u, 8u, 6u, 6u, 6u, 5u, 3u, 3u,
    3u, 3u, 8u, 15u, 3u, 3u, 6u, 10u, 5u, 8u, 8u, 6u, 8u, 5u, 15u, 15u,
    8u, 15u, 3u, 5u, 6u, 10u, 8u, 15u, 15u, 3u, 15u, 5u, 15u, 15u, 15u, 15u,
    3u, 15u, 5u, 5u, 5u, 8u, 5u, 10u, 5u, 10u, 8u, 13u, 15u, 12u, 3u, 3u,
);
const BC7_A3B = array<u32, 64>(
    15u, 8u, 8u, 3u, 15u, 15u, 3u, 8u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 8u,
    15u, 8u, 15u, 3u, 15u, 8u, 15u, 8u, 3u, 15u, 6u, 10u, 15u, 15u, 10u, 8u,
    15u, 3u, 15u, 10u, 10u, 8u, 9u, 10u, 6u, 15u, 8u, 15u, 3u, 6u, 6u, 8u,
    15u, 3u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 15u, 3u, 15u, 15u, 8u,
);
// Interpolation weights (out of 64) of 2-, 3- and 4-bit indices, one after the other.
const BC7_W = array<u32, 28>(
    0u, 21u, 43u, 64u,
    0u, 9u, 18u, 27u, 37u, 46u, 55u, 64u,
    0u, 4u, 9u, 13u, 17u, 21u, 26u, 30u, 34u, 38u, 43u, 47u, 51u, 55u, 60u, 64u,
);

fn bc7_weight(bits: u32, k: u32) -> u32 {
    let first = select(select(12u, 4u, bits == 3u), 0u, bits == 2u);
    return BC7_W[first + min(k, (1u << bits) - 1u)];
}

fn bc7_subset(subsets: u32, part: u32, i: u32) -> u32 {
    if (subsets == 2u) {
        return (BC7_P2[part] >> i) & 1u;
    }
    if (subsets == 3u) {
        return (BC7_P3[part] >> (2u * i)) & 3u;
    }
    return 0u;
}

// The anchor pixel of subset `s` (16: none).
fn bc7_anchor(subsets: u32, part: u32, s: u32) -> u32 {
    if (s == 0u) {
        return 0u;
    }
    if (subsets == 2u && s == 1u) {
        return BC7_A2[part];
    }
    if (subsets == 3u) {
        return select(BC7_A3B[part], BC7_A3A[part], s == 1u);
    }
    return 16u;
}

fn bc7_expand(v: u32, bits: u32) -> u32 {
    if (bits >= 8u) {
        return v;
    }
    return (v << (8u - bits)) | (v >> select(0u, 2u * bits - 8u, 2u * bits > 8u));
}

// ---- how a fit stores its endpoints ----

// P-bit choices: none, one per endpoint (4 choices), shared (2), or mode 6's opaque [1, 1].
const PBITS_NONE = 0u;
const PBITS_ENDPOINT = 1u;
const PBITS_SHARED = 2u;
const PBITS_OPAQUE = 3u;

fn bc7_pbit_choices(kind: u32) -> u32 {
    return select(select(1u, 2u, kind == PBITS_SHARED), 4u, kind == PBITS_ENDPOINT);
}

// The p-bits (p0, p1) of choice `k`: [0,0], [0,1], [1,0], [1,1] one per endpoint; [0,0], [1,1]
// shared; [1,1] opaque; [0,0] without.
fn bc7_pbit_choice(kind: u32, k: u32) -> vec2<u32> {
    if (kind == PBITS_ENDPOINT) {
        return vec2<u32>(k >> 1u, k & 1u);
    }
    if (kind == PBITS_SHARED) {
        return vec2<u32>(k, k);
    }
    return vec2<u32>(select(0u, 1u, kind == PBITS_OPAQUE));
}

// The 8-bit value of stored component q with p-bit p, `bits` bits before the p-bit.
fn bc7_value(bits: u32, kind: u32, q: u32, p: u32) -> u32 {
    let pbit = select(1u, 0u, kind == PBITS_NONE);
    return bc7_expand((q << pbit) | (p & pbit), bits + pbit);
}

// The stored value whose expansion is nearest `target`.
fn bc7_quantize(bits: u32, kind: u32, goal: i32, p: u32) -> u32 {
    let pbit = select(1u, 0u, kind == PBITS_NONE);
    let total = bits + pbit;
    let most = (1u << bits) - 1u;
    let t = u32(clamp(goal, 0, 255));
    let guess = ((t * ((1u << total) - 1u) + 127u) / 255u) >> pbit;
    var best = min(guess, most);
    let lower = select(0u, guess - 1u, guess > 0u);
    for (var k = 0u; k < 2u; k++) {
        let q = min(select(guess + 1u, lower, k == 0u), most);
        let dq = abs(i32(bc7_value(bits, kind, q, p)) - i32(t));
        let db = abs(i32(bc7_value(bits, kind, best, p)) - i32(t));
        if (dq < db) {
            best = q;
        }
    }
    return best;
}

// ---- fitting the pixels of one subset ----

// The fit being made: the pixels (`fit_mask`), their components first..first + dims of each
// pixel, how the endpoints are stored.
var<private> fit_mask: u32;
var<private> fit_first: u32;
var<private> fit_dims: u32;
var<private> fit_bits: u32;
var<private> fit_kind: u32;
var<private> fit_index_bits: u32;

struct Fit {
    ends: array<vec4<u32>, 2>,
    pbits: vec2<u32>,
    index: array<u32, 16>,
    error: u32,
}

// The member's fitted components (0 past dims). Without loops, here and in the other functions
// a fit calls per pixel: lavapipe, the CI's Vulkan driver, stops a shader's loops once a batch of
// invocations has run 65 535 iterations together (docs/GPU.md, "Known problems"), and a block's
// search runs some 35 fits.
fn bc7_point(i: u32) -> vec4<i32> {
    let p = px[i] >> (8u * fit_first);
    let all = vec4<i32>(vec4<u32>(p, p >> 8u, p >> 16u, p >> 24u) & vec4<u32>(255u));
    return select(vec4<i32>(0), all, vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(fit_dims));
}

// The members at both ends of the principal axis of the fitted components, as 8-bit targets
// (`Subset::axis_ends` and the core's `principal_ends`): the first member twice when they do not
// spread. The first member wins a tie at the low end, the last at the high end.
fn bc7_axis_ends() -> array<vec4<i32>, 2> {
    var n = 0;
    var sum = vec4<i32>(0);
    var first = 16u;
    for (var i = 0u; i < 16u; i++) {
        if (counts(fit_mask, i)) {
            n++;
            sum += bc7_point(i);
            first = min(first, i);
        }
    }
    var ends = array<vec4<i32>, 2>(bc7_point(first), bc7_point(first));
    // |deviation| ≤ 15·255 and |covariance| ≤ 16 · (15·255)² < 2^28: both fit an i32.
    var cov = array<vec4<i32>, 4>();
    for (var i = 0u; i < 16u; i++) {
        if (counts(fit_mask, i)) {
            let d = n * bc7_point(i) - sum;
            cov[0] += d.x * d;
            cov[1] += d.y * d;
            cov[2] += d.z * d;
            cov[3] += d.w * d;
        }
    }
    var widest = 0u;
    for (var c = 1u; c < fit_dims; c++) {
        if (cov[c][c] >= cov[widest][widest]) {
            widest = c;
        }
    }
    var v = array<vec2<u32>, 4>();
    for (var c = 0u; c < 4u; c++) {
        v[c] = wide(cov[widest][c]);
    }
    var s = vec4<i32>(0);
    for (var iteration = 0u; iteration <= 8u; iteration++) {
        // s = v scaled down below 2^16.
        let scale = max(max(bit_length64(v[0]), bit_length64(v[1])),
            max(bit_length64(v[2]), bit_length64(v[3])));
        if (scale == 0u) {
            return ends;
        }
        let shift = select(0u, scale - 16u, scale > 16u);
        s = vec4<i32>(shr64(v[0], shift), shr64(v[1], shift), shr64(v[2], shift), shr64(v[3], shift));
        if (iteration == 8u) {
            break;
        }
        for (var r = 0u; r < 4u; r++) {
            v[r] = add64(add64(imul64(cov[r].x, s.x), imul64(cov[r].y, s.y)),
                add64(imul64(cov[r].z, s.z), imul64(cov[r].w, s.w)));
        }
    }
    // |projection| ≤ 4 · 15·255 · 2^16 < 2^31.
    var lo_p = 0;
    var hi_p = 0;
    var seen = false;
    for (var i = 0u; i < 16u; i++) {
        if (!counts(fit_mask, i)) {
            continue;
        }
        let d = n * bc7_point(i) - sum;
        let p = dot(d, s);
        if (!seen || p < lo_p) {
            lo_p = p;
            ends[0] = bc7_point(i);
        }
        if (!seen || p >= hi_p) {
            hi_p = p;
            ends[1] = bc7_point(i);
        }
        seen = true;
    }
    return ends;
}

// The nearest palette entry of every member (the lowest index on a tie) and the squared error,
// for stored endpoints `ends` with p-bits `pbits` (`Subset::assign`).
fn bc7_assign(ends: array<vec4<u32>, 2>, pbits: vec2<u32>) -> Fit {
    var fit = Fit();
    fit.ends = ends;
    fit.pbits = pbits;
    fit.error = 0u;
    var e0 = vec4<i32>(0);
    var e1 = vec4<i32>(0);
    for (var c = 0u; c < fit_dims; c++) {
        e0[c] = i32(bc7_value(fit_bits, fit_kind, ends[0][c], pbits.x));
        e1[c] = i32(bc7_value(fit_bits, fit_kind, ends[1][c], pbits.y));
    }
    let entries = 1u << fit_index_bits;
    var palette = array<vec4<i32>, 16>();
    for (var k = 0u; k < entries; k++) {
        // Each component interpolated as the format defines it (weights out of 64, rounded).
        let w = i32(bc7_weight(fit_index_bits, k));
        palette[k] = ((64 - w) * e0 + w * e1 + vec4<i32>(32)) >> vec4<u32>(6u);
    }
    let d = e1 - e0;
    let dd = dot(d, d);
    for (var i = 0u; i < 16u; i++) {
        fit.index[i] = 0u;
        if (!counts(fit_mask, i)) {
            continue;
        }
        let p = bc7_point(i);
        // The entry nearest the pixel's projection on the endpoint line, then its neighbours.
        var guess = 0u;
        if (dd != 0) {
            let t = dot(p - e0, d);
            let wt = u32(clamp(nmat_floor_div(t * 64 + dd / 2, dd), 0, 64));
            // The first entry whose weight is at least wt: ⌈wt · (entries − 1) / 64⌉, one step
            // down, then one up (exact for every wt of 0–64 and each weight table).
            var k = (wt * (entries - 1u) + 63u) / 64u;
            if (k > 0u && bc7_weight(fit_index_bits, k - 1u) >= wt) {
                k -= 1u;
            }
            if (bc7_weight(fit_index_bits, k) < wt) {
                k += 1u;
            }
            let below = select(0u, k - 1u, k > 0u);
            guess = select(k, below, wt - bc7_weight(fit_index_bits, below)
                <= bc7_weight(fit_index_bits, k) - wt);
        }
        let dg = p - palette[guess];
        var best_k = guess;
        var best_e = u32(dot(dg, dg));
        // The neighbours below, then above (the lower on a tie).
        if (guess > 0u) {
            let dk = p - palette[guess - 1u];
            let e = u32(dot(dk, dk));
            if (e <= best_e) {
                best_k = guess - 1u;
                best_e = e;
            }
        }
        if (guess + 1u < entries) {
            let dk = p - palette[guess + 1u];
            let e = u32(dot(dk, dk));
            if (e < best_e) {
                best_k = guess + 1u;
                best_e = e;
            }
        }
        fit.index[i] = best_k;
        fit.error += best_e;
    }
    return fit;
}

// ---- signed 64-bit arithmetic for the least-squares step ----

fn sub64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return add64(a, neg64(b));
}

fn shl64(v: vec2<u32>, shift: u32) -> vec2<u32> {
    return vec2<u32>((v.x << shift) | (v.y >> (32u - shift)), v.y << shift);
}

// a ≤ b for non-negative values.
fn le64(a: vec2<u32>, b: vec2<u32>) -> bool {
    return a.x < b.x || (a.x == b.x && a.y <= b.y);
}

// clamp(⌊num / den⌋, 0, 255) for den > 0 below 2^40 and |num| below 2^62.
fn bc7_solve(num: vec2<u32>, den: vec2<u32>) -> i32 {
    if (bitcast<i32>(num.x) < 0) {
        return 0;
    }
    var q = 0u;
    for (var bit = 7; bit >= 0; bit--) {
        let c = q | (1u << u32(bit));
        // c · den (c < 2^8, den < 2^40).
        let lo = nmat_umul64(den.y, c);
        let product = vec2<u32>(lo.x + den.x * c, lo.y);
        if (le64(product, num)) {
            q = c;
        }
    }
    return i32(q);
}

// Least-squares 8-bit endpoints for the weights of `fit`'s indices (`Subset::refine`); ok = false
// if every member has the same weight. Sums: aa, bb, ab ≤ 16 · 64² = 2^16, x and y
// ≤ 16 · 64 · 255, so their products need 64 bits.
struct Targets {
    ok: bool,
    ends: array<vec4<i32>, 2>,
}

fn bc7_refine(fit: Fit) -> Targets {
    var aa = 0;
    var bb = 0;
    var ab = 0;
    var x = vec4<i32>(0);
    var y = vec4<i32>(0);
    for (var i = 0u; i < 16u; i++) {
        if (!counts(fit_mask, i)) {
            continue;
        }
        let beta = i32(bc7_weight(fit_index_bits, fit.index[i]));
        let alpha = 64 - beta;
        aa += alpha * alpha;
        bb += beta * beta;
        ab += alpha * beta;
        let p = bc7_point(i);
        x += alpha * p;
        y += beta * p;
    }
    var r = Targets();
    let det = sub64(imul64(aa, bb), imul64(ab, ab));
    r.ok = det.x != 0u || det.y != 0u;
    if (!r.ok) {
        return r;
    }
    // ⌊(2 · 64 · (bb·x − ab·y) + det) / (2 · det)⌋, and the same with aa·y − ab·x.
    let den = shl64(det, 1u);
    for (var c = 0u; c < 4u; c++) {
        let n0 = shl64(sub64(imul64(bb, x[c]), imul64(ab, y[c])), 7u);
        let n1 = shl64(sub64(imul64(aa, y[c]), imul64(ab, x[c])), 7u);
        r.ends[0][c] = bc7_solve(add64(n0, det), den);
        r.ends[1][c] = bc7_solve(add64(n1, det), den);
    }
    return r;
}

// The best endpoints for the fit's pixels (`Subset::fit`): from the principal axis, every p-bit
// choice, then least squares twice.
fn bc7_fit() -> Fit {
    var best = Fit();
    best.error = 0u;
    best.pbits = vec2<u32>(0u);
    best.ends = array<vec4<u32>, 2>(vec4<u32>(0u), vec4<u32>(0u));
    for (var i = 0u; i < 16u; i++) {
        best.index[i] = 0u;
    }
    if (fit_mask == 0u) {
        return best;
    }
    var targets = bc7_axis_ends();
    var have = false;
    for (var round = 0u; round < 3u; round++) {
        for (var k = 0u; k < bc7_pbit_choices(fit_kind); k++) {
            let pbits = bc7_pbit_choice(fit_kind, k);
            var ends = array<vec4<u32>, 2>(vec4<u32>(0u), vec4<u32>(0u));
            for (var c = 0u; c < fit_dims; c++) {
                ends[0][c] = bc7_quantize(fit_bits, fit_kind, targets[0][c], pbits.x);
                ends[1][c] = bc7_quantize(fit_bits, fit_kind, targets[1][c], pbits.y);
            }
            let fit = bc7_assign(ends, pbits);
            if (!have || fit.error < best.error) {
                have = true;
                best = fit;
            }
        }
        if (round >= 2u || best.error == 0u) {
            break;
        }
        let next = bc7_refine(best);
        if (!next.ok) {
            break;
        }
        targets = next.ends;
    }
    return best;
}

fn bc7_set_fit(mask: u32, first: u32, dims: u32, bits: u32, kind: u32, index_bits: u32) {
    fit_mask = mask;
    fit_first = first;
    fit_dims = dims;
    fit_bits = bits;
    fit_kind = kind;
    fit_index_bits = index_bits;
}

// ---- whole blocks ----

struct Candidate {
    mode: u32,
    part: u32,
    // Modes 4 and 5: the colour channel (1–3) stored in the alpha slot; mode 4: 1 when colour
    // takes the 3-bit indices (`index2`).
    rotation: u32,
    selector: u32,
    // Stored endpoints per subset (RGBA; alpha as the mode stores it) and p-bits.
    ends: array<vec4<u32>, 6>,
    pbits: array<vec2<u32>, 3>,
    index: array<u32, 16>,
    index2: array<u32, 16>,
    error: u32,
}

fn bc7_empty(mode: u32, part: u32) -> Candidate {
    var c = Candidate();
    c.mode = mode;
    c.part = part;
    c.rotation = 0u;
    c.selector = 0u;
    for (var k = 0u; k < 6u; k++) {
        c.ends[k] = vec4<u32>(0u);
    }
    for (var s = 0u; s < 3u; s++) {
        c.pbits[s] = vec2<u32>(0u);
    }
    for (var i = 0u; i < 16u; i++) {
        c.index[i] = 0u;
        c.index2[i] = 0u;
    }
    c.error = 0u;
    return c;
}

// The 4 partitions of the 64 with the least squared error when each subset is its mean colour,
// best first (the lower partition on a tie), four per word; and in .y the same of the first 16
// (mode 0's), from the same pass (`rank_partitions`).
fn bc7_rank(valid: u32, subsets: u32) -> vec2<u32> {
    var cost = array<vec4<i32>, 2>(vec4<i32>(0x7FFFFFFF), vec4<i32>(0x7FFFFFFF));
    var order = array<vec4<u32>, 2>(vec4<u32>(0u), vec4<u32>(0u));
    for (var part = 0u; part < 64u; part++) {
        var n = vec3<i32>(0);
        var sum = array<vec3<i32>, 3>();
        var sq = vec3<i32>(0);
        for (var i = 0u; i < 16u; i++) {
            if (counts(valid, i)) {
                let s = bc7_subset(subsets, part, i);
                let p = rgb(px[i]);
                n[s] += 1;
                sum[s] += p;
                sq[s] += dot(p, p);
            }
        }
        var total = 0;
        for (var s = 0u; s < 3u; s++) {
            if (n[s] > 0) {
                let m = sum[s] * sum[s] / n[s];
                total += sq[s] - (m.x + m.y + m.z);
            }
        }
        for (var r = 0u; r < select(1u, 2u, part < 16u); r++) {
            for (var slot = 0u; slot < 4u; slot++) {
                if (total < cost[r][slot]) {
                    for (var j = 3u; j > slot; j--) {
                        cost[r][j] = cost[r][j - 1u];
                        order[r][j] = order[r][j - 1u];
                    }
                    cost[r][slot] = total;
                    order[r][slot] = part;
                    break;
                }
            }
        }
    }
    let all = order[0];
    let first16 = order[1];
    return vec2<u32>(all.x | (all.y << 8u) | (all.z << 16u) | (all.w << 24u),
        first16.x | (first16.y << 8u) | (first16.z << 16u) | (first16.w << 24u));
}

// ---- packing ----

var<private> bits7: vec4<u32>;
var<private> pos7: u32;

fn bc7_put(v: u32, bits: u32) {
    if (bits == 0u) {
        return;
    }
    let value = v & ((1u << bits) - 1u);
    let word = pos7 / 32u;
    let at = pos7 % 32u;
    bits7[word] |= value << at;
    if (at + bits > 32u) {
        bits7[word + 1u] |= value >> (32u - at);
    }
    pos7 += bits;
}

// The candidate's 16 bytes as 4 words (`Candidate::pack`, anchors fixed first).
fn bc7_pack(candidate: Candidate) -> vec4<u32> {
    var c = candidate;
    var subsets = 1u;
    var partition_bits = 0u;
    var rotation_bits = 0u;
    var colour_bits = 7u;
    var alpha_bits = 0u;
    var kind = PBITS_NONE;
    var index_bits = 2u;
    var index2_bits = 0u;
    switch (c.mode) {
        case 0u: { subsets = 3u; partition_bits = 4u; colour_bits = 4u; kind = PBITS_ENDPOINT; index_bits = 3u; }
        case 1u: { subsets = 2u; partition_bits = 6u; colour_bits = 6u; kind = PBITS_SHARED; index_bits = 3u; }
        case 2u: { subsets = 3u; partition_bits = 6u; colour_bits = 5u; }
        case 3u: { subsets = 2u; partition_bits = 6u; kind = PBITS_ENDPOINT; }
        case 4u: { rotation_bits = 2u; colour_bits = 5u; alpha_bits = 6u; index2_bits = 3u; }
        case 5u: { rotation_bits = 2u; alpha_bits = 8u; index2_bits = 2u; }
        default: { alpha_bits = 7u; kind = PBITS_ENDPOINT; index_bits = 4u; }
    }
    // An anchor's index is stored without its top bit: where it is set, swap the subset's
    // endpoints (of the components the indices interpolate: all, colour — or, with the selector
    // set, alpha — when alpha has indices of its own) and invert its indices.
    let top = 1u << (index_bits - 1u);
    let two = index2_bits > 0u;
    let first = select(0u, 3u, two && c.selector == 1u);
    let last = select(4u, 3u, two && c.selector == 0u);
    for (var s = 0u; s < subsets; s++) {
        if ((c.index[bc7_anchor(subsets, c.part, s)] & top) == 0u) {
            continue;
        }
        for (var i = 0u; i < 16u; i++) {
            if (bc7_subset(subsets, c.part, i) == s) {
                c.index[i] = 2u * top - 1u - c.index[i];
            }
        }
        for (var k = first; k < last; k++) {
            let a = c.ends[2u * s][k];
            c.ends[2u * s][k] = c.ends[2u * s + 1u][k];
            c.ends[2u * s + 1u][k] = a;
        }
        c.pbits[s] = c.pbits[s].yx;
    }
    if (two && (c.index2[0] & (1u << (index2_bits - 1u))) != 0u) {
        for (var i = 0u; i < 16u; i++) {
            c.index2[i] = (1u << index2_bits) - 1u - c.index2[i];
        }
        // The components `index` does not interpolate.
        for (var k = select(3u, 0u, c.selector == 1u); k < select(4u, 3u, c.selector == 1u); k++) {
            let a = c.ends[0][k];
            c.ends[0][k] = c.ends[1][k];
            c.ends[1][k] = a;
        }
    }
    bits7 = vec4<u32>(0u);
    pos7 = 0u;
    bc7_put(1u << c.mode, c.mode + 1u);
    bc7_put(c.part, partition_bits);
    bc7_put(c.rotation, rotation_bits);
    bc7_put(c.selector, select(0u, 1u, c.mode == 4u));
    let comps = select(3u, 4u, alpha_bits > 0u);
    for (var k = 0u; k < comps; k++) {
        let bits = select(colour_bits, alpha_bits, k == 3u);
        for (var e = 0u; e < 2u * subsets; e++) {
            bc7_put(c.ends[e][k], bits);
        }
    }
    for (var s = 0u; s < subsets; s++) {
        if (kind == PBITS_SHARED) {
            bc7_put(c.pbits[s].x, 1u);
        } else if (kind == PBITS_ENDPOINT) {
            bc7_put(c.pbits[s].x, 1u);
            bc7_put(c.pbits[s].y, 1u);
        }
    }
    for (var i = 0u; i < 16u; i++) {
        let anchor = bc7_anchor(subsets, c.part, bc7_subset(subsets, c.part, i)) == i;
        bc7_put(c.index[i], index_bits - select(0u, 1u, anchor));
    }
    for (var i = 0u; i < 16u; i++) {
        bc7_put(c.index2[i], index2_bits - select(0u, 1u, i == 0u && index2_bits > 0u));
    }
    return bits7;
}

// Pixel `p` with colour channel `rotation` - 1 (1–3) moved to the alpha slot and 255 in its place
// (an opaque block's alpha, which the decoder swaps back); `p` itself for rotation 0.
fn bc7_rotated(p: u32, rotation: u32) -> u32 {
    if (rotation == 0u) {
        return p;
    }
    let shift = 8u * (rotation - 1u);
    return ((p | (255u << shift)) & 0x00FFFFFFu) | (((p >> shift) & 255u) << 24u);
}

// The block in `px` as BC7 (`encode_bc7`): with `alpha` false the pixels' alpha is ignored and
// every pixel decodes with alpha 255; with `alpha` true, blocks whose valid pixels all have
// alpha 255 are encoded as opaque, the others with alpha. The core's candidates in its order —
// an opaque block: mode 6, then (unless exact) mode 1 on the 4 best two-subset partitions, mode 3
// on the 2 best, mode 2 on the 2 best three-subset ones, mode 0 on the 2 best of the first 16,
// mode 5 with each colour channel rotated into the alpha slot, mode 4 (both selectors) with the
// channel mode 5 did best with; a block with alpha: mode 6, then mode 5's colour and alpha — are
// fitted one after the other through a single call of `bc7_fit` (a shader compiler inlines every
// call: one call keeps the shader a fraction of the size).
fn encode_bc7(valid_in: u32, alpha: bool) -> vec4<u32> {
    var translucent = false;
    for (var i = 0u; i < 16u; i++) {
        translucent = translucent || (alpha && counts(valid_in, i) && (px[i] >> 24u) != 255u);
    }
    var valid = valid_in;
    if (valid == 0u) {
        // Mode 6 of opaque black, and nothing else.
        for (var i = 0u; i < 16u; i++) {
            px[i] = 0xFF000000u;
        }
        valid = 0xFFFFu;
    }
    // The pixels as given: modes 4 and 5 fit them rotated.
    let source = px;
    var best = bc7_empty(6u, 0u);
    var c = bc7_empty(6u, 0u);
    var mode = 6u;
    var t = 0u; // the partition's rank among those tried
    var s = 0u; // the subset, or modes 4 and 5's colour (0) and alpha (1)
    var ranked = 0u;
    var ranked16 = 0u; // mode 0's, from mode 2's ranking
    // Mode 5's least error and its rotation, for mode 4.
    var rotated_error = 0xFFFFFFFFu;
    var rotation = 1u;
    loop {
        var subsets = 1u;
        var bits = 7u;
        var kind = PBITS_NONE;
        var index_bits = 2u;
        switch (mode) {
            case 0u: { subsets = 3u; bits = 4u; kind = PBITS_ENDPOINT; index_bits = 3u; }
            case 1u: { subsets = 2u; bits = 6u; kind = PBITS_SHARED; index_bits = 3u; }
            case 2u: { subsets = 3u; bits = 5u; }
            case 3u: { subsets = 2u; kind = PBITS_ENDPOINT; }
            default: {}
        }
        if (t == 0u && s == 0u && (mode == 1u || mode == 2u)) {
            let both = bc7_rank(valid, subsets);
            ranked = both.x;
            ranked16 = both.y;
        }
        if (t == 0u && s == 0u && mode == 0u) {
            ranked = ranked16;
        }
        var mask = valid;
        var part = 0u;
        if (subsets > 1u) {
            part = (ranked >> (8u * t)) & 255u;
            if (s == 0u) {
                c = bc7_empty(mode, part);
            }
            var members = 0u;
            for (var i = 0u; i < 16u; i++) {
                members |= select(0u, 1u << i, bc7_subset(subsets, part, i) == s);
            }
            mask = members & valid;
        }
        if (mode == 6u) {
            let dims = select(3u, 4u, translucent);
            bc7_set_fit(mask, 0u, dims, 7u, select(PBITS_OPAQUE, PBITS_ENDPOINT, translucent), 4u);
        } else if (mode == 5u) {
            // Colour: 7 bits; alpha: 8 bits, indices of its own.
            bc7_set_fit(mask, 3u * s, 3u - 2u * s, 7u + s, PBITS_NONE, 2u);
        } else if (mode == 4u) {
            // Colour: 5 bits; alpha: 6 bits; 2-bit indices for one, 3-bit for the other (colour's
            // 3-bit with the selector set).
            let wide = (s == 0u) == (c.selector == 1u);
            bc7_set_fit(mask, 3u * s, 3u - 2u * s, 5u + s, PBITS_NONE, select(2u, 3u, wide));
        } else {
            bc7_set_fit(mask, 0u, 3u, bits, kind, index_bits);
        }
        let fit = bc7_fit();
        if (mode == 6u) {
            c = bc7_empty(6u, 0u);
            c.ends[0] = fit.ends[0];
            c.ends[1] = fit.ends[1];
            if (!translucent) {
                c.ends[0].w = 127u;
                c.ends[1].w = 127u;
            }
            c.pbits[0] = fit.pbits;
            c.index = fit.index;
            c.error = fit.error;
            best = c;
            if (translucent) {
                mode = 5u;
                c = bc7_empty(5u, 0u);
                continue;
            }
            if (valid_in == 0u || c.error == 0u) {
                break;
            }
            mode = 1u;
            continue;
        }
        if (mode == 5u || mode == 4u) {
            // `index` holds the 2-bit indices: colour's, or alpha's with the selector set.
            let second = (s == 0u) == (c.selector == 1u);
            if (second) {
                c.index2 = fit.index;
            } else {
                c.index = fit.index;
            }
            if (s == 0u) {
                c.ends[0] = fit.ends[0];
                c.ends[1] = fit.ends[1];
                c.error = fit.error;
                s = 1u;
                continue;
            }
            c.ends[0].w = fit.ends[0].x;
            c.ends[1].w = fit.ends[1].x;
            c.error += fit.error;
            if (c.error < best.error) {
                best = c;
            }
            if (translucent) {
                break;
            }
            s = 0u;
            var next = bc7_empty(mode, 0u);
            if (mode == 5u) {
                if (c.error < rotated_error) {
                    rotated_error = c.error;
                    rotation = c.rotation;
                }
                if (c.rotation < 3u) {
                    next.rotation = c.rotation + 1u;
                } else {
                    next.mode = 4u;
                    next.rotation = rotation;
                }
            } else if (c.selector == 0u) {
                next.rotation = c.rotation;
                next.selector = 1u;
            } else {
                break;
            }
            mode = next.mode;
            c = next;
            for (var i = 0u; i < 16u; i++) {
                px[i] = bc7_rotated(source[i], c.rotation);
            }
            continue;
        }
        // Modes 1, 3, 2 and 0: subset s of partition `part`.
        c.ends[2u * s] = fit.ends[0];
        c.ends[2u * s + 1u] = fit.ends[1];
        c.pbits[s] = fit.pbits;
        for (var i = 0u; i < 16u; i++) {
            if (counts(mask, i)) {
                c.index[i] = fit.index[i];
            }
        }
        c.error += fit.error;
        s++;
        if (s < subsets && c.error < best.error) {
            continue;
        }
        if (c.error < best.error) {
            best = c;
        }
        s = 0u;
        t++;
        if (t < select(2u, 4u, mode == 1u)) {
            continue;
        }
        t = 0u;
        if (mode == 0u) {
            // Then mode 5, red in the alpha slot first.
            mode = 5u;
            c = bc7_empty(5u, 0u);
            c.rotation = 1u;
            for (var i = 0u; i < 16u; i++) {
                px[i] = bc7_rotated(source[i], 1u);
            }
            continue;
        }
        mode = select(select(0u, 2u, mode == 3u), 3u, mode == 1u);
    }
    return bc7_pack(best);
}

@compute @workgroup_size(64)
fn encode_codes_bc7(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let block = gid.x + gid.y * groups.x * 64u;
    if (block >= params.count) {
        return;
    }
    write_block(block, encode_bc7(gather_codes(block), params.format == 8u));
}

@compute @workgroup_size(64)
fn encode_pixels_bc7(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let block = gid.x + gid.y * groups.x * 64u;
    if (block >= params.count) {
        return;
    }
    write_block(block, encode_bc7(gather_pixels(block), params.format == 8u));
}

// Filtered lookups (`nmat_sample`) from any shader stage that may read storage buffers
// (docs/GPU.md, "Inference on sample"), shared by the sampling module (sample.wgsl: texels
// decoded where they are needed) and the tile cache's module (cache_sample.wgsl: texels read from
// the cache, which holds the same codes). Whoever includes this file defines the material's
// accessors: `nmat_mip_count()`, `nmat_mip_size(mip)`, `nmat_valid_channels(channels)`,
// `nmat_channel_range(c)` (min, max) and `nmat_fetch(x, y, mip, mask)`, which writes a texel's
// codes into `nmat_codes`.
//
// Filtering is that of nmat_core's `Material::sample` with `Precision::Integer`: the texels'
// codes (bit-exact, texel.wgsl) / 255 weighted like the CPU weights them, the sum clamped to
// [0, 1] and mapped onto each channel's range. The weights are computed in f32 here (f64 on the
// CPU): where u · width and v · height are exact in f32 (e.g. dyadic coordinates) both pick the
// same texels with the same weights, and the values agree to f32 rounding; elsewhere a nearest or
// stochastic lookup exactly on a texel boundary may pick the neighbour. Coordinates must satisfy
// |u · width| < 2^30 (same for v); NaN inputs are undefined (WGSL does not promise to keep NaN).
//
// Cost: texels per lookup (decodes, in the sampling module): nearest 1, bilinear 4, trilinear 8
// (4 where lod is an integer or the last mip), stochastic 1 (the NTC paper's filtering by random
// selection; average it over frames or samples). Channels outside `channels` are not computed in
// the last layer.

const NMAT_NEAREST: u32 = 0u;
const NMAT_BILINEAR: u32 = 1u;
const NMAT_TRILINEAR: u32 = 2u;
const NMAT_STOCHASTIC: u32 = 3u;
const NMAT_ALL_CHANNELS: u32 = 0xFFFFu;

struct NmatAxis {
    first: i32,
    frac: f32,
}

// The texel-space footprint of `u` on an axis of `size` texels: first texel, weight of the next.
fn nmat_axis(u: f32, size: u32, centred: bool) -> NmatAxis {
    let p = clamp(u * f32(size) - select(0.0, 0.5, centred), -1073741824.0, 1073741824.0);
    let base = floor(p);
    return NmatAxis(i32(base), p - base);
}

// The weighted sum of a lookup's texels (codes / 255), by channel.
var<private> nmat_acc: array<f32, 16>;

fn nmat_tap(x: i32, y: i32, mip: u32, weight: f32, mask: u32) {
    if (weight == 0.0) {
        return;
    }
    nmat_fetch(x, y, mip, mask);
    for (var c = 0u; c < 16u; c++) {
        if (((mask >> c) & 1u) != 0u) {
            nmat_acc[c] += weight * (f32(nmat_codes[c]) / 255.0);
        }
    }
}

// A level of a lookup: its mip, its weight and its footprint there — the first texel and the
// weight of the next on each axis (a single texel: that texel, next weights 0).
struct NmatLevel {
    x: NmatAxis,
    y: NmatAxis,
    mip: u32,
    weight: f32,
}

// The four texels around `uv` on `mip`.
fn nmat_bilinear_level(uv: vec2<f32>, mip: u32, weight: f32) -> NmatLevel {
    let size = nmat_mip_size(mip);
    return NmatLevel(nmat_axis(uv.x, size.x, true), nmat_axis(uv.y, size.y, true), mip, weight);
}

fn nmat_single_level(x: i32, y: i32, mip: u32) -> NmatLevel {
    return NmatLevel(NmatAxis(x, 0.0), NmatAxis(y, 0.0), mip, 1.0);
}

// A filtered lookup: `uv` normalized ((0, 0) the top-left corner of texel (0, 0), (1, 1) the
// bottom-right corner of the last; outside [0, 1] the material's address mode applies), `lod`
// the mip level (fractional, clamped to the chain), `rnd` three uniform numbers in [0, 1) for
// NMAT_STOCHASTIC (ignored otherwise; clamped), `mode` one of NMAT_NEAREST, NMAT_BILINEAR,
// NMAT_TRILINEAR, NMAT_STOCHASTIC (other values: nearest), `channels` bit c for channel c
// (NMAT_ALL_CHANNELS: all). Returns the values in each channel's range, indexed by channel;
// channels not asked for (or not in the material) are 0.
fn nmat_sample(
    uv: vec2<f32>,
    lod: f32,
    rnd: vec3<f32>,
    mode: u32,
    channels: u32,
) -> array<f32, 16> {
    let mask = nmat_valid_channels(channels);
    let last = nmat_mip_count() - 1u;
    let level = clamp(lod, 0.0, f32(last));
    let nearest = min(u32(floor(level + 0.5)), last);
    let low = min(u32(floor(level)), last);
    let high = min(low + 1u, last);
    let t = level - f32(low);
    let r = clamp(rnd, vec3<f32>(0.0), vec3<f32>(1.0));
    for (var c = 0u; c < 16u; c++) {
        nmat_acc[c] = 0.0;
    }
    // The lookup's levels (two for a trilinear lookup between two mips) and its texels: four a
    // level, one where the lookup reads a single texel.
    var first = NmatLevel();
    var second = NmatLevel();
    var taps = 4u;
    if (mode == NMAT_BILINEAR) {
        first = nmat_bilinear_level(uv, nearest, 1.0);
    } else if (mode == NMAT_TRILINEAR) {
        first = nmat_bilinear_level(uv, low, 1.0 - t);
        if (high != low) {
            second = nmat_bilinear_level(uv, high, t);
            taps = 8u;
        }
    } else if (mode == NMAT_STOCHASTIC) {
        let mip = select(low, high, r.z < t);
        let size = nmat_mip_size(mip);
        let ax = nmat_axis(uv.x, size.x, true);
        let ay = nmat_axis(uv.y, size.y, true);
        let x = select(ax.first, ax.first + 1, r.x < ax.frac);
        let y = select(ay.first, ay.first + 1, r.y < ay.frac);
        first = nmat_single_level(x, y, mip);
        taps = 1u;
    } else {
        let size = nmat_mip_size(nearest);
        let x = nmat_axis(uv.x, size.x, false).first;
        let y = nmat_axis(uv.y, size.y, false).first;
        first = nmat_single_level(x, y, nearest);
        taps = 1u;
    }
    // Every texel through one call of `nmat_tap` in a loop: the decode is in the shader once,
    // not once per texel of every filter (a trilinear lookup written out holds eight decodes:
    // longer compiles, more instructions to cache). Texel k of a level (k in 0..4) is its first
    // texel + (k % 2, k / 2) with weight level weight × x weight × y weight: the CPU's texels,
    // order and products.
    var at = first;
    for (var k = 0u; k < taps; k++) {
        if (k == 4u) {
            at = second;
        }
        let dx = k & 1u;
        let dy = (k >> 1u) & 1u;
        let wx = select(1.0 - at.x.frac, at.x.frac, dx == 1u);
        let wy = select(1.0 - at.y.frac, at.y.frac, dy == 1u);
        nmat_tap(at.x.first + i32(dx), at.y.first + i32(dy), at.mip, at.weight * wx * wy, mask);
    }
    var out = array<f32, 16>();
    for (var c = 0u; c < 16u; c++) {
        if (((mask >> c) & 1u) != 0u) {
            let unit = clamp(nmat_acc[c], 0.0, 1.0);
            let range = nmat_channel_range(c);
            out[c] = range.x * (1.0 - unit) + range.y * unit;
        }
    }
    return out;
}

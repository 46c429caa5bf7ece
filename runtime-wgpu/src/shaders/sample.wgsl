// The sampling module's material accessors (filter.wgsl documents what they provide): the
// material in `nmat_desc`, texels decoded by `nmat_decode` (texel.wgsl).

fn nmat_channel_count() -> u32 {
    return nmat_desc[NMAT_DESC_CHANNEL_COUNT];
}

fn nmat_mip_count() -> u32 {
    return nmat_desc[NMAT_DESC_MIP_COUNT];
}

// Width and height of `mip` (clamped to the chain).
fn nmat_mip_size(mip: u32) -> vec2<u32> {
    let m = min(mip, nmat_desc[NMAT_DESC_MIP_COUNT] - 1u);
    let size = vec2<u32>(nmat_desc[NMAT_DESC_WIDTH], nmat_desc[NMAT_DESC_HEIGHT]);
    return max(size >> vec2<u32>(m), vec2<u32>(1u));
}

// Channel `c`'s range: (min, max).
fn nmat_channel_range(c: u32) -> vec2<f32> {
    let at = nmat_desc[NMAT_DESC_RANGES_AT] + NMAT_RANGE_WORDS * c;
    let range = vec2<u32>(nmat_desc[at + NMAT_RANGE_MIN], nmat_desc[at + NMAT_RANGE_MAX]);
    return bitcast<vec2<f32>>(range);
}

// The codes of texel (x, y) of `mip` into `nmat_codes` (channels in `mask`): decoded here.
fn nmat_fetch(x: i32, y: i32, mip: u32, mask: u32) {
    nmat_decode(x, y, mip, mask);
}

// `channels` without the bits of channels the material does not have.
fn nmat_valid_channels(channels: u32) -> u32 {
    return channels & ((1u << nmat_desc[NMAT_DESC_CHANNEL_COUNT]) - 1u);
}

// The 8-bit codes of texel (x, y) of `mip`, addressed (wrap or clamp) and clamped to the chain
// like `Material::decode_texel_u8`, indexed by channel; channels outside `channels` are 0.
fn nmat_texel(xy: vec2<i32>, mip: u32, channels: u32) -> array<u32, 16> {
    let mask = nmat_valid_channels(channels);
    nmat_decode(xy.x, xy.y, mip, mask);
    var out = array<u32, 16>();
    for (var c = 0u; c < 16u; c++) {
        if (((mask >> c) & 1u) != 0u) {
            out[c] = nmat_codes[c];
        }
    }
    return out;
}


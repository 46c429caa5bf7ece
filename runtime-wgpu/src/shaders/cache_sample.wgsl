// The tile cache's material accessors (filter.wgsl says what they provide): texels are read from
// the cache's tiles, not decoded. Whoever includes this file declares `nmat_cache_word(i)` (word
// i of the table), `nmat_cache_record_word(material, i)` (word i of a material's record: the
// table's, or the passes' uniform copy of it), `nmat_cache_code_word(i)` (word i of the codes)
// and `nmat_fetch`, which calls `nmat_cache_read` (cache.rs writes the buffers; every name
// starts with `nmat_`, `Nmat` or `NMAT_`, as in the sampling module).
//
// The table (cache.rs writes it) is read through the constants nmat-wgpu's layout.rs generates
// and prepends to this file: NMAT_CACHE_* (its head: this frame's counters, then the materials,
// the page ranges and the pages), NMAT_CACHE_MAT_* (a record per material, from word
// NMAT_CACHE_WORDS: sizes, address mode, each mip's first page, each channel's range),
// NMAT_CACHE_SPAN_* (the pages of every mip of every material in page order: how a page finds
// its tile). A page is the slot holding its tile + 1 (0: not in the cache), NMAT_CACHE_MARK set
// when the frame marked it.
// The codes: slot s from word s · (words per slot); texel (x, y) of the tile, channel c of its
// material at byte (16 · y + x) · (channel count) + c.


// The codes `nmat_fetch` wrote, by channel.
var<private> nmat_codes: array<u32, 16>;
// The material of the lookup being filtered.
var<private> nmat_cache_material: u32;
// Texels the last lookup read from tiles the cache did not hold (their codes read as 0).
var<private> nmat_cache_misses: u32;

// Word `i` of the record of the material being filtered.
fn nmat_cache_record(i: u32) -> u32 {
    return nmat_cache_record_word(nmat_cache_material, i);
}

fn nmat_channel_count() -> u32 {
    return nmat_cache_record(NMAT_CACHE_MAT_CHANNEL_COUNT);
}

fn nmat_mip_count() -> u32 {
    return nmat_cache_record(NMAT_CACHE_MAT_MIP_COUNT);
}

fn nmat_mip_size(mip: u32) -> vec2<u32> {
    let m = min(mip, nmat_mip_count() - 1u);
    let size = vec2<u32>(nmat_cache_record(NMAT_CACHE_MAT_WIDTH), nmat_cache_record(NMAT_CACHE_MAT_HEIGHT));
    return max(size >> vec2<u32>(m), vec2<u32>(1u));
}

fn nmat_channel_range(c: u32) -> vec2<f32> {
    let at = NMAT_CACHE_MAT_RANGES + NMAT_CACHE_RANGE_WORDS * c;
    let range = vec2<u32>(nmat_cache_record(at + NMAT_CACHE_RANGE_MIN), nmat_cache_record(at + NMAT_CACHE_RANGE_MAX));
    return bitcast<vec2<f32>>(range);
}

fn nmat_valid_channels(channels: u32) -> u32 {
    return channels & ((1u << nmat_channel_count()) - 1u);
}

fn nmat_cache_address(i: i32, size: u32, clamp_mode: bool) -> u32 {
    let s = i32(size);
    if (clamp_mode) {
        return u32(clamp(i, 0, s - 1));
    }
    // i modulo s of unsigned operands (texel.wgsl's nmat_wrap, which this module does not
    // include: GLSL leaves `%` of a negative operand undefined).
    if (i < 0) {
        return size - 1u - u32(-(i + 1)) % size;
    }
    return u32(i) % size;
}

// Texel (x, y) of `mip` addressed like `Material::decode_texel_u8` (wrap or clamp, the mip
// clamped to the chain): (its page, x, y, mip).
fn nmat_cache_page(x: i32, y: i32, mip: u32) -> vec4<u32> {
    let m = min(mip, nmat_mip_count() - 1u);
    let size = nmat_mip_size(m);
    let clamp_mode = nmat_cache_record(NMAT_CACHE_MAT_ADDRESS_MODE) == 1u;
    let ax = nmat_cache_address(x, size.x, clamp_mode);
    let ay = nmat_cache_address(y, size.y, clamp_mode);
    let page = nmat_cache_record(NMAT_CACHE_MAT_FIRST_PAGE + m) + (ay / 16u) * ((size.x + 15u) / 16u) + ax / 16u;
    return vec4<u32>(page, ax, ay, m);
}

// The page `nmat_cache_read` read last (0, the table's first word, is never a page), and where its
// tile's codes start (a byte of the codes; 0xFFFFFFFF: not in the cache). A lookup's taps mostly
// share a page, and the table does not change while lookups are resolved.
var<private> nmat_cache_read_page: u32;
var<private> nmat_cache_read_first: u32;

// The codes of texel (x, y) of `mip` (channels in `mask`) into `nmat_codes`, read from its tile;
// a tile the cache does not hold reads as codes 0 and counts in `nmat_cache_misses`.
fn nmat_cache_read(x: i32, y: i32, mip: u32, mask: u32) {
    let p = nmat_cache_page(x, y, mip);
    if (p.x != nmat_cache_read_page) {
        nmat_cache_read_page = p.x;
        let entry = nmat_cache_word(p.x) & ~NMAT_CACHE_MARK;
        nmat_cache_read_first = select(0xFFFFFFFFu, (entry - 1u) * nmat_cache_word(NMAT_CACHE_SLOT_WORDS) * 4u, entry != 0u);
    }
    for (var c = 0u; c < 16u; c++) {
        nmat_codes[c] = 0u;
    }
    if (nmat_cache_read_first == 0xFFFFFFFFu) {
        nmat_cache_misses += 1u;
        return;
    }
    let n = nmat_channel_count();
    let first = nmat_cache_read_first + ((p.z % 16u) * 16u + p.y % 16u) * n;
    // Each word of the texel's codes is loaded once.
    var word_at = 0xFFFFFFFFu;
    var word = 0u;
    for (var c = 0u; c < n; c++) {
        if (((mask >> c) & 1u) != 0u) {
            let byte = first + c;
            if (byte / 4u != word_at) {
                word_at = byte / 4u;
                word = nmat_cache_code_word(word_at);
            }
            nmat_codes[c] = (word >> (8u * (byte % 4u))) & 255u;
        }
    }
}

// A filtered lookup of material `material` (its index in the cache's list) from the cache:
// `nmat_sample`'s arguments and result (filter.wgsl), the texels read from the tiles a frame
// marked and decoded. Where the cache held every tile (`nmat_cache_misses == 0u` after the call)
// the values are those of the sampling module's `nmat_sample` for that material, bit for bit.
fn nmat_cache_sample(
    material: u32,
    uv: vec2<f32>,
    lod: f32,
    rnd: vec3<f32>,
    mode: u32,
    channels: u32,
) -> array<f32, 16> {
    nmat_cache_material = material;
    nmat_cache_misses = 0u;
    return nmat_sample(uv, lod, rnd, mode, channels);
}

// Indexed-JPEG materials (docs/FORMAT.md §11) on the GPU, bit-identical with nmat_core's
// decoder: one workgroup per MCU (the JPEG-texture paper's layout). Invocation 0 decodes the MCU's
// entropy-coded blocks (sequential by nature) into workgroup memory, 8 invocations per block run
// the two passes of the islow IDCT, and every invocation then writes the texels it owns. One
// dispatch decodes one map; jpeg.rs dispatches each map that holds a selected channel.
//
// Requests decode each MCU they read once, through a work buffer (jpeg.rs, `WorkShape`): word 0
// counts the MCUs listed, then a table of one word per MCU of a map's chain (0, or CLAIMED | the
// MCU's slot), the list of MCUs (`params.list_at`, keys as the tile cache's: mip << 26 | row << 13
// | column) and their slots of decoded codes (`params.scratch_at`, `params.slot_words` each).
// `jpeg_mark` claims each request's MCU and lists it; `jpeg_main` in mode 3 decodes the listed
// MCUs, one workgroup each, every channel of the map into the MCU's slot; `jpeg_resolve` copies
// each request's selected channels out of its MCU's slot; `jpeg_reset` clears the table again.
//
// `jdesc` (written by `upload_words` in jpeg.rs) is read through the constants nmat-wgpu's
// layout.rs generates and prepends to this file: JDESC_* (the header: sizes, address mode, where
// the records start), JMIP_* (each mip's size), JMAP_* (a map's channels and luma sampling),
// JSTREAM_* (per map and mip, map-major: byte offsets into `section` and the Y, Cb, Cr tables'
// numbers, `Jpeg::stream_parts`), JHUFF_* (per table: maxcode[0..17] and offset[0..17] as i32
// bits, `huffman_decoding`, then where its symbols start in `section` and how many there are).
// `section` is the file's JPEG section, four bytes per word, little-endian.

@group(0) @binding(0) var<storage, read> jdesc: array<u32>;
@group(0) @binding(1) var<storage, read> section: array<u32>;
@group(0) @binding(2) var<storage, read> requests: array<i32>;
// Codes packed four per word; each dispatch ORs its bytes into a cleared buffer (several maps
// and MCUs share words).
@group(0) @binding(3) var<storage, read_write> out_codes: array<atomic<u32>>;
@group(0) @binding(4) var<uniform> params: Params;

// Width and height of `mip`.
fn mip_width(mip: u32) -> u32 {
    return jdesc[JDESC_MIP_SIZES + JMIP_WORDS * mip + JMIP_WIDTH];
}

fn mip_height(mip: u32) -> u32 {
    return jdesc[JDESC_MIP_SIZES + JMIP_WORDS * mip + JMIP_HEIGHT];
}

// The MCU's blocks (at most 4 luma, Cb, Cr): dequantized coefficients in natural order, then
// samples; and the IDCT's intermediate rows.
var<workgroup> blocks: array<i32, 384>;
var<workgroup> ws: array<i32, 384>;
// The request pass's list count and this workgroup's MCU key, shared uniformly (jpeg_main).
var<workgroup> listed_mcu: vec2<u32>;

const ZIGZAG = array<u32, 64>(
    0u, 1u, 8u, 16u, 9u, 2u, 3u, 10u, 17u, 24u, 32u, 25u, 18u, 11u, 4u, 5u, 12u, 19u, 26u, 33u,
    40u, 48u, 41u, 34u, 27u, 20u, 13u, 6u, 7u, 14u, 21u, 28u, 35u, 42u, 49u, 56u, 57u, 50u, 43u,
    36u, 29u, 22u, 15u, 23u, 30u, 37u, 44u, 51u, 58u, 59u, 52u, 45u, 38u, 31u, 39u, 46u, 53u, 60u,
    61u, 54u, 47u, 55u, 62u, 63u);

fn sbyte(at: u32) -> u32 {
    return (section[at >> 2u] >> (8u * (at & 3u))) & 255u;
}

// The entropy-coded data being read: where it starts, its length and the bit position.
var<private> data_at: u32;
var<private> data_len: u32;
var<private> bit_pos: u32;

fn data_byte(i: u32) -> u32 {
    if (i < data_len) {
        return sbyte(data_at + i);
    }
    return 0u; // bits past the end are 0, as on the CPU
}

fn peek16() -> u32 {
    let byte = bit_pos >> 3u;
    let word = (data_byte(byte) << 16u) | (data_byte(byte + 1u) << 8u) | data_byte(byte + 2u);
    return (word >> (8u - (bit_pos & 7u))) & 0xFFFFu;
}

fn take(n: u32) -> u32 {
    if (n == 0u) {
        return 0u;
    }
    let v = peek16() >> (16u - min(n, 16u));
    bit_pos += n;
    return v;
}

// The symbol of the next code of Huffman table `t`; an unknown code is 16 bits of symbol 0.
fn huffman(t: u32) -> u32 {
    let base = jdesc[JDESC_HUFFMAN_AT] + JHUFF_WORDS * t;
    let word = i32(peek16());
    for (var l = 1u; l <= 16u; l++) {
        let code = word >> (16u - l);
        if (code <= bitcast<i32>(jdesc[base + JHUFF_MAXCODE + l])) {
            bit_pos += l;
            let at = code + bitcast<i32>(jdesc[base + JHUFF_OFFSET + l]);
            if (at < 0 || u32(at) >= jdesc[base + JHUFF_VALUES]) {
                return 0u;
            }
            return sbyte(jdesc[base + JHUFF_VALUES_AT] + u32(at));
        }
    }
    bit_pos += 16u;
    return 0u;
}

fn extend(v: u32, n: u32) -> i32 {
    if (n == 0u) {
        return 0;
    }
    if (v < (1u << (n - 1u))) {
        return i32(v) - (1 << n) + 1;
    }
    return i32(v);
}

// One block into `blocks[at..at + 64]` (AC coefficients dequantized, DC left 0); returns the DC
// difference.
fn block(at: u32, dc_table: u32, ac_table: u32, quant_at: u32) -> i32 {
    for (var i = 0u; i < 64u; i++) {
        blocks[at + i] = 0;
    }
    let s = min(huffman(dc_table), 16u);
    let diff = extend(take(s), s);
    var k = 1u;
    loop {
        if (k >= 64u) {
            break;
        }
        let rs = huffman(ac_table);
        let run = rs >> 4u;
        let size = rs & 15u;
        if (size == 0u) {
            if (run != 15u) {
                break;
            }
            k += 16u;
            continue;
        }
        k += run;
        let v = extend(take(size), size);
        if (k < 64u) {
            blocks[at + ZIGZAG[k]] = v * i32(sbyte(quant_at + k));
        }
        k += 1u;
    }
    return diff;
}

// Stored DC value `k` of the stream (12 bits, sign-extended); 0 past the DC values.
fn stored_dc(dc_at: u32, dc_len: u32, k: u32) -> i32 {
    let bit = 12u * k;
    let i = bit >> 3u;
    var word = 0u;
    if (i < dc_len) {
        word = sbyte(dc_at + i);
    }
    if (i + 1u < dc_len) {
        word |= sbyte(dc_at + i + 1u) << 8u;
    }
    let v = (word >> (bit & 7u)) & 0xFFFu;
    return bitcast<i32>(v << 20u) >> 20u;
}

// Entropy-decodes MCU `mcu` of the stream whose record starts at word `s` of `jdesc`.
fn decode_blocks(s: u32, mcu: u32, luma_blocks: u32, colour: bool) {
    let index_at = jdesc[s + JSTREAM_INDEX_AT];
    let dc_at = jdesc[s + JSTREAM_DC_AT];
    data_at = jdesc[s + JSTREAM_DATA_AT];
    data_len = jdesc[s + JSTREAM_DATA_LEN];
    let g = mcu / 9u;
    let j = mcu % 9u;
    let group = index_at + 20u * g;
    var start = sbyte(group) | (sbyte(group + 1u) << 8u) | (sbyte(group + 2u) << 16u)
        | (sbyte(group + 3u) << 24u);
    if (j > 0u) {
        let rel = group + 4u + 2u * (j - 1u);
        start += sbyte(rel) | (sbyte(rel + 1u) << 8u);
    }
    bit_pos = start;
    let values = select(1u, 3u, colour);
    let dc_len = data_at - dc_at;
    let quant0 = jdesc[s + JSTREAM_QUANT_AT];
    var dc = stored_dc(dc_at, dc_len, mcu * values);
    for (var b = 0u; b < luma_blocks; b++) {
        let diff = block(64u * b, jdesc[s + JSTREAM_DC_TABLE], jdesc[s + JSTREAM_AC_TABLE], quant0);
        if (b > 0u) {
            dc += diff;
        }
        blocks[64u * b] = dc * i32(sbyte(quant0));
    }
    if (colour) {
        for (var c = 0u; c < 2u; c++) {
            // Component 1 + c (Cb, Cr).
            let k = 1u + c;
            let quant = jdesc[s + JSTREAM_QUANT_AT + k];
            let at = 64u * (luma_blocks + c);
            block(at, jdesc[s + JSTREAM_DC_TABLE + k], jdesc[s + JSTREAM_AC_TABLE + k], quant);
            blocks[at] = stored_dc(dc_at, dc_len, mcu * values + 1u + c) * i32(sbyte(quant));
        }
    }
}

// One 1-D pass of the islow IDCT (13-bit constants), outputs scaled by 2^13.
fn idct_pass(x: array<i32, 8>) -> array<i32, 8> {
    let z1 = (x[2] + x[6]) * 4433;
    let t2 = z1 + x[6] * -15137;
    let t3 = z1 + x[2] * 6270;
    let t0 = (x[0] + x[4]) << 13u;
    let t1 = (x[0] - x[4]) << 13u;
    let e10 = t0 + t3;
    let e13 = t0 - t3;
    let e11 = t1 + t2;
    let e12 = t1 - t2;
    var a1 = x[7] + x[1];
    var a2 = x[5] + x[3];
    var a3 = x[7] + x[3];
    var a4 = x[5] + x[1];
    let z5 = (a3 + a4) * 9633;
    a1 = a1 * -7373;
    a2 = a2 * -20995;
    a3 = a3 * -16069 + z5;
    a4 = a4 * -3196 + z5;
    let o0 = x[7] * 2446 + a1 + a3;
    let o1 = x[5] * 16819 + a2 + a4;
    let o2 = x[3] * 25172 + a2 + a3;
    let o3 = x[1] * 12299 + a1 + a4;
    return array<i32, 8>(e10 + o3, e11 + o2, e12 + o1, e13 + o0, e13 - o0, e12 - o1, e11 - o2,
        e10 - o3);
}

fn descale(v: i32, n: u32) -> i32 {
    return (v + (1 << (n - 1u))) >> n;
}

fn address(v: i32, size: u32) -> u32 {
    let s = i32(size);
    if (jdesc[JDESC_ADDRESS_MODE] == 0u) {
        // v modulo s of unsigned operands (as texel.wgsl's nmat_wrap: GLSL leaves `%` of a
        // negative operand undefined).
        if (v < 0) {
            return size - 1u - u32(-(v + 1)) % size;
        }
        return u32(v) % size;
    }
    return u32(clamp(v, 0, s - 1));
}

// The first word of the output (the tile cache: of the tile's slot).
var<private> out_base: u32;

fn put(byte: u32, code: u32) {
    atomicOr(&out_codes[out_base + (byte >> 2u)], code << (8u * (byte & 3u)));
}

// The `count` channels' codes of this map at texel (x, y) of the MCU (samples in `blocks`).
fn texel_codes(x: u32, y: u32, count: u32, lh: u32, lv: u32) -> array<u32, 3> {
    var codes = array<u32, 3>();
    if (count == 1u) {
        codes[0] = u32(blocks[8u * y + x]);
    } else {
        let luma = 64u * ((y / 8u) * lh + x / 8u) + 8u * (y % 8u) + x % 8u;
        let chroma = 64u * lh * lv + 8u * (y / lv) + x / lh;
        let yv = blocks[luma];
        let cb = blocks[chroma] - 128;
        let cr = blocks[chroma + 64u] - 128;
        codes[0] = u32(clamp(yv + ((91881 * cr + 32768) >> 16u), 0, 255));
        codes[1] = u32(clamp(yv + ((-22554 * cb - 46802 * cr + 32768) >> 16u), 0, 255));
        codes[2] = u32(clamp(yv + ((116130 * cb + 32768) >> 16u), 0, 255));
    }
    return codes;
}

// Writes `codes`, the `count` channels of this map from channel `first`, as output texel `t`'s
// selected channels.
fn put_codes(t: u32, codes: array<u32, 3>, first: u32, count: u32) {
    let mask = params.channel_mask;
    var slot = countOneBits(mask & ((1u << first) - 1u));
    for (var c = 0u; c < count; c++) {
        if ((mask & (1u << (first + c))) != 0u) {
            put(t * params.out_channels + slot, codes[c]);
            slot += 1u;
        }
    }
}

// Writes the selected channels of this map at texel (x, y) of the MCU as output texel `t`.
fn write_texel(t: u32, x: u32, y: u32, first: u32, count: u32, lh: u32, lv: u32) {
    put_codes(t, texel_codes(x, y, count, lh, lv), first, count);
}

@compute @workgroup_size(64)
fn jpeg_main(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let g = wg.x + wg.y * groups.x;
    let map = jdesc[JDESC_MAPS_AT] + JMAP_WORDS * params.map;
    let first = jdesc[map + JMAP_FIRST_CHANNEL];
    let count = jdesc[map + JMAP_CHANNEL_COUNT];
    let lh = jdesc[map + JMAP_LUMA_H];
    let lv = jdesc[map + JMAP_LUMA_V];
    let mw = 8u * lh;
    let mh = 8u * lv;
    var mip = params.mip;
    var mx = 0u;
    var my = 0u;
    out_base = params.out_offset;
    if (params.mode == 2u) {
        // Tile g / mcu_count of the queue, its MCU g % mcu_count (a tile of 16 × 16 texels
        // holds whole MCUs; those past the mip's edge are not decoded).
        let q = params.in_offset;
        let tile = g / params.mcu_count;
        if (tile >= u32(requests[q + NMAT_CACHE_QUEUE_COUNT])) {
            return;
        }
        let entry = q + NMAT_CACHE_QUEUE_WORDS + NMAT_CACHE_ENTRY_WORDS * tile;
        out_base = u32(requests[entry + NMAT_CACHE_ENTRY_SLOT]) * params.slot_words;
        let key = u32(requests[entry + NMAT_CACHE_ENTRY_KEY]);
        mip = key >> 26u;
        let k = g % params.mcu_count;
        mx = (16u * (key & 0x1FFFu)) / mw + k % params.mcu_columns;
        my = (16u * ((key >> 13u) & 0x1FFFu)) / mh + k / params.mcu_columns;
        if (mx * mw >= mip_width(mip) || my * mh >= mip_height(mip)) {
            return;
        }
    } else if (params.mode == 3u) {
        // The listed MCU g, into its slot. The list's count and the MCU's key are read by one
        // invocation and handed to all through workgroupUniformLoad: WGSL counts an atomic's
        // value as non-uniform, and the barriers below need uniform control flow (Tint, the
        // browser's compiler, refuses the shader otherwise; naga did not check).
        if (lid == 0u) {
            let listed = atomicLoad(&out_codes[0]);
            var key = 0u;
            if (g < listed) {
                key = atomicLoad(&out_codes[params.list_at + g]);
            }
            listed_mcu = vec2<u32>(listed, key);
        }
        let listed = workgroupUniformLoad(&listed_mcu);
        if (g >= listed.x) {
            return;
        }
        let key = listed.y;
        mip = key >> 26u;
        mx = key & 0x1FFFu;
        my = (key >> 13u) & 0x1FFFu;
        out_base = params.scratch_at + g * params.slot_words;
    } else {
        if (g >= params.mcu_count) {
            return;
        }
        mx = params.x0 / mw + g % params.mcu_columns;
        my = params.y0 / mh + g / params.mcu_columns;
    }
    let s = jdesc[JDESC_STREAMS_AT] + JSTREAM_WORDS * (params.map * jdesc[JDESC_MIP_COUNT] + mip);
    let colour = count == 3u;
    let n_blocks = select(1u, lh * lv + 2u, colour);
    if (lid == 0u) {
        decode_blocks(s, my * jdesc[s + JSTREAM_MCUS_X] + mx, select(1u, lh * lv, colour), colour);
    }
    workgroupBarrier();
    // Columns, then rows: invocation 8·b + k takes column (row) k of block b.
    let b = lid / 8u;
    let k = lid % 8u;
    if (b < n_blocks) {
        var x = array<i32, 8>();
        for (var i = 0u; i < 8u; i++) {
            x[i] = blocks[64u * b + 8u * i + k];
        }
        var v = idct_pass(x);
        for (var i = 0u; i < 8u; i++) {
            ws[64u * b + 8u * i + k] = descale(v[i], 11u);
        }
    }
    workgroupBarrier();
    if (b < n_blocks) {
        var x = array<i32, 8>();
        for (var i = 0u; i < 8u; i++) {
            x[i] = ws[64u * b + 8u * k + i];
        }
        var v = idct_pass(x);
        for (var i = 0u; i < 8u; i++) {
            blocks[64u * b + 8u * k + i] = clamp(descale(v[i], 18u) + 128, 0, 255);
        }
    }
    workgroupBarrier();
    if (params.mode == 3u) {
        // Whole words of the slot: byte 4·w + i is channel b % count of texel b / count (a
        // texel's codes computed once for the bytes of it a word holds).
        for (var w = lid; w < params.slot_words; w += 64u) {
            var word = 0u;
            var t = 0xFFFFFFFFu;
            var codes = array<u32, 3>();
            for (var i = 0u; i < 4u; i++) {
                let b = 4u * w + i;
                if (b / count >= mw * mh) {
                    break;
                }
                if (b / count != t) {
                    t = b / count;
                    codes = texel_codes(t % mw, t / mw, count, lh, lv);
                }
                word |= codes[b % count] << (8u * i);
            }
            atomicStore(&out_codes[out_base + w], word);
        }
        return;
    }
    for (var i = lid; i < mw * mh; i += 64u) {
        let x = mx * mw + i % mw;
        let y = my * mh + i / mw;
        if (params.mode == 2u) {
            if (x < mip_width(mip) && y < mip_height(mip)) {
                write_texel((y % 16u) * 16u + x % 16u, i % mw, i / mw, first, count, lh, lv);
            }
        } else if (x >= params.x0 && x - params.x0 < params.width && y >= params.y0
            && y - params.y0 < params.count / params.width) {
            let t = (y - params.y0) * params.width + (x - params.x0);
            write_texel(t, i % mw, i / mw, first, count, lh, lv);
        }
    }
}

// A claimed entry of the request passes' table; its low bits are the MCU's slot.
const CLAIMED = 0x80000000u;

// Request g of the round: its mip and texel (addressed as the CPU does), its MCU's key and
// table word, and the map's channels and MCU shape.
struct JpegRequest {
    mip: u32,
    tx: u32,
    ty: u32,
    key: u32,
    table: u32,
    first: u32,
    count: u32,
    lh: u32,
    lv: u32,
}

fn jpeg_request(g: u32) -> JpegRequest {
    var q = JpegRequest();
    let map = jdesc[JDESC_MAPS_AT] + JMAP_WORDS * params.map;
    q.first = jdesc[map + JMAP_FIRST_CHANNEL];
    q.count = jdesc[map + JMAP_CHANNEL_COUNT];
    q.lh = jdesc[map + JMAP_LUMA_H];
    q.lv = jdesc[map + JMAP_LUMA_V];
    let r = params.in_offset + 3u * g;
    q.mip = min(bitcast<u32>(requests[r + 2u]), jdesc[JDESC_MIP_COUNT] - 1u);
    q.tx = address(requests[r], mip_width(q.mip));
    q.ty = address(requests[r + 1u], mip_height(q.mip));
    let mx = q.tx / (8u * q.lh);
    let my = q.ty / (8u * q.lv);
    q.key = (q.mip << 26u) | (my << 13u) | mx;
    let s = jdesc[JDESC_STREAMS_AT] + JSTREAM_WORDS * (params.map * jdesc[JDESC_MIP_COUNT] + q.mip);
    q.table = jdesc[s + JSTREAM_TABLE_AT] + my * jdesc[s + JSTREAM_MCUS_X] + mx;
    return q;
}

// The number of this invocation in a dispatch of 64-invocation workgroups (x + y · columns).
fn invocation_index(id: vec3<u32>, groups: vec3<u32>) -> u32 {
    return id.x + id.y * groups.x * 64u;
}

// Claims each request's MCU: the first request to reach an MCU lists it and gives it the next
// slot.
@compute @workgroup_size(64)
fn jpeg_mark(
    @builtin(global_invocation_id) id: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let g = invocation_index(id, groups);
    if (g >= params.count) {
        return;
    }
    let q = jpeg_request(g);
    if (atomicOr(&out_codes[q.table], CLAIMED) == 0u) {
        let slot = atomicAdd(&out_codes[0], 1u);
        atomicStore(&out_codes[params.list_at + slot], q.key);
        atomicStore(&out_codes[q.table], CLAIMED | slot);
    }
}

// Each request's selected channels from its MCU's slot (`section` is the work buffer here).
@compute @workgroup_size(64)
fn jpeg_resolve(
    @builtin(global_invocation_id) id: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let g = invocation_index(id, groups);
    if (g >= params.count) {
        return;
    }
    let q = jpeg_request(g);
    let slot = section[q.table] & ~CLAIMED;
    let mw = 8u * q.lh;
    let t = (q.ty % (8u * q.lv)) * mw + q.tx % mw;
    let at = 4u * (params.scratch_at + slot * params.slot_words) + t * q.count;
    var codes = array<u32, 3>();
    for (var c = 0u; c < q.count; c++) {
        codes[c] = sbyte(at + c);
    }
    out_base = params.out_offset;
    put_codes(params.first + g, codes, q.first, q.count);
}

// Clears the table entries the round claimed.
@compute @workgroup_size(64)
fn jpeg_reset(
    @builtin(global_invocation_id) id: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let g = invocation_index(id, groups);
    if (g < params.count) {
        atomicStore(&out_codes[jpeg_request(g).table], 0u);
    }
}

// Zeroes the words the codes of `params` take (from `params.out_offset`), before the maps' passes
// OR their bytes in.
@compute @workgroup_size(64)
fn jpeg_clear(
    @builtin(global_invocation_id) id: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let i = invocation_index(id, groups);
    if (i < params.clear_words) {
        atomicStore(&out_codes[params.out_offset + i], 0u);
    }
}

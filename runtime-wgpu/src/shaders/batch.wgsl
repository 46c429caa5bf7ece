// Where the batched kernels (tiled.wgsl, unrolled.wgsl, matrix.wgsl) write a batch's codes,
// staged one per u32 in their `tile_codes` (P texels, texel then channel): the dispatch's
// output (`nmat_store_codes`), or a tile of the tile cache (`params.mode` 2, their cache
// entries; cache.rs): the material's queue from word `params.in_offset` of `requests` (the
// cache's state, laid out by cache.wgsl), each tile's codes, every channel
// (`params.out_channels` of them), into its slot of `out_codes`, `params.row_words` words a
// slot. A tile's batch is P texels of it (row-major, 16 a row), P a multiple of 4; where P does
// not divide 256 (the matrix kernel's batches of 48 texels with three subgroups) a tile's last
// batch reaches past its 256 texels, and those texels are neither decoded nor stored.

// The input features of texel `index` of the dispatch (request or rectangle, decode.wgsl's
// `texel_of`) in nmat_act_a[0..inputs) (`nmat_texel_features`, generated for the material's
// latent layout by features.rs); stand-in features varying by texel instead in a
// pipeline that times the layers alone (`PART == 2u`, measure.rs).
fn nmat_batch_features(index: u32, inputs: u32) {
    if (PART == 2u) {
        stand_in_features(index, inputs);
    } else {
        let texel = texel_of(index);
        nmat_texel_features(texel.x, texel.y, bitcast<u32>(texel.z));
    }
}

// The codes of texels first … first + P − 1 of the dispatch (those past `params.count` left
// out) packed four per word into `out_codes` from word `params.out_offset` (a batch's codes
// start on a word: P is a multiple of 4; the last word's spare bytes are 0); invocation `lid`
// of `invocations` writes every invocations-th word.
fn nmat_store_codes(first: u32, lid: u32, invocations: u32) {
    let n = params.out_channels;
    let texels = select(0u, min(params.count - first, P), first < params.count);
    let count = texels * n;
    for (var w = lid; 4u * w < count; w += invocations) {
        var word = 0u;
        for (var k = 0u; k < 4u; k++) {
            if (4u * w + k < count) {
                word |= tile_codes[4u * w + k] << (8u * k);
            }
        }
        out_codes[params.out_offset + first / 4u * n + w] = word;
    }
}

// A queued tile: its slot, its mip, its first texel and the mip's size.
struct NmatQueuedTile {
    slot: u32,
    mip: u32,
    origin: vec2<u32>,
    size: vec2<u32>,
}

// Tiles in the material's queue.
fn nmat_queued_count() -> u32 {
    return bitcast<u32>(requests[params.in_offset + NMAT_CACHE_QUEUE_COUNT]);
}

// Tile `k` of the queue (k below `nmat_queued_count()`); its key is mip << 26 | row << 13 |
// column.
fn nmat_queued_tile(k: u32) -> NmatQueuedTile {
    let entry = params.in_offset + NMAT_CACHE_QUEUE_WORDS + NMAT_CACHE_ENTRY_WORDS * k;
    let key = bitcast<u32>(requests[entry + NMAT_CACHE_ENTRY_KEY]);
    let mip = key >> 26u;
    let full = vec2<u32>(nmat_desc[NMAT_DESC_WIDTH], nmat_desc[NMAT_DESC_HEIGHT]);
    return NmatQueuedTile(
        bitcast<u32>(requests[entry + NMAT_CACHE_ENTRY_SLOT]),
        mip,
        16u * vec2<u32>(key & 0x1FFFu, (key >> 13u) & 0x1FFFu),
        max(full >> vec2<u32>(mip), vec2<u32>(1u)),
    );
}

// Texel `i` of `tile` (0 … 255), in mip coordinates.
fn nmat_tile_texel(tile: NmatQueuedTile, i: u32) -> vec2<u32> {
    return tile.origin + vec2<u32>(i % 16u, i / 16u);
}

// Whether texel `i` of `tile` is one of its 256 and lies inside its mip (an edge tile's others,
// and a last batch's texels past the tile, are not decoded).
fn nmat_tile_has(tile: NmatQueuedTile, i: u32) -> bool {
    return i < 256u && all(nmat_tile_texel(tile, i) < tile.size);
}

// The codes of texels t0 … t0 + P − 1 of `tile` (those up to its last, 255) from `tile_codes`
// into its slot: P · n bytes (fewer in a last batch past the tile), a whole number of words
// starting on one (t0 and P are multiples of 4), each written whole (0 for a texel outside the
// mip); invocation `lid` of `invocations` writes every invocations-th word.
fn nmat_store_batch(tile: NmatQueuedTile, t0: u32, lid: u32, invocations: u32) {
    let n = params.out_channels;
    let first = tile.slot * params.row_words + t0 * n / 4u;
    let words = min(P, 256u - t0) * n / 4u;
    for (var w = lid; w < words; w += invocations) {
        var word = 0u;
        for (var k = 0u; k < 4u; k++) {
            let t = t0 + (4u * w + k) / n;
            if (nmat_tile_has(tile, t)) {
                word |= tile_codes[4u * w + k] << (8u * k);
            }
        }
        out_codes[first + w] = word;
    }
}

// The tiled decode kernel (docs/GPU.md, "The tiled kernel"): a workgroup of 64 invocations
// decodes P texels at once. Each invocation computes one texel's input features; then every
// layer is a small matrix product over workgroup memory, each invocation computing tiles of
// 4 rows × 4 texels (16 accumulators in registers) so that every weight read serves 4 texels
// and every activation read serves 4 rows. Bit-identical with `nmat_decode` (texel.wgsl) and
// with the CPU.
//
// Prepended by tiled.rs (per material shape): `const P` (texels per workgroup, a multiple of 4
// up to 64), `const WMAX` (the widest layer rounded up to 4), `const CH` (channels), `const
// PART` (0; 1 or 2 in a pipeline that times the features or the layers alone, with
// `stand_in_features`) and `fn layers(lid)`, which calls `layer` once per layer with its widths
// as literals, a barrier after each (`features_sink` instead in a pipeline timing the
// features). Then texel.wgsl (the decoder), the input features for the material's latent layout
// (features.rs: features.wgsl and `nmat_texel_features`), decode.wgsl (bindings), one of
// tiled_i32.wgsl / tiled_dot4.wgsl (where activations live and how a tile's products are
// formed), requant.wgsl (`nmat_requant_with`), this file, then batch.wgsl.
//
// Per layer (its record's NMAT_LAYER_PACKED_AT) its packed weights in `nmat_desc`: rows padded
// to a multiple of 4 rows and 4 columns, 4 int8 weights per word (column 4j + b in byte b of
// word j); at NMAT_LAYER_REQUANT_AT its row table, a NmatRequantRow per (padded) row (layout.rs):
// bias (the 8-bit-product kernel adds 128 × the row's weight sum, see tiled_dot4.wgsl),
// multiplier m, shift s, u (0 for the 64-bit path, else the shift of the 32-bit one),
// m' = m >> (s − u), m' / 2^u as f32 bits, and the saturation range lo, hi.

// The codes of this workgroup, one per u32, in output order (texel, then channel).
var<workgroup> tile_codes: array<u32, P * CH>;

// Layer `l` (its inputs in `kw` words of 4 per row, its outputs in `row_groups` groups of 4
// rows) from activation buffer `src` into the other one, or into `tile_codes` if `last`.
fn layer(lid: u32, l: u32, kw: u32, row_groups: u32, src: u32, last: bool) {
    let lb = nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_WORDS * l;
    let frac = nmat_desc[lb + NMAT_LAYER_OUT_FRAC_BITS];
    let gelu = nmat_desc[lb + NMAT_LAYER_HARD_GELU] == 1u;
    let weights_at = nmat_desc[lb + NMAT_LAYER_PACKED_AT];
    let rows_at = nmat_desc[lb + NMAT_LAYER_REQUANT_AT];
    let n = params.out_channels;
    // Neighbouring invocations take neighbouring texels of the same rows: one weight word
    // serves the whole subgroup.
    for (var item = lid; item < row_groups * (P / 4u); item += 64u) {
        let o0 = 4u * (item / (P / 4u));
        let t0 = 4u * (item % (P / 4u));
        if (last && (o0 >= CH || ((params.channel_mask >> o0) & 15u) == 0u)) {
            continue;
        }
        let acc = mac4(src, t0, weights_at + o0 * kw, kw);
        var v = array<vec4<i32>, 4>();
        for (var r = 0u; r < 4u; r++) {
            let row = nmat_requant_table(rows_at + NMAT_REQUANT_WORDS * (o0 + r));
            for (var j = 0u; j < 4u; j++) {
                var z = nmat_requant_with(acc[r][j] + row.bias, row);
                if (gelu) {
                    z = nmat_hard_gelu(z, frac);
                }
                v[r][j] = z;
            }
        }
        if (!last) {
            put_outputs(1u - src, o0, t0, v);
            continue;
        }
        for (var r = 0u; r < 4u; r++) {
            let o = o0 + r;
            if (o < CH && (params.channel_mask & (1u << o)) != 0u) {
                let slot = countOneBits(params.channel_mask & ((1u << o) - 1u));
                for (var j = 0u; j < 4u; j++) {
                    let code = clamp((v[r][j] * 255 + (1 << (frac - 1u))) >> frac, 0, 255);
                    tile_codes[(t0 + j) * n + slot] = u32(code);
                }
            }
        }
    }
}

// For a pipeline that times the input features alone (tiled.rs, `PART == 1u`, called in place
// of the layers): each texel's staged features folded into its codes, so that no compiler drops
// them as never read.
fn features_sink(lid: u32) {
    let n = params.out_channels;
    for (var t = lid; t < P; t += 64u) {
        var x = 0u;
        for (var j = 0u; j < WMAX / 4u; j++) {
            x ^= feature_word(j, t);
        }
        for (var c = 0u; c < n; c++) {
            tile_codes[t * n + c] = (x >> (8u * (c % 4u))) & 255u;
        }
    }
}

// Decodes `params.count` texels as `main` does (same requests, rectangle and packed output), P
// per workgroup.
@compute @workgroup_size(64)
fn tiled(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let first = (wg.x + wg.y * groups.x) * P;
    let inputs = nmat_desc[nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_INPUTS];
    for (var t = lid; t < P; t += 64u) {
        let index = first + t;
        if (index < params.count) {
            nmat_batch_features(index, inputs);
            put_features(t, inputs);
        }
    }
    workgroupBarrier();
    layers(lid);
    nmat_store_codes(first, lid, 64u);
}

// The tile cache's decode of a material's new tiles through this kernel (cache.rs; `params.mode`
// 2; the queue, the tiles and their slots as batch.wgsl reads and writes them): four
// workgroups per tile, each 64 texels of it (rows 4k … 4k + 3 of the 16 × 16 tile) in batches of
// P. Bit-identical with cache_decode.wgsl, which decodes one texel per invocation.
@compute @workgroup_size(64)
fn tiled_cache(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let g = wg.x + wg.y * groups.x;
    if (g / 4u >= nmat_queued_count()) {
        return;
    }
    let tile = nmat_queued_tile(g / 4u);
    let inputs = nmat_desc[nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_INPUTS];
    for (var b = 0u; b < 64u / P; b++) {
        // The batch's first texel in the tile.
        let t0 = 64u * (g % 4u) + b * P;
        for (var t = lid; t < P; t += 64u) {
            if (nmat_tile_has(tile, t0 + t)) {
                let xy = nmat_tile_texel(tile, t0 + t);
                nmat_texel_features(i32(xy.x), i32(xy.y), tile.mip);
                put_features(t, inputs);
            }
        }
        workgroupBarrier();
        layers(lid);
        nmat_store_batch(tile, t0, lid, 64u);
        workgroupBarrier();
    }
}

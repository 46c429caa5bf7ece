// The unrolled kernels (docs/GPU.md, "The kernels"): one texel per invocation, no workgroup
// memory between layers and no barrier until the codes are written: unrolled.rs generates
// `network(t)` for the material's shape, each row's sum written out over the layer's input
// words, so that a layer's inputs are named values a GPU keeps in registers (not a private
// array indexed at run time, which GPUs keep in slow per-thread memory) and each weight word is
// loaded at a constant offset from the row's start; the rows are a loop whose values pass
// through `nmat_act_b` into the next layer's words. A word of four weights times four
// activations comes from the products file, unrolled_dot4.wgsl (`dot4I8Packed` on the high and
// low bytes, as the tiled dot4 kernel) or unrolled_i32.wgsl (32-bit multiply-adds); each row's
// sum is the CPU's accumulator. Requantization, hardGELU and codes as in the tiled kernels
// (requant.wgsl). Bit-identical with `nmat_decode` (texel.wgsl).
//
// Prepended by unrolled.rs: `const P` (64: texels per workgroup, one per invocation), `const
// CH` (channels), `const PART` (as in tiled.wgsl) and `fn network(t)`. Then texel.wgsl, the
// input features (features.rs), decode.wgsl, requant.wgsl, the products file,
// unrolled_network.wgsl, this file and batch.wgsl.

// The codes of this workgroup, one per u32, in output order (texel, then channel).
var<workgroup> tile_codes: array<u32, P * CH>;

// Channel `o`'s code (`frac` fraction bits) of texel `t` into tile_codes, where the mask
// selects it.
fn nmat_u_code(t: u32, o: u32, frac: u32, z: i32) {
    let mask = params.channel_mask;
    if ((mask & (1u << o)) != 0u) {
        let slot = countOneBits(mask & ((1u << o) - 1u));
        let code = clamp((z * 255 + (1 << (frac - 1u))) >> frac, 0, 255);
        tile_codes[t * params.out_channels + slot] = u32(code);
    }
}

// For a pipeline that times the input features alone (`PART == 1u`, in place of `network`): the
// texel's features folded into its codes, so that no compiler drops them as never read.
fn features_sink(t: u32) {
    let inputs = nmat_desc[nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_INPUTS];
    var x = 0u;
    for (var j = 0u; j < (inputs + 3u) / 4u; j++) {
        let f = nmat_u_features(j, inputs);
        x ^= nmat_u_fold(f);
    }
    for (var c = 0u; c < params.out_channels; c++) {
        tile_codes[t * params.out_channels + c] = (x >> (8u * (c % 4u))) & 255u;
    }
}

// Decodes `params.count` texels as `main` does (same requests, rectangle and packed output), one
// per invocation.
@compute @workgroup_size(64)
fn unrolled(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let first = (wg.x + wg.y * groups.x) * P;
    let index = first + lid;
    if (index < params.count) {
        nmat_batch_features(index, nmat_desc[nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_INPUTS]);
        if (PART == 1u) {
            features_sink(lid);
        } else {
            network(lid);
        }
    }
    workgroupBarrier();
    nmat_store_codes(first, lid, 64u);
}

// The tile cache's decode of a material's new tiles through this kernel (cache.rs; `params.mode`
// 2; the queue, the tiles and their slots as batch.wgsl reads and writes them): four
// workgroups per tile, one texel of it per invocation. Bit-identical with cache_decode.wgsl.
@compute @workgroup_size(64)
fn unrolled_cache(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let g = wg.x + wg.y * groups.x;
    if (g / 4u >= nmat_queued_count()) {
        return;
    }
    let tile = nmat_queued_tile(g / 4u);
    let t0 = 64u * (g % 4u);
    if (nmat_tile_has(tile, t0 + lid)) {
        let xy = nmat_tile_texel(tile, t0 + lid);
        nmat_texel_features(i32(xy.x), i32(xy.y), tile.mip);
        network(lid);
    }
    workgroupBarrier();
    nmat_store_batch(tile, t0, lid, 64u);
}

// The matrix kernel (docs/GPU.md, "The matrix kernel"): every layer as 16×16×16 cooperative
// matrix multiply-adds (tensor cores), bit-identical with `nmat_decode` (texel.wgsl) and the CPU.
// A workgroup is NW subgroups of SG invocations. It stages every layer's int8 weights as f16 in
// workgroup memory once (or reads them from a storage buffer), then decodes BATCHES batches of
// P = 16 · NW · TB texels: one invocation per texel computes its input features; then each
// subgroup takes its own 16 · TB texels through every layer: per block of 16 output rows, two
// products over the fan-in in steps of 16 — the weights times the activations' high bytes and
// times their low bytes — accumulated in registers, then combined, biased, requantized and
// activated in i32 and written back over the activations.
//
// Exactness: an i16 activation a is 256 · h + l with h = a >> 8 in [−128, 127] and l = a & 255
// in [0, 255], both exact in f16 (integers up to 2^11 are), as is every int8 weight. Each
// product w · h or w · l is an integer below 2^15 in magnitude, and every partial sum of a row
// over a fan-in K ≤ 128 (MAX_WIDTH) is an integer of magnitude at most K · 127 · 255 < 2^22,
// which f32 (24-bit significand) holds exactly: whatever order or grouping the matrix unit sums
// in, no rounding happens. Then Σ w · a = 256 · Σ w · h + Σ w · l in i32 (below 2^31, as on the
// CPU).
//
// Prepended by matrix.rs (per material shape): the `enable` directives, `const P`, `const NW`,
// `const BATCHES`, `const SG` (a subgroup's invocations), `const WMAX` (the widest layer rounded
// up to 16), `const CH` (channels), `const WTOTAL` (the weights, f16), the strides `AS` and
// `SS`, `const SB` (16 · SS), `const PAIRED` and `const PARTS` (the products' round trip below),
// `const PER_LANE`, `const PART` (0; 1 or 2 in a pipeline that times the features or the layers
// alone, with `stand_in_features`), the weights (below), `fn stage_weights(lid)` calling `stage`
// per layer (or nothing) and `fn layers(lane, warp)` (`features_sink` instead in a pipeline
// timing the features): per layer its products with the block counts and offsets as literals
// (the accumulators of all its row blocks live in registers), then per row block its products
// through `sums` into `finish`: the high bytes' products, a barrier, `collect`, a barrier, the
// low bytes', a barrier, `finish`, a barrier — or, PAIRED, both stored at once, a barrier,
// `finish`, a barrier (half the barriers and no private copy, for twice the memory of `sums`).
// Then texel.wgsl, the input features (features.rs), decode.wgsl, requant.wgsl, this file and
// batch.wgsl.
// Weights and row tables are the tiled kernels' (tiled.wgsl), the bias without the dot4
// kernel's 128 · Σ w.

// `weights16`: every layer's weights, row o and column k of a layer at woff + o · ws + k (ws:
// its fan-in padded with zeros to a multiple of 16, plus a pad against bank conflicts; rows
// padded with zeros to a multiple of 16): the A operands, row-major. In workgroup memory, where
// `stage_weights` stages them (matrix_stage.wgsl), or (`NMAT_WGPU_MATRIX_WEIGHTS=storage`) a
// read-only storage buffer of the same layout without the pad, which the loads read through the
// GPU's caches (matrix.rs declares it; `stage_weights` then does nothing).
// Activations, row k of texel t at k · AS + t (AS = P + a pad), high and low bytes apart: the B
// operands, row-major. Subgroup w reads and writes only its texels [16 · TB · w,
// 16 · TB · (w + 1)). Rows past a layer's width hold zeros or earlier finite values, and meet
// zero weights.
var<workgroup> act_hi: array<f16, WMAX * AS>;
var<workgroup> act_lo: array<f16, WMAX * AS>;
// Per subgroup and texel block, one row block of products (16 rows of SS = 16 + a pad, row-
// major): first the products with the high bytes, then with the low bytes — or, where PAIRED
// (PARTS = 2), both at once, the low bytes' LO = SB elements after the high bytes'.
var<workgroup> sums: array<f32, SB * PARTS * TB * NW>;
const LO: u32 = (PARTS - 1u) * SB;
// The codes of this batch, one per u32, in output order (texel, then channel).
var<workgroup> tile_codes: array<u32, P * CH>;
// This invocation's share of a subgroup's products with the high bytes (256 · TB / SG; not
// PAIRED).
var<private> hi_part: array<i32, PER_LANE>;

// Activation `a` (an i16 value) of row k, texel t, split into its bytes.
fn put_activation(k: u32, t: u32, a: i32) {
    act_hi[k * AS + t] = f16(a >> 8u);
    act_lo[k * AS + t] = f16(a & 255);
}

// This invocation's place in a subgroup's row block: row lane % 16 of it, and texels
// lane / 16 + k · (SG / 16) of the subgroup's 16 · TB, k < PER_LANE; `sum_at` is where the
// product of row r and texel j is.
fn sum_at(warp: u32, r: u32, j: u32) -> u32 {
    return SB * PARTS * (warp * TB + j / 16u) + r * SS + j % 16u;
}

// This invocation's products with the high bytes, from `sums` into hi_part (exact integers).
fn collect(lane: u32, warp: u32) {
    for (var k = 0u; k < PER_LANE; k++) {
        hi_part[k] = i32(sums[sum_at(warp, lane % 16u, lane / 16u + k * (SG / 16u))]);
    }
}

// Row block `ob` of layer `l` (output fraction bits `frac`, `rows` rows, hardGELU where `gelu`:
// literals in the calls, which matrix.rs writes) for subgroup `warp`, from hi_part (or, PAIRED,
// `sums`) and the products with the low bytes in `sums`: bias, requantization and activation,
// into the activations (or, if `last`, the codes). Each invocation reads its row's table once.
fn finish(lane: u32, warp: u32, l: u32, ob: u32, last: bool, frac: u32, rows: u32, gelu: bool) {
    let o = 16u * ob + lane % 16u;
    if (o >= rows || (last && (o >= CH || (params.channel_mask & (1u << o)) == 0u))) {
        return;
    }
    let lb = nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_WORDS * l;
    let row = nmat_requant_table(nmat_desc[lb + NMAT_LAYER_REQUANT_AT] + NMAT_REQUANT_WORDS * o);
    let n = params.out_channels;
    var slot = 0u;
    if (last) {
        slot = countOneBits(params.channel_mask & ((1u << o) - 1u));
    }
    for (var k = 0u; k < PER_LANE; k++) {
        let j = lane / 16u + k * (SG / 16u);
        let at = sum_at(warp, lane % 16u, j);
        var hi = hi_part[k];
        if (PAIRED) {
            hi = i32(sums[at]);
        }
        let acc = 256 * hi + i32(sums[at + LO]) + row.bias;
        var z = nmat_requant_with(acc, row);
        if (gelu) {
            z = nmat_hard_gelu(z, frac);
        }
        let t = 16u * TB * warp + j;
        if (!last) {
            put_activation(o, t, z);
        } else {
            let code = clamp((z * 255 + (1 << (frac - 1u))) >> frac, 0, 255);
            tile_codes[t * n + slot] = u32(code);
        }
    }
}

// The input features of texel `index` of the request list or rectangle into activation column
// `t`, zeros up to WMAX.
fn features(t: u32, index: u32, inputs: u32) {
    nmat_batch_features(index, inputs);
    put_features(t, inputs);
}

// nmat_act_a[0..inputs) into activation column `t`, zeros up to WMAX.
fn put_features(t: u32, inputs: u32) {
    for (var k = 0u; k < WMAX; k++) {
        put_activation(k, t, select(0, nmat_act_a[min(k, 127u)], k < inputs));
    }
}

// For a pipeline that times the input features alone (matrix.rs, `PART == 1u`, called in place
// of the layers): each texel's staged activations folded into its codes, so that no compiler
// drops them as never read.
fn features_sink(lane: u32, warp: u32) {
    let n = params.out_channels;
    for (var t = warp * SG + lane; t < P; t += SG * NW) {
        var x = 0.0;
        for (var k = 0u; k < WMAX; k++) {
            x += f32(act_hi[k * AS + t]) + f32(act_lo[k * AS + t]);
        }
        for (var c = 0u; c < n; c++) {
            tile_codes[t * n + c] = u32(abs(x)) & 255u;
        }
    }
}

// Decodes `params.count` texels as `main` does (same requests, rectangle and packed output),
// P · BATCHES per workgroup: the body of the entry point `matrix` (matrix.rs writes it, with
// invocation `lid` of workgroup `g`, in subgroup `warp` as its lane `lane`).
fn matrix_batches(lid: u32, warp: u32, lane: u32, g: u32) {
    stage_weights(lid);
    let inputs = nmat_desc[nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_INPUTS];
    for (var batch = 0u; batch < BATCHES; batch++) {
        let first = (g * BATCHES + batch) * P;
        if (first >= params.count) {
            break;
        }
        for (var t = lid; t < P; t += SG * NW) {
            if (first + t < params.count) {
                features(t, first + t, inputs);
            }
        }
        workgroupBarrier();
        layers(lane, warp);
        nmat_store_codes(first, lid, SG * NW);
        workgroupBarrier();
    }
}

// The tile cache's decode of a material's new tiles through this kernel (cache.rs; `params.mode`
// 2; the queue, the tiles and their slots as batch.wgsl reads and writes them): one
// workgroup per tile, which stages the weights once and takes the tile's 256 texels in batches of
// P (the last batch reaching past the tile where P does not divide 256, as three subgroups'
// batches of 48 do: batch.wgsl leaves those texels out). Bit-identical with
// cache_decode.wgsl, which decodes one texel per invocation: a texel outside an edge tile's mip
// leaves its activation column as it was (finite values: each texel's column meets only its own
// products) and its codes are not written. The body of the entry point `matrix_cache`.
fn matrix_tiles(lid: u32, warp: u32, lane: u32, g: u32) {
    if (g >= nmat_queued_count()) {
        return;
    }
    stage_weights(lid);
    let tile = nmat_queued_tile(g);
    let inputs = nmat_desc[nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_INPUTS];
    for (var b = 0u; b < (256u + P - 1u) / P; b++) {
        let t0 = b * P;
        for (var t = lid; t < P; t += SG * NW) {
            if (nmat_tile_has(tile, t0 + t)) {
                let xy = nmat_tile_texel(tile, t0 + t);
                nmat_texel_features(i32(xy.x), i32(xy.y), tile.mip);
                put_features(t, inputs);
            }
        }
        workgroupBarrier();
        layers(lane, warp);
        nmat_store_batch(tile, t0, lid, SG * NW);
        workgroupBarrier();
    }
}

// The matrix kernel's weights staged in workgroup memory (matrix.wgsl, `weights16`): every
// workgroup converts the tiled kernels' packed int8 table to f16 once, before its batches.
// Included by matrix.rs unless the weights are read from a storage buffer.

var<workgroup> weights16: array<f16, WTOTAL>;

// Layer `l`'s weights (the tiled kernels' packed int8 table) into weights16 from `woff`,
// `opad` rows of `kpad` columns `ws` apart, zeros outside the layer.
fn stage(lid: u32, l: u32, kpad: u32, opad: u32, woff: u32, ws: u32) {
    let lb = nmat_desc[NMAT_DESC_LAYERS_AT] + NMAT_LAYER_WORDS * l;
    let kw = (nmat_desc[lb + NMAT_LAYER_INPUTS] + 3u) / 4u;
    let rows = (nmat_desc[lb + NMAT_LAYER_OUTPUTS] + 3u) / 4u * 4u;
    let weights_at = nmat_desc[lb + NMAT_LAYER_PACKED_AT];
    let row_words = kpad / 4u;
    for (var i = lid; i < opad * row_words; i += SG * NW) {
        let o = i / row_words;
        let j = i % row_words;
        var word = 0;
        if (o < rows && j < kw) {
            word = bitcast<i32>(nmat_desc[weights_at + o * kw + j]);
        }
        let at = woff + o * ws + 4u * j;
        weights16[at] = f16(extractBits(word, 0u, 8u));
        weights16[at + 1u] = f16(extractBits(word, 8u, 8u));
        weights16[at + 2u] = f16(extractBits(word, 16u, 8u));
        weights16[at + 3u] = f16(extractBits(word, 24u, 8u));
    }
}

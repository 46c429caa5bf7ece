// The tiled kernel's 32-bit products: activations as i32 in workgroup memory, buffer b, row k,
// texel t at tile[(b · WMAX + k) · P + t]; each int8 weight extracted from its word.

var<workgroup> tile: array<i32, 2u * WMAX * P>;

// nmat_act_a[0..inputs) of texel t into buffer 0, zeros up to WMAX.
fn put_features(t: u32, inputs: u32) {
    for (var k = 0u; k < WMAX; k++) {
        tile[k * P + t] = select(0, nmat_act_a[min(k, 127u)], k < inputs);
    }
}

// Σ_k w[o0 + r][k] · x[k][t0 + j] for the 4 × 4 tile (r, j), `kw` words of 4 weights per row
// from nmat_desc[w0] (rows kw words apart).
fn mac4(src: u32, t0: u32, w0: u32, kw: u32) -> array<vec4<i32>, 4> {
    var acc = array<vec4<i32>, 4>();
    let base = src * WMAX * P + t0;
    for (var j = 0u; j < kw; j++) {
        let i = base + 4u * j * P;
        let x0 = vec4<i32>(tile[i], tile[i + 1u], tile[i + 2u], tile[i + 3u]);
        let x1 = vec4<i32>(tile[i + P], tile[i + P + 1u], tile[i + P + 2u], tile[i + P + 3u]);
        let i2 = i + 2u * P;
        let x2 = vec4<i32>(tile[i2], tile[i2 + 1u], tile[i2 + 2u], tile[i2 + 3u]);
        let i3 = i + 3u * P;
        let x3 = vec4<i32>(tile[i3], tile[i3 + 1u], tile[i3 + 2u], tile[i3 + 3u]);
        for (var r = 0u; r < 4u; r++) {
            let w = bitcast<i32>(nmat_desc[w0 + r * kw + j]);
            acc[r] += extractBits(w, 0u, 8u) * x0 + extractBits(w, 8u, 8u) * x1
                + extractBits(w, 16u, 8u) * x2 + extractBits(w, 24u, 8u) * x3;
        }
    }
    return acc;
}

// Rows 4j … 4j + 3 of texel t in buffer 0 as one word (tiled.wgsl's `features_sink`).
fn feature_word(j: u32, t: u32) -> u32 {
    let i = 4u * j * P + t;
    return bitcast<u32>(tile[i] ^ tile[i + P] ^ tile[i + 2u * P] ^ tile[i + 3u * P]);
}

// The tile's outputs (row o0 + r, texel t0 + j) into buffer `dst`.
fn put_outputs(dst: u32, o0: u32, t0: u32, v: array<vec4<i32>, 4>) {
    for (var r = 0u; r < 4u; r++) {
        let i = (dst * WMAX + o0 + r) * P + t0;
        tile[i] = v[r].x;
        tile[i + 1u] = v[r].y;
        tile[i + 2u] = v[r].z;
        tile[i + 3u] = v[r].w;
    }
}

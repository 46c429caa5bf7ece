// The tiled kernel's 8-bit products (`dot4I8Packed`, W8A16 exactly): an i16 activation a is
// 256 · h + l with h = a >> 8 in [−128, 127] and l = a & 255; stored as two signed bytes h and
// l − 128 (= l ^ 128), 4 rows per word: buffer b, word j (rows 4j..4j+3), texel t at
// hi_tile / lo_tile[(b · WMAX / 4 + j) · P + t]. Then
//   Σ w · a = 256 · Σ w · h + Σ w · (l − 128) + 128 · Σ w,
// two dot4I8Packed per 4 weights; tiled.rs folds 128 · Σ w into the row's bias. Both partial sums
// stay below 2^22 in magnitude (fan-in ≤ 128, |w| ≤ 127, bytes in [−128, 127]).

var<workgroup> hi_tile: array<u32, WMAX / 2u * P>;
var<workgroup> lo_tile: array<u32, WMAX / 2u * P>;

// The high and low byte words of four activations (row 4j + b in byte b).
fn split4(a: vec4<i32>) -> vec2<u32> {
    let h = vec4<u32>(bitcast<vec4<u32>>(a >> vec4<u32>(8u)) & vec4<u32>(255u));
    let l = (bitcast<vec4<u32>>(a) & vec4<u32>(255u)) ^ vec4<u32>(128u);
    return vec2<u32>(
        h.x | (h.y << 8u) | (h.z << 16u) | (h.w << 24u),
        l.x | (l.y << 8u) | (l.z << 16u) | (l.w << 24u),
    );
}

// nmat_act_a[0..inputs) of texel t into buffer 0, zeros up to WMAX.
fn put_features(t: u32, inputs: u32) {
    for (var j = 0u; j < WMAX / 4u; j++) {
        var a = vec4<i32>(0);
        for (var b = 0u; b < 4u; b++) {
            let k = 4u * j + b;
            a[b] = select(0, nmat_act_a[min(k, 127u)], k < inputs);
        }
        let s = split4(a);
        hi_tile[j * P + t] = s.x;
        lo_tile[j * P + t] = s.y;
    }
}

// Σ_k w[o0 + r][k] · x[k][t0 + j] − 128 · Σ_k w[o0 + r][k] for the 4 × 4 tile (r, j).
fn mac4(src: u32, t0: u32, w0: u32, kw: u32) -> array<vec4<i32>, 4> {
    var high = array<vec4<i32>, 4>();
    var low = array<vec4<i32>, 4>();
    let base = src * (WMAX / 4u) * P + t0;
    for (var j = 0u; j < kw; j++) {
        let i = base + j * P;
        let h = vec4<u32>(hi_tile[i], hi_tile[i + 1u], hi_tile[i + 2u], hi_tile[i + 3u]);
        let l = vec4<u32>(lo_tile[i], lo_tile[i + 1u], lo_tile[i + 2u], lo_tile[i + 3u]);
        for (var r = 0u; r < 4u; r++) {
            let w = nmat_desc[w0 + r * kw + j];
            high[r] += vec4<i32>(dot4I8Packed(w, h.x), dot4I8Packed(w, h.y),
                dot4I8Packed(w, h.z), dot4I8Packed(w, h.w));
            low[r] += vec4<i32>(dot4I8Packed(w, l.x), dot4I8Packed(w, l.y),
                dot4I8Packed(w, l.z), dot4I8Packed(w, l.w));
        }
    }
    var acc = array<vec4<i32>, 4>();
    for (var r = 0u; r < 4u; r++) {
        acc[r] = (high[r] << vec4<u32>(8u)) + low[r];
    }
    return acc;
}

// Rows 4j … 4j + 3 of texel t in buffer 0 as one word (tiled.wgsl's `features_sink`).
fn feature_word(j: u32, t: u32) -> u32 {
    return hi_tile[j * P + t] ^ lo_tile[j * P + t];
}

// The tile's outputs (row o0 + r, texel t0 + j) into buffer `dst`, one word pair per texel.
fn put_outputs(dst: u32, o0: u32, t0: u32, v: array<vec4<i32>, 4>) {
    for (var j = 0u; j < 4u; j++) {
        let s = split4(vec4<i32>(v[0][j], v[1][j], v[2][j], v[3][j]));
        let i = (dst * (WMAX / 4u) + o0 / 4u) * P + t0 + j;
        hi_tile[i] = s.x;
        lo_tile[i] = s.y;
    }
}

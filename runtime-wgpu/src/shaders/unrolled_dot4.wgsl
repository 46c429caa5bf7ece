// The unrolled kernel's 8-bit products (`dot4I8Packed`, as tiled_dot4.wgsl): four activations
// a = 256 · h + l as a word of their high bytes h and a word of their low bytes l − 128 (= l ^
// 128), row 4j + b in byte b; a word of four weights times them is
//   (dot4I8Packed(w, h) << 8) + dot4I8Packed(w, l ^ 128)
// (256 · Σ w · h + Σ w · (l − 128); 128 · Σ w is folded into the row's bias by tiled.rs). Each
// partial sum stays below 2^30 in magnitude; the row's total is the exact accumulator.

alias NmatWord = vec2<u32>;

// Four activations as a high and a low word.
fn nmat_u_word(a: vec4<i32>) -> NmatWord {
    let h = vec4<u32>(bitcast<vec4<u32>>(a >> vec4<u32>(8u)) & vec4<u32>(255u));
    let l = (bitcast<vec4<u32>>(a) & vec4<u32>(255u)) ^ vec4<u32>(128u);
    return vec2<u32>(
        h.x | (h.y << 8u) | (h.z << 16u) | (h.w << 24u),
        l.x | (l.y << 8u) | (l.z << 16u) | (l.w << 24u),
    );
}

// Four weights (word `w`, weight b in byte b) times four activations.
fn nmat_u_mac(w: u32, x: NmatWord) -> i32 {
    return (dot4I8Packed(w, x.x) << 8u) + dot4I8Packed(w, x.y);
}

// Every bit of a word folded into one u32 (for a pipeline that times the features alone).
fn nmat_u_fold(x: NmatWord) -> u32 {
    return x.x ^ x.y;
}

// The unrolled kernel's 32-bit products (as tiled_i32.wgsl): four activations as a vec4<i32>;
// a word of four weights times them is four 32-bit multiply-adds, each int8 weight extracted
// (sign-extended) from its byte.

alias NmatWord = vec4<i32>;

// Four activations as they are.
fn nmat_u_word(a: vec4<i32>) -> NmatWord {
    return a;
}

// Four weights (word `w`, weight b in byte b) times four activations.
fn nmat_u_mac(w: u32, x: NmatWord) -> i32 {
    let s = bitcast<i32>(w);
    return extractBits(s, 0u, 8u) * x.x + extractBits(s, 8u, 8u) * x.y
        + extractBits(s, 16u, 8u) * x.z + extractBits(s, 24u, 8u) * x.w;
}

// Every bit of a word folded into one u32 (for a pipeline that times the features alone).
fn nmat_u_fold(x: NmatWord) -> u32 {
    let u = bitcast<vec4<u32>>(x);
    return u.x ^ u.y ^ u.z ^ u.w;
}

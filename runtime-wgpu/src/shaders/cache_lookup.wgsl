// What the mark pass (cache.wgsl) and the resolve pass (cache_resolve.wgsl) share: both run one
// invocation per lookup of the caller's buffer (`nmat_cache_lookups`, from word
// `nmat_cache_params.in_offset`) through the filter of cache_sample.wgsl; they differ in their
// `nmat_fetch` (mark the texel's tile, or read it).

// The invocation's index in a dispatch of 64-invocation workgroups spread over x and y.
fn nmat_cache_index(id: vec3<u32>, groups: vec3<u32>) -> u32 {
    return id.x + id.y * groups.x * 64u;
}

// Lookups are 8 words: u, v, lod (f32 bits), material (its index; past the list: no lookup),
// filter (NMAT_NEAREST …), three random numbers for NMAT_STOCHASTIC (f32 bits).
fn nmat_cache_lookup(i: u32) -> array<f32, 16> {
    let at = nmat_cache_params.in_offset + NMAT_LOOKUP_WORDS * i;
    let material = nmat_cache_lookups[at + NMAT_LOOKUP_MATERIAL];
    if (material >= nmat_cache_params.materials) {
        return array<f32, 16>();
    }
    let uv = bitcast<vec2<f32>>(vec2<u32>(nmat_cache_lookups[at + NMAT_LOOKUP_U], nmat_cache_lookups[at + NMAT_LOOKUP_V]));
    let lod = bitcast<f32>(nmat_cache_lookups[at + NMAT_LOOKUP_LOD]);
    let rnd = bitcast<vec3<f32>>(vec3<u32>(
        nmat_cache_lookups[at + NMAT_LOOKUP_RANDOM_0],
        nmat_cache_lookups[at + NMAT_LOOKUP_RANDOM_1],
        nmat_cache_lookups[at + NMAT_LOOKUP_RANDOM_2],
    ));
    let mode = nmat_cache_lookups[at + NMAT_LOOKUP_FILTER];
    return nmat_cache_sample(material, uv, lod, rnd, mode, nmat_cache_params.channels);
}

// The tile cache's resolve pass (cache.rs records it after the decode; docs/GPU.md, "The tile
// cache"): one invocation per lookup runs the filter of cache_sample.wgsl reading the cached
// codes. Its own module so that what it reads most binds read-only: the codes (plain loads,
// which GPUs cache near the cores, where an atomic load of a read-write buffer goes to the
// device-wide cache) and the material records (`nmat_cache_records`, a uniform block cache.rs
// prepends); the table stays read-write for the resolve-miss counter, and each tap's page word
// is loaded once per distinct page (cache_sample.wgsl). cache_lookup.wgsl follows this file.

@group(0) @binding(0) var<storage, read_write> nmat_cache_table: array<atomic<u32>>;
// The resolved values (the caller's buffer): f32 bits, `out_channels` per lookup.
@group(0) @binding(1) var<storage, read_write> nmat_cache_out: array<u32>;
@group(0) @binding(2) var<storage, read> nmat_cache_lookups: array<u32>;
@group(0) @binding(3) var<storage, read> nmat_cache_codes: array<u32>;
@group(0) @binding(4) var<uniform> nmat_cache_params: NmatCacheParams;

fn nmat_cache_word(i: u32) -> u32 {
    return atomicLoad(&nmat_cache_table[i]);
}

fn nmat_cache_code_word(i: u32) -> u32 {
    return nmat_cache_codes[i];
}

fn nmat_fetch(x: i32, y: i32, mip: u32, mask: u32) {
    nmat_cache_read(x, y, mip, mask);
}

// One invocation per lookup: the filtered values of the channels in `channels` (f32 bits, in
// channel order, `out_channels` per lookup) into `nmat_cache_out` from word `out_offset`; texels
// of tiles the cache lacks count as resolve misses.
@compute @workgroup_size(64)
fn nmat_cache_resolve(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = nmat_cache_index(id, groups);
    if (i >= nmat_cache_params.count) {
        return;
    }
    nmat_cache_misses = 0u;
    let values = nmat_cache_lookup(i);
    if (nmat_cache_misses != 0u) {
        atomicAdd(&nmat_cache_table[NMAT_CACHE_RESOLVE_MISSES], nmat_cache_misses);
    }
    var at = nmat_cache_params.out_offset + i * nmat_cache_params.out_channels;
    for (var c = 0u; c < 16u; c++) {
        if (((nmat_cache_params.channels >> c) & 1u) != 0u) {
            nmat_cache_out[at] = bitcast<u32>(values[c]);
            at += 1u;
        }
    }
}

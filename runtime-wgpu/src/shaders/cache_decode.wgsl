// The tile cache's decode of a neural material's new tiles (cache.rs; the queue is cache.wgsl's):
// four workgroups per tile of the material's decode queue, one texel of the tile per invocation
// decoded by `nmat_decode` (texel.wgsl; one decode per invocation keeps lavapipe's loop cap far
// away, docs/GPU.md) and its codes ORed into the tile's cleared slot.

@group(0) @binding(2) var<storage, read> nmat_cd_queue: array<u32>;
@group(0) @binding(3) var<storage, read_write> nmat_cd_codes: array<atomic<u32>>;
@group(0) @binding(4) var<uniform> nmat_cd: NmatCacheDecode;

@compute @workgroup_size(64)
fn nmat_cache_decode(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let g = (wg.x + wg.y * groups.x) / 4u;
    let t = 64u * ((wg.x + wg.y * groups.x) % 4u) + lid;
    let q = nmat_cd.queue_at;
    if (g >= nmat_cd_queue[q + NMAT_CACHE_QUEUE_COUNT]) {
        return;
    }
    let entry = q + NMAT_CACHE_QUEUE_WORDS + NMAT_CACHE_ENTRY_WORDS * g;
    let slot = nmat_cd_queue[entry + NMAT_CACHE_ENTRY_SLOT];
    let tile = nmat_cd_queue[entry + NMAT_CACHE_ENTRY_KEY];
    let mip = tile >> 26u;
    let x0 = 16u * (tile & 0x1FFFu);
    let y0 = 16u * ((tile >> 13u) & 0x1FFFu);
    let size = nmat_mip_size(mip);
    let n = nmat_channel_count();
    let x = x0 + t % 16u;
    let y = y0 + t / 16u;
    if (x < size.x && y < size.y) {
        nmat_decode(i32(x), i32(y), mip, NMAT_ALL_CHANNELS);
        for (var c = 0u; c < n; c++) {
            let byte = slot * nmat_cd.slot_words * 4u + t * n + c;
            atomicOr(&nmat_cd_codes[byte / 4u], nmat_codes[c] << (8u * (byte % 4u)));
        }
    }
}

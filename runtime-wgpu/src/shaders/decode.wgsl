// The decode kernel (`main`): requests or a rectangle, one texel per invocation, codes packed
// four per u32. texel.wgsl (the decoder itself) and the material's `nmat_desc` layout come with
// it (context.rs, tiled.rs and matrix.rs concatenate them).

// Four storage buffers: the most downlevel limits allow per stage. The int8 weights (widened to
// i32) and the per-row constants live in `nmat_desc` after the descriptors.
@group(0) @binding(0) var<storage, read> nmat_desc: array<u32>;
@group(0) @binding(1) var<storage, read> nmat_latents: array<u32>;
@group(0) @binding(2) var<storage, read> requests: array<i32>;
@group(0) @binding(3) var<storage, read_write> out_codes: array<u32>;
@group(0) @binding(4) var<uniform> params: Params;

// Texel `index` of a dispatch (x, y, mip as i32 bits): request `index` from word
// `params.in_offset` of `requests`, or texel `index` of the rectangle in row-major order.
fn texel_of(index: u32) -> vec3<i32> {
    if (params.mode == 0u) {
        let r = params.in_offset + 3u * index;
        return vec3<i32>(requests[r], requests[r + 1u], requests[r + 2u]);
    }
    let x = params.x0 + index % params.width;
    let y = params.y0 + index / params.width;
    return vec3<i32>(i32(x), i32(y), bitcast<i32>(params.mip));
}

// One workgroup's codes, one per u32, in output order (texel, then channel), before packing.
var<workgroup> staged: array<u32, 1024>;

// Decodes `params.count` texels (requests from word `params.in_offset` of `requests`, or a
// rectangle), 64 per workgroup, and writes their codes packed four per u32 (code i in byte
// i % 4 of word i / 4, so the buffer's bytes are the codes in order) from word
// `params.out_offset` of `out_codes`. A workgroup's codes start on a word boundary (64 texels
// hold a multiple of 4 codes); the last word of the last workgroup is padded with zeros.
@compute @workgroup_size(64)
fn main(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let group = wg.x + wg.y * groups.x;
    let index = group * 64u + lid;
    let n = params.out_channels;
    if (index < params.count) {
        let texel = texel_of(index);
        nmat_decode(texel.x, texel.y, bitcast<u32>(texel.z), params.channel_mask);
        var slot = lid * n;
        for (var c = 0u; c < nmat_desc[NMAT_DESC_CHANNEL_COUNT]; c++) {
            if ((params.channel_mask & (1u << c)) != 0u) {
                staged[slot] = nmat_codes[c];
                slot++;
            }
        }
    }
    workgroupBarrier();
    let first = group * 64u;
    let texels = select(0u, min(params.count - first, 64u), first < params.count);
    let count = texels * n;
    for (var w = lid; 4u * w < count; w += 64u) {
        var word = 0u;
        for (var k = 0u; k < 4u; k++) {
            if (4u * w + k < count) {
                word |= staged[4u * w + k] << (8u * k);
            }
        }
        out_codes[params.out_offset + first / 4u * n + w] = word;
    }
}

// Codes (packed four per u32, `channels` per texel, row-major over width × height) into a
// storage texture at (x0, y0): component c of the texel is code c / 255; components past
// `channels` are 0 (R, G, B) and 1 (A). The value written is (code + 1/4) / 255: a unorm8 store
// rounds it to the code whether the device rounds to nearest or toward zero.

struct Store {
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
    channels: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<storage, read> store_codes: array<u32>;
@group(0) @binding(1) var<uniform> store: Store;
@group(0) @binding(2) var store_target: texture_storage_2d<FORMAT, write>;

@compute @workgroup_size(8, 8)
fn store_texels(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= store.width || id.y >= store.height) {
        return;
    }
    let first = (id.y * store.width + id.x) * store.channels;
    var v = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    for (var c = 0u; c < store.channels; c++) {
        let i = first + c;
        let code = (store_codes[i / 4u] >> (8u * (i % 4u))) & 255u;
        v[c] = (f32(code) + 0.25) / 255.0;
    }
    textureStore(store_target, vec2<u32>(store.x0 + id.x, store.y0 + id.y), v);
}

// 32 `dot4I8Packed` per iteration (128 multiply-accumulates): 4 rounds of 8 chains, each
// feeding its own sum back as the next packed operand.
@compute @workgroup_size(64)
fn dot4(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let index = gid.x + gid.y * groups.x * 64u;
    let w = probe.multiplier;
    var a0 = index; var a1 = index + 1u; var a2 = index + 2u; var a3 = index + 3u;
    var a4 = index + 4u; var a5 = index + 5u; var a6 = index + 6u; var a7 = index + 7u;
    for (var i = 0u; i < probe.iterations; i++) {
        for (var r = 0; r < 4; r++) {
            a0 += bitcast<u32>(dot4I8Packed(a0, w)); a1 += bitcast<u32>(dot4I8Packed(a1, w));
            a2 += bitcast<u32>(dot4I8Packed(a2, w)); a3 += bitcast<u32>(dot4I8Packed(a3, w));
            a4 += bitcast<u32>(dot4I8Packed(a4, w)); a5 += bitcast<u32>(dot4I8Packed(a5, w));
            a6 += bitcast<u32>(dot4I8Packed(a6, w)); a7 += bitcast<u32>(dot4I8Packed(a7, w));
        }
    }
    sink[index] = a0 ^ a1 ^ a2 ^ a3 ^ a4 ^ a5 ^ a6 ^ a7;
}

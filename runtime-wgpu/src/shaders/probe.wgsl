// Peak-rate probes for `nmat_wgpu::measure`: register-only loops of 32-bit integer multiply-adds
// and (where the language has it) of `dot4I8Packed`, eight independent chains per invocation so
// the latency is covered. The sink keeps every chain alive.

struct Probe {
    iterations: u32,
    multiplier: u32,
    addend: u32,
    pad: u32,
}

@group(0) @binding(0) var<storage, read_write> sink: array<u32>;
@group(0) @binding(1) var<uniform> probe: Probe;

// 32 multiply-adds per iteration: 4 rounds of 8 chains.
@compute @workgroup_size(64)
fn mad(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let index = gid.x + gid.y * groups.x * 64u;
    let m = bitcast<i32>(probe.multiplier | 1u);
    let c = bitcast<i32>(probe.addend);
    let i0 = bitcast<i32>(index);
    var a0 = i0; var a1 = i0 + 1; var a2 = i0 + 2; var a3 = i0 + 3;
    var a4 = i0 + 4; var a5 = i0 + 5; var a6 = i0 + 6; var a7 = i0 + 7;
    for (var i = 0u; i < probe.iterations; i++) {
        for (var r = 0; r < 4; r++) {
            a0 = a0 * m + c; a1 = a1 * m + c; a2 = a2 * m + c; a3 = a3 * m + c;
            a4 = a4 * m + c; a5 = a5 * m + c; a6 = a6 * m + c; a7 = a7 * m + c;
        }
    }
    sink[index] = bitcast<u32>(a0 ^ a1 ^ a2 ^ a3 ^ a4 ^ a5 ^ a6 ^ a7);
}

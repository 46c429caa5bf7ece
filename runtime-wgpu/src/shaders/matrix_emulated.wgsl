// The cooperative matrix operations of the matrix kernel, emulated in scalar code, so that the
// kernel's structure (staging, features, the byte split, the products' round trip through
// workgroup memory, requantization, codes, the tile entry) runs and is tested for exactness on
// a device without matrix units (lavapipe in CI; `Context::emulate_matrix_for_testing`). Only
// the matrix instructions differ from matrix.wgsl's real kernel; matrix.rs writes the calls.
//
// A subgroup's 16 × 16 f32 accumulator is EMU = 256 / SG elements in each of its SG
// invocations: element e of lane `lane` is number i = lane + SG · e, row i / 16 and column
// i % 16; a layer's accumulators (one per row block) are an EmuAccumulators. A "loaded" operand is the offset of its first element, read at the multiply-add
// (nothing writes an operand between its load and its multiply-add). Every product and partial
// sum is an integer below 2^24 (matrix.wgsl), so the order of the sums does not matter.

const EMU: u32 = 256u / SG;
alias EmuAccumulators = array<array<f32, EMU>, WMAX / 16u>;

// Element `i` of act_hi (`hi`) or act_lo.
fn emu_act(hi: bool, i: u32) -> f32 {
    if (hi) {
        return f32(act_hi[i]);
    }
    return f32(act_lo[i]);
}

// acc[ob] += A · B for the A operand at weights16[a], rows `lda` apart, and the B operand at
// act_hi[b] (`hi`) or act_lo[b], rows AS apart (both row-major, as coopLoadT reads them).
fn emu_mma(
    acc: ptr<function, EmuAccumulators>,
    ob: u32,
    a: u32,
    lda: u32,
    hi: bool,
    b: u32,
    lane: u32,
) {
    for (var e = 0u; e < EMU; e++) {
        let i = lane + SG * e;
        let w = a + i / 16u * lda;
        let x = b + i % 16u;
        // Written out: lavapipe caps a shader's loop iterations (docs/GPU.md, "Known problems").
        var s = f32(weights16[w]) * emu_act(hi, x);
        s += f32(weights16[w + 1u]) * emu_act(hi, x + AS);
        s += f32(weights16[w + 2u]) * emu_act(hi, x + 2u * AS);
        s += f32(weights16[w + 3u]) * emu_act(hi, x + 3u * AS);
        s += f32(weights16[w + 4u]) * emu_act(hi, x + 4u * AS);
        s += f32(weights16[w + 5u]) * emu_act(hi, x + 5u * AS);
        s += f32(weights16[w + 6u]) * emu_act(hi, x + 6u * AS);
        s += f32(weights16[w + 7u]) * emu_act(hi, x + 7u * AS);
        s += f32(weights16[w + 8u]) * emu_act(hi, x + 8u * AS);
        s += f32(weights16[w + 9u]) * emu_act(hi, x + 9u * AS);
        s += f32(weights16[w + 10u]) * emu_act(hi, x + 10u * AS);
        s += f32(weights16[w + 11u]) * emu_act(hi, x + 11u * AS);
        s += f32(weights16[w + 12u]) * emu_act(hi, x + 12u * AS);
        s += f32(weights16[w + 13u]) * emu_act(hi, x + 13u * AS);
        s += f32(weights16[w + 14u]) * emu_act(hi, x + 14u * AS);
        s += f32(weights16[w + 15u]) * emu_act(hi, x + 15u * AS);
        (*acc)[ob][e] += s;
    }
}

// Accumulator acc[ob] into sums[at], rows `stride` apart (row-major, as coopStoreT writes it).
fn emu_store(acc: ptr<function, EmuAccumulators>, ob: u32, at: u32, stride: u32, lane: u32) {
    for (var e = 0u; e < EMU; e++) {
        let i = lane + SG * e;
        sums[at + i / 16u * stride + i % 16u] = (*acc)[ob][e];
    }
}

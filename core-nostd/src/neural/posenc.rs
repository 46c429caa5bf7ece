//! Tiled triangle-wave positional encoding (docs/FORMAT.md §6.4), after the NTC paper: the
//! 4-nearest-cell features say *which* cells surround a texel but not *where* in them it lies;
//! triangle waves of the texel coordinate with periods 4, 8, 16, … texels, in two phases a quarter
//! period apart, tell the network.

/// Triangle wave of frequency `k` and `phase` (0 or 1) at texel coordinate `x`, in Q.`frac_bits`.
/// The value is `|2a − 2P| / 2P` with `P = 2^(k+2)` and `a = (2x + 1 + phase·P/2) mod 2P`; its
/// denominator is `2^(k+3)`, so it is exact whenever `k + 3 ≤ frac_bits` (checked by parse).
pub fn triangle_q(x: u32, k: u8, phase: u32, frac_bits: u8) -> i16 {
    let k = u32::from(k.min(12));
    let period = 1u64 << (k + 2);
    // `% (2 * period)` on a power of two, as a mask (a division per feature is measurable).
    let a = (2 * u64::from(x) + 1 + u64::from(phase.min(1)) * (period / 2)) & (2 * period - 1);
    let magnitude = (2 * a).abs_diff(2 * period);
    let shift = i64::from(frac_bits) - i64::from(k as u8 + 3);
    // magnitude < 2^(k+3); scaled by 2^(f−k−3) it stays below 2^f ≤ 2^14.
    (if shift >= 0 { magnitude << shift } else { magnitude >> -shift }) as i16
}

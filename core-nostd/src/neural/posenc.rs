//! Tiled triangle-wave positional encoding (docs/FORMAT.md §6.4), after the NTC paper: the
//! 4-nearest-cell features say *which* cells surround a texel but not *where* in them it lies;
//! triangle waves of the texel coordinate with periods 4, 8, 16, … texels, in two phases a quarter
//! period apart, tell the network.

#[cfg(feature = "alloc")]
use crate::limits::MAX_PE_FREQUENCIES;

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

/// Lanes of the positional encoding of a texel: the features of `frequencies` frequencies, 4
/// each, in the order x phase 0, x phase 1, y phase 0, y phase 1 (FORMAT.md §6.4), as
/// [`triangle_q`] gives them, with everything but the coordinates computed once; fixed-length
/// arithmetic over all `PE_LANES` lanes (vector code), the lanes past the features 0. In u32:
/// for coordinates below 2^16, `2x + 1 + P/2 < 2^18` and a value before its shift is at most
/// `2P ≤ 2^15`, shifted left by at most 14.
#[cfg(feature = "alloc")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct PeLanes {
    /// Per lane: `1 + phase·P/2`, the mask of `mod 2P`, `2P`, the shifts to Q.`frac_bits` (one
    /// of them 0), and whether the lane encodes y (all ones) or x (0).
    add: [u32; PE_LANES],
    mask: [u32; PE_LANES],
    two_period: [u32; PE_LANES],
    left: [u32; PE_LANES],
    right: [u32; PE_LANES],
    y: [u32; PE_LANES],
}

/// Lanes of [`PeLanes`]: 4 features for each of up to `MAX_PE_FREQUENCIES` frequencies.
#[cfg(feature = "alloc")]
pub(crate) const PE_LANES: usize = 4 * MAX_PE_FREQUENCIES as usize;

#[cfg(feature = "alloc")]
impl PeLanes {
    pub(crate) fn new(frequencies: u8, frac_bits: u8) -> PeLanes {
        // Lane i: (add, mask, 2P, left, right, y), all 0 past the features.
        let lane = |i: usize| {
            if i >= 4 * usize::from(frequencies) {
                return [0; 6];
            }
            let (k, phase, y) = ((i / 4).min(12) as u32, i as u32 & 1, i & 2 != 0);
            let period = 1u32 << (k + 2);
            let shift = i64::from(frac_bits) - i64::from(k + 3);
            let (left, right) = (shift.max(0) as u32, (-shift).max(0) as u32);
            let y = if y { u32::MAX } else { 0 };
            [1 + phase * (period / 2), 2 * period - 1, 2 * period, left, right, y]
        };
        let field = |f: usize| core::array::from_fn(|i| lane(i).get(f).copied().unwrap_or(0));
        PeLanes {
            add: field(0),
            mask: field(1),
            two_period: field(2),
            left: field(3),
            right: field(4),
            y: field(5),
        }
    }

    /// The features of texel (x, y), both below 2^16 (addressed coordinates are).
    #[inline(always)]
    pub(crate) fn at(&self, x: u32, y: u32) -> [i32; PE_LANES] {
        let mut out = [0; PE_LANES];
        let lanes = out.iter_mut().zip(&self.add).zip(&self.mask).zip(&self.two_period);
        let lanes = lanes.zip(&self.left).zip(&self.right).zip(&self.y);
        for ((((((v, &add), &mask), &two_period), &left), &right), &is_y) in lanes {
            let coordinate = (x & !is_y) | (y & is_y);
            let a = (2 * coordinate + add) & mask;
            let magnitude = (2 * a).abs_diff(two_period);
            *v = ((magnitude << left) >> right) as i16 as i32;
        }
        out
    }
}

#[cfg(all(test, feature = "alloc"))]
mod tests {
    use super::*;

    /// The lanes equal the definition for every frequency count, phase and fraction width, over
    /// whole periods and the largest coordinates; lanes past the features are 0.
    #[test]
    fn the_prepared_lanes_equal_triangle_q() {
        for f in 0..=14u8 {
            for frequencies in 0..=MAX_PE_FREQUENCIES {
                let lanes = PeLanes::new(frequencies, f);
                let xs = (0..130u32).chain(16_300..16_384).chain([65_535]);
                for (x, y) in xs.clone().zip(xs.rev()) {
                    let got = lanes.at(x, y);
                    let mut want = [0i32; PE_LANES];
                    for k in 0..frequencies {
                        let at = 4 * usize::from(k);
                        want[at] = i32::from(triangle_q(x, k, 0, f));
                        want[at + 1] = i32::from(triangle_q(x, k, 1, f));
                        want[at + 2] = i32::from(triangle_q(y, k, 0, f));
                        want[at + 3] = i32::from(triangle_q(y, k, 1, f));
                    }
                    assert_eq!(got, want, "x {x} y {y} K {frequencies} f {f}");
                }
            }
        }
    }
}

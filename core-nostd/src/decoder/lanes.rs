//! The per-row tables each SIMD kernel reads from a packed layer, in that kernel's lane order:
//! data only, built once when a material is prepared. How each kernel computes with its table is
//! in its file under `kernel/`; the tables live here so that the packed layer, which carries
//! them, depends on no kernel (the kernels depend on it).

extern crate alloc;

#[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
use alloc::vec::Vec;

/// The per-row requantization constants in the lane orders of each SIMD kernel this target
/// has (each kernel's table type says what it holds).
#[derive(Clone, Debug)]
pub(super) struct Tables {
    #[cfg(target_arch = "x86_64")]
    pub(super) avx2: Avx2Lanes,
    #[cfg(target_arch = "x86_64")]
    pub(super) avx512: Avx512Lanes,
    #[cfg(target_arch = "aarch64")]
    pub(super) neon: NeonLanes,
    #[cfg(target_arch = "aarch64")]
    pub(super) neon_dot: NeonDotLanes,
}

impl Tables {
    /// From the prepared `[pair][row][2]` weights of `in_pairs` pairs and per-row multipliers and
    /// shifts (`out_pad` rows, a multiple of 16; multipliers in [2^30, 2^31) or 0, shifts in
    /// 1..=62, as `Requant` guarantees).
    #[allow(unused_variables, reason = "each target's kernels read only some of them")]
    pub(super) fn new(
        weights: &[i16],
        in_pairs: usize,
        multiplier: &[i32],
        shift: &[u32],
    ) -> Tables {
        Tables {
            #[cfg(target_arch = "x86_64")]
            avx2: Avx2Lanes::new(multiplier, shift),
            #[cfg(target_arch = "x86_64")]
            avx512: Avx512Lanes::new(multiplier, shift),
            #[cfg(target_arch = "aarch64")]
            neon: NeonLanes::new(shift),
            #[cfg(target_arch = "aarch64")]
            neon_dot: NeonDotLanes::new(weights, in_pairs, shift.len()),
        }
    }
}

#[cfg(target_arch = "x86_64")]
/// The requantization constants of each row (multiplier m, shift s: `(acc·m + 2^(s−1)) >> s`,
/// then saturated to i16) for [`requantize`], which per 8-row block works in 32-bit lanes where
/// it can: the accumulator is first clamped to `[clamp_lo, clamp_hi]`, the widest range outside
/// which the row saturates anyway, so the requantized value fits an i32 (see `Requant::saturation_range`) and
/// the i16 saturation is a 32-bit one. The 64-bit product plus `round` = 2^(s−1) (lane order
/// rows 0, 2, 4, 6, 1, 3, 5, 7, as the 64-bit multiply takes the even 32-bit lanes) is shifted
/// left by `lift` = max(0, 32 − s) (exact: the value fits an i32, so the shifted one fits an
/// i64), its high half taken, and that shifted right by `post_shift` = max(0, s − 32) (row order).
#[derive(Clone, Debug)]
pub(super) struct Avx2Lanes {
    pub(super) clamp_lo: Vec<i32>,
    pub(super) clamp_hi: Vec<i32>,
    pub(super) round: Vec<i64>,
    pub(super) lift: Vec<u64>,
    /// Whether any `lift` is non-zero (else the left shift is skipped).
    pub(super) lifted: bool,
    pub(super) post_shift: Vec<u32>,
}

#[cfg(target_arch = "x86_64")]
impl Avx2Lanes {
    /// From per-row multipliers and shifts (equal lengths, a multiple of 8; multipliers in
    /// [2^30, 2^31) or 0, shifts in 1..=62, as `PackedLayer` guarantees).
    pub(super) fn new(multiplier: &[i32], shift: &[u32]) -> Avx2Lanes {
        let rows = multiplier.len().min(shift.len());
        let pick = |o: usize| {
            (i64::from(multiplier.get(o).copied().unwrap_or(0)), shift.get(o).copied().unwrap_or(1))
        };
        // Lane i of a block of 8 rows holds row 2i (first half) or 2(i − 4) + 1.
        let order = (0..rows).map(|i| {
            let (block, lane) = (i / 8, i % 8);
            8 * block + if lane < 4 { 2 * lane } else { 2 * (lane - 4) + 1 }
        });
        let narrow: Vec<u32> = order.map(|o| pick(o).1).collect();
        let (clamp_lo, clamp_hi) = (0..rows)
            .map(|o| {
                let (m, s) = pick(o);
                crate::neural::mlp::Requant { multiplier: m as i32, shift: s }.saturation_range()
            })
            .unzip();
        let lift: Vec<u64> = narrow.iter().map(|&s| u64::from(32u32.saturating_sub(s))).collect();
        Avx2Lanes {
            clamp_lo,
            clamp_hi,
            round: narrow.iter().map(|&s| 1i64 << (s - 1)).collect(),
            lifted: lift.iter().any(|&u| u != 0),
            lift,
            post_shift: (0..rows).map(|o| pick(o).1.saturating_sub(32)).collect(),
        }
    }
}

#[cfg(target_arch = "x86_64")]
/// The requantization constants of each row for [`requantize`], per 16-row block in the lane
/// order rows 0, 2, …, 14, 1, 3, …, 15 (the 64-bit multiply takes the even 32-bit lanes):
/// `wide_multiplier` = m (as i64; the multiply reads its low half), `wide_round` = 2^(s−1),
/// `wide_shift` = s.
#[derive(Clone, Debug)]
pub(super) struct Avx512Lanes {
    pub(super) wide_multiplier: Vec<i64>,
    pub(super) wide_round: Vec<i64>,
    pub(super) wide_shift: Vec<u64>,
}

#[cfg(target_arch = "x86_64")]
impl Avx512Lanes {
    /// From per-row multipliers and shifts (equal lengths, a multiple of 16; shifts in 1..=62).
    pub(super) fn new(multiplier: &[i32], shift: &[u32]) -> Avx512Lanes {
        let rows = multiplier.len().min(shift.len());
        let pick = |o: usize| {
            (i64::from(multiplier.get(o).copied().unwrap_or(0)), shift.get(o).copied().unwrap_or(1))
        };
        // Lane i of a block of 16 rows holds row 2i (first half) or 2(i − 8) + 1.
        let wide: Vec<(i64, u32)> = (0..rows)
            .map(|i| {
                let (block, lane) = (i / 16, i % 16);
                pick(16 * block + if lane < 8 { 2 * lane } else { 2 * (lane - 8) + 1 })
            })
            .collect();
        Avx512Lanes {
            wide_multiplier: wide.iter().map(|&(m, _)| m).collect(),
            wide_round: wide.iter().map(|&(_, s)| 1i64 << (s - 1)).collect(),
            wide_shift: wide.iter().map(|&(_, s)| u64::from(s)).collect(),
        }
    }
}

#[cfg(target_arch = "aarch64")]
/// The requantization shifts of each row, negated and widened to the 64-bit lanes of `srshl`
/// (row order).
#[derive(Clone, Debug)]
pub(super) struct NeonLanes {
    pub(super) neg_shift: Vec<i64>,
}

#[cfg(target_arch = "aarch64")]
impl NeonLanes {
    /// From per-row shifts (in 1..=62, as `PackedLayer` guarantees).
    pub(super) fn new(shift: &[u32]) -> NeonLanes {
        NeonLanes { neg_shift: shift.iter().map(|&s| -i64::from(s)).collect() }
    }
}

/// Inputs per chunk of the dot-product kernel: a 16-byte vector of activations.
#[cfg(target_arch = "aarch64")]
pub(super) const CHUNK: usize = 16;

#[cfg(target_arch = "aarch64")]
/// The weights in the dot-product layout and the per-row constants of the byte split.
#[derive(Clone, Debug)]
pub(super) struct NeonDotLanes {
    /// `[quad][row][4]`: the weights of inputs 4q..4q + 4 of each row; `4·chunks` quads.
    pub(super) weights: Vec<i8>,
    /// `[c][row]` for c in 0..=chunks: 128 · the row's weight sum over inputs 0..16c.
    pub(super) offset: Vec<i32>,
    /// Chunks of 16 inputs the layer has (its inputs rounded up).
    pub(super) chunks: usize,
}

#[cfg(target_arch = "aarch64")]
impl NeonDotLanes {
    /// From the prepared `[pair][row][2]` weights of `in_pairs` pairs and `out_pad` rows.
    pub(super) fn new(weights: &[i16], in_pairs: usize, out_pad: usize) -> NeonDotLanes {
        let chunks = (2 * in_pairs).div_ceil(CHUNK);
        let weight = |row: usize, input: usize| -> i8 {
            let at = (input / 2 * out_pad + row) * 2 + input % 2;
            // The prepared weights are int8 values widened to i16.
            weights.get(at).map_or(0, |&w| w as i8)
        };
        let mut dot = alloc::vec![0i8; CHUNK * chunks * out_pad];
        for (quad, rows) in dot.chunks_exact_mut(4 * out_pad).enumerate() {
            for (row, w) in rows.chunks_exact_mut(4).enumerate() {
                for (k, slot) in w.iter_mut().enumerate() {
                    *slot = weight(row, 4 * quad + k);
                }
            }
        }
        let mut offset = alloc::vec![0i32; (chunks + 1) * out_pad];
        for c in 1..=chunks {
            for row in 0..out_pad {
                let sum: i32 =
                    (CHUNK * (c - 1)..CHUNK * c).map(|i| i32::from(weight(row, i))).sum();
                let before = offset.get((c - 1) * out_pad + row).copied().unwrap_or(0);
                if let Some(slot) = offset.get_mut(c * out_pad + row) {
                    *slot = before.wrapping_add(128 * sum);
                }
            }
        }
        NeonDotLanes { weights: dot, offset, chunks }
    }
}

//! The decoder MLP in two arithmetics over one stored network (docs/FORMAT.md §6.6–§6.8):
//! - float: the int8 weights and i32 biases dequantized with their row scales, f32 activations —
//!   the accuracy reference;
//! - integer (W8A16): int8 weights, i32 biases and accumulators, i16 activations in a per-layer
//!   Q-format, round-half-up requantization — defined so every correct implementation agrees
//!   bit for bit.

use crate::bytes::{f32_at, i32_at, u8_at};
use crate::limits::MAX_WIDTH;

/// Activation after a layer.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    /// Identity (the output layer).
    None = 0,
    /// hardGELU: 0 below −1.5, x above 1.5, x·(x + 1.5)/3 between (the NTC paper's activation).
    HardGelu = 1,
}

/// A validated view of one layer's parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layer<'a> {
    pub(crate) inputs: u16,
    pub(crate) outputs: u16,
    /// Fraction bits of this layer's input (the previous layer's output, or the MLP input).
    pub(crate) in_frac_bits: u8,
    pub(crate) out_frac_bits: u8,
    pub(crate) activation: Activation,
    pub(crate) weights_i8: &'a [u8],
    pub(crate) scales: &'a [u8],
    pub(crate) bias: &'a [u8],
}

/// The integer requantization of one output row: `y = (acc · multiplier + 2^(shift−1)) >> shift`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Requant {
    /// In [2^30, 2^31) for a non-zero scale, 0 for a zero scale.
    pub multiplier: i32,
    /// In 1..=62.
    pub shift: u32,
}

impl Requant {
    /// Derives the requantization from the bits of an f32 row scale, exactly and without floating
    /// point (FORMAT.md §6.6): a normal f32 is `m · 2^e` with a 24-bit integer `m`; the multiplier is
    /// `m << 7` and the shift absorbs `e` and the change of Q-format. `None` if the scale is
    /// negative, subnormal, infinite or NaN, or if the shift would leave 1..=62.
    pub fn from_scale_bits(
        scale_bits: u32,
        in_frac_bits: u8,
        out_frac_bits: u8,
    ) -> Option<Requant> {
        if scale_bits == 0 {
            return Some(Requant { multiplier: 0, shift: 1 });
        }
        let biased = (scale_bits >> 23) & 0xFF;
        if scale_bits >> 31 != 0 || biased == 0 || biased == 0xFF {
            return None;
        }
        let mantissa = (scale_bits & 0x007F_FFFF) | 0x0080_0000;
        let exponent = biased as i32 - 150;
        let shift = 7 - exponent + i32::from(in_frac_bits) - i32::from(out_frac_bits);
        if !(1..=62).contains(&shift) {
            return None;
        }
        Some(Requant { multiplier: (mantissa << 7) as i32, shift: shift as u32 })
    }

    /// Round-half-up requantization of an accumulator. |acc · multiplier| < 2^62, so the i64
    /// arithmetic cannot overflow.
    pub fn apply(self, acc: i32) -> i64 {
        let product = i64::from(acc) * i64::from(self.multiplier);
        (product + (1i64 << (self.shift - 1))) >> self.shift
    }

    /// The accumulators `[lo, hi]` such that clamping an accumulator to them leaves its
    /// saturated requantized value unchanged (for the SIMD and GPU kernels, which then work in
    /// 32 bits): `hi` is the least accumulator whose value saturates at the top (`i32::MAX` if
    /// none does), `lo` the greatest one saturating at the bottom (`i32::MIN` if none does). The
    /// value is non-decreasing in the accumulator and grows by at most ⌈m / 2^s⌉ ≤ 2^30 per step,
    /// so over `[lo, hi]` it stays within (−2^31, 2^31).
    pub fn saturation_range(self) -> (i32, i32) {
        let value = |acc: i32| self.apply(acc);
        let top = i64::from(i16::MAX);
        let bottom = i64::from(i16::MIN);
        let hi = if value(i32::MAX) < top {
            i32::MAX
        } else {
            // The least acc with value(acc) ≥ top, by bisection of the monotone value.
            let (mut below, mut at) = (i64::from(i32::MIN) - 1, i64::from(i32::MAX));
            while at - below > 1 {
                let mid = below + (at - below) / 2;
                if value(mid as i32) >= top { at = mid } else { below = mid }
            }
            at as i32
        };
        let lo = if value(i32::MIN) > bottom {
            i32::MIN
        } else {
            let (mut at, mut above) = (i64::from(i32::MIN), i64::from(i32::MAX) + 1);
            while above - at > 1 {
                let mid = at + (above - at) / 2;
                if value(mid as i32) <= bottom { at = mid } else { above = mid }
            }
            at as i32
        };
        (lo, hi)
    }
}

/// Saturates to the i16 activation range.
pub fn saturate_i16(v: i64) -> i16 {
    v.clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16
}

/// hardGELU in Q.`frac_bits` (1 ≤ frac_bits ≤ 14), exact to within 0.5 LSB of the real function:
/// with t = 1.5·2^f, z ≥ t → z; z ≤ −t → 0; else floor((z·(z + t) + t) / (3·2^f)).
pub fn hard_gelu_q(z: i16, frac_bits: u8) -> i16 {
    let f = u32::from(frac_bits.clamp(1, 14));
    let t = 3i32 << (f - 1);
    let z = i32::from(z);
    if z >= t {
        z as i16
    } else if z <= -t {
        0
    } else {
        // |z| < 1.5·2^14, so the product is below 2^31 (docs/FORMAT.md §6.6).
        let num = z * (z + t) + t;
        num.div_euclid(3i32 << f) as i16
    }
}

/// hardGELU in f32.
pub fn hard_gelu_f32(x: f32) -> f32 {
    if x >= 1.5 {
        x
    } else if x <= -1.5 {
        0.0
    } else {
        x * (x + 1.5) / 3.0
    }
}

impl<'a> Layer<'a> {
    pub fn inputs(&self) -> usize {
        usize::from(self.inputs)
    }
    pub fn outputs(&self) -> usize {
        usize::from(self.outputs)
    }
    pub fn in_frac_bits(&self) -> u8 {
        self.in_frac_bits
    }
    pub fn out_frac_bits(&self) -> u8 {
        self.out_frac_bits
    }
    pub fn activation(&self) -> Activation {
        self.activation
    }
    /// int8 weight of row `o`, column `i` (row-major `[outputs][inputs]`).
    pub fn weight_i8(&self, o: usize, i: usize) -> i8 {
        u8_at(self.weights_i8, o * self.inputs() + i) as i8
    }
    /// f32 scale of row `o` of the integer weights.
    pub fn scale(&self, o: usize) -> f32 {
        f32_at(self.scales, 4 * o)
    }
    /// i32 bias of row `o` in accumulator units (input LSB × weight LSB).
    pub fn bias(&self, o: usize) -> i32 {
        i32_at(self.bias, 4 * o)
    }
    /// Weight of the float decoder: the int8 weight times its row scale, one f32 rounding
    /// (FORMAT.md §6.8).
    pub fn float_weight(&self, o: usize, i: usize) -> f32 {
        f32::from(self.weight_i8(o, i)) * self.scale(o)
    }
    /// Bias of the float decoder: `bias · scale · 2^−in_frac_bits` (the integer bias is in units of
    /// the input LSB times the weight LSB), computed in f64 and rounded once to f32.
    pub fn float_bias(&self, o: usize) -> f32 {
        let lsb = 1.0 / f64::from(1u32 << self.in_frac_bits.min(31));
        (f64::from(self.bias(o)) * f64::from(self.scale(o)) * lsb) as f32
    }
    /// The requantization of row `o`; parse has checked that it exists.
    pub fn requant(&self, o: usize) -> Requant {
        let bits = f32_at(self.scales, 4 * o).to_bits();
        Requant::from_scale_bits(bits, self.in_frac_bits, self.out_frac_bits)
            .unwrap_or(Requant { multiplier: 0, shift: 1 })
    }

    /// Integer accumulator of row `o`: bias + Σ w·x. Parse bounds |bias| so this cannot overflow
    /// (docs/FORMAT.md §5.3); wrapping ops keep the function panic-free regardless.
    pub fn accumulate(&self, o: usize, x: &[i16]) -> i32 {
        let n = self.inputs();
        let row = self.weights_i8.get(o * n..(o + 1) * n).unwrap_or(&[]);
        let dot = row
            .iter()
            .zip(x)
            .fold(0i32, |acc, (&w, &v)| acc.wrapping_add(i32::from(w as i8) * i32::from(v)));
        dot.wrapping_add(self.bias(o))
    }

    /// Integer output of row `o` (requantized, saturated, activated).
    pub fn row_int(&self, o: usize, x: &[i16]) -> i16 {
        let y = saturate_i16(self.requant(o).apply(self.accumulate(o, x)));
        match self.activation {
            Activation::None => y,
            Activation::HardGelu => hard_gelu_q(y, self.out_frac_bits),
        }
    }

    /// Float output of row `o`: float bias + Σ float weight·x in input order, then the activation.
    pub fn row_float(&self, o: usize, x: &[f32]) -> f32 {
        let n = self.inputs();
        let scale = self.scale(o);
        let row = self.weights_i8.get(o * n..(o + 1) * n).unwrap_or(&[]);
        let dot =
            row.iter().zip(x).fold(0.0f32, |acc, (&w, &v)| acc + f32::from(w as i8) * scale * v);
        let y = dot + self.float_bias(o);
        match self.activation {
            Activation::None => y,
            Activation::HardGelu => hard_gelu_f32(y),
        }
    }
}

/// Runs the integer network on `io` (the input vector on entry, the outputs on exit). Rows of the
/// last layer not in `last_rows` are skipped and left 0 ("model only what a scene requires").
pub(crate) fn forward_int(layers: &[Layer<'_>], io: &mut [i16; MAX_WIDTH], last_rows: u16) {
    let mut next = [0i16; MAX_WIDTH];
    let count = layers.len();
    for (li, layer) in layers.iter().enumerate() {
        let last = li + 1 == count;
        for (o, slot) in next.iter_mut().enumerate().take(layer.outputs()) {
            *slot = if last && (o >= 16 || last_rows & (1 << o) == 0) {
                0
            } else {
                layer.row_int(o, io)
            };
        }
        io.copy_from_slice(&next);
    }
}

/// Float twin of [`forward_int`].
pub(crate) fn forward_float(layers: &[Layer<'_>], io: &mut [f32; MAX_WIDTH], last_rows: u16) {
    let mut next = [0f32; MAX_WIDTH];
    let count = layers.len();
    for (li, layer) in layers.iter().enumerate() {
        let last = li + 1 == count;
        for (o, slot) in next.iter_mut().enumerate().take(layer.outputs()) {
            *slot = if last && (o >= 16 || last_rows & (1 << o) == 0) {
                0.0
            } else {
                layer.row_float(o, io)
            };
        }
        io.copy_from_slice(&next);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requant_of_one_is_identity_between_equal_formats() {
        let rq = Requant::from_scale_bits(1.0f32.to_bits(), 12, 12).unwrap();
        for acc in [-70000, -3, -1, 0, 1, 2, 12345, 1 << 20] {
            assert_eq!(rq.apply(acc), i64::from(acc));
        }
    }

    #[test]
    fn requant_rejects_bad_scales() {
        for s in [-1.0f32, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e-40, -0.0] {
            assert_eq!(Requant::from_scale_bits(s.to_bits(), 12, 12), None, "{s}");
        }
    }

    #[test]
    fn hard_gelu_minimum_is_minus_three_sixteenths() {
        // Real minimum at x = −0.75: −0.75·0.75/3 = −0.1875 = −768/4096.
        assert_eq!(hard_gelu_q(-3072, 12), -768);
        assert_eq!(hard_gelu_f32(-0.75), -0.1875);
    }
}

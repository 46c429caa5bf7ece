//! One MLP layer in the prepared layout ([`PackedLayer`]): the int8 weights widened to i16 and
//! interleaved by input pairs for the integer kernels, the requantization constants per row (and
//! in the kernels' lane orders), the dequantized f32 weights transposed for the float path; and
//! the scalar twin of the integer layer, which every kernel is tested against.

extern crate alloc;

use alloc::vec::Vec;
use core::ops::Range;

use super::lanes::Tables;
use crate::limits::MAX_WIDTH;
use crate::neural::mlp::{Activation, Layer, Requant, hard_gelu_f32, hard_gelu_q, saturate_i16};

/// One layer in the prepared layout. Invariants (established by the constructors, the only
/// way to make one; the SIMD kernels rely on them): `out_pad` is a multiple of 16 and at most
/// `MAX_WIDTH`; `2·in_pairs` is at most `MAX_WIDTH`; `weights` holds `in_pairs · out_pad · 2`
/// values; the per-row vectors hold `out_pad`; padding rows and columns are zero (multiplier 0,
/// shift 1), so they decode to 0; multipliers are in [2^30, 2^31) or 0, shifts in 1..=62.
#[derive(Clone, Debug)]
// Targets without a SIMD kernel read only the scalar twin's fields.
#[cfg_attr(not(any(target_arch = "x86_64", target_arch = "aarch64")), allow(dead_code))]
pub(crate) struct PackedLayer {
    in_pairs: usize,
    outputs: usize,
    out_pad: usize,
    /// `[pair][row][2]`: the int8 weights of inputs 2p and 2p+1 of each row, as i16.
    weights: Vec<i16>,
    bias: Vec<i32>,
    multiplier: Vec<i32>,
    shift: Vec<u32>,
    /// Per-row requantization constants in the lane orders of the SIMD kernels.
    tables: Tables,
    out_frac_bits: u8,
    activation: Activation,
    /// `[input][row]` f32 weights (the dequantized int8 ones, `Layer::float_weight`), rows padded
    /// to `out_pad`; empty for a layer made by [`PackedLayer::from_parts`].
    float_weights: Vec<f32>,
    float_bias: Vec<f32>,
}

/// The integer parts of a layer, row by row, for [`PackedLayer::from_parts`].
#[cfg(test)]
pub(crate) struct Parts<'p> {
    pub inputs: usize,
    pub outputs: usize,
    /// `outputs × inputs`, row-major.
    pub weights: &'p [i8],
    pub bias: &'p [i32],
    pub requant: &'p [Requant],
    pub out_frac_bits: u8,
    pub activation: Activation,
}

impl PackedLayer {
    /// Prepares a layer of a parsed material (whose sizes and requantization constants the
    /// parser checked).
    pub(super) fn new(layer: &Layer<'_>) -> PackedLayer {
        let (inputs, outputs) = (layer.inputs(), layer.outputs());
        let mut packed = PackedLayer::integer(
            inputs,
            outputs,
            |o, i| layer.weight_i8(o, i),
            |o| layer.bias(o),
            |o| layer.requant(o),
            layer.out_frac_bits(),
            layer.activation(),
        );
        let out_pad = packed.out_pad;
        let mut float_weights = alloc::vec![0f32; inputs * out_pad];
        for (i, row) in float_weights.chunks_exact_mut(out_pad).enumerate() {
            for (o, slot) in row.iter_mut().take(outputs).enumerate() {
                *slot = layer.float_weight(o, i);
            }
        }
        packed.float_weights = float_weights;
        packed.float_bias =
            (0..out_pad).map(|o| if o < outputs { layer.float_bias(o) } else { 0.0 }).collect();
        packed
    }

    /// A layer from its integer parts (no float path), or `None` if they break a limit: sizes in
    /// 1..=`MAX_WIDTH`, slices of the sizes stated, multipliers in [2^30, 2^31) or 0, shifts in
    /// 1..=62, `out_frac_bits` in 1..=14.
    #[cfg(test)]
    pub(crate) fn from_parts(p: &Parts<'_>) -> Option<PackedLayer> {
        let size_ok = |n: usize| (1..=MAX_WIDTH).contains(&n);
        let requant_ok = |r: &Requant| {
            (r.multiplier == 0 || r.multiplier >= 1 << 30) && (1..=62).contains(&r.shift)
        };
        let ok = size_ok(p.inputs)
            && size_ok(p.outputs)
            && p.weights.len() == p.inputs * p.outputs
            && p.bias.len() == p.outputs
            && p.requant.len() == p.outputs
            && p.requant.iter().all(requant_ok)
            && (1..=14).contains(&p.out_frac_bits);
        ok.then(|| {
            PackedLayer::integer(
                p.inputs,
                p.outputs,
                |o, i| p.weights.get(o * p.inputs + i).copied().unwrap_or(0),
                |o| p.bias.get(o).copied().unwrap_or(0),
                |o| p.requant.get(o).copied().unwrap_or(Requant { multiplier: 0, shift: 1 }),
                p.out_frac_bits,
                p.activation,
            )
        })
    }

    /// The integer part of a layer of `inputs` × `outputs` (both in 1..=`MAX_WIDTH`), padded.
    fn integer(
        inputs: usize,
        outputs: usize,
        weight: impl Fn(usize, usize) -> i8,
        bias: impl Fn(usize) -> i32,
        requant: impl Fn(usize) -> Requant,
        out_frac_bits: u8,
        activation: Activation,
    ) -> PackedLayer {
        let (inputs, outputs) = (inputs.min(MAX_WIDTH), outputs.min(MAX_WIDTH));
        let in_pairs = inputs.div_ceil(2);
        let out_pad = outputs.div_ceil(16) * 16;
        let mut weights = alloc::vec![0i16; in_pairs * out_pad * 2];
        for (p, pair) in weights.chunks_exact_mut(out_pad * 2).enumerate() {
            for (o, w) in pair.chunks_exact_mut(2).take(outputs).enumerate() {
                for (k, slot) in w.iter_mut().enumerate() {
                    if 2 * p + k < inputs {
                        *slot = i16::from(weight(o, 2 * p + k));
                    }
                }
            }
        }
        let zero = Requant { multiplier: 0, shift: 1 };
        let requant = |o: usize| if o < outputs { requant(o) } else { zero };
        let bias = (0..out_pad).map(|o| if o < outputs { bias(o) } else { 0 }).collect();
        let multiplier: Vec<i32> = (0..out_pad).map(|o| requant(o).multiplier).collect();
        let shift: Vec<u32> = (0..out_pad).map(|o| requant(o).shift.clamp(1, 62)).collect();
        PackedLayer {
            tables: Tables::new(&weights, in_pairs, &multiplier, &shift),
            in_pairs,
            outputs,
            out_pad,
            weights,
            bias,
            multiplier,
            shift,
            out_frac_bits: out_frac_bits.clamp(1, 14),
            activation,
            float_weights: Vec::new(),
            float_bias: Vec::new(),
        }
    }
}

/// What the kernels read (see the type's invariants).
#[cfg_attr(not(any(target_arch = "x86_64", target_arch = "aarch64")), allow(dead_code))]
impl PackedLayer {
    /// Input pairs (inputs rounded up to even, halved).
    pub(crate) fn in_pairs(&self) -> usize {
        self.in_pairs
    }

    /// Rows, padded to a multiple of 16.
    pub(crate) fn out_pad(&self) -> usize {
        self.out_pad
    }

    /// `[pair][row][2]` weights (see the type).
    pub(crate) fn weights(&self) -> &[i16] {
        &self.weights
    }

    /// Per-row bias (`out_pad` rows).
    pub(crate) fn bias(&self) -> &[i32] {
        &self.bias
    }

    /// Per-row requantization multiplier (`out_pad` rows).
    pub(crate) fn multiplier(&self) -> &[i32] {
        &self.multiplier
    }

    pub(crate) fn tables(&self) -> &Tables {
        &self.tables
    }

    /// The Q-format of the outputs, in 1..=14.
    pub(crate) fn out_frac_bits(&self) -> u8 {
        self.out_frac_bits
    }

    pub(crate) fn activation(&self) -> Activation {
        self.activation
    }
}

impl PackedLayer {
    /// `pairs` cut to the layer's input pairs (an empty range where it starts past them). Used
    /// by the SIMD kernels only (x86-64 and AArch64).
    #[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
    pub(crate) fn pairs_within(&self, pairs: Range<usize>) -> Range<usize> {
        let end = pairs.end.min(self.in_pairs);
        pairs.start.min(end)..end
    }

    /// The accumulators' start values for a layer pass: `init`, or the bias if `init` is shorter
    /// than `out_pad` (the rule of `forward_scalar_from` and every kernel's group form).
    pub(crate) fn start_row<'s>(&'s self, init: &'s [i32]) -> &'s [i32] {
        if init.len() < self.out_pad { &self.bias } else { init }
    }

    /// Which 8-row blocks to compute: all of them, or for the last layer only those holding a
    /// selected row.
    pub(super) fn blocks(&self, last: bool, rows: u16) -> u32 {
        let all = if self.out_pad >= 8 * 32 { u32::MAX } else { (1u32 << (self.out_pad / 8)) - 1 };
        if !last {
            return all;
        }
        let mut blocks = 0;
        for b in 0..2 {
            if (rows >> (8 * b)) & 0xFF != 0 {
                blocks |= 1 << b;
            }
        }
        blocks & all
    }

    /// The scalar twin: exactly the integer layer of FORMAT.md §6.6 over the prepared layout,
    /// with the accumulators starting at `init` (per row; a row shorter than `out_pad` counts as
    /// the bias) instead of the bias, and only input pairs `pairs` summed: with `init` = bias +
    /// the sum over the other pairs (`partial_sums`, `pair_sums`) this is the whole layer, as
    /// integer sums do not depend on their order.
    pub(crate) fn forward_scalar_from(
        &self,
        x: &[i16; MAX_WIDTH],
        init: &[i32],
        pairs: Range<usize>,
        y: &mut [i16; MAX_WIDTH],
        blocks: u32,
    ) {
        let init = self.start_row(init);
        let row_len = 2 * self.out_pad;
        for (b, out) in y.chunks_exact_mut(8).take(self.out_pad / 8).enumerate() {
            if blocks & (1 << b) == 0 {
                continue;
            }
            let mut acc = [0i32; 8];
            for (a, &start) in acc.iter_mut().zip(init.iter().skip(8 * b)) {
                *a = start;
            }
            let weights = self.weights.chunks_exact(row_len).zip(x.chunks_exact(2));
            for (pair, x) in weights.take(pairs.end).skip(pairs.start) {
                let (x0, x1) = match x {
                    [x0, x1] => (i32::from(*x0), i32::from(*x1)),
                    _ => (0, 0),
                };
                let w = pair.get(16 * b..16 * b + 16).unwrap_or(&[]);
                for (a, w) in acc.iter_mut().zip(w.chunks_exact(2)) {
                    if let [w0, w1] = w {
                        let term = i32::from(*w0) * x0 + i32::from(*w1) * x1;
                        *a = a.wrapping_add(term);
                    }
                }
            }
            for (k, (slot, a)) in out.iter_mut().zip(acc).enumerate() {
                let o = 8 * b + k;
                let rq = Requant {
                    multiplier: self.multiplier.get(o).copied().unwrap_or(0),
                    shift: self.shift.get(o).copied().unwrap_or(1),
                };
                let v = saturate_i16(rq.apply(a));
                *slot = match self.activation {
                    Activation::None => v,
                    Activation::HardGelu => hard_gelu_q(v, self.out_frac_bits),
                };
            }
        }
    }

    /// Per row: the bias plus the sum over input pairs `first_pair..` of `x` (wrapping, like every
    /// accumulator), into the first `out_pad` entries of `sums`: the `init` of
    /// [`PackedLayer::forward_scalar_from`] for inputs that do not change between texels.
    pub(super) fn partial_sums(
        &self,
        x: &[i16; MAX_WIDTH],
        first_pair: usize,
        sums: &mut [i32; MAX_WIDTH],
    ) {
        self.pair_sums(x, first_pair..self.in_pairs, sums);
        for (s, &b) in sums.iter_mut().zip(&self.bias) {
            *s = s.wrapping_add(b);
        }
    }

    /// Per row: the sum over input pairs `pairs` of `x` (wrapping, like every accumulator; no
    /// bias), into the first `out_pad` entries of `sums`: the scalar form of `Layers::sums`.
    pub(super) fn pair_sums(
        &self,
        x: &[i16; MAX_WIDTH],
        pairs: Range<usize>,
        sums: &mut [i32; MAX_WIDTH],
    ) {
        sums.iter_mut().take(self.out_pad).for_each(|s| *s = 0);
        let weights = self.weights.chunks_exact(2 * self.out_pad).zip(x.chunks_exact(2));
        for (pair, x) in weights.take(pairs.end).skip(pairs.start) {
            let (x0, x1) = match x {
                [x0, x1] => (i32::from(*x0), i32::from(*x1)),
                _ => (0, 0),
            };
            for (s, w) in sums.iter_mut().zip(pair.chunks_exact(2)) {
                if let [w0, w1] = w {
                    let term = i32::from(*w0) * x0 + i32::from(*w1) * x1;
                    *s = s.wrapping_add(term);
                }
            }
        }
    }

    /// The float layer, summed in input order per row like `Layer::row_float` (the loop over rows
    /// is the one the compiler vectorizes).
    pub(super) fn forward_float(&self, x: &[f32; MAX_WIDTH], y: &mut [f32; MAX_WIDTH]) {
        let mut acc = [0f32; MAX_WIDTH];
        for (row, &xi) in self.float_weights.chunks_exact(self.out_pad).zip(x.iter()) {
            for (a, &w) in acc.iter_mut().zip(row) {
                *a += w * xi;
            }
        }
        for ((slot, a), b) in y.iter_mut().zip(acc).zip(&self.float_bias).take(self.outputs) {
            let v = a + b;
            *slot = match self.activation {
                Activation::None => v,
                Activation::HardGelu => hard_gelu_f32(v),
            };
        }
    }
}

//! A prepared decoder for throughput (docs/PERFORMANCE.md): the MLP's weights are
//! re-laid once — int8 widened to i16 and interleaved by input pairs so one SIMD multiply-add
//! serves 8 or 16 output rows, dequantized to f32 for the float path and transposed — and kept hot
//! across texels;
//! spans go through the network 4 texels at a time.
//!
//! Every result is bit-identical to the per-texel definition on [`Material`] (FORMAT.md §6): the
//! integer sums are exact and the float sums keep the input order of `Layer::row_float`. Three
//! kernels compute the integer layers: [`Kernel::Scalar`], portable Rust over the prepared
//! layout (the twin every SIMD kernel is tested against), [`Kernel::Avx2`] and
//! [`Kernel::Avx512Vnni`] (x86-64, `core::arch`, chosen at run time with the `std` feature, at
//! compile time without it).

extern crate alloc;

use alloc::vec::Vec;

use crate::decode::{ChannelMask, code, unit, write_selected};
use crate::error::{Argument, Error};
use crate::filter::{Precision, SampleRequest};
use crate::limits::MAX_WIDTH;
use crate::material::Material;
use crate::mlp::{Activation, Layer, Requant, hard_gelu_f32, hard_gelu_q, saturate_i16};

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod span;

use span::{MAX_X_PERIOD, Slots, SpanGather};

/// Which code computes the integer layers of a [`Decoder`].
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// Portable Rust over the prepared layout; what the compiler makes of it on any target.
    Scalar,
    /// x86-64 AVX2: `vpmaddwd` over 8 output rows per instruction, vector requantization.
    Avx2,
    /// x86-64 AVX-512 with VNNI: `vpdpwssd` (multiply, add pairs, accumulate) over 16 rows.
    Avx512Vnni,
}

impl Kernel {
    /// The fastest kernel this CPU runs.
    pub fn best() -> Kernel {
        [Kernel::Avx512Vnni, Kernel::Avx2]
            .into_iter()
            .find(|k| k.is_available())
            .unwrap_or(Kernel::Scalar)
    }

    /// Every kernel this build knows, slowest first.
    pub const ALL: [Kernel; 3] = [Kernel::Scalar, Kernel::Avx2, Kernel::Avx512Vnni];

    /// Whether this CPU can run the kernel (with the `std` feature the CPU is asked; without it
    /// only what the build targets counts).
    pub fn is_available(self) -> bool {
        match self {
            Kernel::Scalar => true,
            Kernel::Avx2 => avx2_available(),
            Kernel::Avx512Vnni => avx512_vnni_available(),
        }
    }

    /// Multiply-adds one round of [`Kernel::probe`] performs.
    pub fn probe_macs_per_round(self) -> u64 {
        match self {
            Kernel::Scalar => 8,
            Kernel::Avx2 => 128,
            Kernel::Avx512Vnni => 256,
        }
    }

    /// A register-only loop of this kernel's multiply-add instruction, for measuring the CPU's
    /// peak rate (the roofline of docs/PERFORMANCE.md): time `rounds` rounds and divide
    /// `rounds · probe_macs_per_round()` by the time. Returns a value depending on every product
    /// (print or `black_box` it), or `None` if this CPU lacks the kernel.
    pub fn probe(self, rounds: u64) -> Option<i64> {
        if !self.is_available() {
            return None;
        }
        Some(match self {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => avx2::probe(rounds),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512Vnni => avx512::probe(rounds),
            _ => scalar_probe(rounds),
        })
    }

    /// Short lowercase name for tables and logs.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Scalar => "scalar",
            Kernel::Avx2 => "avx2",
            Kernel::Avx512Vnni => "avx512-vnni",
        }
    }
}

#[cfg(all(target_arch = "x86_64", feature = "std"))]
fn avx2_available() -> bool {
    extern crate std;
    std::is_x86_feature_detected!("avx2")
}

#[cfg(all(target_arch = "x86_64", feature = "std"))]
fn avx512_vnni_available() -> bool {
    extern crate std;
    std::is_x86_feature_detected!("avx512f")
        && std::is_x86_feature_detected!("avx512bw")
        && std::is_x86_feature_detected!("avx512vnni")
}

#[cfg(all(target_arch = "x86_64", not(feature = "std")))]
fn avx2_available() -> bool {
    cfg!(target_feature = "avx2")
}

#[cfg(all(target_arch = "x86_64", not(feature = "std")))]
fn avx512_vnni_available() -> bool {
    cfg!(all(
        target_feature = "avx512f",
        target_feature = "avx512bw",
        target_feature = "avx512vnni"
    ))
}

#[cfg(not(target_arch = "x86_64"))]
fn avx2_available() -> bool {
    false
}

#[cfg(not(target_arch = "x86_64"))]
fn avx512_vnni_available() -> bool {
    false
}

/// 8 independent scalar i32 multiply-add chains (what the scalar kernel's inner loop is).
fn scalar_probe(rounds: u64) -> i64 {
    let mut acc = [0i32; 8];
    let mut x = 3i32;
    for _ in 0..rounds {
        for (k, a) in acc.iter_mut().enumerate() {
            *a = a.wrapping_add((k as i32 + 1).wrapping_mul(x));
        }
        // Opaque to the optimizer, which would otherwise sum the series in closed form.
        x = core::hint::black_box(x.wrapping_add(1));
    }
    acc.iter().map(|&a| i64::from(a)).sum()
}

/// Texels a span decodes together (the batched kernel's group).
const GROUP: usize = 4;

/// The first layer's accumulators for the inputs of a span that repeat along x (the positional
/// encoding, whose period is at most `MAX_X_PERIOD` texels, and the span-constant features of y
/// and the LOD): bias plus their weighted sum, one row per texel of the period. Per texel only
/// the first `pairs` input pairs (the latent features) are left to sum; integer sums do not
/// depend on their order, so the result is the layer's to the bit.
struct PeriodicSums<'t> {
    pairs: usize,
    /// The period minus one (a power of two).
    mask: u32,
    table: &'t [[i32; MAX_WIDTH]; MAX_X_PERIOD],
}

impl PeriodicSums<'_> {
    /// The row of the texel at addressed x.
    fn at(&self, x: u32) -> &[i32] {
        self.table.get((x & self.mask) as usize).map_or(&[], |row| row.as_slice())
    }
}

/// Work run inside a function compiled for a kernel's instruction set (`avx2::with_avx2`,
/// `avx512::with_avx512`); `run` is inlined there, and with it what it calls inline.
trait Job {
    type Output;
    fn run(self) -> Self::Output;
}

/// The arguments of [`Decoder::span_codes`].
struct SpanJob<'j, 'a, T, N> {
    decoder: &'j Decoder,
    material: &'j Material<'a>,
    at: (i64, i64, u32),
    count: usize,
    rows: (u16, usize),
    out: &'j mut [T],
    full_scale: i32,
    narrow: N,
}

impl<T, N: Fn(i32) -> T> Job for SpanJob<'_, '_, T, N> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        let SpanJob { decoder, material, at, count, rows, out, full_scale, narrow } = self;
        decoder.span_codes_here(material, at, count, rows, out, full_scale, narrow);
    }
}

/// The arguments of [`Decoder::texel_codes`].
struct TexelJob<'j, 'a, T, N> {
    decoder: &'j Decoder,
    material: &'j Material<'a>,
    at: (i64, i64, u32),
    rows: u16,
    out: &'j mut [T],
    full_scale: i32,
    narrow: N,
}

impl<T, N: Fn(i32) -> T> Job for TexelJob<'_, '_, T, N> {
    type Output = usize;
    #[inline(always)]
    fn run(self) -> usize {
        let TexelJob { decoder, material, at, rows, out, full_scale, narrow } = self;
        decoder.texel_codes_here(material, at, rows, out, full_scale, narrow)
    }
}

/// The requantization constants of each row (multiplier m, shift s: `(acc·m + 2^(s−1)) >> s`,
/// then saturated to i16) for the SIMD kernels, some in the lane orders of their 64-bit
/// multiplies (which take the even 32-bit lanes).
///
/// `avx2::requantize`, per 8-row block, works in 32-bit lanes where it can: the accumulator is
/// first clamped to `[clamp_lo, clamp_hi]`, the widest range outside which the row saturates
/// anyway, so the requantized value fits an i32 (see `clamp_range`) and the i16 saturation is
/// a 32-bit one. The 64-bit product plus `round` = 2^(s−1) (lane order rows 0, 2, 4, 6, 1, 3,
/// 5, 7) is shifted left by `lift` =
/// max(0, 32 − s) (exact: the value fits an i32, so the shifted one fits an i64), its high
/// half taken, and that shifted right by `post_shift` = max(0, s − 32) (row order).
///
/// `avx512::requantize`, per 16-row block, rows 0, 2, …, 14, 1, 3, …, 15: `wide_multiplier`
/// = m (as i64; the multiply reads its low half), `wide_round` = 2^(s−1), `wide_shift` = s.
#[derive(Clone, Debug)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
struct Lanes {
    clamp_lo: Vec<i32>,
    clamp_hi: Vec<i32>,
    round: Vec<i64>,
    lift: Vec<u64>,
    /// Whether any `lift` is non-zero (else the left shift is skipped).
    lifted: bool,
    post_shift: Vec<u32>,
    wide_multiplier: Vec<i64>,
    wide_round: Vec<i64>,
    wide_shift: Vec<u64>,
}

impl Lanes {
    /// From per-row multipliers and shifts (equal lengths, a multiple of 16; multipliers in
    /// [2^30, 2^31) or 0, shifts in 1..=62, as `Requant` guarantees).
    fn new(multiplier: &[i32], shift: &[u32]) -> Lanes {
        let rows = multiplier.len().min(shift.len());
        let pick = |o: usize| {
            (i64::from(multiplier.get(o).copied().unwrap_or(0)), shift.get(o).copied().unwrap_or(1))
        };
        // Lane i of a block of `width` rows holds row 2i (first half) or 2(i − width/2) + 1.
        let order = |width: usize| {
            (0..rows).map(move |i| {
                let (block, lane) = (i / width, i % width);
                let half = width / 2;
                width * block + if lane < half { 2 * lane } else { 2 * (lane - half) + 1 }
            })
        };
        let narrow: Vec<u32> = order(8).map(|o| pick(o).1).collect();
        let wide: Vec<(i64, u32)> = order(16).map(pick).collect();
        let (clamp_lo, clamp_hi) = (0..rows).map(|o| clamp_range(pick(o).0, pick(o).1)).unzip();
        let lift: Vec<u64> = narrow.iter().map(|&s| u64::from(32u32.saturating_sub(s))).collect();
        Lanes {
            clamp_lo,
            clamp_hi,
            round: narrow.iter().map(|&s| 1i64 << (s - 1)).collect(),
            lifted: lift.iter().any(|&u| u != 0),
            lift,
            post_shift: (0..rows).map(|o| pick(o).1.saturating_sub(32)).collect(),
            wide_multiplier: wide.iter().map(|&(m, _)| m).collect(),
            wide_round: wide.iter().map(|&(_, s)| 1i64 << (s - 1)).collect(),
            wide_shift: wide.iter().map(|&(_, s)| u64::from(s)).collect(),
        }
    }
}

/// For a row with multiplier `m` (≥ 0) and shift `s`: the accumulators `[lo, hi]` such that
/// clamping an accumulator to them leaves its saturated requantized value unchanged — `hi` is
/// the least accumulator whose value saturates at the top (i32::MAX if none does), `lo` the
/// greatest one saturating at the bottom. The value is non-decreasing in the accumulator and
/// grows by at most ⌈m / 2^s⌉ ≤ 2^30 per step, so over `[lo, hi]` it stays within
/// (−2^31, 2^31).
fn clamp_range(m: i64, s: u32) -> (i32, i32) {
    let value = |acc: i32| (i64::from(acc) * m + (1i64 << (s - 1))) >> s;
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

/// One layer in the prepared layout. Invariants (established by [`PackedLayer::new`], relied on
/// by the SIMD kernels): `out_pad` is a multiple of 16 and at most `MAX_WIDTH`; `2·in_pairs` is at
/// most `MAX_WIDTH`; `weights` holds `in_pairs · out_pad · 2` values; the per-row vectors hold
/// `out_pad`; padding rows and columns are zero (multiplier 0, shift 1), so they decode to 0.
#[derive(Clone, Debug)]
// The lane vectors and `in_pairs` serve the x86-64 kernels only.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
struct PackedLayer {
    in_pairs: usize,
    outputs: usize,
    out_pad: usize,
    /// `[pair][row][2]`: the int8 weights of inputs 2p and 2p+1 of each row, as i16.
    weights: Vec<i16>,
    bias: Vec<i32>,
    multiplier: Vec<i32>,
    shift: Vec<u32>,
    /// Per-row requantization constants in the lane orders of the SIMD kernels.
    lanes: Lanes,
    out_frac_bits: u8,
    activation: Activation,
    /// `[input][row]` f32 weights (the dequantized int8 ones, `Layer::float_weight`), rows padded
    /// to `out_pad`.
    float_weights: Vec<f32>,
    float_bias: Vec<f32>,
}

impl PackedLayer {
    fn new(layer: &Layer<'_>) -> PackedLayer {
        let (inputs, outputs) = (layer.inputs(), layer.outputs());
        let in_pairs = inputs.div_ceil(2);
        let out_pad = outputs.div_ceil(16) * 16;
        let mut weights = alloc::vec![0i16; in_pairs * out_pad * 2];
        let mut float_weights = alloc::vec![0f32; inputs * out_pad];
        for (p, pair) in weights.chunks_exact_mut(out_pad * 2).enumerate() {
            for (o, w) in pair.chunks_exact_mut(2).take(outputs).enumerate() {
                for (k, slot) in w.iter_mut().enumerate() {
                    if 2 * p + k < inputs {
                        *slot = i16::from(layer.weight_i8(o, 2 * p + k));
                    }
                }
            }
        }
        for (i, row) in float_weights.chunks_exact_mut(out_pad).enumerate() {
            for (o, slot) in row.iter_mut().take(outputs).enumerate() {
                *slot = layer.float_weight(o, i);
            }
        }
        let row = |o: usize| (o < outputs).then_some(o);
        let requant =
            |o: usize| row(o).map_or(Requant { multiplier: 0, shift: 1 }, |o| layer.requant(o));
        let bias = (0..out_pad).map(|o| row(o).map_or(0, |o| layer.bias(o))).collect();
        let multiplier: Vec<i32> = (0..out_pad).map(|o| requant(o).multiplier).collect();
        let shift: Vec<u32> = (0..out_pad).map(|o| requant(o).shift).collect();
        let lanes = Lanes::new(&multiplier, &shift);
        let float_bias =
            (0..out_pad).map(|o| row(o).map_or(0.0, |o| layer.float_bias(o))).collect();
        PackedLayer {
            in_pairs,
            outputs,
            out_pad,
            weights,
            bias,
            multiplier,
            shift,
            lanes,
            out_frac_bits: layer.out_frac_bits(),
            activation: layer.activation(),
            float_weights,
            float_bias,
        }
    }

    /// Which 8-row blocks to compute: all of them, or for the last layer only those holding a
    /// selected row.
    fn blocks(&self, last: bool, rows: u16) -> u32 {
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

    /// The scalar twin: exactly the integer layer of FORMAT.md §6.6 over the prepared layout.
    fn forward_scalar(&self, x: &[i16; MAX_WIDTH], y: &mut [i16; MAX_WIDTH], blocks: u32) {
        self.forward_scalar_from(x, &self.bias, self.in_pairs, y, blocks);
    }

    /// The layer with the accumulators starting at `init` (per row) instead of the bias, and
    /// only input pairs `0..pairs` summed: with `init` = bias + the sum over the other pairs
    /// (`partial_sums`) this is the whole layer, as integer sums do not depend on their order.
    fn forward_scalar_from(
        &self,
        x: &[i16; MAX_WIDTH],
        init: &[i32],
        pairs: usize,
        y: &mut [i16; MAX_WIDTH],
        blocks: u32,
    ) {
        let row_len = 2 * self.out_pad;
        for (b, out) in y.chunks_exact_mut(8).take(self.out_pad / 8).enumerate() {
            if blocks & (1 << b) == 0 {
                continue;
            }
            let mut acc = [0i32; 8];
            for (a, &start) in acc.iter_mut().zip(init.iter().skip(8 * b)) {
                *a = start;
            }
            let weights = self.weights.chunks_exact(row_len).take(pairs);
            for (pair, x) in weights.zip(x.chunks_exact(2)) {
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
    fn partial_sums(&self, x: &[i16; MAX_WIDTH], first_pair: usize, sums: &mut [i32; MAX_WIDTH]) {
        for (s, &b) in sums.iter_mut().zip(&self.bias) {
            *s = b;
        }
        let pairs = self.weights.chunks_exact(2 * self.out_pad).zip(x.chunks_exact(2));
        for (pair, x) in pairs.skip(first_pair) {
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
    fn forward_float(&self, x: &[f32; MAX_WIDTH], y: &mut [f32; MAX_WIDTH]) {
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

/// The MLP of one material, prepared for fast decoding (see the module documentation). It owns
/// its data and borrows nothing, so it can live next to the material in any handle; every call
/// takes the [`Material`] it was made from and refuses another one.
#[derive(Clone, Debug)]
pub struct Decoder {
    kernel: Kernel,
    layers: Vec<PackedLayer>,
    /// Address and length of the first layer's weights in the file: which material this is.
    identity: (usize, usize),
}

fn identity(material: &Material<'_>) -> (usize, usize) {
    material
        .mlp
        .layers
        .first()
        .map_or((0, 0), |l| (l.weights_i8.as_ptr() as usize, l.weights_i8.len()))
}

impl Decoder {
    /// Prepares `material` for the fastest kernel of this CPU.
    pub fn new(material: &Material<'_>) -> Decoder {
        Decoder {
            kernel: Kernel::best(),
            layers: material.mlp.layers.iter().map(PackedLayer::new).collect(),
            identity: identity(material),
        }
    }

    /// Prepares `material` for a given kernel; `BadArgument(Kernel)` if this CPU lacks it.
    pub fn with_kernel(material: &Material<'_>, kernel: Kernel) -> Result<Decoder, Error> {
        if !kernel.is_available() {
            return Err(Error::BadArgument {
                argument: Argument::Kernel,
                value: kernel as u64,
                limit: 0,
            });
        }
        Ok(Decoder { kernel, ..Decoder::new(material) })
    }

    /// The kernel computing the integer layers.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    fn check(&self, material: &Material<'_>) -> Result<(), Error> {
        if identity(material) == self.identity {
            Ok(())
        } else {
            Err(Error::BadArgument {
                argument: Argument::Material,
                value: identity(material).0 as u64,
                limit: self.identity.0 as u64,
            })
        }
    }

    /// Runs the integer layers on `x` (inputs on entry, outputs on exit).
    fn forward_int(&self, x: &mut [i16; MAX_WIDTH], rows: u16) {
        let mut spare = [0i16; MAX_WIDTH];
        let (mut from, mut to) = (&mut *x, &mut spare);
        let count = self.layers.len();
        for (li, layer) in self.layers.iter().enumerate() {
            let blocks = layer.blocks(li + 1 == count, rows);
            match self.kernel {
                #[cfg(target_arch = "x86_64")]
                Kernel::Avx2 => avx2::forward(layer, from, to, blocks),
                #[cfg(target_arch = "x86_64")]
                Kernel::Avx512Vnni => avx512::forward(layer, from, to, blocks),
                _ => layer.forward_scalar(from, to, blocks),
            }
            // Rows past this layer's width may hold stale values: the next layer's padding
            // column has weight 0, and the last layer's unselected rows are never read.
            core::mem::swap(&mut from, &mut to);
        }
        if count % 2 == 1 {
            x.copy_from_slice(&spare);
        }
    }

    /// [`Decoder::forward_int`] for the first `count` texels of a group, batched (each weight
    /// loaded once for the group) by the SIMD kernels. With `periodic`, the first layer starts
    /// from the span's sums over the periodic inputs of each texel's addressed x; the SIMD
    /// kernels then compute the whole group (texels from `count` on are ignored).
    fn forward_int_group(
        &self,
        xs: &mut [[i16; MAX_WIDTH]; GROUP],
        count: usize,
        rows: u16,
        periodic: Option<(&PeriodicSums<'_>, &[u32; GROUP])>,
    ) {
        if count < GROUP && periodic.is_none() {
            for x in xs.iter_mut().take(count) {
                self.forward_int(x, rows);
            }
            return;
        }
        let mut spare = [[0i16; MAX_WIDTH]; GROUP];
        let (mut from, mut to) = (&mut *xs, &mut spare);
        let layers = self.layers.len();
        for (li, layer) in self.layers.iter().enumerate() {
            let blocks = layer.blocks(li + 1 == layers, rows);
            let (init, pairs) = match periodic.filter(|_| li == 0) {
                Some((sums, at)) => (at.map(|x| sums.at(x)), sums.pairs),
                None => ([layer.bias.as_slice(); GROUP], layer.in_pairs),
            };
            match self.kernel {
                #[cfg(target_arch = "x86_64")]
                Kernel::Avx2 => avx2::forward_group_from(layer, from, init, pairs, to, blocks),
                #[cfg(target_arch = "x86_64")]
                Kernel::Avx512Vnni => {
                    avx512::forward_group_from(layer, from, init, pairs, to, blocks)
                }
                _ => {
                    let texels = from.iter().zip(to.iter_mut()).zip(init).take(count);
                    for ((x, y), init) in texels {
                        layer.forward_scalar_from(x, init, pairs, y, blocks);
                    }
                }
            }
            core::mem::swap(&mut from, &mut to);
        }
        if layers % 2 == 1 {
            *xs = spare;
        }
    }

    /// The first layer's sums over the inputs of `gather` that repeat along the row (positional
    /// encoding, LOD), one row per texel of the period, kept in `room` — when the inputs have
    /// such a tail and the span is long enough to repay the table.
    fn periodic_sums<'t>(
        &self,
        gather: &SpanGather<'_, '_, i16>,
        count: usize,
        room: &'t mut Option<[[i32; MAX_WIDTH]; MAX_X_PERIOD]>,
    ) -> Option<PeriodicSums<'t>> {
        let (latents, period) = gather.periodic_tail()?;
        let layer = self.layers.first()?;
        // Per texel: the pairs holding a latent feature (one may hold x's first feature too).
        let pairs = latents.div_ceil(2);
        // Building the table costs `period` texels' worth of the pairs it saves.
        if pairs >= layer.in_pairs || count < 2 * period as usize {
            return None;
        }
        let table = room.insert([[0; MAX_WIDTH]; MAX_X_PERIOD]);
        let mut x = [0i16; MAX_WIDTH];
        for (phase, sums) in (0..period).zip(table.iter_mut()) {
            gather.fixed_inputs(phase, &mut x);
            layer.partial_sums(&x, pairs, sums);
        }
        Some(PeriodicSums { pairs, mask: period - 1, table })
    }

    /// The integer codes of `count` texels of a span into `out` (`n` values each), all of it
    /// compiled for the kernel's instruction set.
    #[allow(clippy::too_many_arguments)]
    fn span_codes<T>(
        &self,
        material: &Material<'_>,
        at: (i64, i64, u32),
        count: usize,
        rows: (u16, usize),
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) {
        let job = SpanJob { decoder: self, material, at, count, rows, out, full_scale, narrow };
        self.run_compiled(job);
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn span_codes_here<T>(
        &self,
        material: &Material<'_>,
        (x0, y, mip): (i64, i64, u32),
        count: usize,
        (rows, n): (u16, usize),
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) {
        let mut slots = Slots::new();
        let mut gather = SpanGather::new(material, y, mip, &mut slots);
        let f = material.last_frac_bits();
        // Rows 0..n: the outputs are the first n values.
        let first_rows = rows & rows.wrapping_add(1) == 0;
        // Room for the table, filled (and zeroed first) only if the span uses it.
        let mut table = None;
        let periodic = self.periodic_sums(&gather, count, &mut table);
        let mut xs = [[0i16; MAX_WIDTH]; GROUP];
        let mut at = [0u32; GROUP];
        for (g, texels) in out.chunks_mut(GROUP * n).take(count.div_ceil(GROUP)).enumerate() {
            let k = (count - g * GROUP).min(GROUP);
            for ((i, x), at) in xs.iter_mut().enumerate().zip(&mut at).take(k) {
                *at = gather.inputs(x0.wrapping_add((g * GROUP + i) as i64), x);
            }
            self.forward_int_group(&mut xs, k, rows, periodic.as_ref().map(|p| (p, &at)));
            for (x, texel) in xs.iter().zip(texels.chunks_exact_mut(n)) {
                if first_rows {
                    // All 16 lanes at once (fixed length: vector code), then the n wanted.
                    let mut codes = [0i32; 16];
                    for (c, &v) in codes.iter_mut().zip(x) {
                        *c = code(v, f, full_scale);
                    }
                    for (out, &c) in texel.iter_mut().zip(&codes) {
                        *out = narrow(c);
                    }
                } else {
                    write_selected(rows, x, texel, |&v| narrow(code(v, f, full_scale)));
                }
            }
        }
    }

    fn forward_float(&self, x: &mut [f32; MAX_WIDTH]) {
        let mut y = [0f32; MAX_WIDTH];
        for layer in &self.layers {
            layer.forward_float(x, &mut y);
            core::mem::swap(x, &mut y);
        }
    }

    /// Integer decode to 8-bit codes, bit-identical to [`Material::decode_texel_u8`].
    pub fn decode_texel_u8(
        &self,
        material: &Material<'_>,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [u8],
    ) -> Result<usize, Error> {
        self.check(material)?;
        let rows = material.check_out(channels, out.len())?;
        Ok(self.texel_codes(material, (x, y, mip), rows, out, 255, |c| c as u8))
    }

    /// Integer decode to 16-bit codes, bit-identical to [`Material::decode_texel_u16`].
    pub fn decode_texel_u16(
        &self,
        material: &Material<'_>,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [u16],
    ) -> Result<usize, Error> {
        self.check(material)?;
        let rows = material.check_out(channels, out.len())?;
        Ok(self.texel_codes(material, (x, y, mip), rows, out, 65535, |c| c as u16))
    }

    /// Float decode (values in channel ranges) with f32 weights, bit-identical to
    /// [`Material::decode_texel`] (which dequantizes each weight where it uses it).
    pub fn decode_texel(
        &self,
        material: &Material<'_>,
        x: i64,
        y: i64,
        mip: u32,
        channels: ChannelMask,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        self.check(material)?;
        let rows = material.check_out(channels, out.len())?;
        Ok(self.texel_float(material, (x, y, mip), rows, out))
    }

    /// Filtered sample, equal to [`Material::sample`] but decoding its texels with this
    /// decoder (a bilinear sample is 4 texel decodes, a trilinear one 8).
    pub fn sample(
        &self,
        material: &Material<'_>,
        req: &SampleRequest,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        self.check(material)?;
        material.sample_with(req, out, &|x, y, mip, channels, precision, out| {
            let rows = material.check_out(channels, out.len())?;
            Ok(match precision {
                Precision::Float => {
                    let mut io = material.inputs(x, y, mip);
                    self.forward_float(&mut io);
                    write_selected(rows, &io, out, |v| unit(*v))
                }
                Precision::Integer => {
                    self.texel_codes(material, (x, y, mip), rows, out, 255, |c| c as f32 / 255.0)
                }
            })
        })
    }

    /// Integer decode of `count` consecutive texels of row `y` from column `x0` (addressed like
    /// single texels), packed: `count · channels` codes. Returns how many values were written.
    #[allow(clippy::too_many_arguments)] // a texel address, a span, a mask and the output
    pub fn decode_span_u8(
        &self,
        material: &Material<'_>,
        x0: i64,
        y: i64,
        mip: u32,
        count: usize,
        channels: ChannelMask,
        out: &mut [u8],
    ) -> Result<usize, Error> {
        let (rows, n) = self.check_span(material, count, channels, out.len())?;
        self.span_codes(material, (x0, y, mip), count, (rows, n), out, 255, |c| c as u8);
        Ok(count * n)
    }

    /// Integer decode of a span to 16-bit codes, like [`Decoder::decode_span_u8`].
    #[allow(clippy::too_many_arguments)]
    pub fn decode_span_u16(
        &self,
        material: &Material<'_>,
        x0: i64,
        y: i64,
        mip: u32,
        count: usize,
        channels: ChannelMask,
        out: &mut [u16],
    ) -> Result<usize, Error> {
        let (rows, n) = self.check_span(material, count, channels, out.len())?;
        self.span_codes(material, (x0, y, mip), count, (rows, n), out, 65535, |c| c as u16);
        Ok(count * n)
    }

    /// Float decode (values in channel ranges) of a span, like [`Decoder::decode_span_u8`].
    #[allow(clippy::too_many_arguments)]
    pub fn decode_span_f32(
        &self,
        material: &Material<'_>,
        x0: i64,
        y: i64,
        mip: u32,
        count: usize,
        channels: ChannelMask,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        let (rows, n) = self.check_span(material, count, channels, out.len())?;
        let mut slots = Slots::new();
        let mut gather = SpanGather::new(material, y, mip, &mut slots);
        let mut io = [0f32; MAX_WIDTH];
        for (i, texel) in out.chunks_exact_mut(n).take(count).enumerate() {
            gather.inputs(x0.wrapping_add(i as i64), &mut io);
            self.forward_float(&mut io);
            material.write_ranged(rows, &io, texel);
        }
        Ok(count * n)
    }

    fn check_span(
        &self,
        material: &Material<'_>,
        count: usize,
        channels: ChannelMask,
        out_len: usize,
    ) -> Result<(u16, usize), Error> {
        self.check(material)?;
        let rows = material.resolve_channels(channels)?;
        let n = rows.count_ones() as usize;
        let needed = count.saturating_mul(n);
        if out_len < needed {
            return Err(Error::BadArgument {
                argument: Argument::Output,
                value: out_len as u64,
                limit: needed as u64,
            });
        }
        Ok((rows, n))
    }

    /// The integer codes of one texel into `out`, all of it (the gather too) compiled for the
    /// kernel's instruction set. Returns how many values were written.
    #[allow(clippy::too_many_arguments)]
    fn texel_codes<T>(
        &self,
        material: &Material<'_>,
        at: (i64, i64, u32),
        rows: u16,
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) -> usize {
        let job = TexelJob { decoder: self, material, at, rows, out, full_scale, narrow };
        self.run_compiled(job)
    }

    /// Runs `job` in code compiled for the kernel's instruction set.
    fn run_compiled<J: Job>(&self, job: J) -> J::Output {
        match self.kernel {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => avx2::with_avx2(job),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512Vnni => avx512::with_avx512(job),
            _ => job.run(),
        }
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn texel_codes_here<T>(
        &self,
        material: &Material<'_>,
        (x, y, mip): (i64, i64, u32),
        rows: u16,
        out: &mut [T],
        full_scale: i32,
        narrow: impl Fn(i32) -> T,
    ) -> usize {
        let mut io = material.inputs(x, y, mip);
        self.forward_int(&mut io, rows);
        let f = material.last_frac_bits();
        write_selected(rows, &io, out, |&v| narrow(code(v, f, full_scale)))
    }

    fn texel_float(
        &self,
        material: &Material<'_>,
        (x, y, mip): (i64, i64, u32),
        rows: u16,
        out: &mut [f32],
    ) -> usize {
        let mut io = material.inputs(x, y, mip);
        self.forward_float(&mut io);
        material.write_ranged(rows, &io, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn simd_kernels() -> Vec<Kernel> {
        [Kernel::Avx2, Kernel::Avx512Vnni].into_iter().filter(|k| k.is_available()).collect()
    }

    fn run(
        kernel: Kernel,
        l: &PackedLayer,
        x: &[i16; MAX_WIDTH],
        y: &mut [i16; MAX_WIDTH],
        blocks: u32,
    ) {
        match kernel {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => avx2::forward(l, x, y, blocks),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512Vnni => avx512::forward(l, x, y, blocks),
            _ => l.forward_scalar(x, y, blocks),
        }
    }

    fn run_group(
        kernel: Kernel,
        l: &PackedLayer,
        xs: &[[i16; MAX_WIDTH]; GROUP],
        init: [&[i32]; GROUP],
        pairs: usize,
        ys: &mut [[i16; MAX_WIDTH]; GROUP],
        blocks: u32,
    ) {
        match kernel {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => avx2::forward_group_from(l, xs, init, pairs, ys, blocks),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512Vnni => avx512::forward_group_from(l, xs, init, pairs, ys, blocks),
            _ => {
                for ((x, y), init) in xs.iter().zip(ys.iter_mut()).zip(init) {
                    l.forward_scalar_from(x, init, pairs, y, blocks);
                }
            }
        }
    }

    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            // xorshift64*
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        fn range(&mut self, lo: i64, hi: i64) -> i64 {
            lo + (self.next() % (hi - lo + 1) as u64) as i64
        }
        /// Mostly uniform, sometimes a bound: extremes are where shortcuts break.
        fn edgy(&mut self, lo: i64, hi: i64) -> i64 {
            match self.next() % 8 {
                0 => lo,
                1 => hi,
                2 => self.range(-2, 2).clamp(lo, hi),
                _ => self.range(lo, hi),
            }
        }
    }

    fn layer(rng: &mut Rng, inputs: usize, outputs: usize) -> PackedLayer {
        let in_pairs = inputs.div_ceil(2);
        let out_pad = outputs.div_ceil(16) * 16;
        let mut weights = alloc::vec![0i16; in_pairs * out_pad * 2];
        for (p, pair) in weights.chunks_exact_mut(2 * out_pad).enumerate() {
            for (o, w) in pair.chunks_exact_mut(2).take(outputs).enumerate() {
                for (k, slot) in w.iter_mut().enumerate() {
                    if 2 * p + k < inputs && o < outputs {
                        *slot = rng.edgy(-128, 127) as i16;
                    }
                }
            }
        }
        let live = |o: usize| o < outputs;
        let bias: Vec<i32> = (0..out_pad)
            .map(|o| if live(o) { rng.edgy(-(1 << 30), 1 << 30) as i32 } else { 0 })
            .collect();
        let multiplier: Vec<i32> = (0..out_pad)
            .map(|o| match (live(o), rng.next() % 6) {
                (false, _) | (true, 0) => 0,
                _ => rng.edgy(1 << 30, i64::from(i32::MAX)) as i32,
            })
            .collect();
        let shift: Vec<u32> = (0..out_pad)
            .map(|o| if live(o) && multiplier[o] != 0 { rng.edgy(1, 62) as u32 } else { 1 })
            .collect();
        PackedLayer {
            in_pairs,
            outputs,
            out_pad,
            weights,
            bias,
            lanes: Lanes::new(&multiplier, &shift),
            multiplier,
            shift,
            out_frac_bits: rng.edgy(1, 14) as u8,
            activation: if rng.next().is_multiple_of(2) {
                Activation::None
            } else {
                Activation::HardGelu
            },
            float_weights: Vec::new(),
            float_bias: Vec::new(),
        }
    }

    /// Every SIMD layer this CPU runs against the scalar twin on random layers of every shape class (one block,
    /// 4-block runs plus a remainder, odd input counts) with extreme weights, inputs, biases,
    /// multipliers and shifts, and every block selection.
    #[test]
    fn simd_layers_match_the_scalar_twin() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        for trial in 0..4000 {
            let inputs = rng.range(1, MAX_WIDTH as i64) as usize;
            let outputs = rng.range(1, MAX_WIDTH as i64) as usize;
            let l = layer(&mut rng, inputs, outputs);
            let mut x = [0i16; MAX_WIDTH];
            for v in x.iter_mut().take(2 * l.in_pairs) {
                *v = rng.edgy(i64::from(i16::MIN), i64::from(i16::MAX)) as i16;
            }
            let blocks = if trial % 3 == 0 { rng.next() as u32 } else { u32::MAX };
            let mut scalar = [7i16; MAX_WIDTH];
            l.forward_scalar(&x, &mut scalar, blocks);
            // The group forms: texel 2 is `x` from the bias; in even trials the others start
            // from random rows, and all sum a random number of pairs.
            let mut xs = [[0i16; MAX_WIDTH]; GROUP];
            let starts: Vec<Vec<i32>> = (0..GROUP)
                .map(|_| (0..l.out_pad).map(|_| rng.edgy(-(1 << 30), 1 << 30) as i32).collect())
                .collect();
            let mut init = [l.bias.as_slice(); GROUP];
            for (t, v) in xs.iter_mut().enumerate() {
                for (i, slot) in v.iter_mut().enumerate().take(2 * l.in_pairs) {
                    *slot = if t == 2 { x[i] } else { rng.edgy(-32768, 32767) as i16 };
                }
                if t != 2 && trial % 2 == 0 {
                    init[t] = &starts[t];
                }
            }
            let pairs =
                if trial % 2 == 0 { rng.range(0, l.in_pairs as i64) as usize } else { l.in_pairs };
            for kernel in simd_kernels() {
                let mut ys = [[7i16; MAX_WIDTH]; GROUP];
                run_group(kernel, &l, &xs, init, pairs, &mut ys, blocks);
                for (t, (xt, yt)) in xs.iter().zip(&ys).enumerate() {
                    let mut want = [7i16; MAX_WIDTH];
                    l.forward_scalar_from(xt, init[t], pairs, &mut want, blocks);
                    if t == 2 && pairs == l.in_pairs {
                        assert_eq!(want, scalar, "the scalar forms differ, trial {trial}");
                    }
                    for b in (0..l.out_pad / 8).filter(|b| blocks & (1 << b) != 0) {
                        let rows = 8 * b..8 * b + 8;
                        assert_eq!(
                            yt[rows.clone()],
                            want[rows],
                            "{kernel:?} group texel {t} trial {trial}"
                        );
                    }
                }
            }
            for kernel in simd_kernels() {
                let mut simd = [7i16; MAX_WIDTH];
                run(kernel, &l, &x, &mut simd, blocks);
                for b in 0..l.out_pad / 8 {
                    if blocks & (1 << b) != 0 {
                        let rows = 8 * b..8 * b + 8;
                        assert_eq!(simd[rows.clone()], scalar[rows], "{kernel:?} trial {trial}");
                    }
                }
            }
        }
    }

    /// Requantization alone over a dense sweep of shifts and accumulators near every power of two.
    #[test]
    fn simd_requantization_matches_the_scalar_twin_at_every_shift() {
        let mut rng = Rng(42);
        for shift in 1..=62u32 {
            for activation in [Activation::None, Activation::HardGelu] {
                let mut l = layer(&mut rng, 1, 8);
                let live = 8;
                l.weights.iter_mut().for_each(|w| *w = 0);
                l.activation = activation;
                for o in 0..live {
                    l.multiplier[o] = rng.edgy(1 << 30, i64::from(i32::MAX)) as i32;
                    l.shift[o] = shift;
                }
                l.lanes = Lanes::new(&l.multiplier, &l.shift);
                for _ in 0..64 {
                    for b in l.bias.iter_mut().take(live) {
                        let e = rng.range(0, 31) as u32;
                        let v = (rng.range(-1, 1) << e) + rng.range(-1, 1);
                        *b = v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
                    }
                    let x = [0i16; MAX_WIDTH];
                    let mut scalar = [0i16; MAX_WIDTH];
                    l.forward_scalar(&x, &mut scalar, 1);
                    for kernel in simd_kernels() {
                        let mut simd = [0i16; MAX_WIDTH];
                        run(kernel, &l, &x, &mut simd, 1);
                        assert_eq!(
                            simd[..8],
                            scalar[..8],
                            "{kernel:?} shift {shift}, bias {:?}",
                            l.bias
                        );
                    }
                }
            }
        }
    }
}

//! The tiled kernel (tiled.wgsl): a pipeline per material shape, and the packed weights and row
//! tables it reads. docs/GPU.md ("The tiled kernel") argues the arithmetic.

use crate::layout::{self, LayerRecord, NeuralHeader, RequantRow, ShaderLayout};
use crate::measure::Part;
use nmat_core::{Layer, Material, Neural};
use std::fmt::Write as _;

/// Which kernel decodes a material's regions and requests. Every kernel gives the same codes
/// (the CPU's); they differ in speed only.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// Layers as 16×16×16 cooperative matrix multiply-adds (tensor cores) on f16 operands that
    /// hold the int8 weights and the activations' bytes exactly, summed in f32 below 2^24
    /// (matrix.wgsl). Where the device has wgpu's cooperative matrices with that configuration
    /// ([`crate::matrix_usable`]) and a subgroup size that does not vary.
    Matrix,
    /// Tiled (4 rows × 4 texels per invocation over workgroup memory), products from
    /// `dot4I8Packed` (two per four W8A16 multiply-adds). Where the device's shader language has
    /// it.
    Dot4,
    /// Tiled, products from 32-bit multiply-adds. Any device.
    Int32,
    /// One texel per invocation with each row's sum written out for the material's shape (a
    /// layer's inputs in registers, weights at constant offsets, no barrier between layers),
    /// products from 32-bit multiply-adds (unrolled.wgsl). Any device.
    UnrolledInt32,
    /// [`Kernel::UnrolledInt32`] with products from `dot4I8Packed` (two per four W8A16
    /// multiply-adds). Where the device's shader language has it.
    UnrolledDot4,
    /// One texel per invocation, everything read through the material's descriptors: the first
    /// kernel, kept as the reference (and used by BC transcoding).
    Reference,
}

impl Kernel {
    /// Every kernel, in the order every kernel list of the workspace has (nmat-core's
    /// `Kernel::ALL`, nmat-encode's `TrainKernel::ALL`): the simplest first, the one expected
    /// fastest last. Which is fastest depends on the GPU: [`crate::Context::upload`] measures
    /// them, and takes them from the end only where it cannot (a software adapter).
    pub const ALL: [Kernel; 6] = [
        Kernel::Reference,
        Kernel::UnrolledInt32,
        Kernel::UnrolledDot4,
        Kernel::Int32,
        Kernel::Dot4,
        Kernel::Matrix,
    ];

    /// Whether its products come from `dot4I8Packed` (its tables then fold 128 · Σ w into each
    /// row's bias: tiled_dot4.wgsl).
    pub(crate) fn dot4(self) -> bool {
        matches!(self, Kernel::Dot4 | Kernel::UnrolledDot4)
    }

    /// How people read it ("tiled dot4"): log lines, errors, `nmat bench --gpu`'s rows.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Matrix => "matrix",
            Kernel::Dot4 => "tiled dot4",
            Kernel::Int32 => "tiled i32",
            Kernel::UnrolledInt32 => "unrolled i32",
            Kernel::UnrolledDot4 => "unrolled dot4",
            Kernel::Reference => "reference",
        }
    }

    /// Its name in text nmat reads back ([`crate::Context::kernel_choices`]) and on the command
    /// line (`nmat bench --gpu --kernel`): `reference`, `unrolled-i32`, `unrolled-dot4`, `i32`,
    /// `dot4`, `matrix`.
    pub fn id(self) -> &'static str {
        match self {
            Kernel::Matrix => "matrix",
            Kernel::Dot4 => "dot4",
            Kernel::Int32 => "i32",
            Kernel::UnrolledInt32 => "unrolled-i32",
            Kernel::UnrolledDot4 => "unrolled-dot4",
            Kernel::Reference => "reference",
        }
    }

    /// The kernel whose [`Kernel::id`] is `id`.
    pub fn from_id(id: &str) -> Option<Kernel> {
        Kernel::ALL.into_iter().find(|k| k.id() == id)
    }
}

/// Texels per workgroup the tiled kernel tries, largest first (`NMAT_WGPU_TILED_TEXELS=P`, one
/// of them, asks for fewer: for measuring).
const TEXELS: [u32; 5] = [64, 32, 16, 8, 4];
/// Words per row in a layer's row table (a [`RequantRow`]).
const ROW_WORDS: usize = std::mem::size_of::<RequantRow>() / 4;

/// What a tiled pipeline is specialised to: widths are literals in its source.
pub(crate) struct Shape {
    /// Texels per workgroup (`P`).
    pub texels: u32,
    /// The widest layer (inputs or outputs) rounded up to 4 (`WMAX`).
    wmax: u32,
    channels: u32,
    /// Per layer: words of 4 inputs per row, groups of 4 rows.
    layers: Vec<(u32, u32)>,
}

impl Shape {
    /// The shape of `m`'s network for `kernel` (tiled ones only), with as many texels per
    /// workgroup as `workgroup_bytes` of workgroup memory allow.
    pub fn new(
        (m, n): (&Material<'_>, &Neural<'_>),
        kernel: Kernel,
        workgroup_bytes: u32,
    ) -> Option<Shape> {
        let layers = n.mlp().layers();
        let wmax =
            layers.iter().flat_map(|l| [l.inputs(), l.outputs()]).max()?.next_multiple_of(4) as u32;
        let channels = m.channel_count() as u32;
        // Activation buffers (two) and the staged codes, in bytes per texel.
        let per_texel = match kernel {
            Kernel::Dot4 => 4 * wmax + 4 * channels,
            Kernel::Int32 => 8 * wmax + 4 * channels,
            Kernel::Reference | Kernel::Matrix | Kernel::UnrolledInt32 | Kernel::UnrolledDot4 => {
                return None;
            }
        };
        let fits = |p: &u32| p * per_texel <= workgroup_bytes;
        // The most that fit, or fewer where `NMAT_WGPU_TILED_TEXELS` asks (for measuring).
        let asked = std::env::var("NMAT_WGPU_TILED_TEXELS").ok().and_then(|v| v.parse().ok());
        let texels = match asked.filter(|p| TEXELS.contains(p) && fits(p)) {
            Some(p) => p,
            None => TEXELS.into_iter().find(fits)?,
        };
        let layers = layers
            .iter()
            .map(|l| (l.inputs().div_ceil(4) as u32, l.outputs().div_ceil(4) as u32))
            .collect();
        Some(Shape { texels, wmax, channels, layers })
    }

    /// The WGSL of the pipeline: this shape's constants and layer calls, then `decode`, with
    /// `features` (features.rs, unchecked); only `part` of the work where it is not
    /// [`Part::Whole`] (for timing: the codes are then wrong).
    pub fn source_part(&self, kernel: Kernel, part: Part, features: &str) -> String {
        let mut calls = String::new();
        if part == Part::Features {
            calls += "    features_sink(lid);\n    workgroupBarrier();\n";
        }
        for (l, &(kw, groups)) in self.layers.iter().enumerate() {
            if part == Part::Features {
                break;
            }
            let last = l + 1 == self.layers.len();
            let _ = writeln!(
                calls,
                "    layer(lid, {l}u, {kw}u, {groups}u, {}u, {last});\n    workgroupBarrier();",
                l % 2
            );
        }
        let products = match kernel {
            Kernel::Dot4 => include_str!("shaders/tiled_dot4.wgsl"),
            _ => include_str!("shaders/tiled_i32.wgsl"),
        };
        format!(
            "const P: u32 = {}u;\nconst WMAX: u32 = {}u;\nconst CH: u32 = {}u;\n\
             const PART: u32 = {}u;\n{}\
             fn layers(lid: u32) {{\n{calls}}}\n{}\n{}\n{products}\n{}\n{}\n",
            self.texels,
            self.wmax,
            self.channels,
            part.code(),
            Part::STAND_IN_WGSL,
            crate::layout::texel_wgsl_with(features, crate::unrolled::GENERIC_NETWORK),
            crate::layout::decode_wgsl(),
            include_str!("shaders/requant.wgsl"),
            include_str!("shaders/tiled.wgsl"),
        ) + &crate::layout::batch_wgsl()
    }
}

/// Appends the tiled kernel's tables of every layer to `desc` (a neural descriptor without
/// them), sets the layer records' `packed_at` and `requant_at`, and the header's
/// `network_key_lo`/`_hi` to `network_key` (the sampling module's unrolled network on these
/// tables: unrolled.rs, `SampleNetwork`; 0 for none).
pub(crate) fn append_tables(
    desc: &mut Vec<u32>,
    n: &Neural<'_>,
    dot4: bool,
    network_key: [u32; 2],
) {
    let mut head: NeuralHeader = layout::read(desc, 0);
    [head.network_key_lo, head.network_key_hi] = network_key;
    layout::write(desc, 0, &head);
    for (l, layer) in n.mlp().layers().iter().enumerate() {
        let rows = layer.outputs().next_multiple_of(4);
        let kw = layer.inputs().div_ceil(4);
        let packed_at = desc.len() as u32;
        for o in 0..rows {
            for j in 0..kw {
                let byte = |b: usize| {
                    let i = 4 * j + b;
                    if o < layer.outputs() && i < layer.inputs() {
                        u32::from(layer.weight_i8(o, i) as u8)
                    } else {
                        0
                    }
                };
                desc.push(byte(0) | byte(1) << 8 | byte(2) << 16 | byte(3) << 24);
            }
        }
        let requant_at = desc.len() as u32;
        for o in 0..rows {
            desc.extend(row_table(layer, o, dot4));
        }
        let at = head.layers_at as usize + LayerRecord::WORDS * l;
        let record: LayerRecord = layout::read(desc, at);
        layout::write(desc, at, &LayerRecord { packed_at, requant_at, ..record });
    }
}

/// Row `o`'s [`RequantRow`]: bias, m, s, u, m', m'/2^u as f32, lo, hi. A padding row
/// (o ≥ outputs) requantizes everything to 0.
fn row_table(layer: &Layer<'_>, o: usize, dot4: bool) -> [u32; ROW_WORDS] {
    if o >= layer.outputs() {
        return bytemuck::cast(RequantRow { s: 1, u: 1, ..RequantRow::default() });
    }
    let rq = layer.requant(o);
    let (lo, hi) = rq.saturation_range();
    let mut bias = layer.bias(o);
    if dot4 {
        let sum: i32 = (0..layer.inputs()).map(|i| i32::from(layer.weight_i8(o, i))).sum();
        bias = bias.wrapping_add(128 * sum);
    }
    let m = rq.multiplier as u32;
    let (u, mp, c) = narrow(m, rq.shift, lo, hi).unwrap_or((0, 0, 0.0));
    let row = RequantRow {
        bias: bias as u32,
        m,
        s: rq.shift,
        u,
        mp,
        c: c.to_bits(),
        lo: lo as u32,
        hi: hi as u32,
    };
    bytemuck::cast(row)
}

/// The 32-bit requantization of a row with multiplier `m`, shift `s` and saturation range
/// `[lo, hi]`, where tiled.wgsl's argument holds: `(u, m', m'/2^u)` with m' = m >> (s − u),
/// m' < 2^24, u ≤ 31, |acc| ≤ 2^24 and |acc · m'/2^u| ≤ 2^20 on the range; `None` otherwise
/// (the 64-bit path).
fn narrow(m: u32, s: u32, lo: i32, hi: i32) -> Option<(u32, u32, f32)> {
    if m == 0 {
        return Some((1, 0, 0.0));
    }
    let z = m.trailing_zeros().min(s - 1);
    let (u, mp) = (s - z, m >> z);
    let reach = i64::from(lo).abs().max(i64::from(hi).abs());
    let c = f64::from(mp) / f64::from(2u32).powi(u as i32);
    let fits =
        u <= 31 && mp < 1 << 24 && reach <= 1 << 24 && reach as f64 * c <= f64::from(1u32 << 20);
    fits.then_some((u, mp, c as f32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nmat_core::{Container, Requant};
    use nmat_tests::generate::{generate, golden_and_random_configs};

    /// Both tiled kernels' WGSL for every golden fixture's network (1 to 16 channels, 2 to 4
    /// layers up to 64 wide) and 64 random valid materials' (odd widths, 1 to 4 layers, NTC and
    /// NBC layouts) parses and validates in naga (on a device that refuses a source the kernel
    /// is only skipped, so this is where a broken source shows on every machine).
    #[test]
    fn the_tiled_kernels_validate_for_every_fixture_shape() {
        for cfg in golden_and_random_configs(64) {
            let bytes = generate(&cfg).to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            for kernel in [Kernel::Int32, Kernel::Dot4] {
                let n = m.neural().expect("a neural fixture");
                let shape = Shape::new((&m, n), kernel, 16384).expect("a shape in 16 KiB");
                // The kernel, and the pipelines that time its parts alone.
                for part in [Part::Whole, Part::Features, Part::Layers] {
                    let features = crate::features::Features::new(n).wgsl(false);
                    let source = shape.source_part(kernel, part, &features);
                    crate::naga_check::validate(&format!("{cfg:?} {kernel:?} {part:?}"), &source);
                }
            }
        }
    }

    /// requant.wgsl's `requant_with` step by step in Rust (f32 and wrapping i32 as WGSL has them).
    fn requant_row(acc: i32, table: [u32; ROW_WORDS]) -> i32 {
        let [_, m, s, u, mp, c, lo, hi] = table;
        let acc = acc.clamp(lo as i32, hi as i32);
        if u != 0 {
            let mut q = (acc as f32 * f32::from_bits(c) + 0.5).floor() as i32;
            let e = acc.wrapping_mul(mp as i32).wrapping_sub(q.wrapping_shl(u));
            let half = 1i32 << (u - 1);
            q += if e < -half { -1 } else { 0 } + if e >= half { 1 } else { 0 };
            return q.clamp(-32768, 32767);
        }
        let negative = acc < 0;
        let p = u64::from(acc.unsigned_abs()) * u64::from(m);
        let add = (1u64 << (s - 1)) - u64::from(negative);
        let r = ((p + add) >> s) as u32;
        let v = if negative { (r as i32).wrapping_neg() } else { r as i32 };
        v.clamp(-32768, 32767)
    }

    fn table(m: u32, s: u32) -> [u32; ROW_WORDS] {
        let (lo, hi) = Requant { multiplier: m as i32, shift: s }.saturation_range();
        let (u, mp, c) = narrow(m, s, lo, hi).unwrap_or((0, 0, 0.0));
        [0, m, s, u, mp, c.to_bits(), lo as u32, hi as u32]
    }

    /// Both paths equal `Requant::apply` saturated to i16 on the accumulators around every
    /// rounding and saturation boundary and on a spread of others, for multipliers and shifts
    /// like those of trained files (shifts 34–43, multipliers = 24-bit mantissa << 7) and the
    /// extremes (shift 1 and 62, multipliers 2^30 and 2^31 − 1, 0).
    #[test]
    fn both_requantization_paths_equal_the_cpu() {
        let mut state = 0x2545_F491_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut rows: Vec<(u32, u32)> = vec![(0, 1), (0, 40)];
        for s in [1, 2, 7, 8, 16, 24, 30, 31, 32, 33, 40, 50, 61, 62] {
            rows.extend([(1 << 30, s), ((1 << 31) - 1, s)]);
        }
        for _ in 0..400 {
            let mantissa = (next() as u32 & 0x007F_FFFF) | 0x0080_0000;
            rows.push((mantissa << 7, 30 + (next() % 16) as u32));
        }
        let (mut narrow_rows, mut wide_rows) = (0, 0);
        for (m, s) in rows {
            let t = table(m, s);
            if t[3] != 0 {
                narrow_rows += 1
            } else {
                wide_rows += 1
            }
            let rq = Requant { multiplier: m as i32, shift: s };
            let (lo, hi) = rq.saturation_range();
            let mut accs = vec![i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX - 1, i32::MAX];
            for edge in [lo, hi] {
                accs.extend((-3..=3).map(|d| edge.saturating_add(d)));
            }
            // Accumulators where the rounded value steps: acc ≈ (k − 1/2) · 2^s / m.
            for k in [-32768i128, -1000, -1, 0, 1, 7, 1000, 32767] {
                if m != 0 {
                    let at = ((2 * k - 1) << (s - 1)) / i128::from(m);
                    let at = at.clamp(i128::from(i32::MIN) + 2, i128::from(i32::MAX) - 2) as i32;
                    accs.extend((-2..=2).map(|d| at + d));
                }
            }
            accs.extend((0..200).map(|_| next() as i32 >> (next() % 31)));
            for acc in accs {
                let want = rq.apply(acc).clamp(-32768, 32767) as i32;
                assert_eq!(requant_row(acc, t), want, "acc {acc}, m {m}, s {s}, table {t:?}");
            }
        }
        // Both paths were exercised.
        assert!(narrow_rows > 100 && wide_rows > 100, "{narrow_rows} narrow, {wide_rows} wide");
    }
}

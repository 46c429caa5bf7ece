//! The matrix kernel (matrix.wgsl): layers as 16×16×16 cooperative matrix multiply-adds (tensor
//! cores), a pipeline per material shape. docs/GPU.md ("The matrix kernel") argues exactness.

use crate::measure::Part;
use nmat_core::{Material, Neural};
use std::fmt::Write as _;

/// The wgpu features the matrix kernel needs on the device.
pub const FEATURES: wgpu::Features = wgpu::Features::SHADER_F16
    .union(wgpu::Features::SUBGROUP)
    .union(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX);

/// Whether `configs` (an adapter's [`wgpu::Adapter::cooperative_matrix_properties`]) has the
/// configuration the matrix kernel uses: 16×16×16, f16 operands, f32 accumulators.
pub fn usable(configs: &[wgpu::CooperativeMatrixProperties]) -> bool {
    configs.iter().any(|c| {
        (c.m_size, c.n_size, c.k_size) == (16, 16, 16)
            && c.ab_type == wgpu::CooperativeScalarType::F16
            && c.cr_type == wgpu::CooperativeScalarType::F32
    })
}

/// How a workgroup is laid out: subgroups, texel blocks of 16 per subgroup, batches decoded
/// after staging the weights once. `NMAT_WGPU_MATRIX=NW,TB,BATCHES` overrides it (for measuring).
const LAYOUT: (u32, u32, u32) = (4, 1, 4);

/// Elements added to the rows of the activations, the weights and the products in workgroup
/// memory, so that the 16 rows of a matrix load or store fall in different memory banks.
/// `NMAT_WGPU_MATRIX_PAD=A,W,S` overrides it (for measuring).
const PADS: (u32, u32, u32) = (8, 8, 4);

/// Whether a row block's products with the high and the low bytes go through workgroup memory
/// together (half the barriers, twice the memory of `sums`: matrix.wgsl) rather than one after
/// the other. `NMAT_WGPU_MATRIX_SUMS=paired` (or `split`) overrides it (for measuring).
const PAIRED: bool = false;

/// Whether the weights are read by the matrix loads straight from a storage buffer of f16 (bound
/// at [`WEIGHTS_GROUP`]) instead of being staged in workgroup memory: no staging and 2 bytes a
/// weight less workgroup memory (more workgroups per core, or more texels per subgroup), for
/// loads through the GPU's caches. `NMAT_WGPU_MATRIX_WEIGHTS=storage` (or `staged`) overrides
/// it (for measuring).
const STORAGE_WEIGHTS: bool = false;

/// The bind group of a matrix pipeline whose weights are in a storage buffer
/// ([`STORAGE_WEIGHTS`]): binding 0 of it, read-only, the f16 weights
/// ([`Shape::storage_weights`]).
pub(crate) const WEIGHTS_GROUP: u32 = 1;

/// The storage buffers per shader stage a matrix pipeline binds with its weights in storage:
/// the decode kernels' four and the weights (a device's limit must allow them).
pub(crate) const STORAGE_BUFFERS_WITH_WEIGHTS: u32 = 5;

/// How a source declares the weights of [`WEIGHTS_GROUP`]: a source containing it is compiled
/// with that group in its pipeline layout (`Context::pipeline`).
pub(crate) const WEIGHTS_BINDING: &str =
    "@group(1) @binding(0) var<storage, read> weights16: array<f16>;";

/// Three numbers `A,B,C` from the environment variable `name` (a measuring override), if they are
/// there and `valid`.
fn overridden(name: &str, valid: impl Fn([u32; 3]) -> bool) -> Option<(u32, u32, u32)> {
    let text = std::env::var(name).ok()?;
    let n: Vec<u32> = text.split(',').map(|x| x.trim().parse().ok()).collect::<Option<_>>()?;
    let [a, b, c] = <[u32; 3]>::try_from(n).ok()?;
    valid([a, b, c]).then_some((a, b, c))
}

/// What a matrix pipeline is specialised to: widths and offsets are literals in its source.
#[derive(Clone)]
pub(crate) struct Shape {
    /// Subgroups per workgroup, texel blocks per subgroup, batches per workgroup.
    warps: u32,
    blocks: u32,
    batches: u32,
    /// Invocations per subgroup.
    subgroup: u32,
    /// Row padding of the activations, weights and products ([`PADS`]).
    pads: (u32, u32, u32),
    /// The widest layer rounded up to 16 (`WMAX`).
    wmax: u32,
    channels: u32,
    /// Per layer: fan-in and rows rounded up to 16, and where its weights start in the staged
    /// array (rows `kpad + pads.1` apart).
    layers: Vec<(u32, u32, u32)>,
    /// Staged weights (f16) of all layers.
    total: u32,
    /// Per layer: its output fraction bits (so that hardGELU divides by a constant), its rows
    /// and whether it applies hardGELU — literals in its `finish` calls, which then read no
    /// layer record.
    finishes: Vec<(u32, usize, bool)>,
    /// Whether the matrix operations are emulated in scalar code (matrix_emulated.wgsl), for
    /// testing the kernel's structure on a device without matrix units.
    emulated: bool,
    /// Whether a row block's products with the high and low bytes go through `sums` together
    /// ([`PAIRED`]).
    paired: bool,
    /// Whether the weights are read from a storage buffer instead of staged in workgroup
    /// memory ([`STORAGE_WEIGHTS`]).
    storage: bool,
}

/// What a matrix pipeline is asked to be: the layout (subgroups, texel blocks per subgroup,
/// batches), pads, the products' round trip and where the weights are — the defaults, or the
/// measuring overrides.
#[derive(Clone, Copy, Debug)]
struct Asked {
    layout: (u32, u32, u32),
    pads: (u32, u32, u32),
    paired: bool,
    storage: bool,
}

impl Asked {
    const DEFAULT: Asked =
        Asked { layout: LAYOUT, pads: PADS, paired: PAIRED, storage: STORAGE_WEIGHTS };
}

/// The variant of an emulated matrix kernel ([`crate::Context::emulate_matrix_for_testing`]):
/// the products' round trip `paired` ([`PAIRED`]) or not, the weights in a storage buffer
/// ([`STORAGE_WEIGHTS`]) or staged; and the layout and pads where a test asks for other ones
/// than the defaults ([`crate::Context::emulate_matrix_layout_for_testing`]), as
/// `NMAT_WGPU_MATRIX` and `NMAT_WGPU_MATRIX_PAD` do for the real kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Emulation {
    pub paired: bool,
    pub storage_weights: bool,
    pub layout: Option<(u32, u32, u32)>,
    pub pads: Option<(u32, u32, u32)>,
}

/// Whether `NMAT_WGPU_MATRIX`'s subgroups, texel blocks and batches can be asked for.
pub(crate) fn valid_layout([w, b, n]: [u32; 3]) -> bool {
    [w, b, n].iter().all(|x| (1..=64).contains(x))
}

/// Whether `NMAT_WGPU_MATRIX_PAD`'s row pads can be asked for.
pub(crate) fn valid_pads([a, w, s]: [u32; 3]) -> bool {
    a.is_multiple_of(8) && w.is_multiple_of(8) && s.is_multiple_of(4) && a.max(w).max(s) <= 64
}

/// The invocations of an emulated subgroup.
const EMULATED_SUBGROUP: u32 = 32;

impl Shape {
    /// The shape of `m`'s network on `device`, or why the matrix kernel cannot decode it there.
    /// `emulated`: with the matrix operations in scalar code, in that variant, for testing
    /// ([`crate::Context::emulate_matrix_for_testing`]; needs `SHADER_F16` only).
    pub fn new(
        m: (&Material<'_>, &Neural<'_>),
        device: &wgpu::Device,
        emulated: Option<Emulation>,
    ) -> Result<Shape, &'static str> {
        let subgroup = if emulated.is_some() {
            if !device.features().contains(wgpu::Features::SHADER_F16) {
                return Err("the device has no f16 (wgpu feature SHADER_F16), which the \
                            emulated matrix kernel needs");
            }
            EMULATED_SUBGROUP
        } else {
            if !device.features().contains(FEATURES) {
                return Err("the device has no cooperative matrices (wgpu features SHADER_F16, \
                            SUBGROUP and EXPERIMENTAL_COOPERATIVE_MATRIX; default_device asks \
                            for them where the adapter has 16×16×16 f16 → f32)");
            }
            let info = device.adapter_info();
            if info.subgroup_min_size != info.subgroup_max_size
                || !(16..=128).contains(&info.subgroup_min_size)
            {
                return Err("the device's subgroup size varies or is unknown");
            }
            info.subgroup_min_size
        };
        let default = Asked::DEFAULT;
        let layout = emulated
            .and_then(|e| e.layout)
            .or_else(|| overridden("NMAT_WGPU_MATRIX", valid_layout))
            .unwrap_or(default.layout);
        let pads = emulated
            .and_then(|e| e.pads)
            .or_else(|| overridden("NMAT_WGPU_MATRIX_PAD", valid_pads))
            .unwrap_or(default.pads);
        let choice = |name: &str, yes: &str, no: &str, default: bool| match std::env::var(name) {
            Ok(v) if v == yes => true,
            Ok(v) if v == no => false,
            _ => default,
        };
        let (paired, storage) = match emulated {
            Some(e) => (e.paired, e.storage_weights),
            None => (
                choice("NMAT_WGPU_MATRIX_SUMS", "paired", "split", default.paired),
                choice("NMAT_WGPU_MATRIX_WEIGHTS", "storage", "staged", default.storage),
            ),
        };
        let limits = device.limits();
        if storage && limits.max_storage_buffers_per_shader_stage < STORAGE_BUFFERS_WITH_WEIGHTS {
            return Err("the weights in a storage buffer (NMAT_WGPU_MATRIX_WEIGHTS=storage) need \
                        5 storage buffers per shader stage; the device allows fewer");
        }
        let bytes = limits.max_compute_workgroup_storage_size;
        let shape = Shape::sized(m, subgroup, Asked { layout, pads, paired, storage }, bytes)?;
        Ok(Shape { emulated: emulated.is_some(), ..shape })
    }

    /// The shape of `m`'s network for the `Asked` layout, pads, round trip (`paired`) and
    /// weights (`storage` or staged) with subgroups of `subgroup` invocations and `limit` bytes of
    /// workgroup memory (fewer subgroups where the memory is short). Weights in a storage buffer
    /// take no row padding (no memory banks to spread them over).
    fn sized(
        (m, n): (&Material<'_>, &Neural<'_>),
        subgroup: u32,
        Asked { layout, mut pads, paired, storage }: Asked,
        limit: u32,
    ) -> Result<Shape, &'static str> {
        let (warps, blocks, batches) = layout;
        if storage {
            pads.1 = 0;
        }
        let pad = |n: usize| n.next_multiple_of(16) as u32;
        let mut layers = Vec::new();
        let mut total = 0;
        for l in n.mlp().layers() {
            let (kpad, opad) = (pad(l.inputs()), pad(l.outputs()));
            layers.push((kpad, opad, total));
            total += (kpad + pads.1) * opad;
        }
        let wmax = layers.iter().flat_map(|&(k, o, _)| [k, o]).max().ok_or("no layers")?;
        let channels = m.channel_count() as u32;
        // Workgroup memory: staged weights (unless in storage), the activations' high and low
        // bytes (f16), a row block of products (or two, paired) per subgroup and texel block
        // (f32) and the codes.
        let parts = if paired { 2 } else { 1 };
        let staged = if storage { 0 } else { 2 * total };
        let bytes = |w: u32| {
            let p = 16 * blocks * w;
            let sums = 64 * (16 + pads.2) * blocks * w * parts;
            staged + 4 * wmax * (p + pads.0) + sums + 4 * channels * p
        };
        let warps = (1..=warps)
            .rev()
            .find(|&w| bytes(w) <= limit)
            .ok_or("the network is too large for the device's workgroup memory")?;
        let gelu = |l: &nmat_core::Layer<'_>| l.activation() == nmat_core::Activation::HardGelu;
        let finishes = n.mlp().layers().iter();
        let finishes = finishes.map(|l| (u32::from(l.out_frac_bits()), l.outputs(), gelu(l)));
        let finishes = finishes.collect();
        Ok(Shape {
            warps,
            blocks,
            batches,
            subgroup,
            pads,
            wmax,
            channels,
            layers,
            total,
            finishes,
            emulated: false,
            paired,
            storage,
        })
    }

    /// Whether the weights are read from a storage buffer ([`WEIGHTS_GROUP`], laid out by
    /// [`Shape::storage_weights`]) rather than staged.
    pub fn weights_in_storage(&self) -> bool {
        self.storage
    }

    /// The weights as the kernel reads them from storage (and as `stage` lays them out in
    /// workgroup memory): per layer from its offset, its rows padded with zeros to a multiple of
    /// 16, each row its fan-in padded with zeros to a multiple of 16 (plus the row pad), every
    /// int8 weight as the bits of the f16 that holds it exactly.
    pub fn storage_weights(&self, n: &Neural<'_>) -> Vec<u16> {
        let mut words = vec![0u16; self.total as usize];
        for (layer, &(kpad, _, woff)) in n.mlp().layers().iter().zip(&self.layers) {
            let ws = (kpad + self.pads.1) as usize;
            for o in 0..layer.outputs() {
                for i in 0..layer.inputs() {
                    words[woff as usize + o * ws + i] = f16_bits(layer.weight_i8(o, i));
                }
            }
        }
        words
    }

    /// Texels per batch.
    fn batch(&self) -> u32 {
        16 * self.blocks * self.warps
    }

    /// Texels per workgroup.
    pub fn texels(&self) -> u32 {
        self.batch() * self.batches
    }

    /// The WGSL of the pipeline (entry point `matrix`) with `features` (features.rs, unchecked);
    /// only `part` of the work where it is not [`Part::Whole`] (for timing: the codes are then
    /// wrong).
    pub fn source_part(&self, part: Part, features: &str) -> String {
        let (mut stage, mut layers) = (String::new(), String::new());
        if part == Part::Features {
            layers += "    features_sink(lane, warp);\n    workgroupBarrier();\n";
        }
        for (l, &(kpad, opad, woff)) in self.layers.iter().enumerate() {
            let ws = kpad + self.pads.1;
            if !self.storage {
                let _ = writeln!(stage, "    stage(lid, {l}u, {kpad}u, {opad}u, {woff}u, {ws}u);");
            }
            if part != Part::Features {
                layers += &self.layer(l, kpad, opad, woff);
            }
        }
        // The weights: in workgroup memory, staged by every workgroup, or read from storage.
        let weights = if self.storage {
            format!("{WEIGHTS_BINDING}\n")
        } else {
            stage += "    workgroupBarrier();\n";
            include_str!("shaders/matrix_stage.wgsl").to_string()
        };
        // The entry points: invocation `lid` of workgroup `g`, lane `lane` of subgroup `warp`
        // (in an emulated kernel, numbered from lid: it has no subgroup operation).
        let (builtins, warp_lane, enable, emulation) = if self.emulated {
            ("", "lid / SG, lid % SG", "", include_str!("shaders/matrix_emulated.wgsl"))
        } else {
            (
                "@builtin(subgroup_id) warp: u32, @builtin(subgroup_invocation_id) lane: u32, ",
                "warp, lane",
                "enable wgpu_cooperative_matrix;\n",
                "",
            )
        };
        let (paired, parts) = (self.paired, if self.paired { 2 } else { 1 });
        let mut entries = String::new();
        for (entry, body) in [("matrix", "matrix_batches"), ("matrix_cache", "matrix_tiles")] {
            let _ = writeln!(
                entries,
                "@compute @workgroup_size(SG * NW)\nfn {entry}(\
                 @builtin(local_invocation_index) lid: u32, {builtins}\
                 @builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) \
                 {{\n    {body}(lid, {warp_lane}, wg.x + wg.y * groups.x);\n}}"
            );
        }
        format!(
            "enable f16;\n{enable}\
             const P: u32 = {}u;\nconst NW: u32 = {}u;\nconst TB: u32 = {}u;\n\
             const BATCHES: u32 = {}u;\nconst SG: u32 = {}u;\nconst AS: u32 = {}u;\n\
             const SS: u32 = {}u;\nconst SB: u32 = 16u * SS;\n\
             const PAIRED: bool = {paired};\nconst PARTS: u32 = {parts}u;\n\
             const PER_LANE: u32 = 256u * TB / SG;\n\
             const WMAX: u32 = {}u;\nconst CH: u32 = {}u;\nconst WTOTAL: u32 = {}u;\n\
             const PART: u32 = {}u;\n{weights}{}\
             fn stage_weights(lid: u32) {{\n{stage}}}\n\
             fn layers(lane: u32, warp: u32) {{\n{layers}}}\n{}\n{}\n{}\n{}\n{emulation}\n{}\n{entries}",
            self.batch(),
            self.warps,
            self.blocks,
            self.batches,
            self.subgroup,
            self.batch() + self.pads.0,
            16 + self.pads.2,
            self.wmax,
            self.channels,
            self.total,
            part.code(),
            Part::STAND_IN_WGSL,
            crate::layout::texel_wgsl_with(features, crate::unrolled::GENERIC_NETWORK),
            crate::layout::decode_wgsl(),
            include_str!("shaders/requant.wgsl"),
            include_str!("shaders/matrix.wgsl"),
            crate::layout::batch_wgsl(),
        )
    }

    /// Layer `l` in `layers(lane, warp)`: the products of every (texel block, row block) pair
    /// accumulated in registers over the fan-in (each weight block loaded once per step and
    /// used for every texel block), then per row block its products through workgroup memory
    /// into `finish`.
    fn layer(&self, l: usize, kpad: u32, opad: u32, woff: u32) -> String {
        let last = l + 1 == self.layers.len();
        let (frac, rows, gelu) = self.finishes[l];
        let (row_blocks, blocks) = (opad / 16, self.blocks);
        let mut s = format!("    {{ // layer {l}\n");
        // The accumulators, the loads and the multiply-adds, as cooperative matrix operations,
        // or emulated (matrix_emulated.wgsl: an accumulator is an array, an operand its offset;
        // the row blocks a loop, which lavapipe compiles faster).
        let ws = kpad + self.pads.1;
        if self.emulated {
            for tb in 0..blocks {
                let _ = writeln!(
                    s,
                    "    var h{tb} = EmuAccumulators();\n    var l{tb} = EmuAccumulators();"
                );
            }
            let _ = writeln!(s, "    for (var kb = 0u; kb < {}u; kb++) {{", kpad / 16);
            let _ = writeln!(s, "    for (var ob = 0u; ob < {row_blocks}u; ob++) {{");
            let _ = writeln!(s, "        let w = {woff}u + 16u * ob * {ws}u + 16u * kb;");
            for tb in 0..blocks {
                let _ = writeln!(
                    s,
                    "        let x{tb} = 16u * kb * AS + 16u * (warp * TB + {tb}u);\n        \
                     emu_mma(&h{tb}, ob, w, {ws}u, true, x{tb}, lane);\n        \
                     emu_mma(&l{tb}, ob, w, {ws}u, false, x{tb}, lane);"
                );
            }
            s += "    }\n";
        } else {
            for tb in 0..blocks {
                for ob in 0..row_blocks {
                    let _ = writeln!(
                        s,
                        "    var h{tb}_{ob} = coop_mat16x16<f32, C>();\n    \
                         var l{tb}_{ob} = coop_mat16x16<f32, C>();"
                    );
                }
            }
            let _ = writeln!(s, "    for (var kb = 0u; kb < {}u; kb++) {{", kpad / 16);
            for tb in 0..blocks {
                let _ = writeln!(
                    s,
                    "        let x{tb} = 16u * kb * AS + 16u * (warp * TB + {tb}u);\n        \
                     let bh{tb} = coopLoadT<coop_mat16x16<f16, B>>(&act_hi[x{tb}], AS);\n        \
                     let bl{tb} = coopLoadT<coop_mat16x16<f16, B>>(&act_lo[x{tb}], AS);"
                );
            }
            for ob in 0..row_blocks {
                let _ = writeln!(
                    s,
                    "        let w{ob} = coopLoadT<coop_mat16x16<f16, A>>(\
                     &weights16[{}u + 16u * kb], {ws}u);",
                    woff + 16 * ob * ws
                );
                for tb in 0..blocks {
                    let _ = writeln!(
                        s,
                        "        h{tb}_{ob} = coopMultiplyAdd(w{ob}, bh{tb}, h{tb}_{ob});\n        \
                         l{tb}_{ob} = coopMultiplyAdd(w{ob}, bl{tb}, l{tb}_{ob});"
                    );
                }
            }
        }
        // (Split, `finish` must not overwrite activations a lane may still be loading; paired,
        // the barrier after the stores is that one.)
        s += if self.paired { "    }\n" } else { "    }\n    workgroupBarrier();\n" };
        // Per row block `ob`: its products through workgroup memory into `finish`; `store`
        // writes the instruction that stores texel block tb's accumulator of one part.
        let round_trip = |s: &mut String, ob: &str, store: &dyn Fn(char, u32) -> String| {
            for part in ['h', 'l'] {
                for tb in 0..blocks {
                    let _ = writeln!(s, "    {}", store(part, tb));
                }
                s.push_str(match (part, self.paired) {
                    ('h', true) => "",
                    ('h', false) => {
                        "    workgroupBarrier();\n    collect(lane, warp);\n    workgroupBarrier();\n"
                    }
                    _ => "    workgroupBarrier();\n",
                });
            }
            let _ = writeln!(
                s,
                "    finish(lane, warp, {l}u, {ob}, {last}, {frac}u, {rows}u, {gelu});\n    \
                 workgroupBarrier();"
            );
        };
        // Where texel block tb's products of one part go (paired: the low bytes' after the
        // high bytes').
        let at = |part: char, tb: u32| {
            let lo = if self.paired && part == 'l' { " + LO" } else { "" };
            format!("SB * PARTS * (warp * TB + {tb}u){lo}")
        };
        if self.emulated {
            let _ = writeln!(s, "    for (var ob = 0u; ob < {row_blocks}u; ob++) {{");
            round_trip(&mut s, "ob", &|part, tb| {
                format!("emu_store(&{part}{tb}, ob, {}, SS, lane);", at(part, tb))
            });
            s += "    }\n";
        } else {
            for ob in 0..row_blocks {
                round_trip(&mut s, &format!("{ob}u"), &|part, tb| {
                    format!("coopStoreT({part}{tb}_{ob}, &sums[{}], SS);", at(part, tb))
                });
            }
        }
        s + "    }\n"
    }
}

/// The bits of the f16 that holds `v` exactly (every integer up to 2^11 in magnitude is one):
/// sign, exponent e + 15 for |v| in [2^e, 2^(e+1)), and the bits of |v| below its leading one
/// as the top bits of the 10-bit fraction.
fn f16_bits(v: i8) -> u16 {
    let a = u16::from(v.unsigned_abs());
    if a == 0 {
        return 0;
    }
    let e = 15 - a.leading_zeros() as u16; // 0..=7
    let sign = if v < 0 { 0x8000 } else { 0 };
    sign | (e + 15) << 10 | ((a << (10 - e)) & 0x3FF)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nmat_core::Container;
    use nmat_tests::generate::{
        FixtureConfig, generate, golden_and_random_configs, golden_configs,
    };

    /// naga's verdict on `source`: parsed, validated with every capability a device may lack
    /// (cooperative matrices, f16) and written as SPIR-V, as wgpu does on Vulkan.
    fn compile(source: &str) -> Result<Vec<u32>, String> {
        compile_with(source, naga::valid::Capabilities::all())
    }

    /// [`compile`] with only `capabilities`.
    fn compile_with(
        source: &str,
        capabilities: naga::valid::Capabilities,
    ) -> Result<Vec<u32>, String> {
        let (module, info) = crate::naga_check::validate_with(source, capabilities)?;
        let options = naga::back::spv::Options { lang_version: (1, 6), ..Default::default() };
        naga::back::spv::write_vec(&module, &info, &options, None).map_err(|e| e.to_string())
    }

    /// Whether `spirv` has OpCooperativeMatrixMulAddKHR (4459) and OpCooperativeMatrixLoadKHR
    /// (4457) instructions.
    fn has_matrix_ops(spirv: &[u32]) -> bool {
        let has = |op: u32| spirv.iter().any(|&w| w & 0xFFFF == op && w >> 16 >= 4);
        has(4459) && has(4457)
    }

    /// The value of f16 `bits` (normal numbers and zeros), read by the IEEE 754 binary16
    /// definition: (−1)^sign · 2^(exponent − 15) · (1 + fraction / 2^10).
    fn f16_value(bits: u16) -> f64 {
        let sign = if bits & 0x8000 != 0 { -1.0 } else { 1.0 };
        let exponent = i32::from(bits >> 10 & 0x1F);
        let fraction = f64::from(bits & 0x3FF);
        if exponent == 0 {
            return sign * fraction / 1024.0 * 2f64.powi(-14);
        }
        sign * (1.0 + fraction / 1024.0) * 2f64.powi(exponent - 15)
    }

    /// Every int8 weight becomes the f16 of the same value, zero as +0.
    #[test]
    fn every_int8_weight_is_its_f16() {
        for v in i8::MIN..=i8::MAX {
            assert_eq!(f16_value(f16_bits(v)), f64::from(v), "{v}");
        }
        assert_eq!(f16_bits(0), 0);
    }

    /// The weights of a kernel that reads them from storage: each layer's from its offset, row o
    /// and column i at `o · stride + i` equal to the network's weight, and zeros in the padding
    /// (rows and columns up to multiples of 16) — the layout `stage` gives the staged ones.
    #[test]
    fn weights_in_storage_are_laid_out_as_staged() {
        for cfg in golden_configs().into_iter().filter(|c| c.name.starts_with("ntc")) {
            let bytes = generate(&cfg).to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            let n = m.neural().expect("a neural fixture");
            let shape = Shape::sized((&m, n), 32, Asked { storage: true, ..Asked::DEFAULT }, 49152)
                .unwrap();
            let words = shape.storage_weights(n);
            assert_eq!(words.len() as u32, shape.total, "{}", cfg.name);
            let mut at = 0;
            for layer in n.mlp().layers() {
                let (kpad, opad) = (layer.inputs().next_multiple_of(16), layer.outputs());
                for o in 0..opad.next_multiple_of(16) {
                    for i in 0..kpad {
                        let want = if o < opad && i < layer.inputs() {
                            f64::from(layer.weight_i8(o, i))
                        } else {
                            0.0
                        };
                        assert_eq!(f16_value(words[at]), want, "{} ({o}, {i})", cfg.name);
                        at += 1;
                    }
                }
            }
            assert_eq!(at, words.len(), "{}", cfg.name);
        }
    }

    /// lavapipe runs no cooperative matrices, so CI cannot run this kernel: its WGSL for every
    /// golden fixture's network (1 to 16 channels, 2 to 4 layers up to 64 wide) and 64 random
    /// valid materials' (odd widths, NTC and NBC layouts) is valid for naga and becomes SPIR-V
    /// with the cooperative matrix instructions; the widest network the format allows (four
    /// layers of 128) is refused in 48 KiB of workgroup memory, not miscompiled.
    #[test]
    fn the_matrix_kernel_validates_for_every_fixture_shape() {
        let golden: Vec<&str> = golden_configs().iter().map(|cfg| cfg.name).collect();
        let mut configs = golden_and_random_configs(64);
        configs.push(FixtureConfig {
            hidden: vec![128, 128, 128],
            ..FixtureConfig::ntc("widest", 9, 32, 32, 16)
        });
        let mut refused = 0;
        for cfg in configs {
            let bytes = generate(&cfg).to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            let n = m.neural().expect("a neural fixture");
            let shape = match Shape::sized((&m, n), 32, Asked::DEFAULT, 49152) {
                Ok(shape) => shape,
                Err(reason) => {
                    assert_eq!(cfg.name, "widest", "{reason}");
                    // 4 layers of 128 × 128 f16 weights are 128 KiB.
                    assert!(
                        Shape::sized((&m, n), 32, Asked::DEFAULT, 1 << 18).is_ok(),
                        "{}",
                        cfg.name
                    );
                    refused += 1;
                    continue;
                }
            };
            assert_eq!(shape.texels() % 16, 0);
            if golden.contains(&cfg.name) && cfg.hidden.iter().all(|&h| h <= 64) {
                // The fixtures' networks up to 64 wide keep the 4 subgroups in 48 KiB.
                assert_eq!(shape.warps, LAYOUT.0, "{}", cfg.name);
            }
            let features = crate::features::Features::new(n).wgsl(false);
            let source = shape.source_part(Part::Whole, &features);
            let spirv = compile(&source).unwrap_or_else(|e| panic!("{}: {e}", cfg.name));
            // The tile cache's entry is in the module naga validated.
            let module = naga::front::wgsl::parse_str(&source).unwrap();
            let entries: Vec<&str> = module.entry_points.iter().map(|e| e.name.as_str()).collect();
            assert!(
                entries.contains(&"matrix") && entries.contains(&"matrix_cache"),
                "{entries:?}"
            );
            assert!(has_matrix_ops(&spirv), "{}: no cooperative matrix instructions", cfg.name);
            // The emulated kernel (for tests on devices without matrix units) uses no
            // cooperative matrix and no subgroup operation.
            let without = naga::valid::Capabilities::all()
                - naga::valid::Capabilities::COOPERATIVE_MATRIX
                - naga::valid::Capabilities::SUBGROUP;
            for (paired, storage) in [(false, false), (true, false), (false, true), (true, true)] {
                let variant = format!("{}, paired {paired}, storage {storage}", cfg.name);
                let sized =
                    Shape::sized((&m, n), 32, Asked { paired, storage, ..Asked::DEFAULT }, 49152);
                let real = sized.unwrap_or_else(|e| panic!("{variant}: {e}"));
                let emulated = Shape { emulated: true, ..real.clone() };
                let source = emulated.source_part(Part::Whole, &features);
                compile_with(&source, without)
                    .unwrap_or_else(|e| panic!("{variant}, emulated: {e}"));
                // The products' round trip with both parts at once (NMAT_WGPU_MATRIX_SUMS) and
                // the weights read from storage (NMAT_WGPU_MATRIX_WEIGHTS): the weights are
                // declared in the group the pipeline layout gives them, or in workgroup memory.
                let source = real.source_part(Part::Whole, &features);
                let spirv = compile(&source).unwrap_or_else(|e| panic!("{variant}: {e}"));
                assert!(has_matrix_ops(&spirv), "{variant}");
                assert_eq!(source.contains(WEIGHTS_BINDING), storage, "{variant}");
                assert_eq!(source.contains("var<workgroup> weights16"), !storage, "{variant}");
                assert_eq!(real.weights_in_storage(), storage);
            }
            // The pipelines that time a part alone compile too.
            for part in [Part::Features, Part::Layers] {
                let source = shape.source_part(part, &features);
                compile(&source).unwrap_or_else(|e| panic!("{} {part:?}: {e}", cfg.name));
            }
        }
        assert_eq!(refused, 1);
    }
}

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
}

/// The invocations of an emulated subgroup.
const EMULATED_SUBGROUP: u32 = 32;

impl Shape {
    /// The shape of `m`'s network on `device`, or why the matrix kernel cannot decode it there.
    /// `emulated`: with the matrix operations in scalar code and the products' round trip
    /// `paired` or not, for testing ([`crate::Context::emulate_matrix_for_testing`]; needs
    /// `SHADER_F16` only).
    pub fn new(
        m: (&Material<'_>, &Neural<'_>),
        device: &wgpu::Device,
        emulated: Option<bool>,
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
        let layout = overridden("NMAT_WGPU_MATRIX", |[w, b, n]| {
            [w, b, n].iter().all(|x| (1..=64).contains(x))
        })
        .unwrap_or(LAYOUT);
        let pads = overridden("NMAT_WGPU_MATRIX_PAD", |[a, w, s]| {
            a.is_multiple_of(8)
                && w.is_multiple_of(8)
                && s.is_multiple_of(4)
                && a.max(w).max(s) <= 64
        })
        .unwrap_or(PADS);
        let paired = emulated.unwrap_or_else(|| match std::env::var("NMAT_WGPU_MATRIX_SUMS") {
            Ok(v) if v == "paired" => true,
            Ok(v) if v == "split" => false,
            _ => PAIRED,
        });
        let limits = device.limits();
        let bytes = limits.max_compute_workgroup_storage_size;
        let shape = Shape::sized(m, subgroup, (layout, pads, paired), bytes)?;
        Ok(Shape { emulated: emulated.is_some(), ..shape })
    }

    /// The shape of `m`'s network for `layout`, `pads` and round trip (`paired`) with subgroups
    /// of `subgroup` invocations and `limit` bytes of workgroup memory (fewer subgroups where
    /// the memory is short).
    fn sized(
        (m, n): (&Material<'_>, &Neural<'_>),
        subgroup: u32,
        ((warps, blocks, batches), pads, paired): ((u32, u32, u32), (u32, u32, u32), bool),
        limit: u32,
    ) -> Result<Shape, &'static str> {
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
        // Workgroup memory: staged weights, the activations' high and low bytes (f16), a row
        // block of products (or two, paired) per subgroup and texel block (f32) and the codes.
        let parts = if paired { 2 } else { 1 };
        let bytes = |w: u32| {
            let p = 16 * blocks * w;
            let sums = 64 * (16 + pads.2) * blocks * w * parts;
            2 * total + 4 * wmax * (p + pads.0) + sums + 4 * channels * p
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
        })
    }

    /// Texels per batch.
    fn batch(&self) -> u32 {
        16 * self.blocks * self.warps
    }

    /// Texels per workgroup.
    pub fn texels(&self) -> u32 {
        self.batch() * self.batches
    }

    /// Whether the source's `matrix_cache` entry can decode the tile cache's tiles: a batch
    /// divides a tile's 256 texels.
    pub fn decodes_tiles(&self) -> bool {
        256 % self.batch() == 0
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
            let _ = writeln!(stage, "    stage(lid, {l}u, {kpad}u, {opad}u, {woff}u, {ws}u);");
            if part != Part::Features {
                layers += &self.layer(l, kpad, opad, woff);
            }
        }
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
             const PART: u32 = {}u;\n{}\
             fn stage_weights(lid: u32) {{\n{stage}    workgroupBarrier();\n}}\n\
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
                let _ =
                    writeln!(s, "    var h{tb}: EmuAccumulators;\n    var l{tb}: EmuAccumulators;");
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

#[cfg(test)]
mod tests {
    use super::*;
    use nmat_core::Container;
    use nmat_tests::generate::{FixtureConfig, generate, golden_configs};

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
        let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
        let flags = naga::valid::ValidationFlags::all();
        let info = naga::valid::Validator::new(flags, capabilities)
            .validate(&module)
            .map_err(|e| e.emit_to_string(source))?;
        let options = naga::back::spv::Options { lang_version: (1, 6), ..Default::default() };
        naga::back::spv::write_vec(&module, &info, &options, None).map_err(|e| e.to_string())
    }

    /// lavapipe runs no cooperative matrices, so CI cannot run this kernel: its WGSL for every
    /// golden fixture's network (1 to 16 channels, 2 to 4 layers up to 64 wide) is valid for
    /// naga and becomes SPIR-V with the cooperative matrix instructions; the widest network the
    /// format allows (four layers of 128) is refused in 48 KiB of workgroup memory, not
    /// miscompiled.
    #[test]
    fn the_matrix_kernel_validates_for_every_fixture_shape() {
        let mut configs = golden_configs();
        configs.push(FixtureConfig {
            hidden: vec![128, 128, 128],
            ..FixtureConfig::ntc("widest", 9, 32, 32, 16)
        });
        let mut refused = 0;
        for cfg in configs {
            let bytes = generate(&cfg).to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            let n = m.neural().expect("a neural fixture");
            let shape = match Shape::sized((&m, n), 32, (LAYOUT, PADS, PAIRED), 49152) {
                Ok(shape) => shape,
                Err(reason) => {
                    assert_eq!(cfg.name, "widest", "{reason}");
                    // 4 layers of 128 × 128 f16 weights are 128 KiB.
                    assert!(
                        Shape::sized((&m, n), 32, (LAYOUT, PADS, PAIRED), 1 << 18).is_ok(),
                        "{}",
                        cfg.name
                    );
                    refused += 1;
                    continue;
                }
            };
            assert_eq!(shape.texels() % 16, 0);
            if cfg.hidden.iter().all(|&h| h <= 64) {
                // Networks up to 64 wide keep the 4 subgroups in 48 KiB.
                assert_eq!(shape.warps, LAYOUT.0, "{}", cfg.name);
            }
            let features = crate::features::Features::new(n).wgsl(false);
            let source = shape.source_part(Part::Whole, &features);
            let spirv = compile(&source).unwrap_or_else(|e| panic!("{}: {e}", cfg.name));
            // The tile cache's entry is in the module naga validated.
            assert!(shape.decodes_tiles(), "{}", cfg.name);
            let module = naga::front::wgsl::parse_str(&source).unwrap();
            let entries: Vec<&str> = module.entry_points.iter().map(|e| e.name.as_str()).collect();
            assert!(
                entries.contains(&"matrix") && entries.contains(&"matrix_cache"),
                "{entries:?}"
            );
            // OpCooperativeMatrixMulAddKHR (4459) and OpCooperativeMatrixLoadKHR (4457).
            let has = |op: u32| spirv.iter().any(|&w| w & 0xFFFF == op && w >> 16 >= 4);
            assert!(has(4459) && has(4457), "{}: no cooperative matrix instructions", cfg.name);
            // The emulated kernel (for tests on devices without matrix units) uses no
            // cooperative matrix and no subgroup operation.
            let without = naga::valid::Capabilities::all()
                - naga::valid::Capabilities::COOPERATIVE_MATRIX
                - naga::valid::Capabilities::SUBGROUP;
            for paired in [false, true] {
                let emulated = Shape { emulated: true, paired, ..shape.clone() };
                let source = emulated.source_part(Part::Whole, &features);
                compile_with(&source, without)
                    .unwrap_or_else(|e| panic!("{} emulated, paired {paired}: {e}", cfg.name));
                // The products' round trip with both parts at once (NMAT_WGPU_MATRIX_SUMS).
                let real = Shape { paired, ..shape.clone() };
                compile(&real.source_part(Part::Whole, &features))
                    .unwrap_or_else(|e| panic!("{} paired {paired}: {e}", cfg.name));
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

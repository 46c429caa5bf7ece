//! Inference on sample (`SampleBindings::module`, and `module_for` a material's layout):
//! `nmat_texel` in a compute shader gives the CPU's codes byte for byte through either, and the
//! example's fragment shader (`examples/sample_quad.rs`, run here as a module) draws every
//! filter, lod and channel group of the golden fixtures and a trained material like
//! `Material::sample` on the CPU, to f32 rounding. The coordinates cross the material's edges
//! (wrap and clamp addressing) and the lods go past the chain.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{ChannelMask, Container, Filter, Precision, SampleRequest};
use nmat_tests::generate::{generate, golden_configs};
use nmat_wgpu::{Context, GpuMaterial, Kernel, SampleBindings};

mod common;
use common::{buffer, cpu_codes, device, random_requests, submit_and_read, trained_material};

#[allow(dead_code)] // the example's `main` and whatever the tests do not call
#[path = "../examples/sample_quad.rs"]
mod example;
use example::{Quad, TOLERANCE, View, cpu_pixels, max_difference};

/// Every golden fixture and the trained material, by name.
fn materials() -> Vec<(String, Vec<u8>)> {
    let mut all: Vec<(String, Vec<u8>)> = golden_configs()
        .into_iter()
        .map(|cfg| (cfg.name.to_string(), generate(&cfg).to_bytes().unwrap()))
        .collect();
    all.push(("trained bricks".into(), trained_material()));
    all
}

#[test]
fn fragment_shader_samples_like_the_cpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let quad = Quad::new(&device);
    let filters = [Filter::Nearest, Filter::Bilinear, Filter::Trilinear, Filter::Stochastic];
    for (name, bytes) in materials() {
        let m = Container::parse(&bytes).unwrap();
        let gpu = ctx.upload(&device, &queue, &m).unwrap();
        for first_channel in (0..m.channel_count() as u32).step_by(4) {
            for lod in [0.0, 0.5, 2.25, 40.0] {
                for filter in filters {
                    // 20 × 12 pixels over uv [−3/8, 7/8) × [−1/4, 1/2): across the left and
                    // top edges, a few pixels per texel of mip 0.
                    let view = View {
                        size: (20, 12),
                        origin: [-0.375, -0.25],
                        scale: 1.0 / 16.0,
                        lod,
                        filter,
                        first_channel,
                    };
                    let got = quad.render(&device, &queue, &gpu, &view);
                    let want = cpu_pixels(&m, &view).unwrap();
                    let worst = max_difference(&m, &view, &got, &want);
                    assert!(worst <= TOLERANCE, "{name} {view:?}: off by {worst:e} of the range");
                }
            }
        }
    }
}

/// A compute shader writing `nmat_texel`'s 16 codes per request (channels in `mask`), the
/// sampling module being `module`.
fn texel_shader(module: &str, mask: u16) -> String {
    format!(
        "{module}\n\
         @group(0) @binding(2) var<storage, read> reqs: array<i32>;\n\
         @group(0) @binding(3) var<storage, read_write> out: array<u32>;\n\
         @compute @workgroup_size(64)\n\
         fn main(@builtin(global_invocation_id) id: vec3<u32>) {{\n\
             let i = id.x;\n\
             if (i >= arrayLength(&reqs) / 3u) {{ return; }}\n\
             let xy = vec2<i32>(reqs[3u * i], reqs[3u * i + 1u]);\n\
             let codes = nmat_texel(xy, bitcast<u32>(reqs[3u * i + 2u]), {mask}u);\n\
             for (var c = 0u; c < 16u; c++) {{ out[16u * i + c] = codes[c]; }}\n\
         }}\n"
    )
}

#[test]
fn texel_codes_match_the_cpu_byte_for_byte() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let harness = Harness::new(&device, &queue);
    let bindings = harness.bindings;
    let pipeline = |module: &str, mask| harness.pipeline(&texel_shader(module, mask));
    // A module specialised to another material's layout (a 16-channel one with 8-bit codes):
    // bound to any other material, it computes the generic features.
    let config = golden_configs().into_iter().find(|c| c.name == "ntc_16ch_8bit_32").unwrap();
    let other = generate(&config).to_bytes().unwrap();
    let other = ctx.upload(&device, &queue, &Container::parse(&other).unwrap()).unwrap();
    for mask in [0xFFFF, 0b1010_0101_0110] {
        let any_material = pipeline(&bindings.module(), mask);
        let other_material = pipeline(&bindings.module_for(&other).unwrap(), mask);
        for (name, bytes) in materials() {
            let m = Container::parse(&bytes).unwrap();
            let gpu = ctx.upload(&device, &queue, &m).unwrap();
            // Uploaded with the reference kernel (no tables: a module_for's unrolled network
            // must not run).
            let no_tables = ctx.upload_with(&device, &queue, &m, Some(Kernel::Reference)).unwrap();
            // The module for any material, the one specialised to another material, and (with
            // the second mask for three materials only: each is a compile on lavapipe) the one
            // specialised to this material (its features and, on its kernel's tables, its
            // network unrolled).
            let mut modules = vec![
                ("module", &any_material, &gpu),
                ("module_for another material", &other_material, &gpu),
            ];
            let few = ["ntc_pbr10_96x80_clamp", "nbc_8421_64", "trained bricks"];
            let this_material = (mask == 0xFFFF || few.contains(&name.as_str())).then(|| {
                let source = bindings.module_for(&gpu).unwrap();
                if gpu.kernel() != Kernel::Reference {
                    assert!(source.contains("fn nmat_u_network("), "{name}: no unrolled network");
                }
                pipeline(&source, mask)
            });
            // And, for those three (each a compile), with the tiled i32 kernel (tables without
            // 128 · Σ w in the bias).
            let i32_tables = (mask == 0xFFFF && few.contains(&name.as_str()))
                .then(|| ctx.upload_with(&device, &queue, &m, Some(Kernel::Int32)).unwrap());
            let i32_module =
                i32_tables.as_ref().map(|t| pipeline(&bindings.module_for(t).unwrap(), mask));
            if let Some(this_material) = &this_material {
                modules.push(("module_for", this_material, &gpu));
                modules.push((
                    "module_for, the material without tables",
                    this_material,
                    &no_tables,
                ));
                if let (Some(tables), Some(module)) = (&i32_tables, &i32_module) {
                    modules.push(("module_for, tiled i32 kernel's tables", module, tables));
                    modules.push(("module_for, other tables", this_material, tables));
                }
            }
            for (module, pipeline, gpu) in modules {
                let reqs = random_requests(7, 300, 200, m.mip_count() + 2);
                let words: Vec<u8> = reqs
                    .iter()
                    .flat_map(|r| [r.x, r.y, r.mip as i32])
                    .flat_map(i32::to_le_bytes)
                    .collect();
                let got: Vec<u32> = harness
                    .run(pipeline, gpu, &words, reqs.len(), 64)
                    .chunks(4)
                    .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
                    .collect();
                // The CPU's codes, put back at their channel's index (0 for the others; all 0 where
                // the material has none of the channels).
                let kept = mask & (((1u32 << m.channel_count()) - 1) as u16);
                let channels: Vec<usize> = (0..16).filter(|c| kept & (1 << c) != 0).collect();
                let packed =
                    if kept == 0 { Vec::new() } else { cpu_codes(&m, &reqs, ChannelMask(kept)) };
                let mut want = vec![0u32; 16 * reqs.len()];
                for (i, codes) in packed.chunks(channels.len().max(1)).enumerate() {
                    for (&c, &code) in channels.iter().zip(codes) {
                        want[16 * i + c] = u32::from(code);
                    }
                }
                assert!(
                    got == want,
                    "{name}, mask {mask:#x}: nmat_texel of {module} differs from the CPU"
                );
            }
        }
    }
}

/// A test's compute shader next to a material: the material's two bindings at 0 and 1 (group
/// 0), the requests (read) at 2 and the results (written) at 3; one invocation a request, 64 a
/// workgroup.
struct Harness<'d> {
    device: &'d wgpu::Device,
    queue: &'d wgpu::Queue,
    bindings: SampleBindings,
    layout: wgpu::BindGroupLayout,
    pipeline_layout: wgpu::PipelineLayout,
}

impl<'d> Harness<'d> {
    fn new(device: &'d wgpu::Device, queue: &'d wgpu::Queue) -> Harness<'d> {
        let bindings = SampleBindings { group: 0, first_binding: 0 };
        let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let [desc, latents] = bindings.layout_entries(wgpu::ShaderStages::COMPUTE);
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: None,
            entries: &[desc, latents, storage(2, true), storage(3, false)],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: None,
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        Harness { device, queue, bindings, layout, pipeline_layout }
    }

    fn pipeline(&self, source: &str) -> wgpu::ComputePipeline {
        common::compute_pipeline(self.device, source, Some(&self.pipeline_layout))
    }

    /// The bytes `pipeline` writes for `count` requests read from `input`, `result_bytes` each,
    /// with `gpu` bound.
    fn run(
        &self,
        pipeline: &wgpu::ComputePipeline,
        gpu: &GpuMaterial,
        input: &[u8],
        count: usize,
        result_bytes: u64,
    ) -> Vec<u8> {
        let (device, queue) = (self.device, self.queue);
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let reqs = buffer(device, input.len() as u64, usage, None);
        queue.write_buffer(&reqs, 0, input);
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        let out = buffer(device, result_bytes * count as u64, usage, None);
        let [desc, latents] = gpu.sample_entries(self.bindings).unwrap();
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.layout,
            entries: &[
                desc,
                latents,
                wgpu::BindGroupEntry { binding: 2, resource: reqs.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: out.as_entire_binding() },
            ],
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups((count as u32).div_ceil(64), 1, 1);
        }
        submit_and_read(device, queue, encoder, &out)
    }
}

/// A compute shader writing `nmat_sample`'s 16 values per request (u, v, lod, three random
/// numbers) with stochastic filtering, the sampling module being `module`.
fn stochastic_shader(module: &str) -> String {
    format!(
        "{module}\n\
         @group(0) @binding(2) var<storage, read> reqs: array<f32>;\n\
         @group(0) @binding(3) var<storage, read_write> out: array<f32>;\n\
         @compute @workgroup_size(64)\n\
         fn main(@builtin(global_invocation_id) id: vec3<u32>) {{\n\
             let i = id.x;\n\
             if (i >= arrayLength(&reqs) / 6u) {{ return; }}\n\
             let r = 6u * i;\n\
             let s = nmat_sample(vec2<f32>(reqs[r], reqs[r + 1u]), reqs[r + 2u],\n\
                 vec3<f32>(reqs[r + 3u], reqs[r + 4u], reqs[r + 5u]), NMAT_STOCHASTIC,\n\
                 NMAT_ALL_CHANNELS);\n\
             for (var c = 0u; c < 16u; c++) {{ out[16u * i + c] = s[c]; }}\n\
         }}\n"
    )
}

/// Stochastic filtering on the GPU picks the texel and mip the CPU picks where the random
/// numbers sit on the edges of FORMAT.md §6.9: equal to a texel's fraction (the next texel is
/// picked only for a number below it) or to the LOD's fraction; 0, 1 and a number below 0
/// (which counts as 0); at a texel's centre and an integer LOD, and across the material's left
/// edge. The random tests of `nmat_sample` draw numbers that almost never equal a fraction.
/// Coordinates are dyadic on power-of-two materials, so that f32 on the GPU and f64 on the CPU
/// see the same fractions.
#[test]
fn stochastic_sampling_picks_the_cpus_texel_at_every_edge() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let harness = Harness::new(&device, &queue);
    let pipeline = harness.pipeline(&stochastic_shader(&harness.bindings.module()));
    // Below 0 and from 1 up, numbers are clamped.
    let edges = [-0.5, 0.0, 0.2, 0.25, 0.375, 0.5, 0.7, 1.0f32];
    let power_of_two = ["ntc_rgb_64", "nbc_8421_64", "ntc_16ch_8bit_32", "trained bricks"];
    for (name, bytes) in materials().into_iter().filter(|(n, _)| power_of_two.contains(&&**n)) {
        let m = Container::parse(&bytes).unwrap();
        let gpu = ctx.upload(&device, &queue, &m).unwrap();
        // (x, y) in texel space on `mip` (u · width − ½), and the LOD: fractions ¼ and ½ and
        // LOD fraction ½; a texel's centre at an integer LOD; fractions ¼ on mip 0 (⅜ and ⅞ on
        // mip 1) left of the material, LOD fraction ¼.
        let points = [(10.25, 7.5, 1, 1.5f32), (5.0, 6.0, 2, 2.0), (-0.75, 8.25, 0, 0.25)];
        for (px, py, mip, lod) in points {
            let (w, h) = m.mip_size(mip);
            let (u, v) = ((px + 0.5) / w as f32, (py + 0.5) / h as f32);
            let k = edges.len();
            let requests: Vec<[f32; 6]> = (0..k.pow(3))
                .map(|i| [u, v, lod, edges[i / (k * k)], edges[i / k % k], edges[i % k]])
                .collect();
            let input: Vec<u8> = requests.iter().flatten().flat_map(|f| f.to_le_bytes()).collect();
            let got: Vec<f32> = harness
                .run(&pipeline, &gpu, &input, requests.len(), 64)
                .chunks(4)
                .map(|w| f32::from_le_bytes([w[0], w[1], w[2], w[3]]))
                .collect();
            let channels = m.channel_count();
            let mut picks = Vec::new();
            for (req, got) in requests.iter().zip(got.chunks(16)) {
                let mut want = [0f32; 16];
                let request = SampleRequest {
                    u,
                    v,
                    lod,
                    filter: Filter::Stochastic,
                    precision: Precision::Integer,
                    random: [req[3], req[4], req[5]],
                    channels: ChannelMask::ALL,
                };
                assert_eq!(m.sample(&request, &mut want).unwrap(), channels);
                for (c, (a, b)) in got.iter().zip(want).take(channels).enumerate() {
                    let range = &m.channels()[c];
                    let width = (range.range_max - range.range_min).abs();
                    assert!(
                        (a - b).abs() <= TOLERANCE * if width > 0.0 { width } else { 1.0 },
                        "{name}: ({px}, {py}) on mip {mip}, LOD {lod}, r = {:?}: channel {c} is \
                         {a} on the GPU, {b} on the CPU",
                        &req[3..]
                    );
                }
                if !picks.contains(&want) {
                    picks.push(want);
                }
            }
            // The test could fail: the texels the edges choose between differ (two per axis,
            // two mips where the LOD has a fraction; one texel at a centre and integer LOD).
            let expected = if lod.fract() == 0.0 { 1 } else { 8 };
            assert_eq!(picks.len(), expected, "{name}: ({px}, {py}) on mip {mip}: distinct picks");
        }
    }
}

/// The names of an engine's own shader (and of nmat's compute kernels) next to the module.
#[test]
fn module_compiles_next_to_the_engines_own_names() {
    let (device, _queue) = device();
    let engine = "
        struct Params { x: u32 }
        var<private> codes: array<u32, 16>;
        var<private> act_a: array<i32, 4>;
        const LEVEL_WORDS: u32 = 1u;
        fn desc() -> u32 { return 0u; }
        fn decode(x: i32) -> i32 { return x; }
        fn bilinear(a: f32) -> f32 { return a; }
        fn features() {}
        fn requantize() {}
        fn sample() {}
        @compute @workgroup_size(1)
        fn main() {
            let s = nmat_sample(vec2<f32>(0.5), 0.0, vec3<f32>(0.0), NMAT_BILINEAR, 1u);
            codes[0] = u32(s[0]) + desc() + LEVEL_WORDS + u32(decode(act_a[0]));
        }";
    for bindings in [
        SampleBindings { group: 0, first_binding: 0 },
        SampleBindings { group: 3, first_binding: 7 },
    ] {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let _module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: None,
            source: wgpu::ShaderSource::Wgsl(format!("{engine}\n{}", bindings.module()).into()),
        });
        let error = pollster::block_on(scope.pop());
        assert!(error.is_none(), "{bindings:?}: {error:?}");
    }
}

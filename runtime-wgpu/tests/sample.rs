//! Inference on sample (`SampleBindings::module`, and `module_for` a material's layout):
//! `nmat_texel` in a compute shader gives the CPU's codes byte for byte through either, and the
//! example's fragment shader (`examples/sample_quad.rs`, run here as a module) draws every
//! filter, lod and channel group of the golden fixtures and a trained material like
//! `Material::sample` on the CPU, to f32 rounding. The coordinates cross the material's edges
//! (wrap and clamp addressing) and the lods go past the chain.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{ChannelMask, Container, Filter};
use nmat_tests::generate::{generate, golden_configs};
use nmat_wgpu::{Context, Kernel, SampleBindings};

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
    let pipeline = |module: &str, mask| {
        common::compute_pipeline(&device, &texel_shader(module, mask), Some(&pipeline_layout))
    };
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
                let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
                let input = buffer(&device, words.len() as u64, usage, None);
                queue.write_buffer(&input, 0, &words);
                let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
                let out = buffer(&device, 64 * reqs.len() as u64, usage, None);
                let [desc, latents] = gpu.sample_entries(bindings).unwrap();
                let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: None,
                    layout: &layout,
                    entries: &[
                        desc,
                        latents,
                        wgpu::BindGroupEntry { binding: 2, resource: input.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 3, resource: out.as_entire_binding() },
                    ],
                });
                let mut encoder = device.create_command_encoder(&Default::default());
                {
                    let mut pass = encoder.begin_compute_pass(&Default::default());
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, &group, &[]);
                    pass.dispatch_workgroups((reqs.len() as u32).div_ceil(64), 1, 1);
                }
                let got: Vec<u32> = submit_and_read(&device, &queue, encoder, &out)
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

//! `nmat walk --gpu`: the same walk through nmat-wgpu's tile cache (`GpuTileCache`): per frame
//! the G-buffer of lookups is uploaded (untimed: a renderer writes it on the GPU), then one
//! submission records begin → mark → decode missing → resolve → end, timed between GPU
//! timestamps where the adapter has them, a timestamp after marking and after decoding too (so
//! the frame's three stages are timed apart, as the CPU walk's are); else submit to completion.
//! Every Nth frame also resolves every lookup with `nmat_sample` (decoding its texels, no cache;
//! neural materials only) and checks the two images are bit-identical.

use super::Walk;
use super::device;
use crate::common::Result;
use crate::corridor::{Lookup, Options, Row, gbuffer, request};
use nmat_core::{ChannelMask, Material};
use nmat_wgpu::measure::{self, Clock};
use nmat_wgpu::wgpu;
use nmat_wgpu::{CacheLookup, Context, SampleBindings, read_buffer};

/// A compute shader writing channels 0–2 of `nmat_sample` for the lookups of one material, the
/// sampling module being `module` (its own: `SampleBindings::module_for`).
fn direct_source(material: usize, module: &str) -> String {
    format!(
        "{module}\n\
         @group(0) @binding(2) var<storage, read> lookups: array<u32>;\n\
         @group(0) @binding(3) var<storage, read_write> out: array<f32>;\n\
         @compute @workgroup_size(64)\n\
         fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) n: vec3<u32>) {{\n\
             let i = id.x + id.y * n.x * 64u;\n\
             if (i >= arrayLength(&lookups) / 8u || lookups[8u * i + 3u] != {material}u) {{ return; }}\n\
             let uv = vec2<f32>(bitcast<f32>(lookups[8u * i]), bitcast<f32>(lookups[8u * i + 1u]));\n\
             let v = nmat_sample(uv, bitcast<f32>(lookups[8u * i + 2u]), vec3<f32>(0.0), lookups[8u * i + 4u], 7u);\n\
             out[3u * i] = v[0];\n\
             out[3u * i + 1u] = v[1];\n\
             out[3u * i + 2u] = v[2];\n\
         }}\n"
    )
}

pub fn walk(opts: &Options, materials: &[Material<'_>], mips: bool) -> Result<Walk> {
    let (device, queue, info) = device::open()?;
    let ctx = Context::new(&device);
    let gpus: Vec<_> = materials
        .iter()
        .map(|m| ctx.upload(&device, &queue, m))
        .collect::<std::result::Result<_, _>>()?;
    let refs: Vec<_> = gpus.iter().collect();
    let tiles = u32::try_from(opts.tiles).map_err(|_| "--tiles: at most 2^32 − 1 on the GPU")?;
    let cache = ctx.create_tile_cache(&device, &refs, tiles)?;
    let pixels = u64::from(opts.width) * u64::from(opts.height);
    let count = u32::try_from(pixels).map_err(|_| "--size: too many pixels")?;
    use wgpu::BufferUsages as U;
    let buffer = |label, size, usage| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        })
    };
    let lookups = buffer("walk lookups", CacheLookup::BYTES * pixels, U::STORAGE | U::COPY_DST);
    let cached_out = buffer("walk cached", 12 * pixels, U::STORAGE | U::COPY_SRC);
    let direct_out = buffer("walk direct", 12 * pixels, U::STORAGE | U::COPY_SRC);
    // Direct sampling: one pass per material (the sampling module binds one material), each
    // through the module specialised to its layout, as an engine would compile them.
    let neural = gpus.iter().all(|g| g.codec() == nmat_core::Codec::Neural);
    let mut direct = Vec::new();
    if neural {
        let bindings = SampleBindings { group: 0, first_binding: 0 };
        for (k, g) in gpus.iter().enumerate() {
            let source = direct_source(k, &bindings.module_for(g)?);
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("walk direct"),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("walk direct"),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            });
            let [a, b] = g.sample_entries(bindings)?;
            let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("walk direct"),
                layout: &pipeline.get_bind_group_layout(0),
                entries: &[
                    a,
                    b,
                    wgpu::BindGroupEntry { binding: 2, resource: lookups.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: direct_out.as_entire_binding() },
                ],
            });
            direct.push((pipeline, group));
        }
    }
    let wait = || device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| e.to_string());
    let mut rows = Vec::new();
    let mut clock = Clock::WallClock;
    for f in 0..opts.frames {
        let items: Vec<CacheLookup> = gbuffer(opts, materials, f, mips)
            .iter()
            .map(|l: &Lookup| CacheLookup::new(u32::from(l.material), &request(l, mips)))
            .collect();
        queue.write_buffer(&lookups, 0, &CacheLookup::bytes(&items));
        queue.submit([]);
        wait()?;
        let channels = ChannelMask(0b111);
        let timed = measure::time_stages(
            &device,
            &queue,
            &mut [
                &mut |encoder| {
                    cache.record_begin_frame(encoder);
                    cache.record_mark(&device, encoder, (&lookups, 0, count))
                },
                &mut |encoder| {
                    cache.record_decode_missing(encoder);
                    Ok(())
                },
                &mut |encoder| {
                    let out = (&cached_out, 0);
                    cache.record_resolve(&device, encoder, (&lookups, 0, count), channels, out)?;
                    cache.record_end_frame(encoder);
                    Ok(())
                },
            ],
        )?;
        let (seconds, c) = (timed.seconds, timed.clock);
        let stages = timed.stages.map(|st| [st[0] * 1e3, st[1] * 1e3, st[2] * 1e3]);
        clock = c;
        let stats = cache.read_stats(&device)?;
        let (mut direct_ms, mut identical) = (None, None);
        if !direct.is_empty() && opts.direct_every > 0 && f % opts.direct_every == 0 {
            let (seconds, _) = measure::time_once(&device, &queue, |encoder| {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                let groups = pixels.div_ceil(64);
                for (pipeline, group) in &direct {
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, group, &[]);
                    pass.dispatch_workgroups(
                        groups.min(65535) as u32,
                        groups.div_ceil(65535) as u32,
                        1,
                    );
                }
                Ok(())
            })?;
            direct_ms = Some(seconds * 1e3);
            identical = Some(
                read_buffer(&device, &queue, &cached_out)?
                    == read_buffer(&device, &queue, &direct_out)?,
            );
        }
        rows.push(Row { stats, stages, cached_ms: seconds * 1e3, direct_ms, identical });
    }
    Ok(Walk {
        adapter: format!("{} ({:?})", info.name, info.backend),
        software: info.device_type == nmat_wgpu::DeviceType::Cpu,
        clock: clock.name(),
        tile_kernels: gpus
            .iter()
            .map(|g| match g.codec() {
                nmat_core::Codec::Jpeg => "JPEG",
                nmat_core::Codec::Neural => g.tile_kernel().name(),
            })
            .collect(),
        rows,
    })
}

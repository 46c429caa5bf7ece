//! `nmat bench --gpu`: the GPU decoder measured like a GPU (docs/GPU.md, "Measured"): kernels
//! timed with GPU timestamps where the adapter has them, against the adapter's own integer peak
//! (`nmat_wgpu::measure`), for a region, the whole chain, random requests, channel subsets and
//! `nmat_sample` (the shader module) with stochastic and trilinear filtering, BC transcoding of
//! the region (the default layout, and every map in BC7; against the CPU on all its threads); upload and a region's round trip (submit,
//! decode, read back) on their own rows.

use super::device;
use crate::common::{Result, macs};
use nmat_cli::stats::median;
use nmat_cli::transcode;
use nmat_core::bc::{BcFormat, BcTexture};
use nmat_core::{BlockRegion, ChannelMask, Material};
use nmat_wgpu::measure::{self, Clock, Part};
use nmat_wgpu::wgpu;
use nmat_wgpu::{Context, GpuError, GpuMaterial, Kernel, TexelRequest};
use std::time::Instant;

/// Each timed submission runs at least this long (repeats of the work in one submission).
const MIN_SECONDS: f64 = 0.05;

/// The table for `m`: a `region`² region of mip 0 (at most the mip), `runs` timed runs a row;
/// every row through `only` where given (no row for the other kernels).
pub fn table(m: &Material<'_>, region: u32, runs: usize, only: Option<Kernel>) -> Result<()> {
    let (device, queue, info) = device::open()?;
    let software = info.device_type == nmat_wgpu::DeviceType::Cpu;
    println!(
        "  GPU {} ({:?}{})",
        info.name,
        info.backend,
        if software { ", a software rasterizer on the CPU: not a GPU's numbers" } else { "" }
    );
    let peak = measure::probe_peak(&device, &queue)?;
    println!(
        "  peak: {:.1} G i32 multiply-add/s, {} (register-only WGSL loops, {})",
        peak.i32_mad_per_s / 1e9,
        peak.dot4_mac_per_s.map_or("no dot4I8Packed".to_string(), |r| format!(
            "{:.1} G MAC/s through dot4I8Packed",
            r / 1e9
        )),
        peak.clock.name()
    );
    let ctx = Context::new(&device);
    let start = Instant::now();
    let gm = ctx.upload_with(&device, &queue, m, only)?;
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| e.to_string())?;
    let upload = start.elapsed().as_secs_f64();
    // The other kernels the device runs, for a region row each (same codes, other speed).
    let others: Vec<GpuMaterial> = Kernel::ALL
        .into_iter()
        .rev()
        .filter(|&k| k != gm.kernel() && only.is_none())
        .filter_map(|k| ctx.upload_with(&device, &queue, m, Some(k)).ok())
        .collect();
    // Where each tiled or matrix kernel's time goes: its input features alone and its layers
    // alone (pipelines made for timing only: their codes are not the material's).
    let mut parts = Vec::new();
    for kernel in std::iter::once(&gm).chain(&others).map(GpuMaterial::kernel) {
        for part in [Part::Features, Part::Layers] {
            if let Ok(timed) = ctx.upload_part_for_timing(&device, m, kernel, part) {
                parts.push((part, timed));
            }
        }
    }
    let c = m.channel_count();
    let (w, h) = m.mip_size(0);
    let side = (region.min(w).max(1), region.min(h).max(1));
    let chain: u64 = (0..m.mip_count()).map(|k| texels(m.mip_size(k))).sum();
    let requests = random_requests(m, texels(side));
    let request_bytes: Vec<u8> = requests
        .iter()
        .flat_map(|r| [r.x.to_le_bytes(), r.y.to_le_bytes(), r.mip.to_le_bytes()])
        .flatten()
        .collect();
    use wgpu::util::DeviceExt;
    let request_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("bench requests"),
        contents: &request_bytes,
        usage: wgpu::BufferUsages::STORAGE,
    });
    let out = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("bench codes"),
        size: (chain.max(texels(side)) * c as u64).next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    println!(
        "  kernel: {}{} ({}); tiles decoded by: {}",
        gm.kernel().name(),
        gm.workgroup_texels().map_or(String::new(), |p| format!(", {p} texels a workgroup")),
        match only {
            Some(_) => "asked for with --kernel; its codes equal the CPU's on upload's probe",
            None =>
                "of the kernels whose codes equal the CPU's on upload's probe, the fastest \
                     measured on this device; docs/GPU.md",
        },
        gm.tile_kernel().name()
    );
    for (kernel, reason) in gm.rejected() {
        println!("  not used: the {} kernel ({reason})", kernel.name());
    }
    println!(
        "  median of {} runs; Mtexel/s and % of the i32 roofline (MACs per texel × texels/s ÷ peak \
         multiply-adds/s) from the kernels' time alone ({})",
        runs,
        peak.clock.name()
    );
    println!("  | what | texels | MACs/texel | µs per call | Mtexel/s | % of i32 roofline |");
    println!("  |---|---:|---:|---:|---:|---:|");
    let all = ChannelMask::ALL;
    let region = Work::Region(side, all);
    let mut rows = vec![
        (
            format!("region {}×{} of mip 0, all {c} channels", side.0, side.1),
            texels(side),
            macs(m, c),
            region,
            &gm,
        ),
        (format!("whole chain, {} mips", m.mip_count()), chain, macs(m, c), Work::Chain, &gm),
        (
            format!("{} random requests over the chain", requests.len()),
            texels(side),
            macs(m, c),
            Work::Requests,
            &gm,
        ),
        (
            format!("region {}×{}, channel 0", side.0, side.1),
            texels(side),
            macs(m, 1),
            Work::Region(side, ChannelMask(1)),
            &gm,
        ),
    ];
    if c > 3 {
        let mask = ChannelMask(0b111);
        rows.push((
            format!("region {}×{}, channels 0-2", side.0, side.1),
            texels(side),
            macs(m, 3),
            Work::Region(side, mask),
            &gm,
        ));
    }
    // Inference on sample: nmat_sample (the module engines include: for any material, and
    // specialised to this one's layout) once per texel of the region, a quarter texel off centre
    // and halfway between mips 0 and 1 (so a trilinear sample decodes all 8 texels), in a compute
    // shader; its rate is of decoded texels.
    // (A JPEG material has no sample module: it decodes by regions and requests.)
    let sampler = Sampler::new(&device, side, &gm);
    let mut refused = Vec::new();
    let jpeg = gm.codec() == nmat_core::Codec::Jpeg;
    let modes = [("NMAT_STOCHASTIC", 1), ("NMAT_TRILINEAR", 8)];
    for (own, (mode, decodes)) in [false, true].into_iter().flat_map(|o| modes.map(|m| (o, m))) {
        if jpeg {
            break;
        }
        if !sampler.pipelines.iter().any(|p| (p.0, p.1) == (mode, own)) {
            refused.push(format!("{mode}{}", if own { " (module_for)" } else { "" }));
            continue;
        }
        let filter = mode.trim_start_matches("NMAT_").to_lowercase();
        let name = format!(
            "nmat_sample {filter}{}, {}×{} samples × {decodes} decode{}, all channels",
            if own { " (module_for the material)" } else { "" },
            side.0,
            side.1,
            if decodes == 1 { "" } else { "s" }
        );
        let work = Work::Sample(side, mode, own);
        rows.push((name, texels(side) * decodes, macs(m, c), work, &gm));
    }
    // BC transcoding of the region (decode once, then every texture's blocks encoded), as a
    // frame or a streaming system would ask for it: the default layout's textures, and every map
    // in BC7; the CPU's time on all its threads follows the table.
    let transcodes: Vec<Transcode> =
        [false, true].into_iter().filter_map(|bc7| Transcode::new(&device, m, side, bc7)).collect();
    for (k, t) in transcodes.iter().enumerate() {
        let name = format!(
            "BC transcode of the region {}×{}: {} texture{} ({}), decode and encode",
            side.0,
            side.1,
            t.textures.len(),
            if t.textures.len() == 1 { "" } else { "s" },
            t.formats()
        );
        rows.push((name, texels(side), macs(m, t.channels()), Work::Transcode(k), &gm));
    }
    for other in &others {
        let name =
            format!("region {}×{}, all channels, {} kernel", side.0, side.1, other.kernel().name());
        rows.push((name, texels(side), macs(m, c), Work::Region(side, all), other));
    }
    for (part, timed) in &parts {
        let name = format!(
            "region {}×{}, {} kernel: {} (for timing; codes not valid)",
            side.0,
            side.1,
            timed.kernel().name(),
            part.name()
        );
        // (The input features alone make no multiply-adds of the network.)
        let macs = if *part == Part::Features { 0 } else { macs(m, c) };
        rows.push((name, texels(side), macs, Work::Region(side, all), timed));
    }
    let mut gpu_transcode = vec![None; transcodes.len()];
    for (name, n, macs_per_texel, work, gm) in &rows {
        let gpu = Gpu {
            ctx: &ctx,
            device: &device,
            gm,
            m,
            out: &out,
            requests: (&request_buffer, requests.len() as u32),
            sampler: &sampler,
            transcodes: &transcodes,
        };
        let seconds = median_time(&device, &queue, runs, &|e| gpu.record(e, work))?;
        if let Work::Transcode(k) = work {
            gpu_transcode[*k] = Some(seconds);
        }
        let rate = *n as f64 / seconds;
        println!(
            "  | {name} | {n} | {macs_per_texel} | {:.1} | {:.3} | {:.2} |",
            seconds * 1e6,
            rate / 1e6,
            100.0 * rate * *macs_per_texel as f64 / peak.i32_mad_per_s
        );
    }
    if !refused.is_empty() {
        println!("  no nmat_sample row for {}: the device refused the shader", refused.join(", "));
    }
    if jpeg {
        println!(
            "  a JPEG material: one workgroup per MCU (requests: each MCU they read decoded once \
             per call); no nmat_sample rows (neural materials only)"
        );
    }
    for (t, gpu_seconds) in transcodes.iter().zip(gpu_transcode) {
        let Some(gpu_seconds) = gpu_seconds else { continue };
        let cpu = t.cpu_seconds(m, runs)?;
        println!(
            "  BC transcode of the same region and textures ({}) on the CPU (`nmat transcode`'s \
             path, {} threads, wall clock, median of {runs}): {:.1} µs; the GPU takes {:.3}× \
             the CPU's time",
            t.formats(),
            rayon::current_num_threads(),
            cpu * 1e6,
            gpu_seconds / cpu
        );
    }
    let round_trips: Vec<f64> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            ctx.submit_region(&device, &queue, &gm, 0, (0, 0, side.0, side.1), all)?
                .wait(&device)?;
            Ok(start.elapsed().as_secs_f64())
        })
        .collect::<Result<_>>()?;
    println!(
        "  upload {:.2} ms (once per material: it compiles, probes and, first per network \
         shape, times the kernels); region round trip (submit, decode, read back, wall clock) \
         {:.2} ms",
        upload * 1e3,
        median(round_trips) * 1e3
    );
    Ok(())
}

/// What a row decodes.
enum Work {
    /// The top-left (width, height) of mip 0, these channels.
    Region((u32, u32), ChannelMask),
    /// Every mip, every channel.
    Chain,
    /// The random requests, every channel.
    Requests,
    /// One `nmat_sample` with this mode per texel of the top-left (width, height) of mip 0,
    /// through the module for any material or (true) the one for the material's layout.
    Sample((u32, u32), &'static str, bool),
    /// The region's BC textures (the bench's [`Transcode`] `k`).
    Transcode(usize),
}

/// The BC textures of the material's default layout (BC1, BC4, BC5), or of every map in BC7 (RGBA
/// for a map of four channels), that the GPU encodes, the blocks of the bench's region, and a
/// buffer for all of their blocks.
struct Transcode {
    textures: Vec<BcTexture>,
    blocks: BlockRegion,
    /// Per texture: its offset and row pitch in `out`.
    spans: Vec<(u64, u64)>,
    out: wgpu::Buffer,
}

impl Transcode {
    /// `None` where the GPU encodes none of the textures.
    fn new(
        device: &wgpu::Device,
        m: &Material<'_>,
        (w, h): (u32, u32),
        bc7: bool,
    ) -> Option<Transcode> {
        let layout = if bc7 {
            nmat_core::bc::layout_with(m, |_| Some(BcFormat::Bc7Rgba))
        } else {
            nmat_core::bc::default_layout(m)
        };
        let textures: Vec<BcTexture> =
            layout.into_iter().filter(|t| nmat_wgpu::encodes(t.format)).collect();
        if textures.is_empty() {
            return None;
        }
        let blocks = BlockRegion { x: 0, y: 0, width: w.div_ceil(4), height: h.div_ceil(4) };
        let mut spans = Vec::new();
        let mut len = 0u64;
        for t in &textures {
            let pitch = nmat_wgpu::aligned_row_pitch(t.format, blocks.width);
            spans.push((len, pitch));
            len += pitch * u64::from(blocks.height);
        }
        let out = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bench BC blocks"),
            size: len.max(4),
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        Some(Transcode { textures, blocks, spans, out })
    }

    /// How many of the material's channels the textures take (those the decode computes).
    fn channels(&self) -> usize {
        let mask =
            self.textures.iter().flat_map(|t| t.channel_list()).fold(0u32, |m, &c| m | 1 << c);
        mask.count_ones() as usize
    }

    /// The formats, e.g. `BC1, BC4, BC5`, each once.
    fn formats(&self) -> String {
        let mut names: Vec<String> = Vec::new();
        for name in self.textures.iter().map(|t| t.format.name().to_uppercase()) {
            if !names.contains(&name) {
                names.push(name);
            }
        }
        names.join(", ")
    }

    fn record(
        &self,
        (ctx, device): (&Context, &wgpu::Device),
        e: &mut wgpu::CommandEncoder,
        gm: &GpuMaterial,
    ) -> std::result::Result<(), GpuError> {
        let targets: Vec<(&BcTexture, nmat_wgpu::BlockTarget<'_>)> = self
            .textures
            .iter()
            .zip(&self.spans)
            .map(|(t, &(offset, pitch))| (t, (&self.out, offset, pitch)))
            .collect();
        ctx.record_transcode_textures(device, e, gm, 0, self.blocks, &targets)
    }

    /// Median seconds of the same transcoding on the CPU, on rayon's threads.
    fn cpu_seconds(&self, m: &Material<'_>, runs: usize) -> Result<f64> {
        let decoder = nmat_core::Decoder::new(m);
        let mut times = Vec::with_capacity(runs);
        for _ in 0..runs {
            let start = Instant::now();
            let (textures, region) = (&self.textures, (0, self.blocks));
            transcode::transcode_region(m, &decoder, textures, region, &mut |_| {})?;
            times.push(start.elapsed().as_secs_f64());
        }
        Ok(median(times))
    }
}

/// Compute pipelines calling `nmat_sample` (per mode, through `SampleBindings::module` and
/// through `module_for` the material: true), the sink they write to.
struct Sampler {
    layout: wgpu::BindGroupLayout,
    pipelines: Vec<(&'static str, bool, wgpu::ComputePipeline)>,
    sink: wgpu::Buffer,
}

impl Sampler {
    const BINDINGS: nmat_wgpu::SampleBindings =
        nmat_wgpu::SampleBindings { group: 0, first_binding: 0 };

    fn new(device: &wgpu::Device, (w, h): (u32, u32), gm: &GpuMaterial) -> Sampler {
        let [desc, latents] = Self::BINDINGS.layout_entries(wgpu::ShaderStages::COMPUTE);
        let sink = wgpu::BindGroupLayoutEntry {
            binding: 2,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: false },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("bench sample"),
            entries: &[desc, latents, sink],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("bench sample"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipelines = [false, true]
            .into_iter()
            .flat_map(|own| ["NMAT_STOCHASTIC", "NMAT_TRILINEAR"].map(|mode| (own, mode)))
            .filter_map(|(own, mode)| {
                let module = match own {
                    true => Self::BINDINGS.module_for(gm).ok()?,
                    false => Self::BINDINGS.module(),
                };
                // u = (x + ¼) / width (every bilinear weight nonzero on mips 0 and 1), random
                // numbers on a 1/16 lattice;
                // the sum of the channels is written so that nothing is optimised away.
                let source = format!(
                    "{}\n@group(0) @binding(2) var<storage, read_write> sink: array<f32>;\n\
                     @compute @workgroup_size(64)\n\
                     fn bench_sample(@builtin(global_invocation_id) id: vec3<u32>,\n\
                                     @builtin(num_workgroups) groups: vec3<u32>) {{\n\
                         let i = id.x + id.y * groups.x * 64u;\n\
                         if (i >= {w}u * {h}u) {{ return; }}\n\
                         let p = vec2<u32>(i % {w}u, i / {w}u);\n\
                         let size = vec2<f32>(nmat_mip_size(0u));\n\
                         let k = vec3<u32>(p.x * 7u + p.y * 13u, p.x * 5u + p.y * 3u, p.x + p.y * 11u);\n\
                         let rnd = (vec3<f32>(k % vec3<u32>(16u)) + 0.5) * 0.0625;\n\
                         let s = nmat_sample((vec2<f32>(p) + 0.25) / size, 0.5, rnd, {mode}, NMAT_ALL_CHANNELS);\n\
                         var sum = 0.0;\n\
                         for (var c = 0u; c < 16u; c++) {{ sum += s[c]; }}\n\
                         sink[i] = sum;\n\
                     }}\n",
                    module
                );
                // A device that refuses the shader loses the row, not the table.
                let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
                let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("bench sample"),
                    source: wgpu::ShaderSource::Wgsl(source.into()),
                });
                let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some("bench sample"),
                    layout: Some(&pipeline_layout),
                    module: &module,
                    entry_point: Some("bench_sample"),
                    compilation_options: Default::default(),
                    cache: None,
                });
                let refused = pollster::block_on(scope.pop()).is_some();
                (!refused).then_some((mode, own, pipeline))
            })
            .collect();
        let sink = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bench sample sink"),
            size: 4 * texels((w, h)).max(1),
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        Sampler { layout, pipelines, sink }
    }

    fn record(
        &self,
        device: &wgpu::Device,
        e: &mut wgpu::CommandEncoder,
        gm: &GpuMaterial,
        (mode, own): (&str, bool),
        n: u64,
    ) -> std::result::Result<(), GpuError> {
        let Some((_, _, pipeline)) = self.pipelines.iter().find(|p| (p.0, p.1) == (mode, own))
        else {
            return Ok(());
        };
        let [desc, latents] = gm.sample_entries(Self::BINDINGS)?;
        let sink = wgpu::BindGroupEntry { binding: 2, resource: self.sink.as_entire_binding() };
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bench sample"),
            layout: &self.layout,
            entries: &[desc, latents, sink],
        });
        let groups = n.div_ceil(64) as u32;
        let mut pass = e.begin_compute_pass(&Default::default());
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(groups.min(65_535), groups.div_ceil(65_535), 1);
        Ok(())
    }
}

/// What recording needs.
struct Gpu<'a> {
    ctx: &'a Context,
    device: &'a wgpu::Device,
    gm: &'a GpuMaterial,
    m: &'a Material<'a>,
    out: &'a wgpu::Buffer,
    requests: (&'a wgpu::Buffer, u32),
    sampler: &'a Sampler,
    transcodes: &'a [Transcode],
}

impl Gpu<'_> {
    fn record(
        &self,
        e: &mut wgpu::CommandEncoder,
        work: &Work,
    ) -> std::result::Result<(), GpuError> {
        let Gpu { ctx, device, gm, out, .. } = *self;
        let all = ChannelMask::ALL;
        match *work {
            Work::Region((w, h), mask) => {
                ctx.record_region(device, e, gm, 0, (0, 0, w, h), mask, (out, 0))?;
            }
            Work::Chain => {
                let mut at = 0;
                for mip in 0..self.m.mip_count() {
                    let (w, h) = self.m.mip_size(mip);
                    let n = ctx.record_region(device, e, gm, mip, (0, 0, w, h), all, (out, at))?;
                    at += n.next_multiple_of(4);
                }
            }
            Work::Requests => {
                let (buffer, count) = self.requests;
                ctx.record_requests(device, e, gm, (buffer, 0, count), all, (out, 0))?;
            }
            Work::Sample(side, mode, own) => {
                self.sampler.record(device, e, gm, (mode, own), texels(side))?
            }
            Work::Transcode(k) => {
                if let Some(t) = self.transcodes.get(k) {
                    t.record((ctx, device), e, gm)?;
                }
            }
        }
        Ok(())
    }
}

/// Median seconds per call of `work`: each run repeats it in one submission until that takes
/// at least [`MIN_SECONDS`].
fn median_time(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    runs: usize,
    work: &dyn Fn(&mut wgpu::CommandEncoder) -> std::result::Result<(), GpuError>,
) -> Result<f64> {
    let (first, _): (f64, Clock) = measure::time_recorded(device, queue, 1, work)?;
    let repeats = (MIN_SECONDS / first.max(1e-9)).ceil().clamp(1.0, 1000.0) as u32;
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs {
        times.push(measure::time_recorded(device, queue, repeats, work)?.0);
    }
    Ok(median(times))
}

fn texels((w, h): (u32, u32)) -> u64 {
    u64::from(w) * u64::from(h)
}

/// `n` texels drawn uniformly over the whole chain (each mip in proportion to its area), by a
/// fixed LCG so runs compare.
fn random_requests(m: &Material<'_>, n: u64) -> Vec<TexelRequest> {
    let areas: Vec<u64> = (0..m.mip_count()).map(|k| texels(m.mip_size(k))).collect();
    let total: u64 = areas.iter().sum();
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        s >> 33
    };
    (0..n)
        .map(|_| {
            let mut t = next() % total.max(1);
            let mut mip = 0;
            while mip + 1 < areas.len() && t >= areas[mip] {
                t -= areas[mip];
                mip += 1;
            }
            let (w, _) = m.mip_size(mip as u32);
            TexelRequest {
                x: (t % u64::from(w)) as i32,
                y: (t / u64::from(w)) as i32,
                mip: mip as u32,
            }
        })
        .collect()
}

//! Inference on sample: a fragment shader that includes nmat's WGSL module
//! (`nmat_wgpu::SampleBindings::module`) decodes a material where it draws it. The example renders
//! a quad headlessly into an `Rgba32Uint` texture (the bits of the f32 values), once per filter,
//! reads the pixels back and compares every one with `Material::sample` on the CPU (integer
//! precision); it fails if any differs by more than f32 rounding.
//!
//! ```text
//! cargo run -p nmat-wgpu --example sample_quad [MATERIAL.nmat]
//! ```
//!
//! Without an argument it draws a small committed test material (random weights, 10 channels).
//! An engine would pass its interpolated texture coordinates and a lod from derivatives; here the
//! coordinates come from the pixel position on a power-of-two grid, so that u · width is exact in
//! f32 and the GPU and the CPU pick the same texels with the same weights.

use nmat_core::{ChannelMask, Container, Filter, Material, Precision, SampleRequest};
use nmat_wgpu::{Context, GpuMaterial, SampleBindings};

/// The material drawn without an argument: `tests/fixtures/ntc_pbr10_96x80_clamp.nmat`.
const FIXTURE: &[u8] = include_bytes!("../../tests/fixtures/ntc_pbr10_96x80_clamp.nmat");

/// The largest difference allowed between a GPU and a CPU pixel, as a fraction of the channel's
/// range: f32 rounding of the weighted sum is below 10⁻⁶; one wrong code of weight w moves the
/// value by w / 255, over 10⁻⁴ for the weights of these views.
pub const TOLERANCE: f32 = 1e-5;

/// What the quad shows: pixel (x, y) samples uv = origin + (x + ½, y + ½) · scale.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// Width and height of the render target in pixels.
    pub size: (u32, u32),
    pub origin: [f32; 2],
    /// A power of two keeps every coordinate exact.
    pub scale: f32,
    pub lod: f32,
    pub filter: Filter,
    /// Channels `first_channel..` (up to 4 the material has) go to red, green, blue, alpha.
    pub first_channel: u32,
}

impl View {
    /// How many channels the view shows of a material with `channels`.
    pub fn count(&self, channels: usize) -> u32 {
        (channels as u32).saturating_sub(self.first_channel).min(4)
    }
}

/// The engine's side: a vertex shader drawing the quad, a fragment shader calling `nmat_sample`.
const SHADER: &str = r#"
struct View {
    origin: vec2<f32>,
    scale: f32,
    lod: f32,
    mode: u32,
    first: u32,
    count: u32,
    pad: u32,
}
// A storage buffer rather than a uniform one: Mesa's lavapipe (the CPU driver of the tests)
// compiles a fragment shader again at every draw whose uniforms steer its branches and loops,
// and this one takes about a minute to compile there.
@group(0) @binding(0) var<storage, read> view: View;

// A triangle strip over the whole target.
@vertex
fn quad(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    return vec4<f32>(f32(i & 1u) * 2.0 - 1.0, f32(i >> 1u) * 2.0 - 1.0, 0.0, 1.0);
}

// Three random numbers per pixel on a 1/16 lattice (an engine would use blue noise or a hash
// varying over frames).
fn noise(p: vec2<u32>) -> vec3<f32> {
    let k = vec3<u32>(p.x * 7u + p.y * 13u, p.x * 5u + p.y * 3u + 7u, p.x + p.y * 11u + 3u);
    return (vec3<f32>(k % vec3<u32>(16u)) + 0.5) * 0.0625;
}

// The target holds the values' bits (see FORMAT).
@fragment
fn shade(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<u32> {
    let uv = view.origin + pos.xy * view.scale;
    let mask = ((1u << view.count) - 1u) << view.first;
    let s = nmat_sample(uv, view.lod, noise(vec2<u32>(pos.xy)), view.mode, mask);
    var out = vec4<f32>(0.0);
    for (var k = 0u; k < view.count; k++) {
        out[k] = s[view.first + k];
    }
    return bitcast<vec4<u32>>(out);
}
"#;

/// The same random numbers as the shader's `noise`.
pub fn noise(x: u32, y: u32) -> [f32; 3] {
    let k = [x * 7 + y * 13, x * 5 + y * 3 + 7, x + y * 11 + 3];
    k.map(|k| ((k % 16) as f32 + 0.5) * 0.0625)
}

/// The render pipeline, with the material's bindings next to the view's buffer in group 0.
pub struct Quad {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    bindings: SampleBindings,
}

/// The render target: the f32 values' bits as `u32`s, which every backend renders to and reads
/// back unchanged; OpenGL ES renders into `Rgba32Float` only with `EXT_color_buffer_float`
/// (wgpu's GL backend on Mesa's llvmpipe refuses it: "not renderable"). An engine renders into
/// whatever its frame uses.
const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;

impl Quad {
    pub fn new(device: &wgpu::Device) -> Quad {
        let bindings = SampleBindings { group: 0, first_binding: 1 };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("sample quad"),
            source: wgpu::ShaderSource::Wgsl(format!("{}\n{SHADER}", bindings.module()).into()),
        });
        let [desc, latents] = bindings.layout_entries(wgpu::ShaderStages::FRAGMENT);
        let view_entry = wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("sample quad"),
            entries: &[view_entry, desc, latents],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("sample quad"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("sample quad"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("quad"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleStrip,
                ..Default::default()
            },
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("shade"),
                compilation_options: Default::default(),
                targets: &[Some(FORMAT.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        Quad { pipeline, layout, bindings }
    }

    /// Draws `gpu` as `view` says and reads the pixels back, row by row (RGBA).
    pub fn render(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gpu: &GpuMaterial,
        view: &View,
    ) -> Vec<[f32; 4]> {
        let (w, h) = view.size;
        let mode = match view.filter {
            Filter::Nearest => 0u32,
            Filter::Bilinear => 1,
            Filter::Trilinear => 2,
            Filter::Stochastic => 3,
        };
        let words = [
            view.origin[0].to_bits(),
            view.origin[1].to_bits(),
            view.scale.to_bits(),
            view.lod.to_bits(),
            mode,
            view.first_channel,
            view.count(gpu.channel_count()),
            0,
        ];
        let view_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("view"),
            size: 32,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        queue.write_buffer(&view_buffer, 0, &words.map(u32::to_le_bytes).concat());
        let [desc, latents] = gpu.sample_entries(self.bindings).expect("a neural material");
        let view_entry =
            wgpu::BindGroupEntry { binding: 0, resource: view_buffer.as_entire_binding() };
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("sample quad"),
            layout: &self.layout,
            entries: &[view_entry, desc, latents],
        });
        let target = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("sample quad"),
            size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let pitch = (w * 16).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let back = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("sample quad readback"),
            size: u64::from(pitch * h),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let target_view = target.create_view(&Default::default());
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("sample quad"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &target_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.draw(0..4, 0..1);
        }
        encoder.copy_texture_to_buffer(
            target.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &back,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(pitch),
                    rows_per_image: None,
                },
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        queue.submit([encoder.finish()]);
        back.map_async(wgpu::MapMode::Read, .., |r| r.expect("mapping the readback buffer"));
        device.poll(wgpu::PollType::wait_indefinitely()).expect("waiting for the GPU");
        let bytes = back.get_mapped_range(..).expect("the mapped readback").to_vec();
        bytes
            .chunks(pitch as usize)
            .flat_map(|row| row[..(w * 16) as usize].chunks(16).map(pixel).collect::<Vec<_>>())
            .collect()
    }
}

fn pixel(bytes: &[u8]) -> [f32; 4] {
    core::array::from_fn(|k| {
        f32::from_le_bytes([bytes[4 * k], bytes[4 * k + 1], bytes[4 * k + 2], bytes[4 * k + 3]])
    })
}

/// What the CPU samples for every pixel of `view` (channels the view does not show: 0).
pub fn cpu_pixels(m: &Material<'_>, view: &View) -> Result<Vec<[f32; 4]>, nmat_core::Error> {
    let count = view.count(m.channel_count());
    let mask = ChannelMask((((1u32 << count) - 1) << view.first_channel) as u16);
    let mut pixels = Vec::new();
    for y in 0..view.size.1 {
        for x in 0..view.size.0 {
            let req = SampleRequest {
                u: view.origin[0] + (x as f32 + 0.5) * view.scale,
                v: view.origin[1] + (y as f32 + 0.5) * view.scale,
                lod: view.lod,
                filter: view.filter,
                precision: Precision::Integer,
                random: noise(x, y),
                channels: mask,
            };
            let mut px = [0f32; 4];
            m.sample(&req, &mut px[..count as usize])?;
            pixels.push(px);
        }
    }
    Ok(pixels)
}

/// The largest |GPU − CPU| over all pixels and shown channels, as a fraction of each channel's
/// range (constant channels: of 1).
pub fn max_difference(m: &Material<'_>, view: &View, gpu: &[[f32; 4]], cpu: &[[f32; 4]]) -> f32 {
    let first = view.first_channel as usize;
    let widths: Vec<f32> = m.channels()[first..first + view.count(m.channel_count()) as usize]
        .iter()
        .map(|c| (c.range_max - c.range_min).abs())
        .map(|w| if w > 0.0 { w } else { 1.0 })
        .collect();
    let mut worst = if gpu.len() == cpu.len() { 0f32 } else { f32::INFINITY };
    for (g, c) in gpu.iter().zip(cpu) {
        for (k, width) in widths.iter().enumerate() {
            worst = worst.max((g[k] - c[k]).abs() / width);
        }
    }
    worst
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let bytes = match std::env::args_os().nth(1) {
        Some(path) => std::fs::read(&path)
            .map_err(|e| format!("reading {}: {e}", std::path::Path::new(&path).display()))?,
        None => FIXTURE.to_vec(),
    };
    // `nmat encode` writes packed files by default: unpack once (a no-op for fixed-rate ones).
    let bytes = nmat_core::unpack(&bytes, Default::default())?;
    let material = Container::parse(&bytes)?;
    let (device, queue, info) =
        pollster::block_on(nmat_wgpu::default_device()).ok_or("no GPU adapter found")?;
    println!("adapter: {} ({:?})", info.name, info.backend);
    let context = Context::new(&device);
    let gpu = context.upload(&device, &queue, &material)?;
    let quad = Quad::new(&device);
    // The whole material (uv in [0, 1]) on a power-of-two square, halfway between mips 0 and 1.
    let (w, h) = material.mip_size(0);
    let side = w.max(h).next_power_of_two().clamp(16, 512);
    let mut failed = false;
    for filter in [Filter::Nearest, Filter::Bilinear, Filter::Trilinear, Filter::Stochastic] {
        let view = View {
            size: (side, side),
            origin: [0.0, 0.0],
            scale: 1.0 / side as f32,
            lod: 0.5,
            filter,
            first_channel: 0,
        };
        let pixels = quad.render(&device, &queue, &gpu, &view);
        let expected = cpu_pixels(&material, &view)?;
        let worst = max_difference(&material, &view, &pixels, &expected);
        println!(
            "{filter:?}: {side}×{side} pixels, channels 0..{}: largest |GPU − CPU| = {worst:.2e} \
             of the channel range",
            view.count(material.channel_count())
        );
        failed |= worst.is_nan() || worst > TOLERANCE;
    }
    if failed {
        return Err(format!("pixels differ from the CPU by more than {TOLERANCE:e}").into());
    }
    println!("every pixel agrees with Material::sample on the CPU");
    Ok(())
}

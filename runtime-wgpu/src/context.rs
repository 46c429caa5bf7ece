//! [`Context`]: a device's pipelines, pools and caches, and the bind group every decode,
//! transcode and encode entry point of the main shader shares.

use crate::gpu::{WORKGROUP, storage_entry, uniform_buffer, uniform_entry};
use crate::layout::ShaderLayout;
use crate::submit::Pool;
use crate::upload::NetworkPipeline;
use crate::{GpuError, GpuMaterial, Kernel, jpeg};
use nmat_core::ChannelMask;
use std::collections::HashMap;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};

/// The cached pipelines (decode, BC transcode, BC encode of given pixels). Create one per device.
pub struct Context {
    /// The reference decode kernel (`main` in decode.wgsl).
    pub(crate) pipeline: wgpu::ComputePipeline,
    /// BC encoding of decoded codes (`encode_codes` in bc.wgsl).
    pub(crate) encode_codes: wgpu::ComputePipeline,
    pub(crate) encode: wgpu::ComputePipeline,
    pub(crate) layout: wgpu::BindGroupLayout,
    pub(crate) pipeline_layout: wgpu::PipelineLayout,
    /// Tiled and matrix pipelines by source (one per kernel and material shape); `None` where
    /// the device refused the source.
    pub(crate) tiled: Mutex<HashMap<String, Option<Arc<wgpu::ComputePipeline>>>>,
    /// Store pipelines of `record_map_to_texture` by texture format.
    pub(crate) stores: Mutex<HashMap<wgpu::TextureFormat, Option<Arc<wgpu::ComputePipeline>>>>,
    /// The codes between the two passes of `record_map_to_texture`, shared by all its calls
    /// (replaced by a larger one when a call needs more).
    pub(crate) texture_codes: Mutex<Option<wgpu::Buffer>>,
    /// Bound where a dispatch has no material or no requests.
    pub(crate) empty: wgpu::Buffer,
    /// Buffers of finished submit-and-wait decodes, for the next ones.
    pub(crate) pool: Pool,
    /// The JPEG decode pipeline (jpeg.wgsl), built when a JPEG material is first decoded.
    pub(crate) jpeg: Mutex<Option<Arc<jpeg::JpegPipelines>>>,
    /// The kernel measured fastest per network shape (`shape_key`).
    pub(crate) choices: Mutex<HashMap<String, Kernel>>,
    /// A kernel made to compute wrong codes ([`Context::break_kernel_for_testing`]).
    pub(crate) fault: Mutex<Option<Kernel>>,
    /// Tile entries made to store wrong codes ([`Context::break_tile_decoders_for_testing`]).
    pub(crate) tile_fault: AtomicBool,
    /// The JPEG request passes' work buffer and its shape, shared by every JPEG material's calls
    /// (replaced by a larger one when a material needs more; jpeg.rs, `WorkShape`).
    pub(crate) jpeg_work: Mutex<Option<(wgpu::Buffer, jpeg::WorkShape)>>,
    /// The JPEG request passes' scratch words per material, where a test made it small
    /// ([`Context::limit_jpeg_scratch_for_testing`]).
    pub(crate) jpeg_scratch: Mutex<Option<u32>>,
}

/// The shader: BC1's single-colour table from the core, the decoder, the BC encoders.
pub(crate) fn shader_source() -> String {
    let table: Vec<String> = (0..=255u8)
        .map(|v| {
            let [[a5, b5], [a6, b6]] = nmat_core::bc::bc1_single_colour_endpoints(v);
            let word = u32::from_le_bytes([a5, b5, a6, b6]);
            format!("{word}u")
        })
        .collect();
    format!(
        "// BC1 single-colour endpoints per 8-bit value: 5-bit pair in bytes 0-1, 6-bit in 2-3.\n\
         const BC1_SINGLE = array<u32, 256>({});\n{}\n{}\n{}",
        table.join(", "),
        crate::layout::texel_wgsl(),
        crate::layout::decode_wgsl(),
        include_str!("shaders/bc.wgsl")
    )
}

impl Context {
    pub fn new(device: &wgpu::Device) -> Context {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("nmat decode"),
            source: wgpu::ShaderSource::Wgsl(shader_source().into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("nmat decode"),
            entries: &[
                storage_entry(0, true),
                storage_entry(1, true),
                storage_entry(2, true),
                storage_entry(3, false),
                uniform_entry(4),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("nmat decode"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let empty = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("nmat empty"),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        Context {
            pipeline: pipeline("main"),
            encode_codes: pipeline("encode_codes"),
            encode: pipeline("encode_pixels"),
            layout,
            pipeline_layout,
            tiled: Mutex::default(),
            stores: Mutex::default(),
            texture_codes: Mutex::default(),
            empty,
            pool: Pool::default(),
            jpeg: Mutex::default(),
            choices: Mutex::default(),
            fault: Mutex::default(),
            tile_fault: AtomicBool::new(false),
            jpeg_work: Mutex::default(),
            jpeg_scratch: Mutex::default(),
        }
    }

    /// A bind group of the five bindings every entry point declares.
    pub(crate) fn bind(
        &self,
        device: &wgpu::Device,
        material: Option<&GpuMaterial>,
        requests: Option<&wgpu::Buffer>,
        out: &wgpu::Buffer,
        params: &impl ShaderLayout,
    ) -> wgpu::BindGroup {
        let uniform = uniform_buffer(device, &params.bytes());
        self.bind_with(device, material, requests, out, &uniform)
    }

    /// A bind group of the five bindings, with the parameters in `uniform`.
    pub(crate) fn bind_with(
        &self,
        device: &wgpu::Device,
        material: Option<&GpuMaterial>,
        requests: Option<&wgpu::Buffer>,
        out: &wgpu::Buffer,
        uniform: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let (desc, latents) =
            material.map_or((&self.empty, &self.empty), |m| (&m.desc, &m.latents));
        self.bind_buffers(device, [desc, latents, requests.unwrap_or(&self.empty), out], uniform)
    }

    /// A bind group of the five bindings: four storage buffers, then the parameters.
    pub(crate) fn bind_buffers(
        &self,
        device: &wgpu::Device,
        buffers: [&wgpu::Buffer; 4],
        uniform: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
            .iter()
            .chain([&uniform])
            .enumerate()
            .map(|(binding, b)| wgpu::BindGroupEntry {
                binding: binding as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("nmat"),
            layout: &self.layout,
            entries: &entries,
        })
    }

    /// The decode pipeline of a neural material's kernel (`tiled`) and its texels per workgroup.
    pub(crate) fn decode_pipeline<'a>(
        &'a self,
        tiled: &'a NetworkPipeline,
    ) -> (&'a wgpu::ComputePipeline, u32) {
        match tiled {
            Some((pipeline, texels)) => (pipeline, *texels),
            None => (&self.pipeline, WORKGROUP),
        }
    }

    pub(crate) fn mask(
        &self,
        gm: &GpuMaterial,
        channels: ChannelMask,
    ) -> Result<(u32, u32), GpuError> {
        let mask =
            channels.resolve(gm.channel_count).ok_or(GpuError::Channels { mask: channels.0 })?;
        Ok((u32::from(mask), mask.count_ones()))
    }
}

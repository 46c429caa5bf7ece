//! [`Context`]: a device's pipelines, pools and caches, and the bind group every decode,
//! transcode and encode entry point of the main shader shares.

use crate::gpu::{
    Bound, KeptBinds, WORKGROUP, Waits, checked_pipeline, now, storage_entry, uniform_buffer,
    uniform_entry,
};
use crate::layout::{JpegParams, ShaderLayout};
use crate::submit::Pool;
use crate::upload::NetworkPipeline;
use crate::{GpuError, GpuMaterial, Kernel, jpeg};
use nmat_core::ChannelMask;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};

/// The cached pipelines (decode, BC transcode, BC encode of given pixels). Create one per device.
pub struct Context {
    /// The reference decode kernel (`main` in decode.wgsl).
    pub(crate) pipeline: wgpu::ComputePipeline,
    /// BC encoding of decoded codes (`encode_codes` in bc.wgsl).
    pub(crate) encode_codes: wgpu::ComputePipeline,
    pub(crate) encode: wgpu::ComputePipeline,
    /// BC7's module (bc7.wgsl after the main shader) and its `encode_codes_bc7` and
    /// `encode_pixels_bc7` pipelines, each built when first used.
    pub(crate) bc7: Mutex<Bc7Pipelines>,
    pub(crate) layout: wgpu::BindGroupLayout,
    pub(crate) pipeline_layout: wgpu::PipelineLayout,
    /// The matrix kernel's weights in a storage buffer (group 1, `matrix::WEIGHTS_GROUP`), and
    /// the pipeline layout of the decode kernels with that group (`None` on a device that binds
    /// fewer than 5 storage buffers per shader stage).
    pub(crate) weights_layout: wgpu::BindGroupLayout,
    pub(crate) weights_pipeline_layout: Option<wgpu::PipelineLayout>,
    /// Whether dispatches take their parameters as immediates ([`immediates_usable`]) rather
    /// than from a uniform buffer (binding 4) made per call.
    pub(crate) immediates: bool,
    /// With immediates: the bind groups of the last [`KEPT_BINDS`] distinct buffer sets, most
    /// recent first, so that calls on the same buffers allocate nothing.
    pub(crate) binds: KeptBinds<[wgpu::Buffer; 4]>,
    /// Bind groups made for dispatches so far (a test reads it).
    pub(crate) binds_made: AtomicU32,
    /// Tiled and matrix pipelines by source (one per kernel and material shape); `None` where
    /// the device refused the source.
    pub(crate) tiled: Mutex<HashMap<String, Option<Arc<wgpu::ComputePipeline>>>>,
    /// Store pipelines of `record_map_to_texture` by texture format.
    pub(crate) stores: Mutex<HashMap<wgpu::TextureFormat, Option<Arc<wgpu::ComputePipeline>>>>,
    /// With immediates: the store pass's bind groups of recent targets (texture, mip level, the
    /// codes buffer), most recent first.
    pub(crate) store_binds: KeptBinds<StoreKey>,
    /// The codes between the two passes of `record_map_to_texture`, shared by all its calls
    /// (replaced by a larger one when a call needs more).
    pub(crate) texture_codes: Mutex<Option<wgpu::Buffer>>,
    /// The blocks of `record_bc_textures` between its encode passes and its copies into the
    /// textures, shared by all its calls (replaced by a larger one when a call needs more).
    pub(crate) bc_staging: Mutex<Option<wgpu::Buffer>>,
    /// The most bytes one pass of the transcoding calls decodes or stages, where a test made it
    /// small ([`Context::limit_pass_bytes_for_testing`]).
    pub(crate) pass_bytes: Mutex<Option<u64>>,
    /// The engine's pipeline cache, where it gave one ([`Context::with_pipeline_cache`]): every
    /// pipeline the `Context` builds is created with it.
    pub(crate) pipeline_cache: Option<wgpu::PipelineCache>,
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
    /// Whether the matrix kernel's matrix operations are emulated, and in which variant
    /// ([`Context::emulate_matrix_for_testing`]).
    pub(crate) matrix_emulation: Mutex<Option<crate::matrix::Emulation>>,
    /// How long a probe decode is waited for, where a test set it
    /// ([`Context::limit_probe_wait_for_testing`]).
    pub(crate) probe_wait: Mutex<Option<std::time::Duration>>,
    /// The JPEG request passes' work buffer and its shape, shared by every JPEG material's calls
    /// (replaced by a larger one when a material needs more; jpeg.rs, `WorkShape`).
    pub(crate) jpeg_work: Mutex<Option<(wgpu::Buffer, jpeg::WorkShape)>>,
    /// The JPEG request passes' scratch words per material, where a test made it small
    /// ([`Context::limit_jpeg_scratch_for_testing`]).
    pub(crate) jpeg_scratch: Mutex<Option<u32>>,
}

/// What a kept store bind group binds: the target texture, its mip level, the codes.
pub(crate) type StoreKey = (wgpu::Texture, u32, wgpu::Buffer);

/// Bind groups a [`Context`] keeps (with immediates): a frame's worth of distinct buffer sets
/// (materials, request lists, outputs).
const KEPT_BINDS: usize = 16;

/// Store bind groups a [`Context`] keeps (with immediates): targets of a frame's calls.
const KEPT_STORE_BINDS: usize = 8;

/// Bytes of the largest parameter block a dispatch of the decode kernels takes (the JPEG
/// passes'; the others' are shorter): what a device needs for `max_immediate_size` so that
/// dispatches take their parameters as immediates.
pub const IMMEDIATE_BYTES: u32 = 4 * JpegParams::WORDS as u32;

/// Whether `device` takes the decode kernels' parameters as immediates: wgpu's `IMMEDIATES`
/// enabled with room for [`IMMEDIATE_BYTES`] (Vulkan, Metal and DirectX 12 have them;
/// `default_device` asks for them).
pub fn immediates_usable(device: &wgpu::Device) -> bool {
    device.features().contains(wgpu::Features::IMMEDIATES)
        && device.limits().max_immediate_size >= IMMEDIATE_BYTES
}

/// BC7's shader module and its two pipelines (of decoded codes, of given pixels), built when
/// first used.
#[derive(Default)]
pub(crate) struct Bc7Pipelines {
    module: Option<wgpu::ShaderModule>,
    pipelines: [Option<Arc<wgpu::ComputePipeline>>; 2],
}

/// A BC encoding pipeline: one of the `Context`'s own, or one of BC7's.
pub(crate) enum EncoderPipeline<'a> {
    Main(&'a wgpu::ComputePipeline),
    Bc7(Arc<wgpu::ComputePipeline>),
}

impl std::ops::Deref for EncoderPipeline<'_> {
    type Target = wgpu::ComputePipeline;

    fn deref(&self) -> &wgpu::ComputePipeline {
        match self {
            EncoderPipeline::Main(p) => p,
            EncoderPipeline::Bc7(p) => p,
        }
    }
}

/// `source` with its parameters (the uniform at binding 4) declared as immediates where
/// `immediates`: the same struct, read the same way.
pub(crate) fn with_parameters(source: &str, immediates: bool) -> String {
    if immediates {
        source.replace("@group(0) @binding(4) var<uniform> ", "var<immediate> ")
    } else {
        source.to_string()
    }
}

/// The BC7 encoder's shader: the main one (whose decoder and helpers it calls) and bc7.wgsl.
pub(crate) fn bc7_source() -> String {
    format!("{}\n{}", shader_source(), include_str!("shaders/bc7.wgsl"))
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
    /// The pipelines and state for decoding on `device` (one `Context` per device).
    pub fn new(device: &wgpu::Device) -> Context {
        Context::build(device, None)
    }

    /// [`Context::new`], every pipeline the `Context` builds (now and as materials of new shapes
    /// arrive) created with `cache`: an engine that keeps a `wgpu::PipelineCache`
    /// (`Features::PIPELINE_CACHE`, Vulkan) and saves its `get_data()` between runs gives it here,
    /// so that a later run's pipelines can come from the driver's cache instead of its compiler.
    /// The cache must belong to `device`.
    pub fn with_pipeline_cache(device: &wgpu::Device, cache: wgpu::PipelineCache) -> Context {
        Context::build(device, Some(cache))
    }

    fn build(device: &wgpu::Device, pipeline_cache: Option<wgpu::PipelineCache>) -> Context {
        let immediates = immediates_usable(device);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("nmat decode"),
            source: wgpu::ShaderSource::Wgsl(with_parameters(&shader_source(), immediates).into()),
        });
        let mut entries = vec![
            storage_entry(0, true),
            storage_entry(1, true),
            storage_entry(2, true),
            storage_entry(3, false),
        ];
        if !immediates {
            entries.push(uniform_entry(4));
        }
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("nmat decode"),
            entries: &entries,
        });
        let immediate_size = if immediates { IMMEDIATE_BYTES } else { 0 };
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("nmat decode"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size,
        });
        let weights_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("nmat matrix weights"),
            entries: &[storage_entry(0, true)],
        });
        let weights_pipeline_layout = (device.limits().max_storage_buffers_per_shader_stage
            >= crate::matrix::STORAGE_BUFFERS_WITH_WEIGHTS)
            .then(|| {
                device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("nmat decode, weights in storage"),
                    bind_group_layouts: &[Some(&layout), Some(&weights_layout)],
                    immediate_size,
                })
            });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: pipeline_cache.as_ref(),
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
            bc7: Mutex::default(),
            layout,
            pipeline_layout,
            weights_layout,
            weights_pipeline_layout,
            immediates,
            binds: KeptBinds::new(KEPT_BINDS),
            binds_made: AtomicU32::new(0),
            tiled: Mutex::default(),
            stores: Mutex::default(),
            store_binds: KeptBinds::new(KEPT_STORE_BINDS),
            texture_codes: Mutex::default(),
            bc_staging: Mutex::default(),
            pass_bytes: Mutex::default(),
            pipeline_cache,
            empty,
            pool: Pool::default(),
            jpeg: Mutex::default(),
            choices: Mutex::default(),
            fault: Mutex::default(),
            tile_fault: AtomicBool::new(false),
            matrix_emulation: Mutex::default(),
            probe_wait: Mutex::default(),
            jpeg_work: Mutex::default(),
            jpeg_scratch: Mutex::default(),
        }
    }

    /// The BC encoding pipeline of `format` (bc.wgsl's, or bc7.wgsl's, built on first use): of
    /// decoded codes (`codes`) or of pixels given by the caller.
    pub(crate) fn encoder_pipeline(
        &self,
        device: &wgpu::Device,
        format: nmat_core::bc::BcFormat,
        codes: bool,
    ) -> EncoderPipeline<'_> {
        use nmat_core::bc::BcFormat;
        if !matches!(format, BcFormat::Bc7Rgb | BcFormat::Bc7Rgba) {
            return EncoderPipeline::Main(if codes { &self.encode_codes } else { &self.encode });
        }
        let mut bc7 = self.bc7.lock().unwrap_or_else(|e| e.into_inner());
        let Bc7Pipelines { module, pipelines } = &mut *bc7;
        let module = module.get_or_insert_with(|| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("nmat bc7"),
                source: wgpu::ShaderSource::Wgsl(
                    with_parameters(&bc7_source(), self.immediates).into(),
                ),
            })
        });
        let entry = if codes { "encode_codes_bc7" } else { "encode_pixels_bc7" };
        let pipeline = pipelines[usize::from(!codes)].get_or_insert_with(|| {
            Arc::new(device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&self.pipeline_layout),
                module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: self.pipeline_cache.as_ref(),
            }))
        });
        EncoderPipeline::Bc7(pipeline.clone())
    }

    /// The bindings of a dispatch of the decode kernels' layout — the material's descriptor and
    /// latents (or none), the requests (or none), the output — and its parameters.
    pub(crate) fn bind(
        &self,
        device: &wgpu::Device,
        material: Option<&GpuMaterial>,
        requests: Option<&wgpu::Buffer>,
        out: &wgpu::Buffer,
        params: &impl ShaderLayout,
    ) -> Bound {
        let (desc, latents) =
            material.map_or((&self.empty, &self.empty), |m| (&m.desc, &m.latents));
        let buffers = [desc, latents, requests.unwrap_or(&self.empty), out];
        self.bind_buffers(device, buffers, &params.bytes())
    }

    /// The bindings of a dispatch: four storage buffers, and the parameters `bytes` — as
    /// immediates with a bind group kept for the same buffers (nothing allocated), or where the
    /// device has no immediates in a uniform buffer and a bind group made for this call.
    pub(crate) fn bind_buffers(
        &self,
        device: &wgpu::Device,
        buffers: [&wgpu::Buffer; 4],
        bytes: &[u8],
    ) -> Bound {
        if !self.immediates {
            return self.bind_fixed(device, buffers, bytes);
        }
        let key = buffers.map(Clone::clone);
        let group = self.binds.get_or_make(key, |_| self.make_group(device, buffers, None));
        Bound::new(group, Some(bytes.to_vec()))
    }

    /// The bindings of dispatches whose caller keeps them (the tile cache's decodes): a bind
    /// group made for them, with the parameters `bytes` as immediates or in a uniform buffer.
    pub(crate) fn bind_fixed(
        &self,
        device: &wgpu::Device,
        buffers: [&wgpu::Buffer; 4],
        bytes: &[u8],
    ) -> Bound {
        if self.immediates {
            let group = self.make_group(device, buffers, None);
            return Bound::new(group, Some(bytes.to_vec()));
        }
        let uniform = uniform_buffer(device, bytes);
        Bound::new(self.make_group(device, buffers, Some(&uniform)), None)
    }

    /// A bind group of the decode kernels' layout: four storage buffers, and the uniform where
    /// the layout has one.
    pub(crate) fn make_group(
        &self,
        device: &wgpu::Device,
        buffers: [&wgpu::Buffer; 4],
        uniform: Option<&wgpu::Buffer>,
    ) -> wgpu::BindGroup {
        self.binds_made.fetch_add(1, Ordering::Relaxed);
        let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
            .into_iter()
            .chain(uniform)
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

    /// The pipeline of `entry` in `source` (a shader of the decode kernels' layout, declaring its
    /// parameters at binding 4) in this context's layout — with the matrix kernel's weights as
    /// group 1 where the source declares them (`matrix::WEIGHTS_BINDING`); `None` where the
    /// device refuses it, as it answers now (`gpu::try_pipeline`).
    pub(crate) fn pipeline(
        &self,
        device: &wgpu::Device,
        source: &str,
        entry: &str,
    ) -> Option<wgpu::ComputePipeline> {
        now(self.checked_pipeline(device, source, entry, Waits::Block)).flatten()
    }

    /// [`Context::pipeline`] once the device has answered on it (`Waits::Await`), or with the
    /// answer it has now (`gpu::checked_pipeline`).
    pub(crate) fn checked_pipeline(
        &self,
        device: &wgpu::Device,
        source: &str,
        entry: &str,
        waits: Waits,
    ) -> impl Future<Output = Option<wgpu::ComputePipeline>> + use<> {
        let layout = if source.contains(crate::matrix::WEIGHTS_BINDING) {
            self.weights_pipeline_layout.as_ref()
        } else {
            Some(&self.pipeline_layout)
        };
        let source = with_parameters(source, self.immediates);
        let built = layout.map(|layout| {
            let layout_and_cache = (Some(layout), self.pipeline_cache.as_ref());
            checked_pipeline(device, &source, entry, layout_and_cache, waits)
        });
        async move {
            match built {
                Some(pipeline) => pipeline.await,
                None => None,
            }
        }
    }

    /// Whether dispatches take their parameters as immediates ([`immediates_usable`]): then a
    /// recorded call on buffers a recent call bound allocates nothing.
    pub fn uses_immediates(&self) -> bool {
        self.immediates
    }

    /// Drops the bind groups kept for recent calls (with immediates, those of the last 16
    /// distinct sets of buffers and of the last 8 texture targets), and with them the
    /// references they hold to those buffers and textures: e.g. after dropping a material or an
    /// output whose memory should be freed now.
    pub fn release_kept_bind_groups(&self) {
        self.binds.forget(|_| true);
        self.store_binds.forget(|_| true);
    }

    /// Drops the kept bind groups that bind `buffer` (one of the `Context`'s own that is no
    /// longer needed, e.g. upload's timing output), so that they do not keep it alive.
    pub(crate) fn forget_bindings_of(&self, buffer: &wgpu::Buffer) {
        self.binds.forget(|kept| kept.contains(buffer));
    }

    /// Bind groups made for dispatches so far. For tests only.
    #[doc(hidden)]
    pub fn bind_groups_made_for_testing(&self) -> u32 {
        self.binds_made.load(Ordering::Relaxed)
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

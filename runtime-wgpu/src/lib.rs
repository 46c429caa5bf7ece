//! `nmat-wgpu`: batch decoding of `.nmat` materials on any GPU wgpu reaches (Vulkan, Metal,
//! D3D12, OpenGL ES, WebGPU), bit-exact with `nmat_core`'s integer decoder: the same 8-bit codes
//! as every CPU kernel and the C API.
//!
//! The caller owns the device and queue (engines do); a [`Context`] caches the pipelines;
//! [`Context::upload`] puts a material's packed latent words (as stored in the file), its int8
//! weights and its requantization constants into buffers once. Decodes are submit-then-map:
//! [`Context::submit_requests`] / [`Context::submit_region`] record and submit the work and return
//! a [`PendingDecode`] whose [`PendingDecode::wait`] maps the result; `decode_*` do both.
//!
//! ```no_run
//! # async fn demo(bytes: &[u8]) -> Result<(), Box<dyn std::error::Error>> {
//! use nmat_core::{ChannelMask, Container};
//! use nmat_wgpu::{Context, TexelRequest};
//! let material = Container::parse(bytes)?;
//! // An engine passes its own device; tools can ask for the first adapter wgpu finds.
//! let (device, queue, _info) = nmat_wgpu::default_device().await.ok_or("no GPU adapter")?;
//! let context = Context::new(&device); // once per device
//! let gpu = context.upload(&device, &queue, &material)?; // once per material
//! // A whole mip: one code per texel and channel, row by row.
//! let mip0 = context.decode_mip(&device, &queue, &gpu, 0, ChannelMask::ALL)?;
//! // Scattered texels (e.g. what a frame touches): many per call.
//! let requests = [TexelRequest { x: 3, y: 5, mip: 0 }, TexelRequest { x: 9, y: 1, mip: 2 }];
//! let codes = context.decode_requests(&device, &queue, &gpu, &requests, ChannelMask::ALL)?;
//! # let _ = (mip0, codes); Ok(()) }
//! ```
//!
//! For throughput keep several decodes in flight: submit regions with
//! [`Context::submit_region`] and [`PendingDecode::wait`] on them later; their buffers and bind
//! groups are reused by later calls. An engine that keeps the codes on the GPU records instead:
//! [`Context::record_region`] and [`Context::record_requests`] (requests read from the caller's
//! buffer, e.g. written by its own pass) add a dispatch to the caller's command encoder that
//! writes the codes, packed four per `u32`, into the caller's buffer; nothing is submitted.
//! Upload picks, of the [`Kernel`]s the device runs (tiled: 4 rows × 4 texels per invocation
//! over workgroup memory, with `dot4I8Packed` where the device's WGSL has it; matrix: tensor
//! cores through wgpu's cooperative matrices, where the device has them), the fastest by
//! measurement among those whose codes on a probe of the material equal the CPU's; all give the
//! same codes. To decode where a material is drawn, an engine includes the decoder in its
//! own shaders: [`SampleBindings::module`] is a WGSL module with `nmat_sample(uv, lod, rnd, mode,
//! channels)` (the CPU's filters) and `nmat_texel`, bound with [`GpuMaterial::sample_entries`]
//! (example `sample_quad`). Only downlevel limits are needed: 32-bit integers only (no `f16`,
//! no subgroups, no 64-bit integers; the wide products are computed in pieces); the matrix
//! kernel alone needs more ([`MATRIX_FEATURES`]) and is skipped where the device lacks it. The
//! decode arithmetic is that of the format specification (`docs/FORMAT.md` of the repository, §6;
//! embedded in `nmat_core::spec`); how the kernel maps it onto 32-bit integers and what it costs
//! is in `docs/GPU.md`, embedded here as [`design`]. JPEG materials (§11) upload and decode
//! through the same region and request calls, one workgroup per MCU ([`GpuMaterial::codec`]).
//! A renderer that decodes only what its frames touch keeps a [`GpuTileCache`]
//! ([`Context::create_tile_cache`]): mark, decode the missing tiles and resolve, as passes
//! recorded into its own encoder, for neural and JPEG materials alike.

mod cache;
mod jpeg;
mod matrix;
pub mod measure;
mod sample;
mod texture;
mod tiled;
mod transcode;
mod upload;

pub use cache::{CacheLookup, GpuTileCache, MAX_CACHE_MATERIALS};
pub use matrix::{FEATURES as MATRIX_FEATURES, usable as matrix_usable};
pub use sample::SampleBindings;
pub use texture::TextureTarget;
pub use tiled::Kernel;
pub use transcode::{PendingBlocks, aligned_row_pitch, encodes, texture_format};
pub use upload::PROBE_TEXELS;

/// The GPU runtime's design and measured speed (`docs/GPU.md` of the repository).
#[cfg(doc)]
#[doc = include_str!("../../docs/GPU.md")]
#[allow(rustdoc::broken_intra_doc_links)]
pub mod design {}

use nmat_core::bc::BcFormat;
use nmat_core::{BlockRegion, ChannelMask};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, mpsc};
use wgpu::util::DeviceExt;

/// The wgpu this crate is built against (its types are in this crate's API).
pub use wgpu;
pub use wgpu::DeviceType;

/// Everything that can go wrong, named.
#[derive(Debug)]
#[non_exhaustive]
pub enum GpuError {
    /// The channel mask is empty or names a channel the material lacks.
    Channels { mask: u16 },
    /// A region outside the mip, or a mip beyond the chain.
    Region { mip: u32, x0: u32, y0: u32, width: u32, height: u32 },
    /// More texels in one call than one dispatch or buffer allows.
    TooLarge { texels: u64, limit: u64 },
    /// A grid too large for 32-bit bit addressing on the GPU (≥ 2^32 latent bits).
    GridTooLarge { grid: usize },
    /// Mapping the result buffer failed (device lost, …).
    Map(String),
    /// A BC format the GPU does not encode (BC7 is encoded on the CPU only).
    Format { format: BcFormat },
    /// A region of blocks outside the mip's blocks, or a mip beyond the chain.
    Blocks { mip: u32, region: BlockRegion },
    /// A row pitch shorter than a row of blocks, or not a multiple of 4 bytes.
    RowPitch { row_pitch: u64, min: u64 },
    /// The output buffer lacks `STORAGE` usage, is larger than the device's storage binding
    /// limit, or the offset is not a multiple of 4 bytes.
    OutputBuffer { reason: &'static str },
    /// The output buffer (from the offset) is too small for the blocks or codes.
    Output { needed: u64, size: u64 },
    /// A buffer of requests that lacks `STORAGE` usage, is larger than the device's storage
    /// binding limit, has an offset that is not a multiple of 4 bytes, or ends before the last
    /// request.
    RequestBuffer { reason: &'static str },
    /// A kernel asked for by [`Context::upload_with`] that this device cannot run.
    Kernel { kernel: Kernel, reason: &'static str },
    /// A texture [`Context::record_map_to_texture`] cannot write (dimension, usage, format,
    /// mip level, room at the origin).
    Texture { reason: &'static str },
    /// A JPEG material's section larger than one storage binding of the device (or 2^28 bytes,
    /// so that bit positions fit 32 bits).
    SectionTooLarge { bytes: u64, limit: u64 },
    /// A tile cache [`Context::create_tile_cache`] cannot make: no material or more than
    /// [`MAX_CACHE_MATERIALS`], no slot, or more tiles than one storage binding holds.
    Cache { reason: &'static str },
    /// A JPEG material (docs/FORMAT.md §11) given to a path that decodes neural materials only
    /// (`nmat_sample`, textures, BC transcoding): decode its regions or requests, or decode it
    /// on the CPU (`nmat_core`).
    Codec,
}

impl std::fmt::Display for GpuError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            GpuError::Channels { mask } => {
                write!(f, "channel mask {mask:#06x} is empty or names a missing channel")
            }
            GpuError::SectionTooLarge { bytes, limit } => write!(
                f,
                "the JPEG section has {bytes} bytes; this device binds at most {limit} in one buffer"
            ),
            GpuError::Codec => write!(
                f,
                "a JPEG material: this GPU path decodes neural materials only; use the region or \
                 request decode calls, or decode it on the CPU"
            ),
            GpuError::Region { mip, x0, y0, width, height } => {
                write!(
                    f,
                    "region {width}×{height} at ({x0}, {y0}) of mip {mip} is outside the material"
                )
            }
            GpuError::TooLarge { texels, limit } => {
                write!(f, "{texels} texels in one call; at most {limit}")
            }
            GpuError::GridTooLarge { grid } => {
                write!(f, "grid {grid} has 2^32 or more latent bits")
            }
            GpuError::Map(e) => write!(f, "reading the result back failed: {e}"),
            GpuError::Format { format } => {
                write!(f, "{} is not encoded on the GPU (BC1, BC4 and BC5 are)", format.name())
            }
            GpuError::Blocks { mip, region } => write!(
                f,
                "blocks {}×{} at ({}, {}) of mip {mip} are outside the mip's blocks",
                region.width, region.height, region.x, region.y
            ),
            GpuError::RowPitch { row_pitch, min } => {
                write!(f, "row pitch {row_pitch} bytes: needs at least {min} and a multiple of 4")
            }
            GpuError::OutputBuffer { reason } => write!(f, "output buffer: {reason}"),
            GpuError::Output { needed, size } => {
                write!(f, "output buffer of {size} bytes; the output needs {needed}")
            }
            GpuError::RequestBuffer { reason } => write!(f, "request buffer: {reason}"),
            GpuError::Texture { reason } => write!(f, "target texture: {reason}"),
            GpuError::Cache { reason } => write!(f, "tile cache: {reason}"),
            GpuError::Kernel { kernel, reason } => {
                write!(f, "the {} kernel does not run on this device: {reason}", kernel.name())
            }
        }
    }
}

impl std::error::Error for GpuError {}

/// One texel to decode: coordinates wrap or clamp by the material's address mode; a mip beyond
/// the chain is clamped to the last (as `Material::decode_texel_u8`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TexelRequest {
    pub x: i32,
    pub y: i32,
    pub mip: u32,
}

/// The cached pipelines (decode, BC transcode, BC encode of given pixels). Create one per device.
pub struct Context {
    /// The reference decode kernel (`main` in decode.wgsl).
    pipeline: wgpu::ComputePipeline,
    transcode: wgpu::ComputePipeline,
    encode: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    pipeline_layout: wgpu::PipelineLayout,
    /// Tiled and matrix pipelines by source (one per kernel and material shape); `None` where
    /// the device refused the source.
    tiled: Mutex<HashMap<String, Option<Arc<wgpu::ComputePipeline>>>>,
    /// Store pipelines of `record_map_to_texture` by texture format.
    stores: Mutex<HashMap<wgpu::TextureFormat, Option<Arc<wgpu::ComputePipeline>>>>,
    /// The codes between the two passes of `record_map_to_texture`, shared by all its calls
    /// (replaced by a larger one when a call needs more).
    texture_codes: Mutex<Option<wgpu::Buffer>>,
    /// Bound where a dispatch has no material or no requests.
    empty: wgpu::Buffer,
    /// Buffers of finished submit-and-wait decodes, for the next ones.
    pool: Pool,
    /// The JPEG decode pipeline (jpeg.wgsl), built when a JPEG material is first decoded.
    jpeg: Mutex<Option<Arc<jpeg::JpegPipelines>>>,
    /// The kernel measured fastest per network shape (`shape_key`).
    choices: Mutex<HashMap<String, Kernel>>,
    /// A kernel made to compute wrong codes ([`Context::break_kernel_for_testing`]).
    fault: Mutex<Option<Kernel>>,
}

/// A material's buffers on the GPU.
pub struct GpuMaterial {
    /// Unique per upload: which material a cached bind group binds.
    id: u64,
    desc: wgpu::Buffer,
    latents: wgpu::Buffer,
    channel_count: usize,
    mip_sizes: Vec<(u32, u32)>,
    /// Clamp (true) or wrap addressing, and each channel's range (min, max): for the tile cache.
    address_clamp: bool,
    ranges: Vec<(f32, f32)>,
    /// Per channel: the code of a constant channel (`Channel::constant_code`), which BC
    /// transcoding uses instead of the decoded one, as the CPU does.
    constant_codes: Vec<Option<u8>>,
    kernel: Kernel,
    /// Kernels whose codes on the upload's probe differed from the CPU's, and why.
    rejected: Vec<(Kernel, &'static str)>,
    /// The tiled or matrix kernel's pipeline and texels per workgroup (`None`: the reference
    /// kernel).
    tiled: Option<(Arc<wgpu::ComputePipeline>, u32)>,
    /// A JPEG material's maps (`desc` and `latents` then hold its descriptor and section).
    jpeg: Option<jpeg::JpegMaps>,
}

impl GpuMaterial {
    pub fn channel_count(&self) -> usize {
        self.channel_count
    }
    /// The kernel that decodes this material's regions and requests.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }
    /// The kernels [`Context::upload`] did not use because their codes on its probe differed
    /// from the CPU's (a driver that computes differently), with the reason; usually empty.
    pub fn rejected(&self) -> &[(Kernel, &'static str)] {
        &self.rejected
    }
    /// Width and height of each mip.
    pub fn mip_sizes(&self) -> &[(u32, u32)] {
        &self.mip_sizes
    }
    /// The material's codec. A JPEG material decodes through regions and requests (submitted or
    /// recorded); `nmat_sample`, textures and BC transcoding refuse it with [`GpuError::Codec`].
    pub fn codec(&self) -> nmat_core::Codec {
        if self.jpeg.is_some() { nmat_core::Codec::Jpeg } else { nmat_core::Codec::Neural }
    }
    /// [`GpuError::Codec`] for a JPEG material (paths that decode neural materials only).
    pub(crate) fn neural(&self) -> Result<(), GpuError> {
        if self.jpeg.is_some() { Err(GpuError::Codec) } else { Ok(()) }
    }
}

/// Work submitted to the queue; `wait` maps the result: `channels` 8-bit codes per texel, in
/// request (or row-major) order.
pub struct PendingDecode {
    /// `scratch`'s output and readback buffers (handles to the same buffers).
    out: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// Given back to `pool` on `wait` or drop.
    scratch: Option<Scratch>,
    pool: Pool,
    len: usize,
}

type Pool = Arc<Mutex<Vec<Scratch>>>;

const WORKGROUP: u32 = 64;
/// Workgroups per dispatch dimension guaranteed by downlevel limits.
const MAX_GROUPS: u32 = 65535;

/// The uniform block of every entry point (`Params` in decode.wgsl).
#[derive(Clone, Copy, Default)]
struct Params {
    mode: u32,
    count: u32,
    mip: u32,
    x0: u32,
    y0: u32,
    width: u32,
    channel_mask: u32,
    out_channels: u32,
    // BC transcoding (bc.wgsl).
    format: u32,
    components: u32,
    constants: u32,
    constant_mask: u32,
    row_words: u32,
    out_offset: u32,
    in_offset: u32,
}

/// Size of [`Params`] on the GPU: 16 words.
const PARAMS_BYTES: u64 = 64;

impl Params {
    fn bytes(&self) -> Vec<u8> {
        let words = [
            self.mode,
            self.count,
            self.mip,
            self.x0,
            self.y0,
            self.width,
            self.channel_mask,
            self.out_channels,
            self.format,
            self.components,
            self.constants,
            self.constant_mask,
            self.row_words,
            self.out_offset,
            self.in_offset,
            0,
        ];
        words_to_bytes(&words)
    }
}

fn words_to_bytes(words: &[u32]) -> Vec<u8> {
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

/// The shader: BC1's single-colour table from the core, the decoder, the BC encoders.
fn shader_source() -> String {
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
        include_str!("texel.wgsl"),
        include_str!("decode.wgsl"),
        include_str!("bc.wgsl")
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
            transcode: pipeline("transcode"),
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
        }
    }

    /// A bind group of the five bindings every entry point declares.
    fn bind(
        &self,
        device: &wgpu::Device,
        material: Option<&GpuMaterial>,
        requests: Option<&wgpu::Buffer>,
        out: &wgpu::Buffer,
        params: &Params,
    ) -> wgpu::BindGroup {
        let uniform = uniform_buffer(device, &params.bytes());
        self.bind_with(device, material, requests, out, &uniform)
    }

    /// A bind group of the five bindings, with the parameters in `uniform`.
    fn bind_with(
        &self,
        device: &wgpu::Device,
        material: Option<&GpuMaterial>,
        requests: Option<&wgpu::Buffer>,
        out: &wgpu::Buffer,
        uniform: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let (desc, latents) =
            material.map_or((&self.empty, &self.empty), |m| (&m.desc, &m.latents));
        let buffers = [desc, latents, requests.unwrap_or(&self.empty), out, uniform];
        let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
            .iter()
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

    /// The decode pipeline of `gm` and its texels per workgroup.
    fn decode_pipeline<'a>(&'a self, gm: &'a GpuMaterial) -> (&'a wgpu::ComputePipeline, u32) {
        match &gm.tiled {
            Some((pipeline, texels)) => (pipeline, *texels),
            None => (&self.pipeline, WORKGROUP),
        }
    }

    fn mask(&self, gm: &GpuMaterial, channels: ChannelMask) -> Result<(u32, u32), GpuError> {
        let mask =
            channels.resolve(gm.channel_count).ok_or(GpuError::Channels { mask: channels.0 })?;
        Ok((u32::from(mask), mask.count_ones()))
    }

    /// The workgroups of a decode of `params.count` texels, checked against the dispatch and
    /// binding limits (the codes take `count · out_channels` bytes).
    fn decode_groups(
        &self,
        device: &wgpu::Device,
        gm: &GpuMaterial,
        params: &Params,
    ) -> Result<u64, GpuError> {
        let texels = u64::from(self.decode_pipeline(gm).1);
        let count = u64::from(params.count);
        let groups = count.div_ceil(texels);
        let per_texel = u64::from(params.out_channels).max(1);
        let max_binding = device.limits().max_storage_buffer_binding_size;
        let max_groups = u64::from(MAX_GROUPS) * u64::from(MAX_GROUPS);
        if groups > max_groups || count * per_texel > max_binding {
            let limit = (max_groups * texels).min(max_binding / per_texel);
            return Err(GpuError::TooLarge { texels: count, limit });
        }
        Ok(groups)
    }

    /// The decode of the rectangle (x0, y0, width, height) of `mip`, checked.
    fn region_params(
        &self,
        gm: &GpuMaterial,
        mip: u32,
        (x0, y0, width, height): (u32, u32, u32, u32),
        channels: ChannelMask,
    ) -> Result<Params, GpuError> {
        let (mask, n) = self.mask(gm, channels)?;
        let region = GpuError::Region { mip, x0, y0, width, height };
        let Some(&(mw, mh)) = gm.mip_sizes.get(mip as usize) else {
            return Err(region);
        };
        if x0.checked_add(width).is_none_or(|e| e > mw)
            || y0.checked_add(height).is_none_or(|e| e > mh)
        {
            return Err(region);
        }
        let count = u64::from(width) * u64::from(height);
        let count = u32::try_from(count)
            .map_err(|_| GpuError::TooLarge { texels: count, limit: u64::from(u32::MAX) })?;
        Ok(Params {
            mode: 1,
            count,
            mip,
            x0,
            y0,
            width: width.max(1),
            channel_mask: mask,
            out_channels: n,
            ..Params::default()
        })
    }

    /// Takes reusable buffers with room for `out_bytes` of codes and `request_bytes` of
    /// requests from the pool, or makes new ones.
    fn take_scratch(&self, device: &wgpu::Device, out_bytes: u64, request_bytes: u64) -> Scratch {
        let mut pool = self.pool.lock().unwrap_or_else(|e| e.into_inner());
        let fits = |s: &Scratch| s.out.size() >= out_bytes && s.requests.size() >= request_bytes;
        if let Some(k) = pool.iter().position(fits) {
            return pool.swap_remove(k);
        }
        drop(pool);
        Scratch::new(device, out_bytes, request_bytes)
    }

    /// Submits a decode with the pool's buffers (bind group reused when the material is the
    /// one they were last bound to).
    fn submit(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        params: Params,
        requests: &[u8],
    ) -> Result<PendingDecode, GpuError> {
        // A JPEG material records its own passes (no uniform or bind group to reuse).
        let groups = match gm.jpeg {
            Some(_) => None,
            None => Some(self.decode_groups(device, gm, &params)?),
        };
        let len = u64::from(params.count) * u64::from(params.out_channels);
        let copy = len.next_multiple_of(4).max(4);
        let mut scratch = self.take_scratch(device, copy, requests.len() as u64);
        if !requests.is_empty() {
            queue.write_buffer(&scratch.requests, 0, requests);
        }
        let mut encoder = device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("nmat decode") });
        let Some(groups) = groups else {
            let requests = Some(&scratch.requests);
            self.record_jpeg(device, &mut encoder, gm, params, requests, &scratch.out)?;
            return Ok(self.finish(queue, encoder, scratch, len));
        };
        queue.write_buffer(&scratch.uniform, 0, &params.bytes());
        if scratch.bind.as_ref().is_none_or(|(id, _)| *id != gm.id) {
            let bind = self.bind_with(
                device,
                Some(gm),
                Some(&scratch.requests),
                &scratch.out,
                &scratch.uniform,
            );
            scratch.bind = Some((gm.id, bind));
        }
        if let Some((_, bind)) = &scratch.bind {
            dispatch(&mut encoder, self.decode_pipeline(gm).0, bind, groups);
        }
        Ok(self.finish(queue, encoder, scratch, len))
    }

    /// Copies the codes of `scratch` to its readback buffer after the work in `encoder`, submits,
    /// and hands the buffers to the [`PendingDecode`] (`len` codes).
    fn finish(
        &self,
        queue: &wgpu::Queue,
        mut encoder: wgpu::CommandEncoder,
        scratch: Scratch,
        len: u64,
    ) -> PendingDecode {
        let copy = len.next_multiple_of(4).max(4);
        encoder.copy_buffer_to_buffer(&scratch.out, 0, &scratch.readback, 0, copy);
        queue.submit([encoder.finish()]);
        PendingDecode {
            out: scratch.out.clone(),
            readback: scratch.readback.clone(),
            scratch: Some(scratch),
            pool: Arc::clone(&self.pool),
            len: len as usize,
        }
    }

    /// Checks that `out` can take `bytes` from byte `offset` (the last word whole); returns the
    /// offset in words.
    pub(crate) fn check_output(
        device: &wgpu::Device,
        out: &wgpu::Buffer,
        offset: u64,
        bytes: u64,
    ) -> Result<u32, GpuError> {
        if !out.usage().contains(wgpu::BufferUsages::STORAGE) {
            return Err(GpuError::OutputBuffer { reason: "it needs STORAGE usage" });
        }
        if !offset.is_multiple_of(4) {
            return Err(GpuError::OutputBuffer { reason: "the offset is not a multiple of 4" });
        }
        if out.size() > device.limits().max_storage_buffer_binding_size {
            return Err(GpuError::OutputBuffer {
                reason: "it is larger than the device's storage binding limit",
            });
        }
        let needed = offset + bytes.next_multiple_of(4);
        if needed > out.size() {
            return Err(GpuError::Output { needed, size: out.size() });
        }
        u32::try_from(offset / 4)
            .map_err(|_| GpuError::OutputBuffer { reason: "the offset is 2^34 bytes or more" })
    }

    /// Checks that `requests` holds `bytes` of requests from byte `offset` and can be bound;
    /// returns the offset in words.
    pub(crate) fn check_requests(
        device: &wgpu::Device,
        requests: &wgpu::Buffer,
        offset: u64,
        bytes: u64,
    ) -> Result<u32, GpuError> {
        let reason = if !requests.usage().contains(wgpu::BufferUsages::STORAGE) {
            Some("it needs STORAGE usage")
        } else if !offset.is_multiple_of(4) {
            Some("the offset is not a multiple of 4")
        } else if requests.size() > device.limits().max_storage_buffer_binding_size {
            Some("it is larger than the device's storage binding limit")
        } else if offset + bytes > requests.size() {
            Some("it ends before the last request")
        } else {
            None
        };
        if let Some(reason) = reason {
            return Err(GpuError::RequestBuffer { reason });
        }
        u32::try_from(offset / 4)
            .map_err(|_| GpuError::RequestBuffer { reason: "the offset is 2^34 bytes or more" })
    }

    /// Records, into the caller's `encoder` (nothing is submitted), the decode of the rectangle
    /// (x0, y0, width, height) of `mip`, row-major, channels in `channels`, into `out` from byte
    /// `offset`: the codes packed four per `u32`, so the bytes from `offset` are the codes in
    /// order (texel, then channel), as [`PendingDecode::wait`] returns them; the last word's
    /// spare bytes are written as zeros. Returns the number of codes. `out` needs `STORAGE`
    /// usage; `offset` is a multiple of 4. Everything is checked before anything is recorded.
    #[allow(clippy::too_many_arguments)] // a material, what, and where the codes go
    pub fn record_region(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        gm: &GpuMaterial,
        mip: u32,
        rect: (u32, u32, u32, u32),
        channels: ChannelMask,
        (out, offset): (&wgpu::Buffer, u64),
    ) -> Result<u64, GpuError> {
        let mut params = self.region_params(gm, mip, rect, channels)?;
        let len = u64::from(params.count) * u64::from(params.out_channels);
        params.out_offset = Self::check_output(device, out, offset, len)?;
        if gm.jpeg.is_some() {
            self.record_jpeg(device, encoder, gm, params, None, out)?;
            return Ok(len);
        }
        let groups = self.decode_groups(device, gm, &params)?;
        let bind = self.bind(device, Some(gm), None, out, &params);
        dispatch(encoder, self.decode_pipeline(gm).0, &bind, groups);
        Ok(len)
    }

    /// Records the decode of `count` [`TexelRequest`]s that are already on the GPU (e.g. written
    /// by the caller's own pass): 12 bytes each (x, y as `i32`, mip as `u32`, little-endian)
    /// from byte `requests_offset` of `requests` (`STORAGE` usage, offset a multiple of 4). The
    /// codes go to `out` as in [`Context::record_region`]. Returns the number of codes.
    #[allow(clippy::too_many_arguments)] // a material, what, and where the codes go
    pub fn record_requests(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        gm: &GpuMaterial,
        (requests, requests_offset, count): (&wgpu::Buffer, u64, u32),
        channels: ChannelMask,
        (out, offset): (&wgpu::Buffer, u64),
    ) -> Result<u64, GpuError> {
        let (mask, n) = self.mask(gm, channels)?;
        let mut params = Params {
            mode: 0,
            count,
            width: 1,
            channel_mask: mask,
            out_channels: n,
            ..Params::default()
        };
        let groups = self.decode_groups(device, gm, &params)?;
        params.in_offset =
            Self::check_requests(device, requests, requests_offset, 12 * u64::from(count))?;
        let len = u64::from(count) * u64::from(n);
        params.out_offset = Self::check_output(device, out, offset, len)?;
        if gm.jpeg.is_some() {
            self.record_jpeg(device, encoder, gm, params, Some(requests), out)?;
            return Ok(len);
        }
        let bind = self.bind(device, Some(gm), Some(requests), out, &params);
        dispatch(encoder, self.decode_pipeline(gm).0, &bind, groups);
        Ok(len)
    }

    /// Decodes a batch of arbitrary texels (the random-access path), channels in `channels`.
    pub fn submit_requests(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        requests: &[TexelRequest],
        channels: ChannelMask,
    ) -> Result<PendingDecode, GpuError> {
        let (mask, n) = self.mask(gm, channels)?;
        let count = u32::try_from(requests.len()).map_err(|_| GpuError::TooLarge {
            texels: requests.len() as u64,
            limit: u64::from(u32::MAX),
        })?;
        let bytes: Vec<u8> = requests
            .iter()
            .flat_map(|r| [r.x.to_le_bytes(), r.y.to_le_bytes(), r.mip.to_le_bytes()])
            .flatten()
            .collect();
        if bytes.len() as u64 > device.limits().max_storage_buffer_binding_size {
            return Err(GpuError::TooLarge {
                texels: u64::from(count),
                limit: device.limits().max_storage_buffer_binding_size / 12,
            });
        }
        let params = Params {
            mode: 0,
            count,
            width: 1,
            channel_mask: mask,
            out_channels: n,
            ..Params::default()
        };
        self.submit(device, queue, gm, params, &bytes)
    }

    /// Decodes the rectangle (x0, y0, width, height) of `mip`, row-major.
    #[allow(clippy::too_many_arguments)] // a rectangle is four numbers
    pub fn submit_region(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        mip: u32,
        rect: (u32, u32, u32, u32),
        channels: ChannelMask,
    ) -> Result<PendingDecode, GpuError> {
        let params = self.region_params(gm, mip, rect, channels)?;
        self.submit(device, queue, gm, params, &[])
    }

    /// Blocking convenience: `submit_requests` then `wait`.
    pub fn decode_requests(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        requests: &[TexelRequest],
        channels: ChannelMask,
    ) -> Result<Vec<u8>, GpuError> {
        self.submit_requests(device, queue, gm, requests, channels)?.wait(device)
    }

    /// Blocking convenience: a whole mip.
    pub fn decode_mip(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        mip: u32,
        channels: ChannelMask,
    ) -> Result<Vec<u8>, GpuError> {
        let &(w, h) = gm.mip_sizes.get(mip as usize).ok_or(GpuError::Region {
            mip,
            x0: 0,
            y0: 0,
            width: 0,
            height: 0,
        })?;
        self.submit_region(device, queue, gm, mip, (0, 0, w, h), channels)?.wait(device)
    }

    /// Blocking convenience: every mip, concatenated mip by mip.
    pub fn decode_chain(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        channels: ChannelMask,
    ) -> Result<Vec<u8>, GpuError> {
        let pending: Vec<PendingDecode> = (0..gm.mip_sizes.len() as u32)
            .map(|mip| {
                let (w, h) = gm.mip_sizes[mip as usize];
                self.submit_region(device, queue, gm, mip, (0, 0, w, h), channels)
            })
            .collect::<Result<_, _>>()?;
        let mut out = Vec::new();
        for p in pending {
            out.extend(p.wait(device)?);
        }
        Ok(out)
    }
}

impl PendingDecode {
    /// The GPU-side result: the codes packed four per `u32` (the buffer's bytes from 0 are the
    /// codes in order, channels fastest), usable as a storage buffer by the caller's own passes
    /// without a round trip through the CPU. The buffer may be longer than the result; it is
    /// reused by later decodes once this one is waited on or dropped.
    pub fn gpu_buffer(&self) -> &wgpu::Buffer {
        &self.out
    }

    /// Number of codes in the result.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Maps the result (blocking on the device) and returns the codes.
    pub fn wait(mut self, device: &wgpu::Device) -> Result<Vec<u8>, GpuError> {
        let mut bytes =
            read_back(device, &self.readback, (self.len as u64).next_multiple_of(4).max(4))?;
        bytes.truncate(self.len);
        self.give_back();
        Ok(bytes)
    }

    /// Returns the buffers to the context's pool (at most [`POOL`] are kept).
    fn give_back(&mut self) {
        if let Some(scratch) = self.scratch.take() {
            let mut pool = self.pool.lock().unwrap_or_else(|e| e.into_inner());
            if pool.len() < POOL {
                pool.push(scratch);
            }
        }
    }
}

impl Drop for PendingDecode {
    fn drop(&mut self) {
        self.give_back();
    }
}

/// Buffers of the submit-and-wait calls, reused between calls: a submit takes a set from the
/// context's pool (or makes one) and its [`PendingDecode`] gives it back.
struct Scratch {
    uniform: wgpu::Buffer,
    requests: wgpu::Buffer,
    out: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// The bind group of these buffers with the material of this id ([`GpuMaterial`]).
    bind: Option<(u64, wgpu::BindGroup)>,
}

/// Most sets of buffers a context keeps for reuse.
const POOL: usize = 8;

impl Scratch {
    /// Room for `out_bytes` of codes and `request_bytes` of requests, rounded up to a power of
    /// two (so that nearby sizes reuse the set) where the binding limit allows.
    fn new(device: &wgpu::Device, out_bytes: u64, request_bytes: u64) -> Scratch {
        let max_binding = device.limits().max_storage_buffer_binding_size;
        let room = |n: u64| {
            let n = n.next_multiple_of(4).max(16);
            if n.next_power_of_two() <= max_binding { n.next_power_of_two() } else { n }
        };
        let buffer = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let out_size = room(out_bytes);
        Scratch {
            uniform: buffer("nmat params", PARAMS_BYTES, U::UNIFORM | U::COPY_DST),
            requests: buffer("nmat requests", room(request_bytes), U::STORAGE | U::COPY_DST),
            out: buffer("nmat codes", out_size, U::STORAGE | U::COPY_SRC),
            readback: buffer("nmat readback", out_size, U::MAP_READ | U::COPY_DST),
            bind: None,
        }
    }
}

/// A compute-stage storage buffer binding of a bind group layout.
pub(crate) fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A compute-stage uniform buffer binding of a bind group layout.
pub(crate) fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// The bytes of `source` (a `COPY_SRC` buffer): copied into a mappable buffer, submitted, mapped
/// (blocks on the device). For tests and tools; a renderer keeps its results on the GPU.
pub fn read_buffer(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    source: &wgpu::Buffer,
) -> Result<Vec<u8>, GpuError> {
    let back = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("nmat readback"),
        size: source.size(),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(source, 0, &back, 0, source.size());
    queue.submit([encoder.finish()]);
    read_back(device, &back, source.size())
}

/// Maps the first `bytes` of `buffer` (blocking on the device) and returns them.
fn read_back(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<u8>, GpuError> {
    let (tx, rx) = mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, ..bytes, move |r| {
        let _ = tx.send(r);
    });
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Map(e.to_string()))?;
    rx.recv()
        .map_err(|e| GpuError::Map(e.to_string()))?
        .map_err(|e| GpuError::Map(e.to_string()))?;
    let view = buffer.get_mapped_range(..bytes).map_err(|e| GpuError::Map(e.to_string()))?;
    let bytes = view.to_vec();
    drop(view);
    buffer.unmap();
    Ok(bytes)
}

/// The compute pipeline of `entry` in `source` (with `layout`, or the one wgpu derives), or
/// `None` where the device refuses it (a shader language feature it lacks, a limit).
pub(crate) fn try_pipeline(
    device: &wgpu::Device,
    source: &str,
    entry: &str,
    layout: Option<&wgpu::PipelineLayout>,
) -> Option<wgpu::ComputePipeline> {
    let internal = device.push_error_scope(wgpu::ErrorFilter::Internal);
    let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(entry),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout,
        module: &module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    });
    // wgpu's native backends report a scope at once; a pending answer counts as refused.
    let mut clean = true;
    for scope in [validation, internal] {
        let mut error = std::pin::pin!(scope.pop());
        let waker = std::task::Waker::noop();
        let answer = error.as_mut().poll(&mut std::task::Context::from_waker(waker));
        clean &= matches!(answer, std::task::Poll::Ready(None));
    }
    clean.then_some(pipeline)
}

/// Records one dispatch of `groups` workgroups (spread over x and y past the per-dimension limit).
fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    bind: &wgpu::BindGroup,
    groups: u64,
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some("nmat"),
        timestamp_writes: None,
    });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bind, &[]);
    if groups > 0 {
        let (gx, gy) = spread(groups);
        pass.dispatch_workgroups(gx, gy, 1);
    }
}

/// `groups` workgroups as a dispatch's x and y (at least 1 each): x up to the per-dimension
/// limit, y rows of it; shaders index workgroup x + y · (x count).
pub(crate) fn spread(groups: u64) -> (u32, u32) {
    let gx = groups.min(u64::from(MAX_GROUPS)) as u32;
    let gy = groups.div_ceil(u64::from(MAX_GROUPS)) as u32;
    (gx.max(1), gy.max(1))
}

/// A uniform buffer holding `bytes` (a dispatch's parameters).
pub(crate) fn uniform_buffer(device: &wgpu::Device, bytes: &[u8]) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("nmat params"),
        contents: bytes,
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

/// Creates a device on the first adapter wgpu finds (any backend, software adapters included),
/// with downlevel limits only. For tools and tests; engines pass their own device.
pub async fn default_device() -> Option<(wgpu::Device, wgpu::Queue, wgpu::AdapterInfo)> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = instance
        .request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        })
        .await
        .ok()?;
    let info = adapter.get_info();
    // Cooperative matrices (the matrix kernel) where the adapter has the configuration it uses.
    let matrices = adapter.features().contains(MATRIX_FEATURES)
        && matrix_usable(&adapter.cooperative_matrix_properties());
    let (device, queue) = adapter
        .request_device(&wgpu::DeviceDescriptor {
            label: Some("nmat"),
            // BC textures (for transcoded blocks), timestamp queries (for measuring), the
            // adapter's own format features (R8Unorm storage textures) and cooperative matrices
            // where the adapter has them, nothing else.
            required_features: adapter.features()
                & (wgpu::Features::TEXTURE_COMPRESSION_BC
                    | measure::TIMESTAMP_FEATURES
                    | wgpu::Features::TEXTURE_ADAPTER_SPECIFIC_FORMAT_FEATURES)
                | if matrices { MATRIX_FEATURES } else { wgpu::Features::empty() },
            // Downlevel limits, but all the workgroup memory the adapter has: the tiled kernel
            // decodes more texels per workgroup with more.
            required_limits: wgpu::Limits {
                max_compute_workgroup_storage_size: adapter
                    .limits()
                    .max_compute_workgroup_storage_size,
                ..wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits())
            },
            experimental_features: if matrices {
                experimental()
            } else {
                wgpu::ExperimentalFeatures::disabled()
            },
            memory_hints: wgpu::MemoryHints::MemoryUsage,
            trace: wgpu::Trace::Off,
        })
        .await
        .ok()?;
    Some((device, queue, info))
}

/// wgpu's consent token for its experimental features, which the matrix kernel's cooperative
/// matrices are.
#[allow(unsafe_code)]
fn experimental() -> wgpu::ExperimentalFeatures {
    // SAFETY: wgpu asks its caller to accept that an experimental feature may have bugs. The
    // only experimental feature enabled is EXPERIMENTAL_COOPERATIVE_MATRIX, used only by the
    // matrix kernel, whose results `Context::upload` compares with the CPU's before using it.
    unsafe { wgpu::ExperimentalFeatures::enabled() }
}

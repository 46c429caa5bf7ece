//! `nmat-wgpu`: batch decoding of `.nmat` materials on any GPU wgpu reaches (Vulkan, Metal,
//! D3D12, OpenGL ES, and WebGPU in a browser through the calls that never block), bit-exact
//! with `nmat_core`'s integer decoder: the same 8-bit codes as every CPU kernel and the C API.
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
//! // A packed file (format 2.2) is unpacked once into the fixed-rate form the GPU reads;
//! // a fixed-rate file is used in place.
//! let bytes = nmat_core::unpack(bytes, Default::default())?;
//! let material = Container::parse(&bytes)?;
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
//! Where nothing may block (WebGPU in a browser, whose blocking calls return
//! [`GpuError::CannotWait`]; an engine's render thread), [`Context::upload_async`] and
//! [`PendingDecode::wait_async`] (also on BC transcodes and the tile cache's counters) return
//! futures, ready once the device has run the work and been polled (by the browser's event
//! loop; natively by the caller's `Device::poll`):
//!
//! ```no_run
//! # async fn web(ctx: &nmat_wgpu::Context, device: &wgpu::Device, queue: &wgpu::Queue,
//! #              material: &nmat_core::Material<'_>) -> Result<Vec<u8>, nmat_wgpu::GpuError> {
//! let gpu = ctx.upload_async(device, queue, material).await?;
//! let all = nmat_core::ChannelMask::ALL;
//! let pending = ctx.submit_region(device, queue, &gpu, 0, (0, 0, 64, 64), all)?;
//! pending.wait_async().await
//! # }
//! ```
//!
//! For throughput keep several decodes in flight: submit regions with
//! [`Context::submit_region`] and [`PendingDecode::wait`] on them later; their buffers and bind
//! groups are reused by later calls. An engine that keeps the codes on the GPU records instead:
//! [`Context::record_region`] and [`Context::record_requests`] (requests read from the caller's
//! buffer, e.g. written by its own pass) add a dispatch to the caller's command encoder that
//! writes the codes, packed four per `u32`, into the caller's buffer; nothing is submitted.
//! Where the device has wgpu's `IMMEDIATES` with room for [`IMMEDIATE_BYTES`]
//! ([`immediates_usable`]; [`default_device`] asks for them), every dispatch takes its
//! parameters as immediates and the bind groups of recent buffer sets are kept, so that a frame
//! loop recording on the same buffers allocates nothing; elsewhere each recorded call makes a
//! small uniform buffer and a bind group.
//! Upload picks, of the [`Kernel`]s the device runs (tiled: 4 rows × 4 texels per invocation
//! over workgroup memory, with `dot4I8Packed` where the device's WGSL has it; unrolled: one
//! texel per invocation, each row's sum written out, the same two products; matrix: tensor
//! cores through wgpu's cooperative matrices, where the device has them), the fastest by
//! measurement among those whose codes on a probe of the material equal the CPU's; all give the
//! same codes ([`Context::kernel_choices`] keeps what it measured for a later run). To decode where a material is drawn, an engine includes the decoder in its
//! own shaders: [`SampleBindings::module`] is a WGSL module with `nmat_sample(uv, lod, rnd, mode,
//! channels)` (the CPU's filters) and `nmat_texel`, bound with [`GpuMaterial::sample_entries`]
//! (example `sample_quad`). Only downlevel limits are needed: 32-bit integers only (no `f16`,
//! no subgroups, no 64-bit integers; the wide products are computed in pieces); the matrix
//! kernel alone needs more ([`MATRIX_FEATURES`]) and is skipped where the device lacks it. The
//! decode arithmetic is that of the format specification (`docs/FORMAT.md` of the repository, §6;
//! embedded in `nmat_core::spec`); how the kernel maps it onto 32-bit integers and what it costs
//! is in `docs/GPU.md`, embedded here as [`design`]. JPEG materials (§11) upload and decode
//! through the same region and request calls, one workgroup per MCU ([`GpuMaterial::codec`]).
//! For engines that sample BC textures, [`Context::create_bc_textures`] makes wgpu BC textures
//! of a material's whole chain on the GPU (BC1/BC4/BC5/BC7, the CPU transcoder's bytes;
//! [`Context::record_bc_textures`] records the same into the caller's textures).
//! A renderer that decodes only what its frames touch keeps a [`GpuTileCache`]
//! ([`Context::create_tile_cache`]): mark, decode the missing tiles and resolve, as passes
//! recorded into its own encoder, for neural and JPEG materials alike.

mod bc_texture;
mod cache;
mod choices;
mod context;
mod decode;
mod device;
mod error;
mod features;
mod gpu;
mod jpeg;
mod layout;
mod matrix;
pub mod measure;
#[cfg(test)]
mod naga_check;
mod sample;
mod submit;
mod texture;
mod tiled;
mod transcode;
mod unrolled;
mod upload;

pub use bc_texture::bc_texture_descriptor;
pub use cache::{CacheLookup, GpuTileCache, MAX_CACHE_MATERIALS};
pub use context::{Context, IMMEDIATE_BYTES, immediates_usable};
pub use decode::TexelRequest;
pub use device::default_device;
pub use error::GpuError;
pub use gpu::{read_buffer, read_buffer_async, refuse_waits_on_this_thread_for_testing};
pub use matrix::{FEATURES as MATRIX_FEATURES, usable as matrix_usable};
pub use sample::SampleBindings;
pub use submit::PendingDecode;
pub use texture::TextureTarget;
pub use tiled::Kernel;
pub use transcode::{
    BlockTarget, PendingBlocks, PendingTextures, aligned_row_pitch, encodes, texture_format,
};
pub use upload::{GpuMaterial, PROBE_TEXELS, PROBE_WAIT};

/// The GPU runtime's design and measured speed (`docs/GPU.md` of the repository).
#[cfg(doc)]
#[doc = include_str!("../../docs/GPU.md")]
#[allow(rustdoc::broken_intra_doc_links)]
pub mod design {}

/// The wgpu this crate is built against (its types are in this crate's API).
pub use wgpu;
pub use wgpu::DeviceType;

//! [`GpuError`]: everything the GPU runtime refuses or fails at, named.

use crate::Kernel;
#[cfg(doc)]
use crate::{Context, MAX_CACHE_MATERIALS};
use nmat_core::BlockRegion;
use nmat_core::bc::BcFormat;

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
    /// A BC format the GPU does not encode (it encodes every `BcFormat` nmat-core has today:
    /// BC1, BC4, BC5 and BC7; a format the core adds later is refused until the GPU has it).
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
    /// mip level, room at the origin), or a BC texture [`Context::record_bc_textures`] cannot fill
    /// (format, usage, size, levels; a material whose mip 0 no BC texture can have; a device
    /// without BC textures; recording on wgpu's GL backend, which copies no padded rows into
    /// them — [`Context::create_bc_textures`] fills them there another way).
    Texture { reason: &'static str },
    /// A JPEG material's section larger than one storage binding of the device (or 2^28 bytes,
    /// so that bit positions fit 32 bits).
    SectionTooLarge { bytes: u64, limit: u64 },
    /// A material's latents (every grid's packed words) or descriptors (the network's weights and
    /// tables, a JPEG material's index and Huffman tables) larger than one storage binding of
    /// the device: decode it on the CPU, or on a device that binds more.
    DataTooLarge { what: &'static str, bytes: u64, limit: u64 },
    /// Requests of a JPEG material whose MCU table and scratch (one word per MCU of a map's
    /// chain, then up to 8 MiB of decoded MCUs) exceed one storage binding of the device: decode
    /// its regions, or its requests on the CPU.
    RequestTablesTooLarge { bytes: u64, limit: u64 },
    /// A tile cache [`Context::create_tile_cache`] cannot make: no material or more than
    /// [`MAX_CACHE_MATERIALS`], no slot, or more tiles than one storage binding holds.
    Cache { reason: &'static str },
    /// A JPEG material (docs/FORMAT.md §11) given to a path that decodes neural materials only
    /// (`nmat_sample`): decode its regions or requests, use the tile cache, or decode it on the
    /// CPU (`nmat_core`).
    Codec,
    /// A kernel's probe at upload ([`Context::upload`]) did not finish within the probe time
    /// limit: the kernel may never finish on this device (a driver or shader compiler fault).
    /// The device's queue may stay busy with it; recreate the device, or upload with another
    /// kernel ([`Context::upload_with`]) on a new one.
    Hung { kernel: Kernel, seconds: u32 },
    /// A call that waits for the device, made on WebGPU in a browser (`wgpu::Backend::
    /// BrowserWebGpu`), where it could never return: there wgpu's polls do not wait, and a
    /// buffer's mapping completes only once control is back in the browser's event loop. The
    /// calls that wait: [`Context::upload`] of a neural material (it reads back each kernel's
    /// probe), `wait` and `is_finished` of work in flight, the `decode_*` and `transcode_*`
    /// calls, the tile cache's `read_stats`, and the timings of [`crate::measure`]. Refused
    /// rather than left blocking; in a browser use the calls that never block:
    /// [`Context::upload_async`], `submit_*` then `wait_async`, `read_stats_async`.
    CannotWait,
    /// Text given to [`Context::remember_kernel_choices`] that is not what
    /// [`Context::kernel_choices`] writes: `line` (from 1) is the first line at fault.
    KernelChoices { line: usize, reason: &'static str },
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
            GpuError::DataTooLarge { what, bytes, limit } => write!(
                f,
                "the material's {what} take {bytes} bytes; this device binds at most {limit} in \
                 one buffer"
            ),
            GpuError::RequestTablesTooLarge { bytes, limit } => write!(
                f,
                "the JPEG material's request tables take {bytes} bytes; this device binds at most \
                 {limit} in one buffer (decode regions, or requests on the CPU)"
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
                write!(f, "{} is not encoded on the GPU (BC1, BC4, BC5 and BC7 are)", format.name())
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
            GpuError::Hung { kernel, seconds } => write!(
                f,
                "the {} kernel's probe did not finish within {seconds} s: it may hang on this \
                 device, whose queue may stay busy (recreate the device)",
                kernel.name()
            ),
            GpuError::CannotWait => write!(
                f,
                "this call waits for the device, which WebGPU in a browser cannot do (upload, \
                 wait, is_finished, decode_*, transcode_*, read_stats and timings block; use \
                 upload_async, submit_* then wait_async, read_stats_async)"
            ),
            GpuError::KernelChoices { line, reason } => {
                write!(f, "kernel choices, line {line}: {reason}")
            }
            GpuError::Kernel { kernel, reason } => {
                write!(f, "the {} kernel does not run on this device: {reason}", kernel.name())
            }
        }
    }
}

impl std::error::Error for GpuError {}

//! Decoding straight into BC blocks on the GPU: a region's texels are decoded once by the
//! material's kernel (the fastest exact one `upload` measured) for every texture asked, then each
//! texture's blocks are encoded from those codes, one invocation per block, as BC1, BC4, BC5 or
//! BC7 blocks byte-identical with the CPU's `Decoder::transcode_blocks`, into a buffer that can
//! be copied into a BC texture. The encoders are `bc.wgsl` and `bc7.wgsl`, ports of
//! `nmat_core::bc`.

use crate::gpu::{
    MAX_GROUPS, check_output, dispatch_bound, finished_within, read_back_after, read_back_async,
};
use crate::layout::Params;
use crate::{Context, GpuError, GpuMaterial};
use nmat_core::bc::{BLOCK_PIXELS, BcFormat, BcTexture};
use nmat_core::{BlockRegion, ChannelMask};
use std::time::Duration;
use wgpu::util::DeviceExt;

/// Blocks per workgroup of `encode_codes` and `encode_pixels` (one invocation each).
const BLOCKS_PER_GROUP: u64 = 64;
/// The most bytes one pass of the transcoding calls decodes or stages, where the device binds
/// that much.
const PASS_BYTES: u64 = 32 << 20;

/// BC blocks submitted to the queue; [`PendingBlocks::wait`] maps them.
pub struct PendingBlocks {
    blocks: wgpu::Buffer,
    readback: wgpu::Buffer,
    len: usize,
    /// The submission that writes them.
    submission: wgpu::SubmissionIndex,
}

impl PendingBlocks {
    /// The GPU-side blocks (rows of blocks without padding), usable as the source of a
    /// `copy_buffer_to_texture` when the row is a multiple of 256 bytes, or by the caller's passes.
    pub fn gpu_buffer(&self) -> &wgpu::Buffer {
        &self.blocks
    }

    /// Whether the device has run the transcoding, waiting at most `wait` for it
    /// (`Duration::ZERO`: asks without blocking); once it says `true`,
    /// [`PendingBlocks::wait`] maps the blocks without waiting for the device
    /// ([`crate::PendingDecode::is_finished`]).
    pub fn is_finished(&self, device: &wgpu::Device, wait: Duration) -> Result<bool, GpuError> {
        finished_within(device, &self.submission, wait)
    }

    /// Maps the blocks (blocking until the device has run their submission, not the work
    /// submitted after it) and returns their bytes.
    pub fn wait(self, device: &wgpu::Device) -> Result<Vec<u8>, GpuError> {
        let size = self.readback.size();
        let mut bytes = read_back_after(device, &self.readback, size, Some(self.submission))?;
        bytes.truncate(self.len);
        Ok(bytes)
    }

    /// [`PendingBlocks::wait`] without blocking, as [`crate::PendingDecode::wait_async`]: ready
    /// with the blocks once the device has run the transcoding and been polled.
    pub async fn wait_async(self) -> Result<Vec<u8>, GpuError> {
        let mut bytes = read_back_async(&self.readback, self.readback.size()).await?;
        bytes.truncate(self.len);
        Ok(bytes)
    }
}

/// The BC blocks of one mip of several textures, submitted to the queue in one submission
/// ([`Context::submit_transcode_textures`]); [`PendingTextures::wait`] maps them. (Blocks to
/// keep on the GPU are recorded into the caller's buffers: [`Context::record_transcode_textures`].)
pub struct PendingTextures {
    blocks: PendingBlocks,
    /// Each texture's byte range in `blocks` (at a word boundary).
    spans: Vec<(u64, u64)>,
}

impl PendingTextures {
    /// Whether the device has run the transcoding, waiting at most `wait` for it
    /// ([`PendingBlocks::is_finished`]).
    pub fn is_finished(&self, device: &wgpu::Device, wait: Duration) -> Result<bool, GpuError> {
        self.blocks.is_finished(device, wait)
    }

    /// Maps the blocks (blocking until the device has run their submission, not the work
    /// submitted after it) and returns each texture's, in the order asked.
    pub fn wait(self, device: &wgpu::Device) -> Result<Vec<Vec<u8>>, GpuError> {
        let bytes = self.blocks.wait(device)?;
        Ok(split_spans(&bytes, &self.spans))
    }

    /// [`PendingTextures::wait`] without blocking ([`PendingBlocks::wait_async`]).
    pub async fn wait_async(self) -> Result<Vec<Vec<u8>>, GpuError> {
        let bytes = self.blocks.wait_async().await?;
        Ok(split_spans(&bytes, &self.spans))
    }
}

/// Each texture's blocks out of one mip's: the bytes of each span (offset, length).
fn split_spans(bytes: &[u8], spans: &[(u64, u64)]) -> Vec<Vec<u8>> {
    spans.iter().map(|&(at, n)| bytes[at as usize..(at + n) as usize].to_vec()).collect()
}

/// The wgpu texture format that samples a [`BcTexture`]'s blocks (BC1 as `Bc1RgbaUnorm`, whose
/// blocks from nmat are opaque; sRGB where the texture asks for it), or `None` for a format wgpu
/// lacks.
pub fn texture_format(texture: &BcTexture) -> Option<wgpu::TextureFormat> {
    use wgpu::TextureFormat as F;
    Some(match (texture.format, texture.srgb) {
        (BcFormat::Bc1, false) => F::Bc1RgbaUnorm,
        (BcFormat::Bc1, true) => F::Bc1RgbaUnormSrgb,
        (BcFormat::Bc4, _) => F::Bc4RUnorm,
        (BcFormat::Bc5, _) => F::Bc5RgUnorm,
        (BcFormat::Bc7Rgb | BcFormat::Bc7Rgba, false) => F::Bc7RgbaUnorm,
        (BcFormat::Bc7Rgb | BcFormat::Bc7Rgba, true) => F::Bc7RgbaUnormSrgb,
        _ => return None,
    })
}

/// The smallest row pitch ≥ `blocks_wide` blocks of `format` that `copy_buffer_to_texture`
/// accepts (a multiple of 256 bytes).
pub fn aligned_row_pitch(format: BcFormat, blocks_wide: u32) -> u64 {
    let row = u64::from(blocks_wide) * format.block_bytes() as u64;
    row.div_ceil(u64::from(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT))
        * u64::from(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
}

/// Whether the GPU encodes `format` (BC1, BC4, BC5 and BC7: every format nmat-core has today).
pub fn encodes(format: BcFormat) -> bool {
    shader_format(format).is_ok()
}

/// How the encoders take `texture` of `gm`: its format's code, the code of each constant
/// component (a constant channel's, or 0 for a component the format does not read), and the
/// material channel each other component reads; `Format` or `Channels` where it cannot.
pub(crate) fn texture_params(
    gm: &GpuMaterial,
    texture: &BcTexture,
) -> Result<(Params, [Option<u8>; 4]), GpuError> {
    let mut params = Params { format: shader_format(texture.format)?, ..Params::default() };
    let mut channels = [None; 4];
    for (k, &c) in texture.channel_list().iter().enumerate() {
        let constant = gm
            .constant_codes
            .get(usize::from(c))
            .ok_or(GpuError::Channels { mask: 1u16.checked_shl(u32::from(c)).unwrap_or(0) })?;
        match constant {
            Some(code) => {
                params.constants |= u32::from(*code) << (8 * k);
                params.constant_mask |= 1 << k;
            }
            None => channels[k] = Some(c),
        }
    }
    // Components the format does not read: constant 0.
    params.constant_mask |= 0b1111 & !((1 << texture.format.components()) - 1);
    Ok((params, channels))
}

/// `format`'s code in the shader (`params.format`), or the error for a format it lacks.
fn shader_format(format: BcFormat) -> Result<u32, GpuError> {
    match format {
        BcFormat::Bc1 => Ok(1),
        BcFormat::Bc4 => Ok(4),
        BcFormat::Bc5 => Ok(5),
        BcFormat::Bc7Rgb => Ok(7),
        BcFormat::Bc7Rgba => Ok(8),
        _ => Err(GpuError::Format { format }),
    }
}

impl GpuMaterial {
    /// Every block of `mip` (a mip of w × h texels has ⌈w/4⌉ × ⌈h/4⌉ blocks), or `None` for a
    /// mip beyond the chain.
    pub fn blocks(&self, mip: u32) -> Option<BlockRegion> {
        let &(w, h) = self.mip_sizes.get(mip as usize)?;
        Some(BlockRegion { x: 0, y: 0, width: w.div_ceil(4), height: h.div_ceil(4) })
    }
}

/// Where a texture's blocks go: a buffer, the byte of the first block, and the row pitch in
/// bytes (see [`Context::record_transcode`]).
pub type BlockTarget<'a> = (&'a wgpu::Buffer, u64, u64);

impl Context {
    /// Records, into the caller's `encoder` (nothing is submitted), the decode of `region` of
    /// `mip` and its encoding as blocks of `texture` (BC1, BC4, BC5 or BC7): block row `r` of the
    /// region starts at byte `offset + r · row_pitch` of `out`, its blocks left to right. The
    /// bytes equal the CPU's `Decoder::transcode_blocks` with the same arguments. `out` needs
    /// `STORAGE` usage (and `COPY_SRC` to be copied into a texture: then `row_pitch` must be a
    /// multiple of 256, see [`aligned_row_pitch`]); `offset` and `row_pitch` are multiples of 4.
    /// Everything is checked before anything is recorded. Several textures of one material:
    /// [`Context::record_transcode_textures`] decodes their texels once.
    #[allow(clippy::too_many_arguments)] // a material, what, where, and the output with its layout
    pub fn record_transcode(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        gm: &GpuMaterial,
        texture: &BcTexture,
        mip: u32,
        region: BlockRegion,
        out: BlockTarget<'_>,
    ) -> Result<(), GpuError> {
        self.record_transcode_textures(device, encoder, gm, mip, region, &[(texture, out)])
    }

    /// Records the blocks of `region` of `mip` of every texture of `targets` (each as
    /// [`Context::record_transcode`] writes one) with one decode of the region: its texels
    /// are decoded once by the material's kernel (the channels any texture takes; constant
    /// channels are not decoded, as on the CPU) into a buffer the `Context`
    /// keeps for such passes, then each texture's blocks are encoded from those codes, one
    /// invocation per block. Everything is checked before anything is recorded.
    pub fn record_transcode_textures(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        gm: &GpuMaterial,
        mip: u32,
        region: BlockRegion,
        targets: &[(&BcTexture, BlockTarget<'_>)],
    ) -> Result<(), GpuError> {
        let all = gm.blocks(mip).ok_or(GpuError::Blocks { mip, region })?;
        if u64::from(region.x) + u64::from(region.width) > u64::from(all.width)
            || u64::from(region.y) + u64::from(region.height) > u64::from(all.height)
        {
            return Err(GpuError::Blocks { mip, region });
        }
        let count = u64::from(region.width) * u64::from(region.height);
        let groups = count.div_ceil(BLOCKS_PER_GROUP);
        let too_large = |limit: u64| GpuError::TooLarge { texels: count * 16, limit };
        if groups > u64::from(MAX_GROUPS) * u64::from(MAX_GROUPS) {
            return Err(too_large(u64::from(MAX_GROUPS).pow(2) * BLOCKS_PER_GROUP * 16));
        }
        let fit = |n: u64| u32::try_from(n).map_err(|_| too_large(u64::from(u32::MAX)));
        // The texels of the region inside the mip, decoded once for every texture.
        let (mw, mh) = gm.mip_sizes[mip as usize];
        let x = 4 * region.x;
        let y = 4 * region.y;
        let width = (4 * u64::from(region.width)).min(u64::from(mw.saturating_sub(x))) as u32;
        let height = (4 * u64::from(region.height)).min(u64::from(mh.saturating_sub(y))) as u32;
        let mut decoded = 0u16;
        let mut encodes = Vec::new();
        for &(texture, (out, offset, row_pitch)) in targets {
            let (mut params, channels) = texture_params(gm, texture)?;
            params.mip = mip;
            for &c in channels.iter().flatten() {
                decoded |= 1 << c;
            }
            let block_bytes = texture.format.block_bytes() as u64;
            let row_bytes = u64::from(region.width) * block_bytes;
            if row_pitch < row_bytes || !row_pitch.is_multiple_of(4) {
                return Err(GpuError::RowPitch { row_pitch, min: row_bytes.next_multiple_of(4) });
            }
            let span = match region.height {
                0 => 0,
                h => u64::from(h - 1) * row_pitch + row_bytes,
            };
            params.out_offset = check_output(device, out, offset, span)?;
            params.count = fit(count)?;
            params.width = region.width.max(1);
            params.row_words = fit(row_pitch / 4)?;
            params.x0 = width;
            params.y0 = height;
            encodes.push((params, channels, out, texture.format));
        }
        // Where each decoded channel lies among a texel's codes.
        for (params, channels, _, _) in &mut encodes {
            params.out_channels = decoded.count_ones();
            for (k, c) in channels.iter().enumerate() {
                if let Some(c) = c {
                    let slot = (decoded & ((1u16 << c) - 1)).count_ones();
                    params.components |= slot << (8 * k);
                }
            }
        }
        if count == 0 || targets.is_empty() {
            return Ok(());
        }
        // In bands of block rows whose codes fit one pass (a 4096² mip of nine channels is
        // 151 MB of codes, more than a downlevel device binds at once).
        let channels = u64::from(decoded.count_ones());
        let band_rows = self.band_rows(device, u64::from(width) * 4 * channels, region.height);
        for first in (0..region.height).step_by(band_rows as usize) {
            let rows = band_rows.min(region.height - first);
            let band_y = y + 4 * first;
            let band_height = (4 * rows).min(mh.saturating_sub(band_y));
            let codes = if decoded == 0 {
                None
            } else {
                let bytes = u64::from(width) * u64::from(band_height) * channels;
                let codes = self.texture_codes(device, bytes.next_multiple_of(4).max(4));
                let rect = (x, band_y, width, band_height);
                let mask = ChannelMask(decoded);
                self.record_region(device, encoder, gm, mip, rect, mask, (&codes, 0))?;
                Some(codes)
            };
            for (params, _, out, format) in &encodes {
                let params = Params {
                    count: region.width * rows,
                    out_offset: params.out_offset + first * params.row_words,
                    y0: band_height,
                    ..*params
                };
                let pipeline = self.encoder_pipeline(device, *format, true);
                let bind = self.bind(device, None, codes.as_ref(), out, &params);
                let groups = u64::from(params.count).div_ceil(BLOCKS_PER_GROUP);
                dispatch_bound(encoder, &pipeline, &bind, groups);
            }
        }
        Ok(())
    }

    /// The most bytes one pass of the transcoding calls decodes (the codes of a band of block
    /// rows) or stages (the blocks of a band of every texture): 32 MiB, or less where the device
    /// binds less or a test asked for less.
    pub(crate) fn pass_bytes(&self, device: &wgpu::Device) -> u64 {
        let limit = device.limits().max_storage_buffer_binding_size.min(PASS_BYTES);
        let asked = *self.pass_bytes.lock().unwrap_or_else(|e| e.into_inner());
        asked.map_or(limit, |asked| asked.min(limit))
    }

    /// How many of `rows` rows of `row_bytes` bytes one pass takes: as many as
    /// [`Context::pass_bytes`] holds, at least one.
    pub(crate) fn band_rows(&self, device: &wgpu::Device, row_bytes: u64, rows: u32) -> u32 {
        (self.pass_bytes(device) / row_bytes.max(1)).clamp(1, u64::from(rows.max(1))) as u32
    }

    /// Makes every later pass of the transcoding calls decode and stage at most `bytes` (at
    /// least one block row), so that a test sees a mip done in several bands. For tests only.
    #[doc(hidden)]
    pub fn limit_pass_bytes_for_testing(&self, bytes: u64) {
        *self.pass_bytes.lock().unwrap_or_else(|e| e.into_inner()) = Some(bytes);
    }

    /// Decodes `region` of `mip` into BC blocks of `texture` on the GPU and submits the work:
    /// the blocks come back row by row without padding (`region.width` blocks per row) from
    /// [`PendingBlocks::wait`].
    #[allow(clippy::too_many_arguments)] // one dispatch's worth of state
    pub fn submit_transcode(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        texture: &BcTexture,
        mip: u32,
        region: BlockRegion,
    ) -> Result<PendingBlocks, GpuError> {
        let row_bytes = u64::from(region.width) * texture.format.block_bytes() as u64;
        let len = row_bytes * u64::from(region.height);
        let (blocks, readback) = output_buffers(device, len)?;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("nmat transcode"),
        });
        self.record_transcode(
            device,
            &mut encoder,
            gm,
            texture,
            mip,
            region,
            (&blocks, 0, row_bytes),
        )?;
        encoder.copy_buffer_to_buffer(&blocks, 0, &readback, 0, readback.size());
        let submission = queue.submit([encoder.finish()]);
        Ok(PendingBlocks { blocks, readback, len: len as usize, submission })
    }

    /// Blocking convenience: every block of `mip` as `texture`, row by row without padding —
    /// the same bytes as the CPU's `Decoder::transcode_blocks` over `BlockRegion::mip`.
    pub fn transcode_mip(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        texture: &BcTexture,
        mip: u32,
    ) -> Result<Vec<u8>, GpuError> {
        let mut blocks = self.transcode_textures_mip(device, queue, gm, &[*texture], mip)?;
        Ok(blocks.pop().unwrap_or_default())
    }

    /// Blocking convenience: every block of `mip` of each of `textures`, as
    /// [`Context::transcode_mip`] gives one, from one decode of the mip and one submission
    /// ([`Context::submit_transcode_textures`], then its `wait`).
    pub fn transcode_textures_mip(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        textures: &[BcTexture],
        mip: u32,
    ) -> Result<Vec<Vec<u8>>, GpuError> {
        self.submit_transcode_textures(device, queue, gm, textures, mip)?.wait(device)
    }

    /// Decodes `mip` once and encodes every block of it as each of `textures` (as
    /// [`Context::record_transcode_textures`] over the whole mip), and submits the work: one
    /// submission, waited for by [`PendingTextures::wait`] only. `nmat transcode --gpu` submits
    /// a whole chain mip after mip and then waits for each in order, so that the GPU can run
    /// each mip's passes right after the previous ones' (a wait between them leaves it idle
    /// for a round trip).
    pub fn submit_transcode_textures(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        textures: &[BcTexture],
        mip: u32,
    ) -> Result<PendingTextures, GpuError> {
        let region = gm.blocks(mip).ok_or(GpuError::Blocks {
            mip,
            region: BlockRegion { x: 0, y: 0, width: 0, height: 0 },
        })?;
        self.submit_transcode_band(device, queue, gm, textures, mip, region)
    }

    /// [`Context::submit_transcode_textures`] for the blocks of `region` (of `mip`) only, each
    /// texture's rows of the region without padding.
    pub(crate) fn submit_transcode_band(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        textures: &[BcTexture],
        mip: u32,
        region: BlockRegion,
    ) -> Result<PendingTextures, GpuError> {
        // Each texture's blocks at a word boundary of one buffer.
        let mut spans = Vec::new();
        let mut len = 0u64;
        for t in textures {
            let row_bytes = u64::from(region.width) * t.format.block_bytes() as u64;
            let bytes = row_bytes * u64::from(region.height);
            spans.push((len, row_bytes, bytes));
            len = (len + bytes).next_multiple_of(4);
        }
        let (blocks, readback) = output_buffers(device, len)?;
        let targets: Vec<(&BcTexture, BlockTarget<'_>)> = textures
            .iter()
            .zip(&spans)
            .map(|(t, &(offset, row_bytes, _))| (t, (&blocks, offset, row_bytes.max(4))))
            .collect();
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("nmat transcode"),
        });
        self.record_transcode_textures(device, &mut encoder, gm, mip, region, &targets)?;
        encoder.copy_buffer_to_buffer(&blocks, 0, &readback, 0, readback.size());
        let submission = queue.submit([encoder.finish()]);
        let blocks = PendingBlocks { blocks, readback, len: len as usize, submission };
        Ok(PendingTextures { blocks, spans: spans.iter().map(|&(at, _, n)| (at, n)).collect() })
    }

    /// Encodes blocks of RGBA pixels given by the caller (each with its `valid` mask, as
    /// `nmat_core::bc::encode_block` takes them) as `format` on the GPU: the same bytes as that
    /// function, block after block. For textures that are not materials, and for testing the
    /// GPU encoders on any pixels.
    pub fn encode_blocks(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        format: BcFormat,
        blocks: &[([[u8; 4]; BLOCK_PIXELS], u16)],
    ) -> Result<Vec<u8>, GpuError> {
        if blocks.is_empty() {
            shader_format(format)?;
            return Ok(Vec::new());
        }
        self.submit_encode_blocks(device, queue, format, blocks)?.wait(device)
    }

    /// [`Context::encode_blocks`] submitted, not waited for: [`PendingBlocks::wait`] (or
    /// `wait_async`, which never blocks) returns the blocks.
    pub fn submit_encode_blocks(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        format: BcFormat,
        blocks: &[([[u8; 4]; BLOCK_PIXELS], u16)],
    ) -> Result<PendingBlocks, GpuError> {
        let params_format = shader_format(format)?;
        let count = blocks.len() as u64;
        let too_large = GpuError::TooLarge {
            texels: count * 16,
            limit: u64::from(MAX_GROUPS).pow(2) * BLOCKS_PER_GROUP * 16,
        };
        let groups = count.div_ceil(BLOCKS_PER_GROUP);
        let input_bytes = count * 17 * 4;
        let max_binding = device.limits().max_storage_buffer_binding_size;
        if groups > u64::from(MAX_GROUPS).pow(2) || input_bytes > max_binding {
            return Err(too_large);
        }
        let mut words: Vec<u8> = blocks
            .iter()
            .flat_map(|(pixels, valid)| {
                let pixel_words = pixels.iter().map(|p| u32::from_le_bytes(*p));
                pixel_words.chain([u32::from(*valid)]).flat_map(u32::to_le_bytes)
            })
            .collect();
        // No block: nothing is dispatched, but a binding cannot be empty.
        words.resize(words.len().max(17 * 4), 0);
        let input = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("nmat pixels"),
            contents: &words,
            usage: wgpu::BufferUsages::STORAGE,
        });
        let block_bytes = format.block_bytes() as u64;
        let (out, readback) = output_buffers(device, count * block_bytes)?;
        let params = Params {
            count: u32::try_from(count).map_err(|_| too_large)?,
            width: 1,
            format: params_format,
            row_words: (block_bytes / 4) as u32,
            ..Params::default()
        };
        let bind = self.bind(device, None, Some(&input), &out, &params);
        let mut encoder = device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("nmat encode") });
        let pipeline = self.encoder_pipeline(device, format, false);
        dispatch_bound(&mut encoder, &pipeline, &bind, groups);
        encoder.copy_buffer_to_buffer(&out, 0, &readback, 0, readback.size());
        let submission = queue.submit([encoder.finish()]);
        let len = (count * block_bytes) as usize;
        Ok(PendingBlocks { blocks: out, readback, len, submission })
    }
}

/// A storage buffer for `len` bytes of blocks and its readback twin (at least 4 bytes each).
fn output_buffers(
    device: &wgpu::Device,
    len: u64,
) -> Result<(wgpu::Buffer, wgpu::Buffer), GpuError> {
    let max_binding = device.limits().max_storage_buffer_binding_size;
    if len > max_binding {
        return Err(GpuError::TooLarge { texels: len / 8 * 16, limit: max_binding / 8 * 16 });
    }
    let size = len.next_multiple_of(4).max(4);
    let buffer = |label, usage| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        })
    };
    Ok((
        buffer("nmat blocks", wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC),
        buffer("nmat blocks readback", wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST),
    ))
}

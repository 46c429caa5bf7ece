//! Whole BC textures on the GPU: every mip of a material transcoded straight into the levels of
//! wgpu BC textures, nothing read back — what an engine samples with its own shaders and
//! hardware filtering. The blocks are `transcode.rs`'s (the CPU's bytes), staged in bands of
//! block rows and copied into each level.

use crate::gpu::kept_buffer;
use crate::transcode::{BlockTarget, aligned_row_pitch, texture_format, texture_params};
use crate::{Context, GpuError, GpuMaterial};
use nmat_core::BlockRegion;
use nmat_core::bc::BcTexture;

/// The usages of the textures [`Context::create_bc_textures`] makes.
const USAGE: wgpu::TextureUsages = wgpu::TextureUsages::TEXTURE_BINDING
    .union(wgpu::TextureUsages::COPY_DST)
    .union(wgpu::TextureUsages::COPY_SRC);

/// The descriptor of a texture that holds the whole chain of `texture` of `gm` as
/// [`Context::record_bc_textures`] writes it: mip 0's size, one level per mip of the material, the
/// format [`texture_format`] names, and `usage` (which needs `COPY_DST`). A material whose mip 0
/// is not a multiple of 4 texels wide and high has no such texture — wgpu makes no BC texture of
/// that size, and one padded to a multiple of 4 would have other mip sizes than the material —
/// and gets `GpuError::Texture`: transcode its mips into buffers
/// ([`Context::record_transcode_textures`]) and lay them out as the engine needs.
pub fn bc_texture_descriptor(
    gm: &GpuMaterial,
    texture: &BcTexture,
    usage: wgpu::TextureUsages,
) -> Result<wgpu::TextureDescriptor<'static>, GpuError> {
    let format = texture_format(texture).ok_or(GpuError::Format { format: texture.format })?;
    let (width, height) = gm.mip_sizes[0];
    if !width.is_multiple_of(4) || !height.is_multiple_of(4) {
        return Err(GpuError::Texture {
            reason: "the material's mip 0 is not a multiple of 4 texels wide and high, which a BC \
                     texture's must be",
        });
    }
    let size = wgpu::Extent3d { width, height, depth_or_array_layers: 1 };
    Ok(wgpu::TextureDescriptor {
        label: Some("nmat BC texture"),
        size,
        mip_level_count: (gm.mip_sizes.len() as u32).min(size.max_mips(wgpu::TextureDimension::D2)),
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

impl Context {
    /// Records, into the caller's `encoder` (nothing is submitted), every level of each target:
    /// level `l` of a target gets mip `l` of its [`BcTexture`], the bytes of the CPU's
    /// `Decoder::transcode_blocks` for that mip. A target is a 2D texture (array layer 0 is
    /// written) of mip 0's size, the format [`texture_format`] names, `COPY_DST` usage and at
    /// most as many levels as the material has mips — what [`bc_texture_descriptor`] describes.
    /// Each mip is decoded once for all the targets that have its level; the blocks go through
    /// a buffer the `Context` keeps (at most 32 MiB: a larger mip goes in bands of block rows)
    /// and are copied into the levels. Everything is checked before anything is recorded
    /// (`GpuError::Texture` for a target, `Channels` and `Format` for a `BcTexture`).
    pub fn record_bc_textures(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        gm: &GpuMaterial,
        targets: &[(&BcTexture, &wgpu::Texture)],
    ) -> Result<(), GpuError> {
        if device.adapter_info().backend == wgpu::Backend::Gl {
            return Err(GpuError::Texture { reason: GL_COMPRESSED_COPIES });
        }
        for &(texture, target) in targets {
            check_target(gm, texture, target)?;
            texture_params(gm, texture)?;
        }
        let levels = targets.iter().map(|(_, t)| t.mip_level_count()).max().unwrap_or(0);
        for mip in 0..levels {
            let these: Vec<_> = targets.iter().filter(|(_, t)| t.mip_level_count() > mip).collect();
            let Some(all) = gm.blocks(mip) else { break };
            // Each target's rows at a pitch a copy takes; a band of rows of every target in
            // the staging buffer, target after target.
            let pitches: Vec<u64> =
                these.iter().map(|(bc, _)| aligned_row_pitch(bc.format, all.width)).collect();
            let row_bytes: u64 = pitches.iter().sum();
            let band_rows = self.band_rows(device, row_bytes, all.height);
            let staging = kept_buffer(
                &self.bc_staging,
                device,
                row_bytes * u64::from(band_rows),
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                "nmat BC staging",
            );
            for first in (0..all.height).step_by(band_rows as usize) {
                let rows = band_rows.min(all.height - first);
                let band = BlockRegion { y: first, height: rows, ..all };
                let mut offsets = Vec::with_capacity(these.len());
                let mut at = 0;
                for pitch in &pitches {
                    offsets.push(at);
                    at += pitch * u64::from(rows);
                }
                let blocks: Vec<(&BcTexture, BlockTarget<'_>)> = these
                    .iter()
                    .zip(offsets.iter().zip(&pitches))
                    .map(|((bc, _), (&offset, &pitch))| (*bc, (&staging, offset, pitch)))
                    .collect();
                self.record_transcode_textures(device, encoder, gm, mip, band, &blocks)?;
                for (((_, target), &offset), &pitch) in these.iter().zip(&offsets).zip(&pitches) {
                    let layout = wgpu::TexelCopyBufferLayout {
                        offset,
                        bytes_per_row: Some(pitch as u32),
                        rows_per_image: Some(rows),
                    };
                    encoder.copy_buffer_to_texture(
                        wgpu::TexelCopyBufferInfo { buffer: &staging, layout },
                        wgpu::TexelCopyTextureInfo {
                            texture: target,
                            mip_level: mip,
                            origin: wgpu::Origin3d { x: 0, y: 4 * first, z: 0 },
                            aspect: wgpu::TextureAspect::All,
                        },
                        wgpu::Extent3d {
                            width: 4 * all.width,
                            height: 4 * rows,
                            depth_or_array_layers: 1,
                        },
                    );
                }
            }
        }
        Ok(())
    }

    /// Creates a texture per entry of `textures` ([`bc_texture_descriptor`] with
    /// `TEXTURE_BINDING | COPY_DST | COPY_SRC`), records their whole chains
    /// ([`Context::record_bc_textures`]) and submits that work; the textures are ready for any
    /// work submitted after this call (nothing is waited for). The device needs
    /// `Features::TEXTURE_COMPRESSION_BC` (`GpuError::Texture` without it).
    ///
    /// On wgpu's GL backend, which copies no buffer into a compressed texture right (the reason
    /// `record_bc_textures` refuses it), the blocks of every mip are transcoded on the GPU as
    /// [`Context::submit_transcode_textures`] does, read back, and written into the levels
    /// with `Queue::write_texture`: the same textures, but this call waits for the GPU there.
    pub fn create_bc_textures(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        textures: &[BcTexture],
    ) -> Result<Vec<wgpu::Texture>, GpuError> {
        if !device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC) {
            return Err(GpuError::Texture {
                reason: "the device was created without Features::TEXTURE_COMPRESSION_BC",
            });
        }
        let descriptors = textures
            .iter()
            .map(|t| bc_texture_descriptor(gm, t, USAGE))
            .collect::<Result<Vec<_>, _>>()?;
        for texture in textures {
            texture_params(gm, texture)?;
        }
        let made: Vec<wgpu::Texture> =
            descriptors.iter().map(|d| device.create_texture(d)).collect();
        if device.adapter_info().backend == wgpu::Backend::Gl {
            self.write_bc_levels(device, queue, gm, textures, &made)?;
            return Ok(made);
        }
        let targets: Vec<(&BcTexture, &wgpu::Texture)> = textures.iter().zip(&made).collect();
        let mut encoder = device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("nmat BC") });
        self.record_bc_textures(device, &mut encoder, gm, &targets)?;
        queue.submit([encoder.finish()]);
        Ok(made)
    }

    /// Fills every level of `made` (textures of `textures`, as [`Context::create_bc_textures`]
    /// makes them) with the blocks of [`Context::submit_transcode_textures`] through
    /// `Queue::write_texture`, whose rows are not padded: the way wgpu's GL backend fills a
    /// compressed texture. A mip goes in bands of block rows as in `record_bc_textures`, every
    /// band of a mip submitted before the first is waited for.
    fn write_bc_levels(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        gm: &GpuMaterial,
        textures: &[BcTexture],
        made: &[wgpu::Texture],
    ) -> Result<(), GpuError> {
        let levels = made.first().map_or(0, wgpu::Texture::mip_level_count);
        for mip in 0..levels {
            let Some(all) = gm.blocks(mip) else { break };
            let row_bytes: u64 =
                textures.iter().map(|t| u64::from(all.width) * t.format.block_bytes() as u64).sum();
            let band_rows = self.band_rows(device, row_bytes, all.height);
            let bands = (0..all.height)
                .step_by(band_rows as usize)
                .map(|first| {
                    let band =
                        BlockRegion { y: first, height: band_rows.min(all.height - first), ..all };
                    Ok((band, self.submit_transcode_band(device, queue, gm, textures, mip, band)?))
                })
                .collect::<Result<Vec<_>, GpuError>>()?;
            for (band, pending) in bands {
                for ((texture, target), bytes) in
                    textures.iter().zip(made).zip(pending.wait(device)?)
                {
                    let layout = wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(band.width * texture.format.block_bytes() as u32),
                        rows_per_image: Some(band.height),
                    };
                    let extent = wgpu::Extent3d {
                        width: 4 * band.width,
                        height: 4 * band.height,
                        depth_or_array_layers: 1,
                    };
                    let at = wgpu::TexelCopyTextureInfo {
                        texture: target,
                        mip_level: mip,
                        origin: wgpu::Origin3d { x: 0, y: 4 * band.y, z: 0 },
                        aspect: wgpu::TextureAspect::All,
                    };
                    queue.write_texture(at, &bytes, layout, extent);
                }
            }
        }
        Ok(())
    }
}

/// Why [`Context::record_bc_textures`] refuses wgpu's GL backend: it copies a buffer into a
/// compressed texture with `glCompressedTexSubImage2D`, which in OpenGL ES takes tightly packed
/// rows only (no row length for compressed data), while a copy's rows are padded to 256 bytes
/// (wgpu 30 on Mesa's llvmpipe: the level stays empty). `Queue::write_texture` of the blocks
/// of `Context::submit_transcode_textures`, with unpadded rows, fills such a texture there (as
/// [`Context::create_bc_textures`] does on that backend).
const GL_COMPRESSED_COPIES: &str = "wgpu's GL backend copies no padded rows into a compressed \
     texture; use create_bc_textures, or write the blocks of submit_transcode_textures with \
     Queue::write_texture";

/// Checks that `target` can take the whole chain of `texture` of `gm` as
/// [`Context::record_bc_textures`] writes it.
fn check_target(
    gm: &GpuMaterial,
    texture: &BcTexture,
    target: &wgpu::Texture,
) -> Result<(), GpuError> {
    let (width, height) = gm.mip_sizes[0];
    let reason = if target.dimension() != wgpu::TextureDimension::D2 {
        Some("it is not a 2D texture")
    } else if Some(target.format()) != texture_format(texture) {
        Some("its format is not the one nmat_wgpu::texture_format names for the BC texture")
    } else if !target.usage().contains(wgpu::TextureUsages::COPY_DST) {
        Some("it needs COPY_DST usage")
    } else if target.sample_count() != 1 {
        Some("it is multisampled")
    } else if (target.width(), target.height()) != (width, height) {
        Some("its size is not the material's mip 0")
    } else if target.mip_level_count() as usize > gm.mip_sizes.len() {
        Some("it has more mip levels than the material has mips")
    } else {
        None
    };
    reason.map_or(Ok(()), |reason| Err(GpuError::Texture { reason }))
}

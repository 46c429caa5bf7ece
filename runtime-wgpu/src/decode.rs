//! Decoding regions and requests with the material's kernel: submitted (the codes come back
//! through a [`PendingDecode`]) or recorded into the caller's encoder (the codes stay on the GPU).

use crate::gpu::{MAX_GROUPS, check_output, check_requests, dispatch_bound};
use crate::layout::Params;
use crate::upload::{GpuBody, NetworkPipeline};
use crate::{Context, GpuError, GpuMaterial, PendingDecode};
use nmat_core::ChannelMask;

/// One texel to decode: coordinates wrap or clamp by the material's address mode; a mip beyond
/// the chain is clamped to the last (as `Material::decode_texel_u8`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TexelRequest {
    pub x: i32,
    pub y: i32,
    pub mip: u32,
}

impl Context {
    /// The workgroups of a decode of `params.count` texels, checked against the dispatch and
    /// binding limits (the codes take `count · out_channels` bytes).
    pub(crate) fn decode_groups(
        &self,
        device: &wgpu::Device,
        tiled: &NetworkPipeline,
        params: &Params,
    ) -> Result<u64, GpuError> {
        let texels = u64::from(self.decode_pipeline(tiled).1);
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
    pub(crate) fn region_params(
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
        params.out_offset = check_output(device, out, offset, len)?;
        match &gm.body {
            GpuBody::Jpeg(maps) => {
                self.record_jpeg(device, encoder, (gm, maps), params, None, out)?
            }
            GpuBody::Neural(tiled) => {
                let groups = self.decode_groups(device, tiled, &params)?;
                let bind = self.bind(device, Some(gm), None, out, &params).with_weights_of(gm);
                dispatch_bound(encoder, self.decode_pipeline(tiled).0, &bind, groups);
            }
        }
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
        let bytes = 12 * u64::from(count);
        let len = u64::from(count) * u64::from(n);
        params.in_offset = check_requests(device, requests, requests_offset, bytes)?;
        params.out_offset = check_output(device, out, offset, len)?;
        match &gm.body {
            GpuBody::Neural(tiled) => {
                let groups = self.decode_groups(device, tiled, &params)?;
                let bind =
                    self.bind(device, Some(gm), Some(requests), out, &params).with_weights_of(gm);
                dispatch_bound(encoder, self.decode_pipeline(tiled).0, &bind, groups);
            }
            GpuBody::Jpeg(maps) => {
                let requests = Some(requests);
                self.record_jpeg(device, encoder, (gm, maps), params, requests, out)?;
            }
        }
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

//! Decoding into the caller's textures: a map's channels (the material's maps, as
//! `nmat_core::bc::maps` groups them) into an `Rgba8Unorm` or `R8Unorm` storage texture, recorded
//! into the caller's command encoder. Two passes: the material's decode kernel writes the codes
//! into a buffer, `store.wgsl` writes them into the texture.

use crate::gpu::{kept_buffer, try_pipeline};
use crate::layout::words_to_bytes;
use crate::{Context, GpuError, GpuMaterial};
use nmat_core::ChannelMask;
use nmat_core::bc::MapChannels;
use std::sync::Arc;
use wgpu::util::DeviceExt;

/// Where [`Context::record_map_to_texture`] writes: a 2D texture (array layer 0) with
/// `STORAGE_BINDING` usage in `Rgba8Unorm` (a map of 1–4 channels; missing components are
/// written as 0, alpha as 1) or `R8Unorm` (a map of one channel; as a storage texture it needs
/// the device's adapter-specific format features on most backends), the mip level, and the texel
/// where the region's top-left corner goes.
#[derive(Clone, Copy, Debug)]
pub struct TextureTarget<'a> {
    pub texture: &'a wgpu::Texture,
    pub mip_level: u32,
    pub origin: (u32, u32),
}

/// The formats [`TextureTarget`] takes.
const FORMATS: [(wgpu::TextureFormat, &str); 2] =
    [(wgpu::TextureFormat::Rgba8Unorm, "rgba8unorm"), (wgpu::TextureFormat::R8Unorm, "r8unorm")];

impl Context {
    /// Records, into the caller's `encoder` (nothing is submitted), the decode of the rectangle
    /// (x0, y0, width, height) of `mip` for the channels of `map` into `target`: texel (x0 + i,
    /// y0 + j) lands on `target.origin` + (i, j), component c holding channel `map.first + c` as
    /// unorm8 (the code / 255, exactly the CPU's code). Everything is checked before anything is
    /// recorded (`GpuError::Channels` for a map outside the material, `GpuError::Texture` for
    /// the target). The codes pass through a buffer the `Context` keeps for all such calls (grown
    /// when a call needs more; a region whose codes exceed 32 MiB, or what the device binds, goes
    /// in bands of rows, a decode and a store pass each). With immediates
    /// ([`Context::uses_immediates`]) a call into a texture and level a recent call wrote
    /// allocates nothing; else each call (each band) creates a small uniform, a view and bind
    /// groups.
    #[allow(clippy::too_many_arguments)] // a material, what, and where the texels go
    pub fn record_map_to_texture(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        gm: &GpuMaterial,
        mip: u32,
        rect: (u32, u32, u32, u32),
        map: &MapChannels,
        target: TextureTarget<'_>,
    ) -> Result<(), GpuError> {
        let (first, count) = (u32::from(map.first), u32::from(map.count));
        let mask = ChannelMask((((1u64 << count.min(16)) - 1) << first.min(16)) as u16);
        if !(1..=4).contains(&count) || (first + count) as usize > gm.channel_count() {
            return Err(GpuError::Channels { mask: mask.0 });
        }
        let texture = target.texture;
        let format = texture.format();
        let (width, height) = (rect.2, rect.3);
        let size = |s: u32| s.checked_shr(target.mip_level).unwrap_or(0);
        let level = (size(texture.width()), size(texture.height()));
        let reason = if texture.dimension() != wgpu::TextureDimension::D2 {
            Some("it is not a 2D texture")
        } else if !texture.usage().contains(wgpu::TextureUsages::STORAGE_BINDING) {
            Some("it needs STORAGE_BINDING usage")
        } else if !FORMATS.iter().any(|(f, _)| *f == format) {
            Some("its format is neither Rgba8Unorm nor R8Unorm")
        } else if format == wgpu::TextureFormat::R8Unorm && count != 1 {
            Some("an R8Unorm texture takes a map of one channel")
        } else if target.mip_level >= texture.mip_level_count() {
            Some("its mip level is beyond the texture's")
        } else if u64::from(target.origin.0) + u64::from(width) > u64::from(level.0.max(1))
            || u64::from(target.origin.1) + u64::from(height) > u64::from(level.1.max(1))
        {
            Some("the region does not fit its mip level at the origin")
        } else {
            None
        };
        if let Some(reason) = reason {
            return Err(GpuError::Texture { reason });
        }
        let store = self.store_pipeline(device, format).ok_or(GpuError::Texture {
            reason: "the device refused a storage texture of its format",
        })?;
        // The whole region checked (inside the mip) before anything is recorded, then decoded
        // and stored in bands of rows whose codes fit one pass.
        self.region_params(gm, mip, rect, mask)?;
        let row_codes = u64::from(width) * u64::from(count);
        let band_rows = self.band_rows(device, row_codes, height);
        let codes = row_codes * u64::from(band_rows.min(height));
        let buffer = self.texture_codes(device, codes.next_multiple_of(4).max(4));
        for first in (0..height).step_by(band_rows as usize) {
            let rows = band_rows.min(height - first);
            let band = (rect.0, rect.1 + first, width, rows);
            self.record_region(device, encoder, gm, mip, band, mask, (&buffer, 0))?;
            let words = [target.origin.0, target.origin.1 + first, width, rows, count, 0, 0, 0];
            let bytes = words_to_bytes(&words);
            let bind = self.store_bind(device, &store, &buffer, target, &bytes);
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("nmat store"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&store);
            pass.set_bind_group(0, &bind, &[]);
            if self.immediates {
                pass.set_immediates(0, &bytes);
            }
            if width > 0 {
                pass.dispatch_workgroups(width.div_ceil(8), rows.div_ceil(8), 1);
            }
        }
        Ok(())
    }

    /// The store pass's bind group for `target`'s mip level and the codes in `buffer`: with
    /// immediates (the parameters `bytes` set at the dispatch) one kept for the same texture,
    /// level and buffer where a recent call made it; else a view, a uniform holding `bytes`
    /// and a bind group made for this call.
    fn store_bind(
        &self,
        device: &wgpu::Device,
        store: &wgpu::ComputePipeline,
        buffer: &wgpu::Buffer,
        target: TextureTarget<'_>,
        bytes: &[u8],
    ) -> wgpu::BindGroup {
        let make = || {
            let view = target.texture.create_view(&wgpu::TextureViewDescriptor {
                label: Some("nmat target"),
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_mip_level: target.mip_level,
                mip_level_count: Some(1),
                base_array_layer: 0,
                array_layer_count: Some(1),
                ..Default::default()
            });
            let uniform = (!self.immediates).then(|| {
                device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("nmat store"),
                    contents: bytes,
                    usage: wgpu::BufferUsages::UNIFORM,
                })
            });
            let mut entries = vec![
                wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
            ];
            if let Some(uniform) = &uniform {
                let resource = uniform.as_entire_binding();
                entries.push(wgpu::BindGroupEntry { binding: 1, resource });
            }
            self.binds_made.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("nmat store"),
                layout: &store.get_bind_group_layout(0),
                entries: &entries,
            })
        };
        if !self.immediates {
            return make();
        }
        let key = (target.texture.clone(), target.mip_level, buffer.clone());
        self.store_binds.get_or_make(key, |_| make())
    }

    /// The buffer between a decode and the passes that read its codes (the store pass, BC
    /// encoding), at least `bytes` long: one buffer serves every call ([`kept_buffer`]).
    pub(crate) fn texture_codes(&self, device: &wgpu::Device, bytes: u64) -> wgpu::Buffer {
        let usage = wgpu::BufferUsages::STORAGE;
        kept_buffer(&self.texture_codes, device, bytes, usage, "nmat texture codes")
    }

    /// The store pipeline for `format` (cached), or `None` where the device refuses it.
    fn store_pipeline(
        &self,
        device: &wgpu::Device,
        format: wgpu::TextureFormat,
    ) -> Option<Arc<wgpu::ComputePipeline>> {
        let (_, name) = FORMATS.iter().find(|(f, _)| *f == format)?;
        let mut cache = self.stores.lock().unwrap_or_else(|e| e.into_inner());
        cache
            .entry(format)
            .or_insert_with(|| {
                let source = include_str!("shaders/store.wgsl").replace("FORMAT", name);
                let source = if self.immediates {
                    source.replace("@group(0) @binding(1) var<uniform> ", "var<immediate> ")
                } else {
                    source
                };
                try_pipeline(device, &source, "store_texels", (None, self.pipeline_cache.as_ref()))
                    .map(Arc::new)
            })
            .clone()
    }
}

//! Indexed-JPEG materials (docs/FORMAT.md §11) on the GPU: the section uploaded as it is stored,
//! a small descriptor of where each stream and table lies (layout.rs: [`JpegHeader`] and the
//! records after it), and
//! a pass that clears the output, then one dispatch per map with one workgroup per MCU. Regions
//! and requests, submitted or recorded; the sampling module, the texture and the BC paths refuse
//! a JPEG material with [`GpuError::Codec`].

use std::sync::Arc;

use nmat_core::internals::huffman_decoding;
use nmat_core::{Jpeg, Material};

use crate::gpu::{MAX_GROUPS, dispatch, try_pipeline};
use crate::layout::{
    self, HuffmanRecord, JpegHeader, JpegMapRecord, JpegParams, JpegStreamRecord, MipSize, Params,
    ShaderLayout,
};
use crate::{Context, GpuError, GpuMaterial};

/// Sections from this size on are refused: bit positions must stay below 2^32 on the GPU.
const MAX_SECTION_BYTES: usize = 1 << 28;

/// The JPEG decode and the pass that clears its output first.
pub(crate) struct JpegPipelines {
    pub(crate) decode: wgpu::ComputePipeline,
    clear: wgpu::ComputePipeline,
}

/// What the host needs of a JPEG material's maps: first channel, channel count, MCU size.
#[derive(Clone, Debug)]
pub(crate) struct JpegMaps {
    pub(crate) maps: Vec<(u32, u32, u32, u32)>,
}

/// The descriptor words and the section words of a JPEG material (layout in jpeg.wgsl).
pub(crate) fn upload_words(
    device: &wgpu::Device,
    m: &Material<'_>,
    j: &Jpeg<'_>,
) -> Result<(Vec<u32>, Vec<u32>, JpegMaps), GpuError> {
    let section = j.section();
    // The section is one storage binding; bit positions must stay below 2^32.
    let limits = device.limits();
    let limit = (MAX_SECTION_BYTES as u64 - 1)
        .min(limits.max_storage_buffer_binding_size)
        .min(limits.max_buffer_size);
    if section.len() as u64 > limit {
        return Err(GpuError::SectionTooLarge { bytes: section.len() as u64, limit });
    }
    let mut head = JpegHeader {
        width: m.width(),
        height: m.height(),
        mip_count: m.mip_count(),
        channel_count: m.channel_count() as u32,
        address_mode: m.address_mode() as u32,
        map_count: j.maps().len() as u32,
        ..JpegHeader::default()
    };
    for mip in 0..m.mip_count() {
        let (width, height) = m.mip_size(mip);
        head.mip_sizes[mip as usize] = MipSize { width, height };
    }
    let mut desc = vec![0u32; JpegHeader::WORDS];
    head.maps_at = desc.len() as u32;
    let mut maps = Vec::new();
    for map in j.maps() {
        let (mw, mh) = map.mcu_size();
        let record = JpegMapRecord {
            first_channel: u32::from(map.first_channel),
            channel_count: u32::from(map.channel_count),
            luma_h: u32::from(map.luma_h),
            luma_v: u32::from(map.luma_v),
        };
        desc.extend_from_slice(record.words());
        maps.push((u32::from(map.first_channel), u32::from(map.channel_count), mw, mh));
    }
    head.streams_at = desc.len() as u32;
    let mut tables = 0u8;
    for map in 0..j.maps().len() {
        for mip in 0..m.mip_count() {
            let p = j.stream_parts(map, mip).ok_or(GpuError::Codec)?;
            let record = JpegStreamRecord {
                index_at: p.index_at as u32,
                dc_at: p.dc_at as u32,
                data_at: p.data_at as u32,
                data_len: p.data_len as u32,
                mcus_x: p.mcus.0,
                mcus_y: p.mcus.1,
                quant_at: p.quant_at.map(|q| q as u32),
                dc_table: p.dc_table.map(u32::from),
                ac_table: p.ac_table.map(u32::from),
                pad: 0,
            };
            tables = tables.max(p.dc_table.into_iter().chain(p.ac_table).max().unwrap_or(0) + 1);
            desc.extend_from_slice(record.words());
        }
    }
    head.huffman_at = desc.len() as u32;
    for t in 0..tables {
        let (_, counts, values_at) = j.huffman_table(t).ok_or(GpuError::Codec)?;
        let (maxcode, offset) = huffman_decoding(&counts);
        let record = HuffmanRecord {
            maxcode: maxcode.map(|v| v as u32),
            offset: offset.map(|v| v as u32),
            values_at: values_at as u32,
            values: counts.iter().map(|&c| u32::from(c)).sum(),
        };
        desc.extend_from_slice(record.words());
    }
    layout::write(&mut desc, 0, &head);
    let words = section
        .chunks(4)
        .map(|w| {
            let mut b = [0u8; 4];
            b[..w.len()].copy_from_slice(w);
            u32::from_le_bytes(b)
        })
        .collect();
    Ok((desc, words, JpegMaps { maps }))
}

impl Context {
    /// The JPEG pipelines (decode, clear), built on first use.
    pub(crate) fn jpeg_pipelines(
        &self,
        device: &wgpu::Device,
    ) -> Result<Arc<JpegPipelines>, GpuError> {
        let mut slot = self.jpeg.lock().unwrap_or_else(|e| e.into_inner());
        if slot.is_none() {
            let source = crate::layout::jpeg_wgsl();
            let layout = Some(&self.pipeline_layout);
            let decode = try_pipeline(device, &source, "jpeg_main", layout);
            let clear = try_pipeline(device, &source, "jpeg_clear", layout);
            if let (Some(decode), Some(clear)) = (decode, clear) {
                *slot = Some(Arc::new(JpegPipelines { decode, clear }));
            }
        }
        slot.clone().ok_or(GpuError::Kernel {
            kernel: crate::Kernel::Reference,
            reason: "the device refused the JPEG decode shader",
        })
    }

    /// Records the decode of `params` (a rectangle or requests, checked by the caller, the
    /// output offset set) of JPEG material `gm` into `out`: the codes' words cleared, then one
    /// dispatch per map that holds a selected channel, one workgroup per MCU (rectangles) or per
    /// request.
    pub(crate) fn record_jpeg(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        (gm, maps): (&GpuMaterial, &JpegMaps),
        params: Params,
        requests: Option<&wgpu::Buffer>,
        out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let pipelines = self.jpeg_pipelines(device)?;
        let len = u64::from(params.count) * u64::from(params.out_channels);
        let max_binding = device.limits().max_storage_buffer_binding_size;
        let max_groups = u64::from(MAX_GROUPS) * u64::from(MAX_GROUPS);
        let too_large = GpuError::TooLarge {
            texels: u64::from(params.count),
            limit: (max_binding / u64::from(params.out_channels).max(1)).min(max_groups),
        };
        if len > max_binding {
            return Err(too_large);
        }
        // Workgroups of each map: its MCUs the rectangle touches, or one per request.
        let mut dispatches = Vec::new();
        for (k, &(first, count, mw, mh)) in maps.maps.iter().enumerate() {
            if params.channel_mask & (((1 << count) - 1) << first) == 0 {
                continue;
            }
            let mut p = JpegParams { map: k as u32, ..JpegParams::from(params) };
            let groups = if params.mode == 0 {
                u64::from(params.count)
            } else if params.count == 0 {
                0
            } else {
                let height = params.count / params.width;
                let columns = (params.x0 + params.width - 1) / mw - params.x0 / mw + 1;
                let rows = (params.y0 + height - 1) / mh - params.y0 / mh + 1;
                p.mcu_columns = columns;
                p.mcu_count = columns * rows;
                u64::from(columns) * u64::from(rows)
            };
            if groups > max_groups {
                return Err(too_large);
            }
            dispatches.push((p, groups));
        }
        // The clear pass takes its word count from the host (no 32-bit product in the shader).
        let words = len.div_ceil(4);
        let clear = JpegParams { clear_words: words as u32, ..JpegParams::from(params) };
        let bind = self.bind(device, Some(gm), requests, out, &clear);
        dispatch(encoder, &pipelines.clear, &bind, words.div_ceil(64));
        for (p, groups) in &dispatches {
            let bind = self.bind(device, Some(gm), requests, out, p);
            dispatch(encoder, &pipelines.decode, &bind, *groups);
        }
        Ok(())
    }
}

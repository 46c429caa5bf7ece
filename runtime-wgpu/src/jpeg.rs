//! Indexed-JPEG materials (docs/FORMAT.md §11) on the GPU: the section uploaded as it is stored,
//! a small descriptor of where each stream and table lies (layout.rs: [`JpegHeader`] and the
//! records after it), and
//! a pass that clears the output, then per map: for a rectangle one dispatch with one workgroup
//! per MCU; for requests, passes that decode each MCU the requests read once (mark, decode,
//! resolve, reset; jpeg.wgsl). Regions and requests, submitted or recorded; the sampling module,
//! the texture and the BC paths refuse a JPEG material with [`GpuError::Codec`].

use std::sync::Arc;

use nmat_core::internals::huffman_decoding;
use nmat_core::{Jpeg, Material};

use crate::gpu::{MAX_GROUPS, Waits, dispatch_bound};
use crate::layout::{
    self, HuffmanRecord, JpegHeader, JpegMapRecord, JpegParams, JpegStreamRecord, MipSize, Params,
    ShaderLayout,
};
use crate::{Context, GpuError, GpuMaterial};

/// Sections from this size on are refused: bit positions must stay below 2^32 on the GPU.
const MAX_SECTION_BYTES: usize = 1 << 28;

/// The most words a map's scratch slots take in the request passes' work buffer (8 MiB): a map
/// with more MCUs than fit decodes its requests in rounds.
const SCRATCH_WORDS: u32 = 1 << 21;

/// The JPEG decode, the pass that clears its output first, and the request passes.
pub(crate) struct JpegPipelines {
    pub(crate) decode: wgpu::ComputePipeline,
    clear: wgpu::ComputePipeline,
    mark: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    reset: wgpu::ComputePipeline,
}

/// A map of a JPEG material, as the host dispatches it.
#[derive(Clone, Debug)]
pub(crate) struct JpegMap {
    pub(crate) first_channel: u32,
    pub(crate) channel_count: u32,
    /// MCU width and height in texels.
    pub(crate) mcu: (u32, u32),
    /// MCUs over the whole chain.
    mcus: u32,
    /// Scratch slots: MCUs one round of requests may decode.
    slots: u32,
    /// Words of one scratch slot: the MCU's codes, every channel of the map, texel-major.
    slot_words: u32,
}

/// Words of the request passes' work buffer: after word 0 (the round's count of listed MCUs) a
/// table of one word per MCU of a map's chain (0, or `CLAIMED | slot` while a round runs: every
/// round leaves it 0), the list of a round's MCUs (`list` words from `1 + table`), and their
/// scratch slots of decoded codes (`scratch` words after the list). One work buffer per
/// [`Context`] serves every JPEG material: it is replaced by one with the larger of each part
/// when a material needs more, so the table's words are never anything else.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WorkShape {
    table: u32,
    list: u32,
    scratch: u32,
}

impl WorkShape {
    fn bytes(self) -> u64 {
        4 * (1 + u64::from(self.table) + u64::from(self.list) + u64::from(self.scratch))
    }

    fn covers(self, other: WorkShape) -> bool {
        self.table >= other.table && self.list >= other.list && self.scratch >= other.scratch
    }

    fn max(self, other: WorkShape) -> WorkShape {
        WorkShape {
            table: self.table.max(other.table),
            list: self.list.max(other.list),
            scratch: self.scratch.max(other.scratch),
        }
    }
}

/// What the host needs of a JPEG material's maps, and the work buffer its requests need.
#[derive(Clone, Debug)]
pub(crate) struct JpegMaps {
    pub(crate) maps: Vec<JpegMap>,
    work: WorkShape,
}

/// The descriptor words and the section words of a JPEG material (layout in jpeg.wgsl), and its
/// maps with the request passes' work buffer (scratch slots of at most `scratch_words` words,
/// default [`SCRATCH_WORDS`]).
pub(crate) fn upload_words(
    device: &wgpu::Device,
    m: &Material<'_>,
    j: &Jpeg<'_>,
    scratch_words: Option<u32>,
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
        let count = u32::from(map.channel_count);
        maps.push(JpegMap {
            first_channel: u32::from(map.first_channel),
            channel_count: count,
            mcu: (mw, mh),
            mcus: 0,
            slots: 0,
            slot_words: (mw * mh * count).div_ceil(4),
        });
    }
    head.streams_at = desc.len() as u32;
    let mut tables = 0u8;
    for (map, record) in maps.iter_mut().enumerate() {
        for mip in 0..m.mip_count() {
            let p = j.stream_parts(map, mip).ok_or(GpuError::Codec)?;
            // The table's words follow the count word; every map's chain starts at word 1.
            let table_at = 1 + record.mcus;
            record.mcus += p.mcus.0 * p.mcus.1;
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
                table_at,
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
    let scratch = scratch_words.unwrap_or(SCRATCH_WORDS);
    for map in &mut maps {
        map.slots = map.mcus.min(scratch / map.slot_words).max(1);
    }
    let work = WorkShape {
        table: maps.iter().map(|m| m.mcus).max().unwrap_or(0),
        list: maps.iter().map(|m| m.slots).max().unwrap_or(0),
        scratch: maps.iter().map(|m| m.slots * m.slot_words).max().unwrap_or(0),
    };
    Ok((desc, words, JpegMaps { maps, work }))
}

impl Context {
    /// The JPEG pipelines (decode, clear), built on first use.
    pub(crate) fn jpeg_pipelines(
        &self,
        device: &wgpu::Device,
    ) -> Result<Arc<JpegPipelines>, GpuError> {
        // Built and kept by the first call; with `Waits::Block` ready at once.
        crate::gpu::now(self.build_jpeg_pipelines(device, Waits::Block))
            .unwrap_or(Err(jpeg_refused()))
    }

    /// The JPEG pipelines built and kept, unless they are already: once the device has answered
    /// on each (`Waits::Await`: `Context::upload_async`), or with the answers it has now.
    pub(crate) async fn build_jpeg_pipelines(
        &self,
        device: &wgpu::Device,
        waits: Waits,
    ) -> Result<Arc<JpegPipelines>, GpuError> {
        let built = self.jpeg.lock().unwrap_or_else(|e| e.into_inner()).clone();
        if let Some(pipelines) = built {
            return Ok(pipelines);
        }
        let source = crate::layout::jpeg_wgsl();
        let names = ["jpeg_main", "jpeg_clear", "jpeg_mark", "jpeg_resolve", "jpeg_reset"];
        let [decode, clear, mark, resolve, reset] =
            names.map(|name| self.checked_pipeline(device, &source, name, waits));
        let all = (decode.await, clear.await, mark.await, resolve.await, reset.await);
        let (Some(decode), Some(clear), Some(mark), Some(resolve), Some(reset)) = all else {
            return Err(jpeg_refused());
        };
        let pipelines = Arc::new(JpegPipelines { decode, clear, mark, resolve, reset });
        let mut slot = self.jpeg.lock().unwrap_or_else(|e| e.into_inner());
        Ok(slot.get_or_insert(pipelines).clone())
    }

    /// Records the decode of `params` (a rectangle or requests, checked by the caller, the
    /// output offset set) of JPEG material `gm` into `out`: the codes' words cleared, then for
    /// every map that holds a selected channel one workgroup per MCU the rectangle touches, or
    /// the request passes: each MCU the requests read decoded once (in rounds of as many
    /// requests as the map's scratch slots where its MCUs do not all fit).
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
        if len > max_binding || u64::from(params.count).div_ceil(64) > max_groups {
            return Err(too_large);
        }
        let work = if params.mode == 0 { Some(self.jpeg_work(device, maps.work)?) } else { None };
        // The clear pass takes its word count from the host (no 32-bit product in the shader).
        let words = len.div_ceil(4);
        let clear = JpegParams { clear_words: words as u32, ..JpegParams::from(params) };
        let bind = self.bind(device, Some(gm), requests, out, &clear);
        dispatch_bound(encoder, &pipelines.clear, &bind, words.div_ceil(64));
        for (k, map) in maps.maps.iter().enumerate() {
            let (first, count, (mw, mh)) = (map.first_channel, map.channel_count, map.mcu);
            if params.channel_mask & (((1 << count) - 1) << first) == 0 || params.count == 0 {
                continue;
            }
            let p = JpegParams { map: k as u32, ..JpegParams::from(params) };
            if let Some(work) = &work {
                let requests = requests.unwrap_or(&self.empty);
                let passes = (gm, map, pipelines.as_ref());
                self.record_jpeg_requests(device, encoder, passes, work, p, (requests, out));
                continue;
            }
            // A rectangle: one workgroup per MCU it touches.
            let height = params.count / params.width;
            let columns = (params.x0 + params.width - 1) / mw - params.x0 / mw + 1;
            let rows = (params.y0 + height - 1) / mh - params.y0 / mh + 1;
            let p = JpegParams { mcu_columns: columns, mcu_count: columns * rows, ..p };
            let groups = u64::from(columns) * u64::from(rows);
            if groups > max_groups {
                return Err(too_large);
            }
            let bind = self.bind(device, Some(gm), requests, out, &p);
            dispatch_bound(encoder, &pipelines.decode, &bind, groups);
        }
        Ok(())
    }

    /// The request passes of one map, per round of at most as many requests as the map has
    /// scratch slots (one round where every MCU of its chain has a slot): the count of listed
    /// MCUs cleared; *mark* lists each MCU a request reads once and gives it a slot; *decode*
    /// decodes each listed MCU into its slot (one workgroup each); *resolve* copies each
    /// request's codes from its MCU's slot into `out`; *reset* clears the table entries the
    /// round claimed.
    fn record_jpeg_requests(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        (gm, map, pipelines): (&GpuMaterial, &JpegMap, &JpegPipelines),
        (work, shape): &(wgpu::Buffer, WorkShape),
        p: JpegParams,
        (requests, out): (&wgpu::Buffer, &wgpu::Buffer),
    ) {
        let round = if map.slots >= map.mcus { p.count } else { map.slots };
        let (desc, section) = (&gm.desc, &gm.latents);
        let list_at = 1 + shape.table;
        let mut start = 0;
        while start < p.count {
            let n = round.min(p.count - start);
            let params = JpegParams {
                mode: 3,
                count: n,
                in_offset: p.in_offset + 3 * start,
                first: start,
                list_at,
                scratch_at: list_at + shape.list,
                slot_words: map.slot_words,
                ..p
            };
            // Mark, decode and reset read the material and write the work buffer; resolve reads
            // the work buffer (as the section) and writes the output.
            let bytes = params.bytes();
            let on_work = self.bind_buffers(device, [desc, section, requests, work], &bytes);
            let to_out = self.bind_buffers(device, [desc, work, requests, out], &bytes);
            let per_request = u64::from(n).div_ceil(64);
            encoder.clear_buffer(work, 0, Some(4));
            dispatch_bound(encoder, &pipelines.mark, &on_work, per_request);
            dispatch_bound(encoder, &pipelines.decode, &on_work, u64::from(n.min(map.slots)));
            dispatch_bound(encoder, &pipelines.resolve, &to_out, per_request);
            dispatch_bound(encoder, &pipelines.reset, &on_work, per_request);
            start += n;
        }
    }

    /// The context's work buffer for the request passes, replaced by a larger one (zeroed) where
    /// it lacks any part of `need`; [`GpuError::RequestTablesTooLarge`] past one binding.
    fn jpeg_work(
        &self,
        device: &wgpu::Device,
        need: WorkShape,
    ) -> Result<(wgpu::Buffer, WorkShape), GpuError> {
        let mut slot = self.jpeg_work.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((buffer, shape)) = &*slot
            && shape.covers(need)
        {
            return Ok((buffer.clone(), *shape));
        }
        let shape = slot.as_ref().map_or(need, |(_, old)| old.max(need));
        let limits = device.limits();
        let limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        if shape.bytes() > limit {
            return Err(GpuError::RequestTablesTooLarge { bytes: shape.bytes(), limit });
        }
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("nmat jpeg requests"),
            size: shape.bytes(),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        *slot = Some((buffer.clone(), shape));
        Ok((buffer, shape))
    }
}

/// The device refused the JPEG decode shader (or left it unanswered).
fn jpeg_refused() -> GpuError {
    GpuError::Kernel {
        kernel: crate::Kernel::Reference,
        reason: "the device refused the JPEG decode shader",
    }
}

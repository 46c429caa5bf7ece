//! The tile cache on the GPU: `nmat_core::TileCache`'s frame protocol as passes an engine records
//! into its own command encoder — mark the tiles a frame's lookups read (from a buffer of
//! lookups its G-buffer pass wrote), compact the marked tiles the cache lacks into a queue, give
//! them slots (evicting the tiles the frame did not mark), decode them into the cache buffer, and
//! resolve lookups from it — with no readback and no CPU work per frame. The passes
//! (cache.wgsl, cache_decode.wgsl, jpeg.wgsl) and their buffers are documented in the shaders;
//! the design and its measurements are in docs/GPU.md, "The tile cache".

use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};

use nmat_core::{ChannelMask, Filter, FrameStats, Material, TILE_SIZE, TileKey};
use wgpu::util::DeviceExt;

use crate::gpu::{
    Bound, KeptBinds, Waits, check_output, check_requests, dispatch, dispatch_bound, read_back,
    read_back_async, read_buffer, read_buffer_async, read_buffer_within, spread, storage_entry,
    try_pipeline, uniform_buffer, uniform_entry,
};
use crate::jpeg::JpegMap;
use crate::layout::{
    self, CacheArgs, CacheDecodeParams, CacheHeader, CacheMaterial, CacheParams, CacheState,
    ChannelRange, DecodeArgs, DispatchArgs, JpegParams, MAX_MIPS, PAGE_MARK, PageRange, Params,
    QueueEntry, QueueHead, ShaderLayout, words_to_bytes,
};
use crate::upload::GpuBody;
use crate::{Context, GpuError, GpuMaterial, SampleBindings};
use std::mem::offset_of;

/// Materials one GPU tile cache serves (as `nmat_core::TileCache`).
pub const MAX_CACHE_MATERIALS: usize = nmat_core::MAX_CACHE_MATERIALS;

/// The frame's counters: the table's head up to `materials` (layout.rs: [`CacheHeader`]).
const COUNTER_BYTES: u64 = offset_of!(CacheHeader, materials) as u64;

/// One lookup of a frame, as the mark and resolve passes read it from the caller's buffer:
/// 32 bytes, little-endian (`bytemuck`-compatible layout): `nmat_core::SampleRequest`'s
/// coordinates, lod, filter and random numbers, and which material (its index in the cache's
/// list; [`CacheLookup::NONE`] or any index past the list: no lookup, e.g. the sky, resolved
/// as zeros). An engine's G-buffer pass writes these from its own shader.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CacheLookup {
    pub u: f32,
    pub v: f32,
    pub lod: f32,
    pub material: u32,
    /// `NMAT_NEAREST` (0), `NMAT_BILINEAR` (1), `NMAT_TRILINEAR` (2) or `NMAT_STOCHASTIC` (3):
    /// [`CacheLookup::filter_code`]; other values filter as nearest.
    pub filter: u32,
    pub random: [f32; 3],
}

impl ShaderLayout for CacheLookup {
    const FIELDS: &'static [(&'static str, usize, usize)] = &[
        ("u", offset_of!(CacheLookup, u) / 4, 1),
        ("v", offset_of!(CacheLookup, v) / 4, 1),
        ("lod", offset_of!(CacheLookup, lod) / 4, 1),
        ("material", offset_of!(CacheLookup, material) / 4, 1),
        ("filter", offset_of!(CacheLookup, filter) / 4, 1),
        ("random_0", offset_of!(CacheLookup, random) / 4, 1),
        ("random_1", offset_of!(CacheLookup, random) / 4 + 1, 1),
        ("random_2", offset_of!(CacheLookup, random) / 4 + 2, 1),
    ];
}

impl CacheLookup {
    /// The material index of a pixel with no lookup.
    pub const NONE: u32 = u32::MAX;
    /// Bytes per lookup in a buffer.
    pub const BYTES: u64 = 32;

    /// The lookup of `req` (its channels and precision are the resolve call's) in material
    /// `material` of the cache.
    pub fn new(material: u32, req: &nmat_core::SampleRequest) -> CacheLookup {
        CacheLookup {
            u: req.u,
            v: req.v,
            lod: req.lod,
            material,
            filter: CacheLookup::filter_code(req.filter),
            random: req.random,
        }
    }

    /// A filter's number in a lookup (the module's `NMAT_*` constants).
    pub fn filter_code(filter: Filter) -> u32 {
        match filter {
            Filter::Nearest => 0,
            Filter::Bilinear => 1,
            Filter::Trilinear => 2,
            Filter::Stochastic => 3,
        }
    }

    /// The buffer bytes of `lookups`.
    pub fn bytes(lookups: &[CacheLookup]) -> Vec<u8> {
        let mut out = Vec::with_capacity(lookups.len() * Self::BYTES as usize);
        for l in lookups {
            for word in [l.u.to_bits(), l.v.to_bits(), l.lod.to_bits(), l.material, l.filter] {
                out.extend(word.to_le_bytes());
            }
            for r in l.random {
                out.extend(r.to_bits().to_le_bytes());
            }
        }
        out
    }
}

/// What the host keeps of a cached material.
struct CachedMaterial {
    channels: u32,
    mip_sizes: Vec<(u32, u32)>,
    /// The table index of each mip's first page.
    first_page: Vec<u32>,
}

/// A decode dispatch of the frame: pipeline, bindings, and where its indirect arguments lie.
struct Decode {
    pipeline: wgpu::ComputePipeline,
    bound: Bound,
    args: u64,
}

/// The cache's passes (cache.wgsl).
struct Passes {
    mark: wgpu::ComputePipeline,
    compact: wgpu::ComputePipeline,
    plan: wgpu::ComputePipeline,
    allocate: wgpu::ComputePipeline,
    finish: wgpu::ComputePipeline,
    clear: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
}

/// A fixed-capacity cache of decoded 16×16 tiles ([`TILE_SIZE`]) of up to
/// [`MAX_CACHE_MATERIALS`] materials (neural and JPEG) on the GPU, made by
/// [`Context::create_tile_cache`]. A frame records, in order:
/// [`GpuTileCache::record_begin_frame`], [`GpuTileCache::record_mark`] (every lookup the frame
/// will make), [`GpuTileCache::record_decode_missing`], then [`GpuTileCache::record_resolve`] or
/// the engine's own shaders calling `nmat_cache_sample` ([`GpuTileCache::sample_module`]), then
/// [`GpuTileCache::record_end_frame`]; [`GpuTileCache::read_stats`] reads the frame's counters
/// once it has run.
///
/// Tiles and counters are those of `nmat_core::TileCache` given the same lookups (the tiles'
/// codes are the CPU's, byte for byte): a tile the frame does not mark is evicted; a new tile
/// takes a free slot; when none is left the tile is not cached ([`FrameStats::overflowed`]) and
/// the texels lookups read from it count as [`FrameStats::resolve_misses`] and read as code 0 —
/// the GPU cannot decode them on the spot for every material, so size the cache above the
/// largest frame (the CPU cache decodes such texels directly).
pub struct GpuTileCache {
    table: wgpu::Buffer,
    state: wgpu::Buffer,
    codes: wgpu::Buffer,
    /// The indirect dispatches' arguments (cache.wgsl).
    args: wgpu::Buffer,
    /// The counters copied at the end of a frame, for `read_stats`.
    stats: wgpu::Buffer,
    /// The material records as the mark and resolve passes read them (a uniform block).
    records: wgpu::Buffer,
    layout: wgpu::BindGroupLayout,
    /// The resolve pass's layout: the codes read-only.
    resolve_layout: wgpu::BindGroupLayout,
    passes: Passes,
    /// The bind groups of the passes that read no lookups; of the plan and finish passes.
    frame_bind: wgpu::BindGroup,
    plan_bind: wgpu::BindGroup,
    decodes: Vec<Decode>,
    materials: Vec<CachedMaterial>,
    slots: u32,
    pages: u32,
    slot_words: u32,
    frame: AtomicU32,
    /// The bind groups (with their parameters) of the last mark and resolve calls, most recent
    /// first: a frame that marks and resolves the same lookups into the same output as an
    /// earlier one allocates nothing.
    binds: KeptBinds<BindKey>,
    /// Bind groups made for mark and resolve calls so far (a test reads it).
    binds_made: AtomicU32,
}

/// What a mark or resolve call binds: its pass (0 mark, 1 resolve), the lookups (buffer, first
/// word, count), the channels, the output (resolve) and its first word.
#[derive(Clone, PartialEq, Eq)]
struct BindKey {
    pass: u8,
    lookups: wgpu::Buffer,
    in_offset: u32,
    count: u32,
    channels: u32,
    out: Option<wgpu::Buffer>,
    out_offset: u32,
}

/// Bind groups a cache keeps for its mark and resolve calls (two per frame: a few frames'
/// worth of different buffers or counts).
const KEPT_BINDS: usize = 8;

/// The material records of a cache of `materials` materials as the passes read them: a uniform
/// block (`nmat_cache_records`, binding 5; every lookup reads its material's record, which never
/// changes: a uniform read is served near the cores, an atomic load of the table is not) with
/// the accessor cache_sample.wgsl asks for.
fn records_wgsl(materials: usize) -> String {
    format!(
        "@group(0) @binding(5) var<uniform> nmat_cache_records: array<vec4<u32>, {}>;\n\
         fn nmat_cache_record_word(material: u32, i: u32) -> u32 {{\n\
         \x20   let w = NMAT_CACHE_MAT_WORDS * material + i;\n\
         \x20   return nmat_cache_records[w / 4u][w % 4u];\n\
         }}\n",
        record_vec4s(materials)
    )
}

/// The `vec4<u32>`s of the records' uniform block: 16 per material (a record is 64 words), 16 KiB
/// for the most materials, the smallest limit a device may have for a uniform binding.
fn record_vec4s(materials: usize) -> usize {
    (CacheMaterial::WORDS * materials).div_ceil(4)
}

/// The cache's generated declarations and the filter, after a pass module's own file.
fn cache_module(own: &str, materials: usize) -> String {
    [
        layout::cache_state_wgsl(),
        layout::cache_table_wgsl(),
        layout::wgsl_struct::<CacheParams>("NmatCacheParams"),
        records_wgsl(materials),
        own.to_string(),
        include_str!("shaders/cache_lookup.wgsl").to_string(),
        include_str!("shaders/cache_sample.wgsl").to_string(),
        include_str!("shaders/filter.wgsl").to_string(),
    ]
    .join("\n")
}

/// The shader of the cache's passes but the resolve (cache.wgsl), for `materials` materials.
pub(crate) fn passes_source(materials: usize) -> String {
    cache_module(include_str!("shaders/cache.wgsl"), materials)
}

/// The shader of the resolve pass (cache_resolve.wgsl), for `materials` materials.
pub(crate) fn resolve_source(materials: usize) -> String {
    cache_module(include_str!("shaders/cache_resolve.wgsl"), materials)
}

/// The shader of the neural decode of new tiles (cache_decode.wgsl).
pub(crate) fn decode_source() -> String {
    [
        SampleBindings { group: 0, first_binding: 0 }.module(),
        layout::cache_state_wgsl(),
        layout::wgsl_struct::<CacheDecodeParams>("NmatCacheDecode"),
        include_str!("shaders/cache_decode.wgsl").to_string(),
    ]
    .join("\n")
}

/// The uniform block of cache.wgsl.
fn cache_params(
    count: u32,
    in_offset: u32,
    channels: u32,
    out_offset: u32,
    materials: usize,
) -> Vec<u8> {
    let out_channels = channels.count_ones();
    let materials = materials as u32;
    CacheParams { count, in_offset, channels, out_channels, out_offset, materials, pad: [0; 2] }
        .bytes()
}

impl Context {
    /// A tile cache of `slots` tiles over `materials` (indexed 0, 1, … in lookups), neural or
    /// JPEG, with its buffers allocated once: `slots` × 256 × (the most channels of a material)
    /// bytes of codes, a page word per tile of every mip, and the queues. Its passes are built
    /// here. [`GpuError::Cache`] for no material or more than [`MAX_CACHE_MATERIALS`], no slot,
    /// or codes larger than one storage binding of the device.
    pub fn create_tile_cache(
        &self,
        device: &wgpu::Device,
        materials: &[&GpuMaterial],
        slots: u32,
    ) -> Result<GpuTileCache, GpuError> {
        if materials.is_empty() || materials.len() > MAX_CACHE_MATERIALS {
            return Err(GpuError::Cache { reason: "it serves 1 to 64 materials" });
        }
        if slots == 0 {
            return Err(GpuError::Cache { reason: "it needs at least one slot" });
        }
        let channels = materials.iter().map(|m| m.channel_count).max().unwrap_or(1).max(1);
        let slot_words = (TILE_SIZE * TILE_SIZE) as u64 * channels as u64 / 4;
        let max_binding = device.limits().max_storage_buffer_binding_size;
        let code_bytes = u64::from(slots) * slot_words * 4;
        if code_bytes > max_binding {
            return Err(GpuError::Cache {
                reason: "its codes are larger than one storage binding of the device",
            });
        }
        // The table: header, material records, page ranges, pages.
        let header_words = CacheHeader::WORDS + CacheMaterial::WORDS * materials.len();
        let mut table = vec![0u32; header_words];
        let mut records = Vec::new();
        let mut ranges = Vec::new();
        let mut cached = Vec::new();
        let mut pages = 0u32;
        for (k, m) in materials.iter().enumerate() {
            let (w, h) = m.mip_sizes[0];
            let mut record = CacheMaterial {
                width: w,
                height: h,
                mip_count: m.mip_sizes.len() as u32,
                channel_count: m.channel_count as u32,
                address_mode: m.address_clamp as u32,
                ..CacheMaterial::default()
            };
            for (range, &(lo, hi)) in record.ranges.iter_mut().zip(&m.ranges) {
                *range = ChannelRange { min: lo.to_bits(), max: hi.to_bits() };
            }
            let mut first_page = Vec::new();
            for (mip, &(mw, mh)) in m.mip_sizes.iter().enumerate().take(MAX_MIPS) {
                first_page.push(pages);
                ranges.push((pages, (k as u32) << 8 | mip as u32));
                pages += mw.div_ceil(TILE_SIZE) * mh.div_ceil(TILE_SIZE);
            }
            records.push(record);
            cached.push(CachedMaterial {
                channels: m.channel_count as u32,
                mip_sizes: m.mip_sizes.clone(),
                first_page,
            });
        }
        let ranges_at = table.len() as u32;
        let pages_at = ranges_at + (PageRange::WORDS * ranges.len()) as u32;
        for (k, (m, record)) in cached.iter_mut().zip(&mut records).enumerate() {
            for (first, slot) in m.first_page.iter_mut().zip(&mut record.first_page) {
                *first += pages_at;
                *slot = *first;
            }
            layout::write(&mut table, CacheHeader::WORDS + CacheMaterial::WORDS * k, record);
        }
        for &(first, which) in &ranges {
            table.extend_from_slice(PageRange { first_page: first + pages_at, which }.words());
        }
        let head = CacheHeader {
            materials: materials.len() as u32,
            ranges: ranges.len() as u32,
            ranges_at,
            pages_at,
            pages,
            slot_words: slot_words as u32,
            slots,
            ..CacheHeader::default()
        };
        layout::write(&mut table, 0, &head);
        table.resize(table.len() + pages as usize, 0);
        // The state: every slot free. Both tables are checked before the state is allocated.
        let queue_words = QueueHead::WORDS + QueueEntry::WORDS * slots as usize;
        let queues_at = CacheState::WORDS + 2 * slots as usize;
        let state_words = queues_at + materials.len() * queue_words;
        if 4 * table.len().max(state_words) as u64 > max_binding {
            return Err(GpuError::Cache {
                reason: "its tables are larger than one storage binding of the device",
            });
        }
        let mut state = vec![0u32; state_words];
        layout::write(&mut state, 0, &CacheState { free: slots, ..CacheState::default() });
        let free = &mut state[CacheState::WORDS..CacheState::WORDS + slots as usize];
        for (i, s) in free.iter_mut().enumerate() {
            *s = slots - 1 - i as u32;
        }
        use wgpu::BufferUsages as U;
        let args_bytes =
            (size_of::<CacheArgs>() + size_of::<DecodeArgs>() * materials.len()) as u64;
        let init = |label, words: &[u32], usage| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: &words_to_bytes(words),
                usage,
            })
        };
        let table = init("nmat cache table", &table, U::STORAGE | U::COPY_SRC | U::COPY_DST);
        let state = init("nmat cache state", &state, U::STORAGE | U::COPY_SRC | U::COPY_DST);
        let buffer = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let codes = buffer("nmat cache codes", code_bytes, U::STORAGE | U::COPY_SRC);
        let stats = buffer("nmat cache stats", COUNTER_BYTES, U::MAP_READ | U::COPY_DST);
        let args = buffer("nmat cache dispatches", args_bytes, U::STORAGE | U::INDIRECT);
        let empty = buffer("nmat cache no lookups", 32, U::STORAGE);
        let (layout, resolve_layout, passes) = self.cache_passes(device, materials.len())?;
        let uniform = |bytes: &[u8]| uniform_buffer(device, bytes);
        let mut record_words = vec![0u32; 4 * record_vec4s(materials.len())];
        for (k, record) in records.iter().enumerate() {
            layout::write(&mut record_words, CacheMaterial::WORDS * k, record);
        }
        let records = uniform(&words_to_bytes(&record_words));
        let params = uniform(&[0; 32]);
        let frame = [&table, &state, &empty, &codes];
        let frame_bind = bind(device, &layout, frame, &params, &records);
        let plan = [&table, &state, &empty, &args];
        let plan_bind = bind(device, &layout, plan, &params, &records);
        // The decode dispatches of each material, reading its queue.
        let mut decodes = Vec::new();
        let neural = self.cache_decode_pipeline(device)?;
        for (k, m) in materials.iter().enumerate() {
            let queue_at = (queues_at + k * queue_words) as u32;
            // The byte of the material's dispatch of `per_tile` (1, 2 or 4) workgroups per tile.
            let args = |per_tile: u32| {
                let at = size_of::<CacheArgs>() + size_of::<DecodeArgs>() * k;
                (at + size_of::<DispatchArgs>() * per_tile.ilog2() as usize) as u64
            };
            let GpuBody::Jpeg(maps) = &m.body else {
                // Through the material's tile decoder where it has one (tiled.wgsl's
                // `tiled_cache`, four workgroups a tile; matrix.wgsl's `matrix_cache`, one),
                // else one texel per invocation (cache_decode.wgsl, four workgroups a tile).
                let (pipeline, params, per_tile, weights) = match &m.tile_decoder {
                    Some(decoder) => {
                        let channels = m.channel_count as u32;
                        let params = Params {
                            mode: 2,
                            channel_mask: (1 << channels) - 1,
                            out_channels: channels,
                            row_words: slot_words as u32,
                            in_offset: queue_at,
                            ..Params::default()
                        };
                        let pipeline = decoder.pipeline.as_ref().clone();
                        (pipeline, params.bytes(), decoder.per_tile, true)
                    }
                    None => {
                        let slot_words = slot_words as u32;
                        let params = CacheDecodeParams { queue_at, slot_words, pad: [0; 2] };
                        (neural.clone(), params.bytes(), 4, false)
                    }
                };
                let mut bound =
                    self.bind_fixed(device, [&m.desc, &m.latents, &state, &codes], &params);
                if weights {
                    bound = bound.with_weights_of(m);
                }
                decodes.push(Decode { pipeline, bound, args: args(per_tile) });
                continue;
            };
            let jpeg = self.jpeg_pipelines(device)?;
            for (map, &JpegMap { mcu: (mw, mh), .. }) in maps.maps.iter().enumerate() {
                let (columns, rows) = (TILE_SIZE / mw, TILE_SIZE / mh);
                let params = JpegParams {
                    mode: 2,
                    channel_mask: (1 << m.channel_count) - 1,
                    out_channels: m.channel_count as u32,
                    map: map as u32,
                    mcu_columns: columns,
                    mcu_count: columns * rows,
                    slot_words: slot_words as u32,
                    in_offset: queue_at,
                    ..JpegParams::default()
                };
                let buffers = [&m.desc, &m.latents, &state, &codes];
                let bound = self.bind_fixed(device, buffers, &params.bytes());
                let pipeline = jpeg.decode.clone();
                decodes.push(Decode { pipeline, bound, args: args(columns * rows) });
            }
        }
        Ok(GpuTileCache {
            table,
            state,
            codes,
            args,
            stats,
            records,
            layout,
            resolve_layout,
            passes,
            frame_bind,
            plan_bind,
            decodes,
            materials: cached,
            slots,
            pages,
            slot_words: slot_words as u32,
            frame: AtomicU32::new(0),
            binds: KeptBinds::new(KEPT_BINDS),
            binds_made: AtomicU32::new(0),
        })
    }

    /// The layouts (the passes', the resolve pass's) and pipelines of cache.wgsl and
    /// cache_resolve.wgsl for `materials` materials.
    fn cache_passes(
        &self,
        device: &wgpu::Device,
        materials: usize,
    ) -> Result<(wgpu::BindGroupLayout, wgpu::BindGroupLayout, Passes), GpuError> {
        let layout_of = |codes_read_only: bool| {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("nmat cache"),
                entries: &[
                    storage_entry(0, false),
                    storage_entry(1, false),
                    storage_entry(2, true),
                    storage_entry(3, codes_read_only),
                    uniform_entry(4),
                    uniform_entry(5),
                ],
            })
        };
        let (layout, resolve_layout) = (layout_of(false), layout_of(true));
        let pipeline_layout = |layout| {
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("nmat cache"),
                bind_group_layouts: &[Some(layout)],
                immediate_size: 0,
            })
        };
        let pipeline = |source: &str, layout: &wgpu::PipelineLayout, entry: &str| {
            try_pipeline(device, source, entry, (Some(layout), self.pipeline_cache.as_ref())).ok_or(
                GpuError::Kernel {
                    kernel: crate::Kernel::Reference,
                    reason: "the device refused the tile cache's shader",
                },
            )
        };
        let (source, passes_layout) = (passes_source(materials), pipeline_layout(&layout));
        let pass = |entry: &str| pipeline(&source, &passes_layout, entry);
        let passes = Passes {
            mark: pass("nmat_cache_mark")?,
            compact: pass("nmat_cache_compact")?,
            plan: pass("nmat_cache_plan")?,
            allocate: pass("nmat_cache_allocate")?,
            finish: pass("nmat_cache_finish")?,
            clear: pass("nmat_cache_clear")?,
            resolve: pipeline(
                &resolve_source(materials),
                &pipeline_layout(&resolve_layout),
                "nmat_cache_resolve",
            )?,
        };
        Ok((layout, resolve_layout, passes))
    }

    /// `gm` (uploaded with the tiled or matrix kernel `entry` belongs to) with that kernel's tile
    /// entry as its tile decoder where the entry decodes the probe tiles ([`probe_tiles`]) as
    /// the CPU does; without one (the tile cache then decodes its tiles one texel per
    /// invocation) where it does not, or where the device refuses the entry, logged like a
    /// kernel whose probe fails.
    pub(crate) async fn with_tile_decoder(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        m: &Material<'_>,
        gm: GpuMaterial,
        entry: Option<TileEntry>,
        waits: Waits,
    ) -> Result<GpuMaterial, GpuError> {
        let Some(entry) = entry else { return Ok(gm) };
        let checked = match self.tile_pipeline(device, &entry).await {
            None => Err("the device refused it"),
            Some(pipeline) => {
                let decoder = TileDecoder { pipeline, per_tile: entry.per_tile };
                match self.probe_tile_decoder(device, queue, m, &gm, &decoder, waits).await {
                    Ok(Some(true)) => Ok(decoder),
                    Ok(Some(false)) => Err("its codes on the probe tiles differ from the CPU's"),
                    Ok(None) => {
                        let seconds = self.probe_wait(device).as_secs() as u32;
                        return Err(GpuError::Hung { kernel: gm.kernel, seconds });
                    }
                    Err(_) => Err("the probe decode failed"),
                }
            }
        };
        Ok(match checked {
            Ok(decoder) => GpuMaterial { tile_decoder: Some(decoder), ..gm },
            Err(reason) => {
                log::warn!(
                    "nmat-wgpu: the {} kernel's tile entry is not used (tiles decode one texel \
                     per invocation): {reason}",
                    gm.kernel.name()
                );
                gm
            }
        })
    }

    /// The pipeline of a kernel's tile entry, built once per material shape (keyed apart from
    /// the kernel's own pipeline: same source, another entry); `None` where the device refuses
    /// it. Broken on purpose after [`Context::break_tile_decoders_for_testing`].
    async fn tile_pipeline(
        &self,
        device: &wgpu::Device,
        entry: &TileEntry,
    ) -> Option<Arc<wgpu::ComputePipeline>> {
        let mut source = entry.source.clone();
        if self.tile_fault.load(Ordering::Relaxed) {
            // Every word a tile entry stores gets its lowest bit flipped (batch.wgsl).
            source =
                source.replace("out_codes[first + w] = word;", "out_codes[first + w] = word ^ 1u;");
        }
        let key = format!("{source}// {}\n", entry.entry);
        self.kept_pipeline(device, key, entry.entry).await
    }

    /// Whether `decoder` decodes [`probe_tiles`] of `m` (uploaded as `gm`) as the CPU does:
    /// every texel and channel of each tile into its own slot of a fresh buffer, through a queue
    /// laid out as the cache's, then read back (blocking, waits for the device as long as for
    /// a kernel's probe: `None` where it had not finished; or awaited).
    async fn probe_tile_decoder(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        m: &Material<'_>,
        gm: &GpuMaterial,
        decoder: &TileDecoder,
        waits: Waits,
    ) -> Result<Option<bool>, GpuError> {
        let tiles = probe_tiles(m);
        let n = m.channel_count() as u32;
        let row_words = TILE_SIZE * TILE_SIZE * n / 4;
        let mut words = vec![0u32; QueueHead::WORDS];
        layout::write(&mut words, 0, &QueueHead { count: tiles.len() as u32, pad: [0; 3] });
        for (slot, key) in tiles.iter().enumerate() {
            let key = u32::from(key.mip) << 26 | u32::from(key.y) << 13 | u32::from(key.x);
            words.extend_from_slice(QueueEntry { slot: slot as u32, key }.words());
        }
        let requests = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("nmat tile probe queue"),
            contents: &words_to_bytes(&words),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let out = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("nmat tile probe codes"),
            size: 4 * u64::from(row_words) * tiles.len() as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let params = Params {
            mode: 2,
            channel_mask: (1 << n) - 1,
            out_channels: n,
            row_words,
            in_offset: 0,
            ..Params::default()
        };
        // Bound for this probe only (not kept: its buffers go when it returns).
        let buffers = [&gm.desc, &gm.latents, &requests, &out];
        let bind = self.bind_fixed(device, buffers, &params.bytes()).with_weights_of(gm);
        let mut encoder = device.create_command_encoder(&Default::default());
        let groups = u64::from(decoder.per_tile) * tiles.len() as u64;
        dispatch_bound(&mut encoder, &decoder.pipeline, &bind, groups);
        queue.submit([encoder.finish()]);
        let got = match waits {
            Waits::Block => read_buffer_within(device, queue, &out, self.probe_wait(device))?,
            Waits::Await => Some(read_buffer_async(device, queue, &out).await?),
        };
        let Some(got) = got else { return Ok(None) };
        let want: Vec<u8> = tiles.iter().flat_map(|&key| cpu_tile_codes(m, key)).collect();
        Ok(Some(got == want))
    }

    /// Makes the tile entries of the materials uploaded from now on store wrong codes, so that
    /// a test can see their probe reject them ([`GpuMaterial::tile_kernel`]). For tests only.
    #[doc(hidden)]
    pub fn break_tile_decoders_for_testing(&self) {
        self.tile_fault.store(true, Ordering::Relaxed);
    }

    /// The neural decode of new tiles (cache_decode.wgsl), in the decode kernels' layout.
    fn cache_decode_pipeline(
        &self,
        device: &wgpu::Device,
    ) -> Result<wgpu::ComputePipeline, GpuError> {
        let source = decode_source();
        self.pipeline(device, &source, "nmat_cache_decode").ok_or(GpuError::Kernel {
            kernel: crate::Kernel::Reference,
            reason: "the device refused the tile cache's decode shader",
        })
    }
}

/// The entry of a tiled or matrix kernel's source that decodes the tile cache's new tiles
/// (batch.wgsl): tiled.wgsl's `tiled_cache` or matrix.wgsl's `matrix_cache`.
pub(crate) struct TileEntry {
    pub source: String,
    pub entry: &'static str,
    /// Workgroups per tile: 4 (`tiled_cache`) or 1 (`matrix_cache`).
    pub per_tile: u32,
}

/// A material's tile entry, built and checked against the CPU at upload.
#[derive(Clone)]
pub(crate) struct TileDecoder {
    pipeline: Arc<wgpu::ComputePipeline>,
    per_tile: u32,
}

/// The most tiles [`Context::upload`] decodes through a kernel's tile entry before the tile
/// cache uses it.
const PROBE_TILES: usize = 8;

/// The tiles a tile entry decodes before it is used: the first and the last tile of mip 0 and
/// the last tile of mips spread over the chain (edge tiles where a mip is not a multiple of 16,
/// and the 1 × 1 mip), [`PROBE_TILES`] at most.
fn probe_tiles(m: &Material<'_>) -> Vec<TileKey> {
    let mips = m.mip_count();
    let spread = (PROBE_TILES - 1) as u32;
    let mut keys = vec![TileKey { material: 0, mip: 0, x: 0, y: 0 }];
    for k in 0..spread.min(mips) {
        let mip = if mips <= spread { k } else { k * (mips - 1) / (spread - 1) };
        let (w, h) = m.mip_size(mip);
        let (x, y) = ((w - 1) / TILE_SIZE, (h - 1) / TILE_SIZE);
        let key = TileKey { material: 0, mip: mip as u8, x: x as u16, y: y as u16 };
        if !keys.contains(&key) {
            keys.push(key);
        }
    }
    keys
}

/// The CPU's codes of tile `key` of `m`: 16 × 16 texels, every channel, 0 past the mip's edge
/// (a slot of the cache).
fn cpu_tile_codes(m: &Material<'_>, key: TileKey) -> Vec<u8> {
    let n = m.channel_count();
    let mip = u32::from(key.mip);
    let (w, h) = m.mip_size(mip);
    let mut out = vec![0u8; (TILE_SIZE * TILE_SIZE) as usize * n];
    for (t, texel) in out.chunks_exact_mut(n).enumerate() {
        let t = t as u32;
        let x = u32::from(key.x) * TILE_SIZE + t % TILE_SIZE;
        let y = u32::from(key.y) * TILE_SIZE + t / TILE_SIZE;
        if x < w && y < h {
            // A texel inside the mip always decodes; a failure leaves zeros, which the probe
            // then finds unequal unless the GPU wrote zeros too.
            let _ = m.decode_texel_u8(i64::from(x), i64::from(y), mip, ChannelMask::ALL, texel);
        }
    }
    out
}

/// A bind group of cache.wgsl's (or cache_resolve.wgsl's) layout.
fn bind(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    buffers: [&wgpu::Buffer; 4],
    uniform: &wgpu::Buffer,
    records: &wgpu::Buffer,
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
        .iter()
        .copied()
        .chain([uniform, records])
        .enumerate()
        .map(|(binding, b)| wgpu::BindGroupEntry {
            binding: binding as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("nmat cache"),
        layout,
        entries: &entries,
    })
}

/// Workgroups of 64 invocations for `count` items.
fn groups_of_64(count: u32) -> u64 {
    u64::from(count).div_ceil(64)
}

impl GpuTileCache {
    /// Tiles the cache holds at most.
    pub fn capacity(&self) -> u32 {
        self.slots
    }

    /// Starts a frame: its counters are cleared (recorded; the frame number counts calls).
    pub fn record_begin_frame(&self, encoder: &mut wgpu::CommandEncoder) {
        self.frame.fetch_add(1, Ordering::Relaxed);
        encoder.clear_buffer(&self.table, 0, Some(COUNTER_BYTES));
        // The new tiles and the slots given (state words 1 and 2).
        encoder.clear_buffer(&self.state, 4, Some(8));
    }

    /// Records the mark pass over `count` [`CacheLookup`]s in `lookups` from byte `offset`
    /// (`STORAGE` usage, offset a multiple of 4): every tile each lookup's filter reads is
    /// marked (the same tiles `nmat_core::TileCache::mark` marks for the same request, where
    /// u · width and v · height are exact in f32 — filter.wgsl). Several calls may mark one
    /// frame.
    /// A call with the buffer, offset and count of one of the last few mark or resolve calls
    /// reuses its bind group, so a frame loop over the same G-buffer allocates nothing after its
    /// first frame (the cache holds a reference to those buffers until other calls replace them).
    pub fn record_mark(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        (lookups, offset, count): (&wgpu::Buffer, u64, u32),
    ) -> Result<(), GpuError> {
        let bytes = CacheLookup::BYTES * u64::from(count);
        let in_offset = check_requests(device, lookups, offset, bytes)?;
        let key = BindKey {
            pass: 0,
            lookups: lookups.clone(),
            in_offset,
            count,
            // No channel: marking runs the filter for the texels it reads, not their values.
            channels: 0,
            out: None,
            out_offset: 0,
        };
        let group = self.bind_for(device, key, |uniform| {
            let buffers = [&self.table, &self.state, lookups, &self.codes];
            bind(device, &self.layout, buffers, uniform, &self.records)
        });
        dispatch(encoder, &self.passes.mark, &group, groups_of_64(count));
        Ok(())
    }

    /// Records the passes between marking and resolving: compact the marked tiles the cache
    /// lacks into a queue and evict the tiles the frame did not mark (one invocation per page),
    /// give the new tiles free slots, clear those slots, and decode each material's new tiles
    /// into them (neural: every texel by the integer decoder; JPEG: each MCU of the tile once).
    /// Dispatch sizes are computed on the GPU (indirect dispatches): nothing is read back.
    pub fn record_decode_missing(&self, encoder: &mut wgpu::CommandEncoder) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("nmat cache decode"),
            timestamp_writes: None,
        });
        pass.set_bind_group(0, &self.frame_bind, &[]);
        let (gx, gy) = spread(groups_of_64(self.pages));
        pass.set_pipeline(&self.passes.compact);
        pass.dispatch_workgroups(gx, gy, 1);
        pass.set_bind_group(0, &self.plan_bind, &[]);
        pass.set_pipeline(&self.passes.plan);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_bind_group(0, &self.frame_bind, &[]);
        pass.set_pipeline(&self.passes.allocate);
        pass.dispatch_workgroups_indirect(&self.args, offset_of!(CacheArgs, allocate) as u64);
        pass.set_bind_group(0, &self.plan_bind, &[]);
        pass.set_pipeline(&self.passes.finish);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_bind_group(0, &self.frame_bind, &[]);
        pass.set_pipeline(&self.passes.clear);
        pass.dispatch_workgroups_indirect(&self.args, offset_of!(CacheArgs, clear) as u64);
        for d in &self.decodes {
            pass.set_pipeline(&d.pipeline);
            d.bound.set(&mut pass);
            pass.dispatch_workgroups_indirect(&self.args, d.args);
        }
    }

    /// Records the resolve of `count` [`CacheLookup`]s (as [`GpuTileCache::record_mark`]) into
    /// `out` from byte `out_offset` (`STORAGE` usage, a multiple of 4): per lookup, the filtered
    /// value of each channel in `channels` as an `f32`, channel by channel (a channel its
    /// material lacks, or a lookup with no material, gives 0) — `Material::sample`'s values for
    /// the same request, computed in f32 (to f32 rounding, filter.wgsl), from the cache's codes.
    /// Returns the number of values written. Like [`GpuTileCache::record_mark`], a call with
    /// the same buffers, offsets, count and channels as a recent one allocates nothing.
    pub fn record_resolve(
        &self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        (lookups, offset, count): (&wgpu::Buffer, u64, u32),
        channels: ChannelMask,
        (out, out_offset): (&wgpu::Buffer, u64),
    ) -> Result<u64, GpuError> {
        if channels.0 == 0 {
            return Err(GpuError::Channels { mask: channels.0 });
        }
        let bytes = CacheLookup::BYTES * u64::from(count);
        let in_offset = check_requests(device, lookups, offset, bytes)?;
        let values = u64::from(count) * u64::from(channels.0.count_ones());
        let out_word = check_output(device, out, out_offset, 4 * values)?;
        let key = BindKey {
            pass: 1,
            lookups: lookups.clone(),
            in_offset,
            count,
            channels: u32::from(channels.0),
            out: Some(out.clone()),
            out_offset: out_word,
        };
        let group = self.bind_for(device, key, |uniform| {
            let buffers = [&self.table, out, lookups, &self.codes];
            bind(device, &self.resolve_layout, buffers, uniform, &self.records)
        });
        dispatch(encoder, &self.passes.resolve, &group, groups_of_64(count));
        Ok(values)
    }

    /// The bind group of a mark or resolve call: a kept one for the same `key`, else one made
    /// by `make` with the call's parameters (kept, the oldest dropped past [`KEPT_BINDS`]).
    fn bind_for(
        &self,
        device: &wgpu::Device,
        key: BindKey,
        make: impl FnOnce(&wgpu::Buffer) -> wgpu::BindGroup,
    ) -> wgpu::BindGroup {
        self.binds.get_or_make(key, |key| {
            let materials = self.materials.len();
            let params =
                cache_params(key.count, key.in_offset, key.channels, key.out_offset, materials);
            self.binds_made.fetch_add(1, Ordering::Relaxed);
            make(&uniform_buffer(device, &params))
        })
    }

    /// Bind groups made for mark and resolve calls so far. For tests only.
    #[doc(hidden)]
    pub fn bind_groups_made_for_testing(&self) -> u32 {
        self.binds_made.load(Ordering::Relaxed)
    }

    /// Ends the frame: its counters are copied for [`GpuTileCache::read_stats`] (recorded).
    /// Tiles the next frame does not mark are evicted by its `record_decode_missing`.
    pub fn record_end_frame(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.copy_buffer_to_buffer(&self.table, 0, &self.stats, 0, COUNTER_BYTES);
    }

    /// The counters of the last frame whose `record_end_frame` has been submitted (blocks on
    /// the device): `nmat_core::FrameStats`, with `frame` the number of `record_begin_frame`
    /// calls so far.
    pub fn read_stats(&self, device: &wgpu::Device) -> Result<FrameStats, GpuError> {
        let bytes = read_back(device, &self.stats, COUNTER_BYTES)?;
        Ok(self.stats_of(&bytes))
    }

    /// [`GpuTileCache::read_stats`] without blocking (e.g. on WebGPU in a browser): ready once
    /// the device has run that frame's submission and been polled (the browser's event loop,
    /// or natively the caller's `Device::poll`). Await it before submitting the next
    /// `record_end_frame`, which copies into the same buffer.
    pub async fn read_stats_async(&self) -> Result<FrameStats, GpuError> {
        let bytes = read_back_async(&self.stats, COUNTER_BYTES).await?;
        Ok(self.stats_of(&bytes))
    }

    /// The counters in `bytes` (the stats buffer's), with the frames begun so far.
    fn stats_of(&self, bytes: &[u8]) -> FrameStats {
        let w: Vec<u32> =
            bytes.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        let mut head = [0u32; CacheHeader::WORDS];
        for (to, from) in head.iter_mut().zip(w) {
            *to = from;
        }
        let c: CacheHeader = bytemuck::cast(head);
        FrameStats {
            frame: self.frame.load(Ordering::Relaxed),
            marked: c.marked,
            hits: c.hits,
            decoded: c.decoded,
            decoded_texels: c.decoded_texels,
            evicted: c.evicted,
            overflowed: c.overflowed,
            resolve_misses: c.resolve_misses,
        }
    }

    /// Every tile the cache holds and its codes (submits a copy and blocks on the device; for
    /// tests and tools): per tile its key and 16 × 16 texels row by row, each with every channel
    /// of its material (texels past the mip's edge are 0).
    pub fn resident_tiles(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Vec<(TileKey, Vec<u8>)>, GpuError> {
        let table = read_buffer(device, queue, &self.table)?;
        let codes = read_buffer(device, queue, &self.codes)?;
        let word = |i: u32| {
            let at = 4 * i as usize;
            table.get(at..at + 4).map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        };
        let slot_bytes = 4 * self.slot_words as usize;
        let mut tiles = Vec::new();
        for (k, m) in self.materials.iter().enumerate() {
            for (mip, (&(w, h), &first)) in m.mip_sizes.iter().zip(&m.first_page).enumerate() {
                let columns = w.div_ceil(TILE_SIZE);
                for p in 0..columns * h.div_ceil(TILE_SIZE) {
                    let slot = word(first + p) & !PAGE_MARK;
                    if slot == 0 {
                        continue;
                    }
                    let at = (slot as usize - 1) * slot_bytes;
                    let n = (TILE_SIZE * TILE_SIZE * m.channels) as usize;
                    let key = TileKey {
                        material: k as u16,
                        mip: mip as u8,
                        x: (p % columns) as u16,
                        y: (p / columns) as u16,
                    };
                    tiles.push((key, codes.get(at..at + n).unwrap_or_default().to_vec()));
                }
            }
        }
        Ok(tiles)
    }

    /// The WGSL module that resolves lookups from this cache in the engine's own shaders:
    /// `nmat_cache_sample(material, uv, lod, rnd, mode, channels) -> array<f32, 16>` (the
    /// sampling module's `nmat_sample` with a material index; the private `nmat_cache_misses`
    /// says how many texels the cache lacked), bound to two read-only storage buffers where
    /// `bindings` says ([`SampleBindings::layout_entries`], [`GpuTileCache::sample_entries`]).
    /// Include it instead of, not next to, the sampling module (they share names).
    pub fn sample_module(bindings: SampleBindings) -> String {
        let (g, b) = (bindings.group, bindings.first_binding);
        format!(
            "// nmat: the tile cache's bindings (nmat_wgpu::GpuTileCache::sample_module).\n\
             @group({g}) @binding({b}) var<storage, read> nmat_cache_table: array<u32>;\n\
             @group({g}) @binding({}) var<storage, read> nmat_cache_codes: array<u32>;\n\
             fn nmat_cache_word(i: u32) -> u32 {{ return nmat_cache_table[i]; }}\n\
             fn nmat_cache_record_word(material: u32, i: u32) -> u32 {{\n\
             \x20   return nmat_cache_table[NMAT_CACHE_WORDS + NMAT_CACHE_MAT_WORDS * material + i];\n\
             }}\n\
             fn nmat_cache_code_word(i: u32) -> u32 {{ return nmat_cache_codes[i]; }}\n\
             fn nmat_fetch(x: i32, y: i32, mip: u32, mask: u32) {{ nmat_cache_read(x, y, mip, mask); }}\n\n{}\n{}\n{}",
            b + 1,
            layout::cache_table_wgsl(),
            include_str!("shaders/cache_sample.wgsl"),
            include_str!("shaders/filter.wgsl"),
        )
    }

    /// The two bind group entries of [`GpuTileCache::sample_module`]'s bindings.
    pub fn sample_entries(&self, bindings: SampleBindings) -> [wgpu::BindGroupEntry<'_>; 2] {
        [
            wgpu::BindGroupEntry {
                binding: bindings.first_binding,
                resource: self.table.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: bindings.first_binding + 1,
                resource: self.codes.as_entire_binding(),
            },
        ]
    }
}

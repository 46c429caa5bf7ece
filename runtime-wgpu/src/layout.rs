//! Every struct the shaders read, laid out once: `#[repr(C)]` + `bytemuck::Pod` here, and the
//! WGSL side generated from these definitions (never written by hand): the uniform blocks
//! ([`Params`], [`JpegParams`], [`CacheParams`], [`CacheDecodeParams`]) as WGSL `struct`s, and
//! the records of the descriptors in storage buffers (a material's `nmat_desc`, a JPEG
//! material's `jdesc`, the tile cache's table) as word-offset constants, `PREFIX_FIELD` for each
//! field and `PREFIX_WORDS` for the record's size. A shader reads a field as
//! `nmat_desc[record + NMAT_GRID_BITS]`, never as a bare number; the tests below fail if a shader
//! indexes a descriptor with a literal or if WGSL lays a uniform block out otherwise than Rust.

use bytemuck::{Pod, Zeroable};
use std::fmt::Write as _;

/// A struct the shaders read: its fields in order, each `(name, first word, words)`.
pub(crate) trait ShaderLayout: Pod {
    const FIELDS: &'static [(&'static str, usize, usize)];
    /// The struct's size in 32-bit words.
    const WORDS: usize = std::mem::size_of::<Self>() / 4;

    /// The struct as the words a storage buffer holds.
    fn words(&self) -> &[u32] {
        bytemuck::cast_slice(std::slice::from_ref(self))
    }

    /// The struct as little-endian bytes (a uniform buffer's contents).
    fn bytes(&self) -> Vec<u8> {
        words_to_bytes(self.words())
    }
}

/// The `T` at word `at` of `words` (a descriptor being written).
pub(crate) fn read<T: ShaderLayout>(words: &[u32], at: usize) -> T {
    bytemuck::pod_read_unaligned(bytemuck::cast_slice(&words[at..at + T::WORDS]))
}

/// Writes `value` at word `at` of `words`.
pub(crate) fn write<T: ShaderLayout>(words: &mut [u32], at: usize, value: &T) {
    words[at..at + T::WORDS].copy_from_slice(value.words());
}

/// Little-endian bytes of `words` (a buffer's contents).
pub(crate) fn words_to_bytes(words: &[u32]) -> Vec<u8> {
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

/// Declares a `#[repr(C)]` + `Pod` struct of 32-bit words (fields of type `u32`, `[u32; N]` or
/// another such struct, arrays of them) and its [`ShaderLayout`].
macro_rules! shader_layout {
    ($(#[$meta:meta])* struct $name:ident { $($(#[$fmeta:meta])* $field:ident: $ty:ty,)* }) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
        pub(crate) struct $name {
            $($(#[$fmeta])* pub(crate) $field: $ty,)*
        }
        impl ShaderLayout for $name {
            const FIELDS: &'static [(&'static str, usize, usize)] = &[$((
                stringify!($field),
                std::mem::offset_of!($name, $field) / 4,
                std::mem::size_of::<$ty>() / 4,
            ),)*];
        }
    };
}

shader_layout! {
    /// The uniform block of the decode kernels, BC transcoding and BC encoding (decode.wgsl,
    /// bc.wgsl, the tiled and matrix kernels).
    struct Params {
        /// 0: decode `count` requests from `requests`; 1: decode the rectangle (x0, y0, width,
        /// height) of `mip` in row-major order; 2 (the tiled kernels' `tiled_cache`): the tile
        /// cache's decode queue at word `in_offset` of `requests`, `row_words` words a slot.
        mode: u32,
        count: u32,
        mip: u32,
        x0: u32,
        y0: u32,
        width: u32,
        channel_mask: u32,
        out_channels: u32,
        /// BC transcoding (bc.wgsl, bc7.wgsl): 1 (BC1), 4 (BC4), 5 (BC5), 7 (BC7 RGB) or 8 (BC7
        /// RGBA).
        format: u32,
        /// The material channel of each component (byte k = component k).
        components: u32,
        /// The code of each constant component (byte k), and which are constant (bit k).
        constants: u32,
        constant_mask: u32,
        /// The output's row pitch in words.
        row_words: u32,
        /// Every entry point: where the output starts, in words.
        out_offset: u32,
        /// Decoding requests: the word where they start in `requests`.
        in_offset: u32,
        pad: u32,
    }
}

shader_layout! {
    /// The uniform block of the JPEG passes (jpeg.wgsl): [`Params`]'s words but for the five
    /// between `out_channels` and `out_offset`, which say what a JPEG dispatch needs.
    struct JpegParams {
        /// `jpeg_main`: 1: the rectangle (x0, y0, width, height) of `mip`, row-major; 2: the
        /// tile cache's decode queue at `in_offset` (cache.wgsl), every channel into the tiles'
        /// slots; 3: the MCUs the mark pass listed, every channel into their scratch slots.
        /// The request passes (`jpeg_mark`, `jpeg_resolve`, `jpeg_reset`): `count` requests
        /// from word `in_offset` of `requests`.
        mode: u32,
        count: u32,
        mip: u32,
        x0: u32,
        y0: u32,
        width: u32,
        channel_mask: u32,
        out_channels: u32,
        /// The map this dispatch decodes.
        map: u32,
        /// Rectangles: the MCU columns of the MCUs it touches, and how many MCUs (workgroups);
        /// the tile cache: the MCU columns of a tile, and the MCUs of a tile.
        mcu_columns: u32,
        mcu_count: u32,
        /// The clear pass: how many words to zero.
        clear_words: u32,
        /// The tile cache: words per slot; requests: words per scratch slot (an MCU's codes).
        slot_words: u32,
        out_offset: u32,
        in_offset: u32,
        /// Requests: the number of the first (its place in the output).
        first: u32,
        /// Requests: where the list of MCUs and their scratch slots start in the work buffer.
        list_at: u32,
        scratch_at: u32,
        /// To a multiple of four words.
        spare: [u32; 2],
    }
}

impl From<Params> for JpegParams {
    /// The region or request decode `p` as a JPEG dispatch (the JPEG words zero).
    fn from(p: Params) -> JpegParams {
        JpegParams {
            mode: p.mode,
            count: p.count,
            mip: p.mip,
            x0: p.x0,
            y0: p.y0,
            width: p.width,
            channel_mask: p.channel_mask,
            out_channels: p.out_channels,
            out_offset: p.out_offset,
            in_offset: p.in_offset,
            ..JpegParams::default()
        }
    }
}

shader_layout! {
    /// The uniform block of the tile cache's passes (cache.wgsl).
    struct CacheParams {
        /// Lookups (mark, resolve): how many, and the word of the first in the lookups.
        count: u32,
        in_offset: u32,
        /// Resolve: the channels written per lookup (mask), how many, and the first word of the
        /// output.
        channels: u32,
        out_channels: u32,
        out_offset: u32,
        /// The cache's materials (a lookup of another index is no lookup).
        materials: u32,
        pad: [u32; 2],
    }
}

shader_layout! {
    /// The uniform block of the tile cache's decode of a neural material (cache_decode.wgsl).
    struct CacheDecodeParams {
        /// The material's decode queue in the cache's state, and the words of a slot.
        queue_at: u32,
        slot_words: u32,
        pad: [u32; 2],
    }
}

/// Most mips of a material (a 65536² mip 0 has 17; the container allows 16).
pub(crate) const MAX_MIPS: usize = 16;

shader_layout! {
    /// The head of a neural material's descriptor (`nmat_desc`, written by `network_words` in
    /// upload.rs); the `*_at` fields are word offsets into `nmat_desc`.
    struct NeuralHeader {
        width: u32,
        height: u32,
        mip_count: u32,
        channel_count: u32,
        /// 0 wrap, 1 clamp.
        address_mode: u32,
        input_frac_bits: u32,
        pe_frequencies: u32,
        lod_input: u32,
        layer_count: u32,
        level_count: u32,
        grid_count: u32,
        /// [`GridRecord`]s, one per grid.
        grids_at: u32,
        /// [`LevelRecord`]s, one per level.
        levels_at: u32,
        /// [`LayerRecord`]s, one per layer.
        layers_at: u32,
        /// The level of each mip.
        level_of_mip: [u32; MAX_MIPS],
        /// A [`ChannelRange`] per channel (for `nmat_sample`).
        ranges_at: u32,
        /// A 64-bit fingerprint (low word, high word) of the input features generated for the
        /// material's latent layout (features.rs, `key`): generated features check it, and
        /// compute the generic ones for a material of another layout.
        features_key_lo: u32,
        features_key_hi: u32,
        /// A 64-bit fingerprint of the network unrolled for the sampling module on the tables
        /// the descriptor holds (unrolled.rs, `SampleNetwork`), 0 without tables: the sampling
        /// module made for a material checks it, and runs the generic layers for another.
        network_key_lo: u32,
        network_key_hi: u32,
    }
}

shader_layout! {
    /// A latent grid.
    struct GridRecord {
        width: u32,
        height: u32,
        channels: u32,
        bits: u32,
        /// Where its packed latents start in `nmat_latents`, and how many words they take.
        latents_at: u32,
        latent_words: u32,
        /// A [`Quantizer`] per channel.
        quant_at: u32,
        pad: u32,
    }
}

shader_layout! {
    /// A channel's range, f32 bits (`nmat_sample` maps codes into it).
    struct ChannelRange {
        min: u32,
        max: u32,
    }
}

shader_layout! {
    /// A grid channel's dequantization: latent = offset + code · step (i32 bits).
    struct Quantizer {
        offset: u32,
        step: u32,
    }
}

/// Most fusion terms of a level, and most grids of a term's chain.
pub(crate) const MAX_TERMS: usize = 4;
pub(crate) const MAX_CHAIN: usize = 8;

shader_layout! {
    /// A fusion term of a level: its grids, sampled bilinearly (1) or as the four nearest
    /// texels (0).
    struct TermRecord {
        bilinear: u32,
        chain_len: u32,
        grids: [u32; MAX_CHAIN],
    }
}

shader_layout! {
    /// A level of latents: the terms that make a texel's features.
    struct LevelRecord {
        term_count: u32,
        terms: [TermRecord; MAX_TERMS],
    }
}

shader_layout! {
    /// A layer of the network.
    struct LayerRecord {
        inputs: u32,
        outputs: u32,
        out_frac_bits: u32,
        /// 1: hard GELU, 0: ReLU-like (the core's `Activation`).
        hard_gelu: u32,
        /// The weights as one i32 each, row by row, and per row a [`RowConstants`] (the
        /// reference kernel).
        weights_at: u32,
        rows_at: u32,
        /// The tiled and matrix kernels: the weights packed four int8 per word, rows padded;
        /// and per (padded) row a [`RequantRow`].
        packed_at: u32,
        requant_at: u32,
    }
}

shader_layout! {
    /// A row's bias and requantization (the reference kernel; i32 bits).
    struct RowConstants {
        bias: u32,
        multiplier: u32,
        shift: u32,
    }
}

shader_layout! {
    /// A row's requantization as the tiled and matrix kernels compute it (requant.wgsl,
    /// `tiled::row_table`): bias (i32), multiplier m, shift s, the 32-bit path's u and m'
    /// (u = 0: the 64-bit path) and m'/2^u (f32 bits), the saturation range [lo, hi] (i32).
    struct RequantRow {
        bias: u32,
        m: u32,
        s: u32,
        u: u32,
        mp: u32,
        c: u32,
        lo: u32,
        hi: u32,
    }
}

shader_layout! {
    /// A mip's width and height.
    struct MipSize {
        width: u32,
        height: u32,
    }
}

shader_layout! {
    /// The head of a JPEG material's descriptor (`jdesc`, written by `jpeg::upload_words`).
    struct JpegHeader {
        width: u32,
        height: u32,
        mip_count: u32,
        channel_count: u32,
        /// 0 wrap, 1 clamp.
        address_mode: u32,
        map_count: u32,
        /// [`JpegMapRecord`]s, one per map.
        maps_at: u32,
        /// [`JpegStreamRecord`]s, one per map and mip (map-major).
        streams_at: u32,
        /// [`HuffmanRecord`]s, one per table.
        huffman_at: u32,
        pad: [u32; 7],
        mip_sizes: [MipSize; MAX_MIPS],
    }
}

shader_layout! {
    /// A map of a JPEG material.
    struct JpegMapRecord {
        first_channel: u32,
        channel_count: u32,
        luma_h: u32,
        luma_v: u32,
    }
}

shader_layout! {
    /// The stream of one map and mip: byte offsets into the section and table numbers
    /// (`Jpeg::stream_parts`).
    struct JpegStreamRecord {
        index_at: u32,
        dc_at: u32,
        data_at: u32,
        data_len: u32,
        mcus_x: u32,
        mcus_y: u32,
        /// Y, Cb, Cr.
        quant_at: [u32; 3],
        dc_table: [u32; 3],
        ac_table: [u32; 3],
        /// The word of the stream's first MCU in the request passes' table (the work buffer,
        /// `jpeg::JpegMaps`): one word per MCU, row-major.
        table_at: u32,
    }
}

shader_layout! {
    /// A Huffman table's canonical decoding (`huffman_decoding`), as i32 bits, then where its
    /// symbols start in the section and how many there are.
    struct HuffmanRecord {
        maxcode: [u32; 17],
        offset: [u32; 17],
        values_at: u32,
        values: u32,
    }
}

shader_layout! {
    /// The head of the tile cache's table (`GpuTileCache`; cache_sample.wgsl): this frame's
    /// counters (cleared by `record_begin_frame`, read back by `read_stats`), then where the
    /// rest lies. The material records follow it.
    struct CacheHeader {
        marked: u32,
        hits: u32,
        decoded: u32,
        decoded_texels: u32,
        evicted: u32,
        overflowed: u32,
        resolve_misses: u32,
        pad0: u32,
        materials: u32,
        /// [`PageRange`]s: how many, and where they start.
        ranges: u32,
        ranges_at: u32,
        /// One page per tile of every mip of every material, row by row: bit 31 set when the
        /// frame marked the tile, bits 0–30 the slot holding it + 1 (0: not in the cache).
        pages_at: u32,
        pages: u32,
        slot_words: u32,
        slots: u32,
        pad1: u32,
    }
}

shader_layout! {
    /// A material of the tile cache.
    struct CacheMaterial {
        width: u32,
        height: u32,
        mip_count: u32,
        channel_count: u32,
        /// 0 wrap, 1 clamp.
        address_mode: u32,
        pad0: [u32; 3],
        /// The index of each mip's first page.
        first_page: [u32; MAX_MIPS],
        ranges: [ChannelRange; 16],
        pad1: [u32; 8],
    }
}

shader_layout! {
    /// The pages of one mip of one material, in page order (how a page finds its tile).
    struct PageRange {
        first_page: u32,
        /// material << 8 | mip.
        which: u32,
    }
}

shader_layout! {
    /// The head of the tile cache's state (cache.wgsl): the free slots, the tiles marked this
    /// frame and not cached ("new"), the new tiles given a slot. The free slots (a stack) follow
    /// it, then the new tiles' pages (as many as slots), then each material's decode queue.
    struct CacheState {
        free: u32,
        new: u32,
        given: u32,
        pad: [u32; 13],
    }
}

shader_layout! {
    /// The head of a material's decode queue; a [`QueueEntry`] per tile follows it.
    struct QueueHead {
        count: u32,
        pad: [u32; 3],
    }
}

shader_layout! {
    /// A tile to decode: its slot, and mip << 26 | row << 13 | column.
    struct QueueEntry {
        slot: u32,
        key: u32,
    }
}

shader_layout! {
    /// An indirect dispatch's workgroups.
    struct DispatchArgs {
        x: u32,
        y: u32,
        z: u32,
    }
}

shader_layout! {
    /// The tile cache's indirect dispatches (their own buffer, written by the plan and finish
    /// passes): the allocate and clear passes; a [`DecodeArgs`] per material follows.
    struct CacheArgs {
        allocate: DispatchArgs,
        pad0: u32,
        clear: DispatchArgs,
        pad1: u32,
    }
}

shader_layout! {
    /// A material's decode dispatches: one, two and four workgroups per new tile.
    struct DecodeArgs {
        one: DispatchArgs,
        two: DispatchArgs,
        four: DispatchArgs,
        pad: [u32; 3],
    }
}

/// A page's bit 31: the frame marked its tile.
pub(crate) const PAGE_MARK: u32 = 1 << 31;

/// The generated declarations of the tile cache's table (cache_sample.wgsl, part of the module
/// engines include: every name starts with `NMAT_`).
pub(crate) fn cache_table_wgsl() -> String {
    [
        "// nmat: the layout of the tile cache's table (generated from nmat-wgpu's layout.rs).\n"
            .to_string(),
        wgsl_offsets::<CacheHeader>("NMAT_CACHE"),
        wgsl_offsets::<CacheMaterial>("NMAT_CACHE_MAT"),
        wgsl_offsets::<ChannelRange>("NMAT_CACHE_RANGE"),
        wgsl_offsets::<PageRange>("NMAT_CACHE_SPAN"),
        wgsl_offsets::<crate::CacheLookup>("NMAT_LOOKUP"),
        format!("const NMAT_CACHE_MARK: u32 = {PAGE_MARK:#x}u;\n"),
    ]
    .concat()
}

/// The generated declarations of the tile cache's passes (cache.wgsl, cache_decode.wgsl and the
/// JPEG decode of the cache's queue).
pub(crate) fn cache_state_wgsl() -> String {
    [
        wgsl_offsets::<CacheState>("NMAT_CACHE_STATE"),
        wgsl_offsets::<QueueHead>("NMAT_CACHE_QUEUE"),
        wgsl_offsets::<QueueEntry>("NMAT_CACHE_ENTRY"),
        wgsl_offsets::<DispatchArgs>("NMAT_CACHE_DISPATCH"),
        wgsl_offsets::<CacheArgs>("NMAT_CACHE_ARGS"),
        wgsl_offsets::<DecodeArgs>("NMAT_CACHE_DECODE"),
    ]
    .concat()
}

/// Where the tiled, unrolled and matrix kernels write a batch's codes — the dispatch's output, or
/// the tile cache's slots through its queue (batch.wgsl, with the queue's generated
/// declarations).
pub(crate) fn batch_wgsl() -> String {
    cache_state_wgsl() + include_str!("shaders/batch.wgsl")
}

/// `T` as a WGSL `struct` named `name`, every field a `u32` (arrays become `name_k` fields: a
/// uniform block's arrays would take 16 bytes per element in WGSL).
pub(crate) fn wgsl_struct<T: ShaderLayout>(name: &str) -> String {
    let mut s = format!("struct {name} {{\n");
    for &(field, _, words) in T::FIELDS {
        if words == 1 {
            let _ = writeln!(s, "    {field}: u32,");
        } else {
            for k in 0..words {
                let _ = writeln!(s, "    {field}_{k}: u32,");
            }
        }
    }
    s.push_str("}\n");
    s
}

/// `T` as the WGSL struct `name` ([`wgsl_struct`]) and `fn reader(at: u32) -> name`, which reads
/// the record at word `at` of `nmat_desc` through the `PREFIX_*` offsets ([`wgsl_offsets`]) once
/// (padding fields, named `pad`, left 0).
pub(crate) fn wgsl_record_reader<T: ShaderLayout>(
    name: &str,
    reader: &str,
    prefix: &str,
) -> String {
    let mut s = wgsl_struct::<T>(name);
    let _ = writeln!(s, "fn {reader}(at: u32) -> {name} {{\n    var r = {name}();");
    for &(field, _, words) in T::FIELDS.iter().filter(|f| f.0 != "pad") {
        let at = format!("at + {prefix}_{}", field.to_uppercase());
        if words == 1 {
            let _ = writeln!(s, "    r.{field} = nmat_desc[{at}];");
        } else {
            for k in 0..words {
                let _ = writeln!(s, "    r.{field}_{k} = nmat_desc[{at} + {k}u];");
            }
        }
    }
    s.push_str("    return r;\n}\n");
    s
}

/// `T`'s word offsets as WGSL constants: `PREFIX_FIELD` per field and `PREFIX_WORDS`.
pub(crate) fn wgsl_offsets<T: ShaderLayout>(prefix: &str) -> String {
    let mut s = String::new();
    for &(field, at, _) in T::FIELDS {
        let _ = writeln!(s, "const {prefix}_{}: u32 = {at}u;", field.to_uppercase());
    }
    let _ = writeln!(s, "const {prefix}_WORDS: u32 = {}u;", T::WORDS);
    s
}

/// The generated declarations a neural material's descriptor is read with — the records' word
/// offsets, and the grid record's struct and reader — for texel.wgsl and every shader that
/// includes it, the sampling module among them (every name starts with `NMAT_`, `Nmat` or
/// `nmat_`).
pub(crate) fn neural_wgsl() -> String {
    [
        "// nmat: the layout of `nmat_desc` (generated from nmat-wgpu's layout.rs).\n".to_string(),
        wgsl_offsets::<NeuralHeader>("NMAT_DESC"),
        wgsl_offsets::<ChannelRange>("NMAT_RANGE"),
        wgsl_offsets::<GridRecord>("NMAT_GRID"),
        wgsl_offsets::<Quantizer>("NMAT_QUANT"),
        wgsl_offsets::<LevelRecord>("NMAT_LEVEL"),
        wgsl_offsets::<TermRecord>("NMAT_TERM"),
        wgsl_offsets::<LayerRecord>("NMAT_LAYER"),
        wgsl_offsets::<RowConstants>("NMAT_ROW"),
        wgsl_offsets::<RequantRow>("NMAT_REQUANT"),
        wgsl_record_reader::<GridRecord>("NmatGrid", "nmat_grid_record", "NMAT_GRID"),
    ]
    .concat()
}

/// texel.wgsl (the decoder every decode shader and the sampling module include) with the
/// descriptor's layout it reads and the generic `nmat_texel_features` and `nmat_texel_network`
/// (any material).
pub(crate) fn texel_wgsl() -> String {
    texel_wgsl_with(crate::features::GENERIC, crate::unrolled::GENERIC_NETWORK)
}

/// texel.wgsl with `features` and `network`: definitions of `nmat_texel_features` and
/// `nmat_texel_network`, the input features and the network `nmat_decode` computes
/// ([`crate::features`], [`crate::unrolled`]).
pub(crate) fn texel_wgsl_with(features: &str, network: &str) -> String {
    format!("{}\n{}\n{features}\n{network}", neural_wgsl(), include_str!("shaders/texel.wgsl"))
}

/// decode.wgsl (the reference kernel and the bindings every decode kernel shares) with its
/// uniform block.
pub(crate) fn decode_wgsl() -> String {
    format!("{}\n{}", wgsl_struct::<Params>("Params"), include_str!("shaders/decode.wgsl"))
}

/// jpeg.wgsl with its uniform block and the layout of `jdesc`.
pub(crate) fn jpeg_wgsl() -> String {
    [
        wgsl_struct::<JpegParams>("Params"),
        wgsl_offsets::<JpegHeader>("JDESC"),
        wgsl_offsets::<MipSize>("JMIP"),
        wgsl_offsets::<JpegMapRecord>("JMAP"),
        wgsl_offsets::<JpegStreamRecord>("JSTREAM"),
        wgsl_offsets::<HuffmanRecord>("JHUFF"),
        wgsl_offsets::<QueueHead>("NMAT_CACHE_QUEUE"),
        wgsl_offsets::<QueueEntry>("NMAT_CACHE_ENTRY"),
        include_str!("shaders/jpeg.wgsl").to_string(),
    ]
    .join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every shader source of the crate.
    const SHADERS: &[(&str, &str)] = &[
        ("bc.wgsl", include_str!("shaders/bc.wgsl")),
        ("bc7.wgsl", include_str!("shaders/bc7.wgsl")),
        ("cache.wgsl", include_str!("shaders/cache.wgsl")),
        ("cache_decode.wgsl", include_str!("shaders/cache_decode.wgsl")),
        ("cache_lookup.wgsl", include_str!("shaders/cache_lookup.wgsl")),
        ("cache_resolve.wgsl", include_str!("shaders/cache_resolve.wgsl")),
        ("cache_sample.wgsl", include_str!("shaders/cache_sample.wgsl")),
        ("batch.wgsl", include_str!("shaders/batch.wgsl")),
        ("decode.wgsl", include_str!("shaders/decode.wgsl")),
        ("features.wgsl", include_str!("shaders/features.wgsl")),
        ("filter.wgsl", include_str!("shaders/filter.wgsl")),
        ("jpeg.wgsl", include_str!("shaders/jpeg.wgsl")),
        ("matrix.wgsl", include_str!("shaders/matrix.wgsl")),
        ("probe.wgsl", include_str!("shaders/probe.wgsl")),
        ("probe_dot4.wgsl", include_str!("shaders/probe_dot4.wgsl")),
        ("requant.wgsl", include_str!("shaders/requant.wgsl")),
        ("sample.wgsl", include_str!("shaders/sample.wgsl")),
        ("store.wgsl", include_str!("shaders/store.wgsl")),
        ("texel.wgsl", include_str!("shaders/texel.wgsl")),
        ("tiled.wgsl", include_str!("shaders/tiled.wgsl")),
        ("tiled_dot4.wgsl", include_str!("shaders/tiled_dot4.wgsl")),
        ("tiled_i32.wgsl", include_str!("shaders/tiled_i32.wgsl")),
        ("unrolled.wgsl", include_str!("shaders/unrolled.wgsl")),
        ("unrolled_dot4.wgsl", include_str!("shaders/unrolled_dot4.wgsl")),
        ("unrolled_i32.wgsl", include_str!("shaders/unrolled_i32.wgsl")),
    ];

    /// No shader reads a descriptor, the cache's table, state, queues or lookups at a bare number
    /// (`nmat_desc[3]`, `jdesc[lb + 2u]`, `nmat_cache_word(8u)`): every such word is named by a
    /// generated constant, so that a change of layout.rs reaches every reader. Comments are
    /// skipped.
    #[test]
    fn no_shader_indexes_a_descriptor_with_a_literal() {
        let readers = [
            "nmat_desc[",
            "jdesc[",
            "nmat_cache_word(",
            "nmat_cache_record(",
            "nmat_cache_table[",
            "nmat_cache_rw[",
            "nmat_cache_lookups[",
            "nmat_cd_queue[",
        ];
        let mut found = Vec::new();
        for (file, source) in SHADERS {
            for (n, line) in source.lines().enumerate() {
                let code = line.split("//").next().unwrap_or("");
                for reader in readers {
                    for (at, _) in code.match_indices(reader) {
                        let index = &code[at + reader.len()..];
                        let end = index.find([']', ')']).unwrap_or(index.len());
                        let index = &index[..end];
                        // A literal alone, or a literal added to a record's base.
                        let literal = index.split('+').any(|term| {
                            let t = term.trim();
                            !t.is_empty() && t.chars().next().is_some_and(|c| c.is_ascii_digit())
                        });
                        if literal {
                            found.push(format!("{file}:{}: {}", n + 1, line.trim()));
                        }
                    }
                }
            }
        }
        assert!(found.is_empty(), "descriptor words read at a bare number:\n{}", found.join("\n"));
    }

    /// naga (the compiler wgpu runs) lays each generated uniform block out as Rust does: every
    /// member at the byte offset of the Rust field (or array element) it stands for, and the
    /// whole block as large as the Rust struct.
    #[test]
    fn wgsl_lays_the_uniform_blocks_out_as_rust_does() {
        fn check<T: ShaderLayout>(name: &str) {
            let source = format!(
                "{}\n@group(0) @binding(0) var<uniform> u: {name};\n\
                 @compute @workgroup_size(1) fn main() {{ _ = u.{}; }}",
                wgsl_struct::<T>(name),
                T::FIELDS[0].0
            );
            let module = naga::front::wgsl::parse_str(&source)
                .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&source)));
            let mut layouter = naga::proc::Layouter::default();
            layouter.update(module.to_ctx()).expect("layout");
            let (handle, ty) = module
                .types
                .iter()
                .find(|(_, ty)| ty.name.as_deref() == Some(name))
                .expect("the struct");
            let naga::TypeInner::Struct { members, span } = &ty.inner else { panic!("a struct") };
            let mut expected = Vec::new();
            for &(field, at, words) in T::FIELDS {
                for k in 0..words {
                    let member =
                        if words == 1 { field.to_string() } else { format!("{field}_{k}") };
                    expected.push((member, 4 * (at + k) as u32));
                }
            }
            let got: Vec<(String, u32)> =
                members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset)).collect();
            assert_eq!(got, expected, "{name}: member offsets");
            assert_eq!(*span as usize, std::mem::size_of::<T>(), "{name}: size");
            assert_eq!(layouter[handle].size as usize, std::mem::size_of::<T>(), "{name}");
        }
        check::<Params>("Params");
        check::<JpegParams>("Params");
        check::<CacheParams>("NmatCacheParams");
        check::<CacheDecodeParams>("NmatCacheDecode");
    }

    /// Every shader the crate builds without a material (the main decode shader, the BC7
    /// encoder, the JPEG passes, the tile cache's passes and decode, the sampling and cache
    /// sampling modules) parses and validates in naga with the generated declarations (a
    /// constant a shader reads that layout.rs does not generate fails here, on any machine; the
    /// tiled and matrix kernels are validated per material in their own tests and on every
    /// device) and takes no remainder of signed integers (`naga_check::signed_remainders`).
    #[test]
    fn every_shader_validates_with_the_generated_layout() {
        let bindings = crate::SampleBindings { group: 0, first_binding: 0 };
        let sources = [
            ("main", crate::context::shader_source()),
            ("bc7", crate::context::bc7_source()),
            ("jpeg", jpeg_wgsl()),
            ("cache passes", crate::cache::passes_source(1)),
            ("cache resolve", crate::cache::resolve_source(crate::cache::MAX_CACHE_MATERIALS)),
            ("cache decode", crate::cache::decode_source()),
            ("sampling module", bindings.module()),
            ("cache sampling module", crate::GpuTileCache::sample_module(bindings)),
        ];
        for (name, source) in sources {
            crate::naga_check::validate(name, &source);
        }
    }

    /// The JPEG passes read a region or request decode's words where [`Params`] has them: the
    /// words the two blocks share are at the same offsets.
    #[test]
    fn jpeg_params_share_the_decode_words_of_params() {
        let p = Params {
            mode: 1,
            count: 2,
            mip: 3,
            x0: 4,
            y0: 5,
            width: 6,
            channel_mask: 7,
            out_channels: 8,
            format: 9,
            components: 10,
            constants: 11,
            constant_mask: 12,
            row_words: 13,
            out_offset: 14,
            in_offset: 15,
            pad: 0,
        };
        let j = JpegParams::from(p);
        let (pw, jw) = (p.words(), j.words());
        for &(field, at, _) in JpegParams::FIELDS {
            match Params::FIELDS.iter().find(|f| f.0 == field) {
                Some(&(_, p_at, _)) => {
                    assert_eq!(p_at, at, "{field}");
                    assert_eq!(jw[at], pw[p_at], "{field}");
                }
                None => assert_eq!(jw[at], 0, "{field}: a JPEG word starts at zero"),
            }
        }
    }

    /// The records' sizes the shaders step by (a level is 41 words: its term count and four
    /// terms of a mode, a chain length and eight grids).
    #[test]
    fn records_have_the_sizes_the_format_gives_them() {
        assert_eq!(NeuralHeader::WORDS, 35);
        assert_eq!(TermRecord::WORDS, 2 + MAX_CHAIN);
        assert_eq!(LevelRecord::WORDS, 1 + MAX_TERMS * TermRecord::WORDS);
        assert_eq!(JpegHeader::WORDS, 16 + 2 * MAX_MIPS);
        assert_eq!(JpegStreamRecord::WORDS, 16);
        assert_eq!(HuffmanRecord::WORDS, 36);
        let constants = neural_wgsl();
        assert!(constants.contains("const NMAT_DESC_LEVEL_OF_MIP: u32 = 14u;\n"), "{constants}");
        assert!(constants.contains("const NMAT_LEVEL_WORDS: u32 = 41u;\n"), "{constants}");
    }
}

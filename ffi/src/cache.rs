//! The tile cache in C (`nmat_cache_*`): one frame is `nmat_cache_begin_frame`, a
//! `nmat_cache_mark` per lookup, `nmat_cache_decode_missing`, a `nmat_cache_resolve` per lookup
//! (the values `nmat_sample` gives in integer mode), `nmat_cache_end_frame`.

use super::{
    Castable, arg_mut, fail, free_box, guard, handle, mask, nmat_status, request, slice, slice_mut,
    to_boxed_ptr, try_mut, try_ref,
};
use nmat_core::{Decoder, FrameStats, Material, Slot, TileCache, TileKey};

/// A tile cache over a fixed list of materials. Opaque; create with `nmat_cache_create`, destroy
/// with `nmat_cache_free`.
pub struct nmat_cache {
    _private: [u8; 0],
}

/// What a frame did (`nmat_cache_stats`, `nmat_cache_end_frame`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct nmat_frame_stats {
    /// The frame's number (1 for the first `nmat_cache_begin_frame`).
    pub frame: u32,
    /// Distinct tiles marked this frame.
    pub marked: u32,
    /// Of those, tiles already decoded when first marked (kept from the previous frame).
    pub hits: u32,
    /// Tiles decoded this frame.
    pub decoded: u32,
    /// Texels those tiles hold.
    pub decoded_texels: u32,
    /// Tiles dropped: unseen at the end of the frame, or their slot taken for a new tile.
    pub evicted: u32,
    /// New tiles that found no slot (every slot held a tile this frame marked): their lookups
    /// are decoded directly by `nmat_cache_resolve` — correct, slower.
    pub overflowed: u32,
    /// Texels `nmat_cache_resolve` decoded itself because their tile was not in the cache.
    pub resolve_misses: u32,
}

impl From<FrameStats> for nmat_frame_stats {
    fn from(s: FrameStats) -> nmat_frame_stats {
        nmat_frame_stats {
            frame: s.frame,
            marked: s.marked,
            hits: s.hits,
            decoded: s.decoded,
            decoded_texels: s.decoded_texels,
            evicted: s.evicted,
            overflowed: s.overflowed,
            resolve_misses: s.resolve_misses,
        }
    }
}

/// The one owner behind `nmat_cache*`: the cache with its memory, and the prepared decoder of
/// each of its materials. The material handles are the caller's and outlive it (the contract of
/// `nmat_cache_create`), so their references are held as `'static`.
pub(crate) struct Cache {
    cache: TileCache<'static, Vec<Slot>, Vec<u8>>,
    decoders: Vec<&'static Decoder>,
}

impl Castable for nmat_cache {
    type RustType = Cache;
}

/// Creates a cache of `tiles` tiles (16 × 16 texels each, every channel, 8-bit codes) over the
/// `material_count` materials at `materials` (then named by their index, 0 …). Its memory is
/// allocated here, once: `tiles` × (256 × the largest channel count + 24) bytes. The materials
/// must stay open until `nmat_cache_free`. At most 64 materials; `tiles` ≥ 1.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_create(
    materials: *const *const super::nmat_material,
    material_count: usize,
    tiles: usize,
    out: *mut *mut nmat_cache,
) -> nmat_status {
    guard(|| {
        let out = arg_mut(out)?;
        *out = std::ptr::null_mut();
        let handles = slice(materials, material_count)?;
        let mut list: Vec<&'static Material<'static>> = Vec::with_capacity(handles.len());
        let mut decoders: Vec<&'static Decoder> = Vec::with_capacity(handles.len());
        for &h in handles {
            let h = handle(h)?;
            // SAFETY: the contract of this function: every material handle stays open (and so
            // its parsed material and decoder stay where they are, unchanged) until
            // `nmat_cache_free`, which drops these references first.
            list.push(unsafe { &*std::ptr::from_ref(h.material()).cast::<Material<'static>>() });
            // SAFETY: as above.
            decoders.push(unsafe { &*std::ptr::from_ref(&h.decoder) });
        }
        let slot_bytes = TileCache::<Vec<Slot>, Vec<u8>>::slot_bytes(&list);
        let bytes = tiles.checked_mul(slot_bytes).ok_or(nmat_status::NMAT_SIZE_OVERFLOW)?;
        let mut slots = Vec::new();
        let mut texels = Vec::new();
        if slots.try_reserve_exact(tiles).is_err() || texels.try_reserve_exact(bytes).is_err() {
            return Err(nmat_status::NMAT_OUT_OF_MEMORY);
        }
        slots.resize(tiles, Slot::EMPTY);
        texels.resize(bytes, 0);
        let cache = TileCache::new(&list, slots, texels).map_err(fail)?;
        *out = to_boxed_ptr(Cache { cache, decoders });
        Ok(())
    })
}

/// Destroys a cache (before its materials). NULL is accepted and ignored.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_free(cache: *mut nmat_cache) {
    let _ = guard(|| {
        free_box(cache);
        Ok(())
    });
}

/// Starts a frame: its counters start at zero.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_begin_frame(cache: *mut nmat_cache) -> nmat_status {
    guard(|| {
        try_mut(cache)?.cache.begin_frame();
        Ok(())
    })
}

/// Marks the tiles that the lookup `nmat_cache_resolve(cache, material, u, v, lod, filter,
/// random, …)` will read: every texel of the filter's footprint (a bilinear lookup marks the
/// neighbour tiles it straddles, a trilinear one those of both mips). `random` as in
/// `nmat_sample`.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_mark(
    cache: *mut nmat_cache,
    material: u32,
    u: f32,
    v: f32,
    lod: f32,
    filter: u32,
    random: *const f32,
) -> nmat_status {
    guard(|| {
        let c = try_mut(cache)?;
        let req = request(u, v, lod, filter, random)?;
        c.cache.mark(material as usize, &req).map_err(fail)
    })
}

/// Marks the tile of texel (x, y) of `mip` (coordinates wrap or clamp by the material's address
/// mode; a mip beyond the chain is `NMAT_BAD_ARGUMENT`).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_mark_texel(
    cache: *mut nmat_cache,
    material: u32,
    x: i64,
    y: i64,
    mip: u32,
) -> nmat_status {
    guard(|| try_mut(cache)?.cache.mark_texel(material as usize, x, y, mip).map_err(fail))
}

/// One tile: material (its index in the cache), mip, and tile column and row (texel x / 16,
/// y / 16), as `nmat_cache_footprint` lists them.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct nmat_tile_key {
    pub material: u16,
    pub mip: u8,
    pub x: u16,
    pub y: u16,
}

impl From<TileKey> for nmat_tile_key {
    fn from(k: TileKey) -> nmat_tile_key {
        nmat_tile_key { material: k.material, mip: k.mip, x: k.x, y: k.y }
    }
}

impl From<nmat_tile_key> for TileKey {
    fn from(k: nmat_tile_key) -> TileKey {
        TileKey { material: k.material, mip: k.mip, x: k.x, y: k.y }
    }
}

/// Lists in `out` (room for `out_len`, 8 always suffice) the tiles the lookup
/// `nmat_cache_resolve(cache, material, u, v, lod, filter, random, …)` reads, and their number in
/// `*count`; marks nothing. Any number of threads may call it at once (like
/// `nmat_cache_resolve`), so a frame's footprints can be found in parallel and marked with one
/// `nmat_cache_mark_tiles`.
#[unsafe(no_mangle)]
#[allow(clippy::too_many_arguments)] // the lookup of nmat_cache_resolve, and where the keys go
pub extern "C" fn nmat_cache_footprint(
    cache: *const nmat_cache,
    material: u32,
    u: f32,
    v: f32,
    lod: f32,
    filter: u32,
    random: *const f32,
    out: *mut nmat_tile_key,
    out_len: usize,
    count: *mut usize,
) -> nmat_status {
    guard(|| {
        let c = try_ref(cache)?;
        let (out, count) = (slice_mut(out, out_len)?, arg_mut(count)?);
        let req = request(u, v, lod, filter, random)?;
        let keys = c.cache.footprint(material as usize, &req).map_err(fail)?;
        if out.len() < keys.len() {
            return Err(nmat_status::NMAT_BUFFER_TOO_SMALL);
        }
        for (o, &k) in out.iter_mut().zip(&keys) {
            *o = k.into();
        }
        *count = keys.len();
        Ok(())
    })
}

/// Marks `count` tiles listed by `nmat_cache_footprint` (repeats count once per frame). The
/// tiles already cached are marked first, so a full cache gives up only tiles none of `keys`
/// needs. A key the cache's materials do not have is `NMAT_BAD_ARGUMENT`, and then nothing is
/// marked.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_mark_tiles(
    cache: *mut nmat_cache,
    keys: *const nmat_tile_key,
    count: usize,
) -> nmat_status {
    guard(|| {
        let c = try_mut(cache)?;
        let keys: Vec<TileKey> = slice(keys, count)?.iter().map(|&k| k.into()).collect();
        c.cache.mark_tiles(&keys).map_err(fail)
    })
}

/// Decodes every marked tile not decoded yet, on `threads` threads (0: one per CPU); writes how
/// many to `*decoded` (may be NULL). On an error the other tiles are still decoded; a tile that
/// failed stays undecoded and its lookups decode directly.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_decode_missing(
    cache: *mut nmat_cache,
    threads: u32,
    decoded: *mut u32,
) -> nmat_status {
    guard(|| {
        let c = try_mut(cache)?;
        let decoders = &c.decoders;
        let jobs: Vec<_> = c.cache.pending().collect();
        let threads = match threads {
            0 => std::thread::available_parallelism().map_or(1, usize::from),
            n => n as usize,
        };
        let threads = threads.min(jobs.len()).max(1);
        let mut parts: Vec<Vec<_>> = (0..threads).map(|_| Vec::new()).collect();
        for (k, job) in jobs.into_iter().enumerate() {
            parts[k % threads].push(job);
        }
        let run = |part: Vec<nmat_core::PendingTile<'_, '_>>| {
            let mut result = (0u32, None);
            for job in part {
                let d = decoders.get(usize::from(job.key().material));
                match d.map(|d| job.decode_with(d)) {
                    Some(Ok(())) => result.0 += 1,
                    Some(Err(e)) => {
                        result.1.get_or_insert(e);
                    }
                    None => {}
                }
            }
            result
        };
        let results: Vec<(u32, Option<nmat_core::Error>)> = if threads == 1 {
            parts.into_iter().map(run).collect()
        } else {
            std::thread::scope(|s| {
                let running: Vec<_> =
                    parts.into_iter().map(|part| s.spawn(move || run(part))).collect();
                // A panic on a decoding thread reaches `guard` (NMAT_INTERNAL_ERROR).
                let joined = running.into_iter().map(|t| t.join());
                joined.map(|r| r.unwrap_or_else(|p| std::panic::resume_unwind(p))).collect()
            })
        };
        if !decoded.is_null() {
            *arg_mut(decoded)? = results.iter().map(|r| r.0).sum();
        }
        match results.into_iter().find_map(|r| r.1) {
            Some(e) => Err(fail(e)),
            None => Ok(()),
        }
    })
}

/// The filtered lookup of `nmat_sample` in integer mode (`NMAT_MODE_INTEGER`), from the cache:
/// the same values to the bit. Texels whose tile is missing are decoded directly. Any number of
/// threads may resolve from one cache at once (but not while it is marked, decoded or ended).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_resolve(
    cache: *const nmat_cache,
    material: u32,
    u: f32,
    v: f32,
    lod: f32,
    filter: u32,
    random: *const f32,
    channel_mask: u32,
    out: *mut f32,
    out_len: usize,
) -> nmat_status {
    guard(|| {
        let c = try_ref(cache)?;
        let m = c.cache.material(material as usize).map_err(fail)?;
        let out = slice_mut(out, out_len)?;
        let (channels, _) = mask(m, channel_mask)?;
        let req = nmat_core::SampleRequest { channels, ..request(u, v, lod, filter, random)? };
        c.cache.resolve(material as usize, &req, out).map(|_| ()).map_err(fail)
    })
}

/// This frame's counters so far.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_stats(
    cache: *const nmat_cache,
    out: *mut nmat_frame_stats,
) -> nmat_status {
    guard(|| {
        let c = try_ref(cache)?;
        *arg_mut(out)? = c.cache.stats().into();
        Ok(())
    })
}

/// Ends the frame: every tile it did not mark is evicted. Writes the frame's counters to `*out`
/// (may be NULL).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_end_frame(
    cache: *mut nmat_cache,
    out: *mut nmat_frame_stats,
) -> nmat_status {
    guard(|| {
        let stats = try_mut(cache)?.cache.end_frame();
        if !out.is_null() {
            *arg_mut(out)? = stats.into();
        }
        Ok(())
    })
}

// The thread-safety promise of `nmat_cache_resolve`: a compile-time fact.
const _: fn() = || {
    fn shareable<T: Send + Sync>() {}
    shareable::<Cache>();
};

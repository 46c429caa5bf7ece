//! The tile cache in C (`nmat_cache_*`): one frame is `nmat_cache_begin_frame`, a
//! `nmat_cache_mark` per lookup, `nmat_cache_decode_missing`, a `nmat_cache_resolve` per lookup
//! (the values `nmat_sample` gives in integer mode), `nmat_cache_end_frame`.
//!
//! Threads: the calls that change the cache (begin_frame, mark, mark_texel, mark_tiles,
//! decode_missing, end_frame) need it to themselves; footprint, resolve and stats only read it and
//! may run together. C cannot be made to keep that rule, so every call takes the cache through
//! [`Users`], a reader-writer lock that never waits: a call that would overlap where it must not
//! returns `NMAT_CACHE_BUSY` and does nothing, instead of racing.

use crate::boundary::boundary;
use crate::decode::mask;
use crate::material::{Handle, nmat_material};
use crate::pointers::{
    Castable, OwnershipBox, arg_mut, clone_arc, free_box, slice, slice_mut, to_boxed_ptr, try_ref,
};
use crate::sample::request;
use crate::status::{fail, guard, nmat_status, set_last_error};
use nmat_core::{Decoder, FrameStats, Material, Slot, TileCache, TileKey};
use std::cell::UnsafeCell;
use std::ops::{Deref, DerefMut};
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};

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

/// The one owner behind `nmat_cache*`: the cache's state, reached only through [`ExclusiveUse`]
/// and [`SharedUse`], and the count of the calls using it that those keep. C callers get a
/// shared reference to it and nothing more: a call that changes the state takes `users` first,
/// through that shared reference, and only then makes its `&mut` to `inner`.
pub(crate) struct Cache {
    users: Users,
    inner: UnsafeCell<Inner>,
}

self_cell::self_cell!(
    /// The cache's materials, one reference to each handle (so C may free its own handles
    /// first), and the state that borrows them.
    struct Inner {
        owner: Vec<Arc<Handle>>,
        #[covariant]
        dependent: State,
    }
);

/// The cache with its memory, and the prepared decoder of each of its materials.
struct State<'m> {
    cache: TileCache<'m, Vec<Slot>, Vec<u8>>,
    decoders: Vec<&'m Decoder>,
}

impl Inner {
    /// The state, to read.
    fn state(&self) -> &State<'_> {
        self.borrow_dependent()
    }

    /// The state, to change.
    fn change<R>(&mut self, f: impl for<'m> FnOnce(&mut State<'m>) -> R) -> R {
        self.with_dependent_mut(|_, state| f(state))
    }
}

impl Castable for nmat_cache {
    type Ownership = OwnershipBox;
    type RustType = Cache;
}

/// Who is using a cache: 0 nobody, [`Users::EXCLUSIVE`] one call that changes it, else that many
/// calls that read it. Taken with one atomic read-modify-write on entry and given back on exit
/// (by the guards' `Drop`, so also on an error or a panic); a call that cannot take it is refused,
/// never kept waiting: overlapping calls are the caller's bug, and a frame must not stall on it.
#[derive(Debug, Default)]
struct Users(AtomicU32);

impl Users {
    const EXCLUSIVE: u32 = u32::MAX;

    /// Takes the cache alone: only when nobody uses it. `Acquire` pairs with the `Release` of the
    /// previous users' exits, so their writes are visible to this call.
    fn try_exclusive(&self) -> bool {
        self.0.compare_exchange(0, Users::EXCLUSIVE, Ordering::Acquire, Ordering::Relaxed).is_ok()
    }

    fn release_exclusive(&self) {
        self.0.store(0, Ordering::Release);
    }

    /// Joins the readers: only when no call that changes the cache runs (and fewer than
    /// 2^32 − 2 readers do).
    fn try_shared(&self) -> bool {
        let join = |n: u32| n.checked_add(1).filter(|&joined| joined != Users::EXCLUSIVE);
        self.0.fetch_update(Ordering::Acquire, Ordering::Relaxed, join).is_ok()
    }

    fn release_shared(&self) {
        self.0.fetch_sub(1, Ordering::Release);
    }
}

/// A call that changes the cache, with `&mut` access to it until dropped.
struct ExclusiveUse<'a> {
    owner: &'a Cache,
}

/// A call that reads the cache, beside any number of others.
struct SharedUse<'a> {
    owner: &'a Cache,
}

fn busy(call: &str, rule: &str) -> nmat_status {
    set_last_error(format!("another thread is using this cache: {call} {rule}"));
    nmat_status::NMAT_CACHE_BUSY
}

/// The cache behind `p` for `call`, a call that changes it: `NMAT_CACHE_BUSY` while any other
/// call uses it.
fn exclusive<'a>(p: *mut nmat_cache, call: &str) -> Result<ExclusiveUse<'a>, nmat_status> {
    // Only a shared reference to the owner here: another thread may hold `&mut Inner` right now,
    // inside the `UnsafeCell`, which a shared reference to the owner does not claim.
    let owner = try_ref(p.cast_const())?;
    if !owner.users.try_exclusive() {
        return Err(busy(call, "changes the cache and must not overlap with any other call on it"));
    }
    Ok(ExclusiveUse { owner })
}

/// The cache behind `p` for `call`, a call that reads it: `NMAT_CACHE_BUSY` while a call that
/// changes it runs.
fn shared<'a>(p: *const nmat_cache, call: &str) -> Result<SharedUse<'a>, nmat_status> {
    let owner = try_ref(p)?;
    if !owner.users.try_shared() {
        return Err(busy(
            call,
            "may run beside other reading calls, but not while a call that changes the cache \
             (begin_frame, mark, mark_texel, mark_tiles, decode_missing, end_frame) runs",
        ));
    }
    Ok(SharedUse { owner })
}

impl Deref for ExclusiveUse<'_> {
    type Target = Inner;
    fn deref(&self) -> &Inner {
        // SAFETY: `users` is `EXCLUSIVE` while this guard lives (taken in `exclusive`, given back
        // only by its `Drop`), so no other guard, and no other reference to `inner`, exists.
        unsafe { &*self.owner.inner.get() }
    }
}

impl DerefMut for ExclusiveUse<'_> {
    fn deref_mut(&mut self) -> &mut Inner {
        // SAFETY: as for `deref`; the `&mut` borrows this guard, so it ends before the guard
        // gives the cache back.
        unsafe { &mut *self.owner.inner.get() }
    }
}

impl Drop for ExclusiveUse<'_> {
    fn drop(&mut self) {
        self.owner.users.release_exclusive();
    }
}

impl Deref for SharedUse<'_> {
    type Target = Inner;
    fn deref(&self) -> &Inner {
        // SAFETY: `users` counts this guard while it lives, so no `ExclusiveUse` (the only source
        // of `&mut Inner`) can exist; other readers hold shared references only.
        unsafe { &*self.owner.inner.get() }
    }
}

impl Drop for SharedUse<'_> {
    fn drop(&mut self) {
        self.owner.users.release_shared();
    }
}

// SAFETY: `inner` is reached only through the guards above, which `users` keeps to one
// `ExclusiveUse` or any number of `SharedUse`s at a time (a reader-writer lock); `Inner` is
// `Sync` (checked at the end of this file), so `&Inner` on several threads is sound.
unsafe impl Sync for Cache {}

/// Creates a cache of `tiles` tiles (16 × 16 texels each, every channel, 8-bit codes) over the
/// `material_count` materials at `materials` (then named by their index, 0 …). Its memory is
/// allocated here, once: `tiles` × (256 × the largest channel count + 24) bytes. The cache holds
/// its own reference to each material: the caller may free its handles before the cache (the
/// bytes of a borrowed material stay in use until the cache is freed). At most 64 materials;
/// `tiles` from 1 to 2^32 − 2 (`NMAT_BAD_ARGUMENT` otherwise, naming the limit, before anything
/// is allocated); `NMAT_OUT_OF_MEMORY` when the memory cannot be allocated.
///
/// Threads: the calls that change the cache (`nmat_cache_begin_frame`, `_mark`, `_mark_texel`,
/// `_mark_tiles`, `_decode_missing`, `_end_frame`) need it to themselves; `nmat_cache_footprint`,
/// `_resolve` and `_stats` may run on any number of threads at once, but not during one of those.
/// A call that breaks this rule is detected and returns `NMAT_CACHE_BUSY` without doing anything
/// (the other call goes on unharmed). `nmat_cache_free` must not overlap with any call.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_create(
    materials: *const *const nmat_material,
    material_count: usize,
    tiles: usize,
    out: *mut *mut nmat_cache,
) -> nmat_status {
    guard(|| {
        let out = arg_mut(out)?;
        *out = std::ptr::null_mut();
        let handles = slice(materials, material_count)?;
        let owned = handles.iter().map(|&h| clone_arc(h)).collect::<Result<Vec<_>, _>>()?;
        // Checks the tile count (`TileCache::memory_for`) before it allocates, fallibly.
        let inner = Inner::try_new(owned, |owned| {
            let list: Vec<&Material<'_>> = owned.iter().map(|h| h.material()).collect();
            let decoders = owned.iter().map(|h| &h.decoder).collect();
            TileCache::with_capacity(&list, tiles).map(|cache| State { cache, decoders })
        })
        .map_err(fail)?;
        let inner = UnsafeCell::new(inner);
        *out = to_boxed_ptr(Cache { users: Users::default(), inner });
        Ok(())
    })
}

/// Destroys a cache, and gives back its references to its materials. NULL is accepted and
/// ignored.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_free(cache: *mut nmat_cache) {
    boundary(|| free_box(cache));
}

/// Starts a frame: its counters start at zero. `NMAT_CACHE_BUSY` if another call uses the cache.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_begin_frame(cache: *mut nmat_cache) -> nmat_status {
    guard(|| {
        exclusive(cache, "nmat_cache_begin_frame")?.change(|s| s.cache.begin_frame());
        Ok(())
    })
}

/// Marks the tiles that the lookup `nmat_cache_resolve(cache, material, u, v, lod, filter,
/// random, …)` will read: every texel of the filter's footprint (a bilinear lookup marks the
/// neighbour tiles it straddles, a trilinear one those of both mips). `random` as in
/// `nmat_sample` (aligned to 4 bytes, else `NMAT_MISALIGNED_ARGUMENT`). Changes the cache: one
/// call at a time, `NMAT_CACHE_BUSY` if another call uses the cache.
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
        let mut c = exclusive(cache, "nmat_cache_mark")?;
        let req = request(u, v, lod, filter, random)?;
        c.change(|s| s.cache.mark(material as usize, &req)).map_err(fail)
    })
}

/// Marks the tile of texel (x, y) of `mip` (coordinates wrap or clamp by the material's address
/// mode; a mip beyond the chain is `NMAT_BAD_ARGUMENT`). `NMAT_CACHE_BUSY` if another call uses
/// the cache.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_mark_texel(
    cache: *mut nmat_cache,
    material: u32,
    x: i64,
    y: i64,
    mip: u32,
) -> nmat_status {
    guard(|| {
        let mut c = exclusive(cache, "nmat_cache_mark_texel")?;
        c.change(|s| s.cache.mark_texel(material as usize, x, y, mip)).map_err(fail)
    })
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
/// `nmat_cache_mark_tiles`; but not while a call changes the cache (`NMAT_CACHE_BUSY`). `out`
/// (and `random`) must be aligned for their types (`NMAT_MISALIGNED_ARGUMENT`): 2 bytes for
/// `nmat_tile_key`, 4 for `float`.
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
        let c = shared(cache, "nmat_cache_footprint")?;
        let (out, count) = (slice_mut(out, out_len)?, arg_mut(count)?);
        let req = request(u, v, lod, filter, random)?;
        let keys = c.state().cache.footprint(material as usize, &req).map_err(fail)?;
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
/// marked. `keys` must be aligned to 2 bytes (`NMAT_MISALIGNED_ARGUMENT`). `NMAT_CACHE_BUSY` if
/// another call uses the cache.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_mark_tiles(
    cache: *mut nmat_cache,
    keys: *const nmat_tile_key,
    count: usize,
) -> nmat_status {
    guard(|| {
        let mut c = exclusive(cache, "nmat_cache_mark_tiles")?;
        let keys: Vec<TileKey> = slice(keys, count)?.iter().map(|&k| k.into()).collect();
        c.change(|s| s.cache.mark_tiles(&keys)).map_err(fail)
    })
}

/// Decodes every marked tile not decoded yet, on `threads` threads (0: one per CPU); writes how
/// many to `*decoded` (may be NULL). On an error the other tiles are still decoded; a tile that
/// failed stays undecoded and its lookups decode directly. `NMAT_CACHE_BUSY` if another call
/// uses the cache (the threads here are its own).
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_decode_missing(
    cache: *mut nmat_cache,
    threads: u32,
    decoded: *mut u32,
) -> nmat_status {
    guard(|| {
        let mut c = exclusive(cache, "nmat_cache_decode_missing")?;
        // Checked before the work, so a bad pointer is refused with nothing done.
        let decoded = if decoded.is_null() { None } else { Some(arg_mut(decoded)?) };
        let results = c.change(|state| decode_pending(state, threads));
        if let Some(decoded) = decoded {
            *decoded = results.iter().map(|r| r.0).sum();
        }
        match results.into_iter().find_map(|r| r.1) {
            Some(e) => Err(fail(e)),
            None => Ok(()),
        }
    })
}

/// Decodes the tiles marked and missing on `threads` threads (0: one per core): per thread the
/// tiles decoded and the first error.
fn decode_pending(state: &mut State<'_>, threads: u32) -> Vec<(u32, Option<nmat_core::Error>)> {
    let decoders = &state.decoders;
    let jobs: Vec<_> = state.cache.pending().collect();
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
    if threads == 1 {
        parts.into_iter().map(run).collect()
    } else {
        std::thread::scope(|s| {
            let running: Vec<_> =
                parts.into_iter().map(|part| s.spawn(move || run(part))).collect();
            // A panic on a decoding thread reaches `guard` (NMAT_INTERNAL_ERROR).
            let joined = running.into_iter().map(|t| t.join());
            joined.map(|r| r.unwrap_or_else(|p| std::panic::resume_unwind(p))).collect()
        })
    }
}

/// The filtered lookup of `nmat_sample` in integer mode (`NMAT_MODE_INTEGER`), from the cache:
/// the same values to the bit. Texels whose tile is missing are decoded directly. Any number of
/// threads may resolve from one cache at once, but not while a call changes it (marks, decodes,
/// begins or ends a frame): then `NMAT_CACHE_BUSY`. `out` (and `random`) are `float`s, aligned to
/// 4 bytes (`NMAT_MISALIGNED_ARGUMENT` otherwise).
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
        let c = shared(cache, "nmat_cache_resolve")?;
        let state = c.state();
        let m = state.cache.material(material as usize).map_err(fail)?;
        let out = slice_mut(out, out_len)?;
        let (channels, _) = mask(m, channel_mask)?;
        let req = nmat_core::SampleRequest { channels, ..request(u, v, lod, filter, random)? };
        state.cache.resolve(material as usize, &req, out).map(|_| ()).map_err(fail)
    })
}

/// This frame's counters so far. May run beside `nmat_cache_resolve` and `_footprint`;
/// `NMAT_CACHE_BUSY` while a call changes the cache.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_stats(
    cache: *const nmat_cache,
    out: *mut nmat_frame_stats,
) -> nmat_status {
    guard(|| {
        let c = shared(cache, "nmat_cache_stats")?;
        *arg_mut(out)? = c.state().cache.stats().into();
        Ok(())
    })
}

/// Ends the frame: every tile it did not mark is evicted. Writes the frame's counters to `*out`
/// (may be NULL). `NMAT_CACHE_BUSY` if another call uses the cache.
#[unsafe(no_mangle)]
pub extern "C" fn nmat_cache_end_frame(
    cache: *mut nmat_cache,
    out: *mut nmat_frame_stats,
) -> nmat_status {
    guard(|| {
        let mut c = exclusive(cache, "nmat_cache_end_frame")?;
        // Checked before the frame ends, so a bad pointer is refused with nothing done.
        let out = if out.is_null() { None } else { Some(arg_mut(out)?) };
        let stats = c.change(|s| s.cache.end_frame());
        if let Some(out) = out {
            *out = stats.into();
        }
        Ok(())
    })
}

// The thread-safety promise of `nmat_cache_resolve`, and what `Sync for Cache` relies on:
// compile-time facts.
const _: fn() = || {
    fn shareable<T: Send + Sync>() {}
    shareable::<Inner>();
    shareable::<Cache>();
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{nmat_material, nmat_material_free, nmat_material_open, nmat_status::*};
    use std::ptr::{null, null_mut};

    fn open(name: &str) -> *mut nmat_material {
        let path = format!("{}/../tests/fixtures/{name}", env!("CARGO_MANIFEST_DIR"));
        let bytes = std::fs::read(path).unwrap();
        let mut m = null_mut();
        assert_eq!(nmat_material_open(bytes.as_ptr(), bytes.len(), &mut m), NMAT_OK);
        m
    }

    fn last_error() -> String {
        let mut buf = [0u8; 512];
        let n = crate::nmat_last_error(buf.as_mut_ptr(), buf.len());
        String::from_utf8_lossy(&buf[..n.min(buf.len()) - 1]).into_owned()
    }

    #[test]
    fn users_admit_one_call_that_changes_or_many_that_read() {
        let users = Users::default();
        assert!(users.try_shared() && users.try_shared());
        assert!(!users.try_exclusive());
        users.release_shared();
        assert!(!users.try_exclusive());
        users.release_shared();
        assert!(users.try_exclusive());
        assert!(!users.try_exclusive() && !users.try_shared());
        users.release_exclusive();
        assert!(users.try_shared());
    }

    fn lookup(cache: *mut nmat_cache, out: &mut [f32; 16]) -> nmat_status {
        nmat_cache_resolve(cache, 0, 0.3, 0.6, 0.0, 1, null(), 0x7, out.as_mut_ptr(), 16)
    }

    #[test]
    fn overlapping_calls_are_refused_and_the_cache_is_given_back_after_errors_and_panics() {
        let m = open("ntc_rgb_64.nmat");
        let list = [m.cast_const()];
        let mut cache = null_mut();
        assert_eq!(nmat_cache_create(list.as_ptr(), 1, 16, &mut cache), NMAT_OK);
        let (mut out, mut stats) = ([0f32; 16], nmat_frame_stats::default());
        let mut keys = [nmat_tile_key::default(); 8];
        let mut count = 0;
        {
            let _changing = exclusive(cache, "a test").unwrap();
            assert_eq!(nmat_cache_begin_frame(cache), NMAT_CACHE_BUSY);
            assert_eq!(nmat_cache_mark(cache, 0, 0.5, 0.5, 0.0, 1, null()), NMAT_CACHE_BUSY);
            assert!(last_error().contains("nmat_cache_mark changes the cache"), "{}", last_error());
            assert_eq!(nmat_cache_mark_texel(cache, 0, 1, 1, 0), NMAT_CACHE_BUSY);
            assert_eq!(nmat_cache_mark_tiles(cache, keys.as_ptr(), 1), NMAT_CACHE_BUSY);
            assert_eq!(nmat_cache_decode_missing(cache, 1, null_mut()), NMAT_CACHE_BUSY);
            assert_eq!(nmat_cache_end_frame(cache, null_mut()), NMAT_CACHE_BUSY);
            assert_eq!(lookup(cache, &mut out), NMAT_CACHE_BUSY);
            assert!(last_error().contains("nmat_cache_resolve may run beside"), "{}", last_error());
            assert_eq!(nmat_cache_stats(cache, &mut stats), NMAT_CACHE_BUSY);
        }
        {
            let _reading = shared(cache, "a test").unwrap();
            assert_eq!(lookup(cache, &mut out), NMAT_OK);
            let fp = nmat_cache_footprint(
                cache,
                0,
                0.3,
                0.6,
                0.0,
                1,
                null(),
                keys.as_mut_ptr(),
                8,
                &mut count,
            );
            assert_eq!(fp, NMAT_OK);
            assert_eq!(nmat_cache_stats(cache, &mut stats), NMAT_OK);
            assert_eq!(nmat_cache_mark_tiles(cache, keys.as_ptr(), count), NMAT_CACHE_BUSY);
            assert_eq!(nmat_cache_begin_frame(cache), NMAT_CACHE_BUSY);
        }
        // Given back after a refusal and after a panic inside a call.
        assert_eq!(nmat_cache_mark(cache, 9, 0.5, 0.5, 0.0, 1, null()), NMAT_BAD_ARGUMENT);
        // (The panic's message on stderr is expected.)
        let panicking = guard(|| {
            let _changing = exclusive(cache, "a test")?;
            panic!("a bug inside a call that changes the cache");
        });
        assert_eq!(panicking, NMAT_INTERNAL_ERROR);
        assert_eq!(nmat_cache_begin_frame(cache), NMAT_OK);
        assert_eq!(nmat_cache_mark_tiles(cache, keys.as_ptr(), count), NMAT_OK);
        let mut decoded = 0;
        assert_eq!(nmat_cache_decode_missing(cache, 2, &mut decoded), NMAT_OK);
        assert_eq!(lookup(cache, &mut out), NMAT_OK);
        assert_eq!(nmat_cache_end_frame(cache, &mut stats), NMAT_OK);
        assert_eq!(
            (stats.marked as usize, stats.decoded, stats.resolve_misses),
            (count, decoded, 0)
        );
        nmat_cache_free(cache);
        nmat_material_free(m);
    }

    #[test]
    fn misaligned_typed_buffers_and_tile_counts_beyond_the_limit_are_refused() {
        let m = open("ntc_rgb_64.nmat");
        let list = [m.cast_const()];
        let mut cache = null_mut();
        for tiles in [u32::MAX as usize, u32::MAX as usize + 1, usize::MAX] {
            assert_eq!(nmat_cache_create(list.as_ptr(), 1, tiles, &mut cache), NMAT_BAD_ARGUMENT);
            assert!(last_error().contains("limit 4294967294"), "{}", last_error());
        }
        assert_eq!(nmat_cache_create(list.as_ptr(), 1, 4, &mut cache), NMAT_OK);
        let mut words = [0u32; 48];
        let odd = words.as_mut_ptr().cast::<u8>().wrapping_add(1);
        let r = nmat_cache_resolve(cache, 0, 0.5, 0.5, 0.0, 0, null(), 0x7, odd.cast(), 16);
        assert_eq!(r, NMAT_MISALIGNED_ARGUMENT);
        assert!(
            last_error().contains("float values must start at a multiple of 4 bytes"),
            "{}",
            last_error()
        );
        let r = nmat_cache_mark(cache, 0, 0.5, 0.5, 0.0, 3, odd.cast_const().cast());
        assert_eq!(r, NMAT_MISALIGNED_ARGUMENT);
        assert_eq!(
            nmat_cache_mark_tiles(cache, odd.cast_const().cast(), 1),
            NMAT_MISALIGNED_ARGUMENT
        );
        assert!(
            last_error().contains("nmat_tile_key values must start at a multiple of 2"),
            "{}",
            last_error()
        );
        let mut count = 0;
        let fp =
            nmat_cache_footprint(cache, 0, 0.5, 0.5, 0.0, 0, null(), odd.cast(), 8, &mut count);
        assert_eq!(fp, NMAT_MISALIGNED_ARGUMENT);
        let stats = odd.cast::<nmat_frame_stats>();
        assert_eq!(nmat_cache_stats(cache, stats), NMAT_MISALIGNED_ARGUMENT);
        // Nothing was taken by the refused calls.
        assert_eq!(nmat_cache_begin_frame(cache), NMAT_OK);
        nmat_cache_free(cache);
        nmat_material_free(m);
    }
}

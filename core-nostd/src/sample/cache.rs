//! A tile cache for renderers: decode only the tiles a frame touches, once, and filter from them
//! (the frame protocol of the JPEG-texture paper's block cache and of "inference on feedback").
//!
//! A frame runs [`TileCache::begin_frame`], then [`TileCache::mark`] for every lookup it will make
//! (the same arguments as [`Material::sample`]) or [`TileCache::mark_texel`] for single texels
//! (or [`TileCache::footprint`] on many threads, then [`TileCache::mark_tiles`]), then [`TileCache::decode_missing`] (or [`TileCache::pending`] on the caller's threads), then
//! [`TileCache::resolve`] for the lookups themselves, then [`TileCache::end_frame`], which evicts
//! every tile the frame did not mark. Tiles are [`TILE_SIZE`]² texels of one mip of one material
//! (an 8×8, 16×8 or 16×16 JPEG MCU never straddles two), keyed by (material, mip, tile column,
//! tile row), and hold the integer decoder's 8-bit codes of every channel.
//!
//! `resolve` gives exactly what `Material::sample` gives with [`Precision::Integer`]: marking
//! runs the same filter code as sampling with a texel reader that records tiles instead of
//! decoding, so a bilinear, trilinear or stochastic lookup marks every neighbour tile it will read
//! (and no other); and a texel whose tile is not in the cache (not marked, not decoded yet, or no
//! room) is decoded directly — slower, never wrong — and counted in
//! [`FrameStats::resolve_misses`].
//!
//! Memory is the caller's, sized once: one [`Slot`] (bookkeeping, 24 bytes) and
//! [`TileCache::slot_bytes`] texel bytes per tile, at most [`MAX_CACHE_TILES`] tiles
//! ([`TileCache::memory_for`] checks a tile count and gives the bytes before anything is
//! allocated); nothing is allocated per frame. When a new tile
//! finds no free slot, `mark` takes the slot of a tile the current frame has not marked (every such
//! tile was last used in the previous frame: the least recently used) — one this frame may still
//! mark later, which is then decoded again ([`TileCache::mark_tiles`], given the frame's tiles at
//! once, marks the cached ones first and avoids that), so size the cache above the largest frame;
//! when every slot holds a tile the frame has marked, the tile is not cached,
//! [`FrameStats::overflowed`] counts it and its lookups decode directly.

#[cfg(feature = "alloc")]
extern crate alloc;

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicU32, Ordering};

use crate::decode::ChannelMask;
use crate::error::{Argument, Error};
use crate::limits::MAX_CHANNELS;
use crate::material::Material;
use crate::sample::filter::{Precision, SampleRequest};

/// Texels along each side of a tile.
pub const TILE_SIZE: u32 = 16;
const TILE_TEXELS: usize = (TILE_SIZE * TILE_SIZE) as usize;
/// Materials one cache serves.
pub const MAX_CACHE_MATERIALS: usize = 64;
/// No slot (end of a chain or of the free list).
const NONE: u32 = u32::MAX;
/// Tiles one cache holds at most, 2^32 − 2: slots are numbered by `u32`, and `u32::MAX` marks the
/// end of a chain. (Where a tile's texel bytes times this would not fit in one allocation, on
/// 32-bit targets, [`TileCache::memory_for`] allows fewer.)
pub const MAX_CACHE_TILES: usize = NONE as usize - 1;

/// Which tile: material (its index in the cache's list), mip, and tile column and row
/// (texel x / [`TILE_SIZE`], y / [`TILE_SIZE`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct TileKey {
    pub material: u16,
    pub mip: u8,
    pub x: u16,
    pub y: u16,
}

impl TileKey {
    fn hash(self) -> u64 {
        let packed = (u64::from(self.material) << 40)
            | (u64::from(self.mip) << 32)
            | (u64::from(self.x) << 16)
            | u64::from(self.y);
        packed.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Free,
    /// Marked, its texels not decoded yet.
    Pending,
    Ready,
}

/// The bookkeeping of one cached tile. Opaque: give the cache `[Slot::EMPTY; N]` (or
/// `vec![Slot::EMPTY; n]`) and leave it alone.
#[derive(Clone, Copy, Debug)]
pub struct Slot {
    key: TileKey,
    state: State,
    /// The frame that last marked the tile.
    seen: u32,
    /// The next slot in this slot's hash chain, or in the free list.
    next: u32,
    /// The first slot of hash bucket `this slot's index` (buckets and slots are as many).
    head: u32,
}

impl Slot {
    pub const EMPTY: Slot = Slot {
        key: TileKey { material: 0, mip: 0, x: 0, y: 0 },
        state: State::Free,
        seen: 0,
        next: NONE,
        head: NONE,
    };
}

impl Default for Slot {
    fn default() -> Slot {
        Slot::EMPTY
    }
}

/// What one frame did ([`TileCache::stats`], [`TileCache::end_frame`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameStats {
    /// The frame's number (1 for the first `begin_frame`).
    pub frame: u32,
    /// Distinct tiles marked this frame.
    pub marked: u32,
    /// Of those, tiles already decoded when first marked (kept from the previous frame).
    pub hits: u32,
    /// Tiles decoded this frame.
    pub decoded: u32,
    /// Texels those tiles hold (a tile at a mip's right or bottom edge holds fewer).
    pub decoded_texels: u32,
    /// Tiles dropped: unseen at `end_frame`, or their slot taken for a new tile.
    pub evicted: u32,
    /// Marks of a new tile that found no slot (every slot held a tile this frame marked).
    pub overflowed: u32,
    /// Texels `resolve` decoded itself because their tile was not in the cache.
    pub resolve_misses: u32,
}

/// What a cache of `tiles` tiles needs ([`TileCache::memory_for`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheSize {
    pub tiles: usize,
    /// Texel bytes of one tile ([`TileCache::slot_bytes`]).
    pub slot_bytes: usize,
    /// Texel bytes of every tile: what `texels` of [`TileCache::new`] must hold at least.
    pub texel_bytes: usize,
    /// All of it: the texel bytes and the tiles' bookkeeping (`tiles` [`Slot`]s), to compare with
    /// a memory budget.
    pub total_bytes: usize,
}

/// The counters that `resolve` and decoding jobs update through a shared reference.
#[derive(Debug, Default)]
struct Shared {
    decoded: AtomicU32,
    decoded_texels: AtomicU32,
    resolve_misses: AtomicU32,
}

/// A fixed-capacity cache of decoded tiles over up to [`MAX_CACHE_MATERIALS`] materials; `S` and
/// `T` hold its memory (`&mut [Slot]` and `&mut [u8]`, or `Vec`s). See the module documentation
/// for the frame protocol.
pub struct TileCache<'m, S, T> {
    materials: heapless::Vec<&'m Material<'m>, MAX_CACHE_MATERIALS>,
    slots: S,
    texels: T,
    slot_bytes: usize,
    frame: u32,
    free: u32,
    /// Slots holding a tile marked this frame.
    in_frame: u32,
    /// Where the search for a slot to take resumes.
    clock: u32,
    stats: FrameStats,
    shared: Shared,
}

/// `mip` is in the material's chain (`Argument::Mip` otherwise).
fn check_mip(m: &Material<'_>, mip: u32) -> Result<(), Error> {
    if mip >= m.mip_count() {
        return Err(Error::BadArgument {
            argument: Argument::Mip,
            value: u64::from(mip),
            limit: u64::from(m.mip_count()),
        });
    }
    Ok(())
}

/// `BadArgument` on the cache's memory.
fn memory_error(value: usize, limit: usize) -> Error {
    Error::BadArgument { argument: Argument::CacheMemory, value: value as u64, limit: limit as u64 }
}

impl<'m, S, T> TileCache<'m, S, T>
where
    S: AsRef<[Slot]> + AsMut<[Slot]>,
    T: AsRef<[u8]> + AsMut<[u8]>,
{
    /// Texel bytes per slot for `materials`: a tile of the material with the most channels.
    pub fn slot_bytes(materials: &[&Material<'_>]) -> usize {
        TILE_TEXELS * materials.iter().map(|m| m.channel_count()).max().unwrap_or(1).max(1)
    }

    /// Checks a cache of `tiles` tiles over `materials` against the cache's limits and gives the
    /// memory it needs, allocating nothing: the one check of [`TileCache::new`] and
    /// [`TileCache::with_capacity`], for callers that size their memory (or compare it with a
    /// budget) first. Errors: more than [`MAX_CACHE_MATERIALS`] materials or none
    /// (`Argument::Material`); no tile, or more than the limit (`Argument::CacheMemory` with
    /// `value` = `tiles`, `limit` = the most tiles allowed: [`MAX_CACHE_TILES`], or fewer where
    /// their texel bytes would exceed `isize::MAX`, the most one allocation can hold).
    pub fn memory_for(materials: &[&Material<'_>], tiles: usize) -> Result<CacheSize, Error> {
        if materials.is_empty() || materials.len() > MAX_CACHE_MATERIALS {
            return Err(Error::BadArgument {
                argument: Argument::Material,
                value: materials.len() as u64,
                limit: MAX_CACHE_MATERIALS as u64,
            });
        }
        let slot_bytes = Self::slot_bytes(materials);
        // A tile's texels outweigh its slot (256 bytes or more against 24), so within this limit
        // both arrays are valid allocations and their sum fits in `usize`.
        let limit = MAX_CACHE_TILES.min(isize::MAX as usize / slot_bytes.max(size_of::<Slot>()));
        if tiles == 0 || tiles > limit {
            return Err(memory_error(tiles, limit));
        }
        let texel_bytes = tiles.checked_mul(slot_bytes).ok_or(memory_error(tiles, limit))?;
        let total_bytes = tiles
            .checked_mul(size_of::<Slot>())
            .and_then(|b| b.checked_add(texel_bytes))
            .ok_or(memory_error(tiles, limit))?;
        Ok(CacheSize { tiles, slot_bytes, texel_bytes, total_bytes })
    }

    /// A cache over `materials` (indexed 0, 1, … in every later call) holding `slots.len()` tiles;
    /// `texels` must hold `slots.len() ·` [`TileCache::slot_bytes`] bytes. Every slot is reset.
    /// Errors: those of [`TileCache::memory_for`] for `slots.len()` tiles, and too few texel bytes
    /// (`Argument::CacheMemory` with `value` = the bytes given, `limit` = the bytes needed).
    pub fn new(materials: &[&'m Material<'m>], mut slots: S, texels: T) -> Result<Self, Error> {
        let n = slots.as_ref().len();
        let CacheSize { slot_bytes, texel_bytes, .. } = Self::memory_for(materials, n)?;
        if texels.as_ref().len() < texel_bytes {
            return Err(memory_error(texels.as_ref().len(), texel_bytes));
        }
        for (i, s) in slots.as_mut().iter_mut().enumerate() {
            *s = Slot { next: if i + 1 < n { i as u32 + 1 } else { NONE }, ..Slot::EMPTY };
        }
        let mut list = heapless::Vec::new();
        for &m in materials {
            // Cannot fail: the length was checked above.
            let _ = list.push(m);
        }
        Ok(TileCache {
            materials: list,
            slots,
            texels,
            slot_bytes,
            frame: 0,
            free: 0,
            in_frame: 0,
            clock: 0,
            stats: FrameStats::default(),
            shared: Shared::default(),
        })
    }

    /// Tiles the cache holds at most.
    pub fn capacity(&self) -> usize {
        self.slots.as_ref().len()
    }

    /// Material `index` of the cache's list.
    pub fn material(&self, index: usize) -> Result<&'m Material<'m>, Error> {
        self.materials.get(index).copied().ok_or(Error::BadArgument {
            argument: Argument::Material,
            value: index as u64,
            limit: self.materials.len() as u64,
        })
    }

    /// Starts a frame: its counters start at zero.
    pub fn begin_frame(&mut self) {
        self.frame = self.frame.wrapping_add(1);
        self.in_frame = 0;
        self.stats = FrameStats { frame: self.frame, ..FrameStats::default() };
        self.shared = Shared::default();
    }

    /// Marks every tile that `resolve(material, req, …)` will read (the channel mask and
    /// precision of `req` do not matter here, but the mask must be valid for the material).
    pub fn mark(&mut self, material: usize, req: &SampleRequest) -> Result<(), Error> {
        let tiles = self.footprint(material, req)?;
        for key in tiles {
            self.mark_tile(key);
        }
        Ok(())
    }

    /// The tiles `resolve(material, req, …)` reads (one to eight), without marking them: a
    /// shared-reference call, so threads can compute the footprints of a frame's lookups side by
    /// side and [`TileCache::mark_tiles`] marks what they found.
    pub fn footprint(
        &self,
        material: usize,
        req: &SampleRequest,
    ) -> Result<heapless::Vec<TileKey, 8>, Error> {
        let m = self.material(material)?;
        m.resolve_channels(req.channels)?;
        let touched = RefCell::new(heapless::Vec::<TileKey, 8>::new());
        let mut scratch = [0f32; MAX_CHANNELS];
        let req = SampleRequest { channels: ChannelMask::single(0), ..*req };
        m.sample_with(&req, &mut scratch, &|x, y, mip, _, _, _| {
            let (x, y, mip) = m.address_texel(x, y, mip);
            let mut t = touched.borrow_mut();
            let key = Self::key(material, x / TILE_SIZE, y / TILE_SIZE, mip);
            if !t.contains(&key) {
                // A lookup reads at most 8 texels (trilinear): the push cannot fail.
                let _ = t.push(key);
            }
            Ok(0)
        })?;
        Ok(touched.into_inner())
    }

    /// Marks tiles found by [`TileCache::footprint`] (repeats are counted once per frame). The
    /// tiles already cached are marked first, so when the cache is full a new tile only takes the
    /// slot of a tile none of `keys` needs. A key naming a material, mip or tile the cache's
    /// materials do not have is refused (`Argument::Material`, `Argument::Mip`,
    /// `Argument::Region`) before anything is marked.
    pub fn mark_tiles(&mut self, keys: &[TileKey]) -> Result<(), Error> {
        for key in keys {
            let m = self.material(usize::from(key.material))?;
            let mip = u32::from(key.mip);
            check_mip(m, mip)?;
            let (w, h) = m.mip_size(mip);
            let (x, y) = (u32::from(key.x), u32::from(key.y));
            if x >= w.div_ceil(TILE_SIZE) || y >= h.div_ceil(TILE_SIZE) {
                return Err(Error::BadArgument {
                    argument: Argument::Region,
                    value: u64::from(x.max(y)),
                    limit: u64::from(w.div_ceil(TILE_SIZE).max(h.div_ceil(TILE_SIZE))),
                });
            }
        }
        for &key in keys {
            if let Some(i) = self.find(key) {
                self.touch(i);
            }
        }
        for &key in keys {
            self.mark_tile(key);
        }
        Ok(())
    }

    /// Marks the tile of texel (x, y) of `mip` (addressed like `Material::decode_texel_u8`).
    pub fn mark_texel(&mut self, material: usize, x: i64, y: i64, mip: u32) -> Result<(), Error> {
        let m = self.material(material)?;
        check_mip(m, mip)?;
        let (x, y, mip) = m.address_texel(x, y, mip);
        self.mark_tile(Self::key(material, x / TILE_SIZE, y / TILE_SIZE, mip));
        Ok(())
    }

    fn key(material: usize, x: u32, y: u32, mip: u32) -> TileKey {
        // Every value fits: material < MAX_CACHE_MATERIALS, mip < MAX_MIPS, and a tile index is
        // at most MAX_DIMENSION / TILE_SIZE.
        TileKey { material: material as u16, mip: mip as u8, x: x as u16, y: y as u16 }
    }

    fn bucket(&self, key: TileKey) -> usize {
        (key.hash() % self.slots.as_ref().len() as u64) as usize
    }

    /// The slot holding `key`.
    fn find(&self, key: TileKey) -> Option<usize> {
        let slots = self.slots.as_ref();
        let mut i = slots.get(self.bucket(key))?.head;
        while i != NONE {
            let s = slots.get(i as usize)?;
            if s.key == key && s.state != State::Free {
                return Some(i as usize);
            }
            i = s.next;
        }
        None
    }

    /// Marks the cached tile in slot `i` (once per frame).
    fn touch(&mut self, i: usize) {
        let frame = self.frame;
        if let Some(s) = self.slots.as_mut().get_mut(i)
            && s.seen != frame
        {
            s.seen = frame;
            self.in_frame += 1;
            self.stats.marked += 1;
            self.stats.hits += u32::from(s.state == State::Ready);
        }
    }

    fn mark_tile(&mut self, key: TileKey) {
        let frame = self.frame;
        if let Some(i) = self.find(key) {
            self.touch(i);
            return;
        }
        let Some(i) = self.take_slot() else {
            self.stats.overflowed += 1;
            return;
        };
        let b = self.bucket(key);
        let slots = self.slots.as_mut();
        let head = slots.get(b).map_or(NONE, |s| s.head);
        if let Some(s) = slots.get_mut(i) {
            *s = Slot { key, state: State::Pending, seen: frame, next: head, head: s.head };
        }
        if let Some(s) = slots.get_mut(b) {
            s.head = i as u32;
        }
        self.in_frame += 1;
        self.stats.marked += 1;
    }

    /// A free slot, or the slot of a tile this frame has not marked (evicted); `None` when every
    /// slot holds a tile of this frame.
    fn take_slot(&mut self) -> Option<usize> {
        if self.free != NONE {
            let i = self.free as usize;
            self.free = self.slots.as_ref().get(i).map_or(NONE, |s| s.next);
            return Some(i);
        }
        let n = self.slots.as_ref().len();
        if self.in_frame as usize >= n {
            return None;
        }
        for _ in 0..n {
            let i = self.clock as usize % n;
            self.clock = ((i + 1) % n) as u32;
            let stale = self.slots.as_ref().get(i).is_some_and(|s| s.seen != self.frame);
            if stale {
                self.unlink(i);
                self.stats.evicted += 1;
                return Some(i);
            }
        }
        None
    }

    /// Takes slot `i` out of its hash chain and marks it free (not on the free list).
    fn unlink(&mut self, i: usize) {
        let Some(key) = self.slots.as_ref().get(i).map(|s| s.key) else {
            return;
        };
        let b = self.bucket(key);
        let slots = self.slots.as_mut();
        let next = slots.get(i).map_or(NONE, |s| s.next);
        if slots.get(b).is_some_and(|s| s.head == i as u32) {
            if let Some(s) = slots.get_mut(b) {
                s.head = next;
            }
        } else {
            let mut j = slots.get(b).map_or(NONE, |s| s.head);
            while j != NONE {
                let Some(s) = slots.get_mut(j as usize) else { break };
                if s.next == i as u32 {
                    s.next = next;
                    break;
                }
                j = s.next;
            }
        }
        if let Some(s) = slots.get_mut(i) {
            s.state = State::Free;
            s.next = NONE;
        }
    }

    /// The marked tiles whose texels are not decoded yet, as independent jobs: run them on any
    /// threads (each owns its tile's memory), e.g. with rayon's `par_bridge`. A job that fails
    /// leaves its tile undecoded (its lookups decode directly).
    pub fn pending(&mut self) -> impl Iterator<Item = PendingTile<'_, 'm>> + '_ {
        let materials = &self.materials;
        let shared = &self.shared;
        self.slots
            .as_mut()
            .iter_mut()
            .zip(self.texels.as_mut().chunks_exact_mut(self.slot_bytes))
            .filter(|(s, _)| s.state == State::Pending)
            .filter_map(move |(slot, texels)| {
                let material = *materials.get(usize::from(slot.key.material))?;
                Some(PendingTile { material, slot, texels, shared })
            })
    }

    /// Decodes every pending tile on this thread with the material's own per-texel decoder (with
    /// the `alloc` feature, [`TileCache::decode_missing_with`] is much faster). Returns the tiles
    /// decoded; on an error the other tiles are still decoded and the first error is returned.
    pub fn decode_missing(&mut self) -> Result<u32, Error> {
        self.run_pending(|t| t.decode())
    }

    fn run_pending(
        &mut self,
        mut run: impl FnMut(PendingTile<'_, 'm>) -> Result<(), Error>,
    ) -> Result<u32, Error> {
        let (mut done, mut first_error) = (0, None);
        for t in self.pending() {
            match run(t) {
                Ok(()) => done += 1,
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
        first_error.map_or(Ok(done), Err)
    }

    /// A filtered lookup from the cache: the same values as `Material::sample(req, out)`;
    /// `req.precision` must be [`Precision::Integer`] (the cache holds 8-bit codes;
    /// `Argument::Precision` otherwise). Any number of threads may resolve at once.
    pub fn resolve(
        &self,
        material: usize,
        req: &SampleRequest,
        out: &mut [f32],
    ) -> Result<usize, Error> {
        if req.precision != Precision::Integer {
            return Err(Error::BadArgument { argument: Argument::Precision, value: 1, limit: 0 });
        }
        let m = self.material(material)?;
        // The texels of a bilinear footprint mostly share a tile: look it up once.
        let last = Cell::new(None::<(TileKey, Option<usize>)>);
        m.sample_with(req, out, &|x, y, mip, channels, _, values| {
            let (x, y, mip) = m.address_texel(x, y, mip);
            let key = Self::key(material, x / TILE_SIZE, y / TILE_SIZE, mip);
            let slot = match last.get() {
                Some((k, slot)) if k == key => slot,
                _ => {
                    let slot = self.ready_slot(key);
                    last.set(Some((key, slot)));
                    slot
                }
            };
            let mut codes = [0u8; MAX_CHANNELS];
            let n = match slot.and_then(|i| self.cached_texel(i, material, x, y)) {
                Some(texel) => {
                    let selected = texel
                        .iter()
                        .enumerate()
                        .filter(|(c, _)| channels.0 & (1 << c) != 0)
                        .map(|(_, &v)| v);
                    let mut n = 0;
                    for (slot, v) in codes.iter_mut().zip(selected) {
                        *slot = v;
                        n += 1;
                    }
                    n
                }
                None => {
                    self.shared.resolve_misses.fetch_add(1, Ordering::Relaxed);
                    m.decode_texel_u8(i64::from(x), i64::from(y), mip, channels, &mut codes)?
                }
            };
            for (v, &c) in values.iter_mut().zip(&codes).take(n) {
                *v = f32::from(c) / 255.0;
            }
            Ok(n)
        })
    }

    /// The slot of tile `key` if it is decoded.
    fn ready_slot(&self, key: TileKey) -> Option<usize> {
        let i = self.find(key)?;
        (self.slots.as_ref().get(i)?.state == State::Ready).then_some(i)
    }

    /// The codes of every channel of texel (x, y) (addressed) of the decoded tile in slot `i`.
    fn cached_texel(&self, i: usize, material: usize, x: u32, y: u32) -> Option<&[u8]> {
        let channels = self.materials.get(material)?.channel_count();
        let at = ((y % TILE_SIZE) * TILE_SIZE + x % TILE_SIZE) as usize * channels;
        self.texels.as_ref().get(i * self.slot_bytes + at..)?.get(..channels)
    }

    /// This frame's counters so far.
    pub fn stats(&self) -> FrameStats {
        FrameStats {
            decoded: self.shared.decoded.load(Ordering::Relaxed),
            decoded_texels: self.shared.decoded_texels.load(Ordering::Relaxed),
            resolve_misses: self.shared.resolve_misses.load(Ordering::Relaxed),
            ..self.stats
        }
    }

    /// Ends the frame: every tile it did not mark is evicted. Returns the frame's counters.
    pub fn end_frame(&mut self) -> FrameStats {
        for i in 0..self.slots.as_ref().len() {
            let stale = self
                .slots
                .as_ref()
                .get(i)
                .is_some_and(|s| s.state != State::Free && s.seen != self.frame);
            if stale {
                self.unlink(i);
                if let Some(s) = self.slots.as_mut().get_mut(i) {
                    s.next = self.free;
                }
                self.free = i as u32;
                self.stats.evicted += 1;
            }
        }
        self.stats()
    }
}

#[cfg(feature = "alloc")]
impl<'m> TileCache<'m, alloc::vec::Vec<Slot>, alloc::vec::Vec<u8>> {
    /// A cache of `tiles` slots in memory of its own (allocated here, once:
    /// [`CacheSize::total_bytes`] of [`TileCache::memory_for`]). Errors: those of `memory_for`,
    /// checked before anything is allocated, and `Error::OutOfMemory` when the allocator refuses
    /// the memory (instead of aborting the process).
    pub fn with_capacity(materials: &[&'m Material<'m>], tiles: usize) -> Result<Self, Error> {
        let size = Self::memory_for(materials, tiles)?;
        let out_of_memory = |_| Error::OutOfMemory { bytes: size.total_bytes as u64 };
        let (mut slots, mut texels) = (alloc::vec::Vec::new(), alloc::vec::Vec::new());
        slots.try_reserve_exact(tiles).map_err(out_of_memory)?;
        texels.try_reserve_exact(size.texel_bytes).map_err(out_of_memory)?;
        // The zeros are written here, once (`vec![0; n]` would take them lazily from the system,
        // but aborts the process where the allocation is refused).
        slots.resize(tiles, Slot::EMPTY);
        texels.resize(size.texel_bytes, 0);
        TileCache::new(materials, slots, texels)
    }
}

#[cfg(feature = "alloc")]
impl<'m, S, T> TileCache<'m, S, T>
where
    S: AsRef<[Slot]> + AsMut<[Slot]>,
    T: AsRef<[u8]> + AsMut<[u8]>,
{
    /// [`TileCache::decode_missing`] with the prepared decoders of the materials
    /// (`decoders[i]` for material `i`): tiles are decoded as regions, a JPEG MCU once.
    pub fn decode_missing_with(
        &mut self,
        decoders: &[&crate::decoder::Decoder],
    ) -> Result<u32, Error> {
        self.run_pending(|t| {
            let i = t.key().material;
            let d = decoders.get(usize::from(i)).ok_or(Error::BadArgument {
                argument: Argument::Material,
                value: u64::from(i),
                limit: decoders.len() as u64,
            })?;
            t.decode_with(d)
        })
    }
}

/// One marked tile to decode ([`TileCache::pending`]).
pub struct PendingTile<'c, 'm> {
    material: &'m Material<'m>,
    slot: &'c mut Slot,
    texels: &'c mut [u8],
    shared: &'c Shared,
}

impl PendingTile<'_, '_> {
    /// Which tile.
    pub fn key(&self) -> TileKey {
        self.slot.key
    }

    /// The tile's texels in its mip: (x0, y0, width, height).
    pub fn rect(&self) -> (u32, u32, u32, u32) {
        let k = self.slot.key;
        let (w, h) = self.material.mip_size(u32::from(k.mip));
        let (x0, y0) = (u32::from(k.x) * TILE_SIZE, u32::from(k.y) * TILE_SIZE);
        (x0, y0, TILE_SIZE.min(w.saturating_sub(x0)), TILE_SIZE.min(h.saturating_sub(y0)))
    }

    /// Decodes the tile texel by texel with the material's own decoder.
    pub fn decode(self) -> Result<(), Error> {
        let (x0, y0, w, h) = self.rect();
        let channels = self.material.channel_count();
        let mip = u32::from(self.slot.key.mip);
        for y in 0..h {
            for x in 0..w {
                let at = (y * TILE_SIZE + x) as usize * channels;
                let out = self.texels.get_mut(at..at + channels).ok_or(memory_error(at, 0))?;
                self.material.decode_texel_u8(
                    i64::from(x0 + x),
                    i64::from(y0 + y),
                    mip,
                    ChannelMask::ALL,
                    out,
                )?;
            }
        }
        self.done(w * h);
        Ok(())
    }

    /// Decodes the tile as one region with `decoder` (prepared from this tile's material).
    #[cfg(feature = "alloc")]
    pub fn decode_with(self, decoder: &crate::decoder::Decoder) -> Result<(), Error> {
        let rect = self.rect();
        let pitch = TILE_SIZE as usize * self.material.channel_count();
        let mip = u32::from(self.slot.key.mip);
        decoder.decode_region_u8(self.material, mip, rect, ChannelMask::ALL, self.texels, pitch)?;
        self.done(rect.2 * rect.3);
        Ok(())
    }

    fn done(self, texels: u32) {
        self.slot.state = State::Ready;
        self.shared.decoded.fetch_add(1, Ordering::Relaxed);
        self.shared.decoded_texels.fetch_add(texels, Ordering::Relaxed);
    }
}

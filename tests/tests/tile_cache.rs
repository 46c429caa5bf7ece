//! The tile cache (`nmat_core::cache`): every resolved value equals `Material::sample`, for
//! neural and JPEG materials, every filter, wrap and clamp, in one cache; what a frame counts;
//! eviction of unseen tiles; a cache too small for the frame; decoding on threads; refusals.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{
    Argument, CacheSize, ChannelMask, Container, Decoder, Error, Filter, FrameStats, Material,
    Precision, SampleRequest, Slot, TILE_SIZE, TileCache,
};
use nmat_core::{MAX_CACHE_MATERIALS, MAX_CACHE_TILES};
use nmat_tests::fixtures_dir;
use nmat_tests::generate::Rng;
use nmat_tests::generate_jpeg::DcJpegMaterial;

/// Four materials of different codecs, sizes, channel counts and address modes: two neural,
/// the committed JPEG one and a JPEG one of four maps and four mips.
fn fixture_bytes() -> Vec<Vec<u8>> {
    let mut files: Vec<Vec<u8>> =
        ["ntc_rgb_64.nmat", "ntc_pbr10_96x80_clamp.nmat", "jpeg/pattern_420_37x21.nmat"]
            .iter()
            .map(|name| std::fs::read(fixtures_dir().join(name)).unwrap())
            .collect();
    files.push(DcJpegMaterial::new(5).spec.to_bytes().unwrap());
    files
}

fn random_request(r: &mut Rng, m: &Material<'_>) -> SampleRequest {
    let filter = [Filter::Nearest, Filter::Bilinear, Filter::Trilinear, Filter::Stochastic]
        [r.range(0, 3) as usize];
    let all = (1u32 << m.channel_count()) - 1;
    SampleRequest {
        u: (r.unit() * 1.6 - 0.3) as f32,
        v: (r.unit() * 1.6 - 0.3) as f32,
        lod: (r.unit() * f64::from(m.mip_count() + 1) - 0.5) as f32,
        filter,
        precision: Precision::Integer,
        random: [r.unit() as f32, r.unit() as f32, r.unit() as f32],
        channels: ChannelMask(r.range(1, i64::from(all)) as u16),
    }
}

fn requests(materials: &[Material<'_>], seed: u64, count: usize) -> Vec<(usize, SampleRequest)> {
    let mut r = Rng::new(seed);
    (0..count)
        .map(|_| {
            let i = r.range(0, materials.len() as i64 - 1) as usize;
            (i, random_request(&mut r, &materials[i]))
        })
        .collect()
}

/// Resolves every request and checks it against `Material::sample`, to the bit.
fn assert_resolved_equal_sample<S, T>(
    cache: &TileCache<'_, S, T>,
    materials: &[Material<'_>],
    requests: &[(usize, SampleRequest)],
) where
    S: AsRef<[Slot]> + AsMut<[Slot]>,
    T: AsRef<[u8]> + AsMut<[u8]>,
{
    for (k, (i, req)) in requests.iter().enumerate() {
        let (mut got, mut want) = ([0f32; 16], [0f32; 16]);
        let n = cache.resolve(*i, req, &mut got).unwrap();
        assert_eq!(materials[*i].sample(req, &mut want).unwrap(), n);
        assert_eq!(
            got[..n].iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            want[..n].iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "request {k} on material {i}: {req:?}"
        );
    }
}

/// One frame: mark every request, decode what is missing, resolve and compare, end.
fn frame<S, T>(
    cache: &mut TileCache<'_, S, T>,
    materials: &[Material<'_>],
    decoders: &[&Decoder],
    requests: &[(usize, SampleRequest)],
) -> FrameStats
where
    S: AsRef<[Slot]> + AsMut<[Slot]>,
    T: AsRef<[u8]> + AsMut<[u8]>,
{
    frame_marked(cache, materials, decoders, requests, false)
}

/// [`frame`], marking lookup by lookup or (`batched`) every footprint with one `mark_tiles`.
fn frame_marked<S, T>(
    cache: &mut TileCache<'_, S, T>,
    materials: &[Material<'_>],
    decoders: &[&Decoder],
    requests: &[(usize, SampleRequest)],
    batched: bool,
) -> FrameStats
where
    S: AsRef<[Slot]> + AsMut<[Slot]>,
    T: AsRef<[u8]> + AsMut<[u8]>,
{
    cache.begin_frame();
    if batched {
        let keys: Vec<_> =
            requests.iter().flat_map(|(i, req)| cache.footprint(*i, req).unwrap()).collect();
        cache.mark_tiles(&keys).unwrap();
    } else {
        for (i, req) in requests {
            cache.mark(*i, req).unwrap();
        }
    }
    let decoded = cache.decode_missing_with(decoders).unwrap();
    assert_eq!(cache.stats().decoded, decoded);
    assert_resolved_equal_sample(cache, materials, requests);
    cache.end_frame()
}

#[test]
fn resolved_values_equal_material_sample_and_a_second_frame_hits() {
    let bytes = fixture_bytes();
    let materials: Vec<Material> = bytes.iter().map(|b| Container::parse(b).unwrap()).collect();
    let refs: Vec<&Material> = materials.iter().collect();
    let decoders: Vec<Decoder> = materials.iter().map(Decoder::new).collect();
    let decoders: Vec<&Decoder> = decoders.iter().collect();
    let mut cache = TileCache::with_capacity(&refs, 4096).unwrap();
    let reqs = requests(&materials, 7, 3000);

    let first = frame(&mut cache, &materials, &decoders, &reqs);
    assert_eq!(first.frame, 1);
    assert!(first.marked > 20, "{first:?}");
    assert_eq!((first.hits, first.evicted, first.overflowed), (0, 0, 0), "{first:?}");
    assert_eq!(first.decoded, first.marked, "every marked tile decoded once: {first:?}");
    assert_eq!(first.resolve_misses, 0, "marking covers every texel a lookup reads: {first:?}");
    // The texels decoded are those of the tiles (edge tiles are smaller), at most a full tile's.
    assert!(first.decoded_texels <= first.decoded * TILE_SIZE * TILE_SIZE);
    assert!(first.decoded_texels > first.decoded * TILE_SIZE * TILE_SIZE / 8, "{first:?}");

    let second = frame(&mut cache, &materials, &decoders, &reqs);
    assert_eq!(second.frame, 2);
    assert_eq!((second.marked, second.hits), (first.marked, first.marked), "{second:?}");
    assert_eq!((second.decoded, second.resolve_misses, second.evicted), (0, 0, 0), "{second:?}");
}

#[test]
fn the_per_texel_decode_and_jobs_on_threads_fill_the_same_tiles() {
    let bytes = fixture_bytes();
    let materials: Vec<Material> = bytes.iter().map(|b| Container::parse(b).unwrap()).collect();
    let refs: Vec<&Material> = materials.iter().collect();
    let decoders: Vec<Decoder> = materials.iter().map(Decoder::new).collect();
    let reqs = requests(&materials, 11, 800);

    // On this thread, the materials' own per-texel decoder.
    let mut plain = TileCache::with_capacity(&refs, 2048).unwrap();
    plain.begin_frame();
    for (i, req) in &reqs {
        plain.mark(*i, req).unwrap();
    }
    let marked = plain.stats().marked;
    // Each decode counts its tile's texels (edge tiles are smaller).
    let tile_texels: u32 = plain.pending().map(|t| t.rect()).map(|(_, _, w, h)| w * h).sum();
    assert_eq!(plain.decode_missing().unwrap(), marked);
    assert_eq!(plain.stats().decoded_texels, tile_texels);
    assert_resolved_equal_sample(&plain, &materials, &reqs);
    assert_eq!(plain.stats().resolve_misses, 0);

    // The pending jobs spread over three threads, with the prepared decoders.
    let mut slots = vec![Slot::EMPTY; 2048];
    let mut texels = vec![0u8; 2048 * TileCache::<&mut [Slot], &mut [u8]>::slot_bytes(&refs)];
    let mut threaded = TileCache::new(&refs, &mut slots[..], &mut texels[..]).unwrap();
    threaded.begin_frame();
    for (i, req) in &reqs {
        threaded.mark(*i, req).unwrap();
    }
    let jobs: Vec<_> = threaded.pending().collect();
    assert_eq!(jobs.len() as u32, marked);
    let mut parts: Vec<Vec<_>> = (0..3).map(|_| Vec::new()).collect();
    for (k, job) in jobs.into_iter().enumerate() {
        parts[k % 3].push(job);
    }
    std::thread::scope(|s| {
        for part in parts {
            let decoders = &decoders;
            s.spawn(move || {
                for job in part {
                    let d = &decoders[usize::from(job.key().material)];
                    job.decode_with(d).unwrap();
                }
            });
        }
    });
    assert_eq!(threaded.stats().decoded, marked);
    assert_eq!(threaded.stats().decoded_texels, tile_texels);
    assert_eq!(threaded.pending().count(), 0);
    assert_resolved_equal_sample(&threaded, &materials, &reqs);
    assert_eq!(threaded.stats().resolve_misses, 0);
}

#[test]
fn end_frame_evicts_the_tiles_a_frame_did_not_mark() {
    let bytes = fixture_bytes();
    let m = Container::parse(&bytes[1]).unwrap(); // 96×80: 6×5 tiles at mip 0
    let d = Decoder::new(&m);
    let mut cache = TileCache::with_capacity(&[&m], 64).unwrap();
    let nearest = |x: u32, y: u32| SampleRequest {
        u: (x as f32 + 0.5) / 96.0,
        v: (y as f32 + 0.5) / 80.0,
        lod: 0.0,
        filter: Filter::Nearest,
        precision: Precision::Integer,
        random: [0.0; 3],
        channels: ChannelMask::ALL,
    };
    // Frame 1: the tiles of row 0 (6); frame 2: tiles (0, 0) and (0, 1).
    let row0: Vec<_> = (0..6).map(|t| (0, nearest(t * 16 + 3, 5))).collect();
    let s1 = frame(&mut cache, std::slice::from_ref(&m), &[&d], &row0);
    assert_eq!((s1.marked, s1.decoded, s1.evicted), (6, 6, 0));
    let two = [(0, nearest(1, 1)), (0, nearest(2, 20))];
    let s2 = frame(&mut cache, std::slice::from_ref(&m), &[&d], &two);
    assert_eq!((s2.marked, s2.hits, s2.decoded, s2.evicted), (2, 1, 1, 5), "{s2:?}");
    // Frame 3 asks for row 0 again: only tile (0, 0) survived frame 2.
    let s3 = frame(&mut cache, std::slice::from_ref(&m), &[&d], &row0);
    assert_eq!((s3.marked, s3.hits, s3.decoded, s3.evicted), (6, 1, 5, 1), "{s3:?}");
    // Texel marks: the tile of (x, y) after addressing (clamp here), at the mip asked for.
    cache.begin_frame();
    cache.mark_texel(0, -5, 1000, 0).unwrap(); // clamps to (0, 79): tile (0, 4)
    cache.mark_texel(0, 40, 3, 1).unwrap(); // tile (2, 0) of mip 1
    assert_eq!(cache.stats().marked, 2);
    let mut keys: Vec<_> = cache.pending().map(|t| t.key()).map(|k| (k.mip, k.x, k.y)).collect();
    keys.sort();
    assert_eq!(keys, [(0, 0, 4), (1, 2, 0)]);
    assert_eq!(cache.decode_missing_with(&[&d]).unwrap(), 2);
    let stats = cache.end_frame();
    assert_eq!(stats.evicted, 6, "{stats:?}");
}

#[test]
fn a_cache_too_small_for_the_frame_still_resolves_exactly() {
    let bytes = fixture_bytes();
    let materials: Vec<Material> = bytes.iter().map(|b| Container::parse(b).unwrap()).collect();
    let refs: Vec<&Material> = materials.iter().collect();
    let decoders: Vec<Decoder> = materials.iter().map(Decoder::new).collect();
    let decoders: Vec<&Decoder> = decoders.iter().collect();
    let mut cache = TileCache::with_capacity(&refs, 5).unwrap();
    let reqs = requests(&materials, 3, 500);
    let s = frame(&mut cache, &materials, &decoders, &reqs);
    assert_eq!(s.marked, 5, "{s:?}");
    assert!(s.overflowed > 0 && s.resolve_misses > 0, "{s:?}");
    // A smaller working set in the next frame takes the slots of the old tiles (least recently
    // used first) and fits again.
    let nearest = SampleRequest { filter: Filter::Nearest, lod: 0.0, ..reqs[0].1 };
    let few = [(reqs[0].0, nearest)];
    let s = frame(&mut cache, &materials, &decoders, &few);
    assert_eq!((s.overflowed, s.resolve_misses), (0, 0), "{s:?}");
}

#[test]
fn a_full_cache_takes_the_slot_of_a_tile_this_frame_did_not_mark() {
    let bytes = fixture_bytes();
    let m = Container::parse(&bytes[0]).unwrap(); // 64×64 wrap: 4×4 tiles at mip 0
    let d = Decoder::new(&m);
    let mut cache = TileCache::with_capacity(&[&m], 2).unwrap();
    let at = |tx: u32| {
        let x = f32::from(tx as u8) * 16.0 + 8.0;
        (
            0,
            SampleRequest {
                u: x / 64.0,
                v: 8.0 / 64.0,
                lod: 0.0,
                filter: Filter::Nearest,
                precision: Precision::Integer,
                random: [0.0; 3],
                channels: ChannelMask::ALL,
            },
        )
    };
    let s = frame(&mut cache, std::slice::from_ref(&m), &[&d], &[at(0), at(1)]);
    assert_eq!((s.marked, s.decoded, s.evicted, s.overflowed), (2, 2, 0, 0));
    // Tile 2 while tiles 0 and 1 are cached and unmarked: one of them gives up its slot; tile 3
    // takes the other; tile 0 again finds none (both slots hold tiles of this frame).
    let s = frame(&mut cache, std::slice::from_ref(&m), &[&d], &[at(2), at(3), at(0)]);
    assert_eq!((s.marked, s.decoded, s.evicted, s.overflowed), (2, 2, 2, 1), "{s:?}");
    assert_eq!(s.resolve_misses, 1, "{s:?}");
}

fn bad<T>(e: Result<T, Error>, argument: Argument) {
    match e {
        Err(Error::BadArgument { argument: a, .. }) => assert_eq!(a, argument),
        Err(other) => panic!("expected {argument:?}, got {other:?}"),
        Ok(_) => panic!("expected {argument:?}, got Ok"),
    }
}

#[test]
fn bad_arguments_are_typed_errors() {
    let bytes = fixture_bytes();
    let m = Container::parse(&bytes[0]).unwrap();
    let one_tile = TileCache::<&mut [Slot], &mut [u8]>::slot_bytes(&[&m]);
    assert_eq!(one_tile, 16 * 16 * m.channel_count());
    let (mut slots, mut texels) = (vec![Slot::EMPTY; 4], vec![0u8; 4 * one_tile]);
    bad(TileCache::new(&[&m], &mut slots[..0], &mut texels[..]), Argument::CacheMemory);
    bad(
        TileCache::new(&[&m], &mut slots[..], &mut texels[..4 * one_tile - 1]),
        Argument::CacheMemory,
    );
    bad(TileCache::new(&[], &mut slots[..], &mut texels[..]), Argument::Material);
    let mut cache = TileCache::new(&[&m], &mut slots[..], &mut texels[..]).unwrap();
    cache.begin_frame();
    let req = SampleRequest {
        u: 0.5,
        v: 0.5,
        lod: 0.0,
        filter: Filter::Bilinear,
        precision: Precision::Integer,
        random: [0.0; 3],
        channels: ChannelMask::ALL,
    };
    bad(cache.mark(1, &req), Argument::Material);
    bad(cache.mark(0, &SampleRequest { channels: ChannelMask(1 << 9), ..req }), Argument::Channels);
    bad(cache.mark_texel(0, 0, 0, m.mip_count()), Argument::Mip);
    let mut out = [0f32; 16];
    bad(
        cache.resolve(0, &SampleRequest { precision: Precision::Float, ..req }, &mut out),
        Argument::Precision,
    );
    bad(cache.resolve(0, &req, &mut out[..1]), Argument::Output);
    bad(cache.resolve(3, &req, &mut out), Argument::Material);
    cache.mark(0, &req).unwrap();
    bad(cache.decode_missing_with(&[]), Argument::Material);
    // The failed job left its tiles pending: lookups decode directly until they are decoded.
    assert_eq!(cache.resolve(0, &req, &mut out).unwrap(), m.channel_count());
    assert_eq!(cache.stats().resolve_misses, 4);
    assert_eq!(cache.decode_missing().unwrap(), cache.stats().marked);
}

/// `memory_for` is the one check of `new` and `with_capacity`; the counts here would abort the
/// process if anything were allocated for them (2^32 − 1 tiles are 96 GiB of slots alone). The
/// material count's limit is allowed, one more refused.
#[test]
fn tile_counts_beyond_the_limit_are_refused_before_anything_is_allocated() {
    type Owned<'m> = TileCache<'m, Vec<Slot>, Vec<u8>>;
    let bytes = fixture_bytes();
    let m = Container::parse(&bytes[1]).unwrap();
    let one_tile = Owned::slot_bytes(&[&m]);
    assert_eq!(MAX_CACHE_TILES as u64, (1 << 32) - 2);
    // 32-bit targets allow fewer: what one allocation can hold.
    let limit = MAX_CACHE_TILES.min(isize::MAX as usize / one_tile);
    let bytes_overflow = usize::MAX / one_tile + 1;
    let mut counts = vec![0, limit + 1, u32::MAX as usize, usize::MAX, bytes_overflow];
    if cfg!(target_pointer_width = "64") {
        assert_eq!(limit, MAX_CACHE_TILES);
        counts.push((u32::MAX as usize).wrapping_add(1));
    }
    for tiles in counts {
        let refused = Error::BadArgument {
            argument: Argument::CacheMemory,
            value: tiles as u64,
            limit: limit as u64,
        };
        assert_eq!(Owned::memory_for(&[&m], tiles).err(), Some(refused), "{tiles} tiles");
        assert_eq!(TileCache::with_capacity(&[&m], tiles).err(), Some(refused), "{tiles} tiles");
        assert!(refused.to_string().contains(&format!("limit {limit}")), "{refused}");
    }
    // The largest cache allowed is sized, not allocated; a small one is allocated as sized.
    let largest = Owned::memory_for(&[&m], limit).unwrap();
    assert_eq!(largest.texel_bytes, limit * one_tile);
    assert_eq!(largest.total_bytes, limit * (one_tile + size_of::<Slot>()));
    let small = Owned::memory_for(&[&m], 5).unwrap();
    let want = CacheSize {
        tiles: 5,
        slot_bytes: one_tile,
        texel_bytes: 5 * one_tile,
        total_bytes: 5 * (one_tile + size_of::<Slot>()),
    };
    assert_eq!(small, want);
    assert_eq!(TileCache::with_capacity(&[&m], 5).unwrap().capacity(), 5);
    let too_many = vec![&m; MAX_CACHE_MATERIALS + 1];
    bad(Owned::memory_for(&too_many, 5), Argument::Material);
    bad(TileCache::with_capacity(&too_many, 5), Argument::Material);
    // As many materials as allowed, the last one addressable.
    let most = vec![&m; MAX_CACHE_MATERIALS];
    assert_eq!(Owned::memory_for(&most, 5).unwrap(), want);
    let mut cache = TileCache::with_capacity(&most, 5).unwrap();
    cache.begin_frame();
    cache.mark_texel(MAX_CACHE_MATERIALS - 1, 0, 0, 0).unwrap();
    assert_eq!(cache.pending().count(), 1);
    bad(cache.mark_texel(MAX_CACHE_MATERIALS, 0, 0, 0), Argument::Material);
}

#[test]
fn footprints_from_threads_marked_together_equal_marking_each_lookup() {
    let bytes = fixture_bytes();
    let materials: Vec<Material> = bytes.iter().map(|b| Container::parse(b).unwrap()).collect();
    let refs: Vec<&Material> = materials.iter().collect();
    let decoders: Vec<Decoder> = materials.iter().map(Decoder::new).collect();
    let decoders: Vec<&Decoder> = decoders.iter().collect();
    let reqs = requests(&materials, 5, 1200);
    let mut one = TileCache::with_capacity(&refs, 1024).unwrap();
    let by_lookup = frame(&mut one, &materials, &decoders, &reqs);

    let mut split = TileCache::with_capacity(&refs, 1024).unwrap();
    split.begin_frame();
    let keys: Vec<_> = std::thread::scope(|s| {
        let cache = &split;
        let jobs: Vec<_> = reqs
            .chunks(400)
            .map(|part| {
                s.spawn(move || {
                    part.iter()
                        .flat_map(|(i, r)| cache.footprint(*i, r).unwrap())
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        jobs.into_iter().flat_map(|j| j.join().unwrap()).collect()
    });
    assert!(keys.len() > by_lookup.marked as usize, "repeats are listed: {}", keys.len());
    split.mark_tiles(&keys).unwrap();
    assert_eq!(split.stats().marked, by_lookup.marked);
    split.decode_missing_with(&decoders).unwrap();
    assert_resolved_equal_sample(&split, &materials, &reqs);
    assert_eq!(split.end_frame().resolve_misses, 0);

    // Keys the materials do not have are refused.
    let key = |material, mip, x, y| nmat_core::TileKey { material, mip, x, y };
    bad(split.mark_tiles(&[key(4, 0, 0, 0)]), Argument::Material);
    bad(split.mark_tiles(&[key(0, 7, 0, 0)]), Argument::Mip); // 64×64: 7 mips, 0 to 6
    bad(split.mark_tiles(&[key(0, 0, 4, 0)]), Argument::Region); // 4 tiles across
    bad(split.mark_tiles(&[key(2, 0, 0, 2)]), Argument::Region); // 37×21: 2 tile rows
    split.mark_tiles(&[key(0, 6, 0, 0), key(2, 0, 2, 1)]).unwrap();
}

/// Many frames of random lookups through caches of several sizes, marked lookup by lookup and in
/// batches: whatever the hash chains, evictions and slot reuse did, every value equals
/// `Material::sample`, a frame's counters add up, and the tiles kept match a model of the
/// protocol.
#[test]
fn random_frames_through_small_caches_keep_the_books_and_the_values() {
    use std::collections::HashSet;
    let bytes = fixture_bytes();
    let materials: Vec<Material> = bytes.iter().map(|b| Container::parse(b).unwrap()).collect();
    let refs: Vec<&Material> = materials.iter().collect();
    let decoders: Vec<Decoder> = materials.iter().map(Decoder::new).collect();
    let decoders: Vec<&Decoder> = decoders.iter().collect();
    let mut r = Rng::new(99);
    for (capacity, batched) in [1, 2, 7, 16, 61].into_iter().flat_map(|c| [(c, false), (c, true)]) {
        let mut cache = TileCache::with_capacity(&refs, capacity).unwrap();
        // The tiles the model says are cached between frames.
        let (mut kept, mut frames) = (HashSet::new(), 0);
        for _ in 0..25 {
            let reqs = requests(&materials, r.next_u64(), r.range(1, 40) as usize);
            let mut wanted = HashSet::new();
            for (i, req) in &reqs {
                wanted.extend(cache.footprint(*i, req).unwrap());
            }
            // `frame` also checks every resolved value against `Material::sample`.
            let s = frame_marked(&mut cache, &materials, &decoders, &reqs, batched);
            frames += 1;
            assert_eq!(s.frame, frames);
            assert_eq!(s.marked, s.hits + s.decoded, "{s:?}");
            if wanted.len() <= capacity {
                assert_eq!(s.marked as usize, wanted.len(), "{s:?}");
                assert_eq!((s.overflowed, s.resolve_misses), (0, 0), "{s:?}");
                // Tiles alive at the end = alive at the start + decoded − evicted.
                assert_eq!(s.evicted + s.marked, kept.len() as u32 + s.decoded, "{s:?}");
                let both = kept.intersection(&wanted).count();
                if batched || kept.union(&wanted).count() <= capacity {
                    // Room for all, or marked as one batch (kept tiles first): every kept tile
                    // wanted again is a hit, the others go at the end of the frame or to new
                    // tiles.
                    assert_eq!(s.hits as usize, both, "{s:?}");
                } else {
                    // New tiles may take the slots of kept ones before the frame marks them.
                    assert!(s.hits as usize <= both, "{s:?}");
                }
                kept = wanted;
            } else {
                // Every slot ends the frame holding one of its tiles; the rest overflowed.
                assert_eq!(s.marked as usize, capacity, "{s:?}");
                assert!(s.overflowed as usize >= wanted.len() - capacity, "{s:?}");
                assert!(s.resolve_misses > 0, "{s:?}");
                // Which tiles stayed is the cache's choice: an empty frame evicts them all.
                cache.begin_frame();
                assert_eq!(cache.end_frame().evicted, s.marked);
                (kept, frames) = (HashSet::new(), frames + 1);
            }
        }
    }
}

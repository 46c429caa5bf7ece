//! The tile cache on the GPU (`GpuTileCache`) against the CPU's (`nmat_core::TileCache`), with
//! neural (wrap; clamp with 10 channels) and JPEG (4:2:0) materials in one cache and every
//! filter: the same counters frame after frame, the same tiles with the CPU's codes byte for
//! byte, resolved values equal to the CPU's (to f32 rounding) and to the sampling module's
//! `nmat_sample` bit for bit; the engine's module resolves like the recorded pass; new tiles
//! decode alike through every kernel; a cache too small overflows as documented; refusals.
//! Coordinates are dyadic, so the f32 footprints of the GPU and the f64 ones of the CPU pick the
//! same texels (filter.wgsl).
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use std::collections::BTreeMap;

use nmat_core::{
    ChannelMask, Container, Filter, FrameStats, Material, SampleRequest, TileCache, TileKey,
};
use nmat_tests::fixtures_dir;
use nmat_wgpu::{CacheLookup, Context, GpuError, GpuTileCache, Kernel, SampleBindings};

mod common;
use common::{buffer, device, lookups, run_as_a_browser, submit_and_read};

fn fixture_bytes() -> Vec<Vec<u8>> {
    ["ntc_rgb_64.nmat", "ntc_pbr10_96x80_clamp.nmat", "jpeg/pattern_420_37x21.nmat"]
        .iter()
        .map(|name| std::fs::read(fixtures_dir().join(name)).unwrap())
        .collect()
}

/// The fixtures of [`fixture_bytes`] parsed.
fn parse(bytes: &[Vec<u8>]) -> Vec<Material<'_>> {
    bytes.iter().map(|b| Container::parse(b).unwrap()).collect()
}

/// `materials` uploaded (each with the kernel `upload` picks) and a GPU cache of `slots` tiles
/// over them.
fn gpu_cache(
    ctx: &Context,
    (device, queue): (&wgpu::Device, &wgpu::Queue),
    materials: &[Material<'_>],
    slots: u32,
) -> (Vec<nmat_wgpu::GpuMaterial>, GpuTileCache) {
    let gpus: Vec<_> = materials.iter().map(|m| ctx.upload(device, queue, m).unwrap()).collect();
    let cache = ctx.create_tile_cache(device, &gpus.iter().collect::<Vec<_>>(), slots).unwrap();
    (gpus, cache)
}

fn to_words(bytes: &[u8]) -> Vec<u32> {
    bytes.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
}

/// A storage buffer holding `lookups`.
fn lookup_buffer(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    lookups: &[(usize, SampleRequest)],
) -> wgpu::Buffer {
    let items: Vec<CacheLookup> =
        lookups.iter().map(|(i, req)| CacheLookup::new(*i as u32, req)).collect();
    let bytes = CacheLookup::bytes(&items);
    let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
    let b = buffer(device, bytes.len().max(32) as u64, usage, None);
    queue.write_buffer(&b, 0, &bytes);
    b
}

/// One frame through the GPU cache: its counters and the 16 resolved values per lookup.
fn gpu_frame(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    cache: &GpuTileCache,
    lookups: &[(usize, SampleRequest)],
) -> (FrameStats, Vec<u32>) {
    let input = lookup_buffer(device, queue, lookups);
    let count = lookups.len() as u32;
    gpu_frame_with(device, queue, cache, (&input, count), &output_buffer(device, count))
}

/// A buffer for the 16 resolved values of `count` lookups.
fn output_buffer(device: &wgpu::Device, count: u32) -> wgpu::Buffer {
    let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
    buffer(device, 64 * u64::from(count).max(1), usage, None)
}

/// [`gpu_frame`] with the lookups already in `input`, resolved into `out`.
fn gpu_frame_with(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    cache: &GpuTileCache,
    (input, count): (&wgpu::Buffer, u32),
    out: &wgpu::Buffer,
) -> (FrameStats, Vec<u32>) {
    let mut encoder = device.create_command_encoder(&Default::default());
    cache.record_begin_frame(&mut encoder);
    cache.record_mark(device, &mut encoder, (input, 0, count)).unwrap();
    cache.record_decode_missing(&mut encoder);
    let written = cache
        .record_resolve(device, &mut encoder, (input, 0, count), ChannelMask::ALL, (out, 0))
        .unwrap();
    assert_eq!(written, 16 * u64::from(count));
    cache.record_end_frame(&mut encoder);
    let values = to_words(&submit_and_read(device, queue, encoder, out));
    let stats = cache.read_stats(device).unwrap();
    let (again, _) = run_as_a_browser(device, cache.read_stats_async());
    assert_eq!(again.unwrap(), stats, "read_stats_async");
    (stats, values)
}

/// One frame through the CPU cache (marking each lookup): counters, tiles marked, values.
fn cpu_frame<S, T>(
    cache: &mut TileCache<'_, S, T>,
    lookups: &[(usize, SampleRequest)],
) -> (FrameStats, Vec<TileKey>, Vec<[f32; 16]>)
where
    S: AsRef<[nmat_core::Slot]> + AsMut<[nmat_core::Slot]>,
    T: AsRef<[u8]> + AsMut<[u8]>,
{
    cache.begin_frame();
    let mut keys = Vec::new();
    for (i, req) in lookups {
        keys.extend(cache.footprint(*i, req).unwrap());
        cache.mark(*i, req).unwrap();
    }
    cache.decode_missing().unwrap();
    let values = lookups
        .iter()
        .map(|(i, req)| {
            let mut v = [0f32; 16];
            cache.resolve(*i, req, &mut v).unwrap();
            v
        })
        .collect();
    keys.sort_by_key(|k| (k.material, k.mip, k.y, k.x));
    keys.dedup();
    (cache.end_frame(), keys, values)
}

/// The codes the CPU decodes for tile `key`: 16 × 16 texels, every channel, 0 past the edge.
fn cpu_tile(m: &Material<'_>, key: TileKey) -> Vec<u8> {
    let n = m.channel_count();
    let (w, h) = m.mip_size(u32::from(key.mip));
    let mut out = vec![0u8; 256 * n];
    for t in 0..256u32 {
        let (x, y) = (u32::from(key.x) * 16 + t % 16, u32::from(key.y) * 16 + t / 16);
        if x < w && y < h {
            let at = t as usize * n;
            let texel = &mut out[at..at + n];
            m.decode_texel_u8(
                i64::from(x),
                i64::from(y),
                u32::from(key.mip),
                ChannelMask::ALL,
                texel,
            )
            .unwrap();
        }
    }
    out
}

/// The GPU's resident tiles are `keys`, each with the CPU's codes.
fn assert_tiles(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    cache: &GpuTileCache,
    materials: &[Material<'_>],
    keys: &[TileKey],
) -> BTreeMap<(u16, u8, u16, u16), Vec<u8>> {
    let tiles: BTreeMap<_, _> = cache
        .resident_tiles(device, queue)
        .unwrap()
        .into_iter()
        .map(|(k, codes)| ((k.material, k.mip, k.x, k.y), codes))
        .collect();
    let want: Vec<_> = keys.iter().map(|k| (k.material, k.mip, k.x, k.y)).collect();
    let got: Vec<_> = tiles.keys().copied().collect();
    let mut want_sorted = want.clone();
    want_sorted.sort();
    let missing: Vec<_> = want_sorted.iter().filter(|k| !got.contains(k)).collect();
    let extra: Vec<_> = got.iter().filter(|k| !want_sorted.contains(k)).collect();
    assert!(
        missing.is_empty() && extra.is_empty(),
        "the GPU lacks {missing:?} and holds {extra:?} (of {} tiles)",
        want_sorted.len()
    );
    for (&(material, mip, x, y), codes) in &tiles {
        let key = TileKey { material, mip, x, y };
        assert!(*codes == cpu_tile(&materials[usize::from(material)], key), "tile {key:?} differs");
    }
    tiles
}

/// GPU values (16 f32 bits per lookup) agree with the CPU's to f32 rounding of each channel's
/// range.
fn assert_values_close(
    materials: &[Material<'_>],
    lookups: &[(usize, SampleRequest)],
    gpu: &[u32],
    cpu: &[[f32; 16]],
    only: impl Fn(usize) -> bool,
) {
    for (k, ((i, req), want)) in lookups.iter().zip(cpu).enumerate() {
        if !only(k) {
            continue;
        }
        let m = &materials[*i];
        for c in 0..16 {
            let got = f32::from_bits(gpu[16 * k + c]);
            if c >= m.channel_count() {
                assert_eq!(got, 0.0, "lookup {k}: channel {c} the material lacks");
                continue;
            }
            let ch = &m.channels()[c];
            let width = (ch.range_max - ch.range_min).abs().max(1e-6);
            let off = (got - want[c]).abs() / width;
            assert!(
                off <= 1e-5,
                "lookup {k} ({req:?}, material {i}), channel {c}: {got} vs {}",
                want[c]
            );
        }
    }
}

/// A compute shader writing, per lookup, 16 values of `call` (an expression of `material`, `uv`,
/// `lod`, `rnd`, `mode`) after `module`; bindings 0 and 1 the module's, 2 the lookups, 3 out.
fn lookup_shader(module: &str, call: &str, workgroup: u32) -> String {
    format!(
        "{module}\n\
         @group(0) @binding(2) var<storage, read> lookups: array<u32>;\n\
         @group(0) @binding(3) var<storage, read_write> out: array<f32>;\n\
         @compute @workgroup_size({workgroup})\n\
         fn main(@builtin(global_invocation_id) id: vec3<u32>) {{\n\
             let i = id.x;\n\
             if (i >= arrayLength(&lookups) / 8u) {{ return; }}\n\
             let material = lookups[8u * i + 3u];\n\
             let uv = vec2<f32>(bitcast<f32>(lookups[8u * i]), bitcast<f32>(lookups[8u * i + 1u]));\n\
             let lod = bitcast<f32>(lookups[8u * i + 2u]);\n\
             let mode = lookups[8u * i + 4u];\n\
             let rnd = vec3<f32>(bitcast<f32>(lookups[8u * i + 5u]), bitcast<f32>(lookups[8u * i + 6u]), bitcast<f32>(lookups[8u * i + 7u]));\n\
             let v = {call};\n\
             for (var c = 0u; c < 16u; c++) {{ out[16u * i + c] = v[c]; }}\n\
         }}\n"
    )
}

/// Runs `lookup_shader` with the module's two bind group entries; returns the values' bits.
fn run_lookup_shader(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    source: &str,
    entries: [wgpu::BindGroupEntry<'_>; 2],
    lookups: &[(usize, SampleRequest)],
    workgroup: u32,
) -> Vec<u32> {
    let pipeline = common::compute_pipeline(device, source, None);
    let input = lookup_buffer(device, queue, lookups);
    let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
    let out = buffer(device, 64 * lookups.len() as u64, usage, None);
    let [a, b] = entries;
    let entries = [
        a,
        b,
        wgpu::BindGroupEntry { binding: 2, resource: input.as_entire_binding() },
        wgpu::BindGroupEntry { binding: 3, resource: out.as_entire_binding() },
    ];
    let groups = ((lookups.len() as u32).div_ceil(workgroup), 1);
    to_words(&common::run_compute((device, queue), &pipeline, &entries, groups, &out))
}

#[test]
fn frames_match_the_cpu_cache_tile_for_tile_and_value_for_value() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = fixture_bytes();
    let materials = parse(&bytes);
    let refs: Vec<&Material<'_>> = materials.iter().collect();
    let (gpus, cache) = gpu_cache(&ctx, (&device, &queue), &materials, 512);
    assert_eq!(cache.capacity(), 512);
    let mut cpu = TileCache::with_capacity(&refs, 512).unwrap();

    // Frame 1, frame 2 (half of frame 1's lookups and new ones), frame 3 (none of them).
    let first = lookups(&materials, 1, 1500);
    let second: Vec<_> = first[750..].iter().cloned().chain(lookups(&materials, 2, 600)).collect();
    let third = lookups(&materials, 3, 400);
    for (f, frame) in [first, second, third].iter().enumerate() {
        let (cpu_stats, keys, cpu_values) = cpu_frame(&mut cpu, frame);
        let (gpu_stats, gpu_values) = gpu_frame(&device, &queue, &cache, frame);
        assert_eq!(gpu_stats, cpu_stats, "frame {}", f + 1);
        assert!(cpu_stats.marked > 0 && cpu_stats.overflowed == 0 && cpu_stats.resolve_misses == 0);
        if f > 0 {
            assert!(cpu_stats.hits > 0 && cpu_stats.evicted > 0, "frame {}: {cpu_stats:?}", f + 1);
        }
        assert_tiles(&device, &queue, &cache, &materials, &keys);
        assert_values_close(&materials, frame, &gpu_values, &cpu_values, |_| true);

        // The engine's module resolves like the pass, bit for bit.
        let bindings = SampleBindings { group: 0, first_binding: 0 };
        let source = lookup_shader(
            &GpuTileCache::sample_module(bindings),
            "nmat_cache_sample(material, uv, lod, rnd, mode, NMAT_ALL_CHANNELS)",
            64,
        );
        let engine =
            run_lookup_shader(&device, &queue, &source, cache.sample_entries(bindings), frame, 64);
        assert!(engine == gpu_values, "frame {}: the module differs from the resolve pass", f + 1);

        // Neural lookups equal the sampling module's nmat_sample, bit for bit (a workgroup's
        // lookups mix filters: on lavapipe this needs texel.wgsl's loops far below its cap,
        // docs/GPU.md, "Known problems").
        for (k, gpu) in gpus.iter().enumerate() {
            if gpu.codec() != nmat_core::Codec::Neural {
                continue;
            }
            let own: Vec<_> = frame.iter().filter(|(i, _)| *i == k).cloned().collect();
            let source = lookup_shader(
                &bindings.module(),
                "nmat_sample(uv, lod, rnd, mode, NMAT_ALL_CHANNELS)",
                64,
            );
            let direct = run_lookup_shader(
                &device,
                &queue,
                &source,
                gpu.sample_entries(bindings).unwrap(),
                &own,
                64,
            );
            let cached: Vec<u32> = frame
                .iter()
                .enumerate()
                .filter(|(_, (i, _))| *i == k)
                .flat_map(|(j, _)| gpu_values[16 * j..16 * j + 16].to_vec())
                .collect();
            if let Some(j) = (0..direct.len()).find(|&j| direct[j] != cached[j]) {
                let l = &own[j / 16];
                panic!(
                    "frame {}, material {k}: value {j} is {} by nmat_sample, {} from the cache ({:?})",
                    f + 1,
                    f32::from_bits(direct[j]),
                    f32::from_bits(cached[j]),
                    l
                );
            }
        }
    }
}

/// A cache decodes its new tiles through each material's kernel (the tiled kernels' own
/// `tiled_cache` entry, the others one texel per invocation): whatever kernel the neural
/// materials were uploaded with, the tiles hold the CPU's codes (edge tiles and small mips
/// included: the fixtures are 64² and 96 × 80, so their chains end in partial tiles).
#[test]
fn new_tiles_decode_alike_through_every_kernel() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = fixture_bytes();
    let materials = parse(&bytes);
    let frame = lookups(&materials, 5, 300);
    for kernel in Kernel::ALL {
        new_tiles_decode_alike_through(&ctx, (&device, &queue), &materials, &frame, kernel, false);
    }
}

/// The matrix kernel's tile entry, its matrix operations emulated (lavapipe has no matrix
/// units), in two layouts the default one does not cover: with its weights read from a storage
/// buffer (a bind group of its own, set with each material's decode of new tiles), and with
/// three subgroups a workgroup (batches of 48 texels, so a tile's 256 end in a partial batch,
/// whose texels past the tile must not be stored). The tiles are the CPU's.
#[test]
fn new_tiles_decode_alike_through_the_matrix_kernel_in_other_layouts() {
    let Some((device, queue)) = common::device_with_f16() else { return };
    let bytes = fixture_bytes();
    let materials = parse(&bytes);
    let device_queue = (&device, &queue);
    for (seed, storage, layout) in [(6, true, (4, 1, 4)), (7, false, (3, 1, 4))] {
        let ctx = Context::new(&device);
        ctx.emulate_matrix_for_testing(false, storage);
        ctx.emulate_matrix_layout_for_testing(layout, (8, 8, 4));
        let frame = lookups(&materials, seed, 300);
        new_tiles_decode_alike_through(
            &ctx,
            device_queue,
            &materials,
            &frame,
            Kernel::Matrix,
            true,
        );
        // The layout was taken: a workgroup decodes four batches of 16 texels a subgroup.
        let gm = ctx.upload_with(&device, &queue, &materials[1], Some(Kernel::Matrix)).unwrap();
        assert_eq!(gm.workgroup_texels(), Some(16 * layout.0 * layout.2), "{layout:?}");
    }
}

/// The neural `materials` uploaded with `kernel` (the others as `upload` picks) decode the new
/// tiles of `frame` through its tile entry as the CPU does: counters and every tile's codes
/// (noted and skipped where the device cannot run the kernel, unless `required` or the
/// environment requires it; a kernel whose probe differs from the CPU's always fails).
fn new_tiles_decode_alike_through(
    ctx: &Context,
    (device, queue): (&wgpu::Device, &wgpu::Queue),
    materials: &[Material<'_>],
    frame: &[(usize, SampleRequest)],
    kernel: Kernel,
    required: bool,
) {
    let absent = |k: Kernel, reason: &str| {
        let env = match k {
            Kernel::Dot4 | Kernel::UnrolledDot4 => "NMAT_REQUIRE_DOT4",
            Kernel::Matrix => "NMAT_REQUIRE_MATRIX",
            _ => return false,
        };
        !required && std::env::var_os(env).is_none() && !reason.contains("differ")
    };
    let mut gpus = Vec::new();
    for m in materials {
        let forced = (m.codec() == nmat_core::Codec::Neural).then_some(kernel);
        match ctx.upload_with(device, queue, m, forced) {
            Ok(gm) => gpus.push(gm),
            Err(GpuError::Kernel { kernel, reason }) if absent(kernel, reason) => {}
            Err(e) => panic!("{kernel:?}: {e}"),
        }
    }
    if gpus.len() < materials.len() {
        eprintln!("{} kernel not tested here", kernel.name());
        return;
    }
    for (gm, m) in gpus.iter().zip(materials) {
        // A tiled or matrix kernel decodes the tiles through its own tile entry (its probe
        // tiles passed); the reference kernel and JPEG one texel per invocation.
        let own = m.codec() == nmat_core::Codec::Neural && kernel != Kernel::Reference;
        let want = if own { kernel } else { Kernel::Reference };
        assert_eq!(gm.tile_kernel(), want, "{kernel:?}");
    }
    let gpu_refs: Vec<_> = gpus.iter().collect();
    let cache = ctx.create_tile_cache(device, &gpu_refs, 512).unwrap();
    let refs: Vec<&Material<'_>> = materials.iter().collect();
    let mut cpu = TileCache::with_capacity(&refs, 512).unwrap();
    let (cpu_stats, keys, _) = cpu_frame(&mut cpu, frame);
    let (gpu_stats, _) = gpu_frame(device, queue, &cache, frame);
    assert_eq!(gpu_stats, cpu_stats, "{kernel:?}");
    assert!(cpu_stats.decoded > 0);
    assert_tiles(device, queue, &cache, materials, &keys);
}

/// A kernel's tile entry that stores wrong codes (broken on purpose: every word's lowest bit
/// flipped) fails its probe tiles at upload: the material keeps its kernel for regions and
/// requests, its tiles decode one texel per invocation, and the cache's tiles are the CPU's.
#[test]
fn a_tile_entry_that_decodes_wrong_is_not_used() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    ctx.break_tile_decoders_for_testing();
    let bytes = fixture_bytes();
    let materials = parse(&bytes);
    let refs: Vec<&Material<'_>> = materials.iter().collect();
    let (gpus, cache) = gpu_cache(&ctx, (&device, &queue), &materials, 512);
    for (gm, m) in gpus.iter().zip(&materials) {
        if m.codec() == nmat_core::Codec::Neural {
            assert_ne!(gm.kernel(), Kernel::Reference, "upload picks a tiled or matrix kernel");
        }
        assert_eq!(gm.tile_kernel(), Kernel::Reference);
    }
    let mut cpu = TileCache::with_capacity(&refs, 512).unwrap();
    let frame = lookups(&materials, 8, 300);
    let (cpu_stats, keys, _) = cpu_frame(&mut cpu, &frame);
    let (gpu_stats, _) = gpu_frame(&device, &queue, &cache, &frame);
    assert_eq!(gpu_stats, cpu_stats);
    assert_tiles(&device, &queue, &cache, &materials, &keys);
}

/// A frame of a few trilinear lookups, so that each tile is marked by one lookup's taps alone (in
/// a dense frame a neighbour's lookup marks it too): the marked tiles, counters and codes are the
/// CPU's.
#[test]
fn sparse_lookups_mark_every_tile_their_filter_reads() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = fixture_bytes();
    let materials = parse(&bytes);
    let refs: Vec<&Material<'_>> = materials.iter().collect();
    let (_gpus, cache) = gpu_cache(&ctx, (&device, &queue), &materials, 512);
    let mut cpu = TileCache::with_capacity(&refs, 512).unwrap();
    // Trilinear lookups between two mips of the chain: each reads tiles of two mips.
    let frame: Vec<_> = lookups(&materials, 7, 400)
        .into_iter()
        .filter(|(i, r)| {
            let last = materials[*i].mip_count() as f32 - 1.0;
            r.filter == Filter::Trilinear && r.lod.fract() != 0.0 && r.lod > 0.0 && r.lod < last
        })
        .take(6)
        .collect();
    assert_eq!(frame.len(), 6);
    let (cpu_stats, keys, cpu_values) = cpu_frame(&mut cpu, &frame);
    let (gpu_stats, gpu_values) = gpu_frame(&device, &queue, &cache, &frame);
    assert_eq!(gpu_stats, cpu_stats);
    assert_tiles(&device, &queue, &cache, &materials, &keys);
    assert_values_close(&materials, &frame, &gpu_values, &cpu_values, |_| true);
}

/// Frames that mark and resolve the same lookups into the same output make their bind groups
/// once: no allocation per frame after the first (another count or channel mask makes new ones),
/// and the kept bind groups resolve as fresh ones do.
#[test]
fn repeated_frames_reuse_their_bind_groups() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = fixture_bytes();
    let materials = parse(&bytes);
    let (_gpus, cache) = gpu_cache(&ctx, (&device, &queue), &materials, 512);
    let frame = lookups(&materials, 6, 200);
    let input = lookup_buffer(&device, &queue, &frame);
    let out = output_buffer(&device, 200);
    let (_, first) = gpu_frame_with(&device, &queue, &cache, (&input, 200), &out);
    assert_eq!(cache.bind_groups_made_for_testing(), 2, "a mark and a resolve");
    for _ in 0..3 {
        let (stats, values) = gpu_frame_with(&device, &queue, &cache, (&input, 200), &out);
        assert_eq!(values, first);
        assert!(stats.marked > 0 && stats.decoded == 0);
    }
    assert_eq!(cache.bind_groups_made_for_testing(), 2, "nothing made after the first frame");
    // Fewer lookups of the same buffer: new bind groups; values as a fresh frame of them gives.
    let (_, fewer) = gpu_frame_with(&device, &queue, &cache, (&input, 100), &out);
    assert_eq!(cache.bind_groups_made_for_testing(), 4);
    assert_eq!(fewer[..16 * 100], first[..16 * 100]);
}

#[test]
fn a_full_cache_overflows_counts_its_misses_and_keeps_what_it_holds_exact() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = fixture_bytes();
    let materials = parse(&bytes);
    let refs: Vec<&Material<'_>> = materials.iter().collect();
    let slots = 5;
    let (_gpus, cache) = gpu_cache(&ctx, (&device, &queue), &materials, slots);
    let mut cpu = TileCache::with_capacity(&refs, 1024).unwrap();
    let frame = lookups(&materials, 4, 600);
    let (big, keys, cpu_values) = cpu_frame(&mut cpu, &frame);
    for f in 1..=2u32 {
        let (stats, values) = gpu_frame(&device, &queue, &cache, &frame);
        // Frame 1: every slot free, 5 tiles decoded; frame 2: the same 5 kept (all marked).
        let decoded = if f == 1 { slots } else { 0 };
        let hits = if f == 1 { 0 } else { slots };
        let want = FrameStats {
            frame: f,
            marked: big.marked,
            hits,
            decoded,
            decoded_texels: stats.decoded_texels,
            evicted: 0,
            overflowed: big.marked - slots,
            resolve_misses: stats.resolve_misses,
        };
        assert_eq!(stats, want, "frame {f}");
        assert!(stats.resolve_misses > 0);
        // The tiles held are some of the frame's, with the CPU's codes; lookups whose tiles are
        // all held resolve exactly.
        let held = cache.resident_tiles(&device, &queue).unwrap();
        assert_eq!(held.len(), slots as usize);
        let mut held_keys = Vec::new();
        for (key, codes) in &held {
            assert!(keys.contains(key), "{key:?} was not marked");
            assert!(*codes == cpu_tile(&materials[usize::from(key.material)], *key));
            held_keys.push(*key);
        }
        let whole = |k: usize| {
            let (i, req) = &frame[k];
            cpu.footprint(*i, req).unwrap().iter().all(|t| held_keys.contains(t))
        };
        assert!((0..frame.len()).any(whole), "no lookup entirely in 5 tiles");
        assert_values_close(&materials, &frame, &values, &cpu_values, whole);
    }
}

#[test]
fn refusals_name_what_is_wrong() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = fixture_bytes();
    let m = Container::parse(&bytes[0]).unwrap();
    let gpu = ctx.upload(&device, &queue, &m).unwrap();
    let cache_error = |r: Result<GpuTileCache, GpuError>| match r {
        Err(GpuError::Cache { reason }) => reason,
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("accepted"),
    };
    assert!(cache_error(ctx.create_tile_cache(&device, &[], 8)).contains("materials"));
    assert!(cache_error(ctx.create_tile_cache(&device, &[&gpu], 0)).contains("slot"));
    let too_many = vec![&gpu; 65];
    assert!(cache_error(ctx.create_tile_cache(&device, &too_many, 8)).contains("materials"));
    let huge = ctx.create_tile_cache(&device, &[&gpu], u32::MAX / 256);
    assert!(cache_error(huge).contains("storage binding"));

    let cache = ctx.create_tile_cache(&device, &[&gpu], 8).unwrap();
    let mut encoder = device.create_command_encoder(&Default::default());
    let short = buffer(&device, 64, wgpu::BufferUsages::STORAGE, None);
    let no_storage = buffer(&device, 64, wgpu::BufferUsages::COPY_DST, None);
    let out = buffer(&device, 64, wgpu::BufferUsages::STORAGE, None);
    let request = |r: Result<(), GpuError>| match r {
        Err(GpuError::RequestBuffer { reason }) => reason,
        other => panic!("{other:?}"),
    };
    assert!(request(cache.record_mark(&device, &mut encoder, (&short, 0, 3))).contains("ends"));
    assert!(request(cache.record_mark(&device, &mut encoder, (&short, 2, 1))).contains("multiple"));
    assert!(
        request(cache.record_mark(&device, &mut encoder, (&no_storage, 0, 1))).contains("STORAGE")
    );
    let resolve = |channels, out_buffer: &wgpu::Buffer, count| {
        cache.record_resolve(
            &device,
            &mut device.create_command_encoder(&Default::default()),
            (&short, 0, count),
            channels,
            (out_buffer, 0),
        )
    };
    assert!(matches!(resolve(ChannelMask(0), &out, 1), Err(GpuError::Channels { mask: 0 })));
    assert!(matches!(
        resolve(ChannelMask::ALL, &out, 2),
        Err(GpuError::Output { needed: 128, size: 64 })
    ));
    assert!(matches!(resolve(ChannelMask(0b111), &out, 2), Ok(6)));
    drop(queue);
}

//! nmat-wgpu in a browser: WebGPU through wgpu's browser backend, where no call may block. Built
//! for `wasm32-unknown-unknown` only and run by `scripts/test-web.sh` (wasm-bindgen-test in a
//! headless Chromium); natively this file is empty (`tests/record.rs` runs the same calls as a
//! browser would). Every code and block against the CPU's.
#![cfg(target_arch = "wasm32")]
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::bc::{BcFormat, BcTexture};
use nmat_core::{ChannelMask, Container, Material, TileCache};
use nmat_wgpu::{CacheLookup, Context, GpuError, Kernel};
use wasm_bindgen_test::{console_log, wasm_bindgen_test, wasm_bindgen_test_configure};

wasm_bindgen_test_configure!(run_in_browser);

mod common;
use common::{copy_level, cpu_blocks, lookups, unpadded_rows};

/// Neural golden fixtures (3 channels, wrap; 10 channels, clamp) and the JPEG one (4:2:0,
/// 37 × 21).
const RGB: &[u8] = include_bytes!("../../tests/fixtures/ntc_rgb_64.nmat");
const NEURAL: &[u8] = include_bytes!("../../tests/fixtures/ntc_pbr10_96x80_clamp.nmat");
const JPEG: &[u8] = include_bytes!("../../tests/fixtures/jpeg/pattern_420_37x21.nmat");

/// The CPU's codes of mip `mip`, row by row, every channel.
fn cpu_mip(m: &Material<'_>, mip: u32) -> Vec<u8> {
    let (w, h) = m.mip_size(mip);
    let mut out = Vec::new();
    let mut texel = [0u8; 16];
    for y in 0..h {
        for x in 0..w {
            let n = m
                .decode_texel_u8(i64::from(x), i64::from(y), mip, ChannelMask::ALL, &mut texel)
                .unwrap();
            out.extend_from_slice(&texel[..n]);
        }
    }
    out
}

/// Every mip of `gm` decoded on the GPU (submitted, then awaited) equals the CPU's.
async fn assert_every_mip(
    ctx: &Context,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    m: &Material<'_>,
    gm: &nmat_wgpu::GpuMaterial,
    what: &str,
) {
    for mip in 0..m.mip_count() {
        let (w, h) = m.mip_size(mip);
        let pending = ctx.submit_region(device, queue, gm, mip, (0, 0, w, h), ChannelMask::ALL);
        let codes = pending.unwrap().wait_async().await.unwrap();
        assert!(codes == cpu_mip(m, mip), "{what}: mip {mip} differs from the CPU's");
    }
}

/// The adapter is the browser's WebGPU; the blocking calls say so at once; `upload_async` checks
/// every kernel the browser runs against the CPU (their shaders' validation answered later
/// there, as a promise) and the chosen and each named kernel decode every mip as the CPU does;
/// BC blocks and a JPEG material too.
#[wasm_bindgen_test]
async fn the_calls_that_never_block_decode_exactly_in_a_browser() {
    let (device, queue, info) = nmat_wgpu::default_device().await.expect("a WebGPU adapter");
    console_log!(
        "adapter: {} ({:?}, {:?}, {})",
        info.name,
        info.backend,
        info.device_type,
        info.driver
    );
    assert_eq!(info.backend, wgpu::Backend::BrowserWebGpu);
    let m = Container::parse(NEURAL).unwrap();
    let ctx = Context::new(&device);
    assert!(matches!(ctx.upload(&device, &queue, &m), Err(GpuError::CannotWait)));
    let gm = ctx.upload_async(&device, &queue, &m).await.unwrap();
    console_log!(
        "upload_async chose the {} kernel (tiles: {})",
        gm.kernel().name(),
        gm.tile_kernel().name()
    );
    assert!(gm.rejected().is_empty(), "{:?}", gm.rejected());
    assert_every_mip(&ctx, &device, &queue, &m, &gm, gm.kernel().name()).await;
    let pending = ctx.submit_region(&device, &queue, &gm, 0, (0, 0, 8, 8), ChannelMask::ALL);
    assert!(matches!(pending.unwrap().wait(&device), Err(GpuError::CannotWait)));
    for kernel in Kernel::ALL {
        match ctx.upload_with_async(&device, &queue, &m, Some(kernel)).await {
            Ok(gm) => {
                assert_eq!(gm.kernel(), kernel);
                assert_every_mip(&ctx, &device, &queue, &m, &gm, kernel.name()).await;
                console_log!("the {} kernel: every mip as the CPU's", kernel.name());
            }
            Err(GpuError::Kernel { reason, .. }) if !reason.contains("differ") => {
                console_log!("the {} kernel does not run here: {reason}", kernel.name());
            }
            Err(e) => panic!("{}: {e}", kernel.name()),
        }
    }
    // BC1 and BC4 of mip 0, against the CPU's transcoder.
    let textures = [
        BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2, 0], srgb: false },
        BcTexture { format: BcFormat::Bc4, channels: [3, 0, 0, 0], srgb: false },
    ];
    let pending = ctx.submit_transcode_textures(&device, &queue, &gm, &textures, 0).unwrap();
    let got = pending.wait_async().await.unwrap();
    let cpu = nmat_core::Decoder::new(&m);
    for (texture, blocks) in textures.iter().zip(&got) {
        let want = cpu_blocks(&cpu, &m, texture, 0);
        assert!(*blocks == want, "{} blocks differ from the CPU's", texture.format.name());
    }
    // A JPEG material.
    let jm = Container::parse(JPEG).unwrap();
    let jgm = ctx.upload_async(&device, &queue, &jm).await.unwrap();
    assert_every_mip(&ctx, &device, &queue, &jm, &jgm, "JPEG").await;
}

/// The tile cache in a browser, over a neural material of each addressing and the JPEG one:
/// one frame of 300 lookups (every filter, across the edges and past both ends of the chains)
/// marked, decoded and resolved on the GPU (its passes' pipelines, built without waiting
/// there, compiled by the browser), with the CPU cache's counters (`read_stats_async`) and
/// values (to f32 rounding).
#[wasm_bindgen_test]
async fn the_tile_cache_resolves_as_the_cpus_in_a_browser() {
    let (device, queue, _) = nmat_wgpu::default_device().await.expect("a WebGPU adapter");
    let materials: Vec<Material<'_>> =
        [RGB, NEURAL, JPEG].iter().map(|b| Container::parse(b).unwrap()).collect();
    let ctx = Context::new(&device);
    let mut gpus = Vec::new();
    for m in &materials {
        gpus.push(ctx.upload_async(&device, &queue, m).await.unwrap());
    }
    let cache = ctx.create_tile_cache(&device, &gpus.iter().collect::<Vec<_>>(), 512).unwrap();
    let refs: Vec<&Material<'_>> = materials.iter().collect();
    let mut cpu = TileCache::with_capacity(&refs, 512).unwrap();
    // Dyadic coordinates: the GPU's f32 footprints and the CPU's f64 ones pick the same texels.
    let lookups = lookups(&materials, 11, 300);
    cpu.begin_frame();
    for (i, req) in &lookups {
        cpu.mark(*i, req).unwrap();
    }
    cpu.decode_missing().unwrap();
    let mut want = Vec::new();
    for (i, req) in &lookups {
        let mut v = [0f32; 16];
        cpu.resolve(*i, req, &mut v).unwrap();
        want.push(v);
    }
    let cpu_stats = cpu.end_frame();
    // The GPU's frame, recorded into one encoder.
    let items: Vec<CacheLookup> =
        lookups.iter().map(|(i, req)| CacheLookup::new(*i as u32, req)).collect();
    let bytes = CacheLookup::bytes(&items);
    let buffer = |size: u64, usage| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size,
            usage,
            mapped_at_creation: false,
        })
    };
    let input =
        buffer(bytes.len() as u64, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST);
    queue.write_buffer(&input, 0, &bytes);
    let count = lookups.len() as u32;
    let out =
        buffer(64 * u64::from(count), wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC);
    let mut encoder = device.create_command_encoder(&Default::default());
    cache.record_begin_frame(&mut encoder);
    cache.record_mark(&device, &mut encoder, (&input, 0, count)).unwrap();
    cache.record_decode_missing(&mut encoder);
    cache
        .record_resolve(&device, &mut encoder, (&input, 0, count), ChannelMask::ALL, (&out, 0))
        .unwrap();
    cache.record_end_frame(&mut encoder);
    queue.submit([encoder.finish()]);
    let values = nmat_wgpu::read_buffer_async(&device, &queue, &out).await.unwrap();
    assert_eq!(cache.read_stats_async().await.unwrap(), cpu_stats);
    console_log!("a frame: {cpu_stats:?}");
    for (k, ((i, req), want)) in lookups.iter().zip(&want).enumerate() {
        let m = &materials[*i];
        for (c, (ch, want)) in m.channels().iter().zip(want).enumerate() {
            let at = 4 * (16 * k + c);
            let got =
                f32::from_le_bytes([values[at], values[at + 1], values[at + 2], values[at + 3]]);
            let width = (ch.range_max - ch.range_min).abs().max(1e-6);
            assert!(
                (got - want).abs() / width <= 1e-5,
                "lookup {k} ({req:?}, material {i}), channel {c}: {got} vs {want}"
            );
        }
    }
}

/// What an engine takes into its own passes compiles in the browser and gives the CPU's results:
/// the sampling modules (`nmat_sample` for any material and specialised to one, the tile
/// cache's lookup for the engine's shaders) in a compute shader, validated by the browser's
/// compiler; every map of a material decoded into an `Rgba8Unorm` storage texture; blocks of
/// any pixels in BC1, BC4, BC5 and BC7 (RGB, RGBA), a material's BC7 texture, and wgpu BC
/// textures of its whole chain (`create_bc_textures`, every level copied back). (Before its
/// shaders spelt out their zero initializers, the BC7 blocks differed here: 451 of the
/// material's 480, and a single colour's partition.)
#[wasm_bindgen_test]
async fn the_shaders_an_engine_takes_compile_and_decode_in_a_browser() {
    let (device, queue, _) = nmat_wgpu::default_device().await.expect("a WebGPU adapter");
    let m = Container::parse(NEURAL).unwrap();
    let ctx = Context::new(&device);
    let gm = ctx.upload_async(&device, &queue, &m).await.unwrap();
    // The modules, each with a compute entry that calls it, refused by nothing.
    let bindings = nmat_wgpu::SampleBindings { group: 0, first_binding: 0 };
    let cache = ctx.create_tile_cache(&device, &[&gm], 64).unwrap();
    let sample = "nmat_sample(0u, uv, 0.5, vec3<f32>(0.25), NMAT_TRILINEAR, 0xFFFFu)";
    let modules = [
        ("nmat_sample", bindings.module(), sample.replace("0u, ", "")),
        (
            "nmat_sample for the material",
            bindings.module_for(&gm).unwrap(),
            sample.replace("0u, ", ""),
        ),
        (
            "the tile cache's lookup",
            nmat_wgpu::GpuTileCache::sample_module(bindings),
            sample.replace("nmat_sample", "nmat_cache_sample"),
        ),
    ];
    for (what, module, call) in modules {
        let source = format!(
            "{module}\n@group(0) @binding(9) var<storage, read_write> out: array<f32>;\n\
             @compute @workgroup_size(64)\n\
             fn main(@builtin(global_invocation_id) id: vec3<u32>) {{\n\
                 let uv = vec2<f32>(f32(id.x) / 64.0, 0.5);\n\
                 let v = {call};\n\
                 out[id.x] = v[0];\n\
             }}\n"
        );
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(what),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let _ = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(what),
            layout: None,
            module: &shader,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        if let Some(e) = scope.pop().await {
            panic!("{what}: the browser refused it: {e}");
        }
    }
    drop(cache);
    // Every map into a storage texture, read back through a buffer.
    let (w, h) = m.mip_size(0);
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage: wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    });
    let pitch = (4 * w).next_multiple_of(256);
    let back = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: u64::from(pitch * h),
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let all = cpu_mip(&m, 0);
    let n = m.channel_count();
    for map in nmat_core::bc::maps(&m) {
        let mut encoder = device.create_command_encoder(&Default::default());
        let target = nmat_wgpu::TextureTarget { texture: &texture, mip_level: 0, origin: (0, 0) };
        ctx.record_map_to_texture(&device, &mut encoder, &gm, 0, (0, 0, w, h), &map, target)
            .unwrap();
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &back,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(pitch),
                    rows_per_image: None,
                },
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        queue.submit([encoder.finish()]);
        let got = nmat_wgpu::read_buffer_async(&device, &queue, &back).await.unwrap();
        let (first, count) = (usize::from(map.first), usize::from(map.count));
        for y in 0..h as usize {
            for x in 0..w as usize {
                let texel = &got[y * pitch as usize + 4 * x..][..4];
                let codes = &all[(y * w as usize + x) * n + first..][..count];
                for (c, &got) in texel.iter().enumerate() {
                    let want = codes.get(c).copied().unwrap_or(if c == 3 { 255 } else { 0 });
                    let semantic = map.semantic;
                    assert_eq!(got, want, "{semantic:?} map, texel ({x}, {y}), component {c}");
                }
            }
        }
    }
    // Blocks of any pixels (single colours, two colours, a gradient, noise) in every format.
    let mut blocks = Vec::new();
    for v in [0u8, 1, 7, 100, 128, 255] {
        blocks.push(([[v, v, v, 255]; 16], 0xFFFFu16));
    }
    let mut two = [[10u8, 20, 30, 255]; 16];
    two[8..].fill([200, 150, 100, 40]);
    blocks.push((two, 0xFFFF));
    blocks.push((
        core::array::from_fn(|i| [(16 * i) as u8, (255 - 16 * i) as u8, (7 * i) as u8, 255]),
        0x7FFF,
    ));
    let mut r = nmat_tests::generate::Rng::new(3);
    for _ in 0..8 {
        let mut byte = || r.range(0, 255) as u8;
        blocks.push((core::array::from_fn(|_| [byte(), byte(), byte(), byte()]), 0xFFFF));
    }
    for format in [BcFormat::Bc1, BcFormat::Bc4, BcFormat::Bc5, BcFormat::Bc7Rgb, BcFormat::Bc7Rgba]
    {
        let pending = ctx.submit_encode_blocks(&device, &queue, format, &blocks).unwrap();
        let got = pending.wait_async().await.unwrap();
        let size = format.block_bytes();
        for (k, (pixels, valid)) in blocks.iter().enumerate() {
            let mut want = vec![0u8; size];
            nmat_core::bc::encode_block(format, pixels, *valid, &mut want);
            assert_eq!(got[size * k..size * (k + 1)], want[..], "{} block {k}", format.name());
        }
    }
    // wgpu BC textures of the whole chain in the default layout, every level read back.
    let layout = nmat_core::bc::default_layout(&m);
    let textures = ctx.create_bc_textures(&device, &queue, &gm, &layout).unwrap();
    let cpu = nmat_core::Decoder::new(&m);
    for (texture, bc) in textures.iter().zip(&layout) {
        for level in 0..m.mip_count() {
            let blocks = nmat_core::BlockRegion::mip(&m, level);
            let size = bc.format.block_bytes();
            let usage = wgpu::BufferUsages::COPY_SRC;
            let (back, pitch) = copy_level(&device, &queue, (texture, level), blocks, size, usage);
            let got = nmat_wgpu::read_buffer_async(&device, &queue, &back).await.unwrap();
            let got = unpadded_rows(&got, pitch, blocks.width as usize * size);
            let want = cpu_blocks(&cpu, &m, bc, level);
            assert!(got == want, "{} texture, level {level}: blocks differ", bc.format.name());
        }
    }
    // BC7 of the albedo, against the CPU's encoder.
    let texture = BcTexture { format: BcFormat::Bc7Rgb, channels: [0, 1, 2, 0], srgb: false };
    let pending = ctx.submit_transcode_textures(&device, &queue, &gm, &[texture], 0).unwrap();
    let got = pending.wait_async().await.unwrap();
    let want = cpu_blocks(&nmat_core::Decoder::new(&m), &m, &texture, 0);
    assert!(got[0] == want, "BC7 blocks differ from the CPU's");
}

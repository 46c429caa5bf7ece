//! BC transcoding on the GPU against the CPU, byte for byte: the GPU's BC1/BC4/BC5/BC7 encoders on
//! random and hard blocks against `nmat_core::bc::encode_block`, and decode + encode of every mip
//! of the golden fixtures, a trained material and a material with constant channels against
//! `Decoder::transcode_blocks` (also in bands of one block row), and whole chains made into wgpu
//! BC textures, read back and read by the texture unit. Runs on whatever adapter wgpu finds
//! (lavapipe in CI); no adapter is a failure.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::bc::{self, BcFormat, BcTexture, layout_with};
use nmat_core::{BlockRegion, Container, Decoder, Material};
use nmat_tests::fixtures_dir;
use nmat_tests::generate::{FixtureConfig, Rng, generate, golden_configs};
use nmat_wgpu::{Context, GpuError, GpuMaterial};

mod common;
use common::{assert_same_bytes, cpu_blocks, device, read_level, trained_material};

const GPU_FORMATS: [BcFormat; 5] =
    [BcFormat::Bc1, BcFormat::Bc4, BcFormat::Bc5, BcFormat::Bc7Rgb, BcFormat::Bc7Rgba];

fn byte(rng: &mut Rng) -> u8 {
    (rng.next_u64() >> 56) as u8
}

type Block = ([[u8; 4]; 16], u16);

/// Blocks of every kind an encoder branches on: noise, two-colour and gradient blocks with
/// a little noise, single colours (every value in some channel), the extremes 0 and 255, near-flat
/// blocks, ties on the principal axis, and random masks of valid pixels (none, one, edge shapes,
/// any).
fn hard_blocks(n: usize) -> Vec<Block> {
    let mut rng = Rng::new(0x9E37_79B9_7F4A_7C15);
    let mut blocks = Vec::new();
    for k in 0..n {
        let a: [u8; 4] = std::array::from_fn(|_| byte(&mut rng));
        let b: [u8; 4] = std::array::from_fn(|_| byte(&mut rng));
        let noise = [0u8, 1, 3, 12][k % 4];
        let mut jitter = |v: u8| {
            let d = (rng.next_u64() % (2 * u64::from(noise) + 1)) as i32 - i32::from(noise);
            (i32::from(v) + d).clamp(0, 255) as u8
        };
        let pixels: [[u8; 4]; 16] = match k % 8 {
            0 => std::array::from_fn(|_| std::array::from_fn(|_| byte(&mut rng))),
            1 => std::array::from_fn(|i| if (i * 7 + k) % 3 == 0 { a } else { b }),
            2 => std::array::from_fn(|i| {
                let t = i as i32;
                std::array::from_fn(|c| {
                    jitter((i32::from(a[c]) + (i32::from(b[c]) - i32::from(a[c])) * t / 15) as u8)
                })
            }),
            3 => [[(k / 8 % 256) as u8, (k * 3 % 256) as u8, a[2], a[3]]; 16],
            4 => std::array::from_fn(|i| [[0; 4], [255; 4], a][(i + k) % 3]),
            5 => std::array::from_fn(|_| a.map(&mut jitter)),
            // The corners of a square, as many pixels each: ties on the principal axis.
            6 => std::array::from_fn(|i| {
                let (x, y) = ((i + k) % 2, (i / 2 + k / 8) % 2);
                [x as u8 * a[0], y as u8 * a[0], a[2], a[3]]
            }),
            _ => {
                std::array::from_fn(
                    |i| if i % 5 == 0 { [0, 255, 0, 255] } else { a.map(&mut jitter) },
                )
            }
        };
        let valid = match k % 11 {
            0 => 0,
            1 => 1 << (k % 16),
            2 => bc::valid_mask(0, 0, 1 + (k % 4) as u32, 1 + (k / 4 % 4) as u32),
            3 => rng.next_u64() as u16,
            _ => bc::ALL_VALID,
        };
        blocks.push((pixels, valid));
    }
    blocks
}

#[test]
fn gpu_encoders_write_the_cores_bytes_for_any_block() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let blocks = hard_blocks(8 * 11 * 40);
    // BC7's modes and, for modes 4 and 5, rotations (0–3) and mode 4's selector among the
    // blocks compared: each branch of the encoder is met.
    let mut modes = [0u32; 8];
    let mut rotations = [[0u32; 2]; 4];
    for format in GPU_FORMATS {
        let gpu = ctx.encode_blocks(&device, &queue, format, &blocks).unwrap();
        let size = format.block_bytes();
        assert_eq!(gpu.len(), blocks.len() * size);
        for (k, ((pixels, valid), got)) in blocks.iter().zip(gpu.chunks(size)).enumerate() {
            let mut want = [0u8; 16];
            bc::encode_block(format, pixels, *valid, &mut want);
            assert_eq!(got, &want[..size], "{format:?} block {k} (valid {valid:#06x}): {pixels:?}");
            if matches!(format, BcFormat::Bc7Rgb | BcFormat::Bc7Rgba) {
                let mode = want[0].trailing_zeros() as usize;
                modes[mode.min(7)] += 1;
                if mode == 4 || mode == 5 {
                    let fields = usize::from(want[0]) >> (mode + 1);
                    rotations[fields & 3][if mode == 4 { (fields >> 2) & 1 } else { 0 }] += 1;
                }
            }
        }
    }
    assert!(modes[..7].iter().all(|&n| n > 0), "BC7 modes {modes:?}");
    assert!(rotations[1..].iter().flatten().all(|&n| n > 0), "rotations {rotations:?}");
    assert!(ctx.encode_blocks(&device, &queue, BcFormat::Bc1, &[]).unwrap().is_empty());
}

/// Every texture of `m` in BC1, BC4, BC5 and BC7 (each map in each format, and the default layout's
/// textures the GPU encodes), every mip, all textures of a mip in one call: the GPU's blocks
/// equal the CPU's. Every mip is submitted before the first is waited for (as `nmat transcode
/// --gpu` does), so each wait maps its blocks while later mips' passes, which reuse the
/// `Context`'s buffer of decoded codes, are still queued.
fn check_material(
    ctx: &Context,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    m: &Material<'_>,
    name: &str,
) {
    let gm = ctx.upload(device, queue, m).unwrap();
    let cpu = Decoder::new(m);
    let mut textures: Vec<BcTexture> = Vec::new();
    for format in GPU_FORMATS {
        textures.extend(layout_with(m, |_| Some(format)));
    }
    textures
        .extend(layout_with(m, |_| None).into_iter().filter(|t| GPU_FORMATS.contains(&t.format)));
    // All of them from one decode of the mip (each texture's channels at their place among
    // the decoded ones).
    let pending: Vec<_> = (0..m.mip_count())
        .map(|mip| ctx.submit_transcode_textures(device, queue, &gm, &textures, mip).unwrap())
        .collect();
    for (mip, pending) in (0..m.mip_count()).zip(pending) {
        let all = pending.wait(device).unwrap();
        assert_eq!(all.len(), textures.len());
        for (texture, gpu) in textures.iter().zip(all) {
            let want = cpu_blocks(&cpu, m, texture, mip);
            assert_same_bytes(&gpu, &want, format!("{name} {texture:?} mip {mip}"));
        }
    }
}

#[test]
fn golden_fixtures_transcode_identically_on_the_gpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    for cfg in golden_configs() {
        let bytes = std::fs::read(fixtures_dir().join(format!("{}.nmat", cfg.name))).unwrap();
        let m = Container::parse(&bytes).unwrap();
        check_material(&ctx, &device, &queue, &m, cfg.name);
    }
}

#[test]
fn trained_and_constant_channel_materials_transcode_identically_on_the_gpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let trained = trained_material();
    check_material(&ctx, &device, &queue, &Container::parse(&trained).unwrap(), "bricks");
    // Constant channels (range_min = range_max) take their value's code, not a decoded one.
    let mut spec = generate(&FixtureConfig::ntc("constants", 9, 21, 13, 10));
    for (c, v) in [(3, 0.0), (8, 0.75)] {
        spec.channels[c].range_min = v;
        spec.channels[c].range_max = v;
    }
    let bytes = spec.to_bytes().unwrap();
    check_material(&ctx, &device, &queue, &Container::parse(&bytes).unwrap(), "constants");
    // Each mip decoded and encoded in bands of one block row (as a mip whose codes exceed a
    // pass is), the bands' blocks at their rows.
    ctx.limit_pass_bytes_for_testing(1);
    let trained = Container::parse(&trained).unwrap();
    check_material(&ctx, &device, &queue, &trained, "bricks, one block row a pass");
}

/// A region recorded into the caller's encoder and buffer, at an offset with a padded row pitch,
/// holds the same blocks as the whole mip; bad arguments are refused before anything is recorded.
#[test]
fn recorded_regions_land_where_asked_and_bad_arguments_are_refused() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let cfg = golden_configs().into_iter().find(|c| c.name == "ntc_pbr10_96x80_clamp").unwrap();
    let bytes = generate(&cfg).to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let gm: GpuMaterial = ctx.upload(&device, &queue, &m).unwrap();
    let texture = BcTexture { format: BcFormat::Bc5, channels: [3, 4, 0, 0], srgb: false };
    let whole = ctx.transcode_mip(&device, &queue, &gm, &texture, 0).unwrap();
    let all = gm.blocks(0).unwrap();
    let region = BlockRegion { x: 3, y: 2, width: 9, height: 5 };
    let (offset, pitch) = (64u64, 9 * 16 + 52);
    let size = offset + 5 * pitch;
    let out = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let readback = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    ctx.record_transcode(&device, &mut encoder, &gm, &texture, 0, region, (&out, offset, pitch))
        .unwrap();
    encoder.copy_buffer_to_buffer(&out, 0, &readback, 0, size);
    queue.submit([encoder.finish()]);
    readback.map_async(wgpu::MapMode::Read, .., |r| r.unwrap());
    device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
    let got = readback.get_mapped_range(..).unwrap().to_vec();
    let whole_row = all.width as usize * 16;
    for r in 0..5usize {
        let at = offset as usize + r * pitch as usize;
        let from = (region.y as usize + r) * whole_row + region.x as usize * 16;
        assert_eq!(&got[at..at + 9 * 16], &whole[from..from + 9 * 16], "row {r}");
        assert!(
            got[at + 9 * 16..at + pitch as usize].iter().all(|&b| b == 0),
            "padding of row {r}"
        );
    }
    assert!(got[..offset as usize].iter().all(|&b| b == 0), "bytes before the offset");

    let mut encoder = device.create_command_encoder(&Default::default());
    let mut record = |texture: &BcTexture, mip, region, target| {
        ctx.record_transcode(&device, &mut encoder, &gm, texture, mip, region, target)
    };
    let fits = (&out, 0, 9 * 16);
    let missing = BcTexture { channels: [3, 10, 0, 0], ..texture };
    assert!(matches!(record(&missing, 0, region, fits), Err(GpuError::Channels { .. })));
    let past = BlockRegion { x: all.width - 8, ..region };
    assert!(matches!(record(&texture, 0, past, fits), Err(GpuError::Blocks { .. })));
    assert!(matches!(record(&texture, 99, region, fits), Err(GpuError::Blocks { .. })));
    assert!(matches!(
        record(&texture, 0, region, (&out, 0, 9 * 16 - 4)),
        Err(GpuError::RowPitch { .. })
    ));
    assert!(matches!(
        record(&texture, 0, region, (&out, 0, 9 * 16 + 2)),
        Err(GpuError::RowPitch { .. })
    ));
    assert!(matches!(
        record(&texture, 0, region, (&out, 2, 9 * 16)),
        Err(GpuError::OutputBuffer { .. })
    ));
    assert!(matches!(
        record(&texture, 0, region, (&readback, 0, 9 * 16)),
        Err(GpuError::OutputBuffer { .. })
    ));
    assert!(matches!(
        record(&texture, 0, region, (&out, size - 64, 9 * 16)),
        Err(GpuError::Output { .. })
    ));
}

/// Where the adapter samples BC textures, the blocks copy into a BC texture of the format
/// `texture_format` names and read back unchanged.
#[test]
fn blocks_copy_into_a_bc_texture() {
    let (device, queue) = device();
    if !device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC) {
        eprintln!("the adapter has no BC textures: nothing to copy into");
        return;
    }
    if !common::copies_bc_textures(&device) {
        eprintln!("wgpu's GL backend copies no padded rows into a compressed texture");
        return;
    }
    let ctx = Context::new(&device);
    let cfg = golden_configs().into_iter().find(|c| c.name == "ntc_pbr10_96x80_clamp").unwrap();
    let bytes = generate(&cfg).to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let texture = BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2, 0], srgb: true };
    let blocks = gm.blocks(0).unwrap();
    let pitch = nmat_wgpu::aligned_row_pitch(texture.format, blocks.width);
    let size = pitch * u64::from(blocks.height);
    let buffer = |usage| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size,
            usage,
            mapped_at_creation: false,
        })
    };
    let staging = buffer(wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC);
    let extent = wgpu::Extent3d {
        width: 4 * blocks.width,
        height: 4 * blocks.height,
        depth_or_array_layers: 1,
    };
    let gpu_texture = device.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size: extent,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: nmat_wgpu::texture_format(&texture).unwrap(),
        usage: wgpu::TextureUsages::COPY_DST
            | wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    });
    let layout = wgpu::TexelCopyBufferLayout {
        offset: 0,
        bytes_per_row: Some(pitch as u32),
        rows_per_image: Some(blocks.height),
    };
    let mut encoder = device.create_command_encoder(&Default::default());
    ctx.record_transcode(&device, &mut encoder, &gm, &texture, 0, blocks, (&staging, 0, pitch))
        .unwrap();
    encoder.copy_buffer_to_texture(
        wgpu::TexelCopyBufferInfo { buffer: &staging, layout },
        gpu_texture.as_image_copy(),
        extent,
    );
    queue.submit([encoder.finish()]);
    let want = ctx.transcode_mip(&device, &queue, &gm, &texture, 0).unwrap();
    assert_same_bytes(&read_level(&device, &queue, &gpu_texture, 0, blocks, 8), &want, "copied");
}

/// Whole BC textures made on the GPU (`create_bc_textures`, every level) hold the CPU's blocks
/// for every mip of the golden fixtures whose mip 0 a BC texture can have and of the trained
/// material — in the default layout and as BC7 — also when each mip goes in bands of one
/// block row; the device's texture unit reads mip 0 as the core's block decoder does (the
/// format each texture gets is the one its blocks are). On wgpu's GL backend, which reads no
/// compressed texture back into a buffer and fills the levels through `Queue::write_texture`,
/// the texture unit's reading of every level is the check.
#[test]
fn whole_chains_transcode_into_bc_textures() {
    let (device, queue) = device();
    if !device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC) {
        eprintln!("the adapter has no BC textures: nothing to transcode into");
        return;
    }
    let ctx = Context::new(&device);
    let copies = common::copies_bc_textures(&device);
    let golden: Vec<Vec<u8>> = golden_configs()
        .iter()
        .map(|cfg| std::fs::read(fixtures_dir().join(format!("{}.nmat", cfg.name))).unwrap())
        .collect();
    let trained = trained_material();
    let mut checked = 0;
    for (pass, bytes) in golden.iter().chain([&trained]).enumerate() {
        let m = Container::parse(bytes).unwrap();
        let gm = ctx.upload(&device, &queue, &m).unwrap();
        let mut textures: Vec<BcTexture> = layout_with(&m, |_| None)
            .into_iter()
            .filter(|t| GPU_FORMATS.contains(&t.format))
            .collect();
        if m.channel_count() >= 4 {
            textures.push(BcTexture {
                format: BcFormat::Bc7Rgba,
                channels: [0, 1, 2, 3],
                srgb: false,
            });
        }
        if m.channel_count() >= 3 {
            textures.push(BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2, 0], srgb: false });
        }
        if m.width() % 4 != 0 || m.height() % 4 != 0 {
            let refused = ctx.create_bc_textures(&device, &queue, &gm, &textures);
            assert!(
                matches!(refused, Err(GpuError::Texture { .. })),
                "{}×{}",
                m.width(),
                m.height()
            );
            continue;
        }
        // The trained material once more with one block row a band.
        for banded in [false, true].into_iter().take(if pass == golden.len() { 2 } else { 1 }) {
            if banded {
                ctx.limit_pass_bytes_for_testing(1);
            }
            let made = ctx.create_bc_textures(&device, &queue, &gm, &textures).unwrap();
            let cpu = Decoder::new(&m);
            for (texture, gpu_texture) in textures.iter().zip(&made) {
                assert_eq!(gpu_texture.mip_level_count(), m.mip_count());
                for mip in 0..m.mip_count() {
                    let want = cpu_blocks(&cpu, &m, texture, mip);
                    let what = format!("{texture:?} mip {mip} (banded: {banded})");
                    let gpu = (&device, &queue);
                    common::assert_bc_level(gpu, gpu_texture, mip, texture.format, &want, &what);
                    if mip == 0 && copies {
                        // The texture unit's reading too, against the core's block decoder (of
                        // the CPU's blocks, which the level holds, as just checked).
                        let format = texture.format;
                        common::assert_texture_unit_reads(
                            gpu,
                            gpu_texture,
                            0,
                            format,
                            &want,
                            &what,
                        );
                    }
                }
            }
            checked += 1;
        }
    }
    assert!(checked >= 8, "{checked} materials checked");
}

/// What a BC texture cannot hold is refused with a readable error before anything is recorded.
#[test]
fn bc_textures_refuse_what_they_cannot_hold() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let cfg = FixtureConfig { mip_count: 3, ..FixtureConfig::ntc("three_mips", 11, 24, 16, 4) };
    let bytes = generate(&cfg).to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let bc1 = BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2, 0], srgb: false };
    let usage = wgpu::TextureUsages::COPY_DST | wgpu::TextureUsages::TEXTURE_BINDING;
    let good = nmat_wgpu::bc_texture_descriptor(&gm, &bc1, usage).unwrap();
    assert_eq!((good.size.width, good.size.height, good.mip_level_count), (24, 16, 3));
    assert_eq!(good.format, wgpu::TextureFormat::Bc1RgbaUnorm);
    let missing = BcTexture { channels: [0, 1, 9, 0], ..bc1 };
    assert!(matches!(
        ctx.create_bc_textures(&device, &queue, &gm, &[missing]),
        Err(GpuError::Channels { .. })
    ));
    // A strip 1 texel wide: no BC texture has its size.
    let strip = generate(&FixtureConfig::ntc("strip", 12, 1, 37, 2)).to_bytes().unwrap();
    let strip = ctx.upload(&device, &queue, &Container::parse(&strip).unwrap()).unwrap();
    let bc4 = BcTexture { format: BcFormat::Bc4, channels: [0, 0, 0, 0], srgb: false };
    let refused = nmat_wgpu::bc_texture_descriptor(&strip, &bc4, usage);
    assert!(matches!(refused, Err(GpuError::Texture { .. })));
    assert!(refused.unwrap_err().to_string().contains("multiple of 4"));
    // A device made without BC textures.
    let (plain, plain_queue) = common::device_without_immediates();
    if !plain.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC) {
        let plain_ctx = Context::new(&plain);
        let plain_gm = plain_ctx.upload(&plain, &plain_queue, &m).unwrap();
        let refused = plain_ctx.create_bc_textures(&plain, &plain_queue, &plain_gm, &[bc1]);
        let message = refused.unwrap_err().to_string();
        assert!(message.contains("TEXTURE_COMPRESSION_BC"), "{message}");
    }
    if !device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC) {
        return;
    }
    if !common::copies_bc_textures(&device) {
        // Recording into a texture is refused, naming the ways around, before anything is
        // recorded.
        let target = device.create_texture(&good);
        let mut encoder = device.create_command_encoder(&Default::default());
        let refused = ctx.record_bc_textures(&device, &mut encoder, &gm, &[(&bc1, &target)]);
        let message = refused.unwrap_err().to_string();
        assert!(message.contains("create_bc_textures"), "{message}");
        return;
    }
    // Targets the chain does not fit: each refused.
    // The good descriptor with one thing changed.
    let make = |format, usage, width, levels| {
        device.create_texture(&wgpu::TextureDescriptor {
            size: wgpu::Extent3d { width, ..good.size },
            mip_level_count: levels,
            format,
            usage,
            ..good.clone()
        })
    };
    let bad = [
        make(wgpu::TextureFormat::Bc4RUnorm, usage, 24, 3),
        make(wgpu::TextureFormat::Bc1RgbaUnorm, wgpu::TextureUsages::TEXTURE_BINDING, 24, 3),
        make(wgpu::TextureFormat::Bc1RgbaUnorm, usage, 32, 3),
        make(wgpu::TextureFormat::Bc1RgbaUnorm, usage, 24, 4),
    ];
    for (target, what) in bad.iter().zip(["format", "COPY_DST", "size", "levels"]) {
        let mut encoder = device.create_command_encoder(&Default::default());
        let refused = ctx.record_bc_textures(&device, &mut encoder, &gm, &[(&bc1, target)]);
        let message = match refused {
            Err(e @ GpuError::Texture { .. }) => e.to_string(),
            other => panic!("{what}: {other:?}"),
        };
        eprintln!("{what}: {message}");
    }
    // A target with fewer levels than the material gets its first levels.
    let two = make(wgpu::TextureFormat::Bc1RgbaUnorm, usage | wgpu::TextureUsages::COPY_SRC, 24, 2);
    let mut encoder = device.create_command_encoder(&Default::default());
    ctx.record_bc_textures(&device, &mut encoder, &gm, &[(&bc1, &two)]).unwrap();
    queue.submit([encoder.finish()]);
    for mip in 0..2 {
        let want = ctx.transcode_mip(&device, &queue, &gm, &bc1, mip).unwrap();
        assert_eq!(read_level(&device, &queue, &two, mip, gm.blocks(mip).unwrap(), 8), want);
    }
}

//! Decoding into the caller's storage textures (`Context::record_map_to_texture`) against the
//! CPU, byte for byte: every map of a 10-channel golden material (1- and 3-channel maps) into an
//! `Rgba8Unorm` texture at an offset (all recorded into one encoder, through the `Context`'s one
//! codes buffer; also one row a pass), a one-channel map into `R8Unorm` where the device allows
//! that storage format, the texels around the region untouched, and bad targets refused.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::bc::{MapChannels, maps};
use nmat_core::{ChannelMask, Container};
use nmat_tests::generate::{generate, golden_configs};
use nmat_wgpu::{Context, GpuError, TexelRequest, TextureTarget};

mod common;
use common::{buffer, cpu_codes, device};

const SIZE: (u32, u32) = (40, 24);
/// The region: (x0, y0, width, height) of mip 1 (48 × 40), and where it goes in the texture.
const RECT: (u32, u32, u32, u32) = (3, 2, 21, 9);
const ORIGIN: (u32, u32) = (5, 3);

fn texture(
    device: &wgpu::Device,
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size: wgpu::Extent3d { width: SIZE.0, height: SIZE.1, depth_or_array_layers: 1 },
        mip_level_count: 2,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// Level 0 of `texture` (`bytes` per texel), row by row without padding.
fn read_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    mut encoder: wgpu::CommandEncoder,
    texture: &wgpu::Texture,
    bytes: u32,
) -> Vec<u8> {
    let pitch = (SIZE.0 * bytes).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let out = buffer(
        device,
        u64::from(pitch * SIZE.1),
        wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
        None,
    );
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &out,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(pitch),
                rows_per_image: None,
            },
        },
        wgpu::Extent3d { width: SIZE.0, height: SIZE.1, depth_or_array_layers: 1 },
    );
    let padded = common::submit_and_read(device, queue, encoder, &out);
    padded
        .chunks(pitch as usize)
        .flat_map(|row| row[..(SIZE.0 * bytes) as usize].to_vec())
        .collect()
}

/// What the texture must hold: the CPU's codes of `map` in [`RECT`] of mip 1 at the origin
/// (missing components 0, alpha 255 for RGBA), zeros elsewhere.
fn expected(m: &nmat_core::Material<'_>, map: &MapChannels, bytes: u32) -> Vec<u8> {
    expected_at(m, map, bytes, 1, RECT)
}

/// [`expected`] for the region `rect` of `mip`.
fn expected_at(
    m: &nmat_core::Material<'_>,
    map: &MapChannels,
    bytes: u32,
    mip: u32,
    rect: (u32, u32, u32, u32),
) -> Vec<u8> {
    let (first, count) = (u32::from(map.first), u32::from(map.count));
    let mask = ChannelMask((((1u32 << count) - 1) << first) as u16);
    let mut want = vec![0u8; (SIZE.0 * SIZE.1 * bytes) as usize];
    for j in 0..rect.3 {
        for i in 0..rect.2 {
            let r = TexelRequest { x: (rect.0 + i) as i32, y: (rect.1 + j) as i32, mip };
            let codes = cpu_codes(m, &[r], mask);
            let at = (((ORIGIN.1 + j) * SIZE.0 + ORIGIN.0 + i) * bytes) as usize;
            for c in 0..bytes as usize {
                want[at + c] = codes.get(c).copied().unwrap_or(if c == 3 { 255 } else { 0 });
            }
        }
    }
    want
}

/// The 10-channel golden material (albedo, normal and gray maps).
fn pbr10() -> Vec<u8> {
    let cfg = golden_configs().into_iter().find(|c| c.name == "ntc_pbr10_96x80_clamp").unwrap();
    generate(&cfg).to_bytes().unwrap()
}

#[test]
fn maps_decode_into_storage_textures_like_the_cpu() {
    let (device, queue) = device();
    maps_into_textures(&device, &queue, false);
    maps_into_textures(&device, &queue, true);
}

/// The same on a device without immediates: the store pass reads its parameters from a uniform.
#[test]
fn maps_decode_into_storage_textures_without_immediates() {
    let (device, queue) = common::device_without_immediates();
    maps_into_textures(&device, &queue, false);
    maps_into_textures(&device, &queue, true);
}

/// Every map of [`pbr10`] into its own `Rgba8Unorm` texture (and a gray one into `R8Unorm`
/// where the device has that storage format), compared with the CPU; `banded`: each region
/// decoded and stored one row a pass (as a region whose codes exceed a pass is).
fn maps_into_textures(device: &wgpu::Device, queue: &wgpu::Queue, banded: bool) {
    let ctx = Context::new(device);
    if banded {
        ctx.limit_pass_bytes_for_testing(1);
    }
    let bytes = pbr10();
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(device, queue, &m).unwrap();
    let usage = wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_SRC;
    let all = maps(&m);
    assert!(all.iter().any(|map| map.count == 1) && all.iter().any(|map| map.count == 3));
    // Every map recorded into one encoder (their codes pass through the same buffer), then read.
    let targets: Vec<wgpu::Texture> =
        all.iter().map(|_| texture(device, wgpu::TextureFormat::Rgba8Unorm, usage)).collect();
    let mut encoder = device.create_command_encoder(&Default::default());
    for (map, target) in all.iter().zip(&targets) {
        let at = TextureTarget { texture: target, mip_level: 0, origin: ORIGIN };
        ctx.record_map_to_texture(device, &mut encoder, &gm, 1, RECT, map, at).unwrap();
    }
    queue.submit([encoder.finish()]);
    for (map, target) in all.iter().zip(&targets) {
        let encoder = device.create_command_encoder(&Default::default());
        let got = read_texture(device, queue, encoder, target, 4);
        assert!(got == expected(&m, map, 4), "{map:?} into Rgba8Unorm");
    }
    // One channel into R8Unorm, where the device has that storage format.
    let gray = all.iter().find(|map| map.count == 1).unwrap();
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let r8 = texture(device, wgpu::TextureFormat::R8Unorm, usage);
    if pollster::block_on(scope.pop()).is_some() {
        eprintln!("R8Unorm storage textures not tested: the device refuses them");
    } else {
        let mut encoder = device.create_command_encoder(&Default::default());
        let at = TextureTarget { texture: &r8, mip_level: 0, origin: ORIGIN };
        ctx.record_map_to_texture(device, &mut encoder, &gm, 1, RECT, gray, at).unwrap();
        let got = read_texture(device, queue, encoder, &r8, 1);
        assert!(got == expected(&m, gray, 1), "{gray:?} into R8Unorm");
    }
}

/// A JPEG material's maps decode into textures too (the region through the JPEG kernel).
#[test]
fn jpeg_maps_decode_into_storage_textures_like_the_cpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let path = nmat_tests::fixtures_dir().join("jpeg/pattern_420_37x21.nmat");
    let bytes = std::fs::read(path).unwrap();
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let usage = wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_SRC;
    let rect = (2, 1, 30, 17);
    for map in maps(&m) {
        let target = texture(&device, wgpu::TextureFormat::Rgba8Unorm, usage);
        let mut encoder = device.create_command_encoder(&Default::default());
        let at = TextureTarget { texture: &target, mip_level: 0, origin: ORIGIN };
        ctx.record_map_to_texture(&device, &mut encoder, &gm, 0, rect, &map, at).unwrap();
        let got = read_texture(&device, &queue, encoder, &target, 4);
        assert!(got == expected_at(&m, &map, 4, 0, rect), "{map:?}");
    }
}

/// Frames that write a map into the same texture level (mip 0 and mip 1 of the material in
/// turn) make their bind groups in the first frame only where the device has immediates; every
/// frame's texels are the CPU's.
#[test]
fn repeated_calls_into_the_same_target_make_no_bind_group() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = pbr10();
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let usage = wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_SRC;
    let target = texture(&device, wgpu::TextureFormat::Rgba8Unorm, usage);
    let map = maps(&m)[0];
    let mut made = 0;
    for frame in 0..4 {
        let mip = frame % 2;
        let mut encoder = device.create_command_encoder(&Default::default());
        let at = TextureTarget { texture: &target, mip_level: 0, origin: ORIGIN };
        ctx.record_map_to_texture(&device, &mut encoder, &gm, mip, RECT, &map, at).unwrap();
        let got = read_texture(&device, &queue, encoder, &target, 4);
        assert!(got == expected_at(&m, &map, 4, mip, RECT), "frame {frame}");
        if frame == 0 {
            made = ctx.bind_groups_made_for_testing();
        }
    }
    if ctx.uses_immediates() {
        assert_eq!(ctx.bind_groups_made_for_testing(), made);
    } else {
        eprintln!("this device has no immediates: the bind groups are made per call");
    }
}

#[test]
fn bad_targets_are_refused_before_anything_is_recorded() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = pbr10();
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let rgb = *maps(&m).iter().find(|map| map.count == 3).unwrap();
    let storage =
        texture(&device, wgpu::TextureFormat::Rgba8Unorm, wgpu::TextureUsages::STORAGE_BINDING);
    let sampled =
        texture(&device, wgpu::TextureFormat::Rgba8Unorm, wgpu::TextureUsages::TEXTURE_BINDING);
    let mut encoder = device.create_command_encoder(&Default::default());
    let mut record = |target: TextureTarget<'_>, rect, map: &MapChannels| {
        ctx.record_map_to_texture(&device, &mut encoder, &gm, 1, rect, map, target)
    };
    let at = |texture, mip_level, origin| TextureTarget { texture, mip_level, origin };
    let texture_error = |r: Result<(), GpuError>| matches!(r, Err(GpuError::Texture { .. }));
    assert!(texture_error(record(at(&sampled, 0, ORIGIN), RECT, &rgb)), "no storage usage");
    assert!(texture_error(record(at(&storage, 2, (0, 0)), RECT, &rgb)), "mip level 2 of 2");
    assert!(texture_error(record(at(&storage, 40, (0, 0)), RECT, &rgb)), "mip level 40 of 2");
    assert!(texture_error(record(at(&storage, 1, (0, 0)), RECT, &rgb)), "21 × 9 into 20 × 12");
    assert!(texture_error(record(at(&storage, 0, (20, 0)), RECT, &rgb)), "past the right edge");
    // A map past the material's channels; a region outside the mip.
    let outside = MapChannels { first: 9, count: 3, ..rgb };
    assert!(matches!(
        record(at(&storage, 0, ORIGIN), RECT, &outside),
        Err(GpuError::Channels { .. })
    ));
    let too_far = (30, 0, 21, 9);
    assert!(matches!(record(at(&storage, 0, ORIGIN), too_far, &rgb), Err(GpuError::Region { .. })));
    // Nothing invalid reached the encoder: it still finishes cleanly.
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    drop(encoder.finish());
    assert!(pollster::block_on(scope.pop()).is_none());
}

//! How dispatches get their parameters: as immediates, with the bind groups of recent buffer
//! sets kept, where the device has them (a frame loop recording on the same buffers allocates
//! nothing); from a uniform buffer per call where it has not. Both decode as the CPU does.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{ChannelMask, Container, Material, TileKey};
use nmat_tests::fixtures_dir;
use nmat_wgpu::{CacheLookup, Context, GpuMaterial, Kernel, TexelRequest};
use wgpu::BufferUsages as U;

mod common;
use common::{
    buffer, cpu_codes, device, device_without_immediates, random_requests, submit_and_read,
};

fn fixtures() -> Vec<Vec<u8>> {
    ["ntc_pbr10_96x80_clamp.nmat", "jpeg/pattern_420_37x21.nmat"]
        .iter()
        .map(|name| std::fs::read(fixtures_dir().join(name)).unwrap())
        .collect()
}

fn rect(mip: u32, (x0, y0, w, h): (u32, u32, u32, u32)) -> Vec<TexelRequest> {
    (y0..y0 + h)
        .flat_map(|y| (x0..x0 + w).map(move |x| TexelRequest { x: x as i32, y: y as i32, mip }))
        .collect()
}

/// The bytes of `requests` as a storage buffer reads them (x, y, mip; little-endian).
fn request_bytes(requests: &[TexelRequest]) -> Vec<u8> {
    requests.iter().flat_map(|r| [r.x, r.y, r.mip as i32]).flat_map(i32::to_le_bytes).collect()
}

/// One "frame" of an engine: three regions (other mips, rectangles, channels and offsets each
/// frame) and a batch of requests from the caller's buffer, recorded into one encoder and one
/// output buffer; every code compared with the CPU's.
fn frame(
    (device, queue): (&wgpu::Device, &wgpu::Queue),
    ctx: &Context,
    (m, gm): (&Material<'_>, &GpuMaterial),
    (requests, out): (&wgpu::Buffer, &wgpu::Buffer),
    (f, reqs): (u32, &[TexelRequest]),
) {
    let (w, h) = m.mip_size(0);
    let second = 1.min(m.mip_count() - 1);
    let (w1, h1) = m.mip_size(second);
    let regions = [
        (0, (f, 2 * f, w / 2, h / 3), ChannelMask::ALL),
        (second, (f % 3, 0, w1 / 4, h1 / 4), ChannelMask(0b101)),
        (f % m.mip_count(), (0, 0, 1, 1), ChannelMask(1 << (f as usize % m.channel_count()))),
    ];
    let mut encoder = device.create_command_encoder(&Default::default());
    let mut at = 4 * u64::from(f);
    let mut want = Vec::new();
    for (mip, r, mask) in regions {
        let n = ctx.record_region(device, &mut encoder, gm, mip, r, mask, (out, at)).unwrap();
        want.push((at, cpu_codes(m, &rect(mip, r), mask)));
        at = (at + n).next_multiple_of(4);
    }
    let count = reqs.len() as u32;
    let mask = ChannelMask::ALL;
    ctx.record_requests(device, &mut encoder, gm, (requests, 0, count), mask, (out, at)).unwrap();
    want.push((at, cpu_codes(m, reqs, mask)));
    let got = submit_and_read(device, queue, encoder, out);
    for (at, codes) in want {
        let at = at as usize;
        assert_eq!(&got[at..at + codes.len()], &codes[..], "frame {f}, codes at byte {at}");
    }
}

/// Where the device has immediates (lavapipe has), four frames recorded on the same buffers,
/// with other rectangles, mips, channels and offsets each frame, make their bind groups in the
/// first frame only, for a neural and a JPEG material; the codes are the CPU's every frame.
/// Releasing the kept bind groups makes the next frame make them again.
#[test]
fn a_frame_loop_on_the_same_buffers_makes_no_bind_group_after_its_first_frame() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    if !ctx.uses_immediates() {
        eprintln!("this device has no immediates: not tested here");
        return;
    }
    for bytes in fixtures() {
        let m = Container::parse(&bytes).unwrap();
        let gm = ctx.upload(&device, &queue, &m).unwrap();
        let reqs = random_requests(9, 300, 300, m.mip_count() + 1);
        let requests = buffer(&device, 12 * 300, U::STORAGE | U::COPY_DST, None);
        queue.write_buffer(&requests, 0, &request_bytes(&reqs));
        let out = buffer(&device, 1 << 16, U::STORAGE | U::COPY_SRC, None);
        let both = (&device, &queue);
        frame(both, &ctx, (&m, &gm), (&requests, &out), (0, &reqs));
        let made = ctx.bind_groups_made_for_testing();
        for f in 1..4 {
            frame(both, &ctx, (&m, &gm), (&requests, &out), (f, &reqs));
        }
        assert_eq!(ctx.bind_groups_made_for_testing(), made, "{:?}", m.codec());
        ctx.release_kept_bind_groups();
        frame(both, &ctx, (&m, &gm), (&requests, &out), (4, &reqs));
        assert!(ctx.bind_groups_made_for_testing() > made, "{:?}", m.codec());
    }
}

/// The CPU's codes of tile `key` of `m`: every channel, 0 past the mip's edge.
fn cpu_tile(m: &Material<'_>, key: TileKey) -> Vec<u8> {
    let (x0, y0) = (u32::from(key.x) * 16, u32::from(key.y) * 16);
    let (w, h) = m.mip_size(u32::from(key.mip));
    let n = m.channel_count();
    let mut out = vec![0u8; 256 * n];
    for t in 0..256u32 {
        let (x, y) = (x0 + t % 16, y0 + t / 16);
        if x < w && y < h {
            let r = TexelRequest { x: x as i32, y: y as i32, mip: u32::from(key.mip) };
            let at = t as usize * n;
            out[at..at + n].copy_from_slice(&cpu_codes(m, &[r], ChannelMask::ALL));
        }
    }
    out
}

/// On a device without immediates every dispatch reads its parameters from a uniform buffer:
/// regions and requests through every kernel the device runs, a JPEG material's, and a tile
/// cache's new tiles all decode as the CPU does.
#[test]
fn without_immediates_every_path_decodes_as_the_cpu() {
    let (device, queue) = device_without_immediates();
    let ctx = Context::new(&device);
    assert!(!ctx.uses_immediates());
    let bytes = fixtures();
    let materials: Vec<Material<'_>> = bytes.iter().map(|b| Container::parse(b).unwrap()).collect();
    let reqs = random_requests(3, 200, 300, 8);
    let requests = buffer(&device, 12 * 200, U::STORAGE | U::COPY_DST, None);
    queue.write_buffer(&requests, 0, &request_bytes(&reqs));
    let out = buffer(&device, 1 << 16, U::STORAGE | U::COPY_SRC, None);
    let mut uploaded = Vec::new();
    for m in &materials {
        let kernels: &[Kernel] = match m.codec() {
            nmat_core::Codec::Neural => &[
                Kernel::Reference,
                Kernel::Int32,
                Kernel::UnrolledInt32,
                Kernel::UnrolledDot4,
                Kernel::Dot4,
            ],
            nmat_core::Codec::Jpeg => &[Kernel::Reference],
        };
        for &kernel in kernels {
            let Ok(gm) = ctx.upload_with(&device, &queue, m, Some(kernel)) else {
                eprintln!("{} kernel not tested here", kernel.name());
                continue;
            };
            frame((&device, &queue), &ctx, (m, &gm), (&requests, &out), (1, &reqs));
            uploaded.push(gm);
        }
    }
    assert!(uploaded.len() >= 3, "the reference and a tiled kernel, and JPEG");
    // A cache over the last neural upload (a tiled kernel's tile entry) and the JPEG material.
    let (neural, jpeg) = (&uploaded[uploaded.len() - 2], &uploaded[uploaded.len() - 1]);
    assert_eq!(neural.tile_kernel(), neural.kernel());
    let cache = ctx.create_tile_cache(&device, &[neural, jpeg], 64).unwrap();
    let lookups: Vec<CacheLookup> = (0..64)
        .map(|i| {
            let (u, v) = ((i % 8) as f32 / 8.0, (i / 8) as f32 / 8.0);
            let req = nmat_core::SampleRequest {
                u,
                v,
                lod: (i % 3) as f32,
                filter: nmat_core::Filter::Bilinear,
                precision: nmat_core::Precision::Integer,
                random: [0.0; 3],
                channels: ChannelMask::ALL,
            };
            CacheLookup::new(i % 2, &req)
        })
        .collect();
    let input = buffer(&device, 64 * CacheLookup::BYTES, U::STORAGE | U::COPY_DST, None);
    queue.write_buffer(&input, 0, &CacheLookup::bytes(&lookups));
    let mut encoder = device.create_command_encoder(&Default::default());
    cache.record_begin_frame(&mut encoder);
    cache.record_mark(&device, &mut encoder, (&input, 0, 64)).unwrap();
    cache.record_decode_missing(&mut encoder);
    cache.record_end_frame(&mut encoder);
    queue.submit([encoder.finish()]);
    let tiles = cache.resident_tiles(&device, &queue).unwrap();
    assert!(
        tiles.iter().any(|(k, _)| k.material == 0) && tiles.iter().any(|(k, _)| k.material == 1)
    );
    for (key, codes) in tiles {
        let m = &materials[usize::from(key.material)];
        assert!(codes == cpu_tile(m, key), "tile {key:?}");
    }
}

//! Indexed-JPEG materials (docs/FORMAT.md §11) on the GPU: every code equal to `nmat_core`'s
//! decoder — whole chains, odd rectangles, channel subsets, scattered requests (wrapping, clamped
//! mips), materials at the codec's edges (tiny mips, extreme contents and qualities), and
//! streams whose entropy-coded bits were damaged (the decode is total on both sides).
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

mod common;

use nmat_core::{ChannelMask, Codec, Container, Material, ParseOptions};
use nmat_wgpu::{Context, GpuError, TexelRequest};

/// The CPU's codes of `rect` of `mip`, row-major, channels of `mask`.
fn cpu_region(
    m: &Material<'_>,
    mip: u32,
    (x0, y0, w, h): (u32, u32, u32, u32),
    mask: ChannelMask,
) -> Vec<u8> {
    let mut out = Vec::new();
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            let mut t = [0u8; 16];
            let n = m.decode_texel_u8(i64::from(x), i64::from(y), mip, mask, &mut t).unwrap();
            out.extend_from_slice(&t[..n]);
        }
    }
    out
}

/// A JPEG material of the brick maps (colour 4:2:0, normal 4:4:4, two gray maps; 7 mips).
fn bricks_jpeg(subsampling: nmat_encode::jpeg::Subsampling) -> Vec<u8> {
    let set = nmat_encode::demo::bricks(64);
    let options = nmat_encode::jpeg::JpegOptions { quality: 70, subsampling, ..Default::default() };
    nmat_encode::jpeg::encode_jpeg(&set, &options).unwrap().bytes
}

fn fixture() -> Vec<u8> {
    let path =
        concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/fixtures/jpeg/pattern_420_37x21.nmat");
    std::fs::read(path).unwrap()
}

fn check_material(
    context: &Context,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    m: &Material<'_>,
    name: &str,
) {
    let gm = context.upload(device, queue, m).unwrap();
    assert_eq!(gm.codec(), Codec::Jpeg);
    let all = ChannelMask::ALL;
    // Every mip whole, all channels.
    let chain = context.decode_chain(device, queue, &gm, all).unwrap();
    let mut expected = Vec::new();
    for mip in 0..m.mip_count() {
        let (w, h) = m.mip_size(mip);
        expected.extend(cpu_region(m, mip, (0, 0, w, h), all));
    }
    assert!(chain == expected, "{name}: the GPU chain differs from the CPU's");
    // Odd rectangles and channel subsets (one channel of a colour map, channels of two maps).
    let (w, h) = m.mip_size(0);
    let masks = [
        all,
        ChannelMask(0b10),
        ChannelMask(0b1000_0101 & ((1 << m.channel_count()) - 1) as u16 | 1),
    ];
    for (rect, mask) in [
        ((w / 3, h / 4, w / 2, h / 2 + 1), masks[1]),
        ((1, 2, w.saturating_sub(1), h.saturating_sub(2)), masks[2]),
        ((w - 1, h - 1, 1, 1), masks[0]),
    ] {
        if rect.2 == 0 || rect.3 == 0 {
            continue; // a mip too small for this rectangle
        }
        let gpu =
            context.submit_region(device, queue, &gm, 0, rect, mask).unwrap().wait(device).unwrap();
        assert!(gpu == cpu_region(m, 0, rect, mask), "{name}: region {rect:?} mask {mask:?}");
    }
    // Scattered requests: negative and large coordinates wrap (or clamp), a mip past the chain
    // is the last one.
    let requests: Vec<TexelRequest> = (0..200i32)
        .map(|i| TexelRequest { x: i * 37 - 900, y: i * 11 - 50, mip: (i % 9) as u32 })
        .collect();
    let gpu = context.decode_requests(device, queue, &gm, &requests, all).unwrap();
    assert!(gpu == cpu_requests(m, &requests, all), "{name}: requests differ");
}

#[test]
fn jpeg_materials_decode_on_the_gpu_exactly_as_on_the_cpu() {
    let (device, queue) = common::device();
    let context = Context::new(&device);
    let materials = [
        ("fixture 37×21 4:2:0 with restarts", fixture()),
        ("bricks 4:2:0", bricks_jpeg(nmat_encode::jpeg::Subsampling::S420)),
        ("bricks 4:2:2", bricks_jpeg(nmat_encode::jpeg::Subsampling::S422)),
        // Four maps (4:2:0, gray, luma 1 × 2 — which the encoder never writes —, gray), 4 mips,
        // exactly two Huffman tables; its CPU codes are checked against FORMAT.md §11 in
        // tests/tests/golden.rs.
        (
            "DC-only, four maps, luma 1 × 2",
            nmat_tests::generate_jpeg::DcJpegMaterial::new(7).spec.to_bytes().unwrap(),
        ),
    ];
    for (name, bytes) in &materials {
        let m = Container::parse(bytes).unwrap();
        check_material(&context, &device, &queue, &m, name);
        check_transcode(&context, (&device, &queue), &m, name, false);
    }
}

/// JPEG materials at the codec's edges: mips of 1 × 1, 1 × 19, 23 × 2 and 17 × 9 texels (MCUs
/// mostly padding, edge replication), a one-texel checkerboard of 0 and 255 (the largest AC
/// coefficients, whose IDCT overshoots the range and clamps) and uniform noise (the longest
/// Huffman codes), at quality 100 (every quantization step 1) in 4:2:0 and quality 1 (steps of
/// 255) in 4:4:4; and maps all 0 and all 255. Every code of every mip, odd regions and scattered
/// requests equal the CPU's (`check_material`), and so do their BC blocks in the default layout
/// (`check_transcode`: blocks padded past tiny mips, flat and two-colour blocks).
#[test]
fn jpeg_materials_at_the_codecs_edges_decode_as_on_the_cpu() {
    use nmat_encode::jpeg::{JpegOptions, Subsampling, encode_jpeg};
    let (device, queue) = common::device();
    let context = Context::new(&device);
    // The bricks' eight channels (an sRGB colour map, a normal map, two gray maps) over other
    // texels.
    let material = |(w, h): (u32, u32), value: &dyn Fn(u32, u32, usize) -> f32, options| {
        let layout = nmat_encode::demo::bricks(8);
        let texels: Vec<(u32, u32)> = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).collect();
        let planes: Vec<Vec<f32>> = (0..layout.channel_count())
            .map(|k| texels.iter().map(|&(x, y)| value(x, y, k)).collect())
            .collect();
        let mips = nmat_encode::texset::build_mips(w, h, planes);
        let set = nmat_encode::texset::TextureSet { width: w, height: h, mips, ..layout };
        encode_jpeg(&set, &options).unwrap().bytes
    };
    let checker = |x: u32, y: u32, k: usize| ((x + y + k as u32) % 2) as f32;
    let noise = |x: u32, y: u32, k: usize| {
        let h = (x.wrapping_mul(73_856_093) ^ y.wrapping_mul(19_349_663) ^ (k as u32) << 20)
            .wrapping_mul(2_654_435_761);
        (h >> 24) as f32 / 255.0
    };
    let fine = JpegOptions { quality: 100, subsampling: Subsampling::S420, ..Default::default() };
    let coarse = JpegOptions { quality: 1, subsampling: Subsampling::S444, ..Default::default() };
    let mut materials = Vec::new();
    for size in [(1, 1), (1, 19), (23, 2), (17, 9)] {
        for (pattern, value) in
            [("checkerboard", &checker as &dyn Fn(_, _, _) -> _), ("noise", &noise)]
        {
            for (quality, options) in [("q100 4:2:0", &fine), ("q1 4:4:4", &coarse)] {
                let name = format!("{size:?} {pattern} {quality}");
                materials.push((name, material(size, value, options.clone())));
            }
        }
    }
    for (level, value) in [("all 0", 0.0), ("all 255", 1.0)] {
        materials.push((level.to_string(), material((21, 13), &|_, _, _| value, fine.clone())));
    }
    for (name, bytes) in &materials {
        let m = Container::parse(bytes).unwrap();
        check_material(&context, &device, &queue, &m, name);
    }
}

/// Damaged entropy-coded bits (the checksum skipped): the CPU decodes something for every
/// texel, and the GPU the same something.
#[test]
fn damaged_jpeg_streams_decode_alike_on_the_gpu() {
    let (device, queue) = common::device();
    let context = Context::new(&device);
    let good = bricks_jpeg(nmat_encode::jpeg::Subsampling::S420);
    let parts = {
        let m = Container::parse(&good).unwrap();
        let j = m.jpeg().unwrap();
        let section_at = good.windows(j.section().len()).position(|w| w == j.section()).unwrap();
        let p = j.stream_parts(0, 0).unwrap();
        (section_at + p.data_at, p.data_len)
    };
    let mut tried = 0;
    for k in 0..14 {
        let mut bytes = good.clone();
        let at = parts.0 + (k * 7919) % parts.1;
        if k < 12 {
            bytes[at] ^= 1 << (k % 8);
        } else {
            // Sixteen 1-bits: a code no table has (the decoder's total fallback).
            bytes[at..at + 4].fill(0xFF);
        }
        let Ok(m) = Container::parse_with(&bytes, ParseOptions { verify_checksum: false }) else {
            continue;
        };
        tried += 1;
        check_material(&context, &device, &queue, &m, &format!("damage at byte {at}"));
    }
    assert!(tried >= 12, "only {tried} damaged files parsed");
}

/// Recorded into the caller's buffer (at an offset, over stale bytes): the same codes as the
/// submitted decode, the last word's spare bytes zero; requests read from the caller's buffer.
#[test]
fn recorded_jpeg_decodes_equal_submitted_ones() {
    let (device, queue) = common::device();
    let context = Context::new(&device);
    let bytes = bricks_jpeg(nmat_encode::jpeg::Subsampling::S420);
    let m = Container::parse(&bytes).unwrap();
    let gm = context.upload(&device, &queue, &m).unwrap();
    let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
    let out = common::buffer(&device, 1 << 16, usage, Some(0xAB));
    let (rect, mask) = ((5, 3, 23, 17), ChannelMask(0b1100_0101));
    let mut encoder = device.create_command_encoder(&Default::default());
    let n = context.record_region(&device, &mut encoder, &gm, 1, rect, mask, (&out, 256)).unwrap();
    let back = common::submit_and_read(&device, &queue, encoder, &out);
    let expected = cpu_region(&m, 1, rect, mask);
    assert_eq!(n as usize, expected.len());
    assert!(back[256..256 + expected.len()] == expected[..]);
    let end = 256 + expected.len();
    assert!(back[end..end.next_multiple_of(4)].iter().all(|&b| b == 0));
    assert!(back[..256].iter().chain(&back[end.next_multiple_of(4)..]).all(|&b| b == 0xAB));

    let requests: Vec<TexelRequest> =
        (0..50).map(|i| TexelRequest { x: 3 * i - 20, y: 7 * i, mip: (i % 4) as u32 }).collect();
    let words: Vec<u8> = requests
        .iter()
        .flat_map(|r| [r.x.to_le_bytes(), r.y.to_le_bytes(), r.mip.to_le_bytes()])
        .flatten()
        .collect();
    let request_buffer = common::buffer(
        &device,
        12 + words.len() as u64,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        Some(0),
    );
    queue.write_buffer(&request_buffer, 12, &words);
    let out = common::buffer(&device, 4096, usage, Some(0xCD));
    let mut encoder = device.create_command_encoder(&Default::default());
    let count = requests.len() as u32;
    context
        .record_requests(
            &device,
            &mut encoder,
            &gm,
            (&request_buffer, 12, count),
            ChannelMask::ALL,
            (&out, 0),
        )
        .unwrap();
    let back = common::submit_and_read(&device, &queue, encoder, &out);
    let submitted =
        context.decode_requests(&device, &queue, &gm, &requests, ChannelMask::ALL).unwrap();
    assert!(back[..submitted.len()] == submitted[..]);
}

/// The CPU's codes of `requests` (a mip past the chain is the last one), channels of `mask`.
fn cpu_requests(m: &Material<'_>, requests: &[TexelRequest], mask: ChannelMask) -> Vec<u8> {
    let mut out = Vec::new();
    for r in requests {
        let mip = r.mip.min(m.mip_count() - 1);
        let mut t = [0u8; 16];
        let n = m.decode_texel_u8(i64::from(r.x), i64::from(r.y), mip, mask, &mut t).unwrap();
        out.extend_from_slice(&t[..n]);
    }
    out
}

/// Requests decode each MCU they read once, through a table the passes clear again: many
/// requests on few MCUs (repeats within and across calls), in one round and — with scratch room
/// for one colour MCU, or a few — in many rounds, equal to the CPU's codes; a call after them,
/// or on another material sharing the context's work buffer, reads no stale slot.
#[test]
fn requests_sharing_mcus_decode_alike_in_one_round_or_many() {
    let (device, queue) = common::device();
    let bytes = bricks_jpeg(nmat_encode::jpeg::Subsampling::S420);
    let m = Container::parse(&bytes).unwrap();
    let small_bytes = fixture();
    let small = Container::parse(&small_bytes).unwrap();
    // A small LCG: 1 500 requests clustered on a few MCUs of mips 0–2, then spread ones.
    let mut seed = 7u32;
    let mut next = |n: u32| {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (seed >> 8) % n
    };
    let clustered: Vec<TexelRequest> = (0..1500)
        .map(|_| TexelRequest { x: next(24) as i32 - 4, y: next(40) as i32, mip: next(3) })
        .collect();
    let spread: Vec<TexelRequest> = (0..300)
        .map(|_| TexelRequest {
            x: next(300) as i32 - 100,
            y: next(300) as i32 - 100,
            mip: next(9),
        })
        .collect();
    // 192 words: one 16 × 16 colour MCU (and 12 gray ones); 1 000: five colour MCUs.
    for scratch in [None, Some(192), Some(1000)] {
        let context = Context::new(&device);
        if let Some(words) = scratch {
            context.limit_jpeg_scratch_for_testing(words);
        }
        // The small material first: the larger one's calls grow the shared work buffer.
        let gm_small = context.upload(&device, &queue, &small).unwrap();
        let gm = context.upload(&device, &queue, &m).unwrap();
        for (requests, mask) in [
            (&clustered, ChannelMask::ALL),
            (&spread, ChannelMask(0b1010_0110)),
            (&clustered, ChannelMask(0b1)),
        ] {
            let gpu = context.decode_requests(&device, &queue, &gm, requests, mask).unwrap();
            let cpu = cpu_requests(&m, requests, mask);
            assert!(gpu == cpu, "scratch {scratch:?}, mask {mask:?}: requests differ");
            // The fixture's 3 channels of the mask.
            let mask = ChannelMask(mask.0 & 0b111);
            let gpu = context.decode_requests(&device, &queue, &gm_small, requests, mask).unwrap();
            let cpu = cpu_requests(&small, requests, mask);
            assert!(
                gpu == cpu,
                "scratch {scratch:?}, mask {mask:?}: the fixture's requests differ"
            );
        }
    }
}

/// Every mip of `m` transcoded on the GPU in the default layout, all textures of a mip in one
/// call, equals the CPU's blocks; with `into_textures` (where the device has BC textures) the
/// levels of whole BC textures made by `create_bc_textures` too (on wgpu's GL backend, which
/// reads no compressed texture back, as the texture unit reads them: within 2 steps of the
/// core's block decoder).
fn check_transcode(
    context: &Context,
    (device, queue): (&wgpu::Device, &wgpu::Queue),
    m: &Material<'_>,
    name: &str,
    into_textures: bool,
) {
    let gm = context.upload(device, queue, m).unwrap();
    let cpu = nmat_core::Decoder::new(m);
    let textures = nmat_core::bc::default_layout(m);
    assert!(!textures.is_empty());
    let has_bc = device.features().contains(wgpu::Features::TEXTURE_COMPRESSION_BC);
    let made = if into_textures && has_bc {
        context.create_bc_textures(device, queue, &gm, &textures).unwrap()
    } else {
        Vec::new()
    };
    for mip in 0..m.mip_count() {
        let gpu = context.transcode_textures_mip(device, queue, &gm, &textures, mip).unwrap();
        for (t, (texture, gpu)) in textures.iter().zip(gpu).enumerate() {
            let want = common::cpu_blocks(&cpu, m, texture, mip);
            common::assert_same_bytes(&gpu, &want, format!("{name}: {texture:?} mip {mip}"));
            if let Some(made) = made.get(t) {
                let what = format!("{name}: {texture:?} mip {mip} in a BC texture");
                common::assert_bc_level((device, queue), made, mip, texture.format, &want, &what);
            }
        }
    }
}

/// BC transcoding decodes a region first (the JPEG kernel here), so a JPEG material's textures
/// transcode on the GPU as on the CPU, every mip, all textures of a mip in one call.
#[test]
fn jpeg_materials_transcode_as_on_the_cpu() {
    let (device, queue) = common::device();
    let context = Context::new(&device);
    let bytes = fixture();
    let m = Container::parse(&bytes).unwrap();
    check_transcode(&context, (&device, &queue), &m, "the fixture", false);
    // The bricks (64², 4:2:0: MCUs of 16 rows) one block row a pass, so that each pass decodes
    // a quarter of a row of MCUs; and straight into BC textures.
    context.limit_pass_bytes_for_testing(1);
    let bytes = bricks_jpeg(nmat_encode::jpeg::Subsampling::S420);
    let m = Container::parse(&bytes).unwrap();
    check_transcode(&context, (&device, &queue), &m, "bricks", true);
}

#[test]
fn paths_for_neural_materials_refuse_a_jpeg_one() {
    let (device, queue) = common::device();
    let context = Context::new(&device);
    let bytes = fixture();
    let m = Container::parse(&bytes).unwrap();
    let gm = context.upload(&device, &queue, &m).unwrap();
    let bindings = nmat_wgpu::SampleBindings { group: 0, first_binding: 0 };
    assert!(matches!(gm.sample_entries(bindings), Err(GpuError::Codec)));
    let r = context.upload_with(&device, &queue, &m, Some(nmat_wgpu::Kernel::Dot4));
    assert!(matches!(r, Err(GpuError::Kernel { .. })));
}

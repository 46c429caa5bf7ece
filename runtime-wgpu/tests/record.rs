//! Decodes recorded into the caller's command encoder and buffers, the packed output, and the
//! reuse of buffers between submit-and-wait calls: every code against the CPU integer decoder.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::bc::{BcFormat, BcTexture};
use nmat_core::{ChannelMask, Container};
use nmat_tests::generate::{generate, golden_configs};
use nmat_wgpu::{Context, GpuError, TexelRequest};
use wgpu::BufferUsages as U;

mod common;
use common::{
    assert_same_bytes, buffer, cpu_blocks, cpu_codes, device, random_requests, run_as_a_browser,
    submit_and_read, trained_material,
};

fn rect(mip: u32, (x0, y0, w, h): (u32, u32, u32, u32)) -> Vec<TexelRequest> {
    (y0..y0 + h)
        .flat_map(|y| (x0..x0 + w).map(move |x| TexelRequest { x: x as i32, y: y as i32, mip }))
        .collect()
}

fn golden(name: &str) -> Vec<u8> {
    let cfg = golden_configs().into_iter().find(|c| c.name == name).unwrap();
    generate(&cfg).to_bytes().unwrap()
}

/// Regions with channel counts that do not fill whole words (3 and 1 of 10), over several
/// workgroups, recorded at an offset into a buffer full of 0xEE: the codes land packed from
/// the offset, the last word's spare bytes are zero, and nothing outside is touched.
#[test]
fn recorded_regions_pack_their_codes_at_the_offset() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = golden("ntc_pbr10_96x80_clamp");
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let cases = [
        (0, (5, 7, 31, 13), ChannelMask(0b00_1001_0100)),
        (1, (0, 0, 48, 40), ChannelMask(0b1)),
        (2, (3, 1, 7, 9), ChannelMask::ALL),
        (0, (95, 79, 1, 1), ChannelMask(0b111)),
    ];
    for (mip, r, mask) in cases {
        let want = cpu_codes(&m, &rect(mip, r), mask);
        let offset = 36u64;
        let size = offset + want.len().next_multiple_of(4) as u64 + 32;
        let out = buffer(&device, size, U::STORAGE | U::COPY_SRC, Some(0xEE));
        let mut encoder = device.create_command_encoder(&Default::default());
        let n =
            ctx.record_region(&device, &mut encoder, &gm, mip, r, mask, (&out, offset)).unwrap();
        assert_eq!(n, want.len() as u64);
        let got = submit_and_read(&device, &queue, encoder, &out);
        let (at, end) = (offset as usize, offset as usize + want.len());
        assert!(got[..at].iter().all(|&b| b == 0xEE), "{r:?}: bytes before the offset");
        assert_eq!(&got[at..end], &want[..], "{r:?} of mip {mip}, mask {mask:?}");
        let pad = end.next_multiple_of(4);
        assert!(got[end..pad].iter().all(|&b| b == 0), "{r:?}: the last word's spare bytes");
        assert!(got[pad..].iter().all(|&b| b == 0xEE), "{r:?}: bytes after the last word");
    }
}

/// Requests the caller already has on the GPU, read from an offset, decode as on the CPU.
#[test]
fn recorded_requests_read_from_the_callers_buffer() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = golden("ntc_pbr10_96x80_clamp");
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let mut reqs = random_requests(99, 300, 300, 10);
    reqs.push(TexelRequest { x: i32::MIN, y: i32::MAX, mip: u32::MAX });
    let mask = ChannelMask(0b11_0000_0111);
    let want = cpu_codes(&m, &reqs, mask);
    let request_bytes: Vec<u8> = reqs
        .iter()
        .flat_map(|r| [r.x.to_le_bytes(), r.y.to_le_bytes(), r.mip.to_le_bytes()])
        .flatten()
        .collect();
    let in_offset = 24u64;
    let requests =
        buffer(&device, in_offset + request_bytes.len() as u64, U::STORAGE | U::COPY_DST, None);
    queue.write_buffer(&requests, in_offset, &request_bytes);
    let out =
        buffer(&device, 8 + want.len().next_multiple_of(4) as u64, U::STORAGE | U::COPY_SRC, None);
    let mut encoder = device.create_command_encoder(&Default::default());
    let count = reqs.len() as u32;
    ctx.record_requests(&device, &mut encoder, &gm, (&requests, in_offset, count), mask, (&out, 8))
        .unwrap();
    let got = submit_and_read(&device, &queue, encoder, &out);
    assert_eq!(&got[8..8 + want.len()], &want[..]);

    // Bad buffers and offsets are refused before anything is recorded.
    let mut encoder = device.create_command_encoder(&Default::default());
    let mut record = |reqs: (&wgpu::Buffer, u64, u32), out: (&wgpu::Buffer, u64)| {
        ctx.record_requests(&device, &mut encoder, &gm, reqs, mask, out)
    };
    let bad_request = |e| matches!(e, Err(GpuError::RequestBuffer { .. }));
    assert!(bad_request(record((&requests, in_offset + 4, count), (&out, 8))), "past the end");
    assert!(bad_request(record((&requests, 2, 1), (&out, 8))), "unaligned");
    let mappable = buffer(&device, 64, U::MAP_READ | U::COPY_DST, None);
    assert!(bad_request(record((&mappable, 0, 1), (&out, 8))), "no STORAGE usage");
    let bad_output = |e| matches!(e, Err(GpuError::OutputBuffer { .. }));
    assert!(bad_output(record((&requests, in_offset, count), (&out, 6))), "unaligned output");
    assert!(bad_output(record((&requests, in_offset, count), (&mappable, 0))), "output usage");
    assert!(matches!(
        record((&requests, in_offset, count), (&out, 12)),
        Err(GpuError::Output { .. })
    ));
    assert!(matches!(
        record((&requests, in_offset, count), (&out, 8)).map(|n| n == want.len() as u64),
        Ok(true)
    ));
}

/// Submit-and-wait calls reuse their buffers and bind groups: decodes of two materials of the
/// same shape, alternating, each equal the CPU's (a bind group reused for the wrong material
/// would return the other's codes), and a pending result's GPU buffer holds the same codes as
/// `wait` returns.
#[test]
fn reused_buffers_keep_materials_and_sizes_apart() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let a_bytes = trained_material();
    let b_bytes = golden("ntc_pbr10_96x80_clamp");
    let (a, b) = (Container::parse(&a_bytes).unwrap(), Container::parse(&b_bytes).unwrap());
    let (ga, gb) =
        (ctx.upload(&device, &queue, &a).unwrap(), ctx.upload(&device, &queue, &b).unwrap());
    let mask = ChannelMask(0b111);
    for round in 0..3u32 {
        for (m, gm) in [(&a, &ga), (&b, &gb)] {
            let r = (round, 2 * round, 20 + round, 9);
            let got = ctx.submit_region(&device, &queue, gm, 0, r, mask).unwrap().wait(&device);
            assert_eq!(got.unwrap(), cpu_codes(m, &rect(0, r), mask), "round {round}, {r:?}");
        }
    }
    let r = (4, 4, 17, 5);
    let pending = ctx.submit_region(&device, &queue, &gb, 1, r, ChannelMask::ALL).unwrap();
    let source = pending.gpu_buffer();
    let copy = buffer(&device, source.size(), U::STORAGE | U::COPY_SRC | U::COPY_DST, None);
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(source, 0, &copy, 0, source.size());
    let on_gpu = submit_and_read(&device, &queue, encoder, &copy);
    let len = pending.len();
    let codes = pending.wait(&device).unwrap();
    assert_eq!(codes, cpu_codes(&b, &rect(1, r), ChannelMask::ALL));
    assert_eq!(&on_gpu[..len], &codes[..]);
    // Several decodes in flight, each waited for on its own submission: newest first, one
    // submitted between two waits, one dropped unwaited (its buffers go back to the pool).
    let rects = [(0, 0, 31, 7), (3, 9, 12, 12), (40, 1, 5, 30), (7, 7, 1, 1)];
    let submit = |k: usize| {
        let (m, gm) = if k.is_multiple_of(2) { (&a, &ga) } else { (&b, &gb) };
        let pending = ctx.submit_region(&device, &queue, gm, 0, rects[k], mask).unwrap();
        (pending, cpu_codes(m, &rect(0, rects[k]), mask))
    };
    let mut in_flight: Vec<_> = (0..3).map(submit).collect();
    drop(ctx.submit_region(&device, &queue, &ga, 1, (0, 0, 9, 9), mask).unwrap());
    let (newest, want) = in_flight.pop().unwrap();
    assert_eq!(newest.wait(&device).unwrap(), want, "the newest of three");
    in_flight.push(submit(3));
    for (k, (pending, want)) in in_flight.into_iter().enumerate().rev() {
        assert_eq!(pending.wait(&device).unwrap(), want, "in flight, {k}");
    }
}

/// Decodes kept in flight are asked about without blocking: right after their submission the
/// last of three whole mip-0 decodes (96 × 80 texels each, a fraction of a second on lavapipe)
/// is not finished (`is_finished` with no wait; a race the device could win is retried), is
/// said to be finished within a bounded wait, stays finished — as do the two before it — and
/// each maps the CPU's codes; a submitted transcoding (BC1 and BC4 of one mip) likewise, with
/// the CPU's blocks. A decode asked about and then dropped unwaited gives its buffers back, and
/// the next decode is exact.
#[test]
fn pending_work_says_whether_it_has_finished_without_blocking() {
    use std::time::{Duration, Instant};
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let bytes = golden("ntc_pbr10_96x80_clamp");
    let m = Container::parse(&bytes).unwrap();
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let (r, mask) = ((0, 0, 96, 80), ChannelMask::ALL);
    let want = cpu_codes(&m, &rect(0, r), mask);
    // Asks until it says finished, each ask waiting at most 10 ms, for at most 60 s.
    let finishes = |is_finished: &dyn Fn(Duration) -> bool| {
        let start = Instant::now();
        while !is_finished(Duration::from_millis(10)) {
            assert!(start.elapsed() < Duration::from_secs(60), "not finished in 60 s");
        }
        assert!(is_finished(Duration::ZERO), "finished, then not");
    };
    let mut unfinished_seen = 0;
    for _attempt in 0..5 {
        // Three in a row, the last asked about (queued behind two, it is unfinished on a fast
        // GPU too); once it has finished, the queue has run the two before it.
        let pending: Vec<_> =
            (0..3).map(|_| ctx.submit_region(&device, &queue, &gm, 0, r, mask).unwrap()).collect();
        if !pending[2].is_finished(&device, Duration::ZERO).unwrap() {
            unfinished_seen += 1;
        }
        finishes(&|wait| pending[2].is_finished(&device, wait).unwrap());
        for (k, pending) in pending.into_iter().enumerate() {
            assert!(pending.is_finished(&device, Duration::ZERO).unwrap(), "decode {k}");
            assert_eq!(pending.wait(&device).unwrap(), want, "decode {k}");
        }
        if unfinished_seen > 0 {
            break;
        }
        eprintln!("the device finished the decodes before they were asked about; again");
    }
    // (wgpu's GL backend over Mesa's llvmpipe runs the work as it is submitted: there every
    // decode had finished when first asked, as for the upload's probe in bitexact.rs.)
    if device.adapter_info().backend != wgpu::Backend::Gl {
        assert_eq!(unfinished_seen, 1, "no decode was seen unfinished in 5 attempts");
    }
    // Asked, then dropped unwaited: its buffers go back to the pool and serve the next decode.
    let pending = ctx.submit_region(&device, &queue, &gm, 0, r, mask).unwrap();
    let _ = pending.is_finished(&device, Duration::ZERO).unwrap();
    drop(pending);
    let again = ctx.submit_region(&device, &queue, &gm, 0, r, mask).unwrap();
    assert_eq!(again.wait(&device).unwrap(), want, "after a dropped decode");
    // Transcoding: one mip into two textures, asked about, then mapped.
    let textures = [
        BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2, 0], srgb: false },
        BcTexture { format: BcFormat::Bc4, channels: [3, 0, 0, 0], srgb: false },
    ];
    let pending = ctx.submit_transcode_textures(&device, &queue, &gm, &textures, 1).unwrap();
    finishes(&|wait| pending.is_finished(&device, wait).unwrap());
    let got = pending.wait(&device).unwrap();
    let cpu = nmat_core::Decoder::new(&m);
    for (texture, blocks) in textures.iter().zip(&got) {
        assert_same_bytes(blocks, &cpu_blocks(&cpu, &m, texture, 1), texture.format.name());
    }
}

/// A material whose latents, descriptors or JPEG section exceed one storage binding of the device
/// is refused at upload with a typed error naming them and the limit (without the check, every
/// kernel's probe failed and `upload` said that no kernel's codes equalled the CPU's).
#[test]
fn materials_larger_than_the_devices_bindings_are_refused() {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default())).unwrap();
    let limits = wgpu::Limits {
        max_storage_buffer_binding_size: 256,
        ..wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits())
    };
    let descriptor = wgpu::DeviceDescriptor { required_limits: limits, ..Default::default() };
    let (device, queue) = pollster::block_on(adapter.request_device(&descriptor)).unwrap();
    let ctx = Context::new(&device);
    let neural = generate(&golden_configs()[1]).to_bytes().unwrap();
    let jpeg =
        std::fs::read(nmat_tests::fixtures_dir().join("jpeg/pattern_420_37x21.nmat")).unwrap();
    for bytes in [neural, jpeg] {
        let m = Container::parse(&bytes).unwrap();
        let refused = ctx.upload(&device, &queue, &m).err().unwrap();
        let message = refused.to_string();
        assert!(
            matches!(
                refused,
                GpuError::DataTooLarge { limit: 256, .. }
                    | GpuError::SectionTooLarge { limit: 256, .. }
            ),
            "{message}"
        );
        assert!(message.contains("at most 256"), "{message}");
        eprintln!("{message}");
    }
}

/// A `Context` given the engine's pipeline cache builds its pipelines with it: a material
/// decodes exactly as without one, and a second `Context` given a cache made from the first
/// cache's data decodes exactly too (where the adapter has pipeline caches). (Whether the driver
/// put compiled code in the cache is the driver's business: lavapipe's holds 96 bytes.)
#[test]
#[allow(unsafe_code)] // wgpu's pipeline-cache constructor is unsafe (see the SAFETY notes)
fn pipelines_come_from_the_engines_cache() {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default())).unwrap();
    if !adapter.features().contains(wgpu::Features::PIPELINE_CACHE) {
        eprintln!("the adapter has no pipeline caches: nothing to test");
        return;
    }
    let descriptor = wgpu::DeviceDescriptor {
        required_features: wgpu::Features::PIPELINE_CACHE,
        required_limits: wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits()),
        ..Default::default()
    };
    let (device, queue) = pollster::block_on(adapter.request_device(&descriptor)).unwrap();
    let bytes = golden("ntc_pbr10_96x80_clamp");
    let m = Container::parse(&bytes).unwrap();
    let r = (5, 3, 40, 21);
    let want = cpu_codes(&m, &rect(1, r), ChannelMask::ALL);
    let decode = |ctx: &Context| {
        let gm = ctx.upload(&device, &queue, &m).unwrap();
        ctx.submit_region(&device, &queue, &gm, 1, r, ChannelMask::ALL).unwrap().wait(&device)
    };
    let empty = wgpu::PipelineCacheDescriptor { label: None, data: None, fallback: true };
    // SAFETY: no data is given, so there is nothing wgpu must trust.
    let cache = unsafe { device.create_pipeline_cache(&empty) };
    let start = std::time::Instant::now();
    assert_eq!(decode(&Context::with_pipeline_cache(&device, cache.clone())).unwrap(), want);
    let first = start.elapsed();
    let data = cache.get_data().unwrap_or_default();
    eprintln!("{} bytes of pipeline cache after {first:.2?}", data.len());
    let filled = wgpu::PipelineCacheDescriptor { data: Some(&data), ..empty };
    // SAFETY: the data is what `get_data` returned for a cache of this very device, this run.
    let restored = unsafe { device.create_pipeline_cache(&filled) };
    let start = std::time::Instant::now();
    assert_eq!(decode(&Context::with_pipeline_cache(&device, restored)).unwrap(), want);
    eprintln!("again from the cache's data: {:.2?}", start.elapsed());
}

fn assert_send<T: Send>(_: &T) {}

/// The calls a browser can make (WebGPU, where every blocking call is refused): `upload_async`
/// and the pending results' `wait_async`, driven without a single blocking wait, with every
/// call that blocks refused on this thread as in a browser. Each returns pending first, is
/// woken by the device's answer, and gives what the blocking calls give: the same kernel and
/// tile kernel on a software adapter (neither is timed there), the CPU's codes and blocks; a
/// kernel whose codes differ is refused on its probe, and a JPEG material decodes too.
#[test]
fn async_calls_decode_exactly_without_blocking() {
    let (device, queue) = device();
    let bytes = golden("ntc_pbr10_96x80_clamp");
    let m = Container::parse(&bytes).unwrap();
    let blocking = Context::new(&device).upload(&device, &queue, &m).unwrap();
    nmat_wgpu::refuse_waits_on_this_thread_for_testing(true);
    let ctx = Context::new(&device);
    assert!(matches!(ctx.upload(&device, &queue, &m), Err(GpuError::CannotWait)));
    let upload = ctx.upload_async(&device, &queue, &m);
    assert_send(&upload);
    let (gm, polls) = run_as_a_browser(&device, upload);
    let gm = gm.unwrap();
    assert!(polls > 0, "upload_async was ready at once: it blocked");
    if device.adapter_info().device_type == wgpu::DeviceType::Cpu {
        assert_eq!(gm.kernel(), blocking.kernel());
    }
    assert_eq!(gm.tile_kernel(), gm.kernel(), "the tile entry's probe, awaited");
    assert!(gm.rejected().is_empty(), "{:?}", gm.rejected());
    let (r, mask) = ((5, 3, 70, 61), ChannelMask::ALL);
    let pending = ctx.submit_region(&device, &queue, &gm, 0, r, mask).unwrap();
    let codes = pending.wait_async();
    assert_send(&codes);
    let (codes, polls) = run_as_a_browser(&device, codes);
    assert!(polls > 0, "wait_async was ready at once");
    assert_same_bytes(&codes.unwrap(), &cpu_codes(&m, &rect(0, r), mask), "region");
    let pending = ctx.submit_region(&device, &queue, &gm, 0, r, mask).unwrap();
    assert!(matches!(pending.wait(&device), Err(GpuError::CannotWait)));
    // Its buffers went back to the pool: the next decode reuses them, codes intact.
    let reqs = random_requests(7, 300, 400, m.mip_count() + 1);
    let pending = ctx.submit_requests(&device, &queue, &gm, &reqs, mask).unwrap();
    let (codes, _) = run_as_a_browser(&device, pending.wait_async());
    assert_same_bytes(&codes.unwrap(), &cpu_codes(&m, &reqs, mask), "requests");
    let textures = [
        BcTexture { format: BcFormat::Bc1, channels: [0, 1, 2, 0], srgb: false },
        BcTexture { format: BcFormat::Bc4, channels: [3, 0, 0, 0], srgb: false },
    ];
    let pending = ctx.submit_transcode_textures(&device, &queue, &gm, &textures, 1).unwrap();
    let (got, polls) = run_as_a_browser(&device, pending.wait_async());
    assert!(polls > 0, "PendingTextures::wait_async was ready at once");
    let cpu = nmat_core::Decoder::new(&m);
    for (texture, blocks) in textures.iter().zip(&got.unwrap()) {
        assert_same_bytes(blocks, &cpu_blocks(&cpu, &m, texture, 1), texture.format.name());
    }
    // A kernel whose codes differ is refused on its awaited probe, and a tile entry whose
    // codes differ leaves the tiles to one texel per invocation.
    let broken = Context::new(&device);
    broken.break_kernel_for_testing(gm.kernel());
    broken.break_tile_decoders_for_testing();
    let named = broken.upload_with_async(&device, &queue, &m, Some(gm.kernel()));
    match run_as_a_browser(&device, named).0 {
        Err(GpuError::Kernel { kernel, reason }) => {
            assert_eq!(kernel, gm.kernel());
            assert!(reason.contains("differ"), "{reason}");
        }
        other => panic!("a broken kernel was not refused: {:?}", other.map(|g| g.kernel())),
    }
    let other = run_as_a_browser(&device, broken.upload_async(&device, &queue, &m)).0.unwrap();
    assert_ne!(other.kernel(), gm.kernel());
    assert_eq!(other.rejected().iter().map(|r| r.0).collect::<Vec<_>>(), [gm.kernel()]);
    assert_eq!(other.tile_kernel(), nmat_wgpu::Kernel::Reference);
    // A JPEG material (its decode pipelines built in the upload).
    let set = nmat_encode::demo::bricks(32);
    let jpeg = nmat_encode::jpeg::encode_jpeg(&set, &Default::default()).unwrap().bytes;
    let jm = Container::parse(&jpeg).unwrap();
    let (jgm, _) = run_as_a_browser(&device, ctx.upload_async(&device, &queue, &jm));
    let jgm = jgm.unwrap();
    let r = (0, 0, 32, 32);
    let pending = ctx.submit_region(&device, &queue, &jgm, 0, r, mask).unwrap();
    let (codes, _) = run_as_a_browser(&device, pending.wait_async());
    assert_same_bytes(&codes.unwrap(), &cpu_codes(&jm, &rect(0, r), mask), "JPEG region");
    nmat_wgpu::refuse_waits_on_this_thread_for_testing(false);
}

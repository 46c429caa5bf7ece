//! What the GPU tests share: the device, and a small trained material.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

/// The first adapter wgpu finds (lavapipe in CI); none is a failure, not a skip.
#[allow(dead_code)] // not every test file uses every helper
pub fn device() -> (wgpu::Device, wgpu::Queue) {
    let (device, queue, info) = pollster::block_on(nmat_wgpu::default_device()).expect(
        "no GPU adapter found: install a Vulkan driver (CI: apt-get install mesa-vulkan-drivers libvulkan1)",
    );
    eprintln!("adapter: {} ({:?}, {:?})", info.name, info.backend, info.device_type);
    (device, queue)
}

/// The bytes of the demo bricks (64²) trained for 150 steps.
#[allow(dead_code)] // not every test file uses every helper
pub fn trained_material() -> Vec<u8> {
    let set = nmat_encode::demo::bricks(64);
    let options = nmat_encode::EncodeOptions {
        train: nmat_encode::TrainOptions { steps: 150, ..Default::default() },
        ..Default::default()
    };
    nmat_encode::encode(&set, &options, &mut |_| {}).unwrap().bytes
}

/// A buffer of `size` bytes; with `fill`, its bytes are set to that value first.
#[allow(dead_code)] // not every test file uses every helper
pub fn buffer(
    device: &wgpu::Device,
    size: u64,
    usage: wgpu::BufferUsages,
    fill: Option<u8>,
) -> wgpu::Buffer {
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size,
        usage,
        mapped_at_creation: fill.is_some(),
    });
    if let Some(v) = fill {
        buffer.get_mapped_range_mut(..).unwrap().copy_from_slice(&vec![v; size as usize]);
        buffer.unmap();
    }
    buffer
}

/// The bytes of `source` (`COPY_SRC`), copied into a mappable buffer after the work in
/// `encoder`, which this submits.
#[allow(dead_code)]
pub fn submit_and_read(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    mut encoder: wgpu::CommandEncoder,
    source: &wgpu::Buffer,
) -> Vec<u8> {
    let size = source.size();
    let back =
        buffer(device, size, wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST, None);
    encoder.copy_buffer_to_buffer(source, 0, &back, 0, size);
    queue.submit([encoder.finish()]);
    back.map_async(wgpu::MapMode::Read, .., |r| r.unwrap());
    device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
    back.get_mapped_range(..).unwrap().to_vec()
}

/// The CPU's codes of `reqs`, channels in `mask`, texel after texel.
#[allow(dead_code)]
pub fn cpu_codes(
    m: &nmat_core::Material<'_>,
    reqs: &[nmat_wgpu::TexelRequest],
    mask: nmat_core::ChannelMask,
) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; 16];
    for r in reqs {
        let n = m.decode_texel_u8(i64::from(r.x), i64::from(r.y), r.mip, mask, &mut buf).unwrap();
        out.extend_from_slice(&buf[..n]);
    }
    out
}

/// `m` uploaded once per kernel the device runs: the tiled 32-bit and reference kernels run
/// everywhere; the dot4 kernel where the device's WGSL has `dot4I8Packed` (lavapipe has it, and
/// `NMAT_REQUIRE_DOT4=1` makes its absence a failure); the matrix kernel where the device has
/// cooperative matrices (lavapipe has none; `NMAT_REQUIRE_MATRIX=1` makes their absence a
/// failure). Each upload checked its kernel on a probe; the default upload takes one of them (on
/// a software adapter, which is not measured, the last of `Kernel::ALL`).
#[allow(dead_code)]
pub fn each_kernel(
    ctx: &nmat_wgpu::Context,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    m: &nmat_core::Material<'_>,
) -> Vec<nmat_wgpu::GpuMaterial> {
    let mut uploads = Vec::new();
    for kernel in nmat_wgpu::Kernel::ALL {
        match ctx.upload_with(device, queue, m, Some(kernel)) {
            Ok(gm) => {
                assert_eq!(gm.kernel(), kernel);
                uploads.push(gm);
            }
            // (Absent where the device lacks dot4I8Packed; codes that differ always fail.)
            Err(nmat_wgpu::GpuError::Kernel {
                kernel: k @ (nmat_wgpu::Kernel::Dot4 | nmat_wgpu::Kernel::UnrolledDot4),
                reason,
            }) if std::env::var_os("NMAT_REQUIRE_DOT4").is_none() && !reason.contains("differ") => {
                eprintln!("{} kernel not tested here: {reason}", k.name());
            }
            // (Absent without cooperative matrices, and refused for a network whose weights
            // exceed the workgroup memory.)
            Err(nmat_wgpu::GpuError::Kernel { kernel: nmat_wgpu::Kernel::Matrix, reason })
                if std::env::var_os("NMAT_REQUIRE_MATRIX").is_none()
                    || reason.contains(MATRIX_TOO_LARGE) =>
            {
                eprintln!("matrix kernel not tested here: {reason}");
            }
            Err(e) => panic!("{kernel:?}: {e}"),
        }
    }
    let chosen = ctx.upload(device, queue, m).unwrap();
    assert!(chosen.rejected().is_empty(), "{:?}", chosen.rejected());
    assert!(uploads.iter().any(|gm| gm.kernel() == chosen.kernel()));
    if device.adapter_info().device_type == wgpu::DeviceType::Cpu {
        assert_eq!(Some(chosen.kernel()), uploads.last().map(nmat_wgpu::GpuMaterial::kernel));
    }
    uploads
}

/// The reason the matrix kernel gives for a network whose staged weights exceed the device's
/// workgroup memory (a refusal, not a failure).
#[allow(dead_code)]
pub const MATRIX_TOO_LARGE: &str = "too large for the device's workgroup memory";

/// `got` equals `want` byte for byte; else fails naming `what` and the first byte that differs.
#[allow(dead_code)]
pub fn assert_same_bytes(got: &[u8], want: &[u8], what: impl std::fmt::Display) {
    let first = got.iter().zip(want).position(|(a, b)| a != b);
    assert!(
        got.len() == want.len() && first.is_none(),
        "{what}: first difference at byte {first:?} of {} (lengths {} and {})",
        want.len(),
        got.len(),
        want.len()
    );
}

/// The CPU's blocks of `texture` for the whole of `mip`, block rows without padding, and the
/// bytes a block takes.
#[allow(dead_code)]
pub fn cpu_blocks(
    cpu: &nmat_core::Decoder,
    m: &nmat_core::Material<'_>,
    texture: &nmat_core::bc::BcTexture,
    mip: u32,
) -> Vec<u8> {
    let region = nmat_core::BlockRegion::mip(m, mip);
    let row = region.width as usize * texture.format.block_bytes();
    let mut want = vec![0u8; row * region.height as usize];
    cpu.transcode_blocks(m, texture, mip, region, &mut want, row).unwrap();
    want
}

/// `count` requests from an LCG seeded with `seed`: x and y in [−span/2, span/2), mip below
/// `mips` (coordinates outside the mip wrap or clamp, mips past the chain clamp).
#[allow(dead_code)]
pub fn random_requests(
    seed: u64,
    count: usize,
    span: i64,
    mips: u32,
) -> Vec<nmat_wgpu::TexelRequest> {
    let mut s = seed;
    (0..count)
        .map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let v = (s >> 33) as i64;
            nmat_wgpu::TexelRequest {
                x: (v % span - span / 2) as i32,
                y: ((v >> 9) % span - span / 2) as i32,
                mip: (v >> 20) as u32 % mips,
            }
        })
        .collect()
}

/// A device on the first adapter with downlevel limits and no feature at all: no immediates
/// (dispatch parameters then come from a uniform buffer per call), no timestamps, no
/// cooperative matrices.
#[allow(dead_code)]
pub fn device_without_immediates() -> (wgpu::Device, wgpu::Queue) {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default())).unwrap();
    let limits = wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits());
    let descriptor = wgpu::DeviceDescriptor { required_limits: limits, ..Default::default() };
    pollster::block_on(adapter.request_device(&descriptor)).unwrap()
}

/// A device on the first adapter with f16 (`SHADER_F16`, which the matrix kernel's emulation
/// needs: lavapipe has it) and, as `default_device` asks, all the adapter's workgroup memory and
/// immediates where they fit; no adapter, or one without f16, is a failure — except on wgpu's GL
/// backend, which has no f16 at all (`None`: the emulated matrix kernel is not tested there; no
/// GL device has the cooperative matrices the real one needs either).
#[allow(dead_code)]
pub fn device_with_f16() -> Option<(wgpu::Device, wgpu::Queue)> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default())).unwrap();
    let f16 = adapter.features().contains(wgpu::Features::SHADER_F16);
    if !f16 && adapter.get_info().backend == wgpu::Backend::Gl {
        eprintln!("wgpu's GL backend has no f16: the emulated matrix kernel is not tested here");
        return None;
    }
    assert!(f16, "the adapter has no f16");
    let immediates = adapter.features().contains(wgpu::Features::IMMEDIATES)
        && adapter.limits().max_immediate_size >= nmat_wgpu::IMMEDIATE_BYTES;
    let descriptor = wgpu::DeviceDescriptor {
        required_features: wgpu::Features::SHADER_F16
            | if immediates { wgpu::Features::IMMEDIATES } else { wgpu::Features::empty() },
        required_limits: wgpu::Limits {
            max_compute_workgroup_storage_size: adapter.limits().max_compute_workgroup_storage_size,
            // As default_device: up to 8 storage buffers a stage (the matrix kernel with its
            // weights in storage binds 5).
            max_storage_buffers_per_shader_stage: adapter
                .limits()
                .max_storage_buffers_per_shader_stage
                .clamp(4, 8),
            max_immediate_size: if immediates { nmat_wgpu::IMMEDIATE_BYTES } else { 0 },
            ..wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits())
        },
        ..Default::default()
    };
    Some(pollster::block_on(adapter.request_device(&descriptor)).unwrap())
}

/// Whether buffers copy into compressed textures and back on `device`: not on wgpu's GL
/// backend, which copies no padded rows into them (`Context::record_bc_textures` refuses it)
/// and none out of them (gfx-rs/wgpu#8614; docs/GPU.md, "Known problems").
#[allow(dead_code)]
pub fn copies_bc_textures(device: &wgpu::Device) -> bool {
    device.adapter_info().backend != wgpu::Backend::Gl
}

/// Level `level` of the BC texture `texture` (`blocks` of `block_bytes` bytes), read back block
/// row by block row without padding.
#[allow(dead_code)]
pub fn read_level(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    level: u32,
    blocks: nmat_core::BlockRegion,
    block_bytes: usize,
) -> Vec<u8> {
    let usage = wgpu::BufferUsages::MAP_READ;
    let (back, pitch) = copy_level(device, queue, (texture, level), blocks, block_bytes, usage);
    back.map_async(wgpu::MapMode::Read, .., |r| r.unwrap());
    device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
    let got = back.get_mapped_range(..).unwrap().to_vec();
    unpadded_rows(&got, pitch, blocks.width as usize * block_bytes)
}

/// A new buffer (`usage` and `COPY_DST`) holding level `level` of a BC texture of `blocks`,
/// its rows padded to `COPY_BYTES_PER_ROW_ALIGNMENT` (the pitch, returned); the copy submitted.
#[allow(dead_code)]
pub fn copy_level(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    (texture, level): (&wgpu::Texture, u32),
    blocks: nmat_core::BlockRegion,
    block_bytes: usize,
    usage: wgpu::BufferUsages,
) -> (wgpu::Buffer, usize) {
    let row = blocks.width as usize * block_bytes;
    let pitch = row.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as usize);
    let back = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: (pitch * blocks.height as usize) as u64,
        usage: usage | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: level,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &back,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(pitch as u32),
                rows_per_image: Some(blocks.height),
            },
        },
        wgpu::Extent3d {
            width: 4 * blocks.width,
            height: 4 * blocks.height,
            depth_or_array_layers: 1,
        },
    );
    queue.submit([encoder.finish()]);
    (back, pitch)
}

/// The first `row` bytes of each `pitch` of `padded`.
#[allow(dead_code)]
pub fn unpadded_rows(padded: &[u8], pitch: usize, row: usize) -> Vec<u8> {
    padded.chunks(pitch).flat_map(|r| r[..row].to_vec()).collect()
}

/// The compute pipeline of `source`'s `main` (a test's own WGSL), with `layout` or, without one,
/// the layout wgpu derives from the shader.
#[allow(dead_code)]
pub fn compute_pipeline(
    device: &wgpu::Device,
    source: &str,
    layout: Option<&wgpu::PipelineLayout>,
) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: None,
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: None,
        layout,
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    })
}

/// Runs `pipeline` (its bind group 0 made of `entries`) over `groups` workgroups (x, y), submits
/// the work and returns the bytes of `out` after it.
#[allow(dead_code)]
pub fn run_compute(
    (device, queue): (&wgpu::Device, &wgpu::Queue),
    pipeline: &wgpu::ComputePipeline,
    entries: &[wgpu::BindGroupEntry<'_>],
    (x, y): (u32, u32),
    out: &wgpu::Buffer,
) -> Vec<u8> {
    let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(x, y, 1);
    }
    submit_and_read(device, queue, encoder, out)
}

/// Level `level` of the BC texture `texture` holds the blocks `want` (of `format`): byte for
/// byte where the device copies compressed textures back ([`copies_bc_textures`]); elsewhere
/// (wgpu's GL backend) as its texture unit reads them ([`assert_texture_unit_reads`]). Fails
/// naming `what`.
#[allow(dead_code)]
pub fn assert_bc_level(
    (device, queue): (&wgpu::Device, &wgpu::Queue),
    texture: &wgpu::Texture,
    level: u32,
    format: nmat_core::bc::BcFormat,
    want: &[u8],
    what: &str,
) {
    if !copies_bc_textures(device) {
        assert_texture_unit_reads((device, queue), texture, level, format, want, what);
        return;
    }
    let (w, h) = ((texture.width() >> level).max(1), (texture.height() >> level).max(1));
    let blocks = nmat_core::BlockRegion { x: 0, y: 0, width: w.div_ceil(4), height: h.div_ceil(4) };
    let got = read_level(device, queue, texture, level, blocks, format.block_bytes());
    assert_same_bytes(&got, want, what);
}

/// The texture unit reads level `level` of `texture` as `nmat_core::bc::decode_block` decodes
/// the blocks `want` (of `format`), within 2 steps ([`steps_off`]: hardware BC decoders may
/// round interpolated colours differently by a step). Fails naming `what`.
#[allow(dead_code)]
pub fn assert_texture_unit_reads(
    (device, queue): (&wgpu::Device, &wgpu::Queue),
    texture: &wgpu::Texture,
    level: u32,
    format: nmat_core::bc::BcFormat,
    want: &[u8],
    what: &str,
) {
    let worst = steps_off((device, queue), texture, level, format, want);
    assert!(worst <= 2, "{what}: the texture unit reads {worst} steps off");
}

/// The most steps by which the texture unit's reading of level `level` of `texture`
/// (`textureLoad`, each component × 255 rounded, after sRGB encoding for an sRGB texture)
/// differs from `nmat_core::bc::decode_block` of the blocks `want` of `format`, over the level's texels
/// and the format's components.
fn steps_off(
    (device, queue): (&wgpu::Device, &wgpu::Queue),
    texture: &wgpu::Texture,
    level: u32,
    format: nmat_core::bc::BcFormat,
    want: &[u8],
) -> u8 {
    let (w, h) = ((texture.width() >> level).max(1), (texture.height() >> level).max(1));
    let source = "@group(0) @binding(0) var t: texture_2d<f32>;
        @group(0) @binding(1) var<storage, read_write> out: array<vec4<f32>>;
        @compute @workgroup_size(8, 8)
        fn main(@builtin(global_invocation_id) id: vec3<u32>) {
            let size = textureDimensions(t, 0);
            if (id.x < size.x && id.y < size.y) {
                out[id.y * size.x + id.x] = textureLoad(t, vec2<i32>(id.xy), 0);
            }
        }";
    let pipeline = compute_pipeline(device, source, None);
    let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
    let out = buffer(device, u64::from(w) * u64::from(h) * 16, usage, None);
    let view = texture.create_view(&wgpu::TextureViewDescriptor {
        base_mip_level: level,
        mip_level_count: Some(1),
        ..Default::default()
    });
    let entries = [
        wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&view) },
        wgpu::BindGroupEntry { binding: 1, resource: out.as_entire_binding() },
    ];
    let groups = (w.div_ceil(8), h.div_ceil(8));
    let bytes = run_compute((device, queue), &pipeline, &entries, groups, &out);
    let srgb = texture.format().is_srgb();
    let block_bytes = format.block_bytes();
    let mut worst = 0;
    for (i, texel) in bytes.chunks(16).enumerate() {
        let (x, y) = (i as u32 % w, i as u32 / w);
        let b = ((y / 4) * w.div_ceil(4) + x / 4) as usize * block_bytes;
        let decoded = nmat_core::bc::decode_block(format, &want[b..b + block_bytes]);
        for k in 0..format.components() {
            let mut v = f32::from_le_bytes(texel[4 * k..4 * k + 4].try_into().unwrap());
            // The sRGB transfer function (alpha is stored linear).
            if srgb && k < 3 {
                v = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
            }
            let read = (v * 255.0).round().clamp(0.0, 255.0) as u8;
            worst = worst.max(read.abs_diff(decoded[((y % 4) * 4 + x % 4) as usize][k]));
        }
    }
    worst
}

/// Runs `future` as a browser's event loop would: polled only when its waker was called, the
/// device polled without blocking (`PollType::Poll`, which runs the mappings' callbacks) in
/// between; nothing here waits for the device. Returns the output and how often the future was
/// polled before it was ready. A future that blocked inside would be ready at its first poll;
/// one that forgot its waker would never be polled again (fails after 300 s).
#[allow(dead_code)]
pub fn run_as_a_browser<F: std::future::Future>(
    device: &wgpu::Device,
    future: F,
) -> (F::Output, usize) {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::task::{Poll, Wake, Waker};
    struct Woken(AtomicBool);
    impl Wake for Woken {
        fn wake(self: Arc<Self>) {
            self.0.store(true, Ordering::SeqCst);
        }
    }
    let woken = Arc::new(Woken(AtomicBool::new(true)));
    let waker = Waker::from(Arc::clone(&woken));
    let mut cx = std::task::Context::from_waker(&waker);
    let mut future = std::pin::pin!(future);
    let start = std::time::Instant::now();
    let mut polls = 0;
    loop {
        if woken.0.swap(false, Ordering::SeqCst) {
            if let Poll::Ready(output) = future.as_mut().poll(&mut cx) {
                return (output, polls);
            }
            polls += 1;
        } else {
            assert!(start.elapsed().as_secs() < 300, "not ready after 300 s ({polls} polls)");
            device.poll(wgpu::PollType::Poll).unwrap();
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    }
}

/// `count` lookups over the materials: u, v in multiples of 1/1024 across the edges, lod in
/// quarters past both ends of the chain, every filter, dyadic random numbers.
#[allow(dead_code)]
pub fn lookups(
    materials: &[nmat_core::Material<'_>],
    seed: u64,
    count: usize,
) -> Vec<(usize, nmat_core::SampleRequest)> {
    use nmat_core::{ChannelMask, Filter, Precision, SampleRequest};
    let mut r = nmat_tests::generate::Rng::new(seed);
    (0..count)
        .map(|_| {
            let i = r.range(0, materials.len() as i64 - 1) as usize;
            let filter = [Filter::Nearest, Filter::Bilinear, Filter::Trilinear, Filter::Stochastic]
                [r.range(0, 3) as usize];
            let mut dyadic = |lo: i64, hi: i64, scale: f32| r.range(lo, hi) as f32 / scale;
            let req = SampleRequest {
                u: dyadic(-300, 1300, 1024.0),
                v: dyadic(-300, 1300, 1024.0),
                lod: dyadic(-2, 4 * i64::from(materials[i].mip_count()) + 2, 4.0),
                filter,
                precision: Precision::Integer,
                random: [dyadic(0, 255, 256.0), dyadic(0, 255, 256.0), dyadic(0, 255, 256.0)],
                channels: ChannelMask::ALL,
            };
            (i, req)
        })
        .collect()
}

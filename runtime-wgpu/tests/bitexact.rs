//! The GPU decoder against the CPU integer decoder, byte for byte: every texel of every mip of
//! every golden fixture, a trained material, and random-access requests at odd coordinates with
//! channel subsets — through every kernel the device runs (`Kernel::ALL`). Runs on whatever
//! adapter wgpu finds (lavapipe in CI); no adapter is a failure.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{ChannelMask, Container, Material};
use nmat_tests::generate::{generate, golden_configs};
use nmat_tests::{decode_all_u8, fixtures_dir};
use nmat_wgpu::{Context, GpuError, GpuMaterial, Kernel, TexelRequest};

mod common;
use common::{cpu_codes, device, random_requests, trained_material};

/// `m` uploaded once per kernel the device runs: the tiled 32-bit and reference kernels run
/// everywhere; the dot4 kernel where the device's WGSL has `dot4I8Packed` (lavapipe has it, and
/// `NMAT_REQUIRE_DOT4=1` makes its absence a failure). The default upload takes the fastest.
fn each_kernel(ctx: &Context, device: &wgpu::Device, m: &Material<'_>) -> Vec<GpuMaterial> {
    let mut uploads = Vec::new();
    for kernel in Kernel::ALL {
        match ctx.upload_with(device, m, Some(kernel)) {
            Ok(gm) => {
                assert_eq!(gm.kernel(), kernel);
                uploads.push(gm);
            }
            Err(GpuError::Kernel { kernel: Kernel::Dot4, reason })
                if std::env::var_os("NMAT_REQUIRE_DOT4").is_none() =>
            {
                eprintln!("dot4 kernel not tested here: {reason}");
            }
            Err(e) => panic!("{kernel:?}: {e}"),
        }
    }
    // `Kernel::ALL` is slowest first: the fastest the device runs is the last upload.
    let fastest = uploads.last().map(GpuMaterial::kernel);
    assert_eq!(Some(ctx.upload(device, m).unwrap().kernel()), fastest, "not the fastest");
    uploads
}

#[test]
fn golden_fixtures_decode_identically_on_the_gpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    for cfg in golden_configs() {
        let bytes = std::fs::read(fixtures_dir().join(format!("{}.nmat", cfg.name))).unwrap();
        let m = Container::parse(&bytes).unwrap();
        let cpu = decode_all_u8(&m);
        for gm in each_kernel(&ctx, &device, &m) {
            let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
            assert_eq!(gpu.len(), cpu.len(), "{}", cfg.name);
            let first = gpu.iter().zip(&cpu).position(|(a, b)| a != b);
            let kernel = gm.kernel();
            assert!(first.is_none(), "{} {kernel:?}: first difference at code {first:?}", cfg.name);
        }
    }
}

#[test]
fn random_access_requests_and_subsets_match_the_cpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let cfg = golden_configs().into_iter().find(|c| c.name == "ntc_pbr10_96x80_clamp").unwrap();
    let spec = generate(&cfg);
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let mut reqs = random_requests(12345, 500, 400, 9);
    reqs.extend([
        TexelRequest { x: i32::MIN, y: i32::MAX, mip: 0 },
        TexelRequest { x: i32::MAX, y: i32::MIN, mip: u32::MAX },
    ]);
    let as_requests: Vec<TexelRequest> =
        (7..18).flat_map(|y| (5..35).map(move |x| TexelRequest { x, y, mip: 1 })).collect();
    for gm in each_kernel(&ctx, &device, &m) {
        let kernel = gm.kernel();
        for mask in [ChannelMask::ALL, ChannelMask(0b1), ChannelMask(0b10_1001_0110)] {
            let gpu = ctx.decode_requests(&device, &queue, &gm, &reqs, mask).unwrap();
            assert_eq!(gpu, cpu_codes(&m, &reqs, mask), "{kernel:?}, mask {mask:?}");
        }
        // A region equals the same texels decoded one by one.
        let region = ctx
            .submit_region(&device, &queue, &gm, 1, (5, 7, 30, 11), ChannelMask(0b111))
            .unwrap()
            .wait(&device)
            .unwrap();
        assert_eq!(region, cpu_codes(&m, &as_requests, ChannelMask(0b111)), "{kernel:?}");
    }
    let gm = ctx.upload(&device, &m).unwrap();
    // Sizes are validated before anything is submitted.
    assert!(ctx.submit_region(&device, &queue, &gm, 1, (40, 0, 10, 1), ChannelMask::ALL).is_err());
    assert!(ctx.submit_region(&device, &queue, &gm, 9, (0, 0, 1, 1), ChannelMask::ALL).is_err());
    assert!(ctx.decode_requests(&device, &queue, &gm, &reqs, ChannelMask(1 << 12)).is_err());
    assert!(ctx.decode_requests(&device, &queue, &gm, &reqs, ChannelMask(0)).is_err());
}

#[test]
fn a_trained_material_decodes_identically_on_the_gpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let trained = trained_material();
    let m = Container::parse(&trained).unwrap();
    let cpu = decode_all_u8(&m);
    for gm in each_kernel(&ctx, &device, &m) {
        let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
        assert!(gpu == cpu, "trained material differs on the GPU ({:?})", gm.kernel());
    }
}

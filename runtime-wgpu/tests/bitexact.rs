//! The GPU decoder against the CPU integer decoder, byte for byte: every texel of every mip of
//! every golden fixture, a trained material, and random-access requests at odd coordinates with
//! channel subsets. Runs on whatever adapter wgpu finds (lavapipe in CI); no adapter is a failure.

use nmat_core::{ChannelMask, Container};
use nmat_tests::generate::{generate, golden_configs};
use nmat_tests::{decode_all_u8, fixtures_dir};
use nmat_wgpu::{Context, TexelRequest};

mod common;
use common::{cpu_codes, device, random_requests, trained_material};

#[test]
fn golden_fixtures_decode_identically_on_the_gpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    for cfg in golden_configs() {
        let bytes = std::fs::read(fixtures_dir().join(format!("{}.nmat", cfg.name))).unwrap();
        let m = Container::parse(&bytes).unwrap();
        let gm = ctx.upload(&device, &m).unwrap();
        let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
        let cpu = decode_all_u8(&m);
        assert_eq!(gpu.len(), cpu.len(), "{}", cfg.name);
        let first = gpu.iter().zip(&cpu).position(|(a, b)| a != b);
        assert!(first.is_none(), "{}: first difference at code {first:?}", cfg.name);
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
    let gm = ctx.upload(&device, &m).unwrap();
    let mut reqs = random_requests(12345, 500, 400, 9);
    reqs.extend([
        TexelRequest { x: i32::MIN, y: i32::MAX, mip: 0 },
        TexelRequest { x: i32::MAX, y: i32::MIN, mip: u32::MAX },
    ]);
    for mask in [ChannelMask::ALL, ChannelMask(0b1), ChannelMask(0b10_1001_0110)] {
        let gpu = ctx.decode_requests(&device, &queue, &gm, &reqs, mask).unwrap();
        assert_eq!(gpu, cpu_codes(&m, &reqs, mask), "mask {mask:?}");
    }
    // A region equals the same texels decoded one by one.
    let region = ctx
        .submit_region(&device, &queue, &gm, 1, (5, 7, 30, 11), ChannelMask(0b111))
        .unwrap()
        .wait(&device)
        .unwrap();
    let as_requests: Vec<TexelRequest> =
        (7..18).flat_map(|y| (5..35).map(move |x| TexelRequest { x, y, mip: 1 })).collect();
    assert_eq!(region, cpu_codes(&m, &as_requests, ChannelMask(0b111)));
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
    let gm = ctx.upload(&device, &m).unwrap();
    let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
    assert!(gpu == decode_all_u8(&m), "trained material differs on the GPU");
}

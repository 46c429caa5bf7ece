//! The GPU decoder against the CPU integer decoder, byte for byte: every texel of every mip of
//! every golden fixture, of every scale of the LOD feature and of a trained material, and
//! random-access requests at odd coordinates with channel subsets — through every kernel the
//! device runs (`Kernel::ALL`). Runs on whatever adapter wgpu finds (lavapipe in CI); no adapter
//! is a failure.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{Body, ChannelMask, Container, Material};
use nmat_tests::generate::{generate, golden_configs};
use nmat_tests::{decode_all_u8, fixtures_dir};
use nmat_wgpu::{Context, GpuError, Kernel, TexelRequest};

mod common;
use common::{
    assert_same_bytes, cpu_codes, device, each_kernel, random_requests, trained_material,
};

#[test]
fn golden_fixtures_decode_identically_on_the_gpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    for cfg in golden_configs() {
        let bytes = std::fs::read(fixtures_dir().join(format!("{}.nmat", cfg.name))).unwrap();
        let m = Container::parse(&bytes).unwrap();
        let cpu = decode_all_u8(&m);
        for gm in each_kernel(&ctx, &device, &queue, &m) {
            let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
            assert_same_bytes(&gpu, &cpu, format!("{} {:?}", cfg.name, gm.kernel()));
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
    for gm in each_kernel(&ctx, &device, &queue, &m) {
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
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    // Sizes are validated before anything is submitted.
    assert!(ctx.submit_region(&device, &queue, &gm, 1, (40, 0, 10, 1), ChannelMask::ALL).is_err());
    assert!(ctx.submit_region(&device, &queue, &gm, 9, (0, 0, 1, 1), ChannelMask::ALL).is_err());
    assert!(ctx.decode_requests(&device, &queue, &gm, &reqs, ChannelMask(1 << 12)).is_err());
    assert!(ctx.decode_requests(&device, &queue, &gm, &reqs, ChannelMask(0)).is_err());
}

#[test]
fn every_lod_feature_scale_decodes_identically_on_the_gpu() {
    // The LOD feature mip · 2^(code − 5) (FORMAT.md §6.5): none, code 1 (mip / 16, before
    // format 2.3) and the scaled codes, at the input formats they fit, on a 7-mip chain.
    let (device, queue) = device();
    let ctx = Context::new(&device);
    for (code, f) in [(0u8, 12u8), (1, 12), (4, 12), (1, 11), (5, 11)] {
        let cfg = nmat_tests::generate::FixtureConfig {
            lod_input: code,
            input_frac_bits: f,
            ..nmat_tests::generate::FixtureConfig::ntc("lod", 40 + u64::from(code), 64, 48, 7)
        };
        let bytes = generate(&cfg).to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let cpu = decode_all_u8(&m);
        for gm in each_kernel(&ctx, &device, &queue, &m) {
            let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
            assert!(gpu == cpu, "LOD code {code}, Q.{f}: differs on the GPU ({:?})", gm.kernel());
        }
    }
}

#[test]
fn a_trained_material_decodes_identically_on_the_gpu() {
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let trained = trained_material();
    let m = Container::parse(&trained).unwrap();
    let cpu = decode_all_u8(&m);
    for gm in each_kernel(&ctx, &device, &queue, &m) {
        let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
        assert!(gpu == cpu, "trained material differs on the GPU ({:?})", gm.kernel());
    }
}

/// The matrix kernel's structure — everything but its matrix instructions: the staged weights,
/// the input features split into bytes, the products' round trip through workgroup memory, the
/// requantization, the codes, the tile cache's entry — on a device without matrix units
/// (lavapipe): its cooperative matrix operations emulated in scalar code
/// (`emulate_matrix_for_testing`), the golden fixtures' chains, a trained material, random
/// requests with channel subsets and a region equal the CPU's codes byte for byte (each
/// upload's probes checked first); and in the variants `NMAT_WGPU_MATRIX_SUMS=paired` (the
/// products' round trip) and `NMAT_WGPU_MATRIX_WEIGHTS=storage` (the weights read from a
/// storage buffer, a bind group of their own) select, three fixtures and the requests. The real
/// kernel differs only in the matrix instructions (naga validates it: `matrix::tests`).
#[test]
fn the_matrix_kernel_with_emulated_matrices_decodes_identically() {
    let Some((device, queue)) = common::device_with_f16() else { return };
    // The golden fixtures but three, each a compile of seconds on lavapipe: the NBC one whose
    // input features take longest (the other NBC fixture has its chains; the features are the
    // other kernels' and tested with them) and two ntc ones whose networks the others cover.
    let left_out = ["nbc_8421_64", "ntc_1bit_q10_40x24", "ntc_hi_twice_48x40"];
    let mut materials: Vec<(String, Vec<u8>)> = golden_configs()
        .into_iter()
        .filter(|cfg| !left_out.contains(&cfg.name))
        .map(|cfg| {
            let path = fixtures_dir().join(format!("{}.nmat", cfg.name));
            (cfg.name.to_string(), std::fs::read(path).unwrap())
        })
        .collect();
    materials.push(("trained".into(), trained_material()));
    // The variants but the default on three fixtures.
    let variant_set = ["ntc_pbr10_96x80_clamp", "ntc_16ch_8bit_32", "strip_1x37"];
    for (paired, storage) in [(false, false), (true, false), (false, true)] {
        let variant = format!("paired {paired}, weights in storage {storage}");
        let all = !paired && !storage;
        let ctx = Context::new(&device);
        ctx.emulate_matrix_for_testing(paired, storage);
        let upload = |m: &Material<'_>| {
            let gm = ctx.upload_with(&device, &queue, m, Some(Kernel::Matrix)).unwrap();
            assert_eq!(gm.kernel(), Kernel::Matrix);
            // Its tile entry (matrix_cache) passed its probe: whole tiles, edges, the last mip.
            assert_eq!(gm.tile_kernel(), Kernel::Matrix);
            gm
        };
        for (name, bytes) in materials.iter().filter(|(n, _)| all || variant_set.contains(&&**n)) {
            let m = Container::parse(bytes).unwrap();
            let gpu = ctx.decode_chain(&device, &queue, &upload(&m), ChannelMask::ALL).unwrap();
            let cpu = decode_all_u8(&m);
            assert_same_bytes(&gpu, &cpu, format!("{name}, {variant}"));
        }
        let bytes = std::fs::read(fixtures_dir().join("ntc_pbr10_96x80_clamp.nmat")).unwrap();
        let m = Container::parse(&bytes).unwrap();
        let gm = upload(&m);
        let reqs = random_requests(777, 300, 400, 9);
        for mask in [ChannelMask::ALL, ChannelMask(0b1), ChannelMask(0b10_1001_0110)] {
            let gpu = ctx.decode_requests(&device, &queue, &gm, &reqs, mask).unwrap();
            assert_eq!(gpu, cpu_codes(&m, &reqs, mask), "mask {mask:?}, {variant}");
        }
        let region = ctx
            .submit_region(&device, &queue, &gm, 0, (3, 5, 41, 13), ChannelMask(0b1110))
            .unwrap()
            .wait(&device)
            .unwrap();
        let texels: Vec<TexelRequest> =
            (5..18).flat_map(|y| (3..44).map(move |x| TexelRequest { x, y, mip: 0 })).collect();
        assert_eq!(region, cpu_codes(&m, &texels, ChannelMask(0b1110)), "{variant}");
    }
}

/// The layouts `scripts/gpu-run.sh` times the matrix kernel in (`NMAT_WGPU_MATRIX`,
/// `NMAT_WGPU_MATRIX_PAD`, `NMAT_WGPU_MATRIX_SUMS`, `NMAT_WGPU_MATRIX_WEIGHTS`) that the
/// default one does not cover, and three subgroups (batches of 48 texels, which do not divide a
/// tile), emulated: two texel blocks a subgroup, eight batches, the paired round trip without
/// pads, one subgroup with two texel blocks and the weights in storage. A 10-channel fixture
/// with partial tiles decodes as the CPU in each, through the kernel and its tile entry (whose
/// probe must pass), so that a layout's own code is checked before a GPU's time is spent on it
/// (about 11 s of lavapipe's compilation a layout, cold). A device with less workgroup memory
/// than a layout needs runs it with fewer subgroups.
#[test]
fn the_matrix_kernel_in_every_measured_layout_decodes_identically() {
    let Some((device, queue)) = common::device_with_f16() else { return };
    let bytes = std::fs::read(fixtures_dir().join("ntc_pbr10_96x80_clamp.nmat")).unwrap();
    let m = Container::parse(&bytes).unwrap();
    let cpu = decode_all_u8(&m);
    let (default_layout, default_pads) = ((4, 1, 4), (8, 8, 4));
    for (name, paired, storage, layout, pads) in [
        ("blocks-2", false, false, (4, 2, 4), default_pads),
        ("batches-8", false, false, (4, 1, 8), default_pads),
        ("three subgroups", false, false, (3, 1, 4), default_pads),
        ("paired-pad-0", true, false, default_layout, (0, 0, 0)),
        ("storage-1x2", false, true, (1, 2, 8), default_pads),
    ] {
        let ctx = Context::new(&device);
        ctx.emulate_matrix_for_testing(paired, storage);
        ctx.emulate_matrix_layout_for_testing(layout, pads);
        let gm = ctx.upload_with(&device, &queue, &m, Some(Kernel::Matrix)).unwrap();
        assert_eq!(gm.tile_kernel(), Kernel::Matrix, "{name}: the tile entry's probe");
        // The layout asked for: P = 16 · blocks · subgroups · batches, with as many of the
        // subgroups as the workgroup memory holds (all three where three are asked).
        let (warps, blocks, batches) = layout;
        let per_warp = 16 * blocks * batches;
        let texels = gm.workgroup_texels().unwrap();
        assert!(
            texels.is_multiple_of(per_warp) && (1..=warps).contains(&(texels / per_warp)),
            "{name}"
        );
        if warps == 3 {
            assert_eq!(texels, 3 * per_warp, "{name}");
        }
        let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
        assert_same_bytes(&gpu, &cpu, name);
    }
}

/// Never wrong: a kernel whose codes differ from the CPU's on the upload's probe is not used.
/// The kernel the default upload picks is broken on purpose (`break_kernel_for_testing`: the
/// last layer's first row requantized to 0, so channel 0 decodes as code 0): the upload falls
/// back to another kernel, names the broken one in `rejected`, and still decodes every mip as
/// the CPU does. Every kernel, broken and asked for, is an error that says why.
#[test]
fn a_kernel_that_differs_from_the_cpu_on_the_probe_is_not_used() {
    let (device, queue) = device();
    let cfg = golden_configs().into_iter().find(|c| c.name == "ntc_rgb_64").unwrap();
    let bytes = std::fs::read(fixtures_dir().join(format!("{}.nmat", cfg.name))).unwrap();
    let m = Container::parse(&bytes).unwrap();
    let cpu = decode_all_u8(&m);
    // Channel 0 is not code 0 everywhere, so the broken row shows on the probe.
    assert!(cpu.chunks(m.channel_count()).any(|texel| texel[0] != 0));
    let chosen = Context::new(&device).upload(&device, &queue, &m).unwrap().kernel();
    let ctx = Context::new(&device);
    ctx.break_kernel_for_testing(chosen);
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    assert_ne!(gm.kernel(), chosen);
    assert_eq!(gm.rejected(), [(chosen, "its codes on the probe differ from the CPU's")]);
    let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
    assert!(gpu == cpu, "{:?} after rejecting {chosen:?}", gm.kernel());
    let mut runs = 0;
    for broken in Kernel::ALL {
        let ctx = Context::new(&device);
        if ctx.upload_with(&device, &queue, &m, Some(broken)).is_err() {
            continue; // not on this device
        }
        runs += 1;
        ctx.break_kernel_for_testing(broken);
        match ctx.upload_with(&device, &queue, &m, Some(broken)) {
            Err(GpuError::Kernel { kernel, reason }) => {
                assert_eq!(kernel, broken);
                assert!(reason.contains("differ from the CPU"), "{reason}");
            }
            other => panic!("{broken:?}: {:?}", other.map(|gm| gm.kernel())),
        }
    }
    assert!(runs >= 3, "{runs} kernels run here");
}

/// Kernel choices kept between runs (`kernel_choices` / `remember_kernel_choices`): a choice
/// remembered for the material's shape, written as the docs say (the layer widths, then the
/// channel count), is the kernel `upload` uses — here a kernel other than the one it picks by
/// itself — and decodes as the CPU; it is written back out; a choice made on another adapter
/// is not taken; a remembered kernel whose probe fails is not used (the upload falls back);
/// text that is not such a text is refused, naming its line, and taken in no part.
#[test]
fn remembered_kernel_choices_are_used_where_they_were_made() {
    let (device, queue) = device();
    let bytes = std::fs::read(fixtures_dir().join("ntc_rgb_64.nmat")).unwrap();
    let m = Container::parse(&bytes).unwrap();
    let cpu = decode_all_u8(&m);
    let Body::Neural(n) = m.body() else { panic!("a neural fixture") };
    let widths: Vec<(usize, usize)> =
        n.mlp().layers().iter().map(|l| (l.inputs(), l.outputs())).collect();
    let shape = format!("{widths:?} {}", m.channel_count());
    let own = Context::new(&device).upload(&device, &queue, &m).unwrap().kernel();
    let other = Kernel::ALL
        .into_iter()
        .find(|&k| {
            k != own && Context::new(&device).upload_with(&device, &queue, &m, Some(k)).is_ok()
        })
        .unwrap();
    let header = Context::new(&device).kernel_choices(&device);
    let header = header.lines().next().unwrap();
    let text = format!("{header}\n{}\t{shape}\n", other.id());

    let ctx = Context::new(&device);
    assert_eq!(ctx.remember_kernel_choices(&device, &text).unwrap(), 1);
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    assert_eq!(gm.kernel(), other, "the remembered kernel, not {own:?}");
    let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
    assert_same_bytes(&gpu, &cpu, format!("remembered {other:?}"));
    assert_eq!(ctx.kernel_choices(&device), text);

    // Made on another adapter (or driver, or version): nothing taken.
    let elsewhere = Context::new(&device);
    let foreign =
        format!("nmat-wgpu kernel choices 0.0.0 on another GPU\n{}\t{shape}\n", other.id());
    assert_eq!(elsewhere.remember_kernel_choices(&device, &foreign).unwrap(), 0);
    assert_eq!(elsewhere.kernel_choices(&device), format!("{header}\n"));
    if device.adapter_info().device_type == wgpu::DeviceType::Cpu {
        // Nothing measured here: the upload picks as it does by itself. (A GPU measures
        // again, and may rank kernels of close speeds otherwise.)
        assert_eq!(elsewhere.upload(&device, &queue, &m).unwrap().kernel(), own);
    }

    // Remembered, but its probe differs from the CPU: not used.
    let broken = Context::new(&device);
    broken.remember_kernel_choices(&device, &text).unwrap();
    broken.break_kernel_for_testing(other);
    let gm = broken.upload(&device, &queue, &m).unwrap();
    assert_ne!(gm.kernel(), other);
    assert_eq!(gm.rejected(), [(other, "its codes on the probe differ from the CPU's")]);
    let gpu = broken.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
    assert_same_bytes(&gpu, &cpu, format!("{:?} after the remembered {other:?}", gm.kernel()));

    // Not such a text: refused, naming the line, nothing taken (line 2 is good, 3 is not).
    let good = format!("{}\t{shape}", other.id());
    for (bad, line, reason) in [
        ("# my kernels\n".to_string(), 1, "first line"),
        (format!("{header}\n{good}\ntiled dot4\t{shape}\n"), 3, "not a kernel's name"),
        (format!("{header}\n{good}\ndot4 {shape}\n"), 3, "a tab"),
        (format!("{header}\n{good}\ndot4\t\n"), 3, "no network shape"),
    ] {
        let ctx = Context::new(&device);
        match ctx.remember_kernel_choices(&device, &bad) {
            Err(e @ GpuError::KernelChoices { line: at, .. }) => {
                assert_eq!(at, line, "{bad:?}: {e}");
                assert!(e.to_string().contains(&format!("line {line}: ")), "{e}");
                assert!(e.to_string().contains(reason), "{e}");
            }
            other => panic!("{bad:?}: {other:?}"),
        }
        assert_eq!(ctx.kernel_choices(&device), format!("{header}\n"), "{bad:?}");
    }
}

/// No hang: a probe decode that has not finished when the upload's wait for it ends is reported
/// as `GpuError::Hung`, naming the kernel, instead of being waited for without end (a kernel
/// that never finishes on some driver). A wait of zero cannot see lavapipe finish a probe of
/// hundreds of texels (a race the device could win is retried). The device stays usable: once
/// the probe has run, a fresh upload with the normal wait decodes as the CPU does.
#[test]
fn a_probe_that_does_not_finish_in_time_is_reported_not_waited_for() {
    let (device, queue) = device();
    let bytes = std::fs::read(fixtures_dir().join("ntc_pbr10_96x80_clamp.nmat")).unwrap();
    let m = Container::parse(&bytes).unwrap();
    let mut reported = Vec::new();
    for forced in [None, Some(Kernel::Reference)] {
        for _attempt in 0..5 {
            let ctx = Context::new(&device);
            ctx.limit_probe_wait_for_testing(std::time::Duration::ZERO);
            match ctx.upload_with(&device, &queue, &m, forced) {
                Err(GpuError::Hung { kernel, seconds: 0 }) => {
                    reported.push((forced, kernel));
                    break;
                }
                Ok(_) => eprintln!("{forced:?}: the device finished first; again"),
                Err(e) => panic!("{forced:?}: {e}"),
            }
        }
    }
    // The default upload stops at the first kernel it probes (the fastest first: not the
    // reference one); a forced kernel is named as itself. (On wgpu's GL backend over Mesa's
    // llvmpipe the probe had finished when the zero wait asked in 10 of 10 attempts — GL runs
    // the work as it is submitted — so every upload above took its kernel, as it should once
    // the device has finished.)
    if !(reported.is_empty() && device.adapter_info().backend == wgpu::Backend::Gl) {
        assert_eq!(reported.len(), 2, "{reported:?}");
        assert_ne!(reported[0].1, Kernel::Reference);
        assert_eq!(reported[1].1, Kernel::Reference);
    }
    let message = GpuError::Hung { kernel: Kernel::Reference, seconds: 20 }.to_string();
    assert!(message.contains("reference kernel's probe did not finish within 20 s"), "{message}");
    device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
    let ctx = Context::new(&device);
    let gm = ctx.upload(&device, &queue, &m).unwrap();
    let gpu = ctx.decode_chain(&device, &queue, &gm, ChannelMask::ALL).unwrap();
    assert!(gpu == decode_all_u8(&m));
}

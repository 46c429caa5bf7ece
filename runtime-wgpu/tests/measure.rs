//! The measuring tools of `nmat_wgpu::measure` on whatever adapter wgpu finds (lavapipe in CI).

use nmat_wgpu::measure::{self, Clock};

mod common;
use common::device;

/// The probes report finite positive rates, and `dot4I8Packed` (4 MACs a call) where the
/// language has it; work timed with 4 repeats takes about a quarter of the total per repeat.
#[test]
fn peaks_and_timings_are_positive_and_scale_with_the_work() {
    let (device, queue) = device();
    let peak = measure::probe_peak(&device, &queue).unwrap();
    assert!(peak.i32_mad_per_s.is_finite() && peak.i32_mad_per_s > 1e6, "{peak:?}");
    assert!(peak.dot4_mac_per_s.is_none_or(|r| r.is_finite() && r > 1e6), "{peak:?}");
    let want = if device.features().contains(measure::TIMESTAMP_FEATURES) {
        Clock::Timestamps
    } else {
        Clock::WallClock
    };
    assert_eq!(peak.clock, want);
    // A failing record is passed through, not timed.
    let failed = measure::time_recorded(&device, &queue, 3, |_| {
        Err(nmat_wgpu::GpuError::Map("refused".to_string()))
    });
    assert!(matches!(failed, Err(nmat_wgpu::GpuError::Map(m)) if m == "refused"));
    let mut calls = 0;
    let (seconds, clock) = measure::time_recorded(&device, &queue, 4, |_| {
        calls += 1;
        Ok(())
    })
    .unwrap();
    assert_eq!(calls, 1 + 4, "one warm-up and four timed repeats");
    assert!(seconds.is_finite() && seconds >= 0.0);
    assert_eq!(clock, want);
}

/// `time_stages` times each stage apart in one submission: an empty stage takes less than one
/// that clears 64 MiB, and the stages add up to the whole; a failing stage is passed through.
#[test]
fn stages_are_timed_apart_and_add_up() {
    let (device, queue) = device();
    let size = 64 << 20;
    let buffer = device.create_buffer(&nmat_wgpu::wgpu::BufferDescriptor {
        label: Some("cleared"),
        size,
        usage: nmat_wgpu::wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut calls = 0;
    let timed = measure::time_stages(
        &device,
        &queue,
        &mut [
            &mut |_| {
                calls += 1;
                Ok(())
            },
            &mut |encoder| {
                for _ in 0..4 {
                    encoder.clear_buffer(&buffer, 0, Some(size));
                }
                Ok(())
            },
            &mut |_| Ok(()),
        ],
    )
    .unwrap();
    assert_eq!(calls, 1, "each stage is recorded once");
    assert!(timed.seconds.is_finite() && timed.seconds > 0.0, "{timed:?}");
    if timed.clock == Clock::WallClock {
        assert_eq!(timed.stages, None);
    } else {
        let stages = timed.stages.clone().unwrap();
        assert_eq!(stages.len(), 3, "{timed:?}");
        let sum: f64 = stages.iter().sum();
        assert!((sum - timed.seconds).abs() <= 1e-9 + 1e-6 * timed.seconds, "{timed:?}");
        assert!(stages[1] > stages[0] && stages[1] > stages[2], "{timed:?}");
    }
    let failed = measure::time_stages(
        &device,
        &queue,
        &mut [&mut |_| Ok(()), &mut |_| Err(nmat_wgpu::GpuError::Map("refused".to_string()))],
    );
    assert!(matches!(failed, Err(nmat_wgpu::GpuError::Map(m)) if m == "refused"));
}

/// A kernel's parts for timing (`upload_part_for_timing`) run and give other codes than the
/// whole kernel, varying by texel (the features alone fold each texel's features into its codes,
/// the layers alone run on stand-in features that vary by texel: neither is constant, so no
/// compiler can drop or fold the part being timed); the reference kernel and a JPEG material
/// have no parts.
#[test]
fn kernel_parts_for_timing_do_only_their_part() {
    use nmat_core::{ChannelMask, Container};
    use nmat_wgpu::measure::Part;
    use nmat_wgpu::{Context, GpuError, Kernel};
    let (device, queue) = device();
    let ctx = Context::new(&device);
    let fixtures = nmat_tests::fixtures_dir();
    let bytes = std::fs::read(fixtures.join("ntc_pbr10_96x80_clamp.nmat")).unwrap();
    let m = Container::parse(&bytes).unwrap();
    let c = m.channel_count();
    for kernel in [Kernel::Int32, Kernel::Dot4, Kernel::UnrolledInt32, Kernel::UnrolledDot4] {
        let Ok(whole) = ctx.upload_with(&device, &queue, &m, Some(kernel)) else {
            assert!(
                std::env::var_os("NMAT_REQUIRE_DOT4").is_none() && kernel.name().contains("dot4")
            );
            continue;
        };
        let want = ctx.decode_mip(&device, &queue, &whole, 0, ChannelMask::ALL).unwrap();
        assert!(want.chunks(c).any(|t| t != &want[..c]), "a material with varying texels");
        for part in [Part::Features, Part::Layers] {
            let timed = ctx.upload_part_for_timing(&device, &m, kernel, part).unwrap();
            let got = ctx.decode_mip(&device, &queue, &timed, 0, ChannelMask::ALL).unwrap();
            assert_eq!(got.len(), want.len());
            assert!(got != want, "{kernel:?} {part:?}: not the whole kernel's codes");
            assert!(got.chunks(c).any(|t| t != &got[..c]), "{kernel:?} {part:?}: constant");
        }
    }
    let refused = ctx.upload_part_for_timing(&device, &m, Kernel::Reference, Part::Layers);
    assert!(matches!(refused, Err(GpuError::Kernel { kernel: Kernel::Reference, .. })));
    let jpeg = std::fs::read(fixtures.join("jpeg/pattern_420_37x21.nmat")).unwrap();
    let jpeg = Container::parse(&jpeg).unwrap();
    let refused = ctx.upload_part_for_timing(&device, &jpeg, Kernel::Dot4, Part::Features);
    assert!(matches!(refused, Err(GpuError::Codec)));
}

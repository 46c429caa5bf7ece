//! The numerical extremes of the integer decoder (docs/FORMAT.md §5–6), one test group each:
//! 1. the accumulator bound (fan-in, weights and inputs at their limits, bias at and past the
//!    limit); 2. requantization corners; 3. hardGELU over every i16; 4. latents at their extremes
//!    and interpolation weights; 5. coordinates and LOD (0, 1 − ε, negative, huge, NaN); 6. sizes
//!    (1×1 to 16384², mip sizes, the positional encoding's phase); 7. file values (NaN, infinite,
//!    subnormal, negative and zero scales); 8. outputs far out of range clamp. Agreement of the
//!    SIMD kernels with the definition is tested in `core-nostd/src/decoder/kernel/tests.rs`, of
//!    every decoder with golden hashes in `golden.rs`, of the GPU in `runtime-wgpu`.

use nmat_core::Requant;
use nmat_core::internals::hard_gelu_q;
use nmat_core::internals::triangle_q;
use nmat_core::{
    AddressMode, ChannelMask, Container, Error, Field, Filter, MaterialSpec, Precision,
    SampleRequest,
};
use nmat_tests::generate::{
    BIAS_LIMIT_128, FixtureConfig, Layout, accumulator_corners, generate, largest_material,
    set_codes, wide_constant_material,
};
use nmat_tests::reference;

fn small(name: &'static str) -> MaterialSpec {
    generate(&FixtureConfig::ntc(name, 11, 16, 12, 3))
}

// 1. Accumulator bound.
#[test]
fn accumulator_at_the_bound_does_not_overflow_and_beyond_is_rejected() {
    let limit = BIAS_LIMIT_128;
    for (input, weight, bias) in accumulator_corners() {
        let spec = wide_constant_material(input, weight, bias);
        let bytes = spec.to_bytes().expect("bias at the limit is valid");
        let m = Container::parse(&bytes).unwrap();
        let mut out = [0u16; 1];
        m.decode_texel_u16(1, 2, 0, ChannelMask::ALL, &mut out).unwrap();
        // The reference accumulates in i64 and asserts |acc| < 2^31.
        assert_eq!(out.to_vec(), reference::decode_u16(&spec, 1, 2, 0));
    }
    let over = wide_constant_material(1, 1, limit + 1);
    assert!(matches!(over.to_bytes(), Err(Error::LimitExceeded { field: Field::Bias, .. })));
    let under = wide_constant_material(1, 1, -limit - 1);
    assert!(matches!(under.to_bytes(), Err(Error::LimitExceeded { field: Field::Bias, .. })));
}

#[test]
fn int8_minus_128_is_rejected() {
    let mut spec = small("w");
    spec.mlp.layers[0].weights_i8[5] = i8::MIN;
    assert!(matches!(
        spec.to_bytes(),
        Err(Error::Malformed { field: Field::WeightInt8, index: 0, value: 5 })
    ));
}

// 2. Requantize corners, against exact i128 round-half-up.
#[test]
fn requantize_corners_match_exact_rounding() {
    for acc in [i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX - 1, i32::MAX] {
        for multiplier in [1 << 30, (1 << 30) + 1, i32::MAX] {
            for shift in 1..=62u32 {
                let rq = Requant { multiplier, shift };
                let num = i128::from(acc) * i128::from(multiplier);
                let den = 1i128 << shift;
                let exact = (num + den / 2).div_euclid(den);
                assert_eq!(
                    i128::from(rq.apply(acc)),
                    exact,
                    "acc {acc} mult {multiplier} shift {shift}"
                );
            }
        }
    }
}

#[test]
fn requant_from_scale_covers_every_valid_shift_exactly() {
    // scale = 2^-k: multiplier 2^30, shift = 7 + 23 + k − 23 … checked against the definition.
    for k in -20i32..=40 {
        let scale = 2f32.powi(-k);
        match Requant::from_scale_bits(scale.to_bits(), 12, 12) {
            Some(rq) => {
                assert_eq!(rq.multiplier, 1 << 30);
                assert_eq!(rq.shift as i32, 30 + k, "scale 2^-{k}");
            }
            None => assert!(!(1..=62).contains(&(30 + k)), "scale 2^-{k} wrongly rejected"),
        }
    }
}

// 3. hardGELU: exhaustive over i16 for every allowed Q-format.
#[test]
fn hard_gelu_is_within_half_an_lsb_everywhere() {
    for f in 1..=14u8 {
        let one = f64::from(1u32 << f);
        for z in i16::MIN..=i16::MAX {
            let x = f64::from(z) / one;
            let exact = if x <= -1.5 {
                0.0
            } else if x >= 1.5 {
                x
            } else {
                x * (x + 1.5) / 3.0
            };
            let got = f64::from(hard_gelu_q(z, f)) / one;
            assert!((got - exact).abs() * one <= 0.5, "f {f} z {z}: {got} vs {exact}");
        }
        // Boundaries: continuous at ±1.5, identity above, zero below, minimum −0.1875.
        let t = 3i32 << (f - 1);
        if t <= i32::from(i16::MAX) {
            assert_eq!(i32::from(hard_gelu_q(t as i16, f)), t);
            assert_eq!(hard_gelu_q((-t) as i16, f), 0);
        }
        let min = (i16::MIN..=i16::MAX).map(|z| hard_gelu_q(z, f)).min().unwrap();
        assert_eq!(f64::from(min), (-0.1875 * one + 0.5).floor(), "f {f}: round half up");
        assert_eq!(hard_gelu_q(i16::MAX, f), i16::MAX, "saturated inputs pass through");
    }
}

// 4. Latents: all-max, all-min, checkerboard, 1 and 8 bits; interpolation weights sum exactly.

#[test]
fn extreme_latent_patterns_decode_like_the_reference() {
    for bits in [1u8, 8] {
        let cfg = FixtureConfig {
            layout: Layout::Ntc { hi_channels: 3, lo_channels: 2, hi_bits: bits, lo_bits: bits },
            ..FixtureConfig::ntc("lat", 13, 24, 20, 2)
        };
        type Pattern = fn(usize, u8) -> u8;
        let patterns: [Pattern; 3] =
            [|_, max| max, |_, _| 0, |i, max| if i % 2 == 0 { max } else { 0 }];
        for pattern in patterns {
            let mut spec = generate(&cfg);
            set_codes(&mut spec, pattern);
            let bytes = spec.to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            let back = m.to_spec().expect("a neural material");
            assert_eq!(back.grids, spec.grids, "codes survive packing at {bits} bits");
            let mut out = [0u8; 2];
            for (x, y, mip) in nmat_tests::texels(&m) {
                m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut out).unwrap();
                assert_eq!(out.to_vec(), reference::decode_u8(&spec, x, y, mip));
            }
        }
    }
}

#[test]
fn bilinear_of_a_constant_grid_is_exactly_the_constant() {
    // If the four weights did not sum to exactly 65536, a constant would drift at some positions.
    for value in [i16::MAX, i16::MIN, 1, -1, 12345] {
        let cfg = FixtureConfig {
            hidden: vec![],
            pe_frequencies: 0,
            lod_input: 0,
            layout: Layout::Nbc { channels: 1, bits_coarse_to_fine: vec![3] },
            input_frac_bits: 14,
            ..FixtureConfig::ntc("const", 14, 37, 23, 1)
        };
        let mut spec = generate(&cfg);
        spec.grids[0].quantization = vec![(value, 0)];
        spec.levels[0].terms.truncate(1);
        let layer = &mut spec.mlp.layers[0];
        layer.inputs = 1;
        layer.weights_i8 = vec![1];
        layer.bias = vec![0];
        layer.out_frac_bits = 14;
        // scale 1 with equal Q-formats: the output is the input feature itself.
        layer.scales = vec![1.0];
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let mut out = [0u16; 1];
        let expected = reference::decode_u16(&spec, 0, 0, 0);
        for (x, y, mip) in nmat_tests::texels(&m) {
            m.decode_texel_u16(x, y, mip, ChannelMask::ALL, &mut out).unwrap();
            assert_eq!(out.to_vec(), expected, "value {value} at ({x},{y}) mip {mip}");
        }
    }
}

// 5. Coordinates and LOD.
#[test]
fn out_of_range_texels_follow_the_address_mode() {
    for mode in [AddressMode::Wrap, AddressMode::Clamp] {
        let mut spec = small("addr");
        spec.address_mode = mode;
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let (w, h) = (i64::from(m.width()), i64::from(m.height()));
        let decode = |x: i64, y: i64, mip: u32| {
            let mut o = [0u8; 3];
            m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut o).unwrap();
            o
        };
        for (x, y) in [
            (-1, 0),
            (w, 3),
            (0, -1),
            (5, h),
            (i64::MIN, i64::MAX),
            (i64::MAX, i64::MIN),
            (-3 * w - 2, 7 * h + 1),
        ] {
            let (ex, ey) = match mode {
                AddressMode::Wrap => (x.rem_euclid(w), y.rem_euclid(h)),
                _ => (x.clamp(0, w - 1), y.clamp(0, h - 1)),
            };
            assert_eq!(decode(x, y, 0), decode(ex, ey, 0), "{mode:?} ({x},{y})");
            assert_eq!(decode(x, y, 0).to_vec(), reference::decode_u8(&spec, x, y, 0));
        }
        let last = m.mip_count() - 1;
        assert_eq!(decode(0, 0, last + 1), decode(0, 0, last), "mip beyond the chain clamps");
        assert_eq!(decode(0, 0, u32::MAX), decode(0, 0, last));
    }
}

#[test]
fn sample_handles_every_odd_coordinate_and_lod() {
    let spec = small("samp");
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let odd = [
        0.0,
        1.0 - f32::EPSILON,
        1.0,
        -0.25,
        1.75,
        1e30,
        -1e30,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MIN_POSITIVE,
    ];
    let lods = [-1.0, 0.0, 0.5, 2.25, 100.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
    let run = |u: f32, v: f32, lod: f32, filter, precision| {
        let mut out = [0f32; 3];
        let req = SampleRequest {
            u,
            v,
            lod,
            filter,
            precision,
            random: [0.3, 0.7, 0.5],
            channels: ChannelMask::ALL,
        };
        m.sample(&req, &mut out).unwrap();
        out
    };
    for filter in [Filter::Nearest, Filter::Bilinear, Filter::Trilinear, Filter::Stochastic] {
        for precision in [Precision::Float, Precision::Integer] {
            for &u in &odd {
                for &lod in &lods {
                    let out = run(u, 0.4, lod, filter, precision);
                    assert!(
                        out.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
                        "{filter:?} u {u} lod {lod}: {out:?}"
                    );
                }
            }
            assert_eq!(
                run(f32::NAN, 0.4, 0.0, filter, precision),
                run(0.0, 0.4, 0.0, filter, precision),
                "NaN u is 0"
            );
            assert_eq!(
                run(0.3, 0.4, f32::NAN, filter, precision),
                run(0.3, 0.4, 0.0, filter, precision),
                "NaN lod is 0"
            );
            assert_eq!(
                run(0.3, 0.4, -5.0, filter, precision),
                run(0.3, 0.4, 0.0, filter, precision),
                "lod below 0 clamps"
            );
            let last = (m.mip_count() - 1) as f32;
            assert_eq!(
                run(0.3, 0.4, 99.0, filter, precision),
                run(0.3, 0.4, last, filter, precision),
                "lod beyond clamps"
            );
            assert_eq!(
                run(1.25, -0.625, 0.0, filter, precision),
                run(0.25, 0.375, 0.0, filter, precision),
                "wrap by whole turns"
            );
        }
    }
}

// 6. Sizes: the largest texture; mip sizes; positional encoding phase at 16k.
#[test]
fn the_largest_texture_decodes_like_the_reference() {
    let spec = largest_material();
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    for mip in 0..15u32 {
        assert_eq!(m.mip_size(mip), ((16384 >> mip).max(1), (16384 >> mip).max(1)));
        let s = i64::from(16384u32 >> mip);
        for (x, y) in [(0, 0), (s - 1, s - 1), (s / 3, s / 2 + 1)] {
            let mut out = [0u8; 2];
            m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut out).unwrap();
            assert_eq!(out.to_vec(), reference::decode_u8(&spec, x, y, mip), "mip {mip} ({x},{y})");
        }
    }
}

#[test]
fn positional_encoding_is_exact_at_16k() {
    for f in 11..=14u8 {
        for k in 0..=(f - 3).min(8) {
            for x in [0u32, 1, 2, 3, 4095, 16380, 16381, 16382, 16383] {
                for phase in 0..2 {
                    let period = 2f64.powi(i32::from(k) + 2);
                    let t =
                        ((f64::from(x) + 0.5) / period + f64::from(phase) * 0.25).rem_euclid(1.0);
                    let exact = (2.0 * t - 1.0).abs();
                    let got = f64::from(triangle_q(x, k, phase, f)) / f64::from(1u32 << f);
                    assert_eq!(got, exact, "f {f} k {k} x {x} phase {phase}");
                }
            }
        }
    }
}

// 7. File values.
#[test]
fn bad_scales_are_rejected_and_zero_scale_is_handled() {
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.5, -0.0, 1e-42, 1e30] {
        let mut spec = small("scale");
        spec.mlp.layers[1].scales[3] = bad;
        match spec.to_bytes() {
            Err(Error::Malformed { field: Field::WeightScale, index: 1, .. }) => {}
            other => panic!("scale {bad}: {other:?}"),
        }
    }
    let mut spec = small("zero");
    let last = spec.mlp.layers.last_mut().unwrap();
    last.scales = vec![0.0; 3];
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let mut out = [9u8; 3];
    m.decode_texel_u8(3, 4, 0, ChannelMask::ALL, &mut out).unwrap();
    assert_eq!(out, [0, 0, 0], "a zero scale makes the channel constant 0");
}

#[test]
fn all_zero_weights_give_the_bias() {
    let mut spec = small("zw");
    for l in &mut spec.mlp.layers {
        l.weights_i8.iter_mut().for_each(|w| *w = 0);
    }
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let (mut a, mut b) = ([0u8; 3], [0u8; 3]);
    m.decode_texel_u8(0, 0, 0, ChannelMask::ALL, &mut a).unwrap();
    m.decode_texel_u8(7, 9, 2, ChannelMask::ALL, &mut b).unwrap();
    assert_eq!(a, b, "output independent of the texel");
    assert_eq!(a.to_vec(), reference::decode_u8(&spec, 0, 0, 0));
}

// 8. Outputs far out of range clamp, never wrap.
#[test]
fn huge_pre_activations_clamp_to_the_code_range() {
    for (bias_sign, expect8, expect16) in [(1i64, 255u8, 65535u16), (-1, 0, 0)] {
        let mut spec = small("clamp");
        let last = spec.mlp.layers.last_mut().unwrap();
        let limit = i64::from(i32::MAX) - i64::from(last.inputs) * 127 * 32768;
        last.bias = vec![(bias_sign * limit) as i32; 3];
        last.scales = vec![1.0; 3];
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let (mut o8, mut o16) = ([0u8; 3], [0u16; 3]);
        m.decode_texel_u8(1, 1, 0, ChannelMask::ALL, &mut o8).unwrap();
        m.decode_texel_u16(1, 1, 0, ChannelMask::ALL, &mut o16).unwrap();
        assert_eq!(o8, [expect8; 3]);
        assert_eq!(o16, [expect16; 3]);
    }
}

#[test]
fn fusion_chain_sums_saturate_instead_of_wrapping() {
    // Three grids at +32767 each sum to 98301 before the i16 saturation of the input (§6.3).
    let cfg = FixtureConfig {
        layout: Layout::Nbc { channels: 1, bits_coarse_to_fine: vec![2, 2, 2] },
        ..FixtureConfig::ntc("sat", 16, 32, 32, 1)
    };
    let mut spec = generate(&cfg);
    for g in &mut spec.grids {
        g.quantization = vec![(i16::MAX, 0)];
    }
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    for (x, y, mip) in nmat_tests::texels(&m) {
        let mut out = [0u8; 1];
        m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut out).unwrap();
        assert_eq!(out.to_vec(), reference::decode_u8(&spec, x, y, mip));
    }
}

#[test]
fn grid_quantization_that_leaves_i16_is_rejected() {
    let mut spec = small("q");
    let bits = spec.grids[0].bits;
    spec.grids[0].quantization[1] = (32000, (1000 / ((1 << bits) - 1)).max(1) as i16 * 10);
    assert!(matches!(
        spec.to_bytes(),
        Err(Error::Malformed { field: Field::LatentQuantization, index: 0, .. })
    ));
}

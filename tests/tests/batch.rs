//! The prepared `Decoder` against the per-texel definition on `Material`: every kernel,
//! every output type, spans, channel subsets, out-of-range coordinates, accumulator extremes.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::AddressMode;
use nmat_core::{Argument, ChannelMask, Container, Decoder, Error, Kernel, Material, TexelAt};
use nmat_tests::generate::{
    FixtureConfig, Layout, Rng, generate, golden_configs, sixteen_grids_in_one_level,
    terms_in_any_order, wide_cells, wide_constant_material,
};
use nmat_tests::{assert_decodes_as_the_reference, fixtures_dir};

fn kernels() -> Vec<Kernel> {
    Kernel::ALL.into_iter().filter(|k| k.is_available()).collect()
}

fn random_mask(r: &mut Rng, m: &Material<'_>) -> ChannelMask {
    let all = (1u32 << m.channel_count()) - 1;
    match r.range(0, 3) {
        0 => ChannelMask::ALL,
        1 => ChannelMask::single(r.range(0, m.channel_count() as i64 - 1) as u32),
        _ => ChannelMask(r.range(1, i64::from(all)) as u16),
    }
}

/// Texel by texel: u8, u16 and float (to the bit) equal the `Material` decoders.
fn assert_texels_agree(m: &Material<'_>, r: &mut Rng, count: usize) {
    for kernel in kernels() {
        let d = Decoder::with_kernel(m, kernel).unwrap();
        for _ in 0..count {
            let mip = r.range(0, i64::from(m.mip_count())) as u32; // one past the chain clamps
            let (x, y) =
                (r.range(-40, i64::from(m.width()) + 40), r.range(-40, i64::from(m.height()) + 40));
            let mask = random_mask(r, m);
            let (mut a8, mut b8) = ([0u8; 16], [0u8; 16]);
            let (mut a16, mut b16) = ([0u16; 16], [0u16; 16]);
            let (mut af, mut bf) = ([0f32; 16], [0f32; 16]);
            let n = m.decode_texel_u8(x, y, mip, mask, &mut a8).unwrap();
            assert_eq!(d.decode_texel_u8(m, x, y, mip, mask, &mut b8).unwrap(), n);
            m.decode_texel_u16(x, y, mip, mask, &mut a16).unwrap();
            d.decode_texel_u16(m, x, y, mip, mask, &mut b16).unwrap();
            m.decode_texel(x, y, mip, mask, &mut af).unwrap();
            d.decode_texel(m, x, y, mip, mask, &mut bf).unwrap();
            let at = format!("{kernel:?} texel ({x}, {y}) mip {mip} mask {:#x}", mask.0);
            assert_eq!(a8[..n], b8[..n], "u8 {at}");
            assert_eq!(a16[..n], b16[..n], "u16 {at}");
            let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&af[..n]), bits(&bf[..n]), "float {at}");
        }
    }
}

#[test]
fn every_kernel_matches_the_per_texel_definition_on_every_fixture() {
    let mut r = Rng::new(77);
    for cfg in golden_configs() {
        let bytes = generate(&cfg).to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        assert_texels_agree(&m, &mut r, 300);
    }
}

#[test]
fn every_kernel_survives_the_accumulator_bound() {
    let limit = i32::MAX - 128 * 127 * 32768;
    let mut r = Rng::new(78);
    for (input, weight, bias) in [
        (i16::MAX, 127, limit),
        (i16::MIN, 127, -limit),
        (i16::MIN, -127, limit),
        (i16::MAX, -127, -limit),
    ] {
        let bytes = wide_constant_material(input, weight, bias).to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        assert_texels_agree(&m, &mut r, 20);
    }
}

#[test]
fn spans_equal_texel_by_texel_decodes() {
    let mut r = Rng::new(79);
    for cfg in golden_configs() {
        let bytes = generate(&cfg).to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        assert_spans_agree(&m, &mut r, 20);
    }
    // JPEG materials: the committed one and one of four maps and four mips.
    let committed = committed_jpeg();
    let four_maps = nmat_tests::generate_jpeg::DcJpegMaterial::new(2).spec.to_bytes().unwrap();
    for bytes in [committed, four_maps] {
        assert_spans_agree(&Container::parse(&bytes).unwrap(), &mut r, 20);
    }
}

/// The committed JPEG material (tests/fixtures/jpeg/README.md).
fn committed_jpeg() -> Vec<u8> {
    std::fs::read(fixtures_dir().join("jpeg/pattern_420_37x21.nmat")).unwrap()
}

/// Spans of every kernel, u8, u16 and float, equal the texel-by-texel `Material` decodes and
/// say how many values they wrote: `spans` spans of 0–70 texels each, some starting or ending
/// outside the mip.
fn assert_spans_agree(m: &Material<'_>, r: &mut Rng, spans: usize) {
    for kernel in kernels() {
        let d = Decoder::with_kernel(m, kernel).unwrap();
        for _ in 0..spans {
            let mip = r.range(0, i64::from(m.mip_count()) - 1) as u32;
            let (x0, y, count) = (r.range(-20, 90), r.range(-20, 90), r.range(0, 70) as usize);
            let mask = random_mask(r, m);
            let n = m.required_len(mask).unwrap();
            let mut span8 = vec![0u8; count * n];
            let mut span16 = vec![0u16; count * n];
            let mut spanf = vec![0f32; count * n];
            let written = (
                d.decode_span_u8(m, x0, y, mip, count, mask, &mut span8).unwrap(),
                d.decode_span_u16(m, x0, y, mip, count, mask, &mut span16).unwrap(),
                d.decode_span_f32(m, x0, y, mip, count, mask, &mut spanf).unwrap(),
            );
            assert_eq!(written, (count * n, count * n, count * n), "{kernel:?}: values written");
            for i in 0..count {
                let (mut t8, mut t16, mut tf) = ([0u8; 16], [0u16; 16], [0f32; 16]);
                m.decode_texel_u8(x0 + i as i64, y, mip, mask, &mut t8).unwrap();
                m.decode_texel_u16(x0 + i as i64, y, mip, mask, &mut t16).unwrap();
                m.decode_texel(x0 + i as i64, y, mip, mask, &mut tf).unwrap();
                let at = format!("{kernel:?} span at ({x0}, {y}) mip {mip}, texel {i}");
                assert_eq!(span8[i * n..(i + 1) * n], t8[..n], "u8 {at}");
                assert_eq!(span16[i * n..(i + 1) * n], t16[..n], "u16 {at}");
                assert_eq!(spanf[i * n..(i + 1) * n], tf[..n], "float {at}");
            }
        }
    }
}

/// A level whose terms come in an order the NTC and NBC layouts never write
/// (`terms_in_any_order`: two `Nearest4` terms, the second on a grid read bilinearly before
/// it, a chain of eight fusing that grid with another): the per-texel definition equals the
/// independent reference decoder on every texel of every mip, and every kernel's texels and spans
/// equal it.
#[test]
fn a_level_of_terms_in_any_order_decodes_as_the_reference() {
    assert_every_decoder_agrees_with_the_reference(&terms_in_any_order(), 81);
}

/// Cells wider than the kernels' 64-bit window reads (`wide_cells`: 128, 60 and 64 bits a
/// cell), which every kernel reads latent by latent: the golden fixtures' cells are at most 48
/// bits wide. The per-texel definition equals the reference decoder on every texel, and every
/// kernel's texels and spans equal it.
#[test]
fn cells_wider_than_a_window_read_decode_as_the_reference() {
    assert_every_decoder_agrees_with_the_reference(&wide_cells(), 82);
}

/// A level reading all 16 grids (`sixteen_grids_in_one_level`: two chains of 8 and two nearest
/// terms, 18 grids-and-modes that a span steps along its row): the per-texel definition equals
/// the reference decoder on every texel, and every kernel's texels and spans equal it.
#[test]
fn a_level_of_sixteen_grids_decodes_as_the_reference() {
    assert_every_decoder_agrees_with_the_reference(&sixteen_grids_in_one_level(), 83);
}

/// Layers narrower than the golden fixtures' (8 wide at least): hidden layers of 3, 1 and 5,
/// whose weights the kernels pack by pairs of inputs padded to 16 rows, with an odd last pair.
/// The per-texel definition equals the reference decoder on every texel, and every kernel's
/// texels and spans equal it.
#[test]
fn narrow_layers_decode_as_the_reference() {
    let cfg =
        FixtureConfig { hidden: vec![3, 1, 5], ..FixtureConfig::ntc("narrow", 19, 29, 23, 3) };
    assert_every_decoder_agrees_with_the_reference(&cfg, 84);
}

/// `cfg`'s material through the reference decoder (every texel of every mip, the per-texel
/// definition), then every kernel's texels and spans at random against the per-texel definition.
fn assert_every_decoder_agrees_with_the_reference(cfg: &FixtureConfig, seed: u64) {
    let spec = generate(cfg);
    assert_decodes_as_the_reference(&spec);
    let bytes = spec.to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    let mut r = Rng::new(seed);
    assert_texels_agree(&m, &mut r, 300);
    assert_spans_agree(&m, &mut r, 40);
}

/// Long spans, where the first layer starts from the span's sums over the positional encoding
/// and LOD (`PeriodicSums`): every tabulated period of x (0 to 4 frequencies) and one beyond it
/// (5), latent features ending mid-pair (odd widths) or not, mip widths that the period does not
/// divide, wrap and clamp, spans starting outside the mip; and a first nearest term of one
/// channel, whose 4 features the texels of a cell share (`shared_pairs`), followed by features
/// that change from texel to texel.
#[test]
fn long_spans_equal_texel_by_texel_decodes_for_every_period() {
    let mut r = Rng::new(80);
    let layouts = [
        Layout::Nbc { channels: 5, bits_coarse_to_fine: vec![4, 2] },
        Layout::Ntc { hi_channels: 3, lo_channels: 3, hi_bits: 4, lo_bits: 3 },
        Layout::Nbc { channels: 4, bits_coarse_to_fine: vec![8, 4, 2, 1] },
        Layout::Ntc { hi_channels: 1, lo_channels: 2, hi_bits: 3, lo_bits: 5 },
    ];
    for frequencies in 0..=5u8 {
        for (l, layout) in layouts.iter().enumerate() {
            let cfg = FixtureConfig {
                layout: layout.clone(),
                pe_frequencies: frequencies,
                // mip / 16, none, mip / 2, mip / 16.
                lod_input: [1, 0, 4, 1][l],
                address_mode: if l == 2 { AddressMode::Clamp } else { AddressMode::Wrap },
                ..FixtureConfig::ntc("periodic", 100 + u64::from(frequencies), 72, 20, 3)
            };
            let bytes = generate(&cfg).to_bytes().unwrap();
            let m = Container::parse(&bytes).unwrap();
            for kernel in kernels() {
                let d = Decoder::with_kernel(&m, kernel).unwrap();
                for _ in 0..6 {
                    let mip = r.range(0, 1) as u32;
                    let (x0, y, count) = (r.range(-50, 50), r.range(-5, 25), r.range(60, 230));
                    let count = count as usize;
                    let mask = random_mask(&mut r, &m);
                    let n = m.required_len(mask).unwrap();
                    let mut span = vec![0u8; count * n];
                    d.decode_span_u8(&m, x0, y, mip, count, mask, &mut span).unwrap();
                    for i in 0..count {
                        let mut t = [0u8; 16];
                        m.decode_texel_u8(x0 + i as i64, y, mip, mask, &mut t).unwrap();
                        let what =
                            format!("{kernel:?} K={frequencies} layout {l} x={}", x0 + i as i64);
                        assert_eq!(span[i * n..(i + 1) * n], t[..n], "{what}");
                    }
                }
            }
        }
    }
}

/// Scattered texels in one call (`decode_texels_*`): each texel's codes equal its own
/// `decode_texel_*` call, whatever the count (groups of 4 and a short tail), the mips (one past
/// the chain clamps), coordinates outside the mip, the channels; on every kernel and codec.
#[test]
fn scattered_texels_in_one_call_equal_texel_by_texel_decodes() {
    let jpeg = committed_jpeg();
    let mut files: Vec<Vec<u8>> =
        golden_configs().iter().map(|cfg| generate(cfg).to_bytes().unwrap()).collect();
    files.push(jpeg);
    files.push(nmat_tests::generate_jpeg::DcJpegMaterial::new(9).spec.to_bytes().unwrap());
    let mut r = Rng::new(81);
    for (f, bytes) in files.iter().enumerate() {
        let m = Container::parse(bytes).unwrap();
        for kernel in kernels() {
            let d = Decoder::with_kernel(&m, kernel).unwrap();
            for count in [0, 1, 3, 4, 5, 9, 37] {
                let texels: Vec<TexelAt> = (0..count)
                    .map(|_| TexelAt {
                        x: r.range(-40, i64::from(m.width()) + 40),
                        y: r.range(-40, i64::from(m.height()) + 40),
                        mip: r.range(0, i64::from(m.mip_count())) as u32,
                    })
                    .collect();
                let mask = random_mask(&mut r, &m);
                let n = m.required_len(mask).unwrap();
                let (mut u8s, mut u16s) = (vec![0u8; count * n], vec![0u16; count * n]);
                assert_eq!(d.decode_texels_u8(&m, &texels, mask, &mut u8s).unwrap(), count * n);
                assert_eq!(d.decode_texels_u16(&m, &texels, mask, &mut u16s).unwrap(), count * n);
                for (i, t) in texels.iter().enumerate() {
                    let (mut a8, mut a16) = ([0u8; 16], [0u16; 16]);
                    d.decode_texel_u8(&m, t.x, t.y, t.mip, mask, &mut a8).unwrap();
                    m.decode_texel_u16(t.x, t.y, t.mip, mask, &mut a16).unwrap();
                    let at = format!("file {f} {kernel:?} {count} texels, #{i} {t:?}");
                    assert_eq!(u8s[i * n..(i + 1) * n], a8[..n], "u8 {at}");
                    assert_eq!(u16s[i * n..(i + 1) * n], a16[..n], "u16 {at}");
                }
            }
        }
    }
}

#[test]
fn a_decoder_refuses_another_material_and_short_outputs() {
    let (a, b) = (
        generate(&golden_configs()[0]).to_bytes().unwrap(),
        generate(&golden_configs()[1]).to_bytes().unwrap(),
    );
    let (ma, mb) = (Container::parse(&a).unwrap(), Container::parse(&b).unwrap());
    let d = Decoder::new(&ma);
    let mut out = [0u8; 64];
    let err = d.decode_texel_u8(&mb, 0, 0, 0, ChannelMask::ALL, &mut out).unwrap_err();
    assert!(matches!(err, Error::BadArgument { argument: Argument::Material, .. }), "{err}");
    let err = d.decode_span_u8(&ma, 0, 0, 0, 22, ChannelMask::ALL, &mut out).unwrap_err();
    assert!(
        matches!(err, Error::BadArgument { argument: Argument::Output, value: 64, limit: 66 }),
        "{err}"
    );
    let err = d.decode_span_u8(&ma, 0, 0, 0, usize::MAX, ChannelMask::ALL, &mut out).unwrap_err();
    assert!(matches!(err, Error::BadArgument { argument: Argument::Output, .. }), "{err}");
    let texels = [TexelAt::default(); 22];
    let err = d.decode_texels_u8(&ma, &texels, ChannelMask::ALL, &mut out).unwrap_err();
    assert!(
        matches!(err, Error::BadArgument { argument: Argument::Output, value: 64, limit: 66 }),
        "{err}"
    );
    let err = d.decode_texels_u8(&mb, &texels[..1], ChannelMask::ALL, &mut out).unwrap_err();
    assert!(matches!(err, Error::BadArgument { argument: Argument::Material, .. }), "{err}");
    let err = d.decode_texel_u8(&ma, 0, 0, 0, ChannelMask(1 << 5), &mut out).unwrap_err();
    assert!(matches!(err, Error::BadArgument { argument: Argument::Channels, .. }), "{err}");
}

#[test]
fn kernel_choice_is_reported_and_unavailable_kernels_are_refused() {
    let bytes = generate(&golden_configs()[0]).to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    assert_eq!(Decoder::new(&m).kernel(), Kernel::best());
    for kernel in Kernel::ALL {
        match Decoder::with_kernel(&m, kernel) {
            Ok(d) => assert!(kernel.is_available() && d.kernel() == kernel),
            Err(e) => assert!(
                !kernel.is_available()
                    && matches!(e, Error::BadArgument { argument: Argument::Kernel, .. })
            ),
        }
    }
}

#[test]
fn decoder_samples_equal_material_samples() {
    use nmat_core::{Filter, Precision, SampleRequest};
    let mut r = Rng::new(80);
    for cfg in golden_configs() {
        let bytes = generate(&cfg).to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        for kernel in kernels() {
            let d = Decoder::with_kernel(&m, kernel).unwrap();
            for _ in 0..60 {
                let u = |r: &mut Rng| r.range(-1500, 2500) as f32 / 1000.0;
                let req = SampleRequest {
                    u: u(&mut r),
                    v: u(&mut r),
                    lod: r.range(-10, 120) as f32 / 10.0,
                    filter: [
                        Filter::Nearest,
                        Filter::Bilinear,
                        Filter::Trilinear,
                        Filter::Stochastic,
                    ][r.range(0, 3) as usize],
                    precision: if r.range(0, 1) == 0 {
                        Precision::Integer
                    } else {
                        Precision::Float
                    },
                    random: [r.unit() as f32, r.unit() as f32, r.unit() as f32],
                    channels: random_mask(&mut r, &m),
                };
                let (mut a, mut b) = ([0f32; 16], [0f32; 16]);
                let n = m.sample(&req, &mut a).unwrap();
                assert_eq!(d.sample(&m, &req, &mut b).unwrap(), n);
                let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&a[..n]), bits(&b[..n]), "{kernel:?} {req:?}");
            }
        }
    }
}

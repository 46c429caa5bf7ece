//! The decode API: channel subsets, filters, bad arguments, threads.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{
    Argument, ChannelMask, Container, Error, Filter, Material, Precision, SampleRequest,
};
use nmat_tests::generate::{FixtureConfig, Rng, generate, golden_configs};

fn fixture(i: usize) -> Vec<u8> {
    generate(&golden_configs()[i]).to_bytes().unwrap()
}

#[test]
fn channel_subsets_equal_the_same_channels_of_a_full_decode() {
    let bytes = fixture(1); // 10 channels
    let m = Container::parse(&bytes).unwrap();
    let mut r = Rng::new(5);
    for _ in 0..200 {
        let (x, y, mip) = (r.range(-50, 150), r.range(-50, 150), r.range(0, 8) as u32);
        let mask = r.range(1, (1 << 10) - 1) as u16;
        let (mut full8, mut sub8) = ([0u8; 16], [0u8; 16]);
        let (mut fullf, mut subf) = ([0f32; 16], [0f32; 16]);
        m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut full8).unwrap();
        m.decode_texel(x, y, mip, ChannelMask::ALL, &mut fullf).unwrap();
        let n = m.decode_texel_u8(x, y, mip, ChannelMask(mask), &mut sub8).unwrap();
        m.decode_texel(x, y, mip, ChannelMask(mask), &mut subf).unwrap();
        assert_eq!(n, mask.count_ones() as usize);
        let picked: Vec<usize> = (0..10).filter(|c| mask & (1 << c) != 0).collect();
        for (k, &c) in picked.iter().enumerate() {
            assert_eq!(sub8[k], full8[c]);
            assert_eq!(subf[k], fullf[c]);
        }
    }
}

#[test]
fn float_values_are_mapped_into_each_channel_range() {
    let bytes = fixture(1);
    let m = Container::parse(&bytes).unwrap();
    let (mut unit, mut val) = ([0f32; 16], [0f32; 16]);
    m.decode_texel_unit(4, 4, 0, ChannelMask::ALL, &mut unit).unwrap();
    m.decode_texel(4, 4, 0, ChannelMask::ALL, &mut val).unwrap();
    for (c, ch) in m.channels().iter().enumerate() {
        let expected = ch.range_min + unit[c] * (ch.range_max - ch.range_min);
        assert!((val[c] - expected).abs() < 1e-6, "{}: {} vs {expected}", ch.name, val[c]);
        assert!((ch.range_min..=ch.range_max).contains(&val[c]));
    }
    assert!(
        m.channels().iter().any(|c| c.range_min < 0.0),
        "fixture has a signed (normal) channel"
    );
}

#[test]
fn bad_arguments_are_typed_errors() {
    let bytes = fixture(0); // 3 channels
    let m = Container::parse(&bytes).unwrap();
    let mut out = [0u8; 3];
    for mask in [0u16, 0b1000, 0x8001] {
        assert!(matches!(
            m.decode_texel_u8(0, 0, 0, ChannelMask(mask), &mut out),
            Err(Error::BadArgument { argument: Argument::Channels, .. })
        ));
    }
    let mut short = [0u8; 2];
    assert_eq!(
        m.decode_texel_u8(0, 0, 0, ChannelMask::ALL, &mut short),
        Err(Error::BadArgument { argument: Argument::Output, value: 2, limit: 3 })
    );
    let mut shortf = [0f32; 1];
    let req = SampleRequest {
        u: 0.5,
        v: 0.5,
        lod: 0.0,
        filter: Filter::Bilinear,
        precision: Precision::Float,
        random: [0.0; 3],
        channels: ChannelMask::ALL,
    };
    assert!(matches!(
        m.sample(&req, &mut shortf),
        Err(Error::BadArgument { argument: Argument::Output, .. })
    ));
    assert_eq!(m.required_len(ChannelMask(0b101)), Ok(2));
    let msg = m.decode_texel_u8(0, 0, 0, ChannelMask(0), &mut out).unwrap_err().to_string();
    assert!(msg.contains("Channels"), "{msg}");
}

fn sample(
    m: &Material<'_>,
    u: f32,
    v: f32,
    lod: f32,
    filter: Filter,
    precision: Precision,
    random: [f32; 3],
) -> Vec<f32> {
    let mut out = [0f32; 16];
    let n = m
        .sample(
            &SampleRequest { u, v, lod, filter, precision, random, channels: ChannelMask::ALL },
            &mut out,
        )
        .unwrap();
    out[..n].to_vec()
}

#[test]
fn filters_agree_with_texel_decodes_where_they_must() {
    let bytes = fixture(0);
    let m = Container::parse(&bytes).unwrap();
    let (w, h) = (m.width() as f32, m.height() as f32);
    for precision in [Precision::Float, Precision::Integer] {
        for (x, y) in [(0u32, 0u32), (5, 9), (63, 63)] {
            // At a texel centre, nearest and bilinear are that texel.
            let (u, v) = ((x as f32 + 0.5) / w, (y as f32 + 0.5) / h);
            let mut texel = [0f32; 3];
            match precision {
                Precision::Float => {
                    m.decode_texel(i64::from(x), i64::from(y), 0, ChannelMask::ALL, &mut texel)
                        .unwrap();
                }
                _ => {
                    let mut c = [0u8; 3];
                    m.decode_texel_u8(i64::from(x), i64::from(y), 0, ChannelMask::ALL, &mut c)
                        .unwrap();
                    texel = c.map(|c| f32::from(c) / 255.0);
                }
            }
            for filter in [Filter::Nearest, Filter::Bilinear, Filter::Stochastic] {
                let got = sample(&m, u, v, 0.0, filter, precision, [0.99, 0.99, 0.99]);
                for (a, b) in got.iter().zip(texel) {
                    assert!(
                        (a - b).abs() < 1e-6,
                        "{filter:?} {precision:?} at ({x},{y}): {a} vs {b}"
                    );
                }
            }
            // Trilinear at an integer LOD is bilinear at that mip.
            assert_eq!(
                sample(&m, u, v, 1.0, Filter::Trilinear, precision, [0.0; 3]),
                sample(&m, u, v, 1.0, Filter::Bilinear, precision, [0.0; 3])
            );
        }
    }
}

#[test]
fn stochastic_filtering_averages_to_trilinear() {
    let bytes = fixture(0);
    let m = Container::parse(&bytes).unwrap();
    let (u, v, lod) = (0.37, 0.61, 1.3);
    let target = sample(&m, u, v, lod, Filter::Trilinear, Precision::Float, [0.0; 3]);
    let mut r = Rng::new(17);
    let trials = 4000;
    let mut mean = vec![0f64; target.len()];
    for _ in 0..trials {
        let rnd = [r.unit() as f32, r.unit() as f32, r.unit() as f32];
        for (acc, v) in
            mean.iter_mut().zip(sample(&m, u, v, lod, Filter::Stochastic, Precision::Float, rnd))
        {
            *acc += f64::from(v) / f64::from(trials);
        }
    }
    for (a, b) in mean.iter().zip(&target) {
        // 8 texels with values spread over ~0.3: the standard error of 4000 draws is ~0.003.
        assert!((a - f64::from(*b)).abs() < 0.015, "{a} vs {b}");
    }
    // And it is a selection, not a blend: every draw equals one of the 8 footprint texels.
    let one = sample(&m, u, v, lod, Filter::Stochastic, Precision::Float, [0.1, 0.9, 0.2]);
    assert_ne!(one, target);
}

/// Stochastic filtering picks exactly the texel its definition names (FORMAT.md §6.9): mip
/// `floor(lod) + 1` if `r2 < lod − floor(lod)`, texel `x0 + 1` if `r0 < fx`, `y0 + 1` if
/// `r1 < fy` — at the edges too: `r` equal to the fraction, 0 at a texel's centre and an
/// integer LOD (where every `r` picks that texel), and 1.
#[test]
fn stochastic_filtering_picks_the_texel_its_definition_names() {
    let bytes = fixture(0); // 64×64, 7 mips
    let m = Container::parse(&bytes).unwrap();
    let last = m.mip_count() - 1;
    // (u, v, lod): fractions 0.25, 0.5 and 0.5 at mip 1 (exact in f32), then a texel's centre
    // at mip 2 and LOD 2.
    let points = [(10.75 / 32.0, 8.0 / 32.0, 1.5f32), (5.5 / 16.0, 9.5 / 16.0, 2.0)];
    let edges = [0.0, 0.2, 0.25, 0.5, 0.7, 1.0f32];
    for (u, v, lod) in points {
        let k = edges.len();
        for i in 0..k.pow(3) {
            let (r0, r1, r2) = (edges[i / (k * k)], edges[i / k % k], edges[i % k]);
            let low = f64::from(lod).floor();
            let mip =
                if f64::from(r2) < f64::from(lod) - low { low as u32 + 1 } else { low as u32 };
            let mip = mip.min(last);
            let (w, h) = m.mip_size(mip);
            let pick = |c: f32, size: u32, r: f32| {
                let p = f64::from(c) * f64::from(size) - 0.5;
                p.floor() as i64 + i64::from(f64::from(r) < p - p.floor())
            };
            let (x, y) = (pick(u, w, r0), pick(v, h, r1));
            let mut want = [0f32; 3];
            m.decode_texel_unit(x, y, mip, ChannelMask::ALL, &mut want).unwrap();
            let got = sample(&m, u, v, lod, Filter::Stochastic, Precision::Float, [r0, r1, r2]);
            let at =
                format!("({u}, {v}) LOD {lod}, r = ({r0}, {r1}, {r2}): texel ({x}, {y}) mip {mip}");
            for (a, b) in got.iter().zip(want) {
                assert!((a - b).abs() < 1e-6, "{at}: {got:?} vs {want:?}");
            }
        }
    }
}

/// A sample of some channels equals the same channels of a sample of all of them, for every
/// filter: each channel is mapped to its own range (the fixture's normal channels are signed),
/// as a texel decode maps it.
#[test]
fn samples_map_each_channel_to_its_range_and_subsets_equal_a_full_sample() {
    let bytes = fixture(1); // 10 channels
    let m = Container::parse(&bytes).unwrap();
    let (w, h) = (m.width() as f32, m.height() as f32);
    for (x, y) in [(0, 0), (7, 3), (40, 21)] {
        let (u, v) = ((x as f32 + 0.5) / w, (y as f32 + 0.5) / h);
        let got = sample(&m, u, v, 0.0, Filter::Nearest, Precision::Float, [0.0; 3]);
        let mut want = [0f32; 10];
        m.decode_texel(x, y, 0, ChannelMask::ALL, &mut want).unwrap();
        for (c, (a, b)) in got.iter().zip(want).enumerate() {
            assert!((a - b).abs() < 1e-6, "texel ({x}, {y}) channel {c}: {a} vs {b}");
        }
    }
    let mut r = Rng::new(6);
    for filter in [Filter::Nearest, Filter::Bilinear, Filter::Trilinear, Filter::Stochastic] {
        for _ in 0..40 {
            let (u, v, lod) = (r.unit() as f32, r.unit() as f32, (r.unit() * 4.0) as f32);
            let random = [r.unit() as f32, r.unit() as f32, r.unit() as f32];
            let mask = r.range(1, (1 << 10) - 1) as u16;
            let full = sample(&m, u, v, lod, filter, Precision::Float, random);
            let mut sub = [0f32; 16];
            let req = SampleRequest {
                u,
                v,
                lod,
                filter,
                precision: Precision::Float,
                random,
                channels: ChannelMask(mask),
            };
            let n = m.sample(&req, &mut sub).unwrap();
            let picked: Vec<f32> =
                (0..10).filter(|c| mask & (1 << c) != 0).map(|c| full[c]).collect();
            assert_eq!(sub[..n], picked[..], "{filter:?} mask {mask:#x} at ({u}, {v}) LOD {lod}");
        }
    }
}

#[test]
fn a_material_is_shared_across_threads() {
    fn assert_sync<T: Sync + Send>(_: &T) {}
    let bytes = generate(&FixtureConfig::ntc("threads", 9, 32, 32, 4)).to_bytes().unwrap();
    let m = Container::parse(&bytes).unwrap();
    assert_sync(&m);
    let single = nmat_tests::decode_all_u8(&m);
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..4).map(|_| s.spawn(|| nmat_tests::decode_all_u8(&m))).collect();
        for h in handles {
            assert_eq!(h.join().unwrap(), single);
        }
    });
}

#[test]
fn decode_cost_counts_the_texels_and_the_networks_multiply_adds() {
    // ntc_rgb_64: 64×64, 7 mips, MLP 49→64→64→3 (tests/fixtures/README.md).
    let bytes = fixture(0);
    let m = Container::parse(&bytes).unwrap();
    let per_texel = 49 * 64 + 64 * 64 + 64 * 3;
    let cost = m.decode_cost(0);
    assert_eq!((cost.texels, cost.macs), (4096, 4096 * per_texel));
    assert_eq!(m.decode_cost(3).texels, 64);
    assert_eq!(m.decode_cost(3).macs, 64 * per_texel);
    // A mip beyond the chain is clamped to the last one (1×1), like `mip_size`.
    assert_eq!(m.decode_cost(99).texels, 1);
}

/// `Decoder::decode_region_u8` refuses what it cannot do, each by name with the value and the
/// limit, and writes nothing: a mip past the chain, a rectangle past the mip on either axis
/// alone (the axis past it is the one reported; x where both are), one whose end overflows u32,
/// a row pitch shorter than a row or so long that the rows overflow memory, an output too short
/// for the last row; for a neural and a JPEG material alike.
#[test]
fn regions_the_mip_or_the_output_cannot_hold_are_refused_by_name() {
    use nmat_core::Decoder;
    let jpeg = nmat_tests::generate_jpeg::DcJpegMaterial::new(1).spec.to_bytes().unwrap();
    for bytes in [fixture(0), jpeg] {
        let m = Container::parse(&bytes).unwrap();
        let d = Decoder::new(&m);
        let (w, h) = m.mip_size(0);
        let n = m.channel_count();
        let mut out = vec![9u8; (w * h) as usize * n];
        let mut region = |mip, rect, pitch| {
            d.decode_region_u8(&m, mip, rect, ChannelMask::ALL, &mut out, pitch).unwrap_err()
        };
        let bad = |argument, value: u64, limit: u64| Error::BadArgument { argument, value, limit };
        let mips = m.mip_count();
        assert_eq!(region(mips, (0, 0, 1, 1), 0), bad(Argument::Mip, mips.into(), mips.into()));
        let x_past = (w - 4, 0, 5, 1);
        assert_eq!(region(0, x_past, 0), bad(Argument::Region, (w + 1).into(), w.into()));
        let y_past = (0, h - 2, 1, 3);
        assert_eq!(region(0, y_past, 0), bad(Argument::Region, (h + 1).into(), h.into()));
        let y_past_full_width = (0, h - 2, w, 3);
        let y_error = bad(Argument::Region, (h + 1).into(), h.into());
        assert_eq!(region(0, y_past_full_width, 0), y_error);
        let both = (1, 1, w, h);
        assert_eq!(region(0, both, 0), bad(Argument::Region, (w + 1).into(), w.into()));
        let end = u64::from(u32::MAX) + 2;
        assert_eq!(region(0, (u32::MAX, 0, 2, 1), 0), bad(Argument::Region, end, w.into()));
        let row = 3 * n as u64;
        assert_eq!(region(0, (0, 0, 3, 2), 3 * n - 1), bad(Argument::RowPitch, row - 1, row));
        let huge = usize::MAX / 2;
        let overflow = bad(Argument::RowPitch, huge as u64, (usize::MAX / 3) as u64);
        assert_eq!(region(0, (0, 0, 3, 3), huge), overflow);
        // Rows 3n + 7 codes apart: the third row ends at 2 · (3n + 7) + 3n.
        let pitch = 3 * n + 7;
        let needed = 2 * pitch + 3 * n;
        let mut short = vec![9u8; needed - 1];
        let got = d.decode_region_u8(&m, 0, (0, 0, 3, 3), ChannelMask::ALL, &mut short, pitch);
        assert_eq!(got, Err(bad(Argument::Output, needed as u64 - 1, needed as u64)));
        assert!(out.iter().chain(&short).all(|&v| v == 9), "a refused region writes nothing");
        // At the limits themselves: the last texel, the whole mip, a pitch of one row.
        assert_eq!(
            d.decode_region_u8(&m, 0, (w - 1, h - 1, 1, 1), ChannelMask::ALL, &mut out, 0),
            Ok(n)
        );
        let whole = (0, 0, w, h);
        assert_eq!(
            d.decode_region_u8(&m, 0, whole, ChannelMask::ALL, &mut out, w as usize * n),
            Ok(w as usize * n)
        );
    }
}

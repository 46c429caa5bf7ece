//! Golden fixtures: committed `.nmat` files rebuilt byte for byte by the generator, their integer
//! decodes pinned by hash, and every decoded value checked against the independent reference
//! decoder (`nmat_tests::reference`). Set `NMAT_BLESS=1` to rewrite the fixtures and hashes after
//! an intended format or decoder change (and say why in the commit).

use nmat_core::{ChannelMask, Container};
use nmat_tests::generate::{generate, golden_configs};
use nmat_tests::{
    decode_all_u8, decode_all_u16, fixtures_dir, fnv1a, int_vs_float, reference, texels,
};
use std::collections::BTreeMap;
use std::fmt::Write as _;

fn bless() -> bool {
    std::env::var_os("NMAT_BLESS").is_some_and(|v| v == "1")
}

fn read_hashes() -> BTreeMap<String, String> {
    let text = std::fs::read_to_string(fixtures_dir().join("golden.txt")).unwrap_or_default();
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .filter_map(|l| l.split_once(' ').map(|(n, rest)| (n.to_string(), rest.trim().to_string())))
        .collect()
}

#[test]
fn fixtures_are_reproducible_and_decode_to_their_golden_hashes() {
    let hashes = read_hashes();
    let mut blessed =
        String::from("# name  fnv1a64(u8 codes)  fnv1a64(u16 codes)  file bytes — see README.md\n");
    for cfg in golden_configs() {
        let bytes = generate(&cfg).to_bytes().expect("generator makes valid specs");
        let path = fixtures_dir().join(format!("{}.nmat", cfg.name));
        if bless() {
            std::fs::write(&path, &bytes).unwrap();
        }
        let committed = std::fs::read(&path)
            .unwrap_or_else(|e| panic!("{}: {e} (run with NMAT_BLESS=1)", path.display()));
        assert!(
            committed == bytes,
            "{}: the generator or writer no longer reproduces the committed file",
            cfg.name
        );
        let m = Container::parse(&committed).unwrap();
        let line = format!(
            "{:016x} {:016x} {}",
            fnv1a(decode_all_u8(&m)),
            fnv1a(decode_all_u16(&m)),
            committed.len()
        );
        writeln!(blessed, "{} {line}", cfg.name).unwrap();
        if !bless() {
            assert_eq!(hashes.get(cfg.name), Some(&line), "{}: integer decode changed", cfg.name);
        }
    }
    if bless() {
        std::fs::write(fixtures_dir().join("golden.txt"), blessed).unwrap();
    }
}

#[test]
fn integer_decoder_matches_the_reference_on_every_texel() {
    for cfg in golden_configs() {
        let spec = generate(&cfg);
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let n = m.channel_count();
        let (mut c8, mut c16) = ([0u8; 16], [0u16; 16]);
        for (x, y, mip) in texels(&m) {
            m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut c8).unwrap();
            m.decode_texel_u16(x, y, mip, ChannelMask::ALL, &mut c16).unwrap();
            assert_eq!(
                &c8[..n],
                reference::decode_u8(&spec, x, y, mip),
                "{} u8 at ({x},{y}) mip {mip}",
                cfg.name
            );
            assert_eq!(
                &c16[..n],
                reference::decode_u16(&spec, x, y, mip),
                "{} u16 at ({x},{y}) mip {mip}",
                cfg.name
            );
        }
    }
}

#[test]
fn float_decoder_matches_the_f64_reference() {
    for cfg in golden_configs() {
        let spec = generate(&cfg);
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let n = m.channel_count();
        let mut worst = 0f64;
        let mut out = [0f32; 16];
        for (x, y, mip) in texels(&m) {
            m.decode_texel_unit(x, y, mip, ChannelMask::ALL, &mut out).unwrap();
            for (a, b) in out[..n].iter().zip(reference::decode_unit_f64(&spec, x, y, mip)) {
                worst = worst.max((f64::from(*a) - b).abs());
            }
        }
        // f32 against f64 on ~100-term dot products: a few ulps of the activations, far below a code.
        assert!(worst < 1e-4, "{}: float path is {worst} away from the f64 reference", cfg.name);
    }
}

#[test]
fn integer_decoder_is_within_one_code_of_the_float_decoder() {
    let (mut total, mut sum) = (0u64, 0f64);
    for cfg in golden_configs() {
        let bytes = generate(&cfg).to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let a = int_vs_float(&m);
        eprintln!(
            "{:24} codes {:7} max|Δ| {} mean Δ {:+.4} exact {:.2}%",
            cfg.name,
            a.count,
            a.max_abs,
            a.mean,
            100.0 * a.exact as f64 / a.count as f64
        );
        assert!(a.max_abs <= 1, "{}: max |Δ| = {}", cfg.name, a.max_abs);
        // A mean is a statistic: judged where there are enough codes for it to mean something.
        if a.count >= 1000 {
            assert!(a.mean.abs() < 0.05, "{}: mean Δ = {}", cfg.name, a.mean);
        }
        total += a.count;
        sum += a.mean * a.count as f64;
    }
    assert!((sum / total as f64).abs() < 0.05, "pooled mean Δ = {}", sum / total as f64);
}

/// The C tests (`bindings-c/tests/test_nmat.c`) compare the C API's output with committed bytes;
/// this keeps those bytes equal to the Rust integer decoder of the same fixture (which the test
/// above checks against the reference decoder).
#[test]
fn c_test_expectations_match_the_rust_decoder() {
    let name = "ntc_16ch_8bit_32";
    let bytes = std::fs::read(fixtures_dir().join(format!("{name}.nmat"))).unwrap();
    let m = Container::parse(&bytes).unwrap();
    let decoded = decode_all_u8(&m);
    let path = fixtures_dir().join(format!("../../bindings-c/tests/data/{name}.u8"));
    if bless() {
        std::fs::write(&path, &decoded).unwrap();
    }
    let committed = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(committed == decoded, "{} differs from the decoder's output", path.display());
}

/// Fixtures whose packed form (FORMAT.md §12) is committed beside them: 8-bit latents, and the
/// 8-4-2-1 bit depths of NBC. The C tests open the first.
const PACKED_FIXTURES: [&str; 2] = ["ntc_16ch_8bit_32", "nbc_8421_64"];

#[test]
fn packed_fixtures_are_reproducible_and_unpack_to_their_twins() {
    for name in PACKED_FIXTURES {
        let fixed = std::fs::read(fixtures_dir().join(format!("{name}.nmat"))).unwrap();
        let packed = nmat_core::pack(&fixed).unwrap();
        let path = fixtures_dir().join(format!("{name}.packed.nmat"));
        if bless() {
            std::fs::write(&path, &packed).unwrap();
        }
        let committed = std::fs::read(&path)
            .unwrap_or_else(|e| panic!("{}: {e} (run with NMAT_BLESS=1)", path.display()));
        assert!(committed == packed, "{name}: packing no longer gives the committed file");
        let unpacked = nmat_core::unpack(&committed, Default::default()).unwrap();
        assert!(unpacked.as_ref() == fixed.as_slice(), "{name}: does not unpack to its twin");
    }
}

/// The committed JPEG materials (tests/fixtures/jpeg/README.md: 4:2:0 with restart markers,
/// 4:2:2 without) decode to djpeg's decode of their JPEGs, the committed `.u8` files, through
/// every integer path of the core: texel by texel (8 and 16 bits), on every kernel by region (the
/// whole mip, a rectangle cut across MCUs, one channel) and by span. `encoder/tests/jpeg.rs`
/// checks that the `.u8` files are still what djpeg gives.
#[test]
fn the_committed_jpeg_materials_decode_like_djpeg_on_every_path() {
    use nmat_core::{Decoder, Kernel};
    let dir = fixtures_dir().join("jpeg");
    for name in nmat_tests::JPEG_FIXTURES {
        let nmat = std::fs::read(dir.join(format!("{name}.nmat"))).unwrap();
        let expected = std::fs::read(dir.join(format!("{name}.u8"))).unwrap();
        let m = Container::parse(&nmat).unwrap();
        let (w, h) = (37usize, 21usize);
        assert_eq!((m.mip_count(), m.mip_size(0), m.channel_count()), (1, (37, 21), 3));
        assert_eq!(expected.len(), w * h * 3);
        assert!(decode_all_u8(&m) == expected, "{name}: texel by texel, 8 bits");
        let times_257: Vec<u8> =
            expected.iter().flat_map(|&c| (u16::from(c) * 257).to_le_bytes()).collect();
        assert!(
            decode_all_u16(&m) == times_257,
            "{name}: texel by texel, 16 bits (each code · 257)"
        );
        // A rectangle that starts and ends inside MCUs (16 × 16 texels at 4:2:0, 16 × 8 at 4:2:2).
        let (x0, y0, rw, rh) = (5usize, 3usize, 26usize, 17usize);
        let cut: Vec<u8> = (y0..y0 + rh)
            .flat_map(|y| expected[(y * w + x0) * 3..(y * w + x0 + rw) * 3].to_vec())
            .collect();
        for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
            let d = Decoder::with_kernel(&m, kernel).unwrap();
            let mut out = vec![0u8; w * h * 3];
            d.decode_region_u8(&m, 0, (0, 0, 37, 21), ChannelMask::ALL, &mut out, 0).unwrap();
            assert!(out == expected, "{name}, {kernel:?}: the whole mip as a region");
            let mut out = vec![0u8; rw * rh * 3];
            let rect = (x0 as u32, y0 as u32, rw as u32, rh as u32);
            d.decode_region_u8(&m, 0, rect, ChannelMask::ALL, &mut out, 0).unwrap();
            assert!(out == cut, "{name}, {kernel:?}: a rectangle across MCUs");
            let mut green = vec![0u8; rw * rh];
            d.decode_region_u8(&m, 0, rect, ChannelMask::single(1), &mut green, 0).unwrap();
            let cut_green: Vec<u8> = cut.iter().skip(1).step_by(3).copied().collect();
            assert!(green == cut_green, "{name}, {kernel:?}: the green channel of the rectangle");
            for y in 0..h {
                let mut row = vec![0u8; w * 3];
                d.decode_span_u8(&m, 0, y as i64, 0, w, ChannelMask::ALL, &mut row).unwrap();
                assert!(
                    row[..] == expected[y * w * 3..(y + 1) * w * 3],
                    "{name}, {kernel:?}: row {y}"
                );
            }
        }
    }
}

/// A JPEG material of four maps (4:2:0, gray, luma 1 × 2, gray), four mips and streams of up to
/// five index groups, built in code with DC-only blocks so that every code follows from
/// FORMAT.md §11 (`nmat_tests::generate_jpeg`): decoded texel by texel (8-bit codes, unit and
/// ranged floats), and on every kernel by region (each whole mip, a rectangle across MCUs,
/// channels of several maps, empty rectangles), by span (8-bit, 16-bit and ranged floats; every
/// row, one that wraps around the edges, a mip past the chain) — the sums over maps, mips and
/// index groups that the one-map fixture above cannot check.
#[test]
fn a_jpeg_material_of_several_maps_and_mips_decodes_as_the_format_says() {
    use nmat_core::{Decoder, Kernel};
    use nmat_tests::generate_jpeg::DcJpegMaterial;
    let material = &DcJpegMaterial::new(7);
    let bytes = material.spec.to_bytes().expect("a valid JPEG material");
    let m = Container::parse(&bytes).unwrap();
    assert_eq!((m.mip_count(), m.mip_size(3), m.channel_count()), (4, (8, 4), 8));
    let per_mip: Vec<Vec<u8>> = (0..4).map(|mip| material.mip_codes(mip)).collect();
    let expected = per_mip.concat();
    assert!(decode_all_u8(&m) == expected, "texel by texel, 8 bits");
    // The float decoders (FORMAT.md §11.5): `c / 255`, and in the channel's range
    // `range_min · (1 − c/255) + range_max · c/255`; a mask of one channel of each map.
    let ranges: Vec<(f32, f32)> =
        material.spec.channels.iter().map(|c| (c.range_min, c.range_max)).collect();
    let one_a_map = [1usize, 3, 6, 7];
    let one_a_map_mask = ChannelMask(one_a_map.iter().map(|c| 1u16 << c).sum());
    for (x, y, mip) in texels(&m) {
        let (mut unit, mut ranged) = ([0f32; 16], [0f32; 16]);
        assert_eq!(m.decode_texel_unit(x, y, mip, one_a_map_mask, &mut unit).unwrap(), 4);
        assert_eq!(m.decode_texel(x, y, mip, one_a_map_mask, &mut ranged).unwrap(), 4);
        for (k, &c) in one_a_map.iter().enumerate() {
            let u = f32::from(material.code(c, x as u32, y as u32, mip)) / 255.0;
            let (lo, hi) = ranges[c];
            let at = format!("channel {c} at ({x}, {y}) mip {mip}");
            assert_eq!(unit[k].to_bits(), u.to_bits(), "unit {at}");
            assert_eq!(ranged[k].to_bits(), (lo * (1.0 - u) + hi * u).to_bits(), "ranged {at}");
        }
    }
    let n = 8usize;
    // Channels 2 (B of the 4:2:0 map), 3 (gray), 5 (G of the 1 × 2 map) and 7 (gray).
    let some = [2usize, 3, 5, 7];
    let mask = ChannelMask(some.iter().map(|c| 1u16 << c).sum());
    for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
        let d = Decoder::with_kernel(&m, kernel).unwrap();
        for mip in 0..4 {
            let (w, h) = m.mip_size(mip);
            let (w, h) = (w as usize, h as usize);
            let codes = &per_mip[mip as usize];
            let mut out = vec![0u8; w * h * n];
            d.decode_region_u8(&m, mip, (0, 0, w as u32, h as u32), ChannelMask::ALL, &mut out, 0)
                .unwrap();
            assert!(out == *codes, "{kernel:?}: mip {mip} as a region");
            let mut picked = vec![0u8; w * h * some.len()];
            d.decode_region_u8(&m, mip, (0, 0, w as u32, h as u32), mask, &mut picked, 0).unwrap();
            let want: Vec<u8> = codes.chunks(n).flat_map(|t| some.iter().map(|&c| t[c])).collect();
            assert!(picked == want, "{kernel:?}: mip {mip}, channels {some:?} as a region");
            for y in 0..h {
                let mut row = vec![0u8; w * n];
                d.decode_span_u8(&m, 0, y as i64, mip, w, ChannelMask::ALL, &mut row).unwrap();
                assert!(
                    row[..] == codes[y * w * n..(y + 1) * w * n],
                    "{kernel:?}: mip {mip} row {y}"
                );
            }
        }
        // A rectangle of mip 0 that starts and ends inside MCUs of every map.
        let (x0, y0, rw, rh) = (5u32, 3u32, 51u32, 29u32);
        let mut out = vec![0u8; (rw * rh) as usize * n];
        d.decode_region_u8(&m, 0, (x0, y0, rw, rh), ChannelMask::ALL, &mut out, 0).unwrap();
        let cut: Vec<u8> = (y0..y0 + rh)
            .flat_map(|y| (x0..x0 + rw).flat_map(move |x| (0..n).map(move |c| (c, x, y))))
            .map(|(c, x, y)| material.code(c, x, y, 0))
            .collect();
        assert!(out == cut, "{kernel:?}: a rectangle across MCUs");
        // Every row of mip 1 as 16-bit codes (257 · c) and as values in the channels' ranges
        // (one channel of each map); a mip past the chain is the last one; empty rectangles.
        let (w, h) = (35usize, 18usize);
        for y in 0..h {
            let (mut u16s, mut floats) = (vec![0u16; w * n], vec![0f32; w * 4]);
            let u16_count = d.decode_span_u16(&m, 0, y as i64, 1, w, ChannelMask::ALL, &mut u16s);
            let f32_count = d.decode_span_f32(&m, 0, y as i64, 1, w, one_a_map_mask, &mut floats);
            assert_eq!((u16_count, f32_count), (Ok(w * n), Ok(w * 4)), "{kernel:?}: row {y}");
            for x in 0..w {
                for c in 0..n {
                    let code = u16::from(material.code(c, x as u32, y as u32, 1));
                    assert_eq!(u16s[x * n + c], 257 * code, "{kernel:?}: u16 ({x}, {y}) {c}");
                }
                for (k, &c) in one_a_map.iter().enumerate() {
                    let u = f32::from(material.code(c, x as u32, y as u32, 1)) / 255.0;
                    let (lo, hi) = ranges[c];
                    let want = (lo * (1.0 - u) + hi * u).to_bits();
                    assert_eq!(floats[x * 4 + k].to_bits(), want, "{kernel:?}: f32 ({x}, {y}) {c}");
                }
            }
        }
        let (mut past, mut last) = (vec![0u8; 8 * n], vec![0u8; 8 * n]);
        d.decode_span_u8(&m, 0, 3, 9, 8, ChannelMask::ALL, &mut past).unwrap();
        d.decode_span_u8(&m, 0, 3, 3, 8, ChannelMask::ALL, &mut last).unwrap();
        assert!(past == last, "{kernel:?}: mip 9 is mip 3");
        let (mut past, mut last) = (vec![0f32; 8 * n], vec![0f32; 8 * n]);
        d.decode_span_f32(&m, 0, 3, 9, 8, ChannelMask::ALL, &mut past).unwrap();
        d.decode_span_f32(&m, 0, 3, 3, 8, ChannelMask::ALL, &mut last).unwrap();
        assert!(past == last, "{kernel:?}: mip 9 is mip 3, as floats");
        let mut untouched = vec![7u8; 8 * n];
        for rect in [(0, 0, 0, 5), (0, 0, 5, 0), (70, 37, 0, 0)] {
            let per_row = d.decode_region_u8(&m, 0, rect, ChannelMask::ALL, &mut untouched, 0);
            assert_eq!(per_row, Ok(rect.2 as usize * n), "{kernel:?}: codes per row of {rect:?}");
        }
        assert!(untouched.iter().all(|&v| v == 7), "{kernel:?}: an empty rectangle writes nothing");
        // A span of mip 1 (35 × 18) from x = −5 over 45 texels: it wraps at both edges.
        let mut row = vec![0u8; 45 * some.len()];
        d.decode_span_u8(&m, -5, 17, 1, 45, mask, &mut row).unwrap();
        let want: Vec<u8> = (-5i64..40)
            .flat_map(|x| {
                some.iter().map(move |&c| material.code(c, x.rem_euclid(35) as u32, 17, 1))
            })
            .collect();
        assert!(row == want, "{kernel:?}: a span that wraps");
    }
}

/// The integer network's input vector (`internals::input_vector`, which the encoder's refit
/// starts from) equals the reference's (FORMAT.md §6.3: features rounded and saturated to i16),
/// zeros past the input width, at texels inside and outside every mip (wrapped or clamped) of
/// every golden material; a JPEG material has none.
#[test]
fn the_input_vector_is_the_reference_s() {
    use nmat_core::internals::input_vector;
    for cfg in golden_configs() {
        let spec = generate(&cfg);
        let bytes = spec.to_bytes().unwrap();
        let m = Container::parse(&bytes).unwrap();
        let width = usize::from(spec.mlp.layers[0].inputs);
        for mip in 0..m.mip_count() + 1 {
            let (w, h) = m.mip_size(mip);
            let (w, h) = (i64::from(w), i64::from(h));
            for (x, y) in [(0, 0), (w - 1, h - 1), (w / 2, h / 3), (-3, h + 5), (2 * w + 1, -h)] {
                let got = input_vector(&m, x, y, mip).unwrap();
                let want = reference::input_vector(&spec, x, y, mip);
                assert_eq!(want.len(), width, "{}", cfg.name);
                let got: Vec<i64> = got.iter().map(|&v| i64::from(v)).collect();
                assert_eq!(got[..width], want[..], "{} ({x}, {y}) mip {mip}", cfg.name);
                assert!(got[width..].iter().all(|&v| v == 0), "{}: past the inputs", cfg.name);
            }
        }
    }
    let jpeg = std::fs::read(fixtures_dir().join("jpeg/pattern_420_37x21.nmat")).unwrap();
    assert_eq!(input_vector(&Container::parse(&jpeg).unwrap(), 0, 0, 0), None);
}

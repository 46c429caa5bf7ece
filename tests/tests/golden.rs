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

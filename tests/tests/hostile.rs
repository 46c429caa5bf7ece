//! Truncated and bit-flipped fixtures: always an error or a valid material that decodes (like
//! the reference decoder), never a panic.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{
    ChannelMask, Container, Error, Field, Filter, JpegMap, Material, MaterialSpec, ParseOptions,
    Precision, SampleRequest, SectionKind,
};
use nmat_tests::files::{jpeg_stream_records, refresh_checksum, section, section_entry};
use nmat_tests::generate::{FixtureConfig, generate, golden_configs, terms_in_any_order};
use nmat_tests::{assert_decodes_as_the_reference, fixtures_dir, reference};

fn fixtures() -> Vec<(&'static str, Vec<u8>)> {
    golden_configs().into_iter().map(|c| (c.name, generate(&c).to_bytes().unwrap())).collect()
}

/// Decodes a handful of texels through every entry point; they must not panic.
fn exercise(m: &Material<'_>) {
    let last = m.mip_count() - 1;
    let mut f = [0f32; 16];
    let mut c8 = [0u8; 16];
    let mut c16 = [0u16; 16];
    m.decode_texel(-1, 7, 1, ChannelMask::ALL, &mut f).unwrap();
    m.decode_texel_u8(1 << 20, -3, last, ChannelMask::ALL, &mut c8).unwrap();
    m.decode_texel_u16(5, 5, last + 3, ChannelMask::single(0), &mut c16).unwrap();
    let req = SampleRequest {
        u: 0.3,
        v: 0.9,
        lod: 0.6,
        filter: Filter::Stochastic,
        precision: Precision::Integer,
        random: [0.5; 3],
        channels: ChannelMask::ALL,
    };
    m.sample(&req, &mut f).unwrap();
}

#[test]
fn every_truncation_is_an_error() {
    for (name, bytes) in fixtures() {
        for len in 0..bytes.len() {
            assert!(Container::parse(&bytes[..len]).is_err(), "{name}: {len} bytes parsed");
        }
    }
}

#[test]
fn truncations_with_a_consistent_header_are_errors_or_decode() {
    // Patch the declared length and checksum so validation must find the missing bytes itself.
    for (name, bytes) in fixtures() {
        for len in (0..bytes.len()).filter(|l| l % 4 == 0 || *l < 64) {
            let mut cut = bytes[..len].to_vec();
            if len >= 32 {
                cut[12..16].copy_from_slice(&(len as u32).to_le_bytes());
                refresh_checksum(&mut cut);
            }
            match Container::parse(&cut) {
                Ok(m) => {
                    panic!("{name}: a {len}-byte prefix parsed as {}×{}", m.width(), m.height())
                }
                Err(Error::Truncated { .. } | Error::Malformed { .. }) => {}
                Err(other) => panic!("{name}: {len} bytes gave {other}"),
            }
        }
    }
}

#[test]
fn every_bit_flip_breaks_the_checksum_or_a_field() {
    for (name, bytes) in fixtures() {
        let mut b = bytes.clone();
        for bit in 0..b.len() * 8 {
            b[bit / 8] ^= 1 << (bit % 8);
            assert!(Container::parse(&b).is_err(), "{name}: flip of bit {bit} went unnoticed");
            b[bit / 8] ^= 1 << (bit % 8);
        }
    }
}

#[test]
fn every_bit_flip_past_the_checksum_is_an_error_or_a_valid_decode() {
    let no_crc = ParseOptions { verify_checksum: false };
    let fixtures = fixtures();
    std::thread::scope(|s| {
        for (name, bytes) in &fixtures {
            s.spawn(move || {
                let (mut accepted, mut rejected) = (0usize, 0usize);
                let mut b = bytes.clone();
                for bit in 0..b.len() * 8 {
                    b[bit / 8] ^= 1 << (bit % 8);
                    match Container::parse_with(&b, no_crc) {
                        Ok(m) => {
                            accepted += 1;
                            exercise(&m);
                            // A sparse sample of the accepted files is checked against the
                            // reference: whatever bytes parse, the decoders agree on them.
                            if bit % 97 == 0 {
                                let spec = m.to_spec().expect("a neural fixture");
                                let mut out = [0u8; 16];
                                let n =
                                    m.decode_texel_u8(3, 2, 0, ChannelMask::ALL, &mut out).unwrap();
                                assert_eq!(
                                    out[..n].to_vec(),
                                    reference::decode_u8(&spec, 3, 2, 0),
                                    "{name} bit {bit}"
                                );
                            }
                        }
                        Err(e) => {
                            rejected += 1;
                            // Errors render, and name the field at fault as FORMAT.md does
                            // (its Debug name); the version, packing and flags refusals say
                            // what to do instead.
                            let message = e.to_string();
                            let field = match e {
                                Error::Malformed { field, .. }
                                | Error::LimitExceeded { field, .. }
                                | Error::Truncated { field, .. }
                                | Error::Unsupported { field, .. } => Some(field),
                                _ => None,
                            };
                            match field {
                                Some(Field::VersionMajor | Field::Packed | Field::Flags) => {
                                    assert!(message.contains("nmat"), "{message}")
                                }
                                Some(f) => {
                                    assert!(message.contains(&format!("{f:?}[")), "{message}")
                                }
                                None => assert!(!message.is_empty()),
                            }
                        }
                    }
                    b[bit / 8] ^= 1 << (bit % 8);
                }
                eprintln!("{name:24} flips accepted {accepted:7} rejected {rejected:7}");
            });
        }
    });
}

/// The byte offset of the first section of `kind` in a well-formed file.
fn section_offset(bytes: &[u8], kind: u32) -> usize {
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    let entry = (0..word(16) as usize).map(|i| 32 + 16 * i).find(|&e| word(e) == kind).unwrap();
    word(entry + 8) as usize
}

#[test]
fn the_lod_feature_scale_needs_its_flag_and_must_fit_the_input_format() {
    // ntc_rgb_64: input Q.12, a LOD feature (code 1, mip / 16). MLP header byte 3 is the code,
    // header flag bit 0 allows codes 2–5 (mip · 2^(code − 5)) where f + code ≤ 16 (§5.3, §6.5).
    let (name, good) = fixtures().remove(0);
    let mlp = section_offset(&good, 3);
    assert_eq!((good[mlp + 1], good[mlp + 3]), (12, 1), "{name}");
    let with = |flags: u32, code: u8| {
        let mut b = good.clone();
        b[8..12].copy_from_slice(&flags.to_le_bytes());
        b[mlp + 3] = code;
        refresh_checksum(&mut b);
        Container::parse(&b).map(|m| match m.body() {
            nmat_core::Body::Neural(n) => (n.mlp().lod_code(), n.mlp().lod_feature(6)),
            _ => unreachable!("a neural fixture"),
        })
    };
    let lod_field =
        |r: Result<_, Error>| matches!(r, Err(Error::Malformed { field: Field::LodInput, .. }));
    // Q.12: mip 6 is 6 · 2^12 · 2^(code − 5).
    assert_eq!(with(0, 1), Ok((1, Some(6 << 8))));
    assert_eq!(with(1, 4), Ok((4, Some(6 << 11))));
    assert!(with(0, 0).is_err(), "the input width counts the LOD feature");
    assert!(lod_field(with(0, 4)), "a scaled code without its flag");
    assert!(lod_field(with(1, 5)), "Q.12 cannot hold mip 14 · 2^0");
    assert!(lod_field(with(1, 6)), "no code 6");
}

#[test]
fn specific_corruptions_give_specific_errors() {
    let (_, good) = fixtures().remove(0);
    let edit = |off: usize, bytes: &[u8]| {
        let mut b = good.clone();
        b[off..off + bytes.len()].copy_from_slice(bytes);
        refresh_checksum(&mut b);
        Container::parse(&b).map(|m| m.version_minor())
    };
    assert!(matches!(edit(0, b"NMAX"), Err(Error::Malformed { field: Field::Magic, .. })));
    // Shorter than the header: another kind of file (a few bytes of a PNG) is named by its
    // magic, a cut nmat file (its magic or a prefix of it, or nothing) by its length.
    for short in [&b"\x89PNG\r\n"[..], b"NMAX", b"NX", b"P"] {
        let got = Container::parse(short);
        assert!(matches!(got, Err(Error::Malformed { field: Field::Magic, .. })), "{got:?}");
    }
    for len in [0, 1, 3, 4, 31] {
        let got = Container::parse(&good[..len]);
        let truncated = matches!(got, Err(Error::Truncated { field: Field::FileLength, .. }));
        assert!(truncated, "{len} bytes: {got:?}");
    }
    assert!(matches!(
        edit(4, &3u16.to_le_bytes()),
        Err(Error::Unsupported { field: Field::VersionMajor, value: 3, .. })
    ));
    let message = edit(4, &3u16.to_le_bytes()).unwrap_err().to_string();
    assert!(
        message.contains("format version 3") && message.contains("versions 1 and 2"),
        "{message}"
    );
    // A newer minor version is accepted (§1.3).
    assert_eq!(edit(6, &7u16.to_le_bytes()), Ok(7));
    // Flag bit 0 (2.3's scaled LOD feature) is known; any other is a newer feature.
    assert_eq!(edit(8, &1u32.to_le_bytes()), Ok(0));
    for flags in [2u32, 1 << 31] {
        let e = edit(8, &flags.to_le_bytes()).unwrap_err();
        assert!(matches!(e, Error::Unsupported { field: Field::Flags, .. }), "{e:?}");
        assert!(e.to_string().contains("newer nmat"), "{e}");
    }
    assert!(matches!(
        edit(16, &0u32.to_le_bytes()),
        Err(Error::Malformed { field: Field::SectionCount, .. })
    ));
    assert!(matches!(
        edit(16, &99u32.to_le_bytes()),
        Err(Error::LimitExceeded { field: Field::SectionCount, .. })
    ));
    // Section 0 (material) moved onto section 1 (levels): overlap.
    let levels_offset = u32::from_le_bytes(good[32 + 16 + 8..32 + 16 + 12].try_into().unwrap());
    assert!(matches!(
        edit(32 + 8, &levels_offset.to_le_bytes()),
        Err(Error::Malformed { field: Field::SectionOffset, .. })
    ));
    assert!(matches!(
        edit(32 + 8, &(levels_offset + 2).to_le_bytes()),
        Err(Error::Malformed { field: Field::SectionOffset, .. })
    ));
    // An unknown required section kind, and the same kind made optional (skipped, then missing).
    assert!(matches!(
        edit(32, &77u32.to_le_bytes()),
        Err(Error::Unsupported { field: Field::SectionKind, value: 77, .. })
    ));
    let mut b = good.clone();
    b[32..36].copy_from_slice(&77u32.to_le_bytes());
    b[36..40].copy_from_slice(&0u32.to_le_bytes());
    refresh_checksum(&mut b);
    assert!(matches!(
        Container::parse(&b),
        Err(Error::Malformed { field: Field::MissingSection, index: 1, .. })
    ));
    // Checksum.
    let mut b = good.clone();
    b[100] ^= 0x10;
    assert!(matches!(Container::parse(&b), Err(Error::ChecksumMismatch { .. })));
    // Trailing bytes and a short file.
    let mut b = good.clone();
    b.extend_from_slice(&[0; 4]);
    assert!(matches!(Container::parse(&b), Err(Error::Malformed { field: Field::FileLength, .. })));
    assert!(matches!(
        Container::parse(&good[..good.len() - 4]),
        Err(Error::Truncated { field: Field::FileLength, .. })
    ));
}

/// The parser's rules hold exactly at their edges: a value at a bound parses, the first one past
/// it is refused by name, and every reserved field is checked on its own. Each case here was
/// found unchecked by mutating the rule (cargo-mutants on `container.rs`).
#[test]
fn the_parser_rules_hold_at_their_edges() {
    let base = generate(&FixtureConfig::ntc("edges", 3, 20, 10, 3)); // 5 mips, 3 levels
    let refused = |spec: &MaterialSpec, field: Field, index: u32| {
        let got = spec.to_bytes().and_then(|b| Container::parse(&b).map(|_| ()));
        let named = match got {
            Err(
                Error::Malformed { field: f, index: i, .. }
                | Error::LimitExceeded { field: f, index: i, .. },
            ) => (f, i) == (field, index),
            _ => false,
        };
        assert!(named, "{field:?} {index}: {got:?}");
    };
    // A channel's range: each end must be finite on its own.
    for (min, max) in [(f32::NAN, 1.0), (0.0, f32::INFINITY), (f32::NEG_INFINITY, 1.0)] {
        let mut s = base.clone();
        (s.channels[1].range_min, s.channels[1].range_max) = (min, max);
        refused(&s, Field::ChannelRange, 1);
    }
    // A mip's level: the last level is the largest.
    let mut s = base.clone();
    s.mip_to_level[1] = base.levels.len() as u8;
    refused(&s, Field::MipToLevel, 1);
    // The fewest fraction bits of the input format (4) parse and decode.
    let at_least = FixtureConfig {
        input_frac_bits: 4,
        pe_frequencies: 2,
        ..FixtureConfig::ntc("f4", 4, 12, 9, 2)
    };
    assert_decodes_as_the_reference(&generate(&at_least));
    // A chain of eight grids (the most, §5.2) parses and decodes; none is refused.
    assert_decodes_as_the_reference(&generate(&terms_in_any_order()));
    let mut s = base.clone();
    s.levels[0].terms[1].grids.clear();
    refused(&s, Field::TermChainLength, 1);
    // A term's index counts the terms of the levels before it (4 a level).
    let mut s = base.clone();
    s.levels[1].terms[1].grids = vec![17];
    refused(&s, Field::TermGrid, 4 + 1);
    // Dequantized latents must stay i16 at both ends of the codes (§4.2): offset + max · step.
    let max = (1i32 << base.grids[0].bits) - 1;
    for (offset, step) in [(32000, (1000 + max - 1) / max), (0, 33000 / max + 1)] {
        let mut s = base.clone();
        s.grids[0].quantization[1] = (offset as i16, step as i16);
        refused(&s, Field::LatentQuantization, 0);
    }
    // Layers: each takes the previous one's outputs, none has no outputs, the last has one a
    // channel, and every bias of a layer is within the accumulator bound (§5.3).
    let resized = |l: &mut nmat_core::LayerSpec, inputs: u16, outputs: u16| {
        let n = usize::from(inputs) * usize::from(outputs);
        l.weights_i8.resize(n, 1);
        l.scales.resize(usize::from(outputs), l.scales[0]);
        l.bias.resize(usize::from(outputs), 0);
        (l.inputs, l.outputs) = (inputs, outputs);
    };
    let mut s = base.clone();
    let (inputs, outputs) = (s.mlp.layers[1].inputs + 1, s.mlp.layers[1].outputs);
    resized(&mut s.mlp.layers[1], inputs, outputs);
    refused(&s, Field::LayerInputs, 1);
    let mut s = base.clone();
    let inputs = s.mlp.layers[0].inputs;
    resized(&mut s.mlp.layers[0], inputs, 0);
    let outputs = s.mlp.layers[1].outputs;
    resized(&mut s.mlp.layers[1], 0, outputs);
    refused(&s, Field::LayerOutputs, 0);
    let mut s = base.clone();
    let last = s.mlp.layers.len() - 1;
    let inputs = s.mlp.layers[last].inputs;
    resized(&mut s.mlp.layers[last], inputs, 2);
    refused(&s, Field::LayerOutputs, last as u32);
    let mut s = base.clone();
    let inputs = i32::from(s.mlp.layers[0].inputs);
    s.mlp.layers[0].bias[2] = i32::MAX - inputs * 127 * 32768 + 1;
    refused(&s, Field::Bias, 0);

    // Patched files (the checksum refreshed): each reserved field alone, and counts that the
    // section cannot hold.
    let good = base.to_bytes().unwrap();
    let patched = |kind: SectionKind, at: usize, bytes: &[u8]| {
        let (offset, _) = section(&good, kind.0);
        let mut b = good.clone();
        b[offset + at..offset + at + bytes.len()].copy_from_slice(bytes);
        refresh_checksum(&mut b);
        Container::parse(&b).map(|_| ())
    };
    let is = |got: Result<(), Error>, field: Field, index: u32| {
        let named = match got {
            Err(Error::Malformed { field: f, index: i, .. }) => (f, i) == (field, index),
            _ => false,
        };
        assert!(named, "{field:?} {index}: {got:?}");
    };
    // Channel record 1 (after the material's 12 bytes; 32 a channel, §3): byte 19, word 28.
    is(patched(SectionKind::MATERIAL, 12 + 32 + 19, &[1]), Field::ChannelReserved, 1);
    is(patched(SectionKind::MATERIAL, 12 + 32 + 28, &[1]), Field::ChannelReserved, 1);
    // The level table's entry for the first mip past the chain (levels header byte 4 + mip).
    let mips = usize::from(base.mip_count);
    is(patched(SectionKind::LEVELS, 4 + mips, &[1]), Field::MipToLevel, mips as u32);
    // Level 0's header, after the 20-byte levels header and the grid records (16 + 4 bytes a
    // channel, §5.1): its reserved bytes, then its second term's chain length past the most (8).
    let level0 = 20 + base.grids.iter().map(|g| 16 + 4 * usize::from(g.channels)).sum::<usize>();
    is(patched(SectionKind::LEVELS, level0 + 3, &[1]), Field::LevelReserved, 0);
    is(patched(SectionKind::LEVELS, level0 + 4 + 12 + 1, &[9]), Field::TermChainLength, 1);
    // Grid 0's record (after the levels header): its reserved u16, named with its value.
    let got = patched(SectionKind::LEVELS, 20 + 6, &[1, 2]);
    let field = Field::GridReserved;
    assert_eq!(got, Err(Error::Malformed { field, index: 0, value: 0x0201 }));
    // The last level claiming more terms than the section holds (each level here has two).
    let last = base.levels.len() - 1;
    let got = patched(SectionKind::LEVELS, level0 + (4 + 2 * 12) * last, &[4]);
    let truncated = match got {
        Err(Error::Truncated { field: Field::TermCount, index, .. }) => index == last as u32,
        _ => false,
    };
    assert!(truncated, "{got:?}");
    // An MLP section that ends inside its table of layer records (one record short).
    let entry = section_entry(&good, SectionKind::MLP.0);
    let mut b = good.clone();
    let short = 8 + 8 * (base.mlp.layers.len() as u32 - 1);
    b[entry + 12..entry + 16].copy_from_slice(&short.to_le_bytes());
    refresh_checksum(&mut b);
    let got = Container::parse(&b).map(|_| ());
    let truncated = matches!(got, Err(Error::Truncated { field: Field::LayerCount, .. }));
    assert!(truncated, "{got:?}");
    // Layer 1's record (after the MLP's 8-byte header, 8 a layer, §5.3): its reserved u16.
    let got = patched(SectionKind::MLP, 8 + 8 + 6, &[1, 2]);
    assert_eq!(got, Err(Error::Malformed { field: Field::LayerReserved, index: 1, value: 0x0201 }));
}

/// An edit of a section's bytes.
type Edit<'a> = Box<dyn Fn(&mut [u8]) + 'a>;

/// The committed JPEG material: one 4:2:0 colour map of 3 × 2 MCUs, one mip, 2 quantization
/// and 4 Huffman tables (tests/fixtures/jpeg/README.md).
fn jpeg_material() -> Vec<u8> {
    std::fs::read(fixtures_dir().join("jpeg/pattern_420_37x21.nmat")).unwrap()
}

/// The JPEG section's rules (FORMAT.md §11.1) hold at their edges, each refused by name with the
/// element and value at fault: the header's counts and reserved bytes, the map, the quantization
/// and Huffman tables, the stream record's table references and reserved bytes, the stream's
/// length and its index of MCU offsets. Found unchecked by mutating `jpeg/mod.rs` (cargo-mutants).
#[test]
fn the_jpeg_section_rules_hold_at_their_edges() {
    use Error::{LimitExceeded, Malformed, Truncated, Unsupported};
    let bytes = jpeg_material();
    let (at, len) = section(&bytes, SectionKind::JPEG.0);
    assert!(Container::parse(&bytes).is_ok());
    let s = &bytes[at..at + len];
    assert_eq!((s[2], s[3], s[4]), (1, 2, 4), "maps, quantization and Huffman tables");
    let u16_of = |at: usize| usize::from(u16::from_le_bytes([s[at], s[at + 1]]));
    let u32_of = |at: usize| u32::from_le_bytes(s[at..at + 4].try_into().unwrap()) as usize;
    let quant = 8 + 4;
    let mut huffman = vec![quant + 2 * 64];
    for t in 0..3 {
        huffman.push((huffman[t] + 20 + u16_of(huffman[t] + 2) + 3) & !3);
    }
    let record = jpeg_stream_records(s);
    assert_eq!(record, (huffman[3] + 20 + u16_of(huffman[3] + 2) + 3) & !3);
    let (body, entropy) = (u32_of(record), u32_of(record + 4));
    // 6 MCUs: one index group (20 bytes), then 6 · 3 DC values of 12 bits (28 bytes padded).
    let (index, end_bit) = (body, 8 * entropy);
    let align4 = |n: usize| (n + 3) & !3;
    assert_eq!(align4(body + 20 + 28 + entropy), len);
    let first_mcu = u32_of(index);

    let parse = |edit: &dyn Fn(&mut [u8])| {
        let mut b = bytes.clone();
        edit(&mut b[at..at + len]);
        refresh_checksum(&mut b);
        Container::parse(&b).map(|_| ()).err()
    };
    let put16 = |s: &mut [u8], at: usize, v: usize| {
        s[at..at + 2].copy_from_slice(&(v as u16).to_le_bytes())
    };
    let put32 = |s: &mut [u8], at: usize, v: usize| {
        s[at..at + 4].copy_from_slice(&(v as u32).to_le_bytes())
    };
    let cases: Vec<(&str, Edit<'_>, Error)> = vec![
        // The header.
        (
            "version 2",
            Box::new(|s| s[0] = 2),
            Unsupported { field: Field::JpegVersion, index: 0, value: 2 },
        ),
        (
            "no map",
            Box::new(|s| s[2] = 0),
            Malformed { field: Field::JpegMapCount, index: 0, value: 0 },
        ),
        (
            "more maps than channels",
            Box::new(|s| s[2] = 4),
            LimitExceeded { field: Field::JpegMapCount, index: 0, value: 4, limit: 3 },
        ),
        (
            "no quantization table",
            Box::new(|s| s[3] = 0),
            Malformed { field: Field::JpegQuantCount, index: 0, value: 0 },
        ),
        (
            "17 quantization tables",
            Box::new(|s| s[3] = 17),
            LimitExceeded { field: Field::JpegQuantCount, index: 0, value: 17, limit: 16 },
        ),
        (
            "one Huffman table",
            Box::new(|s| s[4] = 1),
            Malformed { field: Field::JpegHuffmanCount, index: 0, value: 1 },
        ),
        (
            "33 Huffman tables",
            Box::new(|s| s[4] = 33),
            LimitExceeded { field: Field::JpegHuffmanCount, index: 0, value: 33, limit: 32 },
        ),
        (
            "header byte 5",
            Box::new(|s| s[5] = 9),
            Malformed { field: Field::JpegReserved, index: 0, value: 9 },
        ),
        (
            "header byte 6",
            Box::new(|s| s[6] = 9),
            Malformed { field: Field::JpegReserved, index: 0, value: 9 },
        ),
        (
            "header byte 7",
            Box::new(|s| s[7] = 9),
            Malformed { field: Field::JpegReserved, index: 0, value: 9 },
        ),
        // The map: from channel 0, of 1 or 3 channels, sampling 1×1 for gray, 1–2 for colour.
        (
            "map from channel 1",
            Box::new(|s| s[8] = 1),
            Malformed { field: Field::JpegMap, index: 0, value: 1 },
        ),
        (
            "map of 2 channels",
            Box::new(|s| s[9] = 2),
            Unsupported { field: Field::JpegMapChannels, index: 0, value: 2 },
        ),
        (
            "gray map sampled 2×2",
            Box::new(|s| s[9] = 1),
            Unsupported { field: Field::JpegSubsampling, index: 0, value: 0x0202 },
        ),
        (
            "luma sampled 3×2",
            Box::new(|s| s[10] = 3),
            Unsupported { field: Field::JpegSubsampling, index: 0, value: 0x0302 },
        ),
        (
            "luma sampled 2×0",
            Box::new(|s| s[11] = 0),
            Unsupported { field: Field::JpegSubsampling, index: 0, value: 0x0200 },
        ),
        // Quantization: every value 1–255, the last of the second table too.
        (
            "a quantization value 0",
            Box::new(move |s| s[quant + 127] = 0),
            Malformed { field: Field::JpegQuantTable, index: 1, value: 0 },
        ),
        // Huffman tables: class 0 or 1, a zero byte, 1–256 symbols as the counts say, codes
        // that fit their lengths, baseline symbols.
        (
            "Huffman class 2",
            Box::new(|s| s[huffman[1]] = 2),
            Malformed { field: Field::JpegHuffmanTable, index: 1, value: 2 },
        ),
        (
            "Huffman byte 1",
            Box::new(|s| s[huffman[1] + 1] = 1),
            Malformed { field: Field::JpegHuffmanTable, index: 1, value: 1 },
        ),
        (
            "no Huffman symbol",
            Box::new(|s| put16(s, huffman[2] + 2, 0)),
            Malformed { field: Field::JpegHuffmanTable, index: 2, value: 0 },
        ),
        (
            "257 Huffman symbols",
            Box::new(|s| put16(s, huffman[2] + 2, 257)),
            Malformed { field: Field::JpegHuffmanTable, index: 2, value: 257 },
        ),
        (
            "counts one short of the symbols",
            Box::new(|s| s[huffman[0] + 4 + 1] -= 1),
            Malformed { field: Field::JpegHuffmanTable, index: 0, value: 12 },
        ),
        (
            "codes overflowing length 3",
            Box::new(|s| (s[huffman[0] + 4], s[huffman[0] + 5]) = (1, 0)),
            Malformed { field: Field::JpegHuffmanTable, index: 0, value: 3 },
        ),
        (
            "DC symbol 12",
            Box::new(|s| s[huffman[2] + 20 + 11] = 12),
            Malformed { field: Field::JpegHuffmanSymbol, index: 2, value: 12 },
        ),
        (
            "AC symbol of size 11",
            Box::new(|s| s[huffman[3] + 20] = 0x1B),
            Malformed { field: Field::JpegHuffmanSymbol, index: 3, value: 0x1B },
        ),
        (
            "AC symbol of size 0, neither end-of-block nor 16 zeros",
            Box::new(|s| s[huffman[3] + 20] = 0x10),
            Malformed { field: Field::JpegHuffmanSymbol, index: 3, value: 0x10 },
        ),
        // The stream record: after the records, 4-aligned, tables that exist and are of their
        // kind's class, reserved bytes 0.
        (
            "stream inside the records",
            Box::new(move |s| put32(s, record, body - 4)),
            Malformed { field: Field::JpegStreamOffset, index: 0, value: body as i64 - 4 },
        ),
        (
            "stream offset + 2",
            Box::new(move |s| put32(s, record, body + 2)),
            Malformed { field: Field::JpegStreamOffset, index: 0, value: body as i64 + 2 },
        ),
        (
            "Cr quantized by table 2",
            Box::new(move |s| s[record + 8 + 2] = 2),
            Malformed { field: Field::JpegTableRef, index: 0, value: 2 },
        ),
        (
            "Y's DC coded by an AC table",
            Box::new(move |s| s[record + 8 + 3] = 1),
            Malformed { field: Field::JpegTableRef, index: 0, value: 1 },
        ),
        (
            "Cb's AC coded by a DC table",
            Box::new(move |s| s[record + 8 + 6 + 1] = 2),
            Malformed { field: Field::JpegTableRef, index: 0, value: 2 },
        ),
        (
            "Cr's DC coded by table 4",
            Box::new(move |s| s[record + 8 + 3 + 2] = 4),
            Malformed { field: Field::JpegTableRef, index: 0, value: 4 },
        ),
        (
            "record byte 17",
            Box::new(move |s| s[record + 17] = 5),
            Malformed { field: Field::JpegReserved, index: 0, value: 5 },
        ),
        (
            "record byte 19",
            Box::new(move |s| s[record + 19] = 6),
            Malformed { field: Field::JpegReserved, index: 0, value: 6 },
        ),
        // The stream's length: past the section, or leaving bytes after the last stream.
        (
            "entropy + 2",
            Box::new(move |s| put32(s, record + 4, entropy + 2)),
            Truncated {
                field: Field::JpegStreamLength,
                index: 0,
                needed: (body + 48 + entropy + 2) as u64,
                available: len as u64,
            },
        ),
        (
            "entropy - 4",
            Box::new(move |s| put32(s, record + 4, entropy - 4)),
            Malformed { field: Field::SectionContent, index: 5, value: len as i64 },
        ),
        // The index: MCU offsets inside the entropy data, never going back, 0 past the last MCU.
        (
            "first MCU past the end",
            Box::new(move |s| put32(s, index, end_bit + 1)),
            Malformed { field: Field::JpegIndex, index: 0, value: end_bit as i64 + 1 },
        ),
        (
            "an MCU before the one before it",
            Box::new(move |s| {
                put16(s, index + 4, 4000);
                put16(s, index + 6, 3999);
            }),
            Malformed { field: Field::JpegIndex, index: 0, value: first_mcu as i64 + 3999 },
        ),
        (
            "an offset for a seventh MCU",
            Box::new(move |s| put16(s, index + 4 + 2 * 5, 1)),
            Malformed { field: Field::JpegIndex, index: 0, value: 1 },
        ),
    ];
    for (what, edit, expected) in &cases {
        assert_eq!(parse(edit.as_ref()), Some(*expected), "{what}");
    }
    // The parsed section reads back the layout found above from its bytes (§11.1, §11.2).
    let m = Container::parse(&bytes).unwrap();
    let jpeg = m.jpeg().unwrap();
    assert_eq!(jpeg.maps()[0].blocks_per_mcu(), 4 + 2, "2 × 2 luma blocks, Cb and Cr");
    let map =
        |channel_count, luma_h, luma_v| JpegMap { first_channel: 0, channel_count, luma_h, luma_v };
    assert_eq!((map(3, 2, 1).blocks_per_mcu(), map(1, 1, 1).blocks_per_mcu()), (2 + 2, 1));
    let p = jpeg.stream_parts(0, 0).unwrap();
    assert_eq!((p.index_at, p.dc_at, p.data_at, p.data_len), (body, body + 20, body + 48, entropy));
    assert_eq!(p.mcus, (3, 2));
    let refs = &s[record + 8..record + 17];
    assert_eq!(
        p.quant_at.to_vec(),
        refs[..3].iter().map(|&t| quant + 64 * usize::from(t)).collect::<Vec<_>>()
    );
    assert_eq!((&p.dc_table[..], &p.ac_table[..]), (&refs[3..6], &refs[6..9]));
    assert!(jpeg.stream_parts(1, 0).is_none() && jpeg.stream_parts(0, 1).is_none());
    for (t, &h) in huffman.iter().enumerate() {
        let counts: [u8; 16] = s[h + 4..h + 20].try_into().unwrap();
        assert_eq!(jpeg.huffman_table(t as u8), Some((s[h], counts, h + 20)), "table {t}");
    }
    assert_eq!(jpeg.huffman_table(4), None);
    assert_eq!(
        (jpeg.mcu_grid(0, 0), jpeg.mcu_grid(0, 1), jpeg.mcu_grid(1, 0)),
        ((3, 2), (0, 0), (0, 0))
    );
    // Index: one group of 20 bytes; DC values: 6 MCUs × 3 × 12 bits.
    let overhead = (8 * 20 + 6 * 3 * 12, 8 * entropy as u64);
    assert_eq!((jpeg.overhead_bits(), jpeg.stream_overhead_bits(0, 0)), (overhead, overhead));
    assert_eq!(
        (jpeg.stream_overhead_bits(0, 1), jpeg.stream_overhead_bits(1, 0)),
        ((0, 0), (0, 0))
    );
    // At the edges themselves: an MCU may start at the very end of the data (the parser does not
    // decode), and the stream may end exactly at the section's end.
    assert_eq!(
        parse(&|s| {
            put32(s, index, 0);
            (0..5).for_each(|j| put16(s, index + 4 + 2 * j, end_bit));
        }),
        None
    );
    assert_eq!(parse(&|s| put32(s, record + 4, entropy + 1)), None);
}

/// `check_huffman_table` (also the indexer's check of a JPEG's tables) at its edges: no code,
/// 257 codes, and 256 codes, the most, that fit their lengths (FORMAT.md §11.1).
#[test]
fn huffman_tables_hold_one_to_256_codes() {
    use nmat_core::internals::{HuffmanProblem, check_huffman_table};
    assert_eq!(check_huffman_table(0, &[0; 16], &[]), Err(HuffmanProblem::Count(0)));
    let mut counts = [0u8; 16];
    (counts[8], counts[9]) = (255, 1); // 255 codes of 9 bits, 1 of 10
    assert_eq!(check_huffman_table(0, &counts, &[3; 256]), Ok(()));
    counts[9] = 2;
    assert_eq!(check_huffman_table(0, &counts, &[3; 257]), Err(HuffmanProblem::Count(257)));
}

/// The JPEG section of a material of four maps and four mips (`nmat_tests::generate_jpeg`): each
/// stream's parts, MCU grid and overhead read back as the writer laid them out — offsets summed
/// over the records before it, index groups past the first, the fewest Huffman tables (2), a
/// table of the most symbols (256) — and the parser's rules that span streams and index groups:
/// a stream that starts inside the one before it (or inside the records), a section that ends
/// inside the records, an index group whose base goes back past the group before it, an entry
/// past the last MCU in a later group; and a symbol count of 65535.
#[test]
fn the_jpeg_section_of_several_maps_and_mips_reads_back_as_written() {
    use nmat_tests::generate_jpeg::DcJpegMaterial;
    let material = DcJpegMaterial::new(3);
    let spec = &material.spec;
    let bytes = spec.to_bytes().unwrap();
    let (at, len) = section(&bytes, SectionKind::JPEG.0);
    let s = &bytes[at..at + len];
    assert_eq!((s[2], s[3], s[4]), (4, 3, 2), "maps, quantization and Huffman tables");
    let m = Container::parse(&bytes).unwrap();
    let jpeg = m.jpeg().unwrap();
    let u16_of = |at: usize| u64::from(u16::from_le_bytes([s[at], s[at + 1]]));
    let u32_of = |at: usize| u64::from(u32::from_le_bytes(s[at..at + 4].try_into().unwrap()));
    let quant = 8 + 4 * 4;
    let mut parts = vec![];
    let mut total = (0, 0);
    for (k, map) in spec.maps.iter().enumerate() {
        let values = if map.channel_count == 3 { 3 } else { 1 };
        for mip in 0..4u32 {
            let stream = &spec.streams[k * 4 + mip as usize];
            let p = jpeg.stream_parts(k, mip).unwrap();
            let (w, h) = m.mip_size(mip);
            let (mw, mh) = map.mcu_size();
            let grid = (w.div_ceil(mw), h.div_ceil(mh));
            let at = format!("map {k} mip {mip}");
            assert_eq!((p.mcus, jpeg.mcu_grid(k, mip)), (grid, grid), "{at}");
            let mcus = (grid.0 * grid.1) as usize;
            assert_eq!(p.dc_at - p.index_at, 20 * mcus.div_ceil(9), "{at}: index groups");
            assert_eq!(p.data_at - p.dc_at, (mcus * values * 12).div_ceil(32) * 4, "{at}: DCs");
            assert_eq!(&s[p.data_at..p.data_at + p.data_len], &stream.data[..], "{at}: data");
            for (i, &bit) in stream.mcu_bits.iter().enumerate() {
                let group = p.index_at + 20 * (i / 9);
                let rel = if i % 9 == 0 { 0 } else { u16_of(group + 4 + 2 * (i % 9 - 1)) };
                assert_eq!(u32_of(group) + rel, bit, "{at}: MCU {i}'s offset");
            }
            for (c, &t) in stream.quant.iter().enumerate() {
                assert_eq!(p.quant_at[c], quant + 64 * usize::from(t), "{at}: component {c}");
                let table = &s[p.quant_at[c]..p.quant_at[c] + 64];
                assert_eq!(table, &spec.quant_tables[usize::from(t)][..], "{at}: component {c}");
            }
            assert_eq!((p.dc_table, p.ac_table), (stream.dc, stream.ac), "{at}");
            let bits = jpeg.stream_overhead_bits(k, mip);
            let index_and_dc = 8 * 20 * mcus.div_ceil(9) + mcus * values * 12;
            assert_eq!(bits, (index_and_dc as u64, 8 * stream.data.len() as u64), "{at}");
            total = (total.0 + bits.0, total.1 + bits.1);
            parts.push(p);
        }
    }
    assert_eq!(jpeg.overhead_bits(), total);
    assert!(jpeg.stream_parts(4, 0).is_none() && jpeg.stream_parts(0, 4).is_none());
    assert_eq!((jpeg.mcu_grid(4, 0), jpeg.mcu_grid(0, 4)), ((0, 0), (0, 0)));
    assert_eq!(
        (jpeg.stream_overhead_bits(4, 0), jpeg.stream_overhead_bits(3, 4)),
        ((0, 0), (0, 0))
    );
    let huffman = 8 + 4 * 4 + 3 * 64;
    assert_eq!(
        jpeg.huffman_table(0),
        Some((0, s[huffman + 4..huffman + 20].try_into().unwrap(), huffman + 20))
    );
    let ac_table = (huffman + 20 + 12 + 3) & !3;
    assert_eq!(
        jpeg.huffman_table(1),
        Some((1, s[ac_table + 4..ac_table + 20].try_into().unwrap(), ac_table + 20))
    );
    assert_eq!(jpeg.huffman_table(2), None);

    let parse = |edit: &dyn Fn(&mut [u8])| {
        let mut b = bytes.clone();
        edit(&mut b[at..at + len]);
        refresh_checksum(&mut b);
        Container::parse(&b).map(|_| ()).err()
    };
    let put = |s: &mut [u8], at: usize, v: u64, n: usize| {
        s[at..at + n].copy_from_slice(&v.to_le_bytes()[..n]);
    };
    // The AC table holds 256 symbols, the most; a count of 65535 is refused by name before its
    // symbols are looked for.
    assert_eq!(s[ac_table + 2..ac_table + 4], [0, 1], "256 symbols");
    assert_eq!(
        parse(&|s| put(s, ac_table + 2, 65535, 2)),
        Some(Error::Malformed { field: Field::JpegHuffmanTable, index: 1, value: 65535 })
    );
    // Every stream moved back by 4 bytes starts inside the one before it (the first: inside the
    // stream records).
    let records = jpeg_stream_records(s);
    assert_eq!(parts[0].index_at, records + 20 * 16);
    for (i, p) in parts.iter().enumerate() {
        assert_eq!(
            parse(&|s| put(s, records + 20 * i, p.index_at as u64 - 4, 4)),
            Some(Error::Malformed {
                field: Field::JpegStreamOffset,
                index: i as u32,
                value: p.index_at as i64 - 4
            }),
            "stream {i}"
        );
    }
    // A section that ends inside the stream records.
    let mut cut = bytes.clone();
    let entry = section_entry(&cut, SectionKind::JPEG.0);
    cut[entry + 12..entry + 16].copy_from_slice(&(records as u32 + 20 * 15).to_le_bytes());
    refresh_checksum(&mut cut);
    assert_eq!(
        Container::parse(&cut).err(),
        Some(Error::Truncated {
            field: Field::JpegStream,
            index: 0,
            needed: records as u64 + 20 * 16,
            available: records as u64 + 20 * 15
        })
    );
    // Map 0 at mip 0 (4:2:0, 5 × 3 = 15 MCUs): its second index group (`group1`) holds MCUs
    // 9 … 14, then 3 entries that must be 0.
    let (p, mcu_bits) = (&parts[0], &spec.streams[0].mcu_bits);
    assert_eq!(mcu_bits.len(), 15);
    let group1 = p.index_at + 20;
    let eighth = mcu_bits[8];
    assert_eq!(
        parse(&|s| put(s, group1, eighth - 1, 4)),
        Some(Error::Malformed { field: Field::JpegIndex, index: 0, value: eighth as i64 - 1 }),
        "the second group's base before MCU 8"
    );
    assert_eq!(parse(&|s| put(s, group1, eighth, 4)), None, "the second group's base at MCU 8");
    assert_eq!(
        parse(&|s| put(s, group1 + 4 + 2 * 5, 1, 2)),
        Some(Error::Malformed { field: Field::JpegIndex, index: 0, value: 1 }),
        "MCU 15's entry"
    );
    let end = 8 * p.data_len as u64;
    assert_eq!(
        parse(&|s| put(s, group1 + 4 + 2 * 4, end - u32_of(group1), 2)),
        None,
        "MCU 14 at the very end of the data"
    );
    assert_eq!(
        parse(&|s| {
            put(s, group1, end, 4);
            (0..5).for_each(|j| put(s, group1 + 4 + 2 * j, 0, 2));
        }),
        None,
        "the second group's MCUs all at the end"
    );
    assert_eq!(
        parse(&|s| put(s, group1, end + 1, 4)),
        Some(Error::Malformed { field: Field::JpegIndex, index: 0, value: end as i64 + 1 }),
        "the second group's base past the end"
    );
}

//! Entropy-coded latents (FORMAT.md §12): packing loses nothing, the coder compresses what is
//! compressible and does not inflate what is not, and hostile packed files end in typed errors.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::internals::coded_latents_len;
use nmat_core::{
    Argument, Container, Error, Field, PACKED_VERSION_MINOR, ParseOptions, SectionKind, pack,
    unpack, unpack_into, unpacked_len,
};
use nmat_tests::files::{jpeg_stream_records, refresh_checksum, section, section_entry};
use nmat_tests::generate::{
    FixtureConfig, Layout, Rng, generate, random_config, terms_in_any_order,
};

const NO_CHECKSUM: ParseOptions = ParseOptions { verify_checksum: false };

#[test]
fn random_materials_pack_and_unpack_to_the_same_bytes() {
    // Random materials, and a level of terms in an order the NTC and NBC layouts never write.
    for cfg in (0..300).map(random_config).chain([terms_in_any_order()]) {
        let what = format!("{} seed {}", cfg.name, cfg.seed);
        let spec = generate(&cfg);
        let bytes = spec.to_bytes().unwrap();
        let packed = pack(&bytes).unwrap_or_else(|e| panic!("{what}: {e}"));
        // The encoder's estimate of the coded stream, from the codes alone, is its length.
        let grids: Vec<_> = (spec.grids.iter())
            .map(|g| {
                (g.width.into(), g.height.into(), g.channels.into(), g.bits.into(), &g.codes[..])
            })
            .collect();
        let stream = section(&packed, SectionKind::PACKED_LATENTS.0).1 - 8;
        assert_eq!(coded_latents_len(&grids), stream, "{what}");
        // 2.2, or the file's own minor where it is newer (2.3: a scaled LOD feature, whose
        // header flag the packed file keeps).
        let minor = u16::from_le_bytes([bytes[6], bytes[7]]).max(PACKED_VERSION_MINOR);
        assert_eq!(u16::from_le_bytes([packed[6], packed[7]]), minor, "{what}");
        assert_eq!(packed[8..12], bytes[8..12], "{what}: header flags");
        assert_eq!(unpacked_len(&packed).unwrap(), Some(bytes.len()), "{what}");
        assert_eq!(unpacked_len(&bytes).unwrap(), None);
        assert_eq!(unpack(&packed, ParseOptions::default()).unwrap().as_ref(), &bytes[..]);
        // Caller memory: exactly long enough works (dirty memory is overwritten), shorter is
        // refused by name.
        let mut out = vec![0xA5u8; bytes.len()];
        assert_eq!(unpack_into(&packed, ParseOptions::default(), &mut out), Ok(bytes.len()));
        assert_eq!(out, bytes);
        assert!(matches!(
            unpack_into(&packed, ParseOptions::default(), &mut out[..bytes.len() - 1]),
            Err(Error::BadArgument { argument: Argument::Output, .. })
        ));
        // Parsing a packed file says what to do, with the memory it needs.
        let refusal = Container::parse(&packed).err();
        assert_eq!(
            refusal,
            Some(Error::Unsupported { field: Field::Packed, index: 0, value: bytes.len() as u64 })
        );
        let message = refusal.map(|e| e.to_string()).unwrap_or_default();
        let needs = format!("unpack it first into {} bytes", bytes.len());
        assert!(message.contains("packed .nmat") && message.contains(&needs), "{message}");
        // Packing is idempotent; an unpacked file unpacks to itself without a copy.
        assert_eq!(pack(&packed).unwrap(), packed);
        assert!(matches!(
            unpack(&bytes, ParseOptions::default()),
            Ok(std::borrow::Cow::Borrowed(_))
        ));
    }
}

/// Materials large enough for the coder's fixed costs not to matter, every bit depth.
fn large_configs() -> Vec<FixtureConfig> {
    let ntc = |seed, hi_bits, lo_bits| FixtureConfig {
        layout: Layout::Ntc { hi_channels: 4, lo_channels: 4, hi_bits, lo_bits },
        ..FixtureConfig::ntc("large", seed, 256, 192, 4)
    };
    vec![
        ntc(1, 2, 4),
        ntc(2, 4, 4),
        ntc(3, 8, 8),
        ntc(4, 3, 5),
        FixtureConfig::nbc("nbc", 5, 256, 256, 4),
    ]
}

/// `cfg` with every grid's codes replaced by `code(rng, bits)`, serialized.
fn with_codes(cfg: &FixtureConfig, code: impl Fn(&mut Rng, u8) -> u8) -> Vec<u8> {
    let mut spec = generate(cfg);
    let mut r = Rng::new(cfg.seed ^ 0x5EED);
    for g in &mut spec.grids {
        let bits = g.bits;
        for c in &mut g.codes {
            *c = code(&mut r, bits);
        }
    }
    spec.to_bytes().unwrap()
}

fn latents_ratio(bytes: &[u8]) -> f64 {
    let packed = pack(bytes).unwrap();
    let (_, stream) = section(&packed, SectionKind::PACKED_LATENTS.0);
    let (_, raw) = section(bytes, SectionKind::LATENTS.0);
    stream as f64 / raw as f64
}

#[test]
fn skewed_codes_shrink_and_uniform_codes_do_not_grow() {
    for cfg in large_configs() {
        let bits: Vec<u8> = generate(&cfg).grids.iter().map(|g| g.bits).collect();
        // Codes that are 0 nine times in ten carry 0.47 bits each whatever their depth: grids
        // of 2 bits and more must shrink to well under half (1-bit grids to about 0.5).
        let skewed = latents_ratio(&with_codes(&cfg, |r, _| u8::from(r.unit() < 0.1)));
        let limit = if bits.contains(&1) { 0.6 } else { 0.4 };
        assert!(
            skewed < limit,
            "seed {}: skewed codes at {skewed} of the fixed-rate size",
            cfg.seed
        );
        // Uniform codes have nothing to remove: at most 2 % more than the fixed-rate form (what
        // the adaptive model spends learning that).
        let uniform =
            latents_ratio(&with_codes(&cfg, |r, bits| (r.next_u64() % (1u64 << bits)) as u8));
        assert!(uniform < 1.02, "seed {}: uniform codes grew to {uniform}", cfg.seed);
        assert!(uniform > 0.97, "seed {}: uniform codes cannot shrink to {uniform}", cfg.seed);
    }
}

/// `flips` random one-bit changes of every byte of `packed`, checksum ignored: each ends in an
/// error or in a file that parses or not — never a panic, never more memory than the format's
/// bound (256 × the packed section).
fn flip_every_byte(packed: &[u8], flips: usize, seed: u64) {
    let mut r = Rng::new(seed);
    for i in 0..packed.len() {
        for _ in 0..flips {
            let mut bad = packed.to_vec();
            bad[i] ^= 1 << (r.next_u64() % 8);
            if let Ok(Some(n)) = unpacked_len(&bad) {
                assert!(n <= 256 * (packed.len() + 64) + bad.len(), "byte {i}: {n}");
                let mut out = vec![0; n];
                if let Ok(n) = unpack_into(&bad, NO_CHECKSUM, &mut out) {
                    let _ = Container::parse(&out[..n]);
                }
            }
        }
    }
}

#[test]
fn hostile_packed_files_end_in_typed_errors() {
    let bytes = generate(&random_config(7)).to_bytes().unwrap();
    let packed = pack(&bytes).unwrap();
    let (offset, len) = section(&packed, SectionKind::PACKED_LATENTS.0);
    // Every single-byte change, checksum ignored: an error or a file that parses or not — never
    // a panic, never more memory than the bound.
    flip_every_byte(&packed, 4, 99);
    // A flipped bit is caught by the checksum when it is checked.
    let mut bad = packed.clone();
    bad[offset + 12] ^= 0x10;
    assert!(matches!(unpack(&bad, ParseOptions::default()), Err(Error::ChecksumMismatch { .. })));

    let patch = |f: &dyn Fn(&mut Vec<u8>)| {
        let mut b = packed.clone();
        f(&mut b);
        refresh_checksum(&mut b);
        unpack(&b, ParseOptions::default()).map(|_| ())
    };
    let set_len = |b: &mut Vec<u8>, l: u32| {
        b[32 + 16 * 3 + 12..32 + 16 * 3 + 16].copy_from_slice(&l.to_le_bytes())
    };
    // The stream one byte short, and one byte too long (the next section's padding).
    // The decoder asks for the byte past the stream's `len - 9` (8 header bytes, 1 cut off).
    assert_eq!(
        patch(&|b| set_len(b, len as u32 - 1)),
        Err(Error::Truncated {
            field: Field::PackedStream,
            index: 0,
            needed: len as u64 - 8,
            available: len as u64 - 9
        })
    );
    if len % 4 != 0 {
        assert!(matches!(
            patch(&|b| set_len(b, len as u32 + 1)),
            Err(Error::Malformed { field: Field::PackedStream, .. })
        ));
    }
    // A LATENTS length the stream cannot stand for: refused before any memory is taken.
    let huge = patch(&|b| b[offset..offset + 4].copy_from_slice(&0x7FFF_FFF0u32.to_le_bytes()));
    assert!(matches!(huge, Err(Error::Malformed { field: Field::PackedLength, .. })), "{huge:?}");
    assert!(matches!(
        patch(&|b| b[offset..offset + 4].copy_from_slice(&6u32.to_le_bytes())),
        Err(Error::Malformed { field: Field::PackedLength, value: 6, .. })
    ));
    // Without REQUIRED a reader before 2.2 would skip the latents: refused.
    assert_eq!(
        patch(&|b| b[32 + 16 * 3 + 4] = 0),
        Err(Error::Malformed { field: Field::SectionFlags, index: 3, value: 0 })
    );
    assert!(matches!(
        patch(&|b| b[offset + 4] = 2),
        Err(Error::Unsupported { field: Field::PackedCoder, value: 2, .. })
    ));
    assert!(matches!(
        patch(&|b| b[offset + 5] = 1),
        Err(Error::Malformed { field: Field::PackedReserved, .. })
    ));
    // PACKED_LATENTS beside LATENTS: one or the other.
    // (The MLP entry of the fixed-rate file relabelled PACKED_LATENTS.)
    let mut both = bytes.clone();
    both[32 + 16 * 2..32 + 16 * 2 + 4].copy_from_slice(&6u32.to_le_bytes());
    refresh_checksum(&mut both);
    assert_eq!(
        Container::parse(&both).err(),
        Some(Error::Malformed { field: Field::SectionKind, index: 5, value: 6 })
    );
}

/// A grid record edit: the LEVELS section, the record's offset in it, the LATENTS length.
type RecordEdit = (&'static str, fn(&mut [u8], usize, usize));

/// A packed file whose LEVELS section is broken fails to unpack with the error that parsing the
/// fixed-rate file with the same LEVELS gives (the field at fault, its grid and value), in every
/// grid of the material, before any unpacked byte is returned.
#[test]
fn a_broken_levels_section_is_reported_as_the_parser_reports_it() {
    // The LEVELS section cut to `length` bytes (its table entry's length), in either file.
    let cut_levels = |b: &mut Vec<u8>, length: usize| {
        let e = section_entry(b, SectionKind::LEVELS.0) + 12;
        b[e..e + 4].copy_from_slice(&(length as u32).to_le_bytes());
    };
    let edits: [RecordEdit; 13] = [
        ("width 0", |l, r, _| l[r..r + 2].fill(0)),
        ("height 0", |l, r, _| l[r + 2..r + 4].fill(0)),
        ("width 16385", |l, r, _| l[r..r + 2].copy_from_slice(&16385u16.to_le_bytes())),
        ("channels 0", |l, r, _| l[r + 4] = 0),
        ("channels 17", |l, r, _| l[r + 4] = 17),
        ("bits 0", |l, r, _| l[r + 5] = 0),
        ("bits 9", |l, r, _| l[r + 5] = 9),
        ("reserved 1", |l, r, _| l[r + 7] = 1),
        ("data_offset + 2", |l, r, _| l[r + 8] += 2),
        ("data_offset at the end of LATENTS", |l, r, latents| {
            l[r + 8..r + 12].copy_from_slice(&(latents as u32).to_le_bytes())
        }),
        ("data_offset past 4 GiB", |l, r, _| l[r + 8..r + 12].fill(0xFC)),
        ("data_length + 4", |l, r, _| l[r + 12] = l[r + 12].wrapping_add(4)),
        ("data_length 0", |l, r, _| l[r + 12..r + 16].fill(0)),
    ];
    let mut compared = 0;
    for seed in 0..12 {
        let bytes = generate(&random_config(seed)).to_bytes().unwrap();
        let packed = pack(&bytes).unwrap();
        let (levels_at, levels_len) = section(&bytes, SectionKind::LEVELS.0);
        let (packed_levels_at, _) = section(&packed, SectionKind::LEVELS.0);
        let latents_len = section(&bytes, SectionKind::LATENTS.0).1;
        // Applies `edit` to the LEVELS section of both files and compares the errors.
        let check = |what: &str, edit: &dyn Fn(&mut Vec<u8>, usize)| {
            let mut fixed = bytes.clone();
            edit(&mut fixed, levels_at);
            refresh_checksum(&mut fixed);
            let mut edited = packed.clone();
            edit(&mut edited, packed_levels_at);
            refresh_checksum(&mut edited);
            let expected = Container::parse(&fixed).err();
            assert!(expected.is_some(), "seed {seed}, {what}: the parser accepts it");
            assert_eq!(
                unpack(&edited, ParseOptions::default()).err(),
                expected,
                "seed {seed}, {what}"
            );
        };
        let levels = &bytes[levels_at..levels_at + levels_len];
        let mut record = 20;
        for g in 0..usize::from(levels[1]) {
            for (name, edit) in edits {
                check(&format!("grid {g}: {name}"), &|b, at| {
                    edit(&mut b[at..], record, latents_len)
                });
                compared += 1;
            }
            // LEVELS ending inside this record.
            check(&format!("grid {g}: LEVELS cut inside the record"), &|b, _| {
                cut_levels(b, record + 15)
            });
            record += 16 + 4 * usize::from(levels[record + 4]);
        }
        let counts: [RecordEdit; 4] = [
            ("grid_count 0", |l, _, _| l[1] = 0),
            ("grid_count 17", |l, _, _| l[1] = 17),
            ("level_count 0", |l, _, _| l[0] = 0),
            ("level_count 17", |l, _, _| l[0] = 17),
        ];
        for (name, edit) in counts {
            check(name, &|b, at| edit(&mut b[at..], 0, latents_len));
        }
        check("LEVELS of 19 bytes", &|b, _| cut_levels(b, 19));
    }
    assert!(compared > 12 * 13, "{compared} grid edits");
    // What the errors are, on one material (the comparison above holds unpacking to the parser).
    let bytes = generate(&random_config(0)).to_bytes().unwrap();
    let packed = pack(&bytes).unwrap();
    let (at, _) = section(&packed, SectionKind::LEVELS.0);
    let unpack_with = |edit: &dyn Fn(&mut Vec<u8>)| {
        let mut b = packed.clone();
        edit(&mut b);
        refresh_checksum(&mut b);
        unpack(&b, ParseOptions::default()).err()
    };
    assert_eq!(
        unpack_with(&|b| b[at + 1] = 0),
        Some(Error::Malformed { field: Field::GridCount, index: 0, value: 0 })
    );
    assert_eq!(
        unpack_with(&|b| b[at + 20 + 4] = 0),
        Some(Error::Malformed { field: Field::GridChannels, index: 0, value: 0 })
    );
    assert_eq!(
        unpack_with(&|b| b[at + 20 + 5] = 9),
        Some(Error::Malformed { field: Field::GridBits, index: 0, value: 9 })
    );
}

/// The committed indexed-JPEG fixture (4:2:0, a restart marker after every MCU row) and its
/// packed twin.
fn jpeg_fixture(name: &str) -> Vec<u8> {
    std::fs::read(format!("{}/fixtures/jpeg/{name}", env!("CARGO_MANIFEST_DIR"))).unwrap()
}

#[test]
fn a_jpeg_material_packs_without_its_index_and_unpacks_to_the_same_bytes() {
    let bytes = jpeg_fixture("pattern_420_37x21.nmat");
    let packed = pack(&bytes).unwrap();
    assert!(packed.len() < bytes.len());
    let (_, body) = section(&packed, SectionKind::PACKED_JPEG.0);
    let (_, indexed) = section(&bytes, SectionKind::JPEG.0);
    // 6 MCUs: one index group of 20 bytes and 18 DC values of 12 bits (27 bytes, padded to 28)
    // are gone, 8 header bytes came.
    assert_eq!(indexed - body, 20 + 28 - 8);
    assert_eq!(unpack(&packed, ParseOptions::default()).unwrap().as_ref(), &bytes[..]);
    assert_eq!(packed, jpeg_fixture("pattern_420_37x21.packed.nmat"), "the committed twin");
    assert_eq!(
        Container::parse(&packed).err(),
        Some(Error::Unsupported { field: Field::Packed, index: 0, value: bytes.len() as u64 })
    );
}

/// A JPEG material of four maps and four mips (`nmat_tests::generate_jpeg`: streams of 1 to 45
/// MCUs, no restart markers) packs to what the reference packer written from FORMAT.md §12.5
/// writes, and each unpacks the other's packed file to the fixed-rate bytes.
#[test]
fn a_jpeg_material_of_several_maps_and_mips_packs_like_the_reference() {
    use nmat_tests::files::assert_same_bytes;
    use nmat_tests::reference_packed_jpeg;
    for seed in 0..4 {
        let bytes = nmat_tests::generate_jpeg::DcJpegMaterial::new(seed).spec.to_bytes().unwrap();
        let packed = pack(&bytes).unwrap();
        let reference = reference_packed_jpeg::pack(&bytes).unwrap();
        assert_same_bytes(&format!("seed {seed}: pack"), &packed, &reference);
        let unpacked = unpack(&packed, ParseOptions::default()).unwrap();
        assert_same_bytes(&format!("seed {seed}: unpack"), &unpacked, &bytes);
        let by_reference = reference_packed_jpeg::unpack(&packed).unwrap();
        assert_same_bytes(&format!("seed {seed}: reference unpack"), &by_reference, &bytes);
    }
}

/// A stream whose last MCU starts exactly at the end of its data (a restart after every MCU,
/// the last MCU all zero bits: DC difference 0 and end-of-block, which bits past the end read
/// as) packs as the reference packer packs it and unpacks to the same bytes (§12.5 refuses only
/// an MCU that would start past the data); one bit further, the fixed-rate file is refused.
#[test]
fn a_last_mcu_at_the_very_end_of_its_data_packs() {
    use nmat_core::{
        AddressMode, ChannelSpec, ColorSpace, HuffmanTableSpec, JpegMap, JpegMaterialSpec,
        JpegStreamSpec, Semantic,
    };
    use nmat_tests::reference_packed_jpeg;
    let mut dc_counts = [0u8; 16];
    dc_counts[3] = 12; // DC sizes 0 … 11 as 4-bit codes
    let mut ac_counts = [0u8; 16];
    ac_counts[0] = 1; // end-of-block is `0`
    // 16 × 8 gray: two 8 × 8 MCUs. MCU 0: size 2 (`0010`), difference 3 (`11`), end-of-block
    // (`0`), padded with a 1 bit to the restart: 0x2D. MCU 1 starts at bit 8, the end.
    let material = |second_mcu_at: u64| JpegMaterialSpec {
        width: 16,
        height: 8,
        mip_count: 1,
        address_mode: AddressMode::Wrap,
        channels: vec![ChannelSpec {
            name: "height".to_string(),
            semantic: Semantic::HEIGHT,
            component: 0,
            color_space: ColorSpace::Linear,
            range_min: 0.0,
            range_max: 1.0,
        }],
        maps: vec![JpegMap { first_channel: 0, channel_count: 1, luma_h: 1, luma_v: 1 }],
        quant_tables: vec![[4; 64]],
        huffman_tables: vec![
            HuffmanTableSpec { class: 0, counts: dc_counts, values: (0..12).collect() },
            HuffmanTableSpec { class: 1, counts: ac_counts, values: vec![0] },
        ],
        streams: vec![JpegStreamSpec {
            quant: [0; 3],
            dc: [0; 3],
            ac: [1, 0, 0],
            mcu_bits: vec![0, second_mcu_at],
            dcs: vec![3, 0],
            data: vec![0x2D],
        }],
        optional_sections: vec![],
    };
    let fixed = material(8).to_bytes().unwrap();
    let m = Container::parse(&fixed).unwrap();
    let mut codes = [0u8; 1];
    m.decode_texel_u8(0, 0, 0, nmat_core::ChannelMask::ALL, &mut codes).unwrap();
    assert_eq!(codes[0], 128 + (3 * 4 + 4) / 8, "MCU 0: DC 3 · 4");
    m.decode_texel_u8(15, 7, 0, nmat_core::ChannelMask::ALL, &mut codes).unwrap();
    assert_eq!(codes[0], 128, "MCU 1: DC 0 after the restart");
    let packed = pack(&fixed).unwrap();
    assert_eq!(packed, reference_packed_jpeg::pack(&fixed).unwrap(), "as the reference packs");
    assert_eq!(unpack(&packed, ParseOptions::default()).unwrap().as_ref(), &fixed[..]);
    // An MCU past the data: the fixed-rate file is refused, so nothing can be packed.
    assert_eq!(
        material(9).to_bytes().err(),
        Some(Error::Malformed { field: Field::JpegIndex, index: 0, value: 9 })
    );
}

#[test]
fn hostile_packed_jpeg_files_end_in_typed_errors() {
    let packed = jpeg_fixture("pattern_420_37x21.packed.nmat");
    let (offset, _) = section(&packed, SectionKind::PACKED_JPEG.0);
    flip_every_byte(&packed, 8, 5);
    let patch = |f: &dyn Fn(&mut Vec<u8>)| {
        let mut b = packed.clone();
        f(&mut b);
        refresh_checksum(&mut b);
        unpack(&b, ParseOptions::default()).map(|_| ())
    };
    // A length other than the streams give, the latents' coder, a restart interval that puts an
    // MCU past the data.
    assert!(matches!(
        patch(&|b| {
            let l = u32::from_le_bytes(b[offset..offset + 4].try_into().unwrap());
            b[offset..offset + 4].copy_from_slice(&(l + 4).to_le_bytes());
        }),
        Err(Error::Malformed { field: Field::PackedLength, .. })
    ));
    assert!(matches!(
        patch(&|b| b[offset + 4] = 1),
        Err(Error::Unsupported { field: Field::PackedCoder, value: 1, .. })
    ));
    // Another restart interval walks the stream differently: a different index (or an error),
    // never the original material's.
    let restarted = |v: u16| {
        let mut b = packed.clone();
        let body = offset + 8;
        let records = body + jpeg_stream_records(&b[body..]);
        b[records + 18..records + 20].copy_from_slice(&v.to_le_bytes());
        refresh_checksum(&mut b);
        unpack(&b, ParseOptions::default()).map(|u| u.into_owned())
    };
    let original = jpeg_fixture("pattern_420_37x21.nmat");
    assert_eq!(restarted(3).unwrap(), original, "the fixture's own interval");
    for v in [0, 1, 2, 4, 5, u16::MAX] {
        assert!(restarted(v).map_or(true, |u| u != original), "restart interval {v}");
    }
}

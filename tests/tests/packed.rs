//! Entropy-coded latents (FORMAT.md §12): packing loses nothing, the coder compresses what is
//! compressible and does not inflate what is not, and hostile packed files end in typed errors.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::{
    Argument, Container, Error, Field, PACKED_VERSION_MINOR, ParseOptions, SectionKind, pack,
    unpack, unpack_into, unpacked_len,
};
use nmat_tests::files::{jpeg_stream_records, refresh_checksum, section};
use nmat_tests::generate::{
    FixtureConfig, Layout, Rng, generate, random_config, terms_in_any_order,
};

const NO_CHECKSUM: ParseOptions = ParseOptions { verify_checksum: false };

#[test]
fn random_materials_pack_and_unpack_to_the_same_bytes() {
    // Random materials, and a level of terms in an order the NTC and NBC layouts never write.
    for cfg in (0..300).map(random_config).chain([terms_in_any_order()]) {
        let what = format!("{} seed {}", cfg.name, cfg.seed);
        let bytes = generate(&cfg).to_bytes().unwrap();
        let packed = pack(&bytes).unwrap_or_else(|e| panic!("{what}: {e}"));
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
        assert_eq!(
            Container::parse(&packed).err(),
            Some(Error::Unsupported { field: Field::Packed, index: 0, value: bytes.len() as u64 })
        );
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
    assert!(matches!(
        patch(&|b| set_len(b, len as u32 - 1)),
        Err(Error::Truncated { field: Field::PackedStream, .. })
    ));
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

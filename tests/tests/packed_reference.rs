//! nmat-core's `pack`/`unpack` against `nmat_tests::reference_packed`, a second implementation of
//! FORMAT.md §12 written from the text: byte-identical packed files, and each unpacks the other's.

#![allow(clippy::unwrap_used)]

use nmat_core::{MaterialSpec, ParseOptions};
use nmat_tests::files::{assert_same_bytes, refresh_checksum};
use nmat_tests::generate::{FixtureConfig, Layout, Rng, generate, random_config};
use nmat_tests::reference_packed;

/// On one fixed-rate file: both packers write the same bytes, the reference unpacks nmat-core's
/// packed file and nmat-core the reference's, each to the input. Returns the packed file.
fn compare(what: &str, bytes: &[u8]) -> Vec<u8> {
    let theirs = nmat_core::pack(bytes).unwrap_or_else(|e| panic!("{what}: nmat_core::pack: {e}"));
    let mine = reference_packed::pack(bytes)
        .unwrap_or_else(|e| panic!("{what}: reference_packed::pack: {e}"));
    assert_same_bytes(&format!("{what}: pack, reference vs nmat-core"), &mine, &theirs);

    let unpacked_by_reference = reference_packed::unpack(&theirs)
        .unwrap_or_else(|e| panic!("{what}: reference_packed::unpack: {e}"));
    assert_same_bytes(
        &format!("{what}: reference unpack of nmat-core's pack"),
        &unpacked_by_reference,
        bytes,
    );

    let unpacked_by_core = nmat_core::unpack(&mine, ParseOptions::default())
        .unwrap_or_else(|e| panic!("{what}: nmat_core::unpack: {e}"));
    assert_same_bytes(
        &format!("{what}: nmat-core unpack of the reference's pack"),
        &unpacked_by_core,
        bytes,
    );
    mine
}

fn bytes_of(spec: &MaterialSpec) -> Vec<u8> {
    spec.to_bytes().unwrap()
}

#[test]
fn random_materials_pack_identically() {
    for seed in 0..200 {
        let bytes = bytes_of(&generate(&random_config(seed)));
        compare(&format!("seed {seed}"), &bytes);
    }
}

/// Every code 0 with probability 0.9, else uniform: long runs of likely decisions (p near 4065),
/// which is where the range encoder holds back 0xFF bytes and carries into them.
fn skew_codes(spec: &mut MaterialSpec, seed: u64) {
    let mut rng = Rng::new(seed);
    for grid in &mut spec.grids {
        let max = (1i64 << grid.bits) - 1;
        for code in &mut grid.codes {
            *code = if rng.unit() < 0.9 { 0 } else { rng.range(0, max) as u8 };
        }
    }
}

fn uniform_codes(spec: &mut MaterialSpec, seed: u64) {
    let mut rng = Rng::new(seed);
    for grid in &mut spec.grids {
        let max = (1i64 << grid.bits) - 1;
        for code in &mut grid.codes {
            *code = rng.range(0, max) as u8;
        }
    }
}

fn larger_configs() -> Vec<FixtureConfig> {
    vec![
        FixtureConfig {
            layout: Layout::Ntc { hi_channels: 4, lo_channels: 4, hi_bits: 4, lo_bits: 8 },
            ..FixtureConfig::ntc("big", 1, 256, 192, 4)
        },
        FixtureConfig::nbc("nbc", 5, 256, 256, 4),
        FixtureConfig {
            layout: Layout::Nbc { channels: 3, bits_coarse_to_fine: vec![1, 2, 3, 5, 7] },
            ..FixtureConfig::nbc("nbc-odd", 9, 300, 200, 3)
        },
    ]
}

#[test]
fn larger_materials_pack_identically() {
    let mut carries = 0;
    for cfg in larger_configs() {
        let generated = generate(&cfg);
        compare(&format!("{} as generated", cfg.name), &bytes_of(&generated));

        let mut skewed = generated.clone();
        skew_codes(&mut skewed, cfg.seed);
        let bytes = bytes_of(&skewed);
        compare(&format!("{} skewed", cfg.name), &bytes);
        carries += reference_packed::pack_counting_carries(&bytes).unwrap().1;

        let mut uniform = generated.clone();
        uniform_codes(&mut uniform, cfg.seed + 1);
        let bytes = bytes_of(&uniform);
        compare(&format!("{} uniform", cfg.name), &bytes);
        carries += reference_packed::pack_counting_carries(&bytes).unwrap().1;
    }
    // The comparisons above went through the carry path of the encoder, not only around it.
    assert!(carries > 0, "no carry was propagated: the carry path is untested");
}

/// Optional sections keep their place and flags; an odd length exercises the zero padding.
#[test]
fn optional_sections_keep_their_place() {
    for seed in [3, 4] {
        let mut spec = generate(&random_config(seed));
        spec.optional_sections = vec![(0x7E57_0001, vec![1, 2, 3, 4, 5]), (0x7E57_0002, vec![9])];
        compare(&format!("seed {seed} with optional sections"), &bytes_of(&spec));
    }
}

/// A material of one grid, from the NBC layout with a single level.
fn one_grid(width: u32, height: u32, channels: u8, bits: u8) -> MaterialSpec {
    let cfg = FixtureConfig {
        layout: Layout::Nbc { channels, bits_coarse_to_fine: vec![bits] },
        ..FixtureConfig::nbc("one-grid", 7, width, height, 1)
    };
    let spec = generate(&cfg);
    assert_eq!(spec.grids.len(), 1);
    spec
}

/// The stream of a packed file written by `pack` (the section table's last entry is
/// PACKED_LATENTS; its payload is 8 bytes of fields, then the stream).
fn stream_of(packed: &[u8]) -> &[u8] {
    let (offset, length) = last_section(packed);
    assert_eq!(u32le(packed, 32 + 16 * (section_count(packed) - 1)), 6);
    &packed[offset + 8..offset + length]
}

fn u32le(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn section_count(b: &[u8]) -> usize {
    u32le(b, 16) as usize
}

fn last_section(b: &[u8]) -> (usize, usize) {
    let entry = 32 + 16 * (section_count(b) - 1);
    (u32le(b, entry + 8) as usize, u32le(b, entry + 12) as usize)
}

/// One cell, one channel, one bit: a single decision with p = 2048, worked by hand from §12.3.
/// `range = 0xFFFFFFFF`, `bound = (range >> 12) · 2048 = 0xFFFFF · 0x800 = 0x7FFFF800`, and
/// `range` stays ≥ 2^24 either way, so there is no renormalization; the five flush shifts emit
/// the initial cache byte 0 (not written) and the four bytes of `low`, big-endian.
/// - code 0: `low = 0` → stream `00 00 00 00` (the decoder's `code = 0 < bound` gives 0);
/// - code 1: `low = bound` → stream `7F FF F8 00` (`code = bound`, not `< bound`, gives 1). Its
///   `FF` is held back by the encoder until the `F8` after it shows no carry can reach it.
#[test]
fn one_decision_by_hand() {
    for (code, stream) in [(0u8, [0u8, 0, 0, 0]), (1, [0x7F, 0xFF, 0xF8, 0x00])] {
        let mut spec = one_grid(4, 4, 1, 1);
        assert_eq!((spec.grids[0].width, spec.grids[0].height), (1, 1));
        spec.grids[0].codes = vec![code];
        let packed = compare(&format!("one decision, code {code}"), &bytes_of(&spec));
        assert_eq!(stream_of(&packed), stream, "code {code}");
        // latents_length: one 1-bit code takes one u32 word; coder 1; reserved 0; minor 0.
        let (offset, _) = last_section(&packed);
        assert_eq!(packed[offset..offset + 8], [4, 0, 0, 0, 1, 0, 0, 0]);
    }
}

/// §12.2's model cost, in bits, of `n` decisions of 0 in one fresh context:
/// `Σ −log2(p_i / 4096)` with `p_0 = 2048`, `p_{i+1} = p_i + ((4096 − p_i) >> 5)`.
fn zeros_cost(n: usize) -> f64 {
    let mut p = 2048u32;
    let mut bits = 0.0;
    for _ in 0..n {
        bits -= (f64::from(p) / 4096.0).log2();
        p += (4096 - p) >> 5;
    }
    bits
}

/// A 64×64 grid of 4 channels of 8 bits, every code 0: 131 072 decisions, 16 KiB fixed-rate.
///
/// Each code 0 walks nodes 1, 2, 4, …, 128 (eight contexts per neighbour-class pair), always
/// coding 0. Per channel, the class pair is (4, 4) at (0, 0), (0, 4) along y = 0, (4, 0) along
/// x = 0 and (0, 0) for the 63 × 63 others, so the model's cost of a channel is
/// `8 · (C(1) + 2 · C(63) + C(3969))` with `C` = [`zeros_cost`] — about 970 bits. The coder pays
/// at most that, plus < 2^-12 relative per decision for `(range >> 12) · p` rounding down
/// (≤ 0.00036 bit each), plus the 4 flush bytes. And no stream can be shorter than §12.3's floor:
/// a decision costs at least −log2(4065/4096) ≈ 0.011 bits, so ≥ 131 072 · 0.011 / 8 ≈ 179 bytes
/// (less the 4 bytes the decoder reads ahead).
#[test]
fn all_zero_grid_is_short() {
    let mut spec = one_grid(256, 256, 4, 8);
    let grid = &mut spec.grids[0];
    assert_eq!((grid.width, grid.height, grid.channels, grid.bits), (64, 64, 4, 8));
    grid.codes.iter_mut().for_each(|c| *c = 0);
    let decisions = 64 * 64 * 4 * 8;

    let packed = compare("all-zero 64x64x4x8", &bytes_of(&spec));
    let stream_bits = 8.0 * stream_of(&packed).len() as f64;

    let model = 4.0 * 8.0 * (zeros_cost(1) + 2.0 * zeros_cost(63) + zeros_cost(63 * 63));
    let floor = decisions as f64 * -(4065.0f64 / 4096.0).log2();
    assert!(
        stream_bits <= model + decisions as f64 * 0.00036 + 32.0 + 8.0,
        "{stream_bits} bits, model cost {model:.1}"
    );
    assert!(stream_bits + 32.0 >= floor, "{stream_bits} bits, below the floor {floor:.1}");
    // Against the 16 384 fixed-rate bytes: about 3 %.
    assert!(stream_bits / 8.0 < 600.0, "{stream_bits} bits");
}

/// Rewrites the payload of the last section (PACKED_LATENTS, as `pack` lays files out), keeping
/// the file consistent: section length, zero padding, `file_length`, checksum.
fn with_packed_payload(packed: &[u8], edit: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let (offset, length) = last_section(packed);
    let entry = 32 + 16 * (section_count(packed) - 1);
    let mut payload = packed[offset..offset + length].to_vec();
    edit(&mut payload);
    let mut out = packed[..offset].to_vec();
    out.extend_from_slice(&payload);
    out.resize(out.len().div_ceil(4) * 4, 0);
    out[entry + 12..entry + 16].copy_from_slice(&(payload.len() as u32).to_le_bytes());
    let file_length = out.len() as u32;
    out[12..16].copy_from_slice(&file_length.to_le_bytes());
    out[20..24].fill(0);
    let crc = nmat_core::internals::file_checksum(&out);
    out[20..24].copy_from_slice(&crc.to_le_bytes());
    out
}

/// Edited packed files: both implementations accept the same ones (with the same unpacked bytes)
/// and refuse the same ones.
#[test]
fn edited_packed_files_agree() {
    type Edit = (&'static str, fn(&mut Vec<u8>));
    let edits: [Edit; 13] = [
        ("stream byte 0 flipped", |p| p[8] ^= 0x80),
        ("middle stream byte flipped", |p| {
            let i = 8 + (p.len() - 8) / 2;
            p[i] ^= 0x11;
        }),
        ("last stream byte flipped", |p| *p.last_mut().unwrap() ^= 0x01),
        ("last stream byte dropped", |p| {
            p.pop();
        }),
        ("a byte appended", |p| p.push(0)),
        ("latents_length + 4", |p| {
            let n = u32::from_le_bytes(p[0..4].try_into().unwrap()) + 4;
            p[0..4].copy_from_slice(&n.to_le_bytes());
        }),
        ("latents_length - 4", |p| {
            let n = u32::from_le_bytes(p[0..4].try_into().unwrap()) - 4;
            p[0..4].copy_from_slice(&n.to_le_bytes());
        }),
        ("latents_length + 2", |p| {
            let n = u32::from_le_bytes(p[0..4].try_into().unwrap()) + 2;
            p[0..4].copy_from_slice(&n.to_le_bytes());
        }),
        // §12.1's bound, 256 · (stream length + 64), the stream being the payload after 8 bytes.
        ("latents_length at the bound", |p| {
            let n = 256 * (p.len() as u32 - 8 + 64);
            p[0..4].copy_from_slice(&n.to_le_bytes());
        }),
        ("latents_length 4 over the bound", |p| {
            let n = 256 * (p.len() as u32 - 8 + 64) + 4;
            p[0..4].copy_from_slice(&n.to_le_bytes());
        }),
        ("coder 2", |p| p[4] = 2),
        ("reserved 1", |p| p[5] = 1),
        ("unpacked_minor 7", |p| p[6] = 7),
    ];
    let mut accepted = [0; 13];
    for seed in 0..20 {
        let bytes = bytes_of(&generate(&random_config(seed)));
        let packed = reference_packed::pack(&bytes).unwrap();
        for (i, (name, edit)) in edits.into_iter().enumerate() {
            let edited = with_packed_payload(&packed, edit);
            let core = nmat_core::unpack(&edited, ParseOptions::default());
            let reference = reference_packed::unpack(&edited);
            match (core, reference) {
                (Ok(a), Ok(b)) => {
                    assert_same_bytes(&format!("seed {seed}, {name}"), &b, &a);
                    accepted[i] += 1;
                    if name == "last stream byte flipped" {
                        assert_same_bytes(&format!("seed {seed}, {name}"), &a, &bytes);
                    }
                }
                (Err(_), Err(_)) => {}
                (Ok(_), Err(e)) => panic!("seed {seed}, {name}: nmat-core accepts, reference: {e}"),
                (Err(e), Ok(_)) => panic!("seed {seed}, {name}: reference accepts, nmat-core: {e}"),
            }
        }
    }
    // A longer LATENTS (zero tail) and another unpacked_minor give valid files on every seed. So
    // does flipping the lowest bit of the stream's last byte: the flush writes all of `low`, more
    // precision than the decoder needs to land in the final interval, so the codes do not change.
    let always: Vec<_> =
        edits.iter().zip(accepted).filter(|(_, n)| *n == 20).map(|(e, _)| e.0).collect();
    assert_eq!(
        always,
        [
            "last stream byte flipped",
            "latents_length + 4",
            "latents_length at the bound",
            "unpacked_minor 7"
        ]
    );
}

/// Fixed-rate files off the writer's beaten path: both packers accept the same ones (with the same
/// bytes) and refuse the same ones. §12 keeps flags and `version_minor` through packing; a file
/// whose layout or spare bits an unpacked file cannot reproduce cannot be packed losslessly.
#[test]
fn unusual_fixed_rate_inputs_agree() {
    let bytes = bytes_of(&generate(&random_config(1)));
    let latents_entry = 32 + 16 * 3;
    assert_eq!(u32le(&bytes, latents_entry), 4);
    let latents_end =
        (u32le(&bytes, latents_entry + 8) + u32le(&bytes, latents_entry + 12)) as usize;

    type Edit = (&'static str, fn(&mut Vec<u8>, usize));
    let edits: [Edit; 5] = [
        ("LATENTS without REQUIRED", |b, _| b[32 + 16 * 3 + 4] = 0),
        ("version_minor 5", |b, _| b[6] = 5),
        ("version_minor 2", |b, _| b[6] = 2),
        ("table order not file order", |b, _| {
            let first: [u8; 16] = b[32..48].try_into().unwrap();
            b.copy_within(48..64, 32);
            b[48..64].copy_from_slice(&first);
        }),
        ("an unused high bit of the last latent word set", |b, end| b[end - 1] |= 0x80),
    ];
    for (name, edit) in edits {
        let mut edited = bytes.clone();
        edit(&mut edited, latents_end);
        refresh_checksum(&mut edited);
        assert!(nmat_core::Container::parse(&edited).is_ok(), "{name}: a valid fixed-rate file");
        match (nmat_core::pack(&edited), reference_packed::pack(&edited)) {
            (Ok(theirs), Ok(mine)) => {
                assert_same_bytes(name, &mine, &theirs);
                compare(name, &edited);
            }
            (Err(_), Err(_)) => {}
            (Ok(_), Err(e)) => panic!("{name}: nmat-core packs, reference: {e}"),
            (Err(e), Ok(_)) => panic!("{name}: reference packs, nmat-core: {e}"),
        }
    }
}

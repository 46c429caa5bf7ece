//! nmat-core's `pack`/`unpack` of JPEG materials against `nmat_tests::reference_packed_jpeg`, a
//! second implementation of FORMAT.md §12.5 (PACKED_JPEG) written from the text: byte-identical
//! packed files, each unpacks the other's to the fixed-rate input, and edited packed files are
//! accepted by both with the same result or refused by both.

#![allow(clippy::unwrap_used)]

mod common;

use common::MODES;

use jpeg_encoder::SamplingFactor;
use nmat_core::{Container, ParseOptions};
use nmat_encode::Storage;
use nmat_encode::jpeg::{JpegOptions, Subsampling, encode_jpeg, index_jpeg, material_from_jpeg};
use nmat_tests::files::{assert_same_bytes, jpeg_stream_records, refresh_checksum, section};
use nmat_tests::generate::Rng;
use nmat_tests::generate_jpeg::BitWriter;
use nmat_tests::reference_packed_jpeg;

fn core_unpack(bytes: &[u8]) -> Result<Vec<u8>, nmat_core::Error> {
    nmat_core::unpack(bytes, ParseOptions::default()).map(|u| u.into_owned())
}

/// On one fixed-rate JPEG file: both packers write the same bytes, the reference unpacks
/// nmat-core's packed file and nmat-core the reference's, each to the input. Returns the packed
/// file.
fn compare(what: &str, fixed: &[u8]) -> Vec<u8> {
    let theirs = nmat_core::pack(fixed).unwrap_or_else(|e| panic!("{what}: nmat_core::pack: {e}"));
    let mine = reference_packed_jpeg::pack(fixed)
        .unwrap_or_else(|e| panic!("{what}: reference_packed_jpeg::pack: {e}"));
    assert_same_bytes(&format!("{what}: pack, reference vs nmat-core"), &mine, &theirs);
    assert!(mine.len() < fixed.len(), "{what}: packed {} vs {}", mine.len(), fixed.len());

    let by_reference = reference_packed_jpeg::unpack(&theirs)
        .unwrap_or_else(|e| panic!("{what}: reference_packed_jpeg::unpack: {e}"));
    assert_same_bytes(
        &format!("{what}: reference unpack of nmat-core's pack"),
        &by_reference,
        fixed,
    );

    let by_core = core_unpack(&mine).unwrap_or_else(|e| panic!("{what}: nmat_core::unpack: {e}"));
    assert_same_bytes(
        &format!("{what}: nmat-core unpack of the reference's pack"),
        &by_core,
        fixed,
    );
    mine
}

fn jpeg_fixture(name: &str) -> Vec<u8> {
    std::fs::read(nmat_tests::fixtures_dir().join("jpeg").join(name)).unwrap()
}

#[test]
fn the_committed_fixture_and_its_packed_twin() {
    let fixed = jpeg_fixture("pattern_420_37x21.nmat");
    let twin = jpeg_fixture("pattern_420_37x21.packed.nmat");
    assert_same_bytes(
        "reference pack of the fixture",
        &reference_packed_jpeg::pack(&fixed).unwrap(),
        &twin,
    );
    assert_same_bytes(
        "reference unpack of the twin",
        &reference_packed_jpeg::unpack(&twin).unwrap(),
        &fixed,
    );
    let mine = reference_packed_jpeg::pack(&fixed).unwrap();
    assert_same_bytes(
        "nmat-core unpack of the reference's pack",
        &core_unpack(&mine).unwrap(),
        &fixed,
    );
    compare("fixture", &fixed);
}

// ---------------------------------------------------------------------------------------------
// Generated materials
// ---------------------------------------------------------------------------------------------

fn jpeg_file(
    (w, h): (u32, u32),
    components: usize,
    sampling: SamplingFactor,
    quality: u8,
    restart: u16,
) -> Vec<u8> {
    common::jpeg(w, h, components, sampling, quality, restart)
}

/// The fixed-rate material `nmat index` makes of a JPEG file.
fn indexed_material(file: &[u8]) -> Vec<u8> {
    material_from_jpeg(&index_jpeg(file).unwrap(), "test.png").to_bytes().unwrap()
}

const SIZES: [(u32, u32); 9] =
    [(1, 1), (7, 5), (8, 8), (17, 9), (16, 48), (33, 47), (64, 64), (100, 37), (130, 71)];

#[test]
fn indexed_jpeg_files_pack_identically() {
    let mut restarted = 0;
    for size in SIZES {
        for (components, sampling, name) in MODES {
            for (quality, restart) in
                [(20, 0), (75, 0), (97, 0), (40, 1), (75, 2), (90, 5), (60, 64)]
            {
                let what = format!("{}×{} {name} q{quality} restart {restart}", size.0, size.1);
                let fixed =
                    indexed_material(&jpeg_file(size, components, sampling, quality, restart));
                let packed = compare(&what, &fixed);
                restarted += usize::from(has_restart_interval(&packed));
            }
        }
    }
    // The restart cases must have exercised the interval search, not only interval 0.
    assert!(restarted > 80, "{restarted} packed files with a restart interval");
}

/// Several maps (gray and colour), several mips, down to 1×1.
#[test]
fn encoded_multi_map_materials_pack_identically() {
    for (size, quality, subsampling) in [
        (64, 85, Subsampling::S420),
        (64, 30, Subsampling::S444),
        (64, 95, Subsampling::S422),
        (48, 60, Subsampling::S420),
        (37, 75, Subsampling::S422),
    ] {
        let what = format!("bricks({size}) q{quality} {subsampling:?}");
        let options =
            JpegOptions { quality, subsampling, storage: Storage::FixedRate, ..Default::default() };
        let encoded = encode_jpeg(&nmat_encode::demo::bricks(size), &options).unwrap();
        let fixed = &encoded.bytes;
        let m = Container::parse(fixed).unwrap();
        assert!(m.mip_count() > 1, "{what}: {} mips", m.mip_count());
        drop(m);
        compare(&what, fixed);
    }
}

// ---------------------------------------------------------------------------------------------
// Edited packed files
// ---------------------------------------------------------------------------------------------

/// Where the stream records of a packed file are, and how many there are.
fn stream_records(packed: &[u8]) -> (usize, usize) {
    let (offset, _) = section(packed, 7);
    let body = offset + 8;
    let records = body + jpeg_stream_records(&packed[body..]);
    let first_stream =
        u32::from_le_bytes(packed[records..records + 4].try_into().unwrap()) as usize;
    (records, (body + first_stream - records) / 20)
}

fn has_restart_interval(packed: &[u8]) -> bool {
    let (records, count) = stream_records(packed);
    (0..count).any(|s| packed[records + 20 * s + 18] != 0 || packed[records + 20 * s + 19] != 0)
}

/// What one unpacker made of an edited file: its unpacked bytes, or why it refused.
type Outcome = Result<Vec<u8>, String>;

/// Whether the file opens: unpacked, and the result parses (`Container::parse`, which checks
/// everything §1–§11 ask of a fixed-rate file).
fn opens(outcome: &Outcome) -> bool {
    outcome.as_ref().is_ok_and(|b| Container::parse(b).is_ok())
}

/// Runs every edit through both unpackers and fails listing the disagreements: a file that opens
/// after one unpacker and not after the other, or opens after both with different bytes.
///
/// Where exactly a bad file is refused may differ — nmat-core's unpacking also checks what its
/// parser would (e.g. channel names) and hands back a file without a packed section as it is,
/// the reference checks §11.1 while unpacking but not the rest of the MATERIAL section — so a
/// refusal by one unpacker and a result the parser refuses from the other count as agreement (the
/// file does not open either way); they are counted, and listed with `NMAT_JREF_DEBUG=1`. Two
/// unpacked files that neither parse must still be the same bytes.
fn check_edits(what: &str, edits: Vec<(String, Vec<u8>)>) {
    let (mut same, mut refused, mut refused_elsewhere) = (0, 0, 0);
    let mut disagreements = Vec::new();
    let mut elsewhere = Vec::new();
    for (edit, bytes) in edits {
        let reference: Outcome = reference_packed_jpeg::unpack(&bytes);
        let core: Outcome = core_unpack(&bytes).map_err(|e| e.to_string());
        match (opens(&reference), opens(&core)) {
            (true, true) => {
                let (a, b) = (reference.as_ref().unwrap(), core.as_ref().unwrap());
                if a == b {
                    same += 1;
                } else {
                    let first = a.iter().zip(b).position(|(x, y)| x != y);
                    disagreements.push(format!(
                        "{edit}: both open, {} vs {} bytes, first difference at {first:?}",
                        a.len(),
                        b.len()
                    ));
                }
            }
            (false, false) => {
                if let (Ok(a), Ok(b)) = (&reference, &core)
                    && a != b
                {
                    disagreements.push(format!("{edit}: neither opens, unpacked differently"));
                } else if reference.is_err() == core.is_err() {
                    refused += 1;
                } else {
                    refused_elsewhere += 1;
                    elsewhere.push(format!(
                        "{edit}: reference {:?}, nmat-core {:?}",
                        reference.as_ref().map(|_| "unpacks, does not parse"),
                        core.as_ref().map(|_| "unpacks, does not parse"),
                    ));
                }
            }
            (r, c) => disagreements.push(format!(
                "{edit}: reference {} ({:?}), nmat-core {} ({:?})",
                if r { "opens" } else { "refuses" },
                reference.as_ref().map(|_| "unpacked"),
                if c { "opens" } else { "refuses" },
                core.as_ref().map(|_| "unpacked"),
            )),
        }
    }
    eprintln!(
        "{what}: {same} open identically, {refused} refused by both unpackers, \
         {refused_elsewhere} refused by one unpacker and by the parser after the other, \
         {} disagreements",
        disagreements.len()
    );
    if std::env::var_os("NMAT_JREF_DEBUG").is_some() {
        for line in &elsewhere {
            eprintln!("  {line}");
        }
    }
    assert!(
        disagreements.is_empty(),
        "{what}: {} disagreements:\n{}",
        disagreements.len(),
        disagreements.iter().take(40).cloned().collect::<Vec<_>>().join("\n")
    );
}

/// Edits of one packed file: random bit flips everywhere (checksum refreshed), every restart
/// interval from 0 to 12 and a few large ones, entropy lengths and offsets moved, the section
/// header's fields changed.
fn edits_of(packed: &[u8], seed: u64) -> Vec<(String, Vec<u8>)> {
    let mut edits = Vec::new();
    let mut edit = |name: String, f: &dyn Fn(&mut Vec<u8>)| {
        let mut b = packed.to_vec();
        f(&mut b);
        refresh_checksum(&mut b);
        edits.push((name, b));
    };
    let (offset, length) = section(packed, 7);
    let mut r = Rng::new(seed);
    for i in 0..packed.len() {
        for _ in 0..4 {
            let bit = r.next_u64() % 8;
            edit(format!("byte {i} bit {bit}"), &|b| b[i] ^= 1 << bit);
        }
    }
    // The body alone, more densely: every bit of it.
    for i in offset..offset + length {
        for bit in 0..8 {
            edit(format!("body byte {i} bit {bit}"), &|b| b[i] ^= 1 << bit);
        }
    }
    let (records, count) = stream_records(packed);
    for s in 0..count {
        let rec = records + 20 * s;
        let word = |b: &[u8], at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
        let data = offset + 8 + word(packed, rec) as usize;
        let data_len = word(packed, rec + 4) as usize;
        // Runs of one bits: no Huffman code matches 16 of them (the all-ones code is never
        // assigned), so §11.3's "symbol 0, 16 bits consumed" rule decides where MCUs start.
        for at in [0, data_len / 3, data_len / 2, data_len.saturating_sub(3)] {
            for run in [2usize, 3, 6] {
                edit(format!("stream {s} 0xFF × {run} at {at}"), &|b| {
                    let end = (data + at + run).min(data + data_len);
                    b[data + at.min(data_len)..end].fill(0xFF);
                });
            }
        }
        // Shorter data, with `jpeg_length` following: a gap before the next stream (allowed by
        // §11.1's "at or after the previous stream"?), or the last stream's padding grown.
        for cut in [1u32, 4, 5] {
            edit(format!("stream {s} entropy_length −{cut}, jpeg_length to match"), &|b| {
                let l = word(b, rec + 4);
                if l >= cut {
                    b[rec + 4..rec + 8].copy_from_slice(&(l - cut).to_le_bytes());
                    let j = word(b, offset) as usize;
                    let (old, new) = ((l as usize).div_ceil(4), ((l - cut) as usize).div_ceil(4));
                    let j = (j - 4 * (old - new)) as u32;
                    b[offset..offset + 4].copy_from_slice(&j.to_le_bytes());
                }
            });
        }
        for v in (0..=12u16).chain([15, 16, 31, 64, 100, 255, 256, 1000, u16::MAX]) {
            edit(format!("stream {s} restart interval {v}"), &|b| {
                b[rec + 18..rec + 20].copy_from_slice(&v.to_le_bytes());
            });
        }
        edit(format!("stream {s} byte 17"), &|b| b[rec + 17] = 1);
        for delta in [-8i64, -4, -1, 1, 3, 4, 8] {
            edit(format!("stream {s} entropy_length {delta:+}"), &|b| {
                let l = i64::from(u32::from_le_bytes(b[rec + 4..rec + 8].try_into().unwrap()));
                b[rec + 4..rec + 8].copy_from_slice(&((l + delta).max(0) as u32).to_le_bytes());
            });
            edit(format!("stream {s} offset {delta:+}"), &|b| {
                let o = i64::from(u32::from_le_bytes(b[rec..rec + 4].try_into().unwrap()));
                b[rec..rec + 4].copy_from_slice(&((o + delta).max(0) as u32).to_le_bytes());
            });
        }
    }
    for delta in [-8i64, -4, -1, 1, 4, 8, 1 << 20] {
        edit(format!("jpeg_length {delta:+}"), &|b| {
            let l = i64::from(u32::from_le_bytes(b[offset..offset + 4].try_into().unwrap()));
            b[offset..offset + 4].copy_from_slice(&((l + delta).max(0) as u32).to_le_bytes());
        });
    }
    for coder in [0u8, 1, 3, 255] {
        edit(format!("coder {coder}"), &|b| b[offset + 4] = coder);
    }
    edit("reserved 1".into(), &|b| b[offset + 5] = 1);
    for minor in [0u16, 2, 7] {
        edit(format!("unpacked_minor {minor}"), &|b| {
            b[offset + 6..offset + 8].copy_from_slice(&minor.to_le_bytes());
        });
    }
    // The PACKED_JPEG table entry: without REQUIRED, or another kind.
    let count = u32::from_le_bytes(packed[16..20].try_into().unwrap()) as usize;
    let entry = (0..count).map(|i| 32 + 16 * i).find(|&e| packed[e] == 7).unwrap();
    edit("PACKED_JPEG not REQUIRED".into(), &|b| b[entry + 4] = 0);
    for kind in [5u8, 6] {
        edit(format!("PACKED_JPEG as kind {kind}"), &|b| b[entry] = kind);
    }
    edits
}

#[test]
fn edited_packed_fixture_same_verdicts() {
    let twin = jpeg_fixture("pattern_420_37x21.packed.nmat");
    check_edits("fixture twin", edits_of(&twin, 1));
}

#[test]
fn edited_packed_generated_files_same_verdicts() {
    let cases = [
        ((17, 9), 1, SamplingFactor::F_1_1, 50, 0),
        ((33, 20), 3, SamplingFactor::R_4_4_4, 70, 2),
        ((40, 17), 3, SamplingFactor::R_4_2_2, 85, 1),
        ((24, 40), 3, SamplingFactor::R_4_4_0, 60, 3),
    ];
    for (i, (size, components, sampling, quality, restart)) in cases.into_iter().enumerate() {
        let fixed = indexed_material(&jpeg_file(size, components, sampling, quality, restart));
        let packed = nmat_core::pack(&fixed).unwrap();
        check_edits(&format!("case {i}"), edits_of(&packed, 10 + i as u64));
    }
    let options = JpegOptions { quality: 40, storage: Storage::FixedRate, ..Default::default() };
    let fixed = encode_jpeg(&nmat_encode::demo::bricks(16), &options).unwrap().bytes;
    let packed = nmat_core::pack(&fixed).unwrap();
    check_edits("bricks(16)", edits_of(&packed, 99));
}

/// Fixed-rate files with one bit flipped in their JPEG section (index, DC values, tables, data):
/// both packers write the same file or both refuse (FORMAT.md §12.5: a stream whose index no
/// restart interval reproduces, or a file that does not unpack to its own bytes, is not packed).
#[test]
fn edited_fixed_rate_files_pack_alike() {
    let fixture = jpeg_fixture("pattern_420_37x21.nmat");
    let restarted = indexed_material(&jpeg_file((40, 24), 1, SamplingFactor::F_1_1, 70, 2));
    let plain = indexed_material(&jpeg_file((24, 24), 3, SamplingFactor::R_4_4_4, 70, 0));
    for (what, fixed) in [("fixture", fixture), ("gray restart 2", restarted), ("4:4:4", plain)] {
        let (offset, length) = section(&fixed, 5);
        let (mut packed, mut refused) = (0, 0);
        let mut disagreements = Vec::new();
        for i in offset..offset + length {
            for bit in 0..8 {
                let mut b = fixed.clone();
                b[i] ^= 1 << bit;
                refresh_checksum(&mut b);
                match (reference_packed_jpeg::pack(&b), nmat_core::pack(&b)) {
                    (Ok(x), Ok(y)) if x == y => packed += 1,
                    (Err(_), Err(_)) => refused += 1,
                    (x, y) => disagreements.push(format!(
                        "byte {i} bit {bit}: reference {:?}, nmat-core {:?}",
                        x.map(|p| p.len()),
                        y.map(|p| p.len())
                    )),
                }
            }
        }
        eprintln!("{what}: {packed} packed alike, {refused} refused by both");
        assert!(
            disagreements.is_empty(),
            "{what}: {} disagreements:\n{}",
            disagreements.len(),
            disagreements.iter().take(40).cloned().collect::<Vec<_>>().join("\n")
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Files put together section by section
// ---------------------------------------------------------------------------------------------

/// Sections in table order: (kind, flags, bytes).
type SectionList = Vec<(u32, u32, Vec<u8>)>;

/// The sections of a file in table order.
fn sections_of(bytes: &[u8]) -> SectionList {
    let count = u32::from_le_bytes(bytes[16..20].try_into().unwrap()) as usize;
    (0..count)
        .map(|i| {
            let e = 32 + 16 * i;
            let word = |k: usize| u32::from_le_bytes(bytes[e + k..e + k + 4].try_into().unwrap());
            let (offset, length) = (word(8) as usize, word(12) as usize);
            (word(0), word(4), bytes[offset..offset + length].to_vec())
        })
        .collect()
}

/// A file with `header`'s fields and the given sections, each at the next multiple of 4 after
/// the table and the previous one, checksum filled in.
fn file_of(header: &[u8], sections: &[(u32, u32, Vec<u8>)]) -> Vec<u8> {
    let mut out = header[..32].to_vec();
    out[16..20].copy_from_slice(&(sections.len() as u32).to_le_bytes());
    let mut offset = 32 + 16 * sections.len();
    for (kind, flags, data) in sections {
        for v in [*kind, *flags, offset as u32, data.len() as u32] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        offset = (offset + data.len()).div_ceil(4) * 4;
    }
    for (_, _, data) in sections {
        out.extend_from_slice(data);
        out.resize(out.len().div_ceil(4) * 4, 0);
    }
    let len = out.len() as u32;
    out[12..16].copy_from_slice(&len.to_le_bytes());
    refresh_checksum(&mut out);
    out
}

/// Packed files whose section lists differ from what nmat writes: other orders, optional
/// sections (known or not, REQUIRED or not), a second PACKED_JPEG, a JPEG section or a neural
/// section beside PACKED_JPEG, MATERIAL missing. Both unpackers agree on each.
#[test]
fn packed_files_with_other_section_lists_same_verdicts() {
    let fixed = jpeg_fixture("pattern_420_37x21.nmat");
    let twin = jpeg_fixture("pattern_420_37x21.packed.nmat");
    let all = sections_of(&twin);
    let find = |kind: u32| all.iter().find(|s| s.0 == kind).unwrap().clone();
    let (material, packed) = (find(1), find(7));
    let jpeg = sections_of(&fixed).into_iter().find(|s| s.0 == 5).unwrap();
    let optional = (0x0001_4D53u32, 0u32, vec![1, 2, 3, 4, 5]);
    let unknown = (0x7777u32, 0u32, vec![9; 7]);
    let unknown_required = (0x7777u32, 1u32, vec![9; 7]);
    let lists: Vec<(&str, SectionList)> = vec![
        ("as written", all.clone()),
        ("PACKED_JPEG first", vec![packed.clone(), material.clone()]),
        ("an unknown optional section between", vec![material.clone(), unknown, packed.clone()]),
        ("an unknown REQUIRED section", vec![material.clone(), packed.clone(), unknown_required]),
        ("a malformed SOURCE_MAPS", vec![optional, packed.clone(), material.clone()]),
        ("two PACKED_JPEG", vec![material.clone(), packed.clone(), packed.clone()]),
        ("JPEG beside PACKED_JPEG", vec![material.clone(), packed.clone(), jpeg]),
        ("MLP beside PACKED_JPEG", vec![material.clone(), packed.clone(), (3, 1, vec![0; 8])]),
        ("no MATERIAL", vec![packed.clone()]),
        ("two MATERIAL", vec![material.clone(), material.clone(), packed.clone()]),
    ];
    let edits =
        lists.into_iter().map(|(name, list)| (name.to_string(), file_of(&twin, &list))).collect();
    check_edits("section lists", edits);
}

// ---------------------------------------------------------------------------------------------
// The 16-bit relative offsets of the index (§11.2, §12.5)
// ---------------------------------------------------------------------------------------------

/// The canonical codes (T.81 annex C) of a Huffman table at `at` in a JPEG section body:
/// (class, symbol → (code, length)), and the table's padded length.
fn huffman_codes(body: &[u8], at: usize) -> (u8, Vec<Option<(u32, u32)>>, usize) {
    let count = u16::from_le_bytes([body[at + 2], body[at + 3]]) as usize;
    let mut codes = vec![None; 256];
    let (mut code, mut k) = (0u32, 0usize);
    for l in 1..=16u32 {
        for _ in 0..body[at + 3 + l as usize] {
            codes[body[at + 20 + k] as usize] = Some((code, l));
            code += 1;
            k += 1;
        }
        code <<= 1;
    }
    (body[at], codes, (20 + count).div_ceil(4) * 4)
}

/// One block of exactly `length` bits with the given tables: DC category 0, then AC
/// coefficients of run 0 (categories 1 … 10, their `s` bits all ones), then end of block unless
/// all 63 are there. Panics if no such block has that length.
fn block_of_length(
    w: &mut BitWriter,
    dc: &[Option<(u32, u32)>],
    ac: &[Option<(u32, u32)>],
    length: u32,
) {
    let (dc0, eob) = (dc[0].unwrap(), ac[0].unwrap());
    // cost[s] of one coefficient of category s (code + s bits), for the categories the table has.
    let costs: Vec<(u8, u32)> =
        (1u8..=10).filter_map(|s| ac[usize::from(s)].map(|(_, l)| (s, l + u32::from(s)))).collect();
    let body = length.checked_sub(dc0.1).unwrap();
    // reach[n][b]: a choice of n coefficients costing b bits (the last category chosen).
    let max = body as usize;
    let mut reach = vec![vec![None::<u8>; max + 1]; 64];
    reach[0][0] = Some(0);
    for n in 0..63 {
        for b in 0..=max {
            if reach[n][b].is_some() {
                for &(s, c) in &costs {
                    if b + c as usize <= max && reach[n + 1][b + c as usize].is_none() {
                        reach[n + 1][b + c as usize] = Some(s);
                    }
                }
            }
        }
    }
    let end = |n: usize| if n == 63 { 0 } else { eob.1 as usize };
    let n = (0..=63).find(|&n| max >= end(n) && reach[n][max - end(n)].is_some()).unwrap();
    let mut categories = Vec::new();
    let mut b = max - end(n);
    for m in (1..=n).rev() {
        let s = reach[m][b].unwrap();
        categories.push(s);
        b -= costs.iter().find(|c| c.0 == s).unwrap().1 as usize;
    }
    w.put(dc0.0, dc0.1);
    for s in categories {
        let (code, l) = ac[usize::from(s)].unwrap();
        w.put(code, l);
        w.put((1 << s) - 1, u32::from(s));
    }
    if n < 63 {
        w.put(eob.0, eob.1);
    }
}

/// A packed 4:2:0 material of 3 × 3 MCUs whose stream is replaced by one where MCUs 0 … 7 take
/// `span` bits together, so that MCU 8 starts `span` bits after MCU 0, its group's first.
fn packed_with_span(span: u32) -> Vec<u8> {
    let fixed = indexed_material(&jpeg_file((48, 48), 3, SamplingFactor::R_4_2_0, 75, 0));
    let packed = nmat_core::pack(&fixed).unwrap();
    let mut sections = sections_of(&packed);
    let section = sections.iter_mut().find(|s| s.0 == 7).unwrap();
    let body = &section.2[8..];
    let records = jpeg_stream_records(body);
    assert_eq!(
        records + 20,
        u32::from_le_bytes(body[records..records + 4].try_into().unwrap()) as usize
    );
    // The tables of each component, from the stream record.
    let mut tables = Vec::new();
    let mut at = 8 + 4 * body[2] as usize + 64 * body[3] as usize;
    for _ in 0..body[4] {
        let (class, codes, len) = huffman_codes(body, at);
        tables.push((class, codes));
        at += len;
    }
    let rec = &body[records..records + 20];
    let table = |c: usize| (&tables[rec[11 + c] as usize].1, &tables[rec[14 + c] as usize].1);

    let mut w = BitWriter::default();
    // Blocks: 4 luma, Cb, Cr per MCU; MCUs 0 … 7 share `span` bits, MCU 8 is short.
    let per_block = span / 48;
    for mcu in 0..9 {
        for b in 0..6 {
            let (dc, ac) = table(if b < 4 { 0 } else { b - 3 });
            let length = match (mcu, b) {
                (8, _) => 40,
                // The remainder on a luma block: its table reaches further than chroma's.
                (7, 3) => span - 47 * per_block,
                _ => per_block,
            };
            block_of_length(&mut w, dc, ac, length);
        }
    }
    let data = w.into_bytes();
    let records_end = records + 20;
    // jpeg_length: records, then the stream's index (one group), 27 DC values and the data.
    let jpeg_length = (records_end + 20 + (27 * 12usize).div_ceil(8).div_ceil(4) * 4 + data.len())
        .div_ceil(4)
        * 4;
    let mut new_body = body[..records_end].to_vec();
    new_body[records + 4..records + 8].copy_from_slice(&(data.len() as u32).to_le_bytes());
    new_body.extend_from_slice(&data);
    new_body.resize(new_body.len().div_ceil(4) * 4, 0);
    let mut new_section = section.2[..8].to_vec();
    new_section[0..4].copy_from_slice(&(jpeg_length as u32).to_le_bytes());
    new_section.extend_from_slice(&new_body);
    section.2 = new_section;
    file_of(&packed, &sections)
}

/// §12.5: "an MCU more than 65535 bits after the one that starts its group of 9 is
/// `LimitExceeded JpegIndex`": 65535 is written, 65536 is refused, by both unpackers.
#[test]
fn an_mcu_65535_bits_after_its_group_start_is_the_limit() {
    let fits = packed_with_span(65535);
    let unpacked = reference_packed_jpeg::unpack(&fits).unwrap();
    assert_same_bytes(
        "65535 bits: nmat-core vs reference",
        &core_unpack(&fits).unwrap(),
        &unpacked,
    );
    let m = Container::parse(&unpacked).unwrap();
    drop(m);
    let (jpeg, _) = section(&unpacked, 5);
    let body = &unpacked[jpeg..];
    let stream =
        u32::from_le_bytes(body[jpeg_stream_records(body)..][..4].try_into().unwrap()) as usize;
    let group = &body[stream..stream + 20];
    assert_eq!(u32::from_le_bytes(group[0..4].try_into().unwrap()), 0);
    assert_eq!(u16::from_le_bytes([group[18], group[19]]), 65535, "MCU 8's relative offset");

    let over = packed_with_span(65536);
    let reference = reference_packed_jpeg::unpack(&over);
    assert!(
        reference.as_ref().is_err_and(|e| e.contains("LimitExceeded JpegIndex")),
        "{reference:?}"
    );
    let core = core_unpack(&over);
    assert!(
        matches!(core, Err(nmat_core::Error::LimitExceeded { .. })),
        "nmat-core: {:?}",
        core.map(|u| u.len())
    );
}

//! Reading and patching `.nmat` bytes in tests that forge or compare files (FORMAT.md §1, §11.1):
//! a section's place in the table, the checksum after an edit, the stream records of a JPEG
//! section, and a comparison of long byte strings that names the first difference.
// Test code: a malformed file here is a broken test, which should panic.
#![allow(clippy::unwrap_used)]

use nmat_core::internals::file_checksum;

/// (offset, length) of the first section of `kind` in the file's table.
pub fn section(bytes: &[u8], kind: u32) -> (usize, usize) {
    let e = section_entry(bytes, kind);
    let word = |k: usize| u32::from_le_bytes(bytes[e + k..e + k + 4].try_into().unwrap());
    (word(8) as usize, word(12) as usize)
}

/// Where the table entry of the first section of `kind` starts in the file (16 bytes: kind,
/// flags, offset, length).
pub fn section_entry(bytes: &[u8], kind: u32) -> usize {
    let count = u32::from_le_bytes(bytes[16..20].try_into().unwrap()) as usize;
    (0..count)
        .map(|i| 32 + 16 * i)
        .find(|&e| u32::from_le_bytes(bytes[e..e + 4].try_into().unwrap()) == kind)
        .unwrap_or_else(|| panic!("no section of kind {kind}"))
}

/// Writes the CRC-32 of the file into its header after an edit (§1.4).
pub fn refresh_checksum(bytes: &mut [u8]) {
    let crc = file_checksum(bytes);
    bytes[20..24].copy_from_slice(&crc.to_le_bytes());
}

/// Offset of the stream records in a JPEG section (or PACKED_JPEG body): after the header, map
/// records, quantization tables and Huffman tables (§11.1).
pub fn jpeg_stream_records(body: &[u8]) -> usize {
    let (maps, quant, huffman) = (body[2] as usize, body[3] as usize, body[4] as usize);
    let mut pos = 8 + 4 * maps + 64 * quant;
    for _ in 0..huffman {
        let count = u16::from_le_bytes([body[pos + 2], body[pos + 3]]) as usize;
        pos = (pos + 20 + count + 3) & !3;
    }
    pos
}

/// Panics naming the first differing byte (the vectors are too long for `assert_eq!`'s dump).
pub fn assert_same_bytes(what: &str, actual: &[u8], expected: &[u8]) {
    if actual == expected {
        return;
    }
    let first = actual.iter().zip(expected).position(|(a, b)| a != b);
    panic!(
        "{what}: {} bytes vs {} expected; first difference at {first:?} ({:?} vs {:?})",
        actual.len(),
        expected.len(),
        first.map(|i| actual[i]),
        first.map(|i| expected[i]),
    );
}

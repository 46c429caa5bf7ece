//! Version-1 files (before the network was stored once) are still read (FORMAT.md §10). The two
//! files in `fixtures/v1/` were written by the version-1 writer from the same generator
//! configurations as today's fixtures of the same names, so they hold the same int8 network: their
//! integer decodes must equal the hashes pinned in `golden.txt`, and both decoders must give what
//! the version-2 twin gives.
// Test code: an unwrap that fails fails the test (clippy.toml allows it only inside #[test]).
#![allow(clippy::unwrap_used)]

use nmat_core::internals::file_checksum;
use nmat_core::{ChannelMask, Container, Error, Field, LEGACY_VERSION_MAJOR, VERSION_MAJOR};
use nmat_tests::generate::{generate, golden_configs};
use nmat_tests::{decode_all_u8, decode_all_u16, fixtures_dir, fnv1a, texels};

const LEGACY: [&str; 2] = ["ntc_1bit_q10_40x24", "nbc_clamp_nolod_48x36"];

fn legacy_bytes(name: &str) -> Vec<u8> {
    let path = fixtures_dir().join("v1").join(format!("{name}.nmat"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn pinned_hashes(name: &str) -> (String, String) {
    let text = std::fs::read_to_string(fixtures_dir().join("golden.txt")).unwrap();
    let line = text.lines().find(|l| l.split(' ').next() == Some(name)).unwrap();
    let fields: Vec<&str> = line.split_whitespace().collect();
    (fields[1].to_string(), fields[2].to_string())
}

#[test]
fn version_one_files_decode_like_their_version_two_twins() {
    for name in LEGACY {
        let old = legacy_bytes(name);
        let old_m = Container::parse(&old).unwrap();
        assert_eq!(old_m.version_major(), LEGACY_VERSION_MAJOR);
        let (u8_hash, u16_hash) = pinned_hashes(name);
        assert_eq!(format!("{:016x}", fnv1a(decode_all_u8(&old_m))), u8_hash, "{name} u8");
        assert_eq!(format!("{:016x}", fnv1a(decode_all_u16(&old_m))), u16_hash, "{name} u16");

        let cfg = golden_configs().into_iter().find(|c| c.name == name).unwrap();
        let new = generate(&cfg).to_bytes().unwrap();
        let new_m = Container::parse(&new).unwrap();
        assert_eq!(new_m.version_major(), VERSION_MAJOR);
        assert!(new.len() < old.len(), "{name}: the network is stored once");
        let n = old_m.channel_count();
        let (mut a, mut b) = ([0f32; 16], [0f32; 16]);
        for (x, y, mip) in texels(&old_m) {
            old_m.decode_texel(x, y, mip, ChannelMask::ALL, &mut a).unwrap();
            new_m.decode_texel(x, y, mip, ChannelMask::ALL, &mut b).unwrap();
            assert_eq!(a[..n], b[..n], "{name} float at ({x},{y}) mip {mip}");
        }
        // Re-writing a version-1 material gives today's format and the same network.
        assert_eq!(
            old_m.to_spec().expect("a neural material").to_bytes().unwrap(),
            new,
            "{name}: to_spec round trip"
        );
    }
}

/// Offset of layer 0's f16 weights in a version-1 file: MLP section + header + layer records +
/// the int8 part of the block (weights padded, scales, biases).
fn first_f16_weight(bytes: &[u8]) -> usize {
    let m = Container::parse(bytes).unwrap();
    let sections = u32::from_le_bytes(bytes[16..20].try_into().unwrap()) as usize;
    let mlp = (0..sections)
        .map(|i| 32 + 16 * i)
        .find(|&e| u32::from_le_bytes(bytes[e..e + 4].try_into().unwrap()) == 3)
        .map(|e| u32::from_le_bytes(bytes[e + 8..e + 12].try_into().unwrap()) as usize)
        .unwrap();
    let layers = m.neural().expect("a neural material").mlp().layers();
    let l0 = &layers[0];
    let n = l0.inputs() * l0.outputs();
    mlp + 8 + 8 * layers.len() + n.div_ceil(4) * 4 + 8 * l0.outputs()
}

#[test]
fn version_one_float_copy_is_still_validated() {
    let good = legacy_bytes(LEGACY[0]);
    let at = first_f16_weight(&good);
    for bad in [0x7E00u16, 0x7C00, 0xFC00] {
        let mut b = good.clone();
        b[at + 2..at + 4].copy_from_slice(&bad.to_le_bytes());
        let crc = file_checksum(&b);
        b[20..24].copy_from_slice(&crc.to_le_bytes());
        assert!(
            matches!(
                Container::parse(&b),
                Err(Error::Malformed { field: Field::FloatWeight, index: 0, value: 1 })
            ),
            "f16 {bad:#06x}: {:?}",
            Container::parse(&b).err()
        );
    }
    // A version-2 reader does not take a version-1 file's layer blocks for its own: a version-1
    // file relabelled as version 2 has bytes left over in its MLP section.
    let mut relabelled = good.clone();
    relabelled[4..6].copy_from_slice(&VERSION_MAJOR.to_le_bytes());
    let crc = file_checksum(&relabelled);
    relabelled[20..24].copy_from_slice(&crc.to_le_bytes());
    assert!(Container::parse(&relabelled).is_err());
}

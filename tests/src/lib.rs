//! Shared helpers of the nmat test suite: the deterministic material generators (neural, and a
//! DC-only JPEG material whose codes follow from FORMAT.md §11, `generate_jpeg`), an independent
//! reference decoder, independent packers/unpackers of FORMAT.md §12 (`reference_packed` for
//! neural materials, `reference_packed_jpeg` for JPEG materials, §12.5), fixture I/O and hashing.
//! The tests themselves live in `tests/tests/`.

pub mod files;
pub mod generate;
pub mod generate_jpeg;
pub mod reference;
pub(crate) mod reference_container;
pub mod reference_packed;
pub mod reference_packed_jpeg;

use nmat_core::{ChannelMask, Container, Material, MaterialSpec};
use std::path::PathBuf;

/// `tests/fixtures/`.
pub fn fixtures_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

/// The committed JPEG fixtures of `tests/fixtures/jpeg/` (its README): 4:2:0 with restart
/// markers, 4:2:2 without; each a `.jpg`, the `.nmat` it indexes to and djpeg's decode, `.u8`.
pub const JPEG_FIXTURES: [&str; 2] = ["pattern_420_37x21", "pattern_422_37x21"];

/// 64-bit FNV-1a: a stable, dependency-free hash for golden outputs.
pub fn fnv1a(bytes: impl IntoIterator<Item = u8>) -> u64 {
    bytes
        .into_iter()
        .fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

/// Every texel of every mip, in mip → row → column → channel order.
pub fn texels<'m>(m: &'m Material<'_>) -> impl Iterator<Item = (i64, i64, u32)> + 'm {
    (0..m.mip_count()).flat_map(move |mip| {
        let (w, h) = m.mip_size(mip);
        (0..h).flat_map(move |y| (0..w).map(move |x| (i64::from(x), i64::from(y), mip)))
    })
}

/// Asserts that every texel of every mip of `spec`, written and parsed, decodes to the 8-bit
/// codes of the independent reference decoder (all channels).
pub fn assert_decodes_as_the_reference(spec: &MaterialSpec) {
    let bytes = spec.to_bytes().expect("a valid spec");
    let m = Container::parse(&bytes).expect("a spec's bytes parse");
    let mut codes = [0u8; 16];
    for (x, y, mip) in texels(&m) {
        let n = m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut codes).expect("valid request");
        let want = reference::decode_u8(spec, x, y, mip);
        assert_eq!(codes[..n], want[..], "texel ({x}, {y}) mip {mip}");
    }
}

/// Integer decode of the whole chain to 8-bit codes, all channels.
pub fn decode_all_u8(m: &Material<'_>) -> Vec<u8> {
    let n = m.channel_count();
    let mut out = Vec::new();
    let mut buf = [0u8; 16];
    for (x, y, mip) in texels(m) {
        m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut buf).expect("valid request");
        out.extend_from_slice(&buf[..n]);
    }
    out
}

/// Integer decode of the whole chain to 16-bit codes (little-endian bytes), all channels.
pub fn decode_all_u16(m: &Material<'_>) -> Vec<u8> {
    let n = m.channel_count();
    let mut out = Vec::new();
    let mut buf = [0u16; 16];
    for (x, y, mip) in texels(m) {
        m.decode_texel_u16(x, y, mip, ChannelMask::ALL, &mut buf).expect("valid request");
        out.extend(buf[..n].iter().flat_map(|v| v.to_le_bytes()));
    }
    out
}

/// The statistics of integer codes against float codes (`round(unit · 255)`) over the chain.
#[derive(Clone, Copy, Debug, Default)]
pub struct CodeAgreement {
    pub count: u64,
    pub max_abs: i32,
    /// Mean of (integer code − float code before rounding), in codes.
    pub mean: f64,
    pub exact: u64,
}

pub fn int_vs_float(m: &Material<'_>) -> CodeAgreement {
    let n = m.channel_count();
    let (mut a, mut sum) = (CodeAgreement::default(), 0f64);
    let (mut codes, mut units) = ([0u8; 16], [0f32; 16]);
    for (x, y, mip) in texels(m) {
        m.decode_texel_u8(x, y, mip, ChannelMask::ALL, &mut codes).expect("valid request");
        m.decode_texel_unit(x, y, mip, ChannelMask::ALL, &mut units).expect("valid request");
        for (&c, &u) in codes[..n].iter().zip(&units[..n]) {
            let real = f64::from(u) * 255.0;
            let d = i32::from(c) - real.round() as i32;
            a.max_abs = a.max_abs.max(d.abs());
            a.exact += u64::from(d == 0);
            sum += f64::from(c) - real;
            a.count += 1;
        }
    }
    a.mean = sum / a.count.max(1) as f64;
    a
}

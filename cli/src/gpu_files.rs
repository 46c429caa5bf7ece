//! GPU texture files of BC blocks: KTX2 (Khronos) and DDS with the DX10 header (Direct3D), the
//! containers engines load block-compressed textures from.

use nmat_core::bc::BcFormat;

/// One block-compressed texture with its mip chain (level 0 first), each level's blocks row by
/// row with no padding.
pub struct BcImage {
    pub format: BcFormat,
    pub srgb: bool,
    pub width: u32,
    pub height: u32,
    pub levels: Vec<Vec<u8>>,
}

impl BcImage {
    /// The Vulkan format (`VK_FORMAT_*_BLOCK`) of KTX2's header.
    pub fn vk_format(&self) -> u32 {
        match (self.format, self.srgb) {
            (BcFormat::Bc1, false) => 131,
            (BcFormat::Bc1, true) => 132,
            (BcFormat::Bc4, _) => 139,
            (BcFormat::Bc5, _) => 141,
            (_, false) => 145, // BC7, RGB or RGBA
            (_, true) => 146,
        }
    }

    /// The DXGI format of DDS's DX10 header.
    pub fn dxgi_format(&self) -> u32 {
        match (self.format, self.srgb) {
            (BcFormat::Bc1, false) => 71,
            (BcFormat::Bc1, true) => 72,
            (BcFormat::Bc4, _) => 80,
            (BcFormat::Bc5, _) => 83,
            (_, false) => 98,
            (_, true) => 99,
        }
    }
}

fn put32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put64(out: &mut Vec<u8>, v: u64) {
    out.extend_from_slice(&v.to_le_bytes());
}

/// The KTX2 data format descriptor of a BC format (KTX 2.0 §3.10 with the Khronos Data Format
/// Specification's compressed colour models): one 64- or 128-bit sample per block, BC5's two
/// (red, then green).
fn ktx2_dfd(image: &BcImage) -> Vec<u8> {
    const MODEL_BC1A: u32 = 128;
    const MODEL_BC4: u32 = 131;
    const MODEL_BC5: u32 = 132;
    const MODEL_BC7: u32 = 134;
    let bytes = image.format.block_bytes() as u32;
    let (model, samples): (u32, &[(u32, u32)]) = match image.format {
        BcFormat::Bc1 => (MODEL_BC1A, &[(0, 0)]),
        BcFormat::Bc4 => (MODEL_BC4, &[(0, 0)]),
        BcFormat::Bc5 => (MODEL_BC5, &[(0, 0), (64, 1)]),
        _ => (MODEL_BC7, &[(0, 0)]),
    };
    let bits_per_sample = 8 * bytes / samples.len() as u32;
    let transfer = if image.srgb { 2 } else { 1 }; // sRGB or linear
    let block_size = 24 + 16 * samples.len() as u32;
    let mut d = Vec::new();
    put32(&mut d, 4 + block_size); // dfdTotalSize
    put32(&mut d, 0); // vendor Khronos, descriptor type basic
    put32(&mut d, 2 | (block_size << 16)); // version 1.3 (2), block size
    put32(&mut d, model | (1 << 8) | (transfer << 16)); // BT.709 primaries, straight alpha
    put32(&mut d, 3 | (3 << 8)); // 4×4×1×1 texels per block (dimensions − 1)
    put32(&mut d, bytes); // bytesPlane0
    put32(&mut d, 0);
    for &(offset, channel) in samples {
        put32(&mut d, offset | ((bits_per_sample - 1) << 16) | (channel << 24));
        put32(&mut d, 0); // sample position
        put32(&mut d, 0); // sampleLower
        put32(&mut d, u32::MAX); // sampleUpper
    }
    d
}

/// The image as a KTX2 file: no supercompression, levels stored smallest first (as KTX2 asks)
/// at offsets aligned to the block size, the writer named in `KTXwriter`.
pub fn ktx2(image: &BcImage) -> Vec<u8> {
    const IDENTIFIER: [u8; 12] =
        [0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A];
    let levels = image.levels.len();
    let dfd = ktx2_dfd(image);
    let mut kvd = Vec::new();
    let entry = format!("KTXwriter\0nmat {}\0", env!("CARGO_PKG_VERSION"));
    put32(&mut kvd, entry.len() as u32);
    kvd.extend_from_slice(entry.as_bytes());
    kvd.resize(kvd.len().next_multiple_of(4), 0);
    let dfd_at = 80 + 24 * levels;
    let kvd_at = dfd_at + dfd.len();
    let align = image.format.block_bytes();
    // Offsets of the levels, smallest first after the key/value data.
    let mut offsets = vec![0usize; levels];
    let mut at = kvd_at + kvd.len();
    for level in (0..levels).rev() {
        at = at.next_multiple_of(align);
        offsets[level] = at;
        at += image.levels[level].len();
    }
    let mut out = Vec::with_capacity(at);
    out.extend_from_slice(&IDENTIFIER);
    for v in [image.vk_format(), 1, image.width, image.height, 0, 0, 1, levels as u32, 0] {
        put32(&mut out, v); // format, type size, size, depth, layers, faces, levels, scheme
    }
    for v in [dfd_at, dfd.len(), kvd_at, kvd.len()] {
        put32(&mut out, v as u32);
    }
    put64(&mut out, 0); // no supercompression global data
    put64(&mut out, 0);
    for (level, data) in image.levels.iter().enumerate() {
        put64(&mut out, offsets[level] as u64);
        put64(&mut out, data.len() as u64);
        put64(&mut out, data.len() as u64);
    }
    out.extend_from_slice(&dfd);
    out.extend_from_slice(&kvd);
    for level in (0..levels).rev() {
        out.resize(offsets[level], 0);
        out.extend_from_slice(&image.levels[level]);
    }
    out
}

/// The FourCC of the DDS forms that predate the DX10 header, which older tools read and some read
/// only (NVIDIA Texture Tools 2 misreads DX10 files): linear BC1, BC4 and BC5.
fn legacy_fourcc(image: &BcImage) -> Option<&'static [u8; 4]> {
    match (image.format, image.srgb) {
        (BcFormat::Bc1, false) => Some(b"DXT1"),
        (BcFormat::Bc4, _) => Some(b"ATI1"),
        (BcFormat::Bc5, _) => Some(b"ATI2"),
        _ => None,
    }
}

/// The image as a DDS file, levels largest first: with a legacy FourCC where one names the
/// format (linear BC1 `DXT1`, BC4 `ATI1`, BC5 `ATI2`), else with the DX10 header (sRGB BC1, BC7).
pub fn dds(image: &BcImage) -> Vec<u8> {
    const CAPS: u32 = 0x1;
    const HEIGHT: u32 = 0x2;
    const WIDTH: u32 = 0x4;
    const PIXELFORMAT: u32 = 0x1000;
    const MIPMAPCOUNT: u32 = 0x2_0000;
    const LINEARSIZE: u32 = 0x8_0000;
    const FOURCC: u32 = 0x4;
    const CAPS_COMPLEX: u32 = 0x8;
    const CAPS_TEXTURE: u32 = 0x1000;
    const CAPS_MIPMAP: u32 = 0x40_0000;
    let levels = image.levels.len() as u32;
    let mut out = Vec::new();
    out.extend_from_slice(b"DDS ");
    put32(&mut out, 124);
    put32(&mut out, CAPS | HEIGHT | WIDTH | PIXELFORMAT | MIPMAPCOUNT | LINEARSIZE);
    put32(&mut out, image.height);
    put32(&mut out, image.width);
    put32(&mut out, image.levels.first().map_or(0, |l| l.len() as u32)); // linear size
    put32(&mut out, 0); // depth
    put32(&mut out, levels);
    out.resize(out.len() + 11 * 4, 0); // reserved
    // The pixel format: a FourCC, the format's own or "DX10" (a header that follows names it).
    let legacy = legacy_fourcc(image);
    put32(&mut out, 32);
    put32(&mut out, FOURCC);
    out.extend_from_slice(legacy.unwrap_or(b"DX10"));
    out.resize(out.len() + 5 * 4, 0); // bit count and masks
    let caps = CAPS_TEXTURE | if levels > 1 { CAPS_COMPLEX | CAPS_MIPMAP } else { 0 };
    put32(&mut out, caps);
    out.resize(out.len() + 4 * 4, 0); // caps2, caps3, caps4, reserved
    if legacy.is_none() {
        // DDS_HEADER_DXT10: format, 2D texture, no flags, one element, alpha mode (opaque, or
        // straight for BC7 with alpha).
        let opaque = image.format != BcFormat::Bc7Rgba;
        for v in [image.dxgi_format(), 3, 0, 1, if opaque { 3 } else { 1 }] {
            put32(&mut out, v);
        }
    }
    for level in &image.levels {
        out.extend_from_slice(level);
    }
    out
}

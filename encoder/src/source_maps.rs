//! The optional SOURCE_MAPS section (docs/FORMAT.md §9): which files a material came from and how
//! their components map to channels, so `nmat decode` can write the maps back under their own
//! names and layouts. Decoders that do not know it skip it.

use crate::texset::{FileLayout, Role, SourceMap};
use nmat_core::Semantic;

/// Section kind ("SM" + 1): optional, never REQUIRED.
pub const SECTION_KIND: u32 = 0x0001_4D53;
const VERSION: u16 = 1;

const GRAY_RGB: u8 = 1;
const CONSTANT_ALPHA: u8 = 2;
const SIXTEEN_BIT: u8 = 4;

pub fn encode(maps: &[SourceMap]) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(maps.len() as u16).to_le_bytes());
    for m in maps {
        // At most 255 bytes (the length is one byte), cut at a character boundary.
        let mut end = m.file_name.len().min(255);
        while !m.file_name.is_char_boundary(end) {
            end -= 1;
        }
        let name = &m.file_name.as_bytes()[..end];
        let flags = (u8::from(m.gray_rgb) * GRAY_RGB)
            | (u8::from(m.alpha_value.is_some()) * CONSTANT_ALPHA)
            | (u8::from(m.sixteen_bit) * SIXTEEN_BIT);
        out.extend_from_slice(&[
            m.role.semantic().0,
            m.layout as u8,
            m.first_channel as u8,
            m.channel_count as u8,
            flags,
            m.alpha_value.unwrap_or(255),
            0,
            name.len() as u8,
        ]);
        out.extend_from_slice(name);
        out.resize(out.len().div_ceil(4) * 4, 0);
    }
    out
}

/// Reads the section; `None` if it is malformed (callers then fall back to channel names).
pub fn decode(bytes: &[u8]) -> Option<Vec<SourceMap>> {
    let version = u16::from_le_bytes(bytes.get(0..2)?.try_into().ok()?);
    if version != VERSION {
        return None;
    }
    let count = u16::from_le_bytes(bytes.get(2..4)?.try_into().ok()?);
    let mut pos = 4;
    let mut maps = Vec::new();
    for _ in 0..count {
        let h = bytes.get(pos..pos + 8)?;
        let name_len = usize::from(h[7]);
        let name = std::str::from_utf8(bytes.get(pos + 8..pos + 8 + name_len)?).ok()?;
        maps.push(SourceMap {
            role: Role::from_semantic(Semantic(h[0]))?,
            // A bare, printable file name: never a path out of the output folder, a hidden
            // file, a device or a terminal escape (the file may say anything).
            file_name: crate::names::file_name(name),
            layout: FileLayout::from_code(h[1])?,
            first_channel: usize::from(h[2]),
            channel_count: usize::from(h[3]),
            gray_rgb: h[4] & GRAY_RGB != 0,
            alpha_value: (h[4] & CONSTANT_ALPHA != 0).then_some(h[5]),
            sixteen_bit: h[4] & SIXTEEN_BIT != 0,
        });
        pos = (pos + 8 + name_len).div_ceil(4) * 4;
    }
    Some(maps)
}

//! The writer (feature `alloc`): an owned description of a material and its serialization to the
//! layout of docs/FORMAT.md. `to_bytes` parses its own output before returning it, so the writer
//! can never produce a file the parser rejects — one definition of validity.

extern crate alloc;

use alloc::string::String;
use alloc::vec::Vec;

use crate::bytes::align4;
use crate::error::{Argument, Error};
use crate::format::channel::{AddressMode, ColorSpace, Semantic};
use crate::format::checksum::file_checksum;
use crate::format::container::*;
use crate::material::{Material, TermMode};
use crate::neural::latents::packed_len;
use crate::neural::mlp::Activation;

#[derive(Clone, Debug, PartialEq)]
pub struct ChannelSpec {
    /// UTF-8, 1 to 16 bytes, no NUL.
    pub name: String,
    pub semantic: Semantic,
    pub component: u8,
    pub color_space: ColorSpace,
    pub range_min: f32,
    pub range_max: f32,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GridSpec {
    pub width: u16,
    pub height: u16,
    pub channels: u8,
    pub bits: u8,
    /// Per channel `(offset, step)` in input Q-format units.
    pub quantization: Vec<(i16, i16)>,
    /// `width · height · channels` codes, channel fastest, then x, then y; each `< 2^bits`.
    pub codes: Vec<u8>,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TermSpec {
    pub mode: TermMode,
    pub grids: Vec<u8>,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LevelSpec {
    pub terms: Vec<TermSpec>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct LayerSpec {
    pub inputs: u16,
    pub outputs: u16,
    pub out_frac_bits: u8,
    pub activation: Activation,
    /// Row-major `[outputs][inputs]`, in [−127, 127].
    pub weights_i8: Vec<i8>,
    /// Per output row: the real value of one weight LSB (FORMAT.md §5.3).
    pub scales: Vec<f32>,
    /// Per output row, in accumulator units (input LSB × weight LSB).
    pub bias: Vec<i32>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct MlpSpec {
    pub input_frac_bits: u8,
    pub pe_frequencies: u8,
    /// 0: no LOD feature; 1: `mip / 16`; 2–5: `mip · 2^(lod_input − 5)`, written as format 2.3
    /// (FORMAT.md §6.5).
    pub lod_input: u8,
    pub layers: Vec<LayerSpec>,
}

/// Everything a `.nmat` file holds, owned.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialSpec {
    pub width: u32,
    pub height: u32,
    pub mip_count: u8,
    pub address_mode: AddressMode,
    pub channels: Vec<ChannelSpec>,
    /// Feature level of each mip (`mip_count` entries).
    pub mip_to_level: Vec<u8>,
    pub grids: Vec<GridSpec>,
    pub levels: Vec<LevelSpec>,
    pub mlp: MlpSpec,
    /// Optional sections (`kind`, payload), written without the REQUIRED flag after the four
    /// required ones; readers that do not know a kind skip it (FORMAT.md §1.3, §9).
    pub optional_sections: Vec<(u32, Vec<u8>)>,
}

pub(crate) fn spec_error(value: usize, limit: usize) -> Error {
    Error::BadArgument { argument: Argument::Spec, value: value as u64, limit: limit as u64 }
}

pub(crate) fn put_u16(out: &mut Vec<u8>, v: u16) {
    out.extend_from_slice(&v.to_le_bytes());
}
pub(crate) fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}
/// Copies `src` into the front of `dst` (as much as fits).
fn copy_into(dst: &mut [u8], src: &[u8]) {
    dst.iter_mut().zip(src).for_each(|(d, s)| *d = *s);
}
pub(crate) fn pad4(out: &mut Vec<u8>) {
    out.resize(align4(out.len()), 0);
}
pub(crate) fn len_u8(n: usize) -> Result<u8, Error> {
    u8::try_from(n).map_err(|_| spec_error(n, 255))
}
pub(crate) fn len_u32(n: usize) -> Result<u32, Error> {
    u32::try_from(n).map_err(|_| spec_error(n, u32::MAX as usize))
}

/// Packs codes LSB-first into little-endian 32-bit words (FORMAT.md §4.1).
pub fn pack_codes(codes: &[u8], bits: u8) -> Vec<u8> {
    let bits = u32::from(bits.clamp(1, 8));
    let total_bits = codes.len() as u64 * u64::from(bits);
    let mut words = alloc::vec![0u32; total_bits.div_ceil(32) as usize];
    for (i, &c) in codes.iter().enumerate() {
        let bit = i as u64 * u64::from(bits);
        let v = u64::from(c) & ((1 << bits) - 1);
        let word = (bit / 32) as usize;
        let shifted = v << (bit % 32);
        if let Some(w) = words.get_mut(word) {
            *w |= shifted as u32;
        }
        if let Some(w) = words.get_mut(word + 1) {
            *w |= (shifted >> 32) as u32;
        }
    }
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

/// The MATERIAL section (FORMAT.md §3).
pub(crate) fn material_section(
    (width, height, mip_count): (u32, u32, u8),
    address_mode: AddressMode,
    channels: &[ChannelSpec],
) -> Result<Vec<u8>, Error> {
    let mut s = Vec::new();
    put_u32(&mut s, width);
    put_u32(&mut s, height);
    s.push(mip_count);
    s.push(len_u8(channels.len())?);
    s.push(address_mode as u8);
    s.push(0);
    for ch in channels {
        let mut name = [0u8; 16];
        let bytes = ch.name.as_bytes();
        if bytes.len() > name.len() {
            return Err(spec_error(bytes.len(), name.len()));
        }
        copy_into(&mut name, bytes);
        s.extend_from_slice(&name);
        s.extend_from_slice(&[ch.semantic.0, ch.component, ch.color_space as u8, 0]);
        s.extend_from_slice(&ch.range_min.to_le_bytes());
        s.extend_from_slice(&ch.range_max.to_le_bytes());
        s.extend_from_slice(&[0; 4]);
    }
    Ok(s)
}

/// A whole file from its required sections (written with the REQUIRED flag, in order) and the
/// optional ones, checked by parsing it.
pub(crate) fn assemble(
    required: Vec<(SectionKind, Vec<u8>)>,
    optional: &[(u32, Vec<u8>)],
    (minor, flags): (u16, u32),
) -> Result<Vec<u8>, Error> {
    let mut sections: Vec<(SectionKind, u32, &[u8])> =
        required.iter().map(|(k, d)| (*k, SECTION_REQUIRED, d.as_slice())).collect();
    for (kind, data) in optional {
        let kind = SectionKind(*kind);
        if SectionKind::KNOWN.contains(&kind) {
            return Err(spec_error(kind.0 as usize, 0));
        }
        sections.push((kind, 0, data));
    }
    let mut out = Vec::new();
    out.extend_from_slice(&MAGIC);
    put_u16(&mut out, VERSION_MAJOR);
    put_u16(&mut out, minor);
    put_u32(&mut out, flags);
    put_u32(&mut out, 0); // file length, patched below
    put_u32(&mut out, sections.len() as u32);
    put_u32(&mut out, 0); // checksum, patched below
    out.extend_from_slice(&[0; 8]);
    let mut offset = HEADER_LEN + SECTION_ENTRY_LEN * sections.len();
    for (kind, flags, data) in &sections {
        put_u32(&mut out, kind.0);
        put_u32(&mut out, *flags);
        put_u32(&mut out, len_u32(offset)?);
        put_u32(&mut out, len_u32(data.len())?);
        offset = align4(offset + data.len());
    }
    for (_, _, data) in &sections {
        out.extend_from_slice(data);
        pad4(&mut out);
    }
    let file_len = len_u32(out.len())?;
    copy_into(out.get_mut(12..).unwrap_or(&mut []), &file_len.to_le_bytes());
    let crc = file_checksum(&out);
    copy_into(out.get_mut(20..).unwrap_or(&mut []), &crc.to_le_bytes());
    Container::parse(&out)?;
    Ok(out)
}

impl MaterialSpec {
    /// Serializes and validates. Errors are the parser's (naming the field) or `BadArgument(Spec)`
    /// for vectors whose lengths contradict the sizes they declare.
    pub fn to_bytes(&self) -> Result<Vec<u8>, Error> {
        let material = self.material_section()?;
        let (levels, latents) = self.levels_and_latents()?;
        let mlp = self.mlp_section()?;
        let required = alloc::vec![
            (SectionKind::MATERIAL, material),
            (SectionKind::LEVELS, levels),
            (SectionKind::MLP, mlp),
            (SectionKind::LATENTS, latents),
        ];
        // A scaled LOD feature is 2.3's: its flag makes older readers refuse the file.
        let version = if self.mlp.lod_input > 1 {
            (LOD_SCALE_VERSION_MINOR, FLAG_LOD_SCALE)
        } else {
            (VERSION_MINOR, 0)
        };
        assemble(required, &self.optional_sections, version)
    }

    fn material_section(&self) -> Result<Vec<u8>, Error> {
        material_section(
            (self.width, self.height, self.mip_count),
            self.address_mode,
            &self.channels,
        )
    }

    fn levels_and_latents(&self) -> Result<(Vec<u8>, Vec<u8>), Error> {
        let mut s = Vec::new();
        let mut latents = Vec::new();
        s.push(len_u8(self.levels.len())?);
        s.push(len_u8(self.grids.len())?);
        put_u16(&mut s, 0);
        let mut table = [0u8; MIP_TABLE_LEN];
        if self.mip_to_level.len() > table.len() {
            return Err(spec_error(self.mip_to_level.len(), table.len()));
        }
        copy_into(&mut table, &self.mip_to_level);
        s.extend_from_slice(&table);
        for g in &self.grids {
            let cells = usize::from(g.width) * usize::from(g.height) * usize::from(g.channels);
            if g.codes.len() != cells {
                return Err(spec_error(g.codes.len(), cells));
            }
            if g.quantization.len() != usize::from(g.channels) {
                return Err(spec_error(g.quantization.len(), usize::from(g.channels)));
            }
            let packed = pack_codes(&g.codes, g.bits);
            let expected =
                packed_len(g.width.into(), g.height.into(), g.channels.into(), g.bits.into());
            put_u16(&mut s, g.width);
            put_u16(&mut s, g.height);
            s.extend_from_slice(&[g.channels, g.bits]);
            put_u16(&mut s, 0);
            put_u32(&mut s, len_u32(latents.len())?);
            put_u32(&mut s, len_u32(expected.unwrap_or(packed.len()))?);
            for &(offset, step) in &g.quantization {
                s.extend_from_slice(&offset.to_le_bytes());
                s.extend_from_slice(&step.to_le_bytes());
            }
            latents.extend_from_slice(&packed);
        }
        for level in &self.levels {
            s.push(len_u8(level.terms.len())?);
            s.extend_from_slice(&[0; 3]);
            for term in &level.terms {
                s.extend_from_slice(&[term.mode as u8, len_u8(term.grids.len())?, 0, 0]);
                let mut slots = [0u8; 8];
                if term.grids.len() > slots.len() {
                    return Err(spec_error(term.grids.len(), slots.len()));
                }
                copy_into(&mut slots, &term.grids);
                s.extend_from_slice(&slots);
            }
        }
        Ok((s, latents))
    }

    fn mlp_section(&self) -> Result<Vec<u8>, Error> {
        let m = &self.mlp;
        let mut s = Vec::new();
        s.extend_from_slice(&[
            len_u8(m.layers.len())?,
            m.input_frac_bits,
            m.pe_frequencies,
            m.lod_input,
        ]);
        put_u16(&mut s, m.layers.first().map_or(0, |l| l.inputs));
        put_u16(&mut s, 0);
        for l in &m.layers {
            put_u16(&mut s, l.inputs);
            put_u16(&mut s, l.outputs);
            s.extend_from_slice(&[l.out_frac_bits, l.activation as u8]);
            put_u16(&mut s, 0);
        }
        for l in &m.layers {
            let n = usize::from(l.inputs) * usize::from(l.outputs);
            let rows = usize::from(l.outputs);
            for (len, want) in
                [(l.weights_i8.len(), n), (l.scales.len(), rows), (l.bias.len(), rows)]
            {
                if len != want {
                    return Err(spec_error(len, want));
                }
            }
            s.extend(l.weights_i8.iter().map(|&w| w as u8));
            pad4(&mut s);
            l.scales.iter().for_each(|v| s.extend_from_slice(&v.to_le_bytes()));
            l.bias.iter().for_each(|v| s.extend_from_slice(&v.to_le_bytes()));
        }
        Ok(s)
    }
}

impl<'a> Material<'a> {
    /// An owned copy of everything a neural material's file holds (the inverse of
    /// [`MaterialSpec::to_bytes`]); `None` for a JPEG material (whose section is its own spec,
    /// `JpegMaterialSpec`).
    pub fn to_spec(&self) -> Option<MaterialSpec> {
        let n = self.neural()?;
        let channels = self
            .channels()
            .iter()
            .map(|c| ChannelSpec {
                name: String::from(c.name),
                semantic: c.semantic,
                component: c.component,
                color_space: c.color_space,
                range_min: c.range_min,
                range_max: c.range_max,
            })
            .collect();
        let grids = n
            .grids()
            .iter()
            .map(|g| GridSpec {
                width: g.width,
                height: g.height,
                channels: g.channels,
                bits: g.bits,
                quantization: (0..g.channels()).map(|c| g.quantization(c)).collect(),
                codes: (0..g.height())
                    .flat_map(|y| {
                        (0..g.width())
                            .flat_map(move |x| (0..g.channels()).map(move |c| g.code(x, y, c)))
                    })
                    .collect(),
            })
            .collect();
        let levels = n
            .levels()
            .iter()
            .map(|l| LevelSpec {
                terms: l
                    .terms
                    .iter()
                    .map(|t| TermSpec { mode: t.mode, grids: t.grids.iter().copied().collect() })
                    .collect(),
            })
            .collect();
        let layers = n
            .mlp()
            .layers()
            .iter()
            .map(|l| {
                let (n_in, n_out) = (l.inputs(), l.outputs());
                let cells = || (0..n_out).flat_map(move |o| (0..n_in).map(move |i| (o, i)));
                LayerSpec {
                    inputs: l.inputs,
                    outputs: l.outputs,
                    out_frac_bits: l.out_frac_bits,
                    activation: l.activation,
                    weights_i8: cells().map(|(o, i)| l.weight_i8(o, i)).collect(),
                    scales: (0..n_out).map(|o| l.scale(o)).collect(),
                    bias: (0..n_out).map(|o| l.bias(o)).collect(),
                }
            })
            .collect();
        Some(MaterialSpec {
            width: self.width,
            height: self.height,
            mip_count: self.mip_count,
            address_mode: self.address_mode,
            channels,
            mip_to_level: n
                .mip_to_level
                .iter()
                .copied()
                .take(usize::from(self.mip_count))
                .collect(),
            grids,
            levels,
            mlp: MlpSpec {
                input_frac_bits: n.mlp.input_frac_bits,
                pe_frequencies: n.mlp.pe_frequencies,
                lod_input: n.mlp.lod_input,
                layers,
            },
            optional_sections: self
                .optional_sections
                .iter()
                .map(|(k, d)| (k.0, d.to_vec()))
                .collect(),
        })
    }
}

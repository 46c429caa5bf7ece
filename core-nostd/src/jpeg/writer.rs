//! Writing JPEG materials (feature `alloc`): an owned description and its serialization to the
//! JPEG section of docs/FORMAT.md §11, checked by parsing it like every file the writer makes.

extern crate alloc;

use alloc::vec::Vec;

use super::{
    DC_BITS, GROUP_MCUS, JPEG_SECTION_VERSION, JpegMap, QUANT_TABLE_LEN, STREAM_RECORD_LEN,
};
use crate::bytes::align4;
use crate::error::{Error, Field};
use crate::format::channel::AddressMode;
use crate::format::container::{JPEG_VERSION_MINOR, SectionKind};
use crate::writer::{
    ChannelSpec, assemble, len_u8, len_u32, material_section, pad4, put_u16, put_u32, spec_error,
};

/// A Huffman table as in a JPEG DHT segment.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HuffmanTableSpec {
    /// 0 DC, 1 AC.
    pub class: u8,
    /// Codes of each length 1..=16.
    pub counts: [u8; 16],
    /// Symbols in code order.
    pub values: Vec<u8>,
}

/// One map at one mip.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JpegStreamSpec {
    /// Quantization, DC and AC table of each component (Y, Cb, Cr; 0 where unused).
    pub quant: [u8; 3],
    pub dc: [u8; 3],
    pub ac: [u8; 3],
    /// Bit offset of every MCU in `data`, in scan order.
    pub mcu_bits: Vec<u64>,
    /// Absolute DC values, MCU-major: the first luma block's, then Cb's and Cr's for colour.
    pub dcs: Vec<i16>,
    /// The entropy-coded data, byte stuffing and markers removed.
    pub data: Vec<u8>,
}

/// Everything a JPEG `.nmat` file holds, owned.
#[derive(Clone, Debug, PartialEq)]
pub struct JpegMaterialSpec {
    pub width: u32,
    pub height: u32,
    pub mip_count: u8,
    pub address_mode: AddressMode,
    pub channels: Vec<ChannelSpec>,
    pub maps: Vec<JpegMap>,
    /// 64 values each, zigzag order.
    pub quant_tables: Vec<[u8; QUANT_TABLE_LEN]>,
    pub huffman_tables: Vec<HuffmanTableSpec>,
    /// Map-major: every mip of map 0, then of map 1, …
    pub streams: Vec<JpegStreamSpec>,
    /// Optional sections, as in [`crate::MaterialSpec`].
    pub optional_sections: Vec<(u32, Vec<u8>)>,
}

impl JpegMaterialSpec {
    /// Serializes and validates (errors are the parser's, `LimitExceeded(JpegIndex)` where eight
    /// MCUs after an indexed one span more than 65535 bits, or `BadArgument(Spec)`).
    pub fn to_bytes(&self) -> Result<Vec<u8>, Error> {
        let material = material_section(
            (self.width, self.height, self.mip_count),
            self.address_mode,
            &self.channels,
        )?;
        let required =
            alloc::vec![(SectionKind::MATERIAL, material), (SectionKind::JPEG, self.section()?)];
        assemble(required, &self.optional_sections, (JPEG_VERSION_MINOR, 0))
    }

    fn section(&self) -> Result<Vec<u8>, Error> {
        let mut s = Vec::new();
        put_u16(&mut s, JPEG_SECTION_VERSION);
        s.push(len_u8(self.maps.len())?);
        s.push(len_u8(self.quant_tables.len())?);
        s.push(len_u8(self.huffman_tables.len())?);
        s.extend_from_slice(&[0; 3]);
        for m in &self.maps {
            s.extend_from_slice(&[m.first_channel, m.channel_count, m.luma_h, m.luma_v]);
        }
        for q in &self.quant_tables {
            s.extend_from_slice(q);
        }
        for h in &self.huffman_tables {
            s.extend_from_slice(&[h.class, 0]);
            put_u16(
                &mut s,
                u16::try_from(h.values.len()).map_err(|_| spec_error(h.values.len(), 256))?,
            );
            s.extend_from_slice(&h.counts);
            s.extend_from_slice(&h.values);
            pad4(&mut s);
        }
        let records = s.len();
        s.resize(records + self.streams.len() * STREAM_RECORD_LEN, 0);
        for (i, st) in self.streams.iter().enumerate() {
            let offset = s.len();
            for (g, group) in st.mcu_bits.chunks(GROUP_MCUS).enumerate() {
                let base = group.first().copied().unwrap_or(0);
                put_u32(
                    &mut s,
                    u32::try_from(base)
                        .map_err(|_| spec_error(base as usize, u32::MAX as usize))?,
                );
                for j in 1..GROUP_MCUS {
                    let rel = group.get(j).map_or(0, |&b| b.saturating_sub(base));
                    let rel = u16::try_from(rel).map_err(|_| Error::LimitExceeded {
                        field: Field::JpegIndex,
                        index: (g * GROUP_MCUS + j) as u32,
                        value: rel,
                        limit: u64::from(u16::MAX),
                    })?;
                    put_u16(&mut s, rel);
                }
            }
            let mut dc = alloc::vec![0u8; (st.dcs.len() * DC_BITS).div_ceil(8)];
            for (k, &v) in st.dcs.iter().enumerate() {
                let bit = k * DC_BITS;
                let word = (u32::from(v as u16) & 0xFFF) << (bit % 8);
                for (b, byte) in word.to_le_bytes().iter().enumerate().take(3) {
                    if let Some(d) = dc.get_mut(bit / 8 + b) {
                        *d |= byte;
                    }
                }
            }
            s.extend_from_slice(&dc);
            pad4(&mut s);
            s.extend_from_slice(&st.data);
            let mut record = Vec::with_capacity(STREAM_RECORD_LEN);
            put_u32(&mut record, len_u32(offset)?);
            put_u32(&mut record, len_u32(st.data.len())?);
            for t in [st.quant, st.dc, st.ac] {
                record.extend_from_slice(&t);
            }
            record.resize(STREAM_RECORD_LEN, 0);
            let at = records + i * STREAM_RECORD_LEN;
            if let Some(dst) = s.get_mut(at..at + STREAM_RECORD_LEN) {
                dst.copy_from_slice(&record);
            }
            pad4(&mut s);
        }
        debug_assert_eq!(s.len(), align4(s.len()));
        Ok(s)
    }
}

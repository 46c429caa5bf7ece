//! A JPEG section without its index (the body of PACKED_JPEG, docs/FORMAT.md §12.5) and back:
//! the index and DC values of §11.2 are a function of the entropy-coded data, so a packed file
//! stores the data alone and unpacking rebuilds them by scanning each stream once (Huffman
//! decoding, no inverse DCT).

#[cfg(feature = "alloc")]
extern crate alloc;

use super::entropy::{Bits, block};
use super::{
    DC_BITS, GROUP_LEN, GROUP_MCUS, Jpeg, STREAM_RECORD_LEN, Stream, Streams, stream_layout,
};
use crate::bytes::{align4, u16_at, u32_at};
use crate::error::{Error, Field, malformed};

impl Stream<'_> {
    /// Walks the stream's MCUs in order as a decoder without an index would: for each, its bit
    /// offset and the absolute DC values an index stores (the first luma block's, then Cb's and
    /// Cr's). Every `restart` MCUs (0: never) the data continues at the next byte and the DC
    /// predictions restart at 0, as at a restart marker. An MCU that would start past the end of
    /// the data is `Malformed JpegIndex` (so the walk ends after at most 4 MCUs per byte).
    pub(crate) fn scan(
        &self,
        restart: u16,
        stream: usize,
        mcus: usize,
        mut visit: impl FnMut(usize, u64, [i32; 3]) -> Result<(), Error>,
    ) -> Result<(), Error> {
        let end = 8 * self.data.len() as u64;
        let mut bits = Bits { data: self.data, pos: 0 };
        let mut coefs = [0i32; 64];
        let mut pred = [0i32; 3];
        let luma = usize::from(self.map.luma_h) * usize::from(self.map.luma_v);
        let components = if self.map.channel_count == 3 { 3 } else { 1 };
        for i in 0..mcus {
            if restart > 0 && i > 0 && i % usize::from(restart) == 0 {
                bits.pos = bits.pos.div_ceil(8) * 8;
                pred = [0; 3];
            }
            if bits.pos > end {
                return Err(malformed(Field::JpegIndex, stream, bits.pos as i64));
            }
            let start = bits.pos;
            let mut dcs = [0i32; 3];
            for (c, (quant, dc, ac)) in self.tables.iter().enumerate().take(components) {
                let blocks = if c == 0 { luma } else { 1 };
                for b in 0..blocks {
                    let diff = block(&mut bits, dc, ac, quant, &mut coefs);
                    if let Some(p) = pred.get_mut(c) {
                        *p = p.wrapping_add(diff);
                        if b == 0
                            && let Some(d) = dcs.get_mut(c)
                        {
                            *d = *p;
                        }
                    }
                }
            }
            visit(i, start, dcs)?;
        }
        Ok(())
    }

    /// MCU `i`'s bit offset and stored DC values, from the index (an indexed stream).
    #[cfg(feature = "alloc")]
    fn indexed(&self, i: usize) -> (u64, [i32; 3]) {
        let values = if self.map.channel_count == 3 { 3 } else { 1 };
        let dcs = core::array::from_fn(|c| if c < values { self.dc(i * values + c) } else { 0 });
        (self.mcu_bit(i), dcs)
    }
}

/// Writes MCU `i`'s bit offset into an index (§11.2) whose earlier entries are written.
fn put_offset(index: &mut [u8], i: usize, bit: u64, stream: usize) -> Result<(), Error> {
    let (g, j) = (i / GROUP_MCUS, i % GROUP_MCUS);
    let at = g * GROUP_LEN;
    if j == 0 {
        let base =
            u32::try_from(bit).map_err(|_| malformed(Field::JpegIndex, stream, bit as i64))?;
        return put(index, at, &base.to_le_bytes());
    }
    let rel = bit.saturating_sub(u64::from(u32_at(index, at)));
    let rel = u16::try_from(rel).map_err(|_| Error::LimitExceeded {
        field: Field::JpegIndex,
        index: i as u32,
        value: rel,
        limit: u64::from(u16::MAX),
    })?;
    put(index, at + 4 + 2 * (j - 1), &rel.to_le_bytes())
}

/// Writes DC value `k` (12-bit two's complement, §11.2) into zeroed DC bytes.
fn put_dc(dc: &mut [u8], k: usize, value: i32) {
    let bit = k * DC_BITS;
    let word = ((value as u32) & 0xFFF) << (bit % 8);
    for (b, byte) in word.to_le_bytes().iter().enumerate().take(3) {
        if let Some(d) = dc.get_mut(bit / 8 + b) {
            *d |= byte;
        }
    }
}

fn put(out: &mut [u8], at: usize, bytes: &[u8]) -> Result<(), Error> {
    let available = out.len();
    at.checked_add(bytes.len())
        .and_then(|end| out.get_mut(at..end))
        .ok_or(Error::Truncated {
            field: Field::JpegStream,
            index: 0,
            needed: (at + bytes.len()) as u64,
            available: available as u64,
        })?
        .copy_from_slice(bytes);
    Ok(())
}

impl Jpeg<'_> {
    fn record(&self, i: usize) -> &[u8] {
        let at = self.streams_at + i * STREAM_RECORD_LEN;
        self.section.get(at..at + STREAM_RECORD_LEN).unwrap_or(&[])
    }

    fn streams_in_order(&self) -> impl Iterator<Item = (usize, usize, u32)> + '_ {
        let mips = u32::from(self.mip_count);
        (0..self.maps.len())
            .flat_map(move |m| (0..mips).map(move |mip| (m, mip)))
            .enumerate()
            .map(|(i, (m, mip))| (i, m, mip))
    }

    /// The length of the JPEG section this bare one stands for (§11, streams indexed).
    pub(crate) fn indexed_len(&self) -> usize {
        let mut len = self.streams_at + self.stream_count() * STREAM_RECORD_LEN;
        for (i, m, mip) in self.streams_in_order() {
            let size = self.mip_sizes.get(mip as usize).copied().unwrap_or((1, 1));
            let (index, dc, _) = self
                .maps
                .get(m)
                .map_or((0, 0, 0), |map| stream_layout(map, size, Streams::Indexed));
            len = align4(len + index + dc + u32_at(self.record(i), 4) as usize);
        }
        len
    }

    fn stream_count(&self) -> usize {
        self.maps.len() * usize::from(self.mip_count)
    }

    /// Writes the indexed JPEG section this bare one stands for into `out` (zeroed, exactly
    /// [`Jpeg::indexed_len`] bytes): the same tables and records, each stream's index and DC
    /// values rebuilt by [`Stream::scan`] with the restart interval its record holds.
    pub(crate) fn write_indexed(&self, out: &mut [u8]) -> Result<(), Error> {
        let head = self.section.get(..self.streams_at).unwrap_or(&[]);
        put(out, 0, head)?;
        let mut offset = self.streams_at + self.stream_count() * STREAM_RECORD_LEN;
        for (i, m, mip) in self.streams_in_order() {
            let record = self.record(i);
            let stream = self.stream(m, mip).ok_or(malformed(Field::JpegStream, i, 0))?;
            let size = self.mip_sizes.get(mip as usize).copied().unwrap_or((1, 1));
            let (index_len, dc_len, mcus) = stream_layout(&stream.map, size, Streams::Indexed);
            let values = if stream.map.channel_count == 3 { 3 } else { 1 };
            let at = self.streams_at + i * STREAM_RECORD_LEN;
            put(out, at, &(offset as u32).to_le_bytes())?;
            put(out, at + 4, record.get(4..17).unwrap_or(&[]))?;
            let available = out.len();
            let body = out.get_mut(offset..).ok_or(Error::Truncated {
                field: Field::JpegStream,
                index: i as u32,
                needed: offset as u64,
                available: available as u64,
            })?;
            let (index, rest) = body.split_at_mut(index_len.min(body.len()));
            let (dc, rest) = rest.split_at_mut(dc_len.min(rest.len()));
            stream.scan(u16_at(record, 18), i, mcus, |k, bit, dcs| {
                put_offset(index, k, bit, i)?;
                for (c, &v) in dcs.iter().enumerate().take(values) {
                    put_dc(dc, k * values + c, v);
                }
                Ok(())
            })?;
            put(rest, 0, stream.data)?;
            offset = align4(offset + index_len + dc_len + stream.data.len());
        }
        if offset != out.len() {
            return Err(malformed(Field::PackedLength, 0, offset as i64));
        }
        Ok(())
    }

    /// The restart interval (in MCUs, 0: none) under which scanning stream `i` from its data
    /// reproduces its stored index and DC values, or `None` if none does (an index a scan cannot
    /// rebuild: such a file cannot drop it).
    #[cfg(feature = "alloc")]
    fn restart_interval(&self, i: usize, m: usize, mip: u32) -> Option<u16> {
        let stream = self.stream(m, mip)?;
        let (_, _, mcus) = self.maps.get(m).map(|map| {
            stream_layout(
                map,
                self.mip_sizes.get(mip as usize).copied().unwrap_or((1, 1)),
                Streams::Indexed,
            )
        })?;
        let first_mismatch = |restart: u16| {
            let mut mismatch = None;
            let walked = stream.scan(restart, i, mcus, |k, bit, dcs| {
                if mismatch.is_none() && stream.indexed(k) != (bit, dcs) {
                    mismatch = Some(k);
                }
                Ok(())
            });
            (walked.is_ok(), mismatch)
        };
        match first_mismatch(0) {
            (true, None) => Some(0),
            // The first MCU the plain walk gets wrong follows a restart marker: the interval
            // divides its number (a smaller one if the walk happened to agree at its earlier
            // markers, byte-aligned with predictions of 0).
            (_, Some(k)) if k > 0 => (1..=k.min(usize::from(u16::MAX)))
                .filter(|r| k % r == 0)
                .find(|&r| first_mismatch(r as u16) == (true, None))
                .map(|r| r as u16),
            _ => None,
        }
    }

    /// The bare body of this (indexed) section: the same tables, each stream's entropy-coded data
    /// alone with its restart interval in its record. `None` where an index cannot be rebuilt
    /// from its data.
    #[cfg(feature = "alloc")]
    pub(crate) fn bare_section(&self) -> Option<alloc::vec::Vec<u8>> {
        let mut out = alloc::vec::Vec::new();
        out.extend_from_slice(self.section.get(..self.streams_at)?);
        out.resize(self.streams_at + self.stream_count() * STREAM_RECORD_LEN, 0);
        for (i, m, mip) in self.streams_in_order() {
            let restart = self.restart_interval(i, m, mip)?;
            let data = self.stream(m, mip)?.data;
            let at = self.streams_at + i * STREAM_RECORD_LEN;
            let offset = u32::try_from(out.len()).ok()?;
            let record = out.get_mut(at..at + STREAM_RECORD_LEN)?;
            record.copy_from_slice(self.record(i));
            record.get_mut(0..4)?.copy_from_slice(&offset.to_le_bytes());
            record.get_mut(18..20)?.copy_from_slice(&restart.to_le_bytes());
            out.extend_from_slice(data);
            out.resize(align4(out.len()), 0);
        }
        Some(out)
    }
}
